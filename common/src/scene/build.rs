//! Records -> render scene: resolve ids, load PLY files, compose transformations, build BVHs.
//!
//! Every failure here is a [`SceneError`] that points at the element whose reference or data is
//! wrong (the records carry their source line), so the user can fix the scene file.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use glam::{DAffine3, DMat3, DMat4, DVec2, DVec3};
use rayon::prelude::*;

use super::cache::{CachedMesh, MeshCache, content_key};
use super::records::*;
use super::tree::json_words;
use super::{Scene, SceneStats};
use crate::assets::AssetResolver;
use crate::camera::Camera;
use crate::error::{Loc, SceneError, Warning};
use crate::geometry::mesh::{MeshGeom, area_weighted_normals, drop_degenerate, grouped_normals};
use crate::geometry::{Accel, Instance, ObjectTextures, Shape};
use crate::lights::{AreaLight, DirectionalLight, EnvLight, ObjectLight, PointLight, SpotLight};
use crate::material::{Brdf, Material};
use crate::math::{Transform, v3};
use crate::texture::image::TextureImage;
use crate::texture::maps::{Source, TextureMap};
use crate::texture::mip::MipChain;
use sha2::{Digest, Sha256};

/// Largest image we agree to render (a float frame of this size is 3 GiB).
const MAX_IMAGE_SIDE: u32 = 65_536;
const MAX_IMAGE_PIXELS: u64 = 1 << 28;

/// The exponent that linearises `degamma="true"` materials and texture maps (§6.6): the `Gamma`
/// of the first camera's first `<Tonemap>` when it is a number, else 2.2 (also for `sRGB`, whose
/// curve 2.2 approximates).
fn degamma_exponent(rec: &SceneRecords) -> f64 {
    rec.cameras
        .iter()
        .find_map(|c| c.tonemaps.first())
        .and_then(|t| match t.params.gamma {
            crate::tonemap::params::Gamma::Power(g) => Some(g),
            crate::tonemap::params::Gamma::Srgb => None,
        })
        .unwrap_or(2.2)
}

struct Ctx<'a> {
    rec: &'a SceneRecords,
    resolver: &'a dyn AssetResolver,
    /// Meshes and images kept across builds ([`build_scene_cached`]).
    cache: Option<&'a MeshCache>,
}

impl Ctx<'_> {
    /// An error about the scene, in the words of its dialect.
    fn err(&self, loc: &Loc, msg: impl Into<String>) -> SceneError {
        let msg = msg.into();
        let msg = if self.rec.json { json_words(&msg) } else { msg };
        SceneError::new(&self.rec.source, loc.clone(), msg)
    }

    /// The one way every step reports a warning about the scene: at `loc` of the scene file.
    /// ([`build_scene`] puts them all in the words of the scene's dialect at the end.)
    fn warn(&self, warnings: &mut Vec<Warning>, loc: &Loc, message: impl Into<String>) {
        warnings.push(Warning::new(&self.rec.source, loc.clone(), message));
    }

    fn material(&self, ids: &HashMap<&str, u32>, id: &str, loc: &Loc) -> Result<u32, SceneError> {
        ids.get(id).copied().ok_or_else(|| {
            self.err(loc, format!("material \"{id}\" is not defined; add <Material id=\"{id}\"> under <Materials> or use an existing id"))
        })
    }

    fn vertex(&self, id: i64, loc: &Loc, what: &str) -> Result<u32, SceneError> {
        let n = self.rec.vertices.len();
        if id >= 1 && (id as u64) <= n as u64 {
            Ok((id - 1) as u32)
        } else {
            Err(self.err(
                loc,
                format!("{what} refers to vertex {id}, but <VertexData> has {n} vertices (ids start at 1)"),
            ))
        }
    }

    fn transform(
        &self,
        table: &HashMap<(char, &str), TransformOp>,
        refs: &[TransformRef],
        loc: &Loc,
    ) -> Result<DAffine3, SceneError> {
        let mut m = DAffine3::IDENTITY;
        for r in refs {
            let op = table.get(&(r.letter, r.id.as_str())).ok_or_else(|| {
                let kind = match r.letter {
                    't' => "Translation",
                    's' => "Scaling",
                    'r' => "Rotation",
                    _ => "Composite",
                };
                self.err(loc, format!("transformation \"{}{}\" is not defined; add <{kind} id=\"{}\"> under <Transformations>", r.letter, r.id, r.id))
            })?;
            // Tokens apply left to right: M = Xn ··· X2 · X1.
            m = op_matrix(op) * m;
        }
        Ok(m)
    }

    fn make_transform(&self, m: DAffine3, loc: &Loc) -> Result<Option<Transform>, SceneError> {
        if m == DAffine3::IDENTITY {
            return Ok(None);
        }
        Transform::new(m).map(Some).ok_or_else(|| {
            self.err(loc, "the transformation is singular (a zero scale?); the object would be flat: use non-zero Scaling factors")
        })
    }

    /// Where a camera's or light's `Transformations` put it (§10.4): the same composite matrix
    /// as an object's, `None` when there are none, so untransformed scenes keep their exact
    /// numbers. A singular matrix is refused: it would squash a viewing or lighting direction
    /// to nothing or, for an area light, leave its normal undefined.
    fn placement(
        &self,
        table: &HashMap<(char, &str), TransformOp>,
        refs: &[TransformRef],
        loc: &Loc,
    ) -> Result<Option<Transform>, SceneError> {
        if refs.is_empty() {
            return Ok(None);
        }
        let m = self.transform(table, refs, loc)?;
        Transform::new(m).map(Some).ok_or_else(|| {
            self.err(loc, "the transformation is singular (a zero scale?); it would flatten the directions of this camera or light: use non-zero Scaling factors")
        })
    }
}

/// A position (camera or light Position) under an optional placement: moved as a point (w = 1).
fn placed_point(placement: Option<&Transform>, p: Vec3) -> DVec3 {
    placement.map_or(v3(p), |t| t.to_world.transform_point3(v3(p)))
}

/// A direction (Gaze, Up, light Direction) under an optional placement: only the linear part
/// acts (w = 0). Its length is not kept; every user normalises it.
fn placed_vector(placement: Option<&Transform>, d: Vec3) -> DVec3 {
    placement.map_or(v3(d), |t| t.to_world.transform_vector3(v3(d)))
}

/// An area light's normal under an optional placement: by the inverse transpose, like a
/// surface normal (§10.3), so that it stays perpendicular to the square's plane under
/// non-uniform scaling.
fn placed_normal(placement: Option<&Transform>, n: Vec3) -> DVec3 {
    placement.map_or(v3(n), |t| t.normal_to_world(v3(n)))
}

/// A camera record with its `Transformations` applied. A GazePoint camera's record holds
/// `GazePoint − Position`, and moving both points by an affine M changes that difference by M's
/// linear part only, so treating it as a direction places the gaze point as a point. Distances
/// (NearDistance, NearPlane, FovY, FocusDistance) stay as written: scaling a camera changes
/// where it looks, not its image plane.
fn placed_camera(c: &CameraRec, placement: Option<&Transform>) -> CameraRec {
    let mut placed = c.clone();
    placed.position = placed_point(placement, c.position).to_array();
    placed.gaze = placed_vector(placement, c.gaze).to_array();
    placed.up = placed_vector(placement, c.up).to_array();
    // The course's renderer keeps the transformed gaze's length: a scaling along the view
    // moves a NearPlane camera's image plane (its extents as given) that many times further,
    // which zooms. Measured on the sequence camera_zoom_david (a scaling of 1 to 2 along the
    // gaze about the camera; its reference video zooms in by that factor).
    if let (Some(_), crate::scene::records::Projection::NearPlane { .. }) = (placement, &c.projection) {
        let unit = v3(c.gaze);
        if unit.length_squared() > 0.0 {
            let stretched = placed_vector(placement, unit.normalize().to_array()).length();
            if stretched.is_finite() && stretched > 0.0 {
                placed.near_distance = c.near_distance * stretched;
            }
        }
    }
    placed
}

/// The matrix of one transformation element (§10.1).
pub fn op_matrix(op: &TransformOp) -> DAffine3 {
    match *op {
        TransformOp::Translation(t) => DAffine3::from_translation(v3(t)),
        TransformOp::Scaling(s) => DAffine3::from_scale(v3(s)),
        TransformOp::Rotation { degrees, axis } => {
            let a = v3(axis);
            if a.length_squared() == 0.0 {
                DAffine3::IDENTITY
            } else {
                DAffine3::from_axis_angle(a.normalize(), degrees.to_radians())
            }
        }
        TransformOp::Composite(m) => {
            // Row-major in the file; glam reads column-major.
            let mat = DMat4::from_cols_array(&m).transpose();
            DAffine3 { matrix3: DMat3::from_mat4(mat), translation: mat.w_axis.truncate() }
        }
    }
}

/// A MeshInstance with its chain of bases followed down to a Mesh.
#[derive(Clone, Copy)]
struct ResolvedInstance {
    /// Index of the Mesh record whose geometry it shows.
    mesh: usize,
    world: DAffine3,
    material: u32,
    smooth: bool,
    /// The MeshInstance record whose `Textures` it shows (the nearest in its chain that has
    /// some); `None`: its Mesh's.
    textures_from: Option<usize>,
}

/// Resolves every MeshInstance: `baseMeshId` names a Mesh, or else another MeshInstance (the
/// course files use one id space for both). Without `resetTransform` the instance's own
/// transformations apply on top of its base's world transform; the material, the texture maps
/// and smooth shading are inherited unless the instance sets them. Cycles are errors.
fn resolve_instances(
    ctx: &Ctx,
    mat_ids: &HashMap<&str, u32>,
    transforms: &HashMap<(char, &str), TransformOp>,
    mesh_world: &[DAffine3],
) -> Result<Vec<ResolvedInstance>, SceneError> {
    let rec = ctx.rec;
    let mesh_index: HashMap<&str, usize> =
        rec.meshes.iter().enumerate().map(|(i, m)| (m.id.as_str(), i)).rev().collect();
    let inst_index: HashMap<&str, usize> =
        rec.instances.iter().enumerate().map(|(i, m)| (m.id.as_str(), i)).rev().collect();
    let mut done: Vec<Option<ResolvedInstance>> = vec![None; rec.instances.len()];
    for start in 0..rec.instances.len() {
        // Walk down the chain to something resolved (or a Mesh), then unwind.
        let mut chain: Vec<usize> = Vec::new();
        let mut cur = start;
        let mut base: ResolvedInstance = loop {
            if let Some(r) = done[cur] {
                break r;
            }
            if chain.contains(&cur) {
                let inst = &rec.instances[start];
                return Err(ctx.err(
                    &inst.loc,
                    format!(
                        "baseMeshId=\"{}\" leads back to this instance (a cycle of MeshInstances)",
                        inst.base_mesh
                    ),
                ));
            }
            chain.push(cur);
            let inst = &rec.instances[cur];
            if let Some(&m) = mesh_index.get(inst.base_mesh.as_str()) {
                let mesh = &rec.meshes[m];
                break ResolvedInstance {
                    mesh: m,
                    world: mesh_world[m],
                    material: ctx.material(mat_ids, &mesh.material, &mesh.loc)?,
                    smooth: mesh.shading == ShadingMode::Smooth,
                    textures_from: None,
                };
            }
            match inst_index.get(inst.base_mesh.as_str()) {
                Some(&i) if i != cur => cur = i,
                _ => {
                    return Err(ctx.err(
                        &inst.loc,
                        format!("baseMeshId=\"{}\" names no <Mesh> or other <MeshInstance>; use the id of a Mesh under <Objects>", inst.base_mesh),
                    ));
                }
            }
        };
        for &i in chain.iter().rev() {
            if done[i].is_none() {
                let inst = &rec.instances[i];
                let own = ctx.transform(transforms, &inst.transforms, &inst.loc)?;
                let r = ResolvedInstance {
                    mesh: base.mesh,
                    world: if inst.reset_transform { own } else { own * base.world },
                    material: match &inst.material {
                        Some(id) => ctx.material(mat_ids, id, &inst.loc)?,
                        None => base.material,
                    },
                    smooth: base.smooth || inst.shading == Some(ShadingMode::Smooth),
                    textures_from: if inst.textures.is_empty() { base.textures_from } else { Some(i) },
                };
                done[i] = Some(r);
            }
            base = done[i].unwrap_or(base);
        }
    }
    Ok(done.into_iter().flatten().collect())
}

/// Raw triangle data of one Mesh record before the BVH is built.
struct MeshData {
    positions: Vec<DVec3>,
    indices: Vec<[u32; 3]>,
    file_normals: Option<Vec<DVec3>>,
    uvs: Option<Vec<DVec2>>,
    /// For inline meshes: the scene vertex each of our vertices came from (a vertex is split
    /// when its corners use different texture coordinates; smooth normals are shared by group).
    groups: Option<Vec<u32>>,
}

/// The triangle data of a Mesh record whose faces are in the scene (a PLY mesh's comes from
/// [`load_ply_cached`]).
fn load_mesh_data(ctx: &Ctx, mesh: &MeshRec) -> Result<Arc<MeshData>, SceneError> {
    match &mesh.faces {
        FacesRec::Ply { .. } => Err(ctx.err(&mesh.faces_loc, "internal: PLY not loaded")),
        FacesRec::Binary { .. } => Err(ctx.err(&mesh.faces_loc, "internal: binary faces not read")),
        FacesRec::Inline { indices, vertex_offset, .. } => {
            if indices.len() % 3 != 0 {
                return Err(ctx.err(
                    &mesh.faces_loc,
                    format!(
                        "has {} vertex ids, not a multiple of 3; give three vertex ids per triangle",
                        indices.len()
                    ),
                ));
            }
            // Keep only the vertices this mesh uses, so a BVH never carries the whole scene's list.
            // With texture coordinates a vertex is keyed by (vertex id, uv id): the uv id is
            // index + textureOffset, or the vertex id itself (§8.4).
            let texture_offset = match &mesh.faces {
                FacesRec::Inline { texture_offset, .. } => *texture_offset,
                FacesRec::Ply { .. } | FacesRec::Binary { .. } => None,
            };
            let tex = &ctx.rec.tex_coords;
            let mut with_uvs = !tex.is_empty();
            let mut remap: HashMap<(u32, i64), u32> = HashMap::new();
            let mut positions = Vec::new();
            let mut groups = Vec::new();
            let mut uv_ids: Vec<i64> = Vec::new();
            let mut tris = Vec::with_capacity(indices.len() / 3);
            for tri in indices.chunks_exact(3) {
                let mut out = [0u32; 3];
                for (k, &i) in tri.iter().enumerate() {
                    let g =
                        ctx.vertex(i + vertex_offset, &mesh.faces_loc, &format!("face {}", tris.len() + 1))?;
                    let uv_id = if with_uvs { texture_offset.map_or(g as i64 + 1, |o| i + o) } else { 0 };
                    out[k] = *remap.entry((g, uv_id)).or_insert_with(|| {
                        positions.push(v3(ctx.rec.vertices[g as usize]));
                        groups.push(g);
                        uv_ids.push(uv_id);
                        (positions.len() - 1) as u32
                    });
                }
                tris.push(out);
            }
            // Texture coordinates only when every id is in range; a mesh that then carries an
            // image texture is reported by the texture step.
            with_uvs &= uv_ids.iter().all(|&k| k >= 1 && (k as usize) <= tex.len());
            let uvs = with_uvs
                .then(|| uv_ids.iter().map(|&k| DVec2::from_array(tex[k as usize - 1])).collect::<Vec<_>>());
            Ok(Arc::new(MeshData { positions, indices: tris, file_normals: None, uvs, groups: Some(groups) }))
        }
    }
}

/// Why the PLY file `path` named at `loc` cannot be read.
fn ply_read_error(ctx: &Ctx, path: &str, loc: &Loc, e: std::io::Error) -> SceneError {
    SceneError::new(
        &ctx.rec.source,
        loc.clone(),
        format!(
            "cannot read PLY file {}: {e}; check the plyFile path (it is relative to the scene file)",
            ctx.resolver.display_path(path).display()
        ),
    )
}

/// Parses the PLY file `path` named at `loc`: the bytes `read` when the caller has them, else
/// read through the resolver.
fn load_ply(
    ctx: &Ctx,
    path: &str,
    loc: &Loc,
    read: Option<(Vec<u8>, std::path::PathBuf)>,
) -> Result<Arc<MeshData>, SceneError> {
    let (bytes, found) = match read {
        Some(r) => r,
        None => ctx.resolver.read(path).map_err(|e| ply_read_error(ctx, path, loc, e))?,
    };
    if let Some(cache) = ctx.cache {
        cache.count_parse();
    }
    let ply = crate::ply::parse_ply(&bytes).map_err(|e| {
        let mut err = SceneError::file(&found, format!("{e} (referenced from {}", ctx.rec.source.display()));
        if let Some(l) = loc.line {
            err.message.push_str(&format!(" line {l}"));
        }
        err.message.push(')');
        if let Some(l) = e.line {
            err.loc.line = Some(l);
        }
        err
    })?;
    let positions: Vec<DVec3> =
        ply.positions.iter().map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)).collect();
    let file_normals = ply.normals.map(|ns| {
        ns.iter().map(|n| DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64).normalize_or_zero()).collect()
    });
    let uvs = ply.uvs.map(|t| t.iter().map(|uv| DVec2::new(uv[0] as f64, uv[1] as f64)).collect());
    Ok(Arc::new(MeshData { positions, indices: ply.triangles, file_normals, uvs, groups: None }))
}

/// One PLY file as step 5 has it: its content key (with a cache), the meshes the cache had
/// for it (by shading: flat, smooth), and its parsed data when some mesh of it is still to be
/// built.
struct PlyLoaded {
    content: Option<[u8; 32]>,
    cached: [Option<CachedMesh>; 2],
    data: Option<Arc<MeshData>>,
}

/// Loads the PLY file `path` named at `loc`, whose meshes are wanted flat (`wanted[0]`) and/or
/// smooth (`wanted[1]`). With a cache, the file is neither parsed nor (when the resolver knows
/// its content id) read if every wanted mesh is cached.
fn load_ply_cached(ctx: &Ctx, path: &str, loc: &Loc, wanted: [bool; 2]) -> Result<PlyLoaded, SceneError> {
    let Some(cache) = ctx.cache else {
        let data = load_ply(ctx, path, loc, None)?;
        return Ok(PlyLoaded { content: None, cached: [None, None], data: Some(data) });
    };
    let (content, read) = content_key(ctx.resolver, path).map_err(|e| ply_read_error(ctx, path, loc, e))?;
    let mut cached = [None, None];
    for (k, slot) in cached.iter_mut().enumerate() {
        if wanted[k] {
            *slot = cache.mesh(&content, k == 1);
        }
    }
    let missing = (0..2).any(|k| wanted[k] && cached[k].is_none());
    let data = if missing { Some(load_ply(ctx, path, loc, read)?) } else { None };
    Ok(PlyLoaded { content: Some(content), cached, data })
}

/// Whether an object's maps include an image (which needs texture coordinates).
fn uses_image(textures: &BuiltTextures, t: &ObjectTextures) -> bool {
    let more = t.more_colour.map_or(Vec::new(), |i| {
        textures.more_colour.lock().map(|m| m[i as usize].clone()).unwrap_or_default()
    });
    [t.colour[0], t.colour[1], t.normal]
        .into_iter()
        .flatten()
        .chain(more)
        .any(|k| matches!(textures.maps[k as usize].source, Source::Image { .. }))
}

/// Texture maps ready for shading, by position, and how the scene's ids find them.
struct BuiltTextures<'a> {
    maps: Vec<TextureMap>,
    ids: HashMap<&'a str, u32>,
    background: Option<u32>,
    env_light: Option<EnvLight>,
    extra_env_lights: Vec<EnvLight>,
    /// Objects' colour maps after their first two (`ObjectTextures::more_colour`), filled as
    /// objects are placed.
    more_colour: std::sync::Mutex<Vec<Vec<u32>>>,
}

/// Step 4: decodes every image a texture map or the environment light uses (each file once, in
/// parallel), builds the maps and the environment light.
fn build_textures<'a>(ctx: &Ctx<'a>, warnings: &mut Vec<Warning>) -> Result<BuiltTextures<'a>, SceneError> {
    let rec = ctx.rec;
    let image_recs: HashMap<&str, &ImageRec> = rec.images.iter().rev().map(|i| (i.id.as_str(), i)).collect();
    // The images the maps and the environment light need, each file once, with the first user
    // of each (for messages).
    let mut wanted: Vec<(&ImageRec, String)> = Vec::new();
    let mut want = |img: &'a ImageRec, user: String| {
        if !wanted.iter().any(|(w, _)| w.path == img.path) {
            wanted.push((img, user));
        }
    };
    for m in &rec.texture_maps {
        if let TextureSource::Image { image, .. } = &m.source {
            let img = image_recs.get(image.as_str()).ok_or_else(|| {
                ctx.err(&m.loc, format!("ImageId {image} names no <Image>; add <Image id=\"{image}\"> under <Textures><Images>"))
            })?;
            want(img, format!("texture map {}", m.id));
        }
    }
    for l in &rec.env_lights {
        let img = image_recs.get(l.image.as_str()).ok_or_else(|| {
            ctx.err(
                &l.loc,
                format!("ImageId {} names no <Image>; add <Image id=\"{}\"> with the environment map's path under <Textures><Images>", l.image, l.image),
            )
        })?;
        want(img, format!("environment light {}", l.id).trim_end().to_string());
    }
    // Every environment light's map is decoded once, like the texture maps' images.
    let decoded: Vec<Result<(String, Arc<TextureImage>), SceneError>> = wanted
        .par_iter()
        .map(|(img, user)| {
            let unreadable = |e: std::io::Error| {
                ctx.err(
                    &img.loc,
                    format!(
                        "cannot read image {} (image id {}, used by {user}): {e}; check the path (it is relative to the scene file)",
                        ctx.resolver.display_path(&img.path).display(),
                        img.id
                    ),
                )
            };
            // With a cache: the decoded image of the same content, if it has it.
            let (content, read) = match ctx.cache {
                Some(cache) => {
                    let (content, read) = content_key(ctx.resolver, &img.path).map_err(unreadable)?;
                    if let Some(image) = cache.image(&content) {
                        return Ok((img.path.clone(), image));
                    }
                    (Some(content), read)
                }
                None => (None, None),
            };
            let (bytes, found) = match read {
                Some(r) => r,
                None => ctx.resolver.read(&img.path).map_err(unreadable)?,
            };
            let decoded = TextureImage::decode(&bytes).map_err(|e| {
                ctx.err(
                    &img.loc,
                    format!("cannot decode image {} (image id {}, used by {user}): {e}", found.display(), img.id),
                )
            })?;
            let decoded = Arc::new(decoded);
            let decoded = match (ctx.cache, content) {
                (Some(cache), Some(content)) => cache.put_image(&content, decoded),
                _ => decoded,
            };
            Ok((img.path.clone(), decoded))
        })
        .collect();
    let mut by_path: HashMap<String, Arc<TextureImage>> = HashMap::new();
    for d in decoded {
        let (path, img) = d?;
        by_path.insert(path, img);
    }
    // Mip pyramids (§11.5) for the images that trilinear maps read, each built once.
    let mut trilinear_paths: Vec<&str> = Vec::new();
    for m in &rec.texture_maps {
        if let TextureSource::Image { image, interpolation: Interpolation::Trilinear, .. } = &m.source {
            let path = image_recs[image.as_str()].path.as_str();
            if !trilinear_paths.contains(&path) {
                trilinear_paths.push(path);
            }
        }
    }
    let mips: HashMap<&str, Arc<MipChain>> = trilinear_paths
        .par_iter()
        .map(|&path| (path, Arc::new(MipChain::new(by_path[path].clone()))))
        .collect();
    let mut env_lights = rec
        .env_lights
        .iter()
        .map(|l| EnvLight::new(by_path[&image_recs[l.image.as_str()].path].clone(), l.mapping, l.sampler));
    let env_light = env_lights.next();
    let extra_env_lights = env_lights.collect();
    let mut out = BuiltTextures {
        maps: Vec::new(),
        ids: HashMap::new(),
        background: None,
        env_light,
        extra_env_lights,
        more_colour: Default::default(),
    };
    for m in &rec.texture_maps {
        let source = match &m.source {
            TextureSource::Image { image, interpolation, normalizer, clamp } => {
                let path = &image_recs[image.as_str()].path;
                if *normalizer == 0.0 {
                    return Err(ctx.err(&m.loc, "Normalizer must not be 0"));
                }
                Source::Image {
                    image: by_path[path].clone(),
                    mips: match interpolation {
                        Interpolation::Trilinear => mips.get(path.as_str()).cloned(),
                        _ => None,
                    },
                    interpolation: *interpolation,
                    normalizer: *normalizer,
                    clamp: *clamp,
                }
            }
            TextureSource::Perlin { conversion, scale, octaves } => {
                Source::Perlin { conversion: *conversion, scale: *scale, octaves: *octaves }
            }
            TextureSource::Checkerboard { black, white, scale, offset, dimension3 } => Source::Checkerboard {
                black: v3(*black),
                white: v3(*white),
                scale: *scale,
                offset: *offset,
                dimension3: *dimension3,
            },
        };
        if out.ids.contains_key(m.id.as_str()) {
            ctx.warn(
                warnings,
                &m.loc,
                format!("texture map id \"{}\" is defined again; references use the first definition", m.id),
            );
        } else {
            out.ids.insert(m.id.as_str(), out.maps.len() as u32);
        }
        if m.decal == DecalMode::ReplaceBackground && out.background.is_none() {
            out.background = Some(out.maps.len() as u32);
        }
        out.maps.push(TextureMap {
            source,
            decal: m.decal,
            bump_factor: m.bump_factor,
            degamma: m.degamma.then_some(degamma_exponent(rec)),
        });
    }
    Ok(out)
}

impl BuiltTextures<'_> {
    /// Sorts an object's `<Textures>` ids into its colour maps, applied in the order given, and
    /// its normal map, the last one given (§11.1).
    fn for_object(
        &self,
        ctx: &Ctx,
        ids: &[String],
        loc: &Loc,
        warnings: &mut Vec<Warning>,
    ) -> Result<ObjectTextures, SceneError> {
        let mut t = ObjectTextures::default();
        let mut colour = Vec::new();
        for id in ids {
            let k = *self.ids.get(id.as_str()).ok_or_else(|| {
                ctx.err(
                    loc,
                    format!("texture \"{id}\" is not defined; add <TextureMap id=\"{id}\"> under <Textures>"),
                )
            })?;
            match self.maps[k as usize].decal {
                // The last normal or bump map wins (the course material has no object with two).
                DecalMode::ReplaceNormal | DecalMode::BumpNormal => t.normal = Some(k),
                DecalMode::ReplaceBackground => {
                    ctx.warn(warnings, loc, format!("texture {id} is a replace_background map; it applies to the background, not to this object"));
                }
                _ => colour.push(k),
            }
        }
        for (slot, &k) in t.colour.iter_mut().zip(&colour) {
            *slot = Some(k);
        }
        if colour.len() > 2 {
            let mut more =
                self.more_colour.lock().map_err(|_| ctx.err(loc, "internal: texture lists poisoned"))?;
            t.more_colour = Some(more.len() as u32);
            more.push(colour[2..].to_vec());
        }
        Ok(t)
    }
}

/// The scene's cameras, placed by their `Transformations` (§10.4) and checked (size limits, a
/// valid frame), without loading any asset: what the farm server needs to name and size frames.
pub fn build_cameras(rec: &SceneRecords) -> Result<Vec<Camera>, SceneError> {
    let no_assets = crate::assets::MemResolver { files: HashMap::new(), base: String::new() };
    let ctx = Ctx { rec, resolver: &no_assets, cache: None };
    let transforms = transform_table(rec);
    placed_cameras(&ctx, &transforms)
}

/// The `<Transformations>` block by (letter, id).
fn transform_table(rec: &SceneRecords) -> HashMap<(char, &str), TransformOp> {
    rec.transformations.iter().map(|t| ((t.op.letter(), t.id.as_str()), t.op)).collect()
}

/// Step 2 (and all of [`build_cameras`]): the cameras, placed by their `Transformations`
/// (§10.4) and checked: an image size within the limits, a valid camera frame.
fn placed_cameras(
    ctx: &Ctx,
    transforms: &HashMap<(char, &str), TransformOp>,
) -> Result<Vec<Camera>, SceneError> {
    let rec = ctx.rec;
    let mut cameras = Vec::with_capacity(rec.cameras.len());
    for c in &rec.cameras {
        if c.width == 0 || c.height == 0 {
            return Err(
                ctx.err(&c.loc, format!("<ImageResolution> {} {} has a zero size", c.width, c.height))
            );
        }
        if c.width > MAX_IMAGE_SIDE
            || c.height > MAX_IMAGE_SIDE
            || c.width as u64 * c.height as u64 > MAX_IMAGE_PIXELS
        {
            return Err(ctx.err(
                &c.loc,
                format!(
                    "<ImageResolution> {} {} is too large: at most {MAX_IMAGE_SIDE} pixels a side and {MAX_IMAGE_PIXELS} in all",
                    c.width, c.height
                ),
            ));
        }
        let placement = ctx.placement(transforms, &c.transforms, &c.loc)?;
        let placed = placed_camera(c, placement.as_ref());
        let cam = Camera::from_record(&placed).ok_or_else(|| {
            ctx.err(&c.loc, "Gaze and Up are zero or parallel, so they do not define a camera frame; give an Up that is not parallel to the viewing direction")
        })?;
        cameras.push(cam);
    }
    Ok(cameras)
}

/// Builds the render scene. `resolver` supplies the PLY files and images named by the scene.
///
/// The steps run in this order (each one's errors before the next one's): materials, cameras,
/// lights, texture maps and their images, meshes (PLY files, mesh instances, normals, BVHs),
/// then every object placed as an [`Instance`]. Warnings come out in that order too, after the
/// parser's.
pub fn build_scene(rec: &SceneRecords, resolver: &dyn AssetResolver) -> Result<Scene, SceneError> {
    build_scene_with(rec, resolver, None)
}

/// [`build_scene`] with meshes and images kept in `cache` across builds: a PLY mesh or an image
/// whose content (and, for a mesh, shading) the cache has is neither parsed nor built again.
/// The scene is the same, bit for bit, as [`build_scene`]'s.
pub fn build_scene_cached(
    rec: &SceneRecords,
    resolver: &dyn AssetResolver,
    cache: &MeshCache,
) -> Result<Scene, SceneError> {
    build_scene_with(rec, resolver, Some(cache))
}

fn build_scene_with(
    rec: &SceneRecords,
    resolver: &dyn AssetResolver,
    cache: Option<&MeshCache>,
) -> Result<Scene, SceneError> {
    let started = Instant::now();
    let legacy = super::legacy_data::legacy_data(rec, resolver)?;
    let rec: &SceneRecords = &legacy;
    let ctx = Ctx { rec, resolver, cache };
    let mut warnings: Vec<Warning> = rec.warnings.clone();

    let (materials, mat_ids) = build_materials(&ctx, &mut warnings)?;
    let transforms = transform_table(rec);
    let cameras = placed_cameras(&ctx, &transforms)?;
    if cameras.is_empty() {
        ctx.warn(&mut warnings, &Loc::default(), "the scene has no <Camera>; nothing will be rendered");
    }
    let lights = placed_lights(&ctx, &transforms)?;
    let textures = build_textures(&ctx, &mut warnings)?;
    let meshes_started = Instant::now();
    let mut meshes = build_meshes(&ctx, &transforms, &mat_ids, &mut warnings)?;
    let mesh_seconds = meshes_started.elapsed().as_secs_f64();
    let meshes_cached = meshes.cached;
    let identity = std::mem::take(&mut meshes.identity);
    let objects = Objects { ctx: &ctx, transforms: &transforms, mat_ids: &mat_ids, textures: &textures };
    let (geoms, instances, emitters) = objects.place(meshes, &mut warnings)?;

    // The top level; with a cache, the world-space tree of the static mesh instances is
    // shared with an earlier scene that placed the same meshes the same way.
    let accel_started = Instant::now();
    let (accel, world_tree_cached) = match cache {
        Some(cache) => {
            let key = world_tree_key(&geoms, &identity, &instances);
            match cache.world_tree(&key) {
                Some(tree) => (Accel::with_world_tree(geoms, instances, Some(tree)), true),
                None => {
                    let accel = Accel::new(geoms, instances);
                    cache.put_world_tree(&key, accel.shared_world_tree());
                    (accel, false)
                }
            }
        }
        None => (Accel::new(geoms, instances), false),
    };
    let accel_seconds = accel_started.elapsed().as_secs_f64();
    epsilons(&ctx, accel.extent(), &mut warnings);
    let (object_lights, instance_emission, instance_light) =
        object_lights(&ctx, &accel, &emitters, &mut warnings);
    let stats = SceneStats {
        triangles: accel.instanced_triangle_count(),
        instances: accel.instances.len(),
        build_seconds: started.elapsed().as_secs_f64(),
        mesh_seconds,
        meshes_cached,
        accel_seconds,
        world_tree_cached,
    };
    if rec.json {
        // The parser's warnings are in JSON words already; this makes the build's match them.
        for w in &mut warnings {
            w.message = json_words(&w.message);
        }
    }
    let mut scene = Scene {
        source: rec.source.clone(),
        background: v3(rec.background_color),
        shadow_ray_epsilon: rec.shadow_ray_epsilon,
        intersection_test_epsilon: rec.intersection_test_epsilon,
        max_recursion_depth: rec.max_recursion_depth.min(MAX_RECURSION_DEPTH_LIMIT),
        cull_camera_back_faces: rec.json,
        rules: Default::default(),
        ambient_light: v3(rec.ambient_light),
        area_lights: lights.area,
        point_lights: lights.point,
        directional_lights: lights.directional,
        spot_lights: lights.spot,
        object_lights,
        instance_emission,
        instance_light,
        env_light: textures.env_light,
        extra_env_lights: textures.extra_env_lights,
        more_colour_maps: textures.more_colour.into_inner().unwrap_or_default(),
        materials,
        cameras,
        accel,
        textures: textures.maps,
        background_texture: textures.background,
        warnings,
        stats,
        light_choice: Default::default(),
        path_lanes: Default::default(),
    };
    scene.light_choice = crate::lights::choice::LightChoice::new(
        &scene.point_lights,
        &scene.area_lights,
        &scene.directional_lights,
        &scene.spot_lights,
        &scene.object_lights,
        scene.env_light.iter().chain(&scene.extra_env_lights),
        scene.accel.extent().unwrap_or(2.0) / 2.0,
    );
    Ok(scene)
}

/// Warnings about epsilons that no scene means: negative ones, and offsets beyond a tenth of
/// the objects' extent (`extent`, the diagonal of their box), which let rays pass through
/// whole objects near their start. Both still render as given.
fn epsilons(ctx: &Ctx, extent: Option<f64>, warnings: &mut Vec<Warning>) {
    let rec = ctx.rec;
    let given = [
        (
            rec.shadow_ray_epsilon,
            "ShadowRayEpsilon",
            "1e-3",
            "offset",
            "start below their surface, which then shadows itself (dark speckles)",
            "start that far from their surface and pass through whatever is nearer",
        ),
        (
            rec.intersection_test_epsilon,
            "IntersectionTestEpsilon",
            "1e-6",
            "tolerance",
            "accept hits behind their origin",
            "ignore every surface nearer than that",
        ),
    ];
    for ((e, name, default, what, negative, large), loc) in given.into_iter().zip(&rec.epsilon_locs) {
        let Some(loc) = loc else { continue };
        // Numbers as a person writes them: 2e54, not 54 zeros.
        let moderate = |x: f64| x == 0.0 || (1e-3..1e6).contains(&x.abs());
        let shown = if moderate(e) { format!("{e}") } else { format!("{e:e}") };
        let problem = if e < 0.0 {
            format!("{name} {shown} is negative: rays {negative}")
        } else if let Some(d) = extent.filter(|&d| d > 0.0 && e > 0.1 * d) {
            let span = if moderate(d) { format!("{d:.3}") } else { format!("{d:.3e}") };
            format!(
                "{name} {shown} is more than a tenth of the scene's size (its objects span {span}): rays {large}"
            )
        } else {
            continue;
        };
        ctx.warn(
            warnings,
            loc,
            format!("{problem}; give a small positive {what} such as {default} (the default)"),
        );
    }
}

/// Step 1: the materials, by position, and how the scene's ids find them (a repeated id keeps
/// its first definition, with a warning). `degamma` materials are linearised here (§6.6). A
/// material's `BRDF` attribute finds its `<BRDFs>` entry (§7), whose Exponent replaces the
/// material's PhongExponent.
fn build_materials<'a>(
    ctx: &Ctx<'a>,
    warnings: &mut Vec<Warning>,
) -> Result<(Vec<Material>, HashMap<&'a str, u32>), SceneError> {
    let rec = ctx.rec;
    let mut brdfs: HashMap<&str, &BrdfRec> = HashMap::new();
    for b in &rec.brdfs {
        if brdfs.contains_key(b.id.as_str()) {
            ctx.warn(
                warnings,
                &b.loc,
                format!("BRDF id \"{}\" is defined again; materials use the first definition", b.id),
            );
        }
        brdfs.entry(b.id.as_str()).or_insert(b);
    }
    let mut mat_ids: HashMap<&str, u32> = HashMap::new();
    let mut materials = Vec::with_capacity(rec.materials.len());
    let degamma = degamma_exponent(rec);
    for m in &rec.materials {
        if mat_ids.contains_key(m.id.as_str()) {
            ctx.warn(
                warnings,
                &m.loc,
                format!("material id \"{}\" is defined again; references use the first definition", m.id),
            );
        }
        mat_ids.entry(m.id.as_str()).or_insert(materials.len() as u32);
        let lin = |c: Vec3| -> DVec3 {
            let c = v3(c);
            if m.degamma { c.max(DVec3::ZERO).powf(degamma) } else { c }
        };
        let brdf = match &m.brdf {
            None => None,
            Some(id) => Some(*brdfs.get(id.as_str()).ok_or_else(|| {
                ctx.err(
                    &m.loc,
                    format!("BRDF \"{id}\" is not defined; add an entry with id=\"{id}\" under <BRDFs> or use an existing id"),
                )
            })?),
        };
        let exponent = brdf.map_or(m.phong_exponent, |b| b.exponent);
        materials.push(Material {
            kind: m.kind,
            ambient: lin(m.ambient),
            diffuse: lin(m.diffuse),
            specular: lin(m.specular),
            mirror: lin(m.mirror),
            phong_exponent: exponent,
            phong_exponent_int: (exponent.fract() == 0.0 && (0.0..=4096.0).contains(&exponent))
                .then_some(exponent as i32),
            refraction_index: m.refraction_index,
            absorption_index: m.absorption_index,
            absorption: v3(m.absorption_coefficient),
            roughness: m.roughness,
            brdf: brdf.map(|b| Brdf {
                kind: b.kind,
                normalized: b.normalized,
                kd_fresnel: b.kd_fresnel,
                refractive_index: b.refractive_index,
            }),
        });
    }
    Ok((materials, mat_ids))
}

/// The scene's point, area, directional and spot lights (the environment light is built with
/// the textures, whose image it shares).
struct Lights {
    point: Vec<PointLight>,
    area: Vec<AreaLight>,
    directional: Vec<DirectionalLight>,
    spot: Vec<SpotLight>,
}

/// Step 3: the lights, each placed by its own Transformations (§10.4). An area light keeps its
/// Size: the record is a square of side `size`, which a non-uniform scale could not keep square,
/// and the course gives no rule for scaling it.
fn placed_lights(ctx: &Ctx, transforms: &HashMap<(char, &str), TransformOp>) -> Result<Lights, SceneError> {
    let rec = ctx.rec;
    let mut point = Vec::with_capacity(rec.point_lights.len());
    for l in &rec.point_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        let position = placed_point(placement.as_ref(), l.position);
        point.push(PointLight { position, intensity: v3(l.intensity) });
    }
    let mut area = Vec::with_capacity(rec.area_lights.len());
    for l in &rec.area_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        let center = placed_point(placement.as_ref(), l.position);
        let normal = placed_normal(placement.as_ref(), l.normal);
        area.push(AreaLight::new(center, normal, l.size, v3(l.radiance)));
    }
    let mut directional = Vec::with_capacity(rec.directional_lights.len());
    for l in &rec.directional_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        let direction = placed_vector(placement.as_ref(), l.direction);
        directional.push(DirectionalLight::new(direction, v3(l.radiance)));
    }
    let mut spot = Vec::with_capacity(rec.spot_lights.len());
    for l in &rec.spot_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        spot.push(SpotLight::new(
            placed_point(placement.as_ref(), l.position),
            placed_vector(placement.as_ref(), l.direction),
            v3(l.intensity),
            l.coverage_angle,
            l.falloff_angle,
        ));
    }
    Ok(Lights { point, area, directional, spot })
}

/// The geometry of every Mesh record (by record position) and what instances them.
struct Meshes {
    geoms: Vec<Arc<MeshGeom>>,
    /// Each Mesh record's own world transform.
    world: Vec<DAffine3>,
    /// Every MeshInstance record, resolved down to its Mesh.
    instances: Vec<ResolvedInstance>,
    /// How many Mesh records the cache served (neither parsed nor built).
    cached: usize,
    /// Each Mesh record's geometry's identity when the build has one without hashing its
    /// vertices (a PLY mesh under a cache: its file's SHA-256 and shading), for the world
    /// tree's key.
    identity: Vec<Option<[u8; 32]>>,
}

/// Step 5: the meshes. Mesh instances are resolved through their chains (a MeshInstance may
/// name another MeshInstance as its base, as grass_desert and marching_dragons do) before any
/// geometry is built, because a flat mesh needs vertex normals when a smooth instance shows it;
/// PLY files are then read and parsed once each even when several meshes name them, in
/// parallel (with a [`MeshCache`], not at all when every mesh of the file is cached); then
/// degenerate triangles are dropped, normals computed and BVHs built, in parallel (and obvhs
/// parallelises each build), and offered to the cache.
fn build_meshes(
    ctx: &Ctx,
    transforms: &HashMap<(char, &str), TransformOp>,
    mat_ids: &HashMap<&str, u32>,
    warnings: &mut Vec<Warning>,
) -> Result<Meshes, SceneError> {
    let rec = ctx.rec;
    let world: Vec<DAffine3> = rec
        .meshes
        .iter()
        .map(|m| ctx.transform(transforms, &m.transforms, &m.loc))
        .collect::<Result<_, _>>()?;
    let instances = resolve_instances(ctx, mat_ids, transforms, &world)?;
    // Which meshes need vertex normals: smooth themselves or smooth through an instance.
    let mut needs_smooth: Vec<bool> = rec.meshes.iter().map(|m| m.shading == ShadingMode::Smooth).collect();
    for r in &instances {
        needs_smooth[r.mesh] |= r.smooth;
    }
    // Each PLY file once, with the shadings its meshes want (flat, smooth).
    let mut ply_paths: Vec<(&str, &Loc, [bool; 2])> = Vec::new();
    for (m, &smooth) in rec.meshes.iter().zip(&needs_smooth) {
        if let FacesRec::Ply { path } = &m.faces {
            match ply_paths.iter_mut().find(|(p, _, _)| p == path) {
                Some((_, _, wanted)) => wanted[usize::from(smooth)] = true,
                None => {
                    let mut wanted = [false; 2];
                    wanted[usize::from(smooth)] = true;
                    ply_paths.push((path.as_str(), &m.faces_loc, wanted));
                }
            }
        }
    }
    let plys: HashMap<&str, Result<PlyLoaded, SceneError>> =
        ply_paths.par_iter().map(|&(p, loc, wanted)| (p, load_ply_cached(ctx, p, loc, wanted))).collect();

    // Each mesh, whether the cache served it, and its identity (see `Meshes::identity`).
    type Built = (CachedMesh, bool, Option<[u8; 32]>);
    let built: Vec<Result<Built, SceneError>> = rec
        .meshes
        .par_iter()
        .enumerate()
        .map(|(i, m)| {
            let (data, content) = match &m.faces {
                FacesRec::Ply { path } => {
                    let loaded = match plys.get(path.as_str()) {
                        Some(Ok(l)) => l,
                        Some(Err(e)) => return Err(e.clone()),
                        None => return Err(ctx.err(&m.faces_loc, "internal: PLY not loaded")),
                    };
                    let identity = loaded.content.map(|c| mesh_identity(&c, needs_smooth[i]));
                    if let Some(c) = &loaded.cached[usize::from(needs_smooth[i])] {
                        return Ok((c.clone(), true, identity));
                    }
                    let data = loaded.data.clone();
                    (data.ok_or_else(|| ctx.err(&m.faces_loc, "internal: PLY not parsed"))?, loaded.content)
                }
                _ => (load_mesh_data(ctx, m)?, None),
            };
            let mut indices = data.indices.clone();
            let dropped = drop_degenerate(&data.positions, &mut indices);
            let normals = if needs_smooth[i] {
                match (&data.file_normals, &data.groups) {
                    (Some(n), _) => Some(n.clone()),
                    (None, Some(groups)) => Some(grouped_normals(&data.positions, &indices, groups)),
                    (None, None) => Some(area_weighted_normals(&data.positions, &indices)),
                }
            } else {
                None
            };
            let geom = MeshGeom::with_uvs(data.positions.clone(), indices, normals, data.uvs.clone());
            let mesh = CachedMesh { geom: Arc::new(geom), dropped };
            Ok(match (ctx.cache, content) {
                (Some(cache), Some(content)) => (
                    cache.put_mesh(&content, needs_smooth[i], mesh),
                    false,
                    Some(mesh_identity(&content, needs_smooth[i])),
                ),
                _ => (mesh, false, None),
            })
        })
        .collect();
    let mut geoms: Vec<Arc<MeshGeom>> = Vec::with_capacity(built.len());
    let mut cached = 0;
    let mut identity = Vec::with_capacity(rec.meshes.len());
    for (g, m) in built.into_iter().zip(&rec.meshes) {
        let (CachedMesh { geom, dropped }, hit, id) = g?;
        cached += usize::from(hit);
        identity.push(id);
        if dropped > 0 {
            ctx.warn(warnings, &m.faces_loc, format!("skipped {dropped} degenerate triangle(s)"));
        }
        if geom.triangle_count() == 0 {
            ctx.warn(warnings, &m.loc, "mesh has no triangles");
        }
        geoms.push(geom);
    }
    Ok(Meshes { geoms, world, instances, cached, identity })
}

/// The identity of a PLY mesh built from the file of SHA-256 `content`, smooth or not.
fn mesh_identity(content: &[u8; 32], smooth: bool) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"ply mesh");
    h.update(content);
    h.update([u8::from(smooth)]);
    h.finalize().into()
}

/// The key of the world-space tree of `instances` over `geoms`: a hash of everything
/// `geometry::merge_static_meshes` reads (see `Accel::with_world_tree`). A mesh is named by its
/// `identity` when it has one, else by its positions and triangles, bit for bit.
fn world_tree_key(
    geoms: &[Arc<MeshGeom>],
    identity: &[Option<[u8; 32]>],
    instances: &[Instance],
) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"tessera world tree 1");
    h.update((geoms.len() as u64).to_le_bytes());
    for (i, g) in geoms.iter().enumerate() {
        match identity.get(i).copied().flatten() {
            Some(id) => {
                h.update([1]);
                h.update(id);
            }
            None => {
                h.update([0]);
                h.update((g.positions.len() as u64).to_le_bytes());
                for p in &g.positions {
                    for c in p.to_array() {
                        h.update(c.to_bits().to_le_bytes());
                    }
                }
                h.update((g.indices.len() as u64).to_le_bytes());
                for t in &g.indices {
                    for k in t {
                        h.update(k.to_le_bytes());
                    }
                }
            }
        }
    }
    h.update((instances.len() as u64).to_le_bytes());
    for inst in instances {
        match inst.shape {
            Shape::Mesh { mesh, smooth } => {
                h.update([1, u8::from(smooth)]);
                h.update(mesh.to_le_bytes());
            }
            Shape::Sphere { .. } => h.update([2]),
            Shape::Plane { .. } => h.update([3]),
        }
        match &inst.transform {
            Some(t) => {
                h.update([1]);
                for c in t.to_world.to_cols_array() {
                    h.update(c.to_bits().to_le_bytes());
                }
            }
            None => h.update([0]),
        }
        match inst.motion {
            Some(m) => {
                h.update([1]);
                for c in m.to_array() {
                    h.update(c.to_bits().to_le_bytes());
                }
            }
            None => h.update([0]),
        }
        h.update([u8::from(inst.textures == ObjectTextures::default())]);
    }
    h.finalize().into()
}

/// What step 6 reads: the id tables and the built texture maps.
struct Objects<'c, 'a> {
    ctx: &'c Ctx<'a>,
    transforms: &'c HashMap<(char, &'a str), TransformOp>,
    mat_ids: &'c HashMap<&'a str, u32>,
    textures: &'c BuiltTextures<'a>,
}

impl Objects<'_, '_> {
    /// Step 6: every object as an [`Instance`] with its material, transform, motion and texture
    /// maps: meshes themselves, mesh instances, single triangles (each a one-triangle mesh of its
    /// own, added to `meshes.geoms`), spheres and planes, in that order. Returns all the mesh
    /// geometry, the instances, and which of them emit (LightMesh, LightSphere) with their
    /// radiance and the record's location.
    #[allow(clippy::type_complexity)]
    fn place(
        &self,
        meshes: Meshes,
        warnings: &mut Vec<Warning>,
    ) -> Result<(Vec<Arc<MeshGeom>>, Vec<Instance>, Vec<Emitter>), SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let Meshes { mut geoms, world, instances: resolved, .. } = meshes;
        let mut instances = Vec::new();
        let mut emitters = Vec::new();
        let mut mesh_textures = Vec::with_capacity(rec.meshes.len());
        for m in &rec.meshes {
            mesh_textures.push(self.textures.for_object(ctx, &m.textures, &m.loc, warnings)?);
        }
        for (i, m) in rec.meshes.iter().enumerate() {
            let material = ctx.material(self.mat_ids, &m.material, &m.loc)?;
            if uses_image(self.textures, &mesh_textures[i]) && geoms[i].uvs.is_none() {
                ctx.warn(warnings, &m.loc, "an image texture is applied but the mesh has no texture coordinates (TexCoordData or PLY u v); it is sampled at the barycentric coordinates");
            }
            if let Some(r) = m.radiance {
                emitters.push(Emitter {
                    instance: instances.len() as u32,
                    radiance: v3(r),
                    loc: m.loc.clone(),
                });
            }
            instances.push(Instance {
                shape: Shape::Mesh { mesh: i as u32, smooth: m.shading == ShadingMode::Smooth },
                material,
                transform: ctx.make_transform(world[i], &m.loc)?,
                motion: motion(m.motion_blur),
                textures: mesh_textures[i],
            });
        }
        for (r, inst) in resolved.iter().zip(&rec.instances) {
            // An instance's own `Textures` replace its base mesh's.
            let textures = match r.textures_from {
                None => mesh_textures[r.mesh],
                Some(k) => {
                    let own = &rec.instances[k];
                    let t = self.textures.for_object(ctx, &own.textures, &own.loc, warnings)?;
                    if uses_image(self.textures, &t) && geoms[r.mesh].uvs.is_none() {
                        ctx.warn(warnings, &own.loc, "an image texture is applied but the base mesh has no texture coordinates (TexCoordData or PLY u v); it is sampled at the barycentric coordinates");
                    }
                    t
                }
            };
            instances.push(Instance {
                shape: Shape::Mesh { mesh: r.mesh as u32, smooth: r.smooth },
                material: r.material,
                transform: ctx.make_transform(r.world, &inst.loc)?,
                motion: motion(inst.motion_blur),
                textures,
            });
        }
        for t in &rec.triangles {
            if let Some((geom, instance)) = self.triangle(t, geoms.len() as u32, warnings)? {
                geoms.push(geom);
                instances.push(instance);
            }
        }
        for s in &rec.spheres {
            if let Some(r) = s.radiance {
                emitters.push(Emitter {
                    instance: instances.len() as u32,
                    radiance: v3(r),
                    loc: s.loc.clone(),
                });
            }
            instances.push(self.sphere(s, warnings)?);
        }
        for p in &rec.planes {
            instances.push(self.plane(p, warnings)?);
        }
        Ok((geoms, instances, emitters))
    }

    /// A `<Triangle>` as a one-triangle mesh (the mesh index `mesh` in the scene) and its
    /// instance; `None` (with a warning) when it is degenerate.
    fn triangle(
        &self,
        t: &TriangleRec,
        mesh: u32,
        warnings: &mut Vec<Warning>,
    ) -> Result<Option<(Arc<MeshGeom>, Instance)>, SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let material = ctx.material(self.mat_ids, &t.material, &t.loc)?;
        let mut ids = [0u32; 3];
        for (id, &index) in ids.iter_mut().zip(&t.indices) {
            *id = ctx.vertex(index, &t.loc, "<Indices>")?;
        }
        let positions: Vec<DVec3> = ids.iter().map(|&g| v3(rec.vertices[g as usize])).collect();
        let mut indices = vec![[0, 1, 2]];
        if drop_degenerate(&positions, &mut indices) > 0 {
            ctx.warn(warnings, &t.loc, "degenerate triangle skipped");
            return Ok(None);
        }
        let world = ctx.transform(self.transforms, &t.transforms, &t.loc)?;
        // Texture coordinates are parallel to the vertex list (§8.2).
        let uvs = ids
            .iter()
            .map(|&g| rec.tex_coords.get(g as usize).map(|t| DVec2::from_array(*t)))
            .collect::<Option<Vec<_>>>();
        let object_textures = self.textures.for_object(ctx, &t.textures, &t.loc, warnings)?;
        if uvs.is_none() && uses_image(self.textures, &object_textures) {
            ctx.warn(warnings, &t.loc, "an image texture is applied but <TexCoordData> has no entry for its vertices; it is sampled at the barycentric coordinates");
        }
        let geom = Arc::new(MeshGeom::with_uvs(positions, indices, None, uvs));
        let instance = Instance {
            shape: Shape::Mesh { mesh, smooth: false },
            material,
            transform: ctx.make_transform(world, &t.loc)?,
            motion: motion(t.motion_blur),
            textures: object_textures,
        };
        Ok(Some((geom, instance)))
    }

    fn sphere(&self, s: &SphereRec, warnings: &mut Vec<Warning>) -> Result<Instance, SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let material = ctx.material(self.mat_ids, &s.material, &s.loc)?;
        let c = ctx.vertex(s.center, &s.loc, "<Center>")?;
        if !(s.radius > 0.0 && s.radius.is_finite()) {
            return Err(ctx.err(&s.loc, format!("<Radius> must be a positive number, found {}", s.radius)));
        }
        let world = ctx.transform(self.transforms, &s.transforms, &s.loc)?;
        let (center, textures) =
            (v3(rec.vertices[c as usize]), self.textures.for_object(ctx, &s.textures, &s.loc, warnings)?);
        let motion = motion(s.motion_blur);
        // An untextured, unmoving sphere under a similarity is a world-space sphere: the ray
        // is tested directly instead of being carried into object space first. (Textures keep
        // the transform: their coordinates and solid noise live in object space.)
        if textures == ObjectTextures::default()
            && motion.is_none()
            && let Some(scale) = crate::math::uniform_scale(&world.matrix3)
            && world != DAffine3::IDENTITY
        {
            return Ok(Instance {
                shape: Shape::Sphere { center: world.transform_point3(center), radius: s.radius * scale },
                material,
                transform: None,
                motion,
                textures,
            });
        }
        Ok(Instance {
            shape: Shape::Sphere { center, radius: s.radius },
            material,
            transform: ctx.make_transform(world, &s.loc)?,
            motion,
            textures,
        })
    }

    fn plane(&self, p: &PlaneRec, warnings: &mut Vec<Warning>) -> Result<Instance, SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let material = ctx.material(self.mat_ids, &p.material, &p.loc)?;
        let point = ctx.vertex(p.point, &p.loc, "<Point>")?;
        let normal = v3(p.normal).normalize_or_zero();
        if normal == DVec3::ZERO || !normal.is_finite() {
            return Err(ctx.err(&p.loc, "<Normal> must be a non-zero direction"));
        }
        let world = ctx.transform(self.transforms, &p.transforms, &p.loc)?;
        Ok(Instance {
            shape: Shape::Plane { point: v3(rec.vertices[point as usize]), normal },
            material,
            transform: ctx.make_transform(world, &p.loc)?,
            motion: motion(p.motion_blur),
            textures: self.textures.for_object(ctx, &p.textures, &p.loc, warnings)?,
        })
    }
}

/// An emitting object found by [`Objects::place`].
struct Emitter {
    instance: u32,
    radiance: DVec3,
    loc: Loc,
}

/// Step 7: the object lights (§13.3), each a world-space copy of its surface for sampling, and
/// the radiance of every instance by index (`None` for objects that do not emit). A light with
/// no area (every triangle degenerate) still shows where it is seen but lights nothing, with a
/// warning.
fn object_lights(
    ctx: &Ctx,
    accel: &Accel,
    emitters: &[Emitter],
    warnings: &mut Vec<Warning>,
) -> (Vec<ObjectLight>, Vec<Option<DVec3>>, Vec<u32>) {
    let mut emission = vec![None; if emitters.is_empty() { 0 } else { accel.instances.len() }];
    let mut light_of = vec![u32::MAX; emission.len()];
    let mut lights = Vec::with_capacity(emitters.len());
    for e in emitters {
        emission[e.instance as usize] = Some(e.radiance);
        if e.radiance == DVec3::ZERO {
            continue;
        }
        let inst = &accel.instances[e.instance as usize];
        let to_world = inst.transform.as_ref().map(|t| t.to_world);
        let light = match &inst.shape {
            Shape::Mesh { mesh, .. } => {
                let g = &accel.meshes[*mesh as usize];
                let place = |p: DVec3| to_world.map_or(p, |m| m.transform_point3(p));
                let tris = g.indices.iter().map(|t| t.map(|k| place(g.positions[k as usize]))).collect();
                ObjectLight::triangles(tris, e.radiance, e.instance)
            }
            Shape::Sphere { center, radius } => {
                Some(ObjectLight::sphere(*center, *radius, to_world, e.radiance, e.instance))
            }
            Shape::Plane { .. } => None,
        };
        match light {
            Some(l) => {
                light_of[e.instance as usize] = lights.len() as u32;
                lights.push(l);
            }
            None => ctx.warn(warnings, &e.loc, "the light has no area; it is visible but lights nothing"),
        }
    }
    (lights, emission, light_of)
}

/// An object's `<MotionBlur>` velocity; none when absent or zero.
fn motion(motion_blur: Option<Vec3>) -> Option<DVec3> {
    motion_blur.map(v3).filter(|v| *v != DVec3::ZERO)
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::assets::FsResolver;
    use crate::math::Ray;

    fn build(xml: &str) -> Result<Scene, SceneError> {
        let rec = crate::scene::xml::parse_xml(xml, std::path::Path::new("t.xml"))?;
        build_scene(&rec, &FsResolver { base_dir: ".".into() })
    }

    const CHAIN: &str = r#"<Scene>
      <Materials><Material id="1"/><Material id="2"/></Materials>
      <Transformations><Translation id="1">0 0 -10</Translation><Translation id="2">100 0 0</Translation></Transformations>
      <VertexData>-1 -1 0  1 -1 0  0 1 0</VertexData>
      <Objects>
        <Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
        <MeshInstance id="2" baseMeshId="1"><Transformations>t1</Transformations></MeshInstance>
        <MeshInstance id="3" baseMeshId="2"><Material>2</Material><Transformations>t1</Transformations></MeshInstance>
        <MeshInstance id="4" baseMeshId="3" resetTransform="true"><Transformations>t2</Transformations></MeshInstance>
      </Objects></Scene>"#;

    /// `Textures` on a MeshInstance replace its base mesh's; an instance without any keeps its
    /// base's, through a chain of instances.
    #[test]
    fn an_instance_s_own_textures_replace_its_base_s() {
        let scene = build(
            r#"<Scene>
      <Materials><Material id="1"/></Materials>
      <Textures>
        <TextureMap id="red" type="checkerboard"><DecalMode>replace_kd</DecalMode><BlackColor>1 0 0</BlackColor><WhiteColor>1 0 0</WhiteColor></TextureMap>
        <TextureMap id="blue" type="checkerboard"><DecalMode>replace_kd</DecalMode><BlackColor>0 0 1</BlackColor><WhiteColor>0 0 1</WhiteColor></TextureMap>
      </Textures>
      <VertexData>-1 -1 0  1 -1 0  0 1 0</VertexData>
      <Objects>
        <Mesh id="1"><Material>1</Material><Textures>red</Textures><Faces>1 2 3</Faces></Mesh>
        <MeshInstance id="2" baseMeshId="1"></MeshInstance>
        <MeshInstance id="3" baseMeshId="1"><Textures>blue</Textures></MeshInstance>
        <MeshInstance id="4" baseMeshId="3"></MeshInstance>
      </Objects></Scene>"#,
        )
        .unwrap();
        let colour = |i: usize| {
            let t = scene.accel.instances[i].textures;
            assert!(t.colour[1].is_none() && t.normal.is_none());
            let map = &scene.textures[t.colour[0].expect("a colour map") as usize];
            let p = crate::texture::maps::TexturePoint {
                uv: glam::DVec2::ZERO,
                object: DVec3::splat(0.5),
                footprint: glam::DVec2::ZERO,
            };
            map.value(&p)
        };
        let (red, blue) = (DVec3::X, DVec3::Z);
        // The mesh, the instance without textures, the one with its own, and its instance.
        assert_eq!([colour(0), colour(1), colour(2), colour(3)], [red, red, blue, blue]);
    }

    /// A material's BRDF must exist; a LightMesh and a LightSphere become object lights with
    /// their instances' radiance, in file order; a light of no area shows but does not light.
    #[test]
    fn brdf_references_and_object_lights() {
        let err = build(r#"<Scene><Materials><Material id="1" BRDF="9"></Material></Materials></Scene>"#)
            .err()
            .expect("an unknown BRDF is an error");
        assert!(err.to_string().contains(r#"BRDF "9" is not defined"#), "{err}");
        let scene = build(
            r#"<Scene><BRDFs><ModifiedPhong id="b"><Exponent>20</Exponent></ModifiedPhong></BRDFs>
            <Materials><Material id="1" BRDF="b"><PhongExponent>3</PhongExponent></Material></Materials>
            <VertexData>0 0 0  1 0 0  0 1 0  0 0 0</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
              <LightMesh id="2"><Material>1</Material><Radiance>2 2 2</Radiance><Faces>1 2 3</Faces></LightMesh>
              <LightMesh id="3"><Material>1</Material><Radiance>2 2 2</Radiance><Faces>1 1 2</Faces></LightMesh>
              <LightSphere id="4"><Material>1</Material><Center>4</Center><Radius>2</Radius><Radiance>1 2 3</Radiance></LightSphere>
            </Objects></Scene>"#,
        )
        .unwrap();
        assert_eq!(scene.materials[0].phong_exponent, 20.0, "the BRDF's Exponent replaces PhongExponent");
        assert_eq!(scene.materials[0].brdf.map(|b| b.kind), Some(BrdfKind::ModifiedPhong));
        let emission: Vec<Option<DVec3>> = scene.instance_emission.clone();
        assert_eq!(emission.len(), scene.accel.instances.len());
        assert_eq!(emission.iter().filter(|e| e.is_some()).count(), 3);
        let lit: Vec<u32> = scene.object_lights.iter().map(|l| l.instance).collect();
        assert_eq!(lit.len(), 2, "the degenerate light mesh lights nothing");
        assert_eq!(emission[lit[0] as usize], Some(DVec3::splat(2.0)));
        assert_eq!(emission[lit[1] as usize], Some(DVec3::new(1.0, 2.0, 3.0)));
        assert_eq!(scene.object_lights[1].area(), Some(16.0 * std::f64::consts::PI));
    }

    /// An untextured, unmoving sphere under rotations, a reflection, a uniform scale and a
    /// translation becomes a world-space sphere (no transform to apply per ray), hit where the
    /// transformed one is; a non-uniform scale, motion or a texture keep the transform.
    #[test]
    fn similarity_transformed_spheres_are_placed_in_world_space() {
        let scene = build(
            r#"<Scene><Materials><Material id="1"></Material></Materials>
            <Transformations><Translation id="1">1 2 3</Translation><Scaling id="1">2 2 2</Scaling>
              <Scaling id="2">-2 2 2</Scaling><Scaling id="3">2 1 1</Scaling><Rotation id="1">30 1 1 0</Rotation></Transformations>
            <VertexData>0 0 0  0.5 0 0</VertexData>
            <Objects>
              <Sphere id="1"><Material>1</Material><Center>2</Center><Radius>1</Radius><Transformations>r1 s1 t1</Transformations></Sphere>
              <Sphere id="2"><Material>1</Material><Center>1</Center><Radius>1</Radius><Transformations>s2 r1</Transformations></Sphere>
              <Sphere id="3"><Material>1</Material><Center>1</Center><Radius>1</Radius><Transformations>s3</Transformations></Sphere>
              <Sphere id="4"><Material>1</Material><Center>1</Center><Radius>1</Radius><Transformations>s1</Transformations><MotionBlur>0 1 0</MotionBlur></Sphere>
            </Objects></Scene>"#,
        )
        .unwrap();
        let shapes: Vec<(Option<(DVec3, f64)>, bool)> = scene
            .accel
            .instances
            .iter()
            .map(|i| match i.shape {
                Shape::Sphere { center, radius } => (Some((center, radius)), i.transform.is_some()),
                _ => (None, i.transform.is_some()),
            })
            .collect();
        // r1 s1 t1 applied to (0.5, 0, 0): rotated about (1 1 0)/√2 by 30°, doubled, moved.
        let m = DAffine3::from_translation(DVec3::new(1.0, 2.0, 3.0))
            * DAffine3::from_scale(DVec3::splat(2.0))
            * DAffine3::from_axis_angle(DVec3::new(1.0, 1.0, 0.0).normalize(), 30f64.to_radians());
        let (c, r) = shapes[0].0.unwrap();
        assert!(
            (c - m.transform_point3(DVec3::new(0.5, 0.0, 0.0))).length() < 1e-12 && (r - 2.0).abs() < 1e-12
        );
        assert!(!shapes[0].1 && !shapes[1].1, "similarities (with a reflection too) are baked: {shapes:?}");
        assert_eq!(shapes[1].0.map(|s| s.1), Some(2.0));
        assert!(shapes[2].1 && shapes[3].1, "a non-uniform scale and a moving sphere keep their transform");
        // Hit where the transformed sphere is: its top along the world z axis through the centre.
        let h = scene
            .accel
            .intersect(&Ray::new(c + DVec3::new(0.0, 0.0, 10.0), DVec3::NEG_Z), 1e-9, 1e9)
            .unwrap();
        assert!((h.t - 8.0).abs() < 1e-9 && (h.geo_normal - DVec3::Z).length() < 1e-12, "{h:?}");
    }

    #[test]
    fn instances_chain_through_other_instances() {
        let scene = build(CHAIN).unwrap();
        let hit = |x: f64, z0: f64| {
            scene.accel.intersect(&Ray::new(DVec3::new(x, 0.0, z0), DVec3::NEG_Z), 1e-9, 1e9)
        };
        // The mesh at z=0, instance 2 at z=-10, instance 3 (t1 on top of instance 2) at z=-20.
        let h = hit(0.0, -15.0).unwrap();
        assert!((h.point.z + 20.0).abs() < 1e-9 && h.material == 1, "{h:?}");
        let h = hit(0.0, -5.0).unwrap();
        assert!((h.point.z + 10.0).abs() < 1e-9 && h.material == 0, "{h:?}");
        // Instance 4 resets to its own t2 and inherits instance 3's material.
        let h = hit(100.0, 5.0).unwrap();
        assert!(h.point.z.abs() < 1e-9 && h.material == 1, "{h:?}");
    }

    #[test]
    fn instance_cycles_and_unknown_bases_are_errors() {
        let cyc = CHAIN
            .replace(r#"<MeshInstance id="2" baseMeshId="1">"#, r#"<MeshInstance id="2" baseMeshId="4">"#);
        let e = build(&cyc).err().expect("a cycle must fail").to_string();
        assert!(e.contains("cycle") && e.contains("MeshInstance"), "{e}");
        let unknown = CHAIN.replace(r#"baseMeshId="3""#, r#"baseMeshId="9""#);
        let e = build(&unknown).err().expect("an unknown base must fail").to_string();
        assert!(e.contains(r#"baseMeshId="9""#) && e.contains("t.xml:"), "{e}");
    }

    /// A 2019 binary file: the int32 count, then the records' 32-bit words, little-endian.
    fn binary(count: i32, words: &[[u8; 4]]) -> Vec<u8> {
        let mut out = count.to_le_bytes().to_vec();
        words.iter().for_each(|w| out.extend(w));
        out
    }

    /// 2019 `binaryFile` vertices, texture coordinates and faces, and `ZeroBasedIndexing`
    /// (faces and a Triangle's Indices count from 0): a square of a binary-faced mesh and a
    /// Triangle, each hit where its vertices put it, with the binary uvs (the mesh has a map, so
    /// its hits carry them).
    #[test]
    fn binary_data_and_zero_based_indexing() {
        let dir = tessera_testkit::TempDir::new("build-binary");
        let f = |v: f32| v.to_le_bytes();
        let verts: Vec<[u8; 4]> =
            [-1.0, -1.0, -5.0, 1.0, -1.0, -5.0, 1.0, 1.0, -5.0, -1.0, 1.0, -5.0].map(f).to_vec();
        let uvs: Vec<[u8; 4]> = [0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0].map(f).to_vec();
        std::fs::write(dir.join("v.bin"), binary(4, &verts)).unwrap();
        std::fs::write(dir.join("uv.bin"), binary(4, &uvs)).unwrap();
        std::fs::write(dir.join("f.bin"), binary(1, &[0i32, 1, 2].map(i32::to_le_bytes))).unwrap();
        // A count beyond the data.
        std::fs::write(dir.join("short.bin"), binary(2, &[0i32, 1, 2].map(i32::to_le_bytes))).unwrap();
        let xml = |zero_based: &str, faces: &str| {
            format!(
                r#"<Scene>
<ZeroBasedIndexing>{zero_based}</ZeroBasedIndexing>
<Materials><Material id="1"/></Materials><Textures><TextureMap id="c" type="checkerboard"><DecalMode>replace_kd</DecalMode></TextureMap></Textures>
<VertexData binaryFile="v.bin"/>
<TexCoordData binaryFile="uv.bin"/>
<Objects>
<Mesh id="1"><Material>1</Material><Textures>c</Textures><Faces binaryFile="{faces}"/></Mesh>
<Triangle id="1"><Material>1</Material><Indices>0 2 3</Indices></Triangle>
</Objects></Scene>"#
            )
        };
        let build_at = |text: &str| {
            let rec = crate::scene::xml::parse_xml(text, &dir.join("s.xml"))?;
            build_scene(&rec, &FsResolver { base_dir: dir.to_path_buf() })
        };
        let scene = build_at(&xml("true", "f.bin")).unwrap();
        assert!(scene.warnings.iter().all(|w| !w.unsupported), "{:?}", scene.warnings);
        let hit = |x: f64, y: f64| {
            scene.accel.intersect(&Ray::new(DVec3::new(x, y, 0.0), DVec3::NEG_Z), 1e-9, 1e9).expect("a hit")
        };
        let h = hit(0.5, -0.5);
        assert_eq!(h.instance, 0);
        assert!((h.t - 5.0).abs() < 1e-9);
        assert!((h.uv - DVec2::new(0.75, 0.25)).length() < 1e-6, "{:?}", h.uv);
        let h = hit(-0.5, 0.5);
        assert_eq!(h.instance, 1);
        assert!((h.t - 5.0).abs() < 1e-9);
        // Read 1-based, vertex 0 does not exist.
        let e = build_at(&xml("false", "f.bin")).err().expect("vertex 0 is an error 1-based");
        assert!(
            e.to_string().contains("s.xml:7: <Mesh id=\"1\"> / <Faces>: face 1 refers to vertex 0"),
            "{e}"
        );
        // A missing or truncated file is an error naming the element's line and the file.
        let e = build_at(&xml("true", "none.bin")).err().expect("a missing file");
        assert!(e.to_string().contains("s.xml:7: <Mesh id=\"1\"> / <Faces>: cannot read binary file"), "{e}");
        assert!(e.to_string().contains("none.bin"), "{e}");
        let e = build_at(&xml("true", "short.bin")).err().expect("a truncated file");
        assert!(
            e.to_string()
                .contains("says it holds 2 triangles of 3 int32 vertex ids, but it is 16 bytes long"),
            "{e}"
        );
    }

    #[test]
    fn an_image_used_by_several_maps_is_decoded_once() {
        let dir = tessera_testkit::TempDir::new("build-img");
        // A 1x1 grey PNG from the image crate.
        let png = dir.join("g.png");
        image::save_buffer(&png, &[9, 9, 9], 1, 1, image::ExtendedColorType::Rgb8).unwrap();
        let xml = r#"<Scene><Textures><Images><Image id="1">g.png</Image><Image id="2">./g.png</Image></Images>
            <TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode></TextureMap>
            <TextureMap id="2" type="image"><ImageId>1</ImageId><DecalMode>bump_normal</DecalMode></TextureMap>
            <TextureMap id="3" type="image"><ImageId>2</ImageId><DecalMode>replace_ks</DecalMode></TextureMap>
            </Textures></Scene>"#;
        let rec = crate::scene::xml::parse_xml(xml, &dir.join("s.xml")).unwrap();
        let scene = build_scene(&rec, &FsResolver { base_dir: dir.to_path_buf() }).unwrap();
        let img = |k: usize| match &scene.textures[k].source {
            Source::Image { image, .. } => image.clone(),
            _ => panic!("not an image map"),
        };
        // Maps 1 and 2 share image 1: one decoded copy. Image 2 names the file differently.
        assert!(Arc::ptr_eq(&img(0), &img(1)));
        assert_eq!(img(2).texels, img(0).texels);
        // A missing image names the file, the image id and the map that uses it.
        let missing = xml.replace("<Image id=\"1\">g.png", "<Image id=\"1\">nope.png");
        let rec = crate::scene::xml::parse_xml(&missing, &dir.join("s.xml")).unwrap();
        let e = build_scene(&rec, &FsResolver { base_dir: dir.to_path_buf() })
            .err()
            .expect("must fail")
            .to_string();
        assert!(e.contains("nope.png") && e.contains("image id 1") && e.contains("texture map 1"), "{e}");
    }

    #[test]
    fn oversized_images_are_refused() {
        let xml = r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
            <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>100000 100000</ImageResolution>
            <ImageName>a.png</ImageName></Camera></Cameras></Scene>"#;
        let e = build(xml).err().expect("must fail").to_string();
        assert!(e.contains("too large") && e.contains("Camera"), "{e}");
    }

    /// A scene with r1 (90° about y), t1 (10, 0, 0), s1 (2, 1, 1) and s2 (0, 0, 0), and the given
    /// `<Cameras>` and `<Lights>` contents.
    fn placed(cameras: &str, lights: &str) -> String {
        format!(
            r#"<Scene>
      <Transformations><Rotation id="1">90 0 1 0</Rotation><Translation id="1">10 0 0</Translation>
        <Scaling id="1">2 1 1</Scaling><Scaling id="2">0 0 0</Scaling></Transformations>
      <Cameras>
{cameras}
      </Cameras>
      <Lights>
{lights}
      </Lights></Scene>"#
        )
    }

    /// A camera of `kind` (`""` or `type="lookAt"`) with the given view children.
    fn camera_xml(kind: &str, view: &str) -> String {
        let plane =
            if kind.is_empty() { "<NearPlane>-1 1 -0.75 0.75</NearPlane>" } else { "<FovY>40</FovY>" };
        format!(
            r#"<Camera id="1" {kind}>{view}{plane}
            <NearDistance>1</NearDistance><ImageResolution>8 6</ImageResolution><ImageName>a.png</ImageName></Camera>"#
        )
    }

    fn assert_near(got: DVec3, want: DVec3, what: &str) {
        assert!((got - want).length() < 1e-9, "{what}: got {got}, want {want}");
    }

    /// Every pixel's primary ray, through several points of the pixel.
    fn assert_same_rays(got: &Camera, want: &Camera) {
        for y in 0..want.height {
            for x in 0..want.width {
                for (dx, dy) in [(0.0, 0.0), (0.5, 0.5), (0.9, 0.2)] {
                    let (g, w) = (got.ray(x, y, dx, dy), want.ray(x, y, dx, dy));
                    assert_near(g.origin, w.origin, &format!("origin of ray ({x}, {y})"));
                    assert_near(g.dir, w.dir, &format!("direction of ray ({x}, {y})"));
                }
            }
        }
    }

    #[test]
    fn camera_transformations_place_it_like_moving_its_vectors_by_hand() {
        // r1 then t1: (x, y, z) -> (z + 10, y, -x). Up is tilted so the rotation changes it.
        let cases = [
            (
                "",
                "<Position>1 2 3</Position><Gaze>0 0 -1</Gaze><Up>0 1 0.2</Up>",
                "<Position>13 2 -1</Position><Gaze>-1 0 0</Gaze><Up>0.2 1 0</Up>",
            ),
            (
                r#"type="lookAt""#,
                "<Position>1 2 3</Position><GazePoint>1 2 -7</GazePoint><Up>0 1 0.2</Up>",
                "<Position>13 2 -1</Position><GazePoint>3 2 -1</GazePoint><Up>0.2 1 0</Up>",
            ),
        ];
        for (kind, view, by_hand) in cases {
            let transformed = format!("{view}<Transformations>r1 t1</Transformations>");
            let got = build(&placed(&camera_xml(kind, &transformed), "")).unwrap();
            let want = build(&placed(&camera_xml(kind, by_hand), "")).unwrap();
            assert!(got.warnings.is_empty(), "{:?}", got.warnings);
            assert_same_rays(&got.cameras[0], &want.cameras[0]);
        }
        // Rotation alone: the position turns about the origin too.
        let got = build(&placed(
            &camera_xml("", "<Position>1 2 3</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up><Transformations>r1</Transformations>"),
            "",
        ))
        .unwrap();
        let want = build(&placed(
            &camera_xml("", "<Position>3 2 -1</Position><Gaze>-1 0 0</Gaze><Up>0 1 0</Up>"),
            "",
        ))
        .unwrap();
        assert_same_rays(&got.cameras[0], &want.cameras[0]);
    }

    /// A scaling along the gaze moves a NearPlane camera's image plane by its factor (the
    /// plane's extents as given): camera_zoom_david's frames zoom so.
    #[test]
    fn a_scaling_along_the_gaze_moves_the_image_plane() {
        let view = "<Position>0 0 0</Position><Gaze>-1 0 0</Gaze><Up>0 1 0</Up>";
        let got =
            build(&placed(&camera_xml("", &format!("{view}<Transformations>s1</Transformations>")), ""))
                .unwrap();
        let by_hand =
            camera_xml("", view).replace("<NearDistance>1</NearDistance>", "<NearDistance>2</NearDistance>");
        let want = build(&placed(&by_hand, "")).unwrap();
        assert_same_rays(&got.cameras[0], &want.cameras[0]);
        // Across the gaze it changes nothing (the scaling is along x, the view along z).
        let across = "<Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>";
        let got =
            build(&placed(&camera_xml("", &format!("{across}<Transformations>s1</Transformations>")), ""))
                .unwrap();
        let want = build(&placed(&camera_xml("", across), "")).unwrap();
        assert_same_rays(&got.cameras[0], &want.cameras[0]);
    }

    #[test]
    fn light_transformations_move_positions_and_turn_directions() {
        let lights = r#"<PointLight id="1"><Position>1 2 3</Position><Intensity>5 5 5</Intensity>
                <Transformations>t1</Transformations></PointLight>
            <SpotLight id="2"><Position>1 2 3</Position><Direction>0 0 -1</Direction><Intensity>1 1 1</Intensity>
                <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Transformations>r1 t1</Transformations></SpotLight>
            <DirectionalLight id="3"><Direction>0 0 -2</Direction><Radiance>1 1 1</Radiance>
                <Transformations>r1</Transformations></DirectionalLight>
            <AreaLight id="4"><Position>0 5 0</Position><Normal>0 0 1</Normal><Size>2</Size><Radiance>1 1 1</Radiance>
                <Transformations>r1</Transformations></AreaLight>
            <AreaLight id="5"><Position>1 1 1</Position><Normal>1 1 0</Normal><Size>3</Size><Radiance>1 1 1</Radiance>
                <Transformations>s1</Transformations></AreaLight>
            <PointLight id="6"><Position>1 2 3</Position><Intensity>5 5 5</Intensity></PointLight>"#;
        let scene = build(&placed("", lights)).unwrap();
        assert_near(scene.point_lights[0].position, DVec3::new(11.0, 2.0, 3.0), "translated point light");
        assert_eq!(scene.point_lights[0].intensity, DVec3::splat(5.0));
        assert_eq!(scene.point_lights[1].position, DVec3::new(1.0, 2.0, 3.0), "untransformed point light");
        let spot = &scene.spot_lights[0];
        assert_near(spot.position, DVec3::new(13.0, 2.0, -1.0), "spot position");
        assert_near(spot.axis, DVec3::NEG_X, "spot axis");
        assert_near(scene.directional_lights[0].to_light, DVec3::X, "directional light");
        let area = &scene.area_lights[0];
        assert_near(area.center, DVec3::new(0.0, 5.0, 0.0), "area light centre on the rotation axis");
        assert_near(area.normal, DVec3::X, "rotated area light normal");
        assert_eq!(area.size, 2.0);
        // Under a non-uniform scale the normal goes by the inverse transpose, so it stays
        // perpendicular to the scaled square (a tangent (1, -1, 0) becomes (2, -1, 0)); Size stays.
        let scaled = &scene.area_lights[1];
        assert_near(scaled.normal, DVec3::new(0.5, 1.0, 0.0).normalize(), "scaled area light normal");
        assert!(scaled.normal.dot(DVec3::new(2.0, -1.0, 0.0)).abs() < 1e-12);
        assert_near(scaled.center, DVec3::new(2.0, 1.0, 1.0), "scaled area light centre");
        assert_eq!(scaled.size, 3.0);
    }

    #[test]
    fn unknown_or_singular_camera_and_light_transformations_are_errors() {
        let view = "<Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>";
        let point = |t: &str| {
            format!(
                "<PointLight id=\"7\"><Position>0 0 0</Position><Intensity>1 1 1</Intensity><Transformations>{t}</Transformations></PointLight>"
            )
        };
        let spot = r#"<SpotLight id="8"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity>
                <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Transformations>t1 c3</Transformations></SpotLight>"#;
        let directional = r#"<DirectionalLight id="9"><Direction>0 -1 0</Direction><Radiance>1 1 1</Radiance>
                <Transformations>r1 s2</Transformations></DirectionalLight>"#;
        let cases: &[(String, &str)] = &[
            (
                placed(&camera_xml("", &format!("{view}<Transformations>r1 r9</Transformations>")), ""),
                r#"t.xml:5: <Camera id="1">: transformation "r9" is not defined; add <Rotation id="9"> under <Transformations>"#,
            ),
            (
                placed(
                    &camera_xml(r#"type="lookAt""#, &format!("{view}<Transformations>t2</Transformations>")),
                    "",
                ),
                r#"t.xml:5: <Camera id="1">: transformation "t2" is not defined; add <Translation id="2"> under <Transformations>"#,
            ),
            (
                placed("", &point("s5")),
                r#"t.xml:8: <PointLight id="7">: transformation "s5" is not defined; add <Scaling id="5"> under <Transformations>"#,
            ),
            (
                placed("", spot),
                r#"t.xml:8: <SpotLight id="8">: transformation "c3" is not defined; add <Composite id="3"> under <Transformations>"#,
            ),
            (
                placed("", directional),
                r#"t.xml:8: <DirectionalLight id="9">: the transformation is singular (a zero scale?); it would flatten the directions of this camera or light: use non-zero Scaling factors"#,
            ),
        ];
        for (xml, want) in cases {
            match build(xml) {
                Ok(_) => panic!("expected {want:?} for\n{xml}"),
                Err(e) => assert_eq!(e.to_string(), *want, "input:\n{xml}"),
            }
        }
    }

    #[test]
    fn transformation_tokens_apply_left_to_right() {
        // "t1 s1" with t1 = (-0.5, 0, -0.5) and s1 = 1000 centres a unit square before scaling (§10.2).
        let ops = [TransformOp::Translation([-0.5, 0.0, -0.5]), TransformOp::Scaling([1000.0; 3])];
        let m = op_matrix(&ops[1]) * op_matrix(&ops[0]);
        let p = m.transform_point3(DVec3::new(1.0, 0.0, 1.0));
        assert!((p - DVec3::new(500.0, 0.0, 500.0)).length() < 1e-9);
    }

    #[test]
    fn rotation_is_right_handed_in_degrees() {
        let m = op_matrix(&TransformOp::Rotation { degrees: 90.0, axis: [0.0, 0.0, 2.0] });
        assert!((m.transform_vector3(DVec3::X) - DVec3::Y).length() < 1e-12);
    }

    #[test]
    fn composite_is_row_major() {
        let mut a = [0.0; 16];
        a[0] = 1.0;
        a[5] = 1.0;
        a[10] = 1.0;
        a[15] = 1.0;
        a[3] = 7.0; // row 0, column 3 = x translation
        let m = op_matrix(&TransformOp::Composite(a));
        assert_eq!(m.transform_point3(DVec3::ZERO), DVec3::new(7.0, 0.0, 0.0));
    }
}
