//! The image and what the pointer and keys do to it: orbit, pan, zoom, the sun, the
//! divider of the split view, and the overlays of pins and cells drawn over it.

use pinrender::render::EstimatorSpec;

use super::Viewer;
use crate::gizmos;
use crate::pin_overlay::Projector;

/// What the pointer and keys did: the view changed (the accumulation starts again), it is
/// moving (the box and sun are drawn over the image until the first whole pass of the new
/// view), where the image stands in the window, and the divider of the split view.
#[derive(Debug)]
pub struct Input {
    pub dirty: bool,
    pub moving: bool,
    pub image_rect: Option<egui::Rect>,
    /// Where the divider stands, as a fraction of the image's width (left: the first
    /// estimator), and whether its handle holds the pointer (a drag that started on it).
    pub split: f32,
    pub divider_held: bool,
}

impl Default for Input {
    fn default() -> Self {
        Self {
            dirty: false,
            moving: false,
            image_rect: None,
            split: 0.5,
            divider_held: false,
        }
    }
}

/// How far from the divider's line (points, either side) a press takes the divider rather
/// than the camera.
pub const HANDLE_REACH: f32 = 10.0;

/// The divider's grab handle: a pill on the line at the image's middle height, with grip
/// marks, brighter while held.
fn draw_handle(painter: &egui::Painter, x: f32, rect: egui::Rect, held: bool) {
    let pill = egui::Rect::from_center_size(
        egui::pos2(x, rect.center().y),
        egui::vec2(12.0, 40.0f32.min(rect.height())),
    );
    let fill = if held {
        egui::Color32::WHITE
    } else {
        egui::Color32::from_gray(210)
    };
    painter.rect_filled(pill, 6.0, fill);
    painter.rect_stroke(
        pill,
        6.0,
        egui::Stroke::new(1.0, egui::Color32::from_black_alpha(200)),
        egui::StrokeKind::Inside,
    );
    for dy in [-6.0, 0.0, 6.0] {
        let y = pill.center().y + dy;
        painter.line_segment(
            [egui::pos2(x - 3.0, y), egui::pos2(x + 3.0, y)],
            egui::Stroke::new(1.0, egui::Color32::from_gray(80)),
        );
    }
}

impl Viewer {
    /// The image with its mouse controls.
    pub(super) fn image(&mut self, ui: &mut egui::Ui) {
        let avail = ui.available_size();
        let ppp = ui.ctx().pixels_per_point();
        // Nothing accumulated to lose yet: the first size is taken at once.
        let at_once = self.main.live.is_none() && self.main.pending.is_none();
        let current = (self.view.width, self.view.height);
        let held = self.held();
        if let Some((w, h)) = self.viewport.update(
            avail,
            ppp,
            current,
            std::time::Instant::now(),
            at_once,
            held,
        ) {
            self.view.width = w;
            self.view.height = h;
        }
        if let Some(note) = self.viewport.reduction_note() {
            self.note(note);
        }
        let (w, h) = self.images.main.size;
        let scale = (avail.x / w as f32)
            .min(avail.y / h as f32)
            .min(self.viewport.points_per_pixel(ppp))
            .max(0.01);
        let size = egui::vec2(w as f32 * scale, h as f32 * scale);
        let response = ui.add(
            egui::Image::new(egui::load::SizedTexture::new(self.images.main.id, size))
                .sense(egui::Sense::click_and_drag()),
        );
        if self.overlays.heat_on
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
        self.input.image_rect = Some(response.rect);
        self.draw_overlays(ui, &response);
        if self.input.moving {
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

    /// The second estimator's image right of the divider, the divider (dragged to move it),
    /// and each side's label: estimator, spp and seconds spent. Returns whether the divider
    /// is being dragged.
    pub(super) fn split_view(&mut self, ui: &mut egui::Ui, rect: egui::Rect) -> bool {
        let (Some(c), Some(target)) = (&self.compare.live, &self.images.compare) else {
            self.input.divider_held = false;
            return false;
        };
        let split = self.input.split;
        let x = rect.left() + split * rect.width();
        let painter = ui.painter_at(rect);
        let right = egui::Rect::from_min_max(egui::pos2(x, rect.top()), rect.max);
        let right_id = match &self.error.textures[1] {
            Some(t) if self.overlays.heat_on => t.id(),
            _ => target.id,
        };
        painter.image(
            right_id,
            right,
            egui::Rect::from_min_max(egui::pos2(split, 0.0), egui::pos2(1.0, 1.0)),
            egui::Color32::WHITE,
        );
        painter.line_segment(
            [egui::pos2(x, rect.top()), egui::pos2(x, rect.bottom())],
            egui::Stroke::new(2.0, egui::Color32::WHITE),
        );
        let label = |est: EstimatorSpec, passes: u32, seconds: f64| {
            format!("{est}  {passes} spp  {seconds:.2} s")
        };
        let texts = [
            (
                label(self.view.estimator, self.main.passes(), self.main.seconds()),
                egui::pos2(rect.left() + 4.0, rect.top() + 4.0),
                egui::Align2::LEFT_TOP,
            ),
            (
                label(c.estimator, c.session.passes(), self.compare.seconds()),
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
        self.grab_divider(ui, rect);
        draw_handle(&painter, x, rect, self.input.divider_held);
        self.input.divider_held
    }

    /// The divider's handle takes the pointer before the camera does: a press within
    /// [`HANDLE_REACH`] of the line holds it until the button is let go, the divider
    /// following the pointer, and the image's drag (orbit, pan, sun) sees nothing of it.
    fn grab_divider(&mut self, ui: &egui::Ui, rect: egui::Rect) {
        let x = rect.left() + self.input.split * rect.width();
        let (pressed, down, released, origin, pos, hover) = ui.input(|i| {
            let p = &i.pointer;
            (
                p.primary_pressed(),
                p.primary_down(),
                p.primary_released(),
                p.press_origin(),
                p.interact_pos(),
                p.hover_pos(),
            )
        });
        let near = |p: egui::Pos2| {
            (p.x - x).abs() <= HANDLE_REACH && (rect.top()..=rect.bottom()).contains(&p.y)
        };
        if pressed && origin.is_some_and(near) {
            self.input.divider_held = true;
        }
        if self.input.divider_held
            && (down || released)
            && let Some(p) = pos
        {
            self.input.split = ((p.x - rect.left()) / rect.width().max(1.0)).clamp(0.0, 1.0);
        }
        if self.input.divider_held || hover.is_some_and(near) {
            ui.ctx().set_cursor_icon(egui::CursorIcon::ResizeHorizontal);
        }
        // Held through the frame the button is let go in, so that frame does not orbit.
        if self.input.divider_held && !down && !released {
            self.input.divider_held = false;
        }
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
            self.reset_view();
        }
        if let Some(s) = &mut self.playback.sequence {
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
                self.toasts.say(e.to_string());
            }
        }
    }

    /// The column where the second side's image starts.
    pub(super) fn split_column(&self, width: u32) -> u32 {
        ((self.input.split.clamp(0.0, 1.0) * width as f32).round() as u32).min(width)
    }
}
