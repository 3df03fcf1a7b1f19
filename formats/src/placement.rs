//! The placement rule: where a grid may sit so that the runtime's f32 queries can find it.
//!
//! One rule for every surface: the baker applies it before a bake starts (to the box and the
//! transform the bake will record), and every reader applies it when it opens or verifies a
//! file ([`crate::GridShape::new`]). A placement outside it used to bake and verify and then
//! answer nonsense (a box of extent 1e39 overflows f32 and read as empty space: transmittance
//! 1 through an opaque box) or nothing at all (a box of extent 1e-300, a singular or hugely
//! sheared `local_to_world`, which every query refused).

/// A number for the messages: scientific below 1e-3 and from 1e6 up (`1e-9`, not
/// `0.000000001`), else [`crate::text::num`].
fn num(x: f64) -> String {
    if x != 0.0 && x.is_finite() && !(1e-3..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        crate::text::num(x)
    }
}

/// The largest coordinate of a box corner, local or world, in either sign: beyond it an f32
/// position has a spacing of more than 2^16 units and squared lengths approach f32's range.
pub const MAX_PLACEMENT_COORD: f64 = 1e12;
/// The smallest edge of a box, local or world: the smallest voxel size a bake accepts.
pub const MIN_PLACEMENT_EXTENT: f64 = 1e-9;
/// The smallest edge of a box relative to its largest coordinate: a box narrower than this
/// spans fewer than about 80 f32 steps of its own position, and a query cannot tell its
/// cells apart.
pub const MIN_RELATIVE_EXTENT: f64 = 1e-5;
/// The smallest `|det L| / (|L e0| |L e1| |L e2|)` of the transform's linear part `L`: 1 for
/// a rotation with any scales, 0 for a singular map; below it the map is too sheared for
/// its f32 inverse to keep three significant digits.
pub const MIN_TRANSFORM_CONDITION: f64 = 1e-6;

/// The one singularity rule for an affine map's linear part `L` (row-major 3x4 `m`, the
/// translation ignored), shared by the file format, the scene format and the runtime:
/// `(det L, |det L| / (|L e0| |L e1| |L e2|))`. The second is 1 for a rotation with any
/// scales (`{"scale": [1e-6, 1e6, 1]}` included), 0 for a singular map and NaN for a
/// non-finite one; a map is usable when it is at least [`MIN_TRANSFORM_CONDITION`].
pub fn transform_condition(m: &[f64; 12]) -> (f64, f64) {
    let col = |j: usize| [m[j], m[4 + j], m[8 + j]];
    let norm = |c: [f64; 3]| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let det = m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8])
        + m[2] * (m[4] * m[9] - m[5] * m[8]);
    let lengths = norm(col(0)) * norm(col(1)) * norm(col(2));
    (det, det.abs() / lengths)
}

/// The identity `local_to_world`: a grid placed in its source's own frame.
pub const IDENTITY_LOCAL_TO_WORLD: [f64; 12] =
    [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];

/// Checks a grid's placement: the local box `[box_min, box_max]` and the row-major 3x4
/// `local_to_world`. Finite, invertible, and within what f32 queries can represent: every
/// corner, local and world, within [`MAX_PLACEMENT_COORD`]; every edge at least
/// [`MIN_PLACEMENT_EXTENT`] and [`MIN_RELATIVE_EXTENT`] of the box's largest coordinate;
/// the linear part's condition at least [`MIN_TRANSFORM_CONDITION`]. The error is one
/// phrase for a message.
pub fn check_placement(
    box_min: [f64; 3],
    box_max: [f64; 3],
    local_to_world: &[f64; 12],
) -> Result<(), String> {
    check_box("box", box_min, box_max)?;
    let m = local_to_world;
    if m.iter().any(|x| !x.is_finite()) {
        return Err("local-to-world transform is not finite".into());
    }
    let (det, condition) = transform_condition(m);
    if !(condition >= MIN_TRANSFORM_CONDITION) {
        return Err(format!(
            "local-to-world transform is singular or too sheared (det {}, |det| over its columns' lengths {}, at least {} needed)",
            num(det),
            num(condition),
            num(MIN_TRANSFORM_CONDITION)
        ));
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for corner in 0..8 {
        let p = [0, 1, 2].map(|k| {
            if corner >> k & 1 == 0 {
                box_min[k]
            } else {
                box_max[k]
            }
        });
        for i in 0..3 {
            let w = m[4 * i] * p[0] + m[4 * i + 1] * p[1] + m[4 * i + 2] * p[2] + m[4 * i + 3];
            lo[i] = lo[i].min(w);
            hi[i] = hi[i].max(w);
        }
    }
    check_box("world box", lo, hi)
}

/// The box rules of [`check_placement`] for one box.
fn check_box(what: &str, min: [f64; 3], max: [f64; 3]) -> Result<(), String> {
    let show = |v: [f64; 3]| v.map(num).join(",");
    let largest = min
        .iter()
        .chain(&max)
        .fold(0.0f64, |acc, x| acc.max(x.abs()));
    if !(largest <= MAX_PLACEMENT_COORD) {
        return Err(format!(
            "{what} [{}]..[{}] reaches beyond +-{} (or is not finite)",
            show(min),
            show(max),
            num(MAX_PLACEMENT_COORD)
        ));
    }
    let least = MIN_PLACEMENT_EXTENT.max(MIN_RELATIVE_EXTENT * largest);
    for (axis, (a, b)) in ["x", "y", "z"].iter().zip(min.iter().zip(&max)) {
        let edge = b - a;
        if !(edge >= least) {
            return Err(format!(
                "{what} [{}]..[{}] is {} wide along {axis}, less than {} that f32 queries can resolve there",
                show(min),
                show(max),
                num(edge),
                num(least)
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const ID: [f64; 12] = IDENTITY_LOCAL_TO_WORLD;

    #[test]
    fn ordinary_placements_pass() {
        assert_eq!(check_placement([0.0; 3], [1.0; 3], &ID), Ok(()));
        // A voxel-index box with a 0.01 voxel size and a 30 degree rotation about z.
        let (s, c) = (0.5f64 * 0.01, 0.866_025_403_784_438_6 * 0.01);
        let m = [c, -s, 0.0, 5.0, s, c, 0.0, -3.0, 0.0, 0.0, 0.01, 1.0];
        assert_eq!(check_placement([-20.0; 3], [300.0; 3], &m), Ok(()));
    }

    #[test]
    fn what_f32_cannot_hold_is_refused() {
        let e = check_placement([0.0; 3], [1e39; 3], &ID).unwrap_err();
        assert!(e.contains("beyond +-1e12"), "{e}");
        let e = check_placement([0.0; 3], [1e-300; 3], &ID).unwrap_err();
        assert!(e.contains("1e-300 wide along x, less than 1e-9"), "{e}");
        // 1e-3 wide at 1e6: 1e-9 relative.
        assert!(check_placement([1e6; 3], [1e6 + 1e-3; 3], &ID).is_err());
        assert!(check_placement([0.0; 3], [f64::NAN, 1.0, 1.0], &ID).is_err());
        let mut shear = ID;
        shear[1] = 1e100;
        let e = check_placement([0.0; 3], [1.0; 3], &shear).unwrap_err();
        assert!(e.contains("too sheared"), "{e}");
        let mut singular = ID;
        singular[10] = 0.0;
        assert!(check_placement([0.0; 3], [1.0; 3], &singular).is_err());
        let mut far = ID;
        far[3] = 1e13;
        let e = check_placement([0.0; 3], [1.0; 3], &far).unwrap_err();
        assert!(e.starts_with("world box"), "{e}");
        // No 301-digit numbers.
        assert!(e.len() < 200, "{e}");
    }
}
