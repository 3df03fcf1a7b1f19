//! CSV files, the markdown report and the docs/evaluation.md update.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};

use super::scenes::Sizes;
use super::{EvalArgs, Gpu, SceneResult};

/// The estimator whose error at its largest budget is the target of the time-to-error column.
pub const BASELINE: &str = "rm@0.015";

/// The output contract of `pinrender eval` (file names and the CSV's first columns).
pub const ERRORS_CSV: &str = "errors.csv";
pub const ERRORS_PNG: &str = "errors.png";
pub const SUMMARY_MD: &str = "summary.md";
pub const ERRORS_CSV_HEADER: &str = "scene,estimator,backend,seconds,rmse,relmse,budget_s,spp";

/// A time-to-error target closer than this factor to the reference's own noise is not
/// resolved by the reference: the column says so instead of printing a speedup of noise.
pub const REFERENCE_NOISE_FACTOR: f64 = 2.0;

/// Every estimator's error against time (the headline `errors.png` shows four per scene).
pub const ERRORS_ALL_PNG: &str = "errors_all.png";
/// The report `--docs DIR` writes, under `DIR/eval/` beside its figures.
pub const DOCS_REPORT: &str = "report.md";

/// How the run was made, for the report header.
pub struct RunMeta {
    pub command: String,
    pub budgets: Vec<f64>,
    pub quick: bool,
    pub threads: String,
    /// What the CPU rows' budgets count (`--clock`).
    pub clock: super::Clock,
    pub cpu: String,
    pub total_seconds: f64,
    pub sizes: Sizes,
    /// The report's GPU sentence.
    pub gpu: String,
}

impl RunMeta {
    pub fn new(
        a: &EvalArgs,
        budgets: &[f64],
        sizes: &Sizes,
        total_seconds: f64,
        gpu: &Gpu,
    ) -> Self {
        let args: Vec<String> = std::env::args().skip(1).collect();
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split_once(':'))
                    .map(|(_, v)| v.trim().to_string())
            })
            .unwrap_or_else(|| "unknown CPU".into());
        let cores = std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1);
        RunMeta {
            command: format!("pinrender {}", args.join(" ")),
            budgets: budgets.to_vec(),
            quick: a.quick,
            threads: match a.threads {
                Some(t) => format!("{t} threads"),
                None => format!("{cores} threads (all cores)"),
            },
            clock: a.clock,
            cpu,
            total_seconds,
            sizes: *sizes,
            gpu: gpu_sentence(gpu, a.gpu_batch),
        }
    }
}

/// What the report says about the GPU.
fn gpu_sentence(gpu: &Gpu, batch: u32) -> String {
    match gpu {
        Gpu::Off => "**GPU: not measured** (`--no-gpu`).".into(),
        Gpu::NoAdapter(e) => {
            format!("**GPU: no adapter** (the `(gpu)` rows are missing: {e}).")
        }
        Gpu::Ready {
            describe,
            software,
            seconds,
            ..
        } => {
            let mut s = format!(
                "GPU: rows marked `(gpu)` are the WGSL path tracer \
                 (`pinrender::gpu_render::GpuRenderer`, backend `gpu` in the CSV) on `{describe}` \
                 over the same media as the CPU rows (the same pin grid and lookup jitter, a GPU \
                 copy of the density, the CPU's majorant grids, every instance), measured the \
                 same way ({batch} spp per render call, each call a pass with its own seed, \
                 averaged; the per-scene renderer setup and the {seconds:.2} s device creation \
                 are not in the times)."
            );
            if *software {
                s.push_str(
                    " **This adapter is lavapipe/llvmpipe, Vulkan on the CPU**: the GPU rows \
                     measure the WGSL code path on the same CPU threads, not a GPU; they show \
                     that the GPU estimator converges to the same reference, not GPU speed.",
                );
            }
            s
        }
    }
}

pub fn write_csv(path: &Path, results: &[SceneResult]) -> Result<()> {
    let mut s = format!("{ERRORS_CSV_HEADER}\n");
    for r in results {
        for row in &r.rows {
            let _ = writeln!(
                s,
                "{},{},{},{:.4},{:.6e},{:.6e},{},{}",
                row.scene,
                row.estimator,
                row.backend,
                row.seconds,
                row.rmse,
                row.rel_mse,
                row.budget_s,
                row.spp,
            );
        }
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

pub fn write_bake_csv(path: &Path, results: &[SceneResult]) -> Result<()> {
    // `cells` was one count per axis when every eval bake was a cube; it is `XxYxZ` now that
    // the full eval bakes what `pinbake bake` chooses. `direction_set` was added.
    let mut s = String::from("scene,cells,directions,pins,bytes,seconds,direction_set\n");
    for r in results {
        if let Some(b) = &r.bake {
            let [x, y, z] = b.cells;
            let _ = writeln!(
                s,
                "{},{x}x{y}x{z},{},{},{},{:.4},{}",
                r.name, b.directions, b.pins, b.bytes, b.seconds, b.direction_set
            );
        }
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

/// One point of an error curve: (seconds, rmse, spp).
pub type Point = (f64, f64, u32);

/// The error curve of one estimator: (seconds, rmse, spp) by increasing time, one point per
/// distinct spp.
pub fn curve(r: &SceneResult, label: &str) -> Vec<Point> {
    let mut v: Vec<Point> = Vec::new();
    for row in r.rows.iter().filter(|x| x.label() == label) {
        if v.last().is_none_or(|l| l.2 != row.spp) {
            v.push((row.seconds, row.rmse, row.spp));
        }
    }
    v
}

/// When the curve first reaches `target` RMSE, interpolated log-log between measurements.
pub enum Reach {
    /// Reached at this time (interpolated).
    At(f64),
    /// Already below the target at the first measurement (this time).
    Before(f64),
    Never,
}

pub fn time_to(curve: &[Point], target: f64) -> Reach {
    if !(target > 0.0) || curve.is_empty() {
        return Reach::Never;
    }
    if curve[0].1 <= target {
        return Reach::Before(curve[0].0);
    }
    for w in curve.windows(2) {
        let ((t0, e0, _), (t1, e1, _)) = (w[0], w[1]);
        if e1 <= target && e0 > target {
            if !(t0 > 0.0 && t1 > 0.0 && e1 > 0.0) {
                return Reach::At(t1);
            }
            let (lt0, lt1) = (t0.ln(), t1.ln());
            let (le0, le1) = (e0.ln(), e1.ln());
            let f = (target.ln() - le0) / (le1 - le0);
            return Reach::At((lt0 + f * (lt1 - lt0)).exp());
        }
    }
    Reach::Never
}

fn fmt_s(x: f64) -> String {
    if x >= 10.0 {
        format!("{x:.1} s")
    } else {
        format!("{x:.2} s")
    }
}

/// The markdown table of one scene.
pub fn scene_table(r: &SceneResult) -> String {
    let mut s = String::new();
    let ests: Vec<String> = {
        let mut v: Vec<String> = Vec::new();
        for row in &r.rows {
            let l = row.label();
            if !v.contains(&l) {
                v.push(l);
            }
        }
        v
    };
    // Each backend against its own ray marching at step 0.015 (the GPU rows against the GPU's,
    // the comparison the thesis makes on its GPU); the CPU's when a backend lacks one.
    let cpu_target = curve(r, BASELINE).last().map(|p| (p.1, p.0));
    let target_of = |label: &str| -> Option<(f64, f64)> {
        match label.rfind(" (") {
            Some(i) if label.ends_with(')') => {
                let backend_base = format!("{BASELINE}{}", &label[i..]);
                curve(r, &backend_base)
                    .last()
                    .map(|p| (p.1, p.0))
                    .or(cpu_target)
            }
            _ => cpu_target,
        }
    };
    let _ = writeln!(
        s,
        "| estimator | spp | time | RMSE | rel. MSE | time to {BASELINE}'s final RMSE (same backend) | speedup vs {BASELINE} (same backend) |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|");
    for est in &ests {
        let est = est.as_str();
        let c = curve(r, est);
        let Some(&(secs, err, spp)) = c.last() else {
            continue;
        };
        let rel = r
            .rows
            .iter()
            .rfind(|x| x.label() == est)
            .map(|x| x.rel_mse)
            .unwrap_or(f64::NAN);
        let (reach, speed) = match target_of(est) {
            None => ("n/a (no baseline)".to_string(), "n/a".to_string()),
            Some((e_target, _)) if e_target < REFERENCE_NOISE_FACTOR * r.reference_noise => {
                ("n/a (reference noise)".to_string(), "n/a".to_string())
            }
            Some((e_target, t_base)) => match time_to(&c, e_target) {
                Reach::At(t) => (fmt_s(t), format!("{:.2}x", t_base / t)),
                Reach::Before(t) => (format!("<= {}", fmt_s(t)), format!(">= {:.2}x", t_base / t)),
                Reach::Never => ("not reached".to_string(), "-".to_string()),
            },
        };
        let name = if est == BASELINE
            || est
                .strip_prefix(BASELINE)
                .is_some_and(|t| t.starts_with(" ("))
        {
            format!("**{est}**")
        } else {
            est.to_string()
        };
        let _ = writeln!(
            s,
            "| {name} | {spp} | {} | {err:.4} | {rel:.4} | {reach} | {speed} |",
            fmt_s(secs)
        );
    }
    s
}

/// Whether estimator `est` of an eval row reads the bake (`pins`, `pinms`, `pinms+cache`,
/// `pinurm`), or `None` for the scenes' exact estimators (the closed forms and whole-volume
/// sampling), which a real volume does not have and which neither side of the comparison
/// below counts.
pub fn reads_bake(est: &str) -> Option<bool> {
    match est {
        "cosine-closed-form" | "box-closed-form" | "whole-volume" => None,
        "pinms+cache" => Some(true),
        e => e.parse::<pinlab::Estimator>().ok().map(|s| s.needs_pins()),
    }
}

/// Per budget, the CPU estimator with the lowest RMSE among those that read the bake and
/// among those that do not, with the ratio of their RMSEs: `(budget, (bake name, rmse),
/// (no-bake name, rmse))`, budgets in increasing order, a side `None` when the scene ran
/// none of its kind.
pub type BakeVsNoBake = (f64, Option<(String, f64)>, Option<(String, f64)>);

pub fn bake_vs_no_bake(r: &SceneResult) -> Vec<BakeVsNoBake> {
    let mut budgets: Vec<f64> = r
        .rows
        .iter()
        .filter(|x| x.backend == "cpu")
        .map(|x| x.budget_s)
        .collect();
    budgets.sort_by(f64::total_cmp);
    budgets.dedup();
    let best = |budget: f64, bake: bool| {
        r.rows
            .iter()
            .filter(|x| {
                x.backend == "cpu"
                    && x.budget_s == budget
                    && x.rmse.is_finite()
                    && reads_bake(&x.estimator) == Some(bake)
            })
            .min_by(|a, b| a.rmse.total_cmp(&b.rmse))
            .map(|x| (x.estimator.clone(), x.rmse))
    };
    budgets
        .into_iter()
        .map(|b| (b, best(b, true), best(b, false)))
        .collect()
}

/// The markdown table of [`bake_vs_no_bake`], or an empty string when the scene has no row
/// on one of the two sides.
pub fn bake_table(r: &SceneResult) -> String {
    let rows = bake_vs_no_bake(r);
    if !rows.iter().any(|(_, a, b)| a.is_some() && b.is_some()) {
        return String::new();
    }
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| budget | best reading the bake | RMSE | best without | RMSE | RMSE ratio (bake / without) |"
    );
    let _ = writeln!(s, "|---:|---|---:|---|---:|---:|");
    for (budget, bake, plain) in rows {
        let cell = |x: &Option<(String, f64)>| match x {
            Some((n, e)) => (n.clone(), format!("{e:.4}")),
            None => ("-".to_string(), "-".to_string()),
        };
        let ((bn, be), (pn, pe)) = (cell(&bake), cell(&plain));
        let ratio = match (&bake, &plain) {
            (Some((_, a)), Some((_, b))) if *b > 0.0 => format!("{:.2}", a / b),
            _ => "-".to_string(),
        };
        let _ = writeln!(s, "| {budget} s | {bn} | {be} | {pn} | {pe} | {ratio} |");
    }
    s
}

/// The report body (shared by summary.md and docs/evaluation.md); `link_prefix` goes in front
/// of image file names.
pub fn body(results: &[SceneResult], meta: &RunMeta, link_prefix: &str) -> String {
    let mut s = String::new();
    let budgets: Vec<String> = meta.budgets.iter().map(|b| format!("{b}")).collect();
    let _ = writeln!(s, "Command: `{}`", meta.command);
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "Machine: {}, {}; total run time {:.0} s{}. Budgets: {} s of {} per estimator \
         (CPU path tracer, `pinrender::render`, unless marked `(gpu)`). {}",
        meta.cpu,
        meta.threads,
        meta.total_seconds,
        if meta.quick { " (`--quick`)" } else { "" },
        budgets.join(", "),
        match meta.clock {
            super::Clock::Wall => "wall time",
            super::Clock::Cpu =>
                "CPU time per worker thread (`--clock cpu`; `(gpu)` rows: wall time)",
        },
        meta.gpu
    );
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "How to read the tables: *spp*, *time*, *RMSE* and *rel. MSE* are at the largest budget \
         (equal time; the time is the measured wall time, which overruns the budget by at most \
         one 1-spp pass). *Time to {BASELINE}'s final RMSE* is when the estimator's error curve \
         first reaches the RMSE that ray marching at step 0.015 reaches at the largest budget \
         on the same backend (CPU rows against `{BASELINE}`, `(gpu)` rows against \
         `{BASELINE} (gpu)`), interpolated log-log between measurements (`<= t`: already there \
         at the first measurement; *not reached*: never within the budgets, usually bias; *n/a \
         (reference noise)*: that RMSE is within {REFERENCE_NOISE_FACTOR}x the reference's own \
         noise, so the reference cannot resolve it). \
         *Speedup* is that baseline's time divided by that time. Errors are against a high-sample reference \
         rendered once and cached (`out/eval/cache/`); relative MSE is \
         `mean((x - ref)^2 / (ref^2 + 0.01))`. Pin bakes are an offline asset step: their time \
         is listed per scene and is *not* included in the render times. {} bounces (1 for \
         box-ss), albedo 0.95, isotropic phase, pins looked up as `pinrender render` looks \
         them up by default (`SamplerOptions::RENDER`): at the middle of the query segment (a \
         ray from inside the medium at its start), one cell of directional jitter, the cell \
         whose pin line passes nearest the lookup point (`docs/sampling.md` section 15).",
        meta.sizes.max_bounces
    );
    let _ = writeln!(s);
    for r in results {
        let _ = writeln!(s, "### {}", r.name);
        let _ = writeln!(s);
        let _ = writeln!(s, "{}.", r.about);
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "Reference: {}, {} spp{}; its own noise (RMSE, from two independent halves): \
             {:.2e}.",
            r.reference,
            r.reference_spp,
            match r.reference_seconds {
                Some(t) => format!(" ({t:.1} s)"),
                None => " (from the cache)".into(),
            },
            r.reference_noise
        );
        if let Some(b) = &r.bake {
            let _ = writeln!(
                s,
                "Pin bake (offline, not in the times below): {}x{}x{} cells x {} ({} directions), \
                 {} pins, {:.2} MB, {:.2} s.",
                b.cells[0],
                b.cells[1],
                b.cells[2],
                b.direction_set,
                b.directions,
                b.pins,
                b.bytes as f64 / 1e6,
                b.seconds
            );
        }
        if let Some(g) = &r.gpu_note {
            let _ = writeln!(s, "{g}");
        }
        let _ = writeln!(s);
        s.push_str(&scene_table(r));
        let _ = writeln!(s);
        let versus = bake_table(r);
        if !versus.is_empty() {
            let _ = writeln!(
                s,
                "At equal CPU time, per budget: the best estimator that reads the bake against \
                 the best that does not (CPU rows; the closed forms and whole-volume sampling \
                 left out of both):"
            );
            let _ = writeln!(s);
            s.push_str(&versus);
            let _ = writeln!(s);
        }
        let _ = writeln!(
            s,
            "![error vs time, {n}]({p}error_vs_time_{n}.png)",
            n = r.name,
            p = link_prefix
        );
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "![equal-time images, {n}: reference then each estimator at the largest budget]({p}images_{n}.png)",
            n = r.name,
            p = link_prefix
        );
        let _ = writeln!(s);
    }
    s
}

/// One line per scene: what the bake buys at each budget (the best CPU estimator reading
/// the bake against the best without, as RMSE ratios), the first thing summary.md says.
pub fn what_the_bake_buys(results: &[SceneResult]) -> String {
    let mut s = String::from(
        "What the bake buys, per scene and budget: the lowest RMSE of an estimator that reads \
         the pin file divided by the lowest of one that needs nothing baked, at equal time on \
         the CPU (below 1: the bake wins; the two estimators in brackets).\n\n",
    );
    for r in results {
        let cells: Vec<String> = bake_vs_no_bake(r)
            .into_iter()
            .filter_map(|(budget, bake, plain)| {
                let ((bn, be), (pn, pe)) = (bake?, plain?);
                (pe > 0.0).then(|| format!("{budget} s: {:.2} ({bn} / {pn})", be / pe))
            })
            .collect();
        let line = if cells.is_empty() {
            "no estimator reading the bake ran".to_string()
        } else {
            cells.join("; ")
        };
        let _ = writeln!(s, "- **{}**: {line}.", r.name);
    }
    s.push('\n');
    s
}

/// The three sentences that open summary.md: what the reader is looking at.
fn opening(results: &[SceneResult], meta: &RunMeta) -> String {
    let names: Vec<&str> = results.iter().map(|r| r.name.as_str()).collect();
    format!(
        "This report measures how quickly each way of computing light transport through a \
         volume (an *estimator*) approaches a converged reference image, on {} scene{} ({}). \
         Every estimator renders the same image for fixed amounts of {} ({} s){}, and \
         lower error (RMSE against the reference) at equal time is better; `pins` and \
         `pinms` answer transmittance from a pin grid that was baked once beforehand, the \
         others need nothing precomputed. `{ERRORS_PNG}` plots error against time per scene \
         for the best estimator without a bake, `pins`, `pinms` and `pinres`, \
         `{ERRORS_ALL_PNG}` for every estimator, `{ERRORS_CSV}` holds every measurement, and the tables below say how much \
         sooner each estimator reaches the error of ray marching at step 0.015.{}\n\n",
        names.len(),
        if names.len() == 1 { "" } else { "s" },
        names.join(", "),
        match meta.clock {
            super::Clock::Wall => "wall time",
            super::Clock::Cpu => "CPU time per worker thread",
        },
        meta.budgets
            .iter()
            .map(|b| format!("{b}"))
            .collect::<Vec<_>>()
            .join(", "),
        match meta.clock {
            super::Clock::Wall => "",
            super::Clock::Cpu => " (`--clock cpu`; the `(gpu)` rows count wall time)",
        },
        if meta.quick {
            " This is the quick run (48 px images, sub-second budgets, references of 64 \
             samples per pixel and up, only the estimators a user picks): its figures show the \
             shape of the curves, not final numbers; `pinrender eval` without `--quick` makes \
             the full report."
        } else {
            ""
        }
    )
}

/// summary.md in the output directory.
pub fn markdown(results: &[SceneResult], meta: &RunMeta) -> Result<String> {
    let mut s = String::from("# pinrender eval: error against run time\n\n");
    s.push_str(&what_the_bake_buys(results));
    s.push_str(&opening(results, meta));
    let _ = writeln!(
        s,
        "![error against time per scene: the best estimator without a bake, pins, pinms, pinres]({ERRORS_PNG})\n"
    );
    s.push_str(&body(results, meta, ""));
    s.push_str(&format!(
        "Raw numbers: `{ERRORS_CSV}` (every budget), `bake.csv`; images: `<scene>/*.exr`.\n"
    ));
    Ok(s)
}

/// Writes the report for the docs, `docs/eval/report.md` (its own file: no hand-written
/// page is rewritten), and copies the figures beside it.
pub fn write_docs(docs: &Path, out: &Path, results: &[SceneResult], meta: &RunMeta) -> Result<()> {
    let eval_dir = docs.join("eval");
    std::fs::create_dir_all(&eval_dir)
        .with_context(|| format!("creating {}", eval_dir.display()))?;
    let per_scene = results.iter().flat_map(|r| {
        [
            format!("error_vs_time_{}.png", r.name),
            format!("images_{}.png", r.name),
        ]
    });
    for f in per_scene.chain([ERRORS_PNG.to_string(), ERRORS_ALL_PNG.to_string()]) {
        std::fs::copy(out.join(&f), eval_dir.join(&f))
            .with_context(|| format!("copying {f} to {}", eval_dir.display()))?;
    }
    let path = eval_dir.join(DOCS_REPORT);
    let md = markdown(results, meta)?;
    std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))
}
