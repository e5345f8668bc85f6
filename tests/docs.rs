//! Keeps README.md and docs/*.md true to the binary and the repository:
//!
//! - every `configs/...toml` path they name passes `gfcal check` (exit 0);
//! - every `gfcal SUBCOMMAND` in a code block (fenced, or an inline code span) names a subcommand
//!   that `gfcal --help` lists, and every `--flag` on that line is one of the subcommand's options
//!   (`gfcal SUBCOMMAND --help`); a command line in a fenced block (`gfcal ...` or
//!   `cargo run --release -- ...`) is also parsed whole by the binary's own parser, with `--help`
//!   appended so that nothing runs: an unknown flag, an extra argument or a value of the wrong type
//!   fails it;
//! - every relative Markdown link points at an existing file, and a `#fragment` into a Markdown
//!   file at one of its headings;
//! - README.md stays under 150 lines (the front door; the rest belongs in docs/).
//!
//! Each failure names the file and line, so a typo in a doc is found where it is.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const README_MAX_LINES: usize = 150;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn gfcal(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gfcal"))
        .args(args)
        .current_dir(root())
        .output()
        .unwrap_or_else(|e| panic!("cannot start gfcal {args:?}: {e}"))
}

/// README.md and every docs/*.md, as (path relative to the root, text).
fn pages() -> Vec<(String, String)> {
    let mut paths = vec![root().join("README.md")];
    let docs = root().join("docs");
    let mut entries: Vec<PathBuf> = std::fs::read_dir(&docs)
        .unwrap_or_else(|e| panic!("{}: {e}", docs.display()))
        .map(|e| e.expect("directory entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    entries.sort();
    assert!(!entries.is_empty(), "docs/ holds no Markdown pages");
    paths.extend(entries);
    paths
        .into_iter()
        .map(|p| {
            let text = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            let rel = p.strip_prefix(root()).expect("under the root").to_string_lossy().into_owned();
            (rel, text)
        })
        .collect()
}

/// A piece of a page: prose (with its inline code spans found separately) or a fenced block's line.
#[derive(Debug)]
enum Piece<'a> {
    Prose { line: usize, text: &'a str },
    Fenced { line: usize, text: &'a str },
}

fn pieces(text: &str) -> Vec<Piece<'_>> {
    let mut out = Vec::new();
    let mut fence: Option<&str> = None;
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        let marker = if trimmed.starts_with("```") {
            Some("```")
        } else if trimmed.starts_with("~~~") {
            Some("~~~")
        } else {
            None
        };
        match (fence, marker) {
            (None, Some(m)) => fence = Some(m),
            (Some(f), Some(m)) if f == m && trimmed.trim_end() == m => fence = None,
            (Some(_), _) => out.push(Piece::Fenced { line: i + 1, text: line }),
            (None, None) => out.push(Piece::Prose { line: i + 1, text: line }),
        }
    }
    assert!(fence.is_none(), "a fenced code block is not closed");
    out
}

/// The prose of a page as blocks between fenced code blocks: (line number of the block's first
/// line, the block's text). Code spans and links may run over a line break inside a block.
fn prose_blocks(text: &str) -> Vec<(usize, String)> {
    let mut out: Vec<(usize, String)> = Vec::new();
    let mut last_line = 0;
    for piece in pieces(text) {
        if let Piece::Prose { line, text } = piece {
            match out.last_mut() {
                Some((_, block)) if line == last_line + 1 => {
                    block.push('\n');
                    block.push_str(text);
                }
                _ => out.push((line, text.to_string())),
            }
            last_line = line;
        }
    }
    out
}

/// The inline code spans of a prose block, each with its line within the block (0-based), and the
/// block with every span blanked out (line breaks kept, so offsets still give lines).
fn inline_code(block: &str) -> (Vec<(usize, String)>, String) {
    let chars: Vec<char> = block.chars().collect();
    let mut spans = Vec::new();
    let mut rest = String::with_capacity(block.len());
    let line_at = |i: usize| chars[..i].iter().filter(|&&c| c == '\n').count();
    let mut i = 0;
    while i < chars.len() {
        if chars[i] != '`' {
            rest.push(chars[i]);
            i += 1;
            continue;
        }
        let ticks = chars[i..].iter().take_while(|&&c| c == '`').count();
        let open = i + ticks;
        let mut j = open;
        let mut close = None;
        while j < chars.len() {
            if chars[j] == '`' {
                let n = chars[j..].iter().take_while(|&&c| c == '`').count();
                if n == ticks {
                    close = Some(j);
                    break;
                }
                j += n;
            } else {
                j += 1;
            }
        }
        let Some(c) = close else {
            rest.extend(&chars[i..]);
            break;
        };
        let span: String = chars[open..c].iter().map(|&ch| if ch == '\n' { ' ' } else { ch }).collect();
        spans.push((line_at(i), span.trim().to_string()));
        rest.extend(chars[i..c + ticks].iter().map(|&ch| if ch == '\n' { '\n' } else { ' ' }));
        i = c + ticks;
    }
    (spans, rest)
}

/// Splits a shell line into words: quotes removed, stopping at a comment, a redirection, a pipe
/// or a command separator. Variables are left as written (gfcal sees them as plain text).
fn shell_words(line: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut quote: Option<char> = None;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match quote {
            Some(q) if c == q => quote = None,
            Some(_) => word.push(c),
            None => match c {
                '\'' | '"' => {
                    quote = Some(c);
                    in_word = true;
                }
                '\\' => {
                    if let Some(n) = chars.next() {
                        word.push(n);
                        in_word = true;
                    }
                }
                c if c.is_whitespace() => {
                    if in_word {
                        words.push(std::mem::take(&mut word));
                        in_word = false;
                    }
                }
                '#' if !in_word => break,
                '>' | '<' | '|' | ';' | '&' => {
                    // `2>` and friends: drop a bare file-descriptor number before the operator.
                    if in_word && word.chars().all(|d| d.is_ascii_digit()) {
                        word.clear();
                        in_word = false;
                    }
                    break;
                }
                c => {
                    word.push(c);
                    in_word = true;
                }
            },
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

/// The fenced blocks' lines of a page with `\` continuations joined: (first line number, line).
fn fenced_commands(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut pending: Option<(usize, String)> = None;
    for piece in pieces(text) {
        let Piece::Fenced { line, text } = piece else {
            if let Some(p) = pending.take() {
                out.push(p);
            }
            continue;
        };
        let body = text.trim();
        let (start, mut joined) = pending.take().unwrap_or((line, String::new()));
        let continued = body.ends_with('\\');
        joined.push_str(body.trim_end_matches('\\'));
        joined.push(' ');
        if continued {
            pending = Some((start, joined));
        } else {
            out.push((start, joined));
        }
    }
    if let Some(p) = pending {
        out.push(p);
    }
    out
}

/// The gfcal arguments of a command line: after `gfcal` or `cargo run --release --`, else None.
fn gfcal_args(line: &str) -> Option<Vec<String>> {
    let line = line.trim().trim_start_matches("$ ");
    let rest =
        if let Some(r) = line.strip_prefix("gfcal ") { r } else { line.strip_prefix("cargo run --release -- ")? };
    Some(shell_words(rest))
}

/// A subcommand as typed, not a placeholder such as `COMMAND` or `<command>`.
fn is_subcommand_word(w: &str) -> bool {
    !w.is_empty() && w.chars().all(|c| c.is_ascii_lowercase() || c == '-') && !w.starts_with('-')
}

/// The `--flags` among words; brackets of a synopsis (`[--out DIR]`) are not part of a flag.
fn flags_of(words: &[String]) -> Vec<String> {
    words
        .iter()
        .map(|w| w.trim_start_matches(['[', '(']))
        .filter(|w| w.starts_with("--") && w.len() > 2)
        .map(|w| {
            let w = w.split('=').next().unwrap_or(w);
            w.trim_end_matches([']', ')', ',', '.']).to_string()
        })
        .collect()
}

/// An inline code span is a synopsis, not a shell line: `[--resume | --force]`, `xx|xy|...|zz`.
fn synopsis_words(span: &str) -> Option<Vec<String>> {
    let rest = span.trim().strip_prefix("gfcal ")?;
    Some(rest.split_whitespace().map(str::to_string).collect())
}

struct Cli {
    subcommands: BTreeSet<String>,
    options: BTreeMap<String, BTreeSet<String>>,
}

/// Reads the subcommands from `gfcal --help` and each one's options from `gfcal SUB --help`.
fn cli() -> Cli {
    let help = gfcal(&["--help"]);
    assert!(help.status.success(), "gfcal --help failed: {}", String::from_utf8_lossy(&help.stderr));
    let text = String::from_utf8_lossy(&help.stdout).into_owned();
    let mut subcommands = BTreeSet::new();
    let mut in_commands = false;
    for line in text.lines() {
        if line.trim_end() == "Commands:" {
            in_commands = true;
            continue;
        }
        if in_commands {
            if line.trim().is_empty() {
                break;
            }
            // A command's line is indented by two; its wrapped description by more.
            if line.starts_with("  ") && !line.starts_with("   ") {
                let name = line.split_whitespace().next().unwrap_or_default();
                if name != "help" {
                    subcommands.insert(name.to_string());
                }
            }
        }
    }
    assert!(subcommands.len() >= 10, "could not read the subcommands of gfcal --help:\n{text}");
    let mut options = BTreeMap::new();
    for sub in &subcommands {
        let out = gfcal(&[sub, "--help"]);
        assert!(out.status.success(), "gfcal {sub} --help failed");
        let mut flags = BTreeSet::new();
        for line in String::from_utf8_lossy(&out.stdout).lines() {
            let t = line.trim_start();
            let t = match t.strip_prefix('-') {
                Some(r) if !r.starts_with('-') => r.split_once(", ").map_or(t, |(_, after)| after),
                _ => t,
            };
            if let Some(name) = t.strip_prefix("--") {
                let name: String = name.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '-').collect();
                flags.insert(format!("--{name}"));
            }
        }
        assert!(flags.contains("--help"), "could not read the options of gfcal {sub} --help");
        options.insert(sub.clone(), flags);
    }
    Cli { subcommands, options }
}

/// Checks one gfcal command line's subcommand and flags; returns the problems found.
fn check_words(cli: &Cli, words: &[String]) -> Vec<String> {
    let Some(sub) = words.first() else { return vec![] };
    if sub.starts_with('-') {
        // `gfcal --help`, `gfcal --version`: options of gfcal itself.
        return flags_of(words)
            .into_iter()
            .filter(|f| f != "--help" && f != "--version")
            .map(|f| format!("`gfcal {f}` is not an option of gfcal"))
            .collect();
    }
    if !is_subcommand_word(sub) {
        return vec![];
    }
    let Some(known) = cli.options.get(sub.as_str()) else {
        return vec![format!(
            "`gfcal {sub}`: no such subcommand (gfcal --help lists {})",
            cli.subcommands.iter().cloned().collect::<Vec<_>>().join(", ")
        )];
    };
    flags_of(&words[1..])
        .into_iter()
        .filter(|f| !known.contains(f))
        .map(|f| {
            format!(
                "`{f}` is not an option of `gfcal {sub}` (it has {})",
                known.iter().cloned().collect::<Vec<_>>().join(", ")
            )
        })
        .collect()
}

#[test]
fn every_gfcal_command_in_the_docs_uses_real_subcommands_and_flags() {
    let cli = cli();
    let mut problems = Vec::new();
    let mut checked = 0;
    let mut parsed = 0;
    for (page, text) in pages() {
        for (first, block) in prose_blocks(&text) {
            for (offset, span) in inline_code(&block).0 {
                if let Some(words) = synopsis_words(&span) {
                    checked += 1;
                    let line = first + offset;
                    problems.extend(check_words(&cli, &words).into_iter().map(|p| format!("{page}:{line}: {p}")));
                }
            }
        }
        for (line, command) in fenced_commands(&text) {
            let Some(words) = gfcal_args(&command) else { continue };
            checked += 1;
            let found = check_words(&cli, &words);
            let is_sub = words.first().is_some_and(|w| cli.subcommands.contains(w.as_str()));
            problems.extend(found.iter().map(|p| format!("{page}:{line}: {p}")));
            if found.is_empty() && is_sub {
                // The binary's own parser, stopped by --help before anything runs.
                let mut args: Vec<&str> = words.iter().map(String::as_str).collect();
                args.push("--help");
                let out = gfcal(&args);
                parsed += 1;
                if !out.status.success() {
                    problems.push(format!(
                        "{page}:{line}: `gfcal {}` does not parse: {}",
                        words.join(" "),
                        String::from_utf8_lossy(&out.stderr).lines().next().unwrap_or("(no message)")
                    ));
                }
            }
        }
    }
    assert!(checked >= 20 && parsed >= 10, "too few gfcal commands found in the docs ({checked}, {parsed} parsed)");
    assert!(problems.is_empty(), "gfcal commands in the docs that the binary does not have:\n{}", problems.join("\n"));
}

/// `configs/...toml` paths named anywhere in a text (prose, code spans, fenced blocks).
fn config_paths(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let bytes = text.as_bytes();
    let mut from = 0;
    while let Some(i) = text[from..].find("configs/") {
        let start = from + i;
        from = start + "configs/".len();
        if start > 0 && (bytes[start - 1].is_ascii_alphanumeric() || matches!(bytes[start - 1], b'_' | b'/' | b'.')) {
            continue; // part of a longer path, e.g. results/x/configs/
        }
        let end = text[start..]
            .find(|c: char| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/' | '*')))
            .map_or(text.len(), |e| start + e);
        let path = text[start..end].trim_end_matches('.');
        // `configs/...toml` is a placeholder, not a file.
        if path.ends_with(".toml") && !path.contains("...") {
            out.push(path.to_string());
        }
    }
    out
}

/// Expands `dir/*.toml` against the repository; a plain path is returned as is.
fn expand(path: &str) -> Vec<String> {
    let Some((dir, pattern)) = path.rsplit_once('/') else { return vec![path.to_string()] };
    if !pattern.contains('*') {
        return vec![path.to_string()];
    }
    let suffix = pattern.trim_start_matches('*');
    let mut found: Vec<String> = std::fs::read_dir(root().join(dir))
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(suffix))
                .map(|n| format!("{dir}/{n}"))
                .collect()
        })
        .unwrap_or_default();
    found.sort();
    if found.is_empty() { vec![path.to_string()] } else { found }
}

#[test]
fn every_config_the_docs_name_passes_gfcal_check() {
    let mut named: BTreeMap<String, String> = BTreeMap::new();
    for (page, text) in pages() {
        for (i, line) in text.lines().enumerate() {
            for path in config_paths(line) {
                for p in expand(&path) {
                    named.entry(p).or_insert_with(|| format!("{page}:{}", i + 1));
                }
            }
        }
    }
    assert!(named.len() >= 10, "too few configs named in the docs: {named:?}");
    let mut problems = Vec::new();
    for (path, where_) in &named {
        if !root().join(path).is_file() {
            problems.push(format!("{where_}: {path} does not exist"));
            continue;
        }
        let out = gfcal(&["check", path]);
        if !out.status.success() {
            problems.push(format!(
                "{where_}: gfcal check {path} exits {:?}: {}",
                out.status.code(),
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
    }
    assert!(problems.is_empty(), "configs named in the docs that gfcal does not accept:\n{}", problems.join("\n"));
}

/// GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, ' ' | '-' | '_'))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of a Markdown file's headings (repeated headings get -1, -2, ... as on GitHub).
fn anchors(text: &str) -> BTreeSet<String> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut out = BTreeSet::new();
    for piece in pieces(text) {
        let Piece::Prose { text, .. } = piece else { continue };
        let t = text.trim_start();
        if !t.starts_with('#') {
            continue;
        }
        let hashes = t.chars().take_while(|&c| c == '#').count();
        if hashes > 6 || !t[hashes..].starts_with(' ') {
            continue;
        }
        let plain: String = t[hashes..].chars().filter(|&c| c != '`').collect();
        let base = anchor(&plain);
        let n = seen.entry(base.clone()).or_insert(0);
        out.insert(if *n == 0 { base.clone() } else { format!("{base}-{n}") });
        *n += 1;
    }
    out
}

/// The targets of the Markdown links and images of a prose block (code spans left out), each
/// with its line within the block (0-based).
fn link_targets(block: &str) -> Vec<(usize, String)> {
    let (_, prose) = inline_code(block);
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(i) = prose[from..].find("](") {
        let start = from + i + 2;
        let Some(len) = prose[start..].find(')') else { break };
        let target = prose[start..start + len].trim();
        // `[text](path "title")`: the path only.
        let target = target.split_whitespace().next().unwrap_or_default();
        let line = prose[..start].matches('\n').count();
        out.push((line, target.trim_start_matches('<').trim_end_matches('>').to_string()));
        from = start + len;
    }
    out
}

#[test]
fn every_relative_link_in_the_docs_points_at_an_existing_file() {
    let mut problems = Vec::new();
    let mut checked = 0;
    for (page, text) in pages() {
        let dir = root().join(&page).parent().expect("a page's folder").to_path_buf();
        for (first, block) in prose_blocks(&text) {
            for (offset, target) in link_targets(&block) {
                let line = first + offset;
                if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                checked += 1;
                let (path, fragment) = match target.split_once('#') {
                    Some((p, f)) => (p, Some(f)),
                    None => (target.as_str(), None),
                };
                let file = if path.is_empty() { root().join(&page) } else { dir.join(path) };
                if !file.exists() {
                    problems.push(format!("{page}:{line}: link to {target}: {} does not exist", file.display()));
                    continue;
                }
                if let Some(fragment) = fragment
                    && file.extension().is_some_and(|x| x == "md")
                {
                    let text = std::fs::read_to_string(&file).unwrap_or_default();
                    if !anchors(&text).contains(fragment) {
                        problems.push(format!(
                            "{page}:{line}: link to {target}: {} has no heading with the anchor #{fragment}",
                            Path::new(path).display()
                        ));
                    }
                }
            }
        }
    }
    assert!(checked >= 20, "too few relative links found in the docs ({checked})");
    assert!(problems.is_empty(), "broken links in the docs:\n{}", problems.join("\n"));
}

/// Every source path the docs (and ARCHITECTURE.md) name exists: a file that moves takes its
/// mentions with it.
#[test]
fn every_source_file_the_docs_name_exists() {
    let mut pages = pages();
    let arch = root().join("ARCHITECTURE.md");
    pages.push(("ARCHITECTURE.md".into(), std::fs::read_to_string(&arch).expect("ARCHITECTURE.md")));
    let mut missing = Vec::new();
    let mut seen = 0;
    for (page, text) in &pages {
        for (n, line) in text.lines().enumerate() {
            let mut rest = line;
            while let Some(i) = rest.find("src/") {
                let tail = &rest[i..];
                let end = tail
                    .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == '/' || c == '.'))
                    .unwrap_or(tail.len());
                let path = tail[..end].trim_end_matches('.');
                if path.ends_with(".rs") {
                    seen += 1;
                    if !root().join(path).is_file() {
                        missing.push(format!("{page}:{}: {path}", n + 1));
                    }
                }
                rest = &tail[end..];
            }
        }
    }
    assert!(seen >= 10, "too few source paths found in the docs ({seen})");
    assert!(missing.is_empty(), "source files the docs name that do not exist:\n{}", missing.join("\n"));
}

#[test]
fn the_readme_stays_short() {
    let text = std::fs::read_to_string(root().join("README.md")).expect("README.md");
    let lines = text.lines().count();
    assert!(
        lines < README_MAX_LINES,
        "README.md has {lines} lines; keep it under {README_MAX_LINES} (move detail into docs/)"
    );
}

#[test]
fn the_parsers_of_this_test_read_what_the_docs_write() {
    assert_eq!(
        shell_words("run \"$data/r 1.parquet\" --out x > log.txt # note"),
        vec!["run", "$data/r 1.parquet", "--out", "x"]
    );
    assert_eq!(shell_words("report dir 2> err.txt"), vec!["report", "dir"]);
    assert_eq!(
        gfcal_args("cargo run --release -- run configs/quickstart.toml"),
        Some(vec!["run".into(), "configs/quickstart.toml".into()])
    );
    assert_eq!(gfcal_args("cargo test"), None);
    let (spans, _) = inline_code("see `gfcal run X\n--out D` and\n[a](b.md) `[c](d.md)`");
    assert_eq!(spans, vec![(0, "gfcal run X --out D".to_string()), (2, "[c](d.md)".to_string())]);
    assert_eq!(link_targets("see `x`\nand [a](b.md) `[c](d.md)`"), vec![(1, "b.md".to_string())]);
    assert_eq!(
        flags_of(&synopsis_words("gfcal run CONFIG [--out DIR] [--resume | --force]").unwrap()),
        vec!["--out", "--resume", "--force"]
    );
    assert_eq!(anchor("Sensitivity: SRRC and Sobol' indices"), "sensitivity-srrc-and-sobol-indices");
    assert_eq!(
        anchor("The effect library (`src/discrepancy/effect/`)".replace('`', "").as_str()),
        "the-effect-library-srcdiscrepancyeffect"
    );
    assert_eq!(
        config_paths("`configs/a.toml`, configs/arrays/*.toml, configs/...toml and configs/slurm/x.sh."),
        vec!["configs/a.toml", "configs/arrays/*.toml"]
    );
    let cmds = fenced_commands("```sh\ngfcal calibrate r.parquet \\\n    --array a.toml\n```\n");
    assert_eq!(cmds.len(), 1);
    assert_eq!(shell_words(&cmds[0].1.replacen("gfcal ", "", 1)), vec!["calibrate", "r.parquet", "--array", "a.toml"]);
}
