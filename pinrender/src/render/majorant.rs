//! Coarse majorant grid and its DDA traversal (per-segment majorants, as in pbrt-v4).

use super::error::RenderError;
use glam::DVec3;
use pin_volume::{Aabb, Density};

/// Max extinction per brick over a world box; bricks tile the box, `x` fastest, then `y`,
/// then `z` (the pin file's majorant-section layout).
#[derive(Clone, Debug)]
pub struct MajorantGrid {
    lo: [f64; 3],
    hi: [f64; 3],
    dims: [u32; 3],
    values: Vec<f32>,
    /// `dims / (hi - lo)`: world to brick coordinates.
    scale: [f64; 3],
}

/// One piece of a ray inside one brick: `[t0, t1]` (world distance along a unit direction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MajorantSegment {
    pub t0: f64,
    pub t1: f64,
    pub majorant: f32,
    pub brick: [u32; 3],
}

fn invalid(why: String) -> RenderError {
    RenderError::Invalid {
        what: "majorant grid",
        why,
    }
}

/// Accepts a box finite on every axis with `min < max` there; the message says why not.
pub fn check_box(lo: &[f64; 3], hi: &[f64; 3]) -> Result<(), String> {
    if (0..3).all(|a| lo[a].is_finite() && hi[a].is_finite() && lo[a] < hi[a]) {
        Ok(())
    } else {
        Err(format!(
            "box {lo:?}..{hi:?} must be finite with min < max on every axis"
        ))
    }
}

impl MajorantGrid {
    /// The pin file's majorant section as is: `values` is `dims[0] * dims[1] * dims[2]` f32
    /// tiling `[box_min, box_max]`, `x` fastest. Values must be finite and `>= 0`.
    pub fn from_parts(
        box_min: [f64; 3],
        box_max: [f64; 3],
        dims: [u32; 3],
        values: Vec<f32>,
    ) -> Result<Self, RenderError> {
        check_box(&box_min, &box_max).map_err(invalid)?;
        let n = (dims[0] as u64) * (dims[1] as u64) * (dims[2] as u64);
        if n == 0 || n != values.len() as u64 {
            return Err(invalid(format!(
                "dims {dims:?} need {n} values (>= 1), got {}",
                values.len()
            )));
        }
        if dims.iter().any(|&d| d > i32::MAX as u32) {
            return Err(invalid(format!("dims {dims:?} too large")));
        }
        if let Some(i) = values.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(invalid(format!(
                "value {} at {i} is not finite and >= 0",
                values[i]
            )));
        }
        let scale = [0, 1, 2].map(|a| dims[a] as f64 / (box_max[a] - box_min[a]));
        Ok(MajorantGrid {
            lo: box_min,
            hi: box_max,
            dims,
            values,
            scale,
        })
    }

    /// A single brick of majorant `value` over the box.
    pub fn uniform(box_min: [f64; 3], box_max: [f64; 3], value: f32) -> Result<Self, RenderError> {
        Self::from_parts(box_min, box_max, [1, 1, 1], vec![value])
    }

    /// Build over the field's bounds with `dims` bricks. Per brick it uses the field's exact
    /// [`Density::max_extinction_in`] where it is finite; otherwise the max over a 5x5x5 lattice
    /// of points spanning the brick (faces included) times 1.05 (conservative only for fields
    /// smooth at that scale; ratio tracking stays unbiased anyway, delta tracking clamps the
    /// acceptance probability where the bound is violated). Non-finite maxima (an infinite
    /// extinction) are stored as `f32::MAX`.
    pub fn from_field(field: &dyn Density, dims: [u32; 3]) -> Result<Self, RenderError> {
        let (lo, hi) = field.bounds().to_arrays();
        check_box(&lo, &hi).map_err(invalid)?;
        let n = (dims[0] as u64) * (dims[1] as u64) * (dims[2] as u64);
        if n == 0 || n > (1 << 30) {
            return Err(invalid(format!("dims {dims:?}: need 1 ..= 2^30 bricks")));
        }
        let mut values = Vec::with_capacity(n as usize);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let (blo, bhi) = brick_box(&lo, &hi, dims, [x, y, z]);
                    let m = match field.max_extinction_in(Aabb::from_arrays(blo, bhi)) {
                        m if m.is_finite() => m,
                        _ => {
                            const K: u32 = 5;
                            let mut m = 0.0f32;
                            for c in 0..K * K * K {
                                let k = [c % K, (c / K) % K, c / (K * K)];
                                let p = [0, 1, 2].map(|a| {
                                    (blo[a] + (bhi[a] - blo[a]) * k[a] as f64 / (K - 1) as f64)
                                        as f32
                                });
                                let v = field.extinction(glam::Vec3::from_array(p).as_dvec3());
                                if v > m {
                                    m = v;
                                }
                            }
                            m * 1.05
                        }
                    };
                    let m = if m > 0.0 { m.min(f32::MAX) } else { 0.0 };
                    values.push(m);
                }
            }
        }
        Self::from_parts(lo, hi, dims, values)
    }

    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        (self.lo, self.hi)
    }
    /// The closed world box of brick `i` (the last brick on an axis ends exactly at the
    /// grid's face).
    pub fn brick_bounds(&self, i: [u32; 3]) -> ([f64; 3], [f64; 3]) {
        brick_box(&self.lo, &self.hi, self.dims, i)
    }
    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }
    pub fn values(&self) -> &[f32] {
        &self.values
    }
    pub fn max_value(&self) -> f32 {
        self.values.iter().fold(0.0, |m, &v| m.max(v))
    }

    #[cfg(test)]
    fn value(&self, b: [i32; 3]) -> f32 {
        let d = self.dims;
        self.values[b[0] as usize + d[0] as usize * (b[1] as usize + d[1] as usize * b[2] as usize)]
    }

    /// The bricks crossed by the ray `o + t d` (`d` unit, all finite) for `t` in
    /// `[t_min, t_max]`, in order, clipped to the box. Zero-length segments may appear where
    /// the ray crosses an edge or corner; they are harmless to trackers.
    pub fn segments(&self, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Dda<'_> {
        Dda::new(self, o, d, t_min, t_max)
    }
}

/// Brick `i` of `dims` bricks tiling `[lo, hi]`.
fn brick_box(lo: &[f64; 3], hi: &[f64; 3], dims: [u32; 3], i: [u32; 3]) -> ([f64; 3], [f64; 3]) {
    let size = [0, 1, 2].map(|a| (hi[a] - lo[a]) / dims[a] as f64);
    let blo = [0, 1, 2].map(|a| lo[a] + i[a] as f64 * size[a]);
    let bhi = [0, 1, 2].map(|a| {
        if i[a] + 1 == dims[a] {
            hi[a]
        } else {
            lo[a] + (i[a] + 1) as f64 * size[a]
        }
    });
    (blo, bhi)
}

/// Slab clip of `o + t d`, `t` in `[t0, t1]`, against the closed box `[lo, hi]`. Axes with
/// `d = 0` (either sign) constrain nothing if the origin is within the slab (faces included)
/// and reject otherwise, so no `0 * inf` NaN can arise. Returns `None` for an empty or
/// zero-length overlap.
#[inline]
pub fn clip_box(
    o: DVec3,
    d: DVec3,
    lo: &[f64; 3],
    hi: &[f64; 3],
    t0: f64,
    t1: f64,
) -> Option<(f64, f64)> {
    let (mut tn, mut tf) = (t0, t1);
    for a in 0..3 {
        let (oa, da) = (o[a], d[a]);
        if da == 0.0 {
            if oa < lo[a] || oa > hi[a] {
                return None;
            }
        } else {
            let inv = 1.0 / da;
            let (mut n, mut f) = ((lo[a] - oa) * inv, (hi[a] - oa) * inv);
            if n > f {
                std::mem::swap(&mut n, &mut f);
            }
            if n > tn {
                tn = n;
            }
            if f < tf {
                tf = f;
            }
        }
    }
    if tn < tf { Some((tn, tf)) } else { None }
}

/// 3D DDA over the bricks (Amanatides-Woo), in f64.
///
/// The per-axis state is indexed only by constants in [`Iterator::next`] (one arm per
/// axis), so that the compiler can keep it in registers when a tracker's loop inlines the
/// iterator, and the brick's value is read through a running linear index.
pub struct Dda<'a> {
    values: &'a [f32],
    brick: [i32; 3],
    step: [i32; 3],
    limit: [i32; 3],
    next_t: [f64; 3],
    delta_t: [f64; 3],
    /// `brick`'s index into `values`, and its change per step along each axis.
    lin: isize,
    lin_step: [isize; 3],
    t: f64,
    t_end: f64,
    done: bool,
}

impl<'a> Dda<'a> {
    fn new(grid: &'a MajorantGrid, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Self {
        let mut it = Dda {
            values: &grid.values,
            brick: [0; 3],
            step: [0; 3],
            limit: [0; 3],
            next_t: [f64::INFINITY; 3],
            delta_t: [f64::INFINITY; 3],
            lin: 0,
            lin_step: [0; 3],
            t: 0.0,
            t_end: 0.0,
            done: true,
        };
        let Some((t0, t1)) = clip_box(o, d, &grid.lo, &grid.hi, t_min, t_max) else {
            return it;
        };
        it.t = t0;
        it.t_end = t1;
        it.done = false;
        let p = o + d * t0;
        let stride = [
            1isize,
            grid.dims[0] as isize,
            grid.dims[0] as isize * grid.dims[1] as isize,
        ];
        for a in 0..3 {
            let n = grid.dims[a] as i32;
            // Brick coordinate of the entry point; clamped because the entry point of a ray
            // from outside lies on a face, possibly a rounding error beyond it.
            let g = (p[a] - grid.lo[a]) * grid.scale[a];
            // `as` truncates towards zero and saturates (NaN: 0): after the clamp that is
            // `floor` (below 0 both give 0), without the libm call.
            let b = (g as i64).clamp(0, n as i64 - 1) as i32;
            it.brick[a] = b;
            it.lin += b as isize * stride[a];
            let dg = d[a] * grid.scale[a]; // bricks per unit t
            if dg > 0.0 {
                // max(0): the clamped brick may start after g (rounding); never step back.
                it.next_t[a] = t0 + ((b + 1) as f64 - g).max(0.0) / dg;
                it.delta_t[a] = 1.0 / dg;
                it.step[a] = 1;
                it.limit[a] = n;
            } else if dg < 0.0 {
                it.next_t[a] = t0 + (b as f64 - g).min(0.0) / dg;
                it.delta_t[a] = -1.0 / dg;
                it.step[a] = -1;
                it.limit[a] = -1;
            }
            it.lin_step[a] = it.step[a] as isize * stride[a];
            // dg == 0 (either sign of zero): never crosses on this axis; next_t stays inf.
        }
        it
    }

    /// The segment that ends at the next crossing of axis `A`, then the step across it.
    #[inline(always)]
    fn cross<const A: usize>(&mut self) -> MajorantSegment {
        let t1 = self.next_t[A].min(self.t_end);
        let seg = MajorantSegment {
            t0: self.t,
            t1,
            majorant: self.values[self.lin as usize],
            brick: self.brick.map(|v| v as u32),
        };
        if self.next_t[A] >= self.t_end {
            self.done = true;
        } else {
            self.brick[A] += self.step[A];
            self.lin += self.lin_step[A];
            if self.brick[A] == self.limit[A] {
                self.done = true;
            }
            self.next_t[A] += self.delta_t[A];
            self.t = t1;
        }
        seg
    }
}

impl Iterator for Dda<'_> {
    type Item = MajorantSegment;

    #[inline(always)]
    fn next(&mut self) -> Option<MajorantSegment> {
        if self.done {
            return None;
        }
        // Axis of the nearest crossing.
        let [x, y, z] = self.next_t;
        Some(if x < y {
            if x < z {
                self.cross::<0>()
            } else {
                self.cross::<2>()
            }
        } else if y < z {
            self.cross::<1>()
        } else {
            self.cross::<2>()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::field::FnField;
    use crate::render::rng::Pcg32;

    fn grid(dims: [u32; 3]) -> MajorantGrid {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let values = (0..n).map(|i| i as f32).collect();
        MajorantGrid::from_parts([-1.0, 0.0, 2.0], [1.0, 3.0, 2.5], dims, values).unwrap()
    }

    /// Compare the DDA against a brute-force fine march of the brick index: every fine
    /// sample point must lie in the DDA segment that covers it, with the same brick, and the
    /// segments must tile the clipped chord.
    fn check_ray(g: &MajorantGrid, o: DVec3, d: DVec3, t_max: f64) {
        let d = d.normalize();
        let segs: Vec<MajorantSegment> = g.segments(o, d, 0.0, t_max).collect();
        let chord = clip_box(o, d, &g.lo, &g.hi, 0.0, t_max);
        let Some((c0, c1)) = chord else {
            assert!(segs.is_empty(), "miss but segments {segs:?}");
            return;
        };
        assert!(!segs.is_empty());
        assert!((segs[0].t0 - c0).abs() < 1e-9);
        assert!(
            (segs.last().unwrap().t1 - c1).abs() < 1e-9,
            "{segs:?} vs {c1}"
        );
        for w in segs.windows(2) {
            assert_eq!(w[0].t1, w[1].t0);
            assert!(w[0].t1 >= w[0].t0);
        }
        let n = 20_000;
        for i in 0..n {
            let t = c0 + (c1 - c0) * (i as f64 + 0.5) / n as f64;
            let p = o + d * t;
            let brute = [0, 1, 2].map(|a| {
                (((p[a] - g.lo[a]) * g.scale[a]).floor() as i64).clamp(0, g.dims[a] as i64 - 1)
                    as u32
            });
            // Skip points within rounding distance of a brick face.
            let near_face = (0..3).any(|a| {
                let gc = (p[a] - g.lo[a]) * g.scale[a];
                (gc - gc.round()).abs() < 1e-7 && d[a] != 0.0
            });
            if near_face {
                continue;
            }
            let s = segs.iter().find(|s| s.t0 <= t && t <= s.t1).unwrap();
            assert_eq!(s.brick, brute, "t {t} o {o} d {d} segs {segs:?}");
            assert_eq!(s.majorant, g.value(brute.map(|v| v as i32)));
        }
    }

    #[test]
    fn dda_matches_brute_force() {
        let g = grid([4, 3, 5]);
        let v = |x, y, z| DVec3::new(x, y, z);
        // Axis-parallel, both signs, including -0.0 components.
        check_ray(&g, v(-5.0, 1.3, 2.2), v(1.0, 0.0, 0.0), f64::INFINITY);
        check_ray(&g, v(5.0, 1.3, 2.2), v(-1.0, -0.0, 0.0), f64::INFINITY);
        check_ray(&g, v(0.1, 10.0, 2.3), v(0.0, -1.0, -0.0), f64::INFINITY);
        check_ray(&g, v(0.1, 1.0, -3.0), v(0.0, 0.0, 1.0), f64::INFINITY);
        // Diagonal, through the box corner region.
        check_ray(&g, v(-2.0, -1.0, 1.0), v(1.0, 1.0, 0.5), f64::INFINITY);
        check_ray(&g, v(-1.0, 0.0, 2.0), v(2.0, 3.0, 0.5), f64::INFINITY); // corner to corner
        // Starting inside, with a t_max cut inside.
        check_ray(&g, v(0.2, 1.7, 2.1), v(-0.3, 0.9, 0.2), f64::INFINITY);
        check_ray(&g, v(0.2, 1.7, 2.1), v(0.7, -0.2, 0.1), 0.4);
        // Grazing: along a face (closed box), along an edge, along an inner brick boundary.
        check_ray(&g, v(-1.0, 0.5, 2.2), v(0.0, 1.0, 0.0), f64::INFINITY);
        check_ray(&g, v(-1.0, 0.0, 0.0), v(0.0, 0.0, 1.0), f64::INFINITY);
        check_ray(&g, v(0.0, -1.0, 2.25), v(0.0, 1.0, 0.0), f64::INFINITY);
        // Just outside a face: miss.
        check_ray(
            &g,
            v(-1.0 - 1e-12, 0.5, 2.2),
            v(0.0, 1.0, 0.0),
            f64::INFINITY,
        );
        // Pointing away, and t_max before the box.
        check_ray(&g, v(-5.0, 1.3, 2.2), v(-1.0, 0.0, 0.0), f64::INFINITY);
        check_ray(&g, v(-5.0, 1.3, 2.2), v(1.0, 0.0, 0.0), 1.0);
        // Random rays from outside and inside.
        let mut rng = Pcg32::new(9, 9);
        for _ in 0..200 {
            let o = v(
                -3.0 + 6.0 * rng.next_f64(),
                -2.0 + 7.0 * rng.next_f64(),
                1.0 + 2.5 * rng.next_f64(),
            );
            let d = v(
                rng.next_f64() - 0.5,
                rng.next_f64() - 0.5,
                rng.next_f64() - 0.5,
            );
            if d.length() > 1e-3 {
                check_ray(&g, o, d, f64::INFINITY);
            }
        }
    }

    #[test]
    fn from_parts_validates() {
        assert!(MajorantGrid::from_parts([0.0; 3], [1.0; 3], [2, 1, 1], vec![1.0]).is_err());
        assert!(MajorantGrid::from_parts([0.0; 3], [1.0; 3], [1, 1, 1], vec![-1.0]).is_err());
        assert!(MajorantGrid::from_parts([0.0; 3], [1.0; 3], [1, 1, 1], vec![f32::NAN]).is_err());
        assert!(MajorantGrid::from_parts([0.0; 3], [0.0; 3], [1, 1, 1], vec![1.0]).is_err());
        assert!(MajorantGrid::from_parts([0.0; 3], [1.0; 3], [0, 1, 1], vec![]).is_err());
        assert!(MajorantGrid::uniform([0.0; 3], [1.0; 3], 0.0).is_ok());
    }

    #[test]
    fn from_field_bounds_field() {
        // Linear ramp in x: sampling with faces included finds the exact max per brick.
        let f = FnField {
            min: [0.0; 3],
            max: [1.0; 3],
            f: |p: glam::Vec3| 1.0 + 3.0 * p.x,
        };
        let g = MajorantGrid::from_field(&f, [4, 2, 2]).unwrap();
        for (i, &v) in g.values().iter().enumerate() {
            let bx = (i % 4) as f32;
            assert!(v >= 1.0 + 3.0 * (bx + 1.0) / 4.0 - 1e-5, "{i}: {v}");
        }
    }
}
