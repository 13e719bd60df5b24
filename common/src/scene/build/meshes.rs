//! Step 5 of the build: the meshes. Instances resolved through their chains, PLY files read
//! once each (or not at all when the cache has their meshes), normals, BVHs, and the content
//! keys that name a mesh and a world tree in the cache.

use std::collections::HashMap;
use std::sync::Arc;

use glam::{DAffine3, DVec2, DVec3};
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use super::context::{Ctx, unplaced_message};
use crate::error::{Loc, SceneError, Warning};
use crate::geometry::mesh::{MeshGeom, area_weighted_normals, drop_degenerate, grouped_normals};
use crate::geometry::{Instance, ObjectTextures, Shape};
use crate::math::v3;
use crate::scene::cache::{CachedMesh, read_rekeyed};
use crate::scene::records::*;

/// A MeshInstance with its chain of bases followed down to a Mesh.
#[derive(Clone, Copy)]
pub(super) struct ResolvedInstance {
    /// Index of the Mesh record whose geometry it shows.
    pub(super) mesh: usize,
    pub(super) world: DAffine3,
    pub(super) material: u32,
    pub(super) smooth: bool,
    /// The MeshInstance record whose `Textures` it shows (the nearest in its chain that has
    /// some); `None`: its Mesh's.
    pub(super) textures_from: Option<usize>,
}

/// Resolves every MeshInstance: `baseMeshId` names a Mesh, or else another MeshInstance (the
/// course files use one id space for both). Without `resetTransform` the instance's own
/// transformations apply on top of its base's world transform; the material, the texture maps
/// and smooth shading are inherited unless the instance sets them. Cycles are errors.
pub(super) fn resolve_instances(
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
pub(super) struct MeshData {
    pub(super) positions: Vec<DVec3>,
    pub(super) indices: Vec<[u32; 3]>,
    pub(super) file_normals: Option<Vec<DVec3>>,
    pub(super) uvs: Option<Vec<DVec2>>,
    /// For inline meshes: the scene vertex each of our vertices came from (a vertex is split
    /// when its corners use different texture coordinates; smooth normals are shared by group).
    pub(super) groups: Option<Vec<u32>>,
}

/// The triangle data of a Mesh record whose faces are in the scene (a PLY mesh's comes from
/// [`load_ply_cached`]).
pub(super) fn load_mesh_data(ctx: &Ctx, mesh: &MeshRec) -> Result<Arc<MeshData>, SceneError> {
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
pub(super) fn ply_read_error(ctx: &Ctx, path: &str, loc: &Loc, e: std::io::Error) -> SceneError {
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
pub(super) fn load_ply(
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
pub(super) struct PlyLoaded {
    pub(super) content: Option<[u8; 32]>,
    pub(super) cached: [Option<CachedMesh>; 2],
    pub(super) data: Option<Arc<MeshData>>,
}

/// Loads the PLY file `path` named at `loc`, whose meshes are wanted flat (`wanted[0]`) and/or
/// smooth (`wanted[1]`). With a cache, the file is neither parsed nor (when the resolver knows
/// its content id) read if every wanted mesh is cached.
pub(super) fn load_ply_cached(
    ctx: &Ctx,
    path: &str,
    loc: &Loc,
    wanted: [bool; 2],
) -> Result<PlyLoaded, SceneError> {
    let Some(cache) = ctx.cache else {
        let data = load_ply(ctx, path, loc, None)?;
        return Ok(PlyLoaded { content: None, cached: [None, None], data: Some(data) });
    };
    let (mut content, read) =
        cache.content_key(ctx.resolver, path).map_err(|e| ply_read_error(ctx, path, loc, e))?;
    let mut cached = [None, None];
    for (k, slot) in cached.iter_mut().enumerate() {
        if wanted[k] {
            *slot = cache.mesh(&content, k == 1);
        }
    }
    let missing = (0..2).any(|k| wanted[k] && cached[k].is_none());
    let data = if missing {
        let read = match read {
            Some(r) => r,
            None => read_rekeyed(ctx.resolver, path, &mut content)
                .map_err(|e| ply_read_error(ctx, path, loc, e))?,
        };
        Some(load_ply(ctx, path, loc, Some(read))?)
    } else {
        None
    };
    Ok(PlyLoaded { content: Some(content), cached, data })
}

/// The geometry of every Mesh record (by record position) and what instances them.
pub(super) struct Meshes {
    pub(super) geoms: Vec<Arc<MeshGeom>>,
    /// Each Mesh record's own world transform.
    pub(super) world: Vec<DAffine3>,
    /// Every MeshInstance record, resolved down to its Mesh.
    pub(super) instances: Vec<ResolvedInstance>,
    /// How many Mesh records the cache served (neither parsed nor built).
    pub(super) cached: usize,
    /// Each Mesh record's geometry's identity when the build has one without hashing its
    /// vertices (a PLY mesh under a cache: its file's SHA-256 and shading), for the world
    /// tree's key.
    pub(super) identity: Vec<Option<[u8; 32]>>,
}

/// Step 5: the meshes. Mesh instances are resolved through their chains (a MeshInstance may
/// name another MeshInstance as its base, as grass_desert and marching_dragons do) before any
/// geometry is built, because a flat mesh needs vertex normals when a smooth instance shows it;
/// PLY files are then read and parsed once each even when several meshes name them, in
/// parallel (with a [`MeshCache`], not at all when every mesh of the file is cached); then
/// degenerate triangles are dropped, normals computed and BVHs built, in parallel (and obvhs
/// parallelises each build), and offered to the cache.
pub(super) fn build_meshes(
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
        if geom.unplaced() > 0 {
            ctx.warn(warnings, &m.faces_loc, unplaced_message(geom.unplaced(), geom.triangle_count(), false));
        }
        geoms.push(geom);
    }
    Ok(Meshes { geoms, world, instances, cached, identity })
}

/// The identity of a PLY mesh built from the file of SHA-256 `content`, smooth or not.
pub(super) fn mesh_identity(content: &[u8; 32], smooth: bool) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"ply mesh");
    h.update(content);
    h.update([u8::from(smooth)]);
    h.finalize().into()
}

/// The key of the world-space tree of `instances` over `geoms`: a hash of everything
/// `geometry::merge_static_meshes` reads (see `Accel::with_world_tree`). A mesh is named by its
/// `identity` when it has one, else by its positions and triangles, bit for bit.
pub(super) fn world_tree_key(
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
