//! Allocations sized by input, each a [`BakeError::Alloc`] naming what it was for instead of
//! an abort of the process.

use crate::error::BakeError;

/// `vec![value; n]` that reports a failed allocation instead of aborting the process.
pub fn try_filled<T: Clone>(what: &'static str, n: usize, value: T) -> Result<Vec<T>, BakeError> {
    let mut v = try_reserved(what, n)?;
    v.resize(n, value);
    Ok(v)
}

/// An empty vector with room for `n` values, or [`BakeError::Alloc`] naming `what`.
pub fn try_reserved<T>(what: &'static str, n: usize) -> Result<Vec<T>, BakeError> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| BakeError::Alloc {
        what,
        bytes: (n as u64).saturating_mul(size_of::<T>() as u64),
    })?;
    Ok(v)
}
