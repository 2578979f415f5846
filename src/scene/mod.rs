//! Scene files: the TOML schema, `--set` overrides by dotted path, and validation.
//!
//! All values are SI: metres, kilograms, seconds, pascals.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::short_numbers;
use crate::solver::Mode;
use crate::{Error, Result};

mod discretization;
mod geometry;
mod specs;
mod validate;

pub use discretization::*;
pub use geometry::*;
pub use specs::*;
use validate::{resolve_exact, validate, Invalid};

/// A complete scene.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Short name used in reports; defaults to the file stem.
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub description: Option<String>,
    pub geometry: Geometry,
    #[serde(default)]
    pub discretization: Discretization,
    pub material: MaterialSpec,
    #[serde(default)]
    pub boundaries: BTreeMap<String, BoundarySpec>,
    /// `[regions.NAME]`: tissue regions with their own material.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub regions: BTreeMap<String, RegionSpec>,
    /// `[loads.NAME]`: gravity, point forces, tractions and pressures.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub loads: BTreeMap<String, LoadSpec>,
    /// `[measured.NAME]`: displacements prescribed node by node from a file.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub measured: BTreeMap<String, MeasuredSpec>,
    /// `[contact.NAME]`: rigid bodies the body's surface touches without friction.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub contact: BTreeMap<String, ContactSpec>,
    /// `[curves.NAME]`: tabulated load curves that boundaries and loads name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub curves: BTreeMap<String, CurveSpec>,
    #[serde(default)]
    pub solver: SolverSpec,
    #[serde(default)]
    pub probes: BTreeMap<String, ProbeSpec>,
    #[serde(default)]
    pub references: BTreeMap<String, ReferenceSpec>,
    #[serde(default)]
    pub output: OutputSpec,
    /// `[initial]`: rigid initial motion (dynamic runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial: Option<InitialSpec>,
    /// Directory of the scene file: relative input paths are resolved against it.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

impl Scene {
    /// True for `solver.mode = "dynamic"`.
    pub fn mode_is_dynamic(&self) -> bool {
        self.solver.mode == Mode::Dynamic
    }
}

/// Loads a scene file, applies `--set key.path=value` overrides and validates it.
pub fn load(path: &Path, overrides: &[String]) -> Result<Scene> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse(&text, path, overrides)
}

/// A body from a surface file (or an image's surface) is filled with tetrahedra, so a scene
/// that names no element gets tet4-anp (the non-locking tet) rather than the hex8 default it
/// could not use.
fn surface_element_default(value: &mut toml::Table) -> bool {
    let g = value.get("geometry");
    let surface = g.and_then(|g| g.get("surface")).is_some()
        || (g.and_then(|g| g.get("image")).is_some()
            && g.and_then(|g| g.get("body")).and_then(|b| b.as_str()) != Some("voxels"));
    let named = value
        .get("discretization")
        .and_then(|d| d.get("element"))
        .is_some();
    if surface && !named {
        if let Some(d) = value
            .entry("discretization")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
        {
            d.insert("element".into(), toml::Value::String("tet4-anp".into()));
            return true;
        }
    }
    false
}

/// A scene given as a JSON object (a Python dict through `json.dumps`), with the same keys,
/// overrides and checks as a scene file: its relative paths resolve against `base_dir`, and
/// errors name it as `BASE_DIR/<dict>`.
pub fn from_json(json: &str, base_dir: &Path, overrides: &[String]) -> Result<Scene> {
    let file = base_dir.join("<dict>");
    let err = |message: String| Error::scene(&file, short_numbers(&message));
    let value: serde_json::Value =
        serde_json::from_str(json).map_err(|e| err(format!("not a JSON object: {e}")))?;
    if !value.is_object() {
        return Err(err(
            "a scene is a table of tables (a dict), not a list or a value".into(),
        ));
    }
    let table = toml::Value::try_from(&value).map_err(|e| {
        err(format!(
            "{e} (None / null has no place in a scene: leave the key out)"
        ))
    })?;
    let text = toml::to_string(&table).map_err(|e| err(e.to_string()))?;
    parse(&text, &file, overrides)
}

/// Parses scene text (see [`load`]); `path` names the source in errors, which are
/// [`crate::InputKind::Scene`] errors with the file, the line (as written, when the text has it) and
/// the key (when it is known).
pub fn parse(text: &str, path: &Path, overrides: &[String]) -> Result<Scene> {
    // serde's and toml's messages write an f64 in full (1e300 as 301 digits).
    let err = |message: &str| Error::scene(path, short_numbers(message));
    // hytled's own checks write their numbers once (error::Num); nothing to shorten.
    let invalid = |b: Invalid| Error::scene(path, b.message).key(b.key);
    // Deserialise the file as written first, so schema errors carry its line numbers.
    let mut scene: Scene = toml::from_str(text).map_err(|e| {
        let table = toml::from_str::<toml::Table>(text).ok();
        let hint = table
            .as_ref()
            .and_then(name_hint)
            .map_or(String::new(), |h| format!("\n  {h}"));
        let mut error = err(&format!(
            "{}{hint}",
            with_suggestion(&e.to_string()).trim_end()
        ));
        if let Some(span) = e.span() {
            error = error.line(1 + text[..span.start.min(text.len())].matches('\n').count());
        }
        match table.as_ref().and_then(schema_path) {
            Some(key) => error.key(key),
            None => error,
        }
    })?;
    let mut value: toml::Table = toml::from_str(text).map_err(|e| err(&e.to_string()))?;
    for o in overrides {
        apply_override(&mut value, o).map_err(|m| {
            let key = o.split_once('=').map_or(o.as_str(), |(k, _)| k.trim());
            err(&format!("--set {o}: {m}")).key(key)
        })?;
    }
    check_finite(&toml::Value::Table(value.clone()), "").map_err(invalid)?;
    let tets_by_default = surface_element_default(&mut value);
    let written = toml::Value::Table(value.clone());
    if !overrides.is_empty() {
        if let Some(h) = name_hint(&value) {
            return Err(err(&format!("after --set overrides: {h}")));
        }
        // The merged table has no source lines to point at; name the key path instead.
        scene = serde_path_to_error::deserialize(toml::Value::Table(value)).map_err(
            |e: serde_path_to_error::Error<toml::de::Error>| {
                let (at, message) = (e.path().to_string(), e.inner().message());
                // Custom checks (geometry, ...) already start with their key.
                let key = if at == "." || message.starts_with(&format!("{at}:")) {
                    String::new()
                } else {
                    format!("{at}: ")
                };
                let error = err(&format!(
                    "after --set overrides: {key}{}",
                    with_suggestion(message)
                ));
                if at == "." {
                    error
                } else {
                    error.key(at)
                }
            },
        )?;
    }
    if tets_by_default {
        scene.discretization.element = ElementName::Tet4Anp;
    }
    // serde fills a fixed-size array from the first elements of a longer one: compare.
    if let Ok(typed) = toml::Value::try_from(&scene) {
        check_lengths(&written, &typed, "").map_err(invalid)?;
    }
    scene.base_dir = path.parent().map(PathBuf::from).unwrap_or_default();
    if scene.name.is_none() {
        scene.name = path.file_stem().map(|s| s.to_string_lossy().into_owned());
    }
    validate(&scene).map_err(invalid)?;
    resolve_exact(&mut scene).map_err(invalid)?;
    Ok(scene)
}

/// The dotted key at which a table fails to read as a [`Scene`] (`"."` is the whole scene).
fn schema_path(table: &toml::Table) -> Option<String> {
    let e =
        serde_path_to_error::deserialize::<_, Scene>(toml::Value::Table(table.clone())).err()?;
    let at = e.path().to_string();
    (at != ".").then_some(at)
}

/// Refuses numeric arrays longer (or shorter) than the key takes: `written` is the scene as
/// written (with overrides), `typed` the same read into [`Scene`] and written back (a
/// 4-component `gravity` came back with 3, a 3-element curve point with 2).
fn check_lengths(
    written: &toml::Value,
    typed: &toml::Value,
    at: &str,
) -> std::result::Result<(), Invalid> {
    use toml::Value as V;
    let key = |k: &str| {
        if at.is_empty() {
            k.to_string()
        } else {
            format!("{at}.{k}")
        }
    };
    match (written, typed) {
        (V::Table(a), V::Table(b)) => {
            for (k, v) in a {
                if let Some(w) = b.get(k) {
                    check_lengths(v, w, &key(k))?;
                }
            }
        }
        (V::Array(a), V::Array(b)) => {
            let numeric = a
                .iter()
                .all(|x| matches!(x, V::Integer(_) | V::Float(_) | V::Array(_)));
            if numeric && !a.is_empty() && a.len() != b.len() {
                return Err(Invalid::at(
                    at,
                    format!("{at}: {} values given, it takes {}", a.len(), b.len()),
                ));
            }
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                check_lengths(x, y, &format!("{at}[{i}]"))?;
            }
        }
        _ => {}
    }
    Ok(())
}

/// For a key that takes a name but got a number, array or bool (`support = 8` meant as
/// `support_nodes = 8`), "KEY: expected a name in quotes, one of `a`, `b`": serde says only
/// "wanted string or table". The names come from deserialising again with "?" at that key.
fn name_hint(table: &toml::Table) -> Option<String> {
    let e =
        serde_path_to_error::deserialize::<_, Scene>(toml::Value::Table(table.clone())).err()?;
    let message = e.inner().message();
    if !(message.contains("unit variant") || message.contains("wanted string or table")) {
        return None;
    }
    let mut probe = table.clone();
    let mut segments = e.path().iter().peekable();
    let mut cur = &mut probe;
    while let Some(seg) = segments.next() {
        let serde_path_to_error::Segment::Map { key } = seg else {
            return None;
        };
        if segments.peek().is_none() {
            cur.insert(key.clone(), toml::Value::String("?".into()));
            break;
        }
        cur = cur.get_mut(key)?.as_table_mut()?;
    }
    let again = serde_path_to_error::deserialize::<_, Scene>(toml::Value::Table(probe)).err()?;
    let m = again.inner().message();
    let marker = "unknown variant `?`, expected ";
    let names = &m[m.find(marker)? + marker.len()..];
    Some(format!("{}: expected a name in quotes, {names}", e.path()))
}

/// Refuses nan and inf anywhere in the scene (TOML allows them; no scene value means them).
fn check_finite(v: &toml::Value, key: &str) -> std::result::Result<(), Invalid> {
    match v {
        toml::Value::Float(x) if !x.is_finite() => Err(Invalid::at(
            key,
            format!("{key} = {x}: numbers must be finite (nan and inf are not scene values)"),
        )),
        toml::Value::Array(a) => a
            .iter()
            .enumerate()
            .try_for_each(|(i, x)| check_finite(x, &format!("{key}[{i}]"))),
        toml::Value::Table(t) => t.iter().try_for_each(|(k, x)| {
            let key = if key.is_empty() {
                k.clone()
            } else {
                format!("{key}.{k}")
            };
            check_finite(x, &key)
        }),
        _ => Ok(()),
    }
}

/// Built-in meshes larger than this many elements are refused before any memory is taken
/// (about 1 kB per element and its points: 20 GB).
pub const MAX_ELEMENTS: f64 = 2e7;

/// Sets `a.b.c = value` in a TOML table; the value is parsed as TOML (number, bool, array,
/// inline table) or else taken as a string.
pub fn apply_override(
    table: &mut toml::Table,
    assignment: &str,
) -> std::result::Result<(), String> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or("expected key.path=value")?;
    let key = key.trim();
    let raw = raw.trim();
    if key.is_empty() {
        return Err("empty key".into());
    }
    let value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
        Ok(mut t) => t.remove("v").unwrap_or(toml::Value::String(raw.into())),
        // TOML refuses numbers past f64 (1e400); taken as a string they would read "expected f64".
        Err(_) if raw.parse::<f64>().is_ok() => {
            return Err(format!(
                "{raw} is not a finite number (f64 spans about 1e-308 to 1e308)"
            ))
        }
        Err(_) => toml::Value::String(raw.into()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for (i, part) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            cur.insert(part.to_string(), value);
            return Ok(());
        }
        let entry = cur
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = match entry {
            toml::Value::Table(t) => t,
            _ => return Err(format!("'{}' is not a table", parts[..=i].join("."))),
        };
    }
    Ok(())
}

/// Appends "did you mean ...?" to serde's unknown-field / unknown-variant messages, and says
/// "a table" where serde names an internal type ("expected struct SolverSpec") and what a number
/// must be where it names a Rust type ("expected usize").
fn with_suggestion(msg: &str) -> String {
    let mut plain = msg.to_string();
    for (rust, words) in [
        ("expected usize", "expected a whole number, 0 or more"),
        ("expected u64", "expected a whole number, 0 or more"),
        ("expected u32", "expected a whole number, 0 or more"),
        ("expected f64", "expected a number"),
    ] {
        plain = plain.replace(rust, words);
    }
    let msg = &plain;
    if let Some(start) = msg.find("expected struct ") {
        let rest = &msg[start + "expected struct ".len()..];
        let end = rest
            .find(|c: char| !c.is_alphanumeric() && c != '_')
            .unwrap_or(rest.len());
        return format!(
            "{}expected a table (a [section] or {{ key = value, ... }}){}",
            &msg[..start],
            &rest[end..]
        );
    }
    for marker in ["unknown field `", "unknown variant `"] {
        if let Some(start) = msg.find(marker) {
            let rest = &msg[start + marker.len()..];
            let Some(end) = rest.find('`') else { break };
            let bad = &rest[..end];
            // rest[end..] = "`, expected one of `a`, `b`": the names are every other piece.
            let candidates: Vec<&str> = rest[end..].split('`').skip(2).step_by(2).collect();
            let best = candidates
                .iter()
                .map(|c| (strsim::jaro_winkler(bad, c), *c))
                .max_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((score, c)) = best {
                if score > 0.7 {
                    return format!("{}\n  did you mean `{c}`?", msg.trim_end());
                }
            }
        }
    }
    // toml's own wording for inline tables: "unexpected keys in table: a, available keys: b, c".
    if let Some(start) = msg.find("unexpected keys in table: ") {
        let rest = &msg[start + "unexpected keys in table: ".len()..];
        if let Some((bad, avail)) = rest.split_once(", available keys: ") {
            let avail: Vec<&str> = avail.lines().next().unwrap_or("").split(", ").collect();
            let hints: Vec<String> = bad
                .split(", ")
                .filter_map(|b| {
                    let best = avail
                        .iter()
                        .map(|c| (strsim::jaro_winkler(b, c), *c))
                        .max_by(|x, y| x.0.total_cmp(&y.0))?;
                    (best.0 > 0.7).then(|| format!("`{b}` -> did you mean `{}`?", best.1))
                })
                .collect();
            if !hints.is_empty() {
                return format!("{}\n  {}", msg.trim_end(), hints.join("\n  "));
            }
        }
    }
    msg.to_string()
}
