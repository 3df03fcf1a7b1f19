//! The evaluation scenes: volumes, cameras, lights, per-instance estimators, references.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, anyhow, bail};
use glam::{DVec3, Vec3};
use pin_volume::procedural::CosineParams;
use pin_volume::{
    self as source, Aabb, CosineNoise, DenseGrid, Density, DensitySource, ProceduralSpec,
};
use pinlab::whole_volume::WholeVolumeBox;
use pinlab::{AnalyticOpticalDepth, CacheSettings, ClosedFormTracker, Estimator};
use pinrender::render::{
    Camera, EstimatorSpec, MajorantGrid, Medium, Scene, Sun, TransportEstimator, splitmix64,
};

use pinrender::gpu_render::{GpuDensity, GpuEstimator, GpuMedia};
use pinrender::medium::MediumDesc;
use pinrt::SamplerOptions;

use crate::volume::{Opened, TrackedSource, VolumeArgs};

/// Sizes that differ between the default run and `--quick`.
#[derive(Clone, Copy, Debug)]
pub struct Sizes {
    /// Image edge for the volume scenes (the cheap box scenes use 1.5x).
    pub image: u32,
    /// Pin grid cells per axis (scaled per scene).
    pub pin_cells: u32,
    /// Reference samples per pixel (scaled per scene by its cost).
    pub ref_spp: u32,
    pub max_bounces: u32,
    /// Training samples per pixel of the radiance cache.
    pub cache_training_spp: u32,
}

impl Sizes {
    pub fn default_run() -> Self {
        Sizes {
            image: 112,
            pin_cells: 24,
            ref_spp: 256,
            max_bounces: 8,
            cache_training_spp: 2,
        }
    }
    /// Small enough for well under a minute on 2 cores, large enough to read: 48 px images,
    /// references whose own noise the report states beside every error.
    pub fn quick() -> Self {
        Sizes {
            image: 48,
            pin_cells: 12,
            ref_spp: 64,
            max_bounces: 4,
            cache_training_spp: 1,
        }
    }
}

/// How the reference image of a scene is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RefKind {
    /// Ratio tracking transmittance + delta tracking distances over the majorant grid.
    Tracker,
    /// The closed-form tracker: exact transmittance, exact distance sampling.
    ClosedForm,
    /// Whole-volume sampling of the homogeneous box's single scattering (zero variance in
    /// the sun term; with no environment the only noise left is pixel anti-aliasing).
    WholeVolume,
}

impl RefKind {
    pub fn label(self) -> &'static str {
        match self {
            RefKind::Tracker => "ratio tracking (transmittance) + delta tracking (distances)",
            RefKind::ClosedForm => {
                "closed-form tracker (exact transmittance, exact distance sampling)"
            }
            RefKind::WholeVolume => {
                "whole-volume sampling of analytic single scattering (exact sun term)"
            }
        }
    }
}

/// An evaluation scene.
pub struct EvalScene {
    pub name: &'static str,
    /// One line for the report: what the scene is, resolution, density.
    pub about: String,
    /// Everything the reference depends on (for the on-disk cache key).
    pub key: String,
    /// Camera, lights, material; `media` is empty (filled per estimator).
    pub scene: Scene,
    pub max_bounces: u32,
    /// Each medium instance, described once for the CPU estimators and the GPU packing;
    /// their pins are placed after the bake.
    pub instances: Vec<MediumDesc>,
    /// The closed form of the one medium's optical depth (exact references), if it has one.
    pub closed_form: Option<Arc<dyn AnalyticOpticalDepth>>,
    /// The fields the pins are baked from, one pin grid each (the base volume for instanced
    /// scenes; a scene of several assets has one per asset).
    pub bake_sources: Vec<Arc<dyn DensitySource>>,
    /// Per instance, the index in `bake_sources` of its asset (empty: every instance's is
    /// the first). An instance's pins are placed in its description's frame by its
    /// `translation`.
    pub asset_of: Vec<usize>,
    pub bake_cells: u32,
    /// Bake with the cells and directions `pinbake bake` chooses for the volume (its default)
    /// even in `--quick` runs, which otherwise bake `bake_cells`^3 x octahedral:8 for time.
    pub choose_bake: bool,
    pub whole_volume: Option<WholeVolumeBox>,
    pub reference: RefKind,
    pub ref_spp: u32,
    pub estimators: Vec<String>,
    pub cache: CacheSettings,
    /// Why the GPU path tracer cannot render this scene on any device (no GPU copy of its
    /// density), if so.
    pub gpu_refusal: Option<String>,
}

pub const SCENES: [&str; 9] = [
    "smoke",
    "hydrogen",
    "cosine",
    "box",
    "box-ss",
    "instances",
    "cloud",
    "production",
    "cloudscape",
];

/// Scenes of the full run only, never of `--quick` (which CI runs): the 512^3 cloud needs
/// ~1 GiB and minutes to generate, bake and reference; the production cloud is an OpenVDB
/// file of 404 MB that `scripts/production/generate.sh half` writes; the cloudscape's 256
/// instances make every path and its reference several times a single cloud's cost.
pub const FULL_ONLY: [&str; 3] = ["cloud", "production", "cloudscape"];

/// The production scene's density scale (the cloud's densest voxels are 1).
pub const PRODUCTION_DENSITY_SCALE: f64 = 0.5;

pub const SMOKE_DENSITY_SCALE: f64 = 2.0;
const HYDROGEN_DENSITY_SCALE: f64 = 0.6;
const COSINE_SPEC: &str = "cosine:seed=7,freq=16,waves=8,density=4";
const BOX_MAX: [f64; 3] = [1.0, 0.7, 0.85];
const BOX_SIGMA: f64 = 4.0;
const BLOB_DENSITY: f64 = 6.0;
const BLOB_VOXELS: u32 = 32;
const INSTANCES_PER_AXIS: usize = 4;

/// The standard estimator list, plus scene extras.
fn estimators(extra: &[&str], cache: bool) -> Vec<String> {
    let mut v: Vec<String> = [
        "rm@0.05",
        "rm@0.015",
        "rm@0.005",
        "delta",
        "ratio",
        "residual",
        "urm",
        "jackknife",
        "pins",
        "pinms",
        "pinurm",
        "pinres",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    if cache {
        v.push("pinms+cache".into());
    }
    v.extend(extra.iter().map(|s| s.to_string()));
    v
}

/// Builds a scene by name; `production` is the OpenVDB file of the production scene.
pub fn build(name: &str, sizes: &Sizes, production: &Path) -> Result<EvalScene> {
    match name {
        "smoke" => smoke(sizes),
        "hydrogen" => hydrogen(sizes),
        "cosine" => cosine(sizes),
        "box" => homogeneous_box(sizes, false),
        "box-ss" => homogeneous_box(sizes, true),
        "instances" => instances(sizes),
        "cloud" => cloud(sizes),
        "production" => production_cloud(sizes, production),
        "cloudscape" => cloudscape(sizes),
        other => bail!("unknown scene '{other}' (known: {})", SCENES.join(", ")),
    }
}

pub fn volume_args(density_scale: f64) -> Result<VolumeArgs> {
    Ok(VolumeArgs::scaled(source::DensityScale::new(
        density_scale,
    )?))
}

/// A camera looking at the box centre from the front-right-above, framing the box.
fn frame_camera(lo: DVec3, hi: DVec3, size: u32, dir: DVec3, vfov: f64, fill: f64) -> Camera {
    let centre = (lo + hi) * 0.5;
    let radius = 0.5 * (hi - lo).length();
    let dist = radius / (0.5 * vfov.to_radians()).tan() * fill;
    let origin = centre + dir.normalize() * dist;
    let f = |v: DVec3| v.as_vec3().to_array();
    Camera {
        origin: f(origin),
        target: f(centre),
        vfov_deg: vfov as f32,
        width: size,
        height: size,
    }
}

fn lights(scene_size: f64) -> (Option<Sun>, [f32; 3]) {
    let _ = scene_size;
    (
        Some(Sun {
            dir: [-0.5, 0.8, 0.35],
            radiance: [3.0, 2.85, 2.6],
        }),
        [0.25, 0.3, 0.4],
    )
}

fn base_scene(camera: Camera, sun: Option<Sun>, env: [f32; 3]) -> Scene {
    Scene {
        camera,
        sun,
        env_radiance: env,
        albedo: 0.95,
        g: 0.0,
        media: Vec::new(),
    }
}

fn cache_for(lo: DVec3, hi: DVec3, sizes: &Sizes) -> CacheSettings {
    let extent = (hi - lo).max_element();
    CacheSettings {
        cell_size: (0.04 * extent) as f32,
        training_spp: sizes.cache_training_spp,
        ..CacheSettings::default()
    }
}

/// The one medium of a single-volume scene: `field` for the CPU, its GPU copy in the same
/// frame, majorants of `bricks`^3.
fn single_instance(
    field: Arc<dyn Density>,
    bricks: u32,
    gpu_density: Option<Arc<GpuDensity>>,
) -> Result<MediumDesc> {
    let majorants =
        Arc::new(MajorantGrid::from_field(&*field, [bricks; 3]).map_err(|e| anyhow!("{e}"))?);
    Ok(MediumDesc {
        field: Some(field),
        majorants: Some(majorants),
        majorant_bricks: bricks,
        pins: None,
        gpu_density,
        translation: [0.0; 3],
        placement: None,
    })
}

fn bounds_of(src: &dyn DensitySource) -> (DVec3, DVec3) {
    let b = src.bounds();
    (b.min, b.max)
}

fn cells(sizes: &Sizes, factor: f64) -> u32 {
    ((sizes.pin_cells as f64 * factor).round() as u32).max(2)
}

fn smoke(sizes: &Sizes) -> Result<EvalScene> {
    let path = crate::data::path("openvdb_smoke1.vdb")?;
    let opened = crate::volume::open_volume_typed(
        path.to_str().context("data path is not UTF-8")?,
        &volume_args(SMOKE_DENSITY_SCALE)?,
    )?;
    let src = opened.source();
    let gpu_density = Arc::new(opened.gpu_density()?);
    let (lo, hi) = bounds_of(&*src);
    let field: Arc<dyn Density> = Arc::new(TrackedSource::new(src.clone()));
    let inst = single_instance(field, 16, Some(gpu_density))?;
    let size = sizes.image;
    let camera = frame_camera(lo, hi, size, DVec3::new(0.4, 0.15, 1.0), 40.0, 0.95);
    let (sun, env) = lights((hi - lo).length());
    let bake_cells = cells(sizes, 1.0);
    Ok(EvalScene {
        name: "smoke",
        about: format!(
            "OpenVDB sample `openvdb_smoke1.vdb` (half-float density, voxel 0.476, box {:.1} x {:.1} x {:.1}), density scale {SMOKE_DENSITY_SCALE}, {size}x{size} px, {} bounces",
            (hi - lo).x,
            (hi - lo).y,
            (hi - lo).z,
            sizes.max_bounces
        ),
        key: format!("smoke|scale={SMOKE_DENSITY_SCALE}|maj=16"),
        scene: base_scene(camera, sun, env),
        max_bounces: sizes.max_bounces,
        instances: vec![inst],
        closed_form: None,
        bake_sources: vec![src],
        asset_of: Vec::new(),
        bake_cells,
        choose_bake: false,
        whole_volume: None,
        reference: RefKind::Tracker,
        ref_spp: sizes.ref_spp * 3,
        estimators: estimators(&[], true),
        cache: cache_for(lo, hi, sizes),
        gpu_refusal: None,
    })
}

/// How the hydrogen scene reads its raw file: the options and the density scale.
pub fn hydrogen_read() -> (source::RawOptions, f64) {
    let options = source::RawOptions {
        dims: Some([128; 3]),
        voxel_type: Some(source::RawType::U8),
        spacing: [1.0 / 128.0; 3],
        origin: [0.0; 3],
        ..source::RawOptions::default()
    };
    (options, HYDROGEN_DENSITY_SCALE)
}

fn hydrogen(sizes: &Sizes) -> Result<EvalScene> {
    let path = crate::data::path("hydrogen_atom_128x128x128_uint8.raw")?;
    let (options, scale) = hydrogen_read();
    let scale = source::DensityScale::new(scale)?;
    let opened = Opened::Dense(Arc::new(source::raw::read_raw(&path, &options, scale)?));
    let src = opened.source();
    let gpu_density = Arc::new(opened.gpu_density()?);
    let (lo, hi) = bounds_of(&*src);
    let field: Arc<dyn Density> = Arc::new(TrackedSource::new(src.clone()));
    let inst = single_instance(field, 16, Some(gpu_density))?;
    let size = sizes.image;
    let camera = frame_camera(lo, hi, size, DVec3::new(0.5, 0.35, 1.0), 40.0, 0.8);
    let (sun, env) = lights(1.0);
    let bake_cells = cells(sizes, 0.75);
    Ok(EvalScene {
        name: "hydrogen",
        about: format!(
            "hydrogen atom, raw u8 128^3 in the unit cube, density scale {HYDROGEN_DENSITY_SCALE} (extinction up to {:.0}), {size}x{size} px, {} bounces",
            250.0 * HYDROGEN_DENSITY_SCALE,
            sizes.max_bounces
        ),
        key: format!("hydrogen|scale={HYDROGEN_DENSITY_SCALE}|maj=16"),
        scene: base_scene(camera, sun, env),
        max_bounces: sizes.max_bounces,
        instances: vec![inst],
        closed_form: None,
        bake_sources: vec![src],
        asset_of: Vec::new(),
        bake_cells,
        choose_bake: false,
        whole_volume: None,
        reference: RefKind::Tracker,
        ref_spp: sizes.ref_spp * 8,
        estimators: estimators(&[], true),
        cache: cache_for(lo, hi, sizes),
        gpu_refusal: None,
    })
}

/// pinbake's cosine noise as the closed-form tracker's analytic field.
struct CosineAnalytic(Arc<CosineNoise>);

impl AnalyticOpticalDepth for CosineAnalytic {
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let b = Density::bounds(&*self.0);
        (b.min.to_array(), b.max.to_array())
    }
    fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
        self.0.optical_depth(o, d, t)
    }
    fn extinction(&self, p: DVec3) -> Option<f64> {
        Some(self.0.field(p))
    }
}

fn cosine(sizes: &Sizes) -> Result<EvalScene> {
    let spec: ProceduralSpec = COSINE_SPEC.parse().map_err(|e| anyhow!("{e}"))?;
    let noise = Arc::new(spec.build_noise()?);
    let src: Arc<dyn DensitySource> = noise.clone();
    let gpu_density = Arc::new(Opened::Noise(noise.clone()).gpu_density()?);
    let (lo, hi) = bounds_of(&*src);
    let field: Arc<dyn Density> = Arc::new(TrackedSource::new(src.clone()));
    let analytic: Arc<dyn AnalyticOpticalDepth> = Arc::new(CosineAnalytic(noise));
    let inst = single_instance(field, 16, Some(gpu_density))?;
    let size = sizes.image;
    let camera = frame_camera(lo, hi, size, DVec3::new(0.6, 0.45, 1.0), 40.0, 0.8);
    let (sun, env) = lights(1.0);
    let bake_cells = cells(sizes, 1.0);
    Ok(EvalScene {
        name: "cosine",
        about: format!(
            "unit cube of cosine noise `{COSINE_SPEC}` (16 cycles across the box: the thesis' hard case for ray marching), {size}x{size} px, {} bounces",
            sizes.max_bounces
        ),
        key: format!("cosine|{COSINE_SPEC}"),
        scene: base_scene(camera, sun, env),
        max_bounces: sizes.max_bounces,
        instances: vec![inst],
        closed_form: Some(analytic),
        bake_sources: vec![src],
        asset_of: Vec::new(),
        bake_cells,
        choose_bake: false,
        whole_volume: None,
        reference: RefKind::ClosedForm,
        ref_spp: sizes.ref_spp * 2,
        estimators: estimators(&["cosine-closed-form"], true),
        cache: cache_for(lo, hi, sizes),
        gpu_refusal: None,
    })
}

/// The homogeneous box's closed-form optical depth (chord length times extinction).
struct BoxAnalytic(source::HomogeneousBox);

impl AnalyticOpticalDepth for BoxAnalytic {
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let b = Density::bounds(&self.0);
        (b.min.to_array(), b.max.to_array())
    }
    fn optical_depth(&self, o: DVec3, d: DVec3, t: f64) -> f64 {
        self.0.optical_depth(o, d, t)
    }
    fn extinction(&self, _p: DVec3) -> Option<f64> {
        Some(self.0.density() as f64)
    }
}

fn homogeneous_box(sizes: &Sizes, single: bool) -> Result<EvalScene> {
    let (lo, hi) = (DVec3::ZERO, DVec3::from_array(BOX_MAX));
    let pb = source::HomogeneousBox::new(Aabb::new(lo, hi), BOX_SIGMA as f32)?;
    let src: Arc<dyn DensitySource> = Arc::new(pb.clone());
    let gpu_density = Arc::new(Opened::Box(pb.clone()).gpu_density()?);
    // The renderer tracks the baker's box itself.
    let field = src.clone();
    let analytic: Arc<dyn AnalyticOpticalDepth> = Arc::new(BoxAnalytic(pb));
    let inst = single_instance(field, 1, Some(gpu_density))?;
    // The box scenes are cheap: a larger image.
    let size = sizes.image + sizes.image / 2;
    let camera = frame_camera(lo, hi, size, DVec3::new(0.55, 0.5, 1.0), 40.0, 0.8);
    let (sun, env) = lights(1.0);
    let bake_cells = cells(sizes, 0.34);
    let (name, env, bounces, reference, ests, about) = if single {
        (
            "box-ss",
            [0.0; 3],
            1,
            RefKind::WholeVolume,
            [
                "rm@0.05",
                "rm@0.015",
                "rm@0.005",
                "delta",
                "ratio",
                "residual",
                "urm",
                "jackknife",
                "pins",
                "box-closed-form",
                "whole-volume",
            ]
            .iter()
            .map(|s| s.to_string())
            .collect(),
            "single scattering only (1 bounce, sun only, no environment): the exact reference of the whole-volume paper; PinMS and the cache do not apply (no multiple scattering)",
        )
    } else {
        (
            "box",
            env,
            sizes.max_bounces,
            RefKind::ClosedForm,
            estimators(&["box-closed-form"], true),
            "multiple scattering, sun and sky",
        )
    };
    Ok(EvalScene {
        name,
        about: format!(
            "homogeneous box {:?} with extinction {BOX_SIGMA}, {about}; {size}x{size} px, {bounces} bounce(s)",
            BOX_MAX
        ),
        key: format!("{name}|box={BOX_MAX:?}|sigma={BOX_SIGMA}|env={env:?}"),
        scene: base_scene(camera, sun, env),
        max_bounces: bounces,
        instances: vec![inst],
        closed_form: Some(analytic),
        bake_sources: vec![src],
        asset_of: Vec::new(),
        bake_cells,
        choose_bake: false,
        whole_volume: Some(WholeVolumeBox::new(
            lo.to_array(),
            hi.to_array(),
            BOX_SIGMA,
        )?),
        reference,
        ref_spp: sizes.ref_spp * if single { 1 } else { 8 },
        estimators: ests,
        cache: cache_for(lo, hi, sizes),
        gpu_refusal: None,
    })
}

/// A field moved by `offset` (what an instance transform does to a tracker's field).
pub struct Offset {
    inner: Arc<dyn Density>,
    off: [f64; 3],
    off32: Vec3,
    lo: [f64; 3],
    hi: [f64; 3],
}

impl Offset {
    pub fn new(inner: Arc<dyn Density>, off: [f64; 3]) -> Self {
        let (lo, hi) = inner.bounds().to_arrays();
        Offset {
            off,
            off32: DVec3::from_array(off).as_vec3(),
            lo: [0, 1, 2].map(|a| lo[a] + off[a]),
            hi: [0, 1, 2].map(|a| hi[a] + off[a]),
            inner,
        }
    }
}

impl Density for Offset {
    fn bounds(&self) -> Aabb {
        Aabb::from_arrays(self.lo, self.hi)
    }
    /// The shift in f32, as an instance transform moves the renderer's f32 points.
    #[inline]
    fn extinction(&self, p: DVec3) -> f32 {
        self.inner.extinction((p.as_vec3() - self.off32).as_dvec3())
    }
    fn max_extinction_in(&self, region: Aabb) -> f32 {
        let (lo, hi) = region.to_arrays();
        self.inner.max_extinction_in(Aabb::from_arrays(
            [0, 1, 2].map(|a| lo[a] - self.off[a]),
            [0, 1, 2].map(|a| hi[a] - self.off[a]),
        ))
    }
}

/// The instance blob: a ball with a smooth `(1 - r^2)^2` falloff modulated by low-frequency
/// cosine noise, voxelised to `BLOB_VOXELS^3` in the unit cube.
fn blob() -> Result<DenseGrid> {
    let noise = CosineNoise::new(
        Aabb::new(DVec3::ZERO, DVec3::ONE),
        &CosineParams {
            seed: 3,
            freq: 3.0,
            waves: 12,
            density: 1.0,
            ..CosineParams::default()
        },
        "blob noise",
    )?;
    let n = BLOB_VOXELS as usize;
    let h = 1.0 / n as f64;
    let mut data = vec![0.0f32; n * n * n];
    for (i, v) in data.iter_mut().enumerate() {
        let p = DVec3::new(
            (i % n) as f64 + 0.5,
            ((i / n) % n) as f64 + 0.5,
            (i / (n * n)) as f64 + 0.5,
        ) * h;
        let r2 = ((p - DVec3::splat(0.5)) * 2.0).length_squared();
        let w = if r2 < 1.0 {
            (1.0 - r2) * (1.0 - r2)
        } else {
            0.0
        };
        *v = (BLOB_DENSITY * w * noise.field(p)) as f32;
    }
    Ok(DenseGrid::new(
        [BLOB_VOXELS; 3],
        data,
        DVec3::splat(h),
        DVec3::ZERO,
        "noise blob",
    )?)
}

fn instances(sizes: &Sizes) -> Result<EvalScene> {
    let blob = Opened::Dense(Arc::new(blob()?));
    let gpu_density = Arc::new(blob.gpu_density()?);
    let base = blob.source();
    let base_field: Arc<dyn Density> = Arc::new(TrackedSource::new(base.clone()));
    let k = INSTANCES_PER_AXIS;
    let spacing = 0.55;
    let mut seed = 0x1257_u64;
    let mut rnd = || {
        seed = splitmix64(seed);
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut insts = Vec::with_capacity(k * k * k);
    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
    for z in 0..k {
        for y in 0..k {
            for x in 0..k {
                let off = DVec3::new(x as f64, y as f64, z as f64) * spacing
                    + DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5) * 0.25;
                let field: Arc<dyn Density> =
                    Arc::new(Offset::new(base_field.clone(), off.to_array()));
                lo = lo.min(off);
                hi = hi.max(off + DVec3::ONE);
                let majorants = Arc::new(
                    MajorantGrid::from_field(&*field, [4; 3]).map_err(|e| anyhow!("{e}"))?,
                );
                insts.push(MediumDesc {
                    field: Some(field),
                    majorants: Some(majorants),
                    majorant_bricks: 4,
                    pins: None,
                    gpu_density: Some(gpu_density.clone()),
                    translation: off.to_array(),
                    placement: None,
                });
            }
        }
    }
    // 64 media, of which a ray meets about 8: every path is still several times the cost
    // of a single-medium path, hence a smaller image.
    let size = (sizes.image * 5 / 7).max(4);
    let camera = frame_camera(lo, hi, size, DVec3::new(0.5, 0.6, 1.0), 40.0, 0.8);
    let (sun, env) = lights((hi - lo).length());
    // 12^3 cells over the 32^3 blob (2.7 voxels per cell): PinMS's multiple-scattering bias
    // (the RMSE of 8x8-pixel block means against a 1536-spp reference, where the noise of
    // an unbiased estimator is ~0.0015) drops from 0.0052 at 8^3 cells to 0.0037, at the same
    // spp (a 0.9 MB grid, still cache-resident); 16^3 gives no further gain and 24^3 (7.2 MB)
    // costs ~20% of the spp for 0.0031.
    let bake_cells = cells(sizes, 0.5);
    let n = insts.len();
    Ok(EvalScene {
        name: "instances",
        about: format!(
            "{n} overlapping instances (4x4x4 jittered lattice, spacing {spacing}) of one noise blob ({BLOB_VOXELS}^3 voxels, unit box, peak extinction ~{:.0}), each its own medium with its own majorant grid / pin sampler placed by a translation; {size}x{size} px, {} bounces, one pin grid shared by all instances",
            2.0 * BLOB_DENSITY,
            sizes.max_bounces
        ),
        // `boxes`: since media whose box a ray misses are skipped, the reference draws
        // different random numbers (same expectation) than before.
        key: format!("instances|n={n}|blob={BLOB_VOXELS},{BLOB_DENSITY}|maj=4|boxes"),
        scene: base_scene(camera, sun, env),
        max_bounces: sizes.max_bounces,
        instances: insts,
        closed_form: None,
        bake_sources: vec![base],
        asset_of: Vec::new(),
        bake_cells,
        choose_bake: false,
        whole_volume: None,
        reference: RefKind::Tracker,
        // Skipping missed media made the reference tracker ~2x faster: twice the samples
        // of before (384 at the default size) in about the same time.
        ref_spp: (sizes.ref_spp * 3).max(1),
        estimators: estimators(&[], true),
        cache: cache_for(lo, hi, sizes),
        gpu_refusal: None,
    })
}

/// The production-scale scene: a fractal cloud of `CLOUD_VOXELS`^3 f32
/// voxels generated at run time (`eval/cloud.rs`), pins baked as `pinbake bake` chooses.
fn cloud(sizes: &Sizes) -> Result<EvalScene> {
    use pinlab::fractal_cloud::{CLOUD_DENSITY, CLOUD_VOXELS};
    let t = std::time::Instant::now();
    let opened = Opened::Dense(Arc::new(pinlab::fractal_cloud::cloud(CLOUD_VOXELS)?));
    pin_cli::errln!(
        "  cloud: {CLOUD_VOXELS}^3 voxels generated in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    let src = opened.source();
    let gpu_density = Arc::new(opened.gpu_density()?);
    let (lo, hi) = bounds_of(&*src);
    let field: Arc<dyn Density> = Arc::new(TrackedSource::new(src.clone()));
    // Finer bricks than the other scenes: the cloud has large empty regions between lobes.
    let inst = single_instance(field, 32, Some(gpu_density))?;
    let size = sizes.image;
    let camera = frame_camera(lo, hi, size, DVec3::new(0.5, 0.3, 1.0), 40.0, 0.8);
    let (sun, env) = lights(1.0);
    // The trackers, pins and PinMS, and rm@0.015 for the time-to-error
    // column; the other estimators would add minutes at this size and say nothing new.
    let ests: Vec<String> = [
        "rm@0.015", "delta", "ratio", "residual", "pins", "pinms", "pinurm", "pinres",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    Ok(EvalScene {
        name: "cloud",
        about: format!(
            "production scale: a fractal cloud voxelised at run time to {CLOUD_VOXELS}^3 f32 voxels ({} MiB, larger than the CPU caches) in the unit cube, peak extinction {CLOUD_DENSITY}, {size}x{size} px, {} bounces, pins as `pinbake bake` chooses them",
            (u64::from(CLOUD_VOXELS).pow(3) * 4) >> 20,
            sizes.max_bounces
        ),
        key: format!("cloud|n={CLOUD_VOXELS}|density={CLOUD_DENSITY}|maj=32"),
        scene: base_scene(camera, sun, env),
        max_bounces: sizes.max_bounces,
        instances: vec![inst],
        closed_form: None,
        bake_sources: vec![src],
        asset_of: Vec::new(),
        bake_cells: 0,
        choose_bake: true,
        whole_volume: None,
        reference: RefKind::Tracker,
        ref_spp: sizes.ref_spp,
        estimators: ests,
        cache: cache_for(lo, hi, sizes),
        gpu_refusal: None,
    })
}

/// The production-scale scene: the OpenVDB cumulus cloud of `scripts/production/generate.sh
/// half` (992 x 674 x 1225 voxels, about 263 M active, half floats), read as `pinbake bake` and
/// `pinrender render` read it, pins baked as `pinbake bake` chooses them. Its reference has 4
/// times the base samples per pixel (ratio tracking is slow here, so the estimators reach
/// fewer samples in a budget than on the small scenes).
fn production_cloud(sizes: &Sizes, vdb: &Path) -> Result<EvalScene> {
    let t = std::time::Instant::now();
    let opened =
        crate::volume::open_volume_typed(vdb.as_os_str(), &volume_args(PRODUCTION_DENSITY_SCALE)?)?;
    let src = opened.source();
    pin_cli::errln!(
        "  production: {} opened in {:.1} s",
        vdb.display(),
        t.elapsed().as_secs_f64()
    );
    // The GPU rows need a copy of the density the device can hold; where there is none, the
    // CPU rows stand and the report says why the GPU rows are missing.
    let (gpu_density, gpu_refusal) = match opened.gpu_density() {
        Ok(d) => (Some(Arc::new(d)), None),
        Err(e) => (None, Some(format!("{e:#}"))),
    };
    let (lo, hi) = bounds_of(&*src);
    let field: Arc<dyn Density> = Arc::new(TrackedSource::new(src.clone()));
    let inst = single_instance(field, 32, gpu_density)?;
    let size = sizes.image;
    let camera = frame_camera(lo, hi, size, DVec3::new(0.5, 0.3, 1.0), 40.0, 0.8);
    let (sun, env) = lights((hi - lo).length());
    let ests: Vec<String> = [
        "rm@0.015", "delta", "ratio", "residual", "urm", "pins", "pinms", "pinurm", "pinres",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let bytes = std::fs::metadata(vdb).map(|m| m.len()).unwrap_or(0);
    Ok(EvalScene {
        name: "production",
        about: format!(
            "production scale: the OpenVDB cumulus cloud `{}` ({:.0} MB, written by OpenVDB \
             with `scripts/production/generate.sh half`), box {:.0} x {:.0} x {:.0}, density \
             scale {PRODUCTION_DENSITY_SCALE}, {size}x{size} px, {} bounces, pins as `pinbake \
             bake` chooses them",
            vdb.file_name().map_or_else(
                || vdb.display().to_string(),
                |n| n.to_string_lossy().into_owned()
            ),
            bytes as f64 / 1e6,
            (hi - lo).x,
            (hi - lo).y,
            (hi - lo).z,
            sizes.max_bounces
        ),
        key: format!(
            "production|file={}|bytes={bytes}|scale={PRODUCTION_DENSITY_SCALE}|maj=32",
            vdb.display()
        ),
        scene: base_scene(camera, sun, env),
        max_bounces: sizes.max_bounces,
        instances: vec![inst],
        closed_form: None,
        bake_sources: vec![src],
        asset_of: Vec::new(),
        bake_cells: 0,
        choose_bake: true,
        whole_volume: None,
        reference: RefKind::Tracker,
        ref_spp: sizes.ref_spp * 4,
        estimators: ests,
        cache: cache_for(lo, hi, sizes),
        gpu_refusal,
    })
}

/// Instances of the cloudscape (`scripts/cloudscape_scene.py`'s rule at 256).
const CLOUDSCAPE_INSTANCES: usize = 256;
/// Its two clouds' voxels, the sizes of `scripts/cloudscape-bench.sh` (the same cloud at
/// two resolutions, alternating between instances).
const CLOUDSCAPE_DIMS: [[u32; 3]; 2] = [[62, 42, 77], [124, 84, 153]];
/// A cloud's length along its longest axis (the production generator's clouds span 10).
const CLOUDSCAPE_CLOUD: f64 = 10.0;
/// Peak extinction per unit: a 10-unit cloud's core is some 10 mean free paths across.
const CLOUDSCAPE_PEAK: f64 = 1.5;
/// Majorant bricks per axis of each cloud (8 to 10 voxels per brick of the finer cloud).
const CLOUDSCAPE_BRICKS: u32 = 16;

/// The 256-instance cloudscape of `docs/scene.md` ("Cloudscapes measured"): two clouds of
/// `pinlab::fractal_cloud` (`stretched_cloud`, the same cloud at two resolutions), each
/// voxelised, given its majorants and GPU copy and baked once, placed by 256 instances
/// turned about the vertical, tilted and stretched per axis over a sky slab, the two
/// alternating: `scripts/cloudscape_scene.py`'s rule and look with seed 1, drawn from the
/// eval's splitmix64 stream (not Python's). Each instance asks its queries in its cloud's
/// frame (`MediumDesc::placement`) on the CPU and the GPU.
fn cloudscape(sizes: &Sizes) -> Result<EvalScene> {
    use pinrender::instance::world_box;
    let t = std::time::Instant::now();
    struct Cloud {
        source: Arc<dyn DensitySource>,
        desc: MediumDesc,
        bounds: ([f64; 3], [f64; 3]),
    }
    let mut clouds = Vec::new();
    for dims in CLOUDSCAPE_DIMS {
        let grid = pinlab::fractal_cloud::stretched_cloud(dims, CLOUDSCAPE_CLOUD, CLOUDSCAPE_PEAK)?;
        let opened = Opened::Dense(Arc::new(grid));
        let gpu_density = Arc::new(opened.gpu_density()?);
        let source = opened.source();
        let (lo, hi) = bounds_of(&*source);
        let field: Arc<dyn Density> = Arc::new(TrackedSource::new(source.clone()));
        let desc = single_instance(field, CLOUDSCAPE_BRICKS, Some(gpu_density))?;
        clouds.push(Cloud {
            source,
            desc,
            bounds: (lo.to_array(), hi.to_array()),
        });
    }
    pin_cli::errln!(
        "  cloudscape: clouds of {:?} voxels generated in {:.1} s",
        CLOUDSCAPE_DIMS,
        t.elapsed().as_secs_f64()
    );
    // scripts/cloudscape_scene.py: a slab of side 2 sqrt(count) cloud lengths.
    let size = CLOUDSCAPE_CLOUD;
    let side = (CLOUDSCAPE_INSTANCES as f64).sqrt() * size;
    let mut seed = 1_u64;
    let mut uniform = |a: f64, b: f64| {
        seed = splitmix64(seed);
        a + (b - a) * ((seed >> 11) as f64 / (1u64 << 53) as f64)
    };
    let mut placed = Vec::with_capacity(CLOUDSCAPE_INSTANCES);
    for i in 0..CLOUDSCAPE_INSTANCES {
        let s = uniform(0.6, 1.4);
        let trs = pin_scene::Trs {
            translate: [
                uniform(-side, side),
                uniform(0.0, 0.6 * size),
                uniform(-side, side),
            ],
            rotate_deg: [uniform(-8.0, 8.0), uniform(0.0, 360.0), uniform(-8.0, 8.0)],
            scale: [
                s * uniform(0.85, 1.25),
                s * uniform(0.8, 1.0),
                s * uniform(0.85, 1.25),
            ],
        };
        let m = pin_scene::compose_trs(&trs);
        let asset = i % CLOUDSCAPE_DIMS.len();
        placed.push((asset, m, world_box(&m, clouds[asset].bounds)));
    }
    // Morton order of the instances' boxes, as a scene file's are listed (neighbours share
    // the leaves of the box hierarchy).
    let boxes: Vec<_> = placed.iter().map(|p| p.2).collect();
    let order = pinrender::scene_media::morton_order(&boxes);
    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
    let mut insts = Vec::with_capacity(order.len());
    let mut asset_of = Vec::with_capacity(order.len());
    for i in order {
        let (asset, m, (blo, bhi)) = placed[i];
        lo = lo.min(DVec3::from(blo));
        hi = hi.max(DVec3::from(bhi));
        insts.push(MediumDesc {
            placement: Some(m),
            ..clouds[asset].desc.clone()
        });
        asset_of.push(asset);
    }
    let image = sizes.image;
    // The script's camera: from above the slab's edge, looking across it and down a little.
    let camera = Camera {
        origin: [0.0, (2.5 * size) as f32, (-side - 3.0 * size) as f32],
        target: [0.0, (0.3 * size) as f32, 0.0],
        vfov_deg: 50.0,
        width: image,
        height: image,
    };
    let sun = Some(Sun {
        dir: [0.4, 1.0, 0.3],
        radiance: [3.0; 3],
    });
    // The eval's material (albedo 0.95, isotropic), the script's sun and sky.
    let scene = base_scene(camera, sun, [0.3; 3]);
    let n = insts.len();
    Ok(EvalScene {
        name: "cloudscape",
        about: format!(
            "{n} overlapping instances of two fractal clouds (the same cloud voxelised at {:?} and {:?}, {CLOUDSCAPE_CLOUD} units long, peak extinction {CLOUDSCAPE_PEAK}), alternating, turned about the vertical, tilted and stretched per axis over a {:.0}-unit sky slab (scripts/cloudscape_scene.py's rule, seed 1), each asset's density, majorants ({CLOUDSCAPE_BRICKS}^3) and pins built once and every instance queried in its cloud's frame; {image}x{image} px, {} bounces",
            CLOUDSCAPE_DIMS[0],
            CLOUDSCAPE_DIMS[1],
            2.0 * side,
            sizes.max_bounces
        ),
        key: format!(
            "cloudscape|n={n}|dims={CLOUDSCAPE_DIMS:?}|len={CLOUDSCAPE_CLOUD}|peak={CLOUDSCAPE_PEAK}|maj={CLOUDSCAPE_BRICKS}|seed=1"
        ),
        scene,
        max_bounces: sizes.max_bounces,
        instances: insts,
        closed_form: None,
        bake_sources: clouds.iter().map(|c| c.source.clone()).collect(),
        asset_of,
        bake_cells: cells(sizes, 0.5),
        choose_bake: true,
        whole_volume: None,
        reference: RefKind::Tracker,
        // 64 times the base samples (16,384 at the default, as `scripts/cloudscape-bench.sh`'s
        // reference): the estimators' errors at the longer budgets are a few 1e-3 here.
        ref_spp: sizes.ref_spp * 64,
        estimators: estimators(&[], true),
        cache: cache_for(lo, hi, sizes),
        gpu_refusal: None,
    })
}

/// One instance's estimator by name: the closed forms (over the scene's `closed_form`) here,
/// every other through the one parser and the instance's description.
pub fn estimator(
    inst: &MediumDesc,
    closed_form: Option<&Arc<dyn AnalyticOpticalDepth>>,
    name: &str,
) -> Result<Arc<dyn TransportEstimator>> {
    Ok(match name {
        "pins" => {
            inst.cpu_medium(EstimatorSpec::Pins, super::LOOKUP)
                .map_err(|_| anyhow!("pins are not baked for this scene"))?
                .primary
        }
        "cosine-closed-form" | "box-closed-form" => {
            let a = closed_form
                .cloned()
                .ok_or_else(|| anyhow!("{name}: this scene has no closed form"))?;
            Arc::new(ClosedFormTracker::new(a).map_err(|e| anyhow!("{e}"))?)
        }
        other => {
            let e: Estimator = other.parse().map_err(|e: String| anyhow!("{e}"))?;
            let medium = e
                .cpu_medium(inst, super::LOOKUP)
                .map_err(|e| anyhow!("{e}"))?;
            if e.needs_pins() {
                bail!("estimator {other}: not over a density");
            }
            medium.primary
        }
    })
}

/// The media of a scene rendered with estimator `name` (PinMS: ratio tracking primary, pins
/// secondary).
pub fn media(es: &EvalScene, name: &str) -> Result<Vec<Medium>> {
    es.instances
        .iter()
        .map(|inst| {
            Ok(match name {
                "pinms" | "pinms+cache" => Medium::new(
                    estimator(inst, None, "ratio")?,
                    estimator(inst, None, "pins")?,
                ),
                other => match other.parse::<Estimator>() {
                    // Estimators that read the density and the pins together.
                    Ok(e @ (Estimator::PinUrm { .. } | Estimator::Core(EstimatorSpec::PinRes))) => {
                        e.cpu_medium(inst, super::LOOKUP)
                            .map_err(|e| anyhow!("{other}: {e}"))?
                    }
                    _ => Medium::single(estimator(inst, es.closed_form.as_ref(), other)?),
                },
            })
        })
        .collect()
}

/// The 3x4 row-major world placement of an instance: the grid's own placement moved by
/// `offset`.
pub fn translated(local_to_world: &[f64; 12], offset: [f64; 3]) -> [f64; 12] {
    let mut m = *local_to_world;
    m[3] += offset[0];
    m[7] += offset[1];
    m[11] += offset[2];
    m
}

/// The scene's media for the GPU renderer's estimators `ests`, from the same descriptions as
/// the CPU's: the baked pin grid (if any) and the density, placed per instance exactly as
/// the CPU estimators place them, with the CPU's majorant grids and residual controls;
/// `lookup` is the pins' lookup jitter.
pub fn gpu_media<'a>(
    es: &'a EvalScene,
    ests: &[GpuEstimator],
    lookup: SamplerOptions,
) -> Result<GpuMedia<'a>> {
    pinrender::medium::gpu_media_for(&es.instances, ests, lookup).map_err(|e| anyhow!("{e}"))
}
