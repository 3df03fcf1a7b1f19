//! An answer within a frame while the view changes: when a drag (or any change of camera,
//! sun or material) starts the accumulation again, one pass at a coarse size on the shown
//! renderer is drawn at once, upscaled, and stands until the accumulation's first whole
//! pass replaces it. The coarse side starts at the preview's ([`build::PREVIEW_SIDE`]) and
//! follows the measured time of the coarse pass: halved while it takes more than
//! [`COARSE_BUDGET`], doubled (up to the preview's) while it takes under a quarter of it, so
//! a drag answers within a frame on a slow adapter too. The accumulation itself is
//! untouched: its passes are still the batch renderer's bits.

use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};
use pinrender::gpu_render::GpuSession;
use pinrender::render::EstimatorSpec;

use super::Viewer;
use super::events::Shown;
use super::window::write_image;
use crate::build::{self, Relay};

/// The wall time a coarse pass may take (its tone map and read-back included).
pub const COARSE_BUDGET: Duration = Duration::from_millis(50);
/// The coarse image's longer side at the least.
const MIN_SIDE: u32 = 16;

/// The coarse image's state: whether one is due (the view changed this frame), its session
/// and its longer side, following its measured time.
pub struct Coarse {
    pub due: bool,
    session: Option<CoarseSession>,
    side: u32,
}

impl Default for Coarse {
    fn default() -> Self {
        Self {
            due: false,
            session: None,
            side: build::PREVIEW_SIDE,
        }
    }
}

impl Coarse {
    /// Drops the coarse session (the shown renderer or the medium changed).
    pub fn forget(&mut self) {
        self.session = None;
    }
}

/// The coarse session, kept between changes (a reset, not a new session, per drag step),
/// with the tone map on its device.
struct CoarseSession {
    estimator: EstimatorSpec,
    session: GpuSession,
    relay: Relay,
}

impl Viewer {
    /// Draws the coarse image of the current view into the displayed texture, where the
    /// image is larger than the coarse one and the shown renderer is in; returns whether it
    /// drew.
    pub(super) fn draw_coarse(&mut self) -> Result<bool> {
        let Some(live) = &self.main.live else {
            return Ok(false);
        };
        let (est, renderer) = (&live.estimator, &live.renderer);
        let (w, h) = (self.view.width, self.view.height);
        let Some((pw, ph, f)) = build::scaled_size(w, h, self.coarse.side) else {
            return Ok(false);
        };
        let started = Instant::now();
        let mut scene = self.view.scene();
        (scene.camera.width, scene.camera.height) = (pw, ph);
        let seed = self.view.seed;
        let mut coarse = match self.coarse.session.take() {
            Some(mut c)
                if c.estimator == *est && (c.session.width(), c.session.height()) == (pw, ph) =>
            {
                c.session.reset(&scene, seed).map_err(|e| anyhow!("{e}"))?;
                c
            }
            _ => {
                let session = renderer
                    .session(&scene, *est, seed)
                    .map_err(|e| anyhow!("{e}"))?;
                let relay = Relay::new(session.device());
                CoarseSession {
                    estimator: *est,
                    session,
                    relay,
                }
            }
        };
        coarse.session.add_passes(1).map_err(|e| anyhow!("{e}"))?;
        let rgba = coarse.relay.image(&coarse.session, self.view.exposure)?;
        let t = &self.images.main;
        let drawn = t.size == (w, h);
        if drawn {
            let full = build::upscale(&rgba, pw, ph, f, w, h);
            write_image(&self.gpu.queue, &t.texture, w, h, &full);
            self.shown.get_or_insert(Shown::Preview);
        }
        self.coarse.session = Some(coarse);
        self.coarse.side = next_side(self.coarse.side, started.elapsed());
        Ok(drawn)
    }
}

/// The coarse side after a coarse pass that took `took` at `side`.
fn next_side(side: u32, took: Duration) -> u32 {
    if took > COARSE_BUDGET {
        (side / 2).max(MIN_SIDE)
    } else if took * 4 < COARSE_BUDGET {
        (side * 2).min(build::PREVIEW_SIDE)
    } else {
        side
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_coarse_side_follows_the_time_of_its_pass() {
        let ms = Duration::from_millis;
        assert_eq!(next_side(128, ms(200)), 64);
        assert_eq!(next_side(16, ms(200)), 16);
        assert_eq!(next_side(32, ms(30)), 32);
        assert_eq!(next_side(32, ms(5)), 64);
        assert_eq!(next_side(128, ms(1)), 128);
    }
}
