//! Single-ray queries against Embree 4 on the same mesh and the same rays, in one run (issue #18).
//!
//! taskset -c 0 cargo bench -p tessera-common --bench rays [-- --quick] [--rounds N]
//!
//! For head.ply (17,674 triangles) and for the same head subdivided 1-to-4 three times (1.13M
//! triangles, written with `ply::write_ply_binary_le`), it generates three ray sets once:
//! - primary: a 1920x1080 pinhole camera, the anchor's (`../shared/bench/head_primary.xml`)
//!   (closest hit),
//! - shadow: from each primary hit point (offset along the normal facing the camera) to a point
//!   light above the front right of the mesh (any hit, tmax = the distance to the light),
//! - diffuse bounce: a cosine-distributed direction around that normal from the same offset
//!   origin (closest hit),
//!
//! writes them as f32 records (origin, direction, tmax; tmin 0) and the mesh as PLY to a temp
//! directory, and starts `embree_rays.py` (Python `embreex`, from `$TESSERA_ANCHORS_PY` or
//! `~/.cache/anchors/bin/python`) on them. Then it alternates: Tessera traces a set, Embree
//! traces the same set, for every set and `--rounds` times; each figure is the median over the
//! rounds and every ratio compares figures of the same run. Tessera's side is `Accel::intersect`
//! (the renderer's closest-hit query, world-space `SurfaceHit` included) and `Accel::occluded`,
//! one ray per call, one thread; Embree's is rtcIntersect1 / rtcOccluded1, one ray per call.
//! BVH build: `MeshGeom::new` + `Accel::new` on one thread vs a new Embree scene + commit.
//! Before timing, both sides' closest-hit distances are compared (share of rays that agree).
//!
//! Run it under `taskset -c 0`: Embree's build then uses one core like Tessera's.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::Instant;

use glam::DVec3;
use tessera::geometry::Accel;
use tessera::math::{Ray, orthonormal_pair};
use tessera::sampler::Sampler;

mod support;
use support::{bounding_box, build, load_head, subdivide};

/// One ray as both sides read it: f32 origin, direction, tmax (tmin is 0).
#[derive(Clone, Copy)]
struct FRay {
    o: [f32; 3],
    d: [f32; 3],
    tmax: f32,
}

impl FRay {
    fn new(o: DVec3, d: DVec3, tmax: f64) -> Self {
        FRay { o: o.as_vec3().to_array(), d: d.as_vec3().to_array(), tmax: tmax as f32 }
    }
    fn ray(&self) -> (Ray, f64) {
        let v = |a: [f32; 3]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        (Ray::new(v(self.o), v(self.d)), if self.tmax.is_finite() { self.tmax as f64 } else { f64::INFINITY })
    }
}

struct RaySet {
    name: &'static str,
    any_hit: bool,
    rays: Vec<FRay>,
}

fn make_rays(accel: &Accel, pos: &[DVec3], w: u32, h: u32) -> Vec<RaySet> {
    let (lo, hi) = bounding_box(pos);
    let (center, radius) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
    // The anchor's camera (../shared/bench/head_primary.xml): lookAt, up +y, FovY 30.
    let eye = DVec3::new(0.322839, 0.0534825, 0.504299);
    let gaze = (DVec3::new(-0.140808, -0.162727, -0.35493) - eye).normalize();
    let cu = gaze.cross(DVec3::Y).normalize();
    let cv = cu.cross(gaze);
    let fov = 30f64.to_radians();
    let (top, right) = ((fov / 2.0).tan(), (fov / 2.0).tan() * w as f64 / h as f64);
    let light = center + DVec3::new(1.5, 2.0, 2.5) * radius;
    let mut primary = Vec::with_capacity((w * h) as usize);
    let (mut shadow, mut bounce) = (Vec::new(), Vec::new());
    for y in 0..h {
        for x in 0..w {
            let sx = ((x as f64 + 0.5) / w as f64 * 2.0 - 1.0) * right;
            let sy = (1.0 - (y as f64 + 0.5) / h as f64 * 2.0) * top;
            let fr = FRay::new(eye, (cu * sx + cv * sy + gaze).normalize(), f64::INFINITY);
            primary.push(fr);
            let (ray, _) = fr.ray();
            let Some(hit) = accel.intersect(&ray, 0.0, f64::INFINITY) else { continue };
            let n = if hit.geo_normal.dot(ray.dir) < 0.0 { hit.geo_normal } else { -hit.geo_normal };
            let o = hit.point + n * 1e-4 * radius;
            let to_light = light - o;
            let dist = to_light.length();
            shadow.push(FRay::new(o, to_light / dist, dist));
            let mut r = Sampler::new(2, x, y, 0);
            let (u, v) = orthonormal_pair(n);
            let (r1, r2) = r.next_2d();
            let (s, phi) = (r1.sqrt(), 2.0 * std::f64::consts::PI * r2);
            let dir = (u * (s * phi.cos()) + v * (s * phi.sin()) + n * (1.0 - r1).sqrt()).normalize();
            bounce.push(FRay::new(o, dir, f64::INFINITY));
        }
    }
    vec![
        RaySet { name: "primary", any_hit: false, rays: primary },
        RaySet { name: "shadow", any_hit: true, rays: shadow },
        RaySet { name: "diffuse", any_hit: false, rays: bounce },
    ]
}

fn write_rays(path: &Path, rays: &[FRay]) {
    let mut out = Vec::with_capacity(rays.len() * 28);
    for r in rays {
        for c in r.o.iter().chain(&r.d).chain(std::iter::once(&r.tmax)) {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    std::fs::write(path, out).expect("write rays");
}

/// Tessera's side: seconds for one pass over the set, and the number of hits.
fn trace(accel: &Accel, rays: &[(Ray, f64)], any_hit: bool) -> (f64, usize) {
    let t = Instant::now();
    let mut hits = 0usize;
    if any_hit {
        for (ray, tmax) in rays {
            hits += accel.occluded(ray, 0.0, *tmax) as usize;
        }
    } else {
        for (ray, tmax) in rays {
            hits += accel.intersect(ray, 0.0, *tmax).is_some() as usize;
        }
    }
    (t.elapsed().as_secs_f64(), std::hint::black_box(hits))
}

struct Embree {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

impl Embree {
    fn start(mesh: &Path, dir: &Path) -> Embree {
        let python = tessera_testkit::anchor_python();
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/embree_rays.py");
        let mut child = Command::new(&python)
            .arg(&script)
            .arg(mesh)
            .arg(dir)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| {
                panic!(
                    "cannot start {} (python3 -m venv ~/.cache/anchors && ~/.cache/anchors/bin/pip install numpy embreex): {e}",
                    python.display()
                )
            });
        let stdin = child.stdin.take().expect("stdin");
        let stdout = BufReader::new(child.stdout.take().expect("stdout"));
        Embree { child, stdin, stdout }
    }

    fn ask(&mut self, cmd: &str) -> serde_json::Value {
        writeln!(self.stdin, "{cmd}").expect("write to embree_rays.py");
        self.stdin.flush().expect("flush");
        let mut line = String::new();
        self.stdout.read_line(&mut line).expect("read from embree_rays.py");
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("embree_rays.py said {line:?}: {e}"))
    }
}

impl Drop for Embree {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "quit");
        let _ = self.stdin.flush();
        let _ = self.child.wait();
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Share of rays on which both sides agree: both miss, or both hit at distances within 1e-3
/// relative (a different triangle at the same distance counts as agreeing).
fn agreement(accel: &Accel, rays: &[(Ray, f64)], embree_t: &Path) -> f64 {
    let bytes = std::fs::read(embree_t).expect("read embree distances");
    let et: Vec<f32> = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    assert_eq!(et.len(), rays.len());
    let mut same = 0usize;
    for ((ray, tmax), &e) in rays.iter().zip(&et) {
        let ours = accel.intersect(ray, 0.0, *tmax).map(|h| h.t);
        same += match ours {
            None => !e.is_finite(),
            Some(t) => e.is_finite() && (t - e as f64).abs() <= 1e-3 * t.max(1e-6),
        } as usize;
    }
    same as f64 / rays.len() as f64
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let rounds: usize = args
        .iter()
        .position(|a| a == "--rounds")
        .and_then(|i| args.get(i + 1))
        .and_then(|s| s.parse().ok())
        .unwrap_or(if quick { 3 } else { 5 });
    let (w, h) = if quick { (640, 360) } else { (1920, 1080) };
    let (pos, tris) = load_head();
    let (pos1m, tris1m) = subdivide(&pos, &tris, 3);
    let dir = std::env::temp_dir().join(format!("tessera-rays-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");

    println!("machine: {}", tessera_testkit::cpu_description());
    println!(
        "tessera vs Embree 4 (embreex), single rays, one thread, {w}x{h} camera, median of {rounds} rounds"
    );
    println!(
        "| mesh | triangles | query | Tessera Mrays/s | Embree Mrays/s | ratio | hits T / E | agree % |"
    );
    println!("|---|---:|---|---:|---:|---:|---:|---:|");
    let mut builds = Vec::new();
    for (name, p, t) in [("head.ply", &pos, &tris), ("head x3 (1.13M)", &pos1m, &tris1m)] {
        let mesh_path = dir.join(format!("{}.ply", if t.len() > 100_000 { "big" } else { "head" }));
        let ply = tessera::ply::PlyMesh {
            positions: p.iter().map(|v| v.as_vec3().to_array()).collect(),
            triangles: t.to_vec(),
            ..Default::default()
        };
        std::fs::write(&mesh_path, tessera::ply::write_ply_binary_le(&ply)).expect("write ply");
        // Both sides trace the f32 vertices the PLY holds.
        let p32: Vec<DVec3> = ply.positions.iter().map(|v| glam::Vec3::from_array(*v).as_dvec3()).collect();
        let (accel, _) = build(&p32, t, 1);
        let sets = make_rays(&accel, &p32, w, h);
        let set_dir = dir.join(if t.len() > 100_000 { "big" } else { "head" });
        std::fs::create_dir_all(&set_dir).expect("ray dir");
        for s in &sets {
            write_rays(&set_dir.join(format!("{}.rays", s.name)), &s.rays);
        }
        let mut embree = Embree::start(&mesh_path, &set_dir);

        let (mut tb, mut eb) = (Vec::new(), Vec::new());
        for _ in 0..rounds.min(3) {
            tb.push(build(&p32, t, 1).1);
            eb.push(embree.ask("build")["build_s"].as_f64().expect("build_s"));
        }
        builds.push((name, t.len(), median(tb), median(eb)));

        let rays: Vec<Vec<(Ray, f64)>> =
            sets.iter().map(|s| s.rays.iter().map(FRay::ray).collect()).collect();
        let mut agree = Vec::new();
        for (s, r) in sets.iter().zip(&rays) {
            if s.any_hit {
                agree.push(None);
            } else {
                let v = embree.ask(&format!("distances {}", s.name));
                agree.push(Some(agreement(&accel, r, Path::new(v["written"].as_str().expect("path")))));
            }
        }
        let mut times = vec![(Vec::new(), Vec::new(), 0usize, 0usize); sets.len()];
        for _ in 0..rounds {
            for (i, (s, r)) in sets.iter().zip(&rays).enumerate() {
                let (ts, th) = trace(&accel, r, s.any_hit);
                let q = if s.any_hit { "OCCLUDED" } else { "INTERSECT" };
                let v = embree.ask(&format!("trace {} {q}", s.name));
                times[i].0.push(ts);
                times[i].1.push(v["s"].as_f64().expect("s"));
                times[i].2 = th;
                times[i].3 = v["hits"].as_u64().expect("hits") as usize;
            }
        }
        for (i, s) in sets.iter().enumerate() {
            let n = s.rays.len() as f64;
            let tm = n / median(times[i].0.clone()) / 1e6;
            let em = n / median(times[i].1.clone()) / 1e6;
            println!(
                "| {name} | {} | {} ({}) | {tm:.2} | {em:.2} | {:.2} | {} / {} | {} |",
                t.len(),
                s.name,
                if s.any_hit { "any hit" } else { "closest" },
                tm / em,
                times[i].2,
                times[i].3,
                agree[i].map_or("-".to_string(), |a| format!("{:.3}", a * 100.0)),
            );
        }
    }
    println!();
    println!("| mesh | triangles | Tessera build s | Embree build s | Tessera / Embree |");
    println!("|---|---:|---:|---:|---:|");
    for (name, n, tb, eb) in builds {
        println!("| {name} | {n} | {tb:.4} | {eb:.4} | {:.2} |", tb / eb);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
