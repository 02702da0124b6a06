//! The library's error types, below every other module. Every variant that concerns a file
//! names it, so a message printed on its own says which input was wrong and why.
//!
//! * [`Error`]: what a library call returns.
//! * [`SourceError`]: a source that cannot be read (per-scan problems travel as stream items,
//!   `sources::ScanFailure`, with this error's message); converts into [`Error`].
//! * [`ConfigErrors`]: every problem of a pipeline file at once; converts into [`Error`].

use std::path::{Path, PathBuf};

/// A toporec error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file or folder could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A Parquet file could not be read or written.
    #[error("{}: {source}", path.display())]
    Parquet {
        /// The file.
        path: PathBuf,
        /// The Parquet error.
        source: parquet::errors::ParquetError,
    },
    /// Arrow data could not be built or read.
    #[error("{}: {source}", path.display())]
    Arrow {
        /// The file.
        path: PathBuf,
        /// The Arrow error.
        source: arrow::error::ArrowError,
    },
    /// A table is not one toporec can read: a missing column, a wrong type, a newer layout.
    #[error("{}: {message}", path.display())]
    Table {
        /// The Parquet file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A committed part file whose bytes are not the ones its commit recorded (a flipped bit,
    /// a truncated copy, another file in its place): nothing of it is used.
    #[error(
        "{}: damaged {what}: the file changed after it was committed ({found}; its commit recorded \
         {expected}); nothing was read from it. `toporec repair --index {}` rebuilds it",
        path.display(),
        index.display()
    )]
    Damaged {
        /// The part file.
        path: PathBuf,
        /// The index it belongs to.
        index: PathBuf,
        /// Which table it is a part of (`scans part`, `descriptors part of toporec-plus`).
        what: String,
        /// The checksum and size its commit recorded.
        expected: String,
        /// The checksum and size found (or `missing`).
        found: String,
    },
    /// An index folder is not usable as asked.
    #[error("{}: {message}", path.display())]
    Index {
        /// The index folder.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Another writer holds the index.
    #[error("index {} is locked by {holder}", path.display())]
    Locked {
        /// The index folder.
        path: PathBuf,
        /// Who holds it: `pid N (host H) since T`.
        holder: String,
    },
    /// A codebook file could not be read, or a codebook could not be fitted.
    #[error("{}: {message}", path.display())]
    Codebook {
        /// The codebook file (or the input it was fitted on).
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A diagram file could not be read.
    #[error("{}: {message}", path.display())]
    Diagram {
        /// The file.
        path: PathBuf,
        /// What is wrong, with the line.
        message: String,
    },
    /// A plot could not be drawn.
    #[error("{}: {message}", path.display())]
    Plot {
        /// The image file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// An MCAP file could not be written.
    #[error("{}: {source}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The MCAP error.
        source: ::mcap::McapError,
    },
    /// A source could not be opened or read.
    #[error(transparent)]
    Source(#[from] SourceError),
    /// A pipeline file is invalid.
    #[error(transparent)]
    Config(#[from] ConfigErrors),
    /// An argument or a combination of arguments cannot be used.
    #[error("{0}")]
    Invalid(String),
}

/// All errors of a file: one on one line, several one per line.
#[derive(Debug, thiserror::Error)]
#[error("{}", render_config_errors(path, errors))]
pub struct ConfigErrors {
    /// The file.
    pub path: PathBuf,
    /// Each error, starting with its key path.
    pub errors: Vec<String>,
}

fn render_config_errors(path: &Path, errors: &[String]) -> String {
    match errors {
        [one] => format!("{}: {one}", path.display()),
        many => format!(
            "{}: {} errors:\n{}",
            path.display(),
            many.len(),
            many.iter().map(|e| format!("  {e}")).collect::<Vec<_>>().join("\n")
        ),
    }
}

/// An error reading a source, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file size is not a whole number of records.
    #[error("{path}: truncated: {len} bytes is not a multiple of the {record}-byte record size")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Its length in bytes.
        len: usize,
        /// The record size.
        record: usize,
    },
    /// A text line could not be parsed.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("{path}: point {index} has a non-finite coordinate")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// 0-based point index.
        index: usize,
    },
    /// The format could not be determined.
    #[error("{path}: unknown cloud format (expected .csv, .bin, .pcd or .ply; use --format)")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// The file or folder is not what the source expects.
    #[error("{path}: {message}")]
    Invalid {
        /// The file or folder.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

impl SourceError {
    /// An [`SourceError::Invalid`].
    pub fn invalid(path: &Path, message: impl Into<String>) -> Self {
        SourceError::Invalid { path: path.to_owned(), message: message.into() }
    }
}
/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An [`Error::Invalid`].
    pub fn invalid(message: impl Into<String>) -> Self {
        Error::Invalid(message.into())
    }

    /// An [`Error::Index`].
    pub fn index(path: &Path, message: impl Into<String>) -> Self {
        Error::Index { path: path.to_owned(), message: message.into() }
    }

    /// Whether the error is a file or folder that does not exist.
    pub fn is_not_found(&self) -> bool {
        matches!(self, Error::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound)
    }

    /// An [`Error::Table`].
    pub fn table(path: &Path, message: impl Into<String>) -> Self {
        Error::Table { path: path.to_owned(), message: message.into() }
    }
}

/// Errors that become an [`Error`] once the file they concern is known.
pub(crate) trait FileError {
    /// The error about `path`.
    fn at(self, path: &Path) -> Error;
}

impl FileError for std::io::Error {
    fn at(self, path: &Path) -> Error {
        Error::Io { path: path.to_owned(), source: self }
    }
}

impl FileError for parquet::errors::ParquetError {
    fn at(self, path: &Path) -> Error {
        Error::Parquet { path: path.to_owned(), source: self }
    }
}

impl FileError for arrow::error::ArrowError {
    fn at(self, path: &Path) -> Error {
        Error::Arrow { path: path.to_owned(), source: self }
    }
}

impl FileError for ::mcap::McapError {
    fn at(self, path: &Path) -> Error {
        Error::Mcap { path: path.to_owned(), source: self }
    }
}

/// `.at(path)` on results: names the file in the error.
pub(crate) trait ResultExt<T> {
    /// The error, if any, as an [`Error`] about `path`.
    fn at(self, path: &Path) -> Result<T>;
}

impl<T, E: FileError> ResultExt<T> for std::result::Result<T, E> {
    fn at(self, path: &Path) -> Result<T> {
        self.map_err(|e| e.at(path))
    }
}
