//! The crate's modules use each other without a loop: the graph of `crate::`
//! paths in their code (comments and unit tests left out) is a DAG, so each
//! module can be read and changed knowing only the ones below it. A module
//! is a file of a folder (`coarse/laplacian.rs`, with its own child
//! modules in `coarse/laplacian/`); inside the crate, modules name each
//! other by that path, never through a folder's re-exports, so the graph
//! sees every use.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The module a source file belongs to, as `folder/module`
/// (`coarse/laplacian/shared.rs` is `coarse/laplacian`); `None` for the
/// crate root and a folder's `mod.rs`, which only declare and re-export.
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let relative = file.strip_prefix(src).ok()?;
    let parts: Vec<String> = relative
        .components()
        .map(|c| {
            c.as_os_str()
                .to_string_lossy()
                .trim_end_matches(".rs")
                .to_owned()
        })
        .collect();
    match parts.as_slice() {
        [folder, module, ..] if module != "mod" => Some(format!("{folder}/{module}")),
        _ => None,
    }
}

fn files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.unwrap_or_else(|e| panic!("{e}")).path();
        if path.is_dir() {
            files(&path, out);
        } else if path.extension().is_some_and(|x| x == "rs") {
            out.push(path);
        }
    }
}

/// Every `crate::FOLDER::MODULE` in `code`, as `FOLDER/MODULE`; a path
/// that stops at a folder (`crate::model::Elastic`, through its
/// re-exports) as `FOLDER`.
fn uses(code: &str) -> BTreeSet<String> {
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect()
    };
    let mut found = BTreeSet::new();
    let mut rest = code;
    while let Some(at) = rest.find("crate::") {
        rest = &rest[at + "crate::".len()..];
        let folder = ident(rest);
        let after = &rest[folder.len()..];
        match after.strip_prefix("::").map(ident) {
            Some(module) if module.starts_with(|c: char| c.is_ascii_lowercase()) => {
                found.insert(format!("{folder}/{module}"));
            }
            _ => {
                found.insert(folder);
            }
        }
    }
    found
}

#[test]
fn the_modules_use_each_other_without_a_loop() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut all = Vec::new();
    files(&src, &mut all);
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in &all {
        let Some(module) = module_of(&src, file) else {
            continue;
        };
        let text = std::fs::read_to_string(file).unwrap_or_else(|e| panic!("{e}"));
        let code_part = text.split("#[cfg(test)]").next().unwrap_or_default();
        let code: String = code_part
            .lines()
            .filter(|line| !line.trim_start().starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n");
        let entry = graph.entry(module.clone()).or_default();
        entry.extend(uses(&code).into_iter().filter(|used| *used != module));
    }
    assert!(graph.len() > 20, "{} modules read", graph.len());
    for (module, used) in &graph {
        for name in used {
            assert!(
                graph.contains_key(name),
                "{module} uses `crate::{}`, which is no module of the crate: name \
                 the module (`crate::folder::module::Item`), not a folder's re-export",
                name.replace('/', "::")
            );
        }
    }
    // Depth-first search; a module met again while on the path closes a loop.
    fn visit(
        module: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) {
        if done.contains(module) {
            return;
        }
        if let Some(at) = path.iter().position(|m| m == module) {
            panic!("a loop of modules: {} -> {module}", path[at..].join(" -> "));
        }
        path.push(module.to_owned());
        for used in graph.get(module).into_iter().flatten() {
            if graph.contains_key(used) {
                visit(used, graph, path, done);
            }
        }
        path.pop();
        done.insert(module.to_owned());
    }
    let mut done = BTreeSet::new();
    for module in graph.keys() {
        visit(module, &graph, &mut Vec::new(), &mut done);
    }
}
