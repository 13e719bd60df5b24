//! Speed against the anchors where the farm's time goes (issue #54): path tracing against
//! Mitsuba 3, and the primary-ray render phase against Embree 4 and Mitsuba's first-hit render.
//!
//! ```text
//! cargo run --release -p tessera-tests --bin pathbench -- [--rounds N] [--samples N] [--threads N] [--one-light] [--mis] [--mitsuba-avx2]
//! cargo run --release -p tessera-tests --bin pathbench -- --primary [--rounds N] [--width W --height H]
//! ```
//! The default is the path-tracing workload: `../shared/bench/jaroslav_path.xml`
//! (cornellbox_jaroslav_path_diffuse's `diffuse_next_importance` camera: NEE, cosine sampling,
//! MaxRecursionDepth 3, no roulette, 512x512) rendered by Tessera in this process and by
//! Mitsuba 3 (`mitsuba_jaroslav_path.py` beside it: `path`, max_depth 5, no roulette, the same
//! geometry, lights and diffuse reflectances) alternately, `--rounds` times, both on
//! `--threads` threads (default 1: the per-core figure). Both time the render only. It prints
//! each round's Msamples/s, the best and the median of each side with their ratios, the median
//! of the rounds' own ratios (each round's two renders run back to back), and how far apart
//! the two images' means over a 4x4 grid of regions are (the last round's images, at
//! `--samples`, default 16: a check that both render the same picture, looser at few samples).
//! `--one-light` adds Tessera's `SampleOneLight` to the camera's `RendererParams`: one light a
//! vertex, chosen by power, as Mitsuba samples one emitter a vertex (the course's estimator,
//! the default, samples both).
//! `--mis` adds `MultipleImportanceSampling`: the light box's light weighed between its sampled
//! points and the bounces that find it, as Mitsuba's `path` integrator weighs them (with both
//! flags, Tessera's estimator is Mitsuba's). Mitsuba's LLVM variant compiles its kernels for
//! the host: sixteen lanes an instruction where it has AVX-512 (the bench prints the width);
//! `--mitsuba-avx2` has it compile for AVX2 at eight lanes, the instruction set Tessera ships.
//!
//! `--primary` is the camera-ray workload: head.ply at 3840x2160, one ray through each pixel
//! centre (`../shared/bench/head_primary.xml`), no lights and no bounces. Tessera's render
//! phase on one thread against Embree 4 (`embree_primary.py`: embreex, one ray a call, one
//! thread) in alternating rounds, then Tessera on two threads against Mitsuba's first-hit render
//! (`tests/bench/mitsuba_head_first_hit.py`, the `aov` integrator, one thread per core;
//! `--mitsuba-avx2` sets its width as for the path workload).
//!
//! The Python anchors run with `$TESSERA_ANCHORS_PY` (default `~/.cache/anchors/bin/python`; see
//! ../shared/bench/README.md); Mitsuba's llvm variant needs `DRJIT_LIBLLVM_PATH`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use tessera::hdr_io::read_exr;
use tessera::image::Image;
use tessera::integrator::RayStats;
use tessera::render::{RenderSettings, render_camera};
use tessera::scene::Scene;
use tessera::scene::load::load_scene_file;
use tessera_tests::anchors::{
    json_number, last_figure, round_summaries, run as anchor, vector_width, with_llvm_target,
};

struct Args {
    primary: bool,
    one_light: bool,
    mis: bool,
    mitsuba_avx2: bool,
    rounds: usize,
    samples: u32,
    threads: usize,
    width: u32,
    height: u32,
}

/// The value `value` of option `name` as a count or size of type `T`: a number of at least 1
/// that `T` holds (a 0 is refused, not quietly raised; a larger one is refused, not wrapped).
fn count<T: TryFrom<u64>>(value: Option<String>, name: &str) -> Result<T> {
    let n: u64 = value
        .with_context(|| format!("{name} needs a value"))?
        .parse()
        .with_context(|| format!("{name}: a number"))?;
    if n == 0 {
        bail!("{name}: at least 1");
    }
    T::try_from(n).ok().with_context(|| format!("{name}: too large"))
}

fn parse_args() -> Result<Args> {
    let mut a = Args {
        primary: false,
        one_light: false,
        mis: false,
        mitsuba_avx2: false,
        rounds: 5,
        samples: 16,
        threads: 1,
        width: 3840,
        height: 2160,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--primary" => a.primary = true,
            "--one-light" => a.one_light = true,
            "--mis" => a.mis = true,
            "--mitsuba-avx2" => a.mitsuba_avx2 = true,
            "--rounds" => a.rounds = count(it.next(), "--rounds")?,
            "--samples" => a.samples = count(it.next(), "--samples")?,
            "--threads" => a.threads = count(it.next(), "--threads")?,
            "--width" => a.width = count(it.next(), "--width")?,
            "--height" => a.height = count(it.next(), "--height")?,
            "-h" | "--help" => {
                println!(
                    "{}",
                    include_str!("pathbench.rs")
                        .lines()
                        .take_while(|l| l.starts_with("//!"))
                        .map(|l| l.trim_start_matches("//!").trim_start())
                        .collect::<Vec<_>>()
                        .join("\n")
                );
                std::process::exit(0);
            }
            other => bail!("unknown argument {other} (see --help)"),
        }
    }
    Ok(a)
}

/// Renders camera 0 on a pool of `threads` threads: the image, the render's seconds, its rays.
fn render(scene: &Scene, settings: &RenderSettings, threads: usize) -> (Image, f64, RayStats) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
    pool.install(|| {
        let start = Instant::now();
        let (img, stats) = render_camera(scene, 0, 32, settings, &|_, _| {});
        (img, start.elapsed().as_secs_f64(), stats)
    })
}

/// `rounds` alternating rounds of `ours` and then `theirs` (each gives its figure in `unit` for
/// the round it is told), each round printed, then the medians and their ratio.
fn alternate(
    rounds: usize,
    unit: &str,
    theirs_name: &str,
    mut ours: impl FnMut(usize) -> Result<f64>,
    mut theirs: impl FnMut(usize) -> Result<f64>,
) -> Result<()> {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for round in 0..rounds {
        let (o, t) = (ours(round)?, theirs(round)?);
        println!("  round {round}: Tessera {o:.3} {unit}, {theirs_name} {t:.3}, ratio {:.3}", o / t);
        a.push(o);
        b.push(t);
    }
    for line in round_summaries(&a, &b, theirs_name, unit) {
        println!("{line}");
    }
    Ok(())
}

fn need_llvm() -> Result<()> {
    if std::env::var_os("DRJIT_LIBLLVM_PATH").is_none() {
        bail!(
            "Mitsuba's llvm_ad_rgb variant needs DRJIT_LIBLLVM_PATH, the path of libLLVM (Debian: apt install libllvm19; see ../shared/bench/README.md)"
        );
    }
    Ok(())
}

/// The mean of each of 4x4 regions of an image, in luminance.
fn region_means(img: &Image) -> Vec<f64> {
    let mut out = Vec::new();
    for ry in 0..4 {
        for rx in 0..4 {
            let (mut sum, mut n) = (0.0, 0.0);
            for y in ry * img.height / 4..(ry + 1) * img.height / 4 {
                for x in rx * img.width / 4..(rx + 1) * img.width / 4 {
                    let p = img.pixels[(y * img.width + x) as usize];
                    sum += 0.2126 * f64::from(p[0]) + 0.7152 * f64::from(p[1]) + 0.0722 * f64::from(p[2]);
                    n += 1.0;
                }
            }
            out.push(sum / n);
        }
    }
    out
}

fn path_figures(args: &Args, out: &Path) -> Result<()> {
    need_llvm()?;
    let bench = tessera_tests::shared_bench();
    let mut xml =
        std::fs::read_to_string(bench.join("jaroslav_path.xml"))?.replace("SPP", &args.samples.to_string());
    let params = "NextEventEstimation ImportanceSampling";
    let flags: Vec<&str> = [(args.one_light, "SampleOneLight"), (args.mis, "MultipleImportanceSampling")]
        .into_iter()
        .filter_map(|(on, flag)| on.then_some(flag))
        .collect();
    if !flags.is_empty() {
        if !xml.contains(params) {
            bail!("jaroslav_path.xml: `{params}` not found, so {} cannot be added", flags.join(" and "));
        }
        xml = xml.replace(params, &format!("{params} {}", flags.join(" ")));
    }
    let scene_path = out.join("jaroslav_path.xml");
    std::fs::write(&scene_path, xml)?;
    let scene = load_scene_file(&scene_path)?;
    let (w, h) = (scene.cameras[0].width, scene.cameras[0].height);
    let samples = f64::from(w * h) * f64::from(args.samples);
    let settings = RenderSettings::default();
    // The anchor's script with the lines that print (and with `--mitsuba-avx2`, set) its
    // kernels' width, in a folder of its own beside the scene it reads.
    let source = bench.join("mitsuba_jaroslav_path.py");
    let text = std::fs::read_to_string(&source).with_context(|| format!("reading {}", source.display()))?;
    let anchor_dir = out.join("mitsuba");
    std::fs::create_dir_all(&anchor_dir)?;
    std::fs::copy(bench.join("jaroslav_path.xml"), anchor_dir.join("jaroslav_path.xml"))?;
    let script = anchor_dir.join("mitsuba_jaroslav_path.py");
    std::fs::write(&script, with_llvm_target(&text, args.mitsuba_avx2).context("mitsuba_jaroslav_path.py")?)?;
    let theirs_exr = out.join("mitsuba.exr");
    println!(
        "jaroslav_path (cornellbox_jaroslav_path_diffuse, diffuse_next_importance), {w}x{h}, {} spp, {} thread(s), {} rounds{}",
        args.samples,
        args.threads,
        args.rounds,
        if flags.is_empty() { String::new() } else { format!(", Tessera with {}", flags.join(" ")) }
    );
    let mut last = None;
    let mitsuba_args = [
        args.samples.to_string(),
        "llvm_ad_rgb".into(),
        args.threads.to_string(),
        theirs_exr.display().to_string(),
    ];
    alternate(
        args.rounds,
        "Msamples/s",
        "Mitsuba",
        |round| {
            let (img, secs, stats) = render(&scene, &settings, args.threads);
            if round == 0 {
                println!(
                    "  Tessera: {:.2} rays a sample ({:.2} shadow, {:.2} bounce)",
                    stats.total() as f64 / samples,
                    stats.shadow as f64 / samples,
                    stats.secondary as f64 / samples
                );
            }
            last = Some(img);
            Ok(samples / secs / 1e6)
        },
        |round| {
            let text = anchor(&script, &mitsuba_args)?;
            if round == 0 {
                println!(
                    "  Mitsuba's kernels: {} lanes an instruction",
                    vector_width(&text).unwrap_or("unknown")
                );
            }
            last_figure(&text)
        },
    )?;
    let ours_img = last.expect("at least one round");
    let theirs_img = read_exr(&theirs_exr).with_context(|| format!("reading {}", theirs_exr.display()))?;
    if (theirs_img.width, theirs_img.height) != (w, h) {
        bail!("Mitsuba's image is {}x{}, not {w}x{h}", theirs_img.width, theirs_img.height);
    }
    let (a, b) = (region_means(&ours_img), region_means(&theirs_img));
    let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs() / y.abs().max(1e-6)).fold(0.0, f64::max);
    let whole = a.iter().sum::<f64>() / b.iter().sum::<f64>();
    println!(
        "  images: whole-frame mean ratio {whole:.4}, largest region-mean difference {:.1} % (4x4 regions)",
        100.0 * worst
    );
    Ok(())
}

fn primary_figures(args: &Args, out: &Path) -> Result<()> {
    let bench = tessera_tests::shared_bench();
    let ply = tessera_tests::shared_scenes().join("xml/ply/head.ply");
    let (w, h) = (args.width, args.height);
    let xml = std::fs::read_to_string(bench.join("head_primary.xml"))?
        .replace("RES", &format!("{w} {h}"))
        .replace("PLY", &ply.display().to_string());
    let scene_path = out.join("head_primary.xml");
    std::fs::write(&scene_path, xml)?;
    let scene = load_scene_file(&scene_path)?;
    let settings = RenderSettings::default();
    let rays = f64::from(w * h);
    let camera = ["0.322839", "0.0534825", "0.504299", "-0.140808", "-0.162727", "-0.35493", "30"];
    let mut embree_args = vec![ply.display().to_string(), w.to_string(), h.to_string()];
    embree_args.extend(camera.iter().map(|s| s.to_string()));
    embree_args.push("1".into());
    println!("head.ply primary rays, {w}x{h}, one a pixel, {} rounds", args.rounds);
    let embree = bench.join("embree_primary.py");
    alternate(
        args.rounds,
        "Mrays/s (render phase, one thread)",
        "Embree",
        |round| {
            let (img, secs, _) = render(&scene, &settings, 1);
            if round == 0 {
                let hit = img.pixels.iter().filter(|p| p[0] > 0.0).count() as f64 / rays;
                println!("  Tessera: {hit:.4} of the rays hit the head");
            }
            Ok(rays / secs / 1e6)
        },
        |round| {
            let text = anchor(&embree, &embree_args)?;
            if round == 0 {
                println!("  Embree: {:.4} of the rays hit the head", json_number(&text, "hit")?);
            }
            json_number(&text, "embree_mrays_s")
        },
    )?;
    need_llvm()?;
    // The anchor's script with the lines that print (and with `--mitsuba-avx2`, set) its
    // kernels' width.
    let source = tessera_tests::repo_root().join("tests/bench/mitsuba_head_first_hit.py");
    let text = std::fs::read_to_string(&source).with_context(|| format!("reading {}", source.display()))?;
    let script = out.join("mitsuba_head_first_hit.py");
    std::fs::write(
        &script,
        with_llvm_target(&text, args.mitsuba_avx2).context("mitsuba_head_first_hit.py")?,
    )?;
    let mitsuba_args = [ply.display().to_string(), w.to_string(), h.to_string(), "llvm_ad_rgb".into()];
    alternate(
        args.rounds,
        "Mrays/s (two threads)",
        "Mitsuba first hit",
        |_| {
            let (_, secs, _) = render(&scene, &settings, 2);
            Ok(rays / secs / 1e6)
        },
        |round| {
            let text = anchor(&script, &mitsuba_args)?;
            if round == 0 {
                println!(
                    "  Mitsuba first hit: {:.4} of the rays hit the head, {} lanes an instruction",
                    json_number(&text, "hit")?,
                    vector_width(&text).unwrap_or("unknown")
                );
            }
            json_number(&text, "mrays_per_s")
        },
    )?;
    Ok(())
}

fn main() -> Result<()> {
    let args = parse_args()?;
    let out: PathBuf = tessera_tests::repo_root().join("target/pathbench");
    std::fs::create_dir_all(&out)?;
    if args.primary && (args.one_light || args.mis) {
        bail!("--one-light and --mis apply to the path-tracing workload, not --primary");
    }
    if args.primary { primary_figures(&args, &out) } else { path_figures(&args, &out) }
}
