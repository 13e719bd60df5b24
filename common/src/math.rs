//! Small geometric helpers shared by the tracer: rays, affine transforms, orthonormal bases.
//!
//! Shading and hit points are computed in `f64` (the course scenes span scales from 0.1 to 1e3,
//! and the instructor recommends double precision against speckles); BVH traversal runs in `f32`
//! and every accepted closest hit is re-intersected in `f64`.

use glam::{DAffine3, DMat3, DVec3};

/// A ray in world or object space. `dir` is unit length in world space; in object space it is
/// the transformed (not renormalised) direction, so `t` is the same in both spaces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    pub dir: DVec3,
    /// Time within the exposure, in [0, 1): where moving objects are (motion blur). Every ray
    /// spawned from a camera sample carries that sample's time.
    pub time: f64,
}

impl Ray {
    /// A ray at time 0.
    #[inline]
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Ray { origin, dir, time: 0.0 }
    }

    /// A secondary ray (shadow, reflection, refraction) at the same time as `self`.
    #[inline]
    pub fn spawn(&self, origin: DVec3, dir: DVec3) -> Self {
        Ray { origin, dir, time: self.time }
    }

    #[inline]
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.dir * t
    }
}

/// An object-to-world transform with what intersection and shading need precomputed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    pub to_world: DAffine3,
    pub to_object: DAffine3,
    /// Inverse transpose of the linear part: maps object-space normals to world space.
    pub normal_matrix: DMat3,
}

/// The scale factor of a similarity (rotations, reflections and one uniform scale): `Some(s)`
/// when `m`'s columns are orthogonal and of one length `s` (to a relative 1e-9), else `None`.
/// A sphere under such a matrix is still a sphere, of radius `s·r`.
pub fn uniform_scale(m: &DMat3) -> Option<f64> {
    let g = m.transpose() * *m;
    let s2 = g.x_axis.x;
    let off = g.x_axis.y.abs() + g.x_axis.z.abs() + g.y_axis.z.abs();
    let uniform = s2 > 0.0
        && s2.is_finite()
        && (g.y_axis.y - s2).abs() <= 1e-9 * s2
        && (g.z_axis.z - s2).abs() <= 1e-9 * s2
        && off <= 1e-9 * s2;
    uniform.then(|| s2.sqrt())
}

impl Transform {
    /// `None` when the matrix is singular (a zero scale): the caller reports that as an error.
    pub fn new(to_world: DAffine3) -> Option<Self> {
        let det = to_world.matrix3.determinant();
        if !det.is_finite() || det.abs() < 1e-300 {
            return None;
        }
        let to_object = to_world.inverse();
        let normal_matrix = to_world.matrix3.inverse().transpose();
        Some(Transform { to_world, to_object, normal_matrix })
    }

    #[inline]
    pub fn ray_to_object(&self, ray: &Ray) -> Ray {
        Ray {
            origin: self.to_object.transform_point3(ray.origin),
            dir: self.to_object.transform_vector3(ray.dir),
            time: ray.time,
        }
    }

    #[inline]
    pub fn normal_to_world(&self, n: DVec3) -> DVec3 {
        (self.normal_matrix * n).normalize()
    }
}

/// Mirror direction of `d` about the unit normal `n`.
#[inline]
pub fn reflect(d: DVec3, n: DVec3) -> DVec3 {
    d - 2.0 * d.dot(n) * n
}

/// Two unit vectors orthogonal to the unit vector `n` and to each other, built the course's way
/// (scene-format.md §6.7): replace the smallest-magnitude component of `n` by 1, cross.
pub fn orthonormal_pair(n: DVec3) -> (DVec3, DVec3) {
    let a = n.abs();
    let mut r = n;
    if a.x <= a.y && a.x <= a.z {
        r.x = 1.0;
    } else if a.y <= a.z {
        r.y = 1.0;
    } else {
        r.z = 1.0;
    }
    let u = r.cross(n).normalize();
    let v = n.cross(u);
    (u, v)
}

/// Two unit vectors orthogonal to the unit vector `n` and to each other, with neither a branch
/// nor a square root (Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 2017): for
/// sampling frames, where only the distribution around `n` matters. The course's construction,
/// [`orthonormal_pair`], stays where the frame's orientation is part of the scene (an area
/// light's square).
#[inline(always)]
pub fn sampling_frame(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), DVec3::new(b, sign + n.y * n.y * a, -n.y))
}

/// `(sin 2πt, cos 2πt)` for a finite `t` in turns, to within 3e-16 of the exact values, without
/// a call into libm: sampled directions (azimuths, lat-long map points) take an angle from a
/// random number in [0, 1), and libm's `sin_cos` was a twentieth of an environment-lit render.
/// Being plain IEEE arithmetic, the result is also the same bits on every machine, whatever
/// libm a worker has.
///
/// The reduction is exact: `r = t − round(t)` in [−½, ½], then the nearest quarter turn `q/4`
/// leaves `f = r − q/4` in [−⅛, ⅛], i.e. `x = 2πf` in [−π/4, π/4], where the Taylor series of
/// sine to x¹⁵ and of cosine to x¹⁶ are within 5e-17 of the functions; the quarter turn then
/// swaps and negates the pair. Whole and quarter turns give exact 0 and ±1. NaN and ±∞ give NaN.
#[inline]
pub fn sincos_turns(t: f64) -> (f64, f64) {
    // sin x = x + x³·P(x²) and cos x = Q(x²), the Taylor coefficients ±1/n!, lowest first.
    const P: [f64; 7] = [
        -1.0 / 6.0,
        1.0 / 120.0,
        -1.0 / 5_040.0,
        1.0 / 362_880.0,
        -1.0 / 39_916_800.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 1_307_674_368_000.0,
    ];
    const Q: [f64; 9] = [
        1.0,
        -1.0 / 2.0,
        1.0 / 24.0,
        -1.0 / 720.0,
        1.0 / 40_320.0,
        -1.0 / 3_628_800.0,
        1.0 / 479_001_600.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 20_922_789_888_000.0,
    ];
    let r = t - t.round();
    let q = (4.0 * r).round();
    let x = (r - 0.25 * q) * std::f64::consts::TAU;
    let y = x * x;
    let y2 = y * y;
    let y4 = y2 * y2;
    // Estrin's scheme: a few fused multiply-adds deep instead of one per coefficient.
    let p_lo = P[2].mul_add(y, P[1]).mul_add(y, P[0]);
    let p_hi = P[6].mul_add(y, P[5]).mul_add(y2, P[4].mul_add(y, P[3]));
    let p = p_hi.mul_add(y * y2, p_lo);
    let sin = (x * y).mul_add(p, x);
    let q_lo = Q[3].mul_add(y, Q[2]).mul_add(y2, Q[1].mul_add(y, Q[0]));
    let q_hi = Q[7].mul_add(y, Q[6]).mul_add(y2, Q[5].mul_add(y, Q[4]));
    let cos = Q[8].mul_add(y4 * y4, q_hi.mul_add(y4, q_lo));
    quarter_turn(q as i64, sin, cos)
}

/// `(sin, cos)` of an angle turned on by `q` quarter turns (q in -2..=2, as [`sincos_turns`]
/// reduces): `q mod 4` = 0 gives (sin, cos), 1 (cos, −sin), 2 (−sin, −cos), 3 (−cos, sin).
/// Chosen with bit masks, not branches: q is as random as the sample that asked, and a
/// mispredicted branch per call cost more than the polynomial (3 % of head_env_light's time).
/// Negation is a flip of the sign bit, as `-x` is.
#[inline(always)]
fn quarter_turn(q: i64, sin: f64, cos: f64) -> (f64, f64) {
    let k = q as u64;
    let swap = 0u64.wrapping_sub(k & 1);
    let (s, c) = (sin.to_bits(), cos.to_bits());
    let first = (c & swap) | (s & !swap);
    let second = (s & swap) | (c & !swap);
    let first_sign = (k >> 1 & 1) << 63;
    let second_sign = ((k ^ k >> 1) & 1) << 63;
    (f64::from_bits(first ^ first_sign), f64::from_bits(second ^ second_sign))
}

/// `y.atan2(x)` to within 2e-10 radians, without a call into libm: the environment lookup of
/// every ray that misses the scene needs two inverse trigonometric functions, and libm's
/// `atan2` took a sixth of the time of a render where every ray misses (head_env_light's map).
///
/// The argument is reduced to `t = min(|x|, |y|) / max(|x|, |y|)` in [0, 1], where
/// `atan(t) = t·P(t²)` with `P` a degree-10 polynomial fitted for the least maximum error
/// (1.4e-10 on [0, 1]; evaluated in Estrin's scheme, so its latency is four fused
/// multiply-adds deep, not eleven), then unfolded by the octant. Signed zeros and quadrants
/// follow `f64::atan2`; a NaN argument gives NaN. Fused multiply-adds are exact IEEE
/// operations, so the result is the same bits on every machine.
#[inline]
pub fn atan2_approx(y: f64, x: f64) -> f64 {
    const C: [f64; 11] = [
        0.999_999_996_672_234_3,
        -0.333_333_020_880_277_16,
        0.199_991_297_644_411,
        -0.142_744_317_995_845_72,
        0.110_286_493_418_870_85,
        -0.087_138_548_442_562_9,
        0.065_413_675_627_087_82,
        -0.042_087_973_372_376_57,
        0.020_467_737_348_113_385,
        -0.006_394_727_546_410_552,
        0.000_937_551_064_287_188_8,
    ];
    let (ax, ay) = (x.abs(), y.abs());
    // Comparisons with a NaN are false: the NaN lands in `t`.
    let (lo, hi, steep) = if ay > ax { (ax, ay, true) } else { (ay, ax, false) };
    let t = if hi == 0.0 { 0.0 } else { lo / hi };
    let s = t * t;
    let s2 = s * s;
    let s4 = s2 * s2;
    let q0 = C[1].mul_add(s, C[0]);
    let q1 = C[3].mul_add(s, C[2]);
    let q2 = C[5].mul_add(s, C[4]);
    let q3 = C[7].mul_add(s, C[6]);
    let q4 = C[9].mul_add(s, C[8]);
    let r0 = q1.mul_add(s2, q0);
    let r1 = q3.mul_add(s2, q2);
    let r2 = C[10].mul_add(s2, q4);
    let p = r2.mul_add(s4 * s4, r1.mul_add(s4, r0));
    let a = t * p;
    // Selects, not branches: the signs and the octant are as random as the directions asked
    // about, and a mispredicted branch costs more than the subtraction it skips.
    let a = select(steep, std::f64::consts::FRAC_PI_2 - a, a);
    left_half(a, x).copysign(y)
}

/// `π − a` when `x` has its sign bit set, else `a`, for `a` that is +0 or positive: `π + (−a)`
/// (the same operation as `π − a`) or `0 + a` (which is `a`), both terms picked by x's sign
/// bit. No branch: that sign is as random as the directions asked about, and x86 turns a select
/// of floats on it into a branch.
#[inline(always)]
fn left_half(a: f64, x: f64) -> f64 {
    let sign = x.to_bits() & (1 << 63);
    let base = f64::from_bits(std::f64::consts::PI.to_bits() & 0u64.wrapping_sub(sign >> 63));
    base + f64::from_bits(a.to_bits() ^ sign)
}

/// `if c { a } else { b }` as a blend instead of a branch, for conditions a branch predictor
/// cannot learn (a random sample's octant). The compiler blends when `c` is a comparison of
/// floats; on x86 a float select on other conditions still becomes a branch.
#[inline(always)]
pub fn select(c: bool, a: f64, b: f64) -> f64 {
    std::hint::select_unpredictable(c, a, b)
}

/// Eight `f32` lanes: the environment light's sampling kernels work on a pixel's group of
/// samples a field at a time, in loops of this fixed length that compile to one AVX register
/// per field. Each lane's operations are its own and plain IEEE arithmetic, so a lane's bits do
/// not depend on its neighbours, on whether the loop was vectorised, or on the machine.
pub type F8 = [f32; 8];

/// Lane `k` of eight `f32` vectors given by axis, as an `f64` vector.
#[inline(always)]
pub fn lane(v: &[F8; 3], k: usize) -> DVec3 {
    DVec3::new(f64::from(v[0][k]), f64::from(v[1][k]), f64::from(v[2][k]))
}

/// [`sincos_turns`] of eight lanes in `f32`: `(sin 2πt, cos 2πt)` to within about 1e-7 (the
/// Taylor series of sine to x⁹ and of cosine to x¹⁰ on [−π/4, π/4], whose truncation errors are
/// 2e-9 and 1e-10, below `f32`'s rounding), with the same exact reduction and quarter-turn
/// unfolding. Whole and quarter turns give exact 0 and ±1; NaN and ±∞ give NaN.
#[inline(always)]
pub fn sincos_turns8(t: &F8) -> (F8, F8) {
    const S: [f32; 4] = [-1.0 / 6.0, 1.0 / 120.0, -1.0 / 5_040.0, 1.0 / 362_880.0];
    const C: [f32; 5] = [-1.0 / 2.0, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40_320.0, -1.0 / 3_628_800.0];
    let (mut sin, mut cos) = ([0.0; 8], [0.0; 8]);
    for i in 0..8 {
        let r = t[i] - t[i].round_ties_even();
        let q = (4.0 * r).round_ties_even();
        let x = (r - 0.25 * q) * std::f32::consts::TAU;
        let y = x * x;
        let ps = S[3].mul_add(y, S[2]).mul_add(y, S[1]).mul_add(y, S[0]);
        let s = (x * y).mul_add(ps, x);
        let pc = C[4].mul_add(y, C[3]).mul_add(y, C[2]).mul_add(y, C[1]).mul_add(y, C[0]);
        let c = pc.mul_add(y, 1.0);
        // The quarter turn by bit masks, as `quarter_turn`. q is an integer in -2..=2 (or NaN,
        // when sin and cos are NaN anyway); added to 1.5·2²³ it lands where a float's lowest
        // mantissa bits are the integer in two's complement, so its bits give q mod 4 without
        // a conversion (Rust's saturating `as i32` costs a dozen vector instructions).
        let k = (q + 12_582_912.0).to_bits();
        let swap = 0u32.wrapping_sub(k & 1);
        let (sb, cb) = (s.to_bits(), c.to_bits());
        let first = (cb & swap) | (sb & !swap);
        let second = (sb & swap) | (cb & !swap);
        sin[i] = f32::from_bits(first ^ ((k >> 1 & 1) << 31));
        cos[i] = f32::from_bits(second ^ (((k ^ k >> 1) & 1) << 31));
    }
    (sin, cos)
}

/// [`atan2_approx`] of eight lanes in `f32`: `y[i].atan2(x[i])` to within 3.5e-7 radians,
/// about one and a half `f32` steps near ±π (the same octant reduction, then `atan(t) = t·P(t²)`
/// on [0, 1] with `P` of degree 7, fitted for the least maximum error: 3.7e-8; the rest is
/// `f32` rounding), unfolded by selects. Signed zeros and quadrants follow `f32::atan2`; a NaN
/// argument gives NaN.
#[inline(always)]
pub fn atan2_8(y: &F8, x: &F8) -> F8 {
    const C: [f32; 8] = [
        0.999_999_34,
        -0.333_298_6,
        0.199_465_66,
        -0.139_086_29,
        0.096_421_97,
        -0.055_912_327,
        0.021_862_958,
        -0.004_054_567,
    ];
    let mut out = [0.0; 8];
    for i in 0..8 {
        let (ax, ay) = (x[i].abs(), y[i].abs());
        let steep = ay > ax;
        let (lo, hi) = if steep { (ax, ay) } else { (ay, ax) };
        let t = if hi == 0.0 { 0.0 } else { lo / hi };
        let s = t * t;
        let mut p = C[7];
        for &c in C[..7].iter().rev() {
            p = p.mul_add(s, c);
        }
        let a = t * p;
        let a = if steep { std::f32::consts::FRAC_PI_2 - a } else { a };
        // π + (−a) when x's sign bit is set, 0 + a otherwise (as `left_half`).
        let sign = x[i].to_bits() & 0x8000_0000;
        let base = f32::from_bits(std::f32::consts::PI.to_bits() & 0u32.wrapping_sub(sign >> 31));
        out[i] = (base + f32::from_bits(a.to_bits() ^ sign)).copysign(y[i]);
    }
    out
}

/// [`sampling_frame`] of eight unit normals given by axis, in `f32`: the two tangents, by axis.
#[inline(always)]
pub fn sampling_frame8(n: &[F8; 3]) -> ([F8; 3], [F8; 3]) {
    let (mut t, mut b) = ([[0.0; 8]; 3], [[0.0; 8]; 3]);
    for i in 0..8 {
        let (x, y, z) = (n[0][i], n[1][i], n[2][i]);
        let sign = 1f32.copysign(z);
        let a = -1.0 / (sign + z);
        let c = x * y * a;
        t[0][i] = 1.0 + sign * x * x * a;
        t[1][i] = sign * c;
        t[2][i] = -sign * x;
        b[0][i] = c;
        b[1][i] = sign + y * y * a;
        b[2][i] = -y;
    }
    (t, b)
}

/// Asks the processor to bring `slice[index]` into the cache, without waiting for it (nothing
/// when the index is out of bounds, or off x86-64). For lookups whose addresses are known well
/// before their values are needed: the load's latency then overlaps the work in between.
#[inline(always)]
pub fn prefetch<T>(slice: &[T], index: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(item) = slice.get(index) {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: SSE is part of every x86-64 processor, and a prefetch reads nothing into the
        // program (it cannot fault); the pointer comes from a live reference anyway.
        unsafe { _mm_prefetch::<_MM_HINT_T0>((item as *const T).cast()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (slice, index);
}

/// The lanes set in `mask`, lowest first.
#[inline]
pub fn lanes(mut mask: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let k = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            k
        })
    })
}

/// A word of all ones for `true`, of zeros for `false`: what [`pick`] selects with.
#[inline(always)]
pub fn word(c: bool) -> u64 {
    0u64.wrapping_sub(u64::from(c))
}

/// Each of eight lanes as a [`word`] of whether `mask` has its bit. Lane masks made from a bit
/// mask by comparisons compile, in some loops, to a branch per lane, which random lanes
/// mispredict about one time in three.
#[inline(always)]
pub fn lane_words(mask: u32) -> [u64; 8] {
    std::array::from_fn(|k| word((mask >> k) & 1 != 0))
}

/// `a` where `word` (one of [`lane_words`]) is all ones, `b` where it is zero, by their bits
/// (NaNs and signed zeros pass as they are), without a branch.
#[inline(always)]
pub fn pick(word: u64, a: f64, b: f64) -> f64 {
    f64::from_bits((a.to_bits() & word) | (b.to_bits() & !word))
}

/// The bit mask of eight lanes' flags (bit `k` for lane `k`): the inverse of [`lane_words`].
/// Folded bit by bit, flags made by vector comparisons compile to a chain of packs, shuffles
/// and a horizontal OR (about twenty instructions, one long dependency); here each lane's flag
/// is a sign bit read by two `movmskpd`.
#[inline(always)]
pub fn lane_bits(flags: [bool; 8]) -> u32 {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx"))]
    {
        use std::arch::x86_64::{_mm256_loadu_pd, _mm256_movemask_pd};
        let words = flags.map(word);
        // SAFETY: AVX is enabled at compile time; the loads read the eight words of `words`.
        unsafe {
            let lo = _mm256_movemask_pd(_mm256_loadu_pd(words.as_ptr().cast()));
            let hi = _mm256_movemask_pd(_mm256_loadu_pd(words.as_ptr().add(4).cast()));
            (lo | hi << 4) as u32
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx")))]
    flags.iter().enumerate().fold(0, |m, (k, &f)| m | u32::from(f) << k)
}

/// Converts a `[f64; 3]` record value into a vector.
#[inline]
pub fn v3(a: [f64; 3]) -> DVec3 {
    DVec3::from_array(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lane_bits_inverts_lane_words() {
        for mask in [0u32, 1, 0x80, 0xff, 0x5a, 0xa5, 0x3c, 0x81] {
            assert_eq!(lane_bits(lane_words(mask).map(|w| w != 0)), mask);
        }
        for k in 0..8 {
            let flags: [bool; 8] = std::array::from_fn(|i| i == k);
            assert_eq!(lane_bits(flags), 1 << k);
        }
    }

    /// A prefetch of any index, in bounds or not, of any slice (empty too) is harmless and
    /// changes nothing.
    #[test]
    fn prefetch_takes_any_index() {
        let v = vec![1.0f64; 1000];
        for i in [0, 1, 999, 1000, usize::MAX] {
            prefetch(&v, i);
        }
        prefetch::<u8>(&[], 0);
        assert!(v.iter().all(|&x| x == 1.0));
    }

    /// `pick` gives the bits of the lane's chosen value, whatever they are, for every mask.
    #[test]
    fn lane_words_pick_each_lane_by_its_bit() {
        let a = [1.5, f64::NAN, -0.0, f64::INFINITY, 2.0, -3.0, 0.0, f64::MIN_POSITIVE];
        let b = [-1.0, 0.0, 0.0, f64::NEG_INFINITY, f64::NAN, 7.0, -0.0, 9.0];
        for mask in 0..256u32 {
            let words = lane_words(mask);
            for k in 0..8 {
                let want = if mask & (1 << k) != 0 { a[k] } else { b[k] };
                assert_eq!(pick(words[k], a[k], b[k]).to_bits(), want.to_bits(), "mask {mask:#b}, lane {k}");
            }
        }
        // Bits beyond the eighth lane are ignored.
        assert_eq!(lane_words(0xffff_ff00), [0; 8]);
    }

    #[test]
    fn atan2_approx_is_within_its_bound_of_libm_everywhere() {
        // Directions all around the circle, at several radii, and the axes and their signed
        // zeros.
        let mut worst = 0.0f64;
        for k in 0..200_000 {
            let a = (k as f64 / 200_000.0 - 0.5) * std::f64::consts::TAU * 1.0001;
            for r in [1e-300, 1e-3, 1.0, 7.5e4, 1e300] {
                let (y, x) = (r * a.sin(), r * a.cos());
                worst = worst.max((atan2_approx(y, x) - y.atan2(x)).abs());
            }
        }
        assert!(worst < 2e-10, "worst error {worst:e}");
        for (y, x) in
            [(0.0, 1.0), (0.0, -1.0), (-0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 0.0), (-0.0, -0.0)]
        {
            let (got, want) = (atan2_approx(y, x), f64::atan2(y, x));
            assert!(
                (got - want).abs() < 1e-15 && got.is_sign_negative() == want.is_sign_negative(),
                "{y} {x}"
            );
        }
        assert!(atan2_approx(f64::NAN, 1.0).is_nan() && atan2_approx(1.0, f64::NAN).is_nan());
    }

    #[test]
    fn sincos_turns_is_within_its_bound_of_libm_everywhere() {
        let mut worst = 0.0f64;
        // [0, 1) finely (where sampled angles come from), then a few turns either way.
        for k in 0..400_000 {
            for t in [k as f64 / 400_000.0, (k as f64 - 200_000.0) / 40_000.0] {
                let (s, c) = sincos_turns(t);
                let (ws, wc) = (std::f64::consts::TAU * t).sin_cos();
                // libm's own argument 2πt is rounded, by up to half an ulp of 2πt (4e-16 at
                // t = 5); the reduced argument here is exact.
                let slack = (std::f64::consts::TAU * t).abs() * f64::EPSILON;
                worst = worst.max(((s - ws).abs() - slack).max((c - wc).abs() - slack));
            }
        }
        assert!(worst < 3e-16, "worst error {worst:e}");
        // Whole and quarter turns are exact, and sin² + cos² stays 1.
        for (t, want) in [
            (0.0, (0.0, 1.0)),
            (0.25, (1.0, 0.0)),
            (0.5, (0.0, -1.0)),
            (-0.25, (-1.0, 0.0)),
            (3.0, (0.0, 1.0)),
        ] {
            let (s, c) = sincos_turns(t);
            assert!(s == want.0 && c == want.1, "{t}: {s} {c}");
        }
        let (s, c) = sincos_turns(0.123_456_789);
        assert!((s * s + c * c - 1.0).abs() < 4e-16);
        assert!(sincos_turns(f64::NAN).0.is_nan() && sincos_turns(f64::INFINITY).1.is_nan());
    }

    /// The eight-lane `f32` version: within 2.5e-7 of the `f64` one on [0, 1) and a few turns
    /// either way, exact at whole and quarter turns, NaN for NaN and ±∞, and each lane's value
    /// its own (the same whichever lane it sits in).
    #[test]
    fn sincos_turns8_is_within_its_bound_everywhere() {
        let mut worst = 0.0f64;
        for k in 0..100_000 {
            let base = [k as f32 / 100_000.0, (k as f32 - 50_000.0) / 10_000.0];
            for t in base {
                let lanes: F8 = std::array::from_fn(|i| if i == k % 8 { t } else { 0.37 * i as f32 });
                let (s, c) = sincos_turns8(&lanes);
                let (ws, wc) = sincos_turns(f64::from(t));
                let i = k % 8;
                worst = worst.max((f64::from(s[i]) - ws).abs()).max((f64::from(c[i]) - wc).abs());
                let (s1, c1) = sincos_turns8(&[t; 8]);
                assert_eq!((s1[3].to_bits(), c1[3].to_bits()), (s[i].to_bits(), c[i].to_bits()), "{t}");
            }
        }
        assert!(worst < 2.5e-7, "worst error {worst:e}");
        let t: F8 = [0.0, 0.25, 0.5, -0.25, 3.0, 0.75, f32::NAN, f32::INFINITY];
        let (s, c) = sincos_turns8(&t);
        let want = [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (0.0, 1.0), (-1.0, 0.0)];
        for (i, w) in want.iter().enumerate() {
            assert!(s[i] == w.0 && c[i] == w.1, "{}: {} {}", t[i], s[i], c[i]);
        }
        assert!(s[6].is_nan() && c[6].is_nan() && s[7].is_nan() && c[7].is_nan());
    }

    /// The eight-lane `f32` atan2 is within 3.5e-7 of the `f64` one on directions all round and
    /// near the axes, with its signed zeros and quadrants, NaN for a NaN argument.
    #[test]
    fn atan2_8_is_within_its_bound_everywhere() {
        let mut worst = 0.0f64;
        let mut check = |ys: F8, xs: F8| {
            let got = atan2_8(&ys, &xs);
            for i in 0..8 {
                let want = f64::from(ys[i]).atan2(f64::from(xs[i]));
                worst = worst.max((f64::from(got[i]) - want).abs());
            }
        };
        for k in 0..50_000 {
            let (s, c) = sincos_turns(k as f64 / 50_000.0);
            let r = [1.0, 3e-3, 7e4, 1e-30, 0.5, 2.0, 1e30, 0.1];
            check(std::array::from_fn(|i| (s * r[i]) as f32), std::array::from_fn(|i| (c * r[i]) as f32));
        }
        assert!(worst < 3.5e-7, "worst error {worst:e}");
        let zeros = atan2_8(
            &[0.0, -0.0, 0.0, -0.0, 1.0, -1.0, 0.0, 5.0],
            &[1.0, 1.0, -1.0, -1.0, 0.0, 0.0, 0.0, -0.0],
        );
        let want = [0.0, -0.0, std::f32::consts::PI, -std::f32::consts::PI];
        for i in 0..4 {
            assert_eq!(zeros[i].to_bits(), want[i].to_bits(), "lane {i}");
        }
        assert!(
            (zeros[4] - std::f32::consts::FRAC_PI_2).abs() < 1e-7
                && (zeros[5] + std::f32::consts::FRAC_PI_2).abs() < 1e-7
        );
        let nan = atan2_8(
            &[f32::NAN, 1.0, f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0],
            &[1.0, f32::NAN, f32::NAN, 1.0, 1.0, 1.0, 1.0, 1.0],
        );
        assert!(nan[0].is_nan() && nan[1].is_nan() && nan[2].is_nan());
    }

    /// The `f32` frame is the `f64` one to `f32` rounding: unit tangents orthogonal to the
    /// normal and to each other, for normals of every direction (both signs of z).
    #[test]
    fn sampling_frame8_is_the_frame_in_f32() {
        for k in 0..1000 {
            let (a, b) = ((k as f64 * 0.618_034).fract(), (k as f64 * 0.414_214).fract());
            let (sz, cz) = sincos_turns(0.5 * b);
            let (sp, cp) = sincos_turns(a);
            let n = DVec3::new(sz * cp, sz * sp, cz);
            let lanes: [F8; 3] = std::array::from_fn(|ax| [n[ax] as f32; 8]);
            let (t, bt) = sampling_frame8(&lanes);
            let (wt, wb) = sampling_frame(n);
            for ax in 0..3 {
                assert!((f64::from(t[ax][5]) - wt[ax]).abs() < 2e-6, "{n}: {:?} {wt}", t);
                assert!((f64::from(bt[ax][5]) - wb[ax]).abs() < 2e-6, "{n}: {:?} {wb}", bt);
            }
        }
    }

    #[test]
    fn the_branch_free_steps_give_the_branches_bits() {
        let values = [0.0, -0.0, 1.0, -1.0, 0.3, -0.7, 1e-300, f64::INFINITY, f64::NAN, f64::MIN_POSITIVE];
        let bits = |(a, b): (f64, f64)| (a.to_bits(), b.to_bits());
        for q in -2..=2 {
            for &s in &values {
                for &c in &values {
                    let want = match q {
                        0 => (s, c),
                        1 => (c, -s),
                        -1 => (-c, s),
                        _ => (-s, -c),
                    };
                    assert_eq!(bits(quarter_turn(q, s, c)), bits(want), "q {q}, sin {s}, cos {c}");
                }
            }
        }
        for a in [0.0, 1e-300, 0.4, std::f64::consts::FRAC_PI_2, 1.5, std::f64::consts::PI] {
            for x in [0.0, -0.0, 2.0, -2.0, f64::NAN, -f64::NAN, f64::NEG_INFINITY] {
                let want = if x.is_sign_negative() { std::f64::consts::PI - a } else { a };
                assert_eq!(left_half(a, x).to_bits(), want.to_bits(), "a {a}, x {x}");
            }
        }
    }

    #[test]
    fn sampling_frame_is_orthonormal_everywhere() {
        // The poles (either sign of zero), near the south pole where `sign + n.z` cancels, and
        // a spread of directions.
        let mut ns = vec![DVec3::Z, -DVec3::Z, DVec3::X, -DVec3::Y, DVec3::new(1.0, 0.0, -0.0)];
        ns.push(DVec3::new(1e-9, -2e-9, -1.0).normalize());
        ns.push(DVec3::new(-3e-5, 1e-5, -1.0).normalize());
        for i in 0..2000 {
            let (s, c) = sincos_turns(i as f64 * 0.618_033_988_749);
            let z = 1.0 - (i as f64 + 0.5) / 1000.0;
            let r = (1.0 - z * z).sqrt();
            ns.push(DVec3::new(r * c, r * s, z));
        }
        for n in ns {
            let (u, v) = sampling_frame(n);
            assert!((u.length() - 1.0).abs() < 1e-12 && (v.length() - 1.0).abs() < 1e-12, "{n}");
            assert!(u.dot(n).abs() < 1e-12 && v.dot(n).abs() < 1e-12 && u.dot(v).abs() < 1e-12, "{n}");
            // Right-handed: u x v = n.
            assert!((u.cross(v) - n).length() < 1e-12, "{n}");
        }
    }

    #[test]
    fn orthonormal_pair_is_orthonormal() {
        for n in [
            DVec3::X,
            DVec3::Y,
            DVec3::Z,
            DVec3::new(1.0, 2.0, -3.0).normalize(),
            DVec3::new(-0.3, 0.0, 0.9).normalize(),
        ] {
            let (u, v) = orthonormal_pair(n);
            assert!((u.length() - 1.0).abs() < 1e-12 && (v.length() - 1.0).abs() < 1e-12);
            assert!(u.dot(n).abs() < 1e-12 && v.dot(n).abs() < 1e-12 && u.dot(v).abs() < 1e-12);
        }
    }

    #[test]
    fn uniform_scale_recognises_similarities_only() {
        let rot = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        assert!(
            (uniform_scale(&(rot * DMat3::from_diagonal(DVec3::splat(3.0)))).unwrap() - 3.0).abs() < 1e-12
        );
        assert!(
            (uniform_scale(&DMat3::from_diagonal(DVec3::new(-0.5, 0.5, 0.5))).unwrap() - 0.5).abs() < 1e-12
        );
        assert_eq!(uniform_scale(&(rot * DMat3::from_diagonal(DVec3::new(1.0, 1.0, 1.001)))), None);
        assert_eq!(
            uniform_scale(&DMat3::from_cols(DVec3::X, DVec3::new(0.1, 1.0, 0.0), DVec3::Z)),
            None,
            "shear"
        );
        assert_eq!(uniform_scale(&DMat3::ZERO), None);
    }

    #[test]
    fn normal_matrix_keeps_normals_perpendicular_under_nonuniform_scale() {
        let t = Transform::new(DAffine3::from_scale(DVec3::new(2.0, 0.5, -1.0))).unwrap();
        // A plane with normal (1,1,0)/√2 contains the tangent (1,-1,0).
        let n = DVec3::new(1.0, 1.0, 0.0).normalize();
        let tangent = t.to_world.transform_vector3(DVec3::new(1.0, -1.0, 0.0));
        assert!(t.normal_to_world(n).dot(tangent).abs() < 1e-12);
        assert!(Transform::new(DAffine3::from_scale(DVec3::new(1.0, 0.0, 1.0))).is_none());
    }
}
