//! The library's error type. Every variant that concerns a file names it, so a message
//! printed on its own says which input was wrong and why. Sources keep their own
//! [`SourceError`] (per-scan problems travel as stream items, not as this type); it converts.

use crate::pipeline::config::ConfigErrors;
use crate::sources::SourceError;
use crate::vectorize::atol::AtolError;
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
    /// An index folder is not usable as asked.
    #[error("{}: {message}", path.display())]
    Index {
        /// The index folder.
        path: PathBuf,
        /// What is wrong.
        message: String,
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
    /// An ATOL model could not be fitted.
    #[error(transparent)]
    Atol(#[from] AtolError),
    /// An argument or a combination of arguments cannot be used.
    #[error("{0}")]
    Invalid(String),
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

    /// An [`Error::Table`].
    pub fn table(path: &Path, message: impl Into<String>) -> Self {
        Error::Table { path: path.to_owned(), message: message.into() }
    }
}

/// Errors that become an [`Error`] once the file they concern is known.
pub trait FileError {
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
pub trait ResultExt<T> {
    /// The error, if any, as an [`Error`] about `path`.
    fn at(self, path: &Path) -> Result<T>;
}

impl<T, E: FileError> ResultExt<T> for std::result::Result<T, E> {
    fn at(self, path: &Path) -> Result<T> {
        self.map_err(|e| e.at(path))
    }
}
