//! The PointNetVLAD benchmark (Uy & Lee, CVPR 2018) as it ships: a `benchmark_datasets/`
//! folder of submaps, each a raw little-endian float64 file of exactly 4096 × 3 values
//! (point-major: x1, y1, z1, x2, …), already centred and scaled into [−1, 1], listed with its
//! UTM centroid in one CSV per run (`timestamp,northing,easting`).
//!
//! * Oxford RobotCar: `oxford/<run>/pointcloud_20m/<timestamp>.bin` with
//!   `oxford/<run>/pointcloud_locations_20m.csv` (the test submaps);
//! * the in-house sets (university, residential, business areas):
//!   `inhouse_datasets/<run>/pointcloud_25m_25/<timestamp>.bin` with
//!   `inhouse_datasets/<run>/pointcloud_centroids_25.csv`.
//!
//! Each run is a session; a scan's id is `<run>/<timestamp>`, its pose the centroid
//! (x = northing, y = easting, z = 0), its time the timestamp (µs). A row whose file is missing
//! or has another size is an error of that scan; the others are read.

use super::{Pose, Scan, ScanFailure, ScanStream, SourceError};
use crate::types::Point;
use std::path::{Path, PathBuf};

/// Values in a submap file: 4096 points × 3.
pub(crate) const SUBMAP_VALUES: usize = 4096 * 3;

/// A benchmark set and where its runs keep their test submaps.
struct Layout {
    /// Folder under the benchmark root holding the runs.
    folder: &'static str,
    /// Submap folder in each run.
    submaps: &'static str,
    /// Locations CSV in each run.
    csv: &'static str,
}

/// The sets: Oxford RobotCar and the in-house ones.
const LAYOUTS: [(&str, Layout); 2] = [
    ("oxford", Layout { folder: "oxford", submaps: "pointcloud_20m", csv: "pointcloud_locations_20m.csv" }),
    (
        "inhouse",
        Layout {
            folder: "inhouse_datasets",
            submaps: "pointcloud_25m_25",
            csv: "pointcloud_centroids_25.csv",
        },
    ),
];

/// `kind = "pointnetvlad"` in a pipeline file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointNetVladSpec {
    /// The `benchmark_datasets` folder.
    pub root: PathBuf,
    /// The sets to read: `oxford`, `inhouse` (default: every one the folder holds).
    #[serde(default)]
    pub sets: Vec<String>,
}

/// One run of a set: its folder, submap folder and CSV.
#[derive(Clone, Debug, PartialEq)]
pub struct Run {
    /// `oxford` or `inhouse`.
    pub set: &'static str,
    /// The run's name (its folder).
    pub name: String,
    /// The run's folder.
    pub dir: PathBuf,
    /// Its submap folder.
    pub submaps: PathBuf,
    /// Its locations CSV.
    pub csv: PathBuf,
}

impl super::Kind for PointNetVladSpec {
    const NAME: &'static str = "pointnetvlad";
    const READS: &'static str = "";

    /// Only by a pipeline file: the benchmark's folder is not recognised on the command line.
    fn detect(_: &Path) -> Option<super::Detected> {
        None
    }
}

impl super::Source for PointNetVladSpec {
    fn kind(&self) -> &'static str {
        <Self as super::Kind>::NAME
    }

    fn keys(&self) -> toml::Table {
        toml::Table::try_from(self).expect("plain data")
    }

    fn problems(&self, inputs: bool) -> Vec<(&'static str, String)> {
        super::missing("root", std::slice::from_ref(&self.root), inputs)
    }

    fn open(&self) -> Result<ScanStream, SourceError> {
        PointNetVladSpec::open(self)
    }

    fn sessions(&self) -> Result<Vec<(String, PathBuf)>, SourceError> {
        Ok(self.runs()?.into_iter().map(|r| (r.name, r.dir)).collect())
    }

    /// Runs are named by their set and folder: the stream is filtered instead.
    fn narrowed(&self, _: Vec<PathBuf>) -> Option<Box<dyn super::Source>> {
        None
    }

    fn paths_mut(&mut self) -> Vec<&mut PathBuf> {
        vec![&mut self.root]
    }

    fn boxed(&self) -> Box<dyn super::Source> {
        Box::new(self.clone())
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

impl PointNetVladSpec {
    /// The sets asked for, checked.
    fn layouts(&self) -> Result<Vec<(&'static str, &'static Layout)>, SourceError> {
        let known: Vec<&str> = LAYOUTS.iter().map(|l| l.0).collect();
        if let Some(bad) = self.sets.iter().find(|s| !known.contains(&s.as_str())) {
            return Err(SourceError::invalid(&self.root, format!("unknown set `{bad}` (oxford, inhouse)")));
        }
        Ok(LAYOUTS
            .iter()
            .filter(|(name, l)| {
                if self.sets.is_empty() {
                    self.root.join(l.folder).is_dir()
                } else {
                    self.sets.iter().any(|s| s == name)
                }
            })
            .map(|(name, l)| (*name, l))
            .collect())
    }

    /// Every run of the sets, sorted by name within a set (the order `generate_test_sets.py`
    /// indexes them in).
    pub fn runs(&self) -> Result<Vec<Run>, SourceError> {
        let layouts = self.layouts()?;
        if layouts.is_empty() {
            return Err(SourceError::invalid(
                &self.root,
                "not a PointNetVLAD benchmark folder (no oxford/ or inhouse_datasets/)",
            ));
        }
        let mut out = Vec::new();
        for (set, layout) in layouts {
            let dir = self.root.join(layout.folder);
            let entries =
                std::fs::read_dir(&dir).map_err(|source| SourceError::Io { path: dir.clone(), source })?;
            let mut runs: Vec<PathBuf> =
                entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_dir()).collect();
            runs.sort();
            for run in runs {
                let name = run.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                out.push(Run {
                    set,
                    name,
                    submaps: run.join(layout.submaps),
                    csv: run.join(layout.csv),
                    dir: run,
                });
            }
        }
        Ok(out)
    }

    /// Opens the stream over every run's test submaps, run by run, in CSV order.
    #[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
    pub fn open(&self) -> Result<ScanStream, SourceError> {
        let mut streams: Vec<ScanStream> = Vec::new();
        for run in self.runs()? {
            let rows = read_locations(&run.csv)?;
            streams.push(Box::new(rows.into_iter().map(move |(t, n, e)| submap_scan(&run, t, n, e))));
        }
        Ok(Box::new(streams.into_iter().flatten()))
    }
}

/// The rows of a locations CSV: (timestamp, northing, easting). A header line is skipped; a
/// bad line is an error naming the file and the line.
pub(crate) fn read_locations(path: &Path) -> Result<Vec<(i64, f64, f64)>, SourceError> {
    let bytes = std::fs::read(path).map_err(|source| SourceError::Io { path: path.to_owned(), source })?;
    let mut reader = ::csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(::csv::Trim::All)
        .from_reader(bytes.as_slice());
    let mut out = Vec::new();
    for (i, (line, record)) in super::csv::numbered_records(&mut reader).enumerate() {
        let bad = |message: String| SourceError::Parse { path: path.to_owned(), line, message };
        let record = record.map_err(|e| bad(format!("not CSV: {e}")))?;
        let field = |k: usize| record.get(k).unwrap_or_default();
        if i == 0 && field(0).parse::<f64>().is_err() {
            continue; // the header
        }
        let row = (field(0).parse::<i64>(), field(1).parse::<f64>(), field(2).parse::<f64>());
        match row {
            (Ok(t), Ok(n), Ok(e)) => out.push((t, n, e)),
            _ => return Err(bad("expected timestamp,northing,easting".into())),
        }
    }
    Ok(out)
}

/// Decodes a submap file: exactly 4096 × 3 little-endian float64 values.
pub fn decode(bytes: &[u8], path: &Path) -> Result<Vec<Point>, SourceError> {
    if bytes.len() != SUBMAP_VALUES * 8 {
        return Err(SourceError::invalid(
            path,
            format!(
                "{} bytes; a PointNetVLAD submap is 4096 x 3 float64 values ({} bytes)",
                bytes.len(),
                SUBMAP_VALUES * 8
            ),
        ));
    }
    let value = |k: usize| {
        let b = &bytes[8 * k..8 * k + 8];
        f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
    };
    Ok((0..4096).map(|i| [value(3 * i), value(3 * i + 1), value(3 * i + 2)]).collect())
}

#[expect(clippy::result_large_err, reason = "a stream item: its Ok side, a whole scan, is larger still")]
fn submap_scan(run: &Run, timestamp: i64, northing: f64, easting: f64) -> Result<Scan, ScanFailure> {
    let path = run.submaps.join(format!("{timestamp}.bin"));
    let id = format!("{}/{timestamp}", run.name);
    let fail = |error: String| ScanFailure::of_file(id.clone(), &run.name, &path, Some(timestamp), error);
    let bytes = std::fs::read(&path).map_err(|e| fail(format!("{}: {e}", path.display())))?;
    let fingerprint = crate::fingerprint::of_bytes(&bytes);
    let mut points = decode(&bytes, &path).map_err(|e| fail(e.to_string()).with_fingerprint(fingerprint))?;
    let raw_points = points.len();
    let (mut intensity, mut ring) = (None, None);
    super::drop_invalid(&mut points, &mut intensity, &mut ring);
    let pose = Pose { x: northing, y: easting, z: 0.0, yaw: 0.0 };
    let finite = northing.is_finite() && easting.is_finite();
    Ok(Scan {
        id,
        fingerprint,
        session: run.name.clone(),
        path,
        message_index: None,
        utime: Some(timestamp),
        points,
        intensity,
        ring,
        raw_points,
        pose: finite.then_some(pose),
        no_pose: (!finite).then_some(super::NoPose::NonFinite),
    })
}
