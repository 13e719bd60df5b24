//! A farm job's files by manifest: a lease of a job stored since sequences names its
//! [`Manifest`] (a file of the server's file store) and the frame's scene file; the worker
//! fetches the manifest, then each file a scene names, by SHA-256
//! (`GET /api/v1/worker/files/{sha256}`), each verified against its hash and fetched once
//! ([`fetch_file`], the one place files come from), and builds the scene with a resolver that
//! finds paths where the server's validation found them (`tessera::assets::bundle_candidates`).

use std::collections::HashMap;
use std::io;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

use anyhow::{Context, Result, anyhow, bail};
use sha2::{Digest, Sha256};
use tessera::assets::{AssetResolver, MemResolver, bundle_candidates, scene_dir};
use tessera::bundle::load_scene_bytes;
use tessera::protocol::{JobFile, Manifest};
use tessera::scene::Scene;
use tessera::scene::load::LoadOptions;

use crate::farm::{Caches, Client, describe};
use crate::filecache::FileCache;

/// Manifests fetched so far (small JSON files whose size a lease does not say), by SHA-256.
fn manifests_fetched() -> &'static Mutex<HashMap<String, Arc<Vec<u8>>>> {
    static FILES: OnceLock<Mutex<HashMap<String, Arc<Vec<u8>>>>> = OnceLock::new();
    FILES.get_or_init(Default::default)
}

/// Downloads the file `sha` from the server into `out`.
fn download(client: &Client, sha: &str, out: &mut dyn std::io::Write) -> Result<()> {
    let resp = client
        .agent
        .get(&client.url(&format!("/api/v1/worker/files/{sha}")))
        .set("Authorization", &format!("Bearer {}", client.token))
        .call()
        .map_err(|e| anyhow!("fetching file {sha}: {}", describe(e)))?;
    std::io::copy(&mut resp.into_reader(), out).with_context(|| format!("downloading file {sha}"))?;
    Ok(())
}

/// The file `sha` of `size` bytes, from the worker's file cache on disk or downloaded once
/// into it (checked against its size and SHA-256 before it is kept), or, when its size is not
/// known (a manifest), downloaded once per process, checked and kept in memory.
pub fn fetch_file(client: &Client, cache: &FileCache, sha: &str, size: Option<u64>) -> Result<Arc<Vec<u8>>> {
    if let Some(size) = size {
        return cache.get_or_fetch(sha, size, |out| download(client, sha, out));
    }
    if let Some(bytes) = manifests_fetched().lock().unwrap_or_else(|e| e.into_inner()).get(sha) {
        return Ok(bytes.clone());
    }
    let mut bytes = Vec::new();
    download(client, sha, &mut bytes)?;
    let actual = Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect::<String>();
    if actual != sha {
        bail!("file {sha}: the bytes the server sent hash to {actual}; not using them");
    }
    let bytes = Arc::new(bytes);
    manifests_fetched().lock().unwrap_or_else(|e| e.into_inner()).insert(sha.to_string(), bytes.clone());
    Ok(bytes)
}

/// A job's files by path, from its manifest.
pub type ManifestFiles = HashMap<String, JobFile>;

/// The manifest `sha`'s files, fetched once.
pub fn manifest(client: &Client, cache: &FileCache, sha: &str) -> Result<Arc<ManifestFiles>> {
    static MANIFESTS: OnceLock<Mutex<HashMap<String, Arc<ManifestFiles>>>> = OnceLock::new();
    let manifests = MANIFESTS.get_or_init(Default::default);
    if let Some(m) = manifests.lock().unwrap_or_else(|e| e.into_inner()).get(sha) {
        return Ok(m.clone());
    }
    let bytes = fetch_file(client, cache, sha, None)?;
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
    cache: &'a FileCache,
    files: &'a ManifestFiles,
    /// The scene file's folder (a path of the manifest; "" for the top).
    base: String,
}

impl ManifestResolver<'_> {
    /// The manifest's file a scene's path `rel` names, and its path in the manifest.
    fn find(&self, rel: &str) -> Option<(String, &JobFile)> {
        bundle_candidates(&self.base, rel).into_iter().find_map(|cand| {
            let f = self.files.get(&cand)?;
            Some((cand, f))
        })
    }
}

impl AssetResolver for ManifestResolver<'_> {
    fn read(&self, rel: &str) -> io::Result<(Vec<u8>, PathBuf)> {
        let Some((path, f)) = self.find(rel) else {
            return Err(io::Error::new(io::ErrorKind::NotFound, "not among the job's files"));
        };
        let bytes = fetch_file(self.client, self.cache, &f.sha256, Some(f.size))
            .map_err(|e| io::Error::other(format!("{e:#}")))?;
        Ok((bytes.as_ref().clone(), PathBuf::from(path)))
    }

    /// The manifest names every file by its SHA-256: a mesh the worker built from it before is
    /// taken from the mesh cache without fetching or reading the file.
    fn content_id(&self, rel: &str) -> Option<[u8; 32]> {
        let (_, f) = self.find(rel)?;
        let hex = f.sha256.as_bytes();
        if hex.len() != 64 {
            return None;
        }
        let mut id = [0u8; 32];
        for (k, pair) in hex.chunks(2).enumerate() {
            id[k] = u8::from_str_radix(std::str::from_utf8(pair).ok()?, 16).ok()?;
        }
        Some(id)
    }

    fn display_path(&self, rel: &str) -> PathBuf {
        MemResolver { files: HashMap::new(), base: self.base.clone() }.display_path(rel)
    }
}

/// Builds the scene `scene_path` of the job whose manifest is `manifest_sha`, with its assets
/// from the manifest (the server validated it the same way).
pub fn manifest_scene(
    client: &Client,
    caches: Caches<'_>,
    manifest_sha: &str,
    scene_path: &str,
    options: LoadOptions,
) -> Result<Scene> {
    let files = manifest(client, caches.files, manifest_sha)?;
    let scene =
        files.get(scene_path).ok_or_else(|| anyhow!("the job's manifest has no scene file {scene_path}"))?;
    let bytes = fetch_file(client, caches.files, &scene.sha256, Some(scene.size))?;
    let resolver =
        ManifestResolver { client, cache: caches.files, files: &files, base: scene_dir(scene_path) };
    Ok(load_scene_bytes(&bytes, scene_path, &resolver, options, Some(caches.meshes))?)
}
