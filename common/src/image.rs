//! Float images, their pixel rectangles ([`TileRect`]) and their LDR conversion.

use crate::protocol::Rect;

/// A rectangle of pixels, `x0, y0` from the top-left corner of the frame: what
/// [`render_tile`](crate::render::render_tile) renders and [`Image::put_tile`] puts in place.
/// The farm's wire twin is [`Rect`]; they convert both ways with `From`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TileRect {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

impl TileRect {
    /// The index in a row-major frame `frame_width` pixels wide of the first pixel of each of
    /// the rectangle's rows, top to bottom.
    pub fn row_starts(self, frame_width: u32) -> impl Iterator<Item = usize> {
        (self.y0 as usize..(self.y0 + self.height) as usize)
            .map(move |y| y * frame_width as usize + self.x0 as usize)
    }
}

impl From<Rect> for TileRect {
    fn from(r: Rect) -> Self {
        TileRect { x0: r.x0, y0: r.y0, width: r.width, height: r.height }
    }
}

impl From<TileRect> for Rect {
    fn from(r: TileRect) -> Self {
        Rect { x0: r.x0, y0: r.y0, width: r.width, height: r.height }
    }
}

/// Whether all three channels of a pixel are finite (not NaN, not infinite). The tests joined
/// with `&`, not `all`'s early exit, so that a loop of them over an image vectorises.
#[inline]
pub fn is_finite_pixel(p: &[f32; 3]) -> bool {
    p[0].is_finite() & p[1].is_finite() & p[2].is_finite()
}

/// A linear float RGB image, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

impl Image {
    pub fn new(width: u32, height: u32) -> Self {
        Image { width, height, pixels: vec![[0.0; 3]; (width as usize) * (height as usize)] }
    }

    /// Copies a rendered tile into place.
    pub fn put_tile(&mut self, r: TileRect, px: &[[f32; 3]]) {
        let w = r.width as usize;
        for (row, start) in r.row_starts(self.width).enumerate() {
            self.pixels[start..start + w].copy_from_slice(&px[row * w..(row + 1) * w]);
        }
    }

    /// 8-bit RGB as the course's LDR output: clamp to [0, 255], then truncate (a C cast); NaN
    /// -> 0. Measured against the official images, truncation is what the course's renderer
    /// does, although scene-format.md §12.1 says "rounded": on deterministic scenes our pixels
    /// were never below the reference and 27-44 % of channels one above it when rounding, and
    /// truncating makes two_spheres identical and bunny 111 dB after the 4x4 box (62 dB
    /// rounding), cube_point 102 dB (54), cornellbox_boxes_dynamic 53.6 (50.7, at 16 spp).
    pub fn to_ldr(&self) -> Vec<u8> {
        // In vector instructions, eight channels at a time: a max and a min that make NaN 0
        // (their comparisons are false for it), the truncation, and the integer read from the
        // low mantissa bits of k + 2^23, exact for every integer k in [0, 255]. (`as u8` is
        // the same rule but compiled to scalar code with saturation checks.)
        let channels = self.pixels.as_flattened();
        let mut out = vec![0u8; channels.len()];
        for (o, &c) in out.iter_mut().zip(channels) {
            let v = if c > 0.0 { c } else { 0.0 };
            let v = if v < 255.0 { v } else { 255.0 };
            *o = (v.trunc() + 8_388_608.0).to_bits() as u8;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ldr_clamps_truncates_and_zeroes_nan() {
        let img = Image {
            width: 3,
            height: 1,
            pixels: vec![[-3.0, 0.5, 254.99], [f32::NAN, 300.0, 1.5], [0.999, 1.0, 255.0]],
        };
        assert_eq!(img.to_ldr(), vec![0, 0, 254, 0, 255, 1, 0, 1, 255]);
        // Every kind of value, against the rule written out.
        let values = [
            f32::NEG_INFINITY,
            -1e30,
            -0.5,
            -0.0,
            0.0,
            f32::MIN_POSITIVE,
            0.5,
            1.0 - f32::EPSILON,
            127.5,
            254.999_98,
            255.0,
            255.5,
            256.0,
            1e30,
            f32::INFINITY,
            f32::NAN,
            -f32::NAN,
        ];
        let pixels: Vec<[f32; 3]> =
            values.chunks(3).map(|c| std::array::from_fn(|i| c[i % c.len()])).collect();
        let img = Image { width: pixels.len() as u32, height: 1, pixels };
        let rule = |c: f32| if c.is_nan() { 0 } else { c.clamp(0.0, 255.0) as u8 };
        let expected: Vec<u8> = img.pixels.iter().flatten().map(|&c| rule(c)).collect();
        assert_eq!(img.to_ldr(), expected);
    }
}
