//! The look of a render (camera field of view, sun, sky, material, bounces): the values a
//! scene file may set and a flag overrides, for `pinrender render`, `render --scene` and
//! `pinview`. A leaf: the front end's flags and the scene media both read it.

use pin_scene::Scene;

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
