//! The one error type of hytled. Every message says what is wrong, where, and how to fix it.

use std::path::PathBuf;

/// Errors reachable from user input or from a run that cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene file that cannot be read or does not follow the schema.
    #[error("{file}: {message}")]
    Scene { file: PathBuf, message: String },
    /// A geometric input or selection that cannot be used.
    #[error("{0}")]
    Input(String),
    /// An element or integration point with non-positive volume.
    #[error("element {element} has non-positive volume {volume:.6e} m^3 (inverted or degenerate); check its node order and coordinates")]
    InvalidElement { element: usize, volume: f64 },
    /// The explicit integrator diverged.
    #[error("{0}")]
    Unstable(String),
    /// File system errors, with the path involved.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// Result with the hytled error type.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// Wraps an I/O error with the path it concerns.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}
