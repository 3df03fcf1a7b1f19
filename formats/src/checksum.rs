//! Section checksums: xxh3-64.
//!
//! Chosen for speed (tens of GB/s, so `verify` on a large file is bound by I/O) and for being a
//! well-specified, widely available hash a C reader can link. It detects damage, it does not
//! authenticate: anyone can recompute it.

use crate::layout::FileHeader;

#[cfg(feature = "writer")]
pub use xxhash_rust::xxh3::Xxh3 as StreamingChecksum;

pub fn checksum(bytes: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytes)
}

/// Checksum over the header bytes that precede the checksum field itself.
pub(crate) fn header_checksum(h: &FileHeader) -> u64 {
    checksum(&bytemuck::bytes_of(h)[..56])
}
