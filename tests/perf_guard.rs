//! The performance guard: how much work the release `tessera-worker render` does on small fixed
//! workloads, counted in instructions (Valgrind's cachegrind, one render thread), against the
//! committed baseline `tests/perf-guard/baseline.json`. Instruction counts do not depend on the
//! machine's load, so the guard can fail on a few per cent where timings on shared cores cannot
//! tell 10 % from noise. The test that runs it is `tests/tests/perf_guard.rs`; what it measures,
//! the tolerance and how to raise the baseline are in docs/PERFORMANCE.md ("The guard").
//!
//! The workloads are derived, when the guard runs, from the course's scenes in
//! `../shared/scenes` (made smaller by exact text edits that must each match, so a changed corpus
//! file fails loudly instead of silently measuring something else), or from a template in
//! `tests/perf-guard/` that points at the corpus's assets.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::{Context, Result, bail, ensure};
use serde_json::Value;

/// How much more work than its baseline a workload may do before the guard fails (1 %), and how
/// much less before it suggests lowering the baseline. It is not there for noise: counts repeat
/// to within 0.02 % from run to run (at most some 40 thousand instructions in 220 million, usually
/// a few thousand: the idle render thread's polling). It leaves room for what moves counts
/// without a change to the renderer and that [`PINNED_LIBC`] does not pin (the CPU-dependent
/// string functions glibc still picks moved `head_env_direct` by 0.24 %), and it still catches
/// little: three extra vector instructions in the triangle test are +1.3 % on `head_primary`.
/// Another compiler, glibc or Valgrind can move counts by more: that is a deliberate raise of the
/// baseline. Each commit is compared with the committed baseline, not with its parent, so small
/// losses add up against it and fail once together they pass 1 %.
pub const TOLERANCE: f64 = 0.01;

/// The C library's choices that depend on the host CPU, fixed for the measured process
/// (`GLIBC_TUNABLES`). With ERMS (or FSRM), glibc copies and clears large buffers with `rep movsb`
/// / `rep stosb`, which Valgrind counts once per byte: on a host with ERMS that is 2 % of
/// `head_env_direct`'s count, on one without it nothing. Turned off, every x86-64 host runs the
/// same vector loops; the non-temporal threshold, which glibc derives from the L3 size, is fixed
/// too (it moves counts by about 0.002 %), and RTM (TSX) variants are not chosen.
pub const PINNED_LIBC: &str =
    "glibc.cpu.hwcaps=-ERMS,-FSRM,-RTM:glibc.cpu.x86_non_temporal_threshold=0xc0000";

/// The baseline file, relative to the repository root.
pub const BASELINE: &str = "tests/perf-guard/baseline.json";

/// The command that measures every workload and rewrites the baseline file.
pub const UPDATE_COMMAND: &str = "cargo test -p tessera-tests --test perf_guard -- --update";

/// The longest one workload may run under Valgrind (a few seconds normally): a hang fails by name.
pub const RUN_LIMIT: Duration = Duration::from_secs(600);

/// One fixed workload: the scene files one `render` process is given and the options that go
/// with them.
pub struct Workload {
    pub name: &'static str,
    /// What it exercises, for the guard's table and the docs.
    pub what: &'static str,
    /// Options of `tessera-worker render` besides the scenes, `--out`, `--threads 1`, `--quiet`.
    pub args: &'static [&'static str],
    input: Input,
}

/// Where a workload's scene files come from.
enum Input {
    /// One scene file made from the corpus at the given path (its text).
    Scene(fn(&Path) -> Result<String>),
    /// Frames of a corpus sequence, as they are: the directory under `../shared/scenes` and the
    /// files, in the order the process renders them.
    Frames { dir: &'static str, files: &'static [&'static str] },
}

impl Workload {
    /// The scene files of the workload in render order: a made scene written into `dir` as
    /// `NAME.xml`, or the sequence's frames in the corpus `scenes` (`../shared/scenes`).
    pub fn scene_files(&self, scenes: &Path, dir: &Path) -> Result<Vec<PathBuf>> {
        let made = || -> Result<Vec<PathBuf>> {
            match &self.input {
                Input::Scene(text) => {
                    let path = dir.join(format!("{}.xml", self.name));
                    std::fs::write(&path, text(scenes)?)?;
                    Ok(vec![path])
                }
                Input::Frames { dir: seq, files } => files
                    .iter()
                    .map(|f| {
                        let path = scenes.join(seq).join(f);
                        ensure!(path.is_file(), "{} is missing", path.display());
                        Ok(path)
                    })
                    .collect(),
            }
        };
        made().with_context(|| format!("making the scenes of workload {}", self.name))
    }
}

/// The workloads, in the order the guard runs and reports them.
pub const WORKLOADS: &[Workload] = &[
    Workload {
        name: "head_env_direct",
        what: "head_env_light (head.ply, 17,674 triangles, no texture) lit by hdri/park.exr, \
               importance-sampled environment, direct lighting, 200x112, 16 spp",
        args: &["--samples", "16", "--env-sampling", "importance"],
        input: Input::Scene(head_env_direct),
    },
    Workload {
        name: "jaroslav_path_nee",
        what: "cornellbox_jaroslav_path_diffuse camera 3 (path tracing, next-event estimation, cosine \
               importance sampling, depth 3), 128x128, 8 spp",
        args: &["--camera", "3", "--samples", "8"],
        input: Input::Scene(jaroslav_path_nee),
    },
    Workload {
        name: "head_primary",
        what: "primary rays only at head.ply (tests/perf-guard/head_primary.xml), 640x360, 1 spp",
        args: &[],
        input: Input::Scene(head_primary),
    },
    Workload {
        name: "cornellbox_area",
        what: "cornellbox_area (the classic tracer: an area light, a mirror and a glossy sphere), 200x200, 4 spp",
        args: &["--samples", "4"],
        input: Input::Scene(cornellbox_area),
    },
    Workload {
        name: "david_cached_frames",
        what: "frames 0-7 of the camera_around_david sequence in one process, 80x80: the first builds \
               the two statues' meshes and world tree, the seven after take them from the caches",
        args: &["--scale", "0.1"],
        input: Input::Frames { dir: "sequences/camera_around_david", files: DAVID_FRAMES },
    },
];

/// The frames of [`WORKLOADS`]' sequence workload, in `sequences/camera_around_david`.
const DAVID_FRAMES: &[&str] = &[
    "davids_camera_000.json",
    "davids_camera_001.json",
    "davids_camera_002.json",
    "davids_camera_003.json",
    "davids_camera_004.json",
    "davids_camera_005.json",
    "davids_camera_006.json",
    "davids_camera_007.json",
];

/// The corpus files the workloads read, relative to `../shared/scenes`.
pub const CORPUS_FILES: &[&str] = &[
    "xml/head_env_light.xml",
    "xml/ply/head.ply",
    "hdri/park.exr",
    "xml/cornellbox_jaroslav_path_diffuse.xml",
    "xml/cornellbox_area.xml",
    "sequences/camera_around_david/davids_camera_000.json",
    "sequences/camera_around_david/david_ply/mesh_3.ply",
    "sequences/camera_around_david/david_ply/mesh_4.ply",
];

/// `text` with each of the `count` occurrences of `from` replaced by `to`; an error when `from`
/// occurs another number of times (the corpus file is not the one the workload was made from).
fn replace_exactly(text: &str, from: &str, to: &str, count: usize) -> Result<String> {
    let found = text.matches(from).count();
    ensure!(found == count, "expected {count} occurrence(s) of `{from}`, found {found}");
    Ok(text.replace(from, to))
}

/// `text` without the one block from `start` to the end of `end` (and the rest of its line).
fn remove_block(text: &str, start: &str, end: &str) -> Result<String> {
    ensure!(text.matches(start).count() == 1, "expected one `{start}`");
    let a = text.find(start).expect("counted above");
    let b = a + text[a..].find(end).with_context(|| format!("no `{end}` after `{start}`"))? + end.len();
    let a = text[..a].rfind('\n').map_or(0, |i| i + 1);
    let b = text[b..].find('\n').map_or(text.len(), |i| b + i + 1);
    Ok(format!("{}{}", &text[..a], &text[b..]))
}

fn read(scenes: &Path, rel: &str) -> Result<String> {
    let path = scenes.join(rel);
    std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))
}

fn asset(scenes: &Path, rel: &str) -> Result<String> {
    let path = scenes.join(rel);
    let path = path.canonicalize().with_context(|| format!("{} is missing", path.display()))?;
    Ok(path.display().to_string())
}

/// The course's head_env_light as `../shared/bench/head_env_park.xml` makes it: the missing
/// Pisa map replaced by `hdri/park.exr`, the missing albedo texture dropped; then 200x112.
fn head_env_direct(scenes: &Path) -> Result<String> {
    let rel = "xml/head_env_light.xml";
    let text = read(scenes, rel)?;
    let edit = |text: &str| -> Result<String> {
        let t = replace_exactly(
            text,
            "<ImageResolution>800 450</ImageResolution>",
            "<ImageResolution>200 112</ImageResolution>",
            1,
        )?;
        let t = replace_exactly(&t, "textures/pisa_latlong.exr", &asset(scenes, "hdri/park.exr")?, 1)?;
        let t = replace_exactly(
            &t,
            "plyFile=\"ply/head.ply\"",
            &format!("plyFile=\"{}\"", asset(scenes, "xml/ply/head.ply")?),
            1,
        )?;
        let t = remove_block(&t, "<Image id=\"1\">textures/head_albedomap_flip.png", "</Image>")?;
        let t = remove_block(&t, "<TextureMap id=\"1\"", "</TextureMap>")?;
        remove_block(&t, "<Textures>1</Textures>", "</Textures>")
    };
    edit(&text).with_context(|| format!("editing {rel}"))
}

/// The course's cornellbox_jaroslav_path_diffuse at 128x128 (camera 3 is rendered: its
/// renderer parameters are checked here).
fn jaroslav_path_nee(scenes: &Path) -> Result<String> {
    let rel = "xml/cornellbox_jaroslav_path_diffuse.xml";
    let text = read(scenes, rel)?;
    let edit = |text: &str| -> Result<String> {
        let cameras: Vec<&str> = text.split("<Camera id=").skip(1).collect();
        ensure!(cameras.len() == 8, "expected 8 cameras, found {}", cameras.len());
        ensure!(
            cameras[2].contains("<RendererParams>NextEventEstimation ImportanceSampling</RendererParams>"),
            "camera 3 is not the NextEventEstimation ImportanceSampling camera"
        );
        replace_exactly(
            text,
            "<ImageResolution>512 512</ImageResolution>",
            "<ImageResolution>128 128</ImageResolution>",
            8,
        )
    };
    edit(&text).with_context(|| format!("editing {rel}"))
}

/// `tests/perf-guard/head_primary.xml` (`../shared/bench/head_primary.xml`'s camera) at 640x360.
fn head_primary(scenes: &Path) -> Result<String> {
    let text = include_str!("perf-guard/head_primary.xml");
    replace_exactly(text, "HEAD_PLY", &asset(scenes, "xml/ply/head.ply")?, 1)
}

/// The course's cornellbox_area at 200x200.
fn cornellbox_area(scenes: &Path) -> Result<String> {
    let rel = "xml/cornellbox_area.xml";
    replace_exactly(
        &read(scenes, rel)?,
        "<ImageResolution>800 800</ImageResolution>",
        "<ImageResolution>200 200</ImageResolution>",
        1,
    )
    .with_context(|| format!("editing {rel}"))
}

pub use tessera_testkit::without_test_env;

/// Where `cargo build --release` puts the binaries.
pub fn release_dir() -> PathBuf {
    let repo = crate::repo_root();
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(dir) if !dir.is_empty() => repo.join(dir).join("release"),
        _ => repo.join("target/release"),
    }
}

/// Builds the release binaries exactly as `deploy/build-image.sh` does (so that in CI the
/// container test and the guard share one build) and returns the worker's path.
pub fn build_release_worker() -> Result<PathBuf> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args([
        "build",
        "--release",
        "--locked",
        "-p",
        "tessera-server",
        "-p",
        "tessera-worker",
        "-p",
        "tessera-client",
    ]);
    cmd.current_dir(crate::repo_root()).stdin(Stdio::null());
    without_test_env(&mut cmd);
    let status = cmd.status().context("running cargo build --release")?;
    ensure!(status.success(), "cargo build --release failed ({status})");
    let worker = release_dir().join("tessera-worker");
    ensure!(worker.is_file(), "{} is missing after cargo build --release", worker.display());
    Ok(worker)
}

/// The first line of `program --version`, or None when it cannot run.
pub fn version_of(program: &str) -> Option<String> {
    let out = Command::new(program).arg("--version").stdin(Stdio::null()).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).lines().next().unwrap_or("").trim().to_string())
}

/// The instructions one `tessera-worker render` process of `scenes` executes (every thread,
/// start-up, scene loads, BVH builds, renders and image writing), counted by cachegrind without
/// its cache simulation, with the C library's CPU-dependent choices pinned ([`PINNED_LIBC`]).
/// `dir` receives the images and Valgrind's files.
pub fn count_instructions(worker: &Path, scenes: &[PathBuf], args: &[&str], dir: &Path) -> Result<u64> {
    std::fs::create_dir_all(dir)?;
    let counts = dir.join("cachegrind.out");
    let log = dir.join("valgrind.log");
    let mut cmd = Command::new("valgrind");
    cmd.arg("--tool=cachegrind")
        .arg("--cache-sim=no")
        .arg(format!("--cachegrind-out-file={}", counts.display()))
        .arg(worker)
        .arg("render")
        .args(scenes)
        .arg("--out")
        .arg(dir.join("out"))
        .args(["--threads", "1", "--quiet"])
        .args(args)
        .env("GLIBC_TUNABLES", PINNED_LIBC)
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(dir.join("stdout.log"))?)
        .stderr(std::fs::File::create(&log)?);
    let mut child = cmd.spawn().context("starting valgrind")?;
    let Some(status) = tessera_testkit::wait_timeout(&mut child, RUN_LIMIT) else {
        let _ = child.kill();
        let _ = child.wait();
        bail!("still running after {} s under valgrind: stopped", RUN_LIMIT.as_secs());
    };
    let stderr = std::fs::read_to_string(&log).unwrap_or_default();
    ensure!(status.success(), "valgrind tessera-worker render failed ({status}):\n{stderr}");
    let text = std::fs::read_to_string(&counts).with_context(|| format!("reading {}", counts.display()))?;
    parse_cachegrind_summary(&text).with_context(|| format!("no instruction count in {}", counts.display()))
}

/// The instruction count of a cachegrind output file: its `summary:` line's first figure (with
/// `--cache-sim=no` the only event is `Ir`).
pub fn parse_cachegrind_summary(text: &str) -> Option<u64> {
    let events = text.lines().find_map(|l| l.strip_prefix("events:"))?;
    let ir = events.split_whitespace().position(|e| e == "Ir")?;
    let summary = text.lines().find_map(|l| l.strip_prefix("summary:"))?;
    summary.split_whitespace().nth(ir)?.parse().ok()
}

/// The baseline file's first field.
const ABOUT: &str = "Instruction counts of the perf guard's workloads (tests/perf_guard.rs; docs/PERFORMANCE.md, \
                     \"The guard\"). Rewritten by `cargo test -p tessera-tests --test perf_guard -- --update`; \
                     commit a change to it saying why the work changed.";

/// One workload's line in the baseline.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub name: String,
    pub instructions: u64,
    /// The commit it was measured on (`git describe --always --dirty`).
    pub commit: String,
    /// The day it was measured on (UTC, `YYYY-MM-DD`).
    pub date: String,
}

/// The baseline file: each workload's count and what it was measured with.
#[derive(Clone, Debug, PartialEq)]
pub struct Baseline {
    pub rustc: String,
    pub valgrind: String,
    pub cpu: String,
    pub workloads: Vec<Entry>,
}

impl Baseline {
    pub fn parse(text: &str) -> Result<Baseline> {
        let v: Value = serde_json::from_str(text)?;
        let s = |v: &Value, k: &str| -> Result<String> {
            Ok(v.get(k)
                .and_then(Value::as_str)
                .with_context(|| format!("`{k}` missing or not a string"))?
                .to_string())
        };
        let measured = v.get("measured_with").context("`measured_with` missing")?;
        let mut workloads = Vec::new();
        for w in v.get("workloads").and_then(Value::as_array).context("`workloads` missing or not a list")? {
            workloads.push(Entry {
                name: s(w, "name")?,
                instructions: w
                    .get("instructions")
                    .and_then(Value::as_u64)
                    .context("`instructions` missing or not a whole number")?,
                commit: s(w, "commit")?,
                date: s(w, "date")?,
            });
        }
        Ok(Baseline {
            rustc: s(measured, "rustc")?,
            valgrind: s(measured, "valgrind")?,
            cpu: s(measured, "cpu")?,
            workloads,
        })
    }

    /// The file's text: pretty JSON with each workload on one line, its name first.
    pub fn to_json(&self) -> String {
        let q = |s: &str| Value::from(s).to_string();
        let workloads: Vec<String> = self
            .workloads
            .iter()
            .map(|e| {
                format!(
                    "    {{\"name\": {}, \"instructions\": {}, \"commit\": {}, \"date\": {}}}",
                    q(&e.name),
                    e.instructions,
                    q(&e.commit),
                    q(&e.date)
                )
            })
            .collect();
        format!(
            "{{\n  \"about\": {},\n  \"measured_with\": {{\"rustc\": {}, \"valgrind\": {}, \"cpu\": {}}},\n  \"workloads\": [\n{}\n  ]\n}}\n",
            q(ABOUT),
            q(&self.rustc),
            q(&self.valgrind),
            q(&self.cpu),
            workloads.join(",\n")
        )
    }

    pub fn entry(&self, name: &str) -> Option<&Entry> {
        self.workloads.iter().find(|e| e.name == name)
    }
}

/// How a measured count stands against its baseline.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Within the tolerance either way.
    Within,
    /// More than the tolerance above the baseline: the guard fails.
    MoreWork,
    /// More than the tolerance below: the baseline should be lowered (not a failure).
    LessWork,
}

/// The comparison the guard makes: `measured` against `baseline` at `tolerance` (0.02 = 2 %).
pub fn judge(baseline: u64, measured: u64, tolerance: f64) -> Verdict {
    let ratio = measured as f64 / baseline.max(1) as f64;
    if ratio > 1.0 + tolerance {
        Verdict::MoreWork
    } else if ratio < 1.0 - tolerance {
        Verdict::LessWork
    } else {
        Verdict::Within
    }
}

/// `n` with thousands separators.
pub fn grouped(n: u64) -> String {
    if n < 1000 { n.to_string() } else { format!("{},{:03}", grouped(n / 1000), n % 1000) }
}

/// The verdict on one workload and the message that says it.
pub fn verdict_message(base: &Entry, measured: u64, tolerance: f64) -> (Verdict, String) {
    let verdict = judge(base.instructions, measured, tolerance);
    let ratio = measured as f64 / base.instructions.max(1) as f64;
    let figures = format!(
        "{}: measured {} instructions, baseline {} (measured at {} on {}), ratio {ratio:.4} ({:+.2} %), tolerance ±{:.1} %",
        base.name,
        grouped(measured),
        grouped(base.instructions),
        base.commit,
        base.date,
        (ratio - 1.0) * 100.0,
        tolerance * 100.0
    );
    let message = match verdict {
        Verdict::Within => format!("ok   {figures}"),
        Verdict::MoreWork => format!(
            "FAIL {figures}\n     The renderer now does measurably more work on this workload. Find the change that \
             added it: the workloads are defined in tests/perf_guard.rs; `-- --keep DIR` keeps their \
             scene files, and valgrind --tool=cachegrind with cg_annotate shows where the instructions go. If the extra \
             work is deliberate (a feature that costs, a compiler upgrade), raise the baseline with \
             `{UPDATE_COMMAND}` and commit {BASELINE} saying why."
        ),
        Verdict::LessWork => format!(
            "note {figures}\n     Less work than the baseline: lower it with `{UPDATE_COMMAND}` and commit {BASELINE}, \
             so that the guard holds the gain."
        ),
    };
    (verdict, message)
}

/// Today's date, UTC, as `YYYY-MM-DD`.
pub fn today() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let days = (secs / 86_400) as i64;
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

/// The commit the working tree is at, `-dirty` when it has uncommitted changes.
pub fn current_commit() -> String {
    Command::new("git")
        .args(["describe", "--always", "--dirty", "--abbrev=7"])
        .current_dir(crate::repo_root())
        .stdin(Stdio::null())
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "unknown".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(instructions: u64) -> Entry {
        Entry { name: "w".into(), instructions, commit: "abc1234".into(), date: "2026-01-01".into() }
    }

    #[test]
    fn the_comparator_fails_only_above_the_tolerance() {
        assert_eq!(judge(1_000_000, 1_000_000, 0.02), Verdict::Within);
        assert_eq!(judge(1_000_000, 1_020_000, 0.02), Verdict::Within);
        assert_eq!(judge(1_000_000, 1_020_001, 0.02), Verdict::MoreWork);
        assert_eq!(judge(492_600_000, 543_200_000, 0.02), Verdict::MoreWork);
        assert_eq!(judge(1_000_000, 980_000, 0.02), Verdict::Within);
        assert_eq!(judge(1_000_000, 979_999, 0.02), Verdict::LessWork);
    }

    #[test]
    fn a_failure_names_the_figures_and_how_to_raise_the_baseline() {
        let (v, msg) = verdict_message(&entry(500_000_000), 550_000_000, 0.02);
        assert_eq!(v, Verdict::MoreWork);
        for part in [
            "FAIL",
            "w:",
            "550,000,000",
            "500,000,000",
            "abc1234",
            "1.1000",
            "+10.00 %",
            "±2.0 %",
            "--update",
        ] {
            assert!(msg.contains(part), "{part} missing from: {msg}");
        }
        let (v, msg) = verdict_message(&entry(500_000_000), 400_000_000, 0.02);
        assert_eq!(v, Verdict::LessWork);
        assert!(msg.starts_with("note") && msg.contains("lower it"), "{msg}");
    }

    #[test]
    fn the_baseline_file_round_trips() {
        let b = Baseline {
            rustc: "rustc 1.0".into(),
            valgrind: "valgrind-3".into(),
            cpu: "a CPU".into(),
            workloads: vec![entry(123), Entry { name: "x".into(), ..entry(u64::from(u32::MAX) * 3) }],
        };
        assert_eq!(Baseline::parse(&b.to_json()).unwrap(), b);
        assert!(Baseline::parse("{\"workloads\": []}").is_err());
    }

    #[test]
    fn cachegrind_summaries_are_read() {
        let text = "desc: I1 cache: ...\ncmd: x\nevents: Ir\nfl=a\n1 5\nsummary: 543210987\n";
        assert_eq!(parse_cachegrind_summary(text), Some(543_210_987));
        let text = "events: Ir I1mr ILmr\nsummary: 77 1 2\n";
        assert_eq!(parse_cachegrind_summary(text), Some(77));
        assert_eq!(parse_cachegrind_summary("events: Ir\n"), None);
    }

    #[test]
    fn edits_must_match_exactly() {
        assert_eq!(replace_exactly("a b a", "a", "c", 2).unwrap(), "c b c");
        assert!(replace_exactly("a b a", "a", "c", 1).is_err());
        assert_eq!(
            remove_block("x\n  <T id=\"1\">\n y\n  </T>\nz\n", "<T id=\"1\"", "</T>").unwrap(),
            "x\nz\n"
        );
    }

    #[test]
    fn numbers_are_grouped() {
        assert_eq!(grouped(0), "0");
        assert_eq!(grouped(999), "999");
        assert_eq!(grouped(1000), "1,000");
        assert_eq!(grouped(543_210_987), "543,210,987");
    }
}
