//! The error view: a reference accumulated by ratio tracking in a session of its own (with
//! an independent seed), each shown estimator's |estimate - reference| as a heat map, and
//! its RMSE against the reference over time for the live plot. The accumulations are read
//! back at a bounded rate ([`ERROR_PERIOD`]), never every frame.

use std::time::Duration;

use anyhow::{Result, anyhow};
use pinrender::gpu_render::GpuSession;
use pinrender::render::EstimatorSpec;

use crate::open::Medium;

/// The reference's seed is the view's seed with these bits flipped: its noise is
/// independent of an estimate with the view's seed.
pub const REFERENCE_SEED_XOR: u64 = 0x9e37_79b9_7f4a_7c15;

/// The reference's estimator: ratio tracking, unbiased and the trackers' usual choice.
pub const REFERENCE_ESTIMATOR: EstimatorSpec = EstimatorSpec::RatioTracking;

/// How often the error (heat map, RMSE) is read back and recomputed.
pub const ERROR_PERIOD: Duration = Duration::from_millis(500);

/// Why a medium has no reference, or `None` where it has one.
pub fn no_reference_reason(medium: &Medium) -> Option<String> {
    if medium.scene().is_some() {
        return Some(format!(
            "no reference: the error view needs one medium with a density; {} is a scene, \
             which the GPU renders with pins alone",
            medium.path.display()
        ));
    }
    (!medium.estimators().contains(&EstimatorSpec::RatioTracking)).then(|| {
        format!(
            "no reference: {} holds no density (pins alone), which ratio tracking needs",
            medium.path.display()
        )
    })
}

/// A session's mean image (linear RGB per pixel, x fastest) read back without finishing a
/// pass in progress: the rows the pass has reached hold one sample more. With whole passes
/// these are the bits of [`GpuSession::image`]. `device` and `queue` are the session's.
pub fn read_mean(session: &GpuSession) -> Result<Vec<[f32; 3]>> {
    // The session's own device: on a CPU adapter each renderer has one (`crate::build`).
    let (device, queue) = (session.device(), session.queue());
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let size = session.accumulation().size();
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("error view readback"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("error view readback"),
    });
    enc.copy_buffer_to_buffer(session.accumulation(), 0, &staging, 0, size);
    queue.submit([enc.finish()]);
    let sums: Vec<[f32; 8]> = pollster::block_on(pinrt::gpu::read_back(
        device,
        &staging,
        scope,
        "error view readback",
    ))
    .map_err(|e| anyhow!("{e}"))?;
    let w = session.width() as usize;
    let inv = |n: u32| if n > 0 { 1.0 / f64::from(n) } else { 0.0 };
    let (whole, partial) = (inv(session.passes()), inv(session.passes() + 1));
    let next_row = session.next_row() as usize;
    Ok(sums
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let k = if i / w < next_row { partial } else { whole };
            // Kahan: the compensation holds what the running sum over-counted.
            std::array::from_fn(|c| ((f64::from(s[c]) - f64::from(s[4 + c])) * k) as f32)
        })
        .collect())
}

/// Root mean square of `estimate - reference` over every pixel and channel.
pub fn rmse(estimate: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let n = estimate.len().min(reference.len()) * 3;
    if n == 0 {
        return 0.0;
    }
    let sum: f64 = estimate
        .iter()
        .zip(reference)
        .flat_map(|(a, b)| (0..3).map(move |c| f64::from(a[c]) - f64::from(b[c])))
        .map(|d| d * d)
        .sum();
    (sum / n as f64).sqrt()
}

/// The heat map of `|estimate - reference|` (the mean over channels, times `exposure`,
/// through x / (1 + x)) as black, red, yellow, white: exactly black where they are equal.
pub fn heat_map(estimate: &[[f32; 3]], reference: &[[f32; 3]], exposure: f32) -> Vec<u8> {
    estimate
        .iter()
        .zip(reference)
        .flat_map(|(a, b)| {
            let e = (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() / 3.0 * exposure;
            let t = if e.is_finite() { e / (1.0 + e) } else { 1.0 };
            let ramp = |lo: f32| ((3.0 * t - lo).clamp(0.0, 1.0) * 255.0).round() as u8;
            [ramp(0.0), ramp(1.0), ramp(2.0)]
        })
        .collect()
}

/// What the error view measured: for the first and the second side, the RMSE against the
/// reference over the side's seconds, the latest RMSE, the latest heat map (RGB) and its
/// texture.
#[derive(Default)]
pub struct ErrorTrack {
    /// When the error was last read back.
    pub last: Option<std::time::Instant>,
    pub points: [Vec<[f64; 2]>; 2],
    pub rmse: [Option<f64>; 2],
    pub heat: [Option<Vec<u8>>; 2],
    pub textures: [Option<egui::TextureHandle>; 2],
    /// The reference's passes at the latest read-back.
    pub reference_passes: u32,
    /// Wall time of the latest read-back and measurement, seconds (the window waits for it).
    pub update_seconds: f64,
}

impl ErrorTrack {
    /// Forgets one side's measurements (its session started again).
    pub fn clear(&mut self, side: usize) {
        self.points[side].clear();
        self.rmse[side] = None;
        self.heat[side] = None;
        self.textures[side] = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_images_have_no_error_and_a_black_map() {
        let a = vec![[0.5, 0.25, 1.0]; 4];
        assert_eq!(rmse(&a, &a), 0.0);
        assert!(heat_map(&a, &a, 1.0).iter().all(|&c| c == 0));
        let b = vec![[0.5, 0.25, 4.0]; 4];
        // One channel of three off by 3: sqrt(9 / 3).
        assert!((rmse(&a, &b) - 3f64.sqrt()).abs() < 1e-12);
        assert!(heat_map(&a, &b, 1.0).iter().any(|&c| c > 0));
    }
}
