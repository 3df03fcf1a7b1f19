//! Precision figures for docs/stability.md: optical-depth accumulation in f32 (naive and
//! Kahan) vs f64 over long pins, the baker's own f64 path against closed forms, and the
//! closed-form stiff limits (cosine integral as w.S -> 0, whole-volume slope c -> 0).

use crate::common::Table;
use glam::DVec3;
use pin_volume::procedural::{CosineParams, sinc};
use pin_volume::{Aabb, CosineNoise, DensitySource, HomogeneousBox};
use pinbake::pin::{Placement, interval_optical_depths};
use pinrender::render::exprel;

/// Neumaier-compensated f64 sum: the reference for "the exact sum of these f32 samples".
fn neumaier(v: &[f32]) -> f64 {
    let (mut s, mut c) = (0.0f64, 0.0f64);
    for &x in v {
        let x = f64::from(x);
        let t = s + x;
        c += if s.abs() >= x.abs() {
            (s - t) + x
        } else {
            (x - t) + s
        };
        s = t;
    }
    s + c
}

fn kahan_f32(v: &[f32]) -> f32 {
    let (mut s, mut c) = (0.0f32, 0.0f32);
    for &x in v {
        let y = x - c;
        let t = s + y;
        c = (t - s) - y;
        s = t;
    }
    s
}

#[test]
fn optical_depth_accumulation_f32_vs_f64() {
    let unit = Aabb::new(DVec3::ZERO, DVec3::ONE);
    let hbox = HomogeneousBox::new(unit, 0.7).unwrap();
    let params = CosineParams {
        seed: 9,
        freq: 8.0,
        density: 5.0,
        ..CosineParams::default()
    };
    let noise = CosineNoise::new(unit, &params, "cos").unwrap();
    let mut table = Table::new(
        "optical depth of one pin summed from n midpoint samples: relative error of the sum against the exact sum of the same f32 samples (and, last column, of the f64 quadrature against the closed form)",
        &[
            "field",
            "n",
            "f32 naive",
            "f32 Kahan",
            "f64 (baker)",
            "f64 quadrature vs closed form",
        ],
    );
    let (p, d) = (
        DVec3::new(0.0, 0.31, 0.17),
        DVec3::new(1.0, 0.62, 0.35).normalize(),
    );
    let len = 1.0 / d.x; // x runs 0 -> 1; y, z stay inside
    let mut worst_f64 = 0.0f64;
    for (name, src, exact) in [
        (
            "homogeneous 0.7",
            &hbox as &dyn DensitySource,
            hbox.optical_depth(p, d, len),
        ),
        (
            "cosine freq 8",
            &noise as &dyn DensitySource,
            noise.optical_depth(p, d, len),
        ),
    ] {
        for e in 2..=6 {
            let n = 10usize.pow(e);
            let h = len / n as f64;
            let mut v = vec![0.0f32; n];
            src.extinction_along(p + d * (0.5 * h), d * h, n, &mut v);
            let reference = neumaier(&v);
            let naive = v.iter().sum::<f32>();
            let kahan = kahan_f32(&v);
            let f64sum = v.iter().map(|&x| f64::from(x)).sum::<f64>();
            let rel = |x: f64| ((x - reference) / reference).abs();
            let r64 = rel(f64sum);
            worst_f64 = worst_f64.max(r64);
            table.row(vec![
                name.into(),
                format!("1e{e}"),
                format!("{:.1e}", rel(f64::from(naive))),
                format!("{:.1e}", rel(f64::from(kahan))),
                format!("{r64:.1e}"),
                format!("{:.1e}", ((f64sum * h - exact) / exact).abs()),
            ]);
            assert!(r64 < 1e-9, "{name} n={n}: f64 accumulation off by {r64}");
        }
    }
    table.print();
    eprintln!("worst f64 accumulation error: {worst_f64:.1e}");
}

/// The baker's own path (`interval_optical_depths`, f64 sums) on a long pin through a
/// homogeneous box: the 32 interval depths sum to the closed form within 1e-9 relative at
/// every step count from 10^2 to 10^6 samples per pin.
#[test]
fn baker_interval_depths_match_closed_form() {
    let unit = Aabb::new(DVec3::ZERO, DVec3::ONE);
    let mut table = Table::new(
        "baker `interval_optical_depths` (f64 sums), homogeneous box, whole pin vs closed form",
        &["density", "samples per pin", "relative error"],
    );
    for density in [1e-3f32, 1.0, 1e6] {
        let hbox = HomogeneousBox::new(unit, density).unwrap();
        let (p, w) = (
            DVec3::new(0.3, 0.4, 0.0),
            DVec3::new(0.1, 0.2, 0.97).normalize(),
        );
        let (s0, s1) = pinbake::pin::unit_cube_chord(p, w).unwrap();
        let exact = f64::from(density) * (s1 - s0);
        for e in 2..=6 {
            let samples = 10f64.powi(e);
            let step = (s1 - s0) / samples;
            let placement = Placement {
                box_min: DVec3::ZERO,
                extent: DVec3::ONE,
                step,
            };
            let taus = interval_optical_depths(&hbox, &placement, p, w);
            let sum: f64 = taus.iter().sum();
            let rel = ((sum - exact) / exact).abs();
            table.row(vec![
                format!("{density:e}"),
                format!("1e{e}"),
                format!("{rel:.1e}"),
            ]);
            assert!(rel < 1e-9, "density {density}, 1e{e} samples: {rel}");
        }
    }
    table.print();
}

/// `integral_0^T cos(a + b s) ds` by its Taylor series in `b` (converged for `|b T| <= 0.1`).
fn cos_integral_series(a: f64, b: f64, t: f64) -> f64 {
    let (mut c_sum, mut s_sum) = (0.0, 0.0);
    let mut fact = 1.0; // k!
    for k in 0..20 {
        if k > 0 {
            fact *= k as f64;
        }
        let term = b.powi(k) * t.powi(k + 1) / (fact * (k + 1) as f64);
        match k % 4 {
            0 => c_sum += term,
            1 => s_sum += term,
            2 => c_sum -= term,
            _ => s_sum -= term,
        }
    }
    // cos(a + x) = cos a cos x - sin a sin x; the series above integrates cos x and sin x.
    a.cos() * c_sum - a.sin() * s_sum
}

#[test]
fn closed_form_stiff_limits() {
    let (a, t) = (0.3f64, 1.0f64);
    let mut table = Table::new(
        "cosine-noise integral integral_0^1 cos(0.3 + b s) ds as b = w.S -> 0: relative error",
        &[
            "b",
            "naive (sin(a+bT) - sin a)/b",
            "sinc form T cos(a + bT/2) sinc(bT/2)",
        ],
    );
    for e in 1..=16 {
        let b = 10f64.powi(-e);
        let r = cos_integral_series(a, b, t);
        let naive = ((a + b * t).sin() - a.sin()) / b;
        let stable = t * (a + 0.5 * b * t).cos() * sinc(0.5 * b * t);
        let (rn, rs) = (((naive - r) / r).abs(), ((stable - r) / r).abs());
        assert!(rs < 1e-15, "sinc form at b = {b}: {rs}");
        table.row(vec![
            format!("1e-{e}"),
            format!("{rn:.1e}"),
            format!("{rs:.1e}"),
        ]);
    }
    let naive0 = ((a + 0.0 * t).sin() - a.sin()) / 0.0;
    let stable0 = t * a.cos() * sinc(0.0);
    assert!(naive0.is_nan() && (stable0 - a.cos()).abs() < 1e-16);
    table.row(vec![
        "0".into(),
        format!("{naive0} (0/0)"),
        format!("{:.1e}", ((stable0 - a.cos()) / a.cos()).abs()),
    ]);
    table.print();

    let (sigma, h) = (2.0f64, 1.0f64);
    let mut table = Table::new(
        "whole-volume piece integral_0^h exp(-k s) ds, k = sigma c, as the slope c -> 0: relative error",
        &["c", "naive (1 - e^(-kh))/k", "stable h exprel(-kh)"],
    );
    for e in 0..=16 {
        let c = 10f64.powi(-e);
        let k = sigma * c;
        let x = -k * h;
        let reference = if x.abs() < 2e-3 {
            h * (1.0 + x / 2.0 + x * x / 6.0 + x.powi(3) / 24.0 + x.powi(4) / 120.0)
        } else {
            h * x.exp_m1() / x
        };
        let naive = (1.0 - (-k * h).exp()) / k;
        let stable = h * exprel(x);
        let (rn, rs) = (
            ((naive - reference) / reference).abs(),
            ((stable - reference) / reference).abs(),
        );
        assert!(rs < 4e-16);
        table.row(vec![
            format!("1e-{e}"),
            format!("{rn:.1e}"),
            format!("{rs:.1e}"),
        ]);
    }
    table.print();
}
