//! Where the pin model's bias floor comes from. Bakes a volume with `pinbake bake`'s
//! default choice, then for camera rays (to the box exit) and shadow rays (from a scattering
//! point toward the sun) of four views compares, per ray, the EXPECTED transmittance of five
//! models against the exact optical depth along the query ray:
//!
//! * `a` the pin as baked: its one binary mask and `t_min` (frozen mask noise);
//! * `b` the same pin's exact interval transmittances along the PIN's line (no mask noise);
//! * `c` b, with the query segment mapped onto the pin by position along the pin's line
//!   (projection of the segment's ends) instead of by interval index of the query's chord;
//! * `d` the query's own line cut into 32 intervals with the partial-interval rule (the
//!   discretisation alone);
//! * `c_nominal` c, with the pin's line taken as it would be without bake jitter (cell centre
//!   and direction-cell centre: what a runtime knows without the baker's generator), but the
//!   baked pin's transmittances (only the mapping uses the nominal line).
//!
//! A third family, `single`, measures where a collision lands inside its interval: single
//! scattering toward the sun along the camera ray with exact transmittances, the collision
//! drawn exactly (`exact`) and as the pins place it (`d`: the same interval, then uniform).
//!
//! A fourth family, `scatter`, is single scattering toward the sun along the camera ray as
//! `pinrender render --estimator pins` computes it, with the runtime's own sampler answering
//! the collision (`pin_distance`), the shadow ray from it (`pin_shadow`) or both (`pins`),
//! the rest exact (Monte Carlo, `--scatter-samples` per pixel); `scatter_shadow` gives models
//! a-d for those shadow rays (`--scatter-parts`). `collision_query_line` and
//! `collision_pin_line` redo `pin_distance` with the lookup written out here (middle, the
//! `--jitter`) and place the collision once on the query's line (as the runtime does) and
//! once on the answering pin's own line (through its cell's and direction cell's centres)
//! at the same fraction of its chord. `--start-inside` turns on the runtime's
//! `start_inside` (docs/sampling.md section 14); the `--shadow-*` and `--camera-stride`
//! options try other lookups for the two kinds of query.
//!
//! a, b, c and c_nominal average over `--draws` lookups (pin choice and lookup jitter drawn as
//! the sampler draws them). Output: per view and ray family, the mean error and the RMS over
//! 8x8-pixel blocks of the block mean's relative error, in percent (docs/evaluation.md, "Where
//! the bias floor comes from").
//!
//! `cargo run --release -p pinrender --features cli --example pin_bias_parts -- \
//!     --volume data/openvdb_smoke1.vdb --density-scale 2 [--jitter-pins] [--jitter S]`

use std::collections::HashMap;
use std::sync::Mutex;

use anyhow::{Result, anyhow};
use clap::Parser;
use glam::DVec3;
use pin_volume::DensitySource;
use pinbake::bake::PinLayout;
use pinbake::pin::{Field, INTERVALS, Placement, field_optical_depths, unit_cube_chord};
use pinrt::chord::{Segment, segment};
use pinrt::lookup::{DirJitter, GridView, direction_cell, spatial_cell};
use pinrt::mask::sanitize_t_min;
use pinrt::{PinEntry, PinGrid, Rng};
use rayon::prelude::*;

/// Pin `k` of the entry `(cell, dcell)` as the sampler reads it: its sanitised `t_min` and
/// its mask, bit-reversed for a query running against the hemisphere (`reversed`); an empty
/// entry where the grid stores none.
fn oriented_entry(
    view: &GridView<'_>,
    cell: [u32; 3],
    dcell: u32,
    k: u32,
    reversed: bool,
) -> (f64, u32) {
    let entry = view
        .entry_index(cell, dcell, k)
        .and_then(|i| view.pins.get(i as usize).copied())
        .unwrap_or(PinEntry::EMPTY);
    let mask = if reversed {
        entry.mask.reverse_bits()
    } else {
        entry.mask
    };
    (f64::from(sanitize_t_min(entry.t_min)), mask)
}

#[derive(Parser)]
struct Args {
    #[command(flatten)]
    volume: pinrender::volume::VolumeArgs,
    /// Image side in pixels (8x8 blocks).
    #[arg(long, default_value_t = 64)]
    size: usize,
    /// Lookups averaged per ray.
    #[arg(long, default_value_t = 32)]
    draws: u32,
    /// Lookup jitter, spatial and directional, in cells (`pinrender render`'s default: 1).
    #[arg(long, default_value_t = 1.0)]
    jitter: f32,
    /// Look up at the segment's start instead of its middle (the render default).
    #[arg(long)]
    start: bool,
    /// Fixed cells per axis instead of the default choice.
    #[arg(long)]
    cells: Option<u32>,
    /// Camera distance from the box centre, in box diagonals.
    #[arg(long, default_value_t = 1.2)]
    distance: f64,
    /// Bake the thesis' jittered pins instead of the default pins through cell centres.
    #[arg(long)]
    jitter_pins: bool,
    /// Collisions per pixel of the `scatter` family (Monte Carlo with the runtime's sampler).
    #[arg(long, default_value_t = 32)]
    scatter_samples: u32,
    /// Also the models a-d for the shadow rays of `scatter`'s exact collisions (slow).
    #[arg(long)]
    scatter_parts: bool,
    /// `scatter`: look shadow rays up at their start (the collision) instead of `--start`'s.
    #[arg(long)]
    shadow_start: bool,
    /// `scatter`: chain stride of the shadow rays' lookups (0: one lookup).
    #[arg(long, default_value_t = 0)]
    shadow_stride: u32,
    /// `scatter`: directional jitter of the shadow rays' lookups (default `--jitter`).
    #[arg(long)]
    shadow_dir_jitter: Option<f32>,
    /// `scatter`: spatial jitter of the shadow rays' lookups (default `--jitter`).
    #[arg(long)]
    shadow_spatial_jitter: Option<f32>,
    /// `scatter`: the runtime's `start_inside` (a ray from inside the box looked up at its
    /// start without spatial jitter; `pinrender render`'s default) for both samplers.
    #[arg(long)]
    start_inside: bool,
    /// `scatter`: chain stride of the camera rays' lookups (0: one lookup).
    #[arg(long, default_value_t = 0)]
    camera_stride: u32,
}

const MODELS: [&str; 6] = ["exact", "a", "b", "c", "d", "c_nominal"];
/// The `scatter` family: which of the two queries of single scattering the pins answer
/// (`pins`: both, as `pinrender render --estimator pins` does; `pin_distance`: the collision
/// along the camera ray only; `pin_shadow`: the transmittance toward the sun only).
const SCATTER_MODELS: [&str; 6] = [
    "exact",
    "pins",
    "pin_distance",
    "pin_shadow",
    "collision_query_line",
    "collision_pin_line",
];

struct Ctx<'a> {
    src: &'a dyn DensitySource,
    view: GridView<'a>,
    layout: PinLayout,
    placement: Placement,
    box_min: DVec3,
    extent: DVec3,
    /// Fine march step in world units (the exact reference).
    fine: f64,
    jitter: f32,
    middle: bool,
    draws: u32,
    taus: Mutex<HashMap<(u64, u32, u32), [f64; INTERVALS]>>,
}

/// Covered fraction of interval `i` by `[s0, s1]` (interval units).
fn cover(i: usize, s0: f64, s1: f64) -> f64 {
    let lo = s0.max(i as f64);
    let hi = s1.min(i as f64 + 1.0);
    (hi - lo).max(0.0)
}

/// Section 5's expectation over 32 interval transmittances `t` for the range `[s0, s1]`.
fn partial_rule(t: &[f64; INTERVALS], s0: f64, s1: f64) -> f64 {
    (0..INTERVALS)
        .map(|i| 1.0 - cover(i, s0, s1) * (1.0 - t[i]))
        .product()
}

impl Ctx<'_> {
    /// Optical depth along world `o + t d` over `[ta, tb]`, midpoint rule at the fine step.
    fn depth(&self, o: DVec3, d: DVec3, ta: f64, tb: f64) -> f64 {
        let len = (tb - ta) * d.length();
        if !(len > 0.0) {
            return 0.0;
        }
        let n = (len / self.fine).ceil().max(1.0) as usize;
        let h = (tb - ta) / n as f64;
        (0..n)
            .map(|i| f64::from(self.src.extinction(o + d * (ta + (i as f64 + 0.5) * h))))
            .sum::<f64>()
            * h
            * d.length()
    }

    fn pin_taus(&self, cell: [u32; 3], dir: u32, k: u32) -> [f64; INTERVALS] {
        let key = (self.layout.cell_linear(cell), dir, k);
        if let Some(t) = self.taus.lock().unwrap().get(&key) {
            return *t;
        }
        let mut rng = self.layout.rng(key.0, dir, k);
        let (p, w) = self.layout.line(cell, dir, &mut rng);
        let t = field_optical_depths(Field::of(self.src), &self.placement, p, w);
        self.taus.lock().unwrap().insert(key, t);
        t
    }

    /// Every model's expected transmittance over `[0, t_max]` of the world ray `o + t d`.
    fn models(&self, o: DVec3, d: DVec3, t_max: f64, seed: u32) -> [f64; 6] {
        let ou = (o - self.box_min) / self.extent;
        let du = d / self.extent;
        let f3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
        let (of, df) = (f3(ou), f3(du));
        let Some(seg) =
            pinrt::chord::unit_cube_chord(of, df).and_then(|c| segment(c, t_max as f32))
        else {
            return [1.0; 6];
        };
        let Segment {
            t_enter,
            t0,
            t1,
            s0,
            s1,
            ..
        } = seg;
        let (t0, t1, s0, s1) = (f64::from(t0), f64::from(t1), f64::from(s0), f64::from(s1));
        let len = f64::from(seg.interval_len);
        let exact = (-self.depth(o, d, t0, t1)).exp();
        let te = f64::from(t_enter);
        let q: [f64; INTERVALS] = std::array::from_fn(|i| {
            let (a, b) = (te + i as f64 * len, te + (i + 1) as f64 * len);
            if cover(i, s0, s1) > 0.0 {
                (-self.depth(o, d, a, b)).exp()
            } else {
                1.0
            }
        });
        let model_d = partial_rule(&q, s0, s1);
        let reversed = df[2] < 0.0;
        let dl = if reversed {
            [-df[0], -df[1], -df[2]]
        } else {
            df
        };
        let dirs = self.view.shape.directions;
        let ppe = self.view.shape.pins_per_entry;
        let mut rng = Rng::for_query(seed, 0x0b1a5);
        let (mut sa, mut sb, mut sc, mut sn) = (0.0, 0.0, 0.0, 0.0);
        let (p0, p1) = (ou + du * t0, ou + du * t1);
        for _ in 0..self.draws {
            let k = rng.below_256(ppe);
            let sj = (self.jitter > 0.0).then(|| {
                (
                    self.jitter,
                    [rng.next_f32(), rng.next_f32(), rng.next_f32()],
                )
            });
            let dj = (self.jitter > 0.0).then(|| DirJitter {
                strength: self.jitter,
                xi: [rng.next_f32(), rng.next_f32()],
            });
            let t = if self.middle { 0.5 * (t0 + t1) } else { t0 } as f32;
            let p = [of[0] + df[0] * t, of[1] + df[1] * t, of[2] + df[2] * t];
            let cell = spatial_cell(p, &self.view, sj);
            let dcell = direction_cell(&dirs, dl, dj);
            // a: the baked entry, closed form over the partial ends (Sampler::piece_expectation).
            let (t_min, mask) = oriented_entry(&self.view, cell, dcell, k, reversed);
            sa += (0..INTERVALS)
                .map(|i| {
                    if mask & (1u32 << (31 - i)) != 0 {
                        1.0 - cover(i, s0, s1) * (1.0 - t_min)
                    } else {
                        1.0
                    }
                })
                .product::<f64>();
            // b: the same pin's exact interval transmittances, matched by index.
            let taus = self.pin_taus(cell, dcell, k);
            let tp: [f64; INTERVALS] = std::array::from_fn(|i| {
                let j = if reversed { INTERVALS - 1 - i } else { i };
                (-taus[j]).exp()
            });
            sb += partial_rule(&tp, s0, s1);
            // c: mapped by position along the pin's own line (pin interval order).
            let tpin: [f64; INTERVALS] = std::array::from_fn(|i| (-taus[i]).exp());
            let mut lrng = self.layout.rng(self.layout.cell_linear(cell), dcell, k);
            let (pp, w) = self.layout.line(cell, dcell, &mut lrng);
            sc += self.by_position(&tpin, pp, w, p0, p1);
            // c_nominal: the line a runtime can compute without the baker's generator.
            let nominal = PinLayout {
                jitter: false,
                ..self.layout
            };
            let mut nrng = nominal.rng(0, 0, 0);
            let (pn, wn) = nominal.line(cell, dcell, &mut nrng);
            sn += self.by_position(&tpin, pn, wn, p0, p1);
        }
        let n = f64::from(self.draws);
        [exact, sa / n, sb / n, sc / n, model_d, sn / n]
    }

    /// Partial rule over the pin's intervals covered by the projection of `[p0, p1]` onto the
    /// line `p + s w` (unit cube).
    fn by_position(&self, t: &[f64; INTERVALS], p: DVec3, w: DVec3, p0: DVec3, p1: DVec3) -> f64 {
        let Some((c0, c1)) = unit_cube_chord(p, w) else {
            return 1.0;
        };
        let w2 = w.length_squared();
        let u = |x: DVec3| 32.0 * (((x - p).dot(w) / w2) - c0) / (c1 - c0);
        let (u0, u1) = (u(p0), u(p1));
        let (lo, hi) = (u0.min(u1).clamp(0.0, 32.0), u0.max(u1).clamp(0.0, 32.0));
        partial_rule(t, lo, hi)
    }
}

fn main() -> std::process::ExitCode {
    // OpenVDB files are read in a child process that re-runs this executable.
    let raw: Vec<std::ffi::OsString> = std::env::args_os().collect();
    if let Some(code) = pin_volume::vdb::serve_vdb_worker_if_asked(&raw) {
        return code;
    }
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("pin_bias_parts: error: {e:#}");
            std::process::ExitCode::from(1)
        }
    }
}

fn run() -> Result<()> {
    let args = Args::parse();
    let input = args
        .volume
        .volume
        .clone()
        .ok_or_else(|| anyhow!("--volume is required"))?;
    let src = pinrender::volume::open_volume(&input, &args.volume)?;
    let stats = pinbake::choose::analyse(&*src, true)?;
    let fixed = pinbake::choose::Fixed {
        cells: args
            .cells
            .map(|c| pinbake::choose::proportional_cells(c, stats.extent, stats.voxels)),
        ..Default::default()
    };
    let choice = pinbake::choose::choose_default(&stats, fixed);
    let opts = pinbake::BakeOptions {
        cells: choice.cells,
        directions: choice.directions,
        pins_per_entry: choice.pins_per_entry,
        jitter_pins: args.jitter_pins,
        ..Default::default()
    };
    let (owned, _) = pinbake::bake(&*src, &opts, &|_| {})?;
    let grid = PinGrid::from_bytes(owned.to_bytes()?).map_err(|e| anyhow!("{e}"))?;
    let desc = *grid.desc();
    eprintln!(
        "bake: cells {:?}, {:?}, {} pins per entry, {} bytes",
        desc.dims,
        desc_directions(&grid),
        choice.pins_per_entry,
        grid.bytes().len()
    );
    let box_min = DVec3::from(desc.box_min);
    let extent = DVec3::from(desc.box_max) - box_min;
    let layout = PinLayout {
        dims: desc.dims,
        directions: grid.shape().directions,
        pins_per_entry: choice.pins_per_entry,
        jitter: opts.jitter_pins,
        seed: opts.seed,
    };
    let placement = Placement {
        box_min,
        extent,
        step: opts.step * extent.max_element(),
    };
    let ctx = Ctx {
        src: &*src,
        view: GridView::new(&grid),
        layout,
        placement,
        box_min,
        extent,
        fine: placement.step / 4.0,
        jitter: args.jitter,
        middle: !args.start,
        draws: if args.jitter > 0.0 || choice.pins_per_entry > 1 {
            args.draws
        } else {
            1
        },
        taus: Mutex::new(HashMap::new()),
    };
    check_against_sampler(&ctx, &grid)?;
    // The renderer's own sampler, with `pinrender render`'s lookup, for the `scatter` family.
    let lookup = pinrt::SamplerOptions {
        spatial_jitter: ctx.jitter,
        directional_jitter: ctx.jitter,
        midpoint_lookup: ctx.middle,
        ..pinrt::SamplerOptions::THESIS
    };
    let lookup = pinrt::SamplerOptions {
        start_inside: args.start_inside,
        ..lookup
    };
    let sampler = pinrt::Sampler::new(&grid)?.with_options(pinrt::SamplerOptions {
        chain_stride: args.camera_stride,
        ..lookup
    });
    // Shadow rays start inside the medium: optionally another lookup for them.
    let shadow_sampler = pinrt::Sampler::new(&grid)?.with_options(pinrt::SamplerOptions {
        midpoint_lookup: ctx.middle && !args.shadow_start,
        chain_stride: args.shadow_stride,
        directional_jitter: args.shadow_dir_jitter.unwrap_or(ctx.jitter),
        spatial_jitter: args.shadow_spatial_jitter.unwrap_or(ctx.jitter),
        ..lookup
    });
    let setup = Scatter {
        camera: &sampler,
        shadow: &shadow_sampler,
        samples: args.scatter_samples,
        parts: args.scatter_parts,
    };
    let centre = box_min + extent * 0.5;
    let diag = extent.length();
    let sun = DVec3::new(0.3, 1.0, 0.2).normalize();
    let views = [
        ("pz", DVec3::Z),
        ("mz", -DVec3::Z),
        ("px", DVec3::X),
        ("diag", DVec3::ONE.normalize()),
    ];
    println!("view,family,model,mean_error_pct,block8_rel_rms_pct,block8_abs_rms");
    let mut totals: HashMap<(&str, &str), (f64, f64, f64, usize)> = HashMap::new();
    for (vname, v) in views {
        let cam = centre + v * (args.distance * diag);
        let fwd = (centre - cam).normalize();
        let up0 = if fwd.y.abs() > 0.9 {
            DVec3::Z
        } else {
            DVec3::Y
        };
        let right = fwd.cross(up0).normalize();
        let up = right.cross(fwd);
        let half = (0.5 / args.distance).atan().tan();
        let n = args.size;
        let rows: Vec<[[f64; 6]; 5]> = (0..n * n)
            .into_par_iter()
            .map(|px| {
                let (x, y) = (px % n, px / n);
                let sx = ((x as f64 + 0.5) / n as f64 * 2.0 - 1.0) * half;
                let sy = (1.0 - (y as f64 + 0.5) / n as f64 * 2.0) * half;
                let d = (fwd + right * sx + up * sy).normalize();
                let primary = ctx.models(cam, d, f64::INFINITY, px as u32);
                // The scattering point: where the exact optical depth along the camera ray
                // reaches min(ln 2, half the total); no shadow ray through empty pixels.
                let total = -primary[0].ln();
                let shadow = if total > 0.05 {
                    let target = total.min(2f64.ln()).min(0.5 * total);
                    let t = scatter_point(&ctx, cam, d, target);
                    ctx.models(cam + d * t, sun, f64::INFINITY, (px as u32) ^ 0x8000_0000)
                } else {
                    [1.0; 6]
                };
                let (ss, placed) = single_scatter(&ctx, cam, d, sun, px as u32);
                let nan = f64::NAN;
                let (sc, sp) = scatter(&ctx, &setup, cam, d, sun, px as u32);
                [
                    primary,
                    shadow,
                    [ss, nan, nan, nan, placed, nan],
                    [sc[0], sc[1], sc[2], sc[3], sc[4], sc[5]],
                    if args.scatter_parts { sp } else { [nan; 6] },
                ]
            })
            .collect();
        for (fi, family) in ["camera", "shadow", "single", "scatter", "scatter_shadow"]
            .iter()
            .enumerate()
        {
            let names = if fi == 3 { &SCATTER_MODELS } else { &MODELS };
            for (m, model) in names.iter().enumerate().skip(1) {
                if rows[0][fi][m].is_nan() {
                    continue;
                }
                let (mean, block, abs) = errors(&rows, n, fi, m);
                println!("{vname},{family},{model},{mean:.2},{block:.2},{abs:.4}");
                let e = totals.entry((family, model)).or_default();
                e.0 = e.0.max(mean.abs());
                e.1 += block * block;
                e.2 += abs * abs;
                e.3 += 1;
            }
        }
    }
    eprintln!("family, model: worst |mean| %, relative and absolute block RMS over views");
    let mut keys: Vec<_> = totals.keys().copied().collect();
    keys.sort();
    for k in keys {
        let (m, b2, a2, c) = totals[&k];
        let c = c as f64;
        eprintln!(
            "{:>7} {:>10}: {m:6.2} {:6.2} {:.4}",
            k.0,
            k.1,
            (b2 / c).sqrt(),
            (a2 / c).sqrt()
        );
    }
    Ok(())
}

fn desc_directions(grid: &PinGrid) -> pinrt::Directions {
    grid.shape().directions
}

/// Single scattering toward the sun along the camera ray `o + t d`, with exact transmittance
/// toward the sun: `(1 - T) E[T_sun(x)]` with the collision `x` drawn (a) from the exact
/// distance distribution and (b) as the pins place it: the interval from the exact interval
/// transmittances of the ray's own 32 intervals (model `d`), then uniformly inside it
/// (`docs/sampling.md` section 5). Both from the same 16 stratified uniforms. `(b) - (a)` is
/// the placement of collisions inside their intervals alone.
fn single_scatter(ctx: &Ctx<'_>, o: DVec3, d: DVec3, sun: DVec3, seed: u32) -> (f64, f64) {
    const M: usize = 16;
    let ou = (o - ctx.box_min) / ctx.extent;
    let du = d / ctx.extent;
    let Some((te, tx)) = unit_cube_chord(ou, du) else {
        return (0.0, 0.0);
    };
    let ta = te.max(0.0);
    if !(tx > ta) {
        return (0.0, 0.0);
    }
    // Cumulative optical depth at the fine samples' boundaries.
    let n = ((tx - ta) * d.length() / ctx.fine).ceil().max(1.0) as usize;
    let h = (tx - ta) / n as f64;
    let mut cum = vec![0.0f64; n + 1];
    for i in 0..n {
        let t = ta + (i as f64 + 0.5) * h;
        cum[i + 1] = cum[i] + f64::from(ctx.src.extinction(o + d * t)) * h * d.length();
    }
    let total = cum[n];
    if total < 1e-6 {
        return (0.0, 0.0);
    }
    let t_at = |tau: f64| -> f64 {
        let i = cum.partition_point(|&c| c < tau).clamp(1, n);
        let (c0, c1) = (cum[i - 1], cum[i]);
        let f = if c1 > c0 { (tau - c0) / (c1 - c0) } else { 0.5 };
        ta + (i as f64 - 1.0 + f.clamp(0.0, 1.0)) * h
    };
    let tau_at = |t: f64| -> f64 {
        let x = ((t - ta) / h).clamp(0.0, n as f64);
        let i = (x.floor() as usize).min(n - 1);
        cum[i] + (cum[i + 1] - cum[i]) * (x - i as f64)
    };
    let sun_t = |t: f64| -> f64 {
        let x = o + d * t;
        let xu = (x - ctx.box_min) / ctx.extent;
        match unit_cube_chord(xu, sun / ctx.extent) {
            Some((_, s1)) if s1 > 0.0 => (-ctx.depth(x, sun, 0.0, s1)).exp(),
            _ => 1.0,
        }
    };
    let absorbed = 1.0 - (-total).exp();
    // The pins' intervals: 32 equal parts of the whole chord.
    let len = (tx - te) / 32.0;
    let taus: Vec<f64> = (0..32)
        .map(|i| tau_at(te + (i + 1) as f64 * len) - tau_at(te + i as f64 * len))
        .collect();
    let mut rng = Rng::for_query(seed, 0x55);
    let (mut exact, mut placed) = (0.0, 0.0);
    for k in 0..M {
        let u = (k as f64 + f64::from(rng.next_f32())) / M as f64 * absorbed;
        // Exact: the optical depth at which the collision happens.
        exact += sun_t(t_at(-(1.0 - u).ln()));
        // Pins: the interval whose cumulative collision probability passes u, then uniform.
        let mut before = 1.0;
        let mut j = 31;
        for (i, &tau) in taus.iter().enumerate() {
            let after = before * (-tau).exp();
            if 1.0 - after >= u {
                j = i;
                break;
            }
            before = after;
        }
        let t = te + (j as f64 + f64::from(rng.next_f32())) * len;
        placed += sun_t(t.max(ta));
    }
    (absorbed * exact / M as f64, absorbed * placed / M as f64)
}

/// The `scatter` family's samplers (camera rays, shadow rays) and samples per pixel; `parts`:
/// also models a-d for the shadow rays.
#[derive(Clone, Copy)]
struct Scatter<'a> {
    camera: &'a pinrt::Sampler<'a>,
    shadow: &'a pinrt::Sampler<'a>,
    samples: u32,
    parts: bool,
}

/// Single scattering toward the sun along the camera ray `o + t d`, the collision and the
/// shadow ray's transmittance each either exact or from the runtime's sampler (`pinrender
/// render`'s lookup): `[exact, pins for both, pins for the collision only, pins for the
/// shadow ray only]`, each `E[1{collision} T_sun(x)]` over `m` samples. The exact collisions
/// are stratified; the pins' collisions are the sampler's own draws.
fn scatter(
    ctx: &Ctx<'_>,
    q: &Scatter<'_>,
    o: DVec3,
    d: DVec3,
    sun: DVec3,
    seed: u32,
) -> ([f64; 6], [f64; 6]) {
    let Scatter {
        camera: sampler,
        shadow: shadow_sampler,
        samples: m,
        parts: with_parts,
    } = *q;
    let f3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
    let ou = (o - ctx.box_min) / ctx.extent;
    let du = d / ctx.extent;
    let Some((te, tx)) = unit_cube_chord(ou, du) else {
        return ([0.0; 6], [0.0; 6]);
    };
    let ta = te.max(0.0);
    if !(tx > ta) {
        return ([0.0; 6], [0.0; 6]);
    }
    let n = ((tx - ta) * d.length() / ctx.fine).ceil().max(1.0) as usize;
    let h = (tx - ta) / n as f64;
    let mut cum = vec![0.0f64; n + 1];
    for i in 0..n {
        let t = ta + (i as f64 + 0.5) * h;
        cum[i + 1] = cum[i] + f64::from(ctx.src.extinction(o + d * t)) * h * d.length();
    }
    let total = cum[n];
    let t_at = |tau: f64| -> f64 {
        let i = cum.partition_point(|&c| c < tau).clamp(1, n);
        let (c0, c1) = (cum[i - 1], cum[i]);
        let f = if c1 > c0 { (tau - c0) / (c1 - c0) } else { 0.5 };
        ta + (i as f64 - 1.0 + f.clamp(0.0, 1.0)) * h
    };
    let sun_exact = |x: DVec3| -> f64 {
        let xu = (x - ctx.box_min) / ctx.extent;
        match unit_cube_chord(xu, sun / ctx.extent) {
            Some((_, s1)) if s1 > 0.0 => (-ctx.depth(x, sun, 0.0, s1)).exp(),
            _ => 1.0,
        }
    };
    let mut rng = Rng::for_query(seed, 0x5ca7);
    let absorbed = 1.0 - (-total).exp();
    let mut sum = [0.0f64; 6];
    let mut parts = [0.0f64; 6];
    let cam = pinrt::Ray::new(f3(o), f3(d));
    for k in 0..m {
        if total > 1e-6 {
            let u = (f64::from(k) + f64::from(rng.next_f32())) / f64::from(m) * absorbed;
            let x = o + d * t_at(-(1.0 - u).ln());
            sum[0] += absorbed * sun_exact(x);
            let ray = pinrt::Ray::new(f3(x), f3(sun));
            sum[3] +=
                absorbed * f64::from(shadow_sampler.transmittance(&ray, f32::INFINITY, &mut rng));
            if with_parts {
                let mm = ctx.models(
                    x,
                    sun,
                    f64::INFINITY,
                    seed.wrapping_mul(977).wrapping_add(k),
                );
                for (p, v) in parts.iter_mut().zip(mm) {
                    *p += absorbed * v;
                }
            }
        }
        if let Some(t) = sampler.sample_distance(&cam, f32::INFINITY, &mut rng) {
            let x = o + d * f64::from(t);
            sum[2] += sun_exact(x);
            let ray = pinrt::Ray::new(f3(x), f3(sun));
            sum[1] += f64::from(shadow_sampler.transmittance(&ray, f32::INFINITY, &mut rng));
        }
    }
    // The collision of one lookup (the render's: middle, one cell of jitter), placed on the
    // query's line (as the runtime does) and on the pin's own line (nominal: through the
    // cell and direction-cell centres) at the same fraction of its chord; exact shadow ray.
    let du32 = du.as_vec3().to_array();
    let reversed = du32[2] < 0.0;
    let dl = if reversed {
        [-du32[0], -du32[1], -du32[2]]
    } else {
        du32
    };
    let nominal = PinLayout {
        jitter: false,
        ..ctx.layout
    };
    let (tm, len) = ((ta + tx) * 0.5, (tx - te) / 32.0);
    for _ in 0..m {
        let k = rng.below_256(ctx.view.shape.pins_per_entry);
        let sj = (ctx.jitter, [rng.next_f32(), rng.next_f32(), rng.next_f32()]);
        let dj = DirJitter {
            strength: ctx.jitter,
            xi: [rng.next_f32(), rng.next_f32()],
        };
        let pm = ou + du * tm;
        let cell = spatial_cell(pm.as_vec3().to_array(), &ctx.view, Some(sj));
        let dcell = direction_cell(&ctx.view.shape.directions, dl, Some(dj));
        let (t_min, mask) = oriented_entry(&ctx.view, cell, dcell, k, reversed);
        let s0 = (ta - te) / len;
        let mut hit = None;
        for i in 0..32usize {
            if mask & (1u32 << (31 - i)) == 0 || (i as f64 + 1.0) <= s0 {
                continue;
            }
            if f64::from(rng.next_f32()) < 1.0 - t_min {
                hit = Some(i as f64 + f64::from(rng.next_f32()));
                break;
            }
        }
        let Some(sc) = hit else { continue };
        let sc = sc.max(s0);
        sum[4] += sun_exact(o + d * (te + sc * len));
        let mut nrng = nominal.rng(0, 0, 0);
        let (pp, w) = nominal.line(cell, dcell, &mut nrng);
        let Some((c0, c1)) = unit_cube_chord(pp, w) else {
            continue;
        };
        let f = if reversed { 1.0 - sc / 32.0 } else { sc / 32.0 };
        let xu = pp + w * (c0 + (c1 - c0) * f);
        sum[5] += sun_exact(ctx.box_min + xu * ctx.extent);
    }
    (
        sum.map(|s| s / f64::from(m)),
        parts.map(|s| s / f64::from(m)),
    )
}

/// Ray parameter where the optical depth along `o + t d` from the box entry reaches `target`.
fn scatter_point(ctx: &Ctx<'_>, o: DVec3, d: DVec3, target: f64) -> f64 {
    let ou = (o - ctx.box_min) / ctx.extent;
    let du = d / ctx.extent;
    let Some((ta, tb)) = unit_cube_chord(ou, du) else {
        return 0.0;
    };
    let ta = ta.max(0.0);
    let n = ((tb - ta) * d.length() / ctx.fine).ceil().max(1.0) as usize;
    let h = (tb - ta) / n as f64;
    let mut acc = 0.0;
    for i in 0..n {
        let t = ta + (i as f64 + 0.5) * h;
        acc += f64::from(ctx.src.extinction(o + d * t)) * h * d.length();
        if acc >= target {
            return t;
        }
    }
    tb
}

/// (mean error %, 8x8 block RMS of the relative error %, 8x8 block RMS of the absolute error)
/// of model `m` against `exact` in family `fi`. Blocks without medium (exact mean above 0.99)
/// are left out of both RMS, and opaque blocks (exact mean below 0.02, where a relative error
/// of a transmittance says nothing about an image) out of the relative one.
fn errors(rows: &[[[f64; 6]; 5]], n: usize, fi: usize, m: usize) -> (f64, f64, f64) {
    let mean = |k: usize| rows.iter().map(|r| r[fi][k]).sum::<f64>() / rows.len() as f64;
    let me = 100.0 * (mean(m) - mean(0)) / mean(0);
    let (mut r2, mut rc, mut a2, mut ac) = (0.0, 0usize, 0.0, 0usize);
    for by in 0..n / 8 {
        for bx in 0..n / 8 {
            let (mut e, mut x) = (0.0, 0.0);
            for y in 0..8 {
                for xx in 0..8 {
                    let r = rows[(by * 8 + y) * n + bx * 8 + xx][fi];
                    e += r[0] / 64.0;
                    x += r[m] / 64.0;
                }
            }
            if e < 0.99 {
                a2 += (x - e).powi(2);
                ac += 1;
                if e > 0.02 {
                    r2 += ((x - e) / e).powi(2);
                    rc += 1;
                }
            }
        }
    }
    (
        me,
        100.0 * (r2 / rc.max(1) as f64).sqrt(),
        (a2 / ac.max(1) as f64).sqrt(),
    )
}

/// Model `a` must be what the product sampler returns on average: 24 rays, its mean over 4096
/// draws against ours over 4096 lookups, within 5 standard errors.
fn check_against_sampler(ctx: &Ctx<'_>, grid: &PinGrid) -> Result<()> {
    let opts = pinrt::SamplerOptions {
        spatial_jitter: ctx.jitter,
        directional_jitter: ctx.jitter,
        midpoint_lookup: ctx.middle,
        ..pinrt::SamplerOptions::THESIS
    };
    let sampler = pinrt::Sampler::new(grid)?.with_options(opts);
    let check = Ctx {
        draws: 4096,
        taus: Mutex::new(HashMap::new()),
        ..*ctx
    };
    let centre = ctx.box_min + ctx.extent * 0.5;
    let mut rng = Rng::for_query(99, 1);
    let mut worst = 0.0f64;
    for i in 0..24 {
        let dir = loop {
            let v = DVec3::new(
                rng.next_f32().into(),
                rng.next_f32().into(),
                rng.next_f32().into(),
            ) * 2.0
                - 1.0;
            if v.length() > 0.1 && v.length() < 1.0 {
                break v.normalize();
            }
        };
        // Off the box centre: without jitter a ray through a cell corner would read a cell
        // chosen by the last bit of rounding, differently here and in the sampler.
        let off = DVec3::new(
            rng.next_f32().into(),
            rng.next_f32().into(),
            rng.next_f32().into(),
        ) - 0.5;
        let o = centre + off * ctx.extent * 0.3 - dir * ctx.extent.length();
        let ours = check.models(o, dir, f64::INFINITY, i)[1];
        let f3 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32];
        let theirs =
            sampler.mean_transmittance(&pinrt::Ray::new(f3(o), f3(dir)), f32::INFINITY, 4096, i);
        // Standard error of each mean: at most 0.5 / sqrt(4096) (a [0, 1] variable).
        worst = worst.max((ours - theirs).abs() / (0.5 / 64.0 * 2f64.sqrt()));
    }
    eprintln!("model a against the sampler: worst |z| {worst:.2} over 24 rays");
    if worst > 5.0 {
        return Err(anyhow!(
            "model a disagrees with the sampler (|z| {worst:.2})"
        ));
    }
    Ok(())
}
