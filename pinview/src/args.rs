//! The command line: a file, the render flags `pinrender render` flattens too
//! ([`pinrender::front::RenderFlags`]: the same names, ranges and defaults), the image size,
//! and the scripting flags.

use std::path::PathBuf;

use clap::Parser;
use pin_cli::parse::parse_finite;
use pinrender::front::RenderFlags;
use pinrender::render::EstimatorSpec;

#[derive(Parser, Debug, Clone)]
#[command(
    name = "pinview",
    version,
    about = "Look through a bake: an interactive GPU viewer of pin files and volumes.",
    after_help = "\
FILE is a pin file (.pin: shown with ratio tracking of its density where it embeds one, as a
bake with no flags writes, else with pins alone; pinms, pinres, ratio and the other trackers
where it embeds a density or a control), a volume (.vdb, .nvdb, .raw with --dims, or
procedural:SPEC: tracked at once while its pins bake in the background, then every estimator),
a scene file of instanced volumes (.json, docs/scene.md: its camera, sun, sky, albedo, g and
bounces unless a flag gives them; every estimator its assets answer, as `pinrender render
--scene --backend gpu`), or a frame pattern (sim.####.pin or sim.%04d.pin, as `pinbake
--frames` writes them, negative frames too: play, pause, step and scrub). A file dropped
on the window opens in its place. A volume opened without --density-scale opens at the
scale of its first look: the power of two that gives a median optical depth of 8 along the
view (the window's notes and --json's first_look say which; the copied command carries it;
--density-scale 1 shows the file's own values).

Scripting: --frames N renders N one-sample passes in the window, then writes --screenshot
(the render as the window shows it, tone-mapped as `pinrender render` writes its PNG) and
--save (the accumulated linear image as EXR: the same bits as `pinrender render --backend gpu
--spp N` with the same flags and seed), prints one JSON object with --json, and exits 0.
Errors (no display, no adapter, a bad file) are one line on stderr and exit 1 (without
--frames a refused file's line is first shown in a window); usage errors exit 2.

Mouse on the image: drag orbits, right-drag (or shift-drag) pans, the wheel zooms, ctrl-drag
moves the sun. Keys: arrows orbit, +/- zoom, R resets the view, space plays or pauses a
sequence, . and , step it."
)]
pub struct ViewArgs {
    /// A .pin file, a volume (.vdb, .nvdb, .raw, procedural:SPEC), a scene file (.json) or a
    /// frame pattern.
    pub file: PathBuf,
    #[command(flatten)]
    pub read: pinbake::cli_args::SourceArgs,
    /// rm@STEP, delta, ratio, residual[@min|@mean], pins, pinms or pinres (the renderer's
    /// estimators; the lab's urm, jackknife and pinurm are `pinrender render`'s only).
    /// Default: as `pinrender render`: ratio for a pin file that embeds a density, pins for
    /// one without, pinms for a volume once its pins are baked (ratio until then).
    #[arg(long, value_parser = parse_estimator)]
    pub estimator: Option<EstimatorSpec>,
    /// A second estimator beside the first, at equal GPU time (split view). With --frames,
    /// the first renders N passes and the second as many as take the nearest equal time;
    /// the screenshot holds both halves and --json a `compare` object.
    #[arg(long, value_parser = parse_estimator)]
    pub compare: Option<EstimatorSpec>,
    /// The error view: ratio tracking accumulates a reference in the background (where the
    /// file holds a density), |estimate - reference| is shown as a heat map and the RMSE
    /// plotted against time. With --frames the screenshot is the heat map and --json gains
    /// an `error` object.
    #[arg(long)]
    pub error_view: bool,
    /// Show the pins of the entry under image pixel X,Y (from the top-left corner) as if the
    /// cursor stood there; with --json, a `pin` object (cell, direction, t_min and mask of
    /// each pin).
    #[arg(long, value_parser = parse_pixel)]
    pub pin_at: Option<[f64; 2]>,
    /// A volume only: re-bake its pins at this density scale on the GPU as soon as the window
    /// is open, as the density-scale slider does (the volume read again at that scale); a
    /// scripted run renders its --frames passes once the new pins are in.
    #[arg(long, value_parser = pinbake::cli_args::parse_density_scale)]
    pub rebake_scale: Option<pin_volume::DensityScale>,
    /// Draw the box and the cell grid over the image.
    #[arg(long)]
    pub grid_overlay: bool,
    /// Image width in pixels (1..=16384). Either size flag fixes the image's size; without
    /// them the image fills the window's viewport and follows it (512 x 512 off-screen).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub width: Option<u32>,
    /// Image height in pixels (1..=16384).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=16384))]
    pub height: Option<u32>,
    /// The camera, the lighting and the material, the seed, the size of a volume's bake
    /// (`--pin-cells`: refused for a pin file or a scene), the memory budget and the
    /// exposure: `pinrender render`'s flags, with its ranges and defaults.
    #[command(flatten)]
    pub flags: RenderFlags,
    /// Render this many one-sample passes, write the outputs asked for and exit.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: Option<u32>,
    /// With --frames: the window's render as PNG.
    #[arg(long, requires = "frames")]
    pub screenshot: Option<PathBuf>,
    /// With --frames: the accumulated linear image as EXR.
    #[arg(long, requires = "frames")]
    pub save: Option<PathBuf>,
    /// With --frames: the whole window (controls and readouts included) as PNG, taken after
    /// the other outputs.
    #[arg(long, requires = "frames")]
    pub window_screenshot: Option<PathBuf>,
    /// With --frames: one JSON object on stdout (adapter, backend, estimator, width, height,
    /// passes, first_image_s and its breakdown, first_preview_s, warm_up_s, ms_per_pass,
    /// pass_time_source, samples_per_second, gpu_bytes, longest_frame_gap_ms, frame,
    /// frame_path, ...).
    #[arg(long, requires = "frames")]
    pub json: bool,
    /// With --frames: replay the timed input events of this JSON file in the window (orbit,
    /// zoom, pan, sun, estimator, exposure, frame, resize; docs/viewer.md); the run ends N
    /// passes after the last event, or 10 s after it, and --json gains `events`.
    #[arg(long, requires = "frames")]
    pub input_script: Option<PathBuf>,
    /// With --frames: render without a window (no display needed): the same session,
    /// passes and tone map into a texture on the same adapter, then the outputs and JSON.
    #[arg(long, requires = "frames")]
    pub offscreen: bool,
    /// Play a frame sequence from the start (one frame per --frame-passes passes).
    #[arg(long)]
    pub play: bool,
    /// Passes each frame of a playing sequence accumulates before the next.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..))]
    pub frame_passes: u32,
    /// A volume opened without `--density-scale`: the scale its first look chose
    /// ([`pinrender::front::first_look`]), which then stands in `read.density_scale`.
    #[arg(skip)]
    pub first_look: Option<pinrender::front::first_look::FirstLook>,
}

/// The renderer's estimators (`pinrender::render::ESTIMATORS`); the lab's (urm, jackknife,
/// pinurm) are not linked into the viewer.
fn parse_estimator(s: &str) -> Result<EstimatorSpec, String> {
    s.parse()
}

fn parse_pixel(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<&str> = s.split(',').collect();
    if v.len() != 2 {
        return Err(format!("{s}: expected X,Y"));
    }
    let x = parse_finite(v[0].trim())?;
    let y = parse_finite(v[1].trim())?;
    if x < 0.0 || y < 0.0 {
        return Err(format!("{s}: pixel coordinates must be >= 0"));
    }
    Ok([x, y])
}

/// The image's side where no size flag gives it (off-screen, and the window's first frame).
pub const DEFAULT_SIDE: u32 = 512;

impl ViewArgs {
    /// Whether the command line gives `--density-scale` (1 included: the file's own).
    pub fn density_scale_given() -> bool {
        std::env::args_os().any(|w| {
            let w = w.to_string_lossy();
            w == "--density-scale" || w.starts_with("--density-scale=")
        })
    }

    /// The image size the flags give (a side not given: [`DEFAULT_SIDE`]).
    pub fn size(&self) -> (u32, u32) {
        (
            self.width.unwrap_or(DEFAULT_SIDE),
            self.height.unwrap_or(DEFAULT_SIDE),
        )
    }

    /// Whether a size flag fixes the image's size (else the window's viewport sets it).
    pub fn size_fixed(&self) -> bool {
        self.width.is_some() || self.height.is_some()
    }

    /// The bake the viewer makes of a volume: `pinbake bake`'s choice, with the cells
    /// `--pin-cells` gives (`pinrender::volume::pins_for`'s request).
    pub fn preview_bake(&self) -> crate::open::PreviewBake {
        crate::open::PreviewBake {
            seed: self.flags.seed,
            cells: self.flags.pin_cells,
            budget: self.flags.budget(),
        }
    }
}
