//! A scene file's media: each asset opened once (its volume read, its pins loaded or baked
//! in memory, its estimators built in its own frame), then placed once per instance
//! ([`crate::instance`]), in an order that keeps neighbours together so that the runs of
//! consecutive instances in the leaves of the tracer's box hierarchy are compact.
//!
//! Messages name the scene file and the JSON path of what failed (`assets.cloud.volume`),
//! then the problem.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Result, anyhow};
use pin_scene::{Asset, Scene};
use pin_volume::DensityScale;
use pin_volume::files::MemoryBudget;
use pinrt::SamplerOptions;

use crate::front::open::{PIN_FILE_READ_FACTOR, VOLUME_READ_FACTOR, read_cost};
use crate::front::{self, Holds, Input, PinsWanted, RenderFlags};
use crate::instance::{place_medium, world_box};
use crate::medium::MediumDesc;
use crate::render::{EstimatorSpec, Medium};
use crate::volume::OpenedMedium;

pub use crate::look::{Look, LookFlags};

/// What a render asks of its assets.
#[derive(Clone, Copy, Debug)]
pub struct AssetOptions {
    pub estimator: EstimatorSpec,
    /// Cells of an in-memory bake (an asset with a volume and no pins, for the pin
    /// estimators); `None`: chosen as `pinbake bake` chooses them.
    pub pin_cells: Option<u32>,
    pub seed: u64,
    pub majorant_bricks: u32,
    /// The command's one memory budget: the assets are charged to it together.
    pub budget: MemoryBudget,
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

/// What every asset an instance uses holds, from the scene's keys alone (nothing is read):
/// pins where each names a pin file, a density where each names a volume (a pin file's
/// embedded density is not looked for).
pub fn declared_holds(scene: &Scene) -> Holds {
    Holds::all(
        scene
            .assets
            .iter()
            .zip(scene.uses())
            .filter(|(_, n)| *n > 0)
            .map(|(a, _)| Holds {
                pins: a.pins.is_some(),
                density: a.volume.is_some(),
                volume: a.volume.is_some(),
                control: false,
            }),
    )
}

/// The estimator when none is asked for (`pinrender render --scene`, `pinview`): the one
/// default rule ([`front::default_estimator`]) over what every used asset declares
/// ([`declared_holds`]): pinms when every one has a volume and pins, pins when every one
/// has pins, ratio otherwise.
pub fn default_estimator(scene: &Scene) -> EstimatorSpec {
    front::default_estimator(declared_holds(scene), crate::render::ESTIMATORS)
}

/// What makes two assets one: the same files (by their canonical paths, where they
/// resolve), grid and density scale. Names that share a key are opened, read and baked once
/// and charged to the budget once.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct AssetKey {
    volume: Option<PathBuf>,
    pins: Option<PathBuf>,
    grid: Option<String>,
    density_scale: Option<u64>,
}

impl AssetKey {
    fn of(a: &Asset) -> Self {
        let canon = |p: &Option<PathBuf>| {
            p.as_ref()
                .map(|p| std::fs::canonicalize(p).unwrap_or_else(|_| p.clone()))
        };
        AssetKey {
            volume: canon(&a.volume),
            pins: canon(&a.pins),
            grid: a.grid.clone(),
            density_scale: a.density_scale.map(f64::to_bits),
        }
    }
}

/// Opens every asset that an instance uses, each distinct asset once ([`AssetKey`]: names
/// of one file share its opening), within the one budget of the command: each distinct
/// asset is opened within what the ones before it left, and its read and in-memory bake are
/// charged before the next (unused assets are not read).
pub fn open_assets(scene: &Scene, o: &AssetOptions) -> Result<Vec<Option<Arc<OpenedAsset>>>> {
    let instances = (scene.instances.len() as u64).saturating_mul(BYTES_PER_INSTANCE);
    o.budget
        .check(&format!("{} instances", scene.instances.len()), instances)?;
    let mut charged = instances;
    let mut opened: HashMap<AssetKey, Arc<OpenedAsset>> = HashMap::new();
    let mut out = Vec::with_capacity(scene.assets.len());
    for (a, n) in scene.assets.iter().zip(scene.uses()) {
        if n == 0 {
            out.push(None);
            continue;
        }
        let key = AssetKey::of(a);
        if let Some(x) = opened.get(&key) {
            out.push(Some(x.clone()));
            continue;
        }
        let left = MemoryBudget {
            limit: o.budget.limit.saturating_sub(charged),
        };
        let (asset, cost) = open_asset(scene, a, o, &left)?;
        charged = charged.saturating_add(cost);
        let asset = Arc::new(asset);
        opened.insert(key, asset.clone());
        out.push(Some(asset));
    }
    Ok(out)
}

/// Opens one asset within `budget` (what the assets before it left): its medium and the
/// bytes it holds (its read, and the pins baked in memory).
fn open_asset(
    scene: &Scene,
    a: &Asset,
    o: &AssetOptions,
    budget: &MemoryBudget,
) -> Result<(OpenedAsset, u64)> {
    let spec = o.estimator;
    let flags = RenderFlags {
        pin_cells: o.pin_cells,
        seed: o.seed,
        ..RenderFlags::default()
    };
    match (&a.volume, &a.pins) {
        (Some(v), pins) => {
            let at = a.json_path("volume");
            // The scene's range rule (`pin_scene::ranges`) has checked it; the one rule
            // again, as a message rather than a panic.
            let density_scale = DensityScale::new(a.density_scale.unwrap_or(1.0))
                .map_err(|e| named(scene, &a.json_path("density_scale"), e.to_string()))?;
            let read = pinbake::cli_args::SourceArgs {
                grid: a.grid.clone(),
                density_scale,
                ..Default::default()
            };
            let wants_pins = spec.needs_pins() || (o.named_pins && pins.is_some());
            let input = Input {
                volume: Some(v),
                read: &read,
                pins: pins.as_deref(),
                wanted: if wants_pins {
                    PinsWanted::Now {
                        control: spec.needs_control(),
                    }
                } else {
                    PinsWanted::No
                },
                allow_mismatched_pins: o.allow_mismatched_pins,
                gpu: None,
            };
            // The volume first, then its pins: each failure names its own key.
            let medium = front::open_medium(
                &Input {
                    wanted: PinsWanted::No,
                    ..input
                },
                &flags,
                budget,
            )
            .map_err(|e| named(scene, &at, format!("{e:#}")))?;
            let medium = front::open::with_pins(medium, &input, &flags, budget)
                .map_err(|e| named(scene, &a.json_path("pins"), format!("{e:#}")))?;
            let mut cost = read_cost(v, VOLUME_READ_FACTOR);
            if let Some(grid) = &medium.pins {
                cost = cost.saturating_add(match pins {
                    Some(p) => read_cost(p, 1),
                    None => grid.bytes().len() as u64,
                });
            }
            Ok((
                OpenedAsset {
                    desc: medium.desc(o.majorant_bricks, None),
                    bounds: medium.bounds,
                    medium,
                },
                cost,
            ))
        }
        (None, Some(p)) => {
            let at = a.json_path("pins");
            let input = Input {
                volume: None,
                read: &pinbake::cli_args::SourceArgs::default(),
                pins: Some(p),
                wanted: PinsWanted::No,
                allow_mismatched_pins: false,
                gpu: None,
            };
            let medium = front::open_medium(&input, &flags, budget)
                .map_err(|e| named(scene, &at, format!("{e:#}")))?;
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
            Ok((
                OpenedAsset {
                    desc: medium.desc(o.majorant_bricks, None),
                    bounds: medium.bounds,
                    medium,
                },
                read_cost(p, PIN_FILE_READ_FACTOR),
            ))
        }
        (None, None) => Err(named(
            scene,
            &format!("assets.{}", a.name),
            "needs a volume, pins, or both",
        )),
    }
}

/// For each asset, the first asset that shares its opening (itself where none before does).
fn first_names(assets: &[Option<Arc<OpenedAsset>>]) -> Vec<usize> {
    let mut seen: HashMap<*const OpenedAsset, usize> = HashMap::new();
    (0..assets.len())
        .map(|k| match &assets[k] {
            Some(x) => *seen.entry(Arc::as_ptr(x)).or_insert(k),
            None => k,
        })
        .collect()
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
    assets: &[Option<Arc<OpenedAsset>>],
    o: &AssetOptions,
) -> Result<SceneMedia> {
    let mut built: Vec<Option<Medium>> = Vec::with_capacity(assets.len());
    let first = first_names(assets);
    for (k, (a, opened)) in scene.assets.iter().zip(assets).enumerate() {
        built.push(match opened {
            // Another name of an asset built already: its medium, shared.
            Some(_) if first[k] < k => built[first[k]].clone(),
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
    assets: &[Option<Arc<OpenedAsset>>],
    o: &AssetOptions,
    limits: &wgpu::Limits,
) -> Result<(Vec<MediumDesc>, WorldBox)> {
    let spec = o.estimator;
    let mut framed: Vec<Option<MediumDesc>> = Vec::with_capacity(assets.len());
    let first = first_names(assets);
    for (k, (a, opened)) in scene.assets.iter().zip(assets).enumerate() {
        framed.push(match opened {
            None => None,
            // Another name of an asset framed already: its description, its density's GPU
            // copy uploaded once.
            Some(_) if first[k] < k => framed[first[k]].clone(),
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
pub fn load_scene(path: &Path, budget: &MemoryBudget) -> Result<Scene> {
    pin_scene::load(path, Some(budget.limit)).map_err(|e| anyhow!("{e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Names of one file share one opening (one read, one medium), and the distinct assets
    /// are charged to one budget together.
    #[test]
    fn names_of_one_file_are_opened_once_within_one_budget() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str| {
            let values: Vec<u8> = (0..16 * 16 * 16u32)
                .flat_map(|i| (1.0 + (i % 3) as f32).to_le_bytes())
                .collect();
            let p = dir.path().join(name);
            std::fs::write(&p, values).unwrap();
            p
        };
        // 16 KiB each, charged 128 KiB (8x) when read.
        write("a_16x16x16_float32.raw");
        write("b_16x16x16_float32.raw");
        let scene_of = |files: &[&str]| {
            let assets: Vec<String> = files
                .iter()
                .enumerate()
                .map(|(k, f)| format!("\"n{k}\": {{\"volume\": \"{f}\"}}"))
                .collect();
            let instances: Vec<String> = (0..files.len())
                .map(|k| format!("{{\"asset\": \"n{k}\"}}"))
                .collect();
            let text = format!(
                "{{\"assets\": {{{}}}, \"instances\": [{}]}}",
                assets.join(","),
                instances.join(",")
            );
            let p = dir.path().join("s.json");
            std::fs::write(&p, text).unwrap();
            pin_scene::load(&p, None).unwrap()
        };
        let options = |limit: u64| AssetOptions {
            estimator: EstimatorSpec::RatioTracking,
            pin_cells: None,
            seed: 0,
            majorant_bricks: 4,
            budget: MemoryBudget { limit },
            allow_mismatched_pins: false,
            lookup: SamplerOptions::RENDER,
            named_pins: false,
        };
        let one = ["a_16x16x16_float32.raw"; 3];
        let opened = open_assets(&scene_of(&one), &options(200 << 10)).unwrap();
        let [Some(x), Some(y), Some(z)] = &opened[..] else {
            panic!("three names, three assets");
        };
        assert!(
            Arc::ptr_eq(x, y) && Arc::ptr_eq(y, z),
            "one file, one opening"
        );
        let two = ["a_16x16x16_float32.raw", "b_16x16x16_float32.raw"];
        let e = open_assets(&scene_of(&two), &options(200 << 10))
            .err()
            .expect("two files of 128 KiB each exceed 200 KiB together")
            .to_string();
        assert!(
            e.contains("assets.n1.volume") && e.contains("reading"),
            "{e}"
        );
        assert!(open_assets(&scene_of(&two), &options(300 << 10)).is_ok());
    }

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
