//! Index maintenance benchmark: `toporec verify` of an index of 100,000 scans, then
//! `toporec revectorize` of its stored diagrams with b = 50 (a codebook fitted on them, then
//! every descriptor; design goal ≥ 5,000 scans/s on 2 cores).
//!
//! The index is built once (cached in `target/tmp/bench-index`, about 11 GB): the sample
//! drive's 64 real diagrams (4096 points per scan, H0 + H1 + H2, ~8,700 pairs each) stored
//! under 100,000 scan ids, written through toporec's own index writer.
//!
//! Run: `cargo bench --bench index`.

use std::path::Path;
use std::process::Command;
use std::time::Instant;
use toporec::sinks::index::{IndexReader, IndexWriter};
use toporec::sinks::parquet::{ScanRow, Status};

const SCANS: usize = 100_000;

fn build(bin: &str, dir: &Path) {
    let seed = dir.join("seed");
    let index = dir.join("index");
    if index.join("manifest.json").is_file() {
        return;
    }
    let _ = std::fs::remove_dir_all(dir);
    let pipeline = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/sample.toml");
    let st = Command::new(bin)
        .args(["run", pipeline.to_str().unwrap(), "--index", seed.to_str().unwrap(), "--no-progress"])
        .status()
        .unwrap();
    assert!(st.success());
    let reader = IndexReader::open(&seed).unwrap();
    let diagrams: Vec<_> = reader.diagrams().unwrap().map(Result::unwrap).collect();
    let settings = toporec::pipeline::config::Pipeline::of_index(&seed).unwrap().settings_hash();
    std::fs::create_dir_all(&index).unwrap();
    std::fs::copy(seed.join("pipeline.toml"), index.join("pipeline.toml")).unwrap();
    let mut writer = IndexWriter::open(&index, &settings, false).unwrap();
    let t = Instant::now();
    for i in 0..SCANS {
        let (_, d) = &diagrams[i % diagrams.len()];
        let session = format!("s{:02}", i / 10_000);
        let row = ScanRow {
            scan_id: format!("{session}/{i:06}"),
            fingerprint: Some(format!("{i:016x}")),
            settings_hash: settings.clone(),
            session,
            seq: i as u64,
            source_path: "bench".into(),
            message_index: None,
            utime: Some(i as i64),
            pose: None,
            raw_points: 4096,
            kept_points: 4096,
            status: Status::Ok,
            error: None,
        };
        writer.write_scan(row, Some(d), &[0, 1, 2], Vec::new()).unwrap();
        if writer.chunk_len() >= 5_000 {
            writer.commit().unwrap();
        }
    }
    writer.commit().unwrap();
    println!("built the index of {SCANS} scans in {:.0} s", t.elapsed().as_secs_f64());
}

fn main() {
    let bin = env!("CARGO_BIN_EXE_toporec");
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/tmp/bench-index");
    build(bin, &dir);
    let index = dir.join("index");
    let pairs: u64 =
        IndexReader::open(&index).unwrap().manifest().unwrap().files_of("diagrams").map(|f| f.rows).sum();
    println!("{SCANS} scans, {pairs} stored pairs ({:.0} per scan)", pairs as f64 / SCANS as f64);
    // A first full read (verify checks every byte) brings the files into the page cache.
    let t = Instant::now();
    let o = Command::new(bin).args(["verify", "--index", index.to_str().unwrap()]).output().unwrap();
    println!("verify: {:.1} s: {}", t.elapsed().as_secs_f64(), String::from_utf8_lossy(&o.stdout).trim());
    for threads in [2, 1] {
        let t = Instant::now();
        let o = Command::new(bin)
            .args(["revectorize", "--index", index.to_str().unwrap(), "-b", "50", "-t", &threads.to_string()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let secs = t.elapsed().as_secs_f64();
        println!(
            "revectorize, b = 50, {threads} thread(s): {secs:.1} s, {:.0} scans/s (design goal >= 5,000 on 2 cores)",
            SCANS as f64 / secs
        );
        println!("  {}", String::from_utf8_lossy(&o.stderr).trim());
    }
}
