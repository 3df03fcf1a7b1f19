//! The bake's march over a dense grid, in z-layers of the grid rather than pin by pin.
//!
//! Why: a 512^3 grid is 512 MiB, and consecutive pins of the per-pin order are lines a cell
//! (14 voxels at 37^3 cells) or more apart, so they share no cache lines: every one of a
//! bake's ~4e8 samples waited on DRAM (docs/performance.md, "## Bake"). No order of whole
//! pins helps, because a pin crosses the whole grid; what does is cutting the pins by the
//! grid. Every pin's direction has `z >= 0` in the bake box ([`PinLayout::line`]), so along
//! a pin the grid's z index never decreases. A batch of pins is therefore marched layer by
//! layer of the grid ([`Sweep::layer`] voxels of z at a time, a contiguous slab of the grid):
//! each pin takes its next samples until it leaves the layer, so the whole batch's samples
//! in one layer read only that slab. The figures (the CPU against the per-pin march, and the
//! layer depth of [`Sweep::default`] against thinner layers) are in docs/performance.md,
//! "Marching by layers of the grid", with the commands that measure them.
//!
//! The bytes do not change: each pin's samples are the points, values and f64 sums of
//! [`crate::pin::field_optical_depths`] (its whole-pin path: one f64 base per interval, f32
//! steps inside), summed in the same order, because a pin's samples are taken in sample order
//! whatever the layer they fall in (the layer only decides when). Neither the batch size, the
//! layer depth, nor the thread count moves a bit (tests below). A pin whose samples are out
//! of z order (NaN, a direction with `z < 0`) is simply marched in fewer layers.

use glam::DVec3;
use pin_format::PinEntry;
use rayon::prelude::*;

use crate::pin::{
    ChordSamples, Field, GRID_WHOLE_PIN_STEPS, INTERVALS, PinLayout, Placement, chord_samples,
    field_optical_depths, make_entry,
};
use crate::rng::CounterRng;
use pin_volume::DenseGrid;
use pin_volume::grid::Cells;

/// How a layered bake is cut up. [`Sweep::default`] is what bakes use; the bytes do not
/// depend on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sweep {
    /// Pins marched together (the working set is ~420 bytes per pin).
    pub batch_pins: usize,
    /// Voxels of z per layer.
    pub layer: u32,
    /// Pins per parallel task within a layer.
    pub task_pins: usize,
    /// Grids of fewer bytes are marched pin by pin: they stay in the caches anyway, and
    /// there the batches' bookkeeping costs more than it saves (64^3: 7.1 CPU-s layered
    /// against 6.2 pin by pin, docs/performance.md).
    pub min_grid_bytes: usize,
}

impl Default for Sweep {
    fn default() -> Self {
        Self {
            batch_pins: 1 << 18,
            layer: 64,
            task_pins: 4096,
            // The last-level cache of the machines measured.
            min_grid_bytes: 32 << 20,
        }
    }
}

/// Bytes the layered march holds beside the grid and the output for a bake of `pins` pins
/// whose grid is at least [`Sweep::min_grid_bytes`]: one batch's per-pin state.
pub(crate) fn working_set_bytes(pins: u64) -> u64 {
    let per_pin = (std::mem::size_of::<Head>() + std::mem::size_of::<Lane>()) as u64;
    pins.min(Sweep::default().batch_pins as u64)
        .saturating_mul(per_pin)
}

/// What marching one pin touches at every sample, apart from the rest of its state
/// ([`Lane`]) so that a layer's pass over a batch streams 48 bytes per pin, not 400.
#[derive(Clone, Copy, Debug, Default)]
struct Head {
    /// The current interval's base index and the f32 index step per sample.
    base: [f32; 3],
    du: [f32; 3],
    /// Samples per interval, the current interval (`INTERVALS` when done) and sample.
    n: u32,
    r: u32,
    j: u32,
    /// The current interval's sum so far.
    acc: f64,
}

/// The rest of a pin being marched: its line, random stream and finished intervals.
#[derive(Clone)]
struct Lane {
    /// The line in the grid's continuous index, per unit of chord parameter.
    ua: DVec3,
    ub: DVec3,
    /// f64 index step per sample (`ub * h`).
    du64: DVec3,
    s0: f64,
    ds: f64,
    weight: f64,
    /// The pin's random stream after its line was drawn: the mask bits come next.
    rng: CounterRng,
    taus: [f64; INTERVALS],
}

impl Lane {
    /// Interval `r`'s first sample, as the per-pin rule computes it.
    fn base_of(&self, r: u32) -> [f32; 3] {
        let b = self.ua + self.ub * (self.s0 + self.ds * f64::from(r)) + self.du64 * 0.5;
        [b.x as f32, b.y as f32, b.z as f32]
    }
}

/// A pin already integrated (or with nothing to integrate): only its entry is left.
fn finished(taus: [f64; INTERVALS], rng: CounterRng) -> (Head, Lane) {
    (
        Head {
            r: INTERVALS as u32,
            ..Head::default()
        },
        Lane {
            ua: DVec3::ZERO,
            ub: DVec3::ZERO,
            du64: DVec3::ZERO,
            s0: 0.0,
            ds: 0.0,
            weight: 1.0,
            rng,
            taus,
        },
    )
}

/// Bakes the pins of `out`'s cells (tile-local, x fastest, rows of `nx` by `ny` from cell
/// layer `z_begin`) of a dense grid, `block_len` entries per cell, `sweep.batch_pins` pins at
/// a time. `progress` gets the pins of each finished batch.
#[allow(clippy::too_many_arguments)]
pub(crate) fn bake_grid(
    grid: &DenseGrid,
    placement: &Placement,
    layout: &PinLayout,
    (nx, ny, z_begin): (usize, usize, u32),
    block_len: usize,
    out: &mut [PinEntry],
    sweep: Sweep,
    progress: &(dyn Fn(u64) + Sync),
    cancelled: &(dyn Fn() -> bool + Sync),
) {
    let block_len = block_len.max(1);
    let cells_total = out.len() / block_len;
    let per_batch = (sweep.batch_pins / block_len).max(1);
    let layer = sweep.layer.max(1);
    let layers = grid.dims()[2].div_ceil(layer);
    let task = sweep.task_pins.max(1);
    let cells = grid.cells();
    let (mut heads, mut lanes): (Vec<Head>, Vec<Lane>) = (Vec::new(), Vec::new());
    let mut c0 = 0;
    // A cancelled bake stops after the batch in flight; its caller reports it.
    while c0 < cells_total && !cancelled() {
        let nc = per_batch.min(cells_total - c0);
        // Slot-major inside the batch: neighbouring lanes are pins of one direction in
        // neighbouring cells, whose samples in a layer lie near each other.
        (0..nc * block_len)
            .into_par_iter()
            .map(|i| {
                let (slot, c) = ((i / nc) as u32, c0 + i % nc);
                let cell = [
                    (c % nx) as u32,
                    ((c / nx) % ny) as u32,
                    (c / (nx * ny)) as u32 + z_begin,
                ];
                let (dir, k) = (slot / layout.pins_per_entry, slot % layout.pins_per_entry);
                let mut rng = layout.rng(layout.cell_linear(cell), dir, k);
                let (p, w) = layout.line(cell, dir, &mut rng);
                lane(grid, placement, p, w, rng)
            })
            .unzip_into_vecs(&mut heads, &mut lanes);
        for l in 0..layers {
            // The last layer takes whatever is left, so every lane finishes.
            let z_end = if l + 1 == layers {
                f32::INFINITY
            } else {
                ((l + 1) * layer) as f32
            };
            heads
                .par_chunks_mut(task)
                .zip(lanes.par_chunks_mut(task))
                .for_each(|(h, l)| {
                    // Polled per task too: a batch of long pins takes seconds. A cancelled
                    // batch is left unfinished and never written.
                    if !cancelled() {
                        advance(&cells, h, l, z_end)
                    }
                });
        }
        let out = &mut out[c0 * block_len..(c0 + nc) * block_len];
        out.par_chunks_mut(block_len)
            .enumerate()
            .for_each(|(c, block)| {
                for (slot, e) in block.iter_mut().enumerate() {
                    let lane = &lanes[slot * nc + c];
                    let mut taus = lane.taus;
                    for tau in &mut taus {
                        *tau *= lane.weight;
                    }
                    *e = make_entry(&taus, &mut lane.rng.clone());
                }
            });
        progress((nc * block_len) as u64);
        c0 += nc;
    }
}

/// The lane of the pin `p + s w`, marched later, or integrated now where the chord is empty
/// or too finely sampled for the whole-pin rule.
fn lane(
    grid: &DenseGrid,
    placement: &Placement,
    p: DVec3,
    w: DVec3,
    rng: CounterRng,
) -> (Head, Lane) {
    let Some(ChordSamples {
        s0,
        ds,
        steps,
        h,
        weight,
        origin,
        world_dir,
    }) = chord_samples(placement, p, w)
    else {
        return finished([0.0; INTERVALS], rng);
    };
    if steps > GRID_WHOLE_PIN_STEPS {
        let taus = field_optical_depths(Field::Grid(grid), placement, p, w);
        return finished(taus, rng);
    }
    let (ua, ub) = (grid.index_of(origin), grid.index_dir(world_dir));
    let du64 = ub * h;
    let lane = Lane {
        ua,
        ub,
        du64,
        s0,
        ds,
        weight,
        rng,
        taus: [0.0; INTERVALS],
    };
    let head = Head {
        base: lane.base_of(0),
        du: [du64.x as f32, du64.y as f32, du64.z as f32],
        n: steps as u32,
        r: 0,
        j: 0,
        acc: 0.0,
    };
    (head, lane)
}

/// Marches every lane up to its first sample at or beyond grid z index `z_end`, a block of
/// samples at a time: locate and prefetch the block, then read and sum it.
fn advance(cells: &Cells<'_>, heads: &mut [Head], lanes: &mut [Lane], z_end: f32) {
    const BLOCK: usize = 128;
    // Per sample: its lane, its interval, and whether it ends the interval.
    let mut who = [(0u32, 0u8, false); BLOCK];
    let mut base = [0usize; BLOCK];
    let mut frac = [[0.0f32; 3]; BLOCK];
    let mut next = 0;
    loop {
        let mut len = 0;
        while len < BLOCK && next < heads.len() {
            let h = &mut heads[next];
            if h.r as usize >= INTERVALS {
                next += 1;
                continue;
            }
            let t = h.j as f32;
            let u = [
                h.base[0] + t * h.du[0],
                h.base[1] + t * h.du[1],
                h.base[2] + t * h.du[2],
            ];
            // `>=` so that a NaN index is taken now rather than never.
            if u[2] >= z_end {
                next += 1;
                continue;
            }
            (base[len], frac[len]) = cells.locate(u);
            cells.prefetch(base[len]);
            h.j += 1;
            let last = h.j == h.n;
            who[len] = (next as u32, h.r as u8, last);
            len += 1;
            if last {
                h.j = 0;
                h.r += 1;
                if (h.r as usize) < INTERVALS {
                    h.base = lanes[next].base_of(h.r);
                }
            }
        }
        if len == 0 {
            return;
        }
        // In block order, which is each lane's sample order: the sums are the per-pin rule's.
        for ((&(i, r, last), &b), &f) in who.iter().zip(&base).zip(&frac).take(len) {
            let h = &mut heads[i as usize];
            h.acc += f64::from(cells.interpolate(b, f));
            if last {
                lanes[i as usize].taus[usize::from(r)] = h.acc;
                h.acc = 0.0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::{BakeOptions, bake_with_sweep};
    use pin_format::Directions;

    /// A grid with detail at every voxel, so that any sample moved or summed in another
    /// order changes bytes.
    fn scattered(dims: [u32; 3]) -> DenseGrid {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let data: Vec<f32> = (0..n).map(|i| ((i * 7919) % 97) as f32 / 13.0).collect();
        DenseGrid::new(
            dims,
            data,
            DVec3::new(0.1, 0.07, 0.12),
            DVec3::new(-1.0, 0.5, 2.0),
            "t",
        )
        .unwrap()
    }

    fn opts() -> BakeOptions {
        BakeOptions {
            cells: [5, 4, 6],
            directions: Directions::Octahedral { n: 4 },
            pins_per_entry: 2,
            majorant: None,
            seed: 11,
            ..BakeOptions::default()
        }
    }

    #[test]
    fn layers_batches_and_threads_give_the_per_pin_bytes() {
        let g = scattered([23, 31, 40]);
        let per_pin = bake_with_sweep(&g, &opts(), None, &|_| {})
            .unwrap()
            .0
            .to_bytes()
            .unwrap();
        let small = Sweep {
            min_grid_bytes: 0,
            ..Sweep::default()
        };
        for (threads, sweep) in [
            (1, small),
            (2, small),
            (
                3,
                Sweep {
                    batch_pins: 7,
                    layer: 1,
                    task_pins: 3,
                    min_grid_bytes: 0,
                },
            ),
            (
                2,
                Sweep {
                    batch_pins: 100,
                    layer: 5,
                    task_pins: 17,
                    min_grid_bytes: 0,
                },
            ),
            (
                1,
                Sweep {
                    batch_pins: 1 << 20,
                    layer: 1000,
                    task_pins: 1 << 20,
                    min_grid_bytes: 0,
                },
            ),
        ] {
            let o = BakeOptions {
                threads: Some(threads),
                ..opts()
            };
            let layered = bake_with_sweep(&g, &o, Some(sweep), &|_| {})
                .unwrap()
                .0
                .to_bytes()
                .unwrap();
            assert!(layered == per_pin, "{threads} threads, {sweep:?}");
        }
    }

    #[test]
    fn fine_steps_and_tiles_take_the_per_pin_bytes_too() {
        // 300 samples per interval: beyond the whole-pin rule, marched per pin inside the
        // layered bake; and a tile, whose cells start at a later z layer.
        let g = scattered([9, 8, 7]);
        for o in [
            BakeOptions {
                step: 0.0001,
                cells: [2, 2, 2],
                ..opts()
            },
            BakeOptions {
                tile: Some(crate::Tile { index: 1, count: 3 }),
                ..opts()
            },
        ] {
            let a = bake_with_sweep(&g, &o, None, &|_| {}).unwrap().0;
            let sweep = Sweep {
                min_grid_bytes: 0,
                ..Sweep::default()
            };
            let b = bake_with_sweep(&g, &o, Some(sweep), &|_| {}).unwrap().0;
            assert!(a.to_bytes().unwrap() == b.to_bytes().unwrap(), "{o:?}");
        }
    }
}
