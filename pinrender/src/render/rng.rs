//! A small PCG32 generator (O'Neill's XSH-RR variant) for the path tracer.
//!
//! The renderer needs a cheap, well-distributed, seedable stream per pixel sample so that an
//! image depends only on `(seed, pixel, sample index)` and never on the thread schedule. This
//! module deliberately does not reuse `pinrt::rng` (the pin sampler's generator, which follows
//! the GPU's draw order); an estimator that wants that generator can seed it from
//! [`Pcg32::next_u64`].

const MULT: u64 = 6_364_136_223_846_793_005;

/// PCG32: 64-bit state, 32-bit output, selectable stream.
#[derive(Clone, Debug)]
pub struct Pcg32 {
    state: u64,
    inc: u64,
}

/// SplitMix64 finaliser: turns structured integers (pixel indices, counters) into
/// well-mixed seeds, so neighbouring pixels do not get correlated PCG streams.
#[inline]
pub fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Pcg32 {
    /// The reference PCG32 seeding procedure for `(seed, stream)`.
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut r = Pcg32 {
            state: 0,
            inc: (stream << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(seed);
        r.next_u32();
        r
    }

    /// The generator of sample `sample` of pixel `pixel` (row-major index) for a render with
    /// seed `seed`. Each input is passed through SplitMix64 so that all three matter.
    pub fn for_sample(seed: u64, pixel: u64, sample: u64) -> Self {
        let a = splitmix64(seed);
        let b = splitmix64(a ^ pixel);
        let c = splitmix64(b ^ sample.wrapping_mul(0xD1B5_4A32_D192_ED03));
        Pcg32::new(c, splitmix64(c ^ 0x5851_F42D_4C95_7F2D))
    }

    #[inline]
    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(MULT).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        ((self.next_u32() as u64) << 32) | self.next_u32() as u64
    }

    /// Uniform in `[0, 1)` with 24 random bits (every value exactly representable).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// Uniform in `[0, 1)` with 32 random bits, in f64 (for exponential sampling: the largest
    /// sample `-ln(2^-32)` is about 22.2 optical depths, so the tail cut is below 2^-32).
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        self.next_u32() as f64 * (1.0 / 4_294_967_296.0)
    }

    /// A unit-rate exponential sample `-ln(1 - u)`, finite and `>= 0`.
    #[inline]
    pub fn next_exp(&mut self) -> f64 {
        -(1.0 - self.next_f64()).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_vector() {
        // First outputs of the reference pcg32 demo (seed 42, stream 54).
        let mut r = Pcg32::new(42, 54);
        let got: Vec<u32> = (0..6).map(|_| r.next_u32()).collect();
        assert_eq!(
            got,
            [
                0xa15c02b7, 0x7b47f409, 0xba1d3330, 0x83d2f293, 0xbfa4784b, 0xcbed606e
            ]
        );
    }

    #[test]
    fn uniform_ranges_and_mean() {
        let mut r = Pcg32::for_sample(1, 2, 3);
        let n = 100_000;
        let mut s = 0.0;
        for _ in 0..n {
            let a = r.next_f32();
            let b = r.next_f64();
            assert!((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b));
            assert!(r.next_exp().is_finite());
            s += b;
        }
        assert!((s / n as f64 - 0.5).abs() < 0.005);
        // Distinct streams for neighbouring samples.
        assert_ne!(
            Pcg32::for_sample(1, 2, 3).next_u64(),
            Pcg32::for_sample(1, 2, 4).next_u64()
        );
    }
}
