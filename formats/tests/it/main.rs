//! pin-format's integration tests, one binary (one link of the crate and its dependencies).
//!
//! `fuzz_mutations` installs this binary's global allocator: it counts per thread and only
//! inside the closure a test measures, so the other tests (each on its own thread) neither
//! disturb its figures nor see anything but a thread-local add per allocation.

mod common;

mod corruption;
mod fuzz_corpus;
mod fuzz_mutations;
mod golden;
mod roundtrip;
mod spec_directions;
