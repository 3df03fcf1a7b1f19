//! The image and what the pointer and keys do to it: orbit, pan, zoom, the sun, the
//! divider of the split view, and the overlays of pins and cells drawn over it.

use pinrender::render::EstimatorSpec;

use super::Viewer;
use crate::gizmos;
use crate::pin_overlay::{self, Pick, Projector};

impl Viewer {
    /// The image with its mouse controls.
    pub(super) fn image(&mut self, ui: &mut egui::Ui) {
        let (w, h) = self.target.size;
        let avail = ui.available_size();
        let scale = (avail.x / w as f32)
            .min(avail.y / h as f32)
            .clamp(0.05, 1.0);
        let size = egui::vec2(w as f32 * scale, h as f32 * scale);
        let response = ui.add(
            egui::Image::new(egui::load::SizedTexture::new(self.target.id, size))
                .sense(egui::Sense::click_and_drag()),
        );
        if self.heat_on
            && let Some(t) = &self.error.textures[0]
        {
            ui.painter().image(
                t.id(),
                response.rect,
                egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
                egui::Color32::WHITE,
            );
        }
        let divider_dragged = self.split_view(ui, response.rect);
        self.image_rect = Some(response.rect);
        self.overlays(ui, &response);
        if self.moving {
            self.gizmos(ui, response.rect);
        }
        let d = if divider_dragged {
            egui::Vec2::ZERO
        } else {
            response.drag_delta()
        };
        let (ctrl, shift) = ui.input(|i| (i.modifiers.ctrl, i.modifiers.shift));
        let k = 0.01;
        if d != egui::Vec2::ZERO {
            if ctrl {
                self.view.turn_sun(f64::from(d.x) * k, f64::from(-d.y) * k);
            } else if response.dragged_by(egui::PointerButton::Secondary) || shift {
                self.view.pan(
                    f64::from(d.x) / f64::from(size.x),
                    f64::from(d.y) / f64::from(size.y),
                );
            } else {
                self.view.orbit(f64::from(-d.x) * k, f64::from(d.y) * k);
            }
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                self.view.zoom((-f64::from(scroll) * 0.002).exp());
            }
        }
    }

    /// The box and the sun's arrow over the image, while the view changes.
    fn gizmos(&self, ui: &egui::Ui, rect: egui::Rect) {
        let Some(proj) = Projector::new(&self.view) else {
            return;
        };
        let (w, h) = (f64::from(self.view.width), f64::from(self.view.height));
        let to_screen = |p: [f64; 2]| {
            egui::pos2(
                rect.left() + (p[0] / w) as f32 * rect.width(),
                rect.top() + (p[1] / h) as f32 * rect.height(),
            )
        };
        let painter = ui.painter_at(rect);
        gizmos::draw_box(&painter, &proj, &to_screen, self.medium.bounds);
        gizmos::draw_sun(
            &painter,
            &proj,
            &to_screen,
            self.medium.bounds,
            self.view.look.sun_dir,
        );
    }

    /// The pins under the cursor (or at the held pixel: a click holds or releases it) and the
    /// box with its cell grid, projected through the view's camera.
    pub(super) fn overlays(&mut self, ui: &egui::Ui, response: &egui::Response) {
        let rect = response.rect;
        let (w, h) = (f64::from(self.view.width), f64::from(self.view.height));
        let to_pixel = |p: egui::Pos2| {
            [
                (f64::from((p.x - rect.left()) / rect.width().max(1.0)) * w).floor(),
                (f64::from((p.y - rect.top()) / rect.height().max(1.0)) * h).floor(),
            ]
        };
        if self.pins_on && response.clicked() {
            self.held_pixel = match self.held_pixel {
                Some(_) => None,
                None => response.interact_pointer_pos().map(to_pixel),
            };
            self.held = None;
        }
        let (Some(grid), Some(proj)) = (self.medium.pins().cloned(), Projector::new(&self.view))
        else {
            self.pick = None;
            return;
        };
        let to_screen = |p: [f64; 2]| {
            egui::pos2(
                rect.left() + (p[0] / w) as f32 * rect.width(),
                rect.top() + (p[1] / h) as f32 * rect.height(),
            )
        };
        let painter = ui.painter_at(rect);
        if self.grid_on {
            pin_overlay::draw_grid(&painter, &proj, &to_screen, &grid);
        }
        if !self.pins_on {
            self.pick = None;
            return;
        }
        // A hold keeps the entry picked when it was taken, whatever the view does since.
        if self.held.is_none()
            && let Some([x, y]) = self.held_pixel
        {
            self.held = self.pick_at(x, y);
        }
        self.pick = match &self.held {
            Some(p) => Some(p.clone()),
            None => response
                .hover_pos()
                .map(to_pixel)
                .and_then(|[x, y]| self.pick_at(x, y)),
        };
        if let Some(p) = &self.pick {
            pin_overlay::draw_pins(&painter, &proj, &to_screen, p);
        }
    }

    /// The second estimator's image right of the divider, the divider (dragged to move it),
    /// and each side's label: estimator, spp and seconds spent. Returns whether the divider
    /// is being dragged.
    pub(super) fn split_view(&mut self, ui: &mut egui::Ui, rect: egui::Rect) -> bool {
        let (Some(c), Some(target)) = (&self.compare, &self.compare_target) else {
            return false;
        };
        let x = rect.left() + self.split * rect.width();
        let painter = ui.painter_at(rect);
        let right = egui::Rect::from_min_max(egui::pos2(x, rect.top()), rect.max);
        let right_id = match &self.error.textures[1] {
            Some(t) if self.heat_on => t.id(),
            _ => target.id,
        };
        painter.image(
            right_id,
            right,
            egui::Rect::from_min_max(egui::pos2(self.split, 0.0), egui::pos2(1.0, 1.0)),
            egui::Color32::WHITE,
        );
        painter.line_segment(
            [egui::pos2(x, rect.top()), egui::pos2(x, rect.bottom())],
            egui::Stroke::new(2.0, egui::Color32::WHITE),
        );
        let label = |est: EstimatorSpec, passes: u32, seconds: f64| {
            format!("{est}  {passes} spp  {seconds:.2} s")
        };
        let first = self.session.as_ref().map_or(0, |s| s.passes());
        let texts = [
            (
                label(self.view.estimator, first, self.seconds()),
                egui::pos2(rect.left() + 4.0, rect.top() + 4.0),
                egui::Align2::LEFT_TOP,
            ),
            (
                label(c.estimator, c.session.passes(), c.seconds()),
                // Bottom right: the two labels never overlap on a narrow image.
                egui::pos2(rect.right() - 4.0, rect.bottom() - 4.0),
                egui::Align2::RIGHT_BOTTOM,
            ),
        ];
        for (text, at, align) in texts {
            let galley =
                painter.layout_no_wrap(text, egui::FontId::monospace(12.0), egui::Color32::WHITE);
            let r = align.anchor_size(at, galley.size());
            painter.rect_filled(r.expand(2.0), 2.0, egui::Color32::from_black_alpha(160));
            painter.galley(r.min, galley, egui::Color32::WHITE);
        }
        let handle = egui::Rect::from_center_size(
            egui::pos2(x, rect.center().y),
            egui::vec2(12.0, rect.height()),
        );
        let r = ui.interact(
            handle,
            ui.make_persistent_id("pinview divider"),
            egui::Sense::drag(),
        );
        if r.hovered() || r.dragged() {
            ui.ctx().set_cursor_icon(egui::CursorIcon::ResizeHorizontal);
        }
        if r.dragged() {
            self.split = (self.split + r.drag_delta().x / rect.width().max(1.0)).clamp(0.0, 1.0);
        }
        r.dragged()
    }

    pub(super) fn keys(&mut self, ctx: &egui::Context) {
        use egui::Key;
        let pressed = |k: Key| ctx.input(|i| i.key_pressed(k));
        if ctx.egui_wants_keyboard_input() {
            return;
        }
        let step = 0.08;
        if pressed(Key::ArrowLeft) {
            self.view.orbit(-step, 0.0);
        }
        if pressed(Key::ArrowRight) {
            self.view.orbit(step, 0.0);
        }
        if pressed(Key::ArrowUp) {
            self.view.orbit(0.0, step);
        }
        if pressed(Key::ArrowDown) {
            self.view.orbit(0.0, -step);
        }
        if pressed(Key::Plus) || pressed(Key::Equals) {
            self.view.zoom(0.9);
        }
        if pressed(Key::Minus) {
            self.view.zoom(1.1);
        }
        if pressed(Key::F) {
            crate::scene_framing::frame_all(&mut self.view, &self.medium);
        }
        if pressed(Key::R) {
            let (o, t) = self.medium.home();
            self.view.origin = o;
            self.view.target = t;
        }
        if let Some(s) = &mut self.sequence {
            if pressed(Key::Space) {
                s.playing = !s.playing;
            }
            let n = s.len();
            let step_to = if pressed(Key::Period) {
                Some((s.current + 1) % n)
            } else if pressed(Key::Comma) {
                Some((s.current + n - 1) % n)
            } else {
                None
            };
            if let Some(i) = step_to
                && let Err(e) = self.go_to_frame(i)
            {
                self.status = e.to_string();
            }
        }
    }

    /// The entry under image pixel `(x, y)` (its centre at `x + 0.5`), where the medium has
    /// pins and the ray enters the box.
    pub(super) fn pick_at(&self, x: f64, y: f64) -> Option<Pick> {
        let grid = self.medium.pins()?;
        let proj = Projector::new(&self.view)?;
        let (o, d) = proj.ray(x + 0.5, y + 0.5);
        pin_overlay::pick(grid, o, d)
    }

    /// The column where the second side's image starts.
    pub(super) fn split_column(&self, width: u32) -> u32 {
        ((self.split.clamp(0.0, 1.0) * width as f32).round() as u32).min(width)
    }
}
