//! The architecture invariant "no import cycles between the modules of
//! `ntg-trainer`" (docs/ARCHITECTURE.md), checked on the source: every
//! `crate::…` and `super::…` path outside comments and test modules is an
//! edge from the module whose file holds it to the deepest module the path
//! names (a path into a module's own ancestors is not an edge: a child
//! module may use its parent).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Module path (`domain::blocks`) → the source text it counts, from the
/// crate's `src/` (not `lib.rs` / `main.rs`, which only declare; not
/// `tests.rs` files, which are test modules).
fn modules(src: &Path) -> BTreeMap<String, String> {
    fn walk(dir: &Path, prefix: &[String], out: &mut BTreeMap<String, String>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            let name = entry.file_name().to_string_lossy().into_owned();
            if path.is_dir() {
                let mut inner = prefix.to_vec();
                inner.push(name);
                walk(&path, &inner, out);
                continue;
            }
            let Some(stem) = name.strip_suffix(".rs") else {
                continue;
            };
            if prefix.is_empty() && matches!(stem, "lib" | "main") || stem == "tests" {
                continue;
            }
            let mut module = prefix.to_vec();
            if stem != "mod" {
                module.push(stem.to_owned());
            }
            let text = std::fs::read_to_string(&path).unwrap();
            out.insert(module.join("::"), code_of(&text));
        }
    }
    let mut out = BTreeMap::new();
    walk(src, &[], &mut out);
    out
}

/// `text` without its test module (from `#[cfg(test)]` on: the crate keeps
/// them at the end of a file) and without comment lines (doc links are not
/// imports).
fn code_of(text: &str) -> String {
    let code = text.split("#[cfg(test)]").next().unwrap_or_default();
    code.lines()
        .filter(|line| !line.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The paths `code` names after `anchor` (`crate::` or `super::`), a
/// braced group `a::{b, c::d}` expanded one level.
fn paths_after(code: &str, anchor: &str) -> Vec<String> {
    let ident = |c: char| c.is_alphanumeric() || c == '_' || c == ':';
    let mut out = Vec::new();
    for (at, _) in code.match_indices(anchor) {
        if code[..at].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':') {
            continue; // e.g. `my_crate::`, or the second `super::` of a chain
        }
        let rest = &code[at + anchor.len()..];
        let head: String = rest.chars().take_while(|&c| ident(c)).collect();
        let after = &rest[head.len()..];
        match after.strip_prefix('{') {
            Some(group) if head.is_empty() || head.ends_with("::") => {
                let group = &group[..group.find('}').unwrap_or(group.len())];
                for item in group.split(',') {
                    let item: String = item.trim().chars().take_while(|&c| ident(c)).collect();
                    out.push(format!("{head}{item}"));
                }
            }
            _ => out.push(head),
        }
    }
    out
}

/// The import edges between `modules`.
fn edges(modules: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    let deepest = |path: &str| {
        let segments: Vec<&str> = path.split("::").filter(|s| !s.is_empty()).collect();
        (1..=segments.len())
            .rev()
            .map(|n| segments[..n].join("::"))
            .find(|candidate| modules.contains_key(candidate))
    };
    let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (module, code) in modules {
        // `super::super::x` from `a::b::c` is `a::x`.
        let from_super = |path: String| {
            let mut base: Vec<&str> = module.split("::").collect();
            base.pop();
            let mut rest = path.as_str();
            while let Some(up) = rest.strip_prefix("super::") {
                base.pop();
                rest = up;
            }
            format!("{}::{rest}", base.join("::"))
        };
        let named = paths_after(code, "crate::")
            .into_iter()
            .chain(paths_after(code, "super::").into_iter().map(from_super));
        for target in named.filter_map(|p| deepest(&p)) {
            let ancestor = module.starts_with(&format!("{target}::"));
            if target != *module && !ancestor {
                out.entry(module.clone()).or_default().insert(target);
            }
        }
    }
    out
}

/// A cycle of `edges`, as the modules along it, if there is one.
fn find_cycle(edges: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        edges: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|n| n == node) {
            let mut cycle = path[at..].to_vec();
            cycle.push(node.to_owned());
            return Some(cycle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_owned());
        for next in edges.get(node).into_iter().flatten() {
            if let Some(cycle) = visit(next, edges, path, done) {
                return Some(cycle);
            }
        }
        path.pop();
        done.insert(node.to_owned());
        None
    }
    let mut done = BTreeSet::new();
    edges
        .keys()
        .find_map(|node| visit(node, edges, &mut Vec::new(), &mut done))
}

#[test]
fn the_modules_of_ntg_trainer_import_each_other_without_a_cycle() {
    let modules = modules(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"));
    assert!(modules.contains_key("domain::blocks") && modules.contains_key("fit"));
    let edges = edges(&modules);
    // The check sees imports: the one epoch loop is used by every method.
    assert!(edges["method::ntg"].contains("fit"), "{edges:?}");
    if let Some(cycle) = find_cycle(&edges) {
        panic!("import cycle: {}", cycle.join(" -> "));
    }
}

#[test]
fn the_cycle_check_finds_a_cycle_through_a_braced_import_and_super() {
    let modules: BTreeMap<String, String> = [
        ("fit", "use crate::{spec, run_dir::RunDir};"),
        ("run_dir", "fn f() { crate::method::ntg::step(); }"),
        ("method", "pub mod ntg;"),
        ("method::ntg", "use super::super::fit::fit; // crate::spec"),
        ("spec", "/// [`crate::fit`]\nfn g() {}"),
    ]
    .into_iter()
    .map(|(m, text)| (m.to_owned(), code_of(text)))
    .collect();
    let edges = edges(&modules);
    assert!(!edges.contains_key("spec"), "a doc link is no import");
    let cycle = find_cycle(&edges).expect("fit -> run_dir -> method::ntg -> fit");
    assert_eq!(cycle.first(), cycle.last());
    assert_eq!(cycle.len(), 4, "{cycle:?}");
}
