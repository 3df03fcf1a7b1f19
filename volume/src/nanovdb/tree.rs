//! The walk over a grid's tree, read in place: root tiles (keys of 4096^3 regions), upper
//! 32^3 and lower 16^3 internal nodes (value and child masks, then a table of tile values or
//! signed child offsets from the node), and 8^3 leaves. Produces what the parent-side sparse
//! table of the OpenVDB path is built from: the non-empty leaves, with the same rules for
//! inactive values, negative values and level sets as the OpenVDB worker, and the non-zero
//! tiles.
//!
//! Child offsets come from the file, so each is checked to land inside the buffer, and
//! every node visited counts against the counts the tree header declared (themselves
//! checked against the buffer's size): a file whose offsets share or loop nodes cannot make
//! the walk, or the table it fills, larger than the file.

use super::bytes::{Bytes, offset_by};
use super::grid::{GridHeader, LOWER_BYTES, UPPER_BYTES};
use super::leaf::{self, LEAF_FLAGS, Leaf, ValueType};
use crate::vdb::LeafValues;

/// What the walk found: the input of `VdbSource::from_stream`.
pub(super) struct TreeOut {
    pub(super) origins: Vec<[i32; 3]>,
    pub(super) leaves: LeafValues,
    pub(super) tiles: Vec<([i32; 3], u8, f32)>,
    pub(super) active: u64,
    pub(super) negatives: u64,
}

struct Walk<'a, 'b> {
    b: Bytes<'a>,
    h: &'b GridHeader,
    shown: &'b str,
    release: &'b Release<'b>,
    /// The byte span of the leaves read since the last lower node was finished.
    leaf_span: (u64, u64),
    seen: [u64; 3],
    out: TreeOut,
    leaf: Leaf,
}

/// Whether the leaves are kept as f16 bits: half grids, level sets baked as fog (0 and 1),
/// as the OpenVDB path keeps them, and float grids whose every density is a half value (an
/// OpenVDB float grid saved as half, converted by `nanovdb_convert`: [`float_fits_half`]),
/// which the OpenVDB path keeps as half too. The same values at half the bytes.
pub(super) fn keeps_half(b: &Bytes<'_>, h: &GridHeader, release: &Release<'_>) -> bool {
    h.level_set
        || h.value == ValueType::Half
        || (h.value == ValueType::Float && float_fits_half(b, h, release))
}

/// Called with byte ranges of the grid that the walk is done with (`Buffer::release`).
pub(super) type Release<'a> = dyn Fn(u64, u64) + 'a;

/// The density a leaf voxel gives outside level sets (before the checks of the walk).
fn fog_density(v: f32, active: bool) -> f32 {
    if active { v.max(0.0) } else { 0.0 }
}

/// Whether every density of the float leaves in the grid's leaf array (the declared count
/// from the declared first leaf) is exact in f16. Reads the array in order, once; a leaf
/// out of bounds answers no. The walk checks every leaf it reaches again, so a file whose
/// leaves lie elsewhere is refused rather than rounded.
fn float_fits_half(b: &Bytes<'_>, h: &GridHeader, release: &Release<'_>) -> bool {
    const SIZE: u64 = 2144;
    // Pages are released every 4096 leaves (8.4 MB) as the array is read.
    const CHUNK: u64 = 4096;
    (0..h.node_count[0]).all(|i| {
        if i % CHUNK == 0 && i > 0 {
            release(h.first_leaf + (i - CHUNK) * SIZE, CHUNK * SIZE);
        }
        let Some(bytes) = h
            .first_leaf
            .checked_add(i * SIZE)
            .and_then(|off| b.slice(off, SIZE, "leaf").ok())
        else {
            return false;
        };
        let mask = &bytes[16..80];
        bytes[96..].chunks_exact(4).enumerate().all(|(k, c)| {
            let active = mask[k >> 3] >> (k & 7) & 1 != 0;
            let d = fog_density(f32::from_le_bytes([c[0], c[1], c[2], c[3]]), active);
            !d.is_finite() || half::f16::from_f32(d).to_f32() == d
        })
    })
}

/// Walks the tree of the grid whose buffer is `b`, keeping leaves as f16 when `half` (see
/// [`keeps_half`]). The declared leaf count is reserved up front (already checked against
/// the memory budget).
pub(super) fn walk(
    b: Bytes<'_>,
    h: &GridHeader,
    shown: &str,
    half: bool,
    release: &Release<'_>,
) -> Result<TreeOut, String> {
    let n = h.node_count[0] as usize;
    let leaves = if half {
        let mut v: Vec<[u16; 512]> = Vec::new();
        v.try_reserve_exact(n).map_err(|_| no_memory(shown, n))?;
        LeafValues::Half(v)
    } else {
        let mut v: Vec<[f32; 512]> = Vec::new();
        v.try_reserve_exact(n).map_err(|_| no_memory(shown, n))?;
        LeafValues::F32(v)
    };
    let mut origins = Vec::new();
    origins
        .try_reserve_exact(n)
        .map_err(|_| no_memory(shown, n))?;
    let mut w = Walk {
        b,
        h,
        shown,
        release,
        leaf_span: (u64::MAX, 0),
        seen: [0; 3],
        out: TreeOut {
            origins,
            leaves,
            tiles: Vec::new(),
            active: 0,
            negatives: 0,
        },
        leaf: Leaf {
            mask: [0; 8],
            values: [0.0; 512],
        },
    };
    w.root()?;
    Ok(w.out)
}

fn no_memory(shown: &str, n: usize) -> String {
    format!("grid '{shown}': a table of {n} leaves does not fit in this machine's memory")
}

/// Child `i` of a node of `log2` entries per axis at `origin`, whose children span
/// `child_log2` voxels per axis (NanoVDB's and OpenVDB's order: x slowest, z fastest).
fn child_origin(origin: [i32; 3], i: usize, log2: u32, child_log2: u32) -> [i32; 3] {
    let m = (1usize << log2) - 1;
    let l = [i >> (2 * log2), (i >> log2) & m, i & m];
    [0, 1, 2].map(|a| origin[a].wrapping_add((l[a] as i32) << child_log2))
}

impl Walk<'_, '_> {
    fn count(&mut self, level: usize) -> Result<(), String> {
        self.seen[level] += 1;
        if self.seen[level] > self.h.node_count[level] {
            const NAMES: [&str; 3] = ["leaf", "lower internal", "upper internal"];
            return Err(format!(
                "grid '{}' reaches more {} nodes than the {} its tree header declares (corrupt file)",
                self.shown, NAMES[level], self.h.node_count[level]
            ));
        }
        Ok(())
    }

    /// The density of a tile (root or internal): the OpenVDB worker's rules.
    fn tile_density(&mut self, v: f32, active: bool, at: [i32; 3]) -> Result<f32, String> {
        if self.h.level_set {
            return Ok(if v < 0.0 { 1.0 } else { 0.0 });
        }
        if !active {
            return Ok(0.0);
        }
        if !v.is_finite() {
            return Err(format!(
                "grid '{}' has value {v} in the tile at ({},{},{})",
                self.shown, at[0], at[1], at[2]
            ));
        }
        if v < 0.0 {
            self.out.negatives += 1;
        }
        Ok(v.max(0.0))
    }

    fn root(&mut self) -> Result<(), String> {
        let b = self.b;
        let t = self.h.value;
        let root = self.h.root;
        let table = u64::from(b.u32(root + 24, "root node")?);
        let first = root + t.root_data_size();
        b.slice(first, table.saturating_mul(32), "root tile table")
            .map_err(|e| format!("grid '{}': {e}", self.shown))?;
        let mut origins = Vec::with_capacity(table as usize);
        for i in 0..table {
            let at = first + 32 * i;
            let key = b.u64(at, "root tile")?;
            // 21 bits per axis of the coordinate shifted right by 12, z lowest
            // (`RootData::KeyToCoord`).
            let axis = |s: u32| ((((key >> s) & 0x1f_ffff) << 12) as u32) as i32;
            origins.push([axis(42), axis(21), axis(0)]);
        }
        let mut sorted = origins.clone();
        sorted.sort_unstable();
        if let Some(d) = sorted.windows(2).find(|w| w[0] == w[1]) {
            return Err(format!(
                "grid '{}' has two root entries at ({},{},{}) (corrupt file)",
                self.shown, d[0][0], d[0][1], d[0][2]
            ));
        }
        for (i, o) in origins.into_iter().enumerate() {
            let at = first + 32 * i as u64;
            let child = b.i64(at + 8, "root tile")?;
            if child != 0 {
                let off = offset_by(root, child)
                    .filter(|off| off.checked_add(UPPER_BYTES).is_some_and(|e| e <= b.len()))
                    .ok_or_else(|| self.bad_child("root", o))?;
                self.count(2)?;
                self.internal(off, o, 5)?;
                continue;
            }
            let active = b.u32(at + 16, "root tile")? != 0;
            let v = t.tile_value(&b, at + t.root_tile_value_offset())?;
            self.out.active = self.out.active.saturating_add(u64::from(active) << 36);
            let d = self.tile_density(v, active, o)?;
            if d != 0.0 {
                self.out.tiles.push((o, 3, d));
            }
        }
        Ok(())
    }

    fn bad_child(&self, node: &str, o: [i32; 3]) -> String {
        format!(
            "grid '{}' has a {node} node at ({},{},{}) whose child offset points outside the grid (corrupt file)",
            self.shown, o[0], o[1], o[2]
        )
    }

    /// An upper (`log2` 5) or lower (`log2` 4) internal node at byte `off`.
    fn internal(&mut self, off: u64, origin: [i32; 3], log2: u32) -> Result<(), String> {
        let b = self.b;
        let t = self.h.value;
        let n = 1usize << (3 * log2);
        let words = (n / 64) as u64;
        let child_log2 = if log2 == 5 { 7 } else { 3 };
        let table = if log2 == 5 { 8256 } else { 1088 };
        let mut value_mask = vec![0u64; n / 64];
        let mut child_mask = vec![0u64; n / 64];
        for w in 0..words {
            value_mask[w as usize] = b.u64(off + 32 + 8 * w, "node value mask")?;
            child_mask[w as usize] = b.u64(off + 32 + 8 * words + 8 * w, "node child mask")?;
        }
        let bit = |m: &[u64], i: usize| m[i >> 6] >> (i & 63) & 1 != 0;
        for i in 0..n {
            let entry = off + table + 8 * i as u64;
            let o = child_origin(origin, i, log2, child_log2);
            if bit(&child_mask, i) {
                let child = b.i64(entry, "node child offset")?;
                let size = if log2 == 5 { LOWER_BYTES } else { 96 };
                let what = if log2 == 5 { "upper" } else { "lower" };
                let c = offset_by(off, child)
                    .filter(|c| c.checked_add(size).is_some_and(|e| e <= b.len()))
                    .ok_or_else(|| self.bad_child(what, origin))?;
                if log2 == 5 {
                    self.count(1)?;
                    self.internal(c, o, 4)?;
                } else {
                    self.count(0)?;
                    self.leaf(c, o)?;
                }
                continue;
            }
            let active = bit(&value_mask, i);
            let v = t.tile_value(&b, entry)?;
            self.out.active = self
                .out
                .active
                .saturating_add(u64::from(active) << (3 * child_log2));
            let d = self.tile_density(v, active, o)?;
            if d != 0.0 {
                self.out.tiles.push((o, if log2 == 5 { 2 } else { 1 }, d));
            }
        }
        // The node and (lower nodes) its leaves are done with: NanoVDB lays the leaves of
        // one lower node out one after another.
        if log2 == 4 {
            let (lo, hi) = std::mem::replace(&mut self.leaf_span, (u64::MAX, 0));
            if lo < hi {
                (self.release)(lo, hi - lo);
            }
            (self.release)(off, LOWER_BYTES);
        } else {
            (self.release)(off, UPPER_BYTES);
        }
        Ok(())
    }

    fn leaf(&mut self, off: u64, o: [i32; 3]) -> Result<(), String> {
        let b = self.b;
        let t = self.h.value;
        let in_grid = |e: String| format!("grid '{}': {e}", self.shown);
        let size = t
            .leaf_size(b.u8(off + LEAF_FLAGS, "leaf flags")?)
            .map_err(in_grid)?;
        let bytes = Bytes::new(b.slice(off, size, "leaf node").map_err(in_grid)?);
        self.leaf_span = (self.leaf_span.0.min(off), self.leaf_span.1.max(off + size));
        leaf::decode(t, &bytes, &mut self.leaf).map_err(in_grid)?;
        let mut vals = [0f32; 512];
        let mut any = false;
        self.out.active += self
            .leaf
            .mask
            .iter()
            .map(|m| u64::from(m.count_ones()))
            .sum::<u64>();
        for (k, out) in vals.iter_mut().enumerate() {
            let v = self.leaf.values[k];
            if self.h.level_set {
                // NanoVDB keeps the values of inactive voxels, which OpenVDB's signed flood
                // fill left at plus or minus the background: their sign is the inside test.
                *out = if v < 0.0 { 1.0 } else { 0.0 };
            } else {
                let v = if self.leaf.active(k) { v } else { 0.0 };
                if !v.is_finite() {
                    return Err(format!(
                        "grid '{}' has value {v} at voxel ({},{},{})",
                        self.shown,
                        o[0] + (k >> 6) as i32,
                        o[1] + ((k >> 3) & 7) as i32,
                        o[2] + (k & 7) as i32
                    ));
                }
                if v < 0.0 {
                    self.out.negatives += 1;
                }
                *out = v.max(0.0);
            }
            any |= *out != 0.0;
        }
        if !any {
            return Ok(());
        }
        self.out.origins.push(o);
        match &mut self.out.leaves {
            LeafValues::F32(v) => v.push(vals),
            LeafValues::Half(v) => {
                let mut bits = [0u16; 512];
                for (b, x) in bits.iter_mut().zip(&vals) {
                    let h = half::f16::from_f32(*x);
                    // Exact for half grids and fog level sets; a float grid is kept as half
                    // only when its leaf array was found exact, which a leaf reached outside
                    // that array need not be.
                    if h.to_f32() != *x {
                        return Err(format!(
                            "grid '{}' has a leaf at ({},{},{}) outside its leaf array (corrupt file)",
                            self.shown, o[0], o[1], o[2]
                        ));
                    }
                    *b = h.to_bits();
                }
                v.push(bits);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn child_origins_follow_the_node_order() {
        assert_eq!(child_origin([0, 0, 0], 1, 5, 7), [0, 0, 128]);
        assert_eq!(child_origin([0, 0, 0], 32, 5, 7), [0, 128, 0]);
        assert_eq!(
            child_origin([4096, 0, -4096], 1024, 5, 7),
            [4096 + 128, 0, -4096]
        );
        assert_eq!(child_origin([0, 0, 0], 4095, 4, 3), [120, 120, 120]);
    }
}
