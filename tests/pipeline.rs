//! `toporec run` end to end: every shipped pipeline file, the Parquet tables read back by
//! arrow-rs and by an independent reader (DuckDB/pyarrow), determinism across thread counts,
//! bad scans mid-run, validation errors, schemas kept in sync.

use crate::util::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use toporec::pipeline::config::Pipeline;
use toporec::sinks::index::reader::{diagrams as read_diagrams, read_scans};
use toporec::sinks::parquet::Status;

/// The parquet files of one table, sorted.
fn parts(index: &Path, table: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let dir =
        if table == "descriptors" { index.join(table).join("method=toporec") } else { index.join(table) };
    for session in std::fs::read_dir(dir).unwrap().flatten() {
        for f in std::fs::read_dir(session.path()).unwrap().flatten() {
            out.push(f.path());
        }
    }
    out.sort();
    out
}

/// Descriptor rows (scan_id, values) via arrow-rs.
fn descriptors(index: &Path) -> Vec<(String, Vec<f32>)> {
    use arrow::array::{AsArray, Float32Array};
    let mut out = Vec::new();
    for p in parts(index, "descriptors") {
        let f = std::fs::File::open(&p).unwrap();
        let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f)
            .unwrap()
            .build()
            .unwrap();
        for b in reader {
            let b = b.unwrap();
            let ids = b.column_by_name("scan_id").unwrap().as_string::<i32>().clone();
            let vec = b.column_by_name("descriptor").unwrap().as_fixed_size_list().clone();
            for i in 0..b.num_rows() {
                let v = vec.value(i);
                let v = v.as_any().downcast_ref::<Float32Array>().unwrap();
                out.push((ids.value(i).to_string(), v.values().to_vec()));
            }
        }
    }
    out
}

#[test]
fn sample_pipeline_end_to_end_and_thread_count_invariant() {
    let dir = scratch_dir("pipeline_sample");
    let pipeline = root().join("pipelines/sample.toml");
    let one = dir.join("t1");
    let o = run_pipeline(&pipeline, &one, 1);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let summary = text(&o.stderr);
    assert!(summary.contains("scans: 64 read, 64 indexed, 0 skipped, 0 errors"), "{summary}");
    for name in ["codebook.json", "pipeline.toml", "manifest.json"] {
        assert!(one.join(name).is_file(), "{name}");
    }
    assert_eq!(parts(&one, "scans").len(), 2, "one partition per session");
    assert!(part_file(&one, "scans", "2026-01-01").is_file());
    assert!(
        std::fs::read_dir(&one)
            .unwrap()
            .flatten()
            .all(|e| !e.file_name().to_string_lossy().starts_with(".staging"))
    );
    // The effective pipeline is itself a valid pipeline that names the same index.
    let eff = Pipeline::load(&one.join("pipeline.toml")).unwrap();
    assert_eq!(eff.preprocess, Pipeline::load(&pipeline).unwrap().preprocess);

    // arrow-rs read-back: scans and diagrams agree with each other and with the engine.
    let scans = read_scans(&part_file(&one, "scans", "2026-01-02"), "2026-01-02").unwrap();
    assert_eq!(scans.len(), 32);
    assert!(scans.iter().all(|s| s.status == Status::Ok), "every sample scan is indexed");
    assert!(scans.iter().all(|s| s.pose.is_some()), "every sample scan has its ground-truth pose");
    let diagrams: Vec<_> =
        read_diagrams(&part_file(&one, "diagrams", "2026-01-02")).unwrap().map(Result::unwrap).collect();
    assert_eq!(diagrams.len(), 32);
    let h0 = diagrams[0].1.dimension(0);
    assert_eq!(h0.iter().filter(|p| p.death.is_infinite()).count(), 1, "one essential class");
    assert!(h0.len() > 1000, "H0 has one pair per kept point: {}", h0.len());
    let d = descriptors(&one);
    assert_eq!(d.len(), 64);
    assert!(d.iter().all(|(_, v)| v.len() == 50 && v.iter().all(|x| x.is_finite())));

    // 2 threads: identical tables.
    let two = dir.join("t2");
    let o = run_pipeline(&pipeline, &two, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(descriptors(&two), d, "descriptors independent of the thread count");
    for table in ["scans", "diagrams", "descriptors"] {
        for (a, b) in parts(&one, table).iter().zip(parts(&two, table)) {
            assert_eq!(
                std::fs::read(a).unwrap(),
                std::fs::read(&b).unwrap(),
                "{table}: byte-identical files"
            );
        }
    }
    // A second run finds every scan up to date.
    let o = run_pipeline(&pipeline, &two, 2);
    assert!(o.status.success());
    assert!(text(&o.stderr).contains("changes: 64 up to date, 0 added"), "{}", text(&o.stderr));
    assert_eq!(descriptors(&two), d);

    // An independent reader, when installed (.ci/run installs duckdb and pyarrow).
    independent_reader_check(&one);

    // `fit` and `vectorize` read the index's diagrams table and write a descriptors table.
    let cb = dir.join("cb.json");
    let o = toporec(&["fit", one.to_str().unwrap(), "-o", cb.to_str().unwrap(), "-b", "8"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let table = dir.join("standalone.parquet");
    let o = toporec(&[
        "vectorize",
        one.to_str().unwrap(),
        "-c",
        cb.to_str().unwrap(),
        "-o",
        table.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("64 descriptors (length 8)"), "{}", text(&o.stderr));
    let f = std::fs::File::open(&table).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f).unwrap();
    let meta = reader.schema().metadata().clone();
    let id = toporec::vectorize::codebook::Codebook::load(&cb).unwrap().id();
    assert_eq!(meta.get("toporec.codebook_id"), Some(&id));
    assert_eq!(reader.build().unwrap().map(|b| b.unwrap().num_rows()).sum::<usize>(), 64);
}

fn independent_reader_check(index: &Path) {
    let script = format!(
        r#"
import duckdb, pyarrow.dataset as ds
idx = "{idx}"
con = duckdb.connect()
rows = con.sql(f"select session, status, count(*) from read_parquet('{{idx}}/scans/*/*.parquet', hive_partitioning=true, hive_types_autocast=false) group by all order by 1").fetchall()
assert rows == [("2026-01-01", "ok", 32), ("2026-01-02", "ok", 32)], rows
h = con.sql(f"select dim, count(*), count(*) filter (where isinf(death)) from read_parquet('{{idx}}/diagrams/*/*.parquet', hive_partitioning=true) group by dim order by dim").fetchall()
assert h[0][0] == 0 and h[0][2] == 64, h
t = ds.dataset(f"{{idx}}/descriptors", format="parquet", partitioning="hive").to_table()
assert t.num_rows == 64 and str(t.schema.field("descriptor").type) == "fixed_size_list<item: float not null>[50]", t.schema
assert set(t.column_names) >= {{"scan_id", "utime", "pose_x", "pose_y", "pose_z", "dim_used", "descriptor", "codebook_id", "session"}}
md = ds.dataset(f"{{idx}}/scans", format="parquet").files
import pyarrow.parquet as pq
meta = pq.read_metadata(md[0]).metadata
assert meta[b"toporec.schema_version"] == b"2" and meta[b"toporec.table"] == b"scans", meta
print("independent reader ok")
"#,
        idx = index.display()
    );
    if !python_with("independent reader", &["duckdb", "pyarrow"]) {
        return;
    }
    let o = Command::new("python3").args(["-c", &script]).output().unwrap();
    assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));
}

#[test]
fn shipped_pipelines_run_on_shared_data() {
    let Some(_) = shared_data("shipped_pipelines_run_on_shared_data") else { return };
    let dir = scratch_dir("pipeline_shipped");
    for (name, read, sessions) in [("nclt", 14, 1), ("mcap", 6, 2), ("kitti", 48, 11)] {
        let index = dir.join(name);
        let o = run_pipeline(&root().join(format!("pipelines/{name}.toml")), &index, 2);
        assert!(o.status.success(), "{name}: {}", text(&o.stderr));
        assert!(
            text(&o.stderr).contains(&format!("scans: {read} read, {read} indexed")),
            "{name}: {}",
            text(&o.stderr)
        );
        assert_eq!(parts(&index, "descriptors").len(), sessions, "{name}");
    }
    // The NCLT session's poses made it into the descriptors.
    let scans = read_scans(&part_file(&dir.join("nclt"), "scans", "2011-10-03"), "2011-10-03").unwrap();
    assert!(scans.iter().all(|s| s.pose.is_some()));
}

#[test]
fn bad_scans_mid_run_are_recorded_and_the_run_is_partial() {
    let dir = scratch_dir("pipeline_bad_scan");
    // A copy of one sample session with one truncated and one empty scan.
    let src = root().join("samples/town/velodyne_data/2026-01-01/velodyne_sync");
    let session = dir.join("data/velodyne_data/2026-01-01/velodyne_sync");
    std::fs::create_dir_all(&session).unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&src).unwrap().flatten().map(|e| e.path()).collect();
    files.sort();
    for f in files.iter().take(6) {
        std::fs::copy(f, session.join(f.file_name().unwrap())).unwrap();
    }
    let bad = session.join(files[2].file_name().unwrap());
    let bytes = std::fs::read(&bad).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() - 3]).unwrap();
    std::fs::write(session.join("1767261600999999.bin"), b"").unwrap();
    let pipeline = dir.join("p.toml");
    std::fs::write(&pipeline, "[output]\nindex = \"idx\"\n[[sources]]\nkind = \"nclt\"\nsessions = [\"data/velodyne_data\"]\n[preprocess]\nsubsample = 1024\nnormalize = true\n[vectorize]\nb = 4\n").unwrap();
    let o = toporec(&["run", pipeline.to_str().unwrap(), "--no-progress"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let err = text(&o.stderr);
    assert!(err.contains("partial: 1 of 7 scans failed"), "{err}");
    assert!(err.contains("1 skipped"), "the empty scan is skipped: {err}");
    assert!(err.contains(&format!("{}: truncated", bad.display())), "{err}");
    // The scans table holds the skipped and the error row, in input order (sorted by utime:
    // the empty scan, …0999999, comes before the truncated one).
    let rows = read_scans(&part_file(&dir.join("idx"), "scans", "2026-01-01"), "2026-01-01").unwrap();
    let status: Vec<(u64, Status)> = rows.iter().map(|r| (r.seq, r.status)).collect();
    assert_eq!(
        status,
        [
            (0, Status::Ok),
            (1, Status::Ok),
            (2, Status::Skipped),
            (3, Status::Error),
            (4, Status::Ok),
            (5, Status::Ok),
            (6, Status::Ok)
        ]
    );
    let skipped = rows[2].error.as_deref().unwrap();
    assert!(skipped.starts_with("0 points after preprocessing"), "{skipped}");
    assert_eq!(rows[2].kept_points, 0);
    let error = rows[3].error.as_deref().unwrap();
    assert!(error.contains(&format!("{}: truncated", bad.display())), "{error}");
    assert_eq!(
        (rows[3].raw_points, rows[3].utime),
        (0, rows[3].scan_id.rsplit('/').next().unwrap().parse().ok())
    );
    assert_eq!(descriptors(&dir.join("idx")).len(), 5);
}

#[test]
fn validation_reports_every_error_with_its_key_path() {
    let dir = scratch_dir("pipeline_validate");
    let p = dir.join("bad.toml");
    std::fs::write(
        &p,
        r#"
[output]
index = "x"
colour = "red"
[[sources]]
kind = "nclt"
sessions = ["missing-folder"]
[[sources]]
kind = "mcap"
fils = ["a.mcap"]
[[sources]]
kind = "nclt"
sessions = "one-session"
tolerance_ms = "100"
[preprocess]
voxel = -1.0
subsample = "many"
range = { min = 5.0, max = 1.0 }
[persistence]
dims = [2]
[vectorize]
b = 0
contrast = "sharp"
"#,
    )
    .unwrap();
    let o = toporec(&["validate", p.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    let e = text(&o.stderr);
    for needle in [
        "output.colour: unknown key",
        "sources[0].sessions:",
        "missing-folder does not exist",
        "sources[1].fils: unknown field `fils`",
        "sources[1]: missing field `files`",
        // Two bad keys in one entry: both, each with its key path.
        "sources[2].sessions: invalid type: string \"one-session\", expected a sequence",
        "sources[2].tolerance_ms: invalid type: string \"100\", expected f64",
        "preprocess.voxel: the cell size must be > 0",
        "preprocess.subsample:",
        "preprocess.range: need 0 <= min < max",
        "vectorize.b: must be in [1, 100000]; found 0",
        "vectorize.contrast:",
        "persistence.dims: the descriptor needs H0",
    ] {
        assert!(e.contains(needle), "missing `{needle}` in:\n{e}");
    }
    assert!(e.contains("12 errors:"), "{e}");
    // Syntax errors name the line.
    std::fs::write(&p, "[output\nindex = 1").unwrap();
    let e = text(&toporec(&["validate", p.to_str().unwrap()]).stderr);
    assert!(e.contains("bad.toml") && e.contains("line 1"), "{e}");
    // Every shipped pipeline validates.
    for f in std::fs::read_dir(root().join("pipelines")).unwrap().flatten() {
        let o = toporec(&["validate", f.path().to_str().unwrap()]);
        if shared_data("validate shipped").is_some() || f.file_name() == "sample.toml" {
            assert!(o.status.success(), "{}: {}", f.path().display(), text(&o.stderr));
        }
    }
}

#[test]
fn schema_files_equal_the_code() {
    for t in toporec::sinks::schema::all() {
        let path = root().join(format!("schemas/{}.json", t.name));
        let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
        assert_eq!(
            on_disk,
            toporec::sinks::schema::render_json(&t),
            "{} is stale: run `cargo run -- schemas schemas`",
            path.display()
        );
    }
    let on_disk = std::fs::read_to_string(root().join("schemas/report.json")).unwrap_or_default();
    assert!(
        on_disk == toporec::eval::report::schema(),
        "schemas/report.json is stale: run `cargo run -- schemas schemas`"
    );
}

#[test]
fn saved_codebook_run_replaces_only_its_sessions() {
    let dir = scratch_dir("pipeline_saved_codebook");
    let index = dir.join("index");
    let o = run_pipeline(&root().join("pipelines/sample.toml"), &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let before = descriptors(&index);
    // Keep the codebook outside the index, then re-index day 2 only with it.
    let cb = dir.join("codebook.json");
    std::fs::copy(index.join("codebook.json"), &cb).unwrap();
    let p = dir.join("day2.toml");
    let sample = std::fs::read_to_string(root().join("pipelines/sample.toml")).unwrap();
    let body = sample.split("[vectorize]").next().unwrap().replace(
        "sessions = [\"../samples/town/velodyne_data\"]",
        &format!("sessions = [\"{}\"]", root().join("samples/town/velodyne_data/2026-01-02").display()),
    );
    std::fs::write(&p, format!("{body}[vectorize]\ncodebook = \"{}\"\n", cb.display())).unwrap();
    let o = run_pipeline(&p, &index, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("scans: 32 read, 32 indexed"), "{}", text(&o.stderr));
    // Day 1 kept, day 2 rewritten with identical descriptors (same codebook, same preprocessing).
    assert_eq!(parts(&index, "scans").len(), 2);
    assert_eq!(descriptors(&index), before);
    // A codebook with fit keys beside it is refused at validation.
    std::fs::write(&p, format!("{body}[vectorize]\ncodebook = \"{}\"\nb = 10\n", cb.display())).unwrap();
    let e = text(&toporec(&["validate", p.to_str().unwrap()]).stderr);
    assert!(e.contains("vectorize: b given with a saved codebook"), "{e}");
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(300))]

    /// Random edits of the shipped pipeline files give an error list or a valid plan, never a
    /// panic: a byte replaced, a line dropped or doubled, a value swapped for an odd one.
    #[test]
    fn fuzz_pipeline_files(file in 0usize..4, line in 0usize..80, edit in 0usize..6, byte in proptest::prelude::any::<u8>()) {
        let names = ["sample", "nclt", "mcap", "kitti"];
        let path = root().join(format!("pipelines/{}.toml", names[file]));
        let text = std::fs::read_to_string(&path).unwrap();
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        let i = line % lines.len().max(1);
        let odd = ["nan", "inf", "-1", "0", "1e400", "\"\"", "[]", "{}", "18446744073709551616"];
        match edit {
            0 => { lines.remove(i); }
            1 => { let l = lines[i].clone(); lines.insert(i, l); }
            2 => if let Some(eq) = lines[i].find('=') {
                lines[i] = format!("{}= {}", &lines[i][..eq], odd[byte as usize % odd.len()]);
            },
            3 => {
                let mut b = lines[i].clone().into_bytes();
                if !b.is_empty() { let j = byte as usize % b.len(); b[j] = byte; }
                lines[i] = String::from_utf8_lossy(&b).into_owned();
            }
            4 => lines.push(format!("unknown_key_{byte} = {}", odd[byte as usize % odd.len()])),
            _ => lines.truncate(i),
        }
        let edited = lines.join("\n");
        let result = std::panic::catch_unwind(|| Pipeline::parse(&edited, &path));
        proptest::prop_assert!(result.is_ok(), "panicked on:\n{edited}");
        if let Ok(Err(e)) = result {
            proptest::prop_assert!(!e.errors.is_empty());
        }
    }
}
