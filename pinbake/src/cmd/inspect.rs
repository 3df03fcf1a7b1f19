//! `pinbake inspect` and the JSON summary shared with `bake --json`.

use std::path::Path;
use std::process::ExitCode;

use anyhow::{Context, Result};
use pin_format::{Directions, GridShape, OwnedPinGrid, PinEntry, PinFile, SectionKind};
use serde_json::{Value, json};

use pinbake::BakeStats;

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

pub(crate) fn directions_json(d: Directions) -> Value {
    match d {
        Directions::Polar { n_phi, n_theta } => {
            json!({"kind": "polar", "n_phi": n_phi, "n_theta": n_theta})
        }
        Directions::Octahedral { n } => json!({"kind": "octahedral", "n": n}),
    }
}

/// The JSON object scripts rely on (see the README and `--help`).
pub fn summary_json(grid: &OwnedPinGrid, file_bytes: u64, stats: Option<&BakeStats>) -> Value {
    let shape = GridShape::new(&grid.desc, grid.tile.as_ref()).expect("validated grid");
    summary(
        &grid.desc,
        &shape,
        &grid.pins,
        file_bytes,
        grid.metadata.as_ref().map(|m| m.source_name.clone()),
        stats,
    )
}

fn summary(
    desc: &pin_format::GridDesc,
    shape: &GridShape,
    pins: &[PinEntry],
    file_bytes: u64,
    source: Option<String>,
    _stats: Option<&BakeStats>,
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
        "box": {"min": desc.box_min, "max": desc.box_max},
        "source_box": {"min": desc.source_box_min, "max": desc.source_box_max},
        "cropped": desc.flags & pin_format::layout::GRID_FLAG_CROPPED != 0,
        "step_size": desc.step_size,
        "density_scale": desc.density_scale,
        "seed": desc.seed,
        "tile": if shape.z_begin == 0 && shape.z_end == desc.dims[2] { Value::Null } else { json!([shape.z_begin, shape.z_end]) },
        "source": source,
    })
}

pub fn run(path: &Path, as_json: bool) -> Result<ExitCode> {
    let bytes = super::read_file(path, &pinbake::files::MemoryBudget::new(None))?;
    let file = PinFile::parse(&bytes).with_context(|| format!("{}", path.display()))?;
    let metadata = file
        .metadata()
        .transpose()
        .with_context(|| format!("{}", path.display()))?;
    let mut v = summary(
        file.desc(),
        file.shape(),
        file.pins(),
        bytes.len() as u64,
        metadata.as_ref().map(|m| m.source_name.clone()),
        None,
    );
    let sections: Vec<Value> = file
        .sections()
        .iter()
        .map(|s| {
            json!({
                "kind": SectionKind::from_u32(s.kind).map(|k| k.name().to_string()).unwrap_or_else(|| format!("unknown({})", s.kind)),
                "offset": s.offset,
                "length": s.length,
                "checksum": format!("{:016x}", s.checksum),
            })
        })
        .collect();
    v["sections"] = Value::Array(sections);
    v["version"] = json!(format!(
        "{}.{}",
        file.header().version_major,
        file.header().version_minor
    ));
    if let Some(m) = &metadata {
        v["metadata"] = json!({
            "tool": m.tool, "tool_version": m.tool_version, "source_name": m.source_name,
            "source_hash": m.source_hash, "source_description": m.source_description,
            "seed": m.seed, "step_size": m.step_size, "density_scale": m.density_scale,
            "bake_unix_time": m.bake_unix_time, "extra": m.extra,
        });
    }
    if as_json {
        pinbake::outln!("{v}")?;
        return Ok(ExitCode::SUCCESS);
    }
    pinbake::outln!("{}", path.display())?;
    pinbake::outln!("  format        {}", v["version"].as_str().unwrap_or("?"))?;
    pinbake::outln!(
        "  grid          {} x {} x {} cells, {} directions ({}), {} pin(s) per entry",
        file.desc().dims[0],
        file.desc().dims[1],
        file.desc().dims[2],
        file.shape().directions.count(),
        directions_json(file.shape().directions),
        file.desc().pins_per_entry
    )?;
    pinbake::outln!(
        "  box           {:?} .. {:?}{}",
        file.desc().box_min,
        file.desc().box_max,
        if v["cropped"] == json!(true) {
            " (cropped)"
        } else {
            ""
        }
    )?;
    pinbake::outln!(
        "  cells         {} covered, {} stored, {} empty ({:.1}% sparse)",
        v["covered_cells"],
        v["stored_cells"],
        v["empty_cells"],
        v["sparse_fraction"].as_f64().unwrap_or(0.0) * 100.0
    )?;
    pinbake::outln!("  pins          {} stored", v["pins"])?;
    pinbake::outln!(
        "  t_min         min {:.6}  max {:.6}  mean {:.6}",
        v["t_min"]["min"].as_f64().unwrap_or(f64::NAN),
        v["t_min"]["max"].as_f64().unwrap_or(f64::NAN),
        v["t_min"]["mean"].as_f64().unwrap_or(f64::NAN)
    )?;
    pinbake::outln!(
        "  t_min histogram (10 bins over [0,1]): {}",
        v["t_min"]["histogram"]
    )?;
    pinbake::outln!("  sections")?;
    for s in file.sections() {
        let name = SectionKind::from_u32(s.kind)
            .map(|k| k.name().to_string())
            .unwrap_or_else(|| format!("unknown({})", s.kind));
        pinbake::outln!(
            "    {name:<12} offset {:>12}  length {:>12}  xxh3 {:016x}",
            s.offset,
            s.length,
            s.checksum
        )?;
    }
    if let Some(m) = metadata {
        pinbake::outln!(
            "  source        {} ({}) hash {}",
            m.source_name,
            m.source_description,
            if m.source_hash.is_empty() {
                "-"
            } else {
                &m.source_hash
            }
        )?;
        pinbake::outln!(
            "  baked by      {} {}, seed {}, step {}, density scale {}",
            m.tool,
            m.tool_version,
            m.seed,
            m.step_size,
            m.density_scale
        )?;
    }
    pinbake::outln!("  file          {} bytes", bytes.len())?;
    Ok(ExitCode::SUCCESS)
}
