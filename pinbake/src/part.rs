//! A farm bake that splits the volume: part `I` of `N` (`pinbake bake --part I/N`) holds only
//! its z-slab of the source (a VDB reads only that slab's leaves: `VdbOptions::part`), takes
//! the samples of every pin that lie in the slab, and writes them to a part file
//! ([`crate::part_file`]). [`merge_parts`] adds every pin's samples in the order a monolithic
//! bake adds them and then draws the masks as the bake does, so the merged file has the
//! monolithic bake's bytes whatever `N` (docs/farm.md).
//!
//! Why samples and not partial optical depths: the bake sums an interval's samples one after
//! the other in f64, and a float sum cut at a slab boundary and added back rounds differently.
//! Each sample is exact on its own (a function of the pin and of the field around one point),
//! so the parts exchange samples and the merge repeats the bake's sum; the bake's bytes stay
//! as they are. A pin's samples are ordered along its direction (z >= 0), so each slab holds
//! one contiguous run of them ([`owned_range`]).

use std::ops::Range;
use std::time::Instant;

use glam::DVec3;
use pin_format::layout::GRID_FLAG_JITTERED_PINS;
use pin_format::{Directions, GridDesc, MajorantHeader, Metadata, OwnedPinGrid, PinEntry};
use rayon::prelude::*;

use crate::alloc::{try_filled, try_reserved};
use crate::bake::{BakeOptions, BakeStats};
use crate::error::BakeError;
use crate::pin::{
    ChordSamples, GRID_WHOLE_PIN_STEPS, INTERVALS, IntervalSums, PinLayout, Placement,
    chord_samples, make_entry, source_runs,
};
use pin_volume::{Aabb, DenseGrid, DensitySource, identity};

pub use pin_volume::part_facts::{LeafSummary, PartFacts};

/// Part `index` of `count` of a bake split by volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Part {
    pub index: u32,
    pub count: u32,
}

/// The most parts a bake splits into (`--part I/N`, [`PartData::part`] of a part file). Every
/// part reads the whole tree's topology and hashes the whole input, and the merge holds every
/// part's identity lattice (160 KiB each: 160 MiB at this count), so a larger split costs
/// more than it saves; a part count above it in a part file is damage.
pub const MAX_PARTS: u32 = 1024;

/// What one part computed: with the other parts, everything the merge needs.
#[derive(Clone, Debug, PartialEq)]
pub struct PartData {
    pub part: Part,
    /// The grid description a monolithic bake writes, `stored_cells` 0.
    pub desc: GridDesc,
    /// The metadata a monolithic bake writes, except that its content hash
    /// ([`identity::KEY_CONTENT`]) is empty: the merge computes it from the lattice.
    pub metadata: Metadata,
    /// `[lo, hi)` in the bake frame's z: the pins' samples this part took.
    pub slab: [f64; 2],
    /// The samples are a dense grid's march (a dense source or the dense copy of a sparse
    /// one) rather than the source's `extinction_along`: parts that disagree do not merge.
    pub grid_march: bool,
    /// The majorant's bricks and this part's maxima in them (the merge takes the largest).
    pub majorant: Option<([u32; 3], Vec<f32>)>,
    /// The identity lattice's values ([`identity::lattice_values`]) at the points this part
    /// owns (those in its slab), 0 elsewhere, and 1 where it owns the point.
    pub lattice: Vec<f32>,
    pub lattice_owned: Vec<u8>,
    /// The samples of every pin in the slab, pin after pin in the file's order (cells x
    /// fastest, then direction, then pin of the entry).
    pub samples: Vec<f32>,
    /// A voxel grid's facts ([`DensitySource::part_facts`]); `None` for a source read whole.
    pub facts: Option<PartFacts>,
}

/// Why parts do not merge. Messages are one line and name the part.
#[derive(Debug, thiserror::Error)]
pub enum PartError {
    #[error("no parts given")]
    Empty,
    #[error("{name}: {problem}")]
    Mismatch { name: String, problem: String },
    #[error("parts do not cover the volume: {0}")]
    Coverage(String),
    #[error(
        "merging the parts needs about {need} bytes for the merged grid, more than the {limit} bytes the memory budget (--max-memory) leaves beside the part files"
    )]
    Memory { need: u64, limit: u64 },
    #[error(transparent)]
    Bake(#[from] BakeError),
}

const CHUNK: usize = GRID_WHOLE_PIN_STEPS;

/// How the bake samples the field: the source's `extinction_along`, or a dense grid's march.
#[derive(Clone, Copy)]
enum March<'a> {
    Source(&'a dyn DensitySource),
    Grid(&'a DenseGrid),
}

impl March<'_> {
    /// Appends samples `range` of the pin `cs` (sample `k` is sample `k % steps` of interval
    /// `k / steps`) with the bits the bake's march gives them (`pin::field_optical_depths`):
    /// the same chunk bases and steps.
    fn samples(
        &self,
        cs: &ChordSamples,
        range: Range<usize>,
        buf: &mut [f32; CHUNK],
        out: &mut Vec<f32>,
    ) {
        if range.is_empty() {
            return;
        }
        match *self {
            March::Source(source) => source_samples(source, cs, range, buf, out),
            March::Grid(grid) => grid_samples(grid, cs, range, out),
        }
    }
}

/// [`March::samples`] of a source: the runs `pin::field_optical_depths` reads.
fn source_samples(
    source: &dyn DensitySource,
    cs: &ChordSamples,
    range: Range<usize>,
    buf: &mut [f32; CHUNK],
    out: &mut Vec<f32>,
) {
    source_runs(source, cs, range.clone(), buf, |k0, run| {
        let (a, b) = (range.start.max(k0), range.end.min(k0 + run.len()));
        out.extend_from_slice(&run[a - k0..b - k0]);
    });
}

/// [`March::samples`] of a dense grid: the march of `pin::field_optical_depths`, one f64 base
/// per interval (and per `CHUNK` samples of a longer one), f32 steps from there.
fn grid_samples(grid: &DenseGrid, cs: &ChordSamples, range: Range<usize>, out: &mut Vec<f32>) {
    let steps = cs.steps;
    let f32x3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
    let (ua, ub) = (grid.index_of(cs.origin), grid.index_dir(cs.world_dir));
    let du = ub * cs.h;
    let duf = f32x3(du);
    for i in range.start / steps..=(range.end - 1) / steps {
        let js = range.start.max(i * steps) - i * steps..range.end.min((i + 1) * steps) - i * steps;
        let start = ua + ub * (cs.s0 + cs.ds * i as f64) + du * 0.5;
        if steps <= CHUNK {
            // The whole pin in one march: one f32 base per interval.
            grid.run_samples(f32x3(start), duf, js, out);
        } else {
            // Chunks of the interval that hold samples of `js`: sample `j` is sample `j - j0`
            // of the chunk from `j0`.
            let mut j0 = js.start / CHUNK * CHUNK;
            while j0 < js.end {
                let n = (steps - j0).min(CHUNK);
                let (a, b) = (js.start.max(j0), js.end.min(j0 + n));
                grid.run_samples(f32x3(start + du * j0 as f64), duf, a - j0..b - j0, out);
                j0 += n;
            }
        }
    }
}

/// The optical depths the bake computes from pin `cs`'s `samples` (all of them, in order):
/// each interval's samples summed in f64 one after the other in chunks of [`CHUNK`] (a
/// fresh sum per chunk, added to the interval's), times the sample weight. One rule for both
/// marches of `pin::field_optical_depths`: a whole-pin dense march adds to a sum that starts
/// at +0.0, which the chunk's sum added to +0.0 equals bit for bit.
pub(crate) fn optical_depths(samples: &[f32], cs: &ChordSamples) -> [f64; INTERVALS] {
    let mut sums = IntervalSums::new(cs.steps);
    sums.extend(samples);
    sums.finish(cs.weight)
}

/// The samples `[a, b)` of pin `cs` whose position lies in `slab` (z in `[lo, hi)` of the
/// bake frame), by one rule that every part and the merge apply: the slabs of a bake share
/// their boundaries bit for bit, so the pieces of one pin tile its samples exactly.
pub(crate) fn owned_range(cs: &ChordSamples, slab: [f64; 2]) -> (usize, usize) {
    let total = INTERVALS * cs.steps;
    let z = |k: usize| {
        let (i, j) = (k / cs.steps, k % cs.steps);
        cs.origin.z + cs.world_dir.z * (cs.s0 + cs.ds * i as f64 + cs.h * (j as f64 + 0.5))
    };
    // The first `k` for which `pred` fails, `pred` holding for a prefix.
    let first_not = |pred: &dyn Fn(usize) -> bool| {
        let (mut lo, mut hi) = (0, total);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if pred(mid) {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        lo
    };
    if cs.world_dir.z >= 0.0 {
        (
            first_not(&|k| z(k) < slab[0]),
            first_not(&|k| z(k) < slab[1]),
        )
    } else {
        (
            first_not(&|k| z(k) >= slab[1]),
            first_not(&|k| z(k) >= slab[0]),
        )
    }
}

/// Slab `part` of an even split of `bbox` along z, open below for the first part and above
/// for the last: the split of a source that holds the whole field (a dense or procedural one).
fn even_slab(bbox: &Aabb, part: Part) -> [f64; 2] {
    let cut = |b: u32| {
        if b == 0 {
            f64::NEG_INFINITY
        } else if b == part.count {
            f64::INFINITY
        } else {
            bbox.min.z + bbox.extent().z * f64::from(b) / f64::from(part.count)
        }
    };
    [cut(part.index), cut(part.index + 1)]
}

fn check(part: Part, opts: &BakeOptions) -> Result<(), BakeError> {
    if part.count == 0 || part.index >= part.count || part.count > MAX_PARTS {
        return Err(BakeError::Options(format!(
            "part {}/{} out of range (at most {MAX_PARTS} parts)",
            part.index, part.count
        )));
    }
    if opts.tile.is_some() {
        return Err(BakeError::Options("a part bake takes no --tile".into()));
    }
    if opts.embed_density.is_some() {
        return Err(BakeError::Options(
            "--embed-density is not available in a part bake (--part)".into(),
        ));
    }
    if opts.embed_control.is_some() {
        return Err(BakeError::Options(
            "--embed-control is not available in a part bake (--part)".into(),
        ));
    }
    crate::bake::check_step(opts)
}

/// Where a part's samples go as they are taken: [`SampleSink::start`] once with everything
/// of the part but its samples, then [`SampleSink::samples`] with the samples in the part
/// file's order, batch after batch, so that a part written to a file never holds them all.
pub trait SampleSink {
    /// `head` is the part with `samples` empty; `total` samples follow.
    fn start(&mut self, head: &PartData, total: u64) -> Result<(), BakeError>;
    fn samples(&mut self, samples: &[f32]) -> Result<(), BakeError>;
}

/// The samples kept in memory ([`bake_part`]).
struct InMemory(Vec<f32>);

impl SampleSink for InMemory {
    fn start(&mut self, _: &PartData, total: u64) -> Result<(), BakeError> {
        self.0 = try_reserved("the part's samples", total as usize)?;
        Ok(())
    }
    fn samples(&mut self, samples: &[f32]) -> Result<(), BakeError> {
        self.0.extend_from_slice(samples);
        Ok(())
    }
}

/// Bakes part `part` of `source` with `opts`: the samples of every pin in the part's slab
/// (the source's [`DensitySource::part_slab`], or an even split of the box along z for a
/// source that holds the whole field), the majorant over what it holds, the identity
/// lattice's points in the slab. `progress` hears of the pins done.
pub fn bake_part(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    part: Part,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<PartData, BakeError> {
    let mut sink = InMemory(Vec::new());
    let mut data = bake_part_into(source, opts, part, progress, &mut sink)?;
    data.samples = sink.0;
    Ok(data)
}

/// [`bake_part`], with the samples handed to `sink` as they are taken (the part comes back
/// with `samples` empty).
pub fn bake_part_into(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    part: Part,
    progress: &(dyn Fn(u64) + Sync),
    sink: &mut (dyn SampleSink + Send),
) -> Result<PartData, BakeError> {
    bake_part_batched(source, opts, part, progress, sink, SAMPLE_BATCH)
}

/// [`bake_part_into`] with at most `batch` samples a batch (or one row's, when a row has more).
pub(crate) fn bake_part_batched(
    source: &dyn DensitySource,
    opts: &BakeOptions,
    part: Part,
    progress: &(dyn Fn(u64) + Sync),
    sink: &mut (dyn SampleSink + Send),
    batch: usize,
) -> Result<PartData, BakeError> {
    check(part, opts)?;
    let pool = crate::bake::thread_pool(opts)?;
    pool.install(|| {
        let frame = source.bake_frame();
        let (local, local_to_world) = match &frame {
            Some((local, m)) => (local.as_ref(), Some(*m)),
            None => (source, None),
        };
        part_in_pool(
            (source, local, local_to_world),
            opts,
            part,
            progress,
            sink,
            batch,
        )
    })
}

/// Samples taken in one batch of rows: the most a part holds of them at once.
const SAMPLE_BATCH: usize = 4 << 20;

fn part_in_pool(
    (world, source, local_to_world): (&dyn DensitySource, &dyn DensitySource, Option<[f64; 12]>),
    opts: &BakeOptions,
    part: Part,
    progress: &(dyn Fn(u64) + Sync),
    sink: &mut (dyn SampleSink + Send),
    batch: usize,
) -> Result<PartData, BakeError> {
    let (bbox, mut desc) = crate::bake::grid_description(source, opts)?;
    let slab = source.part_slab().unwrap_or_else(|| even_slab(&bbox, part));
    let placement = Placement::over(&bbox, opts.step);
    // The same choice of march as the bake's (`bake::bake_in_pool`).
    let copy = match source.as_dense_grid() {
        Some(_) => None,
        None => source.dense_copy(crate::bake::dense_copy_limit(opts)),
    };
    let march = match (&copy, source.as_dense_grid()) {
        (Some(c), _) => March::Grid(c),
        (None, Some(g)) => March::Grid(g),
        (None, None) => March::Source(source),
    };
    let layout = layout_of(
        opts.cells,
        opts.directions,
        opts.pins_per_entry,
        opts.jitter_pins,
        opts.seed,
    );
    let nx = opts.cells[0];
    let (dirs, ppe) = (opts.directions.count(), opts.pins_per_entry);
    // Everything but the samples first: the part file holds it before them.
    let majorant = opts
        .majorant
        .map(|dims| crate::bake::bake_majorant(source, &bbox, dims).map(|(h, v)| (h.dims, v)))
        .transpose()?;
    let mut metadata = opts.metadata.clone();
    for (k, v) in &mut metadata.extra {
        if k == identity::KEY_CONTENT {
            v.clear();
        }
    }
    if let Some(m) = local_to_world {
        desc.local_to_world = m;
    }
    let (lattice, lattice_owned) = lattice_part(world, local_to_world, slab);
    let head = PartData {
        part,
        desc,
        metadata,
        slab,
        grid_march: matches!(march, March::Grid(_)),
        majorant,
        lattice,
        lattice_owned,
        samples: Vec::new(),
        facts: source.part_facts(),
    };
    // The samples are counted first: the file states their number before them, and each
    // batch of rows is one allocation that the rows fill in place.
    let counts: Vec<usize> = row_counts(&layout, &placement, &[slab])
        .into_iter()
        .map(|c| c[0])
        .collect();
    sink.start(&head, counts.iter().map(|&c| c as u64).sum())?;
    let largest = counts.iter().copied().max().unwrap_or(0);
    let mut buffer = try_filled(
        "a batch of the part's samples",
        SAMPLE_BATCH.max(largest),
        0f32,
    )?;
    let mut row0 = 0usize;
    while row0 < counts.len() {
        let (mut row1, mut n) = (row0, 0usize);
        while row1 < counts.len() && (row1 == row0 || n + counts[row1] <= batch) {
            n += counts[row1];
            row1 += 1;
        }
        let mut slices: Vec<&mut [f32]> = Vec::with_capacity(row1 - row0);
        let mut rest = &mut buffer[..n];
        for &c in &counts[row0..row1] {
            let (row, tail) = rest.split_at_mut(c);
            slices.push(row);
            rest = tail;
        }
        slices.into_par_iter().enumerate().for_each(|(i, slice)| {
            let mut out = Vec::with_capacity(slice.len());
            let mut buf = [0f32; CHUNK];
            for_each_chord_in_row(&layout, &placement, row0 + i, |cs| {
                let (a, b) = owned_range(cs, slab);
                march.samples(cs, a..b, &mut buf, &mut out);
            });
            slice.copy_from_slice(&out);
            progress(u64::from(nx) * u64::from(dirs) * u64::from(ppe));
        });
        sink.samples(&buffer[..n])?;
        row0 = row1;
    }
    Ok(head)
}

fn layout_of(
    dims: [u32; 3],
    directions: Directions,
    pins_per_entry: u32,
    jitter: bool,
    seed: u64,
) -> PinLayout {
    PinLayout {
        dims,
        directions,
        pins_per_entry,
        jitter,
        seed,
    }
}

/// The identity lattice of `source` at the points whose bake-frame z lies in `slab`.
fn lattice_part(
    source: &dyn DensitySource,
    local_to_world: Option<[f64; 12]>,
    slab: [f64; 2],
) -> (Vec<f32>, Vec<u8>) {
    let mut values = identity::lattice_values(source);
    let b = source.bounds();
    let n = identity::LATTICE;
    let size = (b.max - b.min) / n as f64;
    // Frame z of a world point: the rigid placement's inverse, `Q^T (p - t)`.
    let frame_z = |p: DVec3| match local_to_world {
        None => p.z,
        Some(m) => m[2] * (p.x - m[3]) + m[6] * (p.y - m[7]) + m[10] * (p.z - m[11]),
    };
    let mut owned = vec![0u8; values.len()];
    for (r, (row, own)) in values.chunks_mut(n).zip(owned.chunks_mut(n)).enumerate() {
        let start = identity::lattice_row_start(b, r % n, r / n);
        for (x, (v, o)) in row.iter_mut().zip(own.iter_mut()).enumerate() {
            // The point `extinction_along` sampled.
            let z = frame_z(start + DVec3::new(size.x, 0.0, 0.0) * x as f64);
            if z >= slab[0] && z < slab[1] {
                *o = 1;
            } else {
                *v = 0.0;
            }
        }
    }
    (values, owned)
}

/// Calls `f` with the chord of every pin of row `row` of cells (`y + ny * z`) that crosses
/// the box, in file order (x, then direction, then pin): the order of a part's samples.
fn for_each_chord_in_row(
    layout: &PinLayout,
    placement: &Placement,
    row: usize,
    mut f: impl FnMut(&ChordSamples),
) {
    let [nx, ny, _] = layout.dims;
    let (dirs, ppe) = (layout.directions.count(), layout.pins_per_entry);
    let (y, z) = ((row % ny as usize) as u32, (row / ny as usize) as u32);
    for x in 0..nx {
        for dir in 0..dirs {
            for k in 0..ppe {
                let cell = [x, y, z];
                let mut rng = layout.rng(layout.cell_linear(cell), dir, k);
                let (p, w) = layout.line(cell, dir, &mut rng);
                if let Some(cs) = chord_samples(placement, p, w) {
                    f(&cs);
                }
            }
        }
    }
}

/// For each row of cells (`y + ny * z`), the number of its pins' samples in each of
/// `slabs`: where each row's samples start in a part's file.
fn row_counts(layout: &PinLayout, placement: &Placement, slabs: &[[f64; 2]]) -> Vec<Vec<usize>> {
    let [_, ny, nz] = layout.dims;
    (0..ny as usize * nz as usize)
        .into_par_iter()
        .map(|row| {
            let mut c = vec![0usize; slabs.len()];
            for_each_chord_in_row(layout, placement, row, |cs| {
                for (c, s) in c.iter_mut().zip(slabs) {
                    let (a, b) = owned_range(cs, *s);
                    *c += b - a;
                }
            });
            c
        })
        .collect()
}

/// Joins parts (any order) into the grid a monolithic bake with their options writes, and
/// its statistics. `parts` are named for messages. Refused: parts of different bakes (grid
/// description, metadata, march or majorant size differ), a part missing or given twice,
/// slabs that do not tile the volume, a part whose sample count is not what the grid needs.
pub fn merge_parts(parts: &[(String, PartData)]) -> Result<(OwnedPinGrid, BakeStats), PartError> {
    merge_parts_within(parts, None)
}

/// [`merge_parts`] refusing, before it allocates them, a grid and tables of more than
/// `max_memory` bytes (what the merge holds beside the parts themselves).
pub fn merge_parts_within(
    parts: &[(String, PartData)],
    max_memory: Option<u64>,
) -> Result<(OwnedPinGrid, BakeStats), PartError> {
    let started = Instant::now();
    let (first_name, first) = parts.first().ok_or(PartError::Empty)?;
    let count = first.part.count;
    let mismatch = |name: &str, problem: String| PartError::Mismatch {
        name: name.to_string(),
        problem,
    };
    for (name, p) in parts {
        if p.part.count != count {
            return Err(mismatch(
                name,
                format!(
                    "is part of {} but {first_name} is part of {count}",
                    p.part.count
                ),
            ));
        }
        let what = if bytemuck::bytes_of(&p.desc) != bytemuck::bytes_of(&first.desc) {
            Some("grid description (cells, directions, box, step, seed or flags)")
        } else if p.metadata != first.metadata {
            Some("metadata (source, options)")
        } else if p.grid_march != first.grid_march {
            Some("way of marching (dense copy or tree)")
        } else if p.majorant.as_ref().map(|m| m.0) != first.majorant.as_ref().map(|m| m.0) {
            Some("majorant grid")
        } else if p.lattice.len() != first.lattice.len() {
            Some("identity lattice")
        } else if p
            .facts
            .map(|f| (f.grid, f.negative_values, f.tile_negative_values))
            != first
                .facts
                .map(|f| (f.grid, f.negative_values, f.tile_negative_values))
        {
            Some("grid statistics (non-zero leaves, their box and largest value, negative values)")
        } else {
            None
        };
        if let Some(what) = what {
            return Err(mismatch(name, format!("{what} differs from {first_name}")));
        }
    }
    // The part count comes from a file: nothing is sized by it. The parts given, sorted by
    // index, must be 0, 1, ... count - 1.
    let mut by_index: Vec<(u32, &str)> = parts
        .iter()
        .map(|(name, p)| (p.part.index, name.as_str()))
        .collect();
    by_index.sort_unstable();
    for (name, p) in parts {
        if p.part.index >= count {
            return Err(mismatch(
                name,
                format!("part {} of {count} out of range", p.part.index),
            ));
        }
    }
    for w in by_index.windows(2) {
        if w[0].0 == w[1].0 {
            return Err(PartError::Coverage(format!(
                "part {} of {count} is given twice ({} and {})",
                w[0].0, w[0].1, w[1].1
            )));
        }
    }
    if by_index.len() != count as usize {
        let i = by_index
            .iter()
            .zip(0u32..)
            .find(|((index, _), i)| index != i)
            .map_or(by_index.len() as u32, |(_, i)| i);
        return Err(PartError::Coverage(format!(
            "part {i} of {count} is missing ({} of {count} given)",
            parts.len()
        )));
    }
    // The slabs, bottom to top, must tile the line.
    let mut order: Vec<&(String, PartData)> = parts.iter().collect();
    order.sort_by(|a, b| {
        a.1.slab[0]
            .total_cmp(&b.1.slab[0])
            .then(a.1.slab[1].total_cmp(&b.1.slab[1]))
    });
    let mut z = f64::NEG_INFINITY;
    for (name, p) in &order {
        if p.slab[0] != z || !(p.slab[0] <= p.slab[1]) {
            return Err(PartError::Coverage(format!(
                "{name} holds z {} .. {} but z {z} is next",
                p.slab[0], p.slab[1]
            )));
        }
        z = p.slab[1];
    }
    if z != f64::INFINITY {
        return Err(PartError::Coverage(format!("no part holds z from {z} up")));
    }
    let slabs: Vec<[f64; 2]> = order.iter().map(|(_, p)| p.slab).collect();
    check_facts(first_name, &order)?;

    // The identity: each lattice point from its one owner.
    let mut metadata = first.metadata.clone();
    let mut lattice = vec![0f32; first.lattice.len()];
    for (i, v) in lattice.iter_mut().enumerate() {
        let owners: Vec<&PartData> = order
            .iter()
            .map(|(_, p)| p)
            .filter(|p| p.lattice_owned.get(i) == Some(&1))
            .collect();
        match owners.as_slice() {
            [one] => *v = one.lattice[i],
            _ => {
                return Err(PartError::Coverage(format!(
                    "identity lattice point {i} is held by {} parts, not one",
                    owners.len()
                )));
            }
        }
    }
    if let Some(Ok(id)) = identity::SourceIdentity::from_extra(&{
        // `from_extra` checks the hash's form: any 32 hex digits stand in for the one to come.
        let mut e = metadata.extra.clone();
        for (k, v) in &mut e {
            if k == identity::KEY_CONTENT {
                *v = "0".repeat(32);
            }
        }
        e
    }) {
        let b = Aabb::new(DVec3::from(id.box_min), DVec3::from(id.box_max));
        let content = identity::content_hash(b, &lattice);
        for (k, v) in &mut metadata.extra {
            if k == identity::KEY_CONTENT {
                *v = content.clone();
            }
        }
    }

    let majorant = first.majorant.as_ref().map(|(dims, v0)| {
        let mut m = v0.clone();
        for (_, p) in &order {
            if let Some((_, v)) = &p.majorant {
                for (a, b) in m.iter_mut().zip(v) {
                    *a = a.max(*b);
                }
            }
        }
        (
            MajorantHeader {
                dims: *dims,
                reserved: 0,
            },
            m,
        )
    });

    // The pins: the bake's geometry again, each pin's samples gathered from the parts.
    let desc = first.desc;
    let directions = Directions::from_desc(desc.direction_kind, desc.direction_res)
        .map_err(|e| mismatch(first_name, format!("directions: {e}")))?;
    let layout = layout_of(
        desc.dims,
        directions,
        desc.pins_per_entry,
        desc.flags & GRID_FLAG_JITTERED_PINS != 0,
        desc.seed,
    );
    // The description comes from a file: its counts, box and step are checked before any
    // work they size.
    pin_format::GridShape::new(&desc, None)
        .map_err(|e| mismatch(first_name, format!("grid description: {e}")))?;
    crate::limits::check_rel_step(desc.step_size)
        .map_err(|e| mismatch(first_name, format!("step: {e}")))?;
    let bbox = Aabb::new(DVec3::from(desc.box_min), DVec3::from(desc.box_max));
    if !bbox.is_valid() {
        return Err(mismatch(
            first_name,
            format!("box {bbox:?} is empty or not finite"),
        ));
    }
    let placement = Placement::over(&bbox, desc.step_size);
    let [nx, ny, nz] = desc.dims;
    let (dirs, ppe) = (directions.count(), desc.pins_per_entry);
    let block_len = dirs as usize * ppe as usize;
    let rows = ny as usize * nz as usize;
    let pins = (rows as u64)
        .checked_mul(u64::from(nx))
        .and_then(|v| v.checked_mul(block_len as u64))
        .filter(|&v| v <= (isize::MAX as u64) / 8)
        .ok_or_else(|| mismatch(first_name, "grid has more pins than memory can hold".into()))?
        as usize;
    if let Some(limit) = max_memory {
        let need = merge_bytes(pins, rows, slabs.len(), first.lattice.len());
        if need > limit {
            return Err(PartError::Memory { need, limit });
        }
    }
    // The pins first: a grid too large for memory is refused before the passes over it.
    let mut dense = try_filled("the pins", pins, PinEntry::EMPTY)?;
    let pin = |row: usize, x: u32, dir: u32, k: u32| {
        let cell = [x, (row % ny as usize) as u32, (row / ny as usize) as u32];
        let mut rng = layout.rng(layout.cell_linear(cell), dir, k);
        let (p, w) = layout.line(cell, dir, &mut rng);
        (chord_samples(&placement, p, w), rng)
    };
    // Pass 1: each row's sample count per part, for where each row starts in each part.
    let counts = row_counts(&layout, &placement, &slabs);
    let mut starts = vec![vec![0usize; slabs.len()]; rows + 1];
    for row in 0..rows {
        for s in 0..slabs.len() {
            starts[row + 1][s] = starts[row][s] + counts[row][s];
        }
    }
    for (s, (name, p)) in order.iter().enumerate() {
        if starts[rows][s] != p.samples.len() {
            return Err(mismatch(
                name,
                format!(
                    "has {} samples where its slab of this grid holds {}",
                    p.samples.len(),
                    starts[rows][s]
                ),
            ));
        }
    }
    // Pass 2: each pin's optical depths as the bake sums them, then its entry.
    dense
        .par_chunks_mut(nx as usize * block_len)
        .enumerate()
        .for_each(|(row, blocks)| {
            let mut at = starts[row].clone();
            let mut all = Vec::new();
            for (x, block) in blocks.chunks_mut(block_len).enumerate() {
                for dir in 0..dirs {
                    for k in 0..ppe {
                        let (cs, mut rng) = pin(row, x as u32, dir, k);
                        let Some(cs) = cs else {
                            // No chord: zero optical depths, as the bake's.
                            block[(dir * ppe + k) as usize] =
                                make_entry(&[0.0; INTERVALS], &mut rng);
                            continue;
                        };
                        // The pieces in sample order: slabs bottom to top along a pin that
                        // climbs in z, top to bottom along one that descends.
                        let mut pieces: Vec<(usize, usize, usize)> = slabs
                            .iter()
                            .enumerate()
                            .map(|(s, slab)| {
                                let (a, b) = owned_range(&cs, *slab);
                                (a, b, s)
                            })
                            .collect();
                        pieces.sort_unstable();
                        all.clear();
                        for (a, b, s) in pieces {
                            let n = b - a;
                            all.extend_from_slice(&order[s].1.samples[at[s]..at[s] + n]);
                            at[s] += n;
                        }
                        let taus = optical_depths(&all, &cs);
                        block[(dir * ppe + k) as usize] = make_entry(&taus, &mut rng);
                    }
                }
            }
        });
    Ok(crate::bake::finish(
        desc,
        None,
        dense,
        (majorant, None),
        metadata,
        block_len,
        started,
    )?)
}

/// What [`merge_parts_within`] allocates beside the parts: the pins (and the canonical
/// grid's copy of them), each row's sample counts and starts per part, the lattice.
fn merge_bytes(pins: usize, rows: usize, parts: usize, lattice: usize) -> u64 {
    let row_table = (size_of::<Vec<usize>>() as u64)
        .saturating_add((parts as u64).saturating_mul(size_of::<usize>() as u64));
    (pins as u64)
        .saturating_mul(2 * size_of::<PinEntry>() as u64)
        .saturating_add(
            (rows as u64 + 1)
                .saturating_mul(row_table)
                .saturating_mul(2),
        )
        .saturating_add((lattice as u64).saturating_mul(4))
}

/// The parts of a voxel grid (`order`, bottom to top) against the grid statistics they were
/// baked with (which they agree on, checked before): their slabs tile the grid, so the
/// leaves of all the slabs are the grid's leaves. Statistics that widen or shrink the
/// non-zero box, or miscount the leaves or the largest value, give every part the same
/// wrong bytes and pass every other check; here they fail.
fn check_facts(first_name: &str, order: &[&(String, PartData)]) -> Result<(), PartError> {
    let Some(want) = order.first().and_then(|(_, p)| p.facts) else {
        return Ok(());
    };
    let facts = || order.iter().filter_map(|(_, p)| p.facts);
    let got = facts().fold(LeafSummary::EMPTY, |a, f| a.union(f.slab));
    let negatives = facts().fold(want.tile_negative_values, |a, f| {
        a.saturating_add(f.slab_negative_values)
    });
    // The largest values are maxima of the same f32 values: equal, not close.
    let same = got.nonzero_leaves == want.grid.nonzero_leaves
        && got.nonzero_box == want.grid.nonzero_box
        && got.max_value == want.grid.max_value;
    let problem = if !same {
        format!("say {}, the parts' slabs hold {got}", want.grid)
    } else if negatives != want.negative_values {
        format!(
            "count {} negative values, the parts' slabs and the tiles hold {negatives}",
            want.negative_values
        )
    } else {
        return Ok(());
    };
    Err(PartError::Mismatch {
        name: first_name.to_string(),
        problem: format!(
            "the grid statistics the parts were baked with do not match the grid: they {problem} (statistics edited, or made for another file or other options)"
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::bake;
    use crate::pin::field_optical_depths;
    use crate::rng::CounterRng;
    use pin_volume::Density;
    use pin_volume::HomogeneousBox;

    /// A field with structure along every axis, sampled through `extinction_along`.
    struct Waves;
    impl Density for Waves {
        fn bounds(&self) -> Aabb {
            Aabb::new(DVec3::new(-1.0, 0.0, 2.0), DVec3::new(1.0, 0.5, 3.5))
        }
        fn extinction(&self, p: DVec3) -> f32 {
            if !(p.cmpge(self.bounds().min).all() && p.cmple(self.bounds().max).all()) {
                return 0.0;
            }
            // Values over 40 binary orders of magnitude: an f64 sum of them rounds, so a sum
            // in another order gives other bits (where a narrow range would add exactly).
            let octave = ((p.y * 40.0).floor() as i32).rem_euclid(9) * 5 - 20;
            ((2.0 + (7.0 * p.x).sin() * (5.0 * p.y + 1.0).cos() + (9.0 * p.z).sin())
                * 2f64.powi(octave)) as f32
        }
        fn max_extinction_in(&self, _: Aabb) -> f32 {
            4.0 * 2f32.powi(20)
        }
    }

    impl DensitySource for Waves {
        fn describe(&self) -> String {
            "waves".into()
        }
    }

    fn grid() -> DenseGrid {
        let dims = [13u32, 9, 17];
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        // Over 40 binary orders of magnitude, as `Waves`.
        let data: Vec<f32> = (0..n)
            .map(|i| ((i * 7919) % 97) as f32 / 23.0 * 2f32.powi((i % 41) as i32 - 20))
            .collect();
        DenseGrid::new(
            dims,
            data,
            DVec3::new(0.2, 0.3, 0.25),
            DVec3::new(-1.0, 2.0, 0.5),
            "t",
        )
        .unwrap()
    }

    fn opts() -> BakeOptions {
        BakeOptions {
            cells: [4, 3, 5],
            directions: Directions::Octahedral { n: 3 },
            pins_per_entry: 2,
            majorant: Some([2, 3, 4]),
            seed: 11,
            ..BakeOptions::default()
        }
    }

    /// The parts of `count`, baked in reverse order with `threads`, merged in `order`.
    fn merged(
        source: &dyn DensitySource,
        opts: &BakeOptions,
        count: u32,
        threads: usize,
    ) -> Vec<u8> {
        let mut parts: Vec<(String, PartData)> = (0..count)
            .rev()
            .map(|index| {
                let o = BakeOptions {
                    threads: Some(threads),
                    ..opts.clone()
                };
                let d = bake_part(source, &o, Part { index, count }, &|_| {}).unwrap();
                // Through the file format, as a farm hands them over.
                let d = crate::part_file::decode(&crate::part_file::encode(&d).unwrap()).unwrap();
                (format!("p{index}"), d)
            })
            .collect();
        // Any order: rotate by one.
        parts.rotate_left(1);
        merge_parts(&parts).unwrap().0.to_bytes().unwrap()
    }

    /// The merged parts are the monolithic bake's bytes for 1, 2, 3 and 5 parts, for a
    /// procedural field (`extinction_along`) and a dense grid (its march, whole pins and
    /// pins of more than one chunk per interval), with jittered pins too, for any thread
    /// count of the parts.
    #[test]
    fn parts_merge_into_the_monolithic_bytes() {
        let g = grid();
        let fine = BakeOptions {
            // More than 256 samples per interval: the chunked march.
            step: 0.00005,
            cells: [2, 2, 3],
            directions: Directions::Octahedral { n: 2 },
            ..opts()
        };
        let jittered = BakeOptions {
            jitter_pins: true,
            ..opts()
        };
        let cases: [(&dyn DensitySource, BakeOptions); 4] = [
            (&Waves, opts()),
            (&g, opts()),
            (&g, fine),
            (&Waves, jittered),
        ];
        for (i, (source, o)) in cases.iter().enumerate() {
            let whole = bake(*source, o, &|_| {}).unwrap().0.to_bytes().unwrap();
            for count in [1, 2, 3, 5] {
                let threads = 1 + (count as usize % 3);
                assert!(
                    merged(*source, o, count, threads) == whole,
                    "case {i}: {count} parts differ from the monolithic bake"
                );
            }
        }
    }

    /// A dense grid of 32 MiB and more is baked by layers (`crate::sweep`); its parts merge
    /// into those bytes too.
    #[test]
    fn parts_of_a_layered_bake_merge_into_its_bytes() {
        let g = grid();
        let sweep = crate::sweep::Sweep {
            min_grid_bytes: 0,
            batch_pins: 64,
            layer: 3,
            ..crate::sweep::Sweep::default()
        };
        let o = opts();
        let layered = crate::bake::bake_with_sweep(&g, &o, Some(sweep), &|_| {})
            .unwrap()
            .0
            .to_bytes()
            .unwrap();
        assert!(merged(&g, &o, 3, 2) == layered);
    }

    /// The split itself: for random pins, the pieces of every slab in sample order are the
    /// pin's samples, and the merge's sum of them has the bits of the bake's optical depths
    /// (the associativity the byte equality rests on, tested below the masks: a rounding
    /// difference need not flip a mask bit).
    #[test]
    fn pieces_sum_to_the_bits_of_the_bake() {
        let g = grid();
        let box_ = g.bounds();
        let slabs = [
            [f64::NEG_INFINITY, 1.3],
            [1.3, 1.31],
            [1.31, 2.9],
            [2.9, f64::INFINITY],
        ];
        for (field, march, step) in [
            (
                crate::pin::Field::Source(&Waves as &dyn DensitySource),
                March::Source(&Waves),
                0.01,
            ),
            (crate::pin::Field::Grid(&g), March::Grid(&g), 0.01),
            (crate::pin::Field::Grid(&g), March::Grid(&g), 0.00005),
            (
                crate::pin::Field::Source(&Waves as &dyn DensitySource),
                March::Source(&Waves),
                0.00005,
            ),
        ] {
            let bounds = match march {
                March::Source(s) => s.bounds(),
                March::Grid(_) => box_,
            };
            let placement = Placement::over(&bounds, step);
            let mut buf = [0f32; CHUNK];
            for n in 0..40 {
                let mut rng = CounterRng::new(9, 2, n);
                let p = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
                let w = DVec3::new(rng.next_f64() - 0.5, rng.next_f64() - 0.5, rng.next_f64())
                    .normalize();
                let Some(cs) = chord_samples(&placement, p, w) else {
                    continue;
                };
                let total = INTERVALS * cs.steps;
                let mut whole = Vec::new();
                march.samples(&cs, 0..total, &mut buf, &mut whole);
                assert_eq!(whole.len(), total);
                let mut pieces = Vec::new();
                let mut next = 0;
                for s in slabs {
                    let (a, b) = owned_range(&cs, s);
                    assert_eq!(a, next, "pin {n}: the pieces tile the samples");
                    march.samples(&cs, a..b, &mut buf, &mut pieces);
                    next = b;
                }
                assert_eq!(next, total);
                assert!(pieces == whole, "pin {n}: pieces differ from the whole pin");
                let want = field_optical_depths(field, &placement, p, w);
                let got = optical_depths(&pieces, &cs);
                assert_eq!(
                    want.map(f64::to_bits),
                    got.map(f64::to_bits),
                    "pin {n}, step {step}"
                );
            }
        }
    }

    #[test]
    fn batches_and_the_streamed_file_give_the_bytes_of_one_batch() {
        let g = grid();
        let o = opts();
        let part = Part { index: 1, count: 3 };
        let whole = bake_part(&g, &o, part, &|_| {}).unwrap();
        let rows = (o.cells[1] * o.cells[2]) as u64;
        assert!(
            whole.samples.len() as u64 > 4 * rows,
            "the test needs rows of samples"
        );
        // Batches of one row (a row never splits), of a few rows, of everything.
        for batch in [1, whole.samples.len() / 7, usize::MAX / 2] {
            let mut sink = InMemory(Vec::new());
            let mut d = bake_part_batched(&g, &o, part, &|_| {}, &mut sink, batch).unwrap();
            d.samples = sink.0;
            assert!(d == whole, "batches of {batch} samples");
        }
        // Streamed into its file as it is baked: the bytes of the whole part's encoding, and
        // nothing but the file in the directory.
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("p.part");
        let mut w = crate::part_file::PartFileWriter::create(&target).unwrap();
        bake_part_batched(&g, &o, part, &|_| {}, &mut w, 1000).unwrap();
        assert_eq!(w.samples_written(), whole.samples.len() as u64);
        w.finish().unwrap();
        assert!(std::fs::read(&target).unwrap() == crate::part_file::encode(&whole).unwrap());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn merge_refuses_missing_duplicated_and_mismatched_parts() {
        let src = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 0.7).unwrap();
        let part = |index, count, seed| {
            let o = BakeOptions { seed, ..opts() };
            (
                format!("p{index}s{seed}"),
                bake_part(&src, &o, Part { index, count }, &|_| {}).unwrap(),
            )
        };
        let (a, b, c) = (part(0, 3, 1), part(1, 3, 1), part(2, 3, 1));
        let err = |parts: &[(String, PartData)]| merge_parts(parts).unwrap_err().to_string();
        assert!(err(&[a.clone(), c.clone()]).contains("part 1 of 3 is missing"));
        assert!(err(&[a.clone(), b.clone(), b.clone(), c.clone()]).contains("given twice"));
        let other_seed = part(1, 3, 2);
        let e = err(&[a.clone(), other_seed, c.clone()]);
        assert!(e.contains("p1s2") && e.contains("grid description"), "{e}");
        let other_count = part(1, 2, 1);
        assert!(err(&[a.clone(), other_count, c.clone()]).contains("is part of 2"));
        let mut short = b.clone();
        short.1.samples.pop();
        assert!(err(&[a.clone(), short, c.clone()]).contains("samples"));
        let mut gap = b.clone();
        gap.1.slab[1] -= 0.125;
        assert!(err(&[a.clone(), gap, c.clone()]).contains("do not cover"));
        assert!(matches!(merge_parts(&[]), Err(PartError::Empty)));
        // A description that the parts agree on but no bake writes: refused before any work.
        let hostile = |f: &dyn Fn(&mut GridDesc)| {
            let mut parts = [a.clone(), b.clone(), c.clone()];
            for p in &mut parts {
                f(&mut p.1.desc);
            }
            err(&parts)
        };
        assert!(hostile(&|d| d.step_size = 1e-300).contains("step"));
        assert!(hostile(&|d| d.box_max[0] = f64::NAN).contains("box"));
        assert!(hostile(&|d| d.dims = [0, 3, 5]).contains("grid description"));
        // The three merge.
        assert!(merge_parts(&[c, a, b]).is_ok());
    }

    /// The part count is read from the files: a count far above the parts given is a
    /// missing part, found without sizing anything by the count.
    #[test]
    fn merge_sizes_nothing_by_the_part_count() {
        let src = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 0.7).unwrap();
        let mut parts: Vec<(String, PartData)> = (0..2)
            .map(|index| {
                let d = bake_part(&src, &opts(), Part { index, count: 2 }, &|_| {}).unwrap();
                (format!("p{index}"), d)
            })
            .collect();
        for (_, p) in &mut parts {
            p.part.count = u32::MAX;
        }
        let e = merge_parts(&parts).unwrap_err().to_string();
        assert!(e.contains("part 2 of 4294967295 is missing"), "{e}");
        parts[1].1.part.index = 7;
        let e = merge_parts(&parts).unwrap_err().to_string();
        assert!(e.contains("part 1 of 4294967295 is missing"), "{e}");
    }

    /// A merge with a memory budget refuses a grid beyond it before allocating it.
    #[test]
    fn merge_within_a_budget_refuses_before_allocating() {
        let src = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 0.7).unwrap();
        let parts: Vec<(String, PartData)> = (0..2)
            .map(|index| {
                let d = bake_part(&src, &opts(), Part { index, count: 2 }, &|_| {}).unwrap();
                (format!("p{index}"), d)
            })
            .collect();
        assert!(matches!(
            merge_parts_within(&parts, Some(1000)),
            Err(PartError::Memory { limit: 1000, .. })
        ));
        assert!(merge_parts_within(&parts, Some(1 << 30)).is_ok());
    }

    /// Parts of a voxel grid carry the grid's facts they baked with and their slab's: parts
    /// that disagree on the grid's, or whose slabs together are not the grid, do not merge.
    #[test]
    fn merge_checks_the_parts_grid_facts() {
        let src = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 0.7).unwrap();
        let summary = |n, lo: [i32; 3], hi: [i32; 3], m| LeafSummary {
            nonzero_leaves: n,
            nonzero_box: Some([lo, hi]),
            max_value: m,
        };
        let grid = summary(5, [0, 0, 0], [20, 9, 30], 2.0);
        let slabs = [
            (summary(2, [1, 0, 0], [20, 3, 15], 2.0), 1),
            (summary(3, [0, 2, 16], [19, 9, 30], 1.5), 2),
        ];
        let parts: Vec<(String, PartData)> = slabs
            .iter()
            .enumerate()
            .map(|(index, (slab, negatives))| {
                let mut d = bake_part(
                    &src,
                    &opts(),
                    Part {
                        index: index as u32,
                        count: 2,
                    },
                    &|_| {},
                )
                .unwrap();
                d.facts = Some(PartFacts {
                    grid,
                    negative_values: 7,
                    slab: *slab,
                    slab_negative_values: *negatives,
                    tile_negative_values: 4,
                });
                (format!("p{index}"), d)
            })
            .collect();
        assert!(merge_parts(&parts).is_ok());
        let edit = |f: &dyn Fn(&mut PartFacts)| {
            let mut p = parts.clone();
            for (_, d) in &mut p {
                f(d.facts.as_mut().unwrap());
            }
            merge_parts(&p).unwrap_err().to_string()
        };
        // Every part baked with the same lying statistics.
        let e = edit(&|f| f.grid.nonzero_box = Some([[0, 0, 0], [21, 9, 30]]));
        assert!(
            e.contains("do not match the grid") && e.starts_with("p0: "),
            "{e}"
        );
        assert!(edit(&|f| f.grid.nonzero_leaves = 6).contains("do not match"));
        assert!(edit(&|f| f.grid.max_value = 3.0).contains("do not match"));
        assert!(edit(&|f| f.negative_values = 8).contains("negative values"));
        // Parts baked with different statistics.
        let mut p = parts.clone();
        p[1].1.facts.as_mut().unwrap().grid.max_value = 3.0;
        let e = merge_parts(&p).unwrap_err().to_string();
        assert!(e.contains("p1") && e.contains("grid statistics"), "{e}");
        // A part of a voxel grid among parts of a source read whole.
        let mut p = parts.clone();
        p[0].1.facts = None;
        assert!(
            merge_parts(&p)
                .unwrap_err()
                .to_string()
                .contains("grid statistics")
        );
    }

    #[test]
    fn part_bakes_refuse_what_they_cannot_split() {
        let src = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 0.7).unwrap();
        for o in [
            BakeOptions {
                embed_density: Some(crate::EmbedDensity::Dense([2, 2, 2])),
                ..opts()
            },
            BakeOptions {
                tile: Some(crate::Tile { index: 0, count: 2 }),
                ..opts()
            },
        ] {
            assert!(matches!(
                bake_part(&src, &o, Part { index: 0, count: 2 }, &|_| {}),
                Err(BakeError::Options(_))
            ));
        }
        assert!(bake_part(&src, &opts(), Part { index: 2, count: 2 }, &|_| {}).is_err());
        let too_many = Part {
            index: 1,
            count: MAX_PARTS + 1,
        };
        assert!(matches!(
            bake_part(&src, &opts(), too_many, &|_| {}),
            Err(BakeError::Options(_))
        ));
    }
}
