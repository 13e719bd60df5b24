//! `tessera`: the command-line client of a Tessera render farm.
//!
//! `submit` takes one scene file or a sequence of them (`pack.rs`: each parsed by the library,
//! not built, with every file its build would read found on disk), sends the files by content
//! (`upload.rs`: only those the server lacks, then the job as JSON; a single scene as a bundle to
//! an older server), and with `--wait` follows the job (`follow.rs`) and downloads its outputs,
//! the files `tessera-worker render` would write, and its video. `status`, `cancel`, `fetch` and
//! `logs` speak the job API (`api.rs`). The server and token come from flags, the environment or
//! a config file (`config.rs`).

mod api;
mod config;
mod follow;
mod jobctl;
mod pack;
mod upload;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use tessera::protocol::{JobEvent, JobInfo, JobRequest, JobState, VideoKind};

use crate::api::{Api, CallError};

#[derive(Parser)]
#[command(
    name = "tessera",
    version,
    about = "Submit CENG795 scenes to a Tessera render farm, follow them and fetch the images",
    long_about = "Submit CENG795 scenes (XML or 2025 JSON) to a Tessera render farm (tessera-server), follow the jobs and fetch the images.\n\n\
The server and the API token come from --server and --token, else the environment (TESSERA_SERVER, TESSERA_TOKEN), \
else the config file ($XDG_CONFIG_HOME/tessera/client.toml, or ~/.config/tessera/client.toml, or --config), whose lines are\n  \
server = \"http://farm.example:8080\"\n  token = \"...\"\n\
and otherwise http://127.0.0.1:8080 without a token (a tessera-server started with no options).",
    after_help = "Examples:\n  \
tessera submit scenes/tori.xml --wait --out out/       # render on the farm; out/ gets what tessera-worker render writes\n  \
tessera submit big.xml --priority 5 --samples 4        # a quick preview, ahead of priority-0 jobs\n  \
tessera submit orbit/frame_*.json --wait --out orbit/  # a sequence as one job, frames and video\n  \
tessera status                                         # every job\n  \
tessera status 7                                       # one job, frame by frame\n  \
tessera logs 7 --follow                                # its events as they happen\n  \
tessera fetch 7 --out out/                             # download the outputs of a finished job\n  \
tessera cancel 7\n\n\
See 'tessera help submit' (and the other commands) for every option."
)]
struct Cli {
    /// The farm's URL [default: the config file's server, else http://127.0.0.1:8080].
    #[arg(long, short = 's', global = true, env = "TESSERA_SERVER", value_name = "URL")]
    server: Option<String>,
    /// The farm's API token (tessera-server --api-token), sent as "Authorization: Bearer TOKEN"
    /// [default: the config file's token, else none].
    #[arg(long, global = true, env = "TESSERA_TOKEN", value_name = "TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// The config file to read instead of $XDG_CONFIG_HOME/tessera/client.toml
    /// (~/.config/tessera/client.toml).
    #[arg(long, global = true, env = "TESSERA_CONFIG", value_name = "FILE")]
    config: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

/// `--video`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum VideoArg {
    Mp4,
    Gif,
    None,
}

impl VideoArg {
    fn kind(self) -> VideoKind {
        match self {
            VideoArg::Mp4 => VideoKind::Mp4,
            VideoArg::Gif => VideoKind::Gif,
            VideoArg::None => VideoKind::None,
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Submit one scene, or a sequence of scene files as one job, and optionally wait for the
    /// images (and the video).
    ///
    /// Each scene file is parsed here (not rendered): every PLY model, binary data file, texture
    /// and environment map it names is found on disk as tessera-worker render finds it (relative
    /// to the scene file, with the course's path fallbacks). A scene that cannot be parsed or
    /// names a file that is not there is reported with its file, line and element (and for a
    /// sequence its frame), and nothing is uploaded.
    ///
    /// Several scene files make one job whose frames are their cameras in the order given (a
    /// shell glob of zero-padded names, a_*.json, gives frame order), with a video made of the
    /// frames by default (--video). Files are sent by content: the server is asked which it lacks
    /// (by SHA-256) and only those are uploaded, so a PLY every frame shares, or one an earlier
    /// job sent, is sent once.
    ///
    /// With --wait the job is followed (a bar per frame, or one for a sequence's frames), and its
    /// outputs are downloaded into --out: the same files, byte for byte, as
    /// `tessera-worker render SCENE... --out DIR` writes (--float-exr adds the float frame the
    /// farm keeps for .png images), and the video.
    ///
    /// Example: tessera submit scenes/tori.xml --wait --out out/
    ///
    /// Example: tessera submit orbit/davids_camera_*.json --samples 4 --wait --out orbit/
    Submit {
        /// The scene files (CENG795 XML or 2025 JSON, told apart by content), in frame order.
        #[arg(required = true, value_name = "SCENE")]
        scenes: Vec<PathBuf>,
        /// Priority: jobs with a higher one are rendered first (negative allowed).
        #[arg(long, short, default_value_t = 0, allow_negative_numbers = true, value_name = "N")]
        priority: i64,
        /// Samples per pixel for every camera instead of its <NumSamples> (as tessera-worker render
        /// --samples).
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
        samples: Option<u32>,
        /// Tile edge in pixels (the farm's unit of work; does not change the image, except under a
        /// noise target, which decides tile by tile) [default: the
        /// server's].
        #[arg(long, value_name = "PX", value_parser = clap::value_parser!(u32).range(1..=4096))]
        tile_size: Option<u32>,
        /// Render only these cameras of each scene file (numbered from 1 in the file), e.g. 1,3.
        #[arg(long, value_name = "K,K,...")]
        cameras: Option<String>,
        /// A name for the job [default: the (first) scene's file name].
        #[arg(long, value_name = "NAME")]
        name: Option<String>,
        /// Render even if the scene uses elements Tessera does not implement and whose absence
        /// changes the picture (the server refuses such a scene otherwise, naming each element).
        #[arg(long)]
        allow_unsupported: bool,
        /// Also write each image denoised by the server (Intel Open Image Denoise):
        /// <stem>_denoised.exr and its PNG, beside the course's outputs (downloaded with --wait).
        /// The server refuses the job (422) if it has no denoiser.
        #[arg(long)]
        denoise: bool,
        /// Samples per pass (whole blocks of 16; default: a sixteenth of the samples, at least 256
        /// without --noise-target). Each
        /// tile's passes go to workers on their own, and the frame is published after every pass
        /// (pass.exr, pass.png; --wait reports them).
        #[arg(long, value_name = "N")]
        pass_samples: Option<u32>,
        /// Stop sampling a tile once its estimated relative noise is at most this, in (0, 1]
        /// (e.g. 0.02); the samples become a cap.
        #[arg(long, value_name = "ERROR")]
        noise_target: Option<f64>,
        /// Render at this scale, in (0, 1], for a quick low-resolution look: each side of the
        /// image times the scale, rounded to the nearest pixel (halves up), at least 1 (0.25
        /// renders an 800x450 camera at 200x113); the picture is the same, coarser, and the
        /// same bits as `tessera-worker render --scale` gives.
        #[arg(long, value_name = "FACTOR", value_parser = parse_scale)]
        scale: Option<f64>,
        /// Follow the job until it ends and download its outputs into --out.
        #[arg(long, short)]
        wait: bool,
        /// Where --wait puts the outputs (created if missing; implies --wait) [default: the current
        /// directory, as tessera-worker render].
        #[arg(long, short, value_name = "DIR")]
        out: Option<PathBuf>,
        /// With --wait: also download the float frame (.exr) the farm keeps beside each .png image.
        #[arg(long)]
        float_exr: bool,
        /// The video made of the frames once all are done: mp4 (H.264, made by the server's
        /// ffmpeg), gif, or none [default: mp4 for a sequence of several scene files, none for
        /// one; a GIF when the server has no ffmpeg and --video was not given].
        #[arg(long, value_enum, value_name = "KIND")]
        video: Option<VideoArg>,
        /// Frames a second of the video [default: 30, the course's].
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=120))]
        fps: Option<u32>,
        /// Keep only the PNG of each frame on the server, not the float frame (.exr) it keeps
        /// beside it by default for a job of one scene (--float-exr then has nothing to
        /// download).
        #[arg(long, conflicts_with = "keep_float")]
        no_keep_float: bool,
        /// Keep each frame's float frame (.exr, losslessly compressed) beside its PNG on the
        /// server also for a sequence, which by default keeps only the PNGs.
        #[arg(long)]
        keep_float: bool,
        /// Render only on workers that have this tag (tessera-worker work --tags); repeat it, or
        /// separate tags with commas, for workers that have them all. Letters, digits, '-', '_'
        /// and '.', at most 32 each.
        #[arg(long = "worker-tag", value_name = "TAG", value_delimiter = ',')]
        worker_tags: Vec<String>,
        /// Parse the scenes, find their files and list them (job path, size, role, file on disk),
        /// without hashing or submitting anything.
        #[arg(long)]
        dry_run: bool,
        /// Say how long finding and hashing the files took, and list the files uploaded.
        #[arg(long, short)]
        verbose: bool,
        /// No progress bars or messages: print only the job id (and with --wait the files
        /// written); errors still go to stderr.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Show one job (state, frames, tiles, files) or, without an id, list every job.
    Status {
        /// The job; omit it to list every job, newest first.
        id: Option<u64>,
        /// Print the server's JSON answer instead (for scripts).
        #[arg(long)]
        json: bool,
    },
    /// Cancel a job: its queued tiles are dropped and tiles being rendered stop within a moment.
    Cancel {
        /// The job to cancel.
        id: u64,
    },
    /// Download the outputs of a job's finished frames into a directory.
    ///
    /// The files are those tessera-worker render writes (--float-exr adds the float frame the farm
    /// keeps for .png images). A frame not finished yet is an error after the others are
    /// downloaded; --wait follows the job to its end first.
    Fetch {
        /// The job.
        id: u64,
        /// Where to put the files (created if missing).
        #[arg(long, short, default_value = ".", value_name = "DIR")]
        out: PathBuf,
        /// Follow the job until it ends first (progress bars on a terminal).
        #[arg(long, short)]
        wait: bool,
        /// Also download the float frame (.exr) the farm keeps beside each .png image.
        #[arg(long)]
        float_exr: bool,
        /// No progress bars or messages; the files written still go to stdout.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Delete a finished (done, failed or cancelled) job with its outputs; a job still queued,
    /// running or paused must be cancelled first.
    Delete {
        /// The job to delete.
        id: u64,
    },
    /// Pause a queued or running job: no more of its tiles are handed out; tiles being
    /// rendered finish and are kept. `tessera resume` goes on.
    Pause {
        /// The job to pause.
        id: u64,
    },
    /// Resume a paused job.
    Resume {
        /// The job to resume.
        id: u64,
    },
    /// Render a finished job again without submitting it again: a failed or cancelled job's
    /// unfinished frames (with fresh retry counts), or with --frames, those frames of any
    /// finished job (their outputs replaced when done; a sequence's video made again).
    Requeue {
        /// The job to requeue.
        id: u64,
        /// Frames to render again, numbered from 0 as `tessera status ID` lists them: indexes
        /// and ranges separated by commas, e.g. 0-9,12.
        #[arg(long, value_name = "LIST", value_parser = jobctl::check_frames)]
        frames: Option<String>,
    },
    /// Change the priority of a job that has not ended (higher first); its next tiles are handed
    /// out by it.
    Priority {
        /// The job.
        id: u64,
        /// The new priority (any integer; submissions default to 0).
        #[arg(allow_negative_numbers = true)]
        priority: i64,
    },
    /// List the farm's workers: state (idle, rendering, lost), mode, current tile, tiles done.
    Workers {
        /// Print the server's JSON answer instead (for scripts).
        #[arg(long)]
        json: bool,
    },
    /// Drain, disable or enable a worker (its id as `tessera workers` lists it).
    ///
    /// drain: it finishes the tiles it holds and takes no new one; disable: it takes nothing and
    /// the tiles it holds go back to the queue at once; enable: it takes work again.
    Worker {
        #[arg(value_parser = ["drain", "disable", "enable"])]
        action: String,
        /// The worker's id.
        id: u64,
    },
    /// Print a job's event log: acceptance, warnings, tiles done or failed, merges, the end.
    Logs {
        /// The job.
        id: u64,
        /// Keep printing new events until the job ends.
        #[arg(long, short)]
        follow: bool,
        /// Print only events after this sequence number.
        #[arg(long, default_value_t = 0, value_name = "SEQ")]
        after: u64,
    },
}

/// Ctrl-C while the client follows a job: a word on what goes on, then the usual exit (130).
mod interrupt {
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// The message, written by the signal handler (only `write` and `_exit` there, which are
    /// safe in a handler): a fixed buffer and its length, set before the handler is installed.
    static mut MESSAGE: [u8; 512] = [0; 512];
    static LENGTH: AtomicUsize = AtomicUsize::new(0);

    extern "C" fn on_sigint(_: libc::c_int) {
        let n = LENGTH.load(Ordering::SeqCst);
        // SAFETY: MESSAGE is written only before the handler is installed; write and _exit are
        // async-signal-safe.
        unsafe {
            let buffer = &raw const MESSAGE;
            libc::write(2, buffer.cast(), n);
            libc::_exit(130);
        }
    }

    /// From now on, Ctrl-C prints `message` on stderr and exits with status 130.
    pub fn say_on_ctrl_c(message: &str) {
        #[cfg(unix)]
        {
            let bytes = message.as_bytes();
            let n = bytes.len().min(512);
            // SAFETY: no handler reads MESSAGE yet (it is installed below, once).
            unsafe {
                let buffer = &raw mut MESSAGE;
                std::ptr::copy_nonoverlapping(bytes.as_ptr(), buffer.cast::<u8>(), n);
            }
            LENGTH.store(n, Ordering::SeqCst);
            // SAFETY: installing a handler that only writes and exits.
            unsafe {
                libc::signal(libc::SIGINT, on_sigint as *const () as libc::sighandler_t);
            }
        }
    }
}

fn main() -> ExitCode {
    // Output cut off by its reader (`tessera logs 6 | head -1`) ends the client quietly, as it
    // ends other Unix tools, instead of a panic in the next print. Its sockets are unaffected:
    // the standard library writes to them with MSG_NOSIGNAL (Linux) or SO_NOSIGPIPE.
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to the default, before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// The API client for the server and token the flags, environment or config file name.
fn connect(cli_server: Option<&str>, cli_token: Option<&str>, config: Option<&Path>) -> Result<Api> {
    let default = config::default_config_path(
        std::env::var("XDG_CONFIG_HOME").ok().as_deref(),
        std::env::var("HOME").ok().as_deref(),
    );
    let hint = config
        .map(Path::to_path_buf)
        .or_else(|| default.clone())
        .map_or("the config file".to_string(), |p| p.display().to_string());
    let r = config::resolve(cli_server, cli_token, config, default)?;
    Ok(Api::new(r.server, r.token, hint))
}

fn run(cli: Cli) -> Result<ExitCode> {
    let Cli { server, token, config, command } = cli;
    let connect = || connect(server.as_deref(), token.as_deref(), config.as_deref());
    match command {
        Command::Submit {
            scenes,
            priority,
            samples,
            tile_size,
            cameras,
            name,
            allow_unsupported,
            denoise,
            pass_samples,
            noise_target,
            scale,
            wait,
            out,
            float_exr,
            video,
            fps,
            no_keep_float,
            keep_float,
            worker_tags,
            dry_run,
            verbose,
            quiet,
        } => {
            let cameras = parse_cameras(cameras.as_deref())?;
            let opts = SubmitOptions {
                priority,
                samples,
                tile_size,
                cameras: cameras.clone(),
                name,
                allow_unsupported,
                denoise,
                pass_samples,
                noise_target,
                video: video.map(VideoArg::kind),
                fps,
                keep_float: if keep_float { Some(true) } else { no_keep_float.then_some(false) },
                scale,
                worker_tags: tessera::protocol::check_tags(&worker_tags)
                    .map_err(|e| anyhow::anyhow!("--worker-tag: {e}"))?,
                quiet,
                verbose,
            };
            // Everything local first: scenes that cannot be packed never reach the network.
            let pack_opts =
                pack::PackOptions { allow_unsupported, skip_hash: dry_run, cameras: cameras.as_deref() };
            let packed = pack::pack(&scenes, pack_opts)?;
            if dry_run {
                print_packed(&packed);
                return Ok(ExitCode::SUCCESS);
            }
            let api = connect()?;
            let job = submit(&api, &packed, &opts)?;
            if !(wait || out.is_some()) {
                // (--wait says it while it follows the job.)
                if let (Some(w), false) = (&job.waiting_for, quiet) {
                    eprintln!("job {} waits: {w}", job.id);
                }
                return Ok(ExitCode::SUCCESS);
            }
            let out = out.unwrap_or_else(|| PathBuf::from("."));
            finish(&api, job.id, &out, float_exr, quiet)
        }
        Command::Status { id, json } => {
            let api = connect()?;
            match id {
                Some(id) => {
                    let job = api.job(id)?;
                    if json {
                        println!("{}", serde_json::to_string_pretty(&job)?);
                    } else {
                        print_job(&job);
                    }
                }
                None => {
                    let list = api.jobs()?;
                    if json {
                        println!("{}", serde_json::to_string_pretty(&list)?);
                    } else {
                        print_jobs(&list.jobs, &api.base);
                    }
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Delete { id } => {
            let api = connect()?;
            api.delete(id)?;
            println!("job {id} deleted with its files");
            Ok(ExitCode::SUCCESS)
        }
        Command::Pause { id } => {
            jobctl::pause(&connect()?, id)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Resume { id } => {
            jobctl::resume(&connect()?, id)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Requeue { id, frames } => {
            jobctl::requeue(&connect()?, id, frames.as_deref())?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Priority { id, priority } => {
            jobctl::priority(&connect()?, id, priority)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Workers { json } => {
            let api = connect()?;
            let list = api.workers()?;
            if json {
                println!("{}", serde_json::to_string_pretty(&list)?);
            } else if list.workers.is_empty() {
                println!("no workers have registered with {}", api.base);
            } else {
                println!(
                    "{:>4}  {:<24} {:>7}  {:<9} {:<8} {:<12} {:>10}  current tile",
                    "id", "name", "threads", "state", "mode", "tags", "tiles done"
                );
                for w in &list.workers {
                    let tile = w.current_tile.as_ref().map_or(String::new(), |t| {
                        format!("job {} frame {} tile {}", t.job, t.frame, t.tile)
                    });
                    let tags = if w.tags.is_empty() { "-".to_string() } else { w.tags.join(",") };
                    println!(
                        "{:>4}  {:<24} {:>7}  {:<9} {:<8} {:<12} {:>10}  {tile}",
                        w.id, w.name, w.threads, w.state, w.mode, tags, w.tiles_done
                    );
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Worker { action, id } => {
            let api = connect()?;
            let w = api.worker_action(id, &action)?;
            let what = match w.mode.as_str() {
                "draining" => "finishes the tiles it holds and takes no new one",
                "disabled" => "takes no work; the tiles it held are queued again",
                _ => "takes work",
            };
            println!("worker {id} ({}) is {}: it {what}", w.name, w.mode);
            Ok(ExitCode::SUCCESS)
        }
        Command::Cancel { id } => {
            let api = connect()?;
            let job = api.cancel(id)?;
            println!("job {id} ({}): {}", job.name, job.state.as_str());
            Ok(ExitCode::SUCCESS)
        }
        Command::Fetch { id, out, wait, float_exr, quiet } => {
            let api = connect()?;
            if wait {
                return finish(&api, id, &out, float_exr, quiet);
            }
            let job = api.job(id)?;
            follow::download(&api, &job, &out, float_exr, quiet)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Logs { id, follow, after } => {
            let api = connect()?;
            logs(&api, id, follow, after)?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

struct SubmitOptions {
    priority: i64,
    samples: Option<u32>,
    tile_size: Option<u32>,
    cameras: Option<Vec<u32>>,
    name: Option<String>,
    allow_unsupported: bool,
    denoise: bool,
    pass_samples: Option<u32>,
    noise_target: Option<f64>,
    video: Option<VideoKind>,
    fps: Option<u32>,
    keep_float: Option<bool>,
    scale: Option<f64>,
    /// Tags a worker must all have (`--worker-tag`, checked).
    worker_tags: Vec<String>,
    quiet: bool,
    verbose: bool,
}

/// `--scale`: a number in (0, 1].
fn parse_scale(text: &str) -> Result<f64, String> {
    let v: f64 =
        text.trim().parse().map_err(|_| format!("{text:?} is not a number; write e.g. --scale 0.25"))?;
    tessera::camera::check_scale(v)
}

/// `--cameras` as camera numbers (from 1); each scene is checked against them before anything
/// is uploaded (`pack`).
fn parse_cameras(list: Option<&str>) -> Result<Option<Vec<u32>>> {
    let Some(list) = list else { return Ok(None) };
    let mut ks = Vec::new();
    for part in list.split([',', ' ']).filter(|p| !p.is_empty()) {
        let k: u32 = part.parse().ok().filter(|k| *k >= 1).ok_or_else(|| {
            anyhow::anyhow!(
                "--cameras: {part:?} is not a camera number (1, 2, ...); write e.g. --cameras 1,3"
            )
        })?;
        ks.push(k);
    }
    if ks.is_empty() {
        bail!("--cameras is empty; write e.g. --cameras 1,3, or leave it out to render every camera");
    }
    Ok(Some(ks))
}

fn human_bytes(n: u64) -> String {
    if n >= 1 << 20 {
        format!("{:.1} MiB", n as f64 / f64::from(1 << 20))
    } else if n >= 1 << 10 {
        format!("{:.1} KiB", n as f64 / f64::from(1 << 10))
    } else {
        format!("{n} B")
    }
}

/// `--dry-run`: the warnings, then each path of the job with its size, role and file on disk.
fn print_packed(packed: &pack::Packed) {
    for w in &packed.warnings {
        eprintln!("{w}");
    }
    for (path, e) in &packed.entries {
        let d = &packed.distinct[e.file];
        let role = if e.scene { "scene" } else { "asset" };
        println!("{path}\t{}\t{role}\t{}", d.size, d.source.display());
    }
    eprintln!(
        "{} scene file(s), {} file(s), {}; nothing was submitted (--dry-run)",
        packed.scenes.len(),
        packed.distinct.len(),
        human_bytes(packed.total_bytes())
    );
}

/// The job's options as multipart fields (for a server without JSON submissions).
fn multipart_fields(scene_path: &str, opts: &SubmitOptions) -> Vec<(&'static str, String)> {
    let mut fields = vec![("scene_path", scene_path.to_string()), ("priority", opts.priority.to_string())];
    if let Some(n) = &opts.name {
        fields.push(("name", n.clone()));
    }
    if let Some(s) = opts.samples {
        fields.push(("samples", s.to_string()));
    }
    if let Some(t) = opts.tile_size {
        fields.push(("tile_size", t.to_string()));
    }
    if let Some(c) = &opts.cameras {
        fields.push(("cameras", c.iter().map(u32::to_string).collect::<Vec<_>>().join(",")));
    }
    if opts.allow_unsupported {
        fields.push(("allow_unsupported", "true".to_string()));
    }
    if opts.denoise {
        fields.push(("denoise", "true".to_string()));
    }
    if let Some(p) = opts.pass_samples {
        fields.push(("pass_samples", p.to_string()));
    }
    if let Some(t) = opts.noise_target {
        fields.push(("noise_target", t.to_string()));
    }
    if let Some(v) = opts.video {
        fields.push(("video", v.as_str().to_string()));
    }
    if let Some(f) = opts.fps {
        fields.push(("fps", f.to_string()));
    }
    if let Some(k) = opts.keep_float {
        fields.push(("keep_float", k.to_string()));
    }
    if let Some(s) = opts.scale {
        fields.push(("scale", s.to_string()));
    }
    if !opts.worker_tags.is_empty() {
        fields.push(("worker_tags", opts.worker_tags.join(",")));
    }
    fields
}

/// A server older than content-addressed files: one scene goes as a multipart `.tar.gz`
/// bundle, as it always did.
fn submit_bundle(api: &Api, packed: &pack::Packed, opts: &SubmitOptions) -> Result<JobInfo> {
    if packed.scenes.len() > 1 {
        bail!(
            "the server at {} does not take sequences (it has no POST /api/v1/files/missing); upgrade it, or submit the {} scene files one at a time",
            api.base,
            packed.scenes.len()
        );
    }
    let tar = packed.tar_gz()?;
    let fields = multipart_fields(&packed.scenes[0].path, opts);
    let (content_type, head, tail) = api::multipart_frame(&fields, "bundle", "bundle.tar.gz");
    let length = (head.len() + tar.len() + tail.len()) as u64;
    if !opts.quiet {
        eprintln!(
            "the server takes bundles only (it is older than this client): packed {} with {} asset(s), {} to upload",
            packed.scenes[0].path,
            packed.entries.len() - 1,
            human_bytes(length)
        );
    }
    let body = std::io::Cursor::new(head).chain(std::io::Cursor::new(tar)).chain(std::io::Cursor::new(tail));
    if follow::bars_wanted(opts.quiet) {
        let bar = ProgressBar::new(length);
        bar.set_style(
            ProgressStyle::with_template("uploading [{bar:30}] {bytes}/{total_bytes}, {bytes_per_sec}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        let job = api.submit(&content_type, length, bar.wrap_read(body));
        bar.finish_and_clear();
        Ok(job?)
    } else {
        Ok(api.submit(&content_type, length, body)?)
    }
}

/// Sends the job's files the server lacks, submits it and prints what the server accepted.
fn submit(api: &Api, packed: &pack::Packed, opts: &SubmitOptions) -> Result<JobInfo> {
    for w in &packed.warnings {
        eprintln!("{w}");
    }
    if opts.verbose {
        eprintln!(
            "found {} file(s) of {} scene file(s) in {:.3} s, hashed {} in {:.3} s",
            packed.distinct.len(),
            packed.scenes.len(),
            packed.list_seconds,
            human_bytes(packed.total_bytes()),
            packed.hash_seconds
        );
    }
    let request = JobRequest {
        name: opts.name.clone(),
        priority: Some(opts.priority),
        tile_size: opts.tile_size,
        samples: opts.samples,
        cameras: opts.cameras.clone(),
        pass_samples: opts.pass_samples,
        noise_target: opts.noise_target,
        allow_unsupported: opts.allow_unsupported,
        denoise: opts.denoise,
        video: opts.video,
        fps: opts.fps,
        keep_float: opts.keep_float,
        scale: opts.scale,
        worker_tags: opts.worker_tags.clone(),
        ..JobRequest::default()
    };
    let bars = follow::bars_wanted(opts.quiet);
    let job = match upload::submit(api, packed, request, bars, !bars && !opts.quiet)? {
        upload::Submitted::Job(job, sent) => {
            if !opts.quiet {
                eprintln!("{sent}");
            }
            if opts.verbose {
                eprintln!(
                    "asked and uploaded in {:.3} s; the server took {:.3} s to check and accept the job",
                    sent.upload_seconds, sent.submit_seconds
                );
            }
            *job
        }
        upload::Submitted::OldServer => submit_bundle(api, packed, opts)?,
    };
    // The server's own reading of the scenes: only what was not shown before the upload.
    for w in pack::unseen_warnings(&packed.warnings, &job.warnings) {
        eprintln!("{w}");
    }
    if opts.quiet {
        println!("{}", job.id);
    } else {
        let tiles: u32 = job.frames.iter().map(|f| f.tiles_total).sum();
        let frames = job.frames.len().max(frame_total(&job) as usize);
        let video = match &job.video {
            Some(v) => format!(", then a {} video at {} fps", v.kind.as_str(), v.fps),
            None => String::new(),
        };
        println!(
            "submitted job {} ({}): {frames} frame(s), {tiles} tile(s){video}; follow it with `tessera status {}` or at {}/",
            job.id, job.name, job.id, api.base
        );
        if let Some(m) = job.video.as_ref().and_then(|v| v.message.as_ref()) {
            eprintln!("video: {m}");
        }
    }
    Ok(job)
}

/// Frames of a job by its counts (complete also when the server leaves `frames` out).
fn frame_total(job: &JobInfo) -> u32 {
    let c = &job.frame_counts;
    c.done + c.rendering + c.queued
}

/// Follows a job to its end and downloads its outputs; a job that failed or was cancelled is
/// an error (exit status 1).
fn finish(api: &Api, id: u64, out: &Path, float_exr: bool, quiet: bool) -> Result<ExitCode> {
    interrupt::say_on_ctrl_c(&format!(
        "\nstopped following job {id}; it goes on rendering on the farm. Follow it again with: tessera fetch {id} --wait --out {}\n",
        out.display()
    ));
    let job = follow::follow(api, id, follow::bars_wanted(quiet), quiet)?;
    match job.state {
        JobState::Done => {
            follow::download(api, &job, out, float_exr, quiet)?;
            Ok(ExitCode::SUCCESS)
        }
        JobState::Failed => {
            bail!("job {id} ({}) failed: {}", job.name, job.error.as_deref().unwrap_or("no reason given"))
        }
        JobState::Canceled => bail!("job {id} ({}) was cancelled; nothing to download", job.name),
        JobState::Queued | JobState::Running | JobState::Paused => {
            bail!("job {id} has not ended ({})", job.state.as_str())
        }
    }
}

fn job_tiles(job: &JobInfo) -> (u32, u32) {
    (job.frames.iter().map(|f| f.tiles_done).sum(), job.frames.iter().map(|f| f.tiles_total).sum())
}

/// ", pass 6 of 16, 96 spp, 37% of samples" for a frame under way ("" from a server that does
/// not count samples).
fn frame_samples(f: &tessera::protocol::FrameInfo) -> String {
    if f.samples_total == 0 {
        return String::new();
    }
    let (done, total) = follow::frame_work(f);
    format!(", {}, {}% of samples", follow::pass_note(f), follow::percent(done, total))
}

fn print_jobs(jobs: &[JobInfo], base: &str) {
    if jobs.is_empty() {
        println!("no jobs on {base}");
        return;
    }
    println!(
        "{:>5}  {:<8}  {:>4}  {:>15}  {:>11}  {:<19}  NAME",
        "ID", "STATE", "PRI", "TILES", "FRAMES", "SUBMITTED (UTC)"
    );
    for j in jobs {
        let (done, total) = job_tiles(j);
        // The percentage counts samples (tiles from a server that does not count them).
        let (work_done, work_total) = follow::job_work(j);
        let pct = follow::percent(work_done, work_total);
        // The counts are complete even when the list leaves the frames out.
        let frames = match frame_total(j) {
            0 => format!("{}", j.frames.len()),
            n => format!("{}/{n}", j.frame_counts.done),
        };
        println!(
            "{:>5}  {:<8}  {:>4}  {:>15}  {:>11}  {:<19}  {}",
            j.id,
            j.state.as_str(),
            j.priority,
            format!("{done}/{total} {pct:>3}%"),
            frames,
            follow::utc(j.submitted_at),
            j.name
        );
    }
    print_waiting(jobs);
}

/// The jobs that wait for a worker, each reason once: "jobs 3, 4: no worker is connected ...".
fn print_waiting(jobs: &[JobInfo]) {
    let mut reasons: Vec<(&str, Vec<u64>)> = Vec::new();
    for j in jobs {
        let Some(w) = j.waiting_for.as_deref() else { continue };
        match reasons.iter_mut().find(|(r, _)| *r == w) {
            Some((_, ids)) => ids.push(j.id),
            None => reasons.push((w, vec![j.id])),
        }
    }
    for (reason, ids) in reasons {
        let ids: Vec<String> = ids.iter().rev().map(u64::to_string).collect();
        let (which, verb) = if ids.len() == 1 { ("job", "waits") } else { ("jobs", "wait") };
        println!("{which} {} {verb}: {reason}", ids.join(", "));
    }
}

fn print_job(job: &JobInfo) {
    let (done, total) = job_tiles(job);
    println!("job {}: {}", job.id, job.name);
    let now = || {
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
    };
    let took = match (job.started_at, job.finished_at) {
        (Some(s), Some(e)) => format!(" in {:.1} s", e - s),
        (Some(s), None) => format!(", {:.1} s since it started", now() - s),
        (None, _) => String::new(),
    };
    // Progress by samples, pass by pass: the ETA from the rate of samples since the start.
    let (work_done, work_total) = follow::job_work(job);
    let mut progress = String::new();
    if job.samples_total > 0 && !job.state.is_final() {
        progress = format!(", {}% of samples", follow::percent(work_done, work_total));
        if let (JobState::Running, Some(s)) = (job.state, job.started_at) {
            let elapsed = std::time::Duration::from_secs_f64((now() - s).max(0.0));
            progress.push_str(&format!(
                ", {}",
                follow::eta_text(work_done, work_total, elapsed, job.samples_total_is_bound)
            ));
        }
    }
    println!("state: {} ({done}/{total} tiles){took}{progress}", job.state.as_str());
    println!("submitted: {} UTC", follow::utc(job.submitted_at));
    let samples = job.samples.map_or("the scene's".to_string(), |s| s.to_string());
    println!("priority {}, tile size {}, samples per pixel: {samples}", job.priority, job.tile_size);
    if follow::by_counts(job) {
        println!("frames: {} (of {} scene file(s))", follow::counts_line(job), job.scenes.max(1));
        // The frames under way, not hundreds of lines (--json lists every frame).
        let busy: Vec<_> = job
            .frames
            .iter()
            .filter(|f| f.outputs.is_empty() && (f.tiles_done > 0 || f.passes_done > 0))
            .collect();
        for f in busy.iter().take(8) {
            println!(
                "frame {}: {} ({}x{}), {}/{} tiles{}{}",
                f.index,
                f.image_name,
                f.width,
                f.height,
                f.tiles_done,
                f.tiles_total,
                f.scene.as_ref().map_or(String::new(), |s| format!(", from {s}")),
                frame_samples(f)
            );
        }
        if busy.len() > 8 {
            println!(
                "... and {} more frames under way (tessera status {} --json lists them all)",
                busy.len() - 8,
                job.id
            );
        }
    }
    let frames: &[tessera::protocol::FrameInfo] = if follow::by_counts(job) { &[] } else { &job.frames };
    for f in frames {
        println!(
            "frame {}: camera {}, {} ({}x{}), {}/{} tiles{}",
            f.index,
            f.camera + 1,
            f.image_name,
            f.width,
            f.height,
            f.tiles_done,
            f.tiles_total,
            if f.outputs.is_empty() { frame_samples(f) } else { String::new() }
        );
        if !f.outputs.is_empty() {
            let names: Vec<&str> = f.outputs.iter().map(|o| o.name.as_str()).collect();
            println!("  files: {}", names.join(", "));
        }
    }
    if let Some(v) = &job.video {
        let mut line = format!("video: {} at {} fps, {}", v.kind.as_str(), v.fps, v.state);
        if let Some(u) = &v.url {
            line.push_str(&format!(", {u}"));
        }
        if let Some(m) = &v.message {
            line.push_str(&format!(" ({m})"));
        }
        println!("{line}");
    }
    if !job.worker_tags.is_empty() {
        println!("worker tags: {} (only workers with them all render it)", job.worker_tags.join(", "));
    }
    if let Some(w) = &job.waiting_for {
        println!("waiting: {w}");
    }
    if let Some(e) = &job.error {
        println!("error: {e}");
    }
}

/// One log event on one line: time, kind, where (frame, tile, worker, seconds), message.
fn format_event(e: &JobEvent) -> String {
    let mut place = Vec::new();
    if let Some(f) = e.frame {
        place.push(format!("frame {f}"));
    }
    if let Some(t) = e.tile {
        place.push(format!("tile {t}"));
    }
    if let Some(w) = &e.worker {
        place.push(format!("worker {w}"));
    }
    if let Some(s) = e.seconds {
        place.push(format!("{s:.2} s"));
    }
    let place = if place.is_empty() { String::new() } else { format!("{}: ", place.join(", ")) };
    format!("{:>4} {} {:<16} {place}{}", e.seq, follow::utc(e.at), e.kind, e.message)
}

/// The event kinds after which a job's log has nothing more to say.
fn is_last_event(kind: &str) -> bool {
    matches!(kind, "job_done" | "job_failed" | "job_cancelled" | "job_canceled")
}

/// `logs`: prints the events after `after`; with `follow`, polls for more until the job ends.
fn logs(api: &Api, id: u64, follow: bool, mut after: u64) -> Result<()> {
    let fetch = |after: u64| -> Result<Vec<JobEvent>> {
        match api.log(id, after) {
            Ok(log) => Ok(log.events),
            Err(CallError::Status { code: 404, message }) if message.contains("no such endpoint") => bail!(
                "the server at {} has no job log (GET /api/v1/jobs/{id}/log): it is older than this client; use `tessera status {id}`",
                api.base
            ),
            Err(e) => Err(e.into()),
        }
    };
    let print = |events: Vec<JobEvent>, after: &mut u64| -> bool {
        let mut ended = false;
        for e in events {
            if e.seq <= *after {
                continue;
            }
            println!("{}", format_event(&e));
            *after = e.seq;
            ended |= is_last_event(&e.kind);
        }
        ended
    };
    let events = fetch(after)?;
    if print(events, &mut after) || !follow {
        return Ok(());
    }
    loop {
        std::thread::sleep(Duration::from_secs(1));
        let events = follow::with_retries(false, || api.log(id, after).map(|l| l.events))?;
        if print(events, &mut after) {
            return Ok(());
        }
        // A job that ended without a last event in its log: one more look, then stop.
        let job = follow::with_retries(false, || api.job(id))?;
        if job.state.is_final() {
            let events = fetch(after)?;
            print(events, &mut after);
            return Ok(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn cameras_are_camera_numbers() {
        assert_eq!(parse_cameras(None).unwrap(), None);
        assert_eq!(parse_cameras(Some("2, 1")).unwrap(), Some(vec![2, 1]));
        let e = parse_cameras(Some("0")).unwrap_err().to_string();
        assert!(e.contains("\"0\" is not a camera number"), "{e}");
        assert!(parse_cameras(Some(",")).is_err());
    }

    #[test]
    fn events_read_as_one_line() {
        let e = JobEvent {
            seq: 12,
            at: 0.0,
            kind: "tile_done".into(),
            frame: Some(0),
            tile: Some(3),
            worker: Some("w1".into()),
            worker_id: Some(1),
            seconds: Some(0.4213),
            message: "tile 3 rendered".into(),
        };
        assert_eq!(
            format_event(&e),
            "  12 1970-01-01 00:00:00 tile_done        frame 0, tile 3, worker w1, 0.42 s: tile 3 rendered"
        );
        let e =
            JobEvent { frame: None, tile: None, worker: None, seconds: None, kind: "accepted".into(), ..e };
        assert_eq!(format_event(&e), "  12 1970-01-01 00:00:00 accepted         tile 3 rendered");
    }
}
