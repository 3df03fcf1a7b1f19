//! The query random number generator: a 32-bit PCG-style generator that WGSL reproduces exactly.
//!
//! WGSL has no 64-bit integers, so the state is one `u32` and every operation is a wrapping
//! 32-bit multiply, add, shift or xor. The same code lives in `shaders/pin.wgsl`
//! (`rng_next`, `pcg_hash`, `rng_for_query`); the tests in `gpu` check that both sides consume
//! the same numbers by comparing the final state of every query.
//!
//! * step: `state = state * 747796405 + 2891336453`
//! * output: `word = ((state >> ((state >> 28) + 4)) ^ state) * 277803737; out = (word >> 22) ^ word`
//!   (the output of the *new* state; the shift amount is in `4..=19`, never 32)
//! * float in `[0, 1)`: `(out >> 8) as f32 * 2^-24` (exact: 24 bits fit the mantissa)
//! * per-query seeding: `state = pcg_hash(pcg_hash(seed) ^ query_index)` where `pcg_hash(x)`
//!   is one step-and-output from state `x`. `pcg_hash` is a bijection of `u32`, so for one seed
//!   distinct query indices start from distinct states.

/// LCG multiplier of the state step.
pub const PCG_MUL: u32 = 747_796_405;
/// LCG increment of the state step.
pub const PCG_INC: u32 = 2_891_336_453;
/// Multiplier of the output permutation.
pub const PCG_OUT_MUL: u32 = 277_803_737;

/// The output permutation (RXS-M-XS) of a state.
#[inline(always)]
pub fn pcg_output(state: u32) -> u32 {
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(PCG_OUT_MUL);
    (word >> 22) ^ word
}

/// One step and output from state `x`: a well-mixing bijection of `u32`.
#[inline(always)]
pub fn pcg_hash(x: u32) -> u32 {
    pcg_output(x.wrapping_mul(PCG_MUL).wrapping_add(PCG_INC))
}

/// Maps a random `u32` to `[0, 1)` using its top 24 bits.
#[inline(always)]
pub fn unit_f32(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// The generator: one `u32` of state, `Copy` so a query can carry it between batch phases.
/// A 32-bit PCG-style generator that `shaders/pin.wgsl` reproduces exactly (its definition
/// and the per-query seeding are in `docs/sampling.md` section 7).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Rng {
    /// The raw state (exposed so results can report it and GPU/CPU runs can be compared).
    pub state: u32,
}

impl Rng {
    /// A generator starting from a raw state.
    pub const fn new(state: u32) -> Self {
        Self { state }
    }

    /// The generator of query `query_index` under `seed`: `pcg_hash(pcg_hash(seed) ^ index)`.
    /// CPU batches and GPU dispatches seed query `i` of a run this way.
    #[inline(always)]
    pub fn for_query(seed: u32, query_index: u32) -> Self {
        Self {
            state: pcg_hash(pcg_hash(seed) ^ query_index),
        }
    }

    /// The next 32 random bits.
    #[inline(always)]
    pub fn next_u32(&mut self) -> u32 {
        self.state = self.state.wrapping_mul(PCG_MUL).wrapping_add(PCG_INC);
        pcg_output(self.state)
    }

    /// A uniform float in `[0, 1)` (multiples of 2^-24).
    #[inline(always)]
    pub fn next_f32(&mut self) -> f32 {
        unit_f32(self.next_u32())
    }

    /// A uniform integer in `0..n` for `n <= 256` from one draw: `((x >> 8) * n) >> 24`.
    /// Exact for powers of two, otherwise biased by less than 2^-24 relative; no `u64` needed.
    #[inline(always)]
    pub fn below_256(&mut self, n: u32) -> u32 {
        debug_assert!((1..=256).contains(&n));
        ((self.next_u32() >> 8) * n) >> 24
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values_are_stable() {
        // Guards the contract with the WGSL side: these numbers must never change.
        let mut r = Rng::new(0);
        let first: Vec<u32> = (0..3).map(|_| r.next_u32()).collect();
        let mut r2 = Rng::new(0);
        assert_eq!(first, (0..3).map(|_| r2.next_u32()).collect::<Vec<_>>());
        assert_eq!(pcg_hash(0), pcg_output(PCG_INC));
        assert_eq!(
            Rng::for_query(7, 3).state,
            pcg_hash(pcg_hash(7) ^ 3),
            "seeding formula"
        );
    }

    #[test]
    fn floats_are_in_unit_interval_and_uniformish() {
        let mut r = Rng::for_query(1, 2);
        let n = 200_000;
        let mut sum = 0.0f64;
        for _ in 0..n {
            let x = r.next_f32();
            assert!((0.0..1.0).contains(&x));
            sum += f64::from(x);
        }
        let mean = sum / n as f64;
        // sd of the mean = sqrt(1/12/n) ~ 6.5e-4
        assert!((mean - 0.5).abs() < 4.5 * 6.5e-4, "mean {mean}");
        assert_eq!(unit_f32(u32::MAX), 1.0 - 1.0 / 16_777_216.0);
        assert_eq!(unit_f32(0), 0.0);
    }

    #[test]
    fn below_256_covers_range() {
        let mut r = Rng::new(5);
        for n in [1u32, 2, 3, 7, 256] {
            let mut seen = vec![0u32; n as usize];
            for _ in 0..(n * 200) {
                let k = r.below_256(n);
                assert!(k < n);
                seen[k as usize] += 1;
            }
            assert!(seen.iter().all(|&c| c > 0), "{n}: {seen:?}");
        }
    }

    #[test]
    fn per_query_streams_differ() {
        let a: Vec<u32> = (0..1000).map(|i| Rng::for_query(9, i).state).collect();
        let mut s = a.clone();
        s.sort_unstable();
        s.dedup();
        assert_eq!(s.len(), a.len());
    }
}
