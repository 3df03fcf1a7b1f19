//! pinbake's integration tests, one binary (one link of the crate and its dependencies),
//! except those that bound a child's peak memory (`tests/memory/`). Most drive the `pinbake`
//! binary (`CARGO_BIN_EXE_pinbake`), which is also the isolated VDB reader the library tests
//! start.

mod nanovdb;
/// The OpenVDB compatibility corpus, shared by path with the cross-crate tests.
#[path = "../openvdb/mod.rs"]
mod openvdb;

mod cli;
mod default_asset;
#[cfg(feature = "gpu")]
mod gpu_bake;
mod nanovdb_corpus;
mod outputs;
mod production;
mod slurm;
mod sources;
mod vdb_corpus;
mod vdb_parts;
