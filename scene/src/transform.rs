//! An instance's transform: 12 numbers (row-major 3x4 local-to-world) or translate, rotate
//! and scale, composed as `T * R * S` (scale first), with `R = Rz * Ry * Rx` (XYZ Euler
//! angles in degrees: about x first, then y, then z, each about the fixed world axes).

use crate::ranges::num;

/// The identity local-to-world.
pub const IDENTITY: [f64; 12] = pin_format::IDENTITY_LOCAL_TO_WORLD;

/// Translate, rotate (XYZ Euler, degrees) and scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trs {
    pub translate: [f64; 3],
    pub rotate_deg: [f64; 3],
    pub scale: [f64; 3],
}

impl Default for Trs {
    fn default() -> Self {
        Trs {
            translate: [0.0; 3],
            rotate_deg: [0.0; 3],
            scale: [1.0; 3],
        }
    }
}

type M3 = [[f64; 3]; 3];

fn mul(a: &M3, b: &M3) -> M3 {
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    r
}

/// The row-major 3x4 local-to-world of `t`: `T * Rz * Ry * Rx * S`.
pub fn compose_trs(t: &Trs) -> [f64; 12] {
    let [x, y, z] = t.rotate_deg.map(f64::to_radians);
    let rx = [
        [1.0, 0.0, 0.0],
        [0.0, x.cos(), -x.sin()],
        [0.0, x.sin(), x.cos()],
    ];
    let ry = [
        [y.cos(), 0.0, y.sin()],
        [0.0, 1.0, 0.0],
        [-y.sin(), 0.0, y.cos()],
    ];
    let rz = [
        [z.cos(), -z.sin(), 0.0],
        [z.sin(), z.cos(), 0.0],
        [0.0, 0.0, 1.0],
    ];
    let s = [
        [t.scale[0], 0.0, 0.0],
        [0.0, t.scale[1], 0.0],
        [0.0, 0.0, t.scale[2]],
    ];
    let l = mul(&mul(&mul(&rz, &ry), &rx), &s);
    let mut m = [0.0; 12];
    for i in 0..3 {
        m[4 * i..4 * i + 3].copy_from_slice(&l[i]);
        m[4 * i + 3] = t.translate[i];
    }
    m
}

/// Shortest and longest column of the linear part a transform may have: a scale beyond a
/// million either way leaves the f32 queries of one of the two frames without precision.
pub const MIN_SCALE: f64 = 1e-6;
pub const MAX_SCALE: f64 = 1e6;

/// Checks a local-to-world: finite, translation within +-1e12, every column's length in
/// [[`MIN_SCALE`], [`MAX_SCALE`]], and the linear part's condition (`|det|` over the columns'
/// lengths, 1 for any rotation and scales) at least [`pin_format::MIN_TRANSFORM_CONDITION`]:
/// the one rule (`pin_format::transform_condition`) the pin format applies to a
/// grid's own transform and the runtime to every placement it samples.
pub fn check(m: &[f64; 12]) -> Result<(), String> {
    if m.iter().any(|x| !x.is_finite()) {
        return Err("a transform must be finite".into());
    }
    crate::ranges::position([m[3], m[7], m[11]]).map_err(|e| format!("translation {e}"))?;
    let col = |j: usize| [m[j], m[4 + j], m[8 + j]];
    let len = |c: [f64; 3]| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    for (j, axis) in ["x", "y", "z"].iter().enumerate() {
        let l = len(col(j));
        if !(MIN_SCALE..=MAX_SCALE).contains(&l) {
            return Err(format!(
                "scales the {axis} axis by {}, outside [{}, {}]",
                num(l),
                num(MIN_SCALE),
                num(MAX_SCALE)
            ));
        }
    }
    let (_, condition) = pin_format::transform_condition(m);
    if !(condition >= pin_format::MIN_TRANSFORM_CONDITION) {
        return Err(format!(
            "singular or too sheared (|det| over its columns' lengths {}, at least {} needed)",
            num(condition),
            num(pin_format::MIN_TRANSFORM_CONDITION)
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn apply(m: &[f64; 12], p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2]
            .map(|i| m[4 * i] * p[0] + m[4 * i + 1] * p[1] + m[4 * i + 2] * p[2] + m[4 * i + 3])
    }

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12)
    }

    #[test]
    fn scale_then_rotate_x_then_z_then_translate() {
        let t = Trs {
            translate: [10.0, 20.0, 30.0],
            rotate_deg: [90.0, 0.0, 90.0],
            scale: [2.0, 3.0, 4.0],
        };
        let m = compose_trs(&t);
        // x: scaled to 2, unmoved by Rx, turned by Rz onto y.
        assert!(close(apply(&m, [1.0, 0.0, 0.0]), [10.0, 22.0, 30.0]));
        // y: scaled to 3, Rx turns it onto z, Rz keeps z.
        assert!(close(apply(&m, [0.0, 1.0, 0.0]), [10.0, 20.0, 33.0]));
        // z: scaled to 4, Rx turns it onto -y, Rz turns -y onto +x.
        assert!(close(apply(&m, [0.0, 0.0, 1.0]), [14.0, 20.0, 30.0]));
        assert_eq!(compose_trs(&Trs::default()), IDENTITY);
    }

    #[test]
    fn rotate_y_turns_z_onto_x() {
        let m = compose_trs(&Trs {
            rotate_deg: [0.0, 90.0, 0.0],
            ..Trs::default()
        });
        assert!(close(apply(&m, [0.0, 0.0, 1.0]), [1.0, 0.0, 0.0]));
    }

    #[test]
    fn checks_refuse_what_queries_cannot_resolve() {
        assert!(check(&IDENTITY).is_ok());
        let mirrored = compose_trs(&Trs {
            scale: [-1.0, 1.0, 1.0],
            ..Trs::default()
        });
        assert!(check(&mirrored).is_ok());
        let mut singular = IDENTITY;
        singular[10] = 0.0;
        assert!(
            check(&singular)
                .unwrap_err()
                .contains("scales the z axis by 0")
        );
        let mut sheared = IDENTITY;
        sheared[1] = 1e9;
        sheared[0] = 1e-3;
        assert!(check(&sheared).is_err());
        let mut flat = IDENTITY;
        flat[2] = 1.0;
        flat[10] = 1e-9;
        assert!(check(&flat).unwrap_err().contains("singular"));
        let mut far = IDENTITY;
        far[3] = 2e12;
        assert!(check(&far).unwrap_err().contains("translation"));
        let mut nan = IDENTITY;
        nan[5] = f64::NAN;
        assert!(check(&nan).is_err());
    }
}
