//! The error view's measurements: the accumulations read back at a bounded rate, each
//! side's RMSE against the reference, its plot point and heat map.

use std::time::Instant;

use anyhow::Result;

use super::Viewer;
use crate::error_view;

impl Viewer {
    /// Whether the interactive window reads the error back this frame.
    pub(super) fn error_due(&self) -> bool {
        self.error_on
            && self.args.frames.is_none()
            && self.reference.passes() > 0
            && self
                .error
                .last
                .is_none_or(|t| t.elapsed() >= error_view::ERROR_PERIOD)
    }

    /// Reads the accumulations back (at most once per [`error_view::ERROR_PERIOD`], or now
    /// with `now`) and measures each side against the reference: RMSE, plot point, heat map.
    pub(super) fn update_error(&mut self, ctx: &egui::Context, now: bool) -> Result<()> {
        let Some(r) = self.reference.session() else {
            return Ok(());
        };
        if r.passes() == 0
            || (!now
                && self
                    .error
                    .last
                    .is_some_and(|t| t.elapsed() < error_view::ERROR_PERIOD))
        {
            return Ok(());
        }
        let started = Instant::now();
        self.error.last = Some(started);
        let reference = error_view::read_mean(r)?;
        self.error.reference_passes = r.passes();
        let sides = [
            self.main.session().map(|s| (s, self.main.seconds())),
            self.compare.session().map(|s| (s, self.compare.seconds())),
        ];
        for (k, side) in sides.into_iter().enumerate() {
            let Some((session, seconds)) = side.filter(|(s, _)| s.passes() > 0) else {
                continue;
            };
            let estimate = error_view::read_mean(session)?;
            let e = error_view::rmse(&estimate, &reference);
            self.error.rmse[k] = Some(e);
            self.error.points[k].push([seconds, e]);
            let rgb = error_view::heat_map(&estimate, &reference, self.view.exposure);
            let size = [session.width() as usize, session.height() as usize];
            let image = egui::ColorImage::from_rgb(size, &rgb);
            match &mut self.error.textures[k] {
                Some(t) => t.set(image, egui::TextureOptions::NEAREST),
                None => {
                    self.error.textures[k] = Some(ctx.load_texture(
                        format!("pinview error {k}"),
                        image,
                        egui::TextureOptions::NEAREST,
                    ));
                }
            }
            self.error.heat[k] = Some(rgb);
        }
        self.error.update_seconds = started.elapsed().as_secs_f64();
        Ok(())
    }
}
