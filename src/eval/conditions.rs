//! Real-world conditions applied to a raw query scan (sensor frame, metres, z up) before any
//! method's own preprocessing: what a revisit meets that the TopoRec paper's perturbations
//! leave out. Each is seeded (by the scan id and the evaluation's seed) and deterministic.
//!
//! | name | what |
//! |---|---|
//! | `as-recorded` | the scan as stored (`eval places` then uses the stored descriptors) |
//! | `yaw`, `yaw=DEG` | the scan turned about the sensor's z axis by a random angle, or by DEG |
//! | `occlusion=DEG` | the returns of a sector DEG wide (default 90) removed, at a random azimuth: a truck beside the car |
//! | `drop=F` | a fraction F (default 0.5) of the returns removed at random |
//! | `beams=N` | only N beams kept, evenly among the sensor's rings (a sensor with fewer beams); needs ring ids |
//! | `offset=M` | the sensor M metres (default 3) to the left: every point moved by −M in y; the pose is not changed |
//! | `max-range=M` | returns farther than M metres (horizontally; default 40) removed |
//! | `paper` | the TopoRec paper's set, each on the raw scan: jitter, scale ×1.05 and ×0.95, translation (0.2, 0.2, 0.1), turns by 45°, 90°, 135° — lengths in units of the scan's normalization scale |
//!
//! `paper` expands to its seven perturbations (named `paper: jitter`, …).

use super::Perturbation;
use crate::rng::SplitMix64;
use crate::types::Point;

/// One condition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Condition {
    /// The scan as stored.
    AsRecorded,
    /// Turned about z: by a random angle (`None`) or by these degrees.
    Yaw(Option<f64>),
    /// A sector this many degrees wide removed at a random azimuth.
    Occlusion(f64),
    /// This fraction of the returns removed at random.
    Drop(f64),
    /// This many beams kept.
    Beams(u16),
    /// The sensor this many metres to the left (points moved by −M in y).
    Offset(f64),
    /// Returns beyond this horizontal range removed.
    MaxRange(f64),
    /// Driving the other way this many metres over: the sensor moved this far to the left,
    /// then turned by 180° (a revisit in the opposite lane).
    Reverse(f64),
    /// One of the paper's perturbations, on the raw scan.
    Paper(Perturbation),
}

/// A condition that cannot be applied to a scan (beam decimation of a scan without ring ids).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct NotApplicable(pub String);

impl Condition {
    /// Parses a `--condition` value; `paper` gives the paper's seven.
    pub fn parse(text: &str) -> Result<Vec<Condition>, String> {
        let (name, value) = match text.split_once('=') {
            Some((n, v)) => (n.trim(), Some(v.trim())),
            None => (text.trim(), None),
        };
        let number = |default: f64, lo: f64, hi: f64, unit: &str| -> Result<f64, String> {
            let v = match value {
                None => default,
                Some(v) => v.parse::<f64>().map_err(|_| format!("{name}={v}: not a number"))?,
            };
            if v.is_finite() && v >= lo && v <= hi {
                Ok(v)
            } else {
                Err(format!("{name}={v}: must be in [{lo}, {hi}]{unit}"))
            }
        };
        let one = match name {
            "as-recorded" if value.is_none() => Condition::AsRecorded,
            "yaw" => match value {
                None => Condition::Yaw(None),
                Some(_) => Condition::Yaw(Some(number(0.0, -360.0, 360.0, " degrees")?)),
            },
            "occlusion" => Condition::Occlusion(number(90.0, 0.0, 360.0, " degrees")?),
            "drop" => Condition::Drop(number(0.5, 0.0, 0.99, "")?),
            "beams" => {
                let n = number(16.0, 1.0, 1024.0, " beams")?;
                if n.fract() != 0.0 {
                    return Err(format!("beams={n}: a whole number of beams"));
                }
                Condition::Beams(n as u16)
            }
            "offset" => Condition::Offset(number(3.0, -100.0, 100.0, " m")?),
            "max-range" => Condition::MaxRange(number(40.0, 0.1, 10_000.0, " m")?),
            "reverse" => Condition::Reverse(number(3.5, -100.0, 100.0, " m")?),
            "paper" if value.is_none() => {
                let all = Perturbation::paper().into_iter().filter(|p| *p != Perturbation::Original);
                return Ok(all.map(Condition::Paper).collect());
            }
            _ => {
                return Err(format!(
                    "unknown condition `{text}` (as-recorded, yaw[=DEG], occlusion[=DEG], drop[=F], beams[=N], offset[=M], max-range[=M], reverse[=M], paper)"
                ));
            }
        };
        Ok(vec![one])
    }

    /// Its name in reports (`occlusion 90°`, `paper: jitter`, …).
    pub fn name(&self) -> String {
        match self {
            Condition::AsRecorded => "as recorded".into(),
            Condition::Yaw(None) => "random yaw".into(),
            Condition::Yaw(Some(d)) => format!("yaw {d}°"),
            Condition::Occlusion(d) => format!("occlusion {d}°"),
            Condition::Drop(f) => format!("drop {}%", f * 100.0),
            Condition::Beams(n) => format!("{n} beams"),
            Condition::Offset(m) => format!("offset {m} m"),
            Condition::MaxRange(m) => format!("max range {m} m"),
            Condition::Reverse(m) => format!("reverse, {m} m over"),
            Condition::Paper(p) => format!("paper: {}", p.name()),
        }
    }

    /// Its label in tables: [`Condition::name`], and for the paper's translation its mean
    /// length in metres (`mean_unit`: the queries' mean normalization scale), so that
    /// `(0.2, 0.2, 0.1)` in units of the scale does not read as 20 cm.
    pub fn label(&self, mean_unit: Option<f64>) -> String {
        match (self, mean_unit) {
            (Condition::Paper(Perturbation::Translate(t)), Some(unit)) => {
                let length = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt() * unit;
                format!("{} × scale (mean {length:.1} m)", self.name())
            }
            _ => self.name(),
        }
    }

    /// Applies it to a raw scan: `points` with their ring ids (when the source has them),
    /// seeded by `seed`; `unit` is the scan's normalization scale (for the paper's lengths).
    pub fn apply(
        &self,
        points: &[Point],
        rings: Option<&[u16]>,
        seed: u64,
        unit: f64,
    ) -> Result<Vec<Point>, NotApplicable> {
        let mut rng = SplitMix64(seed ^ 0x636f_6e64);
        let keep = |f: &dyn Fn(usize, &Point) -> bool| -> Vec<Point> {
            points.iter().enumerate().filter(|(i, p)| f(*i, p)).map(|(_, p)| *p).collect()
        };
        Ok(match *self {
            Condition::AsRecorded => points.to_vec(),
            Condition::Yaw(angle) => {
                let deg = angle.unwrap_or_else(|| rng.next_f64() * 360.0);
                Perturbation::Rotate(deg).apply(points, seed)
            }
            Condition::Occlusion(width) => {
                let start = rng.next_f64() * 360.0;
                keep(&|_, p| (p[1].atan2(p[0]).to_degrees() - start).rem_euclid(360.0) >= width)
            }
            Condition::Drop(fraction) => {
                let dropped: Vec<bool> = points.iter().map(|_| rng.next_f64() < fraction).collect();
                keep(&|i, _| !dropped[i])
            }
            Condition::Beams(n) => {
                let Some(rings) = rings else {
                    return Err(NotApplicable("the scan has no ring ids".into()));
                };
                // The rings present, in order of elevation (ring ids need not be: an HDL-32E's
                // interleave), each at the mean elevation of its returns.
                let ids = rings.iter().copied().max().map_or(0, |m| m as usize + 1);
                let mut elevation = vec![(0.0f64, 0usize); ids];
                for (p, &r) in points.iter().zip(rings) {
                    let e = &mut elevation[r as usize];
                    e.0 += p[2].atan2(p[0].hypot(p[1]));
                    e.1 += 1;
                }
                let mut present: Vec<(f64, usize)> = (0..ids)
                    .filter(|&r| elevation[r].1 > 0)
                    .map(|r| (elevation[r].0 / elevation[r].1 as f64, r))
                    .collect();
                present.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                let beams = present.len();
                if (n as usize) > beams {
                    return Err(NotApplicable(format!("the scan has {beams} beams, not {n}")));
                }
                // The beams of elevation rank ⌊k · beams / n⌋, k = 0..n: evenly spread, the
                // lowest kept.
                let mut kept = vec![false; ids];
                for k in 0..n as usize {
                    kept[present[(k * beams) / n as usize].1] = true;
                }
                keep(&|i, _| kept[rings[i] as usize])
            }
            Condition::Offset(m) => points.iter().map(|p| [p[0], p[1] - m, p[2]]).collect(),
            Condition::MaxRange(m) => keep(&|_, p| p[0].hypot(p[1]) <= m),
            // A half turn is exact: (x, y) -> (-x, -y).
            Condition::Reverse(m) => points.iter().map(|p| [-p[0], m - p[1], p[2]]).collect(),
            Condition::Paper(p) => p.apply_in(points, seed, unit),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ring of points every degree at 10 m, on 4 beams (ring id = index mod 4).
    fn cloud() -> (Vec<Point>, Vec<u16>) {
        let pts: Vec<Point> = (0..360)
            .map(|d| {
                let a = (d as f64 + 0.5).to_radians();
                [10.0 * a.cos(), 10.0 * a.sin(), (d % 4) as f64]
            })
            .collect();
        let rings = (0..360).map(|d| (d % 4) as u16).collect();
        (pts, rings)
    }

    #[test]
    fn the_removed_sector_is_empty_and_only_it() {
        let (pts, rings) = cloud();
        let out = Condition::Occlusion(90.0).apply(&pts, Some(&rings), 11, 1.0).unwrap();
        assert_eq!(out.len(), 270, "a quarter of the returns, one a degree");
        let mut azimuths: Vec<f64> =
            out.iter().map(|p| p[1].atan2(p[0]).to_degrees().rem_euclid(360.0)).collect();
        azimuths.sort_by(f64::total_cmp);
        // The widest gap between kept azimuths (wrapping) is the hidden sector: 90° + 1°.
        let mut gaps: Vec<f64> = azimuths.windows(2).map(|w| w[1] - w[0]).collect();
        gaps.push(azimuths[0] + 360.0 - azimuths[azimuths.len() - 1]);
        let widest = gaps.iter().copied().fold(0.0, f64::max);
        assert!((widest - 91.0).abs() < 1e-9, "widest gap {widest}");
        assert_eq!(gaps.iter().filter(|&&g| g > 1.5).count(), 1, "one gap");
        // Seeded: the same seed hides the same sector, another seed another one.
        assert_eq!(out, Condition::Occlusion(90.0).apply(&pts, None, 11, 1.0).unwrap());
        assert_ne!(out, Condition::Occlusion(90.0).apply(&pts, None, 12, 1.0).unwrap());
    }

    #[test]
    fn the_offset_moves_the_origin() {
        let (pts, _) = cloud();
        let out = Condition::Offset(3.0).apply(&pts, None, 0, 1.0).unwrap();
        // The ring was centred on the sensor; now on (0, -3): the sensor sits 3 m to its left.
        let centre = out.iter().fold([0.0, 0.0], |c, p| [c[0] + p[0] / 360.0, c[1] + p[1] / 360.0]);
        assert!(centre[0].abs() < 1e-9 && (centre[1] + 3.0).abs() < 1e-9, "{centre:?}");
        for (a, b) in pts.iter().zip(&out) {
            assert_eq!([a[0], a[1] - 3.0, a[2]], *b);
        }
    }

    #[test]
    fn reverse_moves_the_sensor_a_lane_over_and_turns_it_round() {
        let (pts, _) = cloud();
        assert_eq!(Condition::parse("reverse"), Ok(vec![Condition::Reverse(3.5)]));
        let out = Condition::Reverse(3.5).apply(&pts, None, 0, 1.0).unwrap();
        // A point ahead (+x) is now behind; the ring, centred on the old sensor, is centred
        // 3.5 m to the new sensor's left (its +y): the lane it came along.
        for (a, b) in pts.iter().zip(&out) {
            assert_eq!([-a[0], 3.5 - a[1], a[2]], *b);
        }
        let centre = out.iter().fold([0.0, 0.0], |c, p| [c[0] + p[0] / 360.0, c[1] + p[1] / 360.0]);
        assert!(centre[0].abs() < 1e-9 && (centre[1] - 3.5).abs() < 1e-9, "{centre:?}");
    }

    #[test]
    fn decimation_keeps_the_right_rings() {
        let (pts, rings) = cloud();
        let two = Condition::Beams(2).apply(&pts, Some(&rings), 0, 1.0).unwrap();
        assert_eq!(two.len(), 180);
        assert!(two.iter().all(|p| p[2] == 0.0 || p[2] == 2.0), "rings 0 and 2 (z = ring id here)");
        let one = Condition::Beams(1).apply(&pts, Some(&rings), 0, 1.0).unwrap();
        assert!(one.iter().all(|p| p[2] == 0.0) && one.len() == 90);
        assert_eq!(Condition::Beams(4).apply(&pts, Some(&rings), 0, 1.0).unwrap(), pts);
        assert!(Condition::Beams(8).apply(&pts, Some(&rings), 0, 1.0).is_err(), "more beams than the sensor");
        assert!(Condition::Beams(2).apply(&pts, None, 0, 1.0).is_err(), "no ring ids");
    }

    #[test]
    fn drop_range_and_yaw_do_what_they_say() {
        let (pts, _) = cloud();
        let half = Condition::Drop(0.5).apply(&pts, None, 5, 1.0).unwrap();
        assert!((150..=210).contains(&half.len()), "{} kept of 360", half.len());
        assert!(half.iter().all(|p| pts.contains(p)));
        let near: Vec<Point> =
            pts.iter().map(|p| [p[0] * 0.5, p[1] * 0.5, p[2]]).chain(pts.clone()).collect();
        assert_eq!(Condition::MaxRange(6.0).apply(&near, None, 0, 1.0).unwrap().len(), 360);
        let turned = Condition::Yaw(Some(90.0)).apply(&pts, None, 0, 1.0).unwrap();
        assert!((turned[0][0] + pts[0][1]).abs() < 1e-12 && (turned[0][1] - pts[0][0]).abs() < 1e-12);
        let a = Condition::Yaw(None).apply(&pts, None, 1, 1.0).unwrap();
        assert_eq!(a, Condition::Yaw(None).apply(&pts, None, 1, 1.0).unwrap(), "seeded");
        assert_ne!(a, Condition::Yaw(None).apply(&pts, None, 2, 1.0).unwrap());
    }

    #[test]
    fn names_parse_and_bad_values_are_refused() {
        assert_eq!(Condition::parse("occlusion").unwrap(), vec![Condition::Occlusion(90.0)]);
        assert_eq!(Condition::parse("beams=16").unwrap(), vec![Condition::Beams(16)]);
        assert_eq!(Condition::parse("yaw=30").unwrap(), vec![Condition::Yaw(Some(30.0))]);
        assert_eq!(Condition::parse("paper").unwrap().len(), 7);
        for bad in ["drop=1.5", "beams=2.5", "offset=x", "nonsense", "as-recorded=3"] {
            assert!(Condition::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_papers_translation_is_labelled_in_metres() {
        let paper = Condition::parse("paper").unwrap();
        let translate = paper.iter().find(|c| c.name().contains("translate")).unwrap();
        // |(0.2, 0.2, 0.1)| = 0.3 units; scans of scale 52 m on average: 15.6 m.
        assert_eq!(translate.label(Some(52.0)), "paper: translate (0.2, 0.2, 0.1) × scale (mean 15.6 m)");
        assert_eq!(translate.label(None), translate.name());
        assert_eq!(Condition::Occlusion(90.0).label(Some(52.0)), "occlusion 90°");
    }
}
