//! A committed part whose bytes changed after its commit is never believed: every read checks it
//! against the checksum its commit recorded — refused (exit 2, naming the file, its table, both
//! checksums and `toporec repair`), or left out and named with the scans it held
//! (`--skip-damaged`, exit 1) — and `toporec repair` rebuilds it, after which every answer
//! equals the intact index's. Damage of every kind in every table: a flipped bit in a page
//! header, the dictionary page, a data page and the footer; a truncated part; another valid
//! part of the same table in its place; an empty file.

use crate::util::*;
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use toporec::search::Engine;
use toporec::sinks::index::IndexReader;
use toporec::sinks::index::damage::Damage;
use toporec::sinks::index::holdings::held_scans;

/// The methods of the test index: the paper's, toporec's own, and ScanContext.
const METHODS: [&str; 3] = ["toporec", "toporec-plus", "scancontext"];
const DB: &str = "2026-01-01";
const QUERIES: &str = "2026-01-02";

/// The intact index, made once: the sample drive (512 points, codebook of 8) with three
/// methods, committed every 8 scans (four parts per session and table). Its sources are a copy
/// of the sample beside it.
fn intact() -> &'static Path {
    static INDEX: OnceLock<PathBuf> = OnceLock::new();
    INDEX.get_or_init(|| {
        let dir = scratch_dir("damage_intact");
        let data = sample_copy(&dir, &[DB, QUERIES]);
        let p = sample_pipeline(&dir, &data, 512);
        let body = std::fs::read_to_string(&p).unwrap().replace("b = 50 ", "b = 8 ");
        std::fs::write(&p, format!("{body}\n[descriptors]\nmethods = {METHODS:?}\n")).unwrap();
        let index = dir.join("idx");
        let o = toporec(&[
            "run",
            p.to_str().unwrap(),
            "--index",
            index.to_str().unwrap(),
            "--commit-every",
            "8",
            "--no-progress",
        ]);
        assert!(o.status.success(), "{}", text(&o.stderr));
        index
    })
}

/// A copy of the intact index (its sources stay where the pipeline names them), without search
/// caches.
fn copy_of_intact(test: &str) -> PathBuf {
    let to = scratch_dir(test).join("idx");
    let from = intact();
    for e in walkdir::WalkDir::new(from).into_iter().flatten() {
        let rel = e.path().strip_prefix(from).unwrap();
        if rel.starts_with("searchers") {
            continue;
        }
        if e.file_type().is_dir() {
            std::fs::create_dir_all(to.join(rel)).unwrap();
        } else {
            std::fs::copy(e.path(), to.join(rel)).unwrap();
        }
    }
    to
}

/// Every method's answers: the 3 best day-1 scans of each stored day-2 descriptor, with the
/// distances' bits.
fn answers(index: &Path, damage: &Damage) -> toporec::Result<Vec<String>> {
    let mut out = Vec::new();
    let reader = IndexReader::open_with(index, damage)?;
    let manifest = reader.manifest().unwrap().clone();
    for m in METHODS {
        let length = match manifest.methods.get(m) {
            Some(e) => e.length,
            None => manifest.descriptor_length.unwrap(),
        };
        let engine = Engine::open_with(index, &[DB.to_string()], m, damage)?;
        let queries = reader.descriptors_of(m, &[QUERIES.to_string()], Some(length))?;
        let flat: Vec<f32> = queries.iter().flat_map(|q| q.descriptor.iter().copied()).collect();
        for (q, (hits, _)) in queries.iter().zip(engine.find_many(&flat, 3).unwrap()) {
            for h in hits {
                let id = &engine.scans[h.row].scan_id;
                out.push(format!("{m} {} {id} {:016x}", q.scan_id, h.distance.to_bits()));
            }
        }
    }
    Ok(out)
}

/// What a whole-table read gives: every row of `scans` or `diagrams` (ids, with the diagrams'
/// pair counts).
fn table_read(index: &Path, table: &str, damage: &Damage) -> toporec::Result<Vec<String>> {
    let reader = IndexReader::open_with(index, damage)?;
    let mut out: Vec<String> = match table {
        "scans" => {
            reader.scans()?.into_iter().map(|r| format!("{} {:?}", r.scan_id, r.fingerprint)).collect()
        }
        "diagrams" => {
            let mut v = Vec::new();
            for d in reader.diagrams()? {
                let (id, d) = d?;
                v.push(format!("{id} {}", d.len()));
            }
            v
        }
        _ => unreachable!(),
    };
    out.sort();
    Ok(out)
}

/// The committed parts of a table (`descriptors:<method>`) in the day-1 session, in part order.
fn parts_of(index: &Path, table: &str) -> Vec<PathBuf> {
    let reader = IndexReader::open(index).unwrap();
    let files = match table.split_once(':') {
        Some((_, method)) => reader.descriptor_files(method).unwrap(),
        None => reader.files(table).unwrap(),
    };
    let mut parts: Vec<PathBuf> = files.into_iter().filter(|(s, _)| s == DB).map(|(_, p)| p).collect();
    parts.sort();
    parts
}

/// Byte offsets inside a part: a data page's header, the dictionary page, a data page's
/// values, the footer (from the file's own metadata).
fn regions(path: &Path) -> Vec<(&'static str, usize)> {
    use parquet::file::reader::{FileReader, SerializedFileReader};
    let bytes = std::fs::read(path).unwrap();
    let reader = SerializedFileReader::new(bytes::Bytes::from(bytes.clone())).unwrap();
    let columns: Vec<_> = reader.metadata().row_groups().iter().flat_map(|g| g.columns().to_vec()).collect();
    let with_dictionary =
        columns.iter().find(|c| c.dictionary_page_offset().is_some()).expect("a dictionary-encoded column");
    let dictionary = with_dictionary.dictionary_page_offset().unwrap() as usize;
    let data = with_dictionary.data_page_offset() as usize;
    let (start, length) = with_dictionary.byte_range();
    let footer_len = u32::from_le_bytes(bytes[bytes.len() - 8..bytes.len() - 4].try_into().unwrap()) as usize;
    vec![
        ("a page header", data + 1),
        ("the dictionary page", (dictionary + data) / 2),
        ("a data page", (start + length) as usize - 2),
        ("the footer", bytes.len() - 8 - footer_len / 2),
    ]
}

/// Damages `part` as `kind` says; `other` is another valid part of the same table.
fn damage(part: &Path, other: &Path, kind: &str) {
    let mut bytes = std::fs::read(part).unwrap();
    match kind {
        "truncated" => bytes.truncate(bytes.len() / 2),
        "swapped" => bytes = std::fs::read(other).unwrap(),
        "empty" => bytes.clear(),
        flip => {
            let (_, at) = regions(part).into_iter().find(|(name, _)| *name == flip).unwrap();
            bytes[at] ^= 0x10;
        }
    }
    std::fs::write(part, bytes).unwrap();
}

const KINDS: [&str; 7] =
    ["a page header", "the dictionary page", "a data page", "the footer", "truncated", "swapped", "empty"];

/// For a table: each kind of damage to its first day-1 part is refused by name, skipped with
/// the part's scans named, and repaired to the intact answers and rows.
fn every_damage_of(table: &str) {
    let intact_answers = answers(intact(), &Damage::refuse()).unwrap();
    let intact_rows: Vec<Vec<String>> =
        ["scans", "diagrams", "descriptors"].iter().map(|t| rows(intact(), t)).collect();
    let held: Vec<String> = {
        let mut ids = toporec::sinks::index::reader::scan_ids(&parts_of(intact(), table)[0]).unwrap();
        ids.dedup();
        ids
    };
    for kind in KINDS {
        let what = format!("{table}, {kind}");
        let index = copy_of_intact(&format!("damage_{}_{}", table.replace(':', "_"), kind.replace(' ', "_")));
        let parts = parts_of(&index, table);
        damage(&parts[0], &parts[1], kind);
        let rel = parts[0].strip_prefix(&index).unwrap().display().to_string();

        // Refused: the read names the file, the table, both checksums and the repair.
        let refused = match table {
            "scans" | "diagrams" => table_read(&index, table, &Damage::refuse()).map(|_| ()),
            _ => answers(&index, &Damage::refuse()).map(|_| ()),
        };
        let e = refused.expect_err(&what).to_string();
        assert!(e.contains(parts[0].to_str().unwrap()), "{what}: {e}");
        assert!(e.contains("damaged") && e.contains("its commit recorded xxh3"), "{what}: {e}");
        assert!(e.contains(&format!("toporec repair --index {}", index.display())), "{what}: {e}");
        let table_name = table.split(':').next().unwrap();
        assert!(e.contains(&format!("{table_name} part")), "{what}: {e}");

        // Skipped: the rest is read, the part is named with the scans it held.
        let skip = Damage::skip();
        match table {
            "scans" | "diagrams" => {
                let rest = table_read(&index, table, &skip).unwrap();
                assert!(
                    rest.iter().all(|r| !held.iter().any(|id| r.starts_with(&format!("{id} ")))),
                    "{what}"
                );
                assert!(!rest.is_empty(), "{what}");
            }
            _ => {
                let rest = answers(&index, &skip).unwrap();
                let method = table.split(':').nth(1).unwrap();
                assert!(
                    rest.iter()
                        .filter(|r| r.starts_with(&format!("{method} ")))
                        .all(|r| !held.iter().any(|id| r.contains(&format!(" {id} ")))),
                    "{what}: an answer from the damaged part"
                );
            }
        }
        let found = held_scans(skip.found()).unwrap();
        assert_eq!(found.len(), 1, "{what}: {found:?}");
        assert_eq!(found[0].path, rel, "{what}");
        assert_eq!(found[0].scans, held, "{what}: the scans it held");

        // Repaired: verify is clean, answers and rows are the intact index's, bit for bit.
        let r = toporec::repair::repair(&toporec::repair::RepairArgs { index: index.clone(), threads: 2 })
            .unwrap_or_else(|e| panic!("{what}: repair: {e}"));
        assert_eq!(r.damaged.len(), 1, "{what}");
        assert!(r.lost.is_empty(), "{what}: {:?}", r.lost);
        let v = toporec::maintenance::verify(&index, false).unwrap();
        assert!(v.problems.is_empty(), "{what}: {:?}", v.problems);
        assert_eq!(answers(&index, &Damage::refuse()).unwrap(), intact_answers, "{what}");
        let now: Vec<Vec<String>> =
            ["scans", "diagrams", "descriptors"].iter().map(|t| rows(&index, t)).collect();
        assert!(now == intact_rows, "{what}: the repaired rows differ from the intact ones");
    }
}

#[test]
fn a_damaged_scans_part_is_refused_skipped_and_repaired() {
    every_damage_of("scans");
}

#[test]
fn a_damaged_diagrams_part_is_refused_skipped_and_repaired() {
    every_damage_of("diagrams");
}

#[test]
fn a_damaged_toporec_descriptors_part_is_refused_skipped_and_repaired() {
    every_damage_of("descriptors:toporec");
}

#[test]
fn a_damaged_descriptors_part_of_a_computed_method_is_refused_skipped_and_repaired() {
    every_damage_of("descriptors:toporec-plus");
}

/// Flips bit `bit` of byte `at` of `path`.
fn flip(path: &Path, at: usize, bit: u8) {
    let mut bytes = std::fs::read(path).unwrap();
    bytes[at] ^= 1 << bit;
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn the_commands_refuse_damage_or_answer_from_the_rest_and_name_it() {
    let index = copy_of_intact("damage_commands");
    let dir = index.parent().unwrap().to_owned();
    let queries = intact().parent().unwrap().join("town/velodyne_data").join(QUERIES);
    let (idx, q) = (index.to_str().unwrap(), queries.to_str().unwrap());
    let query = |extra: &[&str], out: &str| {
        let out = dir.join(out);
        let mut args =
            vec!["query", "--index", idx, "--method", "toporec-plus", "--session", DB, q, "-k", "3"];
        args.extend(["-o", out.to_str().unwrap()]);
        args.extend(extra);
        (toporec(&args), out)
    };
    let (o, reference) = query(&[], "ref.csv");
    assert!(o.status.success(), "{}", text(&o.stderr));
    std::fs::remove_dir_all(index.join("searchers")).unwrap();
    let part = parts_of(&index, "descriptors:toporec-plus")[0].clone();
    let held = toporec::sinks::index::reader::scan_ids(&part).unwrap();
    flip(&part, regions(&part)[2].1, 3);

    // Without --skip-damaged: exit 2, one line naming the file, both checksums and the repair.
    let (o, out) = query(&[], "damaged.csv");
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains(part.to_str().unwrap()) && err.contains("descriptors part of toporec-plus"),
        "{err}"
    );
    assert!(err.contains(&format!("`toporec repair --index {idx}`")), "{err}");
    assert!(!out.exists(), "no answer written");
    // No cache was built from the damaged part.
    assert!(!index.join("searchers").exists());

    // With it: the rest answers, exit 1, the part and every scan it held named.
    let (o, out) = query(&["--skip-damaged"], "skipped.csv");
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains(part.to_str().unwrap()), "{err}");
    assert!(held.iter().all(|id| err.contains(id.as_str())), "{err}");
    let answers = std::fs::read_to_string(&out).unwrap();
    assert!(held.iter().all(|id| !answers.contains(&format!(",{id},"))), "an answer from the damaged part");
    assert!(!index.join("searchers").exists(), "a cache of part of the rows is never written");

    // eval places: the same, and report.json lists the part and its scans.
    let eval = |extra: &[&str]| {
        eval_days(&index, &dir.join("eval"), &[&["--method", "toporec-plus"], extra].concat())
    };
    assert_eq!(eval(&[]).status.code(), Some(2));
    let o = eval(&["--skip-damaged"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let report = read_json(&dir.join("eval/report.json"));
    let damaged = report["damaged"].as_array().unwrap();
    assert_eq!(damaged.len(), 1, "{report}");
    let listed: Vec<&str> =
        damaged[0]["scans"].as_array().unwrap().iter().map(|s| s.as_str().unwrap()).collect();
    assert_eq!(listed, held.iter().map(String::as_str).collect::<Vec<_>>());

    // loops: the same.
    let loops = |extra: &[&str]| {
        let out = dir.join("loops.csv");
        let mut args = vec!["loops", "--index", idx, "--method", "toporec-plus", "-o", out.to_str().unwrap()];
        args.extend(extra);
        toporec(&args)
    };
    assert_eq!(loops(&[]).status.code(), Some(2));
    let o = loops(&["--skip-damaged"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains(part.to_str().unwrap()), "{}", text(&o.stderr));

    // verify names it; repair rebuilds it; the answers are the intact index's again.
    let o = toporec(&["verify", "--index", idx]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stdout).contains("toporec repair"), "{}", text(&o.stdout));
    let o = toporec(&["repair", "--index", idx]);
    assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));
    assert!(text(&o.stdout).contains(&format!("{} scans read again", held.len())), "{}", text(&o.stdout));
    assert!(toporec(&["verify", "--index", idx]).status.success());
    let (o, again) = query(&[], "again.csv");
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(std::fs::read_to_string(again).unwrap(), std::fs::read_to_string(reference).unwrap());
    // Nothing left to repair.
    let o = toporec(&["repair", "--index", idx]);
    assert!(o.status.success() && text(&o.stdout).contains("nothing to repair"), "{}", text(&o.stdout));
}

#[test]
fn a_scans_part_is_checked_by_info_and_by_every_writer() {
    let index = copy_of_intact("damage_info");
    let idx = index.to_str().unwrap();
    let part = parts_of(&index, "scans")[0].clone();
    flip(&part, regions(&part)[3].1, 0);
    let o = toporec(&["info", "--index", idx]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    let o = toporec(&["info", "--index", idx, "--skip-damaged"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains(part.to_str().unwrap()), "{}", text(&o.stderr));
    // A run, an import and a compaction read the committed scans first: refused, untouched.
    let manifest = std::fs::read(index.join("manifest.json")).unwrap();
    let pipeline = intact().parent().unwrap().join("sample-512.toml");
    let o = toporec(&["run", pipeline.to_str().unwrap(), "--index", idx, "--no-progress"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("toporec repair"), "{}", text(&o.stderr));
    let o = toporec(&["compact", "--index", idx]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert_eq!(std::fs::read(index.join("manifest.json")).unwrap(), manifest);
}

#[test]
fn verify_reports_a_search_cache_whose_parts_fail_their_checks() {
    let index = copy_of_intact("damage_cache");
    let engine = Engine::open(&index, &[], "toporec-plus").unwrap();
    drop(engine);
    assert!(index.join("searchers").is_dir(), "the query built its cache");
    let part = parts_of(&index, "descriptors:toporec-plus")[1].clone();
    flip(&part, 40, 2);
    let v = toporec::maintenance::verify(&index, false).unwrap();
    assert!(
        v.problems.iter().any(|p| p.contains("searchers/") && p.contains("fail their checks")),
        "{:?}",
        v.problems
    );
    // A query answered from the current cache reads no part; repair makes the cache stale.
    Engine::open(&index, &[], "toporec-plus").unwrap();
    toporec::repair::repair(&toporec::repair::RepairArgs { index: index.clone(), threads: 1 }).unwrap();
    let v = toporec::maintenance::verify(&index, false).unwrap();
    assert!(v.problems.is_empty(), "{:?}", v.problems);
}

#[test]
fn repair_reports_the_scans_of_a_changed_or_gone_source_lost_and_keeps_the_rest() {
    let index = copy_of_intact("damage_lost");
    let sources = index.parent().unwrap().join("sources");
    // The index's sources are the intact index's copy of the sample: give this index its own.
    let data = sample_copy(&sources, &[DB, QUERIES]);
    let pipeline = std::fs::read_to_string(index.join("pipeline.toml")).unwrap();
    let old = intact().parent().unwrap().join("town").display().to_string();
    let moved = pipeline.replace(&old, &data.display().to_string());
    assert_ne!(moved, pipeline);
    let mut m = read_json(&index.join("manifest.json"));
    m["pipeline"] = serde_json::Value::String(moved.clone());
    std::fs::write(index.join("manifest.json"), serde_json::to_string_pretty(&m).unwrap()).unwrap();
    std::fs::write(index.join("pipeline.toml"), moved).unwrap();
    // (The manifest edit is not a part: every part still passes its check.)
    assert!(toporec::maintenance::verify(&index, false).unwrap().problems.is_empty());

    let part = parts_of(&index, "descriptors:scancontext")[0].clone();
    let held = toporec::sinks::index::reader::scan_ids(&part).unwrap();
    flip(&part, regions(&part)[1].1, 5);
    // One of its scans changed since, another gone.
    let file = |id: &str| {
        data.join(format!("velodyne_data/{DB}/velodyne_sync/{}.bin", id.split('/').nth(1).unwrap()))
    };
    let mut bytes = std::fs::read(file(&held[0])).unwrap();
    bytes[40] ^= 1;
    std::fs::write(file(&held[0]), bytes).unwrap();
    std::fs::remove_file(file(&held[1])).unwrap();

    let r =
        toporec::repair::repair(&toporec::repair::RepairArgs { index: index.clone(), threads: 2 }).unwrap();
    let lost: Vec<(&str, &str)> = r.lost.iter().map(|l| (l.scan_id.as_str(), l.why.as_str())).collect();
    assert_eq!(lost.len(), 2, "{lost:?}");
    assert!(lost.iter().any(|(id, why)| *id == held[0] && why.contains("changed")), "{lost:?}");
    assert!(lost.iter().any(|(id, why)| *id == held[1] && why.contains("no longer yields")), "{lost:?}");
    assert_eq!(r.from_sources as usize, held.len() - 2);
    // The index is whole and readable: the lost scans are error rows saying so.
    let v = toporec::maintenance::verify(&index, false).unwrap();
    assert!(v.problems.is_empty(), "{:?}", v.problems);
    let scans = IndexReader::open(&index).unwrap().scans().unwrap();
    for id in &held[..2] {
        let row = scans.iter().find(|s| &s.scan_id == id).unwrap();
        assert!(row.error.as_deref().unwrap().contains("lost by `toporec repair`"), "{row:?}");
    }
    answers(&index, &Damage::refuse()).unwrap();
    // A run takes the changed scan anew (the gone one stays reported until pruned).
    let p = index.parent().unwrap().join("again.toml");
    std::fs::write(&p, std::fs::read_to_string(index.join("pipeline.toml")).unwrap()).unwrap();
    let o = toporec(&["run", p.to_str().unwrap(), "--index", index.to_str().unwrap(), "--no-progress"]);
    assert!(text(&o.stderr).contains("1 replaced"), "{}", text(&o.stderr));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, failure_persistence: None, ..ProptestConfig::default() })]

    /// A random bit of a random committed part flipped: every read that touches the part ends
    /// in the damage error, never in other answers.
    #[test]
    fn a_random_flip_never_gives_other_answers(pick in 0usize..1000, at in 0.0f64..1.0, bit in 0u8..8) {
        let index = copy_of_intact(&format!("damage_flip_{pick}_{bit}"));
        let manifest = read_json(&index.join("manifest.json"));
        let files = manifest["files"].as_array().unwrap();
        let rel = files[pick % files.len()]["path"].as_str().unwrap().to_string();
        let path = index.join(&rel);
        let len = std::fs::metadata(&path).unwrap().len() as usize;
        flip(&path, ((len as f64 * at) as usize).min(len - 1), bit);
        let intact_answers = answers(intact(), &Damage::refuse()).unwrap();
        match answers(&index, &Damage::refuse()) {
            Ok(a) => prop_assert_eq!(a, intact_answers, "{} read, with other answers", rel),
            Err(e) => prop_assert!(e.to_string().contains("damaged"), "{}", e),
        }
        for table in ["scans", "diagrams"] {
            match table_read(&index, table, &Damage::refuse()) {
                Ok(rows) => prop_assert_eq!(rows, table_read(intact(), table, &Damage::refuse()).unwrap()),
                Err(e) => prop_assert!(e.to_string().contains("damaged"), "{}", e),
            }
        }
        let _ = std::fs::remove_dir_all(index.parent().unwrap());
    }
}
