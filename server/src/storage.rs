//! The data directory and what keeps the work in it: the check that refuses to start on a lost
//! job store, the sweep of what a killed writer left, and telling a full disk apart from other
//! failures.
//!
//! The data directory holds:
//! - `tessera.db` (and SQLite's `-wal` and `-shm` beside it): the job store;
//! - `results/LEASE-PID-K.f32`: large tile results (a whole frame's floats), each named by its tile's
//!   row until the frame is merged (`db::results`);
//! - `blobs/HASH.tar`: the uploaded bundles;
//! - `uploads/`: submissions being read (removed at start);
//! - `outputs/JOB/FRAME/`: a merged frame's outputs and nothing else (their names come from the
//!   scene's `ImageName`, so any name can be an output);
//! - `frames/JOB/FRAME/`: the server's own files of a frame, never an output: the frame after
//!   its latest pass (`pass.exr`, `pass.png`) and the finished frame's `preview.png`.
//!
//! Every file is written under a temporary name of its writer's own and renamed
//! (`tessera::atomic_write`); [`sweep`] removes the temporaries a killed server left.

use std::path::Path;

use anyhow::{Context, Result, bail};

use crate::db::Store;

/// The job store's file in the data directory.
pub const DB_FILE: &str = "tessera.db";

/// Where the frames' outputs are, and the server's own files of each frame.
pub const OUTPUTS_DIR: &str = "outputs";
pub const FRAMES_DIR: &str = "frames";

/// The frame after its latest pass, in `frames/JOB/FRAME/` until the frame is merged (and the
/// names under which clients download it: `merge::PASS_FILES`).
pub const PASS_FILES: [&str; 2] = ["pass.exr", "pass.png"];

/// The frame after its latest pass denoised, for a job with `denoise`: beside [`PASS_FILES`],
/// and like them served by its name until the frame's own denoised PNG replaces it.
pub const PASS_DENOISED_FILE: &str = "pass_denoised.png";

/// A merged frame's preview, in `frames/JOB/FRAME/`.
pub const PREVIEW_FILE: &str = "preview.png";

/// What a request that found the disk full is told (a 507).
pub const OUT_OF_SPACE: &str =
    "the server's disk is full; nothing was stored; try again when an operator has freed space";

/// Whether `e` comes from a full disk or an exhausted quota (ENOSPC, EDQUOT, SQLite's
/// SQLITE_FULL): a failure that freeing space cures. Looks at the error chain's types, and at
/// its text for the layers that keep only the operating system's message.
pub fn out_of_space(e: &anyhow::Error) -> bool {
    let io_full = |e: &std::io::Error| matches!(e.raw_os_error(), Some(libc::ENOSPC | libc::EDQUOT));
    let typed = e.chain().any(|cause| {
        if let Some(io) = cause.downcast_ref::<std::io::Error>() {
            return io_full(io);
        }
        if let Some(tessera::hdr_io::HdrError::Io { error, .. }) = cause.downcast_ref() {
            return io_full(error);
        }
        if let Some(w) = cause.downcast_ref::<tessera::atomic_write::WriteError>() {
            return io_full(&w.error);
        }
        if let Some(rusqlite::Error::SqliteFailure(f, _)) = cause.downcast_ref() {
            return f.code == rusqlite::ErrorCode::DiskFull;
        }
        false
    });
    let text = format!("{e:#}");
    typed
        || [
            format!("(os error {})", libc::ENOSPC),
            format!("(os error {})", libc::EDQUOT),
            "database or disk is full".to_string(),
        ]
        .iter()
        .any(|m| text.contains(m.as_str()))
}

/// `message` with every path into the data directory cut to its file name, for what clients
/// see (a job's error, its log): the full paths go to the server's log only.
pub fn without_paths(message: &str, data_dir: &Path) -> String {
    let mut prefixes = vec![data_dir.display().to_string()];
    if let Ok(full) = data_dir.canonicalize() {
        prefixes.push(full.display().to_string());
    }
    if let Ok(cwd) = std::env::current_dir() {
        prefixes.push(cwd.join(data_dir).display().to_string());
    }
    prefixes.retain(|p| !p.is_empty() && p != "." && p != "/");
    prefixes.sort_by_key(|p| std::cmp::Reverse(p.len()));
    let mut out = message.to_string();
    for p in prefixes {
        let mut from = 0;
        while let Some(found) = out[from..].find(&p) {
            let at = from + found;
            let before_ok = out[..at].chars().next_back().is_none_or(|c| " \"'(".contains(c));
            let after = &out[at + p.len()..];
            let after_ok = after.is_empty() || after.starts_with(['/', ':', ' ', '"', '\'', ')']);
            if !(before_ok && after_ok) {
                from = at + p.len();
                continue;
            }
            // The path runs to the next ": " (the layers write "PATH: what happened") or the end.
            let end = at + out[at..].find(": ").unwrap_or(out.len() - at);
            let name = Path::new(&out[at..end])
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| "the data directory".into());
            out.replace_range(at..end, &name);
            from = at + name.len();
        }
    }
    out
}

/// Whether `name` is a temporary file of a writer ([`tessera::atomic_write::unique_temp_name`]:
/// `.NAME.PID-N-NANOS.tmp`), or the pass file's temporary of older versions (`.pass.exr.tmp`).
pub fn is_temp_name(name: &str) -> bool {
    if name == ".pass.exr.tmp" {
        return true;
    }
    let Some(inner) = name.strip_prefix('.').and_then(|n| n.strip_suffix(".tmp")) else {
        return false;
    };
    let Some((stem, tag)) = inner.rsplit_once('.') else { return false };
    let parts: Vec<&str> = tag.split('-').collect();
    !stem.is_empty()
        && parts.len() == 3
        && parts.iter().all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()))
}

/// Refuses to start on a job store that was lost while the work it recorded is still there: a
/// `tessera.db` that is missing, empty (a truncated disk, a bad restore) or unreadable while
/// `outputs/`, `frames/` or `blobs/` hold files. Started anyway, the farm would be empty, hand
/// out job 1 again and write over job 1's outputs. The message says what to do.
pub fn check_data_dir(data_dir: &Path) -> Result<()> {
    let db = data_dir.join(DB_FILE);
    let holds_files =
        |sub: &str| std::fs::read_dir(data_dir.join(sub)).is_ok_and(|mut entries| entries.next().is_some());
    let work: Vec<&str> = [OUTPUTS_DIR, FRAMES_DIR, "blobs", "files", crate::db::RESULTS_DIR]
        .into_iter()
        .filter(|s| holds_files(s))
        .collect();
    if work.is_empty() {
        return Ok(());
    }
    let problem = match std::fs::metadata(&db) {
        Ok(m) if m.len() == 0 => "is empty (zero bytes)".to_string(),
        Ok(_) => return Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "is missing".to_string(),
        Err(e) => format!("cannot be read ({e})"),
    };
    bail!(
        "refusing to start: the job store {} {problem}, but the data directory {} holds the work of earlier \
         jobs (in {}). Started on it, the farm would be empty and would write new jobs over the old jobs' \
         outputs. Restore {DB_FILE} (with its {DB_FILE}-wal file, if there was one) from a backup, or move the \
         data directory away (or pass another --data-dir) to start an empty farm",
        db.display(),
        data_dir.display(),
        work.join(", ")
    )
}

/// Opens the job store after [`check_data_dir`]; a store that cannot be read is a refusal that
/// says what to do, never a new empty store in its place.
pub fn open_store(data_dir: &Path) -> Result<Store> {
    check_data_dir(data_dir)?;
    let db = data_dir.join(DB_FILE);
    let store = Store::open(&db).with_context(|| {
        format!(
            "refusing to start: the job store {} cannot be read. Restore {DB_FILE} (with its {DB_FILE}-wal \
             file, if there was one) from a backup, or move the data directory {} away (or pass another \
             --data-dir) to start an empty farm",
            db.display(),
            data_dir.display()
        )
    })?;
    // A job's folders are named by its id: a new job never takes the id of a folder that is
    // there already (a store restored from an older backup, folders of removed jobs).
    store.keep_job_ids_above(highest_job_folder(data_dir));
    Ok(store)
}

/// The largest job id that names a folder under `outputs/` or `frames/` (0 if none).
pub fn highest_job_folder(data_dir: &Path) -> u64 {
    [OUTPUTS_DIR, FRAMES_DIR]
        .iter()
        .filter_map(|sub| std::fs::read_dir(data_dir.join(sub)).ok())
        .flat_map(|entries| entries.flatten())
        .filter_map(|e| e.file_name().to_str()?.parse::<u64>().ok())
        .max()
        .unwrap_or(0)
}

/// What [`sweep`] removed.
#[derive(Debug, Default, PartialEq)]
pub struct Swept {
    pub temporaries: usize,
    /// Pass files older versions wrote among the outputs of frames that are not merged.
    pub old_pass_files: usize,
}

/// Removes, before anything else writes, what a killed server left in the frames' folders:
/// every writer's temporary file ([`is_temp_name`]) under `outputs/JOB/FRAME/` and
/// `frames/JOB/FRAME/` (never a file a frame records as an output, whatever its name), and
/// the pass files older versions kept beside the outputs of frames not merged yet (their merge
/// writes those folders afresh).
pub fn sweep(data_dir: &Path, store: &Store) -> Result<Swept> {
    let mut swept = Swept::default();
    for sub in [OUTPUTS_DIR, FRAMES_DIR] {
        let Ok(jobs) = std::fs::read_dir(data_dir.join(sub)) else { continue };
        for job_dir in jobs.flatten() {
            let Some(job) = job_dir.file_name().to_str().and_then(|n| n.parse::<u64>().ok()) else {
                continue;
            };
            let Ok(frame_dirs) = std::fs::read_dir(job_dir.path()) else { continue };
            let mut frames = None;
            for frame_dir in frame_dirs.flatten() {
                let Some(frame) = frame_dir.file_name().to_str().and_then(|n| n.parse::<u32>().ok()) else {
                    continue;
                };
                let Ok(files) = std::fs::read_dir(frame_dir.path()) else { continue };
                let names: Vec<String> =
                    files.flatten().filter_map(|f| f.file_name().to_str().map(str::to_string)).collect();
                let outputs_dir = sub == OUTPUTS_DIR;
                let legacy = |n: &str| outputs_dir && PASS_FILES.contains(&n);
                if !names.iter().any(|n| is_temp_name(n) || legacy(n)) {
                    continue;
                }
                let rows = match &frames {
                    Some(rows) => rows,
                    None => frames.insert(store.frames(job)?),
                };
                let row = rows.iter().find(|f| f.index == frame);
                let outputs = row.and_then(|f| f.outputs.clone());
                for name in names {
                    let recorded = outputs_dir && outputs.as_ref().is_some_and(|o| o.contains(&name));
                    if recorded {
                        continue;
                    }
                    let path = frame_dir.path().join(&name);
                    if is_temp_name(&name) {
                        if std::fs::remove_file(&path).is_ok() {
                            tracing::info!("removed {}, left by a write that was cut off", path.display());
                            swept.temporaries += 1;
                        }
                    } else if legacy(&name)
                        && row.is_some()
                        && outputs.is_none()
                        && std::fs::remove_file(&path).is_ok()
                    {
                        swept.old_pass_files += 1;
                    }
                }
            }
        }
    }
    Ok(swept)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_is_told_apart_from_other_failures() {
        let enospc = std::io::Error::from_raw_os_error(libc::ENOSPC);
        assert!(out_of_space(&anyhow::Error::new(enospc).context("writing x")));
        let quota = std::io::Error::from_raw_os_error(libc::EDQUOT);
        assert!(out_of_space(&anyhow::Error::new(quota)));
        // Only the text is left (a layer formatted the error into its own message).
        let flat =
            anyhow::anyhow!("/d/outputs/1/0/x.exr: cannot create: No space left on device (os error 28)");
        assert!(out_of_space(&flat));
        let full = rusqlite::Error::SqliteFailure(
            rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_FULL),
            Some("database or disk is full".into()),
        );
        assert!(out_of_space(&anyhow::Error::new(full)));
        let denied = std::io::Error::from_raw_os_error(libc::EACCES);
        assert!(!out_of_space(&anyhow::Error::new(denied)));
        assert!(!out_of_space(&anyhow::anyhow!("tile lies outside the frame")));
    }

    #[test]
    fn paths_into_the_data_directory_become_file_names() {
        let data = Path::new("/srv/farm data");
        let m = "merging frame 0 failed: /srv/farm data/outputs/3/0/a b.exr: cannot write: Permission denied";
        assert_eq!(
            without_paths(m, data),
            "merging frame 0 failed: a b.exr: cannot write: Permission denied"
        );
        assert_eq!(without_paths("cannot create /srv/farm data/outputs/3", data), "cannot create 3");
        // Not a path into the data directory: left alone.
        let other = "/srv/farm datax/y and x/srv/farm data";
        assert_eq!(without_paths(other, data), other);
        let rel = Path::new("tessera-data");
        assert_eq!(
            without_paths("tessera-data/outputs/1/0/x.png: cannot write: No space", rel),
            "x.png: cannot write: No space"
        );
    }

    #[test]
    fn only_a_writers_temporary_names_are_temporary() {
        for t in [".x.png.123-0-456.tmp", ".pass.exr.tmp", ".a.b.c.exr.1-22-333.tmp"] {
            assert!(is_temp_name(t), "{t}");
        }
        for n in [
            "x.tmp",
            ".x.tmp",
            ".x.png.12-3.tmp",
            ".x.png.1-2-3a.tmp",
            "pass.exr",
            ".preview.png",
            "..1-2-3.tmp",
        ] {
            assert!(!is_temp_name(n), "{n}");
        }
        let name = tessera::atomic_write::unique_temp_name(Path::new("/d/out.exr"));
        assert!(is_temp_name(name.file_name().unwrap().to_str().unwrap()), "{}", name.display());
    }

    /// The sweep removes writers' temporary files and old pass files among unmerged outputs,
    /// and nothing a frame records as an output, whatever its name.
    #[test]
    fn the_sweep_removes_temporaries_and_never_an_output() {
        let dir = tessera_testkit::TempDir::new("unit-storage-sweep");
        let data = dir.path();
        let store = Store::open(&data.join(DB_FILE)).unwrap();
        let frames = vec![crate::testutil::frame("pass.png", 1, 1), crate::testutil::frame("x.png", 1, 1)];
        let id = store
            .insert_job(&crate::db::NewJob { scene_path: "s.xml".into(), ..crate::testutil::job_of(frames) })
            .unwrap();
        let recorded = [".odd.png.1-2-3.tmp".to_string(), "pass.png".to_string()];
        store.frame_merged(id, 0, &recorded, Default::default()).unwrap();
        let put = |rel: &str| {
            let p = data.join(rel);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(&p, b"x").unwrap();
            p
        };
        let kept = [
            put("outputs/1/0/.odd.png.1-2-3.tmp"),
            put("outputs/1/0/pass.png"),
            put("outputs/1/1/x.png"),
            put("frames/1/1/pass.png"),
            put("blobs/.a.tar.1-2-3.tmp"),
        ];
        let gone = [
            put("outputs/1/0/.x.exr.4-5-6.tmp"),
            put("outputs/1/1/.pass.exr.tmp"),
            put("frames/1/1/.preview.png.7-8-9.tmp"),
            put("outputs/9/0/.y.png.1-1-1.tmp"),
        ];
        let legacy = put("outputs/1/1/pass.exr");
        let swept = sweep(data, &store).unwrap();
        assert_eq!(swept, Swept { temporaries: 4, old_pass_files: 1 });
        assert!(kept.iter().all(|p| p.exists()), "{kept:?}");
        assert!(!legacy.exists() && gone.iter().all(|p| !p.exists()), "{gone:?}");
        assert_eq!(highest_job_folder(data), 9);
    }

    #[test]
    fn a_lost_store_beside_earlier_work_is_a_refusal_that_says_what_to_do() {
        let dir = tessera_testkit::TempDir::new("unit-storage-check");
        let data = dir.path().join("data");
        std::fs::create_dir_all(data.join("outputs/1/0")).unwrap();
        std::fs::write(data.join("outputs/1/0/a.png"), b"png").unwrap();
        for (db, says) in [(None, "is missing"), (Some(&b""[..]), "is empty")] {
            let _ = std::fs::remove_file(data.join(DB_FILE));
            if let Some(bytes) = db {
                std::fs::write(data.join(DB_FILE), bytes).unwrap();
            }
            let e = open_store(&data).err().expect("a refusal").to_string();
            assert!(e.contains(says) && e.contains("backup") && e.contains("move the data directory"), "{e}");
        }
        std::fs::write(data.join(DB_FILE), vec![b'x'; 8192]).unwrap();
        let e = format!("{:#}", open_store(&data).err().expect("a refusal"));
        assert!(e.contains("cannot be read") && e.contains("backup"), "{e}");
        assert_eq!(std::fs::read(data.join("outputs/1/0/a.png")).unwrap(), b"png");
        // A fresh data directory starts; so does an empty store with nothing beside it.
        let fresh = dir.path().join("fresh");
        std::fs::create_dir_all(&fresh).unwrap();
        std::fs::write(fresh.join(DB_FILE), b"").unwrap();
        assert!(open_store(&fresh).is_ok());
    }
}
