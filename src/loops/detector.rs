//! The online loop detector: scans arrive one at a time, in time order, from a running system
//! (a SLAM front end); each is described, searched against the earlier scans outside its own
//! session's exclusion window, and added. Its matches are `toporec loops`' on the same scans in
//! the same order (both search the method's [`Searcher`], grown in that order, under the same
//! rule).

use super::exclusion::{Exclusion, allowed_by, distance3};
pub use super::row::Match;
use crate::methods::{Method, Searcher};
use crate::types::Point;

/// Seconds the last [`Detector::add`] spent in each step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AddTimes {
    /// Describing the scan.
    pub describe: f64,
    /// Searching the earlier scans and inserting this one.
    pub search_insert: f64,
}

/// An online loop detector for one method computed from raw scans (toporec-plus, ScanContext,
/// SOLiD, M2DP).
pub struct Detector {
    method: Method,
    exclusion: Exclusion,
    threshold: f64,
    growing: Box<dyn Searcher>,
    /// Per scan added: session (an index into `sessions`), time (µs), pose, position within
    /// its session.
    session: Vec<u32>,
    utime: Vec<Option<i64>>,
    pose: Vec<Option<[f64; 3]>>,
    in_session: Vec<usize>,
    /// Sessions by index, and the scans added of each.
    sessions: Vec<(String, usize)>,
    last: AddTimes,
}

impl Detector {
    /// A detector for `method`, leaving out each scan's own session's scans within `exclusion`,
    /// accepting matches below `threshold`; an error for a method that does not describe raw
    /// scans (TopoRec needs an index's codebook; imported vectors are made elsewhere).
    pub fn new(method: Method, exclusion: Exclusion, threshold: f64) -> Result<Self, String> {
        if !method.is_computed() {
            return Err(format!(
                "{}: the loop detector takes the methods computed from raw scans ({})",
                method.name,
                crate::methods::computed_names().join(", ")
            ));
        }
        if !(threshold.is_finite() && threshold > 0.0) {
            return Err(format!("threshold {threshold}: must be in (0, inf)"));
        }
        let growing = method.searcher(Vec::new(), method.len());
        Ok(Detector {
            method,
            exclusion,
            threshold,
            growing,
            session: Vec::new(),
            utime: Vec::new(),
            pose: Vec::new(),
            in_session: Vec::new(),
            sessions: Vec::new(),
            last: AddTimes::default(),
        })
    }

    /// The method.
    pub fn method(&self) -> &Method {
        &self.method
    }

    /// The threshold below which a match is a loop.
    pub fn threshold(&self) -> f64 {
        self.threshold
    }

    /// Scans added.
    pub fn len(&self) -> usize {
        self.growing.len()
    }

    /// Whether no scan was added.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// What the last [`Detector::add`] cost.
    pub fn last_times(&self) -> AddTimes {
        self.last
    }

    /// Describes the raw scan `points` (sensor frame, metres, z up), taken at `utime` (µs) in
    /// `session`, at `pose` when known; returns its best allowed earlier match (accepted or
    /// not: see [`Match::accepted`]), and adds it. An error when the method cannot describe it
    /// (the scan is then not added).
    pub fn add(
        &mut self,
        points: &[Point],
        utime: Option<i64>,
        session: &str,
        pose: Option<[f64; 3]>,
    ) -> Result<Option<Match>, String> {
        let t = std::time::Instant::now();
        let descriptor = match self.method.describe_raw(points) {
            Some(Ok(d)) => d,
            Some(Err(e)) => return Err(e),
            None => return Err(format!("{}: not computed from raw scans", self.method.name)),
        };
        if !descriptor.iter().all(|v| v.is_finite()) {
            return Err("the descriptor has non-finite values".into());
        }
        let describe = t.elapsed().as_secs_f64();
        let found = self.add_descriptor(&descriptor, utime, session, pose);
        self.last.describe = describe;
        Ok(found)
    }

    /// As [`Detector::add`], for a scan already described by the method.
    pub fn add_descriptor(
        &mut self,
        descriptor: &[f32],
        utime: Option<i64>,
        session: &str,
        pose: Option<[f64; 3]>,
    ) -> Option<Match> {
        let t = std::time::Instant::now();
        let session_id = match self.sessions.iter().position(|s| s.0 == session) {
            Some(i) => i,
            None => {
                self.sessions.push((session.to_string(), 0));
                self.sessions.len() - 1
            }
        };
        let in_session = self.sessions[session_id].1;
        self.sessions[session_id].1 += 1;
        let session_id = session_id as u32;
        let allowed = |row: usize| {
            allowed_by(
                self.exclusion,
                (session_id, in_session, utime),
                (self.session[row], self.in_session[row], self.utime[row]),
            )
        };
        let (hits, _) = self.growing.search(descriptor, 2, Some(&allowed));
        let found = hits.first().and_then(|best| {
            let truth = pose.zip(self.pose[best.row]).map(|(a, b)| distance3(a, b));
            let found = Match::of_hits(&hits, best.row, truth)?;
            Some(Match { accepted: found.distance < self.threshold, ..found })
        });
        self.growing.push(descriptor);
        self.session.push(session_id);
        self.utime.push(utime);
        self.pose.push(pose);
        self.in_session.push(in_session);
        self.last = AddTimes { describe: 0.0, search_insert: t.elapsed().as_secs_f64() };
        found
    }
}

/// The method `name` as `index` computes it (its settings from the index's manifest), for a
/// detector whose descriptors match the index's.
pub fn method_of_index(index: &std::path::Path, name: &str) -> crate::Result<Method> {
    let reader = crate::sinks::index::IndexReader::open(index)?;
    reader.manifest().and_then(|m| m.methods.get(name)).and_then(|entry| entry.method(name)).ok_or_else(
        || crate::Error::index(index, format!("holds no method `{name}` computed from raw scans")),
    )
}
