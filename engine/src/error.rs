//! One error type for the engine: every message names the file or the item that is wrong.
//!
//! A message about a setting of a job names it by its field name in backticks (`` `observe` 130
//! is more than the scene length ``), never by a command-line flag; the CLI shows those
//! names as its flags.

use std::fmt;
use std::path::{Path, PathBuf};

/// Errors raised by socdiff. `Display` gives one line naming the file (if any) and the problem.
#[derive(Debug)]
pub enum Error {
    /// The operating system refused to read or write a file.
    Io { path: PathBuf, source: std::io::Error },
    /// A file's content is malformed or does not fit what it claims to be.
    Format { path: PathBuf, msg: String },
    /// Well-formed input that cannot be used (degenerate pose, mismatched skeletons, bad option).
    Invalid(String),
}

/// Engine result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// A malformed-file error naming `path`.
    pub fn format(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        Error::Format { path: path.as_ref().to_path_buf(), msg: msg.into() }
    }

    /// An I/O error naming `path`.
    pub fn io(path: impl AsRef<Path>, source: std::io::Error) -> Self {
        Error::Io { path: path.as_ref().to_path_buf(), source }
    }

    /// An invalid-input error.
    pub fn invalid(msg: impl Into<String>) -> Self {
        Error::Invalid(msg.into())
    }

    /// Attach a file to an error raised without one (e.g. by an in-memory parser).
    pub fn in_file(self, path: impl AsRef<Path>) -> Self {
        match self {
            Error::Invalid(msg) => Error::format(path, msg),
            other => other,
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Io { path, source } => write!(f, "{}: {}", path.display(), source),
            Error::Format { path, msg } => write!(f, "{}: {}", path.display(), msg),
            Error::Invalid(msg) => write!(f, "{msg}"),
        }
    }
}

impl std::error::Error for Error {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Error::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// Shorthand for `Err(Error::Invalid(format!(...)))`.
#[macro_export]
macro_rules! bail {
    ($($arg:tt)*) => { return Err($crate::Error::Invalid(format!($($arg)*))) };
}
