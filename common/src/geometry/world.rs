//! The world-space tree of a scene's static mesh instances (see `Accel::merged` and
//! `Accel::lone`): which instances go into it, their triangles carried to world space into one
//! merged `bvh8` tree (or a lone mesh's own tree in its place), and each flat triangle's plane
//! in world space for the hits that take it.

use std::sync::Arc;

use glam::DVec3;
use obvhs::aabb::Aabb;

use super::bvh8::Bvh8;
use super::instance::{Instance, ObjectTextures, Shape};
use super::mesh::{self, MeshGeom};
use super::rays::refined_t;

/// A triangle's plane in world space, in `f64`: a vertex and the unit geometric normal (what
/// the triangle's own face normal becomes through its instance's normal transform).
#[derive(Clone, Copy, Debug)]
pub(super) struct WorldPlane {
    pub(super) p0: DVec3,
    pub(super) n: DVec3,
}

impl WorldPlane {
    /// The exact distance along the ray (`origin`, `dir`) to this plane, `n·(p0−o)/n·d`; the
    /// traversal's `f32` distance `t32` where the ray runs along the plane.
    #[inline(always)]
    pub(super) fn distance(&self, origin: DVec3, dir: DVec3, t32: f64) -> f64 {
        refined_t(self.n.dot(self.p0 - origin) / self.n.dot(dir), t32)
    }
}

/// Most world-tree triangles (merged, or of the lone mesh) that get a [`WorldPlane`] (48 bytes
/// each, so 96 MB at most): beyond it, hits take the general path.
const PLANES_MAX: usize = 1 << 21;

/// See `Accel::lone`.
#[derive(Clone, Copy, Debug)]
pub(super) struct LoneMesh {
    pub(super) instance: u32,
    pub(super) mesh: u32,
}

/// Most triangles [`merge_static_meshes`] copies into the merged tree: instancing a large mesh
/// many times must not multiply the scene's memory; instances beyond it keep the two levels.
const MERGED_TRIANGLES_MAX: usize = 1 << 22;

/// The world-space tree of a scene's static mesh instances: see `Accel::merged` and
/// `Accel::lone`. Cheap to clone (its parts are shared), so that scenes whose static mesh
/// instances are the same (an animation whose camera moves) can share one
/// ([`Accel::with_world_tree`](super::Accel::with_world_tree)).
#[derive(Clone, Default)]
pub struct WorldTree {
    pub(super) merged: Arc<Bvh8>,
    pub(super) prims: Arc<Vec<(u32, u32)>>,
    /// Which instances it holds (empty: none).
    pub(super) members: Arc<Vec<bool>>,
    pub(super) lone: Option<LoneMesh>,
    pub(super) planes: Arc<Vec<WorldPlane>>,
    /// (instance, count) of each member whose transform carries some of its mesh's triangles
    /// beyond [`mesh::MAX_COORDINATE`]: those triangles are left out of `merged`.
    pub(super) unplaced: Arc<Vec<(u32, u32)>>,
}

impl WorldTree {
    /// An estimate of the bytes it holds, for memory-bounded caches.
    pub fn heap_bytes(&self) -> usize {
        self.merged.heap_bytes()
            + self.prims.capacity() * std::mem::size_of::<(u32, u32)>()
            + self.members.capacity()
            + self.planes.capacity() * std::mem::size_of::<WorldPlane>()
            + self.unplaced.capacity() * std::mem::size_of::<(u32, u32)>()
    }
}

/// The merged BVH of the static mesh instances (see `Accel::merged`): their triangles carried
/// to world space, its triangle table, and which instances it holds. Empty when no instance
/// qualifies, or one untransformed one (a single mesh is already a single tree: it is returned
/// as the [`LoneMesh`] instead).
pub(super) fn merge_static_meshes(meshes: &[Arc<MeshGeom>], instances: &[Instance]) -> WorldTree {
    let mut set = vec![false; instances.len()];
    let mut total = 0usize;
    for (i, inst) in instances.iter().enumerate() {
        if let Shape::Mesh { mesh, .. } = inst.shape {
            let m = &meshes[mesh as usize];
            if inst.motion.is_none()
                && !m.is_empty()
                && mesh::is_sane(&m.bounds)
                && total + m.triangle_count() <= MERGED_TRIANGLES_MAX
            {
                set[i] = true;
                total += m.triangle_count();
            }
        }
    }
    // One untransformed mesh is already a single world-space tree; one transformed mesh is
    // worth carrying to world space (no ray transform per query).
    let count = set.iter().filter(|&&q| q).count();
    let one_transformed = count == 1 && set.iter().zip(instances).any(|(&q, i)| q && i.transform.is_some());
    if count < 2 && !one_transformed {
        let lone = set.iter().position(|&q| q).and_then(|i| match instances[i].shape {
            Shape::Mesh { mesh, .. } => Some(LoneMesh { instance: i as u32, mesh }),
            _ => None,
        });
        // A flat, untextured lone mesh gets its planes too (indexed by triangle, which is what
        // its own tree reports): the only hits that would read them.
        let planes = match lone {
            Some(LoneMesh { instance, mesh }) => {
                let (inst, m) = (&instances[instance as usize], &meshes[mesh as usize]);
                let flat = matches!(inst.shape, Shape::Mesh { smooth: false, .. });
                if flat && inst.textures == ObjectTextures::default() && m.triangle_count() <= PLANES_MAX {
                    (0..m.triangle_count() as u32)
                        .map(|k| WorldPlane {
                            p0: m.positions[m.indices[k as usize][0] as usize],
                            n: m.face_normal(k),
                        })
                        .collect()
                } else {
                    Vec::new()
                }
            }
            None => Vec::new(),
        };
        return WorldTree { members: Arc::new(set), lone, planes: Arc::new(planes), ..WorldTree::default() };
    }
    let (mut tris, mut aabbs, mut prims) =
        (Vec::with_capacity(total), Vec::with_capacity(total), Vec::with_capacity(total));
    let with_planes = total <= PLANES_MAX;
    let mut planes = Vec::with_capacity(if with_planes { total } else { 0 });
    let mut unplaced = Vec::new();
    for (i, inst) in instances.iter().enumerate() {
        let Shape::Mesh { mesh, .. } = inst.shape else { continue };
        if !set[i] {
            continue;
        }
        let m = &meshes[mesh as usize];
        let to_world = inst.transform.as_ref().map(|xf| &xf.to_world);
        let before = tris.len();
        for (k, t) in m.bvh_triangles(to_world) {
            aabbs.push(Aabb::from_points(&[t[0], t[0] + t[1], t[0] + t[2]]));
            tris.push(t);
            prims.push((i as u32, k));
            if with_planes {
                let p0 = m.positions[m.indices[k as usize][0] as usize];
                let n = m.face_normal(k);
                planes.push(match &inst.transform {
                    Some(xf) => WorldPlane { p0: xf.to_world.transform_point3(p0), n: xf.normal_to_world(n) },
                    None => WorldPlane { p0, n },
                });
            }
        }
        let left_out = m.triangle_count() - m.unplaced() - (tris.len() - before);
        if left_out > 0 {
            unplaced.push((i as u32, left_out as u32));
        }
    }
    let ids: Vec<u32> = (0..tris.len() as u32).collect();
    WorldTree {
        merged: Arc::new(Bvh8::build(&tris, &aabbs, &ids)),
        prims: Arc::new(prims),
        members: Arc::new(set),
        lone: None,
        planes: Arc::new(planes),
        unplaced: Arc::new(unplaced),
    }
}
