//! One pin: its line through the unit cube, its 32 interval optical depths, and the sampled
//! (mask, t_min) entry. This is the whole per-pin computation of a bake, in one pass.

use std::ops::Range;

use glam::DVec3;
use pin_format::{Directions, PinEntry};

use crate::rng::CounterRng;
use pin_volume::{DenseGrid, DensitySource};

/// Deterministic per-pin geometry in unit-cube coordinates.
#[derive(Clone, Copy, Debug)]
pub struct PinLayout {
    pub dims: [u32; 3],
    pub directions: Directions,
    pub pins_per_entry: u32,
    pub jitter: bool,
    pub seed: u64,
}

impl PinLayout {
    /// The RNG stream of pin `(cell, dir, k)`; draws: 3 position, 2 direction, 32 mask bits.
    pub fn rng(&self, cell_linear: u64, dir: u32, k: u32) -> CounterRng {
        let slot = u64::from(dir) * u64::from(self.pins_per_entry) + u64::from(k);
        CounterRng::new(self.seed, cell_linear, slot)
    }

    /// The pin's point and unit direction (z >= 0) in unit-cube coordinates.
    pub fn line(&self, cell: [u32; 3], dir: u32, rng: &mut CounterRng) -> (DVec3, DVec3) {
        let j = |rng: &mut CounterRng| if self.jitter { rng.next_f64() } else { 0.5 };
        let (jx, jy, jz) = (j(rng), j(rng), j(rng));
        let p = DVec3::new(
            (f64::from(cell[0]) + jx) / f64::from(self.dims[0]),
            (f64::from(cell[1]) + jy) / f64::from(self.dims[1]),
            (f64::from(cell[2]) + jz) / f64::from(self.dims[2]),
        );
        let (a, b) = (j(rng), j(rng));
        let w = DVec3::from(self.directions.direction_in_cell(dir, a, b));
        (p, w)
    }

    pub fn cell_linear(&self, cell: [u32; 3]) -> u64 {
        u64::from(cell[0])
            + u64::from(self.dims[0])
                * (u64::from(cell[1]) + u64::from(self.dims[1]) * u64::from(cell[2]))
    }
}

/// Intervals per pin.
pub const INTERVALS: usize = 32;
const _: () = assert!(INTERVALS == pin_format::layout::BITS_PER_PIN as usize);

/// Where the grid sits in world space and how fine the bake marches.
#[derive(Clone, Copy, Debug)]
pub struct Placement {
    pub box_min: DVec3,
    pub extent: DVec3,
    /// World-space ray-marching step.
    pub step: f64,
}

impl Placement {
    /// A bake over `bbox` marching `rel_step` of the box's longest edge per sample (the
    /// baker's `--step` convention).
    pub fn over(bbox: &pin_volume::Aabb, rel_step: f64) -> Self {
        let extent = bbox.extent();
        Placement {
            box_min: bbox.min,
            extent,
            step: rel_step * extent.max_element(),
        }
    }

    pub fn to_world(&self, u: DVec3) -> DVec3 {
        self.box_min + u * self.extent
    }
}

/// Parameter range `[s0, s1]` of the line `p + s w` inside the unit cube, or `None`.
///
/// Robust to axis-parallel directions (no 0 * inf): an axis with `w == 0` constrains nothing
/// if `p` is inside that slab and empties the chord otherwise.
pub fn unit_cube_chord(p: DVec3, w: DVec3) -> Option<(f64, f64)> {
    let mut s0 = f64::NEG_INFINITY;
    let mut s1 = f64::INFINITY;
    for a in 0..3 {
        if w[a] == 0.0 {
            if !(0.0..=1.0).contains(&p[a]) {
                return None;
            }
            continue;
        }
        let inv = 1.0 / w[a];
        let (mut ta, mut tb) = ((0.0 - p[a]) * inv, (1.0 - p[a]) * inv);
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
        }
        s0 = s0.max(ta);
        s1 = s1.min(tb);
    }
    (s0.is_finite() && s1.is_finite() && s1 >= s0).then_some((s0, s1))
}

/// What a bake marches: the source itself, or its dense grid where it is one.
#[derive(Clone, Copy)]
pub enum Field<'a> {
    Source(&'a dyn DensitySource),
    /// A dense grid marched on its own voxels: the same samples as `Source`, without the
    /// per-sample transform and box test.
    Grid(&'a DenseGrid),
}

impl<'a> Field<'a> {
    /// The fastest exact way to march `source`: its dense grid where it is one, else the
    /// source itself.
    pub fn of(source: &'a dyn DensitySource) -> Self {
        source
            .as_dense_grid()
            .map_or(Field::Source(source), Field::Grid)
    }
}

/// Optical depth of each of the 32 equal intervals of the chord of `p + s w` (unit-cube
/// coordinates), by the midpoint rule with at most `placement.step` world units per sample,
/// sampling `source` itself.
///
/// Sums run in f64 so that long pins through dense media keep their relative precision.
/// Returns zeros for a chord of zero length.
pub fn interval_optical_depths(
    source: &dyn DensitySource,
    placement: &Placement,
    p: DVec3,
    w: DVec3,
) -> [f64; INTERVALS] {
    field_optical_depths(Field::Source(source), placement, p, w)
}

/// The most samples per interval for which a dense grid is marched one whole pin at a time
/// (from one f64 base per interval); longer intervals take a fresh base every this many
/// samples, which sums in another order.
pub const GRID_WHOLE_PIN_STEPS: usize = 256;

/// Where the midpoint rule samples one pin's chord: `steps` samples per interval, sample `j`
/// of interval `i` at unit-cube parameter `s0 + ds * i + h * (j + 0.5)`, each weighing
/// `weight` world units. One definition for every way of marching a pin (per pin here, by
/// layers in `sweep.rs`), so that they take the same samples.
#[derive(Clone, Copy, Debug)]
pub struct ChordSamples {
    pub s0: f64,
    /// Parameter length of one interval.
    pub ds: f64,
    pub steps: usize,
    /// Parameter length of one sample.
    pub h: f64,
    pub weight: f64,
    /// The pin's point in world space.
    pub origin: DVec3,
    /// World displacement per unit of parameter.
    pub world_dir: DVec3,
}

/// The samples of the chord of `p + s w` (unit-cube coordinates) at `placement.step`, or
/// `None` when the chord misses the cube or has zero length (all optical depths zero).
pub fn chord_samples(placement: &Placement, p: DVec3, w: DVec3) -> Option<ChordSamples> {
    let (s0, s1) = unit_cube_chord(p, w)?;
    let ds = (s1 - s0) / INTERVALS as f64;
    let world_dir = w * placement.extent;
    let interval_len = ds * world_dir.length();
    if !(interval_len > 0.0) {
        return None;
    }
    let steps = (interval_len / placement.step).ceil().clamp(1.0, 1e6) as usize;
    Some(ChordSamples {
        s0,
        ds,
        steps,
        h: ds / steps as f64,
        weight: interval_len / steps as f64,
        origin: placement.to_world(p),
        world_dir,
    })
}

/// [`interval_optical_depths`] over either field: the same sample points and weights; a
/// [`Field::Grid`] steps its index in f32 from one f64 transform per interval instead of
/// transforming every sample.
pub fn field_optical_depths(
    field: Field<'_>,
    placement: &Placement,
    p: DVec3,
    w: DVec3,
) -> [f64; INTERVALS] {
    let mut taus = [0.0f64; INTERVALS];
    let Some(cs) = chord_samples(placement, p, w) else {
        return taus;
    };
    let ChordSamples {
        s0,
        ds,
        steps,
        h,
        weight,
        origin,
        world_dir,
    } = cs;
    // Sample points are evenly spaced along the whole chord, so sources can step
    // incrementally (`extinction_along`); a fixed chunk keeps the working set on the stack.
    const CHUNK: usize = GRID_WHOLE_PIN_STEPS;
    match field {
        Field::Source(source) => {
            let mut buf = [0.0f32; CHUNK];
            let mut sums = IntervalSums::new(steps);
            source_runs(source, &cs, 0..steps * INTERVALS, &mut buf, |_, run| {
                sums.extend(run)
            });
            taus = sums.finish(weight);
        }
        Field::Grid(grid) if steps <= CHUNK => {
            // The whole pin in one call: one f64 base per interval, f32 steps inside.
            let (ua, ub) = (grid.index_of(origin), grid.index_dir(world_dir));
            let du = ub * h;
            let f32x3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
            let bases: [[f32; 3]; INTERVALS] =
                std::array::from_fn(|i| f32x3(ua + ub * (s0 + ds * i as f64) + du * 0.5));
            grid.march_runs(&bases, f32x3(du), steps, &mut taus);
            for tau in &mut taus {
                *tau *= weight;
            }
        }
        Field::Grid(grid) => march(
            &mut taus,
            grid.index_of(origin),
            grid.index_dir(world_dir),
            (s0, ds, h, steps, weight),
            |u, du, n| {
                let mut sum = [0.0f64];
                grid.march_runs(&[u], du, n, &mut sum);
                sum[0]
            },
        ),
    }
    taus
}

/// The source's samples `range` of chord `cs` (sample `k` is sample `k % steps` of interval
/// `k / steps`, at `start + k * step`), as `visit(k0, run)` for runs of up to
/// [`GRID_WHOLE_PIN_STEPS`] samples from `k0`, a multiple of that, that overlap the range.
/// The whole chord in such runs, not one run per interval: a source that steps along a line
/// (the cosine noise's rotations) pays its set-up per run, and short intervals made that
/// set-up most of a procedural bake. The bake ([`field_optical_depths`]) and a farm part's
/// samples (`part.rs`) both read a chord through this, so their samples are the same bits.
pub(crate) fn source_runs(
    source: &dyn DensitySource,
    cs: &ChordSamples,
    range: Range<usize>,
    buf: &mut [f32; GRID_WHOLE_PIN_STEPS],
    mut visit: impl FnMut(usize, &[f32]),
) {
    const CHUNK: usize = GRID_WHOLE_PIN_STEPS;
    let step = cs.world_dir * cs.h;
    let start = cs.origin + cs.world_dir * cs.s0 + step * 0.5;
    let total = INTERVALS * cs.steps;
    let mut k0 = range.start / CHUNK * CHUNK;
    while k0 < range.end {
        let n = (total - k0).min(CHUNK);
        source.extinction_along(start + step * k0 as f64, step, n, &mut buf[..n]);
        visit(k0, &buf[..n]);
        k0 += n;
    }
}

/// Sums a chord's samples, fed in order, into its intervals' optical depths: per interval, a
/// fresh f64 sum per [`GRID_WHOLE_PIN_STEPS`] samples (counted from the interval's start)
/// added to the interval's, then times the weight. The one rule of the bake's sampled path
/// and of a farm merge (`part::optical_depths`).
pub(crate) struct IntervalSums {
    steps: usize,
    taus: [f64; INTERVALS],
    interval: usize,
    /// Samples of the current interval taken so far.
    j: usize,
    run: f64,
}

impl IntervalSums {
    pub(crate) fn new(steps: usize) -> Self {
        IntervalSums {
            steps,
            taus: [0.0; INTERVALS],
            interval: 0,
            j: 0,
            // As `Iterator::sum` over f64 starts.
            run: -0.0,
        }
    }

    pub(crate) fn extend(&mut self, samples: &[f32]) {
        for &v in samples {
            self.run += f64::from(v);
            self.j += 1;
            if self.j == self.steps || self.j.is_multiple_of(GRID_WHOLE_PIN_STEPS) {
                self.taus[self.interval] += self.run;
                self.run = -0.0;
                if self.j == self.steps {
                    self.interval += 1;
                    self.j = 0;
                }
            }
        }
    }

    pub(crate) fn finish(mut self, weight: f64) -> [f64; INTERVALS] {
        for tau in &mut self.taus {
            *tau *= weight;
        }
        self.taus
    }
}

/// The intervals of one chord in a grid's index space: `ua + s ub` is the line, each interval
/// gets one f64 base and f32 steps from there (a fresh base every `CHUNK` samples bounds the
/// f32 stepping error on long runs).
#[inline(always)]
fn march(
    taus: &mut [f64; INTERVALS],
    ua: DVec3,
    ub: DVec3,
    (s0, ds, h, steps, weight): (f64, f64, f64, usize, f64),
    sum_run: impl Fn([f32; 3], [f32; 3], usize) -> f64,
) {
    const CHUNK: usize = 256;
    let f32x3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
    let du = ub * h;
    let duf = f32x3(du);
    for (i, tau) in taus.iter_mut().enumerate() {
        let start = ua + ub * (s0 + ds * i as f64) + du * 0.5;
        let mut sum = 0.0f64;
        let mut j = 0;
        while j < steps {
            let n = (steps - j).min(CHUNK);
            sum += sum_run(f32x3(start + du * j as f64), duf, n);
            j += n;
        }
        *tau = sum * weight;
    }
}

/// The stored entry for a pin with interval optical depths `taus`, drawing one uniform per
/// interval from `rng`.
///
/// Uses `1 - t = -expm1(-tau)` so that the ratio `(1 - t_i) / (1 - t_min)` stays accurate for
/// optical depths down to subnormals and is never 0/0: `tau_max == 0` (or a `t_min` that
/// rounds to 1 in f32) gives the empty pin.
pub fn make_entry(taus: &[f64; INTERVALS], rng: &mut CounterRng) -> PinEntry {
    let tau_max = taus.iter().copied().fold(0.0f64, f64::max);
    let t_min = (-tau_max).exp() as f32;
    if !(tau_max > 0.0) || t_min >= 1.0 {
        return PinEntry::EMPTY;
    }
    let denom = -(-tau_max).exp_m1();
    let mut mask = 0u32;
    for (i, &tau) in taus.iter().enumerate() {
        let p = -(-tau).exp_m1() / denom;
        if rng.next_f64() < p {
            mask |= 1u32 << (31 - i);
        }
    }
    PinEntry { mask, t_min }
}

/// How far a bake's optical depths are from the exact ones, over a sample of random pins.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntegrationError {
    /// Pins measured.
    pub pins: usize,
    /// Mean over pins and intervals of `|exp(-tau) - exp(-tau_exact)|`: the error in the
    /// interval transmittances the masks encode.
    pub mean_abs_transmittance: f64,
    /// The largest such difference.
    pub max_abs_transmittance: f64,
    /// Mean over pins of `|sum tau - sum tau_exact| / max(sum tau_exact, 1e-12)`.
    pub mean_rel_optical_depth: f64,
}

/// Measures the midpoint rule at `placement.step` against the same rule at
/// `placement.step / supersample` (the "exact" optical depth: the error of a midpoint rule
/// falls with the square of its step, so 16x finer is ~256x more accurate) on `pins` random
/// lines through the unit cube, drawn from `seed`. Deterministic.
pub fn integration_error(
    source: &dyn DensitySource,
    placement: &Placement,
    pins: usize,
    supersample: u32,
    seed: u64,
) -> IntegrationError {
    integration_error_of(
        Field::Source(source),
        source,
        placement,
        pins,
        supersample,
        seed,
    )
}

/// [`integration_error`] of the rule that marches `field` at `placement.step` (what a bake
/// does: [`Field::of`] the source) against the `supersample`x finer midpoint rule on
/// `exact`, the source itself.
pub fn integration_error_of(
    field: Field<'_>,
    exact: &dyn DensitySource,
    placement: &Placement,
    pins: usize,
    supersample: u32,
    seed: u64,
) -> IntegrationError {
    let fine = Placement {
        step: placement.step / f64::from(supersample.max(1)),
        ..*placement
    };
    let (mut sum_t, mut max_t, mut sum_rel) = (0.0f64, 0.0f64, 0.0f64);
    for i in 0..pins {
        let mut rng = CounterRng::new(seed, 0x1e_7e57, i as u64);
        let p = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
        // A uniform direction on the sphere.
        let z = 2.0 * rng.next_f64() - 1.0;
        let phi = std::f64::consts::TAU * rng.next_f64();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let w = DVec3::new(r * phi.cos(), r * phi.sin(), z);
        let coarse = field_optical_depths(field, placement, p, w);
        let exact = interval_optical_depths(exact, &fine, p, w);
        for (a, b) in coarse.iter().zip(&exact) {
            let d = ((-a).exp() - (-b).exp()).abs();
            sum_t += d;
            max_t = max_t.max(d);
        }
        let (ta, tb): (f64, f64) = (coarse.iter().sum(), exact.iter().sum());
        sum_rel += (ta - tb).abs() / tb.max(1e-12);
    }
    let n = pins.max(1) as f64;
    IntegrationError {
        pins,
        mean_abs_transmittance: sum_t / (n * INTERVALS as f64),
        max_abs_transmittance: max_t,
        mean_rel_optical_depth: sum_rel / n,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_volume::Aabb;
    use pin_volume::Density;

    /// Extinction `k x^2` over the unit cube: the midpoint rule's error is known to fall as
    /// the square of the step.
    struct Parabola(f64);

    impl Density for Parabola {
        fn bounds(&self) -> Aabb {
            Aabb::new(DVec3::ZERO, DVec3::ONE)
        }
        fn extinction(&self, p: DVec3) -> f32 {
            (self.0 * p.x * p.x) as f32
        }
        fn max_extinction_in(&self, _region: Aabb) -> f32 {
            self.0 as f32
        }
    }

    impl DensitySource for Parabola {
        fn describe(&self) -> String {
            "parabola".into()
        }
    }

    fn unit(step: f64) -> Placement {
        Placement {
            box_min: DVec3::ZERO,
            extent: DVec3::ONE,
            step,
        }
    }

    #[test]
    fn integration_error_falls_with_the_square_of_the_step() {
        let src = Parabola(40.0);
        let coarse = integration_error(&src, &unit(0.02), 64, 16, 3);
        let finer = integration_error(&src, &unit(0.005), 64, 16, 3);
        assert_eq!(coarse.pins, 64);
        assert!(coarse.mean_abs_transmittance > 0.0);
        // 4x smaller step: ~16x smaller error (between 8x and 32x allows for the partial
        // steps at the interval ends and the f32 density).
        let ratio = coarse.mean_abs_transmittance / finer.mean_abs_transmittance;
        assert!(
            (8.0..32.0).contains(&ratio),
            "ratio {ratio}: {coarse:?} vs {finer:?}"
        );
        assert!(coarse.max_abs_transmittance >= coarse.mean_abs_transmittance);
        // Deterministic.
        assert_eq!(coarse, integration_error(&src, &unit(0.02), 64, 16, 3));
    }

    #[test]
    fn grid_marching_matches_the_source_rule() {
        // A 23x17x29 grid of scattered values, off-origin and anisotropic: the marched path
        // (f32 stepping, prefetched two-pass trilinear) gives the optical depths of the
        // sampled path to f32 precision, on short and long (> one run) pins.
        use pin_volume::DenseGrid;
        let dims = [23u32, 17, 29];
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let data: Vec<f32> = (0..n).map(|i| ((i * 7919) % 97) as f32 / 9.0).collect();
        let g = DenseGrid::new(
            dims,
            data,
            DVec3::new(0.1, 0.3, 0.2),
            DVec3::new(-1.0, 2.0, 0.5),
            "t",
        )
        .unwrap();
        for step in [0.01, 0.0003] {
            let placement = Placement::over(&g.bounds(), step);
            for i in 0..40 {
                let mut rng = CounterRng::new(5, 1, i);
                let p = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
                let w = DVec3::new(rng.next_f64() - 0.5, rng.next_f64() - 0.5, rng.next_f64())
                    .normalize();
                let a = interval_optical_depths(&g, &placement, p, w);
                let b = field_optical_depths(Field::of(&g), &placement, p, w);
                for (x, y) in a.iter().zip(&b) {
                    assert!(
                        (x - y).abs() <= 1e-5 * x.max(1e-3),
                        "{step} {i}: {x} vs {y}"
                    );
                }
            }
        }
    }
}
