//! The drive and its loops, drawn from what the search found: each session's trajectory from
//! its poses (or its scans in walking order when none has a pose), each checked match an edge,
//! kept or rejected ([`crate::plot::loops_map`], PNG and SVG beside the output).

use super::summary::Summary;
use crate::error::Result;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A scan of the walk: its id, session and pose (x, y, z), in time order.
#[derive(Clone, Debug, PartialEq)]
pub struct Walked {
    /// The scan.
    pub scan_id: String,
    /// Its session.
    pub session: String,
    /// Its pose, when it has one.
    pub pose: Option<[f64; 3]>,
}

/// Draws `summary`'s loops over the walk of `sessions` into `<out stem>.png` and `.svg`;
/// returns the files.
pub(super) fn draw(out: &Path, summary: &Summary, sessions: &[String]) -> Result<Vec<PathBuf>> {
    let walk: Vec<&Walked> = summary.walk.iter().filter(|w| sessions.contains(&w.session)).collect();
    let ordered = walk.iter().all(|w| w.pose.is_none());
    let place: HashMap<&str, [f64; 2]> = walk
        .iter()
        .enumerate()
        .map(|(i, w)| {
            let p = match (&w.pose, ordered) {
                (Some(p), false) => [p[0], p[1]],
                (None, false) => [f64::NAN; 2],
                (_, true) => [i as f64, 0.0],
            };
            (w.scan_id.as_str(), p)
        })
        .collect();
    let tracks: Vec<(String, Vec<[f64; 2]>)> = sessions
        .iter()
        .map(|s| {
            let track = walk.iter().filter(|w| &w.session == s).map(|w| place[w.scan_id.as_str()]).collect();
            (s.clone(), track)
        })
        .collect();
    let edges: Vec<crate::plot::LoopEdge> = summary
        .checked
        .iter()
        .filter_map(|r| {
            let (from, to) = (place.get(r.query_scan.as_str())?, place.get(r.matched_scan.as_str())?);
            Some(crate::plot::LoopEdge {
                from: *from,
                to: *to,
                kept: r.found.accepted,
                rejected_by_map: r.in_map == Some(false),
            })
        })
        .collect();
    let methods: Vec<&str> = summary.methods.iter().map(|m| m.method.as_str()).collect();
    let title = if ordered {
        format!("loops ({}): no poses, scans in walking order", methods.join(", "))
    } else {
        format!("loops ({})", methods.join(", "))
    };
    // The first map's corrected poses, by the walk's scans (the map's walk is its method's).
    let corrected: Vec<(String, Vec<[f64; 2]>)> = match summary.maps.iter().find(|m| !m.corrected.is_empty())
    {
        Some(map) if !ordered && map.corrected.len() == summary.walk.len() => sessions
            .iter()
            .map(|s| {
                let track = summary
                    .walk
                    .iter()
                    .zip(&map.corrected)
                    .filter(|(w, _)| &w.session == s)
                    .map(|(_, p)| p.map_or([f64::NAN; 2], |p| [p.translation.x, p.translation.y]))
                    .collect();
                (s.clone(), track)
            })
            .collect(),
        _ => Vec::new(),
    };
    crate::plot::loops_map(&out.with_extension(""), &title, &tracks, &corrected, &edges, ordered)
}
