//! How a pixel's samples add up, so that any part of them can be rendered anywhere.
//!
//! A pixel's samples are cut into **blocks** of [`BLOCK`] samples (the last one may be short).
//! Inside a block the samples are summed in `f64`, in sample order; each block's sum is then
//! turned into a fixed-point integer ([`SCALE`] units per unit of radiance) and added to the
//! pixel's [`PixelSum`]. Integer addition is exact, so the sum of a pixel's blocks is the same
//! bits whatever order they arrive in and however they were grouped: a tile rendered whole by the
//! CLI, or cut into **passes** (ranges of whole blocks) rendered by different farm workers and
//! added up by the server, gives the same film values.
//!
//! Beside the colour, a `PixelSum` keeps the luminance of its odd blocks alone: a second,
//! independent estimate of the pixel from half its samples, whose distance from the whole
//! estimate measures the pixel's noise ([`tile_error`]; the two-buffer estimate of Dammertz et
//! al. 2010 and of Cycles' adaptive sampling).

use glam::DVec3;

/// Samples per block: the unit of summation, of passes and of the noise estimate.
pub const BLOCK: u32 = 16;

/// Fixed-point units per unit of radiance (2^40: steps of about 1e-12).
pub const SCALE: f64 = (1u64 << 40) as f64;

/// The largest magnitude of one block's fixed-point value (2^98, about 2.9e17 units of radiance
/// once divided by [`SCALE`]). A pixel has at most 2^28 blocks (`u32` samples), so its sum stays
/// below 2^126 and the integer additions never overflow.
const BLOCK_LIMIT: f64 = (1u128 << 98) as f64;

/// Bytes of one [`PixelSum`] on the wire: four little-endian `i128`.
pub const PIXEL_SUM_BYTES: usize = 64;

/// A pixel's average as the film keeps it: `f32`, always a finite number. A NaN (a degenerate
/// scene: a zero-length normal, an infinite intensity times zero) becomes 0 and a value beyond
/// `f32`'s range the largest `f32` of its sign, so every output format and the farm's tiles
/// (whose server refuses non-finite values) hold the same finite numbers. Negative values, from
/// lights of negative power, stay as they are.
pub fn film_value(c: DVec3) -> [f32; 3] {
    let f = |v: f64| {
        if v.is_nan() { 0.0 } else { (v as f32).clamp(f32::MIN, f32::MAX) }
    };
    [f(c.x), f(c.y), f(c.z)]
}

/// The Rec. 709 luminance of a linear RGB value.
pub fn luminance(c: DVec3) -> f64 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

fn fixed(v: f64) -> i128 {
    let x = v * SCALE;
    // Nearly every block fits in an i64, whose conversion is one instruction where i128's is a
    // library call; both truncate towards zero, so the value is the same.
    if x.abs() < I64_LIMIT {
        return i128::from(x as i64);
    }
    // `as` maps NaN to 0; the clamp keeps every sum of a pixel's blocks inside i128.
    x.clamp(-BLOCK_LIMIT, BLOCK_LIMIT) as i128
}

/// `float(fixed(v))` without the integer: `v * SCALE` truncated towards zero, what both
/// conversions make of it. Below 2^63 in magnitude the truncated value is an `f64` (below 2^53
/// it is exact, above the value has no fraction), with `+ 0.0` turning the truncation's -0 into
/// the integer's 0; beyond, the clamp the `i128` takes (whose bounds and the values past 2^63
/// are integers the float holds exactly); NaN is 0.
#[inline]
fn fixed_float(v: f64) -> f64 {
    let x = v * SCALE;
    if x.abs() < I64_LIMIT {
        x.trunc() + 0.0
    } else if x.is_nan() {
        0.0
    } else {
        x.clamp(-BLOCK_LIMIT, BLOCK_LIMIT)
    }
}

/// 2^63: below it in magnitude an `f64` converts to `i64` exactly as to `i128`.
const I64_LIMIT: f64 = 9_223_372_036_854_775_808.0;

/// `v` as the nearest `f64`: through `i64` when it fits (one instruction, the same rounding to
/// nearest as the `i128` conversion's library call). The optimiser knows the two conversions
/// agree and would merge the branches into the library call, so the `i64` is hidden from it.
#[inline]
fn float(v: i128) -> f64 {
    match i64::try_from(v) {
        Ok(small) => std::hint::black_box(small) as f64,
        Err(_) => v as f64,
    }
}

/// A pixel's samples summed block by block in fixed point: the colour of every block, and the
/// luminance of the odd-numbered blocks alone.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PixelSum {
    pub rgb: [i128; 3],
    pub odd_luminance: i128,
}

impl PixelSum {
    /// Adds block `block`'s sum of sample radiances.
    pub fn add_block(&mut self, block: u32, sum: DVec3) {
        for (acc, v) in self.rgb.iter_mut().zip(sum.to_array()) {
            *acc += fixed(v);
        }
        if block % 2 == 1 {
            self.odd_luminance += fixed(luminance(sum));
        }
    }

    /// Adds another sum of disjoint blocks of the same pixel.
    pub fn add(&mut self, other: &PixelSum) {
        for (a, b) in self.rgb.iter_mut().zip(other.rgb) {
            *a += b;
        }
        self.odd_luminance += other.odd_luminance;
    }

    /// The pixel's average over `samples` samples, as the film keeps it (finite `f32`).
    pub fn film(&self, samples: u32) -> [f32; 3] {
        let n = f64::from(samples.max(1));
        let c = DVec3::new(float(self.rgb[0]), float(self.rgb[1]), float(self.rgb[2])) / SCALE / n;
        film_value(c)
    }

    /// The film value of a pixel of one sample of radiance `sum`: [`Self::film`]`(1)` of the
    /// `PixelSum` that [`Self::add_block`]`(0, sum)` makes, bit for bit, without the integers
    /// (a one-sample frame's pixels never meet another block). Each component is the fixed-point
    /// value's float, [`fixed_float`].
    #[inline]
    pub fn film_of_one(sum: DVec3) -> [f32; 3] {
        film_value(DVec3::new(fixed_float(sum.x), fixed_float(sum.y), fixed_float(sum.z)) / SCALE)
    }

    /// The average over all `samples`, and over the odd blocks' `odd` samples, in luminance.
    fn estimates(&self, samples: u32, odd: u32) -> (f64, f64) {
        let all = DVec3::new(float(self.rgb[0]), float(self.rgb[1]), float(self.rgb[2])) / SCALE;
        (luminance(all) / f64::from(samples), float(self.odd_luminance) / SCALE / f64::from(odd))
    }
}

/// How many of the samples `0..end` fall in odd-numbered blocks.
pub fn odd_samples(end: u32) -> u32 {
    let full_pairs = end / (2 * BLOCK);
    let rest = end % (2 * BLOCK);
    full_pairs * BLOCK + rest.saturating_sub(BLOCK)
}

/// A range of a pixel's sample indices, `start..end`; a pass's `start` is a whole block.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SampleRange {
    pub start: u32,
    pub end: u32,
}

impl SampleRange {
    pub fn all(samples: u32) -> SampleRange {
        SampleRange { start: 0, end: samples }
    }
    pub fn len(&self) -> u32 {
        self.end.saturating_sub(self.start)
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The pass size a job gets when it names none: a sixteenth of its samples, rounded up to whole
/// blocks (at least one).
pub fn default_pass_samples(samples: u32) -> u32 {
    round_to_blocks(samples.div_ceil(16))
}

/// The fewest samples of a pass the farm cuts a frame into by default when no noise target
/// needs finer steps: each pass costs the server an addition of its sums and a store of the
/// tile (a few milliseconds), which should be noise beside its render.
pub const MIN_DEFAULT_PASS: u32 = 256;

/// The farm's pass size when a job names none: [`default_pass_samples`] under a noise target
/// (the steps at which tiles may stop), else at least [`MIN_DEFAULT_PASS`] samples, so that a
/// frame of up to 256 samples renders its tiles whole.
pub fn default_farm_pass_samples(samples: u32, noise_target: bool) -> u32 {
    let p = default_pass_samples(samples);
    if noise_target { p } else { p.max(MIN_DEFAULT_PASS) }
}

/// `samples` rounded up to whole blocks, at least one block.
pub fn round_to_blocks(samples: u32) -> u32 {
    samples.max(1).div_ceil(BLOCK).saturating_mul(BLOCK)
}

/// How many passes of `pass_samples` (whole blocks) a pixel of `samples` samples takes.
pub fn pass_count(samples: u32, pass_samples: u32) -> u32 {
    samples.max(1).div_ceil(round_to_blocks(pass_samples))
}

/// The samples of pass `k` of a pixel of `samples` samples.
pub fn pass_range(samples: u32, pass_samples: u32, k: u32) -> SampleRange {
    let p = round_to_blocks(pass_samples);
    let samples = samples.max(1);
    let start = k.saturating_mul(p).min(samples);
    SampleRange { start, end: start.saturating_add(p).min(samples) }
}

/// A tile's noise after its first `samples` samples: the mean over its pixels of the relative
/// distance between the whole estimate and the odd blocks' estimate (each pixel's term at most 1,
/// so one firefly weighs like one wrong pixel, not like a thousand), in luminance. The distance
/// is about the relative standard error of the pixel's average. Pixels darker than a twentieth
/// of the tile's mean are measured against that twentieth (dark corners do not keep a bright
/// tile sampling). `None` until both halves have samples.
pub fn tile_error(sums: &[PixelSum], samples: u32) -> Option<f64> {
    tile_error_of(sums, &vec![samples; sums.len()])
}

/// [`tile_error`] of a tile whose pixel `i` has its first `counts[i]` samples.
pub fn tile_error_of(sums: &[PixelSum], counts: &[u32]) -> Option<f64> {
    let errors = pixel_errors(sums, counts)?;
    Some(errors.iter().sum::<f64>() / errors.len() as f64)
}

/// Each pixel's term of [`tile_error_of`]: the relative distance between its whole estimate and
/// its odd blocks' estimate, at most 1, measured against at least a twentieth of the tile's mean.
/// `None` when a pixel has no samples in one of the halves.
pub fn pixel_errors(sums: &[PixelSum], counts: &[u32]) -> Option<Vec<f64>> {
    let (est, floor) = pixel_estimates(sums, counts)?;
    Some(errors_of(&est, floor))
}

/// Each pixel's (whole, odd blocks') luminance estimates, and the level darker pixels are
/// measured against (a twentieth of the tile's mean): what [`pixel_errors`] compares. `None`
/// when a pixel has no samples in one of the halves.
fn pixel_estimates(sums: &[PixelSum], counts: &[u32]) -> Option<(Vec<(f64, f64)>, f64)> {
    if sums.is_empty() || sums.len() != counts.len() {
        return None;
    }
    let mut est = Vec::with_capacity(sums.len());
    for (s, &n) in sums.iter().zip(counts) {
        let odd = odd_samples(n);
        if odd == 0 || odd == n {
            return None;
        }
        est.push(s.estimates(n, odd));
    }
    let mean = est.iter().map(|(all, _)| all.max(0.0)).sum::<f64>() / est.len() as f64;
    Some((est, (0.05 * mean).max(1e-12)))
}

/// [`pixel_errors`] of the estimates.
fn errors_of(est: &[(f64, f64)], floor: f64) -> Vec<f64> {
    est.iter().map(|(all, odd)| ((odd - all).abs() / all.max(floor)).min(1.0)).collect()
}

/// The pixels of a `width`-wide tile that render the next pass, when pixel `i` has its first
/// `counts[i]` samples of `samples`, in passes of `pass_samples`: a pure function of the tile's
/// exact sums, so the CLI and the farm's server take the same decisions.
///
/// A pixel renders the next pass when it rendered the last one (`counts[i]` is the most any
/// pixel has: a pixel that stopped stays stopped, so every pixel's samples are its first ones),
/// the cap is not reached, and without a `target` always; with one, while it has fewer than
/// [`min_adaptive_samples`] or its pooled noise is above the target. A pixel's own noise
/// ([`pixel_errors`]) is one draw of a noisy estimate, so it is pooled: the mean over the 3x3
/// pixels around it (those inside the tile), and a pixel goes on while any pooled value of its
/// 3x3 neighbourhood is above the target (edges of noisy regions are not cut short), or while
/// its own distance measured against its neighbours' median estimate is above three times the
/// target (a firefly, which the pooling hides, keeps sampling until it is diluted).
pub fn active_pixels(
    sums: &[PixelSum],
    counts: &[u32],
    width: u32,
    samples: u32,
    pass_samples: u32,
    target: Option<f64>,
) -> Vec<bool> {
    let done = counts.iter().copied().max().unwrap_or(0);
    let live: Vec<bool> = counts.iter().map(|&c| c == done && c < samples.max(1)).collect();
    let Some(t) = target else { return live };
    if done < min_adaptive_samples(samples, pass_samples) {
        return live;
    }
    let Some((own, floor)) = pixel_estimates(sums, counts) else { return live };
    let errors = errors_of(&own, floor);
    let w = width.max(1) as usize;
    let h = errors.len() / w;
    if w * h != errors.len() {
        return live;
    }
    // The mean, then the max, over each pixel's 3x3 neighbourhood inside the tile.
    let window = |values: &[f64], x: usize, y: usize, f: &mut dyn FnMut(f64)| {
        for yy in y.saturating_sub(1)..(y + 2).min(h) {
            for xx in x.saturating_sub(1)..(x + 2).min(w) {
                f(values[yy * w + xx]);
            }
        }
    };
    let mut pooled = vec![0.0; errors.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut n) = (0.0, 0.0);
            window(&errors, x, y, &mut |e| {
                sum += e;
                n += 1.0;
            });
            pooled[y * w + x] = sum / n;
        }
    }
    // Each pixel's own distance against its neighbourhood's level, uncapped: a firefly in a
    // dark region inflates its own estimate (its term's denominator), its term is capped at 1
    // and the pooling divides it by nine, so the pooled rule alone lets it stop with the
    // firefly weighing 1/n of its value. Measured against the median of the 3x3 pixels'
    // estimates (which a lone firefly does not move), it goes on while that distance is
    // above three times the target (one pixel's distance spreads about three times as widely
    // as the mean of nine).
    let whole: Vec<f64> = own.iter().map(|&(all, _)| all).collect();
    let mut out = live;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if out[i] {
                let mut worst = 0.0f64;
                window(&pooled, x, y, &mut |e| worst = worst.max(e));
                let (mut around, mut k) = ([0.0f64; 9], 0);
                window(&whole, x, y, &mut |a| {
                    around[k] = a;
                    k += 1;
                });
                around[..k].sort_by(f64::total_cmp);
                let level = around[k / 2].max(floor);
                let (all, odd) = own[i];
                out[i] = worst > t || (odd - all).abs() / level > 3.0 * t;
            }
        }
    }
    out
}

/// A mask of a tile's pixels as bytes: bit `i % 8` of byte `i / 8` is pixel `i` (row-major).
pub fn encode_mask(mask: &[bool]) -> Vec<u8> {
    let mut out = vec![0u8; mask.len().div_ceil(8)];
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        out[i / 8] |= 1 << (i % 8);
    }
    out
}

/// The mask of `pixels` pixels from [`encode_mask`]'s bytes; `None` when the length is wrong or
/// a bit past the last pixel is set.
pub fn decode_mask(bytes: &[u8], pixels: usize) -> Option<Vec<bool>> {
    if bytes.len() != pixels.div_ceil(8) {
        return None;
    }
    let mask: Vec<bool> = (0..pixels).map(|i| bytes[i / 8] & (1 << (i % 8)) != 0).collect();
    (encode_mask(&mask) == bytes).then_some(mask)
}

/// A mask's bytes ([`encode_mask`]) as lowercase hex, as a lease carries them.
pub fn mask_to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The mask of `pixels` pixels from [`mask_to_hex`]'s text; `None` unless it is exactly that.
pub fn mask_from_hex(text: &str, pixels: usize) -> Option<Vec<bool>> {
    if !text.len().is_multiple_of(2) || !text.bytes().all(|c| matches!(c, b'0'..=b'9' | b'a'..=b'f')) {
        return None;
    }
    let bytes: Option<Vec<u8>> =
        (0..text.len()).step_by(2).map(|i| u8::from_str_radix(&text[i..i + 2], 16).ok()).collect();
    decode_mask(&bytes?, pixels)
}

/// A pixel count per pixel as bytes (little-endian `u32`s), as the server keeps a tile's.
pub fn encode_counts(counts: &[u32]) -> Vec<u8> {
    counts.iter().flat_map(|c| c.to_le_bytes()).collect()
}

/// The counts of [`encode_counts`] for `pixels` pixels; `None` when the length is wrong.
pub fn decode_counts(bytes: &[u8], pixels: usize) -> Option<Vec<u32>> {
    (bytes.len() == pixels.checked_mul(4)?)
        .then(|| bytes.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes"))).collect())
}

/// The samples a tile takes at least before a noise target may stop it: two passes and four
/// blocks (an estimate from fewer misses rare bright paths), or all of them.
pub fn min_adaptive_samples(samples: u32, pass_samples: u32) -> u32 {
    (2 * round_to_blocks(pass_samples)).max(4 * BLOCK).min(samples.max(1))
}

/// Checks a noise target given by a user: a relative error in (0, 1].
pub fn check_noise_target(t: f64) -> Result<f64, String> {
    if t.is_finite() && t > 0.0 && t <= 1.0 {
        Ok(t)
    } else {
        Err(format!(
            "the noise target {t} is not a relative error in (0, 1]; try 0.02 (about 2 % noise per pixel)"
        ))
    }
}

/// A tile's sums as bytes: each pixel's four `i128`, little-endian.
pub fn encode_sums(sums: &[PixelSum]) -> Vec<u8> {
    let mut out = Vec::with_capacity(sums.len() * PIXEL_SUM_BYTES);
    for s in sums {
        for v in s.rgb.iter().chain(std::iter::once(&s.odd_luminance)) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

/// The sums of [`encode_sums`]; `None` when the length is not whole pixels.
pub fn decode_sums(bytes: &[u8]) -> Option<Vec<PixelSum>> {
    if !bytes.len().is_multiple_of(PIXEL_SUM_BYTES) {
        return None;
    }
    let word = |c: &[u8]| i128::from_le_bytes(c.try_into().expect("16 bytes"));
    Some(
        bytes
            .chunks_exact(PIXEL_SUM_BYTES)
            .map(|p| PixelSum {
                rgb: [word(&p[0..16]), word(&p[16..32]), word(&p[32..48])],
                odd_luminance: word(&p[48..64]),
            })
            .collect(),
    )
}

/// The size of a pass's result for `pixels` pixels: the block sums ([`encode_sums`]), then with
/// `aux` the albedo and normal planes (12 bytes a pixel each, little-endian `f32` RGB).
pub fn pass_tile_bytes(pixels: usize, aux: bool) -> usize {
    pixels * PIXEL_SUM_BYTES + if aux { pixels * 24 } else { 0 }
}

/// A tile's albedo and normal planes.
pub type Features<'a> = (&'a [[f32; 3]], &'a [[f32; 3]]);

/// A pass's result on the wire: its sums, then (the first pass of a denoised job) the albedo and
/// normal planes.
pub fn encode_pass_tile(sums: &[PixelSum], aux: Option<Features<'_>>) -> Vec<u8> {
    let mut out = encode_sums(sums);
    if let Some((albedo, normal)) = aux {
        for p in albedo.iter().chain(normal) {
            for c in p {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    out
}

/// The largest magnitude one value of a pixel's sums over `blocks` blocks can have: what
/// [`PixelSum::add_block`] reaches when every block is at its limit (a pixel has at most
/// [`MAX_PIXEL_BLOCKS`]). At most 2^126, so the sums of a pixel's passes, each within the limit
/// of its own blocks, add up without overflow.
pub fn sum_limit(blocks: u32) -> u128 {
    (BLOCK_LIMIT as u128) * u128::from(blocks.clamp(1, MAX_PIXEL_BLOCKS))
}

/// The most blocks one pixel has: those of `u32::MAX` samples (2^28).
pub const MAX_PIXEL_BLOCKS: u32 = u32::MAX.div_ceil(BLOCK);

/// Whether every value of decoded sums could come from a render (each within [`sum_limit`] of
/// `blocks` blocks): a worker's upload is checked with it. Every `i128` is measured, `i128::MIN`
/// included (its magnitude does not fit an `i128`).
pub fn sums_in_range(sums: &[PixelSum], blocks: u32) -> bool {
    first_out_of_range(sums, blocks).is_none()
}

/// The first value of `sums` past [`sum_limit`] of `blocks` blocks: (pixel, channel, value),
/// the channels being R, G, B and the odd blocks' luminance (3).
pub fn first_out_of_range(sums: &[PixelSum], blocks: u32) -> Option<(usize, usize, i128)> {
    let limit = sum_limit(blocks);
    sums.iter().enumerate().find_map(|(i, s)| {
        s.rgb
            .iter()
            .chain([&s.odd_luminance])
            .enumerate()
            .find(|(_, v)| v.unsigned_abs() > limit)
            .map(|(c, v)| (i, c, *v))
    })
}

/// Why a pass's result cannot be stored.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PassResultError {
    /// The body is not `pixels` sums followed by whole features (or nothing).
    WrongSize { got: usize, sums: usize },
    /// A sum is larger than `blocks` blocks of samples can add up to.
    OutOfRange { pixel: usize, channel: usize, value: i128, limit: u128 },
}

impl std::fmt::Display for PassResultError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PassResultError::WrongSize { got, sums } => write!(
                f,
                "a pass's result holds {got} bytes: it must be {sums} bytes of sums (64 a pixel) and then whole features (24 bytes a pixel) or nothing"
            ),
            PassResultError::OutOfRange { pixel, channel, value, limit } => {
                let name = ["R", "G", "B", "odd-block luminance"][(*channel).min(3)];
                write!(
                    f,
                    "the pass's sum of pixel {pixel} (row-major), channel {name}, is {value}: larger in magnitude than its samples can add up to (at most {limit} units of 2^-40)"
                )
            }
        }
    }
}

impl std::error::Error for PassResultError {}

/// Decodes a pass's result as a worker uploads it for `pixels` pixels and `blocks` blocks of
/// samples: the sums ([`encode_sums`]), each checked against [`sum_limit`], and the bytes after
/// them (the features of a denoised job's first pass, or nothing), returned as they are. Never
/// panics, whatever the bytes.
pub fn decode_pass_result(
    body: &[u8],
    pixels: usize,
    blocks: u32,
) -> Result<(Vec<PixelSum>, &[u8]), PassResultError> {
    let wrong =
        || PassResultError::WrongSize { got: body.len(), sums: pixels.saturating_mul(PIXEL_SUM_BYTES) };
    let split = pixels.checked_mul(PIXEL_SUM_BYTES).filter(|&n| n <= body.len()).ok_or_else(wrong)?;
    let (sums, rest) = body.split_at(split);
    if !rest.is_empty() && rest.len() != pixels.saturating_mul(24) {
        return Err(wrong());
    }
    let sums = decode_sums(sums).ok_or_else(wrong)?;
    if let Some((pixel, channel, value)) = first_out_of_range(&sums, blocks) {
        return Err(PassResultError::OutOfRange { pixel, channel, value, limit: sum_limit(blocks) });
    }
    Ok((sums, rest))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_i64_shortcuts_convert_as_i128_does() {
        let edge = I64_LIMIT / SCALE;
        let values = [
            0.0,
            -0.0,
            1e-13,
            0.3,
            -0.7,
            1.0 / 3.0,
            12345.678,
            -9e7,
            edge,
            -edge,
            edge * (1.0 - 1e-16),
            -edge * (1.0 - 1e-16),
            edge * 1.5,
            1e30,
            -1e30,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for v in values {
            let slow = (v * SCALE).clamp(-BLOCK_LIMIT, BLOCK_LIMIT) as i128;
            assert_eq!(fixed(v), slow, "{v}");
            assert_eq!(float(slow).to_bits(), (slow as f64).to_bits(), "{v}");
        }
        // Integers that round: just past 2^53, and either side of the i64 range.
        for i in [
            (1i128 << 53) + 1,
            (1 << 60) + 3,
            i128::from(i64::MAX),
            i128::from(i64::MIN),
            1 << 70,
            -(1 << 90) - 7,
        ] {
            assert_eq!(float(i).to_bits(), (i as f64).to_bits(), "{i}");
        }
    }

    #[test]
    fn a_one_sample_film_value_is_the_fixed_point_films() {
        let edge = I64_LIMIT / SCALE;
        let mut values = vec![
            0.0,
            -0.0,
            1e-13,
            -1e-13,
            -1e-300,
            0.3,
            -0.7,
            1.0 / 3.0,
            255.0,
            12345.678,
            -9e7,
            8192.0 + 1e-9,
            edge,
            -edge,
            edge * (1.0 - 1e-16),
            -edge * (1.0 - 1e-16),
            edge * 1.5,
            1e30,
            -1e30,
            1e300,
            f64::MAX,
            f64::MIN_POSITIVE,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        // Values of every magnitude, from a fixed xorshift.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..2000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let v = f64::from_bits(state);
            if v.is_finite() {
                values.push(v);
                values.push(v * 1e-290);
            }
        }
        for w in values.windows(3) {
            let sum = DVec3::new(w[0], w[1], w[2]);
            let mut p = PixelSum::default();
            p.add_block(0, sum);
            let (a, b) = (PixelSum::film_of_one(sum), p.film(1));
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "{sum:?}");
        }
    }

    #[test]
    fn odd_samples_counts_the_odd_blocks() {
        assert_eq!(odd_samples(0), 0);
        assert_eq!(odd_samples(16), 0);
        assert_eq!(odd_samples(17), 1);
        assert_eq!(odd_samples(32), 16);
        assert_eq!(odd_samples(40), 16);
        assert_eq!(odd_samples(100), 48, "blocks 1, 3 and 5; block 6 is 96..100");
    }

    #[test]
    fn passes_are_whole_blocks_that_cover_the_samples_once() {
        for (n, p) in [(100, 16), (100, 7), (2500, 160), (1, 1), (16, 100), (33, 16)] {
            let k = pass_count(n, p);
            let mut next = 0;
            for i in 0..k {
                let r = pass_range(n, p, i);
                assert_eq!(r.start, next);
                assert_eq!(r.start % BLOCK, 0);
                assert!(!r.is_empty());
                next = r.end;
            }
            assert_eq!(next, n, "{n} samples in passes of {p}");
        }
        assert_eq!(default_pass_samples(2500), 160);
        assert_eq!(default_pass_samples(100), 16);
        assert_eq!(default_pass_samples(1), 16);
    }

    #[test]
    fn block_sums_add_to_the_same_bits_in_any_grouping() {
        // Values of very different sizes, where f64 addition would depend on the order.
        let blocks: Vec<DVec3> =
            (0..40).map(|i| DVec3::new(1e6 / (i as f64 + 1.0), 0.1 * i as f64, 1e-7 * i as f64)).collect();
        let mut whole = PixelSum::default();
        for (b, s) in blocks.iter().enumerate() {
            whole.add_block(b as u32, *s);
        }
        for cut in [1, 3, 7, 39] {
            let (mut first, mut second) = (PixelSum::default(), PixelSum::default());
            for (b, s) in blocks.iter().enumerate() {
                if b < cut { &mut first } else { &mut second }.add_block(b as u32, *s);
            }
            second.add(&first);
            assert_eq!(second, whole);
        }
    }

    #[test]
    fn a_sum_survives_the_wire_and_the_film_is_the_average() {
        let mut s = PixelSum::default();
        s.add_block(0, DVec3::new(16.0, 32.0, -8.0));
        s.add_block(1, DVec3::new(16.0, 0.0, 8.0));
        assert_eq!(s.film(32), [1.0, 1.0, 0.0]);
        let bytes = encode_sums(&[s, PixelSum::default()]);
        assert_eq!(bytes.len(), 2 * PIXEL_SUM_BYTES);
        assert_eq!(decode_sums(&bytes).unwrap(), vec![s, PixelSum::default()]);
        assert!(decode_sums(&bytes[1..]).is_none());
        // NaN counts as nothing, an infinity as the block limit: the sum stays exact and finite.
        let mut bad = PixelSum::default();
        bad.add_block(0, DVec3::new(f64::NAN, f64::INFINITY, 0.0));
        assert_eq!(bad.rgb[0], 0);
        assert!(sums_in_range(&[bad], 1));
        let huge = PixelSum { rgb: [i128::MAX, 0, 0], odd_luminance: 0 };
        assert!(!sums_in_range(&[huge], 4));
    }

    /// `i128::MIN` has no `i128` magnitude (`abs` overflows: a panic in a debug build, itself
    /// again in a release build, where it passed the check): it is out of range like every
    /// value past the limit, in every channel, for every block count.
    #[test]
    fn the_most_negative_sums_are_out_of_range() {
        for blocks in [0, 1, 4, 1 << 28, u32::MAX] {
            let limit = sum_limit(blocks);
            for c in 0..4 {
                let mut s = PixelSum::default();
                let mut set = |v: i128| {
                    if c == 3 {
                        s.odd_luminance = v
                    } else {
                        s.rgb[c] = v
                    }
                    s
                };
                for v in [i128::MIN, i128::MIN + 1, i128::MAX] {
                    assert_eq!(first_out_of_range(&[set(v)], blocks), Some((0, c, v)), "{blocks} {c} {v}");
                }
                if let Ok(edge) = i128::try_from(limit) {
                    assert!(sums_in_range(&[set(edge)], blocks) && sums_in_range(&[set(-edge)], blocks));
                    assert!(
                        !sums_in_range(&[set(edge + 1)], blocks) && !sums_in_range(&[set(-edge - 1)], blocks)
                    );
                }
            }
        }
        // The limit over every block a pixel can have still fits an `i128`: passes within
        // their limits add up without overflow.
        assert_eq!(sum_limit(u32::MAX), 1 << 126);
        let mut body = encode_sums(&[PixelSum { rgb: [0, i128::MIN, 0], odd_luminance: 0 }]);
        let e = decode_pass_result(&body, 1, 1).unwrap_err();
        assert!(matches!(e, PassResultError::OutOfRange { pixel: 0, channel: 1, .. }), "{e:?}");
        assert!(e.to_string().contains("channel G"), "{e}");
        body.extend_from_slice(&[0; 24]);
        assert!(decode_pass_result(&body, 1, 1).is_err());
        let fine = encode_sums(&[PixelSum { rgb: [1, -1, 0], odd_luminance: 5 }]);
        assert_eq!(decode_pass_result(&fine, 1, 1).unwrap().1, &[] as &[u8]);
        assert!(matches!(decode_pass_result(&fine, 2, 1), Err(PassResultError::WrongSize { .. })));
        assert!(matches!(decode_pass_result(&fine[..63], 1, 1), Err(PassResultError::WrongSize { .. })));
        assert!(matches!(decode_pass_result(&fine, usize::MAX, 1), Err(PassResultError::WrongSize { .. })));
    }

    /// Random pass results (a fixed seed, many shapes and lengths, the values worth trying
    /// mixed into random bits) never make the decoder panic; what it accepts is whole pixels
    /// within the limit, re-encodes to the same bytes and adds up, pass after pass over every
    /// block a pixel can have, without overflow.
    #[test]
    fn the_pass_result_decoder_never_panics_on_random_bytes() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let (mut accepted, mut refused) = (0, 0);
        for round in 0..20_000 {
            let pixels = (next() % 9) as usize;
            let blocks = match next() % 4 {
                0 => 0,
                1 => 1 + (next() % 8) as u32,
                2 => u32::MAX,
                _ => next() as u32,
            };
            let limit = sum_limit(blocks);
            let len = match next() % 4 {
                0 => pixels * PIXEL_SUM_BYTES,
                1 => pixels * (PIXEL_SUM_BYTES + 24),
                _ => (next() % 600) as usize,
            };
            let mut body = Vec::with_capacity(len + 16);
            while body.len() < len {
                let v: i128 = match next() % 8 {
                    0 => i128::MIN,
                    1 => i128::MAX,
                    2 => i128::try_from(limit).unwrap_or(i128::MAX),
                    3 => -i128::try_from(limit).unwrap_or(i128::MAX),
                    4 => i128::try_from(limit).map_or(i128::MIN, |l| -l - 1),
                    5 => (next() % 1000) as i128 - 500,
                    _ => (i128::from(next()) << 64) | i128::from(next()),
                };
                body.extend_from_slice(&v.to_le_bytes());
            }
            body.truncate(len);
            match std::panic::catch_unwind(|| decode_pass_result(&body, pixels, blocks)) {
                Err(_) => {
                    panic!("round {round}: the decoder panicked on {pixels} px, {blocks} blocks, {body:?}")
                }
                Ok(Err(_)) => refused += 1,
                Ok(Ok((sums, rest))) => {
                    accepted += 1;
                    assert_eq!(sums.len(), pixels);
                    assert_eq!([encode_sums(&sums).as_slice(), rest].concat(), body);
                    assert!(sums_in_range(&sums, blocks));
                    // Passes of this size over every block of a pixel: no overflow.
                    let passes = MAX_PIXEL_BLOCKS / blocks.clamp(1, MAX_PIXEL_BLOCKS);
                    for s in &sums {
                        for v in s.rgb.iter().chain([&s.odd_luminance]) {
                            let total = v.unsigned_abs().checked_mul(u128::from(passes));
                            assert!(total.is_some_and(|t| t <= i128::MAX as u128), "{v} x {passes}");
                        }
                        let _ = s.film(1);
                    }
                    let _ = tile_error(&sums, 32);
                }
            }
        }
        assert!(accepted > 1000 && refused > 1000, "{accepted} accepted, {refused} refused");
    }

    /// Tile sums of `pixels` pixels whose samples are `value` plus a noise of `noise` (the same
    /// pattern each block, alternating in sign from block to block).
    fn tile(pixels: usize, blocks: u32, value: f64, noise: f64) -> Vec<PixelSum> {
        (0..pixels)
            .map(|_| {
                let mut s = PixelSum::default();
                for b in 0..blocks {
                    let sign = if b % 2 == 0 { 1.0 } else { -1.0 };
                    s.add_block(b, DVec3::splat((value + sign * noise) * f64::from(BLOCK)));
                }
                s
            })
            .collect()
    }

    #[test]
    fn the_error_grows_with_the_noise_and_needs_both_halves() {
        assert_eq!(tile_error(&tile(4, 1, 1.0, 0.5), 16), None);
        let quiet = tile_error(&tile(4, 4, 1.0, 0.01), 64).unwrap();
        let loud = tile_error(&tile(4, 4, 1.0, 0.3), 64).unwrap();
        assert!((quiet - 0.01).abs() < 1e-9, "{quiet}");
        assert!((loud - 0.3).abs() < 1e-9, "{loud}");
        // A black tile has no noise.
        assert_eq!(tile_error(&tile(4, 4, 0.0, 0.0), 64), Some(0.0));
        // One firefly pixel counts at most as one wrong pixel.
        let mut t = tile(4, 4, 1.0, 0.0);
        t[0] = tile(1, 4, 1.0, 1e9)[0];
        assert!(tile_error(&t, 64).unwrap() <= 0.25 + 1e-12);
    }

    /// A tile of `w` x `h` pixels whose pixel `i` has `blocks` blocks of samples around 1, with
    /// the noise `noise(i)`.
    fn noisy(w: usize, h: usize, blocks: u32, noise: impl Fn(usize) -> f64) -> Vec<PixelSum> {
        (0..w * h).map(|i| tile(1, blocks, 1.0, noise(i))[0]).collect()
    }

    #[test]
    fn a_target_stops_pixels_only_past_the_minimum_and_below_the_target() {
        // 100 samples in passes of 16: at least 64 before a target may stop a pixel.
        let quiet = noisy(4, 4, 4, |_| 0.001);
        let count = |c: u32| vec![c; 16];
        assert!(active_pixels(&quiet, &count(32), 4, 100, 16, None).iter().all(|&a| a));
        assert!(active_pixels(&quiet, &count(100), 4, 100, 16, None).iter().all(|&a| !a), "the cap");
        assert!(active_pixels(&quiet, &count(48), 4, 100, 16, Some(0.01)).iter().all(|&a| a), "the minimum");
        assert!(active_pixels(&quiet, &count(64), 4, 100, 16, Some(0.01)).iter().all(|&a| !a));
        let loud = noisy(4, 4, 4, |_| 0.05);
        assert!(active_pixels(&loud, &count(64), 4, 100, 16, Some(0.01)).iter().all(|&a| a));
        assert!(active_pixels(&loud, &count(100), 4, 100, 16, Some(0.01)).iter().all(|&a| !a), "the cap");
        // One block only: no estimate, every pixel goes on.
        assert!(active_pixels(&noisy(2, 2, 1, |_| 0.5), &[16; 4], 2, 100, 16, Some(0.9)).iter().all(|&a| a));
    }

    #[test]
    fn a_noisy_pixel_keeps_its_neighbourhood_sampling_and_stopped_pixels_stay_stopped() {
        // 8 x 6 pixels, quiet (0.001) except a noisy one at (5, 2) (0.5): its pooled noise is
        // 0.5 / 9 plus the quiet ones; everything within two pixels of it goes on (the mean's
        // 3x3, then the max's), nothing else.
        let (w, h) = (8usize, 6usize);
        let sums = noisy(w, h, 4, |i| if i == 2 * w + 5 { 0.5 } else { 0.001 });
        let counts = vec![64; w * h];
        let mask = active_pixels(&sums, &counts, w as u32, 256, 16, Some(0.02));
        for y in 0..h {
            for x in 0..w {
                let near = x.abs_diff(5) <= 2 && y.abs_diff(2) <= 2;
                assert_eq!(mask[y * w + x], near, "({x}, {y})");
            }
        }
        // A pixel that has fewer samples than the others stopped earlier: it stays stopped,
        // however noisy it or its neighbours are.
        let mut counts = counts;
        counts[0] = 48;
        let loud = noisy(w, h, 4, |_| 0.5);
        let mask = active_pixels(&loud, &counts, w as u32, 256, 16, Some(0.02));
        assert!(!mask[0] && mask[1..].iter().all(|&a| a));
        // The same sums, the same decision (a pure function), whatever the rows' order of
        // evaluation: computed twice.
        assert_eq!(mask, active_pixels(&loud, &counts, w as u32, 256, 16, Some(0.02)));
        // The tile's noise with each pixel's own samples.
        assert!(tile_error_of(&loud, &counts).unwrap() > 0.4);
    }

    #[test]
    fn a_firefly_in_a_dark_region_keeps_sampling() {
        // 6 x 6 dark pixels (0.01, noise 0.0005) and one firefly at (2, 3): its odd blocks
        // hold a sample a thousand times brighter than the rest. Its own term is capped at 1
        // and the pooled mean around it stays below 0.3, so the pooled rule alone stops it.
        let (w, h) = (6usize, 6usize);
        let firefly = 3 * w + 2;
        let mut sums: Vec<PixelSum> = (0..w * h).map(|_| tile(1, 4, 0.01, 0.0005)[0]).collect();
        let mut s = PixelSum::default();
        for b in 0..4 {
            let v = if b == 1 { 10.0 } else { 0.01 };
            s.add_block(b, DVec3::splat(v * f64::from(BLOCK)));
        }
        sums[firefly] = s;
        let counts = vec![64; w * h];
        let pooled_only = {
            let errors = pixel_errors(&sums, &counts).unwrap();
            let near: Vec<f64> = (0..w * h)
                .filter(|i| (i % w).abs_diff(2) <= 1 && (i / w).abs_diff(3) <= 1)
                .map(|i| errors[i])
                .collect();
            near.iter().sum::<f64>() / near.len() as f64
        };
        assert!(pooled_only < 0.3, "{pooled_only}");
        let mask = active_pixels(&sums, &counts, w as u32, 1024, 16, Some(0.3));
        assert!(mask[firefly], "the firefly goes on");
        assert_eq!(mask.iter().filter(|&&a| a).count(), 1, "the quiet dark pixels stop: {mask:?}");
        // A target above its distance lets it stop too.
        let mask = active_pixels(&sums, &counts, w as u32, 1024, 16, Some(1e6));
        assert!(mask.iter().all(|&a| !a));
    }

    #[test]
    fn masks_and_counts_survive_the_wire() {
        for pixels in [0usize, 1, 7, 8, 9, 1024, 1023] {
            let mask: Vec<bool> = (0..pixels).map(|i| i % 3 == 0 || i % 7 == 1).collect();
            let bytes = encode_mask(&mask);
            assert_eq!(bytes.len(), pixels.div_ceil(8));
            assert_eq!(decode_mask(&bytes, pixels), Some(mask.clone()));
            assert_eq!(decode_mask(&bytes, pixels + 8), None);
            assert_eq!(mask_from_hex(&mask_to_hex(&bytes), pixels), Some(mask.clone()));
            let counts: Vec<u32> = (0..pixels as u32).map(|i| i * 16).collect();
            assert_eq!(decode_counts(&encode_counts(&counts), pixels), Some(counts));
        }
        // A bit past the last pixel.
        assert_eq!(decode_mask(&[0b1000_0000], 7), None);
        assert_eq!(decode_counts(&[0; 5], 1), None);
        assert_eq!(mask_from_hex("0g", 8), None);
        assert_eq!(mask_from_hex("0F", 8), None, "lowercase only");
        assert_eq!(mask_from_hex("0", 4), None);
        assert_eq!(mask_from_hex("05", 8), Some(vec![true, false, true, false, false, false, false, false]));
    }

    #[test]
    fn noise_targets_are_relative_errors() {
        assert!(check_noise_target(0.0).is_err() && check_noise_target(f64::NAN).is_err());
        assert_eq!(check_noise_target(0.02), Ok(0.02));
    }
}
