//! The small provenance section, encoded with bincode 2 (standard config, varint integers).
//!
//! Only human-interesting facts live here; nothing a sampler needs. Decoding is bounded: a
//! lying length inside the encoding cannot make the reader allocate more than
//! [`MAX_METADATA_BYTES`] (bincode's decode limit).

use bincode::{Decode, Encode};

use crate::error::{FormatError, Result};

/// Provenance of a bake. Times are optional so that deterministic bakes stay byte-identical.
#[derive(Clone, Debug, Default, PartialEq, Encode, Decode)]
pub struct Metadata {
    /// Name of the producing tool, e.g. `pinbake`.
    pub tool: String,
    pub tool_version: String,
    /// File name (not path) of the source volume, or a procedural description.
    pub source_name: String,
    /// Hex xxh3-128 of the source file's bytes (empty for procedural sources).
    pub source_hash: String,
    /// What the source was (grid name, type, dims...).
    pub source_description: String,
    pub seed: u64,
    /// Relative ray-marching step of the bake.
    pub step_size: f64,
    pub density_scale: f64,
    /// Seconds since the Unix epoch, when recorded (see `SOURCE_DATE_EPOCH` in the baker).
    pub bake_unix_time: Option<u64>,
    /// Free-form key/value pairs, sorted by the producer for determinism.
    pub extra: Vec<(String, String)>,
}

/// Sections larger than this are rejected before decoding.
pub const MAX_METADATA_BYTES: usize = 1 << 20;

fn config() -> impl bincode::config::Config {
    bincode::config::standard()
        .with_little_endian()
        .with_variable_int_encoding()
        .with_limit::<MAX_METADATA_BYTES>()
}

impl Metadata {
    pub fn encode(&self) -> Result<Vec<u8>> {
        let bytes = bincode::encode_to_vec(self, config())
            .map_err(|e| FormatError::InvalidInput(format!("metadata: {e}")))?;
        if bytes.len() > MAX_METADATA_BYTES {
            return Err(FormatError::InvalidInput(format!(
                "metadata is {} bytes, limit {MAX_METADATA_BYTES}",
                bytes.len()
            )));
        }
        // bincode's decode limit also counts the in-memory size of container elements not yet
        // read (48 bytes per `extra` pair), so a small encoding can still exceed it on decode:
        // refuse to write what would not read back.
        Self::decode(&bytes)
            .map_err(|e| FormatError::InvalidInput(format!("metadata would not read back: {e}")))?;
        Ok(bytes)
    }

    pub fn decode(bytes: &[u8]) -> Result<Self> {
        if bytes.len() > MAX_METADATA_BYTES {
            return Err(FormatError::BadMetadata(format!(
                "{} bytes exceeds the {MAX_METADATA_BYTES}-byte limit",
                bytes.len()
            )));
        }
        let (value, used): (Metadata, usize) = bincode::decode_from_slice(bytes, config())
            .map_err(|e| FormatError::BadMetadata(e.to_string()))?;
        if used != bytes.len() {
            return Err(FormatError::BadMetadata(format!(
                "{} trailing bytes after the encoded value",
                bytes.len() - used
            )));
        }
        Ok(value)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let m = Metadata {
            tool: "pinbake".into(),
            tool_version: "0.1.0".into(),
            source_name: "smoke.vdb".into(),
            source_hash: "00ff".into(),
            source_description: "vdb density".into(),
            seed: 7,
            step_size: 0.01,
            density_scale: 2.0,
            bake_unix_time: Some(1_700_000_000),
            extra: vec![("k".into(), "v".into())],
        };
        let bytes = m.encode().unwrap();
        assert_eq!(Metadata::decode(&bytes).unwrap(), m);
    }

    #[test]
    fn lying_string_length_is_an_error_not_an_allocation() {
        // A varint string length of u64::MAX-ish right at the start (tool name).
        let mut bytes = vec![0xFFu8, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF];
        bytes.extend_from_slice(b"abc");
        assert!(Metadata::decode(&bytes).is_err());
        assert!(Metadata::decode(&[]).is_err());
        let good = Metadata::default().encode().unwrap();
        let mut extra = good.clone();
        extra.push(0);
        assert!(Metadata::decode(&extra).is_err());
    }
}
