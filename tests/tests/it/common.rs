//! Shared helpers of the proof suite: finiteness assertions, p-values, data paths, tables.
#![allow(dead_code)]

use std::path::PathBuf;

/// `data/` relative to the project root.
pub fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

/// The isolated VDB reader built with this crate.
pub fn vdb_worker() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_pin-tests-vdb-worker"))
}

/// A transmittance: finite and in `[0, 1]`.
#[track_caller]
pub fn assert_transmittance(t: f32, what: &str) {
    assert!(
        t.is_finite() && (0.0..=1.0).contains(&t),
        "{what}: transmittance {t} escaped [0, 1]"
    );
}

/// A distance: `+inf` (none) or finite and `>= 0`; never NaN.
#[track_caller]
pub fn assert_distance(d: f32, what: &str) {
    assert!(
        !d.is_nan() && d >= 0.0 && (d.is_finite() || d == f32::INFINITY),
        "{what}: distance {d} is NaN, negative or -inf"
    );
}

/// Two-sided p-value of a standard normal z.
pub fn normal_p(z: f64) -> f64 {
    erfc(z.abs() / std::f64::consts::SQRT_2)
}

/// Complementary error function (W. J. Cody's rational Chebyshev via `erfc = Q(1/2, x^2)`).
pub fn erfc(x: f64) -> f64 {
    if x < 0.0 {
        return 2.0 - erfc(-x);
    }
    gamma_q(0.5, x * x)
}

/// Survival function of the chi-square distribution with `k` degrees of freedom.
pub fn chi2_sf(x: f64, k: f64) -> f64 {
    gamma_q(0.5 * k, 0.5 * x)
}

fn ln_gamma(x: f64) -> f64 {
    // Lanczos, g = 7, n = 9: ~1e-15 relative for x > 0.
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularised upper incomplete gamma `Q(a, x)` (series below `a + 1`, Lentz continued
/// fraction above).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let lnpre = -x + a * x.ln() - ln_gamma(a);
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (1.0 - sum * lnpre.exp()).max(0.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-16 {
                break;
            }
        }
        lnpre.exp() * h
    }
}

/// Pearson chi-square of `observed` counts against expected probabilities `p` (summing to
/// one); bins with expectation < 5 are pooled into their neighbour. Returns the statistic,
/// the degrees of freedom and the p-value.
pub fn chi_square(observed: &[u64], p: &[f64]) -> (f64, usize, f64) {
    assert_eq!(observed.len(), p.len());
    let n: u64 = observed.iter().sum();
    let n = n as f64;
    let mut bins: Vec<(f64, f64)> = Vec::new();
    let (mut o_acc, mut e_acc) = (0.0, 0.0);
    for (&o, &pi) in observed.iter().zip(p) {
        o_acc += o as f64;
        e_acc += pi * n;
        if e_acc >= 5.0 {
            bins.push((o_acc, e_acc));
            o_acc = 0.0;
            e_acc = 0.0;
        }
    }
    if let Some(last) = bins.last_mut() {
        last.0 += o_acc;
        last.1 += e_acc;
    } else {
        bins.push((o_acc, e_acc));
    }
    let stat: f64 = bins
        .iter()
        .map(|&(o, e)| if e > 0.0 { (o - e) * (o - e) / e } else { 0.0 })
        .sum();
    let dof = bins.len().saturating_sub(1).max(1);
    (stat, dof, chi2_sf(stat, dof as f64))
}

/// Collects rows of a markdown table and prints it (visible with `--nocapture`).
pub struct Table {
    pub title: String,
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    pub fn new(title: &str, header: &[&str]) -> Self {
        Self {
            title: title.into(),
            header: header.iter().map(|s| s.to_string()).collect(),
            rows: Vec::new(),
        }
    }
    pub fn row(&mut self, cells: Vec<String>) {
        self.rows.push(cells);
    }
    pub fn print(&self) {
        let mut s = format!(
            "\n#### {}\n\n| {} |\n|",
            self.title,
            self.header.join(" | ")
        );
        for _ in &self.header {
            s.push_str("---|");
        }
        s.push('\n');
        for r in &self.rows {
            s.push_str(&format!("| {} |\n", r.join(" | ")));
        }
        eprintln!("{s}");
    }
}

#[test]
fn p_value_helpers_are_right() {
    // Known values: P(|Z| > 1.96) = 0.05, chi2(k = 10) sf at 18.307 = 0.05.
    assert!((normal_p(1.959_963_985) - 0.05).abs() < 1e-9);
    assert!((chi2_sf(18.307_038, 10.0) - 0.05).abs() < 1e-6);
    assert!((chi2_sf(2.0, 2.0) - (-1.0f64).exp()).abs() < 1e-12);
    assert!((chi2_sf(300.0, 10.0)) < 1e-50);
}
