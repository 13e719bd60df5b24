//! The BVH's node and leaf layouts and the eight-wide tests a walk makes on them: a ray
//! against a node's eight child boxes, and against a leaf's triangle packets (AVX2 and FMA, with
//! a scalar fallback for other targets).
//!
//! [`super`] builds the tree and walks it; everything here is one test of one node or one leaf,
//! with no memory of the walk.

use glam::Vec3A;

/// Eight child boxes as planes: `b[0..3]` the minima (x, y, z), `b[3..6]` the maxima. Empty
/// slots have min = +inf and max = -inf, which no ray can enter (no NaN: see [`Ray8`]).
#[derive(Clone, Copy)]
#[repr(C, align(32))]
pub(super) struct Node {
    pub(super) b: [[f32; 8]; 6],
    pub(super) child: [u32; 8],
}

/// Four triangles: vertex 0 and the two edges from it, lanes side by side. Unused lanes have
/// zero edges (determinant 0: never hit).
#[derive(Clone, Copy)]
#[repr(C, align(16))]
pub(super) struct Tri4 {
    pub(super) v0: [[f32; 4]; 3],
    pub(super) e1: [[f32; 4]; 3],
    pub(super) e2: [[f32; 4]; 3],
    pub(super) id: [u32; 4],
}

/// A child reference with this bit set is a leaf: packets `first .. first + count`.
pub(super) const LEAF: u32 = 1 << 31;
pub(super) const COUNT_SHIFT: u32 = 28;
pub(super) const FIRST_MASK: u32 = (1 << COUNT_SHIFT) - 1;

/// Up to eight rays traced together through one traversal (structure of arrays): coherent rays,
/// such as the camera rays of one pixel, share their node visits and test every triangle of a
/// leaf eight at a time. Each lane gets the hit its own [`Ray8`] query would find, ties of `t`
/// between triangles included (both go to the lowest id, [`nearer`]).
pub struct Packet8 {
    pub(super) o: [[f32; 8]; 3],
    pub(super) d: [[f32; 8]; 3],
    pub(super) inv: [[f32; 8]; 3],
    /// Each lane's `o · inv`, nudged as a single ray's ([`o_inv_bounds`]).
    pub(super) o_inv_near: [[f32; 8]; 3],
    pub(super) o_inv_far: [[f32; 8]; 3],
    pub(super) tmin: [f32; 8],
    /// Lanes that hold a ray.
    pub(super) active: u32,
}

/// A ray prepared for the box test: direction components too close to zero are replaced by
/// ±1e-18 (as Embree does) so that `1/d` is finite and `0 * inf` never makes a NaN.
pub struct Ray8 {
    pub(super) o: [f32; 3],
    pub(super) d: [f32; 3],
    pub(super) inv: [f32; 3],
    /// `o · inv` per axis, nudged by [`o_inv_bounds`]: a box plane's distance
    /// `b · inv − o_inv_near` is at most the exact one, `b · inv − o_inv_far` at least.
    pub(super) o_inv_near: [f32; 3],
    pub(super) o_inv_far: [f32; 3],
    /// Plane index (into `Node::b`) of the near and far side per axis.
    pub(super) near: [usize; 3],
    pub(super) far: [usize; 3],
    pub(super) tmin: f32,
    pub(super) tmax: f32,
    /// Whether the ray has a NaN in its origin, direction or bounds (see [`Self::has_nan`]),
    /// worked out while the values are in registers: a walk that began by loading the fields
    /// it was just built from, several at once, waited for their stores.
    pub(super) nan: bool,
}

/// `o · inv` rounded, then moved by at least one ulp each way: the rounded product is within half
/// an ulp of the exact one, so `b · inv − near` (one fused operation) is at most the plane's
/// distance `(b − o) · inv` up to the rounding of that difference, and `b · inv − far` at least.
/// Box tests with them are conservative however the subtraction cancels (a ray whose origin is
/// far from a box along a nearly perpendicular axis), which keeps a box touched at a corner or
/// an edge from being culled: every walk then meets every triangle that could tie with its
/// hit, and ties go to the lowest id ([`nearer`]) whatever the walk.
#[inline(always)]
pub(super) fn o_inv_bounds(o_inv: f32) -> (f32, f32) {
    // EPSILON·|x| is one to two ulps of x (x normal); a subnormal or zero product gets the
    // least normal's.
    let slack = (o_inv.abs() * f32::EPSILON).max(f32::MIN_POSITIVE);
    (o_inv + slack, o_inv - slack)
}

/// `1 / d` of a direction component, with components of magnitude below 1e-18 taken as ±1e-18
/// (a finite inverse, so slab tests never compute 0·∞).
#[inline(always)]
pub(super) fn safe_inv(d: f32) -> f32 {
    1.0 / if d.abs() < 1e-18 { 1e-18f32.copysign(d) } else { d }
}

impl Ray8 {
    #[inline(always)]
    pub fn new(origin: Vec3A, dir: Vec3A, tmin: f32, tmax: f32) -> Self {
        let o = origin.to_array();
        let d = dir.to_array();
        let mut inv = [0.0f32; 3];
        let mut o_inv_near = [0.0f32; 3];
        let mut o_inv_far = [0.0f32; 3];
        let mut near = [0usize; 3];
        let mut far = [0usize; 3];
        for a in 0..3 {
            inv[a] = safe_inv(d[a]);
            (o_inv_near[a], o_inv_far[a]) = o_inv_bounds(o[a] * inv[a]);
            let neg = (inv[a] < 0.0) as usize;
            near[a] = a + 3 * neg;
            far[a] = a + 3 * (1 - neg);
        }
        let nan = o_inv_near[0].is_nan()
            || o_inv_near[1].is_nan()
            || o_inv_near[2].is_nan()
            || tmin.is_nan()
            || tmax.is_nan();
        Ray8 { o, d, inv, o_inv_near, o_inv_far, near, far, tmin, tmax, nan }
    }

    /// Whether the ray has a NaN in its origin, direction or bounds: such a ray hits nothing
    /// (every comparison of a triangle test with a NaN is false), so its walk is skipped. Walked,
    /// it would still end (`node_hits` keeps out of empty slots), but the min and max
    /// instructions drop a NaN operand and would let it into every filled slot, to test the
    /// whole tree for nothing. A NaN direction component makes its inverse NaN, and either
    /// makes the scaled origin NaN.
    #[inline(always)]
    pub(super) fn has_nan(&self) -> bool {
        self.nan
    }
}

/// The least (`hmin8`) or greatest (`hmax8`) of the eight lanes of `v`, in every lane: the
/// reductions of a packet walk (its intervals, a child's nearest entry).
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn hmin8(v: std::arch::x86_64::__m256) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX (cfg above); register operations only.
    unsafe {
        let v = _mm256_min_ps(v, _mm256_permute2f128_ps(v, v, 1));
        let v = _mm256_min_ps(v, _mm256_shuffle_ps(v, v, 0b01_00_11_10));
        _mm256_min_ps(v, _mm256_shuffle_ps(v, v, 0b10_11_00_01))
    }
}

/// See [`hmin8`].
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn hmax8(v: std::arch::x86_64::__m256) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX (cfg above); register operations only.
    unsafe {
        let v = _mm256_max_ps(v, _mm256_permute2f128_ps(v, v, 1));
        let v = _mm256_max_ps(v, _mm256_shuffle_ps(v, v, 0b01_00_11_10));
        _mm256_max_ps(v, _mm256_shuffle_ps(v, v, 0b10_11_00_01))
    }
}

/// A packet's lanes as intervals, per axis (each value broadcast to every lane): the least and
/// greatest inverse direction, the least far term and the greatest near term of its scaled
/// origins (see [`o_inv_bounds`]). The packet walks of eight and sixteen lanes make them once a
/// walk and test every node's eight boxes with them first ([`Intervals::slots`]).
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
pub(super) struct Intervals {
    pub(super) inv_lo: [std::arch::x86_64::__m256; 3],
    pub(super) inv_hi: [std::arch::x86_64::__m256; 3],
    pub(super) oinv_lo: [std::arch::x86_64::__m256; 3],
    pub(super) oinv_hi: [std::arch::x86_64::__m256; 3],
}

#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
impl Intervals {
    /// The filled slots of `node` that some lane of the packet may enter between `tmin` and
    /// `far` (the greatest far bound of its lanes). Per lane the exact test computes each
    /// plane's distance as round(b·inv − o), o the lane's nudged near or far term, which is
    /// monotonic in the exact value; the exact value is least at an end of the inverse's
    /// interval and at the greatest scaled origin, greatest at an end and at the least origin,
    /// so one rounded product per end bounds every lane's. Mins, maxes and the product by
    /// [`SLACK`] keep the order, so a slot is dropped only when every lane's own test would
    /// drop it. A NaN bound keeps the slot.
    #[inline(always)]
    pub(super) fn slots(
        &self,
        node: &Node,
        tmin: std::arch::x86_64::__m256,
        far: std::arch::x86_64::__m256,
    ) -> u32 {
        use std::arch::x86_64::*;
        let Intervals { inv_lo, inv_hi, oinv_lo, oinv_hi } = self;
        // SAFETY: the target has AVX2 and FMA (cfg above); `Node` is 32-byte aligned and its
        // planes are 32 bytes each.
        unsafe {
            let plane = |k: usize| _mm256_load_ps(node.b[k].as_ptr());
            let lo = |b: __m256, a: usize| {
                _mm256_min_ps(
                    _mm256_fmsub_ps(b, inv_lo[a], oinv_hi[a]),
                    _mm256_fmsub_ps(b, inv_hi[a], oinv_hi[a]),
                )
            };
            let hi = |b: __m256, a: usize| {
                _mm256_max_ps(
                    _mm256_fmsub_ps(b, inv_lo[a], oinv_lo[a]),
                    _mm256_fmsub_ps(b, inv_hi[a], oinv_lo[a]),
                )
            };
            let (b0, b1, b2, b3, b4, b5) = (plane(0), plane(1), plane(2), plane(3), plane(4), plane(5));
            let tn = _mm256_max_ps(
                _mm256_max_ps(_mm256_min_ps(lo(b0, 0), lo(b3, 0)), _mm256_min_ps(lo(b1, 1), lo(b4, 1))),
                _mm256_max_ps(_mm256_min_ps(lo(b2, 2), lo(b5, 2)), tmin),
            );
            let tf = _mm256_min_ps(
                _mm256_min_ps(_mm256_max_ps(hi(b0, 0), hi(b3, 0)), _mm256_max_ps(hi(b1, 1), hi(b4, 1))),
                _mm256_min_ps(_mm256_max_ps(hi(b2, 2), hi(b5, 2)), far),
            );
            _mm256_movemask_ps(_mm256_cmp_ps(tn, _mm256_mul_ps(tf, _mm256_set1_ps(SLACK)), _CMP_NGT_UQ))
                as u32
        }
    }
}

/// The slots of `node` that hold a box (empty ones have min > max).
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn filled_slots(node: &Node) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX (cfg above); `Node` is 32-byte aligned, its planes 32 bytes.
    unsafe {
        _mm256_movemask_ps(_mm256_cmp_ps(
            _mm256_load_ps(node.b[0].as_ptr()),
            _mm256_load_ps(node.b[3].as_ptr()),
            _CMP_LE_OQ,
        )) as u32
    }
}

/// A packet walk's child `k` (node reference, lanes, nearest entry) put among the first `n` of
/// `kids`, which are in descending entry distance (the nearest last, to be walked first).
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn insert_by_entry(kids: &mut [(u32, u32, f32); 8], n: usize, k: (u32, u32, f32)) {
    let mut j = n;
    while j > 0 && kids[j - 1].2 < k.2 {
        kids[j] = kids[j - 1];
        j -= 1;
    }
    kids[j] = k;
}

/// The lanes of `mask` as an all-ones / all-zeros vector.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn lane_mask(mask: u32) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX2 (cfg above); register operations only.
    unsafe {
        let bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let m = _mm256_and_si256(_mm256_set1_epi32(mask as i32), bits);
        _mm256_castsi256_ps(_mm256_cmpeq_epi32(m, bits))
    }
}

#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn node_hits(node: &Node, ray: &Ray8, tmax: f32) -> (u32, [f32; 8]) {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX2 and FMA (cfg above); `Node` is 32-byte aligned and its planes
    // are 32 bytes each.
    unsafe {
        let base: *const f32 = node.b.as_ptr().cast();
        // `near`/`far` are plane indices below 6 (see `Ray8::new`): in bounds.
        let plane = |i: usize| _mm256_load_ps(base.add(i * 8));
        let t = |i: usize, a: usize, o_inv: &[f32; 3]| {
            _mm256_fmsub_ps(plane(i), _mm256_set1_ps(ray.inv[a]), _mm256_set1_ps(o_inv[a]))
        };
        let (on, of) = (&ray.o_inv_near, &ray.o_inv_far);
        let tn = _mm256_max_ps(
            _mm256_max_ps(t(ray.near[0], 0, on), t(ray.near[1], 1, on)),
            _mm256_max_ps(t(ray.near[2], 2, on), _mm256_set1_ps(ray.tmin)),
        );
        let tf = _mm256_min_ps(
            _mm256_min_ps(t(ray.far[0], 0, of), t(ray.far[1], 1, of)),
            _mm256_min_ps(t(ray.far[2], 2, of), _mm256_set1_ps(tmax)),
        );
        // Conservative by a few ulps, so rounding never culls a box the ray touches.
        let tf = _mm256_mul_ps(tf, _mm256_set1_ps(SLACK));
        // Only slots with a box (empty ones have min > max, and their child reference is the
        // root): a ray whose plane distances come out NaN in the empty slots' infinite planes
        // (an infinite origin or direction component, ∞ − ∞ or ∞·0) would enter them
        // otherwise, since min and max drop a NaN operand, and push the root forever.
        let filled = _mm256_cmp_ps(plane(0), plane(3), _CMP_LE_OQ);
        let mask = _mm256_movemask_ps(_mm256_and_ps(filled, _mm256_cmp_ps(tn, tf, _CMP_LE_OQ))) as u32;
        let mut dist = [0f32; 8];
        _mm256_storeu_ps(dist.as_mut_ptr(), tn);
        (mask, dist)
    }
}

#[cfg(not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma")))]
#[inline(always)]
pub(super) fn node_hits(node: &Node, ray: &Ray8, tmax: f32) -> (u32, [f32; 8]) {
    let mut mask = 0u32;
    let mut dist = [0f32; 8];
    for s in 0..8 {
        let t = |i: usize, a: usize, o_inv: &[f32; 3]| node.b[i][s].mul_add(ray.inv[a], -o_inv[a]);
        let (on, of) = (&ray.o_inv_near, &ray.o_inv_far);
        let tn = t(ray.near[0], 0, on).max(t(ray.near[1], 1, on)).max(t(ray.near[2], 2, on)).max(ray.tmin);
        let tf = t(ray.far[0], 0, of).min(t(ray.far[1], 1, of)).min(t(ray.far[2], 2, of)).min(tmax);
        // Only slots with a box (see the AVX2 version).
        if tn <= tf * SLACK && node.b[0][s] <= node.b[3][s] {
            mask |= 1 << s;
        }
        dist[s] = tn;
    }
    (mask, dist)
}

/// The relative slack of the walks' far bounds, a few ulps: box tests compare entries with
/// exits times it (rounding never culls a box the ray touches), popped nodes' entries with the
/// hit times it, and the far pre-tests `tt <= tmax·|det|·SLACK` hold for every lane whose divided
/// distance is at most `tmax` (the product's two roundings and the division's are each half an
/// ulp).
pub(super) const SLACK: f32 = 1.0 + 4.0 * f32::EPSILON;

/// Whether a hit at `t` on triangle `id` is nearer than the best so far (`bt` on `bid`;
/// `bid == u32::MAX`: none, `bt` is the ray's far bound): nearer, or as near on a triangle of
/// lower id. So the closest hit is the least (distance, id) of the triangles hit, whatever the
/// order the walk meets them in: a packet of other rays, another tree shape or another tile
/// finds the same triangle on a corner or an edge where two triangles' distances are equal.
/// Ids are below 2^31 (the trees' triangle counts), so a signed comparison orders them and puts
/// "none" (-1) before every one, which a tie then cannot beat.
#[inline(always)]
pub(super) fn nearer(t: f32, id: u32, bt: f32, bid: u32) -> bool {
    t < bt || (t == bt && (id as i32) < (bid as i32))
}

/// Möller–Trumbore in AVX registers, eight (triangle, ray) pairs side by side: edges `e1`, `e2`,
/// `s` = origin − vertex 0, direction `d`, per axis. The operations of `tri4_closest` per lane,
/// in its order: every test but the far bound's (`ok`), and the two values that test compares,
/// `tt` and `|det|`. The single ray's pair of packets (`tri8_tests`) and the packet's one
/// triangle against eight rays (`Bvh8::closest_packet`) both come here.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) unsafe fn mt8(
    e1: [std::arch::x86_64::__m256; 3],
    e2: [std::arch::x86_64::__m256; 3],
    s: [std::arch::x86_64::__m256; 3],
    d: [std::arch::x86_64::__m256; 3],
    tmin: std::arch::x86_64::__m256,
) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256, std::arch::x86_64::__m256) {
    use std::arch::x86_64::*;
    // SAFETY (the caller's): the target has AVX2 and FMA; register operations only.
    unsafe {
        let ([e1x, e1y, e1z], [e2x, e2y, e2z], [sx, sy, sz], [dx, dy, dz]) = (e1, e2, s, d);
        // p = d x e2, q = s x e1 (the products written out: a*b - c*d)
        let px = _mm256_fmsub_ps(dy, e2z, _mm256_mul_ps(dz, e2y));
        let py = _mm256_fmsub_ps(dz, e2x, _mm256_mul_ps(dx, e2z));
        let pz = _mm256_fmsub_ps(dx, e2y, _mm256_mul_ps(dy, e2x));
        let qx = _mm256_fmsub_ps(sy, e1z, _mm256_mul_ps(sz, e1y));
        let qy = _mm256_fmsub_ps(sz, e1x, _mm256_mul_ps(sx, e1z));
        let qz = _mm256_fmsub_ps(sx, e1y, _mm256_mul_ps(sy, e1x));
        let dot =
            |ax, ay, az, bx, by, bz| _mm256_fmadd_ps(ax, bx, _mm256_fmadd_ps(ay, by, _mm256_mul_ps(az, bz)));
        let det = dot(e1x, e1y, e1z, px, py, pz);
        let signbit = _mm256_set1_ps(-0.0);
        let sign = _mm256_and_ps(det, signbit);
        let adet = _mm256_andnot_ps(signbit, det);
        let u = _mm256_xor_ps(dot(sx, sy, sz, px, py, pz), sign);
        let v = _mm256_xor_ps(dot(dx, dy, dz, qx, qy, qz), sign);
        let tt = _mm256_xor_ps(dot(e2x, e2y, e2z, qx, qy, qz), sign);
        let zero = _mm256_setzero_ps();
        let mut ok = _mm256_cmp_ps::<_CMP_GT_OQ>(adet, zero);
        ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GE_OQ>(u, zero));
        ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GE_OQ>(v, zero));
        ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(_mm256_add_ps(u, v), adet));
        ok = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GT_OQ>(tt, _mm256_mul_ps(tmin, adet)));
        (ok, tt, adet)
    }
}

/// Packets `a` (low half) and `b` (high half) against one ray: [`mt8`] with the ray broadcast.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
unsafe fn tri8_tests(
    a: &Tri4,
    b: &Tri4,
    ray: &Ray8,
) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256, std::arch::x86_64::__m256) {
    use std::arch::x86_64::*;
    // SAFETY (the caller's): the target has AVX2 and FMA; every row of a `Tri4` is four `f32`s,
    // read unaligned.
    unsafe {
        let ld = |ra: &[[f32; 4]; 3], rb: &[[f32; 4]; 3]| {
            std::array::from_fn(|k| _mm256_loadu2_m128(rb[k].as_ptr(), ra[k].as_ptr()))
        };
        let v0: [__m256; 3] = ld(&a.v0, &b.v0);
        let s = std::array::from_fn(|k| _mm256_sub_ps(_mm256_set1_ps(ray.o[k]), v0[k]));
        let d = ray.d.map(|c| _mm256_set1_ps(c));
        mt8(ld(&a.e1, &b.e1), ld(&a.e2, &b.e2), s, d, _mm256_set1_ps(ray.tmin))
    }
}

/// The lanes of `ok` whose `tt` may lie at or below the far bound `tmax` scaled by `|det|`, with
/// a few ulps to spare ([`SLACK`]): a pre-test that saves the division of the lanes beyond
/// the bound, never dropping one whose divided distance `tt / |det|` the exact tests would take.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) unsafe fn below(
    ok: std::arch::x86_64::__m256,
    tt: std::arch::x86_64::__m256,
    adet: std::arch::x86_64::__m256,
    tmax: std::arch::x86_64::__m256,
) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    // SAFETY (the caller's): the target has AVX.
    unsafe {
        let bound = _mm256_mul_ps(_mm256_mul_ps(tmax, adet), _mm256_set1_ps(SLACK));
        _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_LE_OQ>(tt, bound))
    }
}

/// Whether any triangle of packets `a` and `b` is hit with t in (ray.tmin, tmax): exactly when
/// `tri4_closest` of `a` or of `b` returns a hit (a lane passes the scaled tests and its
/// distance `tt / |det|` is below `tmax`), without picking the nearest lane.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn tri8_any(a: &Tri4, b: &Tri4, ray: &Ray8, tmax: f32) -> bool {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX2 and FMA (cfg above).
    unsafe {
        let (ok, tt, adet) = tri8_tests(a, b, ray);
        let ok = below(ok, tt, adet, _mm256_set1_ps(tmax));
        if _mm256_testz_ps(ok, ok) != 0 {
            return false;
        }
        let near = _mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_div_ps(tt, adet), _mm256_set1_ps(tmax));
        _mm256_testz_ps(ok, near) == 0
    }
}

/// The nearest hit of packets `a` then `b` [`nearer`] than (`tmax`, `bid`), t above
/// ray.tmin: (t, lane), lanes 0-3 of `a` and 4-7 of `b`. Exactly what `tri4_closest` of `a`,
/// then of `b` against `a`'s hit, finds: `b`'s far test is redone with that bound.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn tri8_closest(a: &Tri4, b: &Tri4, ray: &Ray8, tmax: f32, bid: u32) -> Option<(f32, usize)> {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX2 and FMA (cfg above); one store into a local array of eight.
    unsafe {
        let (ok, tt, adet) = tri8_tests(a, b, ray);
        let first = below(ok, tt, adet, _mm256_set1_ps(tmax));
        let mut mask = _mm256_movemask_ps(first) as u32;
        if mask == 0 {
            return None;
        }
        let mut t = [0f32; 8];
        _mm256_storeu_ps(t.as_mut_ptr(), _mm256_div_ps(tt, adet));
        let id = |l: usize| if l < 4 { a.id[l] } else { b.id[l - 4] };
        // The lanes of `mask` in order, each kept when nearer than the nearest so far.
        let pick = |mask: u32, bt: &mut f32, bid: &mut u32, best: &mut Option<(f32, usize)>| {
            let mut m = mask;
            while m != 0 {
                let l = m.trailing_zeros() as usize;
                m &= m - 1;
                if nearer(t[l], id(l), *bt, *bid) {
                    (*bt, *bid) = (t[l], id(l));
                    *best = Some((t[l], l));
                }
            }
        };
        let (mut best, mut bt, mut bid) = (None, tmax, bid);
        pick(mask & 0x0f, &mut bt, &mut bid, &mut best);
        if best.is_some() {
            // `a` hit: `b` is tested against the nearer bound.
            mask = _mm256_movemask_ps(below(ok, tt, adet, _mm256_set1_ps(bt))) as u32;
        }
        pick(mask & 0xf0, &mut bt, &mut bid, &mut best);
        best
    }
}

/// Whether any triangle of packets `a` and `b` is hit with t in (ray.tmin, tmax): exactly when
/// `tri4_closest` of `a` or of `b` returns a hit.
#[cfg(not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma")))]
#[inline(always)]
pub(super) fn tri8_any(a: &Tri4, b: &Tri4, ray: &Ray8, tmax: f32) -> bool {
    tri4_closest(a, ray, tmax, u32::MAX).is_some() || tri4_closest(b, ray, tmax, u32::MAX).is_some()
}

/// The nearest hit of packets `a` then `b`: `tri4_closest` of each in turn, lanes of `b` 4-7.
#[cfg(not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma")))]
#[inline(always)]
pub(super) fn tri8_closest(a: &Tri4, b: &Tri4, ray: &Ray8, tmax: f32, bid: u32) -> Option<(f32, usize)> {
    let first = tri4_closest(a, ray, tmax, bid);
    let (bound, bid) = first.map_or((tmax, bid), |h| (h.0, a.id[h.1]));
    tri4_closest(b, ray, bound, bid).map(|(t, l)| (t, l + 4)).or(first)
}

/// The nearest of four triangles hit [`nearer`] than (`tmax`, `bid`), t above ray.tmin: (t,
/// lane). Möller–Trumbore with the division deferred: barycentrics and t are compared scaled by
/// |det| (the far bound with slack, as [`below`]), the distances of the lanes that pass divided
/// out and compared exactly; four lanes in SSE registers.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma"))]
#[inline(always)]
pub(super) fn tri4_closest(p: &Tri4, ray: &Ray8, tmax: f32, bid: u32) -> Option<(f32, usize)> {
    use std::arch::x86_64::*;
    // SAFETY: the target has AVX2 and FMA (cfg above); `Tri4` is 16-byte aligned, every row 16
    // bytes.
    unsafe {
        let ld = |r: &[f32; 4]| _mm_load_ps(r.as_ptr());
        let set = _mm_set1_ps;
        let (e1x, e1y, e1z) = (ld(&p.e1[0]), ld(&p.e1[1]), ld(&p.e1[2]));
        let (e2x, e2y, e2z) = (ld(&p.e2[0]), ld(&p.e2[1]), ld(&p.e2[2]));
        let (dx, dy, dz) = (set(ray.d[0]), set(ray.d[1]), set(ray.d[2]));
        let sx = _mm_sub_ps(set(ray.o[0]), ld(&p.v0[0]));
        let sy = _mm_sub_ps(set(ray.o[1]), ld(&p.v0[1]));
        let sz = _mm_sub_ps(set(ray.o[2]), ld(&p.v0[2]));
        // p = d x e2, q = s x e1 (the products written out: a*b - c*d)
        let px = _mm_fmsub_ps(dy, e2z, _mm_mul_ps(dz, e2y));
        let py = _mm_fmsub_ps(dz, e2x, _mm_mul_ps(dx, e2z));
        let pz = _mm_fmsub_ps(dx, e2y, _mm_mul_ps(dy, e2x));
        let qx = _mm_fmsub_ps(sy, e1z, _mm_mul_ps(sz, e1y));
        let qy = _mm_fmsub_ps(sz, e1x, _mm_mul_ps(sx, e1z));
        let qz = _mm_fmsub_ps(sx, e1y, _mm_mul_ps(sy, e1x));
        let dot = |ax, ay, az, bx, by, bz| _mm_fmadd_ps(ax, bx, _mm_fmadd_ps(ay, by, _mm_mul_ps(az, bz)));
        let det = dot(e1x, e1y, e1z, px, py, pz);
        let signbit = set(-0.0);
        let sign = _mm_and_ps(det, signbit);
        let adet = _mm_andnot_ps(signbit, det);
        let u = _mm_xor_ps(dot(sx, sy, sz, px, py, pz), sign);
        let v = _mm_xor_ps(dot(dx, dy, dz, qx, qy, qz), sign);
        let tt = _mm_xor_ps(dot(e2x, e2y, e2z, qx, qy, qz), sign);
        let zero = _mm_setzero_ps();
        let mut ok = _mm_cmpgt_ps(adet, zero);
        ok = _mm_and_ps(ok, _mm_cmpge_ps(u, zero));
        ok = _mm_and_ps(ok, _mm_cmpge_ps(v, zero));
        ok = _mm_and_ps(ok, _mm_cmple_ps(_mm_add_ps(u, v), adet));
        ok = _mm_and_ps(ok, _mm_cmpgt_ps(tt, _mm_mul_ps(set(ray.tmin), adet)));
        ok = _mm_and_ps(ok, _mm_cmple_ps(tt, _mm_mul_ps(_mm_mul_ps(set(tmax), adet), set(SLACK))));
        let mut mask = _mm_movemask_ps(ok) as u32;
        if mask == 0 {
            return None;
        }
        let mut t = [0f32; 4];
        _mm_storeu_ps(t.as_mut_ptr(), _mm_div_ps(tt, adet));
        let (mut best, mut bt, mut bid) = (None, tmax, bid);
        while mask != 0 {
            let l = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            if nearer(t[l], p.id[l], bt, bid) {
                (bt, bid) = (t[l], p.id[l]);
                best = Some((t[l], l));
            }
        }
        best
    }
}

/// The nearest of four triangles hit with t in (ray.tmin, tmax): (t, lane). Möller–Trumbore
/// with the division deferred: barycentrics and t are compared scaled by |det|.
#[cfg(not(all(target_arch = "x86_64", target_feature = "avx2", target_feature = "fma")))]
#[inline(always)]
pub(super) fn tri4_closest(p: &Tri4, ray: &Ray8, tmax: f32, bid: u32) -> Option<(f32, usize)> {
    // NaN where a lane fails its tests: never nearer than anything.
    let mut t = [f32::NAN; 4];
    // Written lane by lane over arrays: LLVM turns this into one SSE/AVX sequence.
    for l in 0..4 {
        let e1 = [p.e1[0][l], p.e1[1][l], p.e1[2][l]];
        let e2 = [p.e2[0][l], p.e2[1][l], p.e2[2][l]];
        let s = [ray.o[0] - p.v0[0][l], ray.o[1] - p.v0[1][l], ray.o[2] - p.v0[2][l]];
        let d = ray.d;
        // p = d x e2, q = s x e1
        let pv = [d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2], d[0] * e2[1] - d[1] * e2[0]];
        let qv = [s[1] * e1[2] - s[2] * e1[1], s[2] * e1[0] - s[0] * e1[2], s[0] * e1[1] - s[1] * e1[0]];
        let det = e1[0] * pv[0] + e1[1] * pv[1] + e1[2] * pv[2];
        let sign = det.to_bits() & 0x8000_0000;
        let adet = det.abs();
        let flip = |x: f32| f32::from_bits(x.to_bits() ^ sign);
        let u = flip(s[0] * pv[0] + s[1] * pv[1] + s[2] * pv[2]);
        let v = flip(d[0] * qv[0] + d[1] * qv[1] + d[2] * qv[2]);
        let tt = flip(e2[0] * qv[0] + e2[1] * qv[1] + e2[2] * qv[2]);
        let ok = adet > 0.0
            && u >= 0.0
            && v >= 0.0
            && u + v <= adet
            && tt > ray.tmin * adet
            && tt <= tmax * adet * SLACK;
        t[l] = if ok { tt / adet } else { f32::NAN };
    }
    let (mut best, mut bt, mut bid) = (None, tmax, bid);
    for (l, &tl) in t.iter().enumerate() {
        if nearer(tl, p.id[l], bt, bid) {
            (bt, bid) = (tl, p.id[l]);
            best = Some((tl, l));
        }
    }
    best
}
