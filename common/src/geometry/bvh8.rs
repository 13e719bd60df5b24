//! An 8-wide BVH over triangles for ray queries on the CPU (single rays and packets of up to
//! eight), built from obvhs's binary PLOC tree.
//!
//! obvhs's CWBVH is a GPU layout: quantised child boxes (decoded per node), one triangle at a
//! time in the leaves, and the same traversal for closest and any hit. Here the node holds its
//! eight child boxes as full `f32` planes (structure of arrays, one AVX2 register per plane),
//! leaves hold triangles in packets of four with precomputed edges (a single ray tests a leaf's
//! two packets in one AVX Möller–Trumbore pass), closest-hit traversal visits children nearest
//! first and skips popped nodes beyond the closest hit so far, and the any-hit query stops at
//! the first hit in any order.
//!
//! The results are those of a plain `f32` Möller–Trumbore test (two-sided) of every triangle, so
//! which surface a ray finds does not depend on the BVH's shape, ties included: box tests are
//! conservative, so every triangle at the hit's distance is met, and the lowest id wins.
//!
//! Coherent rays (a pixel's camera rays) can also walk the tree together as a [`Packet8`]: one
//! traversal for up to eight rays, every box and triangle test done for all lanes at once with
//! the single-ray operations, so each lane's result is its own query's.
//!
//! This file builds the tree and walks it; the node and leaf layouts and the eight-wide box and
//! triangle tests each step of a walk makes are in [`kernels`].

use std::mem::MaybeUninit;

use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::{Bvh2, reinsertion::ReinsertionOptimizer};
use obvhs::ploc::{PlocBuilder, PlocSearchDistance, SortPrecision};

mod kernels;
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
mod wide;

use kernels::{
    COUNT_SHIFT, FIRST_MASK, LEAF, Node, SLACK, Tri4, node_hits, safe_inv, tri4_closest, tri8_any,
    tri8_closest,
};
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
use kernels::{Intervals, below, filled_slots, hmax8, hmin8, insert_by_entry, lane_mask, mt8};
pub use kernels::{Packet8, Ray8};

/// Whether [`Bvh8::intersect_packet_pair`] walks its two packets at once (sixteen lanes an
/// instruction, on a host with AVX-512) rather than one after the other: callers with two
/// packets' rays at hand pair them only then.
pub fn pair_walks_at_once() -> bool {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
    return wide_walks();
    #[allow(unreachable_code)]
    false
}

/// Whether this process walks pairs of packets sixteen lanes at a time: the processor has
/// AVX-512 (F and DQ, [`wide::detected`]) and [`SIMD_VARIABLE`] does not ask for eight lanes.
/// Decided once a process.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
fn wide_walks() -> bool {
    static WIDE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *WIDE.get_or_init(|| {
        let narrow = narrow_walks_asked(std::env::var_os(SIMD_VARIABLE).as_deref()).unwrap_or(false);
        !narrow && wide::detected()
    })
}

/// The environment variable that keeps the world-tree walks eight lanes wide on an AVX-512
/// host (to time one width against the other with one build).
pub const SIMD_VARIABLE: &str = "TESSERA_SIMD";

/// What a value of [`SIMD_VARIABLE`] asks for: `Ok(true)` for eight-lane walks (`avx2`, in any
/// case), `Ok(false)` when it is unset or empty (the widest walk the processor runs), and an
/// error that names the variable and its one accepted value for anything else (which the
/// walks then ignore).
pub fn narrow_walks_asked(value: Option<&std::ffi::OsStr>) -> Result<bool, String> {
    let Some(value) = value else { return Ok(false) };
    match value.to_str() {
        Some("") => Ok(false),
        Some(v) if v.eq_ignore_ascii_case("avx2") => Ok(true),
        _ => Err(format!(
            "{SIMD_VARIABLE}={} is not understood and is ignored: its one value is 'avx2' (keep \
             the world-tree walks eight lanes wide on an AVX-512 processor); unset it to use the \
             widest walk the processor runs",
            value.to_string_lossy()
        )),
    }
}

/// Subtrees of at most this many triangles become one leaf.
/// (Measured with the rays bench: 8, two packets, traces faster than 2, 4 or 6 on both meshes;
/// with two packets tested per pass, 12 and 16 take 3 % and 5 % more instructions on
/// head_env_light.)
const LEAF_MAX: u32 = 8;
/// Stack entries on the machine stack; deeper trees use a heap stack.
const STACK: usize = 256;

/// The BVH: nodes (root first) and triangle packets.
#[derive(Default)]
pub struct Bvh8 {
    nodes: Vec<Node>,
    tris: Vec<Tri4>,
    /// Deepest path from the root, in nodes (sizes the traversal stack).
    depth: usize,
    /// The root's box, the union of its children's: minima (x, y, z), then maxima.
    bounds: [f32; 6],
}

/// One triangle: vertex 0 and its two edges.
pub type Tri = [Vec3A; 3];

struct Builder<'a> {
    bvh2: &'a Bvh2,
    tris: &'a [Tri],
    ids: &'a [u32],
    /// Triangles under each BVH2 node.
    count: Vec<u32>,
    out: Bvh8,
}

impl Bvh8 {
    /// The bytes its nodes and triangle packets take on the heap (for memory-bounded caches).
    pub fn heap_bytes(&self) -> usize {
        self.nodes.capacity() * std::mem::size_of::<Node>()
            + self.tris.capacity() * std::mem::size_of::<Tri4>()
    }

    /// Builds over `tris` (vertex 0, edge 1, edge 2) with boxes `aabbs`; `ids[i]` is what a hit
    /// on `tris[i]` reports. `aabbs` must be finite (see `mesh::is_sane`).
    pub fn build(tris: &[Tri], aabbs: &[Aabb], ids: &[u32]) -> Bvh8 {
        if tris.is_empty() {
            return Bvh8::default();
        }
        // obvhs's `medium_build` PLOC and reinsertion parameters, without its leaf collapse
        // (leaves are ours): on the 1.13M-triangle head it traces diffuse rays about 8 %
        // faster than `fast_build`'s and still builds in about 0.6x Embree's time.
        let mut bvh2 = PlocBuilder::with_capacity(aabbs.len()).build(
            PlocSearchDistance::Medium,
            aabbs,
            (0..aabbs.len() as u32).collect(),
            SortPrecision::U64,
            3,
        );
        ReinsertionOptimizer::default().run(&mut bvh2, 0.05, None);
        let mut count = vec![0u32; bvh2.nodes.len()];
        fill_counts(&bvh2, 0, &mut count);
        let mut b = Builder { bvh2: &bvh2, tris, ids, count, out: Bvh8::default() };
        b.out.nodes.reserve(tris.len() / 4 + 1);
        b.out.tris.reserve(tris.len() / 2 + 1);
        b.node(0, 1);
        let root = &b.out.nodes[0].b;
        for a in 0..3 {
            b.out.bounds[a] = root[a].iter().copied().fold(f32::INFINITY, f32::min);
            b.out.bounds[a + 3] = root[a + 3].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        }
        b.out
    }

    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The root's box: minima (x, y, z), then maxima.
    pub(super) fn bounds(&self) -> [f32; 6] {
        self.bounds
    }

    /// Where each id's triangle is kept (`slot / 4` its packet, `slot % 4` its lane), indexed
    /// by id; `u32::MAX` for ids the tree does not hold. `None` when an id exceeds `max_id`.
    pub(super) fn triangle_slots(&self, max_id: u32) -> Option<Vec<u32>> {
        let mut top = 0u32;
        for p in &self.tris {
            for &id in &p.id {
                if id != u32::MAX {
                    if id > max_id {
                        return None;
                    }
                    top = top.max(id + 1);
                }
            }
        }
        let mut slots = vec![u32::MAX; top as usize];
        for (k, p) in self.tris.iter().enumerate() {
            for (lane, &id) in p.id.iter().enumerate() {
                if id != u32::MAX {
                    slots[id as usize] = (k * 4 + lane) as u32;
                }
            }
        }
        Some(slots)
    }

    /// The triangle at `slot` (see [`Self::triangle_slots`]) as the walks test it: vertex 0 and
    /// its two edges, in the tree's own `f32` values.
    #[inline(always)]
    pub(super) fn triangle(&self, slot: u32) -> [[f32; 3]; 3] {
        let p = &self.tris[slot as usize / 4];
        let l = slot as usize % 4;
        [
            [p.v0[0][l], p.v0[1][l], p.v0[2][l]],
            [p.e1[0][l], p.e1[1][l], p.e1[2][l]],
            [p.e2[0][l], p.e2[1][l], p.e2[2][l]],
        ]
    }

    /// The root's reference, for a walk of a query's own ([`Self::children`],
    /// [`Self::leaf_triangles`]); `None` when the tree is empty.
    pub(super) fn root(&self) -> Option<u32> {
        (!self.nodes.is_empty()).then_some(0)
    }

    /// Each child of node reference `cur` (not a leaf: see [`Self::is_leaf`]) with its box
    /// (minima, then maxima) and its slot's number among all nodes' (`8·node + slot`, below
    /// [`Self::slot_count`]).
    pub(super) fn children(&self, cur: u32, mut f: impl FnMut([f32; 3], [f32; 3], u32, usize)) {
        let node = &self.nodes[cur as usize];
        for slot in 0..8 {
            let lo = [node.b[0][slot], node.b[1][slot], node.b[2][slot]];
            let hi = [node.b[3][slot], node.b[4][slot], node.b[5][slot]];
            // An empty slot's minima are above its maxima.
            if lo[0] <= hi[0] {
                f(lo, hi, node.child[slot], cur as usize * 8 + slot);
            }
        }
    }

    /// How many child slots the nodes have in all.
    pub(super) fn slot_count(&self) -> usize {
        self.nodes.len() * 8
    }

    /// Every triangle under child reference `cur`, as [`Self::triangle`] gives it.
    pub(super) fn subtree_triangles(&self, cur: u32, f: &mut impl FnMut([[f32; 3]; 3])) {
        if Self::is_leaf(cur) {
            self.leaf_triangles(cur, f);
        } else {
            self.children(cur, |_, _, child, _| self.subtree_triangles(child, f));
        }
    }

    /// Whether child reference `cur` is a leaf.
    pub(super) fn is_leaf(cur: u32) -> bool {
        cur & LEAF != 0
    }

    /// Each triangle of leaf reference `cur` as [`Self::triangle`] gives it.
    pub(super) fn leaf_triangles(&self, cur: u32, mut f: impl FnMut([[f32; 3]; 3])) {
        let first = (cur & FIRST_MASK) as usize;
        let n = ((cur & !LEAF) >> COUNT_SHIFT) as usize;
        for k in first..first + n {
            for lane in 0..4 {
                if self.tris[k].id[lane] != u32::MAX {
                    f(self.triangle((k * 4 + lane) as u32));
                }
            }
        }
    }

    /// Closest hit with t in (ray.tmin, ray.tmax): (t, id).
    #[inline]
    pub fn intersect(&self, ray: &Ray8) -> Option<(f32, u32)> {
        if self.nodes.is_empty() || ray.has_nan() {
            return None;
        }
        let need = self.depth * 7 + 1;
        if need <= STACK {
            let mut stack = [const { MaybeUninit::<(u32, f32)>::uninit() }; STACK];
            self.closest(ray, &mut stack)
        } else {
            let mut stack = vec![MaybeUninit::<(u32, f32)>::uninit(); need];
            self.closest(ray, &mut stack)
        }
    }

    /// Whether anything is hit with t in (ray.tmin, ray.tmax).
    #[inline]
    pub fn occluded(&self, ray: &Ray8) -> bool {
        if self.nodes.is_empty() || ray.has_nan() {
            return false;
        }
        let need = self.depth * 7 + 1;
        if need <= STACK {
            let mut stack = [const { MaybeUninit::<u32>::uninit() }; STACK];
            self.any(ray, &mut stack)
        } else {
            let mut stack = vec![MaybeUninit::<u32>::uninit(); need];
            self.any(ray, &mut stack)
        }
    }

    /// Starts loading the first cache line of child reference `c` (a node's first planes, or a
    /// leaf's first triangle packet): a walk visits the children it pushes later, and on a mesh
    /// larger than the caches each visit would otherwise wait for memory.
    #[inline(always)]
    fn prefetch_child(&self, c: u32) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let ptr: *const i8 = if c & LEAF == 0 {
                self.nodes.as_ptr().wrapping_add(c as usize).cast()
            } else {
                self.tris.as_ptr().wrapping_add((c & FIRST_MASK) as usize).cast()
            };
            // SAFETY: a prefetch reads nothing into the program and cannot fault, whatever the
            // address (child references of a built tree are in bounds anyway).
            unsafe { _mm_prefetch::<_MM_HINT_T0>(ptr) };
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = c;
    }

    #[inline(always)]
    fn closest(&self, ray: &Ray8, stack: &mut [MaybeUninit<(u32, f32)>]) -> Option<(f32, u32)> {
        let mut tmax = ray.tmax;
        let mut found = u32::MAX;
        let mut sp = 0usize;
        let mut cur = 0u32;
        loop {
            if cur & LEAF == 0 {
                // SAFETY: a built tree's child references are in bounds (see `Builder::node`).
                let node = unsafe { self.nodes.get_unchecked(cur as usize) };
                let (mut mask, dist) = node_hits(node, ray, tmax);
                if mask != 0 {
                    if mask & (mask - 1) == 0 {
                        cur = node.child[mask.trailing_zeros() as usize];
                        continue;
                    }
                    // Exactly two children (a common case; not counted): push the farther,
                    // visit the nearer, with selects instead of the sort's branches. Equal
                    // distances go as the sort below sends them: the higher slot first.
                    let i = mask.trailing_zeros() as usize;
                    let rest = mask & (mask - 1);
                    if rest & (rest - 1) == 0 {
                        let j = rest.trailing_zeros() as usize;
                        let (a, b) = ((node.child[i], dist[i]), (node.child[j], dist[j]));
                        self.prefetch_child(a.0);
                        self.prefetch_child(b.0);
                        let (near, far) = if a.1 < b.1 { (a, b) } else { (b, a) };
                        stack[sp] = MaybeUninit::new(far);
                        sp += 1;
                        cur = near.0;
                        continue;
                    }
                    // More: push all but the nearest, farthest first.
                    let mut c = [(0u32, 0f32); 8];
                    let mut n = 0;
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        let e = (node.child[i], dist[i]);
                        self.prefetch_child(e.0);
                        // Insertion sort, descending distance.
                        let mut j = n;
                        while j > 0 && c[j - 1].1 < e.1 {
                            c[j] = c[j - 1];
                            j -= 1;
                        }
                        c[j] = e;
                        n += 1;
                    }
                    for e in &c[..n - 1] {
                        stack[sp] = MaybeUninit::new(*e);
                        sp += 1;
                    }
                    cur = c[n - 1].0;
                    continue;
                }
            } else {
                let first = (cur & FIRST_MASK) as usize;
                let n = ((cur & !LEAF) >> COUNT_SHIFT) as usize;
                // Two packets per test; an odd last one alone.
                for pair in self.tris[first..first + n].chunks(2) {
                    let hit = match pair {
                        [a, b] => {
                            tri8_closest(a, b, ray, tmax, found).map(|(t, l)| (t, [a, b][l / 4].id[l % 4]))
                        }
                        [a] => tri4_closest(a, ray, tmax, found).map(|(t, l)| (t, a.id[l])),
                        _ => None,
                    };
                    if let Some((t, id)) = hit {
                        tmax = t;
                        found = id;
                    }
                }
            }
            // Pop the next node nearer than the closest hit.
            loop {
                if sp == 0 {
                    return (found != u32::MAX).then_some((tmax, found));
                }
                sp -= 1;
                // SAFETY: entries below `sp` were written by the pushes above.
                let (c, d) = unsafe { stack[sp].assume_init() };
                // With the box test's slack: a box's entry can round past a hit on its own
                // surface, and a triangle there at the same distance may still win on its id.
                if d <= tmax * SLACK {
                    cur = c;
                    break;
                }
            }
        }
    }

    #[inline(always)]
    fn any(&self, ray: &Ray8, stack: &mut [MaybeUninit<u32>]) -> bool {
        let mut sp = 0usize;
        let mut cur = 0u32;
        loop {
            if cur & LEAF == 0 {
                // SAFETY: a built tree's child references are in bounds (see `Builder::node`).
                let node = unsafe { self.nodes.get_unchecked(cur as usize) };
                let (mut mask, _) = node_hits(node, ray, ray.tmax);
                if mask != 0 {
                    let i = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    cur = node.child[i];
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        stack[sp] = MaybeUninit::new(node.child[i]);
                        sp += 1;
                    }
                    continue;
                }
            } else {
                let first = (cur & FIRST_MASK) as usize;
                let n = ((cur & !LEAF) >> COUNT_SHIFT) as usize;
                // Two packets per test; an odd last one is tested twice over.
                for pair in self.tris[first..first + n].chunks(2) {
                    if tri8_any(&pair[0], &pair[pair.len() - 1], ray, ray.tmax) {
                        return true;
                    }
                }
            }
            if sp == 0 {
                return false;
            }
            sp -= 1;
            // SAFETY: entries below `sp` were written by the pushes above.
            cur = unsafe { stack[sp].assume_init() };
        }
    }
}

/// Up to eight rays in `f32`, side by side (unused lanes repeat the first ray): the one
/// conversion from `f64` that a group's packet walk ([`Packet8`]), box tests ([`BoxRays8`]) and
/// single-ray queries (`obvhs::ray::Ray`s) are all made from. obvhs's inverse directions, which
/// only the box tests and obvhs's rays read, are computed for all lanes at once when asked for
/// ([`Self::compute_inverse`]): a scene whose geometry is all in the world tree never needs them.
pub struct Lanes8 {
    pub o: [[f32; 8]; 3],
    pub d: [[f32; 8]; 3],
    /// `obvhs::ray::safe_inverse` of each direction component, once computed.
    inv: Option<[[f32; 8]; 3]>,
    /// How many lanes hold a ray.
    pub len: usize,
}

impl Lanes8 {
    /// `len` rays given in `f64` by axis, then lane (origins `o`, directions `d`), in `f32` (an
    /// axis of eight lanes at a time).
    #[inline(always)]
    pub fn new(o: &[[f64; 8]; 3], d: &[[f64; 8]; 3], len: usize) -> Self {
        assert!((1..=8).contains(&len), "one to eight rays");
        let mut l = Lanes8 { o: [[0.0; 8]; 3], d: [[0.0; 8]; 3], inv: None, len };
        for a in 0..3 {
            for lane in 0..8 {
                l.o[a][lane] = o[a][lane] as f32;
                l.d[a][lane] = d[a][lane] as f32;
            }
        }
        l
    }

    /// Computes the inverse directions (once).
    #[inline(always)]
    pub fn compute_inverse(&mut self) {
        if self.inv.is_some() {
            return;
        }
        // obvhs's `safe_inverse`, both sides computed and one kept (the compiler vectorises
        // the loop): the same bits as its branch.
        let mut inv = [[0.0; 8]; 3];
        for (row, d) in inv.iter_mut().zip(&self.d) {
            for (v, &x) in row.iter_mut().zip(d) {
                let small = if x.is_nan() { f32::NAN } else { 1.0f32.copysign(x) } / f32::EPSILON;
                *v = if x.abs() <= f32::EPSILON { small } else { 1.0 / x };
            }
        }
        self.inv = Some(inv);
    }

    /// The inverse directions; [`Self::compute_inverse`] must have run.
    #[inline(always)]
    fn inv(&self) -> &[[f32; 8]; 3] {
        self.inv.as_ref().expect("Lanes8::compute_inverse runs before the inverses are read")
    }

    /// Lane `lane` as one obvhs ray with bounds (tmin, tmax): what `obvhs::ray::Ray::new` makes
    /// of the same values. [`Self::compute_inverse`] must have run.
    #[inline]
    pub fn ray(&self, lane: usize, tmin: f32, tmax: f32) -> obvhs::ray::Ray {
        let v = |x: &[[f32; 8]; 3]| Vec3A::new(x[0][lane], x[1][lane], x[2][lane]);
        obvhs::ray::Ray {
            origin: v(&self.o),
            direction: v(&self.d),
            inv_direction: v(self.inv()),
            tmin,
            tmax,
        }
    }
}

impl Packet8 {
    /// The packet of `rays` (origin, direction; at most eight), all with `tmin`.
    pub fn new(rays: &[(Vec3A, Vec3A)], tmin: f32) -> Self {
        assert!(!rays.is_empty() && rays.len() <= 8, "a packet holds one to eight rays");
        let (mut o, mut d) = ([[0.0; 8]; 3], [[0.0; 8]; 3]);
        // Unused lanes repeat the first ray (finite values; their results are never read).
        for lane in 0..8 {
            let (ro, rd) = rays.get(lane).unwrap_or(&rays[0]);
            for a in 0..3 {
                o[a][lane] = ro[a];
                d[a][lane] = rd[a];
            }
        }
        Self::from_axes(o, d, rays.len(), tmin)
    }

    /// Only the lanes of `mask` among those in use take part (the others' results are not
    /// written).
    #[inline]
    pub fn set_active(&mut self, mask: u32) {
        self.active &= mask;
    }

    /// The packet of `lanes`, all with `tmin`: what [`Self::new`] makes of the same rays.
    /// (Always inlined: a caller that makes two, for a pair walk, got a call to each.)
    #[inline(always)]
    pub fn from_lanes(lanes: &Lanes8, tmin: f32) -> Self {
        Self::from_axes(lanes.o, lanes.d, lanes.len, tmin)
    }

    /// The packet of origins `o` and directions `d` (by axis, then lane; `len` lanes in use).
    #[inline(always)]
    fn from_axes(o: [[f32; 8]; 3], d: [[f32; 8]; 3], len: usize, tmin: f32) -> Self {
        let mut p = Packet8 {
            o,
            d,
            inv: [[0.0; 8]; 3],
            o_inv_near: [[0.0; 8]; 3],
            o_inv_far: [[0.0; 8]; 3],
            tmin: [tmin; 8],
            active: (1u32 << len) - 1,
        };
        // Ray8::new's operations, an axis of eight lanes at a time (the compiler vectorises
        // this loop).
        for a in 0..3 {
            for lane in 0..8 {
                p.inv[a][lane] = safe_inv(p.d[a][lane]);
                (p.o_inv_near[a][lane], p.o_inv_far[a][lane]) =
                    kernels::o_inv_bounds(p.o[a][lane] * p.inv[a][lane]);
            }
        }
        p
    }

    /// Lane `lane` as a single ray, with its own `tmax`.
    #[cfg(any(test, not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))))]
    fn lane(&self, lane: usize, tmax: f32) -> Ray8 {
        let o = Vec3A::new(self.o[0][lane], self.o[1][lane], self.o[2][lane]);
        let d = Vec3A::new(self.d[0][lane], self.d[1][lane], self.d[2][lane]);
        Ray8::new(o, d, self.tmin[lane], tmax)
    }
}

impl Bvh8 {
    /// The closest hit of every active lane of `p` with t in (tmin, `tmax[lane]`): where a lane
    /// hits, `tmax[lane]` becomes its distance and `id[lane]` what the triangle reports.
    /// Returns the mask of lanes that hit.
    pub fn intersect_packet(&self, p: &Packet8, tmax: &mut [f32; 8], id: &mut [u32; 8]) -> u32 {
        self.walk_packet::<false>(p, tmax, id)
    }

    /// The lanes of `p` that hit anything with t in (tmin, `tmax[lane]`): each lane's answer is
    /// its own [`Self::occluded`] query's (the same node and triangle tests), but the lanes
    /// share their node visits, and a lane stops taking part once it is blocked.
    pub fn occluded_packet(&self, p: &Packet8, tmax: &[f32; 8]) -> u32 {
        let mut tmax = *tmax;
        self.walk_packet::<true>(p, &mut tmax, &mut [u32::MAX; 8])
    }

    /// The closest hits of two packets, `p` and `q`: what [`Self::intersect_packet`] of each
    /// finds, bit for bit (`tmax[0]`, `id[0]` and the first mask are `p`'s). On a host with
    /// AVX-512 the two go through one walk, sixteen lanes an instruction (see `bvh8/wide.rs`);
    /// elsewhere one after the other.
    pub fn intersect_packet_pair(
        &self,
        p: &Packet8,
        q: &Packet8,
        tmax: &mut [[f32; 8]; 2],
        id: &mut [[u32; 8]; 2],
    ) -> [u32; 2] {
        #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
        if wide_walks() {
            return self.walk_pair(p, q, tmax, id);
        }
        [
            self.intersect_packet(p, &mut tmax[0], &mut id[0]),
            self.intersect_packet(q, &mut tmax[1], &mut id[1]),
        ]
    }

    /// The sixteen-lane walk of a pair of packets (the processor has AVX-512: [`wide::detected`]).
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
    fn walk_pair(
        &self,
        p: &Packet8,
        q: &Packet8,
        tmax: &mut [[f32; 8]; 2],
        id: &mut [[u32; 8]; 2],
    ) -> [u32; 2] {
        debug_assert!(wide::detected());
        if self.nodes.is_empty() || (p.active | q.active) == 0 {
            return [0, 0];
        }
        // The halves side by side: `[[T; 8]; 2]` is laid out as `[T; 16]`.
        let (t16, i16): (&mut [f32; 16], &mut [u32; 16]) =
            (tmax.as_flattened_mut().try_into().unwrap(), id.as_flattened_mut().try_into().unwrap());
        // The stack as `walk_packet` chooses it. (That choice shared as a function taking the
        // walk as a closure made the eight-lane walks of one-node trees do 0.96 % more
        // instructions on jaroslav_path_nee.)
        let need = self.depth * 7 + 1;
        let (nodes, tris, bounds) = (&self.nodes, &self.tris, &self.bounds);
        // SAFETY: the callers check AVX-512 (`wide_walks`, `wide::detected`); the stacks
        // hold `need` entries.
        let hit = unsafe {
            if need <= STACK {
                let mut stack = [const { MaybeUninit::<(u32, u32, f32)>::uninit() }; STACK];
                if self.nodes.len() == 1 {
                    wide::walk16::<true>(nodes, tris, bounds, p, q, t16, i16, &mut stack)
                } else {
                    wide::walk16::<false>(nodes, tris, bounds, p, q, t16, i16, &mut stack)
                }
            } else {
                let mut stack = vec![MaybeUninit::<(u32, u32, f32)>::uninit(); need];
                wide::walk16::<false>(nodes, tris, bounds, p, q, t16, i16, &mut stack)
            }
        };
        [hit & 0xff, hit >> 8]
    }

    /// The packet walk: closest hits, or (`ANY`) whether there is any hit.
    #[inline(always)]
    fn walk_packet<const ANY: bool>(&self, p: &Packet8, tmax: &mut [f32; 8], id: &mut [u32; 8]) -> u32 {
        if self.nodes.is_empty() || p.active == 0 {
            return 0;
        }
        let need = self.depth * 7 + 1;
        if need <= STACK {
            let mut stack = [const { MaybeUninit::<(u32, u32, f32)>::uninit() }; STACK];
            if self.nodes.len() == 1 {
                self.closest_packet::<ANY, true>(p, tmax, id, &mut stack)
            } else {
                self.closest_packet::<ANY, false>(p, tmax, id, &mut stack)
            }
        } else {
            let mut stack = vec![MaybeUninit::<(u32, u32, f32)>::uninit(); need];
            self.closest_packet::<ANY, false>(p, tmax, id, &mut stack)
        }
    }

    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma")))]
    fn closest_packet<const ANY: bool, const ONE_NODE: bool>(
        &self,
        p: &Packet8,
        tmax: &mut [f32; 8],
        id: &mut [u32; 8],
        _stack: &mut [MaybeUninit<(u32, u32, f32)>],
    ) -> u32 {
        // Without AVX2 the lanes go one by one.
        let mut hit = 0;
        for lane in 0..8 {
            if ANY {
                if p.active & (1 << lane) != 0 && self.occluded(&p.lane(lane, tmax[lane])) {
                    hit |= 1 << lane;
                }
                continue;
            }
            if p.active & (1 << lane) != 0
                && let Some((t, i)) = self.intersect(&p.lane(lane, tmax[lane]))
            {
                tmax[lane] = t;
                id[lane] = i;
                hit |= 1 << lane;
            }
        }
        hit
    }

    /// `ANY`: a lane that hits anything is done (its `tmax` drops to -inf, so no box or
    /// triangle test passes for it again) and the walk ends when every lane is.
    ///
    /// `ONE_NODE`: the tree is one node of leaves (a scene of a few dozen triangles). Its
    /// packets enter the root anyway, and testing each of its slots exactly costs less than
    /// reducing the packet's intervals for that one node (`Intervals::slots`): 0.955x the time on
    /// the path-traced Cornell box, whose tree is one node of eight leaves.
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
    fn closest_packet<const ANY: bool, const ONE_NODE: bool>(
        &self,
        p: &Packet8,
        tmax_out: &mut [f32; 8],
        id_out: &mut [u32; 8],
        stack: &mut [MaybeUninit<(u32, u32, f32)>],
    ) -> u32 {
        use std::arch::x86_64::*;
        // SAFETY: the target has AVX2 and FMA (cfg above); every load below reads a whole
        // `[f32; 8]` or `[u32; 8]` (unaligned loads), and broadcasts read single elements.
        unsafe {
            let ld = |a: &[f32; 8]| _mm256_loadu_ps(a.as_ptr());
            let (ox, oy, oz) = (ld(&p.o[0]), ld(&p.o[1]), ld(&p.o[2]));
            let (dx, dy, dz) = (ld(&p.d[0]), ld(&p.d[1]), ld(&p.d[2]));
            let (ix, iy, iz) = (ld(&p.inv[0]), ld(&p.inv[1]), ld(&p.inv[2]));
            let (oix, oiy, oiz) = (ld(&p.o_inv_near[0]), ld(&p.o_inv_near[1]), ld(&p.o_inv_near[2]));
            let (ofx, ofy, ofz) = (ld(&p.o_inv_far[0]), ld(&p.o_inv_far[1]), ld(&p.o_inv_far[2]));
            let tmin = ld(&p.tmin);
            let mut tmax = ld(tmax_out);
            let mut ids = _mm256_loadu_si256(id_out.as_ptr().cast());
            let mut hit_lanes = 0u32;
            let grow = _mm256_set1_ps(SLACK);
            let inf = _mm256_set1_ps(f32::INFINITY);
            // The lanes that reach the root's own box (the union of its children's, by the
            // same test, so no lane that would enter a child is dropped): a packet that misses
            // the mesh's box (most of a frame around a lone model) is done in one test instead
            // of one per filled slot.
            // Where the lanes enter a box given as its six planes broadcast (minima x, y, z,
            // then maxima) before their far bounds `tmax`: the entry distances, and the lanes
            // that enter (conservative by a few ulps, as the single-ray test).
            // Each plane's distance at most the exact one (the lanes' near terms); a lane's
            // exits are those plus the gap between its near and far terms, which makes them at
            // least the exact ones (which plane is a lane's near one depends on its direction,
            // and the min and max pick it).
            let (gx, gy, gz) = (_mm256_sub_ps(oix, ofx), _mm256_sub_ps(oiy, ofy), _mm256_sub_ps(oiz, ofz));
            let enter = move |b: [__m256; 6], tmax: __m256| {
                let t0x = _mm256_fmsub_ps(b[0], ix, oix);
                let t1x = _mm256_fmsub_ps(b[3], ix, oix);
                let t0y = _mm256_fmsub_ps(b[1], iy, oiy);
                let t1y = _mm256_fmsub_ps(b[4], iy, oiy);
                let t0z = _mm256_fmsub_ps(b[2], iz, oiz);
                let t1z = _mm256_fmsub_ps(b[5], iz, oiz);
                let tn = _mm256_max_ps(
                    _mm256_max_ps(_mm256_min_ps(t0x, t1x), _mm256_min_ps(t0y, t1y)),
                    _mm256_max_ps(_mm256_min_ps(t0z, t1z), tmin),
                );
                let tf = _mm256_min_ps(
                    _mm256_min_ps(
                        _mm256_add_ps(_mm256_max_ps(t0x, t1x), gx),
                        _mm256_add_ps(_mm256_max_ps(t0y, t1y), gy),
                    ),
                    _mm256_min_ps(_mm256_add_ps(_mm256_max_ps(t0z, t1z), gz), tmax),
                );
                (tn, _mm256_cmp_ps(tn, _mm256_mul_ps(tf, grow), _CMP_LE_OQ))
            };
            // The lanes that reach the root's own box (the union of its children's, by the
            // same test, so no lane that would enter a child is dropped): a packet that misses
            // the mesh's box (most of a frame around a lone model) is done in one test instead
            // of one per filled slot.
            let (_, in_root) = enter(std::array::from_fn(|k| _mm256_set1_ps(self.bounds[k])), tmax);
            let root = _mm256_movemask_ps(in_root) as u32 & p.active;
            if root == 0 {
                return 0;
            }
            // The packet as intervals: the least and greatest inverse direction and scaled
            // origin of its lanes, per axis. A box tested with them gives, per slot, a lower
            // bound of every lane's entry distance and an upper bound of every lane's exit
            // distance (see `Intervals::slots`).
            let act = lane_mask(p.active);
            let neg_inf = _mm256_set1_ps(f32::NEG_INFINITY);
            let hmin = |v: __m256| hmin8(_mm256_blendv_ps(inf, v, act));
            let hmax = |v: __m256| hmax8(_mm256_blendv_ps(neg_inf, v, act));
            // A lane with a NaN inverse, scaled origin or far bound (a NaN ray) has no
            // interval; the min and max instructions would drop it in some lanes of a reduction
            // and not in others, and a bound reduced that way can miss a valid lane's value.
            // Such a packet keeps every filled slot for the exact tests. A NaN inverse makes its
            // scaled origin NaN, and a sum with a NaN term is NaN (an infinite sum that is NaN,
            // ∞ − ∞, only keeps every slot: still correct). Far bounds only fall during the
            // walk, to a hit's distance or −∞, so the first ones are the ones to check.
            let sum = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(oix, oiy), oiz), tmax);
            let nan_lanes = _mm256_movemask_ps(_mm256_cmp_ps(sum, sum, _CMP_UNORD_Q)) as u32 & p.active;
            let keep_all = if nan_lanes == 0 { 0 } else { 0xff };
            // The least of the far terms and the greatest of the near ones: the intervals
            // bound the nudged distances, so they stay conservative. (`ONE_NODE` walks never
            // read them: nothing of theirs depends on these values.)
            let intervals = Intervals {
                inv_lo: [hmin(ix), hmin(iy), hmin(iz)],
                inv_hi: [hmax(ix), hmax(iy), hmax(iz)],
                oinv_lo: [hmin(ofx), hmin(ofy), hmin(ofz)],
                oinv_hi: [hmax(oix), hmax(oiy), hmax(oiz)],
            };
            let mut sp = 0usize;
            let mut cur = (0u32, root);
            loop {
                let (node_ref, mask) = cur;
                if node_ref & LEAF == 0 {
                    let node = &self.nodes[node_ref as usize];
                    // Slots with a box that the packet's intervals may enter.
                    let filled = filled_slots(node);
                    let mut kids = [(0u32, 0u32, 0f32); 8];
                    let mut n = 0;
                    let mut slots = if ONE_NODE {
                        filled
                    } else {
                        filled & (intervals.slots(node, tmin, hmax(tmax)) | keep_all)
                    };
                    while slots != 0 {
                        let i = slots.trailing_zeros() as usize;
                        slots &= slots - 1;
                        let (tn, in_box) = enter(std::array::from_fn(|k| _mm256_set1_ps(node.b[k][i])), tmax);
                        let lanes = _mm256_movemask_ps(in_box) as u32 & mask;
                        if lanes != 0 {
                            // The nearest entry among the lanes that enter orders the children.
                            let entry = _mm256_cvtss_f32(hmin8(_mm256_blendv_ps(inf, tn, in_box)));
                            insert_by_entry(&mut kids, n, (node.child[i], lanes, entry));
                            n += 1;
                        }
                    }
                    if n > 0 {
                        for k in &kids[..n - 1] {
                            stack[sp] = MaybeUninit::new(*k);
                            sp += 1;
                        }
                        cur = (kids[n - 1].0, kids[n - 1].1);
                        continue;
                    }
                } else {
                    let first = (node_ref & FIRST_MASK) as usize;
                    let count = ((node_ref & !LEAF) >> COUNT_SHIFT) as usize;
                    let live = lane_mask(mask);
                    for tri in &self.tris[first..first + count] {
                        for l in 0..4 {
                            if tri.id[l] == u32::MAX {
                                break;
                            }
                            let c = |v: &[[f32; 4]; 3]| std::array::from_fn(|a| _mm256_set1_ps(v[a][l]));
                            let v0: [__m256; 3] = c(&tri.v0);
                            let s = [
                                _mm256_sub_ps(ox, v0[0]),
                                _mm256_sub_ps(oy, v0[1]),
                                _mm256_sub_ps(oz, v0[2]),
                            ];
                            // The operations of `tri4_closest`, one triangle against eight rays.
                            let (ok, tt, adet) = mt8(c(&tri.e1), c(&tri.e2), s, [dx, dy, dz], tmin);
                            let mut ok = below(_mm256_and_ps(live, ok), tt, adet, tmax);
                            if ANY {
                                // The single-ray any-hit test's second far test, on the
                                // distance itself (`tri8_any`), so each lane answers as it does.
                                ok = _mm256_and_ps(
                                    ok,
                                    _mm256_cmp_ps(_mm256_div_ps(tt, adet), tmax, _CMP_LT_OQ),
                                );
                            }
                            let m = _mm256_movemask_ps(ok) as u32;
                            if m == 0 {
                                continue;
                            }
                            if ANY {
                                tmax = _mm256_blendv_ps(tmax, _mm256_set1_ps(f32::NEG_INFINITY), ok);
                                hit_lanes |= m;
                                if hit_lanes == p.active {
                                    return hit_lanes;
                                }
                                continue;
                            }
                            // The scaled test has slack: the divided distance decides, as
                            // `nearer` does for a single ray (ties to the lower id; "none",
                            // u32::MAX, is -1 in the signed comparison and loses every tie).
                            let t = _mm256_div_ps(tt, adet);
                            let tie = _mm256_and_ps(
                                _mm256_cmp_ps(t, tmax, _CMP_EQ_OQ),
                                _mm256_castsi256_ps(_mm256_cmpgt_epi32(
                                    ids,
                                    _mm256_set1_epi32(tri.id[l] as i32),
                                )),
                            );
                            let closer =
                                _mm256_and_ps(ok, _mm256_or_ps(_mm256_cmp_ps(t, tmax, _CMP_LT_OQ), tie));
                            tmax = _mm256_blendv_ps(tmax, t, closer);
                            ids = _mm256_castps_si256(_mm256_blendv_ps(
                                _mm256_castsi256_ps(ids),
                                _mm256_castsi256_ps(_mm256_set1_epi32(tri.id[l] as i32)),
                                closer,
                            ));
                            hit_lanes |= _mm256_movemask_ps(closer) as u32;
                        }
                    }
                }
                // Pop the next node some lane may still reach before its closest hit.
                loop {
                    if sp == 0 {
                        _mm256_storeu_ps(tmax_out.as_mut_ptr(), tmax);
                        _mm256_storeu_si256(id_out.as_mut_ptr().cast(), ids);
                        return hit_lanes;
                    }
                    sp -= 1;
                    // SAFETY: entries below `sp` were written by the pushes above.
                    let (c, m, d) = stack[sp].assume_init();
                    // A closest-hit lane drops a node that starts beyond its hit, as the single
                    // walk does. An any-hit lane that has not hit keeps every node it entered
                    // (the single any-hit walk never drops one): its far bound has not moved,
                    // and its box test let it in up to the far bound times `grow`.
                    // A closest-hit lane keeps the box test's slack too: a triangle on the box's
                    // surface at the hit's own distance may still win on its id.
                    let bound = _mm256_mul_ps(tmax, grow);
                    let reach =
                        _mm256_movemask_ps(_mm256_cmp_ps(_mm256_set1_ps(d), bound, _CMP_LE_OQ)) as u32;
                    if m & reach != 0 {
                        cur = (c, m & reach);
                        break;
                    }
                }
            }
        }
    }
}

/// Up to eight rays in obvhs's form, side by side, for its box test ([`Aabb::intersect_ray`]):
/// one test of a box against all of them, each lane's answer that of the single test.
pub struct BoxRays8 {
    o: [[f32; 8]; 3],
    inv: [[f32; 8]; 3],
    /// Each lane's far bound: a box the lane enters beyond it does not count. The caller
    /// lowers it as the lane's closest hit comes nearer.
    pub tmax: [f32; 8],
    active: u32,
}

impl BoxRays8 {
    pub fn new(rays: &[obvhs::ray::Ray]) -> Self {
        assert!(rays.len() <= 8, "at most eight rays");
        let mut b = BoxRays8 {
            o: [[0.0; 8]; 3],
            inv: [[0.0; 8]; 3],
            tmax: [f32::NEG_INFINITY; 8],
            active: (1u32 << rays.len()) - 1,
        };
        for (lane, r) in rays.iter().enumerate() {
            for a in 0..3 {
                b.o[a][lane] = r.origin[a];
                b.inv[a][lane] = r.inv_direction[a];
            }
            b.tmax[lane] = r.tmax;
        }
        b
    }

    /// The box tests of `lanes` with far bounds `tmax`: what [`Self::new`] makes of the same
    /// rays. [`Lanes8::compute_inverse`] must have run.
    #[inline]
    pub fn from_lanes(lanes: &Lanes8, tmax: [f32; 8]) -> Self {
        BoxRays8 { o: lanes.o, inv: *lanes.inv(), tmax, active: (1u32 << lanes.len) - 1 }
    }

    /// The lanes whose ray enters `b` at a distance up to their `tmax`: obvhs's
    /// `b.intersect_ray(ray) <= ray.tmax` for each, with the same operations.
    #[inline]
    pub fn hits(&self, b: &Aabb) -> u32 {
        #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
        {
            use std::arch::x86_64::*;
            // SAFETY: the target has AVX2 (cfg above); unaligned loads of whole `[f32; 8]`s.
            unsafe {
                let ld = |a: &[f32; 8]| _mm256_loadu_ps(a.as_ptr());
                let axis = |a: usize| {
                    let (o, inv) = (ld(&self.o[a]), ld(&self.inv[a]));
                    let t1 = _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(b.min[a]), o), inv);
                    let t2 = _mm256_mul_ps(_mm256_sub_ps(_mm256_set1_ps(b.max[a]), o), inv);
                    (_mm256_min_ps(t1, t2), _mm256_max_ps(t1, t2))
                };
                let ((nx, fx), (ny, fy), (nz, fz)) = (axis(0), axis(1), axis(2));
                let near = _mm256_max_ps(_mm256_max_ps(nx, ny), nz);
                let far = _mm256_min_ps(_mm256_min_ps(fx, fy), fz);
                let ok = _mm256_and_ps(
                    _mm256_and_ps(
                        _mm256_cmp_ps(far, near, _CMP_GE_OQ),
                        _mm256_cmp_ps(far, _mm256_setzero_ps(), _CMP_GE_OQ),
                    ),
                    _mm256_cmp_ps(near, ld(&self.tmax), _CMP_LE_OQ),
                );
                _mm256_movemask_ps(ok) as u32 & self.active
            }
        }
        #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma")))]
        {
            let mut mask = 0;
            for lane in 0..8 {
                let t = |a: usize, p: f32| (p - self.o[a][lane]) * self.inv[a][lane];
                let (mut near, mut far) = (f32::NEG_INFINITY, f32::INFINITY);
                for a in 0..3 {
                    let (t1, t2) = (t(a, b.min[a]), t(a, b.max[a]));
                    near = near.max(t1.min(t2));
                    far = far.min(t1.max(t2));
                }
                if far >= near && far >= 0.0 && near <= self.tmax[lane] {
                    mask |= 1 << lane;
                }
            }
            mask & self.active
        }
    }
}

fn fill_counts(bvh2: &Bvh2, root: usize, count: &mut [u32]) {
    // Iterative post-order: children before parents.
    let mut stack = vec![(root, false)];
    while let Some((i, done)) = stack.pop() {
        let n = &bvh2.nodes[i];
        if n.is_leaf() {
            count[i] = n.prim_count;
        } else if done {
            let c = n.first_index as usize;
            count[i] = count[c] + count[c + 1];
        } else {
            stack.push((i, true));
            stack.push((n.first_index as usize, false));
            stack.push((n.first_index as usize + 1, false));
        }
    }
}

impl Builder<'_> {
    /// Emits the 8-wide node for BVH2 node `i` (opened until it has 8 children or none can be
    /// opened); returns its index.
    fn node(&mut self, i: usize, depth: usize) -> u32 {
        self.out.depth = self.out.depth.max(depth);
        let idx = self.out.nodes.len();
        self.out.nodes.push(Node {
            b: [
                [f32::INFINITY; 8],
                [f32::INFINITY; 8],
                [f32::INFINITY; 8],
                [f32::NEG_INFINITY; 8],
                [f32::NEG_INFINITY; 8],
                [f32::NEG_INFINITY; 8],
            ],
            child: [0; 8],
        });
        let n = &self.bvh2.nodes[i];
        let mut kids: Vec<usize> = if n.is_leaf() || self.count[i] <= LEAF_MAX {
            vec![i]
        } else {
            vec![n.first_index as usize, n.first_index as usize + 1]
        };
        // Open the largest child that is not to be a leaf, while slots are free.
        while kids.len() < 8 && self.open_largest(&mut kids, |k| self.count[k] > LEAF_MAX) {}
        // The root's free slots then go to leaves split further (a tree of at most about 64
        // triangles: a Cornell box): one node of small leaves with tight boxes, where a few
        // leaves would each span the room and every ray would test them all. Below the root a
        // free slot stays free: split leaves there cost a large mesh's shadow rays more than
        // they save.
        while depth == 1 && kids.len() < 8 && self.open_largest(&mut kids, |_| true) {}
        for (slot, &k) in kids.iter().enumerate() {
            let kn = &self.bvh2.nodes[k];
            let (lo, hi) = (kn.aabb.min, kn.aabb.max);
            let b = &mut self.out.nodes[idx].b;
            for a in 0..3 {
                b[a][slot] = lo[a];
                b[a + 3][slot] = hi[a];
            }
            let child = if kn.is_leaf() || self.count[k] <= LEAF_MAX {
                self.leaf(k)
            } else {
                self.node(k, depth + 1)
            };
            self.out.nodes[idx].child[slot] = child;
        }
        idx as u32
    }

    /// Replaces the child in `kids` with the largest box, of those that are inner BVH2 nodes
    /// and pass `can`, by its two children; false when there is none.
    fn open_largest(&self, kids: &mut Vec<usize>, can: impl Fn(usize) -> bool) -> bool {
        let area = |k: usize| self.bvh2.nodes[k].aabb.half_area();
        let best = kids
            .iter()
            .enumerate()
            .filter(|&(_, &k)| !self.bvh2.nodes[k].is_leaf() && can(k))
            .max_by(|a, b| area(*a.1).total_cmp(&area(*b.1)))
            .map(|(j, _)| j);
        let Some(j) = best else { return false };
        let k = kids.swap_remove(j);
        let f = self.bvh2.nodes[k].first_index as usize;
        kids.push(f);
        kids.push(f + 1);
        true
    }

    /// Packs the triangles under BVH2 node `i` into packets; returns the leaf reference.
    fn leaf(&mut self, i: usize) -> u32 {
        let mut prims = Vec::with_capacity(self.count[i] as usize);
        let mut stack = vec![i];
        while let Some(k) = stack.pop() {
            let n = &self.bvh2.nodes[k];
            if n.is_leaf() {
                let f = n.first_index as usize;
                prims.extend_from_slice(&self.bvh2.primitive_indices[f..f + n.prim_count as usize]);
            } else {
                stack.push(n.first_index as usize + 1);
                stack.push(n.first_index as usize);
            }
        }
        let first = self.out.tris.len();
        for chunk in prims.chunks(4) {
            let mut p = Tri4 { v0: [[0.0; 4]; 3], e1: [[0.0; 4]; 3], e2: [[0.0; 4]; 3], id: [u32::MAX; 4] };
            for (lane, &prim) in chunk.iter().enumerate() {
                let t = &self.tris[prim as usize];
                for (a, ((v0, e1), e2)) in p.v0.iter_mut().zip(&mut p.e1).zip(&mut p.e2).enumerate() {
                    v0[lane] = t[0][a];
                    e1[lane] = t[1][a];
                    e2[lane] = t[2][a];
                }
                p.id[lane] = self.ids[prim as usize];
            }
            self.out.tris.push(p);
        }
        let count = (self.out.tris.len() - first) as u32;
        assert!(count < 8 && (first as u32) <= FIRST_MASK, "BVH leaf too large");
        LEAF | (count << COUNT_SHIFT) | first as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_simd_variable_takes_avx2_or_nothing_and_names_itself_otherwise() {
        let ask = |v: &str| narrow_walks_asked(Some(std::ffi::OsStr::new(v)));
        assert_eq!(narrow_walks_asked(None), Ok(false));
        assert_eq!(ask(""), Ok(false));
        assert_eq!(ask("avx2"), Ok(true));
        assert_eq!(ask("AVX2"), Ok(true));
        for bad in ["avx512", "avx-2", " avx2", "1"] {
            let e = ask(bad).unwrap_err();
            assert!(e.starts_with(&format!("TESSERA_SIMD={bad} ")) && e.contains("'avx2'"), "{e}");
        }
    }

    /// Every lane of a packet finds what its own single-ray query finds: coherent packets (the
    /// rays of one small cone), scattered ones, partial ones, and lanes with their own tmax.
    /// Uniform numbers in [0, 1) from a xorshift generator.
    fn xorshift(mut s: u64) -> impl FnMut() -> f32 {
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// `count` random small triangles in a 10-unit cube (vertex 0 and edges) and their BVH.
    fn soup(r: &mut impl FnMut() -> f32, count: usize) -> (Vec<Tri>, Bvh8) {
        soup_of_size(r, count, 1.0)
    }

    /// `count` random triangles about `size` across in a 10-unit cube, and their BVH.
    fn soup_of_size(r: &mut impl FnMut() -> f32, count: usize, size: f32) -> (Vec<Tri>, Bvh8) {
        let mut tris = Vec::new();
        for _ in 0..count {
            let c = Vec3A::new(r(), r(), r()) * 10.0;
            let a = c + (Vec3A::new(r(), r(), r()) - 0.5) * size;
            let b = c + (Vec3A::new(r(), r(), r()) - 0.5) * size;
            let d = c + (Vec3A::new(r(), r(), r()) - 0.5) * size;
            tris.push([a, b - a, d - a]);
        }
        let aabbs: Vec<Aabb> =
            tris.iter().map(|t| Aabb::from_points(&[t[0], t[0] + t[1], t[0] + t[2]])).collect();
        let ids: Vec<u32> = (0..tris.len() as u32).collect();
        let bvh = Bvh8::build(&tris, &aabbs, &ids);
        (tris, bvh)
    }

    /// A packet of four copies of triangle `t` (vertex 0 and edges), all reporting `id`: one
    /// triangle's test through the packet kernels.
    fn splat(t: &Tri, id: u32) -> Tri4 {
        let lanes = |v: Vec3A| [[v.x; 4], [v.y; 4], [v.z; 4]];
        Tri4 { v0: lanes(t[0]), e1: lanes(t[1]), e2: lanes(t[2]), id: [id; 4] }
    }

    /// A soup of 3,000 triangles and a ray from inside it that hits one (the probes of the walk's
    /// odd rays vary that ray).
    fn soup_and_ray() -> (Bvh8, Vec3A, Vec3A) {
        let mut r = xorshift(99);
        let (_, bvh) = soup(&mut r, 3000);
        (bvh, Vec3A::splat(5.0), Vec3A::new(0.3, -0.5, 0.8).normalize())
    }

    /// A single ray with a NaN in its origin, direction or bounds hits nothing, and its walk
    /// ends (the box test would let it into every slot, the empty ones, which point at the
    /// root, too).
    #[test]
    fn a_ray_with_a_nan_hits_nothing() {
        let (bvh, o, d) = soup_and_ray();
        let nan = f32::NAN;
        let rays = [
            Ray8::new(o, Vec3A::splat(nan), 0.0, f32::INFINITY),
            Ray8::new(o, Vec3A::new(nan, d.y, d.z), 0.0, f32::INFINITY),
            Ray8::new(Vec3A::new(5.0, nan, 5.0), d, 0.0, f32::INFINITY),
            Ray8::new(o, d, nan, f32::INFINITY),
            Ray8::new(o, d, 0.0, nan),
        ];
        for (k, ray) in rays.iter().enumerate() {
            assert_eq!(bvh.intersect(ray), None, "ray {k}");
            assert!(!bvh.occluded(ray), "ray {k}");
        }
        // The same ray without the NaN hits (the soup fills the box it starts in).
        assert!(bvh.occluded(&Ray8::new(o, d, 0.0, f32::INFINITY)));
    }

    /// A ray with an infinite origin or direction component (what an f64 ray far out, or carried
    /// into object space by a huge or tiny scale, becomes in f32) gets an answer and its walk
    /// ends: its plane distances come out NaN in the empty slots' infinite planes (∞ − ∞, ∞·0),
    /// and the walk must not enter them (found by fuzzing the renderer: a shadow-ray epsilon
    /// of 2e54 put the rays' origins at f32 infinity).
    #[test]
    fn a_ray_with_an_infinity_ends_its_walk() {
        let (bvh, o, d) = soup_and_ray();
        let inf = f32::INFINITY;
        // Every pattern of infinite, zero and finite components, in origins and directions.
        let values = [inf, -inf, 0.0, 5.0, -3.0, 1e30];
        let mut rays = Vec::new();
        for a in values {
            for b in values {
                for c in values {
                    let v = Vec3A::new(a, b, c);
                    rays.push(Ray8::new(v, d, 0.0, inf));
                    rays.push(Ray8::new(v, -d, 0.0, inf));
                    rays.push(Ray8::new(o, v, 0.0, inf));
                    rays.push(Ray8::new(v, Vec3A::new(d.x, 0.0, d.z), 0.0, inf));
                }
            }
        }
        for (k, ray) in rays.iter().enumerate() {
            // Whatever the answer, it comes back (before the fix: an index out of bounds).
            let closest = bvh.intersect(ray);
            let any = bvh.occluded(ray);
            assert_eq!(closest.is_some(), any, "ray {k}");
        }
        // Finite rays keep their answers: the slots they enter are filled ones anyway.
        assert!(bvh.occluded(&Ray8::new(o, d, 0.0, inf)));
    }

    /// A lane with a NaN direction, origin or far bound hits nothing, and the other lanes of its
    /// packet still find what their single rays find (a NaN would otherwise leak into the packet's
    /// interval bounds, which the min and max instructions reduce lane by lane).
    #[test]
    fn a_nan_lane_leaves_its_packet_alone() {
        let mut r = xorshift(4242);
        let (_, bvh) = soup(&mut r, 3000);
        let mut lanes_hit = 0;
        for k in 0..4000 {
            let o = Vec3A::new(r(), r(), r()) * 14.0 - 2.0;
            let d = Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize();
            let bad = k % 8;
            let rays: Vec<(Vec3A, Vec3A)> = (0..8)
                .map(|lane| {
                    let jitter = Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5) * [0.05, 1.0][k % 2];
                    let (mut o, mut d) = (o + jitter, (d + jitter).normalize());
                    if lane == bad {
                        match k % 3 {
                            0 => d.x = f32::NAN,
                            1 => o.y = f32::NAN,
                            _ => d = Vec3A::splat(f32::NAN),
                        }
                    }
                    (o, d)
                })
                .collect();
            let packet = Packet8::new(&rays, 0.0);
            // Every fourth packet: the lanes' own far bounds, the NaN lane's a NaN.
            let mut tmax = [f32::INFINITY; 8];
            if k % 4 == 3 {
                tmax = std::array::from_fn(|_| 2.0 + 14.0 * r());
                tmax[bad] = f32::NAN;
            }
            let limits = tmax;
            let mut id = [u32::MAX; 8];
            let hit = bvh.intersect_packet(&packet, &mut tmax, &mut id);
            assert_eq!(hit & (1 << bad), 0, "packet {k}: the NaN lane hits nothing");
            for lane in (0..8).filter(|&l| l != bad) {
                let single = bvh.intersect(&packet.lane(lane, limits[lane]));
                let got = (hit & (1 << lane) != 0).then_some(tmax[lane]);
                assert_eq!(got.map(f32::to_bits), single.map(|s| s.0.to_bits()), "packet {k} lane {lane}");
                lanes_hit += usize::from(got.is_some());
            }
            // Paired with a packet of clean rays (the NaN lane's replaced), either way round,
            // both find what they find alone.
            let clean_rays: Vec<_> = (0..8).map(|l| rays[if l == bad { (bad + 1) % 8 } else { l }]).collect();
            let clean = Packet8::new(&clean_rays, 0.0);
            let (mut clean_tmax, mut clean_id) = ([f32::INFINITY; 8], [u32::MAX; 8]);
            let clean_hit = bvh.intersect_packet(&clean, &mut clean_tmax, &mut clean_id);
            let alone = [(hit, tmax, id), (clean_hit, clean_tmax, clean_id)];
            for order in [[0, 1], [1, 0]] {
                let packets = [&packet, &clean];
                let (mut t, mut i) = ([limits, [f32::INFINITY; 8]], [[u32::MAX; 8]; 2]);
                (t, i) = ([t[order[0]], t[order[1]]], [i[order[0]], i[order[1]]]);
                let h = bvh.intersect_packet_pair(packets[order[0]], packets[order[1]], &mut t, &mut i);
                for g in 0..2 {
                    let (ah, at, ai) = alone[order[g]];
                    assert_eq!(
                        (h[g], t[g].map(f32::to_bits), i[g]),
                        (ah, at.map(f32::to_bits), ai),
                        "pair {k}"
                    );
                }
            }
        }
        assert!(lanes_hit > 1000, "{lanes_hit} lanes hit");
    }

    #[test]
    fn packets_find_what_single_rays_find() {
        let mut r = xorshift(777);
        let (_, bvh) = soup(&mut r, 5000);
        let (mut lanes_hit, mut lanes) = (0, 0);
        for k in 0..3000 {
            let n = 1 + k % 8;
            let o = Vec3A::new(r(), r(), r()) * 14.0 - 2.0;
            let d = Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize();
            let spread = [0.002, 0.05, 1.0][k % 3];
            let rays: Vec<(Vec3A, Vec3A)> = (0..n)
                .map(|_| {
                    let jitter = Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5) * spread;
                    let dir = if k % 17 == 0 { Vec3A::new(0.0, 0.0, -1.0) } else { (d + jitter).normalize() };
                    (o + jitter * 0.1, dir)
                })
                .collect();
            let packet = Packet8::new(&rays, 0.0);
            let mut tmax = [f32::INFINITY; 8];
            for (lane, t) in tmax.iter_mut().enumerate().take(n) {
                if (k + lane) % 4 == 0 {
                    *t = 3.0 + lane as f32;
                }
            }
            let limits = tmax;
            let mut id = [u32::MAX; 8];
            let hit = bvh.intersect_packet(&packet, &mut tmax, &mut id);
            assert_eq!(hit >> n, 0, "only active lanes hit");
            for lane in 0..n {
                let single = bvh.intersect(&packet.lane(lane, limits[lane]));
                let got = (hit & (1 << lane) != 0).then_some((tmax[lane], id[lane]));
                assert_eq!(
                    got.map(|g| g.0.to_bits()),
                    single.map(|s| s.0.to_bits()),
                    "packet {k} lane {lane}"
                );
                if got.is_none() {
                    assert_eq!(
                        (tmax[lane], id[lane]),
                        (limits[lane], u32::MAX),
                        "a missing lane is untouched"
                    );
                }
                lanes_hit += usize::from(got.is_some());
                lanes += 1;
            }
        }
        assert!(lanes_hit > lanes / 5, "{lanes_hit} of {lanes} lanes hit");
    }

    /// Two packets walked as a pair find, lane by lane and bit for bit, what each finds walked
    /// alone: in big trees and in a tree of one node, with partly filled packets, far bounds
    /// short of some hits, and NaN rays among them. Both ways a pair can go are checked where
    /// the host has them: the public call (whichever walk this process takes) and, on a host
    /// with AVX-512, the sixteen-lane walk itself.
    #[test]
    fn pairs_of_packets_find_what_each_packet_finds_alone() {
        let mut r = xorshift(31337);
        let (_, big) = soup(&mut r, 5000);
        let (_, small) = soup(&mut r, 20);
        assert_eq!(small.nodes.len(), 1, "a soup of 20 triangles is one node");
        let make = |k: usize, r: &mut dyn FnMut() -> f32| {
            let n = 1 + (k * 7 + 3) % 8;
            let o = Vec3A::new(r(), r(), r()) * 14.0 - 2.0;
            let d = Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize();
            let spread = [0.002, 0.05, 1.0][k % 3];
            let rays: Vec<(Vec3A, Vec3A)> = (0..n)
                .map(|lane| {
                    let jitter = Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5) * spread;
                    let dir =
                        if k.is_multiple_of(29) && lane == 1 { Vec3A::NAN } else { (d + jitter).normalize() };
                    (o + jitter * 0.1, dir)
                })
                .collect();
            let mut packet = Packet8::new(&rays, 0.0);
            if k.is_multiple_of(11) {
                packet.set_active(0b1010_1101);
            }
            let tmax: [f32; 8] = std::array::from_fn(|lane| {
                if (k + lane).is_multiple_of(4) { 3.0 + lane as f32 } else { f32::INFINITY }
            });
            (packet, tmax)
        };
        let (mut lanes_hit, mut paired_wide) = (0, 0);
        for k in 0..3000 {
            let bvh = if k % 5 == 4 { &small } else { &big };
            let (p, q) = (make(2 * k, &mut r), make(2 * k + 1, &mut r));
            let mut alone = [(p.1, [u32::MAX; 8], 0), (q.1, [u32::MAX; 8], 0)];
            for (g, packet) in [&p.0, &q.0].into_iter().enumerate() {
                let (tmax, id, hit) = &mut alone[g];
                *hit = bvh.intersect_packet(packet, tmax, id);
                lanes_hit += hit.count_ones();
            }
            let mut walks = vec![("intersect_packet_pair", {
                let (mut tmax, mut id) = ([p.1, q.1], [[u32::MAX; 8]; 2]);
                let hit = bvh.intersect_packet_pair(&p.0, &q.0, &mut tmax, &mut id);
                (tmax, id, hit)
            })];
            #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
            if wide::detected() {
                let (mut tmax, mut id) = ([p.1, q.1], [[u32::MAX; 8]; 2]);
                let hit = bvh.walk_pair(&p.0, &q.0, &mut tmax, &mut id);
                walks.push(("walk_pair", (tmax, id, hit)));
                paired_wide += 1;
            }
            for (name, (tmax, id, hit)) in walks {
                for g in 0..2 {
                    assert_eq!(hit[g], alone[g].2, "{name}: pair {k}, packet {g}: the lanes that hit");
                    assert_eq!(
                        tmax[g].map(f32::to_bits),
                        alone[g].0.map(f32::to_bits),
                        "{name}: pair {k}, packet {g}"
                    );
                    assert_eq!(id[g], alone[g].1, "{name}: pair {k}, packet {g}");
                }
            }
        }
        assert!(lanes_hit > 5000, "only {lanes_hit} lanes hit");
        #[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
        assert_eq!(paired_wide > 0, wide::detected(), "the sixteen-lane walk ran where the host has it");
    }

    /// Any-hit packets answer as each lane's single query does where it matters most: far
    /// bounds within rounding of a triangle's distance (a shadow ray stopping just short of a
    /// light's surface), in scattered packets whose lanes point every way.
    #[test]
    fn any_hit_packets_agree_with_single_rays_at_the_far_bound() {
        let mut r = xorshift(4242);
        let (_, bvh) = soup(&mut r, 2000);
        let (mut blocked, mut lanes) = (0, 0);
        for k in 0..4000 {
            let n = 2 + k % 7;
            let rays: Vec<(Vec3A, Vec3A)> = (0..n)
                .map(|_| {
                    let o = Vec3A::new(r(), r(), r()) * 10.0;
                    (o, Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize())
                })
                .collect();
            let packet = Packet8::new(&rays, 1e-4);
            let mut far = [f32::NEG_INFINITY; 8];
            for (lane, f) in far.iter_mut().enumerate().take(n) {
                let nearest = bvh.intersect(&packet.lane(lane, f32::INFINITY)).map_or(1.0, |h| h.0);
                let nudge = [-2e-6, -1e-6, -3e-7, -1e-7, 0.0, 1e-7, 1e-6][(k + lane) % 7];
                *f = nearest * (1.0 + nudge);
            }
            let got = bvh.occluded_packet(&packet, &far);
            for (lane, &f) in far.iter().enumerate().take(n) {
                let single = bvh.occluded(&packet.lane(lane, f));
                assert_eq!(got & (1 << lane) != 0, single, "packet {k} lane {lane}, far {f}");
                blocked += usize::from(single);
                lanes += 1;
            }
        }
        assert!(blocked > lanes / 10 && blocked < lanes * 9 / 10, "{blocked} of {lanes} blocked");
    }

    /// A scene of a few dozen triangles makes a tree of one node, whose packets test every
    /// slot exactly (no intervals): closest and any-hit packets still answer, lane by lane, as
    /// the single rays do, far bounds at and around the nearest hit included.
    #[test]
    fn a_tree_of_one_node_answers_as_single_rays_do() {
        let mut r = xorshift(99);
        let (_, bvh) = soup_of_size(&mut r, 20, 6.0);
        assert_eq!(bvh.nodes.len(), 1, "twenty triangles make one node");
        let (mut hit, mut blocked, mut lanes) = (0, 0, 0);
        for k in 0..3000 {
            let n = 1 + k % 8;
            let rays: Vec<(Vec3A, Vec3A)> = (0..n)
                .map(|_| {
                    let o = Vec3A::new(r(), r(), r()) * 10.0;
                    let towards = Vec3A::new(r(), r(), r()) * 10.0;
                    (o, (towards - o).normalize())
                })
                .collect();
            let packet = Packet8::new(&rays, 1e-4);
            let (mut tmax, mut id) = ([f32::INFINITY; 8], [u32::MAX; 8]);
            let found = bvh.intersect_packet(&packet, &mut tmax, &mut id);
            let mut far = [f32::NEG_INFINITY; 8];
            for lane in 0..n {
                let single = bvh.intersect(&packet.lane(lane, f32::INFINITY));
                let got = (found & (1 << lane) != 0).then_some(tmax[lane]);
                assert_eq!(got.map(f32::to_bits), single.map(|s| s.0.to_bits()), "packet {k} lane {lane}");
                let nudge = [-1e-6, -1e-7, 0.0, 1e-7, 1e-6, -0.5][(k + lane) % 6];
                far[lane] = single.map_or(5.0, |s| s.0) * (1.0 + nudge);
                hit += usize::from(single.is_some());
                lanes += 1;
            }
            let got = bvh.occluded_packet(&packet, &far);
            for (lane, &f) in far.iter().enumerate().take(n) {
                let single = bvh.occluded(&packet.lane(lane, f));
                assert_eq!(got & (1 << lane) != 0, single, "any hit: packet {k} lane {lane}, far {f}");
                blocked += usize::from(single);
            }
        }
        assert!(hit > lanes / 5 && hit < lanes * 19 / 20, "{hit} of {lanes} lanes hit");
        assert!(blocked > lanes / 10 && blocked < hit, "{blocked} of {lanes} lanes blocked");
    }

    /// Two packets tested in one pass find what `tri4_closest` finds testing one packet, then
    /// the other below the first one's hit: the any-hit answer and the nearest hit, lane and
    /// distance, with far bounds at and around the hit.
    #[test]
    fn a_pair_of_packets_finds_what_its_packets_find_one_after_the_other() {
        let mut r = xorshift(777);
        let (tris, _) = soup(&mut r, 64);
        let packet = |k: usize| {
            let mut p = Tri4 { v0: [[0.0; 4]; 3], e1: [[0.0; 4]; 3], e2: [[0.0; 4]; 3], id: [u32::MAX; 4] };
            // Packets of one to four triangles (unused lanes stay empty).
            for lane in 0..1 + k % 4 {
                let t = &tris[(k * 4 + lane) % tris.len()];
                let [v0, e1, e2] = t.map(|c| c.to_array());
                for a in 0..3 {
                    (p.v0[a][lane], p.e1[a][lane], p.e2[a][lane]) = (v0[a], e1[a], e2[a]);
                }
                p.id[lane] = lane as u32;
            }
            p
        };
        let (mut blocked, mut at_bound) = (0, 0);
        for k in 0..20_000 {
            let (a, b) = (packet(k % 16), packet((k / 16) % 16));
            let o = Vec3A::new(r(), r(), r()) * 14.0 - 2.0;
            // Mostly towards a point of one of the packets' triangles (inside or just outside
            // it), some in any direction.
            let t = &tris[(k % 16) * 4 % tris.len()];
            let (u, v) = (r() * 1.2 - 0.1, r() * 1.2 - 0.1);
            let aim = t[0] + u * t[1] + (1.0 - u) * v * t[2];
            let d =
                if k % 5 == 0 { Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5) } else { aim - o }.normalize();
            let probe = Ray8::new(o, d, 0.0, f32::INFINITY);
            // Far bounds at infinity, at the nearest hit itself and one ulp either side of it
            // (where the scaled test and the divided distance must agree), and short of it.
            let none = u32::MAX;
            let hit = tri4_closest(&a, &probe, f32::INFINITY, none).or(tri4_closest(
                &b,
                &probe,
                f32::INFINITY,
                none,
            ));
            let bounds = match hit {
                Some((t, _)) => vec![f32::INFINITY, t, t.next_up(), t.next_down(), 0.5 * t],
                None => vec![f32::INFINITY, 3.0],
            };
            for tmax in bounds {
                let ray = Ray8::new(o, d, 0.0, tmax);
                let expect = tri4_closest(&a, &ray, tmax, none).is_some()
                    || tri4_closest(&b, &ray, tmax, none).is_some();
                assert_eq!(tri8_any(&a, &b, &ray, tmax), expect, "ray {k}, tmax {tmax}");
                // The nearest: `a`'s, then `b`'s below it (equal packets: `a`'s lane wins).
                let first = tri4_closest(&a, &ray, tmax, none);
                let (bound, bid) = first.map_or((tmax, none), |h| (h.0, a.id[h.1]));
                let second = tri4_closest(&b, &ray, bound, bid);
                let nearest = second.map(|(t, l)| (t, l + 4)).or(first);
                assert_eq!(tri8_closest(&a, &b, &ray, tmax, none), nearest, "ray {k}, tmax {tmax}");
                blocked += expect as u32;
                at_bound += (hit.is_some_and(|h| h.0 == tmax)) as u32;
            }
        }
        assert!(blocked > 1000 && at_bound > 100, "{blocked} blocked, {at_bound} at the bound");
    }

    /// Rays aimed at the corners of a grid of triangles (each corner shared by up to six, all
    /// at one distance): the closest hit is the least (distance, id) of the triangles hit, as
    /// brute force finds it, whichever walk meets them and in whatever order: a single ray, and
    /// the same ray as any lane of packets of other rays.
    #[test]
    fn ties_go_to_the_lowest_id_in_every_walk() {
        let mut r = xorshift(4242);
        // A 6x6 grid of squares in the plane z = 1, two triangles each, ids shuffled.
        let mut tris = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                let p = Vec3A::new(i as f32, j as f32, 1.0);
                let (x, y) = (Vec3A::X, Vec3A::Y);
                tris.push([p, x, x + y]);
                tris.push([p, x + y, y]);
            }
        }
        let mut ids: Vec<u32> = (0..tris.len() as u32).collect();
        for k in (1..ids.len()).rev() {
            ids.swap(k, (r() * (k + 1) as f32) as usize % (k + 1));
        }
        let aabbs: Vec<Aabb> =
            tris.iter().map(|t| Aabb::from_points(&[t[0], t[0] + t[1], t[0] + t[2]])).collect();
        let bvh = Bvh8::build(&tris, &aabbs, &ids);
        let brute = |ray: &Ray8| {
            let mut best: Option<(f32, u32)> = None;
            for (t, &id) in tris.iter().zip(&ids) {
                let p = splat(t, id);
                let (bound, bid) = best.map_or((ray.tmax, u32::MAX), |b| b);
                if let Some((tt, _)) = tri4_closest(&p, ray, bound, bid) {
                    best = Some((tt, id));
                }
            }
            best
        };
        let mut ties = 0;
        for k in 0..400 {
            // Eight rays from one origin below the grid, each at a grid corner.
            let o = Vec3A::new(r() * 6.0, r() * 6.0, -2.0 - 3.0 * r());
            let rays: Vec<(Vec3A, Vec3A)> = (0..8)
                .map(|_| {
                    let c = Vec3A::new((r() * 7.0).floor().min(6.0), (r() * 7.0).floor().min(6.0), 1.0);
                    (o, (c - o).normalize())
                })
                .collect();
            let packet = Packet8::new(&rays, 0.0);
            let (mut tmax, mut id) = ([f32::INFINITY; 8], [u32::MAX; 8]);
            let hit = bvh.intersect_packet(&packet, &mut tmax, &mut id);
            // The same rays as the second packet of a pair (the first: the rays reversed).
            let reversed: Vec<_> = rays.iter().rev().copied().collect();
            let (mut pair_tmax, mut pair_id) = ([[f32::INFINITY; 8]; 2], [[u32::MAX; 8]; 2]);
            let pair_hit = bvh.intersect_packet_pair(
                &Packet8::new(&reversed, 0.0),
                &packet,
                &mut pair_tmax,
                &mut pair_id,
            );
            for (lane, &(o, d)) in rays.iter().enumerate() {
                let ray = Ray8::new(o, d, 0.0, f32::INFINITY);
                let expect = brute(&ray);
                assert_eq!(bvh.intersect(&ray), expect, "rays {k}, lane {lane}: single walk");
                let got = (hit & (1 << lane) != 0).then_some((tmax[lane], id[lane]));
                assert_eq!(got, expect, "rays {k}, lane {lane}: packet walk");
                let paired = |g: usize, l: usize| {
                    (pair_hit[g] & (1 << l) != 0).then_some((pair_tmax[g][l], pair_id[g][l]))
                };
                assert_eq!(paired(1, lane), expect, "rays {k}, lane {lane}: pair walk");
                assert_eq!(paired(0, 7 - lane), expect, "rays {k}, lane {lane}: pair walk, reversed");
                // Rays whose hit another triangle also takes at the same distance.
                ties += usize::from(expect.is_some_and(|(t, id)| {
                    tris.iter().zip(&ids).filter(|&(_, &other)| other != id).any(|(tri, &other)| {
                        let p = splat(tri, other);
                        tri4_closest(&p, &ray, f32::INFINITY, u32::MAX).is_some_and(|h| h.0 == t)
                    })
                }));
            }
        }
        assert!(ties > 500, "only {ties} rays met a tie");
    }

    /// Brute force over every triangle agrees with the BVH on random rays through a random soup.
    #[test]
    fn agrees_with_brute_force() {
        let mut r = xorshift(12345);
        let (tris, bvh) = soup(&mut r, 3000);
        let mut hits = 0;
        for k in 0..4000 {
            let o = Vec3A::new(r(), r(), r()) * 14.0 - 2.0;
            let mut d = Vec3A::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize();
            if k % 10 == 0 {
                d = Vec3A::new(0.0, 0.0, if k % 20 == 0 { 1.0 } else { -1.0 });
            }
            let tmax = if k % 3 == 0 { 5.0 } else { f32::INFINITY };
            let ray = Ray8::new(o, d, 0.0, tmax);
            let mut expect: Option<(f32, u32)> = None;
            for (i, t) in tris.iter().enumerate() {
                let p = splat(t, i as u32);
                let (bound, bid) = expect.map_or((tmax, u32::MAX), |e| e);
                if let Some((tt, _)) = tri4_closest(&p, &ray, bound, bid) {
                    expect = Some((tt, i as u32));
                }
            }
            let got = bvh.intersect(&ray);
            assert_eq!(got, expect, "ray {k}");
            assert_eq!(bvh.occluded(&ray), expect.is_some(), "ray {k}");
            hits += expect.is_some() as u32;
        }
        assert!(hits > 500, "{hits}");
    }
}
