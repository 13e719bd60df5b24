//! One or more scene files (a sequence, in the order given) and every file they name, laid out
//! as one job's files: what `tessera submit` sends.
//!
//! No scene is built here and no PLY is parsed: each scene is parsed to its records (the
//! library's own parser), the files it names come from [`SceneRecords::asset_paths`] (exactly
//! the ones the renderer's build reads), and each is found on disk where the renderer would
//! read it ([`FsResolver::locate`], the corpus' path fallbacks included). A file that cannot be
//! found is an error naming the scene file, its frame and the path, before anything goes on the
//! network.
//!
//! The job's top folder is the deepest folder that holds every file (scenes and assets); each
//! file's job path is its path below it (`/`-separated). The farm resolves a scene's paths with
//! [`MemResolver`]'s rules, which mirror `FsResolver`'s; where they would find another file (or
//! none) for a path a scene names, the file is also listed at the place the farm looks first
//! ([`bundle_path_for`]): the same bytes under a second path cost no upload, files being sent
//! by their SHA-256. Two different files on one job path are an error.
//!
//! Files are identified by their canonical path: each distinct file is hashed once (SHA-256,
//! streamed from disk), however many frames name it.

use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Write};
use std::path::{Component, Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use sha2::{Digest, Sha256};
use tessera::assets::{AssetResolver, FsResolver, MemResolver, bundle_path_for, normalize_bundle_path};
use tessera::error::SceneError;
use tessera::protocol::{FileDigest, JobFile};
use tessera::scene::build::build_cameras;
use tessera::scene::load::{LoadOptions, join_errors, parse_scene};

/// Most missing files listed in one error (the count of the others follows).
const MISSING_SHOWN: usize = 10;

/// One scene file of the job.
#[derive(Clone, Debug)]
pub struct SceneFile {
    /// Its path among the job's files.
    pub path: String,
}

/// One distinct file on disk.
#[derive(Clone, Debug)]
pub struct Distinct {
    /// Where it was found (as the scene's path led there).
    pub source: PathBuf,
    pub size: u64,
    /// SHA-256 (hex), once hashed.
    pub sha256: String,
}

/// One path of the job.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    /// Index into [`Packed::distinct`].
    pub file: usize,
    /// A scene file of the job (not only an asset).
    pub scene: bool,
}

/// Scenes packed for submission.
#[derive(Debug)]
pub struct Packed {
    /// In frame order.
    pub scenes: Vec<SceneFile>,
    /// Every path of the job, sorted.
    pub entries: BTreeMap<String, Entry>,
    pub distinct: Vec<Distinct>,
    /// The parsers' warnings, each once (a warning every frame repeats is counted).
    pub warnings: Vec<String>,
    /// Seconds spent parsing and locating, and hashing.
    pub list_seconds: f64,
    pub hash_seconds: f64,
}

impl Packed {
    /// Bytes of every distinct file.
    pub fn total_bytes(&self) -> u64 {
        self.distinct.iter().map(|d| d.size).sum()
    }

    /// The job's files for a [`tessera::protocol::JobRequest`], sorted by path.
    pub fn job_files(&self) -> Vec<JobFile> {
        self.entries
            .iter()
            .map(|(path, e)| {
                let d = &self.distinct[e.file];
                JobFile { path: path.clone(), sha256: d.sha256.clone(), size: d.size }
            })
            .collect()
    }

    /// Every distinct file's digest, in order.
    pub fn digests(&self) -> Vec<FileDigest> {
        self.distinct.iter().map(|d| FileDigest { sha256: d.sha256.clone(), size: d.size }).collect()
    }

    /// The job's files as a gzip-compressed tar (for a server without content-addressed files):
    /// entries sorted, mode 0644, mtime 0.
    pub fn tar_gz(&self) -> Result<Vec<u8>> {
        let gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        let mut builder = tar::Builder::new(gz);
        for (path, e) in &self.entries {
            let d = &self.distinct[e.file];
            let bytes = std::fs::read(&d.source)
                .with_context(|| format!("cannot read {} to pack it", d.source.display()))?;
            if bytes.len() as u64 != d.size {
                bail!("{} changed while it was being packed; submit again", d.source.display());
            }
            let mut header = tar::Header::new_gnu();
            header.set_size(bytes.len() as u64);
            header.set_mode(0o644);
            header.set_mtime(0);
            header.set_entry_type(tar::EntryType::Regular);
            builder
                .append_data(&mut header, path, bytes.as_slice())
                .with_context(|| format!("cannot pack {path}"))?;
        }
        let mut gz = builder.into_inner().context("cannot finish the bundle")?;
        gz.flush().context("cannot finish the bundle")?;
        gz.finish().context("cannot finish the bundle")
    }
}

/// `path` made absolute (against the current directory) with `.` and `..` resolved by name,
/// as the operating system would read it when no folder on the way is a link.
fn absolute(path: &Path) -> Result<PathBuf> {
    let abs =
        std::path::absolute(path).with_context(|| format!("{}: cannot make it absolute", path.display()))?;
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    Ok(out)
}

/// The deepest folder holding every one of `files` (absolute, normalised).
pub fn top_folder<'a>(files: impl IntoIterator<Item = &'a Path>) -> PathBuf {
    let mut top: Option<PathBuf> = None;
    for f in files {
        let dir = f.parent().unwrap_or(Path::new("/"));
        top = Some(match top {
            None => dir.to_path_buf(),
            Some(t) => {
                t.components().zip(dir.components()).take_while(|(a, b)| a == b).map(|(a, _)| a).collect()
            }
        });
    }
    top.unwrap_or_else(|| PathBuf::from("/"))
}

/// `file`'s job path below `top`: `/`-separated, checked to be a path the farm accepts as it is.
pub fn job_path(top: &Path, file: &Path) -> Result<String> {
    let rel = file
        .strip_prefix(top)
        .with_context(|| format!("{} is not below {}", file.display(), top.display()))?;
    let mut parts = Vec::new();
    for c in rel.components() {
        let Component::Normal(name) = c else {
            bail!("{}: not a plain path below {}", file.display(), top.display())
        };
        let Some(name) = name.to_str() else {
            bail!("{}: the file name is not UTF-8; rename it", file.display())
        };
        parts.push(name);
    }
    let joined = parts.join("/");
    if normalize_bundle_path(&joined).as_deref() != Some(joined.as_str()) {
        bail!(
            "{}: the farm cannot take a file named like this (a ':' or '\\' in a name); rename it",
            file.display()
        );
    }
    Ok(joined)
}

/// "frame 199 (input/w_199.json): " for a sequence, nothing for a single scene. Frames are
/// numbered from 0, as the job's JSON, `tessera status` and `tessera requeue --frames` number
/// them.
fn frame_prefix(count: usize, first_frame: usize, scene: &Path) -> String {
    if count > 1 { format!("frame {first_frame} ({}): ", scene.display()) } else { String::new() }
}

/// SHA-256 (hex) of the file at `path`, streamed.
pub fn sha256_file(path: &Path) -> Result<(String, u64)> {
    let mut f = std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut size = 0u64;
    loop {
        let n = f.read(&mut buf).with_context(|| format!("cannot read {}", path.display()))?;
        if n == 0 {
            break;
        }
        size += n as u64;
        hasher.update(&buf[..n]);
    }
    Ok((format!("{:x}", hasher.finalize()), size))
}

/// What [`pack`] is told.
#[derive(Clone, Copy, Debug, Default)]
pub struct PackOptions<'a> {
    /// Unsupported elements are warnings (the server's `allow_unsupported`), not errors.
    pub allow_unsupported: bool,
    /// Leave the files unhashed (`--dry-run`).
    pub skip_hash: bool,
    /// `--cameras`: the cameras of each scene to render (1-based), checked against every scene.
    pub cameras: Option<&'a [u32]>,
}

/// Parses `scenes` (frame order), finds every file they name and lays them out as one job.
pub fn pack(scenes: &[PathBuf], opts: PackOptions) -> Result<Packed> {
    let started = Instant::now();
    if scenes.is_empty() {
        bail!("no scene file given; name one or more (e.g. tessera submit a_000.json a_001.json)");
    }
    let count = scenes.len();
    // (scene index, the asset path as written, where it was found: as the OS reads it, and
    // that path normalised by name for the layout).
    let mut uses: Vec<(usize, String, PathBuf, PathBuf)> = Vec::new();
    let mut missing: Vec<String> = Vec::new();
    let mut warnings: Vec<(String, usize)> = Vec::new();
    let mut scene_abs = Vec::with_capacity(count);
    let mut located: HashMap<(PathBuf, String), Option<PathBuf>> = HashMap::new();
    let mut first_frame = 0usize;
    let unsupported =
        if opts.allow_unsupported { LoadOptions::ALLOW_UNSUPPORTED } else { LoadOptions::STRICT };
    for (k, scene) in scenes.iter().enumerate() {
        let bytes = std::fs::read(scene).map_err(|e| {
            anyhow::anyhow!(
                "{}{}: cannot read the scene file: {e}",
                frame_prefix(count, first_frame, scene),
                scene.display()
            )
        })?;
        let text = std::str::from_utf8(&bytes).map_err(|e| {
            anyhow::anyhow!(
                "{}{}: the scene file is not UTF-8 text (byte {}); save it as UTF-8",
                frame_prefix(count, first_frame, scene),
                scene.display(),
                e.valid_up_to()
            )
        })?;
        let prefix = frame_prefix(count, first_frame, scene);
        let records = parse_scene(text, scene).map_err(|e| anyhow::anyhow!("{prefix}{e}"))?;
        if let Err(errors) = unsupported.check(&records.warnings) {
            let e = join_errors(errors).expect("some errors");
            bail!("{prefix}{e}\n(--allow-unsupported renders the scene without them)");
        }
        let cams = build_cameras(&records).map_err(|e| anyhow::anyhow!("{prefix}{e}"))?;
        if cams.is_empty() {
            bail!(
                "{prefix}{}: the scene has no camera, so nothing to render; add one under <Cameras>",
                scene.display()
            );
        }
        let abs = absolute(scene)?;
        let fs = FsResolver::for_scene(&abs);
        for a in records.asset_paths() {
            let found = located
                .entry((fs.base_dir.clone(), a.path.clone()))
                .or_insert_with(|| fs.locate(&a.path))
                .clone();
            match found {
                Some(at) => {
                    let lexical = absolute(&at)?;
                    uses.push((k, a.path, at, lexical));
                }
                None => missing.push(format!(
                    "{prefix}{}",
                    SceneError::new(
                        scene,
                        a.loc,
                        format!(
                            "cannot find the {} {}; check the path (it is relative to the scene file)",
                            a.kind.describe(),
                            fs.display_path(&a.path).display()
                        )
                    )
                )),
            }
        }
        let frames = match &opts.cameras {
            None => cams.len(),
            Some(list) => {
                if let Some(k) = list.iter().find(|&&k| k == 0 || k as usize > cams.len()) {
                    bail!(
                        "{prefix}--cameras: camera {k} does not exist in {}; it has {} camera(s), numbered from 1",
                        scene.display(),
                        cams.len()
                    );
                }
                list.len()
            }
        };
        // Each warning once, with the frames of the other scene files that repeat it.
        for w in &records.warnings {
            let w = w.to_string();
            match warnings.iter_mut().find(|(m, _)| strip_file(m) == strip_file(&w)) {
                Some((_, n)) if count > 1 => *n += frames,
                _ => warnings.push((format!("{prefix}{w}"), 0)),
            }
        }
        first_frame += frames;
        scene_abs.push(abs);
    }
    if !missing.is_empty() {
        let n = missing.len();
        let mut text = missing.into_iter().take(MISSING_SHOWN).collect::<Vec<_>>().join("\n");
        if n > MISSING_SHOWN {
            text.push_str(&format!("\n... and {} more", n - MISSING_SHOWN));
        }
        bail!("{text}\nnothing was uploaded");
    }

    // The layout: the top folder, each file's job path, files by canonical path.
    let top =
        top_folder(scene_abs.iter().map(PathBuf::as_path).chain(uses.iter().map(|(_, _, _, p)| p.as_path())));
    let mut distinct: Vec<Distinct> = Vec::new();
    let mut by_canonical: HashMap<PathBuf, usize> = HashMap::new();
    let mut canonical_of: HashMap<PathBuf, usize> = HashMap::new();
    let mut entries: BTreeMap<String, Entry> = BTreeMap::new();
    // `found`: the path as the OS reads it (identity, bytes); `lexical`: for the layout.
    let mut place = |found: &Path,
                     lexical: &Path,
                     scene: bool,
                     entries: &mut BTreeMap<String, Entry>|
     -> Result<(String, usize)> {
        let file = match canonical_of.get(found) {
            Some(&i) => i,
            None => {
                let canonical = std::fs::canonicalize(found)
                    .with_context(|| format!("cannot read {}", found.display()))?;
                let i = *by_canonical.entry(canonical).or_insert_with(|| {
                    distinct.push(Distinct { source: found.to_path_buf(), size: 0, sha256: String::new() });
                    distinct.len() - 1
                });
                canonical_of.insert(found.to_path_buf(), i);
                i
            }
        };
        let path = job_path(&top, lexical)?;
        add_entry(entries, &path, Entry { file, scene }, found)?;
        Ok((path, file))
    };
    let mut scene_files = Vec::with_capacity(count);
    for (k, abs) in scene_abs.iter().enumerate() {
        let (path, _) = place(&scenes[k], abs, true, &mut entries)?;
        scene_files.push(SceneFile { path });
    }
    let mut asset_file: Vec<usize> = Vec::with_capacity(uses.len());
    for (_, _, found, lexical) in &uses {
        asset_file.push(place(found, lexical, false, &mut entries)?.1);
    }

    // Where the farm would look for each path a scene names: where it finds another file or
    // none, the file goes (also) where it looks first.
    let mut mem = MemResolver {
        files: entries.keys().map(|p| (p.clone(), Arc::new(Vec::new()))).collect(),
        base: String::new(),
    };
    for pass in 0..2 {
        for ((k, rel, at, _), &file) in uses.iter().zip(&asset_file) {
            let scene_path = &scene_files[*k].path;
            mem.base = scene_path.rsplit_once('/').map_or(String::new(), |(d, _)| d.to_string());
            let found = mem.read(rel).ok().map(|(_, p)| p.to_string_lossy().into_owned());
            if found.as_ref().and_then(|p| entries.get(p)).is_some_and(|e| e.file == file) {
                continue;
            }
            let Some(first) = bundle_path_for(&mem.base, rel) else {
                bail!(
                    "{}: the path {rel:?} names no file the farm can look up; name the file by its path relative to the scene file",
                    scenes[*k].display()
                );
            };
            if pass == 1 {
                bail!(
                    "{}: the farm would not find {rel:?} ({}) among the job's files; rename or move the files so that each path a scene names leads to one file",
                    scenes[*k].display(),
                    at.display()
                );
            }
            add_entry(&mut entries, &first, Entry { file, scene: false }, at)?;
            mem.files.insert(first, Arc::new(Vec::new()));
        }
    }
    let list_seconds = started.elapsed().as_secs_f64();

    let started = Instant::now();
    for d in &mut distinct {
        if opts.skip_hash {
            d.size = std::fs::metadata(&d.source)
                .with_context(|| format!("cannot read {}", d.source.display()))?
                .len();
        } else {
            (d.sha256, d.size) = sha256_file(&d.source)?;
        }
    }
    let warnings = warnings.into_iter().map(|(w, more)| with_more_frames(w, more)).collect();
    Ok(Packed {
        scenes: scene_files,
        entries,
        distinct,
        warnings,
        list_seconds,
        hash_seconds: started.elapsed().as_secs_f64(),
    })
}

/// `warning`, and when `more` other frames repeat it, "(and in N more frames)".
fn with_more_frames(warning: String, more: usize) -> String {
    match more {
        0 => warning,
        1 => format!("{warning} (and in 1 more frame)"),
        n => format!("{warning} (and in {n} more frames)"),
    }
}

/// The server's `warnings` of a job that the client has not shown yet (`shown`: the pack's
/// warnings), each once with the count of the other frames that repeat it: the server lists a
/// sequence's warnings frame by frame.
pub fn unseen_warnings(shown: &[String], warnings: &[String]) -> Vec<String> {
    let mut out: Vec<(String, usize)> = Vec::new();
    // What was shown, without its count of frames.
    let shown: Vec<&str> = shown
        .iter()
        .map(|s| match s.rfind(" (and in ") {
            Some(k) if s.ends_with(" more frames)") || s.ends_with(" more frame)") => &s[..k],
            _ => s.as_str(),
        })
        .collect();
    for w in warnings {
        if shown.iter().any(|s| strip_file(s) == strip_file(w)) {
            continue;
        }
        match out.iter_mut().find(|(m, _)| strip_file(m) == strip_file(w)) {
            Some((_, n)) => *n += 1,
            None => out.push((w.clone(), 0)),
        }
    }
    out.into_iter().map(|(w, more)| with_more_frames(w, more)).collect()
}

/// A warning's text without the scene file's name (the same warning in every frame of a
/// sequence is one warning).
fn strip_file(w: &str) -> &str {
    // "warning: FILE:LINE: ..." or "frame N (FILE): warning: FILE:LINE: ...": what follows the
    // file's name.
    let w = w.rsplit_once("warning: ").map_or(w, |(_, rest)| rest);
    w.split_once(':').map_or(w, |(_, rest)| rest)
}

/// Adds `path` → `entry`, or checks that it is already that file.
fn add_entry(entries: &mut BTreeMap<String, Entry>, path: &str, entry: Entry, source: &Path) -> Result<()> {
    match entries.get_mut(path) {
        None => {
            entries.insert(path.to_string(), entry);
        }
        Some(e) if e.file == entry.file => e.scene |= entry.scene,
        Some(_) => bail!(
            "{} and another file would both be {path} among the job's files, with different contents; rename one of them",
            source.display()
        ),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_testkit::TempDir;

    const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 -2\n1 0 -2\n0 1 -2\n3 0 1 2\n";

    /// A scene in `dir/xml/` naming a PLY beside it, one a folder up, one through a rewritten
    /// path (found by the fallback) and an image, with a file it does not use next to them.
    fn scene_with_assets(dir: &Path) -> PathBuf {
        for d in ["xml/ply", "models", "xml/textures"] {
            std::fs::create_dir_all(dir.join(d)).unwrap();
        }
        std::fs::write(dir.join("xml/ply/a.ply"), PLY).unwrap();
        std::fs::write(dir.join("models/b.ply"), PLY.replace("-2", "-3")).unwrap();
        std::fs::write(dir.join("xml/ply/c.ply"), PLY.replace("-2", "-4")).unwrap();
        std::fs::write(dir.join("xml/ply/unused.ply"), PLY).unwrap();
        std::fs::write(dir.join("xml/textures/t.png"), image_png_2x2()).unwrap();
        let scene = dir.join("xml/s.xml");
        std::fs::write(
            &scene,
            scene_xml(
                "s.png",
                r#"<Textures><Images><Image id="1">textures/t.png</Image></Images>
<TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode></TextureMap></Textures>
<Objects>
<Mesh id="1"><Material>1</Material><Textures>1</Textures><Faces plyFile="ply/a.ply"/></Mesh>
<Mesh id="2"><Material>1</Material><Faces plyFile="../models/b.ply"/></Mesh>
<Mesh id="3"><Material>1</Material><Faces plyFile="assets/ply/c.ply"/></Mesh>
<Mesh id="4"><Material>1</Material><Faces plyFile="ply/a.ply"/></Mesh>
</Objects>"#,
            ),
        )
        .unwrap();
        scene
    }

    /// A scene file of one 4x4 camera writing `image` and one white material, then `body`.
    fn scene_xml(image: &str, body: &str) -> String {
        format!(
            r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
<ImageName>{image}</ImageName></Camera></Cameras>
<Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
{body}</Scene>"#
        )
    }

    fn image_png_2x2() -> Vec<u8> {
        tessera::hdr_io::encode_png_rgb8(2, 2, &[255, 0, 0, 0, 255, 0, 0, 0, 255, 9, 9, 9]).unwrap()
    }

    fn paths(p: &Packed) -> Vec<&str> {
        p.entries.keys().map(String::as_str).collect()
    }

    #[test]
    fn top_folders_and_job_paths() {
        let t = |v: &[&str]| top_folder(v.iter().map(Path::new));
        assert_eq!(t(&["/a/b/s.json", "/a/b/ply/x.ply"]), PathBuf::from("/a/b"));
        assert_eq!(t(&["/a/b/input/s.json", "/a/b/ply/x.ply"]), PathBuf::from("/a/b"));
        assert_eq!(t(&["/a/b/s.json", "/c/x.ply"]), PathBuf::from("/"));
        assert_eq!(t(&["/a/bc/s.json", "/a/b/x.ply"]), PathBuf::from("/a"), "whole names, not prefixes");
        assert_eq!(job_path(Path::new("/a/b"), Path::new("/a/b/ply/x.ply")).unwrap(), "ply/x.ply");
        assert_eq!(job_path(Path::new("/"), Path::new("/c/x.ply")).unwrap(), "c/x.ply");
        let e = job_path(Path::new("/a"), Path::new("/a/c:d.ply")).unwrap_err().to_string();
        assert!(e.contains("rename it"), "{e}");
        assert!(job_path(Path::new("/a/b"), Path::new("/a/x.ply")).is_err());
        assert_eq!(absolute(Path::new("/a/./b/../c.ply")).unwrap(), PathBuf::from("/a/c.ply"));
    }

    #[test]
    fn packs_the_files_the_renderer_reads_where_the_farm_finds_them() {
        let dir = TempDir::new("client-pack");
        let scene = scene_with_assets(&dir);
        let packed = pack(std::slice::from_ref(&scene), PackOptions::default()).unwrap();
        // The top folder holds xml/ and models/.
        assert_eq!(packed.scenes[0].path, "xml/s.xml");
        assert_eq!(
            paths(&packed),
            ["models/b.ply", "xml/ply/a.ply", "xml/ply/c.ply", "xml/s.xml", "xml/textures/t.png"]
        );
        assert_eq!(packed.distinct.len(), 5);
        for (path, e) in &packed.entries {
            let d = &packed.distinct[e.file];
            let bytes = std::fs::read(&d.source).unwrap();
            assert_eq!(d.size, bytes.len() as u64, "{path}");
            assert_eq!(d.sha256, format!("{:x}", Sha256::digest(&bytes)), "{path}");
        }
        // The farm's own path from a bundle to a scene reads it, with the same assets.
        let gz = packed.tar_gz().unwrap();
        let mut raw = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(gz.as_slice()), &mut raw).unwrap();
        let files = tessera::bundle::read_tar(&raw).unwrap();
        let farm = tessera::bundle::load_bundle_scene(files, "xml/s.xml", LoadOptions::default()).unwrap();
        let cli = tessera::scene::load::load_scene_file(&scene).unwrap();
        assert_eq!(farm.stats.triangles, cli.stats.triangles);
        assert_eq!(farm.stats.triangles, 4);
    }

    #[test]
    fn a_sequence_shares_its_files_and_a_missing_one_names_scene_frame_and_path() {
        let dir = TempDir::new("client-pack-seq");
        std::fs::create_dir_all(dir.join("input")).unwrap();
        std::fs::create_dir_all(dir.join("ply")).unwrap();
        std::fs::write(dir.join("ply/m.ply"), PLY).unwrap();
        let body =
            r#"<Objects><Mesh id="1"><Material>1</Material><Faces plyFile="../ply/m.ply"/></Mesh></Objects>"#;
        let scenes: Vec<PathBuf> = (0..5)
            .map(|k| {
                let p = dir.join(format!("input/f_{k:03}.xml"));
                std::fs::write(&p, scene_xml(&format!("f_{k:03}.png"), body)).unwrap();
                p
            })
            .collect();
        let packed = pack(&scenes, PackOptions::default()).unwrap();
        assert_eq!(packed.distinct.len(), 6, "five scenes and one PLY");
        assert_eq!(
            paths(&packed),
            [
                "input/f_000.xml",
                "input/f_001.xml",
                "input/f_002.xml",
                "input/f_003.xml",
                "input/f_004.xml",
                "ply/m.ply"
            ]
        );
        let order: Vec<&str> = packed.scenes.iter().map(|s| s.path.as_str()).collect();
        assert_eq!(order[0], "input/f_000.xml");
        // The order given is kept.
        let reversed: Vec<PathBuf> = scenes.iter().rev().cloned().collect();
        let packed = pack(&reversed, PackOptions::default()).unwrap();
        assert_eq!(packed.scenes[0].path, "input/f_004.xml");
        // Frame 3's PLY (frames count from 0) is missing: refused, naming the scene, its frame and the path.
        std::fs::write(&scenes[3], scene_xml("f_003.png", &body.replace("m.ply", "gone.ply"))).unwrap();
        let e = pack(&scenes, PackOptions::default()).unwrap_err().to_string();
        assert!(e.starts_with(&format!("frame 3 ({}): ", scenes[3].display())), "{e}");
        assert!(e.contains("f_003.xml:5: <Mesh id=\"1\"> / <Faces>: cannot find the PLY file"), "{e}");
        assert!(e.contains("ply/gone.ply") && e.ends_with("nothing was uploaded"), "{e}");
    }

    #[test]
    fn a_path_the_farm_resolves_elsewhere_is_also_put_where_it_looks_first() {
        // a/s.xml names "b/ply/x.ply", found on disk at a/ply/x.ply by the fallback (leading
        // components stripped).
        let dir = TempDir::new("client-pack-alias");
        std::fs::create_dir_all(dir.join("a/ply")).unwrap();
        std::fs::create_dir_all(dir.join("b/ply")).unwrap();
        std::fs::write(dir.join("a/ply/x.ply"), PLY).unwrap();
        std::fs::write(dir.join("b/ply/x.ply"), PLY.replace("-2", "-6")).unwrap();
        let a = dir.join("a/s.xml");
        std::fs::write(&a, scene_xml("a.png", r#"<Objects><Mesh id="1"><Material>1</Material><Faces plyFile="b/ply/x.ply"/></Mesh></Objects>"#)).unwrap();
        // Alone, the farm's fallback finds it at the same place.
        let packed = pack(std::slice::from_ref(&a), PackOptions::default()).unwrap();
        assert_eq!(paths(&packed), ["ply/x.ply", "s.xml"]);
        // With b/s.xml in the job, the top folder is dir, and the farm would look for "b/ply/x.ply"
        // relative to the top (its second candidate) before the stripped path: a/ply/x.ply
        // is put at a/b/ply/x.ply, where it looks first.
        let b = dir.join("b/s.xml");
        std::fs::write(&b, scene_xml("b.png", r#"<Objects><Mesh id="1"><Material>1</Material><Faces plyFile="ply/x.ply"/></Mesh></Objects>"#)).unwrap();
        let packed = pack(&[a.clone(), b], PackOptions::default()).unwrap();
        assert_eq!(paths(&packed), ["a/b/ply/x.ply", "a/ply/x.ply", "a/s.xml", "b/ply/x.ply", "b/s.xml"]);
        assert_eq!(packed.entries["a/b/ply/x.ply"].file, packed.entries["a/ply/x.ply"].file);
        assert_eq!(packed.distinct.len(), 4);
    }

    #[cfg(unix)]
    #[test]
    fn two_files_on_one_job_path_are_refused() {
        // "ply/../x.ply" read through a link "ply" is another folder's x.ply, but its job path
        // (by name) is x.ply, beside the scene, where another x.ply is.
        let dir = TempDir::new("client-pack-clash");
        std::fs::create_dir_all(dir.join("s")).unwrap();
        std::fs::create_dir_all(dir.join("elsewhere/deep")).unwrap();
        std::fs::write(dir.join("s/x.ply"), PLY).unwrap();
        std::fs::write(dir.join("elsewhere/x.ply"), PLY.replace("-2", "-5")).unwrap();
        std::os::unix::fs::symlink(dir.join("elsewhere/deep"), dir.join("s/ply")).unwrap();
        let scene = dir.join("s/a.xml");
        std::fs::write(
            &scene,
            scene_xml(
                "a.png",
                r#"<Objects><Mesh id="1"><Material>1</Material><Faces plyFile="x.ply"/></Mesh>
<Mesh id="2"><Material>1</Material><Faces plyFile="ply/../x.ply"/></Mesh></Objects>"#,
            ),
        )
        .unwrap();
        let e = pack(&[scene], PackOptions::default()).unwrap_err().to_string();
        assert!(e.contains("would both be x.ply among the job's files, with different contents"), "{e}");
    }
}
