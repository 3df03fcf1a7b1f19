//! A scene file's media: each asset opened once (its volume read, its pins loaded or baked
//! in memory, its estimators built in its own frame), then placed once per instance
//! ([`crate::instance`]), in an order that keeps neighbours together so that the runs of
//! consecutive instances in the leaves of the tracer's box hierarchy are compact.
//!
//! Messages name the scene file and the JSON path of what failed (`assets.cloud.volume`),
//! then the problem.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Result, anyhow};
use pin_scene::{Asset, Scene};
use pinbake::source::DensityScale;
use pinrt::SamplerOptions;

use crate::instance::{place_medium, world_box};
use crate::medium::MediumDesc;
use crate::render::{EstimatorSpec, Medium};
use crate::volume::{self, OpenedMedium, VolumeArgs};

/// What a render asks of its assets.
#[derive(Clone, Copy, Debug)]
pub struct AssetOptions {
    pub estimator: EstimatorSpec,
    /// Cells of an in-memory bake (an asset with a volume and no pins, for the pin
    /// estimators); `None`: chosen as `pinbake bake` chooses them.
    pub pin_cells: Option<u32>,
    pub seed: u64,
    pub majorant_bricks: u32,
    pub max_memory: Option<u64>,
    pub allow_mismatched_pins: bool,
    pub lookup: SamplerOptions,
    /// Load the pins an asset names even where `estimator` reads none (the viewer, whose
    /// menu offers every estimator the assets answer); a volume without pins is baked only
    /// for an estimator that reads them.
    pub named_pins: bool,
}

/// A world box `(min, max)`.
pub type WorldBox = ([f64; 3], [f64; 3]);

/// One asset, opened: its medium in its own frame and that frame's box.
pub struct OpenedAsset {
    pub desc: MediumDesc,
    pub bounds: ([f64; 3], [f64; 3]),
    /// The medium as `pinrender render` opens a volume or a pin file: what the GPU's copy of
    /// its density is made from ([`OpenedMedium::gpu_density`]).
    pub medium: OpenedMedium,
}

/// Bytes a placed instance holds at most on the CPU (its estimators, their boxes, a pin
/// sampler), counted against the memory budget before any is built.
pub const BYTES_PER_INSTANCE: u64 = 1024;

/// The scene's CPU media, one per instance, and the world box of them all.
pub struct SceneMedia {
    pub media: Vec<Medium>,
    /// `order[k]`: the instance (its index in the file) that `media[k]` places.
    pub order: Vec<usize>,
    pub bounds: ([f64; 3], [f64; 3]),
}

fn named(scene: &Scene, at: &str, e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("{}: {at}: {e}", pin_format::input::quoted(&scene.file))
}

/// The estimator when none is asked for (`pinrender render --scene`, `pinview`): pinms when
/// every asset an instance uses has both a volume and pins, pins when every one has pins,
/// ratio otherwise.
pub fn default_estimator(scene: &Scene) -> EstimatorSpec {
    let used: Vec<&Asset> = scene
        .assets
        .iter()
        .zip(scene.uses())
        .filter(|(_, n)| *n > 0)
        .map(|(a, _)| a)
        .collect();
    if used.iter().all(|a| a.pins.is_some() && a.volume.is_some()) {
        EstimatorSpec::PinMs
    } else if used.iter().all(|a| a.pins.is_some()) {
        EstimatorSpec::Pins
    } else {
        EstimatorSpec::RatioTracking
    }
}

/// Opens every asset that an instance uses (each once; unused assets are not read).
pub fn open_assets(scene: &Scene, o: &AssetOptions) -> Result<Vec<Option<OpenedAsset>>> {
    let budget = pinbake::files::MemoryBudget::new(o.max_memory);
    budget.check(
        &format!("{} instances", scene.instances.len()),
        (scene.instances.len() as u64).saturating_mul(BYTES_PER_INSTANCE),
    )?;
    let uses = scene.uses();
    scene
        .assets
        .iter()
        .zip(uses)
        .map(|(a, n)| (n > 0).then(|| open_asset(scene, a, o)).transpose())
        .collect()
}

fn open_asset(scene: &Scene, a: &Asset, o: &AssetOptions) -> Result<OpenedAsset> {
    let spec = o.estimator;
    match (&a.volume, &a.pins) {
        (Some(v), pins) => {
            let at = a.json_path("volume");
            // The scene's range rule (`pin_scene::ranges`) has checked it; the one rule
            // again, as a message rather than a panic.
            let density_scale = DensityScale::new(a.density_scale.unwrap_or(1.0))
                .map_err(|e| named(scene, &a.json_path("density_scale"), e.to_string()))?;
            let args = VolumeArgs {
                volume: None,
                read: pinbake::cli_args::SourceArgs {
                    grid: a.grid.clone(),
                    density_scale,
                    ..Default::default()
                },
            };
            let budget = pinbake::files::MemoryBudget::new(o.max_memory);
            let opened = volume::open_volume_within(v, &args, &budget)
                .map_err(|e| named(scene, &at, format!("{e:#}")))?;
            let source = opened.source();
            let b = source.bounds();
            let grid = if spec.needs_pins() || (o.named_pins && pins.is_some()) {
                let budget = pinbake::files::MemoryBudget::new(o.max_memory);
                let grid = volume::pins_for(
                    pins.as_deref(),
                    source.as_ref(),
                    o.pin_cells,
                    o.seed,
                    spec.needs_control(),
                    &budget,
                )
                .map_err(|e| named(scene, &a.json_path("pins"), format!("{e:#}")))?;
                if let Some(p) = pins {
                    volume::check_pins_match(
                        p,
                        &grid,
                        v,
                        source.as_ref(),
                        args.read.density_scale,
                        o.allow_mismatched_pins,
                    )
                    .map_err(|e| named(scene, &a.json_path("pins"), format!("{e:#}")))?;
                }
                Some(Arc::new(grid))
            } else {
                None
            };
            let medium = OpenedMedium::volume(
                opened,
                grid,
                pinbake::files::MemoryBudget::new(o.max_memory).limit,
            );
            Ok(OpenedAsset {
                desc: medium.desc(o.majorant_bricks, None),
                bounds: (b.min.to_array(), b.max.to_array()),
                medium,
            })
        }
        (None, Some(p)) => {
            let at = a.json_path("pins");
            let grid =
                Arc::new(volume::load_pins(p).map_err(|e| named(scene, &at, format!("{e:#}")))?);
            let medium =
                OpenedMedium::pin_file(p, grid).map_err(|e| named(scene, &at, format!("{e:#}")))?;
            if spec.needs_density() && medium.field.is_none() {
                return Err(named(
                    scene,
                    &at,
                    format!(
                        "{}: no embedded density, which the {spec} estimator needs (give the \
                         asset a volume, or bake with `pinbake bake --embed-density`)",
                        p.display()
                    ),
                ));
            }
            Ok(OpenedAsset {
                desc: medium.desc(o.majorant_bricks, None),
                bounds: medium.bounds,
                medium,
            })
        }
        (None, None) => Err(named(
            scene,
            &format!("assets.{}", a.name),
            "needs a volume, pins, or both",
        )),
    }
}

/// Interleaves the low 21 bits of `v` with two zero bits between each.
fn spread(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    (x | x << 2) & 0x1249_2492_4924_9249
}

/// The instances in Morton order of their world boxes' centres (ties in file order), so
/// that neighbours share the leaves of the tracer's box hierarchy.
pub fn morton_order(boxes: &[([f64; 3], [f64; 3])]) -> Vec<usize> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let centres: Vec<[f64; 3]> = boxes
        .iter()
        .map(|(a, b)| [0, 1, 2].map(|k| 0.5 * (a[k] + b[k])))
        .collect();
    for c in &centres {
        for k in 0..3 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    let cell = |c: &[f64; 3], k: usize| {
        let span = hi[k] - lo[k];
        if span > 0.0 {
            (((c[k] - lo[k]) / span) * f64::from((1u32 << 21) - 1)) as u64
        } else {
            0
        }
    };
    let mut keyed: Vec<(u64, usize)> = centres
        .iter()
        .enumerate()
        .map(|(i, c)| {
            (
                spread(cell(c, 0)) | spread(cell(c, 1)) << 1 | spread(cell(c, 2)) << 2,
                i,
            )
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// The CPU media of `scene`: each used asset's medium built once for `o.estimator`, placed
/// per instance.
pub fn cpu_media(
    scene: &Scene,
    assets: &[Option<OpenedAsset>],
    o: &AssetOptions,
) -> Result<SceneMedia> {
    let mut built: Vec<Option<Medium>> = Vec::with_capacity(assets.len());
    for (a, opened) in scene.assets.iter().zip(assets) {
        built.push(match opened {
            Some(x) => Some(
                x.desc
                    .cpu_medium(o.estimator, o.lookup)
                    .map_err(|e| named(scene, &format!("assets.{}", a.name), e))?,
            ),
            None => None,
        });
    }
    let boxes: Vec<_> = scene
        .instances
        .iter()
        .map(|inst| {
            let a = assets[inst.asset as usize]
                .as_ref()
                .expect("every used asset is opened");
            world_box(&inst.local_to_world, a.bounds)
        })
        .collect();
    let order = morton_order(&boxes);
    let mut media = Vec::with_capacity(order.len());
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in &order {
        let inst = &scene.instances[i];
        let asset = built[inst.asset as usize]
            .as_ref()
            .expect("every used asset is built");
        let placed = place_medium(asset, &inst.local_to_world, o.lookup)
            .map_err(|e| named(scene, &format!("{}.transform", Scene::instance_path(i)), e))?;
        media.push(placed);
        for k in 0..3 {
            lo[k] = lo[k].min(boxes[i].0[k]);
            hi[k] = hi[k].max(boxes[i].1[k]);
        }
    }
    Ok(SceneMedia {
        media,
        order,
        bounds: (lo, hi),
    })
}

/// The scene's instances as GPU medium descriptions for `o.estimator` on a device with
/// `limits`, in the order of [`cpu_media`]: each used asset's description (its density's GPU
/// copy made once, where the estimator reads the density) placed by the instance's transform
/// (`MediumDesc::placement`), so that the GPU asks every query of an instance in its asset's
/// frame as the CPU does ([`crate::instance`]) and uploads each asset once.
pub fn gpu_descs(
    scene: &Scene,
    assets: &[Option<OpenedAsset>],
    o: &AssetOptions,
    limits: &wgpu::Limits,
) -> Result<(Vec<MediumDesc>, WorldBox)> {
    let spec = o.estimator;
    let mut framed: Vec<Option<MediumDesc>> = Vec::with_capacity(assets.len());
    for (a, opened) in scene.assets.iter().zip(assets) {
        framed.push(match opened {
            None => None,
            Some(x) => {
                let at = || {
                    let key = if a.volume.is_some() { "volume" } else { "pins" };
                    a.json_path(key)
                };
                if spec.needs_pins() && x.desc.pins.is_none() {
                    return Err(named(scene, &format!("assets.{}", a.name), "no pins"));
                }
                let gpu_density = if spec.needs_density() {
                    let copy = x
                        .medium
                        .gpu_density(limits)
                        .map_err(|e| named(scene, &at(), format!("{e:#}")))?;
                    Some(Arc::new(copy))
                } else {
                    None
                };
                Some(MediumDesc {
                    gpu_density,
                    ..x.desc.clone()
                })
            }
        });
    }
    let mut descs = Vec::with_capacity(scene.instances.len());
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut boxes = Vec::with_capacity(scene.instances.len());
    for inst in &scene.instances {
        let a = assets[inst.asset as usize]
            .as_ref()
            .expect("every used asset is opened");
        boxes.push(world_box(&inst.local_to_world, a.bounds));
    }
    for i in morton_order(&boxes) {
        let inst = &scene.instances[i];
        let asset = framed[inst.asset as usize]
            .as_ref()
            .expect("every used asset is opened");
        crate::instance::invert(&inst.local_to_world).ok_or_else(|| {
            named(
                scene,
                &format!("{}.transform", Scene::instance_path(i)),
                "it is singular",
            )
        })?;
        descs.push(MediumDesc {
            placement: Some(inst.local_to_world),
            ..asset.clone()
        });
        for k in 0..3 {
            lo[k] = lo[k].min(boxes[i].0[k]);
            hi[k] = hi[k].max(boxes[i].1[k]);
        }
    }
    Ok((descs, (lo, hi)))
}

/// The values a scene file may set and a flag overrides (`pinrender render --scene`,
/// `pinview`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Look {
    pub fov: f64,
    pub sun_dir: [f64; 3],
    pub sun_radiance: f64,
    pub env_radiance: f64,
    pub albedo: f64,
    pub g: f64,
    pub max_bounces: u32,
}

impl Default for Look {
    fn default() -> Self {
        Look {
            fov: 40.0,
            sun_dir: [0.3, 1.0, 0.2],
            sun_radiance: 3.0,
            env_radiance: 0.3,
            albedo: 0.9,
            g: 0.0,
            max_bounces: 8,
        }
    }
}

/// The [`Look`] flags given on a command line (`None`: not given).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LookFlags {
    pub fov: Option<f64>,
    pub sun_dir: Option<[f64; 3]>,
    pub sun_radiance: Option<f64>,
    pub env_radiance: Option<f64>,
    pub albedo: Option<f64>,
    pub g: Option<f64>,
    pub max_bounces: Option<u32>,
}

impl Look {
    /// Each flag given, else the scene's value, else the default.
    pub fn over(flags: &LookFlags, scene: Option<&Scene>) -> Look {
        let d = Look::default();
        let sc = |f: &dyn Fn(&Scene) -> Option<f64>| scene.and_then(f);
        Look {
            fov: flags.fov.or(sc(&|s| s.camera.fov)).unwrap_or(d.fov),
            sun_dir: flags
                .sun_dir
                .or(scene.and_then(|s| s.sun.direction))
                .unwrap_or(d.sun_dir),
            sun_radiance: flags
                .sun_radiance
                .or(sc(&|s| s.sun.radiance))
                .unwrap_or(d.sun_radiance),
            env_radiance: flags
                .env_radiance
                .or(sc(&|s| s.env_radiance))
                .unwrap_or(d.env_radiance),
            albedo: flags.albedo.or(sc(&|s| s.albedo)).unwrap_or(d.albedo),
            g: flags.g.or(sc(&|s| s.g)).unwrap_or(d.g),
            max_bounces: flags
                .max_bounces
                .or(scene.and_then(|s| s.max_bounces))
                .unwrap_or(d.max_bounces),
        }
    }

    /// The frame a render with this look shows: the camera from `origin` to `target` at
    /// `width` x `height`, the sun where its radiance is positive, the sky and the material;
    /// no media yet (`max_bounces` goes to the render's settings).
    pub fn frame(
        &self,
        (origin, target): ([f64; 3], [f64; 3]),
        width: u32,
        height: u32,
    ) -> crate::render::Scene {
        let f = |v: [f64; 3]| v.map(|x| x as f32);
        crate::render::Scene {
            camera: crate::render::Camera {
                origin: f(origin),
                target: f(target),
                vfov_deg: self.fov as f32,
                width,
                height,
            },
            sun: (self.sun_radiance > 0.0).then(|| crate::render::Sun {
                dir: f(self.sun_dir),
                radiance: [self.sun_radiance as f32; 3],
            }),
            env_radiance: [self.env_radiance as f32; 3],
            albedo: self.albedo as f32,
            g: self.g as f32,
            media: Vec::new(),
        }
    }
}

/// The camera `(origin, target)`: each flag given, else the scene's, else in front of the
/// world box looking at its centre (as for one volume).
pub fn camera_over(
    origin: Option<[f64; 3]>,
    target: Option<[f64; 3]>,
    scene: Option<&Scene>,
    bounds: WorldBox,
) -> ([f64; 3], [f64; 3]) {
    let (lo, hi) = (glam::DVec3::from(bounds.0), glam::DVec3::from(bounds.1));
    let centre = (lo + hi) * 0.5;
    let size = (hi - lo).length();
    let target = target
        .or(scene.and_then(|s| s.camera.target))
        .unwrap_or(centre.to_array());
    let origin = origin.or(scene.and_then(|s| s.camera.origin)).unwrap_or([
        centre[0] + 0.35 * size,
        centre[1] + 0.25 * size,
        centre[2] + 1.6 * size,
    ]);
    (origin, target)
}

/// Loads `path` as a scene under the memory budget (`pin_scene::load`), with the error as
/// one line.
pub fn load_scene(path: &Path, max_memory: Option<u64>) -> Result<Scene> {
    let limit = pinbake::files::MemoryBudget::new(max_memory).limit;
    pin_scene::load(path, Some(limit)).map_err(|e| anyhow!("{e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_order_keeps_neighbours_together() {
        // Two clusters far apart, listed interleaved: the order separates them.
        let mut boxes = Vec::new();
        for i in 0..8 {
            let x = if i % 2 == 0 { 0.0 } else { 1000.0 } + i as f64 * 0.1;
            boxes.push(([x, 0.0, 0.0], [x + 1.0, 1.0, 1.0]));
        }
        let order = morton_order(&boxes);
        let first: Vec<bool> = order.iter().map(|&i| i % 2 == 0).collect();
        assert_eq!(first, [true, true, true, true, false, false, false, false]);
        let mut sorted = order.clone();
        sorted.sort();
        assert_eq!(sorted, (0..8).collect::<Vec<_>>());
        assert_eq!(spread(0b111), 0b1001001);
    }
}
