//! The viewport: without `--width`/`--height` the image fills the window's central panel and
//! follows it, at a resolution scale (25% to 100% of the panel's physical pixels: the
//! window's HiDPI factor is counted, so at 100% one image pixel is one screen pixel). A new
//! size starts the accumulation again at that size; while the panel is still changing (a
//! window being drag-resized, the scale slider being dragged) the size waits until it has
//! stood for [`SETTLE`], so a drag does not rebuild every frame. A size flag, or a scripted
//! `resize` event, fixes the size instead.

use std::time::{Duration, Instant};

/// How long a new viewport size must stand before the image takes it.
pub const SETTLE: Duration = Duration::from_millis(250);
/// The image's longest side when it follows the window (a 4K panel at 100%).
pub const MAX_SIDE: u32 = 4096;
/// The resolution scale's range, in percent.
pub const SCALE_PERCENT: std::ops::RangeInclusive<u32> = 25..=100;

/// Whether the image follows the window, its resolution scale, and a size waiting to settle.
#[derive(Debug)]
pub struct Viewport {
    pub follow: bool,
    /// Percent of the panel's physical pixels ([`SCALE_PERCENT`]).
    pub scale_percent: u32,
    /// The central panel's size (points) and the window's pixels per point, last seen.
    pub panel: Option<(egui::Vec2, f32)>,
    pending: Option<((u32, u32), Instant)>,
}

impl Viewport {
    pub fn new(follow: bool) -> Self {
        Self {
            follow,
            scale_percent: 100,
            panel: None,
            pending: None,
        }
    }

    fn scale(&self) -> f32 {
        self.scale_percent
            .clamp(*SCALE_PERCENT.start(), *SCALE_PERCENT.end()) as f32
            / 100.0
    }

    /// The image size (pixels) that fills a panel of `panel` points at `ppp` pixels per point.
    pub fn size_for(&self, panel: egui::Vec2, ppp: f32) -> (u32, u32) {
        let k = ppp.max(0.1) * self.scale();
        let side = |x: f32| ((x.max(0.0) * k).floor() as u32).clamp(1, MAX_SIDE);
        (side(panel.x), side(panel.y))
    }

    /// The panel is `panel` points at `ppp` at `now`, the image `current` pixels: the size
    /// the image takes now, if any. `at_once`: no accumulation to lose yet, no waiting.
    pub fn update(
        &mut self,
        panel: egui::Vec2,
        ppp: f32,
        current: (u32, u32),
        now: Instant,
        at_once: bool,
    ) -> Option<(u32, u32)> {
        self.panel = Some((panel, ppp));
        if !self.follow {
            self.pending = None;
            return None;
        }
        let want = self.size_for(panel, ppp);
        if want == current {
            self.pending = None;
            return None;
        }
        match self.pending {
            _ if at_once => {
                self.pending = None;
                Some(want)
            }
            Some((size, since)) if size == want => (now.saturating_duration_since(since) >= SETTLE)
                .then(|| {
                    self.pending = None;
                    want
                }),
            _ => {
                self.pending = Some((want, now));
                None
            }
        }
    }

    /// Whether no new size is waiting to settle.
    pub fn settled(&self) -> bool {
        self.pending.is_none()
    }

    /// Points an image pixel takes on screen at most: following the window, the panel's
    /// pixels over the image's (one screen pixel each at 100%); a fixed size, one point.
    pub fn points_per_pixel(&self, ppp: f32) -> f32 {
        if self.follow {
            1.0 / (ppp.max(0.1) * self.scale())
        } else {
            1.0
        }
    }

    /// The JSON line's `viewport`.
    pub fn json(&self) -> serde_json::Value {
        let (panel, ppp) = self.panel.unwrap_or((egui::Vec2::ZERO, 1.0));
        serde_json::json!({
            "follow": self.follow,
            "scale_percent": self.scale_percent,
            "pixels_per_point": ppp,
            "panel_points": [panel.x, panel.y],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_size_waits_until_it_has_stood_for_the_settle_time() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut v = Viewport::new(true);
        let panel = egui::vec2(300.0, 200.0);
        // Nothing to lose yet: at once, in physical pixels.
        assert_eq!(v.update(panel, 2.0, (512, 512), t0, true), Some((600, 400)));
        // A drag-resize: each new size starts the wait again.
        let p2 = egui::vec2(310.0, 200.0);
        assert_eq!(v.update(p2, 2.0, (600, 400), t0, false), None);
        assert_eq!(v.update(p2, 2.0, (600, 400), t0 + ms(200), false), None);
        let p3 = egui::vec2(320.0, 200.0);
        assert_eq!(v.update(p3, 2.0, (600, 400), t0 + ms(300), false), None);
        assert!(!v.settled());
        assert_eq!(v.update(p3, 2.0, (600, 400), t0 + ms(500), false), None);
        assert_eq!(
            v.update(p3, 2.0, (600, 400), t0 + ms(560), false),
            Some((640, 400))
        );
        assert!(v.settled());
        // Half resolution: half the pixels a side.
        v.scale_percent = 50;
        assert_eq!(v.size_for(p3, 2.0), (320, 200));
        assert_eq!(v.points_per_pixel(2.0), 1.0);
        // A fixed size never changes.
        let mut f = Viewport::new(false);
        assert_eq!(f.update(panel, 1.0, (48, 40), t0, true), None);
    }
}
