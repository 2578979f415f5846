//! The architecture the brief asks for, checked on the source: the module graph (which
//! top-level module names which through `crate::`) has no cycle, and the layers below the
//! pipeline never see the scene schema (issue 23: "the lower layers must not see `Scene`").

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Top-level modules that may read the scene: the schema itself, the pipeline that translates
/// it, and the commands built on the pipeline.
const TOP: [&str; 5] = ["scene", "simulation", "comparison", "sweep", "bench"];

/// Modules exempt from the `Scene` check: `error` has a variant for scene-file errors.
const NAMES_SCENE_ERRORS: &str = "error";

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The code of a file without comments and without its unit-test module (tests may build
/// fixtures from any layer).
fn code(text: &str) -> String {
    let body = match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => &text[..i],
        None => text,
    };
    body.lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Module of each source file (`src/meshless/mls.rs` -> "meshless"), with its code.
fn modules() -> BTreeMap<String, String> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut out: BTreeMap<String, String> = BTreeMap::new();
    for f in files {
        let rel = f.strip_prefix(&src).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let name = first.trim_end_matches(".rs").to_string();
        if name == "main" || name == "lib" {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        out.entry(name).or_default().push_str(&code(&text));
    }
    out
}

/// The modules a module's code names through `crate::name`.
fn edges(mods: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    let mut g = BTreeMap::new();
    for (m, text) in mods {
        let mut to = BTreeSet::new();
        for piece in text.split("crate::").skip(1) {
            let name: String = piece
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if name != *m && mods.contains_key(&name) {
                to.insert(name);
            }
        }
        // `use crate::{a, b::c}` groups.
        for piece in text.split("crate::{").skip(1) {
            let group: String = piece.chars().take_while(|&c| c != ';').collect();
            for name in mods.keys() {
                if name != m
                    && group
                        .split(|c: char| !(c.is_alphanumeric() || c == '_'))
                        .any(|w| w == name)
                {
                    to.insert(name.clone());
                }
            }
        }
        g.insert(m.clone(), to);
    }
    g
}

/// A cycle through `start`, as the path of module names, if there is one.
fn cycle_from(g: &BTreeMap<String, BTreeSet<String>>, start: &str) -> Option<Vec<String>> {
    let mut stack = vec![(start.to_string(), vec![start.to_string()])];
    let mut seen = BTreeSet::new();
    while let Some((m, path)) = stack.pop() {
        for n in g.get(&m).into_iter().flatten() {
            if n == start {
                let mut p = path.clone();
                p.push(n.clone());
                return Some(p);
            }
            if seen.insert(n.clone()) {
                let mut p = path.clone();
                p.push(n.clone());
                stack.push((n.clone(), p));
            }
        }
    }
    None
}

#[test]
fn the_module_graph_has_no_cycle() {
    let mods = modules();
    assert!(mods.contains_key("solver") && mods.contains_key("meshless"));
    let g = edges(&mods);
    for m in g.keys() {
        if let Some(c) = cycle_from(&g, m) {
            panic!("module cycle: {}", c.join(" -> "));
        }
    }
}

#[test]
fn lower_layers_do_not_see_the_scene() {
    for (m, text) in modules() {
        if TOP.contains(&m.as_str()) || m == NAMES_SCENE_ERRORS {
            continue;
        }
        for bad in ["crate::scene", "crate::simulation", "Scene"] {
            assert!(
                !text.contains(bad),
                "module `{m}` names `{bad}`: lower layers take typed settings, translated from the \
                 scene in simulation"
            );
        }
    }
}

/// Issue 23: the pipeline (`simulation`) is the one place that knows both the scene schema and
/// the solver; the schema and the commands built on the pipeline reach the solver through it.
#[test]
fn only_the_pipeline_knows_both_the_scene_and_the_solver() {
    for (m, text) in modules() {
        if m == "simulation" || !TOP.contains(&m.as_str()) {
            continue;
        }
        // The schema names the solver's mode, step-estimate, device and static-variant enums as
        // scene values.
        let calls: Vec<&str> = text
            .split("crate::solver")
            .skip(1)
            .filter(|rest| {
                !(rest.starts_with("::Mode")
                    || rest.starts_with("::StepEstimate")
                    || rest.starts_with("::Device")
                    || rest.starts_with("::StaticVariant"))
            })
            .collect();
        assert!(
            calls.is_empty(),
            "module `{m}` names the solver: go through simulation (solve, critical_step)"
        );
    }
}
