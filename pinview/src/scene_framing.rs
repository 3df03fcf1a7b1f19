//! Framing what is rendered: "frame all" (a button, the `F` key) puts the camera outside the
//! union of the instances' boxes, looking at its centre, with the whole union in view; a
//! scene file whose camera stands inside an instance's box (a camera meant for a larger
//! placement, or a slab of clouds around the origin) opens framed that way instead, with a
//! note. The scene panel's instance count and what a scene offers are here too.

use glam::DVec3;
use pinrender::render::EstimatorSpec;

use crate::open::Medium;
use crate::view::View;

type WorldBox = ([f64; 3], [f64; 3]);

/// Whether `p` is inside (or on) `b`.
fn inside(p: DVec3, (lo, hi): WorldBox) -> bool {
    (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k])
}

/// The box around every box of `boxes` (`None` for none, or only empty ones).
fn union(boxes: &[WorldBox]) -> Option<WorldBox> {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for &(l, h) in boxes {
        lo = lo.min(DVec3::from(l));
        hi = hi.max(DVec3::from(h));
    }
    (lo.cmple(hi).all() && lo.is_finite() && hi.is_finite()).then(|| (lo.to_array(), hi.to_array()))
}

/// The camera `(origin, target)` that sees all of `boxes` from the side of `origin`: the
/// target at the centre of their union, the origin back along the current direction (the
/// default front-right-above one where origin and target meet) far enough that the sphere
/// around the union fits the narrower of the vertical field `fov_deg` and the horizontal one
/// of `aspect` (width / height), so it stands outside every box.
pub fn frame_all_camera(
    boxes: &[WorldBox],
    origin: [f64; 3],
    target: [f64; 3],
    fov_deg: f64,
    aspect: f64,
) -> Option<([f64; 3], [f64; 3])> {
    let (lo, hi) = union(boxes)?;
    let (lo, hi) = (DVec3::from(lo), DVec3::from(hi));
    let centre = 0.5 * (lo + hi);
    let radius = (0.5 * (hi - lo).length()).max(1e-6);
    let mut dir = (DVec3::from(origin) - DVec3::from(target)).normalize_or_zero();
    if dir == DVec3::ZERO || !dir.is_finite() {
        dir = DVec3::new(0.35, 0.25, 1.6).normalize();
    }
    let half_v = 0.5 * fov_deg.clamp(1.0, 179.0).to_radians();
    let half_h = (half_v.tan() * aspect.max(1e-3)).atan();
    let half = half_v.min(half_h);
    // A sphere of `radius` fills a cone of half-angle `half` at `radius / sin(half)`; a
    // little margin keeps the union off the image's edges.
    let distance = 1.05 * radius / half.sin();
    Some(((centre + dir * distance).to_array(), centre.to_array()))
}

/// Frames all of `medium` in `view` (the camera only).
pub fn frame_all(view: &mut View, medium: &Medium) {
    let aspect = f64::from(view.width) / f64::from(view.height.max(1));
    if let Some((o, t)) = frame_all_camera(
        &medium.instance_boxes(),
        view.origin,
        view.target,
        view.look.fov,
        aspect,
    ) {
        view.origin = o;
        view.target = t;
    }
}

/// Where a scene's camera stands inside an instance's box and no `--camera-origin` was
/// given, frames all instead and says so (the line for the window's notes).
pub fn open_outside(view: &mut View, medium: &Medium, origin_flag: bool) -> Option<String> {
    medium.scene()?;
    if origin_flag {
        return None;
    }
    let boxes = medium.instance_boxes();
    let o = DVec3::from(view.origin);
    let k = boxes.iter().position(|&b| inside(o, b))?;
    let was = view.origin;
    frame_all(view, medium);
    Some(format!(
        "the scene's camera at {:.3},{:.3},{:.3} is inside instance {} of {}: opened framing \
         all instances instead (--camera-origin keeps a camera)",
        was[0],
        was[1],
        was[2],
        k + 1,
        boxes.len()
    ))
}

/// The scene's lines in the panel: its instance count and what a scene offers; and the
/// "frame all" button (true when clicked).
pub fn scene_panel(ui: &mut egui::Ui, medium: &Medium, estimators: &[EstimatorSpec]) -> bool {
    if let Some(scene) = medium.scene() {
        ui.label(format!(
            "a scene: {} instances of {} assets",
            scene.instances.len(),
            scene.assets.len()
        ));
        ui.label(scene_note(estimators));
    }
    ui.button("frame all (F)")
        .on_hover_text("the camera outside every instance, looking at them all")
        .clicked()
}

/// What a scene offers: the estimators every asset answers (the menu), and the features
/// that need one medium.
fn scene_note(estimators: &[EstimatorSpec]) -> String {
    format!(
        "{} estimator{} that every asset answers; compare, the error view, the pin overlay and \
         re-bake need one medium",
        estimators.len(),
        if estimators.len() == 1 { "" } else { "s" }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_all_stands_outside_every_box_and_looks_at_the_union() {
        let boxes: Vec<WorldBox> = (0..256)
            .map(|i| {
                let (x, z) = (f64::from(i % 16) * 1.5, f64::from(i / 16) * 1.5);
                ([x, 0.0, z], [x + 1.0, 1.0, z + 1.0])
            })
            .collect();
        // From inside the slab, and from a degenerate camera (origin on its target).
        for (o, t) in [([3.2, 0.5, 3.3], [0.0, 0.5, 0.0]), ([1.0; 3], [1.0; 3])] {
            for (fov, aspect) in [(40.0, 1.0), (120.0, 0.5), (10.0, 3.0)] {
                let (o, t) = frame_all_camera(&boxes, o, t, fov, aspect).unwrap();
                let p = DVec3::from(o);
                assert!(boxes.iter().all(|&b| !inside(p, b)), "{o:?}");
                assert_eq!(t, [11.75, 0.5, 11.75]);
                // Every corner of the union within the narrower half-field.
                let half = 0.5_f64.to_radians() * fov;
                let half = half.min((half.tan() * aspect).atan());
                let f = (DVec3::from(t) - p).normalize();
                for c in [[0.0, 0.0, 0.0], [23.5, 1.0, 23.5], [0.0, 1.0, 23.5]] {
                    let d = (DVec3::from(c) - p).normalize();
                    assert!(d.dot(f).acos() < half, "{c:?} outside the view");
                }
            }
        }
        assert!(frame_all_camera(&[], [0.0; 3], [1.0; 3], 40.0, 1.0).is_none());
    }

    #[test]
    fn the_note_counts_the_menu() {
        let all = [EstimatorSpec::Pins, EstimatorSpec::RatioTracking];
        assert!(scene_note(&all).starts_with("2 estimators"));
        assert!(scene_note(&all[..1]).starts_with("1 estimator that"));
    }
}
