//! The analytic shapes' exact ray tests in `f64` (spheres, one ray or eight side by side;
//! planes) and their texture frames: what [`super::Accel`] runs behind a sphere's or plane's
//! box, and where a textured hit on one gets its `uv` and tangents.

use glam::{DVec2, DVec3};

use crate::math::{Ray, Transform};

/// Smallest root in (tmin, tmax) of the sphere test, in the ray's own space.
#[inline]
pub(super) fn sphere_t(center: DVec3, radius: f64, r: &Ray, tmin: f64, tmax: f64) -> Option<f64> {
    let oc = r.origin - center;
    let a = r.dir.length_squared();
    let half_b = oc.dot(r.dir);
    let c = oc.length_squared() - radius * radius;
    let disc = half_b * half_b - a * c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // Numerically stable pair of roots.
    let q = -half_b - half_b.signum() * sq;
    let (mut t0, mut t1) = if q != 0.0 { (q / a, c / q) } else { (-half_b / a, -half_b / a) };
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    if t0 > tmin && t0 < tmax {
        Some(t0)
    } else if t1 > tmin && t1 < tmax {
        Some(t1)
    } else {
        None
    }
}

/// [`sphere_t`] of eight world-space rays side by side (origins `o`, directions `d`, by axis then lane) against the sphere (`center`,
/// `radius`) of an instance with transform `xf`, each lane within (tmin, `tmax[lane]`):
/// infinity where `sphere_t` says `None`, else its distance. Every lane's operations are those
/// of [`Transform::ray_to_object`] and `sphere_t`, in their order (so the same bits), without
/// branches: the compiler makes four-lane vector code of the transform, square root and
/// divisions. (`q / a` is `-half_b / a` bit for bit when `q` is zero: both are then a zero of
/// the same sign.)
#[inline(always)]
pub(super) fn sphere_lanes(
    center: DVec3,
    radius: f64,
    xf: Option<&Transform>,
    o: &[[f64; 8]; 3],
    d: &[[f64; 8]; 3],
    tmin: f64,
    tmax: &[f64; 8],
) -> [f64; 8] {
    let (ro, rd) = (o, d);
    let (mut o, mut d) = (*o, *d);
    if let Some(xf) = xf {
        let (m, tr) = (&xf.to_object.matrix3, xf.to_object.translation);
        for lane in 0..8 {
            let (x, y, z) = (ro[0][lane], ro[1][lane], ro[2][lane]);
            let (dx, dy, dz) = (rd[0][lane], rd[1][lane], rd[2][lane]);
            for a in 0..3 {
                o[a][lane] = m.x_axis[a] * x + m.y_axis[a] * y + m.z_axis[a] * z + tr[a];
                d[a][lane] = m.x_axis[a] * dx + m.y_axis[a] * dy + m.z_axis[a] * dz;
            }
        }
    }
    let r2 = radius * radius;
    let mut out = [f64::INFINITY; 8];
    for lane in 0..8 {
        let oc = [o[0][lane] - center.x, o[1][lane] - center.y, o[2][lane] - center.z];
        let dd = [d[0][lane], d[1][lane], d[2][lane]];
        let a = dd[0] * dd[0] + dd[1] * dd[1] + dd[2] * dd[2];
        let half_b = oc[0] * dd[0] + oc[1] * dd[1] + oc[2] * dd[2];
        let c = (oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2]) - r2;
        let disc = half_b * half_b - a * c;
        let sq = disc.sqrt();
        let q = -half_b - half_b.signum() * sq;
        let t0 = q / a;
        let t1 = if q != 0.0 { c / q } else { t0 };
        let (t0, t1) = if t0 > t1 { (t1, t0) } else { (t0, t1) };
        let t = if t0 > tmin && t0 < tmax[lane] {
            t0
        } else if t1 > tmin && t1 < tmax[lane] {
            t1
        } else {
            f64::INFINITY
        };
        out[lane] = if disc < 0.0 { f64::INFINITY } else { t };
    }
    out
}

/// The lanes whose segments (`tmin`, `tmax[lane]`) along unit directions may meet the sphere:
/// a lane left out is one [`sphere_lanes`] answers `INFINITY` for. A lane is left out only
/// when the segment's nearest point to the centre lies outside the sphere by a margin a
/// billion times the rounding of `sphere_lanes`' roots (which then lie at least that margin
/// beyond the segment's ends); NaNs keep a lane. No square root or division.
#[inline(always)]
pub(super) fn sphere_may_block(
    center: DVec3,
    radius: f64,
    o: &[[f64; 8]; 3],
    d: &[[f64; 8]; 3],
    tmin: f64,
    tmax: &[f64; 8],
) -> u32 {
    let r2 = radius * radius;
    let mut near = [false; 8];
    for lane in 0..8 {
        let oc = [o[0][lane] - center.x, o[1][lane] - center.y, o[2][lane] - center.z];
        let tc = -(oc[0] * d[0][lane] + oc[1] * d[1][lane] + oc[2] * d[2][lane]);
        let t = tc.max(tmin).min(tmax[lane]);
        let p = [oc[0] + d[0][lane] * t, oc[1] + d[1][lane] * t, oc[2] + d[2][lane] * t];
        let dist2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
        let scale = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] + r2 + t * t;
        let bound = r2 + 1e-9 * scale;
        // Kept unless clearly outside; NaN keeps it.
        near[lane] = (dist2 <= bound) | dist2.is_nan() | bound.is_nan();
    }
    crate::math::lane_bits(near)
}

/// Distance in (tmin, tmax) to the plane through `point` with normal `normal`, in the ray's own
/// space; `None` for rays parallel to it.
#[inline]
pub(super) fn plane_t(point: DVec3, normal: DVec3, r: &Ray, tmin: f64, tmax: f64) -> Option<f64> {
    let denom = normal.dot(r.dir);
    if denom == 0.0 || !denom.is_finite() {
        return None;
    }
    let t = (point - r.origin).dot(normal) / denom;
    (t > tmin && t < tmax).then_some(t)
}

/// Texture coordinates and ∂p/∂u, ∂p/∂v of a plane at object-space offset `d` from its point:
/// distances along a fixed unit tangent pair (u along the axis least aligned with the normal,
/// projected into the plane), so a texture repeats with period 1 in object units.
pub(super) fn plane_uv_frame(d: DVec3, n: DVec3) -> (DVec2, DVec3, DVec3) {
    let a = n.abs();
    let axis = if a.x <= a.y && a.x <= a.z {
        DVec3::X
    } else if a.y <= a.z {
        DVec3::Y
    } else {
        DVec3::Z
    };
    let t = (axis - n * n.dot(axis)).normalize_or_zero();
    let b = n.cross(t);
    (DVec2::new(d.dot(t), d.dot(b)), t, b)
}

/// Texture coordinates and ∂p/∂u, ∂p/∂v of a sphere at object-space offset `d` from its centre
/// (§11.4, §11.6a): θ from +Y, φ = atan2(z, x), u = (π - φ)/2π, v = θ/π.
pub(super) fn sphere_uv_frame(d: DVec3, r: f64) -> (DVec2, DVec3, DVec3) {
    let theta = (d.y / r).clamp(-1.0, 1.0).acos();
    let phi = d.z.atan2(d.x);
    let uv =
        DVec2::new((std::f64::consts::PI - phi) / (2.0 * std::f64::consts::PI), theta / std::f64::consts::PI);
    let pi = std::f64::consts::PI;
    let dpdu = DVec3::new(2.0 * pi * d.z, 0.0, -2.0 * pi * d.x);
    let dpdv = DVec3::new(pi * d.y * phi.cos(), -pi * r * theta.sin(), pi * d.y * phi.sin());
    (uv, dpdu, dpdv)
}
