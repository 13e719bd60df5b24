//! Test-only helpers shared by the tests of every crate (a dev-dependency; it depends on no
//! Tessera crate, so `tessera-common`'s own unit tests can use it too).
//!
//! The course corpus (scenes, assets, official images) is read from `../shared/scenes` beside
//! the repository, or from `$TESSERA_SCENES`. A test that needs it and finds it missing skips,
//! saying so, unless `TESSERA_REQUIRE_SCENES` is set (`.ci/run` sets it): then it fails, so CI
//! can never pass by skipping the corpus tests.
//!
//! Tests write into a [`TempDir`] of their own, removed when it drops, and judge 8-bit pictures
//! with [`rgb8`] (PNG reading and the comparison metrics).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

pub mod rgb8;

/// The repository root.
pub fn repo_root() -> PathBuf {
    // This crate sits at tests/testkit.
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.parent().and_then(Path::parent).unwrap_or(here).to_path_buf()
}

/// The course corpus: `$TESSERA_SCENES`, or `../shared/scenes` beside the repository.
pub fn shared_scenes() -> PathBuf {
    match std::env::var_os("TESSERA_SCENES") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => repo_root().join("../shared/scenes"),
    }
}

/// The speed anchors' workloads and scripts (`../shared/bench`): beside the course corpus.
pub fn shared_bench() -> PathBuf {
    shared_scenes().join("../bench")
}

/// The Python that runs the speed anchors (embreex, Mitsuba 3): `$TESSERA_ANCHORS_PY`, or the
/// venv `~/.cache/anchors` that ../shared/bench/README.md sets up.
pub fn anchor_python() -> PathBuf {
    match std::env::var_os("TESSERA_ANCHORS_PY") {
        Some(p) if !p.is_empty() => PathBuf::from(p),
        _ => PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache/anchors/bin/python"),
    }
}

/// The machine a bench runs on, for its first line: the CPU model and the widest vector
/// instructions it has (`/proc/cpuinfo`). An anchor that compiles for the host (Mitsuba's LLVM
/// variant) uses AVX-512 where it exists, and Tessera's binaries are built for AVX2 everywhere,
/// so ratios taken on different CPUs are not comparable without it.
pub fn cpu_description() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |name: &str| {
        info.lines().find_map(|l| {
            l.split_once(':').filter(|(k, _)| k.trim() == name).map(|(_, v)| v.trim().to_string())
        })
    };
    let model = field("model name").unwrap_or_else(|| "unknown CPU".into());
    let flags = field("flags").unwrap_or_default();
    let has = |f: &str| flags.split_whitespace().any(|x| x == f);
    let vector = if has("avx512f") {
        "AVX-512"
    } else if has("avx2") {
        "AVX2"
    } else {
        "no AVX2"
    };
    let cpus = info.lines().filter(|l| l.starts_with("processor")).count();
    format!("{model}, {cpus} logical CPUs, widest vectors {vector}")
}

/// Whether `TESSERA_REQUIRE_SCENES` asks for the corpus (set, and neither empty nor `0`).
pub fn scenes_required() -> bool {
    std::env::var_os("TESSERA_REQUIRE_SCENES").is_some_and(|v| !v.is_empty() && v != "0")
}

/// The scene files (`.xml`, `.json`) under `dir` and its subfolders, sorted; none when `dir`
/// cannot be read.
pub fn scene_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut dirs = vec![dir.to_path_buf()];
    while let Some(d) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for path in entries.flatten().map(|e| e.path()) {
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "xml" || e == "json") {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

/// Whether the corpus file or folder `path` is there. When it is not, the calling test should
/// skip: this prints why, or panics when `TESSERA_REQUIRE_SCENES` is set.
pub fn corpus_has(path: &Path) -> bool {
    if path.exists() {
        return true;
    }
    missing(&format!("{} is absent", path.display()));
    false
}

/// Reports a part of the corpus the calling test needs and did not find (see [`corpus_has`]).
pub fn missing(what: &str) {
    assert!(
        !scenes_required(),
        "TESSERA_REQUIRE_SCENES is set but {what}: put the course corpus in ../shared/scenes beside \
         the repository, or point TESSERA_SCENES at it (the corpus looked for: {})",
        shared_scenes().display()
    );
    eprintln!(
        "skipping: {what} (the course corpus is not checked out; TESSERA_REQUIRE_SCENES makes this a failure)"
    );
}

/// A directory of its own under the system's temporary one, created empty and removed with
/// everything in it on drop: `tessera-<tag>-<pid>-<n>`, with `n` counted per process, so no two
/// tests (of this process or another) share one, whatever tags they pass. It dereferences to its
/// [`Path`]: keep it alive (bound to a name) for as long as the directory is used.
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("tessera-{tag}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
        TempDir(dir)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }

    /// Writes `contents` to the file `name` in the directory and returns its path.
    pub fn write(&self, name: &str, contents: impl AsRef<[u8]>) -> PathBuf {
        let p = self.0.join(name);
        std::fs::write(&p, contents).unwrap_or_else(|e| panic!("cannot write {}: {e}", p.display()));
        p
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A scene of one sphere, `w` x `h` pixels, with nothing to load.
pub fn tiny_scene(w: u32, h: u32) -> Vec<u8> {
    format!(
        r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>{w} {h}</ImageResolution>
<ImageName>tiny.png</ImageName></Camera></Cameras><Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<VertexData>0 0 -5</VertexData><Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects></Scene>"#
    )
    .into_bytes()
}

/// The lock that runs a test binary's process-heavy tests one at a time (each wants every core),
/// and the hang watchdog of the test holding it: see [`serial`].
pub struct Serial {
    _lock: MutexGuard<'static, ()>,
    done: Arc<AtomicBool>,
}

impl Drop for Serial {
    fn drop(&mut self) {
        self.done.store(true, Ordering::SeqCst);
    }
}

/// Takes this test binary's serial lock and starts a watchdog: a test still holding it after
/// `limit` (a child that never exits, a pipe that never closes) stops the whole binary with the
/// test's name, so a hang fails CI by name instead of eating its clock. Never an assertion about
/// speed: the limit is far above any test's time.
pub fn serial(limit: Duration) -> Serial {
    static SERIAL: Mutex<()> = Mutex::new(());
    let lock = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let done = Arc::new(AtomicBool::new(false));
    let flag = done.clone();
    let test = std::thread::current().name().unwrap_or("a test").to_string();
    std::thread::spawn(move || {
        let start = Instant::now();
        while start.elapsed() < limit {
            std::thread::sleep(Duration::from_millis(200));
            if flag.load(Ordering::SeqCst) {
                return;
            }
        }
        // Straight to file descriptor 2: the harness captures eprintln! and would lose it.
        use std::io::Write;
        let _ = writeln!(
            std::io::stderr(),
            "{test} is still running after {} s: it hangs; stopping this test binary",
            limit.as_secs()
        );
        std::process::abort();
    });
    Serial { _lock: lock, done }
}

/// Sends signal `sig` to a child process (tests stop, kill and interrupt the farm's processes).
pub fn signal(child: &std::process::Child, sig: libc::c_int) {
    // SAFETY: kill(2) has no memory effects; a pid that is gone gives ESRCH, which is fine here.
    unsafe {
        libc::kill(child.id() as libc::pid_t, sig);
    }
}

/// The child's exit status, or None when it is still running after `limit`.
pub fn wait_timeout(child: &mut std::process::Child, limit: Duration) -> Option<std::process::ExitStatus> {
    let start = Instant::now();
    loop {
        if let Ok(Some(status)) = child.try_wait() {
            return Some(status);
        }
        if start.elapsed() > limit {
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The first line a child writes to `stdout` (read on a thread of its own, which then drains the
/// rest so the child never blocks on a full pipe), or None after `limit` or at end of file.
pub fn first_line(stdout: std::process::ChildStdout, limit: Duration) -> Option<String> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut lines = std::io::BufRead::lines(std::io::BufReader::new(stdout));
        if let Some(Ok(line)) = lines.next() {
            let _ = tx.send(line);
        }
        for _ in lines {}
    });
    rx.recv_timeout(limit).ok()
}

/// Starts `tessera-server` as `cmd` says (its binary, data directory and options; the API and
/// worker tokens of the caller's environment are removed), its stderr into `log`, and waits for
/// the line that says where it listens: the child and the server's base URL. Panics with the log
/// when the server does not start within 30 s.
pub fn start_server(mut cmd: std::process::Command, log: &Path) -> (std::process::Child, String) {
    let mut child = cmd
        .env_remove("TESSERA_API_TOKEN")
        .env_remove("TESSERA_WORKER_TOKEN")
        .stdout(std::process::Stdio::piped())
        .stderr(std::fs::File::create(log).unwrap_or_else(|e| panic!("{}: {e}", log.display())))
        .spawn()
        .expect("start tessera-server");
    let line = first_line(child.stdout.take().unwrap(), Duration::from_secs(30)).unwrap_or_else(|| {
        let _ = child.kill();
        panic!("the server did not start:\n{}", std::fs::read_to_string(log).unwrap_or_default())
    });
    let url = line
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    (child, url)
}

/// Whether a test that needs Intel Open Image Denoise may run, given the outcome of looking for
/// it (`tessera_denoise::oidn()`, mapped to `()`): when it is missing, the test should skip, and
/// this says why, or panics when `TESSERA_REQUIRE_OIDN` is set (`.ci/run` installs the pyoidn
/// wheel and sets it), so CI cannot pass by skipping the denoiser.
pub fn denoiser_found(lookup: Result<(), String>) -> bool {
    let Err(e) = lookup else { return true };
    let required = std::env::var_os("TESSERA_REQUIRE_OIDN").is_some_and(|v| !v.is_empty() && v != "0");
    assert!(!required, "TESSERA_REQUIRE_OIDN is set but {e}");
    eprintln!("skipping: {e} (TESSERA_REQUIRE_OIDN makes this a failure)");
    false
}

/// The course's path-traced Cornell box with a glass sphere (`cornellbox_jaroslav_path_glass`)
/// made small for tests: every camera at 96 x 96 pixels, written into `dir`. `None` (the test
/// skips) when the corpus is absent; see [`corpus_has`].
pub fn small_path_traced_box(dir: &Path) -> Option<PathBuf> {
    let source = shared_scenes().join("xml/cornellbox_jaroslav_path_glass.xml");
    if !corpus_has(&source) {
        return None;
    }
    let text = std::fs::read_to_string(&source).expect("read the corpus scene");
    let small = text
        .replace("<ImageResolution>512 512</ImageResolution>", "<ImageResolution>96 96</ImageResolution>");
    assert_ne!(small, text, "the corpus scene's resolution changed; update small_path_traced_box");
    let path = dir.join("box.xml");
    std::fs::write(&path, small).expect("write the small scene");
    Some(path)
}

/// Removes the variables cargo sets for a test run (`CARGO_MANIFEST_DIR`, `CARGO_PKG_*`, ...)
/// from a command that runs cargo: build scripts that watch them (ring's watches
/// CARGO_MANIFEST_DIR) would otherwise rebuild their crates there, and again in the next
/// `cargo test`.
pub fn without_test_env(cmd: &mut std::process::Command) {
    for (name, _) in std::env::vars_os() {
        let name = name.to_string_lossy();
        if name.starts_with("CARGO_MANIFEST_")
            || name.starts_with("CARGO_PKG_")
            || ["CARGO_CRATE_NAME", "CARGO_BIN_NAME", "CARGO_PRIMARY_PACKAGE"].contains(&&*name)
        {
            cmd.env_remove(&*name);
        }
    }
}
