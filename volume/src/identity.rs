//! The identity of a source as a bake sees it, recorded in the pin file so that a renderer
//! can tell whether pins belong to the volume it is given (`docs/format.md`, "Source
//! identity").
//!
//! Four facts: a content hash of the extinction *as sampled* (a fixed lattice of points over
//! the source's box, after the density scale), the density scale, the placement
//! (`local_to_world` of the source's bake frame) and the box. The hash samples instead of
//! hashing the file so that the same volume read through different files or flags that give
//! the same field agree, and so that a different `--density-scale`, `--dims` or `--type`
//! does not. They travel in the metadata's free-form `extra` pairs, which older readers skip
//! and older files lack (a renderer then warns instead of checking).

use glam::DVec3;

use super::DensitySource;

/// Points per axis of the sampling lattice (cell centres of the source's box).
pub const LATTICE: usize = 32;

/// The `extra` keys, sorted (the metadata keeps its pairs sorted for determinism).
pub const KEY_BOX: &str = "source.box";
pub const KEY_CONTENT: &str = "source.content_xxh3";
pub const KEY_DENSITY_SCALE: &str = "source.density_scale";
pub const KEY_TRANSFORM: &str = "source.local_to_world";

/// What identifies a source to its pins.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceIdentity {
    /// Hex xxh3-128 of the f32 extinction bits at the lattice points, with the box.
    pub content: String,
    pub density_scale: f64,
    /// Row-major 3x4 placement of the source's bake frame (identity for world-space sources).
    pub local_to_world: [f64; 12],
    pub box_min: [f64; 3],
    pub box_max: [f64; 3],
}

/// The extinction of `source` at the lattice points, z-major, then y, then x (what
/// [`content_hash`] hashes). A row is sampled in one `extinction_along` call from its first
/// point, so point `(x, y, z)` is `extinction_along`'s `x`-th sample of row `(y, z)`.
pub fn lattice_values(source: &dyn DensitySource) -> Vec<f32> {
    let b = source.bounds();
    let size = (b.max - b.min) / LATTICE as f64;
    let mut values = vec![0f32; LATTICE * LATTICE * LATTICE];
    for (r, row) in values.chunks_mut(LATTICE).enumerate() {
        let (y, z) = (r % LATTICE, r / LATTICE);
        source.extinction_along(
            lattice_row_start(b, y, z),
            DVec3::new(size.x, 0.0, 0.0),
            LATTICE,
            row,
        );
    }
    values
}

/// The first point of lattice row `(y, z)` of the box `b`; the row steps by `b`'s extent
/// along x over [`LATTICE`].
pub fn lattice_row_start(b: super::Aabb, y: usize, z: usize) -> DVec3 {
    let size = (b.max - b.min) / LATTICE as f64;
    b.min + size * DVec3::new(0.5, y as f64 + 0.5, z as f64 + 0.5)
}

/// The content hash of a source with box `b` whose lattice values are `values`
/// ([`lattice_values`]): hex xxh3-128 of the box and the values' bits.
pub fn content_hash(b: super::Aabb, values: &[f32]) -> String {
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    for v in [b.min, b.max] {
        for c in v.to_array() {
            h.update(&c.to_le_bytes());
        }
    }
    for v in values {
        h.update(&v.to_bits().to_le_bytes());
    }
    format!("{:032x}", h.digest128())
}

const IDENTITY: [f64; 12] = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];

fn join(v: &[f64]) -> String {
    // `{:?}` prints the shortest text that parses back to the same f64.
    v.iter()
        .map(|x| format!("{x:?}"))
        .collect::<Vec<_>>()
        .join(",")
}

fn split<const N: usize>(s: &str) -> Option<[f64; N]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.parse().ok())
        .collect::<Option<_>>()?;
    v.try_into().ok()
}

impl SourceIdentity {
    /// The identity of `source` (already density-scaled by `density_scale`).
    pub fn of(source: &dyn DensitySource, density_scale: f64) -> Self {
        let b = source.bounds();
        let local_to_world = source.bake_frame().map_or(IDENTITY, |(_, m)| m);
        Self {
            content: content_hash(b, &lattice_values(source)),
            density_scale,
            local_to_world,
            box_min: b.min.to_array(),
            box_max: b.max.to_array(),
        }
    }

    /// The metadata `extra` pairs, in key order.
    pub fn to_extra(&self) -> Vec<(String, String)> {
        let mut bx = self.box_min.to_vec();
        bx.extend_from_slice(&self.box_max);
        vec![
            (KEY_BOX.into(), join(&bx)),
            (KEY_CONTENT.into(), self.content.clone()),
            (KEY_DENSITY_SCALE.into(), join(&[self.density_scale])),
            (KEY_TRANSFORM.into(), join(&self.local_to_world)),
        ]
    }

    /// The identity in `extra`: `None` when the file records none (a bake older than the
    /// identity), an error naming the key when it records a malformed one.
    pub fn from_extra(extra: &[(String, String)]) -> Option<Result<Self, String>> {
        let get = |k: &str| {
            extra
                .iter()
                .find(|(key, _)| key == k)
                .map(|(_, v)| v.as_str())
        };
        let content = get(KEY_CONTENT)?;
        let bad = |k: &str| format!("metadata {k} is malformed");
        Some((|| {
            let bx: [f64; 6] = get(KEY_BOX).and_then(split).ok_or_else(|| bad(KEY_BOX))?;
            let [density_scale] = get(KEY_DENSITY_SCALE)
                .and_then(split)
                .ok_or_else(|| bad(KEY_DENSITY_SCALE))?;
            let local_to_world = get(KEY_TRANSFORM)
                .and_then(split)
                .ok_or_else(|| bad(KEY_TRANSFORM))?;
            if content.len() != 32 || !content.bytes().all(|c| c.is_ascii_hexdigit()) {
                return Err(bad(KEY_CONTENT));
            }
            Ok(Self {
                content: content.to_string(),
                density_scale,
                local_to_world,
                box_min: [bx[0], bx[1], bx[2]],
                box_max: [bx[3], bx[4], bx[5]],
            })
        })())
    }

    /// What differs between the identity recorded with pins (`self`) and a volume's
    /// (`other`), each as "what: pins vs volume"; empty when they match.
    pub fn differences(&self, other: &Self) -> Vec<String> {
        let mut out = Vec::new();
        if self.density_scale != other.density_scale {
            out.push(format!(
                "density scale {:?} vs {:?}",
                self.density_scale, other.density_scale
            ));
        }
        if self.local_to_world != other.local_to_world {
            out.push(format!(
                "transform [{}] vs [{}]",
                join(&self.local_to_world),
                join(&other.local_to_world)
            ));
        }
        if self.box_min != other.box_min || self.box_max != other.box_max {
            out.push(format!(
                "box {:?}..{:?} vs {:?}..{:?}",
                self.box_min, self.box_max, other.box_min, other.box_max
            ));
        }
        if self.content != other.content {
            out.push(format!(
                "density content {} vs {}",
                self.content, other.content
            ));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ProceduralSpec;

    fn identity(spec: &str, scale: f64) -> SourceIdentity {
        let mut p: ProceduralSpec = spec.parse().unwrap();
        p.density *= scale;
        SourceIdentity::of(p.build(crate::DensityScale::ONE).unwrap().as_ref(), scale)
    }

    #[test]
    fn same_source_same_identity_and_it_round_trips() {
        let a = identity("cosine:seed=3", 1.0);
        assert_eq!(a, identity("cosine:seed=3", 1.0));
        assert!(a.differences(&a).is_empty());
        let back = SourceIdentity::from_extra(&a.to_extra()).unwrap().unwrap();
        assert_eq!(back, a);
        let keys: Vec<String> = a.to_extra().into_iter().map(|(k, _)| k).collect();
        let mut sorted = keys.clone();
        sorted.sort();
        assert_eq!(keys, sorted);
    }

    #[test]
    fn another_field_scale_or_box_is_told_apart() {
        let a = identity("cosine:seed=3", 1.0);
        let seed = identity("cosine:seed=4", 1.0);
        assert_eq!(a.differences(&seed).len(), 1);
        assert!(a.differences(&seed)[0].starts_with("density content"));
        let scaled = identity("cosine:seed=3", 2.0);
        let d = a.differences(&scaled);
        assert!(
            d.iter().any(|s| s.starts_with("density scale 1.0 vs 2.0")),
            "{d:?}"
        );
        assert!(d.iter().any(|s| s.starts_with("density content")), "{d:?}");
        let other = identity("box", 1.0);
        assert!(
            a.differences(&other)
                .iter()
                .any(|s| s.starts_with("density content"))
        );
    }

    #[test]
    fn absent_or_malformed_identity() {
        assert!(SourceIdentity::from_extra(&[("cells".into(), "[1, 1, 1]".into())]).is_none());
        let mut extra = identity("box", 1.0).to_extra();
        extra[0].1 = "1,2".into();
        let e = SourceIdentity::from_extra(&extra).unwrap().unwrap_err();
        assert!(e.contains(KEY_BOX), "{e}");
    }
}
