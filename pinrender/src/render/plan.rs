//! [`RenderPlan`]: what a render with one estimator loads, which CPU sample loop it runs and
//! what memory that loop holds, chosen once from its [`EstimatorSpec`] and read by the
//! `pinrender` binary's render command and its eval (an extension's estimators give a plan
//! of their own).

use super::spec::EstimatorSpec;
use super::wavefront::{DEFAULT_WAVEFRONT_BATCH, row_scratch_bytes};

/// The CPU sample loop of a render.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleLoop {
    /// `render`: one path at a time per worker.
    Paths,
    /// `render_wavefront`: the same image, a row's paths in tiles whose pin queries are
    /// answered in batches.
    Wavefront,
}

/// What a render with one estimator reads and runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderPlan {
    /// It reads the bake: a pin grid, or (`pinres`) the pin file's control section.
    pub reads_bake: bool,
    /// It queries the pin grid itself (not only the control section).
    pub queries_pins: bool,
    /// It reads the pin file's control section (`pinbake bake --embed-control`).
    pub control: bool,
    /// It reads the density.
    pub density: bool,
    /// It tracks over majorants.
    pub majorants: bool,
    /// The CPU sample loop that renders it.
    pub sample_loop: SampleLoop,
}

impl RenderPlan {
    /// Bytes the CPU sample loop holds per worker thread for an image `width` pixels wide,
    /// besides the image: the wavefront loop's rows in flight, nothing for the path loop.
    pub fn scratch_bytes_per_thread(&self, width: usize) -> u64 {
        match self.sample_loop {
            SampleLoop::Wavefront => row_scratch_bytes(width, DEFAULT_WAVEFRONT_BATCH),
            SampleLoop::Paths => 0,
        }
    }
}

impl EstimatorSpec {
    /// The plan of a render with this estimator: `pins` and `pinms` answer their pin queries
    /// in batches (the wavefront loop); every other estimator runs the path loop.
    pub fn plan(self) -> RenderPlan {
        let batched = matches!(self, Self::Pins | Self::PinMs);
        RenderPlan {
            reads_bake: self.needs_pins(),
            queries_pins: batched,
            control: self.needs_control(),
            density: self.needs_density(),
            majorants: self.needs_majorants(),
            sample_loop: if batched {
                SampleLoop::Wavefront
            } else {
                SampleLoop::Paths
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loop follows the pin queries: only `pins` and `pinms` run the wavefront loop and
    /// count its rows; `pinres` reads the bake's control section without querying pins.
    #[test]
    fn the_plan_follows_the_estimator() {
        for e in super::super::ESTIMATORS {
            let p = e.spec.plan();
            assert_eq!(p.reads_bake, e.spec.needs_pins(), "{}", e.name);
            assert_eq!(
                p.sample_loop == SampleLoop::Wavefront,
                p.queries_pins,
                "{}",
                e.name
            );
            assert_eq!(
                p.scratch_bytes_per_thread(64) > 0,
                p.queries_pins,
                "{}",
                e.name
            );
        }
        let pinres = EstimatorSpec::PinRes.plan();
        assert!(pinres.reads_bake && pinres.control && !pinres.queries_pins);
        assert_eq!(pinres.sample_loop, SampleLoop::Paths);
        assert_eq!(pinres.scratch_bytes_per_thread(512), 0);
        let pinms = EstimatorSpec::PinMs.plan();
        assert!(pinms.queries_pins && pinms.density && pinms.majorants);
    }
}
