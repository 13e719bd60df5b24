//! Horizons: the directions in which a shadow ray leaving a triangle of the world tree is
//! certainly not blocked, so that it need not be traced.
//!
//! An environment light's shadow rays leave a lit point in directions drawn from the map, and
//! most reach the sky (on a scanned head about nine in ten): each walk proves that nothing is
//! hit, at the cost of a traversal near its origin. Around every triangle, seen from its side,
//! the rest of the scene rises above the triangle's plane only up to some elevation in each
//! direction: its horizon. A ray steeper than the horizon in its own azimuth cannot meet
//! anything. The horizon is kept as eight azimuth sectors of 45° in the triangle's plane, each
//! with the sine of its highest elevation, rounded up to a byte; the eight bytes of a side fit
//! one `u64`.
//!
//! The bound is conservative, so a ray it lets through is one the walk would also have let
//! through, and an image is the same bytes whether or not the horizon answered; so it is
//! computed lazily, for a triangle's side once it has been asked about [`QUERIES_BEFORE`]
//! times, by whichever thread asks then, and only renders of many samples a pixel ask
//! (`render::HORIZON_SAMPLES`): a bound costs about as much as a few hundred shadow rays.
//! It is found by walking the tree best first from the triangle outwards, each subtree bounded
//! by its box and by the disk of its triangles ([`Disk`]), so that the few pieces that make
//! the horizon are met early and the rest is passed over. It covers:
//! - the ray's origin: the hit point moved by the shadow-ray epsilon along the lit normal,
//!   which must be within [`LEAST_COSINE`] of the side's geometric normal; so the origin
//!   stands at least `0.9 ε` above the plane, and at most `0.436 ε` beside the triangle;
//! - every other piece of geometry: the world tree must hold the whole scene (checked by the
//!   caller, [`super::Accel::horizons`]). The tree's boxes bound whole subtrees; a triangle
//!   near the origin is split into up to 4^[`MAX_DEPTH`] pieces, so that the low parts of a
//!   neighbour do not count as high; and a triangle whose plane has every origin on one side
//!   blocks, in each wedge, no ray climbing more steeply than that plane
//!   ([`Horizons::plane_bound`]), so that a neighbour rising from the triangle's edge bounds
//!   the horizon by its slope instead of closing it;
//! - the precision of the walk: the triangles are the tree's own `f32` values, positions are
//!   widened by a tolerance of `1e-6` of the scene's largest coordinate, azimuth sectors by
//!   [`AZIMUTH_PAD`] radians, and sines by [`SINE_MARGIN`].
//!
//! A point of a piece at height `h` above the plane and horizontal distance at least `d` from
//! any origin can only be met by a ray of elevation `e` with `tan e <= (h - h_origin) / d`; a
//! piece entirely below the lowest origin cannot be met by a ray that climbs.

// `!(a > b)` is meant wherever it stands: a NaN bound must fail the test it is put to.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

use glam::{DVec2, DVec3};

use super::bvh8::Bvh8;

/// The least cosine between a lit point's normal (along which its shadow rays' origin is
/// moved off the surface) and its triangle's geometric normal on that side for a horizon to
/// answer: steeper normals (a bump map's, a smooth normal far from its face) trace.
const LEAST_COSINE: f64 = 0.9;
/// Most triangle ids a world tree may have for its horizons to be kept: about 72 bytes a
/// triangle (its two entries, frame and slot, 56, and the disks of its tree's slots), so 75 MB
/// at most.
const MAX_TRIANGLES: u32 = 1 << 20;
/// A sector's byte `b` lets a direction through when its sine of elevation exceeds
/// `b / STEPS`; [`NEVER`] lets nothing through.
const STEPS: f64 = 253.0;
const NEVER: u64 = 253;
/// An entry that lets nothing through.
const ALL_NEVER: u64 = 0xFDFD_FDFD_FDFD_FDFD;
/// The top byte of an entry not yet computed (a computed entry's bytes are at most
/// [`NEVER`]); its low bits count the queries so far.
const UNKNOWN: u64 = 0xFF << 56;
/// Queries of a triangle's side before its horizon is computed: a triangle seen by a few
/// samples only is cheaper to trace than to bound.
const QUERIES_BEFORE: u64 = 24;
/// How many times a triangle near the origin is split in four, at most.
const MAX_DEPTH: u32 = 2;
/// Radians added on each side of a piece's azimuth range.
const AZIMUTH_PAD: f64 = 1e-4 + ANGLE_ERROR;
/// Added to each sector's sine before it is rounded up.
const SINE_MARGIN: f64 = 1e-4;
/// Directions within about 0.8° of a triangle's normal are let through only above every
/// sector (their azimuth is ill-conditioned).
const NEAR_NORMAL: f64 = 0.9999;
/// A horizon whose every wedge is this steep (76°) lets so little through that its side is
/// stored as letting nothing through, and its walk ends.
const TAN_USELESS: f64 = 4.0;
/// The lowest horizon kept (about 6°): directions that low are few, and the pieces that would
/// set a lower one (the tops of boxes beside a curved surface) are many.
const TAN_FLOOR: f64 = 0.1;

/// The lazily computed horizons of a world tree's triangles, for one shadow-ray epsilon.
pub struct Horizons {
    /// The lowest height above its triangle's plane at which a ray can meet anything.
    floor: f64,
    /// How far beside its triangle an origin may stand, widened by two tolerances.
    reach: f64,
    /// The greatest height above its triangle's plane an origin may have.
    ceiling: f64,
    /// The tolerance of positions: 1e-6 of the scene's largest coordinate.
    tol: f64,
    /// Where each id's triangle is in the tree ([`Bvh8::triangle_slots`]).
    slots: Vec<u32>,
    /// Each id's frame: the unit geometric normal, the unit first edge and their cross
    /// product, in `f32` (what both the bound and the query read, so they agree to the bit);
    /// zero for a degenerate triangle or an id the tree does not hold.
    frames: Vec<[f32; 9]>,
    /// Front and back entries of each id.
    table: Vec<[AtomicU64; 2]>,
    /// Each child slot's disk ([`Bvh8::children`] numbers them), zero for empty slots.
    disks: Vec<Disk>,
}

/// What a subtree holds, bounded as a disk: a ball (centre `c`, radius `r`) cut to a slab of
/// half-thickness `t` about the plane through `c` with unit normal `m`, the subtree's
/// area-weighted mean normal. A patch of a surface is much thinner than its box, whose corners
/// stand above the plane of a triangle beside the patch.
#[derive(Clone, Copy, Default)]
struct Disk {
    c: DVec3,
    m: DVec3,
    r: f64,
    t: f64,
}

impl Disk {
    /// The disk of a subtree's triangles.
    fn of(tree: &Bvh8, child: u32, lo: [f32; 3], hi: [f32; 3]) -> Disk {
        let v = |a: [f32; 3]| DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64);
        let c = (v(lo) + v(hi)) * 0.5;
        let mut sum = DVec3::ZERO;
        tree.subtree_triangles(child, &mut |t| sum += v(t[1]).cross(v(t[2])));
        let m = sum.normalize_or_zero();
        let (mut r, mut h) = (0.0f64, 0.0f64);
        tree.subtree_triangles(child, &mut |t| {
            let p0 = v(t[0]);
            for p in [p0, p0 + v(t[1]), p0 + v(t[2])] {
                r = r.max((p - c).length());
                h = h.max((p - c).dot(m).abs());
            }
        });
        // Rounded outwards: the bound must hold the vertices themselves.
        let widen = 1.0 + 1e-12;
        Disk { c, m, r: r * widen + 1e-300, t: h * widen + 1e-300 }
    }

    /// Its greatest extent along unit vector `n`: at most `t·|m·n| + r·sqrt(1 - (m·n)²)`.
    fn extent(&self, n: DVec3) -> f64 {
        let k = self.m.dot(n).abs().min(1.0);
        self.t * k + self.r * (1.0 - k * k).sqrt()
    }
}

/// A triangle's frame on one side: vertex 0, the unit normal of that side, the unit first
/// edge and the third axis; its vertices in the plane's coordinates.
struct Frame {
    a: DVec3,
    n: DVec3,
    t1: DVec3,
    t2: DVec3,
    flat: [DVec2; 3],
    /// The centroid in the plane, and the radius about it that holds every origin.
    centre: DVec2,
    radius: f64,
}

impl Frame {
    /// Point `p`'s coordinates in the triangle's plane (vertex 0 at the origin).
    fn flat_of(&self, p: DVec3) -> DVec2 {
        let w = p - self.a;
        DVec2::new(w.dot(self.t1), w.dot(self.t2))
    }
}

/// The frame of a tree triangle (see [`Horizons::frames`]), zero when it is degenerate.
fn frame_of(t: &[[f32; 3]; 3]) -> [f32; 9] {
    let e1 = DVec3::new(t[1][0] as f64, t[1][1] as f64, t[1][2] as f64);
    let e2 = DVec3::new(t[2][0] as f64, t[2][1] as f64, t[2][2] as f64);
    let c = e1.cross(e2);
    let (len, l1) = (c.length(), e1.length());
    if !(len > 0.0 && len.is_finite() && l1 > 0.0) {
        return [0.0; 9];
    }
    let (g, t1) = ((c / len).as_vec3(), (e1 / l1).as_vec3());
    let t2 = g.cross(t1);
    [g.x, g.y, g.z, t1.x, t1.y, t1.z, t2.x, t2.y, t2.z]
}

/// The axes of a stored frame, in `f64`: normal, first edge, their cross product.
#[inline(always)]
fn axes(f: &[f32; 9]) -> (DVec3, DVec3, DVec3) {
    let v = |i: usize| DVec3::new(f[i] as f64, f[i + 1] as f64, f[i + 2] as f64);
    (v(0), v(3), v(6))
}

/// The sector code of a direction with coordinates (`x`, `y`) in a frame's plane: which of
/// eight 45° wedges, by three comparisons.
#[inline(always)]
fn code(x: f64, y: f64) -> usize {
    (usize::from(x > 0.0) << 2) | (usize::from(y > 0.0) << 1) | usize::from(x.abs() > y.abs())
}

/// The code of the wedge between `k·45°` and `(k+1)·45°` from the first axis.
fn wedge_code(k: usize) -> usize {
    let psi = (k as f64 + 0.5) * std::f64::consts::FRAC_PI_4;
    code(psi.cos(), psi.sin())
}

impl Horizons {
    /// Horizons for `tree`, whose shadow rays leave their points `epsilon` along the lit
    /// normal; `None` when the tree is empty or too large, or the epsilon too small against
    /// the precision of the scene's coordinates.
    pub(super) fn new(tree: &Bvh8, epsilon: f64) -> Option<Horizons> {
        if tree.is_empty() || !(epsilon.is_finite() && epsilon > 0.0) {
            return None;
        }
        let largest = tree.bounds().iter().fold(0.0f64, |m, &v| m.max((v as f64).abs()));
        let tol = 1e-6 * largest + 1e-30;
        let floor = LEAST_COSINE * epsilon - 3.0 * tol;
        if !(floor > 0.5 * LEAST_COSINE * epsilon) {
            return None;
        }
        let beside = epsilon * (1.0 + 1e-9 - LEAST_COSINE * LEAST_COSINE).sqrt();
        let slots = tree.triangle_slots(MAX_TRIANGLES)?;
        let frames = slots
            .iter()
            .map(|&s| if s == u32::MAX { [0.0; 9] } else { frame_of(&tree.triangle(s)) })
            .collect();
        let table = (0..slots.len()).map(|_| [AtomicU64::new(UNKNOWN), AtomicU64::new(UNKNOWN)]).collect();
        let mut disks = vec![Disk::default(); tree.slot_count()];
        let mut todo: Vec<u32> = tree.root().into_iter().collect();
        while let Some(cur) = todo.pop() {
            tree.children(cur, |lo, hi, child, index| {
                disks[index] = Disk::of(tree, child, lo, hi);
                if !Bvh8::is_leaf(child) {
                    todo.push(child);
                }
            });
        }
        let ceiling = epsilon * (1.0 + 1e-9) + 3.0 * tol;
        Some(Horizons { floor, reach: beside + 3.0 * tol, ceiling, tol, slots, frames, table, disks })
    }

    /// How many triangle sides have had their horizon bounded so far.
    pub fn bounded(&self) -> usize {
        self.table.iter().flatten().filter(|c| c.load(Relaxed) >> 56 != 0xFF).count()
    }

    /// Whether a shadow ray in unit direction `d`, leaving the point of triangle `id` of
    /// `tree` at the shadow-ray epsilon along the unit lit normal `n`, certainly reaches
    /// infinity unblocked. False whenever it cannot tell (the ray is then traced).
    #[inline(always)]
    pub(super) fn clear(&self, tree: &Bvh8, id: u32, n: DVec3, d: DVec3) -> bool {
        let (Some(frame), Some(cells)) = (self.frames.get(id as usize), self.table.get(id as usize)) else {
            return false;
        };
        let (g, t1, t2) = axes(frame);
        let ng = n.dot(g);
        let back = ng < 0.0;
        let sign = if back { -1.0 } else { 1.0 };
        let up = sign * d.dot(g);
        // A degenerate triangle's zero normal fails the first test.
        if !(ng.abs() >= LEAST_COSINE && up > 0.0 && n.length_squared() <= 1.0 + 1e-9) {
            return false;
        }
        let cell = &cells[usize::from(back)];
        let mut bytes = cell.load(Relaxed);
        if bytes >> 56 == 0xFF {
            let asked = bytes & !UNKNOWN;
            if asked + 1 < QUERIES_BEFORE {
                cell.store(bytes + 1, Relaxed);
                return false;
            }
            bytes = self.compute(tree, id, back);
            cell.store(bytes, Relaxed);
        }
        let b = if up > NEAR_NORMAL {
            (0..8).map(|k| (bytes >> (8 * k)) & 0xFF).max().unwrap_or(NEVER)
        } else {
            (bytes >> (8 * code(d.dot(t1), sign * d.dot(t2)))) & 0xFF
        };
        b < NEVER && up * STEPS > b as f64
    }

    /// The eight sector bytes of a triangle's side: the tree walked best first (the boxes
    /// that may raise the horizon most, those around the triangle before all), so that the
    /// few pieces that make the horizon are met early and the rest is pruned.
    #[cold]
    #[inline(never)]
    fn compute(&self, tree: &Bvh8, id: u32, back: bool) -> u64 {
        let tri = tree.triangle(self.slots[id as usize]);
        let (g, t1, t2) = axes(&self.frames[id as usize]);
        let (n, t2) = if back { (-g, -t2) } else { (g, t2) };
        let a = DVec3::new(tri[0][0] as f64, tri[0][1] as f64, tri[0][2] as f64);
        let flat_of = |e: &[f32; 3]| {
            let e = DVec3::new(e[0] as f64, e[1] as f64, e[2] as f64);
            DVec2::new(e.dot(t1), e.dot(t2))
        };
        let flat = [DVec2::ZERO, flat_of(&tri[1]), flat_of(&tri[2])];
        let centre = (flat[0] + flat[1] + flat[2]) / 3.0;
        let radius = flat.iter().map(|v| (*v - centre).length()).fold(0.0, f64::max) + self.reach;
        let frame = Frame { a, n, t1, t2, flat, centre, radius };
        let mut tan = [TAN_FLOOR; 8];
        let mut heap = std::collections::BinaryHeap::with_capacity(64);
        if let Some(root) = tree.root() {
            heap.push(Pending { key: f64::INFINITY, sectors: 0xFF, node: root });
        }
        while let Some(e) = heap.pop() {
            if !raises(&tan, e.key, e.sectors) {
                continue;
            }
            if Bvh8::is_leaf(e.node) {
                let mut blocked = false;
                tree.leaf_triangles(e.node, |t| {
                    let p0 = DVec3::new(t[0][0] as f64, t[0][1] as f64, t[0][2] as f64);
                    let p1 = p0 + DVec3::new(t[1][0] as f64, t[1][1] as f64, t[1][2] as f64);
                    let p2 = p0 + DVec3::new(t[2][0] as f64, t[2][1] as f64, t[2][2] as f64);
                    self.piece(&frame, [p0, p1, p2], 0, None, &mut tan, &mut blocked);
                });
                if blocked || tan.iter().all(|&t| t >= TAN_USELESS) {
                    return ALL_NEVER;
                }
            } else {
                tree.children(e.node, |lo, hi, child, index| {
                    let lo = DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64);
                    let hi = DVec3::new(hi[0] as f64, hi[1] as f64, hi[2] as f64);
                    let (c, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
                    let disk = &self.disks[index];
                    let top = ((c - frame.a).dot(frame.n) + half.abs().dot(frame.n.abs()))
                        .min((disk.c - frame.a).dot(frame.n) + disk.extent(frame.n));
                    match self.bound(&frame, c, half.length().min(disk.r), Some((half, disk)), top, &tan) {
                        Bound::Below => {}
                        Bound::Near => heap.push(Pending { key: f64::INFINITY, sectors: 0xFF, node: child }),
                        Bound::Rises(t, sectors) => {
                            if raises(&tan, t, sectors) {
                                heap.push(Pending { key: t, sectors, node: child });
                            }
                        }
                    }
                });
            }
        }
        let mut bytes = 0u64;
        for (k, &t) in tan.iter().enumerate() {
            let t = lifted(t);
            let sine = if t.is_finite() { t / (1.0 + t * t).sqrt() } else { 1.0 };
            let b = ((sine + SINE_MARGIN) * STEPS).ceil().clamp(0.0, NEVER as f64) as u64;
            bytes |= b << (8 * wedge_code(k));
        }
        bytes
    }

    /// Bounds a triangle piece, splitting it in four where that may lower what it raises.
    /// `plane`, when known, bounds in each wedge what the piece's whole plane can block
    /// ([`Horizons::plane_bound`]).
    fn piece(
        &self,
        f: &Frame,
        p: [DVec3; 3],
        depth: u32,
        plane: Option<&[f64; 8]>,
        tan: &mut [f64; 8],
        blocked: &mut bool,
    ) {
        if *blocked {
            return;
        }
        let top = p.iter().map(|&q| (q - f.a).dot(f.n)).fold(f64::NEG_INFINITY, f64::max);
        if !(top > self.floor) {
            // NaN vertices make no piece (the walk never meets them either).
            return;
        }
        let c = (p[0] + p[1] + p[2]) / 3.0;
        let r = p.iter().map(|&q| (q - c).length()).fold(0.0, f64::max);
        let bound = self.bound(f, c, r, None, top, tan);
        if let Bound::Below = bound {
            return;
        }
        // A whole triangle that may raise something: its plane's bound, which its pieces share.
        let own;
        let plane = if depth == 0 {
            own = self.plane_bound(f, p);
            match &own {
                Some(pt) if !raises_each(tan, pt, 0xFF) => return,
                o => o.as_ref(),
            }
        } else {
            plane
        };
        let split = |tan: &mut [f64; 8], blocked: &mut bool| {
            let m = [(p[0] + p[1]) * 0.5, (p[1] + p[2]) * 0.5, (p[2] + p[0]) * 0.5];
            for q in [[p[0], m[0], m[2]], [m[0], p[1], m[1]], [m[2], m[1], p[2]], [m[0], m[1], m[2]]] {
                self.piece(f, q, depth + 1, plane, tan, blocked);
            }
        };
        // What the piece raises each wedge to: `t` in `sectors`, no more than its plane allows.
        let raise = |tan: &mut [f64; 8], t: f64, sectors: u8| {
            for (k, v) in tan.iter_mut().enumerate() {
                if sectors & (1 << k) != 0 {
                    *v = v.max(plane.map_or(t, |pt| t.min(pt[k])));
                }
            }
        };
        match bound {
            Bound::Below => {}
            Bound::Near if depth < MAX_DEPTH => split(tan, blocked),
            Bound::Near => match plane {
                Some(_) => raise(tan, f64::INFINITY, 0xFF),
                None => *blocked = true,
            },
            Bound::Rises(t, sectors) => {
                let lowered = plane.map(|pt| pt.map(|v| v.min(t)));
                if !raises_each(tan, lowered.as_ref().unwrap_or(&[t; 8]), sectors) {
                    return;
                }
                if depth < MAX_DEPTH && r > 0.2 * self.gap(f, c, r) {
                    split(tan, blocked);
                } else {
                    raise(tan, t, sectors);
                }
            }
        }
    }

    /// What the plane of a triangle `p` can block, in each wedge: when every origin stands on
    /// one side of that plane, at least a few tolerances off it, a ray that does not turn
    /// towards the plane never meets it. Along azimuth `φ`, with the side's unit normal `m`
    /// (pointing at the origins) in the frame's coordinates, the ray of elevation `e` turns
    /// away when `cos e·(m_x cos φ + m_y sin φ) + m_z sin e >= 0`, that is when `tan e >=
    /// -(m_x cos φ + m_y sin φ) / m_z`; the wedge's bound is the greatest of that over its
    /// azimuths, widened by [`AZIMUTH_PAD`]. `None` when the origins straddle the plane or it
    /// is too steep to bound anything.
    fn plane_bound(&self, f: &Frame, p: [DVec3; 3]) -> Option<[f64; 8]> {
        let m = (p[1] - p[0]).cross(p[2] - p[0]);
        let len = m.length();
        if !(len > 0.0 && len.is_finite()) {
            return None;
        }
        let m = m / len;
        let (mx, my, mz) = (m.dot(f.t1), m.dot(f.t2), m.dot(f.n));
        // The signed distance of an origin from the plane is linear over where origins may
        // be: the triangle widened by `reach`, between `floor` and `ceiling` above it.
        let base = (f.a - p[0]).dot(m);
        let at = f.flat.map(|v| base + v.x * mx + v.y * my);
        let beside = self.reach * mx.hypot(my);
        let least = at.iter().fold(f64::INFINITY, |a, &b| a.min(b)) - beside;
        let most = at.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b)) + beside;
        let (h0, h1) = (self.floor * mz, self.ceiling * mz);
        let margin = 4.0 * self.tol;
        let s = if least + h0.min(h1) > margin {
            1.0
        } else if most + h0.max(h1) < -margin {
            -1.0
        } else {
            return None;
        };
        let (sx, sy, sz) = (s * mx, s * my, s * mz);
        if !(sz >= 0.05) {
            return None;
        }
        let peak = angle(DVec2::new(-sx, -sy));
        let most_tan = (sx * sx + sy * sy).sqrt() / sz;
        // At the wedges' edges `k·45°`; the padding can raise a wedge's greatest value by at
        // most the slope's bound times the pad.
        const C: [f64; 9] = [1.0, R, 0.0, -R, -1.0, -R, 0.0, R, 1.0];
        const S: [f64; 9] = [0.0, R, 1.0, R, 0.0, -R, -1.0, -R, 0.0];
        const R: f64 = std::f64::consts::FRAC_1_SQRT_2;
        let edge: [f64; 9] = std::array::from_fn(|k| -(sx * C[k] + sy * S[k]) / sz);
        let pad = most_tan * AZIMUTH_PAD + 1e-9;
        let half = 0.5 * std::f64::consts::FRAC_PI_4 + AZIMUTH_PAD;
        Some(std::array::from_fn(|k| {
            let mid = (k as f64 + 0.5) * std::f64::consts::FRAC_PI_4;
            let inside = wrap(peak - mid).abs() <= half;
            (if inside { most_tan } else { edge[k].max(edge[k + 1]) }) + pad
        }))
    }

    /// The least horizontal distance between a ball (centre `c`, radius `r`) and any origin.
    fn gap(&self, f: &Frame, c: DVec3, r: f64) -> f64 {
        distance_to_triangle(f.flat_of(c), &f.flat) - r - self.reach
    }

    /// What a ball (centre `c`, radius `r`) whose highest point is `top` above the plane can
    /// block: nothing above the wedges' horizons `tan`, anything, or rays up to an elevation's
    /// tangent in some sectors. The sectors are those seen from the triangle's three widened
    /// vertices for a piece of a triangle, and for a subtree (`boxed`: its box's half extents
    /// and its disk) from a disk around the whole triangle (one arc tangent, not three).
    fn bound(
        &self,
        f: &Frame,
        c: DVec3,
        r: f64,
        boxed: Option<(DVec3, &Disk)>,
        top: f64,
        tan: &[f64; 8],
    ) -> Bound {
        if !(top > self.floor) {
            return Bound::Below;
        }
        let q = f.flat_of(c);
        let mut gap = self.gap(f, c, r);
        if let Some((half, disk)) = boxed
            && !(gap > 0.0)
        {
            // A box (half extents `half`) is often much flatter than its ball: along the
            // horizontal axis from the triangle's centroid to its centre, its extent is
            // Σ|u_i|·half_i, and the triangle's its vertices' furthest.
            let to = q - f.centre;
            let len = to.length();
            if len > 0.0 {
                let u2 = to / len;
                let u = f.t1 * u2.x + f.t2 * u2.y;
                let own = f.flat.iter().map(|v| (*v - f.centre).dot(u2)).fold(f64::NEG_INFINITY, f64::max);
                let across = u.abs().dot(half).min(disk.extent(u));
                gap = gap.max(len - across - own - self.reach);
            }
        }
        if !(gap > 0.0) {
            return Bound::Near;
        }
        let t = (top - self.floor) / gap;
        if !raises(tan, t, 0xFF) {
            // Not even in every sector: its azimuths need not be found.
            return Bound::Below;
        }
        if boxed.is_some() {
            let to = q - f.centre;
            let len = to.length();
            let widen = r + f.radius;
            if !(len > widen) {
                return Bound::Rises(t, 0xFF);
            }
            let (mid, half) = (angle(to), arcsine_above(widen / len) + AZIMUTH_PAD);
            return Bound::Rises(t, sectors_of(mid, half));
        }
        // The azimuths from any origin (the triangle widened by `reach`) to the ball: the span
        // of the three vertices' widened cones, measured from the direction to vertex 0.
        let widen = r + self.reach;
        let base = angle(q - f.flat[0]);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in &f.flat {
            let to = q - *v;
            let len = to.length();
            let spread = arcsine_above((widen / len).min(1.0));
            let rel = wrap(angle(to) - base);
            lo = lo.min(rel - spread);
            hi = hi.max(rel + spread);
        }
        let (lo, hi) = (base + lo - AZIMUTH_PAD, base + hi + AZIMUTH_PAD);
        Bound::Rises(t, sectors_of((lo + hi) * 0.5, (hi - lo) * 0.5))
    }
}

/// See [`Horizons::bound`].
enum Bound {
    /// Nothing that would raise a wedge: below the lowest origin, or too low or far.
    Below,
    Near,
    /// The tangent of the highest elevation, and the sectors (by wedge) it applies in.
    Rises(f64, u8),
}

/// The wedges an azimuth range (centre `mid`, half-width `half`) meets, as a mask: wedge `k`
/// spans `k·45°` to `(k+1)·45°`, closed, so a range touching a boundary takes both wedges.
fn sectors_of(mid: f64, half: f64) -> u8 {
    let q = std::f64::consts::FRAC_PI_4;
    // Widened past the rounding of the divisions below, so that a range ending on a boundary
    // takes the wedge beyond it too.
    let half = half + 1e-9;
    if !(half < 3.0 * q) {
        return 0xFF;
    }
    // The first and last wedge the range meets.
    let start = (mid - half) / q;
    let first = start.floor();
    let last = ((mid + half) / q).floor();
    let count = (last - first) as u32 + 1;
    let first = first.rem_euclid(8.0) as u32;
    let run = ((1u32 << count.min(8)) - 1) as u8;
    run.rotate_left(first)
}

/// A wedge's tangent as stored: a little above the highest found, so that a piece whose
/// tangent is below it may be passed over ([`raises`]) and the horizon stays a bound.
fn lifted(t: f64) -> f64 {
    t * 1.1 + 0.05
}

/// Whether tangent `t` over wedges `sectors` would raise some wedge's stored horizon.
fn raises(tan: &[f64; 8], t: f64, sectors: u8) -> bool {
    raises_each(tan, &[t; 8], sectors)
}

/// Whether raising wedges `sectors` to `t[k]` each would raise some wedge's stored horizon.
fn raises_each(tan: &[f64; 8], t: &[f64; 8], sectors: u8) -> bool {
    (0..8).any(|k| sectors & (1 << k) != 0 && t[k] > lifted(tan[k]))
}

/// A subtree still to be walked, with what it may raise: a key of infinity for the subtrees
/// around the triangle.
struct Pending {
    key: f64,
    sectors: u8,
    node: u32,
}

impl PartialEq for Pending {
    fn eq(&self, other: &Self) -> bool {
        self.key.total_cmp(&other.key).is_eq()
    }
}
impl Eq for Pending {}
impl PartialOrd for Pending {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Pending {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.key.total_cmp(&other.key)
    }
}

/// The azimuth of `v`, to within [`ANGLE_ERROR`].
fn angle(v: DVec2) -> f64 {
    crate::math::atan2_approx(v.y, v.x)
}

/// More than the error of [`angle`] (1.4e-10 radians), added to every azimuth range.
const ANGLE_ERROR: f64 = 1e-9;

/// An upper bound of `asin(x)` for `x` in [0, 1] that needs no library call: `(asin(x) - x)
/// / x³` grows from 1/6 to `π/2 - 1` there (its series' coefficients are all positive), so
/// `asin(x) <= x + (π/2 - 1)·x³`, equal at 0 and 1.
fn arcsine_above(x: f64) -> f64 {
    x + (std::f64::consts::FRAC_PI_2 - 1.0) * x * x * x
}

/// An angle brought into [-π, π].
fn wrap(a: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    a - tau * (a / tau).round()
}

/// The distance from `q` to the triangle `t` in the plane (zero inside).
fn distance_to_triangle(q: DVec2, t: &[DVec2; 3]) -> f64 {
    let side = |a: DVec2, b: DVec2| (b - a).perp_dot(q - a);
    let (s0, s1, s2) = (side(t[0], t[1]), side(t[1], t[2]), side(t[2], t[0]));
    if (s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0) || (s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0) {
        return 0.0;
    }
    let seg = |a: DVec2, b: DVec2| {
        let ab = b - a;
        let l2 = ab.length_squared();
        let s = if l2 > 0.0 { ((q - a).dot(ab) / l2).clamp(0.0, 1.0) } else { 0.0 };
        (q - (a + ab * s)).length()
    };
    seg(t[0], t[1]).min(seg(t[1], t[2])).min(seg(t[2], t[0]))
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use glam::DVec3;

    use super::{QUERIES_BEFORE, sectors_of, wrap};
    use crate::geometry::{Accel, Instance, MeshGeom, ObjectTextures, Shape};
    use crate::math::Ray;

    /// A lumpy ball: a UV sphere of radius `radius` at `centre` whose every vertex is moved
    /// along its radius by up to `lumps` (random) and a bulge on one side, so that its surface
    /// has creases and hollows of every size.
    fn lumpy(centre: DVec3, radius: f64, lumps: f64, r: &mut impl FnMut() -> f64) -> Arc<MeshGeom> {
        let (rings, segments) = (24, 48);
        let mut positions = Vec::new();
        for i in 0..=rings {
            let theta = std::f64::consts::PI * i as f64 / rings as f64;
            for j in 0..segments {
                let phi = std::f64::consts::TAU * j as f64 / segments as f64;
                let dir = DVec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin());
                let bulge = 0.4 * (-(dir - DVec3::X).length_squared() * 8.0).exp();
                let k = if i == 0 || i == rings { 0.0 } else { lumps * (r() * 2.0 - 1.0) };
                positions.push(centre + dir * (radius * (1.0 + bulge) + k));
            }
        }
        let mut faces = Vec::new();
        for i in 0..rings {
            for j in 0..segments {
                let (a, b) = ((i * segments + j) as u32, (i * segments + (j + 1) % segments) as u32);
                let (c, d) = (a + segments as u32, b + segments as u32);
                faces.push([a, c, b]);
                faces.push([b, c, d]);
            }
        }
        Arc::new(MeshGeom::new(positions, faces, None))
    }

    fn mesh(mesh: u32) -> Instance {
        Instance {
            shape: Shape::Mesh { mesh, smooth: true },
            material: 0,
            transform: None,
            motion: None,
            textures: ObjectTextures::default(),
        }
    }

    /// The property horizons rest on: a shadow ray the horizon lets through is one the walk
    /// finds unblocked. Two lumpy balls side by side (one tree of both, each shading the
    /// other), camera-like hits from every side, lit normals leaning up to the least cosine,
    /// and random directions; after the warm-up queries, a good share of rays must be let
    /// through, or the test would prove nothing.
    #[test]
    fn a_ray_above_the_horizon_is_never_blocked() {
        let mut rng = crate::sampler::Sampler::new(7, 1, 2, 3);
        let mut r = move || rng.next_1d();
        let meshes =
            vec![lumpy(DVec3::ZERO, 1.0, 0.003, &mut r), lumpy(DVec3::new(2.6, 0.3, 0.0), 0.8, 0.01, &mut r)];
        let accel = Accel::new(meshes, vec![mesh(0), mesh(1)]);
        let eps = 1e-3;
        let horizons = accel.horizons(eps).expect("the world tree holds the whole scene");
        let unit = |r: &mut dyn FnMut() -> f64| {
            let z: f64 = r() * 2.0 - 1.0;
            let phi = std::f64::consts::TAU * r();
            let s = (1.0 - z * z).max(0.0).sqrt();
            DVec3::new(s * phi.cos(), s * phi.sin(), z)
        };
        let (mut asked, mut let_through, mut points) = (0usize, 0usize, 0usize);
        while points < 300 {
            // A ray from afar at a point near either ball.
            let target = if r() < 0.5 { DVec3::ZERO } else { DVec3::new(2.6, 0.3, 0.0) } + unit(&mut r) * 0.5;
            let from = target + unit(&mut r) * 6.0;
            let ray = Ray::new(from, (target - from).normalize());
            let Some(hit) = accel.intersect(&ray, 1e-6, f64::INFINITY) else { continue };
            assert_ne!(hit.world, u32::MAX, "a world-tree hit says which triangle");
            points += 1;
            // The lit normal on the viewer's side, leant at random (some beyond the least cosine).
            let facing = if hit.geo_normal.dot(ray.dir) < 0.0 { hit.geo_normal } else { -hit.geo_normal };
            let n = (facing + unit(&mut r) * 0.5 * r() * r()).normalize();
            let origin = hit.point + eps * n;
            for _ in 0..(QUERIES_BEFORE as usize + 200) {
                let d = unit(&mut r);
                if n.dot(d) <= 0.0 {
                    continue;
                }
                asked += 1;
                if accel.horizon_clear(&horizons, hit.world, n, d) {
                    let_through += 1;
                    let shadow = Ray::new(origin, d);
                    assert!(
                        !accel.occluded(&shadow, 1e-6, f64::INFINITY),
                        "let through but blocked: point {:?}, normal {n:?}, direction {d:?}",
                        hit.point
                    );
                }
            }
        }
        assert!(let_through * 4 > asked, "only {let_through} of {asked} rays let through");
    }

    /// A valley: a floor meeting a wall that rises at 35°. Seen from the floor beside the crease,
    /// the wall's nearest pieces touch the origins, so no distance bounds them; their plane
    /// does: a ray climbing more steeply than the wall, towards it, passes over it. Such rays
    /// are let through, and no ray let through is blocked.
    #[test]
    fn a_valley_lets_through_what_climbs_over_its_wall() {
        let slope = 35f64.to_radians().tan();
        let (cells, mut positions, mut faces) = (8u32, Vec::new(), Vec::new());
        // Rows of vertices along x from -1 to 1, the wall's height x·slope beyond the crease.
        for i in 0..=cells {
            let x = -1.0 + 2.0 * i as f64 / cells as f64;
            for j in 0..=cells {
                let y = -1.0 + 2.0 * j as f64 / cells as f64;
                positions.push(DVec3::new(x, y, x.max(0.0) * slope));
            }
        }
        for i in 0..cells {
            for j in 0..cells {
                let a = i * (cells + 1) + j;
                let (b, c, d) = (a + 1, a + cells + 1, a + cells + 2);
                faces.push([a, c, b]);
                faces.push([b, c, d]);
            }
        }
        let accel = Accel::new(vec![Arc::new(MeshGeom::new(positions, faces, None))], vec![mesh(0)]);
        let eps = 1e-3;
        let horizons = accel.horizons(eps).expect("the world tree holds the whole scene");
        let up = DVec3::Z;
        let (mut over, mut let_through) = (0, 0);
        for p in [DVec3::new(-0.1, 0.05, 1.0), DVec3::new(-0.2, -0.3, 1.0), DVec3::new(-0.05, 0.6, 1.0)] {
            let hit = accel.intersect(&Ray::new(p, -up), 1e-6, f64::INFINITY).expect("the floor");
            assert_ne!(hit.world, u32::MAX);
            let origin = hit.point + eps * up;
            for _ in 0..QUERIES_BEFORE {
                accel.horizon_clear(&horizons, hit.world, up, DVec3::new(0.6, 0.0, 0.8));
            }
            for step in 0..=90 {
                for azimuth in [-20.0f64, 0.0, 15.0, 180.0] {
                    let (e, a) = ((step as f64).to_radians(), azimuth.to_radians());
                    let d = DVec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
                    if !accel.horizon_clear(&horizons, hit.world, up, d) {
                        continue;
                    }
                    let_through += 1;
                    assert!(
                        !accel.occluded(&Ray::new(origin, d), 1e-6, f64::INFINITY),
                        "let through but blocked: from {origin:?} along {d:?}"
                    );
                    if azimuth == 0.0 {
                        assert!(e.tan() > slope, "{step}° towards the wall is let through");
                        over += 1;
                    }
                }
            }
        }
        // Towards the wall (three azimuths), from about 50° up (its 35°, the margins, a byte's
        // rounding); away from it, from about 10° up.
        assert!(over >= 3 * 35, "only {over} rays over the wall let through");
        assert!(let_through > 3 * (3 * 35 + 75), "only {let_through} rays let through");
    }

    /// The wedge mask of an azimuth range is every wedge the closed range meets.
    #[test]
    fn sectors_are_the_wedges_a_range_meets() {
        let mut rng = crate::sampler::Sampler::new(9, 1, 2, 3);
        let q = std::f64::consts::FRAC_PI_4;
        for i in 0..20_000 {
            let (mid, half) = if i % 4 == 0 {
                // On and beside wedge boundaries.
                ((rng.next_1d() * 16.0).round() * q * 0.5 - 3.0 * q, (rng.next_1d() * 6.0).round() * q * 0.5)
            } else {
                (rng.next_1d() * 20.0 - 10.0, rng.next_1d() * 2.0)
            };
            let mut expected = 0u8;
            for k in 0..8 {
                let centre = (k as f64 + 0.5) * q;
                if half >= 3.0 * q || wrap(mid - centre).abs() <= half + q * 0.5 + 1e-12 {
                    expected |= 1 << k;
                }
            }
            let got = sectors_of(mid, half);
            assert_eq!(
                got & expected,
                expected,
                "mid {mid}, half {half}: {got:08b} lacks some of {expected:08b}"
            );
        }
    }

    /// A world tree beside objects outside it (a sphere) has no horizons: they would not see it.
    #[test]
    fn no_horizons_when_the_tree_is_not_the_whole_scene() {
        let mut rng = crate::sampler::Sampler::new(5, 1, 2, 3);
        let mut r = move || rng.next_1d();
        let ball = Instance {
            shape: Shape::Sphere { center: DVec3::new(0.0, 3.0, 0.0), radius: 1.0 },
            material: 0,
            transform: None,
            motion: None,
            textures: ObjectTextures::default(),
        };
        let accel = Accel::new(vec![lumpy(DVec3::ZERO, 1.0, 0.02, &mut r)], vec![mesh(0), ball]);
        assert!(accel.horizons(1e-3).is_none());
        let alone = Accel::new(vec![lumpy(DVec3::ZERO, 1.0, 0.02, &mut r)], vec![mesh(0)]);
        assert!(alone.horizons(1e-3).is_some());
        assert!(alone.horizons(0.0).is_none() && alone.horizons(f64::NAN).is_none());
    }
}
