//! What the intact parts of an index tell of the scans its damaged parts held ([`super::damage`]):
//! for naming them (`--skip-damaged`) and for `toporec repair`.

use super::MANIFEST_FILE;
use super::damage::{Checked, DamagedPart, checked_bytes, damaged_parts};
use super::manifest::Manifest;
use super::resolve;
use crate::error::Result;
use crate::sinks::parquet::{ScanRow, Status};
use crate::sinks::schema::tables;
use std::collections::{BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};

/// What the intact parts of an index tell of its scans, per session: each scan's status (from
/// `scans`), and which tables hold its rows.
#[derive(Default)]
pub(crate) struct Holdings {
    /// Scan id → its row in the intact `scans` parts.
    pub scan_rows: HashMap<String, ScanRow>,
    /// (table, method) → the ids with rows in its intact parts.
    pub rows_in: HashMap<(String, Option<String>), HashSet<String>>,
    /// Session → every id any intact part names.
    pub by_session: HashMap<String, BTreeSet<String>>,
}

impl Holdings {
    /// Reads the scan ids of every intact part (those not in `damaged`).
    pub(crate) fn read(root: &Path, manifest: &Manifest, damaged: &[DamagedPart]) -> Result<Self> {
        let broken: HashSet<&str> = damaged.iter().map(|d| d.path.as_str()).collect();
        let mut h = Holdings::default();
        for f in manifest.files.iter().filter(|f| !broken.contains(f.path.as_str())) {
            let Checked::Intact(bytes) = checked_bytes(root, f, manifest.generation)? else { continue };
            let path = resolve(root, &f.path);
            let ids: Vec<String> = if f.table == tables::SCANS {
                let rows = super::reader::read_scans_in(&path, bytes, &f.session)?;
                let ids = rows.iter().map(|r| r.scan_id.clone()).collect();
                h.scan_rows.extend(rows.into_iter().map(|r| (r.scan_id.clone(), r)));
                ids
            } else {
                super::reader::scan_ids_in(&path, bytes)?
            };
            let method = (f.table == tables::DESCRIPTORS).then(|| f.method_name().to_string());
            h.by_session.entry(f.session.clone()).or_default().extend(ids.iter().cloned());
            h.rows_in.entry((f.table.clone(), method)).or_default().extend(ids);
        }
        Ok(h)
    }

    /// The scans `part` held, as far as the intact parts tell: for `scans`, the scans of its
    /// session that other tables hold rows of but no intact `scans` part has a row for (its
    /// skipped and error scans, which have rows nowhere else, cannot be told); for `diagrams`
    /// and `descriptors`, the ok scans of its session (or of unknown status) without a row in
    /// the table's intact parts.
    pub(crate) fn held(&self, part: &DamagedPart) -> Vec<String> {
        let Some(ids) = self.by_session.get(&part.session) else { return Vec::new() };
        let key = (part.table.clone(), part.method.clone());
        let empty = HashSet::new();
        let present = self.rows_in.get(&key).unwrap_or(&empty);
        ids.iter()
            .filter(|id| !present.contains(*id))
            .filter(|id| {
                part.table == tables::SCANS || self.scan_rows.get(*id).is_none_or(|r| r.status == Status::Ok)
            })
            .cloned()
            .collect()
    }
}

/// `parts` with the scans each held filled in (see `Holdings::held`), read from the intact
/// parts of their indexes.
pub fn held_scans(parts: Vec<DamagedPart>) -> Result<Vec<DamagedPart>> {
    let mut holdings: HashMap<PathBuf, Holdings> = HashMap::new();
    let mut out = Vec::with_capacity(parts.len());
    for mut p in parts {
        if !holdings.contains_key(&p.index) {
            let Some(manifest) = Manifest::load(&p.index.join(MANIFEST_FILE))? else {
                out.push(p);
                continue;
            };
            let damaged = damaged_parts(&p.index, &manifest)?;
            holdings.insert(p.index.clone(), Holdings::read(&p.index, &manifest, &damaged)?);
        }
        p.scans = holdings[&p.index].held(&p);
        out.push(p);
    }
    Ok(out)
}
