//! The house's rules (ARCHITECTURE.md), read from the source itself: every `crate::`, `super::`,
//! `self::` and child-module path in `src/**/*.rs` is resolved to the file that defines it, and
//!
//! - a library module imports only from its own layer or below;
//! - the L2 siblings (`nav`, `calib`, `selfcal`) never import each other;
//! - no circle of files: the file graph (re-exports in a `mod.rs` followed to the file that defines
//!   the name, not counted as imports themselves) has no strongly connected component of two or more.
//!
//! The binary (`main.rs` and `src/cli/`) sits above every layer; it reaches the library as `gfcal::`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each library module (the first segment below `crate::`) and its layer.
const LAYERS: &[(&str, u8)] = &[
    ("units", 0),
    ("rng", 0),
    ("stats", 0),
    ("signal", 0),
    ("io", 0),
    ("motion", 1),
    ("array", 1),
    ("sensor", 1),
    ("nav", 2),
    ("calib", 2),
    ("selfcal", 2),
    ("discrepancy", 3),
    ("config", 4),
    ("mc", 5),
    ("lincov", 5),
    ("report", 6),
];

/// Modules of one layer that must not import each other.
const SIBLINGS: &[&str] = &["nav", "calib", "selfcal"];

/// Violations that are allowed to remain, each with the reason it stays (source file, target file).
/// This list may only shrink.
const ALLOWED: &[(&str, &str, &str)] = &[];

/// A source file: its module path below the crate root and whether it belongs to the binary.
struct Source {
    module: Vec<String>,
    binary: bool,
    text: String,
}

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// Removes comments, string and char literals (keeps line structure irrelevant: imports only).
fn strip(text: &str) -> String {
    let b: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c == '/' && b.get(i + 1) == Some(&'/') {
            while i < b.len() && b[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && b.get(i + 1) == Some(&'*') {
            let mut depth = 0;
            while i < b.len() {
                if b[i] == '/' && b.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == '*' && b.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if c == 'r'
            && (b.get(i + 1) == Some(&'"') || b.get(i + 1) == Some(&'#'))
            && !is_ident(b.get(i.wrapping_sub(1)).copied())
        {
            // raw string r"..." or r#"..."#
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&'"') {
                out.push(c);
                i += 1;
                continue;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == '"' && (0..hashes).all(|h| b.get(j + 1 + h) == Some(&'#')) {
                    j += 1 + hashes;
                    break;
                }
                j += 1;
            }
            out.push_str("\"\"");
            i = j;
        } else if c == '"' {
            i += 1;
            while i < b.len() && b[i] != '"' {
                if b[i] == '\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push_str("\"\"");
        } else if c == '\'' {
            // a char literal ('x', '\n', '\u{..}') or a lifetime ('a)
            if b.get(i + 2) == Some(&'\'') {
                i += 3;
                out.push_str("' '");
            } else if b.get(i + 1) == Some(&'\\') {
                let mut j = i + 2;
                while j < b.len() && b[j] != '\'' {
                    j += 1;
                }
                i = j + 1;
                out.push_str("' '");
            } else {
                out.push(c);
                i += 1;
            }
        } else {
            out.push(c);
            i += 1;
        }
    }
    out
}

fn is_ident(c: Option<char>) -> bool {
    c.is_some_and(|c| c.is_alphanumeric() || c == '_')
}

/// Expands a use tree (`a::{b, c::{d, e}}`) into its paths.
fn expand(tree: &str) -> Vec<Vec<String>> {
    // `x as y` keeps x: the rename is cut at '@' once whitespace is gone
    let tree: String = tree.split_whitespace().collect::<Vec<_>>().join(" ").replace(" as ", "@");
    let tree: String = tree.chars().filter(|c| !c.is_whitespace()).collect();
    fn go(prefix: &[String], t: &str, out: &mut Vec<Vec<String>>) {
        if let Some(open) = t.find('{') {
            let head = &t[..open];
            let inner = &t[open + 1..t.len() - 1];
            let mut p = prefix.to_vec();
            p.extend(head.split("::").filter(|s| !s.is_empty()).map(String::from));
            let mut depth = 0;
            let mut start = 0;
            for (i, c) in inner.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        go(&p, &inner[start..i], out);
                        start = i + 1;
                    }
                    _ => {}
                }
            }
            go(&p, &inner[start..], out);
        } else if !t.is_empty() {
            let mut p = prefix.to_vec();
            let t = t.split('@').next().unwrap_or(t);
            p.extend(t.split("::").filter(|s| !s.is_empty()).map(String::from));
            out.push(p);
        }
    }
    let mut out = Vec::new();
    go(&[], &tree, &mut out);
    out
}

/// How many inline modules (`mod name { ... }`) are open at each byte of `text`.
fn inline_depth(text: &str) -> Vec<u8> {
    let b = text.as_bytes();
    let mut depth = vec![0u8; b.len() + 1];
    // a stack of brace levels at which an inline module opened
    let mut opened: Vec<usize> = Vec::new();
    let mut level = 0usize;
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'{' {
            // is this the brace of `mod name {`?
            let before = text[..i].trim_end();
            let word_start = before.rfind(|c: char| !(c.is_alphanumeric() || c == '_')).map_or(0, |k| k + 1);
            let head = before[..word_start].trim_end();
            if !before[word_start..].is_empty() && (head.ends_with(" mod") || head == "mod" || head.ends_with("\nmod"))
            {
                opened.push(level);
            }
            level += 1;
        } else if b[i] == b'}' {
            level = level.saturating_sub(1);
            if opened.last() == Some(&level) {
                opened.pop();
            }
        }
        depth[i] = opened.len() as u8;
        i += 1;
    }
    depth
}

/// `use` statements as (is `pub use`, path) pairs, and other `crate::`/`super::` paths; a
/// `super` that leaves an inline module of the file (`mod tests { use super::*; }`) is dropped,
/// so that each path is relative to the file's own module.
fn imports(text: &str) -> Vec<(bool, Vec<String>)> {
    let depth = inline_depth(text);
    let unnest = |at: usize, mut p: Vec<String>| -> Vec<String> {
        let d = depth[at] as usize;
        let supers = p.iter().take_while(|s| *s == "super").count();
        if d > 0 && supers > 0 {
            let drop = supers.min(d);
            p.drain(..drop);
            if p.first().is_none_or(|s| s != "super") {
                p.insert(0, "self".into());
            }
        }
        p
    };
    let mut out = Vec::new();
    let mut rest = text;
    // use statements
    while let Some(pos) = find_word(rest, "use") {
        let before = &rest[..pos];
        let is_pub = before.trim_end().ends_with("pub") || before.trim_end().ends_with(")");
        let after = &rest[pos + 3..];
        let Some(end) = after.find(';') else { break };
        let tree = &after[..end];
        let at = text.len() - rest.len() + pos;
        for p in expand(tree) {
            out.push((is_pub, unnest(at, p)));
        }
        rest = &after[end..];
    }
    // inline paths: crate::a::b, super::a, self::a (outside use statements too)
    let s = text;
    for start_kw in ["crate::", "super::"] {
        let mut from = 0;
        while let Some(off) = s[from..].find(start_kw) {
            let i = from + off;
            from = i + start_kw.len();
            if is_ident(s[..i].chars().last()) {
                continue;
            }
            let mut j = i;
            let bytes = s.as_bytes();
            while j < s.len() && (bytes[j].is_ascii_alphanumeric() || bytes[j] == b'_' || bytes[j] == b':') {
                j += 1;
            }
            let path: Vec<String> = s[i..j].split("::").filter(|x| !x.is_empty()).map(String::from).collect();
            out.push((false, unnest(i, path)));
        }
    }
    out
}

fn find_word(s: &str, w: &str) -> Option<usize> {
    let mut from = 0;
    while let Some(off) = s[from..].find(w) {
        let i = from + off;
        let before = s[..i].chars().last();
        let after = s[i + w.len()..].chars().next();
        if !is_ident(before) && after.is_some_and(|c| c.is_whitespace()) {
            return Some(i);
        }
        from = i + w.len();
    }
    None
}

struct House {
    files: BTreeMap<PathBuf, Source>,
    /// (binary?, module path) -> file
    by_module: BTreeMap<(bool, Vec<String>), PathBuf>,
}

impl House {
    fn read() -> House {
        let src = src_dir();
        let mut paths = Vec::new();
        rust_files(&src, &mut paths);
        let mut files = BTreeMap::new();
        let mut by_module = BTreeMap::new();
        for p in paths {
            let rel = p.strip_prefix(&src).expect("under src").to_path_buf();
            let mut parts: Vec<String> = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
            let last = parts.pop().expect("a file name");
            let binary = parts.first().is_some_and(|f| f == "cli")
                || (parts.is_empty() && last == "main.rs")
                || (parts.is_empty() && is_binary_root_module(&src, &last));
            // src/cli/x.rs is the binary's module cli::x
            let mut module = parts;
            match last.as_str() {
                "mod.rs" | "lib.rs" | "main.rs" => {}
                other => module.push(other.trim_end_matches(".rs").to_string()),
            }
            let text = strip(&std::fs::read_to_string(&p).expect("source readable"));
            by_module.insert((binary, module.clone()), rel.clone());
            files.insert(rel, Source { module, binary, text });
        }
        House { files, by_module }
    }

    /// The file a path (segments from the crate root) resolves to, following `pub use` re-exports.
    fn resolve(&self, binary: bool, path: &[String]) -> Option<PathBuf> {
        let mut best = None;
        let mut depth = 0;
        for k in 0..=path.len() {
            if let Some(f) = self.by_module.get(&(binary, path[..k].to_vec())) {
                best = Some(f.clone());
                depth = k;
            }
        }
        let file = best?;
        // Follow a re-export: `pub use child::{Name}` in the module file that holds the path.
        if let Some(name) = path.get(depth) {
            let src = &self.files[&file];
            for (is_pub, p) in imports(&src.text) {
                if is_pub && p.last() == Some(name) && p.len() >= 2 {
                    let target = self.absolute(&file, &p[..p.len() - 1])?;
                    let mut full = target;
                    full.push(name.clone());
                    return self.resolve(binary, &full).or(Some(file));
                }
            }
        }
        Some(file)
    }

    /// A use path written in `file`, made absolute (segments from the crate root), or None for
    /// paths outside the crate (std, other crates).
    fn absolute(&self, file: &Path, p: &[String]) -> Option<Vec<String>> {
        let src = &self.files[file];
        let first = p.first()?;
        let own: &[String] = &src.module;
        // the module whose scope `self`/`super` refer to: a non-mod file's module is itself
        match first.as_str() {
            "crate" => Some(p[1..].to_vec()),
            "self" => {
                let mut m = own.to_vec();
                m.extend_from_slice(&p[1..]);
                Some(m)
            }
            "super" => {
                let mut m = own.to_vec();
                let mut rest = p;
                while rest.first().is_some_and(|s| s == "super") {
                    m.pop();
                    rest = &rest[1..];
                }
                m.extend_from_slice(rest);
                Some(m)
            }
            "gfcal" if src.binary => None,
            name => {
                // a child module of this file's module (`use child::X` in a mod.rs)
                let mut m = own.to_vec();
                m.push(name.to_string());
                if self.by_module.contains_key(&(src.binary, m.clone())) {
                    m.extend_from_slice(&p[1..]);
                    Some(m)
                } else {
                    None
                }
            }
        }
    }

    /// Import edges file -> file (re-exports left out).
    fn edges(&self) -> BTreeSet<(PathBuf, PathBuf)> {
        let mut edges = BTreeSet::new();
        for (file, src) in &self.files {
            for (is_pub, p) in imports(&src.text) {
                if is_pub && is_module_file(file) {
                    continue;
                }
                let Some(abs) = self.absolute(file, &p) else { continue };
                if let Some(target) = self.resolve(src.binary, &abs)
                    && &target != file
                {
                    edges.insert((file.clone(), target));
                }
            }
        }
        edges
    }
}

fn is_binary_root_module(src: &Path, file: &str) -> bool {
    // modules declared by main.rs at the top of src/
    let Ok(main) = std::fs::read_to_string(src.join("main.rs")) else { return false };
    let name = file.trim_end_matches(".rs");
    main.lines().any(|l| {
        let l = l.trim();
        l == format!("mod {name};") || l == format!("pub mod {name};") || l == format!("pub(crate) mod {name};")
    })
}

fn is_module_file(p: &Path) -> bool {
    matches!(p.file_name().and_then(|f| f.to_str()), Some("mod.rs" | "lib.rs" | "main.rs"))
}

fn layer_of(src: &Source) -> Option<(String, u8)> {
    if src.binary {
        return Some(("<binary>".into(), 100));
    }
    let top = src.module.first()?;
    LAYERS.iter().find(|(m, _)| m == top).map(|(m, l)| (m.to_string(), *l))
}

/// Strongly connected components of two or more files (Tarjan).
fn circles(edges: &BTreeSet<(PathBuf, PathBuf)>) -> Vec<Vec<PathBuf>> {
    let mut nodes: BTreeSet<&PathBuf> = BTreeSet::new();
    let mut adj: BTreeMap<&PathBuf, Vec<&PathBuf>> = BTreeMap::new();
    for (a, b) in edges {
        nodes.insert(a);
        nodes.insert(b);
        adj.entry(a).or_default().push(b);
    }
    struct T<'a> {
        index: BTreeMap<&'a PathBuf, usize>,
        low: BTreeMap<&'a PathBuf, usize>,
        stack: Vec<&'a PathBuf>,
        on: BTreeSet<&'a PathBuf>,
        next: usize,
        out: Vec<Vec<PathBuf>>,
    }
    fn visit<'a>(v: &'a PathBuf, adj: &BTreeMap<&'a PathBuf, Vec<&'a PathBuf>>, t: &mut T<'a>) {
        t.index.insert(v, t.next);
        t.low.insert(v, t.next);
        t.next += 1;
        t.stack.push(v);
        t.on.insert(v);
        for &w in adj.get(v).map(Vec::as_slice).unwrap_or(&[]) {
            if !t.index.contains_key(w) {
                visit(w, adj, t);
                let lw = t.low[w];
                let lv = t.low[v];
                t.low.insert(v, lv.min(lw));
            } else if t.on.contains(w) {
                let iw = t.index[w];
                let lv = t.low[v];
                t.low.insert(v, lv.min(iw));
            }
        }
        if t.low[v] == t.index[v] {
            let mut comp = Vec::new();
            while let Some(w) = t.stack.pop() {
                t.on.remove(w);
                comp.push(w.clone());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                comp.sort();
                t.out.push(comp);
            }
        }
    }
    let mut t = T {
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in nodes {
        if !t.index.contains_key(v) {
            visit(v, &adj, &mut t);
        }
    }
    t.out
}

fn allowed(a: &Path, b: &Path) -> bool {
    ALLOWED.iter().any(|(x, y, _)| Path::new(x) == a && Path::new(y) == b)
}

#[test]
fn every_library_module_has_a_layer() {
    let house = House::read();
    let unknown: Vec<String> = house
        .files
        .iter()
        .filter(|(_, s)| !s.binary && !s.module.is_empty() && layer_of(s).is_none())
        .map(|(p, _)| p.display().to_string())
        .collect();
    assert!(unknown.is_empty(), "files in no layer of ARCHITECTURE.md: {unknown:?}");
}

#[test]
fn no_import_goes_up_a_layer_or_between_siblings() {
    let house = House::read();
    let mut bad = Vec::new();
    for (a, b) in house.edges() {
        let (Some((ma, la)), Some((mb, lb))) = (layer_of(&house.files[&a]), layer_of(&house.files[&b])) else {
            continue;
        };
        let sibling = ma != mb && SIBLINGS.contains(&ma.as_str()) && SIBLINGS.contains(&mb.as_str());
        if (lb > la || sibling) && !allowed(&a, &b) {
            bad.push(format!("{} (L{la}) -> {} (L{lb})", a.display(), b.display()));
        }
    }
    assert!(bad.is_empty(), "imports against the layers:\n{}", bad.join("\n"));
}

#[test]
fn no_circle_of_files() {
    let house = House::read();
    let edges: BTreeSet<_> = house.edges().into_iter().filter(|(a, b)| !allowed(a, b)).collect();
    let found = circles(&edges);
    let text: Vec<String> =
        found.iter().map(|c| c.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")).collect();
    assert!(found.is_empty(), "circles of files:\n{}", text.join("\n"));
}

#[test]
fn the_checker_sees_a_circle_and_an_upward_import() {
    // The parser on a made-up pair of files: a circle and a re-export followed to its file.
    let a = strip("use crate::nav::drift::{DriftSample, x as y}; // crate::mc::Nothing\nlet s = \"crate::mc\";");
    let paths: Vec<Vec<String>> = imports(&a).into_iter().map(|(_, p)| p).collect();
    assert!(paths.contains(&vec!["crate".into(), "nav".into(), "drift".into(), "DriftSample".into()]));
    assert!(!paths.iter().any(|p| p.contains(&"mc".to_string())), "comments and strings are not imports: {paths:?}");
    // `super` inside a file's inline test module is the file itself.
    let t = strip(
        "use super::Outer;\n#[cfg(test)]\nmod tests {\n    use super::Thing;\n    fn f() { super::super::x(); }\n}\n",
    );
    let paths: Vec<Vec<String>> = imports(&t).into_iter().map(|(_, p)| p).collect();
    assert!(paths.contains(&vec!["super".into(), "Outer".into()]), "{paths:?}");
    assert!(paths.contains(&vec!["self".into(), "Thing".into()]), "{paths:?}");
    assert!(paths.contains(&vec!["super".into(), "x".into()]), "{paths:?}");
    let mut e = BTreeSet::new();
    e.insert((PathBuf::from("a.rs"), PathBuf::from("b.rs")));
    e.insert((PathBuf::from("b.rs"), PathBuf::from("c.rs")));
    e.insert((PathBuf::from("c.rs"), PathBuf::from("a.rs")));
    e.insert((PathBuf::from("c.rs"), PathBuf::from("d.rs")));
    assert_eq!(circles(&e), vec![vec![PathBuf::from("a.rs"), PathBuf::from("b.rs"), PathBuf::from("c.rs")]]);
    // The real house has imports the checker resolves (so that an empty result means something).
    let house = House::read();
    let edges = house.edges();
    assert!(edges.len() > 100, "only {} import edges found", edges.len());
    assert!(
        edges.contains(&(PathBuf::from("mc/trial.rs"), PathBuf::from("nav/navigator.rs")))
            || edges.iter().any(|(a, b)| a.starts_with("mc") && b.starts_with("nav"))
    );
}
