//! The document as serde reads it. Values are checked while they are read, so that a
//! refusal carries the JSON path serde_path_to_error tracks (`camera.fov`,
//! `instances[17].transform.scale`); what needs the whole document (asset names) is checked
//! by `load.rs`.

use std::fmt;

use serde::Deserialize;
use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};

use crate::limits::{MAX_ASSETS, MAX_INSTANCES, MAX_NAME_BYTES};
use crate::ranges;
use crate::transform::{self, Trs};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawScene {
    pub assets: AssetMap,
    pub instances: InstanceList,
    #[serde(default)]
    pub camera: Option<RawCamera>,
    #[serde(default)]
    pub sun: Option<RawSun>,
    #[serde(default, deserialize_with = "radiance")]
    pub env_radiance: Option<f64>,
    #[serde(default, deserialize_with = "albedo")]
    pub albedo: Option<f64>,
    #[serde(default, deserialize_with = "hg_g")]
    pub g: Option<f64>,
    #[serde(default)]
    pub max_bounces: Option<u32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawAsset {
    #[serde(default)]
    pub volume: Option<String>,
    #[serde(default)]
    pub pins: Option<String>,
    #[serde(default, deserialize_with = "density_scale")]
    pub density_scale: Option<f64>,
    #[serde(default)]
    pub grid: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawInstance {
    pub asset: String,
    #[serde(default)]
    pub transform: Option<Transform>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawCamera {
    #[serde(default, deserialize_with = "position")]
    pub origin: Option<[f64; 3]>,
    #[serde(default, deserialize_with = "position")]
    pub target: Option<[f64; 3]>,
    #[serde(default, deserialize_with = "fov")]
    pub fov: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSun {
    #[serde(default, deserialize_with = "direction")]
    pub direction: Option<[f64; 3]>,
    #[serde(default, deserialize_with = "radiance")]
    pub radiance: Option<f64>,
}

/// A value read as `T` and passed through one of [`ranges`]' rules.
fn checked<'de, D, T>(d: D, rule: fn(T) -> Result<T, String>) -> Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    rule(T::deserialize(d)?)
        .map(Some)
        .map_err(de::Error::custom)
}

fn radiance<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    checked(d, ranges::radiance)
}
fn albedo<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    checked(d, ranges::albedo)
}
fn hg_g<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    checked(d, ranges::hg_g)
}
fn fov<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    checked(d, ranges::fov)
}
fn density_scale<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    checked(d, ranges::density_scale)
}
fn position<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    checked(d, ranges::position)
}
fn direction<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    checked(d, ranges::direction)
}

/// The `assets` object in document order; a name given twice is refused (a JSON object
/// read into a map would keep the last one silently).
pub(crate) struct AssetMap(pub Vec<(String, RawAsset)>);

impl<'de> Deserialize<'de> for AssetMap {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = AssetMap;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an object mapping asset names to {volume, pins, density_scale, grid}")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<AssetMap, A::Error> {
                let mut out: Vec<(String, RawAsset)> = Vec::new();
                while let Some(name) = map.next_key::<String>()? {
                    check_name(&name).map_err(de::Error::custom)?;
                    if out.iter().any(|(n, _)| *n == name) {
                        return Err(de::Error::custom(format!("asset {name} is given twice")));
                    }
                    if out.len() == MAX_ASSETS {
                        return Err(de::Error::custom(format!("more than {MAX_ASSETS} assets")));
                    }
                    let asset = map.next_value::<RawAsset>()?;
                    out.push((name, asset));
                }
                Ok(AssetMap(out))
            }
        }
        d.deserialize_map(V)
    }
}

/// An asset name: printable (it appears in one-line messages and JSON paths), not empty,
/// at most [`MAX_NAME_BYTES`].
pub(crate) fn check_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.len() > MAX_NAME_BYTES || name.chars().any(char::is_control) {
        return Err(format!(
            "an asset name must be 1 to {MAX_NAME_BYTES} bytes without control characters, got {name:?}"
        ));
    }
    Ok(())
}

/// The `instances` array, refused past [`MAX_INSTANCES`] while it is read.
pub(crate) struct InstanceList(pub Vec<RawInstance>);

impl<'de> Deserialize<'de> for InstanceList {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = InstanceList;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an array of {asset, transform}")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<InstanceList, A::Error> {
                // The hint comes from the document: trusted only up to a small reserve.
                let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(4096));
                while let Some(inst) = seq.next_element::<RawInstance>()? {
                    if out.len() == MAX_INSTANCES {
                        return Err(de::Error::custom(format!(
                            "more than {MAX_INSTANCES} instances"
                        )));
                    }
                    out.push(inst);
                }
                Ok(InstanceList(out))
            }
        }
        d.deserialize_seq(V)
    }
}

/// A checked local-to-world, read from 12 numbers or from `{translate, rotate_deg, scale}`.
pub(crate) struct Transform(pub [f64; 12]);

const TRANSFORM_FORMS: &str =
    "12 numbers (row-major 3x4 local-to-world) or {\"translate\", \"rotate_deg\", \"scale\"}";

impl<'de> Deserialize<'de> for Transform {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Transform;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(TRANSFORM_FORMS)
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Transform, A::Error> {
                let mut m = [0.0; 12];
                let mut n = 0;
                while let Some(v) = seq.next_element::<f64>()? {
                    if n == 12 {
                        return Err(de::Error::custom(
                            "a matrix transform has 12 numbers (row-major 3x4), got more",
                        ));
                    }
                    m[n] = v;
                    n += 1;
                }
                if n != 12 {
                    return Err(de::Error::custom(format!(
                        "a matrix transform has 12 numbers (row-major 3x4), got {n}"
                    )));
                }
                transform::check(&m).map_err(de::Error::custom)?;
                Ok(Transform(m))
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Transform, A::Error> {
                let mut t = Trs::default();
                let mut seen = [false; 3];
                while let Some(key) = map.next_key::<String>()? {
                    let slot = match key.as_str() {
                        "translate" => 0,
                        "rotate_deg" => 1,
                        "scale" => 2,
                        _ => {
                            return Err(de::Error::custom(format!(
                                "unknown key {key:?}, expected translate, rotate_deg or scale"
                            )));
                        }
                    };
                    if std::mem::replace(&mut seen[slot], true) {
                        return Err(de::Error::custom(format!("{key} is given twice")));
                    }
                    match slot {
                        0 => t.translate = map.next_value()?,
                        1 => t.rotate_deg = map.next_value()?,
                        _ => t.scale = map.next_value::<Scale>()?.0,
                    }
                }
                if t.rotate_deg.iter().any(|a| !(a.abs() <= 360.0 * 1e6)) {
                    return Err(de::Error::custom(
                        "rotate_deg must be finite degrees (within +-3.6e8)",
                    ));
                }
                let m = transform::compose_trs(&t);
                transform::check(&m).map_err(de::Error::custom)?;
                Ok(Transform(m))
            }
        }
        d.deserialize_any(V)
    }
}

/// `scale`: one number for all three axes, or three.
struct Scale([f64; 3]);

impl<'de> Deserialize<'de> for Scale {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Scale;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number or 3 numbers")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Scale, E> {
                Ok(Scale([v; 3]))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Scale, E> {
                Ok(Scale([v as f64; 3]))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Scale, E> {
                Ok(Scale([v as f64; 3]))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<Scale, A::Error> {
                <[f64; 3]>::deserialize(de::value::SeqAccessDeserializer::new(seq)).map(Scale)
            }
        }
        d.deserialize_any(V)
    }
}
