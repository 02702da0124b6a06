//! Indexes written by earlier layouts stay readable. `tests/fixtures/index-layout-2/` is an index
//! of table layout 2, kept as written (see the fixtures' README): it opens, verifies and answers
//! as an index written now; and a part of an older layout that lacks a nullable column (one
//! added to a table since) reads with that column null, and compacts into today's layout.

use crate::util::*;
use std::path::{Path, PathBuf};
use toporec::sinks::index::IndexReader;

const FIXTURE: &str = "tests/fixtures/index-layout-2";

/// A copy of the fixture (a reader may complete a commit, a query writes a search cache).
fn fixture_copy(test: &str) -> PathBuf {
    let to = scratch_dir(test).join("index");
    let from = root().join(FIXTURE);
    for e in walkdir::WalkDir::new(&from).into_iter().flatten() {
        let rel = e.path().strip_prefix(&from).unwrap();
        if e.file_type().is_dir() {
            std::fs::create_dir_all(to.join(rel)).unwrap();
        } else {
            std::fs::copy(e.path(), to.join(rel)).unwrap();
        }
    }
    to
}

/// Every row of every table, sorted, without the columns that name where the scans were read
/// (`source_path`) or when (`seq`).
fn contents(index: &Path) -> Vec<String> {
    use arrow::util::display::{ArrayFormatter, FormatOptions};
    let reader = IndexReader::open(index).unwrap();
    let mut out = Vec::new();
    let mut tables: Vec<(&str, Option<String>)> = vec![("scans", None), ("diagrams", None)];
    tables.extend(reader.methods().unwrap().into_iter().map(|m| ("descriptors", Some(m))));
    for (table, method) in tables {
        let (schema, batches) = reader.table(table, method.as_deref()).unwrap();
        for batch in batches {
            let options = FormatOptions::default();
            let columns: Vec<(String, ArrayFormatter)> = schema
                .fields()
                .iter()
                .zip(batch.columns())
                .filter(|(f, _)| !["source_path", "seq"].contains(&f.name().as_str()))
                .map(|(f, c)| (f.name().clone(), ArrayFormatter::try_new(c.as_ref(), &options).unwrap()))
                .collect();
            for i in 0..batch.num_rows() {
                let cells: Vec<String> = columns.iter().map(|(n, c)| format!("{n}={}", c.value(i))).collect();
                out.push(format!("{table}/{}|{}", method.as_deref().unwrap_or("-"), cells.join("|")));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn an_index_of_layout_2_opens_verifies_and_equals_one_written_now() {
    let index = fixture_copy("layout_2");
    let v = toporec::maintenance::verify(&index, false).unwrap();
    assert!(v.problems.is_empty(), "{:?}", v.problems);
    assert_eq!(v.scans, 6);
    let info = toporec::info::info(&index).unwrap();
    assert_eq!(info.counts.ok, 6);
    let methods: Vec<&str> = info.methods.keys().map(String::as_str).collect();
    assert_eq!(methods, ["scancontext", "toporec", "toporec-plus"]);
    // Day 2's stored descriptors find day 1's scans with every method.
    for method in ["toporec", "toporec-plus", "scancontext"] {
        let engine = toporec::Engine::open(&index, &["2026-01-01".into()], method).unwrap();
        assert_eq!(engine.scans.len(), 3, "{method}");
    }

    // The same scans indexed now, with the same pipeline: the same rows.
    let dir = index.parent().unwrap();
    let p = sources_beside(dir, 3);
    let now = dir.join("now");
    let o = toporec(&["run", p.to_str().unwrap(), "--index", now.to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(contents(&now), contents(&index), "the rows of an index written now differ from layout 2's");
}

/// The fixture's pipeline over a copy of the first `n` scans of each day of the sample in `dir`.
fn sources_beside(dir: &Path, n: usize) -> PathBuf {
    let data = dir.join("town/velodyne_data");
    for session in ["2026-01-01", "2026-01-02"] {
        let from = root().join("samples/town/velodyne_data").join(session).join("velodyne_sync");
        let to = data.join(session).join("velodyne_sync");
        std::fs::create_dir_all(&to).unwrap();
        let mut files: Vec<PathBuf> = std::fs::read_dir(&from).unwrap().flatten().map(|e| e.path()).collect();
        files.sort();
        for f in &files[..n] {
            std::fs::copy(f, to.join(f.file_name().unwrap())).unwrap();
        }
        let gt = format!("groundtruth_{session}.csv");
        std::fs::create_dir_all(dir.join("town/ground_truth")).unwrap();
        std::fs::copy(
            root().join("samples/town/ground_truth").join(&gt),
            dir.join("town/ground_truth").join(&gt),
        )
        .unwrap();
    }
    let pipeline = std::fs::read_to_string(root().join("tests/fixtures/index-layout-2.toml"))
        .unwrap()
        .replace("/data/town", &dir.join("town").display().to_string());
    let p = dir.join(format!("pipeline-{n}.toml"));
    std::fs::write(&p, pipeline).unwrap();
    p
}

/// Rewrites a part without `column` (as a writer of a layout before that column would have
/// written it), and records the part's new size and checksum in the manifest.
fn without_column(index: &Path, rel: &str, column: &str) {
    let path = index.join(rel);
    let file = std::fs::File::open(&path).unwrap();
    let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file).unwrap();
    let schema = reader.schema().clone();
    let keep: Vec<usize> = (0..schema.fields().len()).filter(|&i| schema.field(i).name() != column).collect();
    let narrowed = std::sync::Arc::new(schema.project(&keep).unwrap());
    let batches: Vec<_> = reader.build().unwrap().map(|b| b.unwrap().project(&keep).unwrap()).collect();
    let out = std::fs::File::create(&path).unwrap();
    let mut writer = parquet::arrow::ArrowWriter::try_new(out, narrowed, None).unwrap();
    for b in &batches {
        writer.write(b).unwrap();
    }
    writer.close().unwrap();
    let (bytes, xxh3) = toporec::sinks::index::manifest::file_checksum(&path).unwrap();
    let manifest_path = index.join("manifest.json");
    let mut m = read_json(&manifest_path);
    let entry = m["files"].as_array_mut().unwrap().iter_mut().find(|f| f["path"] == rel).unwrap();
    entry["bytes"] = serde_json::json!(bytes);
    entry["xxh3"] = serde_json::json!(xxh3);
    std::fs::write(&manifest_path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
}

#[test]
fn a_part_without_a_nullable_column_reads_it_as_nulls_and_compacts_to_todays_layout() {
    let index = fixture_copy("layout_nullable");
    let manifest = read_json(&index.join("manifest.json"));
    let part = |table: &str, method: Option<&str>, session: &str| -> String {
        let files = manifest["files"].as_array().unwrap();
        let f = files
            .iter()
            .find(|f| {
                f["table"] == table
                    && f["session"] == session
                    && method.is_none_or(|m| f["method"].as_str().unwrap_or("toporec") == m)
            })
            .unwrap();
        f["path"].as_str().unwrap().to_string()
    };
    let before = contents(&index);
    let scans = part("scans", None, "2026-01-01");
    let descriptors = part("descriptors", Some("toporec"), "2026-01-01");
    without_column(&index, &scans, "message_index");
    without_column(&index, &descriptors, "dim_used");
    // Read as nulls: the tables' contents are unchanged (those columns were null).
    assert_eq!(contents(&index), before);
    let v = toporec::maintenance::verify(&index, false).unwrap();
    assert!(v.problems.is_empty(), "{:?}", v.problems);
    toporec::Engine::open(&index, &[], "toporec").unwrap();
    // A column that is not nullable is still required.
    let rows_before = std::fs::read(index.join(&scans)).unwrap();
    without_column(&index, &scans, "status");
    let e = IndexReader::open(&index).unwrap().scans().unwrap_err().to_string();
    assert!(e.contains("no column `status`"), "{e}");
    std::fs::write(index.join(&scans), rows_before).unwrap();
    without_column(&index, &scans, "message_index");

    // A run adds a scan to day 1 (parts of today's layout beside the older one), and
    // compaction merges them into today's layout: every declared column, in its declared order.
    let p = sources_beside(index.parent().unwrap(), 4);
    let o = toporec(&["run", p.to_str().unwrap(), "--index", index.to_str().unwrap(), "--no-progress"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("6 up to date, 2 added"), "{}", text(&o.stderr));
    let grown = contents(&index);
    let o = toporec(&["compact", "--index", index.to_str().unwrap()]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(contents(&index), grown);
    let v = toporec::maintenance::verify(&index, false).unwrap();
    assert!(v.problems.is_empty(), "{:?}", v.problems);
    let reader = IndexReader::open(&index).unwrap();
    for (session, path) in reader.files("scans").unwrap() {
        let file = std::fs::File::open(&path).unwrap();
        let builder = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file).unwrap();
        let names: Vec<String> = builder.schema().fields().iter().map(|f| f.name().clone()).collect();
        let declared: Vec<String> =
            toporec::sinks::schema::scans().columns.iter().map(|c| c.name.to_string()).collect();
        assert_eq!(names, declared, "{session}");
    }
}
