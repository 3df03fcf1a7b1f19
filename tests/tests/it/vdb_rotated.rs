//! A rotated VDB renders where OpenVDB's index-to-world says: the grid written by OpenVDB with
//! an `AffineMap` (pinbake/tests/openvdb/corpus.cpp) is read, baked in its index space with
//! the affine recorded as the pin file's `local_to_world`, loaded by pinrt, and queried along
//! world rays placed with OpenVDB's own transform (from its dump, not from our reader).

#[path = "../../../pinbake/tests/openvdb/mod.rs"]
mod openvdb;

use glam::{DMat3, DVec3};
use pin_format::Directions;
use pin_volume::{Density, VdbOptions, VdbSource};
use pinbake::{BakeOptions, bake};
use pinrt::{PinGrid, Ray, Rng, Sampler};

/// OpenVDB's index-to-world of one grid, rebuilt from its dumped probes (the map is affine, so
/// the images of the origin and the three unit points determine it).
struct OpenVdbMap {
    origin: DVec3,
    lin: DMat3,
}

impl OpenVdbMap {
    fn from(g: &openvdb::Grid) -> Self {
        let w = |k: usize| DVec3::from_array(g.index_to_world[k].1);
        assert_eq!(g.index_to_world[0].0, [0.0, 0.0, 0.0]);
        let origin = w(0);
        Self {
            origin,
            lin: DMat3::from_cols(w(1) - origin, w(2) - origin, w(3) - origin),
        }
    }
    fn world(&self, i: DVec3) -> DVec3 {
        self.lin * i + self.origin
    }
    fn index(&self, w: DVec3) -> DVec3 {
        self.lin.inverse() * (w - self.origin)
    }
}

fn bake_opts() -> BakeOptions {
    BakeOptions {
        cells: [10, 6, 12],
        directions: Directions::Polar {
            n_phi: 16,
            n_theta: 16,
        },
        pins_per_entry: 1,
        step: 0.005,
        threads: Some(2),
        ..BakeOptions::default()
    }
}

/// Mean of `n` transmittance estimates along `ray` (a fixed seed: deterministic).
fn pin_transmittance(s: &Sampler<'_>, ray: &Ray, n: u32) -> f64 {
    let mut rng = Rng::new(0x5eed);
    (0..n)
        .map(|_| f64::from(s.transmittance(ray, f32::INFINITY, &mut rng)))
        .sum::<f64>()
        / f64::from(n)
}

fn ray(origin: DVec3, dir: DVec3) -> Ray {
    Ray::new(origin.as_vec3().to_array(), dir.as_vec3().to_array())
}

#[test]
fn rotated_grid_renders_where_openvdb_places_it() {
    let dir = openvdb::corpus(env!("CARGO_TARGET_TMPDIR"), "pin-tests");
    let files = openvdb::manifest(dir);
    let f = files
        .iter()
        .find(|f| f.file.ends_with("transforms.vdb"))
        .expect("transforms.vdb in the corpus");
    let g = f
        .grids
        .iter()
        .find(|g| g.name == "rotated_nonuniform")
        .expect("the rotated grid");
    assert_eq!(g.map, "AffineMap");
    let vdb = OpenVdbMap::from(g);

    let opt = VdbOptions {
        grid: Some(g.name.clone()),
        ..VdbOptions::with_worker(env!("CARGO_BIN_EXE_pin-tests-vdb-worker"))
    };
    let src = VdbSource::open(&f.file, &opt, pin_volume::DensityScale::ONE)
        .expect("the rotated grid opens");
    let (owned, _) = bake(&src, &bake_opts(), &|_| {}).expect("the rotated grid bakes");
    // Baked in the grid's own frame: the pin box is the index box (-3,-1,0)..(7,5,11)
    // scaled per axis, placed by the rotation and OpenVDB's translation.
    let scale = DVec3::new(
        vdb.lin.x_axis.length(),
        vdb.lin.y_axis.length(),
        vdb.lin.z_axis.length(),
    );
    let close = |a: [f64; 3], b: DVec3| (DVec3::from_array(a) - b).abs().max_element() < 1e-12;
    assert!(close(
        owned.desc.box_min,
        DVec3::new(-3.0, -1.0, 0.0) * scale
    ));
    assert!(close(
        owned.desc.box_max,
        DVec3::new(7.0, 5.0, 11.0) * scale
    ));
    let grid = PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap();
    let sampler = grid.sampler().unwrap();

    // The box of density 1 spans index voxels (-2,0,1)..(5,3,9). Through its centre, along
    // the image of the index z axis, trilinear density is 1 over 8 voxels plus two ramps of
    // half a voxel: optical depth 9 index units times the world length of one.
    let ez = vdb.lin.z_axis;
    let d = ez.normalize();
    let centre = vdb.world(DVec3::new(1.5, 1.5, 5.0));
    let through = ray(centre - d * 10.0, d);
    let t_exact = (-9.0 * ez.length()).exp();
    let t_world = pinrt::march::transmittance(
        |p| src.extinction(p),
        &pinrt::march::MarchBox {
            min: src.bounds().min,
            max: src.bounds().max,
        },
        centre - d * 10.0,
        d,
        f64::INFINITY,
        1e-4,
    );
    let t_pins = pin_transmittance(&sampler, &through, 512);
    eprintln!(
        "through OpenVDB's centre {centre}: exact {t_exact:.4}, world march {t_world:.4}, pins {t_pins:.4}"
    );
    // Our world-space sampler agrees with OpenVDB's placement to the marching error.
    assert!((t_world - t_exact).abs() < 1e-3, "{t_world} vs {t_exact}");
    // The pins agree to the pin model's resolution (32 intervals per chord, direction cells
    // of up to ~20 degrees around this ray); a misplaced grid would give 1.
    assert!((t_pins - t_exact).abs() < 0.1, "{t_pins} vs {t_exact}");

    // Where a reader that ignored the rotation would put the box centre (scale only). That
    // point is outside the real grid's index box, so nothing is there.
    let naive = DVec3::new(1.5, 1.5, 5.0) * scale + vdb.origin;
    let at = vdb.index(naive);
    assert!(
        at.x < -3.2 || at.x > 7.2 || at.y < -1.2 || at.y > 5.2,
        "test setup: the unrotated centre {naive} must lie outside the rotated grid ({at})"
    );
    let beside = ray(naive - d * 10.0, d);
    assert_eq!(pin_transmittance(&sampler, &beside, 64), 1.0);
    // Control: placing the same pins without the rotation attenuates that ray, so the check
    // above can fail.
    let m = owned.desc.local_to_world;
    let unrotated = [
        1.0, 0.0, 0.0, m[3], 0.0, 1.0, 0.0, m[7], 0.0, 0.0, 1.0, m[11],
    ];
    let wrong = Sampler::with_local_to_world(&grid, &unrotated).unwrap();
    let t_wrong = pin_transmittance(&wrong, &beside, 512);
    eprintln!("unrotated placement at {naive}: pins {t_wrong:.4} (the real placement gives 1)");
    assert!(t_wrong < 0.5, "{t_wrong}");
}
