//! docs/format.md section 7 re-implemented from the text alone (constants from their written
//! bit patterns) and compared bit for bit with the crate, so the spec cannot drift.

use crate::common::Rng;
use pin_format::{Directions, atan2_turns, octahedral_uv};

fn bin(x: f32, n: u32) -> u32 {
    (x as u32).min(n - 1)
}

fn spec_atan2_turns(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let (mx, mn) = (ax.max(ay), ax.min(ay));
    if mx == 0.0 {
        return 0.0;
    }
    let a = mn / mx;
    let s = a * a;
    let c = |bits: u32| f32::from_bits(bits);
    let mut r = a
        * (c(0x3F7F_F738)
            + s * (c(0xBEA9_1D04)
                + s * (c(0x3E38_76E2) + s * (c(0xBDAE_5A36) + s * c(0x3CAA_AE5F)))));
    if ay > ax {
        r = c(0x3FC9_0FDB) - r;
    }
    if x < 0.0 {
        r = c(0x4049_0FDB) - r;
    }
    if y < 0.0 {
        r = -r;
    }
    let mut turns = r * c(0x3E22_F983);
    if turns < 0.0 {
        turns += 1.0;
    }
    if turns >= 1.0 { 0.0 } else { turns }
}

fn spec_index_of(dirs: Directions, d: [f32; 3]) -> u32 {
    let [x, y, z] = d;
    match dirs {
        Directions::Polar { n_phi, n_theta } => {
            let len2 = x * x + y * y + z * z;
            let zn = z / len2.sqrt();
            let t = bin((1.0 - zn) * n_theta as f32, n_theta);
            let p = bin(spec_atan2_turns(y, x) * n_phi as f32, n_phi);
            t * n_phi + p
        }
        Directions::Octahedral { n } => {
            let s = x.abs() + y.abs() + z;
            let (px, py) = (x / s, y / s);
            let u = (px + py + 1.0) * 0.5;
            let v = (px - py + 1.0) * 0.5;
            assert_eq!((u, v), octahedral_uv(d));
            bin(v * n as f32, n) * n + bin(u * n as f32, n)
        }
    }
}

#[test]
fn written_spec_matches_the_code_bit_for_bit() {
    let mut rng = Rng(99);
    let all = [
        Directions::THESIS_DEFAULT,
        Directions::Polar {
            n_phi: 7,
            n_theta: 3,
        },
        Directions::Octahedral { n: 1 },
        Directions::Octahedral { n: 8 },
        Directions::Octahedral { n: 13 },
    ];
    for i in 0..200_000 {
        let mut d = [
            (rng.unit() * 2.0 - 1.0) as f32,
            (rng.unit() * 2.0 - 1.0) as f32,
            rng.unit() as f32,
        ];
        // Exact axes, diagonals and signed zeros now and then.
        match i % 16 {
            0 => d[0] = 0.0,
            1 => d[1] = -0.0,
            2 => d[2] = 0.0,
            3 => d[1] = d[0],
            4 => d[1] = -d[0],
            _ => {}
        }
        if d == [0.0; 3] {
            continue;
        }
        let (y, x) = (d[1], d[0]);
        assert_eq!(
            spec_atan2_turns(y, x).to_bits(),
            atan2_turns(y, x).to_bits(),
            "atan2_turns({y}, {x})"
        );
        for dirs in all {
            assert_eq!(spec_index_of(dirs, d), dirs.index_of(d), "{dirs:?} {d:?}");
        }
    }
}

#[test]
fn written_inverse_matches_the_code() {
    for dirs in [Directions::THESIS_DEFAULT, Directions::Octahedral { n: 5 }] {
        for index in 0..dirs.count() {
            for (a, b) in [(0.5, 0.5), (0.1, 0.9), (0.0, 0.0), (1.0, 1.0)] {
                let want = match dirs {
                    Directions::Polar { n_phi, n_theta } => {
                        let (t, p) = (index / n_phi, index % n_phi);
                        let z = 1.0 - (f64::from(t) + a) / f64::from(n_theta);
                        let phi =
                            (f64::from(p) + b) / f64::from(n_phi) * 2.0 * std::f64::consts::PI;
                        let r = (1.0 - z * z).max(0.0).sqrt();
                        [r * phi.cos(), r * phi.sin(), z]
                    }
                    Directions::Octahedral { n } => {
                        let (vb, ub) = (index / n, index % n);
                        let u = (f64::from(ub) + a) / f64::from(n);
                        let v = (f64::from(vb) + b) / f64::from(n);
                        let (px, py) = (u + v - 1.0, u - v);
                        let z = (1.0 - px.abs() - py.abs()).max(0.0);
                        let l = (px * px + py * py + z * z).sqrt();
                        [px / l, py / l, z / l]
                    }
                };
                let got = dirs.direction_in_cell(index, a, b);
                for k in 0..3 {
                    assert!((got[k] - want[k]).abs() < 1e-12, "{dirs:?} {index} {a} {b}");
                }
            }
        }
    }
}
