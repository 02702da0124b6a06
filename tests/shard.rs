//! Sharded runs (`toporec fit --pipeline`, `toporec run --shard I/N`) on the built binary:
//! three shards run at once into one index give exactly the rows of one unsharded run with
//! the same codebook, and `verify` passes.

use crate::util::*;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use toporec::sinks::index::IndexReader;

/// Every row of an index, keyed and sorted: scans, diagrams, TopoRec descriptors.
type Rows = (
    Vec<toporec::sinks::index::reader::ScanRecord>,
    BTreeMap<String, toporec::homology::Diagram>,
    Vec<(String, Vec<f32>, String)>,
);

fn rows(index: &Path) -> Rows {
    let reader = IndexReader::open(index).unwrap();
    let mut scans = reader.scans().unwrap();
    scans.sort_by(|a, b| a.scan_id.cmp(&b.scan_id));
    let diagrams = reader.diagrams().unwrap().map(|r| r.unwrap()).collect();
    let mut descriptors: Vec<_> = reader
        .descriptors(&[], None)
        .unwrap()
        .into_iter()
        .map(|s| (s.scan_id, s.descriptor, s.codebook_id))
        .collect();
    descriptors.sort_by(|a, b| a.0.cmp(&b.0));
    (scans, diagrams, descriptors)
}

#[test]
fn three_concurrent_shards_equal_one_unsharded_run() {
    let dir = scratch_dir("shards");
    let pipeline = root().join("pipelines/sample.toml");
    let (one, sharded) = (dir.join("one"), dir.join("sharded"));
    for index in [&one, &sharded] {
        let o = toporec(&[
            "fit",
            "--pipeline",
            pipeline.to_str().unwrap(),
            "--sample",
            "0.5",
            "--index",
            index.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "fit: {}", text(&o.stderr));
        assert!(text(&o.stderr).contains("frozen in"), "{}", text(&o.stderr));
    }
    let codebook = |i: &Path| IndexReader::open(i).unwrap().codebook().unwrap().id();
    assert_eq!(codebook(&one), codebook(&sharded), "the sample, hence the codebook, is deterministic");

    let o = run_pipeline(&pipeline, &one, 2);
    assert!(o.status.success(), "unsharded run: {}", text(&o.stderr));
    let shards: Vec<_> = (0..3)
        .map(|i| {
            Command::new(env!("CARGO_BIN_EXE_toporec"))
                .args(["run", pipeline.to_str().unwrap(), "--index", sharded.to_str().unwrap()])
                .args(["-t", "1", "--no-progress", "--commit-every", "5", "--shard", &format!("{i}/3")])
                .output_async()
        })
        .collect();
    for (i, shard) in shards.into_iter().enumerate() {
        let o = shard.wait_with_output().unwrap();
        assert!(o.status.success(), "shard {i}/3: {}", text(&o.stderr));
    }
    assert!(!sharded.join("shards").exists(), "every shard folder is merged and removed");

    let o = toporec(&["verify", "--index", sharded.to_str().unwrap()]);
    assert!(o.status.success(), "verify: {}{}", text(&o.stdout), text(&o.stderr));
    let (a, b) = (rows(&one), rows(&sharded));
    assert_eq!(a.0.len(), 64);
    assert_eq!(a.0, b.0, "scan rows (seq included: each scan keeps its place in the input)");
    assert_eq!(a.1, b.1, "diagrams");
    assert_eq!(a.2, b.2, "descriptors");

    // A shard run again finds its scans up to date in the merged index.
    let o = toporec(&[
        "run",
        pipeline.to_str().unwrap(),
        "--index",
        sharded.to_str().unwrap(),
        "--no-progress",
        "--shard",
        "1/3",
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("0 added"), "{}", text(&o.stderr));
}

#[test]
fn shards_of_a_pipeline_with_a_saved_codebook_start_a_new_index() {
    // `[vectorize] codebook = FILE`: no fit first; the first shard freezes the file's codebook
    // into the new index, the others use it.
    let dir = scratch_dir("shards-saved-codebook");
    let first = dir.join("first");
    assert!(run_pipeline(&root().join("pipelines/sample.toml"), &first, 2).status.success());
    // The sample pipeline up to its `[vectorize]` keys (the last section), which name the file.
    let sample = std::fs::read_to_string(root().join("pipelines/sample.toml")).unwrap();
    let samples = format!("{:?}", root().join("samples/town/velodyne_data").display().to_string());
    let body =
        sample.split("[vectorize]").next().unwrap().replace("\"../samples/town/velodyne_data\"", &samples)
            + &format!("[vectorize]\ncodebook = {:?}\n", first.join("codebook.json").display().to_string());
    let pipeline = dir.join("saved.toml");
    std::fs::write(&pipeline, body).unwrap();
    let (one, sharded) = (dir.join("one"), dir.join("sharded"));
    assert!(run_pipeline(&pipeline, &one, 2).status.success());
    let shards: Vec<_> = (0..3)
        .map(|i| {
            Command::new(env!("CARGO_BIN_EXE_toporec"))
                .args(["run", pipeline.to_str().unwrap(), "--index", sharded.to_str().unwrap()])
                .args(["-t", "1", "--no-progress", "--shard", &format!("{i}/3")])
                .output_async()
        })
        .collect();
    for (i, shard) in shards.into_iter().enumerate() {
        let o = shard.wait_with_output().unwrap();
        assert!(o.status.success(), "shard {i}/3: {}", text(&o.stderr));
    }
    let o = toporec(&["verify", "--index", sharded.to_str().unwrap()]);
    assert!(o.status.success(), "verify: {}", text(&o.stdout));
    let codebook = |i: &Path| IndexReader::open(i).unwrap().codebook().unwrap().id();
    assert_eq!(codebook(&sharded), codebook(&first), "the saved codebook, frozen");
    let (a, b) = (rows(&one), rows(&sharded));
    assert_eq!((a.0.len(), &a.1, &a.2), (b.0.len(), &b.1, &b.2), "the rows of one unsharded run");
}

#[test]
fn shard_flags_are_checked() {
    let dir = scratch_dir("shard-flags");
    let pipeline = root().join("pipelines/sample.toml");
    for bad in ["3/3", "1", "a/b", "0/0"] {
        let o = toporec(&["run", pipeline.to_str().unwrap(), "--shard", bad]);
        assert_eq!(o.status.code(), Some(2), "--shard {bad}");
        assert!(text(&o.stderr).contains("--shard"), "{}", text(&o.stderr));
    }
    let o = toporec(&[
        "run",
        pipeline.to_str().unwrap(),
        "--index",
        dir.join("i").to_str().unwrap(),
        "--shard",
        "0/2",
    ]);
    assert!(!o.status.success());
    assert!(text(&o.stderr).contains("toporec fit --pipeline"), "{}", text(&o.stderr));
}

/// Starting a process without waiting for it.
trait OutputAsync {
    fn output_async(&mut self) -> std::process::Child;
}

impl OutputAsync for Command {
    fn output_async(&mut self) -> std::process::Child {
        self.stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("spawn toporec")
    }
}
