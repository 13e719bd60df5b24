//! Determinism of the tracer (render.rs invariant): a pixel depends only on (scene, camera,
//! pixel, seed), never on the thread count, the tile size or the order tiles finish in, and a
//! scene built twice (BVHs included) renders the same bits.

use std::path::{Path, PathBuf};

use tessera::assets::FsResolver;
use tessera::image::{Image, TileRect};
use tessera::render::{RenderSettings, render_camera, render_tile};
use tessera::scene::Scene;
use tessera::scene::load::{load_scene_file, load_scene_str};

/// distribution.xml has every homework-3 effect: jittered multisampling, an area light, glossy
/// reflection, a thin lens and motion blur (checked by `the_distribution_scene_exercises_every_effect`);
/// environment.xml importance-samples an environment map, spotlights.xml has spot and directional
/// lights, path_traced.xml has object lights, BRDFs and path-traced cameras (homework 6),
/// torus_sky.xml lights a PLY mesh with an environment map alone.
const SCENES: [&str; 8] = [
    "cornell_box.xml",
    "tori.xml",
    "distribution.xml",
    "textures.xml",
    "environment.xml",
    "spotlights.xml",
    "path_traced.xml",
    "torus_sky.xml",
];

fn scenes_dir() -> PathBuf {
    tessera_tests::repo_root().join("scenes")
}

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool")
}

fn load(path: &Path) -> Scene {
    load_scene_file(path).unwrap_or_else(|e| panic!("cannot load {}: {e}", path.display()))
}

fn render_in(threads: usize, scene: &Scene, camera: usize, tile: u32) -> Image {
    pool(threads).install(|| render_camera(scene, camera, tile, &RenderSettings::default(), &|_, _| {}).0)
}

/// Panics with the first differing pixel unless `a` and `b` are bitwise identical.
fn assert_same_bits(a: &Image, b: &Image, what: &str) {
    assert_eq!((a.width, a.height), (b.width, b.height), "{what}: sizes differ");
    assert_eq!(a.pixels.len(), (a.width * a.height) as usize, "{what}: pixel count");
    let mut differing = 0usize;
    let mut first = None;
    for (i, (pa, pb)) in a.pixels.iter().zip(&b.pixels).enumerate() {
        if pa.map(f32::to_bits) != pb.map(f32::to_bits) {
            differing += 1;
            first.get_or_insert((i as u32 % a.width, i as u32 / a.width, *pa, *pb));
        }
    }
    if let Some((x, y, pa, pb)) = first {
        panic!("{what}: {differing} pixel(s) differ; first at ({x}, {y}): {pa:?} vs {pb:?}");
    }
}

fn assert_not_blank(img: &Image, what: &str) {
    let lit = img.pixels.iter().filter(|p| p.iter().any(|&c| c > 1.0)).count();
    assert!(lit > img.pixels.len() / 10, "{what}: only {lit} of {} pixels are lit", img.pixels.len());
    assert!(img.pixels.iter().flatten().all(|c| c.is_finite()), "{what}: non-finite pixel values");
}

#[test]
fn thread_count_and_tile_size_do_not_change_the_image() {
    for name in SCENES {
        let scene = load(&scenes_dir().join(name));
        for cam in 0..scene.cameras.len() {
            let a = render_in(1, &scene, cam, 16);
            let b = render_in(2, &scene, cam, 64);
            assert_not_blank(&a, name);
            assert_same_bits(&a, &b, &format!("{name} camera {cam}: 1 thread/tile 16 vs 2 threads/tile 64"));
            // An odd tile size whose tiles do not divide the frame.
            let c = render_in(2, &scene, cam, 23);
            assert_same_bits(&a, &c, &format!("{name} camera {cam}: tile 16 vs tile 23"));
        }
    }
}

#[test]
fn a_single_tile_equals_its_region_of_the_full_frame() {
    for name in SCENES {
        let scene = load(&scenes_dir().join(name));
        let full = render_in(2, &scene, 0, 32);
        let (w, h) = (full.width, full.height);
        // Unaligned rectangles: interior, touching the right/bottom edges, one pixel, one row.
        let rects = [
            TileRect { x0: 37, y0: 101, width: 45, height: 29 },
            TileRect { x0: w - 19, y0: h - 7, width: 19, height: 7 },
            TileRect { x0: w / 2, y0: h / 2, width: 1, height: 1 },
            TileRect { x0: 0, y0: h / 3, width: w, height: 1 },
        ];
        for rect in rects {
            let (px, stats) = render_tile(&scene, 0, rect, &RenderSettings::default());
            assert_eq!(px.len(), (rect.width * rect.height) as usize, "{name} {rect:?}: pixel count");
            let spp = scene.cameras[0].num_samples as u64;
            assert_eq!(
                stats.primary,
                (rect.width * rect.height) as u64 * spp,
                "{name} {rect:?}: NumSamples primary rays per pixel"
            );
            for ty in 0..rect.height {
                for tx in 0..rect.width {
                    let tile_px = px[(ty * rect.width + tx) as usize];
                    let (x, y) = (rect.x0 + tx, rect.y0 + ty);
                    let frame_px = full.pixels[(y * w + x) as usize];
                    assert_eq!(
                        tile_px.map(f32::to_bits),
                        frame_px.map(f32::to_bits),
                        "{name} {rect:?}: pixel ({x}, {y}) is {tile_px:?} in the tile but {frame_px:?} in the frame"
                    );
                }
            }
        }
    }
}

#[test]
fn building_a_scene_twice_gives_identical_images() {
    for name in SCENES {
        let path = scenes_dir().join(name);
        let one = pool(1).install(|| load(&path));
        let two = pool(2).install(|| load(&path));
        assert_eq!(one.stats.triangles, two.stats.triangles, "{name}: triangle count");
        assert_eq!(one.stats.instances, two.stats.instances, "{name}: instance count");
        for cam in 0..one.cameras.len() {
            let a = render_in(2, &one, cam, 32);
            let b = render_in(2, &two, cam, 32);
            assert_same_bits(
                &a,
                &b,
                &format!("{name} camera {cam}: built in a 1-thread pool vs a 2-thread pool"),
            );
        }
    }
}

#[test]
fn multisampled_render_is_deterministic() {
    let dir = scenes_dir();
    let text = std::fs::read_to_string(dir.join("cornell_box.xml")).expect("read cornell_box.xml");
    assert_eq!(text.matches("<ImageName>").count(), 1, "cornell_box.xml is expected to have one camera");
    let ns4 = text.replacen("<ImageName>", "<NumSamples>4</NumSamples>\n            <ImageName>", 1);
    let resolver = FsResolver { base_dir: dir.clone() };
    let source = dir.join("cornell_box_ns4.xml");
    let scene = load_scene_str(&ns4, &source, &resolver).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.cameras[0].num_samples, 4, "NumSamples was not picked up");

    let a = render_in(1, &scene, 0, 16);
    let b = render_in(2, &scene, 0, 64);
    let c = render_in(2, &scene, 0, 23);
    assert_not_blank(&a, "cornell_box NumSamples 4");
    assert_same_bits(&a, &b, "cornell_box NumSamples 4: 1 thread/tile 16 vs 2 threads/tile 64");
    assert_same_bits(&a, &c, "cornell_box NumSamples 4: tile 16 vs tile 23");

    // A second build of the same text renders the same bits.
    let again =
        pool(1).install(|| load_scene_str(&ns4, &source, &resolver).unwrap_or_else(|e| panic!("{e}")));
    assert_same_bits(&a, &render_in(2, &again, 0, 32), "cornell_box NumSamples 4: second build");

    // The jittered samples really are used: some pixels (edges) differ from the 1-spp render.
    let one_spp = load(&dir.join("cornell_box.xml"));
    let single = render_in(2, &one_spp, 0, 32);
    let differing = a
        .pixels
        .iter()
        .zip(&single.pixels)
        .filter(|(p, q)| p.map(f32::to_bits) != q.map(f32::to_bits))
        .count();
    assert!(differing > 0, "NumSamples 4 renders exactly like 1 spp");
}

#[test]
fn the_distribution_scene_exercises_every_effect() {
    let scene = load(&scenes_dir().join("distribution.xml"));
    let cam = &scene.cameras[0];
    assert!(cam.num_samples > 1, "multisampling");
    assert!(cam.lens.is_some(), "depth of field");
    assert!(!scene.area_lights.is_empty(), "area light");
    assert!(scene.materials.iter().any(|m| m.roughness > 0.0), "glossy reflection");
    assert!(scene.accel.instances.iter().filter(|i| i.motion.is_some()).count() >= 2, "motion blur");
    // And the effects change the picture: without them (one centred sample, pinhole, time 0,
    // no area light) the render differs.
    let full = render_in(2, &scene, 0, 32);
    let one = {
        let settings = RenderSettings { samples: Some(1), ..RenderSettings::default() };
        pool(1).install(|| render_camera(&scene, 0, 32, &settings, &|_, _| {}).0)
    };
    assert_ne!(full.pixels, one.pixels);
}

/// With fewer than eight samples a pixel, a group of camera rays takes the samples of several
/// pixels (see `render_tile_sums_until`): each pixel must still get the bits it gets alone, in a
/// one-pixel tile, where its group holds its own samples only.
#[test]
fn groups_across_pixels_give_each_pixel_its_own_bits() {
    for name in ["distribution.xml", "environment.xml", "path_traced.xml", "textures.xml"] {
        let scene = load(&scenes_dir().join(name));
        let cam = &scene.cameras[0];
        // A rectangle of 13 x 5 pixels: 65 pixels, so groups straddle rows and pixels.
        let rect = TileRect { x0: cam.width / 3, y0: cam.height / 2, width: 13, height: 5 };
        for samples in [1, 3, 5] {
            let settings = RenderSettings { samples: Some(samples), ..RenderSettings::default() };
            let (px, stats) = render_tile(&scene, 0, rect, &settings);
            assert_eq!(stats.primary, 65 * u64::from(samples), "{name}: one camera ray a sample");
            let mut alone_primary = 0;
            for ty in 0..rect.height {
                for tx in 0..rect.width {
                    let one = TileRect { x0: rect.x0 + tx, y0: rect.y0 + ty, width: 1, height: 1 };
                    let (alone, s) = render_tile(&scene, 0, one, &settings);
                    alone_primary += s.primary;
                    let grouped = px[(ty * rect.width + tx) as usize];
                    assert_eq!(
                        grouped.map(f32::to_bits),
                        alone[0].map(f32::to_bits),
                        "{name}, {samples} spp, pixel ({}, {}): {grouped:?} grouped, {:?} alone",
                        one.x0,
                        one.y0,
                        alone[0]
                    );
                }
            }
            assert_eq!(alone_primary, stats.primary, "{name}: the same rays either way");
        }
    }
}

/// Horizons let environment shadow rays above them skip their walk (`geometry::Horizons`, from
/// `render::HORIZON_SAMPLES` samples a pixel): the walk would have found them unblocked, so
/// the image is the same bits with and without them. torus_sky.xml's torus under its sky, a
/// region on the torus at the samples that turn them on.
#[test]
fn horizons_do_not_change_the_image() {
    let path = scenes_dir().join("torus_sky.xml");
    let with = load(&path);
    let without = load(&path);
    without.horizons.set(None).ok().expect("no horizons made yet");
    let settings =
        RenderSettings { samples: Some(tessera::render::HORIZON_SAMPLES), ..RenderSettings::default() };
    let rect = TileRect { x0: 150, y0: 60, width: 180, height: 120 };
    let (a, stats_a) = pool(2).install(|| render_tile(&with, 0, rect, &settings));
    let (b, stats_b) = pool(2).install(|| render_tile(&without, 0, rect, &settings));
    assert_eq!(stats_a.shadow, stats_b.shadow, "the same shadow rays, walked or not");
    let bounded = with.horizons().map_or(0, |h| h.bounded());
    assert!(bounded > 100, "the region's triangles had their horizons bounded ({bounded})");
    for (i, (pa, pb)) in a.iter().zip(&b).enumerate() {
        assert_eq!(pa.map(f32::to_bits), pb.map(f32::to_bits), "pixel {i} of {rect:?} differs");
    }
}
