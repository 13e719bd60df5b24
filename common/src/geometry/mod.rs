//! Geometry and acceleration: meshes with their own BVHs, analytic spheres, instances with
//! transforms, and a top-level BVH over all instances.
//!
//! obvhs has no instancing, so the two levels are ours: the top-level CWBVH is built over the
//! world-space bounds of [`Instance`]s; its leaf test transforms the ray into the instance's
//! object space (direction not renormalised, so `t` carries over) and traverses the mesh's BVH.
//! A plain (untransformed) mesh is simply an instance with no transform. Static mesh instances
//! (no motion; up to `MERGED_TRIANGLES_MAX` triangles in all) are also carried to world space
//! into one merged 8-wide tree, walked before the top level, so a scene of many meshes costs one
//! traversal instead of one per overlapping instance; a lone untransformed static mesh's own tree
//! plays that part. That world-space tree can be walked by up to eight coherent rays at once
//! ([`Accel::intersect_packet`], used for a pixel's camera rays), with the same answers as one
//! ray at a time.

pub mod bvh8;
mod horizon;
mod instance;
pub mod mesh;
mod rays;
mod shapes;
mod world;

use std::sync::Arc;
use std::time::Duration;

use glam::{DVec2, DVec3};
use obvhs::{BvhBuildParams, aabb::Aabb, cwbvh::CwBvh, cwbvh::builder::build_cwbvh, ray::RayHit};

use crate::math::{Ray, Transform, pick, word};
use bvh8::{BoxRays8, Bvh8, Lanes8, Packet8, Ray8};
pub use horizon::Horizons;
pub use instance::{Instance, ObjectTextures, Shape};
pub use mesh::MeshGeom;
pub use rays::{Axes, HitLanes, RayLanes};
use rays::{enters, pad, refined_t, side_of, to_f32_ray};
use shapes::{plane_t, plane_uv_frame, sphere_lanes, sphere_may_block, sphere_t, sphere_uv_frame};
pub use world::WorldTree;
use world::{LoneMesh, WorldPlane, merge_static_meshes};

/// A surface point found by a ray, everything in world space.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    pub t: f64,
    pub point: DVec3,
    /// Unit geometric normal as the geometry defines it (CCW winding, sphere outward); not
    /// flipped towards the ray, so dielectrics can tell entering from leaving.
    pub geo_normal: DVec3,
    /// Unit shading normal (interpolated for smooth meshes), on the same side as `geo_normal`.
    pub shading_normal: DVec3,
    pub material: u32,
    pub instance: u32,
    /// Texture coordinates (barycentrics when the mesh has none). This and the three fields
    /// below are only computed for objects with texture maps; they are zero otherwise.
    pub uv: DVec2,
    /// World-space surface derivatives ∂p/∂u and ∂p/∂v (zero when the surface has no uvs).
    pub dpdu: DVec3,
    pub dpdv: DVec3,
    /// The direction and length a bump map's height displaces the surface by (§11.7), on the
    /// side of `shading_normal`. Meshes: the object-space unit shading normal carried to world
    /// space as a vector (not as a normal), so their bumps scale with the object like ∂p/∂u and
    /// ∂p/∂v do. Spheres: the unit world shading normal, whatever the transformation — the
    /// course references do it this way (see `perturbed_normal` for the figures).
    pub bump_axis: DVec3,
    /// The hit triangle's id in the world tree when that tree found it, `u32::MAX` otherwise:
    /// what [`Accel::horizon_clear`] asks about.
    pub world: u32,
}

impl Default for SurfaceHit {
    fn default() -> Self {
        SurfaceHit {
            t: 0.0,
            point: DVec3::ZERO,
            geo_normal: DVec3::ZERO,
            shading_normal: DVec3::ZERO,
            material: 0,
            instance: 0,
            uv: DVec2::ZERO,
            dpdu: DVec3::ZERO,
            dpdv: DVec3::ZERO,
            bump_axis: DVec3::ZERO,
            world: u32::MAX,
        }
    }
}

/// The whole scene's geometry, ready for ray queries.
pub struct Accel {
    pub meshes: Vec<Arc<MeshGeom>>,
    pub instances: Vec<Instance>,
    tlas: CwBvh,
    /// TLAS primitive order -> instance index.
    tlas_order: Vec<u32>,
    /// World bounds of each bounded instance (over the whole exposure), parallel to `bounded`,
    /// for scenes small enough to test every instance directly.
    bounds: Vec<Aabb>,
    /// The instances with bounds (everything but planes): TLAS primitive `k` is `bounded[k]`.
    bounded: Vec<u32>,
    /// Unbounded instances (planes), tested linearly before the bounded ones.
    unbounded: Vec<u32>,
    /// One BVH over the triangles of every static mesh instance (no motion), carried to world
    /// space, when there are two or more (or one with a transform): a ray walks one tree instead
    /// of the top level and then each mesh's tree in turn, with no per-instance ray transform.
    /// Its hits report an index into `merged_prims`. Those instances are in neither `bounded`
    /// nor `unbounded`. Their meshes keep their own trees (other instances may share them), so
    /// the merged triangles are a second copy: at most `MERGED_TRIANGLES_MAX` of them.
    merged: Arc<Bvh8>,
    /// (instance, triangle of its mesh) of each triangle of `merged`.
    merged_prims: Arc<Vec<(u32, u32)>>,
    /// Which instances `merged` (or `lone`) holds.
    merged_set: Arc<Vec<bool>>,
    /// The one static untransformed mesh instance, when it is the only static mesh (a single
    /// PLY model, say): its own tree already is in world space, so it takes the merged tree's
    /// place (packets of camera rays walk it together). Such an instance is in neither `bounded`
    /// nor `unbounded`; `merged` is then empty.
    lone: Option<LoneMesh>,
    /// The world-space plane of each triangle of `merged` (same index), when there are at most
    /// [`PLANES_MAX`] of them (else empty); or of each triangle of the lone mesh, when it is
    /// flat and untextured and no larger: a hit on a flat, untextured triangle of the world
    /// tree takes its distance, point and normal from it, with no ray transform,
    /// re-intersection or normalisation.
    planes: Arc<Vec<WorldPlane>>,
    /// See [`Accel::unplaced_world_triangles`].
    unplaced: Arc<Vec<(u32, u32)>>,
    /// Whether some instance is a world-space, untextured smooth mesh, the only kind
    /// [`Self::smooth_mesh_hits`] completes: without one, it returns at once.
    smooth_world_meshes: bool,
}

/// Up to this many instances a linear loop over their boxes beats traversing the top level.
const LINEAR_MAX: usize = 8;

/// The closest candidate found during traversal.
#[derive(Clone, Copy)]
struct Candidate {
    t: f64,
    instance: u32,
    tri: u32,
    /// Its id in the world tree when that tree found it (`u32::MAX` otherwise): for the merged
    /// tree (or the lone mesh's), where [`Accel::planes`] may keep its world-space plane.
    merged: u32,
}

impl Candidate {
    /// Nothing found yet closer than `t`.
    const fn none(t: f64) -> Self {
        Candidate { t, instance: u32::MAX, tri: 0, merged: u32::MAX }
    }
}

/// Queries of eight rays given side by side, answered side by side: what the path tracer's
/// lanes ask (`integrator::paths`). They serve scenes of flat, untextured meshes in the world
/// tree and spheres in world space, whose hits need no per-instance record. Each lane's answer
/// is bit for bit what [`Accel::intersect`] or [`Accel::occluded`] says of its ray alone.
impl Accel {
    /// Whether [`Self::closest_lanes`] and [`Self::occluded_lanes`] answer for this scene:
    /// every instance is a flat untextured mesh in the world tree with its world planes kept,
    /// or one of a short list of unmoving, untransformed spheres; nothing else (no planes).
    pub fn lanes_fit(&self) -> bool {
        if !self.unbounded.is_empty() || self.bounded.len() > LINEAR_MAX {
            return false;
        }
        if !self.bounded.iter().all(|&idx| self.world_sphere(idx).is_some()) {
            return false;
        }
        let prims = match self.lone {
            Some(lone) => self.meshes[lone.mesh as usize].triangle_count(),
            None => self.merged_prims.len(),
        };
        if self.planes.len() != prims {
            return false;
        }
        self.instances.iter().enumerate().all(|(i, inst)| {
            self.bounded.contains(&(i as u32))
                || (matches!(inst.shape, Shape::Mesh { smooth: false, .. })
                    && inst.textures == ObjectTextures::default()
                    && inst.motion.is_none())
        })
    }

    /// The closest hits with `t` in (tmin, ∞) of the rays of `mask` (origins `o`, unit
    /// directions `d`; other lanes must hold finite rays, whose answers are not read). The
    /// scene must [`Self::lanes_fit`]. Written into `out` (every field), not returned: a
    /// returned record is copied once more.
    pub fn closest_lanes(&self, o: &Axes, d: &Axes, mask: u32, tmin: f64, out: &mut HitLanes) {
        let mut t = [f64::INFINITY; 8];
        let mut instance = [u32::MAX; 8];
        let mut merged = [u32::MAX; 8];
        if let Some(tree) = self.world_tree() {
            let mut packet = Packet8::from_lanes(&Lanes8::new(o, d, 8), tmin as f32);
            packet.set_active(mask);
            let (mut tmax, mut id) = ([f32::INFINITY; 8], [u32::MAX; 8]);
            let hit = tree.intersect_packet(&packet, &mut tmax, &mut id);
            for k in crate::math::lanes(hit) {
                t[k] = tmax[k] as f64;
                instance[k] = self.world_prim(id[k]).0;
                merged[k] = id[k];
            }
        }
        for &idx in &self.bounded {
            let Some((center, radius)) = self.world_sphere(idx) else { continue };
            let ts = sphere_lanes(center, radius, None, o, d, tmin, &t);
            // Selects, not a branch a lane: which lanes the sphere is nearest for is random.
            for k in 0..8 {
                let nearer = ts[k] < f64::INFINITY;
                t[k] = pick(word(nearer), ts[k], t[k]);
                instance[k] = if nearer { idx } else { instance[k] };
                merged[k] = if nearer { u32::MAX } else { merged[k] };
            }
        }
        // Field by field: a whole record built and assigned is a copy.
        out.mask = 0;
        out.point = [[0.0; 8]; 3];
        out.normal = [[0.0; 8]; 3];
        out.t = [0.0; 8];
        out.material = [0; 8];
        out.instance = instance;
        for k in crate::math::lanes(mask) {
            if instance[k] == u32::MAX {
                continue;
            }
            out.mask |= 1 << k;
            let inst = &self.instances[instance[k] as usize];
            out.material[k] = inst.material;
            let (ok, dk) = (DVec3::new(o[0][k], o[1][k], o[2][k]), DVec3::new(d[0][k], d[1][k], d[2][k]));
            // As `surface`: a sphere's distance as found, a face's from its world plane.
            let plane = match inst.shape {
                Shape::Sphere { center, radius } => Err((center, radius)),
                _ => Ok(&self.planes[merged[k] as usize]),
            };
            let tk = plane.map_or(t[k], |plane| plane.distance(ok, dk, t[k]));
            let p = ok + dk * tk;
            out.t[k] = tk;
            let n = match plane {
                Ok(plane) => plane.n,
                Err((center, radius)) => (p - center) / radius,
            };
            for a in 0..3 {
                out.point[a][k] = p[a];
                out.normal[a][k] = n[a];
            }
        }
    }

    /// The lanes of `mask` whose rays (origins `o`, unit directions `d`) are blocked within
    /// (tmin, `far[lane]`). The scene must [`Self::lanes_fit`]; other lanes must hold finite
    /// rays.
    pub fn occluded_lanes(&self, o: &Axes, d: &Axes, far: &[f64; 8], mask: u32, tmin: f64) -> u32 {
        let mut blocked = 0;
        if let Some(tree) = self.world_tree() {
            let mut packet = Packet8::from_lanes(&Lanes8::new(o, d, 8), tmin as f32);
            packet.set_active(mask);
            let far32: [f32; 8] =
                std::array::from_fn(|k| if mask & (1 << k) != 0 { far[k] as f32 } else { f32::NEG_INFINITY });
            blocked = tree.occluded_packet(&packet, &far32) & mask;
        }
        for &idx in &self.bounded {
            if blocked == mask {
                break;
            }
            let Some((center, radius)) = self.world_sphere(idx) else { continue };
            if sphere_may_block(center, radius, o, d, tmin, far) & mask & !blocked == 0 {
                continue;
            }
            let ts = sphere_lanes(center, radius, None, o, d, tmin, far);
            blocked = (blocked | crate::math::lane_bits(ts.map(|t| t < f64::INFINITY))) & mask;
        }
        blocked
    }
}

/// The lane queries' contract: one to eight rays, as many lanes in `wide` (holding the same
/// rays, checked in debug builds) and `out` results.
#[inline(always)]
fn check_lanes(rays: &[Ray], wide: &RayLanes, out: usize) {
    assert!(
        (1..=8).contains(&rays.len()) && out == rays.len() && wide.len == rays.len(),
        "one to eight rays, as many lanes and results"
    );
    debug_assert!(rays.iter().enumerate().all(|(k, r)| wide.holds(k, r)), "the lanes hold the rays");
}

/// World bounds of a bounded instance; `None` for planes.
fn instance_bounds(inst: &Instance, meshes: &[Arc<MeshGeom>]) -> Option<Aabb> {
    let local = match &inst.shape {
        Shape::Mesh { mesh, .. } => meshes[*mesh as usize].bounds,
        Shape::Sphere { center, radius } => {
            let r = DVec3::splat(*radius);
            Aabb::new((*center - r).as_vec3a(), (*center + r).as_vec3a())
        }
        Shape::Plane { .. } => return None,
    };
    let world = match &inst.transform {
        None => local,
        Some(xf) => {
            let mut out = Aabb::empty();
            for i in 0..8 {
                let c = DVec3::new(
                    if i & 1 == 0 { local.min.x } else { local.max.x } as f64,
                    if i & 2 == 0 { local.min.y } else { local.max.y } as f64,
                    if i & 4 == 0 { local.min.z } else { local.max.z } as f64,
                );
                out.extend(xf.to_world.transform_point3(c).as_vec3a());
            }
            out
        }
    };
    // A moving object's box covers the whole exposure: its boxes at time 0 and 1.
    Some(match inst.motion {
        Some(v) => {
            let v = v.as_vec3a();
            pad(world.union(&Aabb::new(world.min + v, world.max + v)))
        }
        None => pad(world),
    })
}

impl Accel {
    pub fn new(meshes: Vec<Arc<MeshGeom>>, instances: Vec<Instance>) -> Self {
        Self::with_world_tree(meshes, instances, None)
    }

    /// [`Accel::new`] with the world-space tree of its static mesh instances given (`Some`)
    /// instead of built: the [`Accel::shared_world_tree`] of an earlier `Accel` whose meshes
    /// and instances were the same in all the tree reads — each mesh instance's mesh index,
    /// that mesh's positions and triangles, its transform, motion, smooth flag and whether it
    /// has texture maps, and every instance's position in `instances`. The caller's key must
    /// guarantee it (`scene::build` hashes exactly those).
    pub fn with_world_tree(
        meshes: Vec<Arc<MeshGeom>>,
        instances: Vec<Instance>,
        world: Option<WorldTree>,
    ) -> Self {
        let (mut bounds, mut bounded, mut unbounded) = (Vec::new(), Vec::new(), Vec::new());
        let WorldTree { merged, prims: merged_prims, members: merged_set, lone, planes, unplaced } =
            world.unwrap_or_else(|| merge_static_meshes(&meshes, &instances));
        for (i, inst) in instances.iter().enumerate() {
            if merged_set.get(i).copied().unwrap_or(false) {
                continue;
            }
            match instance_bounds(inst, &meshes) {
                // A mesh with no triangle in its BVH can never be hit.
                _ if matches!(inst.shape, Shape::Mesh { mesh, .. } if meshes[mesh as usize].is_empty()) => {}
                // Bounds the builder cannot take (beyond f32, or astronomically large): tested
                // on every ray instead, in f64.
                Some(b) if !mesh::is_sane(&b) => unbounded.push(i as u32),
                Some(b) => {
                    bounds.push(b);
                    bounded.push(i as u32);
                }
                None => unbounded.push(i as u32),
            }
        }
        let tlas = if bounds.is_empty() {
            CwBvh::default()
        } else {
            build_cwbvh(&bounds, BvhBuildParams::medium_build(), &mut Duration::default())
        };
        let tlas_order = tlas.primitive_indices.iter().map(|&k| bounded[k as usize]).collect();
        let smooth_world_meshes = instances.iter().any(|i| {
            matches!(i.shape, Shape::Mesh { smooth: true, .. })
                && i.is_world_space()
                && i.textures == ObjectTextures::default()
        });
        Accel {
            meshes,
            instances,
            tlas,
            tlas_order,
            bounds,
            bounded,
            unbounded,
            merged,
            merged_prims,
            merged_set,
            lone,
            planes,
            unplaced,
            smooth_world_meshes,
        }
    }

    /// Its world-space tree of the static mesh instances, to give to
    /// [`Accel::with_world_tree`] for a scene whose static mesh instances are the same.
    pub fn shared_world_tree(&self) -> WorldTree {
        WorldTree {
            merged: self.merged.clone(),
            prims: self.merged_prims.clone(),
            members: self.merged_set.clone(),
            lone: self.lone,
            planes: self.planes.clone(),
            unplaced: self.unplaced.clone(),
        }
    }

    /// (instance, count) of each instance in the world-space tree whose transform carries some
    /// triangles beyond [`mesh::MAX_COORDINATE`]: those are left out and can never be hit (the
    /// scene build warns about them). Triangles beyond it in the mesh's own coordinates are
    /// [`MeshGeom::unplaced`] and not counted here.
    pub fn unplaced_world_triangles(&self) -> &[(u32, u32)] {
        &self.unplaced
    }

    /// The length of the diagonal of the box around every bounded object (planes left out), in
    /// world space over the whole exposure; `None` when nothing has bounds.
    pub fn extent(&self) -> Option<f64> {
        let boxes = self.instances.iter().filter_map(|i| instance_bounds(i, &self.meshes));
        let all = boxes.reduce(|a, b| a.union(&b))?;
        Some((all.max - all.min).as_dvec3().length())
    }

    /// Total triangles over all instances (instanced triangles counted once per instance).
    pub fn instanced_triangle_count(&self) -> usize {
        self.instances
            .iter()
            .map(|i| match i.shape {
                Shape::Mesh { mesh, .. } => self.meshes[mesh as usize].triangle_count(),
                Shape::Sphere { .. } | Shape::Plane { .. } => 0,
            })
            .sum()
    }

    /// Whether instance `idx` is made of triangles (a mesh), not an analytic shape.
    #[inline]
    pub fn is_triangle(&self, idx: u32) -> bool {
        matches!(self.instances[idx as usize].shape, Shape::Mesh { .. })
    }

    /// The world-space tree of the static meshes (the merged one or the lone mesh's own), if
    /// any; [`Self::world_prim`] maps its hit ids to (instance, triangle).
    #[inline]
    fn world_tree(&self) -> Option<&Bvh8> {
        match self.lone {
            Some(lone) => Some(self.meshes[lone.mesh as usize].tree()),
            None => (!self.merged.is_empty()).then_some(&*self.merged),
        }
    }

    /// Horizons for the shadow rays of this scene's world-tree triangles ([`Horizons`]), whose
    /// origins stand `epsilon` off their surface; `None` unless the world tree holds the whole
    /// scene (every blocker must be in it) and is small enough.
    pub fn horizons(&self, epsilon: f64) -> Option<Horizons> {
        if !(self.bounded.is_empty() && self.unbounded.is_empty()) {
            return None;
        }
        Horizons::new(self.world_tree()?, epsilon)
    }

    /// Whether a shadow ray in unit direction `d` from a point of world-tree triangle `world`
    /// (a [`SurfaceHit::world`]), leaving it at the shadow-ray epsilon along the unit lit
    /// normal `n`, certainly reaches infinity unblocked: [`Self::occluded`] would say false.
    /// False when the horizon cannot tell; `horizons` must be this scene's.
    #[inline(always)]
    pub fn horizon_clear(&self, horizons: &Horizons, world: u32, n: DVec3, d: DVec3) -> bool {
        match self.world_tree() {
            Some(tree) => horizons.clear(tree, world, n, d),
            None => false,
        }
    }

    /// The (instance, triangle) of hit id `id` of [`Self::world_tree`].
    #[inline]
    fn world_prim(&self, id: u32) -> (u32, u32) {
        match self.lone {
            Some(lone) => (lone.instance, id),
            None => self.merged_prims[id as usize],
        }
    }

    /// Closest surface hit with `t` in (tmin, tmax).
    pub fn intersect(&self, ray: &Ray, tmin: f64, tmax: f64) -> Option<SurfaceHit> {
        let mut best = Candidate::none(tmax);
        let mut near = tmax as f32;
        if let Some(tree) = self.world_tree()
            && let Some((t, id)) =
                tree.intersect(&Ray8::new(ray.origin.as_vec3a(), ray.dir.as_vec3a(), tmin as f32, near))
        {
            let (instance, tri) = self.world_prim(id);
            best = Candidate { t: t as f64, instance, tri, merged: id };
            near = t;
        }
        // obvhs's ray (its own inverse direction) only where an instance outside the world
        // tree is to be tested: a scene of static meshes alone never needs it.
        if self.unbounded.is_empty() && self.bounded.is_empty() {
            return self.found(ray, best);
        }
        if self.bounded.len() <= LINEAR_MAX {
            return self.intersect_short_list(ray, tmin, tmax, best, near);
        }
        let mut fr = to_f32_ray(ray, tmin, tmax);
        fr.tmax = near;
        self.intersect_rest(ray, tmin, best, fr)
    }

    /// [`Self::intersect`] beyond the world tree when the bounded instances are a short list:
    /// the unbounded ones (planes), then each bounded one in turn, from the world tree's
    /// candidate `best` (`near` its distance in `f32`). A sphere in world space is tested exactly
    /// at once: its test costs about what its box test does, and needs no `f32` ray with its
    /// inverse direction, which is made only for an instance that needs it. (A box is padded, so
    /// it never turns away a hit of its sphere: the same hits as behind the boxes.)
    #[inline]
    fn intersect_short_list(
        &self,
        ray: &Ray,
        tmin: f64,
        tmax: f64,
        mut best: Candidate,
        mut near: f32,
    ) -> Option<SurfaceHit> {
        let mut fr: Option<obvhs::ray::Ray> = None;
        if !self.unbounded.is_empty() {
            let f = fr.insert(to_f32_ray(ray, tmin, tmax));
            f.tmax = near;
            self.unbounded_hits(ray, f, tmin, &mut best);
            near = f.tmax;
        }
        for (&idx, b) in self.bounded.iter().zip(&self.bounds) {
            if let Some((center, radius)) = self.world_sphere(idx) {
                if let Some(t) = sphere_t(center, radius, ray, tmin, best.t) {
                    best = Candidate { t, instance: idx, tri: 0, merged: u32::MAX };
                    near = near.min(t as f32);
                }
                continue;
            }
            let fr = fr.get_or_insert_with(|| to_f32_ray(ray, tmin, tmax));
            fr.tmax = near;
            if enters(b, fr) {
                near = near.min(self.hit_instance(idx, ray, fr, tmin, &mut best));
            }
        }
        self.found(ray, best)
    }

    /// Instance `idx`'s centre and radius when it is a sphere whose object space is world space
    /// (a [`Self::lane_sphere`] without a transform).
    #[inline]
    fn world_sphere(&self, idx: u32) -> Option<(DVec3, f64)> {
        match self.lane_sphere(idx) {
            Some((center, radius, None)) => Some((center, radius)),
            _ => None,
        }
    }

    /// The closest hits of up to eight rays with `t` in (tmin, ∞), each what
    /// [`Self::intersect`] finds: the world tree is walked by all of them
    /// together as a [`Packet8`], and each instance of a short list is box-tested against all of
    /// them at once ([`BoxRays8`]); every ray meets the instances in the order it would alone.
    /// Every slot of `out` is written (`None` for a ray that hits nothing), whatever it held.
    pub fn intersect_packet(&self, rays: &[Ray], tmin: f64, out: &mut [Option<SurfaceHit>]) {
        assert!(rays.len() <= 8 && out.len() == rays.len(), "one result per ray, at most eight rays");
        if rays.is_empty() {
            return;
        }
        self.intersect_lanes(rays, &RayLanes::new(rays), tmin, out);
    }

    /// [`Self::intersect_packet`] of `rays` given side by side as well (`wide` holds the same
    /// rays, as [`RayLanes::new`] would make them: checked in debug builds), so that a caller
    /// that made them that way saves the gathering.
    #[inline(always)]
    pub fn intersect_lanes(&self, rays: &[Ray], wide: &RayLanes, tmin: f64, out: &mut [Option<SurfaceHit>]) {
        check_lanes(rays, wide, out.len());
        let mut best = [Candidate::none(f64::INFINITY); 8];
        let mut lanes = Lanes8::new(&wide.o, &wide.d, wide.len);
        // Each lane's closest hit so far in f32; a lane's obvhs ray is made only where an
        // instance's own test needs one.
        let mut near = [f32::INFINITY; 8];
        if let Some(tree) = self.world_tree() {
            let packet = Packet8::from_lanes(&lanes, tmin as f32);
            let (mut tmax, mut id) = ([f32::INFINITY; 8], [u32::MAX; 8]);
            let hit = tree.intersect_packet(&packet, &mut tmax, &mut id);
            self.world_candidates(hit, &tmax, &id, &mut best, &mut near);
        }
        self.lanes_beyond_world(rays, wide, &mut lanes, tmin, &mut best, &mut near, out);
    }

    /// [`Self::intersect_lanes`] of two groups of rays at once, each group's results what that
    /// call finds: the world tree is walked by both groups together
    /// ([`Bvh8::intersect_packet_pair`], one walk of sixteen lanes on hosts with AVX-512).
    #[inline(always)]
    pub fn intersect_lanes_pair(
        &self,
        rays: [&[Ray]; 2],
        wide: [&RayLanes; 2],
        tmin: f64,
        out: [&mut [Option<SurfaceHit>]; 2],
    ) {
        let Some(tree) = self.world_tree() else {
            let [out0, out1] = out;
            self.intersect_lanes(rays[0], wide[0], tmin, out0);
            self.intersect_lanes(rays[1], wide[1], tmin, out1);
            return;
        };
        for g in 0..2 {
            check_lanes(rays[g], wide[g], out[g].len());
        }
        let mut lanes = wide.map(|w| Lanes8::new(&w.o, &w.d, w.len));
        let packets =
            [Packet8::from_lanes(&lanes[0], tmin as f32), Packet8::from_lanes(&lanes[1], tmin as f32)];
        let (mut tmax, mut id) = ([[f32::INFINITY; 8]; 2], [[u32::MAX; 8]; 2]);
        let hit = tree.intersect_packet_pair(&packets[0], &packets[1], &mut tmax, &mut id);
        for (g, (out, lanes)) in out.into_iter().zip(&mut lanes).enumerate() {
            let (mut best, mut near) = ([Candidate::none(f64::INFINITY); 8], [f32::INFINITY; 8]);
            self.world_candidates(hit[g], &tmax[g], &id[g], &mut best, &mut near);
            self.lanes_beyond_world(rays[g], wide[g], lanes, tmin, &mut best, &mut near, out);
        }
    }

    /// The world tree's hits (lanes `hit`, distances `tmax`, ids `id`) as candidates.
    #[inline(always)]
    fn world_candidates(
        &self,
        mut hit: u32,
        tmax: &[f32; 8],
        id: &[u32; 8],
        best: &mut [Candidate; 8],
        near: &mut [f32; 8],
    ) {
        while hit != 0 {
            let lane = hit.trailing_zeros() as usize;
            hit &= hit - 1;
            let (instance, tri) = self.world_prim(id[lane]);
            best[lane] = Candidate { t: tmax[lane] as f64, instance, tri, merged: id[lane] };
            near[lane] = tmax[lane];
        }
    }

    /// The rest of [`Self::intersect_lanes`] once the world tree has been walked: the
    /// instances outside it, from the candidates `best` (their `f32` distances `near`), then the
    /// surfaces found, into `out`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn lanes_beyond_world(
        &self,
        rays: &[Ray],
        wide: &RayLanes,
        lanes: &mut Lanes8,
        tmin: f64,
        best: &mut [Candidate; 8],
        near: &mut [f32; 8],
        out: &mut [Option<SurfaceHit>],
    ) {
        let n = rays.len();
        let tmin32 = tmin as f32;
        if self.bounded.is_empty() && self.unbounded.is_empty() {
            // Everything was in the world tree.
            if !self.smooth_mesh_hits(rays, wide, best, out) {
                for lane in 0..n {
                    self.found_into(&rays[lane], best[lane], &mut out[lane]);
                }
            }
            return;
        }
        lanes.compute_inverse();
        if self.bounded.len() <= LINEAR_MAX {
            if !self.unbounded.is_empty() {
                for lane in 0..n {
                    let mut fr = lanes.ray(lane, tmin32, near[lane]);
                    self.unbounded_hits(&rays[lane], &mut fr, tmin, &mut best[lane]);
                    near[lane] = fr.tmax;
                }
            }
            // The boxes' far bounds are the lanes' closest hits from here on.
            let mut boxes = BoxRays8::from_lanes(lanes, *near);
            for (&idx, b) in self.bounded.iter().zip(&self.bounds) {
                let mut hit = boxes.hits(b);
                if hit & hit.wrapping_sub(1) != 0
                    && let Some((center, radius, xf)) = self.lane_sphere(idx)
                {
                    // Two lanes or more in a sphere's box: its test for all eight at once.
                    let ts = sphere_lanes(center, radius, xf, &wide.o, &wide.d, tmin, &best.map(|c| c.t));
                    while hit != 0 {
                        let lane = hit.trailing_zeros() as usize;
                        hit &= hit - 1;
                        let t = ts[lane];
                        if t < f64::INFINITY {
                            best[lane] = Candidate { t, instance: idx, tri: 0, merged: u32::MAX };
                            boxes.tmax[lane] = boxes.tmax[lane].min(t as f32);
                        }
                    }
                    continue;
                }
                while hit != 0 {
                    let lane = hit.trailing_zeros() as usize;
                    hit &= hit - 1;
                    let fr = lanes.ray(lane, tmin32, boxes.tmax[lane]);
                    let t = self.hit_instance(idx, &rays[lane], &fr, tmin, &mut best[lane]);
                    boxes.tmax[lane] = boxes.tmax[lane].min(t);
                }
            }
            if !self.smooth_mesh_hits(rays, wide, best, out) {
                for lane in 0..n {
                    self.found_into(&rays[lane], best[lane], &mut out[lane]);
                }
            }
        } else {
            for lane in 0..n {
                out[lane] =
                    self.intersect_rest(&rays[lane], tmin, best[lane], lanes.ray(lane, tmin32, near[lane]));
            }
        }
    }

    /// The unbounded instances (planes) for one ray, from the candidate `best` (`fr.tmax` its
    /// distance); both updated.
    #[inline]
    fn unbounded_hits(&self, ray: &Ray, fr: &mut obvhs::ray::Ray, tmin: f64, best: &mut Candidate) {
        for &idx in &self.unbounded {
            let t = self.hit_instance(idx, ray, fr, tmin, best);
            fr.tmax = fr.tmax.min(t);
        }
    }

    /// [`Self::intersect`] beyond the world tree when the bounded instances are too many for
    /// a short list: the unbounded ones (planes), then the top level, starting from the world
    /// tree's candidate `best` (`fr.tmax` its distance).
    #[inline]
    fn intersect_rest(
        &self,
        ray: &Ray,
        tmin: f64,
        mut best: Candidate,
        mut fr: obvhs::ray::Ray,
    ) -> Option<SurfaceHit> {
        self.unbounded_hits(ray, &mut fr, tmin, &mut best);
        let mut hit = RayHit::none();
        self.tlas.ray_traverse(fr, &mut hit, |fr, id| {
            self.hit_instance(self.tlas_order[id], ray, fr, tmin, &mut best)
        });
        self.found(ray, best)
    }

    /// True if anything blocks the ray within (tmin, tmax).
    pub fn occluded(&self, ray: &Ray, tmin: f64, tmax: f64) -> bool {
        if let Some(tree) = self.world_tree()
            && tree.occluded(&Ray8::new(ray.origin.as_vec3a(), ray.dir.as_vec3a(), tmin as f32, tmax as f32))
        {
            return true;
        }
        if self.unbounded.is_empty() && self.bounded.is_empty() {
            return false;
        }
        if self.bounded.len() <= LINEAR_MAX {
            // As in `intersect_short_list`: spheres in world space exactly, with no box test;
            // the `f32` ray made only for an instance that needs it.
            let mut fr: Option<obvhs::ray::Ray> = None;
            if !self.unbounded.is_empty()
                && self.unbounded_block(ray, fr.insert(to_f32_ray(ray, tmin, tmax)), tmin, tmax)
            {
                return true;
            }
            return self.bounded.iter().zip(&self.bounds).any(|(&idx, b)| match self.world_sphere(idx) {
                Some((center, radius)) => sphere_t(center, radius, ray, tmin, tmax).is_some(),
                None => {
                    let fr = fr.get_or_insert_with(|| to_f32_ray(ray, tmin, tmax));
                    enters(b, fr) && self.blocks(idx, ray, fr, tmin, tmax)
                }
            });
        }
        let fr = to_f32_ray(ray, tmin, tmax);
        if self.unbounded_block(ray, &fr, tmin, tmax) {
            return true;
        }
        self.tlas_blocks(ray, fr, tmin, tmax)
    }

    /// Whether an unbounded instance (a plane) blocks the ray within (tmin, tmax).
    #[inline]
    fn unbounded_block(&self, ray: &Ray, fr: &obvhs::ray::Ray, tmin: f64, tmax: f64) -> bool {
        self.unbounded.iter().any(|&idx| self.blocks(idx, ray, fr, tmin, tmax))
    }

    /// Whether a bounded instance found through the top level blocks the ray within (tmin, tmax).
    fn tlas_blocks(&self, ray: &Ray, fr: obvhs::ray::Ray, tmin: f64, tmax: f64) -> bool {
        !self.tlas.ray_traverse_miss(fr, |fr, id| {
            if self.blocks(self.tlas_order[id], ray, fr, tmin, tmax) { fr.tmin } else { f32::INFINITY }
        })
    }

    /// Which of up to eight rays are blocked within (tmin, `tmax[lane]`), as a lane mask: each
    /// lane's answer is what [`Self::occluded`] says of it. The world tree is walked by the rays
    /// together ([`Bvh8::occluded_packet`]) and a short list of instances is box-tested against
    /// all of them at once; shadow rays from the samples of one pixel towards one light are
    /// nearly parallel, and share most of their nodes.
    pub fn occluded_packet(&self, rays: &[Ray], tmin: f64, tmax: &[f64]) -> u32 {
        assert!(rays.len() <= 8 && tmax.len() == rays.len(), "one bound per ray, at most eight rays");
        let n = rays.len();
        if n <= 1 {
            return rays.first().map_or(0, |r| self.occluded(r, tmin, tmax[0]) as u32);
        }
        let all = (1u32 << n) - 1;
        let wide = RayLanes::new(rays);
        let mut lanes = Lanes8::new(&wide.o, &wide.d, wide.len);
        let tmin32 = tmin as f32;
        // Each lane's far bound in f32 (unused lanes can reach nothing); a lane's obvhs ray is
        // made only where an instance's own test needs one.
        let far: [f32; 8] = std::array::from_fn(|i| tmax.get(i).map_or(f32::NEG_INFINITY, |&t| t as f32));
        let mut blocked = 0u32;
        if let Some(tree) = self.world_tree() {
            let packet = Packet8::from_lanes(&lanes, tmin32);
            blocked = tree.occluded_packet(&packet, &far);
        }
        if self.bounded.is_empty() && self.unbounded.is_empty() {
            return blocked;
        }
        lanes.compute_inverse();
        let ray = |lane: usize| lanes.ray(lane, tmin32, far[lane]);
        if !self.unbounded.is_empty() {
            for lane in 0..n {
                if blocked & (1 << lane) == 0
                    && self.unbounded_block(&rays[lane], &ray(lane), tmin, tmax[lane])
                {
                    blocked |= 1 << lane;
                }
            }
        }
        if self.bounded.len() <= LINEAR_MAX {
            let boxes = BoxRays8::from_lanes(&lanes, far);
            for (&idx, b) in self.bounded.iter().zip(&self.bounds) {
                if blocked == all {
                    break;
                }
                let mut lanes = boxes.hits(b) & !blocked;
                if lanes & lanes.wrapping_sub(1) != 0
                    && let Some((center, radius, xf)) = self.lane_sphere(idx)
                {
                    let far64: [f64; 8] =
                        std::array::from_fn(|i| tmax.get(i).map_or(f64::NEG_INFINITY, |&t| t));
                    let ts = sphere_lanes(center, radius, xf, &wide.o, &wide.d, tmin, &far64);
                    for (lane, t) in ts.iter().enumerate() {
                        if lanes & (1 << lane) != 0 && *t < f64::INFINITY {
                            blocked |= 1 << lane;
                        }
                    }
                    continue;
                }
                while lanes != 0 {
                    let lane = lanes.trailing_zeros() as usize;
                    lanes &= lanes - 1;
                    if self.blocks(idx, &rays[lane], &ray(lane), tmin, tmax[lane]) {
                        blocked |= 1 << lane;
                    }
                }
            }
        } else {
            for lane in 0..n {
                if blocked & (1 << lane) == 0 && self.tlas_blocks(&rays[lane], ray(lane), tmin, tmax[lane]) {
                    blocked |= 1 << lane;
                }
            }
        }
        blocked
    }

    /// The sphere of instance `idx` (centre, radius and transform) when it is one that does not
    /// move: what [`sphere_lanes`] tests.
    #[inline]
    fn lane_sphere(&self, idx: u32) -> Option<(DVec3, f64, Option<&Transform>)> {
        let inst = &self.instances[idx as usize];
        match inst.shape {
            Shape::Sphere { center, radius } if inst.motion.is_none() => {
                Some((center, radius, inst.transform.as_ref()))
            }
            _ => None,
        }
    }

    /// Tests instance `idx` for a hit closer than `best` (`fr` is the world ray in `f32`, its
    /// `tmax` the closest hit so far); updates `best` and returns the hit distance or +inf.
    #[inline]
    fn hit_instance(
        &self,
        idx: u32,
        ray: &Ray,
        fr: &obvhs::ray::Ray,
        tmin: f64,
        best: &mut Candidate,
    ) -> f32 {
        let inst = &self.instances[idx as usize];
        let mut moved = None;
        let local = inst.ray_here(ray, &mut moved);
        match &inst.shape {
            Shape::Sphere { center, radius } => match sphere_t(*center, *radius, local, tmin, best.t) {
                Some(t) => {
                    *best = Candidate { t, instance: idx, tri: 0, merged: u32::MAX };
                    t as f32
                }
                None => f32::INFINITY,
            },
            Shape::Plane { point, normal } => match plane_t(*point, *normal, local, tmin, best.t) {
                Some(t) => {
                    *best = Candidate { t, instance: idx, tri: 0, merged: u32::MAX };
                    t as f32
                }
                None => f32::INFINITY,
            },
            Shape::Mesh { mesh, .. } => {
                let m = &self.meshes[*mesh as usize];
                // A static untransformed mesh sees the world ray itself (no new inverse).
                let lr = if inst.is_world_space() { *fr } else { to_f32_ray(local, tmin, fr.tmax as f64) };
                match m.intersect_f32(lr) {
                    Some((t, tri)) => {
                        *best = Candidate { t: t as f64, instance: idx, tri, merged: u32::MAX };
                        t
                    }
                    None => f32::INFINITY,
                }
            }
        }
    }

    /// Whether instance `idx` blocks the ray within (tmin, tmax).
    #[inline]
    fn blocks(&self, idx: u32, ray: &Ray, fr: &obvhs::ray::Ray, tmin: f64, tmax: f64) -> bool {
        let inst = &self.instances[idx as usize];
        let mut moved = None;
        let local = inst.ray_here(ray, &mut moved);
        match &inst.shape {
            Shape::Sphere { center, radius } => sphere_t(*center, *radius, local, tmin, tmax).is_some(),
            Shape::Plane { point, normal } => plane_t(*point, *normal, local, tmin, tmax).is_some(),
            Shape::Mesh { mesh, .. } => {
                let lr = if inst.is_world_space() { *fr } else { to_f32_ray(local, tmin, fr.tmax as f64) };
                self.meshes[*mesh as usize].occluded_f32(lr)
            }
        }
    }

    /// The hit of the final candidate of a query, if it found anything.
    #[inline]
    fn found(&self, ray: &Ray, best: Candidate) -> Option<SurfaceHit> {
        let mut hit = None;
        self.found_into(ray, best, &mut hit);
        hit
    }

    /// [`Self::found`] written into `out` in place: the record is stored field by field where
    /// it is wanted, never copied whole through a temporary (a copy's wide loads right after the
    /// narrow stores that built it cannot be forwarded, and stall).
    #[inline]
    fn found_into(&self, ray: &Ray, best: Candidate, out: &mut Option<SurfaceHit>) {
        if best.instance == u32::MAX {
            *out = None;
        } else {
            self.surface(ray, best, out.insert(SurfaceHit::default()));
        }
    }

    /// [`Self::found_into`] of every lane at once when two lanes or more hit and all of them
    /// hit one untransformed, unmoving, untextured mesh shaded smooth (a scanned model, or one
    /// of a scene's meshes seen by a whole pixel), with the re-intersections and normals of the
    /// lanes side by side ([`MeshGeom::smooth_hits`]); each lane gets the record
    /// [`Self::surface`] makes. False (nothing written) otherwise.
    fn smooth_mesh_hits(
        &self,
        rays: &[Ray],
        wide: &RayLanes,
        best: &[Candidate; 8],
        out: &mut [Option<SurfaceHit>],
    ) -> bool {
        if !self.smooth_world_meshes {
            return false;
        }
        let hits = (0..rays.len()).filter(|&k| best[k].instance != u32::MAX).fold(0u32, |m, k| m | 1 << k);
        if hits.count_ones() < 2 {
            // None, or one: the single path does as well.
            return false;
        }
        let lead = best[hits.trailing_zeros() as usize];
        let instance = lead.instance;
        if (0..8).any(|k| hits & (1 << k) != 0 && best[k].instance != instance) {
            return false;
        }
        let inst = &self.instances[instance as usize];
        let Shape::Mesh { mesh, smooth: true } = inst.shape else { return false };
        if !inst.is_world_space() || inst.textures != ObjectTextures::default() {
            return false;
        }
        // Lanes without a hit repeat the first hit's triangle (their results are not read).
        let tri: [u32; 8] =
            std::array::from_fn(|k| if hits & (1 << k) != 0 { best[k].tri } else { lead.tri });
        let m = &self.meshes[mesh as usize];
        let Some(h) = m.smooth_hits(&tri, &wide.o, &wide.d) else { return false };
        #[cfg(test)]
        tests::SMOOTH_MESH_PACKETS.with(|c| c.set(c.get() + 1));
        for (k, slot) in out.iter_mut().enumerate() {
            if hits & (1 << k) == 0 {
                *slot = None;
                continue;
            }
            let ray = &rays[k];
            let lane = |v: &[[f64; 8]; 3]| DVec3::new(v[0][k], v[1][k], v[2][k]);
            // As `surface`: the f32 distance where the re-intersection degenerated, the smooth
            // normal on the face's side, the bump axis on the shading normal's.
            let t = refined_t(h.t[k], best[k].t);
            let (geo_normal, n_shade) = (lane(&h.ng), lane(&h.ns));
            let shading_normal = side_of(n_shade, geo_normal);
            let hit = slot.insert(SurfaceHit::default());
            hit.t = t;
            hit.point = ray.at(t);
            hit.geo_normal = geo_normal;
            hit.shading_normal = shading_normal;
            hit.material = inst.material;
            hit.instance = instance;
            hit.bump_axis = side_of(n_shade, shading_normal);
            hit.world = best[k].merged;
        }
        true
    }

    /// Completes a candidate into world-space hit data, re-intersecting triangles in `f64`.
    fn surface(&self, ray: &Ray, c: Candidate, out: &mut SurfaceHit) {
        let inst = &self.instances[c.instance as usize];
        // The texture frame (trigonometry for spheres, uv interpolation for meshes) is only
        // needed by objects that have texture maps: skip it on every other hit.
        let textured = inst.textures != ObjectTextures::default();
        if let Shape::Mesh { smooth: false, .. } = inst.shape
            && !textured
            && let Some(plane) = self.planes.get(c.merged as usize)
        {
            // A flat face with no texture frame: its world plane gives the exact distance
            // (the f32 one kept where the ray runs along the plane) and the normal.
            let n = plane.n;
            let t = plane.distance(ray.origin, ray.dir, c.t);
            *out = SurfaceHit {
                t,
                point: ray.at(t),
                geo_normal: n,
                shading_normal: n,
                material: inst.material,
                instance: c.instance,
                uv: DVec2::ZERO,
                dpdu: DVec3::ZERO,
                dpdv: DVec3::ZERO,
                bump_axis: if inst.transform.is_some() { DVec3::ZERO } else { n },
                world: c.merged,
            };
            return;
        }
        let mut moved = None;
        let local = inst.ray_here(ray, &mut moved);
        let no_frame = (DVec2::ZERO, DVec3::ZERO, DVec3::ZERO);
        let sphere = matches!(inst.shape, Shape::Sphere { .. });
        let (t, n_geo, n_shade, (uv, dpdu, dpdv)) = match &inst.shape {
            Shape::Sphere { center, radius } => {
                let p = local.at(c.t);
                let n = (p - *center) / *radius;
                (c.t, n, n, if textured { sphere_uv_frame(p - *center, *radius) } else { no_frame })
            }
            Shape::Plane { point, normal } => {
                let frame = if textured { plane_uv_frame(local.at(c.t) - *point, *normal) } else { no_frame };
                (c.t, *normal, *normal, frame)
            }
            Shape::Mesh { mesh, smooth } => {
                let m = &self.meshes[*mesh as usize];
                let h = m.refine(c.tri, local.origin, local.dir);
                let t = refined_t(h.t, c.t);
                let ng = h.normal;
                let ns = if *smooth { m.smooth_normal(c.tri, h.u, h.v) } else { ng };
                let frame = if textured {
                    m.uv_frame(c.tri, h.u, h.v).unwrap_or((DVec2::new(h.u, h.v), DVec3::ZERO, DVec3::ZERO))
                } else {
                    no_frame
                };
                (t, ng, ns, frame)
            }
        };
        // Flat faces, spheres and planes shade with their geometric normal: carry it to world
        // space once.
        let normals = |xf: &Transform| {
            let geo = xf.normal_to_world(n_geo);
            (geo, if n_shade == n_geo { geo } else { xf.normal_to_world(n_shade) })
        };
        let (geo_normal, shading_normal, dpdu, dpdv, bump_axis) = match &inst.transform {
            Some(xf) if textured => {
                let (geo, shade) = normals(xf);
                (
                    geo,
                    shade,
                    xf.to_world.transform_vector3(dpdu),
                    xf.to_world.transform_vector3(dpdv),
                    xf.to_world.transform_vector3(n_shade),
                )
            }
            Some(xf) => {
                let (geo, shade) = normals(xf);
                (geo, shade, dpdu, dpdv, DVec3::ZERO)
            }
            None => (n_geo, n_shade, dpdu, dpdv, n_shade),
        };
        // A smooth normal may lean past the face; keep it on the face's side.
        let shading_normal = side_of(shading_normal, geo_normal);
        *out = SurfaceHit {
            t,
            point: ray.at(t),
            geo_normal,
            shading_normal,
            material: inst.material,
            instance: c.instance,
            uv,
            dpdu,
            dpdv,
            // Measured (bump_mapping_transformed): a transformed mesh's relief scales with the
            // object (axis M·n_obj), a transformed sphere's does not (the unit world normal).
            bump_axis: if sphere { shading_normal } else { side_of(bump_axis, shading_normal) },
            world: c.merged,
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DAffine3;
    use glam::Vec3A;

    thread_local! {
        /// Packets completed by `smooth_mesh_hits` on this thread (the test's threads are its own).
        pub(super) static SMOOTH_MESH_PACKETS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
        /// Of those, the packets whose lanes all found one triangle (read once by `smooth_hits`).
        pub(crate) static ONE_TRIANGLE_PACKETS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
    }

    fn unit_quad() -> Arc<MeshGeom> {
        Arc::new(MeshGeom::new(
            vec![
                DVec3::new(-1.0, -1.0, 0.0),
                DVec3::new(1.0, -1.0, 0.0),
                DVec3::new(1.0, 1.0, 0.0),
                DVec3::new(-1.0, 1.0, 0.0),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
            None,
        ))
    }

    #[test]
    fn instances_share_a_mesh_and_transform_rays() {
        let moved = Transform::new(DAffine3::from_translation(DVec3::new(0.0, 0.0, -5.0))).unwrap();
        let scaled = Transform::new(DAffine3::from_scale(DVec3::splat(2.0))).unwrap();
        let accel = Accel::new(
            vec![unit_quad()],
            vec![
                Instance {
                    shape: Shape::Mesh { mesh: 0, smooth: false },
                    material: 0,
                    transform: Some(moved),
                    motion: None,
                    textures: ObjectTextures::default(),
                },
                Instance {
                    shape: Shape::Sphere { center: DVec3::new(5.0, 0.0, 0.0), radius: 1.0 },
                    material: 1,
                    transform: Some(scaled),
                    motion: None,
                    textures: ObjectTextures::default(),
                },
            ],
        );
        let r = Ray::new(DVec3::new(0.5, 0.5, 10.0), DVec3::NEG_Z);
        let h = accel.intersect(&r, 1e-6, f64::INFINITY).unwrap();
        assert!((h.t - 15.0).abs() < 1e-9, "{}", h.t);
        assert_eq!(h.material, 0);
        // The sphere is scaled about the origin: centre (10,0,0), radius 2.
        let r = Ray::new(DVec3::new(10.0, 0.0, 10.0), DVec3::NEG_Z);
        let h = accel.intersect(&r, 1e-6, f64::INFINITY).unwrap();
        assert!((h.t - 8.0).abs() < 1e-9, "{}", h.t);
        assert!((h.geo_normal - DVec3::Z).length() < 1e-9);
        assert!(accel.occluded(&r, 1e-6, 9.0));
        assert!(!accel.occluded(&r, 1e-6, 7.0));
    }

    #[test]
    fn moving_objects_are_where_the_ray_time_puts_them() {
        let accel = Accel::new(
            vec![unit_quad()],
            vec![
                Instance {
                    shape: Shape::Sphere { center: DVec3::ZERO, radius: 1.0 },
                    material: 0,
                    transform: None,
                    motion: Some(DVec3::new(10.0, 0.0, 0.0)),
                    textures: ObjectTextures::default(),
                },
                Instance {
                    shape: Shape::Mesh { mesh: 0, smooth: false },
                    material: 1,
                    transform: Some(
                        Transform::new(DAffine3::from_translation(DVec3::new(0.0, 0.0, -5.0))).unwrap(),
                    ),
                    motion: Some(DVec3::new(0.0, 0.0, 4.0)),
                    textures: ObjectTextures::default(),
                },
            ],
        );
        let at = |x: f64, time: f64| {
            let r = Ray { origin: DVec3::new(x, 0.5, 10.0), dir: DVec3::NEG_Z, time };
            accel.intersect(&r, 1e-6, f64::INFINITY).map(|h| (h.material, h.t))
        };
        // The sphere moves from x = 0 to x = 10; the quad from z = -5 to z = -1.
        assert_eq!(at(0.0, 0.0).map(|h| h.0), Some(0));
        assert_eq!(at(5.0, 0.5).map(|h| h.0), Some(0));
        assert_eq!(at(10.0, 0.0), None);
        assert_eq!(at(10.0, 0.99).map(|h| h.0), Some(0));
        let (m, t) = at(-0.5, 0.75).unwrap_or((9, 0.0));
        // At time 0.75 the sphere is at x = 7.5: the ray at x = -0.5 reaches the quad at z = -2.
        assert_eq!(m, 1);
        assert!((t - 12.0).abs() < 1e-9, "{t}");
        let shadow = Ray { origin: DVec3::new(7.5, 0.0, 10.0), dir: DVec3::NEG_Z, time: 0.75 };
        assert!(accel.occluded(&shadow, 1e-6, 20.0));
        assert!(!accel.occluded(&Ray { time: 0.0, ..shadow }, 1e-6, 11.5));
    }

    /// A mesh instance moved beyond `f32`'s range (a motion blur of 1e39, as a fuzzer wrote) sees
    /// the world's rays from past that range: their `f32` form is an empty ray, finite, which
    /// obvhs accepts (its `Ray::new` asserts finite values where assertions are on), and the
    /// instance is simply not hit, while a mesh beside it still is.
    #[test]
    fn a_mesh_moved_beyond_f32s_range_is_not_hit_and_its_rays_stay_finite() {
        let far = Ray { origin: DVec3::new(-1e39, 0.5, 10.0), dir: DVec3::NEG_Z, time: 1.0 };
        let fr = rays::to_f32_ray(&far, 1e-6, f64::INFINITY);
        assert!(fr.origin.is_finite() && fr.direction.is_finite() && fr.inv_direction.is_finite());
        assert!(fr.tmin > fr.tmax, "an empty interval: {} > {}", fr.tmin, fr.tmax);
        let near = rays::to_f32_ray(&Ray { origin: DVec3::new(0.5, 0.5, 10.0), ..far }, 1e-6, 20.0);
        assert_eq!((near.origin, near.tmin, near.tmax), (Vec3A::new(0.5, 0.5, 10.0), 1e-6, 20.0));
        let quad = |material: u32, motion: f64| Instance {
            shape: Shape::Mesh { mesh: 0, smooth: false },
            material,
            transform: Some(Transform::new(DAffine3::from_translation(DVec3::new(0.0, 0.0, -5.0))).unwrap()),
            motion: Some(DVec3::new(motion, 0.0, 0.0)),
            textures: ObjectTextures::default(),
        };
        let accel = Accel::new(vec![unit_quad()], vec![quad(0, 1e39), quad(1, 0.0)]);
        for time in [0.0, 0.5, 1.0] {
            let r = Ray { origin: DVec3::new(0.5, 0.5, 10.0), dir: DVec3::NEG_Z, time };
            let hit = accel.intersect(&r, 1e-6, f64::INFINITY).map(|h| (h.material, h.t));
            // At time 0 the far quad has not moved yet and lies where the near one does: either
            // may be found (the same distance); later only the near one is there to find.
            match hit {
                Some((m, t)) => assert!((t - 15.0).abs() < 1e-9 && (time == 0.0 || m == 1), "{m} {t}"),
                None => panic!("the unmoved quad is missed at time {time}"),
            }
            assert!(accel.occluded(&r, 1e-6, 20.0));
        }
        let beside = Ray { origin: DVec3::new(5.0, 0.5, 10.0), dir: DVec3::NEG_Z, time: 1.0 };
        assert!(accel.intersect(&beside, 1e-6, f64::INFINITY).is_none());
        assert!(!accel.occluded(&beside, 1e-6, f64::INFINITY));
    }

    /// The top-level BVH (used above LINEAR_MAX instances) and the merged tree of the static
    /// meshes (here the transformed quads without motion) find the same closest hits and
    /// occlusions as testing every instance on its own.
    #[test]
    fn top_level_bvh_agrees_with_brute_force() {
        let mut rng = crate::sampler::Sampler::new(3, 1, 2, 3);
        let mut r = move || rng.next_1d();
        let mut instances = Vec::new();
        for i in 0..40 {
            let at = DVec3::new(r() * 20.0 - 10.0, r() * 20.0 - 10.0, r() * 20.0 - 10.0);
            let inst = if i % 2 == 0 {
                Instance {
                    shape: Shape::Sphere { center: at, radius: 0.3 + r() },
                    material: i,
                    transform: None,
                    motion: None,
                    textures: ObjectTextures::default(),
                }
            } else {
                let xf = DAffine3::from_translation(at)
                    * DAffine3::from_axis_angle(DVec3::new(r(), r(), r()).normalize(), r() * 6.0);
                Instance {
                    shape: Shape::Mesh { mesh: 0, smooth: false },
                    material: i,
                    transform: Transform::new(xf),
                    motion: if i % 3 == 0 { Some(DVec3::new(r(), 0.0, r())) } else { None },
                    textures: ObjectTextures::default(),
                }
            };
            instances.push(inst);
        }
        let accel = Accel::new(vec![unit_quad()], instances.clone());
        assert!(accel.instances.len() > LINEAR_MAX);
        let static_meshes =
            instances.iter().filter(|i| matches!(i.shape, Shape::Mesh { .. }) && i.motion.is_none());
        assert_eq!(
            accel.merged_prims.len(),
            2 * static_meshes.count(),
            "every static quad is in the merged tree"
        );
        let singles: Vec<Accel> =
            instances.iter().map(|i| Accel::new(vec![unit_quad()], vec![i.clone()])).collect();
        for _ in 0..3000 {
            let o = DVec3::new(r() * 30.0 - 15.0, r() * 30.0 - 15.0, r() * 30.0 - 15.0);
            let d = DVec3::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize();
            let ray = Ray { origin: o, dir: d, time: r() };
            let expect = singles
                .iter()
                .enumerate()
                .filter_map(|(i, a)| a.intersect(&ray, 1e-6, f64::INFINITY).map(|h| (h.t, i as u32)))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let got = accel.intersect(&ray, 1e-6, f64::INFINITY).map(|h| (h.t, h.material));
            match (expect, got) {
                (None, None) => {}
                (Some((te, ie)), Some((tg, ig))) => {
                    assert!((te - tg).abs() < 1e-6 && ie == ig, "{expect:?} vs {got:?}");
                }
                _ => panic!("{expect:?} vs {got:?}"),
            }
            let blocked = singles.iter().any(|a| a.occluded(&ray, 1e-6, 12.0));
            assert_eq!(accel.occluded(&ray, 1e-6, 12.0), blocked);
        }
    }

    /// One box test for eight rays answers what each ray's own test answers, boxes hit and
    /// missed, rays inside boxes, bounded and unbounded rays.
    #[test]
    fn a_box_test_for_eight_rays_answers_as_each_rays_own() {
        let mut rng = crate::sampler::Sampler::new(1, 2, 3, 4);
        let mut r = move || rng.next_1d() as f32;
        let (mut entered, mut tested) = (0, 0);
        for k in 0..2000 {
            let c = Vec3A::new(r(), r(), r()) * 10.0 - 5.0;
            let h = Vec3A::new(r(), r(), r()) * 2.0 + 0.01;
            let b = Aabb::new(c - h, c + h);
            let n = 1 + k % 8;
            let rays: Vec<obvhs::ray::Ray> = (0..n)
                .map(|i| {
                    let o = Vec3A::new(r(), r(), r()) * 12.0 - 6.0;
                    let d = if i == 0 && k % 5 == 0 {
                        Vec3A::X
                    } else if i % 3 == 0 {
                        Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize()
                    } else {
                        // Towards the box, near its edges.
                        (c + h * Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5) * 2.4 - o).normalize()
                    };
                    let tmax = if i % 2 == 0 { f32::INFINITY } else { r() * 8.0 };
                    obvhs::ray::Ray::new(o, d, 0.0, tmax)
                })
                .collect();
            let mask = BoxRays8::new(&rays).hits(&b);
            for (i, fr) in rays.iter().enumerate() {
                assert_eq!(mask & (1 << i) != 0, enters(&b, fr), "box {k} ray {i}");
                entered += usize::from(enters(&b, fr));
                tested += 1;
            }
            assert_eq!(mask >> n, 0);
        }
        assert!(entered > tested / 20 && entered < tested / 2, "{entered} of {tested}");
    }

    /// A crumpled sheet of 2 * 16 * 16 triangles around the origin.
    fn sheet(r: &mut impl FnMut() -> f64) -> Arc<MeshGeom> {
        let n = 17;
        let mut positions = Vec::new();
        for j in 0..n {
            for i in 0..n {
                positions.push(DVec3::new(i as f64 - 8.0, j as f64 - 8.0, r() * 2.0 - 1.0));
            }
        }
        let mut faces = Vec::new();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let k = (j * n + i) as u32;
                faces.push([k, k + 1, k + n as u32 + 1]);
                faces.push([k, k + n as u32 + 1, k + n as u32]);
            }
        }
        Arc::new(MeshGeom::new(positions, faces, None))
    }

    /// The sheet as instance 0 (`transform`), beside a sphere, a moving copy of it and a plane.
    fn sheet_scene(sheet: &Arc<MeshGeom>, transform: Option<Transform>) -> Accel {
        let plain = |material: u32, transform: Option<Transform>, motion: Option<DVec3>| Instance {
            shape: Shape::Mesh { mesh: 0, smooth: false },
            material,
            transform,
            motion,
            textures: ObjectTextures::default(),
        };
        let instances = vec![
            plain(0, transform, None),
            Instance {
                shape: Shape::Sphere { center: DVec3::new(2.0, 1.0, 3.0), radius: 1.5 },
                material: 1,
                transform: None,
                motion: None,
                textures: ObjectTextures::default(),
            },
            plain(2, Transform::new(DAffine3::from_translation(DVec3::new(3.0, 0.0, -4.0))), Some(DVec3::X)),
            Instance {
                shape: Shape::Plane { point: DVec3::new(0.0, 0.0, -9.0), normal: DVec3::Z },
                material: 3,
                transform: None,
                motion: None,
                textures: ObjectTextures::default(),
            },
        ];
        Accel::new(vec![sheet.clone()], instances)
    }

    /// A lone untransformed static mesh is walked as the world tree on its own and finds what
    /// the same mesh finds through the merged tree (where an identity transform puts it).
    #[test]
    fn a_lone_world_space_mesh_finds_what_the_merged_tree_finds() {
        let mut rng = crate::sampler::Sampler::new(5, 4, 3, 2);
        let mut r = move || rng.next_1d();
        let sheet = sheet(&mut r);
        let lone = sheet_scene(&sheet, None);
        let merged = sheet_scene(&sheet, Transform::new(DAffine3::IDENTITY));
        assert!(lone.lone.is_some() && lone.merged.is_empty() && lone.bounded.len() == 2);
        assert!(merged.lone.is_none() && merged.merged_prims.len() == 512);
        let mut hits = 0;
        for _ in 0..4000 {
            let o = DVec3::new(r() * 24.0 - 12.0, r() * 24.0 - 12.0, r() * 24.0 - 12.0);
            let d = DVec3::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize();
            let ray = Ray { origin: o, dir: d, time: r() };
            let a = lone.intersect(&ray, 1e-6, f64::INFINITY).map(|h| (h.material, h.t, h.geo_normal));
            let b = merged.intersect(&ray, 1e-6, f64::INFINITY).map(|h| (h.material, h.t, h.geo_normal));
            match (a, b) {
                (Some((ma, ta, na)), Some((mb, tb, nb))) => {
                    assert!(ma == mb && (ta - tb).abs() < 1e-9 && (na - nb).length() < 1e-9, "{a:?} {b:?}");
                    hits += usize::from(ma == 0);
                }
                (None, None) => {}
                _ => panic!("{a:?} vs {b:?}"),
            }
            assert_eq!(lone.occluded(&ray, 1e-6, 10.0), merged.occluded(&ray, 1e-6, 10.0));
        }
        assert!(hits > 300, "the sheet is hit often enough to matter: {hits}");
    }

    /// `n` rays about origin `o` and direction `d`, each moved by up to `spread` (times in [0, 1)
    /// when `moving`, else 0).
    fn packet(
        r: &mut impl FnMut() -> f64,
        n: usize,
        (o, d): (DVec3, DVec3),
        spread: f64,
        moving: bool,
    ) -> Vec<Ray> {
        (0..n)
            .map(|_| {
                let j = DVec3::new(r() - 0.5, r() - 0.5, r() - 0.5) * spread;
                let dir = (d + j).normalize();
                Ray { origin: o + j, dir, time: if moving { r() } else { 0.0 } }
            })
            .collect()
    }

    /// `rays` traced as a packet by `accel`, each beside its own single-ray hit.
    fn packet_and_singles(accel: &Accel, rays: &[Ray]) -> Vec<(Option<SurfaceHit>, Option<SurfaceHit>)> {
        // Stale records in every slot: each must be overwritten.
        let stale = SurfaceHit { t: -1.0, material: 99, ..SurfaceHit::default() };
        let mut out = vec![Some(stale); rays.len()];
        accel.intersect_packet(rays, 1e-6, &mut out);
        out.into_iter().zip(rays).map(|(got, ray)| (got, accel.intersect(ray, 1e-6, f64::INFINITY))).collect()
    }

    /// Rays traced as a packet get the very hits (same bits) they get one by one, and the same
    /// answers to "is anything in the way" within their own bounds, whichever world tree the
    /// scene has (the lone mesh, the merged tree, none) and whatever else it holds; packets of
    /// one to eight rays, narrow and wide.
    #[test]
    fn packets_of_rays_find_what_single_rays_find() {
        let mut rng = crate::sampler::Sampler::new(9, 8, 7, 6);
        let mut r = move || rng.next_1d();
        let sheet = sheet(&mut r);
        let scenes = [
            sheet_scene(&sheet, None),
            sheet_scene(&sheet, Transform::new(DAffine3::from_rotation_x(0.3))),
            // Only a moving mesh: no world tree.
            Accel::new(
                vec![sheet.clone()],
                vec![Instance {
                    shape: Shape::Mesh { mesh: 0, smooth: true },
                    material: 0,
                    transform: None,
                    motion: Some(DVec3::Y),
                    textures: ObjectTextures::default(),
                }],
            ),
        ];
        // Beyond LINEAR_MAX spheres the bounded instances go through the top level.
        let many = Accel::new(
            vec![sheet.clone()],
            (0..12)
                .map(|i| Instance {
                    shape: Shape::Sphere {
                        center: DVec3::new(i as f64 % 4.0 * 3.0 - 4.5, (i / 4) as f64 * 3.0 - 3.0, 2.0),
                        radius: 1.0,
                    },
                    material: i,
                    transform: None,
                    motion: None,
                    textures: ObjectTextures::default(),
                })
                .collect(),
        );
        let scenes: Vec<Accel> = scenes.into_iter().chain([many]).collect();
        assert!(scenes[0].lone.is_some() && !scenes[1].merged.is_empty());
        assert!(scenes[2].world_tree().is_none() && scenes[3].bounded.len() > LINEAR_MAX);
        let key = |h: &Option<SurfaceHit>| {
            h.map(|h| (h.instance, h.t.to_bits(), h.point.to_array().map(f64::to_bits), h.shading_normal))
        };
        let (mut hits, mut shadowed, mut shadow_rays) = (0, 0, 0);
        for (k, accel) in scenes.iter().cycle().take(4 * 500).enumerate() {
            let n = 1 + k % 8;
            let o = DVec3::new(r() * 4.0 - 2.0, r() * 4.0 - 2.0, 12.0);
            let d = DVec3::new(r() * 0.8 - 0.4, r() * 0.8 - 0.4, -1.0).normalize();
            let spread = [1e-3, 0.1, 1.0][k % 3];
            let rays = packet(&mut r, n, (o, d), spread, true);
            for (got, single) in packet_and_singles(accel, &rays) {
                assert_eq!(key(&got), key(&single), "packet {k}");
                hits += usize::from(got.is_some());
            }
            // Shadow rays: bounds from short of the nearest surface to beyond everything.
            let tmax: Vec<f64> = (0..n).map(|_| if r() < 0.2 { f64::INFINITY } else { r() * 24.0 }).collect();
            let blocked = accel.occluded_packet(&rays, 1e-6, &tmax);
            assert_eq!(blocked >> n, 0, "packet {k}: only its own lanes");
            for (lane, (ray, &t)) in rays.iter().zip(&tmax).enumerate() {
                let single = accel.occluded(ray, 1e-6, t);
                assert_eq!(blocked & (1 << lane) != 0, single, "packet {k} lane {lane}, tmax {t}");
                shadowed += usize::from(single);
                shadow_rays += 1;
            }
        }
        assert!(hits > 1000, "the scenes are hit often enough to matter: {hits}");
        assert!(
            shadowed > shadow_rays / 5 && shadowed < shadow_rays * 4 / 5,
            "blocked and clear shadow rays both common: {shadowed} of {shadow_rays}"
        );
    }

    /// A packet's hits on one untransformed smooth mesh (re-intersected and shaded eight lanes
    /// at a time, `smooth_mesh_hits`) are the single rays' records, every field to the bit:
    /// vertex normals that lean past their faces (flipped), that cancel out (the face normal
    /// instead), and ordinary ones; packets of one to eight rays, narrow and wide; a lone mesh,
    /// and two meshes in the merged tree under a sphere (packets whose hits are on several
    /// objects take the single path).
    #[test]
    fn a_smooth_mesh_packet_gets_the_single_rays_records() {
        let mut rng = crate::sampler::Sampler::new(5, 3, 2, 8);
        let mut r = move || rng.next_1d();
        let sheet = sheet(&mut r);
        let normals: Vec<DVec3> = (0..sheet.positions.len())
            .map(|i| match i % 7 {
                // A corner of zero normals (every triangle touching only such corners
                // interpolates to zero), and some that point below the sheet.
                _ if (i / 17) < 3 && i % 17 < 3 => DVec3::ZERO,
                0 | 3 => DVec3::new(r() - 0.5, r() - 0.5, -1.0).normalize(),
                _ => DVec3::new(r() - 0.5, r() - 0.5, 1.0).normalize(),
            })
            .collect();
        let mesh =
            Arc::new(MeshGeom::new(sheet.positions.clone(), sheet.indices.clone(), Some(normals.clone())));
        // The same sheet 16 units along x, as a mesh of its own.
        let moved = sheet.positions.iter().map(|p| *p + DVec3::new(16.0, 0.0, 0.0)).collect();
        let beside = Arc::new(MeshGeom::new(moved, sheet.indices.clone(), Some(normals)));
        let smooth = |mesh: u32, material: u32| Instance {
            shape: Shape::Mesh { mesh, smooth: true },
            material,
            transform: None,
            motion: None,
            textures: ObjectTextures::default(),
        };
        let lone = Accel::new(vec![mesh.clone()], vec![smooth(0, 4)]);
        assert!(lone.lone.is_some() && lone.bounded.is_empty() && lone.unbounded.is_empty());
        let ball = Instance {
            shape: Shape::Sphere { center: DVec3::new(8.0, 0.0, 2.5), radius: 2.0 },
            ..smooth(0, 6)
        };
        let pair = Accel::new(vec![mesh, beside], vec![smooth(0, 4), smooth(1, 5), ball]);
        assert!(!pair.merged.is_empty() && pair.bounded.len() == 1);
        let bits = |v: DVec3| v.to_array().map(f64::to_bits);
        let key = |h: &Option<SurfaceHit>| {
            h.map(|h| {
                (
                    (h.t.to_bits(), bits(h.point), bits(h.geo_normal), bits(h.shading_normal)),
                    (h.material, h.instance, h.uv.to_array().map(f64::to_bits)),
                    (bits(h.dpdu), bits(h.dpdv), bits(h.bump_axis)),
                )
            })
        };
        for (accel, width) in [(&lone, 14.0), (&pair, 30.0)] {
            SMOOTH_MESH_PACKETS.with(|c| c.set(0));
            ONE_TRIANGLE_PACKETS.with(|c| c.set(0));
            let (mut together, mut one_mesh, mut face) = (0, 0, 0);
            for k in 0..3000 {
                let n = 1 + k % 8;
                let o = DVec3::new(r() * width - 7.0, r() * 14.0 - 7.0, 6.0);
                let d = DVec3::new(r() * 0.6 - 0.3, r() * 0.6 - 0.3, -1.0).normalize();
                let spread = [1e-3, 0.1, 1.0][k % 3];
                let rays = packet(&mut r, n, (o, d), spread, false);
                let both = packet_and_singles(accel, &rays);
                for (got, single) in &both {
                    assert_eq!(key(got), key(single), "packet {k}");
                }
                let hit: Vec<SurfaceHit> = both.iter().filter_map(|(got, _)| *got).collect();
                if hit.len() >= 2 {
                    together += 1;
                    face += hit.iter().filter(|h| h.shading_normal == h.geo_normal).count();
                    if hit.iter().all(|h| h.instance == hit[0].instance && h.instance < 2) {
                        one_mesh += 1;
                    }
                }
            }
            assert!(
                together > 1000 && face > 20,
                "packets with two hits or more {together}, face normals {face}"
            );
            // Exactly the packets whose hits are all on one of the meshes came through the
            // eight-lane path (the single rays never do).
            assert!(
                one_mesh > 500 && (accel.lone.is_some() || one_mesh < together),
                "{one_mesh} of {together}"
            );
            assert_eq!(SMOOTH_MESH_PACKETS.with(|c| c.get()), one_mesh);
            // Narrow packets mostly find one triangle, wide ones several: both ways of reading
            // the corners were taken.
            let one_triangle = ONE_TRIANGLE_PACKETS.with(|c| c.get());
            assert!(one_triangle > 100 && one_triangle + 100 < one_mesh, "{one_triangle} of {one_mesh}");
        }
    }

    /// Rays made side by side from one origin are the lanes a gathering of the same rays makes,
    /// unused lanes included (they repeat the first), for groups of one to eight.
    #[test]
    fn lanes_from_one_origin_are_the_gathered_rays() {
        let mut rng = crate::sampler::Sampler::new(4, 4, 4, 4);
        let origin = DVec3::new(0.3, -2.0, 7.5);
        for len in 1..=8 {
            let d: [[f64; 8]; 3] = std::array::from_fn(|_| std::array::from_fn(|_| rng.next_1d() - 0.5));
            let rays: Vec<Ray> =
                (0..len).map(|k| Ray::new(origin, DVec3::new(d[0][k], d[1][k], d[2][k]))).collect();
            let (made, gathered) = (RayLanes::from_origin(origin, &d, len), RayLanes::new(&rays));
            // The same lanes refilled in place, over another group's directions.
            let mut refilled = RayLanes::from_origin(origin, &[[0.25; 8]; 3], 8);
            refilled.refill_dirs(len, |to| *to = d);
            let bits = |v: &[[f64; 8]; 3]| v.map(|row| row.map(f64::to_bits));
            for l in [&made, &refilled] {
                assert_eq!((bits(&l.o), bits(&l.d), l.len), (bits(&gathered.o), bits(&gathered.d), len));
                assert!(rays.iter().enumerate().all(|(k, r)| l.holds(k, r) && l.dir(k) == r.dir));
            }
        }
    }

    /// A hit on a flat, untextured face of the merged tree takes its distance and normal from
    /// the face's world plane; it is the hit the general path (the ray carried to object space,
    /// the triangle re-intersected there, the normal carried back) finds, to rounding: the same
    /// normal bits, the distance and point to 1e-12 of the ray's scale. Smooth faces and faces
    /// outside the merged tree keep the general path.
    #[test]
    fn flat_merged_faces_take_their_world_plane() {
        let mut rng = crate::sampler::Sampler::new(3, 1, 4, 1);
        let mut r = move || rng.next_1d();
        let sheet = sheet(&mut r);
        let normals =
            (0..sheet.positions.len()).map(|_| DVec3::new(r() - 0.5, r() - 0.5, 2.0).normalize()).collect();
        let bent = Arc::new(MeshGeom::new(sheet.positions.clone(), sheet.indices.clone(), Some(normals)));
        let skew = DAffine3::from_translation(DVec3::new(-12.0, -2.0, 0.5))
            * DAffine3::from_rotation_y(0.4)
            * DAffine3::from_scale(DVec3::new(1.5, 0.7, 1.0));
        let face = |smooth: bool, transform: Option<Transform>, material: u32| Instance {
            shape: Shape::Mesh { mesh: u32::from(smooth), smooth },
            material,
            transform,
            motion: None,
            textures: ObjectTextures::default(),
        };
        let instances = vec![
            face(false, Transform::new(skew), 0),
            face(true, Transform::new(DAffine3::from_translation(DVec3::new(12.0, 0.0, 3.0))), 1),
            face(false, None, 2),
        ];
        let meshes = vec![sheet, bent];
        let fast = Accel::new(meshes.clone(), instances.clone());
        let mut general = Accel::new(meshes, instances);
        assert_eq!(fast.planes.len(), fast.merged_prims.len(), "every merged face has its plane");
        general.planes = Default::default();
        let (mut by_instance, mut rounded_differently) = ([0; 3], 0);
        for _ in 0..3000 {
            let o = DVec3::new(r() * 36.0 - 18.0, r() * 8.0 - 4.0, 12.0);
            let ray = Ray { origin: o, dir: DVec3::new(r() - 0.5, r() - 0.5, -1.0).normalize(), time: 0.0 };
            let (a, b) =
                (fast.intersect(&ray, 1e-6, f64::INFINITY), general.intersect(&ray, 1e-6, f64::INFINITY));
            assert_eq!(a.is_some(), b.is_some());
            let (Some(a), Some(b)) = (a, b) else { continue };
            assert_eq!((a.instance, a.material), (b.instance, b.material));
            assert_eq!(a.geo_normal, b.geo_normal, "the normal's bits");
            assert_eq!(a.shading_normal, b.shading_normal);
            assert!((a.t - b.t).abs() <= 1e-12 * b.t.max(1.0), "t {} against {}", a.t, b.t);
            assert!((a.point - b.point).length() <= 1e-12 * (1.0 + o.length() + b.t));
            by_instance[a.instance as usize] += 1;
            if a.instance == 1 {
                // The smooth sheet's shading normals differ from its faces' (checked above):
                // its hits are the general path's, bit for bit.
                assert_ne!(a.shading_normal, a.geo_normal);
                assert_eq!((a.t.to_bits(), a.point), (b.t.to_bits(), b.point));
            } else {
                rounded_differently += usize::from(a.t != b.t);
            }
        }
        assert!(by_instance.iter().all(|&k| k > 100), "each sheet hit often enough: {by_instance:?}");
        // The plane's distance is its own computation (not a copy of the general one's bits).
        assert!(rounded_differently > 0);
    }

    /// A lone mesh (one static untransformed mesh, walked in its own tree) that is flat and
    /// untextured takes its planes as the merged faces do: the same normal bits as the general
    /// path, distances to 1e-12. A smooth or textured lone mesh gets none (no hit would read
    /// them), nor does a sphere beside it change that.
    #[test]
    fn a_flat_lone_mesh_takes_its_planes() {
        let mut rng = crate::sampler::Sampler::new(5, 2, 7, 3);
        let mut r = move || rng.next_1d();
        let sheet = sheet(&mut r);
        let lone = |smooth: bool, textures: ObjectTextures| {
            let ball = Instance {
                shape: Shape::Sphere { center: DVec3::new(0.0, 0.0, 4.0), radius: 1.0 },
                material: 1,
                transform: None,
                motion: None,
                textures: ObjectTextures::default(),
            };
            let face = Instance {
                shape: Shape::Mesh { mesh: 0, smooth },
                material: 0,
                transform: None,
                motion: None,
                textures,
            };
            Accel::new(vec![sheet.clone()], vec![face, ball])
        };
        let fast = lone(false, ObjectTextures::default());
        assert!(fast.lone.is_some() && fast.merged.is_empty());
        assert_eq!(fast.planes.len(), sheet.triangle_count(), "a plane per triangle of the lone mesh");
        assert!(lone(true, ObjectTextures::default()).planes.is_empty(), "smooth: no planes");
        let textured = ObjectTextures { colour: [Some(0), None], ..ObjectTextures::default() };
        assert!(lone(false, textured).planes.is_empty(), "textured: no planes");
        let mut general = lone(false, ObjectTextures::default());
        general.planes = Default::default();
        let (mut sheet_hits, mut rounded_differently) = (0, 0);
        for _ in 0..2000 {
            let o = DVec3::new(r() * 20.0 - 10.0, r() * 20.0 - 10.0, 12.0);
            let ray = Ray { origin: o, dir: DVec3::new(r() - 0.5, r() - 0.5, -1.0).normalize(), time: 0.0 };
            let (a, b) =
                (fast.intersect(&ray, 1e-6, f64::INFINITY), general.intersect(&ray, 1e-6, f64::INFINITY));
            assert_eq!(a.is_some(), b.is_some());
            let (Some(a), Some(b)) = (a, b) else { continue };
            assert_eq!(a.instance, b.instance);
            assert_eq!(
                (a.geo_normal, a.shading_normal),
                (b.geo_normal, b.shading_normal),
                "the normal's bits"
            );
            assert!((a.t - b.t).abs() <= 1e-12 * b.t.max(1.0), "t {} against {}", a.t, b.t);
            assert!((a.point - b.point).length() <= 1e-12 * (1.0 + o.length() + b.t));
            if a.instance == 0 {
                sheet_hits += 1;
                rounded_differently += usize::from(a.t != b.t);
            } else {
                assert_eq!(a.t.to_bits(), b.t.to_bits(), "the sphere's hits are not the planes'");
            }
        }
        assert!(sheet_hits > 500, "the sheet is hit often enough: {sheet_hits}");
        assert!(rounded_differently > 0, "the plane's distance is its own computation");
    }

    #[test]
    fn planes_are_hit_from_both_sides_and_beside_a_bvh() {
        let plane = |material: u32| Instance {
            shape: Shape::Plane { point: DVec3::new(0.0, -1.0, 0.0), normal: DVec3::Y },
            material,
            transform: None,
            motion: None,
            textures: ObjectTextures::default(),
        };
        // Many spheres, so that the bounded instances go through the top-level BVH.
        let mut instances: Vec<Instance> = (0..20)
            .map(|i| Instance {
                shape: Shape::Sphere { center: DVec3::new(i as f64 * 3.0, 0.0, -10.0), radius: 1.0 },
                material: 1,
                transform: None,
                motion: None,
                textures: ObjectTextures::default(),
            })
            .collect();
        instances.push(plane(0));
        let accel = Accel::new(vec![], instances);
        assert!(accel.bounded.len() > LINEAR_MAX && accel.unbounded == vec![20]);
        // Down onto the plane from above, and up onto it from below.
        let down = Ray::new(DVec3::new(100.0, 4.0, 7.0), DVec3::NEG_Y);
        let h = accel.intersect(&down, 1e-6, f64::INFINITY).unwrap();
        assert_eq!(h.material, 0);
        assert!((h.t - 5.0).abs() < 1e-12 && (h.point.y + 1.0).abs() < 1e-12);
        assert_eq!(h.geo_normal, DVec3::Y);
        let up = Ray::new(DVec3::new(0.0, -3.0, 0.0), DVec3::Y);
        assert!((accel.intersect(&up, 1e-6, f64::INFINITY).unwrap().t - 2.0).abs() < 1e-12);
        // A sphere in front of the plane wins; parallel rays miss; shadow rays see the plane.
        let slanted = Ray::new(DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.0, 0.0, -1.0));
        assert_eq!(accel.intersect(&slanted, 1e-6, f64::INFINITY).unwrap().material, 1);
        let parallel = Ray::new(DVec3::new(0.0, 5.0, 0.0), DVec3::X);
        assert!(accel.intersect(&parallel, 1e-6, f64::INFINITY).is_none());
        assert!(accel.occluded(&down, 1e-6, 6.0));
        assert!(!accel.occluded(&down, 1e-6, 4.0));
        // Transformed (lifted by 2) and textured: the frame is orthonormal and in the plane.
        let lifted = Instance {
            transform: Transform::new(DAffine3::from_translation(DVec3::new(0.0, 2.0, 0.0))),
            textures: ObjectTextures { normal: Some(0), ..ObjectTextures::default() },
            ..plane(2)
        };
        let accel = Accel::new(vec![], vec![lifted]);
        let h = accel.intersect(&down, 1e-6, f64::INFINITY).unwrap();
        assert!((h.t - 3.0).abs() < 1e-12 && (h.geo_normal - DVec3::Y).length() < 1e-12);
        assert!(h.dpdu.dot(DVec3::Y).abs() < 1e-12 && h.dpdv.dot(DVec3::Y).abs() < 1e-12);
        assert!((h.dpdu.cross(h.dpdv) - DVec3::Y).length() < 1e-12, "{:?} {:?}", h.dpdu, h.dpdv);
    }

    /// Numbers in [-1, 1) from a xorshift generator seeded with `seed`.
    fn uniform_pm1(mut state: u64) -> impl FnMut() -> f64 {
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        }
    }

    #[test]
    fn eight_lane_sphere_tests_are_the_single_ray_test_bit_for_bit() {
        // Rays through, tangent to, inside, behind and beside a sphere, with and without a
        // transform (rotation, uniform and non-uniform scale, translation), a zero direction
        // and a NaN: every lane's distance is what `sphere_t` finds in the object-space ray.
        let mut next = uniform_pm1(0x2545_f491_4f6c_dd1d);
        let (center, radius) = (DVec3::new(0.5, -0.25, 1.0), 1.5);
        let transforms = [
            None,
            Transform::new(DAffine3::from_scale_rotation_translation(
                DVec3::splat(5.0),
                glam::DQuat::from_rotation_y(0.3),
                DVec3::new(-10.0, 5.0, 10.0),
            )),
            Transform::new(DAffine3::from_scale(DVec3::new(1.0, 3.0, 0.5))),
        ];
        let (mut hits, mut misses) = (0, 0);
        for xf in &transforms {
            for round in 0..64 {
                let mut rays: Vec<Ray> = (0..8)
                    .map(|_| {
                        let o = DVec3::new(next(), next(), next()) * 12.0;
                        let aim = center + DVec3::new(next(), next(), next()) * 2.5;
                        Ray::new(o, (aim - o).normalize())
                    })
                    .collect();
                // Along a tangent, from the centre, a zero direction, a NaN.
                rays[1] = Ray::new(center + DVec3::new(-5.0, radius, 0.0), DVec3::X);
                rays[2] = Ray::new(center, DVec3::Z);
                if round == 0 {
                    rays[3] = Ray::new(DVec3::ONE, DVec3::ZERO);
                    rays[4] = Ray::new(DVec3::new(f64::NAN, 0.0, 0.0), DVec3::X);
                }
                let len = 3 + round % 6;
                let tmax: [f64; 8] =
                    std::array::from_fn(|l| if l % 3 == 0 { f64::INFINITY } else { 4.0 + l as f64 });
                let lanes = RayLanes::new(&rays[..len]);
                let got = sphere_lanes(center, radius, xf.as_ref(), &lanes.o, &lanes.d, 1e-6, &tmax);
                for l in 0..len {
                    let local = xf.as_ref().map_or(rays[l], |xf| xf.ray_to_object(&rays[l]));
                    let want = sphere_t(center, radius, &local, 1e-6, tmax[l]).unwrap_or(f64::INFINITY);
                    assert_eq!(got[l].to_bits(), want.to_bits(), "lane {l} of round {round}: {:?}", rays[l]);
                    if want.is_finite() { hits += 1 } else { misses += 1 }
                }
            }
        }
        assert!(hits > 200 && misses > 100, "{hits} hits, {misses} misses");
    }

    /// The shadow rays' cull before a sphere's exact test drops only lanes the exact test
    /// misses: rays grazing the sphere, segments ending just before, at and just after a root,
    /// origins on the surface heading away or along it, tiny and huge spheres far from the
    /// origin, NaN lanes. And it does drop the rays that pass far from the sphere.
    #[test]
    fn the_sphere_cull_keeps_every_lane_the_exact_test_hits() {
        let mut next = uniform_pm1(0x9e37_79b9_7f4a_7c15);
        let (mut kept_hits, mut dropped) = (0, 0);
        for (center, radius) in [
            (DVec3::new(0.5, -0.25, 1.0), 1.5),
            (DVec3::new(1e5, -3e4, 2e5), 1e-3),
            (DVec3::new(-7.0, 2.0, 0.0), 1e4),
            (DVec3::new(0.0, 0.0, 0.0), 0.3),
        ] {
            for round in 0..400 {
                let mut o = [[0.0; 8]; 3];
                let mut d = [[0.0; 8]; 3];
                let mut tmax = [0.0; 8];
                for l in 0..8 {
                    let unit = DVec3::new(next(), next(), next()).normalize();
                    let (origin, dir, far) = match (round + l) % 4 {
                        // Towards a point just inside or outside the surface, the segment
                        // ending anywhere from well before to well after the sphere.
                        0 => {
                            let aim = center + unit * radius * (1.0 + next() * 1e-9);
                            let origin = aim + DVec3::new(next(), next(), next()).normalize() * radius * 3.0;
                            let dir = (aim - origin).normalize();
                            (origin, dir, (aim - origin).length() * (1.0 + next() * 0.5))
                        }
                        // From the surface (a shading point), heading out, along or in.
                        1 => {
                            let origin = center + unit * radius;
                            let dir = (unit * next() + DVec3::new(next(), next(), next())).normalize();
                            (origin, dir, radius * (2.0 + next()))
                        }
                        // Far from the sphere, heading anywhere.
                        2 => {
                            let origin = center + unit * radius * 50.0;
                            let dir = DVec3::new(next(), next(), next()).normalize();
                            (origin, dir, radius * 10.0 * (1.0 + next()))
                        }
                        // Through the sphere, the far bound near the first root.
                        _ => {
                            let origin = center + unit * radius * 4.0;
                            let aim = center + DVec3::new(next(), next(), next()) * radius * 0.5;
                            let dir = (aim - origin).normalize();
                            let ray = Ray::new(origin, dir);
                            let root = sphere_t(center, radius, &ray, 1e-9, f64::INFINITY).unwrap_or(1.0);
                            let ulps = (next() * 4.0).round() as i64;
                            (origin, dir, f64::from_bits((root.to_bits() as i64 + ulps) as u64))
                        }
                    };
                    for a in 0..3 {
                        o[a][l] = origin[a];
                        d[a][l] = dir[a];
                    }
                    tmax[l] = far;
                }
                if round == 7 {
                    o[0][3] = f64::NAN;
                    tmax[5] = f64::INFINITY;
                    tmax[6] = f64::NAN;
                }
                let tmin = 1e-9 * radius;
                let kept = sphere_may_block(center, radius, &o, &d, tmin, &tmax);
                let exact = sphere_lanes(center, radius, None, &o, &d, tmin, &tmax);
                for (l, &t) in exact.iter().enumerate() {
                    if t < f64::INFINITY {
                        assert!(
                            kept & (1 << l) != 0,
                            "lane {l} of round {round} hits at {t} but was dropped"
                        );
                        kept_hits += 1;
                    } else if kept & (1 << l) == 0 {
                        dropped += 1;
                    }
                }
            }
        }
        assert!(kept_hits > 1500 && dropped > 1500, "{kept_hits} hits kept, {dropped} misses dropped");
    }

    #[test]
    fn sphere_from_inside_hits_far_side() {
        let r = Ray::new(DVec3::ZERO, DVec3::X);
        assert_eq!(sphere_t(DVec3::ZERO, 2.0, &r, 1e-6, f64::INFINITY), Some(2.0));
        assert_eq!(sphere_t(DVec3::new(0.0, 5.0, 0.0), 1.0, &r, 1e-6, f64::INFINITY), None);
    }
}
