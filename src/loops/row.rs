//! A loop row (one scan's best allowed match, with its check), and the `loops` table written.

use crate::error::{Result, ResultExt};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The check of one row.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Check {
    /// Whether the alignment passed the limits.
    pub passed: bool,
    /// Its fitness.
    pub fitness: f64,
    /// Its RMSE (m).
    pub rmse: f64,
    /// The query's pose in the match's sensor frame: x, y, z (m), roll, pitch, yaw (degrees).
    pub relative: [f64; 6],
}

/// One scan's best allowed match.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopRow {
    /// The method.
    pub method: String,
    /// The scan.
    pub query_scan: String,
    /// Its session.
    pub query_session: String,
    /// The earlier scan it matches.
    pub matched_scan: String,
    /// Its session.
    pub matched_session: String,
    /// The query's position in the walking order (its g2o vertex).
    pub query_vertex: usize,
    /// The match: the matched scan's position in the walking order (its vertex), the
    /// distances, and whether it is a loop (below the threshold and, with `--verify`, aligned).
    pub found: Match,
    /// The geometric check (`--verify`), of the rows below the threshold.
    pub check: Option<Check>,
    /// Whether the optimized map kept the loop (`true`) or rejected it (`false`); none when no
    /// map was made or the row is no loop.
    pub in_map: Option<bool>,
}

/// A scan's best allowed earlier match: what the search and the online detector find.
#[derive(Clone, Debug, PartialEq)]
pub struct Match {
    /// The matched scan: its position in the walking order (among the scans added, for the
    /// detector; 0 the first).
    pub row: usize,
    /// Descriptor distance.
    pub distance: f64,
    /// The yaw of the query relative to the match (degrees), for methods that give one.
    pub yaw_degrees: Option<f64>,
    /// The query's estimated position in the match's sensor frame (x forward, y left, m), for
    /// methods that give one.
    pub offset: Option<[f64; 2]>,
    /// The runner-up's distance: the second allowed match's, or the match's own where the
    /// method ranked the runner-up below it although it lies nearer in descriptor distance
    /// (toporec-plus orders its few best by their pose too). Never below `distance`, so
    /// `rank2_distance − distance` is a margin ≥ 0: how clearly the match won.
    pub rank2_distance: Option<f64>,
    /// The distance between the two scans' poses (m), when both have one.
    pub true_distance_m: Option<f64>,
    /// Whether the distance is below the threshold (and, with `--verify`, the scans align).
    pub accepted: bool,
}

impl Match {
    /// The best of `hits` (sorted by the method's rank, up to two), with the poses' distance;
    /// not yet judged against a threshold.
    pub fn of_hits(hits: &[crate::methods::Hit], row: usize, true_distance_m: Option<f64>) -> Option<Match> {
        let best = hits.first()?;
        Some(Match {
            row,
            distance: best.distance,
            yaw_degrees: best.yaw_degrees,
            offset: best.offset,
            // Never below the match's own: a method that ranks by more than the distance
            // (toporec-plus's pose) may put a candidate nearer in distance second.
            rank2_distance: hits.get(1).map(|h| h.distance.max(best.distance)),
            true_distance_m,
            accepted: false,
        })
    }
}

/// Where `--g2o PATH` writes `method`'s edges: `<stem>.<method>.g2o` beside `PATH`, one file
/// per method whatever their number, so a script's path does not depend on `--method`.
pub fn g2o_path(path: &Path, method: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "loops".into());
    path.with_file_name(format!("{stem}.{method}.g2o"))
}

/// The rows as a record batch of the `loops` table ([`crate::sinks::schema::loops`]).
pub(crate) fn rows_batch(rows: &[LoopRow]) -> arrow::record_batch::RecordBatch {
    let mut b = crate::sinks::rows::RowBuilder::plain(&crate::sinks::schema::loops());
    let [method, query, query_session, matched, matched_session] =
        ["method", "query_scan", "query_session", "matched_scan", "matched_session"].map(|n| b.col(n));
    let [distance, yaw, x_m, y_m, rank2, truth, accepted] =
        ["distance", "yaw_degrees", "x_m", "y_m", "rank2_distance", "true_distance_m", "accepted"]
            .map(|n| b.col(n));
    let [query_vertex, matched_vertex, verified, fitness, rmse] =
        ["query_vertex", "matched_vertex", "verified", "icp_fitness", "icp_rmse"].map(|n| b.col(n));
    let relative =
        ["rel_x", "rel_y", "rel_z", "rel_roll_deg", "rel_pitch_deg", "rel_yaw_deg"].map(|n| b.col(n));
    let in_map = b.col("in_map");
    let finite = |v: f64| v.is_finite().then_some(v);
    for r in rows {
        b.text(method, Some(&r.method))
            .text(query, Some(&r.query_scan))
            .text(query_session, Some(&r.query_session))
            .text(matched, Some(&r.matched_scan))
            .text(matched_session, Some(&r.matched_session))
            .float(distance, Some(r.found.distance))
            .float(yaw, r.found.yaw_degrees)
            .float(x_m, r.found.offset.map(|o| o[0]))
            .float(y_m, r.found.offset.map(|o| o[1]))
            .float(rank2, r.found.rank2_distance)
            .float(truth, r.found.true_distance_m)
            .boolean(accepted, Some(r.found.accepted))
            .uint(query_vertex, Some(r.query_vertex as u64))
            .uint(matched_vertex, Some(r.found.row as u64))
            .boolean(verified, r.check.map(|c| c.passed))
            .float(fitness, r.check.map(|c| c.fitness))
            .float(rmse, r.check.and_then(|c| finite(c.rmse)));
        for (k, col) in relative.into_iter().enumerate() {
            b.float(col, r.check.and_then(|c| finite(c.relative[k])));
        }
        b.boolean(in_map, r.in_map);
        b.end_row();
    }
    b.finish().expect("the columns of the loops table")
}

/// Writes the rows to `path`: CSV when it ends in `.csv`, else Parquet (zstd), atomically.
pub(crate) fn write_rows(path: &Path, rows: &[LoopRow]) -> Result<()> {
    let batch = rows_batch(rows);
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
        let mut file = crate::fsutil::AtomicFile::create(path)?;
        let header = crate::sinks::csv::header(&crate::sinks::schema::loops());
        file.write_all(format!("{header}\n{}", crate::sinks::csv::rows(&batch)).as_bytes()).at(path)?;
        file.commit()?;
        return Ok(());
    }
    let mut file = crate::sinks::parquet::TableFile::with_schema(path, batch.schema())?;
    file.write_batch(&batch)?;
    let (staged, _) = file.finish()?;
    staged.publish()?;
    Ok(())
}
