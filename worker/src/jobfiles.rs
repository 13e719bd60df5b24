//! A farm job's files by manifest: a lease of a job stored since sequences names its
//! [`Manifest`] (a file of the server's file store) and the frame's scene file; the worker
//! fetches the manifest, then each file a scene names, by SHA-256
//! (`GET /api/v1/worker/files/{sha256}`), each verified against its hash and fetched once
//! ([`fetch_file`], the one place files come from), and builds the scene with a resolver that
//! finds paths where the server's validation found them (`tessera::assets::bundle_candidates`).

use std::collections::HashMap;
use std::io::{self, Read};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

use anyhow::{Context, Result, anyhow, bail};
use sha2::{Digest, Sha256};
use tessera::assets::{AssetResolver, MemResolver, bundle_candidates, scene_dir};
use tessera::bundle::load_scene_bytes;
use tessera::protocol::{JobFile, Manifest};
use tessera::scene::Scene;
use tessera::scene::load::LoadOptions;

use crate::farm::{Client, describe};

/// Bytes of fetched files kept in memory at most: past it the kept files are let go (and
/// fetched again when a scene needs them).
const KEPT_BYTES: usize = 1 << 30;

/// Files fetched so far, by SHA-256, and their bytes in all: each is downloaded once per
/// worker process while it is kept.
#[derive(Default)]
struct Fetched {
    files: HashMap<String, Arc<Vec<u8>>>,
    bytes: usize,
}

fn fetched() -> &'static Mutex<Fetched> {
    static FILES: OnceLock<Mutex<Fetched>> = OnceLock::new();
    FILES.get_or_init(Default::default)
}

/// The file `sha` (of `size` bytes, when known) from the server, verified against its
/// SHA-256; fetched once, then answered from memory.
pub fn fetch_file(client: &Client, sha: &str, size: Option<u64>) -> Result<Arc<Vec<u8>>> {
    if let Some(bytes) = fetched().lock().unwrap_or_else(|e| e.into_inner()).files.get(sha) {
        return Ok(bytes.clone());
    }
    let resp = client
        .agent
        .get(&client.url(&format!("/api/v1/worker/files/{sha}")))
        .set("Authorization", &format!("Bearer {}", client.token))
        .call()
        .map_err(|e| anyhow!("fetching file {sha}: {}", describe(e)))?;
    let mut bytes = Vec::with_capacity(size.unwrap_or(0).min(1 << 30) as usize);
    resp.into_reader().read_to_end(&mut bytes).with_context(|| format!("downloading file {sha}"))?;
    if let Some(size) = size
        && bytes.len() as u64 != size
    {
        bail!("file {sha}: the server sent {} bytes, the manifest says {size}", bytes.len());
    }
    let actual = Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect::<String>();
    if actual != sha {
        bail!("file {sha}: the bytes the server sent hash to {actual}; not using them");
    }
    let bytes = Arc::new(bytes);
    let mut kept = fetched().lock().unwrap_or_else(|e| e.into_inner());
    if kept.bytes + bytes.len() > KEPT_BYTES {
        *kept = Fetched::default();
    }
    kept.bytes += bytes.len();
    kept.files.insert(sha.to_string(), bytes.clone());
    Ok(bytes)
}

/// A job's files by path, from its manifest.
pub type ManifestFiles = HashMap<String, JobFile>;

/// The manifest `sha`'s files, fetched once.
pub fn manifest(client: &Client, sha: &str) -> Result<Arc<ManifestFiles>> {
    static MANIFESTS: OnceLock<Mutex<HashMap<String, Arc<ManifestFiles>>>> = OnceLock::new();
    let manifests = MANIFESTS.get_or_init(Default::default);
    if let Some(m) = manifests.lock().unwrap_or_else(|e| e.into_inner()).get(sha) {
        return Ok(m.clone());
    }
    let bytes = fetch_file(client, sha, None)?;
    let parsed: Manifest =
        serde_json::from_slice(&bytes).with_context(|| format!("the job's manifest {sha} does not parse"))?;
    let files: Arc<ManifestFiles> = Arc::new(parsed.files.into_iter().map(|f| (f.path.clone(), f)).collect());
    manifests.lock().unwrap_or_else(|e| e.into_inner()).insert(sha.to_string(), files.clone());
    Ok(files)
}

/// Finds a scene's assets among a manifest's files, looking where a [`MemResolver`] over the
/// same files would, and fetches them ([`fetch_file`]).
struct ManifestResolver<'a> {
    client: &'a Client,
    files: &'a ManifestFiles,
    /// The scene file's folder (a path of the manifest; "" for the top).
    base: String,
}

impl AssetResolver for ManifestResolver<'_> {
    fn read(&self, rel: &str) -> io::Result<(Vec<u8>, PathBuf)> {
        for cand in bundle_candidates(&self.base, rel) {
            if let Some(f) = self.files.get(&cand) {
                let bytes = fetch_file(self.client, &f.sha256, Some(f.size))
                    .map_err(|e| io::Error::other(format!("{e:#}")))?;
                return Ok((bytes.as_ref().clone(), PathBuf::from(cand)));
            }
        }
        Err(io::Error::new(io::ErrorKind::NotFound, "not among the job's files"))
    }

    fn display_path(&self, rel: &str) -> PathBuf {
        MemResolver { files: HashMap::new(), base: self.base.clone() }.display_path(rel)
    }
}

/// Builds the scene `scene_path` of the job whose manifest is `manifest_sha`, with its assets
/// from the manifest (the server validated it the same way).
pub fn manifest_scene(
    client: &Client,
    manifest_sha: &str,
    scene_path: &str,
    options: LoadOptions,
) -> Result<Scene> {
    let files = manifest(client, manifest_sha)?;
    let scene =
        files.get(scene_path).ok_or_else(|| anyhow!("the job's manifest has no scene file {scene_path}"))?;
    let bytes = fetch_file(client, &scene.sha256, Some(scene.size))?;
    let resolver = ManifestResolver { client, files: &files, base: scene_dir(scene_path) };
    Ok(load_scene_bytes(&bytes, scene_path, &resolver, options)?)
}
