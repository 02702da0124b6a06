//! What `toporec repair` asks of the writer beyond a run's rows: taking out the rows of scans
//! whose `scans` row was in a damaged part, dropping the damaged parts at the commit, and
//! adding the rows a damaged part held to scans that keep their other rows.

use super::{IndexWriter, MethodDescriptor};
use crate::error::Result;
use crate::homology::Diagram;
use crate::methods::TOPOREC;
use crate::sinks::parquet::ScanRow;

impl IndexWriter {
    /// Marks the rows of scan `scan_id` of `session` for removal at the next commit, whether or
    /// not it has a committed `scans` row (a repair: that row may have been in a damaged part).
    pub(crate) fn remove_in(&mut self, scan_id: &str, session: &str) {
        self.removals.insert(scan_id.to_string());
        self.removal_sessions.insert(session.to_string());
    }

    /// Drops the committed part `path` at the next commit (a repair: a damaged part, its rows
    /// rebuilt in the same commit), and counts the scans anew then.
    pub(crate) fn drop_damaged(&mut self, path: &str) {
        self.dropped.insert(path.to_string());
        self.recount = true;
    }

    /// Whether the committed part `path` is dropped at the next commit.
    pub(crate) fn dropping(&self, path: &str) -> bool {
        self.dropped.contains(path)
    }

    /// Adds rows of a committed scan to the open chunk, without replacing it (a repair): its
    /// `scans` row when given (`has_descriptor`: whether the index holds its TopoRec
    /// descriptor), its pairs in `dims`, its descriptors.
    pub(crate) fn add_rows(
        &mut self,
        session: &str,
        scan_id: &str,
        scan_row: Option<(ScanRow, bool)>,
        diagram: Option<&Diagram>,
        dims: &[u8],
        descriptors: Vec<MethodDescriptor>,
    ) -> Result<()> {
        if let Some(d) = diagram {
            self.push_diagram(session, scan_id, d, dims)?;
        }
        for d in descriptors {
            self.chunk_rows += 1;
            if d.method == TOPOREC
                && let Some(c) = self.committed.get_mut(scan_id)
            {
                c.has_descriptor = true;
            }
            self.push_descriptor(session, &d.method, d.row, || d.id.clone())?;
        }
        if let Some((row, has_descriptor)) = scan_row {
            self.push_scan(row, has_descriptor)?;
        }
        Ok(())
    }
}
