//! Errors the user can fix (exit 2), their messages, and the refusal to write over an input.

use std::path::Path;

use gfcal::config::ConfigError;

/// An error the user can fix by changing the input: exit code 2.
#[derive(Debug, thiserror::Error)]
pub(crate) enum InputError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("{0}")]
    Other(String),
}

/// Refuses a command whose output would replace one of its inputs (`gfcal inject` with `--out` the
/// recording it reads would destroy the recording), or whose two outputs are one file.
pub(crate) fn refuse_overwriting(
    inputs: &[(&str, &Path)],
    outputs: &[(&str, Option<&Path>)],
) -> Result<(), InputError> {
    let outputs: Vec<(&str, &Path)> = outputs.iter().filter_map(|(flag, p)| p.map(|p| (*flag, p))).collect();
    for (flag, out) in &outputs {
        if let Some((what, input)) = inputs.iter().find(|(_, input)| gfcal::io::same_file(out, input)) {
            return Err(InputError::Other(format!(
                "{flag}: {} is the {what} {}, which gfcal reads; it never writes over its input: give another file",
                out.display(),
                input.display()
            )));
        }
    }
    for (i, (flag, out)) in outputs.iter().enumerate() {
        let same = |(_, other): &&(&str, &Path)| other == out || gfcal::io::same_file(out, other);
        if let Some((other_flag, _)) = outputs[i + 1..].iter().find(same) {
            return Err(InputError::Other(format!(
                "{flag} and {other_flag}: both name {}; give each its own file",
                out.display()
            )));
        }
    }
    Ok(())
}

/// The error and its causes, each said once: a cause whose text the message already holds
/// (an error that prints its source, then the source itself) is left out.
pub(crate) fn message(e: &anyhow::Error) -> String {
    let mut out = e.to_string();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        let plain = text.split(" (os error").next().unwrap_or(&text).to_string();
        if !out.contains(&plain) {
            out.push_str(": ");
            out.push_str(&text);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    /// Issue 13: "Read-only file system (os error 30): Read-only file system" said the cause twice.
    #[test]
    fn an_error_says_each_cause_once() {
        let io = std::io::Error::from_raw_os_error(30);
        let text = io.to_string();
        let e = anyhow::Error::new(io).context(format!("cannot write out.csv: {text}"));
        let m = super::message(&e);
        assert_eq!(m.matches("Read-only file system").count(), 1, "{m}");
        let e = anyhow::Error::new(std::io::Error::from_raw_os_error(2)).context("cannot write out.csv");
        assert_eq!(super::message(&e), "cannot write out.csv: No such file or directory (os error 2)");
    }
}
