//! The one-way order of the library's modules: every `crate::` path in `src/` goes to a layer below its own
//! (the order is the `layers` block of ARCHITECTURE.md), and no two sibling files import each other.
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The layers of ARCHITECTURE.md's `layers` block, top first; modules on one line share a layer.
fn layers(architecture: &str) -> Vec<Vec<String>> {
    let block = architecture.split("```layers\n").nth(1).expect("ARCHITECTURE.md has a ```layers block");
    let block = &block[..block.find("```").expect("the layers block is closed")];
    block
        .lines()
        .map(|l| l.split_whitespace().map(str::to_string).collect::<Vec<_>>())
        .filter(|l| !l.is_empty())
        .collect()
}

/// Every `.rs` file under `dir`.
fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The module path of a file under `src/` (`data/collect.rs` -> [data, collect]; `model/mod.rs` -> [model]).
fn module_of(relative: &Path) -> Vec<String> {
    let mut parts: Vec<String> = relative.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" {
        parts.push(stem.to_string());
    }
    parts
}

/// Code without comments (a path named in a doc comment is no import).
fn code(text: &str) -> String {
    text.lines().map(|l| l.split("//").next().unwrap()).collect::<Vec<_>>().join("\n")
}

/// The identifier paths that follow `prefix` in `text` (`crate::a::b` -> [a, b]); braces end a path.
fn paths_after(text: &str, prefix: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for (i, _) in text.match_indices(prefix) {
        let before = text[..i].chars().last();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
            continue;
        }
        let rest = &text[i + prefix.len()..];
        let mut path = Vec::new();
        for segment in rest.split("::") {
            let ident: String = segment.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            if ident.is_empty() {
                break;
            }
            let whole = ident.len() == segment.len();
            path.push(ident);
            if !whole {
                break;
            }
        }
        if !path.is_empty() {
            out.push(path);
        }
    }
    out
}

/// Where a file's imports break the order: `(file, imported module)` pairs.
fn violations(src: &Path, layers: &[Vec<String>]) -> Vec<String> {
    let rank: BTreeMap<&str, usize> =
        layers.iter().enumerate().flat_map(|(i, l)| l.iter().map(move |m| (m.as_str(), i))).collect();
    let mut files = Vec::new();
    sources(src, &mut files);
    let mut bad = Vec::new();
    for file in files {
        let relative = file.strip_prefix(src).unwrap();
        let module = module_of(relative);
        let Some(own) = module.first() else { continue };
        let own_rank = *rank.get(own.as_str()).unwrap_or_else(|| panic!("{own} is in no layer of ARCHITECTURE.md"));
        let text = code(&std::fs::read_to_string(&file).unwrap());
        let prefix = if own == "cli" || own == "main" { "oneshot_lab::" } else { "crate::" };
        for path in paths_after(&text, prefix) {
            let target = path[0].as_str();
            if target == own.as_str() {
                continue;
            }
            match rank.get(target) {
                Some(&r) if r > own_rank => {}
                Some(_) => bad.push(format!("{} imports {target}", relative.display())),
                None => {}
            }
        }
    }
    bad.sort();
    bad.dedup();
    bad
}

/// Registries and the interfaces they register, which name each other by design: the architecture registry and
/// the model settings and policy interface its entries build from; the stage graph and the stage kinds.
const REGISTRIES: [&str; 3] = [
    "model::architectures <-> model::config",
    "model::architectures <-> model::policy",
    "pipeline::graph <-> pipeline::stages",
];

/// Pairs of sibling files (same folder, neither the other's parent) that import each other.
fn mutual_imports(src: &Path) -> Vec<String> {
    let mut files = Vec::new();
    sources(src, &mut files);
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_of(f.strip_prefix(src).unwrap())).collect();
    let mut edges: BTreeSet<(Vec<String>, Vec<String>)> = BTreeSet::new();
    for file in &files {
        let relative = file.strip_prefix(src).unwrap();
        let module = module_of(relative);
        let is_mod = relative.ends_with("mod.rs");
        let text = code(&std::fs::read_to_string(file).unwrap());
        let parent: Vec<String> = if is_mod || module.is_empty() {
            module[..module.len().saturating_sub(1)].to_vec()
        } else {
            module[..module.len() - 1].to_vec()
        };
        let mut targets: Vec<Vec<String>> = paths_after(&text, "crate::");
        targets.extend(paths_after(&text, "super::").into_iter().map(|p| [parent.clone(), p].concat()));
        for t in targets {
            // The longest prefix of the path that is a file's module.
            if let Some(n) = (1..=t.len()).rev().find(|&n| modules.contains(&t[..n])) {
                let target = t[..n].to_vec();
                if target != module {
                    edges.insert((module.clone(), target));
                }
            }
        }
    }
    let mut cycles = Vec::new();
    for (a, b) in &edges {
        let siblings = a.len() == b.len() && a[..a.len() - 1] == b[..b.len() - 1];
        if a < b && siblings && edges.contains(&(b.clone(), a.clone())) {
            cycles.push(format!("{} <-> {}", a.join("::"), b.join("::")));
        }
    }
    cycles
}

#[test]
fn every_import_goes_down_the_declared_layers() {
    let root = Path::new(ROOT);
    let layers = layers(&std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap());
    let declared: BTreeSet<&str> = layers.iter().flatten().map(String::as_str).collect();
    let lib = std::fs::read_to_string(root.join("src/lib.rs")).unwrap();
    for line in lib.lines().filter_map(|l| l.strip_prefix("pub mod ")) {
        let name = line.trim_end_matches(';');
        assert!(declared.contains(name), "src/lib.rs declares {name}, which ARCHITECTURE.md's layers do not list");
    }
    let bad = violations(&root.join("src"), &layers);
    assert!(bad.is_empty(), "imports against the order of ARCHITECTURE.md:\n{}", bad.join("\n"));
    let cycles: Vec<String> =
        mutual_imports(&root.join("src")).into_iter().filter(|c| !REGISTRIES.contains(&c.as_str())).collect();
    assert!(cycles.is_empty(), "sibling files that import each other:\n{}", cycles.join("\n"));
}

#[test]
fn an_import_against_the_order_is_found() {
    // A scratch tree with one upward import and one pair of siblings importing each other.
    let dir = crate::helpers::scratch("layers-check");
    let src = dir.join("src");
    std::fs::create_dir_all(src.join("data")).unwrap();
    std::fs::create_dir_all(src.join("sim")).unwrap();
    std::fs::write(src.join("data/a.rs"), "use super::b::X;\nuse crate::sim::env::Env;\n").unwrap();
    std::fs::write(src.join("data/b.rs"), "use super::a::Y; // crate::train in a comment is no import\n").unwrap();
    std::fs::write(src.join("sim/env.rs"), "use crate::data::a::Y;\n").unwrap();
    let layers = vec![vec!["data".to_string()], vec!["sim".to_string()]];
    assert_eq!(violations(&src, &layers), vec!["sim/env.rs imports data".to_string()]);
    assert_eq!(mutual_imports(&src), vec!["data::a <-> data::b".to_string()]);
}
