//! Triangle meshes in object space, each with its own 8-wide BVH (`bvh8`, built from obvhs's PLOC).
//!
//! Triangles are stored twice on purpose: an `f32` copy in BVH order for the traversal's hot
//! loop (one cache line per few triangles, no indirection), and the indexed vertex arrays for the
//! exact `f64` re-intersection of the closest hit and for smooth normals.

use glam::{DVec2, DVec3, Vec3A};
use obvhs::aabb::Aabb;

use super::bvh8::{Bvh8, Ray8, Tri};
use crate::math::select;

/// Largest coordinate a box may reach to go into a BVH: the builder's surface areas (products
/// of extents) stay finite in `f32` below it.
pub const MAX_COORDINATE: f32 = 1e18;

/// A box that the BVH builder can take: finite, not inverted, within [`MAX_COORDINATE`].
pub fn is_sane(b: &Aabb) -> bool {
    let inside = |v: Vec3A| v.is_finite() && v.abs().max_element() <= MAX_COORDINATE;
    inside(b.min) && inside(b.max) && b.min.cmple(b.max).all()
}

/// A mesh ready for tracing.
pub struct MeshGeom {
    /// Object-space vertex positions.
    pub positions: Vec<DVec3>,
    /// Triangles as indices into `positions` (degenerate ones already removed).
    pub indices: Vec<[u32; 3]>,
    /// Unit per-vertex normals (object space) when some user of the mesh shades it smooth.
    pub vertex_normals: Option<Vec<DVec3>>,
    /// Per-vertex texture coordinates, when the mesh has them (TexCoordData or PLY u v).
    pub uvs: Option<Vec<DVec2>>,
    /// The 8-wide BVH over the `f32` triangles (vertex 0 and edges, in packets of four).
    bvh: Bvh8,
    pub bounds: Aabb,
    /// How many triangles the BVH leaves out: those with a vertex beyond [`MAX_COORDINATE`] (see
    /// [`MeshGeom::with_uvs`]), which no ray can hit.
    unplaced: usize,
}

/// `x` limited to [lo, hi]: `f64::clamp` for bounds in order (the same result, NaN `x`
/// included), without its panic when a bound is NaN (a re-intersection whose determinant came
/// out 0 has a NaN `u`, and `1 - u` bounds `v`). Blends, not branches: which hits fall
/// outside their triangle by a rounding is anybody's guess.
#[inline(always)]
fn clamp(x: f64, lo: f64, hi: f64) -> f64 {
    select(x < lo, lo, select(x > hi, hi, x))
}

/// The length below which an interpolated vertex normal counts as cancelled out: the face
/// normal shades instead ([`MeshGeom::smooth_normal`], [`MeshGeom::smooth_hits`]).
const MIN_SMOOTH_LENGTH: f64 = 1e-12;

/// Eight hits of [`MeshGeom::smooth_hits`], a lane each: the re-intersected distance, the unit
/// face normal and the unit smooth normal (by axis, then lane).
pub struct SmoothHits {
    pub t: [f64; 8],
    pub ng: [[f64; 8]; 3],
    pub ns: [[f64; 8]; 3],
}

/// Closest-hit data within a mesh, in object space.
#[derive(Clone, Copy, Debug)]
pub struct TriHit {
    pub t: f64,
    pub tri: u32,
    pub u: f64,
    pub v: f64,
    /// The triangle's unit face normal ([`MeshGeom::face_normal`], from the edges at hand).
    pub normal: DVec3,
}

impl MeshGeom {
    /// Builds the BVH. `positions` and `indices` must already be validated (indices in range,
    /// degenerate triangles removed).
    pub fn new(positions: Vec<DVec3>, indices: Vec<[u32; 3]>, vertex_normals: Option<Vec<DVec3>>) -> Self {
        Self::with_uvs(positions, indices, vertex_normals, None)
    }

    /// Like [`MeshGeom::new`], with per-vertex texture coordinates.
    pub fn with_uvs(
        positions: Vec<DVec3>,
        indices: Vec<[u32; 3]>,
        vertex_normals: Option<Vec<DVec3>>,
        uvs: Option<Vec<DVec2>>,
    ) -> Self {
        let tris: Vec<Tri> = indices
            .iter()
            .map(|&[a, b, c]| {
                let p = |i: u32| positions[i as usize].as_vec3a();
                [p(a), p(b) - p(a), p(c) - p(a)]
            })
            .collect();
        // Triangles whose box is not finite and within `MAX_COORDINATE` (a vertex beyond f32's
        // range, found by fuzzing) would break the BVH build's arithmetic; they are left out
        // of the BVH and can never be hit.
        let (mut aabbs, mut kept) = (Vec::with_capacity(tris.len()), Vec::with_capacity(tris.len()));
        for (i, t) in tris.iter().enumerate() {
            let b = Aabb::from_points(&[t[0], t[0] + t[1], t[0] + t[2]]);
            if is_sane(&b) {
                aabbs.push(b);
                kept.push(i as u32);
            }
        }
        let unplaced = tris.len() - kept.len();
        let kept_tris: Vec<Tri> = kept.iter().map(|&i| tris[i as usize]).collect();
        let bvh = Bvh8::build(&kept_tris, &aabbs, &kept);
        let mut bounds = Aabb::empty();
        for b in &aabbs {
            bounds = bounds.union(b);
        }
        MeshGeom { positions, indices, vertex_normals, uvs, bvh, bounds, unplaced }
    }

    /// How many of its triangles its BVH leaves out, having a vertex beyond
    /// [`MAX_COORDINATE`]: they can never be hit (the scene build warns about them).
    pub fn unplaced(&self) -> usize {
        self.unplaced
    }

    /// The triangles its BVH holds (the ones whose box the builder can take, see `with_uvs`)
    /// carried by `to_world` (if any), as (triangle index, `f32` vertex 0 and edges); a
    /// triangle whose carried box the builder cannot take is left out.
    pub fn bvh_triangles<'a>(
        &'a self,
        to_world: Option<&'a glam::DAffine3>,
    ) -> impl Iterator<Item = (u32, Tri)> + 'a {
        self.indices.iter().enumerate().filter_map(move |(i, &[a, b, c])| {
            let p = |i: u32| self.positions[i as usize].as_vec3a();
            let own = [p(a), p(b) - p(a), p(c) - p(a)];
            if !is_sane(&Aabb::from_points(&[own[0], own[0] + own[1], own[0] + own[2]])) {
                return None;
            }
            let t = match to_world {
                None => own,
                Some(m) => {
                    let w = |i: u32| m.transform_point3(self.positions[i as usize]);
                    let (w0, w1, w2) = (w(a), w(b), w(c));
                    [w0.as_vec3a(), (w1 - w0).as_vec3a(), (w2 - w0).as_vec3a()]
                }
            };
            is_sane(&Aabb::from_points(&[t[0], t[0] + t[1], t[0] + t[2]])).then_some((i as u32, t))
        })
    }

    /// An estimate of the bytes it holds (vertex arrays, triangles, normals, texture
    /// coordinates and its BVH), for memory-bounded caches.
    pub fn heap_bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + self.positions.capacity() * std::mem::size_of::<DVec3>()
            + self.indices.capacity() * std::mem::size_of::<[u32; 3]>()
            + self.vertex_normals.as_ref().map_or(0, |n| n.capacity() * std::mem::size_of::<DVec3>())
            + self.uvs.as_ref().map_or(0, |u| u.capacity() * std::mem::size_of::<DVec2>())
            + self.bvh.heap_bytes()
    }

    /// Whether no triangle is in the BVH (the mesh can never be hit).
    pub fn is_empty(&self) -> bool {
        self.bvh.is_empty()
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// Closest hit of an object-space `f32` ray; returns (t, triangle) with `f32` precision.
    #[inline]
    pub fn intersect_f32(&self, ray: obvhs::ray::Ray) -> Option<(f32, u32)> {
        self.bvh.intersect(&Ray8::new(ray.origin, ray.direction, ray.tmin, ray.tmax))
    }

    /// The BVH itself, for callers that prepare their own rays (its hits report triangle
    /// indices, as [`Self::intersect_f32`]'s do).
    #[inline]
    pub(super) fn tree(&self) -> &Bvh8 {
        &self.bvh
    }

    /// True if anything is hit in (tmin, tmax).
    #[inline]
    pub fn occluded_f32(&self, ray: obvhs::ray::Ray) -> bool {
        self.bvh.occluded(&Ray8::new(ray.origin, ray.direction, ray.tmin, ray.tmax))
    }

    /// Exact `f64` intersection of a triangle already known to be hit: distance, barycentrics
    /// (clamped into the triangle, since the `f32` test accepted it) and the face normal, whose
    /// square root and division overlap the intersection's.
    pub fn refine(&self, tri: u32, origin: DVec3, dir: DVec3) -> TriHit {
        let [a, b, c] = self.indices[tri as usize];
        let (p0, p1, p2) =
            (self.positions[a as usize], self.positions[b as usize], self.positions[c as usize]);
        let e1 = p1 - p0;
        let e2 = p2 - p0;
        let p = dir.cross(e2);
        let det = e1.dot(p);
        let inv = 1.0 / det;
        let s = origin - p0;
        let mut u = s.dot(p) * inv;
        let q = s.cross(e1);
        let mut v = dir.dot(q) * inv;
        let t = e2.dot(q) * inv;
        u = clamp(u, 0.0, 1.0);
        v = clamp(v, 0.0, 1.0 - u);
        TriHit { t, tri, u, v, normal: e1.cross(e2).normalize() }
    }

    /// [`Self::refine`] of eight hits side by side, then [`Self::smooth_normal`] at each one's
    /// barycentrics: hit `k` is triangle `tri[k]` along the ray of origin `o[·][k]` and
    /// direction `d[·][k]`. Each lane's operations are the single functions', in their order
    /// (glam's `cross`, `dot`, `normalize`, the clamps), so each lane has their bits; laid out
    /// a component at a time, the arithmetic compiles to vector instructions. `None` when the
    /// mesh has no vertex normals.
    #[inline]
    pub fn smooth_hits(&self, tri: &[u32; 8], o: &[[f64; 8]; 3], d: &[[f64; 8]; 3]) -> Option<SmoothHits> {
        let ns = self.vertex_normals.as_deref()?;
        // The three corners' positions and normals, by axis, then lane. A pixel's samples
        // mostly find one triangle: then its corners are read once and copied to every lane.
        let (mut p, mut n) = ([[[0.0; 8]; 3]; 3], [[[0.0; 8]; 3]; 3]);
        if tri.iter().all(|&t| t == tri[0]) {
            #[cfg(test)]
            super::tests::ONE_TRIANGLE_PACKETS.with(|c| c.set(c.get() + 1));
            let corners = self.indices[tri[0] as usize];
            for (c, &i) in corners.iter().enumerate() {
                let (q, m) = (self.positions[i as usize], ns[i as usize]);
                for a in 0..3 {
                    p[c][a] = [q[a]; 8];
                    n[c][a] = [m[a]; 8];
                }
            }
        } else {
            for (k, &t) in tri.iter().enumerate() {
                let corners = self.indices[t as usize];
                for (c, &i) in corners.iter().enumerate() {
                    let (q, m) = (self.positions[i as usize], ns[i as usize]);
                    for a in 0..3 {
                        p[c][a][k] = q[a];
                        n[c][a][k] = m[a];
                    }
                }
            }
        }
        fn lanes(f: impl FnMut(usize) -> f64) -> [f64; 8] {
            std::array::from_fn(f)
        }
        let sub = |x: &[[f64; 8]; 3], y: &[[f64; 8]; 3]| -> [[f64; 8]; 3] {
            std::array::from_fn(|a| std::array::from_fn(|k| x[a][k] - y[a][k]))
        };
        // glam's `cross` and `dot`, a lane at a time.
        let cross = |x: &[[f64; 8]; 3], y: &[[f64; 8]; 3]| -> [[f64; 8]; 3] {
            [
                std::array::from_fn(|k| x[1][k] * y[2][k] - y[1][k] * x[2][k]),
                std::array::from_fn(|k| x[2][k] * y[0][k] - y[2][k] * x[0][k]),
                std::array::from_fn(|k| x[0][k] * y[1][k] - y[0][k] * x[1][k]),
            ]
        };
        let dot = |x: &[[f64; 8]; 3], y: &[[f64; 8]; 3]| -> [f64; 8] {
            std::array::from_fn(|k| (x[0][k] * y[0][k]) + (x[1][k] * y[1][k]) + (x[2][k] * y[2][k]))
        };
        let e1 = sub(&p[1], &p[0]);
        let e2 = sub(&p[2], &p[0]);
        let pv = cross(d, &e2);
        let det = dot(&e1, &pv);
        let inv = lanes(|k| 1.0 / det[k]);
        let sv = sub(o, &p[0]);
        let su = dot(&sv, &pv);
        let q = cross(&sv, &e1);
        let (dq, eq) = (dot(d, &q), dot(&e2, &q));
        let u = lanes(|k| clamp(su[k] * inv[k], 0.0, 1.0));
        let v = lanes(|k| clamp(dq[k] * inv[k], 0.0, 1.0 - u[k]));
        let t = lanes(|k| eq[k] * inv[k]);
        // `normalize`: the product by the reciprocal of the length.
        let face = cross(&e1, &e2);
        let face_len = dot(&face, &face);
        let recip = lanes(|k| 1.0 / face_len[k].sqrt());
        let ng: [[f64; 8]; 3] = std::array::from_fn(|a| std::array::from_fn(|k| face[a][k] * recip[k]));
        // `smooth_normal`: the weights' sum of the corners' normals, divided by its length
        // (the face normal where that length is tiny).
        let w = lanes(|k| 1.0 - u[k] - v[k]);
        let sm: [[f64; 8]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|k| w[k] * n[0][a][k] + u[k] * n[1][a][k] + v[k] * n[2][a][k])
        });
        let sq = dot(&sm, &sm);
        let len = lanes(|k| sq[k].sqrt());
        let ns = std::array::from_fn(|a| {
            std::array::from_fn(|k| if len[k] > MIN_SMOOTH_LENGTH { sm[a][k] / len[k] } else { ng[a][k] })
        });
        Some(SmoothHits { t, ng, ns })
    }

    /// Texture coordinates at barycentrics (u, v) and the surface derivatives ∂p/∂u, ∂p/∂v
    /// (object space, §11.6a), or `None` when the mesh has no texture coordinates or the
    /// triangle's are degenerate.
    pub fn uv_frame(&self, tri: u32, u: f64, v: f64) -> Option<(DVec2, DVec3, DVec3)> {
        let uvs = self.uvs.as_ref()?;
        let [a, b, c] = self.indices[tri as usize];
        let (t0, t1, t2) = (uvs[a as usize], uvs[b as usize], uvs[c as usize]);
        let uv = (1.0 - u - v) * t0 + u * t1 + v * t2;
        let (p0, p1, p2) =
            (self.positions[a as usize], self.positions[b as usize], self.positions[c as usize]);
        let (e1, e2) = (p1 - p0, p2 - p0);
        let (d1, d2) = (t1 - t0, t2 - t0);
        let det = d1.x * d2.y - d2.x * d1.y;
        if det.abs() < 1e-300 {
            return Some((uv, DVec3::ZERO, DVec3::ZERO));
        }
        let dpdu = (d2.y * e1 - d1.y * e2) / det;
        let dpdv = (d1.x * e2 - d2.x * e1) / det;
        Some((uv, dpdu, dpdv))
    }

    /// Object-space geometric normal (unit, counter-clockwise winding).
    pub fn face_normal(&self, tri: u32) -> DVec3 {
        let [a, b, c] = self.indices[tri as usize];
        let (p0, p1, p2) =
            (self.positions[a as usize], self.positions[b as usize], self.positions[c as usize]);
        (p1 - p0).cross(p2 - p0).normalize()
    }

    /// Object-space interpolated vertex normal at barycentrics (u, v); the face normal when the
    /// mesh has no vertex normals.
    pub fn smooth_normal(&self, tri: u32, u: f64, v: f64) -> DVec3 {
        match &self.vertex_normals {
            Some(ns) => {
                let [a, b, c] = self.indices[tri as usize];
                let n = (1.0 - u - v) * ns[a as usize] + u * ns[b as usize] + v * ns[c as usize];
                let len = n.length();
                if len > MIN_SMOOTH_LENGTH { n / len } else { self.face_normal(tri) }
            }
            None => self.face_normal(tri),
        }
    }
}

/// Area-weighted vertex normals: each triangle adds its un-normalised cross product to its three
/// vertices (scene-format.md §9.2, the 2025 text's rule).
pub fn area_weighted_normals(positions: &[DVec3], indices: &[[u32; 3]]) -> Vec<DVec3> {
    let groups: Vec<u32> = (0..positions.len() as u32).collect();
    grouped_normals(positions, indices, &groups)
}

/// Area-weighted normals where vertices of the same `group` (the scene's vertex id, when a
/// vertex was split because its corners have different texture coordinates) share one normal.
pub fn grouped_normals(positions: &[DVec3], indices: &[[u32; 3]], groups: &[u32]) -> Vec<DVec3> {
    let n_groups = groups.iter().map(|&g| g as usize + 1).max().unwrap_or(0);
    let mut acc = vec![DVec3::ZERO; n_groups];
    for &[a, b, c] in indices {
        let (p0, p1, p2) = (positions[a as usize], positions[b as usize], positions[c as usize]);
        let n = (p1 - p0).cross(p2 - p0);
        for v in [a, b, c] {
            acc[groups[v as usize] as usize] += n;
        }
    }
    groups.iter().map(|&g| acc[g as usize].normalize_or_zero()).collect()
}

/// Removes triangles with a repeated index or zero area; returns how many were removed.
pub fn drop_degenerate(positions: &[DVec3], indices: &mut Vec<[u32; 3]>) -> usize {
    let before = indices.len();
    indices.retain(|&[a, b, c]| {
        if a == b || b == c || a == c {
            return false;
        }
        let (p0, p1, p2) = (positions[a as usize], positions[b as usize], positions[c as usize]);
        let n = (p1 - p0).cross(p2 - p0);
        n.length_squared() > 0.0 && n.is_finite()
    });
    before - indices.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ray in the triangle's plane from its first corner makes the re-intersection's
    /// determinant 0 and its `u` NaN (0 · ∞); `v`'s clamp to [0, 1 - u] then had a NaN bound,
    /// and `f64::clamp` panics on one.
    #[test]
    fn a_re_intersection_in_the_triangle_plane_does_not_panic() {
        let q = quad();
        let h = q.refine(0, q.positions[0], DVec3::X);
        assert!(h.u.is_nan(), "{h:?}");
        for x in [-0.5, 0.0, -0.0, 0.3, 1.0, 1.5, f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(clamp(x, 0.0, 1.0).to_bits(), x.clamp(0.0, 1.0).to_bits(), "{x}");
        }
        assert_eq!(clamp(0.25, 0.0, f64::NAN), 0.25);
    }

    fn quad() -> MeshGeom {
        let positions = vec![
            DVec3::new(-1.0, -1.0, 0.0),
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(-1.0, 1.0, 0.0),
        ];
        MeshGeom::new(positions, vec![[0, 1, 2], [0, 2, 3]], None)
    }

    fn fray(o: DVec3, d: DVec3) -> obvhs::ray::Ray {
        obvhs::ray::Ray::new(o.as_vec3a(), d.as_vec3a(), 0.0, f32::INFINITY)
    }

    #[test]
    fn hits_and_misses_a_quad() {
        let m = quad();
        let (t, tri) = m.intersect_f32(fray(DVec3::new(0.5, -0.5, 3.0), DVec3::NEG_Z)).unwrap();
        assert!((t - 3.0).abs() < 1e-6);
        assert_eq!(tri, 0);
        let h = m.refine(tri, DVec3::new(0.5, -0.5, 3.0), DVec3::NEG_Z);
        assert!((h.t - 3.0).abs() < 1e-12);
        assert_eq!(h.normal, m.face_normal(tri));
        assert!(m.intersect_f32(fray(DVec3::new(1.5, 0.0, 3.0), DVec3::NEG_Z)).is_none());
        // From behind: two-sided.
        assert!(m.intersect_f32(fray(DVec3::new(0.0, 0.2, -3.0), DVec3::Z)).is_some());
        assert!(m.occluded_f32(fray(DVec3::new(0.0, 0.2, -3.0), DVec3::Z)));
        assert_eq!(m.face_normal(0), DVec3::Z);
    }

    #[test]
    fn degenerate_triangles_are_dropped() {
        let p = vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::X * 2.0];
        let mut idx = vec![[0, 1, 2], [0, 0, 1], [0, 1, 3]];
        assert_eq!(drop_degenerate(&p, &mut idx), 2);
        assert_eq!(idx, vec![[0, 1, 2]]);
    }

    #[test]
    fn area_weighting_favours_large_faces() {
        // Vertex 0 is shared by a large face in the xy plane and a small one in the xz plane.
        let p = vec![DVec3::ZERO, DVec3::X * 10.0, DVec3::Y * 10.0, DVec3::NEG_Z * 0.1];
        let n = area_weighted_normals(&p, &[[0, 1, 2], [0, 3, 1]]);
        assert!(n[0].z > 0.99, "{:?}", n[0]);
    }
}
