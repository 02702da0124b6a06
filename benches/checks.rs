//! What checking committed parts costs the reads that answer: every part is checked against the
//! checksum its commit recorded before any of its rows is used. Interleaved A/B in one run: the
//! same reads with the checks (what every command does) and without them (the hidden
//! `Damage::unchecked` policy, the baseline), alternating, medians of each.
//!
//! 1. The sample (`pipelines/compare.toml`'s methods over `samples/town`): `toporec query`'s work
//!    with no search cache yet — the engine opened from the parts (toporec-plus's structure
//!    built and written), then day 2's 32 scans described and searched in day 1.
//! 2. 100,000 entries: an index of 100,000 TopoRec (b = 50) and ScanContext (1,200 values)
//!    descriptors (synthetic values; cached in `target/tmp/bench-checks`): the engine opened
//!    from the parts, then 64 stored descriptors searched.
//!
//! A query answered from a current search cache reads no descriptor part, so it checks none.
//!
//! Run: `cargo bench --bench checks`.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;
use toporec::search::Engine;
use toporec::sinks::index::IndexWriter;
use toporec::sinks::index::damage::Damage;
use toporec::sinks::index::writer::MethodDescriptor;
use toporec::sinks::parquet::{DescriptorRow, ScanRow, Status};

const ENTRIES: usize = 100_000;
const REPS: usize = 9;

/// The sample indexed with `methods` into `index` (once).
fn sample_index(bin: &str, dir: &Path, name: &str, methods: &[&str]) -> PathBuf {
    let index = dir.join(name);
    if index.join("manifest.json").is_file() {
        return index;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("pipelines/compare.toml")).unwrap();
    let text = text.replace("\"../samples", &format!("\"{}/samples", root.display()));
    let text = text.lines().filter(|l| !l.starts_with("methods = ")).collect::<Vec<_>>().join("\n");
    let text = text.replace("[descriptors]", &format!("[descriptors]\nmethods = {methods:?}"));
    let pipeline = dir.join(format!("{name}.toml"));
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(&pipeline, text).unwrap();
    let st = Command::new(bin)
        .args(["run", pipeline.to_str().unwrap(), "--index", index.to_str().unwrap(), "--no-progress"])
        .status()
        .unwrap();
    assert!(st.success());
    index
}

/// 100,000 entries with the sample index's codebook and ScanContext settings (once).
fn large_index(seed: &Path, dir: &Path) -> PathBuf {
    let index = dir.join("entries");
    if index.join("manifest.json").is_file() {
        return index;
    }
    let _ = std::fs::remove_dir_all(&index);
    let manifest =
        toporec::sinks::index::manifest::Manifest::load(&seed.join("manifest.json")).unwrap().unwrap();
    let codebook = manifest.codebook(seed).unwrap().unwrap();
    let sc = manifest.methods["scancontext"].clone();
    let mut writer = IndexWriter::open(&index, &manifest.settings_hash, false).unwrap();
    writer.set_codebook(codebook.clone(), manifest.pipeline.clone());
    writer.set_methods(manifest.methods.clone());
    let mut rng = toporec::rng::SplitMix64(7);
    let mut values = |n: usize| (0..n).map(|_| rng.next_f64() as f32).collect::<Vec<f32>>();
    let t = Instant::now();
    for i in 0..ENTRIES {
        let session = format!("s{:02}", i / 10_000);
        let id = format!("{session}/{i:06}");
        let row = ScanRow {
            scan_id: id.clone(),
            fingerprint: Some(format!("{i:016x}")),
            settings_hash: manifest.settings_hash.clone(),
            session,
            seq: i as u64,
            source_path: "bench".into(),
            message_index: None,
            utime: Some(i as i64),
            pose: Some(toporec::types::Pose { x: i as f64, y: 0.0, z: 0.0, yaw: 0.0 }),
            raw_points: 4096,
            kept_points: 4096,
            status: Status::Ok,
            error: None,
        };
        let descriptor = |values: Vec<f32>| DescriptorRow {
            scan_id: id.clone(),
            utime: row.utime,
            pose: row.pose,
            dim_used: None,
            values,
        };
        let descriptors = vec![
            MethodDescriptor {
                method: "toporec".into(),
                id: codebook.id(),
                row: descriptor(values(codebook.len())),
            },
            MethodDescriptor {
                method: "scancontext".into(),
                id: sc.id.clone(),
                row: descriptor(values(sc.length)),
            },
        ];
        writer.write_scan(row, None, &[0, 1, 2], descriptors).unwrap();
        if writer.chunk_len() >= 5_000 {
            writer.commit().unwrap();
        }
    }
    writer.commit().unwrap();
    println!("built {ENTRIES} entries in {:.0} s", t.elapsed().as_secs_f64());
    index
}

/// Medians (ms) of `work` with the checks and without, alternating which goes first, after one
/// untimed run of each (`CHECKS_SAMPLES=1` prints every sample).
fn interleaved(reps: usize, mut work: impl FnMut(&Damage)) -> (f64, f64) {
    // One of each first, not timed: the page cache and the allocator warm.
    work(&Damage::refuse());
    work(&Damage::unchecked());
    let (mut checked, mut unchecked) = (Vec::new(), Vec::new());
    for rep in 0..reps {
        for first in [rep % 2 == 0, rep % 2 != 0] {
            let damage = if first { Damage::refuse() } else { Damage::unchecked() };
            let t = Instant::now();
            work(&damage);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            if first { checked.push(ms) } else { unchecked.push(ms) }
        }
    }
    if std::env::var("CHECKS_SAMPLES").is_ok() {
        println!("    with: {checked:.0?}\n    without: {unchecked:.0?}");
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    (median(&mut checked), median(&mut unchecked))
}

fn report(what: &str, (checked, unchecked): (f64, f64)) {
    println!(
        "{what}: {checked:.1} ms with the checks, {unchecked:.1} ms without: {:+.1} % (goal <= +5 %)",
        100.0 * (checked / unchecked - 1.0)
    );
}

fn main() {
    let bin = env!("CARGO_BIN_EXE_toporec");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("target/tmp/bench-checks");
    let methods = ["toporec", "toporec-plus", "scancontext", "m2dp", "ring"];
    let sample = sample_index(bin, &dir, "sample", &methods);
    let queries = root.join("samples/town/velodyne_data/2026-01-02");
    println!("the sample, one thread:");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| {
        for method in methods {
            let args = toporec::query::QueryArgs {
                index: toporec::flags::IndexFlag { path: sample.clone() },
                inputs: vec![queries.clone()],
                k: 3,
                method: method.into(),
                sessions: vec!["2026-01-01".into()],
                topic: None,
                skip_damaged: false,
                out: None,
            };
            let r = interleaved(REPS, |damage| {
                let _ = std::fs::remove_dir_all(sample.join("searchers"));
                let engine = Engine::open_with(&args.index.path, &args.sessions, method, damage).unwrap();
                toporec::query::run(&engine, &args, &mut std::io::sink(), Path::new("-")).unwrap();
            });
            report(&format!("  query, {method}, no search cache"), r);
        }
    });
    let large = large_index(&sample_index(bin, &dir, "seed", &["toporec", "scancontext"]), &dir);
    println!("{ENTRIES} entries, one thread:");
    pool.install(|| {
        for method in ["toporec", "scancontext"] {
            let stored = toporec::sinks::index::IndexReader::open(&large).unwrap().descriptors_of(
                method,
                &["s00".into()],
                None,
            );
            let stored = stored.unwrap();
            let queries: Vec<f32> =
                stored.iter().take(64).flat_map(|s| s.descriptor.iter().copied()).collect();
            let r = interleaved(REPS, |damage| {
                let engine = Engine::open_with(&large, &[], method, damage).unwrap();
                std::hint::black_box(engine.find_many(&queries, 3).expect("answers"));
            });
            report(&format!("  open + 64 queries, {method}"), r);
            // The checks' own work: reading each part whole and hashing it.
            let files = toporec::info::files(&large, Some("descriptors"), Some(method)).unwrap();
            let (mut read, mut hash, mut bytes) = (0.0, 0.0, 0usize);
            for f in &files {
                let t = Instant::now();
                let b = std::fs::read(f).unwrap();
                read += t.elapsed().as_secs_f64();
                let t = Instant::now();
                std::hint::black_box(twox_hash::XxHash3_64::oneshot(&b));
                hash += t.elapsed().as_secs_f64();
                bytes += b.len();
            }
            println!(
                "    its {} parts, {:.0} MB: read {:.1} ms, xxh3 {:.1} ms ({:.1} GB/s)",
                files.len(),
                bytes as f64 / 1e6,
                read * 1e3,
                hash * 1e3,
                bytes as f64 / hash / 1e9
            );
        }
    });
}
