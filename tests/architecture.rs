//! The house's shape: no two files under `src/` import each other, directly or through other
//! files (a child module's use of its ancestors does not count: they declare it); nothing
//! outside `src/cli/` names the command layer; no file of `src/`, `python/src/` or `tests/`
//! over 800 lines. Imports are read from every `crate::` and `super::` path of the code (use
//! lines and paths inline, `{…}` groups expanded; comments and a file's own test module left
//! out), each resolved to the file of the longest module it names.

use crate::util::root;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = walkdir::WalkDir::new(dir)
        .into_iter()
        .flatten()
        .map(|e| e.into_path())
        .filter(|p| p.extension().is_some_and(|e| e == "rs"))
        .collect();
    out.sort();
    out
}

/// The module path of a file under `src/`: `["crate", "a", "b"]` for `src/a/b.rs` and
/// `src/a/b/mod.rs`; `["crate"]` for `lib.rs` (and `main.rs`, the binary's root).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap();
    let mut parts: Vec<String> = vec!["crate".into()];
    let comps: Vec<String> = rel.iter().map(|c| c.to_string_lossy().into_owned()).collect();
    for (i, c) in comps.iter().enumerate() {
        let last = i + 1 == comps.len();
        if !last {
            parts.push(c.clone());
        } else if c != "mod.rs" && c != "lib.rs" && c != "main.rs" {
            parts.push(c.trim_end_matches(".rs").to_string());
        }
    }
    parts
}

/// The code of a file without its comments and its own test module.
fn code_of(text: &str) -> String {
    let text = match text.find("#[cfg(test)]\nmod tests") {
        Some(at) => &text[..at],
        None => text,
    };
    text.lines().map(|l| l.split("//").next().unwrap_or_default()).collect::<Vec<_>>().join("\n")
}

/// The paths a piece of code names from `crate` or `super`, each as its segments, `{…}` groups
/// expanded.
fn paths_in(code: &str) -> Vec<Vec<String>> {
    let bytes: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let rest: String = bytes[i..bytes.len().min(i + 7)].iter().collect();
        let boundary =
            i == 0 || !(bytes[i - 1].is_alphanumeric() || bytes[i - 1] == '_' || bytes[i - 1] == ':');
        if boundary && (rest.starts_with("crate::") || rest.starts_with("super::")) {
            let (paths, end) = expand(&bytes, i);
            out.extend(paths);
            i = end;
        } else {
            i += 1;
        }
    }
    out
}

/// The paths starting at `start` (`a::b::{c, d::e}`), and where they end.
fn expand(s: &[char], start: usize) -> (Vec<Vec<String>>, usize) {
    let mut segs: Vec<String> = Vec::new();
    let mut i = start;
    loop {
        let begin = i;
        while i < s.len() && (s[i].is_alphanumeric() || s[i] == '_') {
            i += 1;
        }
        if i > begin {
            segs.push(s[begin..i].iter().collect());
        }
        if i + 1 < s.len() && s[i] == ':' && s[i + 1] == ':' {
            i += 2;
            if i < s.len() && s[i] == '{' {
                // A group: each item a path of its own under the prefix.
                let mut out = Vec::new();
                let mut j = i + 1;
                loop {
                    while j < s.len() && (s[j].is_whitespace() || s[j] == ',') {
                        j += 1;
                    }
                    if j >= s.len() || s[j] == '}' {
                        break;
                    }
                    let (inner, end) = expand(s, j);
                    out.extend(inner.into_iter().map(|p| segs.iter().cloned().chain(p).collect()));
                    j = end.max(j + 1);
                    // Skip ` as name` and anything up to the next item.
                    while j < s.len() && s[j] != ',' && s[j] != '}' {
                        j += 1;
                    }
                }
                return (out, j + 1);
            }
            continue;
        }
        return (vec![segs], i);
    }
}

/// The import graph of `src/`: file → files it names.
fn graph(src: &Path) -> BTreeMap<PathBuf, BTreeSet<PathBuf>> {
    // The library: the binary (`main.rs`, `cli/`) is a crate of its own above it.
    let files: Vec<PathBuf> = rust_files(src)
        .into_iter()
        .filter(|f| !f.ends_with("main.rs") && !f.starts_with(src.join("cli")))
        .collect();
    let modules: BTreeMap<Vec<String>, PathBuf> =
        files.iter().map(|f| (module_of(src, f), f.clone())).collect();
    let mut out = BTreeMap::new();
    for file in &files {
        let module = module_of(src, file);
        let code = code_of(&std::fs::read_to_string(file).unwrap());
        let mut names = BTreeSet::new();
        for path in paths_in(&code) {
            let mut resolved: Vec<String> = if path[0] == "crate" {
                vec!["crate".into()]
            } else {
                // `super` is the module above the file's (a `mod.rs` is its folder's module).
                module.clone()
            };
            let mut rest = &path[..];
            if rest[0] == "crate" {
                rest = &rest[1..];
            }
            while rest.first().is_some_and(|s| s == "super") {
                resolved.pop();
                rest = &rest[1..];
            }
            for seg in rest {
                resolved.push(seg.clone());
            }
            // The file of the longest module the path names.
            while !resolved.is_empty() && !modules.contains_key(&resolved) {
                resolved.pop();
            }
            let Some(target) = modules.get(&resolved) else { continue };
            // A module's ancestors declare it: its use of them is no import in a circle.
            let ancestor = module.starts_with(&resolved) && module.len() > resolved.len();
            if target != file && !ancestor {
                names.insert(target.clone());
            }
        }
        out.insert(file.clone(), names);
    }
    out
}

/// The circles of a graph: its strongly connected components of more than one file.
fn circles(graph: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    // Tarjan's algorithm, iterative over a small graph.
    struct State<'a> {
        graph: &'a BTreeMap<PathBuf, BTreeSet<PathBuf>>,
        index: BTreeMap<&'a PathBuf, usize>,
        low: BTreeMap<&'a PathBuf, usize>,
        stack: Vec<&'a PathBuf>,
        on_stack: BTreeSet<&'a PathBuf>,
        next: usize,
        out: Vec<Vec<PathBuf>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a PathBuf) {
        s.index.insert(v, s.next);
        s.low.insert(v, s.next);
        s.next += 1;
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in s.graph.get(v).into_iter().flatten() {
            let Some((w, _)) = s.graph.get_key_value(w) else { continue };
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack.remove(w);
                component.push(w.clone());
                if w == v {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                s.out.push(component);
            }
        }
    }
    let mut s = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in graph.keys() {
        if !s.index.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}

#[test]
fn no_file_under_src_imports_another_that_imports_it_back() {
    let src = root().join("src");
    let g = graph(&src);
    assert!(g.len() > 50, "{} files read", g.len());
    // The reader sees imports: the one command its pipeline, the loops their search.
    assert!(g[&src.join("loops/mod.rs")].contains(&src.join("pipeline/from_sources.rs")));
    assert!(g[&src.join("loops/of_index.rs")].contains(&src.join("loops/matching.rs")));
    let found = circles(&g);
    let named: Vec<String> = found
        .iter()
        .map(|c| {
            c.iter()
                .map(|p| p.strip_prefix(&src).unwrap().display().to_string())
                .collect::<Vec<_>>()
                .join(" ⇄ ")
        })
        .collect();
    assert!(named.is_empty(), "files that import each other: {named:#?}");
}

#[test]
fn the_circle_finder_finds_circles() {
    let p = |s: &str| PathBuf::from(s);
    let mut g = BTreeMap::new();
    g.insert(p("a"), BTreeSet::from([p("b")]));
    g.insert(p("b"), BTreeSet::from([p("c")]));
    g.insert(p("c"), BTreeSet::from([p("a")]));
    g.insert(p("d"), BTreeSet::from([p("a")]));
    assert_eq!(circles(&g), vec![vec![p("a"), p("b"), p("c")]]);
    assert_eq!(
        paths_in("use super::{poses::{PoseTable, kitti}, Scan};\nlet x = crate::a::b(1);"),
        vec![
            vec!["super", "poses", "PoseTable"],
            vec!["super", "poses", "kitti"],
            vec!["super", "Scan"],
            vec!["crate", "a", "b"]
        ]
    );
}

#[test]
fn only_the_command_layer_names_it() {
    let src = root().join("src");
    for file in rust_files(&src) {
        if file.starts_with(src.join("cli")) || file.ends_with("main.rs") {
            continue;
        }
        let code = code_of(&std::fs::read_to_string(&file).unwrap());
        assert!(!code.contains("crate::cli"), "{} names crate::cli", file.display());
    }
}

#[test]
fn no_file_is_over_800_lines() {
    let mut long = Vec::new();
    for dir in ["src", "python/src", "tests"] {
        for file in rust_files(&root().join(dir)) {
            let lines = std::fs::read_to_string(&file).unwrap().lines().count();
            if lines > 800 {
                long.push(format!("{} ({lines})", file.strip_prefix(root()).unwrap().display()));
            }
        }
    }
    assert!(long.is_empty(), "split by job: {long:?}");
}
