//! The workspace-level tests that cross crates, one binary (one link of the whole tree):
//! the code map of `docs/architecture.md`, directions, faults, the fuzz corpora, precision,
//! statistics, stiff cases, the rotated VDB, and GPU against CPU bakes rendered with pins alone.

mod common;

mod architecture;
mod directions;
mod faults;
mod fuzz_corpus;
mod gpu_bake_render;
mod module_cycles;
mod precision;
mod statistics;
mod stiff_cases;
mod vdb_rotated;
