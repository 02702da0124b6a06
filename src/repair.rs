//! `toporec repair`: an index's damaged parts rebuilt from what is intact, in one commit.
//!
//! Every read checks each committed part against the checksum its commit recorded
//! ([`crate::sinks::index::damage`]); `verify` lists the parts that fail. A repair takes those
//! parts out and rebuilds their rows, nothing else:
//!
//! * the TopoRec descriptors of scans whose diagrams are intact, from those diagrams, with the
//!   index's codebook (no source is read);
//! * every other row — `scans`, `diagrams`, the other methods' descriptors — from the sources
//!   of the index's pipeline (the manifest's `pipeline`): only the sessions the damaged parts
//!   belong to are read, and only the scans they held are described. A scan is taken again
//!   only from the bytes the index was made from: its fingerprint equals the one in its intact
//!   `scans` row, or, when that row was in a damaged part, its recomputed descriptors equal those
//!   the intact parts hold. In a session whose `scans` part was damaged, a scan of the source that
//!   no intact part names (its skipped and error scans have rows nowhere else) is indexed again.
//!
//! A scan whose source is gone or changed is lost: its other rows are removed and it stays as
//! an `error` row saying so (a later `toporec run` indexes it anew), never silently dropped.
//! Rows of an imported method cannot be rebuilt: they are reported, to be imported again.
//!
//! Everything is one commit: killed before it, the index is as it was; after it, `verify` is
//! clean and, with the sources unchanged, every answer equals the intact index's.

use crate::describe::Describer;
use crate::error::{Error, Result};
use crate::methods::{IMPORTED, TOPOREC};
use crate::pipeline::config::Pipeline;
use crate::pipeline::{RunOptions, stored_descriptors};
use crate::sinks::index::IndexWriter;
use crate::sinks::index::damage::{Damage, DamagedPart};
use crate::sinks::index::holdings::Holdings;
use crate::sinks::index::reader::IndexReader;
use crate::sinks::index::writer::MethodDescriptor;
use crate::sinks::parquet::{ScanRow, Status};
use crate::sinks::schema::tables;
use crate::sources::{Scan, ScanFailure};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};

/// Arguments of `toporec repair`.
#[derive(Clone, Debug)]
pub struct RepairArgs {
    /// The index.
    pub index: PathBuf,
    /// Worker threads (≥ 1).
    pub threads: usize,
}

/// A scan a repair could not take again.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct LostScan {
    /// The scan.
    pub scan_id: String,
    /// Its session.
    pub session: String,
    /// Why: its source is gone, changed, or unreadable.
    pub why: String,
}

/// What a repair did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Repaired {
    /// The damaged parts, each with the scans it held.
    pub damaged: Vec<DamagedPart>,
    /// TopoRec descriptors made from stored diagrams.
    pub from_diagrams: u64,
    /// Scans read again from their sources.
    pub from_sources: u64,
    /// Scans lost: their source is gone or changed.
    pub lost: Vec<LostScan>,
    /// Imported methods whose rows were in damaged parts (to be imported again).
    pub imported: Vec<String>,
    /// Seconds.
    pub seconds: f64,
}

/// What the damaged parts held of one scan.
#[derive(Clone, Debug, Default)]
struct Need {
    session: String,
    scans_row: bool,
    diagram: bool,
    /// Descriptor methods, TopoRec included.
    methods: BTreeSet<String>,
}

impl Need {
    /// Whether only its TopoRec descriptor is missing (made from its stored diagram).
    fn only_toporec(&self) -> bool {
        !self.scans_row && !self.diagram && self.methods.len() == 1 && self.methods.contains(TOPOREC)
    }
}

/// Repairs the index at `args.index` (see the module doc).
pub fn repair(args: &RepairArgs) -> Result<Repaired> {
    let start = std::time::Instant::now();
    let index = &args.index;
    let (mut writer, damaged) = IndexWriter::open_for_repair(index)?;
    if damaged.is_empty() {
        return Ok(Repaired { seconds: start.elapsed().as_secs_f64(), ..Default::default() });
    }
    let manifest = writer.manifest().clone();
    let holdings = Holdings::read(index, &manifest, &damaged)?;
    let damaged: Vec<DamagedPart> = damaged
        .into_iter()
        .map(|mut d| {
            d.scans = holdings.held(&d);
            d
        })
        .collect();
    let mut out = Repaired::default();
    // What each scan needs, and the sessions whose scans part was damaged.
    let mut needs: BTreeMap<String, Need> = BTreeMap::new();
    let mut scans_damaged: HashSet<String> = HashSet::new();
    let imported: HashSet<&str> =
        manifest.methods.iter().filter(|(_, e)| e.kind == IMPORTED).map(|(m, _)| m.as_str()).collect();
    for part in &damaged {
        writer.drop_damaged(&part.path);
        if let Some(m) = part.method.as_deref().filter(|m| imported.contains(m)) {
            out.imported.push(m.to_string());
            continue;
        }
        if part.table == tables::SCANS {
            scans_damaged.insert(part.session.clone());
        }
        for id in &part.scans {
            let need = needs
                .entry(id.clone())
                .or_insert_with(|| Need { session: part.session.clone(), ..Default::default() });
            match (part.table.as_str(), &part.method) {
                (tables::SCANS, _) => need.scans_row = true,
                (tables::DIAGRAMS, _) => need.diagram = true,
                (_, Some(m)) => {
                    need.methods.insert(m.clone());
                }
                _ => {}
            }
        }
    }
    out.imported.sort();
    out.imported.dedup();
    // The TopoRec descriptors of scans with an intact diagram and `scans` row are made from
    // that diagram below; every other scan is read again.
    let from_source: BTreeMap<String, Need> = needs
        .into_iter()
        .filter(|(id, n)| !(n.only_toporec() && holdings.scan_rows.contains_key(id)))
        .collect();
    if !from_source.is_empty() || !scans_damaged.is_empty() {
        let pipeline = Pipeline::of_index(index).map_err(|e| {
            Error::index(index, format!("its pipeline is needed to read the damaged scans again: {e}"))
        })?;
        let taken = reread(&mut writer, &pipeline, &holdings, &from_source, &scans_damaged, args, &mut out)?;
        out.from_sources = taken;
    }
    let opts =
        RunOptions { commit_every: u64::MAX, commit_seconds: f64::INFINITY, ..RunOptions::new(args.threads) };
    if let Some(codebook) = manifest.codebook(index)? {
        let (_, _, made) = stored_descriptors(&mut writer, &codebook, args.threads, &opts, None)?;
        out.from_diagrams = made;
    }
    writer.commit()?;
    out.damaged = damaged;
    out.lost.sort_by(|a, b| (&a.session, &a.scan_id).cmp(&(&b.session, &b.scan_id)));
    out.seconds = start.elapsed().as_secs_f64();
    Ok(out)
}

/// Reads the sessions of `from_source` (and of `scans_damaged`) again from the pipeline's
/// sources, describes the scans wanted, and adds the rows their damaged parts held; a scan
/// whose bytes are not those the index was made from, or that the sources no longer yield, is
/// lost. Returns the scans taken again.
fn reread(
    writer: &mut IndexWriter,
    pipeline: &Pipeline,
    holdings: &Holdings,
    from_source: &BTreeMap<String, Need>,
    scans_damaged: &HashSet<String>,
    args: &RepairArgs,
    out: &mut Repaired,
) -> Result<u64> {
    let index = &args.index;
    let manifest = writer.manifest().clone();
    let settings = manifest.settings_hash.clone();
    let describer = Describer {
        preprocess: pipeline.preprocess.clone(),
        squared: pipeline.persistence.squared,
        codebook: manifest.codebook(index)?,
        topological: pipeline.methods.toporec,
        computed: pipeline.methods.computed.clone(),
    };
    let codebook_id = describer.codebook.as_ref().map(|c| c.id());
    let computed = describer.computed_ids();
    let dims = pipeline.persistence.dims.clone();
    // The intact descriptors of scans whose `scans` row was lost: what their bytes must give.
    let unfingerprinted: HashSet<&str> = from_source
        .iter()
        .filter(|(id, _)| !holdings.scan_rows.contains_key(*id))
        .map(|(id, _)| id.as_str())
        .collect();
    let expected = intact_descriptors(index, &unfingerprinted, from_source)?;
    let mut sessions: HashSet<String> = from_source.values().map(|n| n.session.clone()).collect();
    sessions.extend(scans_damaged.iter().cloned());
    let wanted = |session: &str, id: &str| {
        from_source.contains_key(id)
            || (scans_damaged.contains(session)
                && !holdings.scan_rows.contains_key(id)
                && !holdings.by_session.get(session).is_some_and(|ids| ids.contains(id)))
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.max(1))
        .build()
        .map_err(|e| Error::invalid(format!("starting {} threads: {e}", args.threads)))?;
    let mut seen: HashSet<String> = HashSet::new();
    let mut taken = 0u64;
    let mut position = 0u64;
    let mut batch: Vec<(u64, std::result::Result<Scan, ScanFailure>)> = Vec::new();
    let mut flush = |batch: &mut Vec<(u64, std::result::Result<Scan, ScanFailure>)>,
                     writer: &mut IndexWriter,
                     out: &mut Repaired|
     -> Result<()> {
        let items = std::mem::take(batch);
        let results: Vec<crate::describe::ScanResult> = pool.install(|| {
            items.into_par_iter().map(|(seq, item)| describer.scan_rows(item, seq, &settings)).collect()
        });
        for r in results {
            let id = r.row.scan_id.clone();
            let session = r.row.session.clone();
            let intact = holdings.scan_rows.get(&id);
            // The bytes must be those the index was made from.
            let changed = match intact {
                Some(row) if row.fingerprint != r.row.fingerprint => Some(format!(
                    "its source changed since it was indexed (fingerprint {}, now {})",
                    row.fingerprint.as_deref().unwrap_or("none"),
                    r.row.fingerprint.as_deref().unwrap_or("none")
                )),
                Some(_) => None,
                None => differs(&r, codebook_id.as_deref(), &computed, expected.get(&id)),
            };
            if let Some(why) = changed {
                lose(writer, &id, &session, intact, &settings, why, out)?;
                continue;
            }
            let descriptors = r.method_descriptors(codebook_id.as_deref(), &computed);
            match from_source.get(&id) {
                Some(need) => {
                    let descriptors: Vec<MethodDescriptor> =
                        descriptors.into_iter().filter(|d| need.methods.contains(&d.method)).collect();
                    let intact_toporec = holdings
                        .rows_in
                        .get(&(tables::DESCRIPTORS.to_string(), Some(TOPOREC.to_string())))
                        .is_some_and(|ids| ids.contains(&id));
                    let has_toporec = (intact_toporec && !need.methods.contains(TOPOREC))
                        || descriptors.iter().any(|d| d.method == TOPOREC);
                    let row = need.scans_row.then(|| (r.row.clone(), has_toporec));
                    let diagram = if need.diagram { r.diagram.as_ref() } else { None };
                    writer.add_rows(&session, &id, row, diagram, &dims, descriptors)?;
                }
                // A scan no intact part names, in a session whose scans part was damaged.
                None => writer.write_scan(r.row.clone(), r.diagram.as_ref(), &dims, descriptors)?,
            }
            taken += 1;
        }
        Ok(())
    };
    for stream in crate::sources::reread::Rereader::new(&pipeline.sources).sessions(&sessions) {
        for item in stream {
            let (id, session) = match &item {
                Ok(s) => (s.id.clone(), s.session.clone()),
                Err(f) => (f.id.clone(), f.session.clone()),
            };
            position += 1;
            if !sessions.contains(&session) || !wanted(&session, &id) || !seen.insert(id.clone()) {
                continue;
            }
            // The scan keeps its place in the input when its row tells it.
            let seq = holdings.scan_rows.get(&id).map_or(position - 1, |r| r.seq);
            batch.push((seq, item));
            if batch.len() >= 16 * args.threads.max(1) {
                flush(&mut batch, writer, out)?;
            }
        }
    }
    flush(&mut batch, writer, out)?;
    for (id, need) in from_source.iter().filter(|(id, _)| !seen.contains(*id)) {
        let why = "its source no longer yields it (gone, or not readable)".to_string();
        lose(writer, id, &need.session, holdings.scan_rows.get(id), &settings, why, out)?;
    }
    Ok(taken)
}

/// The intact descriptors of `ids`, by scan and method (any method whose part for the scan is
/// intact).
fn intact_descriptors(
    index: &Path,
    ids: &HashSet<&str>,
    needs: &BTreeMap<String, Need>,
) -> Result<HashMap<String, HashMap<String, Vec<f32>>>> {
    let mut out: HashMap<String, HashMap<String, Vec<f32>>> = HashMap::new();
    if ids.is_empty() {
        return Ok(out);
    }
    let sessions: Vec<String> = ids
        .iter()
        .filter_map(|id| needs.get(*id).map(|n| n.session.clone()))
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let reader = IndexReader::open_with(index, &Damage::skip())?;
    for method in reader.methods()? {
        let length = match reader.manifest().and_then(|m| m.methods.get(&method)) {
            Some(e) if e.kind == IMPORTED => continue,
            Some(e) => Some(e.length),
            None => reader.manifest().and_then(|m| m.descriptor_length),
        };
        for row in reader.descriptors_of(&method, &sessions, length)? {
            if ids.contains(row.scan_id.as_str()) {
                out.entry(row.scan_id).or_default().insert(method.clone(), row.descriptor);
            }
        }
    }
    Ok(out)
}

/// Why a described scan is not the one whose intact descriptors are `expected` (none: nothing
/// intact to compare with, taken as it is).
fn differs(
    r: &crate::describe::ScanResult,
    codebook_id: Option<&str>,
    computed: &[(String, String)],
    expected: Option<&HashMap<String, Vec<f32>>>,
) -> Option<String> {
    let expected = expected?;
    if r.row.status != Status::Ok {
        return Some(format!("its source no longer gives it (now {})", r.row.status.as_str()));
    }
    let now: HashMap<String, Vec<f32>> =
        r.method_descriptors(codebook_id, computed).into_iter().map(|d| (d.method, d.row.values)).collect();
    for (method, values) in expected {
        let same = now.get(method).is_some_and(|v| {
            v.len() == values.len() && v.iter().zip(values).all(|(a, b)| a.to_bits() == b.to_bits())
        });
        if !same {
            return Some(format!(
                "its source changed since it was indexed (its {method} descriptor differs)"
            ));
        }
    }
    None
}

/// Takes scan `id` out of the index (every row of it) and keeps it as an `error` row saying why.
fn lose(
    writer: &mut IndexWriter,
    id: &str,
    session: &str,
    intact: Option<&ScanRow>,
    settings: &str,
    why: String,
    out: &mut Repaired,
) -> Result<()> {
    writer.remove_in(id, session);
    let message = format!(
        "lost by `toporec repair`: a part holding its rows was damaged, and {why}; `toporec run` indexes it anew"
    );
    let row = match intact {
        Some(r) => ScanRow { status: Status::Error, error: Some(message), kept_points: 0, ..r.clone() },
        None => ScanRow {
            scan_id: id.to_string(),
            fingerprint: None,
            settings_hash: settings.to_string(),
            session: session.to_string(),
            seq: 0,
            source_path: String::new(),
            message_index: None,
            utime: None,
            pose: None,
            raw_points: 0,
            kept_points: 0,
            status: Status::Error,
            error: Some(message),
        },
    };
    writer.write_scan(row, None, &[], Vec::new())?;
    out.lost.push(LostScan { scan_id: id.to_string(), session: session.to_string(), why });
    Ok(())
}
