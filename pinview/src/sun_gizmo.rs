//! The sun gizmo: a small sphere drawn as the camera sees it, with the sun's point on it; a
//! drag on the sphere moves the point there and sets the direction towards the sun. The
//! sphere's front half faces the camera; a sun behind it is drawn hollow, and a drag keeps it
//! on the half it started on.

use glam::DVec3;

/// The gizmo's side in points.
const SIDE: f32 = 96.0;

/// The camera's right, up and back (towards the camera) axes for a view from `origin` to
/// `target`.
fn camera_axes(origin: [f64; 3], target: [f64; 3]) -> (DVec3, DVec3, DVec3) {
    let back = (DVec3::from(origin) - DVec3::from(target)).normalize_or_zero();
    let back = if back == DVec3::ZERO { DVec3::Z } else { back };
    let mut right = DVec3::Y.cross(back);
    if right.length_squared() < 1e-12 {
        right = DVec3::X;
    }
    let right = right.normalize();
    let up = back.cross(right);
    (right, up, back)
}

/// The direction for the point `(x, y)` of the unit disc (x right, y up) on the sphere's
/// front half (`front`) or back half; a point outside the disc is taken to its rim.
pub fn direction_at(
    (x, y): (f64, f64),
    front: bool,
    origin: [f64; 3],
    target: [f64; 3],
) -> [f64; 3] {
    let (right, up, back) = camera_axes(origin, target);
    let r2 = x * x + y * y;
    let (x, y, z) = if r2 >= 1.0 {
        let r = r2.sqrt();
        (x / r, y / r, 0.0)
    } else {
        (x, y, (1.0 - r2).sqrt())
    };
    let z = if front { z } else { -z };
    (x * right + y * up + z * back).normalize().to_array()
}

/// Where `dir` stands on the gizmo: `(x, y)` in the unit disc, and whether on the front half.
pub fn point_of(dir: [f64; 3], origin: [f64; 3], target: [f64; 3]) -> ((f64, f64), bool) {
    let (right, up, back) = camera_axes(origin, target);
    let d = DVec3::from(dir).normalize_or_zero();
    ((d.dot(right), d.dot(up)), d.dot(back) >= 0.0)
}

/// The gizmo: draws the sphere and the sun's point, and sets `sun_dir` from a drag on it
/// (true when it changed).
pub fn sun_gizmo(
    ui: &mut egui::Ui,
    sun_dir: &mut [f64; 3],
    origin: [f64; 3],
    target: [f64; 3],
) -> bool {
    let (rect, response) = ui.allocate_exact_size(egui::vec2(SIDE, SIDE), egui::Sense::drag());
    let centre = rect.center();
    let radius = 0.45 * SIDE;
    let (_, front) = point_of(*sun_dir, origin, target);
    let mut changed = false;
    if let Some(p) = response
        .interact_pointer_pos()
        .filter(|_| response.dragged())
    {
        let x = f64::from((p.x - centre.x) / radius);
        let y = f64::from((centre.y - p.y) / radius);
        *sun_dir = direction_at((x, y), front, origin, target);
        changed = true;
    }
    let painter = ui.painter_at(rect);
    painter.circle(
        centre,
        radius,
        egui::Color32::from_gray(40),
        egui::Stroke::new(1.0, egui::Color32::from_gray(160)),
    );
    // The equator and the meridian facing the camera, for the sphere's shape.
    let line = egui::Stroke::new(0.5, egui::Color32::from_gray(90));
    painter.line_segment(
        [
            centre - egui::vec2(radius, 0.0),
            centre + egui::vec2(radius, 0.0),
        ],
        line,
    );
    painter.line_segment(
        [
            centre - egui::vec2(0.0, radius),
            centre + egui::vec2(0.0, radius),
        ],
        line,
    );
    let ((x, y), front) = point_of(*sun_dir, origin, target);
    let at = centre + egui::vec2(x as f32 * radius, -(y as f32) * radius);
    let sun = egui::Color32::from_rgb(255, 210, 60);
    if front {
        painter.circle_filled(at, 5.0, sun);
    } else {
        painter.circle_stroke(at, 5.0, egui::Stroke::new(1.5, sun));
    }
    response.on_hover_text("drag the point: the direction towards the sun");
    changed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_and_its_direction_round_trip() {
        let (o, t) = ([0.3, 0.8, 2.6], [0.5, 0.5, 0.5]);
        for dir in [[0.3, 1.0, 0.2], [-0.7, 0.1, -0.6], [0.0, -1.0, 0.05]] {
            let (p, front) = point_of(dir, o, t);
            let back = direction_at(p, front, o, t);
            let d = DVec3::from(dir).normalize();
            assert!(
                (DVec3::from(back) - d).length() < 1e-9,
                "{dir:?} -> {back:?}"
            );
        }
        // The disc's centre on the front half points at the camera; the top of the disc up
        // in the image.
        let at_camera = DVec3::from(direction_at((0.0, 0.0), true, o, t));
        let to_camera = (DVec3::from(o) - DVec3::from(t)).normalize();
        assert!((at_camera - to_camera).length() < 1e-9);
        let top = direction_at((0.0, 1.0), true, o, t);
        assert!(top[1] > 0.9, "{top:?}");
        // Outside the disc: its rim.
        let rim = direction_at((3.0, 4.0), true, o, t);
        assert!((DVec3::from(rim).length() - 1.0).abs() < 1e-12);
    }
}
