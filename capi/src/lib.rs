//! # pinrt-capi: the pin grid runtime behind a C ABI
//!
//! A C or C++ renderer links `libpinrt_capi.a` (or `.so`) and includes `include/pinrt.h`
//! (generated from this file by cbindgen, `cargo run -p xtask -- c-header`; CI's `c-header
//! --check` fails when it is stale). The queries run the same Rust code as
//! [`pinrt::Sampler`]'s batch methods, so a C caller gets the same bits as a Rust caller for
//! the same rays, seed and first index.
//!
//! ## Conventions
//!
//! * Every fallible function returns a [`PinrtStatus`]; `PINRT_STATUS_OK` (0) is success.
//!   On failure [`pinrt_last_error`] returns a one-line message (naming the file for file
//!   errors). The message is per thread and describes the last call made on that thread;
//!   a successful call clears it.
//! * No Rust panic crosses the boundary: every entry point runs inside `catch_unwind` and
//!   turns a panic into `PINRT_STATUS_INTERNAL`.
//! * Every pointer argument (grids, options, arrays, out-parameters) is checked for null (a
//!   null array with a length of 0 is allowed) and for the alignment of its type; lengths
//!   are checked against the address space, and copies whose size comes from the caller are
//!   allocated fallibly (`PINRT_STATUS_OUT_OF_MEMORY`).
//! * Files are opened by `pin_format::input`'s rule, as every reader of the workspace: only
//!   regular files, opened without blocking (a FIFO is refused, never waited on); messages
//!   quote paths with control characters, so a message is always one line.
//! * A grid opened with `pinrt_open` is memory-mapped. If another process truncates or
//!   rewrites the file in place while it is open, touching a vanished page raises SIGBUS,
//!   which kills the host process. Replace pin files atomically, by writing a new file and
//!   renaming it over the old one (as pinbake does): the mapping keeps the old file alive.
//!   Where that cannot be ruled out, read the file and use `pinrt_open_memory`.
//! * The default lookup is `pinrt::SamplerOptions::RENDER`, the Rust default
//!   (`PINRT_RENDER_*`): a newly opened grid has it and NULL options give its jitter. The
//!   thesis' lookup is `PINRT_THESIS_*`.
//! * A `PinrtGrid` is immutable after opening: any number of threads may query one grid at
//!   once. `pinrt_close` must not race with queries on the same grid.

use std::cell::RefCell;
use std::ffi::{CStr, CString, c_char};
use std::panic::{AssertUnwindSafe, catch_unwind};

use bytemuck::{Pod, Zeroable};
use pinrt::{PinGrid, QueryResult, RayQuery, Sampler, SamplerOptions};

/// Result codes of every fallible call.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PinrtStatus {
    /// Success.
    Ok = 0,
    /// A required pointer was null.
    NullPointer = 1,
    /// An argument is out of range: misaligned pointer, length too large, bad path string,
    /// bad placement transform.
    InvalidArgument = 2,
    /// The file could not be opened, mapped or read.
    Io = 3,
    /// The bytes are not a valid pin file (truncated, damaged, unsupported version...).
    Format = 4,
    /// A bug in the library (a caught panic); the message says where.
    Internal = 5,
    /// A buffer whose size comes from the file or the caller could not be allocated (a
    /// copy of `pinrt_open_memory`'s bytes, a file read into memory); the message names
    /// the size.
    OutOfMemory = 6,
}

/// An open pin grid (opaque). Created by `pinrt_open` or `pinrt_open_memory`, released by
/// `pinrt_close`.
pub struct PinrtGrid {
    grid: PinGrid,
    /// The lookup options beside the jitter, set by `pinrt_set_lookup` and
    /// `pinrt_set_nearest_line` (a newly opened grid has the default lookup's,
    /// `pinrt::SamplerOptions::RENDER`).
    lookup: Lookup,
}

/// `pinrt_set_lookup`'s options (`pinrt::SamplerOptions` without the jitter, which each batch
/// call's `PinrtQueryOptions` carries).
#[derive(Clone, Copy, Debug)]
struct Lookup {
    chain_stride: u32,
    midpoint_lookup: bool,
    start_inside: bool,
    nearest_line: u32,
}

impl Lookup {
    /// The part of `opts` that the grid holds.
    fn of(opts: SamplerOptions) -> Self {
        Self {
            chain_stride: opts.chain_stride,
            midpoint_lookup: opts.midpoint_lookup,
            start_inside: opts.start_inside,
            nearest_line: opts.nearest_line,
        }
    }
}

/// One query: a world-space ray and the end of its segment (32 bytes, the layout of the GPU
/// query buffer in `docs/gpu.md`). `dir` need not be normalised; distances are in units of
/// the ray parameter. `t_max = INFINITY` queries the whole chord through the grid box.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PinrtRay {
    pub origin: [f32; 3],
    pub t_max: f32,
    pub dir: [f32; 3],
    /// Ignored; keeps the struct at 32 bytes.
    pub pad: u32,
}

/// Everything one query produces (32 bytes; the GPU result buffer's layout).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PinrtResult {
    /// Sampled collision distance, `INFINITY` if the ray passes.
    pub distance: f32,
    /// Transmittance estimate over `[0, t_max]`.
    pub transmittance: f32,
    /// 1 if a collision was sampled.
    pub hit: u32,
    /// Index of the entry read, `UINT32_MAX` if none (miss, invalid ray, empty cell).
    pub entry: u32,
    /// Number of participating set ratio bits (the transmittance exponent).
    pub popcount: u32,
    /// Collision interval (0 nearest the chord start), 32 if none.
    pub interval: u32,
    /// 0 resolved, 1 miss (no chord or empty segment), 2 invalid ray.
    pub status: u32,
    /// Generator state after the query.
    pub rng_state: u32,
}

/// Lookup options and placement for one batch call. Pass NULL for the defaults (the default
/// lookup's jitter, `PINRT_RENDER_SPATIAL_JITTER` and `PINRT_RENDER_DIRECTIONAL_JITTER`, and
/// the file's own `local_to_world`); a caller's struct sets both jitters itself (0 and 0 for
/// the thesis' lookup, `PINRT_THESIS_*`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct PinrtQueryOptions {
    /// Lookup jitter in spatial cells; 0 turns it off (and draws no random numbers).
    pub spatial_jitter: f32,
    /// Lookup jitter in direction cells; 0 turns it off.
    pub directional_jitter: f32,
    /// Row-major 3x4 local-to-world affine placing the grid instead of the file's own (for
    /// instances); NULL keeps the file's.
    pub local_to_world: *const f64,
}

/// What an open grid is: the file's grid description plus derived sizes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PinrtDesc {
    /// Spatial cells along x, y, z.
    pub dims: [u32; 3],
    /// 0 polar (`direction_res` = phi, theta cells), 1 octahedral (n, n).
    pub direction_kind: u32,
    pub direction_res: [u32; 2],
    /// Number of direction cells.
    pub direction_cells: u32,
    pub pins_per_entry: u32,
    pub bits_per_pin: u32,
    /// Cell layers `z_begin..z_end` this file covers (the whole grid unless it is a tile).
    pub z_begin: u32,
    pub z_end: u32,
    /// 1 if the file has a sparse cell index (empty cells not stored).
    pub sparse: u32,
    /// 1 if the file is memory-mapped (`pinrt_open`), 0 if held in memory.
    pub mapped: u32,
    /// `GRID_FLAG_*` bits of the file (1 cropped, 2 jittered pins).
    pub flags: u32,
    /// Cell blocks stored in the pin array.
    pub stored_cells: u64,
    /// Cells this file covers.
    pub covered_cells: u64,
    /// Pins stored.
    pub pin_count: u64,
    /// Size of the file in bytes.
    pub file_bytes: u64,
    pub seed: u64,
    /// The box in the volume's local space that the grid covers.
    pub box_min: [f64; 3],
    pub box_max: [f64; 3],
    /// Row-major 3x4 affine from local to world space.
    pub local_to_world: [f64; 12],
    /// The world-space box of the grid (axis-aligned around it when rotated).
    pub world_min: [f64; 3],
    pub world_max: [f64; 3],
    /// Ray-marching step of the bake, relative to the longest box edge.
    pub step_size: f64,
    pub density_scale: f64,
}

/// The uniform block of the GPU query shader (binding 0 of `shaders/pin.wgsl` and of its
/// translations in `shaders/generated/`; 128 bytes, see `docs/gpu.md`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PinrtGpuParams {
    /// World -> unit cube: row i = (A_i0, A_i1, A_i2, b_i).
    pub rows: [[f32; 4]; 3],
    /// Spatial and directional lookup jitter in cells (0 = off), chain stride in intervals (0:
    /// one lookup), lookup point (0: segment start, 1: middle; `docs/sampling.md` section 12;
    /// plus 2: a piece that starts inside the box at its start without spatial jitter,
    /// section 14).
    pub jitter: [f32; 4],
    /// Cells x, y, z, z_begin.
    pub dims: [u32; 4],
    /// z_end, pins_per_entry, block_len (direction cells x pins per entry), stored_cells.
    pub grid: [u32; 4],
    /// Direction kind (0 polar, 1 octahedral), res0, res1, 1 if the cell index is bound.
    pub dirs: [u32; 4],
    /// Seed, first query index, ray count, invocations per dispatch row: set by the caller
    /// for each dispatch (`pinrt_gpu_params` leaves them 0).
    pub run: [u32; 4],
}

/// Where an open grid's GPU buffers start: the pin section and the cell index as stored in the
/// file, to be uploaded without repacking. Valid until `pinrt_close`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct PinrtGpuBuffers {
    /// Storage buffer binding 1: `pin_count` entries of 8 bytes (u32 mask, f32 t_min).
    pub pins: *const u8,
    pub pins_bytes: usize,
    /// Storage buffer binding 2: one u32 per covered cell; NULL for a dense grid (bind any
    /// buffer of at least 4 bytes then).
    pub cell_index: *const u8,
    pub cell_index_bytes: usize,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(msg: &str) {
    // A message cannot carry an interior NUL into C; such bytes are replaced, never dropped
    // silently into a truncated string.
    let clean = msg.replace('\0', "\\0");
    let line = clean.lines().next().unwrap_or("").to_string();
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::new(line).unwrap_or_default());
}

fn clear_error() {
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::default());
}

/// An error on its way out: the code and the one-line message.
struct Fail(PinrtStatus, String);

impl From<pinrt::Error> for Fail {
    fn from(e: pinrt::Error) -> Self {
        let code = match &e {
            pinrt::Error::Input(pin_format::input::InputError::OutOfMemory { .. }) => {
                PinrtStatus::OutOfMemory
            }
            pinrt::Error::Input(_) | pinrt::Error::Io { .. } => PinrtStatus::Io,
            pinrt::Error::Format { .. } => PinrtStatus::Format,
            pinrt::Error::BadTransform(_) => PinrtStatus::InvalidArgument,
            _ => PinrtStatus::Internal,
        };
        Fail(code, e.to_string())
    }
}

fn null(what: &str) -> Fail {
    Fail(PinrtStatus::NullPointer, format!("{what} is NULL"))
}

/// Runs `body` with the error slot cleared, converting errors and panics into a status.
fn guard(name: &str, body: impl FnOnce() -> Result<(), Fail>) -> PinrtStatus {
    clear_error();
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => PinrtStatus::Ok,
        Ok(Err(Fail(code, msg))) => {
            set_error(&msg);
            code
        }
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            set_error(&format!("{name}: internal error: {what}"));
            PinrtStatus::Internal
        }
    }
}

/// A checked slice from a C pointer and a length: null only with length 0, aligned, and no
/// larger than the address space allows.
///
/// # Safety
/// If `ptr` is non-null it must point to `len` readable values of `T` that stay valid and
/// unaliased by writes for `'a`.
unsafe fn slice_in<'a, T>(ptr: *const T, len: usize, what: &str) -> Result<&'a [T], Fail> {
    if len == 0 {
        return Ok(&[]);
    }
    check_ptr(ptr, len, what)?;
    // SAFETY: non-null, aligned and size-checked above; validity is the caller's contract.
    Ok(unsafe { std::slice::from_raw_parts(ptr, len) })
}

/// Like [`slice_in`] for an output array.
///
/// # Safety
/// If `ptr` is non-null it must point to `len` writable values of `T`, not aliased for `'a`.
unsafe fn slice_out<'a, T>(ptr: *mut T, len: usize, what: &str) -> Result<&'a mut [T], Fail> {
    if len == 0 {
        return Ok(&mut []);
    }
    check_ptr(ptr, len, what)?;
    // SAFETY: as in `slice_in`, and the caller promises exclusive access.
    Ok(unsafe { std::slice::from_raw_parts_mut(ptr, len) })
}

fn check_ptr<T>(ptr: *const T, len: usize, what: &str) -> Result<(), Fail> {
    if ptr.is_null() {
        return Err(null(what));
    }
    if !(ptr as usize).is_multiple_of(align_of::<T>()) {
        return Err(Fail(
            PinrtStatus::InvalidArgument,
            format!("{what} is not aligned to {} bytes", align_of::<T>()),
        ));
    }
    let fits = len
        .checked_mul(size_of::<T>())
        .is_some_and(|b| b <= isize::MAX as usize);
    if !fits {
        return Err(Fail(
            PinrtStatus::InvalidArgument,
            format!("{what}: length {len} is too large"),
        ));
    }
    Ok(())
}

/// # Safety
/// `grid` is null or a pointer returned by `pinrt_open*` and not yet closed.
unsafe fn grid_ref<'a>(grid: *const PinrtGrid) -> Result<&'a PinrtGrid, Fail> {
    check_ptr(grid, 1, "grid")?;
    // SAFETY: the caller's contract; non-null and aligned (checked above).
    unsafe { grid.as_ref() }.ok_or_else(|| null("grid"))
}

/// [`grid_ref`] for the calls that change a grid's lookup settings.
///
/// # Safety
/// `grid` is null or an open grid that no other thread uses during the call.
unsafe fn grid_mut<'a>(grid: *mut PinrtGrid) -> Result<&'a mut PinrtGrid, Fail> {
    check_ptr(grid.cast_const(), 1, "grid")?;
    // SAFETY: the caller's contract; non-null and aligned (checked above).
    unsafe { grid.as_mut() }.ok_or_else(|| null("grid"))
}

fn publish(grid: PinGrid, out: *mut *mut PinrtGrid) {
    let boxed = Box::new(PinrtGrid {
        grid,
        lookup: Lookup::of(SamplerOptions::default()),
    });
    // SAFETY: `out` was checked non-null and aligned by the caller of `publish`.
    unsafe { out.write(Box::into_raw(boxed)) };
}

fn check_out<T>(out: *mut T) -> Result<(), Fail> {
    check_ptr(out.cast_const(), 1, "out")
}

/// Opens a pin file by memory-mapping it: O(number of sections), no copy of the pins.
///
/// Only a regular file is opened: a directory is `PINRT_STATUS_IO` "is a directory", a FIFO,
/// device or socket `PINRT_STATUS_IO` "not a regular file", at once (the open never blocks).
///
/// The file must not be truncated or rewritten in place while it is open: touching a page
/// that vanished raises SIGBUS, which kills the host process (no library can turn it into an
/// error). Replace pin files atomically instead, by writing a new file and renaming it over
/// the old one, as pinbake does: the mapping keeps the old file alive, and the next
/// `pinrt_open` sees the new one. Where in-place changes cannot be ruled out (network file
/// systems, files owned by other tools), read the file and use `pinrt_open_memory`.
///
/// On success `*out` receives the grid; on failure `*out` is set to NULL.
///
/// # Safety
/// `path` is a NUL-terminated string; `out` points to writable storage for one pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_open(path: *const c_char, out: *mut *mut PinrtGrid) -> PinrtStatus {
    guard("pinrt_open", || {
        check_out(out)?;
        // SAFETY: checked non-null and aligned.
        unsafe { out.write(std::ptr::null_mut()) };
        // SAFETY: the caller's contract on `path`.
        let path = unsafe { path_arg(path) }?;
        publish(PinGrid::open(path)?, out);
        Ok(())
    })
}

/// The path argument of the openers: not NULL, UTF-8.
///
/// # Safety
/// `path` is NULL or a NUL-terminated string valid for `'a`.
unsafe fn path_arg<'a>(path: *const c_char) -> Result<&'a str, Fail> {
    if path.is_null() {
        return Err(null("path"));
    }
    // SAFETY: the caller's contract.
    let c = unsafe { CStr::from_ptr(path) };
    c.to_str().map_err(|_| {
        Fail(
            PinrtStatus::InvalidArgument,
            // Quoted with escapes: a control character cannot cut the message.
            format!("{:?}: path is not UTF-8", c),
        )
    })
}

/// `pinrt_open`, then every section's checksum and every value checked before the grid is
/// returned (as `pinrt_verify`, each section read once: linear in the file size). A damaged
/// file is `PINRT_STATUS_FORMAT` with one line naming the file and the section, and `*out`
/// is NULL. For pipelines that want damage refused at open: `pinrt_open` checks the
/// structure only, and the queries read the pins and the cell index lazily, unchecked.
///
/// # Safety
/// As `pinrt_open`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_open_checked(
    path: *const c_char,
    out: *mut *mut PinrtGrid,
) -> PinrtStatus {
    guard("pinrt_open_checked", || {
        check_out(out)?;
        // SAFETY: checked non-null and aligned.
        unsafe { out.write(std::ptr::null_mut()) };
        // SAFETY: the caller's contract on `path`.
        let path = unsafe { path_arg(path) }?;
        publish(PinGrid::open_checked(path)?, out);
        Ok(())
    })
}

/// Opens a pin file from `len` bytes in memory. The bytes are copied; the caller may free its
/// buffer as soon as this returns. Errors name the file `<memory>`.
///
/// # Safety
/// `data` points to `len` readable bytes; `out` points to writable storage for one pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_open_memory(
    data: *const u8,
    len: usize,
    out: *mut *mut PinrtGrid,
) -> PinrtStatus {
    guard("pinrt_open_memory", || {
        check_out(out)?;
        // SAFETY: checked non-null and aligned.
        unsafe { out.write(std::ptr::null_mut()) };
        // SAFETY: the caller's contract on `data` and `len`.
        let bytes = unsafe { slice_in(data, len, "data") }?;
        // One aligned copy, allocated fallibly: a buffer that cannot be copied is
        // PINRT_STATUS_OUT_OF_MEMORY, not an abort of the host.
        publish(PinGrid::from_slice(bytes)?, out);
        Ok(())
    })
}

/// Releases a grid. NULL is ignored.
///
/// # Safety
/// `grid` is NULL or a pointer from `pinrt_open*` not closed before; no other thread uses it.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_close(grid: *mut PinrtGrid) {
    // A panic in a destructor must not unwind into C either; there is nothing to report it to.
    let _ = catch_unwind(AssertUnwindSafe(|| {
        if !grid.is_null() {
            // SAFETY: the pointer came from `Box::into_raw` in `publish` (caller's contract).
            drop(unsafe { Box::from_raw(grid) });
        }
    }));
}

/// Full check of every section checksum and value: linear in the file size (opening checks
/// only the structure).
///
/// # Safety
/// `grid` is NULL or an open grid.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_verify(grid: *const PinrtGrid) -> PinrtStatus {
    guard("pinrt_verify", || {
        // SAFETY: caller's contract.
        let g = unsafe { grid_ref(grid) }?;
        g.grid.verify()?;
        Ok(())
    })
}

/// Fills `*out` with the grid's description.
///
/// # Safety
/// `grid` is NULL or an open grid; `out` is NULL or points to a writable `PinrtDesc`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_describe(
    grid: *const PinrtGrid,
    out: *mut PinrtDesc,
) -> PinrtStatus {
    guard("pinrt_describe", || {
        // SAFETY: caller's contract.
        let g = unsafe { grid_ref(grid) }?;
        check_out(out)?;
        let d = g.grid.desc();
        let s = g.grid.shape();
        let (world_min, world_max) = g
            .grid
            .sampler()?
            .world_bounds()
            .unwrap_or(([f64::NAN; 3], [f64::NAN; 3]));
        let desc = PinrtDesc {
            dims: d.dims,
            direction_kind: d.direction_kind,
            direction_res: d.direction_res,
            direction_cells: s.directions.count(),
            pins_per_entry: d.pins_per_entry,
            bits_per_pin: d.bits_per_pin,
            z_begin: s.z_begin,
            z_end: s.z_end,
            sparse: u32::from(g.grid.cell_index().is_some()),
            mapped: u32::from(g.grid.is_mapped()),
            flags: d.flags,
            stored_cells: d.stored_cells,
            covered_cells: s.covered_cells,
            pin_count: g.grid.pins().len() as u64,
            file_bytes: g.grid.bytes().len() as u64,
            seed: d.seed,
            box_min: d.box_min,
            box_max: d.box_max,
            local_to_world: d.local_to_world,
            world_min,
            world_max,
            step_size: d.step_size,
            density_scale: d.density_scale,
        };
        // SAFETY: checked non-null and aligned.
        unsafe { out.write(desc) };
        Ok(())
    })
}

/// The sampler for one batch call, configured by the optional options.
///
/// # Safety
/// `opts` is NULL or points to a readable `PinrtQueryOptions` whose `local_to_world` is NULL
/// or points to 12 readable doubles.
unsafe fn sampler<'g>(
    g: &'g PinrtGrid,
    opts: *const PinrtQueryOptions,
) -> Result<Sampler<'g>, Fail> {
    let l = g.lookup;
    let with_lookup = |spatial_jitter, directional_jitter| SamplerOptions {
        spatial_jitter,
        directional_jitter,
        chain_stride: l.chain_stride,
        midpoint_lookup: l.midpoint_lookup,
        start_inside: l.start_inside,
        nearest_line: l.nearest_line,
    };
    if !opts.is_null() {
        // Checked like every other pointer: a misaligned options pointer is refused.
        check_ptr(opts, 1, "opts")?;
    }
    // SAFETY: caller's contract; non-null pointers are aligned (checked above).
    let Some(o) = (unsafe { opts.as_ref() }) else {
        let d = SamplerOptions::default();
        return Ok(g
            .grid
            .sampler()?
            .with_options(with_lookup(d.spatial_jitter, d.directional_jitter)));
    };
    let s = if o.local_to_world.is_null() {
        g.grid.sampler()?
    } else {
        // SAFETY: caller's contract: 12 doubles.
        let m = unsafe { slice_in(o.local_to_world, 12, "options.local_to_world") }?;
        let m: &[f64; 12] = m.try_into().map_err(|_| {
            Fail(
                PinrtStatus::Internal,
                "local_to_world is not 12 values".into(),
            )
        })?;
        Sampler::with_local_to_world(&g.grid, m)?
    };
    for (name, v) in [
        ("spatial_jitter", o.spatial_jitter),
        ("directional_jitter", o.directional_jitter),
    ] {
        if !(v >= 0.0 && v.is_finite()) {
            return Err(Fail(
                PinrtStatus::InvalidArgument,
                format!("options.{name} is {v}; it must be finite and >= 0"),
            ));
        }
    }
    // The rest of the lookup is the grid's (`pinrt_set_lookup`; `PinrtQueryOptions` predates
    // chained lookups, and a field added to it would break the ABI).
    Ok(s.with_options(with_lookup(o.spatial_jitter, o.directional_jitter)))
}

/// Shared body of the batch calls: checks the arguments and hands typed slices to `run`.
///
/// # Safety
/// The pointer contracts of the public batch functions.
unsafe fn batch<T>(
    grid: *const PinrtGrid,
    opts: *const PinrtQueryOptions,
    rays: *const PinrtRay,
    count: usize,
    out: *mut T,
    run: impl FnOnce(&Sampler<'_>, &[RayQuery], &mut [T]),
) -> Result<(), Fail> {
    // SAFETY: caller's contract for all pointers.
    let g = unsafe { grid_ref(grid) }?;
    let s = unsafe { sampler(g, opts) }?;
    let rays = unsafe { slice_in(rays, count, "rays") }?;
    let out = unsafe { slice_out(out, count, "out") }?;
    run(&s, bytemuck::cast_slice(rays), out);
    Ok(())
}

/// Transmittance estimates of `count` rays over `[0, t_max]`. Query `i` draws its random
/// numbers from the generator seeded by (`seed`, `first_index + i`), like the Rust batch API
/// and the GPU shader: the same arguments give the same bits everywhere.
///
/// # Safety
/// `grid` is NULL or an open grid; `opts` NULL or valid; `rays` and `out` point to `count`
/// elements each (or are NULL with `count == 0`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_transmittance(
    grid: *const PinrtGrid,
    opts: *const PinrtQueryOptions,
    rays: *const PinrtRay,
    count: usize,
    seed: u32,
    first_index: u32,
    out: *mut f32,
) -> PinrtStatus {
    guard("pinrt_transmittance", || {
        // SAFETY: forwarded caller's contract.
        unsafe {
            batch(grid, opts, rays, count, out, |s, r, o| {
                s.transmittance_batch(r, seed, first_index, o)
            })
        }
    })
}

/// Sampled free-flight distances of `count` rays in `[0, t_max]`; `INFINITY` where the ray
/// passes without a collision. Seeded like `pinrt_transmittance`.
///
/// # Safety
/// As for `pinrt_transmittance`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_sample_distance(
    grid: *const PinrtGrid,
    opts: *const PinrtQueryOptions,
    rays: *const PinrtRay,
    count: usize,
    seed: u32,
    first_index: u32,
    out: *mut f32,
) -> PinrtStatus {
    guard("pinrt_sample_distance", || {
        // SAFETY: forwarded caller's contract.
        unsafe {
            batch(grid, opts, rays, count, out, |s, r, o| {
                // The batch API yields options; chunks keep the scratch on the stack.
                let mut tmp = [None::<f32>; pinrt::BATCH];
                for (i, (rc, oc)) in r
                    .chunks(pinrt::BATCH)
                    .zip(o.chunks_mut(pinrt::BATCH))
                    .enumerate()
                {
                    let first = first_index.wrapping_add((i * pinrt::BATCH) as u32);
                    let t = &mut tmp[..rc.len()];
                    s.sample_distance_batch(rc, seed, first, t);
                    for (d, v) in oc.iter_mut().zip(t.iter()) {
                        *d = v.unwrap_or(f32::INFINITY);
                    }
                }
            })
        }
    })
}

/// Both estimates and the diagnostic integers of `count` rays from one lookup each. Its
/// `transmittance` equals `pinrt_transmittance`'s and its `distance` `pinrt_sample_distance`'s
/// for the same arguments.
///
/// # Safety
/// As for `pinrt_transmittance`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_query(
    grid: *const PinrtGrid,
    opts: *const PinrtQueryOptions,
    rays: *const PinrtRay,
    count: usize,
    seed: u32,
    first_index: u32,
    out: *mut PinrtResult,
) -> PinrtStatus {
    guard("pinrt_query", || {
        // SAFETY: forwarded caller's contract.
        unsafe {
            batch(grid, opts, rays, count, out, |s, r, o| {
                let o: &mut [QueryResult] = bytemuck::cast_slice_mut(o);
                s.query_batch(r, seed, first_index, o)
            })
        }
    })
}

/// Fills `*out` with the uniform block for the GPU query shader: this grid placed by its own
/// `local_to_world` (or `opts->local_to_world`) with `opts`' jitter. The world -> unit cube
/// rows are computed exactly as the CPU sampler computes them, which the bit-exact agreement
/// needs. `run` is left 0 for the caller to fill per dispatch.
///
/// # Safety
/// `grid` is NULL or an open grid; `opts` NULL or valid; `out` NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_gpu_params(
    grid: *const PinrtGrid,
    opts: *const PinrtQueryOptions,
    out: *mut PinrtGpuParams,
) -> PinrtStatus {
    guard("pinrt_gpu_params", || {
        // SAFETY: caller's contract.
        let g = unsafe { grid_ref(grid) }?;
        let s = unsafe { sampler(g, opts) }?;
        check_out(out)?;
        let shape = g.grid.shape();
        let too_big = |what: &str, v: u64| {
            Fail(
                PinrtStatus::InvalidArgument,
                format!("{what} {v} does not fit the shader's u32 fields"),
            )
        };
        let block_len =
            u32::try_from(shape.block_len).map_err(|_| too_big("block length", shape.block_len))?;
        let stored = g.grid.desc().stored_cells;
        let stored = u32::try_from(stored).map_err(|_| too_big("stored cells", stored))?;
        let (kind, res) = shape.directions.to_desc();
        let o = s.options();
        let params = PinrtGpuParams {
            rows: s.transform().rows,
            // As `pinrt::gpu::Params`: stride and the lookup bits, small integers exact in f32.
            jitter: [
                o.spatial_jitter,
                o.directional_jitter,
                if o.chain_stride == 0 {
                    0.0
                } else {
                    o.stride() as f32
                },
                o.lookup_mode(),
            ],
            dims: [shape.dims[0], shape.dims[1], shape.dims[2], shape.z_begin],
            grid: [shape.z_end, shape.pins_per_entry, block_len, stored],
            dirs: [
                kind,
                res[0],
                res[1],
                u32::from(g.grid.cell_index().is_some()),
            ],
            run: [0; 4],
        };
        // SAFETY: checked non-null and aligned.
        unsafe { out.write(params) };
        Ok(())
    })
}

/// Fills `*out` with the grid's pin section and cell index bytes (for GPU upload).
///
/// # Safety
/// `grid` is NULL or an open grid; `out` NULL or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_gpu_buffers(
    grid: *const PinrtGrid,
    out: *mut PinrtGpuBuffers,
) -> PinrtStatus {
    guard("pinrt_gpu_buffers", || {
        // SAFETY: caller's contract.
        let g = unsafe { grid_ref(grid) }?;
        check_out(out)?;
        let pins = g.grid.pins_bytes();
        let index = g.grid.cell_index_bytes();
        let bufs = PinrtGpuBuffers {
            pins: pins.as_ptr(),
            pins_bytes: pins.len(),
            cell_index: index.map_or(std::ptr::null(), |b| b.as_ptr()),
            cell_index_bytes: index.map_or(0, |b| b.len()),
        };
        // SAFETY: checked non-null and aligned.
        unsafe { out.write(bufs) };
        Ok(())
    })
}

/// The default lookup, the one `pinrender render` uses and the least biased this library
/// offers (`pinrt::SamplerOptions::RENDER`, `docs/sampling.md` sections 11-15). A newly
/// opened grid has it, and NULL `PinrtQueryOptions` give its jitter; a caller's
/// `PinrtQueryOptions` sets both jitters to these to keep it. `pinrt_set_lookup(grid,
/// PINRT_RENDER_CHAIN_STRIDE, PINRT_RENDER_MIDPOINT_LOOKUP, PINRT_RENDER_START_INSIDE)` and
/// `pinrt_set_nearest_line(grid, PINRT_RENDER_NEAREST_LINE)` restore the rest.
pub const PINRT_RENDER_SPATIAL_JITTER: f32 = 1.0;
/// See `PINRT_RENDER_SPATIAL_JITTER`.
pub const PINRT_RENDER_DIRECTIONAL_JITTER: f32 = 1.0;
/// See `PINRT_RENDER_SPATIAL_JITTER` (32: one lookup per query).
pub const PINRT_RENDER_CHAIN_STRIDE: u32 = 32;
/// See `PINRT_RENDER_SPATIAL_JITTER`.
pub const PINRT_RENDER_MIDPOINT_LOOKUP: u32 = 1;
/// See `PINRT_RENDER_SPATIAL_JITTER`.
pub const PINRT_RENDER_START_INSIDE: u32 = 1;
/// See `PINRT_RENDER_SPATIAL_JITTER` (`pinrt_set_nearest_line`).
pub const PINRT_RENDER_NEAREST_LINE: u32 = 8;
/// The thesis' lookup (`pinrt::SamplerOptions::THESIS`: no jitter, one lookup per query at
/// the segment start, the cell that holds that point): set both jitters of
/// `PinrtQueryOptions` to these, call `pinrt_set_lookup(grid, PINRT_THESIS_CHAIN_STRIDE,
/// PINRT_THESIS_MIDPOINT_LOOKUP, PINRT_THESIS_START_INSIDE)` and
/// `pinrt_set_nearest_line(grid, PINRT_THESIS_NEAREST_LINE)`.
pub const PINRT_THESIS_SPATIAL_JITTER: f32 = 0.0;
/// See `PINRT_THESIS_SPATIAL_JITTER`.
pub const PINRT_THESIS_DIRECTIONAL_JITTER: f32 = 0.0;
/// See `PINRT_THESIS_SPATIAL_JITTER` (0: one lookup per query).
pub const PINRT_THESIS_CHAIN_STRIDE: u32 = 0;
/// See `PINRT_THESIS_SPATIAL_JITTER`.
pub const PINRT_THESIS_MIDPOINT_LOOKUP: u32 = 0;
/// See `PINRT_THESIS_SPATIAL_JITTER`.
pub const PINRT_THESIS_START_INSIDE: u32 = 0;
/// See `PINRT_THESIS_SPATIAL_JITTER`.
pub const PINRT_THESIS_NEAREST_LINE: u32 = 0;
/// The most steps `pinrt_set_nearest_line` takes.
pub const PINRT_MAX_NEAREST_LINE: u32 = 64;

/// Sets how `grid` answers the batch calls and fills `pinrt_gpu_params` from now on, beside
/// the jitter of each call's `PinrtQueryOptions` (`docs/sampling.md` sections 12-14):
/// `chain_stride` intervals per lookup (0 or 32 and above: one lookup per query),
/// `midpoint_lookup` 1 to look each piece up at its middle instead of its start,
/// `start_inside` 1 to look a piece that starts inside the box up at its start without
/// spatial jitter. A newly opened grid has the default lookup's `PINRT_RENDER_*` values
/// (one lookup, middle, start inside; with both jitters 1 and
/// `PINRT_RENDER_NEAREST_LINE`); the thesis' lookup is 0, 0, 0 (`PINRT_THESIS_*`).
/// `midpoint_lookup` and `start_inside` other than 0 or 1
/// are `PINRT_INVALID_ARGUMENT`.
///
/// # Safety
/// `grid` is NULL or an open grid, not used by another thread during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_set_lookup(
    grid: *mut PinrtGrid,
    chain_stride: u32,
    midpoint_lookup: u32,
    start_inside: u32,
) -> PinrtStatus {
    guard("pinrt_set_lookup", || {
        // SAFETY: the caller's contract: NULL or an open grid used by no other thread.
        let g = unsafe { grid_mut(grid) }?;
        let flag = |name: &str, v: u32| match v {
            0 => Ok(false),
            1 => Ok(true),
            _ => Err(Fail(
                PinrtStatus::InvalidArgument,
                format!("{name} is {v}; it must be 0 or 1"),
            )),
        };
        g.lookup = Lookup {
            chain_stride,
            midpoint_lookup: flag("midpoint_lookup", midpoint_lookup)?,
            start_inside: flag("start_inside", start_inside)?,
            nearest_line: g.lookup.nearest_line,
        };
        Ok(())
    })
}

/// Sets the nearest-line lookup of `grid` for the batch calls and `pinrt_gpu_params` from now
/// on (`docs/sampling.md` section 15): each lookup reads, instead of the cell that holds its
/// point, the cell whose pin line passes nearest the point, searching `steps` one-cell steps
/// on each side along the direction cell's axis; the spatial jitter of `PinrtQueryOptions` is
/// then not applied. 0: off (the thesis' lookup); a newly opened grid has the default
/// lookup's `PINRT_RENDER_NEAREST_LINE`. Octahedral direction sets only: a polar grid reads the cell
/// that holds the point. `steps` above `PINRT_MAX_NEAREST_LINE` is `PINRT_INVALID_ARGUMENT`.
/// `pinrt_set_lookup` leaves this setting as it is.
///
/// # Safety
/// `grid` is NULL or an open grid, not used by another thread during the call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn pinrt_set_nearest_line(grid: *mut PinrtGrid, steps: u32) -> PinrtStatus {
    guard("pinrt_set_nearest_line", || {
        // SAFETY: the caller's contract: NULL or an open grid used by no other thread.
        let g = unsafe { grid_mut(grid) }?;
        if steps > PINRT_MAX_NEAREST_LINE {
            return Err(Fail(
                PinrtStatus::InvalidArgument,
                format!("steps is {steps}; it must be at most {PINRT_MAX_NEAREST_LINE}"),
            ));
        }
        g.lookup.nearest_line = steps;
        Ok(())
    })
}

/// The one-line message of the last failed call on this thread, or "" if the last call
/// succeeded. The pointer stays valid until the next `pinrt_*` call on this thread.
#[unsafe(no_mangle)]
pub extern "C" fn pinrt_last_error() -> *const c_char {
    catch_unwind(|| LAST_ERROR.with(|e| e.borrow().as_ptr()))
        .unwrap_or(c"internal error reading the last error".as_ptr())
}

/// The library version ("MAJOR.MINOR.PATCH"), a static string.
#[unsafe(no_mangle)]
pub extern "C" fn pinrt_version() -> *const c_char {
    const V: &CStr =
        match CStr::from_bytes_with_nul(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes()) {
            Ok(v) => v,
            Err(_) => c"unknown",
        };
    V.as_ptr()
}

#[cfg(test)]
mod tests;
