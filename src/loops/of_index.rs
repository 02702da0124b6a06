//! The loops of an index: every method's rows, thresholded, checked, scored and written.

use super::exclusion::Exclusion;
use super::map::{self, Frames, Vertex};
use super::matching::{Allowed, best_matches_counted, query_descriptors, rows};
use super::row::{LoopRow, g2o_path, write_rows};
use super::summary::{MethodSummary, Summary, progress_bar, protocol_scores};
use super::threshold::{Calibration, calibrate, calibration_path, given_threshold};
use super::{LoopsArgs, verify};
use crate::error::{Error, Result};
use crate::search::Engine;
use crate::sinks::index::damage::Damage;
use crate::sinks::index::reader::IndexedScan;
use std::collections::HashMap;

/// Runs `toporec loops`: the rows of every method, written to `a.out`; with `calibrate`, the
/// thresholds written beside it (`<out stem>.calibration.json`).
pub(super) fn search(a: &LoopsArgs) -> Result<Summary> {
    if !(a.target_precision > 0.0 && a.target_precision <= 1.0) {
        return Err(Error::invalid(format!("--target-precision {}: must be in (0, 1]", a.target_precision)));
    }
    if let Some(band) = a.false_beyond.filter(|&b| b <= a.revisit_radius || b.is_nan()) {
        return Err(Error::invalid(format!(
            "--false-beyond {band}: must be beyond --revisit-radius {}",
            a.revisit_radius
        )));
    }
    if a.threshold.is_some() as u8 + a.threshold_from.is_some() as u8 + a.calibrate as u8 > 1 {
        return Err(Error::invalid("--threshold, --threshold-from and --calibrate: give one".to_string()));
    }
    let Some(index) = a.index.as_deref() else {
        return Err(Error::invalid("loops: give --index DIR, or sources to index"));
    };
    let methods: Vec<String> = if a.methods.is_empty() {
        crate::search::index_methods(index)?.into_iter().map(|m| m.name).collect()
    } else {
        a.methods.clone()
    };
    let verifying = a.verifies();
    let in_sessions = |s: &IndexedScan| a.sessions.is_empty() || a.sessions.contains(&s.session);
    let exclusion = match a.exclude_scans {
        Some(n) => Exclusion::Scans(n),
        None => Exclusion::Seconds(a.exclude_seconds),
    };
    let damage = Damage::skipping(a.skip_damaged);
    let reader = crate::sinks::index::reader::IndexReader::open_with(index, &damage)?;
    // The stored poses (with yaw) are read only for a map, its graph or its cloud.
    let wants_map = !a.no_optimize || a.g2o.is_some() || a.cloud.is_some();
    let stored: HashMap<(String, String), crate::sinks::index::reader::ScanRecord> = if wants_map {
        reader.scans()?.into_iter().map(|r| ((r.session.clone(), r.scan_id.clone()), r)).collect()
    } else {
        HashMap::new()
    };
    let origins = reader.manifest().map(|m| m.poses.clone()).unwrap_or_default();
    let frame_of = |session: &str| -> usize {
        match a.frames {
            Frames::Shared => 0,
            Frames::Own => 1 + a.sessions.iter().position(|s| s == session).unwrap_or(usize::MAX - 1),
            // Pose files (and poses of unknown origin) share one frame; each log's own poses,
            // and each KITTI sequence's (relative to its first frame), are a frame of their own.
            Frames::Auto => match origins.iter().position(|o| o.sessions.iter().any(|s| s == session)) {
                Some(i) if origins[i].in_own_frame() => 1 + i,
                _ => 0,
            },
        }
    };
    let mut summary = Summary::default();
    let mut all_rows = Vec::new();
    let mut calibrations = Vec::new();
    // The steps ICP aligned (or could not), by their two scans: aligned once for every method.
    let mut steps_known = HashMap::new();
    for method in &methods {
        let engine = Engine::open_with(index, &[], method, &damage)?.retain(&in_sessions)?;
        if engine.scans.is_empty() {
            return Err(Error::index(index, format!("no {method} descriptors in sessions {:?}", a.sessions)));
        }
        let queries = query_descriptors(index, &engine, &damage)?;
        let rule = Allowed::new(&engine.scans, exclusion);
        if summary.walk.is_empty() {
            summary.walk = rule
                .order
                .iter()
                .map(|&i| {
                    let s = &engine.scans[i];
                    super::Walked { scan_id: s.scan_id.clone(), session: s.session.clone(), pose: s.pose }
                })
                .collect();
        }
        let bar = progress_bar(!a.no_progress, engine.scans.len(), &format!("scans searched ({method})"));
        let matches = best_matches_counted(&engine, &queries, &rule, bar.as_ref());
        if let Some(b) = bar {
            b.finish_and_clear();
        }
        let mut rows = rows(&engine, &matches, &rule);
        // Poses of two frames are not comparable: no true distance between them.
        for r in &mut rows {
            if frame_of(&r.query_session) != frame_of(&r.matched_session) {
                r.found.true_distance_m = None;
            }
        }
        let threshold = match given_threshold(a, method, &engine)? {
            Some(t) => t,
            None => {
                let judged: Vec<(f64, bool)> = rows
                    .iter()
                    .filter_map(|r| {
                        r.found.true_distance_m.map(|t| (r.found.distance, t <= a.revisit_radius))
                    })
                    .collect();
                // No threshold reaching the precision: 0, which accepts nothing.
                let t = calibrate(&judged, a.target_precision).unwrap_or_else(|| {
                    tracing::warn!(
                        "--calibrate: no threshold of `{method}` reaches precision {} on this index ({} matches \
                         with poses); its threshold is 0: no loop accepted",
                        a.target_precision,
                        judged.len()
                    );
                    0.0
                });
                let accepted: Vec<&(f64, bool)> = judged.iter().filter(|j| j.0 < t).collect();
                // (Vacuously 1 when nothing is accepted.)
                let precision = accepted.iter().filter(|j| j.1).count() as f64 / accepted.len().max(1) as f64
                    + f64::from(u8::from(accepted.is_empty()));
                calibrations.push(Calibration {
                    method: method.clone(),
                    id: engine.id.clone(),
                    threshold: t,
                    target_precision: a.target_precision,
                    precision,
                    accepted: accepted.len(),
                    matches: judged.len(),
                    revisit_radius_m: a.revisit_radius,
                });
                t
            }
        };
        for r in &mut rows {
            r.found.accepted = r.found.distance < threshold;
        }
        let below_threshold = rows.iter().filter(|r| r.found.accepted).count();
        if verifying {
            let checks = verify::check(index, &rows, a.limits, !a.no_progress, &damage)?;
            for (r, c) in rows.iter_mut().zip(checks) {
                r.check = c;
                r.found.accepted &= c.is_some_and(|c| c.passed);
            }
        }
        let is_true = |r: &LoopRow| r.found.true_distance_m.is_some_and(|d| d <= a.revisit_radius);
        // Between the radius and `--false-beyond`: neither true nor false.
        let in_band = |t: f64| t > a.revisit_radius && a.false_beyond.is_some_and(|band| t <= band);
        let with_revisit = rule.with_revisit(a.revisit_radius, &frame_of);
        // Whether a row's query has an allowed revisit (one row per query).
        let has_revisit = |r: &LoopRow| with_revisit[rule.order[r.query_vertex]];
        let (curve, auc) = protocol_scores(&rows, &has_revisit, a.revisit_radius, a.false_beyond);
        summary.methods.push(MethodSummary {
            method: method.clone(),
            threshold,
            matched: rows.len(),
            accepted: rows.iter().filter(|r| r.found.accepted).count(),
            accepted_with_poses: rows
                .iter()
                .filter(|r| r.found.accepted && r.found.true_distance_m.is_some_and(|t| !in_band(t)))
                .count(),
            true_positives: rows.iter().filter(|r| r.found.accepted && is_true(r)).count(),
            revisits: with_revisit.iter().filter(|&&w| w).count(),
            revisits_found: rows.iter().filter(|r| r.found.accepted && is_true(r) && has_revisit(r)).count(),
            curve,
            auc,
            verified: verifying.then_some(below_threshold),
            scans: engine.scans.len(),
            untimed: engine.scans.iter().filter(|s| s.utime.is_none()).count(),
        });
        let notes = summary.methods.last().expect("pushed").exclusion_notes(exclusion);
        for n in notes {
            if !summary.notes.contains(&n) {
                summary.notes.push(n);
            }
        }
        let vertices: Vec<Vertex> = rule
            .order
            .iter()
            .map(|&i| {
                let s = &engine.scans[i];
                let pose = stored.get(&(s.session.clone(), s.scan_id.clone())).and_then(|r| r.pose);
                Vertex { scan_id: s.scan_id.clone(), session: s.session.clone(), utime: s.utime, pose }
            })
            .collect();
        if wants_map && vertices.iter().any(|v| v.pose.is_some()) {
            let first = a.sessions.first().cloned().unwrap_or_else(|| vertices[0].session.clone());
            let aligned = if a.odometry == map::Odometry::Icp {
                Some(aligned_steps(index, &vertices, a, &damage, &mut steps_known)?)
            } else {
                None
            };
            let how =
                map::Making { drift: a.odometry_drift, aligned: aligned.as_ref(), optimize: !a.no_optimize };
            let mut made = map::make(method, &vertices, &rows, &frame_of, &first, &how);
            if !a.no_optimize && made.failed.is_none() {
                for (r, kept) in rows.iter_mut().zip(&made.in_map) {
                    r.in_map = *kept;
                }
                let named = (methods.len() > 1).then_some(method.as_str());
                made.written = map::write_poses(&made, &vertices, &a.out, named)?;
            }
            if let Some(path) = &a.g2o {
                let path = g2o_path(path, method);
                map::write_g2o(&path, &made)?;
                summary.g2o.push(path);
            }
            if let Some(path) = &a.cloud {
                let path = if methods.len() > 1 {
                    g2o_path(path, method).with_extension("ply")
                } else {
                    path.clone()
                };
                // The corrected poses; without a map (--no-optimize, or a solve that failed), the stored.
                let poses = if made.corrected.is_empty() { &made.initial } else { &made.corrected };
                summary.clouds.push(super::cloud::write(
                    index,
                    &vertices,
                    poses,
                    &stored,
                    &path,
                    a.cloud_voxel,
                )?);
            }
            summary.maps.push(made);
        } else {
            if !a.no_optimize || a.cloud.is_some() {
                let note = "no map: no scan has a pose (the map needs poses: a log with /odom or /tf, \
                            --poses FILE, or a pipeline's pose source)"
                    .to_string();
                if !summary.notes.contains(&note) {
                    summary.notes.push(note);
                }
            }
            if let Some(path) = &a.g2o {
                // No poses: no vertex to place, only the loops' edges.
                let path = g2o_path(path, method);
                verify::write_g2o(&path, &rows)?;
                summary.g2o.push(path);
            }
        }
        summary.checked.extend(rows.iter().filter(|r| r.found.accepted || r.check.is_some()).cloned());
        all_rows.extend(rows.into_iter().filter(|r| a.all || r.found.accepted));
    }
    write_rows(&a.out, &all_rows)?;
    if a.calibrate {
        let path = calibration_path(&a.out);
        let text = serde_json::to_string_pretty(&calibrations).expect("plain data") + "\n";
        crate::fsutil::write_atomic(&path, text.as_bytes())?;
        summary.calibrations.push(path);
    }
    summary.damaged = crate::sinks::index::holdings::held_scans(damage.found())?;
    Ok(summary)
}

/// The steps between consecutive scans of `walk` aligned again by ICP (`--odometry icp`), by
/// their walk positions. `known` holds every step an earlier method's walk asked for, aligned or
/// not, by its two scans' ids: only the steps new to it are aligned (the same scans give the
/// same step whichever method found the loops).
fn aligned_steps(
    index: &std::path::Path,
    walk: &[Vertex],
    a: &LoopsArgs,
    damage: &Damage,
    known: &mut HashMap<(String, String), Option<map::AlignedStep>>,
) -> Result<std::collections::BTreeMap<(usize, usize), map::AlignedStep>> {
    let key = |u: usize, v: usize| (walk[u].scan_id.clone(), walk[v].scan_id.clone());
    let pairs: Vec<(usize, usize, _)> = map::steps(walk)
        .into_iter()
        .filter_map(|(u, v)| Some((u, v, map::stored_step(&walk[u], &walk[v])?)))
        .collect();
    let new: Vec<_> = pairs.iter().copied().filter(|&(u, v, _)| !known.contains_key(&key(u, v))).collect();
    if !new.is_empty() {
        let aligned = verify::align_steps(index, walk, &new, a.limits, !a.no_progress, damage)?;
        for &(u, v, _) in &new {
            known.insert(key(u, v), aligned.get(&(u, v)).copied());
        }
    }
    Ok(pairs.iter().filter_map(|&(u, v, _)| Some(((u, v), known[&key(u, v)]?))).collect())
}
