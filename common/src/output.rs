//! Output files of a rendered camera (scene-format.md §12.1): what an `ImageName` asks for and
//! writing it.
//!
//! - `name.png`: the course's LDR output, each channel clamped to [0, 255] and rounded.
//! - `name.exr`: the linear float image as a lossless 32-bit float OpenEXR file, and beside it
//!   `name.png` tone-mapped with the camera's `<Tonemap>` (the photographic defaults of §12.2
//!   when it has none). 2025 scenes may give several `<Tonemap>`s, each with its own
//!   `Extension` replacing `.exr` (`name_phot.png`, ...).
//! - `name.hdr`: the same with a Radiance RGBE file instead of the EXR.
//!
//! Only the file name of `ImageName` is used: a scene cannot write outside the output directory.

use std::path::{Path, PathBuf};

use crate::camera::Camera;
use crate::hdr_io::{HdrError, write_exr, write_hdr, write_png_rgb8};
use crate::image::Image;
use crate::tonemap::params::{Operator, Photographic};
use crate::tonemap::{TonemapStats, tonemap_with};

/// One file to write for a camera.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputFile {
    /// File name (no directories).
    pub name: String,
    pub kind: OutputKind,
}

#[derive(Clone, Debug, PartialEq)]
pub enum OutputKind {
    /// Clamped and rounded 8-bit PNG (§12.1).
    LdrPng,
    /// Lossless float OpenEXR of the linear image.
    Exr,
    /// Radiance RGBE of the linear image.
    Hdr,
    /// 8-bit PNG through a tone-mapping operator (photographic, or the 2025 Filmic / ACES).
    Tonemapped(Operator, Photographic),
}

/// The files a camera's `ImageName` asks for, and notes about anything changed on the way
/// (an unknown extension, a duplicate name).
pub fn plan(cam: &Camera) -> (Vec<OutputFile>, Vec<String>) {
    let mut notes = Vec::new();
    let name = Path::new(&cam.image_name)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .filter(|n| !n.is_empty())
        .unwrap_or_else(|| {
            notes.push(format!("ImageName \"{}\" has no file name; writing image.png", cam.image_name));
            "image.png".into()
        });
    let path = Path::new(&name);
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| name.clone());
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    let hdr_kind = match ext.as_deref() {
        Some("png") => return (vec![OutputFile { name, kind: OutputKind::LdrPng }], notes),
        Some("exr") => OutputKind::Exr,
        Some("hdr") => OutputKind::Hdr,
        other => {
            let png = format!("{stem}.png");
            notes.push(match other {
                Some(e) => format!(
                    "ImageName \"{}\": .{e} is not an output format (png, exr, hdr); writing {png}",
                    cam.image_name
                ),
                None => format!("ImageName \"{}\" has no extension; writing {png}", cam.image_name),
            });
            return (vec![OutputFile { name: png, kind: OutputKind::LdrPng }], notes);
        }
    };
    let mut files = vec![OutputFile { name: name.clone(), kind: hdr_kind }];
    let defaults = [(Operator::Photographic, Photographic::default(), None)];
    let tonemaps: Vec<(Operator, Photographic, Option<&str>)> = if cam.tonemaps.is_empty() {
        defaults.to_vec()
    } else {
        cam.tonemaps.iter().map(|t| (t.operator, t.params, t.extension.as_deref())).collect()
    };
    for (operator, params, extension) in tonemaps {
        let png = format!("{stem}{}", extension.unwrap_or(".png"));
        let png = match Path::new(&png).file_name() {
            Some(n) if !n.is_empty() => n.to_string_lossy().into_owned(),
            _ => format!("{stem}.png"),
        };
        if files.iter().any(|f| f.name == png) {
            notes.push(format!(
                "two <Tonemap>s of camera {} both write {png}; only the first is written",
                cam.id
            ));
            continue;
        }
        files.push(OutputFile { name: png, kind: OutputKind::Tonemapped(operator, params) });
    }
    (files, notes)
}

/// The files of a camera's denoised image (written beside [`plan`]'s, never over them): each
/// of the plan's files with `_denoised` after the image's stem (`s.exr` → `s_denoised.exr`,
/// its tone-mapped `s_phot.png` → `s_denoised_phot.png`), and always a float `.exr`
/// (`.hdr` names get theirs instead of an `.hdr`; `.png` names get one beside the clamped
/// PNG), so the denoised linear frame can be tone-mapped again later.
pub fn denoised_plan(cam: &Camera) -> Vec<OutputFile> {
    let (files, _) = plan(cam);
    let stem =
        Path::new(&files[0].name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let rename = |name: &str| match name.strip_prefix(stem.as_str()) {
        Some(rest) => format!("{stem}_denoised{rest}"),
        None => {
            let p = Path::new(name);
            let own = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            match p.extension() {
                Some(e) => format!("{own}_denoised.{}", e.to_string_lossy()),
                None => format!("{own}_denoised"),
            }
        }
    };
    let mut out = vec![OutputFile { name: format!("{stem}_denoised.exr"), kind: OutputKind::Exr }];
    for f in files {
        match f.kind {
            OutputKind::Exr | OutputKind::Hdr => {}
            kind => out.push(OutputFile { name: rename(&f.name), kind }),
        }
    }
    out
}

/// The name of the map of where a noise target sent samples: `<stem>_samples.png`.
pub fn samples_map_name(cam: &Camera) -> String {
    let (files, _) = plan(cam);
    let stem =
        Path::new(&files[0].name).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    format!("{stem}_samples.png")
}

/// The samples map of a `width` x `height` frame as 8-bit grey RGB: each pixel's samples over
/// the cap `samples`, white where a pixel took every sample. A tile's counts are its pixels'
/// row by row; a tile with a single count has it for every pixel.
pub fn samples_map(
    width: u32,
    height: u32,
    tiles: &[(crate::image::TileRect, &[u32])],
    samples: u32,
) -> Vec<u8> {
    let mut rgb = vec![0u8; width as usize * height as usize * 3];
    for (r, counts) in tiles {
        for y in r.y0..(r.y0 + r.height).min(height) {
            for x in r.x0..(r.x0 + r.width).min(width) {
                let k = ((y - r.y0) * r.width + (x - r.x0)) as usize;
                let n = counts.get(k).or(counts.first()).copied().unwrap_or(0);
                let v = (f64::from(n) / f64::from(samples.max(1)) * 255.0).round().clamp(0.0, 255.0) as u8;
                let i = (y as usize * width as usize + x as usize) * 3;
                rgb[i..i + 3].fill(v);
            }
        }
    }
    rgb
}

/// A file that was written.
#[derive(Clone, Debug, PartialEq)]
pub struct Written {
    pub path: PathBuf,
    pub kind: OutputKind,
    /// For tone-mapped PNGs: what the operator measured (non-finite pixels included).
    pub stats: Option<TonemapStats>,
}

/// Writes every planned file of `img` into `dir`, in order.
pub fn write(dir: &Path, img: &Image, files: &[OutputFile]) -> Result<Vec<Written>, HdrError> {
    let mut out = Vec::with_capacity(files.len());
    for f in files {
        let path = dir.join(&f.name);
        let stats = match &f.kind {
            OutputKind::LdrPng => {
                write_png_rgb8(&path, img.width, img.height, &img.to_ldr())?;
                None
            }
            OutputKind::Exr => {
                write_exr(&path, img)?;
                None
            }
            OutputKind::Hdr => {
                write_hdr(&path, img)?;
                None
            }
            OutputKind::Tonemapped(operator, params) => {
                let (rgb, stats) = tonemap_with(img, *operator, params);
                write_png_rgb8(&path, img.width, img.height, &rgb)?;
                Some(stats)
            }
        };
        out.push(Written { path, kind: f.kind.clone(), stats });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::records::TonemapRec;

    fn camera(image_name: &str, tonemaps: Vec<TonemapRec>) -> Camera {
        let rec = crate::scene::records::CameraRec {
            id: "1".into(),
            loc: crate::Loc::default(),
            position: [0.0; 3],
            gaze: [0.0, 0.0, -1.0],
            up: [0.0, 1.0, 0.0],
            transforms: Vec::new(),
            projection: crate::scene::records::Projection::FovY(45.0),
            near_distance: 1.0,
            width: 2,
            height: 1,
            image_name: image_name.into(),
            handedness: crate::scene::records::Handedness::Right,
            num_samples: 1,
            clamp_samples: None,
            lens: None,
            tonemaps,
            renderer: Default::default(),
        };
        Camera::from_record(&rec).unwrap()
    }

    fn names(files: &[OutputFile]) -> Vec<&str> {
        files.iter().map(|f| f.name.as_str()).collect()
    }

    #[test]
    fn image_names_choose_the_files() {
        let (f, notes) = plan(&camera("out/a.png", vec![]));
        assert_eq!(f, vec![OutputFile { name: "a.png".into(), kind: OutputKind::LdrPng }]);
        assert!(notes.is_empty());

        let (f, _) = plan(&camera("../../etc/cube.exr", vec![]));
        assert_eq!(names(&f), ["cube.exr", "cube.png"]);
        assert_eq!(f[0].kind, OutputKind::Exr);
        assert_eq!(f[1].kind, OutputKind::Tonemapped(Operator::Photographic, Photographic::default()));

        let (f, _) = plan(&camera("c.HDR", vec![]));
        assert_eq!(names(&f), ["c.HDR", "c.png"]);
        assert_eq!(f[0].kind, OutputKind::Hdr);

        let (f, notes) = plan(&camera("old.ppm", vec![]));
        assert_eq!(names(&f), ["old.png"]);
        assert_eq!(notes.len(), 1, "{notes:?}");
    }

    #[test]
    fn denoised_files_sit_beside_the_plans_under_their_own_names() {
        let f = denoised_plan(&camera("out/a.png", vec![]));
        assert_eq!(names(&f), ["a_denoised.exr", "a_denoised.png"]);
        assert_eq!(f[1].kind, OutputKind::LdrPng);
        let f = denoised_plan(&camera("c.hdr", vec![]));
        assert_eq!(names(&f), ["c_denoised.exr", "c_denoised.png"]);
        assert_eq!(f[1].kind, OutputKind::Tonemapped(Operator::Photographic, Photographic::default()));
        let t = |ext: &str| TonemapRec {
            loc: crate::Loc::default(),
            operator: Operator::Photographic,
            params: Photographic::default(),
            extension: Some(ext.into()),
        };
        let f = denoised_plan(&camera("s.exr", vec![t("_phot.png"), t("/../../x.png")]));
        assert_eq!(names(&f), ["s_denoised.exr", "s_denoised_phot.png", "x_denoised.png"]);
        let plain = plan(&camera("s.exr", vec![t("_phot.png"), t("/../../x.png")])).0;
        assert!(f.iter().all(|d| plain.iter().all(|p| p.name != d.name)), "no name is shared");
    }

    #[test]
    fn each_tonemap_writes_its_own_png() {
        let t = |key: f64, ext: Option<&str>| TonemapRec {
            loc: crate::Loc::default(),
            operator: if key == 0.5 { Operator::Aces } else { Operator::Photographic },
            params: Photographic { key, ..Photographic::default() },
            extension: ext.map(Into::into),
        };
        let (f, notes) = plan(&camera("s.exr", vec![t(0.36, None)]));
        assert_eq!(names(&f), ["s.exr", "s.png"]);
        assert_eq!(
            f[1].kind,
            OutputKind::Tonemapped(
                Operator::Photographic,
                Photographic { key: 0.36, ..Photographic::default() }
            )
        );
        assert!(notes.is_empty());

        let (f, notes) = plan(&camera(
            "s.exr",
            vec![t(0.18, Some("_phot.png")), t(0.5, Some("_b.png")), t(1.0, Some("_phot.png"))],
        ));
        assert_eq!(names(&f), ["s.exr", "s_phot.png", "s_b.png"]);
        assert_eq!(
            f[2].kind,
            OutputKind::Tonemapped(Operator::Aces, Photographic { key: 0.5, ..Photographic::default() })
        );
        assert_eq!(notes.len(), 1, "{notes:?}");
        // An Extension cannot leave the directory either.
        let (f, _) = plan(&camera("s.exr", vec![t(0.18, Some("/../../x.png"))]));
        assert_eq!(names(&f), ["s.exr", "x.png"]);
    }
}
