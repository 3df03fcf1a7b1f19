//! Reference values for the bindings' tests (the Python package's pytest suite): runs the Rust
//! sampler's batch queries on rays read from a file and writes the results.
//!
//! `query_reference GRID.pin RAYS.bin SEED OUT.bin [SJ,DJ,STRIDE,start|middle,INSIDE]`
//!
//! The optional last argument sets the lookup (`SamplerOptions`: spatial and directional
//! jitter, chain stride, lookup point, start inside as 0 or 1); without it the default lookup
//! (`SamplerOptions::RENDER`).
//!
//! `RAYS.bin` holds N 32-byte `RayQuery` records (origin xyz, t_max, dir xyz, pad; f32/u32
//! little-endian). `OUT.bin` receives N transmittances then N distances (f32, `inf` where no
//! collision), query `i` seeded by `(SEED, i)`. Prints the queries per second of each batch.

use std::process::ExitCode;
use std::time::Instant;

use pinrt::{PinGrid, RayQuery, SamplerOptions};

/// `SJ,DJ,STRIDE,start|middle,INSIDE[,NEAREST]`.
fn parse_options(s: &str) -> Result<SamplerOptions, String> {
    let bad = || format!("options '{s}': expected SJ,DJ,STRIDE,start|middle,0|1[,NEAREST]");
    // Five fields, or six with the nearest-line steps last.
    let fields = s.split(',').collect::<Vec<_>>();
    let (&[sj, dj, stride, point, inside], nearest) = (match fields[..] {
        [ref base @ .., n] if fields.len() == 6 => (base, n),
        ref base => (base, "0"),
    }) else {
        return Err(bad());
    };
    Ok(SamplerOptions {
        spatial_jitter: sj.parse().map_err(|_| bad())?,
        directional_jitter: dj.parse().map_err(|_| bad())?,
        chain_stride: stride.parse().map_err(|_| bad())?,
        midpoint_lookup: match point {
            "start" => false,
            "middle" => true,
            _ => return Err(bad()),
        },
        start_inside: match inside {
            "0" => false,
            "1" => true,
            _ => return Err(bad()),
        },
        nearest_line: nearest.parse().map_err(|_| bad())?,
    })
}

fn run(args: &[String]) -> Result<(), String> {
    let (grid, rays, seed, out, opts) = match args {
        [grid, rays, seed, out] => (grid, rays, seed, out, SamplerOptions::default()),
        [grid, rays, seed, out, opts] => (grid, rays, seed, out, parse_options(opts)?),
        _ => {
            return Err(
                "usage: query_reference GRID.pin RAYS.bin SEED OUT.bin [SJ,DJ,STRIDE,start|middle,INSIDE]"
                    .into(),
            );
        }
    };
    let seed: u32 = seed.parse().map_err(|e| format!("SEED '{seed}': {e}"))?;
    let bytes = std::fs::read(rays).map_err(|e| format!("{rays}: {e}"))?;
    if !bytes.len().is_multiple_of(size_of::<RayQuery>()) {
        return Err(format!(
            "{rays}: {} bytes is not a whole number of 32-byte rays",
            bytes.len()
        ));
    }
    // Unaligned reads: a Vec<u8> promises no 16-byte alignment for a cast in place.
    let rays: Vec<RayQuery> = bytes
        .chunks_exact(size_of::<RayQuery>())
        .map(bytemuck::pod_read_unaligned)
        .collect();
    let grid = PinGrid::open(grid).map_err(|e| e.to_string())?;
    let s = grid
        .sampler()
        .map_err(|e| e.to_string())?
        .with_options(opts);
    let n = rays.len();
    let mut t = vec![0f32; n];
    let mut d = vec![None; n];
    // An untimed pass first: the timed ones then measure queries, not page faults of the map.
    s.transmittance_batch(&rays, seed, 0, &mut t);
    let t0 = Instant::now();
    s.transmittance_batch(&rays, seed, 0, &mut t);
    let t1 = Instant::now();
    s.sample_distance_batch(&rays, seed, 0, &mut d);
    let t2 = Instant::now();
    let mut buf = Vec::with_capacity(n * 8);
    buf.extend(t.iter().flat_map(|v| v.to_le_bytes()));
    buf.extend(
        d.iter()
            .flat_map(|v| v.unwrap_or(f32::INFINITY).to_le_bytes()),
    );
    std::fs::write(out, buf).map_err(|e| format!("{out}: {e}"))?;
    println!(
        "rust queries/s transmittance {:.0} distance {:.0}",
        n as f64 / (t1 - t0).as_secs_f64(),
        n as f64 / (t2 - t1).as_secs_f64()
    );
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("query_reference: {e}");
            ExitCode::from(1)
        }
    }
}
