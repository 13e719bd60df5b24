//! Deterministic random numbers: a counter-based generator keyed by
//! (frame seed, pixel x, pixel y, sample index) and advanced by a dimension counter.
//!
//! There is no thread-local or global state: a pixel's samples are the same whichever tile,
//! thread, process or machine renders it, which is what makes farm renders equal CLI renders
//! bit for bit.

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

/// The random stream of one camera sample of one pixel.
#[derive(Clone, Debug)]
pub struct SampleRng {
    key: u64,
    dim: u64,
}

impl SampleRng {
    pub fn new(frame_seed: u64, x: u32, y: u32, sample: u32) -> Self {
        let mut k = fmix64(frame_seed ^ GOLDEN);
        k = fmix64(k ^ ((x as u64) << 32 | y as u64));
        k = fmix64(k ^ (sample as u64).wrapping_mul(GOLDEN));
        SampleRng { key: k, dim: 0 }
    }

    /// The next uniform number in [0, 1).
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        self.dim += 1;
        let h = fmix64(self.key.wrapping_add(self.dim.wrapping_mul(GOLDEN)));
        (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Frame seed of camera `camera` of a scene: rendering a camera never depends on the others.
pub fn frame_seed(base: u64, camera: usize) -> u64 {
    fmix64(base ^ fmix64(camera as u64 + 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_key_same_stream_different_keys_differ() {
        let a: Vec<f64> = {
            let mut r = SampleRng::new(7, 3, 4, 5);
            (0..8).map(|_| r.next_f64()).collect()
        };
        let b: Vec<f64> = {
            let mut r = SampleRng::new(7, 3, 4, 5);
            (0..8).map(|_| r.next_f64()).collect()
        };
        let c: Vec<f64> = {
            let mut r = SampleRng::new(7, 4, 3, 5);
            (0..8).map(|_| r.next_f64()).collect()
        };
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn uniform_enough() {
        // Mean and variance of 100k draws over many pixels: 1/2 and 1/12 within sampling error.
        let mut sum = 0.0;
        let mut sq = 0.0;
        let n = 100_000;
        for i in 0..n {
            let mut r = SampleRng::new(1, i % 317, i / 317, 0);
            let x = r.next_f64();
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
