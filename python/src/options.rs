//! Keyword options parsed by the CLI's own option types (clap), so that a Python keyword means
//! exactly what the flag of the same name means: `hidden=32` is `--hidden 32`.

use clap::{Args, Command, FromArgMatches};
use pyo3::exceptions::PyValueError;
use pyo3::PyResult;

/// Parses `args` (`["--hidden", "32", …]`, built by the Python package from keywords) as `T`.
/// Errors name the keyword, not the flag.
pub fn parse<T: Args + FromArgMatches>(call: &'static str, args: &[String]) -> PyResult<T> {
    let cmd = T::augment_args(Command::new(call).no_binary_name(true).disable_help_flag(true).disable_version_flag(true));
    let known: Vec<String> = cmd.get_arguments().filter_map(|a| a.get_long()).map(keyword).collect();
    let matches = cmd.try_get_matches_from(args).map_err(|e| {
        let msg = match e.kind() {
            clap::error::ErrorKind::UnknownArgument => {
                let given = e.get(clap::error::ContextKind::InvalidArg).map(|v| keyword(v.to_string().trim_start_matches('-'))).unwrap_or_default();
                format!("{call}: unknown option `{given}` (options: {})", known.join(", "))
            }
            _ => {
                let first = e.render().to_string().lines().next().unwrap_or_default().trim_start_matches("error: ").to_string();
                format!("{call}: {}", keywords_in(&first))
            }
        };
        PyValueError::new_err(msg)
    })?;
    T::from_arg_matches(&matches).map_err(|e| PyValueError::new_err(format!("{call}: {e}")))
}

/// A flag's long name as a Python keyword (`save-every` → `save_every`).
fn keyword(flag: &str) -> String {
    flag.replace('-', "_")
}

/// `'--save-every <N>'` in a clap message → `` `save_every` ``.
fn keywords_in(msg: &str) -> String {
    let mut out = String::new();
    let mut rest = msg;
    while let Some(i) = rest.find("'--") {
        out.push_str(&rest[..i]);
        let tail = &rest[i + 3..];
        let end = tail.find('\'').unwrap_or(tail.len());
        let name = tail[..end].split_whitespace().next().unwrap_or_default();
        out.push_str(&format!("`{}`", keyword(name)));
        rest = tail.get(end + 1..).unwrap_or_default();
    }
    out.push_str(rest);
    out
}
