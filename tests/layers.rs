//! The layers of `src/` (doc/ARCHITECTURE.md, "Layers"): no cycle between its top-level modules,
//! read from the `crate::` paths of the code (comments aside), so that it stays so.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Top-level module -> the top-level modules its code names, with the files that name each.
type Graph = BTreeMap<String, BTreeMap<String, BTreeSet<String>>>;

fn source_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            source_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

fn graph() -> Graph {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let modules: BTreeSet<String> = std::fs::read_dir(&src).unwrap().map(|e| e.unwrap().path()).filter_map(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned())).filter(|m| !["lib", "main", "build"].contains(&m.as_str())).collect();
    let mut files = Vec::new();
    source_files(&src, &mut files);
    let mut graph = Graph::new();
    for file in files {
        let relative = file.strip_prefix(&src).unwrap().to_string_lossy().into_owned();
        let top = relative.split('/').next().unwrap().trim_end_matches(".rs").to_string();
        if !modules.contains(&top) {
            continue;
        }
        let text = std::fs::read_to_string(&file).unwrap();
        for line in text.lines().filter(|l| !l.trim_start().starts_with("//")) {
            for (at, _) in line.match_indices("crate::") {
                let name: String = line[at + 7..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                if name != top && modules.contains(&name) {
                    graph.entry(top.clone()).or_default().entry(name).or_default().insert(relative.clone());
                }
            }
        }
    }
    graph
}

/// A cycle through `start`, if any: the modules in order.
fn cycle_through(graph: &Graph, start: &str) -> Option<Vec<String>> {
    let mut stack = vec![(start.to_string(), vec![start.to_string()])];
    let mut seen = BTreeSet::new();
    while let Some((node, path)) = stack.pop() {
        for next in graph.get(&node).map(|e| e.keys().cloned().collect::<Vec<_>>()).unwrap_or_default() {
            if next == start {
                return Some(path.iter().cloned().chain([next]).collect());
            }
            if seen.insert(next.clone()) {
                stack.push((next.clone(), path.iter().cloned().chain([next]).collect()));
            }
        }
    }
    None
}

#[test]
fn no_cycle_between_the_top_level_modules_of_src() {
    let graph = graph();
    let mut cycles = Vec::new();
    for module in graph.keys() {
        if let Some(cycle) = cycle_through(&graph, module) {
            let edges: Vec<String> = cycle.windows(2).map(|w| format!("{} -> {} ({})", w[0], w[1], graph[&w[0]][&w[1]].iter().cloned().collect::<Vec<_>>().join(", "))).collect();
            cycles.push(format!("{}: {}", cycle.join(" -> "), edges.join("; ")));
        }
    }
    assert!(cycles.is_empty(), "import cycles between top-level modules:\n{}", cycles.join("\n"));
}

/// The kernels sit below the solver and the backend's choice; the policy they share imports
/// nothing of the engine.
#[test]
fn the_kernels_import_neither_the_solver_nor_the_backend_and_the_policy_nothing() {
    let graph = graph();
    for kernels in ["gpu", "cpu"] {
        for above in ["solver", "backend", "run"] {
            let files = graph.get(kernels).and_then(|e| e.get(above));
            assert!(files.is_none(), "{kernels}/ imports {above}: {files:?}");
        }
    }
    assert!(graph.get("policy").is_none_or(|e| e.keys().all(|m| m == "precision")), "policy.rs imports {:?}", graph.get("policy"));
}
