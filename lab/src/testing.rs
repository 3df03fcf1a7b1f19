//! Helpers of the lab's unit tests.

/// Mean and standard error of `n` draws of `f`.
pub(crate) fn mean_se(n: usize, mut f: impl FnMut() -> f64) -> (f64, f64) {
    let (mut s, mut s2) = (0.0, 0.0);
    for _ in 0..n {
        let x = f();
        s += x;
        s2 += x * x;
    }
    let m = s / n as f64;
    let var = (s2 / n as f64 - m * m).max(0.0) * n as f64 / (n as f64 - 1.0);
    (m, (var / n as f64).sqrt())
}
