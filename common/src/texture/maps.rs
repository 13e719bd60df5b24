//! Texture maps at render time: image lookups, the course's Perlin noise, 3-D checkerboards,
//! and how a map's value enters shading (scene-format.md §11).

use std::sync::Arc;

use glam::{DVec2, DVec3};

use super::image::TextureImage;
use super::mip::MipChain;
use crate::scene::records::{DecalMode, Interpolation, NoiseConversion};

/// Where a map's values come from.
#[derive(Clone, Debug)]
pub enum Source {
    /// `mips` is the image's pyramid, built at scene build when `interpolation` is trilinear
    /// (`None` otherwise; a trilinear map without one reads bilinear).
    Image {
        image: Arc<TextureImage>,
        mips: Option<Arc<MipChain>>,
        interpolation: Interpolation,
        normalizer: f64,
        /// Clamp-to-edge addressing (2019 `<Appearance>clamp`): texture coordinates outside
        /// [0, 1] take the border texels, at every mip level; otherwise they repeat.
        clamp: bool,
    },
    Perlin {
        conversion: NoiseConversion,
        scale: f64,
        /// Octaves of the fractal sum ([`fractal_noise`]); 1 is plain noise.
        octaves: u32,
    },
    Checkerboard {
        black: DVec3,
        white: DVec3,
        scale: f64,
        offset: f64,
        /// `false`: a 2-D checkerboard in the texture coordinates ([`checkerboard_uv`]).
        dimension3: bool,
    },
}

/// A texture map ready for shading.
#[derive(Clone, Debug)]
pub struct TextureMap {
    pub source: Source,
    pub decal: DecalMode,
    pub bump_factor: f64,
    /// `Some(gamma)` when `degamma="true"`: values are raised to `gamma` after normalising.
    pub degamma: Option<f64>,
}

/// What a surface point offers a texture lookup.
#[derive(Clone, Copy, Debug)]
pub struct TexturePoint {
    pub uv: DVec2,
    /// Object-space position: the hit point before the object's transformations and motion
    /// (for a MeshInstance, in its base mesh's vertex space). Perlin noise and checkerboards are
    /// solid textures evaluated here (§11.9-11.10), so the pattern moves and scales with the object.
    pub object: DVec3,
    /// Extent of the pixel's footprint on the surface in texture coordinates (Δu, Δv): picks
    /// the mip level of trilinear maps (zero: level 0). See [`crate::texture::mip`].
    pub footprint: DVec2,
}

impl TextureMap {
    /// Whether lookups depend on [`TexturePoint::footprint`] (trilinear image maps).
    pub fn needs_footprint(&self) -> bool {
        matches!(self.source, Source::Image { interpolation: Interpolation::Trilinear, .. })
    }

    /// Raw image texel value at `uv` through the map's interpolation, before normalising;
    /// `footprint` (Δu, Δv) only matters to trilinear maps.
    fn image_raw(
        image: &TextureImage,
        mips: Option<&MipChain>,
        interpolation: Interpolation,
        clamp: bool,
        uv: DVec2,
        footprint: DVec2,
    ) -> DVec3 {
        let uv = if clamp { clamp_to_edge(uv) } else { uv };
        let t = match (interpolation, mips) {
            (Interpolation::Nearest, _) => image.nearest(uv.x, uv.y),
            (Interpolation::Trilinear, Some(m)) => m.trilinear(uv.x, uv.y, footprint),
            (Interpolation::Bilinear | Interpolation::Trilinear, _) => image.bilinear(uv.x, uv.y),
        };
        DVec3::from_array(t)
    }

    /// The map's colour value `T` at a point (§11.3): image texel / Normalizer, Perlin grey,
    /// or checkerboard colour; degamma applied.
    pub fn value(&self, p: &TexturePoint) -> DVec3 {
        let v = match &self.source {
            Source::Image { image, mips, interpolation, normalizer, clamp } => {
                Self::image_raw(image, mips.as_deref(), *interpolation, *clamp, p.uv, p.footprint)
                    / *normalizer
            }
            Source::Perlin { conversion, scale, octaves } => {
                DVec3::splat(perlin_value(p.object * *scale, *conversion, *octaves))
            }
            Source::Checkerboard { black, white, scale, offset, dimension3: true } => {
                checkerboard(p.object, *scale, *offset, *black, *white)
            }
            Source::Checkerboard { black, white, scale, offset, dimension3: false } => {
                checkerboard_uv(p.uv, *scale, *offset, *black, *white)
            }
        };
        match self.degamma {
            Some(g) => v.max(DVec3::ZERO).powf(g),
            None => v,
        }
    }

    /// Background value for screen position `uv` (§11.8): the raw texel, no normaliser.
    /// `footprint` is one pixel's extent in uv, (1/width, 1/height) of the frame.
    pub fn background(&self, uv: DVec2, footprint: DVec2) -> DVec3 {
        match &self.source {
            Source::Image { image, mips, interpolation, clamp, .. } => {
                Self::image_raw(image, mips.as_deref(), *interpolation, *clamp, uv, footprint)
            }
            _ => self.value(&TexturePoint { uv, object: DVec3::new(uv.x, uv.y, 0.0), footprint }),
        }
    }

    /// A tangent-space normal from a normal map (`replace_normal`, §11.6a): texel/255 mapped
    /// to [-1, 1]. `None` for maps that are not images.
    pub fn tangent_normal(&self, uv: DVec2, footprint: DVec2) -> Option<DVec3> {
        match &self.source {
            Source::Image { image, mips, interpolation, clamp, .. } => {
                let t =
                    Self::image_raw(image, mips.as_deref(), *interpolation, *clamp, uv, footprint) / 255.0;
                Some(t * 2.0 - DVec3::ONE)
            }
            _ => None,
        }
    }
}

/// Height of an image bump map: mean of R, G, B over the Normalizer, looked up with the map's
/// interpolation at `p.uv` offset by (du, dv). A trilinear map reads the level of
/// `p.footprint`, so its slopes are those of the filtered height field.
pub fn image_height(source: &Source, p: &TexturePoint, du: f64, dv: f64) -> f64 {
    match source {
        Source::Image { image, mips, interpolation, normalizer, clamp } => {
            let t = TextureMap::image_raw(
                image,
                mips.as_deref(),
                *interpolation,
                *clamp,
                p.uv + DVec2::new(du, dv),
                p.footprint,
            );
            (t.x + t.y + t.z) / 3.0 / normalizer
        }
        _ => 0.0,
    }
}

/// Clamp-to-edge addressing: each coordinate into [0, 1), so the lookups' repeat wrapping
/// leaves it alone and a coordinate at or past 1 reads the last texel (NaN stays NaN, which the
/// lookups read as 0). Bilinear neighbours and mip levels are clamped at the border already.
fn clamp_to_edge(uv: DVec2) -> DVec2 {
    // The largest f64 below 1.
    const BELOW_ONE: f64 = 1.0 - f64::EPSILON / 2.0;
    let c = |t: f64| if t.is_nan() { t } else { t.clamp(0.0, BELOW_ONE) };
    DVec2::new(c(uv.x), c(uv.y))
}

/// The 2019 checkerboard with `<Dimension3>false`: the 3-D rule of [`checkerboard`] on the
/// texture coordinates (u, v) alone (the course material gives no 2-D rule; this is the 3-D
/// one with the third axis dropped).
pub fn checkerboard_uv(uv: DVec2, scale: f64, offset: f64, black: DVec3, white: DVec3) -> DVec3 {
    let cell = |c: f64| -> bool { (((c + offset) * scale) as i64) % 2 != 0 };
    if cell(uv.x) != cell(uv.y) { black } else { white }
}

/// The course's checkerboard (§11.10): C-style truncation and remainder, at the object-space
/// point `p` (measured on the official VeachAjar image: its floor is scaled by 1.8 along x, and
/// world-space points get 45 % of the floor's pixels wrong).
pub fn checkerboard(p: DVec3, scale: f64, offset: f64, black: DVec3, white: DVec3) -> DVec3 {
    let cell = |c: f64| -> bool { (((c + offset) * scale) as i64) % 2 != 0 };
    if (cell(p.x) != cell(p.y)) != cell(p.z) { black } else { white }
}

/// The 16 gradient directions of the course's Perlin noise (§11.9).
const GRADIENTS: [[f64; 3]; 16] = [
    [1.0, 1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [1.0, -1.0, 0.0],
    [-1.0, -1.0, 0.0],
    [1.0, 0.0, 1.0],
    [-1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
    [-1.0, 0.0, -1.0],
    [0.0, 1.0, 1.0],
    [0.0, -1.0, 1.0],
    [0.0, 1.0, -1.0],
    [0.0, -1.0, -1.0],
    [1.0, 1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [0.0, -1.0, 1.0],
    [0.0, -1.0, -1.0],
];

/// A fixed permutation of 0..15. The reference renderer's table is unknown (it is random per
/// run), so Perlin scenes match the references in character, not pixel for pixel; a fixed
/// table keeps our renders deterministic.
const PERMUTATION: [usize; 16] = [9, 4, 13, 0, 7, 15, 2, 11, 5, 14, 1, 8, 12, 3, 10, 6];

#[inline]
fn phi(i: i64) -> usize {
    PERMUTATION[(i.unsigned_abs() % 16) as usize]
}

/// The course's smooth weight: 1 - 6|t|^5 + 15|t|^4 - 10|t|^3 for |t| < 1.
#[inline]
fn weight(t: f64) -> f64 {
    let a = t.abs();
    if a >= 1.0 { 0.0 } else { 1.0 - a * a * a * (a * (a * 6.0 - 15.0) + 10.0) }
}

/// Course Perlin noise in [-1, 1] (§11.9).
pub fn perlin(p: DVec3) -> f64 {
    let base = p.floor();
    let (bx, by, bz) = (base.x as i64, base.y as i64, base.z as i64);
    let mut sum = 0.0;
    for corner in 0..8 {
        let (cx, cy, cz) = (bx + (corner & 1), by + ((corner >> 1) & 1), bz + ((corner >> 2) & 1));
        let g = GRADIENTS[phi(cx + phi(cy + phi(cz) as i64) as i64)];
        let d = p - DVec3::new(cx as f64, cy as f64, cz as f64);
        sum += (g[0] * d.x + g[1] * d.y + g[2] * d.z) * weight(d.x) * weight(d.y) * weight(d.z);
    }
    sum
}

/// `NumOctaves` (2025): the fractal sum Σ_{i<octaves} 2^-i · noise(2^i · p), octave i at
/// frequency 2^i and amplitude 2^-i; one octave is [`perlin`] itself (0 counts as 1).
pub fn fractal_noise(p: DVec3, octaves: u32) -> f64 {
    let mut sum = perlin(p);
    let (mut freq, mut amp) = (1.0, 1.0);
    for _ in 1..octaves {
        freq *= 2.0;
        amp *= 0.5;
        sum += amp * perlin(p * freq);
    }
    sum
}

/// Noise (a fractal sum of `octaves`) converted as `NoiseConversion` asks: [0, 1] for one
/// octave; the conversion is applied to the sum, not clamped.
pub fn perlin_value(p: DVec3, conversion: NoiseConversion, octaves: u32) -> f64 {
    let n = fractal_noise(p, octaves);
    match conversion {
        NoiseConversion::Linear => (n + 1.0) / 2.0,
        NoiseConversion::AbsVal => n.abs(),
    }
}

/// Gradient of a solid (Perlin) height field at the object-space point `p`, by forward
/// differences, in object space.
pub fn perlin_gradient(p: DVec3, scale: f64, conversion: NoiseConversion, octaves: u32) -> DVec3 {
    const EPS: f64 = 1e-3;
    let h = |q: DVec3| perlin_value(q * scale, conversion, octaves);
    let h0 = h(p);
    DVec3::new(h(p + DVec3::X * EPS) - h0, h(p + DVec3::Y * EPS) - h0, h(p + DVec3::Z * EPS) - h0) / EPS
}

/// Perturbs the unit normal `n` by a height-field gradient `grad` (§11.7), both in world
/// space: the gradient's tangential part is subtracted, scaled by the bump factor.
pub fn bump_by_gradient(n: DVec3, grad: DVec3, factor: f64) -> DVec3 {
    let tangential = grad - grad.dot(n) * n;
    let bent = n - factor * tangential;
    if bent.length_squared() > 0.0 { bent.normalize() } else { n }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perlin_is_zero_on_lattice_points_and_bounded() {
        for p in [DVec3::ZERO, DVec3::new(3.0, -2.0, 7.0), DVec3::new(-5.0, 0.0, 1.0)] {
            assert!(perlin(p).abs() < 1e-12);
        }
        let mut r = crate::sampler::Sampler::new(1, 2, 3, 4);
        for _ in 0..10_000 {
            let p = DVec3::new(r.next_1d(), r.next_1d(), r.next_1d()) * 40.0 - DVec3::splat(20.0);
            let n = perlin(p);
            assert!((-1.0..=1.0).contains(&n), "{n} at {p}");
            assert!((0.0..=1.0).contains(&perlin_value(p, NoiseConversion::Linear, 1)));
        }
    }

    #[test]
    fn perlin_is_continuous() {
        let p = DVec3::new(1.3, 2.7, -0.4);
        let q = p + DVec3::splat(1e-7);
        assert!((perlin(p) - perlin(q)).abs() < 1e-5);
    }

    #[test]
    fn weight_matches_the_course_polynomial() {
        assert_eq!(weight(0.0), 1.0);
        assert_eq!(weight(1.0), 0.0);
        assert!((weight(0.5) - (1.0 - 6.0 / 32.0 + 15.0 / 16.0 - 10.0 / 8.0)).abs() < 1e-15);
        assert_eq!(weight(-0.5), weight(0.5));
    }

    #[test]
    fn checkerboard_truncates_like_c() {
        let (b, w) = (DVec3::ZERO, DVec3::ONE);
        // Cells of size 1 with scale 1: (0.5, 0.5, 0.5) -> all 0 -> white; x in [1,2) -> black.
        assert_eq!(checkerboard(DVec3::splat(0.5), 1.0, 0.0, b, w), w);
        assert_eq!(checkerboard(DVec3::new(1.5, 0.5, 0.5), 1.0, 0.0, b, w), b);
        // Truncation toward zero: -0.5 and 0.5 fall in the same cell.
        assert_eq!(checkerboard(DVec3::new(-0.5, 0.5, 0.5), 1.0, 0.0, b, w), w);
        // -1.5 -> -1 % 2 = -1, non-zero -> odd.
        assert_eq!(checkerboard(DVec3::new(-1.5, 0.5, 0.5), 1.0, 0.0, b, w), b);
    }

    /// A 4x2 image whose texel (x, y) is 10·x + 100·y, as a map with `interpolation`.
    fn ramp_map(interpolation: Interpolation, clamp: bool) -> TextureMap {
        let texels = (0..2).flat_map(|y| (0..4).map(move |x| [(10 * x + 100 * y) as f32; 3])).collect();
        let image = Arc::new(TextureImage { width: 4, height: 2, texels });
        let mips = Some(Arc::new(MipChain::new(image.clone())));
        TextureMap {
            source: Source::Image { image, mips, interpolation, normalizer: 1.0, clamp },
            decal: DecalMode::ReplaceKd,
            bump_factor: 1.0,
            degamma: None,
        }
    }

    fn at(map: &TextureMap, u: f64, v: f64, footprint: f64) -> f64 {
        let p =
            TexturePoint { uv: DVec2::new(u, v), object: DVec3::ZERO, footprint: DVec2::splat(footprint) };
        map.value(&p).x
    }

    /// `<Appearance>clamp`: past the edges the border texels are stretched (nearest, bilinear,
    /// and every mip level of trilinear); repeat wraps around instead.
    #[test]
    fn clamp_addressing_stretches_the_border_texels() {
        for interpolation in [Interpolation::Nearest, Interpolation::Bilinear, Interpolation::Trilinear] {
            let clamped = ramp_map(interpolation, true);
            let repeated = ramp_map(interpolation, false);
            // Right of the image: the last column (30 on row 0, 130 on row 1).
            assert_eq!(at(&clamped, 1.7, 0.0, 0.0), 30.0, "{interpolation:?}");
            assert_eq!(at(&clamped, 1.0, 0.6, 0.0), 130.0, "{interpolation:?}");
            assert_eq!(at(&clamped, 25.0, 7.0, 0.0), 130.0, "{interpolation:?}");
            // Left of and above it: the first column, the first row.
            assert_eq!(at(&clamped, -0.7, 0.0, 0.0), 0.0, "{interpolation:?}");
            assert_eq!(at(&clamped, 0.0, -3.0, 0.0), 0.0, "{interpolation:?}");
            // Inside, clamp and repeat agree.
            assert_eq!(at(&clamped, 0.3, 0.3, 0.0), at(&repeated, 0.3, 0.3, 0.0), "{interpolation:?}");
            // Repeat: u = 1.25 is u = 0.25.
            assert_eq!(at(&repeated, 1.25, 0.1, 0.0), at(&repeated, 0.25, 0.1, 0.0), "{interpolation:?}");
            assert_ne!(at(&repeated, 1.25, 0.1, 0.0), at(&clamped, 1.25, 0.1, 0.0), "{interpolation:?}");
            // Degenerate coordinates stay finite.
            assert!(at(&clamped, f64::NAN, f64::INFINITY, 0.0).is_finite());
        }
        // A footprint of the whole image reads the coarsest level (the mean, 65) wherever it is.
        let clamped = ramp_map(Interpolation::Trilinear, true);
        assert!((at(&clamped, 3.0, -2.0, 4.0) - 65.0).abs() < 1e-9);
        // A coarser level is clamped too: level 1 is 2x1 texels (the 2x2 means 55 and 75); far
        // right it reads its last texel.
        let lvl1 = at(&clamped, 9.0, 0.5, 0.5);
        assert!((lvl1 - 75.0).abs() < 1e-9, "{lvl1}");
    }

    /// `NumOctaves`: octave i at frequency 2^i and amplitude 2^-i, summed; one octave is the
    /// plain noise.
    #[test]
    fn octaves_add_finer_noise_at_half_the_amplitude() {
        let mut r = crate::sampler::Sampler::new(5, 6, 7, 8);
        for _ in 0..200 {
            let p = DVec3::new(r.next_1d(), r.next_1d(), r.next_1d()) * 20.0 - DVec3::splat(10.0);
            assert_eq!(fractal_noise(p, 1), perlin(p));
            assert_eq!(fractal_noise(p, 0), perlin(p));
            let three = perlin(p) + 0.5 * perlin(p * 2.0) + 0.25 * perlin(p * 4.0);
            assert!((fractal_noise(p, 3) - three).abs() < 1e-12);
            assert_eq!(perlin_value(p, NoiseConversion::AbsVal, 3), three.abs());
        }
        // On lattice points every octave is zero.
        assert_eq!(fractal_noise(DVec3::new(2.0, -1.0, 3.0), 8), 0.0);
    }

    /// `<Dimension3>false`: the checkerboard in (u, v), whatever the 3-D point.
    #[test]
    fn two_dimensional_checkerboard_uses_the_texture_coordinates() {
        let (b, w) = (DVec3::ZERO, DVec3::ONE);
        let map = TextureMap {
            source: Source::Checkerboard { black: b, white: w, scale: 4.0, offset: 0.0, dimension3: false },
            decal: DecalMode::ReplaceKd,
            bump_factor: 1.0,
            degamma: None,
        };
        let at = |u: f64, v: f64, object: DVec3| {
            map.value(&TexturePoint { uv: DVec2::new(u, v), object, footprint: DVec2::ZERO })
        };
        // Cells of a quarter: (0.1, 0.1) white, (0.3, 0.1) black, (0.3, 0.3) white.
        for object in [DVec3::ZERO, DVec3::new(1.5, 0.5, 7.3)] {
            assert_eq!(at(0.1, 0.1, object), w);
            assert_eq!(at(0.3, 0.1, object), b);
            assert_eq!(at(0.1, 0.3, object), b);
            assert_eq!(at(0.3, 0.3, object), w);
        }
        assert_eq!(checkerboard_uv(DVec2::new(0.3, 0.1), 4.0, 0.0, b, w), b);
    }

    #[test]
    fn perlin_bump_keeps_unit_length_and_flat_fields_unbent() {
        let n = DVec3::Y;
        let g = perlin_gradient(DVec3::new(0.3, 0.0, 0.7), 3.0, NoiseConversion::Linear, 1);
        let bent = bump_by_gradient(n, g, 1.0);
        assert!((bent.length() - 1.0).abs() < 1e-12);
        assert_ne!(bent, n);
        assert_eq!(bump_by_gradient(n, g, 0.0), n);
        // A gradient along the normal does not bend it.
        assert_eq!(bump_by_gradient(n, DVec3::new(0.0, 5.0, 0.0), 1.0), n);
    }
}
