//! What is drawn over the image while the view changes: the medium's box and an arrow from
//! the sun towards its centre, so a drag answers with the geometry at once, whatever the
//! renderer's speed.

use glam::DVec3;

use crate::pin_overlay::{Projector, segment};

/// The box `(min, max)`'s twelve edges.
pub fn draw_box(
    painter: &egui::Painter,
    proj: &Projector,
    to_screen: &impl Fn([f64; 2]) -> egui::Pos2,
    (min, max): ([f64; 3], [f64; 3]),
) {
    let stroke = egui::Stroke::new(1.5, egui::Color32::from_rgb(80, 255, 120));
    let corner = |i: usize| {
        DVec3::new(
            if i & 1 == 0 { min[0] } else { max[0] },
            if i & 2 == 0 { min[1] } else { max[1] },
            if i & 4 == 0 { min[2] } else { max[2] },
        )
    };
    for i in 0..8 {
        for bit in [1, 2, 4] {
            if i & bit == 0 {
                segment(painter, proj, to_screen, corner(i), corner(i | bit), stroke);
            }
        }
    }
}

/// An arrow from the sun's side towards the box's centre along `sun_dir` (towards the sun),
/// as long as the box's diagonal, with a disc where the light comes from.
pub fn draw_sun(
    painter: &egui::Painter,
    proj: &Projector,
    to_screen: &impl Fn([f64; 2]) -> egui::Pos2,
    (min, max): ([f64; 3], [f64; 3]),
    sun_dir: [f64; 3],
) {
    let (min, max) = (DVec3::from(min), DVec3::from(max));
    let d = DVec3::from(sun_dir).normalize_or_zero();
    if d == DVec3::ZERO {
        return;
    }
    let centre = 0.5 * (min + max);
    let from = centre + d * (max - min).length().max(1e-9);
    let colour = egui::Color32::from_rgb(255, 210, 60);
    let (Some(a), Some(b)) = (proj.project(from), proj.project(centre)) else {
        return;
    };
    let (a, b) = (to_screen(a), to_screen(b));
    painter.circle_filled(a, 6.0, colour);
    painter.arrow(a, b - a, egui::Stroke::new(2.0, colour));
}
