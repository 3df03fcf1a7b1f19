//! The GPU renderer's copies of the densities (`pinrender::volume::Opened::gpu_density`)
//! against their pinbake sources: a raw grid, a sparse VDB (densified with a zero border),
//! cosine noise and a homogeneous box.

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;
use pin_volume::{DensityScale, VdbOptions, VdbSource};
use pinrender::volume::{Opened, VolumeArgs, open_volume_typed};

fn data(name: &str) -> String {
    format!("{}/../data/{name}", env!("CARGO_MANIFEST_DIR"))
}

fn args(density_scale: f64, spacing: Option<[f64; 3]>) -> VolumeArgs {
    let mut a = VolumeArgs::scaled(DensityScale::new(density_scale).unwrap());
    a.read.spacing = spacing;
    a
}

/// The GPU copy of each kind of source gives the source's extinction at random points
/// of (and around) its box: the dense copy of a sparse VDB included.
#[test]
fn gpu_density_reproduces_the_source() {
    let cases = [
        (
            data("hydrogen_atom_128x128x128_uint8.raw"),
            args(0.6, Some([1.0 / 128.0; 3])),
        ),
        (
            "procedural:cosine:seed=7,freq=16,waves=8,density=4".to_string(),
            args(1.0, None),
        ),
        ("procedural:box:density=3".to_string(), args(1.0, None)),
    ];
    let mut opened_cases = Vec::new();
    // The VDB reader runs in a worker process: pinrender's own `__vdb-worker`.
    let smoke = data("openvdb_smoke1.vdb");
    let opts = VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinrender"));
    opened_cases.push((
        smoke.clone(),
        Opened::Vdb(Arc::new(
            VdbSource::open(Path::new(&smoke), &opts, DensityScale::new(2.0).unwrap()).unwrap(),
        )),
    ));
    for (input, a) in cases {
        opened_cases.push((input.clone(), open_volume_typed(&input, &a).unwrap()));
    }
    for (input, opened) in opened_cases {
        let src = opened.source();
        let gpu = opened.gpu_density().unwrap();
        let b = src.bounds();
        assert_eq!(gpu.bounds, (b.min.to_array(), b.max.to_array()), "{input}");
        let scale = src.max_extinction_in(b).max(1e-6) as f64;
        let mut rng = pinrender::render::Pcg32::new(3, 4);
        let mut worst = 0.0f64;
        let mut nonzero = 0;
        for _ in 0..20_000 {
            // 10% beyond the box on each side: outside must be 0 on both.
            let p = [0, 1, 2].map(|k| {
                let e = b.max[k] - b.min[k];
                b.min[k] - 0.1 * e + 1.2 * e * rng.next_f64()
            });
            let want = f64::from(src.extinction(DVec3::from_array(p)));
            let got = gpu.extinction(p);
            worst = worst.max((got - want).abs() / scale);
            if want > 0.0 {
                nonzero += 1;
            }
        }
        assert!(nonzero > 1000, "{input}: only {nonzero} non-zero samples");
        assert!(worst < 1e-5, "{input}: worst relative difference {worst}");
    }
    // No GPU form: a clear error.
    let sphere = open_volume_typed("procedural:sphere", &args(1.0, None)).unwrap();
    let e = sphere.gpu_density().unwrap_err().to_string();
    assert!(e.contains("no form"), "{e}");
}

/// The trackers' dense view of a source (`TrackedSource`'s `dense_view`: a raw grid as is, a
/// VDB through its dense copy) gives the source's extinction at random points of its box,
/// read at the f32 index the trackers step to.
#[test]
fn tracker_dense_view_reproduces_the_source() {
    use pin_volume::Density;
    use pinrender::volume::TrackedSource;
    let smoke = data("openvdb_smoke1.vdb");
    let opts = VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinrender"));
    let sources: Vec<Arc<dyn pin_volume::DensitySource>> = vec![
        Arc::new(
            VdbSource::open(Path::new(&smoke), &opts, DensityScale::new(2.0).unwrap()).unwrap(),
        ),
        open_volume_typed(
            data("hydrogen_atom_128x128x128_uint8.raw"),
            &args(0.6, Some([1.0 / 128.0; 3])),
        )
        .unwrap()
        .source(),
    ];
    for src in sources {
        let field = TrackedSource::new(src.clone());
        let view = field.dense_view().expect("a dense view");
        let (lo, hi) = field.bounds().to_arrays();
        let scale = src.max_extinction_in(src.bounds()) as f64;
        let mut rng = pinrender::render::Pcg32::new(5, 6);
        let (mut worst, mut nonzero) = (0.0f64, 0);
        for _ in 0..50_000 {
            let p = [0, 1, 2].map(|k| lo[k] + (hi[k] - lo[k]) * rng.next_f64());
            let want = src.extinction(DVec3::from(p)) as f64;
            let got = view.at(view.index(p).map(|v| v as f32)) as f64;
            worst = worst.max((got - want).abs() / scale);
            nonzero += usize::from(want > 0.0);
        }
        // f32 index rounding: a few 1e-7 of a voxel's contrast.
        assert!(
            worst < 1e-4,
            "{}: worst relative error {worst}",
            src.describe()
        );
        assert!(
            nonzero > 1000,
            "{}: only {nonzero} non-zero points",
            src.describe()
        );
    }
}

/// A VDB over the dense GPU limit goes to the GPU in bricks (`gpu_density_or_bricks`, here
/// with a limit of 0 voxels): the source's extinction, as the dense copy gives it, and a
/// density under the limit keeps its dense copy.
#[test]
fn a_vdb_over_the_dense_limit_goes_to_the_gpu_in_bricks() {
    use pin_volume::Density;
    use pinrender::gpu_render::GpuDensityKind;
    use pinrender::volume::TrackedSource;
    let smoke = data("openvdb_smoke1.vdb");
    let opts = VdbOptions::with_worker(env!("CARGO_BIN_EXE_pinrender"));
    let vdb = Arc::new(
        VdbSource::open(Path::new(&smoke), &opts, DensityScale::new(2.0).unwrap()).unwrap(),
    );
    let opened = Opened::Vdb(vdb.clone());
    let field = TrackedSource::new(opened.source());
    let dense = opened.gpu_density_or_bricks(&field, 1 << 28).unwrap();
    assert!(matches!(dense.kind, GpuDensityKind::Voxels(_)));
    let bricked = opened.gpu_density_or_bricks(&field, 0).unwrap();
    let GpuDensityKind::Bricks(grid) = &bricked.kind else {
        panic!("not bricked: {:?}", bricked.bounds)
    };
    let (dims, _, stored) = grid.shape();
    let all = dims
        .iter()
        .map(|&d| u64::from(d.div_ceil(8)))
        .product::<u64>();
    assert!((stored as u64) < all, "{stored} of {all} bricks stored");
    assert_eq!(bricked.bounds, dense.bounds);
    let b = vdb.bounds();
    let scale = vdb.max_extinction_in(b) as f64;
    let mut rng = pinrender::render::Pcg32::new(8, 9);
    let (mut worst, mut nonzero) = (0.0f64, 0);
    for _ in 0..20_000 {
        let p = [0, 1, 2].map(|k| {
            let e = b.max[k] - b.min[k];
            b.min[k] - 0.1 * e + 1.2 * e * rng.next_f64()
        });
        let want = f64::from(vdb.extinction(DVec3::from_array(p)));
        let got = bricked.extinction(p);
        worst = worst.max((got - want).abs() / scale);
        nonzero += usize::from(want > 0.0);
        assert!((got - dense.extinction(p)).abs() <= 1e-5 * scale, "{p:?}");
    }
    assert!(nonzero > 1000, "only {nonzero} non-zero samples");
    assert!(worst < 1e-5, "worst relative difference {worst}");
}
