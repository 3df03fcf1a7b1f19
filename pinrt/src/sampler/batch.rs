//! The batch queries: per step of [`BATCH`] rays, the lanes set up every ray's first lookup
//! and start its resolve, while the scalar code addresses, prefetches and finishes each ray,
//! so that a step's memory fetches are in flight together.

use pin_format::PinEntry;

use crate::rng::Rng;

use super::lanes::{BATCH, prepare_lanes, resolve_heads};
use super::prepared::{NO_CELL, NOT_PREPARED, Prepared};
use super::query::{QueryMode, QueryResult, RayQuery};
use super::resolve::Head;
use super::scalar::Sampler;

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

impl Sampler<'_> {
    #[inline(always)]
    pub(super) fn batch(
        &self,
        rays: &[RayQuery],
        seed: u32,
        first_index: u32,
        mode: QueryMode,
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
        prepare_lanes(&self.view, &self.xf, &self.opts, chunk, rng, indexed, prep);
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
        mode: QueryMode,
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
        let mut heads = [Head::default(); BATCH];
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
            resolve_heads(&prep[cur], &entries, &mut heads);
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
    /// lookup (lane parallel, see `lanes`), a prefetch of every cell-index word,
    /// the addresses and a prefetch of every entry, then the finishes in ray order; chains
    /// repeat the fetches and finishes once per piece for the rays still walking.
    #[inline(always)]
    fn batch_with(
        &self,
        rays: &[RayQuery],
        mut seeds: Seeds<'_>,
        mode: QueryMode,
        mut emit: impl FnMut(usize, QueryResult),
    ) {
        let mut prep = [NOT_PREPARED; BATCH];
        let mut addr = [None::<u64>; BATCH];
        let mut acc = [None::<QueryResult>; BATCH];
        let mut live = [false; BATCH];
        let mut rng = [Rng::new(0); BATCH];
        let mut entries = [PinEntry::EMPTY; BATCH];
        let mut heads = [Head::default(); BATCH];
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
                resolve_heads(&prep, &entries, &mut heads);
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
        self.batch(rays, seed, first_index, QueryMode::Transmittance, |i, r| {
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
        self.batch(rays, seed, first_index, QueryMode::Distance, |i, r| {
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
        self.batch(rays, seed, first_index, QueryMode::Both, |i, r| out[i] = r);
    }

    /// Full results of many rays for one kind of query, seeded like
    /// [`Self::query_batch`]: the reference of the GPU's single-purpose dispatches.
    #[cfg(all(test, feature = "gpu"))]
    pub(crate) fn query_batch_mode(
        &self,
        rays: &[RayQuery],
        seed: u32,
        first_index: u32,
        mode: QueryMode,
        out: &mut [QueryResult],
    ) {
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
        self.batch_with(
            rays,
            Seeds::Given(rngs),
            QueryMode::Transmittance,
            |i, r| out[i] = r.transmittance,
        );
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
        self.batch_with(rays, Seeds::Given(rngs), QueryMode::Distance, |i, r| {
            out[i] = r.collision()
        });
    }

    /// Full results of many rays with a generator per ray (equal to [`Self::query`] per ray).
    pub fn query_batch_rngs(&self, rays: &[RayQuery], rngs: &mut [Rng], out: &mut [QueryResult]) {
        assert!(
            rays.len() == out.len() && rays.len() == rngs.len(),
            "one generator and output per ray"
        );
        self.batch_with(rays, Seeds::Given(rngs), QueryMode::Both, |i, r| out[i] = r);
    }
}
