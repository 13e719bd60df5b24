//! Conformance against the course's official reference images.
//!
//! One table (`thresholds.tsv` beside this file) lists every image we compare and the
//! thresholds it must meet; the `conformance` binary renders all of them and writes a Markdown
//! report, and the `conformance` integration test runs the rows marked `ci`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use tessera::render::{RenderSettings, render_camera};
use tessera::scene::ShadingRules;
use tessera::scene::load::{LoadOptions, load_scene_file_with};
use tessera_testkit::rgb8::{Comparison, Rgb8, compare};

/// One row of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub scene: String,
    pub image: String,
    pub min_psnr_box4: f64,
    pub max_off3_pct: f64,
    pub ci: bool,
    /// Samples per pixel override (`None`: the camera's NumSamples).
    pub spp: Option<u32>,
    pub note: String,
}

impl Row {
    /// A 2025 JSON scene's row names it by its path under the corpus without `.json`, e.g.
    /// `json/hw1/simple`; other rows name an XML scene under `xml/`.
    pub fn json_scene(&self) -> Option<&str> {
        self.scene.strip_prefix("json/")
    }

    /// `xml/<scene>.xml`, or `json/<path>.json` for JSON rows.
    pub fn scene_path(&self) -> PathBuf {
        match self.json_scene() {
            Some(path) => crate::shared_scenes().join("json").join(format!("{path}.json")),
            None => crate::shared_scenes().join("xml").join(format!("{}.xml", self.scene)),
        }
    }

    /// `reference/<scene>.png`, or `reference/<scene>__<image>.png` for multi-camera scenes; for a
    /// JSON row `json/<dir>/<name>`, the 2025 reference `reference/json2025/<dir>/<image>`.
    pub fn reference_path(&self) -> PathBuf {
        let dir = crate::shared_scenes().join("reference");
        if let Some(path) = self.json_scene() {
            let sub = Path::new(path).parent().unwrap_or(Path::new(""));
            return dir.join("json2025").join(sub).join(&self.image);
        }
        let single = dir.join(format!("{}.png", self.scene));
        // An HDR camera (`x.exr`) is judged by the tone-mapped PNG beside its reference.
        let stem = Path::new(&self.image).with_extension("png");
        let multi = dir.join(format!("{}__{}", self.scene, stem.display()));
        if multi.exists() { multi } else { single }
    }
}

pub fn table_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("conformance/thresholds.tsv")
}

/// Parses the thresholds table.
pub fn parse_table(text: &str) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim_end();
        if line.trim().is_empty() || line.trim_start().starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line.split('\t').collect();
        if f.len() < 5 {
            bail!(
                "thresholds.tsv line {}: expected at least 5 tab-separated columns, found {}",
                i + 1,
                f.len()
            );
        }
        let num = |s: &str, what: &str| -> Result<f64> {
            s.trim()
                .parse::<f64>()
                .with_context(|| format!("thresholds.tsv line {}: {what} \"{s}\" is not a number", i + 1))
        };
        rows.push(Row {
            scene: f[0].trim().to_string(),
            image: f[1].trim().to_string(),
            min_psnr_box4: num(f[2], "psnr_box4")?,
            max_off3_pct: num(f[3], "off3_pct")?,
            ci: f[4].trim() == "ci",
            spp: match f.get(5).map(|s| s.trim()) {
                None | Some("-") | Some("") => None,
                Some(n) => Some(n.parse::<u32>().ok().filter(|&n| n > 0).with_context(|| {
                    format!("thresholds.tsv line {}: spp \"{n}\" is not a positive integer or -", i + 1)
                })?),
            },
            note: f.get(6).map(|s| s.trim().to_string()).unwrap_or_default(),
        });
    }
    Ok(rows)
}

pub fn load_table() -> Result<Vec<Row>> {
    let p = table_path();
    let text = std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    parse_table(&text)
}

/// The outcome of one row.
#[derive(Clone, Debug)]
pub struct RowResult {
    pub row: Row,
    pub seconds: f64,
    /// The comparison, or why there is none (render error, missing reference, size mismatch).
    pub outcome: Result<Comparison, String>,
}

impl RowResult {
    pub fn passed(&self) -> bool {
        match &self.outcome {
            Ok(c) => {
                c.psnr_box4 >= self.row.min_psnr_box4 && c.off_by_more_than_3 * 100.0 <= self.row.max_off3_pct
            }
            Err(_) => false,
        }
    }
}

fn render_one(row: &Row, out_dir: &Path, rules: ShadingRules) -> Result<Comparison> {
    // A row whose note says `--allow-unsupported` renders its scene without the unsupported
    // elements the note names (as `tessera-worker render --allow-unsupported` would).
    let options = LoadOptions { allow_unsupported: row.note.contains("--allow-unsupported") };
    let mut scene = load_scene_file_with(&row.scene_path(), options).map_err(|e| anyhow::anyhow!("{e}"))?;
    scene.rules = rules;
    let cam = scene
        .cameras
        .iter()
        .position(|c| c.image_name == row.image)
        .with_context(|| format!("{} has no camera with ImageName {}", row.scene, row.image))?;
    let settings = RenderSettings { samples: row.spp, ..RenderSettings::default() };
    let (img, _) = render_camera(&scene, cam, 32, &settings, &|_, _| {});
    let ours = display_image(&scene.cameras[cam], &img);
    let spp = row.spp.map_or(String::new(), |n| format!("__{n}spp"));
    let stem = Path::new(&row.image).with_extension("");
    let out = out_dir.join(format!("{}__{}{spp}.png", row.scene.replace('/', "_"), stem.display()));
    if std::fs::create_dir_all(out_dir).is_ok() {
        let _ = tessera::hdr_io::write_png_rgb8(&out, ours.width, ours.height, &ours.data);
        // An HDR camera's linear image too, to compare means with the official EXR.
        if row.image.ends_with(".exr") {
            let _ = tessera::hdr_io::write_exr(&out.with_extension("exr"), &img);
        }
    }
    let reference = Rgb8::read_png(&row.reference_path())
        .with_context(|| format!("cannot read reference {}", row.reference_path().display()))?;
    // A difference picture beside the render: |ours - reference| x 8, to see where they differ.
    if ours.width == reference.width && ours.height == reference.height {
        let diff: Vec<u8> = ours
            .data
            .iter()
            .zip(&reference.data)
            .map(|(a, b)| (u32::from(a.abs_diff(*b)) * 8).min(255) as u8)
            .collect();
        let _ =
            tessera::hdr_io::write_png_rgb8(&out.with_extension("diff.png"), ours.width, ours.height, &diff);
    }
    compare(&ours, &reference).with_context(|| {
        format!(
            "size {}x{} differs from the reference's {}x{}",
            ours.width, ours.height, reference.width, reference.height
        )
    })
}

/// The 8-bit picture a camera's output is judged by: the clamped PNG of an LDR `ImageName`,
/// the (first) tone-mapped PNG of an HDR one.
pub fn display_image(cam: &tessera::camera::Camera, img: &tessera::image::Image) -> Rgb8 {
    let (files, _) = tessera::output::plan(cam);
    match files.iter().find_map(|f| match &f.kind {
        tessera::output::OutputKind::Tonemapped(op, p) => Some((*op, *p)),
        _ => None,
    }) {
        Some((operator, params)) => {
            let (data, _) = tessera::tonemap::tonemap_with(img, operator, &params);
            Rgb8 { width: img.width, height: img.height, data }
        }
        None => Rgb8 { width: img.width, height: img.height, data: img.to_ldr() },
    }
}

/// Renders and compares every row; `log` receives one line per row as it finishes.
pub fn render_rows(rows: &[Row], out_dir: &Path, log: &dyn Fn(String)) -> Vec<RowResult> {
    render_rows_with(rows, out_dir, ShadingRules::default(), log)
}

/// [`render_rows`] with shading rules other than the defaults, to measure them.
pub fn render_rows_with(
    rows: &[Row],
    out_dir: &Path,
    rules: ShadingRules,
    log: &dyn Fn(String),
) -> Vec<RowResult> {
    rows.iter()
        .map(|row| {
            let t = Instant::now();
            let outcome = render_one(row, out_dir, rules).map_err(|e| format!("{e:#}"));
            let r = RowResult { row: row.clone(), seconds: t.elapsed().as_secs_f64(), outcome };
            log(summary_line(&r));
            r
        })
        .collect()
}

fn fmt_db(x: f64) -> String {
    if x.is_infinite() { "inf".into() } else { format!("{x:.2}") }
}

pub fn summary_line(r: &RowResult) -> String {
    let verdict = if r.passed() { "ok  " } else { "FAIL" };
    match &r.outcome {
        Ok(c) => format!(
            "{verdict} {}/{}: PSNR {} dB, box4 {} dB (min {}), off>3 {:.3}% (max {}%), {:.2} s",
            r.row.scene,
            r.row.image,
            fmt_db(c.psnr),
            fmt_db(c.psnr_box4),
            r.row.min_psnr_box4,
            c.off_by_more_than_3 * 100.0,
            r.row.max_off3_pct,
            r.seconds
        ),
        Err(e) => format!("{verdict} {}/{}: {e}", r.row.scene, r.row.image),
    }
}

/// The Markdown report: one table row per image.
pub fn report_markdown(results: &[RowResult]) -> String {
    let mut s = String::from("# Tessera conformance report\n\n");
    let passed = results.iter().filter(|r| r.passed()).count();
    s += &format!("{passed} of {} images meet their thresholds.\n\n", results.len());
    s += "| scene | image | spp | PSNR dB | PSNR 4x4 dB (min) | off >3 % (max) | time s | result | note |\n";
    s += "|---|---|---:|---:|---:|---:|---:|---|---|\n";
    for r in results {
        let (psnr, box4, off) = match &r.outcome {
            Ok(c) => (fmt_db(c.psnr), fmt_db(c.psnr_box4), format!("{:.3}", c.off_by_more_than_3 * 100.0)),
            Err(e) => ("-".into(), "-".into(), format!("error: {}", e.replace('|', "/"))),
        };
        s += &format!(
            "| {} | {} | {} | {} | {} ({}) | {} ({}) | {:.2} | {} | {} |\n",
            r.row.scene,
            r.row.image,
            r.row.spp.map_or("scene".to_string(), |n| n.to_string()),
            psnr,
            box4,
            r.row.min_psnr_box4,
            off,
            r.row.max_off3_pct,
            r.seconds,
            if r.passed() { "pass" } else { "FAIL" },
            r.row.note
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_parses_and_rejects_bad_numbers() {
        let t = "# c\nsimple\tsimple.png\t35\t0.5\tci\n\nbunny\tbunny.png\t30\t2\t-\t16\tnoisy\n";
        let rows = parse_table(t).unwrap();
        assert_eq!(rows.len(), 2);
        assert!(rows[0].ci && !rows[1].ci);
        assert_eq!((rows[0].spp, rows[1].spp), (None, Some(16)));
        assert_eq!(rows[1].note, "noisy");
        assert!(parse_table("x\ty\t1\t1\tci\t0\n").is_err());
        let err = parse_table("x\ty\tabc\t1\tci\n").unwrap_err().to_string();
        assert!(err.contains("line 1") && err.contains("abc"), "{err}");
    }

    #[test]
    fn json_rows_name_json_scenes_and_2025_references() {
        let rows =
            parse_table("json/hw1/raven/rt_raven\traven.png\t35\t0.5\tci\nsimple\tsimple.png\t35\t0.5\tci\n")
                .unwrap();
        let corpus = crate::shared_scenes();
        assert_eq!(rows[0].scene_path(), corpus.join("json/hw1/raven/rt_raven.json"));
        assert_eq!(rows[0].reference_path(), corpus.join("reference/json2025/hw1/raven/raven.png"));
        assert_eq!(rows[1].scene_path(), corpus.join("xml/simple.xml"));
    }

    #[test]
    fn the_repository_table_is_valid() {
        let rows = load_table().unwrap();
        assert!(!rows.is_empty());
        for r in &rows {
            assert!(r.min_psnr_box4 > 0.0 && r.max_off3_pct >= 0.0, "{r:?}");
        }
    }
}
