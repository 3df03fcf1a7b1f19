//! Where a bake lies: the box it covers and the placement rule for the box and transform it
//! records, checked before any work.

use crate::error::BakeError;
use pin_volume::{Aabb, DensitySource};

/// The box a bake covers: the source bounds, cropped to its non-empty region if asked.
pub fn bake_box(source: &dyn DensitySource, crop: bool) -> Result<(Aabb, bool), BakeError> {
    let bounds = source.bounds();
    if !bounds.is_valid() {
        return Err(BakeError::Bounds(bounds));
    }
    if !crop {
        return Ok((bounds, false));
    }
    match source.occupied_bounds() {
        Some(o) => {
            let min = o.min.max(bounds.min);
            let max = o.max.min(bounds.max);
            let b = Aabb::new(min, max);
            // A field with nothing in it keeps the source box: an all-empty grid is valid.
            if b.is_valid() {
                Ok((b, b != bounds))
            } else {
                Ok((bounds, false))
            }
        }
        None => Ok((bounds, false)),
    }
}

/// The placement rule of every grid ([`pin_format::check_placement`], which readers apply at
/// open and `verify`) for the box and transform a bake of `source` will record, before the
/// bake starts: finite, invertible, within what f32 queries can represent.
pub fn check_source_placement(source: &dyn DensitySource, crop: bool) -> Result<(), BakeError> {
    let (bbox, local_to_world) = match source.bake_frame() {
        None => (
            bake_box(source, crop)?.0,
            pin_format::IDENTITY_LOCAL_TO_WORLD,
        ),
        Some((local, m)) => (bake_box(local.as_ref(), crop)?.0, m),
    };
    pin_format::check_placement(bbox.min.to_array(), bbox.max.to_array(), &local_to_world)
        .map_err(BakeError::Placement)
}
