//! Measures the per-bit probability of the sample mask `H`: the exact bit-sliced mask against
//! the thesis' k-round halving (k = 5), over a sweep of `t_min`. Prints a markdown table
//! (the one in docs/sampling.md).
//!
//! `cargo run --release -p pinrt --example mask_bias [masks per row]`

use pinrt::Rng;
use pinrt::mask::{exact_sample_mask, thesis_mask_probability, thesis_sample_mask};

fn main() {
    let n: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(2_000_000);
    println!("masks per row: {n} (32 bits each)\n");
    println!(
        "| t_min | q = 1 - t_min | exact: measured P(bit) | k=5: realised P(bit) | k=5: measured P(bit) | k=5 relative bias | P(no collision), 32 full intervals: exact t_min^32 | k=5: (1 - p5)^32 |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for t_min in [
        0.0f32, 0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.95, 0.97, 0.99, 0.995, 0.999, 0.9999, 0.99999,
    ] {
        let q = 1.0 - f64::from(t_min);
        let mut rng = Rng::for_query(2024, t_min.to_bits());
        let (mut ones_exact, mut ones_k5) = (0u64, 0u64);
        for _ in 0..n {
            ones_exact += u64::from(exact_sample_mask(t_min, &mut rng).count_ones());
            ones_k5 += u64::from(thesis_sample_mask(q as f32, 5, &mut rng).count_ones());
        }
        let bits = (32 * n) as f64;
        let pe = ones_exact as f64 / bits;
        let pk = ones_k5 as f64 / bits;
        let p5 = thesis_mask_probability(q as f32, 5);
        let rel = if q > 0.0 { (p5 - q) / q } else { 0.0 };
        println!(
            "| {t_min} | {q:.5e} | {pe:.5e} | {p5:.5e} | {pk:.5e} | {rel:+.3} | {:.5e} | {:.5e} |",
            f64::from(t_min).powi(32),
            (1.0 - p5).powi(32)
        );
    }
}
