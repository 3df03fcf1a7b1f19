//! The viewport: without `--width`/`--height` the image fills the window's central panel and
//! follows it, at a resolution scale (25% to 100% of the panel's physical pixels: the
//! window's HiDPI factor is counted, so at 100% one image pixel is one screen pixel). A new
//! size starts the accumulation again at that size; while the panel is still changing (a
//! window being drag-resized, the scale slider being dragged) the size waits until it has
//! stood for [`SETTLE`], so a drag does not rebuild every frame. A size flag, or a scripted
//! `resize` event, fixes the size instead.
//!
//! Every size the image takes fits the command's memory budget (`--max-memory`) together with
//! what else the viewer holds ([`Held`]): the medium's read as `pinrender render` charges it,
//! and one image (charged per pixel as `pinrender render` charges its image) for each side
//! that renders at that size: the main view, the compare side and the error view's
//! reference. A panel whose image would not fit gets the largest image of the panel's aspect
//! that does, and says so once; turning the compare side or the error view on shrinks it.

use std::time::{Duration, Instant};

use pin_volume::files::MemoryBudget;
use pinrender::front::flags::BYTES_PER_PIXEL;

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
    /// The command's memory budget, which every followed size fits.
    budget: MemoryBudget,
    /// The last size the budget reduced: the panel's size and the size taken.
    pub reduced: Option<((u32, u32), (u32, u32))>,
    /// What the last size was fitted beside.
    held: Held,
    noted: bool,
}

/// What the viewer holds besides its images' pixels, and how many images of the view's size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Held {
    /// Images at the view's size: 1, plus the compare side, plus the error view's reference.
    pub images: u64,
    /// Bytes charged for the medium (its read).
    pub reserved: u64,
}

impl Held {
    /// One image and nothing else.
    pub const ONE_IMAGE: Held = Held {
        images: 1,
        reserved: 0,
    };

    /// Whether `size` fits `budget` beside what is held.
    pub fn fits(&self, budget: &MemoryBudget, size: (u32, u32)) -> bool {
        let pixels = u64::from(size.0) * u64::from(size.1);
        pixels
            .saturating_mul(BYTES_PER_PIXEL)
            .saturating_mul(self.images.max(1))
            .saturating_add(self.reserved)
            <= budget.limit
    }
}

impl Viewport {
    pub fn new(follow: bool, budget: MemoryBudget) -> Self {
        Self {
            follow,
            scale_percent: 100,
            panel: None,
            pending: None,
            budget,
            reduced: None,
            held: Held::ONE_IMAGE,
            noted: false,
        }
    }

    fn scale(&self) -> f32 {
        self.scale_percent
            .clamp(*SCALE_PERCENT.start(), *SCALE_PERCENT.end()) as f32
            / 100.0
    }

    /// The image size (pixels) that fills a panel of `panel` points at `ppp` pixels per point,
    /// before the budget.
    fn panel_size(&self, panel: egui::Vec2, ppp: f32) -> (u32, u32) {
        let k = ppp.max(0.1) * self.scale();
        let side = |x: f32| ((x.max(0.0) * k).floor() as u32).clamp(1, MAX_SIDE);
        (side(panel.x), side(panel.y))
    }

    /// The panel is `panel` points at `ppp` at `now`, the image `current` pixels, beside
    /// `held`: the size the image takes now, if any. `at_once`: no accumulation to lose yet,
    /// no waiting. A current size that no longer fits (a side turned on) is left at once.
    pub fn update(
        &mut self,
        panel: egui::Vec2,
        ppp: f32,
        current: (u32, u32),
        now: Instant,
        at_once: bool,
        held: Held,
    ) -> Option<(u32, u32)> {
        self.panel = Some((panel, ppp));
        self.held = held;
        if !self.follow {
            self.pending = None;
            return None;
        }
        let full = self.panel_size(panel, ppp);
        let want = fit(full, &self.budget, held);
        if want == current {
            self.pending = None;
            return None;
        }
        match self.pending {
            _ if at_once || !held.fits(&self.budget, current) => {
                self.pending = None;
                self.took(full, want);
                Some(want)
            }
            Some((size, since)) if size == want => (now.saturating_duration_since(since) >= SETTLE)
                .then(|| {
                    self.pending = None;
                    self.took(full, want);
                    want
                }),
            _ => {
                self.pending = Some((want, now));
                None
            }
        }
    }

    /// Records a size taken in place of the panel's `full` one.
    fn took(&mut self, full: (u32, u32), want: (u32, u32)) {
        if full != want {
            self.reduced = Some((full, want));
        }
    }

    /// The note for the first size the budget reduced (once per viewer).
    pub fn reduction_note(&mut self) -> Option<String> {
        let ((fw, fh), (w, h)) = self.reduced.filter(|_| !self.noted)?;
        self.noted = true;
        let beside = match (self.held.images, self.held.reserved) {
            (1, 0) => String::new(),
            (n, r) => format!("; {n} images of that size and the medium's {r} bytes"),
        };
        Some(format!(
            "the image is {w} x {h}, not the panel's {fw} x {fh}: a larger one would exceed \
             --max-memory ({} bytes at {BYTES_PER_PIXEL} bytes a pixel{beside})",
            self.budget.limit,
        ))
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
            "max_image_bytes": self.budget.limit,
            "reduced_from": self.reduced.map(|(full, _)| [full.0, full.1]),
            "images": self.held.images,
            "reserved_bytes": self.held.reserved,
        })
    }
}

impl super::Viewer {
    /// What the viewer holds beside the main image: the compare side's and the error view's
    /// reference images when they are on and the medium answers them, and the medium's read.
    pub(super) fn held(&self) -> Held {
        let compare = self
            .compare_wanted
            .is_some_and(|e| self.compare_answered(e) || self.baking());
        let reference =
            self.error_on && crate::error_view::no_reference_reason(&self.medium).is_none();
        Held {
            images: 1 + u64::from(compare) + u64::from(reference),
            reserved: self.medium.read_bytes,
        }
    }
}

/// `size`, or the largest size of its aspect whose images fit `budget` beside `held` (at
/// least 1 x 1).
fn fit(size: (u32, u32), budget: &MemoryBudget, held: Held) -> (u32, u32) {
    if held.fits(budget, size) {
        return size;
    }
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let pixels = budget.limit.saturating_sub(held.reserved) / BYTES_PER_PIXEL / held.images.max(1);
    let k = (pixels as f64 / (w * h)).sqrt();
    let mut s = (
        ((w * k).floor() as u32).max(1),
        ((h * k).floor() as u32).max(1),
    );
    // Rounding may leave a pixel too many: shrink the longer side until it fits.
    while !held.fits(budget, s) && (s.0 > 1 || s.1 > 1) {
        if s.0 >= s.1 {
            s.0 -= 1;
        } else {
            s.1 -= 1;
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_size_waits_until_it_has_stood_for_the_settle_time() {
        let t0 = Instant::now();
        let ms = Duration::from_millis;
        let mut v = Viewport::new(true, MemoryBudget::new(None));
        let panel = egui::vec2(300.0, 200.0);
        // Nothing to lose yet: at once, in physical pixels.
        assert_eq!(
            v.update(panel, 2.0, (512, 512), t0, true, Held::ONE_IMAGE),
            Some((600, 400))
        );
        // A drag-resize: each new size starts the wait again.
        let p2 = egui::vec2(310.0, 200.0);
        assert_eq!(
            v.update(p2, 2.0, (600, 400), t0, false, Held::ONE_IMAGE),
            None
        );
        assert_eq!(
            v.update(p2, 2.0, (600, 400), t0 + ms(200), false, Held::ONE_IMAGE),
            None
        );
        let p3 = egui::vec2(320.0, 200.0);
        assert_eq!(
            v.update(p3, 2.0, (600, 400), t0 + ms(300), false, Held::ONE_IMAGE),
            None
        );
        assert!(!v.settled());
        assert_eq!(
            v.update(p3, 2.0, (600, 400), t0 + ms(500), false, Held::ONE_IMAGE),
            None
        );
        assert_eq!(
            v.update(p3, 2.0, (600, 400), t0 + ms(560), false, Held::ONE_IMAGE),
            Some((640, 400))
        );
        assert!(v.settled());
        // Half resolution: half the pixels a side.
        v.scale_percent = 50;
        assert_eq!(v.panel_size(p3, 2.0), (320, 200));
        assert_eq!(v.points_per_pixel(2.0), 1.0);
        // A fixed size never changes.
        let mut f = Viewport::new(false, MemoryBudget::new(None));
        assert_eq!(
            f.update(panel, 1.0, (48, 40), t0, true, Held::ONE_IMAGE),
            None
        );
    }

    #[test]
    fn a_followed_size_fits_the_memory_budget_at_the_panels_aspect() {
        let bpp = pinrender::front::flags::BYTES_PER_PIXEL;
        // Room for 400 x 300 pixels, a panel of 800 x 600.
        let budget = MemoryBudget::new(Some(400 * 300 * bpp));
        let mut v = Viewport::new(true, budget);
        let got = v.update(
            egui::vec2(800.0, 600.0),
            1.0,
            (512, 512),
            Instant::now(),
            true,
            Held::ONE_IMAGE,
        );
        assert_eq!(got, Some((400, 300)));
        assert_eq!(v.reduced, Some(((800, 600), (400, 300))));
        // One byte less: a pixel less, still within.
        let tight = MemoryBudget::new(Some(400 * 300 * bpp - 1));
        let (w, h) = fit((800, 600), &tight, Held::ONE_IMAGE);
        assert!(
            u64::from(w) * u64::from(h) * bpp <= tight.limit,
            "{w} x {h}"
        );
        assert!(w >= 398 && h >= 298, "{w} x {h}");
        // A panel that fits is untouched.
        assert_eq!(fit((100, 50), &budget, Held::ONE_IMAGE), (100, 50));
    }

    #[test]
    fn a_followed_size_leaves_room_for_every_side_and_the_medium() {
        let bpp = BYTES_PER_PIXEL;
        let t0 = Instant::now();
        let panel = egui::vec2(800.0, 600.0);
        // Room for 400 x 300 pixels of one image beside a 1 MiB medium.
        let reserved = 1 << 20;
        let budget = MemoryBudget::new(Some(400 * 300 * bpp + reserved));
        let mut v = Viewport::new(true, budget);
        let one = Held {
            images: 1,
            reserved,
        };
        assert_eq!(
            v.update(panel, 1.0, (8, 8), t0, true, one),
            Some((400, 300))
        );
        // The compare side and the reference turned on: three images share the room, at
        // once (the current size no longer fits), the largest of the panel's aspect.
        let three = Held {
            images: 3,
            reserved,
        };
        let (w, h) = v
            .update(panel, 1.0, (400, 300), t0, false, three)
            .expect("a smaller size at once");
        assert!(three.fits(&budget, (w, h)), "{w} x {h}");
        assert!(
            !three.fits(&budget, (w + 1, h + 1)),
            "{w} x {h} is not the largest"
        );
        assert!(
            (230..=231).contains(&w) && (172..=173).contains(&h),
            "{w} x {h}"
        );
        assert_eq!(v.json()["images"], 3);
        assert_eq!(v.json()["reserved_bytes"], reserved);
        assert!(v.reduction_note().unwrap().contains("3 images"));
        // A medium that takes the whole budget leaves the smallest image.
        let full = Held {
            images: 1,
            reserved: budget.limit,
        };
        assert_eq!(fit((800, 600), &budget, full), (1, 1));
    }
}
