//! Tests of the XML front end and, through it, of the shared element walk (`scene/elements/`).
//!
//! Records, errors and warnings for hand-written scenes.

use super::*;
use crate::error::Loc;
use crate::scene::records::*;
use crate::tonemap::params::{Operator, Photographic};

const FILE: &str = "scene.xml";

fn parse(xml: &str) -> SceneRecords {
    match parse_xml(xml, Path::new(FILE)) {
        Ok(records) => records,
        Err(e) => panic!("unexpected error: {e}\nin:\n{xml}"),
    }
}

fn warnings(xml: &str) -> Vec<String> {
    parse(xml).warnings.iter().map(ToString::to_string).collect()
}

/// `<Scene>` on line 1, `body` from line 2.
fn scene(body: &str) -> String {
    format!("<Scene>\n{body}\n</Scene>\n")
}

/// 1-based line of the first occurrence of `needle` in `text`.
fn line_of(text: &str, needle: &str) -> u32 {
    let at = text.find(needle).unwrap_or_else(|| panic!("{needle:?} not in the test scene"));
    1 + text[..at].matches('\n').count() as u32
}

/// Checks that each input fails with exactly the expected message (as displayed).
fn check_errors(cases: &[(&str, &str)]) {
    for (xml, expected) in cases {
        match parse_xml(xml, Path::new(FILE)) {
            Ok(_) => panic!("expected the error {expected:?}, but parsing succeeded:\n{xml}"),
            Err(e) => assert_eq!(e.to_string(), *expected, "input:\n{xml}"),
        }
    }
}

/// Checks that each input parses, with exactly the expected warnings (as displayed).
fn check_warnings(cases: &[(&str, &[&str])]) {
    for (xml, expected) in cases {
        assert_eq!(warnings(xml), *expected, "input:\n{xml}");
    }
}

/// The first camera of a scene made of one camera element.
fn camera(camera_xml: &str) -> CameraRec {
    let records = parse(&scene(&format!("<Cameras>\n{camera_xml}\n</Cameras>")));
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    records.cameras[0].clone()
}

/// The records of a scene made of one `<Objects>` block (plus whatever `extra` holds).
fn objects(objects_xml: &str, extra: &str) -> SceneRecords {
    parse(&scene(&format!("{extra}\n<Objects>\n{objects_xml}\n</Objects>")))
}

fn refs(list: &[(char, &str)]) -> Vec<TransformRef> {
    list.iter().map(|&(letter, id)| TransformRef { letter, id: id.to_string() }).collect()
}

/// A scene like the course's simple.xml, with its blocks deliberately out of the usual
/// order, comments and odd whitespace.
const SIMPLE: &str = "<?xml version=\"1.0\"?>
<Scene>
    <Objects>
        <Mesh id=\"1\">
            <Material>1</Material>
            <Faces>
                3 1 2
                1 3 4
            </Faces>
        </Mesh>
        <Triangle id=\"1\">
            <Material> 1 </Material>
            <Indices>1 2 3</Indices>
        </Triangle>
        <Sphere id=\"1\"> <!-- the ball -->
            <Material>1</Material>
            <Center>1</Center>
            <Radius>3.73896e-4</Radius>
        </Sphere>
    </Objects>
    <VertexData>
        -0.5 0.5 -2
        -0.5\t-0.5 -2\r
        0.5 -0.5 -2 0.5 0.5 -2
    </VertexData>
    <BackgroundColor>10 20 30</BackgroundColor>
    <ShadowRayEpsilon>1e-3</ShadowRayEpsilon>
    <IntersectionTestEpsilon>1e-5</IntersectionTestEpsilon>
    <Cameras>
        <Camera id=\"1\">
            <Position>0 0 0</Position>
            <Gaze>0 0 -1</Gaze>
            <Up>0 1 0</Up>
            <NearPlane>-1 1 -1 1</NearPlane>
            <NearDistance>1</NearDistance>
            <ImageResolution>800 600</ImageResolution>
            <ImageName>simple.png</ImageName>
        </Camera>
    </Cameras>
    <Lights>
        <AmbientLight>25 25 25</AmbientLight>
        <PointLight id=\"1\">
            <Position> 0 0 0  </Position>
            <Intensity>1000 1000 1e+05</Intensity>
        </PointLight>
    </Lights>
    <Materials>
        <Material id=\"1\"> <!-- For the light -->
            <AmbientReflectance>1 1 1</AmbientReflectance>
            <DiffuseReflectance>1 0.5 0.25</DiffuseReflectance>
            <SpecularReflectance>1 1 1</SpecularReflectance>
            <PhongExponent>10</PhongExponent>
        </Material>
    </Materials>
    <MaxRecursionDepth>6</MaxRecursionDepth>
</Scene>
";

#[test]
fn simple_scene_gives_the_expected_records() {
    let at = |needle: &str, element: &str| Loc::new(line_of(SIMPLE, needle), element);
    let mut expected = SceneRecords::new(FILE);
    expected.background_color = [10.0, 20.0, 30.0];
    expected.shadow_ray_epsilon = 1e-3;
    expected.intersection_test_epsilon = 1e-5;
    expected.epsilon_locs = [
        Some(at("<ShadowRayEpsilon>", "ShadowRayEpsilon")),
        Some(at("<IntersectionTestEpsilon>", "IntersectionTestEpsilon")),
    ];
    expected.max_recursion_depth = 6;
    expected.cameras.push(CameraRec {
        id: "1".into(),
        loc: at("<Camera id", r#"Camera id="1""#),
        position: [0.0, 0.0, 0.0],
        gaze: [0.0, 0.0, -1.0],
        up: [0.0, 1.0, 0.0],
        transforms: Vec::new(),
        projection: Projection::NearPlane { left: -1.0, right: 1.0, bottom: -1.0, top: 1.0 },
        near_distance: 1.0,
        width: 800,
        height: 600,
        image_name: "simple.png".into(),
        handedness: Handedness::Right,
        num_samples: 1,
        clamp_samples: None,
        lens: None,
        tonemaps: Vec::new(),
        renderer: Default::default(),
    });
    expected.ambient_light = [25.0; 3];
    expected.point_lights.push(PointLightRec {
        id: "1".into(),
        loc: at("<PointLight", r#"PointLight id="1""#),
        position: [0.0; 3],
        intensity: [1000.0, 1000.0, 1e5],
        transforms: Vec::new(),
    });
    let mut material = MaterialRec::new("1", at("<Material id", r#"Material id="1""#));
    material.ambient = [1.0; 3];
    material.diffuse = [1.0, 0.5, 0.25];
    material.specular = [1.0; 3];
    material.phong_exponent = 10.0;
    expected.materials.push(material);
    expected.vertices = vec![[-0.5, 0.5, -2.0], [-0.5, -0.5, -2.0], [0.5, -0.5, -2.0], [0.5, 0.5, -2.0]];
    expected.meshes.push(MeshRec {
        id: "1".into(),
        loc: at("<Mesh", r#"Mesh id="1""#),
        material: "1".into(),
        faces: FacesRec::Inline { indices: vec![3, 1, 2, 1, 3, 4], vertex_offset: 0, texture_offset: None },
        faces_loc: at("<Faces", r#"Mesh id="1"> / <Faces"#),
        shading: ShadingMode::Flat,
        transforms: vec![],
        motion_blur: None,
        textures: vec![],
        radiance: None,
    });
    expected.triangles.push(TriangleRec {
        id: "1".into(),
        loc: at("<Triangle", r#"Triangle id="1""#),
        material: "1".into(),
        indices: [1, 2, 3],
        transforms: vec![],
        textures: vec![],
        motion_blur: None,
    });
    expected.spheres.push(SphereRec {
        id: "1".into(),
        loc: at("<Sphere", r#"Sphere id="1""#),
        material: "1".into(),
        center: 1,
        radius: 3.73896e-4,
        transforms: vec![],
        motion_blur: None,
        textures: vec![],
        radiance: None,
    });
    assert_eq!(parse(SIMPLE), expected);
}

#[test]
fn distribution_elements() {
    let rec = parse(
        r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
  <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
  <ImageName>a.png</ImageName><NumSamples>9</NumSamples><FocusDistance>21</FocusDistance><ApertureSize>1.5</ApertureSize>
</Camera></Cameras>
<Lights><AreaLight id="1"><Position>0 9 0</Position><Normal>0 -2 0</Normal><Size>3</Size><Radiance>5 6 7</Radiance></AreaLight></Lights>
<VertexData>0 0 0</VertexData>
<Objects>
  <Mesh id="1"><Material>1</Material><Faces>1 1 1</Faces><MotionBlur>0 0 4</MotionBlur></Mesh>
  <MeshInstance id="2" baseMeshId="1"><MotionBlur>1 2 3</MotionBlur></MeshInstance>
  <Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius><MotionBlur>3 0 0</MotionBlur></Sphere>
  <Triangle id="1"><Material>1</Material><Indices>1 1 1</Indices><MotionBlur>0 5 0</MotionBlur></Triangle>
</Objects></Scene>"#,
    );
    assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);
    let cam = &rec.cameras[0];
    assert_eq!(cam.num_samples, 9);
    assert_eq!(cam.lens, Some(LensRec { focus_distance: 21.0, aperture_size: 1.5 }));
    let l = &rec.area_lights[0];
    assert_eq!(
        (l.position, l.normal, l.size, l.radiance),
        ([0.0, 9.0, 0.0], [0.0, -2.0, 0.0], 3.0, [5.0, 6.0, 7.0])
    );
    assert_eq!(rec.meshes[0].motion_blur, Some([0.0, 0.0, 4.0]));
    assert_eq!(rec.instances[0].motion_blur, Some([1.0, 2.0, 3.0]));
    assert_eq!(rec.spheres[0].motion_blur, Some([3.0, 0.0, 0.0]));
    assert_eq!(rec.triangles[0].motion_blur, Some([0.0, 5.0, 0.0]));
    // Aperture 0 is a pinhole; a zero area-light normal or size is an error.
    let pinhole =
        parse(&SIMPLE.replace(
            "<ImageName>",
            "<FocusDistance>5</FocusDistance><ApertureSize>0</ApertureSize><ImageName>",
        ));
    assert_eq!(pinhole.cameras[0].lens, None);
}

#[test]
fn hdr_lighting_elements() {
    let rec = parse(
        r#"<Scene>
<Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
  <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
  <ImageName>a.exr</ImageName>
  <Tonemap><TMO>Photographic</TMO><TMOOptions>0.36 0</TMOOptions><Saturation>0.8</Saturation><Gamma>sRGB</Gamma></Tonemap>
  <Tonemap><Extension>_two.png</Extension></Tonemap>
  <Tonemap><TMO>ACES</TMO><Extension>_aces.png</Extension></Tonemap>
</Camera></Cameras>
<Textures><Images><Image id="7">textures/sky.exr</Image></Images></Textures>
<Lights>
  <DirectionalLight id="1"><Direction>1 -0.8 -1</Direction><Radiance>200 200 200</Radiance></DirectionalLight>
  <SpotLight id="2"><Position>1 2 3</Position><Direction>0 -1 0</Direction><Intensity>5 5 5</Intensity><CoverageAngle>10</CoverageAngle><FalloffAngle>8</FalloffAngle></SpotLight>
  <SphericalDirectionalLight id="3" type="probe"><ImageId>7</ImageId><Sampler>importance</Sampler></SphericalDirectionalLight>
</Lights>
</Scene>"#,
    );
    assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);
    let t = &rec.cameras[0].tonemaps;
    assert_eq!(t.len(), 3);
    assert_eq!(
        t.iter().map(|t| t.operator).collect::<Vec<_>>(),
        [Operator::Photographic, Operator::Photographic, Operator::Aces]
    );
    assert_eq!(
        t[0].params,
        Photographic {
            key: 0.36,
            burn_percent: 0.0,
            saturation: 0.8,
            gamma: crate::tonemap::params::Gamma::Srgb
        }
    );
    assert_eq!(t[0].extension, None);
    assert_eq!((t[1].params, t[1].extension.as_deref()), (Photographic::default(), Some("_two.png")));
    let d = &rec.directional_lights[0];
    assert_eq!((d.direction, d.radiance), ([1.0, -0.8, -1.0], [200.0; 3]));
    let s = &rec.spot_lights[0];
    assert_eq!(
        (s.position, s.direction, s.intensity, s.coverage_angle, s.falloff_angle),
        ([1.0, 2.0, 3.0], [0.0, -1.0, 0.0], [5.0; 3], 10.0, 8.0)
    );
    let e = &rec.env_lights[0];
    assert_eq!(
        (e.id.as_str(), e.image.as_str(), e.mapping, e.sampler),
        ("3", "7", EnvMapping::Probe, Some(EnvSampler::Importance))
    );
    // Defaults: lat-long, the renderer's sampler. The 2019 EnvMapName gets an image record.
    let legacy = parse(&scene(
        "<Lights><SphericalDirectionalLight id=\"1\"><EnvMapName>maps/pisa.exr</EnvMapName></SphericalDirectionalLight></Lights>",
    ));
    let e = &legacy.env_lights[0];
    assert_eq!((e.mapping, e.sampler), (EnvMapping::LatLong, None));
    assert_eq!(legacy.images.len(), 1);
    assert_eq!(
        (legacy.images[0].id.as_str(), legacy.images[0].path.as_str()),
        (e.image.as_str(), "maps/pisa.exr")
    );
}

#[test]
fn hdr_lighting_errors() {
    let lights = |body: &str| scene(&format!("<Lights>\n{body}\n</Lights>"));
    let spot = |cov: &str, fall: &str| {
        lights(&format!(
            "<SpotLight id=\"1\"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity><CoverageAngle>{cov}</CoverageAngle><FalloffAngle>{fall}</FalloffAngle></SpotLight>"
        ))
    };
    let camera = |tonemap: &str| {
        scene(&format!(
            "<Cameras><Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up><NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution><ImageName>a.exr</ImageName>\n<Tonemap>{tonemap}</Tonemap></Camera></Cameras>"
        ))
    };
    check_errors(&[
        (
            &lights(
                "<DirectionalLight id=\"4\"><Direction>0 0 0</Direction><Radiance>1 1 1</Radiance></DirectionalLight>",
            ),
            r#"scene.xml:3: <DirectionalLight id="4">: <Direction> is the zero vector; give the direction the light travels in"#,
        ),
        (
            &lights("<DirectionalLight id=\"4\"><Direction>0 -1 0</Direction></DirectionalLight>"),
            r#"scene.xml:3: <DirectionalLight id="4">: missing <Radiance>"#,
        ),
        (
            &lights(
                "<DirectionalLight id=\"4\"><Direction>0 -1 0</Direction><Radience>1 1 1</Radience></DirectionalLight>",
            ),
            r#"scene.xml:3: <DirectionalLight id="4"> / <Radience>: unknown element <Radience>; did you mean <Radiance>? <DirectionalLight> needs <Radiance>"#,
        ),
        (
            &spot("0", "0"),
            r#"scene.xml:3: <SpotLight id="1">: <CoverageAngle> must be between 0 and 360 degrees (the full apex angle of the cone), found 0"#,
        ),
        (
            &spot("20", "30"),
            r#"scene.xml:3: <SpotLight id="1">: <FalloffAngle> must be between 0 and <CoverageAngle> (20) degrees, found 30: the full-power cone lies inside the covered cone"#,
        ),
        (
            &lights("<SphericalDirectionalLight id=\"5\"/>"),
            r#"scene.xml:3: <SphericalDirectionalLight id="5">: missing <ImageId>: name the <Image> that holds the environment map"#,
        ),
        (
            &lights(
                "<SphericalDirectionalLight id=\"5\" type=\"cube\"><ImageId>1</ImageId></SphericalDirectionalLight>",
            ),
            r#"scene.xml:3: <SphericalDirectionalLight id="5">: attribute type must be latlong or probe, found "cube""#,
        ),
        (
            &lights(
                "<SphericalDirectionalLight id=\"5\"><ImageId>1</ImageId><Sampler>stratified</Sampler></SphericalDirectionalLight>",
            ),
            r#"scene.xml:3: <SphericalDirectionalLight id="5"> / <Sampler>: Sampler must be uniform, cosine or importance, found "stratified""#,
        ),
        (
            &camera("<TMOOptions>0 1</TMOOptions>"),
            r#"scene.xml:3: <Camera id="1"> / <Tonemap>: key 0: must be a positive number (the scenes use 0.18); fix <TMOOptions> (key, burn percent), <Saturation> or <Gamma>"#,
        ),
        (
            &camera("<TMOOptions>0.18</TMOOptions>"),
            r#"scene.xml:3: <Camera id="1"> / <Tonemap> / <TMOOptions>: expected 2 numbers, found "0.18""#,
        ),
        (
            &camera("<Gamma>-2</Gamma>"),
            r#"scene.xml:3: <Camera id="1"> / <Tonemap> / <Gamma>: gamma "-2": expected a positive number (e.g. 2.2) or sRGB"#,
        ),
    ]);
}

#[test]
fn look_at_cameras() {
    let with_gaze_point = camera(
        r#"<Camera id="2" type="lookAt" handedness="left">
                <Position>1 2 3</Position> <GazePoint>1 2 -7</GazePoint> <Up>0 1 0</Up>
                <FovY>45</FovY> <NearDistance>0.5</NearDistance>
                <ImageResolution>640 480</ImageResolution> <ImageName>a.exr</ImageName>
                <NumSamples>16</NumSamples>
            </Camera>"#,
    );
    assert_eq!(with_gaze_point.gaze, [0.0, 0.0, -10.0]);
    assert_eq!(with_gaze_point.projection, Projection::FovY(45.0));
    assert_eq!(with_gaze_point.handedness, Handedness::Left);
    assert_eq!(with_gaze_point.num_samples, 16);
    assert_eq!((with_gaze_point.width, with_gaze_point.height), (640, 480));
    assert_eq!(with_gaze_point.near_distance, 0.5);

    // All cornellbox_jaroslav scenes: lookAt with Gaze and no GazePoint.
    let with_gaze = camera(
        r#"<Camera id="1" type="lookAt" handedness="right">
                <Position>1 2 3</Position> <Gaze>0 0 -1</Gaze> <Up>0 1 0</Up>
                <FovY>39.3</FovY> <NearDistance>0.1</NearDistance>
                <ImageResolution>8 8</ImageResolution> <ImageName>b.png</ImageName>
            </Camera>"#,
    );
    assert_eq!(with_gaze.gaze, [0.0, 0.0, -1.0]);
    assert_eq!(with_gaze.projection, Projection::FovY(39.3));
    assert_eq!(with_gaze.handedness, Handedness::Right);
}

#[test]
fn near_plane_extra_numbers_are_ignored() {
    // spheres.xml writes a fifth value.
    let c = camera(
        "<Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
             <NearPlane> -1 1\t-0.5 0.5 10</NearPlane><NearDistance>1</NearDistance>
             <ImageResolution>2 1</ImageResolution><ImageName>s.png</ImageName></Camera>",
    );
    assert_eq!(c.projection, Projection::NearPlane { left: -1.0, right: 1.0, bottom: -0.5, top: 0.5 });
}

#[test]
fn transformations_and_reference_strings() {
    let records = objects(
        r#"<Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius>
                   <Transformations> t1 r2
                      s3 c1 </Transformations></Sphere>
               <Triangle id="1"><Material>1</Material><Indices>1 2 3</Indices>
                   <Transformations></Transformations></Triangle>"#,
        r#"<Transformations>
                   <Translation id="1">1 2 3</Translation>
                   <Scaling id="3">2 2 -1</Scaling>
                   <Rotation id="2">90 0 1 0</Rotation>
                   <Composite id="1">1 0 0 7.7898e-009
                       0 1 0 0 0 0 1 0 0 0 0 1</Composite>
                   <Translation id="1">4 5 6</Translation>
               </Transformations>"#,
    );
    let ops: Vec<(String, TransformOp)> =
        records.transformations.iter().map(|t| (t.id.clone(), t.op)).collect();
    let mut composite = [0.0; 16];
    for i in 0..4 {
        composite[i * 5] = 1.0;
    }
    composite[3] = 7.7898e-9;
    assert_eq!(
        ops,
        vec![
            ("1".into(), TransformOp::Translation([1.0, 2.0, 3.0])),
            ("3".into(), TransformOp::Scaling([2.0, 2.0, -1.0])),
            ("2".into(), TransformOp::Rotation { degrees: 90.0, axis: [0.0, 1.0, 0.0] }),
            ("1".into(), TransformOp::Composite(composite)),
            // Duplicate ids are kept; resolving them is the build step's business.
            ("1".into(), TransformOp::Translation([4.0, 5.0, 6.0])),
        ]
    );
    assert_eq!(records.spheres[0].transforms, refs(&[('t', "1"), ('r', "2"), ('s', "3"), ('c', "1")]));
    assert_eq!(records.triangles[0].transforms, vec![]);
}

/// Cameras and lights of 2025 scenes carry `Transformations` (§10.4): recorded like an
/// object's, applied by the build step.
#[test]
fn cameras_and_lights_record_their_transformations() {
    let view = "<Up>0 1 0</Up><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>";
    let records = parse(&scene(&format!(
        r#"<Cameras>
<Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><NearPlane>-1 1 -1 1</NearPlane>{view}
    <ImageName>a.png</ImageName><Transformations>r1 t2</Transformations></Camera>
<Camera id="2" type="lookAt"><Position>1 2 3</Position><GazePoint>1 2 -7</GazePoint><FovY>45</FovY>{view}
    <ImageName>b.png</ImageName><Transformations> c1
    </Transformations></Camera>
<Camera id="3"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><NearPlane>-1 1 -1 1</NearPlane>{view}
    <ImageName>c.png</ImageName></Camera>
</Cameras>
<Lights>
<PointLight id="1"><Position>1 2 3</Position><Intensity>1 1 1</Intensity><Transformations>t1</Transformations></PointLight>
<AreaLight id="2"><Position>0 0 0</Position><Normal>0 1 0</Normal><Size>1</Size><Radiance>1 1 1</Radiance>
    <Transformations>s1 r1</Transformations></AreaLight>
<DirectionalLight id="3"><Direction>0 -1 0</Direction><Radiance>1 1 1</Radiance>
    <Transformations>r2</Transformations></DirectionalLight>
<SpotLight id="4"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity>
    <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Transformations>t3 r3</Transformations></SpotLight>
<PointLight id="5"><Position>0 0 0</Position><Intensity>1 1 1</Intensity></PointLight>
</Lights>"#
    )));
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    assert_eq!(records.cameras[0].transforms, refs(&[('r', "1"), ('t', "2")]));
    assert_eq!(records.cameras[1].transforms, refs(&[('c', "1")]));
    assert_eq!(records.cameras[2].transforms, vec![]);
    assert_eq!(records.point_lights[0].transforms, refs(&[('t', "1")]));
    assert_eq!(records.area_lights[0].transforms, refs(&[('s', "1"), ('r', "1")]));
    assert_eq!(records.directional_lights[0].transforms, refs(&[('r', "2")]));
    assert_eq!(records.spot_lights[0].transforms, refs(&[('t', "3"), ('r', "3")]));
    assert_eq!(records.point_lights[1].transforms, vec![]);
    // Nothing is resolved while parsing: the vectors are as written.
    assert_eq!((records.cameras[1].position, records.cameras[1].gaze), ([1.0, 2.0, 3.0], [0.0, 0.0, -10.0]));
    assert_eq!(records.point_lights[0].position, [1.0, 2.0, 3.0]);

    check_errors(&[
        (
            &scene(
                "<Lights>\n<PointLight id=\"1\"><Position>0 0 0</Position><Intensity>1 1 1</Intensity>\n\
                     <Transformations>t1 q</Transformations></PointLight>\n</Lights>",
            ),
            r#"scene.xml:4: <PointLight id="1"> / <Transformations>: bad transformation reference "q": expected t, s, r or c followed by an id, e.g. "t1""#,
        ),
        (
            &scene(&format!(
                "<Cameras>\n<Camera id=\"5\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><NearPlane>-1 1 -1 1</NearPlane>{view}\n\
                     <ImageName>a.png</ImageName><Transformations>r1,t1</Transformations></Camera>\n</Cameras>"
            )),
            r#"scene.xml:4: <Camera id="5"> / <Transformations>: bad transformation reference "r1,t1": expected t, s, r or c followed by an id, e.g. "t1""#,
        ),
    ]);
}

#[test]
fn mesh_instances() {
    let records = objects(
        r#"<Mesh id="1" shadingMode="smooth"><Material>1</Material><Faces plyFile="ply/dragon.ply"/>
                   <Transformations>s1</Transformations></Mesh>
               <MeshInstance id="1" baseMeshId="1" resetTransform="true">
                   <Material>2</Material><Transformations>t1 r1</Transformations></MeshInstance>
               <MeshInstance id="2" baseMeshId="1" shadingMode="smooth"/>
               <MeshInstance id="3" baseMeshId="1" resetTransform="false" shadingMode="flat"></MeshInstance>"#,
        "",
    );
    let summary: Vec<_> = records
        .instances
        .iter()
        .map(|i| {
            (
                i.id.as_str(),
                i.base_mesh.as_str(),
                i.reset_transform,
                i.material.clone(),
                i.transforms.clone(),
                i.shading,
            )
        })
        .collect();
    assert_eq!(
        summary,
        vec![
            ("1", "1", true, Some("2".to_string()), refs(&[('t', "1"), ('r', "1")]), None),
            ("2", "1", false, None, vec![], Some(ShadingMode::Smooth)),
            ("3", "1", false, None, vec![], Some(ShadingMode::Flat)),
        ]
    );
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
}

#[test]
fn ply_faces_and_vertex_offsets() {
    let xml = scene(
        r#"<Objects>
<Mesh id="1" shadingMode="smooth"><Material>1</Material>
  <Faces plyFile=" ply/head.ply "/></Mesh>
<Mesh id="2"><Material>1</Material>
  <Faces vertexOffset="1">0 1 2
    0 2 3</Faces></Mesh>
<Mesh id="3" shadingMode="flat"><Material>1</Material><Faces vertexOffset="-2"></Faces></Mesh>
</Objects>"#,
    );
    let records = parse(&xml);
    let meshes: Vec<_> =
        records.meshes.iter().map(|m| (m.faces.clone(), m.shading, m.faces_loc.clone())).collect();
    assert_eq!(
        meshes,
        vec![
            (
                FacesRec::Ply { path: "ply/head.ply".into() },
                ShadingMode::Smooth,
                Loc::new(4, r#"Mesh id="1"> / <Faces"#)
            ),
            (
                FacesRec::Inline { indices: vec![0, 1, 2, 0, 2, 3], vertex_offset: 1, texture_offset: None },
                ShadingMode::Flat,
                Loc::new(6, r#"Mesh id="2"> / <Faces"#)
            ),
            (
                FacesRec::Inline { indices: vec![], vertex_offset: -2, texture_offset: None },
                ShadingMode::Flat,
                Loc::new(8, r#"Mesh id="3"> / <Faces"#)
            ),
        ]
    );
}

#[test]
fn materials() {
    let records = parse(&scene(
        r#"<Materials>
<Material id="1" type="conductor" degamma="true">
  <MirrorReflectance>1 0.86 0.57</MirrorReflectance><RefractionIndex>0.370</RefractionIndex>
  <AbsorptionIndex>2.820</AbsorptionIndex><Roughness>0.05</Roughness>
</Material>
<Material id="2" type="dielectric"><AbsorptionCoefficient>0.1 0 0.1</AbsorptionCoefficient>
  <RefractionIndex>1.5</RefractionIndex></Material>
<Material id="3" type="mirror"><MirrorReflectance>1 1 1</MirrorReflectance></Material>
<Material id="4"><MirrorReflectance>1 1 1</MirrorReflectance></Material>
</Materials>"#,
    ));
    let m = &records.materials;
    assert_eq!(m[0].kind, MaterialKind::Conductor);
    assert!(m[0].degamma);
    assert_eq!((m[0].mirror, m[0].refraction_index, m[0].absorption_index), ([1.0, 0.86, 0.57], 0.37, 2.82));
    assert_eq!(m[0].roughness, 0.05);
    assert_eq!(m[1].kind, MaterialKind::Dielectric);
    assert_eq!((m[1].absorption_coefficient, m[1].refraction_index), ([0.1, 0.0, 0.1], 1.5));
    assert_eq!(m[2].kind, MaterialKind::Mirror);
    // A 2020+ file (it has typed materials): untyped MirrorReflectance does not make a mirror.
    assert_eq!(m[3].kind, MaterialKind::Plain);
    assert!(!m[3].degamma);
    assert_eq!(m[3].phong_exponent, 1.0, "default from MaterialRec::new");
}

#[test]
fn legacy_2019_material_rule() {
    let mirror = "<Material id=\"1\"><MirrorReflectance>0.5 0.5 0.5</MirrorReflectance></Material>";
    let zero_mirror = "<Material id=\"2\"><MirrorReflectance>0 0 0</MirrorReflectance></Material>";
    let glass = "<Material id=\"3\"><MirrorReflectance>0.1 0.1 0.1</MirrorReflectance>\
                     <Transparency>1 1 1</Transparency><RefractionIndex>1.5</RefractionIndex></Material>";
    let typed = "<Material id=\"4\" type=\"conductor\"></Material>";
    let texture_map = "<Textures><TextureMap id=\"1\" type=\"perlin\"><DecalMode>replace_kd</DecalMode>\
                           </TextureMap></Textures>";
    use MaterialKind::*;
    let cases: &[(&str, &str, &[MaterialKind])] = &[
        // 2019 file: no type attributes, no TextureMap.
        ("", "", &[Mirror, Plain, Dielectric]),
        // Any typed material makes it a 2020+ file.
        (typed, "", &[Plain, Plain, Plain, Conductor]),
        // So does a TextureMap.
        ("", texture_map, &[Plain, Plain, Plain]),
    ];
    for (extra_material, extra, kinds) in cases {
        let xml =
            scene(&format!("{extra}<Materials>{mirror}{zero_mirror}{glass}{extra_material}</Materials>"));
        let got: Vec<MaterialKind> = parse(&xml).materials.iter().map(|m| m.kind).collect();
        assert_eq!(got, *kinds, "input:\n{xml}");
    }
}

#[test]
fn errors_name_file_line_and_element() {
    let cam = |inner: &str| scene(&format!("<Cameras>\n<Camera id=\"1\">\n{inner}\n</Camera>\n</Cameras>"));
    let complete_camera = |skip: &str| {
        let children = [
            "<Position>0 0 0</Position>",
            "<Gaze>0 0 -1</Gaze>",
            "<Up>0 1 0</Up>",
            "<NearPlane>-1 1 -1 1</NearPlane>",
            "<NearDistance>1</NearDistance>",
            "<ImageResolution>4 4</ImageResolution>",
            "<ImageName>x.png</ImageName>",
        ];
        cam(&children.iter().filter(|c| !c.starts_with(skip)).copied().collect::<Vec<_>>().join("\n"))
    };
    let sphere =
        |inner: &str| scene(&format!("<Objects>\n<Sphere id=\"2\">\n{inner}\n</Sphere>\n</Objects>"));
    let cases: &[(&str, &str)] = &[
        (
            &cam("<Position>0 zero 0</Position>"),
            r#"scene.xml:4: <Camera id="1"> / <Position>: expected 3 numbers, found "0 zero 0""#,
        ),
        (
            &scene("<BackgroundColor>1 2</BackgroundColor>"),
            r#"scene.xml:2: <BackgroundColor>: expected 3 numbers, found "1 2""#,
        ),
        (
            &scene("<BackgroundColor> <!-- none --> </BackgroundColor>"),
            "scene.xml:2: <BackgroundColor>: expected 3 numbers, found nothing",
        ),
        (
            &scene("<MaxRecursionDepth>-1</MaxRecursionDepth>"),
            r#"scene.xml:2: <MaxRecursionDepth>: expected a non-negative integer, found "-1""#,
        ),
        (
            &scene("<ShadowRayEpsilon>nan</ShadowRayEpsilon>"),
            r#"scene.xml:2: <ShadowRayEpsilon>: expected a number, found "nan""#,
        ),
        (&complete_camera("<ImageResolution"), r#"scene.xml:3: <Camera id="1">: missing <ImageResolution>"#),
        (&complete_camera("<NearPlane"), r#"scene.xml:3: <Camera id="1">: missing <NearPlane> (or <FovY>)"#),
        (&complete_camera("<Gaze"), r#"scene.xml:3: <Camera id="1">: missing <Gaze> (or <GazePoint>)"#),
        (
            &cam("<Position>0 0 0</Position><Up>0 1 0</Up><FovY>45</FovY>")
                .replace("id=\"1\"", "id=\"1\" type=\"lookAt\""),
            r#"scene.xml:3: <Camera id="1">: missing <GazePoint> (or <Gaze>)"#,
        ),
        (
            &cam("").replace("id=\"1\"", "id=\"1\" type=\"ortho\""),
            r#"scene.xml:3: <Camera id="1">: unknown camera type "ortho" (expected lookAt, or no type)"#,
        ),
        (
            &complete_camera("<ImageResolution")
                .replace("<ImageName>", "<ImageResolution>640 0</ImageResolution><ImageName>"),
            r#"scene.xml:9: <Camera id="1"> / <ImageResolution>: the image must be at least 1 x 1 pixels, found 640 x 0"#,
        ),
        (
            &scene("<Materials>\n<Material id=\"1\" type=\"glass\"/>\n</Materials>"),
            r#"scene.xml:3: <Material id="1">: unknown material type "glass" (expected mirror, conductor or dielectric, or no type)"#,
        ),
        (
            &scene("<Materials>\n<Material/>\n</Materials>"),
            "scene.xml:3: <Material>: missing attribute id (other elements refer to it by id)",
        ),
        (
            &sphere("<Material>1</Material><Center>1</Center>"),
            r#"scene.xml:3: <Sphere id="2">: missing <Radius>"#,
        ),
        (
            &sphere("<Center>1</Center><Radius>1</Radius>"),
            r#"scene.xml:3: <Sphere id="2">: missing <Material>"#,
        ),
        (
            &sphere("<Material></Material><Center>1</Center><Radius>1</Radius>"),
            r#"scene.xml:4: <Sphere id="2"> / <Material>: expected a material id, found nothing"#,
        ),
        (
            &sphere("<Material>1</Material><Center>1.5</Center><Radius>1</Radius>"),
            r#"scene.xml:4: <Sphere id="2"> / <Center>: expected an integer, found "1.5""#,
        ),
        (
            &sphere(
                "<Material>1</Material><Center>1</Center><Radius>1</Radius>\n<Transformations>t1 x2</Transformations>",
            ),
            r#"scene.xml:5: <Sphere id="2"> / <Transformations>: bad transformation reference "x2": expected t, s, r or c followed by an id, e.g. "t1""#,
        ),
        (
            &sphere(
                "<Material>1</Material><Center>1</Center><Radius>1</Radius>\n<Transformations>t</Transformations>",
            ),
            r#"scene.xml:5: <Sphere id="2"> / <Transformations>: bad transformation reference "t": expected t, s, r or c followed by an id, e.g. "t1""#,
        ),
        (
            &scene("<Objects>\n<Mesh id=\"7\">\n<Material>1</Material>\n</Mesh>\n</Objects>"),
            r#"scene.xml:3: <Mesh id="7">: missing <Faces>"#,
        ),
        (
            &scene(
                "<Objects>\n<Mesh id=\"7\"><Material>1</Material>\n<Faces>1 2 3\n4 5 six\n</Faces></Mesh>\n</Objects>",
            ),
            r#"scene.xml:5: <Mesh id="7"> / <Faces>: expected integers, found "six""#,
        ),
        (
            &scene(
                "<Objects>\n<Mesh id=\"7\"><Material>1</Material>\n<Faces>1 2 3 4</Faces></Mesh>\n</Objects>",
            ),
            r#"scene.xml:4: <Mesh id="7"> / <Faces>: the number of values must be a multiple of 3 (three vertex ids per triangle), found 4"#,
        ),
        (
            &scene(
                "<Objects>\n<Mesh id=\"7\" shadingMode=\"phong\"><Material>1</Material><Faces>1 2 3</Faces></Mesh>\n</Objects>",
            ),
            r#"scene.xml:3: <Mesh id="7">: attribute shadingMode must be smooth or flat, found "phong""#,
        ),
        (
            &scene("<VertexData>\n1 2 3\n4 5 6 # 7\n</VertexData>"),
            r##"scene.xml:4: <VertexData>: expected numbers, found "#""##,
        ),
        (
            &scene("<VertexData>1 2 3 4</VertexData>"),
            "scene.xml:2: <VertexData>: the number of values must be a multiple of 3 (x y z per vertex), found 4",
        ),
        (
            &scene("<Objects>\n<MeshInstance id=\"1\" baseMeshId=\"1\" resetTransform=\"yes\"/>\n</Objects>"),
            r#"scene.xml:3: <MeshInstance id="1">: attribute resetTransform must be true or false, found "yes""#,
        ),
        (
            &scene("<Objects>\n<MeshInstance id=\"1\"/>\n</Objects>"),
            r#"scene.xml:3: <MeshInstance id="1">: missing attribute baseMeshId (the id of the Mesh to reuse)"#,
        ),
        (
            &scene("<Transformations>\n<Rotation id=\"1\">90 0 1</Rotation>\n</Transformations>"),
            r#"scene.xml:3: <Rotation id="1">: expected 4 numbers, found "90 0 1""#,
        ),
        (
            "<Root>\n</Root>",
            "scene.xml:1: <Root>: the root element must be <Scene>, found <Root>; is this a scene file?",
        ),
        ("", "scene.xml: no XML element found: the file is empty or is not an XML scene"),
    ];
    check_errors(cases);
}

#[test]
fn malformed_xml_errors_have_lines_and_hints() {
    let cases: &[(&str, &str)] = &[
        (
            "<Scene>\n<Cameras>\n<Camera id=\"1\">\n</Cameras>\n</Scene>",
            "scene.xml:4: malformed XML: ill-formed document: expected `</Camera>`, but `</Cameras>` was found. \
                 Hint: every <Element> must be closed by its own </Element>, innermost first",
        ),
        (
            "<Scene>\n<Cameras>\n<Camera id=\"1\">\n",
            r#"scene.xml:3: <Camera id="1">: <Camera> is never closed: the file ends first (is it truncated?)"#,
        ),
        (
            "<Scene>\n\n<Lights",
            "scene.xml:3: malformed XML: syntax error: tag not closed: `>` not found before end of input. Hint: the file ends inside a tag, comment or quoted value; is it truncated, or is a `>`, `-->` or quote missing?",
        ),
        (
            "<Scene>\n<Material id=1/>\n</Scene>",
            "scene.xml:2: <Material>: malformed attribute: position 12: attribute value must be enclosed in `\"` or `'`. Hint: attributes are written name=\"value\"",
        ),
        (
            "<Scene>\n<ImageName>a &b; c</ImageName>\n</Scene>",
            "scene.xml:2: unknown entity &b;. Hint: write a literal & as &amp;",
        ),
        (
            "<Scene>\n</Scene>\n<Scene/>",
            "scene.xml:3: <Scene>: a second top-level element <Scene>; a scene file has exactly one <Scene>",
        ),
        ("junk", "scene.xml:1: text \"junk\" outside of any element; is this an XML scene file?"),
    ];
    check_errors(cases);
}

#[test]
fn entities_and_cdata_are_text() {
    let c = camera(
            "<Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
             <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance>
             <ImageResolution>2&#32;1</ImageResolution><ImageName>a&amp;<![CDATA[b]]>.png</ImageName></Camera>",
        );
    assert_eq!((c.width, c.height, c.image_name.as_str()), (2, 1, "a&b.png"));
}

#[test]
fn unknown_and_unsupported_elements_are_warnings() {
    let w = |line: u32, element: &str, message: &str| {
        format!("warning: scene.xml:{line}: <{element}>: {message}")
    };
    let sphere = "<Sphere id=\"1\"><Material>1</Material><Center>1</Center><Radius>1</Radius>";
    let cases: &[(&str, &[&str])] = &[
        (&scene("<Foo>1</Foo>"), &[&w(2, "Foo", "unknown element <Foo>; it is ignored")]),
        // A misspelt element or attribute is named with the one most likely meant.
        (
            &scene(
                "<Lights>\n<PointLigth id=\"1\"><Position>0 0 0</Position><Intensity>1 1 1</Intensity></PointLigth>\n</Lights>",
            ),
            &[&w(
                3,
                r#"PointLigth id="1""#,
                "unknown element <PointLigth>; did you mean <PointLight>? It is ignored",
            )],
        ),
        (
            &scene(
                "<Lights>\n<PointLight id=\"1\" Id=\"2\"><Position>0 0 0</Position><Intensity>1 1 1</Intensity></PointLight>\n</Lights>",
            ),
            &[&w(
                3,
                r#"PointLight id="1""#,
                "unknown attribute Id; did you mean attribute id? It is ignored",
            )],
        ),
        (
            &scene(&format!(
                "<Objects>\n{sphere}\n<Radiuss>2</Radiuss><Textures>1</Textures>\n</Sphere>\n\
                     <MeshInstance id=\"2\" baseMeshId=\"1\"><Textures>1</Textures></MeshInstance>\n</Objects>"
            )),
            &[
                // An instance's own <Textures> are read (they replace its base's).
                &w(
                    4,
                    r#"Sphere id="1"> / <Radiuss"#,
                    "unknown element <Radiuss>; did you mean <Radius>? It is ignored",
                ),
            ],
        ),
        (
            &scene(&format!("<Objects>\n{sphere}<Radius>2</Radius></Sphere>\n</Objects>")),
            &[&w(
                3,
                r#"Sphere id="1"> / <Radius"#,
                "<Radius> is given more than once; only the first one is used",
            )],
        ),
        (
            &scene(
                "<Lights>\n<SpotLight id=\"1\"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity>\
                     <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Exponent>2</Exponent></SpotLight>\n\
                     <SphericalDirectionalLight id=\"1\" scale=\"2\"><ImageId>1</ImageId></SphericalDirectionalLight>\n</Lights>",
            ),
            &[
                &w(3, r#"SpotLight id="1"> / <Exponent"#, "unknown element <Exponent>; it is ignored"),
                &w(4, r#"SphericalDirectionalLight id="1""#, "unknown attribute scale; it is ignored"),
            ],
        ),
        (
            &scene(
                "<Materials>\n<Material id=\"1\" BRDF=\"2\" colour=\"red\"><Position>1</Position></Material>\n</Materials>",
            ),
            &[
                &w(3, r#"Material id="1""#, "unknown attribute colour; it is ignored"),
                &w(3, r#"Material id="1"> / <Position"#, "unknown element <Position>; it is ignored"),
            ],
        ),
        // 2019 binary data is read when the scene is built: no warning.
        (
            &scene(
                "<VertexData binaryFile=\"geometry/vertices.bin\"/>\n<TexCoordData binaryFile=\"geometry/uvs.bin\"/>\n\
                 <Objects>\n<Mesh id=\"1\"><Material>1</Material><Faces binaryFile=\"0_face.bin\"/></Mesh>\n</Objects>",
            ),
            &[],
        ),
        (
            &scene(
                "<Materials>\n<Material id=\"1\" type=\"mirror\"><Transparency>1 1 1</Transparency></Material>\n</Materials>",
            ),
            &[&w(
                3,
                r#"Material id="1"> / <Transparency"#,
                "<Transparency> only has a meaning in 2019 scene files (materials without type); it is ignored",
            )],
        ),
        (
            &scene(
                "<Cameras>\n<Camera id=\"1\" type=\"lookAt\"><Position>0 0 0</Position><GazePoint>0 0 -1</GazePoint>\n<Gaze>0 0 1</Gaze>\
                        <Up>0 1 0</Up><FovY>45</FovY><NearDistance>1</NearDistance><ImageResolution>1 1</ImageResolution>\
                        <ImageName>a.exr</ImageName>\n<Tonemap><TMO>Drago</TMO></Tonemap></Camera>\n</Cameras>",
            ),
            &[
                &w(4, r#"Camera id="1"> / <Gaze"#, "<Gaze> is ignored because <GazePoint> is given"),
                &w(
                    5,
                    r#"Camera id="1"> / <Tonemap> / <TMO"#,
                    "tone-mapping operator \"Drago\" is not supported (Photographic, Filmic or ACES); without it, the photographic operator is used",
                ),
            ],
        ),
    ];
    check_warnings(cases);
    // The mesh with binary faces is skipped, not half-recorded.
    assert!(parse(cases[6].0).meshes.is_empty());
}

// ---------------------------------------------------------------------------------------
// Textures (HW4)
// ---------------------------------------------------------------------------------------

/// `Loc` of the element whose start tag is the first occurrence of `needle` in `xml`.
fn loc_of(xml: &str, needle: &str, element: &str) -> Loc {
    Loc::new(line_of(xml, needle), element)
}

fn map(id: &str, loc: Loc, source: TextureSource, decal: DecalMode) -> TextureMapRec {
    TextureMapRec { id: id.into(), loc, source, decal, bump_factor: 1.0, degamma: false }
}

fn image_source(image: &str, interpolation: Interpolation, normalizer: f64) -> TextureSource {
    TextureSource::Image { image: image.into(), interpolation, normalizer, clamp: false }
}

const TEXTURE_MAPS: &str = r#"<Scene>
<Textures>
  <Images>
    <Image id="1">textures/earth.jpg</Image>
    <Image id="hdr"> textures/grace new.exr </Image>
  </Images>
  <TextureMap id="1" type="image">
    <ImageId>1</ImageId>
    <DecalMode>replace_kd</DecalMode>
  </TextureMap>
  <TextureMap id="2" type="image" degamma="true">
    <ImageId> hdr </ImageId>
    <DecalMode>bump_normal</DecalMode>
    <Interpolation>nearest</Interpolation>
    <Normalizer>1</Normalizer>
    <BumpFactor>30</BumpFactor>
  </TextureMap>
  <TextureMap id="3" type="perlin">
    <DecalMode>replace_kd</DecalMode>
  </TextureMap>
  <TextureMap id="4" type="perlin" degamma="false">
    <DecalMode>bump_normal</DecalMode>
    <NoiseConversion>absval</NoiseConversion>
    <NoiseScale>0.5</NoiseScale>
    <BumpFactor>0.08</BumpFactor>
  </TextureMap>
  <TextureMap id="5" type="checkerboard">
    <DecalMode>blend_kd</DecalMode>
  </TextureMap>
  <TextureMap id="6" type="checkerboard">
    <DecalMode>replace_kd</DecalMode>
    <BlackColor>0.4 0.4 0.4</BlackColor>
    <WhiteColor>10 10 10</WhiteColor>
    <Scale>0.1</Scale>
    <Offset>79</Offset>
    <BumpFactor>2</BumpFactor>
  </TextureMap>
  <TextureMap id="7" type="image">
    <ImageId>1</ImageId>
    <DecalMode>replace_all</DecalMode>
    <Interpolation>trilinear</Interpolation>
  </TextureMap>
  <TextureMap id="8" type="perlin">
    <NoiseConversion>linear</NoiseConversion>
    <DecalMode>replace_kd</DecalMode>
  </TextureMap>
</Textures>
</Scene>
"#;

#[test]
fn texture_maps_of_each_type_with_defaults_and_every_child() {
    use DecalMode::*;
    use Interpolation::*;
    let xml = TEXTURE_MAPS;
    let records = parse(xml);
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    assert_eq!(
        records.images,
        vec![
            ImageRec {
                id: "1".into(),
                loc: loc_of(xml, r#"<Image id="1""#, r#"Images> / <Image id="1""#),
                path: "textures/earth.jpg".into(),
            },
            ImageRec {
                id: "hdr".into(),
                loc: loc_of(xml, r#"<Image id="hdr""#, r#"Images> / <Image id="hdr""#),
                path: "textures/grace new.exr".into(),
            },
        ]
    );
    let at =
        |id: &str| loc_of(xml, &format!(r#"<TextureMap id="{id}""#), &format!(r#"TextureMap id="{id}""#));
    let expected = vec![
        // Defaults: nearest, Normalizer 255, BumpFactor 1, no degamma.
        map("1", at("1"), image_source("1", Nearest, 255.0), ReplaceKd),
        TextureMapRec {
            bump_factor: 30.0,
            degamma: true,
            ..map("2", at("2"), image_source("hdr", Nearest, 1.0), BumpNormal)
        },
        map(
            "3",
            at("3"),
            TextureSource::Perlin { conversion: NoiseConversion::Linear, scale: 1.0, octaves: 1 },
            ReplaceKd,
        ),
        TextureMapRec {
            bump_factor: 0.08,
            ..map(
                "4",
                at("4"),
                TextureSource::Perlin { conversion: NoiseConversion::AbsVal, scale: 0.5, octaves: 1 },
                BumpNormal,
            )
        },
        map(
            "5",
            at("5"),
            TextureSource::Checkerboard {
                black: [0.0; 3],
                white: [1.0; 3],
                scale: 1.0,
                offset: 0.0,
                dimension3: true,
            },
            BlendKd,
        ),
        TextureMapRec {
            bump_factor: 2.0,
            ..map(
                "6",
                at("6"),
                TextureSource::Checkerboard {
                    black: [0.4; 3],
                    white: [10.0; 3],
                    scale: 0.1,
                    offset: 79.0,
                    dimension3: true,
                },
                ReplaceKd,
            )
        },
        map("7", at("7"), image_source("1", Trilinear, 255.0), ReplaceAll),
        map(
            "8",
            at("8"),
            TextureSource::Perlin { conversion: NoiseConversion::Linear, scale: 1.0, octaves: 1 },
            ReplaceKd,
        ),
    ];
    assert_eq!(records.texture_maps, expected);
}

#[test]
fn every_decal_mode() {
    use DecalMode::*;
    let modes = [
        ("replace_kd", ReplaceKd),
        ("blend_kd", BlendKd),
        ("replace_ks", ReplaceKs),
        ("replace_all", ReplaceAll),
        ("replace_normal", ReplaceNormal),
        ("bump_normal", BumpNormal),
        ("replace_background", ReplaceBackground),
    ];
    for (name, mode) in modes {
        for map_type in ["image", "perlin", "checkerboard"] {
            let image = if map_type == "image" { "<ImageId>1</ImageId>" } else { "" };
            let xml = scene(&format!(
                "<Textures><TextureMap id=\"1\" type=\"{map_type}\">{image}\
                     <DecalMode>\n {name}\n</DecalMode></TextureMap></Textures>"
            ));
            let records = parse(&xml);
            assert!(records.warnings.is_empty(), "{:?}", records.warnings);
            assert_eq!(records.texture_maps[0].decal, mode, "input:\n{xml}");
        }
    }
}

#[test]
fn texture_errors_name_file_line_and_element() {
    let texture_map = |attrs: &str, children: &str| {
        scene(&format!("<Textures>\n<TextureMap id=\"1\"{attrs}>\n{children}\n</TextureMap>\n</Textures>"))
    };
    let image_map =
        |children: &str| texture_map(" type=\"image\"", &format!("<ImageId>1</ImageId>\n{children}"));
    let legacy = |attrs: &str, children: &str| {
        scene(&format!("<Textures>\n<Texture id=\"1\"{attrs}>\n{children}\n</Texture>\n</Textures>"))
    };
    let decals =
        "replace_kd, blend_kd, replace_ks, replace_all, replace_normal, bump_normal or replace_background";
    let cases: &[(&str, &str)] = &[
        (
            &image_map("<DecalMode>replace</DecalMode>"),
            &format!(
                r#"scene.xml:5: <TextureMap id="1"> / <DecalMode>: DecalMode must be {decals}, found "replace""#
            ),
        ),
        (
            &image_map("<DecalMode></DecalMode>"),
            &format!(
                r#"scene.xml:5: <TextureMap id="1"> / <DecalMode>: DecalMode must be {decals}, found nothing"#
            ),
        ),
        (
            &image_map("<Interpolation>bilinear</Interpolation>"),
            &format!(
                r#"scene.xml:3: <TextureMap id="1">: missing <DecalMode> (how the texture changes the surface: {decals})"#
            ),
        ),
        (
            &texture_map(" type=\"noise\"", "<DecalMode>replace_kd</DecalMode>"),
            r#"scene.xml:3: <TextureMap id="1">: attribute type must be image, perlin or checkerboard, found "noise""#,
        ),
        (
            &texture_map("", "<DecalMode>replace_kd</DecalMode>"),
            r#"scene.xml:3: <TextureMap id="1">: missing attribute type (image, perlin or checkerboard)"#,
        ),
        (
            &scene(
                "<Textures>\n<TextureMap type=\"perlin\"><DecalMode>replace_kd</DecalMode></TextureMap>\n</Textures>",
            ),
            "scene.xml:3: <TextureMap>: missing attribute id (other elements refer to it by id)",
        ),
        (
            &image_map("<DecalMode>replace_kd</DecalMode>\n<Interpolation>cubic</Interpolation>"),
            r#"scene.xml:6: <TextureMap id="1"> / <Interpolation>: Interpolation must be nearest, bilinear or trilinear, found "cubic""#,
        ),
        (
            &image_map("<DecalMode>replace_kd</DecalMode>\n<Normalizer>0</Normalizer>"),
            r#"scene.xml:6: <TextureMap id="1"> / <Normalizer>: Normalizer must be positive, found 0 (texel values are divided by it; 255 for 8-bit images)"#,
        ),
        (
            &image_map("<DecalMode>replace_kd</DecalMode>\n<BumpFactor>big</BumpFactor>"),
            r#"scene.xml:6: <TextureMap id="1"> / <BumpFactor>: expected a number, found "big""#,
        ),
        (
            &texture_map(" type=\"image\"", "<DecalMode>replace_kd</DecalMode>"),
            r#"scene.xml:3: <TextureMap id="1">: missing <ImageId> (the id of an <Image> in <Textures> / <Images>)"#,
        ),
        (
            &texture_map(" type=\"image\"", "<ImageId>1 2</ImageId><DecalMode>replace_kd</DecalMode>"),
            r#"scene.xml:4: <TextureMap id="1"> / <ImageId>: expected an image id, found "1 2""#,
        ),
        (
            &texture_map(
                " type=\"perlin\"",
                "<DecalMode>replace_kd</DecalMode>\n<NoiseConversion>abs</NoiseConversion>",
            ),
            r#"scene.xml:5: <TextureMap id="1"> / <NoiseConversion>: NoiseConversion must be linear or absval, found "abs""#,
        ),
        (
            &texture_map(
                " type=\"checkerboard\"",
                "<DecalMode>replace_kd</DecalMode>\n<BlackColor>0 0</BlackColor>",
            ),
            r#"scene.xml:5: <TextureMap id="1"> / <BlackColor>: expected 3 numbers, found "0 0""#,
        ),
        (
            &texture_map(" type=\"perlin\" degamma=\"yes\"", "<DecalMode>replace_kd</DecalMode>"),
            r#"scene.xml:3: <TextureMap id="1">: attribute degamma must be true or false, found "yes""#,
        ),
        (
            &scene("<Textures><Images>\n<Image>a.png</Image>\n</Images></Textures>"),
            "scene.xml:3: <Images> / <Image>: missing attribute id (other elements refer to it by id)",
        ),
        (
            &scene("<Textures><Images>\n<Image id=\"1\"> </Image>\n</Images></Textures>"),
            r#"scene.xml:3: <Images> / <Image id="1">: expected an image file path, found nothing"#,
        ),
        (
            &scene("<TexCoordData>\n0 0\n1 one\n</TexCoordData>"),
            r#"scene.xml:4: <TexCoordData>: expected numbers, found "one""#,
        ),
        (
            &scene("<TexCoordData>0 0 1</TexCoordData>"),
            "scene.xml:2: <TexCoordData>: the number of values must be a multiple of 2 (u v per texture coordinate), found 3",
        ),
        (
            &scene(
                "<Objects>\n<Mesh id=\"1\"><Material>1</Material>\n<Faces vertexOffset=\"1\" textureOffset=\"1.5\">0 1 2</Faces></Mesh>\n</Objects>",
            ),
            r#"scene.xml:4: <Mesh id="1"> / <Faces>: attribute textureOffset must be an integer, found "1.5""#,
        ),
        (
            &scene("<BackgroundTexture>\n</BackgroundTexture>"),
            "scene.xml:2: <BackgroundTexture>: expected an image file path, found nothing",
        ),
        // 2019 <Texture>
        (
            &legacy("", "<Interpolation>bilinear</Interpolation>"),
            r#"scene.xml:3: <Texture id="1">: missing <ImageName> (an image file, or the word perlin or checkerboard)"#,
        ),
        (
            &scene("<Textures>\n<Texture><ImageName>perlin</ImageName></Texture>\n</Textures>"),
            "scene.xml:3: <Texture>: missing attribute id (other elements refer to it by id)",
        ),
        (
            &legacy("", "<ImageName>a.jpg</ImageName>\n<DecalMode>mix</DecalMode>"),
            &format!(
                r#"scene.xml:5: <Texture id="1"> / <DecalMode>: DecalMode must be {}, replace or blend, found "mix""#,
                decals.replace(" or ", ", ")
            ),
        ),
        (
            &legacy("", "<ImageName>a.jpg</ImageName>\n<Appearance>vein</Appearance>"),
            r#"scene.xml:5: <Texture id="1"> / <Appearance>: Appearance must be repeat or clamp, found "vein""#,
        ),
        (
            &legacy("", "<ImageName>perlin</ImageName>\n<Appearance>repeat</Appearance>"),
            r#"scene.xml:5: <Texture id="1"> / <Appearance>: Appearance must be patch or vein, found "repeat""#,
        ),
        (
            &legacy("", "<ImageName>perlin</ImageName>\n<Normalizer>one</Normalizer>"),
            r#"scene.xml:5: <Texture id="1"> / <Normalizer>: expected a number, found "one""#,
        ),
        (
            &legacy("", "<ImageName>checkerboard</ImageName>\n<ScalingFactor></ScalingFactor>"),
            r#"scene.xml:5: <Texture id="1"> / <ScalingFactor>: expected a number, found nothing"#,
        ),
        (
            &legacy(" bumpmap=\"yes\"", "<ImageName>a.jpg</ImageName>"),
            r#"scene.xml:3: <Texture id="1">: attribute bumpmap must be true or false, found "yes""#,
        ),
        (
            &legacy(" bumpmap=\"true\" bumpmapMultiplier=\"3x\"", "<ImageName>a.jpg</ImageName>"),
            r#"scene.xml:3: <Texture id="1">: attribute bumpmapMultiplier must be a number, found "3x""#,
        ),
    ];
    check_errors(cases);
}

#[test]
fn tex_coords_and_texture_offset() {
    let records = parse(&scene(
        r#"<VertexData>0 0 0  1 0 0  0 1 0</VertexData>
<TexCoordData>
    0 0
    1 0.5  0.25
    1
</TexCoordData>
<Objects>
  <Mesh id="1"><Material>1</Material><Faces vertexOffset="1" textureOffset="2">0 1 2</Faces></Mesh>
  <Mesh id="2"><Material>1</Material><Faces textureOffset=" -1 ">1 2 3</Faces></Mesh>
  <Mesh id="3"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
</Objects>"#,
    ));
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    assert_eq!(records.tex_coords, vec![[0.0, 0.0], [1.0, 0.5], [0.25, 1.0]]);
    let faces: Vec<_> = records.meshes.iter().map(|m| m.faces.clone()).collect();
    assert_eq!(
        faces,
        vec![
            FacesRec::Inline { indices: vec![0, 1, 2], vertex_offset: 1, texture_offset: Some(2) },
            FacesRec::Inline { indices: vec![1, 2, 3], vertex_offset: 0, texture_offset: Some(-1) },
            FacesRec::Inline { indices: vec![1, 2, 3], vertex_offset: 0, texture_offset: None },
        ]
    );
    // Empty or absent (the PLY scenes: ton_Roosendaal_smooth, tower, windmill).
    for body in [
        "<TexCoordData></TexCoordData>",
        "<TexCoordData/>",
        "<TexCoordData> <!-- none --> </TexCoordData>",
        "",
    ] {
        let records = parse(&scene(body));
        assert!(records.warnings.is_empty(), "{:?}", records.warnings);
        assert!(records.tex_coords.is_empty());
    }
}

#[test]
fn object_texture_lists() {
    let records = objects(
        r#"<Mesh id="1"><Material>1</Material><Textures>1 2</Textures><Faces>1 1 1</Faces></Mesh>
               <Mesh id="2"><Material>1</Material><Textures>1</Textures>
                   <Textures> 1 </Textures><Faces>1 1 1</Faces></Mesh>
               <Mesh id="3"><Material>1</Material><Faces>1 1 1</Faces><Textures></Textures></Mesh>
               <Triangle id="1"><Material>1</Material><Indices>1 1 1</Indices><Textures>
                   a  b
               </Textures></Triangle>
               <Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius><Textures>3</Textures></Sphere>
               <Sphere id="2"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere>"#,
        "",
    );
    // The repeated identical <Textures> of the cube_* scenes is accepted without a warning.
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    let ids = |t: &[String]| t.join(",");
    let meshes: Vec<String> = records.meshes.iter().map(|m| ids(&m.textures)).collect();
    assert_eq!(meshes, ["1,2", "1", ""]);
    assert_eq!(ids(&records.triangles[0].textures), "a,b");
    let spheres: Vec<String> = records.spheres.iter().map(|s| ids(&s.textures)).collect();
    assert_eq!(spheres, ["3", ""]);
}

#[test]
fn object_texture_list_warnings() {
    let w = |line: u32, element: &str, message: &str| {
        format!("warning: scene.xml:{line}: <{element}>: {message}")
    };
    let objs = |inner: &str| scene(&format!("<Objects>\n{inner}\n</Objects>"));
    let cases: &[(&str, &[&str], &[&str])] = &[
        (
            &objs(
                "<Mesh id=\"1\"><Material>1</Material><Faces>1 1 1</Faces>\n<Textures>1 2</Textures>\n<Textures>1</Textures></Mesh>",
            ),
            &[&w(
                5,
                r#"Mesh id="1"> / <Textures"#,
                r#"<Textures> is given more than once with different ids; only the first one ("1 2") is used"#,
            )],
            &["1", "2"],
        ),
        (
            &objs(
                "<Sphere id=\"1\"><Material>1</Material><Center>1</Center><Radius>1</Radius>\n<Texture>1</Texture>\n<Textures>2</Textures></Sphere>",
            ),
            &[&w(
                4,
                r#"Sphere id="1"> / <Texture"#,
                "<Texture> (the 2019 spelling) is ignored because <Textures> is given",
            )],
            &["2"],
        ),
        (
            &objs(
                "<Triangle id=\"1\"><Material>1</Material><Indices>1 1 1</Indices>\n<Textures>1<Id>2</Id></Textures></Triangle>",
            ),
            &[&w(4, r#"Triangle id="1"> / <Textures> / <Id"#, "unknown element <Id>; it is ignored")],
            &["1"],
        ),
    ];
    for (xml, expected_warnings, expected_ids) in cases {
        let records = parse(xml);
        let got: Vec<String> = records.warnings.iter().map(ToString::to_string).collect();
        assert_eq!(got, *expected_warnings, "input:\n{xml}");
        let textures = (records.meshes.iter().map(|m| &m.textures))
            .chain(records.spheres.iter().map(|s| &s.textures))
            .chain(records.triangles.iter().map(|t| &t.textures))
            .next()
            .cloned()
            .unwrap_or_default();
        assert_eq!(textures, *expected_ids, "input:\n{xml}");
    }
}

/// The 2019 textures as the course scenes write them (bump_mapping_basic, spheres_perlin,
/// perlin_types_bump, VeachAjar_2019, skybox), translated into 2020 records.
const LEGACY_TEXTURES: &str = r#"<Scene>
<Textures>
    <Texture id="1">
        <ImageName>textures/earth.jpg</ImageName>
        <Interpolation>nearest</Interpolation>
        <DecalMode>blend_kd</DecalMode>
        <Normalizer>255</Normalizer>
        <Appearance>repeat</Appearance>
    </Texture>
    <Texture id="2" bumpmap="true" bumpmapMultiplier="30" degamma="true">
        <ImageName>textures/another_grid.jpg</ImageName>
        <Interpolation>bilinear</Interpolation>
        <DecalMode>replace_kd</DecalMode>
        <Normalizer>255</Normalizer>
        <Appearance>clamp</Appearance>
    </Texture>
    <Texture id="3" bumpmap="true">
        <ImageName>perlin</ImageName>
        <ScalingFactor>3</ScalingFactor>
        <Appearance>vein</Appearance>
        <DecalMode>replace_kd</DecalMode>
        <Normalizer>1</Normalizer>
    </Texture>
    <Texture id="4">
        <ImageName>perlin</ImageName>
    </Texture>
    <Texture id="5" bumpmap="false" bumpmapMultiplier="30">
        <ImageName>checkerboard</ImageName>
        <BlackColor>0.4 0.4 0.4</BlackColor>
        <WhiteColor>10 10 10</WhiteColor>
        <ScalingFactor>0.1</ScalingFactor>
        <Offset>79</Offset>
        <DecalMode>blend</DecalMode>
        <Normalizer>1</Normalizer>
        <Dimension3>true</Dimension3>
    </Texture>
    <Texture id="6">
        <ImageName>checkerboard</ImageName>
        <DecalMode>replace</DecalMode>
        <Dimension3>false</Dimension3>
    </Texture>
    <Texture id="7">
        <ImageName>textures/sky.jpg</ImageName>
        <DecalMode>replace_all</DecalMode>
        <Normalizer>1</Normalizer>
    </Texture>
    <Texture id="8">
        <ImageName>textures/plain.png</ImageName>
    </Texture>
</Textures>
<Objects>
    <Mesh id="1"><Material>1</Material><Texture>2</Texture><Faces>1 1 1</Faces></Mesh>
    <Sphere id="1"><Material>1</Material><Texture> 3 </Texture><Center>1</Center><Radius>1</Radius></Sphere>
    <Sphere id="2"><Material>1</Material><Texture>5</Texture><Center>1</Center><Radius>1</Radius></Sphere>
    <Sphere id="3"><Material>1</Material><Textures>2 1</Textures><Center>1</Center><Radius>1</Radius></Sphere>
    <Triangle id="1"><Material>1</Material><Texture>1</Texture><Texture>1</Texture><Indices>1 1 1</Indices></Triangle>
</Objects>
</Scene>
"#;

#[test]
fn legacy_2019_textures_become_texture_maps() {
    use DecalMode::*;
    use Interpolation::*;
    let xml = LEGACY_TEXTURES;
    let records = parse(xml);
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    let at = |id: &str| loc_of(xml, &format!(r#"<Texture id="{id}""#), &format!(r#"Texture id="{id}""#));
    let image = |id: &str, path: &str| ImageRec { id: format!("2019:{id}"), loc: at(id), path: path.into() };
    assert_eq!(
        records.images,
        vec![
            image("1", "textures/earth.jpg"),
            image("2", "textures/another_grid.jpg"),
            image("7", "textures/sky.jpg"),
            image("8", "textures/plain.png"),
        ]
    );
    let vein = TextureSource::Perlin { conversion: NoiseConversion::AbsVal, scale: 3.0, octaves: 1 };
    // `<Appearance>clamp`: clamp-to-edge addressing.
    let grid = TextureSource::Image {
        image: "2019:2".into(),
        interpolation: Bilinear,
        normalizer: 255.0,
        clamp: true,
    };
    let expected = vec![
        map("1", at("1"), image_source("2019:1", Nearest, 255.0), BlendKd),
        // bumpmap="true": the colour map and a bump map over the same source.
        TextureMapRec { degamma: true, ..map("2", at("2"), grid.clone(), ReplaceKd) },
        TextureMapRec { bump_factor: 30.0, degamma: true, ..map("2:bump", at("2"), grid, BumpNormal) },
        map("3", at("3"), vein.clone(), ReplaceKd),
        map("3:bump", at("3"), vein, BumpNormal),
        // Defaults: patch (linear), ScalingFactor 1, DecalMode replace_kd.
        map(
            "4",
            at("4"),
            TextureSource::Perlin { conversion: NoiseConversion::Linear, scale: 1.0, octaves: 1 },
            ReplaceKd,
        ),
        // bumpmap="false": the multiplier means nothing.
        map(
            "5",
            at("5"),
            TextureSource::Checkerboard {
                black: [0.4; 3],
                white: [10.0; 3],
                scale: 0.1,
                offset: 79.0,
                dimension3: true,
            },
            BlendKd,
        ),
        map(
            "6",
            at("6"),
            // `<Dimension3>false`: a 2-D checkerboard in (u, v).
            TextureSource::Checkerboard {
                black: [0.0; 3],
                white: [1.0; 3],
                scale: 1.0,
                offset: 0.0,
                dimension3: false,
            },
            ReplaceKd,
        ),
        map("7", at("7"), image_source("2019:7", Nearest, 1.0), ReplaceAll),
        map("8", at("8"), image_source("2019:8", Nearest, 255.0), ReplaceKd),
    ];
    assert_eq!(records.texture_maps, expected);
    // An object's <Texture>k</Texture> names both maps of a bumpmap texture.
    assert_eq!(records.meshes[0].textures, ["2", "2:bump"]);
    assert_eq!(records.spheres[0].textures, ["3", "3:bump"]);
    assert_eq!(records.spheres[1].textures, ["5"]);
    assert_eq!(records.spheres[2].textures, ["2", "2:bump", "1"]);
    assert_eq!(records.triangles[0].textures, ["1"]);
}

#[test]
fn perlin_octaves_and_2019_texture_keywords() {
    let perlin = |octaves: &str| {
        scene(&format!(
            "<Textures>\n<TextureMap id=\"1\" type=\"perlin\">\n<NumOctaves>{octaves}</NumOctaves><DecalMode>replace_kd</DecalMode>\n</TextureMap>\n</Textures>"
        ))
    };
    let octaves = |records: SceneRecords| match records.texture_maps[0].source {
        TextureSource::Perlin { octaves, .. } => octaves,
        ref other => panic!("{other:?}"),
    };
    assert_eq!(octaves(parse(&perlin("4"))), 4);
    assert_eq!(octaves(parse(&perlin(" 1 "))), 1);
    let without = scene(
        "<Textures><TextureMap id=\"1\" type=\"perlin\"><DecalMode>replace_kd</DecalMode></TextureMap></Textures>",
    );
    assert_eq!(octaves(parse(&without)), 1);
    check_errors(&[
        (
            &perlin("0"),
            r#"scene.xml:4: <TextureMap id="1"> / <NumOctaves>: <NumOctaves> must be a whole number from 1 to 32 (octaves of the noise), found 0"#,
        ),
        (
            &perlin("33"),
            r#"scene.xml:4: <TextureMap id="1"> / <NumOctaves>: <NumOctaves> must be a whole number from 1 to 32 (octaves of the noise), found 33"#,
        ),
    ]);
    let legacy = |children: &str| {
        scene(&format!("<Textures>\n<Texture id=\"1\">\n{children}\n</Texture>\n</Textures>"))
    };
    check_errors(&[
        (
            &legacy("<ImageName>checkerboard</ImageName>\n<Dimension3>no</Dimension3>"),
            r#"scene.xml:5: <Texture id="1"> / <Dimension3>: Dimension3 must be true or false, found "no""#,
        ),
        (
            &legacy("<ImageName>a.png</ImageName>\n<Appearance>mirror</Appearance>"),
            r#"scene.xml:5: <Texture id="1"> / <Appearance>: Appearance must be repeat or clamp, found "mirror""#,
        ),
    ]);
}

#[test]
fn texture_warnings() {
    let w = |line: u32, element: &str, message: &str| {
        format!("warning: scene.xml:{line}: <{element}>: {message}")
    };
    let textures = |inner: &str| scene(&format!("<Textures>\n{inner}\n</Textures>"));
    let cases: &[(&str, &[&str])] = &[
        (
            &textures(
                "<TextureMap id=\"1\" type=\"perlin\" bumpmap=\"true\"><DecalMode>replace_kd</DecalMode>\n\
                     <NumOctaves>4</NumOctaves>\n<Normalizer>1</Normalizer><Scale>2</Scale>\n<Foo/></TextureMap>",
            ),
            &[
                &w(3, r#"TextureMap id="1""#, "unknown attribute bumpmap; it is ignored"),
                &w(
                    5,
                    r#"TextureMap id="1"> / <Normalizer"#,
                    "<Normalizer> does not apply to perlin texture maps; it is ignored",
                ),
                &w(
                    5,
                    r#"TextureMap id="1"> / <Scale"#,
                    "<Scale> does not apply to perlin texture maps; it is ignored",
                ),
                &w(6, r#"TextureMap id="1"> / <Foo"#, "unknown element <Foo>; it is ignored"),
            ],
        ),
        (
            &textures(
                "<TextureMap id=\"1\" type=\"checkerboard\"><DecalMode>replace_kd</DecalMode>\n<ImageId>1</ImageId></TextureMap>\n\
                     <TextureMap id=\"2\" type=\"image\"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode>\n\
                     <NoiseScale>2</NoiseScale><DecalMode>blend_kd</DecalMode></TextureMap>",
            ),
            &[
                &w(
                    4,
                    r#"TextureMap id="1"> / <ImageId"#,
                    "<ImageId> does not apply to checkerboard texture maps; it is ignored",
                ),
                &w(
                    6,
                    r#"TextureMap id="2"> / <NoiseScale"#,
                    "<NoiseScale> does not apply to image texture maps; it is ignored",
                ),
                &w(
                    6,
                    r#"TextureMap id="2"> / <DecalMode"#,
                    "<DecalMode> is given more than once; only the first one is used",
                ),
            ],
        ),
        (
            &textures(
                "<Images><Image id=\"1\">a.png</Image>\n<Picture/></Images>\n<Texture id=\"1\">\n<ImageName>a.jpg</ImageName>\n\
                     <Appearance> clamp </Appearance>\n<ScalingFactor>2</ScalingFactor></Texture>\n<Texture id=\"2\">\
                     <ImageName>perlin</ImageName>\n<Normalizer>255</Normalizer><Interpolation>bilinear</Interpolation></Texture>\n\
                     <Texture id=\"3\"><ImageName>checkerboard</ImageName>\n<Appearance>patch</Appearance></Texture>\n<Other/>",
            ),
            &[
                &w(4, "Images> / <Picture", "unknown element <Picture>; it is ignored"),
                &w(
                    8,
                    r#"Texture id="1"> / <ScalingFactor"#,
                    "<ScalingFactor> does not apply to image textures; it is ignored",
                ),
                &w(
                    10,
                    r#"Texture id="2"> / <Interpolation"#,
                    "<Interpolation> does not apply to perlin textures; it is ignored",
                ),
                &w(
                    10,
                    r#"Texture id="2"> / <Normalizer"#,
                    "<Normalizer> has no effect on perlin textures (their values are used as they are); it is ignored",
                ),
                &w(
                    12,
                    r#"Texture id="3"> / <Appearance"#,
                    "<Appearance> does not apply to checkerboard textures; it is ignored",
                ),
                &w(13, "Other", "unknown element <Other>; it is ignored"),
            ],
        ),
    ];
    check_warnings(cases);
}

#[test]
fn background_texture_is_a_raw_replace_background_map() {
    let xml = scene("<BackgroundTexture> textures/galaxy.jpg </BackgroundTexture>");
    let records = parse(&xml);
    assert!(records.warnings.is_empty(), "{:?}", records.warnings);
    let loc = Loc::new(2, "BackgroundTexture");
    assert_eq!(
        records.images,
        vec![ImageRec { id: "2019:background".into(), loc: loc.clone(), path: "textures/galaxy.jpg".into() }]
    );
    assert_eq!(
        records.texture_maps,
        vec![map(
            "2019:background",
            loc,
            image_source("2019:background", Interpolation::Bilinear, 1.0),
            DecalMode::ReplaceBackground
        )]
    );
}

/// Truncated and garbage inputs must give errors, never panics.
#[test]
fn truncated_and_garbage_inputs_are_errors() {
    let end = SIMPLE.find("</Scene>").expect("SIMPLE ends with </Scene>") + "</Scene>".len();
    for (cut, _) in SIMPLE.char_indices().filter(|&(i, _)| i < end) {
        assert!(parse_xml(&SIMPLE[..cut], Path::new(FILE)).is_err(), "truncated at byte {cut} parsed");
    }
    let deep = "<Scene>".to_string() + &"<a>".repeat(100_000);
    let garbage = [
        "<",
        "<<>>",
        "</Scene>",
        "<Scene",
        "<Scene><!-- </Scene>",
        "<Scene><![CDATA[</Scene>",
        "<Scene><Cameras><Camera id=\"1\"><Position>1 2",
        "<Scene>&#0;</Scene>",
        "<Scene>&#xFFFFFFFF;</Scene>",
        "<Scene a='1' a='2'></Scene>",
        "<?xml version=\"1.0\"?>",
        "\u{0}\u{1}\u{2}",
        "\u{feff}",
        &deep,
    ];
    for input in garbage {
        assert!(parse_xml(input, Path::new(FILE)).is_err(), "{:?} parsed", excerpt(input));
    }
    // Random byte mutations of valid scenes: any result is fine, a panic is not.
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for valid in [SIMPLE, TEXTURE_MAPS, LEGACY_TEXTURES] {
        for _ in 0..2000 {
            let mut bytes = valid.as_bytes().to_vec();
            for _ in 0..3 {
                let at = (next() % bytes.len() as u64) as usize;
                bytes[at] = b"<>/=\"' 0x!-&;\n"[(next() % 14) as usize];
            }
            let _ = parse_xml(&String::from_utf8_lossy(&bytes), Path::new(FILE));
        }
    }
}

/// Every scene of the course set parses (2019 files may warn about legacy elements).
#[test]
fn all_course_scenes_parse() {
    let dir = tessera_testkit::shared_scenes().join("xml");
    if !tessera_testkit::corpus_has(&dir) {
        return;
    }
    let entries = std::fs::read_dir(&dir).unwrap();
    let mut paths: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "xml"))
        .collect();
    paths.sort();
    assert!(!paths.is_empty(), "no scenes in {}", dir.display());
    let mut failures = Vec::new();
    for path in &paths {
        let text = std::fs::read_to_string(path).expect("scene file is readable UTF-8");
        match parse_xml(&text, path) {
            Ok(records) => {
                assert!(!records.cameras.is_empty(), "{}: no cameras", path.display());
                let mut kinds: Vec<&str> = records.warnings.iter().map(|w| w.message.as_str()).collect();
                kinds.sort();
                kinds.dedup();
                if !kinds.is_empty() {
                    println!(
                        "{}: {} warnings: {}",
                        path.display(),
                        records.warnings.len(),
                        kinds.join(" | ")
                    );
                }
            }
            Err(e) => failures.push(e.to_string()),
        }
    }
    assert!(failures.is_empty(), "{} scenes failed:\n{}", failures.len(), failures.join("\n"));
}

/// Homework 6 elements: BRDFs, a material's BRDF, renderers, object lights.
#[test]
fn homework_6_elements() {
    let r = parse(&scene(
        "<BRDFs><ModifiedPhong id=\"1\" normalized=\"true\"><Exponent>90</Exponent></ModifiedPhong>\
         <TorranceSparrow id=\"2\" kdfresnel=\"true\"><Exponent>50</Exponent><RefractiveIndex>1.5</RefractiveIndex></TorranceSparrow>\
         <OriginalPhong id=\"3\"><Exponent>7</Exponent></OriginalPhong></BRDFs>\
         <Materials><Material id=\"1\" BRDF=\"2\"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>",
    ));
    assert!(r.warnings.is_empty(), "{:?}", r.warnings);
    let kinds: Vec<_> =
        r.brdfs.iter().map(|b| (b.id.as_str(), b.kind, b.exponent, b.normalized, b.kd_fresnel)).collect();
    assert_eq!(
        kinds,
        [
            ("1", BrdfKind::ModifiedPhong, 90.0, true, false),
            ("2", BrdfKind::TorranceSparrow, 50.0, false, true),
            ("3", BrdfKind::OriginalPhong, 7.0, false, false)
        ]
    );
    assert_eq!(r.brdfs[1].refractive_index, Some(1.5));
    assert_eq!(r.materials[0].brdf.as_deref(), Some("2"));

    let cam = |inner: &str| {
        format!(
            "<Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>\
             <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>2 2</ImageResolution>\
             <ImageName>a.exr</ImageName>{inner}</Camera>"
        )
    };
    assert_eq!(camera(&cam("")).renderer, Renderer::Classic);
    assert_eq!(
        camera(&cam("<Renderer>PathTracing</Renderer><RendererParams>RussianRoulette NextEventEstimation</RendererParams>"))
            .renderer,
        Renderer::Path(PathParams { next_event: true, importance: false, roulette: Roulette::Course, one_light: false, mis: false })
    );
    assert_eq!(
        camera(&cam("<Renderer>PathTracing</Renderer><RendererParams>SampleOneLight NextEventEstimation</RendererParams>"))
            .renderer,
        Renderer::Path(PathParams { next_event: true, importance: false, roulette: Roulette::Off, one_light: true, mis: false })
    );
    assert_eq!(
        camera(&cam(
            "<Renderer>PathTracing</Renderer><RendererParams>UnbiasedRussianRoulette</RendererParams>"
        ))
        .renderer,
        Renderer::Path(PathParams {
            next_event: false,
            importance: false,
            roulette: Roulette::Unbiased,
            one_light: false,
            mis: false,
        })
    );
    // A flag that needs NextEventEstimation, alone: a warning containing `says`.
    let warns_alone = |flag: &str, says: &str| {
        let lone = parse(&format!(
            "<Scene><Cameras>{}</Cameras></Scene>",
            cam(&format!("<Renderer>PathTracing</Renderer><RendererParams>{flag}</RendererParams>"))
        ));
        assert!(lone.warnings.iter().any(|w| w.message.contains(says)), "{flag}: {:?}", lone.warnings);
    };
    warns_alone("SampleOneLight", "without it, it does nothing");
    assert_eq!(
        camera(&cam(
            "<Renderer>PathTracing</Renderer><RendererParams>NextEventEstimation MultipleImportanceSampling</RendererParams>"
        ))
        .renderer,
        Renderer::Path(PathParams { next_event: true, importance: false, roulette: Roulette::Off, one_light: false, mis: true })
    );
    warns_alone("MultipleImportanceSampling", "MultipleImportanceSampling weighs");
    assert_eq!(
        camera(&cam("<Renderer>PathTracing</Renderer><RendererParams></RendererParams>")).renderer,
        Renderer::Path(PathParams::default())
    );

    let r = objects(
        "<LightMesh id=\"1\"><Material>1</Material><Radiance>31.8 31.8 31.8</Radiance><Faces>1 2 3</Faces></LightMesh>\n\
         <LightSphere id=\"2\"><Material>1</Material><Center>1</Center><Radius>0.5</Radius><Radiance>5 4 3</Radiance>\
         <Transformations>s1</Transformations></LightSphere>",
        "<VertexData>0 0 0 1 0 0 0 1 0</VertexData>",
    );
    assert!(r.warnings.is_empty(), "{:?}", r.warnings);
    assert_eq!(r.meshes[0].radiance, Some([31.8; 3]));
    assert_eq!(r.spheres[0].radiance, Some([5.0, 4.0, 3.0]));
    assert_eq!(r.spheres[0].transforms, refs(&[('s', "1")]));

    // A light that would move, unlike every other light, is flagged as unsupported.
    let r = objects(
        "<LightSphere id=\"2\"><Material>1</Material><Center>1</Center><Radius>0.5</Radius><Radiance>5 4 3</Radiance>\
         <MotionBlur>1 0 0</MotionBlur></LightSphere>",
        "<VertexData>0 0 0</VertexData>",
    );
    assert!(r.warnings.len() == 1 && r.warnings[0].unsupported, "{:?}", r.warnings);
}

#[test]
fn homework_6_errors() {
    let s = |body: &str| scene(body);
    let lights = s(
        "<Objects>\n<LightMesh id=\"1\"><Material>1</Material><Faces>1 2 3</Faces></LightMesh>\n</Objects>",
    );
    let negative = s(
        "<Objects>\n<LightSphere id=\"1\"><Material>1</Material><Center>1</Center><Radius>1</Radius><Radiance>1 -1 1</Radiance></LightSphere>\n</Objects>",
    );
    let renderer =
        s("<Cameras>\n<Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>\
         <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>2 2</ImageResolution>\
         <ImageName>a.exr</ImageName><Renderer>PhotonMapping</Renderer></Camera>\n</Cameras>");
    let params = s("<Cameras>\n<Camera id=\"1\"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>\
         <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>2 2</ImageResolution>\
         <ImageName>a.exr</ImageName><Renderer>PathTracing</Renderer>\n<RendererParams>NextEvent</RendererParams></Camera>\n</Cameras>");
    let both = params.replace("NextEvent<", "RussianRoulette UnbiasedRussianRoulette<");
    let exponent = s("<BRDFs>\n<ModifiedPhong id=\"1\"><Exponent>-3</Exponent></ModifiedPhong>\n</BRDFs>");
    check_errors(&[
        (&lights, "scene.xml:3: <LightMesh id=\"1\">: missing <Radiance>"),
        (
            &negative,
            "scene.xml:3: <LightSphere id=\"1\"> / <Radiance>: Radiance must be three non-negative numbers, found \"1 -1 1\"",
        ),
        (
            &renderer,
            "scene.xml:3: <Camera id=\"1\"> / <Renderer>: unknown renderer \"PhotonMapping\" (expected PathTracing, or DirectLighting for the classic ray tracer)",
        ),
        (
            &params,
            "scene.xml:4: <Camera id=\"1\"> / <RendererParams>: unknown renderer parameter \"NextEvent\" (expected any of NextEventEstimation, ImportanceSampling, RussianRoulette, UnbiasedRussianRoulette, SampleOneLight, MultipleImportanceSampling)",
        ),
        (
            &both,
            "scene.xml:4: <Camera id=\"1\"> / <RendererParams>: RussianRoulette (the course's rule) and UnbiasedRussianRoulette exclude each other; keep one",
        ),
        (
            &exponent,
            "scene.xml:3: <ModifiedPhong id=\"1\"> / <Exponent>: Exponent must be between 0 and 1000000, found -3",
        ),
    ]);
}
