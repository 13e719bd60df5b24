//! 8-bit RGB pictures read from PNG files, and how close two of them are: what the tests and the
//! conformance runner judge renders by (PSNR, PSNR after a 4x4 box average, share of pixels off
//! by more than 3 code values). The library never reads its own PNGs back, so this lives here.

use std::path::Path;

/// An 8-bit RGB image, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Rgb8 {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl Rgb8 {
    /// Reads an image file (any format and colour type the `image` crate reads: PNG here) as
    /// 8-bit RGB.
    pub fn read_png(path: &Path) -> Result<Rgb8, image::ImageError> {
        let img = image::open(path)?.to_rgb8();
        Ok(Rgb8 { width: img.width(), height: img.height(), data: img.into_raw() })
    }
}

/// How close two 8-bit images are.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Comparison {
    /// PSNR in dB over all channels (infinite for identical images).
    pub psnr: f64,
    /// PSNR after averaging 4x4 pixel blocks of both images (forgives per-pixel noise).
    pub psnr_box4: f64,
    /// Share of pixels with some channel off by more than 3 code values, in [0, 1].
    pub off_by_more_than_3: f64,
}

fn psnr_from_mse(mse: f64) -> f64 {
    if mse == 0.0 { f64::INFINITY } else { 10.0 * (255.0f64 * 255.0 / mse).log10() }
}

fn box4(img: &Rgb8) -> (Vec<f64>, u32, u32) {
    let (bw, bh) = (img.width / 4, img.height / 4);
    let mut out = vec![0.0; (bw * bh * 3) as usize];
    for by in 0..bh {
        for bx in 0..bw {
            for c in 0..3 {
                let mut s = 0.0;
                for y in 0..4 {
                    for x in 0..4 {
                        s += img.data[(((by * 4 + y) * img.width + bx * 4 + x) * 3 + c) as usize] as f64;
                    }
                }
                out[((by * bw + bx) * 3 + c) as usize] = s / 16.0;
            }
        }
    }
    (out, bw, bh)
}

/// Compares `a` with `b`; `None` if their sizes differ.
pub fn compare(a: &Rgb8, b: &Rgb8) -> Option<Comparison> {
    if a.width != b.width || a.height != b.height {
        return None;
    }
    let mut se = 0.0;
    let mut off = 0usize;
    for (pa, pb) in a.data.chunks_exact(3).zip(b.data.chunks_exact(3)) {
        let mut worst = 0;
        for c in 0..3 {
            let d = pa[c] as i32 - pb[c] as i32;
            se += (d * d) as f64;
            worst = worst.max(d.abs());
        }
        if worst > 3 {
            off += 1;
        }
    }
    let n = (a.width as usize * a.height as usize).max(1);
    let (ba, _, _) = box4(a);
    let (bb, _, _) = box4(b);
    let bse: f64 = ba.iter().zip(&bb).map(|(x, y)| (x - y) * (x - y)).sum();
    Some(Comparison {
        psnr: psnr_from_mse(se / (n * 3) as f64),
        psnr_box4: if ba.is_empty() {
            psnr_from_mse(se / (n * 3) as f64)
        } else {
            psnr_from_mse(bse / ba.len() as f64)
        },
        off_by_more_than_3: off as f64 / n as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn solid(w: u32, h: u32, v: u8) -> Rgb8 {
        Rgb8 { width: w, height: h, data: vec![v; (w * h * 3) as usize] }
    }

    #[test]
    fn psnr_values_by_hand() {
        let a = solid(8, 8, 100);
        let b = solid(8, 8, 110);
        let c = compare(&a, &b).unwrap();
        // MSE 100 -> 10·log10(65025/100) = 28.131 dB.
        assert!((c.psnr - 28.1308).abs() < 1e-3, "{}", c.psnr);
        assert!((c.psnr_box4 - 28.1308).abs() < 1e-3);
        assert_eq!(c.off_by_more_than_3, 1.0);
        assert_eq!(compare(&a, &a).unwrap().psnr, f64::INFINITY);
        assert!(compare(&a, &solid(4, 8, 0)).is_none());
    }

    #[test]
    fn box_average_forgives_zero_mean_noise() {
        // A checkerboard of ±8 around 100 averages out in every 4x4 block.
        let mut a = solid(8, 8, 100);
        for y in 0..8 {
            for x in 0..8 {
                let v = if (x + y) % 2 == 0 { 108 } else { 92 };
                for c in 0..3 {
                    a.data[((y * 8 + x) * 3 + c) as usize] = v;
                }
            }
        }
        let cmp = compare(&a, &solid(8, 8, 100)).unwrap();
        assert!(cmp.psnr < 31.0);
        assert_eq!(cmp.psnr_box4, f64::INFINITY);
    }

    #[test]
    fn png_files_read_as_rgb8() {
        let dir = crate::TempDir::new("testkit-rgb8");
        let path = dir.join("t.png");
        let data: Vec<u8> = (0..2 * 3 * 3).map(|k| (k * 13) as u8).collect();
        image::save_buffer(&path, &data, 2, 3, image::ExtendedColorType::Rgb8).unwrap();
        assert_eq!(Rgb8::read_png(&path).unwrap(), Rgb8 { width: 2, height: 3, data });
    }
}
