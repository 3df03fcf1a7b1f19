//! `pinrender bench`: queries per second of pins (`pins`: one query at a time;
//! `pins-batched`: the prefetching batch API, both on a `--cells`^3 bake;
//! `pins-default-batched`: the batch API on the bake `pinbake bake` chooses for the volume,
//! the file a user gets; these three with the thesis' lookup, `SamplerOptions::THESIS`;
//! `pins-render-batched`: the bake `pinbake bake` chooses with the default lookup, the one
//! `pinrender render` uses, `SamplerOptions::RENDER`: jitter, middle lookup, the
//! nearest-line search) vs ray
//! marching the source density at
//! relative steps 0.015 and 0.005, ratio, residual ratio and delta tracking over a majorant
//! grid (`ratio`, `residual` with the mean control, `residual@min`, `delta`), unbiased ray marching (`urm`) and jackknife transmittance (`jackknife`),
//! and unbiased ray marching around the pins' answer (`pinurm@4`, `pinurm@8`, `pinurm@16`:
//! the default bake with the render's lookup as the control; `pinurm@8/pins=1`: the control
//! from one pin query instead of the mean of eight), on
//! the same random rays, CPU single thread and wgpu. Transmittance rows also
//! carry their mean absolute error against a converged per-ray reference (ray marching at
//! step [`REFERENCE_STEP`]) over the first [`ERROR_RAYS`] rays. The `ratio`, `residual`,
//! `residual@min`, `urm` and `pinurm@N` transmittance rows also carry their variance per
//! density lookup on the first [`VARIANCE_RAYS`] rays (`per_ray_variance`,
//! `lookups_per_query`, `variance_x_lookups`; `pinurm` also reads one pin per query, which
//! its `queries_per_s` counts and `lookups_per_query` does not).
//!
//! CPU rows are timed by wall time (`queries_per_s`) and by the thread's CPU time
//! (`cpu_queries_per_s`); the printed ratios use the CPU rates, which a shared machine does
//! not skew row by row.

use pin_volume::DensitySource;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use anyhow::{Result, anyhow};
use clap::Args;
use glam::DVec3;
use glam::Vec3;
use pin_volume::{Aabb, DenseGrid, ProceduralSpec};
use pinlab::{CombKind, PINURM_DEFAULT_PIN_QUERIES, PinControlledUrm};
use pinrender::render::{
    BakedResidualTracking, DeltaTracking, Density, MajorantGrid, Pcg32, PinsEstimator,
    RatioTracking, ResidualControl, ResidualRatioTracking, TransportEstimator,
};
use pinrt::march::{self, MarchBox};
use pinrt::{PinGrid, RayQuery, Rng, SamplerOptions};
use serde_json::{Value, json};

use crate::volume::{self, TrackedSource, VolumeArgs};

#[derive(Args, Debug)]
pub struct RenderBenchArgs {
    /// Pin file to benchmark (default: bake each volume once, cached in the private
    /// per-user directory $XDG_CACHE_HOME/pinbake or ~/.cache/pinbake).
    #[arg(long)]
    pub pins: Option<PathBuf>,
    #[command(flatten)]
    pub volume: VolumeArgs,
    /// Random rays per measurement (ray marching uses a quarter of them; 1..=10^8).
    #[arg(long, default_value_t = 200_000, value_parser = parse_rays)]
    pub rays: usize,
    /// Spatial cells per axis when baking (the thesis' 37; with the default direction set of
    /// `pinbake bake`, octahedral:16, and pins through cell centres; 1..=4096).
    #[arg(long, default_value_t = 37, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub cells: u32,
    /// Refuse a configuration that needs more than this many bytes of memory (K/M/G/T
    /// suffixes; default: half of the physical memory).
    #[arg(long, value_parser = pin_cli::parse::parse_bytes)]
    pub max_memory: Option<u64>,
    /// Skip the wgpu measurements.
    #[arg(long)]
    pub no_gpu: bool,
    /// The `pinres` rows' control: source voxels per brick edge (`pinbake bake
    /// --embed-control EDGE`; 1..=64; default: the bake's default, 4 or coarser so that the
    /// longest axis has about 64 bricks).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub pinres_edge: Option<u32>,
    /// The `pinres` rows' residual majorant as a fraction of the brick's largest residual
    /// (1, the default, bounds it; (0, 1]).
    #[arg(long, default_value_t = 1.0)]
    pub pinres_floor: f64,
    /// The `pinres` rows' control weights `exp(-2 THICKNESS sigma edge)` (0: the plain mean;
    /// >= 0).
    #[arg(long, default_value_t = 1.0)]
    pub pinres_thickness: f64,
    /// Print one JSON object: {"results": [{volume, method, query, backend, queries_per_s,
    /// cpu_queries_per_s?, mean_abs_error?, error_rays?, per_ray_variance?,
    /// lookups_per_query?, variance_x_lookups?, variance_rays?, bake?, pin_bytes?}, ...]}
    /// (queries_per_s over wall time; cpu_queries_per_s over the thread's CPU time, on CPU
    /// rows; the error fields on transmittance rows; the variance fields on the ratio,
    /// residual, urm and pinurm transmittance rows; bake and pin_bytes on pin rows; query
    /// is "transmittance", "distance", or "both" for the GPU's combined dispatch).
    #[arg(long)]
    pub json: bool,
    /// Folder of the sample volumes (default: $PINBAKE_DATA, else the repository's data/
    /// found from the executable or the working directory).
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
}

/// Relative step of the per-ray reference (1/4000 of the longest edge: 1/16 of a voxel of
/// the 256^3 noise; the midpoint rule's error is then far below any estimator's here).
pub const REFERENCE_STEP: f64 = 0.00025;
/// Majorant bricks per axis for the `urm` and `jackknife` rows, as `pinrender render`'s
/// default (the grid sets their lookups per majorant optical depth).
pub const MAJORANT_BRICKS: u32 = 16;
/// Rays (the first ones of each volume) over which the mean absolute errors are taken.
pub const ERROR_RAYS: usize = 2000;
/// Rays (the first ones of each volume) and estimates per ray of the variance-per-lookup
/// measurement of the ratio-tracking, `urm` and `pinurm` rows.
pub const VARIANCE_RAYS: usize = 1000;
pub const VARIANCE_REPEATS: u64 = 64;

/// A field that counts its lookups. It has no dense view, so a tracker over it asks
/// `extinction` at every tentative collision: its count is the tracker's lookups.
struct Counted {
    inner: Arc<dyn DensitySource>,
    lookups: AtomicU64,
}

impl Density for Counted {
    fn bounds(&self) -> Aabb {
        self.inner.bounds()
    }
    fn extinction(&self, p: DVec3) -> f32 {
        self.lookups.fetch_add(1, Ordering::Relaxed);
        self.inner.extinction(p)
    }
    /// No bound: the majorant grid samples a lattice, as for any field without one.
    fn max_extinction_in(&self, _region: Aabb) -> f32 {
        f32::INFINITY
    }
}

/// `pinres` bakes its control from the counted field.
impl DensitySource for Counted {}

/// Per-ray variance and lookups of a transmittance estimator over `rays`: for each ray
/// `VARIANCE_REPEATS` estimates (fixed seeds), the mean of the rays' sample variances, and
/// the lookups per query that `counted` saw. `variance_x_lookups` is their product, the
/// variance of one lookup's worth of estimate: lower is better at equal lookups.
fn variance_per_lookup(
    est: &dyn TransportEstimator,
    counted: &Counted,
    rays: &[RayQuery],
    row: &mut Value,
) {
    let before = counted.lookups.load(Ordering::Relaxed);
    let mut var_sum = 0.0;
    for (i, r) in rays.iter().enumerate() {
        let (o, d) = (Vec3::from(r.origin), Vec3::from(r.dir));
        let mut rng = Pcg32::new(31, i as u64);
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..VARIANCE_REPEATS {
            let t = f64::from(est.transmittance(o, d, f32::INFINITY, &mut rng));
            s += t;
            s2 += t * t;
        }
        let n = VARIANCE_REPEATS as f64;
        let m = s / n;
        var_sum += (s2 / n - m * m).max(0.0) * n / (n - 1.0);
    }
    let queries = rays.len() as u64 * VARIANCE_REPEATS;
    let lookups = (counted.lookups.load(Ordering::Relaxed) - before) as f64 / queries as f64;
    let var = var_sum / rays.len().max(1) as f64;
    row["per_ray_variance"] = json!(var);
    row["lookups_per_query"] = json!(lookups);
    row["variance_x_lookups"] = json!(var * lookups);
    row["variance_rays"] = json!(rays.len());
}

/// The 256^3 voxelised cosine noise of the benchmark (no file needed).
fn noise_volume() -> Result<Arc<dyn DensitySource>> {
    let spec: ProceduralSpec = "cosine:seed=11,freq=8,density=4"
        .parse()
        .map_err(|e| anyhow!("{e}"))?;
    let noise = spec.build_noise()?;
    let n = 256usize;
    let h = 1.0 / n as f64;
    let mut data = vec![0.0f32; n * n * n];
    for (i, row) in data.chunks_mut(n).enumerate() {
        let start = DVec3::new(
            0.5 * h,
            ((i % n) as f64 + 0.5) * h,
            ((i / n) as f64 + 0.5) * h,
        );
        noise.extinction_along(start, DVec3::new(h, 0.0, 0.0), n, row);
    }
    Ok(Arc::new(DenseGrid::new(
        [n as u32; 3],
        data,
        DVec3::splat(h),
        DVec3::ZERO,
        "cosine noise 256^3",
    )?))
}

fn parse_rays(s: &str) -> Result<usize, String> {
    let n: usize = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    if !(1..=100_000_000).contains(&n) {
        return Err(format!("{n} is not in 1..=100000000"));
    }
    Ok(n)
}

/// The benchmark's pin cache: `$XDG_CACHE_HOME/pinbake` (absolute paths only, as the XDG
/// spec says) or `~/.cache/pinbake`, created 0700 and refused unless it is a directory we
/// own that nobody else can write. A predictable path in the shared /tmp let any user plant
/// a file that the benchmark then measured.
fn cache_dir() -> Result<PathBuf> {
    let base = match std::env::var_os("XDG_CACHE_HOME").map(PathBuf::from) {
        Some(p) if p.is_absolute() => p,
        _ => match std::env::var_os("HOME").map(PathBuf::from) {
            Some(h) if h.is_absolute() => h.join(".cache"),
            _ => {
                anyhow::bail!("no cache directory: set HOME or XDG_CACHE_HOME, or pass --pins FILE")
            }
        },
    };
    let dir = base.join("pinbake");
    pin_volume::files::ensure_private_dir(&dir)?;
    Ok(dir)
}

/// The two bakes a volume is measured with when no `--pins` is given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum BenchBake {
    /// `--cells`^3 cells (the thesis' 37) with the library's default direction set: the
    /// `pins` and `pins-batched` rows.
    Cells(u32),
    /// What `pinbake bake` writes for the volume without options (cells and directions
    /// chosen from the volume): the `pins-default-batched` rows, the file a user gets.
    Default,
}

/// Bakes (or reuses a cached bake of) the pins for a benchmark volume. A cached file is used
/// only when it is a regular file of ours that verifies and was baked from the same settings.
fn cached_pins(name: &str, source: &dyn DensitySource, bake: BenchBake) -> Result<PinGrid> {
    let dir = cache_dir()?;
    let safe_name: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    // What the cached file must have been baked with: the library's defaults at `cells`, or
    // the chooser's choice for the volume. Directions and pin placement are part of it, so a
    // file of an earlier default (another direction set, jittered pins) is baked again
    // rather than measured.
    let (tag, opts) = match bake {
        BenchBake::Cells(cells) => (
            cells.to_string(),
            pinbake::BakeOptions {
                cells: [cells; 3],
                ..pinbake::BakeOptions::default()
            },
        ),
        BenchBake::Default => {
            let defaults = pinbake::BakeOptions::default();
            let stats = pinbake::choose::analyse(source, defaults.crop)?;
            let c = pinbake::choose::choose_default(&stats, pinbake::choose::Fixed::default());
            (
                "default".to_string(),
                pinbake::BakeOptions {
                    cells: c.cells,
                    directions: c.directions,
                    pins_per_entry: c.pins_per_entry,
                    ..defaults
                },
            )
        }
    };
    let path = dir.join(format!(
        "bench-{safe_name}-{tag}-v{}.pin",
        env!("CARGO_PKG_VERSION")
    ));
    let jittered = |g: &PinGrid| g.desc().flags & pin_format::layout::GRID_FLAG_JITTERED_PINS != 0;
    if pin_volume::files::check_input(&path).is_ok()
        && let Ok(g) = PinGrid::open(&path)
        && g.verify().is_ok()
        && g.desc().dims == opts.cells
        && (g.desc().direction_kind, g.desc().direction_res) == opts.directions.to_desc()
        && g.desc().pins_per_entry == opts.pins_per_entry
        && jittered(&g) == opts.jitter_pins
        && g.desc().seed == opts.seed
        && g.desc().source_box_min == source.bounds().min.to_array()
        && g.desc().source_box_max == source.bounds().max.to_array()
    {
        return Ok(g);
    }
    pin_cli::errln!(
        "pinrender bench: baking {name} ({:?} cells x {} directions) once into {}",
        opts.cells,
        opts.directions.count(),
        path.display()
    );
    let (grid, _) = pinbake::bake(source, &opts, &|_| {})?;
    pin_volume::files::write_pin_atomic(&grid, &pin_volume::files::check_output(&path, &[])?)?;
    PinGrid::open(&path).map_err(|e| anyhow!("{e}"))
}

/// Rays from uniform points of the box in uniform directions, to the box exit.
fn random_rays(source: &dyn DensitySource, n: usize) -> Vec<RayQuery> {
    let b = source.bounds();
    let mut rng = Rng::for_query(12345, 0);
    (0..n)
        .map(|_| {
            let u = DVec3::new(
                f64::from(rng.next_f32()),
                f64::from(rng.next_f32()),
                f64::from(rng.next_f32()),
            );
            let o = b.min + u * b.extent();
            let z = 2.0 * rng.next_f32() - 1.0;
            let phi = std::f32::consts::TAU * rng.next_f32();
            let r = (1.0 - z * z).max(0.0).sqrt();
            RayQuery::new(
                o.as_vec3().to_array(),
                [r * phi.cos(), r * phi.sin(), z],
                f32::INFINITY,
            )
        })
        .collect()
}

/// A row's rate, queries per second of wall time and of the thread's CPU time. On a shared
/// machine the wall rate of a row depends on what else ran during that row's window, so
/// ratios between rows are taken from the CPU rates (the CPU rows run on this one thread).
#[derive(Clone, Copy, Debug)]
struct Rate {
    wall: f64,
    /// `None` on the GPU, whose work is not this thread's.
    cpu: Option<f64>,
}

/// Wall and thread CPU time since [`Clock::start`].
struct Clock {
    wall: Instant,
    cpu: f64,
}

impl Clock {
    fn start() -> Self {
        Self {
            wall: Instant::now(),
            cpu: pinlab::cpu_time::thread_s(),
        }
    }

    fn wall_s(&self) -> f64 {
        self.wall.elapsed().as_secs_f64()
    }

    /// The rate of `queries` queries answered since the start.
    fn rate(&self, queries: usize) -> Rate {
        let wall = self.wall_s();
        let cpu = pinlab::cpu_time::thread_s() - self.cpu;
        Rate {
            wall: queries as f64 / wall,
            cpu: (cpu > 0.0 && cpu.is_finite()).then(|| queries as f64 / cpu),
        }
    }
}

/// Each ray's transmittance to infinity from one estimator, on this thread, and its rate.
fn timed_transmittance(
    est: &dyn TransportEstimator,
    rays: &[RayQuery],
    rng: &mut Pcg32,
) -> (Vec<f64>, Rate) {
    let t = Clock::start();
    let values = rays
        .iter()
        .map(|r| {
            let (o, d) = (Vec3::from(r.origin), Vec3::from(r.dir));
            f64::from(est.transmittance(o, d, f32::INFINITY, rng))
        })
        .collect();
    (values, t.rate(rays.len()))
}

fn row(volume: &str, method: &str, query: &str, backend: &str, rate: Rate) -> Value {
    let mut r = json!({"volume": volume, "method": method, "query": query, "backend": backend, "queries_per_s": rate.wall});
    if let Some(cpu) = rate.cpu {
        r["cpu_queries_per_s"] = json!(cpu);
    }
    r
}

/// A GPU row: timed end to end in wall time.
fn gpu_rate(qps: f64) -> Rate {
    Rate {
        wall: qps,
        cpu: None,
    }
}

/// A transmittance row with its mean absolute error against `reference` (per ray, the first
/// `min(estimates, reference)` rays).
fn row_err(
    volume: &str,
    method: &str,
    backend: &str,
    rate: Rate,
    estimates: &[f64],
    reference: &[f64],
) -> Value {
    let n = estimates.len().min(reference.len());
    let mae = estimates[..n]
        .iter()
        .zip(&reference[..n])
        .map(|(e, r)| (e - r).abs())
        .sum::<f64>()
        / n.max(1) as f64;
    let mut r = row(volume, method, "transmittance", backend, rate);
    r["mean_abs_error"] = json!(mae);
    r["error_rays"] = json!(n);
    r
}

/// Adds what a pin row was measured on: `bake` ("37x37x37 x octahedral:16") and
/// `pin_bytes` (the grid's size, which decides whether its queries hit the caches).
fn describe_bake(grid: &PinGrid, rows: &mut [Value]) {
    let d = grid.desc();
    let dirs = match pinrt::Directions::from_desc(d.direction_kind, d.direction_res) {
        Ok(pinrt::Directions::Octahedral { n }) => format!("octahedral:{n}"),
        Ok(pinrt::Directions::Polar { n_phi, n_theta }) => format!("polar:{n_phi}x{n_theta}"),
        Err(_) => "?".to_string(),
    };
    let bake = format!("{}x{}x{} x {dirs}", d.dims[0], d.dims[1], d.dims[2]);
    for r in rows {
        r["bake"] = json!(bake);
        r["pin_bytes"] = json!(grid.bytes().len());
    }
}

/// Wall time the `pins-batched` rows repeat their passes for, at least.
const MIN_BATCHED_S: f64 = 0.1;

/// Queries per second of `pass(0)`, `pass(1)`, ... (each `queries` queries), repeated
/// until [`MIN_BATCHED_S`] of wall time: total queries over total time.
fn repeated_rate(queries: usize, mut pass: impl FnMut(u32)) -> Rate {
    let t = Clock::start();
    let mut passes = 0usize;
    loop {
        pass(passes as u32);
        passes += 1;
        if t.wall_s() >= MIN_BATCHED_S {
            return t.rate(queries * passes);
        }
    }
}

fn bench_volume(
    name: &str,
    source_arc: &Arc<dyn DensitySource>,
    grid: &Arc<PinGrid>,
    args: &RenderBenchArgs,
    default_grid: Option<&Arc<PinGrid>>,
    gpu: Option<&pinrt::gpu::GpuContext>,
    rows: &mut Vec<Value>,
) -> Result<()> {
    let source: &dyn DensitySource = source_arc.as_ref();
    let rays = random_rays(source, args.rays);
    let sampler = grid.sampler()?.with_options(SamplerOptions::THESIS);
    let b = source.bounds();
    let mbox = MarchBox {
        min: b.min,
        max: b.max,
    };
    let density = |p: DVec3| source.extinction(p);
    let ray_od = |r: &RayQuery| {
        (
            DVec3::from(r.origin.map(f64::from)),
            DVec3::from(r.dir.map(f64::from)),
        )
    };
    let n_err = rays.len().min(ERROR_RAYS);
    let reference: Vec<f64> = rays[..n_err]
        .iter()
        .map(|r| {
            let (o, d) = ray_od(r);
            march::transmittance(density, &mbox, o, d, f64::INFINITY, REFERENCE_STEP)
        })
        .collect();
    // Pins, one thread: `pins` answers one query at a time (one generator running through
    // the rays, as a renderer without batching calls it), `pins-batched` the same rays
    // through the prefetching batch API. A warm-up pass first so that page faults of the
    // mmap are not timed.
    let mut t_out = vec![0.0f32; rays.len()];
    let mut d_out = vec![None; rays.len()];
    let mut est_batched = Vec::new();
    sampler.transmittance_batch(&rays, 1, 0, &mut t_out);
    let mut rng = Rng::for_query(2, 0);
    let t = Clock::start();
    for (o, r) in t_out.iter_mut().zip(&rays) {
        *o = sampler.transmittance(&r.ray(), r.t_max, &mut rng);
    }
    let qps = t.rate(rays.len());
    let est: Vec<f64> = t_out.iter().map(|&t| f64::from(t)).collect();
    rows.push(row_err(name, "pins", "cpu", qps, &est, &reference));
    let mut rng = Rng::for_query(3, 0);
    let t = Clock::start();
    for (o, r) in d_out.iter_mut().zip(&rays) {
        *o = sampler.sample_distance(&r.ray(), r.t_max, &mut rng);
    }
    let qps = t.rate(rays.len());
    std::hint::black_box(&d_out);
    rows.push(row(name, "pins", "distance", "cpu", qps));
    // One batched pass over 200,000 rays takes ~10 ms, short enough for one preemption of
    // a loaded machine to halve its rate; so passes repeat (with fresh seeds) until
    // `MIN_BATCHED_S`, and the rate is the mean over all of them (not the best pass).
    let first = rows.len() - 2;
    let mut batched = |method: &str,
                       grid: &PinGrid,
                       lookup: SamplerOptions,
                       rows: &mut Vec<Value>|
     -> Result<()> {
        let sampler = grid.sampler()?.with_options(lookup);
        let first = rows.len();
        sampler.transmittance_batch(&rays, 1, 0, &mut t_out);
        let qps = repeated_rate(rays.len(), |pass| {
            sampler.transmittance_batch(&rays, 2 + 2 * pass, 0, &mut t_out);
            if pass == 0 {
                est_batched = t_out.iter().map(|&t| f64::from(t)).collect();
            }
        });
        rows.push(row_err(name, method, "cpu", qps, &est_batched, &reference));
        let qps = repeated_rate(rays.len(), |pass| {
            sampler.sample_distance_batch(&rays, 3 + 2 * pass, 0, &mut d_out);
        });
        std::hint::black_box(&d_out);
        rows.push(row(name, method, "distance", "cpu", qps));
        describe_bake(grid, &mut rows[first..]);
        Ok(())
    };
    // The thesis' lookup on both bakes, against which `pins-render-batched` is compared.
    batched("pins-batched", grid, SamplerOptions::THESIS, rows)?;
    describe_bake(grid, &mut rows[first..]);
    if let Some(g) = default_grid {
        batched("pins-default-batched", g, SamplerOptions::THESIS, rows)?;
        // What a render pays per query, and how near its answers are.
        batched("pins-render-batched", g, SamplerOptions::RENDER, rows)?;
    }

    let n_rm = (rays.len() / 4).max(1);
    for step in [0.015, 0.005] {
        let t = Clock::start();
        let mut est = Vec::with_capacity(n_rm);
        for r in &rays[..n_rm] {
            let (o, d) = ray_od(r);
            est.push(march::transmittance(
                density,
                &mbox,
                o,
                d,
                f64::INFINITY,
                step,
            ));
        }
        let qps = t.rate(n_rm);
        let method = format!("rm@{step}");
        rows.push(row_err(name, &method, "cpu", qps, &est, &reference));
        let t = Clock::start();
        let mut hits = 0usize;
        for (i, r) in rays[..n_rm].iter().enumerate() {
            let mut rng = Rng::for_query(4, i as u32);
            let o = DVec3::from(r.origin.map(f64::from));
            let d = DVec3::from(r.dir.map(f64::from));
            hits += march::sample_distance(density, &mbox, o, d, f64::INFINITY, step, &mut rng)
                .is_some() as usize;
        }
        std::hint::black_box(hits);
        rows.push(row(name, &method, "distance", "cpu", t.rate(n_rm)));
    }

    // The comb estimators at their default lookups, on the same rays as ray marching, as
    // the path tracer builds them: combs and their majorant-depth rule over a majorant grid
    // of the source (built once, not timed).
    let field = Arc::new(TrackedSource::new(source_arc.clone()));
    let majorants = volume::majorants(&field, MAJORANT_BRICKS)?;
    // The trackers production renderers use, over the same majorant grid and rays: ratio
    // tracking (transmittance; its distances are delta tracking's), residual ratio tracking
    // with either control (controls computed once, not timed) and delta tracking.
    let residual = |control| -> Result<Arc<ResidualRatioTracking>> {
        Ok(Arc::new(
            ResidualRatioTracking::new(
                field.clone() as Arc<dyn Density>,
                majorants.clone(),
                control,
            )
            .map_err(|e| anyhow!("{e}"))?,
        ))
    };
    let (residual_mean, residual_min) = (
        residual(ResidualControl::Mean)?,
        residual(ResidualControl::Min)?,
    );
    // `pinres`: the control section a bake with `--embed-control` stores, computed here over
    // the source's box (not timed), over `f`.
    let control = {
        let opts = pinbake::control::ControlOptions {
            dims: args
                .pinres_edge
                .map_or(pinbake::control::ControlDims::Auto, |e| {
                    pinbake::control::ControlDims::Edge(e)
                }),
            floor: args.pinres_floor,
            thickness: args.pinres_thickness,
            ..pinbake::control::ControlOptions::default()
        };
        pinbake::control::bake_control(source, &b, &opts)?
    };
    let pinres = |f: Arc<dyn DensitySource>| -> Result<Arc<dyn TransportEstimator>> {
        Ok(Arc::new(
            BakedResidualTracking::new(
                f,
                (b.min.to_array(), b.max.to_array()),
                control.dims,
                control.control.clone(),
                control.residual.clone(),
                control.majorant.clone(),
                None,
            )
            .map_err(|e| anyhow!("{e}"))?,
        ))
    };
    let trackers_first = rows.len();
    for (method, tracker) in [
        (
            "ratio",
            Arc::new(RatioTracking::new(field.clone(), majorants.clone()))
                as Arc<dyn TransportEstimator>,
        ),
        ("residual", residual_mean.clone()),
        ("residual@min", residual_min.clone()),
        ("pinres", pinres(field.clone())?),
        (
            "delta",
            Arc::new(DeltaTracking::new(field.clone(), majorants.clone())),
        ),
    ] {
        let mut rng = Pcg32::new(7, method.len() as u64);
        let (est, qps) = timed_transmittance(tracker.as_ref(), &rays[..n_rm], &mut rng);
        rows.push(row_err(name, method, "cpu", qps, &est, &reference));
        let t = Clock::start();
        let hits = rays[..n_rm]
            .iter()
            .filter(|r| {
                let (o, d) = (Vec3::from(r.origin), Vec3::from(r.dir));
                tracker
                    .sample_distance(o, d, f32::INFINITY, &mut rng)
                    .is_some()
            })
            .count();
        std::hint::black_box(hits);
        let qps = t.rate(n_rm);
        rows.push(row(name, method, "distance", "cpu", qps));
    }
    // Variance per lookup of the ratio-tracking family on the same rays: each over a field
    // that counts its lookups, residual ratio tracking with the controls computed above.
    let counted = Counted {
        inner: field.clone(),
        lookups: AtomicU64::new(0),
    };
    let counted = Arc::new(counted);
    let var_rays = &rays[..rays.len().min(VARIANCE_RAYS)];
    let with_controls = |est: &ResidualRatioTracking,
                         maj: &Arc<MajorantGrid>|
     -> Result<Arc<dyn TransportEstimator>> {
        let (controls, residual) = est.controls();
        Ok(Arc::new(
            ResidualRatioTracking::with_controls(
                counted.clone() as Arc<dyn DensitySource>,
                maj.clone(),
                controls.to_vec(),
                residual.to_vec(),
            )
            .map_err(|e| anyhow!("{e}"))?,
        ))
    };
    for (method, est) in [
        (
            "ratio",
            Arc::new(RatioTracking::new(
                counted.clone() as Arc<dyn DensitySource>,
                majorants.clone(),
            )) as Arc<dyn TransportEstimator>,
        ),
        ("residual", with_controls(&residual_mean, &majorants)?),
        ("residual@min", with_controls(&residual_min, &majorants)?),
        ("pinres", pinres(counted.clone())?),
    ] {
        let row = rows[trackers_first..]
            .iter_mut()
            .find(|r| r["method"] == method && r["query"] == "transmittance")
            .ok_or_else(|| anyhow!("no {method} row"))?;
        variance_per_lookup(est.as_ref(), &counted, var_rays, row);
    }
    for kind in [CombKind::Urm, CombKind::Jackknife] {
        let est = kind
            .build(field.clone(), majorants.clone(), kind.default_lookups())
            .map_err(|e| anyhow!("{e}"))?;
        let mut rng = Pcg32::new(6, kind as u64);
        let (est, qps) = timed_transmittance(est.as_ref(), &rays[..n_rm], &mut rng);
        let method = match kind {
            CombKind::Urm => "urm",
            CombKind::Jackknife => "jackknife",
        };
        rows.push(row_err(name, method, "cpu", qps, &est, &reference));
    }
    // Unbiased ray marching around the pin's answer, the pins a user renders with (the
    // default bake, the render's lookup) as the control, at three comb densities.
    let control_grid = default_grid.unwrap_or(grid);
    let pins = Arc::new(
        PinsEstimator::new(control_grid.clone(), None, SamplerOptions::RENDER)
            .map_err(|e| anyhow!("{e}"))?,
    );
    // (lookups per edge, pin queries per control): the default control at three comb
    // densities, and the control from one pin query.
    const PINURM_ROWS: [(u32, u32); 4] = [
        (4, PINURM_DEFAULT_PIN_QUERIES),
        (8, PINURM_DEFAULT_PIN_QUERIES),
        (16, PINURM_DEFAULT_PIN_QUERIES),
        (8, 1),
    ];
    let pinurm_method = |(lookups, queries): (u32, u32)| {
        if queries == PINURM_DEFAULT_PIN_QUERIES {
            format!("pinurm@{lookups}")
        } else {
            format!("pinurm@{lookups}/pins={queries}")
        }
    };
    let pinurm = |f: Arc<dyn DensitySource>,
                  (lookups, queries): (u32, u32)|
     -> Result<Arc<dyn TransportEstimator>> {
        Ok(Arc::new(
            PinControlledUrm::new(f, majorants.clone(), pins.clone(), lookups)
                .and_then(|e| e.with_pin_queries(queries))
                .map_err(|e| anyhow!("{e}"))?,
        ))
    };
    for (k, config) in PINURM_ROWS.into_iter().enumerate() {
        let est = pinurm(field.clone(), config)?;
        let mut rng = Pcg32::new(9, k as u64);
        let (est, qps) = timed_transmittance(est.as_ref(), &rays[..n_rm], &mut rng);
        // Spelled with its count even at the default, so the rows name their combs.
        let method = pinurm_method(config);
        rows.push(row_err(name, &method, "cpu", qps, &est, &reference));
    }
    // Their variance per density lookup, and urm's, over the counting field.
    let mut by_lookups: Vec<(String, Arc<dyn TransportEstimator>)> = vec![(
        "urm".into(),
        CombKind::Urm
            .build(
                counted.clone(),
                majorants.clone(),
                CombKind::Urm.default_lookups(),
            )
            .map_err(|e| anyhow!("{e}"))?,
    )];
    for config in PINURM_ROWS {
        by_lookups.push((pinurm_method(config), pinurm(counted.clone(), config)?));
    }
    for (method, est) in by_lookups {
        let row = rows[trackers_first..]
            .iter_mut()
            .find(|r| r["method"] == method.as_str() && r["query"] == "transmittance")
            .ok_or_else(|| anyhow!("no {method} row"))?;
        variance_per_lookup(est.as_ref(), &counted, var_rays, row);
    }

    if let Some(ctx) = gpu {
        use pinrt::gpu::QueryMode;
        let g = pinrt::gpu::GpuPinGrid::upload_with(ctx, grid, None, SamplerOptions::THESIS)?;
        // Timed per kind of query, as on the CPU: the transmittance-only and distance-only
        // entry points (each skips the other's work), then the combined dispatch that
        // answers both from one lookup (`both`). Each call is timed end to end (upload of
        // the rays, dispatch, read-back) on all the rays. One untimed call of each first
        // (pipelines, first allocations of the big buffers), then three rounds with the
        // modes interleaved, keeping each mode's fastest: lavapipe's threads share the CPU
        // with everything else, and the first full-size call of a run was measured ~2x
        // slower than the next whatever its mode.
        let modes = [
            (QueryMode::Transmittance, 5),
            (QueryMode::Distance, 6),
            (QueryMode::Both, 7),
        ];
        for (mode, _) in modes {
            g.run_queries_mode(&rays, 0, 0, mode)?;
        }
        let mut best = [f64::INFINITY; 3];
        let mut transmittances = Vec::new();
        for _ in 0..3 {
            for (k, (mode, seed)) in modes.into_iter().enumerate() {
                let t = Instant::now();
                let res = g.run_queries_mode(&rays, seed, 0, mode)?;
                best[k] = best[k].min(t.elapsed().as_secs_f64());
                if mode == QueryMode::Transmittance {
                    transmittances = res.iter().map(|q| f64::from(q.transmittance)).collect();
                }
            }
        }
        let qps = |k: usize| gpu_rate(rays.len() as f64 / best[k]);
        rows.push(row_err(
            name,
            "pins",
            "gpu",
            qps(0),
            &transmittances,
            &reference,
        ));
        rows.push(row(name, "pins", "distance", "gpu", qps(1)));
        rows.push(row(name, "pins", "both", "gpu", qps(2)));
    }
    Ok(())
}

pub fn run(args: RenderBenchArgs) -> Result<()> {
    if let Some(d) = &args.data {
        crate::data::set_dir(d.clone());
    }
    let budget = pin_volume::files::MemoryBudget::new(args.max_memory);
    // The rays, the two result arrays and the noise volume.
    budget.check(
        &format!("{} rays", args.rays),
        (args.rays as u64).saturating_mul(64) + 256u64.pow(3) * 4,
    )?;
    if args.pins.is_none() {
        let probe = pinbake::BakeOptions {
            cells: [args.cells; 3],
            ..pinbake::BakeOptions::default()
        };
        // The bake's output and its layered march's working set (up to ~110 MB, which the
        // check used to leave out).
        budget.check(
            &format!("baking {}^3 pin cells", args.cells),
            pinbake::bake::estimate_output_bytes(&probe)
                .saturating_add(pinbake::bake::estimate_working_bytes(&probe)),
        )?;
    }
    let mut volumes: Vec<(String, Arc<dyn DensitySource>)> = Vec::new();
    if let Some(v) = &args.volume.volume {
        volumes.push((
            v.display().to_string(),
            volume::open_volume(v, &args.volume)?,
        ));
    } else {
        let smoke = crate::data::path("openvdb_smoke1.vdb")?;
        if smoke.exists() {
            volumes.push(("smoke".into(), volume::open_volume(&smoke, &args.volume)?));
        } else {
            pin_cli::errln!(
                "pinrender bench: {} not found, skipping the smoke",
                smoke.display()
            );
        }
        volumes.push(("cosine256".into(), noise_volume()?));
    }
    let gpu = if args.no_gpu {
        None
    } else {
        Some(pinrt::gpu::GpuContext::new()?)
    };
    let mut rows = Vec::new();
    for (name, source) in &volumes {
        let grid = Arc::new(match &args.pins {
            Some(p) => {
                pin_volume::files::check_input(p)?;
                PinGrid::open(p).map_err(|e| anyhow!("{e}"))?
            }
            None => cached_pins(name, source.as_ref(), BenchBake::Cells(args.cells))?,
        });
        let default_grid = match &args.pins {
            Some(_) => None,
            None => Some(Arc::new(cached_pins(
                name,
                source.as_ref(),
                BenchBake::Default,
            )?)),
        };
        bench_volume(
            name,
            source,
            &grid,
            &args,
            default_grid.as_ref(),
            gpu.as_ref(),
            &mut rows,
        )?;
    }
    if args.json {
        pin_cli::outln!("{}", json!({"results": rows}))?;
        return Ok(());
    }
    if let Some(ctx) = &gpu {
        pin_cli::outln!("gpu: {}", ctx.describe())?;
    }
    pin_cli::outln!(
        "{:<12} {:<20} {:<14} {:<5} {:>14} {:>10} {:>10} {:>10}",
        "volume",
        "method",
        "query",
        "on",
        "queries/s",
        "batched/x",
        "default/x",
        "mean|err|"
    )?;
    // The CPU rate of `method`'s row for the same volume and query (thread CPU time on CPU
    // rows, see `Rate`; a GPU row is compared by wall rate).
    let rate_of = |r: &Value, method: &str, field: &str| {
        rows.iter()
            .find(|b| {
                b["volume"] == r["volume"]
                    && b["query"] == r["query"]
                    && b["backend"] == "cpu"
                    && b["method"] == method
            })
            .and_then(|b| b[field].as_f64())
            .unwrap_or(f64::NAN)
    };
    let ratio_text = |x: f64| {
        if x.is_finite() {
            format!("{x:.1}")
        } else {
            "-".into()
        }
    };
    for r in &rows {
        let q = r["queries_per_s"].as_f64().unwrap_or(f64::NAN);
        let (field, own) = match r["cpu_queries_per_s"].as_f64() {
            Some(c) => ("cpu_queries_per_s", c),
            None => ("queries_per_s", q),
        };
        let err = r["mean_abs_error"]
            .as_f64()
            .map_or(String::new(), |e| format!("{e:.2e}"));
        // The GPU's combined `both` row has no batched CPU counterpart.
        pin_cli::outln!(
            "{:<12} {:<20} {:<14} {:<5} {:>14.0} {:>10} {:>10} {:>10}",
            r["volume"].as_str().unwrap_or(""),
            r["method"].as_str().unwrap_or(""),
            r["query"].as_str().unwrap_or(""),
            r["backend"].as_str().unwrap_or(""),
            q,
            ratio_text(rate_of(r, "pins-batched", field) / own),
            ratio_text(rate_of(r, "pins-default-batched", field) / own),
            err
        )?;
    }
    Ok(())
}
