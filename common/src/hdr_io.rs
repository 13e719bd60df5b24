//! HDR image files: OpenEXR and Radiance `.hdr` (RGBE) reading and writing, and the 8-bit PNG
//! that tone mapping produces.
//!
//! Implements the file side of scene-format.md §12.1: an `.exr` output holds the linear
//! floating-point radiance as rendered — no clamping, no gamma, values on the course's 0–255
//! scale — and `.hdr` is the accepted alternative container.
//!
//! - [`write_exr`] writes 32-bit float `R`, `G`, `B` channels with RLE compression (lossless),
//!   [`write_exr_zip`] with ZIP (smaller, slower): [`read_exr`] gives back the same bits
//!   (tested, including NaN and ±∞ bit patterns).
//! - [`write_hdr`] writes Radiance RGBE (8-bit mantissas sharing one exponent: about 1% relative
//!   precision, no negatives, no NaN or ∞; see [`write_hdr`] for what happens to those).
//! - [`read_exr`], [`read_hdr`] and [`read_float_image`] decode through
//!   [`TextureImage::decode`](crate::texture::image::TextureImage::decode), the same decoder the
//!   textures use; the first two also insist that the file *is* the format their name says.
//!
//! Every file is encoded in memory and then written in place with
//! [`write_atomic`]: never half a file under its name. Every
//! error names the file ([`HdrError`]).

use std::io::Cursor;
use std::path::{Path, PathBuf};

use crate::atomic_write::{WriteError, WriteStep, write_atomic};
use crate::image::Image;
use crate::texture::image::TextureImage;

/// Why an HDR file could not be read or written. Every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum HdrError {
    /// The file could not be opened, read, created or written.
    #[error("{}: {action}: {error}", path.display())]
    Io {
        path: PathBuf,
        /// "cannot read", "cannot create", "cannot write".
        action: &'static str,
        /// The operating system's reason (shown in the message, so not also a `source()`).
        error: std::io::Error,
    },
    /// The file is readable but is not the expected format, or its contents are malformed.
    #[error("{}: {message}", path.display())]
    Format { path: PathBuf, message: String },
    /// The image cannot be written (empty, inconsistent size, or the encoder failed).
    #[error("{}: cannot write: {message}", path.display())]
    Encode { path: PathBuf, message: String },
}

impl HdrError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            HdrError::Io { path, .. } | HdrError::Format { path, .. } | HdrError::Encode { path, .. } => path,
        }
    }
}

const EXR_MAGIC: &[u8] = &[0x76, 0x2f, 0x31, 0x01];

/// Refuses images whose pixel count does not match their size, or that have no pixels.
fn check_image(path: &Path, img: &Image) -> Result<(), HdrError> {
    let expected = img.width as u64 * img.height as u64;
    if img.width == 0 || img.height == 0 {
        return Err(HdrError::Encode {
            path: path.to_owned(),
            message: format!("the image is empty ({}x{})", img.width, img.height),
        });
    }
    if img.pixels.len() as u64 != expected {
        return Err(HdrError::Encode {
            path: path.to_owned(),
            message: format!(
                "the image holds {} pixels but is {}x{} = {expected}",
                img.pixels.len(),
                img.width,
                img.height
            ),
        });
    }
    Ok(())
}

/// Writes `img` as an OpenEXR file: one layer, channels `R`, `G`, `B` as 32-bit floats, RLE
/// compression on scanlines (lossless), increasing line order. Values are written as they are —
/// no clamping, no scaling, NaN and ±∞ kept bit for bit.
///
/// RLE, not ZIP: on a rendered 800x450 frame ZIP saved 4 % of the file (4.15 MB against 4.33 MB;
/// noisy floats hardly compress) for 123 ms of one thread after the last tile, RLE takes 11 ms
/// and still shrinks flat areas (black backgrounds, mattes) to almost nothing.
pub fn write_exr(path: &Path, img: &Image) -> Result<(), HdrError> {
    write_exr_with(path, img, exr::compression::Compression::RLE)
}

/// [`write_exr`] with ZIP compression (16 scanlines a block; lossless, the same bits back):
/// for a float frame that is kept rather than looked at (the farm's `.exr` beside a PNG
/// frame), smaller at the price of a slower write.
pub fn write_exr_zip(path: &Path, img: &Image) -> Result<(), HdrError> {
    write_exr_with(path, img, exr::compression::Compression::ZIP16)
}

fn write_exr_with(
    path: &Path,
    img: &Image,
    compression: exr::compression::Compression,
) -> Result<(), HdrError> {
    use exr::prelude::*;
    check_image(path, img)?;
    let width = img.width as usize;
    let pixels = &img.pixels;
    let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
        let p = pixels[pos.y() * width + pos.x()];
        (p[0], p[1], p[2])
    });
    let layer = Layer::new(
        (width, img.height as usize),
        LayerAttributes::default(),
        Encoding { compression, blocks: Blocks::ScanLines, line_order: LineOrder::Increasing },
        channels,
    );
    let mut out = Cursor::new(Vec::new());
    exr::prelude::Image::from_layer(layer)
        .write()
        .non_parallel()
        .to_buffered(&mut out)
        .map_err(|e| HdrError::Encode { path: path.to_owned(), message: format!("OpenEXR encoder: {e}") })?;
    write_atomic(path, out.get_ref()).map_err(|e| written(e, "cannot create"))
}

/// Writes `img` as a Radiance `.hdr` (RGBE, run-length encoded scanlines, `-Y H +X W`).
///
/// RGBE stores three 8-bit mantissas and a shared exponent, so values keep about 2–3 significant
/// digits relative to the pixel's largest channel, and some values cannot be stored at all; they
/// are written as follows: NaN and negative channels → 0; +∞ and values above the format's
/// largest (≈1.7·10³⁸) → 1.6·10³⁸; a pixel whose largest channel is below 2⁻¹²⁶ → black.
pub fn write_hdr(path: &Path, img: &Image) -> Result<(), HdrError> {
    use ::image::Rgb;
    use ::image::codecs::hdr::HdrEncoder;
    check_image(path, img)?;
    const LARGEST: f32 = 1.6e38;
    let rgb: Vec<Rgb<f32>> = img
        .pixels
        .iter()
        .map(|p| {
            let c = p.map(|v| if v.is_nan() || v <= 0.0 { 0.0 } else { v.min(LARGEST) });
            if c[0].max(c[1]).max(c[2]) < f32::MIN_POSITIVE { Rgb([0.0; 3]) } else { Rgb(c) }
        })
        .collect();
    let mut out = Vec::new();
    HdrEncoder::new(&mut out).encode(&rgb, img.width as usize, img.height as usize).map_err(|e| {
        HdrError::Encode { path: path.to_owned(), message: format!("Radiance HDR encoder: {e}") }
    })?;
    write_atomic(path, &out).map_err(|e| written(e, "cannot create"))
}

/// Writes 8-bit RGB bytes (`width * height * 3`, row-major from the top-left pixel; e.g. the
/// output of [`crate::tonemap::tonemap`]) as a PNG ([`encode_png_rgb8`]), whatever the file
/// name's extension.
pub fn write_png_rgb8(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<(), HdrError> {
    let png = encode_png_rgb8(width, height, rgb)
        .map_err(|message| HdrError::Encode { path: path.to_owned(), message })?;
    // A PNG that cannot be created is reported as "cannot write", as it always was.
    write_atomic(path, &png).map_err(|e| written(e, "cannot write"))
}

/// 8-bit RGB bytes (`width * height * 3`, row-major from the top-left pixel) as a PNG file in
/// memory: what [`write_png_rgb8`] writes, and what the farm serves as previews. The error says
/// why the bytes are not an image.
pub fn encode_png_rgb8(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>, String> {
    let expected = width as u64 * height as u64 * 3;
    if width == 0 || height == 0 || rgb.len() as u64 != expected {
        return Err(format!("{} bytes do not make a {width}x{height} RGB image", rgb.len()));
    }
    let mut out = Cursor::new(Vec::new());
    let (png, rgb8) = (::image::ImageFormat::Png, ::image::ExtendedColorType::Rgb8);
    ::image::write_buffer_with_format(&mut out, rgb, width, height, rgb8, png)
        .map_err(|e| format!("PNG encoder: {e}"))?;
    Ok(out.into_inner())
}

/// A failed [`write_atomic`] as an [`HdrError::Io`]: `create` names a file that could not be
/// created, every other step is "cannot write".
fn written(e: WriteError, create: &'static str) -> HdrError {
    let action = if e.step == WriteStep::Create { create } else { "cannot write" };
    HdrError::Io { path: e.path, action, error: e.error }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, HdrError> {
    std::fs::read(path).map_err(|error| HdrError::Io { path: path.to_owned(), action: "cannot read", error })
}

fn decode(path: &Path, bytes: &[u8]) -> Result<Image, HdrError> {
    let t =
        TextureImage::decode(bytes).map_err(|e| HdrError::Format { path: path.to_owned(), message: e.0 })?;
    Ok(Image { width: t.width, height: t.height, pixels: t.texels })
}

/// What the first bytes of a file that is not the wanted HDR format look like, for messages.
fn looks_like(bytes: &[u8]) -> String {
    if bytes.is_empty() {
        return "the file is empty".to_owned();
    }
    let known: &[(&[u8], &str)] = &[
        (b"\x89PNG", "it is a PNG image"),
        (&[0xff, 0xd8, 0xff], "it is a JPEG image"),
        (EXR_MAGIC, "it is an OpenEXR image"),
        (b"#?", "it is a Radiance HDR image"),
        (b"version https://git-lfs", "it is a Git LFS pointer (the image itself was not fetched)"),
        (b"<", "it looks like a text/XML file"),
    ];
    if let Some((_, what)) = known.iter().find(|(magic, _)| bytes.starts_with(magic)) {
        return (*what).to_owned();
    }
    let head: Vec<String> = bytes.iter().take(8).map(|b| format!("{b:02x}")).collect();
    format!("it starts with {}", head.join(" "))
}

/// Reads `path` and decodes it if its first bytes pass `accept`; otherwise an error naming the
/// file, the `expected` format and what the bytes look like.
fn read_checked(path: &Path, accept: fn(&[u8]) -> bool, expected: &str) -> Result<Image, HdrError> {
    let bytes = read_bytes(path)?;
    if !accept(&bytes) {
        return Err(HdrError::Format {
            path: path.to_owned(),
            message: format!("not {expected} file ({})", looks_like(&bytes)),
        });
    }
    decode(path, &bytes)
}

fn is_exr(bytes: &[u8]) -> bool {
    bytes.starts_with(EXR_MAGIC)
}

fn is_radiance(bytes: &[u8]) -> bool {
    bytes.starts_with(b"#?")
}

/// Reads an OpenEXR file (half, float or uint channels; RGB, RGBA or luminance; scanline or
/// tiled; any compression) into a linear float [`Image`], values as stored. A file that is not
/// OpenEXR (by its magic bytes, whatever its name) is an error saying what it is instead.
pub fn read_exr(path: &Path) -> Result<Image, HdrError> {
    read_checked(path, is_exr, "an OpenEXR")
}

/// Reads a Radiance `.hdr` (RGBE) file into a linear float [`Image`]. A file that is not Radiance
/// HDR (it must start with `#?`) is an error saying what it is instead.
pub fn read_hdr(path: &Path) -> Result<Image, HdrError> {
    read_checked(path, is_radiance, "a Radiance HDR")
}

/// Reads an HDR image, OpenEXR or Radiance HDR, chosen by the file's content (not its name).
/// Anything else (PNG, JPEG, text, ...) is an error naming the file and what it looks like: an
/// 8-bit image is not a radiance image.
pub fn read_float_image(path: &Path) -> Result<Image, HdrError> {
    read_checked(path, |b| is_exr(b) || is_radiance(b), "an OpenEXR or Radiance HDR")
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_testkit::TempDir;

    /// xorshift64: deterministic pseudo-random bits for the tests.
    struct Bits(u64);

    impl Bits {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }

        /// A random finite f32 of any sign and magnitude (random bits with a finite exponent),
        /// subnormals included.
        fn finite_f32(&mut self) -> f32 {
            loop {
                let v = f32::from_bits(self.next() as u32);
                if v.is_finite() {
                    return v;
                }
            }
        }
    }

    fn random_image(width: u32, height: u32, seed: u64) -> Image {
        let mut bits = Bits(seed);
        let special = [
            0.0,
            -0.0,
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            1e-45, // the smallest subnormal
            -1e-45,
            1.0,
            255.0,
            1e30,
            -1e-30,
            0.1,
            std::f32::consts::PI,
        ];
        let mut pixels = Vec::new();
        for k in 0..width as usize * height as usize {
            let p = std::array::from_fn(|c| {
                let k3 = k * 3 + c;
                if k3 < special.len() {
                    special[k3]
                } else {
                    match bits.next() % 4 {
                        0 => bits.finite_f32(),
                        // Radiance-like values on the 0..255 scale.
                        1 => (bits.next() % 1_000_000) as f32 / 997.0,
                        2 => -((bits.next() % 1000) as f32) / 7.0,
                        _ => f32::from_bits((bits.next() as u32 & 0x807f_ffff) | (100 << 23)),
                    }
                }
            });
            pixels.push(p);
        }
        Image { width, height, pixels }
    }

    fn same_bits(a: &Image, b: &Image) -> bool {
        a.width == b.width
            && a.height == b.height
            && a.pixels.len() == b.pixels.len()
            && a.pixels.iter().zip(&b.pixels).all(|(p, q)| (0..3).all(|c| p[c].to_bits() == q[c].to_bits()))
    }

    #[test]
    fn exr_round_trip_is_bit_exact() {
        let dir = TempDir::new("hdr-io-exr");
        // Odd sizes (partial 16-line ZIP blocks), a single pixel, a single row and column.
        for (k, (w, h)) in [(37u32, 23u32), (1, 1), (64, 1), (1, 40), (200, 50)].into_iter().enumerate() {
            let img = random_image(w, h, 0x9e37_79b9_7f4a_7c15 ^ k as u64);
            assert!(img.pixels.iter().flatten().all(|v| v.is_finite()));
            let path = dir.join(format!("round{k}.exr"));
            write_exr(&path, &img).unwrap();
            let back = read_exr(&path).unwrap();
            assert!(same_bits(&img, &back), "{w}x{h}: EXR round trip changed some value");
            // read_float_image takes the same path for EXR.
            assert!(same_bits(&img, &read_float_image(&path).unwrap()));
            // ZIP is lossless too.
            let zipped = dir.join(format!("round{k}.zip.exr"));
            write_exr_zip(&zipped, &img).unwrap();
            assert!(
                same_bits(&img, &read_exr(&zipped).unwrap()),
                "{w}x{h}: ZIP EXR round trip changed some value"
            );
        }
    }

    #[test]
    fn exr_keeps_non_finite_values() {
        let dir = TempDir::new("hdr-io-exr-nan");
        let img = Image {
            width: 2,
            height: 1,
            pixels: vec![[f32::NAN, f32::INFINITY, f32::NEG_INFINITY], [1.0, -2.0, 3.5]],
        };
        let path = dir.join("nan.exr");
        write_exr(&path, &img).unwrap();
        assert!(same_bits(&img, &read_exr(&path).unwrap()));
    }

    #[test]
    fn exr_file_is_float_rgb_rle_scanlines() {
        let dir = TempDir::new("hdr-io-exr-meta");
        let path = dir.join("meta.exr");
        write_exr(&path, &random_image(8, 8, 7)).unwrap();
        let meta = exr::meta::MetaData::read_from_file(&path, false).unwrap();
        let header = &meta.headers[0];
        assert_eq!(header.compression, exr::compression::Compression::RLE);
        assert_eq!(header.blocks, exr::meta::BlockDescription::ScanLines);
        let names: Vec<String> = header.channels.list.iter().map(|c| c.name.to_string()).collect();
        assert_eq!(names, ["B", "G", "R"]);
        assert!(header.channels.list.iter().all(|c| c.sample_type == exr::meta::attribute::SampleType::F32));
        assert_eq!((header.layer_size.x(), header.layer_size.y()), (8, 8));
    }

    #[test]
    fn a_flat_exr_is_compressed() {
        let dir = TempDir::new("hdr-io-exr-flat");
        let path = dir.join("black.exr");
        let img = Image { width: 256, height: 128, pixels: vec![[0.0; 3]; 256 * 128] };
        write_exr(&path, &img).unwrap();
        let size = std::fs::metadata(&path).unwrap().len();
        // 384 KiB of raw floats; runs of zeros take a few bytes a line.
        assert!(size < 256 * 128 * 12 / 20, "a black frame took {size} bytes");
        assert!(same_bits(&img, &read_exr(&path).unwrap()));
    }

    #[test]
    fn hdr_round_trip_within_rgbe_precision() {
        let dir = TempDir::new("hdr-io-hdr");
        let mut bits = Bits(42);
        let pixels: Vec<[f32; 3]> = (0..40 * 30)
            .map(|_| std::array::from_fn(|_| (bits.next() % 1_000_000) as f32 / 1000.0))
            .collect();
        let img = Image { width: 40, height: 30, pixels };
        let path = dir.join("round.hdr");
        write_hdr(&path, &img).unwrap();
        let back = read_hdr(&path).unwrap();
        assert_eq!((back.width, back.height), (40, 30));
        for (p, q) in img.pixels.iter().zip(&back.pixels) {
            let m = p[0].max(p[1]).max(p[2]);
            for c in 0..3 {
                // A mantissa of 8 bits relative to the largest channel: error below m/128.
                assert!((p[c] - q[c]).abs() <= m / 128.0, "{p:?} -> {q:?}");
            }
        }
        assert!(same_bits(&back, &read_float_image(&path).unwrap()));
    }

    #[test]
    fn hdr_writes_unrepresentable_values_safely() {
        let dir = TempDir::new("hdr-io-hdr-odd");
        let img = Image {
            width: 4,
            height: 1,
            pixels: vec![
                [f32::NAN, -1.0, 2.0],
                [f32::INFINITY, 0.0, 0.0],
                [1e-40, 1e-41, 0.0],
                [f32::MAX, 1.0, 0.0],
            ],
        };
        let path = dir.join("odd.hdr");
        write_hdr(&path, &img).unwrap();
        let back = read_hdr(&path).unwrap();
        assert_eq!(back.pixels[0], [0.0, 0.0, 2.0]);
        assert!(back.pixels[1][0] > 1e38 && back.pixels[1][0].is_finite());
        assert_eq!(back.pixels[2], [0.0; 3]);
        assert!(back.pixels[3][0] > 1e38 && back.pixels[3][0].is_finite());
    }

    #[test]
    fn errors_name_the_file() {
        let dir = TempDir::new("hdr-io-errors");
        let missing = dir.join("missing.exr");
        let err = read_exr(&missing).unwrap_err();
        assert!(matches!(err, HdrError::Io { .. }));
        assert_eq!(err.path(), missing);
        let msg = err.to_string();
        assert!(msg.contains("missing.exr") && msg.contains("cannot read"), "{msg}");

        let png = dir.join("picture.exr");
        std::fs::write(&png, b"\x89PNG\r\n\x1a\n....").unwrap();
        let msg = read_exr(&png).unwrap_err().to_string();
        assert!(
            msg.contains("picture.exr") && msg.contains("not an OpenEXR file") && msg.contains("PNG"),
            "{msg}"
        );
        let msg = read_float_image(&png).unwrap_err().to_string();
        assert!(msg.contains("picture.exr") && msg.contains("not an OpenEXR or Radiance HDR"), "{msg}");

        let exr = dir.join("real.exr");
        write_exr(&exr, &random_image(2, 2, 3)).unwrap();
        let msg = read_hdr(&exr).unwrap_err().to_string();
        assert!(
            msg.contains("real.exr") && msg.contains("not a Radiance HDR file") && msg.contains("OpenEXR"),
            "{msg}"
        );

        let empty = dir.join("empty.exr");
        std::fs::write(&empty, b"").unwrap();
        let msg = read_exr(&empty).unwrap_err().to_string();
        assert!(msg.contains("empty.exr") && msg.contains("empty"), "{msg}");

        // Truncated EXR: malformed, named.
        let bytes = std::fs::read(&exr).unwrap();
        let cut = dir.join("cut.exr");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let msg = read_exr(&cut).unwrap_err().to_string();
        assert!(msg.contains("cut.exr") && msg.contains("OpenEXR"), "{msg}");

        // Writing into a folder that does not exist, and an inconsistent image.
        let nowhere = dir.join("no/such/dir/out.exr");
        let msg = write_exr(&nowhere, &random_image(2, 2, 3)).unwrap_err().to_string();
        assert!(msg.contains("out.exr") && msg.contains("cannot create"), "{msg}");
        let msg = write_hdr(&nowhere.with_extension("hdr"), &random_image(2, 2, 3)).unwrap_err().to_string();
        assert!(msg.contains("out.hdr"), "{msg}");
        let bad = Image { width: 3, height: 3, pixels: vec![[0.0; 3]; 4] };
        let msg = write_exr(&dir.join("bad.exr"), &bad).unwrap_err().to_string();
        assert!(msg.contains("bad.exr") && msg.contains("4 pixels"), "{msg}");
        let empty_img = Image { width: 0, height: 5, pixels: vec![] };
        assert!(write_hdr(&dir.join("e.hdr"), &empty_img).is_err());
        let msg = write_png_rgb8(&dir.join("x.png"), 2, 2, &[0; 5]).unwrap_err().to_string();
        assert!(msg.contains("x.png"), "{msg}");
    }

    #[test]
    fn png_rgb8_round_trip() {
        let dir = TempDir::new("hdr-io-png");
        let path = dir.join("t.png");
        let data: Vec<u8> = (0..3 * 4 * 3).map(|k| (k * 7) as u8).collect();
        write_png_rgb8(&path, 3, 4, &data).unwrap();
        let back = tessera_testkit::rgb8::Rgb8::read_png(&path).unwrap();
        assert_eq!((back.width, back.height), (3, 4));
        assert_eq!(back.data, data);
    }
}
