//! The query scans read again from the query index's sources and described under each
//! condition (other than as-recorded) by each method.

use super::{PlacesArgs, Prepared, Redescribed};
use crate::error::{Error, Result};
use crate::eval::conditions::{Condition, NotApplicable};
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// `(condition, method) → scan id → descriptor`.
pub(super) type Redescriptions = HashMap<(usize, usize), HashMap<String, Redescribed>>;

/// Re-reads every query scan through the query index's sources and describes it, under each
/// condition other than as-recorded, with each method: `(condition, method) → scan id →
/// descriptor`. Each raw scan is read once and dropped once described.
pub(super) fn redescribe(
    a: &PlacesArgs,
    queries_index: &Path,
    prepared: &[Prepared],
    conditions: &[Condition],
) -> Result<(Redescriptions, Option<f64>)> {
    let wanted: HashSet<&str> =
        prepared.iter().flat_map(|p| p.queries.iter().map(|q| q.scan_id.as_str())).collect();
    let pipeline = crate::pipeline::config::Pipeline::of_index(queries_index)?;
    let needs_unit = conditions.iter().any(|c| matches!(c, Condition::Paper(_)));
    let mut metric = pipeline.preprocess.clone();
    metric.normalize = false;
    let mut found = 0usize;
    let mut per_scan: Vec<(String, Vec<Vec<Redescribed>>)> = Vec::new();
    let mut units: Vec<f64> = Vec::new();
    let mut rows = crate::sinks::index::IndexReader::open(queries_index)?.scans()?;
    rows.retain(|r| wanted.contains(r.scan_id.as_str()));
    rows.sort_by_key(|r| r.seq);
    let places: Vec<_> = rows.iter().map(|r| r.place()).collect();
    let rereader = crate::sources::reread::Rereader::new(&pipeline.sources);
    {
        let scans = rereader.stream(&places).filter_map(|(_, item)| item.ok());
        let described: Vec<(String, Vec<Vec<Redescribed>>, f64)> = scans
            .par_bridge()
            .map(|scan| {
                let unit = if needs_unit {
                    crate::preprocess::preprocess(scan.points.clone(), scan.fingerprint, &metric)
                        .map(|mut pts| crate::preprocess::normalize(&mut pts))
                        .unwrap_or(1.0)
                } else {
                    1.0
                };
                let seed = a.seed ^ crate::preprocess::seed_of(&scan.id);
                let per_condition = conditions
                    .iter()
                    .map(|c| {
                        if *c == Condition::AsRecorded {
                            return Vec::new();
                        }
                        let points = c.apply(&scan.points, scan.ring.as_deref(), seed, unit);
                        prepared
                            .iter()
                            .map(|p| match &points {
                                Err(NotApplicable(why)) => Err(format!("{}: {why}", scan.id)),
                                Ok(points) => {
                                    let conditioned = crate::sources::Scan {
                                        points: points.clone(),
                                        ring: None,
                                        intensity: None,
                                        ..scan_header(&scan)
                                    };
                                    p.engine.describe_scan(conditioned).map_err(|e| e.to_string())
                                }
                            })
                            .collect()
                    })
                    .collect();
                (scan.id.clone(), per_condition, unit)
            })
            .collect();
        found += described.len();
        for (id, per_condition, unit) in described {
            per_scan.push((id, per_condition));
            units.push(unit);
        }
    }
    if found < wanted.len() {
        return Err(Error::index(
            queries_index,
            format!("{found} of {} query scans could be re-read from the index's sources", wanted.len()),
        ));
    }
    let mut out: Redescriptions = HashMap::new();
    for (id, per_condition) in per_scan {
        for (ci, per_method) in per_condition.into_iter().enumerate() {
            for (mi, r) in per_method.into_iter().enumerate() {
                out.entry((ci, mi)).or_default().insert(id.clone(), r);
            }
        }
    }
    let mean_unit = (needs_unit && !units.is_empty()).then(|| units.iter().sum::<f64>() / units.len() as f64);
    Ok((out, mean_unit))
}

/// A scan's identity (id, fingerprint, session, path, time, pose) without its points.
fn scan_header(scan: &crate::sources::Scan) -> crate::sources::Scan {
    crate::sources::Scan {
        id: scan.id.clone(),
        fingerprint: scan.fingerprint,
        session: scan.session.clone(),
        path: scan.path.clone(),
        message_index: scan.message_index,
        utime: scan.utime,
        points: Vec::new(),
        intensity: None,
        ring: None,
        raw_points: scan.raw_points,
        pose: scan.pose,
        no_pose: scan.no_pose,
    }
}
