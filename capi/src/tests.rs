//! The C ABI called from Rust: argument checks, error messages, and agreement with the Rust
//! sampler bit for bit.

use std::ffi::{CStr, CString};
use std::ptr;

use pin_format::Directions;
use pinrt::testing::random_grid;
use pinrt::{PinGrid, QueryResult, RayQuery, Rng};

use super::*;

fn last_error() -> String {
    // SAFETY: the pointer is valid until the next call on this thread.
    unsafe { CStr::from_ptr(pinrt_last_error()) }
        .to_string_lossy()
        .into_owned()
}

fn grid_bytes(sparse: bool) -> Vec<u8> {
    random_grid(Directions::THESIS_DEFAULT, [5, 4, 3], 2, sparse, 11)
        .to_bytes()
        .unwrap()
}

fn open_mem(bytes: &[u8]) -> *mut PinrtGrid {
    let mut g = ptr::null_mut();
    // SAFETY: valid buffer and out pointer.
    let st = unsafe { pinrt_open_memory(bytes.as_ptr(), bytes.len(), &mut g) };
    assert_eq!(st, PinrtStatus::Ok, "{}", last_error());
    assert!(!g.is_null());
    g
}

/// Rays from around the unit box through it, some invalid or missing, with finite and
/// infinite segment ends.
fn rays(n: usize) -> Vec<PinrtRay> {
    let mut rng = Rng::for_query(99, 1);
    (0..n)
        .map(|i| {
            let mut u = || rng.next_f32() * 3.0 - 1.0;
            let o = [u(), u(), u()];
            let target = [u() * 0.5 + 0.25, u() * 0.5 + 0.25, u() * 0.5 + 0.25];
            let mut d = [target[0] - o[0], target[1] - o[1], target[2] - o[2]];
            if i % 97 == 0 {
                d = [f32::NAN, 0.0, 1.0];
            }
            let t_max = if i % 3 == 0 {
                f32::INFINITY
            } else {
                u().abs() * 2.0
            };
            PinrtRay {
                origin: o,
                t_max,
                dir: d,
                pad: 0,
            }
        })
        .collect()
}

#[test]
fn layouts_match_the_rust_and_gpu_records() {
    assert_eq!(size_of::<PinrtRay>(), size_of::<RayQuery>());
    assert_eq!(align_of::<PinrtRay>(), align_of::<RayQuery>());
    assert_eq!(size_of::<PinrtResult>(), size_of::<QueryResult>());
    assert_eq!(size_of::<PinrtRay>(), 32);
    assert_eq!(size_of::<PinrtResult>(), 32);
}

#[test]
fn batches_equal_the_rust_sampler_bit_for_bit() {
    for sparse in [false, true] {
        let bytes = grid_bytes(sparse);
        let g = open_mem(&bytes);
        let reference = PinGrid::from_bytes(bytes.clone()).unwrap();
        let s = reference.sampler().unwrap();
        let rs = rays(1000);
        let rq: Vec<RayQuery> = bytemuck::cast_slice(&rs).to_vec();
        let (seed, first) = (4242, 17);

        let mut want = vec![QueryResult::zeroed(); rs.len()];
        s.query_batch(&rq, seed, first, &mut want);

        let mut t = vec![0f32; rs.len()];
        let mut d = vec![0f32; rs.len()];
        let mut q = vec![PinrtResult::default(); rs.len()];
        // SAFETY: all buffers hold `rs.len()` elements.
        unsafe {
            let n = rs.len();
            assert_eq!(
                pinrt_transmittance(g, ptr::null(), rs.as_ptr(), n, seed, first, t.as_mut_ptr()),
                PinrtStatus::Ok
            );
            assert_eq!(
                pinrt_sample_distance(g, ptr::null(), rs.as_ptr(), n, seed, first, d.as_mut_ptr()),
                PinrtStatus::Ok
            );
            assert_eq!(
                pinrt_query(g, ptr::null(), rs.as_ptr(), n, seed, first, q.as_mut_ptr()),
                PinrtStatus::Ok
            );
        }
        let mut misses = 0;
        for i in 0..rs.len() {
            assert_eq!(t[i].to_bits(), want[i].transmittance.to_bits(), "ray {i}");
            assert_eq!(d[i].to_bits(), want[i].distance.to_bits(), "ray {i}");
            assert_eq!(
                bytemuck::bytes_of(&q[i]),
                bytemuck::bytes_of(&want[i]),
                "ray {i}"
            );
            misses += usize::from(want[i].status != pinrt::status::OK);
        }
        // The rays exercise all three statuses, not only the easy one.
        assert!(misses > 0 && misses < rs.len() / 2, "{misses} misses");
        // SAFETY: opened above, closed once.
        unsafe { pinrt_close(g) };
    }
}

/// `pinrt_set_nearest_line` on an octahedral grid (the polar grid of the test below reads the
/// home cell whatever the steps): with `pinrt_set_lookup(32, 1, 1)` and both jitters 1 the
/// batch answers are `SamplerOptions::RENDER`'s bit for bit, and not those of steps 0.
#[test]
fn set_nearest_line_reaches_the_batches() {
    let bytes = random_grid(Directions::Octahedral { n: 6 }, [7, 6, 8], 2, true, 12)
        .to_bytes()
        .unwrap();
    let g = open_mem(&bytes);
    let reference = PinGrid::from_bytes(bytes.clone()).unwrap();
    let mut rs = rays(600);
    let mut rng = Rng::for_query(8, 3);
    for r in rs.iter_mut().step_by(2) {
        r.origin = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
    }
    let rq: Vec<RayQuery> = bytemuck::cast_slice(&rs).to_vec();
    let n = rs.len();
    let opts = PinrtQueryOptions {
        spatial_jitter: PINRT_RENDER_SPATIAL_JITTER,
        directional_jitter: PINRT_RENDER_DIRECTIONAL_JITTER,
        local_to_world: ptr::null(),
    };
    let answers = |steps: u32| {
        let mut t = vec![0f32; n];
        // SAFETY: an open grid used by this thread only; buffers sized `n`.
        unsafe {
            assert_eq!(
                pinrt_set_lookup(
                    g,
                    PINRT_RENDER_CHAIN_STRIDE,
                    PINRT_RENDER_MIDPOINT_LOOKUP,
                    PINRT_RENDER_START_INSIDE
                ),
                PinrtStatus::Ok
            );
            assert_eq!(pinrt_set_nearest_line(g, steps), PinrtStatus::Ok);
            assert_eq!(
                pinrt_transmittance(g, &opts, rs.as_ptr(), n, 9, 0, t.as_mut_ptr()),
                PinrtStatus::Ok
            );
        }
        t
    };
    let near = answers(PINRT_RENDER_NEAREST_LINE);
    let mut want = vec![0f32; n];
    reference
        .sampler()
        .unwrap()
        .with_options(SamplerOptions::RENDER)
        .transmittance_batch(&rq, 9, 0, &mut want);
    for i in 0..n {
        assert_eq!(near[i].to_bits(), want[i].to_bits(), "ray {i}");
    }
    assert_ne!(
        near,
        answers(0),
        "the nearest-line setting did not reach the sampler"
    );
    // SAFETY: opened above, closed once.
    unsafe { pinrt_close(g) };
}

#[test]
fn set_lookup_reaches_the_batches_and_the_gpu_params() {
    let bytes = grid_bytes(false);
    let g = open_mem(&bytes);
    let reference = PinGrid::from_bytes(bytes.clone()).unwrap();
    // Rays from around the box and, for `start_inside`, from points inside it.
    let mut rs = rays(600);
    let mut rng = Rng::for_query(7, 3);
    for r in rs.iter_mut().step_by(2) {
        r.origin = [rng.next_f32(), rng.next_f32(), rng.next_f32()];
    }
    let rq: Vec<RayQuery> = bytemuck::cast_slice(&rs).to_vec();
    let opts = PinrtQueryOptions {
        spatial_jitter: 1.0,
        directional_jitter: 1.0,
        local_to_world: ptr::null(),
    };
    let n = rs.len();
    let answers = |g: *const PinrtGrid| {
        let mut t = vec![0f32; n];
        let mut q = vec![PinrtResult::default(); n];
        // SAFETY: buffers sized `n`.
        unsafe {
            assert_eq!(
                pinrt_transmittance(g, &opts, rs.as_ptr(), n, 9, 0, t.as_mut_ptr()),
                PinrtStatus::Ok
            );
            assert_eq!(
                pinrt_query(g, &opts, rs.as_ptr(), n, 9, 0, q.as_mut_ptr()),
                PinrtStatus::Ok
            );
        }
        (t, q)
    };
    // A newly opened grid has the default lookup, `SamplerOptions::RENDER`, and so do NULL
    // options.
    let mut p = PinrtGpuParams::default();
    // SAFETY: valid grid and out pointer; NULL options.
    assert_eq!(
        unsafe { pinrt_gpu_params(g, ptr::null(), &mut p) },
        PinrtStatus::Ok
    );
    let r = SamplerOptions::RENDER;
    assert_eq!(
        p.jitter,
        [
            r.spatial_jitter,
            r.directional_jitter,
            r.stride() as f32,
            r.lookup_mode()
        ]
    );
    // The thesis' lookup, against which every setting below must change the answers.
    // SAFETY: an open grid, used by this thread only.
    unsafe {
        assert_eq!(
            pinrt_set_lookup(
                g,
                PINRT_THESIS_CHAIN_STRIDE,
                PINRT_THESIS_MIDPOINT_LOOKUP,
                PINRT_THESIS_START_INSIDE
            ),
            PinrtStatus::Ok
        );
        assert_eq!(
            pinrt_set_nearest_line(g, PINRT_THESIS_NEAREST_LINE),
            PinrtStatus::Ok
        );
    }
    let (plain_t, _) = answers(g);
    for (stride, middle, inside, nearest) in [
        (0, 1, 1, 0),
        (4, 0, 1, 0),
        (7, 1, 0, 0),
        (0, 1, 1, PINRT_RENDER_NEAREST_LINE),
        (4, 0, 1, 3),
    ] {
        // SAFETY: an open grid, used by this thread only.
        unsafe {
            assert_eq!(pinrt_set_lookup(g, stride, middle, inside), PinrtStatus::Ok);
            assert_eq!(pinrt_set_nearest_line(g, nearest), PinrtStatus::Ok);
        }
        let s = reference.sampler().unwrap().with_options(SamplerOptions {
            spatial_jitter: 1.0,
            directional_jitter: 1.0,
            chain_stride: stride,
            midpoint_lookup: middle == 1,
            start_inside: inside == 1,
            nearest_line: nearest,
        });
        let mut want_t = vec![0f32; n];
        let mut want_q = vec![QueryResult::zeroed(); n];
        s.transmittance_batch(&rq, 9, 0, &mut want_t);
        s.query_batch(&rq, 9, 0, &mut want_q);
        let (t, q) = answers(g);
        for i in 0..n {
            assert_eq!(
                t[i].to_bits(),
                want_t[i].to_bits(),
                "{stride} {middle} {inside}: ray {i}"
            );
            assert_eq!(bytemuck::bytes_of(&q[i]), bytemuck::bytes_of(&want_q[i]));
        }
        // The lookup reached the sampler: not the thesis lookup's answers.
        assert_ne!(t, plain_t, "{stride} {middle} {inside}");
        let mut p = PinrtGpuParams::default();
        // SAFETY: valid grid, options and out pointer.
        assert_eq!(
            unsafe { pinrt_gpu_params(g, &opts, &mut p) },
            PinrtStatus::Ok
        );
        let bits = (middle | (inside << 1) | (nearest << 2)) as f32;
        let z = if stride == 0 { 0.0 } else { stride as f32 };
        assert_eq!(p.jitter, [1.0, 1.0, z, bits]);
    }
    // Flags other than 0 and 1, and a null grid, are refused with a message.
    // SAFETY: an open grid, then null.
    unsafe {
        assert_eq!(pinrt_set_lookup(g, 0, 2, 0), PinrtStatus::InvalidArgument);
        assert!(
            last_error().contains("midpoint_lookup is 2"),
            "{}",
            last_error()
        );
        assert_eq!(pinrt_set_lookup(g, 0, 0, 7), PinrtStatus::InvalidArgument);
        assert!(
            last_error().contains("start_inside is 7"),
            "{}",
            last_error()
        );
        assert_ne!(pinrt_set_lookup(ptr::null_mut(), 0, 0, 0), PinrtStatus::Ok);
        assert_eq!(
            pinrt_set_nearest_line(g, PINRT_MAX_NEAREST_LINE + 1),
            PinrtStatus::InvalidArgument
        );
        assert!(last_error().contains("steps is 65"), "{}", last_error());
        assert_ne!(pinrt_set_nearest_line(ptr::null_mut(), 1), PinrtStatus::Ok);
        pinrt_close(g);
    }
}

#[test]
fn options_jitter_and_placement_reach_the_sampler() {
    let bytes = grid_bytes(false);
    let g = open_mem(&bytes);
    let reference = PinGrid::from_bytes(bytes.clone()).unwrap();
    let l2w = [2.0, 0.0, 0.0, 1.0, 0.0, 2.0, 0.0, -1.0, 0.0, 0.0, 2.0, 0.5];
    let s = pinrt::Sampler::with_local_to_world(&reference, &l2w)
        .unwrap()
        .with_options(SamplerOptions {
            spatial_jitter: 0.5,
            directional_jitter: 1.0,
            ..SamplerOptions::default()
        });
    let rs = rays(300);
    let mut want = vec![0f32; rs.len()];
    s.transmittance_batch(bytemuck::cast_slice(&rs), 5, 0, &mut want);
    let opts = PinrtQueryOptions {
        spatial_jitter: 0.5,
        directional_jitter: 1.0,
        local_to_world: l2w.as_ptr(),
    };
    let mut got = vec![0f32; rs.len()];
    let mut plain = vec![0f32; rs.len()];
    // SAFETY: buffers sized `rs.len()`; `l2w` holds 12 doubles.
    unsafe {
        assert_eq!(
            pinrt_transmittance(g, &opts, rs.as_ptr(), rs.len(), 5, 0, got.as_mut_ptr()),
            PinrtStatus::Ok
        );
        assert_eq!(
            pinrt_transmittance(
                g,
                ptr::null(),
                rs.as_ptr(),
                rs.len(),
                5,
                0,
                plain.as_mut_ptr()
            ),
            PinrtStatus::Ok
        );
    }
    assert_eq!(got, want);
    // The options changed something (else this test could not tell them from no options).
    assert_ne!(got, plain);

    let bad = PinrtQueryOptions {
        spatial_jitter: f32::NAN,
        ..opts
    };
    // SAFETY: as above.
    let st = unsafe { pinrt_transmittance(g, &bad, rs.as_ptr(), rs.len(), 5, 0, got.as_mut_ptr()) };
    assert_eq!(st, PinrtStatus::InvalidArgument);
    assert_eq!(
        last_error(),
        "options.spatial_jitter is NaN; it must be finite and >= 0"
    );
    let singular = [0.0; 12];
    let bad = PinrtQueryOptions {
        local_to_world: singular.as_ptr(),
        ..opts
    };
    // SAFETY: as above.
    let st = unsafe { pinrt_transmittance(g, &bad, rs.as_ptr(), rs.len(), 5, 0, got.as_mut_ptr()) };
    assert_eq!(st, PinrtStatus::InvalidArgument);
    assert!(
        last_error().starts_with("bad grid transform"),
        "{}",
        last_error()
    );
    // SAFETY: opened above.
    unsafe { pinrt_close(g) };
}

#[test]
fn describe_reports_the_file() {
    let bytes = grid_bytes(true);
    let g = open_mem(&bytes);
    let mut d = PinrtDesc::default();
    // SAFETY: valid grid and out pointer.
    assert_eq!(unsafe { pinrt_describe(g, &mut d) }, PinrtStatus::Ok);
    assert_eq!(d.dims, [5, 4, 3]);
    assert_eq!(d.direction_cells, 64);
    assert_eq!(d.pins_per_entry, 2);
    assert_eq!(d.sparse, 1);
    assert_eq!(d.mapped, 0);
    assert_eq!(d.file_bytes, bytes.len() as u64);
    assert_eq!(d.pin_count, d.stored_cells * 64 * 2);
    assert_eq!((d.z_begin, d.z_end), (0, 3));
    assert_eq!(d.world_min, [0.0; 3]);
    assert_eq!(d.world_max, [1.0; 3]);
    // SAFETY: valid grid.
    assert_eq!(unsafe { pinrt_verify(g) }, PinrtStatus::Ok);
    // SAFETY: opened above.
    unsafe { pinrt_close(g) };
}

#[test]
fn files_open_mapped_and_errors_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("g.pin");
    std::fs::write(&path, grid_bytes(false)).unwrap();
    let c = CString::new(path.to_str().unwrap()).unwrap();
    let mut g = ptr::null_mut();
    // SAFETY: valid string and out pointer.
    assert_eq!(unsafe { pinrt_open(c.as_ptr(), &mut g) }, PinrtStatus::Ok);
    assert_eq!(last_error(), "");
    let mut d = PinrtDesc::default();
    // SAFETY: valid grid and out pointer.
    assert_eq!(unsafe { pinrt_describe(g, &mut d) }, PinrtStatus::Ok);
    assert_eq!(d.mapped, 1);
    // SAFETY: opened above.
    unsafe { pinrt_close(g) };

    let missing = dir.path().join("missing.pin");
    let c = CString::new(missing.to_str().unwrap()).unwrap();
    let mut g = 0x10 as *mut PinrtGrid;
    // SAFETY: valid string and out pointer.
    assert_eq!(unsafe { pinrt_open(c.as_ptr(), &mut g) }, PinrtStatus::Io);
    assert!(g.is_null(), "a failed open leaves NULL behind");
    let msg = last_error();
    assert!(
        msg.starts_with(missing.to_str().unwrap()) && !msg.contains('\n'),
        "{msg}"
    );

    let mut truncated = grid_bytes(false);
    truncated.truncate(truncated.len() / 2);
    let p = dir.path().join("short.pin");
    std::fs::write(&p, &truncated).unwrap();
    let c = CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: valid string and out pointer.
    assert_eq!(
        unsafe { pinrt_open(c.as_ptr(), &mut g) },
        PinrtStatus::Format
    );
    assert!(
        last_error().starts_with(p.to_str().unwrap()),
        "{}",
        last_error()
    );
    // SAFETY: valid buffer and out pointer.
    assert_eq!(
        unsafe { pinrt_open_memory(truncated.as_ptr(), truncated.len(), &mut g) },
        PinrtStatus::Format
    );
    assert!(last_error().starts_with("<memory>: "), "{}", last_error());
    // SAFETY: a zero-length buffer is never read.
    assert_eq!(
        unsafe { pinrt_open_memory(ptr::null(), 0, &mut g) },
        PinrtStatus::Format
    );
}

#[test]
fn null_misaligned_and_oversized_arguments_are_refused() {
    let bytes = grid_bytes(false);
    let g = open_mem(&bytes);
    let rs = rays(4);
    let mut out = [0f32; 8];
    let mut g2 = ptr::null_mut();
    // SAFETY: every call below is refused before touching memory, or gets valid buffers.
    unsafe {
        assert_eq!(pinrt_open(ptr::null(), &mut g2), PinrtStatus::NullPointer);
        assert_eq!(last_error(), "path is NULL");
        assert_eq!(
            pinrt_open(c"x".as_ptr(), ptr::null_mut()),
            PinrtStatus::NullPointer
        );
        assert_eq!(last_error(), "out is NULL");
        assert_eq!(
            pinrt_open_memory(ptr::null(), 5, &mut g2),
            PinrtStatus::NullPointer
        );
        assert_eq!(last_error(), "data is NULL");
        assert_eq!(
            pinrt_describe(ptr::null(), ptr::null_mut()),
            PinrtStatus::NullPointer
        );
        assert_eq!(last_error(), "grid is NULL");
        assert_eq!(pinrt_describe(g, ptr::null_mut()), PinrtStatus::NullPointer);
        assert_eq!(pinrt_verify(ptr::null()), PinrtStatus::NullPointer);
        assert_eq!(
            pinrt_transmittance(g, ptr::null(), ptr::null(), 4, 0, 0, out.as_mut_ptr()),
            PinrtStatus::NullPointer
        );
        assert_eq!(last_error(), "rays is NULL");
        assert_eq!(
            pinrt_sample_distance(g, ptr::null(), rs.as_ptr(), 4, 0, 0, ptr::null_mut()),
            PinrtStatus::NullPointer
        );
        assert_eq!(last_error(), "out is NULL");
        assert_eq!(
            pinrt_query(
                ptr::null(),
                ptr::null(),
                rs.as_ptr(),
                4,
                0,
                0,
                ptr::null_mut()
            ),
            PinrtStatus::NullPointer
        );
        // Zero rays need no buffers at all.
        assert_eq!(
            pinrt_transmittance(g, ptr::null(), ptr::null(), 0, 0, 0, ptr::null_mut()),
            PinrtStatus::Ok
        );
        assert_eq!(last_error(), "");
        // Misaligned output.
        let mis = out.as_mut_ptr().cast::<u8>().add(1).cast::<f32>();
        assert_eq!(
            pinrt_transmittance(g, ptr::null(), rs.as_ptr(), 4, 0, 0, mis),
            PinrtStatus::InvalidArgument
        );
        assert_eq!(last_error(), "out is not aligned to 4 bytes");
        // A length whose byte size overflows is refused before any slice is formed.
        assert_eq!(
            pinrt_transmittance(
                g,
                ptr::null(),
                rs.as_ptr(),
                usize::MAX / 8,
                0,
                0,
                out.as_mut_ptr()
            ),
            PinrtStatus::InvalidArgument
        );
        assert!(last_error().starts_with("rays: length"), "{}", last_error());
        pinrt_close(ptr::null_mut());
        pinrt_close(g);
    }
}

#[test]
fn panics_become_an_internal_status_with_a_message() {
    let st = guard("pinrt_test", || panic!("deliberate"));
    assert_eq!(st, PinrtStatus::Internal);
    assert_eq!(last_error(), "pinrt_test: internal error: deliberate");
    let st = guard("pinrt_test", || Ok(()));
    assert_eq!(st, PinrtStatus::Ok);
    assert_eq!(last_error(), "");
}

#[test]
fn errors_are_per_thread_and_one_line() {
    set_error("first line\nsecond");
    assert_eq!(last_error(), "first line");
    std::thread::spawn(|| assert_eq!(last_error(), ""))
        .join()
        .unwrap();
    // SAFETY: static string.
    let v = unsafe { CStr::from_ptr(pinrt_version()) };
    assert_eq!(v.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
}

#[test]
fn gpu_params_and_buffers_describe_the_grid_as_the_sampler_sees_it() {
    for sparse in [false, true] {
        let bytes = grid_bytes(sparse);
        let g = open_mem(&bytes);
        let reference = PinGrid::from_bytes(bytes.clone()).unwrap();
        let l2w = [0.0, -2.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, -4.0];
        let opts = PinrtQueryOptions {
            spatial_jitter: 0.25,
            directional_jitter: 0.0,
            local_to_world: l2w.as_ptr(),
        };
        let mut p = PinrtGpuParams::default();
        let mut b = PinrtGpuBuffers {
            pins: ptr::null(),
            pins_bytes: 0,
            cell_index: ptr::null(),
            cell_index_bytes: 0,
        };
        // SAFETY: valid grid, options and out pointers.
        unsafe {
            assert_eq!(pinrt_gpu_params(g, &opts, &mut p), PinrtStatus::Ok);
            assert_eq!(pinrt_gpu_buffers(g, &mut b), PinrtStatus::Ok);
        }
        let s = pinrt::Sampler::with_local_to_world(&reference, &l2w).unwrap();
        assert_eq!(p.rows, s.transform().rows);
        // The options' jitter and a newly opened grid's lookup, the default one: one lookup
        // per query (stride 32) and `SamplerOptions::RENDER`'s lookup mode bits.
        let r = SamplerOptions::RENDER;
        assert_eq!(p.jitter, [0.25, 0.0, r.stride() as f32, r.lookup_mode()]);
        assert_eq!(p.dims, [5, 4, 3, 0]);
        let stored = reference.desc().stored_cells as u32;
        assert_eq!(p.grid, [3, 2, 128, stored]);
        assert_eq!(p.dirs, [0, 16, 4, u32::from(sparse)]);
        assert_eq!(p.run, [0; 4]);
        assert_eq!(size_of::<PinrtGpuParams>(), 128);
        // SAFETY: the grid is open, so its bytes are alive.
        let pins = unsafe { std::slice::from_raw_parts(b.pins, b.pins_bytes) };
        assert_eq!(pins, reference.pins_bytes());
        assert_eq!(b.cell_index.is_null(), !sparse);
        assert_eq!(
            b.cell_index_bytes,
            reference.cell_index_bytes().map_or(0, <[u8]>::len)
        );
        // SAFETY: opened above.
        unsafe { pinrt_close(g) };
    }
}

#[test]
fn render_lookup_constants_are_the_rust_samplers() {
    // The `PINRT_RENDER_*` defines are `pinrt::SamplerOptions::RENDER`, field for field: a C
    // caller who sets them gets `pinrender render`'s lookup (the batches' bit-exactness for
    // any lookup is `set_lookup_reaches_the_batches_and_the_gpu_params`).
    let r = SamplerOptions::RENDER;
    assert_eq!(PINRT_RENDER_SPATIAL_JITTER, r.spatial_jitter);
    assert_eq!(PINRT_RENDER_DIRECTIONAL_JITTER, r.directional_jitter);
    assert_eq!(PINRT_RENDER_CHAIN_STRIDE, r.chain_stride);
    assert_eq!(PINRT_RENDER_MIDPOINT_LOOKUP == 1, r.midpoint_lookup);
    assert_eq!(PINRT_RENDER_START_INSIDE == 1, r.start_inside);
    assert_eq!(PINRT_RENDER_NEAREST_LINE, r.nearest_line);
    assert_eq!(PINRT_MAX_NEAREST_LINE, pinrt::MAX_NEAREST_LINE_STEPS);
    // The `PINRT_THESIS_*` defines are `pinrt::SamplerOptions::THESIS`, field for field.
    let t = SamplerOptions::THESIS;
    assert_eq!(PINRT_THESIS_SPATIAL_JITTER, t.spatial_jitter);
    assert_eq!(PINRT_THESIS_DIRECTIONAL_JITTER, t.directional_jitter);
    assert_eq!(PINRT_THESIS_CHAIN_STRIDE, t.chain_stride);
    assert_eq!(PINRT_THESIS_MIDPOINT_LOOKUP == 1, t.midpoint_lookup);
    assert_eq!(PINRT_THESIS_START_INSIDE == 1, t.start_inside);
    assert_eq!(PINRT_THESIS_NEAREST_LINE, t.nearest_line);
}

/// A grid with every section a renderer reads whole (majorant, dense and sparse density,
/// control), valid.
fn grid_with_bulk_sections() -> Vec<u8> {
    use pin_format::layout::DENSITY_F16;
    use pin_format::{
        DensityHeader, MajorantHeader, OwnedControl, OwnedSparseDensity, OwnedSparseValues,
        SparseDensityHeader,
    };
    let mut g = random_grid(Directions::THESIS_DEFAULT, [5, 4, 3], 2, true, 11);
    // f16 2.0, through its bits (the crate has no f16 type of its own).
    let two = || -> Vec<_> { vec![bytemuck::cast(0x4000u16); 64] };
    g.majorant = Some((
        MajorantHeader {
            dims: [2; 3],
            reserved: 0,
        },
        vec![4.0; 8],
    ));
    g.density = Some((
        DensityHeader {
            dims: [4; 3],
            encoding: DENSITY_F16,
        },
        two(),
    ));
    g.sparse_density = Some(OwnedSparseDensity {
        header: SparseDensityHeader {
            dims: [4; 3],
            encoding: DENSITY_F16,
            brick: 2,
            brick_count: 8,
            reserved: [0; 2],
        },
        index: (0..8).collect(),
        values: OwnedSparseValues::F16(two()),
    });
    g.control = Some(OwnedControl {
        dims: [2; 3],
        control: vec![1.0; 8],
        residual: vec![3.0; 8],
        majorant: vec![4.0; 8],
    });
    g.to_bytes().unwrap()
}

/// `pinrt_open` checks the structure (O(number of sections)); `pinrt_open_checked` and
/// `pinrt_verify` check every section: a section damaged so that its values stay in range
/// is refused with one line naming the file once and the section.
#[test]
fn checked_open_refuses_damaged_sections_naming_the_file_once_and_the_section() {
    use pin_format::{PinFile, SectionKind};
    let dir = tempfile::tempdir().unwrap();
    let clean = grid_with_bulk_sections();
    let open = |path: &std::path::Path, checked: bool| {
        let c = CString::new(path.to_str().unwrap()).unwrap();
        let mut g = 0x10 as *mut PinrtGrid;
        // SAFETY: valid string and out pointer.
        let st = unsafe {
            if checked {
                pinrt_open_checked(c.as_ptr(), &mut g)
            } else {
                pinrt_open(c.as_ptr(), &mut g)
            }
        };
        (st, g)
    };
    let ok = dir.path().join("clean.pin");
    std::fs::write(&ok, &clean).unwrap();
    let (st, g) = open(&ok, true);
    assert_eq!(st, PinrtStatus::Ok, "{}", last_error());
    // SAFETY: opened above.
    unsafe { pinrt_close(g) };
    for kind in [
        SectionKind::SparseDensity,
        SectionKind::Control,
        SectionKind::Majorant,
        SectionKind::Density,
        SectionKind::Pins,
    ] {
        let file = PinFile::parse(&clean).unwrap();
        let s = *file
            .sections()
            .iter()
            .find(|s| s.kind == kind as u32)
            .unwrap();
        // The low byte of the section's last value: a value a few ulps away, in range.
        let elem = if matches!(kind, SectionKind::Density | SectionKind::SparseDensity) {
            2
        } else {
            4
        };
        let mut bytes = clean.clone();
        bytes[(s.offset + s.length) as usize - elem] ^= 0x01;
        let path = dir.path().join(format!("{}.pin", kind.name()));
        std::fs::write(&path, &bytes).unwrap();
        let shown = path.to_str().unwrap();
        let want = format!("checksum mismatch in section '{}'", kind.name());
        let (st, g) = open(&path, false);
        assert_eq!(st, PinrtStatus::Ok, "{}: {}", kind.name(), last_error());
        // SAFETY: opened above.
        assert_eq!(unsafe { pinrt_verify(g) }, PinrtStatus::Format);
        let msg = last_error();
        assert!(
            msg.contains(&want) && msg.matches(shown).count() == 1,
            "{msg}"
        );
        // SAFETY: opened above.
        unsafe { pinrt_close(g) };
        let (st, g) = open(&path, true);
        assert_eq!(st, PinrtStatus::Format, "{}", kind.name());
        assert!(g.is_null(), "a refused open leaves NULL behind");
        let msg = last_error();
        assert!(
            msg.starts_with(shown) && msg.contains(&want) && msg.matches(shown).count() == 1,
            "{msg}"
        );
    }
    let mut cut = clean.clone();
    cut.truncate(cut.len() - 3);
    let path = dir.path().join("cut.pin");
    std::fs::write(&path, &cut).unwrap();
    for checked in [false, true] {
        let (st, _) = open(&path, checked);
        assert_eq!(st, PinrtStatus::Format);
        let msg = last_error();
        assert!(
            msg.contains("truncated") && msg.matches(path.to_str().unwrap()).count() == 1,
            "{msg}"
        );
    }
}
