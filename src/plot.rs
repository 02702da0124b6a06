//! Plots (plotters; PNG and SVG side by side; the DejaVu Sans font is embedded, so no system
//! library or font is needed): Recall@N curves, persistence diagrams, and bird's-eye
//! trajectories coloured by retrieval success.

use crate::error::{Error, Result, ResultExt};
use crate::homology::Diagram;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

static FONT: std::sync::Once = std::sync::Once::new();

fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        // Failure only means plots without text; not worth stopping for.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
    });
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

/// A drawing error; [`render`] names the file it was drawing.
fn e(err: impl std::fmt::Display) -> Error {
    Error::Plot { path: PathBuf::new(), message: err.to_string() }
}

/// The error `err` of drawing `file`.
fn drawing(file: &Path) -> impl Fn(Error) -> Error + '_ {
    move |err| match err {
        Error::Plot { message, .. } => Error::Plot { path: file.to_owned(), message },
        other => other,
    }
}

/// The axes of a bird's-eye view of `points`: a square (equal scales on both axes) around the
/// finite ones, 10 % wider than their span. Only finite positions count: a non-finite one would
/// make the span infinite, and the axis ticks endless; a span too large for the axes'
/// arithmetic is capped.
fn square_bounds<'a>(
    points: impl Iterator<Item = &'a [f64; 2]>,
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points.filter(|p| p.iter().all(|c| c.is_finite())) {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    if !lo[0].is_finite() {
        (lo, hi) = ([0.0; 2], [1.0; 2]);
    }
    let span = ((hi[0] - lo[0]).max(hi[1] - lo[1]).max(1.0) * 1.1).min(1e12);
    let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    (c[0] - span / 2.0..c[0] + span / 2.0, c[1] - span / 2.0..c[1] + span / 2.0)
}

/// Something that draws itself on any plotters backend.
trait Figure {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static;
}

/// `<stem>.<extension>`: the extension appended to the whole stem (a stem holding a dot, as
/// `diagram_drive.v2_000001`, keeps all of it), or replacing a `.png` or `.svg` the stem ends
/// with.
fn image_path(stem: &Path, extension: &str) -> PathBuf {
    if stem.extension().is_some_and(|e| e == "png" || e == "svg") {
        return stem.with_extension(extension);
    }
    let mut name = stem.as_os_str().to_owned();
    name.push(".");
    name.push(extension);
    PathBuf::from(name)
}

/// Renders `fig` into `<stem>.png` and `<stem>.svg`.
fn render(stem: &Path, size: (u32, u32), fig: &impl Figure) -> Result<Vec<PathBuf>> {
    register_font();
    if let Some(dir) = stem.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).at(dir)?;
    }
    let (png, svg) = (image_path(stem, "png"), image_path(stem, "svg"));
    {
        let root = BitMapBackend::new(&png, size).into_drawing_area();
        root.fill(&WHITE).map_err(e).map_err(drawing(&png))?;
        fig.draw(&root).map_err(drawing(&png))?;
        root.present().map_err(e).map_err(drawing(&png))?;
    }
    {
        let root = SVGBackend::new(&svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(e).map_err(drawing(&svg))?;
        fig.draw(&root).map_err(drawing(&svg))?;
        root.present().map_err(e).map_err(drawing(&svg))?;
    }
    Ok(vec![png, svg])
}

type Chart<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// The series legend, boxed, at `position`.
/// A series' mark in the legend: 20 pixels of its line.
fn legend_line(style: ShapeStyle) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style)
}

fn legend<'a, DB: DrawingBackend + 'a>(chart: &mut Chart<'a, DB>, position: SeriesLabelPosition) -> Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(e)
}

struct Curves<'a> {
    title: &'a str,
    series: &'a [(String, Vec<f64>)],
}

impl Figure for Curves<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let max_n = self.series.iter().map(|s| s.1.len()).max().unwrap_or(1).max(2);
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(1f64..max_n as f64, 0f64..101f64)
            .map_err(e)?;
        chart.configure_mesh().x_desc("N (top N retrieved)").y_desc("Recall@N (%)").draw().map_err(e)?;
        for (i, (name, values)) in self.series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            let points: Vec<(f64, f64)> =
                values.iter().enumerate().map(|(k, &v)| ((k + 1) as f64, v)).collect();
            chart
                .draw_series(LineSeries::new(points, color.stroke_width(2)))
                .map_err(e)?
                .label(name.as_str())
                .legend(legend_line(color.stroke_width(2)));
        }
        legend(&mut chart, SeriesLabelPosition::LowerRight)?;
        Ok(())
    }
}

/// Recall@N curves, one line per named series (values for N = 1, 2, …, in percent).
pub(crate) fn recall_curves(stem: &Path, title: &str, series: &[(String, Vec<f64>)]) -> Result<Vec<PathBuf>> {
    render(stem, (800, 560), &Curves { title, series })
}

struct PrCurves<'a> {
    title: &'a str,
    series: &'a [(String, Vec<(f64, f64)>)],
}

impl Figure for PrCurves<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(0f64..101f64, 0f64..101f64)
            .map_err(e)?;
        chart.configure_mesh().x_desc("recall (%)").y_desc("precision (%)").draw().map_err(e)?;
        for (i, (name, points)) in self.series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            chart
                .draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(2)))
                .map_err(e)?
                .label(name.as_str())
                .legend(legend_line(color.stroke_width(2)));
        }
        legend(&mut chart, SeriesLabelPosition::LowerLeft)?;
        Ok(())
    }
}

/// Precision–recall curves, one line per named series of (recall, precision) points in percent.
pub fn precision_recall(
    stem: &Path,
    title: &str,
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<Vec<PathBuf>> {
    render(stem, (800, 560), &PrCurves { title, series })
}

struct DiagramFigure<'a> {
    title: &'a str,
    diagram: &'a Diagram,
}

impl Figure for DiagramFigure<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let finite = self.diagram.pairs().iter().filter(|p| p.death.is_finite());
        let top = finite.map(|p| p.death).fold(0.0f64, f64::max).max(1e-12) * 1.08;
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..top, 0f64..top)
            .map_err(e)?;
        chart.configure_mesh().x_desc("birth").y_desc("death (inf drawn at the top)").draw().map_err(e)?;
        chart.draw_series(LineSeries::new(vec![(0.0, 0.0), (top, top)], BLACK.mix(0.5))).map_err(e)?;
        for dim in 0..3u8 {
            let color = PALETTE[dim as usize];
            let pts: Vec<(f64, f64)> = self
                .diagram
                .dimension(dim)
                .iter()
                .map(|p| (p.birth, if p.death.is_finite() { p.death } else { top * 0.99 }))
                .collect();
            let n = pts.len();
            chart
                .draw_series(pts.into_iter().map(|(x, y)| Circle::new((x, y), 2, color.filled())))
                .map_err(e)?
                .label(format!("H{dim} ({n})"))
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
        }
        legend(&mut chart, SeriesLabelPosition::LowerRight)?;
        Ok(())
    }
}

/// A persistence diagram (birth vs death, one colour per dimension).
pub fn diagram(stem: &Path, title: &str, d: &Diagram) -> Result<Vec<PathBuf>> {
    render(stem, (700, 700), &DiagramFigure { title, diagram: d })
}

struct Trajectory<'a> {
    title: &'a str,
    database: &'a [[f64; 2]],
    queries: &'a [([f64; 2], bool)],
}

impl Figure for Trajectory<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let finite = |p: &&[f64; 2]| p.iter().all(|c| c.is_finite());
        let (x, y) = square_bounds(self.database.iter().chain(self.queries.iter().map(|q| &q.0)));
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x, y)
            .map_err(e)?;
        chart.configure_mesh().x_desc("x (m)").y_desc("y (m)").draw().map_err(e)?;
        let grey = RGBColor(170, 170, 170);
        chart
            .draw_series(
                self.database.iter().filter(finite).map(|p| Circle::new((p[0], p[1]), 3, grey.filled())),
            )
            .map_err(e)?
            .label("database")
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, grey.filled()));
        for (ok, color, label) in
            [(true, PALETTE[2], "query: top-1 correct"), (false, PALETTE[3], "query: top-1 wrong")]
        {
            let n = self.queries.iter().filter(|q| q.1 == ok).count();
            chart
                .draw_series(
                    self.queries
                        .iter()
                        .filter(|q| q.1 == ok && finite(&&q.0))
                        .map(|q| Circle::new((q.0[0], q.0[1]), 2, color.filled())),
                )
                .map_err(e)?
                .label(format!("{label} ({n})"))
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, color.filled()));
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        Ok(())
    }
}

/// Bird's-eye view: database positions in grey, queries green (top-1 correct) or red.
pub fn trajectory(
    stem: &Path,
    title: &str,
    database: &[[f64; 2]],
    queries: &[([f64; 2], bool)],
) -> Result<Vec<PathBuf>> {
    render(stem, (800, 800), &Trajectory { title, database, queries })
}

/// One loop edge of [`loops_map`]: the two scans' places and whether it was kept.
#[derive(Clone, Copy, Debug)]
pub struct LoopEdge {
    /// The query scan's place (x, y; or its walking order, 0).
    pub from: [f64; 2],
    /// The matched scan's.
    pub to: [f64; 2],
    /// Kept (accepted, and verified when checked), or rejected by its check.
    pub kept: bool,
    /// Rejected by the map (a kept loop the optimized map found inconsistent).
    pub rejected_by_map: bool,
}

struct LoopsMap<'a> {
    title: &'a str,
    tracks: &'a [(String, Vec<[f64; 2]>)],
    /// Each session's corrected trajectory (the map), when one was made.
    corrected: &'a [(String, Vec<[f64; 2]>)],
    edges: &'a [LoopEdge],
    /// Positions are walking order, not poses: edges are drawn as arcs over the line.
    ordered: bool,
}

impl Figure for LoopsMap<'_> {
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<()>
    where
        DB::ErrorType: 'static,
    {
        let finite = |p: &[f64; 2]| p.iter().all(|c| c.is_finite());
        let (x, y) = square_bounds(self.tracks.iter().chain(self.corrected).flat_map(|t| t.1.iter()));
        let (x_desc, y_desc) = if self.ordered { ("scan (walking order)", "") } else { ("x (m)", "y (m)") };
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x, y)
            .map_err(e)?;
        chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw().map_err(e)?;
        for (i, (session, track)) in self.tracks.iter().enumerate() {
            let color = RGBColor(150, 150, 150).mix(if i == 0 { 1.0 } else { 0.6 });
            let line: Vec<(f64, f64)> = track.iter().filter(|p| finite(p)).map(|p| (p[0], p[1])).collect();
            chart
                .draw_series(LineSeries::new(line, color.stroke_width(1)))
                .map_err(e)?
                .label(session.as_str())
                .legend(legend_line(color.stroke_width(1)));
        }
        for (i, (session, track)) in self.corrected.iter().enumerate() {
            let color = PALETTE[0].mix(if i == 0 { 1.0 } else { 0.6 });
            let line: Vec<(f64, f64)> = track.iter().filter(|p| finite(p)).map(|p| (p[0], p[1])).collect();
            chart
                .draw_series(LineSeries::new(line, color.stroke_width(2)))
                .map_err(e)?
                .label(format!("{session}, corrected"))
                .legend(legend_line(color.stroke_width(2)));
        }
        // An arc between two places on the walking-order line; a straight edge between poses.
        let path = |edge: &LoopEdge| -> Vec<(f64, f64)> {
            if !self.ordered {
                return vec![(edge.from[0], edge.from[1]), (edge.to[0], edge.to[1])];
            }
            let (a, b) = (edge.from[0], edge.to[0]);
            let (mid, r) = ((a + b) / 2.0, (b - a).abs() / 2.0);
            (0..=24)
                .map(|k| std::f64::consts::PI * k as f64 / 24.0)
                .map(|t| (mid + r * t.cos(), r * t.sin()))
                .collect()
        };
        let kinds = [
            ((true, false), PALETTE[2], "loop, kept"),
            ((false, false), PALETTE[3], "match rejected by its check"),
            ((true, true), PALETTE[1], "loop rejected by the map"),
        ];
        for (kind, color, label) in kinds {
            let edges: Vec<&LoopEdge> = self
                .edges
                .iter()
                .filter(|l| (l.kept, l.rejected_by_map) == kind && finite(&l.from) && finite(&l.to))
                .collect();
            let n = edges.len();
            if n == 0 && kind.1 {
                continue;
            }
            chart
                .draw_series(edges.into_iter().map(|l| PathElement::new(path(l), color.stroke_width(2))))
                .map_err(e)?
                .label(format!("{label} ({n})"))
                .legend(legend_line(color.stroke_width(2)));
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        Ok(())
    }
}

/// The loops found over the drive: each session's trajectory (x, y from its poses; or, with
/// `ordered`, its scans along a line in walking order), each loop an edge, kept ones green and
/// those rejected by their check red (PNG and SVG).
pub fn loops_map(
    stem: &Path,
    title: &str,
    tracks: &[(String, Vec<[f64; 2]>)],
    corrected: &[(String, Vec<[f64; 2]>)],
    edges: &[LoopEdge],
    ordered: bool,
) -> Result<Vec<PathBuf>> {
    render(stem, (900, 900), &LoopsMap { title, tracks, corrected, edges, ordered })
}
