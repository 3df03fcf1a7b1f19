//! The [`Sampler`] and its single-ray path: the set-up of a lookup (transform, chord,
//! segment, draws 1-3, cells), its entry address, its resolve, and the chain of pieces.

use pin_format::PinEntry;

use crate::chord::{Segment, UnitTransform, segment, unit_cube_chord};
use crate::error::Result;
use crate::loader::PinGrid;
use crate::lookup::{DirJitter, GridView, direction_cell, nearest_line_cell, spatial_cell};
use crate::mask::{exact_sample_mask, is_finite_bits};
use crate::rng::Rng;

use super::options::SamplerOptions;
use super::prepared::{NO_CELL, Prepared, piece_of};
use super::query::{NO_ENTRY, NO_INTERVAL, QueryMode, QueryResult, Ray, status};
use super::resolve::{Head, position_in_interval, resolve};

/// Samples distances and transmittance through one pin grid placed in the world.
///
/// Cheap to create and `Copy`-free but `Sync`: share one sampler between threads and give each
/// thread its own [`Rng`] (or use the batch methods, which seed per query).
#[derive(Clone, Debug)]
pub struct Sampler<'g> {
    pub(super) view: GridView<'g>,
    pub(super) xf: UnitTransform,
    pub(super) opts: SamplerOptions,
}

impl<'g> Sampler<'g> {
    /// A sampler placing the grid by the file's `local_to_world`, with the default lookup
    /// ([`SamplerOptions::RENDER`]; [`Self::with_options`] changes it).
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

    /// Sets the lookup options ([`SamplerOptions::THESIS`] for the thesis' lookup).
    pub fn with_options(mut self, opts: SamplerOptions) -> Self {
        self.opts = opts;
        self
    }

    /// The lookup options this sampler queries with.
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

    /// The grid as the lookups read it (for the tests that rebuild a lookup by hand).
    #[cfg(test)]
    pub(crate) fn view(&self) -> &GridView<'g> {
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
    pub(super) fn next_piece(&self, p: &Prepared, rng: Rng) -> Option<Prepared> {
        if p.status != status::OK || p.seg.b >= p.full.b {
            return None;
        }
        Some(self.lookup(p.o, p.d, p.full, p.piece + 1, rng))
    }

    /// Entry index for a prepared query (reads the sparse index).
    #[inline(always)]
    pub(super) fn address(&self, p: &Prepared) -> Option<u64> {
        if p.status != status::OK || p.local == NO_CELL {
            return None;
        }
        let block = self.view.block_of(p.local)?;
        Some(block * self.view.shape.block_len + p.within)
    }

    #[inline(always)]
    fn finish(&self, p: &Prepared, entry_index: Option<u64>, mode: QueryMode) -> QueryResult {
        if p.status != status::OK {
            return QueryResult::empty(p.status, p.rng);
        }
        let (entry, entry_id) = match entry_index.and_then(|i| self.view.pins.get(i as usize)) {
            Some(e) => (*e, entry_index.unwrap_or(0) as u32),
            None => (PinEntry::EMPTY, NO_ENTRY),
        };
        resolve(entry, entry_id, p.reversed, &p.seg, p.rng, mode)
    }

    /// [`Self::finish`] after the lanes' `resolve_heads` computed the start of the
    /// resolve: the same result, bit for bit (the distance part is `resolve`'s).
    #[inline(always)]
    pub(super) fn finish_head(
        &self,
        p: &Prepared,
        entry_index: Option<u64>,
        h: &Head,
        mode: QueryMode,
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
        if mode != QueryMode::Distance {
            r.transmittance = h.transmittance;
        }
        if mode != QueryMode::Transmittance {
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
    /// `QueryMode::Both` keeps estimating the transmittance of the remaining pieces. With `head`
    /// (the lane-computed start of `p`'s resolve) the piece is finished by
    /// [`Self::finish_head`], which gives the same result as [`Self::finish`].
    #[inline(always)]
    pub(super) fn step(
        &self,
        p: &Prepared,
        entry_index: Option<u64>,
        mode: QueryMode,
        acc: Option<QueryResult>,
        head: Option<&Head>,
    ) -> (QueryResult, Option<Prepared>) {
        let finish = |m| match head {
            Some(h) => self.finish_head(p, entry_index, h, m),
            None => self.finish(p, entry_index, m),
        };
        let r = match acc {
            None => finish(mode),
            Some(acc) => {
                let m = if mode == QueryMode::Both && acc.hit != 0 {
                    QueryMode::Transmittance
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
        let next = if mode == QueryMode::Distance && r.hit != 0 {
            None
        } else {
            self.next_piece(p, Rng { state: r.rng_state })
        };
        (r, next)
    }

    #[inline(always)]
    fn single(&self, ray: &Ray, t_max: f32, rng: &mut Rng, mode: QueryMode) -> QueryResult {
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
        self.single(ray, t_max, rng, QueryMode::Transmittance)
            .transmittance
    }

    /// A sampled free-flight distance in `[0, t_max]`, or `None` if the ray passes.
    pub fn sample_distance(&self, ray: &Ray, t_max: f32, rng: &mut Rng) -> Option<f32> {
        self.single(ray, t_max, rng, QueryMode::Distance)
            .collision()
    }

    /// Both estimates and the debug integers from one lookup.
    pub fn query(&self, ray: &Ray, t_max: f32, rng: &mut Rng) -> QueryResult {
        self.single(ray, t_max, rng, QueryMode::Both)
    }
}

// Here rather than in the loader, so that the loader does not import the sampler that
// imports it.
impl PinGrid {
    /// A sampler with the default lookup ([`crate::SamplerOptions::RENDER`]) and the file's
    /// own placement.
    pub fn sampler(&self) -> crate::error::Result<Sampler<'_>> {
        Sampler::new(self)
    }
}
