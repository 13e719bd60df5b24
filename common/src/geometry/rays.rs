//! Rays side by side (structure of arrays, eight lanes by axis): how a group's rays are handed
//! to [`super::Accel`]'s packet queries, and the hits its lane queries give back.

use glam::{DVec3, Vec3A};
use obvhs::aabb::Aabb;

use crate::math::Ray;

/// Up to eight `f64` rays side by side (unused lanes repeat the first ray): what a group's
/// `f32` lanes ([`super::bvh8::Lanes8`]) are converted from, and what eight-lane tests in `f64` (spheres) read.
#[derive(Clone)]
pub struct RayLanes {
    /// Origins and directions, by axis then lane.
    pub(crate) o: [[f64; 8]; 3],
    pub(crate) d: [[f64; 8]; 3],
    /// How many lanes hold a ray.
    pub(crate) len: usize,
}

impl RayLanes {
    /// One to eight rays, by axis then lane (a loop of fixed length). Always inlined: built in
    /// the caller's frame, not copied there.
    #[inline(always)]
    pub fn new(rays: &[Ray]) -> Self {
        let len = rays.len();
        assert!((1..=8).contains(&len), "one to eight rays");
        let mut l = RayLanes { o: [[0.0; 8]; 3], d: [[0.0; 8]; 3], len };
        for lane in 0..8 {
            let r = &rays[if lane < len { lane } else { 0 }];
            for a in 0..3 {
                l.o[a][lane] = r.origin[a];
                l.d[a][lane] = r.dir[a];
            }
        }
        l
    }

    /// The first `len` (one to eight) of the rays from `origin` along `d` (directions by axis,
    /// then lane): camera rays made side by side, which need not be gathered from [`Ray`]s.
    #[inline(always)]
    pub fn from_origin(origin: DVec3, d: &[[f64; 8]; 3], len: usize) -> Self {
        let mut l = RayLanes { o: origin.to_array().map(|c| [c; 8]), d: [[0.0; 8]; 3], len: 1 };
        l.refill_dirs(len, |to| *to = *d);
        l
    }

    /// New directions for these rays from one origin ([`Self::from_origin`]'s): `fill` writes
    /// them (by axis, then lane) where they are kept, the first `len` (one to eight) in use.
    #[inline(always)]
    pub fn refill_dirs(&mut self, len: usize, fill: impl FnOnce(&mut [[f64; 8]; 3])) {
        assert!((1..=8).contains(&len), "one to eight rays");
        fill(&mut self.d);
        self.len = len;
        for a in 0..3 {
            for lane in len..8 {
                self.d[a][lane] = self.d[a][0];
            }
        }
    }

    /// New origins and directions for these rays: `fill` writes both (by axis, then lane)
    /// where they are kept, the first `len` (one to eight) in use.
    #[inline(always)]
    pub fn refill(&mut self, len: usize, fill: impl FnOnce(&mut [[f64; 8]; 3], &mut [[f64; 8]; 3])) {
        assert!((1..=8).contains(&len), "one to eight rays");
        fill(&mut self.o, &mut self.d);
        self.len = len;
        for a in 0..3 {
            for lane in len..8 {
                self.o[a][lane] = self.o[a][0];
                self.d[a][lane] = self.d[a][0];
            }
        }
    }

    /// Lane `k`'s origin.
    #[inline(always)]
    pub fn origin(&self, k: usize) -> DVec3 {
        DVec3::new(self.o[0][k], self.o[1][k], self.o[2][k])
    }

    /// Lane `k`'s direction.
    #[inline(always)]
    pub fn dir(&self, k: usize) -> DVec3 {
        DVec3::new(self.d[0][k], self.d[1][k], self.d[2][k])
    }

    /// Whether lane `k` holds `ray`'s origin and direction, bit for bit.
    pub(crate) fn holds(&self, k: usize, ray: &Ray) -> bool {
        (0..3).all(|a| {
            self.o[a][k].to_bits() == ray.origin[a].to_bits()
                && self.d[a][k].to_bits() == ray.dir[a].to_bits()
        })
    }
}

/// Eight rays by axis, then lane.
pub type Axes = [[f64; 8]; 3];

/// The closest hits of eight rays, by lane (see [`super::Accel::closest_lanes`]).
#[derive(Clone, Copy, Debug)]
pub struct HitLanes {
    /// The lanes that hit something.
    pub mask: u32,
    /// The hit point, `origin + dir * t` as [`crate::math::Ray::at`] makes it.
    pub point: Axes,
    /// The unit geometric normal, which is also the shading normal (flat faces and spheres).
    pub normal: Axes,
    /// The distance along the ray ([`crate::geometry::SurfaceHit::t`]).
    pub t: [f64; 8],
    pub material: [u32; 8],
    pub instance: [u32; 8],
}

// ---- Single rays: the conversions and small rules the queries share ----

/// `r` between `tmin` and `tmax` in `f32`, for obvhs's box tests and the meshes' `f32` walks.
/// A ray whose origin or direction is not finite in `f32` (an `f64` value beyond its range: a
/// mesh instance moved or shrunk by an enormous transformation or motion blur sees the world's
/// rays from that far) becomes a ray at the origin with an empty interval (from +inf to -inf):
/// a mesh's walk misses it whatever far bound a caller sets, and a box test that lets an
/// instance through only leads to that instance's own test of the real ray, so no
/// surface is found that the ray does not meet. Its own values would have missed as well (their
/// tests compare infinities and NaNs), but obvhs's rays must be finite (`Ray::new` asserts it
/// where assertions are on, as in the fuzzers' builds).
#[inline]
pub(super) fn to_f32_ray(r: &Ray, tmin: f64, tmax: f64) -> obvhs::ray::Ray {
    let (o, d) = (r.origin.as_vec3a(), r.dir.as_vec3a());
    if o.is_finite() && d.is_finite() {
        obvhs::ray::Ray::new(o, d, tmin as f32, tmax as f32)
    } else {
        obvhs::ray::Ray::new(Vec3A::ZERO, Vec3A::X, f32::INFINITY, f32::NEG_INFINITY)
    }
}

/// Whether `fr` enters box `b` before `fr.tmax`. obvhs's `intersect_ray` answers a miss with
/// +inf, which `<= fr.tmax` alone lets through when the ray is unbounded (every camera ray,
/// every shadow ray to an infinitely far light): those tested every instance exactly.
#[inline]
pub(super) fn enters(b: &Aabb, fr: &obvhs::ray::Ray) -> bool {
    let t = b.intersect_ray(fr);
    t < f32::INFINITY && t <= fr.tmax
}

/// Grows a box by a relative epsilon so `f32` rounding never culls a surface lying on it.
pub(super) fn pad(b: Aabb) -> Aabb {
    let e = (b.max - b.min).abs().max(b.min.abs()).max(b.max.abs()) * 1e-5 + Vec3A::splat(1e-6);
    Aabb::new(b.min - e, b.max + e)
}

/// The `f64` re-intersection's distance `t64`, or the walk's `f32` one `t32` where the
/// re-intersection degenerated (a grazing ray: not finite, or not ahead).
#[inline(always)]
pub(super) fn refined_t(t64: f64, t32: f64) -> f64 {
    if t64.is_finite() && t64 > 0.0 { t64 } else { t32 }
}

/// `n` turned to the side of `reference` (a smooth normal leaning past its face, a bump axis
/// opposite the shading normal).
#[inline(always)]
pub(super) fn side_of(n: DVec3, reference: DVec3) -> DVec3 {
    if n.dot(reference) < 0.0 { -n } else { n }
}
