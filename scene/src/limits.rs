//! The bounds a scene file is read within: a leaf that the bounded read (`load.rs`) and the
//! document's reader (`raw.rs`) both apply.

/// The largest scene file read: 64 MiB holds over a million instances as 12-number matrices.
pub const MAX_SCENE_BYTES: u64 = 64 << 20;
/// The most instances a scene places.
pub const MAX_INSTANCES: usize = 1 << 20;
/// The most assets a scene names.
pub const MAX_ASSETS: usize = 4096;
/// The longest asset name, in bytes.
pub const MAX_NAME_BYTES: usize = 256;
