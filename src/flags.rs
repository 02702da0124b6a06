//! The flags several commands share, declared once: the index a command works on (`--index
//! DIR`) and the worker threads (`-t N`). Each command's option type flattens them.

use std::path::PathBuf;

/// `--index DIR`: the index a command reads or changes.
#[derive(clap::Args, Clone, Debug, PartialEq)]
pub struct IndexFlag {
    /// The index.
    #[arg(long = "index", id = "index", value_name = "INDEX")]
    pub path: PathBuf,
}

/// `-t N`: worker threads.
#[derive(clap::Args, Clone, Copy, Debug, Default, PartialEq)]
pub struct Threads {
    /// Worker threads, [1, ∞) (default: all cores).
    #[arg(long = "threads", short = 't', id = "threads", value_name = "THREADS", value_parser = crate::ranges::count)]
    pub requested: Option<usize>,
}

impl Threads {
    /// The threads asked for, else every core.
    pub fn count(self) -> usize {
        self.requested.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
    }
}
