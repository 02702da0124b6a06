//! toporec-plus on real KITTI scans (yaw: turned scans find themselves, exactly for quarter
//! turns), determinism across thread counts, and the conditions and loop-closure report of
//! `eval places` through the binary.

use crate::util::*;
use std::path::{Path, PathBuf};
use toporec::homology::Point;
use toporec::methods::toporec_plus::{self, PlusParams, Searcher};

/// The 48 shared KITTI scans, by path.
fn kitti_scans(data: &Path) -> Vec<(PathBuf, Vec<Point>)> {
    let mut files: Vec<PathBuf> = (0..11)
        .flat_map(|s| {
            let dir = data.join(format!("kitti/sequences/{s:02}/velodyne"));
            std::fs::read_dir(dir).unwrap().flatten().map(|e| e.path())
        })
        .collect();
    files.sort();
    files.into_iter().map(|f| (f.clone(), read_cloud(&f))).collect()
}

/// Turned about z by `degrees` (counter-clockwise); quarter turns exactly.
fn turned(points: &[Point], degrees: f64) -> Vec<Point> {
    match degrees as i64 {
        0 => points.to_vec(),
        90 => points.iter().map(|&[x, y, z]| [-y, x, z]).collect(),
        180 => points.iter().map(|&[x, y, z]| [-x, -y, z]).collect(),
        270 => points.iter().map(|&[x, y, z]| [y, -x, z]).collect(),
        _ => {
            let (s, c) = degrees.to_radians().sin_cos();
            points.iter().map(|&[x, y, z]| [c * x - s * y, s * x + c * y, z]).collect()
        }
    }
}

#[test]
fn turned_kitti_scans_find_themselves_at_twelve_angles() {
    let Some(data) = shared_data("turned_kitti_scans_find_themselves_at_twelve_angles") else { return };
    let p = PlusParams::default();
    let scans = kitti_scans(&data);
    assert_eq!(scans.len(), 48);
    let descriptors: Vec<f32> =
        scans.iter().flat_map(|(_, c)| toporec_plus::describe(c, &p).unwrap()).collect();
    let searcher = Searcher::new(descriptors, p.clone());
    // Four scans of different sequences, each turned by 0°, 30°, …, 330°.
    for &i in &[0usize, 13, 27, 45] {
        let (path, cloud) = &scans[i];
        for step in 0..12 {
            let angle = 30.0 * step as f64;
            let q = toporec_plus::describe(&turned(cloud, angle), &p).unwrap();
            let (hits, _) = searcher.search(&q, 3);
            assert_eq!(
                hits[0].row,
                i,
                "{} turned by {angle}°: top-1 is row {} ({hits:?})",
                path.display(),
                hits[0].row
            );
            // The yaw estimate: within a sixth of a sector (2°) plus a sector's rounding.
            let yaw = hits[0].yaw_degrees.unwrap();
            let off = (yaw - angle).rem_euclid(360.0).min((angle - yaw).rem_euclid(360.0));
            assert!(off <= 6.0, "{} turned by {angle}°: yaw {yaw}", path.display());
            if step % 3 == 0 {
                // A quarter turn maps the voxel grid and the polar grid onto themselves: the
                // descriptor is the original's shifted by 15 sectors, and the distance 0.
                assert!(
                    hits[0].distance.abs() <= 1e-9,
                    "{} turned by {angle}°: distance {}",
                    path.display(),
                    hits[0].distance
                );
                assert_eq!(yaw, angle, "{} turned by {angle}°", path.display());
            }
        }
    }
}

#[test]
fn descriptors_and_evaluation_do_not_depend_on_the_thread_count() {
    let Some(_) = shared_data("descriptors_and_evaluation_do_not_depend_on_the_thread_count") else { return };
    let dir = scratch_dir("toporec_plus_threads");
    let pipeline = root().join("pipelines/kitti.toml");
    let mut tables = Vec::new();
    let mut reports = Vec::new();
    for threads in [1usize, 2] {
        let index = dir.join(format!("index-{threads}"));
        let o = run_pipeline(&pipeline, &index, threads);
        assert!(o.status.success(), "{}", text(&o.stderr));
        let reader = toporec::sinks::index::IndexReader::open(&index).unwrap();
        let mut rows = reader.descriptors_of("toporec-plus", &[], None).unwrap();
        rows.sort_by(|a, b| a.scan_id.cmp(&b.scan_id));
        tables.push(rows.into_iter().map(|r| (r.scan_id, r.descriptor)).collect::<Vec<_>>());
        let out = dir.join(format!("eval-{threads}"));
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_toporec"))
            .env("RAYON_NUM_THREADS", threads.to_string())
            .args([
                "eval",
                "places",
                "--db",
                index.to_str().unwrap(),
                "--within-session",
                "--thresholds",
                "10",
            ])
            .args(["--method", "toporec-plus", "--db-scan", "*/000000", "--db-scan", "*/000006"])
            .args(["--query-scan", "*/000003", "--query-scan", "*/000009", "--condition", "occlusion"])
            .args(["--condition", "drop", "-o", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        let mut report = read_json(&out.join("report.json"));
        for c in report["methods"][0]["conditions"].as_array_mut().unwrap() {
            c.as_object_mut().unwrap().remove("timing_ms");
        }
        reports.push(report["methods"][0]["conditions"].clone());
    }
    assert_eq!(tables[0].len(), 48);
    assert!(tables[0] == tables[1], "the same descriptors with 1 and 2 threads");
    assert_eq!(reports[0], reports[1], "the same conditions, rankings and metrics with 1 and 2 threads");
}

#[test]
fn eval_places_reports_conditions_nearest_and_loop_closure_for_every_method() {
    let dir = scratch_dir("eval_conditions");
    let index = dir.join("index");
    let o = run_pipeline(&root().join("pipelines/compare.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = dir.join("eval");
    let o = eval_days(
        &index,
        &out,
        &[
            "--thresholds",
            "5,10",
            "--condition",
            "as-recorded",
            "--condition",
            "occlusion=90",
            "--condition",
            "beams=16",
        ],
    );
    assert!(o.status.success(), "{}", text(&o.stderr));
    let table = text(&o.stdout);
    assert!(table.contains("summary: R@1"), "{table}");
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["conditions"], serde_json::json!(["as recorded", "occlusion 90°", "16 beams"]));
    let methods = report["methods"].as_array().unwrap();
    let names: Vec<&str> = methods.iter().map(|m| m["method"].as_str().unwrap()).collect();
    assert_eq!(names, COMPARED);
    for m in methods {
        let conditions = m["conditions"].as_array().unwrap();
        assert_eq!(conditions.len(), 3);
        // As recorded is the stored descriptors: its results are the method's top-level ones.
        assert_eq!(conditions[0]["results"], m["results"]);
        for c in conditions {
            assert_eq!(c["queries"], 32, "{}", m["method"]);
            let nearest = c["nearest"]["recall_at_1"].as_f64().unwrap();
            assert!((0.0..=100.0).contains(&nearest));
            let lc = &c["loop_closure"]["result"];
            assert!(lc["f1_max"].as_f64().unwrap() <= 100.0);
            assert!(!lc["curve"].as_array().unwrap().is_empty());
            assert_eq!(c["top1"]["rows"].as_array().unwrap().len(), 32);
        }
    }
    // The sample's simulated HDL-32E has ring ids: 16 beams apply; an occluded query lacks a
    // quarter of the view, which toporec-plus leaves out of its comparison.
    let plus = &methods[names.iter().position(|n| *n == "toporec-plus").unwrap()]["conditions"];
    assert!(plus[2]["not_applicable"].is_null());
    let r1 = |c: &serde_json::Value| c["results"][0]["with_match"]["at_n"][0].as_f64().unwrap();
    assert!(r1(&plus[1]) >= 50.0, "toporec-plus under occlusion: {}", r1(&plus[1]));
    for f in ["precision_recall.png", "precision_recall.svg", "recall_at_n.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // Bad conditions are refused with the value named.
    let o = eval_days(&index, &dir.join("bad"), &["--condition", "drop=2"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("drop=2"), "{}", text(&o.stderr));
}

#[test]
fn query_answers_with_toporec_plus_and_its_yaw() {
    let dir = scratch_dir("query_plus");
    let index = dir.join("index");
    let o = run_pipeline(&root().join("pipelines/compare.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let scan = root().join("samples/town/velodyne_data/2026-01-01/velodyne_sync");
    let first = std::fs::read_dir(&scan).unwrap().flatten().map(|e| e.path()).min().unwrap();
    let o = toporec(&[
        "query",
        "--index",
        index.to_str().unwrap(),
        "--method",
        "toporec-plus",
        "-k",
        "2",
        first.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!(row[2], format!("2026-01-01/{}", first.file_stem().unwrap().to_string_lossy()), "{out}");
    assert_eq!(row[4].parse::<f64>().unwrap(), 0.0, "itself at distance 0: {out}");
    assert_eq!(row[8], "0.0", "yaw 0: {out}");
}

#[test]
fn the_search_structure_is_cached_in_the_index_and_rebuilt_after_a_commit() {
    // toporec-plus alone on the sample drive: its first query builds the searcher and caches it
    // in INDEX/searchers/; the next queries map it (and answer alike); a commit makes it stale.
    let dir = scratch_dir("plus_search_cache");
    let data = sample_copy(&dir, &["2026-01-01", "2026-01-02"]);
    let body = format!(
        "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n[descriptors]\nmethods = [\"toporec-plus\"]\n",
        data.join("velodyne_data").display().to_string()
    );
    let pipeline = dir.join("plus.toml");
    std::fs::write(&pipeline, body).unwrap();
    let index = dir.join("idx");
    assert!(run_pipeline(&pipeline, &index, 2).status.success());
    let cache = index.join("searchers/toporec-plus.searcher");
    let query = |extra: &[&str]| {
        let day2 = data.join("velodyne_data/2026-01-02");
        let mut args = vec!["query", "--index", index.to_str().unwrap(), "--method", "toporec-plus"];
        args.extend([day2.to_str().unwrap(), "-k", "3"]);
        args.extend(extra);
        let o = toporec(&args);
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
    };
    assert!(!cache.exists());
    let built = query(&[]);
    assert!(cache.is_file(), "the first query caches the searcher");
    let generation = |i: &Path| read_json(&i.join("manifest.json"))["generation"].as_u64().unwrap();
    let header = toporec::sinks::index::searchers::header(&cache).unwrap();
    assert_eq!((header.rows, header.generation), (64, generation(&index)));
    let stamp = std::fs::metadata(&cache).unwrap().modified().unwrap();
    assert_eq!(query(&[]), built, "the mapped searcher answers as the built one");
    assert_eq!(std::fs::metadata(&cache).unwrap().modified().unwrap(), stamp, "not rebuilt");
    // One session only: a copy of its rows, the same answers as a searcher built on them.
    let one = query(&["--session", "2026-01-01"]);
    assert!(one.lines().skip(1).all(|l| l.contains(",2026-01-01,")), "{one}");
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(
        text(&o.stdout).contains("search cache of toporec-plus (64 rows), current"),
        "{}",
        text(&o.stdout)
    );
    // A commit (a scan pruned) makes the cache stale: verify says so, the next query rebuilds.
    let gone = std::fs::read_dir(data.join("velodyne_data/2026-01-01/velodyne_sync"))
        .unwrap()
        .flatten()
        .next()
        .unwrap();
    std::fs::remove_file(gone.path()).unwrap();
    let o = toporec(&[
        "run",
        pipeline.to_str().unwrap(),
        "--index",
        index.to_str().unwrap(),
        "--prune",
        "--no-progress",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(text(&o.stdout).contains("stale, rebuilt by the next query"), "{}", text(&o.stdout));
    let after = query(&[]);
    let header = toporec::sinks::index::searchers::header(&cache).unwrap();
    assert_eq!((header.rows, header.generation), (63, generation(&index)));
    assert_ne!(after, built);
    // A cache that is not one is rebuilt, not trusted.
    std::fs::write(&cache, b"garbage").unwrap();
    assert_eq!(query(&[]), after);
    assert_eq!(toporec::sinks::index::searchers::header(&cache).unwrap().rows, 63);
}

/// The cache at its edges: entries spanning several of its 8 MB checksum blocks, a count that
/// is not a multiple of the first-values block (4), and entries as long as the method's
/// descriptor (its sector rows and its image). Written and mapped through the index's own
/// functions, it answers exactly as the searcher in memory.
/// The byte offset of the body of the cache at `path`.
fn cached_body_offset(path: &std::path::Path) -> usize {
    toporec::sinks::index::searchers::header(path).unwrap().body.0
}

#[test]
fn a_cache_of_several_blocks_answers_as_the_searcher_in_memory() {
    use toporec::methods::Computed;
    use toporec::rng::SplitMix64;
    use toporec::simulate::{self, SimParams, scene::Scene};
    use toporec::sinks::index::searchers;
    let p = PlusParams::default();
    let sim = SimParams::default();
    let scene = Scene::town(&sim.town, sim.seed, 0);
    let described: Vec<Vec<f32>> = (0..8)
        .map(|i| {
            let s = simulate::scan(&sim, &scene, 0, i * 5, &mut scene.mailbox());
            let points: Vec<Point> = s.points.iter().map(|q| q.map(|c| c as f64)).collect();
            toporec_plus::describe(&points, &p).unwrap()
        })
        .collect();
    // Copies noised by ±10 % (the byte codes stay in 1..=255, empty cells empty).
    let n = 3_503;
    let mut rng = SplitMix64(11);
    let mut db = Vec::with_capacity(n * p.len());
    for i in 0..n {
        for &v in &described[i % described.len()] {
            let w = v as f64 * (0.9 + 0.2 * rng.next_f64());
            db.push(if v > 0.0 { w.round().clamp(1.0, 255.0) as f32 } else { 0.0 });
        }
    }
    let queries: Vec<Vec<f32>> =
        (0..12).map(|i| db[i * 281 * p.len()..(i * 281 + 1) * p.len()].to_vec()).collect();
    let in_memory = Searcher::new(db, p.clone());
    let dir = scratch_dir("plus_cache_blocks");
    let path = dir.join("toporec-plus.searcher");
    let rows: Vec<toporec::sinks::index::IndexedScan> = (0..n)
        .map(|i| toporec::sinks::index::IndexedScan {
            scan_id: format!("s/{i:05}"),
            session: "s".into(),
            utime: Some(i as i64),
            pose: None,
            descriptor: Vec::new(),
            codebook_id: "test".into(),
        })
        .collect();
    let header = searchers::Header::new(
        1,
        "toporec-plus",
        "test",
        serde_json::json!({}),
        toporec_plus::SEARCHER_LAYOUT,
        n,
    );
    searchers::write(&path, &header, &rows, &in_memory.bytes()).unwrap();
    let searchers::Opened::Current(cached) = searchers::open(&path, 1, "test", toporec_plus::SEARCHER_LAYOUT)
    else {
        panic!("a current cache")
    };
    assert!(cached.header.checksums.body.len() >= 2, "several checksum blocks");
    let mapped = Searcher::mapped(cached.body, cached.header.rows, p.clone()).unwrap();
    for q in &queries {
        assert_eq!(mapped.search(q, 10).0, in_memory.search(q, 10).0);
    }
    assert_eq!(mapped.damage(), None);
    // The body's blocks are checked as a search reads them: a flipped code in the columns of
    // the first query's own entry passes the open and is found by the search that re-ranks it.
    let (_, columns) =
        toporec_plus::body_sections(n, &p).into_iter().find(|(name, _)| *name == "columns").unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[cached_body_offset(&path) + columns.start + 17] ^= 0x40;
    let damaged = dir.join("damaged.searcher");
    std::fs::write(&damaged, &bytes).unwrap();
    let searchers::Opened::Current(cached) =
        searchers::open(&damaged, 1, "test", toporec_plus::SEARCHER_LAYOUT)
    else {
        panic!("the open reads the header and rows only")
    };
    let mapped = Searcher::mapped(cached.body, n, p.clone()).unwrap();
    assert_eq!(mapped.damage(), None, "nothing read yet");
    mapped.search(&queries[0], 10);
    let why = mapped.damage().expect("the search read the damaged block");
    assert!(why.starts_with("body block 1 of "), "{why}");
    // Values that are not whole entries are refused at once, not read shifted.
    let short = vec![0.0f32; 2 * p.len() - 1];
    let refused = std::panic::catch_unwind(|| Searcher::new(short, p.clone()));
    assert!(refused.is_err());
}

#[test]
fn a_damaged_search_cache_never_answers() {
    // Every way a cache file can be wrong: the answers are a fresh build's, the query warns
    // naming the file, and `verify` reports it (damage as a problem, exit 1; another version's
    // file as a stale one) before the query rebuilds it.
    let dir = scratch_dir("plus_damaged_cache");
    let data = sample_copy(&dir, &["2026-01-01", "2026-01-02"]);
    let body = format!(
        "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n[descriptors]\nmethods = [\"toporec-plus\"]\n",
        data.join("velodyne_data").display().to_string()
    );
    let pipeline = dir.join("plus.toml");
    std::fs::write(&pipeline, body).unwrap();
    let index = dir.join("idx");
    assert!(run_pipeline(&pipeline, &index, 2).status.success());
    let cache = index.join("searchers/toporec-plus.searcher");
    let day2 = data.join("velodyne_data/2026-01-02");
    let query = || {
        let args = ["query", "--index", index.to_str().unwrap(), "--method", "toporec-plus"];
        let o = toporec(&[&args[..], &[day2.to_str().unwrap(), "-k", "3"]].concat());
        assert!(o.status.success(), "{}", text(&o.stderr));
        (text(&o.stdout), text(&o.stderr))
    };
    let (fresh, quiet) = query();
    assert!(!quiet.contains("WARN"), "a fresh build warns of nothing: {quiet}");
    let good = std::fs::read(&cache).unwrap();
    let header = toporec::sinks::index::searchers::header(&cache).unwrap();
    let (offset, size) = header.body;
    let header_len = u64::from_le_bytes(good[16..24].try_into().unwrap()) as usize;
    // Each case: the file's bytes, and whether verify calls it damaged (else stale).
    let mut cases: Vec<(String, Vec<u8>, bool)> = Vec::new();
    let mut scattered = good.clone();
    let mut rng = toporec::rng::SplitMix64(1);
    for _ in 0..200 {
        let j = good.len() / 3 + (rng.next_u64() as usize) % (good.len() - good.len() / 3);
        scattered[j] ^= 0xFF;
    }
    cases.push(("200 bytes flipped past the first third".into(), scattered, true));
    let flipped = |at: usize| {
        let mut b = good.clone();
        b[at] ^= 0x01;
        b
    };
    cases.push(("the header".into(), flipped(24 + header_len / 2), true));
    cases.push(("the header's checksum".into(), flipped(24 + header_len + 3), true));
    cases.push(("the rows".into(), flipped(24 + header_len + 8 + 5), true));
    cases.push(("the padding before the body".into(), flipped(offset - 1), true));
    for (name, range) in toporec_plus::body_sections(header.rows, &PlusParams::default()) {
        cases.push((format!("the body's {name}"), flipped(offset + (range.start + range.end) / 2), true));
    }
    assert_eq!(offset + size, good.len());
    cases.push(("cut short".into(), good[..good.len() / 2].to_vec(), true));
    cases.push(("empty".into(), Vec::new(), true));
    let other = String::from_utf8_lossy(&good[24..24 + header_len])
        .replace("\"format_version\":2", "\"format_version\":1");
    let mut older = good.clone();
    older[24..24 + header_len].copy_from_slice(other.as_bytes());
    cases.push(("of another format version".into(), older, false));
    for (what, bytes, damaged) in cases {
        std::fs::write(&cache, &bytes).unwrap();
        let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
        let report = text(&o.stdout);
        if damaged {
            assert_eq!(o.status.code(), Some(1), "{what}: {report}");
            assert!(
                report.contains("searchers/toporec-plus.searcher: damaged search cache"),
                "{what}: {report}"
            );
        } else {
            assert!(o.status.success(), "{what}: {report}");
            assert!(report.contains("made by another version of toporec"), "{what}: {report}");
        }
        let (answers, warnings) = query();
        assert_eq!(answers, fresh, "{what}: the answers of a fresh build");
        assert!(
            warnings.contains(&cache.display().to_string()),
            "{what}: the warning names the file: {warnings}"
        );
        assert!(warnings.contains("rebuilding it"), "{what}: {warnings}");
        assert_eq!(std::fs::read(&cache).unwrap(), good, "{what}: rebuilt as it was");
        let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
        assert!(o.status.success(), "{what}, rebuilt: {}", text(&o.stdout));
    }
}

#[test]
fn an_index_made_before_the_lateral_views_were_the_default_keeps_its_settings() {
    // What an index of the defaults without views holds is what every index of toporec-plus
    // held before the views were the default: its settings without `lateral`, the id
    // d3e7c12ff2bdef57 (measured on such an index). It keeps them, and their threshold; its
    // pipeline file, run again, names the two ways on; `run --full` moves it to the default.
    let dir = scratch_dir("plus_old_default");
    let data = sample_copy(&dir, &["2026-01-01", "2026-01-02"]);
    let pipeline = dir.join("plus.toml");
    let body = |section: &str| {
        format!(
            "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n[descriptors]\nmethods = [\"toporec-plus\"]\n{section}",
            data.join("velodyne_data").display().to_string()
        )
    };
    std::fs::write(&pipeline, body("[toporec-plus]\nlateral = []\n")).unwrap();
    let index = dir.join("idx");
    assert!(run_pipeline(&pipeline, &index, 2).status.success());
    let entry = &read_json(&index.join("manifest.json"))["methods"]["toporec-plus"];
    assert_eq!(entry["id"], "d3e7c12ff2bdef57", "{entry}");
    assert!(entry["params"].get("lateral").is_none(), "{entry}");
    let method = toporec::loops::detector::method_of_index(&index, "toporec-plus").unwrap();
    assert_eq!(method, toporec::Method::of(PlusParams::plain()));
    assert_eq!(toporec::loops::default_threshold(&method), Some(0.3619));
    let info = |index: &Path| {
        let o = toporec(&["info", "--index", index.to_str().unwrap()]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
    };
    let shown = info(&index);
    assert!(shown.contains("loop threshold 0.3619") && shown.contains("\"lateral\":[]"), "{shown}");

    // The pipeline file without the section: the default now looks sideways. Refused, exit 2,
    // naming both ways on; the index unchanged.
    std::fs::write(&pipeline, body("")).unwrap();
    let before = std::fs::read(index.join("manifest.json")).unwrap();
    let o = run_pipeline(&pipeline, &index, 2);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("`lateral = []`") && err.contains("`lateral = [3.0]`") && err.contains("run --full"),
        "{err}"
    );
    assert_eq!(std::fs::read(index.join("manifest.json")).unwrap(), before);

    // Moved to the default with one command.
    let o = toporec(&["run", "--full", pipeline.to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let shown = info(&index);
    assert!(shown.contains("loop threshold 0.3289") && shown.contains("\"lateral\":[3.0]"), "{shown}");
    let method = toporec::loops::detector::method_of_index(&index, "toporec-plus").unwrap();
    assert_eq!(method, toporec::Method::of(PlusParams::default()));
}
