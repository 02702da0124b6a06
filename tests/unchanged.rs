//! What the one command writes stays byte for byte what it was when these SHA-256s were taken
//! (`tests/fixtures/unchanged.json`): the index's tables, the loops table, the picture and the
//! g2o file, on the sample drive (`pipelines/sample.toml`), `samples/drive.bag` and a simulated
//! drive driven back the other way a lane over. A restructuring of the code changes none of
//! them. The index's Parquet files are hashed as their rows (every column, the scratch folder's
//! path written `<scratch>` and the repository's `<root>`), so the digests hold on any machine;
//! the other files, and the effective pipeline each index keeps, are hashed as they are. `TOPOREC_BLESS=1` writes the digests anew.

use crate::util::*;
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::Path;

fn sha256(bytes: &[u8]) -> String {
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// Each table's rows (every method's descriptors), hashed, with the folders named as
/// placeholders.
fn tables(index: &Path, scratch: &Path, into: &mut BTreeMap<String, String>, case: &str) {
    use arrow::util::display::{ArrayFormatter, FormatOptions};
    for table in ["scans", "diagrams", "descriptors"] {
        let mut lines = Vec::new();
        for entry in walkdir::WalkDir::new(index.join(table)).into_iter().flatten() {
            let path = entry.path();
            if path.extension().is_none_or(|e| e != "parquet") {
                continue;
            }
            // The partition (method, session) from the path, not the part's number.
            let partition = path.parent().unwrap().strip_prefix(index).unwrap().display().to_string();
            let f = std::fs::File::open(path).unwrap();
            let reader = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f).unwrap();
            for batch in reader.build().unwrap() {
                let batch = batch.unwrap();
                let options = FormatOptions::default();
                let columns: Vec<ArrayFormatter> = batch
                    .columns()
                    .iter()
                    .map(|c| ArrayFormatter::try_new(c.as_ref(), &options).unwrap())
                    .collect();
                for i in 0..batch.num_rows() {
                    let cells: Vec<String> = columns.iter().map(|c| c.value(i).to_string()).collect();
                    lines.push(format!("{partition}|{}", cells.join("|")));
                }
            }
        }
        assert!(!lines.is_empty() || table == "diagrams", "{case}: no {table} rows");
        lines.sort();
        let text = lines
            .join("\n")
            .replace(&scratch.display().to_string(), "<scratch>")
            .replace(&root().display().to_string(), "<root>");
        into.insert(format!("{case}/{table}"), sha256(text.as_bytes()));
    }
    // The effective pipeline the index keeps (what `toporec run` on it does again).
    let pipeline = std::fs::read_to_string(index.join("pipeline.toml"))
        .unwrap()
        .replace(&scratch.display().to_string(), "<scratch>")
        .replace(&root().display().to_string(), "<root>");
    into.insert(format!("{case}/pipeline.toml"), sha256(pipeline.as_bytes()));
}

/// The files of one loops run, hashed as they are.
fn files(scratch: &Path, names: &[&str], into: &mut BTreeMap<String, String>, case: &str) {
    for name in names {
        let bytes = std::fs::read(scratch.join(name)).unwrap_or_else(|e| panic!("{case}: {name}: {e}"));
        into.insert(format!("{case}/{name}"), sha256(&bytes));
    }
}

fn ok(o: std::process::Output) {
    assert!(o.status.success(), "{}", text(&o.stderr));
}

#[test]
fn indexes_loops_pictures_and_graphs_are_as_recorded() {
    let dir = scratch_dir("unchanged");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let mut got = BTreeMap::new();

    // The sample drive: the README's first command.
    let sample = dir.join("sample");
    ok(run_pipeline(&root().join("pipelines/sample.toml"), &sample, 2));
    tables(&sample, &dir, &mut got, "sample");

    // The sample bag, in one command.
    let drive = dir.join("drive");
    std::fs::create_dir_all(&drive).unwrap();
    let bag = drive.join("drive.bag");
    std::fs::copy(root().join("samples/drive.bag"), &bag).unwrap();
    let o = toporec(&[
        "loops",
        &s(&bag),
        "--index",
        &s(&drive.join("index")),
        "-o",
        &s(&drive.join("loops.csv")),
        "--g2o",
        &s(&drive.join("loops.g2o")),
        "--no-progress",
        "-t",
        "2",
    ]);
    ok(o);
    tables(&drive.join("index"), &dir, &mut got, "drive");
    files(&drive, &["loops.csv", "loops.png", "loops.svg", "loops.toporec-plus.g2o"], &mut got, "drive");

    // A simulated drive back the other way, 3.5 m over.
    let reversed = dir.join("reversed");
    let bag = simulate_lookalike_laps(&reversed.join("sim"));
    let o = toporec(&[
        "loops",
        &s(&bag),
        "--index",
        &s(&reversed.join("index")),
        "-o",
        &s(&reversed.join("loops.csv")),
        "--g2o",
        &s(&reversed.join("loops.g2o")),
        "--exclude-seconds",
        "10",
        "--no-progress",
        "-t",
        "2",
    ]);
    ok(o);
    tables(&reversed.join("index"), &dir, &mut got, "reversed");
    files(
        &reversed,
        &["loops.csv", "loops.png", "loops.svg", "loops.toporec-plus.g2o"],
        &mut got,
        "reversed",
    );

    let fixture = root().join("tests/fixtures/unchanged.json");
    let text = serde_json::to_string_pretty(&got).unwrap() + "\n";
    if std::env::var("TOPOREC_BLESS").is_ok_and(|v| v == "1") {
        std::fs::write(&fixture, &text).unwrap();
    }
    let recorded: BTreeMap<String, String> = serde_json::from_str(
        &std::fs::read_to_string(&fixture)
            .unwrap_or_else(|_| panic!("{}: run with TOPOREC_BLESS=1", fixture.display())),
    )
    .unwrap();
    let differ: Vec<&String> = got.keys().filter(|k| recorded.get(*k) != got.get(*k)).collect();
    assert!(differ.is_empty(), "differ from tests/fixtures/unchanged.json: {differ:?}");
    assert_eq!(recorded.len(), got.len(), "the same files");
}
