//! What the viewer renders: a pin file alone, a volume (tracked at once, its pins baked in
//! the background), or a scene file's instances, as the media `pinrender render` builds from
//! the same flags, so that the viewer's passes and a batch render of the same view hold the
//! same bits.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::{Result, anyhow, bail};

use pin_volume::files::MemoryBudget;
use pinrender::front::{self, Holds, RenderFlags};
use pinrender::gpu_render::{GpuDensity, GpuMedia};
use pinrender::medium::MediumDesc;
use pinrender::render::{ESTIMATORS, EstimatorSpec};
use pinrender::scene_media;
use pinrender::volume::{OpenedMedium, VolumeArgs};
use pinrt::SamplerOptions;

/// Majorant bricks per axis: `pinrender render`'s default.
pub const MAJORANT_BRICKS: u32 = 16;

/// One frame's medium, with what the estimators can read.
pub struct Medium {
    pub path: PathBuf,
    /// World box of the medium (the camera frames it).
    pub bounds: ([f64; 3], [f64; 3]),
    /// A volume (`--volume`), as opposed to a pin file alone.
    pub is_volume: bool,
    /// What `pinrender render` opens from the same file (`pinrender::volume::OpenedMedium`).
    opened: OpenedMedium,
    /// The GPU copy of the density, made on first use by whichever renderer is built first
    /// (on a worker thread) and shared by the estimators.
    gpu_density: GpuDensityCache,
    /// A scene file: the scene and its opened assets (`pinrender render --scene --backend
    /// gpu`'s own, from [`pinrender::scene_media`]).
    scene: Option<Arc<SceneMedia>>,
    /// The words of the flags a volume was opened with (`pinrender render`'s read flags and
    /// `--pin-cells`), from the flags themselves: the command line repeats them.
    open_flags: Vec<String>,
    /// The bytes the file's read is charged to `--max-memory`
    /// ([`pinrender::front::open::read_charge`]): what the images may not take.
    pub read_bytes: u64,
}

/// A scene file opened: its assets once, and the instances' GPU media made from them.
pub struct SceneMedia {
    pub scene: pin_scene::Scene,
    assets: Vec<Option<Arc<scene_media::OpenedAsset>>>,
    options: scene_media::AssetOptions,
    /// The estimators every used asset answers, in menu order.
    estimators: Vec<EstimatorSpec>,
    /// The instances without the densities' GPU copies (what the pins estimator reads).
    pins_descs: Vec<MediumDesc>,
    /// The instances with the densities' GPU copies, made once by the first build of an
    /// estimator that reads the density (the lock held meanwhile, as for one medium).
    density_descs: Mutex<Option<Vec<MediumDesc>>>,
}

impl SceneMedia {
    /// The instances' descriptions for `estimator` on a device with `limits`.
    fn descs(&self, estimator: EstimatorSpec, limits: &wgpu::Limits) -> Result<Vec<MediumDesc>> {
        if !estimator.needs_density() {
            return Ok(self.pins_descs.clone());
        }
        let mut slot = self
            .density_descs
            .lock()
            .map_err(|_| anyhow!("the scene's GPU densities were poisoned"))?;
        if slot.is_none() {
            let o = scene_media::AssetOptions {
                estimator: EstimatorSpec::RatioTracking,
                ..self.options
            };
            *slot = Some(scene_media::gpu_descs(&self.scene, &self.assets, &o, limits)?.0);
        }
        Ok(slot.clone().unwrap_or_default())
    }
}

/// The density's GPU copy, made once by the first build that needs it: the lock is held
/// while it is made, so a second build (the reference's, the other side's) waits and shares it.
type GpuDensityCache = Arc<Mutex<Option<Arc<GpuDensity>>>>;

/// What a renderer of one estimator reads of a medium, taken on the window's thread and
/// turned into media on a worker ([`MediaJob::descs`]): the medium's shared parts, no copy.
#[derive(Clone)]
pub struct MediaJob {
    pub path: PathBuf,
    pub estimator: EstimatorSpec,
    source: MediaSource,
}

#[derive(Clone)]
enum MediaSource {
    One(OpenedMedium, GpuDensityCache),
    Scene(Arc<SceneMedia>),
}

impl MediaJob {
    /// The media descriptions, as `pinrender render` makes them, for a device with `limits`
    /// (the GPU copy of the density, made here the first time, only where the estimator
    /// reads it): one medium, or a scene's instances.
    pub fn descs(&self, limits: &wgpu::Limits) -> Result<Vec<MediumDesc>> {
        match &self.source {
            MediaSource::Scene(scene) => scene.descs(self.estimator, limits),
            MediaSource::One(m, cache) => {
                let gpu = if self.estimator.needs_density() {
                    let mut slot = cache
                        .lock()
                        .map_err(|_| anyhow!("the density's GPU copy was poisoned"))?;
                    if slot.is_none() {
                        let copy = m
                            .gpu_density(limits)
                            .map_err(|e| anyhow!("{}: {e}", self.path.display()))?;
                        *slot = Some(Arc::new(copy));
                    }
                    slot.clone()
                } else {
                    None
                };
                Ok(vec![m.desc(MAJORANT_BRICKS, gpu)])
            }
        }
    }
}

impl Medium {
    /// A pin file alone (mapped, O(1); the density sections are read when an estimator
    /// asks), or a volume (tracked at once, without pins until [`Medium::set_pins`]; the bake
    /// the viewer starts in the background is planned and charged to `budget` here), opened
    /// as `pinrender render` opens it ([`pinrender::front::open_medium`]) within `budget`.
    pub fn open(
        path: &Path,
        read: &pinbake::cli_args::SourceArgs,
        flags: &RenderFlags,
        budget: &MemoryBudget,
    ) -> Result<Self> {
        let is_volume = !is_pin_file(path);
        let input = front::Input {
            volume: is_volume.then_some(path),
            read,
            pins: (!is_volume).then_some(path),
            wanted: if is_volume {
                front::PinsWanted::Later
            } else {
                front::PinsWanted::No
            },
            allow_mismatched_pins: false,
            gpu: None,
        };
        let opened = front::open_medium(&input, flags, budget)?;
        let mut medium = Self::new(path, opened, is_volume, None);
        medium.read_bytes = front::open::read_charge(&input);
        if is_volume {
            medium.open_flags = read.to_args();
            if let Some(n) = flags.pin_cells {
                medium
                    .open_flags
                    .extend(["--pin-cells".to_string(), n.to_string()]);
            }
        }
        Ok(medium)
    }

    fn new(
        path: &Path,
        opened: OpenedMedium,
        is_volume: bool,
        scene: Option<Arc<SceneMedia>>,
    ) -> Self {
        Self {
            path: path.to_path_buf(),
            bounds: opened.bounds,
            is_volume,
            opened,
            gpu_density: Arc::default(),
            scene,
            open_flags: Vec::new(),
            read_bytes: 0,
        }
    }

    /// A scene file's instances, opened as `pinrender render --scene --backend gpu` opens
    /// them for `estimator` (`pinrender`'s default for the scene when `None`; each asset
    /// once; a volume without pins baked in memory with `seed` where `estimator` reads pins),
    /// within `budget` as `pinrender render --max-memory` bounds it, with the pins every
    /// asset names loaded too, so that the menu offers every estimator the assets answer;
    /// with its messages.
    pub fn open_scene(
        path: &Path,
        estimator: Option<EstimatorSpec>,
        seed: u64,
        budget: &MemoryBudget,
    ) -> Result<Self> {
        let scene = scene_media::load_scene(path, budget)?;
        let estimator = estimator.unwrap_or_else(|| scene_media::default_estimator(&scene));
        let options = scene_media::AssetOptions {
            estimator,
            pin_cells: None,
            seed,
            majorant_bricks: MAJORANT_BRICKS,
            budget: *budget,
            allow_mismatched_pins: false,
            lookup: SamplerOptions::RENDER,
            named_pins: true,
        };
        let assets = scene_media::open_assets(&scene, &options)?;
        let pins_only = scene_media::AssetOptions {
            estimator: EstimatorSpec::Pins,
            ..options
        };
        let holds = Holds::all(assets.iter().flatten().map(|a| holds_of(&a.medium)));
        let estimators = front::available(holds, ESTIMATORS);
        let pins = holds.pins;
        let (pins_descs, bounds) = if pins {
            scene_media::gpu_descs(&scene, &assets, &pins_only, &wgpu::Limits::default())?
        } else {
            (Vec::new(), scene_bounds(&scene, &assets))
        };
        let none = OpenedMedium {
            bounds,
            field: None,
            majorants: None,
            pins: None,
            opened: None,
            voxels: None,
            bricks: None,
        };
        let media = SceneMedia {
            scene,
            assets,
            options,
            estimators,
            pins_descs,
            density_descs: Mutex::new(None),
        };
        Ok(Self::new(path, none, false, Some(Arc::new(media))))
    }

    /// The scene, where this is a scene file.
    pub fn scene(&self) -> Option<&pin_scene::Scene> {
        self.scene.as_ref().map(|s| &s.scene)
    }

    /// The world boxes of what is rendered: each instance's placed asset box (a scene), or
    /// the medium's box.
    pub fn instance_boxes(&self) -> Vec<([f64; 3], [f64; 3])> {
        let Some(s) = &self.scene else {
            return vec![self.bounds];
        };
        s.scene
            .instances
            .iter()
            .filter_map(|inst| {
                let a = s.assets.get(inst.asset as usize)?.as_ref()?;
                Some(pinrender::instance::world_box(
                    &inst.local_to_world,
                    a.bounds,
                ))
            })
            .collect()
    }

    /// The pin files the render reads, each once: a pin file's own, or the pin files a
    /// scene's assets name (not pins baked in memory, which have no file).
    pub fn pin_files(&self) -> Vec<Arc<pinrt::PinGrid>> {
        let Some(s) = &self.scene else {
            return if self.is_volume {
                Vec::new()
            } else {
                self.pins().cloned().into_iter().collect()
            };
        };
        let mut files: Vec<Arc<pinrt::PinGrid>> = Vec::new();
        for a in s.assets.iter().flatten() {
            if let Some(g) = &a.medium.pins
                && g.path().is_some()
                && !files.iter().any(|f| f.path() == g.path())
            {
                files.push(g.clone());
            }
        }
        files
    }

    /// The flags `pinrender render` needs to open this file as it was opened here, as words.
    pub fn open_flags(&self) -> &[String] {
        &self.open_flags
    }

    /// The flag of `pinrender render` that names this file.
    pub fn input_flag(&self) -> &'static str {
        match (&self.scene, self.is_volume) {
            (Some(_), _) => "--scene",
            (None, true) => "--volume",
            (None, false) => "--pins",
        }
    }

    /// The medium's density field as the renderer reads it (a volume, or a pin file's
    /// embedded density); `None` for a scene or pins alone.
    pub fn field(&self) -> Option<&Arc<dyn pin_volume::Density>> {
        self.opened.field.as_ref()
    }

    /// The camera `(origin, target)` the view resets to: the scene's where it sets one, else
    /// in front of the world box.
    pub fn home(&self) -> ([f64; 3], [f64; 3]) {
        scene_media::camera_over(None, None, self.scene(), self.bounds)
    }

    /// Pins baked for this volume (in the background).
    pub fn set_pins(&mut self, grid: Arc<pinrt::PinGrid>) {
        self.opened.pins = Some(grid);
    }

    /// The pins, where the file holds them or the bake has made them.
    pub fn pins(&self) -> Option<&Arc<pinrt::PinGrid>> {
        self.opened.pins.as_ref()
    }

    /// Whether a density is at hand (a scene: every asset it uses has one).
    pub fn has_density(&self) -> bool {
        match &self.scene {
            Some(s) => s.estimators.iter().any(|e| e.needs_density()),
            None => self.opened.field.is_some(),
        }
    }

    /// The estimators this medium answers now (a scene: those every asset it uses answers):
    /// the renderer's one rule ([`pinrender::front::available`]) over its catalogue.
    pub fn estimators(&self) -> Vec<EstimatorSpec> {
        if let Some(s) = &self.scene {
            return s.estimators.clone();
        }
        front::available(holds_of(&self.opened), ESTIMATORS)
    }

    /// The estimator when none is asked for: `pinrender render`'s default rule for what the
    /// medium holds now ([`pinrender::front::default_estimator`]: ratio tracking for a pin
    /// file that embeds its density, pinms for a volume with its pins, pins with pins alone,
    /// ratio for a volume without pins).
    pub fn default_estimator(&self) -> EstimatorSpec {
        if let Some(s) = &self.scene {
            return s.options.estimator;
        }
        front::default_estimator(holds_of(&self.opened), ESTIMATORS)
    }

    /// What a renderer of `estimator` reads of this medium, refused here (on the window's
    /// thread) where the medium cannot answer it: one medium, or a scene's instances.
    pub fn media_job(&self, estimator: EstimatorSpec) -> Result<MediaJob> {
        let source = match &self.scene {
            Some(s) if !s.estimators.contains(&estimator) => bail!(
                "{}: {estimator} reads {}, which some asset of the scene lacks",
                self.path.display(),
                if estimator.needs_density() {
                    "the density"
                } else if estimator == EstimatorSpec::PinRes {
                    "the pins' control section"
                } else {
                    "pins"
                }
            ),
            Some(s) => MediaSource::Scene(s.clone()),
            None => {
                if estimator.needs_pins() && self.pins().is_none() {
                    bail!(
                        "{}: the {estimator} estimator needs pins, which are not baked yet",
                        self.path.display()
                    );
                }
                if estimator.needs_density() && !self.has_density() {
                    bail!(
                        "{}: no embedded density, which the {estimator} estimator needs (bake \
                         with `pinbake bake --embed-density N`, or open the volume)",
                        self.path.display()
                    );
                }
                MediaSource::One(self.opened.clone(), self.gpu_density.clone())
            }
        };
        Ok(MediaJob {
            path: self.path.clone(),
            estimator,
            source,
        })
    }
}

/// The GPU media of `descs` for `estimator`, as `pinrender render --backend gpu` packs them.
pub fn gpu_media(descs: &[MediumDesc], estimator: EstimatorSpec) -> Result<GpuMedia<'_>> {
    pinrender::medium::gpu_media(descs, Some(estimator), SamplerOptions::RENDER)
        .map_err(|e| anyhow!("{e}"))
}

/// A bake of a volume's pins on a worker thread, as `pinrender render` bakes without `--pins`
/// (cells, directions and pins chosen from the volume by `pinbake::plan`), with the control
/// section so that pinres can run too. `T` is what the thread hands back: the pins, or (for a
/// re-bake at another density scale) the whole re-opened medium with its pins.
pub struct BakeJob<T = pinrt::PinGrid> {
    pub done: Arc<AtomicU64>,
    /// Pins to bake (0 until the worker has planned the bake).
    pub total: Arc<AtomicU64>,
    cancel: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<Result<T>>>,
}

/// Counters the worker shares with the window.
#[derive(Clone)]
struct Shared {
    done: Arc<AtomicU64>,
    total: Arc<AtomicU64>,
    cancel: Arc<AtomicBool>,
}

/// What the viewer asks of a volume's bake: the seed, and the cells per axis where given
/// (else `pinbake bake`'s choice for the volume), as `pinrender render` asks.
#[derive(Clone, Copy, Debug)]
pub struct PreviewBake {
    pub seed: u64,
    pub cells: Option<u32>,
    /// The command's memory budget (`--max-memory`), which the bake is planned within.
    pub budget: MemoryBudget,
}

/// Plans and bakes `source`'s pins on `backend`, reporting to `shared`.
fn bake_pins(
    source: &dyn pin_volume::DensitySource,
    bake: PreviewBake,
    backend: pinbake::BakeBackend,
    shared: &Shared,
) -> Result<pinrt::PinGrid> {
    // The bake `pinrender render` makes in memory, with the control section for pinres.
    let mut opts = pinrender::volume::in_memory_bake_options(
        source,
        bake.cells,
        bake.seed,
        true,
        &bake.budget,
    )?;
    opts.cancel = Some(shared.cancel.clone());
    shared
        .total
        .store(pinbake::bake::pin_count(&opts).max(1), Ordering::Relaxed);
    let counter = shared.done.clone();
    let progress = move |n: u64| {
        counter.fetch_add(n, Ordering::Relaxed);
    };
    let (grid, _) = pinbake::bake_on(source, &opts, backend, &progress)?;
    pinrt::PinGrid::from_bytes(grid.to_bytes()?).map_err(|e| anyhow!("{e}"))
}

impl<T: Send + 'static> BakeJob<T> {
    fn spawn(work: impl FnOnce(&Shared) -> Result<T> + Send + 'static) -> Result<Self> {
        let shared = Shared {
            done: Arc::new(AtomicU64::new(0)),
            total: Arc::new(AtomicU64::new(0)),
            cancel: Arc::new(AtomicBool::new(false)),
        };
        let worker = shared.clone();
        let handle = std::thread::Builder::new()
            .name("pinview bake".into())
            .spawn(move || work(&worker))?;
        Ok(Self {
            done: shared.done,
            total: shared.total,
            cancel: shared.cancel,
            handle: Some(handle),
        })
    }

    /// Fraction of the pins baked (0 while the worker plans).
    pub fn progress(&self) -> f32 {
        let total = self.total.load(Ordering::Relaxed);
        if total == 0 {
            return 0.0;
        }
        (self.done.load(Ordering::Relaxed) as f64 / total as f64).min(1.0) as f32
    }

    /// The result when the worker has finished (then `Some` once).
    pub fn finished(&mut self) -> Option<Result<T>> {
        if self.handle.as_ref().is_some_and(|h| h.is_finished()) {
            let h = self.handle.take()?;
            return Some(
                h.join()
                    .unwrap_or_else(|_| Err(anyhow!("the bake panicked"))),
            );
        }
        None
    }
}

impl BakeJob {
    /// The pins of an opened volume, baked on the CPU as `pinrender render` bakes them.
    pub fn start(medium: &Medium, bake: PreviewBake) -> Result<Self> {
        let Some((_, field)) = &medium.opened.opened else {
            bail!("only a volume is baked");
        };
        let source = field.source().clone();
        Self::spawn(move |shared| {
            bake_pins(source.as_ref(), bake, pinbake::BakeBackend::Cpu, shared)
        })
    }
}

/// A volume read again at another density scale, with its pins, and where they were baked.
pub struct Rebaked {
    pub medium: Medium,
    /// `gpu`, or `cpu` where the GPU bake refused the source (`gpu_refused` says why: it
    /// marches a dense grid, which a procedural field or a too large volume does not have).
    pub backend: &'static str,
    pub gpu_refused: Option<String>,
}

impl BakeJob<Rebaked> {
    /// The volume at `path` opened again with `read` (another density scale), its pins
    /// baked on the GPU (`pinbake::bake_on`, on a device of its own; on the CPU where the
    /// GPU bake refuses the source): a medium to replace the shown one when it is ready.
    pub fn rebake(path: PathBuf, read: VolumeArgs, bake: PreviewBake) -> Result<Self> {
        Self::spawn(move |shared| {
            let flags = RenderFlags {
                seed: bake.seed,
                pin_cells: bake.cells,
                ..RenderFlags::default()
            };
            let mut medium = Medium::open(&path, &read.read, &flags, &bake.budget)?;
            let Some((_, field)) = &medium.opened.opened else {
                bail!("only a volume is baked");
            };
            let source = field.source().clone();
            let gpu = pinbake::BakeBackend::Gpu(Default::default());
            let (grid, backend, gpu_refused) = match bake_pins(source.as_ref(), bake, gpu, shared) {
                Ok(g) => (g, "gpu", None),
                Err(e) if !shared.cancel.load(Ordering::Relaxed) => {
                    shared.done.store(0, Ordering::Relaxed);
                    let cpu = pinbake::BakeBackend::Cpu;
                    (
                        bake_pins(source.as_ref(), bake, cpu, shared)?,
                        "cpu",
                        Some(e.to_string()),
                    )
                }
                Err(e) => return Err(e),
            };
            medium.set_pins(Arc::new(grid));
            Ok(Rebaked {
                medium,
                backend,
                gpu_refused,
            })
        })
    }
}

impl<T> Drop for BakeJob<T> {
    fn drop(&mut self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// The world box of a scene's instances (the box of their placed assets' boxes).
fn scene_bounds(
    scene: &pin_scene::Scene,
    assets: &[Option<Arc<scene_media::OpenedAsset>>],
) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for inst in &scene.instances {
        if let Some(a) = &assets[inst.asset as usize] {
            let (l, h) = pinrender::instance::world_box(&inst.local_to_world, a.bounds);
            for k in 0..3 {
                lo[k] = lo[k].min(l[k]);
                hi[k] = hi[k].max(h[k]);
            }
        }
    }
    (lo, hi)
}

/// Whether `path` names a scene file (`.json`; `docs/scene.md`).
pub fn is_scene_file(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

/// Whether `path` names a pin file (by its extension; anything else is read as a volume).
pub fn is_pin_file(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("pin"))
}

/// What an opened medium holds for the estimator rule: its pins (a pin file's, or a volume's
/// once baked), its density, and the pins' control section.
fn holds_of(m: &OpenedMedium) -> Holds {
    Holds {
        pins: m.pins.is_some(),
        density: m.field.is_some(),
        volume: m.opened.is_some(),
        control: m
            .pins
            .as_ref()
            .and_then(|p| p.file().ok().map(|f| f.control().is_some()))
            .unwrap_or(false),
    }
}

/// The first look's line for the window's notes: the scale chosen and how to see the file's
/// own.
pub fn first_look_note(look: &pinrender::front::first_look::FirstLook) -> String {
    format!(
        "density scale {}: the volume's first look (a median optical depth of {:.3} along the \
         view at scale 1, {:.2} at this one); --density-scale 1 shows the file's own",
        look.scale,
        look.median_depth,
        look.median_depth * look.scale
    )
}

/// The JSON's `first_look`: the scale chosen and the median depth it came from (null where
/// `--density-scale` was given, or the input is no single volume).
pub fn first_look_json(look: Option<pinrender::front::first_look::FirstLook>) -> serde_json::Value {
    look.map_or(
        serde_json::Value::Null,
        |l| serde_json::json!({"scale": l.scale, "median_depth": l.median_depth}),
    )
}
