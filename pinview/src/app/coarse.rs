//! An answer within a frame while the view changes: when a drag (or any change of camera,
//! sun or material) starts the accumulation again, one pass at the preview's size
//! (`build::preview_size`) on the shown renderer is drawn at once, upscaled, and stands
//! until the accumulation's first whole pass replaces it. The accumulation itself is
//! untouched: its passes are still the batch renderer's bits.

use anyhow::{Result, anyhow};
use pinrender::gpu_render::GpuSession;
use pinrender::render::EstimatorSpec;

use super::Viewer;
use super::events::Shown;
use super::window::write_image;
use crate::build::{self, Relay};

/// The coarse session, kept between changes (a reset, not a new session, per drag step),
/// with the tone map on its device.
pub struct Coarse {
    estimator: EstimatorSpec,
    session: GpuSession,
    relay: Relay,
}

impl Viewer {
    /// Draws the coarse image of the current view into the displayed texture, where the
    /// image is larger than the preview and the shown renderer is in.
    pub(super) fn draw_coarse(&mut self) -> Result<()> {
        let Some((est, renderer)) = &self.renderer else {
            return Ok(());
        };
        let (w, h) = (self.view.width, self.view.height);
        let Some((pw, ph, f)) = build::preview_size(w, h) else {
            return Ok(());
        };
        let mut scene = self.view.scene();
        (scene.camera.width, scene.camera.height) = (pw, ph);
        let seed = self.view.seed;
        let mut coarse = match self.coarse.take() {
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
                Coarse {
                    estimator: *est,
                    session,
                    relay,
                }
            }
        };
        coarse.session.add_passes(1).map_err(|e| anyhow!("{e}"))?;
        let rgba = coarse.relay.image(&coarse.session, self.view.exposure)?;
        let t = &self.target;
        if t.size == (w, h) {
            let full = build::upscale(&rgba, pw, ph, f, w, h);
            write_image(&self.gpu.queue, &t.texture, w, h, &full);
            self.shown.get_or_insert(Shown::Preview);
        }
        self.coarse = Some(coarse);
        Ok(())
    }
}
