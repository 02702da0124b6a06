//! toporec-plus's unit tests: the relief by hand, turns, keys, hidden sectors, short ranges,
//! the first pass's routes, grown and restricted searches, the fine stage's poses and order.

use super::PlusParams;
use super::distance::*;
use super::field::*;
use super::keys::*;
use super::searcher::*;
use crate::methods::Computed as _;
use crate::methods::Hit;
use crate::methods::Searcher as _;
use crate::types::Point;

/// Box walls around the sensor, sampled every 20 cm with a few centimetres of noise (in
/// general position: no two squares at the same height).
fn scene() -> Vec<Point> {
    let mut rng = crate::rng::SplitMix64(7);
    let mut jitter = move || (rng.next_f64() - 0.5) * 0.04;
    let mut pts = Vec::new();
    let mut add_box = |cx: f64, cy: f64, w: f64, h: f64| {
        let steps = (w / 0.2) as i32;
        for i in 0..=steps {
            for k in 0..=(h / 0.2) as i32 {
                let t = i as f64 * 0.2 - w / 2.0;
                let z = k as f64 * 0.2;
                for q in [
                    [cx + t, cy - w / 2.0, z],
                    [cx + t, cy + w / 2.0, z],
                    [cx - w / 2.0, cy + t, z],
                    [cx + w / 2.0, cy + t, z],
                ] {
                    pts.push([q[0] + jitter(), q[1] + jitter(), q[2] + jitter()]);
                }
            }
        }
    };
    add_box(12.0, 5.0, 6.0, 4.0);
    add_box(-9.0, 14.0, 8.0, 6.0);
    add_box(-15.0, -10.0, 5.0, 3.0);
    add_box(4.0, -20.0, 10.0, 5.0);
    add_box(30.0, -3.0, 4.0, 8.0);
    pts
}

fn turned(pts: &[Point], quarter_turns: usize) -> Vec<Point> {
    pts.iter()
        .map(|&[x, y, z]| match quarter_turns % 4 {
            0 => [x, y, z],
            1 => [-y, x, z],
            2 => [-x, -y, z],
            _ => [y, -x, z],
        })
        .collect()
}

#[test]
fn relief_is_the_height_above_where_the_class_dies() {
    // One row of 1 m squares: peak A (5 m), a saddle (2 m), peak B (4 m), a foot (1 m),
    // in x order A S B D. Heights enter A, B, S, D: B is born apart from A, and S joins
    // them, so B (the younger, lower peak) dies at 2 m; S and D join A's class, which
    // never dies and ends at the lowest square (1 m). Relief: A 5 − 1 = 4 (its
    // persistence), B 4 − 2 = 2 (its persistence), S 2 − 1 = 1, D 1 − 1 = 0.
    let p = PlusParams { cell: 1.0, max_radius: 10.0, ..PlusParams::default() };
    let points = [[0.5, 0.5, 5.0], [1.5, 0.5, 2.0], [2.5, 0.5, 4.0], [3.5, 0.5, 1.0]];
    let field = height_field(&points, &p);
    let (order, relief) = field.relief();
    let at = |x: f64| {
        let k = order.iter().position(|&k| (field.centre(k as usize, p.cell).0 - x).abs() < 1e-9).unwrap();
        relief[k]
    };
    assert_eq!([at(0.5), at(1.5), at(2.5), at(3.5)], [4.0, 1.0, 2.0, 0.0]);
    // Two returns above one square: the height channel holds its highest, 5 m + 2 m, as the
    // code round(255 · √(7 / 64)) = round(84.33) = 84; the relief channel the square's relief
    // (5 − 5 = 0: its class ends at the lowest square, itself); the Cartesian image, the
    // same height code in the one cell the square is in.
    let two = [[0.5, 0.5, 5.0], [0.6, 0.7, 3.0]];
    let d = describe(&two, &p).unwrap();
    let filled = |codes: &[f32]| codes.iter().copied().filter(|&v| v > 0.0).collect::<Vec<f32>>();
    assert_eq!(filled(&d[p.rings * p.sectors..p.polar_len()]), [84.0]);
    assert_eq!(filled(&d[p.polar_len()..]), [84.0]);
    assert!(d[..p.rings * p.sectors].iter().all(|&v| v == 0.0));
}

#[test]
fn a_quarter_turn_is_matched_exactly_and_its_yaw_found() {
    let p = PlusParams::default();
    let a = describe(&scene(), &p).unwrap();
    assert!(a.iter().any(|&v| v > 0.0));
    for q in 1..4 {
        let b = describe(&turned(&scene(), q), &p).unwrap();
        // The descriptor is the original's, its sectors shifted by a quarter.
        for row in 0..2 * p.rings {
            for s in 0..p.sectors {
                let shifted = (s + q * p.sectors / 4) % p.sectors;
                assert_eq!(b[row * p.sectors + shifted], a[row * p.sectors + s]);
            }
        }
        let (d, yaw) = distance(&b, &a, &p);
        assert!(d <= 1e-12, "{q} quarter turns: distance {d}");
        assert_eq!(yaw, 90.0 * q as f64, "{q} quarter turns");
    }
}

#[test]
fn keys_do_not_depend_on_quarter_turns_and_an_empty_scan_has_no_descriptor() {
    let p = PlusParams::default();
    let a = describe(&scene(), &p).unwrap();
    let b = describe(&turned(&scene(), 1), &p).unwrap();
    // The yaw-independent keys: shape, profile, ring.
    let key = |d: &[f32]| [shape_key(d, &p), profile_key(d, &p), ring_key(d, &p)].concat();
    let (ka, kb) = (key(&a), key(&b));
    assert_eq!(ka.len(), shape_len(&p) + profile_len(&p) + p.rings);
    for (x, y) in ka.iter().zip(&kb) {
        assert!((x - y).abs() < 1e-6);
    }
    let far = [[100.0, 0.0, 1.0]];
    assert_eq!(describe(&far, &p).unwrap_err(), "no return within 80 m of the sensor");
    assert!(describe(&[], &p).is_err());
}

#[test]
fn a_hidden_sector_is_left_out_not_counted_as_a_difference() {
    let p = PlusParams::default();
    let full = describe(&scene(), &p).unwrap();
    // The boxes at x > 0, y > 0 (the first quadrant) hidden.
    let hidden: Vec<Point> = scene().into_iter().filter(|q| !(q[0] > 0.0 && q[1] > 0.0)).collect();
    let part = describe(&hidden, &p).unwrap();
    let (d, yaw) = distance(&part, &full, &p);
    let other = describe(
        &turned(&scene(), 1).into_iter().map(|q| [q[0] * 1.7, q[1] * 0.6, q[2]]).collect::<Vec<_>>(),
        &p,
    )
    .unwrap();
    assert!(d < distance(&part, &other, &p).0, "the occluded scan is nearer its own place");
    assert!(!(6.0..=354.0).contains(&yaw), "no turn: yaw {yaw}");
}

#[test]
fn a_scan_cut_at_a_shorter_range_is_compared_where_both_reach() {
    // Rings of 2 m: the scene reaches ring 16 (32 m); cut at 20 m, ring 10.
    let p = PlusParams { max_radius: 40.0, ..PlusParams::default() };
    let full = describe(&scene(), &p).unwrap();
    let near: Vec<Point> = scene().into_iter().filter(|q| q[0].hypot(q[1]) <= 20.0).collect();
    let cut = describe(&near, &p).unwrap();
    let (r_full, r_cut) = (reach(&full, &p), reach(&cut, &p));
    assert!(r_cut < r_full && r_cut <= 11, "reach {r_cut} of {r_full} rings");
    let other: Vec<Point> = turned(&scene(), 1).into_iter().map(|q| [q[0] * 1.7, q[1] * 0.6, q[2]]).collect();
    let other = describe(&other, &p).unwrap();
    let (d, _) = distance(&cut, &full, &p);
    assert!(d < distance(&cut, &other, &p).0, "{d}");
}

#[test]
fn the_first_pass_is_the_same_on_every_route() {
    // Rows of three keys of `width` codes, many of them at equal distances, in blocks (a
    // partial last block too): the vector route and the portable loop keep the rows that
    // sorting every row by (distance, row) puts first, in that order.
    for (width, n) in [(24usize, 5000usize), (8, 1001), (264, 70)] {
        let mut rng = crate::rng::SplitMix64(3);
        let rows: Vec<Vec<u8>> =
            (0..n).map(|_| (0..FIRSTS * width).map(|_| (rng.next_u64() % 8) as u8).collect()).collect();
        let mut blocks = vec![0u8; n.div_ceil(BLOCK) * BLOCK * FIRSTS * width];
        for (row, first) in rows.iter().enumerate() {
            put_first(&mut blocks, row, first);
            assert_eq!(&get_first(&blocks, row, FIRSTS * width), first);
        }
        let query = rows[17].clone();
        let l1 = |r: usize, k: usize| -> u32 {
            (k * width..(k + 1) * width).map(|t| rows[r][t].abs_diff(query[t]) as u32).sum()
        };
        let m = [30, 300, 7];
        for allowed in [&(|_| true) as &dyn Fn(usize) -> bool, &|row: usize| row % 2 == 1] {
            let pass = FirstPass { blocks: &blocks, n, query: &query, width };
            let fast = pass.nearest(m, allowed);
            let plain = pass.nearest_portable(m, allowed);
            assert_eq!(fast, plain, "width {width}");
            for k in 0..FIRSTS {
                let mut sorted: Vec<(u32, usize)> =
                    (0..n).filter(|&r| allowed(r)).map(|r| (l1(r, k), r)).collect();
                sorted.sort_unstable();
                let want: Vec<usize> = sorted.into_iter().take(m[k]).map(|(_, r)| r).collect();
                assert_eq!(fast[k], want, "width {width}, key {k}");
            }
        }
        let pass = FirstPass { blocks: &blocks, n, query: &query, width };
        assert_eq!(pass.nearest(m, &|_| true)[0][0], 17);
    }
}

#[test]
fn a_grown_searcher_and_a_restricted_search_equal_a_searcher_of_those_rows() {
    let p = PlusParams { candidates: 3, ..PlusParams::default() };
    let scenes: Vec<Vec<f32>> = (0..12)
        .map(|i| {
            let s: Vec<Point> = scene()
                .into_iter()
                .map(|q| [q[0] * (1.0 + 0.05 * i as f64), q[1] - i as f64, q[2]])
                .collect();
            describe(&s, &p).unwrap()
        })
        .collect();
    let all: Vec<f32> = scenes.concat();
    let built = Searcher::new(all.clone(), p.clone());
    let mut grown = Searcher::new(Vec::new(), p.clone());
    for d in &scenes {
        grown.push(d);
    }
    assert_eq!(grown.bytes(), built.bytes());
    let query = describe(&turned(&scene(), 1), &p).unwrap();
    // Rows 2, 5, 7 and 9 alone: the same hits as a searcher of those rows, renumbered.
    let kept = [2usize, 5, 7, 9];
    let alone = built.subset(&kept);
    let (restricted, _) = grown.search_where(&query, 2, &|row| kept.contains(&row));
    let (only, _) = alone.search(&query, 2);
    let renumbered: Vec<Hit> = only.iter().map(|h| Hit { row: kept[h.row], ..*h }).collect();
    assert_eq!(restricted, renumbered);
}

#[test]
fn search_finds_a_turned_scan_and_its_yaw() {
    let p = PlusParams::default();
    let scenes: Vec<Vec<Point>> = (0..6)
        .map(|i| scene().into_iter().map(|q| [q[0] * (1.0 + 0.15 * i as f64), q[1], q[2]]).collect())
        .collect();
    let db: Vec<f32> = scenes.iter().flat_map(|s| describe(s, &p).unwrap()).collect();
    // Every entry re-ranked (more candidates than entries), and two by the keys.
    for candidates in [50, 2] {
        let searcher = Searcher::new(db.clone(), p.clone()).with_search(candidates, 0.1);
        for (i, s) in scenes.iter().enumerate() {
            let q = describe(&turned(s, 2), &p).unwrap();
            let (hits, _) = searcher.search(&q, 1);
            assert_eq!((hits[0].row, hits[0].yaw_degrees), (i, Some(180.0)), "{candidates} candidates");
        }
    }
}

#[test]
fn the_fine_stage_finds_where_the_query_stands() {
    // The query's sensor 2.5 m ahead of the candidate's and 1.5 m to its right, turned 30°
    // counter-clockwise: its points are the scene's seen from there.
    let p = PlusParams::default();
    let (tx, ty, heading) = (2.5f64, -1.5f64, 30f64.to_radians());
    let (sin, cos) = heading.sin_cos();
    let seen: Vec<Point> = scene()
        .iter()
        .map(|&[x, y, z]| {
            let (dx, dy) = (x - tx, y - ty);
            [cos * dx + sin * dy, -sin * dx + cos * dy, z]
        })
        .collect();
    let searcher = Searcher::new(describe(&scene(), &p).unwrap(), p.clone());
    let (hits, _) = searcher.search(&describe(&seen, &p).unwrap(), 1);
    let [x, y] = hits[0].offset.expect("the best candidate is posed");
    let yaw = hits[0].yaw_degrees.unwrap();
    // 1 m image cells, turned by a yaw found to a sub-sector turn (2°): within half a cell.
    // The yaw is the turn that brings the query's view onto the candidate's: −30°.
    assert!((x - tx).hypot(y - ty) <= 0.5, "pose ({x:.2}, {y:.2}), expected ({tx}, {ty})");
    let off = (yaw + 30.0).rem_euclid(360.0).min((-30.0 - yaw).rem_euclid(360.0));
    assert!(off <= 2.0, "yaw {yaw}");
}

#[test]
fn a_lateral_view_finds_the_scan_from_the_other_lane() {
    // The same walls scanned from 3 m to the left (y) and turned half round, as on the drive
    // back on the other side of the road. Seen from the origin 3 m to its side, the query's
    // grid is nearer the first scan's than the query's own, and the yaw stays half a turn.
    let p = PlusParams::plain();
    let here = describe(&scene(), &p).unwrap();
    let moved: Vec<Point> = scene().iter().map(|&[x, y, z]| [x, y - 3.0, z]).collect();
    let there = describe(&turned(&moved, 2), &p).unwrap();
    let (plain, _) = distance(&there, &here, &p);
    let lateral = PlusParams::default();
    assert_eq!(lateral.lateral, vec![3.0], "the default looks 3 m to either side");
    let searcher = Searcher::new(here.clone(), lateral.clone());
    let (hits, _) = searcher.search(&there, 1);
    assert!(hits[0].distance < 0.8 * plain, "lateral view {} against {plain}", hits[0].distance);
    let yaw = hits[0].yaw_degrees.unwrap();
    assert!((yaw - 180.0).abs() <= 12.0, "yaw {yaw}");
    // Without views the searcher gives the plain distance; a view of nothing moved is the
    // grid itself (0.000 here; 0.239 against 0.110 above).
    let (hits, _) = Searcher::new(here.clone(), p.clone()).search(&there, 1);
    assert_eq!(hits[0].distance, plain);
    let (same, _) = distance(&super::lateral::view(&here, 1e-9, &p), &here, &p);
    assert!(same < 0.01, "unmoved view {same}");
    assert!(PlusParams { lateral: vec![0.0], ..p.clone() }.problems()[0].contains("lateral"));
}

#[test]
fn the_fine_stage_poses_a_shift_smaller_than_a_cell_at_its_size() {
    // Neighbouring scans of a drive lie a fraction of the image's cell apart, so their pose
    // rests on the refinement between cells. Two images of one relief of narrow mounds (σ 0.6
    // of a cell), the query's sensor a quarter, half and three quarters of a cell ahead and a
    // quarter to the left: each axis within 0.08 of a cell (0.06 at most here). A parabola
    // through the correlation's peak errs by 0.09–0.15 on these (a quarter of a cell ahead
    // posed at 0.12).
    let p = PlusParams::default();
    let n = p.image_side;
    let mounds = [(7.3, 11.0, 200.0), (20.5, 6.2, 150.0), (14.0, 25.7, 230.0), (28.1, 18.4, 120.0)];
    let relief = |shift: (f64, f64)| mounds_image(n, &mounds, 0.6, shift);
    let aligner = super::pose::Aligner::new(&p);
    let candidate = relief((0.0, 0.0));
    for ahead in [0.25, 0.5, 0.75] {
        let pose = aligner.pose(&relief((ahead, 0.25)), &candidate, 0.0, &p);
        let (x, y) = (pose.x / p.image_cell, pose.y / p.image_cell);
        assert!(
            (x - ahead).abs() <= 0.08 && (y - 0.25).abs() <= 0.08,
            "({x:.3}, {y:.3}) cells, expected ({ahead}, 0.25)"
        );
    }
}

#[test]
fn the_fine_stage_leaves_out_the_vehicle_carrying_the_sensor() {
    // Returns off the vehicle itself fill the same cells around the sensor in every scan: they
    // correlate best at no shift. A scene of mounds, the query's sensor 2.5 cells ahead, and
    // a bright block on the sensor in both images: posed within a quarter of a cell of the
    // shift (with the block counted, at 0).
    let p = PlusParams::default();
    let n = p.image_side;
    let mounds = [(7.3, 11.0, 120.0), (30.5, 6.2, 90.0), (14.0, 31.7, 110.0), (28.1, 24.4, 80.0)];
    let scene = |ahead: f64| -> Vec<u8> {
        let mut image = mounds_image(n, &mounds, 1.0, (ahead, 0.0));
        // The vehicle: the sensor stands at the corner of cells n/2 - 1 and n/2.
        for i in n / 2 - 2..n / 2 + 2 {
            for j in n / 2 - 1..n / 2 + 1 {
                image[i * n + j] = 250;
            }
        }
        image
    };
    let pose = super::pose::Aligner::new(&p).pose(&scene(2.5), &scene(0.0), 0.0, &p);
    let x = pose.x / p.image_cell;
    assert!((x - 2.5).abs() <= 0.25 && pose.y.abs() <= 0.25 * p.image_cell, "({x:.3}, {:.3}) cells", pose.y);
}

/// An `n` × `n` image of the fine stage (codes, row by row) of Gaussian mounds `(row, column,
/// height)` of spread `sigma` cells, seen from a sensor moved by `shift` cells: cell (i, j)
/// holds the relief at (i + shift.0, j + shift.1).
fn mounds_image(n: usize, mounds: &[(f64, f64, f64)], sigma: f64, shift: (f64, f64)) -> Vec<u8> {
    let mut image = vec![0u8; n * n];
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 + shift.0, j as f64 + shift.1);
            let h: f64 = mounds
                .iter()
                .map(|&(ci, cj, a)| {
                    a * (-((x - ci).powi(2) + (y - cj).powi(2)) / (2.0 * sigma.powi(2))).exp()
                })
                .sum();
            image[i * n + j] = h.round().min(255.0) as u8;
        }
    }
    image
}

#[test]
fn the_fine_stage_does_not_promote_a_lookalike_turned_half_round() {
    // The query 1.5 m ahead of a map scan of its place, and elsewhere a lookalike: the query's
    // own view turned half round and stretched by a tenth, as a symmetric crossing seen from
    // its other side. The place is first by the polar distance, the lookalike a near-tie posed
    // nearer the query, which its offset alone would promote. A near-tie turned more than a
    // quarter turn from the best is another place, or the place driven the other way, and keeps
    // its polar rank.
    let p = PlusParams::default();
    let seen: Vec<Point> = scene().iter().map(|&[x, y, z]| [x - 1.5, y, z]).collect();
    let lookalike: Vec<Point> = turned(&seen, 2).iter().map(|&[x, y, z]| [1.1 * x, y, z]).collect();
    let db = [describe(&scene(), &p).unwrap(), describe(&lookalike, &p).unwrap()].concat();
    let (hits, _) = Searcher::new(db, p.clone()).search(&describe(&seen, &p).unwrap(), 2);
    let (place, turned_round) = if hits[0].row == 0 { (&hits[0], &hits[1]) } else { (&hits[1], &hits[0]) };
    let score = |h: &Hit| h.distance + POSE_WEIGHT * forward_offset(h.offset.expect("posed")[0]);
    assert!(
        place.distance < turned_round.distance && turned_round.distance <= place.distance + NEAR_TIE,
        "a near-tie behind the place: {place:?}, {turned_round:?}"
    );
    assert!(
        score(turned_round) < score(place),
        "its offset alone would promote it: {place:?}, {turned_round:?}"
    );
    assert!((turned_round.yaw_degrees.unwrap() - 180.0).abs() <= 4.0, "{turned_round:?}");
    assert!(turned_alike(358.0, 2.0) && turned_alike(0.0, 90.0) && !turned_alike(2.0, 178.0));
    assert_eq!(hits[0].row, 0, "{hits:?}");
}
