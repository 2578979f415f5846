//! What the parser records: element references, set events, surface elements and notes
//! for the warnings.

use std::collections::BTreeMap;

use super::lines::{Keyword, Loc};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum ElemRef {
    Vol(usize),
    Face(usize),
    Ignored,
}

#[derive(Debug, Clone)]
pub(super) enum Item {
    Id(u64),
    Gen(u64, u64, u64),
    Name(String),
}

#[derive(Debug, Clone, Copy)]
pub(super) enum Label {
    S(usize),
    Pos,
    Neg,
}

#[derive(Debug, Clone)]
pub(super) enum Target {
    Id(u64),
    Name(String),
}

/// Set definitions, resolved in file order once every node and element is known.
pub(super) enum SetEvent {
    NodeBlock {
        name: String,
        start: usize,
        end: usize,
    },
    ElemBlock {
        name: String,
        refs: Vec<ElemRef>,
    },
    Nset {
        name: String,
        loc: Loc,
        items: Vec<(Item, Loc)>,
        elset: Option<String>,
    },
    Elset {
        name: String,
        items: Vec<(Item, Loc)>,
    },
    Surface {
        name: String,
        entries: Vec<(Target, Option<Label>, Loc)>,
    },
}

pub(super) struct SurfElem {
    pub(super) id: u64,
    pub(super) nodes: Vec<u64>,
    pub(super) loc: Loc,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Mode {
    Top,
    Step,
}

/// What the reader tells the user besides the mesh, gathered over every part read.
#[derive(Default)]
pub(super) struct Notes {
    pub(super) warnings: Vec<String>,
    /// Skipped keywords: (normalized name, name as written), first occurrence of each.
    pub(super) skipped: Vec<(String, String)>,
    pub(super) ignored_types: BTreeMap<String, usize>,
    pub(super) extra_node_fields: usize,
    pub(super) pre_keyword_lines: usize,
    pub(super) assembly_nodes_skipped: usize,
    pub(super) assembly_sets_skipped: Vec<String>,
}

impl Notes {
    pub(super) fn skip_keyword(&mut self, kw: &Keyword) {
        if !self.skipped.iter().any(|(n, _)| *n == kw.name) {
            self.skipped.push((kw.name.clone(), kw.shown.clone()));
        }
    }

    /// Adds the notes of another part read (each warning once).
    pub(super) fn absorb(&mut self, o: Notes) {
        for w in o.warnings {
            if !self.warnings.contains(&w) {
                self.warnings.push(w);
            }
        }
        for (n, shown) in o.skipped {
            if !self.skipped.iter().any(|(m, _)| *m == n) {
                self.skipped.push((n, shown));
            }
        }
        for (ty, n) in o.ignored_types {
            *self.ignored_types.entry(ty).or_insert(0) += n;
        }
        self.extra_node_fields += o.extra_node_fields;
        self.pre_keyword_lines += o.pre_keyword_lines;
        self.assembly_nodes_skipped += o.assembly_nodes_skipped;
        self.assembly_sets_skipped.extend(o.assembly_sets_skipped);
    }

    pub(super) fn into_warnings(self) -> Vec<String> {
        let mut warnings = self.warnings;
        if self.pre_keyword_lines > 0 {
            warnings.push(format!(
                "{} data line(s) before the first keyword were ignored",
                self.pre_keyword_lines
            ));
        }
        if self.extra_node_fields > 0 {
            warnings.push(format!(
                "{} *NODE line(s) have more than 3 coordinates; the extra fields were ignored",
                self.extra_node_fields
            ));
        }
        for (ty, n) in &self.ignored_types {
            warnings.push(format!(
                "ignored {n} element(s) of type {ty} (line/point elements are not part of a volume mesh)"
            ));
        }
        if self.assembly_nodes_skipped > 0 {
            warnings.push(format!(
                "{} node/element line(s) defined in the assembly (reference points?) were skipped",
                self.assembly_nodes_skipped
            ));
        }
        if !self.assembly_sets_skipped.is_empty() {
            warnings.push(format!(
                "assembly-level set(s) of assembly nodes (no INSTANCE=) or of skipped instances were skipped: {}",
                self.assembly_sets_skipped.join(", ")
            ));
        }
        if !self.skipped.is_empty() {
            let names: Vec<&str> = self.skipped.iter().map(|(_, s)| s.as_str()).collect();
            warnings.push(format!("skipped keywords: {}", names.join(", ")));
        }
        warnings
    }
}
