//! Pins made visible: the entry under the cursor (the spatial cell where the cursor's
//! primary ray first enters the box, the direction cell of the ray's direction, as the
//! sampler looks them up) with its pins' lines projected through the camera, each cut into
//! its 32 intervals coloured by the mask bits, and the entry's t_min and masks read from the
//! mapped file; the box and the cell grid as an overlay.

use glam::DVec3;
use pin_format::layout::GRID_FLAG_JITTERED_PINS;
use pinbake::pin::{PinLayout, unit_cube_chord as pin_chord};
use pinrt::chord::{UnitTransform, unit_cube_chord};
use pinrt::lookup::{GridView, direction_cell, spatial_cell};
use pinrt::{PinEntry, PinGrid};

use crate::view::View;

/// Pins drawn at most per entry (an entry holds up to 256).
pub const MAX_DRAWN_PINS: usize = 64;
/// Cell boundaries drawn at most per axis on each face of the box.
const MAX_GRID_LINES: u32 = 64;

/// The camera of a view as `pinrender render` builds it (`Camera::frame`): rays through
/// pixels, and world points back to pixels.
pub struct Projector {
    o: DVec3,
    f: DVec3,
    r: DVec3,
    u: DVec3,
    tan_half: f64,
    aspect: f64,
    w: f64,
    h: f64,
}

impl Projector {
    pub fn new(view: &View) -> Option<Self> {
        let o = DVec3::from(view.origin);
        let f = (DVec3::from(view.target) - o).normalize_or_zero();
        if f == DVec3::ZERO {
            return None;
        }
        let mut r = f.cross(DVec3::Y);
        if r.length_squared() < 1e-12 {
            r = f.cross(DVec3::Z);
        }
        let r = r.normalize();
        Some(Self {
            o,
            f,
            r,
            u: r.cross(f),
            tan_half: (view.look.fov.to_radians() * 0.5).tan(),
            aspect: f64::from(view.width) / f64::from(view.height),
            w: f64::from(view.width),
            h: f64::from(view.height),
        })
    }

    /// The ray through image position `(px, py)` (pixels from the top-left corner).
    pub fn ray(&self, px: f64, py: f64) -> (DVec3, DVec3) {
        let sx = (2.0 * px / self.w - 1.0) * self.tan_half * self.aspect;
        let sy = (1.0 - 2.0 * py / self.h) * self.tan_half;
        (self.o, self.f + self.r * sx + self.u * sy)
    }

    /// The image position of a world point, or `None` behind (or at) the camera.
    pub fn project(&self, p: DVec3) -> Option<[f64; 2]> {
        let v = p - self.o;
        let z = v.dot(self.f);
        if z <= 1e-9 {
            return None;
        }
        let sx = v.dot(self.r) / z / (self.tan_half * self.aspect);
        let sy = v.dot(self.u) / z / self.tan_half;
        Some([(sx + 1.0) * 0.5 * self.w, (1.0 - sy) * 0.5 * self.h])
    }
}

#[derive(Clone)]
/// One pin of the picked entry: its stored entry and its chord's ends in world space (from
/// the start, where interval 0 and mask bit 31 lie).
pub struct PickedPin {
    pub entry: PinEntry,
    pub chord: Option<[DVec3; 2]>,
}

/// The entry a ray reads first.
#[derive(Clone)]
pub struct Pick {
    pub cell: [u32; 3],
    pub direction: u32,
    /// The ray runs against the stored direction (`d.z < 0` in the unit cube): the sampler
    /// reads the mask bit-reversed.
    pub reversed: bool,
    pub pins: Vec<PickedPin>,
}

/// The grid's unit cube to world: `box_min + u * extent` in local space, then
/// `local_to_world`.
fn unit_to_world(grid: &PinGrid, u: DVec3) -> DVec3 {
    let d = grid.desc();
    let local = DVec3::from(d.box_min) + u * (DVec3::from(d.box_max) - DVec3::from(d.box_min));
    let m = &d.local_to_world;
    DVec3::new(
        m[0] * local.x + m[1] * local.y + m[2] * local.z + m[3],
        m[4] * local.x + m[5] * local.y + m[6] * local.z + m[7],
        m[8] * local.x + m[9] * local.y + m[10] * local.z + m[11],
    )
}

/// The entry the world ray `origin + t dir` reads where it first enters the box (or at its
/// origin inside it), looked up as the sampler does without jitter; `None` when it misses.
/// Each pin's line is the bake's (`pinbake::pin::PinLayout` from the file's seed and flags).
pub fn pick(grid: &PinGrid, origin: DVec3, dir: DVec3) -> Option<Pick> {
    let xf = UnitTransform::new(grid.desc(), None).ok()?;
    let f = |v: DVec3| v.to_array().map(|x| x as f32);
    let o = xf.point(f(origin));
    let d = xf.vector(f(dir));
    let chord = unit_cube_chord(o, d)?;
    let t0 = chord.t_enter.max(0.0);
    if !(t0 < chord.t_exit) {
        return None;
    }
    let p = [o[0] + d[0] * t0, o[1] + d[1] * t0, o[2] + d[2] * t0];
    let view = GridView::new(grid);
    let cell = spatial_cell(p, &view, None);
    let reversed = d[2] < 0.0;
    let dl = if reversed { d.map(|x| -x) } else { d };
    let direction = direction_cell(&view.shape.directions, dl, None);
    let desc = grid.desc();
    let layout = PinLayout {
        dims: view.shape.dims,
        directions: view.shape.directions,
        pins_per_entry: view.shape.pins_per_entry,
        jitter: desc.flags & GRID_FLAG_JITTERED_PINS != 0,
        seed: desc.seed,
    };
    let pins = (0..view.shape.pins_per_entry)
        .map(|k| {
            let mut rng = layout.rng(layout.cell_linear(cell), direction, k);
            let (p, w) = layout.line(cell, direction, &mut rng);
            let chord = pin_chord(p, w).map(|(s0, s1)| {
                [
                    unit_to_world(grid, p + w * s0),
                    unit_to_world(grid, p + w * s1),
                ]
            });
            PickedPin {
                entry: grid.entry(cell, direction, k),
                chord,
            }
        })
        .collect();
    Some(Pick {
        cell,
        direction,
        reversed,
        pins,
    })
}

/// `to_screen` maps image pixels to window points.
pub fn segment(
    painter: &egui::Painter,
    proj: &Projector,
    to_screen: &impl Fn([f64; 2]) -> egui::Pos2,
    a: DVec3,
    b: DVec3,
    stroke: egui::Stroke,
) {
    if let (Some(pa), Some(pb)) = (proj.project(a), proj.project(b)) {
        painter.line_segment([to_screen(pa), to_screen(pb)], stroke);
    }
}

/// Draws the picked entry's pins: each chord in 32 intervals, bright where the mask bit is
/// set (medium sampled there), faint where not; a dot at each chord's start.
pub fn draw_pins(
    painter: &egui::Painter,
    proj: &Projector,
    to_screen: &impl Fn([f64; 2]) -> egui::Pos2,
    pick: &Pick,
) {
    let set = egui::Stroke::new(2.5, egui::Color32::from_rgb(255, 200, 40));
    let clear = egui::Stroke::new(
        1.0,
        egui::Color32::from_rgba_unmultiplied(120, 200, 255, 160),
    );
    for pin in pick.pins.iter().take(MAX_DRAWN_PINS) {
        let Some([a, b]) = pin.chord else { continue };
        for i in 0..32u32 {
            let p0 = a + (b - a) * (f64::from(i) / 32.0);
            let p1 = a + (b - a) * (f64::from(i + 1) / 32.0);
            let on = pin.entry.mask >> (31 - i) & 1 == 1;
            segment(
                painter,
                proj,
                to_screen,
                p0,
                p1,
                if on { set } else { clear },
            );
        }
        if let Some(pa) = proj.project(a) {
            painter.circle_filled(to_screen(pa), 2.5, egui::Color32::WHITE);
        }
    }
}

/// Draws the box's edges and the cell boundaries on its faces (every k-th where an axis has
/// more than [`MAX_GRID_LINES`] cells).
pub fn draw_grid(
    painter: &egui::Painter,
    proj: &Projector,
    to_screen: &impl Fn([f64; 2]) -> egui::Pos2,
    grid: &PinGrid,
) {
    let dims = grid.shape().dims;
    let cells = egui::Stroke::new(1.0, egui::Color32::from_rgba_unmultiplied(80, 255, 120, 90));
    let edges = egui::Stroke::new(1.5, egui::Color32::from_rgb(80, 255, 120));
    let w = |u: [f64; 3]| unit_to_world(grid, DVec3::from(u));
    for axis in 0..3 {
        let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
        // Lines along `axis` at cell boundaries of `a1`, on the faces a2 = 0 and a2 = 1, and
        // of `a2` on the faces a1 = 0 and a1 = 1.
        for (across, face) in [(a1, a2), (a2, a1)] {
            let n = dims[across];
            let step = n.div_ceil(MAX_GRID_LINES).max(1);
            for j in (0..=n).step_by(step as usize) {
                let s = f64::from(j) / f64::from(n);
                for side in [0.0, 1.0] {
                    let mut p = [0.0; 3];
                    p[across] = s;
                    p[face] = side;
                    let mut q = p;
                    q[axis] = 1.0;
                    let edge = j == 0 || j == n;
                    segment(
                        painter,
                        proj,
                        to_screen,
                        w(p),
                        w(q),
                        if edge { edges } else { cells },
                    );
                }
            }
        }
    }
}

/// The readout of a pick: cell, direction, and each pin's t_min and mask (bit 31 first, the
/// interval at the chord's start).
pub fn describe(pick: &Pick) -> Vec<String> {
    let mut lines = vec![format!(
        "cell {:?}, direction cell {}{}",
        pick.cell,
        pick.direction,
        if pick.reversed {
            " (ray against it: mask read reversed)"
        } else {
            ""
        }
    )];
    for (k, p) in pick.pins.iter().enumerate().take(16) {
        lines.push(format!(
            "pin {k}: t_min {:.4}, mask {:032b}",
            p.entry.t_min, p.entry.mask
        ));
    }
    if pick.pins.len() > 16 {
        lines.push(format!("... {} pins in all", pick.pins.len()));
    }
    lines
}
