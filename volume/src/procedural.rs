//! Analytic density fields: a homogeneous box, a constant-density sphere, and cosine noise
//! (the cosine-noise paper, docs/background.md) in a single-octave and a fractal form.
//!
//! These are for exact references and for tests: they need no voxel storage, can be sampled at
//! any resolution, and the cosine noise has a closed-form optical depth along any segment
//! ([`CosineNoise::optical_depth`]), so transmittance through it is known without Monte Carlo
//! or quadrature error. They are not meant to model real media.
//!
//! # Cosine noise
//!
//! The paper's field is `phi(x) = c_offset + sum_i cos(x . S_i)` and it suggests clamping when
//! the offset is small; clamping would break the closed-form integral. We use a form that is
//! non-negative by construction instead:
//!
//! `sigma(x) = density * (1 + sum_k a_k cos(w_k . x + phi_k))`, with `a_k > 0`, `sum_k a_k = 1`,
//!
//! so `0 <= sigma <= 2 * density` and the spatial mean is `density`. Wave vectors follow the
//! paper: uniform directions, lengths `2 pi freq / L` times a uniform factor in `[0.8, 1.2]`
//! (`L` = the box's largest extent, so `freq` counts cycles across the box), phases uniform in
//! `[0, 2 pi)`; all drawn from `seed` with splitmix64. The fractal form stacks `octaves` such
//! sets, frequency times `lacunarity` and weight times `gain` per octave.
//!
//! # Spec grammar ([`ProceduralSpec`]'s `FromStr`)
//!
//! ```text
//! spec  := kind [ ':' param { ',' param } ]
//! kind  := 'box' | 'sphere' | 'cosine' | 'fractal'
//! param := key '=' value
//! ```
//!
//! | key | kinds | default | meaning |
//! |---|---|---|---|
//! | `density` | all | 1 | extinction (box, sphere) or mean extinction (noise) |
//! | `extent` | all | 1 | the world box is `[0, extent]^3` |
//! | `radius` | sphere | extent/2 | sphere radius, centred in the box |
//! | `seed` | cosine, fractal | 0 | RNG seed (u64) |
//! | `freq` | cosine, fractal | 4 | cycles across the box (base octave) |
//! | `waves` | cosine, fractal | 24 | wave vectors per octave (1..=1024) |
//! | `octaves` | fractal | 4 | number of octaves (1..=16) |
//! | `lacunarity` | fractal | 2 | frequency ratio between octaves |
//! | `gain` | fractal | 0.5 | weight ratio between octaves |
//!
//! Examples: `box`, `sphere:radius=0.4`, `cosine:seed=7,freq=16`, `fractal:seed=7,octaves=4`.
//! Unknown keys, repeated keys and keys that do not apply to the kind are errors.

use std::f64::consts::TAU;
use std::fmt;
use std::str::FromStr;

use glam::DVec3;

use super::{Aabb, Density, DensityScale, DensitySource, SourceError};

/// Constant extinction inside a box, zero outside.
#[derive(Clone, Debug)]
pub struct HomogeneousBox {
    bounds: Aabb,
    density: f32,
}

impl HomogeneousBox {
    pub fn new(bounds: Aabb, density: f32) -> Result<Self, SourceError> {
        check_box(&bounds)?;
        check_density(density as f64, 1.0)?;
        Ok(Self { bounds, density })
    }
    pub fn density(&self) -> f32 {
        self.density
    }
    /// Optical depth of the segment `p + s d`, `s in [0, t]` (exact).
    pub fn optical_depth(&self, p: DVec3, d: DVec3, t: f64) -> f64 {
        match clip_segment(&self.bounds, p, d, t) {
            Some((s0, s1)) => self.density as f64 * (s1 - s0),
            None => 0.0,
        }
    }
}

impl Density for HomogeneousBox {
    fn bounds(&self) -> Aabb {
        self.bounds
    }
    #[inline]
    fn extinction(&self, p: DVec3) -> f32 {
        if inside(&self.bounds, p) {
            self.density
        } else {
            0.0
        }
    }
    fn max_extinction_in(&self, region: Aabb) -> f32 {
        if intersects(&self.bounds, &region) {
            self.density
        } else {
            0.0
        }
    }
    /// `density` where the region lies inside the box, 0 where it reaches outside.
    fn min_extinction_in(&self, region: Aabb) -> Option<f32> {
        let inside =
            region.min.cmpge(self.bounds.min).all() && region.max.cmple(self.bounds.max).all();
        Some(if inside { self.density } else { 0.0 })
    }
}

impl DensitySource for HomogeneousBox {
    fn describe(&self) -> String {
        format!(
            "procedural box {}..{} density {}",
            self.bounds.min, self.bounds.max, self.density
        )
    }

    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.bounds)
    }
}

/// Constant extinction inside a ball (closed: the surface counts as inside), zero outside.
#[derive(Clone, Debug)]
pub struct Sphere {
    center: DVec3,
    radius: f64,
    radius_sq: f64,
    density: f32,
}

impl Sphere {
    pub fn new(center: DVec3, radius: f64, density: f32) -> Result<Self, SourceError> {
        if !(center.is_finite() && radius.is_finite() && radius > 0.0) {
            return Err(SourceError::InvalidOption(format!(
                "sphere needs a finite centre and a positive radius, got {center} r={radius}"
            )));
        }
        check_density(density as f64, 1.0)?;
        Ok(Self {
            center,
            radius,
            radius_sq: radius * radius,
            density,
        })
    }
    /// Optical depth of the segment `p + s d`, `s in [0, t]` (exact chord length times density).
    pub fn optical_depth(&self, p: DVec3, d: DVec3, t: f64) -> f64 {
        let dd = d.length_squared();
        if !(dd > 0.0 && t > 0.0) {
            return 0.0;
        }
        let oc = p - self.center;
        let b = oc.dot(d) / dd;
        let c = (oc.length_squared() - self.radius_sq) / dd;
        let disc = b * b - c;
        if disc.is_nan() || disc <= 0.0 {
            return 0.0;
        }
        let h = disc.sqrt();
        let (s0, s1) = ((-b - h).max(0.0), (-b + h).min(t));
        if s1 > s0 {
            self.density as f64 * (s1 - s0)
        } else {
            0.0
        }
    }
}

impl Density for Sphere {
    fn bounds(&self) -> Aabb {
        Aabb::new(self.center - self.radius, self.center + self.radius)
    }
    #[inline]
    fn extinction(&self, p: DVec3) -> f32 {
        if (p - self.center).length_squared() <= self.radius_sq {
            self.density
        } else {
            0.0
        }
    }
    fn max_extinction_in(&self, region: Aabb) -> f32 {
        // Closest point of the region to the centre decides.
        let q = self.center.clamp(region.min, region.max);
        if region.min.cmple(region.max).all()
            && (q - self.center).length_squared() <= self.radius_sq
        {
            self.density
        } else {
            0.0
        }
    }
}

impl DensitySource for Sphere {
    fn describe(&self) -> String {
        format!(
            "procedural sphere centre {} radius {} density {}",
            self.center, self.radius, self.density
        )
    }

    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.bounds())
    }
}

#[derive(Clone, Copy, Debug)]
struct Wave {
    w: DVec3,
    phase: f64,
    /// Weight; all weights sum to 1.
    amp: f64,
}

/// Cosine noise (single octave or fractal) inside a box; see the module docs for the form.
#[derive(Clone, Debug)]
pub struct CosineNoise {
    bounds: Aabb,
    density: f64,
    waves: Vec<Wave>,
    /// `density * sum a_k |w_k|`: bounds the gradient, for conservative region maxima.
    lipschitz: f64,
    label: String,
}

/// Parameters of [`CosineNoise`]; `octaves = 1` is the plain noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CosineParams {
    pub seed: u64,
    pub freq: f64,
    pub waves: u32,
    pub octaves: u32,
    pub lacunarity: f64,
    pub gain: f64,
    pub density: f64,
}

impl Default for CosineParams {
    fn default() -> Self {
        Self {
            seed: 0,
            freq: 4.0,
            waves: 24,
            octaves: 1,
            lacunarity: 2.0,
            gain: 0.5,
            density: 1.0,
        }
    }
}

/// splitmix64: tiny, fast, and good enough to place a few hundred waves reproducibly.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1) with 53 bits.
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

impl CosineNoise {
    pub fn new(
        bounds: Aabb,
        p: &CosineParams,
        label: impl Into<String>,
    ) -> Result<Self, SourceError> {
        check_box(&bounds)?;
        check_density(p.density, 2.0)?;
        let bad = |m: String| Err(SourceError::InvalidOption(m));
        if !(p.freq.is_finite() && p.freq > 0.0 && p.freq <= 1e6) {
            return bad(format!(
                "cosine freq must be in (0, 1e6], got {}",
                pin_format::text::num(p.freq)
            ));
        }
        if !(1..=1024).contains(&p.waves) {
            return bad(format!("cosine waves must be in 1..=1024, got {}", p.waves));
        }
        if !(1..=16).contains(&p.octaves) {
            return bad(format!("octaves must be in 1..=16, got {}", p.octaves));
        }
        if !(p.lacunarity.is_finite() && p.lacunarity > 0.0 && p.lacunarity <= 16.0) {
            return bad(format!(
                "lacunarity must be in (0, 16], got {}",
                p.lacunarity
            ));
        }
        if !(p.gain.is_finite() && p.gain > 0.0 && p.gain <= 16.0) {
            return bad(format!(
                "gain must be in (0, 16], got {}",
                pin_format::text::num(p.gain)
            ));
        }
        let top_freq = p.freq * p.lacunarity.powi(p.octaves as i32 - 1);
        if !(top_freq.is_finite() && top_freq <= 1e6) {
            return bad(format!("highest octave frequency {top_freq} exceeds 1e6"));
        }
        let extent = bounds.extent().max_element();
        let mut rng = SplitMix64(p.seed);
        let mut waves = Vec::with_capacity((p.waves * p.octaves) as usize);
        let mut weight_sum = 0.0;
        let mut weight = 1.0;
        let mut freq = p.freq;
        for _ in 0..p.octaves {
            for _ in 0..p.waves {
                let z = 2.0 * rng.next_f64() - 1.0;
                let az = TAU * rng.next_f64();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let dir = DVec3::new(r * az.cos(), r * az.sin(), z);
                let len = TAU * freq * (0.8 + 0.4 * rng.next_f64()) / extent;
                let phase = TAU * rng.next_f64();
                waves.push(Wave {
                    w: dir * len,
                    phase,
                    amp: weight,
                });
                weight_sum += weight;
            }
            weight *= p.gain;
            freq *= p.lacunarity;
        }
        for w in &mut waves {
            w.amp /= weight_sum;
        }
        let lipschitz = p.density * waves.iter().map(|w| w.amp * w.w.length()).sum::<f64>();
        Ok(Self {
            bounds,
            density: p.density,
            waves,
            lipschitz,
            label: label.into(),
        })
    }

    /// Mean extinction (the field lies in `[0, 2 * density]`).
    pub fn density(&self) -> f64 {
        self.density
    }

    /// The waves `(w, amplitude, phase)` of `density * max(0, 1 + sum amplitude cos(w . p +
    /// phase))`, for renderers that evaluate the field themselves (the GPU path tracer).
    pub fn waves(&self) -> impl Iterator<Item = (DVec3, f64, f64)> + '_ {
        self.waves.iter().map(|w| (w.w, w.amp, w.phase))
    }

    /// The analytic field in f64, ignoring the box (callers that want the box use
    /// [`Density::extinction`]).
    #[inline]
    pub fn field(&self, p: DVec3) -> f64 {
        let mut s = 1.0;
        for w in &self.waves {
            s += w.amp * (w.w.dot(p) + w.phase).cos();
        }
        // Rounding can dip a hair below zero where every cosine is near -1.
        (self.density * s).max(0.0)
    }

    /// Optical depth `integral_0^t sigma(p + s d) ds` (in units of `s`: world units when `d` is
    /// a unit vector), clipped to the box, in closed form.
    ///
    /// Uses `integral_0^T cos(a + b s) ds = T cos(a + b T/2) sinc(b T/2)`, which stays accurate
    /// as `b = w . d -> 0` (a direction perpendicular to a wave vector), where the textbook
    /// `(sin(a + b T) - sin a) / b` cancels catastrophically or divides by zero.
    pub fn optical_depth(&self, p: DVec3, d: DVec3, t: f64) -> f64 {
        let Some((s0, s1)) = clip_segment(&self.bounds, p, d, t) else {
            return 0.0;
        };
        let len = s1 - s0;
        let mid = p + d * (0.5 * (s0 + s1));
        let mut acc = len;
        for w in &self.waves {
            let half = 0.5 * w.w.dot(d) * len;
            acc += w.amp * len * (w.w.dot(mid) + w.phase).cos() * sinc(half);
        }
        (self.density * acc).max(0.0)
    }

    /// The textbook antiderivative `(sin(a + b t) - sin(a)) / b` (the paper's equation 7).
    /// Kept only to show where it breaks: it is NaN at `b = 0` and loses digits as `b -> 0`.
    pub fn optical_depth_naive(&self, p: DVec3, d: DVec3, t: f64) -> f64 {
        let Some((s0, s1)) = clip_segment(&self.bounds, p, d, t) else {
            return 0.0;
        };
        let mut acc = s1 - s0;
        for w in &self.waves {
            let a = w.w.dot(p) + w.phase;
            let b = w.w.dot(d);
            acc += w.amp * ((a + b * s1).sin() - (a + b * s0).sin()) / b;
        }
        self.density * acc
    }

    /// Distance `s` along `p + s d` at which the optical depth reaches `tau`, by bisection on
    /// the (monotone) closed form, or `None` if the segment `[0, t]` holds less than `tau`.
    /// Accurate to about `1e-12 * t`.
    pub fn distance_for_optical_depth(&self, p: DVec3, d: DVec3, t: f64, tau: f64) -> Option<f64> {
        if tau.is_nan() || tau < 0.0 || t.is_nan() || t < 0.0 || self.optical_depth(p, d, t) < tau {
            return None;
        }
        let (mut lo, mut hi) = (0.0, t);
        for _ in 0..64 {
            let mid = 0.5 * (lo + hi);
            if self.optical_depth(p, d, mid) < tau {
                lo = mid;
            } else {
                hi = mid;
            }
            if hi - lo <= 1e-12 * t {
                break;
            }
        }
        Some(0.5 * (lo + hi))
    }
}

impl Density for CosineNoise {
    fn bounds(&self) -> Aabb {
        self.bounds
    }
    #[inline]
    fn extinction(&self, p: DVec3) -> f32 {
        if inside(&self.bounds, p) {
            self.field(p) as f32
        } else {
            0.0
        }
    }
    fn max_extinction_in(&self, region: Aabb) -> f32 {
        let lo = region.min.max(self.bounds.min);
        let hi = region.max.min(self.bounds.max);
        if !lo.cmple(hi).all() {
            return 0.0;
        }
        // Value at the centre plus the gradient bound times the half diagonal; rounded up a
        // little so the f32 result can never fall below a sampled f32 value.
        let c = 0.5 * (lo + hi);
        let bound = self.field(c) + self.lipschitz * 0.5 * (hi - lo).length();
        let m = bound.min(2.0 * self.density) * (1.0 + 1e-6);
        m as f32
    }
}

impl DensitySource for CosineNoise {
    fn describe(&self) -> String {
        format!("procedural {}", self.label)
    }
    /// Along a line each wave's phase grows linearly, so `cos` is advanced by a rotation
    /// (two multiply-adds) instead of a libm call; the start phase is recomputed exactly every
    /// 64 samples so rounding cannot drift. About 6x faster than per-point evaluation; agrees
    /// with [`extinction`](Density::extinction) to ~1e-12 relative before the f32
    /// rounding (so within one f32 ulp).
    fn extinction_along(&self, origin: DVec3, step: DVec3, n: usize, out: &mut [f32]) {
        const CHUNK: usize = 64;
        let n = n.min(out.len());
        let mut acc = [0f64; CHUNK];
        let mut start = 0;
        while start < n {
            let len = (n - start).min(CHUNK);
            let o = origin + step * start as f64;
            acc[..len].fill(1.0);
            for w in &self.waves {
                let (mut s, mut c) = (w.w.dot(o) + w.phase).sin_cos();
                let (rs, rc) = w.w.dot(step).sin_cos();
                for a in &mut acc[..len] {
                    *a += w.amp * c;
                    (c, s) = (c * rc - s * rs, s * rc + c * rs);
                }
            }
            for (i, a) in acc[..len].iter().enumerate() {
                let p = origin + step * (start + i) as f64;
                out[start + i] = if inside(&self.bounds, p) {
                    (self.density * a).max(0.0) as f32
                } else {
                    0.0
                };
            }
            start += len;
        }
    }

    fn occupied_bounds(&self) -> Option<Aabb> {
        Some(self.bounds)
    }
}

/// `sin(x) / x` with the removable singularity filled in; the series is used where the
/// quotient would lose digits.
#[inline]
pub fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-3 {
        let x2 = x * x;
        1.0 - x2 / 6.0 * (1.0 - x2 / 20.0)
    } else {
        x.sin() / x
    }
}

/// Parameter interval of `p + s d`, `s in [0, t]`, inside the closed box, if non-empty.
fn clip_segment(b: &Aabb, p: DVec3, d: DVec3, t: f64) -> Option<(f64, f64)> {
    if t.is_nan() || t <= 0.0 || !p.is_finite() || !d.is_finite() {
        return None;
    }
    let (mut s0, mut s1) = (0.0f64, t);
    for a in 0..3 {
        if d[a] == 0.0 {
            if p[a] < b.min[a] || p[a] > b.max[a] {
                return None;
            }
        } else {
            let inv = 1.0 / d[a];
            let (ta, tb) = ((b.min[a] - p[a]) * inv, (b.max[a] - p[a]) * inv);
            s0 = s0.max(ta.min(tb));
            s1 = s1.min(ta.max(tb));
        }
    }
    (s1 > s0).then_some((s0, s1))
}

#[inline(always)]
fn inside(b: &Aabb, p: DVec3) -> bool {
    p.cmpge(b.min).all() && p.cmple(b.max).all()
}

fn intersects(a: &Aabb, b: &Aabb) -> bool {
    a.min.cmple(b.max).all() && b.min.cmple(a.max).all()
}

fn check_box(b: &Aabb) -> Result<(), SourceError> {
    if b.is_valid() {
        Ok(())
    } else {
        Err(SourceError::InvalidOption(format!(
            "box {}..{} must be finite with positive volume",
            b.min, b.max
        )))
    }
}

/// `density * peak` must be a finite f32 so that no sample can overflow.
fn check_density(density: f64, peak: f64) -> Result<(), SourceError> {
    if density.is_finite() && density >= 0.0 && ((density * peak) as f32).is_finite() {
        Ok(())
    } else {
        Err(SourceError::InvalidOption(format!(
            "density must be finite, >= 0 and keep peak values within f32, got {density}"
        )))
    }
}

/// Which analytic field a [`ProceduralSpec`] builds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProceduralKind {
    Box,
    Sphere,
    Cosine,
    Fractal,
}

impl ProceduralKind {
    fn name(self) -> &'static str {
        match self {
            ProceduralKind::Box => "box",
            ProceduralKind::Sphere => "sphere",
            ProceduralKind::Cosine => "cosine",
            ProceduralKind::Fractal => "fractal",
        }
    }
}

/// A parsed procedural source description; see the module docs for the grammar.
#[derive(Clone, Debug, PartialEq)]
pub struct ProceduralSpec {
    pub kind: ProceduralKind,
    pub density: f64,
    pub extent: f64,
    /// Sphere radius; `None` means `extent / 2`.
    pub radius: Option<f64>,
    /// Noise parameters (`octaves` is 1 for `cosine`).
    pub noise: CosineParams,
}

impl ProceduralSpec {
    pub fn new(kind: ProceduralKind) -> Self {
        Self {
            kind,
            density: 1.0,
            extent: 1.0,
            radius: None,
            noise: CosineParams {
                octaves: if kind == ProceduralKind::Fractal {
                    4
                } else {
                    1
                },
                ..CosineParams::default()
            },
        }
    }

    /// The same field with its density multiplied by `scale`.
    pub fn scaled(&self, scale: DensityScale) -> Self {
        Self {
            density: self.density * scale.get(),
            ..self.clone()
        }
    }

    /// The world box `[0, extent]^3`.
    pub fn world_box(&self) -> Aabb {
        Aabb::new(DVec3::ZERO, DVec3::splat(self.extent))
    }

    /// Builds the source, its density multiplied by `scale` (the description names the
    /// scaled density, as the field it is).
    pub fn build(&self, scale: DensityScale) -> Result<Box<dyn DensitySource>, SourceError> {
        if scale != DensityScale::ONE {
            return self.scaled(scale).build(DensityScale::ONE);
        }
        let err = |e: SourceError| SourceError::Procedural {
            spec: self.to_string(),
            message: match e {
                SourceError::InvalidOption(m) => m,
                other => other.to_string(),
            },
        };
        let source: Box<dyn DensitySource> = match self.kind {
            ProceduralKind::Box => {
                Box::new(HomogeneousBox::new(self.world_box(), self.density as f32).map_err(err)?)
            }
            ProceduralKind::Sphere => Box::new(
                Sphere::new(
                    DVec3::splat(0.5 * self.extent),
                    self.radius.unwrap_or(0.5 * self.extent),
                    self.density as f32,
                )
                .map_err(err)?,
            ),
            ProceduralKind::Cosine | ProceduralKind::Fractal => {
                Box::new(self.build_noise().map_err(err)?)
            }
        };
        // The placement rule of every grid (`pin_format::check_placement`): `extent=1e39`
        // overflows f32 and `extent=1e-300` is below what a query resolves.
        let b = source.bounds();
        pin_format::check_placement(
            b.min.to_array(),
            b.max.to_array(),
            &pin_format::IDENTITY_LOCAL_TO_WORLD,
        )
        .map_err(|m| SourceError::Procedural {
            spec: self.to_string(),
            message: m,
        })?;
        Ok(source)
    }

    /// Builds the cosine noise itself (for callers that need the closed form).
    pub fn build_noise(&self) -> Result<CosineNoise, SourceError> {
        let p = CosineParams {
            density: self.density,
            ..self.noise
        };
        CosineNoise::new(self.world_box(), &p, self.to_string())
    }
}

impl fmt::Display for ProceduralSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // `num`: short values as before, long ones (1e308) in scientific notation; both
        // parse back to the same f64.
        use pin_format::text::num;
        write!(
            f,
            "{}:density={},extent={}",
            self.kind.name(),
            num(self.density),
            num(self.extent)
        )?;
        let n = &self.noise;
        match self.kind {
            ProceduralKind::Box => Ok(()),
            ProceduralKind::Sphere => {
                write!(
                    f,
                    ",radius={}",
                    num(self.radius.unwrap_or(0.5 * self.extent))
                )
            }
            ProceduralKind::Cosine => {
                write!(f, ",seed={},freq={},waves={}", n.seed, num(n.freq), n.waves)
            }
            ProceduralKind::Fractal => write!(
                f,
                ",seed={},freq={},waves={},octaves={},lacunarity={},gain={}",
                n.seed,
                num(n.freq),
                n.waves,
                n.octaves,
                num(n.lacunarity),
                num(n.gain)
            ),
        }
    }
}

impl FromStr for ProceduralSpec {
    type Err = SourceError;

    fn from_str(s: &str) -> Result<Self, SourceError> {
        let fail = |m: String| SourceError::Procedural {
            spec: s.to_string(),
            message: m,
        };
        let (kind_s, params) = match s.split_once(':') {
            Some((k, p)) => (k, Some(p)),
            None => (s, None),
        };
        let kind = match kind_s.trim() {
            "box" => ProceduralKind::Box,
            "sphere" => ProceduralKind::Sphere,
            "cosine" => ProceduralKind::Cosine,
            "fractal" => ProceduralKind::Fractal,
            other => {
                return Err(fail(format!(
                    "unknown kind '{other}' (expected box, sphere, cosine or fractal)"
                )));
            }
        };
        let mut spec = ProceduralSpec::new(kind);
        let mut seen: Vec<&str> = Vec::new();
        for item in params.into_iter().flat_map(|p| p.split(',')) {
            let item = item.trim();
            if item.is_empty() {
                continue;
            }
            let (k, v) = item
                .split_once('=')
                .ok_or_else(|| fail(format!("parameter '{item}' is not key=value")))?;
            let (k, v) = (k.trim(), v.trim());
            if seen.contains(&k) {
                return Err(fail(format!("parameter '{k}' given twice")));
            }
            seen.push(k);
            let num = |v: &str| -> Result<f64, SourceError> {
                v.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| fail(format!("{k}={v}: not a finite number")))
            };
            let int = |v: &str| -> Result<u64, SourceError> {
                v.parse::<u64>()
                    .map_err(|_| fail(format!("{k}={v}: not a non-negative integer")))
            };
            let noise = matches!(kind, ProceduralKind::Cosine | ProceduralKind::Fractal);
            let fractal = kind == ProceduralKind::Fractal;
            match k {
                "density" => spec.density = num(v)?,
                "extent" => spec.extent = num(v)?,
                "radius" if kind == ProceduralKind::Sphere => spec.radius = Some(num(v)?),
                "seed" if noise => spec.noise.seed = int(v)?,
                "freq" if noise => spec.noise.freq = num(v)?,
                "waves" if noise => {
                    spec.noise.waves = u32::try_from(int(v)?).unwrap_or(u32::MAX);
                }
                "octaves" if fractal => {
                    spec.noise.octaves = u32::try_from(int(v)?).unwrap_or(u32::MAX);
                }
                "lacunarity" if fractal => spec.noise.lacunarity = num(v)?,
                "gain" if fractal => spec.noise.gain = num(v)?,
                "radius" | "seed" | "freq" | "waves" | "octaves" | "lacunarity" | "gain" => {
                    return Err(fail(format!(
                        "parameter '{k}' does not apply to {}",
                        kind.name()
                    )));
                }
                _ => return Err(fail(format!("unknown parameter '{k}'"))),
            }
        }
        // Validate now so that a bad spec fails at parse time, not at bake time.
        spec.build(DensityScale::ONE).map_err(|e| match e {
            SourceError::Procedural { message, .. } => fail(message),
            other => other,
        })?;
        Ok(spec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(spec: &str) -> CosineNoise {
        spec.parse::<ProceduralSpec>()
            .unwrap()
            .build_noise()
            .unwrap()
    }

    /// Composite 5-point Gauss-Legendre in f64 of the field along the segment (box-clipped).
    fn quadrature(n: &CosineNoise, p: DVec3, d: DVec3, t: f64, panels: usize) -> f64 {
        let Some((s0, s1)) = clip_segment(&n.bounds, p, d, t) else {
            return 0.0;
        };
        const X: [f64; 5] = [
            0.0,
            -0.538_469_310_105_683_1,
            0.538_469_310_105_683_1,
            -0.906_179_845_938_664,
            0.906_179_845_938_664,
        ];
        const W: [f64; 5] = [
            0.568_888_888_888_888_9,
            0.478_628_670_499_366_5,
            0.478_628_670_499_366_5,
            0.236_926_885_056_189_1,
            0.236_926_885_056_189_1,
        ];
        let h = (s1 - s0) / panels as f64;
        let mut acc = 0.0;
        for i in 0..panels {
            let c = s0 + (i as f64 + 0.5) * h;
            for k in 0..5 {
                acc += W[k] * 0.5 * h * n.field(p + d * (c + 0.5 * h * X[k]));
            }
        }
        acc
    }

    #[test]
    fn closed_form_matches_quadrature_including_perpendicular_directions() {
        let mut rng = SplitMix64(42);
        for spec in ["cosine:seed=7,freq=16", "fractal:seed=3,octaves=4,freq=3"] {
            let n = noise(spec);
            for i in 0..200 {
                let p = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 1.4 - 0.2;
                let mut d = DVec3::new(
                    rng.next_f64() - 0.5,
                    rng.next_f64() - 0.5,
                    rng.next_f64() - 0.5,
                )
                .normalize();
                if i % 2 == 1 {
                    // Nearly (or exactly) perpendicular to one wave vector: b = w.d -> 0.
                    let w = n.waves[i % n.waves.len()].w;
                    d = (d - w * (d.dot(w) / w.length_squared())).normalize();
                    if i % 4 == 1 {
                        d = (d + w.normalize() * 1e-9).normalize();
                    }
                }
                let t = 0.05 + 2.0 * rng.next_f64();
                let exact = n.optical_depth(p, d, t);
                let quad = quadrature(&n, p, d, t, 1000);
                let err = (exact - quad).abs() / quad.abs().max(1e-300);
                if quad == 0.0 {
                    assert_eq!(exact, 0.0);
                } else {
                    assert!(err < 1e-6, "{spec} i={i}: {exact} vs {quad} (rel {err:e})");
                }
            }
        }
    }

    #[test]
    fn naive_form_breaks_near_perpendicular() {
        let n = noise("cosine:seed=7,freq=16");
        let w = n.waves[0].w;
        let p = DVec3::splat(0.3);
        // A direction exactly perpendicular to w: b = 0 (up to rounding of the dot product).
        let mut d = DVec3::new(w.y, -w.x, 0.0).normalize();
        let exact = n.optical_depth(p, d, 0.5);
        let quad = quadrature(&n, p, d, 0.5, 4000);
        assert!((exact - quad).abs() / quad < 1e-9);
        let naive = n.optical_depth_naive(p, d, 0.5);
        let naive_err = (naive - quad).abs() / quad;
        assert!(
            !naive.is_finite() || naive_err > 1e-6,
            "naive {naive} (rel {naive_err:e}) was expected to fail at b = {}",
            w.dot(d)
        );
        // Slightly off perpendicular, the naive form loses digits to cancellation.
        // Tilt so that b = w.d is about 1e-12.
        d = (d + w * (1e-12 / w.length_squared())).normalize();
        let naive = n.optical_depth_naive(p, d, 0.5);
        let exact = n.optical_depth(p, d, 0.5);
        let quad = quadrature(&n, p, d, 0.5, 4000);
        assert!((exact - quad).abs() / quad < 1e-9);
        assert!(
            !naive.is_finite() || (naive - quad).abs() / quad > 1e-6,
            "naive {naive} vs {quad}"
        );
        // Far from perpendicular both agree.
        let d = w.normalize();
        let a = n.optical_depth(p, d, 0.5);
        let b = n.optical_depth_naive(p, d, 0.5);
        assert!((a - b).abs() / a < 1e-10);
    }

    #[test]
    fn noise_is_non_negative_bounded_and_deterministic() {
        let a = noise("fractal:seed=9,octaves=3");
        let b = noise("fractal:seed=9,octaves=3");
        let c = noise("fractal:seed=10,octaves=3");
        let mut differs = false;
        let mut rng = SplitMix64(1);
        let mut mean = 0.0;
        for _ in 0..20000 {
            let p = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
            let v = a.extinction(p);
            assert_eq!(v, b.extinction(p));
            differs |= v != c.extinction(p);
            assert!((0.0..=2.0).contains(&v));
            mean += v as f64 / 20000.0;
        }
        assert!(differs);
        assert!((mean - 1.0).abs() < 0.1, "mean {mean}");
        assert_eq!(a.extinction(DVec3::splat(1.5)), 0.0);
    }

    #[test]
    fn region_maximum_is_conservative() {
        let n = noise("cosine:seed=7,freq=16");
        let mut rng = SplitMix64(5);
        for _ in 0..300 {
            let lo = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 0.9;
            let hi = lo + DVec3::splat(0.1 * rng.next_f64());
            let bound = n.max_extinction_in(Aabb::new(lo, hi));
            for _ in 0..20 {
                let u = DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64());
                assert!(n.extinction(lo + (hi - lo) * u) <= bound);
            }
        }
        let outside = Aabb::new(DVec3::splat(2.0), DVec3::splat(3.0));
        assert_eq!(n.max_extinction_in(outside), 0.0);
    }

    #[test]
    fn batched_noise_matches_pointwise() {
        let n = noise("fractal:seed=4,octaves=4,freq=5");
        let o = DVec3::new(-0.1, 0.3, 0.2);
        let step = DVec3::new(0.004, 0.001, 0.0025);
        let mut out = vec![0f32; 300];
        n.extinction_along(o, step, 300, &mut out);
        for (i, v) in out.iter().enumerate() {
            let e = n.extinction(o + step * i as f64);
            assert!(
                (v - e).abs() <= 2.0 * f32::EPSILON * e.max(1e-6),
                "{i}: {v} vs {e}"
            );
        }
    }

    #[test]
    fn bisection_inverts_the_optical_depth() {
        let n = noise("cosine:seed=2,freq=8,density=3");
        let p = DVec3::new(0.0, 0.2, 0.3);
        let d = DVec3::new(1.0, 0.1, 0.05).normalize();
        let total = n.optical_depth(p, d, 2.0);
        let s = n
            .distance_for_optical_depth(p, d, 2.0, 0.5 * total)
            .unwrap();
        assert!((n.optical_depth(p, d, s) - 0.5 * total).abs() < 1e-9);
        assert!(
            n.distance_for_optical_depth(p, d, 2.0, total * 1.01)
                .is_none()
        );
    }

    #[test]
    fn box_and_sphere() {
        let b: ProceduralSpec = "box:density=2,extent=3".parse().unwrap();
        let s = b.build(DensityScale::ONE).unwrap();
        assert_eq!(s.extinction(DVec3::splat(1.0)), 2.0);
        assert_eq!(s.extinction(DVec3::splat(3.1)), 0.0);
        assert_eq!(s.bounds().max, DVec3::splat(3.0));
        let bx = HomogeneousBox::new(s.bounds(), 2.0).unwrap();
        assert!((bx.optical_depth(DVec3::new(-1.0, 1.0, 1.0), DVec3::X, 10.0) - 6.0).abs() < 1e-12);
        // Grazing along a face still counts (closed box); outside does not.
        assert!((bx.optical_depth(DVec3::new(-1.0, 0.0, 3.0), DVec3::X, 10.0) - 6.0).abs() < 1e-12);
        assert_eq!(
            bx.optical_depth(DVec3::new(-1.0, 0.0, 3.1), DVec3::X, 10.0),
            0.0
        );

        let sp: ProceduralSpec = "sphere:radius=0.25".parse().unwrap();
        let s = sp.build(DensityScale::ONE).unwrap();
        assert_eq!(s.extinction(DVec3::splat(0.5)), 1.0);
        assert_eq!(s.extinction(DVec3::new(0.5, 0.5, 0.76)), 0.0);
        assert_eq!(s.bounds().min, DVec3::splat(0.25));
        assert_eq!(
            s.max_extinction_in(Aabb::new(DVec3::splat(0.0), DVec3::splat(0.4))),
            1.0
        );
        assert_eq!(
            s.max_extinction_in(Aabb::new(DVec3::splat(0.0), DVec3::splat(0.2))),
            0.0
        );
        let sph = Sphere::new(DVec3::ZERO, 1.0, 1.0).unwrap();
        assert!(
            (sph.optical_depth(DVec3::new(-5.0, 0.0, 0.0), DVec3::X, 10.0) - 2.0).abs() < 1e-12
        );
    }

    #[test]
    fn spec_grammar() {
        let s: ProceduralSpec = "fractal:seed=7,octaves=4".parse().unwrap();
        assert_eq!(s.noise.seed, 7);
        assert_eq!(s.noise.octaves, 4);
        let again: ProceduralSpec = s.to_string().parse().unwrap();
        assert_eq!(again, s);
        assert_eq!("cosine".parse::<ProceduralSpec>().unwrap().noise.octaves, 1);
        for bad in [
            "cube",
            "cosine:seed=-1",
            "cosine:octaves=3",
            "box:seed=1",
            "cosine:freq=0",
            "cosine:freq=nan",
            "cosine:waves=0",
            "cosine:seed=1,seed=2",
            "cosine:bogus=1",
            "cosine:seed",
            "fractal:octaves=100",
            "box:density=-1",
            "box:density=1e300",
            "box:extent=0",
            "box:extent=1e39",
            "box:extent=1e-300",
            "sphere:radius=1e20",
            "sphere:radius=0",
        ] {
            let e = bad.parse::<ProceduralSpec>().unwrap_err().to_string();
            assert!(e.starts_with("procedural source"), "{bad}: {e}");
        }
        // Density extremes from docs/background.md section 3.
        let z: ProceduralSpec = "cosine:density=0".parse().unwrap();
        assert_eq!(
            z.build(DensityScale::ONE)
                .unwrap()
                .extinction(DVec3::splat(0.5)),
            0.0
        );
        let h: ProceduralSpec = "cosine:density=1e30".parse().unwrap();
        let v = h
            .build(DensityScale::ONE)
            .unwrap()
            .extinction(DVec3::splat(0.5));
        assert!(v.is_finite() && v >= 0.0);
    }

    #[test]
    fn sinc_is_smooth_across_the_switch() {
        for x in [0.0f64, 1e-300, 1e-8, 9.99e-4, 1e-3, 1.0001e-3, 0.5, 3.0] {
            let reference = if x == 0.0 { 1.0 } else { x.sin() / x };
            assert!((sinc(x) - reference).abs() < 1e-15, "{x}");
            assert_eq!(sinc(-x), sinc(x));
        }
    }
}
