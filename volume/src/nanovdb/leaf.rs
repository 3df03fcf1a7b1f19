//! The value types NanoVDB grids hold and how one 8^3 leaf of each is decoded: the node
//! sizes and field offsets of NanoVDB 32 (`NanoVDB.h`: `LeafData<ValueT>` and the quantised
//! `LeafFnBase` leaves), read from the leaf's bytes in place.

use super::bytes::Bytes;

/// The scalar grid types this reader decodes (`nanovdb::GridType`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum ValueType {
    Float,
    Double,
    Half,
    Fp4,
    Fp8,
    Fp16,
    FpN,
}

/// The name of every `nanovdb::GridType` (its enum order), for messages.
const TYPE_NAMES: [&str; 20] = [
    "unknown", "float", "double", "int16", "int32", "int64", "vec3f", "vec3d", "mask", "half",
    "uint32", "bool", "rgba8", "fp4", "fp8", "fp16", "fpN", "vec4f", "vec4d", "index",
];

/// The name of grid type code `t`, whether or not it is read.
pub(super) fn type_name(t: u32) -> String {
    TYPE_NAMES
        .get(t as usize)
        .map_or_else(|| format!("type code {t}"), |s| s.to_string())
}

impl ValueType {
    pub(super) fn from_code(t: u32) -> Option<Self> {
        Some(match t {
            1 => Self::Float,
            2 => Self::Double,
            9 => Self::Half,
            13 => Self::Fp4,
            14 => Self::Fp8,
            15 => Self::Fp16,
            16 => Self::FpN,
            _ => return None,
        })
    }

    /// Whether the upper nodes, lower nodes and root store `f64` values (8-byte tiles, a
    /// 96-byte root); every other type keeps f32 statistics and tiles there (f16 for half).
    fn is_double(self) -> bool {
        self == Self::Double
    }

    /// Size of the root's own data before its tile table (`sizeof(RootData)`).
    pub(super) fn root_data_size(self) -> u64 {
        if self.is_double() { 96 } else { 64 }
    }

    /// Offset of the value inside a 32-byte root tile (`RootData::Tile::value`).
    pub(super) fn root_tile_value_offset(self) -> u64 {
        if self.is_double() { 24 } else { 20 }
    }

    /// A tile value (root or internal node) at `off`, as the f32 the baker holds.
    pub(super) fn tile_value(self, b: &Bytes<'_>, off: u64) -> Result<f32, String> {
        match self {
            Self::Double => Ok(b.f64(off, "tile value")? as f32),
            Self::Half => Ok(half::f16::from_bits(b.u16(off, "tile value")?).to_f32()),
            _ => b.f32(off, "tile value"),
        }
    }

    /// The size of a leaf in bytes; an FpN leaf's size depends on its bit width, read from
    /// its flags byte (`leaf` starts at the leaf).
    pub(super) fn leaf_size(self, leaf_flags: u8) -> Result<u64, String> {
        Ok(match self {
            Self::Float => 2144,
            Self::Double => 4224,
            Self::Half | Self::Fp16 => 1120,
            Self::Fp4 => 352,
            Self::Fp8 => 608,
            Self::FpN => 96 + 64 * u64::from(fpn_bits(leaf_flags)?),
        })
    }

    /// The smallest leaf of this type, for checking node counts against the grid's size.
    pub(super) fn min_leaf_size(self) -> u64 {
        match self {
            Self::FpN => 96 + 64,
            t => t.leaf_size(0).unwrap_or(96),
        }
    }

    /// The name used in messages and in the source description.
    pub(super) fn name(self) -> &'static str {
        match self {
            Self::Float => "float",
            Self::Double => "double",
            Self::Half => "half",
            Self::Fp4 => "fp4",
            Self::Fp8 => "fp8",
            Self::Fp16 => "fp16",
            Self::FpN => "fpN",
        }
    }
}

/// The bit width of an FpN leaf: `1 << (flags >> 5)`, one of 1, 2, 4, 8 and 16.
fn fpn_bits(flags: u8) -> Result<u32, String> {
    let b = flags >> 5;
    if b > 4 {
        return Err(format!(
            "an FpN leaf declares a bit width code {b} (at most 4, 16 bits; corrupt file)"
        ));
    }
    Ok(1 << b)
}

/// Offset of the value mask (64 bytes) in every leaf type.
const LEAF_MASK: u64 = 16;
/// Offset of the flags byte in every leaf type.
pub(super) const LEAF_FLAGS: u64 = 15;

/// One decoded leaf: its value mask and the value of each of its 512 voxels (as the
/// source's file stores it, in NanoVDB's order `x * 64 + y * 8 + z`), before any clamping.
pub(super) struct Leaf {
    pub(super) mask: [u64; 8],
    pub(super) values: [f32; 512],
}

impl Leaf {
    pub(super) fn active(&self, k: usize) -> bool {
        self.mask[k >> 6] >> (k & 63) & 1 != 0
    }
}

/// Decodes the leaf of type `t` whose bytes are `leaf` (exactly its size) into `out`.
pub(super) fn decode(t: ValueType, leaf: &Bytes<'_>, out: &mut Leaf) -> Result<(), String> {
    for (w, m) in out.mask.iter_mut().enumerate() {
        *m = leaf.u64(LEAF_MASK + 8 * w as u64, "leaf value mask")?;
    }
    let v = &mut out.values;
    match t {
        ValueType::Float => {
            let s = leaf.slice(96, 2048, "leaf values")?;
            for (o, c) in v.iter_mut().zip(s.chunks_exact(4)) {
                *o = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            }
        }
        ValueType::Double => {
            let s = leaf.slice(128, 4096, "leaf values")?;
            for (o, c) in v.iter_mut().zip(s.chunks_exact(8)) {
                let mut a = [0u8; 8];
                a.copy_from_slice(c);
                *o = f64::from_le_bytes(a) as f32;
            }
        }
        ValueType::Half => {
            let s = leaf.slice(96, 1024, "leaf values")?;
            for (o, c) in v.iter_mut().zip(s.chunks_exact(2)) {
                *o = half::f16::from_bits(u16::from_le_bytes([c[0], c[1]])).to_f32();
            }
        }
        ValueType::Fp4 | ValueType::Fp8 | ValueType::Fp16 | ValueType::FpN => {
            let min = leaf.f32(80, "leaf minimum")?;
            let quantum = leaf.f32(84, "leaf quantum")?;
            let bits = match t {
                ValueType::Fp4 => 4,
                ValueType::Fp8 => 8,
                ValueType::Fp16 => 16,
                _ => fpn_bits(leaf.u8(LEAF_FLAGS, "leaf flags")?)?,
            };
            let codes = leaf.slice(96, 64 * u64::from(bits), "leaf codes")?;
            let mask = (1u32 << bits) - 1;
            for (i, o) in v.iter_mut().enumerate() {
                // Codes are packed from the lowest bit of each byte (NanoVDB's
                // `LeafData<FpN>::getValue`); 16-bit codes are little-endian words.
                let code = if bits == 16 {
                    u32::from(u16::from_le_bytes([codes[2 * i], codes[2 * i + 1]]))
                } else {
                    let bit = i * bits as usize;
                    (u32::from(codes[bit >> 3]) >> (bit & 7)) & mask
                };
                // The same f32 arithmetic as NanoVDB's decoder: code * quantum + minimum.
                *o = code as f32 * quantum + min;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leaf_bytes(size: usize) -> Vec<u8> {
        let mut b = vec![0u8; size];
        b[LEAF_MASK as usize] = 0b101; // voxels 0 and 2 active
        b
    }

    #[test]
    fn quantised_codes_decode_as_nanovdb_does() {
        // Fp4: voxel 0 has code 3, voxel 1 code 12 (high nibble of byte 0).
        let mut b = leaf_bytes(352);
        b[80..84].copy_from_slice(&1.5f32.to_le_bytes());
        b[84..88].copy_from_slice(&0.25f32.to_le_bytes());
        b[96] = 0xc3;
        let mut out = Leaf {
            mask: [0; 8],
            values: [0.0; 512],
        };
        decode(ValueType::Fp4, &Bytes::new(&b), &mut out).unwrap();
        assert_eq!(out.values[0], 3.0 * 0.25 + 1.5);
        assert_eq!(out.values[1], 12.0 * 0.25 + 1.5);
        assert_eq!(out.values[2], 1.5);
        assert!(out.active(0) && !out.active(1) && out.active(2));

        // FpN with 2-bit codes (flags code 1): voxel 3 is bits 6..8 of byte 0.
        let mut b = leaf_bytes(96 + 128);
        b[LEAF_FLAGS as usize] = 1 << 5;
        b[84..88].copy_from_slice(&1.0f32.to_le_bytes());
        b[96] = 0b1100_0000;
        decode(ValueType::FpN, &Bytes::new(&b), &mut out).unwrap();
        assert_eq!(out.values[3], 3.0);
        assert_eq!(out.values[2], 0.0);
        assert_eq!(ValueType::FpN.leaf_size(1 << 5).unwrap(), 224);
        // A bit-width code past 16 bits is refused.
        assert!(ValueType::FpN.leaf_size(5 << 5).is_err());

        // Fp16: little-endian 16-bit codes.
        let mut b = leaf_bytes(1120);
        b[84..88].copy_from_slice(&1.0f32.to_le_bytes());
        b[98..100].copy_from_slice(&513u16.to_le_bytes());
        decode(ValueType::Fp16, &Bytes::new(&b), &mut out).unwrap();
        assert_eq!(out.values[1], 513.0);
    }

    #[test]
    fn a_short_leaf_is_an_error() {
        let b = leaf_bytes(200);
        let mut out = Leaf {
            mask: [0; 8],
            values: [0.0; 512],
        };
        assert!(decode(ValueType::Float, &Bytes::new(&b), &mut out).is_err());
    }
}
