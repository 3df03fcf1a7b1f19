//! The workspace-level tests that cross crates, one binary (one link of the whole tree):
//! the code map of `docs/architecture.md`, directions, faults, the fuzz corpora, precision,
//! statistics, stiff cases and the rotated VDB.

mod common;

mod architecture;
mod directions;
mod faults;
mod fuzz_corpus;
mod precision;
mod statistics;
mod stiff_cases;
mod vdb_rotated;
