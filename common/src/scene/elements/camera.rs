//! The rules of `<Cameras>`: each camera's view, image plane, lens, samples and renderer.

use crate::scene::records::{
    CameraRec, Handedness, LensRec, PathParams, Projection, Renderer, Roulette, Vec3,
};
use crate::scene::tree::{Node, Parser, Result, Schema, excerpt};

const CAMERAS: Schema = Schema { many: &["Camera"], ..Schema::EMPTY };
const CAMERA: Schema = Schema {
    single: &[
        "Position",
        "Gaze",
        "GazePoint",
        "Up",
        "NearPlane",
        "FovY",
        "NearDistance",
        "ImageResolution",
        "ImageName",
        "NumSamples",
        "FocusDistance",
        "ApertureSize",
        "Transformations",
        "Renderer",
        "RendererParams",
        // 2019 path tracing (§4.1: commented out in sponza_path.xml).
        "ClampSamples",
    ],
    many: &["Tonemap"],
    attrs: &["id", "type", "handedness"],
    ..Schema::EMPTY
};
/// The words of `<RendererParams>` (§13.1).
const RENDERER_PARAMS: &[&str] = &[
    "NextEventEstimation",
    "ImportanceSampling",
    "RussianRoulette",
    "UnbiasedRussianRoulette",
    "SampleOneLight",
    "MultipleImportanceSampling",
];

impl Parser<'_> {
    pub(super) fn cameras(&mut self, block: &Node) -> Result<()> {
        self.check(block, &CAMERAS);
        for camera in block.children_named("Camera") {
            let camera = self.camera(camera)?;
            self.out.cameras.push(camera);
        }
        Ok(())
    }

    pub(super) fn camera(&mut self, n: &Node) -> Result<CameraRec> {
        self.check(n, &CAMERA);
        let look_at = match n.attr("type").map(str::trim) {
            None => false,
            Some("lookAt") => true,
            Some(other) => {
                return Err(
                    self.err(n, format!("unknown camera type \"{other}\" (expected lookAt, or no type)"))
                );
            }
        };
        let handedness = match n.attr("handedness").map(str::trim) {
            None | Some("right") => Handedness::Right,
            Some("left") => Handedness::Left,
            Some(other) => {
                return Err(
                    self.err(n, format!("attribute handedness must be left or right, found \"{other}\""))
                );
            }
        };
        let position: Vec3 = self.required_numbers(n, "Position")?;

        // Each camera type has its own way of giving the view direction and the image plane;
        // the other way is accepted as a fallback.
        let (gaze_first, gaze_second) = if look_at { ("GazePoint", "Gaze") } else { ("Gaze", "GazePoint") };
        let gaze = match self.either(n, gaze_first, gaze_second) {
            Some(g) if g.name == "GazePoint" => {
                let [x, y, z]: Vec3 = self.numbers(g)?;
                [x - position[0], y - position[1], z - position[2]]
            }
            Some(g) => self.numbers(g)?,
            None => return Err(self.err(n, format!("missing <{gaze_first}> (or <{gaze_second}>)"))),
        };
        let (plane_first, plane_second) = if look_at { ("FovY", "NearPlane") } else { ("NearPlane", "FovY") };
        let projection = match self.either(n, plane_first, plane_second) {
            Some(p) if p.name == "FovY" => {
                let fov = self.number::<f64>(p)?;
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(self.err(p, format!("FovY must be between 0 and 180 degrees, found {fov}")));
                }
                Projection::FovY(fov)
            }
            Some(p) => {
                let [left, right, bottom, top] = self.numbers(p)?;
                Projection::NearPlane { left, right, bottom, top }
            }
            None => return Err(self.err(n, format!("missing <{plane_first}> (or <{plane_second}>)"))),
        };

        let up = self.required_numbers(n, "Up")?;
        let near_distance = self.required_number(n, "NearDistance")?;
        let resolution = self.required(n, "ImageResolution")?;
        let [width, height] = self.numbers::<u32, 2>(resolution)?;
        if width == 0 || height == 0 {
            return Err(self.err(
                resolution,
                format!("the image must be at least 1 x 1 pixels, found {width} x {height}"),
            ));
        }
        let image_name = self.text(self.required(n, "ImageName")?, "an image file name")?.to_string();
        let num_samples = match n.child("NumSamples") {
            None => 1,
            Some(s) => match self.number::<u32>(s)? {
                0 => return Err(self.err(s, "NumSamples must be at least 1")),
                k => k,
            },
        };
        let clamp_samples = match n.child("ClampSamples") {
            None => None,
            Some(c) => match self.number::<f64>(c)? {
                v if v > 0.0 => Some(v),
                v => {
                    return Err(self.err(
                        c,
                        format!("ClampSamples must be positive, found {v} (each sample's radiance is clamped to it)"),
                    ));
                }
            },
        };
        let focus: Option<f64> = self.optional_number(n, "FocusDistance")?;
        let aperture: Option<f64> = self.optional_number(n, "ApertureSize")?;
        let lens = match (focus, aperture) {
            (Some(focus_distance), Some(aperture_size)) if aperture_size > 0.0 => {
                // The parser rejects NaN, so this is the only way to be non-positive.
                if focus_distance <= 0.0 {
                    let node = n.child("FocusDistance").unwrap_or(n);
                    return Err(
                        self.err(node, format!("FocusDistance must be positive, found {focus_distance}"))
                    );
                }
                Some(LensRec { focus_distance, aperture_size })
            }
            (Some(_), None) | (None, Some(_)) => {
                self.warn(n, "depth of field needs both <FocusDistance> and <ApertureSize>; rendering as a pinhole camera");
                None
            }
            _ => None,
        };
        let mut tonemaps = Vec::new();
        for t in n.children_named("Tonemap") {
            tonemaps.push(self.tonemap(t)?);
        }
        let renderer = self.renderer(n)?;
        Ok(CameraRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            position,
            gaze,
            up,
            transforms: self.transform_refs(n)?,
            projection,
            near_distance,
            width,
            height,
            image_name,
            handedness,
            num_samples,
            clamp_samples,
            lens,
            tonemaps,
            renderer,
        })
    }

    /// A camera's `<Renderer>` and `<RendererParams>` (§13.1).
    pub(super) fn renderer(&mut self, n: &Node) -> Result<Renderer> {
        let params = n.child("RendererParams");
        let path = match n.child("Renderer") {
            None => false,
            Some(r) => match r.text.trim() {
                "PathTracing" => true,
                // Some parsers accept the classic tracer's name explicitly.
                "" | "DirectLighting" | "RayTracing" => false,
                other => {
                    return Err(self.err(
                        r,
                        format!(
                            "unknown renderer \"{}\" (expected PathTracing, or DirectLighting for the classic ray tracer)",
                            excerpt(other)
                        ),
                    ));
                }
            },
        };
        if !path {
            if let Some(p) = params
                && !p.text.trim().is_empty()
            {
                self.warn(
                    p,
                    "<RendererParams> only applies to <Renderer>PathTracing</Renderer>; it is ignored",
                );
            }
            return Ok(Renderer::Classic);
        }
        let mut out = PathParams::default();
        for word in params.map(|p| p.text.split_ascii_whitespace()).into_iter().flatten() {
            match word {
                "NextEventEstimation" => out.next_event = true,
                "ImportanceSampling" => out.importance = true,
                "SampleOneLight" => out.one_light = true,
                "MultipleImportanceSampling" => out.mis = true,
                "RussianRoulette" | "UnbiasedRussianRoulette" => {
                    let wanted =
                        if word == "RussianRoulette" { Roulette::Course } else { Roulette::Unbiased };
                    if out.roulette != Roulette::Off && out.roulette != wanted {
                        let p = params.expect("words come from it");
                        return Err(self.err(
                            p,
                            "RussianRoulette (the course's rule) and UnbiasedRussianRoulette exclude each other; keep one",
                        ));
                    }
                    out.roulette = wanted;
                }
                other => {
                    let p = params.expect("words come from it");
                    return Err(self.err(
                        p,
                        format!(
                            "unknown renderer parameter \"{}\" (expected any of {})",
                            excerpt(other),
                            RENDERER_PARAMS.join(", ")
                        ),
                    ));
                }
            }
        }
        if out.one_light
            && !out.next_event
            && let Some(p) = params
        {
            self.warn(p, "SampleOneLight changes how NextEventEstimation samples the lights; without it, it does nothing");
        }
        if out.mis
            && !out.next_event
            && let Some(p) = params
        {
            self.warn(
                p,
                "MultipleImportanceSampling weighs NextEventEstimation's light samples against bounces; without it, it does nothing",
            );
        }
        Ok(Renderer::Path(out))
    }
}
