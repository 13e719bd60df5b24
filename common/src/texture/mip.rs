//! Mip-mapped (`Interpolation trilinear`) image lookups, scene-format.md §11.5.
//!
//! No shipped course scene uses trilinear and the 2025 reference's footprint estimate is
//! unknown, so this is the textbook method, kept deterministic and cheap:
//!
//! * **Pyramid** — built once per image at scene build, only for images that a trilinear map
//!   uses ([`MipChain::new`]). Each level halves the previous one, `W' = max(1, ⌊W/2⌋)` (likewise
//!   `H`), down to 1x1, with a box filter: an output texel averages the previous level's texels
//!   under its footprint, weighted by overlap. For even sizes that is the plain 2x2 average; odd
//!   (non-power-of-two) sizes get fractional weights over a 2.5-texel box, so every level keeps
//!   the image's mean exactly and no texel is dropped.
//! * **Alignment** — the course's lookup puts texel `p` at `i = u·W = p` (no half-texel shift,
//!   see `texture::image`). A level-`k` texel averages a box of level-0 texels, so its value
//!   belongs at the box's centre; level `k` is therefore read at
//!   `i_k = u·W_k − ½(1 − W_k/W)` (and likewise `j`), which keeps every level registered with
//!   level 0 and leaves level 0 itself untouched.
//! * **Level** — the caller gives the pixel's footprint on the surface as extents `(Δu, Δv)` in
//!   texture coordinates (the integrator derives it from a ray cone: the camera pixel's spread
//!   angle × the distance travelled, projected onto the surface and mapped through ∂p/∂u,
//!   ∂p/∂v). The level is `λ = log2(max(Δu·W, Δv·H))`, the number of level-0 texels across the
//!   footprint along its longer texture axis (isotropic, like GPU trilinear without anisotropy:
//!   blurry rather than aliased at grazing angles).
//! * **Filter** — λ ≤ 0 (magnification, or no footprint) is exactly the bilinear lookup of
//!   level 0; otherwise bilinear in levels ⌊λ⌋ and ⌊λ⌋ + 1, mixed linearly by λ − ⌊λ⌋; past the
//!   last level, the 1x1 level (the image mean).

use std::sync::Arc;

use glam::DVec2;

use super::image::{TextureImage, texel_space, wrap01};

/// An image with its box-filtered halvings, for trilinear lookups.
#[derive(Clone, Debug)]
pub struct MipChain {
    /// Level 0, shared with the texture maps that read the image directly.
    base: Arc<TextureImage>,
    /// Levels 1, 2, … down to 1x1 (empty for a 1x1 image, or an inconsistent one).
    levels: Vec<TextureImage>,
}

impl MipChain {
    /// Builds every level of `base` (a third more memory than the image itself). An image whose
    /// texel count does not match its size gets no levels (lookups then read level 0 only).
    pub fn new(base: Arc<TextureImage>) -> MipChain {
        let mut levels: Vec<TextureImage> = Vec::new();
        let consistent = base.width >= 1
            && base.height >= 1
            && base.texels.len() as u64 == u64::from(base.width) * u64::from(base.height);
        if consistent {
            let mut prev: &TextureImage = &base;
            while prev.width > 1 || prev.height > 1 {
                let next = halve(prev);
                levels.push(next);
                prev = levels.last().expect("just pushed");
            }
        }
        MipChain { base, levels }
    }

    /// Number of levels including level 0.
    pub fn len(&self) -> usize {
        self.levels.len() + 1
    }

    /// Always false: level 0 is always there (for clippy's `len` without `is_empty` lint).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Level `k` (0 = the image itself); the last level for `k` past it.
    pub fn level(&self, k: usize) -> &TextureImage {
        match k {
            0 => &self.base,
            _ => self.levels.get(k - 1).or(self.levels.last()).unwrap_or(&self.base),
        }
    }

    /// The continuous level λ for a footprint of `(Δu, Δv)` in texture coordinates (see the
    /// module notes); negative for magnification, −∞ for no footprint, never NaN.
    pub fn lod(&self, footprint: DVec2) -> f64 {
        let texels = (footprint.x.abs() * f64::from(self.base.width))
            .max(footprint.y.abs() * f64::from(self.base.height));
        let l = texels.log2();
        if l.is_nan() { 0.0 } else { l }
    }

    /// Trilinear lookup at `(u, v)` (wrapped by repeat) for a footprint of `(Δu, Δv)`.
    pub fn trilinear(&self, u: f64, v: f64, footprint: DVec2) -> [f64; 3] {
        let lod = self.lod(footprint);
        if lod <= 0.0 {
            return self.base.bilinear(u, v);
        }
        let last = (self.len() - 1) as f64;
        if lod >= last {
            return self.sample(self.len() - 1, u, v);
        }
        let k = lod.floor();
        let f = lod - k;
        let (a, b) = (self.sample(k as usize, u, v), self.sample(k as usize + 1, u, v));
        std::array::from_fn(|c| a[c] + f * (b[c] - a[c]))
    }

    /// Bilinear lookup in level `k`, registered with level 0 (the ½(1 − W_k/W) shift).
    fn sample(&self, k: usize, u: f64, v: f64) -> [f64; 3] {
        let img = self.level(k);
        let (i, j) = texel_space(wrap01(u), wrap01(v), img.width, img.height);
        let sx = 0.5 * (1.0 - f64::from(img.width) / f64::from(self.base.width));
        let sy = 0.5 * (1.0 - f64::from(img.height) / f64::from(self.base.height));
        img.bilinear_texel(i - sx, j - sy)
    }
}

/// The next level: `max(1, ⌊n/2⌋)` texels per axis, each the overlap-weighted box average of
/// the texels of `src` it covers. `src` must be consistent (texels = width × height).
fn halve(src: &TextureImage) -> TextureImage {
    let (w, h) = (src.width as usize, src.height as usize);
    let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
    let wx = box_weights(w, nw);
    let wy = box_weights(h, nh);
    // Rows first (nw x h), then columns (nw x nh); sums in f64.
    let mut rows = vec![[0.0f64; 3]; nw * h];
    for y in 0..h {
        let line = &src.texels[y * w..(y + 1) * w];
        for (x, taps) in wx.iter().enumerate() {
            let mut acc = [0.0f64; 3];
            for &(p, wt) in taps {
                for c in 0..3 {
                    acc[c] += wt * f64::from(line[p][c]);
                }
            }
            rows[y * nw + x] = acc;
        }
    }
    let mut texels = vec![[0.0f32; 3]; nw * nh];
    for (y, taps) in wy.iter().enumerate() {
        for x in 0..nw {
            let mut acc = [0.0f64; 3];
            for &(q, wt) in taps {
                for c in 0..3 {
                    acc[c] += wt * rows[q * nw + x][c];
                }
            }
            texels[y * nw + x] = acc.map(|a| a as f32);
        }
    }
    TextureImage { width: nw as u32, height: nh as u32, texels }
}

/// For each of `m` output texels over `n >= m` input texels, the inputs under its box
/// `[x·n/m, (x+1)·n/m)` with their overlap as a fraction of the box (the weights sum to 1).
fn box_weights(n: usize, m: usize) -> Vec<Vec<(usize, f64)>> {
    let s = n as f64 / m as f64;
    (0..m)
        .map(|x| {
            let (a, b) = (x as f64 * s, (x + 1) as f64 * s);
            let first = a.floor() as usize;
            let last = (b.ceil() as usize).min(n);
            (first..last)
                .filter_map(|p| {
                    let overlap = (b.min(p as f64 + 1.0) - a.max(p as f64)) / s;
                    (overlap > 1e-12).then_some((p, overlap))
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> f32) -> Arc<TextureImage> {
        let texels = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| [f(x, y); 3]).collect();
        Arc::new(TextureImage { width: w, height: h, texels })
    }

    fn mean(img: &TextureImage) -> f64 {
        img.texels.iter().map(|t| f64::from(t[0])).sum::<f64>() / img.texels.len() as f64
    }

    #[test]
    fn power_of_two_levels_are_2x2_averages() {
        let img = image(4, 2, |x, y| (x + 4 * y) as f32);
        let chain = MipChain::new(img);
        assert_eq!(chain.len(), 3);
        let l1 = chain.level(1);
        assert_eq!((l1.width, l1.height), (2, 1));
        // (0 + 1 + 4 + 5) / 4 and (2 + 3 + 6 + 7) / 4.
        assert_eq!(l1.texels, vec![[2.5; 3], [4.5; 3]]);
        let l2 = chain.level(2);
        assert_eq!((l2.width, l2.height), (1, 1));
        assert_eq!(l2.texels, vec![[3.5; 3]]);
        // Past the last level: the last level.
        assert_eq!(chain.level(9).texels, l2.texels);
    }

    #[test]
    fn odd_sizes_keep_the_mean_and_end_at_1x1() {
        for (w, h) in [(5, 3), (7, 1), (1, 9), (6, 5), (13, 11)] {
            let img = image(w, h, |x, y| ((x * 7 + y * 13) % 11) as f32);
            let m0 = mean(&img);
            let chain = MipChain::new(img);
            for k in 1..chain.len() {
                let l = chain.level(k);
                assert!((mean(l) - m0).abs() < 1e-4, "{w}x{h} level {k}: mean {} vs {m0}", mean(l));
            }
            let last = chain.level(chain.len() - 1);
            assert_eq!((last.width, last.height), (1, 1), "{w}x{h}");
        }
        // 5 -> 2 texels: each averages 2.5 of the source's.
        let chain = MipChain::new(image(5, 1, |x, _| x as f32));
        let l1 = chain.level(1);
        assert!((l1.texels[0][0] - (0.0 + 1.0 + 0.5 * 2.0) / 2.5).abs() < 1e-6);
        assert!((l1.texels[1][0] - (0.5 * 2.0 + 3.0 + 4.0) / 2.5).abs() < 1e-6);
    }

    #[test]
    fn no_footprint_is_bilinear_on_level_0() {
        let img = image(8, 8, |x, y| ((x * 37 + y * 101) % 256) as f32);
        let chain = MipChain::new(img.clone());
        for (u, v) in [(0.1, 0.2), (0.73, 0.41), (0.999, 0.0), (-0.3, 1.7)] {
            for fp in [DVec2::ZERO, DVec2::new(0.5 / 8.0, 0.9 / 8.0)] {
                assert_eq!(chain.trilinear(u, v, fp), img.bilinear(u, v), "({u}, {v}) footprint {fp}");
            }
        }
    }

    #[test]
    fn levels_blend_linearly_and_a_huge_footprint_gives_the_mean() {
        // A checkerboard of 0 and 255: its 2x2 averages are already the mean.
        let img = image(16, 16, |x, y| if (x + y) % 2 == 0 { 0.0 } else { 255.0 });
        let chain = MipChain::new(img.clone());
        let (u, v) = (3.0 / 16.0, 5.0 / 16.0);
        // One texel per footprint: level 0, the texel itself.
        assert_eq!(chain.trilinear(u, v, DVec2::splat(1.0 / 16.0))[0], 0.0);
        // 1.5 texels: λ = log2 1.5 ≈ 0.585, between the texel (0) and level 1 (127.5).
        let lod = 1.5f64.log2();
        let got = chain.trilinear(u, v, DVec2::splat(1.5 / 16.0))[0];
        assert!((got - lod * 127.5).abs() < 1e-9, "{got}");
        // 2 texels or more: the mean.
        for texels in [2.0, 3.0, 16.0, 1e6] {
            let got = chain.trilinear(u, v, DVec2::new(texels / 16.0, 0.0))[0];
            assert!((got - 127.5).abs() < 1e-9, "{texels} texels: {got}");
        }
        // The longer texture axis decides.
        assert_eq!(chain.lod(DVec2::new(1.0 / 16.0, 4.0 / 16.0)), 2.0);
        // Garbage footprints read level 0.
        for fp in [DVec2::new(f64::NAN, 0.0), DVec2::NAN, DVec2::ZERO] {
            assert!(chain.lod(fp) <= 0.0, "{fp}");
            assert_eq!(chain.trilinear(u, v, fp), img.bilinear(u, v), "{fp}");
        }
    }

    #[test]
    fn coarser_levels_stay_registered_with_level_0() {
        // A linear ramp along u is reproduced by every level (box averages of a ramp are the
        // ramp at the box centre), so with the alignment shift the lookup does not drift.
        let img = image(64, 4, |x, _| x as f32);
        let chain = MipChain::new(img.clone());
        for u in [0.2, 0.37, 0.5, 0.61] {
            let want = img.bilinear(u, 0.5)[0];
            for k in 1..5 {
                let got = chain.sample(k, u, 0.5)[0];
                assert!((got - want).abs() < 1e-4, "u {u} level {k}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn inconsistent_images_do_not_panic() {
        let bad = Arc::new(TextureImage { width: 4, height: 4, texels: vec![[1.0; 3]; 3] });
        let chain = MipChain::new(bad);
        assert_eq!(chain.len(), 1);
        let _ = chain.trilinear(0.5, 0.5, DVec2::splat(10.0));
    }
}
