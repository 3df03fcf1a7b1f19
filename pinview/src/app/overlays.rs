//! The overlays drawn over the image: the pins of the entry under the cursor (or held by a
//! click), the box with its cell grid, and the error view's heat map in place of the image.

use super::Viewer;
use crate::args::ViewArgs;
use crate::pin_overlay::{self, Pick, Projector};

/// Which overlays are on, the held pixel and entry, and the latest pick.
#[derive(Default)]
pub struct Overlays {
    pub pins_on: bool,
    pub grid_on: bool,
    /// The heat map (|estimate - reference|) shown in place of each side's image.
    pub heat_on: bool,
    pub held_pixel: Option<[f64; 2]>,
    /// The entry held: picked at `held_pixel` when the hold was taken and kept as the view
    /// moves, so its pins can be seen from the side.
    pub held: Option<Pick>,
    pub pick: Option<Pick>,
}

impl Overlays {
    /// The overlays the flags ask for.
    pub fn new(args: &ViewArgs) -> Self {
        Self {
            pins_on: args.pin_at.is_some(),
            grid_on: args.grid_overlay,
            heat_on: args.error_view,
            held_pixel: args.pin_at,
            held: None,
            pick: None,
        }
    }
}

impl Viewer {
    /// The pins under the cursor (or at the held pixel: a click holds or releases it) and the
    /// box with its cell grid, projected through the view's camera.
    pub(super) fn draw_overlays(&mut self, ui: &egui::Ui, response: &egui::Response) {
        let rect = response.rect;
        let (w, h) = (f64::from(self.view.width), f64::from(self.view.height));
        let to_pixel = |p: egui::Pos2| {
            [
                (f64::from((p.x - rect.left()) / rect.width().max(1.0)) * w).floor(),
                (f64::from((p.y - rect.top()) / rect.height().max(1.0)) * h).floor(),
            ]
        };
        if self.overlays.pins_on && response.clicked() {
            self.overlays.held_pixel = match self.overlays.held_pixel {
                Some(_) => None,
                None => response.interact_pointer_pos().map(to_pixel),
            };
            self.overlays.held = None;
        }
        let (Some(grid), Some(proj)) = (self.medium.pins().cloned(), Projector::new(&self.view))
        else {
            self.overlays.pick = None;
            return;
        };
        let to_screen = |p: [f64; 2]| {
            egui::pos2(
                rect.left() + (p[0] / w) as f32 * rect.width(),
                rect.top() + (p[1] / h) as f32 * rect.height(),
            )
        };
        let painter = ui.painter_at(rect);
        if self.overlays.grid_on {
            pin_overlay::draw_grid(&painter, &proj, &to_screen, &grid);
        }
        if !self.overlays.pins_on {
            self.overlays.pick = None;
            return;
        }
        // A hold keeps the entry picked when it was taken, whatever the view does since.
        if self.overlays.held.is_none()
            && let Some([x, y]) = self.overlays.held_pixel
        {
            self.overlays.held = self.pick_at(x, y);
        }
        self.overlays.pick = match &self.overlays.held {
            Some(p) => Some(p.clone()),
            None => response
                .hover_pos()
                .map(to_pixel)
                .and_then(|[x, y]| self.pick_at(x, y)),
        };
        if let Some(p) = &self.overlays.pick {
            pin_overlay::draw_pins(&painter, &proj, &to_screen, p);
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
}
