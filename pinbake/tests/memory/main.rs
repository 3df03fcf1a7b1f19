//! pinbake's tests that bound the peak memory of a `pinbake` process they start, in a binary
//! of their own. Linux carries a parent's high-water mark into its child: a child's
//! `ru_maxrss` is at least the resident size of the process that spawned it (its image before
//! `exec`), so a child of the main test binary, which holds the corpora and grids of the
//! other tests, reads hundreds of megabytes whatever it allocates itself. Here the parent
//! stays small and the figures are the child's.

/// The NanoVDB writer of the main test binary.
#[path = "../it/nanovdb.rs"]
mod nanovdb;
/// The OpenVDB compatibility corpus, shared by path with the other test binaries.
#[path = "../openvdb/mod.rs"]
mod openvdb;

mod hostile;
mod sequences;
