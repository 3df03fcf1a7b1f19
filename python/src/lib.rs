//! `pinrt._native`: the compiled half of the `pinrt` Python package. The typed, documented
//! API is `py/pinrt/__init__.py`, which normalises arguments (dtypes, shapes, contiguity)
//! before calling these functions; they still check everything they rely on.
//!
//! Queries run through `pinrt::Sampler`'s batch methods with the GIL released, so the numbers
//! are the Rust sampler's bit for bit (same rays, seed and first index).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use numpy::{
    PyArray1, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods,
};
use pin_format::Directions;
use pin_volume::files::InputSet;
use pin_volume::{
    Endian, GivenSourceOptions, InputKind, ProceduralSpec, RawOptions, RawType, SourceSpec,
    VdbOptions,
};
use pinbake::{BakeInput, BakeRequest, PlanError};
use pinrt::{PinGrid as RtGrid, RayQuery, SamplerOptions};
use pyo3::exceptions::{PyException, PyMemoryError, PyValueError};
use pyo3::prelude::*;
use serde_json::json;

pyo3::create_exception!(
    _native,
    PinError,
    PyException,
    "A pin file, volume or bake failed; the message is the library's one-line error."
);

fn pin_err(e: impl std::fmt::Display) -> PyErr {
    PinError::new_err(e.to_string().replace(['\n', '\r'], " "))
}

/// A runtime error: `MemoryError` for a buffer or a mapping that could not be allocated
/// (out of memory or of address space: ENOMEM), `PinError` else.
fn rt_err(e: pinrt::Error) -> PyErr {
    use pin_format::input::InputError;
    let enomem = |err: &std::io::Error| err.kind() == std::io::ErrorKind::OutOfMemory;
    match &e {
        pinrt::Error::Input(InputError::OutOfMemory { .. }) => {
            PyMemoryError::new_err(e.to_string())
        }
        pinrt::Error::Input(InputError::Io { err, .. }) | pinrt::Error::Io { source: err, .. }
            if enomem(err) =>
        {
            PyMemoryError::new_err(e.to_string())
        }
        _ => pin_err(e),
    }
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
    c_order(a.is_c_contiguous(), a.as_slice().ok(), what)
}

/// The values of an array in C order: a Fortran-order array would be read in the wrong
/// order (its memory order), so it is refused, as any non-contiguous one.
fn c_order<'a>(c_contiguous: bool, values: Option<&'a [f32]>, what: &str) -> PyResult<&'a [f32]> {
    match values {
        Some(v) if c_contiguous => Ok(v),
        _ => Err(value_err(format!("{what} must be C-contiguous"))),
    }
}

/// The ray records of a batch, allocated fallibly (`MemoryError` when they do not fit).
fn ray_queries(o: &[f32], d: &[f32], t: &[f32]) -> PyResult<Vec<RayQuery>> {
    let mut rays = try_with_capacity(t.len(), "the ray records")?;
    rays.extend(
        o.chunks_exact(3)
            .zip(d.chunks_exact(3))
            .zip(t)
            .map(|((o, d), &t)| RayQuery::new([o[0], o[1], o[2]], [d[0], d[1], d[2]], t)),
    );
    Ok(rays)
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
        let max = pinrt::MAX_NEAREST_LINE_STEPS;
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
        let t = c_order(t_max.is_c_contiguous(), t_max.as_slice().ok(), "t_max")?;
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
            let rays = ray_queries(o, d, t)?;
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
            let mut out = try_vec(n, 0f32, "the results")?;
            match kind {
                Query::Transmittance => s.transmittance_batch(&rays, seed, first_index, &mut out),
                Query::Distance => {
                    // In chunks: the optional distances need no second array of N.
                    let mut tmp = [None::<f32>; pinrt::BATCH];
                    for (i, (rc, oc)) in rays
                        .chunks(pinrt::BATCH)
                        .zip(out.chunks_mut(pinrt::BATCH))
                        .enumerate()
                    {
                        let first = first_index.wrapping_add((i * pinrt::BATCH) as u32);
                        let t = &mut tmp[..rc.len()];
                        s.sample_distance_batch(rc, seed, first, t);
                        for (o, v) in oc.iter_mut().zip(t.iter()) {
                            *o = v.unwrap_or(f32::INFINITY);
                        }
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
        let grid = py.detach(|| RtGrid::open(&path)).map_err(rt_err)?;
        Ok(Self { grid })
    }

    /// A grid from the bytes of a pin file (copied).
    #[staticmethod]
    fn from_bytes(data: &[u8]) -> PyResult<Self> {
        Ok(Self {
            grid: RtGrid::from_slice(data).map_err(rt_err)?,
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
            "directions": pinbake::summary::directions_json(s.directions),
            "pins_per_entry": d.pins_per_entry,
            "pins": self.grid.pins().len(),
            "stored_cells": d.stored_cells,
            "covered_cells": s.covered_cells,
            "z_range": [s.z_begin, s.z_end],
            "sparse": self.grid.cell_index().is_some(),
            "mapped": self.grid.is_mapped(),
            "file_bytes": self.grid.bytes().len(),
            "box": {"min": d.box_min, "max": d.box_max, "frame": "local"},
            "local_to_world": d.local_to_world,
            "world_box": bounds.map(|(a, b)| json!({"min": a, "max": b, "frame": "world"})),
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

/// A [`pinbake::PlanError`] as the Python exception it stands for: `ValueError` for an
/// option out of range, `MemoryError` for a refused budget or allocation, `PinError` else.
fn plan_err(e: PlanError) -> PyErr {
    let msg = pin_format::text::error_line(&e);
    match e {
        PlanError::Usage(_) => value_err(msg),
        e if e.is_memory() => PyMemoryError::new_err(msg),
        _ => PinError::new_err(msg),
    }
}

/// An empty vector with room for `n` values, allocated fallibly (`MemoryError` naming `what`
/// and the bytes when it does not fit).
fn try_with_capacity<T>(n: usize, what: &str) -> PyResult<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| {
        PyMemoryError::new_err(format!(
            "{what}: out of memory for {} bytes",
            (n as u64).saturating_mul(std::mem::size_of::<T>() as u64)
        ))
    })?;
    Ok(v)
}

/// `n` copies of `fill`, allocated fallibly (see [`try_with_capacity`]).
fn try_vec<T: Clone>(n: usize, fill: T, what: &str) -> PyResult<Vec<T>> {
    let mut v = try_with_capacity(n, what)?;
    v.resize(n, fill);
    Ok(v)
}

/// `bake(embed_density=...)`: the text of `--embed-density` (`"sparse"`, `"sparse:N"`,
/// `"sparse:X,Y,Z"`, `"64"`, `"voxels:F"`, `"sparse-voxels:F"`), parsed by pinbake as the flag is, or the voxels per axis of a
/// dense copy (the Python layer makes three of one integer). Text first: a string of three
/// characters is no triple.
#[derive(FromPyObject)]
enum EmbedDensityArg {
    Text(String),
    Dims([u32; 3]),
}

impl EmbedDensityArg {
    fn density(self) -> PyResult<pinbake::EmbedDensity> {
        match self {
            Self::Text(t) => t
                .parse()
                .map_err(|e| value_err(format!("embed_density: {e}"))),
            Self::Dims(d) => Ok(pinbake::EmbedDensity::Dense(d)),
        }
    }
}

/// `bake(embed_control=...)`: `True` or `"auto"` for the default brick edge (as
/// `--embed-control` without a value), an edge in voxels, or `False` for none. A bool is
/// tried first: Python's `True` is also the integer 1, which would be a 1-voxel edge.
#[derive(FromPyObject)]
enum ControlEdge {
    Flag(bool),
    Edge(u32),
    Word(String),
}

impl ControlEdge {
    fn dims(self) -> PyResult<Option<pinbake::control::ControlDims>> {
        use pinbake::control::ControlDims;
        match self {
            Self::Flag(false) => Ok(None),
            Self::Flag(true) => Ok(Some(ControlDims::Auto)),
            Self::Edge(e) => Ok(Some(ControlDims::Edge(e))),
            Self::Word(w) if w == "auto" => Ok(Some(ControlDims::Auto)),
            Self::Word(w) => Err(pyo3::exceptions::PyValueError::new_err(format!(
                "embed_control: '{w}' is not `auto`, True or a brick edge of 1..=64 voxels"
            ))),
        }
    }
}

/// Bakes `input` (a file path, `procedural:SPEC`, or `<array>` with `data`) into `output` and
/// returns the JSON summary, through `pinbake::plan::bake_to_file`: the ranges, the output
/// rule, the memory budget, the choice and the summary of `pinbake bake`, by the same code.
/// Options as `pinbake bake`'s flags; the Python layer documents them.
#[pyfunction]
#[pyo3(signature = (
    input, output, *, data=None, spacing=None, origin=None, cells=None,
    directions=None, pins_per_entry=None, target_error=None, step=0.01, seed=0, crop=true,
    center_pins=true, majorant=[16, 16, 16], embed_density=None, embed_control=None,
    density_scale=1.0,
    threads=None, max_memory=None, grid=None, levelset_to_fog=false, dims=None,
    voxel_type=None, endian=None, clamp_negative=false, nan_as_zero=false, vdb_worker=None,
    held_bytes=0, backend="cpu", max_bytes=None
))]
#[allow(clippy::too_many_arguments)]
fn bake(
    py: Python<'_>,
    input: &str,
    output: PathBuf,
    data: Option<Bound<'_, PyAny>>,
    spacing: Option<[f64; 3]>,
    origin: Option<[f64; 3]>,
    cells: Option<[u32; 3]>,
    directions: Option<&str>,
    pins_per_entry: Option<u32>,
    target_error: Option<f64>,
    step: f64,
    seed: u64,
    crop: bool,
    center_pins: bool,
    majorant: [u32; 3],
    embed_density: Option<EmbedDensityArg>,
    embed_control: Option<ControlEdge>,
    density_scale: f64,
    threads: Option<usize>,
    max_memory: Option<u64>,
    grid: Option<String>,
    levelset_to_fog: bool,
    dims: Option<[u32; 3]>,
    voxel_type: Option<&str>,
    endian: Option<&str>,
    clamp_negative: bool,
    nan_as_zero: bool,
    vdb_worker: Option<PathBuf>,
    held_bytes: u64,
    backend: &str,
    max_bytes: Option<u64>,
) -> PyResult<String> {
    check_max_memory(max_memory)?;
    let backend = match backend {
        "cpu" => pinbake::BakeBackend::Cpu,
        "gpu" => pinbake::BakeBackend::Gpu(pinbake::GpuBakeOptions::default()),
        other => {
            return Err(value_err(format!(
                "backend '{other}' is not 'cpu' or 'gpu'"
            )));
        }
    };
    let mut req = BakeRequest {
        cells,
        directions: directions.map(parse_dirs).transpose()?,
        pins_per_entry,
        target_error,
        step,
        seed,
        crop,
        jitter_pins: !center_pins,
        majorant: (majorant != [0; 3]).then_some(majorant),
        embed_density: embed_density.map(EmbedDensityArg::density).transpose()?,
        embed_control: embed_control
            .map(ControlEdge::dims)
            .transpose()?
            .flatten()
            .map(|dims| pinbake::control::ControlOptions {
                dims,
                ..pinbake::control::ControlOptions::default()
            }),
        threads,
        density_scale,
        max_memory,
        max_bytes,
        backend,
        // A bake option without a keyword here (a tile) keeps the command line's default.
        ..BakeRequest::default()
    };
    req.validate().map_err(plan_err)?;
    // Options meant for another kind of input are refused, as on the command line.
    let kind = if data.is_some() {
        InputKind::Array
    } else {
        InputKind::of(Path::new(input))
    };
    let given = GivenSourceOptions {
        dims: dims.is_some(),
        voxel_type: voxel_type.is_some(),
        endian: endian.is_some(),
        spacing: spacing.is_some(),
        origin: origin.is_some(),
        clamp_negative,
        nan_as_zero,
        grid: grid.is_some(),
        levelset_to_fog,
    };
    if let Some(name) = kind.first_inapplicable(&given) {
        return Err(value_err(format!(
            "{name} does not apply to {} input ({input})",
            kind.article_name()
        )));
    }
    let spacing = spacing.unwrap_or([1.0; 3]);
    let origin = origin.unwrap_or([0.0; 3]);

    let source = if let Some(arr) = data {
        // `held_bytes`: a copy the Python layer made (a dtype other than float32/float64),
        // alive throughout the bake; the bake's own budget is what the budget leaves beside it.
        let budget = pin_volume::files::MemoryBudget::new(req.max_memory);
        if held_bytes > 0 {
            req.max_memory = Some(budget.limit.saturating_sub(held_bytes).max(1));
        }
        let (dims, values) = array_values(py, &arr, &budget, held_bytes)?;
        BakeInput::Array {
            dims,
            values,
            spacing,
            origin,
        }
    } else if let Some(rest) = input.strip_prefix("procedural:") {
        // The request's density scale opens it (`pinbake::plan`), as every input.
        let spec: ProceduralSpec = rest.parse().map_err(pin_err)?;
        BakeInput::Source(SourceSpec::Procedural(spec))
    } else {
        let path = PathBuf::from(input);
        if kind.is_vdb_like() {
            // The NanoVDB reader runs in process and never starts the worker.
            let nano = (kind == InputKind::NanoVdb).then(PathBuf::new);
            let worker = vdb_worker.or(nano).ok_or_else(|| {
                value_err("reading OpenVDB needs the pinrt-vdb-worker script (vdb_worker=)")
            })?;
            BakeInput::Source(SourceSpec::Vdb(
                path,
                VdbOptions {
                    grid,
                    levelset_to_fog,
                    worker_exe: worker,
                    ..VdbOptions::default()
                },
            ))
        } else {
            let voxel_type = match voxel_type {
                None => None,
                Some(t) => Some(RawType::parse(t).ok_or_else(|| {
                    value_err(format!(
                        "voxel_type '{t}' is not one of u8, u16, f16, f32, f64"
                    ))
                })?),
            };
            let endian = match endian.unwrap_or("little").to_ascii_lowercase().as_str() {
                "little" | "le" => Endian::Little,
                "big" | "be" => Endian::Big,
                other => return Err(value_err(format!("endian '{other}' is not little or big"))),
            };
            BakeInput::Source(SourceSpec::Raw(
                path,
                RawOptions {
                    dims,
                    voxel_type,
                    endian,
                    spacing,
                    origin,
                    clamp_negative,
                    nan_as_zero,
                },
            ))
        }
    };
    let started = Instant::now();
    let baked = interruptible_bake(py, source, &output, &req)?;
    let mut v = baked
        .summary()
        .map_err(|e| pin_err(format!("{}: {e}", output.display())))?;
    v["seconds"] = serde_json::json!(started.elapsed().as_secs_f64());
    Ok(v.to_string())
}

/// The voxels of `data`, a 3-D float32 or float64 array indexed `[x, y, z]` in any memory
/// order (C, Fortran, strided, broadcast), copied x-fastest into the one f32 vector the bake
/// takes over. The copy is the bake's only one: it is counted against `budget` with `held`
/// bytes the caller holds beside it before it is allocated (a broadcast array of 2^26 voxels
/// holds 4 bytes and needs 256 MiB), and allocated fallibly.
fn array_values(
    py: Python<'_>,
    data: &Bound<'_, PyAny>,
    budget: &pin_volume::files::MemoryBudget,
    held: u64,
) -> PyResult<([u32; 3], Vec<f32>)> {
    if let Ok(a) = data.extract::<PyReadonlyArray3<'_, f32>>() {
        copy_xyz(py, a.as_array(), budget, held, |v| v)
    } else if let Ok(a) = data.extract::<PyReadonlyArray3<'_, f64>>() {
        copy_xyz(py, a.as_array(), budget, held, |v| v as f32)
    } else {
        Err(value_err(
            "data must be a 3-D NumPy array of float32 or float64",
        ))
    }
}

/// Refuses, with `MemoryError`, the f32 copy of a volume array of `shape` beside `held` bytes
/// that the caller holds when the two exceed `budget`; returns the voxel count.
fn check_copy(
    shape: &[usize],
    held: u64,
    budget: &pin_volume::files::MemoryBudget,
) -> PyResult<u64> {
    let n = shape
        .iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(d as u64))
        .unwrap_or(u64::MAX);
    let need = n
        .saturating_mul(4)
        .saturating_add(held)
        .saturating_add(pinbake::plan::PROCESS_BASE_BYTES);
    let shown = shape
        .iter()
        .map(|d| d.to_string())
        .collect::<Vec<_>>()
        .join("x");
    budget
        .check(&format!("copying the {shown} volume array"), need)
        .map_err(|e| PyMemoryError::new_err(pin_format::text::error_line(&e)))?;
    Ok(n)
}

/// The check [`bake`] makes before it copies a volume array (`check_copy`), for the Python
/// layer to make before a dtype conversion of its own (`held` bytes).
#[pyfunction]
#[pyo3(signature = (shape, held, max_memory=None))]
fn check_array_memory(shape: Vec<usize>, held: u64, max_memory: Option<u64>) -> PyResult<()> {
    check_max_memory(max_memory)?;
    let budget = pin_volume::files::MemoryBudget::new(max_memory);
    check_copy(&shape, held, &budget).map(|_| ())
}

/// `max_memory=0` is refused as the command line refuses `--max-memory 0` (it was taken as
/// a budget of 1 byte).
fn check_max_memory(max_memory: Option<u64>) -> PyResult<()> {
    if max_memory == Some(0) {
        return Err(value_err("max_memory must be at least 1 byte, got 0"));
    }
    Ok(())
}

/// See [`array_values`].
fn copy_xyz<T: Copy + Sync>(
    py: Python<'_>,
    a: numpy::ndarray::ArrayView3<'_, T>,
    budget: &pin_volume::files::MemoryBudget,
    held: u64,
    to_f32: impl Fn(T) -> f32 + Send + Sync,
) -> PyResult<([u32; 3], Vec<f32>)> {
    let shape = a.shape();
    let dims = [shape[0], shape[1], shape[2]].map(|d| u32::try_from(d).unwrap_or(u32::MAX));
    let n = check_copy(shape, held, budget)?;
    let n = usize::try_from(n)
        .map_err(|_| PyMemoryError::new_err("the volume array's copy: out of address space"))?;
    let mut values = try_with_capacity(n, "the volume array's copy")?;
    // z slowest, x fastest: the layout of the baker's dense grid.
    let zyx = a.permuted_axes([2, 1, 0]);
    py.detach(|| values.extend(zyx.iter().map(|&v| to_f32(v))));
    Ok((dims, values))
}

/// The bake's progress hook: only its cancel flag.
struct CancelOnly(Arc<AtomicBool>);

impl pinbake::plan::Progress for CancelOnly {
    fn cancel_flag(&self) -> Option<Arc<AtomicBool>> {
        Some(self.0.clone())
    }
}

/// How often the waiting interpreter looks for a signal (Ctrl-C) while a bake runs.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// [`pinbake::plan::bake_to_file`] on a worker thread, with the GIL released, while this
/// thread polls Python's signal handlers every [`SIGNAL_POLL`]: a `KeyboardInterrupt` (or any
/// exception a handler raises) sets the bake's cancel flag, the bake stops at its next row or
/// batch and removes its temp file, and the exception propagates with no output written.
fn interruptible_bake(
    py: Python<'_>,
    source: BakeInput,
    output: &Path,
    req: &BakeRequest,
) -> PyResult<pinbake::plan::Baked> {
    let cancel = Arc::new(AtomicBool::new(false));
    let hook = CancelOnly(cancel.clone());
    std::thread::scope(|s| {
        let waiter = std::thread::current();
        let worker = s.spawn(move || {
            let r = pinbake::plan::bake_to_file(source, output, req, &InputSet::default(), &hook);
            waiter.unpark();
            r
        });
        loop {
            // Woken when the worker ends (or after SIGNAL_POLL, or spuriously).
            py.detach(|| std::thread::park_timeout(SIGNAL_POLL));
            if worker.is_finished() {
                break;
            }
            if let Err(interrupt) = py.check_signals() {
                cancel.store(true, Ordering::Relaxed);
                // The bake stops within a row or batch; its error is the interrupt's.
                let _ = py.detach(|| worker.join());
                return Err(interrupt);
            }
        }
        match py.detach(|| worker.join()) {
            Ok(r) => r.map_err(plan_err),
            Err(_) => Err(pin_err(format!("{}: the bake panicked", output.display()))),
        }
    })
}

/// The isolated OpenVDB reader (`pinrt-vdb-worker __vdb-worker FILE SELECTOR MODE`): `args`
/// are the arguments after the subcommand. Returns the process exit code.
#[pyfunction]
fn vdb_worker(args: Vec<String>) -> i32 {
    let args: Vec<std::ffi::OsString> = args.into_iter().map(Into::into).collect();
    pin_volume::vdb::worker_main(&args)
}

/// A lookup (`pinrt::SamplerOptions::RENDER`, the default, or `THESIS`) as the queries'
/// keyword arguments, so that Python cannot drift from the Rust constants.
fn lookup_kwargs<'py>(
    py: Python<'py>,
    r: SamplerOptions,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
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
    m.add(
        "RENDER_LOOKUP",
        lookup_kwargs(m.py(), SamplerOptions::RENDER)?,
    )?;
    m.add(
        "THESIS_LOOKUP",
        lookup_kwargs(m.py(), SamplerOptions::THESIS)?,
    )?;
    m.add_function(wrap_pyfunction!(bake, m)?)?;
    m.add_function(wrap_pyfunction!(vdb_worker, m)?)?;
    m.add_function(wrap_pyfunction!(check_array_memory, m)?)?;
    m.add("PinError", m.py().get_type::<PinError>())?;
    Ok(())
}
