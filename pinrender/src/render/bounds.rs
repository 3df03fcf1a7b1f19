//! Skipping media a ray cannot meet: per-medium world boxes and a ray/box slab test.
//!
//! An estimator may declare a world box outside which its medium has no extinction
//! ([`super::TransportEstimator::bounds`]). The tracer keeps those boxes (padded outward,
//! f32, struct of arrays) and, per query, asks only the media whose box the segment
//! `[0, t_max]` of the ray meets. A skipped medium would have returned transmittance 1 and no
//! collision, so skipping changes no expectation; it changes which random numbers later
//! media draw, i.e. images change bit-wise, not in distribution.
//!
//! The test is conservative: a ray it cannot reason about (non-finite, zero direction) asks
//! every medium, a medium without a box has the infinite box, and box faces and the segment
//! ends count as inside. Boxes are padded by [`PAD_REL`] of their size plus a few f32 ulps
//! of their coordinates, so a ray grazing a face still reaches the estimator, whose own
//! (f32 or f64) clipping then decides. An axis with `d = 0` (either sign), or whose `1 / d`
//! overflows (a subnormal `d`, as in the pin sampler's chord), is parallel: inside the slab
//! or never.
//!
//! The test is branch-free over a chunk of [`CHUNK`] boxes (struct of arrays), so the
//! compiler vectorises it (SSE).
//!
//! Above the boxes sits one level of hierarchy: the union box of each chunk. A segment that
//! misses a chunk's union misses every box in it (the slab test is monotone in the box: a
//! smaller box gives a later entry and an earlier exit, in f32 as in the reals), so the
//! chunk answers [`MISS`] for all its boxes after one test, the same answers bit for bit as
//! testing each. A scene of thousands of instances, listed in a spatially coherent order
//! (the scene loader sorts them along a Morton curve), then costs a query one test per chunk
//! plus the chunks it meets.
//!
//! That holds a scene of up to one chunk. Above that, [`super::bvh`] indexes the boxes in a
//! hierarchy that keeps the media order, and a query walks it instead: its cost grows with
//! the media the ray meets. Either way the queries see the same boxes met, with the same
//! entries, in the same order ([`MediaBoxes::for_each_met`], [`MetChunks`]).

use glam::Vec3;

use super::bvh::{Bvh, Walk};
pub(crate) use super::slab::{CHUNK, MISS, RaySlabs, slab_entry};

/// Relative padding of a box: this fraction of its longest finite edge on every side.
pub(crate) const PAD_REL: f64 = 1e-5;

/// Absolute part of the padding, in units of the largest finite coordinate magnitude of the
/// box (a few f32 ulps: covers the rounding of the f32 box and of the f32 slab test).
const PAD_ULPS: f64 = 8.0 * f32::EPSILON as f64;

/// A box `[lo, hi]` padded outward as the tracer stores it, or `None` for "unbounded"
/// (no box, or one that is NaN or inverted: conservatively never skipped). The padded
/// bounds are strictly outside the given ones (after rounding to f32).
pub(crate) fn padded(b: Option<([f64; 3], [f64; 3])>) -> Option<([f32; 3], [f32; 3])> {
    let (lo, hi) = b?;
    if !(0..3).all(|a| lo[a] <= hi[a]) {
        return None; // NaN or inverted
    }
    let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
    let edge = (0..3).map(|a| finite(hi[a] - lo[a])).fold(0.0, f64::max);
    let mut out = ([0.0f32; 3], [0.0f32; 3]);
    for a in 0..3 {
        let mag = finite(lo[a]).abs().max(finite(hi[a]).abs());
        let pad = PAD_REL * edge + PAD_ULPS * mag + f64::from(f32::MIN_POSITIVE);
        out.0[a] = (lo[a] - pad) as f32;
        out.1[a] = (hi[a] + pad) as f32;
    }
    Some(out)
}

/// The boxes of one estimator role (primary or secondary) of a scene's media, in media
/// order. An unbounded medium has the infinite box, which every ray meets.
#[derive(Clone, Debug, Default)]
pub(crate) struct MediaBoxes {
    lo: [Vec<f32>; 3],
    hi: [Vec<f32>; 3],
    /// The union box of each chunk of [`CHUNK`] boxes (`start / CHUNK`).
    chunk_lo: Vec<[f32; 3]>,
    chunk_hi: Vec<[f32; 3]>,
    /// The hierarchy over more than one chunk of boxes; `None`: the linear scan of chunks.
    tree: Option<Bvh>,
}

impl MediaBoxes {
    pub(crate) fn new(boxes: impl IntoIterator<Item = Option<([f64; 3], [f64; 3])>>) -> Self {
        let mut m = Self::linear(boxes);
        if m.len() > CHUNK {
            m.tree = Bvh::build(&m.lo, &m.hi);
        }
        m
    }

    /// The boxes without the hierarchy, always scanned chunk by chunk (the tests' reference).
    pub(crate) fn linear(boxes: impl IntoIterator<Item = Option<([f64; 3], [f64; 3])>>) -> Self {
        let mut m = MediaBoxes::default();
        for b in boxes {
            let (lo, hi) = padded(b).unwrap_or(([f32::NEG_INFINITY; 3], [f32::INFINITY; 3]));
            if m.lo[0].len().is_multiple_of(CHUNK) {
                m.chunk_lo.push(lo);
                m.chunk_hi.push(hi);
            }
            let c = m.chunk_lo.len() - 1;
            for a in 0..3 {
                m.lo[a].push(lo[a]);
                m.hi[a].push(hi[a]);
                m.chunk_lo[c][a] = m.chunk_lo[c][a].min(lo[a]);
                m.chunk_hi[c][a] = m.chunk_hi[c][a].max(hi[a]);
            }
        }
        m
    }

    pub(crate) fn len(&self) -> usize {
        self.lo[0].len()
    }

    /// Calls `f(i)` for every box `i` that the segment `[0, t_max]` of `ray` meets, in
    /// media order, until `f` returns false.
    #[inline]
    pub(crate) fn for_each_met(
        &self,
        ray: &RaySlabs,
        t_max: f32,
        mut f: impl FnMut(usize) -> bool,
    ) {
        if let Some(tree) = &self.tree {
            let mut walk = Walk::default();
            while let Some(run) = tree.next_leaf(&mut walk, ray, t_max) {
                for i in run {
                    if self.entry_of(i, ray, t_max) != MISS && !f(i) {
                        return;
                    }
                }
            }
            return;
        }
        let mut entry = [MISS; CHUNK];
        for start in (0..self.len()).step_by(CHUNK) {
            let n = self.entries(start, ray, t_max, &mut entry);
            for (j, e) in entry[..n].iter().enumerate() {
                if *e != MISS && !f(start + j) {
                    return;
                }
            }
        }
    }

    /// Whether queries walk the hierarchy (for tests).
    #[cfg(test)]
    pub(crate) fn has_tree(&self) -> bool {
        self.tree.is_some()
    }

    /// The struct-of-arrays boxes (for the hierarchy's tests).
    #[cfg(test)]
    pub(crate) fn soa(&self) -> (&[Vec<f32>; 3], &[Vec<f32>; 3]) {
        (&self.lo, &self.hi)
    }

    /// Box `i` as stored, padded (for tests).
    #[cfg(test)]
    pub(crate) fn box_of(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        (
            [self.lo[0][i], self.lo[1][i], self.lo[2][i]],
            [self.hi[0][i], self.hi[1][i], self.hi[2][i]],
        )
    }

    /// For the boxes `start..start + n` (`n = min(CHUNK, len - start)`, returned): where
    /// the segment `[0, t_max]` of `ray` enters each (0 if it starts inside) in `out[..n]`,
    /// or [`MISS`] if it certainly misses the box. A NaN `t_max` misses every box (the
    /// estimators treat it as "no medium" too).
    #[inline]
    pub(crate) fn entries(
        &self,
        start: usize,
        ray: &RaySlabs,
        t_max: f32,
        out: &mut [f32; CHUNK],
    ) -> usize {
        let n = self.len().saturating_sub(start).min(CHUNK);
        if start.is_multiple_of(CHUNK)
            && let Some(c) = self.chunk_lo.get(start / CHUNK)
            && slab_entry(*c, self.chunk_hi[start / CHUNK], ray, t_max) == MISS
        {
            out[..n].fill(MISS);
            return n;
        }
        let end = start + n;
        let (lx, ly, lz) = (
            &self.lo[0][start..end],
            &self.lo[1][start..end],
            &self.lo[2][start..end],
        );
        let (hx, hy, hz) = (
            &self.hi[0][start..end],
            &self.hi[1][start..end],
            &self.hi[2][start..end],
        );
        for i in 0..n {
            out[i] = slab_entry([lx[i], ly[i], lz[i]], [hx[i], hy[i], hz[i]], ray, t_max);
        }
        n
    }

    /// [`MediaBoxes::entries`] of box `i` alone, without the chunk's buffer (the
    /// wavefront loop's one-medium box test): the same value, bit for bit.
    #[inline]
    pub(crate) fn entry_of(&self, i: usize, ray: &RaySlabs, t_max: f32) -> f32 {
        slab_entry(
            [self.lo[0][i], self.lo[1][i], self.lo[2][i]],
            [self.hi[0][i], self.hi[1][i], self.hi[2][i]],
            ray,
            t_max,
        )
    }

    /// Whether `o` lies strictly inside box `i`: then [`MediaBoxes::entries`] enters it at 0
    /// for every direction and every `t_max >= 0` (no slab can put the entry after 0 or the
    /// exit before it), so a caller may skip the slab test. False for NaN.
    #[inline]
    pub(crate) fn strictly_inside(&self, i: usize, o: Vec3) -> bool {
        let o = o.to_array();
        (0..3).all(|a| self.lo[a][i] < o[a] && o[a] < self.hi[a][i])
    }

    /// [`MediaBoxes::entries`] of box `i` alone (for tests).
    #[cfg(test)]
    pub(crate) fn entry(&self, i: usize, ray: &RaySlabs, t_max: f32) -> Option<f32> {
        let mut out = [MISS; CHUNK];
        self.entries(i, ray, t_max, &mut out);
        (out[0] < MISS).then_some(out[0])
    }
}

/// The boxes of `entry[..n]` ([`MediaBoxes::entries`]) that the ray meets, by entry, into
/// `order[..k]`; returns `k`. An insertion sort (a handful of boxes), stable: ties keep the
/// media order. The order in which the tracer's nearest-collision search asks the media.
#[inline]
pub(crate) fn met_by_entry(entry: &[f32; CHUNK], n: usize, order: &mut [u8; CHUNK]) -> usize {
    let mut k = 0usize;
    for i in 0..n {
        let e = entry[i];
        if e == MISS {
            continue;
        }
        let mut j = k;
        while j > 0 && entry[order[j - 1] as usize] > e {
            order[j] = order[j - 1];
            j -= 1;
        }
        order[j] = i as u8;
        k += 1;
    }
    k
}

/// The nearest-collision search's view of the boxes: chunk after chunk of [`CHUNK`] media,
/// in media order, the boxes of the chunk that the segment `[0, best]` of the ray meets
/// (`best` as it stands when the chunk is reached), by entry ([`met_by_entry`]'s order).
/// Chunks that the ray does not meet are passed over. Resumable, so that the wavefront loop
/// keeps one per path.
#[derive(Clone, Copy)]
pub(crate) struct MetChunks {
    /// The current chunk's first medium.
    pub(crate) start: usize,
    /// `entry[j]`: where the ray enters box `start + j`, for the boxes in `order[..met]`.
    pub(crate) entry: [f32; CHUNK],
    pub(crate) order: [u8; CHUNK],
    pub(crate) met: usize,
    /// The linear scan: the next chunk's first medium.
    next_start: usize,
    /// The hierarchy: where its walk stands, and a leaf it met that belongs to a later chunk
    /// than the one being gathered (`(first, end)`; `first == end`: none).
    walk: Walk,
    held: (u32, u32),
}

impl MetChunks {
    pub(crate) fn new() -> Self {
        MetChunks {
            start: 0,
            entry: [MISS; CHUNK],
            order: [0; CHUNK],
            met: 0,
            next_start: 0,
            walk: Walk::default(),
            held: (0, 0),
        }
    }

    /// Moves to the next chunk that has a box met by `[0, best]`; false when none is left.
    #[inline]
    pub(crate) fn advance(&mut self, boxes: &MediaBoxes, ray: &RaySlabs, best: f32) -> bool {
        let Some(tree) = &boxes.tree else {
            while self.next_start < boxes.len() {
                self.start = self.next_start;
                self.next_start += CHUNK;
                let n = boxes.entries(self.start, ray, best, &mut self.entry);
                self.met = met_by_entry(&self.entry, n, &mut self.order);
                if self.met > 0 {
                    return true;
                }
            }
            self.met = 0;
            return false;
        };
        // The leaves come in media order and never straddle a chunk, so a chunk's boxes met
        // are gathered from consecutive leaves. Every test uses `best` as it stands now,
        // which is what the linear scan uses for this chunk; a leaf held over from the last
        // chunk was met with an earlier, larger `best`, a superset that its boxes' own tests
        // narrow.
        loop {
            self.met = 0;
            let mut chunk = None;
            loop {
                let run = if self.held.0 < self.held.1 {
                    let r = self.held.0 as usize..self.held.1 as usize;
                    self.held = (0, 0);
                    r
                } else {
                    match tree.next_leaf(&mut self.walk, ray, best) {
                        Some(r) => r,
                        None => break,
                    }
                };
                let c = run.start / CHUNK;
                match chunk {
                    None => {
                        chunk = Some(c);
                        self.start = c * CHUNK;
                    }
                    Some(cur) if cur != c => {
                        self.held = (run.start as u32, run.end as u32);
                        break;
                    }
                    Some(_) => {}
                }
                for i in run {
                    let e = boxes.entry_of(i, ray, best);
                    if e == MISS {
                        continue;
                    }
                    // Insertion by entry, stable (media order on ties): `met_by_entry`.
                    let j0 = i - self.start;
                    self.entry[j0] = e;
                    let mut j = self.met;
                    while j > 0 && self.entry[self.order[j - 1] as usize] > e {
                        self.order[j] = self.order[j - 1];
                        j -= 1;
                    }
                    self.order[j] = j0 as u8;
                    self.met += 1;
                }
            }
            if chunk.is_none() {
                return false;
            }
            if self.met > 0 {
                return true;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Clustered boxes in chunks, some unbounded, and rays of every kind: the chunk's union
    /// test answers exactly what the boxes' own tests answer, and it does skip chunks.
    #[test]
    fn chunk_unions_skip_only_what_every_box_misses() {
        let mut seed = 0x5eed_u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 40) as f64 / (1u64 << 24) as f64
        };
        let mut boxes = Vec::new();
        for i in 0..(5 * CHUNK + 17) {
            // Each chunk clustered around its own centre, so that rays can miss whole chunks.
            let c = (i / CHUNK) as f64 * 10.0;
            if i % 97 == 5 {
                boxes.push(None);
                continue;
            }
            let lo = [c + next() * 4.0, next() * 4.0, next() * 4.0];
            let hi = lo.map(|x| x + 0.01 + next());
            boxes.push(Some((lo, hi)));
        }
        // Without the unbounded ones too: then some chunks can be skipped.
        for with_unbounded in [true, false] {
            let list: Vec<_> = boxes
                .iter()
                .map(|b| {
                    if with_unbounded {
                        *b
                    } else {
                        b.or(Some(([0.0; 3], [1.0; 3])))
                    }
                })
                .collect();
            let m = MediaBoxes::new(list);
            let (mut skipped, mut rays) = (0, 0);
            for _ in 0..4000 {
                let o = [next() * 60.0 - 5.0, next() * 8.0 - 2.0, next() * 8.0 - 2.0];
                let mut d = [next() - 0.5, next() - 0.5, next() - 0.5];
                if next() < 0.2 {
                    d[(next() * 3.0) as usize % 3] = 0.0;
                }
                let t_max = if next() < 0.5 {
                    f32::INFINITY
                } else {
                    (next() * 20.0) as f32
                };
                let Some(ray) = RaySlabs::new(
                    Vec3::from_array(o.map(|x| x as f32)),
                    Vec3::from_array(d.map(|x| x as f32)),
                ) else {
                    continue;
                };
                rays += 1;
                let mut out = [0.0; CHUNK];
                for start in (0..m.len()).step_by(CHUNK) {
                    let n = m.entries(start, &ray, t_max, &mut out);
                    for (i, got) in out[..n].iter().enumerate() {
                        assert_eq!(
                            got.to_bits(),
                            m.entry_of(start + i, &ray, t_max).to_bits(),
                            "box {}",
                            start + i
                        );
                    }
                    let c = start / CHUNK;
                    let skip = slab_entry(m.chunk_lo[c], m.chunk_hi[c], &ray, t_max) == MISS;
                    let unbounded = with_unbounded && boxes[start..start + n].contains(&None);
                    assert!(
                        !(skip && unbounded),
                        "a chunk with an unbounded box is skipped"
                    );
                    skipped += usize::from(skip);
                }
            }
            assert!(rays > 3000);
            assert!(skipped > rays, "{skipped} chunks skipped over {rays} rays");
        }
    }

    fn unit() -> MediaBoxes {
        MediaBoxes::new([Some(([0.0; 3], [1.0; 3]))])
    }

    fn entry(b: &MediaBoxes, o: [f32; 3], d: [f32; 3], t_max: f32) -> Option<f32> {
        let r = RaySlabs::new(Vec3::from_array(o), Vec3::from_array(d))?;
        b.entry(0, &r, t_max)
    }

    fn close(a: Option<f32>, b: f32) -> bool {
        a.is_some_and(|a| (a - b).abs() <= 1e-4)
    }

    /// One box's test without the chunk buffer gives the chunk's value, bit for bit: 70
    /// random boxes (two chunks), rays from around them with zero and negative-zero
    /// direction components, three segment ends.
    #[test]
    fn entry_of_one_box_equals_the_chunk() {
        let mut rng = crate::render::rng::Pcg32::new(12, 4);
        let boxes = MediaBoxes::new((0..70).map(|_| {
            let lo = [0, 1, 2].map(|_| rng.next_f32() as f64 * 2.0 - 1.0);
            let hi = lo.map(|v| v + 0.05 + rng.next_f32() as f64);
            Some((lo, hi))
        }));
        let mut met = 0;
        for _ in 0..2_000 {
            let o = Vec3::from_array([0, 1, 2].map(|_| rng.next_f32() * 4.0 - 2.0));
            let mut d = [0, 1, 2].map(|_| rng.next_f32() - 0.5);
            if rng.next_f32() < 0.3 {
                d[(rng.next_u32() % 3) as usize] = if rng.next_f32() < 0.5 { 0.0 } else { -0.0 };
            }
            let Some(ray) = RaySlabs::new(o, Vec3::from_array(d)) else {
                continue;
            };
            for t_max in [0.7, 3.0, f32::INFINITY] {
                let mut out = [MISS; CHUNK];
                for start in [0, CHUNK] {
                    let n = boxes.entries(start, &ray, t_max, &mut out);
                    for (i, e) in out[..n].iter().enumerate() {
                        let one = boxes.entry_of(start + i, &ray, t_max);
                        assert_eq!(one.to_bits(), e.to_bits(), "box {}", start + i);
                        met += usize::from(*e != MISS);
                    }
                }
            }
        }
        assert!(met > 3_000, "{met} boxes met");
    }

    /// The shortcut of the wavefront loop: a point strictly inside is entered at 0 by every
    /// ray from it (random directions, axis-parallel ones, signed zeros); points on or
    /// beyond the padded faces, and NaN, are not "strictly inside".
    #[test]
    fn strictly_inside_means_entered_at_zero() {
        let b = unit();
        let mut rng = crate::render::rng::Pcg32::new(8, 1);
        let mut checked = 0;
        for _ in 0..20_000 {
            let o = [0, 1, 2].map(|_| -0.1 + 1.2 * rng.next_f32());
            let mut d = [0, 1, 2].map(|_| rng.next_f32() - 0.5);
            if rng.next_f32() < 0.3 {
                d[(rng.next_u32() % 3) as usize] = if rng.next_f32() < 0.5 { 0.0 } else { -0.0 };
            }
            if b.strictly_inside(0, Vec3::from_array(o)) {
                checked += 1;
                for t_max in [0.0, 0.5, f32::INFINITY] {
                    assert_eq!(entry(&b, o, d, t_max), Some(0.0), "{o:?} {d:?}");
                }
            }
        }
        assert!(checked > 10_000);
        let (lo, hi) = padded(Some(([0.0; 3], [1.0; 3]))).unwrap();
        assert!(!b.strictly_inside(0, Vec3::new(lo[0], 0.5, 0.5)));
        assert!(!b.strictly_inside(0, Vec3::new(0.5, hi[1], 0.5)));
        assert!(!b.strictly_inside(0, Vec3::new(0.5, 0.5, f32::NAN)));
        assert!(b.strictly_inside(0, Vec3::splat(0.5)));
    }

    #[test]
    fn through_behind_and_cut_short() {
        let b = unit();
        let inf = f32::INFINITY;
        // Straight through: entry at 1 (minus the padding).
        assert!(close(
            entry(&b, [-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], inf),
            1.0
        ));
        // Box behind the origin.
        assert_eq!(entry(&b, [2.0, 0.5, 0.5], [1.0, 0.0, 0.0], inf), None);
        // t_max before the box; just past the entry; exactly at the entry (closed ends).
        assert_eq!(entry(&b, [-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 0.99), None);
        assert!(entry(&b, [-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 1.001).is_some());
        assert!(entry(&b, [-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 1.0).is_some());
        // Infinite t_max from far away, oblique.
        let d = Vec3::new(1.0, 1.0, 1.0).normalize().to_array();
        assert!(entry(&b, [-1e6, -1e6, -1e6], d, inf).is_some());
        assert_eq!(entry(&b, [-1e6, -1e6 + 5.0, -1e6], d, inf), None);
    }

    #[test]
    fn starting_inside_or_on_the_surface() {
        let b = unit();
        let inf = f32::INFINITY;
        assert_eq!(entry(&b, [0.5; 3], [0.0, 0.0, -1.0], inf), Some(0.0));
        assert_eq!(entry(&b, [0.5; 3], [0.6, 0.0, 0.8], 1e-6), Some(0.0));
        // On a face going out, on an edge, on a corner going away: the closed box meets the
        // origin itself.
        assert_eq!(entry(&b, [0.5, 1.0, 0.5], [0.0, 1.0, 0.0], inf), Some(0.0));
        assert_eq!(entry(&b, [1.0, 1.0, 0.5], [1.0, 1.0, 0.0], inf), Some(0.0));
        assert_eq!(entry(&b, [1.0; 3], [1.0; 3], inf), Some(0.0));
        // Just outside the padding, going away.
        assert_eq!(entry(&b, [1.001, 0.5, 0.5], [1.0, 0.0, 0.0], inf), None);
    }

    #[test]
    fn grazing_and_parallel() {
        let b = unit();
        let inf = f32::INFINITY;
        // In the plane of a face, along it (d has zero components of both signs).
        assert!(entry(&b, [-1.0, 0.0, 0.5], [1.0, 0.0, 0.0], inf).is_some());
        assert!(entry(&b, [-1.0, 1.0, 0.5], [1.0, -0.0, 0.0], inf).is_some());
        // Along an edge; touching an edge in a single point: kept (conservative).
        assert!(entry(&b, [-1.0, 0.0, 1.0], [1.0, 0.0, 0.0], inf).is_some());
        assert!(entry(&b, [-1.0, 1.0, 0.5], [1.0, -1.0, 0.0], inf).is_some());
        // On the diagonal through the corners: towards the box kept, away from it skipped.
        assert!(close(entry(&b, [2.0; 3], [-1.0; 3], inf), 1.0));
        assert_eq!(entry(&b, [-1.0; 3], [-1.0; 3], inf), None);
        // Parallel outside a slab: never, whatever t_max.
        assert_eq!(entry(&b, [-1.0, 1.01, 0.5], [1.0, 0.0, 0.0], inf), None);
        assert_eq!(entry(&b, [-1.0, -0.01, 0.5], [1.0, -0.0, 0.0], inf), None);
        // Inside the padding of a face: kept; outside it: skipped.
        let pad = PAD_REL as f32;
        assert!(entry(&b, [-1.0, 1.0 + 0.5 * pad, 0.5], [1.0, 0.0, 0.0], inf).is_some());
        assert_eq!(
            entry(&b, [-1.0, 1.0 + 3.0 * pad, 0.5], [1.0, 0.0, 0.0], inf),
            None
        );
        // A slightly tilted ray from far away that dips 5e-6 below the top face inside the
        // box (kept), and one that stays above the padding (skipped).
        let d = Vec3::new(1.0, -1e-7, 0.0).normalize().to_array();
        assert!(close(entry(&b, [-100.0, 1.0 + 5e-6, 0.5], d, inf), 100.0));
        let above = 1.0 + 1e-5 + 8.0 * f32::EPSILON + 1.5e-5;
        assert_eq!(entry(&b, [-100.0, above, 0.5], d, inf), None);
    }

    #[test]
    fn degenerate_rays_are_never_skipped_by_mistake() {
        let b = unit();
        let inf = f32::INFINITY;
        // Zero, NaN and infinite rays: no decision (the caller asks every medium).
        for (o, d) in [
            ([5.0; 3], [0.0; 3]),
            ([5.0; 3], [-0.0; 3]),
            ([5.0; 3], [f32::NAN, 0.0, 1.0]),
            ([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0]),
            ([5.0; 3], [f32::INFINITY, 0.0, 0.0]),
            ([f32::NEG_INFINITY, 0.5, 0.5], [1.0, 0.0, 0.0]),
        ] {
            assert!(RaySlabs::new(Vec3::from_array(o), Vec3::from_array(d)).is_none());
        }
        // A subnormal component: 1/d overflows, the axis is parallel (as in the pin
        // sampler's chord): inside the slab kept, outside skipped.
        let r = RaySlabs::new(Vec3::new(0.5, 0.5, -1.0), Vec3::new(1e-40, 0.0, 1.0)).unwrap();
        assert!(close(b.entry(0, &r, inf), 1.0));
        let r = RaySlabs::new(Vec3::new(-1.0, 0.5, 0.5), Vec3::new(1e-40, 0.0, 1.0)).unwrap();
        assert_eq!(b.entry(0, &r, inf), None);
        // NaN t_max: no box is met, as no estimator sees a medium for it. The tracer never
        // passes one.
        for o in [Vec3::new(-1.0, 0.5, 0.5), Vec3::splat(0.5)] {
            let r = RaySlabs::new(o, Vec3::X).unwrap();
            assert_eq!(b.entry(0, &r, f32::NAN), None);
        }
        // Zero t_max at the origin inside: [0, 0] meets the box.
        let r = RaySlabs::new(Vec3::splat(0.5), Vec3::X).unwrap();
        assert_eq!(b.entry(0, &r, 0.0), Some(0.0));
    }

    #[test]
    fn unbounded_invalid_and_infinite_boxes() {
        let inf = f32::INFINITY;
        let boxes = MediaBoxes::new([
            None,
            Some(([f64::NAN, 0.0, 0.0], [1.0; 3])),
            Some(([1.0; 3], [0.0; 3])), // inverted
            Some(([f64::NEG_INFINITY, 0.0, 0.0], [f64::INFINITY, 1.0, 1.0])), // a bar along x
            Some(([10.0, 10.0, 10.0], [11.0, 11.0, 11.0])),
        ]);
        assert_eq!(boxes.len(), 5);
        let r = RaySlabs::new(Vec3::new(0.5, 5.0, 0.5), Vec3::Y).unwrap();
        // The first three are unbounded: always asked.
        for i in 0..3 {
            assert!(boxes.entry(i, &r, inf).is_some(), "{i}");
        }
        // Moving away from the bar along +y, and missing the far box.
        assert_eq!(boxes.entry(3, &r, inf), None);
        assert_eq!(boxes.entry(4, &r, inf), None);
        let r = RaySlabs::new(Vec3::new(1e30, 5.0, 0.5), Vec3::NEG_Y).unwrap();
        assert!(close(boxes.entry(3, &r, inf), 4.0));
        // Padding keeps a box around large coordinates conservative.
        let (lo, hi) = padded(Some(([1e6; 3], [1e6 + 1.0; 3]))).unwrap();
        assert!(f64::from(lo[0]) < 1e6 && f64::from(hi[0]) > 1e6 + 1.0);
        assert!(padded(Some(([0.0; 3], [0.0; 3]))).is_some(), "a point box");
    }
}
