//! `pinrt._native`: the compiled half of the `pinrt` Python package. The typed, documented
//! API is `py/pinrt/__init__.py`, which normalises arguments (dtypes, shapes, contiguity)
//! before calling these functions; they still check everything they rely on.
//!
//! Queries run through `pinrt::Sampler`'s batch methods with the GIL released, so the numbers
//! are the Rust sampler's bit for bit (same rays, seed and first index).

use std::path::{Path, PathBuf};
use std::time::Instant;

use numpy::{
    PyArray1, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods,
};
use pin_format::{Directions, GridShape, OwnedPinGrid};
use pinbake::source::{
    self, DenseGrid, DensitySource, Endian, ProceduralSpec, RawOptions, RawType, SourceSpec,
    VdbOptions,
};
use pinbake::{BakeOptions, BakeStats};
use pinrt::{PinGrid as RtGrid, RayQuery, SamplerOptions};
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use serde_json::{Value, json};

pyo3::create_exception!(
    _native,
    PinError,
    PyException,
    "A pin file, volume or bake failed; the message is the library's one-line error."
);

fn pin_err(e: impl std::fmt::Display) -> PyErr {
    PinError::new_err(e.to_string().replace(['\n', '\r'], " "))
}

fn value_err(msg: impl Into<String>) -> PyErr {
    PyValueError::new_err(msg.into())
}

/// An open pin grid (memory-mapped, or a copy of bytes).
#[pyclass(frozen, module = "pinrt._native")]
struct PinGrid {
    grid: RtGrid,
}

/// Checks an (N, 3) array and returns its contiguous f32 values.
fn rows3<'a>(a: &'a PyReadonlyArray2<'_, f32>, what: &str) -> PyResult<&'a [f32]> {
    let shape = a.shape();
    if shape[1] != 3 {
        return Err(value_err(format!(
            "{what} must have shape (N, 3), got {shape:?}"
        )));
    }
    a.as_slice()
        .map_err(|_| value_err(format!("{what} must be C-contiguous")))
}

fn ray_queries(o: &[f32], d: &[f32], t: &[f32]) -> Vec<RayQuery> {
    o.chunks_exact(3)
        .zip(d.chunks_exact(3))
        .zip(t)
        .map(|((o, d), &t)| RayQuery::new([o[0], o[1], o[2]], [d[0], d[1], d[2]], t))
        .collect()
}

/// The lookup options beside the jitter (`pinrt::SamplerOptions`, docs/sampling.md sections
/// 12 and 14).
#[derive(Clone, Copy)]
struct Lookup {
    chain_stride: u32,
    middle: bool,
    start_inside: bool,
    nearest_line: u32,
}

impl Lookup {
    fn parse(
        chain_stride: u32,
        lookup_point: &str,
        start_inside: bool,
        nearest_line: u32,
    ) -> PyResult<Self> {
        let max = pinrt::lookup::MAX_NEAREST_LINE_STEPS;
        if nearest_line > max {
            return Err(value_err(format!(
                "nearest_line is {nearest_line}; it must be at most {max}"
            )));
        }
        let middle = match lookup_point {
            "start" => false,
            "middle" => true,
            other => {
                return Err(value_err(format!(
                    "lookup_point is '{other}'; it must be 'start' or 'middle'"
                )));
            }
        };
        Ok(Self {
            chain_stride,
            middle,
            start_inside,
            nearest_line,
        })
    }
}

#[derive(Clone, Copy)]
enum Query {
    Transmittance,
    Distance,
}

impl PinGrid {
    #[allow(clippy::too_many_arguments)]
    fn run<'py>(
        &self,
        py: Python<'py>,
        origins: PyReadonlyArray2<'py, f32>,
        directions: PyReadonlyArray2<'py, f32>,
        t_max: PyReadonlyArray1<'py, f32>,
        seed: u32,
        first_index: u32,
        spatial_jitter: f32,
        directional_jitter: f32,
        lookup: Lookup,
        kind: Query,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let o = rows3(&origins, "origins")?;
        let d = rows3(&directions, "directions")?;
        let t = t_max
            .as_slice()
            .map_err(|_| value_err("t_max must be C-contiguous"))?;
        let n = o.len() / 3;
        if d.len() / 3 != n || t.len() != n {
            return Err(value_err(format!(
                "origins, directions and t_max disagree on N: {n}, {}, {}",
                d.len() / 3,
                t.len()
            )));
        }
        for (name, v) in [
            ("spatial_jitter", spatial_jitter),
            ("directional_jitter", directional_jitter),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(value_err(format!(
                    "{name} is {v}; it must be finite and >= 0"
                )));
            }
        }
        let grid = &self.grid;
        // The GIL is released for the copy into ray records and the queries: other Python
        // threads run meanwhile (the NumPy inputs are borrowed read-only for the duration).
        let out: PyResult<Vec<f32>> = py.detach(|| {
            let rays = ray_queries(o, d, t);
            let s = grid
                .sampler()
                .map_err(pin_err)?
                .with_options(SamplerOptions {
                    spatial_jitter,
                    directional_jitter,
                    chain_stride: lookup.chain_stride,
                    midpoint_lookup: lookup.middle,
                    start_inside: lookup.start_inside,
                    nearest_line: lookup.nearest_line,
                });
            let mut out = vec![0f32; n];
            match kind {
                Query::Transmittance => s.transmittance_batch(&rays, seed, first_index, &mut out),
                Query::Distance => {
                    let mut tmp = vec![None; n];
                    s.sample_distance_batch(&rays, seed, first_index, &mut tmp);
                    for (o, v) in out.iter_mut().zip(tmp) {
                        *o = v.unwrap_or(f32::INFINITY);
                    }
                }
            }
            Ok(out)
        });
        Ok(PyArray1::from_vec(py, out?))
    }
}

#[pymethods]
impl PinGrid {
    /// Opens (memory-maps) a pin file.
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let grid = py.detach(|| RtGrid::open(&path)).map_err(pin_err)?;
        Ok(Self { grid })
    }

    /// A grid from the bytes of a pin file (copied).
    #[staticmethod]
    fn from_bytes(data: &[u8]) -> PyResult<Self> {
        Ok(Self {
            grid: RtGrid::from_bytes(data.to_vec()).map_err(pin_err)?,
        })
    }

    /// Full check of every checksum and value (linear in the file size).
    fn verify(&self, py: Python<'_>) -> PyResult<()> {
        py.detach(|| self.grid.verify()).map_err(pin_err)
    }

    /// The grid description as JSON (see `PinGrid.info` in the Python layer).
    fn info_json(&self) -> PyResult<String> {
        let d = self.grid.desc();
        let s = self.grid.shape();
        let bounds = self.grid.sampler().map_err(pin_err)?.world_bounds();
        let v = json!({
            "dims": d.dims,
            "directions": directions_json(s.directions),
            "pins_per_entry": d.pins_per_entry,
            "pins": self.grid.pins().len(),
            "stored_cells": d.stored_cells,
            "covered_cells": s.covered_cells,
            "z_range": [s.z_begin, s.z_end],
            "sparse": self.grid.cell_index().is_some(),
            "mapped": self.grid.is_mapped(),
            "file_bytes": self.grid.bytes().len(),
            "box": {"min": d.box_min, "max": d.box_max},
            "local_to_world": d.local_to_world,
            "world_box": bounds.map(|(a, b)| json!({"min": a, "max": b})),
            "step_size": d.step_size,
            "density_scale": d.density_scale,
            "seed": d.seed,
            "path": self.grid.path().map(|p| p.display().to_string()),
        });
        Ok(v.to_string())
    }

    #[pyo3(signature = (origins, directions, t_max, seed, first_index, spatial_jitter, directional_jitter, chain_stride, lookup_point, start_inside, nearest_line = 0))]
    #[allow(clippy::too_many_arguments)]
    fn transmittance<'py>(
        &self,
        py: Python<'py>,
        origins: PyReadonlyArray2<'py, f32>,
        directions: PyReadonlyArray2<'py, f32>,
        t_max: PyReadonlyArray1<'py, f32>,
        seed: u32,
        first_index: u32,
        spatial_jitter: f32,
        directional_jitter: f32,
        chain_stride: u32,
        lookup_point: &str,
        start_inside: bool,
        nearest_line: u32,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let lookup = Lookup::parse(chain_stride, lookup_point, start_inside, nearest_line)?;
        self.run(
            py,
            origins,
            directions,
            t_max,
            seed,
            first_index,
            spatial_jitter,
            directional_jitter,
            lookup,
            Query::Transmittance,
        )
    }

    #[pyo3(signature = (origins, directions, t_max, seed, first_index, spatial_jitter, directional_jitter, chain_stride, lookup_point, start_inside, nearest_line = 0))]
    #[allow(clippy::too_many_arguments)]
    fn sample_distance<'py>(
        &self,
        py: Python<'py>,
        origins: PyReadonlyArray2<'py, f32>,
        directions: PyReadonlyArray2<'py, f32>,
        t_max: PyReadonlyArray1<'py, f32>,
        seed: u32,
        first_index: u32,
        spatial_jitter: f32,
        directional_jitter: f32,
        chain_stride: u32,
        lookup_point: &str,
        start_inside: bool,
        nearest_line: u32,
    ) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let lookup = Lookup::parse(chain_stride, lookup_point, start_inside, nearest_line)?;
        self.run(
            py,
            origins,
            directions,
            t_max,
            seed,
            first_index,
            spatial_jitter,
            directional_jitter,
            lookup,
            Query::Distance,
        )
    }
}

fn directions_json(d: Directions) -> Value {
    match d {
        Directions::Polar { n_phi, n_theta } => {
            json!({"kind": "polar", "n_phi": n_phi, "n_theta": n_theta})
        }
        Directions::Octahedral { n } => json!({"kind": "octahedral", "n": n}),
    }
}

/// The summary object of `pinbake bake --json` (same keys and meanings; written again here
/// because the CLI's lives in the pinbake binary, not its library).
fn summary_json(
    grid: &OwnedPinGrid,
    file_bytes: u64,
    stats: &BakeStats,
    seconds: f64,
    output: &Path,
) -> PyResult<Value> {
    let desc = &grid.desc;
    let shape = GridShape::new(desc, grid.tile.as_ref()).map_err(pin_err)?;
    let total = shape.covered_cells * shape.block_len;
    let (mut min, mut max, mut sum) = (f64::INFINITY, f64::NEG_INFINITY, 0.0);
    let mut histogram = [0u64; 10];
    let mut add = |t: f64, n: u64| {
        min = min.min(t);
        max = max.max(t);
        sum += t * n as f64;
        histogram[((t * 10.0) as usize).min(9)] += n;
    };
    for p in &grid.pins {
        add(f64::from(p.t_min), 1);
    }
    // Pins of empty (unstored) cells count as t_min = 1, as in the CLI.
    let empty_pins = total.saturating_sub(grid.pins.len() as u64);
    if empty_pins > 0 || grid.pins.is_empty() {
        add(1.0, empty_pins);
    }
    let mean = if total > 0 { sum / total as f64 } else { 1.0 };
    let empty = shape.covered_cells - desc.stored_cells;
    let whole = shape.z_begin == 0 && shape.z_end == desc.dims[2];
    Ok(json!({
        "dims": desc.dims,
        "directions": directions_json(shape.directions),
        "pins_per_entry": desc.pins_per_entry,
        "pins": grid.pins.len(),
        "covered_cells": shape.covered_cells,
        "stored_cells": desc.stored_cells,
        "empty_cells": empty,
        "sparse_fraction": if shape.covered_cells > 0 { empty as f64 / shape.covered_cells as f64 } else { 0.0 },
        "file_bytes": file_bytes,
        "t_min": {"min": min, "max": max, "mean": mean, "histogram": histogram},
        "box": {"min": desc.box_min, "max": desc.box_max},
        "source_box": {"min": desc.source_box_min, "max": desc.source_box_max},
        "cropped": desc.flags & pin_format::layout::GRID_FLAG_CROPPED != 0,
        "step_size": desc.step_size,
        "density_scale": desc.density_scale,
        "seed": desc.seed,
        "tile": if whole { Value::Null } else { json!([shape.z_begin, shape.z_end]) },
        "source": grid.metadata.as_ref().map(|m| m.source_name.clone()),
        "seconds": seconds,
        "bake_seconds": stats.seconds,
        "pins_per_s": stats.pins_per_s,
        "output": output.display().to_string(),
    }))
}

fn parse_dirs(s: &str) -> PyResult<Directions> {
    let bad = |m: String| value_err(format!("directions '{s}': {m}"));
    let (kind, res) = s
        .split_once(':')
        .ok_or_else(|| bad("expected polar:PHIxTHETA or octahedral:N".into()))?;
    let num = |x: &str| {
        x.trim()
            .parse::<u32>()
            .map_err(|e| bad(format!("'{x}': {e}")))
    };
    let d = match kind {
        "polar" => {
            let (a, b) = res
                .split_once('x')
                .ok_or_else(|| bad("polar needs PHIxTHETA, e.g. 16x4".into()))?;
            Directions::Polar {
                n_phi: num(a)?,
                n_theta: num(b)?,
            }
        }
        "octahedral" | "oct" => Directions::Octahedral { n: num(res)? },
        other => return Err(bad(format!("unknown parametrisation '{other}'"))),
    };
    let (k, r) = d.to_desc();
    Directions::from_desc(k, r).map_err(|e| bad(e.to_string()))
}

/// Hex xxh3-128 of a file (the metadata's source hash, as the CLI records it).
fn hash_file(path: &Path) -> PyResult<String> {
    use std::io::Read;
    let io = |e: std::io::Error| pin_err(format!("{}: {e}", path.display()));
    let mut f = std::fs::File::open(path).map_err(io)?;
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(io)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(format!("{:032x}", h.digest128()))
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Bakes `input` (a file path, `procedural:SPEC`, or `<array>` with `data`) into `output` and
/// returns the JSON summary. Options as `pinbake bake`'s flags; the Python layer documents
/// them.
#[pyfunction]
#[pyo3(signature = (
    input, output, *, data=None, spacing=None, origin=None, cells=None,
    directions=None, pins_per_entry=None, step=0.01, seed=0, crop=true,
    center_pins=true, majorant=[16, 16, 16], embed_density=None, density_scale=1.0,
    threads=None, grid=None, levelset_to_fog=false, dims=None, voxel_type=None,
    endian="little", clamp_negative=false, nan_as_zero=false, vdb_worker=None
))]
#[allow(clippy::too_many_arguments)]
fn bake(
    py: Python<'_>,
    input: &str,
    output: PathBuf,
    data: Option<PyReadonlyArray3<'_, f32>>,
    spacing: Option<[f64; 3]>,
    origin: Option<[f64; 3]>,
    cells: Option<[u32; 3]>,
    directions: Option<&str>,
    pins_per_entry: Option<u32>,
    step: f64,
    seed: u64,
    crop: bool,
    center_pins: bool,
    majorant: [u32; 3],
    embed_density: Option<[u32; 3]>,
    density_scale: f64,
    threads: Option<usize>,
    grid: Option<String>,
    levelset_to_fog: bool,
    dims: Option<[u32; 3]>,
    voxel_type: Option<&str>,
    endian: &str,
    clamp_negative: bool,
    nan_as_zero: bool,
    vdb_worker: Option<PathBuf>,
) -> PyResult<String> {
    if !(density_scale.is_finite() && density_scale >= 0.0) {
        return Err(value_err(format!(
            "density_scale {density_scale} must be finite and >= 0"
        )));
    }
    if pins_per_entry.is_some_and(|k| k == 0 || k > pin_format::MAX_PINS_PER_ENTRY) {
        return Err(value_err(format!(
            "pins_per_entry must be in 1..={}",
            pin_format::MAX_PINS_PER_ENTRY
        )));
    }
    if !(step > 0.0 && step <= 1.0) {
        return Err(value_err(format!("step {step} must be in (0, 1]")));
    }
    // Parameters left out are chosen from the volume below, as `pinbake bake` does.
    let dirs = directions.map(parse_dirs).transpose()?;
    let spacing = spacing.unwrap_or([1.0; 3]);
    let origin = origin.unwrap_or([0.0; 3]);

    // The source, and what the metadata records about it (as the CLI does).
    let (source, name, hash): (Box<dyn DensitySource>, String, String) = if let Some(arr) = data {
        // The Python layer passes a C-contiguous (z, y, x) view: x fastest, as DenseGrid
        // stores voxels.
        let shape = arr.shape();
        let values = arr
            .as_slice()
            .map_err(|_| value_err("data must be C-contiguous"))?
            .iter()
            .map(|&v| v * density_scale as f32)
            .collect::<Vec<f32>>();
        let d = [shape[2], shape[1], shape[0]].map(|x| x as u32);
        let g = DenseGrid::new(
            d,
            values,
            spacing.into(),
            origin.into(),
            format!("NumPy array {}x{}x{}", d[0], d[1], d[2]),
        )
        .map_err(|e| pin_err(format!("array: {e}")))?;
        (Box::new(g), "<array>".into(), String::new())
    } else if let Some(rest) = input.strip_prefix("procedural:") {
        let mut spec: ProceduralSpec = rest.parse().map_err(pin_err)?;
        spec.density *= density_scale;
        let name = format!("procedural:{spec}");
        let src = py
            .detach(|| source::open_source(&SourceSpec::Procedural(spec)))
            .map_err(pin_err)?;
        (src, name, String::new())
    } else {
        let path = PathBuf::from(input);
        let is_vdb = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("vdb"));
        let spec = if is_vdb {
            let worker = vdb_worker.ok_or_else(|| {
                value_err("reading OpenVDB needs the pinrt-vdb-worker script (vdb_worker=)")
            })?;
            SourceSpec::Vdb(
                path.clone(),
                VdbOptions {
                    grid,
                    levelset_to_fog,
                    density_scale,
                    worker_exe: worker,
                    ..VdbOptions::default()
                },
            )
        } else {
            let voxel_type = match voxel_type {
                None => None,
                Some(t) => Some(RawType::parse(t).ok_or_else(|| {
                    value_err(format!(
                        "voxel_type '{t}' is not one of u8, u16, f16, f32, f64"
                    ))
                })?),
            };
            let endian = match endian.to_ascii_lowercase().as_str() {
                "little" | "le" => Endian::Little,
                "big" | "be" => Endian::Big,
                other => return Err(value_err(format!("endian '{other}' is not little or big"))),
            };
            SourceSpec::Raw(
                path.clone(),
                RawOptions {
                    dims,
                    voxel_type,
                    endian,
                    spacing,
                    origin,
                    clamp_negative,
                    nan_as_zero,
                    density_scale,
                },
            )
        };
        let src = py.detach(|| source::open_source(&spec)).map_err(pin_err)?;
        (src, file_name(&path), hash_file(&path)?)
    };

    // What `pinbake bake` does with the same arguments: the parameters not given are chosen
    // from the volume, and the metadata is written by the same library function.
    let choice = py
        .detach(|| -> Result<pinbake::choose::Choice, pinbake::BakeError> {
            let stats = pinbake::choose::analyse(source.as_ref(), crop)?;
            let fixed = pinbake::choose::Fixed {
                cells,
                directions: dirs,
                pins_per_entry,
            };
            Ok(pinbake::choose::choose_default(&stats, fixed))
        })
        .map_err(|e| pin_err(format!("{input}: {e}")))?;
    let cells = choice.cells;
    let metadata = pinbake::bake::bake_metadata(
        source.as_ref(),
        pinbake::bake::Provenance {
            source_name: name,
            source_hash: hash,
            seed,
            step,
            density_scale,
            crop,
        },
        cells,
        choice.directions,
    );
    let mut opts = BakeOptions {
        cells,
        directions: choice.directions,
        pins_per_entry: choice.pins_per_entry,
        step,
        seed,
        crop,
        jitter_pins: !center_pins,
        tile: None,
        majorant: (majorant != [0; 3]).then_some(majorant),
        embed_density,
        threads,
        density_scale,
        metadata,
        dense_copy_bytes: 0,
    };
    // What `pinbake bake` allows by default (its default memory budget less the output and the
    // input file), so the two copy the same VDBs densely and write the same bytes.
    let input_bytes = std::fs::metadata(input).map_or(0, |m| m.len());
    opts.dense_copy_bytes = pinbake::files::default_memory_limit()
        .saturating_sub(pinbake::bake::estimate_output_bytes(&opts).saturating_add(input_bytes));
    let started = Instant::now();
    let summary = py.detach(|| -> PyResult<Value> {
        let (grid, stats) = pinbake::bake(source.as_ref(), &opts, &|_| {})
            .map_err(|e| pin_err(format!("{input}: {e}")))?;
        grid.write_atomic(&output)
            .map_err(|e| pin_err(format!("{}: {e}", output.display())))?;
        let bytes = std::fs::metadata(&output)
            .map_err(|e| pin_err(format!("{}: {e}", output.display())))?
            .len();
        summary_json(
            &grid,
            bytes,
            &stats,
            started.elapsed().as_secs_f64(),
            &output,
        )
    })?;
    Ok(summary.to_string())
}

/// The isolated OpenVDB reader (`pinrt-vdb-worker __vdb-worker FILE SELECTOR MODE`): `args`
/// are the arguments after the subcommand. Returns the process exit code.
#[pyfunction]
fn vdb_worker(args: Vec<String>) -> i32 {
    let args: Vec<std::ffi::OsString> = args.into_iter().map(Into::into).collect();
    pinbake::source::vdb::worker_main(&args)
}

/// `pinrt::SamplerOptions::RENDER` (the lookup `pinrender render` uses) as the queries'
/// keyword arguments, so that Python cannot drift from the Rust constant.
fn render_lookup<'py>(py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let r = SamplerOptions::RENDER;
    let d = pyo3::types::PyDict::new(py);
    d.set_item("spatial_jitter", r.spatial_jitter)?;
    d.set_item("directional_jitter", r.directional_jitter)?;
    d.set_item("chain_stride", r.chain_stride)?;
    d.set_item(
        "lookup_point",
        if r.midpoint_lookup { "middle" } else { "start" },
    )?;
    d.set_item("start_inside", r.start_inside)?;
    d.set_item("nearest_line", r.nearest_line)?;
    Ok(d)
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PinGrid>()?;
    m.add("RENDER_LOOKUP", render_lookup(m.py())?)?;
    m.add_function(wrap_pyfunction!(bake, m)?)?;
    m.add_function(wrap_pyfunction!(vdb_worker, m)?)?;
    m.add("PinError", m.py().get_type::<PinError>())?;
    Ok(())
}
