//! Deterministic, stratified sample values: a padded, Owen-scrambled Sobol sampler.
//!
//! Every camera sample of a pixel draws its random numbers in a fixed order of *dimensions*
//! (pixel position, lens, time, then whatever shading asks for: area-light points, glossy
//! directions, environment directions, ...). Dimension `k` of sample `i` of pixel `(x, y)` is a
//! pure function of (frame seed, x, y, i, k): no thread-local or global state, so a pixel's
//! samples are the same whichever tile, thread, process or machine renders it, which is what
//! makes farm renders equal CLI renders bit for bit.
//!
//! Within a pixel the values are stratified in every dimension: each request (one or two
//! numbers) gets its own pair of Sobol dimensions 0 and 1 (a (0, 2)-sequence), whose sample
//! index is shuffled and whose coordinates are Owen-scrambled by hashes of (seed, pixel,
//! dimension) ("padding", as in pbrt-v4's PaddedSobolSampler, with Burley's hash-based Owen
//! scrambling, "Practical Hash-based Owen Scrambling", JCGT 2020). So the first 2^k samples of
//! a pixel fall one per cell of every 2^k-cell elementary interval of each 2-D request
//! (e.g. 8x8 squares for 64 samples), and different requests are decorrelated. Any sample
//! count works; powers of two are stratified best.

/// Murmur3's 64-bit finaliser: a bijective mixer with full avalanche.
#[inline]
fn fmix64(mut k: u64) -> u64 {
    k ^= k >> 33;
    k = k.wrapping_mul(0xff51_afd7_ed55_8ccd);
    k ^= k >> 33;
    k = k.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    k ^= k >> 33;
    k
}

const GOLDEN: u64 = 0x9e37_79b9_7f4a_7c15;

/// Burley's variant of the Laine-Karras permutation: every bit of the result depends only on
/// itself and the *less* significant bits of `x` (additions and products with even constants
/// carry upwards only), which is what nested uniform scrambling needs in the bit-reversed domain.
#[inline]
fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x
}

/// Owen (nested uniform) scrambling of a 32-bit fixed-point value in [0, 1): each bit flips
/// depending only on the more significant bits above it and the seed.
#[inline]
fn owen_scramble(x: u32, seed: u32) -> u32 {
    laine_karras(x.reverse_bits(), seed).reverse_bits()
}

/// Sobol dimension 1 (the Pascal matrix mod 2), bit-reversed: `sobol_dim1(i).reverse_bits()`.
/// Dimension 0 is the van der Corput sequence, `index.reverse_bits()`; together they form a
/// (0, 2)-sequence in base 2.
///
/// The value is the XOR of one direction number `v_n` per set bit `n` of `index`, with
/// `v_0 = 2^31` and `v_{n+1} = v_n ^ (v_n >> 1)`: bit `31 − j` of `v_n` is C(n, j) mod 2, which
/// by Lucas' theorem is 1 exactly when the bits of `j` are a subset of those of `n`. So bit `j`
/// of the reversed value is the XOR of the index bits at every position `n ⊇ j`: a superset
/// transform over the five bits of a position, one shift-and-XOR per bit. Pure arithmetic on
/// one word, so eight lanes vectorise (tables would need gathers).
#[inline]
fn sobol_dim1_reversed(index: u32) -> u32 {
    let mut x = index;
    x ^= (x >> 1) & 0x5555_5555;
    x ^= (x >> 2) & 0x3333_3333;
    x ^= (x >> 4) & 0x0f0f_0f0f;
    x ^= (x >> 8) & 0x00ff_00ff;
    x ^= x >> 16;
    x
}

/// 32-bit fixed point to a float in [0, 1).
#[inline]
fn unit(v: u32) -> f64 {
    f64::from(v) * (1.0 / 4_294_967_296.0)
}

/// [`unit`] by way of the exponent bits of 2^52 (`2^52 + v` exactly, minus 2^52), which eight
/// lanes compute as vectors where the processor has no unsigned conversion: the same value
/// (both are exact).
#[inline(always)]
fn unit_exact(v: u32) -> f64 {
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    (f64::from_bits(TWO_52.to_bits() | u64::from(v)) - TWO_52) * (1.0 / 4_294_967_296.0)
}

/// The sample values of one camera sample of one pixel, drawn dimension by dimension.
#[derive(Clone, Debug)]
pub struct Sampler {
    /// Hash of (frame seed, pixel).
    key: u64,
    /// The camera sample's index within its pixel.
    index: u32,
    /// Next dimension (one per request).
    dim: u64,
}

/// The frame's part of every pixel's sampler key, hashed once for all the pixels of a tile:
/// `FrameKey::new(seed).sampler(x, y, s)` is `Sampler::new(seed, x, y, s)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameKey(u64);

impl FrameKey {
    pub fn new(frame_seed: u64) -> Self {
        FrameKey(fmix64(frame_seed ^ GOLDEN))
    }

    /// The sampler of camera sample `sample` of pixel (x, y).
    #[inline]
    pub fn sampler(self, x: u32, y: u32, sample: u32) -> Sampler {
        Sampler { key: fmix64(self.0 ^ ((x as u64) << 32 | y as u64)), index: sample, dim: 0 }
    }
}

impl Sampler {
    pub fn new(frame_seed: u64, x: u32, y: u32, sample: u32) -> Self {
        FrameKey::new(frame_seed).sampler(x, y, sample)
    }

    /// The sampler of camera sample `sample` of the same pixel: `Sampler::new(seed, x, y,
    /// sample)` without hashing the pixel again.
    #[inline]
    pub fn with_sample(&self, sample: u32) -> Self {
        Sampler { key: self.key, index: sample, dim: 0 }
    }

    /// How many requests this sampler has drawn: the dimension the next one follows.
    #[inline]
    pub fn drawn(&self) -> u64 {
        self.dim
    }

    /// Moves on to request number `drawn`, when fewer have been drawn: a step that reserves a
    /// fixed number of requests and uses fewer leaves later requests at the same dimensions
    /// whatever it used.
    #[inline]
    pub fn skip_to(&mut self, drawn: u64) {
        self.dim = self.dim.max(drawn);
    }

    /// The next request's point of the scrambled (0, 2)-sequence, as fixed-point values.
    #[inline]
    fn next_bits(&mut self) -> (u32, u32) {
        self.dim += 1;
        point(self.index, DimSeeds::of(self.key, self.dim))
    }

    /// One number in [0, 1), stratified over the pixel's samples.
    #[inline]
    pub fn next_1d(&mut self) -> f64 {
        unit(self.next_bits().0)
    }

    /// Two numbers in [0, 1)², stratified jointly over the pixel's samples.
    #[inline]
    pub fn next_2d(&mut self) -> (f64, f64) {
        let (a, b) = self.next_bits();
        (unit(a), unit(b))
    }

    /// [`Self::next_2d`] of each of up to [`GROUP_LANES`] samplers at once: the same values.
    /// When they are samples of one pixel standing at the same dimension (a group of camera
    /// samples drawing their pixel positions, lens points or times), the dimension's seeds are
    /// hashed once and the samples' scrambles run as one eight-lane computation.
    #[inline]
    pub fn next_2d_group(samplers: &mut [Sampler]) -> [(f64, f64); GROUP_LANES] {
        let [[u, v]] = Self::next_2d_groups::<1>(samplers);
        std::array::from_fn(|l| (u[l], v[l]))
    }

    /// `M` requests of [`Self::next_2d_group`] in a row, by request, coordinate and lane:
    /// `out[m][0][l]` and `out[m][1][l]` are the `m`-th request's two values for sampler `l`
    /// (lanes side by side, as the camera rays made from them are computed). The requests'
    /// scrambles are independent chains of multiplications (each one's latency, not the
    /// processor's throughput, is what they cost), so drawing them together lets the processor
    /// overlap them.
    pub fn next_2d_groups<const M: usize>(samplers: &mut [Sampler]) -> [[[f64; GROUP_LANES]; 2]; M] {
        Self::next_2d_groups_of::<M>(samplers, u32::MAX)
    }

    /// [`Self::next_2d_groups`] of the samplers whose bit is set in `mask` (bit `l` for
    /// `samplers[l]`): they draw the values they would draw alone, and the others neither draw
    /// nor move on (their values are zero). When the drawing samplers stand at the same
    /// dimension, every lane's scramble runs as one eight-lane computation and the lanes
    /// outside `mask` are dropped afterwards: a group of paths that lost some lanes still
    /// draws side by side. Samplers of one pixel share the dimension's seeds; samplers of
    /// several (paths gathered from several groups) hash each lane's own in the same loop.
    pub fn next_2d_groups_of<const M: usize>(
        samplers: &mut [Sampler],
        mask: u32,
    ) -> [[[f64; GROUP_LANES]; 2]; M] {
        assert!(samplers.len() <= GROUP_LANES, "at most {GROUP_LANES} samplers a group");
        let mut out = [[[0.0; GROUP_LANES]; 2]; M];
        if samplers.is_empty() {
            return out;
        }
        let mask = mask & (u32::MAX >> (32 - samplers.len()));
        if mask == 0 {
            return out;
        }
        let first = &samplers[mask.trailing_zeros() as usize];
        let (key, dim) = (first.key, first.dim);
        // Whether the drawing samplers stand at other dimensions than the first, or belong to
        // other pixels: one test a lane, and the masks of which lanes only when some lanes
        // do not draw and some differ.
        let all = u32::MAX >> (32 - samplers.len());
        let (same_dim, same_key) =
            samplers.iter().fold((true, true), |(d, k), s| (d & (s.dim == dim), k & (s.key == key)));
        let (dim_differs, key_differs) = if mask == all || (same_dim && same_key) {
            (!same_dim, !same_key)
        } else {
            let (mut off_dim, mut off_key) = (0u32, 0u32);
            for (l, s) in samplers.iter().enumerate() {
                off_dim |= u32::from(s.dim != dim) << l;
                off_key |= u32::from(s.key != key) << l;
            }
            (off_dim & mask != 0, off_key & mask != 0)
        };
        if dim_differs {
            // Each sampler's requests in its own order.
            let mut rest = mask;
            while rest != 0 {
                let l = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                for o in out.iter_mut() {
                    (o[0][l], o[1][l]) = samplers[l].next_2d();
                }
            }
            return out;
        }
        let index: [u32; GROUP_LANES] = std::array::from_fn(|l| samplers.get(l).map_or(0, |s| s.index));
        let mut a = [[0u32; GROUP_LANES]; M];
        let mut b = [[0u32; GROUP_LANES]; M];
        if !key_differs {
            // Samples of one pixel: the dimension's seeds hashed once.
            let seeds: [DimSeeds; M] = std::array::from_fn(|m| DimSeeds::of(key, dim + 1 + m as u64));
            for m in 0..M {
                for l in 0..GROUP_LANES {
                    (a[m][l], b[m][l]) = point(index[l], seeds[m]);
                }
            }
        } else {
            // Samples of several pixels (paths gathered from several groups): each lane hashes
            // its pixel's seeds, side by side.
            let keys: [u64; GROUP_LANES] = std::array::from_fn(|l| samplers.get(l).map_or(key, |s| s.key));
            for m in 0..M {
                for l in 0..GROUP_LANES {
                    (a[m][l], b[m][l]) = point(index[l], DimSeeds::of(keys[l], dim + 1 + m as u64));
                }
            }
        }
        if mask == all {
            for s in samplers.iter_mut() {
                s.dim = dim + M as u64;
            }
        } else {
            for (l, s) in samplers.iter_mut().enumerate() {
                s.dim = if mask >> l & 1 != 0 { dim + M as u64 } else { s.dim };
            }
        }
        for m in 0..M {
            for l in 0..GROUP_LANES {
                out[m][0][l] = unit(a[m][l]);
                out[m][1][l] = unit(b[m][l]);
            }
        }
        let mut outside =
            if mask == all && samplers.len() == GROUP_LANES { 0 } else { !mask & ((1 << GROUP_LANES) - 1) };
        while outside != 0 {
            let l = outside.trailing_zeros() as usize;
            outside &= outside - 1;
            for o in out.iter_mut() {
                (o[0][l], o[1][l]) = (0.0, 0.0);
            }
        }
        out
    }
}

/// The seeds of a pixel's first [`PixelSeeds::REQUESTS`] requests (its position, lens and
/// time), hashed once for all its camera samples: a group of a pixel's samples draws them with
/// [`PixelSeeds::draw`] and no sampler's hashing or checks, as [`Sampler::next_2d_groups`]
/// draws them.
#[derive(Clone, Copy, Debug)]
pub struct PixelSeeds {
    seeds: [DimSeeds; PixelSeeds::REQUESTS],
}

impl PixelSeeds {
    /// How many requests the seeds serve.
    pub const REQUESTS: usize = 3;

    /// The seeds of the pixel whose samplers are `pixel`'s (at any sample and dimension).
    pub fn of(pixel: &Sampler) -> Self {
        PixelSeeds { seeds: std::array::from_fn(|m| DimSeeds::of(pixel.key, 1 + m as u64)) }
    }

    /// Requests 1 to `M` of the pixel's samples `first` to `first + 7`, by request, coordinate
    /// and lane: what [`Sampler::next_2d_groups::<M>`] draws for their samplers standing at
    /// dimension 0 (the samplers then move on with [`Sampler::skip_to`]`(M)`). A group of fewer
    /// samples reads its lanes and leaves the others.
    #[inline(always)]
    pub fn draw<const M: usize>(&self, first: u32) -> [[[f64; GROUP_LANES]; 2]; M] {
        const { assert!(M <= PixelSeeds::REQUESTS, "at most the seeded requests") };
        std::array::from_fn(|m| {
            let seeds = self.seeds[m];
            let mut a = [0u32; GROUP_LANES];
            let mut b = [0u32; GROUP_LANES];
            for l in 0..GROUP_LANES {
                (a[l], b[l]) = point(first.wrapping_add(l as u32), seeds);
            }
            [a.map(unit), b.map(unit)]
        })
    }
}

/// How many samplers [`Sampler::next_2d_group`] serves at once.
pub const GROUP_LANES: usize = 8;

/// The samplers of a group of paths (one a lane, [`GROUP_LANES`] lanes), by field then lane,
/// so that a group's draw compares, hashes and scrambles its lanes as vectors. Each lane draws
/// what its [`Sampler`] draws alone: [`Self::get`] and [`Self::set`] move a lane's sampler in
/// and out unchanged.
#[derive(Clone, Debug)]
pub struct SamplerLanes {
    key: [u64; GROUP_LANES],
    dim: [u64; GROUP_LANES],
    index: [u32; GROUP_LANES],
}

impl SamplerLanes {
    /// The lanes holding `samplers`, in order.
    pub fn new(samplers: &[Sampler; GROUP_LANES]) -> Self {
        SamplerLanes {
            key: std::array::from_fn(|l| samplers[l].key),
            dim: std::array::from_fn(|l| samplers[l].dim),
            index: std::array::from_fn(|l| samplers[l].index),
        }
    }

    /// Lane `l`'s sampler.
    #[inline]
    pub fn get(&self, l: usize) -> Sampler {
        Sampler { key: self.key[l], index: self.index[l], dim: self.dim[l] }
    }

    /// Puts `s` into lane `l`.
    #[inline]
    pub fn set(&mut self, l: usize, s: &Sampler) {
        (self.key[l], self.index[l], self.dim[l]) = (s.key, s.index, s.dim);
    }

    /// Moves lane `k` of `from` into lane `l`.
    #[inline]
    pub fn take(&mut self, l: usize, from: &SamplerLanes, k: usize) {
        (self.key[l], self.index[l], self.dim[l]) = (from.key[k], from.index[k], from.dim[k]);
    }

    /// [`Sampler::next_2d_groups_of`] of the lanes' samplers: `M` requests of the lanes whose
    /// bit is set in `mask`, by request, coordinate and lane, zero for the other lanes (which
    /// do not move on). When the drawing lanes stand at one dimension, every lane's scramble
    /// runs as one eight-lane computation (the dimension's seeds hashed once when they are
    /// samples of one pixel, else each lane's side by side); else each draws alone.
    #[inline(never)]
    pub fn next_2d<const M: usize>(&mut self, mask: u32) -> [[[f64; GROUP_LANES]; 2]; M] {
        let mut out = [[[0.0; GROUP_LANES]; 2]; M];
        let mask = mask & ((1 << GROUP_LANES) - 1);
        if mask & mask.wrapping_sub(1) == 0 {
            // One lane or none: its own draws.
            if mask != 0 {
                let l = mask.trailing_zeros() as usize;
                let mut s = self.get(l);
                for o in &mut out {
                    (o[0][l], o[1][l]) = s.next_2d();
                }
                self.dim[l] = s.dim;
            }
            return out;
        }
        let first = mask.trailing_zeros() as usize;
        let (key, dim) = (self.key[first], self.dim[first]);
        // Each lane's word of all ones when it draws (selections by bits, not branches).
        let on: [u64; GROUP_LANES] = std::array::from_fn(|l| 0u64.wrapping_sub(u64::from((mask >> l) & 1)));
        let (mut off_dim, mut off_key) = (0u32, 0u32);
        for l in 0..GROUP_LANES {
            off_dim |= u32::from(self.dim[l] != dim) << l;
            off_key |= u32::from(self.key[l] != key) << l;
        }
        if off_dim & mask != 0 {
            // Each lane's requests in its own order.
            let mut rest = mask;
            while rest != 0 {
                let l = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                let mut s = self.get(l);
                for o in &mut out {
                    (o[0][l], o[1][l]) = s.next_2d();
                }
                self.dim[l] = s.dim;
            }
            return out;
        }
        let mut a = [[0u32; GROUP_LANES]; M];
        let mut b = [[0u32; GROUP_LANES]; M];
        if off_key & mask == 0 {
            let seeds: [DimSeeds; M] = std::array::from_fn(|m| DimSeeds::of(key, dim + 1 + m as u64));
            for m in 0..M {
                for l in 0..GROUP_LANES {
                    (a[m][l], b[m][l]) = point(self.index[l], seeds[m]);
                }
            }
        } else {
            for m in 0..M {
                for l in 0..GROUP_LANES {
                    (a[m][l], b[m][l]) = point(self.index[l], DimSeeds::of(self.key[l], dim + 1 + m as u64));
                }
            }
        }
        let next = dim + M as u64;
        for (d, w) in self.dim.iter_mut().zip(on) {
            *d = (next & w) | (*d & !w);
        }
        for m in 0..M {
            for l in 0..GROUP_LANES {
                out[m][0][l] = f64::from_bits(unit_exact(a[m][l]).to_bits() & on[l]);
                out[m][1][l] = f64::from_bits(unit_exact(b[m][l]).to_bits() & on[l]);
            }
        }
        out
    }
}

/// The scrambling seeds of one dimension of one pixel (the same for all its samples).
#[derive(Clone, Copy, Debug)]
struct DimSeeds {
    /// Seed of the Owen scramble of the sample index.
    index: u32,
    /// Seeds of the two coordinates' Owen scrambles.
    a: u32,
    b: u32,
}

impl DimSeeds {
    #[inline]
    fn of(key: u64, dim: u64) -> Self {
        let h = fmix64(key ^ dim.wrapping_mul(GOLDEN));
        let h2 = fmix64(h ^ GOLDEN);
        DimSeeds { index: h as u32, a: (h >> 32) as u32, b: h2 as u32 }
    }
}

/// Point `index` of a dimension's scrambled (0, 2)-sequence, as fixed-point values.
#[inline(always)]
fn point(index: u32, seeds: DimSeeds) -> (u32, u32) {
    // Shuffle the index (an Owen scramble of it: within each block of 2^k samples a
    // permutation), then scramble each coordinate with its own seed.
    let i = owen_scramble(index, seeds.index);
    // owen_scramble(i.reverse_bits(), ..) with the two reversals of `i` cancelled.
    let a = laine_karras(i, seeds.a).reverse_bits();
    // owen_scramble(sobol_dim1(i), ..) with the reversal inside it folded in.
    let b = laine_karras(sobol_dim1_reversed(i), seeds.b).reverse_bits();
    (a, b)
}

/// Frame seed of camera `camera` of a scene: rendering a camera never depends on the others.
pub fn frame_seed(base: u64, camera: usize) -> u64 {
    fmix64(base ^ fmix64(camera as u64 + 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_key_makes_the_pixels_samplers() {
        for (seed, x, y, s) in [(0, 0, 0, 0), (0x5eed, 12, 34, 5), (u64::MAX, u32::MAX, 7, u32::MAX)] {
            let (mut a, mut b) = (Sampler::new(seed, x, y, s), FrameKey::new(seed).sampler(x, y, s));
            assert_eq!((a.next_2d(), a.next_2d()), (b.next_2d(), b.next_2d()));
        }
        assert_ne!(FrameKey::new(1).sampler(2, 3, 0).next_2d(), FrameKey::new(1).sampler(3, 2, 0).next_2d());
    }

    /// The points of request `dim` (counted from 1) over samples 0..n of pixel (x, y).
    fn points(x: u32, y: u32, n: u32, dim: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|s| {
                let mut r = Sampler::new(7, x, y, s);
                let mut p = (0.0, 0.0);
                for _ in 0..dim {
                    p = r.next_2d();
                }
                p
            })
            .collect()
    }

    /// Sobol dimension 1 the direct way: one direction number per set bit of the index.
    fn sobol_dim1_bit_loop(mut index: u32) -> u32 {
        let mut v: u32 = 1 << 31;
        let mut r = 0;
        while index != 0 {
            if index & 1 != 0 {
                r ^= v;
            }
            index >>= 1;
            v ^= v >> 1;
        }
        r
    }

    #[test]
    fn the_superset_transform_gives_the_bit_loops_sobol_values() {
        let sobol_dim1 = |i: u32| sobol_dim1_reversed(i).reverse_bits();
        // Every single bit, the first 2^16 indices, and hashed (all-bits) indices.
        for b in 0..32 {
            assert_eq!(sobol_dim1(1 << b), sobol_dim1_bit_loop(1 << b), "bit {b}");
        }
        for i in 0..1u32 << 16 {
            assert_eq!(sobol_dim1(i), sobol_dim1_bit_loop(i), "index {i}");
        }
        for k in 0..1u64 << 16 {
            let i = fmix64(k) as u32;
            assert_eq!(sobol_dim1(i), sobol_dim1_bit_loop(i), "index {i:#x}");
        }
        // Its first values in index (not Gray-code) order: 0, 1/2, 3/4, 1/4, 5/8, 1/8, 3/8, 7/8.
        let first: Vec<u32> = (0..8).map(|i| sobol_dim1(i) >> 29).collect();
        assert_eq!(first, [0, 4, 6, 2, 5, 1, 3, 7]);
    }

    #[test]
    fn same_key_same_values_different_keys_differ() {
        let draw = |x, y, s| {
            let mut r = Sampler::new(7, x, y, s);
            (0..8).map(|_| r.next_1d()).collect::<Vec<f64>>()
        };
        assert_eq!(draw(3, 4, 5), draw(3, 4, 5));
        assert_ne!(draw(3, 4, 5), draw(4, 3, 5));
        assert_ne!(draw(3, 4, 5), draw(3, 4, 6));
        let mut r = Sampler::new(7, 3, 4, 0).with_sample(5);
        assert_eq!((0..8).map(|_| r.next_1d()).collect::<Vec<f64>>(), draw(3, 4, 5));
    }

    #[test]
    fn a_group_draws_what_each_sampler_draws() {
        let pixel = Sampler::new(0x5eed, 12, 34, 0);
        for count in [1, 3, 8] {
            // Camera samples of one pixel, at the first dimensions and after a few.
            for skip in [0, 1, 5] {
                let mut group: Vec<Sampler> = (0..count).map(|k| pixel.with_sample(90 + k)).collect();
                for s in &mut group {
                    (0..skip).for_each(|_| _ = s.next_1d());
                }
                let mut each = group.clone();
                let got = Sampler::next_2d_group(&mut group);
                for (l, s) in each.iter_mut().enumerate() {
                    assert_eq!(got[l], s.next_2d(), "{count} samplers, lane {l}, after {skip}");
                    // Both continue at the same dimension.
                    assert_eq!(group[l].next_1d(), s.next_1d());
                }
            }
        }
        // Samplers at different dimensions or of different pixels: each draws its own.
        let mut mixed = [pixel.with_sample(1), Sampler::new(0x5eed, 13, 34, 1), pixel.with_sample(2)];
        mixed[2].next_1d();
        let mut each = mixed.clone();
        let got = Sampler::next_2d_group(&mut mixed);
        for (l, s) in each.iter_mut().enumerate() {
            assert_eq!(got[l], s.next_2d(), "mixed lane {l}");
        }
    }

    #[test]
    fn skipping_to_a_request_draws_what_follows_the_skipped_ones() {
        let pixel = Sampler::new(0x5eed, 3, 4, 7);
        let mut drew = pixel.clone();
        drew.next_2d();
        drew.next_2d();
        let mut skipped = pixel.clone();
        assert_eq!(skipped.drawn(), 0);
        skipped.skip_to(2);
        assert_eq!(skipped.drawn(), drew.drawn());
        // Never back: a sampler that has drawn more stays where it is.
        skipped.skip_to(1);
        assert_eq!(skipped.drawn(), 2);
        assert_eq!(skipped.next_2d(), drew.next_2d());
    }

    #[test]
    fn requests_drawn_together_are_those_drawn_in_a_row() {
        let pixel = Sampler::new(0x5eed, 12, 34, 0);
        let mut group: Vec<Sampler> = (0..8).map(|k| pixel.with_sample(16 + k)).collect();
        group.iter_mut().for_each(|s| _ = s.next_2d());
        let mut each = group.clone();
        let got = Sampler::next_2d_groups::<3>(&mut group);
        for (l, s) in each.iter_mut().enumerate() {
            for (m, req) in got.iter().enumerate() {
                assert_eq!((req[0][l], req[1][l]), s.next_2d(), "lane {l}, request {m}");
            }
            assert_eq!(group[l].next_1d(), s.next_1d(), "lane {l} continues where it would");
        }
        // A mixed group: each sampler draws its two in order.
        let mut mixed = [pixel.with_sample(1), Sampler::new(0x5eed, 13, 34, 1)];
        let mut each = mixed.clone();
        let got = Sampler::next_2d_groups::<2>(&mut mixed);
        for (l, s) in each.iter_mut().enumerate() {
            let (first, second) = ((got[0][0][l], got[0][1][l]), (got[1][0][l], got[1][1][l]));
            assert_eq!((first, second), (s.next_2d(), s.next_2d()), "mixed lane {l}");
        }
    }

    #[test]
    fn a_pixels_seeds_draw_what_its_samplers_draw() {
        let pixel = Sampler::new(0x5eed, 12, 34, 9);
        let seeds = PixelSeeds::of(&pixel);
        for first in [0u32, 8, 96, u32::MAX - 3] {
            let got = seeds.draw::<3>(first);
            for l in 0..GROUP_LANES {
                let mut s = pixel.with_sample(first.wrapping_add(l as u32));
                for (m, req) in got.iter().enumerate() {
                    assert_eq!((req[0][l], req[1][l]), s.next_2d(), "sample {first}+{l}, request {m}");
                }
            }
            // Fewer requests are the first of them.
            assert_eq!(seeds.draw::<1>(first)[0], got[0]);
            assert_eq!(seeds.draw::<2>(first)[1], got[1]);
        }
        // Another pixel's seeds draw other values.
        assert_ne!(PixelSeeds::of(&Sampler::new(0x5eed, 13, 34, 0)).draw::<1>(0), seeds.draw::<1>(0));
    }

    #[test]
    fn a_masked_group_draws_for_its_lanes_only() {
        let pixel = Sampler::new(0x5eed, 12, 34, 0);
        for mask in [0b1011_0110u32, 0b1000_0001, 0b0000_0100, 0, 0xff] {
            // Eight samples of one pixel at one dimension, the same with one sampler of the
            // mask a request ahead (each then draws alone), and samples of three pixels at one
            // dimension (each lane with its pixel's seeds).
            for (ahead, pixels) in [(false, 1), (true, 1), (false, 3)] {
                let mut group: Vec<Sampler> = (0..8)
                    .map(|k| match pixels {
                        1 => pixel.with_sample(40 + k),
                        _ => Sampler::new(0x5eed, 12 + k % pixels, 34, 40 + k),
                    })
                    .collect();
                group.iter_mut().for_each(|s| _ = s.next_2d());
                if ahead && mask != 0 {
                    group[mask.trailing_zeros() as usize].next_1d();
                }
                let mut each = group.clone();
                let got = Sampler::next_2d_groups_of::<2>(&mut group, mask);
                for (l, s) in each.iter_mut().enumerate() {
                    if mask & 1 << l != 0 {
                        for (m, req) in got.iter().enumerate() {
                            assert_eq!(
                                (req[0][l], req[1][l]),
                                s.next_2d(),
                                "mask {mask:#b}, lane {l}, request {m}"
                            );
                        }
                    } else {
                        assert_eq!(
                            got.map(|req| (req[0][l], req[1][l])),
                            [(0.0, 0.0); 2],
                            "lane {l} outside"
                        );
                    }
                    // A lane outside the mask did not move on; one inside did.
                    assert_eq!(group[l].drawn(), s.drawn(), "mask {mask:#b}, lane {l}");
                    assert_eq!(group[l].next_1d(), s.next_1d(), "mask {mask:#b}, lane {l} continues");
                }
            }
        }
        // Fewer samplers than lanes: mask bits past them are ignored.
        let mut three: Vec<Sampler> = (0..3).map(|k| pixel.with_sample(k)).collect();
        let mut each = three.clone();
        let got = Sampler::next_2d_groups_of::<1>(&mut three, 0b1111_0110);
        assert_eq!((got[0][0][1], got[0][1][1]), each[1].next_2d());
        assert_eq!((got[0][0][2], got[0][1][2]), each[2].next_2d());
        assert_eq!(three[0].drawn(), 0);
    }

    #[test]
    fn sampler_lanes_draw_what_each_sampler_draws() {
        let pixel = Sampler::new(0x5eed, 12, 34, 0);
        // Samples of one pixel, of three pixels, and of one pixel with one lane a request
        // ahead (each lane then draws alone), under several masks.
        for (case, mask) in
            [(0, 0xffu32), (0, 0b0110_1001), (1, 0xff), (1, 0b1000_0010), (2, 0xff), (2, 0b0000_0100), (0, 0)]
        {
            let mut each: [Sampler; GROUP_LANES] = std::array::from_fn(|k| match case {
                1 => Sampler::new(0x5eed, 12 + k as u32 % 3, 34, 40 + k as u32),
                _ => pixel.with_sample(40 + k as u32),
            });
            each.iter_mut().for_each(|s| _ = s.next_2d());
            if case == 2 {
                each[2].next_1d();
            }
            let mut lanes = SamplerLanes::new(&each);
            let got = lanes.next_2d::<3>(mask);
            for (l, s) in each.iter_mut().enumerate() {
                for (m, req) in got.iter().enumerate() {
                    let want = if mask & 1 << l != 0 { s.next_2d() } else { (0.0, 0.0) };
                    assert_eq!(
                        (req[0][l], req[1][l]),
                        want,
                        "case {case}, mask {mask:#b}, lane {l}, request {m}"
                    );
                }
                let mut moved = lanes.get(l);
                assert_eq!(moved.drawn(), s.drawn(), "case {case}, mask {mask:#b}, lane {l}");
                assert_eq!(moved.next_1d(), s.next_1d(), "case {case}, mask {mask:#b}, lane {l} continues");
            }
        }
    }

    #[test]
    fn the_exact_conversion_is_the_plain_one() {
        for v in [0u32, 1, 2, 0x7fff_ffff, 0x8000_0000, 0xdead_beef, u32::MAX] {
            assert_eq!(unit_exact(v).to_bits(), unit(v).to_bits(), "{v:#x}");
        }
        for k in 0..1u64 << 16 {
            let v = fmix64(k) as u32;
            assert_eq!(unit_exact(v).to_bits(), unit(v).to_bits(), "{v:#x}");
        }
    }

    #[test]
    fn every_request_is_stratified_over_a_pixels_samples() {
        // 64 samples: in every request, each of the 8x8, 64x1 and 1x64 elementary intervals
        // holds exactly one point (a (0, 6, 2)-net), on several pixels and dimensions.
        for (x, y) in [(0, 0), (17, 3), (1000, 999)] {
            for dim in [1, 2, 5, 40] {
                let pts = points(x, y, 64, dim);
                for (cols, rows) in [(8usize, 8usize), (64, 1), (1, 64), (16, 4), (2, 32)] {
                    let mut seen = vec![0u32; cols * rows];
                    for &(a, b) in &pts {
                        assert!((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b));
                        seen[(b * rows as f64) as usize * cols + (a * cols as f64) as usize] += 1;
                    }
                    assert!(
                        seen.iter().all(|&c| c == 1),
                        "pixel ({x}, {y}) dim {dim}, {cols}x{rows}: {seen:?}"
                    );
                }
            }
        }
        // Not a power of two (100): still no 10x10 cell with more than 3 of the 100 points,
        // where independent uniform points put 5 or more in one cell almost always.
        let pts = points(5, 6, 100, 3);
        let mut seen = [0u32; 100];
        for &(a, b) in &pts {
            seen[(b * 10.0) as usize * 10 + (a * 10.0) as usize] += 1;
        }
        assert!(seen.iter().all(|&c| c <= 3), "{seen:?}");
    }

    #[test]
    fn requests_are_decorrelated_and_pixels_differ() {
        // Correlation of the first coordinates of two requests over 256 samples.
        let (a, b) = (points(2, 9, 256, 1), points(2, 9, 256, 2));
        let n = a.len() as f64;
        let (ma, mb) = (a.iter().map(|p| p.0).sum::<f64>() / n, b.iter().map(|p| p.0).sum::<f64>() / n);
        let cov = a.iter().zip(&b).map(|(p, q)| (p.0 - ma) * (q.0 - mb)).sum::<f64>() / n;
        let corr = cov / (1.0 / 12.0);
        assert!(corr.abs() < 0.2, "correlation {corr}");
        assert_ne!(points(2, 9, 4, 1), points(3, 9, 4, 1));
    }

    #[test]
    fn uniform_over_many_pixels() {
        // Mean and variance of 100k first values over many pixels: 1/2 and 1/12 within
        // sampling error.
        let (mut sum, mut sq) = (0.0, 0.0);
        let n = 100_000;
        for i in 0..n {
            let x = Sampler::new(1, i % 317, i / 317, 0).next_1d();
            assert!((0.0..1.0).contains(&x));
            sum += x;
            sq += x * x;
        }
        let mean = sum / n as f64;
        let var = sq / n as f64 - mean * mean;
        assert!((mean - 0.5).abs() < 0.005, "{mean}");
        assert!((var - 1.0 / 12.0).abs() < 0.002, "{var}");
    }
}
