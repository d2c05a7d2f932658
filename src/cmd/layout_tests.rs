//! The layout of `src/cmd/`: no two files import each other, directly or round a loop.
//!
//! A file's references are the paths in its code lines (comments skipped) that start with
//! `crate::cmd::`, `super::`, `self::` or the name of one of its own child modules, resolved
//! to the longest module file they name (through `pub use self::a::b as c;` aliases). A child
//! module declaration is not a reference.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

type ModPath = Vec<String>;

/// `decode/p2os.rs` → `["decode", "p2os"]`; `decode/mod.rs` → `["decode"]`; `mod.rs` → `[]`.
fn module_path(rel: &str) -> ModPath {
    let rel = rel.strip_suffix(".rs").unwrap_or(rel);
    let mut parts: ModPath = rel.split('/').map(str::to_owned).collect();
    if parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    parts
}

/// The `::`-separated paths in a line, with `a::{b, c}` expanded to `a::b` and `a::c`.
fn paths_in(line: &str) -> Vec<Vec<String>> {
    let is_ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let chars: Vec<char> = line.chars().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < chars.len() {
        if !is_ident(chars[i]) || (i > 0 && (is_ident(chars[i - 1]) || chars[i - 1] == ':')) {
            i += 1;
            continue;
        }
        let mut segs = Vec::new();
        let mut j = i;
        loop {
            let start = j;
            while j < chars.len() && is_ident(chars[j]) {
                j += 1;
            }
            segs.push(chars[start..j].iter().collect::<String>());
            if chars.get(j) == Some(&':') && chars.get(j + 1) == Some(&':') {
                j += 2;
                if chars.get(j) == Some(&'{') {
                    let end = chars[j..]
                        .iter()
                        .position(|&c| c == '}')
                        .map_or(chars.len(), |k| j + k);
                    let inner: String = chars[j + 1..end].iter().collect();
                    for name in inner.split(',') {
                        let name = name.split_whitespace().next().unwrap_or("");
                        let name = name.split("::").next().unwrap_or("");
                        if !name.is_empty() && name != "self" {
                            let mut p = segs.clone();
                            p.push(name.to_owned());
                            out.push(p);
                        }
                    }
                    j = end;
                    segs.clear();
                    break;
                }
                continue;
            }
            break;
        }
        if segs.len() > 1 {
            out.push(segs);
        }
        i = j.max(i + 1);
    }
    out
}

/// Module → the modules it references, for `files` (path relative to `src/cmd`, source).
fn references(files: &[(String, String)]) -> BTreeMap<ModPath, BTreeSet<ModPath>> {
    let known: BTreeSet<ModPath> = files.iter().map(|(p, _)| module_path(p)).collect();
    let mut aliases: BTreeMap<ModPath, ModPath> = BTreeMap::new();
    for (p, src) in files {
        let me = module_path(p);
        for line in src.lines() {
            let l = line.trim();
            if let Some(rest) = l.strip_prefix("pub use self::")
                && let Some((target, alias)) = rest.trim_end_matches(';').split_once(" as ")
            {
                let mut from = me.clone();
                from.push(alias.trim().to_owned());
                let mut to = me.clone();
                to.extend(target.split("::").map(str::to_owned));
                aliases.insert(from, to);
            }
        }
    }
    let resolve = |path: ModPath| -> Option<ModPath> {
        let mut path = path;
        for (from, to) in &aliases {
            if path.starts_with(from) {
                let mut p = to.clone();
                p.extend(path[from.len()..].iter().cloned());
                path = p;
                break;
            }
        }
        (0..=path.len())
            .rev()
            .map(|n| path[..n].to_vec())
            .find(|p| known.contains(p))
    };
    let mut graph = BTreeMap::new();
    for (p, src) in files {
        let me = module_path(p);
        let mut refs = BTreeSet::new();
        // Inline modules (`mod tests {`) opened so far: their `super` is this file.
        let mut inline = 0usize;
        for line in src.lines() {
            let l = line.trim_start();
            if l.starts_with("//") {
                continue;
            }
            let decl = l.strip_prefix("pub ").unwrap_or(l);
            if decl.starts_with("mod ") {
                if l.trim_end().ends_with('{') {
                    inline += 1;
                }
                continue;
            }
            for path in paths_in(l) {
                let first = path[0].as_str();
                let target = if path.len() > 2 && first == "crate" && path[1] == "cmd" {
                    path[2..].to_vec()
                } else if first == "super" {
                    let ups = path.iter().take_while(|s| *s == "super").count();
                    let Some(n) = ups.checked_sub(inline).filter(|n| *n > 0) else {
                        continue;
                    };
                    let Some(base) = me.len().checked_sub(n).map(|k| me[..k].to_vec()) else {
                        continue;
                    };
                    base.into_iter()
                        .chain(path[ups..].iter().cloned())
                        .collect()
                } else if first == "self" && inline == 0 {
                    me.iter()
                        .cloned()
                        .chain(path[1..].iter().cloned())
                        .collect()
                } else if inline == 0
                    && known.contains(&[me.clone(), vec![first.to_owned()]].concat())
                {
                    me.iter().cloned().chain(path.iter().cloned()).collect()
                } else {
                    continue;
                };
                if let Some(t) = resolve(target)
                    && t != me
                {
                    refs.insert(t);
                }
            }
        }
        graph.insert(me, refs);
    }
    graph
}

/// A loop of references, if any: the modules round it, the first repeated at the end.
fn find_cycle(graph: &BTreeMap<ModPath, BTreeSet<ModPath>>) -> Option<Vec<ModPath>> {
    fn visit(
        n: &ModPath,
        graph: &BTreeMap<ModPath, BTreeSet<ModPath>>,
        stack: &mut Vec<ModPath>,
        done: &mut BTreeSet<ModPath>,
    ) -> Option<Vec<ModPath>> {
        if let Some(i) = stack.iter().position(|m| m == n) {
            let mut c = stack[i..].to_vec();
            c.push(n.clone());
            return Some(c);
        }
        if done.contains(n) {
            return None;
        }
        stack.push(n.clone());
        for m in graph.get(n).into_iter().flatten() {
            if let Some(c) = visit(m, graph, stack, done) {
                return Some(c);
            }
        }
        stack.pop();
        done.insert(n.clone());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|n| visit(n, graph, &mut Vec::new(), &mut done))
}

fn read_tree(dir: &Path, rel: &str, out: &mut Vec<(String, String)>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap())
        .collect();
    entries.sort_by_key(std::fs::DirEntry::file_name);
    for e in entries {
        let name = e.file_name().to_string_lossy().into_owned();
        let r = if rel.is_empty() {
            name.clone()
        } else {
            format!("{rel}/{name}")
        };
        if e.file_type().unwrap().is_dir() {
            read_tree(&e.path(), &r, out);
        } else if name.ends_with(".rs") {
            out.push((r, std::fs::read_to_string(e.path()).unwrap()));
        }
    }
}

fn show(c: &[ModPath]) -> String {
    c.iter()
        .map(|m| {
            if m.is_empty() {
                "cmd".to_owned()
            } else {
                m.join("::")
            }
        })
        .collect::<Vec<_>>()
        .join(" → ")
}

#[test]
fn no_file_level_import_cycles_in_src_cmd() {
    let mut files = Vec::new();
    read_tree(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("src/cmd"),
        "",
        &mut files,
    );
    let graph = references(&files);
    // The reader sees the references the split by area is about.
    let decode = module_path("decode/mod.rs");
    assert!(
        graph[&decode].contains(&module_path("decode/rflex.rs")),
        "{graph:?}"
    );
    assert!(graph[&module_path("mock/world.rs")].contains(&module_path("mock/shared.rs")));
    assert!(
        graph[&module_path("demo.rs")].contains(&module_path("mock/world.rs")),
        "aliases"
    );
    if let Some(c) = find_cycle(&graph) {
        panic!("file-level import cycle: {}", show(&c));
    }
}

#[test]
fn the_reader_finds_back_references_and_skips_tests_and_comments() {
    let files = vec![
        (
            "decode/mod.rs".to_owned(),
            "pub mod rflex;\nuse super::num;\nfn f() { rflex::decode(); }\n".to_owned(),
        ),
        (
            "decode/rflex.rs".to_owned(),
            "//! see super::Direction\nuse super::{Direction, hex};\n".to_owned(),
        ),
        (
            "decode/hex.rs".to_owned(),
            "#[cfg(test)]\nmod tests {\n    use super::*;\n}\n".to_owned(),
        ),
        ("num.rs".to_owned(), String::new()),
    ];
    let graph = references(&files);
    let m = |p: &str| module_path(p);
    assert_eq!(
        graph[&m("decode/mod.rs")],
        [m("decode/rflex.rs"), m("num.rs")].into()
    );
    assert_eq!(
        graph[&m("decode/rflex.rs")],
        [m("decode/mod.rs"), m("decode/hex.rs")].into()
    );
    assert!(
        graph[&m("decode/hex.rs")].is_empty(),
        "a test module's super is its file"
    );
    let c = find_cycle(&graph).expect("decode ↔ decode::rflex");
    assert_eq!(show(&c), "decode → decode::rflex → decode");
}
