//! Lines of a deck with its `*INCLUDE` files flattened in, and keyword lines parsed.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use crate::{Error, InputKind, Result};

use super::MAX_INCLUDE_DEPTH;

/// Where a line is: index into the file list and 1-based line number.
#[derive(Debug, Clone, Copy)]
pub(super) struct Loc {
    pub(super) file: usize,
    pub(super) line: usize,
}

/// A significant (non-blank, non-comment) line, trimmed, includes expanded.
pub(super) struct Line<'a> {
    pub(super) loc: Loc,
    pub(super) text: Cow<'a, str>,
    pub(super) keyword: bool,
}

/// The files lines come from, for messages.
pub(super) struct Files(pub(super) Vec<PathBuf>);

impl Files {
    pub(super) fn name(&self, file: usize) -> String {
        self.0
            .get(file)
            .map(|p| p.display().to_string())
            .unwrap_or_default()
    }

    pub(super) fn at(&self, loc: Loc) -> String {
        format!("{}:{}", self.name(loc.file), loc.line)
    }

    pub(super) fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
        located(&self.0, loc, msg)
    }
}

/// A format error at `loc`, the file and line as facts: "FILE:LINE: message".
fn located(files: &[PathBuf], loc: Loc, msg: impl std::fmt::Display) -> Error {
    let e = Error::input(InputKind::Format, msg.to_string());
    match files.get(loc.file) {
        Some(p) => e.file(p).line(loc.line),
        None => e.append(&format!(" (line {})", loc.line)),
    }
}

pub(super) fn canonical(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
}

/// A parsed keyword line: normalized name (upper case, no blanks), the name as written, and
/// its parameters (normalized key, value as written without quotes; flags have "").
pub(super) struct Keyword {
    pub(super) name: String,
    pub(super) shown: String,
    pub(super) params: Vec<(String, String)>,
}

impl Keyword {
    pub(super) fn get(&self, key: &str) -> Option<&str> {
        self.params
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    pub(super) fn has(&self, key: &str) -> bool {
        self.params.iter().any(|(k, _)| k == key)
    }
}

/// Upper case without blanks.
fn norm_key(s: &str) -> String {
    s.chars()
        .filter(|c| !c.is_whitespace())
        .collect::<String>()
        .to_ascii_uppercase()
}

/// Splits on commas outside double quotes.
fn split_quoted(s: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut start = 0;
    let mut quoted = false;
    for (i, c) in s.char_indices() {
        match c {
            '"' => quoted = !quoted,
            ',' if !quoted => {
                out.push(s.get(start..i).unwrap_or(""));
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(s.get(start..).unwrap_or(""));
    out
}

/// Trims and removes surrounding double quotes.
fn unquote(s: &str) -> &str {
    let t = s.trim();
    if t.len() >= 2 && t.starts_with('"') && t.ends_with('"') {
        t.get(1..t.len() - 1).unwrap_or(t)
    } else {
        t
    }
}

/// Data fields, trimmed and unquoted, trailing empty fields dropped.
pub(super) fn fields(s: &str) -> Vec<&str> {
    let mut f: Vec<&str> = split_quoted(s).into_iter().map(unquote).collect();
    while f.last().is_some_and(|x| x.is_empty()) {
        f.pop();
    }
    f
}

pub(super) fn parse_keyword(text: &str) -> Keyword {
    let body = text.strip_prefix('*').unwrap_or(text);
    let parts = split_quoted(body);
    let first = parts.first().copied().unwrap_or("");
    let mut params = Vec::new();
    for p in parts.iter().skip(1) {
        if p.trim().is_empty() {
            continue;
        }
        match p.split_once('=') {
            Some((k, v)) => params.push((norm_key(k), unquote(v).to_string())),
            None => params.push((norm_key(p), String::new())),
        }
    }
    Keyword {
        name: norm_key(first),
        shown: format!("*{}", first.trim()),
        params,
    }
}

fn is_keyword(t: &str) -> bool {
    t.starts_with('*') && !t.starts_with("**")
}

/// Keywords whose data lines may come from an `INPUT=` file.
fn takes_input_file(name: &str) -> bool {
    matches!(name, "NODE" | "ELEMENT" | "NSET" | "ELSET" | "SURFACE")
}

/// Expands `*INCLUDE` and `INPUT=` into one list of significant lines.
pub(super) struct Flattener {
    pub(super) files: Vec<PathBuf>,
    /// Canonical paths of the files being read, outermost first (cycle detection).
    pub(super) stack: Vec<PathBuf>,
}

impl Flattener {
    pub(super) fn err(&self, loc: Loc, msg: impl std::fmt::Display) -> Error {
        located(&self.files, loc, msg)
    }

    /// Non-blank, non-comment lines of a text, trimmed, with 1-based line numbers.
    fn significant(text: &str) -> Vec<(usize, &str)> {
        text.lines()
            .enumerate()
            .map(|(i, l)| {
                let l = if i == 0 {
                    l.trim_start_matches('\u{feff}')
                } else {
                    l
                };
                (i + 1, l.trim())
            })
            .filter(|(_, t)| !t.is_empty() && !t.starts_with("**"))
            .collect()
    }

    /// Resolves, checks and reads a file named by `INPUT=` on the line at `loc`.
    fn open(&mut self, name: &str, loc: Loc, depth: usize) -> Result<(usize, PathBuf, String)> {
        if name.is_empty() {
            return Err(self.err(loc, "INPUT= names no file"));
        }
        let including = self.files.get(loc.file).cloned().unwrap_or_default();
        let rel = Path::new(name);
        let p = if rel.is_absolute() {
            rel.to_path_buf()
        } else {
            including
                .parent()
                .unwrap_or_else(|| Path::new(""))
                .join(rel)
        };
        let c = canonical(&p);
        if self.stack.contains(&c) {
            let mut chain: Vec<String> =
                self.stack.iter().map(|s| s.display().to_string()).collect();
            chain.push(c.display().to_string());
            return Err(self.err(
                loc,
                format!(
                    "*INCLUDE cycle: {}; remove the include that loops back",
                    chain.join(" -> ")
                ),
            ));
        }
        if depth + 1 > MAX_INCLUDE_DEPTH {
            return Err(self.err(
                loc,
                format!(
                    "*INCLUDE of {} nests deeper than {MAX_INCLUDE_DEPTH} levels",
                    p.display()
                ),
            ));
        }
        // Regular files only: a device (/dev/zero, a pipe) could be read forever.
        if let Ok(md) = std::fs::metadata(&p) {
            if !md.is_file() {
                return Err(self.err(
                    loc,
                    format!("{} named by INPUT= is not a regular file", p.display()),
                ));
            }
        }
        let bytes = std::fs::read(&p).map_err(|e| {
            self.err(
                loc,
                format!("cannot read the file {} named by INPUT=: {e}", p.display()),
            )
        })?;
        let text = String::from_utf8_lossy(&bytes).into_owned();
        self.files.push(p);
        Ok((self.files.len() - 1, c, text))
    }

    pub(super) fn flatten<'t>(
        &mut self,
        text: &'t str,
        file: usize,
        depth: usize,
        out: &mut Vec<Line<'t>>,
    ) -> Result<()> {
        let sig = Self::significant(text);
        let mut i = 0;
        while let Some(&(no, t)) = sig.get(i) {
            let loc = Loc { file, line: no };
            i += 1;
            if !is_keyword(t) {
                out.push(Line {
                    loc,
                    text: Cow::Borrowed(t),
                    keyword: false,
                });
                continue;
            }
            // A keyword line ending with a comma continues on the next line.
            let mut kt: Cow<'t, str> = Cow::Borrowed(t);
            while kt.ends_with(',') {
                match sig.get(i) {
                    Some(&(_, next)) if !next.starts_with('*') => {
                        let mut s = kt.into_owned();
                        s.push_str(next);
                        kt = Cow::Owned(s);
                        i += 1;
                    }
                    _ => break,
                }
            }
            let kw = parse_keyword(&kt);
            if kw.name == "INCLUDE" {
                let Some(name) = kw.get("INPUT") else {
                    return Err(self.err(loc, "*INCLUDE without INPUT=<file>"));
                };
                let (sub_file, c, sub_text) = self.open(name, loc, depth)?;
                self.stack.push(c);
                let mut sub = Vec::new();
                let r = self.flatten(&sub_text, sub_file, depth + 1, &mut sub);
                self.stack.pop();
                r?;
                out.extend(sub.into_iter().map(|l| Line {
                    loc: l.loc,
                    text: Cow::Owned(l.text.into_owned()),
                    keyword: l.keyword,
                }));
                continue;
            }
            let input = kw.get("INPUT").map(str::to_string);
            out.push(Line {
                loc,
                text: kt,
                keyword: true,
            });
            if let (Some(name), true) = (input, takes_input_file(&kw.name)) {
                let (sub_file, _, sub_text) = self.open(&name, loc, depth)?;
                for (no, t) in Self::significant(&sub_text) {
                    let l = Loc {
                        file: sub_file,
                        line: no,
                    };
                    if is_keyword(t) {
                        return Err(self.err(
                            l,
                            format!(
                                "keyword line in a data file read by {} INPUT=; it may hold data lines only",
                                kw.shown
                            ),
                        ));
                    }
                    out.push(Line {
                        loc: l,
                        text: Cow::Owned(t.to_string()),
                        keyword: false,
                    });
                }
            }
        }
        Ok(())
    }
}

pub(super) fn upper(s: &str) -> String {
    s.to_ascii_uppercase()
}

/// A keyword line with its data lines.
pub(super) struct Block<'l, 'a> {
    pub(super) kw: Keyword,
    pub(super) loc: Loc,
    pub(super) data: &'l [Line<'a>],
}

/// The keyword blocks of a list of lines, and the number of data lines before the first
/// keyword.
pub(super) fn blocks<'l, 'a>(lines: &'l [Line<'a>]) -> (usize, Vec<Block<'l, 'a>>) {
    let mut out = Vec::new();
    let mut pre = 0;
    let mut i = 0;
    while let Some(l) = lines.get(i) {
        i += 1;
        if !l.keyword {
            pre += 1;
            continue;
        }
        let start = i;
        while lines.get(i).is_some_and(|d| !d.keyword) {
            i += 1;
        }
        out.push(Block {
            kw: parse_keyword(&l.text),
            loc: l.loc,
            data: lines.get(start..i).unwrap_or(&[]),
        });
    }
    (pre, out)
}
