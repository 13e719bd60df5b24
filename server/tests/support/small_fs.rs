//! A small filesystem for a server under test: a tmpfs on its data directory, in a mount
//! namespace of its own (`unshare(CLONE_NEWNS)` and `mount(2)` in the child before it starts:
//! root on Linux), reached through `/proc/PID/root`. Where that cannot be done a test skips with
//! the reason, unless `TESSERA_REQUIRE_SMALL_FS=1` (`.ci/run`, after a probe) makes it a failure.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use super::{Server, TempDir};

/// Whether `TESSERA_REQUIRE_SMALL_FS` makes a skip a failure.
pub fn small_fs_required() -> bool {
    std::env::var_os("TESSERA_REQUIRE_SMALL_FS").is_some_and(|v| v != "0" && !v.is_empty())
}

/// Skips a test that needs a small filesystem, saying why (a failure where one is required).
pub fn skip(reason: &str) {
    assert!(!small_fs_required(), "TESSERA_REQUIRE_SMALL_FS is set but {reason}");
    eprintln!("skipped: {reason}");
}

/// What the child runs before it becomes `cmd`'s program: a mount namespace of its own (so the
/// mount is seen by it alone and goes with it) and a tmpfs of `mib` MiB on `dir`.
pub fn on_small_fs(cmd: &mut Command, dir: &Path, mib: u32) {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    use std::os::unix::process::CommandExt;
    let target = CString::new(dir.as_os_str().as_bytes()).unwrap();
    let options = CString::new(format!("size={mib}m,mode=0755")).unwrap();
    let hook = move || -> std::io::Result<()> {
        // SAFETY: system calls on C strings made before the fork; no allocation here.
        unsafe {
            if libc::unshare(libc::CLONE_NEWNS) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            let private = libc::MS_REC | libc::MS_PRIVATE;
            if libc::mount(c"none".as_ptr(), c"/".as_ptr(), std::ptr::null(), private, std::ptr::null()) != 0
            {
                return Err(std::io::Error::last_os_error());
            }
            if libc::mount(c"tmpfs".as_ptr(), target.as_ptr(), c"tmpfs".as_ptr(), 0, options.as_ptr().cast())
                != 0
            {
                return Err(std::io::Error::last_os_error());
            }
        }
        Ok(())
    };
    // SAFETY: the hook only makes system calls (see above).
    unsafe {
        cmd.pre_exec(hook);
    }
}

/// Whether a child can be given a small filesystem here (`Err`: why not).
pub fn small_fs_works() -> Result<(), String> {
    let dir = TempDir::new("durable-probe");
    let mut cmd = Command::new("sh");
    cmd.args(["-c", "exit 0"]).stdout(Stdio::null()).stderr(Stdio::null());
    on_small_fs(&mut cmd, &dir, 1);
    match cmd.status() {
        Ok(s) if s.success() => Ok(()),
        Ok(s) => Err(format!("a probe child on a tmpfs exited with {s}")),
        Err(e) => Err(format!(
            "a child cannot get a mount namespace and a tmpfs here ({e}); this needs root on Linux"
        )),
    }
}

/// `dir` as the server process sees it (its own mount namespace), through `/proc/PID/root`.
pub fn as_server_sees(server: &Server, dir: &Path) -> PathBuf {
    Path::new(&format!("/proc/{}/root", server.child.id())).join(dir.strip_prefix("/").unwrap())
}

/// Bytes free for `dir`'s filesystem (statvfs).
pub fn free_bytes(dir: &Path) -> u64 {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).unwrap();
    // SAFETY: statvfs writes into the struct it is given.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    assert_eq!(unsafe { libc::statvfs(path.as_ptr(), &mut st) }, 0, "statvfs {}", dir.display());
    st.f_bavail as u64 * st.f_frsize as u64
}

/// Grows `filler` until at most `leave` bytes are free on its filesystem (0: until it is full).
pub fn fill(filler: &Path, leave: u64) {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new().create(true).append(true).open(filler).unwrap();
    let dir = filler.parent().unwrap();
    for chunk in [1usize << 16, 4096, 1] {
        let block = vec![0x5au8; chunk];
        loop {
            let free = free_bytes(dir);
            if free <= leave || (leave > 0 && free - leave < chunk as u64) {
                break;
            }
            if let Err(e) = f.write_all(&block) {
                assert_eq!(e.raw_os_error(), Some(libc::ENOSPC), "{e}");
                break;
            }
        }
    }
    let _ = f.sync_all();
}
