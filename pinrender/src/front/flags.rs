//! The render flags of `pinrender render` and `pinview` (one struct, flattened by both) and
//! their range parsers: the same names, ranges, defaults and messages in both tools.

use clap::Args;
use pin_cli::parse::{parse_f64x3, parse_finite, parse_nonneg};

use crate::look::{Look, LookFlags};

/// The flags of a render that the renderer and the viewer share: the camera, the lighting
/// and the medium's material (each overriding a scene file's value), the seed, the size of an
/// in-memory bake, the memory budget and the exposure.
#[derive(Args, Debug, Clone, Default)]
pub struct RenderFlags {
    /// Camera position X,Y,Z (default: in front of the volume's box, looking at its centre).
    #[arg(long, value_parser = parse_f64x3, allow_hyphen_values = true)]
    pub camera_origin: Option<[f64; 3]>,
    /// Point the camera looks at (default: the box centre).
    #[arg(long, value_parser = parse_f64x3, allow_hyphen_values = true)]
    pub camera_target: Option<[f64; 3]>,
    /// Vertical field of view in degrees, in (0, 180) [default: 40, or the scene's].
    #[arg(long, value_parser = parse_fov)]
    pub fov: Option<f64>,
    /// Direction from the scene towards the sun (finite, not zero) [default: 0.3,1,0.2, or
    /// the scene's].
    #[arg(long, value_parser = parse_direction, allow_hyphen_values = true)]
    pub sun_dir: Option<[f64; 3]>,
    /// [default: 3, or the scene's]
    #[arg(long, value_parser = parse_nonneg)]
    pub sun_radiance: Option<f64>,
    /// [default: 0.3, or the scene's]
    #[arg(long, value_parser = parse_nonneg)]
    pub env_radiance: Option<f64>,
    /// Single-scattering albedo, in [0, 1] [default: 0.9, or the scene's].
    #[arg(long, value_parser = parse_albedo)]
    pub albedo: Option<f64>,
    /// Henyey-Greenstein asymmetry, in (-1, 1) [default: 0, or the scene's].
    #[arg(long, value_parser = parse_hg_g, allow_negative_numbers = true)]
    pub g: Option<f64>,
    /// Scattering events at most (on the GPU, `--backend gpu` and the viewer, at most 1024,
    /// its limit) [default: 8, or the scene's].
    #[arg(long)]
    pub max_bounces: Option<u32>,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Spatial cells per axis when a volume's pins are baked in memory (1..=4096; default:
    /// chosen from the volume as `pinbake bake` chooses them, at least 20 on the longest
    /// axis, never more than the voxels). Fewer cells bake sooner.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub pin_cells: Option<u32>,
    /// Refuse what would need more than this many bytes of memory (K/M/G/T suffixes;
    /// default: half of the physical memory): the inputs' reads, their dense copies, an
    /// in-memory bake, a scene's assets together and the image buffers.
    #[arg(long, value_parser = pin_cli::parse::parse_bytes)]
    pub max_memory: Option<u64>,
    /// Exposure of the tone-mapped image (the PNG, the window) (finite, > 0).
    #[arg(long, default_value_t = 1.0, value_parser = parse_exposure)]
    pub exposure: f32,
}

impl RenderFlags {
    /// The look flags given (`None` where a flag is not given).
    pub fn look_flags(&self) -> LookFlags {
        LookFlags {
            fov: self.fov,
            sun_dir: self.sun_dir,
            sun_radiance: self.sun_radiance,
            env_radiance: self.env_radiance,
            albedo: self.albedo,
            g: self.g,
            max_bounces: self.max_bounces,
        }
    }

    /// The look of the render: each flag given, else the scene's value, else the default.
    pub fn look(&self, scene: Option<&pin_scene::Scene>) -> Look {
        Look::over(&self.look_flags(), scene)
    }

    /// The command's one memory budget (`--max-memory`, else the default).
    pub fn budget(&self) -> pin_volume::files::MemoryBudget {
        pin_volume::files::MemoryBudget::new(self.max_memory)
    }
}

/// `--fov`: degrees in (0, 180), as the f32 the camera holds.
pub fn parse_fov(s: &str) -> Result<f64, String> {
    pin_scene::ranges::fov(parse_finite(s)?)
}

/// `--albedo`: in [0, 1].
pub fn parse_albedo(s: &str) -> Result<f64, String> {
    pin_scene::ranges::albedo(parse_finite(s)?)
}

/// `--g`: the Henyey-Greenstein asymmetry in (-1, 1), as the f32 the scene holds.
pub fn parse_hg_g(s: &str) -> Result<f64, String> {
    pin_scene::ranges::hg_g(parse_finite(s)?)
}

/// `--sun-dir`: a direction whose f32 form the renderer can normalise (finite, not zero).
pub fn parse_direction(s: &str) -> Result<[f64; 3], String> {
    pin_scene::ranges::direction(parse_f64x3(s)?)
}

/// `--exposure`: finite, > 0, as an f32.
pub fn parse_exposure(s: &str) -> Result<f32, String> {
    let v = parse_finite(s)?;
    if !(v > 0.0 && v <= f64::from(f32::MAX)) {
        return Err(format!("{} must be > 0", pin_cli::num(v)));
    }
    Ok(v as f32)
}

/// `--seconds`: in (0, 1e5].
pub fn parse_seconds(s: &str) -> Result<f64, String> {
    let v = parse_finite(s)?;
    if !(v > 0.0 && v <= 1e5) {
        return Err(format!("{} must be in (0, 1e5]", pin_cli::num(v)));
    }
    Ok(v)
}

/// A pin lookup's jitter strength: in 0..=16 cells.
pub fn parse_jitter(s: &str) -> Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|e| format!("'{s}': {e}"))?;
    if !(v.is_finite() && (0.0..=16.0).contains(&v)) {
        return Err(format!("'{s}' is not a jitter strength in 0..=16 cells"));
    }
    Ok(v)
}

/// Bytes per pixel a render's images hold at most: the f32 RGB image, f64 sums of the
/// passes, the PNG and EXR encoders' copies, with slack. The viewer's per-pixel buffers
/// (the accumulation, the tone-mapped texture, a reference and a compare side) fit in it.
pub const BYTES_PER_PIXEL: u64 = 96;

/// Charges a `width` x `height` image to `budget` ([`BYTES_PER_PIXEL`]).
pub fn check_image(
    budget: &pin_volume::files::MemoryBudget,
    width: u32,
    height: u32,
) -> Result<(), pin_volume::files::FileError> {
    check_images(budget, width, height, 1)
}

/// Charges `images` images of `width` x `height` to `budget` together (a viewer's main view,
/// compare side and reference).
pub fn check_images(
    budget: &pin_volume::files::MemoryBudget,
    width: u32,
    height: u32,
    images: u64,
) -> Result<(), pin_volume::files::FileError> {
    let what = match images {
        1 => format!("a {width}x{height} image"),
        n => format!("{n} images of {width}x{height}"),
    };
    budget.check(
        &what,
        (u64::from(width) * u64::from(height) * BYTES_PER_PIXEL).saturating_mul(images),
    )
}
