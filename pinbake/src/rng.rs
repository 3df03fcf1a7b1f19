//! Counter-based random numbers: a value is a pure function of (seed, counters).
//!
//! This is what makes bakes deterministic whatever the thread count or tiling: no generator
//! state flows from one pin to the next, so any pin can be baked alone and get the same bits.

/// splitmix64's finaliser: a bijective 64-bit mixer with good avalanche.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A stream of random numbers keyed by `(seed, a, b)`; draw `i` is `mix(key + i * golden)`.
#[derive(Clone, Copy, Debug)]
pub struct CounterRng {
    key: u64,
    counter: u64,
}

const GOLDEN: u64 = 0x9e37_79b9_7f4a_7c15;

impl CounterRng {
    pub fn new(seed: u64, a: u64, b: u64) -> Self {
        let key = mix64(mix64(mix64(seed ^ 0x5049_4e42_414b_4531) ^ a).wrapping_add(b));
        Self { key, counter: 0 }
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.counter = self.counter.wrapping_add(1);
        mix64(self.key.wrapping_add(self.counter.wrapping_mul(GOLDEN)))
    }

    /// The stream's key and the number of draws taken: draw `c` (from 1) is
    /// `mix64(key + c * golden)`, what the GPU bake's shader recomputes.
    #[cfg_attr(not(feature = "gpu"), allow(dead_code))]
    pub(crate) fn state(&self) -> (u64, u64) {
        (self.key, self.counter)
    }

    /// Uniform in `[0, 1)` with 53 random bits.
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_mean_and_independence_of_keys() {
        let n = 200_000;
        let mut r = CounterRng::new(1, 2, 3);
        let mean = (0..n).map(|_| r.next_f64()).sum::<f64>() / n as f64;
        // Var of U(0,1) is 1/12: 5 sigma bound.
        assert!((mean - 0.5).abs() < 5.0 * (1.0 / 12.0 / n as f64).sqrt());
        let a = CounterRng::new(1, 2, 3).next_u64();
        let b = CounterRng::new(1, 3, 2).next_u64();
        let c = CounterRng::new(2, 2, 3).next_u64();
        assert!(a != b && a != c && b != c);
        assert_eq!(a, CounterRng::new(1, 2, 3).next_u64());
    }
}
