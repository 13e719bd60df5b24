//! Texture behaviour (homework 4, scene-format.md §8.2, §11): small scenes rendered through the
//! public API, with every expected value worked out by hand from the format's formulas and the
//! conventions Tessera settled on against the course references:
//!
//! * image lookup: i = u·W, j = v·H; `nearest` takes texel (⌊i⌋, ⌊j⌋) (truncation, not rounding);
//!   `bilinear` weights from ⌊i⌋, ⌊j⌋; no `<Interpolation>` means nearest;
//! * T = texel / Normalizer (default 255), then `degamma="true"` raises it to 2.2;
//! * (u, v) = (0, 0) is the top-left texel; `replace_background` uses the raw texel at the pixel
//!   centre u = (x + 0.5)/width, v = (y + 0.5)/height;
//! * checkerboard and Perlin noise use the object-space hit point (before `Transformations`);
//! * image bump maps on transformed spheres displace along the unit world normal.
//!
//! Each test writes its own tiny PNGs (a minimal stored-deflate encoder below) into a temporary
//! directory and loads the scene text with an `FsResolver` pointing there.
//!
//! The common stage: a pinhole camera at the origin looking down -z with its image plane at
//! distance 1, and a textured quad in the plane z = -2 spanning x ∈ [-1, 1], y ∈ [-1.5, 0.5],
//! facing the camera, with TexCoordData u = (x + 1)/2, v = (0.5 − y)/2 (top-left corner uv (0, 0)).
//! A point on the image plane at (a, b) therefore sees the quad at (2a, 2b, -2). The quad's
//! diagonal (y = −x − 0.5) stays away from every point the tests look at.

use std::path::PathBuf;

use tessera::SceneError;
use tessera::assets::FsResolver;
use tessera::image::TileRect;
use tessera::render::{RenderSettings, render_tile};
use tessera::scene::Scene;
use tessera::scene::load::load_scene_str;
use tessera_testkit::TempDir;

// ---------------------------------------------------------------------------------------------
// A small 3-vector (the tests crate does not depend on glam).

#[derive(Clone, Copy, Debug, PartialEq)]
struct V3 {
    x: f64,
    y: f64,
    z: f64,
}

impl V3 {
    const ONE: V3 = V3::splat(1.0);
    const X: V3 = V3::new(1.0, 0.0, 0.0);
    const NEG_Y: V3 = V3::new(0.0, -1.0, 0.0);
    const Z: V3 = V3::new(0.0, 0.0, 1.0);

    const fn new(x: f64, y: f64, z: f64) -> V3 {
        V3 { x, y, z }
    }
    const fn splat(v: f64) -> V3 {
        V3::new(v, v, v)
    }
    fn map(self, f: impl Fn(f64) -> f64) -> V3 {
        V3::new(f(self.x), f(self.y), f(self.z))
    }
    fn dot(self, o: V3) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    fn length_squared(self) -> f64 {
        self.dot(self)
    }
    fn normalize(self) -> V3 {
        self / self.length_squared().sqrt()
    }
    fn powf(self, e: f64) -> V3 {
        self.map(|c| c.powf(e))
    }
    fn max_element(self) -> f64 {
        self.x.max(self.y).max(self.z)
    }
}

impl std::fmt::Display for V3 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "({}, {}, {})", self.x, self.y, self.z)
    }
}

impl std::ops::Add for V3 {
    type Output = V3;
    fn add(self, o: V3) -> V3 {
        V3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}

impl std::ops::Sub for V3 {
    type Output = V3;
    fn sub(self, o: V3) -> V3 {
        V3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}

impl std::ops::Mul<f64> for V3 {
    type Output = V3;
    fn mul(self, k: f64) -> V3 {
        self.map(|c| c * k)
    }
}

impl std::ops::Mul<V3> for f64 {
    type Output = V3;
    fn mul(self, v: V3) -> V3 {
        v * self
    }
}

impl std::ops::Div<f64> for V3 {
    type Output = V3;
    fn div(self, k: f64) -> V3 {
        self.map(|c| c / k)
    }
}

// ---------------------------------------------------------------------------------------------
// A minimal PNG encoder: 8-bit RGB, filter 0, zlib with stored (uncompressed) deflate blocks.

fn crc32(data: &[u8]) -> u32 {
    let mut crc = 0xffff_ffffu32;
    for &byte in data {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xedb8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

fn adler32(data: &[u8]) -> u32 {
    let (mut a, mut b) = (1u32, 0u32);
    for &byte in data {
        a = (a + u32::from(byte)) % 65521;
        b = (b + a) % 65521;
    }
    (b << 16) | a
}

fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// A PNG of `width` x `height` RGB texels given row by row, top row first.
fn png_rgb8(width: u32, height: u32, texels: &[[u8; 3]]) -> Vec<u8> {
    assert_eq!(texels.len(), (width * height) as usize);
    let mut raw = Vec::new();
    for row in texels.chunks(width as usize) {
        raw.push(0); // filter: none
        for t in row {
            raw.extend_from_slice(t);
        }
    }
    let mut zlib = vec![0x78, 0x01];
    let blocks: Vec<&[u8]> = raw.chunks(65_535).collect();
    for (k, block) in blocks.iter().enumerate() {
        zlib.push(u8::from(k + 1 == blocks.len())); // BFINAL, BTYPE = 00 (stored)
        let len = block.len() as u16;
        zlib.extend_from_slice(&len.to_le_bytes());
        zlib.extend_from_slice(&(!len).to_le_bytes());
        zlib.extend_from_slice(block);
    }
    zlib.extend_from_slice(&adler32(&raw).to_be_bytes());
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8-bit, RGB, deflate, filter 0, no interlace
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(&mut png, b"IDAT", &zlib);
    chunk(&mut png, b"IEND", &[]);
    png
}

#[test]
fn the_test_png_encoder_matches_known_checksums() {
    // Standard check values of CRC-32 and Adler-32.
    assert_eq!(crc32(b"123456789"), 0xcbf4_3926);
    assert_eq!(adler32(b"Wikipedia"), 0x11e6_0398);
    // IEND's CRC is fixed by the PNG specification.
    let png = png_rgb8(1, 1, &[[1, 2, 3]]);
    assert_eq!(&png[png.len() - 4..], &[0xae, 0x42, 0x60, 0x82]);
}

// ---------------------------------------------------------------------------------------------
// Scenes.

/// A per-test directory for PNGs; the scene "file" lives there too (it is never written).
struct Stage {
    dir: TempDir,
}

impl Stage {
    fn new(test: &str) -> Stage {
        Stage { dir: TempDir::new(&format!("textures-{test}")) }
    }

    fn write(&self, name: &str, bytes: &[u8]) {
        std::fs::write(self.dir.join(name), bytes).expect("write test image");
    }

    fn png(&self, name: &str, width: u32, height: u32, texels: &[[u8; 3]]) {
        self.write(name, &png_rgb8(width, height, texels));
    }

    fn source(&self) -> PathBuf {
        self.dir.join("scene.xml")
    }

    fn load(&self, xml: &str) -> Result<Scene, SceneError> {
        load_scene_str(xml, &self.source(), &FsResolver { base_dir: self.dir.to_path_buf() })
    }

    fn scene(&self, xml: &str) -> Scene {
        self.load(xml).unwrap_or_else(|e| panic!("scene does not load: {e}\n{xml}"))
    }

    fn error(&self, xml: &str) -> SceneError {
        match self.load(xml) {
            Ok(_) => panic!("the scene loads but should fail:\n{xml}"),
            Err(e) => e,
        }
    }
}

/// Every pixel of the scene's first camera, row by row, as f64.
fn render(scene: &Scene) -> Vec<V3> {
    let cam = &scene.cameras[0];
    let rect = TileRect { x0: 0, y0: 0, width: cam.width, height: cam.height };
    let (px, _) = render_tile(scene, 0, rect, &RenderSettings::default());
    px.iter().map(|p| V3::new(p[0] as f64, p[1] as f64, p[2] as f64)).collect()
}

/// A camera at the origin looking down -z whose image plane (distance 1) spans `[l, r] x [b, t]`
/// with `w` x `h` pixels: pixel (x, y) looks through (l + (x + ½)(r − l)/w, t − (y + ½)(t − b)/h).
fn camera(l: f64, r: f64, b: f64, t: f64, w: u32, h: u32) -> String {
    format!(
        r#"<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
      <NearPlane>{l} {r} {b} {t}</NearPlane><NearDistance>1</NearDistance>
      <ImageResolution>{w} {h}</ImageResolution><ImageName>t.png</ImageName></Camera></Cameras>"#
    )
}

/// A 1x1 camera whose single pixel centre is the image-plane point (a, b), i.e. quad point (2a, 2b).
fn camera_at(a: f64, b: f64) -> String {
    camera(a - 0.01, a + 0.01, b - 0.01, b + 0.01, 1, 1)
}

/// The one-point-light stage: a light of intensity `i` at (0, 0, -0.5), straight in front of
/// the quad point (0, 0, -2) the 1x1 centre camera sees: d = 1.5, d² = 2.25, cos θ = 1.
const LIGHT_I: f64 = 900.0;
const LIGHT_D2: f64 = 2.25;
const AHEAD_LIGHT: &str =
    r#"<PointLight id="1"><Position>0 0 -0.5</Position><Intensity>900 900 900</Intensity></PointLight>"#;

/// The quad scene: `camera`, `lights` (children of `<Lights>`), material 1 with diffuse `kd`,
/// `textures` (children of `<Textures>`) and the quad's `<Textures>` ids.
fn quad_scene(camera: &str, lights: &str, kd: &str, textures: &str, quad_textures: &str) -> String {
    format!(
        r#"<Scene>
  <MaxRecursionDepth>0</MaxRecursionDepth>
  <BackgroundColor>7 7 7</BackgroundColor>
  {camera}
  <Lights>{lights}</Lights>
  <Materials><Material id="1"><DiffuseReflectance>{kd}</DiffuseReflectance></Material></Materials>
  <Textures>
    {textures}
  </Textures>
  <VertexData>-1 0.5 -2  -1 -1.5 -2  1 -1.5 -2  1 0.5 -2</VertexData>
  <TexCoordData>0 0  0 1  1 1  1 0</TexCoordData>
  <Objects>
    <Mesh id="1"><Material>1</Material><Textures>{quad_textures}</Textures><Faces>1 2 3  1 3 4</Faces></Mesh>
  </Objects>
</Scene>"#
    )
}

/// An image texture map over image file `file` (image id 1, map id 1) with extra children.
fn image_map(file: &str, decal: &str, extra: &str) -> String {
    format!(
        r#"<Images><Image id="1">{file}</Image></Images>
    <TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>{decal}</DecalMode>{extra}</TextureMap>"#
    )
}

fn solid(texel: [u8; 3], n: usize) -> Vec<[u8; 3]> {
    vec![texel; n]
}

fn rgb(t: [u8; 3]) -> V3 {
    V3::new(t[0] as f64, t[1] as f64, t[2] as f64)
}

/// `got` equals `want` to a relative tolerance `rel` (absolute below 1).
#[track_caller]
fn assert_close(got: V3, want: V3, rel: f64, what: &str) {
    let ok = [(got.x, want.x), (got.y, want.y), (got.z, want.z)]
        .iter()
        .all(|&(g, w)| (g - w).abs() <= w.abs().max(1.0) * rel);
    assert!(ok, "{what}: got {got}, expected {want} (tolerance {rel} relative)");
}

// ---------------------------------------------------------------------------------------------
// Decal modes.

#[test]
fn replace_kd_uses_the_texel_over_255_as_diffuse_reflectance() {
    let stage = Stage::new("replace_kd");
    let texel = [128, 64, 255];
    stage.png("solid.png", 2, 2, &solid(texel, 4));
    let xml = quad_scene(
        &camera_at(0.0, 0.0),
        AHEAD_LIGHT,
        "1 1 1",
        &image_map("solid.png", "replace_kd", ""),
        "1",
    );
    let got = render(&stage.scene(&xml))[0];
    // L = kd · I / d² · cos θ with kd = texel / 255, I = 900, d² = 2.25, cos θ = 1:
    // (128/255 · 400, 64/255 · 400, 400) = (200.784…, 100.392…, 400).
    let kd = rgb(texel) / 255.0;
    let want = kd * LIGHT_I / LIGHT_D2;
    assert_close(got, want, 1e-5, "replace_kd");
    assert_close(got, V3::new(200.784_313_7, 100.392_156_9, 400.0), 1e-6, "replace_kd (by hand)");
}

#[test]
fn without_a_texture_the_material_kd_is_used() {
    // The control for the decal tests: the same stage with no texture gives kd · I / d².
    let stage = Stage::new("no_texture");
    let xml = quad_scene(&camera_at(0.0, 0.0), AHEAD_LIGHT, "0.2 0.4 0.6", "", "");
    let got = render(&stage.scene(&xml))[0];
    assert_close(got, V3::new(0.2, 0.4, 0.6) * 400.0, 1e-5, "untextured");
}

#[test]
fn replace_all_with_normalizer_1_returns_the_raw_texel_unlit() {
    let stage = Stage::new("replace_all");
    let texel = [200, 100, 50];
    stage.png("solid.png", 2, 2, &solid(texel, 4));
    // A light straight ahead and a white kd: none of it may show.
    let map = image_map("solid.png", "replace_all", "<Normalizer>1</Normalizer>");
    let xml = quad_scene(&camera_at(0.0, 0.0), AHEAD_LIGHT, "1 1 1", &map, "1");
    assert_eq!(render(&stage.scene(&xml))[0], V3::new(200.0, 100.0, 50.0));
    // Without lights at all the result is the same: replace_all is the surface's radiance.
    let dark = quad_scene(&camera_at(0.0, 0.0), "", "0 0 0", &map, "1");
    assert_eq!(render(&stage.scene(&dark))[0], V3::new(200.0, 100.0, 50.0));
}

#[test]
fn blend_kd_averages_material_kd_and_texture() {
    let stage = Stage::new("blend_kd");
    let texel = [255, 0, 102]; // T = (1, 0, 0.4)
    stage.png("solid.png", 2, 2, &solid(texel, 4));
    let xml = quad_scene(
        &camera_at(0.0, 0.0),
        AHEAD_LIGHT,
        "0.2 0.4 0.6",
        &image_map("solid.png", "blend_kd", ""),
        "1",
    );
    let got = render(&stage.scene(&xml))[0];
    // kd = ((0.2, 0.4, 0.6) + (1, 0, 0.4)) / 2 = (0.6, 0.2, 0.5); L = kd · 400 = (240, 80, 200).
    let kd = (V3::new(0.2, 0.4, 0.6) + rgb(texel) / 255.0) / 2.0;
    assert_close(got, kd * LIGHT_I / LIGHT_D2, 1e-5, "blend_kd");
    assert_close(got, V3::new(240.0, 80.0, 200.0), 1e-5, "blend_kd (by hand)");
}

#[test]
fn degamma_raises_the_normalised_texel_to_2_2() {
    let stage = Stage::new("degamma");
    let texel = [128, 64, 255];
    stage.png("solid.png", 2, 2, &solid(texel, 4));
    let textures = r#"<Images><Image id="1">solid.png</Image></Images>
    <TextureMap id="1" type="image" degamma="true"><ImageId>1</ImageId><DecalMode>replace_all</DecalMode></TextureMap>"#;
    let xml = quad_scene(&camera_at(0.0, 0.0), "", "1 1 1", textures, "1");
    let got = render(&stage.scene(&xml))[0];
    // T = (texel / 255)^2.2: (0.50196^2.2, 0.25098^2.2, 1) = (0.21952…, 0.04787…, 1).
    let want = (rgb(texel) / 255.0).powf(2.2);
    assert_close(got, want, 1e-6, "degamma");
    assert_close(got, V3::new(0.219_52, 0.047_87, 1.0), 1e-4, "degamma (by hand)");
    // And without degamma the same map gives texel / 255.
    let plain = textures.replace(r#" degamma="true""#, "");
    let xml = quad_scene(&camera_at(0.0, 0.0), "", "1 1 1", &plain, "1");
    assert_close(render(&stage.scene(&xml))[0], rgb(texel) / 255.0, 1e-6, "no degamma");
}

// ---------------------------------------------------------------------------------------------
// Image lookup.

#[test]
fn nearest_truncates_texel_coordinates() {
    let stage = Stage::new("nearest");
    let (red, blue) = ([255, 0, 0], [0, 0, 255]);
    stage.png("two.png", 2, 1, &[red, blue]);
    // Two pixels whose centres are image-plane x = ∓0.01, i.e. quad x = ∓0.02, u = 0.49 and 0.51:
    // i = u · 2 = 0.98 and 1.02, so truncation takes texel 0 (red) and texel 1 (blue).
    // (Rounding would make both blue.)
    let cam = camera(-0.02, 0.02, -0.01, 0.01, 2, 1);
    let map = image_map("two.png", "replace_all", "<Normalizer>1</Normalizer>");
    let px = render(&stage.scene(&quad_scene(&cam, "", "1 1 1", &map, "1")));
    assert_eq!(px, vec![rgb(red), rgb(blue)], "nearest at u = 0.49 | 0.51");
    // A map without <Interpolation> is nearest too.
    let explicit = image_map(
        "two.png",
        "replace_all",
        "<Normalizer>1</Normalizer><Interpolation>nearest</Interpolation>",
    );
    let px2 = render(&stage.scene(&quad_scene(&cam, "", "1 1 1", &explicit, "1")));
    assert_eq!(px, px2, "absent Interpolation is nearest");

    // u = 0.26 (quad x = -0.48): i = 0.52 truncates to texel 0 (rounding would pick texel 1).
    let px = render(&stage.scene(&quad_scene(&camera_at(-0.24, 0.0), "", "1 1 1", &map, "1")));
    assert_eq!(px[0], rgb(red), "nearest at u = 0.26");
    // u = 0.74 (quad x = 0.48): i = 1.48 -> texel 1.
    let px = render(&stage.scene(&quad_scene(&camera_at(0.24, 0.0), "", "1 1 1", &map, "1")));
    assert_eq!(px[0], rgb(blue), "nearest at u = 0.74");
}

/// A 4x2 image with distinct texels t(col, row).
const T4X2: [[u8; 3]; 8] = [
    // row 0
    [10, 10, 10],
    [100, 0, 50],
    [200, 40, 0],
    [0, 0, 0],
    // row 1
    [20, 20, 20],
    [0, 200, 100],
    [40, 80, 250],
    [255, 255, 255],
];

#[test]
fn bilinear_and_nearest_follow_the_lookup_formulas() {
    let stage = Stage::new("bilinear");
    stage.png("four.png", 4, 2, &T4X2);
    // Pixel centre at image-plane (-0.2, -0.1): quad point (-0.4, -0.2, -2), so
    // u = (x + 1)/2 = 0.3, v = (0.5 − y)/2 = 0.35; i = u·4 = 1.2, j = v·2 = 0.7.
    let cam = camera_at(-0.2, -0.1);
    let t = |col: usize, row: usize| rgb(T4X2[row * 4 + col]);

    // Bilinear (§11.5): p = 1, q = 0, dx = 0.2, dy = 0.7; weights
    // (1−dx)(1−dy) = 0.24, dx(1−dy) = 0.06, (1−dx)dy = 0.56, dx·dy = 0.14:
    //   R = 0.24·100 + 0.06·200 + 0.56·0   + 0.14·40  = 41.6
    //   G = 0.24·0   + 0.06·40  + 0.56·200 + 0.14·80  = 125.6
    //   B = 0.24·50  + 0.06·0   + 0.56·100 + 0.14·250 = 103
    let bilinear = image_map(
        "four.png",
        "replace_all",
        "<Normalizer>1</Normalizer><Interpolation>bilinear</Interpolation>",
    );
    let got = render(&stage.scene(&quad_scene(&cam, "", "1 1 1", &bilinear, "1")))[0];
    let (dx, dy) = (0.2, 0.7);
    let formula = (1.0 - dx) * (1.0 - dy) * t(1, 0)
        + dx * (1.0 - dy) * t(2, 0)
        + (1.0 - dx) * dy * t(1, 1)
        + dx * dy * t(2, 1);
    assert_close(formula, V3::new(41.6, 125.6, 103.0), 1e-12, "hand arithmetic");
    assert_close(got, formula, 1e-5, "bilinear at (u, v) = (0.3, 0.35)");

    // Nearest: texel (⌊1.2⌋, ⌊0.7⌋) = t(1, 0) = (100, 0, 50). (Rounding would give t(1, 1).)
    let nearest = image_map(
        "four.png",
        "replace_all",
        "<Normalizer>1</Normalizer><Interpolation>nearest</Interpolation>",
    );
    let got = render(&stage.scene(&quad_scene(&cam, "", "1 1 1", &nearest, "1")))[0];
    assert_eq!(got, t(1, 0), "nearest at (u, v) = (0.3, 0.35)");

    // The default Normalizer (255) divides the same bilinear value: 41.6/255, 125.6/255, 103/255.
    let normalised = image_map("four.png", "replace_all", "<Interpolation>bilinear</Interpolation>");
    let got = render(&stage.scene(&quad_scene(&cam, "", "1 1 1", &normalised, "1")))[0];
    assert_close(got, formula / 255.0, 1e-5, "bilinear / 255");
}

/// A 2x2 quad at depth `depth` (x, y ∈ [−1, 1], z = −depth; u = (x + 1)/2 + 7/128,
/// v = (1 − y)/2 + 7/128, so the axis point (0, 0) has uv (71/128, 71/128), texel point (35.5,
/// 35.5) of a 64x64 image), seen from the origin by a `w` x `w` camera whose image plane
/// (distance 1) spans ±`half`, showing `map`.
fn far_quad(depth: f64, half: f64, w: u32, map: &str) -> String {
    format!(
        r#"<Scene>
  <MaxRecursionDepth>0</MaxRecursionDepth>
  <BackgroundColor>7 7 7</BackgroundColor>
  {}
  <Lights></Lights>
  <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
  <Textures>{map}</Textures>
  <VertexData>-1 1 -{depth}  -1 -1 -{depth}  1 -1 -{depth}  1 1 -{depth}</VertexData>
  <TexCoordData>{o} {o}  {o} {p}  {p} {p}  {p} {o}</TexCoordData>
  <Objects>
    <Mesh id="1"><Material>1</Material><Textures>1</Textures><Faces>1 2 3  1 3 4</Faces></Mesh>
  </Objects>
</Scene>"#,
        camera(-half, half, -half, half, w, w),
        o = 7.0 / 128.0,
        p = 1.0 + 7.0 / 128.0,
    )
}

/// A `n` x `n` checkerboard of black and white squares of `cell` texels.
fn checker(n: usize, cell: usize) -> Vec<[u8; 3]> {
    (0..n * n)
        .map(|k| if ((k % n) / cell + (k / n) / cell).is_multiple_of(2) { [0; 3] } else { [255; 3] })
        .collect()
}

#[test]
fn trilinear_is_bilinear_close_up_and_the_mean_far_away() {
    // §11.5 trilinear: the mip level follows the pixel's footprint. On this quad seen head-on,
    // a pixel of angular width p (= image-plane width / near distance 1) covers p·depth world
    // units, p·depth/2 in u, i.e. 64·p·depth/2 texels of a 64-texel-wide image.
    let stage = Stage::new("trilinear");
    let map = |file: &str, interp: &str| {
        image_map(
            file,
            "replace_all",
            &format!("<Normalizer>1</Normalizer><Interpolation>{interp}</Interpolation>"),
        )
    };
    // Close up, a pixel covers less than a texel: exactly the bilinear lookup (level 0), on a
    // texture with distinct texels. 8x8 pixels of width 0.0025 at depth 2: 0.16 texels each.
    let noise: Vec<[u8; 3]> = (0..64 * 64)
        .map(|k: usize| [(k * 37 % 251) as u8, (k * 101 % 241) as u8, (k * 7 % 256) as u8])
        .collect();
    stage.png("noise.png", 64, 64, &noise);
    let tri = render(&stage.scene(&far_quad(2.0, 0.01, 8, &map("noise.png", "trilinear"))));
    let bil = render(&stage.scene(&far_quad(2.0, 0.01, 8, &map("noise.png", "bilinear"))));
    assert_eq!(tri, bil, "magnified trilinear = bilinear");

    // Far away, one pixel covers the whole 1-texel checkerboard: the mean, 127.5. Nearest still
    // shows a single texel (bilinear happens to sit on a texel corner here, so it is grey too).
    stage.png("checker.png", 64, 64, &checker(64, 1));
    // Pixel width 0.02 at depth 100: 64 texels across -> λ = 6, the 1x1 level.
    let far = |interp: &str| render(&stage.scene(&far_quad(100.0, 0.01, 1, &map("checker.png", interp))))[0];
    assert_close(far("trilinear"), V3::splat(127.5), 1e-6, "far trilinear");
    let v = far("nearest").x;
    assert!(v == 0.0 || v == 255.0, "nearest aliases: {v}");

    // Squares of 8 texels: the pixel centre, texel point (35.5, 35.5), is the middle of the
    // black square (4, 4), which every level down to 8x8 (one texel per square, λ = 3) still
    // resolves; from λ = 4 on (4x4: each texel averages 2x2 squares) it is grey, and in
    // between the two levels mix linearly. At depth d a pixel of width 0.02 spans 0.64·d
    // texels: λ = log2(0.64·d).
    stage.png("squares.png", 64, 64, &checker(64, 8));
    let at =
        |depth: f64| render(&stage.scene(&far_quad(depth, 0.01, 1, &map("squares.png", "trilinear"))))[0].x;
    let lambda = |l: f64| 2f64.powf(l) / 0.64;
    for (depth, want) in [
        (1.0, 0.0),                         // λ < 0: level 0
        (lambda(2.5), 0.0),                 // levels 2 and 3, both black here
        (lambda(3.0 + 0.25), 0.25 * 127.5), // a quarter of the way to level 4
        (lambda(3.0 + 1.5f64.log2()), 127.5 * 1.5f64.log2()),
        (lambda(4.0), 127.5),
        (500.0, 127.5), // past the last level
    ] {
        let got = at(depth);
        assert!((got - want).abs() < 1e-3, "depth {depth}: {got}, expected {want}");
    }
}

#[test]
fn uv_origin_is_the_top_left_texel() {
    // The 4x2 image on the quad: the quad's top-left corner region shows t(0, 0), its
    // bottom-right t(3, 1), no v flip (§8.2).
    let stage = Stage::new("uv_origin");
    stage.png("four.png", 4, 2, &T4X2);
    let map = image_map("four.png", "replace_all", "<Normalizer>1</Normalizer>");
    // Image-plane (-0.45, 0.2) -> quad (-0.9, 0.4): u = 0.05, v = 0.05 -> texel (0, 0).
    let top_left = render(&stage.scene(&quad_scene(&camera_at(-0.45, 0.2), "", "1 1 1", &map, "1")))[0];
    assert_eq!(top_left, rgb(T4X2[0]));
    // Image-plane (0.45, -0.7) -> quad (0.9, -1.4): u = 0.95, v = 0.95 -> texel (3, 1).
    let bottom_right = render(&stage.scene(&quad_scene(&camera_at(0.45, -0.7), "", "1 1 1", &map, "1")))[0];
    assert_eq!(bottom_right, rgb(T4X2[7]));
}

#[test]
fn spheres_compute_their_own_uv() {
    // §11.4: u = (π − atan2(z, x)) / 2π, v = acos(y / r) / π in object space. A unit sphere at
    // the origin with a 3x1 image, seen along each axis by a 1x1 camera at distance 5:
    //   from +z the hit is (0, 0, 1): φ = π/2  -> u = 0.25, i = 0.75 -> texel 0
    //   from +x the hit is (1, 0, 0): φ = 0    -> u = 0.5,  i = 1.5  -> texel 1
    //   from -z the hit is (0, 0, -1): φ = -π/2 -> u = 0.75, i = 2.25 -> texel 2
    // (v = 0.5 on the equator; the image has one row.)
    let stage = Stage::new("sphere_uv");
    let texels = [[255, 0, 0], [0, 255, 0], [0, 0, 255]];
    stage.png("three.png", 3, 1, &texels);
    for (position, gaze, texel) in
        [("0 0 5", "0 0 -1", texels[0]), ("5 0 0", "-1 0 0", texels[1]), ("0 0 -5", "0 0 1", texels[2])]
    {
        let xml = format!(
            r#"<Scene>
  <Cameras><Camera id="1"><Position>{position}</Position><Gaze>{gaze}</Gaze><Up>0 1 0</Up>
    <NearPlane>-0.01 0.01 -0.01 0.01</NearPlane><NearDistance>1</NearDistance>
    <ImageResolution>1 1</ImageResolution><ImageName>t.png</ImageName></Camera></Cameras>
  <Lights></Lights>
  <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
  <Textures>{}</Textures>
  <VertexData>0 0 0</VertexData>
  <Objects><Sphere id="1"><Material>1</Material><Textures>1</Textures><Center>1</Center><Radius>1</Radius></Sphere></Objects>
</Scene>"#,
            image_map("three.png", "replace_all", "<Normalizer>1</Normalizer>")
        );
        assert_eq!(render(&stage.scene(&xml))[0], rgb(texel), "sphere seen from {position}");
    }
}

// ---------------------------------------------------------------------------------------------
// Procedural textures.

#[test]
fn checkerboard_uses_c_truncation_on_the_object_point() {
    let stage = Stage::new("checkerboard");
    // Four pixels with centres at image-plane x = -0.375, -0.125, 0.125, 0.375 and y = 0.05:
    // quad points x = -0.75, -0.25, 0.25, 0.75, y = 0.1, z = -2.
    let cam = camera(-0.5, 0.5, -0.075, 0.175, 4, 1);
    let textures = r#"<TextureMap id="1" type="checkerboard"><DecalMode>replace_kd</DecalMode>
      <BlackColor>0.1 0.2 0.3</BlackColor><WhiteColor>0.9 0.8 0.7</WhiteColor>
      <Scale>1</Scale><Offset>0.5</Offset></TextureMap>"#;
    let light = V3::new(0.0, 0.0, -0.5);
    let lights =
        r#"<PointLight id="1"><Position>0 0 -0.5</Position><Intensity>900 900 900</Intensity></PointLight>"#;
    let px = render(&stage.scene(&quad_scene(&cam, lights, "1 1 1", textures, "1")));
    // With Offset 0.5, Scale 1 (C truncation toward zero, non-zero remainder = odd):
    //   z: (int)(-2 + 0.5) = -1 -> odd;   y: (int)(0.1 + 0.5) = 0 -> even
    //   x = -0.75: (int)(-0.25) = 0 even;  x = -0.25: (int)(0.25) = 0 even
    //   x =  0.25: (int)(0.75)  = 0 even;  x =  0.75: (int)(1.25) = 1 odd
    // colour = ((a != b) != c) ? Black : White -> Black, Black, Black, White.
    // (With floor instead of truncation x = -0.75 would fall in cell -1 and be White.)
    let black = V3::new(0.1, 0.2, 0.3);
    let white = V3::new(0.9, 0.8, 0.7);
    for (k, (x, kd)) in [(-0.75, black), (-0.25, black), (0.25, black), (0.75, white)].into_iter().enumerate()
    {
        let p = V3::new(x, 0.1, -2.0);
        let to_light = light - p;
        let cos = to_light.normalize().z; // n = +z
        let want = kd * LIGHT_I * cos / to_light.length_squared();
        assert_close(px[k], want, 1e-5, &format!("checkerboard pixel {k} (x = {x})"));
    }
}

#[test]
fn perlin_noise_vanishes_on_lattice_points() {
    // Course Perlin noise is 0 at integer points (§11.9); the quad point (0, 0, -2) seen by the
    // centre pixel is one (the quad is untransformed: object space is world space; NoiseScale 1).
    let stage = Stage::new("perlin");
    let map = |conversion: &str| {
        format!(
            r#"<TextureMap id="1" type="perlin"><DecalMode>replace_kd</DecalMode>
      <NoiseConversion>{conversion}</NoiseConversion><NoiseScale>1</NoiseScale></TextureMap>"#
        )
    };
    // linear: kd = (0 + 1)/2 = 0.5 -> L = 0.5 · 400 = 200.
    let xml = quad_scene(&camera_at(0.0, 0.0), AHEAD_LIGHT, "1 1 1", &map("linear"), "1");
    assert_close(render(&stage.scene(&xml))[0], V3::splat(200.0), 1e-6, "perlin linear");
    // absval: kd = |0| = 0 -> black.
    let xml = quad_scene(&camera_at(0.0, 0.0), AHEAD_LIGHT, "1 1 1", &map("absval"), "1");
    let got = render(&stage.scene(&xml))[0];
    assert!(got.max_element() < 1e-6, "perlin absval at a lattice point: {got}");
}

// ---------------------------------------------------------------------------------------------
// Background.

#[test]
fn replace_background_shows_the_raw_texel_at_each_pixel_centre() {
    let stage = Stage::new("background");
    let texels = [[10, 20, 30], [200, 100, 0], [0, 255, 128], [64, 65, 66]];
    stage.png("bg.png", 2, 2, &texels);
    // Nothing to hit; a 4x4 frame: pixel (x, y) samples u = (x + ½)/4, v = (y + ½)/4, so
    // i = u·2 ∈ {0.25, 0.75, 1.25, 1.75} truncates to 0, 0, 1, 1: each quadrant shows one
    // texel, raw (no /255, although the map has the default Normalizer).
    let xml = format!(
        r#"<Scene>
  <BackgroundColor>1 2 3</BackgroundColor>
  {}
  <Lights></Lights>
  <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
  <Textures>
    <Images><Image id="1">bg.png</Image></Images>
    <TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_background</DecalMode></TextureMap>
  </Textures>
  <VertexData></VertexData>
  <Objects></Objects>
</Scene>"#,
        camera(-1.0, 1.0, -1.0, 1.0, 4, 4)
    );
    let px = render(&stage.scene(&xml));
    for y in 0..4 {
        for x in 0..4 {
            let texel = texels[(y / 2) * 2 + x / 2];
            assert_eq!(px[y * 4 + x], rgb(texel), "background pixel ({x}, {y})");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Normal mapping.

#[test]
fn normal_maps_bend_the_shading_normal_in_tangent_space() {
    let stage = Stage::new("normal_map");
    // The centre pixel sees the quad at p = (0, 0, -2), uv = (0.5, 0.25). Tangent frame of the
    // quad: T = ∂p/∂u along +x, B = ∂p/∂v along -y (v grows downwards), N = +z.
    let p = V3::new(0.0, 0.0, -2.0);
    let (t_axis, b_axis, n_axis) = (V3::X, V3::NEG_Y, V3::Z);
    let lit = |light: V3, textures: &str, ids: &str| -> f64 {
        let lights = format!(
            r#"<PointLight id="1"><Position>{} {} {}</Position><Intensity>900 900 900</Intensity></PointLight>"#,
            light.x, light.y, light.z
        );
        let xml = quad_scene(&camera_at(0.0, 0.0), &lights, "0.5 0.5 0.5", textures, ids);
        render(&stage.scene(&xml))[0].x
    };
    // Expected: kd · I / d² · (n · wi) with n = normalize(n_t.x T + n_t.y B + n_t.z N),
    // n_t = 2 · texel / 255 − 1 (§11.6a).
    let predicted = |light: V3, texel: Option<[u8; 3]>| -> f64 {
        let n = match texel {
            None => n_axis,
            Some(t) => {
                let nt = rgb(t) * (2.0 / 255.0) - V3::ONE;
                (nt.x * t_axis + nt.y * b_axis + nt.z * n_axis).normalize()
            }
        };
        let to_light = light - p;
        0.5 * LIGHT_I * n.dot(to_light.normalize()) / to_light.length_squared()
    };
    let map = |file: &str| image_map(file, "replace_normal", "");

    // Flat blue (128, 128, 255) is +Z up to 8-bit rounding: n_t = (1/255, 1/255, 1), a tilt of
    // 0.3°. With the light 45° to the right (at (1, 0, -1)) the shading barely moves: the plain
    // quad gives 0.5 · 900 / 2 · cos 45° = 159.10; the map changes it by under 1 %.
    stage.png("flat.png", 2, 2, &solid([128, 128, 255], 4));
    let right = V3::new(1.0, 0.0, -1.0);
    let plain = lit(right, "", "");
    assert!((plain - 225.0 * std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-3, "plain quad: {plain}");
    let flat = lit(right, &map("flat.png"), "1");
    assert!((flat - plain).abs() < 0.01 * plain, "flat normal map: {flat} vs {plain}");
    assert!((flat - predicted(right, Some([128, 128, 255]))).abs() < 1e-3, "flat normal map: {flat}");

    // Tilted towards +u (right): n_t ≈ (0.6, 0, 0.8) -> texel (204, 128, 230).
    // Light on the right: n · wi grows from cos 45° = 0.707 to ≈ 0.990 -> brighter;
    // light on the left (at (-1, 0, -1)): it drops to ≈ 0.144 -> darker.
    let right_tilt = [204, 128, 230];
    stage.png("right.png", 2, 2, &solid(right_tilt, 4));
    let left = V3::new(-1.0, 0.0, -1.0);
    let towards = lit(right, &map("right.png"), "1");
    let away = lit(left, &map("right.png"), "1");
    assert!(towards > 1.3 * plain, "tilted towards the light: {towards} vs plain {plain}");
    assert!(away < 0.3 * plain, "tilted away from the light: {away} vs plain {plain}");
    assert!((towards - predicted(right, Some(right_tilt))).abs() < 1e-3, "towards: {towards}");
    assert!((away - predicted(left, Some(right_tilt))).abs() < 1e-3, "away: {away}");

    // Green tilts along B = ∂p/∂v, i.e. down the image (-y): n_t ≈ (0, 0.6, 0.8) brightens a
    // light below the point and darkens one above.
    let down_tilt = [128, 204, 230];
    stage.png("down.png", 2, 2, &solid(down_tilt, 4));
    let below = V3::new(0.0, -1.0, -1.0);
    let above = V3::new(0.0, 1.0, -1.0);
    let lit_below = lit(below, &map("down.png"), "1");
    let lit_above = lit(above, &map("down.png"), "1");
    assert!(
        lit_below > 1.3 * plain && lit_above < 0.3 * plain,
        "green tilt: below {lit_below}, above {lit_above}"
    );
    assert!((lit_below - predicted(below, Some(down_tilt))).abs() < 1e-3, "below: {lit_below}");
    assert!((lit_above - predicted(above, Some(down_tilt))).abs() < 1e-3, "above: {lit_above}");
}

// ---------------------------------------------------------------------------------------------
// Bump mapping.

/// A unit sphere at the origin under `transformations` (empty: none), seen by a 1x1 camera at
/// `eye` looking along `gaze`, lit by one light at `light`; diffuse white, optionally bump-mapped
/// (BumpFactor 0.05) by `ramp.png`. Returns the pixel's red channel.
fn bumped_sphere(stage: &Stage, transformations: &str, eye: V3, gaze: V3, light: V3, bump: bool) -> f64 {
    let (scaling, refs) = match transformations {
        "" => (String::new(), String::new()),
        s => (
            format!("<Transformations><Scaling id=\"1\">{s}</Scaling></Transformations>"),
            "<Transformations>s1</Transformations>".to_string(),
        ),
    };
    let xml = format!(
        r#"<Scene>
  <MaxRecursionDepth>0</MaxRecursionDepth>
  <Cameras><Camera id="1"><Position>{} {} {}</Position><Gaze>{} {} {}</Gaze><Up>0 1 0</Up>
    <NearPlane>-0.01 0.01 -0.01 0.01</NearPlane><NearDistance>1</NearDistance>
    <ImageResolution>1 1</ImageResolution><ImageName>t.png</ImageName></Camera></Cameras>
  <Lights><PointLight id="1"><Position>{} {} {}</Position><Intensity>900 900 900</Intensity></PointLight></Lights>
  <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
  <Textures>{}</Textures>
  {scaling}
  <VertexData>0 0 0</VertexData>
  <Objects><Sphere id="1"><Material>1</Material>{}{refs}<Center>1</Center><Radius>1</Radius></Sphere></Objects>
</Scene>"#,
        eye.x,
        eye.y,
        eye.z,
        gaze.x,
        gaze.y,
        gaze.z,
        light.x,
        light.y,
        light.z,
        image_map("ramp.png", "bump_normal", "<BumpFactor>0.05</BumpFactor>"),
        if bump { "<Textures>1</Textures>" } else { "" },
    );
    render(&stage.scene(&xml))[0].x
}

#[test]
fn bump_maps_on_mirrored_ellipsoids_displace_along_the_unit_world_normal() {
    // bump_mapping_transformed (a sphere scaled by (-2, 1, 1)) settles this: the references bump
    // a transformed sphere with ∂p/∂u, ∂p/∂v carried by the transformation but the height along
    // the *unit* world normal, not along the object normal carried as a vector (length 2 where
    // the x scale of 2 stretches it).
    //
    // The unit sphere's point (1, 0, 0) (u = v = 0.5) has T = ∂p/∂u = (0, 0, −2π),
    // B = ∂p/∂v = (0, −π, 0), n = +x. Scaled by (−2, 1, 1) that object point lands at world
    // (−2, 0, 0) with the same T and B (no x component) and normal −x. So the ellipsoid seen
    // from −x with a light mirrored in x must shade like the plain sphere seen from +x: n·l is
    // unchanged by the mirror as long as the tilt (slope / |T|, slope / |B|) is the same, which
    // holds only if the height is not stretched by the x scale along the normal.
    let stage = Stage::new("bump_mirrored");
    // Grey ramp: height grows by 20 per texel along u and 10 per texel along v; (u, v) = (0.5,
    // 0.5) is texel (2, 2) (or (1, 1) by rounding), whose +1 neighbours are inside the image.
    let ramp: Vec<[u8; 3]> = (0..16)
        .map(|k| {
            let (x, y) = (k % 4, k / 4);
            [(60 + 20 * x + 10 * y) as u8; 3]
        })
        .collect();
    stage.png("ramp.png", 4, 4, &ramp);
    let plain_eye = V3::new(5.0, 0.0, 0.0);
    let plain_light = V3::new(3.0, 1.0, 0.5);
    let mirrored_eye = V3::new(-6.0, 0.0, 0.0);
    let mirrored_light = V3::new(-4.0, 1.0, 0.5);
    let neg_x = V3::new(-1.0, 0.0, 0.0);
    let plain = bumped_sphere(&stage, "", plain_eye, neg_x, plain_light, true);
    let mirrored = bumped_sphere(&stage, "-2 1 1", mirrored_eye, V3::X, mirrored_light, true);
    let unbumped = bumped_sphere(&stage, "", plain_eye, neg_x, plain_light, false);
    let unbumped_mirrored = bumped_sphere(&stage, "-2 1 1", mirrored_eye, V3::X, mirrored_light, false);
    // The geometry is mirrored exactly: without the bump map both shade alike.
    assert!((unbumped - unbumped_mirrored).abs() < 1e-6 * unbumped, "{unbumped} vs {unbumped_mirrored}");
    // The ramp bends the normal noticeably (149.6 -> 163.4; the test would tell nothing
    // otherwise)...
    assert!((plain - unbumped).abs() > 0.05 * unbumped, "bumped {plain} vs plain {unbumped}");
    // ...and by the same amount on the mirrored ellipsoid. Displacing along the object normal
    // carried as a vector (length 2 here) doubles the tilt and gives 169.0 instead.
    assert!((mirrored - plain).abs() < 1e-6 * plain, "mirrored ellipsoid {mirrored} vs sphere {plain}");
}

// ---------------------------------------------------------------------------------------------
// Errors name the file, the element and the id.

fn line_of(xml: &str, needle: &str) -> u32 {
    xml.lines().position(|l| l.contains(needle)).expect("needle in xml") as u32 + 1
}

#[test]
fn a_missing_image_file_names_the_file_and_the_image_id() {
    let stage = Stage::new("missing_image");
    let textures = r#"<Images><Image id="img7">nope/missing.png</Image></Images>
    <TextureMap id="1" type="image"><ImageId>img7</ImageId><DecalMode>replace_kd</DecalMode></TextureMap>"#;
    let xml = quad_scene(&camera_at(0.0, 0.0), AHEAD_LIGHT, "1 1 1", textures, "1");
    let e = stage.error(&xml);
    let msg = e.to_string();
    assert!(msg.contains("missing.png"), "{msg}");
    assert!(msg.contains("image id img7"), "{msg}");
    assert_eq!(e.file, stage.source(), "{msg}");
    assert_eq!(e.loc.line, Some(line_of(&xml, r#"<Image id="img7">"#)), "{msg}");
}

#[test]
fn an_undecodable_image_names_the_file() {
    let stage = Stage::new("garbage_image");
    stage.write("x.png", b"this is not an image at all, just some text pretending to be a PNG");
    let xml =
        quad_scene(&camera_at(0.0, 0.0), AHEAD_LIGHT, "1 1 1", &image_map("x.png", "replace_kd", ""), "1");
    let e = stage.error(&xml);
    let msg = e.to_string();
    assert!(msg.contains("x.png"), "{msg}");
    assert!(msg.contains("image id 1"), "{msg}");
    assert_eq!(e.loc.line, Some(line_of(&xml, r#"<Image id="1">"#)), "{msg}");
}

#[test]
fn an_undefined_texture_id_names_the_id_and_the_object() {
    let stage = Stage::new("undefined_texture");
    stage.png("solid.png", 2, 2, &solid([1, 2, 3], 4));
    let xml = quad_scene(
        &camera_at(0.0, 0.0),
        AHEAD_LIGHT,
        "1 1 1",
        &image_map("solid.png", "replace_kd", ""),
        "9",
    );
    let e = stage.error(&xml);
    let msg = e.to_string();
    assert!(msg.contains(r#"texture "9""#), "{msg}");
    assert!(msg.contains(r#"<Mesh id="1">"#), "{msg}");
    assert_eq!(e.loc.line, Some(line_of(&xml, r#"<Mesh id="1">"#)), "{msg}");
}

#[test]
fn a_texture_map_without_decal_mode_names_the_file_and_line() {
    let stage = Stage::new("no_decal");
    stage.png("solid.png", 2, 2, &solid([1, 2, 3], 4));
    let textures = r#"<Images><Image id="1">solid.png</Image></Images>
    <TextureMap id="1" type="image"><ImageId>1</ImageId></TextureMap>"#;
    let xml = quad_scene(&camera_at(0.0, 0.0), AHEAD_LIGHT, "1 1 1", textures, "1");
    let e = stage.error(&xml);
    let msg = e.to_string();
    let line = line_of(&xml, r#"<TextureMap id="1""#);
    let prefix = format!(r#"{}:{line}: <TextureMap id="1">: "#, stage.source().display());
    assert!(msg.starts_with(&prefix), "{msg}\nexpected to start with {prefix}");
    assert!(msg.contains("DecalMode"), "{msg}");
}

#[test]
fn the_stage_geometry_is_what_the_tests_assume() {
    // Guards the hand computations above: the quad point seen by `camera_at(a, b)` is (2a, 2b, -2)
    // with uv ((2a + 1)/2, (0.5 − 2b)/2). A replace_all map over a 4x2 image, nearest, shows the
    // texel of that uv for a grid of points, including points near the quad's diagonal.
    let stage = Stage::new("geometry");
    stage.png("four.png", 4, 2, &T4X2);
    let map = image_map("four.png", "replace_all", "<Normalizer>1</Normalizer>");
    for (a, b) in [(-0.4, 0.15), (-0.1, 0.1), (0.1, -0.3), (0.3, -0.6), (0.2, -0.33), (-0.3, -0.05)] {
        let px = render(&stage.scene(&quad_scene(&camera_at(a, b), "", "1 1 1", &map, "1")))[0];
        let (u, v) = ((2.0 * a + 1.0) / 2.0, (0.5 - 2.0 * b) / 2.0);
        let (col, row) = ((u * 4.0f64).floor() as usize, (v * 2.0f64).floor() as usize);
        assert_eq!(px, rgb(T4X2[row * 4 + col]), "point ({a}, {b}): uv ({u}, {v})");
    }
}
