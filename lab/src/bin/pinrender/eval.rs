//! `pinrender eval`: error against run time of every estimator on the evaluation scenes.
//!
//! For each scene: a high-sample reference (cached on disk under `<out>/cache/`, keyed by the
//! scene parameters and [`REFERENCE_VERSION`]), the pins baked once (timed separately: an
//! offline asset step), then for each estimator a progressive render: passes of 1 spp with
//! distinct seeds are averaged, and whenever the accumulated wall time crosses one of the
//! budgets the running mean is compared with the reference (RMSE, relative MSE). This is
//! exactly what `Budget::Seconds(b)` does for each budget `b` (passes until the time is
//! spent, at least one), measured in one run per estimator instead of one per budget.
//! The radiance cache's training pass counts towards the time.
//!
//! Rows marked `(gpu)` (CSV: backend `gpu`) are the WGSL path tracer
//! ([`pinrender::gpu_render::GpuRenderer`]) with every estimator it has (`rm@STEP`, `delta`,
//! `ratio`, `urm`, `jackknife`, `pins`, `pinms`) over the scene's media as the CPU sees them: the same pin grid,
//! placements and lookup jitter, a GPU copy of the density ([`scenes::gpu_media`]) and the
//! CPU's majorant grids; measured the same way (`--gpu-batch` spp per render call, distinct
//! seeds, averaged); the one-time renderer setup (upload, pipeline compile) is reported but
//! not counted. `--no-gpu` skips them; without an adapter the run warns and the report says
//! "GPU: no adapter".
//!
//! Outputs (in `--out`), a contract that scripts rely on: `errors.csv` (header
//! `scene,estimator,backend,seconds,rmse,relmse,budget_s,spp`: the first six columns are
//! fixed, later ones may be added), `errors.png` (error against time per scene: the best
//! estimator without a bake, pins, PinMS and pinres), `summary.md` (the report, opening with
//! what the bake buys per scene); also `errors_all.png` (every estimator), `bake.csv`,
//! `error_vs_time_<scene>.png`, `images_<scene>.png`, `<scene>/<estimator>.exr` (the image at
//! the largest budget) and `<scene>/reference.exr`. With `--docs DIR` also
//! `DIR/eval/report.md` (the report, a file of its own) and the PNGs beside it.
//!
//! `--bytes` measures error against the bytes of the file a user ships instead ([`bytes`]:
//! `bytes.csv`, `bytes.png`, `bytes.md`).
//!
//! Each reference is rendered as two independent halves; half their RMSE against each other
//! is the reference's own noise, reported per scene, and a time-to-error target below twice
//! that noise prints "n/a (reference noise)" instead of a speedup that would measure noise.

mod asset_time;
mod bytes;
mod plot;
mod report;
mod scenes;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use pinlab::Estimator;
use pinlab::cache::{render_with_cache, train_cache};
use pinlab::whole_volume::{SingleScatterSampling, render_single_scattering};
use pinrender::gpu_render::{GpuEstimator, GpuPipelines, GpuRenderer, GpuScene};
use pinrender::medium::PlacedPins;
use pinrender::render::{
    Budget, DEFAULT_WAVEFRONT_BATCH, Image, Medium, RatioTracking, RenderOutput, RenderSettings,
    Scene, TransportEstimator, relative_mse, render, render_wavefront, rmse, splitmix64,
};
use pinrt::gpu::GpuContext;
use pinrt::{PinGrid, SamplerOptions};

use scenes::{EvalScene, RefKind, Sizes};

/// Bump when anything that changes reference images changes (renderer, scenes).
pub const REFERENCE_VERSION: &str = "eval-ref-v2";

#[derive(Args, Debug)]
#[command(after_help = "\
Scenes: smoke (OpenVDB smoke), hydrogen (raw u8 128^3), cosine (high-frequency cosine noise,
closed-form reference), box (homogeneous box, closed-form reference), box-ss (its single
scattering, whole-volume reference), instances (64 overlapping noise blobs); full runs only:
cloud (a 512^3 fractal cloud), production (the OpenVDB production cloud), cloudscape (256
turned and stretched instances of two fractal clouds).

Estimators: rm@STEP (ray marching), delta, ratio (trackers over a majorant grid), residual
(residual ratio tracking: a control extinction per majorant brick, the mean, or the minimum
with residual@min, times ratio tracking of the residual), urm[@N]
(unbiased ray marching), jackknife[@N] (jackknife transmittance; both: combs of N lookups per
longest box edge, delta tracking for distances), pins (pins for every ray), pinms (ratio
tracking for primary rays and single scattering, pins after), pinms+cache (pinms with the
hash-grid radiance cache), pinurm[@N] (unbiased ray marching around the pins' answer: the
pins give the control optical depth, combs of N lookups correct it; CPU only), pinres
(residual ratio tracking over the control the bake stores per brick: 4 voxels, coarser on
large volumes), cosine-closed-form / box-closed-form (exact transmittance),
whole-volume (box-ss only). rm@STEP, delta, ratio, residual, urm, jackknife, pins, pinms and
pinres also run on the GPU path tracer (rows marked '(gpu)', backend gpu in the CSV) unless --no-gpu.

Error against bytes (--bytes): each representation baked at a ladder of sizes into a file, rendered
from the file alone against the same reference; writes bytes.csv, bytes.png and bytes.md.

Example: pinrender eval --out out/eval --docs docs
         pinrender eval --bytes --out out/bytes")]
pub struct EvalArgs {
    /// Output directory.
    #[arg(long, default_value = "out/eval")]
    pub out: PathBuf,
    /// Small images, sub-second budgets and references, and only the estimators a user picks
    /// (the renderer's own, on the GPU pins and pinms; the lab's run when named in
    /// --estimators).
    #[arg(long)]
    pub quick: bool,
    /// Time budgets in seconds, comma separated (default 0.25,0.5,1,2,4,10,30,60; --quick
    /// 0.05,0.1,0.2). Each estimator renders once, progressively, and is measured at every
    /// budget: a run costs its longest budget per estimator, not the sum.
    #[arg(long, value_delimiter = ',')]
    pub budgets: Option<Vec<f64>>,
    /// Only these scenes (comma separated).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Option<Vec<String>>,
    /// Only these estimators (comma separated; rm@0.015 is needed for the time-to-error column).
    #[arg(long, value_delimiter = ',')]
    pub estimators: Option<Vec<String>>,
    /// Image edge in pixels for the volume scenes (box scenes use 1.5x).
    #[arg(long)]
    pub size: Option<u32>,
    /// Reference samples per pixel, base value (scaled per scene by its cost).
    #[arg(long)]
    pub ref_spp: Option<u32>,
    /// Recompute references even when cached.
    #[arg(long)]
    pub no_reference_cache: bool,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Worker threads (default: all cores; at most 64 per core and 4096).
    #[arg(long, value_parser = pinbake::cli_args::parse_threads)]
    pub threads: Option<usize>,
    /// Also write the report to DIR/eval/report.md, with copies of its PNGs beside it.
    #[arg(long)]
    pub docs: Option<PathBuf>,
    /// What a CPU row's time budget counts: `wall` seconds, or `cpu`: the process's CPU
    /// seconds divided by the worker threads, which on an idle machine is the wall time and
    /// on a shared one charges each estimator only for the CPU it got. `(gpu)` rows always
    /// count wall time (a hardware GPU's work is not this process's CPU time).
    #[arg(long, value_enum, default_value_t = Clock::Wall)]
    pub clock: Clock,
    /// Error against bytes instead of against time: each representation (pins alone at
    /// several cells and direction sets, the embedded f16 density dense and sparse with ratio
    /// tracking, the dense density with pins and PinMS) baked at a ladder of sizes and
    /// rendered from the file alone, against the converged reference: `bytes.csv`,
    /// `bytes.png`, `bytes.md` (scenes: smoke and hydrogen, or --scenes of
    /// smoke,hydrogen,production; --quick: smoke at 32 px).
    #[arg(long, conflicts_with_all = ["budgets", "estimators", "docs"])]
    pub bytes: bool,
    /// The default file's estimators at equal time: `pinbake bake` with no grid flags on
    /// each scene's volume, then every estimator that file answers alone and beside the
    /// volume, rendered until each budget (--budgets, default 0.1,1; --clock) against the
    /// converged reference: `asset_time.csv`, `asset_time.md` (scenes: smoke and hydrogen, or
    /// --scenes of smoke,hydrogen,production). Checks the default-estimator rule.
    #[arg(long, conflicts_with_all = ["bytes", "estimators", "docs", "quick"])]
    pub default_asset: bool,
    /// With --bytes, also the pins-per-byte experiments on the octahedral:8 pins ladder:
    /// t_min in 16 and 8 bits, near-empty entries left out (their bytes projected for the
    /// candidate format) and 4 pins per entry.
    #[arg(long, requires = "bytes")]
    pub pin_variants: bool,
    /// Do not measure the GPU path tracer (the `(gpu)` rows).
    #[arg(long)]
    pub no_gpu: bool,
    /// Samples per pixel per GPU render call (each call is one measured pass).
    #[arg(long, default_value_t = 1)]
    pub gpu_batch: u32,
    /// The production scene's OpenVDB cloud (default: production/cloud-half.vdb in the
    /// target directory that holds this executable, where `scripts/production/generate.sh
    /// half` writes it).
    #[arg(long, value_name = "FILE")]
    pub production: Option<PathBuf>,
    /// Folder of the sample volumes (default: $PINBAKE_DATA, else the repository's data/
    /// found from the executable or the working directory).
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
}

/// The longest budget the scenes' reference samples per pixel are sized for.
const REFERENCE_BUDGET_S: f64 = 4.0;

/// The quick run's budgets in seconds.
pub const QUICK_BUDGETS: [f64; 3] = [0.05, 0.1, 0.2];

/// The GPU rows of a quick run without --estimators: the estimators that read the bake (each
/// GPU estimator costs a pipeline compile per scene, seconds on lavapipe).
const QUICK_GPU: [&str; 2] = ["pins", "pinms"];

/// The full run's budgets in seconds: previews to final frames.
pub const FULL_BUDGETS: [f64; 8] = [0.25, 0.5, 1.0, 2.0, 4.0, 10.0, 30.0, 60.0];

/// The production scene's VDB: `--production`, else `production/cloud-half.vdb` in the target
/// directory of this executable (`target/release/pinrender` -> `target/production/`).
fn production_vdb(a: &EvalArgs) -> Result<std::path::PathBuf> {
    if let Some(p) = &a.production {
        return Ok(p.clone());
    }
    let exe = std::env::current_exe().context("locating pinrender")?;
    let target = exe.parent().and_then(|d| d.parent()).context(
        "pinrender's executable has no target directory above it; pass --production FILE",
    )?;
    Ok(target.join("production").join("cloud-half.vdb"))
}

/// The time source of the budgets (`--clock`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Clock {
    Wall,
    Cpu,
}

/// A stopwatch on [`Clock`]: `Cpu` reads the process's user + system time
/// (`getrusage(RUSAGE_SELF)`, every thread) and divides it by the worker threads.
struct Stopwatch {
    clock: Clock,
    threads: f64,
    wall: Instant,
    cpu: f64,
}

impl Stopwatch {
    fn start(clock: Clock, threads: usize) -> Self {
        Self {
            clock,
            threads: threads.max(1) as f64,
            wall: Instant::now(),
            cpu: pinlab::cpu_time::process_s(),
        }
    }

    fn seconds(&self) -> f64 {
        let wall = self.wall.elapsed().as_secs_f64();
        match self.clock {
            Clock::Wall => wall,
            Clock::Cpu => {
                let cpu = (pinlab::cpu_time::process_s() - self.cpu) / self.threads;
                // Without getrusage there is only the wall clock.
                if cpu.is_finite() { cpu } else { wall }
            }
        }
    }
}

/// Worker threads of the CPU rows (`--threads`, else every core).
fn worker_threads(a: &EvalArgs) -> usize {
    a.threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    })
}

/// The GPU for the `(gpu)` rows.
pub enum Gpu {
    /// `--no-gpu`.
    Off,
    /// No adapter (or the device failed to open): the message.
    NoAdapter(String),
    Ready {
        /// The context the run's device came from, open for the run.
        _ctx: Box<GpuContext>,
        /// The run's pipelines: each scene's renderer takes those an earlier scene of the same
        /// layout compiled (on lavapipe a compile takes seconds), and compiles the rest.
        store: Arc<GpuPipelines>,
        /// Adapter name, backend, device type, driver.
        describe: String,
        /// A CPU adapter (lavapipe / llvmpipe): Vulkan on CPU threads.
        software: bool,
        /// Context creation (adapter, device, pin shader), once per run, not in the times.
        seconds: f64,
    },
}

impl Gpu {
    fn open(no_gpu: bool) -> Self {
        if no_gpu {
            return Gpu::Off;
        }
        let t = Instant::now();
        match GpuContext::new() {
            Ok(ctx) => {
                let seconds = t.elapsed().as_secs_f64();
                let describe = ctx.describe();
                let software = ctx.adapter_info.device_type == wgpu::DeviceType::Cpu
                    || ctx.adapter_info.name.contains("llvmpipe");
                pin_cli::errln!("GPU: {describe} (context in {seconds:.2} s)");
                if software {
                    pin_cli::errln!(
                        "GPU: note: a software adapter (Vulkan on the CPU): the '(gpu)' \
                         timings measure the WGSL code path on CPU threads, not a GPU"
                    );
                }
                Gpu::Ready {
                    store: GpuPipelines::new(&ctx.device, &ctx.queue, &ctx.limits),
                    _ctx: Box::new(ctx),
                    describe,
                    software,
                    seconds,
                }
            }
            Err(e) => {
                pin_cli::errln!(
                    "warning: GPU: no adapter, the '(gpu)' rows are skipped ({e}); \
                     pass --no-gpu to silence this"
                );
                Gpu::NoAdapter(e.to_string())
            }
        }
    }
}

/// One measurement: an estimator at one budget.
#[derive(Clone, Debug)]
pub struct Measurement {
    pub scene: String,
    pub estimator: String,
    pub backend: &'static str,
    pub budget_s: f64,
    pub spp: u32,
    pub seconds: f64,
    pub rmse: f64,
    pub rel_mse: f64,
}

impl Measurement {
    /// The name in tables and plots: the estimator, with ` (gpu)` on the GPU backend.
    pub fn label(&self) -> String {
        label(&self.estimator, self.backend)
    }
}

/// `pins` + `gpu` -> `pins (gpu)`; the CPU keeps the bare estimator name.
pub fn label(estimator: &str, backend: &str) -> String {
    if backend == "cpu" {
        estimator.to_string()
    } else {
        format!("{estimator} ({backend})")
    }
}

/// What one scene produced.
pub struct SceneResult {
    pub name: String,
    pub about: String,
    pub reference: String,
    pub reference_spp: u32,
    pub reference_seconds: Option<f64>,
    /// The reference's own RMSE (its Monte Carlo noise), estimated from two independent
    /// halves: errors measured against it cannot fall below this.
    pub reference_noise: f64,
    pub bake: Option<BakeInfo>,
    /// The GPU line of the scene (setup time, or why there is no GPU row).
    pub gpu_note: Option<String>,
    pub rows: Vec<Measurement>,
    /// (label, final image) in estimator order.
    pub images: Vec<(String, Image)>,
    pub reference_image: Image,
}

#[derive(Clone, Debug)]
pub struct BakeInfo {
    pub cells: [u32; 3],
    pub directions: u32,
    /// The direction set, as `pinbake bake --dirs` writes it.
    pub direction_set: String,
    pub pins: u64,
    pub bytes: usize,
    pub seconds: f64,
}

pub fn run(a: EvalArgs) -> Result<()> {
    let started = Instant::now();
    if let Some(d) = &a.data {
        crate::data::set_dir(d.clone());
    }
    let mut sizes = {
        let mut s = if a.quick {
            Sizes::quick()
        } else {
            Sizes::default_run()
        };
        if let Some(n) = a.size {
            if !(4..=4096).contains(&n) {
                crate::usage!("--size {n} must be in 4..=4096");
            }
            s.image = n;
        }
        if let Some(r) = a.ref_spp {
            if r == 0 {
                crate::usage!("--ref-spp must be >= 1");
            }
            s.ref_spp = r;
        }
        s
    };
    let mut budgets = a.budgets.clone().unwrap_or_else(|| {
        if a.quick {
            QUICK_BUDGETS.to_vec()
        } else {
            FULL_BUDGETS.to_vec()
        }
    });
    if budgets.is_empty()
        || budgets
            .iter()
            .any(|b| !(b.is_finite() && *b > 0.0 && *b <= 1e5))
    {
        crate::usage!("--budgets must be positive finite seconds (at most 1e5), got {budgets:?}");
    }
    budgets.sort_by(f64::total_cmp);
    budgets.dedup();
    // The scenes' reference samples are sized for budgets up to 4 s. Longer budgets bring the
    // estimators' error down with the square root of their time, so the full run's reference
    // gets as many more samples as its longest budget is longer, and its own noise stays
    // below what it measures (a reference as noisy as the estimate compresses every ratio
    // towards 1). `--ref-spp` is taken as given.
    if !a.quick && a.ref_spp.is_none() {
        let longest = budgets.last().copied().unwrap_or(REFERENCE_BUDGET_S);
        let factor = (longest / REFERENCE_BUDGET_S).ceil().max(1.0) as u32;
        sizes.ref_spp = sizes.ref_spp.saturating_mul(factor);
    }
    if a.gpu_batch == 0 {
        crate::usage!("--gpu-batch must be >= 1");
    }
    for e in a.estimators.iter().flatten() {
        check_estimator_name(e)?;
    }
    let scene_names: Vec<String> = match &a.scenes {
        Some(v) => v.iter().map(|s| s.trim().to_string()).collect(),
        None if a.default_asset => asset_time::ASSET_TIME_SCENES.map(String::from).to_vec(),
        None if a.bytes && a.quick => bytes::QUICK_BYTES_SCENES.map(String::from).to_vec(),
        None if a.bytes => bytes::BYTES_SCENES.map(String::from).to_vec(),
        None => scenes::SCENES
            .iter()
            .filter(|s| !(a.quick && scenes::FULL_ONLY.contains(s)))
            .map(|s| s.to_string())
            .collect(),
    };
    for s in &scene_names {
        if !scenes::SCENES.contains(&s.as_str()) {
            crate::usage!("unknown scene '{s}' (known: {})", scenes::SCENES.join(", "));
        }
        if a.quick && scenes::FULL_ONLY.contains(&s.as_str()) {
            crate::usage!(
                "scene '{s}' is production scale and runs in the full eval only, not with --quick"
            );
        }
    }
    // The production scene's file is checked before any scene runs, so that a full run does
    // not fail after an hour of the other scenes.
    let production = production_vdb(&a)?;
    if scene_names.iter().any(|s| s == "production") && !production.is_file() {
        bail!(
            "{}: the production scene's cloud is missing: write it with `scripts/production/generate.sh half` (about a minute, 404 MB), pass --production FILE, or leave the scene out with --scenes",
            production.display()
        );
    }
    // An output directory only: a file, device or FIFO there is refused, not written into.
    if let Ok(m) = std::fs::metadata(&a.out)
        && !m.is_dir()
    {
        bail!("{}: not a directory", a.out.display());
    }
    std::fs::create_dir_all(a.out.join("cache"))
        .with_context(|| format!("creating {}", a.out.display()))?;
    refuse_special_entries(&a.out, 2)?;
    if let Some(docs) = &a.docs {
        refuse_special_entries(docs, 2)?;
    }

    if a.bytes {
        return bytes::run(&a, &scene_names, &production);
    }
    if a.default_asset {
        let budgets = match a.budgets {
            Some(_) => budgets,
            None => asset_time::ASSET_TIME_BUDGETS.to_vec(),
        };
        return asset_time::run(&a, &scene_names, &budgets, &production);
    }
    let gpu = Gpu::open(a.no_gpu);
    let mut results = Vec::new();
    for name in &scene_names {
        pin_cli::errln!("== scene {name}");
        let r = eval_scene(name, &a, &sizes, &budgets, &gpu, &production)
            .with_context(|| format!("scene {name}"))?;
        results.push(r);
        // Write what we have after every scene, so an interrupted run leaves usable output.
        report::write_csv(&a.out.join(report::ERRORS_CSV), &results)?;
    }
    report::write_bake_csv(&a.out.join("bake.csv"), &results)?;
    for r in &results {
        plot::error_vs_time(&a.out.join(format!("error_vs_time_{}.png", r.name)), r)?;
        plot::montage(&a.out.join(format!("images_{}.png", r.name)), r)?;
    }
    plot::headline(&a.out.join(report::ERRORS_PNG), &results)?;
    plot::error_vs_time_all(&a.out.join(report::ERRORS_ALL_PNG), &results)?;
    let total = started.elapsed().as_secs_f64();
    let meta = report::RunMeta::new(&a, &budgets, &sizes, total, &gpu);
    let md = report::markdown(&results, &meta)?;
    let summary = a.out.join(report::SUMMARY_MD);
    std::fs::write(&summary, md).with_context(|| format!("writing {}", summary.display()))?;
    if let Some(docs) = &a.docs {
        report::write_docs(docs, &a.out, &results, &meta)?;
    }
    pin_cli::errln!("eval done in {total:.1} s -> {}", summary.display());
    Ok(())
}

/// The report is written with plain `std::fs::write` under `dir`; a symlink or special file
/// planted there (`report.md -> /dev/sda`) would be written through. Refuses any entry of
/// `dir` (and of its subdirectories, `depth` levels) that is neither a regular file nor a
/// directory, symlinks included.
fn refuse_special_entries(dir: &std::path::Path, depth: u32) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    for e in entries {
        let e = e.with_context(|| dir.display().to_string())?;
        let t = e
            .file_type()
            .with_context(|| e.path().display().to_string())?;
        if t.is_dir() {
            if depth > 1 {
                refuse_special_entries(&e.path(), depth - 1)?;
            }
        } else if !t.is_file() {
            bail!(
                "{}: not a regular file (eval writes only regular files under its output folders)",
                e.path().display()
            );
        }
    }
    Ok(())
}

/// Estimator names `--estimators` accepts; a typo used to select nothing and exit 0.
const ESTIMATOR_NAMES: [&str; 8] = [
    "delta",
    "ratio",
    "pins",
    "pinms",
    "pinms+cache",
    "cosine-closed-form",
    "box-closed-form",
    "whole-volume",
];

/// The render plan of an eval entry: an estimator's, with the radiance cache's
/// (`pinms+cache`) that of `pinms`; `None` for the scenes' exact estimators.
fn plan_of(e: &str) -> Option<pinrender::render::RenderPlan> {
    let e = e.strip_suffix("+cache").unwrap_or(e);
    e.parse::<Estimator>().ok().map(Estimator::plan)
}

/// Whether an eval entry reads the bake.
fn reads_pins(e: &str) -> bool {
    plan_of(e).is_some_and(|p| p.reads_bake)
}

/// Whether an entry's pin queries go through the batched sampler (`pins`, `pinms`), so
/// that the wavefront loop gives `render`'s image sooner.
fn answers_pins_in_batches(e: &str) -> bool {
    e.parse::<Estimator>()
        .is_ok_and(|e| e.plan().sample_loop == pinrender::render::SampleLoop::Wavefront)
}

/// Whether a user would pick `e` with `pinrender render --estimator`: one of the renderer's
/// own estimators (`pinrender estimators`, the lab's left out), ray marching at the baseline
/// step only. `eval --quick` runs these.
fn user_pickable(e: &str) -> bool {
    use pinrender::render::EstimatorSpec;
    match e.parse::<EstimatorSpec>() {
        Ok(EstimatorSpec::RayMarching { .. }) => e == report::BASELINE,
        Ok(_) => true,
        Err(_) => false,
    }
}

fn check_estimator_name(e: &str) -> Result<()> {
    if ESTIMATOR_NAMES.contains(&e) {
        return Ok(());
    }
    match e.parse::<Estimator>() {
        Ok(_) => Ok(()),
        Err(why) if why.starts_with("unknown estimator") => crate::usage!(
            "--estimators: unknown estimator '{e}' (known: rm@STEP, urm[@N], jackknife[@N], residual[@min|@mean], {})",
            ESTIMATOR_NAMES.join(", ")
        ),
        Err(why) => crate::usage!("--estimators {e}: {why}"),
    }
}

fn settings(es: &EvalScene, seed: u64, budget: Budget, threads: Option<usize>) -> RenderSettings {
    RenderSettings {
        max_bounces: es.max_bounces,
        seed,
        budget,
        threads,
    }
}

fn scene_with(es: &EvalScene, media: Vec<Medium>) -> Scene {
    Scene {
        media,
        ..es.scene.clone()
    }
}

fn fnv1a(s: &str) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in s.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

fn file_name(estimator: &str) -> String {
    estimator
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The reference image and its noise (see [`SceneResult::reference_noise`]): from the cache
/// when present, else rendered as two independent halves, averaged and cached.
fn reference(es: &EvalScene, a: &EvalArgs) -> Result<(Image, f64, Option<f64>)> {
    let cam = &es.scene.camera;
    let key = format!(
        "{REFERENCE_VERSION}|{}|{:?}|{}x{}|fov={}|bounces={}|spp={}|seed={}|ref={:?}|albedo={}|g={}|sun={:?}|env={:?}",
        es.key,
        cam.origin,
        cam.width,
        cam.height,
        cam.vfov_deg,
        es.max_bounces,
        es.ref_spp,
        a.seed,
        es.reference,
        es.scene.albedo,
        es.scene.g,
        es.scene.sun.as_ref().map(|s| (s.dir, s.radiance)),
        es.scene.env_radiance,
    );
    let path = a
        .out
        .join("cache")
        .join(format!("{}-{:016x}.exr", es.name, fnv1a(&key)));
    let key_path = path.with_extension("key");
    let noise_path = path.with_extension("noise");
    if !a.no_reference_cache
        && let (Ok(img), Ok(k), Ok(noise)) = (
            Image::read_exr(&path),
            std::fs::read_to_string(&key_path),
            std::fs::read_to_string(&noise_path),
        )
        && k == key
        && let Ok(noise) = noise.trim().parse::<f64>()
        && noise.is_finite()
        && img.width == cam.width
        && img.height == cam.height
    {
        pin_cli::errln!("  reference: cached {}", path.display());
        return Ok((img, noise, None));
    }
    let t = Instant::now();
    let half_spp = es.ref_spp.div_ceil(2);
    let halves = [0x5EF0_5EF0_5EF0_5EF0u64, 0x0FE5_0FE5_0FE5_0FE5]
        .map(|salt| reference_half(es, a, splitmix64(a.seed ^ salt), half_spp));
    let [h0, h1] = halves;
    let (h0, h1) = (h0?, h1?);
    // Two independent halves: E|h0 - h1|^2 = 2 var(half) = 4 var(mean), so the mean's RMSE
    // against the true image is rmse(h0, h1) / 2.
    let noise = rmse(&h0, &h1).map_err(|e| anyhow!("{e}"))? / 2.0;
    let image = Image {
        width: h0.width,
        height: h0.height,
        rgb: h0
            .rgb
            .iter()
            .zip(&h1.rgb)
            .map(|(p, q)| [0, 1, 2].map(|c| 0.5 * (p[c] + q[c])))
            .collect(),
    };
    let secs = t.elapsed().as_secs_f64();
    pin_cli::errln!(
        "  reference: {} spp in {secs:.1} s ({}), noise RMSE {noise:.2e}",
        2 * half_spp,
        es.reference.label()
    );
    image
        .write_exr(&path)
        .map_err(|e| anyhow!("{}: {e}", path.display()))?;
    std::fs::write(&key_path, &key).with_context(|| format!("writing {}", key_path.display()))?;
    std::fs::write(&noise_path, format!("{noise:e}\n"))
        .with_context(|| format!("writing {}", noise_path.display()))?;
    Ok((image, noise, Some(secs)))
}

/// One half of the reference: `spp` samples per pixel with its own seed.
fn reference_half(es: &EvalScene, a: &EvalArgs, seed: u64, spp: u32) -> Result<Image> {
    let st = settings(es, seed, Budget::Spp(spp), a.threads);
    let out = match es.reference {
        RefKind::Tracker => {
            let media = es
                .instances
                .iter()
                .map(|i| -> Result<Medium> {
                    let f = i.field().map_err(|e| anyhow!("{e}"))?;
                    let m = i.majorants().map_err(|e| anyhow!("{e}"))?;
                    // In the description's frame, placed as every estimator is.
                    let local = Medium::single(
                        Arc::new(RatioTracking::new(f, m)) as Arc<dyn TransportEstimator>
                    );
                    i.place(local, LOOKUP).map_err(|e| anyhow!("{e}"))
                })
                .collect::<Result<_>>()?;
            render(&scene_with(es, media), &st)
        }
        RefKind::ClosedForm => {
            let name = if es.name == "cosine" {
                "cosine-closed-form"
            } else {
                "box-closed-form"
            };
            render(&scene_with(es, scenes::media(es, name)?), &st)
        }
        RefKind::WholeVolume => {
            let wv = es
                .whole_volume
                .as_ref()
                .ok_or_else(|| anyhow!("whole-volume reference without a box"))?;
            render_single_scattering(
                &scene_with(es, Vec::new()),
                wv,
                SingleScatterSampling::WholeVolume,
                &st,
            )
        }
    }
    .map_err(|e| anyhow!("reference render: {e}"))?;
    Ok(out.image)
}

/// The pins' lookup options, CPU and GPU: `pinrender render`'s defaults (one cell of jitter
/// as in the thesis' evaluation, looked up at the segment's middle; docs/evaluation.md).
const LOOKUP: SamplerOptions = crate::render_cmd::DEFAULT_LOOKUP;

/// Bakes the scene's pins and installs a pin estimator per instance.
/// With `control`, the bake also stores the control section (`pinres`).
fn bake_pins(es: &mut EvalScene, a: &EvalArgs, control: bool) -> Result<BakeInfo> {
    let mut info: Option<BakeInfo> = None;
    for (k, source) in es.bake_sources.clone().iter().enumerate() {
        let (grid, one) = bake_one(es, source.as_ref(), a, control)?;
        let l2w = grid.desc().local_to_world;
        for (i, inst) in es.instances.iter_mut().enumerate() {
            if es.asset_of.get(i).copied().unwrap_or(0) != k {
                continue;
            }
            // Each instance's pins placed by its density's translation.
            inst.pins = Some(PlacedPins {
                grid: grid.clone(),
                local_to_world: Some(scenes::translated(&l2w, inst.translation)),
            });
        }
        // Several assets: the first one's cells and directions, every grid's pins, bytes and
        // time.
        info = Some(match info {
            None => one,
            Some(i) => BakeInfo {
                pins: i.pins + one.pins,
                bytes: i.bytes + one.bytes,
                seconds: i.seconds + one.seconds,
                ..i
            },
        });
    }
    info.ok_or_else(|| anyhow!("{}: no volume to bake", es.name))
}

/// Bakes one of a scene's volumes as the eval bakes: what `pinbake bake` chooses, or the
/// scene's small fixed bake in `--quick` runs.
fn bake_one(
    es: &EvalScene,
    source: &dyn pin_volume::DensitySource,
    a: &EvalArgs,
    control: bool,
) -> Result<(Arc<PinGrid>, BakeInfo)> {
    // The full eval bakes what `pinbake bake` chooses by default (the product's default is
    // what the figures are about); `--quick` keeps the scenes' small fixed bakes, for time.
    let (cells, directions) = if es.choose_bake || !a.quick {
        // What `pinbake bake` chooses for the volume by default.
        let stats = pinbake::choose::analyse(source, true)?;
        let c = pinbake::choose::choose_default(&stats, pinbake::choose::Fixed::default());
        pin_cli::errln!(
            "  pins chosen: {:?} cells x {:?} (model variation {:.1}, predicted block error {:.3})",
            c.cells,
            c.directions,
            stats.model_variation,
            c.predicted_error
        );
        (c.cells, c.directions)
    } else {
        // The scenes' cells were sized for 64 directions; keep their bytes (the CLI default
        // is octahedral:16 at fewer cells, docs/evaluation.md).
        ([es.bake_cells; 3], pinrt::Directions::Octahedral { n: 8 })
    };
    let opts = pinbake::BakeOptions {
        cells,
        directions,
        seed: a.seed,
        threads: a.threads,
        embed_control: control.then(pinbake::control::ControlOptions::default),
        ..pinbake::BakeOptions::default()
    };
    let t = Instant::now();
    let (grid, stats) = pinbake::bake(source, &opts, &|_| {})?;
    let bytes = grid.to_bytes()?;
    let seconds = t.elapsed().as_secs_f64();
    let size = bytes.len();
    let grid = Arc::new(PinGrid::from_bytes(bytes).map_err(|e| anyhow!("{e}"))?);
    pin_cli::errln!(
        "  pins: {:?} cells x {} directions, {} pins, {:.1} MB, baked in {seconds:.2} s",
        opts.cells,
        opts.directions.count(),
        stats.pins,
        size as f64 / 1e6
    );
    Ok((
        grid,
        BakeInfo {
            cells: opts.cells,
            directions: opts.directions.count(),
            direction_set: match opts.directions {
                pinrt::Directions::Octahedral { n } => format!("octahedral:{n}"),
                pinrt::Directions::Polar { n_phi, n_theta } => format!("polar:{n_phi}x{n_theta}"),
            },
            pins: stats.pins,
            bytes: size,
            seconds,
        },
    ))
}

fn eval_scene(
    name: &str,
    a: &EvalArgs,
    sizes: &Sizes,
    budgets: &[f64],
    gpu: &Gpu,
    production: &std::path::Path,
) -> Result<SceneResult> {
    let mut es = scenes::build(name, sizes, production)?;
    // Without --estimators, a quick run measures only what a user would pick.
    let wanted = |e: &str| match &a.estimators {
        Some(v) => v.iter().any(|x| x == e),
        None => !a.quick || user_pickable(e),
    };
    let mut ests: Vec<String> = es
        .estimators
        .iter()
        .filter(|e| wanted(e))
        .cloned()
        .collect();
    // An estimator named in --estimators runs on every scene, even where the scene's own
    // list leaves it out (`residual@min`, `urm@64`, `rm@0.002`); the names that only some
    // scenes have (closed forms, the radiance cache) stay with those scenes.
    for e in a.estimators.iter().flatten() {
        let named = e.parse::<Estimator>().is_ok();
        if named && !ests.contains(e) {
            ests.push(e.clone());
        }
    }
    let needs_pins = ests.iter().any(|e| reads_pins(e));
    let bake = if needs_pins {
        let control = ests.iter().any(|e| plan_of(e).is_some_and(|p| p.control));
        Some(bake_pins(&mut es, a, control)?)
    } else {
        None
    };
    let (reference_image, reference_noise, reference_seconds) = reference(&es, a)?;
    let dir = a.out.join(es.name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    reference_image
        .write_exr(dir.join("reference.exr"))
        .map_err(|e| anyhow!("{e}"))?;
    let mut rows = Vec::new();
    let mut images = Vec::new();

    let mut keep = |pts: Vec<Measurement>, img: Image, rows: &mut Vec<Measurement>| -> Result<()> {
        let Some(r) = pts.last() else {
            return Ok(());
        };
        let label = r.label();
        pin_cli::errln!(
            "  {label:<20} {:>5} spp in {:>6.2} s  rmse {:.5}  relmse {:.5}",
            r.spp,
            r.seconds,
            r.rmse,
            r.rel_mse
        );
        img.write_exr(dir.join(format!("{}.exr", file_name(&label))))
            .map_err(|e| anyhow!("{e}"))?;
        rows.extend(pts);
        images.push((label, img));
        Ok(())
    };
    for est in &ests {
        let (pts, img) = measure(&es, est, a, budgets, &reference_image)
            .with_context(|| format!("estimator {est}"))?;
        keep(pts, img, &mut rows)?;
    }
    // The GPU path tracer after the CPU rows: every estimator it has, with the same media.
    // (name, GPU estimator) of every estimator the GPU path tracer runs.
    let gpu_rows: Vec<(String, GpuEstimator)> = ests
        .iter()
        .filter(|e| !a.quick || a.estimators.is_some() || QUICK_GPU.contains(&e.as_str()))
        .filter_map(|e| {
            let e = e.parse::<Estimator>().ok()?;
            Some((e.to_string(), e.gpu()?))
        })
        .collect();
    let gpu_ests: Vec<GpuEstimator> = gpu_rows.iter().map(|&(_, g)| g).collect();
    let gpu_note = Some(match gpu {
        Gpu::Off => "GPU: not measured (`--no-gpu`).".to_string(),
        Gpu::NoAdapter(_) => "**GPU: no adapter** (no GPU rows).".to_string(),
        Gpu::Ready { .. } if gpu_ests.is_empty() => {
            "GPU: none of the selected estimators runs on the GPU.".to_string()
        }
        Gpu::Ready { .. } if es.gpu_refusal.is_some() => format!(
            "**GPU: not measured** (no GPU rows): {}.",
            es.gpu_refusal.as_deref().unwrap_or_default()
        ),
        Gpu::Ready { store, .. } => 'gpu: {
            let t = Instant::now();
            let media = scenes::gpu_media(&es, &gpu_ests, LOOKUP)?;
            // A scene the device cannot hold (the 512^3 cloud's density is over lavapipe's
            // 128 MiB storage-buffer binding) is a property of the device: the CPU rows stand,
            // and the report says why the GPU rows are missing.
            let renderer = match GpuRenderer::with_media_in(store, &media) {
                Ok(r) => r,
                Err(e) => {
                    break 'gpu format!("**GPU: not measured on this device** (no GPU rows): {e}.");
                }
            };
            // Each estimator has its own pipeline, compiled on its first dispatch (lavapipe
            // JITs it): one warm-up pass per estimator belongs to the setup, not to that
            // estimator's times.
            let gs = GpuScene::from_scene(&es.scene, es.max_bounces);
            for (name, est) in &gpu_rows {
                renderer
                    .render(&gs, *est, 1, 0)
                    .map_err(|e| anyhow!("GPU warm-up of {name} for {}: {e}", es.name))?;
            }
            let setup = t.elapsed().as_secs_f64();
            for (name, est) in &gpu_rows {
                let (pts, img) =
                    measure_gpu(&es, &renderer, (name, *est), a, budgets, &reference_image)
                        .with_context(|| format!("estimator {name} (gpu)"))?;
                keep(pts, img, &mut rows)?;
            }
            format!(
                "GPU renderer setup (density, majorant and pin upload, pipeline compiles, one \
                 warm-up pass per estimator; once, not in the times below): {setup:.2} s; {} \
                 spp per render call.",
                a.gpu_batch
            )
        }
    });
    if let Some(n) = &gpu_note {
        pin_cli::errln!("  {n}");
    }
    Ok(SceneResult {
        name: es.name.to_string(),
        about: es.about.clone(),
        reference: es.reference.label().to_string(),
        reference_spp: es.ref_spp,
        reference_seconds,
        reference_noise,
        bake,
        gpu_note,
        rows,
        images,
        reference_image,
    })
}

/// Seed of pass `i` of a progressive measurement (the same for every estimator: common
/// random numbers; the reference uses an unrelated seed).
fn pass_seed(seed: u64, i: u32) -> u64 {
    splitmix64(splitmix64(seed) ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// Progressive render of one estimator: 1-spp passes averaged until the largest budget is
/// spent; a row at every budget crossed.
fn measure(
    es: &EvalScene,
    est: &str,
    a: &EvalArgs,
    budgets: &[f64],
    reference: &Image,
) -> Result<(Vec<Measurement>, Image)> {
    let media = match est {
        "whole-volume" => Vec::new(),
        _ => scenes::media(es, est)?,
    };
    let scene = scene_with(es, media);
    let mut elapsed = 0.0f64;
    // Set-up that counts towards the time: the radiance cache's training pass.
    let cache = if est == "pinms+cache" {
        let t = Stopwatch::start(a.clock, worker_threads(a));
        let st = settings(es, pass_seed(a.seed, u32::MAX), Budget::Spp(1), a.threads);
        let c = train_cache(&scene, &st, &es.cache).map_err(|e| anyhow!("cache training: {e}"))?;
        elapsed += t.seconds();
        Some(c)
    } else {
        None
    };
    let pass = |seed: u64| -> Result<RenderOutput> {
        let st = settings(es, seed, Budget::Spp(1), a.threads);
        let out = match (est, &cache) {
            ("whole-volume", _) => {
                let wv = es
                    .whole_volume
                    .as_ref()
                    .ok_or_else(|| anyhow!("whole-volume needs the homogeneous box"))?;
                render_single_scattering(&scene, wv, SingleScatterSampling::WholeVolume, &st)
            }
            (_, Some(c)) => render_with_cache(&scene, &st, &es.cache, c, Instant::now()),
            // Pin queries answered in batches: the same image as `render`, sooner.
            (e, _) if answers_pins_in_batches(e) => {
                render_wavefront(&scene, &st, DEFAULT_WAVEFRONT_BATCH)
            }
            _ => render(&scene, &st),
        };
        out.map_err(|e| anyhow!("{e}"))
    };
    progressive(es, ("cpu", est), a, budgets, reference, elapsed, |seed| {
        pass(seed).map(|o| (o.image, o.spp))
    })
}

/// One estimator on the GPU path tracer, measured like [`measure`]: `--gpu-batch` spp per
/// render call, each call a pass with its own seed.
fn measure_gpu(
    es: &EvalScene,
    renderer: &GpuRenderer,
    (name, est): (&str, GpuEstimator),
    a: &EvalArgs,
    budgets: &[f64],
    reference: &Image,
) -> Result<(Vec<Measurement>, Image)> {
    let gs = GpuScene::from_scene(&es.scene, es.max_bounces);
    let batch = a.gpu_batch;
    progressive(es, ("gpu", name), a, budgets, reference, 0.0, |seed| {
        renderer
            .render(&gs, est, batch, seed)
            .map(|img| (img, batch))
            .map_err(|e| anyhow!("{e}"))
    })
}

/// The measurement loop: `pass(seed)` (an image of `spp` samples) with distinct seeds,
/// averaged, a row at every budget that the running wall time (`elapsed` already spent
/// included) crosses.
fn progressive(
    es: &EvalScene,
    (backend, est): (&'static str, &str),
    a: &EvalArgs,
    budgets: &[f64],
    reference: &Image,
    mut elapsed: f64,
    mut pass: impl FnMut(u64) -> Result<(Image, u32)>,
) -> Result<(Vec<Measurement>, Image)> {
    let (width, height) = (es.scene.camera.width, es.scene.camera.height);
    let n = (width as usize) * (height as usize);
    let mut sum = vec![[0f64; 3]; n];
    let mut spp = 0u32;
    let mean = |sum: &[[f64; 3]], spp: u32| -> Image {
        let inv = 1.0 / spp.max(1) as f64;
        Image {
            width,
            height,
            rgb: sum.iter().map(|s| s.map(|c| (c * inv) as f32)).collect(),
        }
    };
    let mut rows = Vec::new();
    let mut next = 0usize;
    // GPU rows count wall time whatever `--clock` says.
    let clock = if backend == "cpu" {
        a.clock
    } else {
        Clock::Wall
    };
    while next < budgets.len() {
        let t = Stopwatch::start(clock, worker_threads(a));
        let (image, out_spp) = pass(pass_seed(a.seed, spp))?;
        if image.rgb.len() != n {
            bail!("a pass returned {} pixels, expected {n}", image.rgb.len());
        }
        for (acc, p) in sum.iter_mut().zip(&image.rgb) {
            for c in 0..3 {
                acc[c] += p[c] as f64 * out_spp as f64;
            }
        }
        spp = spp.saturating_add(out_spp);
        elapsed += t.seconds();
        if elapsed >= budgets[next] || spp == u32::MAX {
            let img = mean(&sum, spp);
            let e = rmse(&img, reference).map_err(|e| anyhow!("{e}"))?;
            let r = relative_mse(&img, reference).map_err(|e| anyhow!("{e}"))?;
            while next < budgets.len() && (elapsed >= budgets[next] || spp == u32::MAX) {
                rows.push(Measurement {
                    scene: es.name.to_string(),
                    estimator: est.to_string(),
                    backend,
                    budget_s: budgets[next],
                    spp,
                    seconds: elapsed,
                    rmse: e,
                    rel_mse: r,
                });
                next += 1;
            }
        }
    }
    Ok((rows, mean(&sum, spp)))
}
