//! The index never loses or invents data, whatever a hostile but realistic user does: a bad
//! input file, a byte flipped in a committed file, a folder that is not an index, a kill at any
//! named point of a commit (the `fault-injection` feature, which the test build turns on), a
//! rebuild or a compaction killed midway, a reader racing a writer.

use crate::util::*;
use std::collections::BTreeSet;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// What a glob of the table folders sees: every `*.parquet` file under them (relative paths).
fn globbed(index: &Path) -> BTreeSet<String> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeSet<String>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(root, &p, out);
            } else if p.extension().is_some_and(|x| x == "parquet") {
                out.insert(p.strip_prefix(root).unwrap().display().to_string());
            }
        }
    }
    let mut out = BTreeSet::new();
    for table in ["scans", "diagrams", "descriptors"] {
        walk(index, &index.join(table), &mut out);
    }
    out
}

/// The files the manifest on disk names.
fn named(index: &Path) -> BTreeSet<String> {
    let m = read_json(&index.join("manifest.json"));
    m["files"].as_array().unwrap().iter().map(|f| f["path"].as_str().unwrap().to_string()).collect()
}

/// The files in the staging folder.
fn staged(index: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(index.join(".staging")) else { return Vec::new() };
    entries.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect()
}

/// `toporec args` with `TOPOREC_FAULT=point`: asserts that the process reached the point and
/// was killed there (SIGKILL, no clean-up).
fn killed_at(args: &[&str], point: &str) -> Output {
    let o =
        Command::new(env!("CARGO_BIN_EXE_toporec")).args(args).env("TOPOREC_FAULT", point).output().unwrap();
    let name = point.split('@').next().unwrap();
    let err = text(&o.stderr);
    assert!(
        err.contains(&format!("fault injection: killed at {name}")),
        "{args:?} never reached {point}: {err}"
    );
    assert_eq!(o.status.signal(), Some(9), "{args:?}: killed at {point}");
    o
}

/// The sample drive's small pipeline (512 points, codebook of 8) over a copy in `dir`.
fn small_sample(dir: &Path) -> PathBuf {
    let data = sample_copy(dir, &["2026-01-01", "2026-01-02"]);
    let p = sample_pipeline(dir, &data, 512);
    let text = std::fs::read_to_string(&p).unwrap().replace("b = 50 ", "b = 8 ");
    std::fs::write(&p, text).unwrap();
    p
}

/// `toporec run` into `index` with extra flags.
fn run(pipeline: &Path, index: &Path, extra: &[&str]) -> Output {
    let mut args =
        vec!["run", pipeline.to_str().unwrap(), "--index", index.to_str().unwrap(), "--no-progress"];
    args.extend_from_slice(extra);
    toporec(&args)
}

fn verify(index: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["verify", "--index", index.to_str().unwrap()];
    args.extend_from_slice(extra);
    toporec(&args)
}

fn assert_ok(o: &Output, what: &str) {
    assert!(o.status.success(), "{what}: {}{}", text(&o.stdout), text(&o.stderr));
}

/// Every table's committed rows.
fn all_rows(index: &Path) -> Vec<Vec<String>> {
    ["scans", "diagrams", "descriptors"].iter().map(|t| rows(index, t)).collect()
}

#[test]
fn an_unreadable_mcap_is_one_error_row_and_its_scans_are_never_pruned() {
    let dir = scratch_dir("integrity_mcap");
    let o = toporec(&[
        "simulate",
        "-o",
        dir.join("sim2").to_str().unwrap(),
        "--format",
        "mcap",
        "--sessions",
        "1",
        "--scans",
        "20",
        "--sensor",
        "vlp16",
        "--azimuth-res",
        "2",
    ]);
    assert_ok(&o, "simulate");
    let good = dir.join("good.mcap");
    std::fs::copy(dir.join("sim2/mcap/2026-01-01.mcap"), &good).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let tiny = dir.join("tiny.mcap");
    std::fs::write(&tiny, &bytes[..100]).unwrap();
    let pipeline = |name: &str, files: &[&Path]| {
        let files: Vec<String> = files.iter().map(|f| format!("{:?}", f.display().to_string())).collect();
        let body = format!(
            "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"mcap\"\nfiles = [{}]\n\
             [preprocess]\nsubsample = 512\nnormalize = true\nmin_points = 16\n[vectorize]\nb = 8\n",
            files.join(", ")
        );
        let p = dir.join(name);
        std::fs::write(&p, body).unwrap();
        p
    };
    let only_good = pipeline("good.toml", &[&good]);
    let both = pipeline("both.toml", &[&good, &tiny]);
    let index = dir.join("idx");
    assert_ok(&run(&only_good, &index, &[]), "good.mcap alone");

    // The bad file is one error row naming it; the good file's 20 scans stay, none pruned.
    let o = run(&both, &index, &["--prune"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("scans: 21 read, 20 indexed, 0 skipped, 1 errors"), "{err}");
    assert!(err.contains("20 up to date, 1 added, 0 replaced, 0 pruned"), "{err}");
    let scans = toporec::sinks::index::IndexReader::open(&index).unwrap().scans().unwrap();
    let errors: Vec<_> = scans.iter().filter(|s| s.error.is_some()).collect();
    assert_eq!((scans.len(), errors.len()), (21, 1));
    assert_eq!(errors[0].scan_id, "tiny/tiny.mcap");
    assert!(errors[0].error.as_deref().unwrap().contains("tiny.mcap"), "{:?}", errors[0].error);

    // Into a new index: the good file is indexed, a codebook fitted, exit 1 (partial).
    let o = run(&both, &dir.join("fresh"), &[]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("20 indexed"), "{}", text(&o.stderr));

    // The good file unreadable now: its scans are not reached, and `--prune` keeps them.
    std::fs::write(&good, &bytes[..100]).unwrap();
    let o = run(&only_good, &index, &["--prune"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    // (The one scan pruned is tiny.mcap's error row: that file is no longer in the pipeline.)
    assert!(err.contains("0 up to date, 1 added, 0 replaced, 1 pruned"), "{err}");
    assert!(err.contains("20 indexed scans belong to inputs that could not be read: kept"), "{err}");
    let ok = toporec::sinks::index::IndexReader::open(&index).unwrap().scans().unwrap();
    assert_eq!(ok.iter().filter(|s| s.error.is_none()).count(), 20, "the 20 scans are kept");
    assert_ok(&verify(&index, &[]), "verify");

    // A file taken out of the pipeline is gone: its scans are pruned.
    std::fs::write(&good, &bytes).unwrap();
    let o = run(&pipeline("tiny.toml", &[&tiny]), &index, &["--prune"]);
    assert!(
        text(&o.stderr).contains("21 pruned") || text(&o.stderr).contains("20 pruned"),
        "{}",
        text(&o.stderr)
    );
}

/// Changes `toporec.version`'s value in a Parquet file's footer: the file still parses, and its
/// bytes no longer match the checksum its commit recorded.
fn flip_a_byte(path: &Path) {
    let mut bytes = std::fs::read(path).unwrap();
    let key = b"toporec.version";
    let at = bytes.windows(key.len()).rposition(|w| w == key).expect("the key in the footer");
    let value = at + key.len() + bytes[at + key.len()..].iter().position(|&b| b == b'0').unwrap();
    bytes[value] = b'9';
    std::fs::write(path, bytes).unwrap();
    let f = std::fs::File::open(path).unwrap();
    assert!(
        parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f).is_ok(),
        "still parses"
    );
}

#[test]
fn rewrites_refuse_a_file_changed_after_its_commit() {
    let dir = scratch_dir("integrity_checksums");
    let pipeline = small_sample(&dir);
    let index = dir.join("idx");
    assert_ok(&run(&pipeline, &index, &["--commit-every", "8"]), "run");
    let part = |table: &str| -> PathBuf {
        let files = toporec::sinks::index::IndexReader::open(&index).unwrap().files(table).unwrap();
        files.into_iter().find(|(s, _)| s == "2026-01-01").unwrap().1
    };
    let descriptors = part("descriptors");
    flip_a_byte(&descriptors);
    let manifest = std::fs::read_to_string(index.join("manifest.json")).unwrap();
    let o = verify(&index, &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stdout).contains("checksum"), "{}", text(&o.stdout));
    // compact: refused, naming the file; nothing rewritten, the damage still found.
    let o = toporec(&["compact", "--index", index.to_str().unwrap()]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains(descriptors.to_str().unwrap()) && err.contains("changed after it was committed"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(index.join("manifest.json")).unwrap(), manifest);
    assert_eq!(verify(&index, &[]).status.code(), Some(1), "the damage is still found");
    // A run that replaces a scan of that session rewrites the file: refused too.
    let bins = dir.join("town/velodyne_data/2026-01-01/velodyne_sync");
    let first = std::fs::read_dir(&bins).unwrap().flatten().map(|e| e.path()).min().unwrap();
    let mut scan = std::fs::read(&first).unwrap();
    scan[0] ^= 1;
    std::fs::write(&first, scan).unwrap();
    let o = run(&pipeline, &index, &[]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("changed after it was committed"), "{}", text(&o.stderr));
    assert_eq!(std::fs::read_to_string(index.join("manifest.json")).unwrap(), manifest);
    // revectorize reads every diagrams file: a damaged one is refused.
    let index2 = dir.join("idx2");
    assert_ok(&run(&pipeline, &index2, &["--commit-every", "8"]), "run");
    let files = toporec::sinks::index::IndexReader::open(&index2).unwrap().files("diagrams").unwrap();
    flip_a_byte(&files[0].1);
    let o = toporec(&["revectorize", "--index", index2.to_str().unwrap(), "-b", "4"]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains(files[0].1.to_str().unwrap()) && err.contains("changed after it was committed"),
        "{err}"
    );
}

#[test]
fn writers_touch_only_their_own_files() {
    let dir = scratch_dir("integrity_foreign");
    let pipeline = small_sample(&dir);
    // A folder that holds something and no index is refused, untouched.
    let mine = dir.join("notindex");
    std::fs::create_dir_all(mine.join("scans/session=x")).unwrap();
    std::fs::create_dir_all(mine.join("diagrams")).unwrap();
    std::fs::write(mine.join("scans/session=x/mine.parquet"), b"my data").unwrap();
    std::fs::write(mine.join("diagrams/notes.csv"), b"a,b\n").unwrap();
    let o = run(&pipeline, &mine, &[]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("not empty and not a toporec index") && err.contains("diagrams/, scans/"), "{err}");
    assert_eq!(std::fs::read(mine.join("scans/session=x/mine.parquet")).unwrap(), b"my data");
    assert!(mine.join("diagrams/notes.csv").is_file());
    assert!(!mine.join("manifest.json").exists() && !mine.join(".lock").exists());

    // Inside an index: foreign files stay and are listed; toporec-named orphans are problems
    // (what a glob would see) until a writer removes them.
    let index = dir.join("idx");
    assert_ok(&run(&pipeline, &index, &[]), "run");
    let foreign = ["diagrams/notes.csv", "scans/session=2026-01-01/mine.parquet", "README.txt"];
    for f in foreign {
        std::fs::write(index.join(f), f.as_bytes()).unwrap();
    }
    let orphan = index.join("scans/session=2026-01-01/part-999999.parquet");
    std::fs::copy(part_file(&index, "scans", "2026-01-01"), &orphan).unwrap();
    std::fs::create_dir_all(index.join(".staging")).unwrap();
    std::fs::write(index.join(".staging/part-999998.staged"), b"x").unwrap();
    let o = verify(&index, &[]);
    let out = text(&o.stdout);
    assert_eq!(o.status.code(), Some(1), "{out}");
    assert!(out.contains("problem: scans/session=2026-01-01/part-999999.parquet: not committed"), "{out}");
    assert!(out.contains("note: .staging/part-999998.staged: not committed"), "{out}");
    for f in foreign {
        assert!(out.contains(&format!("note: {f}: foreign")), "{f}: {out}");
    }
    assert_ok(&verify(&index, &["--allow-orphans"]), "verify --allow-orphans");
    assert_ok(&run(&pipeline, &index, &[]), "run");
    assert!(!orphan.exists() && staged(&index).is_empty(), "the writer removed its own kind of orphans");
    for f in foreign {
        assert_eq!(std::fs::read(index.join(f)).unwrap(), f.as_bytes(), "{f} untouched");
    }
    let o = verify(&index, &[]);
    assert_ok(&o, "verify");
    assert!(text(&o.stdout).contains("note: README.txt: foreign"), "{}", text(&o.stdout));
}

#[test]
fn a_kill_at_any_commit_point_shows_a_glob_only_committed_rows() {
    let dir = scratch_dir("integrity_commit_points");
    let pipeline = small_sample(&dir);
    let reference = dir.join("reference");
    assert_ok(&run(&pipeline, &reference, &["--commit-every", "8"]), "reference run");
    let expected = all_rows(&reference);
    let args = |index: &Path| -> Vec<String> {
        [
            "run",
            pipeline.to_str().unwrap(),
            "--index",
            index.to_str().unwrap(),
            "--no-progress",
            "--commit-every",
            "8",
        ]
        .map(String::from)
        .to_vec()
    };
    for point in ["after-staging@3", "after-manifest@3", "mid-renames@3"] {
        let index = dir.join(point.replace('@', "-"));
        let a = args(&index);
        killed_at(&a.iter().map(String::as_str).collect::<Vec<_>>(), point);
        let (on_disk, committed) = (globbed(&index), named(&index));
        // A glob never sees a file no commit names.
        assert!(
            on_disk.is_subset(&committed),
            "{point}: uncommitted files visible: {:?}",
            on_disk.difference(&committed)
        );
        let missing = committed.len() - on_disk.len();
        match point {
            "after-staging@3" => assert_eq!(missing, 0, "{point}: the last commit stands whole"),
            _ => assert!(missing > 0 && !staged(&index).is_empty(), "{point}: the commit is half done"),
        }
        // The next reader completes the commit (here `info --files`, which lists it).
        let o = toporec(&["info", "--index", index.to_str().unwrap(), "--files"]);
        assert_ok(&o, "info --files");
        let listed: BTreeSet<String> = text(&o.stdout)
            .lines()
            .map(|l| {
                Path::new(l).strip_prefix(std::path::absolute(&index).unwrap()).unwrap().display().to_string()
            })
            .collect();
        assert_eq!(listed, committed, "{point}: info --files lists the committed generation");
        assert_eq!(globbed(&index), committed, "{point}: completed by the reader");
        assert_ok(&verify(&index, &[]), point);
        // The next run resumes to the uninterrupted run's rows, with nothing left staged.
        assert_ok(&run(&pipeline, &index, &["--commit-every", "8"]), "resumed run");
        assert!(
            all_rows(&index) == expected,
            "{point}: the resumed index differs from the uninterrupted one"
        );
        assert!(staged(&index).is_empty(), "{point}");
    }
}

#[test]
fn a_killed_rebuild_leaves_the_old_index_whole() {
    let dir = scratch_dir("integrity_full");
    let pipeline = small_sample(&dir);
    let index = dir.join("idx");
    assert_ok(&run(&pipeline, &index, &["--commit-every", "8"]), "run");
    let before = all_rows(&index);
    let manifest = std::fs::read(index.join("manifest.json")).unwrap();
    let idx = index.to_str().unwrap();
    let p = pipeline.to_str().unwrap();
    killed_at(&["run", p, "--index", idx, "--full", "--commit-every", "8", "--no-progress"], "full-mid@2");
    assert_eq!(
        std::fs::read(index.join("manifest.json")).unwrap(),
        manifest,
        "the old generation is the committed one"
    );
    assert!(!staged(&index).is_empty(), "the rebuild's chunks were staged");
    assert_eq!(globbed(&index), named(&index));
    assert_ok(&verify(&index, &["--allow-orphans"]), "verify");
    assert!(all_rows(&index) == before, "readers see the old index whole");
    let session = dir.join("town/velodyne_data/2026-01-02");
    let o = toporec(&["query", "--index", idx, session.to_str().unwrap(), "-k", "1"]);
    assert_ok(&o, "query");
    // A plain run cleans the rebuild away and finds everything up to date.
    let o = run(&pipeline, &index, &[]);
    assert_ok(&o, "run");
    assert!(text(&o.stderr).contains("64 up to date"), "{}", text(&o.stderr));
    assert!(staged(&index).is_empty());
    // An uninterrupted rebuild switches in one commit to the same content.
    let o = run(&pipeline, &index, &["--full", "--commit-every", "8"]);
    assert_ok(&o, "run --full");
    assert!(text(&o.stderr).contains("64 added"), "{}", text(&o.stderr));
    assert!(all_rows(&index) == before, "the rebuilt index holds the same rows");
    assert_ok(&verify(&index, &[]), "verify");
}

#[test]
fn compact_and_revectorize_survive_kills_and_refuse_a_second_writer() {
    let dir = scratch_dir("integrity_maintenance");
    let pipeline = small_sample(&dir);
    let index = dir.join("idx");
    let idx = index.to_str().unwrap();
    assert_ok(&run(&pipeline, &index, &["--commit-every", "8"]), "run");
    let before = all_rows(&index);
    let parts = named(&index).len();
    assert!(parts > 6, "{parts} part files");
    // compact, killed before its commit: the index is as it was.
    killed_at(&["compact", "--index", idx], "compact-mid");
    assert_eq!(named(&index).len(), parts);
    assert_ok(&verify(&index, &[]), "verify after a killed compact");
    // compact, killed after its manifest: a glob sees the old files, the next reader the new.
    let old = named(&index);
    killed_at(&["compact", "--index", idx], "after-manifest");
    assert_eq!(globbed(&index), old, "a glob sees the old generation whole");
    assert_eq!(verify(&index, &[]).status.code(), Some(1), "verify reports the superseded files");
    assert_ok(&toporec(&["info", "--index", idx]), "a reader completes the compaction");
    assert_ok(&verify(&index, &[]), "verify");
    assert_eq!(named(&index).len(), 6, "one file per partition");
    assert_eq!(globbed(&index), named(&index));
    assert!(all_rows(&index) == before, "compaction keeps every row");
    // revectorize, killed midway: the old codebook and descriptors stand.
    let codebook = read_json(&index.join("manifest.json"))["codebook_id"].clone();
    for point in ["revectorize-mid", "after-staging"] {
        killed_at(&["revectorize", "--index", idx, "-b", "4"], point);
        assert_eq!(read_json(&index.join("manifest.json"))["codebook_id"], codebook, "{point}");
        assert_ok(&verify(&index, &["--allow-orphans"]), point);
        assert!(all_rows(&index) == before, "{point}");
    }
    let o = toporec(&["revectorize", "--index", idx, "-b", "4"]);
    assert_ok(&o, "revectorize");
    let m = read_json(&index.join("manifest.json"));
    assert!(m["codebook_id"] != codebook && m["descriptor_length"] == 4, "{m}");
    assert_ok(&verify(&index, &[]), "verify after revectorize");
    // A second writer is refused at once while one holds the index (a rebuild, slowed down).
    let mut first = Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args([
            "run",
            pipeline.to_str().unwrap(),
            "--index",
            idx,
            "--full",
            "--commit-every",
            "8",
            "--no-progress",
        ])
        .env("TOPOREC_COMMIT_PAUSE_MS", "300")
        .spawn()
        .unwrap();
    let lock = index.join(".lock");
    let start = std::time::Instant::now();
    while !std::fs::read_to_string(&lock).is_ok_and(|t| t.contains(&format!("pid {} ", first.id()))) {
        assert!(start.elapsed().as_secs() < 20, "the first writer never took the lock");
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    for args in [vec!["compact", "--index", idx], vec!["revectorize", "--index", idx, "-b", "4"]] {
        let o = toporec(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o.stderr));
        assert!(text(&o.stderr).contains("is locked by pid"), "{}", text(&o.stderr));
    }
    assert!(first.wait().unwrap().success());
    assert_ok(&verify(&index, &[]), "verify");
}

#[test]
fn a_read_that_meets_a_newer_generation_starts_over() {
    let dir = scratch_dir("integrity_read_retry");
    let pipeline = small_sample(&dir);
    let index = dir.join("idx");
    assert_ok(&run(&pipeline, &index, &["--commit-every", "8"]), "run");
    let mut attempts = 0;
    let rows = toporec::sinks::index::IndexReader::read_consistent(&index, |reader| {
        attempts += 1;
        if attempts == 1 {
            // A writer commits between this reader's manifest and its reads: every file it
            // named is replaced.
            assert_ok(&toporec(&["compact", "--index", index.to_str().unwrap()]), "compact");
        }
        let (_, batches) = reader.table("scans", None)?;
        Ok(batches.iter().map(|b| b.num_rows()).sum::<usize>())
    })
    .unwrap();
    assert_eq!((attempts, rows), (2, 64), "the read started over on the newer generation");
}

#[test]
fn errors_name_the_table_and_the_file_at_fault() {
    use arrow::array::{Float64Array, RecordBatch, StringArray, UInt8Array};
    use std::sync::Arc;
    let dir = scratch_dir("integrity_error_names");
    let write = |path: &Path, batch: RecordBatch| {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        let f = std::fs::File::create(path).unwrap();
        let mut w = parquet::arrow::ArrowWriter::try_new(f, batch.schema(), None).unwrap();
        w.write(&batch).unwrap();
        w.close().unwrap();
    };
    // A foreign file among descriptors: the error says descriptors, not diagrams.
    let foreign = dir.join("x/descriptors/method=toporec/session=s/part-000033.parquet");
    let other = RecordBatch::try_from_iter([("a", Arc::new(Float64Array::from(vec![1.0])) as _)]).unwrap();
    write(&foreign, other);
    let e = toporec::sinks::index::reader::scan_ids(&foreign).unwrap_err().to_string();
    assert!(
        e.contains("part-000033.parquet") && e.contains("no column `scan_id` in this `descriptors` table"),
        "{e}"
    );

    // compact meeting a foreign diagrams file (its manifest entry made to match): the error
    // names that file, not the merged file being written.
    let pipeline = small_sample(&dir);
    let index = dir.join("idx");
    assert_ok(&run(&pipeline, &index, &["--commit-every", "8"]), "run");
    let files = toporec::sinks::index::IndexReader::open(&index).unwrap().files("diagrams").unwrap();
    let target = &files[1].1;
    let batch = RecordBatch::try_from_iter([
        ("scan_id", Arc::new(StringArray::from(vec!["a"])) as _),
        ("dim", Arc::new(UInt8Array::from(vec![0u8])) as _),
        ("birth", Arc::new(StringArray::from(vec!["zero"])) as _),
        ("death", Arc::new(Float64Array::from(vec![1.0])) as _),
    ])
    .unwrap();
    write(target, batch);
    let (bytes, xxh3) = toporec::sinks::index::manifest::file_checksum(target).unwrap();
    let manifest_path = index.join("manifest.json");
    let mut m = read_json(&manifest_path);
    let rel = target.strip_prefix(&index).unwrap().display().to_string();
    for f in m["files"].as_array_mut().unwrap() {
        if f["path"] == rel.as_str() {
            f["bytes"] = bytes.into();
            f["xxh3"] = xxh3.clone().into();
        }
    }
    std::fs::write(&manifest_path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    let o = toporec(&["compact", "--index", index.to_str().unwrap()]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains(target.to_str().unwrap()) && err.contains("birth"), "{err}");
    assert!(!err.contains(".staging"), "{err}");
}

#[test]
fn toporec_plus_scans_it_cannot_describe_are_error_rows() {
    let dir = scratch_dir("integrity_plus_errors");
    let data = sample_copy(&dir, &["2026-01-01"]);
    // A radius inside the ego vehicle's shadow: no scan has a return within it.
    let body = format!(
        "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [{:?}]\n\
         [descriptors]\nmethods = [\"toporec-plus\"]\n[toporec-plus]\nmax_radius = 0.5\nlateral = []\n",
        data.join("velodyne_data").display().to_string()
    );
    let p = dir.join("plus.toml");
    std::fs::write(&p, body).unwrap();
    let index = dir.join("idx");
    let o = Command::new(env!("CARGO_BIN_EXE_toporec"))
        .args(["run", p.to_str().unwrap(), "--index", index.to_str().unwrap(), "--no-progress"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let reader = toporec::sinks::index::IndexReader::open(&index).unwrap();
    let scans = reader.scans().unwrap();
    assert_eq!(scans.len(), 32);
    for s in &scans {
        assert_eq!(s.status, toporec::sinks::parquet::Status::Error, "{}", s.scan_id);
        let e = s.error.as_deref().unwrap();
        assert!(e.contains("(toporec-plus)") && e.contains("no return within 0.5 m of the sensor"), "{e}");
    }
    assert!(reader.descriptors_of("toporec-plus", &[], None).unwrap().is_empty(), "no zero vectors stored");
}

#[test]
fn test_hooks_live_behind_the_fault_injection_feature() {
    // The product reads no TOPOREC_* variable of its own but in src/fault.rs, which compiles
    // them out of a build without the feature (.ci/run runs the release binary with
    // TOPOREC_FAULT set, and it finishes).
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            if e.path().is_dir() {
                walk(&e.path(), out);
            } else if e.path().extension().is_some_and(|x| x == "rs") {
                out.push(e.path());
            }
        }
    }
    let mut files = Vec::new();
    walk(&root().join("src"), &mut files);
    for f in files.iter().filter(|f| !f.ends_with("fault.rs")) {
        let text = std::fs::read_to_string(f).unwrap();
        for hook in ["TOPOREC_FAULT", "TOPOREC_COMMIT_PAUSE_MS", "TOPOREC_CELL_LIMIT"] {
            let reads = text.lines().any(|l| l.contains(hook) && l.contains("env::var"));
            assert!(!reads, "{}: reads {hook} outside src/fault.rs", f.display());
        }
    }
    // The test build has the fault points (the dev-dependency on this crate turns them on).
    const _: () = assert!(toporec::FAULT_INJECTION);
}
