//! Cameras: the course's image-plane construction (scene-format.md §4.2-4.3).

#[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
use std::arch::x86_64::*;

use glam::DVec3;

use crate::math::{Ray, v3};
use crate::scene::records::{CameraRec, Handedness, LensRec, Projection, TonemapRec};

/// A camera ready to generate primary rays.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub id: String,
    pub position: DVec3,
    /// Right, up, backward (w = -gaze).
    pub u: DVec3,
    pub v: DVec3,
    pub w: DVec3,
    /// Top-left corner of the image plane.
    pub corner: DVec3,
    /// Image-plane extent per pixel along u and v.
    pub pixel_w: f64,
    pub pixel_h: f64,
    /// Angle (radians, small-angle) one pixel subtends at the image centre: the larger of
    /// pixel_w, pixel_h over the near distance. Trilinear texture lookups grow a ray cone of this
    /// spread from the camera (§11.5); 0 if the frame is degenerate.
    pub pixel_spread: f64,
    pub width: u32,
    pub height: u32,
    pub image_name: String,
    pub num_samples: u32,
    /// 2019 `ClampSamples`: the most a sample may add to a pixel, per channel.
    pub clamp_samples: Option<f64>,
    /// Thin lens (depth of field); `None` for a pinhole.
    pub lens: Option<LensRec>,
    /// How an HDR output is also written as PNG (empty: the photographic defaults).
    pub tonemaps: Vec<TonemapRec>,
    /// Classic ray tracing or path tracing (§13.1).
    pub renderer: crate::scene::records::Renderer,
}

impl Camera {
    /// `None` when the gaze and up vectors do not define a frame (zero or parallel).
    ///
    /// The record's vectors are taken as they are: its `Transformations` (§10.4) are applied by
    /// [`crate::scene::build::build_scene`] and [`crate::scene::build::build_cameras`] before they
    /// call this; use those.
    pub fn from_record(c: &CameraRec) -> Option<Camera> {
        let gaze = v3(c.gaze);
        let up = v3(c.up);
        if gaze.length_squared() == 0.0 || up.length_squared() == 0.0 {
            return None;
        }
        let w = -gaze.normalize();
        let mut u = up.normalize().cross(w);
        if u.length_squared() < 1e-24 {
            return None;
        }
        u = u.normalize();
        let v = w.cross(u);
        if c.handedness == Handedness::Left {
            u = -u;
        }
        let d = c.near_distance;
        let (l, r, b, t) = match c.projection {
            Projection::NearPlane { left, right, bottom, top } => (left, right, bottom, top),
            Projection::FovY(deg) => {
                let t = d * (deg.to_radians() / 2.0).tan();
                let r = t * c.width as f64 / c.height as f64;
                (-r, r, -t, t)
            }
        };
        let position = v3(c.position);
        let m = position - d * w;
        let corner = m + l * u + t * v;
        Some(Camera {
            id: c.id.clone(),
            position,
            u,
            v,
            w,
            corner,
            pixel_w: (r - l) / c.width as f64,
            pixel_h: (t - b) / c.height as f64,
            pixel_spread: {
                let s = ((r - l) / c.width as f64).abs().max(((t - b) / c.height as f64).abs()) / d.abs();
                if s.is_finite() { s } else { 0.0 }
            },
            width: c.width,
            height: c.height,
            image_name: c.image_name.clone(),
            num_samples: c.num_samples.max(1),
            clamp_samples: c.clamp_samples,
            lens: c.lens,
            tonemaps: c.tonemaps.clone(),
            renderer: c.renderer,
        })
    }

    /// Primary ray through image position (x + dx, y + dy), pixel (x, y) counted from the top left,
    /// `dx, dy` in [0, 1) (0.5 = pixel centre).
    #[inline]
    pub fn ray(&self, x: u32, y: u32, dx: f64, dy: f64) -> Ray {
        Ray::new(self.position, (self.image_point(x, y, dx, dy) - self.position).normalize())
    }

    /// The directions of [`Camera::ray`] through image positions (`x[k]` + `dx[k]`, `y[k]` +
    /// `dy[k]`) of eight lanes (pixels given as `f64`; one pixel's samples or one sample of
    /// several pixels), written into `d` by axis then lane (every ray starts at `position`). Each
    /// lane's operations are `ray`'s in their order (no fused multiply-adds), so the bits are
    /// the same; with AVX they run four lanes to an instruction (the compiler left the lanes'
    /// arithmetic scalar), without it each lane is `ray`'s.
    #[inline(always)]
    pub fn ray_dirs8(&self, x: &[f64; 8], y: &[f64; 8], dx: &[f64; 8], dy: &[f64; 8], d: &mut [[f64; 8]; 3]) {
        #[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
        for h in [0, 4] {
            avx_store_unit(avx_image_offsets(self, (x, y), (dx, dy), h), d, h);
        }
        #[cfg(not(all(target_arch = "x86_64", target_feature = "avx")))]
        for k in 0..8 {
            let dir = self.ray(x[k] as u32, y[k] as u32, dx[k], dy[k]).dir;
            for (row, v) in d.iter_mut().zip(dir.to_array()) {
                row[k] = v;
            }
        }
    }

    /// [`Camera::lens_ray`] of eight lanes side by side: lane `k` through image position
    /// (`x[k]` + `dx[k]`, `y[k]` + `dy[k]`) and lens point (`xi1[k]`, `xi2[k]`), its origin
    /// written into `o` and its direction into `d`, by axis then lane. Each lane's operations
    /// are `lens_ray`'s in their order (no fused multiply-adds), so the bits are the same; with
    /// AVX four lanes go to an instruction. A pinhole camera's rays ([`Camera::ray`]) start at
    /// its position.
    #[inline(always)]
    pub fn lens_rays8(
        &self,
        (x, y): (&[f64; 8], &[f64; 8]),
        (dx, dy): (&[f64; 8], &[f64; 8]),
        (xi1, xi2): (&[f64; 8], &[f64; 8]),
        o: &mut [[f64; 8]; 3],
        d: &mut [[f64; 8]; 3],
    ) {
        let Some(lens) = self.lens else {
            *o = self.position.to_array().map(|c| [c; 8]);
            return self.ray_dirs8(x, y, dx, dy, d);
        };
        #[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
        {
            let (u, v, p, nw) =
                (self.u.to_array(), self.v.to_array(), self.position.to_array(), (-self.w).to_array());
            // SAFETY: the target has AVX (cfg above); these intrinsics touch no memory.
            unsafe {
                let all = _mm256_set1_pd;
                let (half, size) = (all(0.5), all(lens.aperture_size));
                for h in [0, 4] {
                    // `lens_ray`'s `s`, its focus point and its lens point, then the unit direction.
                    let s = avx_image_offsets(self, (x, y), (dx, dy), h);
                    let dot = _mm256_add_pd(
                        _mm256_add_pd(_mm256_mul_pd(s[0], all(nw[0])), _mm256_mul_pd(s[1], all(nw[1]))),
                        _mm256_mul_pd(s[2], all(nw[2])),
                    );
                    let k = _mm256_div_pd(all(lens.focus_distance), dot);
                    let su = _mm256_mul_pd(size, _mm256_sub_pd(avx_load(xi1, h), half));
                    let sv = _mm256_mul_pd(size, _mm256_sub_pd(avx_load(xi2, h), half));
                    let t: [__m256d; 3] = std::array::from_fn(|i| {
                        let focus = _mm256_add_pd(all(p[i]), _mm256_mul_pd(k, s[i]));
                        let origin = _mm256_add_pd(
                            _mm256_add_pd(all(p[i]), _mm256_mul_pd(su, all(u[i]))),
                            _mm256_mul_pd(sv, all(v[i])),
                        );
                        avx_store(origin, &mut o[i], h);
                        _mm256_sub_pd(focus, origin)
                    });
                    avx_store_unit(t, d, h);
                }
            }
        }
        #[cfg(not(all(target_arch = "x86_64", target_feature = "avx")))]
        for k in 0..8 {
            // `lens_ray` finds the lens itself.
            let _ = lens;
            let r = self.lens_ray(x[k] as u32, y[k] as u32, dx[k], dy[k], xi1[k], xi2[k]);
            for a in 0..3 {
                (o[a][k], d[a][k]) = (r.origin[a], r.dir[a]);
            }
        }
    }

    /// The point of the image plane at image position (x + dx, y + dy).
    #[inline]
    fn image_point(&self, x: u32, y: u32, dx: f64, dy: f64) -> DVec3 {
        self.corner + ((x as f64 + dx) * self.pixel_w) * self.u - ((y as f64 + dy) * self.pixel_h) * self.v
    }

    /// Like [`Camera::ray`], through the lens point (ξ1, ξ2) ∈ [0, 1)² of a thin-lens camera
    /// (scene-format.md §4.6: a square aperture of side ApertureSize, focus plane at
    /// FocusDistance along the gaze). A pinhole camera ignores the lens point.
    #[inline]
    pub fn lens_ray(&self, x: u32, y: u32, dx: f64, dy: f64, xi1: f64, xi2: f64) -> Ray {
        let Some(lens) = self.lens else { return self.ray(x, y, dx, dy) };
        // The pinhole ray's focus point; its direction need not be unit for that (one square
        // root and division fewer per sample).
        let s = self.image_point(x, y, dx, dy) - self.position;
        let focus = self.position + (lens.focus_distance / s.dot(-self.w)) * s;
        let a = lens.aperture_size;
        let origin = self.position + a * (xi1 - 0.5) * self.u + a * (xi2 - 0.5) * self.v;
        Ray::new(origin, (focus - origin).normalize())
    }
}

// Four lanes of the camera's eight-lane ray making with AVX (`avx_*`), each lane's operations
// those of the one-ray functions in their order (no fused multiply-adds), so the bits are the
// same.

/// Lanes `h..h + 4` of `a` (`h` is 0 or 4).
#[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
#[inline(always)]
fn avx_load(a: &[f64; 8], h: usize) -> __m256d {
    let lanes = &a[h..h + 4];
    // SAFETY: the target has AVX (cfg above); `lanes` holds the four elements read.
    unsafe { _mm256_loadu_pd(lanes.as_ptr()) }
}

/// `v` into lanes `h..h + 4` of `a`.
#[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
#[inline(always)]
fn avx_store(v: __m256d, a: &mut [f64; 8], h: usize) {
    let lanes = &mut a[h..h + 4];
    // SAFETY: the target has AVX (cfg above); `lanes` holds the four elements written.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), v) }
}

/// `image_point(x, y, dx, dy) - position` of lanes `h..h + 4`, by axis.
#[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
#[inline(always)]
fn avx_image_offsets(
    cam: &Camera,
    (x, y): (&[f64; 8], &[f64; 8]),
    (dx, dy): (&[f64; 8], &[f64; 8]),
    h: usize,
) -> [__m256d; 3] {
    let (c, u, v, o) = (cam.corner.to_array(), cam.u.to_array(), cam.v.to_array(), cam.position.to_array());
    // SAFETY: the target has AVX (cfg above); these intrinsics touch no memory.
    unsafe {
        let all = _mm256_set1_pd;
        let a = _mm256_mul_pd(_mm256_add_pd(avx_load(x, h), avx_load(dx, h)), all(cam.pixel_w));
        let b = _mm256_mul_pd(_mm256_add_pd(avx_load(y, h), avx_load(dy, h)), all(cam.pixel_h));
        std::array::from_fn(|i| {
            let p = _mm256_add_pd(all(c[i]), _mm256_mul_pd(a, all(u[i])));
            _mm256_sub_pd(_mm256_sub_pd(p, _mm256_mul_pd(b, all(v[i]))), all(o[i]))
        })
    }
}

/// `t` normalised as glam's `normalize` does (times `1 / sqrt(dot)`), into lanes `h..h + 4`
/// of `d`, by axis.
#[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
#[inline(always)]
fn avx_store_unit(t: [__m256d; 3], d: &mut [[f64; 8]; 3], h: usize) {
    // SAFETY: the target has AVX (cfg above); these intrinsics touch no memory.
    unsafe {
        let sq = |x: __m256d| _mm256_mul_pd(x, x);
        let len2 = _mm256_add_pd(_mm256_add_pd(sq(t[0]), sq(t[1])), sq(t[2]));
        let recip = _mm256_div_pd(_mm256_set1_pd(1.0), _mm256_sqrt_pd(len2));
        for (row, ti) in d.iter_mut().zip(t) {
            avx_store(_mm256_mul_pd(ti, recip), row, h);
        }
    }
}

/// The largest `scale` a render may take: a scale shrinks a frame, never enlarges it.
pub const MAX_SCALE: f64 = 1.0;

/// A render's `scale` (`--scale`, a job's `scale`) as it may be: a number in (0, 1].
pub fn check_scale(scale: f64) -> Result<f64, String> {
    if scale.is_finite() && scale > 0.0 && scale <= MAX_SCALE {
        Ok(scale)
    } else {
        Err(format!(
            "must be a number in (0, {MAX_SCALE}], the factor each side of the image is multiplied by \
             (e.g. 0.25 renders an 800x450 camera at 200x113); found {scale}"
        ))
    }
}

/// `width` x `height` multiplied by `scale`: each side rounded to the nearest pixel (halves
/// up: 450 x 0.25 = 112.5 gives 113), at least 1 pixel.
pub fn scaled_size(width: u32, height: u32, scale: f64) -> (u32, u32) {
    let side = |n: u32| ((f64::from(n) * scale).round() as u32).clamp(1, n.max(1));
    (side(width), side(height))
}

impl Camera {
    /// This camera rendering `scale` times as many pixels a side ([`scaled_size`]): the image
    /// plane stays where it is, so the picture is the same, only coarser. Scale 1 (or a size
    /// that rounds to the same) is the camera itself, bit for bit.
    pub fn scaled(&self, scale: f64) -> Camera {
        let (width, height) = scaled_size(self.width, self.height, scale);
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        let pixel_w = self.pixel_w * f64::from(self.width) / f64::from(width);
        let pixel_h = self.pixel_h * f64::from(self.height) / f64::from(height);
        // The spread is the larger pixel side over the near distance: it grows as they do.
        let old = self.pixel_w.abs().max(self.pixel_h.abs());
        let spread = if old > 0.0 { self.pixel_spread * pixel_w.abs().max(pixel_h.abs()) / old } else { 0.0 };
        Camera {
            pixel_w,
            pixel_h,
            pixel_spread: if spread.is_finite() { spread } else { 0.0 },
            width,
            height,
            ..self.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_scaled_camera_keeps_its_image_plane_with_fewer_pixels() {
        assert_eq!(super::scaled_size(800, 450, 0.25), (200, 113));
        assert_eq!(super::scaled_size(800, 450, 1.0), (800, 450));
        assert_eq!(super::scaled_size(3, 1, 1e-9), (1, 1));
        for bad in [0.0, -0.5, 1.5, f64::NAN, f64::INFINITY] {
            assert!(super::check_scale(bad).is_err(), "{bad}");
        }
        assert_eq!(super::check_scale(0.25), Ok(0.25));
        let c = Camera::from_record(&rec(
            Projection::NearPlane { left: -2.0, right: 2.0, bottom: -1.0, top: 1.0 },
            Handedness::Right,
        ))
        .unwrap();
        let small = c.scaled(0.25);
        assert_eq!((small.width, small.height), super::scaled_size(c.width, c.height, 0.25));
        // The same frame: its corners are the same rays.
        for (x, y, sx, sy) in [(0, 0, 0, 0), (c.width, c.height, small.width, small.height)] {
            assert!((c.ray(x, y, 0.0, 0.0).dir - small.ray(sx, sy, 0.0, 0.0).dir).length() < 1e-12);
        }
        assert_eq!(c.scaled(1.0), c);
    }

    use super::*;
    use crate::Loc;

    fn rec(projection: Projection, handedness: Handedness) -> CameraRec {
        CameraRec {
            id: "1".into(),
            loc: Loc::default(),
            position: [0.0, 0.0, 0.0],
            gaze: [0.0, 0.0, -1.0],
            up: [0.0, 1.0, 0.0],
            transforms: Vec::new(),
            projection,
            near_distance: 1.0,
            width: 100,
            height: 50,
            image_name: "x.png".into(),
            handedness,
            num_samples: 1,
            clamp_samples: None,
            lens: None,
            tonemaps: Vec::new(),
            renderer: Default::default(),
        }
    }

    #[test]
    fn lens_rays_meet_on_the_focus_plane() {
        let mut r =
            rec(Projection::NearPlane { left: -1.0, right: 1.0, bottom: -1.0, top: 1.0 }, Handedness::Right);
        r.lens = Some(LensRec { focus_distance: 7.0, aperture_size: 2.0 });
        let c = Camera::from_record(&r).unwrap();
        // Every lens point's ray through pixel (30, 10) reaches the same point at z = -7.
        let target = c.ray(30, 10, 0.5, 0.5);
        let focus = target.at(7.0 / target.dir.dot(DVec3::NEG_Z));
        for (a, b) in [(0.0, 0.0), (0.99, 0.2), (0.5, 0.5), (0.1, 0.9)] {
            let ray = c.lens_ray(30, 10, 0.5, 0.5, a, b);
            let t = (focus.z - ray.origin.z) / ray.dir.z;
            assert!((ray.at(t) - focus).length() < 1e-9);
            assert!(ray.origin.z == 0.0 && ray.origin.x.abs() <= 1.0 && ray.origin.y.abs() <= 1.0);
        }
    }

    #[test]
    fn lane_directions_are_those_of_single_rays() {
        let mut r = rec(Projection::FovY(37.0), Handedness::Left);
        r.position = [0.3, -1.7, 2.9];
        r.gaze = [0.2, -0.4, -1.0];
        r.up = [0.1, 1.0, 0.3];
        r.width = 801;
        r.height = 333;
        let c = Camera::from_record(&r).unwrap();
        let mut bits = 0x2545_f491_4f6c_dd1du64;
        let mut unit = || {
            bits ^= bits << 13;
            bits ^= bits >> 7;
            bits ^= bits << 17;
            (bits >> 11) as f64 / (1u64 << 53) as f64
        };
        // One pixel's eight samples, and eight pixels of a row (the last one wrapping).
        let one = |x: u32, y: u32| ([x; 8], [y; 8]);
        let row = |x: u32, y: u32| (std::array::from_fn(|k| (x + k as u32) % 801), [y; 8]);
        for (xs, ys) in [one(0, 0), one(400, 166), one(800, 332), one(13, 297), row(795, 3), row(0, 332)] {
            let dx: [f64; 8] = std::array::from_fn(|_| unit());
            let dy: [f64; 8] = std::array::from_fn(|_| unit());
            let mut d = [[f64::NAN; 8]; 3];
            c.ray_dirs8(&xs.map(f64::from), &ys.map(f64::from), &dx, &dy, &mut d);
            for k in 0..8 {
                let single = c.ray(xs[k], ys[k], dx[k], dy[k]).dir;
                assert_eq!(
                    [d[0][k], d[1][k], d[2][k]].map(f64::to_bits),
                    single.to_array().map(f64::to_bits)
                );
            }
        }
    }

    #[test]
    fn lens_lanes_are_the_single_lens_rays_bit_for_bit() {
        let mut r = rec(Projection::FovY(41.0), Handedness::Right);
        r.position = [1.3, 4.7, -2.9];
        r.gaze = [-0.3, -0.2, -1.0];
        r.up = [0.05, 1.0, 0.2];
        r.width = 640;
        r.height = 397;
        let mut bits = 0x9e37_79b9_7f4a_7c15u64;
        let mut unit = || {
            bits ^= bits << 13;
            bits ^= bits >> 7;
            bits ^= bits << 17;
            (bits >> 11) as f64 / (1u64 << 53) as f64
        };
        for (focus, size) in [(21.0, 1.5), (0.37, 0.01), (1e4, 40.0)] {
            r.lens = Some(LensRec { focus_distance: focus, aperture_size: size });
            let c = Camera::from_record(&r).unwrap();
            for (x, y) in [(0u32, 0u32), (639, 396), (320, 11), (17, 300)] {
                let lanes: [[f64; 8]; 4] = std::array::from_fn(|_| std::array::from_fn(|_| unit()));
                let (mut o, mut d) = ([[f64::NAN; 8]; 3], [[f64::NAN; 8]; 3]);
                let (xs, ys) = ([f64::from(x); 8], [f64::from(y); 8]);
                c.lens_rays8((&xs, &ys), (&lanes[0], &lanes[1]), (&lanes[2], &lanes[3]), &mut o, &mut d);
                for k in 0..8 {
                    let single = c.lens_ray(x, y, lanes[0][k], lanes[1][k], lanes[2][k], lanes[3][k]);
                    let bits = |v: [f64; 3]| v.map(f64::to_bits);
                    assert_eq!(bits([o[0][k], o[1][k], o[2][k]]), bits(single.origin.to_array()));
                    assert_eq!(bits([d[0][k], d[1][k], d[2][k]]), bits(single.dir.to_array()));
                }
            }
        }
    }

    #[test]
    fn centre_pixel_looks_along_gaze_and_corners_follow_nearplane() {
        let c = Camera::from_record(&rec(
            Projection::NearPlane { left: -2.0, right: 2.0, bottom: -1.0, top: 1.0 },
            Handedness::Right,
        ))
        .unwrap();
        let r = c.ray(50, 25, 0.0, 0.0);
        assert!((r.dir - DVec3::NEG_Z).length() < 1e-12);
        // Top-left pixel's corner is at (l, t, -d).
        let r = c.ray(0, 0, 0.0, 0.0);
        assert!((r.dir - DVec3::new(-2.0, 1.0, -1.0).normalize()).length() < 1e-12);
        let left = Camera::from_record(&rec(
            Projection::NearPlane { left: -2.0, right: 2.0, bottom: -1.0, top: 1.0 },
            Handedness::Left,
        ))
        .unwrap();
        assert!((left.ray(0, 0, 0.0, 0.0).dir - DVec3::new(2.0, 1.0, -1.0).normalize()).length() < 1e-12);
    }

    #[test]
    fn fovy_gives_symmetric_frustum_with_aspect() {
        let c = Camera::from_record(&rec(Projection::FovY(90.0), Handedness::Right)).unwrap();
        // t = tan(45°) = 1, r = 2 (aspect 2:1).
        let r = c.ray(0, 0, 0.0, 0.0);
        assert!((r.dir - DVec3::new(-2.0, 1.0, -1.0).normalize()).length() < 1e-12);
    }

    #[test]
    fn degenerate_frame_is_rejected() {
        let mut r = rec(Projection::FovY(60.0), Handedness::Right);
        r.up = [0.0, 0.0, 2.0];
        assert!(Camera::from_record(&r).is_none());
    }
}
