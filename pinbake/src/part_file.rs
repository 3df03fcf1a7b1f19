//! The part file of a farm bake split by volume (`pinbake bake --part I/N`,
//! [`crate::part::PartData`]): what one part hands to `pinbake merge`. Byte layout (all
//! little-endian; specified in docs/farm.md, "Part files"):
//!
//! ```text
//! magic "PINPART\0" | version u32 | part index u32 | part count u32 | flags u32
//! slab lo f64 | slab hi f64
//! grid description: length u32 (= size of GridDesc) | GridDesc bytes (pin_format::layout)
//! metadata: length u32 | pin_format metadata encoding (content hash empty)
//! majorant dims 3 x u32 (0 0 0: none) | majorant f32 x (product of dims)
//! lattice count u32 | lattice f32 x count | lattice owners u8 x count
//! grid facts: present u32 (0 or 1) | if 1: grid summary | negative values u64 | slab summary
//!   | slab's negative values u64 | tiles' negative values u64
//!   (a summary: non-zero leaves u64 | box lo 3 x i32 | box hi 3 x i32 | largest value f32;
//!   no box: lo i32::MAX x 3, hi i32::MIN x 3)
//! sample count u64 | samples f32 x count
//! checksum u64: xxh3-64 of every byte before it
//! ```
//!
//! A reader checks the length, magic, version and checksum before anything else, then every
//! count against the bytes left (checked arithmetic) and against what a bake writes (the part
//! count against [`MAX_PARTS`], the lattice against its fixed size), so a damaged or
//! truncated file is a one-line error and never an allocation the file asked for. The
//! checksum is no defence against an edited file whose checksum was recomputed: the counts
//! are checked all the same.

use std::io::Write;
use std::path::{Path, PathBuf};

use pin_format::{GridDesc, Metadata};

use crate::error::BakeError;
use crate::part::{LeafSummary, MAX_PARTS, Part, PartData, PartFacts, SampleSink};
use pin_volume::identity;

pub const PART_MAGIC: &[u8; 8] = b"PINPART\0";
/// 2: the grid facts ([`PartFacts`]) after the lattice.
pub const PART_VERSION: u32 = 2;
/// `flags` bit: the samples are a dense grid's march ([`PartData::grid_march`]).
pub const PART_FLAG_GRID_MARCH: u32 = 1;

#[derive(Debug, thiserror::Error)]
pub enum PartFileError {
    #[error("not a part file (bad magic)")]
    Magic,
    #[error("part file version {0} is not supported (this build reads version {PART_VERSION})")]
    Version(u32),
    #[error("part file is damaged: checksum mismatch")]
    Checksum,
    #[error("part file is damaged: {0}")]
    Corrupt(String),
    #[error("metadata: {0}")]
    Metadata(#[from] pin_format::FormatError),
    #[error("cannot write the part file: {0}")]
    Write(String),
}

/// Whether `bytes` start like a part file (for a merge that takes pin tiles or parts).
pub fn is_part_file(bytes: &[u8]) -> bool {
    bytes.starts_with(PART_MAGIC)
}

/// The file's bytes.
pub fn encode(d: &PartData) -> Result<Vec<u8>, PartFileError> {
    let mut b = Vec::new();
    encode_into(d, &mut b)?;
    Ok(b)
}

/// A writer that hashes what it passes on, for the trailing checksum of a streamed file.
struct Hashing<W: Write> {
    inner: W,
    hash: xxhash_rust::xxh3::Xxh3,
    bytes: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Writes the file to `w` as it goes (the samples are not copied first), returning its
/// length in bytes.
pub fn encode_into(d: &PartData, w: &mut impl Write) -> Result<u64, PartFileError> {
    let mut h = Hashing {
        inner: w,
        hash: xxhash_rust::xxh3::Xxh3::new(),
        bytes: 0,
    };
    write_head(d, d.samples.len() as u64, &mut h)?;
    write_samples(&d.samples, &mut h)?;
    finish_hash(&mut h)
}

fn io(e: std::io::Error) -> PartFileError {
    PartFileError::Write(e.to_string())
}

/// Every byte before the samples, `total` as their count.
fn write_head(d: &PartData, total: u64, b: &mut impl Write) -> Result<(), PartFileError> {
    let meta = d.metadata.encode()?;
    b.write_all(PART_MAGIC).map_err(io)?;
    for v in [
        PART_VERSION,
        d.part.index,
        d.part.count,
        if d.grid_march {
            PART_FLAG_GRID_MARCH
        } else {
            0
        },
    ] {
        b.write_all(&v.to_le_bytes()).map_err(io)?;
    }
    for v in d.slab {
        b.write_all(&v.to_le_bytes()).map_err(io)?;
    }
    let desc = bytemuck::bytes_of(&d.desc);
    b.write_all(&(desc.len() as u32).to_le_bytes())
        .map_err(io)?;
    b.write_all(desc).map_err(io)?;
    b.write_all(&(meta.len() as u32).to_le_bytes())
        .map_err(io)?;
    b.write_all(&meta).map_err(io)?;
    let (dims, maj): ([u32; 3], &[f32]) = match &d.majorant {
        Some((dims, v)) => (*dims, v),
        None => ([0; 3], &[]),
    };
    for v in dims {
        b.write_all(&v.to_le_bytes()).map_err(io)?;
    }
    b.write_all(bytemuck::cast_slice(maj)).map_err(io)?;
    b.write_all(&(d.lattice.len() as u32).to_le_bytes())
        .map_err(io)?;
    b.write_all(bytemuck::cast_slice(&d.lattice)).map_err(io)?;
    b.write_all(&d.lattice_owned).map_err(io)?;
    match &d.facts {
        None => b.write_all(&0u32.to_le_bytes()).map_err(io)?,
        Some(f) => {
            b.write_all(&1u32.to_le_bytes()).map_err(io)?;
            write_summary(&f.grid, b)?;
            b.write_all(&f.negative_values.to_le_bytes()).map_err(io)?;
            write_summary(&f.slab, b)?;
            for v in [f.slab_negative_values, f.tile_negative_values] {
                b.write_all(&v.to_le_bytes()).map_err(io)?;
            }
        }
    }
    b.write_all(&total.to_le_bytes()).map_err(io)
}

fn write_summary(s: &LeafSummary, b: &mut impl Write) -> Result<(), PartFileError> {
    b.write_all(&s.nonzero_leaves.to_le_bytes()).map_err(io)?;
    let [lo, hi] = s.nonzero_box.unwrap_or([[i32::MAX; 3], [i32::MIN; 3]]);
    for v in lo.into_iter().chain(hi) {
        b.write_all(&v.to_le_bytes()).map_err(io)?;
    }
    b.write_all(&s.max_value.to_le_bytes()).map_err(io)
}

fn write_samples(samples: &[f32], b: &mut impl Write) -> Result<(), PartFileError> {
    for chunk in samples.chunks(1 << 16) {
        b.write_all(bytemuck::cast_slice(chunk)).map_err(io)?;
    }
    Ok(())
}

/// Appends the checksum; the file's length.
fn finish_hash<W: Write>(h: &mut Hashing<W>) -> Result<u64, PartFileError> {
    let sum = h.hash.digest();
    h.inner.write_all(&sum.to_le_bytes()).map_err(io)?;
    Ok(h.bytes + 8)
}

/// Reads the bytes from the front, every length checked against what is left.
struct Cursor<'a>(&'a [u8]);

impl<'a> Cursor<'a> {
    fn take(&mut self, n: u64, what: &str) -> Result<&'a [u8], PartFileError> {
        if n > self.0.len() as u64 {
            return Err(PartFileError::Corrupt(format!(
                "{what} needs {n} bytes, {} left",
                self.0.len()
            )));
        }
        let (a, b) = self.0.split_at(n as usize);
        self.0 = b;
        Ok(a)
    }
    fn u32(&mut self, what: &str) -> Result<u32, PartFileError> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes(b.try_into().expect("4 bytes")))
    }
    fn u64(&mut self, what: &str) -> Result<u64, PartFileError> {
        let b = self.take(8, what)?;
        Ok(u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
    /// A [`LeafSummary`]: a box with every `lo <= hi`, or the marker of none with no leaves;
    /// a finite largest value, 0 without leaves.
    fn summary(&mut self, what: &str) -> Result<LeafSummary, PartFileError> {
        let nonzero_leaves = self.u64(what)?;
        let mut v = [0i32; 6];
        for x in &mut v {
            *x = self.u32(what)? as i32;
        }
        let (lo, hi) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
        let max_value = f32::from_bits(self.u32(what)?);
        let nonzero_box = if (lo, hi) == ([i32::MAX; 3], [i32::MIN; 3]) {
            None
        } else {
            Some([lo, hi])
        };
        let valid = match nonzero_box {
            None => nonzero_leaves == 0 && max_value == 0.0,
            Some([lo, hi]) => {
                nonzero_leaves > 0
                    && (0..3).all(|a| lo[a] <= hi[a])
                    && max_value.is_finite()
                    && max_value > 0.0
            }
        };
        if !valid {
            return Err(PartFileError::Corrupt(format!(
                "{what}: {nonzero_leaves} leaves, box {lo:?}..{hi:?}, largest value {max_value}"
            )));
        }
        Ok(LeafSummary {
            nonzero_leaves,
            nonzero_box,
            max_value,
        })
    }
    fn f32s(&mut self, n: u64, what: &str) -> Result<Vec<f32>, PartFileError> {
        let bytes = self.take(
            n.checked_mul(4)
                .ok_or_else(|| PartFileError::Corrupt(format!("{what}: count {n} overflows")))?,
            what,
        )?;
        let v: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect();
        if let Some(x) = v.iter().find(|x| !(x.is_finite() && **x >= 0.0)) {
            return Err(PartFileError::Corrupt(format!(
                "{what} holds {x}, not a density"
            )));
        }
        Ok(v)
    }
}

/// Parses a part file.
pub fn decode(bytes: &[u8]) -> Result<PartData, PartFileError> {
    if !is_part_file(bytes) {
        return Err(PartFileError::Magic);
    }
    if bytes.len() < PART_MAGIC.len() + 4 + 8 {
        return Err(PartFileError::Corrupt(format!(
            "{} bytes is too short",
            bytes.len()
        )));
    }
    let version = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
    if version != PART_VERSION {
        return Err(PartFileError::Version(version));
    }
    let (body, sum) = bytes.split_at(bytes.len() - 8);
    if xxhash_rust::xxh3::xxh3_64(body) != u64::from_le_bytes(sum.try_into().expect("8 bytes")) {
        return Err(PartFileError::Checksum);
    }
    let mut c = Cursor(&body[12..]);
    let index = c.u32("part index")?;
    let count = c.u32("part count")?;
    if count == 0 || index >= count || count > MAX_PARTS {
        return Err(PartFileError::Corrupt(format!(
            "part {index} of {count} (a bake has 1 to {MAX_PARTS} parts)"
        )));
    }
    let flags = c.u32("flags")?;
    if flags & !PART_FLAG_GRID_MARCH != 0 {
        return Err(PartFileError::Corrupt(format!("unknown flags {flags:#x}")));
    }
    let lo = f64::from_bits(c.u64("slab")?);
    let hi = f64::from_bits(c.u64("slab")?);
    if lo.is_nan() || hi.is_nan() || lo > hi {
        return Err(PartFileError::Corrupt(format!("slab {lo} .. {hi}")));
    }
    let n = c.u32("grid description length")?;
    if n as usize != size_of::<GridDesc>() {
        return Err(PartFileError::Corrupt(format!(
            "grid description of {n} bytes, not {}",
            size_of::<GridDesc>()
        )));
    }
    let desc: GridDesc = bytemuck::pod_read_unaligned(c.take(u64::from(n), "grid description")?);
    let n = c.u32("metadata length")?;
    let metadata = Metadata::decode(c.take(u64::from(n), "metadata")?)?;
    let dims = [c.u32("majorant")?, c.u32("majorant")?, c.u32("majorant")?];
    let majorant = if dims == [0; 3] {
        None
    } else {
        if dims.iter().any(|&d| !(1..=4096).contains(&d)) {
            return Err(PartFileError::Corrupt(format!("majorant dims {dims:?}")));
        }
        let n = dims.iter().map(|&d| u64::from(d)).product();
        Some((dims, c.f32s(n, "majorant")?))
    };
    let n = u64::from(c.u32("lattice count")?);
    let points = identity::LATTICE.pow(3) as u64;
    if n != points {
        return Err(PartFileError::Corrupt(format!(
            "identity lattice of {n} points, not {points}"
        )));
    }
    let lattice = c.f32s(n, "lattice")?;
    let lattice_owned = c.take(n, "lattice owners")?.to_vec();
    if lattice_owned.iter().any(|&o| o > 1) {
        return Err(PartFileError::Corrupt(
            "lattice owner flag not 0 or 1".into(),
        ));
    }
    let facts = match c.u32("grid facts")? {
        0 => None,
        1 => {
            let grid = c.summary("the grid's leaves")?;
            let negative_values = c.u64("negative values")?;
            let slab = c.summary("the slab's leaves")?;
            let slab_negative_values = c.u64("negative values")?;
            let tile_negative_values = c.u64("negative values")?;
            if slab.nonzero_leaves > grid.nonzero_leaves
                || slab.max_value > grid.max_value
                || slab_negative_values.saturating_add(tile_negative_values) > negative_values
            {
                return Err(PartFileError::Corrupt(format!(
                    "the slab's leaves ({slab}, {slab_negative_values} negative values) are more than the grid's ({grid}, {negative_values})"
                )));
            }
            Some(PartFacts {
                grid,
                negative_values,
                slab,
                slab_negative_values,
                tile_negative_values,
            })
        }
        other => {
            return Err(PartFileError::Corrupt(format!(
                "grid facts marker {other}, not 0 or 1"
            )));
        }
    };
    let n = c.u64("sample count")?;
    let samples = c.f32s(n, "samples")?;
    if !c.0.is_empty() {
        return Err(PartFileError::Corrupt(format!(
            "{} bytes after the samples",
            c.0.len()
        )));
    }
    Ok(PartData {
        part: Part { index, count },
        desc,
        metadata,
        slab: [lo, hi],
        grid_march: flags & PART_FLAG_GRID_MARCH != 0,
        majorant,
        lattice,
        lattice_owned,
        samples,
        facts,
    })
}

/// Writes the part file of `d` to `target` atomically: a temporary `.NAME.*.partial` beside
/// it (announced to [`pin_volume::files::watch_partial_files`] while it exists), fsync, rename. A
/// failure leaves no file behind. Returns the file's length.
pub fn write_atomic(target: &Path, d: &PartData) -> Result<u64, PartFileError> {
    let mut w = PartFileWriter::create(target)?;
    w.start_part(d, d.samples.len() as u64)?;
    w.write_samples(&d.samples)?;
    w.finish()
}

/// A part file written as its part is baked ([`crate::part::bake_part_into`], as a
/// [`SampleSink`]): the head first, then the samples batch by batch, then the checksum, into
/// a temporary `.NAME.*.partial` beside the target that [`PartFileWriter::finish`] renames
/// into place. Dropped unfinished (an error, a panic), it removes its temporary file.
pub struct PartFileWriter {
    target: PathBuf,
    temp: PathBuf,
    out: Option<Hashing<std::io::BufWriter<std::fs::File>>>,
    /// Samples the head announced, and those written so far.
    total: u64,
    written: u64,
    _announced: pin_volume::files::Announced,
}

impl PartFileWriter {
    /// Creates the temporary file beside `target`.
    pub fn create(target: &Path) -> Result<Self, PartFileError> {
        let dir = pin_volume::files::parent_dir(target);
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "part".into());
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let temp = dir.join(format!(".{name}.{}-{nanos}.partial", std::process::id()));
        let announced = pin_volume::files::announce_partial_file(&temp);
        let f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&temp)
            .map_err(io)?;
        Ok(Self {
            target: target.to_path_buf(),
            temp,
            out: Some(Hashing {
                inner: std::io::BufWriter::with_capacity(1 << 20, f),
                hash: xxhash_rust::xxh3::Xxh3::new(),
                bytes: 0,
            }),
            total: 0,
            written: 0,
            _announced: announced,
        })
    }

    /// The temporary file's path.
    pub fn temp_path(&self) -> &Path {
        &self.temp
    }

    /// Samples written so far.
    pub fn samples_written(&self) -> u64 {
        self.written
    }

    fn out(&mut self) -> Result<&mut Hashing<std::io::BufWriter<std::fs::File>>, PartFileError> {
        self.out
            .as_mut()
            .ok_or_else(|| PartFileError::Write("the part file is already finished".into()))
    }

    /// Writes everything before the samples; `total` samples must follow.
    pub fn start_part(&mut self, head: &PartData, total: u64) -> Result<(), PartFileError> {
        self.total = total;
        write_head(head, total, self.out()?)
    }

    pub fn write_samples(&mut self, samples: &[f32]) -> Result<(), PartFileError> {
        self.written += samples.len() as u64;
        if self.written > self.total {
            return Err(PartFileError::Write(format!(
                "{} samples written, the head announced {}",
                self.written, self.total
            )));
        }
        write_samples(samples, self.out()?)
    }

    /// The checksum, fsync, rename into place; the file's length.
    pub fn finish(mut self) -> Result<u64, PartFileError> {
        if self.written != self.total {
            return Err(PartFileError::Write(format!(
                "{} samples written, the head announced {}",
                self.written, self.total
            )));
        }
        let mut h = self
            .out
            .take()
            .ok_or_else(|| PartFileError::Write("the part file is already finished".into()))?;
        let len = finish_hash(&mut h)?;
        let f = h.inner.into_inner().map_err(|e| io(e.into_error()))?;
        f.sync_all().map_err(io)?;
        std::fs::rename(&self.temp, &self.target).map_err(io)?;
        // Renamed: nothing for the drop to remove.
        self.temp = PathBuf::new();
        if let Ok(d) = std::fs::File::open(pin_volume::files::parent_dir(&self.target)) {
            let _ = d.sync_all();
        }
        Ok(len)
    }
}

impl Drop for PartFileWriter {
    fn drop(&mut self) {
        if !self.temp.as_os_str().is_empty() {
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

impl SampleSink for PartFileWriter {
    fn start(&mut self, head: &PartData, total: u64) -> Result<(), BakeError> {
        let r = self.start_part(head, total);
        r.map_err(|e| self.bake_error(e))
    }
    fn samples(&mut self, samples: &[f32]) -> Result<(), BakeError> {
        let r = self.write_samples(samples);
        r.map_err(|e| self.bake_error(e))
    }
}

impl PartFileWriter {
    fn bake_error(&self, e: PartFileError) -> BakeError {
        BakeError::Write {
            path: self.target.clone(),
            message: e.to_string(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::BakeOptions;
    use glam::DVec3;
    use pin_volume::{Aabb, HomogeneousBox};

    fn sample() -> PartData {
        let src = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 0.7).unwrap();
        let opts = BakeOptions {
            cells: [3, 2, 4],
            directions: pin_format::Directions::Octahedral { n: 2 },
            majorant: Some([2, 2, 2]),
            ..BakeOptions::default()
        };
        crate::part::bake_part(&src, &opts, Part { index: 1, count: 3 }, &|_| {}).unwrap()
    }

    #[test]
    fn a_streamed_part_file_refuses_a_wrong_sample_count_and_leaves_nothing() {
        let d = sample();
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("x.part");
        let n = d.samples.len() as u64;
        // Fewer samples than announced: finish refuses, nothing stays.
        let mut w = PartFileWriter::create(&target).unwrap();
        w.start_part(&d, n).unwrap();
        w.write_samples(&d.samples[..1]).unwrap();
        assert!(w.finish().unwrap_err().to_string().contains("announced"));
        // More: refused as they come.
        let mut w = PartFileWriter::create(&target).unwrap();
        w.start_part(&d, 1).unwrap();
        assert!(w.write_samples(&d.samples).is_err());
        drop(w);
        // Dropped unfinished: nothing stays.
        let mut w = PartFileWriter::create(&target).unwrap();
        w.start_part(&d, n).unwrap();
        assert!(w.temp_path().exists());
        drop(w);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        // Announced and written in pieces: the bytes of the whole encoding.
        let mut w = PartFileWriter::create(&target).unwrap();
        w.start_part(&d, n).unwrap();
        for c in d.samples.chunks(3) {
            w.write_samples(c).unwrap();
        }
        assert_eq!(w.finish().unwrap(), encode(&d).unwrap().len() as u64);
        assert_eq!(std::fs::read(&target).unwrap(), encode(&d).unwrap());
    }

    #[test]
    fn a_part_file_reads_back_what_was_written() {
        let mut d = sample();
        assert!(!d.samples.is_empty());
        let bytes = encode(&d).unwrap();
        assert!(is_part_file(&bytes));
        assert_eq!(decode(&bytes).unwrap(), d);
        let s = |n, m| LeafSummary {
            nonzero_leaves: n,
            nonzero_box: Some([[-3, 0, 8], [40, 41, 42]]),
            max_value: m,
        };
        d.facts = Some(PartFacts {
            grid: s(9, 2.5),
            negative_values: 5,
            slab: LeafSummary::EMPTY,
            slab_negative_values: 1,
            tile_negative_values: 3,
        });
        assert_eq!(decode(&encode(&d).unwrap()).unwrap(), d);
        d.facts.as_mut().unwrap().slab = s(4, 2.0);
        assert_eq!(decode(&encode(&d).unwrap()).unwrap(), d);
        // A slab of more leaves than its grid: refused.
        d.facts.as_mut().unwrap().slab = s(10, 2.0);
        assert!(matches!(
            decode(&encode(&d).unwrap()),
            Err(PartFileError::Corrupt(_))
        ));
    }

    /// Counts a bake never writes, under a valid checksum: one line, before anything is
    /// sized by them.
    #[test]
    fn absurd_counts_are_refused_under_a_valid_checksum() {
        let resealed = |f: &dyn Fn(&mut Vec<u8>)| {
            let mut b = encode(&sample()).unwrap();
            b.truncate(b.len() - 8);
            f(&mut b);
            let sum = xxhash_rust::xxh3::xxh3_64(&b);
            b.extend_from_slice(&sum.to_le_bytes());
            decode(&b).unwrap_err().to_string()
        };
        // The part count (after magic, version and index).
        let e = resealed(&|b| b[16..20].copy_from_slice(&u32::MAX.to_le_bytes()));
        assert!(e.contains("part 1 of 4294967295"), "{e}");
        let e = resealed(&|b| b[16..20].copy_from_slice(&(MAX_PARTS + 1).to_le_bytes()));
        assert!(e.contains("1025"), "{e}");
        // The lattice count: where the lattice's points and owners begin, 5 bytes each.
        let d = sample();
        let tail = 4 + 5 * d.lattice.len() + 4 + 8 + 4 * d.samples.len();
        let e = resealed(&|b| {
            let at = b.len() - tail;
            b[at..at + 4].copy_from_slice(&7u32.to_le_bytes());
        });
        assert!(e.contains("identity lattice of 7 points"), "{e}");
    }

    /// Every truncation and every flipped byte is a one-line error, never a panic or a
    /// part read from damaged bytes.
    #[test]
    fn damaged_part_files_are_refused() {
        let bytes = encode(&sample()).unwrap();
        for cut in (0..bytes.len()).step_by(7) {
            let e = decode(&bytes[..cut]).unwrap_err().to_string();
            assert!(!e.contains('\n'), "{e}");
        }
        for at in (0..bytes.len()).step_by(5) {
            let mut b = bytes.clone();
            b[at] ^= 0x10;
            let e = decode(&b).unwrap_err().to_string();
            assert!(!e.contains('\n'), "{e}");
        }
        let mut other = bytes.clone();
        other[8] = 9;
        assert!(matches!(decode(&other), Err(PartFileError::Version(9))));
        assert!(matches!(decode(b"PINFILE!xxxx"), Err(PartFileError::Magic)));
        // A consistent checksum over a count that claims more than the file holds.
        let mut long = bytes[..bytes.len() - 8].to_vec();
        let n = long.len();
        // The sample count sits before the samples: make it huge.
        let samples = sample().samples.len();
        let at = n - samples * 4 - 8;
        long[at..at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        let sum = xxhash_rust::xxh3::xxh3_64(&long);
        long.extend_from_slice(&sum.to_le_bytes());
        assert!(matches!(decode(&long), Err(PartFileError::Corrupt(_))));
    }
}
