//! What the ray benches share: the head mesh of the course corpus, its subdivision to a mesh
//! of about a million triangles, and the renderer's acceleration structure over one mesh.

use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use tessera::geometry::{Accel, Instance, MeshGeom, Shape};

/// head.ply from ../shared/scenes (17,674 triangles): positions and triangles.
pub fn load_head() -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let path = tessera_testkit::shared_scenes().join("xml/ply/head.ply");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let ply = tessera::ply::parse_ply(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let pos = ply.positions.iter().map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)).collect();
    (pos, ply.triangles)
}

/// 1-to-4 midpoint subdivision, `levels` times, with shared vertices (positions rounded to f32,
/// as the PLY stores them, so both sides trace the same triangles).
pub fn subdivide(pos: &[DVec3], tris: &[[u32; 3]], levels: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut pos: Vec<DVec3> = pos.to_vec();
    let mut tris = tris.to_vec();
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        let mut midpoint = |a: u32, b: u32, pos: &mut Vec<DVec3>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                let p = ((pos[a as usize] + pos[b as usize]) * 0.5).as_vec3().as_dvec3();
                pos.push(p);
                pos.len() as u32 - 1
            })
        };
        for &[a, b, c] in &tris {
            let ab = midpoint(a, b, &mut pos);
            let bc = midpoint(b, c, &mut pos);
            let ca = midpoint(c, a, &mut pos);
            next.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        tris = next;
    }
    (pos, tris)
}

/// `MeshGeom::new` + `Accel::new` for one untransformed mesh on a pool of `threads` threads,
/// and the seconds it took.
pub fn build(pos: &[DVec3], tris: &[[u32; 3]], threads: usize) -> (Accel, f64) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
    pool.install(|| {
        let t = Instant::now();
        let mesh = Arc::new(MeshGeom::new(pos.to_vec(), tris.to_vec(), None));
        let accel = Accel::new(
            vec![mesh],
            vec![Instance {
                shape: Shape::Mesh { mesh: 0, smooth: false },
                material: 0,
                transform: None,
                motion: None,
                textures: Default::default(),
            }],
        );
        (accel, t.elapsed().as_secs_f64())
    })
}

/// The box around `pos` (lower and upper corner), where the benches aim their cameras.
pub fn bounding_box(pos: &[DVec3]) -> (DVec3, DVec3) {
    pos.iter().fold((DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
}
