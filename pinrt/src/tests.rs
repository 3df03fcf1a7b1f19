//! Cross-module tests: the stiff cases of docs/background.md section 3, statistics of the estimators,
//! batch/single and multi-thread agreement.

use pin_format::{Directions, PinEntry};

use crate::chord::{Chord, Segment, segment};
use crate::mask::{interval_bit, thesis_sample_mask};
use crate::rng::Rng;
use crate::sampler::{QueryResult, participating, resolve_entry};
use crate::testing::{random_grid, single_entry_grid};
use crate::{NO_ENTRY, PinGrid, Ray, RayQuery, Sampler, SamplerOptions, status};

fn grid_of(entry: PinEntry) -> PinGrid {
    PinGrid::from_bytes(single_entry_grid(entry).to_bytes().unwrap()).unwrap()
}

/// [`random_grid`] serialised and read back: what a loaded file gives the sampler.
fn loaded_random_grid(
    directions: Directions,
    dims: [u32; 3],
    pins_per_entry: u32,
    sparse: bool,
    seed: u32,
) -> PinGrid {
    let bytes = random_grid(directions, dims, pins_per_entry, sparse, seed)
        .to_bytes()
        .unwrap();
    PinGrid::from_bytes(bytes).unwrap()
}

fn full_chord() -> Segment {
    segment(
        Chord {
            t_enter: 0.0,
            t_exit: 1.0,
        },
        f32::INFINITY,
    )
    .unwrap()
}

/// The segment `[u0, u1]` of a chord `[0, 1]`, in interval units `32 u`.
fn seg_frac(u0: f32, u1: f32) -> Segment {
    let mut s = segment(
        Chord {
            t_enter: -u0,
            t_exit: 1.0 - u0,
        },
        u1 - u0,
    )
    .unwrap();
    if u0 == 0.0 {
        s.s0 = 0.0;
    }
    s
}

fn check_finite(r: &QueryResult) {
    assert!(
        r.transmittance.is_finite() && (0.0..=1.0).contains(&r.transmittance),
        "{r:?}"
    );
    assert!(
        r.distance.is_finite() || (r.hit == 0 && r.distance == f32::INFINITY),
        "{r:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// Stiff cases (docs/background.md section 3)
// ---------------------------------------------------------------------------------------------

#[test]
fn t_min_one_is_transmittance_one_never_nan() {
    // Mask 0 and even a (corrupt) full mask with t_min = 1 give T = 1, no collision.
    for mask in [0u32, u32::MAX] {
        let g = grid_of(PinEntry { mask, t_min: 1.0 });
        let s = g.sampler().unwrap();
        let mut rng = Rng::new(1);
        for _ in 0..1000 {
            let r = s.query(&Ray::new([0.5, 0.5, -1.0], [0.1, 0.2, 1.0]), 5.0, &mut rng);
            assert_eq!(r.status, status::OK);
            assert_eq!(r.transmittance, 1.0);
            assert_eq!(r.hit, 0);
        }
    }
}

#[test]
fn pow_zero_zero_is_one() {
    // t_min = 0 with popcount 0 (mask 0): T = 1; with bits: T = 0 exactly, a collision always.
    let g = grid_of(PinEntry {
        mask: 0,
        t_min: 0.0,
    });
    let s = g.sampler().unwrap();
    let mut rng = Rng::new(2);
    let ray = Ray::new([0.5, 0.5, -1.0], [0.0, 0.0, 1.0]);
    let r = s.query(&ray, f32::INFINITY, &mut rng);
    assert_eq!((r.transmittance, r.popcount, r.hit), (1.0, 0, 0));
    let g = grid_of(PinEntry {
        mask: 0x0000_8000,
        t_min: 0.0,
    });
    let s = g.sampler().unwrap();
    let r = s.query(&ray, f32::INFINITY, &mut rng);
    assert_eq!(
        (r.transmittance, r.popcount, r.hit, r.interval),
        (0.0, 1, 1, 16)
    );
    // Interval 16 of the chord z in [0, 1] from t = 1: t in [1.5, 1.53125].
    assert!((1.5..=1.53125).contains(&r.distance), "{}", r.distance);
    // Subnormal t_min: finite, tiny or zero.
    let g = grid_of(PinEntry {
        mask: u32::MAX,
        t_min: 1e-40,
    });
    let r = g.sampler().unwrap().query(&ray, f32::INFINITY, &mut rng);
    assert_eq!(r.transmittance, 0.0);
    assert_eq!(r.hit, 1);
}

#[test]
fn damaged_t_min_reads_sanitised() {
    for (t, want) in [
        (f32::NAN, 1.0),
        (-1.0, 0.0),
        (7.0, 1.0),
        (f32::INFINITY, 1.0),
    ] {
        let g = grid_of(PinEntry {
            mask: u32::MAX,
            t_min: t,
        });
        let r =
            g.sampler()
                .unwrap()
                .query(&Ray::new([0.5; 3], [0.0, 0.0, 1.0]), 1.0, &mut Rng::new(0));
        assert_eq!(r.transmittance, want, "{t}");
        check_finite(&r);
    }
}

#[test]
fn dz_zero_plane_plus_and_minus_zero_agree() {
    let g = loaded_random_grid(Directions::THESIS_DEFAULT, [3, 3, 3], 2, false, 3);
    let go = loaded_random_grid(Directions::Octahedral { n: 6 }, [3, 3, 3], 2, true, 4);
    for grid in [&g, &go] {
        let s = grid.sampler().unwrap();
        let mut r0 = Rng::new(0);
        for i in 0..2000 {
            let a = i as f32 * 0.01;
            let (x, y) = (a.cos(), a.sin());
            let o = [0.5 - x, 0.5 - y, 0.3];
            let mut ra = Rng::new(r0.next_u32());
            let mut rb = ra;
            let p = s.query(&Ray::new(o, [x, y, 0.0]), 10.0, &mut ra);
            let m = s.query(&Ray::new(o, [x, y, -0.0]), 10.0, &mut rb);
            assert_eq!(p, m);
            assert_eq!(p.status, status::OK);
            check_finite(&p);
        }
    }
}

#[test]
fn reversal_for_negative_z() {
    // Only the first interval along +z (bottom, z in [0, 1/32]) is set.
    let g = grid_of(PinEntry {
        mask: 0x8000_0000,
        t_min: 0.5,
    });
    // The thesis' lookup: the interval bits are those of the ray's own chord.
    let s = g.sampler().unwrap().with_options(SamplerOptions::THESIS);
    let mut rng = Rng::new(5);
    // Downwards from above, top half only (z from 1 to 0.5): never reaches the bit.
    let down = Ray::new([0.5, 0.5, 2.0], [0.0, 0.0, -1.0]);
    let r = s.query(&down, 1.5, &mut rng);
    assert_eq!((r.popcount, r.transmittance, r.hit), (0, 1.0, 0));
    // Down through everything: the bit is the last interval (31) of this chord.
    let r = s.query(&down, f32::INFINITY, &mut rng);
    assert_eq!((r.popcount, r.transmittance), (1, 0.5));
    if r.hit == 1 {
        assert_eq!(r.interval, 31);
        assert!((2.96875..=3.0).contains(&r.distance));
    }
    // Upwards, bottom half: the bit is the first interval.
    let up = Ray::new([0.5, 0.5, -1.0], [0.0, 0.0, 1.0]);
    let r = s.query(&up, 1.5, &mut rng);
    assert_eq!((r.popcount, r.transmittance), (1, 0.5));
}

fn homogeneous_sampler_check(s: &Sampler<'_>, ray: Ray, t_max: f32, want_t: f32) {
    let mut rng = Rng::new(9);
    let r = s.query(&ray, t_max, &mut rng);
    assert_eq!(r.status, status::OK, "{ray:?}");
    assert!(
        (r.transmittance - want_t).abs() <= want_t * 1e-5,
        "{ray:?}: {} vs {want_t}",
        r.transmittance
    );
    check_finite(&r);
}

#[test]
fn axis_parallel_grazing_inside_faces_edges_corners() {
    // Homogeneous: every interval set, t_min = 0.9; full chords are deterministic: 0.9^32.
    let g = grid_of(PinEntry {
        mask: u32::MAX,
        t_min: 0.9,
    });
    let s = g.sampler().unwrap();
    let full = 0.9f32.powi(32);
    let inf = f32::INFINITY;
    for (o, d) in [
        ([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0]),
        ([2.0, 0.5, 0.5], [-1.0, 0.0, 0.0]),
        ([0.5, -1.0, 0.5], [0.0, 1.0, 0.0]),
        ([0.5, 2.0, 0.5], [0.0, -1.0, 0.0]),
        ([0.5, 0.5, -1.0], [0.0, 0.0, 1.0]),
        ([0.5, 0.5, 2.0], [0.0, 0.0, -1.0]),
        // Grazing along a face and along an edge.
        ([-1.0, 0.0, 0.5], [1.0, 0.0, 0.0]),
        ([-1.0, 1.0, 1.0], [1.0, 0.0, 0.0]),
        ([0.0, 0.0, -3.0], [0.0, 0.0, 1.0]),
        // Starting on a face, an edge and a corner, going in.
        ([0.0, 0.5, 0.5], [1.0, 0.0, 0.0]),
        ([0.0, 0.0, 0.5], [1.0, 0.0, 0.0]),
        ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
        ([1.0, 1.0, 1.0], [-1.0, -1.0, -1.0]),
    ] {
        homogeneous_sampler_check(&s, Ray::new(o, d), inf, full);
    }
    // Starting inside: the segment starts at interval 16 exactly.
    homogeneous_sampler_check(
        &s,
        Ray::new([0.5, 0.5, 0.5], [0.0, 0.0, 1.0]),
        inf,
        0.9f32.powi(16),
    );
    homogeneous_sampler_check(
        &s,
        Ray::new([0.5, 0.5, 0.5], [0.0, 0.0, -1.0]),
        inf,
        0.9f32.powi(16),
    );
    // Misses: touching a corner, on a face going out, passing beside the box.
    let mut rng = Rng::new(1);
    for (o, d) in [
        ([-1.0, 1.0, 0.5], [1.0, 1.0, 0.0]),
        ([0.5, 1.0, 0.5], [0.0, 1.0, 0.0]),
        ([1.0, 1.0, 1.0], [1.0, 1.0, 1.0]),
        ([-1.0, 1.5, 0.5], [1.0, 0.0, 0.0]),
        ([0.5, 0.5, 2.0], [0.0, 0.0, 1.0]),
    ] {
        let before = rng;
        let r = s.query(&Ray::new(o, d), inf, &mut rng);
        assert_eq!(r.status, status::MISS, "{o:?} {d:?}");
        assert_eq!((r.transmittance, r.hit, r.entry), (1.0, 0, NO_ENTRY));
        assert_eq!(rng, before, "misses draw nothing");
    }
}

#[test]
fn zero_length_and_infinite_segments() {
    let g = grid_of(PinEntry {
        mask: u32::MAX,
        t_min: 0.9,
    });
    let s = g.sampler().unwrap();
    let mut rng = Rng::new(3);
    for o in [[0.5, 0.5, 0.5], [0.5, 0.5, -1.0]] {
        let ray = Ray::new(o, [0.0, 0.0, 1.0]);
        for t_max in [0.0, -0.0, -1.0, f32::NEG_INFINITY] {
            let r = s.query(&ray, t_max, &mut rng);
            assert_eq!((r.status, r.transmittance, r.hit), (status::MISS, 1.0, 0));
        }
        let a = s.query(&ray, f32::INFINITY, &mut Rng::new(4));
        let b = s.query(&ray, 1e30, &mut Rng::new(4));
        assert_eq!(a, b);
        assert_eq!(a.status, status::OK);
    }
    // A very short segment: a partial first interval, participating rarely.
    let ray = Ray::new([0.5, 0.5, 0.5], [0.0, 0.0, 1.0]);
    let mut sum = 0.0f64;
    let n = 100_000;
    for _ in 0..n {
        let r = s.query(&ray, 1e-4, &mut rng);
        check_finite(&r);
        sum += f64::from(r.transmittance);
        if r.hit == 1 {
            assert!((0.0..=1e-4).contains(&r.distance));
        }
    }
    // E[T] = 1 - f (1 - 0.9), f = 1e-4 * 32.
    let want = 1.0 - 32e-4 * 0.1;
    assert!((sum / n as f64 - want).abs() < 1e-4, "{}", sum / n as f64);
}

#[test]
fn invalid_inputs_give_one_and_no_collision() {
    let g = grid_of(PinEntry {
        mask: u32::MAX,
        t_min: 0.5,
    });
    let s = g.sampler().unwrap();
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let mut rng = Rng::new(8);
    for (o, d, t) in [
        ([0.5; 3], [0.0, 0.0, 0.0], inf),
        ([0.5; 3], [-0.0, 0.0, -0.0], inf),
        ([0.5; 3], [nan, 0.0, 1.0], inf),
        ([nan, 0.5, 0.5], [0.0, 0.0, 1.0], inf),
        ([inf, 0.5, 0.5], [-1.0, 0.0, 0.0], inf),
        ([0.5; 3], [inf, 0.0, 0.0], inf),
        ([0.5; 3], [0.0, 0.0, 1.0], nan),
    ] {
        let before = rng;
        let r = s.query(&Ray::new(o, d), t, &mut rng);
        assert_eq!(r.status, status::INVALID, "{o:?} {d:?} {t}");
        assert_eq!((r.transmittance, r.hit), (1.0, 0));
        assert_eq!(rng, before);
        assert_eq!(s.transmittance(&Ray::new(o, d), t, &mut rng), 1.0);
        assert_eq!(s.sample_distance(&Ray::new(o, d), t, &mut rng), None);
    }
}

#[test]
fn huge_and_tiny_coordinates_stay_finite() {
    let g = grid_of(PinEntry {
        mask: u32::MAX,
        t_min: 0.9,
    });
    let s = g.sampler().unwrap();
    let mut rng = Rng::new(11);
    // Far away but hitting: answers stay finite and in range.
    for far in [1e6f32, 1e20, 1e30, 3e38] {
        for d in [[1.0, 0.0, 0.0], [1.0, 1e-7, -1e-7]] {
            let r = s.query(&Ray::new([-far, 0.5, 0.5], d), f32::INFINITY, &mut rng);
            check_finite(&r);
        }
    }
    // 1e6 away still hits exactly.
    let r = s.query(
        &Ray::new([-1e6, 0.5, 0.5], [1.0, 0.0, 0.0]),
        f32::INFINITY,
        &mut rng,
    );
    assert_eq!(r.status, status::OK);
    assert!((r.transmittance - 0.9f32.powi(32)).abs() < 1e-6);
    // Huge and tiny direction magnitudes: t scales, transmittance does not.
    for scale in [1e-30f32, 1e-3, 1e3, 1e30] {
        let r = s.query(
            &Ray::new([-1.0, 0.5, 0.5], [scale, 0.0, 0.0]),
            f32::INFINITY,
            &mut rng,
        );
        assert_eq!(r.status, status::OK, "{scale}");
        assert!((r.transmittance - 0.9f32.powi(32)).abs() < 1e-6);
        if r.hit == 1 {
            assert!(r.distance >= 1.0 / scale * 0.999 && r.distance <= 2.0 / scale * 1.001);
        }
    }
    // A huge world transform: grid placed at 1e7 with scale 1e-3.
    let l2w = [
        1e-3, 0.0, 0.0, 1e7, 0.0, 1e-3, 0.0, 0.0, 0.0, 0.0, 1e-3, 0.0,
    ];
    let s2 = Sampler::with_local_to_world(&g, &l2w).unwrap();
    let r = s2.query(
        &Ray::new([1e7 - 1.0, 5e-4, 5e-4], [1.0, 0.0, 0.0]),
        f32::INFINITY,
        &mut rng,
    );
    check_finite(&r);
}

// ---------------------------------------------------------------------------------------------
// Statistics
// ---------------------------------------------------------------------------------------------

/// Random interval transmittances for a pin with the given `t_min` (one interval attains it).
fn random_ts(rng: &mut Rng, t_min: f64) -> [f64; 32] {
    let mut t = [0.0; 32];
    for x in t.iter_mut() {
        // Mostly thin intervals, so that the product stays estimable for t_min near 0.
        *x = 1.0 - (1.0 - t_min) * f64::from(rng.next_f32()).powi(4);
    }
    t[(rng.next_u32() % 32) as usize] = t_min;
    t
}

/// A fresh ratio mask: bit of interval j set with probability (1 - t_j) / (1 - t_min).
fn fresh_mask(rng: &mut Rng, t: &[f64; 32], t_min: f64) -> u32 {
    let mut m = 0;
    for (j, &tj) in t.iter().enumerate() {
        let p = if t_min < 1.0 {
            (1.0 - tj) / (1.0 - t_min)
        } else {
            0.0
        };
        if f64::from(rng.next_f32()) < p {
            m |= interval_bit(j as u32);
        }
    }
    m
}

/// Covered fraction of interval j by the segment.
fn coverage(seg: &Segment, j: u32) -> f64 {
    let lo = f64::from(seg.s0).max(f64::from(j));
    let hi = f64::from(seg.s1).min(f64::from(j) + 1.0);
    (hi - lo).clamp(0.0, 1.0)
}

/// E[T] = prod over intervals of (1 - f_j (1 - t_j)) (f = 1 for full ones).
fn expected_t(seg: &Segment, t: &[f64; 32]) -> f64 {
    (0..32)
        .map(|j| 1.0 - coverage(seg, j) * (1.0 - t[j as usize]))
        .product()
}

/// Exact discrete distribution of the collision interval: 32 bins + "none".
fn expected_hist(seg: &Segment, t: &[f64; 32]) -> [f64; 33] {
    let mut p = [0.0; 33];
    let mut survive = 1.0;
    for j in 0..32 {
        let c = coverage(seg, j as u32) * (1.0 - t[j]);
        p[j] = survive * c;
        survive *= 1.0 - c;
    }
    p[32] = survive;
    p
}

fn chi_square(observed: &[u64; 33], p: &[f64; 33], n: u64) -> (f64, usize) {
    let mut chi = 0.0;
    let mut df = 0usize;
    for (o, &pi) in observed.iter().zip(p) {
        let e = pi * n as f64;
        if e < 1e-9 {
            assert_eq!(*o, 0, "observed an impossible interval");
            continue;
        }
        chi += (*o as f64 - e).powi(2) / e;
        df += 1;
    }
    (chi, df.saturating_sub(1))
}

/// For any fixed ratio mask, P(no collision | I) equals E[T | I] exactly: the identity behind
/// "distance sampling and transmittance estimation describe the same medium".
#[test]
fn no_collision_probability_equals_expected_transmittance_exactly() {
    let mut rng = Rng::new(21);
    for _ in 0..2000 {
        let mask = rng.next_u32();
        let t_min = f64::from(rng.next_f32());
        let q = 1.0 - t_min;
        let u0 = rng.next_f32() * 0.5;
        let u1 = u0 + rng.next_f32() * (1.0 - u0);
        if !(u1 > u0) {
            continue;
        }
        let seg = seg_frac(u0, u1);
        let (mut p_none, mut e_t) = (1.0f64, 1.0f64);
        for j in 0..32u32 {
            if mask & interval_bit(j) == 0 {
                continue;
            }
            let f = coverage(&seg, j);
            // Participates w.p. f; then H set w.p. q -> collision; T factor t_min.
            p_none *= 1.0 - f * q;
            e_t *= f * t_min + (1.0 - f);
        }
        assert!((p_none - e_t).abs() < 1e-12, "{p_none} {e_t}");
    }
}

/// Mean of t_min^popcount over fresh masks matches prod t_i (full chord and partial segments).
#[test]
fn transmittance_is_unbiased() {
    let mut rng = Rng::new(31);
    let n = 200_000u32;
    for (case, &t_min) in [1e-4f64, 0.05, 0.5, 0.95, 0.9999].iter().enumerate() {
        for seg in [full_chord(), seg_frac(0.1234, 0.8765), seg_frac(0.3, 0.31)] {
            let t = random_ts(&mut rng, t_min);
            let want = expected_t(&seg, &t);
            let mut r = Rng::for_query(case as u32, 77);
            let (mut sum, mut sum2) = (0.0f64, 0.0f64);
            for _ in 0..n {
                let mask = fresh_mask(&mut r, &t, t_min);
                let e = PinEntry {
                    mask,
                    t_min: t_min as f32,
                };
                let v = f64::from(resolve_entry(e, false, &seg, &mut r, false).transmittance);
                sum += v;
                sum2 += v * v;
            }
            let mean = sum / f64::from(n);
            let var = (sum2 / f64::from(n) - mean * mean).max(0.0);
            let se = (var / f64::from(n)).sqrt().max(1e-7 * want.max(1e-30));
            let z = (mean - want) / se;
            assert!(
                z.abs() < 4.5,
                "t_min {t_min} seg {seg:?}: mean {mean} want {want} z {z}"
            );
        }
    }
}

/// Chi-square of the collision interval against the exact discrete distribution: the exact
/// mask passes everywhere; the thesis' 5-round mask fails at fine q.
#[test]
fn distance_distribution_chi_square() {
    let n = 200_000u64;
    let mut rng = Rng::new(41);
    for &t_min in &[0.001f64, 0.3, 0.9, 0.999] {
        for seg in [full_chord(), seg_frac(0.2, 0.7)] {
            let t = random_ts(&mut rng, t_min);
            let p = expected_hist(&seg, &t);
            let mut exact = [0u64; 33];
            let mut thesis = [0u64; 33];
            let mut r = Rng::for_query(7, (t_min * 1e4) as u32);
            for _ in 0..n {
                let mask = fresh_mask(&mut r, &t, t_min);
                let e = PinEntry {
                    mask,
                    t_min: t_min as f32,
                };
                let q = resolve_entry(e, false, &seg, &mut r, true);
                exact[q.interval as usize] += 1;
                if q.hit == 1 {
                    let d = q.distance;
                    let j = q.interval as f32;
                    let lo = seg.t_enter + j * seg.interval_len;
                    assert!(d >= lo.max(seg.t0) - 1e-6 && d <= lo + seg.interval_len + 1e-6);
                }
                // Same participation, thesis mask.
                let part = participating(&seg, r.next_f32(), r.next_f32());
                let h = thesis_sample_mask((1.0 - t_min) as f32, 5, &mut r);
                let m = mask & part & h;
                thesis[m.leading_zeros() as usize] += 1;
            }
            let (chi, df) = chi_square(&exact, &p, n);
            let limit = df as f64 + 6.0 * (2.0 * df as f64).sqrt() + 10.0;
            assert!(chi < limit, "exact mask t_min {t_min}: chi2 {chi} df {df}");
            let (chi_t, _) = chi_square(&thesis, &p, n);
            if t_min == 0.999 {
                assert!(
                    chi_t > 100.0 * limit,
                    "thesis k=5 should fail at t_min {t_min}: chi2 {chi_t}"
                );
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Agreement: single vs batch vs query, threads
// ---------------------------------------------------------------------------------------------

fn random_rays(n: usize, seed: u32) -> Vec<RayQuery> {
    let mut r = Rng::new(seed);
    (0..n)
        .map(|i| {
            let o = [
                r.next_f32() * 3.0 - 1.0,
                r.next_f32() * 3.0 - 1.0,
                r.next_f32() * 3.0 - 1.0,
            ];
            let d = [
                r.next_f32() * 2.0 - 1.0,
                r.next_f32() * 2.0 - 1.0,
                r.next_f32() * 2.0 - 1.0,
            ];
            let t_max = match i % 4 {
                0 => f32::INFINITY,
                1 => r.next_f32() * 2.0,
                _ => r.next_f32() * 0.5,
            };
            RayQuery::new(o, d, t_max)
        })
        .collect()
}

#[test]
fn batch_equals_single_and_query_parts() {
    for (dirs, sparse) in [
        (Directions::THESIS_DEFAULT, true),
        (Directions::Octahedral { n: 5 }, false),
    ] {
        let g = loaded_random_grid(dirs, [5, 4, 3], 3, sparse, 17);
        for opts in [
            SamplerOptions::THESIS,
            SamplerOptions {
                spatial_jitter: 1.0,
                directional_jitter: 0.5,
                ..SamplerOptions::THESIS
            },
        ] {
            let s = g.sampler().unwrap().with_options(opts);
            let rays = random_rays(3000, 5);
            let mut full = vec![QueryResult::empty_for_tests(); rays.len()];
            let mut ts = vec![0.0; rays.len()];
            let mut ds = vec![None; rays.len()];
            s.query_batch(&rays, 99, 1000, &mut full);
            s.transmittance_batch(&rays, 99, 1000, &mut ts);
            s.sample_distance_batch(&rays, 99, 1000, &mut ds);
            let mut ok = 0;
            for (i, q) in rays.iter().enumerate() {
                let rng = Rng::for_query(99, 1000 + i as u32);
                let single = s.query(&q.ray(), q.t_max, &mut rng.clone());
                assert_eq!(single, full[i]);
                assert_eq!(
                    s.transmittance(&q.ray(), q.t_max, &mut rng.clone()),
                    full[i].transmittance
                );
                assert_eq!(ts[i], full[i].transmittance);
                assert_eq!(
                    s.sample_distance(&q.ray(), q.t_max, &mut rng.clone()),
                    full[i].collision()
                );
                assert_eq!(ds[i], full[i].collision());
                check_finite(&full[i]);
                if full[i].status == status::OK && full[i].entry != NO_ENTRY {
                    ok += 1;
                    let e = g.pins()[full[i].entry as usize];
                    assert!(
                        full[i].popcount <= e.mask.count_ones(),
                        "popcount bounded by the mask"
                    );
                }
            }
            assert!(ok > 100, "{ok} resolved queries");
        }
    }
}

#[test]
fn lookup_matches_pin_file_entry() {
    // With the thesis' lookup (no jitter, the segment start), the entry read is
    // PinFile::entry(cell of the segment start, index_of, k).
    let owned = random_grid(Directions::THESIS_DEFAULT, [4, 3, 5], 2, true, 23);
    let bytes = owned.to_bytes().unwrap();
    let file = pin_format::PinFile::parse(&bytes).unwrap();
    let g = PinGrid::from_bytes(bytes.clone()).unwrap();
    let s = g.sampler().unwrap().with_options(SamplerOptions::THESIS);
    let rays = random_rays(5000, 6);
    for (i, q) in rays.iter().enumerate() {
        let mut rng = Rng::for_query(3, i as u32);
        let r = s.query(&q.ray(), q.t_max, &mut rng);
        if r.status != status::OK {
            continue;
        }
        let chord = crate::chord::unit_cube_chord(q.origin, q.dir).unwrap();
        let seg = segment(chord, q.t_max).unwrap();
        let p: Vec<f32> = (0..3).map(|a| q.origin[a] + q.dir[a] * seg.t0).collect();
        let cell = [
            crate::chord::bin(p[0] * 4.0, 4),
            crate::chord::bin(p[1] * 3.0, 3),
            crate::chord::bin(p[2] * 5.0, 5),
        ];
        let d = if q.dir[2] < 0.0 {
            q.dir.map(|x| -x)
        } else {
            q.dir
        };
        let dir = Directions::THESIS_DEFAULT.index_of(d);
        let k = Rng::for_query(3, i as u32).below_256(2);
        let want = file.entry(cell, dir, k);
        let got = if r.entry == NO_ENTRY {
            PinEntry::EMPTY
        } else {
            g.pins()[r.entry as usize]
        };
        assert_eq!(got, want, "ray {i}");
    }
}

#[test]
fn threads_agree_with_one_thread_on_a_mapped_grid() {
    use rayon::prelude::*;
    let owned = random_grid(Directions::Octahedral { n: 8 }, [9, 7, 8], 2, true, 29);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mt.pin");
    owned.write_atomic(&path).unwrap();
    let g = PinGrid::open(&path).unwrap();
    assert!(g.is_mapped());
    let s = g.sampler().unwrap();
    let rays = random_rays(50_000, 8);
    let mut one = vec![QueryResult::empty_for_tests(); rays.len()];
    s.query_batch(&rays, 5, 0, &mut one);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(4)
        .build()
        .unwrap();
    let many: Vec<QueryResult> = pool.install(|| {
        rays.par_chunks(777)
            .enumerate()
            .flat_map_iter(|(c, chunk)| {
                let mut out = vec![QueryResult::empty_for_tests(); chunk.len()];
                s.query_batch(chunk, 5, (c * 777) as u32, &mut out);
                out
            })
            .collect()
    });
    assert_eq!(one, many);
    // Per-thread generators with single queries give the same as sequential too.
    let singles: Vec<QueryResult> = pool.install(|| {
        rays.par_iter()
            .enumerate()
            .map(|(i, q)| s.query(&q.ray(), q.t_max, &mut Rng::for_query(5, i as u32)))
            .collect()
    });
    assert_eq!(one, singles);
}

impl QueryResult {
    pub(crate) fn empty_for_tests() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

fn parse_wgsl_hex_f32(lit: &str) -> f32 {
    // [-]0x1.HHHHHHp<exp>f
    let (neg, rest) = match lit.strip_prefix('-') {
        Some(r) => (true, r),
        None => (false, lit),
    };
    let rest = rest
        .strip_prefix("0x1.")
        .unwrap()
        .strip_suffix('f')
        .unwrap();
    let (mant, exp) = rest.split_once('p').unwrap();
    let m = u32::from_str_radix(mant, 16).unwrap();
    let e: i32 = exp.parse().unwrap();
    assert_eq!(m & 1, 0, "24-bit hex mantissa");
    let bits = (u32::from(neg) << 31) | (((e + 127) as u32) << 23) | (m >> 1);
    f32::from_bits(bits)
}

#[test]
fn wgsl_constants_match_cpu() {
    let want = [
        ("C0", 0.999_866f32),
        ("C1", -0.330_299_5),
        ("C2", 0.180_141),
        ("C3", -0.085_133),
        ("C4", 0.020_835_1),
        ("HALF_PI", std::f32::consts::FRAC_PI_2),
        ("PI", std::f32::consts::PI),
        ("INV_TAU", 1.0 / std::f32::consts::TAU),
        ("MAXF", f32::MAX),
        ("TWO_M24", 1.0 / 16_777_216.0),
        ("TWO_32", 4_294_967_296.0),
    ];
    for (name, v) in want {
        let prefix = format!("const {name}: f32 = ");
        let line = crate::PIN_WGSL
            .lines()
            .find(|l| l.starts_with(&prefix))
            .unwrap_or_else(|| panic!("{name} missing from pin.wgsl"));
        let lit = line[prefix.len()..].trim_end_matches(';');
        assert_eq!(parse_wgsl_hex_f32(lit).to_bits(), v.to_bits(), "{name}");
    }
    let rng = [
        ("PCG_MUL", crate::rng::PCG_MUL),
        ("PCG_INC", crate::rng::PCG_INC),
        ("PCG_OUT_MUL", crate::rng::PCG_OUT_MUL),
    ];
    for (name, v) in rng {
        assert!(
            crate::PIN_WGSL.contains(&format!("const {name}: u32 = {v}u;")),
            "{name}"
        );
    }
}

/// `Sampler::world_bounds` contains every query the sampler resolves: a ray whose segment
/// misses the box (slab test in f64 with a 1e-5 margin) is a miss with no draws, for
/// translated, scaled and rotated placements.
#[test]
fn world_bounds_contain_every_hit() {
    let mut desc_grid = random_grid(
        Directions::Polar {
            n_phi: 4,
            n_theta: 2,
        },
        [3, 2, 4],
        2,
        false,
        9,
    );
    desc_grid.desc.box_min = [-1.0, 0.5, 2.0];
    desc_grid.desc.box_max = [1.5, 1.0, 4.0];
    let g = PinGrid::from_bytes(desc_grid.to_bytes().unwrap()).unwrap();
    let (c, s) = (0.6f64.cos(), 0.6f64.sin());
    let placements: [Option<[f64; 12]>; 3] = [
        None,
        Some([2.0, 0.0, 0.0, 3.0, 0.0, 0.5, 0.0, -1.0, 0.0, 0.0, 1.0, 7.0]),
        Some([c, -s, 0.0, 0.5, s, c, 0.0, 0.0, 0.0, 0.0, 1.0, -2.0]),
    ];
    let mut rng = Rng::new(77);
    for m in placements {
        let sampler = match &m {
            None => Sampler::new(&g).unwrap(),
            Some(m) => Sampler::with_local_to_world(&g, m).unwrap(),
        };
        let (lo, hi) = sampler.world_bounds().unwrap();
        let centre: [f64; 3] = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..20_000 {
            let o = [0, 1, 2].map(|a| (centre[a] + (rng.next_f32() as f64 - 0.5) * 12.0) as f32);
            // Half of the rays aimed at a point in or near the box, half random.
            let aim =
                [0, 1, 2].map(|a| lo[a] + (hi[a] - lo[a]) * (rng.next_f32() as f64 * 1.2 - 0.1));
            let d = if rng.next_f32() < 0.5 {
                [0, 1, 2].map(|a| (aim[a] - o[a] as f64) as f32)
            } else {
                [0, 1, 2].map(|_| rng.next_f32() - 0.5)
            };
            let t_max = if rng.next_f32() < 0.5 {
                f32::INFINITY
            } else {
                5.0 * rng.next_f32()
            };
            // Exact-ish slab test in f64 against the box grown by 1e-5.
            let (mut tn, mut tf) = (0.0f64, t_max as f64);
            for a in 0..3 {
                let (o, d) = (o[a] as f64, d[a] as f64);
                let (l, h) = (lo[a] - 1e-5, hi[a] + 1e-5);
                if d == 0.0 {
                    if o < l || o > h {
                        tf = -1.0;
                    }
                    continue;
                }
                let (t0, t1) = ((l - o) / d, (h - o) / d);
                tn = tn.max(t0.min(t1));
                tf = tf.min(t0.max(t1));
            }
            let before = rng;
            let mut r = rng;
            let q = sampler.query(&Ray::new(o, d), t_max, &mut r);
            if tn <= tf {
                hits += (q.status == status::OK) as u32;
                rng = r;
                continue;
            }
            misses += 1;
            assert_eq!(q.status, status::MISS, "{o:?} {d:?} {t_max} {m:?}");
            assert_eq!(r.state, before.state, "a miss draws nothing");
        }
        assert!(hits > 1000 && misses > 1000, "{hits} / {misses}");
    }
}

/// `Sampler::expected_transmittance` (closed form) against `Sampler::mean_transmittance`
/// (the mean of many single estimates) on random rays with partial segments through a random
/// grid with several pins per entry: a 5-sigma bound from the estimate's variance (each
/// estimate lies in [0, 1], so var <= E (1 - E)). The power check: a nearby wrong answer, the
/// expectation over the segment extended to the box exit (what a closed form that ignored
/// `t_max` would give), must fall outside the bound for some ray.
#[test]
fn expected_transmittance_is_the_mean_of_the_estimates() {
    let grid = loaded_random_grid(Directions::THESIS_DEFAULT, [3, 4, 2], 3, false, 17);
    // The closed form needs an unjittered lookup.
    let s = Sampler::new(&grid)
        .unwrap()
        .with_options(SamplerOptions::THESIS);
    let mut rng = Rng::new(99);
    let draws = 8192u32;
    let mut mutation_caught = false;
    for i in 0..60 {
        let o = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
        let d = [
            rng.next_f32() - 0.5,
            rng.next_f32() - 0.5,
            rng.next_f32() - 0.5,
        ];
        let ray = Ray::new(o, d);
        let t_max = 0.05 + rng.next_f32();
        let want = s.expected_transmittance(&ray, t_max).unwrap();
        let got = s.mean_transmittance(&ray, t_max, draws, i);
        let bound = five_sigma(want, draws);
        assert!(
            (got - want).abs() <= bound,
            "ray {i}: mean {got} vs expected {want} (bound {bound})"
        );
        let wrong = s.expected_transmittance(&ray, f32::INFINITY).unwrap();
        if (got - wrong).abs() > bound {
            mutation_caught = true;
        }
    }
    assert!(
        mutation_caught,
        "the bound cannot tell a wrong expectation apart"
    );
    let jittered = Sampler::new(&grid).unwrap().with_options(SamplerOptions {
        spatial_jitter: 1.0,
        directional_jitter: 0.0,
        ..SamplerOptions::THESIS
    });
    let ray = Ray::new([0.5; 3], [0.0, 0.0, 1.0]);
    assert_eq!(jittered.expected_transmittance(&ray, 1.0), None);
    assert!(jittered.mean_transmittance(&ray, 1.0, 256, 1).is_finite());
}

// ---------------------------------------------------------------------------------------------
// Chained lookups (docs/sampling.md section 12)
// ---------------------------------------------------------------------------------------------

fn chain(chain_stride: u32, midpoint_lookup: bool, jitter: f32) -> SamplerOptions {
    SamplerOptions {
        spatial_jitter: jitter,
        directional_jitter: jitter,
        chain_stride,
        midpoint_lookup,
        start_inside: false,
        nearest_line: 0,
    }
}

/// FNV-1a over every field of every result: a fingerprint of a run.
fn fingerprint(results: &[QueryResult]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for r in results {
        for w in [
            r.distance.to_bits(),
            r.transmittance.to_bits(),
            r.hit,
            r.entry,
            r.popcount,
            r.interval,
            r.status,
            r.rng_state,
        ] {
            h = (h ^ u64::from(w)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// One lookup per chord (stride 0, 32 or more) must reproduce the sampler from before chained
/// lookups existed bit for bit. The fingerprints were recorded with that sampler (commit
/// 37f2b2c) on these rays and grids, without and with jitter.
#[test]
fn one_lookup_per_chord_reproduces_the_unchained_sampler() {
    let g = loaded_random_grid(Directions::Octahedral { n: 5 }, [5, 4, 3], 3, true, 17);
    let rays = random_rays(4000, 5);
    let run = |opts: SamplerOptions| {
        let mut out = vec![QueryResult::empty_for_tests(); rays.len()];
        g.sampler()
            .unwrap()
            .with_options(opts)
            .query_batch(&rays, 7, 3, &mut out);
        fingerprint(&out)
    };
    let recorded = [0xcabf_0bc0_3061_f62c_u64, 0xe22b_cbf1_f69a_6aab];
    for (i, jitter) in [0.0, 1.0].into_iter().enumerate() {
        for stride in [0, 32, 33, u32::MAX] {
            assert_eq!(
                run(chain(stride, false, jitter)),
                recorded[i],
                "stride {stride}"
            );
        }
        // The mutation: a real chain changes the results.
        assert_ne!(run(chain(16, false, jitter)), recorded[i]);
    }
}

/// Chained queries agree between the single and the batch paths, and `query`'s distance is
/// `sample_distance`'s. Its transmittance is `transmittance()`'s only with one lookup: `query`
/// draws the sample mask (and position) of each piece that `transmittance()` does not draw,
/// so the later pieces see other numbers (both estimates are unbiased).
#[test]
fn chained_batch_equals_single() {
    let g = loaded_random_grid(Directions::THESIS_DEFAULT, [5, 4, 3], 3, true, 17);
    for opts in [
        chain(4, false, 1.0),
        chain(7, true, 0.0),
        chain(1, false, 0.5),
    ] {
        let s = g.sampler().unwrap().with_options(opts);
        let rays = random_rays(3000, 6);
        let mut full = vec![QueryResult::empty_for_tests(); rays.len()];
        let mut ts = vec![0.0; rays.len()];
        let mut ds = vec![None; rays.len()];
        s.query_batch(&rays, 99, 1000, &mut full);
        s.transmittance_batch(&rays, 99, 1000, &mut ts);
        s.sample_distance_batch(&rays, 99, 1000, &mut ds);
        let mut chained = 0;
        for (i, q) in rays.iter().enumerate() {
            let rng = Rng::for_query(99, 1000 + i as u32);
            assert_eq!(s.query(&q.ray(), q.t_max, &mut rng.clone()), full[i]);
            assert_eq!(s.transmittance(&q.ray(), q.t_max, &mut rng.clone()), ts[i]);
            let d = s.sample_distance(&q.ray(), q.t_max, &mut rng.clone());
            assert_eq!(d, ds[i]);
            assert_eq!(d, full[i].collision());
            check_finite(&full[i]);
            let seg = crate::chord::unit_cube_chord(
                s.transform().point(q.origin),
                s.transform().vector(q.dir),
            )
            .and_then(|c| segment(c, q.t_max));
            if let Some(seg) = seg.filter(|_| full[i].status == status::OK) {
                if seg.a / opts.stride() != seg.b / opts.stride() {
                    chained += 1;
                }
                if let Some(t) = d {
                    assert!(seg.t0 <= t && t <= seg.t1, "{t} outside {seg:?}");
                }
            }
        }
        assert!(chained > 50, "{opts:?}: {chained} multi-piece queries");
    }
}

/// The chain's claim (docs/sampling.md section 12): independent lookups per piece make the
/// mean transmittance the product of the pieces' expectations, and distance sampling that
/// walks the pieces misses every piece with that same probability. Checked on random rays
/// against `expected_transmittance` (which multiplies the pieces' closed forms) with a
/// 5-sigma bound from the variance (each estimate and each miss indicator lies in [0, 1]).
/// The power checks: the one-lookup expectation of the same ray, and for distances a walk
/// that stops after the first piece (its miss probability is the first piece's expectation),
/// must each fall outside the bound for some ray.
#[test]
fn chained_mean_is_the_product_of_the_pieces() {
    let grid = loaded_random_grid(Directions::Octahedral { n: 4 }, [4, 3, 5], 2, false, 23);
    let draws = 8192u32;
    for opts in [chain(8, false, 0.0), chain(5, true, 0.0)] {
        let s = Sampler::new(&grid).unwrap().with_options(opts);
        let one = Sampler::new(&grid)
            .unwrap()
            .with_options(SamplerOptions::THESIS);
        let mut rng = Rng::new(41);
        let (mut caught_t, mut caught_d) = (false, false);
        for i in 0..40 {
            let (ray, t_max) = ray_from_inside_unit_box(&mut rng);
            let want = s.expected_transmittance(&ray, t_max).unwrap();
            let got = s.mean_transmittance(&ray, t_max, draws, i);
            let bound = five_sigma(want, draws);
            assert!(
                (got - want).abs() <= bound,
                "{opts:?} ray {i}: mean {got} vs expected {want} (bound {bound})"
            );
            let wrong = one.expected_transmittance(&ray, t_max).unwrap();
            caught_t |= (got - wrong).abs() > bound;

            let rays = vec![RayQuery::new(ray.origin, ray.dir, t_max); draws as usize];
            let mut dist = vec![None; rays.len()];
            s.sample_distance_batch(&rays, 5, i * draws, &mut dist);
            let miss = dist.iter().filter(|x| x.is_none()).count() as f64 / f64::from(draws);
            assert!(
                (miss - want).abs() <= bound,
                "{opts:?} ray {i}: P(no collision) {miss} vs {want} (bound {bound})"
            );
            // The first piece alone: the segment cut at its end.
            let seg = crate::chord::unit_cube_chord(
                s.transform().point(ray.origin),
                s.transform().vector(ray.dir),
            )
            .and_then(|c| segment(c, t_max))
            .unwrap();
            let first = crate::sampler::piece_of(&seg, seg.a / opts.stride(), opts.stride());
            let first_only = s.expected_transmittance(&ray, first.t1).unwrap();
            caught_d |= (miss - first_only).abs() > bound;
        }
        assert!(
            caught_t,
            "{opts:?}: the bound cannot tell one lookup from a chain"
        );
        assert!(
            caught_d,
            "{opts:?}: the bound cannot tell a walk that stops early"
        );
    }
}

/// Pieces cut only at interval boundaries: every interval of the segment belongs to exactly
/// one piece, the segment's partial ends stay where they were, and inner cuts are whole
/// numbers of intervals.
#[test]
fn pieces_tile_the_segment() {
    let mut rng = Rng::new(3);
    for _ in 0..2000 {
        let u0 = rng.next_f32();
        let u1 = u0 + (1.0 - u0) * rng.next_f32();
        if !(u1 > u0) {
            continue;
        }
        let seg = seg_frac(u0, u1);
        for stride in [1, 3, 4, 7, 16, 31, 32] {
            let mut covered = 0u32;
            let mut j = seg.a / stride;
            let mut last_t1 = seg.t0;
            loop {
                let p = crate::sampler::piece_of(&seg, j, stride);
                assert!(p.a <= p.b && p.s0 <= p.s1, "{p:?}");
                assert_eq!(covered & interval_range_bits(p.a, p.b), 0, "overlap");
                covered |= interval_range_bits(p.a, p.b);
                assert_eq!(p.t0, last_t1.max(p.t0), "pieces in order");
                if p.a != seg.a {
                    assert_eq!(p.s0, p.a as f32);
                } else {
                    assert_eq!((p.s0, p.t0), (seg.s0, seg.t0));
                }
                if p.b == seg.b {
                    assert_eq!((p.s1, p.t1), (seg.s1, seg.t1));
                    break;
                }
                assert_eq!(p.s1, (p.b + 1) as f32);
                assert_eq!((p.b + 1) % stride, 0);
                last_t1 = p.t1;
                j += 1;
            }
            assert_eq!(covered, interval_range_bits(seg.a, seg.b));
        }
    }
}

fn interval_range_bits(a: u32, b: u32) -> u32 {
    crate::mask::interval_range(a, b)
}

/// `docs/sampling.md` section 13: with one cell of spatial and directional jitter, a lookup's
/// expectation is the trilinear (space) times bilinear (octahedral square) interpolation of
/// the unjittered expectations of the neighbouring cells, with each cell's pin at its centre:
/// the interpolation weights of pins baked through cell centres (`pinbake`'s default).
#[test]
fn one_cell_of_jitter_interpolates_between_cell_centres() {
    let grid = loaded_random_grid(Directions::Octahedral { n: 4 }, [4, 3, 5], 2, false, 29);
    let draws = 8192u32;
    for middle in [false, true] {
        let s = Sampler::new(&grid).unwrap().with_options(SamplerOptions {
            spatial_jitter: 1.0,
            directional_jitter: 1.0,
            midpoint_lookup: middle,
            ..SamplerOptions::THESIS
        });
        let plain = Sampler::new(&grid).unwrap().with_options(SamplerOptions {
            midpoint_lookup: middle,
            ..SamplerOptions::THESIS
        });
        let mut rng = Rng::new(43);
        let (mut caught_nearest, mut caught_corner) = (false, false);
        for i in 0..40 {
            let (ray, t_max) = ray_from_inside_unit_box(&mut rng);
            let want = interpolated(&plain, &ray, t_max, 0.5);
            let got = s.mean_transmittance(&ray, t_max, draws, i);
            let bound = five_sigma(want, draws);
            assert!(
                (got - want).abs() <= bound,
                "middle {middle}, ray {i}: mean {got} vs interpolated {want} (bound {bound})"
            );
            // Mutations: the nearest cell alone, and weights for pins at the cells' corners.
            let nearest = plain.expected_transmittance(&ray, t_max).unwrap();
            caught_nearest |= (got - nearest).abs() > bound;
            caught_corner |= (got - interpolated(&plain, &ray, t_max, 0.0)).abs() > bound;
        }
        assert!(caught_nearest, "the bound cannot tell jitter from none");
        assert!(caught_corner, "the bound cannot tell where the pins sit");
    }
}

/// `docs/sampling.md` section 14: with `start_inside`, a ray that starts inside the box is
/// looked up at its start without spatial jitter, so its expectation is the bilinear
/// direction interpolation of the start cell's entries alone, whatever the lookup point and
/// the spatial jitter say; a ray that starts outside the box is answered bit for bit as
/// without the option.
#[test]
fn start_inside_reads_the_start_cell() {
    let grid = loaded_random_grid(Directions::Octahedral { n: 4 }, [4, 3, 5], 2, false, 31);
    let render = SamplerOptions {
        spatial_jitter: 1.0,
        directional_jitter: 1.0,
        midpoint_lookup: true,
        ..SamplerOptions::THESIS
    };
    let s = Sampler::new(&grid).unwrap().with_options(SamplerOptions {
        start_inside: true,
        ..render
    });
    let at = |midpoint_lookup| {
        Sampler::new(&grid).unwrap().with_options(SamplerOptions {
            midpoint_lookup,
            ..SamplerOptions::THESIS
        })
    };
    let (start, middle) = (at(false), at(true));
    let draws = 8192u32;
    let mut rng = Rng::new(47);
    let (mut caught_middle, mut caught_spatial) = (false, false);
    for i in 0..40 {
        let (ray, t_max) = ray_from_inside_unit_box(&mut rng);
        let want = interpolated_with(&start, &ray, t_max, 0.5, false);
        let got = s.mean_transmittance(&ray, t_max, draws, i);
        let bound = five_sigma(want, draws);
        assert!(
            (got - want).abs() <= bound,
            "ray {i}: mean {got} vs the start cell's {want} (bound {bound})"
        );
        // Mutations: the rule off (the middle, trilinear), and the start with the spatial
        // jitter kept (trilinear around the start).
        caught_middle |= (got - interpolated(&middle, &ray, t_max, 0.5)).abs() > bound;
        caught_spatial |= (got - interpolated(&start, &ray, t_max, 0.5)).abs() > bound;
    }
    assert!(
        caught_middle,
        "the bound cannot tell the start from the middle"
    );
    assert!(
        caught_spatial,
        "the bound cannot tell the spatial jitter from none"
    );

    // Rays from outside the box: the same results, field for field, as without the option.
    let plain = Sampler::new(&grid).unwrap().with_options(render);
    let rays: Vec<RayQuery> = (0..2000)
        .map(|_| {
            let o = [0, 1, 2].map(|_| rng.next_f32() * 4.0 - 1.5);
            let target = [0, 1, 2].map(|_| rng.next_f32());
            let inside = o.iter().all(|&x| (0.0..=1.0).contains(&x));
            let o = if inside { [-0.5, o[1], o[2]] } else { o };
            let d = [0, 1, 2].map(|a| target[a] - o[a]);
            RayQuery::new(
                o,
                d,
                if rng.next_f32() < 0.5 {
                    f32::INFINITY
                } else {
                    2.0
                },
            )
        })
        .collect();
    let mut a = vec![QueryResult::empty_for_tests(); rays.len()];
    let mut b = a.clone();
    s.query_batch(&rays, 5, 0, &mut a);
    plain.query_batch(&rays, 5, 0, &mut b);
    assert_eq!(fingerprint(&a), fingerprint(&b));
    assert!(a.iter().filter(|r| r.hit != 0).count() > 100);
}

/// A ray of the statistical tests below: from a uniform point of the unit box in a random
/// direction (not normalised), to a segment end in `[0.2, 2.2)`.
fn ray_from_inside_unit_box(rng: &mut Rng) -> (Ray, f32) {
    let o = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
    let d = [
        rng.next_f32() - 0.5,
        rng.next_f32() - 0.5,
        rng.next_f32() - 0.5,
    ];
    (Ray::new(o, d), 0.2 + 2.0 * rng.next_f32())
}

/// Five standard errors of the mean of `draws` values in `[0, 1]` with mean `want` (such a
/// variable has variance at most `want (1 - want)`), plus a rounding allowance.
fn five_sigma(want: f64, draws: u32) -> f64 {
    5.0 * (want * (1.0 - want) / f64::from(draws)).sqrt() + 1e-6
}

/// The interpolation of [`one_cell_of_jitter_interpolates_between_cell_centres`]: `centre` is
/// where a cell's pin sits inside it, in cells (0.5: its centre).
fn interpolated(plain: &Sampler<'_>, ray: &Ray, t_max: f32, centre: f32) -> f64 {
    interpolated_with(plain, ray, t_max, centre, true)
}

/// [`interpolated`], with the trilinear interpolation in space (`spatial`) or the cell of the
/// lookup point alone.
fn interpolated_with(
    plain: &Sampler<'_>,
    ray: &Ray,
    t_max: f32,
    centre: f32,
    spatial: bool,
) -> f64 {
    use crate::sampler::{NO_CELL, Prepared};
    let p: Prepared = plain.prepare(ray.origin, ray.dir, t_max, Rng::new(0));
    if p.status != status::OK {
        return 1.0;
    }
    let v = plain.view();
    let t = if plain.options().midpoint_lookup {
        0.5 * (p.seg.t0 + p.seg.t1)
    } else {
        p.seg.t0
    };
    let x = [0, 1, 2].map(|a| p.o[a] + p.d[a] * t);
    // The two cells around coordinate `c` (in cells) and their linear weights, clamped to
    // the grid as the lookup clamps.
    let axis = |c: f32, n: u32| -> [(u32, f64); 2] {
        let c = c - centre;
        let j0 = c.floor();
        let f = f64::from(c - j0);
        let clamp = |j: f32| (j.max(0.0) as u32).min(n - 1);
        [(clamp(j0), 1.0 - f), (clamp(j0 + 1.0), f)]
    };
    // Without spatial interpolation: the lookup's own cell (`lookup::bin`), weight 1.
    let own = |c: f32, n: u32| -> [(u32, f64); 2] {
        let j = (c.floor().max(0.0) as u32).min(n - 1);
        [(j, 1.0), (j, 0.0)]
    };
    let [sx, sy, sz] = [0, 1, 2].map(|a| {
        if spatial {
            axis(x[a] * v.dims_f[a], v.shape.dims[a])
        } else {
            own(x[a] * v.dims_f[a], v.shape.dims[a])
        }
    });
    let dl = if p.reversed {
        [-p.d[0], -p.d[1], -p.d[2]]
    } else {
        p.d
    };
    let Directions::Octahedral { n } = v.shape.directions else {
        unreachable!("an octahedral grid")
    };
    let (u, w) = pin_format::octahedral_uv(dl);
    let (du, dv) = (axis(u * n as f32, n), axis(w * n as f32, n));
    let ppe = u64::from(v.shape.pins_per_entry);
    let mut e = 0.0;
    for (cx, wx) in sx {
        for (cy, wy) in sy {
            for (cz, wz) in sz {
                for (cu, wu) in du {
                    for (cv, wv) in dv {
                        let q = Prepared {
                            local: v.local_cell([cx, cy, cz]).unwrap_or(NO_CELL),
                            within: u64::from(cv * n + cu) * ppe,
                            ..p
                        };
                        e += wx * wy * wz * wu * wv * plain.piece_expectation(&q);
                    }
                }
            }
        }
    }
    e
}

/// The default lookup is the render lookup, for the options and for every sampler made
/// without options; the thesis' lookup is the one without jitter, at the segment start.
#[test]
fn the_default_lookup_is_the_render_lookup() {
    assert_eq!(SamplerOptions::default(), SamplerOptions::RENDER);
    let grid = loaded_random_grid(Directions::THESIS_DEFAULT, [3, 4, 2], 2, true, 5);
    assert_eq!(*grid.sampler().unwrap().options(), SamplerOptions::RENDER);
    let l2w = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let placed = Sampler::with_local_to_world(&grid, &l2w).unwrap();
    assert_eq!(*placed.options(), SamplerOptions::RENDER);
    let copied = Sampler::with_transform(&grid, *placed.transform());
    assert_eq!(*copied.options(), SamplerOptions::RENDER);
    let t = SamplerOptions::THESIS;
    assert!(!t.spatial_on() && !t.directional_on());
    assert_eq!((t.stride(), t.lookup_mode()), (32, 0.0));
    // The two lookups answer differently on a random grid (so a default that silently fell
    // back to the thesis' lookup would be caught by the query tests, not only here).
    let thesis = grid.sampler().unwrap().with_options(t);
    let render = grid.sampler().unwrap();
    let rays = random_rays(2000, 8);
    let (mut a, mut b) = (vec![0.0f32; rays.len()], vec![0.0f32; rays.len()]);
    thesis.transmittance_batch(&rays, 1, 0, &mut a);
    render.transmittance_batch(&rays, 1, 0, &mut b);
    assert!(a.iter().zip(&b).any(|(x, y)| x != y));
}
