//! A checked scene: what [`crate::load`] returns.

use std::path::PathBuf;

/// A scene read from a file, every value checked.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The scene file (messages name it; asset paths are already resolved against it).
    pub file: PathBuf,
    /// The assets in the order the file lists them.
    pub assets: Vec<Asset>,
    /// The instances in the order the file lists them.
    pub instances: Vec<Instance>,
    pub camera: Camera,
    pub sun: Sun,
    pub env_radiance: Option<f64>,
    pub albedo: Option<f64>,
    pub g: Option<f64>,
    pub max_bounces: Option<u32>,
}

/// One asset: what its instances show. At least one of `volume` and `pins` is set.
#[derive(Debug, Clone, PartialEq)]
pub struct Asset {
    /// Its key in the file's `assets` object.
    pub name: String,
    /// A `.vdb`, `.nvdb` or raw volume, resolved against the scene file's folder.
    pub volume: Option<PathBuf>,
    /// A `.pin` file, resolved against the scene file's folder.
    pub pins: Option<PathBuf>,
    /// Multiplies the volume's density (the pins hold the scale they were baked with).
    pub density_scale: Option<f64>,
    /// The grid of a multi-grid VDB.
    pub grid: Option<String>,
}

impl Asset {
    /// The JSON path of one of this asset's fields (`assets.cloud.volume`), for messages
    /// about what the field names.
    pub fn json_path(&self, field: &str) -> String {
        format!("assets.{}.{field}", self.name)
    }
}

/// One placed copy of an asset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Instance {
    /// Index into [`Scene::assets`].
    pub asset: u32,
    /// Row-major 3x4 local-to-world: finite, invertible, translation within +-1e12.
    pub local_to_world: [f64; 12],
}

impl Scene {
    /// The JSON path of instance `i` (`instances[17]`), for messages.
    pub fn instance_path(i: usize) -> String {
        format!("instances[{i}]")
    }

    /// How many instances use each asset, in asset order.
    pub fn uses(&self) -> Vec<usize> {
        let mut n = vec![0; self.assets.len()];
        for inst in &self.instances {
            n[inst.asset as usize] += 1;
        }
        n
    }
}

/// The camera's optional values; the command line's flags override them.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Camera {
    pub origin: Option<[f64; 3]>,
    pub target: Option<[f64; 3]>,
    /// Vertical field of view in degrees.
    pub fov: Option<f64>,
}

/// The sun's optional values; the command line's flags override them.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sun {
    /// Towards the sun (need not be unit length).
    pub direction: Option<[f64; 3]>,
    pub radiance: Option<f64>,
}
