//! The JSON summary of a pin grid: what `pinbake bake --json`, `pinbake inspect --json` and
//! Python's `pinrt.bake` report, written once here (scripts rely on its keys; see the README).

use pin_format::{Directions, GridShape, OwnedPinGrid, PinEntry};
use serde_json::{Value, json};

use crate::choose::Choice;

/// t_min statistics over every pin of the covered cells; pins of empty cells count as 1.
struct TminStats {
    min: f64,
    max: f64,
    mean: f64,
    /// Ten bins over [0, 1]; the last bin includes 1.
    histogram: [u64; 10],
}

fn tmin_stats(pins: &[PinEntry], total_pins: u64) -> TminStats {
    let mut s = TminStats {
        min: f64::INFINITY,
        max: f64::NEG_INFINITY,
        mean: 0.0,
        histogram: [0; 10],
    };
    let mut sum = 0.0;
    let mut add = |t: f64, n: u64| {
        s.min = s.min.min(t);
        s.max = s.max.max(t);
        sum += t * n as f64;
        s.histogram[((t * 10.0) as usize).min(9)] += n;
    };
    for p in pins {
        add(f64::from(p.t_min), 1);
    }
    let empty = total_pins.saturating_sub(pins.len() as u64);
    if empty > 0 || pins.is_empty() {
        add(1.0, empty);
    }
    s.mean = if total_pins > 0 {
        sum / total_pins as f64
    } else {
        1.0
    };
    s
}

pub fn directions_json(d: Directions) -> Value {
    match d {
        Directions::Polar { n_phi, n_theta } => {
            json!({"kind": "polar", "n_phi": n_phi, "n_theta": n_theta})
        }
        Directions::Octahedral { n } => json!({"kind": "octahedral", "n": n}),
    }
}

/// The JSON object scripts rely on (see the README and `--help`). An error if the grid's
/// description does not hold together (a grid built by hand, not by the baker).
pub fn summary_json(
    grid: &OwnedPinGrid,
    file_bytes: u64,
) -> Result<Value, pin_format::FormatError> {
    let shape = GridShape::new(&grid.desc, grid.tile.as_ref())?;
    Ok(summary(
        &grid.desc,
        &shape,
        &grid.pins,
        file_bytes,
        grid.metadata.as_ref().map(|m| m.source_name.clone()),
    ))
}

pub fn summary(
    desc: &pin_format::GridDesc,
    shape: &GridShape,
    pins: &[PinEntry],
    file_bytes: u64,
    source: Option<String>,
) -> Value {
    let total_pins = shape.covered_cells * shape.block_len;
    let t = tmin_stats(pins, total_pins);
    let empty = shape.covered_cells - desc.stored_cells;
    json!({
        "dims": desc.dims,
        "directions": directions_json(shape.directions),
        "pins_per_entry": desc.pins_per_entry,
        "pins": pins.len(),
        "covered_cells": shape.covered_cells,
        "stored_cells": desc.stored_cells,
        "empty_cells": empty,
        "sparse_fraction": if shape.covered_cells > 0 { empty as f64 / shape.covered_cells as f64 } else { 0.0 },
        "file_bytes": file_bytes,
        "t_min": {"min": t.min, "max": t.max, "mean": t.mean, "histogram": t.histogram},
        // `box` and `source_box` are in the volume's local frame (`local_to_world` places
        // them); `world_box` is the box as placed, axis-aligned around it when rotated.
        "box": {"min": desc.box_min, "max": desc.box_max, "frame": "local"},
        "source_box": {"min": desc.source_box_min, "max": desc.source_box_max, "frame": "local"},
        "world_box": world_box(desc),
        "local_to_world": desc.local_to_world,
        "cropped": desc.flags & pin_format::layout::GRID_FLAG_CROPPED != 0,
        "step_size": desc.step_size,
        "density_scale": desc.density_scale,
        "seed": desc.seed,
        "tile": if shape.z_begin == 0 && shape.z_end == desc.dims[2] { Value::Null } else { json!([shape.z_begin, shape.z_end]) },
        "source": source,
    })
}

/// The grid box placed by the row-major 3x4 `local_to_world`: the axis-aligned box around
/// its eight transformed corners, in f64 (`{"min", "max", "frame": "world"}`).
pub fn world_box(desc: &pin_format::GridDesc) -> Value {
    let m = &desc.local_to_world;
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for corner in 0..8 {
        let p = [0, 1, 2].map(|a| {
            if corner >> a & 1 == 0 {
                desc.box_min[a]
            } else {
                desc.box_max[a]
            }
        });
        for r in 0..3 {
            let w = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
            lo[r] = lo[r].min(w);
            hi[r] = hi[r].max(w);
        }
    }
    json!({"min": lo, "max": hi, "frame": "world"})
}

/// The `choice` object of a bake's summary: what was chosen, why, and what the model
/// predicts.
pub fn choice_json(c: &Choice, file_bytes: u64) -> Value {
    json!({
        "cells": c.cells,
        "directions": directions_json(c.directions),
        "pins_per_entry": c.pins_per_entry,
        "predicted_error": c.predicted_error,
        "target_error": c.target_error,
        "target_met": c.target_met,
        "capped_by_voxels": c.capped_by_voxels,
        "warning": c.warning,
        "predicted_pin_bytes": c.predicted_pin_bytes,
        "bytes": file_bytes,
        "reason": {
            "cells": c.reason_cells,
            "directions": c.reason_directions,
            "pins_per_entry": c.reason_pins_per_entry,
        },
        "volume": c.stats,
        // The default asset's choice: what it chose and each alternative it weighed with its
        // predicted error (null when the bake's parameters were named).
        "asset": c.asset,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_world_box_is_the_placed_local_box() {
        let mut desc: pin_format::GridDesc = bytemuck::Zeroable::zeroed();
        desc.box_min = [0.0, 0.0, 0.0];
        desc.box_max = [2.0, 1.0, 3.0];
        // A quarter turn about z (x -> y, y -> -x), then a shift by (10, 20, 30).
        desc.local_to_world = [
            0.0, -1.0, 0.0, 10.0, //
            1.0, 0.0, 0.0, 20.0, //
            0.0, 0.0, 1.0, 30.0,
        ];
        let w = world_box(&desc);
        assert_eq!(w["min"], json!([9.0, 20.0, 30.0]));
        assert_eq!(w["max"], json!([10.0, 22.0, 33.0]));
        assert_eq!(w["frame"], "world");
    }
}
