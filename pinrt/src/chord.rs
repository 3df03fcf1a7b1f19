//! World ray -> unit cube, the chord through `[0, 1]^3` and the query segment in interval units.
//!
//! Everything here is f32 in a fixed operation order that `shaders/pin.wgsl` repeats; minimum
//! and maximum are written as compare-and-select so that `-0.0`/`+0.0` and NaN resolve the same
//! way on both sides.

use pin_format::GridDesc;

use crate::error::Error;
use crate::mask::is_finite_bits;

/// The determinant of the linear part `L` of a row-major 3x4 affine map and `inverse(L)`
/// by cofactors over that determinant, in this operation order (the bits every placement
/// of the workspace inverts with). The inverse is meaningful only for a finite, non-zero
/// determinant; each caller applies its own rule for "too close to singular".
pub fn linear_inverse(m: &[f64; 12]) -> (f64, [[f64; 3]; 3]) {
    let l = [[m[0], m[1], m[2]], [m[4], m[5], m[6]], [m[8], m[9], m[10]]];
    let det = l[0][0] * (l[1][1] * l[2][2] - l[1][2] * l[2][1])
        - l[0][1] * (l[1][0] * l[2][2] - l[1][2] * l[2][0])
        + l[0][2] * (l[1][0] * l[2][1] - l[1][1] * l[2][0]);
    let inv_det = 1.0 / det;
    let inv = [
        [
            (l[1][1] * l[2][2] - l[1][2] * l[2][1]) * inv_det,
            (l[0][2] * l[2][1] - l[0][1] * l[2][2]) * inv_det,
            (l[0][1] * l[1][2] - l[0][2] * l[1][1]) * inv_det,
        ],
        [
            (l[1][2] * l[2][0] - l[1][0] * l[2][2]) * inv_det,
            (l[0][0] * l[2][2] - l[0][2] * l[2][0]) * inv_det,
            (l[0][2] * l[1][0] - l[0][0] * l[1][2]) * inv_det,
        ],
        [
            (l[1][0] * l[2][1] - l[1][1] * l[2][0]) * inv_det,
            (l[0][1] * l[2][0] - l[0][0] * l[2][1]) * inv_det,
            (l[0][0] * l[1][1] - l[0][1] * l[1][0]) * inv_det,
        ],
    ];
    (det, inv)
}

/// The precomputed affine map from world space to the grid's unit cube.
///
/// `o_u = A o_w + b`, `d_u = A d_w` with `A = diag(1 / extent) * inverse(L)` and
/// `b = diag(1 / extent) * (-inverse(L) t - box_min)`, where `(L, t)` is the row-major 3x4
/// `local_to_world`. Directions are not renormalised: the ray parameter `t` means the same in
/// world, local and unit-cube space. Built in f64 once, stored and applied in f32.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnitTransform {
    /// Rows `(A_i0, A_i1, A_i2, b_i)`.
    pub rows: [[f32; 4]; 3],
}

impl UnitTransform {
    /// From a grid description, with an optional override of its `local_to_world`.
    pub fn new(desc: &GridDesc, local_to_world: Option<&[f64; 12]>) -> Result<Self, Error> {
        let m = local_to_world.unwrap_or(&desc.local_to_world);
        if m.iter().any(|x| !x.is_finite()) {
            return Err(Error::BadTransform("local_to_world is not finite".into()));
        }
        let t = [m[3], m[7], m[11]];
        let (det, inv) = linear_inverse(m);
        // The format's and the scene's rule (`transform_condition`): a map that scales its
        // axes very differently (1e-6, 1e6, 1) is well conditioned; only a singular or
        // too sheared one is refused.
        let (_, condition) = pin_format::transform_condition(m);
        if !det.is_finite() || det == 0.0 || !(condition >= pin_format::MIN_TRANSFORM_CONDITION) {
            return Err(Error::BadTransform(format!(
                "local_to_world is singular or too sheared (det {det:e}, |det| over its \
                 columns' lengths {condition:e}, at least {:e} needed)",
                pin_format::MIN_TRANSFORM_CONDITION
            )));
        }
        let mut rows = [[0.0f32; 4]; 3];
        for i in 0..3 {
            let extent = desc.box_max[i] - desc.box_min[i];
            let s = 1.0 / extent;
            let it = inv[i][0] * t[0] + inv[i][1] * t[1] + inv[i][2] * t[2];
            let row = [
                inv[i][0] * s,
                inv[i][1] * s,
                inv[i][2] * s,
                (-it - desc.box_min[i]) * s,
            ];
            for (dst, src) in rows[i].iter_mut().zip(row) {
                *dst = src as f32;
                if !dst.is_finite() {
                    return Err(Error::BadTransform(
                        "world-to-unit-cube map overflows f32".into(),
                    ));
                }
            }
        }
        Ok(Self { rows })
    }

    /// The world-space axis-aligned box of the unit cube under the inverse of this map (the
    /// grid box as placed in the world; for a rotated placement the box around it), computed
    /// in f64 from the stored f32 rows. `None` if the rows are not invertible in f64 (not
    /// reachable through [`UnitTransform::new`]).
    pub fn world_bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let a = self.rows.map(|r| r.map(f64::from));
        let m = [
            [a[0][0], a[0][1], a[0][2]],
            [a[1][0], a[1][1], a[1][2]],
            [a[2][0], a[2][1], a[2][2]],
        ];
        let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        if !(det.is_finite() && det != 0.0) {
            return None;
        }
        let inv_det = 1.0 / det;
        let inv = [
            [
                (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv_det,
                (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv_det,
                (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv_det,
            ],
            [
                (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv_det,
                (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv_det,
                (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv_det,
            ],
            [
                (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv_det,
                (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv_det,
                (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv_det,
            ],
        ];
        let b = [a[0][3], a[1][3], a[2][3]];
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for corner in 0..8u32 {
            // world = inv (u - b) for the unit-cube corner u.
            let u = [0, 1, 2].map(|k| f64::from((corner >> k) & 1) - b[k]);
            for i in 0..3 {
                let w = inv[i][0] * u[0] + inv[i][1] * u[1] + inv[i][2] * u[2];
                lo[i] = lo[i].min(w);
                hi[i] = hi[i].max(w);
            }
        }
        (lo.iter().chain(&hi).all(|x| x.is_finite())).then_some((lo, hi))
    }

    /// `A p + b`, evaluated as `((A0 px + A1 py) + A2 pz) + b` per row.
    #[inline(always)]
    pub fn point(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.rows;
        [
            r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + r[0][3],
            r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + r[1][3],
            r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + r[2][3],
        ]
    }

    /// `A v`, evaluated as `(A0 vx + A1 vy) + A2 vz` per row.
    #[inline(always)]
    pub fn vector(&self, v: [f32; 3]) -> [f32; 3] {
        let r = &self.rows;
        [
            r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
        ]
    }
}

/// The line's parameter range inside the closed unit cube.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chord {
    pub t_enter: f32,
    pub t_exit: f32,
}

/// Slab intersection of the line `o + t d` with `[0, 1]^3`.
///
/// * An axis with `d = 0` (either sign), or with `1/d` not finite (subnormal `d`), is parallel:
///   the line is inside the slab iff `0 <= o <= 1` (faces count as inside), else no chord.
/// * Other axes give `((0 - o) / d, (1 - o) / d)`; the chord is the intersection of the ranges.
/// * No chord when no axis constrains the line, when the range is empty or a single point
///   (`t_enter >= t_exit`, e.g. a corner graze), or when a bound is not finite (overflow for
///   extreme inputs). Inputs must be finite (checked by the caller).
#[inline(always)]
pub fn unit_cube_chord(o: [f32; 3], d: [f32; 3]) -> Option<Chord> {
    let mut lo = -f32::MAX;
    let mut hi = f32::MAX;
    let mut constrained = false;
    for a in 0..3 {
        let inv = if d[a] == 0.0 {
            f32::INFINITY
        } else {
            1.0 / d[a]
        };
        if !is_finite_bits(inv) {
            // Parallel to this slab (or so nearly that 1/d overflows).
            if !(o[a] >= 0.0 && o[a] <= 1.0) {
                return None;
            }
            continue;
        }
        let t0 = -o[a] * inv;
        let t1 = (1.0 - o[a]) * inv;
        let (n, f) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
        if n > lo {
            lo = n;
        }
        if f < hi {
            hi = f;
        }
        constrained = true;
    }
    if !constrained || !(lo < hi) || !is_finite_bits(lo) || !is_finite_bits(hi) {
        return None;
    }
    Some(Chord {
        t_enter: lo,
        t_exit: hi,
    })
}

/// The query segment `[t0, t1]` on a chord, in interval units `s = 32 (t - t_enter) / C`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    pub t_enter: f32,
    /// Chord length / 32: the length of one interval in ray-parameter units.
    pub interval_len: f32,
    /// `max(0, t_enter)`.
    pub t0: f32,
    /// `min(t_max, t_exit)`.
    pub t1: f32,
    /// Segment start and end in interval units, `0 <= s0 <= s1 <= 32`.
    pub s0: f32,
    pub s1: f32,
    /// First and last touched interval, `a <= b <= 31`.
    pub a: u32,
    pub b: u32,
}

impl Segment {
    /// A segment of no length at the chord start: the placeholder of a query that does not
    /// resolve (never read back).
    pub const EMPTY: Segment = Segment {
        t_enter: 0.0,
        interval_len: 0.0,
        t0: 0.0,
        t1: 0.0,
        s0: 0.0,
        s1: 0.0,
        a: 0,
        b: 0,
    };
}

/// `floor(x)` clamped to `[0, n - 1]`, NaN to 0 (same as `pin_format`'s direction binning).
#[inline(always)]
pub fn bin(x: f32, n: u32) -> u32 {
    (x as u32).min(n - 1)
}

/// Cuts `[max(0, t_enter), min(t_max, t_exit)]` out of the chord. `None` when the segment is
/// empty (`t_max <= max(0, t_enter)`, the whole chord behind the origin, `t_max = 0`) or the
/// chord is too short to divide (`32 / C` overflows). `t_max` must not be NaN (checked by the
/// caller); `+inf` means "to the chord's end".
#[inline(always)]
pub fn segment(chord: Chord, t_max: f32) -> Option<Segment> {
    let Chord { t_enter, t_exit } = chord;
    let t0 = if t_enter > 0.0 { t_enter } else { 0.0 };
    let t1 = if t_max < t_exit { t_max } else { t_exit };
    if !(t0 < t1) {
        return None;
    }
    let c = t_exit - t_enter;
    let k = 32.0 / c;
    if !is_finite_bits(c) || !is_finite_bits(k) {
        return None;
    }
    let s0 = if t0 == t_enter {
        0.0
    } else {
        let s = (t0 - t_enter) * k;
        if s < 32.0 { s } else { 32.0 }
    };
    let s1 = if t1 == t_exit {
        32.0
    } else {
        let s = (t1 - t_enter) * k;
        if s < 32.0 { s } else { 32.0 }
    };
    let a = bin(s0, 32);
    let fl = bin(s1, 32);
    // Last touched interval: ceil(s1) - 1, i.e. floor(s1) unless s1 is a whole number.
    let mut b = if fl as f32 == s1 && fl > 0 {
        fl - 1
    } else {
        fl
    };
    if b < a {
        b = a;
    }
    Some(Segment {
        t_enter,
        interval_len: c * 0.03125,
        t0,
        t1,
        s0,
        s1,
        a,
        b,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_format::{Directions, grid_desc};

    fn chord(o: [f32; 3], d: [f32; 3]) -> Option<(f32, f32)> {
        unit_cube_chord(o, d).map(|c| (c.t_enter, c.t_exit))
    }

    #[test]
    fn axis_parallel_rays() {
        assert_eq!(chord([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0]), Some((1.0, 2.0)));
        assert_eq!(chord([-1.0, 0.5, 0.5], [1.0, -0.0, 0.0]), Some((1.0, 2.0)));
        assert_eq!(chord([2.0, 0.5, 0.5], [-2.0, 0.0, -0.0]), Some((0.5, 1.0)));
        assert_eq!(chord([-1.0, 1.5, 0.5], [1.0, 0.0, 0.0]), None);
        // Inside, pointing along z.
        assert_eq!(
            chord([0.5, 0.5, 0.25], [0.0, 0.0, 1.0]),
            Some((-0.25, 0.75))
        );
    }

    #[test]
    fn faces_edges_corners() {
        // Along a face (y = 0 plane).
        assert_eq!(chord([-1.0, 0.0, 0.5], [1.0, 0.0, 0.0]), Some((1.0, 2.0)));
        // Along an edge (y = 0, z = 1).
        assert_eq!(chord([-1.0, 0.0, 1.0], [1.0, 0.0, 0.0]), Some((1.0, 2.0)));
        // Starting on a corner going in.
        assert_eq!(chord([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]), Some((0.0, 1.0)));
        // Starting on a corner going out: chord is behind.
        assert_eq!(chord([1.0, 1.0, 1.0], [1.0, 1.0, 1.0]), Some((-1.0, 0.0)));
        // Touching a corner only: a single point is no chord.
        assert_eq!(chord([-1.0, 1.0, 0.5], [1.0, 1.0, 0.0]), None);
        // Grazing an edge diagonally: (0,1) point only.
        assert_eq!(chord([-1.0, 0.0, 0.5], [1.0, 1.0, 0.0]), None);
        // On a face, going out.
        let c = chord([0.5, 1.0, 0.5], [0.0, 1.0, 0.0]).unwrap();
        assert_eq!(c, (-1.0, 0.0));
    }

    #[test]
    fn degenerate_directions() {
        assert_eq!(chord([0.5; 3], [0.0; 3]), None);
        assert_eq!(chord([0.5; 3], [-0.0; 3]), None);
        assert_eq!(chord([0.5; 3], [1e-45, 0.0, 0.0]), None); // 1/d overflows: parallel
        let c = chord([0.5; 3], [1e-45, 0.0, 1.0]).unwrap();
        assert_eq!(c, (-0.5, 0.5));
        // Overflowing parameters give no chord rather than inf.
        assert_eq!(chord([-3e38, 0.5, 0.5], [1e-30, 0.0, 0.0]), None);
    }

    #[test]
    fn segments() {
        let c = Chord {
            t_enter: -1.0,
            t_exit: 3.0,
        };
        let s = segment(c, f32::INFINITY).unwrap();
        assert_eq!(
            (s.t0, s.t1, s.s0, s.s1, s.a, s.b),
            (0.0, 3.0, 8.0, 32.0, 8, 31)
        );
        let s = segment(c, 1.0).unwrap();
        assert_eq!((s.s0, s.s1, s.a, s.b), (8.0, 16.0, 8, 15));
        let s = segment(c, 1.01).unwrap();
        assert_eq!((s.a, s.b), (8, 16));
        assert!(segment(c, 0.0).is_none());
        assert!(segment(c, -1.0).is_none());
        let behind = Chord {
            t_enter: -2.0,
            t_exit: -1.0,
        };
        assert!(segment(behind, f32::INFINITY).is_none());
        let front = Chord {
            t_enter: 2.0,
            t_exit: 6.0,
        };
        let s = segment(front, 2.0625).unwrap();
        assert_eq!((s.s0, s.s1, s.a, s.b), (0.0, 0.5, 0, 0));
        assert!(segment(front, 2.0).is_none());
        let tiny = Chord {
            t_enter: 0.0,
            t_exit: 1e-44,
        };
        assert!(segment(tiny, 1.0).is_none(), "32/C overflows");
    }

    #[test]
    fn transform_identity_and_affine() {
        let mut desc = grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1);
        let x = UnitTransform::new(&desc, None).unwrap();
        assert_eq!(x.point([0.25, 0.5, 1.0]), [0.25, 0.5, 1.0]);
        desc.box_min = [-1.0, 0.0, 2.0];
        desc.box_max = [1.0, 4.0, 3.0];
        // world = 2 * local + (10, 0, 0)
        let l2w = [2.0, 0.0, 0.0, 10.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0];
        let x = UnitTransform::new(&desc, Some(&l2w)).unwrap();
        // local (0, 2, 2.5) -> unit (0.5, 0.5, 0.5); world (10, 4, 5).
        assert_eq!(x.point([10.0, 4.0, 5.0]), [0.5, 0.5, 0.5]);
        // world direction (2,0,0) = local (1,0,0) = unit (0.5,0,0).
        assert_eq!(x.vector([2.0, 0.0, 0.0]), [0.5, 0.0, 0.0]);
        let singular = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        assert!(UnitTransform::new(&desc, Some(&singular)).is_err());
    }

    #[test]
    fn world_bounds_of_the_placed_box() {
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| (a[i] - b[i]).abs() <= 1e-5);
        let mut desc = grid_desc([1, 1, 1], Directions::Octahedral { n: 1 }, 1, 1);
        desc.box_min = [-1.0, 0.0, 2.0];
        desc.box_max = [1.0, 4.0, 3.0];
        let x = UnitTransform::new(&desc, None).unwrap();
        let (lo, hi) = x.world_bounds().unwrap();
        assert!(
            close(lo, [-1.0, 0.0, 2.0]) && close(hi, [1.0, 4.0, 3.0]),
            "{lo:?} {hi:?}"
        );
        // world = 2 * local + (10, 0, 0): x in [8, 12], y in [0, 8], z in [4, 6].
        let l2w = [2.0, 0.0, 0.0, 10.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0];
        let (lo, hi) = UnitTransform::new(&desc, Some(&l2w))
            .unwrap()
            .world_bounds()
            .unwrap();
        assert!(
            close(lo, [8.0, 0.0, 4.0]) && close(hi, [12.0, 8.0, 6.0]),
            "{lo:?} {hi:?}"
        );
        // A rotation by 90 degrees about z (x -> y, y -> -x): the box around the image.
        let rot = [0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let (lo, hi) = UnitTransform::new(&desc, Some(&rot))
            .unwrap()
            .world_bounds()
            .unwrap();
        assert!(
            close(lo, [-4.0, -1.0, 2.0]) && close(hi, [0.0, 1.0, 3.0]),
            "{lo:?} {hi:?}"
        );
        // A 90-degree rotation maps the box onto the box: every world corner lands on a
        // unit-cube corner.
        let x = UnitTransform::new(&desc, Some(&rot)).unwrap();
        for c in 0..8u32 {
            let w = [0, 1, 2].map(|k| lo[k] + (hi[k] - lo[k]) * f64::from((c >> k) & 1));
            let u = x.point(w.map(|v| v as f32));
            assert!(
                u.iter()
                    .all(|&v| v.abs() <= 1e-5 || (v - 1.0).abs() <= 1e-5),
                "{w:?} -> {u:?}"
            );
        }
    }
}
