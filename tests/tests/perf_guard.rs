//! The performance guard (docs/PERFORMANCE.md, "The guard"): builds the release worker as
//! `deploy/build-image.sh` does, counts the instructions of `tessera-worker render --threads 1` on
//! each of the fixed workloads of `tessera_tests::perf_guard` under Valgrind's cachegrind, and
//! fails when one does more than `TOLERANCE` above its count in `tests/perf-guard/baseline.json`.
//!
//! A test without the standard harness, so that it takes options of its own:
//!
//! ```sh
//! cargo test -p tessera-tests --test perf_guard                    # the check CI runs
//! cargo test -p tessera-tests --test perf_guard -- --update        # measure, rewrite the baseline
//! cargo test -p tessera-tests --test perf_guard -- --runs 3        # each workload 3 times: the spread
//! cargo test -p tessera-tests --test perf_guard -- --keep DIR      # keep the scenes and images in DIR
//! ```
//!
//! Without Valgrind it skips, saying so, unless `TESSERA_REQUIRE_PERF_GUARD=1` (set by `.ci/run`
//! after installing it), which makes that a failure; without the course corpus it skips or
//! fails as the corpus tests do (`TESSERA_REQUIRE_SCENES`).

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, Result, bail};
use tessera_tests::perf_guard::{self, Baseline, Entry, Verdict, WORKLOADS};

const NAME: &str = "perf_guard";

struct Options {
    update: bool,
    runs: usize,
    keep: Option<PathBuf>,
    list: bool,
    /// Whether the filters of a `cargo test ... FILTER` / `--skip` leave this test out.
    filtered_out: bool,
}

fn options() -> Result<Options> {
    let mut o = Options { update: false, runs: 1, keep: None, list: false, filtered_out: false };
    let (mut filters, mut skips, mut exact) = (Vec::new(), Vec::new(), false);
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--update" => o.update = true,
            "--runs" => {
                let n = args.next().context("--runs needs a number")?;
                o.runs = n.parse().ok().filter(|&n| n >= 1).context("--runs must be a whole number >= 1")?;
            }
            "--keep" => o.keep = Some(args.next().context("--keep needs a directory")?.into()),
            "--list" => o.list = true,
            "--exact" => exact = true,
            "--skip" => skips.push(args.next().unwrap_or_default()),
            // The standard harness's options that take a value, which cargo may pass on.
            "--test-threads" | "--color" | "--format" | "--logfile" | "-Z" => {
                args.next();
            }
            a if a.starts_with('-') => {} // --nocapture, --quiet, --include-ignored, ...: nothing to do here
            a => filters.push(a.to_string()),
        }
    }
    let matches = |f: &String| if exact { f == NAME } else { NAME.contains(f.as_str()) };
    o.filtered_out = (!filters.is_empty() && !filters.iter().any(matches))
        || skips.iter().any(|s| NAME.contains(s.as_str()));
    Ok(o)
}

fn required() -> bool {
    std::env::var_os("TESSERA_REQUIRE_PERF_GUARD").is_some_and(|v| !v.is_empty() && v != "0")
}

/// The median of each workload's counts over the runs, and the spread (max - min).
fn measure(
    worker: &std::path::Path,
    scenes: &[Vec<PathBuf>],
    dir: &std::path::Path,
    runs: usize,
) -> Result<Vec<Vec<u64>>> {
    let jobs: Vec<(usize, usize)> =
        (0..WORKLOADS.len()).flat_map(|w| (0..runs).map(move |r| (w, r))).collect();
    let results: Mutex<Vec<Vec<u64>>> = Mutex::new(vec![Vec::new(); WORKLOADS.len()]);
    let errors: Mutex<Vec<String>> = Mutex::new(Vec::new());
    let next = AtomicUsize::new(0);
    // Counts do not depend on what else runs: use the cores there are.
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).min(jobs.len());
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                while let Some(&(w, r)) = jobs.get(next.fetch_add(1, Ordering::SeqCst)) {
                    let wl = &WORKLOADS[w];
                    let run_dir = dir.join(format!("{}-run{}", wl.name, r + 1));
                    match perf_guard::count_instructions(worker, &scenes[w], wl.args, &run_dir) {
                        Ok(n) => results.lock().unwrap()[w].push(n),
                        Err(e) => errors.lock().unwrap().push(format!("{}: {e:#}", wl.name)),
                    }
                }
            });
        }
    });
    let errors = errors.into_inner().unwrap();
    if !errors.is_empty() {
        bail!("measuring failed:\n{}", errors.join("\n"));
    }
    Ok(results.into_inner().unwrap())
}

/// How the guard ended, when it could run at all.
enum Outcome {
    Passed,
    Failed,
    /// Valgrind or the corpus is missing and not required: the reason is printed.
    Skipped,
}

fn run(o: &Options) -> Result<Outcome> {
    let scenes_dir = tessera_tests::shared_scenes();
    for rel in perf_guard::CORPUS_FILES {
        if !tessera_tests::corpus_has(&scenes_dir.join(rel)) {
            return Ok(Outcome::Skipped);
        }
    }
    let Some(valgrind) = perf_guard::version_of("valgrind") else {
        let reason = "valgrind is not installed (Debian: apt-get install valgrind), so the instruction counts \
                      cannot be measured";
        if required() {
            bail!("TESSERA_REQUIRE_PERF_GUARD is set but {reason}");
        }
        eprintln!("skipped: {reason}; TESSERA_REQUIRE_PERF_GUARD=1 makes this a failure");
        return Ok(Outcome::Skipped);
    };
    let baseline_path = tessera_tests::repo_root().join(perf_guard::BASELINE);
    let baseline = if o.update {
        None
    } else {
        let text = std::fs::read_to_string(&baseline_path).with_context(|| {
            format!("reading {} (make it with `{}`)", perf_guard::BASELINE, perf_guard::UPDATE_COMMAND)
        })?;
        Some(Baseline::parse(&text).with_context(|| format!("reading {}", perf_guard::BASELINE))?)
    };

    let temp = tessera_testkit::TempDir::new("perf-guard");
    let dir = match &o.keep {
        Some(d) => {
            std::fs::create_dir_all(d)?;
            d.canonicalize()?
        }
        None => temp.path().to_path_buf(),
    };
    let mut scene_paths = Vec::new();
    for w in WORKLOADS {
        scene_paths.push(w.scene_files(&scenes_dir, &dir)?);
    }

    println!("perf guard: building the release binaries (as deploy/build-image.sh does)");
    let worker = perf_guard::build_release_worker()?;
    let rustc = perf_guard::version_of("rustc").unwrap_or_else(|| "unknown".into());
    println!(
        "perf guard: cachegrind counts the instructions of `tessera-worker render --threads 1`, whole process, \
         {} run(s) each; {valgrind}, {rustc}",
        o.runs
    );
    for (w, paths) in WORKLOADS.iter().zip(&scene_paths) {
        let more = match paths.len() {
            1 => String::new(),
            n => format!(" and {} more", n - 1),
        };
        println!("  {:<19} {} [{}{more} {}]", w.name, w.what, paths[0].display(), w.args.join(" "));
    }
    let counts = measure(&worker, &scene_paths, &dir, o.runs)?;
    let mut measured = Vec::new();
    for (w, runs) in WORKLOADS.iter().zip(counts) {
        let mut sorted = runs.clone();
        sorted.sort_unstable();
        let median = sorted[sorted.len() / 2];
        let spread = sorted[sorted.len() - 1] - sorted[0];
        if o.runs > 1 {
            println!(
                "  {:<19} runs {}: spread {} instructions ({:.5} % of the median)",
                w.name,
                runs.iter().map(|&n| perf_guard::grouped(n)).collect::<Vec<_>>().join(" "),
                perf_guard::grouped(spread),
                100.0 * spread as f64 / median as f64
            );
        }
        measured.push((w.name, median));
    }

    let Some(baseline) = baseline else {
        let (commit, date) = (perf_guard::current_commit(), perf_guard::today());
        let old = std::fs::read_to_string(&baseline_path).ok().and_then(|t| Baseline::parse(&t).ok());
        let new = Baseline {
            rustc,
            valgrind,
            cpu: tessera_testkit::cpu_description(),
            workloads: measured
                .iter()
                .map(|&(name, n)| Entry {
                    name: name.into(),
                    instructions: n,
                    commit: commit.clone(),
                    date: date.clone(),
                })
                .collect(),
        };
        for e in &new.workloads {
            match old.as_ref().and_then(|b| b.entry(&e.name)) {
                Some(was) => println!(
                    "  {:<19} {} instructions (was {}: {:+.2} %)",
                    e.name,
                    perf_guard::grouped(e.instructions),
                    perf_guard::grouped(was.instructions),
                    100.0 * (e.instructions as f64 / was.instructions as f64 - 1.0)
                ),
                None => {
                    println!("  {:<19} {} instructions (new)", e.name, perf_guard::grouped(e.instructions))
                }
            }
        }
        std::fs::write(&baseline_path, new.to_json())?;
        println!(
            "perf guard: wrote {}; commit it with a message that says why the work changed",
            perf_guard::BASELINE
        );
        return Ok(Outcome::Passed);
    };

    let mut ok = true;
    for &(name, n) in &measured {
        let Some(base) = baseline.entry(name) else {
            eprintln!(
                "FAIL {name}: not in {}: add it with `{}`",
                perf_guard::BASELINE,
                perf_guard::UPDATE_COMMAND
            );
            ok = false;
            continue;
        };
        let (verdict, message) = perf_guard::verdict_message(base, n, perf_guard::TOLERANCE);
        match verdict {
            Verdict::MoreWork => {
                eprintln!("{message}");
                ok = false;
            }
            _ => println!("{message}"),
        }
    }
    for e in &baseline.workloads {
        if !WORKLOADS.iter().any(|w| w.name == e.name) {
            eprintln!(
                "FAIL {}: in {} but no longer a workload: rewrite it with `{}`",
                e.name,
                perf_guard::BASELINE,
                perf_guard::UPDATE_COMMAND
            );
            ok = false;
        }
    }
    if !ok && baseline.rustc != rustc {
        eprintln!(
            "note: the baseline was measured with {}, this build with {rustc}: a compiler change moves the \
             counts too; if that is the cause, raise the baseline (`{}`) in the commit that changes the compiler",
            baseline.rustc,
            perf_guard::UPDATE_COMMAND
        );
    }
    Ok(if ok { Outcome::Passed } else { Outcome::Failed })
}

fn main() -> ExitCode {
    let o = match options() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    if o.list {
        if !o.filtered_out {
            println!("{NAME}: test");
        }
        return ExitCode::SUCCESS;
    }
    if o.filtered_out {
        println!("running 0 tests ({NAME} filtered out)");
        return ExitCode::SUCCESS;
    }
    println!("running 1 test: {NAME}");
    match run(&o) {
        Ok(Outcome::Passed) => {
            println!("test {NAME} ... ok");
            ExitCode::SUCCESS
        }
        Ok(Outcome::Skipped) => {
            println!("test {NAME} ... skipped (the reason is above)");
            ExitCode::SUCCESS
        }
        Ok(Outcome::Failed) => {
            eprintln!("test {NAME} ... FAILED");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("error: {e:#}\ntest {NAME} ... FAILED");
            ExitCode::FAILURE
        }
    }
}
