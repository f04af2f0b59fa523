//! Two architecture invariants of docs/ARCHITECTURE.md, checked on the
//! source of `ntg-trainer` and `ntg-train`: no import cycles between a
//! crate's modules, and no domain file of `ntg-trainer` imports another.
//! Every `crate::…` and `super::…` path outside comments and test modules
//! is an edge from the module whose file holds it to the deepest module the
//! path names, after following the crate's re-exports (`pub use
//! domain::blocks;` in `lib.rs` makes `crate::blocks` name
//! `domain::blocks`). A path into a module's own ancestors is not an edge: a
//! child module may use its parent.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Module path (`domain::blocks`) → the source text it counts, from the
/// crate's `src/` (`lib.rs` as the root module `""`, whose paths are
/// re-exports, not imports; not `main.rs`; not `tests.rs` files, which are
/// test modules).
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
            if prefix.is_empty() && stem == "main" || stem == "tests" {
                continue;
            }
            let mut module = prefix.to_vec();
            if stem != "mod" && !(prefix.is_empty() && stem == "lib") {
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

/// `module`'s path `path` relative to the crate root: `super::` climbs
/// (`super::super::x` from `a::b::c` is `a::x`), `crate::` and `self::`
/// anchor, and a bare first segment naming a child module of `module` is
/// that child (an external crate's path gives `None`).
fn resolve(module: &str, path: &str, modules: &BTreeMap<String, String>) -> Option<String> {
    let join = |base: &[&str], rest: &str| {
        let mut all = base.to_vec();
        all.push(rest);
        all.into_iter()
            .filter(|s| !s.is_empty())
            .collect::<Vec<_>>()
            .join("::")
    };
    let base: Vec<&str> = module.split("::").filter(|s| !s.is_empty()).collect();
    if let Some(rest) = path.strip_prefix("crate::") {
        return Some(rest.to_owned());
    }
    if path.starts_with("super::") {
        let mut base = base;
        let mut rest = path;
        while let Some(up) = rest.strip_prefix("super::") {
            base.pop();
            rest = up;
        }
        return Some(join(&base, rest));
    }
    let rest = path.strip_prefix("self::").unwrap_or(path);
    let first = rest.split("::").next().unwrap_or_default();
    modules
        .contains_key(&join(&base, first))
        .then(|| join(&base, rest))
}

/// The re-exports of `modules`: `module::name` → what it names, relative to
/// the crate root, for every `pub use` of a path into the crate (`pub use
/// domain::{blocks, collect};` in `lib.rs` gives `blocks` →
/// `domain::blocks`).
fn aliases(modules: &BTreeMap<String, String>) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for (module, code) in modules {
        for statement in code.split("pub use ").skip(1) {
            let statement = &statement[..statement.find(';').unwrap_or(statement.len())];
            let statement: String = statement.split_whitespace().collect::<Vec<_>>().join(" ");
            let (head, items) = match statement.split_once('{') {
                Some((head, group)) => (
                    head.to_owned(),
                    group
                        .trim_end_matches('}')
                        .split(',')
                        .map(str::trim)
                        .collect(),
                ),
                None => (String::new(), vec![statement.as_str()]),
            };
            for item in items.into_iter().filter(|i| !i.is_empty() && *i != "*") {
                let (path, name) = match item.split_once(" as ") {
                    Some((path, name)) => (format!("{head}{path}"), name.to_owned()),
                    None => (
                        format!("{head}{item}"),
                        item.rsplit("::").next().unwrap_or(item).to_owned(),
                    ),
                };
                if let Some(target) = resolve(module, &path, modules) {
                    let key = if module.is_empty() {
                        name
                    } else {
                        format!("{module}::{name}")
                    };
                    out.insert(key, target);
                }
            }
        }
    }
    out
}

/// `path` (relative to the crate root) with re-exported prefixes replaced
/// by what they name, until none is left.
fn follow(path: &str, aliases: &BTreeMap<String, String>) -> String {
    let mut path = path.to_owned();
    for _ in 0..8 {
        let segments: Vec<&str> = path.split("::").collect();
        let hit = (1..=segments.len()).rev().find_map(|n| {
            let prefix = segments[..n].join("::");
            aliases.get(&prefix).map(|target| (n, target.clone()))
        });
        match hit {
            Some((n, target)) if target != segments[..n].join("::") => {
                path = std::iter::once(target.as_str())
                    .chain(segments[n..].iter().copied())
                    .collect::<Vec<_>>()
                    .join("::");
            }
            _ => break,
        }
    }
    path
}

/// The import edges between `modules` (the root module's paths are its
/// re-exports: no edges).
fn edges(modules: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    let aliases = aliases(modules);
    let deepest = |path: &str| {
        let path = follow(path, &aliases);
        let segments: Vec<&str> = path.split("::").filter(|s| !s.is_empty()).collect();
        (1..=segments.len())
            .rev()
            .map(|n| segments[..n].join("::"))
            .find(|candidate| modules.contains_key(candidate))
    };
    let mut out: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (module, code) in modules.iter().filter(|(m, _)| !m.is_empty()) {
        let named = paths_after(code, "crate::")
            .into_iter()
            .map(|p| format!("crate::{p}"))
            .chain(
                paths_after(code, "super::")
                    .into_iter()
                    .map(|p| format!("super::{p}")),
            )
            .filter_map(|p| resolve(module, &p, modules));
        for target in named.filter_map(|p| deepest(&p)) {
            let ancestor = module.starts_with(&format!("{target}::"));
            if target != *module && !ancestor {
                out.entry(module.clone()).or_default().insert(target);
            }
        }
    }
    out
}

/// The edges from one domain file of `ntg-trainer` (`domain::x`) to
/// another.
fn domain_imports(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<(String, String)> {
    let domain_file = |m: &str| {
        m.strip_prefix("domain::")
            .is_some_and(|rest| !rest.contains("::"))
    };
    edges
        .iter()
        .filter(|(from, _)| domain_file(from))
        .flat_map(|(from, to)| {
            to.iter()
                .filter(|t| domain_file(t))
                .map(move |t| (from.clone(), t.clone()))
        })
        .collect()
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

fn crate_src(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(name)
        .join("src")
}

#[test]
fn the_modules_of_ntg_trainer_and_ntg_train_import_each_other_without_a_cycle() {
    let trainer = modules(&crate_src("ntg-trainer"));
    assert!(trainer.contains_key("domain::blocks") && trainer.contains_key("experiment"));
    let library = modules(&crate_src("ntg-train"));
    assert!(library.contains_key("fit") && library.contains_key("method::ntg"));
    for modules in [trainer, library] {
        let edges = edges(&modules);
        if let Some(cycle) = find_cycle(&edges) {
            panic!("import cycle: {}", cycle.join(" -> "));
        }
    }
    // The check sees imports: the one epoch loop is used by every method.
    let library_edges = edges(&modules(&crate_src("ntg-train")));
    assert!(
        library_edges["method::ntg"].contains("fit"),
        "{library_edges:?}"
    );
}

#[test]
fn no_domain_file_of_ntg_trainer_imports_another() {
    let edges = edges(&modules(&crate_src("ntg-trainer")));
    // The check sees imports, re-exports followed: sorting uses the block
    // world that block stacking re-exports.
    assert!(
        edges["domain::sorting"].contains("block_world"),
        "{edges:?}"
    );
    assert_eq!(domain_imports(&edges), Vec::<(String, String)>::new());
}

/// The lines of `code` that branch on a method: a `match` or `matches!`
/// over an expression that names one (`config.method`, `flags.method`, a
/// `method` variable). Domains ask a method what it reads instead.
fn method_matches(code: &str) -> Vec<String> {
    code.lines()
        .filter(|line| {
            let line = line.trim();
            let scrutinee = line
                .split_once("match ")
                .or_else(|| line.split_once("matches!("))
                .map(|(_, rest)| rest.split(['{', ',']).next().unwrap_or_default());
            scrutinee.is_some_and(|s| s.contains("method"))
        })
        .map(str::to_owned)
        .collect()
}

#[test]
fn no_domain_file_of_ntg_trainer_matches_on_a_method() {
    let modules = modules(&crate_src("ntg-trainer"));
    let mut found = Vec::new();
    for (name, text) in &modules {
        if name.starts_with("domain::") {
            found.extend(
                method_matches(&code_of(text))
                    .into_iter()
                    .map(|l| format!("{name}: {l}")),
            );
        }
    }
    assert_eq!(found, Vec::<String>::new());
    // Planted, it is seen.
    let planted =
        "fn f() {\n    let kind = match config.method {\n        MethodId::Ntg => 1,\n    };\n}";
    assert_eq!(method_matches(planted).len(), 1);
    assert_eq!(
        method_matches("if matches!(flags.method, MethodId::Ntg | MethodId::Flat) {}").len(),
        1
    );
    assert!(method_matches("match config.obs {").is_empty());
}

#[test]
fn a_planted_import_through_a_re_export_is_seen() {
    let modules: BTreeMap<String, String> = [
        ("", "pub mod domain;\npub use domain::{blocks, collect};"),
        (
            "domain",
            "pub mod blocks;\npub mod collect;\npub mod sorting;",
        ),
        ("domain::blocks", "pub use crate::block_world::encoder;"),
        ("domain::collect", ""),
        (
            "domain::sorting",
            "fn f() { let c = crate::blocks::env_config(1); }",
        ),
        ("block_world", "use crate::fit::Loop;"),
        ("fit", "use crate::{spec, blocks::Recipe};"),
        ("spec", ""),
    ]
    .into_iter()
    .map(|(m, text)| (m.to_owned(), code_of(text)))
    .collect();
    let edges = edges(&modules);
    assert_eq!(
        domain_imports(&edges),
        [("domain::sorting".to_owned(), "domain::blocks".to_owned())]
    );
    let cycle = find_cycle(&edges).expect("fit -> domain::blocks -> block_world -> fit");
    assert_eq!(cycle.first(), cycle.last());
    assert!(cycle.contains(&"domain::blocks".to_owned()), "{cycle:?}");
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
