//! `tessera-worker`: Tessera's CPU tracer as a command-line program.
//!
//! `render` renders a scene file on this machine, like the course's `./raytracer scene.xml`;
//! `tonemap` turns an HDR image (OpenEXR or Radiance HDR) into a PNG with the course's
//! photographic operator; `work` pulls tiles from a `tessera-server` farm (`farm.rs`).

/// `eprintln!` in one write: a farm's local workers share the server's standard error, and
/// `eprintln!` writes a formatted line in pieces, between which another process's line can land.
/// A line of up to 4 KiB written at once to a pipe is never torn (POSIX `PIPE_BUF`).
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let mut line = format!($($arg)*);
        line.push('\n');
        let _ = std::io::stderr().lock().write_all(line.as_bytes());
    }};
}

mod farm;
mod filecache;
mod jobfiles;
mod resolve;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use tessera::assets::FsResolver;
use tessera::hdr_io::{read_float_image, write_png_rgb8};
use tessera::image::is_finite_pixel;
use tessera::output;
use tessera::render::{
    PassPlan, RenderSettings, render_camera, render_camera_passes, render_camera_with_aux,
};
use tessera::scene::build::{build_scene, build_scene_cached};
use tessera::scene::load::{LoadOptions, parse_scene};
use tessera::scene::records::EnvSampler;
use tessera::tonemap::params::{Gamma, Operator, Photographic};
use tessera::tonemap::tonemap_with;

#[derive(Parser)]
#[command(
    name = "tessera-worker",
    version,
    about = "Tessera's CPU ray tracer for CENG795 scene files",
    after_help = "Examples:\n  tessera-worker render scenes/cornell_box.xml --out out/\n  tessera-worker render scene.xml --threads 4 --camera 2 --out renders/\n  tessera-worker tonemap render.exr --key 0.18 --burn 1 -o render.png\n\nSee 'tessera-worker render --help' for every option (--out, --threads, --camera, --tile-size, --quiet)\nand 'tessera-worker tonemap --help' for the tone-mapping parameters."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render every camera of one or more scene files on this machine.
    ///
    /// Several scene files (an animation, one file a frame) are rendered one after another in
    /// the order given, in one process: meshes and images they share are parsed and built once
    /// (kept in memory up to --mesh-cache-mb), and each file's images are the bytes rendering it
    /// alone writes. --timings shows where each frame's time went.
    ///
    /// Each camera's image is written to DIR under the file name of the camera's <ImageName>:
    /// .png is clamped to [0, 255] and rounded, as the course specifies; .exr writes the linear
    /// image as a lossless 32-bit float OpenEXR file and, beside it, a PNG of the same stem
    /// tone-mapped with the camera's <Tonemap> (photographic, key 0.18, burn 1 %, gamma 2.2 when
    /// it has none); .hdr the same with Radiance RGBE. Assets (PLY files, images) are found
    /// relative to the scene file. Warnings about the scene go to stderr; a summary line per
    /// camera goes to stdout. A scene that uses elements Tessera does not implement and that
    /// would change the picture (every element of the course format is implemented; today only
    /// a tone-mapping operator no course material names) is refused, every such element named
    /// with its line, unless --allow-unsupported.
    ///
    /// Example: tessera-worker render scenes/cornell_box.xml --out out/
    ///          tessera-worker render orbit/frame_*.json --samples 4 --timings --out frames/
    Render(RenderArgs),
    /// Pull tiles from a tessera-server and render them, until stopped.
    ///
    /// Registers with the server, then long-polls for tiles (one fetched ahead while the
    /// others render), fetches each job's scene bundle once, renders a tile on each thread
    /// (every core, or --threads) and uploads the float pixels. Heartbeats keep its leases alive; if it dies,
    /// its tiles go back to the queue by themselves.
    ///
    /// Example: tessera-worker work --server http://farm.example:8080 --token "$TOKEN"
    Work {
        /// The server's base URL.
        #[arg(long, env = "TESSERA_SERVER", value_name = "URL")]
        server: String,
        /// The farm's worker token (tessera-server --worker-token).
        #[arg(long, env = "TESSERA_WORKER_TOKEN", value_name = "TOKEN", hide_env_values = true)]
        token: String,
        /// A name for logs and the status page (default: host name and process id).
        #[arg(long, value_name = "NAME")]
        name: Option<String>,
        /// Render threads; default: every core.
        #[arg(long, short = 'j', value_name = "N")]
        threads: Option<usize>,
        /// What this worker offers, e.g. gpu,big (comma-separated or repeated): it renders only
        /// jobs whose worker tags (tessera submit --worker-tag) it all has, and jobs that ask for
        /// none. Each tag 1 to 32 letters, digits, '-', '_' or '.'; at most 16.
        #[arg(long, env = "TESSERA_WORKER_TAGS", value_name = "TAG,...", value_delimiter = ',')]
        tags: Vec<String>,
        /// Exit after rendering this many tiles (for tests and benchmarks).
        #[arg(long, value_name = "N", hide = true)]
        max_tiles: Option<u64>,
        /// Exit when the process that started this one ends (tessera-server's local workers).
        #[arg(long, hide = true)]
        exit_with_parent: bool,
        /// Where job files (scenes, PLY files, images) are kept between frames, jobs and runs,
        /// each under its SHA-256, so that a file is downloaded once. Created if missing; may
        /// be shared by several workers. [default: $XDG_CACHE_HOME/tessera/files, else
        /// $HOME/.cache/tessera/files]
        #[arg(long, env = "TESSERA_WORKER_CACHE_DIR", value_name = "DIR")]
        cache_dir: Option<PathBuf>,
        /// Disk space for --cache-dir in MiB; past it the least recently used files are
        /// removed. 0 keeps nothing (every file is downloaded each time it is needed).
        #[arg(long, env = "TESSERA_WORKER_CACHE_MB", default_value_t = filecache::DEFAULT_CACHE_MB, value_name = "MB")]
        cache_mb: u64,
        /// Memory for parsed meshes (with their BVHs) and decoded images kept across frames
        /// and jobs, in MiB; the least recently used go first. 0 keeps nothing.
        #[arg(long, env = "TESSERA_MESH_CACHE_MB", default_value_t = DEFAULT_MESH_CACHE_MB, value_name = "MB")]
        mesh_cache_mb: u64,
    },
    /// Tone-map an HDR image (OpenEXR or Radiance .hdr) to an 8-bit PNG.
    ///
    /// Uses the course's photographic operator (Reinhard et al. 2002, global; scene-format.md
    /// §12.3), the one a scene's <Tonemap> asks for: luminance Y = 0.2126 R + 0.7152 G + 0.0722 B;
    /// log average Ȳ = exp(mean(ln(1e-6 + Y))); L = key / Ȳ · Y; the white point L_white is the
    /// luminance that --burn percent of the pixels exceed (0: no white point); display luminance
    /// L (1 + L / L_white²) / (1 + L); colour by (C / Y)^saturation; clamp to [0, 1]; gamma;
    /// 255 · value truncated. Pixels with NaN or infinite values are left out of the statistics
    /// and reported.
    ///
    /// The input format is recognised by content; the output is always PNG. One summary line
    /// (log average, white point, non-finite pixels) goes to stdout.
    ///
    /// Example: tessera-worker tonemap head_env_light.exr --key 0.18 --burn 1 -o head_env_light.png
    ///          tessera-worker tonemap render.exr --scene scene.xml --burn 0 -o render.png
    #[command(allow_negative_numbers = true)]
    Tonemap {
        /// The HDR image to tone-map (.exr or .hdr).
        input: PathBuf,
        /// The PNG file to write.
        #[arg(long, short, value_name = "OUT.png")]
        out: PathBuf,
        /// Take the defaults from this scene file's <Tonemap> (of --camera, else the first camera
        /// with one) instead of the course defaults; the options below still override them.
        #[arg(long, value_name = "SCENE")]
        scene: Option<PathBuf>,
        /// With --scene: the camera whose <Tonemap> to use (1 = the first camera in the file).
        #[arg(long, value_name = "K", requires = "scene")]
        camera: Option<usize>,
        /// Key value a: the display luminance the log-average luminance maps to (<TMOOptions>'s
        /// first number). Brighter with a larger key. [default: 0.18, or the scene's]
        #[arg(long, value_name = "K")]
        key: Option<f64>,
        /// Burn-out percentage b, 0 to 100: the share of pixels allowed to reach white
        /// (<TMOOptions>'s second number); 0: no white point, plain L / (1 + L).
        /// [default: 1, or the scene's]
        #[arg(long, value_name = "P")]
        burn: Option<f64>,
        /// Saturation exponent s applied to each channel's ratio to the luminance (<Saturation>):
        /// 1 keeps the colours, 0 gives grey, above 1 saturates. [default: 1, or the scene's]
        #[arg(long, value_name = "S")]
        saturation: Option<f64>,
        /// Display gamma (<Gamma>): a positive number, or "srgb" for the sRGB transfer curve.
        /// [default: 2.2, or the scene's]
        #[arg(long, value_name = "G|srgb")]
        gamma: Option<Gamma>,
        /// The luminance curve (<TMO>): photographic (Reinhard et al. 2002), filmic (Hable) or
        /// aces (Narkowicz's fit); the key, burn-out, saturation and gamma steps are shared. With
        /// --scene, the camera's <Tonemap> of this operator gives the defaults when it has one
        /// (2025 cameras list several). [default: photographic, or the scene's first]
        #[arg(long, value_name = "NAME")]
        operator: Option<Operator>,
    },
}

/// `render`'s arguments: the scenes, where to write, and how to render them.
#[derive(clap::Args)]
struct RenderArgs {
    /// The scene files (CENG795 XML or 2025 JSON; told apart by content), rendered in this
    /// order.
    #[arg(required = true, num_args = 1.., value_name = "SCENE")]
    scenes: Vec<PathBuf>,
    /// Directory for the output images (created if missing).
    #[arg(long, short, default_value = ".", value_name = "DIR")]
    out: PathBuf,
    /// Render threads; default: every core.
    #[arg(long, short = 'j', value_name = "N")]
    threads: Option<usize>,
    /// Render only camera K (1 = the first camera in the file).
    #[arg(long, value_name = "K")]
    camera: Option<usize>,
    /// Tile edge in pixels (the unit of parallel work; does not change the image, except under
    /// --noise-target, whose pixels are judged within their tile).
    #[arg(long, default_value_t = 32, value_name = "PX")]
    tile_size: u32,
    /// Samples per pixel for every camera instead of its <NumSamples> (e.g. 4 for a quick,
    /// noisy preview of a 900-sample scene).
    #[arg(long, value_name = "N")]
    samples: Option<u32>,
    /// How environment lights pick their one direction per shading event, instead of the
    /// light's <Sampler>: uniform (the course's estimator: the hemisphere around the normal,
    /// radiance divided by the pdf 1/(2π)), cosine (pdf cos θ/π) or importance (by the map's
    /// luminance; far less noise for maps with a small bright sun). All converge to the same
    /// image.
    #[arg(long, value_enum, value_name = "MODE")]
    env_sampling: Option<EnvSampling>,
    /// The sampler's base seed instead of Tessera's own (which the farm always uses): a
    /// different seed renders another, independent image of the same scene, such as a
    /// reference to measure a render's noise against.
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Do not draw a progress bar.
    #[arg(long, short)]
    quiet: bool,
    /// Render a scene that uses elements Tessera does not implement although they change the
    /// picture (each one is then a warning, and the image is rendered without it). Without
    /// this option such a scene is an error that names every one of them.
    #[arg(long)]
    allow_unsupported: bool,
    /// Also write a denoised copy of each image beside the course's outputs, never over them:
    /// <stem>_denoised.exr and its tone-mapped (or, for .png image names, clamped) PNG. Uses
    /// Intel Open Image Denoise 2 (its RT filter, high quality, guided by the albedo and
    /// normal of the first surface each pixel sees that is not a perfect mirror or glass,
    /// which are rendered along). The library is looked for in TESSERA_OIDN_LIB, then the
    /// system's library path, then the pyoidn Python wheel (python3 -m pip install pyoidn);
    /// without it nothing is rendered.
    #[arg(long)]
    denoise: bool,
    /// Stop sampling a pixel once its estimated relative noise (pooled over its neighbours)
    /// is at most this, in (0, 1] (e.g. 0.02 for about 2 %); <NumSamples> (or --samples)
    /// becomes the cap. Tiles are then rendered pass by pass (--pass-samples), after each pass
    /// every pixel judged on the luminance of its odd sample blocks against all of them, and
    /// <stem>_samples.png shows where samples went. A farm job with the same noise_target, pass_samples and tile_size
    /// renders the same bits.
    #[arg(long, value_name = "ERROR")]
    noise_target: Option<f64>,
    /// Samples per pass for --noise-target (rounded up to whole blocks of 16; default: a
    /// sixteenth of the samples). Without a noise target passes do not change the image.
    #[arg(long, value_name = "N", requires = "noise_target")]
    pass_samples: Option<u32>,
    /// Print, for each scene file, where its time went on a line of its own on stdout: reading
    /// and parsing the scene file, building it (assets, meshes and their BVHs; how many meshes
    /// came from the cache), the top-level trees over its instances (the world-space tree of
    /// its static meshes comes from the cache when an earlier file placed the same meshes the
    /// same way), rendering and writing.
    #[arg(long)]
    timings: bool,
    /// Like --timings, as one JSON object a line (keys: scene, parse_seconds, build_seconds,
    /// mesh_seconds, meshes, meshes_cached, top_level_seconds, top_level_cached,
    /// render_seconds, write_seconds).
    #[arg(long)]
    timings_json: bool,
    /// Memory for meshes (with their BVHs) and images kept from one scene file for the next,
    /// in MiB; the least recently used go first. 0 keeps nothing.
    #[arg(long, env = "TESSERA_MESH_CACHE_MB", default_value_t = DEFAULT_MESH_CACHE_MB, value_name = "MB")]
    mesh_cache_mb: u64,
    /// Render at this scale, in (0, 1], for a quick low-resolution look: each side of the image
    /// times the scale, rounded to the nearest pixel (halves up), at least 1 (0.25 renders an
    /// 800x450 camera at 200x113). The image plane stays, so the picture is the same, coarser;
    /// a farm job with the same scale renders the same bits.
    #[arg(long, value_name = "FACTOR")]
    scale: Option<f64>,
}

/// `--mesh-cache-mb`'s default: 2 GiB.
const DEFAULT_MESH_CACHE_MB: u64 = tessera::scene::cache::DEFAULT_MESH_CACHE_BYTES >> 20;

/// Bytes of `mb` MiB, refused when it does not fit (clap took it as a number already).
fn mesh_cache_bytes(mb: u64) -> Result<u64> {
    mb.checked_mul(1 << 20).ok_or_else(|| {
        anyhow::anyhow!(
            "--mesh-cache-mb {mb} (TESSERA_MESH_CACHE_MB) is too large; give a number of MiB such as 2048"
        )
    })
}

/// The host name (from /etc/hostname or $HOSTNAME) and the process id.
fn default_worker_name() -> String {
    let host = std::fs::read_to_string("/etc/hostname")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "worker".into());
    format!("{host}-{}", std::process::id())
}

/// `--env-sampling` values.
#[derive(Clone, Copy, clap::ValueEnum)]
enum EnvSampling {
    Uniform,
    Cosine,
    Importance,
}

impl From<EnvSampling> for EnvSampler {
    fn from(s: EnvSampling) -> Self {
        match s {
            EnvSampling::Uniform => EnvSampler::Uniform,
            EnvSampling::Cosine => EnvSampler::Cosine,
            EnvSampling::Importance => EnvSampler::Importance,
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // A misspelt width setting would otherwise go unnoticed: the walks ignore it.
    let simd = std::env::var_os(tessera::geometry::bvh8::SIMD_VARIABLE);
    if let Err(e) = tessera::geometry::bvh8::narrow_walks_asked(simd.as_deref()) {
        say!("warning: {e}");
    }
    let result = match cli.command {
        Command::Render(args) => render(&args),
        Command::Work {
            server,
            token,
            name,
            threads,
            tags,
            max_tiles,
            exit_with_parent,
            cache_dir,
            cache_mb,
            mesh_cache_mb,
        } => {
            if exit_with_parent {
                farm::exit_with_parent();
            }
            if threads == Some(0) {
                say!("error: --threads must be at least 1");
                return ExitCode::FAILURE;
            }
            let name = name.unwrap_or_else(default_worker_name);
            let tags = match tessera::protocol::check_tags(&tags) {
                Ok(tags) => tags,
                Err(e) => {
                    say!("error: --tags: {e}");
                    return ExitCode::FAILURE;
                }
            };
            work_caches(cache_dir, cache_mb, mesh_cache_mb).and_then(|(files, meshes)| {
                farm::work(farm::WorkOptions { server, token, name, threads, tags, max_tiles, files, meshes })
            })
        }
        Command::Tonemap { input, out, scene, camera, key, burn, saturation, gamma, operator } => {
            tonemap_params(scene.as_deref(), camera, operator).and_then(|(scene_operator, base)| {
                let params = Photographic {
                    key: key.unwrap_or(base.key),
                    burn_percent: burn.unwrap_or(base.burn_percent),
                    saturation: saturation.unwrap_or(base.saturation),
                    gamma: gamma.unwrap_or(base.gamma),
                };
                tonemap_file(&input, &out, operator.unwrap_or(scene_operator), &params)
            })
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            say!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// The caches of `work`: job files on disk (`--cache-dir`, `--cache-mb`) and meshes in memory
/// (`--mesh-cache-mb`).
fn work_caches(
    cache_dir: Option<PathBuf>,
    cache_mb: u64,
    mesh_cache_mb: u64,
) -> Result<(std::sync::Arc<filecache::FileCache>, std::sync::Arc<tessera::scene::cache::MeshCache>)> {
    let limit = cache_mb.checked_mul(1 << 20).ok_or_else(|| {
        anyhow::anyhow!(
            "--cache-mb {cache_mb} (TESSERA_WORKER_CACHE_MB) is too large; give a number of MiB such as 2048"
        )
    })?;
    let refused = |dir: &Path, e: anyhow::Error| {
        anyhow::anyhow!(
            "--cache-dir {} (TESSERA_WORKER_CACHE_DIR): {e:#}; give a directory this user may write",
            dir.display()
        )
    };
    let files = match cache_dir {
        Some(dir) => filecache::FileCache::open(&dir, limit).map_err(|e| refused(&dir, e))?,
        // The default place is a convenience: a worker whose home it cannot write (a container
        // with a read-only home, no HOME at all) keeps its files in the temporary directory.
        None => {
            let opened = match filecache::default_dir() {
                Some(dir) => filecache::FileCache::open(&dir, limit).map_err(|e| refused(&dir, e)),
                None => Err(anyhow::anyhow!("neither XDG_CACHE_HOME nor HOME is set")),
            };
            match opened {
                Ok(files) => files,
                Err(e) => {
                    // One place for every run, within the same bound: files verified on every read.
                    let fallback = std::env::temp_dir().join("tessera-worker-files");
                    let files =
                        filecache::FileCache::open(&fallback, limit).map_err(|e| refused(&fallback, e))?;
                    say!(
                        "warning: no default file cache ({e:#}); using {} (give --cache-dir DIR or TESSERA_WORKER_CACHE_DIR to keep files across runs)",
                        fallback.display()
                    );
                    files
                }
            }
        }
    };
    let meshes = tessera::scene::cache::MeshCache::new(mesh_cache_bytes(mesh_cache_mb)?);
    Ok((std::sync::Arc::new(files), std::sync::Arc::new(meshes)))
}

/// Prints `warnings` (unsupported elements too when they are allowed), then refuses the scene
/// if it has unsupported elements that are not: each one is printed as an error with its line.
/// The warnings printed so far, by line, element and message, with how many later scene files
/// repeated each (a sequence's frames share most of theirs: each is printed once).
type SeenWarnings = Vec<(String, String, usize)>;

fn report_warnings(
    scene_path: &Path,
    warnings: &[tessera::Warning],
    load: LoadOptions,
    seen: &mut SeenWarnings,
) -> Result<()> {
    for w in warnings.iter().filter(|w| load.allow_unsupported || !w.unsupported) {
        let key = format!("{:?} {:?} {}", w.loc.line, w.loc.element, w.message);
        match seen.iter_mut().find(|(k, _, _)| *k == key) {
            Some((_, _, n)) => *n += 1,
            None => {
                say!("{w}");
                seen.push((key, w.to_string(), 0));
            }
        }
    }
    if let Err(errors) = load.check(warnings) {
        for e in &errors {
            say!("error: {e}");
        }
        bail!(
            "{}: {} element(s) that change the picture are not supported (listed above); nothing was rendered",
            scene_path.display(),
            errors.len()
        );
    }
    Ok(())
}

/// Where one scene file's time went (`--timings`).
#[derive(Default)]
struct FrameTimings {
    /// Reading and parsing the scene file.
    parse: f64,
    /// Building it (assets, meshes, the top level): `Scene::stats.build_seconds`.
    build: f64,
    /// Of which the meshes (PLY files read and parsed, their BVHs built).
    mesh: f64,
    meshes: usize,
    meshes_cached: usize,
    /// Of which the top-level tree over the instances.
    top_level: f64,
    /// Whether its world-space tree of static mesh instances came from the cache.
    top_level_cached: bool,
    render: f64,
    write: f64,
}

impl FrameTimings {
    fn line(&self, scene: &Path) -> String {
        format!(
            "timings: {}: parse {:.3} s, build {:.3} s (meshes {:.3} s, {} of {} from the cache; top level {:.3} s{}), render {:.3} s, write {:.3} s",
            scene.display(),
            self.parse,
            self.build,
            self.mesh,
            self.meshes_cached,
            self.meshes,
            self.top_level,
            if self.top_level_cached { ", its world tree from the cache" } else { "" },
            self.render,
            self.write
        )
    }

    fn json(&self, scene: &Path) -> String {
        serde_json::json!({
            "scene": scene.display().to_string(),
            "parse_seconds": self.parse,
            "build_seconds": self.build,
            "mesh_seconds": self.mesh,
            "meshes": self.meshes,
            "meshes_cached": self.meshes_cached,
            "top_level_seconds": self.top_level,
            "top_level_cached": self.top_level_cached,
            "render_seconds": self.render,
            "write_seconds": self.write,
        })
        .to_string()
    }
}

fn render(args: &RenderArgs) -> Result<()> {
    let RenderArgs { ref scenes, threads, samples, tile_size, noise_target, pass_samples, .. } = *args;
    if samples == Some(0) {
        bail!("--samples must be at least 1");
    }
    if pass_samples == Some(0) {
        bail!("--pass-samples must be at least 1");
    }
    if let Some(t) = noise_target {
        tessera::passes::check_noise_target(t).map_err(|e| anyhow::anyhow!("--noise-target: {e}"))?;
    }
    if tile_size == 0 {
        bail!("--tile-size must be at least 1");
    }
    if let Some(s) = args.scale {
        tessera::camera::check_scale(s).map_err(|e| anyhow::anyhow!("--scale {e}"))?;
    }
    // One scene file has no next one to keep anything for: it is built as before, without
    // hashing its files.
    let limit = mesh_cache_bytes(args.mesh_cache_mb)?;
    let cache = (scenes.len() > 1).then(|| tessera::scene::cache::MeshCache::new(limit));
    // The denoiser is found before anything is read or rendered: a missing library must not
    // cost a render.
    let oidn = if args.denoise {
        Some(tessera_denoise::oidn().map_err(|e| anyhow::anyhow!("--denoise: {e}"))?)
    } else {
        None
    };
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        if n == 0 {
            bail!("--threads must be at least 1");
        }
        pool = pool.num_threads(n);
    }
    let pool = pool.build().context("cannot start the render threads")?;
    pool.install(|| -> Result<()> {
        // Which scene wrote each output file so far: a later scene writing the same name is
        // worth a warning (its image replaces the earlier one).
        let mut written_by: std::collections::HashMap<PathBuf, PathBuf> = Default::default();
        let mut seen = SeenWarnings::new();
        for scene_path in scenes {
            let t = render_scene(args, scene_path, cache.as_ref(), oidn, &mut written_by, &mut seen)?;
            if args.timings {
                println!("{}", t.line(scene_path));
            }
            if args.timings_json {
                println!("{}", t.json(scene_path));
            }
        }
        // What later scene files repeated, once each at the end.
        for (_, first, n) in seen.iter().filter(|(_, _, n)| *n > 0) {
            let frames =
                if *n == 1 { "1 more scene file".to_string() } else { format!("{n} more scene files") };
            say!("{first} (and in {frames})");
        }
        Ok(())
    })
}

/// Renders the cameras of one scene file (all, or --camera) with the meshes and images of
/// `cache` (when there are several files), and writes their images.
fn render_scene(
    args: &RenderArgs,
    scene_path: &Path,
    cache: Option<&tessera::scene::cache::MeshCache>,
    oidn: Option<&'static tessera_denoise::Oidn>,
    written_by: &mut std::collections::HashMap<PathBuf, PathBuf>,
    seen: &mut SeenWarnings,
) -> Result<FrameTimings> {
    let RenderArgs {
        ref out,
        camera,
        tile_size,
        samples,
        env_sampling,
        quiet,
        allow_unsupported,
        noise_target,
        pass_samples,
        ..
    } = *args;
    let out = out.as_path();
    let env_sampling = env_sampling.map(EnvSampler::from);
    let load = LoadOptions { allow_unsupported };
    let mut timings = FrameTimings::default();
    let t0 = Instant::now();
    // Parse first and show the parser's warnings even if building then fails.
    let text = std::fs::read_to_string(scene_path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the scene file: {e}", scene_path.display()))?;
    let records = parse_scene(&text, scene_path)?;
    timings.parse = t0.elapsed().as_secs_f64();
    // Unsupported elements the parser finds are refused before any asset is read.
    report_warnings(scene_path, &records.warnings, load, seen)?;
    let resolver = FsResolver::for_scene(scene_path);
    let mut scene = match cache {
        Some(cache) => build_scene_cached(&records, &resolver, cache)?,
        None => build_scene(&records, &resolver)?,
    };
    if let Some(s) = args.scale {
        scene.cameras = scene.cameras.iter().map(|c| c.scaled(s)).collect();
    }
    report_warnings(scene_path, &scene.warnings[records.warnings.len()..], load, seen)?;
    timings.build = scene.stats.build_seconds;
    timings.mesh = scene.stats.mesh_seconds;
    timings.meshes = records.meshes.len();
    timings.meshes_cached = scene.stats.meshes_cached;
    timings.top_level = scene.stats.accel_seconds;
    timings.top_level_cached = scene.stats.world_tree_cached;
    say!(
        "loaded {} in {:.2} s: {} triangles, {} objects, {} camera(s)",
        scene_path.display(),
        t0.elapsed().as_secs_f64(),
        scene.stats.triangles,
        scene.stats.instances,
        scene.cameras.len()
    );
    let selected: Vec<usize> = match camera {
        Some(k) if k >= 1 && k <= scene.cameras.len() => vec![k - 1],
        Some(k) => {
            bail!(
                "--camera {k}: {} has {} camera(s), numbered from 1",
                scene_path.display(),
                scene.cameras.len()
            )
        }
        None => (0..scene.cameras.len()).collect(),
    };
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create the output directory {}", out.display()))?;
    let mut settings = RenderSettings { samples, env_sampling, ..RenderSettings::default() };
    if let Some(seed) = args.seed {
        settings.seed = seed;
    }
    for ci in selected {
        let cam = &scene.cameras[ci];
        let (files, notes) = output::plan(cam);
        for n in notes {
            say!("warning: {n}");
        }
        let bar = if quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
        bar.set_style(
            ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} tiles, {elapsed} elapsed, ETA {eta}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        bar.set_message(cam.image_name.clone());
        let t = Instant::now();
        let progress = |done: usize, total: usize| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        };
        let mut outcomes = None;
        let (img, aux, stats) = if let Some(target) = noise_target {
            let n = tessera::render::samples_per_pixel(&scene, ci, &settings);
            let plan = PassPlan {
                pass_samples: pass_samples
                    .map(tessera::passes::round_to_blocks)
                    .unwrap_or_else(|| tessera::passes::default_pass_samples(n)),
                noise_target: Some(target),
            };
            let f = render_camera_passes(&scene, ci, tile_size, &settings, plan, oidn.is_some(), &progress);
            outcomes = Some((n, f.tiles));
            (f.image, f.aux, f.stats)
        } else if oidn.is_some() {
            let (img, aux, stats) = render_camera_with_aux(&scene, ci, tile_size, &settings, &progress);
            (img, Some(aux), stats)
        } else {
            let (img, stats) = render_camera(&scene, ci, tile_size, &settings, &progress);
            (img, None, stats)
        };
        bar.finish_and_clear();
        let secs = t.elapsed().as_secs_f64();
        timings.render += secs;
        let t_write = Instant::now();
        let written = output::write(out, &img, &files)?;
        timings.write += t_write.elapsed().as_secs_f64();
        for w in &written {
            if let Some(earlier) = written_by.insert(w.path.clone(), scene_path.to_path_buf())
                && earlier != scene_path
            {
                say!(
                    "warning: {} from {} replaces the one {} wrote (both name it); give the scenes different ImageNames or render them into different --out folders",
                    w.path.display(),
                    scene_path.display(),
                    earlier.display()
                );
            }
        }
        let non_finite = img.pixels.iter().filter(|p| !is_finite_pixel(p)).count();
        if non_finite > 0 {
            say!(
                "warning: {}: {non_finite} pixel(s) came out NaN or infinite; they are kept in HDR files, left out of tone-mapping statistics and written black (NaN) or white (+inf) in PNGs",
                cam.image_name
            );
        }
        let names: Vec<String> = written.iter().map(|w| w.path.display().to_string()).collect();
        println!(
            "{}: {}x{}, {} spp, {:.3} s, {:.2} Mrays/s ({} primary, {} shadow, {} secondary)",
            names.join(" + "),
            cam.width,
            cam.height,
            samples.unwrap_or(cam.num_samples),
            secs,
            stats.total() as f64 / secs / 1e6,
            stats.primary,
            stats.shadow,
            stats.secondary
        );
        if let Some((n, tiles)) = outcomes {
            let name = output::samples_map_name(cam);
            let placed: Vec<_> = tiles.iter().map(|t| (t.rect, t.pixel_samples.as_slice())).collect();
            let rgb = output::samples_map(cam.width, cam.height, &placed, n);
            tessera::hdr_io::write_png_rgb8(&out.join(&name), cam.width, cam.height, &rgb)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let total: u64 = tiles.iter().map(|t| t.total_samples()).sum();
            let pixels = u64::from(cam.width) * u64::from(cam.height);
            let stopped = tiles.iter().filter(|t| t.samples < n).count();
            let stopped_pixels: usize =
                tiles.iter().map(|t| t.pixel_samples.iter().filter(|&&c| c < n).count()).sum();
            let mut noise: Vec<f64> = tiles.iter().filter_map(|t| t.error).collect();
            noise.sort_by(f64::total_cmp);
            let quantile = |q: f64| noise.get(((noise.len() as f64 - 1.0) * q).round() as usize).copied();
            let spread = match (quantile(0.1), quantile(0.5), quantile(0.9)) {
                (Some(a), Some(b), Some(c)) => format!("; tile noise 10/50/90 %: {a:.4} / {b:.4} / {c:.4}"),
                _ => String::new(),
            };
            println!(
                "{}: noise target {}: {:.2} samples per pixel on average of at most {n}; {stopped_pixels} of {pixels} pixels and {stopped} of {} tiles stopped early{spread}",
                out.join(&name).display(),
                noise_target.unwrap_or_default(),
                total as f64 / pixels.max(1) as f64,
                tiles.len()
            );
        }
        if let Some(oidn) = oidn {
            let (clean, secs) = oidn
                .denoise(&img, aux.as_ref(), tessera_denoise::Quality::High)
                .map_err(|e| anyhow::anyhow!("{}: denoising failed: {e}", cam.image_name))?;
            let written = output::write(out, &clean, &output::denoised_plan(cam))?;
            let names: Vec<String> = written.iter().map(|w| w.path.display().to_string()).collect();
            println!(
                "{}: denoised in {secs:.3} s (Intel Open Image Denoise {}, RT filter, high quality, albedo and normal)",
                names.join(" + "),
                oidn.version()
            );
        }
    }
    Ok(timings)
}

/// The tone-mapping defaults: the course's, or a scene camera's `<Tonemap>`.
/// The operator and parameters `tonemap` starts from: the course defaults, or with a scene the
/// chosen camera's `<Tonemap>` (the one of `wanted`'s operator when it has one, else its first).
fn tonemap_params(
    scene: Option<&Path>,
    camera: Option<usize>,
    wanted: Option<Operator>,
) -> Result<(Operator, Photographic)> {
    let defaults = (Operator::default(), Photographic::default());
    let Some(path) = scene else { return Ok(defaults) };
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("{}: cannot read the scene file: {e}", path.display()))?;
    let records = parse_scene(&text, path)?;
    let cams = &records.cameras;
    let cam = match camera {
        Some(k) if k >= 1 && k <= cams.len() => &cams[k - 1],
        Some(k) => bail!("--camera {k}: {} has {} camera(s), numbered from 1", path.display(), cams.len()),
        None => match cams.iter().find(|c| !c.tonemaps.is_empty()) {
            Some(c) => c,
            None => {
                say!("warning: {} has no <Tonemap>; using the course defaults", path.display());
                return Ok(defaults);
            }
        },
    };
    let chosen = match wanted {
        Some(op) => cam.tonemaps.iter().find(|t| t.operator == op).or(cam.tonemaps.first()),
        None => cam.tonemaps.first(),
    };
    match chosen {
        Some(t) => Ok((t.operator, t.params)),
        None => {
            say!(
                "warning: camera {} of {} has no <Tonemap>; using the course defaults",
                cam.id,
                path.display()
            );
            Ok(defaults)
        }
    }
}

/// `tonemap`: reads an HDR image, tone-maps it, writes the PNG and prints one summary line.
fn tonemap_file(input: &Path, out: &Path, operator: Operator, params: &Photographic) -> Result<()> {
    params.validate().map_err(|e| anyhow::anyhow!("{e}"))?;
    let t = Instant::now();
    let img = read_float_image(input)?;
    let (rgb, stats) = tonemap_with(&img, operator, params);
    write_png_rgb8(out, img.width, img.height, &rgb)?;
    let white = if stats.white.is_finite() {
        format!("white point L_white {:.6} (burn {}%)", stats.white, params.burn_percent)
    } else {
        format!("no white point (burn {}%)", params.burn_percent)
    };
    println!(
        "{}: {}x{} from {}, {operator}, key {}, saturation {}, gamma {}: log-average luminance {:.6}, {white}, {} non-finite pixel(s), {:.3} s",
        out.display(),
        img.width,
        img.height,
        input.display(),
        params.key,
        params.saturation,
        params.gamma,
        stats.log_average,
        stats.non_finite,
        t.elapsed().as_secs_f64()
    );
    if stats.non_finite > 0 {
        say!(
            "warning: {}: {} pixel(s) hold NaN or infinite values; they are left out of the statistics (NaN written black, +inf white)",
            input.display(),
            stats.non_finite
        );
    }
    Ok(())
}
