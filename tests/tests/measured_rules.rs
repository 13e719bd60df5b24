//! Rules of the course's renderer that were settled by measurement against its official images
//! (scene-format.md §6.7, §6.8, §11.10 [MEASURED], and the 2025 references' back-face culling),
//! each pinned on a small scene built here, where the expected outcome is worked out by hand:
//!
//! * rough dielectrics blur what is seen through them (both directions perturbed, §6.7);
//! * checkerboards are evaluated at the object-space point, before `Transformations` (§11.10);
//! * opaque surfaces are lit with their normal as given: seen from behind, a thin quad is lit by
//!   the lights on its front side, and a mirror seen from behind starts its reflected ray on
//!   that side too, like its shadow rays (§6.8);
//! * 2025 JSON scenes cull triangles seen from behind by camera rays, and nothing else culls.

use tessera::assets::FsResolver;
use tessera::image::TileRect;
use tessera::render::{RenderSettings, render_tile};
use tessera::scene::Scene;
use tessera::scene::load::load_scene_str;

fn load(text: &str, name: &str) -> Scene {
    let dir = std::env::temp_dir();
    load_scene_str(text, &dir.join(name), &FsResolver { base_dir: dir.clone() })
        .unwrap_or_else(|e| panic!("scene does not load: {e}\n{text}"))
}

/// Every pixel of the first camera, row by row (red channel; the scenes here are grey).
fn render(scene: &Scene) -> Vec<f32> {
    let cam = &scene.cameras[0];
    let rect = TileRect { x0: 0, y0: 0, width: cam.width, height: cam.height };
    render_tile(scene, 0, rect, &RenderSettings::default()).0.iter().map(|p| p[0]).collect()
}

/// A camera at `pos` looking along `gaze` (up +y) whose image plane at distance 1 spans
/// `[-half_w, half_w] x [-half_h, half_h]`.
fn camera(pos: &str, gaze: &str, half_w: f64, half_h: f64, w: u32, h: u32, spp: u32) -> String {
    format!(
        r#"<Cameras><Camera id="1"><Position>{pos}</Position><Gaze>{gaze}</Gaze><Up>0 1 0</Up>
      <NearPlane>{} {half_w} {} {half_h}</NearPlane><NearDistance>1</NearDistance>
      <ImageResolution>{w} {h}</ImageResolution><NumSamples>{spp}</NumSamples><ImageName>t.png</ImageName></Camera></Cameras>"#,
        -half_w, -half_h
    )
}

// ---------------------------------------------------------------------------------------------
// §6.7: rough glass.

/// One row of 64 pixels across a sharp black | white edge at x = 0 on a wall at z = -4, seen
/// through a glass slab (z from -2 to -2.2, index 1.5) with the given roughness.
fn edge_through_glass(roughness: f64) -> Vec<f32> {
    let xml = format!(
        r#"<Scene><MaxRecursionDepth>4</MaxRecursionDepth>
  {}
  <Lights><AmbientLight>100 100 100</AmbientLight></Lights>
  <Materials>
    <Material id="1"><AmbientReflectance>0 0 0</AmbientReflectance></Material>
    <Material id="2"><AmbientReflectance>1 1 1</AmbientReflectance></Material>
    <Material id="3" type="dielectric"><RefractionIndex>1.5</RefractionIndex><Roughness>{roughness}</Roughness></Material>
  </Materials>
  <VertexData>
    -5 -5 -4   0 -5 -4   0 5 -4   -5 5 -4
     0 -5 -4   5 -5 -4   5 5 -4    0 5 -4
    -5 -5 -2   5 -5 -2   5 5 -2   -5 5 -2
    -5 -5 -2.2 5 -5 -2.2 5 5 -2.2 -5 5 -2.2
  </VertexData>
  <Objects>
    <Mesh id="1"><Material>1</Material><Faces>1 2 3  1 3 4</Faces></Mesh>
    <Mesh id="2"><Material>2</Material><Faces>5 6 7  5 7 8</Faces></Mesh>
    <Mesh id="3"><Material>3</Material><Faces>9 10 11  9 11 12  13 15 14  13 16 15</Faces></Mesh>
  </Objects></Scene>"#,
        camera("0 0 0", "0 0 -1", 0.2, 0.003, 64, 1, 64)
    );
    render(&load(&xml, "glass.xml"))
}

#[test]
fn a_rough_glass_slab_blurs_an_edge_behind_it() {
    // How many pixels lie between 10 % and 90 % of the white plateau.
    let transition = |row: &[f32]| {
        let white = row[row.len() - 1];
        assert!(white > 50.0, "the white side shows through the glass: {row:?}");
        row.iter().filter(|&&v| v > 0.1 * white && v < 0.9 * white).count()
    };
    let clear = edge_through_glass(0.0);
    let rough = edge_through_glass(0.3);
    // Clear glass shifts nothing sideways at normal incidence: the edge stays within a pixel.
    assert!(transition(&clear) <= 1, "clear glass keeps the edge sharp: {clear:?}");
    // Roughness 0.3 spreads directions by about ±0.15 rad on both crossings: the edge blurs over
    // many pixels (each pixel is 0.4/64 wide on the image plane).
    assert!(transition(&rough) >= 6, "rough glass blurs the edge: {rough:?}");
}

// ---------------------------------------------------------------------------------------------
// §11.10: checkerboards in object space.

#[test]
fn a_checkerboard_on_a_scaled_mesh_keeps_object_space_squares() {
    // A quad spanning object x, y in [-1, 1] at z = 0, scaled by 2 along x and moved to z = -5.
    // Checker cells (Scale 1, Offset 10) are one object unit wide: object x in [-1, 0) and
    // [0, 1), world x in [-2, 0) and [0, 2). In world space there would be four cells.
    let xml = format!(
        r#"<Scene>
  {}
  <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
  <Textures><TextureMap id="1" type="checkerboard"><DecalMode>replace_all</DecalMode>
      <BlackColor>0 0 0</BlackColor><WhiteColor>100 100 100</WhiteColor><Scale>1</Scale><Offset>10</Offset></TextureMap></Textures>
  <Transformations><Scaling id="1">2 1 1</Scaling><Translation id="1">0 0 -5</Translation></Transformations>
  <VertexData>-1 -1 0  1 -1 0  1 1 0  -1 1 0</VertexData>
  <Objects><Mesh id="1"><Material>1</Material><Textures>1</Textures><Transformations>s1 t1</Transformations>
    <Faces>1 2 3  1 3 4</Faces></Mesh></Objects></Scene>"#,
        // Eight pixels across world x in [-2, 2] at z = -5 (y = 0.25 stays off the diagonal).
        camera("0 0.25 0", "0 0 -1", 0.4, 0.01, 8, 1, 1)
    );
    let row = render(&load(&xml, "checker.xml"));
    // Object x + 10 in [9, 10): odd -> black (y cell 10 even, z cell 10 even); [10, 11): white.
    assert_eq!(row, vec![0.0, 0.0, 0.0, 0.0, 100.0, 100.0, 100.0, 100.0]);
}

// ---------------------------------------------------------------------------------------------
// §6.8: normals as given.

/// A white diffuse quad at z = -2 facing +z (its front), seen from behind by a camera at
/// z = -4 looking along +z, lit by a point light at `light`; `extra` adds objects.
fn quad_from_behind(material: &str, light: &str, extra_vertices: &str, extra: &str) -> f32 {
    let xml = format!(
        r#"<Scene><MaxRecursionDepth>1</MaxRecursionDepth>
  {}
  <Lights><PointLight id="1"><Position>{light}</Position><Intensity>1000 1000 1000</Intensity></PointLight></Lights>
  <Materials>{material}
    <Material id="9"><AmbientReflectance>1 1 1</AmbientReflectance></Material></Materials>
  <VertexData>-1 -1 -2  1 -1 -2  1 1 -2  -1 1 -2 {extra_vertices}</VertexData>
  <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3  1 3 4</Faces></Mesh>{extra}</Objects></Scene>"#,
        camera("0.1 0.2 -4", "0 0 1", 0.01, 0.01, 1, 1, 1)
    );
    render(&load(&xml, "behind.xml"))[0]
}

const WHITE: &str = r#"<Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material>"#;

#[test]
fn a_thin_quad_seen_from_behind_is_lit_from_its_front() {
    // Light 1 unit in front of the quad's front side, straight over the seen point (0.1, 0.2):
    // E = 1000 / 1², cos = 1.
    let front = quad_from_behind(WHITE, "0.1 0.2 -1", "", "");
    assert!((front - 1000.0).abs() < 1e-3, "lit from its front side: {front}");
    // The same light on the viewer's (back) side lights nothing: the normal is not turned.
    let back = quad_from_behind(WHITE, "0.1 0.2 -3", "", "");
    assert_eq!(back, 0.0, "a light behind the surface does not light it");
    // Shadow rays start on the front side: a blocker between the front and the light shadows
    // it, and the quad itself does not.
    let blocker = r#"<Mesh id="2"><Material>1</Material><Faces>5 6 7</Faces></Mesh>"#;
    let shadowed = quad_from_behind(WHITE, "0.1 0.2 -1", "-5 -5 -1.5  5 -5 -1.5  0 5 -1.5", blocker);
    assert_eq!(shadowed, 0.0, "a blocker on the front side casts its shadow");
}

#[test]
fn a_mirror_seen_from_behind_reflects_from_its_front_side() {
    // A mirror quad (ambient reflectance 0.5, ambient light 50: 25 of its own) seen from behind,
    // with a wall behind the camera at z = -6 (ambient 1·50 = 50). Its reflected ray starts on
    // its front side, x + ε·n with the normal as given, like its shadow rays (§6.8, measured on
    // thin mirror blades): heading back to the viewer's side it meets the quad's own front face
    // (25), not the wall, so the pixel is 25 + 25. Started on the viewer's side it would be
    // 25 + 50.
    let mirror = r#"<Material id="1" type="mirror"><AmbientReflectance>0.5 0.5 0.5</AmbientReflectance><MirrorReflectance>1 1 1</MirrorReflectance></Material>"#;
    let wall = r#"<Mesh id="2"><Material>9</Material><Faces>5 6 7  5 7 8</Faces></Mesh>"#;
    let xml = format!(
        r#"<Scene><MaxRecursionDepth>1</MaxRecursionDepth>
  {}
  <Lights><AmbientLight>50 50 50</AmbientLight></Lights>
  <Materials>{mirror}<Material id="9"><AmbientReflectance>1 1 1</AmbientReflectance></Material></Materials>
  <VertexData>-1 -1 -2  1 -1 -2  1 1 -2  -1 1 -2  -9 -9 -6  9 -9 -6  9 9 -6  -9 9 -6</VertexData>
  <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3  1 3 4</Faces></Mesh>{wall}</Objects></Scene>"#,
        camera("0.1 0.2 -4", "0 0 1", 0.01, 0.01, 1, 1, 1)
    );
    let p = render(&load(&xml, "mirror.xml"))[0];
    assert_eq!(p, 50.0, "the mirror's reflection meets its own front face, not the wall");
}

// ---------------------------------------------------------------------------------------------
// 2025 JSON: camera rays cull back faces.

/// Camera 1 looks from the origin along -z through a grey triangle at z = -2 whose front faces
/// away from it (-z) at a sphere at z = -5 (ambient red). Camera 2 looks straight down at the
/// floor point (0, -3, -10), lit by a light at (0, 5, -10) through a horizontal triangle at
/// y = 1 whose front faces up, so the shadow ray meets its back. `json` picks the dialect.
fn culling_scene(json: bool) -> (f32, f32) {
    let xml = r#"<Scene>
  <Cameras>
    <Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
      <NearPlane>-0.01 0.01 -0.01 0.01</NearPlane><NearDistance>1</NearDistance>
      <ImageResolution>1 1</ImageResolution><ImageName>a.png</ImageName></Camera>
    <Camera id="2"><Position>0 -2 -10</Position><Gaze>0 -1 0</Gaze><Up>0 0 -1</Up>
      <NearPlane>-0.01 0.01 -0.01 0.01</NearPlane><NearDistance>1</NearDistance>
      <ImageResolution>1 1</ImageResolution><ImageName>b.png</ImageName></Camera>
  </Cameras>
  <Lights><AmbientLight>30 30 30</AmbientLight>
    <PointLight id="1"><Position>0 5 -10</Position><Intensity>1000 1000 1000</Intensity></PointLight></Lights>
  <Materials>
    <Material id="1"><AmbientReflectance>0.5 0.5 0.5</AmbientReflectance></Material>
    <Material id="2"><AmbientReflectance>1 0 0</AmbientReflectance></Material>
    <Material id="3"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material>
  </Materials>
  <VertexData>-3 -3 -2  0 3 -2  3 -3 -2  0 0 -5  -50 -3 50  50 -3 50  50 -3 -50  -50 -3 -50
    -3 1 -13  0 1 -7  3 1 -13</VertexData>
  <Objects>
    <Triangle id="1"><Material>1</Material><Indices>1 2 3</Indices></Triangle>
    <Triangle id="2"><Material>1</Material><Indices>9 10 11</Indices></Triangle>
    <Sphere id="1"><Material>2</Material><Center>4</Center><Radius>1</Radius></Sphere>
    <Mesh id="2"><Material>3</Material><Faces>5 6 7  5 7 8</Faces></Mesh>
  </Objects></Scene>"#;
    let text = if json { JSON_TWIN.to_string() } else { xml.to_string() };
    let scene = load(&text, if json { "cull.json" } else { "cull.xml" });
    let first = render(&scene)[0];
    let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
    let floor = render_tile(&scene, 1, rect, &RenderSettings::default()).0[0][0];
    (first, floor)
}

/// The JSON twin of the culling scene (§14.1's mapping, written out by hand).
const JSON_TWIN: &str = r#"{"Scene": {
  "Cameras": {"Camera": [
    {"_id": "1", "Position": "0 0 0", "Gaze": "0 0 -1", "Up": "0 1 0", "NearPlane": "-0.01 0.01 -0.01 0.01",
     "NearDistance": "1", "ImageResolution": "1 1", "ImageName": "a.png"},
    {"_id": "2", "Position": "0 -2 -10", "Gaze": "0 -1 0", "Up": "0 0 -1", "NearPlane": "-0.01 0.01 -0.01 0.01",
     "NearDistance": "1", "ImageResolution": "1 1", "ImageName": "b.png"}]},
  "Lights": {"AmbientLight": "30 30 30",
    "PointLight": {"_id": "1", "Position": "0 5 -10", "Intensity": "1000 1000 1000"}},
  "Materials": {"Material": [
    {"_id": "1", "AmbientReflectance": "0.5 0.5 0.5"},
    {"_id": "2", "AmbientReflectance": "1 0 0"},
    {"_id": "3", "DiffuseReflectance": "1 1 1"}]},
  "VertexData": {"_data": "-3 -3 -2  0 3 -2  3 -3 -2  0 0 -5  -50 -3 50  50 -3 50  50 -3 -50  -50 -3 -50  -3 1 -13  0 1 -7  3 1 -13", "_type": "xyz"},
  "Objects": {
    "Triangle": [{"_id": "1", "Material": "1", "Indices": "1 2 3"}, {"_id": "2", "Material": "1", "Indices": "9 10 11"}],
    "Sphere": {"_id": "1", "Material": "2", "Center": "4", "Radius": "1"},
    "Mesh": {"_id": "2", "Material": "3", "Faces": {"_data": "5 6 7  5 7 8", "_type": "triangle"}}}}}"#;

#[test]
fn json_scenes_cull_back_faces_for_camera_rays_only() {
    let (xml_first, xml_floor) = culling_scene(false);
    let (json_first, json_floor) = culling_scene(true);
    // XML: the camera sees the triangle's back (ambient 0.5 · 30 = 15).
    assert_eq!(xml_first, 15.0);
    // JSON: the camera ray passes through it and sees the sphere's ambient red, 1 · 30.
    assert_eq!(json_first, 30.0);
    // Shadow rays never cull: in both dialects the floor point is in the shadow of the
    // triangle whose back the shadow ray meets (the floor has no ambient reflectance).
    assert_eq!(xml_floor, 0.0);
    assert_eq!(json_floor, 0.0);
}

/// The ray that once looked past a back face for ever: in chessboard_arealight (2025 JSON, at
/// 36 or more samples per pixel) one camera sample of pixel (611, 368) met a back face whose
/// f64 re-intersection put it just before the search's lower bound, and stepping past it gave
/// the same bound again. Its neighbourhood must now render, within a bound on the wait.
#[test]
fn the_camera_ray_that_once_culled_for_ever_finishes() {
    let path = tessera_testkit::shared_scenes().join("json/hw3/ramazan_tokay/chessboard_arealight.json");
    if !tessera_testkit::corpus_has(&path) {
        return;
    }
    let scene = tessera::scene::load::load_scene_file(&path).expect("the course scene loads");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let rect = TileRect { x0: 608, y0: 365, width: 8, height: 8 };
        let settings = RenderSettings { samples: Some(40), ..RenderSettings::default() };
        let _ = tx.send(render_tile(&scene, 0, rect, &settings).0);
    });
    // 64 pixels x 40 samples take a few milliseconds; the loop never ended.
    let pixels = rx.recv_timeout(std::time::Duration::from_secs(60)).expect(
        "pixels (608..616, 365..373) at 40 spp did not finish in 60 s: a camera ray is culling for ever",
    );
    assert!(pixels.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
}

/// A camera ray looks past at most `CULLED_HITS_LIMIT` back faces: behind a stack of more, it
/// takes the next back face as its hit (bounded work per sample); behind fewer, it sees through.
#[test]
fn a_stack_of_back_faces_costs_bounded_work() {
    use tessera::integrator::CULLED_HITS_LIMIT;
    let wall_seen = |layers: u32| -> f32 {
        // Back-facing triangles (front towards -z) at z = -2 - k/1000, a red sphere at z = -5
        // behind them (ambient 1 0 0 · 30); the triangles' ambient is 0.5 · 30 = 15.
        let mut vertices = String::from("0 0 -5");
        let mut faces = String::new();
        for k in 0..layers {
            let z = -2.0 - k as f64 / 1000.0;
            vertices.push_str(&format!("  -3 -3 {z}  0 3 {z}  3 -3 {z}"));
            faces.push_str(&format!(" {} {} {}", 2 + 3 * k, 3 + 3 * k, 4 + 3 * k));
        }
        let json = format!(
            r#"{{"Scene": {{
  "Cameras": {{"Camera": {{"_id": "1", "Position": "0 0 0", "Gaze": "0 0 -1", "Up": "0 1 0",
     "NearPlane": "-0.01 0.01 -0.01 0.01", "NearDistance": "1", "ImageResolution": "1 1", "ImageName": "a.png"}}}},
  "Lights": {{"AmbientLight": "30 30 30"}},
  "Materials": {{"Material": [{{"_id": "1", "AmbientReflectance": "0.5 0.5 0.5"}}, {{"_id": "2", "AmbientReflectance": "1 0 0"}}]}},
  "VertexData": {{"_data": "{vertices}", "_type": "xyz"}},
  "Objects": {{
    "Mesh": {{"_id": "1", "Material": "1", "Faces": {{"_data": "{faces}", "_type": "triangle"}}}},
    "Sphere": {{"_id": "1", "Material": "2", "Center": "1", "Radius": "1"}}}}}}}}"#
        );
        render(&load(&json, "stack.json"))[0]
    };
    assert_eq!(wall_seen(10), 30.0, "ten back faces are looked past");
    assert_eq!(wall_seen(CULLED_HITS_LIMIT), 30.0, "as many as the limit are looked past");
    assert_eq!(wall_seen(CULLED_HITS_LIMIT + 1), 15.0, "one more than the limit: the ray stops at it");
}
