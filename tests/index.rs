//! Reading an index back when other tools have rewritten its tables: compatible types are
//! read, anything else is a one-line error naming the file and the column, never a panic.

use crate::util::*;
use std::path::Path;
use std::process::Command;

/// Runs a pyarrow snippet with `idx` bound to the index folder.
fn pyarrow(idx: &Path, code: &str) {
    let script = format!(
        "import pyarrow as pa, pyarrow.parquet as pq, glob\nidx = {:?}\n{code}",
        idx.display().to_string()
    );
    let o = Command::new("python3").args(["-c", &script]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// Asserts a failed command with one line naming `needles`, and no panic.
fn assert_one_line_error(o: &std::process::Output, needles: &[&str], what: &str) {
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{what}: {err}");
    assert!(!err.contains("panicked"), "{what}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{what}: one line: {err}");
    for n in needles {
        assert!(err.contains(n), "{what}: `{n}` missing from: {err}");
    }
}

#[test]
fn foreign_tables_read_or_fail_cleanly() {
    if !python_with("foreign_tables_read_or_fail_cleanly", &["pyarrow"]) {
        return;
    }
    let dir = scratch_dir("index_foreign");
    let original = dir.join("original");
    let o = run_pipeline(&root().join("pipelines/sample.toml"), &original, 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let query = |idx: &Path| {
        let session = root().join("samples/town/velodyne_data/2026-01-02");
        toporec(&["query", "--index", idx.to_str().unwrap(), session.to_str().unwrap(), "-k", "3"])
    };
    let expected = query(&original);
    assert!(expected.status.success(), "{}", text(&expected.stderr));

    // Rewritten as Polars or pandas would: large strings, a variable-length list of doubles
    // for the descriptor, the key-value metadata gone. The tables of a folder another tool
    // wrote have no manifest (in an index with one, a rewritten part is damage: see
    // tests/damage.rs).
    let copy = |name: &str| {
        let to = dir.join(name);
        let o = Command::new("cp").args(["-r", original.to_str().unwrap(), to.to_str().unwrap()]).output();
        assert!(o.unwrap().status.success());
        std::fs::remove_file(to.join("manifest.json")).unwrap();
        to
    };
    let rewritten = copy("rewritten");
    pyarrow(
        &rewritten,
        r#"
for f in glob.glob(f"{idx}/*/*/*.parquet"):
    t = pq.read_table(f)
    fields = []
    for fld in t.schema:
        ty = fld.type
        if pa.types.is_string(ty):
            ty = pa.large_string()
        elif pa.types.is_fixed_size_list(ty):
            ty = pa.list_(pa.float64())
        fields.append(pa.field(fld.name, ty, True))
    pq.write_table(t.cast(pa.schema(fields)), f)
"#,
    );
    let got = query(&rewritten);
    assert!(got.status.success(), "{}", text(&got.stderr));
    assert_eq!(text(&got.stdout), text(&expected.stdout), "the same answers from the rewritten tables");
    let cb = dir.join("cb.json");
    let o = toporec(&["fit", rewritten.to_str().unwrap(), "-o", cb.to_str().unwrap(), "-b", "4"]);
    assert!(o.status.success(), "{}", text(&o.stderr));

    // Not compatible: each a clean error naming the file and what is wrong.
    let descriptors = "descriptors/method=toporec/session=2026-01-01/";
    let diagrams = "diagrams/session=2026-01-01/";
    let cases: [(&str, &str, &str, &[&str]); 4] = [
        ("no_column", descriptors, "t = t.drop(['codebook_id'])", &["no column `codebook_id`"]),
        (
            "text_birth",
            diagrams,
            "t = t.set_column(t.schema.get_field_index('birth'), 'birth', t['birth'].cast(pa.string()))",
            &["column `birth` is Utf8, expected Float64"],
        ),
        (
            "newer_layout",
            descriptors,
            "t = t.replace_schema_metadata({**t.schema.metadata, b'toporec.schema_version': b'99'})",
            &["table layout version 99"],
        ),
        (
            "null_ids",
            descriptors,
            "t = t.set_column(0, 'scan_id', pa.array([None] * t.num_rows, pa.string()))",
            &["column `scan_id` has null values"],
        ),
    ];
    for (name, file, edit, needles) in cases {
        let idx = copy(name);
        pyarrow(
            &idx,
            &format!(
                "f = glob.glob(f\"{{idx}}/{file}*.parquet\")[0]\nt = pq.read_table(f)\n{edit}\npq.write_table(t, f)\n"
            ),
        );
        let needles: Vec<&str> = needles.iter().copied().chain([file]).collect();
        if file == descriptors {
            assert_one_line_error(&query(&idx), &needles, name);
            let out = idx.join("eval");
            let o = toporec(&["eval", "places", "--db", idx.to_str().unwrap(), "-o", out.to_str().unwrap()]);
            assert_one_line_error(&o, &needles, name);
        } else {
            let cb = idx.join("cb.json");
            let o = toporec(&["fit", idx.to_str().unwrap(), "-o", cb.to_str().unwrap()]);
            assert_one_line_error(&o, &needles, name);
            let o = toporec(&["plot", "diagram", "--index", idx.to_str().unwrap(), "--scan", "x"]);
            assert_one_line_error(&o, &needles, name);
        }
    }
}
