//! The set-up of one batch step (the scalar `Sampler::prepare`) computed for all
//! [`BATCH`] lanes at once, structure-of-arrays, for every lookup option: jitter, the lookup
//! point and the first piece of a chained lookup (`Sampler::next_piece` sets up the later
//! pieces one ray at a time).
//!
//! Why: at 32 rays per step the memory fetches overlap, and what is left of a batched query
//! is the arithmetic of the set-up (transform, slab test, segment, direction cell, the
//! generator's seeding and first draw). Written per ray it branches at every early exit and
//! the compiler cannot use vector registers. Here every lane runs the same straight-line
//! code and the early exits become selects, so each loop compiles to SIMD instructions
//! (16 f32 lanes with AVX-512, 8 with AVX2, 4 with the SSE2 baseline; the widest the CPU
//! has is chosen at run time by [`Isa::best`], and every loop is compiled once per
//! instruction set).
//!
//! The result is bit for bit the scalar `prepare`: the same f32 operations in the same order
//! (vector `+ - * / sqrt` round exactly like scalar ones, and Rust never fuses a multiply
//! and an add), and the same selects. The only difference is that values a scalar early exit
//! never computes are computed and then thrown away. The tests below check the equality on
//! random and hostile rays for every instruction set the CPU has.
//!
//! The same holds for the start of the resolve ([`resolve_heads`]): the two partial-interval
//! draws, the participating set, its popcount and `t_min^n`, as `resolve::resolve` computes
//! them.

use pin_format::{Directions, PinEntry};

use crate::chord::{Segment, UnitTransform};
use crate::lookup::{DirJitter, GridView, direction_cell, line_frame, line_score};
use crate::mask::{is_finite_bits, pow_int, sanitize_t_min};
use crate::rng::{PCG_INC, PCG_MUL, Rng, pcg_hash, pcg_output, unit_f32};

use super::options::SamplerOptions;
use super::prepared::{NO_CELL, Prepared, piece_of};
use super::query::{RayQuery, status};
use super::resolve::{Head, participating};

/// Rays per batch step: enough misses in flight to cover DRAM latency, few enough to stay in L1.
pub const BATCH: usize = 32;

/// Fills `out[..rays.len()]` with what `Sampler::prepare` returns for `rays[i]` and
/// generator `rng[i]`, for a sampler with options `opts`. `rays.len() <= BATCH`.
/// With `indexed = Some((pcg_hash(seed), first))` the generators are first set to
/// `Rng::for_query(seed, first + i)` (the batch API's seeding, done here so that it runs in
/// vector registers too).
#[inline]
pub(crate) fn prepare_lanes(
    view: &GridView<'_>,
    xf: &UnitTransform,
    opts: &SamplerOptions,
    rays: &[RayQuery],
    rng: &mut [Rng; BATCH],
    indexed: Option<(u32, u32)>,
    out: &mut [Prepared; BATCH],
) {
    prepare_lanes_isa(Isa::best(), view, xf, opts, rays, rng, indexed, out);
}

/// The instruction sets the lane loops are compiled for; the best one present is chosen at
/// run time (the tests run every one the CPU has).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Isa {
    /// The target's baseline (SSE2 on x86-64): 4 f32 lanes.
    Baseline,
    /// 8 f32 lanes, per-lane variable shifts for the generator's output permutation.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// 16 f32 lanes, mask registers for the selects, a direct f32 -> u32 conversion
    /// (AVX2 emulates it): 3-4 ns less per batched query than AVX2 on an AMD EPYC.
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Isa {
    /// Every variant this CPU can run, baseline first.
    #[cfg(test)]
    pub(crate) fn available() -> Vec<Isa> {
        let mut v = vec![Isa::Baseline];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                v.push(Isa::Avx2);
            }
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512vl")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512dq")
            {
                v.push(Isa::Avx512);
            }
        }
        v
    }

    /// The widest variant this CPU can run (std caches the CPU's features: a few loads).
    #[inline]
    pub(crate) fn best() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512vl")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512dq")
            {
                return Isa::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return Isa::Avx2;
            }
        }
        Isa::Baseline
    }
}

/// [`prepare_lanes`] compiled for `isa`, which must be one of [`Isa::available`].
#[allow(clippy::too_many_arguments)]
#[inline]
pub(crate) fn prepare_lanes_isa(
    isa: Isa,
    view: &GridView<'_>,
    xf: &UnitTransform,
    opts: &SamplerOptions,
    rays: &[RayQuery],
    rng: &mut [Rng; BATCH],
    indexed: Option<(u32, u32)>,
    out: &mut [Prepared; BATCH],
) {
    match isa {
        Isa::Baseline => lanes_body(view, xf, opts, rays, rng, indexed, out),
        // SAFETY: `isa` comes from `Isa::best` or `Isa::available`, which checked that the
        // CPU has these features.
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { prepare_avx2(view, xf, opts, rays, rng, indexed, out) },
        // SAFETY: as above.
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { prepare_avx512(view, xf, opts, rays, rng, indexed, out) },
    }
}

/// [`lanes_body`] compiled for AVX-512 ([`Isa::Avx512`]). Rust never contracts `a * b + c`
/// into a fused multiply-add, so the FMA this target implies changes no rounding.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq")]
fn prepare_avx512(
    view: &GridView<'_>,
    xf: &UnitTransform,
    opts: &SamplerOptions,
    rays: &[RayQuery],
    rng: &mut [Rng; BATCH],
    indexed: Option<(u32, u32)>,
    out: &mut [Prepared; BATCH],
) {
    lanes_body(view, xf, opts, rays, rng, indexed, out);
}

/// [`lanes_body`] compiled for AVX2 (8 f32 lanes, per-lane variable shifts for the
/// generator's output permutation). AVX2 only, not FMA: no multiply-add may be fused.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn prepare_avx2(
    view: &GridView<'_>,
    xf: &UnitTransform,
    opts: &SamplerOptions,
    rays: &[RayQuery],
    rng: &mut [Rng; BATCH],
    indexed: Option<(u32, u32)>,
    out: &mut [Prepared; BATCH],
) {
    lanes_body(view, xf, opts, rays, rng, indexed, out);
}

/// `(n - 1) as f32` for [`bin_lane`]: exact, since `n <= MAX_DIM = 2^20` for a grid's cells
/// (validated by the format crate) and `n = 32` for intervals.
#[inline(always)]
fn bin_limit(n: u32) -> f32 {
    debug_assert!((1..=1 << 24).contains(&n));
    (n - 1) as f32
}

/// [`bin`] for `n <= 2^24`, `hi = (n - 1) as f32`: the same cell for every `x` (NaN and
/// negatives to 0, beyond `n - 1` to `n - 1`), clamped in f32 first so that the conversion
/// is a plain truncation. Rust's saturating `x as u32` costs a compare-and-blend sequence
/// per lane, and was a quarter of the set-up's time.
#[inline(always)]
fn bin_lane(x: f32, hi: f32) -> u32 {
    let y = if x > 0.0 { x } else { 0.0 };
    let y = if y < hi { y } else { hi };
    // SAFETY: `y` is in `[0, hi]` with `hi < 2^24`: not NaN, and its truncation fits an i32.
    unsafe { y.to_int_unchecked::<i32>() as u32 }
}

/// The set-up as a sequence of stages, each one loop over all [`BATCH`] lanes of plain
/// arrays, so that each loop is short and branch-free enough for the compiler to widen to
/// full vector registers (one long loop was partly left as scalar code). Lanes past
/// `rays.len()` get a zero direction: invalid, never read back.
#[inline(always)]
fn lanes_body(
    view: &GridView<'_>,
    xf: &UnitTransform,
    opts: &SamplerOptions,
    rays: &[RayQuery],
    rng: &mut [Rng; BATCH],
    indexed: Option<(u32, u32)>,
    out: &mut [Prepared; BATCH],
) {
    let n = rays.len().min(BATCH);
    let stride = opts.stride();
    // With one lookup per query the piece is the whole segment: no piece arithmetic.
    let chained = stride < 32;
    let spatial = opts.spatial_on();
    let directional = opts.directional_on();
    let midpoint = opts.midpoint_lookup;
    let start_inside = opts.start_inside;
    let shape = &view.shape;
    let ppe = shape.pins_per_entry;

    // The rays, structure-of-arrays.
    let mut raw = [[0f32; BATCH]; 6];
    let mut t_max = [0f32; BATCH];
    for (i, q) in rays[..n].iter().enumerate() {
        raw[0][i] = q.origin[0];
        raw[1][i] = q.origin[1];
        raw[2][i] = q.origin[2];
        raw[3][i] = q.dir[0];
        raw[4][i] = q.dir[1];
        raw[5][i] = q.dir[2];
        t_max[i] = q.t_max;
    }
    if let Some((seed_hash, first)) = indexed {
        for (i, r) in rng.iter_mut().enumerate() {
            r.state = pcg_hash(seed_hash ^ first.wrapping_add(i as u32));
        }
    }

    // World to unit cube (`UnitTransform::point`, `vector`) and validity.
    let mut o = [[0f32; BATCH]; 3];
    let mut d = [[0f32; BATCH]; 3];
    let mut valid = [false; BATCH];
    for i in 0..BATCH {
        let po = xf.point([raw[0][i], raw[1][i], raw[2][i]]);
        let pd = xf.vector([raw[3][i], raw[4][i], raw[5][i]]);
        let finite = is_finite_bits(po[0])
            & is_finite_bits(po[1])
            & is_finite_bits(po[2])
            & is_finite_bits(pd[0])
            & is_finite_bits(pd[1])
            & is_finite_bits(pd[2]);
        let nan_tmax = (t_max[i].to_bits() & 0x7fff_ffff) > 0x7f80_0000;
        let zero = (pd[0] == 0.0) & (pd[1] == 0.0) & (pd[2] == 0.0);
        valid[i] = finite & !nan_tmax & !zero;
        for ax in 0..3 {
            o[ax][i] = po[ax];
            d[ax][i] = pd[ax];
        }
    }

    // `chord::unit_cube_chord` with its early exits as flags.
    let mut lo = [0f32; BATCH];
    let mut hi = [0f32; BATCH];
    let mut chord = [false; BATCH];
    for i in 0..BATCH {
        let mut l = -f32::MAX;
        let mut h = f32::MAX;
        let mut constrained = false;
        let mut outside = false;
        for ax in 0..3 {
            let (oa, da) = (o[ax][i], d[ax][i]);
            // `1 / +-0` is an infinity, as the scalar code's explicit case: parallel.
            let inv = 1.0 / da;
            let parallel = !is_finite_bits(inv);
            // `&` rather than `contains`' `&&`: no branch in the vector loop.
            #[allow(clippy::manual_range_contains)]
            let inside = (oa >= 0.0) & (oa <= 1.0);
            outside |= parallel & !inside;
            let t0 = -oa * inv;
            let t1 = (1.0 - oa) * inv;
            let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
            l = if !parallel & (near > l) { near } else { l };
            h = if !parallel & (far < h) { far } else { h };
            constrained |= !parallel;
        }
        lo[i] = l;
        hi[i] = h;
        chord[i] = !outside & constrained & (l < h) & is_finite_bits(l) & is_finite_bits(h);
    }

    // `chord::segment`.
    let mut ilen = [0f32; BATCH];
    let mut t0s = [0f32; BATCH];
    let mut t1s = [0f32; BATCH];
    let mut s0s = [0f32; BATCH];
    let mut s1s = [0f32; BATCH];
    let mut a_s = [0u32; BATCH];
    let mut b_s = [0u32; BATCH];
    let mut ok = [false; BATCH];
    for i in 0..BATCH {
        let (l, h) = (lo[i], hi[i]);
        let t0 = if l > 0.0 { l } else { 0.0 };
        let t1 = if t_max[i] < h { t_max[i] } else { h };
        let c = h - l;
        let k = 32.0 / c;
        let seg_ok = (t0 < t1) & is_finite_bits(c) & is_finite_bits(k);
        let s0 = if t0 == l {
            0.0
        } else {
            let s = (t0 - l) * k;
            if s < 32.0 { s } else { 32.0 }
        };
        let s1 = if t1 == h {
            32.0
        } else {
            let s = (t1 - l) * k;
            if s < 32.0 { s } else { 32.0 }
        };
        let a = bin_lane(s0, 31.0);
        let fl = bin_lane(s1, 31.0);
        let b = if (fl as f32 == s1) & (fl > 0) {
            fl.wrapping_sub(1)
        } else {
            fl
        };
        let b = if b < a { a } else { b };
        ok[i] = valid[i] & chord[i] & seg_ok;
        ilen[i] = c * 0.03125;
        t0s[i] = t0;
        t1s[i] = t1;
        s0s[i] = s0;
        s1s[i] = s1;
        a_s[i] = a;
        b_s[i] = b;
    }
    let full = |i: usize| Segment {
        t_enter: lo[i],
        interval_len: ilen[i],
        t0: t0s[i],
        t1: t1s[i],
        s0: s0s[i],
        s1: s1s[i],
        a: a_s[i],
        b: b_s[i],
    };

    // The draws: the pin number (`Rng::below_256`), then the spatial jitter's three and
    // the directional jitter's two uniforms when they are on; only a resolved query draws.
    let mut s = [0u32; BATCH];
    let mut kdraw = [0u32; BATCH];
    let step = |x: u32| x.wrapping_mul(PCG_MUL).wrapping_add(PCG_INC);
    for i in 0..BATCH {
        let x = step(rng[i].state);
        kdraw[i] = ((pcg_output(x) >> 8) * ppe) >> 24;
        s[i] = x;
    }
    let mut sxi = [[0f32; BATCH]; 3];
    if spatial {
        for i in 0..BATCH {
            for xi in &mut sxi {
                s[i] = step(s[i]);
                xi[i] = unit_f32(pcg_output(s[i]));
            }
        }
    }
    let mut dxi = [[0f32; BATCH]; 2];
    if directional {
        for i in 0..BATCH {
            for xi in &mut dxi {
                s[i] = step(s[i]);
                xi[i] = unit_f32(pcg_output(s[i]));
            }
        }
    }

    // The first piece of a chain (`a / stride`, then `piece_of`); rare, so per lane.
    let mut pieces = [0u32; BATCH];
    let mut psegs = [Segment::EMPTY; BATCH];
    let mut pt = [[0f32; BATCH]; 2];
    if chained {
        for i in 0..BATCH {
            pieces[i] = a_s[i] / stride;
            psegs[i] = piece_of(&full(i), pieces[i], stride);
            pt[0][i] = psegs[i].t0;
            pt[1][i] = psegs[i].t1;
        }
    }
    let (lt0, lt1) = if chained {
        (&pt[0], &pt[1])
    } else {
        (&t0s, &t1s)
    };

    // `Sampler::lookup`'s point, then `lookup::spatial_cell`.
    let dims_hi = shape.dims.map(bin_limit);
    let mut cells = [[0u32; BATCH]; 3];
    // The lookup points in cell units before the jitter, for the nearest-line lookup.
    let mut points = [[0f32; BATCH]; 3];
    // `start_inside`: a piece that starts inside the box, at its start without spatial jitter.
    let ls0 = if chained {
        std::array::from_fn::<f32, BATCH, _>(|i| psegs[i].s0)
    } else {
        s0s
    };
    for i in 0..BATCH {
        let inside = start_inside && ls0[i] > 0.0;
        let t = if midpoint && !inside {
            0.5 * (lt0[i] + lt1[i])
        } else {
            lt0[i]
        };
        let mut cf = [0f32; 3];
        for ax in 0..3 {
            cf[ax] = (o[ax][i] + d[ax][i] * t) * view.dims_f[ax];
            points[ax][i] = cf[ax];
        }
        // The nearest-line lookup replaces the spatial jitter (its draws are made above):
        // the cells are then its home cells.
        if spatial && !inside && opts.nearest_line == 0 {
            for ax in 0..3 {
                cf[ax] += (sxi[ax][i] - 0.5) * opts.spatial_jitter;
            }
        }
        for ax in 0..3 {
            cells[ax][i] = bin_lane(cf[ax], dims_hi[ax]);
        }
    }

    // The direction, turned into the upper hemisphere.
    let mut dl = [[0f32; BATCH]; 3];
    let mut rev = [false; BATCH];
    for i in 0..BATCH {
        let reversed = d[2][i] < 0.0;
        for ax in 0..3 {
            dl[ax][i] = if reversed { -d[ax][i] } else { d[ax][i] };
        }
        rev[i] = reversed;
    }

    // Direction cells: one loop per layout so that each is straight-line code.
    let mut dcell = [0u32; BATCH];
    match shape.directions {
        Directions::Polar { n_phi, n_theta } => {
            let dirs = Directions::Polar { n_phi, n_theta };
            direction_cells(&dirs, &dl, directional.then_some((opts, &dxi)), &mut dcell);
        }
        Directions::Octahedral { n } => {
            octahedral_cells(n, &dl, directional.then_some((opts, &dxi)), &mut dcell);
        }
    }

    // The nearest-line lookup replaces the cells.
    if opts.nearest_line > 0 {
        nearest_line_cells(view, &points, &dcell, opts.nearest_line, &mut cells);
    }

    for i in 0..n {
        out[i] = if ok[i] {
            // `GridShape::local_cell`, in 64 bits here only: 64-bit lanes in the loops
            // above would halve their vector width.
            let (cx, cy, cz) = (cells[0][i], cells[1][i], cells[2][i]);
            let local = if cz >= shape.z_begin && cz < shape.z_end {
                u64::from(cx)
                    + u64::from(shape.dims[0])
                        * (u64::from(cy) + u64::from(shape.dims[1]) * u64::from(cz - shape.z_begin))
            } else {
                NO_CELL
            };
            Prepared {
                status: status::OK,
                rng: Rng::new(s[i]),
                seg: if chained { psegs[i] } else { full(i) },
                full: full(i),
                reversed: rev[i],
                local,
                within: u64::from(dcell[i]) * u64::from(ppe) + u64::from(kdraw[i]),
                o: [o[0][i], o[1][i], o[2][i]],
                d: [d[0][i], d[1][i], d[2][i]],
                piece: pieces[i],
            }
        } else {
            let code = if valid[i] {
                status::MISS
            } else {
                status::INVALID
            };
            Prepared::empty(code, rng[i])
        };
    }
}

/// `lookup::nearest_line_cell` for every lane, written as straight loops over local lane
/// arrays so that they vectorise; the same operations and the same order of candidates as
/// the scalar search, so the same cells (`lanes_equal_scalar_prepare`). `cells` holds the
/// home cells (the points binned without jitter) on entry and the chosen ones on return.
#[inline(always)]
fn nearest_line_cells(
    view: &GridView<'_>,
    points: &[[f32; BATCH]; 3],
    dcell: &[u32; BATCH],
    steps: u32,
    cells: &mut [[u32; BATCH]; 3],
) {
    let dims_hi = view.shape.dims.map(bin_limit);
    let Directions::Octahedral { n } = view.shape.directions else {
        return;
    };
    let [px, py, pz] = *points;
    let mut wx = [0f32; BATCH];
    let mut wy = [0f32; BATCH];
    let mut wz = [0f32; BATCH];
    let mut ww = [0f32; BATCH];
    let mut h = [0f32; BATCH];
    for i in 0..BATCH {
        let (w, w2, step) = line_frame(n, dcell[i], view.dims_f);
        [wx[i], wy[i], wz[i]] = w;
        ww[i] = w2;
        h[i] = step;
    }
    let [mut bx, mut by, mut bz] = *cells;
    let mut best = [0f32; BATCH];
    for i in 0..BATCH {
        let w = [wx[i], wy[i], wz[i]];
        best[i] = line_score([bx[i], by[i], bz[i]], [px[i], py[i], pz[i]], w, ww[i]);
    }
    for step in 1..=steps.min(crate::lookup::MAX_NEAREST_LINE_STEPS) {
        let sf = step as f32;
        for negative in [false, true] {
            for i in 0..BATCH {
                let along = sf * h[i];
                let lam = if negative { -along } else { along };
                let qx = px[i] + lam * wx[i];
                let qy = py[i] + lam * wy[i];
                let qz = pz[i] + lam * wz[i];
                // `chord::bin` through `bin_lane`, as the scalar search clamps.
                let kx = bin_lane(qx, dims_hi[0]);
                let ky = bin_lane(qy, dims_hi[1]);
                let kz = bin_lane(qz, dims_hi[2]);
                let w = [wx[i], wy[i], wz[i]];
                let sc = line_score([kx, ky, kz], [px[i], py[i], pz[i]], w, ww[i]);
                let take = sc < best[i];
                best[i] = if take { sc } else { best[i] };
                bx[i] = if take { kx } else { bx[i] };
                by[i] = if take { ky } else { by[i] };
                bz[i] = if take { kz } else { bz[i] };
            }
        }
    }
    *cells = [bx, by, bz];
}

/// `lookup::direction_cell` for an octahedral layout in every lane, operation for
/// operation, with `bin_lane` for `chord::bin`: the saturating `as u32` of the scalar
/// binning kept this loop scalar.
#[inline(always)]
fn octahedral_cells(
    n: u32,
    dl: &[[f32; BATCH]; 3],
    jitter: Option<(&SamplerOptions, &[[f32; BATCH]; 2])>,
    out: &mut [u32; BATCH],
) {
    let nf = n as f32;
    let hi = bin_limit(n);
    let mut cu = [0f32; BATCH];
    let mut cv = [0f32; BATCH];
    for i in 0..BATCH {
        let (u, v) = pin_format::octahedral_uv([dl[0][i], dl[1][i], dl[2][i]]);
        cu[i] = u * nf;
        cv[i] = v * nf;
    }
    if let Some((opts, xi)) = jitter {
        let strength = opts.directional_jitter;
        for i in 0..BATCH {
            cu[i] += (xi[0][i] - 0.5) * strength;
            cv[i] += (xi[1][i] - 0.5) * strength;
        }
    }
    for i in 0..BATCH {
        out[i] = bin_lane(cv[i], hi) * n + bin_lane(cu[i], hi);
    }
}

/// The direction cells of all lanes for one layout (`dirs` a constant of the caller's
/// match arm, so each layout's loop is straight-line code), with the directional jitter's
/// uniforms `xi` when it is on.
#[inline(always)]
fn direction_cells(
    dirs: &Directions,
    dl: &[[f32; BATCH]; 3],
    jitter: Option<(&SamplerOptions, &[[f32; BATCH]; 2])>,
    out: &mut [u32; BATCH],
) {
    match jitter {
        None => {
            for i in 0..BATCH {
                out[i] = direction_cell(dirs, [dl[0][i], dl[1][i], dl[2][i]], None);
            }
        }
        Some((opts, xi)) => {
            for i in 0..BATCH {
                let j = DirJitter {
                    strength: opts.directional_jitter,
                    xi: [xi[0][i], xi[1][i]],
                };
                out[i] = direction_cell(dirs, [dl[0][i], dl[1][i], dl[2][i]], Some(j));
            }
        }
    }
}

/// The start of `resolve::resolve` for all lanes: the two partial-interval draws, the
/// sanitised `t_min`, the (reversed) mask, the participating set, its popcount and
/// `t_min^popcount`. `entries[i]` is lane `i`'s entry (`PinEntry::EMPTY` when none was
/// read). Lanes whose query did not resolve compute values nobody reads.
#[inline]
pub(crate) fn resolve_heads(
    prep: &[Prepared; BATCH],
    entries: &[PinEntry; BATCH],
    out: &mut [Head; BATCH],
) {
    resolve_heads_isa(Isa::best(), prep, entries, out);
}

/// [`resolve_heads`] compiled for `isa`, which must be one of [`Isa::available`].
#[inline]
pub(crate) fn resolve_heads_isa(
    isa: Isa,
    prep: &[Prepared; BATCH],
    entries: &[PinEntry; BATCH],
    out: &mut [Head; BATCH],
) {
    match isa {
        Isa::Baseline => heads_body(prep, entries, out),
        // SAFETY: `isa` comes from `Isa::best` or `Isa::available`, which checked that the
        // CPU has these features.
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { heads_avx2(prep, entries, out) },
        // SAFETY: as above.
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { heads_avx512(prep, entries, out) },
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq")]
fn heads_avx512(prep: &[Prepared; BATCH], entries: &[PinEntry; BATCH], out: &mut [Head; BATCH]) {
    heads_body(prep, entries, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn heads_avx2(prep: &[Prepared; BATCH], entries: &[PinEntry; BATCH], out: &mut [Head; BATCH]) {
    heads_body(prep, entries, out);
}

#[inline(always)]
fn heads_body(prep: &[Prepared; BATCH], entries: &[PinEntry; BATCH], out: &mut [Head; BATCH]) {
    for i in 0..BATCH {
        let p = &prep[i];
        let e = entries[i];
        let mut rng = p.rng;
        let xa = rng.next_f32();
        let xb = rng.next_f32();
        let t_min = sanitize_t_min(e.t_min);
        let mask = if p.reversed {
            e.mask.reverse_bits()
        } else {
            e.mask
        };
        let set = mask & participating(&p.seg, xa, xb);
        let popcount = set.count_ones();
        out[i] = Head {
            state: rng.state,
            t_min,
            set,
            popcount,
            transmittance: pow_int(t_min, popcount),
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chord::bin;
    use crate::rng::Rng;
    use crate::testing::random_grid;
    use crate::{PinGrid, QueryResult, Sampler, SamplerOptions};
    use pin_format::{GridShape, OwnedPinGrid};
    use proptest::prelude::{ProptestConfig, any, prop_assert_eq, proptest};

    /// Components that break the scalar set-up's early exits one at a time: zeros of both
    /// signs, subnormals, the largest finite values, infinities and NaN, besides ordinary ones.
    fn hostile(r: &mut Rng) -> f32 {
        match r.next_u32() % 16 {
            0 => 0.0,
            1 => -0.0,
            2 => f32::NAN,
            3 => f32::INFINITY,
            4 => f32::NEG_INFINITY,
            5 => 1e-40,
            6 => -1e-40,
            7 => f32::MAX,
            8 => 1.0,
            9 => 0.5,
            _ => r.next_f32() * 3.0 - 1.0,
        }
    }

    fn rays(n: usize, seed: u32) -> Vec<RayQuery> {
        let mut r = Rng::new(seed);
        (0..n)
            .map(|i| {
                let ordinary = i % 3 != 0;
                let mut c = || {
                    if ordinary {
                        r.next_f32() * 3.0 - 1.0
                    } else {
                        hostile(&mut r)
                    }
                };
                let o = [c(), c(), c()];
                let d = [c() - 0.5, c() - 0.5, c() - 0.5];
                let t_max = match i % 5 {
                    0 => f32::INFINITY,
                    1 => f32::NAN,
                    2 => 0.0,
                    _ => r.next_f32() * 2.0,
                };
                RayQuery::new(o, d, t_max)
            })
            .collect()
    }

    fn grids() -> Vec<OwnedPinGrid> {
        let mut tile = random_grid(Directions::THESIS_DEFAULT, [4, 5, 6], 2, false, 3);
        // A tile covering z cells 2..5 only: the others are outside (`NO_CELL`).
        tile.tile = Some(pin_format::TileDesc {
            tile_index: 1,
            tile_count: 3,
            z_begin: 2,
            z_end: 5,
        });
        tile.desc.stored_cells = 4 * 5 * 3;
        tile.pins.truncate(4 * 5 * 3 * 64 * 2);
        vec![
            random_grid(Directions::THESIS_DEFAULT, [5, 4, 3], 3, true, 17),
            random_grid(Directions::Octahedral { n: 5 }, [7, 1, 2], 1, false, 18),
            random_grid(
                Directions::Polar {
                    n_phi: 7,
                    n_theta: 3,
                },
                [1, 1, 1],
                256,
                false,
                19,
            ),
            tile,
        ]
    }

    /// Lookup options the lanes serve: none, the render defaults (jitter 1/1, midpoint, start
    /// inside the box), chains with and without jitter, each jitter alone.
    fn option_sets() -> Vec<SamplerOptions> {
        let o =
            |spatial_jitter, directional_jitter, chain_stride, midpoint_lookup| SamplerOptions {
                spatial_jitter,
                directional_jitter,
                chain_stride,
                midpoint_lookup,
                start_inside: false,
                nearest_line: 0,
            };
        let inside = |o: SamplerOptions| SamplerOptions {
            start_inside: true,
            ..o
        };
        vec![
            SamplerOptions::THESIS,
            o(1.0, 1.0, 32, true),
            // `pinrender render`'s defaults, and `start_inside` chained and at the start.
            inside(o(1.0, 1.0, 32, true)),
            inside(o(0.7, 0.4, 5, true)),
            inside(o(1.0, 0.0, 32, false)),
            o(0.0, 0.0, 32, true),
            o(0.0, 0.0, 5, true),
            o(0.7, 0.4, 8, false),
            o(1.0, 0.0, 1, true),
            o(0.0, 2.5, 32, false),
            // The nearest-line lookup: the render's, chained, and at the start.
            SamplerOptions::RENDER,
            SamplerOptions {
                nearest_line: 3,
                ..inside(o(0.7, 0.4, 5, true))
            },
            SamplerOptions {
                nearest_line: 64,
                ..o(0.0, 1.0, 32, false)
            },
        ]
    }

    /// The lane set-up equals the scalar `prepare`, field for field, on ordinary and
    /// hostile rays, for both seedings, every direction layout, every option set and every
    /// instruction set the CPU has; so does the lane start of the resolve.
    #[test]
    fn lanes_equal_scalar_prepare() {
        let isas = Isa::available();
        assert!(isas.contains(&Isa::best()));
        for (owned, opts, isa) in grids().into_iter().flat_map(|g| {
            option_sets().into_iter().flat_map(move |o| {
                let g = g.clone();
                Isa::available().into_iter().map(move |i| (g.clone(), o, i))
            })
        }) {
            let bytes = owned.to_bytes().unwrap();
            let g = PinGrid::from_bytes(bytes).unwrap();
            let s = g.sampler().unwrap().with_options(opts);
            let shape: GridShape = *g.shape();
            let all = rays(4000, 77);
            let mut resolved = 0;
            for (c, chunk) in all.chunks(BATCH - 3).enumerate() {
                let mut rng = [Rng::new(0); BATCH];
                let mut out = [Prepared::empty(status::MISS, Rng::new(0)); BATCH];
                let first = (c * 1000) as u32;
                prepare_lanes_isa(
                    isa,
                    s.view(),
                    s.transform(),
                    s.options(),
                    chunk,
                    &mut rng,
                    Some((crate::rng::pcg_hash(9), first)),
                    &mut out,
                );
                for (i, q) in chunk.iter().enumerate() {
                    let want = s.prepare(
                        q.origin,
                        q.dir,
                        q.t_max,
                        Rng::for_query(9, first + i as u32),
                    );
                    assert_eq!(out[i], want, "{isa:?} {shape:?} {opts:?} ray {q:?}");
                    resolved += usize::from(want.status == status::OK);
                }
                // The resolve's start against random entries, with and without the
                // reversal and with `t_min` outside [0, 1].
                let mut er = Rng::new(c as u32);
                let entries: [PinEntry; BATCH] = std::array::from_fn(|_| PinEntry {
                    mask: er.next_u32(),
                    t_min: er.next_f32() * 1.2 - 0.1,
                });
                let mut heads = [Head::default(); BATCH];
                resolve_heads_isa(isa, &out, &entries, &mut heads);
                for i in 0..chunk.len() {
                    if out[i].status != status::OK {
                        continue;
                    }
                    let mut r = out[i].rng;
                    let want = crate::sampler::resolve_entry(
                        entries[i],
                        out[i].reversed,
                        &out[i].seg,
                        &mut r,
                        false,
                    );
                    let h = heads[i];
                    assert_eq!(
                        (h.state, h.popcount, h.transmittance.to_bits()),
                        (r.state, want.popcount, want.transmittance.to_bits()),
                        "{isa:?} heads"
                    );
                }
                // Given generators.
                let mut given = [Rng::new(0); BATCH];
                for (i, r) in given.iter_mut().enumerate() {
                    *r = Rng::new(i as u32 * 7919 + c as u32);
                }
                let start = given;
                prepare_lanes_isa(
                    isa,
                    s.view(),
                    s.transform(),
                    s.options(),
                    chunk,
                    &mut given,
                    None,
                    &mut out,
                );
                for (i, q) in chunk.iter().enumerate() {
                    assert_eq!(out[i], s.prepare(q.origin, q.dir, q.t_max, start[i]));
                }
            }
            assert!(resolved > 100, "{resolved} resolved queries");
        }
    }

    /// `bin_lane` gives `bin`'s cell for every kind of float and every size the lanes use.
    #[test]
    fn bin_lane_equals_bin() {
        let mut r = Rng::new(31);
        let sizes = [1u32, 2, 3, 7, 32, 37, 4096, 1 << 16, pin_format::MAX_DIM];
        let special = [
            0.0f32,
            -0.0,
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE,
            1e-45,
            -1e-45,
            0.999_999_94,
            1.0,
            30.999_998,
            31.0,
            31.000_002,
            32.0,
            4095.9998,
            1_048_575.0,
            1_048_575.9,
            1_048_576.0,
            16_777_216.0,
            4.3e9,
            f32::MAX,
            -1.0,
        ];
        for &n in &sizes {
            let hi = bin_limit(n);
            for &x in &special {
                assert_eq!(bin_lane(x, hi), bin(x, n), "x {x} n {n}");
            }
            for _ in 0..200_000 {
                // Random bit patterns (every exponent) and values near the cells.
                let x = f32::from_bits(r.next_u32());
                assert_eq!(bin_lane(x, hi), bin(x, n), "x {x:e} n {n}");
                let y = r.next_f32() * (n as f32 + 2.0) - 1.0;
                assert_eq!(bin_lane(y, hi), bin(y, n), "y {y} n {n}");
            }
        }
        // The test can fail: a limit one too small moves the last cell.
        assert_ne!(bin_lane(31.5, 30.0), bin(31.5, 32));
    }

    /// A deliberate slip in the lane code (a different rounding of the segment start) is
    /// caught by the comparison the test above makes: the test can fail.
    #[test]
    fn the_comparison_catches_a_one_ulp_difference() {
        let g = PinGrid::from_bytes(grids().remove(0).to_bytes().unwrap()).unwrap();
        let s = g.sampler().unwrap();
        let q = RayQuery::new([0.3, 0.4, 0.5], [0.2, -0.7, 0.1], 0.4);
        let mut rng = [Rng::new(5); BATCH];
        let mut out = [Prepared::empty(status::MISS, Rng::new(0)); BATCH];
        prepare_lanes(
            s.view(),
            s.transform(),
            s.options(),
            &[q],
            &mut rng,
            None,
            &mut out,
        );
        let mut want = s.prepare(q.origin, q.dir, q.t_max, Rng::new(5));
        assert_eq!(out[0], want);
        want.seg.s1 = f32::from_bits(want.seg.s1.to_bits() + 1);
        assert_ne!(out[0], want);
    }

    fn sampler_for(g: &PinGrid, options: usize) -> Sampler<'_> {
        g.sampler()
            .unwrap()
            .with_options(option_sets()[options % option_sets().len()])
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Batches with a generator per ray equal one single query per ray, results and
        /// generators afterwards, for random rays including NaN, infinite and zero
        /// directions and origins, for every option set (jitter, lookup point, chains).
        #[test]
        fn batch_with_generators_equals_single(
            seed in any::<u32>(),
            n in 1usize..200,
            options in 0usize..7,
            grid in 0usize..4,
        ) {
            let g = PinGrid::from_bytes(grids().swap_remove(grid).to_bytes().unwrap()).unwrap();
            let s = sampler_for(&g, options);
            let rays = rays(n, seed);
            let start: Vec<Rng> = (0..n as u32).map(|i| Rng::new(seed ^ i.wrapping_mul(0x9e37_79b9))).collect();
            let mut rq = start.clone();
            let mut full = vec![QueryResult::empty_for_tests(); n];
            s.query_batch_rngs(&rays, &mut rq, &mut full);
            let mut rt = start.clone();
            let mut ts = vec![0.0; n];
            s.transmittance_batch_rngs(&rays, &mut rt, &mut ts);
            let mut rd = start.clone();
            let mut ds = vec![None; n];
            s.sample_distance_batch_rngs(&rays, &mut rd, &mut ds);
            for (i, q) in rays.iter().enumerate() {
                let mut r1 = start[i];
                prop_assert_eq!(s.query(&q.ray(), q.t_max, &mut r1), full[i]);
                prop_assert_eq!(r1, rq[i]);
                let mut r2 = start[i];
                prop_assert_eq!(s.transmittance(&q.ray(), q.t_max, &mut r2).to_bits(), ts[i].to_bits());
                prop_assert_eq!(r2, rt[i]);
                let mut r3 = start[i];
                prop_assert_eq!(s.sample_distance(&q.ray(), q.t_max, &mut r3).map(f32::to_bits), ds[i].map(f32::to_bits));
                prop_assert_eq!(r3, rd[i]);
            }
            // And the seeded batch equals single queries seeded the same way.
            let mut seeded = vec![QueryResult::empty_for_tests(); n];
            s.query_batch(&rays, seed, 17, &mut seeded);
            for (i, q) in rays.iter().enumerate() {
                let mut r = Rng::for_query(seed, 17 + i as u32);
                prop_assert_eq!(s.query(&q.ray(), q.t_max, &mut r), seeded[i]);
            }
        }
    }
}
