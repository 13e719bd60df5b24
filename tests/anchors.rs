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

/// How the Mitsuba scripts' line with their kernels' width begins (see [`with_llvm_target`]).
const WIDTH_TAG: &str = "mitsuba vector width";

/// Mitsuba script `script` with lines after its `mi.set_variant(variant)` (at that line's
/// indentation): with `avx2`, drjit's LLVM backend is told to compile for AVX2 at eight lanes,
/// the instruction set Tessera's binaries are built for (on an AVX-512 host it would use
/// sixteen); either way the script prints the width its kernels use ([`vector_width`]). The
/// functions are drjit-core's C++ entry points, by their mangled names as drjit 1.5 exports
/// them: without them the width reads "unknown" (a default run goes on) and `avx2` fails with
/// Python's error, which the bench shows.
pub fn with_llvm_target(script: &str, avx2: bool) -> Result<String> {
    let call = "mi.set_variant(variant)\n";
    let at = script.find(call).context("the script sets no variant (`mi.set_variant(variant)`)")?;
    let line_start = script[..at].rfind('\n').map_or(0, |i| i + 1);
    let indent = &script[line_start..at];
    let mut lines = String::from(
        "import ctypes\n\
         try:\n    _jit = ctypes.CDLL(dr.__path__[0] + '/libdrjit-core.so')\n\
         except OSError:\n    _jit = None\n",
    );
    if avx2 {
        lines += "_jit._Z19jit_llvm_set_targetPKcS0_j(b'haswell', \
                  b'+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+popcnt,+sse4.2,+movbe', 8)\n";
    }
    lines += &format!(
        "try:\n    _w = _jit._Z21jit_llvm_vector_widthv\n    _w.restype = ctypes.c_uint32\n    \
         print('{WIDTH_TAG}', _w(), flush=True)\n\
         except AttributeError:\n    print('{WIDTH_TAG} unknown', flush=True)\n"
    );
    let indented: String = lines.lines().map(|l| format!("{indent}{l}\n")).collect();
    let mut out = script.to_string();
    out.insert_str(at + call.len(), &indented);
    Ok(out)
}

/// The width a script made by [`with_llvm_target`] printed: its kernels' lanes per
/// instruction, or "unknown".
pub fn vector_width(text: &str) -> Option<&str> {
    text.lines().find_map(|l| l.strip_prefix(WIDTH_TAG).map(str::trim))
}

/// The three summaries of alternating rounds of throughputs (higher is faster), ours and the
/// anchor's, one line each: the best of each side, the median of each side, and the median of
/// the rounds' own ratios. The last pairs each of our renders with the anchor's run just before
/// or after it, so a slow stretch of the shared machine that lasts a round or more falls on both
/// sides of a ratio; the medians of each side do not pair.
pub fn round_summaries(ours: &[f64], theirs: &[f64], theirs_name: &str, unit: &str) -> [String; 3] {
    assert!(!ours.is_empty() && ours.len() == theirs.len(), "as many rounds of each, at least one");
    let sorted = |v: &[f64]| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        s
    };
    let (a, b) = (sorted(ours), sorted(theirs));
    let ratios = sorted(&ours.iter().zip(theirs).map(|(o, t)| o / t).collect::<Vec<_>>());
    let (best_o, best_t) = (a[a.len() - 1], b[b.len() - 1]);
    let (med_o, med_t) = (a[a.len() / 2], b[b.len() / 2]);
    [
        format!(
            "  best:   Tessera {best_o:.3}, {theirs_name} {best_t:.3} {unit}, ratio {:.3}",
            best_o / best_t
        ),
        format!("  median: Tessera {med_o:.3}, {theirs_name} {med_t:.3} {unit}, ratio {:.3}", med_o / med_t),
        format!(
            "  paired: median of the {} rounds' ratios {:.3} (lowest {:.3}, highest {:.3})",
            ratios.len(),
            ratios[ratios.len() / 2],
            ratios[0],
            ratios[ratios.len() - 1]
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_summaries_pair_each_round_and_take_middles_and_maxima() {
        // The last round ran slow on both sides; its ratio is still the others' (1.25).
        let ours = [10.0, 12.0, 5.0];
        let theirs = [8.0, 10.0, 4.0];
        let [best, median, paired] = round_summaries(&ours, &theirs, "Mitsuba", "Msamples/s");
        assert_eq!(best, "  best:   Tessera 12.000, Mitsuba 10.000 Msamples/s, ratio 1.200");
        assert_eq!(median, "  median: Tessera 10.000, Mitsuba 8.000 Msamples/s, ratio 1.250");
        assert_eq!(paired, "  paired: median of the 3 rounds' ratios 1.250 (lowest 1.200, highest 1.250)");
        let [_, _, even] = round_summaries(&[1.0, 3.0], &[2.0, 2.0], "Embree", "Mrays/s");
        assert!(even.contains("ratios 1.500 (lowest 0.500, highest 1.500)"), "{even}");
    }

    #[test]
    fn figures_are_read_from_the_last_line_and_json_lines() {
        assert_eq!(last_figure("render 1.9 s wall\n2.225 1.885").unwrap(), 2.225);
        assert!(last_figure("no numbers here").is_err());
        let text = "compiling\n{\"tris\": 5, \"embree_mrays_s\": 13.92}\n";
        assert_eq!(json_number(text, "embree_mrays_s").unwrap(), 13.92);
        assert!(json_number(text, "hit").is_err());
        assert!(json_number("nothing", "hit").is_err());
    }

    #[test]
    fn the_llvm_target_lines_follow_the_variant_at_its_indentation() {
        let script = "import drjit as dr\ndef main():\n    mi.set_variant(variant)\n    go()\n";
        let out = with_llvm_target(script, true).unwrap();
        let after: Vec<&str> = out.lines().skip_while(|l| !l.contains("set_variant")).skip(1).collect();
        assert_eq!(after[0], "    import ctypes");
        assert!(after.iter().any(|l| l.starts_with("    _jit._Z19jit_llvm_set_target")), "{out}");
        assert_eq!(after.last(), Some(&"    go()"));
        // Every inserted line keeps the function's indentation or more.
        assert!(after.iter().all(|l| l.starts_with("    ")), "{out}");
        let plain = with_llvm_target(script, false).unwrap();
        assert!(!plain.contains("jit_llvm_set_target") && plain.contains("jit_llvm_vector_width"));
        assert!(with_llvm_target("print(1)\n", false).is_err());
        assert_eq!(vector_width("x\nmitsuba vector width 8\n1.0 2.0"), Some("8"));
        assert_eq!(vector_width("1.0 2.0"), None);
    }
}
