//! Bounds-checked little-endian reads from a byte slice: every offset and length a NanoVDB
//! file gives is checked against the bytes actually there before anything is read.

/// A view of the bytes of a file or of one grid's buffer. Reads never panic: an offset or
/// length past the end is an error naming what was being read.
#[derive(Clone, Copy)]
pub(super) struct Bytes<'a> {
    data: &'a [u8],
}

impl<'a> Bytes<'a> {
    pub(super) fn new(data: &'a [u8]) -> Self {
        Self { data }
    }

    pub(super) fn len(&self) -> u64 {
        self.data.len() as u64
    }

    /// `len` bytes at `off`, or an error naming `what` when they are not all there.
    pub(super) fn slice(&self, off: u64, len: u64, what: &str) -> Result<&'a [u8], String> {
        let end = off.checked_add(len);
        match end {
            Some(end) if end <= self.len() => Ok(&self.data[off as usize..end as usize]),
            _ => Err(format!(
                "{what} at byte {off} ({len} bytes) lies past the end of the {} bytes there (truncated or corrupt file)",
                self.len()
            )),
        }
    }

    fn array<const N: usize>(&self, off: u64, what: &str) -> Result<[u8; N], String> {
        let s = self.slice(off, N as u64, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub(super) fn u8(&self, off: u64, what: &str) -> Result<u8, String> {
        Ok(self.array::<1>(off, what)?[0])
    }
    pub(super) fn u16(&self, off: u64, what: &str) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.array(off, what)?))
    }
    pub(super) fn u32(&self, off: u64, what: &str) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.array(off, what)?))
    }
    pub(super) fn u64(&self, off: u64, what: &str) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.array(off, what)?))
    }
    pub(super) fn i64(&self, off: u64, what: &str) -> Result<i64, String> {
        Ok(i64::from_le_bytes(self.array(off, what)?))
    }
    pub(super) fn f32(&self, off: u64, what: &str) -> Result<f32, String> {
        Ok(f32::from_le_bytes(self.array(off, what)?))
    }
    pub(super) fn f64(&self, off: u64, what: &str) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.array(off, what)?))
    }
}

/// `base + delta` for a signed node offset, when it stays inside `0..=u64::MAX`.
pub(super) fn offset_by(base: u64, delta: i64) -> Option<u64> {
    base.checked_add_signed(delta)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_in_bounds_and_refuses_past_the_end() {
        let b = Bytes::new(&[1, 0, 0, 0, 2, 0, 0, 0]);
        assert_eq!(b.u32(0, "x").unwrap(), 1);
        assert_eq!(b.u32(4, "x").unwrap(), 2);
        assert_eq!(b.u64(0, "x").unwrap(), (2 << 32) | 1);
        let e = b.u32(5, "the thing").unwrap_err();
        assert!(e.contains("the thing at byte 5"), "{e}");
        assert!(b.slice(u64::MAX, 2, "x").is_err());
        assert!(b.slice(8, 0, "x").unwrap().is_empty());
        assert_eq!(offset_by(10, -4), Some(6));
        assert_eq!(offset_by(3, -4), None);
    }
}
