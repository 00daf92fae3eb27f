//! `socdiff cli-reference`: every command's `--help` as one Markdown page (docs/cli.md), made
//! from the same clap definitions the binary parses with, so the page cannot drift from the
//! binary (a test compares them).

use clap::CommandFactory;

/// The CLI reference in Markdown: one section per command, its long help verbatim.
pub fn markdown() -> String {
    let mut cmd = crate::Cli::command();
    cmd.build();
    let mut out = String::from(
        "# CLI reference\n\n\
         Every command's `--help`, as the binary prints it. This page is generated: \
         `socdiff cli-reference > docs/cli.md` (a test fails when it differs from the binary).\n",
    );
    section(&mut cmd, "socdiff", &mut out);
    out
}

/// Appends `cmd`'s help (named `path`) and its subcommands', depth first, hidden ones left out.
fn section(cmd: &mut clap::Command, path: &str, out: &mut String) {
    let level = if path.contains(' ') { "###" } else { "##" };
    let help = cmd.render_long_help().to_string();
    out.push_str(&format!("\n{level} `{path}`\n\n```text\n{}\n```\n", help.trim_end()));
    for sub in cmd.get_subcommands_mut() {
        if sub.is_hide_set() || sub.get_name() == "help" {
            continue;
        }
        let name = format!("{path} {}", sub.get_name());
        section(sub, &name, out);
    }
}
