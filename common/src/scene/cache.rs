//! What scene builds keep for the next: PLY meshes with their BVHs, and decoded images.
//!
//! A sequence of scene files (an animation, one file a frame) names the same PLY files and
//! images frame after frame. [`MeshCache`] keeps what the build makes of them, keyed by the
//! file's content (its SHA-256) and by whatever of the scene changes the result, so that a
//! frame whose meshes are cached costs its scene file, its top-level tree over instances and
//! its pixels ([`super::build::build_scene_cached`]).
//!
//! - A mesh from a PLY file: its [`MeshGeom`] (positions, triangles with the degenerate ones
//!   dropped, texture coordinates, its 8-wide BVH) depends on the bytes and on one thing of the
//!   scene: whether some user shades it smooth (then it carries vertex normals: the file's, or
//!   area-weighted ones). Key: (SHA-256, smooth). Its transformations, material, texture maps
//!   and instances are placed above it and are not part of the key.
//! - An image (texture or environment map): its decoded texels depend on the bytes alone.
//! - The world-space tree merged from a scene's static mesh instances (`geometry`'s
//!   `WorldTree`, rebuilt for every scene otherwise): it depends on the meshes and on how they
//!   are placed, so its key hashes exactly what it reads (each mesh's identity, each instance's
//!   mesh, transformation, motion, shading and whether it is textured). Frames of an animation
//!   whose camera alone moves share it; frames whose objects move build their own.
//!
//! The content key comes from [`AssetResolver::content_id`] when the resolver knows it (a
//! farm worker's files are named by their SHA-256: a hit then reads nothing); for a file of the
//! local file system (the CLI's), from the hash this cache remembers with the file's `stat`
//! identity, if the file had settled when it was hashed and has not changed since (a hit then
//! reads nothing either); else from hashing the bytes read (a hit then reads the file but does
//! not parse it). Entries are
//! bounded by an estimate of their bytes; the least recently used go first. Errors are never
//! cached: they name the scene that met them. Thread-safe; entries come out as `Arc`s, so an
//! entry evicted while a scene uses it lives until that scene is dropped.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use sha2::{Digest, Sha256};

use crate::assets::AssetResolver;
use crate::geometry::WorldTree;
use crate::geometry::mesh::MeshGeom;
use crate::texture::image::TextureImage;

/// The default bound on what a [`MeshCache`] keeps: 2 GiB.
pub const DEFAULT_MESH_CACHE_BYTES: u64 = 2 << 30;

/// The SHA-256 of `bytes`.
pub fn sha256(bytes: &[u8]) -> [u8; 32] {
    Sha256::digest(bytes).into()
}

/// A mesh built from a PLY file, as the cache keeps it.
#[derive(Clone)]
pub struct CachedMesh {
    pub geom: Arc<MeshGeom>,
    /// The degenerate triangles the build dropped (the scene warns about them on every build).
    pub dropped: usize,
}

/// What a cache entry is found by.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Key {
    /// A PLY file's content and whether its mesh carries vertex normals (smooth shading).
    Mesh { content: [u8; 32], smooth: bool },
    /// An image file's content.
    Image { content: [u8; 32] },
    /// The hash of all a scene's world tree reads (`scene::build`'s `world_tree_key`).
    World { key: [u8; 32] },
}

#[derive(Clone)]
enum Value {
    Mesh(CachedMesh),
    Image(Arc<TextureImage>),
    World(WorldTree),
}

struct Entry {
    value: Value,
    bytes: u64,
    /// The use count when it was last used (larger = more recent).
    used: u64,
}

#[derive(Default)]
struct Inner {
    entries: HashMap<Key, Entry>,
    bytes: u64,
    clock: u64,
    stats: CacheStats,
}

/// Counters of a [`MeshCache`] since it was made, and what it holds now.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Meshes found in the cache (not parsed, no BVH built).
    pub mesh_hits: u64,
    /// Meshes built (their PLY file parsed, their BVH built) and offered to the cache.
    pub mesh_misses: u64,
    /// PLY files parsed by builds that use this cache.
    pub ply_parses: u64,
    pub image_hits: u64,
    /// Images decoded and offered to the cache.
    pub image_misses: u64,
    /// World-space trees of static mesh instances reused (the scene's meshes and their
    /// placement the same as an earlier scene's: a camera moving through a still scene).
    pub world_hits: u64,
    /// World-space trees built and offered to the cache.
    pub world_misses: u64,
    /// Entries removed to stay within the bound.
    pub evictions: u64,
    /// Entries held now, and the estimate of their bytes.
    pub entries: u64,
    pub bytes: u64,
}

/// Built meshes and decoded images kept across scene builds (see the module's documentation).
pub struct MeshCache {
    inner: Mutex<Inner>,
    limit: u64,
    /// The SHA-256 of each local file hashed here, with its `stat` identity then
    /// ([`MeshCache::content_key`]).
    files: Mutex<HashMap<PathBuf, (FileStamp, [u8; 32])>>,
}

impl Default for MeshCache {
    fn default() -> Self {
        MeshCache::new(DEFAULT_MESH_CACHE_BYTES)
    }
}

impl std::fmt::Debug for MeshCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MeshCache(limit {} bytes, {:?})", self.limit, self.stats())
    }
}

impl MeshCache {
    /// A cache that keeps at most about `limit_bytes` (by [`MeshGeom::heap_bytes`] and the
    /// images' texels). An entry larger than the whole bound is not kept.
    pub fn new(limit_bytes: u64) -> Self {
        MeshCache { inner: Mutex::default(), limit: limit_bytes, files: Mutex::default() }
    }

    /// The bound it was made with.
    pub fn limit_bytes(&self) -> u64 {
        self.limit
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Its counters and size now.
    pub fn stats(&self) -> CacheStats {
        let inner = self.lock();
        CacheStats { entries: inner.entries.len() as u64, bytes: inner.bytes, ..inner.stats }
    }

    /// The entry of `key`, marked as used now.
    fn get(&self, key: &Key) -> Option<Value> {
        let mut inner = self.lock();
        inner.clock += 1;
        let now = inner.clock;
        let entry = inner.entries.get_mut(key)?;
        entry.used = now;
        let value = entry.value.clone();
        match key {
            Key::Mesh { .. } => inner.stats.mesh_hits += 1,
            Key::Image { .. } => inner.stats.image_hits += 1,
            Key::World { .. } => inner.stats.world_hits += 1,
        }
        Some(value)
    }

    /// Keeps `value` under `key` (unless it alone is over the bound), removing the least
    /// recently used entries past the bound. When another build put the same key meanwhile,
    /// that entry stays and is returned, so that every scene shares one copy.
    fn put(&self, key: Key, value: Value, bytes: u64) -> Value {
        let mut inner = self.lock();
        match key {
            Key::Mesh { .. } => inner.stats.mesh_misses += 1,
            Key::Image { .. } => inner.stats.image_misses += 1,
            Key::World { .. } => inner.stats.world_misses += 1,
        }
        inner.clock += 1;
        let now = inner.clock;
        if let Some(e) = inner.entries.get_mut(&key) {
            e.used = now;
            return e.value.clone();
        }
        if bytes > self.limit {
            return value;
        }
        while inner.bytes + bytes > self.limit {
            let Some((&oldest, _)) = inner.entries.iter().min_by_key(|(_, e)| e.used) else { break };
            if let Some(e) = inner.entries.remove(&oldest) {
                inner.bytes -= e.bytes;
                inner.stats.evictions += 1;
            }
        }
        inner.bytes += bytes;
        inner.entries.insert(key, Entry { value: value.clone(), bytes, used: now });
        value
    }

    /// The cached mesh of the PLY file whose content is `content`, built for smooth shading
    /// or not.
    pub fn mesh(&self, content: &[u8; 32], smooth: bool) -> Option<CachedMesh> {
        match self.get(&Key::Mesh { content: *content, smooth })? {
            Value::Mesh(m) => Some(m),
            _ => None,
        }
    }

    /// Keeps a mesh just built; returns the one to use (the cache's, if another build put it
    /// first).
    pub fn put_mesh(&self, content: &[u8; 32], smooth: bool, mesh: CachedMesh) -> CachedMesh {
        let bytes = mesh.geom.heap_bytes() as u64;
        match self.put(Key::Mesh { content: *content, smooth }, Value::Mesh(mesh.clone()), bytes) {
            Value::Mesh(m) => m,
            _ => mesh,
        }
    }

    /// The cached decoded image whose file's content is `content`.
    pub fn image(&self, content: &[u8; 32]) -> Option<Arc<TextureImage>> {
        match self.get(&Key::Image { content: *content })? {
            Value::Image(i) => Some(i),
            _ => None,
        }
    }

    /// Keeps an image just decoded; returns the one to use.
    pub fn put_image(&self, content: &[u8; 32], image: Arc<TextureImage>) -> Arc<TextureImage> {
        let bytes = (std::mem::size_of::<TextureImage>() + image.texels.capacity() * 12) as u64;
        match self.put(Key::Image { content: *content }, Value::Image(image.clone()), bytes) {
            Value::Image(i) => i,
            _ => image,
        }
    }

    /// The cached world-space tree of static mesh instances under `key`.
    pub fn world_tree(&self, key: &[u8; 32]) -> Option<WorldTree> {
        match self.get(&Key::World { key: *key })? {
            Value::World(w) => Some(w),
            _ => None,
        }
    }

    /// Keeps a world-space tree just built.
    pub fn put_world_tree(&self, key: &[u8; 32], tree: WorldTree) {
        let bytes = tree.heap_bytes() as u64;
        self.put(Key::World { key: *key }, Value::World(tree), bytes);
    }

    /// Counts a PLY file parsed by a build that uses this cache.
    pub(crate) fn count_parse(&self) {
        self.lock().stats.ply_parses += 1;
    }
}

/// An asset's bytes and the path they were found at, as [`AssetResolver::read`] returns them.
pub(crate) type Read = (Vec<u8>, std::path::PathBuf);

/// The bytes of `rel` for a build whose key `content` [`MeshCache::content_key`] found without
/// reading them: `content` becomes their own hash, which a change of the file in between would
/// have moved, so nothing is kept under the key of other bytes.
pub(crate) fn read_rekeyed(
    resolver: &dyn AssetResolver,
    rel: &str,
    content: &mut [u8; 32],
) -> std::io::Result<Read> {
    let read = resolver.read(rel)?;
    *content = sha256(&read.0);
    Ok(read)
}

/// How long before its hashing a file must have last changed for [`MeshCache`] to remember its
/// hash: a write after the hashing then gives it a later time, whatever the granularity of the
/// file system's times (two seconds on FAT; a write within the same tick as the hashing could
/// leave them as they were).
const SETTLED: std::time::Duration = std::time::Duration::from_secs(3);

/// The most files whose hashes a [`MeshCache`] remembers; past it they are forgotten together.
const REMEMBERED_FILES: usize = 65_536;

/// A file's identity as `stat` gives it: a write changes its size or its modification and
/// change times (the change time cannot be set back).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct FileStamp {
    dev: u64,
    ino: u64,
    len: u64,
    modified: (i64, i64),
    changed: (i64, i64),
}

impl FileStamp {
    #[cfg(unix)]
    fn of(meta: &std::fs::Metadata) -> Option<FileStamp> {
        use std::os::unix::fs::MetadataExt;
        Some(FileStamp {
            dev: meta.dev(),
            ino: meta.ino(),
            len: meta.len(),
            modified: (meta.mtime(), meta.mtime_nsec()),
            changed: (meta.ctime(), meta.ctime_nsec()),
        })
    }

    /// Without `stat`'s change time, nothing is remembered.
    #[cfg(not(unix))]
    fn of(_meta: &std::fs::Metadata) -> Option<FileStamp> {
        None
    }

    /// Whether the file had last changed at least [`SETTLED`] before `t`.
    fn settled_before(&self, t: std::time::SystemTime) -> bool {
        let Ok(since) = t.duration_since(std::time::UNIX_EPOCH) else { return false };
        let limit = since.saturating_sub(SETTLED);
        let time = |(secs, nanos): (i64, i64)| {
            u64::try_from(secs).ok().map(|s| std::time::Duration::new(s, nanos.clamp(0, 999_999_999) as u32))
        };
        [self.modified, self.changed].into_iter().all(|t| time(t).is_some_and(|t| t <= limit))
    }
}

impl MeshCache {
    /// An asset's content key and, when they had to be read to find it, its bytes and where
    /// they were found: from [`AssetResolver::content_id`] without reading; for a local file
    /// ([`AssetResolver::local_file`]) whose `stat` identity is the one it had when this cache
    /// last hashed it, the hash remembered then, without reading; else by hashing the bytes.
    /// A caller that reads the bytes after a key found without reading reads them with
    /// [`read_rekeyed`], which keys them by their own hash.
    pub(crate) fn content_key(
        &self,
        resolver: &dyn AssetResolver,
        rel: &str,
    ) -> std::io::Result<([u8; 32], Option<Read>)> {
        if let Some(id) = resolver.content_id(rel) {
            return Ok((id, None));
        }
        if let Some(path) = resolver.local_file(rel)
            && let Some(found) = self.local_content_key(path)
        {
            return Ok(found);
        }
        let (bytes, found) = resolver.read(rel)?;
        Ok((sha256(&bytes), Some((bytes, found))))
    }

    /// [`Self::content_key`] of the local file `path`; `None` when it cannot be read (the
    /// resolver's read then reports it as it would have).
    fn local_content_key(&self, path: PathBuf) -> Option<([u8; 32], Option<Read>)> {
        let stamp = FileStamp::of(&std::fs::metadata(&path).ok()?)?;
        let lock = || self.files.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(&(known, id)) = lock().get(&path)
            && known == stamp
        {
            return Some((id, None));
        }
        let started = std::time::SystemTime::now();
        let bytes = std::fs::read(&path).ok()?;
        let id = sha256(&bytes);
        // Remembered only if nothing changed while it was read, and it had settled before.
        let after = std::fs::metadata(&path).ok().and_then(|m| FileStamp::of(&m));
        if after == Some(stamp) && stamp.settled_before(started) {
            let mut files = lock();
            if files.len() >= REMEMBERED_FILES {
                files.clear();
            }
            files.insert(path.clone(), (stamp, id));
        }
        Some((id, Some((bytes, path))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn mesh(triangles: usize) -> CachedMesh {
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for i in 0..triangles {
            let x = i as f64;
            positions.extend([
                DVec3::new(x, 0.0, 0.0),
                DVec3::new(x + 1.0, 0.0, 0.0),
                DVec3::new(x, 1.0, 0.0),
            ]);
            let k = 3 * i as u32;
            indices.push([k, k + 1, k + 2]);
        }
        CachedMesh { geom: Arc::new(MeshGeom::new(positions, indices, None)), dropped: 0 }
    }

    #[test]
    fn least_recently_used_entries_go_past_the_bound() {
        let one = mesh(100).geom.heap_bytes() as u64;
        // Room for two such meshes, not three.
        let cache = MeshCache::new(one * 2 + one / 2);
        let (a, b, c) = ([1u8; 32], [2u8; 32], [3u8; 32]);
        cache.put_mesh(&a, false, mesh(100));
        cache.put_mesh(&b, false, mesh(100));
        // a used last: b is the one to go.
        assert!(cache.mesh(&a, false).is_some());
        cache.put_mesh(&c, false, mesh(100));
        assert!(cache.mesh(&b, false).is_none());
        assert!(cache.mesh(&a, false).is_some() && cache.mesh(&c, false).is_some());
        // The smooth build of a is another entry.
        assert!(cache.mesh(&a, true).is_none());
        let s = cache.stats();
        assert_eq!((s.entries, s.evictions, s.mesh_misses, s.mesh_hits), (2, 1, 3, 3));
        assert!(s.bytes <= cache.limit_bytes(), "{s:?}");
        // An entry over the whole bound is used but not kept, and evicts nothing.
        let big = cache.put_mesh(&[4; 32], false, mesh(1000));
        assert_eq!(big.geom.triangle_count(), 1000);
        assert!(cache.mesh(&[4; 32], false).is_none());
        assert_eq!(cache.stats().entries, 2);
    }

    /// A bumpy 12x12 grid with texture coordinates, one degenerate triangle (two vertices at the
    /// same place) among its faces.
    fn grid_ply() -> Vec<u8> {
        grid_ply_at(-3.0)
    }

    fn grid_ply_at(z: f32) -> Vec<u8> {
        let n = 12;
        let mut mesh = crate::ply::PlyMesh::default();
        let mut uvs = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32 * 2.0 - 1.0, j as f32 / n as f32 * 2.0 - 1.0);
                mesh.positions.push([x, y, z + 0.3 * (3.0 * x).sin() * (2.0 * y).cos()]);
                uvs.push([i as f32 / n as f32, j as f32 / n as f32]);
            }
        }
        let at = |i: u32, j: u32| j * (n + 1) + i;
        for j in 0..n {
            for i in 0..n {
                mesh.triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                mesh.triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        // A vertex where vertex 0 is: its triangle has no area.
        mesh.positions.push(mesh.positions[0]);
        uvs.push([0.0, 0.0]);
        let last = mesh.positions.len() as u32 - 1;
        mesh.triangles.push([0, last, 5]);
        mesh.uvs = Some(uvs);
        crate::ply::write_ply_binary_le(&mesh)
    }

    /// A scene of the grid flat with an image texture, the grid again smooth and moved, and an
    /// instance of the first, moved too.
    const SCENE: &str = r#"<Scene>
<MaxRecursionDepth>2</MaxRecursionDepth>
<Cameras><Camera id="1"><Position>0 0 2</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
  <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>24 24</ImageResolution>
  <NumSamples>1</NumSamples><ImageName>c.png</ImageName></Camera></Cameras>
<Lights><AmbientLight>10 10 10</AmbientLight><PointLight id="1"><Position>0 2 2</Position><Intensity>900 900 900</Intensity></PointLight></Lights>
<Materials><Material id="1"><AmbientReflectance>0.1 0.1 0.1</AmbientReflectance><DiffuseReflectance>0.8 0.6 0.4</DiffuseReflectance>
  <SpecularReflectance>0.3 0.3 0.3</SpecularReflectance><PhongExponent>20</PhongExponent></Material></Materials>
<Transformations><Translation id="1">0.8 0.4 -0.5</Translation><Rotation id="1">20 0 1 0</Rotation></Transformations>
<Textures><Images><Image id="1">tex.png</Image></Images>
  <TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>blend_kd</DecalMode></TextureMap></Textures>
<Objects>
  <Mesh id="1"><Material>1</Material><Textures>1</Textures><Faces plyFile="grid.ply"/></Mesh>
  <Mesh id="2" shadingMode="smooth"><Material>1</Material><Transformations>r1 t1</Transformations><Faces plyFile="./grid.ply"/></Mesh>
  <MeshInstance id="3" baseMeshId="1"><Transformations>t1</Transformations></MeshInstance>
</Objects></Scene>"#;

    /// Counts the reads of a resolver and, when `ids`, knows every file's SHA-256 without
    /// reading it (as a farm worker's resolver does).
    struct Counting {
        fs: crate::assets::FsResolver,
        ids: bool,
        reads: std::sync::atomic::AtomicUsize,
    }

    impl AssetResolver for Counting {
        fn read(&self, rel: &str) -> std::io::Result<(Vec<u8>, std::path::PathBuf)> {
            self.reads.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            self.fs.read(rel)
        }
        fn display_path(&self, rel: &str) -> std::path::PathBuf {
            self.fs.display_path(rel)
        }
        fn content_id(&self, rel: &str) -> Option<[u8; 32]> {
            self.ids.then(|| sha256(&self.fs.read(rel).expect("test file").0))
        }
    }

    fn render_bits(scene: &crate::scene::Scene) -> Vec<u32> {
        let settings = crate::render::RenderSettings::default();
        let (img, _) = crate::render::render_camera(scene, 0, 8, &settings, &|_, _| {});
        img.pixels.iter().flat_map(|p| p.iter().map(|c| c.to_bits())).collect()
    }

    #[test]
    fn a_cached_build_renders_the_same_bits_without_parsing_again() {
        use crate::scene::build::{build_scene, build_scene_cached};
        let dir = tessera_testkit::TempDir::new("mesh-cache");
        std::fs::write(dir.join("grid.ply"), grid_ply()).unwrap();
        let texels: Vec<u8> = (0..4 * 4 * 3).map(|k| (k * 37 % 256) as u8).collect();
        image::save_buffer(dir.join("tex.png"), &texels, 4, 4, image::ExtendedColorType::Rgb8).unwrap();
        let rec = crate::scene::xml::parse_xml(SCENE, &dir.join("s.xml")).unwrap();
        let fs = crate::assets::FsResolver { base_dir: dir.to_path_buf() };
        let plain = build_scene(&rec, &fs).unwrap();
        let want = render_bits(&plain);
        assert!(want.iter().any(|&b| b != 0), "the scene renders something");
        assert!(plain.warnings.iter().any(|w| w.message.contains("degenerate")), "{:?}", plain.warnings);

        for ids in [false, true] {
            let cache = MeshCache::default();
            let counting = Counting { fs: fs.clone(), ids, reads: Default::default() };
            let first = build_scene_cached(&rec, &counting, &cache).unwrap();
            let after_first = cache.stats();
            // The PLY parsed once for each way the scene writes its path; a flat and a smooth
            // mesh built; the image decoded.
            assert_eq!((after_first.ply_parses, after_first.mesh_misses, after_first.mesh_hits), (2, 2, 0));
            assert_eq!((after_first.image_misses, after_first.image_hits), (1, 0));
            assert_eq!(first.stats.meshes_cached, 0);
            counting.reads.store(0, std::sync::atomic::Ordering::SeqCst);
            let second = build_scene_cached(&rec, &counting, &cache).unwrap();
            let s = cache.stats();
            assert_eq!(s.ply_parses, 2, "the second build parses nothing: {s:?}");
            assert_eq!((s.mesh_misses, s.mesh_hits, s.image_hits), (2, 2, 1), "{s:?}");
            assert_eq!((s.world_misses, s.world_hits), (1, 1), "{s:?}");
            assert_eq!(second.stats.meshes_cached, 2);
            assert!(!first.stats.world_tree_cached && second.stats.world_tree_cached);
            // Knowing the content ids, a hit reads nothing; else each file is read to hash it.
            let reads = counting.reads.load(std::sync::atomic::Ordering::SeqCst);
            assert_eq!(reads, if ids { 0 } else { 3 }, "ids known: {ids}");
            for scene in [&first, &second] {
                assert_eq!(render_bits(scene), want, "ids known: {ids}");
                assert_eq!(scene.warnings, plain.warnings);
                assert_eq!(scene.stats.triangles, plain.stats.triangles);
            }
        }

        // The objects moved (a windmill's blades): the meshes come from the cache, the world
        // tree is built anew, and the picture is the uncached build's.
        let cache = MeshCache::default();
        build_scene_cached(&rec, &fs, &cache).unwrap();
        let moved_text = SCENE.replace("0.8 0.4 -0.5", "0.6 0.2 -0.4");
        let moved = crate::scene::xml::parse_xml(&moved_text, &dir.join("s.xml")).unwrap();
        let cached = build_scene_cached(&moved, &fs, &cache).unwrap();
        let s = cache.stats();
        assert_eq!((s.mesh_hits, s.world_hits, s.world_misses), (2, 0, 2), "{s:?}");
        let plain_moved = render_bits(&build_scene(&moved, &fs).unwrap());
        assert_ne!(plain_moved, want, "the move shows");
        assert_eq!(render_bits(&cached), plain_moved);
        // Back where it was: that tree again.
        let back = build_scene_cached(&rec, &fs, &cache).unwrap();
        assert!(back.stats.world_tree_cached);
        assert_eq!(render_bits(&back), want);
    }

    /// A local file that had settled is hashed from its bytes once, then found by its `stat`
    /// identity without reading, until a write changes it; one written just now is read every
    /// time. A build whose cache lost the mesh reads the file again and keys it by its bytes.
    #[test]
    fn a_settled_local_file_is_hashed_once_until_it_changes() {
        use crate::assets::FsResolver;
        let dir = tessera_testkit::TempDir::new("mesh-cache-files");
        std::fs::write(dir.join("settled.ply"), b"first content").unwrap();
        std::fs::write(dir.join("grid.ply"), grid_ply()).unwrap();
        std::thread::sleep(SETTLED + std::time::Duration::from_millis(200));
        std::fs::write(dir.join("fresh.ply"), b"fresh").unwrap();
        let fs = FsResolver { base_dir: dir.to_path_buf() };
        let cache = MeshCache::default();
        let key = |rel: &str| cache.content_key(&fs, rel).unwrap();

        let (id, read) = key("settled.ply");
        assert_eq!(id, sha256(b"first content"));
        assert!(read.is_some_and(|(bytes, at)| bytes == b"first content" && at == dir.join("settled.ply")));
        let (again, read) = key("settled.ply");
        assert_eq!(again, id);
        assert!(read.is_none(), "an unchanged settled file is not read again");
        for _ in 0..2 {
            let (id, read) = key("fresh.ply");
            assert_eq!(id, sha256(b"fresh"));
            assert!(read.is_some(), "a file written just now is read every time");
        }
        // Other bytes of the same length: its change time moved, so it is read and hashed.
        std::fs::write(dir.join("settled.ply"), b"other content").unwrap();
        let (changed, read) = key("settled.ply");
        assert_eq!(changed, sha256(b"other content"));
        assert!(read.is_some());
        // Another file renamed over it: another inode.
        std::fs::write(dir.join("new.ply"), b"third content").unwrap();
        std::fs::rename(dir.join("new.ply"), dir.join("settled.ply")).unwrap();
        assert_eq!(key("settled.ply").0, sha256(b"third content"));

        // A cache that keeps nothing: the second build's key comes without reading, the mesh
        // is not there, and the file is read, keyed by its bytes and parsed again.
        let text = r#"<Scene><Materials><Material id="1"/></Materials><Objects>
            <Mesh id="1"><Material>1</Material><Faces plyFile="grid.ply"/></Mesh></Objects></Scene>"#;
        let rec = crate::scene::xml::parse_xml(text, &dir.join("s.xml")).unwrap();
        let keeps_nothing = MeshCache::new(0);
        let first = crate::scene::build::build_scene_cached(&rec, &fs, &keeps_nothing).unwrap();
        assert!(keeps_nothing.content_key(&fs, "grid.ply").unwrap().1.is_none(), "remembered");
        let second = crate::scene::build::build_scene_cached(&rec, &fs, &keeps_nothing).unwrap();
        assert_eq!(keeps_nothing.stats().ply_parses, 2);
        assert_eq!(second.stats.triangles, first.stats.triangles);
    }

    #[test]
    fn other_content_or_shading_is_another_entry_and_errors_are_not_kept() {
        use crate::scene::build::build_scene_cached;
        let dir = tessera_testkit::TempDir::new("mesh-cache-keys");
        std::fs::write(dir.join("grid.ply"), grid_ply()).unwrap();
        let fs = crate::assets::FsResolver { base_dir: dir.to_path_buf() };
        let scene = |shading: &str| {
            format!(
                r#"<Scene><Materials><Material id="1"/></Materials><Objects>
                <Mesh id="1" shadingMode="{shading}"><Material>1</Material><Faces plyFile="grid.ply"/></Mesh></Objects></Scene>"#
            )
        };
        let build = |text: &str, cache: &MeshCache| {
            let rec = crate::scene::xml::parse_xml(text, &dir.join("s.xml")).unwrap();
            build_scene_cached(&rec, &fs, cache)
        };
        let cache = MeshCache::default();
        let flat = build(&scene("flat"), &cache).unwrap();
        let smooth = build(&scene("smooth"), &cache).unwrap();
        assert_eq!((cache.stats().mesh_misses, cache.stats().mesh_hits), (2, 0));
        assert!(flat.accel.meshes[0].vertex_normals.is_none());
        assert!(smooth.accel.meshes[0].vertex_normals.is_some());
        // The same path with other bytes: another entry.
        std::fs::write(dir.join("grid.ply"), grid_ply_at(-3.5)).unwrap();
        build(&scene("flat"), &cache).unwrap();
        assert_eq!((cache.stats().mesh_misses, cache.stats().ply_parses), (3, 3));
        // A file that does not parse is an error each time, naming the file.
        std::fs::write(dir.join("grid.ply"), b"ply\nformat nonsense\n").unwrap();
        for _ in 0..2 {
            let e = build(&scene("flat"), &cache).err().expect("a broken PLY").to_string();
            assert!(e.contains("grid.ply"), "{e}");
        }
        // Three meshes and the three scenes' world trees; nothing of the failures.
        let s = cache.stats();
        assert_eq!((s.entries, s.mesh_misses, s.world_misses), (6, 3, 3), "{s:?}");
    }

    #[test]
    fn a_key_put_twice_keeps_the_first_copy() {
        let cache = MeshCache::default();
        let first = cache.put_mesh(&[9; 32], true, mesh(3));
        let second = cache.put_mesh(&[9; 32], true, mesh(3));
        assert!(Arc::ptr_eq(&first.geom, &second.geom));
        let img = Arc::new(TextureImage { width: 1, height: 1, texels: vec![[0.5; 3]] });
        let kept = cache.put_image(&[9; 32], img.clone());
        assert!(Arc::ptr_eq(&kept, &img));
        assert!(Arc::ptr_eq(&cache.image(&[9; 32]).expect("kept"), &img));
        assert_eq!(cache.stats().entries, 2);
    }
}
