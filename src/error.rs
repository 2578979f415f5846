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
    #[error("element {element} is inverted or degenerate: volume {volume:.6e} m^3, not positive or below 1e-12 of its size cubed; check its node order and coordinates (a node far from the others makes a needle)")]
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

/// Process exit codes of `hytled` (documented in the README and `hytled --help`).
pub mod exit {
    /// The run completed (dynamic) or converged (relaxation); other commands did their work.
    pub const SUCCESS: u8 = 0;
    /// Anything else that stopped the program (not expected; please report it).
    pub const OTHER: u8 = 1;
    /// The input is wrong: scene file, mesh, selection, CLI flag (clap's usage errors are 2 too).
    pub const INPUT: u8 = 2;
    /// The solution diverged or a point inverted.
    pub const UNSTABLE: u8 = 3;
    /// Relaxation stopped by `solver.max_steps` before it converged (the summary is written).
    pub const NOT_CONVERGED: u8 = 4;
    /// A file could not be read or written (the path is in the message).
    pub const IO: u8 = 5;
}

impl Error {
    /// The exit code for this error ([`exit`]).
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Scene { .. } | Error::Input(_) | Error::InvalidElement { .. } => exit::INPUT,
            Error::Unstable(_) => exit::UNSTABLE,
            Error::Io { .. } => exit::IO,
        }
    }

    /// A short name of the error's kind, as the JSON error object gives it.
    pub fn kind(&self) -> &'static str {
        match self {
            Error::Scene { .. } => "scene",
            Error::Input(_) => "input",
            Error::InvalidElement { .. } => "invalid element",
            Error::Unstable(_) => "unstable",
            Error::Io { .. } => "io",
        }
    }

    /// Wraps an I/O error with the path it concerns.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}
