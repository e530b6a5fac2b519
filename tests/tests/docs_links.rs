//! The documentation points at things that exist: every relative Markdown link, and every
//! file path of the repository written in backticks (e.g. `core/src/wire.rs`), in every `.md`
//! file of the workspace.

use std::path::{Path, PathBuf};

/// Top-level folders whose files the docs name.
const TOP: [&str; 12] = [
    "core",
    "server",
    "cpu-tracer",
    "gpu-tracer",
    "client-minifb",
    "eval",
    "tests",
    "docs",
    "scripts",
    "tools",
    "data",
    "fuzz",
];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn markdown_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        let name = e.file_name().to_string_lossy().to_string();
        if p.is_dir() {
            if !(name.starts_with('.') || name == "target" || name == "corpus" || name == "artifacts" || name == "out")
            {
                markdown_files(&p, out);
            }
        } else if name.ends_with(".md") {
            out.push(p);
        }
    }
}

/// Relative link targets of `[text](target)`.
fn links(text: &str) -> Vec<String> {
    let mut v = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        rest = &rest[i + 2..];
        let Some(end) = rest.find(')') else { break };
        let t = rest[..end].split_whitespace().next().unwrap_or("").to_string();
        if !(t.is_empty() || t.contains("://") || t.starts_with('#') || t.starts_with("mailto:")) {
            v.push(t.split('#').next().unwrap().to_string());
        }
    }
    v
}

/// Repository file paths written in backticks: `top/…/name.ext` with a known top folder.
fn code_paths(text: &str) -> Vec<String> {
    text.split('`')
        .skip(1)
        .step_by(2)
        .filter(|s| {
            let first = s.split('/').next().unwrap_or("");
            TOP.contains(&first)
                && s.contains('/')
                && !s.contains(|c: char| c.is_whitespace() || "*{}<>$|:?".contains(c))
                && s.rsplit('/').next().is_some_and(|f| f.contains('.') && !f.starts_with('.'))
        })
        .map(str::to_string)
        .collect()
}

#[test]
fn every_link_and_named_file_exists() {
    let root = root();
    let mut files = Vec::new();
    markdown_files(&root, &mut files);
    assert!(files.len() > 10, "found only {} markdown files", files.len());
    let mut missing = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let dir = f.parent().unwrap();
        for l in links(&text) {
            if !dir.join(&l).exists() {
                missing.push(format!("{}: link {l}", f.strip_prefix(&root).unwrap().display()));
            }
        }
        for p in code_paths(&text) {
            if !root.join(&p).exists() {
                missing.push(format!("{}: path `{p}`", f.strip_prefix(&root).unwrap().display()));
            }
        }
    }
    assert!(missing.is_empty(), "the docs name things that do not exist:\n{}", missing.join("\n"));
}

#[test]
fn the_checker_finds_links_and_paths() {
    assert_eq!(links("see [a](docs/x.md#top) and [b](https://e.org) [c](#here)"), ["docs/x.md"]);
    assert_eq!(code_paths("`core/src/wire.rs`, `cargo test`, `out/demo/`, `eval/*.csv`"), ["core/src/wire.rs"]);
}
