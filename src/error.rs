//! The one error type of hytled. Every message says what is wrong, where, and how to fix it.

use std::path::PathBuf;

/// Errors reachable from user input or from a run that cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene file that cannot be read or does not follow the schema.
    #[error("{file}: {}", short_numbers(message))]
    Scene { file: PathBuf, message: String },
    /// A geometric input or selection that cannot be used.
    #[error("{}", short_numbers(.0))]
    Input(String),
    /// An element or integration point with non-positive volume.
    #[error("element {element} is inverted or degenerate: volume {volume:.6e} m^3; its volume (a hexahedron: its Jacobian determinant at a corner or Gauss point) is not positive or below 1e-12 of its size cubed; check its node order and coordinates (a node far from the others makes a needle)")]
    InvalidElement { element: usize, volume: f64 },
    /// The explicit integrator diverged.
    #[error("{}", short_numbers(.0))]
    Unstable(String),
    /// SIGINT (Ctrl-C) or SIGTERM stopped the run between two steps ([`crate::interrupt`]).
    #[error("interrupted by {} {}; nothing after that point was computed", crate::interrupt::signal_name(*.signal), short_numbers(.at))]
    Interrupted {
        /// The signal number (2 SIGINT, 15 SIGTERM).
        signal: i32,
        /// Where the run was (e.g. "at step 120 of relaxation, 35 % of the load").
        at: String,
    },
    /// File system errors, with the path involved.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// A message with its extreme numbers in scientific notation. Rust (and serde) print an f64 in
/// full decimal: a scene's `1e300` as 301 digits, `1e-300` as 0.000...1. A number of more than 20
/// digits is longer than any u64 (node and element ids), so it is such an f64: it is shown as
/// `1e300`; shorter numbers are left as written.
pub fn short_numbers(message: &str) -> String {
    let b = message.as_bytes();
    let mut out = String::with_capacity(message.len());
    let (mut copied, mut i) = (0, 0);
    while i < b.len() {
        // A number stands after a space, a bracket, a sign or a quote, never inside a word
        // or a path.
        let starts = b[i].is_ascii_digit()
            && (i == 0
                || matches!(
                    b[i - 1],
                    b' ' | b'(' | b'[' | b'=' | b'`' | b',' | b'-' | b'\''
                ));
        if !starts {
            i += 1;
            continue;
        }
        let mut j = i;
        while j < b.len() && (b[j].is_ascii_digit() || b[j] == b'.') {
            j += 1;
        }
        // A full stop after the number ends the sentence.
        let end = if b[j - 1] == b'.' { j - 1 } else { j };
        let token = &message[i..end];
        let digits = token.bytes().filter(u8::is_ascii_digit).count();
        if let (true, Ok(v)) = (digits > 20, token.parse::<f64>()) {
            out.push_str(&message[copied..i]);
            out.push_str(&format!("{v:e}"));
            copied = end;
        }
        i = j;
    }
    out.push_str(&message[copied..]);
    tidy_exponents(&out)
}

/// A text with Rust's small-exponent notation written as decimals: `{:.6e}` prints 6.999288 as
/// `6.999288e0` and 1234.5 as `1.2345e3`; a number whose exponent is 0 to 4 is shown as
/// `6.999288` and `1234.5` (the same significant digits), others stay in scientific notation.
/// A shorter number keeps a column's right edge: the spaces before it grow by what it lost.
pub fn tidy_exponents(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let (mut copied, mut i) = (0, 0);
    while i < b.len() {
        // Not inside a word, an identifier or a path (a folder named 1e3).
        let starts = b[i].is_ascii_digit()
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b"._/\\".contains(&b[i - 1])));
        if !starts {
            i += 1;
            continue;
        }
        let mut j = i;
        while j < b.len() && b[j].is_ascii_digit() {
            j += 1;
        }
        let int_end = j;
        let mut frac = 0;
        if j + 1 < b.len() && b[j] == b'.' && b[j + 1].is_ascii_digit() {
            j += 1;
            while j < b.len() && b[j].is_ascii_digit() {
                j += 1;
                frac += 1;
            }
        }
        let exp_start = j;
        if !(j + 1 < b.len() && b[j] == b'e' && b[j + 1].is_ascii_digit()) {
            i = j.max(i + 1);
            continue;
        }
        j += 1;
        while j < b.len() && b[j].is_ascii_digit() {
            j += 1;
        }
        // Not a number if a letter, an identifier or a path goes on (1e5abc, 1e3/mesh).
        if j < b.len() && (b[j].is_ascii_alphanumeric() || b"_/\\".contains(&b[j])) {
            i = j;
            continue;
        }
        let (Ok(k), Ok(v)) = (
            text[exp_start + 1..j].parse::<i32>(),
            text[i..j].parse::<f64>(),
        ) else {
            i = j;
            continue;
        };
        if !(0..=4).contains(&k) || int_end - i != 1 {
            i = j;
            continue;
        }
        let decimals = (frac - k).max(0) as usize;
        let plain = format!("{v:.decimals$}");
        let lost = (j - i).saturating_sub(plain.len());
        // Two spaces before it (and its sign): a right-aligned column, not prose.
        let sign = if i > 0 && b[i - 1] == b'-' { i - 1 } else { i };
        let column = sign >= 2 && b[sign - 1] == b' ' && b[sign - 2] == b' ';
        out.push_str(&text[copied..sign]);
        if column {
            out.push_str(&" ".repeat(lost));
        }
        out.push_str(&text[sign..i]);
        out.push_str(&plain);
        copied = j;
        i = j;
    }
    out.push_str(&text[copied..]);
    out
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
    /// Stopped by SIGINT (Ctrl-C): 128 + 2, the shell's convention for a signal.
    pub const INTERRUPTED: u8 = 130;
    /// Stopped by SIGTERM (a batch scheduler's stop): 128 + 15.
    pub const TERMINATED: u8 = 143;
}

impl Error {
    /// The exit code for this error ([`exit`]).
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Scene { .. } | Error::Input(_) | Error::InvalidElement { .. } => exit::INPUT,
            Error::Unstable(_) => exit::UNSTABLE,
            Error::Io { .. } => exit::IO,
            Error::Interrupted { signal, .. } => {
                if *signal == crate::interrupt::SIGTERM {
                    exit::TERMINATED
                } else {
                    exit::INTERRUPTED
                }
            }
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
            Error::Interrupted { .. } => "interrupted",
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extreme_numbers_are_shown_in_scientific_notation() {
        let huge = format!("{}", 1e300);
        let tiny = format!("{}", 2.5e-300);
        assert_eq!(huge.len(), 301);
        let e = Error::Input(format!("dilatation {huge}; spacing -{tiny} m."));
        assert_eq!(e.to_string(), "dilatation 1e300; spacing -2.5e-300 m.");
        // Ids and ordinary numbers stay as written, the largest u64 included.
        let ok = "node 18446744073709551615 at 0.30000000000000004 m, x1000000000000000000000000, \
                  v1.2.3, /data/1234567890123456789012345/mesh.vtu";
        assert_eq!(short_numbers(ok), ok);
        let s = Error::Scene {
            file: "a.toml".into(),
            message: format!("size = {}: too small", 1e-30),
        };
        assert_eq!(s.to_string(), "a.toml: size = 1e-30: too small");
    }

    #[test]
    fn small_exponents_are_written_as_decimals() {
        let t = format!(
            "z {:.6e} N, t = {:.6e} s, {:.4e} s, {:.1e}, -{:.3e}, 1e300, v1.2e3, f_1e2, x1.5e2, /d/1e3/m",
            6.999288, 1.73557, 5.5936e-4, 2.0e5, 1234.5
        );
        assert_eq!(
            tidy_exponents(&t),
            "z 6.999288 N, t = 1.735570 s, 5.5936e-4 s, 2.0e5, -1234, 1e300, v1.2e3, f_1e2, x1.5e2, /d/1e3/m"
        );
        // A column keeps its right edge.
        let col = format!(
            "|{:>13.6e}|{:>13.6e}|{:>13.6e}|",
            6.999288, -6.999288, -1.5e-3
        );
        assert_eq!(
            tidy_exponents(&col),
            "|     6.999288|    -6.999288| -1.500000e-3|"
        );
    }
}
