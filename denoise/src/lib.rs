//! Denoising with Intel Open Image Denoise 2 (OIDN), found at run time.
//!
//! Tessera builds and runs without OIDN: the library is opened (`dlopen`, through `libloading`)
//! only when a render asks for denoising, from
//! 1. `TESSERA_OIDN_LIB` when it is set (the library file, or the folder holding it) and from
//!    nowhere else, so an explicit choice is never silently replaced;
//! 2. otherwise the system's library search (`LD_LIBRARY_PATH`, the linker cache: a package or a
//!    release archive installed in the usual places);
//! 3. otherwise the `pyoidn` wheel's `oidn/lib` folder, located by asking `python3` where the
//!    `pyoidn` package is (`python3 -m pip install pyoidn` is the easy install on any Linux).
//!
//! The filter is OIDN's `RT` filter on HDR colour with albedo and normal images, which are
//! denoised first by `RT` filters of their own so the main filter can take them as clean
//! (`cleanAux`), as OIDN's documentation recommends for final frames. Everything runs on OIDN's
//! CPU device, so a frame denoises to the same bits on the CLI and on the farm's server of one
//! machine.

use std::ffi::{CStr, CString, c_char, c_void};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use tessera::image::Image;
use tessera::render::AuxImages;

/// The environment variable that names the library (a file or its folder).
pub const LIB_ENV: &str = "TESSERA_OIDN_LIB";

#[cfg(target_os = "macos")]
const LIB_NAME: &str = "libOpenImageDenoise.2.dylib";
#[cfg(target_os = "windows")]
const LIB_NAME: &str = "OpenImageDenoise.dll";
#[cfg(not(any(target_os = "macos", target_os = "windows")))]
const LIB_NAME: &str = "libOpenImageDenoise.so.2";

/// How to install OIDN, for every "not found" message.
pub const INSTALL_HINT: &str = "install Intel Open Image Denoise 2 with `python3 -m pip install pyoidn` \
     (its wheel ships the library and its CPU device), or set TESSERA_OIDN_LIB to the \
     libOpenImageDenoise.so.2 file or the folder that holds it";

/// Filter quality (OIDN's `quality` parameter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// OIDN's `OIDN_QUALITY_FAST`: for previews.
    Fast,
    /// `OIDN_QUALITY_BALANCED`.
    Balanced,
    /// `OIDN_QUALITY_HIGH`: for final frames.
    High,
}

impl Quality {
    fn code(self) -> i32 {
        match self {
            Quality::Fast => 4,
            Quality::Balanced => 5,
            Quality::High => 6,
        }
    }
}

/// The most working memory each filter may take (OIDN's `maxMemoryMB`): larger frames are
/// denoised in overlapping tiles, so a frame's size does not decide the denoiser's memory.
const MAX_MEMORY_MB: i32 = 1024;

// The parts of OIDN 2's C API used here (oidn.h): opaque handles, `OIDN_DEVICE_TYPE_CPU` = 1,
// `OIDN_FORMAT_FLOAT3` = 3, `OIDN_ERROR_NONE` = 0.
type Handle = *mut c_void;
const DEVICE_TYPE_CPU: i32 = 1;
const FORMAT_FLOAT3: i32 = 3;

type NewDevice = unsafe extern "C" fn(i32) -> Handle;
type DeviceFn = unsafe extern "C" fn(Handle);
type GetDeviceError = unsafe extern "C" fn(Handle, *mut *const c_char) -> i32;
type GetDeviceInt = unsafe extern "C" fn(Handle, *const c_char) -> i32;
type NewFilter = unsafe extern "C" fn(Handle, *const c_char) -> Handle;
type FilterFn = unsafe extern "C" fn(Handle);
type SetSharedFilterImage =
    unsafe extern "C" fn(Handle, *const c_char, *mut c_void, i32, usize, usize, usize, usize, usize);
type SetFilterBool = unsafe extern "C" fn(Handle, *const c_char, bool);
type SetFilterInt = unsafe extern "C" fn(Handle, *const c_char, i32);

/// The loaded library and the functions Tessera calls.
pub struct Oidn {
    path: PathBuf,
    version: i32,
    new_device: NewDevice,
    commit_device: DeviceFn,
    release_device: DeviceFn,
    get_device_error: GetDeviceError,
    new_filter: NewFilter,
    set_image: SetSharedFilterImage,
    set_bool: SetFilterBool,
    set_int: SetFilterInt,
    commit_filter: FilterFn,
    execute_filter: FilterFn,
    release_filter: FilterFn,
    /// One denoise at a time per process: OIDN's CPU device already uses every core, and a
    /// frame's buffers are large.
    busy: Mutex<()>,
    // Last: the functions above point into it, and it is never unloaded (the value lives in a
    // `static`).
    _lib: libloading::Library,
}

/// How long a failed lookup of the library stands before the next call looks again: a
/// library installed while a program runs (`pip install pyoidn` beside a running server) is
/// found within this time, without a restart, and a program asked many times meanwhile does
/// not search (and start `python3`) on every call.
pub const RETRY_LOOKUP_AFTER: Duration = Duration::from_secs(2);

/// The library, loaded on first use (see the module's documentation for where it is looked
/// for) and kept once found; the error says where it looked and how to install it. A lookup
/// that failed is repeated by a call [`RETRY_LOOKUP_AFTER`] or more later.
pub fn oidn() -> Result<&'static Oidn, String> {
    static LOADED: OnceLock<Oidn> = OnceLock::new();
    static FAILED: Mutex<Option<(Instant, String)>> = Mutex::new(None);
    if let Some(o) = LOADED.get() {
        return Ok(o);
    }
    // One lookup at a time; the others wait for its outcome.
    let mut failed = FAILED.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(o) = LOADED.get() {
        return Ok(o);
    }
    if let Some((at, e)) = failed.as_ref()
        && at.elapsed() < RETRY_LOOKUP_AFTER
    {
        return Err(e.clone());
    }
    match Oidn::find(std::env::var_os(LIB_ENV).map(PathBuf::from)) {
        Ok(o) => {
            *failed = None;
            Ok(LOADED.get_or_init(|| o))
        }
        Err(e) => {
            *failed = Some((Instant::now(), e.clone()));
            Err(e)
        }
    }
}

/// Where the `pyoidn` wheel keeps the library, if `python3` has it; `Err` says why not.
fn pyoidn_lib_dir() -> Result<PathBuf, &'static str> {
    let out = std::process::Command::new("python3")
        .args([
            "-c",
            "import importlib.util as u; s = u.find_spec('pyoidn'); \
             print(s.submodule_search_locations[0] if s and s.submodule_search_locations else '')",
        ])
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .output()
        .map_err(|_| "there is no python3 to ask")?;
    let dir = String::from_utf8_lossy(&out.stdout);
    let dir = dir.trim();
    if out.status.success() && !dir.is_empty() {
        Ok(Path::new(dir).join("oidn").join("lib"))
    } else {
        Err("python3 has no pyoidn package")
    }
}

impl Oidn {
    /// Loads the library from `explicit` (a file or folder) only, when given; else from the
    /// system's search, then the pyoidn wheel.
    pub fn find(explicit: Option<PathBuf>) -> Result<Oidn, String> {
        if let Some(p) = explicit {
            let file = if p.is_dir() { p.join(LIB_NAME) } else { p.clone() };
            if !file.exists() {
                return Err(format!(
                    "Intel Open Image Denoise was not found: {LIB_ENV} is {}, and {} does not exist; {INSTALL_HINT}",
                    p.display(),
                    file.display()
                ));
            }
            return Oidn::open(&file);
        }
        // A bare name: the dynamic linker's own search (LD_LIBRARY_PATH, its cache).
        let mut tried = match Oidn::open(Path::new(LIB_NAME)) {
            Ok(o) => return Ok(o),
            Err(e) => vec![format!(
                "{LIB_NAME} on the system's library path ({})",
                e.split("; ").next().unwrap_or(&e)
            )],
        };
        match pyoidn_lib_dir() {
            Ok(dir) => {
                let file = dir.join(LIB_NAME);
                if file.exists() {
                    return Oidn::open(&file);
                }
                tried.push(format!("the pyoidn wheel ({} does not exist)", file.display()));
            }
            Err(why) => tried.push(format!("the pyoidn wheel ({why})")),
        }
        Err(format!(
            "Intel Open Image Denoise 2 was not found (looked for {}; {LIB_ENV} is not set): {INSTALL_HINT}",
            tried.join(", then ")
        ))
    }

    /// Opens the library at `file` (a bare name: through the system's search) and checks that
    /// its CPU device works.
    fn open(file: &Path) -> Result<Oidn, String> {
        let what = file.display();
        // SAFETY: opening a shared library runs its initialisers; OIDN's only set up its own
        // state. The symbols below are typed as oidn.h declares them (OIDN 2.x).
        let lib = unsafe { libloading::Library::new(file.as_os_str()) }
            .map_err(|e| format!("cannot load Intel Open Image Denoise from {what}: {e}; {INSTALL_HINT}"))?;
        macro_rules! sym {
            ($name:literal) => {
                // SAFETY: see above; the pointer is copied out and outlives nothing: `lib` is kept
                // in the returned value and never unloaded while it is used.
                *unsafe { lib.get(concat!($name, "\0").as_bytes()) }.map_err(|e| {
                    format!("{what} is not Intel Open Image Denoise 2 (no {}: {e}); {INSTALL_HINT}", $name)
                })?
            };
        }
        let get_int: GetDeviceInt = sym!("oidnGetDeviceInt");
        let mut oidn = Oidn {
            path: file.to_path_buf(),
            version: 0,
            new_device: sym!("oidnNewDevice"),
            commit_device: sym!("oidnCommitDevice"),
            release_device: sym!("oidnReleaseDevice"),
            get_device_error: sym!("oidnGetDeviceError"),
            new_filter: sym!("oidnNewFilter"),
            set_image: sym!("oidnSetSharedFilterImage"),
            set_bool: sym!("oidnSetFilterBool"),
            set_int: sym!("oidnSetFilterInt"),
            commit_filter: sym!("oidnCommitFilter"),
            execute_filter: sym!("oidnExecuteFilter"),
            release_filter: sym!("oidnReleaseFilter"),
            busy: Mutex::new(()),
            _lib: lib,
        };
        let version = {
            let device = oidn.device().map_err(|e| format!("{what}: {e}"))?;
            // SAFETY: a live device and a NUL-terminated parameter name.
            unsafe { get_int(device.0, c"version".as_ptr()) }
        };
        oidn.version = version;
        if oidn.version < 20000 {
            return Err(format!(
                "{what} is Intel Open Image Denoise {}, and Tessera needs 2.x; {INSTALL_HINT}",
                version_text(oidn.version)
            ));
        }
        Ok(oidn)
    }

    /// Where the library was loaded from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The library's version, as "2.5.1".
    pub fn version(&self) -> String {
        version_text(self.version)
    }

    fn device(&self) -> Result<Device<'_>, String> {
        // SAFETY: plain calls into the loaded library with the argument types oidn.h gives.
        let handle = unsafe { (self.new_device)(DEVICE_TYPE_CPU) };
        if handle.is_null() {
            return Err("Intel Open Image Denoise has no CPU device (is libOpenImageDenoise_device_cpu beside the library?)".into());
        }
        let device = Device(handle, self);
        // SAFETY: as above, on the live handle.
        unsafe { (self.commit_device)(handle) };
        device.check()?;
        Ok(device)
    }

    /// `colour` denoised with OIDN's `RT` filter (HDR), guided by `aux` when given (prefiltered,
    /// then passed as clean). Negative colour values (lights of negative power) are taken as 0,
    /// which OIDN requires. Returns the image and the seconds the filters took.
    pub fn denoise(
        &self,
        colour: &Image,
        aux: Option<&AuxImages>,
        quality: Quality,
    ) -> Result<(Image, f64), String> {
        let (w, h) = (colour.width as usize, colour.height as usize);
        if let Some(a) = aux
            && (a.albedo.width, a.albedo.height, a.normal.width, a.normal.height)
                != (colour.width, colour.height, colour.width, colour.height)
        {
            return Err("the albedo and normal images differ in size from the colour image".into());
        }
        let _one = self.busy.lock().unwrap_or_else(|p| p.into_inner());
        let started = Instant::now();
        let device = self.device()?;
        let mut input: Vec<[f32; 3]> = colour.pixels.iter().map(|p| p.map(|c| c.max(0.0))).collect();
        let mut output = vec![[0.0f32; 3]; w * h];
        let mut albedo = aux.map(|a| a.albedo.pixels.clone());
        let mut normal = aux.map(|a| a.normal.pixels.clone());
        // The auxiliary images first, each denoised in place by an RT filter of its own.
        for (name, buf) in [("albedo", albedo.as_mut()), ("normal", normal.as_mut())] {
            let Some(buf) = buf else { continue };
            let f = device.filter()?;
            f.image(name, buf, w, h);
            f.image("output", buf, w, h);
            f.int("quality", quality.code());
            f.int("maxMemoryMB", MAX_MEMORY_MB);
            f.run()?;
        }
        let f = device.filter()?;
        f.image("color", &mut input, w, h);
        if let Some(a) = albedo.as_mut() {
            f.image("albedo", a, w, h);
        }
        if let Some(n) = normal.as_mut() {
            f.image("normal", n, w, h);
        }
        f.image("output", &mut output, w, h);
        f.bool("hdr", true);
        f.bool("cleanAux", aux.is_some());
        f.int("quality", quality.code());
        f.int("maxMemoryMB", MAX_MEMORY_MB);
        f.run()?;
        drop(f);
        drop(device);
        // What OIDN writes is finite for finite input; a NaN would still be refused by every
        // writer downstream, so it is made 0 like the film's.
        let pixels = output.into_iter().map(|p| p.map(|c| if c.is_finite() { c } else { 0.0 })).collect();
        Ok((Image { width: colour.width, height: colour.height, pixels }, started.elapsed().as_secs_f64()))
    }
}

fn version_text(v: i32) -> String {
    format!("{}.{}.{}", v / 10000, v / 100 % 100, v % 100)
}

/// A committed OIDN device, released on drop.
struct Device<'a>(Handle, &'a Oidn);

impl Device<'_> {
    fn check(&self) -> Result<(), String> {
        let mut message: *const c_char = std::ptr::null();
        // SAFETY: a live device; OIDN writes a pointer to its own NUL-terminated message (valid
        // until the next call on the device), which is copied at once.
        let code = unsafe { (self.1.get_device_error)(self.0, &mut message) };
        if code == 0 {
            return Ok(());
        }
        let text = if message.is_null() {
            String::new()
        } else {
            // SAFETY: see above.
            unsafe { CStr::from_ptr(message) }.to_string_lossy().into_owned()
        };
        Err(format!("Intel Open Image Denoise failed (error {code}): {text}"))
    }

    fn filter(&self) -> Result<Filter<'_>, String> {
        // SAFETY: a live device and a NUL-terminated filter type.
        let handle = unsafe { (self.1.new_filter)(self.0, c"RT".as_ptr()) };
        self.check()?;
        if handle.is_null() {
            return Err("Intel Open Image Denoise has no RT filter".into());
        }
        Ok(Filter(handle, self))
    }
}

impl Drop for Device<'_> {
    fn drop(&mut self) {
        // SAFETY: the handle is live and released once.
        unsafe { (self.1.release_device)(self.0) };
    }
}

/// An OIDN filter, released on drop (before the buffers it was given: they are declared first
/// in [`Oidn::denoise`] and outlive it).
struct Filter<'d>(Handle, &'d Device<'d>);

impl Filter<'_> {
    fn name(name: &str) -> CString {
        CString::new(name).expect("parameter names have no NUL")
    }

    /// Shares `buf` (a `w` x `h` image of three f32 per pixel, rows packed) with the filter as
    /// image `name`.
    fn image(&self, name: &str, buf: &mut [[f32; 3]], w: usize, h: usize) {
        assert_eq!(buf.len(), w * h, "image size");
        let name = Filter::name(name);
        // SAFETY: the buffer holds w·h·12 bytes, packed (pixel stride 12, row stride 12·w), and
        // outlives the filter's execution (the caller keeps it until the filter is dropped).
        unsafe {
            (self.1.1.set_image)(
                self.0,
                name.as_ptr(),
                buf.as_mut_ptr().cast(),
                FORMAT_FLOAT3,
                w,
                h,
                0,
                12,
                12 * w,
            )
        };
    }

    fn bool(&self, name: &str, v: bool) {
        let name = Filter::name(name);
        // SAFETY: a live filter and a NUL-terminated name.
        unsafe { (self.1.1.set_bool)(self.0, name.as_ptr(), v) };
    }

    fn int(&self, name: &str, v: i32) {
        let name = Filter::name(name);
        // SAFETY: as above.
        unsafe { (self.1.1.set_int)(self.0, name.as_ptr(), v) };
    }

    fn run(&self) -> Result<(), String> {
        // SAFETY: a live filter whose images were set above and are still alive.
        unsafe { (self.1.1.commit_filter)(self.0) };
        self.1.check()?;
        // SAFETY: as above.
        unsafe { (self.1.1.execute_filter)(self.0) };
        self.1.check()
    }
}

impl Drop for Filter<'_> {
    fn drop(&mut self) {
        // SAFETY: the handle is live and released once.
        unsafe { (self.1.1.release_filter)(self.0) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_explicit_path_that_does_not_exist_says_so_and_how_to_install() {
        let Err(e) = Oidn::find(Some(PathBuf::from("/nonexistent/oidn"))) else { panic!("found") };
        assert!(e.contains("TESSERA_OIDN_LIB is /nonexistent/oidn"), "{e}");
        assert!(e.contains("pip install pyoidn"), "{e}");
    }

    #[test]
    fn a_file_that_is_not_the_library_is_refused_with_its_name() {
        let dir = tessera_testkit::TempDir::new("oidn-bad");
        let file = dir.write("libOpenImageDenoise.so.2", b"not a library");
        let Err(e) = Oidn::find(Some(dir.path().to_path_buf())) else { panic!("loaded") };
        assert!(e.contains(&file.display().to_string()) && e.contains("cannot load"), "{e}");
    }

    #[test]
    fn versions_read_as_major_minor_patch() {
        assert_eq!(version_text(20501), "2.5.1");
        assert_eq!(version_text(10403), "1.4.3");
    }
}
