//! Progress of a run: an indicatif bar (or spinner) on a terminal, a log line every 10 s
//! otherwise.

use super::RunSummary;
use std::time::{Duration, Instant};

/// Progress: an indicatif spinner on a terminal, a log line every 10 s otherwise.
pub(crate) struct Progress {
    bar: Option<indicatif::ProgressBar>,
    start: Instant,
    last: std::cell::Cell<Instant>,
    enabled: bool,
}

impl Progress {
    /// `total`: the number of scans when the sources can tell cheaply (a bar with ETA),
    /// else a spinner.
    pub(crate) fn new(enabled: bool, total: impl FnOnce() -> Option<u64>) -> Self {
        use std::io::IsTerminal;
        let bar = (enabled && std::io::stderr().is_terminal()).then(|| {
            let (b, template) = match total() {
                Some(n) => (
                    indicatif::ProgressBar::new(n),
                    "{elapsed_precise} [{bar:30}] {pos}/{len} scans ({per_sec}, ETA {eta}) {msg}",
                ),
                None => (
                    indicatif::ProgressBar::new_spinner(),
                    "{spinner} {elapsed_precise} {pos} scans ({per_sec}) {msg}",
                ),
            };
            b.set_style(indicatif::ProgressStyle::with_template(template).expect("template"));
            b.enable_steady_tick(Duration::from_millis(200));
            b
        });
        Progress { bar, start: Instant::now(), last: std::cell::Cell::new(Instant::now()), enabled }
    }

    pub(crate) fn tick(&self, s: &RunSummary) {
        if let Some(b) = &self.bar {
            b.set_position(s.read);
            b.set_message(format!("{} indexed, {} errors", s.indexed, s.errors));
        } else if self.enabled && self.last.get().elapsed() >= Duration::from_secs(10) {
            self.last.set(Instant::now());
            let rate = s.read as f64 / self.start.elapsed().as_secs_f64();
            eprintln!(
                "toporec: {} scans read, {} indexed, {} errors, {rate:.1} scans/s",
                s.read, s.indexed, s.errors
            );
        }
    }

    pub(crate) fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
