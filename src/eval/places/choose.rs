//! Which scans an evaluation takes: by id (`--db-scan`, `--query-scan`), and by distance
//! (`--map-every`, `--query-every`).

use crate::error::{Error, Result};
use crate::sinks::index::IndexedScan;

/// The scans `--db-scan` or `--query-scan` choose: those whose id matches one of the globs
/// (`*`: any run of characters, `/` included; `?`: one; `[…]`: one of), every scan when none
/// is given.
pub(crate) struct Chooser(Option<globset::GlobSet>);

impl Chooser {
    /// The chooser of `patterns`, given with `flag`; an error names a pattern that is no glob.
    pub(crate) fn new(flag: &str, patterns: &[String]) -> Result<Self> {
        if patterns.is_empty() {
            return Ok(Chooser(None));
        }
        let mut set = globset::GlobSetBuilder::new();
        for p in patterns {
            let glob = globset::Glob::new(p).map_err(|e| Error::invalid(format!("{flag} `{p}`: {e}")))?;
            set.add(glob);
        }
        set.build().map(|s| Chooser(Some(s))).map_err(|e| Error::invalid(format!("{flag}: {e}")))
    }

    /// Whether the scan `id` is chosen.
    pub(crate) fn chosen(&self, id: &str) -> bool {
        self.0.as_ref().is_none_or(|s| s.is_match(id))
    }
}

pub(super) fn xy(s: &IndexedScan) -> [f64; 2] {
    let p = s.pose.expect("filtered to posed scans");
    [p[0], p[1]]
}

pub(super) fn subsample(scans: Vec<IndexedScan>, every: Option<f64>) -> Vec<IndexedScan> {
    let Some(every) = every else { return scans };
    let mut last: Option<[f64; 2]> = None;
    scans
        .into_iter()
        .filter(|s| {
            let p = xy(s);
            let keep = last.is_none_or(|l| (p[0] - l[0]).hypot(p[1] - l[1]) > every);
            if keep {
                last = Some(p);
            }
            keep
        })
        .collect()
}
