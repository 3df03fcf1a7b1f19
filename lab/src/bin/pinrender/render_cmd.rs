//! `pinrender render`: one image of one volume with a chosen estimator.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Result, anyhow, bail};
use clap::Args;
use std::time::Instant;

use pinlab::Estimator;
use pinrender::gpu_render::{GpuRenderer, GpuScene};
use pinrender::render::{
    Budget, DEFAULT_WAVEFRONT_BATCH, Image, RenderSettings, SampleLoop, Scene, block_bias, render,
    render_wavefront, rmse,
};
use pinrt::SamplerOptions;
use pinrt::gpu::GpuContext;

use crate::volume::{OpenedMedium, VolumeArgs};
use pinrender::front::{self, RenderFlags};
use pinrender::medium::MediumDesc;

#[derive(Args, Debug)]
#[command(after_help = "\
Conventions: right-handed world, y up. --fov is the vertical field of view in degrees. --sun-dir
points from the scene towards the sun; the sun is a delta directional light of radiance
--sun-radiance, the environment a constant radiance --env-radiance over the whole sphere. The
medium has no refractive boundary; scattering = albedo x extinction, Henyey-Greenstein phase
with parameter --g. --max-bounces counts scattering events. A raw volume of dims N with
--spacing s --origin o occupies [o, o + N*s], voxel centres at o + (i + 0.5)*s, trilinear
between centres (Mitsuba's grid-volume convention); a VDB follows its own index-to-world
transform with voxel centres at integer index coordinates.

Estimators:
  rm@STEP     ray marching at a relative step (fraction of the longest box edge), e.g. rm@0.015
  delta       delta tracking (distances) + delta tracking (transmittance) over a majorant grid
  ratio       delta tracking (distances) + ratio tracking (transmittance) over a majorant grid
  urm[@N]     delta tracking (distances) + unbiased ray marching (transmittance, Kettunen et al.
              2021): combs of N lookups per longest box edge (default 16), power-series roulette
  jackknife[@N] delta tracking (distances) + jackknife transmittance (Peters 2025): two combs of
              N lookups per longest box edge (default 32); slightly biased
  pins        pins for every ray (uses --pins FILE, or bakes the volume in memory)
  pinms       pins for multiple scattering only; ratio tracking for primary rays and single scattering
  pinurm[@N]  delta tracking (distances) + unbiased ray marching around the pins' answer
              (transmittance): the pins' optical depth is the control, combs of N lookups per
              longest box edge (default 8) correct it; unbiased, CPU only
  pinres      delta tracking (distances) + residual ratio tracking (transmittance) over the
              control the bake stores per brick (`pinbake bake --embed-control`; bakes the
              volume in memory with it unless --pins); unbiased

--backend gpu renders with the WGSL path tracer (wgpu; every estimator above but pinurm) instead of the CPU
one: the same estimator over a GPU copy of the density (a raw grid as is, a VDB as the dense grid
of its active box, a pin file's sparse density densely (the section the CPU reads: the sparse one
of a file that has both), each as the bricks the CPU trackers read
when the dense copy would exceed 2^28 voxels or one storage binding, cosine noise as its waves, a
box as one voxel; the procedural sphere has no GPU form). Its random streams differ from the CPU's, so the two images agree in expectation, not bit
for bit.")]
pub struct RenderArgs {
    #[command(flatten)]
    pub volume: VolumeArgs,
    /// A scene file of instanced volumes (docs/scene.md), instead of --volume and --pins. Its
    /// camera, sun, sky, albedo, g and bounces apply unless a flag gives them.
    #[arg(long, conflicts_with = "pins")]
    pub scene: Option<PathBuf>,
    /// Pin file for the `pins`, `pinms`, `pinurm` and `pinres` estimators (default: bake the
    /// volume in memory).
    /// Without --volume, the medium itself: the estimators that need density use the file's
    /// embedded density (`pinbake bake --embed-density`) and majorant sections; a file with
    /// both a sparse and a dense density renders the sparse one, on either backend. Each
    /// section is checked against its checksum as it is read.
    #[arg(long)]
    pub pins: Option<PathBuf>,
    /// Render with --pins even when the pin file records a different source than --volume
    /// (another volume, density scale, transform or box).
    #[arg(long)]
    pub allow_mismatched_pins: bool,
    /// rm@STEP (STEP in [1e-5, 1]), delta, ratio, residual[@min|@mean], urm[@N], jackknife[@N],
    /// pins, pinms, pinurm[@N] or pinres. Default: follows the input. With --volume and
    /// --pins, pinms; with a pin file alone, ratio when it embeds a density (what a bake with
    /// no flags writes) and pins when it holds nothing else; with --volume alone, ratio.
    #[arg(long, value_parser = parse_estimator)]
    pub estimator: Option<Estimator>,
    /// Image width in pixels (1..=16384).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub width: u32,
    /// Image height in pixels (1..=16384).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub height: u32,
    /// Samples per pixel (ignored when --seconds is given).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..))]
    pub spp: u32,
    /// Render for this many seconds instead of a fixed --spp (at most 1e5).
    #[arg(long, value_parser = front::flags::parse_seconds)]
    pub seconds: Option<f64>,
    /// The camera, the lighting and the material, the seed, an in-memory bake's cells, the
    /// memory budget and the exposure: the flags the viewer shares.
    #[command(flatten)]
    pub flags: RenderFlags,
    /// Majorant bricks per axis for the trackers (1..=1024).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub majorant_bricks: u32,
    /// Worker threads (default: all cores; at most 64 per core and 4096).
    #[arg(long, value_parser = pinbake::cli_args::parse_threads)]
    pub threads: Option<usize>,
    /// Output image: FILE.exr (linear float RGB) with a tone-mapped FILE.png beside it, or
    /// FILE.png alone. A new path or a regular file other than the inputs.
    #[arg(long)]
    pub out: PathBuf,
    /// cpu (rayon path tracer) or gpu (the WGSL path tracer through wgpu).
    #[arg(long, default_value = "cpu", value_parser = ["cpu", "gpu"])]
    pub backend: String,
    /// Pins: the lookup point moves by up to half this many spatial cells per axis (0: off).
    #[arg(long, default_value_t = DEFAULT_LOOKUP.spatial_jitter, value_parser = front::flags::parse_jitter)]
    pub spatial_jitter: f32,
    /// Pins: the direction moves by up to half this many direction cells per axis (0: off).
    #[arg(long, default_value_t = DEFAULT_LOOKUP.directional_jitter, value_parser = front::flags::parse_jitter)]
    pub directional_jitter: f32,
    /// Pins: intervals of the ray's chord per lookup (1..=32; 32 = one lookup, the thesis'
    /// model). Smaller strides follow the ray with more lookups (docs/sampling.md section 12).
    #[arg(long, default_value_t = DEFAULT_LOOKUP.chain_stride, value_parser = clap::value_parser!(u32).range(1..=32))]
    pub chain_stride: u32,
    /// Pins: where each lookup reads its cell: `start` or `middle` of its piece of the ray.
    #[arg(long, default_value = if DEFAULT_LOOKUP.midpoint_lookup { "middle" } else { "start" }, value_parser = ["start", "middle"])]
    pub lookup_point: String,
    /// Pins: look a ray that starts inside the volume's box (a shadow or scattered ray from a
    /// collision) up at its start and without spatial jitter, whatever --lookup-point says
    /// (docs/sampling.md section 14): `true` or `false`.
    #[arg(long, default_value_t = DEFAULT_LOOKUP.start_inside, action = clap::ArgAction::Set)]
    pub start_inside: bool,
    /// Pins: read the cell whose pin line passes nearest the lookup point, searching this many
    /// one-cell steps each side along the direction's axis, instead of the cell that holds
    /// the point; replaces the spatial jitter (docs/sampling.md section 15). 0: off; 0..=64.
    #[arg(long, default_value_t = DEFAULT_LOOKUP.nearest_line, value_parser = clap::value_parser!(u32).range(0..=64))]
    pub nearest_line: u32,
    /// Compare with this converged image (EXR of the same size) and print one line on stdout:
    /// `mean_error M block8_rms_error B spp N seconds S rmse R` (M and B relative, see
    /// `docs/evaluation.md`; R the per-pixel RMSE in radiance, as `pinrender eval` reports).
    #[arg(long)]
    pub reference: Option<PathBuf>,
}

/// The lookup options `pinrender render` (and `pinrender eval`'s pins) use unless told
/// otherwise: the library's [`SamplerOptions::RENDER`] (its documentation says why each).
pub const DEFAULT_LOOKUP: SamplerOptions = SamplerOptions::RENDER;

impl RenderArgs {
    pub(crate) fn lookup(&self) -> SamplerOptions {
        SamplerOptions {
            spatial_jitter: self.spatial_jitter,
            directional_jitter: self.directional_jitter,
            chain_stride: self.chain_stride,
            midpoint_lookup: self.lookup_point == "middle",
            start_inside: self.start_inside,
            nearest_line: self.nearest_line,
        }
    }
}

/// `--estimator`: [`Estimator`]'s names.
fn parse_estimator(s: &str) -> Result<Estimator, String> {
    s.parse()
}

/// What a render resolves once from its flags and input, before anything is opened: the
/// estimator and the look (the one memory budget is `RenderFlags::budget`'s, made once in
/// `run`). The flags stay as parsed.
pub(crate) struct Job {
    pub estimator: Estimator,
    pub look: Look,
}

impl Job {
    /// Refuses bounces beyond the GPU's limit for a GPU render, naming where they came from.
    fn check_gpu_bounces(&self, a: &RenderArgs) -> Result<()> {
        let max_gpu = pinrender::gpu_render::MAX_GPU_BOUNCES;
        if a.backend == "gpu" && self.look.max_bounces > max_gpu {
            crate::usage!(
                "--max-bounces {} exceeds the GPU limit of {max_gpu} (--backend gpu)",
                self.look.max_bounces
            );
        }
        Ok(())
    }
}

/// Where the images go: `(exr, png)`; `FILE.png` writes the PNG only. Both follow the
/// output rule (`pin_volume::files::check_outputs`): a new path or a regular file, none of the
/// inputs (the reference included), not the same file twice.
pub(crate) fn outputs(a: &RenderArgs, inputs: &[&Path]) -> Result<(Option<PathBuf>, PathBuf)> {
    let is_png = a
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let mut inputs = inputs.to_vec();
    inputs.extend(a.reference.as_deref());
    if is_png {
        return Ok((None, pin_volume::files::check_output(&a.out, &inputs)?));
    }
    let png = a.out.with_extension("png");
    let mut both = pin_volume::files::check_outputs(&[&a.out, &png], &inputs)?.into_iter();
    // The image is written as what its name says: an EXR named `x.txt` (or `x`) was.
    if !a
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
    {
        crate::usage!(
            "--out {} must end in .exr (with a .png beside it) or .png",
            pin_format::input::quoted(&a.out)
        );
    }
    Ok((both.next(), both.next().unwrap_or(png)))
}

/// The reference image (`--reference`), read before the render: a bad path, a file that is
/// not regular or an image of another size fails before anything is rendered or written.
pub(crate) fn read_reference(a: &RenderArgs) -> Result<Option<Image>> {
    a.reference
        .as_ref()
        .map(|r| {
            Image::read_exr_of_size(r, Some((a.width, a.height)))
                .map_err(|e| anyhow!("{}: {e}", r.display()))
        })
        .transpose()
}

pub use pinrender::scene_media::Look;

/// `pinrender render` without `--scene` (`main.rs` sends a scene file to `scene_cmd::run`).
pub fn run(a: RenderArgs) -> Result<()> {
    let budget = a.flags.budget();
    let estimator = match a.estimator {
        Some(e) => e,
        None => {
            let holds = front::holds(a.volume.volume.as_deref(), a.pins.as_deref())?;
            front::default_estimator(holds, pinrender::render::ESTIMATORS).into()
        }
    };
    let job = Job {
        estimator,
        look: a.flags.look(None),
    };
    // What to load, which loop runs and what memory it holds: decided here, once.
    let plan = job.estimator.plan();
    let uses_pins = plan.reads_bake;
    let input = match (&a.volume.volume, &a.pins) {
        (None, None) => crate::usage!(
            "--volume is required (or --pins FILE alone, to render a pin file's own medium)"
        ),
        (Some(_), Some(_)) if !uses_pins => {
            // It used to be ignored silently, so a typo in the estimator went unnoticed.
            crate::usage!(
                "--pins is used only by the pins, pinms, pinurm and pinres estimators, not by {} (or give \
                 --pins without --volume to render the pin file's own medium)",
                job.estimator
            )
        }
        (None, Some(pins)) => {
            if let Some(flag) = a.volume.read.given().first() {
                crate::usage!("{flag} applies to --volume, which is not given");
            }
            pins.clone()
        }
        (Some(v), _) => v.clone(),
    };
    job.check_gpu_bounces(&a)?;
    let inputs: Vec<&Path> = [a.volume.volume.as_deref(), a.pins.as_deref()]
        .into_iter()
        .flatten()
        .collect();
    // Before the render, not after it.
    outputs(&a, &inputs)?;
    front::flags::check_image(&budget, a.width, a.height)?;
    let per_row = plan.scratch_bytes_per_thread(a.width as usize);
    if per_row > 0 {
        // The wavefront loop's rows in flight, one per worker thread: bounded by a chunk of
        // paths whatever --spp is.
        let threads = a.threads.unwrap_or_else(rayon::current_num_threads) as u64;
        budget.check(
            &format!("{threads} image rows of {} pixels in flight", a.width),
            threads.saturating_mul(per_row),
        )?;
    }
    let wanted = if uses_pins && a.volume.volume.is_some() {
        front::PinsWanted::Now {
            control: plan.control,
        }
    } else {
        front::PinsWanted::No
    };
    let medium_input = front::Input {
        volume: a.volume.volume.as_deref(),
        read: &a.volume.read,
        pins: a.pins.as_deref(),
        wanted,
        allow_mismatched_pins: a.allow_mismatched_pins,
        gpu: None,
    };
    // The read first, then what the render adds to it.
    front::open::check_read(&medium_input, &budget)?;
    if plan.majorants && a.volume.volume.is_some() {
        // f32 values plus the brick bounds the grid keeps, per brick.
        budget.check(
            &format!("{}^3 majorant bricks", a.majorant_bricks),
            u64::from(a.majorant_bricks).pow(3) * 16,
        )?;
    }
    let pin_cells = a.flags.pin_cells;
    if uses_pins && a.pins.is_none() {
        let probe = pinbake::BakeOptions {
            // Before the source is open: the default's upper bound.
            cells: [pin_cells.unwrap_or(pinbake::bake::DEFAULT_MAX_CELLS); 3],
            ..pinbake::BakeOptions::default()
        };
        // The bake, its serialised bytes and the loaded copy.
        budget.check(
            &format!(
                "baking {}^3 pin cells in memory",
                pin_cells.unwrap_or(pinbake::bake::DEFAULT_MAX_CELLS)
            ),
            pinbake::bake::estimate_output_bytes(&probe).saturating_mul(2),
        )?;
    }
    // Read the reference first: a bad path should not cost a whole render.
    let reference = read_reference(&a)?;
    // The GPU first: its storage binding limit decides between a dense and a bricked copy,
    // and a pin file's bricks that no binding layout holds are refused before they are read.
    let ctx = if a.backend == "gpu" {
        Some(GpuContext::new().map_err(|e| anyhow!("{e}"))?)
    } else {
        None
    };
    let medium = front::open_medium(
        &front::Input {
            gpu: ctx
                .as_ref()
                .filter(|_| plan.density && a.volume.volume.is_none())
                .map(|c| &c.limits),
            ..medium_input
        },
        &a.flags,
        &budget,
    )?;
    let (lo, hi) = (
        glam::DVec3::from(medium.bounds.0),
        glam::DVec3::from(medium.bounds.1),
    );
    if plan.density && medium.field.is_none() {
        bail!(
            "{}: no embedded density, which the {} estimator needs (bake with \
             `pinbake bake --embed-density N`, or render with --volume)",
            input.display(),
            job.estimator
        );
    }
    let desc = desc(&medium, &a, &job, ctx.as_ref())?;
    let centre = (lo + hi) * 0.5;
    let size = (hi - lo).length();
    let target = a.flags.camera_target.unwrap_or(centre.to_array());
    let origin = a.flags.camera_origin.unwrap_or([
        centre.x + 0.35 * size,
        centre.y + 0.25 * size,
        centre.z + 1.6 * size,
    ]);
    let scene = job.look.frame((origin, target), a.width, a.height);
    if a.backend == "gpu" {
        let ctx = ctx.as_ref().ok_or_else(|| anyhow!("no GPU context"))?;
        let image = render_gpu(&a, &job, ctx, std::slice::from_ref(&desc), &scene)?;
        return write(
            &a,
            &job,
            &input,
            &image.0,
            image.1,
            image.2,
            reference.as_ref(),
        );
    }
    let medium = job
        .estimator
        .cpu_medium(&desc, a.lookup())
        .map_err(|e| anyhow!("{e}"))?;
    let scene = Scene {
        media: vec![medium],
        ..scene
    };
    let settings = RenderSettings {
        max_bounces: job.look.max_bounces,
        seed: a.flags.seed,
        budget: match a.seconds {
            Some(s) => Budget::Seconds(s),
            None => Budget::Spp(a.spp),
        },
        threads: a.threads,
    };
    // Pin queries answered in batches (wavefront loop): the same image as `render`, sooner.
    // Only `pins` and `pinms` answer in batches; the others (`pinurm`, `pinres`) answer one
    // query at a time, which `render`'s own loop does with less bookkeeping (as in the eval).
    let out = if plan.sample_loop == SampleLoop::Wavefront {
        render_wavefront(&scene, &settings, DEFAULT_WAVEFRONT_BATCH)
    } else {
        render(&scene, &settings)
    }
    .map_err(|e| anyhow!("{e}"))?;
    write(
        &a,
        &job,
        &input,
        &out.image,
        out.spp,
        out.seconds,
        reference.as_ref(),
    )
}

/// The render's medium description: what the CPU estimators and the GPU packing read (the
/// GPU copy of the density only for a GPU render of an estimator that reads it).
fn desc(
    medium: &OpenedMedium,
    a: &RenderArgs,
    job: &Job,
    ctx: Option<&GpuContext>,
) -> Result<MediumDesc> {
    let gpu = match ctx.filter(|_| job.estimator.plan().density) {
        Some(ctx) => Some(Arc::new(medium.gpu_density(&ctx.limits)?)),
        None => None,
    };
    Ok(medium.desc(a.majorant_bricks, gpu))
}

pub(crate) fn write(
    a: &RenderArgs,
    job: &Job,
    input: &Path,
    image: &Image,
    spp: u32,
    seconds: f64,
    reference: Option<&Image>,
) -> Result<()> {
    let inputs: Vec<&Path> = [Some(input), a.pins.as_deref()]
        .into_iter()
        .flatten()
        .collect();
    // Checked again: the paths may have been replaced during the render.
    let (exr, png) = outputs(a, &inputs)?;
    // Compared before anything is written: a failure writes nothing.
    let scores = match reference {
        Some(r) => {
            let path = a.reference.as_deref().unwrap_or(Path::new("reference"));
            let at = |e| anyhow!("{}: {e}", path.display());
            Some((
                block_bias(image, r, 8).map_err(at)?,
                rmse(image, r).map_err(at)?,
            ))
        }
        None => None,
    };
    // The EXR and its PNG land together or not at all (`pin_volume::files::write_together`).
    let encode_err = |e: pinrender::render::RenderError| std::io::Error::other(e.to_string());
    let mut files: Vec<(PathBuf, pin_volume::files::WriteFile<'_>)> = Vec::new();
    if let Some(exr) = &exr {
        files.push((
            exr.clone(),
            Box::new(move |out| image.encode_exr(out).map_err(encode_err)),
        ));
    }
    let exposure = a.flags.exposure;
    files.push((
        png.clone(),
        Box::new(move |out| image.encode_png(out, exposure).map_err(encode_err)),
    ));
    pin_volume::files::write_together(files)?;
    pin_cli::errln!(
        "rendered {} with {} ({}): {}x{} at {} spp in {:.2} s -> {}",
        input.display(),
        job.estimator,
        a.backend,
        a.width,
        a.height,
        spp,
        seconds,
        match exr {
            Some(_) => format!("{} (+ {})", a.out.display(), png.display()),
            None => png.display().to_string(),
        }
    );
    if let Some(((mean, block), rmse)) = scores {
        // stdout, one line, for scripts; the render summary above goes to stderr. New fields
        // go at the end (scripts read the first ones by position).
        pin_cli::outln!(
            "mean_error {:+.4} block8_rms_error {:.4} spp {spp} seconds {seconds:.2} rmse {rmse:.6}",
            mean,
            block
        )?;
    }
    Ok(())
}

/// The same render on the GPU path tracer: returns the image, its spp and the seconds spent
/// rendering (upload and pipeline compile excluded, as the CPU's thread-pool start is).
pub(crate) fn render_gpu(
    a: &RenderArgs,
    job: &Job,
    ctx: &GpuContext,
    descs: &[MediumDesc],
    scene: &Scene,
) -> Result<(Image, u32, f64)> {
    let est = job.estimator.gpu_or_err().map_err(|e| anyhow!("{e}"))?;
    let media =
        pinrender::medium::gpu_media_for(descs, &[est], a.lookup()).map_err(|e| anyhow!("{e}"))?;
    let renderer = GpuRenderer::with_media(ctx, &media).map_err(|e| anyhow!("{e}"))?;
    let gs = GpuScene::from_scene(scene, job.look.max_bounces);
    let start = Instant::now();
    match a.seconds {
        None => {
            let image = renderer
                .render(&gs, est, a.spp, a.flags.seed)
                .map_err(|e| anyhow!("{e}"))?;
            Ok((image, a.spp, start.elapsed().as_secs_f64()))
        }
        Some(limit) => {
            // Passes of 1 spp with distinct seeds until the time is spent (at least one).
            let mut sum: Vec<[f64; 3]> = Vec::new();
            let mut spp = 0u32;
            while spp == 0 || (start.elapsed().as_secs_f64() < limit && spp < u32::MAX) {
                let seed = pinrender::render::splitmix64(a.flags.seed ^ u64::from(spp));
                let img = renderer
                    .render(&gs, est, 1, seed)
                    .map_err(|e| anyhow!("{e}"))?;
                sum.resize(img.rgb.len(), [0.0; 3]);
                for (acc, p) in sum.iter_mut().zip(&img.rgb) {
                    for c in 0..3 {
                        acc[c] += f64::from(p[c]);
                    }
                }
                spp += 1;
            }
            let inv = 1.0 / f64::from(spp);
            let image = Image {
                width: a.width,
                height: a.height,
                rgb: sum.iter().map(|s| s.map(|c| (c * inv) as f32)).collect(),
            };
            Ok((image, spp, start.elapsed().as_secs_f64()))
        }
    }
}
