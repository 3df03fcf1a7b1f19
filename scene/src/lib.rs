//! Scene files: a sky of clouds, or any set of instanced volumes, in one JSON document.
//!
//! A scene names its **assets** (a volume, a pin file, or both, each opened once however many
//! instances use it) and places **instances** of them with a 3x4 local-to-world transform
//! each; optionally it sets the camera, the sun, the sky and the medium's albedo, phase and
//! bounces. The schema is `docs/scene.md` (and `docs/scene.schema.json` for editors).
//!
//! [`load`] reads a file under a memory budget and returns a checked [`Scene`]: every asset
//! has a source, every instance names an asset and has a finite, invertible transform within
//! what f32 queries can resolve, every value is in the range the renderer's flags accept
//! ([`ranges`], shared with `pinrender render`'s flags). A bad file gives one line naming the
//! file, the JSON path (`instances[17].transform`) and the problem.
//!
//! What it is not for: opening the assets (the renderer does, with its own readers and
//! budget; [`Asset::json_path`] names an asset's key for its messages) and placing them in
//! the world (the transform's composition with an asset's own placement is the renderer's).

mod error;
mod limits;
mod load;
mod model;
pub mod ranges;
mod raw;
mod transform;

pub use error::SceneError;
pub use limits::{MAX_ASSETS, MAX_INSTANCES, MAX_SCENE_BYTES};
pub use load::{MAX_STRING_BYTES, load, load_bound, parse};
pub use model::{Asset, Camera, Instance, Scene, Sun};
pub use transform::{IDENTITY, Trs, compose_trs};
