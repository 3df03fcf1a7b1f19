//! The `pinrender` binary's tests, one test binary (one link of the tree) with a module per
//! concern.

mod cli_text;
mod eval_asset_time;
mod eval_bytes;
mod eval_cli;
mod front;
mod gpu_density;
mod hostile;
mod pin_alone;
mod scene;
mod shaders;
