//! `pinrender eval --default-asset`: the estimators a default file allows, at equal time.
//!
//! For each scene: the file `pinbake bake` writes with no grid flags (the default asset,
//! [`pinbake::plan::bake_to_file`] with the default request at the scene's density scale),
//! then every estimator of the renderer's catalogue that the file answers alone, and every
//! one that the source volume with the file's pins answers, each rendered progressively (the
//! eval's 1-spp passes, `--clock`) and compared with the converged ratio-tracking reference
//! of the full-resolution volume at each budget (`--budgets`, default 0.1 and 1 s): RMSE and
//! 8x8-block error. The estimator the default rule picks
//! ([`pinrender::front::default_estimator`]) is marked, so that the rule can be checked
//! against the measurement.
//!
//! Outputs (in `--out`): `asset_time.csv` (header [`ASSET_TIME_HEADER`]) and
//! `asset_time.md` (per scene and budget, the estimators by RMSE).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, anyhow};
use pinbake::{BakeInput, BakeRequest};
use pinrender::front::{Holds, available, default_estimator, holds};
use pinrender::medium::{MediumDesc, PlacedPins};
use pinrender::render::{
    Budget, DEFAULT_WAVEFRONT_BATCH, ESTIMATORS, Image, SampleLoop, block_bias, render,
    render_wavefront, rmse,
};
use pinrender::volume::OpenedMedium;

use super::scenes::{self, Sizes};
use super::{EvalArgs, LOOKUP, Stopwatch, pass_seed, scene_with, settings, worker_threads};

pub const ASSET_TIME_CSV: &str = "asset_time.csv";
pub const ASSET_TIME_HEADER: &str =
    "scene,input,estimator,default,budget_s,spp,seconds,rmse,block8_error,mean_error,file_bytes";
pub const ASSET_TIME_MD: &str = "asset_time.md";
/// The budgets without `--budgets`: the viewer's (0.1 s) and a longer one.
pub const ASSET_TIME_BUDGETS: [f64; 2] = [0.1, 1.0];
/// The scenes without `--scenes`.
pub const ASSET_TIME_SCENES: [&str; 2] = ["smoke", "hydrogen"];

/// One measurement.
struct Row {
    scene: String,
    /// `file` (the default file alone) or `volume+file` (the source with the file's pins).
    input: &'static str,
    estimator: String,
    /// The estimator the default rule picks for this input.
    default: bool,
    budget_s: f64,
    spp: u32,
    seconds: f64,
    rmse: f64,
    block8_error: f64,
    mean_error: f64,
    file_bytes: u64,
}

/// `pinrender eval --default-asset`.
pub fn run(a: &EvalArgs, scene_names: &[String], budgets: &[f64], production: &Path) -> Result<()> {
    let started = Instant::now();
    for name in scene_names {
        if !super::bytes::VOLUME_SCENES.contains(&name.as_str()) {
            crate::usage!(
                "--default-asset: scene '{name}' is not a volume file (scenes: {})",
                super::bytes::VOLUME_SCENES.join(", ")
            );
        }
    }
    let mut rows = Vec::new();
    let mut notes = Vec::new();
    for name in scene_names {
        pin_cli::errln!("== default asset at equal time: scene {name}");
        let (r, note) =
            scene_rows(name, a, budgets, production).with_context(|| format!("scene {name}"))?;
        rows.extend(r);
        notes.push(note);
        write_csv(&a.out.join(ASSET_TIME_CSV), &rows)?;
    }
    let md = markdown(&rows, &notes, a, budgets, started.elapsed().as_secs_f64());
    let path = a.out.join(ASSET_TIME_MD);
    std::fs::write(&path, md).with_context(|| format!("writing {}", path.display()))?;
    pin_cli::errln!(
        "eval --default-asset done in {:.1} s -> {}",
        started.elapsed().as_secs_f64(),
        path.display()
    );
    Ok(())
}

/// The scene's volume as `pinbake bake` reads it, at the scene's density scale.
fn bake_input(name: &str, production: &Path) -> Result<(BakeInput, f64, PathBuf)> {
    let exe = || std::env::current_exe().context("locating pinrender");
    let vdb = |path: PathBuf, scale: f64| -> Result<(BakeInput, f64, PathBuf)> {
        let spec = scenes::volume_args(scale)?
            .read
            .source_spec(&path, "volume", exe)?;
        Ok((BakeInput::Source(spec), scale, path))
    };
    match name {
        "smoke" => vdb(
            crate::data::path("openvdb_smoke1.vdb")?,
            scenes::SMOKE_DENSITY_SCALE,
        ),
        "hydrogen" => {
            let path = crate::data::path("hydrogen_atom_128x128x128_uint8.raw")?;
            let (options, scale) = scenes::hydrogen_read();
            Ok((
                BakeInput::Source(pin_volume::SourceSpec::Raw(path.clone(), options)),
                scale,
                path,
            ))
        }
        _ => vdb(production.to_path_buf(), scenes::PRODUCTION_DENSITY_SCALE),
    }
}

fn scene_rows(
    name: &str,
    a: &EvalArgs,
    budgets: &[f64],
    production: &Path,
) -> Result<(Vec<Row>, String)> {
    let sizes = Sizes {
        image: a.size.unwrap_or(128),
        pin_cells: 8,
        ref_spp: a.ref_spp.unwrap_or(1024),
        max_bounces: 8,
        cache_training_spp: 1,
    };
    let mut es = scenes::build(name, &sizes, production)?;
    es.ref_spp = sizes.ref_spp;
    let (reference, noise, _) = super::reference(&es, a)?;

    // The default file: `pinbake bake FILE --density-scale S -o OUT`.
    let (input, scale, source_path) = bake_input(name, production)?;
    let dir = a.out.join("cache");
    let pin = dir.join(format!("asset-{}-{name}.pin", std::process::id()));
    let req = BakeRequest {
        density_scale: scale,
        threads: a.threads,
        ..BakeRequest::default()
    };
    let t = Instant::now();
    let baked = pinbake::plan::bake_to_file(
        input,
        &pin,
        &req,
        &pin_volume::files::InputSet::default(),
        &(),
    )
    .map_err(|e| anyhow!("baking the default file: {e}"))?;
    let bake_s = t.elapsed().as_secs_f64();
    let file_bytes = std::fs::metadata(&pin)
        .with_context(|| pin.display().to_string())?
        .len();
    let chosen = baked
        .choice
        .asset
        .as_ref()
        .map_or("pins (no lattice)".to_string(), |x| {
            format!(
                "{} at factor {} ({}x{}x{})",
                x.chosen.representation,
                x.chosen.factor,
                x.chosen.dims[0],
                x.chosen.dims[1],
                x.chosen.dims[2]
            )
        });
    let grid = Arc::new(crate::volume::load_pins(&pin)?);
    let opened = OpenedMedium::pin_file(&pin, grid.clone())?;
    let file_desc: MediumDesc = opened.desc(16, None);
    let mut volume_desc = es
        .instances
        .first()
        .cloned()
        .ok_or_else(|| anyhow!("no volume"))?;
    volume_desc.pins = Some(PlacedPins {
        grid,
        local_to_world: None,
    });
    let holds_file = holds(None, Some(&pin))?;
    let holds_volume = Holds {
        density: true,
        volume: true,
        ..holds_file
    };
    let mut rows = Vec::new();
    for (input, desc, holds) in [
        ("file", &file_desc, holds_file),
        ("volume+file", &volume_desc, holds_volume),
    ] {
        let picked = default_estimator(holds, ESTIMATORS);
        for est in available(holds, ESTIMATORS) {
            let label = est.to_string();
            let medium = desc
                .cpu_medium(est, LOOKUP)
                .map_err(|e| anyhow!("{input} {label}: {e}"))?;
            let scene = scene_with(&es, vec![medium]);
            let pass = |seed: u64| -> Result<(Image, u32)> {
                let st = settings(&es, seed, Budget::Spp(1), a.threads);
                let out = if est.plan().sample_loop == SampleLoop::Wavefront {
                    render_wavefront(&scene, &st, DEFAULT_WAVEFRONT_BATCH)
                } else {
                    render(&scene, &st)
                }
                .map_err(|e| anyhow!("{e}"))?;
                Ok((out.image, out.spp))
            };
            for snap in progressive_with_images(&es, a, budgets, &reference, pass)? {
                let (mean, block) =
                    block_bias(&snap.image, &reference, 8).map_err(|e| anyhow!("{e}"))?;
                let r = Row {
                    scene: name.to_string(),
                    input,
                    estimator: label.clone(),
                    default: est == picked,
                    budget_s: snap.budget_s,
                    spp: snap.spp,
                    seconds: snap.seconds,
                    rmse: snap.rmse,
                    block8_error: block,
                    mean_error: mean,
                    file_bytes,
                };
                pin_cli::errln!(
                    "  {input:<12} {:<12} {:>5.2} s: {:>5} spp in {:.3} s  rmse {:.5}  block8 {:.4}{}",
                    r.estimator,
                    r.budget_s,
                    r.spp,
                    r.seconds,
                    r.rmse,
                    r.block8_error,
                    if r.default { "  (default)" } else { "" }
                );
                rows.push(r);
            }
        }
    }
    let _ = std::fs::remove_file(&pin);
    let source_bytes = std::fs::metadata(&source_path).map_or(0, |m| m.len());
    let note = format!(
        "**{name}**: {} ({source_bytes} bytes); the default file: {file_bytes} bytes, {chosen}, \
         baked in {bake_s:.1} s; reference: ratio tracking of the source, {} spp, its own \
         noise RMSE {noise:.2e}.",
        source_path.file_name().map_or_else(
            || source_path.display().to_string(),
            |n| n.to_string_lossy().into_owned()
        ),
        es.ref_spp
    );
    Ok((rows, note))
}

/// The running image when a budget was crossed.
struct Snapshot {
    budget_s: f64,
    spp: u32,
    seconds: f64,
    rmse: f64,
    image: Image,
}

/// The eval's progressive loop ([`super::progressive`]: 1-spp passes with the common seeds,
/// a row at each budget the running `--clock` time crosses), keeping the running image at
/// each row for its block error.
fn progressive_with_images(
    es: &scenes::EvalScene,
    a: &EvalArgs,
    budgets: &[f64],
    reference: &Image,
    mut pass: impl FnMut(u64) -> Result<(Image, u32)>,
) -> Result<Vec<Snapshot>> {
    let (width, height) = (es.scene.camera.width, es.scene.camera.height);
    let n = (width as usize) * (height as usize);
    let mut sum = vec![[0f64; 3]; n];
    let mut spp = 0u32;
    let mut elapsed = 0.0f64;
    let mut out = Vec::new();
    let mut next = 0usize;
    while next < budgets.len() {
        let t = Stopwatch::start(a.clock, worker_threads(a));
        let (image, got) = pass(pass_seed(a.seed, spp))?;
        if image.rgb.len() != n {
            anyhow::bail!("a pass returned {} pixels, expected {n}", image.rgb.len());
        }
        for (acc, p) in sum.iter_mut().zip(&image.rgb) {
            for c in 0..3 {
                acc[c] += f64::from(p[c]) * f64::from(got);
            }
        }
        spp = spp.saturating_add(got);
        elapsed += t.seconds();
        if elapsed >= budgets[next] || spp == u32::MAX {
            let inv = 1.0 / f64::from(spp.max(1));
            let img = Image {
                width,
                height,
                rgb: sum.iter().map(|s| s.map(|c| (c * inv) as f32)).collect(),
            };
            let e = rmse(&img, reference).map_err(|e| anyhow!("{e}"))?;
            while next < budgets.len() && (elapsed >= budgets[next] || spp == u32::MAX) {
                out.push(Snapshot {
                    budget_s: budgets[next],
                    spp,
                    seconds: elapsed,
                    rmse: e,
                    image: img.clone(),
                });
                next += 1;
            }
        }
    }
    Ok(out)
}

fn write_csv(path: &Path, rows: &[Row]) -> Result<()> {
    let mut s = String::from(ASSET_TIME_HEADER);
    s.push('\n');
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{},{},{},{:.4},{:.6},{:.6},{:.6},{}\n",
            r.scene,
            r.input,
            r.estimator,
            r.default,
            r.budget_s,
            r.spp,
            r.seconds,
            r.rmse,
            r.block8_error,
            r.mean_error,
            r.file_bytes
        ));
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

fn markdown(rows: &[Row], notes: &[String], a: &EvalArgs, budgets: &[f64], total: f64) -> String {
    let mut md = String::from("# The default file's estimators at equal time\n\n");
    md.push_str(&format!(
        "Each estimator the default file (`pinbake bake` with no grid flags) allows, alone \
         (`file`) or beside the source volume (`volume+file`), rendered progressively (1-spp \
         passes) until each budget of {:?} s ({:?} clock, {} threads) is spent, against a \
         converged ratio-tracking reference of the full-resolution volume. A first pass longer \
         than the budget overshoots it: `seconds` is what each row spent. `default`: what \
         `pinrender render` picks without `--estimator`. Run in {total:.0} s.\n\n",
        budgets,
        a.clock,
        super::worker_threads(a),
    ));
    let mut scenes: Vec<&str> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
    }
    for (k, scene) in scenes.iter().enumerate() {
        md.push_str(&format!("## {scene}\n\n"));
        if let Some(n) = notes.get(k) {
            md.push_str(&format!("{n}\n\n"));
        }
        md.push_str(
            "| input | budget | estimator | spp | seconds | RMSE | 8x8-block error | mean error |\n\
             |---|---|---|---|---|---|---|---|\n",
        );
        for input in ["file", "volume+file"] {
            for &b in budgets {
                let mut of: Vec<&Row> = rows
                    .iter()
                    .filter(|r| r.scene == *scene && r.input == input && r.budget_s == b)
                    .collect();
                of.sort_by(|x, y| x.rmse.total_cmp(&y.rmse));
                for r in of {
                    md.push_str(&format!(
                        "| {input} | {b} s | {}{} | {} | {:.3} | {:.4} | {:.2}% | {:+.2}% |\n",
                        r.estimator,
                        if r.default { " (default)" } else { "" },
                        r.spp,
                        r.seconds,
                        r.rmse,
                        100.0 * r.block8_error,
                        100.0 * r.mean_error
                    ));
                }
            }
        }
        md.push('\n');
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_header_names_every_column_once() {
        let cols: Vec<&str> = ASSET_TIME_HEADER.split(',').collect();
        assert_eq!(cols.len(), 11);
        let mut sorted = cols.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), cols.len());
    }
}
