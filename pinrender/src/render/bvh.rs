//! A bounding-volume hierarchy over the media's boxes that keeps the media order, so that a
//! ray's box tests grow with the media it meets rather than with the media in the scene.
//!
//! The tracer combines media in a fixed order: the transmittance product in media order,
//! the nearest-collision search per chunk of [`CHUNK`] media (see `Ctx::distance`), and each
//! medium draws from the path's generator when it is asked. So the hierarchy must hand out
//! the media a ray meets in media order, exactly those the linear scan meets. Its leaves are
//! therefore runs of consecutive media (at most [`LEAF`], never across a chunk boundary), an
//! inner node covers the run of its two children, and a depth-first walk that visits the
//! lower run first meets the leaves in media order. The nodes are stored in that walk's
//! order with an escape index each (the node after its subtree), so the walk needs no stack
//! and can stop after a leaf and resume (the wavefront loop keeps a search per path).
//!
//! A node's box is the exact f32 union of the padded boxes below it. The slab test is
//! monotone in the box (a smaller box gives a later entry and an earlier exit, in f32 as in
//! the reals; see `bounds.rs`), so a segment that misses a node misses every box
//! below it, and the leaves' boxes are then tested one by one with the linear scan's own
//! test: the boxes met, and their entries, are the linear scan's bit for bit.
//!
//! The build is deterministic (a function of the boxes alone): a run splits where the
//! surface-area cost `area(lower) * n_lower + area(upper) * n_upper` is least, among the
//! splits that leave each side at least a quarter of the run (so the depth is at most
//! `log_{4/3}` of the count and the build `O(n log n)`); ties go to the middle, then to the
//! lower index. The media are expected in a spatially coherent order (the scene loader lists
//! instances along a Morton curve); any order gives the same answers, only slower.

use std::ops::Range;

use super::slab::{CHUNK, MISS, RaySlabs, slab_entry};

/// The most media in a leaf.
pub(crate) const LEAF: usize = 4;

/// One node: its box, the node after its subtree, and for a leaf its run of media.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    /// The index of the first node after this node's subtree.
    escape: u32,
    /// A leaf's run `first..first + count`; `count == 0` for an inner node, whose lower child
    /// is the next node.
    first: u32,
    count: u32,
}

/// The hierarchy over the boxes of one `MediaBoxes` (`bounds.rs`).
#[derive(Clone, Debug, Default)]
pub(crate) struct Bvh {
    nodes: Vec<Node>,
}

/// Where a walk over a [`Bvh`] stands: the next node to test.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Walk {
    node: u32,
}

/// Surface area of a box (half of it: the factor cancels), infinite for an unbounded or
/// non-finite box.
fn area(lo: [f32; 3], hi: [f32; 3]) -> f64 {
    let e = [0, 1, 2].map(|a| f64::from(hi[a]) - f64::from(lo[a]));
    let s = e[0] * e[1] + e[1] * e[2] + e[2] * e[0];
    if s.is_finite() { s } else { f64::INFINITY }
}

fn grow(b: &mut ([f32; 3], [f32; 3]), lo: [f32; 3], hi: [f32; 3]) {
    for a in 0..3 {
        b.0[a] = b.0[a].min(lo[a]);
        b.1[a] = b.1[a].max(hi[a]);
    }
}

const EMPTY: ([f32; 3], [f32; 3]) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);

impl Bvh {
    /// The hierarchy over the boxes `lo[a][i]`, `hi[a][i]` (padded, struct of arrays, as
    /// `MediaBoxes` stores them), or `None` when there are too many to index by `u32`.
    pub(crate) fn build(lo: &[Vec<f32>; 3], hi: &[Vec<f32>; 3]) -> Option<Self> {
        let n = lo[0].len();
        if n > (u32::MAX / 4) as usize {
            return None;
        }
        let mut b = Builder {
            lo,
            hi,
            nodes: Vec::with_capacity(2 * n.div_ceil(LEAF) + 1),
            suffix: vec![0.0; n + 1],
        };
        if n > 0 {
            b.run(0, n);
        }
        Some(Bvh { nodes: b.nodes })
    }

    /// The next leaf of the walk whose box the segment `[0, t_max]` of `ray` meets, in media
    /// order: its run of media. `None` when the walk is over.
    #[inline]
    pub(crate) fn next_leaf(
        &self,
        walk: &mut Walk,
        ray: &RaySlabs,
        t_max: f32,
    ) -> Option<Range<usize>> {
        while let Some(n) = self.nodes.get(walk.node as usize) {
            if slab_entry(n.lo, n.hi, ray, t_max) == MISS {
                walk.node = n.escape;
            } else if n.count > 0 {
                walk.node = n.escape;
                return Some(n.first as usize..(n.first + n.count) as usize);
            } else {
                walk.node += 1;
            }
        }
        None
    }

    /// The nodes as the GPU path tracer walks them (`rt_bvh_*` in `render.wgsl`): eight
    /// words a node, the box's `lo` and `hi` (f32 bits), the escape index, and the leaf's
    /// run as `first | count << 29` (0 for an inner node). `None` when a run's first medium
    /// does not fit in 29 bits.
    #[cfg(feature = "gpu")]
    pub(crate) fn gpu_words(&self) -> Option<Vec<u32>> {
        const _: () = assert!(LEAF < 8, "a leaf's count is packed in 3 bits");
        let mut words = Vec::with_capacity(self.nodes.len() * 8);
        for n in &self.nodes {
            if n.first >= 1 << 29 {
                return None;
            }
            words.extend(n.lo.iter().chain(&n.hi).map(|v| v.to_bits()));
            words.push(n.escape);
            words.push(n.first | n.count << 29);
        }
        Some(words)
    }

    /// The number of nodes (for tests).
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.nodes.len()
    }

    /// The depth of the deepest leaf (for tests): the root is at depth 1.
    #[cfg(test)]
    pub(crate) fn depth(&self) -> usize {
        fn at(nodes: &[Node], i: usize) -> (usize, usize) {
            // (depth of the subtree at `i`, the node after it)
            let n = nodes[i];
            if n.count > 0 {
                return (1, i + 1);
            }
            let (l, next) = at(nodes, i + 1);
            let (r, end) = at(nodes, next);
            debug_assert_eq!(end, n.escape as usize);
            (1 + l.max(r), end)
        }
        if self.nodes.is_empty() {
            0
        } else {
            at(&self.nodes, 0).0
        }
    }
}

struct Builder<'a> {
    lo: &'a [Vec<f32>; 3],
    hi: &'a [Vec<f32>; 3],
    nodes: Vec<Node>,
    /// `suffix[k]`: the cost of the upper side `k..b` of the run being split.
    suffix: Vec<f64>,
}

impl Builder<'_> {
    fn bx(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        (
            [self.lo[0][i], self.lo[1][i], self.lo[2][i]],
            [self.hi[0][i], self.hi[1][i], self.hi[2][i]],
        )
    }

    /// Appends the subtree of the run `a..b` (`a < b`) in walk order.
    fn run(&mut self, a: usize, b: usize) {
        let at = self.nodes.len();
        self.nodes.push(Node {
            lo: EMPTY.0,
            hi: EMPTY.1,
            escape: 0,
            first: a as u32,
            count: 0,
        });
        let crosses_chunk = a / CHUNK != (b - 1) / CHUNK;
        let (whole, split) = if b - a <= LEAF && !crosses_chunk {
            let mut whole = EMPTY;
            for i in a..b {
                let (lo, hi) = self.bx(i);
                grow(&mut whole, lo, hi);
            }
            (whole, None)
        } else if b - a <= LEAF {
            // A short run across a chunk boundary: split there, so that no leaf straddles
            // two chunks of the nearest-collision search.
            let mut whole = EMPTY;
            for i in a..b {
                let (lo, hi) = self.bx(i);
                grow(&mut whole, lo, hi);
            }
            (whole, Some((a / CHUNK + 1) * CHUNK))
        } else {
            let (whole, k) = self.split(a, b);
            (whole, Some(k))
        };
        self.nodes[at].lo = whole.0;
        self.nodes[at].hi = whole.1;
        match split {
            None => self.nodes[at].count = (b - a) as u32,
            Some(k) => {
                self.run(a, k);
                self.run(k, b);
            }
        }
        self.nodes[at].escape = self.nodes.len() as u32;
    }

    /// The union of the run `a..b` and where it splits: the least surface-area cost among
    /// `k` in `[a + len / 4, b - len / 4]` (within `a + 1..b`), ties to the middle, then to
    /// the lower `k`.
    fn split(&mut self, a: usize, b: usize) -> (([f32; 3], [f32; 3]), usize) {
        let len = b - a;
        let (k_lo, k_hi) = ((a + len / 4).max(a + 1), (b - len / 4).min(b - 1));
        let mut upper = EMPTY;
        for k in (a..b).rev() {
            let (lo, hi) = self.bx(k);
            grow(&mut upper, lo, hi);
            self.suffix[k] = area(upper.0, upper.1) * (b - k) as f64;
        }
        let mid = a + len / 2;
        let mut lower = EMPTY;
        let mut best = (f64::INFINITY, mid);
        let mut mid_cost = f64::INFINITY;
        for k in a + 1..=k_hi {
            let (lo, hi) = self.bx(k - 1);
            grow(&mut lower, lo, hi);
            if k < k_lo {
                continue;
            }
            let cost = area(lower.0, lower.1) * (k - a) as f64 + self.suffix[k];
            if k == mid {
                mid_cost = cost;
            }
            if cost < best.0 {
                best = (cost, k);
            }
        }
        let k = if mid_cost <= best.0 { mid } else { best.1 };
        (upper, k)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::bounds::MediaBoxes;
    use glam::Vec3;
    use proptest::prelude::*;

    /// Boxes clustered like instances of a cloudscape: centres in a slab, sizes varying,
    /// some unbounded or inverted (which the tracer keeps as infinite boxes).
    fn boxes_from(seed: u64, n: usize) -> Vec<Option<([f64; 3], [f64; 3])>> {
        let mut rng = crate::render::rng::Pcg32::new(seed, 7);
        (0..n)
            .map(|_| {
                let u = rng.next_f32();
                if u < 0.01 {
                    return None;
                }
                let c = [
                    rng.next_f64() * 100.0,
                    rng.next_f64() * 10.0,
                    rng.next_f64() * 100.0,
                ];
                let s = 0.5 + rng.next_f64() * rng.next_f64() * 8.0;
                Some((c.map(|x| x - s), c.map(|x| x + s)))
            })
            .collect()
    }

    fn ray_from(
        v: &[f32; 7],
        boxes: &MediaBoxes,
        on_face: Option<usize>,
    ) -> Option<(RaySlabs, f32)> {
        let mut o = Vec3::new(v[0] * 140.0 - 20.0, v[1] * 30.0 - 10.0, v[2] * 140.0 - 20.0);
        let mut d = Vec3::new(v[3] - 0.5, v[4] - 0.5, v[5] - 0.5);
        // Zero components of either sign, and origins exactly on a box's padded face: the
        // slab test's parallel and NaN cases.
        if v[6] < 0.3 {
            d.x = if v[6] < 0.15 { 0.0 } else { -0.0 };
        }
        if let Some(i) = on_face {
            let (lo, hi) = boxes.box_of(i);
            o.x = if v[0] < 0.5 { lo[0] } else { hi[0] };
        }
        let t_max = if v[6] > 0.6 {
            (v[6] - 0.6) * 200.0
        } else {
            f32::INFINITY
        };
        Some((RaySlabs::new(o, d)?, t_max))
    }

    /// The boxes a walk of the hierarchy meets, in the order met, with their entries.
    fn walked(boxes: &MediaBoxes, bvh: &Bvh, ray: &RaySlabs, t_max: f32) -> Vec<(usize, u32)> {
        let mut out = Vec::new();
        let mut walk = Walk::default();
        let mut last_end = 0;
        while let Some(run) = bvh.next_leaf(&mut walk, ray, t_max) {
            assert!(run.start >= last_end, "leaves in media order");
            assert_eq!(
                run.start / CHUNK,
                (run.end - 1) / CHUNK,
                "a leaf within a chunk"
            );
            last_end = run.end;
            for i in run {
                let e = boxes.entry_of(i, ray, t_max);
                if e != MISS {
                    out.push((i, e.to_bits()));
                }
            }
        }
        out
    }

    fn brute(boxes: &MediaBoxes, ray: &RaySlabs, t_max: f32) -> Vec<(usize, u32)> {
        (0..boxes.len())
            .filter_map(|i| {
                let e = boxes.entry_of(i, ray, t_max);
                (e != MISS).then_some((i, e.to_bits()))
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// The walk meets exactly the boxes (and entries) that testing every box meets, in
        /// media order, for random scenes of up to a few chunks and random rays of every
        /// kind (parallel axes, signed zeros, origins on faces, finite and infinite ends).
        #[test]
        fn walk_meets_exactly_the_boxes_brute_force_meets(
            seed in any::<u64>(),
            n in 1usize..400,
            rays in proptest::collection::vec(proptest::array::uniform7(0.0f32..1.0), 64),
            face in any::<bool>(),
        ) {
            let list = boxes_from(seed, n);
            let boxes = MediaBoxes::linear(list.clone());
            let (lo, hi) = boxes.soa();
            let bvh = Bvh::build(lo, hi).unwrap();
            prop_assert!(bvh.len() < 2 * n + 1);
            for (j, v) in rays.iter().enumerate() {
                let on_face = face.then_some(j % n).filter(|i| list[*i].is_some());
                let Some((ray, t_max)) = ray_from(v, &boxes, on_face) else { continue };
                prop_assert_eq!(walked(&boxes, &bvh, &ray, t_max), brute(&boxes, &ray, t_max));
            }
        }
    }

    /// Deterministic, shallow, and it prunes: the same boxes give the same nodes; the depth
    /// stays within `log_{4/3}`; a thin ray through 4,096 boxes tests far fewer nodes than
    /// boxes.
    #[test]
    fn build_is_deterministic_shallow_and_prunes() {
        // In a spatial order (by 10-unit column of x, then z), as the scene loader lists
        // instances.
        let mut list = boxes_from(3, 4096);
        let key = |b: &Option<([f64; 3], [f64; 3])>| {
            b.map_or((-1, 0.0), |(lo, _)| ((lo[0] / 10.0) as i64, lo[2]))
        };
        list.sort_by(|a, b| key(a).partial_cmp(&key(b)).unwrap());
        let boxes = MediaBoxes::linear(list);
        let (lo, hi) = boxes.soa();
        let a = Bvh::build(lo, hi).unwrap();
        let b = Bvh::build(lo, hi).unwrap();
        assert_eq!(format!("{:?}", a.nodes), format!("{:?}", b.nodes));
        let bound = (4096f64 / LEAF as f64).ln() / (4.0f64 / 3.0).ln() + 2.0;
        assert!(a.depth() as f64 <= bound, "depth {} > {bound}", a.depth());
        assert!(
            Bvh::build(&Default::default(), &Default::default())
                .unwrap()
                .nodes
                .is_empty()
        );
        // A ray along x at mid height meets the boxes near z = 50 (about one in twenty) and
        // the unbounded ones; the walk reaches few more leaves than boxes met.
        let ray = RaySlabs::new(Vec3::new(-10.0, 5.0, 50.0), Vec3::X).unwrap();
        let met = brute(&boxes, &ray, f32::INFINITY).len();
        let mut walk = Walk::default();
        let mut leaves = 0;
        while a.next_leaf(&mut walk, &ray, f32::INFINITY).is_some() {
            leaves += 1;
        }
        assert!(
            met > 50 && leaves <= 2 * met && leaves < 4096 / LEAF / 4,
            "{leaves} leaves, {met} met"
        );
    }
}
