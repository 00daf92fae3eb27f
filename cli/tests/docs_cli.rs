//! The documents that describe the binary agree with it: docs/cli.md is what
//! `socdiff cli-reference` prints, and README's and the guide's `socdiff` commands name only
//! commands and options the binary has.

mod common;
use common::socdiff;
use std::path::Path;

fn doc(rel: &str) -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn cli_reference_is_what_the_binary_prints() {
    let (ok, printed, err) = socdiff(&["cli-reference"]);
    assert!(ok, "{err}");
    assert!(printed.contains("## `socdiff train`") && printed.contains("### `socdiff data convert`"), "every command has a section");
    if doc("docs/cli.md") != printed {
        panic!("docs/cli.md differs from the binary's help: regenerate it with `cargo run --release -p socdiff-cli -- cli-reference > docs/cli.md`");
    }
}

/// Each `socdiff …` line of a Markdown shell code block (not Python's `import socdiff`, nor
/// Rust's): the command path and its long options.
fn documented_commands(text: &str) -> Vec<(Vec<String>, Vec<String>)> {
    let mut out = Vec::new();
    let (mut in_code, mut shell) = (false, false);
    let mut joined = String::new();
    for line in text.lines() {
        if let Some(lang) = line.trim_start().strip_prefix("```") {
            in_code = !in_code;
            shell = in_code && matches!(lang.trim(), "" | "sh" | "bash" | "shell" | "console");
            continue;
        }
        if !shell || line.trim_start().starts_with('#') {
            continue;
        }
        let line = line.split(" #").next().unwrap_or("").trim_end();
        joined.push_str(line.trim_end_matches('\\'));
        joined.push(' ');
        if line.ends_with('\\') {
            continue;
        }
        let words: Vec<&str> = joined.split_whitespace().collect();
        if let Some(i) = words.iter().position(|w| *w == "socdiff" || w.ends_with("/socdiff")) {
            let rest = &words[i + 1..];
            let path: Vec<String> = rest
                .iter()
                .take_while(|w| !w.starts_with('-') && w.chars().all(|c| c.is_ascii_lowercase() || c == '-'))
                .take(2)
                .map(|w| w.to_string())
                .collect();
            let flags: Vec<String> = rest.iter().filter(|w| w.starts_with("--")).map(|w| w.split('=').next().unwrap_or(w).to_string()).collect();
            if !path.is_empty() {
                out.push((path, flags));
            }
        }
        joined.clear();
    }
    out
}

#[test]
fn documented_commands_and_options_exist() {
    let reference = doc("docs/cli.md");
    for file in ["README.md", "docs/guide.md", "docs/results.md"] {
        let commands = documented_commands(&doc(file));
        assert!(!commands.is_empty(), "{file} shows no socdiff command");
        for (path, flags) in commands {
            // The longest command path the reference has a section for.
            let section = (1..=path.len())
                .rev()
                .map(|n| format!("`socdiff {}`", path[..n].join(" ")))
                .find(|s| reference.contains(&format!("# {s}\n")))
                .unwrap_or_else(|| panic!("{file}: `socdiff {}` is no command", path.join(" ")));
            let start = reference.find(&format!("# {section}\n")).expect("section");
            let body = &reference[start..];
            let end = body[2..].find("\n#").map_or(body.len(), |e| e + 2);
            let body = &body[..end];
            for f in flags {
                assert!(
                    body.contains(&format!("{f} ")) || body.contains(&format!("{f}\n")) || body.contains(&format!("{f},")) || body.contains(&format!("{f}=")),
                    "{file}: {section} has no option {f}"
                );
            }
        }
    }
}
