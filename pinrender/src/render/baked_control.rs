//! `pinres`: residual ratio tracking over the control the bake stores (the pin file's control
//! section, docs/format.md section 5.8), with the section's per-brick majorants for distances
//! and paired queries (docs/final-frames.md).

use std::sync::Arc;

use glam::Vec3;
use pinrt::PinGrid;

use super::error::RenderError;
use super::estimator::{ResidualRatioTracking, TransportEstimator};
use super::majorant::MajorantGrid;
use super::rng::Pcg32;
use pin_volume::{Aabb, Density};

/// Residual ratio tracking (Novák, Selle and Jarosz 2014) over a baked control: per brick of
/// the control grid, the control extinction `c` is taken out exactly and the residual
/// `sigma - c` is ratio-tracked at the baked residual majorant `m`. Distances are delta
/// tracking over the baked majorants `M`; paired queries are ratio tracking's one walk over
/// them (as `residual`'s, docs/residual.md "Distances").
///
/// Unbiased for any control and any `m > 0` (the weights `1 - (sigma - c) / m` may be
/// negative or above 1); a brick with `m = 0` is one the bake bounded by zero, where `sigma =
/// c = 0`. The relative variance of a transmittance estimate is `exp(int (sigma - c)^2 / m) -
/// 1` at `int m` lookups: the baker chooses `c` and `m` per brick to balance the two.
pub struct BakedResidualTracking {
    inner: ResidualRatioTracking<dyn Density>,
    dims: [u32; 3],
}

impl BakedResidualTracking {
    /// Over `field`, with the bricks `dims` tiling the world box `[lo, hi]` and their
    /// control, residual majorant and majorant (each finite and `>= 0`). Distances and
    /// paired queries track the baked majorants, or `other` (the renderer's own grid over
    /// the same medium) where [`walk_cost`] says that walk is cheaper.
    pub fn new(
        field: Arc<dyn Density>,
        (lo, hi): ([f64; 3], [f64; 3]),
        dims: [u32; 3],
        control: Vec<f32>,
        residual: Vec<f32>,
        majorant: Vec<f32>,
        other: Option<Arc<MajorantGrid>>,
    ) -> Result<Self, RenderError> {
        let baked = Arc::new(MajorantGrid::from_parts(lo, hi, dims, majorant)?);
        let residual = MajorantGrid::from_parts(lo, hi, dims, residual)?;
        let majorants = match other {
            Some(m) if walk_cost(&m) < walk_cost(&baked) => m,
            _ => baked,
        };
        let inner = ResidualRatioTracking::with_residual_grid(field, majorants, residual, control)?;
        Ok(Self { inner, dims })
    }

    /// Over `field`, from the control section of `grid` placed by `local_to_world` (the
    /// file's own when `None`): a positive scale and a translation per axis, as the
    /// renderer's fields are axis-aligned; `other` as in [`Self::new`]. Where `field` bounds
    /// itself ([`Density::max_extinction_in`]), a brick's majorant is raised to that bound
    /// and an empty brick where the field is not 0 gets a residual majorant, so that a field
    /// other than the baked one (the file's f16 copy) is still tracked without bias. An error
    /// when the grid has no control section.
    pub fn from_grid(
        field: Arc<dyn Density>,
        grid: &PinGrid,
        local_to_world: Option<&[f64; 12]>,
        other: Option<Arc<MajorantGrid>>,
    ) -> Result<Self, RenderError> {
        let invalid = |why: String| RenderError::Invalid {
            what: "pinres control",
            why,
        };
        let control = grid
            .control()
            .map_err(|e| invalid(e.to_string()))?
            .ok_or_else(|| {
                let file = grid
                    .path()
                    .map_or_else(|| "the pin grid".to_string(), |p| p.display().to_string());
                invalid(format!(
                    "{file} has no control section (bake it with --embed-control)"
                ))
            })?;
        let m = *local_to_world.unwrap_or(&grid.desc().local_to_world);
        let scale = [m[0], m[5], m[10]];
        let off_diagonal = [m[1], m[2], m[4], m[6], m[8], m[9]];
        if !(off_diagonal.iter().all(|&v| v == 0.0)
            && scale.iter().all(|&v| v > 0.0 && v.is_finite()))
        {
            return Err(invalid(
                "the grid is rotated or sheared in the world; its control is axis-aligned".into(),
            ));
        }
        let (blo, bhi) = control.bounds();
        let to_world = |p: [f64; 3]| [0, 1, 2].map(|a| scale[a] * p[a] + m[4 * a + 3]);
        let (lo, hi) = (to_world(blo), to_world(bhi));
        let dims = control.dims();
        let mut residual = control.residual().to_vec();
        let mut majorant = control.majorant().to_vec();
        // The section bounds the field the bake saw; the renderer may track another (the
        // file's f16 copy, whose rounding and resampling reach a little past it). Where the
        // field bounds itself, each brick's majorant is raised to that bound (delta tracking
        // needs one), and an empty brick (`m = 0`, skipped by the walk) where the field is
        // not 0 gets `m` = that bound, so that the walk is unbiased for the field it reads.
        let size = [0, 1, 2].map(|a| (hi[a] - lo[a]) / f64::from(dims[a]));
        let mut k = 0;
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let i = [x, y, z];
                    let blo = [0, 1, 2].map(|a| lo[a] + size[a] * f64::from(i[a]));
                    let bhi = [0, 1, 2].map(|a| lo[a] + size[a] * f64::from(i[a] + 1));
                    let e = field.max_extinction_in(Aabb::from_arrays(blo, bhi));
                    // A field without a bound (infinite) raises nothing.
                    if e.is_finite() {
                        let e = if e > 0.0 { e.min(f32::MAX) } else { 0.0 };
                        majorant[k] = majorant[k].max(e);
                        if residual[k] == 0.0 && e > 0.0 {
                            residual[k] = e;
                        }
                    }
                    k += 1;
                }
            }
        }
        Self::new(
            field,
            (lo, hi),
            dims,
            control.control().to_vec(),
            residual,
            majorant,
            other,
        )
    }

    /// The controls and residual majorants per brick.
    pub fn controls(&self) -> (&[f32], &[f32]) {
        self.inner.controls()
    }

    /// The residual ratio tracking it runs (the statistical tests walk it directly; the GPU
    /// path tracer uploads its grids).
    pub fn tracking(&self) -> &ResidualRatioTracking<dyn Density> {
        &self.inner
    }
}

/// What one DDA step costs, in density lookups (measured with `pinrender bench`: about 5 ns
/// a step against 10 to 20 ns a trilinear lookup).
const DDA_STEP_LOOKUPS: f64 = 0.4;

/// The expected cost of a tracking walk per unit of length through `grid`'s box, in lookups,
/// for isotropic directions: DDA steps (half the bricks per unit length, summed over the
/// axes) at [`DDA_STEP_LOOKUPS`] each, plus the mean majorant (tentative collisions). A fine
/// grid tracks fewer tentative collisions where the medium is sparse and pays more steps
/// where it is smooth.
fn walk_cost(grid: &MajorantGrid) -> f64 {
    let (lo, hi) = grid.bounds();
    let dims = grid.dims();
    let steps: f64 = (0..3)
        .map(|a| 0.5 * f64::from(dims[a]) / (hi[a] - lo[a]))
        .sum();
    let v = grid.values();
    let mean = v.iter().map(|&m| f64::from(m)).sum::<f64>() / v.len().max(1) as f64;
    DDA_STEP_LOOKUPS * steps + mean
}

impl TransportEstimator for BakedResidualTracking {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        self.inner.sample_distance(o, d, t_max, rng)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        self.inner.transmittance(o, d, t_max, rng)
    }
    fn transmittance_and_distance(
        &self,
        o: Vec3,
        d: Vec3,
        t_max: f32,
        rng: &mut Pcg32,
    ) -> (f32, Option<f32>) {
        self.inner.transmittance_and_distance(o, d, t_max, rng)
    }
    fn name(&self) -> String {
        let d = self.dims;
        format!("pinres({}x{}x{})", d[0], d[1], d[2])
    }
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        self.inner.bounds()
    }
}
