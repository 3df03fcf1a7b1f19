//! Distance sampling and transmittance estimation: single queries and prefetching batches.
//!
//! A query runs in three steps, which the batch API interleaves over 32 rays at a time so that
//! all memory fetches of a batch are in flight together (docs/background.md section 4):
//!
//! 1. **prepare** (pure arithmetic): world -> unit cube, validity, chord, segment, then the
//!    draws for the pin number and jitter, the spatial and direction cells.
//! 2. **address**: the sparse cell index (if any), then the entry's index in the pin array.
//! 3. **finish**: the two partial-interval draws, the popcount, `t_min^n`, and for distance
//!    sampling the sample mask `H` and the position draw.
//!
//! ## Random draws per query (the contract the WGSL shader follows)
//!
//! Rays that are invalid, miss the box or have an empty segment draw nothing. Otherwise, in
//! this order:
//!
//! 1. one `u32` for the pin number `k = ((x >> 8) * pins_per_entry) >> 24`;
//! 2. if spatial jitter is on: three floats (x, y, z);
//! 3. if directional jitter is on: two floats;
//! 4. two floats `xi_a`, `xi_b` for the partial first and last interval (always both);
//! 5. distance only: the sample-mask words (0 to 32, see [`crate::mask`]);
//! 6. distance only, and only if a collision interval was found: one float for the position
//!    inside the covered part of that interval.
//!
//! [`Sampler::query`] computes both estimates from one lookup: its transmittance equals
//! [`Sampler::transmittance`] and its distance [`Sampler::sample_distance`] for the same
//! starting generator.
//!
//! ## Chained lookups (`SamplerOptions::chain_stride`, docs/sampling.md section 12)
//!
//! With a stride `S < 32` the segment is cut at the chord's interval boundaries `S, 2S, ...`
//! and each piece is one lookup as above (draws 1-6 in that order, piece after piece, at the
//! piece's start or, with `midpoint_lookup`, its middle; with `start_inside` a piece that
//! starts inside the box at its start without spatial jitter). Transmittance multiplies the pieces;
//! distance sampling stops at the first piece with a collision; `query` continues after a
//! collision with draws 1-4 only, for the transmittance. So `query`'s distance is
//! `sample_distance`'s, but its transmittance equals `transmittance`'s only with one piece.
//! The batch methods run one round of fetches per piece over all rays still walking.

use bytemuck::{Pod, Zeroable};
use pin_format::PinEntry;

use crate::chord::{Segment, UnitTransform, segment, unit_cube_chord};
use crate::error::Result;
use crate::loader::PinGrid;
use crate::lookup::{DirJitter, GridView, direction_cell, nearest_line_cell, spatial_cell};
use crate::mask::{
    exact_sample_mask, interval_bit, interval_range, is_finite_bits, pow_int, sanitize_t_min,
};
use crate::rng::Rng;

/// A world-space ray. `dir` need not be normalised: distances are in units of the ray
/// parameter (`point = origin + t * dir`), which is world distance when `|dir| = 1`.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Ray {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
}

impl Ray {
    pub fn new(origin: [f32; 3], dir: [f32; 3]) -> Self {
        Self { origin, dir }
    }
}

/// A ray with its segment end, laid out for GPU storage buffers (32 bytes) and batches.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Default, Pod, Zeroable)]
pub struct RayQuery {
    pub origin: [f32; 3],
    /// End of the segment in ray-parameter units; `+inf` for the whole chord.
    pub t_max: f32,
    pub dir: [f32; 3],
    pub pad: u32,
}

impl RayQuery {
    pub fn new(origin: [f32; 3], dir: [f32; 3], t_max: f32) -> Self {
        Self {
            origin,
            t_max,
            dir,
            pad: 0,
        }
    }

    pub fn ray(&self) -> Ray {
        Ray::new(self.origin, self.dir)
    }
}

/// The same type under the name the GPU module uses.
pub type GpuRay = RayQuery;

/// Query status codes in [`QueryResult::status`].
pub mod status {
    /// The segment was resolved against an entry (possibly an empty cell).
    pub const OK: u32 = 0;
    /// No chord through the box, or an empty segment: transmittance 1, no collision.
    pub const MISS: u32 = 1;
    /// Non-finite origin or direction, zero direction, or NaN `t_max`: transmittance 1,
    /// no collision.
    pub const INVALID: u32 = 2;
}

/// [`QueryResult::entry`] when no stored entry was read (miss, invalid or empty cell).
pub const NO_ENTRY: u32 = u32::MAX;
/// [`QueryResult::interval`] when there is no collision.
pub const NO_INTERVAL: u32 = 32;

/// Everything one query produces, including the debug integers the CPU/GPU agreement tests
/// compare (32 bytes, GPU storage layout).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct QueryResult {
    /// Sampled collision distance (ray parameter), `+inf` if none.
    pub distance: f32,
    pub transmittance: f32,
    /// 1 if a collision was sampled.
    pub hit: u32,
    /// Index of the entry in the pin array, or [`NO_ENTRY`].
    pub entry: u32,
    /// Participating set ratio bits (the transmittance exponent).
    pub popcount: u32,
    /// Collision interval (0 = nearest the chord start), or [`NO_INTERVAL`].
    pub interval: u32,
    /// One of [`status`].
    pub status: u32,
    /// The generator state after the query: equal iff both sides drew the same numbers.
    pub rng_state: u32,
}

/// The same type under the name the GPU module uses.
pub type GpuResult = QueryResult;

impl QueryResult {
    fn empty(status: u32, rng: Rng) -> Self {
        Self {
            distance: f32::INFINITY,
            transmittance: 1.0,
            hit: 0,
            entry: NO_ENTRY,
            popcount: 0,
            interval: NO_INTERVAL,
            status,
            rng_state: rng.state,
        }
    }

    /// The distance as an option.
    pub fn collision(&self) -> Option<f32> {
        (self.hit != 0).then_some(self.distance)
    }
}

/// Runtime lookup options (thesis fig. 4.4). Strengths are in cells; 0 (default) turns the
/// jitter off and draws no random numbers for it. The default is the thesis' model: one
/// lookup per query, at the segment start. [`SamplerOptions::RENDER`] is the measured-best
/// lookup, the one `pinrender render` uses: prefer it for rendering.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct SamplerOptions {
    /// The lookup point moves by `(xi - 0.5) * strength` cells per axis.
    pub spatial_jitter: f32,
    /// The direction's continuous cell coordinates move by `(xi - 0.5) * strength` cells.
    pub directional_jitter: f32,
    /// Chained lookups (`docs/sampling.md` section 12): the query segment is cut at every
    /// `chain_stride`-th interval boundary of its chord and each piece is looked up at its own
    /// point. 0 or 32 and above: one lookup (the thesis' model).
    pub chain_stride: u32,
    /// Look each piece up at its midpoint instead of its start (section 12).
    pub midpoint_lookup: bool,
    /// A piece that starts inside the box (`s0 > 0`: the ray leaves a point in the medium,
    /// such as a shadow ray from a collision) is looked up at its start and without spatial
    /// jitter, whatever `midpoint_lookup` says (section 14). The jitter's draws are still
    /// made, so the draw order does not change. With chaining every piece after the first
    /// starts inside the box.
    pub start_inside: bool,
    /// The nearest-line lookup (`docs/sampling.md` section 15): instead of the cell that
    /// holds the lookup point, read the cell whose pin line passes nearest it, searching this
    /// many one-cell steps each side along the direction cell's axis (at most
    /// [`crate::lookup::MAX_NEAREST_LINE_STEPS`]). The spatial jitter is then not applied (its
    /// draws are still made). 0: off. Octahedral direction sets only (polar ones read the
    /// cell that holds the point); meant for pins through their cells' centres, the default
    /// bake.
    pub nearest_line: u32,
}

impl SamplerOptions {
    /// The lookup `pinrender render` and `pinrender eval` use, chosen by measurement on
    /// volumes nobody tuned for (`docs/evaluation.md`): one cell of spatial and directional
    /// jitter (`docs/sampling.md` section 11), one lookup per query at the middle of the
    /// segment (section 12), and a ray that starts inside the box looked up at its start
    /// without spatial jitter (section 14). The lowest bias this library offers; `default()`
    /// stays the thesis' model (no jitter, one lookup at the segment start), whose answers
    /// existing callers rely on bit for bit.
    pub const RENDER: SamplerOptions = SamplerOptions {
        spatial_jitter: 1.0,
        directional_jitter: 1.0,
        chain_stride: 32,
        midpoint_lookup: true,
        start_inside: true,
        nearest_line: 8,
    };

    /// The shaders' lookup mode (`Params.jitter.w` in `shaders/pin.wgsl`, `docs/gpu.md`): bit 0
    /// `midpoint_lookup`, bit 1 `start_inside`, bits 2 and up `nearest_line` (clamped to
    /// [`crate::lookup::MAX_NEAREST_LINE_STEPS`]); a small integer, exact in f32.
    pub fn lookup_mode(&self) -> f32 {
        let steps = self.nearest_line.min(crate::lookup::MAX_NEAREST_LINE_STEPS);
        (u32::from(self.midpoint_lookup) | (u32::from(self.start_inside) << 1) | (steps << 2))
            as f32
    }

    /// Intervals per lookup, in `1..=32`.
    pub fn stride(&self) -> u32 {
        if self.chain_stride == 0 || self.chain_stride > 32 {
            32
        } else {
            self.chain_stride
        }
    }

    pub(crate) fn spatial_on(&self) -> bool {
        self.spatial_jitter > 0.0 && self.spatial_jitter.is_finite()
    }
    pub(crate) fn directional_on(&self) -> bool {
        self.directional_jitter > 0.0 && self.directional_jitter.is_finite()
    }
}

/// Rays per batch step: enough misses in flight to cover DRAM latency, few enough to stay in L1.
pub const BATCH: usize = 32;

pub(crate) const NO_CELL: u64 = u64::MAX;

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Prepared {
    pub(crate) status: u32,
    pub(crate) rng: Rng,
    /// The piece of the query segment this lookup resolves (the whole segment unless chained).
    pub(crate) seg: Segment,
    pub(crate) reversed: bool,
    /// Covered-slab cell index, or `NO_CELL` (outside this tile).
    pub(crate) local: u64,
    /// `direction * pins_per_entry + k`.
    pub(crate) within: u64,
    /// Unit-cube origin and direction, the whole segment and the piece's number: what the
    /// next lookup of a chain needs.
    pub(crate) o: [f32; 3],
    pub(crate) d: [f32; 3],
    pub(crate) full: Segment,
    pub(crate) piece: u32,
}

const NOT_PREPARED: Prepared = Prepared {
    status: status::MISS,
    rng: Rng { state: 0 },
    seg: EMPTY_SEGMENT,
    reversed: false,
    local: NO_CELL,
    within: 0,
    o: [0.0; 3],
    d: [0.0; 3],
    full: EMPTY_SEGMENT,
    piece: 0,
};

impl Prepared {
    /// A query that draws nothing and reads nothing (invalid or missing).
    pub(crate) fn empty(status: u32, rng: Rng) -> Self {
        Self {
            status,
            rng,
            ..NOT_PREPARED
        }
    }
}

/// Piece `j` of `full` when the chord is cut every `stride` intervals: the intervals
/// `[j stride, (j + 1) stride)` that the segment touches. Cuts fall on interval boundaries, so
/// only the segment's own ends stay partial; with `stride = 32` piece 0 is `full` itself.
#[inline(always)]
pub fn piece_of(full: &Segment, j: u32, stride: u32) -> Segment {
    let lo = j * stride;
    let hi = (lo + stride).min(32);
    let mut p = *full;
    if full.a < lo {
        p.a = lo;
        p.s0 = lo as f32;
        let t = full.t_enter + lo as f32 * full.interval_len;
        p.t0 = if t > full.t0 { t } else { full.t0 };
    }
    if full.b >= hi {
        p.b = hi - 1;
        p.s1 = hi as f32;
        let t = full.t_enter + hi as f32 * full.interval_len;
        p.t1 = if t < full.t1 { t } else { full.t1 };
    }
    p
}

const EMPTY_SEGMENT: Segment = Segment {
    t_enter: 0.0,
    interval_len: 0.0,
    t0: 0.0,
    t1: 0.0,
    s0: 0.0,
    s1: 0.0,
    a: 0,
    b: 0,
};

#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Transmittance,
    Distance,
    Both,
}

/// Where a batch's generators come from.
enum Seeds<'a> {
    /// `Rng::for_query(seed, first_index + i)` (the GPU's seeding).
    Indexed(u32, u32),
    /// One generator per ray, advanced in place.
    Given(&'a mut [Rng]),
}

/// Requests the line holding `p` into the L2 cache (`_MM_HINT_T1`), not the L1. A batch
/// has 32 entry misses in flight; into the L1 they queue on its few miss buffers and the
/// prefetch instructions themselves stall (docs/performance.md, "Prefetching into L2"),
/// while the L2 tracks more misses at once and the later load of the entry costs an L2 hit.
/// Measured on a 262 MB grid: 28-29 ns per batched transmittance query instead of 37-40.
#[inline(always)]
fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: prefetch is a hint; it never faults, whatever the address.
    #[allow(unused_unsafe)]
    unsafe {
        core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T1 }>(p as *const i8);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Samples distances and transmittance through one pin grid placed in the world.
///
/// Cheap to create and `Copy`-free but `Sync`: share one sampler between threads and give each
/// thread its own [`Rng`] (or use the batch methods, which seed per query).
#[derive(Clone, Debug)]
pub struct Sampler<'g> {
    view: GridView<'g>,
    xf: UnitTransform,
    opts: SamplerOptions,
}

impl<'g> Sampler<'g> {
    /// A sampler placing the grid by the file's `local_to_world`.
    pub fn new(grid: &'g PinGrid) -> Result<Self> {
        Ok(Self {
            view: GridView::new(grid),
            xf: UnitTransform::new(grid.desc(), None)?,
            opts: SamplerOptions::default(),
        })
    }

    /// A sampler placing the grid by `local_to_world` (row-major 3x4) instead of the file's.
    pub fn with_local_to_world(grid: &'g PinGrid, local_to_world: &[f64; 12]) -> Result<Self> {
        Ok(Self {
            view: GridView::new(grid),
            xf: UnitTransform::new(grid.desc(), Some(local_to_world))?,
            opts: SamplerOptions::default(),
        })
    }

    /// A sampler placing the grid by `xf`, a transform already made for it
    /// ([`Self::transform`] of another sampler over the same grid, or [`UnitTransform::new`]
    /// of its description). No validation and no matrix inversion, so that an owner of the
    /// grid (an `Arc<PinGrid>`) can make a sampler per query at the cost of a few copies.
    pub fn with_transform(grid: &'g PinGrid, xf: UnitTransform) -> Self {
        Self {
            view: GridView::new(grid),
            xf,
            opts: SamplerOptions::default(),
        }
    }

    /// Sets the lookup options.
    pub fn with_options(mut self, opts: SamplerOptions) -> Self {
        self.opts = opts;
        self
    }

    pub fn options(&self) -> &SamplerOptions {
        &self.opts
    }

    /// The world -> unit cube map this sampler uses.
    pub fn transform(&self) -> &UnitTransform {
        &self.xf
    }

    /// The world-space box of the grid as this sampler places it (axis-aligned around it for
    /// a rotated placement): outside it every query is a miss (transmittance 1, no
    /// collision, no random draws). See [`UnitTransform::world_bounds`].
    pub fn world_bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.xf.world_bounds()
    }

    pub fn view(&self) -> &GridView<'g> {
        &self.view
    }

    #[inline(always)]
    pub(crate) fn prepare(
        &self,
        origin: [f32; 3],
        dir: [f32; 3],
        t_max: f32,
        rng: Rng,
    ) -> Prepared {
        let bad = Prepared::empty(status::INVALID, rng);
        let o = self.xf.point(origin);
        let d = self.xf.vector(dir);
        let finite = o.iter().chain(d.iter()).all(|&x| is_finite_bits(x));
        let nan_tmax = (t_max.to_bits() & 0x7fff_ffff) > 0x7f80_0000;
        if !finite || nan_tmax || (d[0] == 0.0 && d[1] == 0.0 && d[2] == 0.0) {
            return bad;
        }
        let Some(seg) = unit_cube_chord(o, d).and_then(|c| segment(c, t_max)) else {
            return Prepared {
                status: status::MISS,
                ..bad
            };
        };
        let stride = self.opts.stride();
        self.lookup(o, d, seg, seg.a / stride, rng)
    }

    /// Draws 1-3 and the cells for piece `piece` of the segment `full` (unit-cube `o`, `d`).
    #[inline(always)]
    fn lookup(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        full: Segment,
        piece: u32,
        mut rng: Rng,
    ) -> Prepared {
        let v = &self.view;
        let seg = piece_of(&full, piece, self.opts.stride());
        let k = rng.below_256(v.shape.pins_per_entry);
        let sj = if self.opts.spatial_on() {
            let xi = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
            Some((self.opts.spatial_jitter, xi))
        } else {
            None
        };
        let dj = if self.opts.directional_on() {
            Some(DirJitter {
                strength: self.opts.directional_jitter,
                xi: [rng.next_f32(), rng.next_f32()],
            })
        } else {
            None
        };
        let reversed = d[2] < 0.0;
        let dl = if reversed { [-d[0], -d[1], -d[2]] } else { d };
        let inside = self.opts.start_inside && seg.s0 > 0.0;
        let t = if self.opts.midpoint_lookup && !inside {
            0.5 * (seg.t0 + seg.t1)
        } else {
            seg.t0
        };
        let p = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
        let dcell = direction_cell(&v.shape.directions, dl, dj);
        let cell = if self.opts.nearest_line > 0 {
            let c = [p[0] * v.dims_f[0], p[1] * v.dims_f[1], p[2] * v.dims_f[2]];
            nearest_line_cell(c, v, dcell, self.opts.nearest_line)
        } else {
            spatial_cell(p, v, if inside { None } else { sj })
        };
        Prepared {
            status: status::OK,
            rng,
            seg,
            reversed,
            local: v.local_cell(cell).unwrap_or(NO_CELL),
            within: u64::from(dcell) * u64::from(v.shape.pins_per_entry) + u64::from(k),
            o,
            d,
            full,
            piece,
        }
    }

    /// The next lookup of a chain after `p`, drawing from `rng` (the state after `p`'s
    /// resolve); `None` after the last piece or for a query that never resolved.
    #[inline(always)]
    fn next_piece(&self, p: &Prepared, rng: Rng) -> Option<Prepared> {
        if p.status != status::OK || p.seg.b >= p.full.b {
            return None;
        }
        Some(self.lookup(p.o, p.d, p.full, p.piece + 1, rng))
    }

    /// Entry index for a prepared query (reads the sparse index).
    #[inline(always)]
    fn address(&self, p: &Prepared) -> Option<u64> {
        if p.status != status::OK || p.local == NO_CELL {
            return None;
        }
        let block = self.view.block_of(p.local)?;
        Some(block * self.view.shape.block_len + p.within)
    }

    #[inline(always)]
    fn finish(&self, p: &Prepared, entry_index: Option<u64>, mode: Mode) -> QueryResult {
        if p.status != status::OK {
            return QueryResult::empty(p.status, p.rng);
        }
        let (entry, entry_id) = match entry_index.and_then(|i| self.view.pins.get(i as usize)) {
            Some(e) => (*e, entry_index.unwrap_or(0) as u32),
            None => (PinEntry::EMPTY, NO_ENTRY),
        };
        resolve(entry, entry_id, p.reversed, &p.seg, p.rng, mode)
    }

    /// [`Self::finish`] after [`crate::lanes::resolve_heads`] computed the start of the
    /// resolve: the same result, bit for bit (the distance part is `resolve`'s).
    #[inline(always)]
    fn finish_head(
        &self,
        p: &Prepared,
        entry_index: Option<u64>,
        h: &crate::lanes::Head,
        mode: Mode,
    ) -> QueryResult {
        if p.status != status::OK {
            return QueryResult::empty(p.status, p.rng);
        }
        let entry_id = match entry_index {
            Some(i) if (i as usize) < self.view.pins.len() => i as u32,
            _ => NO_ENTRY,
        };
        let mut r = QueryResult {
            distance: f32::INFINITY,
            transmittance: 1.0,
            hit: 0,
            entry: entry_id,
            popcount: h.popcount,
            interval: NO_INTERVAL,
            status: status::OK,
            rng_state: h.state,
        };
        if mode != Mode::Distance {
            r.transmittance = h.transmittance;
        }
        if mode != Mode::Transmittance {
            let mut rng = Rng::new(h.state);
            let m = h.set & exact_sample_mask(h.t_min, &mut rng);
            if m != 0 {
                let j = m.leading_zeros();
                r.interval = j;
                r.hit = 1;
                r.distance = position_in_interval(&p.seg, j, rng.next_f32());
            }
            r.rng_state = rng.state;
        }
        r
    }

    /// Resolves the prepared lookup `p` (entry index `entry_index`) and folds it into the
    /// chain's result so far (`acc`, `None` for the first piece); returns the new result and
    /// the chain's next lookup, if any. A chain of pieces multiplies their transmittances;
    /// distance sampling walks the pieces in order and stops at the first collision, while
    /// `Mode::Both` keeps estimating the transmittance of the remaining pieces. With `head`
    /// (the lane-computed start of `p`'s resolve) the piece is finished by
    /// [`Self::finish_head`], which gives the same result as [`Self::finish`].
    #[inline(always)]
    fn step(
        &self,
        p: &Prepared,
        entry_index: Option<u64>,
        mode: Mode,
        acc: Option<QueryResult>,
        head: Option<&crate::lanes::Head>,
    ) -> (QueryResult, Option<Prepared>) {
        let finish = |m| match head {
            Some(h) => self.finish_head(p, entry_index, h, m),
            None => self.finish(p, entry_index, m),
        };
        let r = match acc {
            None => finish(mode),
            Some(acc) => {
                let m = if mode == Mode::Both && acc.hit != 0 {
                    Mode::Transmittance
                } else {
                    mode
                };
                let r = finish(m);
                let mut out = acc;
                out.transmittance = acc.transmittance * r.transmittance;
                out.popcount = acc.popcount + r.popcount;
                if acc.hit == 0 && r.hit != 0 {
                    out.hit = 1;
                    out.distance = r.distance;
                    out.interval = r.interval;
                }
                out.rng_state = r.rng_state;
                out
            }
        };
        let next = if mode == Mode::Distance && r.hit != 0 {
            None
        } else {
            self.next_piece(p, Rng { state: r.rng_state })
        };
        (r, next)
    }

    #[inline(always)]
    fn single(&self, ray: &Ray, t_max: f32, rng: &mut Rng, mode: Mode) -> QueryResult {
        let mut p = self.prepare(ray.origin, ray.dir, t_max, *rng);
        let (mut r, mut next) = self.step(&p, self.address(&p), mode, None, None);
        while let Some(n) = next {
            p = n;
            (r, next) = self.step(&p, self.address(&p), mode, Some(r), None);
        }
        rng.state = r.rng_state;
        r
    }

    /// Transmittance estimate over `[0, t_max]` of the ray (`t_max = inf`: to the box exit).
    /// Unbiased for the pin model's interval transmittances (see `docs/sampling.md`).
    pub fn transmittance(&self, ray: &Ray, t_max: f32, rng: &mut Rng) -> f32 {
        self.single(ray, t_max, rng, Mode::Transmittance)
            .transmittance
    }

    /// A sampled free-flight distance in `[0, t_max]`, or `None` if the ray passes.
    pub fn sample_distance(&self, ray: &Ray, t_max: f32, rng: &mut Rng) -> Option<f32> {
        self.single(ray, t_max, rng, Mode::Distance).collision()
    }

    /// Both estimates and the debug integers from one lookup.
    pub fn query(&self, ray: &Ray, t_max: f32, rng: &mut Rng) -> QueryResult {
        self.single(ray, t_max, rng, Mode::Both)
    }

    /// The mean of `draws` independent transmittance estimates of one ray (query `i` seeded
    /// by `Rng::for_query(seed, i)`, as in the batch methods).
    ///
    /// A single estimate is `t_min^n` for an integer `n`: it can be far from the true
    /// transmittance even where the pin model is accurate in the mean (see the crate docs).
    /// The mean over many draws converges to the pin model's expectation for this ray,
    /// lookup jitter included; its standard error is at most `0.5 / sqrt(draws)`.
    pub fn mean_transmittance(&self, ray: &Ray, t_max: f32, draws: u32, seed: u32) -> f64 {
        if draws == 0 {
            return f64::NAN;
        }
        let rays = [RayQuery::new(ray.origin, ray.dir, t_max); BATCH];
        let mut sum = 0.0f64;
        let mut first = 0u32;
        while first < draws {
            let n = (draws - first).min(BATCH as u32) as usize;
            self.batch(&rays[..n], seed, first, Mode::Transmittance, |_, r| {
                sum += f64::from(r.transmittance)
            });
            first += n as u32;
        }
        sum / f64::from(draws)
    }

    /// The pin model's expected transmittance of one ray in closed form, for a sampler
    /// without lookup jitter: the average over the entry's pins of
    /// `t_min^(set bits fully inside the segment) * prod over the partial end intervals whose
    /// bit is set of (1 - f + f t_min)`, where `f` is the covered fraction (a partial
    /// interval takes part with probability `f`). This is exactly what
    /// [`Sampler::transmittance`] returns on average. `None` when the sampler jitters its
    /// lookups (then use [`Sampler::mean_transmittance`]).
    pub fn expected_transmittance(&self, ray: &Ray, t_max: f32) -> Option<f64> {
        if self.opts.spatial_on() || self.opts.directional_on() {
            return None;
        }
        let mut p = self.prepare(ray.origin, ray.dir, t_max, Rng::new(0));
        if p.status != status::OK {
            return Some(1.0);
        }
        // The pieces of a chain draw their pins independently: the expectation is the
        // product of the pieces' expectations.
        let mut product = self.piece_expectation(&p);
        while let Some(n) = self.next_piece(&p, Rng::new(0)) {
            p = n;
            product *= self.piece_expectation(&p);
        }
        Some(product)
    }

    /// The expected transmittance of one unjittered lookup over its piece `p.seg`.
    pub(crate) fn piece_expectation(&self, p: &Prepared) -> f64 {
        let ppe = u64::from(self.view.shape.pins_per_entry.max(1));
        let first_pin = p.within - p.within % ppe;
        let seg = &p.seg;
        // Covered fractions of the end intervals (one interval: the segment's length).
        let (fa, fb) = if seg.a == seg.b {
            (f64::from(seg.s1 - seg.s0), 0.0)
        } else {
            (
                f64::from((seg.a + 1) as f32 - seg.s0),
                f64::from(seg.s1 - seg.b as f32),
            )
        };
        let mut sum = 0.0f64;
        for k in 0..ppe {
            let q = Prepared {
                within: first_pin + k,
                ..*p
            };
            let entry = self
                .address(&q)
                .and_then(|i| self.view.pins.get(i as usize).copied())
                .unwrap_or(PinEntry::EMPTY);
            let t_min = f64::from(sanitize_t_min(entry.t_min));
            let mask = if p.reversed {
                entry.mask.reverse_bits()
            } else {
                entry.mask
            };
            let range = interval_range(seg.a, seg.b);
            let ends = interval_bit(seg.a) | interval_bit(seg.b);
            let full = (mask & range & !ends).count_ones();
            let mut e = t_min.powi(full as i32);
            if mask & interval_bit(seg.a) != 0 {
                e *= 1.0 - fa + fa * t_min;
            }
            if seg.b != seg.a && mask & interval_bit(seg.b) != 0 {
                e *= 1.0 - fb + fb * t_min;
            }
            sum += e;
        }
        sum / ppe as f64
    }

    #[inline(always)]
    fn batch(
        &self,
        rays: &[RayQuery],
        seed: u32,
        first_index: u32,
        mode: Mode,
        emit: impl FnMut(usize, QueryResult),
    ) {
        self.batch_with(rays, Seeds::Indexed(seed, first_index), mode, emit);
    }

    /// One round of fetches of a batch step for the lanes `live[..n]`: a prefetch of every
    /// cell-index word, the addresses and a prefetch of every entry, then the entries (their
    /// lines now on the way) into `entries`.
    #[inline(always)]
    fn fetch_round(
        &self,
        prep: &[Prepared; BATCH],
        addr: &mut [Option<u64>; BATCH],
        entries: &mut [PinEntry; BATCH],
        live: &[bool; BATCH],
        n: usize,
    ) {
        if let Some(ix) = self.view.index {
            for (p, _) in prep[..n].iter().zip(live).filter(|(_, l)| **l) {
                if p.local != NO_CELL {
                    prefetch(ix.as_ptr().wrapping_add(p.local as usize));
                }
            }
        }
        let pins = self.view.pins.as_ptr();
        for i in 0..n {
            if live[i] {
                addr[i] = self.address(&prep[i]);
                if let Some(a) = addr[i] {
                    prefetch(pins.wrapping_add(a as usize));
                }
            }
        }
        for i in 0..n {
            entries[i] = match addr[i].filter(|_| live[i]) {
                Some(a) => self.view.pins.get(a as usize).copied(),
                None => None,
            }
            .unwrap_or(PinEntry::EMPTY);
        }
    }

    /// The lane set-up of step `c` of a batch (`rays[c BATCH..]`, at most [`BATCH`] rays)
    /// into `prep`, with the step's generators; returns the step's number of rays.
    #[inline(always)]
    fn set_up_step(
        &self,
        rays: &[RayQuery],
        c: usize,
        seeds: &Seeds<'_>,
        seed_hash: u32,
        rng: &mut [Rng; BATCH],
        prep: &mut [Prepared; BATCH],
    ) -> usize {
        let base = c * BATCH;
        let chunk = &rays[base..(base + BATCH).min(rays.len())];
        let n = chunk.len();
        // The rays two steps on (1 KB, 16 lines): a caller's large ray array streams from
        // memory, and its misses otherwise stall the set-up's first loop.
        for q in rays.iter().skip(base + 2 * BATCH).take(BATCH).step_by(2) {
            prefetch(q);
        }
        // The next step's rays (1 KB, 16 lines): a caller's ray array streams from memory,
        // and its misses otherwise stall the set-up's first loop.
        if let Some(next) = rays.get(base + BATCH..) {
            for q in next.iter().take(BATCH).step_by(2) {
                prefetch(q);
            }
        }
        let indexed = match seeds {
            Seeds::Indexed(_, first) => Some((seed_hash, first.wrapping_add(base as u32))),
            Seeds::Given(g) => {
                rng[..n].copy_from_slice(&g[base..base + n]);
                None
            }
        };
        crate::lanes::prepare_lanes(&self.view, &self.xf, &self.opts, chunk, rng, indexed, prep);
        n
    }

    /// A prefetch of the sparse cell-index word of each of `prep[..n]` (none for a dense
    /// grid).
    #[inline(always)]
    fn prefetch_index(&self, prep: &[Prepared; BATCH], n: usize) {
        if let Some(ix) = self.view.index {
            for p in &prep[..n] {
                if p.local != NO_CELL {
                    prefetch(ix.as_ptr().wrapping_add(p.local as usize));
                }
            }
        }
    }

    /// The entry addresses of `prep[..n]` (reading their index words) and a prefetch of
    /// each entry.
    #[inline(always)]
    fn address_and_prefetch(
        &self,
        prep: &[Prepared; BATCH],
        addr: &mut [Option<u64>; BATCH],
        n: usize,
    ) {
        let pins = self.view.pins.as_ptr();
        for i in 0..n {
            addr[i] = self.address(&prep[i]);
            if let Some(a) = addr[i] {
                prefetch(pins.wrapping_add(a as usize));
            }
        }
    }

    /// Batches with one lookup per query, software pipelined over the steps of [`BATCH`]
    /// rays: while the entries of step `c` are on their way, step `c + 1` is set up and its
    /// index words fetched; then `c` is resolved, each ray's finish followed by the request
    /// of one entry of `c + 1`. So the memory latency of each step overlaps the arithmetic
    /// of the next instead of stalling it (bench_queries, 262 MB grid: 44 -> 41 ns per
    /// transmittance, 74 -> 64 ns per distance). Each ray's result is the same as without
    /// the pipeline: the steps only reorder work between independent rays.
    #[inline(always)]
    fn batch_single(
        &self,
        rays: &[RayQuery],
        mut seeds: Seeds<'_>,
        seed_hash: u32,
        mode: Mode,
        mut emit: impl FnMut(usize, QueryResult),
    ) {
        let steps = rays.len().div_ceil(BATCH);
        if steps == 0 {
            return;
        }
        let mut prep = [[NOT_PREPARED; BATCH]; 2];
        let mut addr = [[None::<u64>; BATCH]; 2];
        let mut n = [0usize; 2];
        let mut rng = [Rng::new(0); BATCH];
        let mut entries = [PinEntry::EMPTY; BATCH];
        let mut heads = [crate::lanes::Head::default(); BATCH];
        n[0] = self.set_up_step(rays, 0, &seeds, seed_hash, &mut rng, &mut prep[0]);
        self.prefetch_index(&prep[0], n[0]);
        self.address_and_prefetch(&prep[0], &mut addr[0], n[0]);
        for c in 0..steps {
            let (cur, nxt) = (c & 1, (c + 1) & 1);
            let more = c + 1 < steps;
            if more {
                n[nxt] = self.set_up_step(rays, c + 1, &seeds, seed_hash, &mut rng, &mut prep[nxt]);
                self.prefetch_index(&prep[nxt], n[nxt]);
            }
            let pins = self.view.pins;
            for (e, a) in entries.iter_mut().zip(&addr[cur][..n[cur]]) {
                *e = a
                    .and_then(|a| pins.get(a as usize).copied())
                    .unwrap_or(PinEntry::EMPTY);
            }
            // Lanes past `n[cur]` resolve stale values nobody reads.
            crate::lanes::resolve_heads(&prep[cur], &entries, &mut heads);
            let base = c * BATCH;
            // Step `c + 1`'s entry requests go out one per finish of step `c`: a burst of
            // 32 would exceed the core's outstanding-miss slots and stall on them.
            let pins = self.view.pins.as_ptr();
            let (pc, pn) = (&prep[cur], &prep[nxt]);
            let [a0, a1] = &mut addr;
            let (ac, an) = if cur == 0 { (&*a0, a1) } else { (&*a1, a0) };
            let n_next = if more { n[nxt] } else { 0 };
            for i in 0..n[cur].max(n_next) {
                if i < n_next {
                    an[i] = self.address(&pn[i]);
                    if let Some(a) = an[i] {
                        prefetch(pins.wrapping_add(a as usize));
                    }
                }
                if i < n[cur] {
                    let r = self.finish_head(&pc[i], ac[i], &heads[i], mode);
                    if let Seeds::Given(g) = &mut seeds {
                        g[base + i].state = r.rng_state;
                    }
                    emit(base + i, r);
                }
            }
        }
    }

    /// The batch machinery: per step of [`BATCH`] rays, the set-up of every ray's first
    /// lookup (lane parallel, see [`crate::lanes`]), a prefetch of every cell-index word,
    /// the addresses and a prefetch of every entry, then the finishes in ray order; chains
    /// repeat the fetches and finishes once per piece for the rays still walking.
    #[inline(always)]
    fn batch_with(
        &self,
        rays: &[RayQuery],
        mut seeds: Seeds<'_>,
        mode: Mode,
        mut emit: impl FnMut(usize, QueryResult),
    ) {
        let mut prep = [NOT_PREPARED; BATCH];
        let mut addr = [None::<u64>; BATCH];
        let mut acc = [None::<QueryResult>; BATCH];
        let mut live = [false; BATCH];
        let mut rng = [Rng::new(0); BATCH];
        let mut entries = [PinEntry::EMPTY; BATCH];
        let mut heads = [crate::lanes::Head::default(); BATCH];
        let seed_hash = match seeds {
            Seeds::Indexed(seed, _) => crate::rng::pcg_hash(seed),
            Seeds::Given(_) => 0,
        };
        if self.opts.stride() == 32 {
            // One lookup per query (no chain): pipelined, without the chain's bookkeeping.
            self.batch_single(rays, seeds, seed_hash, mode, emit);
            return;
        }
        for c in 0..rays.len().div_ceil(BATCH) {
            let base = c * BATCH;
            // The first lookup of every ray in lanes (every option: jitter, lookup point,
            // the first piece of a chain); later pieces of chains come from the scalar
            // `next_piece`, since few rays of a step walk them.
            let n = self.set_up_step(rays, c, &seeds, seed_hash, &mut rng, &mut prep);
            acc[..n].fill(None);
            live[..n].fill(true);
            // One round per piece of a chain: every round issues the fetches of all the rays
            // still walking their chains before resolving any of them.
            loop {
                self.fetch_round(&prep, &mut addr, &mut entries, &live, n);
                // Lanes no longer walking compute unread values.
                crate::lanes::resolve_heads(&prep, &entries, &mut heads);
                let mut more = false;
                for i in 0..n {
                    if !live[i] {
                        continue;
                    }
                    let (r, next) = self.step(&prep[i], addr[i], mode, acc[i], Some(&heads[i]));
                    acc[i] = Some(r);
                    match next {
                        Some(p) => {
                            prep[i] = p;
                            more = true;
                        }
                        None => live[i] = false,
                    }
                }
                if !more {
                    break;
                }
            }
            for (i, r) in acc[..n].iter().enumerate() {
                if let Some(r) = r {
                    if let Seeds::Given(g) = &mut seeds {
                        g[base + i].state = r.rng_state;
                    }
                    emit(base + i, *r);
                }
            }
        }
    }

    /// Transmittance of many rays; query `i` uses `Rng::for_query(seed, first_index + i)`
    /// (the GPU's seeding). `out.len()` must equal `rays.len()`.
    pub fn transmittance_batch(
        &self,
        rays: &[RayQuery],
        seed: u32,
        first_index: u32,
        out: &mut [f32],
    ) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        self.batch(rays, seed, first_index, Mode::Transmittance, |i, r| {
            out[i] = r.transmittance
        });
    }

    /// Sampled distances of many rays (`None`: no collision), seeded like
    /// [`Self::transmittance_batch`].
    pub fn sample_distance_batch(
        &self,
        rays: &[RayQuery],
        seed: u32,
        first_index: u32,
        out: &mut [Option<f32>],
    ) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        self.batch(rays, seed, first_index, Mode::Distance, |i, r| {
            out[i] = r.collision()
        });
    }

    /// Full results of many rays, seeded like the GPU's `run_queries` (the reference the GPU
    /// is compared against).
    pub fn query_batch(
        &self,
        rays: &[RayQuery],
        seed: u32,
        first_index: u32,
        out: &mut [QueryResult],
    ) {
        assert_eq!(rays.len(), out.len(), "one output per ray");
        self.batch(rays, seed, first_index, Mode::Both, |i, r| out[i] = r);
    }

    /// Full results of many rays for one kind of query, seeded like
    /// [`Self::query_batch`]: the reference of the GPU's single-purpose dispatches.
    #[cfg(all(test, feature = "gpu"))]
    pub(crate) fn query_batch_mode(
        &self,
        rays: &[RayQuery],
        seed: u32,
        first_index: u32,
        mode: crate::gpu::QueryMode,
        out: &mut [QueryResult],
    ) {
        use crate::gpu::QueryMode;
        let mode = match mode {
            QueryMode::Both => Mode::Both,
            QueryMode::Transmittance => Mode::Transmittance,
            QueryMode::Distance => Mode::Distance,
        };
        self.batch(rays, seed, first_index, mode, |i, r| out[i] = r);
    }

    /// Transmittance of many rays, ray `i` with its own generator `rngs[i]`, which is
    /// advanced exactly as [`Self::transmittance`] advances it: the results and the
    /// generators afterwards equal those of one single query per ray. For callers that own
    /// a generator per path (a wavefront renderer); `rays`, `rngs` and `out` have one
    /// element per ray.
    pub fn transmittance_batch_rngs(&self, rays: &[RayQuery], rngs: &mut [Rng], out: &mut [f32]) {
        assert!(
            rays.len() == out.len() && rays.len() == rngs.len(),
            "one generator and output per ray"
        );
        self.batch_with(rays, Seeds::Given(rngs), Mode::Transmittance, |i, r| {
            out[i] = r.transmittance
        });
    }

    /// Sampled distances of many rays with a generator per ray, as
    /// [`Self::transmittance_batch_rngs`] (equal to [`Self::sample_distance`] per ray).
    pub fn sample_distance_batch_rngs(
        &self,
        rays: &[RayQuery],
        rngs: &mut [Rng],
        out: &mut [Option<f32>],
    ) {
        assert!(
            rays.len() == out.len() && rays.len() == rngs.len(),
            "one generator and output per ray"
        );
        self.batch_with(rays, Seeds::Given(rngs), Mode::Distance, |i, r| {
            out[i] = r.collision()
        });
    }

    /// Full results of many rays with a generator per ray (equal to [`Self::query`] per ray).
    pub fn query_batch_rngs(&self, rays: &[RayQuery], rngs: &mut [Rng], out: &mut [QueryResult]) {
        assert!(
            rays.len() == out.len() && rays.len() == rngs.len(),
            "one generator and output per ray"
        );
        self.batch_with(rays, Seeds::Given(rngs), Mode::Both, |i, r| out[i] = r);
    }
}

/// Resolves a segment against one entry: partial-interval participation, transmittance and
/// (depending on `mode`) the distance. Public for the statistical tests.
#[inline(always)]
fn resolve(
    entry: PinEntry,
    entry_id: u32,
    reversed: bool,
    seg: &Segment,
    mut rng: Rng,
    mode: Mode,
) -> QueryResult {
    let xa = rng.next_f32();
    let xb = rng.next_f32();
    let t_min = sanitize_t_min(entry.t_min);
    let mask = if reversed {
        entry.mask.reverse_bits()
    } else {
        entry.mask
    };
    let part = participating(seg, xa, xb);
    let popcount = (mask & part).count_ones();
    let mut r = QueryResult {
        distance: f32::INFINITY,
        transmittance: 1.0,
        hit: 0,
        entry: entry_id,
        popcount,
        interval: NO_INTERVAL,
        status: status::OK,
        rng_state: 0,
    };
    if mode != Mode::Distance {
        r.transmittance = pow_int(t_min, popcount);
    }
    if mode != Mode::Transmittance {
        let h = exact_sample_mask(t_min, &mut rng);
        let m = mask & part & h;
        if m != 0 {
            let j = m.leading_zeros();
            r.interval = j;
            r.hit = 1;
            r.distance = position_in_interval(seg, j, rng.next_f32());
        }
    }
    r.rng_state = rng.state;
    r
}

/// The participating intervals: `a..=b`, minus a partial first/last interval whose draw
/// exceeds its covered fraction (`xi < f` participates). One interval: fraction `s1 - s0`.
#[inline(always)]
pub fn participating(seg: &Segment, xa: f32, xb: f32) -> u32 {
    let (a, b) = (seg.a, seg.b);
    let mut part = interval_range(a, b);
    if a == b {
        if !(xa < seg.s1 - seg.s0) {
            part = 0;
        }
    } else {
        if !(xa < (a + 1) as f32 - seg.s0) {
            part &= !interval_bit(a);
        }
        if !(xb < seg.s1 - b as f32) {
            part &= !interval_bit(b);
        }
    }
    part
}

/// A uniform position inside the covered part of interval `j`, clamped into `[t0, t1]`.
#[inline(always)]
pub fn position_in_interval(seg: &Segment, j: u32, xi: f32) -> f32 {
    let lo = if j == seg.a { seg.s0 } else { j as f32 };
    let hi = if j == seg.b { seg.s1 } else { (j + 1) as f32 };
    let s = lo + xi * (hi - lo);
    let t = seg.t_enter + s * seg.interval_len;
    let t = if t > seg.t0 { t } else { seg.t0 };
    if t < seg.t1 { t } else { seg.t1 }
}

/// Test hook: resolve a segment against an explicit entry.
#[doc(hidden)]
pub fn resolve_entry(
    entry: PinEntry,
    reversed: bool,
    seg: &Segment,
    rng: &mut Rng,
    want_distance: bool,
) -> QueryResult {
    let mode = if want_distance {
        Mode::Both
    } else {
        Mode::Transmittance
    };
    let r = resolve(entry, 0, reversed, seg, *rng, mode);
    rng.state = r.rng_state;
    r
}
