//! The index as an incremental, crash-safe store, on the built binary: up-to-date scans are
//! not recomputed, changed ones replace their rows, a killed run resumes from its last
//! commit, one writer at a time, and `verify` catches damage.

use crate::util::*;
use std::collections::BTreeMap;
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Every file under the table folders, with its bytes.
fn table_bytes(index: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    fn walk(dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for e in entries.flatten() {
            if e.file_type().unwrap().is_dir() {
                walk(&e.path(), out);
            } else {
                out.insert(e.path(), std::fs::read(e.path()).unwrap());
            }
        }
    }
    for table in ["scans", "diagrams", "descriptors"] {
        walk(&index.join(table), &mut out);
    }
    out
}

#[test]
fn a_second_run_computes_nothing_and_changes_no_byte() {
    let dir = scratch_dir("incremental_second_run");
    let index = dir.join("index");
    let (o, first) = run_with(&root().join("pipelines/sample.toml"), &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(counter(&first, "computed"), 64);
    let before = table_bytes(&index);
    let manifest = std::fs::read(index.join("manifest.json")).unwrap();
    let (o, second) = run_with(&root().join("pipelines/sample.toml"), &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!((counter(&second, "computed"), counter(&second, "up_to_date")), (0, 64));
    assert_eq!(second["cpu_seconds"]["persistence"].as_f64(), Some(0.0), "no persistence computed");
    assert_eq!(table_bytes(&index), before, "byte-identical tables");
    assert_eq!(std::fs::read(index.join("manifest.json")).unwrap(), manifest, "no commit");

    // A lone file of the index, queried by its path, finds itself at distance 0.
    let file = root().join("samples/town/velodyne_data/2026-01-02/velodyne_sync/1767348000000000.bin");
    let o = toporec(&["query", "--index", index.to_str().unwrap(), file.to_str().unwrap(), "-k", "1"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    let row: Vec<&str> = out.lines().nth(1).unwrap().split(',').collect();
    assert_eq!((row[1], row[2], row[4]), ("1", "2026-01-02/1767348000000000", "0.0"), "{out}");
}

#[test]
fn new_sessions_and_changed_files_compute_only_themselves() {
    let dir = scratch_dir("incremental_changes");
    let index = dir.join("index");
    let data = sample_copy(&dir, &["2026-01-01"]);
    let pipeline = sample_pipeline(&dir, &data, 1024);
    let (o, s) = run_with(&pipeline, &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(counter(&s, "added"), 32);

    // A new session: only its 32 scans are computed.
    sample_copy(&dir, &["2026-01-02"]);
    let (o, s) = run_with(&pipeline, &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let c = |k| counter(&s, k);
    assert_eq!((c("up_to_date"), c("added"), c("replaced"), c("computed")), (32, 32, 0, 32));

    // One file's bytes change (a point moves 5 mm): only that scan is recomputed, its rows
    // replaced.
    let file = data.join("velodyne_data/2026-01-02/velodyne_sync/1767348001000000.bin");
    let mut bytes = std::fs::read(&file).unwrap();
    bytes[0] = bytes[0].wrapping_add(1);
    std::fs::write(&file, &bytes).unwrap();
    let (o, s) = run_with(&pipeline, &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let c = |k| counter(&s, k);
    assert_eq!((c("up_to_date"), c("added"), c("replaced"), c("computed")), (63, 0, 1, 1));
    let scans = rows(&index, "scans");
    assert_eq!(scans.len(), 64, "the replaced scan has one row");
    let fingerprint = toporec::fingerprint::hex(toporec::fingerprint::of_bytes(&bytes));
    assert!(scans.iter().any(|r| r.contains("2026-01-02/1767348001000000") && r.contains(&fingerprint)));
    assert_eq!(rows(&index, "descriptors").len(), 64);
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));

    // A file gone: reported and kept, then removed with --prune.
    std::fs::remove_file(&file).unwrap();
    let (o, s) = run_with(&pipeline, &index, &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!((counter(&s, "not_in_sources"), counter(&s, "pruned")), (1, 0));
    assert!(
        text(&o.stderr).contains("1 indexed scans are not in this run's sources: kept"),
        "{}",
        text(&o.stderr)
    );
    assert_eq!(rows(&index, "scans").len(), 64);
    let (o, s) = run_with(&pipeline, &index, &["--prune"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(counter(&s, "pruned"), 1);
    for (table, n) in [("scans", 63), ("descriptors", 63)] {
        assert_eq!(rows(&index, table).len(), n, "{table}");
    }
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));

    // Other preprocessing: refused, then rebuilt with --full.
    let other = sample_pipeline(&dir, &data, 512);
    let (o, _) = run_with(&other, &index, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("other preprocess or persistence settings"), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("--full"), "{}", text(&o.stderr));
    assert_eq!(rows(&index, "scans").len(), 63, "nothing changed");
    let (o, s) = run_with(&other, &index, &["--full"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!((counter(&s, "computed"), counter(&s, "added")), (63, 63));
}

#[test]
fn one_writer_at_a_time() {
    let dir = scratch_dir("incremental_lock");
    let index = dir.join("index");
    let pipeline = root().join("pipelines/sample.toml");
    // The first writer commits slowly (a pause before each manifest).
    let mut first = Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args(["run", pipeline.to_str().unwrap(), "--index", index.to_str().unwrap(), "--no-progress"])
        .args(["--commit-every", "8"])
        .env("TOPOREC_COMMIT_PAUSE_MS", "300")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lock = index.join(".lock");
    let start = std::time::Instant::now();
    while std::fs::read_to_string(&lock).map_or(true, |t| t.is_empty()) {
        assert!(start.elapsed().as_secs() < 20, "the first writer never took the lock");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let o = run_pipeline(&pipeline, &index, 1);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let expected = format!("error: index {} is locked by pid {} (host ", index.display(), first.id());
    assert!(err.starts_with(&expected) && err.contains(") since 20"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    let status = first.wait().unwrap();
    assert!(status.success(), "the first writer is unaffected");
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stdout));
    // The lock went with its process: the next writer runs.
    assert!(run_pipeline(&pipeline, &index, 1).status.success());
}

#[test]
fn verify_catches_damage() {
    let dir = scratch_dir("incremental_verify");
    let index = dir.join("index");
    assert!(run_pipeline(&root().join("pipelines/sample.toml"), &index, 2).status.success());
    let verify = |idx: &Path| toporec(&["verify", "--index", idx.to_str().unwrap()]);
    let o = verify(&index);
    assert!(o.status.success(), "{}", text(&o.stdout));
    assert!(text(&o.stdout).contains("ok: 6 files, 64 scans"), "{}", text(&o.stdout));
    let copy = |name: &str| {
        let to = dir.join(name);
        assert!(
            Command::new("cp")
                .args(["-r", index.to_str().unwrap(), to.to_str().unwrap()])
                .status()
                .unwrap()
                .success()
        );
        to
    };
    let part = |idx: &Path, table: &str| part_file(idx, table, "2026-01-01");

    let truncated = copy("truncated");
    let f = part(&truncated, "diagrams");
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() / 2]).unwrap();
    let o = verify(&truncated);
    assert_eq!(o.status.code(), Some(1));
    let out = text(&o.stdout);
    assert!(out.contains("bytes, checksum") && out.contains("the manifest says"), "{out}");
    assert!(out.contains("toporec repair --index"), "{out}");

    let deleted = copy("deleted");
    std::fs::remove_file(part(&deleted, "descriptors")).unwrap();
    let o = verify(&deleted);
    assert_eq!(o.status.code(), Some(1));
    let out = text(&o.stdout);
    // The missing part is the problem, said once (not once per scan it held).
    assert!(out.contains(": missing") && !out.contains("ok, but no row in descriptors"), "{out}");

    let miscounted = copy("miscounted");
    let path = miscounted.join("manifest.json");
    let mut m: serde_json::Value = read_json(&path);
    let entry = m["files"].as_array_mut().unwrap().iter_mut().find(|f| f["table"] == "scans").unwrap();
    entry["rows"] = serde_json::json!(entry["rows"].as_u64().unwrap() + 1);
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    let o = verify(&miscounted);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stdout).contains("32 rows, the manifest says 33"), "{}", text(&o.stdout));
}

#[test]
fn killed_runs_resume_and_end_equal_to_an_uninterrupted_run() {
    let dir = scratch_dir("incremental_crash");
    let data = dir.join("data");
    let o = toporec(&[
        "simulate",
        "-o",
        data.to_str().unwrap(),
        "--sessions",
        "3",
        "--scans",
        "220",
        "--sensor",
        "vlp16",
        "--azimuth-res",
        "1",
        "--seed",
        "5",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let pipeline = dir.join("p.toml");
    let body = format!(
        "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n[preprocess]\nsubsample = 512\nnormalize = true\n[vectorize]\nb = 8\n",
        data.join("velodyne_data").display().to_string()
    );
    std::fs::write(&pipeline, body).unwrap();
    const CHUNK: u64 = 40;
    let chunk = CHUNK.to_string();
    let reference = dir.join("reference");
    let (o, _) = run_with(&pipeline, &reference, &["--commit-every", &chunk]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(rows(&reference, "scans").len(), 660);

    let index = dir.join("killed");
    let committed = |idx: &Path| -> u64 {
        std::fs::read_to_string(idx.join("manifest.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|m| m["counts"]["scans"].as_u64())
            .unwrap_or(0)
    };
    let mut rng = toporec::rng::SplitMix64(2026);
    let mut kills = 0;
    for attempt in 0..12 {
        let during_commit = attempt % 2 == 1;
        let before = committed(&index);
        let mut child = Command::new(env!("CARGO_BIN_EXE_toporec"))
            .args(["run", pipeline.to_str().unwrap(), "--index", index.to_str().unwrap(), "--no-progress"])
            .args(["--commit-every", &chunk, "--log-level", "toporec=debug", "-t", "1"])
            .env("TOPOREC_COMMIT_PAUSE_MS", if during_commit { "150" } else { "0" })
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stderr = child.stderr.take().unwrap();
        // Counts the rows the run wrote; signals each commit it publishes.
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let lines = std::thread::spawn(move || {
            let mut written = 0u64;
            for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
                written += line.contains("row added to the open chunk") as u64;
                if line.contains("publishing a chunk") {
                    let _ = tx.send(());
                }
            }
            written
        });
        let how = if during_commit {
            // Inside a commit: files published, the manifest not yet replaced.
            let skip = rng.below(3);
            let mut seen = 0;
            loop {
                match rx.recv_timeout(std::time::Duration::from_secs(20)) {
                    Ok(()) if seen == skip => break "during a commit",
                    Ok(()) => seen += 1,
                    Err(_) => break "no commit seen",
                }
            }
        } else {
            std::thread::sleep(std::time::Duration::from_millis(100 + rng.below(500) as u64));
            "at a random moment"
        };
        let finished = child.try_wait().unwrap().is_some();
        // SIGKILL: no chance to clean up.
        let _ = child.kill();
        let status = child.wait().unwrap();
        let written = lines.join().unwrap();
        if finished || status.success() {
            println!("attempt {attempt}: the run finished before the kill");
            break;
        }
        kills += 1;
        let after = committed(&index);
        let lost = written.saturating_sub(after - before);
        println!(
            "kill {kills} ({how}): {written} rows written, {} committed, {lost} lost (chunk {CHUNK})",
            after - before
        );
        assert!(lost <= CHUNK, "kill {kills}: {lost} rows lost, more than one chunk");
        // Every Parquet file on disk reads.
        for (path, _) in table_bytes(&index) {
            if path.extension().is_some_and(|e| e == "parquet") {
                let f = std::fs::File::open(&path).unwrap();
                let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f)
                    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                reader.build().unwrap().for_each(|b| drop(b.unwrap()));
            }
        }
        if kills >= 6 && committed(&index) >= 600 {
            break;
        }
    }
    assert!(kills >= 5, "only {kills} kills landed");
    // The last run resumes and finishes.
    let (o, s) = run_with(&pipeline, &index, &["--commit-every", &chunk]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    println!("resumed: {} up to date, {} computed", counter(&s, "up_to_date"), counter(&s, "computed"));
    for table in ["scans", "diagrams", "descriptors"] {
        let (a, b) = (rows(&index, table), rows(&reference, table));
        assert_eq!(a.len(), b.len(), "{table}: row count");
        assert!(a == b, "{table}: the resumed index differs from the uninterrupted one");
    }
    let o = toporec(&["verify", "--index", index.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stdout));
}

#[test]
fn manifest_json_schema_matches_a_real_manifest() {
    let dir = scratch_dir("incremental_manifest_schema");
    let index = dir.join("index");
    assert!(run_pipeline(&root().join("pipelines/sample.toml"), &index, 2).status.success());
    let manifest: serde_json::Value = read_json(&index.join("manifest.json"));
    let schema: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root().join("schemas/manifest.json")).unwrap())
            .unwrap();
    let keys = |v: &serde_json::Value| {
        let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
        k.sort();
        k
    };
    let required = |v: &serde_json::Value| {
        let mut k: Vec<String> =
            v["required"].as_array().unwrap().iter().map(|x| x.as_str().unwrap().to_string()).collect();
        k.sort();
        k
    };
    // Every property is required but `methods` (only when the index has other methods) and
    // `poses` (only when its sources give poses: the sample's ground truth does).
    let mut with_poses = required(&schema);
    with_poses.push("poses".into());
    with_poses.sort();
    assert_eq!(keys(&manifest), with_poses, "top-level keys");
    let mut optional = with_poses;
    optional.push("methods".into());
    optional.sort();
    assert_eq!(keys(&schema["properties"]), optional);
    assert_eq!(
        keys(&manifest["poses"][0]),
        ["file", "file_xxh3", "origin", "poses_xxh3", "scans", "sessions", "with_pose"],
        "pose origins"
    );
    assert_eq!(keys(&manifest["counts"]), required(&schema["properties"]["counts"]), "counts");
    assert_eq!(
        keys(&manifest["files"][0]),
        required(&schema["properties"]["files"]["items"]),
        "file entries"
    );
    assert_eq!(manifest["manifest_version"], schema["properties"]["manifest_version"]["const"]);
    // The method kinds are the registry's computed methods and `imported`.
    let kinds: Vec<String> =
        schema["properties"]["methods"]["additionalProperties"]["properties"]["kind"]["enum"]
            .as_array()
            .unwrap()
            .iter()
            .map(|k| k.as_str().unwrap().to_string())
            .collect();
    let mut registered: Vec<String> =
        toporec::methods::computed_names().iter().map(|n| n.to_string()).collect();
    registered.push("imported".into());
    assert_eq!(kinds, registered, "schemas/manifest.json method kinds");
    // And a real JSON Schema validator agrees, where one is installed.
    if python_with("manifest JSON Schema validation", &["jsonschema"]) {
        let script = format!(
            "import json, jsonschema; jsonschema.validate(json.load(open({:?})), json.load(open({:?})))",
            index.join("manifest.json").display().to_string(),
            root().join("schemas/manifest.json").display().to_string()
        );
        let o = Command::new("python3").args(["-c", &script]).output().unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
    }
}
