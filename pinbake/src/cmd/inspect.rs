//! `pinbake inspect` (its JSON summary is `pinbake::summary`'s, shared with `bake --json`).

use std::path::Path;
use std::process::ExitCode;

use anyhow::{Context, Result};
use pin_format::{PinFile, SectionKind};
use pinbake::summary::{directions_json, summary};
use serde_json::{Value, json};

pub fn run(path: &Path, as_json: bool) -> Result<ExitCode> {
    let bytes = super::map_pin_file(path)?;
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
    if let Some(sd) = file.sparse_density() {
        let h = sd.header;
        v["sparse_density"] = json!({
            "dims": h.dims, "brick": h.brick, "brick_count": h.brick_count,
            "brick_dims": sd.brick_dims,
            "encoding": if h.encoding == pin_format::layout::DENSITY_F32 { "f32" } else { "f16" },
        });
    }
    if let Some(c) = file.control() {
        let bricks = c.len();
        let empty = c.residual.iter().filter(|&&m| m == 0.0).count();
        // The section's length as the table records it (the parse checked it against the
        // brick count).
        let bytes = file
            .sections()
            .iter()
            .find(|s| s.kind == SectionKind::Control as u32)
            .map(|s| s.length);
        v["control"] = json!({
            "dims": c.dims, "bricks": bricks, "empty_bricks": empty, "bytes": bytes,
        });
    }
    if let Some(m) = &metadata {
        v["metadata"] = json!({
            "tool": m.tool, "tool_version": m.tool_version, "source_name": m.source_name,
            "source_hash": m.source_hash, "source_description": m.source_description,
            "seed": m.seed, "step_size": m.step_size, "density_scale": m.density_scale,
            "bake_unix_time": m.bake_unix_time, "extra": m.extra,
        });
    }
    if as_json {
        pin_cli::outln!("{v}")?;
        return Ok(ExitCode::SUCCESS);
    }
    pin_cli::outln!("{}", path.display())?;
    pin_cli::outln!("  format        {}", v["version"].as_str().unwrap_or("?"))?;
    pin_cli::outln!(
        "  grid          {} x {} x {} cells, {} directions ({}), {} pin(s) per entry",
        file.desc().dims[0],
        file.desc().dims[1],
        file.desc().dims[2],
        file.shape().directions.count(),
        directions_json(file.shape().directions),
        file.desc().pins_per_entry
    )?;
    pin_cli::outln!(
        "  box           {:?} .. {:?}{}",
        file.desc().box_min,
        file.desc().box_max,
        if v["cropped"] == json!(true) {
            " (cropped)"
        } else {
            ""
        }
    )?;
    pin_cli::outln!(
        "  cells         {} covered, {} stored, {} empty ({:.1}% sparse)",
        v["covered_cells"],
        v["stored_cells"],
        v["empty_cells"],
        v["sparse_fraction"].as_f64().unwrap_or(0.0) * 100.0
    )?;
    pin_cli::outln!("  pins          {} stored", v["pins"])?;
    pin_cli::outln!(
        "  t_min         min {:.6}  max {:.6}  mean {:.6}",
        v["t_min"]["min"].as_f64().unwrap_or(f64::NAN),
        v["t_min"]["max"].as_f64().unwrap_or(f64::NAN),
        v["t_min"]["mean"].as_f64().unwrap_or(f64::NAN)
    )?;
    pin_cli::outln!(
        "  t_min histogram (10 bins over [0,1]): {}",
        v["t_min"]["histogram"]
    )?;
    pin_cli::outln!("  sections")?;
    for s in file.sections() {
        let name = SectionKind::from_u32(s.kind)
            .map(|k| k.name().to_string())
            .unwrap_or_else(|| format!("unknown({})", s.kind));
        pin_cli::outln!(
            "    {name:<12} offset {:>12}  length {:>12}  xxh3 {:016x}",
            s.offset,
            s.length,
            s.checksum
        )?;
    }
    if let Some(sd) = v.get("sparse_density") {
        pin_cli::outln!(
            "  sparse density {} voxels, {} bricks of {}^3 ({})",
            sd["dims"],
            sd["brick_count"],
            sd["brick"],
            sd["encoding"].as_str().unwrap_or("?")
        )?;
    }
    if let Some(c) = v.get("control") {
        pin_cli::outln!(
            "  control       {} bricks, {} of them empty (residual ratio tracking: pinres)",
            c["dims"],
            c["empty_bricks"]
        )?;
    }
    if let Some(m) = metadata {
        pin_cli::outln!(
            "  source        {} ({}) hash {}",
            m.source_name,
            m.source_description,
            if m.source_hash.is_empty() {
                "-"
            } else {
                &m.source_hash
            }
        )?;
        pin_cli::outln!(
            "  baked by      {} {}, seed {}, step {}, density scale {}",
            m.tool,
            m.tool_version,
            m.seed,
            m.step_size,
            m.density_scale
        )?;
    }
    pin_cli::outln!("  file          {} bytes", bytes.len())?;
    Ok(ExitCode::SUCCESS)
}
