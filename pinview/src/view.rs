//! The view: camera, light, material, estimator and exposure, in the units of `pinrender
//! render`'s flags, so that the GPU scene is built from them exactly as the batch renderer
//! builds it and the view can be written back as its command line.

use glam::DVec3;
use pinrender::gpu_render::GpuScene;
use pinrender::render::EstimatorSpec;
use pinrender::scene_media::{Look, camera_over};

use crate::args::ViewArgs;
use crate::open::Medium;

#[derive(Clone, Debug, PartialEq)]
pub struct View {
    pub estimator: EstimatorSpec,
    pub width: u32,
    pub height: u32,
    pub origin: [f64; 3],
    pub target: [f64; 3],
    /// The field of view, lights and material, as `pinrender render` takes them.
    pub look: Look,
    pub seed: u64,
    pub exposure: f32,
}

impl View {
    /// The view the flags ask for: each flag given, else the scene's value (a scene file),
    /// else `pinrender render`'s default.
    pub fn new(a: &ViewArgs, medium: &Medium, estimator: EstimatorSpec) -> Self {
        let scene = medium.scene();
        let f = &a.flags;
        let (origin, target) = camera_over(f.camera_origin, f.camera_target, scene, medium.bounds);
        let look = f.look(scene);
        Self {
            estimator,
            width: a.size().0,
            height: a.size().1,
            origin,
            target,
            look,
            seed: f.seed,
            exposure: f.exposure,
        }
    }

    /// The scene as `pinrender render` builds it from the same flags.
    pub fn scene(&self) -> GpuScene {
        let frame = self
            .look
            .frame((self.origin, self.target), self.width, self.height);
        GpuScene::from_scene(&frame, self.look.max_bounces)
    }

    /// Turns the camera around its target: `yaw` about the world's y axis, `pitch` towards
    /// the poles (radians; kept off the poles).
    pub fn orbit(&mut self, yaw: f64, pitch: f64) {
        let t = DVec3::from(self.target);
        let d = DVec3::from(self.origin) - t;
        let r = d.length().max(1e-9);
        let az = d.x.atan2(d.z) + yaw;
        let el = ((d.y / r).clamp(-1.0, 1.0).asin() + pitch).clamp(-1.5, 1.5);
        let o = t + r * DVec3::new(el.cos() * az.sin(), el.sin(), el.cos() * az.cos());
        self.origin = o.to_array();
    }

    /// Moves camera and target in the image plane by fractions of the distance to the target.
    pub fn pan(&mut self, dx: f64, dy: f64) {
        let t = DVec3::from(self.target);
        let o = DVec3::from(self.origin);
        let f = (t - o).normalize_or_zero();
        let mut r = f.cross(DVec3::Y);
        if r.length_squared() < 1e-12 {
            r = f.cross(DVec3::Z);
        }
        let r = r.normalize_or_zero();
        let u = r.cross(f);
        let shift = ((-dx) * r + dy * u) * (t - o).length();
        self.origin = (o + shift).to_array();
        self.target = (t + shift).to_array();
    }

    /// Moves the camera towards the target by `factor` of the distance (< 1 closer).
    pub fn zoom(&mut self, factor: f64) {
        let t = DVec3::from(self.target);
        let o = DVec3::from(self.origin);
        let o = t + (o - t) * factor.clamp(0.05, 20.0);
        self.origin = o.to_array();
    }

    /// Turns the sun direction about the world's y axis and towards the zenith.
    pub fn turn_sun(&mut self, yaw: f64, pitch: f64) {
        let d = DVec3::from(self.look.sun_dir).normalize_or_zero();
        let az = d.x.atan2(d.z) + yaw;
        let el = (d.y.clamp(-1.0, 1.0).asin() + pitch).clamp(-1.55, 1.55);
        self.look.sun_dir = [el.cos() * az.sin(), el.sin(), el.cos() * az.cos()];
    }

    /// The `pinrender render` command line that renders this view of `file` in batch
    /// (`spp` samples, the same seed): with `--backend gpu`, the same bits as the viewer's
    /// accumulation after `spp` passes.
    /// `medium` gives the flag that names its file (`--volume`, `--pins` or `--scene`) and
    /// the flags it was opened with (a raw volume's `--dims`, the `--density-scale` of the
    /// bake shown, ...).
    pub fn command_line(&self, medium: &Medium, spp: u32) -> String {
        let v3 = |v: [f64; 3]| format!("{},{},{}", v[0], v[1], v[2]);
        let input = medium.input_flag();
        let file = &medium.path;
        let open: String = medium
            .open_flags()
            .iter()
            .map(|w| format!(" {}", shell_quote(w)))
            .collect();
        format!(
            "pinrender render {input} {}{open} --backend gpu --estimator {} --width {} --height {} \
             --camera-origin {} --camera-target {} --fov {} --sun-dir {} --sun-radiance {} \
             --env-radiance {} --albedo {} --g {} --max-bounces {} --seed {} --exposure {} \
             --spp {} --out view.exr",
            shell_quote(&file.display().to_string()),
            self.estimator,
            self.width,
            self.height,
            v3(self.origin),
            v3(self.target),
            self.look.fov,
            v3(self.look.sun_dir),
            self.look.sun_radiance,
            self.look.env_radiance,
            self.look.albedo,
            self.look.g,
            self.look.max_bounces,
            self.seed,
            self.exposure,
            spp.max(1),
        )
    }
}

/// `s` as one shell word.
fn shell_quote(s: &str) -> String {
    if !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_./:=@,+".contains(&b))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}
