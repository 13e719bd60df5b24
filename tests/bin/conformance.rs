//! `conformance`: renders course scenes and compares them with the official reference images.
//!
//! Usage: cargo run --release -p tessera-tests --bin conformance -- [--ci] [--scene NAME]...
//! [--image NAME]... [--spp N] [--rule dielectric=flag|face] [--rule path-depth=diffuse|glass-once|every]
//! [--report FILE]
//!
//! Reads the table in tests/conformance/thresholds.tsv, renders each listed image with every
//! core, writes the renders and a Markdown report (default target/conformance/report.md) and
//! exits non-zero if any row misses its thresholds. `--spp` renders every chosen row at that
//! many samples (a quicker, noisier check); `--rule` sets a shading rule other than the default
//! (`tessera::scene::ShadingRules`), to measure it.

use std::path::PathBuf;
use std::process::ExitCode;

use tessera::scene::{DielectricSides, PathDepth, ShadingRules};
use tessera_tests::conformance::{Row, load_table, render_rows_with, report_markdown};

fn main() -> ExitCode {
    let mut ci_only = false;
    let mut only: Vec<String> = Vec::new();
    let mut images: Vec<String> = Vec::new();
    let mut spp: Option<u32> = None;
    let mut rules = ShadingRules::default();
    let mut report = tessera_tests::repo_root().join("target/conformance/report.md");
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--ci" => ci_only = true,
            "--scene" => only.extend(args.next()),
            "--image" => images.extend(args.next()),
            "--spp" => match args.next().and_then(|n| n.parse().ok()).filter(|&n| n > 0) {
                Some(n) => spp = Some(n),
                None => {
                    eprintln!("--spp takes a positive integer");
                    return ExitCode::from(2);
                }
            },
            "--rule" => match args.next().as_deref() {
                Some("dielectric=flag") => rules.dielectric_sides = DielectricSides::Flag,
                Some("dielectric=face") => rules.dielectric_sides = DielectricSides::FaceSide,
                Some("path-depth=diffuse") => rules.path_depth = PathDepth::DiffuseBounces,
                Some("path-depth=every") => rules.path_depth = PathDepth::EveryBounce,
                Some("path-depth=glass-once") => rules.path_depth = PathDepth::GlassOnce,
                other => {
                    eprintln!("unknown rule {other:?}; see --help");
                    return ExitCode::from(2);
                }
            },
            "--report" => report = args.next().map(PathBuf::from).unwrap_or(report),
            "-h" | "--help" => {
                println!(
                    "usage: conformance [--ci] [--scene NAME]... [--image NAME]... [--spp N] \
                     [--rule dielectric=flag|face] [--rule path-depth=diffuse|glass-once|every] [--report FILE]"
                );
                println!(
                    "Renders the scenes of tests/conformance/thresholds.tsv and compares them with ../shared/scenes/reference."
                );
                return ExitCode::SUCCESS;
            }
            other => {
                eprintln!("unknown argument {other}; see --help");
                return ExitCode::from(2);
            }
        }
    }
    let table = match load_table() {
        Ok(t) => t,
        Err(e) => {
            eprintln!("error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    let rows: Vec<Row> = table
        .into_iter()
        .filter(|r| (!ci_only || r.ci) && (only.is_empty() || only.contains(&r.scene)))
        .filter(|r| images.is_empty() || images.contains(&r.image))
        .map(|r| Row { spp: spp.or(r.spp), ..r })
        .collect();
    let out_dir = report.parent().map(PathBuf::from).unwrap_or_default();
    let results = render_rows_with(&rows, &out_dir, rules, &|line| eprintln!("{line}"));
    let md = report_markdown(&results);
    if let Err(e) = std::fs::create_dir_all(&out_dir).and_then(|_| std::fs::write(&report, &md)) {
        eprintln!("error: cannot write {}: {e}", report.display());
        return ExitCode::FAILURE;
    }
    println!("{md}");
    println!("report written to {}", report.display());
    if results.iter().all(|r| r.passed()) { ExitCode::SUCCESS } else { ExitCode::FAILURE }
}
