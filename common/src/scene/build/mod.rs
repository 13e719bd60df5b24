//! Records -> render scene: resolve ids, load PLY files, compose transformations, build BVHs.
//!
//! Every failure here is a [`SceneError`] that points at the element whose reference or data is
//! wrong (the records carry their source line), so the user can fix the scene file.

mod context;
mod meshes;
mod objects;
mod textures;

use std::collections::HashMap;
use std::time::Instant;

use glam::DVec3;

use crate::assets::AssetResolver;
use crate::camera::Camera;
use crate::error::{Loc, SceneError, Warning};
use crate::geometry::Accel;
use crate::lights::{AreaLight, DirectionalLight, PointLight, SpotLight};
use crate::material::{Brdf, Material};
use crate::math::{Transform, v3};
use crate::scene::cache::MeshCache;
use crate::scene::records::*;
use crate::scene::tree::json_words;
use crate::scene::{Scene, SceneStats};

use context::{Ctx, degamma_exponent, placed_normal, placed_point, placed_vector, unplaced_message};
use meshes::{build_meshes, world_tree_key};
use objects::{Objects, Placed, object_lights};
use textures::build_textures;

pub use context::op_matrix;

/// Largest image we agree to render (a float frame of this size is 3 GiB).
const MAX_IMAGE_SIDE: u32 = 65_536;
const MAX_IMAGE_PIXELS: u64 = 1 << 28;

/// A camera record with its `Transformations` applied. A GazePoint camera's record holds
/// `GazePoint − Position`, and moving both points by an affine M changes that difference by M's
/// linear part only, so treating it as a direction places the gaze point as a point. Distances
/// (NearDistance, NearPlane, FovY, FocusDistance) stay as written: scaling a camera changes
/// where it looks, not its image plane.
fn placed_camera(c: &CameraRec, placement: Option<&Transform>) -> CameraRec {
    let mut placed = c.clone();
    placed.position = placed_point(placement, c.position).to_array();
    placed.gaze = placed_vector(placement, c.gaze).to_array();
    placed.up = placed_vector(placement, c.up).to_array();
    // The course's renderer keeps the transformed gaze's length: a scaling along the view
    // moves a NearPlane camera's image plane (its extents as given) that many times further,
    // which zooms. Measured on the sequence camera_zoom_david (a scaling of 1 to 2 along the
    // gaze about the camera; its reference video zooms in by that factor).
    if let (Some(_), crate::scene::records::Projection::NearPlane { .. }) = (placement, &c.projection) {
        let unit = v3(c.gaze);
        if unit.length_squared() > 0.0 {
            let stretched = placed_vector(placement, unit.normalize().to_array()).length();
            if stretched.is_finite() && stretched > 0.0 {
                placed.near_distance = c.near_distance * stretched;
            }
        }
    }
    placed
}

/// The scene's cameras, placed by their `Transformations` (§10.4) and checked (size limits, a
/// valid frame), without loading any asset: what the farm server needs to name and size frames.
pub fn build_cameras(rec: &SceneRecords) -> Result<Vec<Camera>, SceneError> {
    let no_assets = crate::assets::MemResolver { files: HashMap::new(), base: String::new() };
    let ctx = Ctx { rec, resolver: &no_assets, cache: None };
    let transforms = transform_table(rec);
    placed_cameras(&ctx, &transforms, &mut Vec::new())
}

/// The `<Transformations>` block by (letter, id).
fn transform_table(rec: &SceneRecords) -> HashMap<(char, &str), TransformOp> {
    rec.transformations.iter().map(|t| ((t.op.letter(), t.id.as_str()), t.op)).collect()
}

/// Step 2 (and all of [`build_cameras`]): the cameras, placed by their `Transformations`
/// (§10.4) and checked: an image size within the limits, a valid camera frame, and (a
/// warning) a position not so far out that its pixels' directions are lost to rounding.
fn placed_cameras(
    ctx: &Ctx,
    transforms: &HashMap<(char, &str), TransformOp>,
    warnings: &mut Vec<Warning>,
) -> Result<Vec<Camera>, SceneError> {
    let rec = ctx.rec;
    let mut cameras = Vec::with_capacity(rec.cameras.len());
    for c in &rec.cameras {
        if c.width == 0 || c.height == 0 {
            return Err(
                ctx.err(&c.loc, format!("<ImageResolution> {} {} has a zero size", c.width, c.height))
            );
        }
        if c.width > MAX_IMAGE_SIDE
            || c.height > MAX_IMAGE_SIDE
            || c.width as u64 * c.height as u64 > MAX_IMAGE_PIXELS
        {
            return Err(ctx.err(
                &c.loc,
                format!(
                    "<ImageResolution> {} {} is too large: at most {MAX_IMAGE_SIDE} pixels a side and {MAX_IMAGE_PIXELS} in all",
                    c.width, c.height
                ),
            ));
        }
        let placement = ctx.placement(transforms, &c.transforms, &c.loc)?;
        let placed = placed_camera(c, placement.as_ref());
        let cam = Camera::from_record(&placed).ok_or_else(|| {
            ctx.err(&c.loc, "Gaze and Up are zero or parallel, so they do not define a camera frame; give an Up that is not parallel to the viewing direction")
        })?;
        // A ray's direction is its image-plane point less the position: both as far out as
        // the position, so rounded to its spacing of doubles, which must stay well below a
        // pixel.
        let far = cam.position.abs().max_element();
        let spacing = far * f64::EPSILON;
        let pixel = cam.pixel_w.abs().min(cam.pixel_h.abs());
        if spacing > pixel / 16.0 {
            ctx.warn(
                warnings,
                &c.loc,
                format!(
                    "the camera is {far:.1e} from the origin, where doubles lie {spacing:.1e} apart: more than a sixteenth of a pixel on its near plane ({pixel:.1e} wide), so its rays' directions are rounded and the picture will be wrong; move the scene and the camera closer to the origin"
                ),
            );
        }
        cameras.push(cam);
    }
    Ok(cameras)
}

/// Builds the render scene. `resolver` supplies the PLY files and images named by the scene.
///
/// The steps run in this order (each one's errors before the next one's): materials, cameras,
/// lights, texture maps and their images, meshes (PLY files, mesh instances, normals, BVHs),
/// then every object placed as an [`Instance`]. Warnings come out in that order too, after the
/// parser's.
pub fn build_scene(rec: &SceneRecords, resolver: &dyn AssetResolver) -> Result<Scene, SceneError> {
    build_scene_with(rec, resolver, None)
}

/// [`build_scene`] with meshes and images kept in `cache` across builds: a PLY mesh or an image
/// whose content (and, for a mesh, shading) the cache has is neither parsed nor built again.
/// The scene is the same, bit for bit, as [`build_scene`]'s.
pub fn build_scene_cached(
    rec: &SceneRecords,
    resolver: &dyn AssetResolver,
    cache: &MeshCache,
) -> Result<Scene, SceneError> {
    build_scene_with(rec, resolver, Some(cache))
}

fn build_scene_with(
    rec: &SceneRecords,
    resolver: &dyn AssetResolver,
    cache: Option<&MeshCache>,
) -> Result<Scene, SceneError> {
    let started = Instant::now();
    let legacy = crate::scene::legacy_data::legacy_data(rec, resolver)?;
    let rec: &SceneRecords = &legacy;
    let ctx = Ctx { rec, resolver, cache };
    let mut warnings: Vec<Warning> = rec.warnings.clone();

    let (materials, mat_ids) = build_materials(&ctx, &mut warnings)?;
    let transforms = transform_table(rec);
    let cameras = placed_cameras(&ctx, &transforms, &mut warnings)?;
    if cameras.is_empty() {
        ctx.warn(&mut warnings, &Loc::default(), "the scene has no <Camera>; nothing will be rendered");
    }
    let lights = placed_lights(&ctx, &transforms)?;
    let textures = build_textures(&ctx, &mut warnings)?;
    let meshes_started = Instant::now();
    let mut meshes = build_meshes(&ctx, &transforms, &mat_ids, &mut warnings)?;
    let mesh_seconds = meshes_started.elapsed().as_secs_f64();
    let meshes_cached = meshes.cached;
    let identity = std::mem::take(&mut meshes.identity);
    let objects = Objects { ctx: &ctx, transforms: &transforms, mat_ids: &mat_ids, textures: &textures };
    let Placed { geoms, instances, locs, emitters } = objects.place(meshes, &mut warnings)?;

    // The top level; with a cache, the world-space tree of the static mesh instances is
    // shared with an earlier scene that placed the same meshes the same way.
    let accel_started = Instant::now();
    let (accel, world_tree_cached) = match cache {
        Some(cache) => {
            let key = world_tree_key(&geoms, &identity, &instances);
            match cache.world_tree(&key) {
                Some(tree) => (Accel::with_world_tree(geoms, instances, Some(tree)), true),
                None => {
                    let accel = Accel::new(geoms, instances);
                    cache.put_world_tree(&key, accel.shared_world_tree());
                    (accel, false)
                }
            }
        }
        None => (Accel::new(geoms, instances), false),
    };
    let accel_seconds = accel_started.elapsed().as_secs_f64();
    for &(i, n) in accel.unplaced_world_triangles() {
        let total = match accel.instances[i as usize].shape {
            crate::geometry::Shape::Mesh { mesh, .. } => accel.meshes[mesh as usize].triangle_count(),
            _ => 0,
        };
        ctx.warn(&mut warnings, &locs[i as usize], unplaced_message(n as usize, total, true));
    }
    epsilons(&ctx, accel.extent(), &mut warnings);
    let (object_lights, instance_emission, instance_light) =
        object_lights(&ctx, &accel, &emitters, &mut warnings);
    let stats = SceneStats {
        triangles: accel.instanced_triangle_count(),
        instances: accel.instances.len(),
        build_seconds: started.elapsed().as_secs_f64(),
        mesh_seconds,
        meshes_cached,
        accel_seconds,
        world_tree_cached,
    };
    if rec.json {
        // The parser's warnings are in JSON words already; this makes the build's match them.
        for w in &mut warnings {
            w.message = json_words(&w.message);
        }
    }
    let mut scene = Scene {
        source: rec.source.clone(),
        background: v3(rec.background_color),
        shadow_ray_epsilon: rec.shadow_ray_epsilon,
        intersection_test_epsilon: rec.intersection_test_epsilon,
        max_recursion_depth: rec.max_recursion_depth.min(MAX_RECURSION_DEPTH_LIMIT),
        cull_camera_back_faces: rec.json,
        rules: Default::default(),
        ambient_light: v3(rec.ambient_light),
        area_lights: lights.area,
        point_lights: lights.point,
        directional_lights: lights.directional,
        spot_lights: lights.spot,
        object_lights,
        instance_emission,
        instance_light,
        env_light: textures.env_light,
        extra_env_lights: textures.extra_env_lights,
        more_colour_maps: textures.more_colour.into_inner().unwrap_or_default(),
        materials,
        cameras,
        accel,
        textures: textures.maps,
        background_texture: textures.background,
        warnings,
        stats,
        light_choice: Default::default(),
        path_lanes: Default::default(),
        horizons: Default::default(),
    };
    scene.light_choice = crate::lights::choice::LightChoice::new(
        &scene.point_lights,
        &scene.area_lights,
        &scene.directional_lights,
        &scene.spot_lights,
        &scene.object_lights,
        scene.env_light.iter().chain(&scene.extra_env_lights),
        scene.accel.extent().unwrap_or(2.0) / 2.0,
    );
    Ok(scene)
}

/// Warnings about epsilons that no scene means: negative ones, and offsets beyond a tenth of
/// the objects' extent (`extent`, the diagonal of their box), which let rays pass through
/// whole objects near their start. Both still render as given.
fn epsilons(ctx: &Ctx, extent: Option<f64>, warnings: &mut Vec<Warning>) {
    let rec = ctx.rec;
    let given = [
        (
            rec.shadow_ray_epsilon,
            "ShadowRayEpsilon",
            "1e-3",
            "offset",
            "start below their surface, which then shadows itself (dark speckles)",
            "start that far from their surface and pass through whatever is nearer",
        ),
        (
            rec.intersection_test_epsilon,
            "IntersectionTestEpsilon",
            "1e-6",
            "tolerance",
            "accept hits behind their origin",
            "ignore every surface nearer than that",
        ),
    ];
    for ((e, name, default, what, negative, large), loc) in given.into_iter().zip(&rec.epsilon_locs) {
        let Some(loc) = loc else { continue };
        // Numbers as a person writes them: 2e54, not 54 zeros.
        let moderate = |x: f64| x == 0.0 || (1e-3..1e6).contains(&x.abs());
        let shown = if moderate(e) { format!("{e}") } else { format!("{e:e}") };
        let problem = if e < 0.0 {
            format!("{name} {shown} is negative: rays {negative}")
        } else if let Some(d) = extent.filter(|&d| d > 0.0 && e > 0.1 * d) {
            let span = if moderate(d) { format!("{d:.3}") } else { format!("{d:.3e}") };
            format!(
                "{name} {shown} is more than a tenth of the scene's size (its objects span {span}): rays {large}"
            )
        } else {
            continue;
        };
        ctx.warn(
            warnings,
            loc,
            format!("{problem}; give a small positive {what} such as {default} (the default)"),
        );
    }
}

/// Step 1: the materials, by position, and how the scene's ids find them (a repeated id keeps
/// its first definition, with a warning). `degamma` materials are linearised here (§6.6). A
/// material's `BRDF` attribute finds its `<BRDFs>` entry (§7), whose Exponent replaces the
/// material's PhongExponent.
fn build_materials<'a>(
    ctx: &Ctx<'a>,
    warnings: &mut Vec<Warning>,
) -> Result<(Vec<Material>, HashMap<&'a str, u32>), SceneError> {
    let rec = ctx.rec;
    let mut brdfs: HashMap<&str, &BrdfRec> = HashMap::new();
    for b in &rec.brdfs {
        if brdfs.contains_key(b.id.as_str()) {
            ctx.warn(
                warnings,
                &b.loc,
                format!("BRDF id \"{}\" is defined again; materials use the first definition", b.id),
            );
        }
        brdfs.entry(b.id.as_str()).or_insert(b);
    }
    let mut mat_ids: HashMap<&str, u32> = HashMap::new();
    let mut materials = Vec::with_capacity(rec.materials.len());
    let degamma = degamma_exponent(rec);
    for m in &rec.materials {
        if mat_ids.contains_key(m.id.as_str()) {
            ctx.warn(
                warnings,
                &m.loc,
                format!("material id \"{}\" is defined again; references use the first definition", m.id),
            );
        }
        mat_ids.entry(m.id.as_str()).or_insert(materials.len() as u32);
        let lin = |c: Vec3| -> DVec3 {
            let c = v3(c);
            if m.degamma { c.max(DVec3::ZERO).powf(degamma) } else { c }
        };
        let brdf = match &m.brdf {
            None => None,
            Some(id) => Some(*brdfs.get(id.as_str()).ok_or_else(|| {
                ctx.err(
                    &m.loc,
                    format!("BRDF \"{id}\" is not defined; add an entry with id=\"{id}\" under <BRDFs> or use an existing id"),
                )
            })?),
        };
        let exponent = brdf.map_or(m.phong_exponent, |b| b.exponent);
        materials.push(Material {
            kind: m.kind,
            ambient: lin(m.ambient),
            diffuse: lin(m.diffuse),
            specular: lin(m.specular),
            mirror: lin(m.mirror),
            phong_exponent: exponent,
            phong_exponent_int: (exponent.fract() == 0.0 && (0.0..=4096.0).contains(&exponent))
                .then_some(exponent as i32),
            refraction_index: m.refraction_index,
            absorption_index: m.absorption_index,
            absorption: v3(m.absorption_coefficient),
            roughness: m.roughness,
            brdf: brdf.map(|b| Brdf {
                kind: b.kind,
                normalized: b.normalized,
                kd_fresnel: b.kd_fresnel,
                refractive_index: b.refractive_index,
            }),
        });
    }
    Ok((materials, mat_ids))
}

/// The scene's point, area, directional and spot lights (the environment light is built with
/// the textures, whose image it shares).
struct Lights {
    point: Vec<PointLight>,
    area: Vec<AreaLight>,
    directional: Vec<DirectionalLight>,
    spot: Vec<SpotLight>,
}

/// Step 3: the lights, each placed by its own Transformations (§10.4). An area light keeps its
/// Size: the record is a square of side `size`, which a non-uniform scale could not keep square,
/// and the course gives no rule for scaling it.
fn placed_lights(ctx: &Ctx, transforms: &HashMap<(char, &str), TransformOp>) -> Result<Lights, SceneError> {
    let rec = ctx.rec;
    let mut point = Vec::with_capacity(rec.point_lights.len());
    for l in &rec.point_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        let position = placed_point(placement.as_ref(), l.position);
        point.push(PointLight { position, intensity: v3(l.intensity) });
    }
    let mut area = Vec::with_capacity(rec.area_lights.len());
    for l in &rec.area_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        let center = placed_point(placement.as_ref(), l.position);
        let normal = placed_normal(placement.as_ref(), l.normal);
        area.push(AreaLight::new(center, normal, l.size, v3(l.radiance)));
    }
    let mut directional = Vec::with_capacity(rec.directional_lights.len());
    for l in &rec.directional_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        let direction = placed_vector(placement.as_ref(), l.direction);
        directional.push(DirectionalLight::new(direction, v3(l.radiance)));
    }
    let mut spot = Vec::with_capacity(rec.spot_lights.len());
    for l in &rec.spot_lights {
        let placement = ctx.placement(transforms, &l.transforms, &l.loc)?;
        spot.push(SpotLight::new(
            placed_point(placement.as_ref(), l.position),
            placed_vector(placement.as_ref(), l.direction),
            v3(l.intensity),
            l.coverage_angle,
            l.falloff_angle,
        ));
    }
    Ok(Lights { point, area, directional, spot })
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::sync::Arc;

    use glam::{DAffine3, DVec2};

    use crate::assets::FsResolver;
    use crate::geometry::Shape;
    use crate::math::Ray;
    use crate::texture::maps::Source;

    fn build(xml: &str) -> Result<Scene, SceneError> {
        let rec = crate::scene::xml::parse_xml(xml, std::path::Path::new("t.xml"))?;
        build_scene(&rec, &FsResolver { base_dir: ".".into() })
    }

    const CHAIN: &str = r#"<Scene>
      <Materials><Material id="1"/><Material id="2"/></Materials>
      <Transformations><Translation id="1">0 0 -10</Translation><Translation id="2">100 0 0</Translation></Transformations>
      <VertexData>-1 -1 0  1 -1 0  0 1 0</VertexData>
      <Objects>
        <Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
        <MeshInstance id="2" baseMeshId="1"><Transformations>t1</Transformations></MeshInstance>
        <MeshInstance id="3" baseMeshId="2"><Material>2</Material><Transformations>t1</Transformations></MeshInstance>
        <MeshInstance id="4" baseMeshId="3" resetTransform="true"><Transformations>t2</Transformations></MeshInstance>
      </Objects></Scene>"#;

    /// `Textures` on a MeshInstance replace its base mesh's; an instance without any keeps its
    /// base's, through a chain of instances.
    #[test]
    fn an_instance_s_own_textures_replace_its_base_s() {
        let scene = build(
            r#"<Scene>
      <Materials><Material id="1"/></Materials>
      <Textures>
        <TextureMap id="red" type="checkerboard"><DecalMode>replace_kd</DecalMode><BlackColor>1 0 0</BlackColor><WhiteColor>1 0 0</WhiteColor></TextureMap>
        <TextureMap id="blue" type="checkerboard"><DecalMode>replace_kd</DecalMode><BlackColor>0 0 1</BlackColor><WhiteColor>0 0 1</WhiteColor></TextureMap>
      </Textures>
      <VertexData>-1 -1 0  1 -1 0  0 1 0</VertexData>
      <Objects>
        <Mesh id="1"><Material>1</Material><Textures>red</Textures><Faces>1 2 3</Faces></Mesh>
        <MeshInstance id="2" baseMeshId="1"></MeshInstance>
        <MeshInstance id="3" baseMeshId="1"><Textures>blue</Textures></MeshInstance>
        <MeshInstance id="4" baseMeshId="3"></MeshInstance>
      </Objects></Scene>"#,
        )
        .unwrap();
        let colour = |i: usize| {
            let t = scene.accel.instances[i].textures;
            assert!(t.colour[1].is_none() && t.normal.is_none());
            let map = &scene.textures[t.colour[0].expect("a colour map") as usize];
            let p = crate::texture::maps::TexturePoint {
                uv: glam::DVec2::ZERO,
                object: DVec3::splat(0.5),
                footprint: glam::DVec2::ZERO,
            };
            map.value(&p)
        };
        let (red, blue) = (DVec3::X, DVec3::Z);
        // The mesh, the instance without textures, the one with its own, and its instance.
        assert_eq!([colour(0), colour(1), colour(2), colour(3)], [red, red, blue, blue]);
    }

    /// Triangles beyond `MAX_COORDINATE`, in a mesh's own coordinates or carried there by an
    /// instance's transformations, are left out of the picture with a warning at the object
    /// that names how many; the rest of the scene is still hit, and a scene within range warns
    /// of nothing.
    #[test]
    fn triangles_beyond_the_range_are_named() {
        let scene = build(
            r#"<Scene>
      <Materials><Material id="1"/></Materials>
      <Transformations><Scaling id="1">1e19 1e19 1e19</Scaling></Transformations>
      <VertexData>-1 -1 0  1 -1 0  0 1 0  1 1 0  3e18 0 0</VertexData>
      <Objects>
        <Mesh id="1"><Material>1</Material><Faces>1 2 3  2 4 3</Faces></Mesh>
        <Mesh id="2"><Material>1</Material><Faces>1 2 3  2 5 3</Faces></Mesh>
        <MeshInstance id="3" baseMeshId="1"><Transformations>s1</Transformations></MeshInstance>
        <Triangle id="4"><Material>1</Material><Indices>1 5 3</Indices></Triangle>
      </Objects></Scene>"#,
        )
        .unwrap();
        let about = |element: &str| -> Vec<&str> {
            scene
                .warnings
                .iter()
                .filter(|w| w.loc.element.as_deref().is_some_and(|e| e.starts_with(element)))
                .map(|w| w.message.as_str())
                .collect()
        };
        assert!(about(r#"Mesh id="1""#).is_empty(), "{:?}", scene.warnings);
        let own = about(r#"Mesh id="2""#);
        assert!(
            own.len() == 1 && own[0].starts_with("its vertex data puts 1 of its 2 triangles beyond ±1e18"),
            "{own:?}"
        );
        let carried = about(r#"MeshInstance id="3""#);
        assert!(
            carried.len() == 1
                && carried[0].starts_with("its transformations carry 2 of its 2 triangles beyond ±1e18"),
            "{carried:?}"
        );
        let single = about(r#"Triangle id="4""#);
        assert!(single.len() == 1 && single[0].contains("puts its triangle beyond"), "{single:?}");
        assert!(single[0].contains("it is left out and will not be seen"), "{single:?}");
        // The meshes' triangles within range are still there, in front of the camera's way.
        let hit =
            scene.accel.intersect(&Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::NEG_Z), 1e-6, f64::INFINITY);
        assert!(hit.is_some_and(|h| (h.t - 5.0).abs() < 1e-9), "{hit:?}");
        let plain = build(CHAIN).unwrap();
        assert!(plain.warnings.iter().all(|w| !w.message.contains("beyond ±")), "{:?}", plain.warnings);
    }

    /// A camera so far out that doubles cannot tell its pixels' directions apart is warned
    /// about (at the camera); the same camera nearer the origin is not.
    #[test]
    fn a_camera_beyond_double_precision_is_named() {
        let scene = |position: &str| {
            build(&format!(
                r#"<Scene><Cameras><Camera id="7"><Position>{position}</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
                <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>64 64</ImageResolution>
                <ImageName>a.png</ImageName></Camera></Cameras></Scene>"#
            ))
            .unwrap()
        };
        let far = scene("0 0 1e16");
        let warned: Vec<_> = far.warnings.iter().filter(|w| w.message.contains("from the origin")).collect();
        assert_eq!(warned.len(), 1, "{:?}", far.warnings);
        assert_eq!(warned[0].loc.element.as_deref(), Some(r#"Camera id="7""#));
        assert!(
            warned[0].message.starts_with("the camera is 1.0e16 from the origin"),
            "{}",
            warned[0].message
        );
        // 1e12 out, doubles lie 1.1e-4 apart: well within a sixteenth of a 1/32-wide pixel.
        let near = scene("5e11 -3 1e12");
        assert!(near.warnings.iter().all(|w| !w.message.contains("from the origin")), "{:?}", near.warnings);
    }

    /// A material's BRDF must exist; a LightMesh and a LightSphere become object lights with
    /// their instances' radiance, in file order; a light of no area shows but does not light.
    #[test]
    fn brdf_references_and_object_lights() {
        let err = build(r#"<Scene><Materials><Material id="1" BRDF="9"></Material></Materials></Scene>"#)
            .err()
            .expect("an unknown BRDF is an error");
        assert!(err.to_string().contains(r#"BRDF "9" is not defined"#), "{err}");
        let scene = build(
            r#"<Scene><BRDFs><ModifiedPhong id="b"><Exponent>20</Exponent></ModifiedPhong></BRDFs>
            <Materials><Material id="1" BRDF="b"><PhongExponent>3</PhongExponent></Material></Materials>
            <VertexData>0 0 0  1 0 0  0 1 0  0 0 0</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh>
              <LightMesh id="2"><Material>1</Material><Radiance>2 2 2</Radiance><Faces>1 2 3</Faces></LightMesh>
              <LightMesh id="3"><Material>1</Material><Radiance>2 2 2</Radiance><Faces>1 1 2</Faces></LightMesh>
              <LightSphere id="4"><Material>1</Material><Center>4</Center><Radius>2</Radius><Radiance>1 2 3</Radiance></LightSphere>
            </Objects></Scene>"#,
        )
        .unwrap();
        assert_eq!(scene.materials[0].phong_exponent, 20.0, "the BRDF's Exponent replaces PhongExponent");
        assert_eq!(scene.materials[0].brdf.map(|b| b.kind), Some(BrdfKind::ModifiedPhong));
        let emission: Vec<Option<DVec3>> = scene.instance_emission.clone();
        assert_eq!(emission.len(), scene.accel.instances.len());
        assert_eq!(emission.iter().filter(|e| e.is_some()).count(), 3);
        let lit: Vec<u32> = scene.object_lights.iter().map(|l| l.instance).collect();
        assert_eq!(lit.len(), 2, "the degenerate light mesh lights nothing");
        assert_eq!(emission[lit[0] as usize], Some(DVec3::splat(2.0)));
        assert_eq!(emission[lit[1] as usize], Some(DVec3::new(1.0, 2.0, 3.0)));
        assert_eq!(scene.object_lights[1].area(), Some(16.0 * std::f64::consts::PI));
    }

    /// An untextured, unmoving sphere under rotations, a reflection, a uniform scale and a
    /// translation becomes a world-space sphere (no transform to apply per ray), hit where the
    /// transformed one is; a non-uniform scale, motion or a texture keep the transform.
    #[test]
    fn similarity_transformed_spheres_are_placed_in_world_space() {
        let scene = build(
            r#"<Scene><Materials><Material id="1"></Material></Materials>
            <Transformations><Translation id="1">1 2 3</Translation><Scaling id="1">2 2 2</Scaling>
              <Scaling id="2">-2 2 2</Scaling><Scaling id="3">2 1 1</Scaling><Rotation id="1">30 1 1 0</Rotation></Transformations>
            <VertexData>0 0 0  0.5 0 0</VertexData>
            <Objects>
              <Sphere id="1"><Material>1</Material><Center>2</Center><Radius>1</Radius><Transformations>r1 s1 t1</Transformations></Sphere>
              <Sphere id="2"><Material>1</Material><Center>1</Center><Radius>1</Radius><Transformations>s2 r1</Transformations></Sphere>
              <Sphere id="3"><Material>1</Material><Center>1</Center><Radius>1</Radius><Transformations>s3</Transformations></Sphere>
              <Sphere id="4"><Material>1</Material><Center>1</Center><Radius>1</Radius><Transformations>s1</Transformations><MotionBlur>0 1 0</MotionBlur></Sphere>
            </Objects></Scene>"#,
        )
        .unwrap();
        let shapes: Vec<(Option<(DVec3, f64)>, bool)> = scene
            .accel
            .instances
            .iter()
            .map(|i| match i.shape {
                Shape::Sphere { center, radius } => (Some((center, radius)), i.transform.is_some()),
                _ => (None, i.transform.is_some()),
            })
            .collect();
        // r1 s1 t1 applied to (0.5, 0, 0): rotated about (1 1 0)/√2 by 30°, doubled, moved.
        let m = DAffine3::from_translation(DVec3::new(1.0, 2.0, 3.0))
            * DAffine3::from_scale(DVec3::splat(2.0))
            * DAffine3::from_axis_angle(DVec3::new(1.0, 1.0, 0.0).normalize(), 30f64.to_radians());
        let (c, r) = shapes[0].0.unwrap();
        assert!(
            (c - m.transform_point3(DVec3::new(0.5, 0.0, 0.0))).length() < 1e-12 && (r - 2.0).abs() < 1e-12
        );
        assert!(!shapes[0].1 && !shapes[1].1, "similarities (with a reflection too) are baked: {shapes:?}");
        assert_eq!(shapes[1].0.map(|s| s.1), Some(2.0));
        assert!(shapes[2].1 && shapes[3].1, "a non-uniform scale and a moving sphere keep their transform");
        // Hit where the transformed sphere is: its top along the world z axis through the centre.
        let h = scene
            .accel
            .intersect(&Ray::new(c + DVec3::new(0.0, 0.0, 10.0), DVec3::NEG_Z), 1e-9, 1e9)
            .unwrap();
        assert!((h.t - 8.0).abs() < 1e-9 && (h.geo_normal - DVec3::Z).length() < 1e-12, "{h:?}");
    }

    #[test]
    fn instances_chain_through_other_instances() {
        let scene = build(CHAIN).unwrap();
        let hit = |x: f64, z0: f64| {
            scene.accel.intersect(&Ray::new(DVec3::new(x, 0.0, z0), DVec3::NEG_Z), 1e-9, 1e9)
        };
        // The mesh at z=0, instance 2 at z=-10, instance 3 (t1 on top of instance 2) at z=-20.
        let h = hit(0.0, -15.0).unwrap();
        assert!((h.point.z + 20.0).abs() < 1e-9 && h.material == 1, "{h:?}");
        let h = hit(0.0, -5.0).unwrap();
        assert!((h.point.z + 10.0).abs() < 1e-9 && h.material == 0, "{h:?}");
        // Instance 4 resets to its own t2 and inherits instance 3's material.
        let h = hit(100.0, 5.0).unwrap();
        assert!(h.point.z.abs() < 1e-9 && h.material == 1, "{h:?}");
    }

    #[test]
    fn instance_cycles_and_unknown_bases_are_errors() {
        let cyc = CHAIN
            .replace(r#"<MeshInstance id="2" baseMeshId="1">"#, r#"<MeshInstance id="2" baseMeshId="4">"#);
        let e = build(&cyc).err().expect("a cycle must fail").to_string();
        assert!(e.contains("cycle") && e.contains("MeshInstance"), "{e}");
        let unknown = CHAIN.replace(r#"baseMeshId="3""#, r#"baseMeshId="9""#);
        let e = build(&unknown).err().expect("an unknown base must fail").to_string();
        assert!(e.contains(r#"baseMeshId="9""#) && e.contains("t.xml:"), "{e}");
    }

    /// A 2019 binary file: the int32 count, then the records' 32-bit words, little-endian.
    fn binary(count: i32, words: &[[u8; 4]]) -> Vec<u8> {
        let mut out = count.to_le_bytes().to_vec();
        words.iter().for_each(|w| out.extend(w));
        out
    }

    /// 2019 `binaryFile` vertices, texture coordinates and faces, and `ZeroBasedIndexing`
    /// (faces and a Triangle's Indices count from 0): a square of a binary-faced mesh and a
    /// Triangle, each hit where its vertices put it, with the binary uvs (the mesh has a map, so
    /// its hits carry them).
    #[test]
    fn binary_data_and_zero_based_indexing() {
        let dir = tessera_testkit::TempDir::new("build-binary");
        let f = |v: f32| v.to_le_bytes();
        let verts: Vec<[u8; 4]> =
            [-1.0, -1.0, -5.0, 1.0, -1.0, -5.0, 1.0, 1.0, -5.0, -1.0, 1.0, -5.0].map(f).to_vec();
        let uvs: Vec<[u8; 4]> = [0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0].map(f).to_vec();
        std::fs::write(dir.join("v.bin"), binary(4, &verts)).unwrap();
        std::fs::write(dir.join("uv.bin"), binary(4, &uvs)).unwrap();
        std::fs::write(dir.join("f.bin"), binary(1, &[0i32, 1, 2].map(i32::to_le_bytes))).unwrap();
        // A count beyond the data.
        std::fs::write(dir.join("short.bin"), binary(2, &[0i32, 1, 2].map(i32::to_le_bytes))).unwrap();
        let xml = |zero_based: &str, faces: &str| {
            format!(
                r#"<Scene>
<ZeroBasedIndexing>{zero_based}</ZeroBasedIndexing>
<Materials><Material id="1"/></Materials><Textures><TextureMap id="c" type="checkerboard"><DecalMode>replace_kd</DecalMode></TextureMap></Textures>
<VertexData binaryFile="v.bin"/>
<TexCoordData binaryFile="uv.bin"/>
<Objects>
<Mesh id="1"><Material>1</Material><Textures>c</Textures><Faces binaryFile="{faces}"/></Mesh>
<Triangle id="1"><Material>1</Material><Indices>0 2 3</Indices></Triangle>
</Objects></Scene>"#
            )
        };
        let build_at = |text: &str| {
            let rec = crate::scene::xml::parse_xml(text, &dir.join("s.xml"))?;
            build_scene(&rec, &FsResolver { base_dir: dir.to_path_buf() })
        };
        let scene = build_at(&xml("true", "f.bin")).unwrap();
        assert!(scene.warnings.iter().all(|w| !w.unsupported), "{:?}", scene.warnings);
        let hit = |x: f64, y: f64| {
            scene.accel.intersect(&Ray::new(DVec3::new(x, y, 0.0), DVec3::NEG_Z), 1e-9, 1e9).expect("a hit")
        };
        let h = hit(0.5, -0.5);
        assert_eq!(h.instance, 0);
        assert!((h.t - 5.0).abs() < 1e-9);
        assert!((h.uv - DVec2::new(0.75, 0.25)).length() < 1e-6, "{:?}", h.uv);
        let h = hit(-0.5, 0.5);
        assert_eq!(h.instance, 1);
        assert!((h.t - 5.0).abs() < 1e-9);
        // Read 1-based, vertex 0 does not exist.
        let e = build_at(&xml("false", "f.bin")).err().expect("vertex 0 is an error 1-based");
        assert!(
            e.to_string().contains("s.xml:7: <Mesh id=\"1\"> / <Faces>: face 1 refers to vertex 0"),
            "{e}"
        );
        // A missing or truncated file is an error naming the element's line and the file.
        let e = build_at(&xml("true", "none.bin")).err().expect("a missing file");
        assert!(e.to_string().contains("s.xml:7: <Mesh id=\"1\"> / <Faces>: cannot read binary file"), "{e}");
        assert!(e.to_string().contains("none.bin"), "{e}");
        let e = build_at(&xml("true", "short.bin")).err().expect("a truncated file");
        assert!(
            e.to_string()
                .contains("says it holds 2 triangles of 3 int32 vertex ids, but it is 16 bytes long"),
            "{e}"
        );
    }

    #[test]
    fn an_image_used_by_several_maps_is_decoded_once() {
        let dir = tessera_testkit::TempDir::new("build-img");
        // A 1x1 grey PNG from the image crate.
        let png = dir.join("g.png");
        image::save_buffer(&png, &[9, 9, 9], 1, 1, image::ExtendedColorType::Rgb8).unwrap();
        let xml = r#"<Scene><Textures><Images><Image id="1">g.png</Image><Image id="2">./g.png</Image></Images>
            <TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode></TextureMap>
            <TextureMap id="2" type="image"><ImageId>1</ImageId><DecalMode>bump_normal</DecalMode></TextureMap>
            <TextureMap id="3" type="image"><ImageId>2</ImageId><DecalMode>replace_ks</DecalMode></TextureMap>
            </Textures></Scene>"#;
        let rec = crate::scene::xml::parse_xml(xml, &dir.join("s.xml")).unwrap();
        let scene = build_scene(&rec, &FsResolver { base_dir: dir.to_path_buf() }).unwrap();
        let img = |k: usize| match &scene.textures[k].source {
            Source::Image { image, .. } => image.clone(),
            _ => panic!("not an image map"),
        };
        // Maps 1 and 2 share image 1: one decoded copy. Image 2 names the file differently.
        assert!(Arc::ptr_eq(&img(0), &img(1)));
        assert_eq!(img(2).texels, img(0).texels);
        // A missing image names the file, the image id and the map that uses it.
        let missing = xml.replace("<Image id=\"1\">g.png", "<Image id=\"1\">nope.png");
        let rec = crate::scene::xml::parse_xml(&missing, &dir.join("s.xml")).unwrap();
        let e = build_scene(&rec, &FsResolver { base_dir: dir.to_path_buf() })
            .err()
            .expect("must fail")
            .to_string();
        assert!(e.contains("nope.png") && e.contains("image id 1") && e.contains("texture map 1"), "{e}");
    }

    #[test]
    fn oversized_images_are_refused() {
        let xml = r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
            <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>100000 100000</ImageResolution>
            <ImageName>a.png</ImageName></Camera></Cameras></Scene>"#;
        let e = build(xml).err().expect("must fail").to_string();
        assert!(e.contains("too large") && e.contains("Camera"), "{e}");
    }

    /// A scene with r1 (90° about y), t1 (10, 0, 0), s1 (2, 1, 1) and s2 (0, 0, 0), and the given
    /// `<Cameras>` and `<Lights>` contents.
    fn placed(cameras: &str, lights: &str) -> String {
        format!(
            r#"<Scene>
      <Transformations><Rotation id="1">90 0 1 0</Rotation><Translation id="1">10 0 0</Translation>
        <Scaling id="1">2 1 1</Scaling><Scaling id="2">0 0 0</Scaling></Transformations>
      <Cameras>
{cameras}
      </Cameras>
      <Lights>
{lights}
      </Lights></Scene>"#
        )
    }

    /// A camera of `kind` (`""` or `type="lookAt"`) with the given view children.
    fn camera_xml(kind: &str, view: &str) -> String {
        let plane =
            if kind.is_empty() { "<NearPlane>-1 1 -0.75 0.75</NearPlane>" } else { "<FovY>40</FovY>" };
        format!(
            r#"<Camera id="1" {kind}>{view}{plane}
            <NearDistance>1</NearDistance><ImageResolution>8 6</ImageResolution><ImageName>a.png</ImageName></Camera>"#
        )
    }

    fn assert_near(got: DVec3, want: DVec3, what: &str) {
        assert!((got - want).length() < 1e-9, "{what}: got {got}, want {want}");
    }

    /// Every pixel's primary ray, through several points of the pixel.
    fn assert_same_rays(got: &Camera, want: &Camera) {
        for y in 0..want.height {
            for x in 0..want.width {
                for (dx, dy) in [(0.0, 0.0), (0.5, 0.5), (0.9, 0.2)] {
                    let (g, w) = (got.ray(x, y, dx, dy), want.ray(x, y, dx, dy));
                    assert_near(g.origin, w.origin, &format!("origin of ray ({x}, {y})"));
                    assert_near(g.dir, w.dir, &format!("direction of ray ({x}, {y})"));
                }
            }
        }
    }

    #[test]
    fn camera_transformations_place_it_like_moving_its_vectors_by_hand() {
        // r1 then t1: (x, y, z) -> (z + 10, y, -x). Up is tilted so the rotation changes it.
        let cases = [
            (
                "",
                "<Position>1 2 3</Position><Gaze>0 0 -1</Gaze><Up>0 1 0.2</Up>",
                "<Position>13 2 -1</Position><Gaze>-1 0 0</Gaze><Up>0.2 1 0</Up>",
            ),
            (
                r#"type="lookAt""#,
                "<Position>1 2 3</Position><GazePoint>1 2 -7</GazePoint><Up>0 1 0.2</Up>",
                "<Position>13 2 -1</Position><GazePoint>3 2 -1</GazePoint><Up>0.2 1 0</Up>",
            ),
        ];
        for (kind, view, by_hand) in cases {
            let transformed = format!("{view}<Transformations>r1 t1</Transformations>");
            let got = build(&placed(&camera_xml(kind, &transformed), "")).unwrap();
            let want = build(&placed(&camera_xml(kind, by_hand), "")).unwrap();
            assert!(got.warnings.is_empty(), "{:?}", got.warnings);
            assert_same_rays(&got.cameras[0], &want.cameras[0]);
        }
        // Rotation alone: the position turns about the origin too.
        let got = build(&placed(
            &camera_xml("", "<Position>1 2 3</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up><Transformations>r1</Transformations>"),
            "",
        ))
        .unwrap();
        let want = build(&placed(
            &camera_xml("", "<Position>3 2 -1</Position><Gaze>-1 0 0</Gaze><Up>0 1 0</Up>"),
            "",
        ))
        .unwrap();
        assert_same_rays(&got.cameras[0], &want.cameras[0]);
    }

    /// A scaling along the gaze moves a NearPlane camera's image plane by its factor (the
    /// plane's extents as given): camera_zoom_david's frames zoom so.
    #[test]
    fn a_scaling_along_the_gaze_moves_the_image_plane() {
        let view = "<Position>0 0 0</Position><Gaze>-1 0 0</Gaze><Up>0 1 0</Up>";
        let got =
            build(&placed(&camera_xml("", &format!("{view}<Transformations>s1</Transformations>")), ""))
                .unwrap();
        let by_hand =
            camera_xml("", view).replace("<NearDistance>1</NearDistance>", "<NearDistance>2</NearDistance>");
        let want = build(&placed(&by_hand, "")).unwrap();
        assert_same_rays(&got.cameras[0], &want.cameras[0]);
        // Across the gaze it changes nothing (the scaling is along x, the view along z).
        let across = "<Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>";
        let got =
            build(&placed(&camera_xml("", &format!("{across}<Transformations>s1</Transformations>")), ""))
                .unwrap();
        let want = build(&placed(&camera_xml("", across), "")).unwrap();
        assert_same_rays(&got.cameras[0], &want.cameras[0]);
    }

    #[test]
    fn light_transformations_move_positions_and_turn_directions() {
        let lights = r#"<PointLight id="1"><Position>1 2 3</Position><Intensity>5 5 5</Intensity>
                <Transformations>t1</Transformations></PointLight>
            <SpotLight id="2"><Position>1 2 3</Position><Direction>0 0 -1</Direction><Intensity>1 1 1</Intensity>
                <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Transformations>r1 t1</Transformations></SpotLight>
            <DirectionalLight id="3"><Direction>0 0 -2</Direction><Radiance>1 1 1</Radiance>
                <Transformations>r1</Transformations></DirectionalLight>
            <AreaLight id="4"><Position>0 5 0</Position><Normal>0 0 1</Normal><Size>2</Size><Radiance>1 1 1</Radiance>
                <Transformations>r1</Transformations></AreaLight>
            <AreaLight id="5"><Position>1 1 1</Position><Normal>1 1 0</Normal><Size>3</Size><Radiance>1 1 1</Radiance>
                <Transformations>s1</Transformations></AreaLight>
            <PointLight id="6"><Position>1 2 3</Position><Intensity>5 5 5</Intensity></PointLight>"#;
        let scene = build(&placed("", lights)).unwrap();
        assert_near(scene.point_lights[0].position, DVec3::new(11.0, 2.0, 3.0), "translated point light");
        assert_eq!(scene.point_lights[0].intensity, DVec3::splat(5.0));
        assert_eq!(scene.point_lights[1].position, DVec3::new(1.0, 2.0, 3.0), "untransformed point light");
        let spot = &scene.spot_lights[0];
        assert_near(spot.position, DVec3::new(13.0, 2.0, -1.0), "spot position");
        assert_near(spot.axis, DVec3::NEG_X, "spot axis");
        assert_near(scene.directional_lights[0].to_light, DVec3::X, "directional light");
        let area = &scene.area_lights[0];
        assert_near(area.center, DVec3::new(0.0, 5.0, 0.0), "area light centre on the rotation axis");
        assert_near(area.normal, DVec3::X, "rotated area light normal");
        assert_eq!(area.size, 2.0);
        // Under a non-uniform scale the normal goes by the inverse transpose, so it stays
        // perpendicular to the scaled square (a tangent (1, -1, 0) becomes (2, -1, 0)); Size stays.
        let scaled = &scene.area_lights[1];
        assert_near(scaled.normal, DVec3::new(0.5, 1.0, 0.0).normalize(), "scaled area light normal");
        assert!(scaled.normal.dot(DVec3::new(2.0, -1.0, 0.0)).abs() < 1e-12);
        assert_near(scaled.center, DVec3::new(2.0, 1.0, 1.0), "scaled area light centre");
        assert_eq!(scaled.size, 3.0);
    }

    #[test]
    fn unknown_or_singular_camera_and_light_transformations_are_errors() {
        let view = "<Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>";
        let point = |t: &str| {
            format!(
                "<PointLight id=\"7\"><Position>0 0 0</Position><Intensity>1 1 1</Intensity><Transformations>{t}</Transformations></PointLight>"
            )
        };
        let spot = r#"<SpotLight id="8"><Position>0 0 0</Position><Direction>0 -1 0</Direction><Intensity>1 1 1</Intensity>
                <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Transformations>t1 c3</Transformations></SpotLight>"#;
        let directional = r#"<DirectionalLight id="9"><Direction>0 -1 0</Direction><Radiance>1 1 1</Radiance>
                <Transformations>r1 s2</Transformations></DirectionalLight>"#;
        let cases: &[(String, &str)] = &[
            (
                placed(&camera_xml("", &format!("{view}<Transformations>r1 r9</Transformations>")), ""),
                r#"t.xml:5: <Camera id="1">: transformation "r9" is not defined; add <Rotation id="9"> under <Transformations>"#,
            ),
            (
                placed(
                    &camera_xml(r#"type="lookAt""#, &format!("{view}<Transformations>t2</Transformations>")),
                    "",
                ),
                r#"t.xml:5: <Camera id="1">: transformation "t2" is not defined; add <Translation id="2"> under <Transformations>"#,
            ),
            (
                placed("", &point("s5")),
                r#"t.xml:8: <PointLight id="7">: transformation "s5" is not defined; add <Scaling id="5"> under <Transformations>"#,
            ),
            (
                placed("", spot),
                r#"t.xml:8: <SpotLight id="8">: transformation "c3" is not defined; add <Composite id="3"> under <Transformations>"#,
            ),
            (
                placed("", directional),
                r#"t.xml:8: <DirectionalLight id="9">: the transformation is singular (a zero scale?); it would flatten the directions of this camera or light: use non-zero Scaling factors"#,
            ),
        ];
        for (xml, want) in cases {
            match build(xml) {
                Ok(_) => panic!("expected {want:?} for\n{xml}"),
                Err(e) => assert_eq!(e.to_string(), *want, "input:\n{xml}"),
            }
        }
    }

    #[test]
    fn transformation_tokens_apply_left_to_right() {
        // "t1 s1" with t1 = (-0.5, 0, -0.5) and s1 = 1000 centres a unit square before scaling (§10.2).
        let ops = [TransformOp::Translation([-0.5, 0.0, -0.5]), TransformOp::Scaling([1000.0; 3])];
        let m = op_matrix(&ops[1]) * op_matrix(&ops[0]);
        let p = m.transform_point3(DVec3::new(1.0, 0.0, 1.0));
        assert!((p - DVec3::new(500.0, 0.0, 500.0)).length() < 1e-9);
    }

    #[test]
    fn rotation_is_right_handed_in_degrees() {
        let m = op_matrix(&TransformOp::Rotation { degrees: 90.0, axis: [0.0, 0.0, 2.0] });
        assert!((m.transform_vector3(DVec3::X) - DVec3::Y).length() < 1e-12);
    }

    #[test]
    fn composite_is_row_major() {
        let mut a = [0.0; 16];
        a[0] = 1.0;
        a[5] = 1.0;
        a[10] = 1.0;
        a[15] = 1.0;
        a[3] = 7.0; // row 0, column 3 = x translation
        let m = op_matrix(&TransformOp::Composite(a));
        assert_eq!(m.transform_point3(DVec3::ZERO), DVec3::new(7.0, 0.0, 0.0));
    }
}
