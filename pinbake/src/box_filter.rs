//! The box filter of an embedded density below the source's resolution: each embedded voxel
//! the mean of the source's field over it, at a fixed set of points summed in a fixed order.
//! A leaf: the dense and sparse embeddings (`embed_density`, `sparse_density`) both read it.

use glam::DVec3;

use pin_volume::DensitySource;

/// Sub-samples per axis at most of the box filter ([`filter_samples`]): a voxel 16 source
/// voxels wide or wider averages 16^3 points of the source's field.
pub const MAX_FILTER_SAMPLES: u32 = 16;

/// Sub-samples per axis of the box filter for embedded voxels of `spacing` over `source`:
/// the source's voxels one embedded voxel spans (rounded up), 1 at or above the source's
/// resolution and for an analytic field (no voxels: sampled at the centre, as before).
pub fn filter_samples(source: &dyn DensitySource, spacing: DVec3) -> [u32; 3] {
    let Some(v) = source
        .voxel_size()
        .filter(|v| v.is_finite() && v.cmpgt(DVec3::ZERO).all())
    else {
        return [1; 3];
    };
    [0, 1, 2].map(|a| {
        let r = spacing[a] / v[a] - 1e-6;
        if r.is_finite() {
            r.ceil().clamp(1.0, f64::from(MAX_FILTER_SAMPLES)) as u32
        } else {
            1
        }
    })
}

/// The embedded voxel centred at `centre` with `spacing`: the source's value there when `sub`
/// is 1 on every axis, else the mean of the source's field at the centres of `sub` equal
/// parts per axis of the voxel, a box filter. On a voxel that covers whole source voxels of
/// an aligned lattice ([`crate::lattice_box`]) those points are the source's voxel centres,
/// and the value is the mean of the source's voxels. Summed in a fixed order, in f64: the
/// same value whatever the threads.
pub fn box_filtered(
    source: &dyn DensitySource,
    centre: DVec3,
    spacing: DVec3,
    sub: [u32; 3],
) -> f32 {
    if sub == [1; 3] {
        return source.extinction(centre);
    }
    let k = sub.map(f64::from);
    let step = spacing / DVec3::new(k[0], k[1], k[2]);
    let first = centre - spacing * 0.5 + step * 0.5;
    let mut row = [0f32; MAX_FILTER_SAMPLES as usize];
    let row = &mut row[..sub[0] as usize];
    let mut sum = 0f64;
    for jz in 0..sub[2] {
        for jy in 0..sub[1] {
            let o = first + DVec3::new(0.0, step.y * f64::from(jy), step.z * f64::from(jz));
            source.extinction_along(o, DVec3::new(step.x, 0.0, 0.0), row.len(), row);
            sum += row.iter().map(|&v| f64::from(v)).sum::<f64>();
        }
    }
    (sum / (k[0] * k[1] * k[2])) as f32
}
