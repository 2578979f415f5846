//! The one error type of hytled. Every message says what is wrong, where, and how to fix it.

use std::path::PathBuf;

/// Errors reachable from user input or from a run that cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene, file, mesh, selection or setting that cannot be used: [`Fault::kind`] says
    /// which, [`Fault::facts`] where.
    #[error("{0}")]
    Input(Box<Fault>),
    /// An element or integration point with non-positive volume.
    #[error("element {element} is inverted or degenerate: volume {} m^3; its volume (a hexahedron: its Jacobian determinant at a corner or Gauss point) is not positive or below 1e-12 of its size cubed; check its node order and coordinates (a node far from the others makes a needle)", Sci(*.volume))]
    InvalidElement { element: usize, volume: f64 },
    /// The explicit integrator diverged.
    #[error("{0}")]
    Unstable(String),
    /// SIGINT (Ctrl-C) or SIGTERM stopped the run between two steps ([`crate::interrupt`]).
    #[error("interrupted by {} {}; nothing after that point was computed", crate::interrupt::signal_name(*.signal), .at)]
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

/// What must change for an input to be usable: a caller (the Python binding, a sweep) tells
/// "no such boundary" from "bad mesh" by this, never by the message's text.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum InputKind {
    /// The scene file or dict: its syntax, an unknown key, a value out of range, keys that
    /// contradict each other. Facts: `file`, `line` (as written, before `--set`), `key`.
    Scene,
    /// A data file's text or bytes cannot be parsed (mesh, cloud, image header, CSV, INP,
    /// surface). Facts: `file`, `line` where the format has lines.
    Format,
    /// A mesh, cloud, surface or image that parses but cannot be used: ids out of range,
    /// degenerate or inverted cells, holes, cell types the method has no element for.
    Mesh,
    /// A name that does not exist or a selection that selects nothing (boundary, region,
    /// probe, curve, node set). Facts: `key`.
    Selection,
    /// A value given at run time (a CLI flag, a Python argument, a re-solve's input) out of
    /// its range or in contradiction with the model. Facts: `key`, `value`.
    Value,
    /// A combination the chosen method or element does not support.
    Unsupported,
    /// Shape functions, integration points or boundary constraints that cannot be built from
    /// these nodes (a support too small, a singular moment matrix). Facts: `node`.
    Discretization,
    /// The model would exceed a limit: memory, a count, a time.
    Limit,
}

impl InputKind {
    /// The kind's name, as `InputKind`'s serde form gives it ("scene", "selection", ...).
    pub fn name(self) -> &'static str {
        match self {
            InputKind::Scene => "scene",
            InputKind::Format => "format",
            InputKind::Mesh => "mesh",
            InputKind::Selection => "selection",
            InputKind::Value => "value",
            InputKind::Unsupported => "unsupported",
            InputKind::Discretization => "discretization",
            InputKind::Limit => "limit",
        }
    }
}

/// Where an input error lies, as data: each is `None` where the error does not know it.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Facts {
    /// The scene key (`discretization.size`, `boundaries.top`) or setting name.
    pub key: Option<String>,
    /// The file at fault (the scene file, a mesh, an image).
    pub file: Option<PathBuf>,
    /// The 1-based line in `file`.
    pub line: Option<usize>,
    /// The node, 0-based, in the order the model holds them.
    pub node: Option<usize>,
    /// The element or cell, 0-based.
    pub element: Option<usize>,
    /// The offending value, SI units.
    pub value: Option<f64>,
}

/// An input error: its kind, its facts and the sentence that says what is wrong and how to
/// fix it. The message is written once, from these: `file[:line]: ` (when the facts have a
/// file) and the sentence.
#[derive(Debug)]
pub struct Fault {
    /// What must change.
    pub kind: InputKind,
    /// Where.
    pub facts: Facts,
    /// What is wrong and how to fix it, without the file and line (the facts give them)
    /// unless `placed_in_message`.
    pub message: String,
    /// The sentence itself names the file and line (set by [`Error::placed`]): the readers of
    /// line-based text (point clouds, measured displacements, curves, MSH 2.2, NRRD headers,
    /// legacy VTK) say
    /// `FILE: line N: ...`, a wording their users and tests know, so no prefix is added.
    pub placed_in_message: bool,
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.facts.file, self.facts.line) {
            _ if self.placed_in_message => {}
            (Some(file), Some(line)) => write!(f, "{}:{line}: ", file.display())?,
            (Some(file), None) => write!(f, "{}: ", file.display())?,
            _ => {}
        }
        f.write_str(&self.message)
    }
}

/// An f64 for a message, written as Rust writes it (`0.3`, `1500`) unless that takes more
/// than 20 digits (a scene's `1e300` as 301 digits, `1e-300` as 0.000...1): then in scientific
/// notation. 20 digits is longer than any u64 (node and element ids).
/// Takes an `f64` or a `&f64`.
#[derive(Clone, Copy, Debug)]
pub struct Num<T = f64>(pub T);

impl<T: std::borrow::Borrow<f64>> std::fmt::Display for Num<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = *self.0.borrow();
        let plain = format!("{v}");
        if plain.bytes().filter(u8::is_ascii_digit).count() > 20 {
            write!(f, "{v:e}")
        } else {
            f.write_str(&plain)
        }
    }
}

/// An f64 in scientific notation for a message (`{:.3e}`, `{:e}`; a format's precision and
/// width are kept), written as a decimal when its exponent is 0 to 4: 6.999288 rather than
/// `6.999288e0`, 1234.5 rather than `1.2345e3`, with the same significant digits.
/// Takes an `f64` or a `&f64`.
#[derive(Clone, Copy, Debug)]
pub struct Sci<T = f64>(pub T);

impl<T: std::borrow::Borrow<f64>> std::fmt::Display for Sci<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = *self.0.borrow();
        let e = match f.precision() {
            Some(digits) => format!("{v:.digits$e}"),
            None => format!("{v:e}"),
        };
        let (mantissa, k) = e
            .rsplit_once('e')
            .and_then(|(m, k)| Some((m, k.parse::<i32>().ok()?)))
            .unwrap_or((&e, i32::MIN));
        let text = if (0..=4).contains(&k) {
            let frac = mantissa.split_once('.').map_or(0, |(_, d)| d.len()) as i32;
            let decimals = (frac - k).max(0) as usize;
            format!("{v:.decimals$}")
        } else {
            e.clone()
        };
        match f.width() {
            Some(w) => write!(f, "{text:>w$}"),
            None => f.write_str(&text),
        }
    }
}

impl<T: std::borrow::Borrow<f64>> std::fmt::LowerExp for Sci<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Display::fmt(self, f)
    }
}

impl Error {
    /// An input error of `kind` with no facts yet: add them with [`Error::key`],
    /// [`Error::file`], [`Error::line`], [`Error::node`], [`Error::element`], [`Error::value`].
    pub fn input(kind: InputKind, message: impl Into<String>) -> Self {
        Error::Input(Box::new(Fault {
            kind,
            facts: Facts::default(),
            message: message.into(),
            placed_in_message: false,
        }))
    }

    /// A scene error in `file` (see [`InputKind::Scene`]).
    pub fn scene(file: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::input(InputKind::Scene, message).file(file)
    }

    /// The input error's kind and facts; `None` for other errors.
    pub fn fault(&self) -> Option<&Fault> {
        match self {
            Error::Input(f) => Some(f),
            _ => None,
        }
    }

    fn with(mut self, set: impl FnOnce(&mut Facts)) -> Self {
        if let Error::Input(f) = &mut self {
            set(&mut f.facts);
        }
        self
    }

    /// Sets the scene key (input errors only; others are returned unchanged).
    pub fn key(self, key: impl Into<String>) -> Self {
        let key = key.into();
        self.with(|f| f.key = Some(key))
    }

    /// Sets the file at fault; the message is then prefixed `file: `.
    pub fn file(self, file: impl Into<PathBuf>) -> Self {
        let file = file.into();
        self.with(|f| f.file = Some(file))
    }

    /// Sets the 1-based line in the file; with a file the message is prefixed `file:line: `.
    pub fn line(self, line: usize) -> Self {
        self.with(|f| f.line = Some(line))
    }

    /// Sets the file and line facts of a sentence that already names them (`FILE: line N:`):
    /// the message is written as it is, with no prefix.
    pub fn placed(mut self, file: impl Into<PathBuf>, line: usize) -> Self {
        if let Error::Input(f) = &mut self {
            f.facts.file = Some(file.into());
            f.facts.line = Some(line);
            f.placed_in_message = true;
        }
        self
    }

    /// Sets the node (0-based).
    pub fn node(self, node: usize) -> Self {
        self.with(|f| f.node = Some(node))
    }

    /// Sets the element or cell (0-based).
    pub fn element(self, element: usize) -> Self {
        self.with(|f| f.element = Some(element))
    }

    /// Sets the offending value (SI units).
    pub fn value(self, value: f64) -> Self {
        self.with(|f| f.value = Some(value))
    }

    /// The same input error with `more` after its sentence (other errors unchanged).
    pub fn append(mut self, more: &str) -> Self {
        if let Error::Input(f) = &mut self {
            f.message.push_str(more);
        }
        self
    }
}

/// Another library's message (serde's, toml's) with its extreme numbers in scientific notation,
/// as [`Num`] writes hytled's own. Rust (and serde) print an f64 in full decimal: a scene's `1e300` as 301 digits, `1e-300` as 0.000...1. A number of more than 20
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
            Error::Input(_) | Error::InvalidElement { .. } => exit::INPUT,
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

    /// A short name of the error's class, as the JSON error object gives it: "scene" for an
    /// [`InputKind::Scene`] error, "input" for the other input kinds (see [`Error::fault`]).
    pub fn kind(&self) -> &'static str {
        match self {
            Error::Input(f) if f.kind == InputKind::Scene => "scene",
            Error::Input(_) => "input",
            Error::InvalidElement { .. } => "invalid element",
            Error::Unstable(_) => "unstable",
            Error::Io { .. } => "io",
            Error::Interrupted { .. } => "interrupted",
        }
    }

    /// The error as the JSON object the CLI's `--json` and a run's failed summary give:
    /// `error` ([`Error::kind`]), `exit_code`, `message`, and for an input error its
    /// `input_kind` and `facts` ([`Facts`]; absent facts are null).
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = serde_json::json!({
            "error": self.kind(),
            "exit_code": self.exit_code(),
            "message": self.to_string(),
        });
        if let Some(f) = self.fault() {
            v["input_kind"] = f.kind.name().into();
            v["facts"] = serde_json::json!(f.facts);
        }
        v
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
        // hytled's own messages write an f64 through Num, once.
        let e = Error::input(
            InputKind::Value,
            format!("dilatation {}; spacing -{} m.", Num(1e300), Num(2.5e-300)),
        );
        assert_eq!(e.to_string(), "dilatation 1e300; spacing -2.5e-300 m.");
        assert_eq!(
            format!("{} {} {}", Num(0.3), Num(1500.0), Num(-0.25)),
            "0.3 1500 -0.25"
        );
        // Another library's text is shortened where it enters an error.
        assert_eq!(
            short_numbers(&format!("dilatation {huge}; spacing -{tiny} m.")),
            "dilatation 1e300; spacing -2.5e-300 m."
        );
        // Ids and ordinary numbers stay as written, the largest u64 included.
        let ok = "node 18446744073709551615 at 0.30000000000000004 m, x1000000000000000000000000, \
                  v1.2.3, /data/1234567890123456789012345/mesh.vtu";
        assert_eq!(short_numbers(ok), ok);
        let s = Error::scene("a.toml", "size = 1e-30: too small");
        assert_eq!(s.to_string(), "a.toml: size = 1e-30: too small");
    }

    /// Issue 58: the message is written once from the kind's facts; the facts are data.
    #[test]
    fn input_errors_carry_their_kind_and_facts() {
        let e = Error::input(InputKind::Format, "expected 3 numbers x y z")
            .file("cloud.xyz")
            .line(7);
        assert_eq!(e.to_string(), "cloud.xyz:7: expected 3 numbers x y z");
        let f = e.fault().expect("an input error");
        assert_eq!(f.kind, InputKind::Format);
        assert_eq!((f.facts.line, f.facts.node), (Some(7), None));
        assert_eq!(e.kind(), "input");
        assert_eq!(e.exit_code(), exit::INPUT);
        let s = Error::scene("a.toml", "x")
            .key("discretization.size")
            .line(3);
        assert_eq!(s.kind(), "scene");
        assert_eq!(s.to_string(), "a.toml:3: x");
        let f = s.fault().expect("an input error");
        assert_eq!(f.facts.key.as_deref(), Some("discretization.size"));
        // Facts on other errors change nothing.
        let u = Error::Unstable("diverged".into()).node(3).append("!");
        assert!(u.fault().is_none() && u.to_string() == "diverged");
        let n = Error::input(InputKind::Discretization, "singular")
            .node(12)
            .value(0.5);
        let facts = &n.fault().expect("input").facts;
        assert_eq!((facts.node, facts.value), (Some(12), Some(0.5)));
        // A sentence that names its place keeps its wording and gains the facts.
        let p =
            Error::input(InputKind::Format, "pts.csv: line 4: not a number").placed("pts.csv", 4);
        assert_eq!(p.to_string(), "pts.csv: line 4: not a number");
        let f = &p.fault().expect("input").facts;
        assert_eq!(
            (f.file.as_deref(), f.line),
            (Some(std::path::Path::new("pts.csv")), Some(4))
        );
        assert_eq!(
            serde_json::to_value(InputKind::Unsupported).expect("json"),
            InputKind::Unsupported.name()
        );
    }

    /// `Sci` writes what `tidy_exponents` made of `{:.6e}`, from the number, not the text.
    #[test]
    fn sci_writes_small_exponents_as_decimals() {
        for (v, digits) in [
            (6.999288, 6),
            (1.73557, 6),
            (5.5936e-4, 4),
            (2.0e5, 1),
            (-1234.5, 3),
            (0.0, 6),
            (-1.5e-3, 6),
        ] {
            let e = format!("{v:.digits$e}");
            assert_eq!(format!("{:.digits$}", Sci(v)), tidy_exponents(&e), "{v}");
        }
        assert_eq!(format!("{:.6e}", Sci(6.999288)), "6.999288");
        assert_eq!(
            format!("{:e}", Sci(1.5)),
            tidy_exponents(&format!("{:e}", 1.5))
        );
        assert_eq!(format!("{:e}", Sci(1.5e-12)), "1.5e-12");
        assert_eq!(format!("{:.3e}", Sci(2.5e-7)), "2.500e-7");
        assert_eq!(format!("{:>13.6e}", Sci(-1.5e-3)), " -1.500000e-3");
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
