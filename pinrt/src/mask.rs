//! Bit-level building blocks: checked shifts, interval ranges, integer powers and the sample
//! (majorant) mask `H`.
//!
//! Bit convention: after the optional reversal for `d.z < 0`, interval `j` of the chord
//! (`j = 0` nearest the chord's start) is bit `31 - j`, so "first interval from the start" is
//! "most significant set bit" (`leading_zeros`).
//!
//! ## The exact sample mask
//!
//! Every bit of `H` must be set independently with probability `q = 1 - t_min`. We use the
//! 32-bit fixed-point threshold `Q = round((1 - t_min) * 2^32)`, computed *exactly* from the f32
//! `t_min` as `2^32 - round_ties_even(t_min * 2^32)` (the product is exact in f32), so
//! `|Q / 2^32 - (1 - t_min)| <= 2^-33` for every representable `t_min`. Bit `i` of `H` is
//! `U_i < Q` for 32 virtual uniform 32-bit integers `U_i`, compared bit-sliced from the most
//! significant bit: lane `i` of the `k`-th random word is bit `31 - k` of `U_i`. A lane is
//! decided at the first position where its `U` bit differs from `Q`'s bit (set if `Q`'s bit is 1
//! and `U`'s is 0). The loop stops when no lane is undecided or after `Q`'s lowest set bit (all
//! lower bits of `Q` are 0, so undecided lanes are `>= Q` and stay clear). Each word halves
//! the undecided lanes on average: about 6.3 draws per mask, at most 32.
//!
//! Hence `P(H_i = 1) = Q / 2^32` exactly and the bias against `1 - t_min` is at most `2^-33`
//! per bit (the bound we state is `2^-32`, including `t_min` values below `2^-33` that round to
//! `q = 1`). The thesis' k-round halving ([`thesis_sample_mask`]) quantises `q` to odd
//! multiples of `2^-k`, which for `k = 5` and `t_min = 0.999` makes collisions 31x too likely.

use crate::rng::Rng;

/// `x << n`, or 0 when `n >= 32` (Rust panics in debug, WGSL would shift by `n % 32`).
#[inline(always)]
pub fn shl(x: u32, n: u32) -> u32 {
    if n >= 32 { 0 } else { x << n }
}

/// `x >> n`, or 0 when `n >= 32`.
#[inline(always)]
pub fn shr(x: u32, n: u32) -> u32 {
    if n >= 32 { 0 } else { x >> n }
}

/// The bit of interval `j` (`j = 0` nearest the chord start is bit 31); 0 for `j >= 32`.
#[inline(always)]
pub fn interval_bit(j: u32) -> u32 {
    shr(0x8000_0000, j)
}

/// Bits of intervals `a..=b` (`a <= b <= 31`); 0 if `a > b`.
#[inline(always)]
pub fn interval_range(a: u32, b: u32) -> u32 {
    if a > b || b > 31 {
        return 0;
    }
    // Shift amounts a and 31 - b are both in 0..=31.
    (u32::MAX >> a) & (u32::MAX << (31 - b))
}

/// `base^n` for an integer exponent `n <= 63` by square-and-multiply over the six exponent
/// bits, branch-free (a multiplication by 1.0 where a bit is clear, which is exact), in the
/// fixed operation order that the WGSL `pow_int` repeats. `pow_int(x, 0) == 1` for every `x`,
/// including 0 and NaN. Callers pass popcounts (`<= 32`).
#[inline(always)]
pub fn pow_int(base: f32, n: u32) -> f32 {
    debug_assert!(n < 64);
    let mut result = 1.0f32;
    let mut b = base;
    for i in 0..6 {
        let f = if (n >> i) & 1 != 0 { b } else { 1.0 };
        result *= f;
        b *= b;
    }
    result
}

/// Clamps a stored `t_min` into `[0, 1]` with integer tests only (so the GPU agrees even where
/// it does not honour NaN): NaN and values above 1 read as 1 (no medium), negative values and
/// `-0.0` as 0.
#[inline(always)]
pub fn sanitize_t_min(t: f32) -> f32 {
    let bits = t.to_bits();
    let mag = bits & 0x7fff_ffff;
    if mag > 0x7f80_0000 {
        1.0 // NaN
    } else if bits & 0x8000_0000 != 0 {
        0.0 // negative, -0.0, -inf
    } else if mag >= 0x3f80_0000 {
        1.0 // >= 1, +inf
    } else {
        t
    }
}

/// Whether `x` is finite, by its exponent bits (robust where float NaN/inf tests are not).
#[inline(always)]
pub fn is_finite_bits(x: f32) -> bool {
    x.to_bits() & 0x7f80_0000 != 0x7f80_0000
}

/// The sample-mask threshold for a (sanitised) `t_min`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Threshold {
    /// `q = 0`: `H = 0`, no draws.
    Never,
    /// `q = 1` (to 2^-32): `H = !0`, no draws.
    Always,
    /// `P(bit) = Q / 2^32` with `0 < Q < 2^32`.
    Fixed(u32),
}

/// `Q = round((1 - t_min) * 2^32)` computed exactly from the f32 `t_min` (see module docs).
#[inline(always)]
pub fn threshold(t_min: f32) -> Threshold {
    let t = sanitize_t_min(t_min);
    if t >= 1.0 {
        return Threshold::Never;
    }
    // Exact product (power-of-two scale, no overflow); <= 2^32 - 256 since t <= 1 - 2^-24.
    // Rounded to nearest, ties to even, with integer steps (no libm `rintf`, same on the GPU):
    // the fraction is exact because below 2^24 `floor(x)` is representable and above it `x`
    // is an integer.
    let x = t * 4_294_967_296.0;
    let fl = x as u32;
    let frac = x - fl as f32;
    let tq = if frac > 0.5 || (frac == 0.5 && fl & 1 == 1) {
        fl + 1
    } else {
        fl
    };
    if tq == 0 {
        Threshold::Always
    } else {
        Threshold::Fixed(tq.wrapping_neg())
    }
}

/// The exact sample mask for threshold `Q` (see module docs); draws 0 to 32 words.
#[inline(always)]
pub fn exact_sample_mask_q(th: Threshold, rng: &mut Rng) -> u32 {
    let q = match th {
        Threshold::Never => return 0,
        Threshold::Always => return u32::MAX,
        Threshold::Fixed(q) => q,
    };
    let stop = q.trailing_zeros(); // q != 0, so stop <= 31
    let mut result = 0u32;
    let mut undecided = u32::MAX;
    let mut j = 31u32;
    loop {
        let r = rng.next_u32();
        // All ones where Q's bit j is 1 (branch-free form of the two cases in the docs).
        let qb = 0u32.wrapping_sub((q >> j) & 1);
        result |= undecided & !r & qb;
        undecided &= !(r ^ qb);
        if undecided == 0 || j == stop {
            break;
        }
        j -= 1;
    }
    result
}

/// The exact sample mask for `q = 1 - t_min`: each bit set independently with probability
/// `round((1 - t_min) 2^32) / 2^32`.
#[inline(always)]
pub fn exact_sample_mask(t_min: f32, rng: &mut Rng) -> u32 {
    exact_sample_mask_q(threshold(t_min), rng)
}

/// The thesis' sample mask (appendix 8.4, `gen_sample_mask`): `k` rounds of halving towards
/// `p`, one random word per round. The bit probability is the last midpoint, an odd multiple of
/// `2^-k`: biased. Kept for comparison and the bias measurements in `docs/sampling.md`.
pub fn thesis_sample_mask(p: f32, k: u32, rng: &mut Rng) -> u32 {
    let mut upper = u32::MAX;
    let mut lower = 0u32;
    let mut upper_p = 1.0f32;
    let mut lower_p = 0.0f32;
    let mut middle = 0u32;
    for _ in 0..k {
        let h = rng.next_u32();
        middle = (h & lower) | (!h & upper);
        let middle_p = 0.5 * (lower_p + upper_p);
        if middle_p > p {
            upper = middle;
            upper_p = middle_p;
        } else {
            lower = middle;
            lower_p = middle_p;
        }
    }
    middle
}

/// The bit probability [`thesis_sample_mask`] actually realises for `p` (its last midpoint).
pub fn thesis_mask_probability(p: f32, k: u32) -> f64 {
    let (mut lo, mut hi, mut mid) = (0.0f32, 1.0f32, 0.0f32);
    for _ in 0..k {
        mid = 0.5 * (lo + hi);
        if mid > p {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    f64::from(mid)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shifts_never_by_32() {
        assert_eq!(shl(1, 32), 0);
        assert_eq!(shr(u32::MAX, 32), 0);
        assert_eq!(shl(1, 31), 0x8000_0000);
        assert_eq!(interval_bit(0), 0x8000_0000);
        assert_eq!(interval_bit(31), 1);
        assert_eq!(interval_bit(32), 0);
        assert_eq!(interval_range(0, 31), u32::MAX);
        assert_eq!(interval_range(0, 0), 0x8000_0000);
        assert_eq!(interval_range(31, 31), 1);
        assert_eq!(interval_range(3, 5), 0b0001_1100 << 24);
        assert_eq!(interval_range(5, 3), 0);
        assert_eq!(interval_range(0, 32), 0);
    }

    #[test]
    fn pow_int_edge_cases() {
        assert_eq!(pow_int(0.0, 0), 1.0);
        assert_eq!(pow_int(0.0, 1), 0.0);
        assert_eq!(pow_int(1.0, 32), 1.0);
        assert_eq!(pow_int(f32::NAN, 0), 1.0);
        assert_eq!(pow_int(0.5, 63), 0.5f32.powi(63));
        assert_eq!(pow_int(0.5, 3), 0.125);
        assert_eq!(pow_int(1e-30, 32), 0.0);
        for n in 0..=32u32 {
            let x = 0.987_654f32;
            let want = f64::from(x).powi(n as i32);
            let got = f64::from(pow_int(x, n));
            assert!((got - want).abs() <= want * 1e-6, "{n}: {got} vs {want}");
        }
    }

    #[test]
    fn sanitize() {
        assert_eq!(sanitize_t_min(f32::NAN), 1.0);
        assert_eq!(sanitize_t_min(2.0), 1.0);
        assert_eq!(sanitize_t_min(f32::INFINITY), 1.0);
        assert_eq!(sanitize_t_min(-0.5), 0.0);
        assert_eq!(sanitize_t_min(-0.0).to_bits(), 0);
        assert_eq!(sanitize_t_min(f32::NEG_INFINITY), 0.0);
        assert_eq!(sanitize_t_min(0.25), 0.25);
        assert_eq!(sanitize_t_min(1e-45), 1e-45);
        assert!(!is_finite_bits(f32::NAN) && !is_finite_bits(f32::INFINITY));
        assert!(is_finite_bits(f32::MAX) && is_finite_bits(-0.0));
    }

    #[test]
    fn thresholds() {
        assert_eq!(threshold(1.0), Threshold::Never);
        assert_eq!(threshold(f32::NAN), Threshold::Never);
        assert_eq!(threshold(0.0), Threshold::Always);
        assert_eq!(threshold(1e-12), Threshold::Always);
        assert_eq!(threshold(0.5), Threshold::Fixed(1 << 31));
        assert_eq!(threshold(0.75), Threshold::Fixed(1 << 30));
        // 1 - 2^-24: Q = 256.
        assert_eq!(threshold(1.0 - 1.0 / 16_777_216.0), Threshold::Fixed(256));
        // Exactness: Q/2^32 within 2^-33 of 1 - t for random t.
        let mut r = Rng::new(3);
        for _ in 0..100_000 {
            let t = f32::from_bits(r.next_u32() % 0x3f80_0000);
            match threshold(t) {
                Threshold::Fixed(q) => {
                    let err = (f64::from(q) / 4_294_967_296.0 - (1.0 - f64::from(t))).abs();
                    assert!(err <= 2f64.powi(-33), "t {t}: err {err}");
                }
                Threshold::Always => assert!(f64::from(t) <= 2f64.powi(-33)),
                Threshold::Never => panic!("t {t} < 1"),
            }
        }
    }

    #[test]
    fn threshold_rounds_ties_to_even() {
        let two_m33 = 2f32.powi(-33);
        // t * 2^32 = 0.5 -> 0 (even) -> q = 1; 1.5 -> 2; 2.5 -> 2.
        assert_eq!(threshold(two_m33), Threshold::Always);
        assert_eq!(
            threshold(3.0 * two_m33),
            Threshold::Fixed(2u32.wrapping_neg())
        );
        assert_eq!(
            threshold(5.0 * two_m33),
            Threshold::Fixed(2u32.wrapping_neg())
        );
        let mut r = Rng::new(8);
        for _ in 0..100_000 {
            let t = f32::from_bits(r.next_u32() % 0x3f80_0000);
            let want = (f64::from(t) * 4_294_967_296.0).round_ties_even() as u32;
            let got = match threshold(t) {
                Threshold::Fixed(q) => q.wrapping_neg(),
                Threshold::Always => 0,
                Threshold::Never => unreachable!(),
            };
            assert_eq!(got, want, "{t:e}");
        }
    }

    #[test]
    fn exact_mask_special_values_and_draws() {
        let mut r = Rng::new(1);
        assert_eq!(exact_sample_mask(1.0, &mut r), 0);
        assert_eq!(exact_sample_mask(0.0, &mut r), u32::MAX);
        assert_eq!(r, Rng::new(1), "special values draw nothing");
        // q = 1/2: exactly one draw, H = !R.
        let mut a = Rng::new(9);
        let mut b = Rng::new(9);
        assert_eq!(exact_sample_mask(0.5, &mut a), !b.next_u32());
        assert_eq!(a, b);
        // Mean number of draws for a generic q is about 6.
        let mut r = Rng::new(2);
        let n = 20_000u64;
        let mut draws = 0u64;
        for _ in 0..n {
            let before = r;
            exact_sample_mask(0.3, &mut r);
            let mut c = before;
            let mut k = 0;
            while c != r {
                c.next_u32();
                k += 1;
            }
            draws += k;
        }
        let mean = draws as f64 / n as f64;
        assert!((5.0..8.0).contains(&mean), "mean draws {mean}");
    }

    /// Per-bit frequency of the exact mask matches q (z-test per bit and pooled).
    #[test]
    fn exact_mask_bit_frequencies() {
        for (q, trials) in [
            (1e-6f64, 4_000_000u64),
            (0.3, 200_000),
            (0.5, 200_000),
            (0.999_999, 4_000_000),
        ] {
            let t_min = (1.0 - q) as f32;
            let q_real = match threshold(t_min) {
                Threshold::Fixed(x) => f64::from(x) / 4_294_967_296.0,
                Threshold::Always => 1.0,
                Threshold::Never => 0.0,
            };
            assert!((q_real - q).abs() < 1e-7, "{q} vs {q_real}");
            let mut r = Rng::for_query(42, q.to_bits() as u32);
            let mut counts = [0u64; 32];
            for _ in 0..trials {
                let h = exact_sample_mask(t_min, &mut r);
                for (i, c) in counts.iter_mut().enumerate() {
                    *c += u64::from((h >> i) & 1);
                }
            }
            let sd = (q_real * (1.0 - q_real) / trials as f64).sqrt();
            let mut pooled = 0.0;
            for (i, &c) in counts.iter().enumerate() {
                let f = c as f64 / trials as f64;
                pooled += f;
                let z = (f - q_real) / sd;
                assert!(z.abs() < 5.0, "q {q} bit {i}: freq {f} z {z}");
            }
            let z = (pooled / 32.0 - q_real) / (sd / 32f64.sqrt());
            assert!(z.abs() < 4.5, "q {q}: pooled z {z}");
        }
    }

    #[test]
    fn exact_mask_bits_independent() {
        // Pairwise: P(bit i and bit j) = q^2 for q = 0.3.
        let t_min = 0.7f32;
        let mut r = Rng::new(77);
        let n = 200_000u64;
        let mut both = 0u64;
        for _ in 0..n {
            let h = exact_sample_mask(t_min, &mut r);
            both += u64::from(h & 0x8000_0001 == 0x8000_0001);
        }
        let p = 0.3f64 * 0.3;
        let z = (both as f64 / n as f64 - p) / (p * (1.0 - p) / n as f64).sqrt();
        assert!(z.abs() < 4.5, "z {z}");
    }

    #[test]
    fn thesis_mask_realises_midpoints() {
        assert_eq!(thesis_mask_probability(0.001, 5), 1.0 / 32.0);
        assert_eq!(thesis_mask_probability(0.5, 1), 0.5);
        assert_eq!(thesis_mask_probability(0.3, 5), 9.0 / 32.0);
        let mut r = Rng::new(4);
        let n = 100_000u64;
        let mut ones = 0u64;
        for _ in 0..n {
            ones += u64::from(thesis_sample_mask(0.001, 5, &mut r).count_ones());
        }
        let f = ones as f64 / (32 * n) as f64;
        assert!((f - 1.0 / 32.0).abs() < 0.001, "{f}");
    }
}
