//! What a search found, per method: counts, the loop-closure protocol's scores, the notes on
//! the exclusion; and the progress bar it shows.

use super::exclusion::{self, Exclusion};
use super::row::LoopRow;
use std::path::PathBuf;

/// What a run found for one method.
#[derive(Clone, Debug, Default)]
pub struct MethodSummary {
    /// The method.
    pub method: String,
    /// Its threshold.
    pub threshold: f64,
    /// Scans with an allowed earlier scan (a best match).
    pub matched: usize,
    /// Matches below the threshold.
    pub accepted: usize,
    /// Accepted matches whose scans both have poses.
    pub accepted_with_poses: usize,
    /// Those within the revisit radius.
    pub true_positives: usize,
    /// Scans with an allowed earlier scan within the revisit radius.
    pub revisits: usize,
    /// Those whose accepted match is within the radius.
    pub revisits_found: usize,
    /// The threshold swept over every match with poses (the loop-closure protocol of the
    /// KITTI evaluations): F1 max, recall at 100 % precision; `None` without poses.
    pub curve: Option<crate::eval::metrics::LoopClosure>,
    /// The area under that precision–recall curve (0–1).
    pub auc: Option<f64>,
    /// With `--verify`: the matches below the threshold that were checked (`accepted` are those
    /// kept).
    pub verified: Option<usize>,
    /// Scans searched.
    pub scans: usize,
    /// Of those, scans without a time (kept apart from their neighbours by position).
    pub untimed: usize,
}

impl MethodSummary {
    /// What the exclusion did, when the user should know: scans without a time kept apart by
    /// position, and no scan left with a candidate (with why).
    pub fn exclusion_notes(&self, exclusion: Exclusion) -> Vec<String> {
        let mut out = Vec::new();
        if let (Exclusion::Seconds(s), true) = (exclusion, self.untimed > 0) {
            out.push(format!(
                "{} of {} scans have no time: a scan's neighbours within {} positions are left out (the {s} s \
                 exclusion at {} Hz; --exclude-scans N sets it)",
                self.untimed,
                self.scans,
                exclusion::untimed_window(s),
                exclusion::UNTIMED_RATE_HZ
            ));
        }
        if self.scans == 1 {
            out.push("no loop could be sought: one scan, and no other to match it with".to_string());
        }
        if self.matched == 0 && self.scans > 1 {
            let window = match exclusion {
                Exclusion::Scans(n) => format!("--exclude-scans {n}"),
                Exclusion::Seconds(s) if self.untimed > 0 => {
                    format!("--exclude-seconds {s}, {} positions without times", exclusion::untimed_window(s))
                }
                Exclusion::Seconds(s) => format!("--exclude-seconds {s}"),
            };
            out.push(format!(
                "no loop could be sought: each of the {} scans has every earlier scan of its session within the \
                 exclusion ({window}); lower it, or add another session",
                self.scans
            ));
        }
        out
    }
}

/// What a run found, per method.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Per method.
    pub methods: Vec<MethodSummary>,
    /// The calibration files written.
    pub calibrations: Vec<PathBuf>,
    /// The g2o files written, one per method.
    pub g2o: Vec<PathBuf>,
    /// Every match below its method's threshold, accepted or rejected by its check.
    pub checked: Vec<LoopRow>,
    /// Damaged parts left out (`skip_damaged`), each with the scans it held.
    pub damaged: Vec<crate::sinks::index::damage::DamagedPart>,
    /// What the exclusion did, where the user should know (see
    /// [`MethodSummary::exclusion_notes`]), once per distinct note.
    pub notes: Vec<String>,
    /// The scans searched, in time order (the first method's): what the picture draws.
    pub walk: Vec<super::Walked>,
    /// Each method's map, where the scans have poses (and `--no-optimize` was not given, or
    /// `--g2o` asked for the graph).
    pub maps: Vec<super::map::MethodMap>,
    /// The point clouds written (`--cloud`), one per method.
    pub clouds: Vec<super::cloud::Written>,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for m in &self.methods {
            match m.verified {
                None => write!(
                    f,
                    "loops ({}): {} scans matched an earlier one, {} below {:.6}",
                    m.method, m.matched, m.accepted, m.threshold
                )?,
                Some(checked) => write!(
                    f,
                    "loops ({}): {} scans matched an earlier one, {checked} below {:.6}, {} of them verified by ICP",
                    m.method, m.matched, m.threshold, m.accepted
                )?,
            }
            if m.accepted_with_poses > 0 {
                let precision = 100.0 * m.true_positives as f64 / m.accepted_with_poses as f64;
                write!(
                    f,
                    "; {} of {} with poses true: precision {precision:.1} %",
                    m.true_positives, m.accepted_with_poses
                )?;
            }
            if m.revisits > 0 {
                let recall = 100.0 * m.revisits_found as f64 / m.revisits as f64;
                write!(f, "; {} of {} revisits found: recall {recall:.1} %", m.revisits_found, m.revisits)?;
            }
            if let (Some(c), Some(auc)) = (&m.curve, m.auc) {
                write!(
                    f,
                    "; every threshold: F1 max {:.1} %{}, recall at 100 % precision {:.1} %, EP {:.1} %, AUC {auc:.3}",
                    c.f1_max,
                    c.f1_max_threshold.map_or_else(String::new, |t| format!(" (at {t:.6})")),
                    c.recall_at_full_precision,
                    crate::eval::metrics::extended_precision(c)
                )?;
            }
            writeln!(f)?;
        }
        for m in &self.maps {
            write!(f, "{m}")?;
        }
        for n in &self.notes {
            writeln!(f, "note: {n}")?;
        }
        for c in &self.calibrations {
            writeln!(f, "calibration written: {}", c.display())?;
        }
        self.fmt_written(f)
    }
}

impl Summary {
    /// The g2o files and clouds written, a line each.
    pub(super) fn fmt_written(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for g in &self.g2o {
            writeln!(f, "g2o written: {}", g.display())?;
        }
        for c in &self.clouds {
            writeln!(f, "cloud: {} ({} points from {} scans)", c.path.display(), c.points, c.scans)?;
            if let (n @ 1.., first) = &c.unread {
                let first = first.as_deref().unwrap_or("no longer where the index found it");
                writeln!(
                    f,
                    "note: {n} scans with a pose could not be read again for the cloud (the first: {first})"
                )?;
            }
        }
        Ok(())
    }
}

/// A progress bar over `len` items on a terminal (when `enabled`), else none.
pub(crate) fn progress_bar(enabled: bool, len: usize, what: &str) -> Option<indicatif::ProgressBar> {
    use std::io::IsTerminal;
    (enabled && std::io::stderr().is_terminal()).then(|| {
        let b = indicatif::ProgressBar::new(len as u64);
        let template =
            format!("{{elapsed_precise}} [{{bar:30}}] {{pos}}/{{len}} {what} ({{per_sec}}, ETA {{eta}})");
        b.set_style(indicatif::ProgressStyle::with_template(&template).expect("template"));
        b
    })
}

/// The loop-closure protocol's scores of one method's rows: every match whose scans both have
/// poses, true within `radius`, false beyond it (beyond `false_beyond` when given; matches in
/// between are left out), a scan with an allowed revisit and a rejected match a false negative;
/// the threshold swept over every distance ([`crate::eval::metrics::loop_closure`]) and the
/// area under the curve ([`crate::eval::metrics::pr_auc`]).
pub(super) fn protocol_scores(
    rows: &[LoopRow],
    has_revisit: &dyn Fn(&LoopRow) -> bool,
    radius: f64,
    false_beyond: Option<f64>,
) -> (Option<crate::eval::metrics::LoopClosure>, Option<f64>) {
    let (mut distance, mut within, mut revisit) = (Vec::new(), Vec::new(), Vec::new());
    for r in rows {
        let Some(t) = r.found.true_distance_m else { continue };
        if t > radius && false_beyond.is_some_and(|band| t <= band) {
            continue;
        }
        distance.push(r.found.distance);
        within.push(t <= radius);
        revisit.push(has_revisit(r));
    }
    if distance.is_empty() {
        return (None, None);
    }
    let curve = crate::eval::metrics::loop_closure(&distance, &within, &revisit);
    let auc = crate::eval::metrics::pr_auc(&curve.curve);
    (Some(curve), Some(auc))
}
