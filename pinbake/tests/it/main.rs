//! pinbake's integration tests, one binary (one link of the crate and its dependencies).
//! Most drive the `pinbake` binary (`CARGO_BIN_EXE_pinbake`), which is also the isolated
//! VDB reader the library tests start.

mod nanovdb;
/// The OpenVDB compatibility corpus, shared by path with the cross-crate tests.
#[path = "../openvdb/mod.rs"]
mod openvdb;

mod cli;
mod hostile;
mod nanovdb_corpus;
mod production;
mod sequences;
mod slurm;
mod sources;
mod vdb_corpus;
