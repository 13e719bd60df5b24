//! Ray throughput and BVH build benchmark (single thread unless stated).
//!
//! cargo bench -p tessera-common --bench trace [-- --quick]
//!
//! On ../shared/scenes/xml/ply/head.ply (17,674 triangles) and on the same head subdivided
//! 1-to-4 three times (1.13M triangles) it prints:
//! - BVH build time (1 thread, and all threads),
//! - primary rays: 1920x1080 pinhole camera framing the mesh, closest hit,
//! - shadow rays: segments between random points of the bounding box, any hit,
//! - diffuse bounce: cosine-distributed rays from the primary hits, closest hit,
//!
//! one ray at a time, through the same top-level + mesh BVH path the renderer uses.
//!
//! Then whole-scene times with every core (load + build, render) for course scenes and for a
//! generated scene around the 1.13M-triangle head (written as a binary PLY to a temp dir).

use std::path::PathBuf;
use std::time::Instant;

use glam::DVec3;
use tessera::geometry::Accel;
use tessera::math::{Ray, orthonormal_pair};
use tessera::sampler::Sampler;

mod support;
use support::{bounding_box, build, load_head, subdivide};

struct Figures {
    primary: f64,
    shadow: f64,
    bounce: f64,
    hit_share: f64,
}

fn throughput(accel: &Accel, pos: &[DVec3], w: u32, h: u32) -> Figures {
    let (lo, hi) = bounding_box(pos);
    let (center, radius) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
    // Camera on +z framing the bounding sphere with a 40° vertical field of view.
    let fov = 40f64.to_radians();
    let eye = center + DVec3::Z * (radius / (fov / 2.0).sin());
    let (top, right) = ((fov / 2.0).tan(), (fov / 2.0).tan() * w as f64 / h as f64);
    let eps = 1e-6;

    let t = Instant::now();
    let mut hits = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let sx = ((x as f64 + 0.5) / w as f64 * 2.0 - 1.0) * right;
            let sy = (1.0 - (y as f64 + 0.5) / h as f64 * 2.0) * top;
            let ray = Ray::new(eye, DVec3::new(sx, sy, -1.0).normalize());
            if let Some(hit) = accel.intersect(&ray, eps, f64::INFINITY) {
                hits.push((
                    hit.point,
                    if hit.geo_normal.dot(ray.dir) < 0.0 { hit.geo_normal } else { -hit.geo_normal },
                ));
            }
        }
    }
    let primary = (w * h) as f64 / t.elapsed().as_secs_f64() / 1e6;
    let hit_share = hits.len() as f64 / (w * h) as f64;

    let n_shadow = (w * h) as usize;
    let mut segs = Vec::with_capacity(n_shadow);
    for i in 0..n_shadow {
        let mut r = Sampler::new(1, i as u32, 0, 0);
        let mut pt = || lo + (hi - lo) * DVec3::new(r.next_1d(), r.next_1d(), r.next_1d());
        let (a, b) = (pt(), pt());
        segs.push((a, b));
    }
    let t = Instant::now();
    let mut blocked = 0usize;
    for (a, b) in &segs {
        let d = *b - *a;
        let len = d.length();
        if accel.occluded(&Ray::new(*a, d / len), eps, len) {
            blocked += 1;
        }
    }
    let shadow = n_shadow as f64 / t.elapsed().as_secs_f64() / 1e6;
    std::hint::black_box(blocked);

    let mut dirs = Vec::with_capacity(hits.len());
    for (i, (p, n)) in hits.iter().enumerate() {
        let mut r = Sampler::new(2, i as u32, 0, 0);
        let (u, v) = orthonormal_pair(*n);
        let (r1, r2) = r.next_2d();
        let (s, phi) = (r1.sqrt(), 2.0 * std::f64::consts::PI * r2);
        let dir = (u * (s * phi.cos()) + v * (s * phi.sin()) + *n * (1.0 - r1).sqrt()).normalize();
        dirs.push(Ray::new(*p + *n * 1e-4 * radius, dir));
    }
    let t = Instant::now();
    let mut found = 0usize;
    for ray in &dirs {
        if accel.intersect(ray, eps, f64::INFINITY).is_some() {
            found += 1;
        }
    }
    let bounce = dirs.len() as f64 / t.elapsed().as_secs_f64() / 1e6;
    std::hint::black_box(found);
    Figures { primary, shadow, bounce, hit_share }
}

struct SceneTimes {
    triangles: usize,
    load: f64,
    render: f64,
    /// Camera samples (pixels x samples per pixel) over all cameras.
    samples: u64,
    rays: u64,
}

/// Load + build and render time of every camera of a scene file, with all threads.
fn whole_scene(path: &std::path::Path) -> Result<SceneTimes, String> {
    let t = Instant::now();
    let scene = tessera::scene::load::load_scene_file(path).map_err(|e| e.to_string())?;
    let load = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let (mut samples, mut rays) = (0u64, 0u64);
    for (i, cam) in scene.cameras.iter().enumerate() {
        let settings = tessera::render::RenderSettings::default();
        let (_, stats) = tessera::render::render_camera(&scene, i, 32, &settings, &|_, _| {});
        samples += cam.width as u64 * cam.height as u64 * cam.num_samples as u64;
        rays += stats.total();
    }
    Ok(SceneTimes {
        triangles: scene.stats.triangles,
        load,
        render: t.elapsed().as_secs_f64(),
        samples,
        rays,
    })
}

/// A scene file around `tris`: the mesh, a floor-less view from +z, two point lights.
fn big_head_scene(pos: &[DVec3], tris: &[[u32; 3]]) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("tessera-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mesh = tessera::ply::PlyMesh {
        positions: pos.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect(),
        triangles: tris.to_vec(),
        ..Default::default()
    };
    std::fs::write(dir.join("head_1m.ply"), tessera::ply::write_ply_binary_le(&mesh)).expect("write ply");
    let xml = r#"<Scene>
  <MaxRecursionDepth>2</MaxRecursionDepth>
  <Cameras><Camera id="1" type="lookAt"><Position>0 -0.1 1.2</Position><GazePoint>0 -0.1 0</GazePoint>
    <Up>0 1 0</Up><FovY>30</FovY><NearDistance>1</NearDistance><ImageResolution>800 800</ImageResolution>
    <ImageName>head_1m.png</ImageName></Camera></Cameras>
  <Lights><AmbientLight>20 20 20</AmbientLight>
    <PointLight id="1"><Position>1 1 2</Position><Intensity>600 600 600</Intensity></PointLight>
    <PointLight id="2"><Position>-1 0 1</Position><Intensity>200 200 250</Intensity></PointLight></Lights>
  <Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance><DiffuseReflectance>0.8 0.7 0.6</DiffuseReflectance>
    <SpecularReflectance>0.5 0.5 0.5</SpecularReflectance><PhongExponent>40</PhongExponent></Material></Materials>
  <Objects><Mesh id="1" shadingMode="smooth"><Material>1</Material><Faces plyFile="head_1m.ply"/></Mesh></Objects>
</Scene>"#;
    let path = dir.join("head_1m.xml");
    std::fs::write(&path, xml).expect("write xml");
    path
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let (w, h) = if quick { (480, 270) } else { (1920, 1080) };
    let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let (pos, tris) = load_head();
    let (pos1m, tris1m) = subdivide(&pos, &tris, 3);
    println!("tessera trace benchmark: {w}x{h} primary rays, one ray at a time, 1 thread");
    println!(
        "| mesh | triangles | build 1 thr s | build {threads} thr s | primary Mrays/s | shadow Mrays/s | diffuse bounce Mrays/s | primary hit % |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for (name, p, t) in [("head.ply", &pos, &tris), ("head.ply subdivided x3", &pos1m, &tris1m)] {
        let (_, build1) = build(p, t, 1);
        let (accel, build_n) = build(p, t, threads);
        let f = throughput(&accel, p, w, h);
        println!(
            "| {name} | {} | {build1:.3} | {build_n:.3} | {:.2} | {:.2} | {:.2} | {:.1} |",
            t.len(),
            f.primary,
            f.shadow,
            f.bounce,
            f.hit_share * 100.0
        );
    }

    println!();
    println!("whole scenes, {threads} threads (load+build includes reading PLY files and building BVHs)");
    println!("| scene | triangles | load+build s | render s | total s | Msamples/s | Mrays/s |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    let xml = tessera_testkit::shared_scenes().join("xml");
    let big = big_head_scene(&pos1m, &tris1m);
    let mut names =
        vec!["bunny", "scienceTree", "cornellbox", "metal_glass_plates_hw2", "ton_Roosendaal_smooth"];
    // Homework 3 (distribution ray tracing): many samples per pixel.
    names.extend(["cornellbox_area", "spheres_dof", "metal_glass_plates"]);
    if !quick {
        names.push("cornellbox_boxes_dynamic"); // 900 spp, about a minute
    }
    let mut scenes: Vec<(String, PathBuf)> =
        names.iter().map(|s| (s.to_string(), xml.join(format!("{s}.xml")))).collect();
    scenes.push(("head 1.13M triangles (generated)".into(), big.clone()));
    for (name, path) in scenes {
        match whole_scene(&path) {
            Ok(t) => println!(
                "| {name} | {} | {:.3} | {:.3} | {:.3} | {:.2} | {:.2} |",
                t.triangles,
                t.load,
                t.render,
                t.load + t.render,
                t.samples as f64 / t.render / 1e6,
                t.rays as f64 / t.render / 1e6
            ),
            Err(e) => println!("| {name} | error: {e} | | | |"),
        }
    }
    if let Some(dir) = big.parent() {
        let _ = std::fs::remove_dir_all(dir);
    }
}
