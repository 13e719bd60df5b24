//! Running the speed anchors' Python scripts (`../shared/bench/README.md`) from the benches.

use std::path::Path;
use std::process::Command;

use anyhow::{Context, Result, bail};

/// Runs anchor script `script` with `args` under [`crate::anchor_python`]; its standard output.
/// A failure's error ends with the script's last lines of errors, which say why (a missing
/// package, libLLVM, a drjit entry point).
pub fn run(script: &Path, args: &[String]) -> Result<String> {
    let python = crate::anchor_python();
    let o = Command::new(&python)
        .arg(script)
        .args(args)
        .output()
        .with_context(|| format!("running {} with {}", script.display(), python.display()))?;
    if !o.status.success() {
        let err = String::from_utf8_lossy(&o.stderr);
        let lines: Vec<&str> = err.lines().collect();
        bail!(
            "{} failed ({}):\n{}",
            script.display(),
            o.status,
            lines[lines.len().saturating_sub(12)..].join("\n")
        );
    }
    Ok(String::from_utf8_lossy(&o.stdout).into_owned())
}

/// The figure the Mitsuba scripts print first on their last line (Msamples/s).
pub fn last_figure(text: &str) -> Result<f64> {
    text.lines()
        .last()
        .and_then(|l| l.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .with_context(|| format!("Mitsuba printed no figure: {text}"))
}

/// Number `key` of the last JSON line an anchor printed.
pub fn json_number(text: &str, key: &str) -> Result<f64> {
    let line = text
        .lines()
        .rev()
        .find(|l| l.trim_start().starts_with('{'))
        .with_context(|| format!("no JSON line in: {text}"))?;
    let v: serde_json::Value = serde_json::from_str(line)?;
    v[key].as_f64().with_context(|| format!("no {key} in {line}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_are_read_from_the_last_line_and_json_lines() {
        assert_eq!(last_figure("render 1.9 s wall\n2.225 1.885").unwrap(), 2.225);
        assert!(last_figure("no numbers here").is_err());
        let text = "compiling\n{\"tris\": 5, \"embree_mrays_s\": 13.92}\n";
        assert_eq!(json_number(text, "embree_mrays_s").unwrap(), 13.92);
        assert!(json_number(text, "hit").is_err());
        assert!(json_number("nothing", "hit").is_err());
    }
}
