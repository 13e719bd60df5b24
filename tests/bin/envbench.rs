//! Environment-light figures: render times of the course's environment scenes with substituted
//! maps, and the noise of importance vs uniform sampling at equal time.
//!
//! ```text
//! cargo run --release -p tessera-tests --bin envbench -- [--samples N] [--width W] [--only SCENE]
//!     [--noise-only] [--scenes-only] [--threads N]
//! cargo run --release -p tessera-tests --bin envbench -- --mitsuba [--rounds N]
//!     [--samples N] [--variant llvm_ad_rgb] [--threads N] [--mitsuba-avx2] [--view whole|hits|misses]
//! ```
//! `--mitsuba` is issue #18's whole-render bench: the head_env_light workload
//! (`../shared/bench/head_env_park.xml`: head.ply, park.exr, 800x450, importance-sampled
//! environment, one shadow ray per hit) rendered by Tessera in this process and by Mitsuba 3
//! (`mitsuba_head_env.py` beside it, run with `$TESSERA_ANCHORS_PY`, default
//! `~/.cache/anchors/bin/python`), alternately, `--rounds` times; prints Msamples/s of each
//! round, the best and the median of each, their ratios, and the median of the rounds' own
//! ratios (each round's two renders run back to back). Both time the render only (not
//! loading, not writing). The script's `dr.set_thread_count` hangs with drjit 1.5.0 (and so
//! does the llvm variant pinned to one core with `taskset -c 0`), so the bench runs a copy of the
//! script without that call: Mitsuba uses one thread per core, and `--threads` should match it
//! (2 on the 2-vCPU bench machine).
//! Mitsuba's LLVM variants compile their kernels for the CPU they run on: sixteen lanes per
//! instruction where it has AVX-512, eight with AVX2. The bench prints the width Mitsuba ran
//! at. `--mitsuba-avx2` has Mitsuba compile for AVX2 at eight lanes (drjit's
//! `jit_llvm_set_target`, called through `ctypes`), the instruction set Tessera's binaries are
//! built for on every machine, so that figures from hosts with and without AVX-512 compare.
//! `--view hits` and `--view misses` change both renderers' camera the same way, to split the
//! whole-frame figure: zoomed in on the head (a field of view of 6 degrees instead of 30:
//! nearly every camera ray hits it and is lit; those whose drawn direction is below the surface
//! trace no shadow ray) or turned around (every camera ray misses and looks the map up);
//! `--view whole` (the default) is the workload itself.
//! Pictures go to `target/envbench/`. `--samples` and `--width` shrink the work (the figures say
//! so); without them every scene renders at its own resolution and NumSamples.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use tessera::image::Image;
use tessera::integrator::RayStats;
use tessera::render::{RenderSettings, render_camera};
use tessera::scene::Scene;
use tessera::scene::records::{EnvSampler, SceneRecords};
use tessera_tests::anchors::{vector_width, with_llvm_target};
use tessera_tests::conformance::display_image;
use tessera_tests::envmaps::{ENV_SCENES, load_substituted};

struct Args {
    samples: Option<u32>,
    width: Option<u32>,
    only: Option<String>,
    noise: bool,
    scenes: bool,
    threads: Option<usize>,
    mitsuba: bool,
    rounds: usize,
    variant: String,
    mitsuba_avx2: bool,
    view: View,
}

/// A text to replace in a copy of the workload, and its replacement.
type Edit = (&'static str, &'static str);

/// Which part of head_env_light's frame `--mitsuba` measures (see the header).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum View {
    Whole,
    Hits,
    Misses,
}

impl View {
    fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "whole" => View::Whole,
            "hits" => View::Hits,
            "misses" => View::Misses,
            other => bail!("--view: whole, hits or misses, not {other}"),
        })
    }

    /// (the text to replace, its replacement) in the scene file and in the Mitsuba script.
    fn edits(self) -> (Vec<Edit>, Vec<Edit>) {
        // Turned around: the gaze point mirrored through the camera's position.
        match self {
            View::Whole => (Vec::new(), Vec::new()),
            View::Hits => (vec![("<FovY>30</FovY>", "<FovY>6</FovY>")], vec![("'fov': 30,", "'fov': 6,")]),
            View::Misses => (
                vec![(
                    "<GazePoint>-0.140808 -0.162727 -0.35493</GazePoint>",
                    "<GazePoint>0.786486 0.269692 1.363528</GazePoint>",
                )],
                vec![("target=[-0.140808, -0.162727, -0.35493]", "target=[0.786486, 0.269692, 1.363528]")],
            ),
        }
    }
}

/// `text` with every edit made; each edit's text must be there (else the bench's copy of the
/// workload has changed under it, and the view would silently be the whole frame).
fn edited(text: String, edits: &[Edit], what: &std::path::Path) -> Result<String> {
    edits.iter().try_fold(text, |t, (from, to)| {
        if !t.contains(from) {
            bail!("{}: `{from}` not found, so --view cannot change the camera", what.display());
        }
        Ok(t.replace(from, to))
    })
}

fn parse_args() -> Result<Args> {
    let mut a = Args {
        samples: None,
        width: None,
        only: None,
        noise: true,
        scenes: true,
        threads: None,
        mitsuba: false,
        rounds: 5,
        variant: "llvm_ad_rgb".into(),
        mitsuba_avx2: false,
        view: View::Whole,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().with_context(|| format!("{name} needs a value"));
        match arg.as_str() {
            "--samples" => a.samples = Some(value("--samples")?.parse().context("--samples: a number")?),
            "--width" => a.width = Some(value("--width")?.parse().context("--width: a number")?),
            "--only" => a.only = Some(value("--only")?),
            "--threads" => a.threads = Some(value("--threads")?.parse().context("--threads: a number")?),
            "--noise-only" => a.scenes = false,
            "--mitsuba" => a.mitsuba = true,
            "--rounds" => {
                a.rounds = value("--rounds")?.parse().context("--rounds: a number")?;
                if a.rounds == 0 {
                    bail!("--rounds: at least 1");
                }
            }
            "--variant" => a.variant = value("--variant")?,
            "--mitsuba-avx2" => a.mitsuba_avx2 = true,
            "--view" => a.view = View::parse(&value("--view")?)?,
            "--scenes-only" => a.noise = false,
            "-h" | "--help" => {
                println!(
                    "envbench: environment-light timings and importance-vs-uniform noise\n\n\
                     options: --samples N  --width W  --only SCENE  --noise-only  --scenes-only  --threads N\n         \
                     --mitsuba [--rounds N] [--variant V] [--mitsuba-avx2]: head_env_light against Mitsuba 3\n         \
                     (--mitsuba-avx2: Mitsuba's LLVM kernels for AVX2, eight lanes, as Tessera's binaries)\n         \
                     --view whole|hits|misses: the whole frame, the head filling it, or the map alone"
                );
                std::process::exit(0);
            }
            other => bail!("unknown argument {other} (try --help)"),
        }
    }
    if a.view != View::Whole && !a.mitsuba {
        bail!("--view applies to the --mitsuba bench (head_env_light against Mitsuba 3)");
    }
    Ok(a)
}

fn shrink(rec: &mut SceneRecords, width: Option<u32>) {
    if let Some(w) = width {
        for c in &mut rec.cameras {
            c.height = (c.height * w / c.width).max(1);
            c.width = w;
        }
    }
}

fn render(scene: &Scene, settings: &RenderSettings) -> (Image, f64, RayStats) {
    let t = Instant::now();
    let (img, stats) = render_camera(scene, 0, 32, settings, &|_, _| {});
    (img, t.elapsed().as_secs_f64(), stats)
}

fn main() -> Result<()> {
    let args = parse_args()?;
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
    }
    let out = tessera_tests::repo_root().join("target/envbench");
    std::fs::create_dir_all(&out)?;
    println!("machine: {}", tessera_testkit::cpu_description());
    println!("threads: {}", rayon::current_num_threads());
    if args.mitsuba {
        return mitsuba_figures(&args, &out);
    }
    if args.scenes {
        for &(name, map) in ENV_SCENES {
            if args.only.as_deref().is_some_and(|o| o != name) {
                continue;
            }
            scene_figures(name, map, &args, &out)?;
        }
    }
    if args.noise {
        noise_figures(&out)?;
    }
    Ok(())
}

fn scene_figures(name: &str, map: &str, args: &Args, out: &std::path::Path) -> Result<()> {
    let t = Instant::now();
    let (scene, subs) = load_substituted(name, map, |r| shrink(r, args.width))?;
    let load = t.elapsed().as_secs_f64();
    let cam = &scene.cameras[0];
    let spp = args.samples.unwrap_or(cam.num_samples);
    let (img, secs, stats) =
        render(&scene, &RenderSettings { samples: args.samples, ..RenderSettings::default() });
    let rays = stats.total();
    let samples = cam.width as f64 * cam.height as f64 * spp as f64;
    let png: PathBuf = out.join(format!("{name}.png"));
    let ldr = display_image(cam, &img);
    tessera::hdr_io::write_png_rgb8(&png, ldr.width, ldr.height, &ldr.data)?;
    let dropped = if subs.dropped_maps.is_empty() {
        String::new()
    } else {
        format!(", dropped texture maps {:?}", subs.dropped_maps)
    };
    println!(
        "{name} (map {map}.exr{dropped}): {}x{} at {spp} spp, {} triangles; load {load:.2} s, render {secs:.2} s, {:.2} M samples/s, {:.2} Mrays/s -> {}",
        cam.width,
        cam.height,
        scene.stats.triangles,
        samples / secs / 1e6,
        rays as f64 / secs / 1e6,
        png.display()
    );
    Ok(())
}

/// RMS error over the pixels where `mask` is set, relative to the reference's mean there.
fn rel_rmse(img: &Image, reference: &Image, mask: &[bool]) -> f64 {
    let (mut se, mut sum, mut n) = (0.0, 0.0, 0usize);
    for ((p, r), m) in img.pixels.iter().zip(&reference.pixels).zip(mask) {
        if *m {
            for c in 0..3 {
                let d = p[c] as f64 - r[c] as f64;
                se += d * d;
                sum += r[c] as f64;
            }
            n += 3;
        }
    }
    (se / n as f64).sqrt() / (sum / n as f64)
}

/// Importance vs uniform on sphere_env_light lit by maps with a small sun: relative RMSE
/// against a converged image, and the ratio at equal render time (RMSE ∝ 1/√time).
fn noise_figures(out: &std::path::Path) -> Result<()> {
    for map in ["sky", "sunrise"] {
        let (scene, _) = load_substituted("sphere_env_light", map, |r| shrink(r, Some(200)))?;
        let settings = |s, spp, seed| RenderSettings { samples: Some(spp), env_sampling: Some(s), seed };
        let (reference, ref_secs, _) = render(&scene, &settings(EnvSampler::Importance, 8192, 99));
        println!(
            "noise, sphere_env_light with {map}.exr at 200x100, sphere pixels only, against importance at 8192 spp ({ref_secs:.1} s); mean of 3 seeds:"
        );
        // The sphere: pixels where two estimators differ at the same seed (same camera rays).
        let (a, _, _) = render(&scene, &settings(EnvSampler::Uniform, 4, 1));
        let (b, _, _) = render(&scene, &settings(EnvSampler::Importance, 4, 1));
        let mask: Vec<bool> = a.pixels.iter().zip(&b.pixels).map(|(p, q)| p != q).collect();
        println!("  {} sphere pixels", mask.iter().filter(|m| **m).count());
        let mut figures = Vec::new();
        for (label, sampler) in [
            ("uniform", EnvSampler::Uniform),
            ("cosine", EnvSampler::Cosine),
            ("importance", EnvSampler::Importance),
        ] {
            let spp = 256;
            let (mut err, mut secs) = (0.0, 0.0);
            for seed in 1..=3u64 {
                let (img, t, _) = render(&scene, &settings(sampler, spp, seed));
                err += rel_rmse(&img, &reference, &mask) / 3.0;
                secs += t / 3.0;
            }
            println!("  {label:<10} {spp} spp: {secs:.2} s, relative RMSE {err:.4}");
            figures.push((err, secs));
        }
        let (eu, tu) = figures[0];
        let (ei, ti) = figures[2];
        let equal_time = (eu / ei) * (tu / ti).sqrt();
        println!(
            "  importance vs uniform: {:.1}x less RMSE at equal samples, {equal_time:.1}x at equal time (uniform needs {:.0}x the time for the same noise)",
            eu / ei,
            equal_time * equal_time
        );
    }
    // Spread of the sphere's mean radiance over seeds at the CI convergence test's size (100 px
    // wide): uniform and cosine at 1024 spp, importance at 256.
    for map in ["sky", "sunrise", "park", "studio"] {
        let (small, _) = load_substituted("sphere_env_light", map, |r| shrink(r, Some(100)))?;
        let settings = |s, spp, seed| RenderSettings { samples: Some(spp), env_sampling: Some(s), seed };
        let mut line = format!("  {map}: sphere mean (green) over 6 seeds, relative sd:");
        for (label, sampler, spp) in [
            ("uniform", EnvSampler::Uniform, 1024),
            ("cosine", EnvSampler::Cosine, 1024),
            ("importance", EnvSampler::Importance, 256),
        ] {
            let mut means = Vec::new();
            for seed in 1..=6u64 {
                let (img, _, _) = render(&small, &settings(sampler, spp, seed));
                let other =
                    if sampler == EnvSampler::Uniform { EnvSampler::Cosine } else { EnvSampler::Uniform };
                let (twin, _, _) = render(&small, &settings(other, spp, seed));
                let m: Vec<bool> = img.pixels.iter().zip(&twin.pixels).map(|(a, b)| a != b).collect();
                let n = m.iter().filter(|x| **x).count() as f64;
                let s: f64 = img.pixels.iter().zip(&m).filter(|(_, k)| **k).map(|(p, _)| p[1] as f64).sum();
                means.push(s / n);
            }
            let avg = means.iter().sum::<f64>() / means.len() as f64;
            let sd =
                (means.iter().map(|m| (m - avg) * (m - avg)).sum::<f64>() / (means.len() - 1) as f64).sqrt();
            line += &format!(" {label} {:.4} (mean {avg:.3})", sd / avg);
        }
        println!("{line}");
        let _ = out;
    }
    Ok(())
}

/// Issue #18's whole-render bench: Tessera and Mitsuba 3 on head_env_light, alternately.
fn mitsuba_figures(args: &Args, out: &std::path::Path) -> Result<()> {
    let bench = tessera_tests::shared_bench();
    let scenes = tessera_tests::shared_scenes();
    if args.mitsuba_avx2 && !args.variant.starts_with("llvm") {
        bail!("--mitsuba-avx2 applies to Mitsuba's llvm variants, not {}", args.variant);
    }
    if args.variant.starts_with("llvm") && std::env::var_os("DRJIT_LIBLLVM_PATH").is_none() {
        bail!(
            "Mitsuba's {} variant needs DRJIT_LIBLLVM_PATH, the path of libLLVM (Debian: apt install libllvm19; \
             see ../shared/bench/README.md), or pass --variant scalar_rgb",
            args.variant
        );
    }
    let spp = args.samples.unwrap_or(16);
    let dir = out.join("head_env");
    for sub in ["ply", "textures"] {
        std::fs::create_dir_all(dir.join(sub))?;
    }
    let ply = dir.join("ply/head.ply");
    let hdri = dir.join("textures/park.exr");
    std::fs::copy(scenes.join("xml/ply/head.ply"), &ply).context("head.ply")?;
    let park = [scenes.join("textures/park.exr"), scenes.join("hdri/park.exr")];
    let park = park.iter().find(|p| p.exists()).context("park.exr not found")?;
    std::fs::copy(park, &hdri)?;
    let (scene_edits, script_edits) = args.view.edits();
    let xml_path = bench.join("head_env_park.xml");
    let xml = std::fs::read_to_string(&xml_path)?.replace("SPP", &spp.to_string());
    let xml = edited(xml, &scene_edits, &xml_path)?;
    let scene_path = dir.join("head_env_park.xml");
    std::fs::write(&scene_path, xml)?;
    let script_src = bench.join("mitsuba_head_env.py");
    let script = edited(std::fs::read_to_string(&script_src)?, &script_edits, &script_src)?;
    let mut script: String =
        script.lines().filter(|l| !l.starts_with("dr.set_thread_count")).map(|l| format!("{l}\n")).collect();
    if args.variant.starts_with("llvm") {
        script = with_llvm_target(&script, args.mitsuba_avx2).context("mitsuba_head_env.py")?;
    }
    let script_path = dir.join("mitsuba_head_env.py");
    std::fs::write(&script_path, script)?;
    let scene = tessera::scene::load::load_scene_file(&scene_path)?;
    let settings = RenderSettings {
        samples: Some(spp),
        env_sampling: Some(EnvSampler::Importance),
        ..RenderSettings::default()
    };
    let samples = 800.0 * 450.0 * spp as f64;
    println!(
        "head_env_light, 800x450, {spp} spp, view {:?}, Mitsuba variant {}, {} rounds",
        args.view, args.variant, args.rounds
    );
    let (mut ours, mut theirs) = (Vec::new(), Vec::new());
    let mut width_shown = false;
    for round in 0..args.rounds {
        let (_, secs, stats) = render(&scene, &settings);
        ours.push(samples / secs / 1e6);
        if round == 0 {
            // What the view does to the work: a shadow ray per lit sample that faces its light.
            println!("  Tessera: {:.3} shadow rays per camera sample", stats.shadow as f64 / samples);
        }
        let args =
            [ply.display().to_string(), hdri.display().to_string(), spp.to_string(), args.variant.clone()];
        let text = tessera_tests::anchors::run(&script_path, &args)?;
        if !width_shown && let Some(w) = vector_width(&text) {
            println!("  Mitsuba's kernels: {w} lanes per instruction");
            width_shown = true;
        }
        let m = tessera_tests::anchors::last_figure(&text)?;
        theirs.push(m);
        println!(
            "  round {round}: Tessera {:.3} Msamples/s, Mitsuba {m:.3} Msamples/s, ratio {:.3}",
            ours[round],
            ours[round] / m
        );
    }
    for line in tessera_tests::anchors::round_summaries(&ours, &theirs, "Mitsuba", "Msamples/s") {
        println!("{line}");
    }
    Ok(())
}
