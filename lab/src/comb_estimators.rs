//! The comb estimators in the path tracer: unbiased ray marching (`urm`) and the jackknife
//! (`jackknife`) for transmittance over the comb math of [`crate::comb`], delta tracking over
//! the majorant grid for distances; [`CombKind`] names them for the command lines.

use std::sync::Arc;

use glam::Vec3;
use pinrender::render::{
    Density, MajorantGrid, Pcg32, PreparedRay, RatioTracking, RenderError, TransportEstimator,
    clean, clip_box, prepare,
};

use crate::comb::{MAX_COMB_LOOKUPS, jackknife_transmittance, lookups_for, urm_transmittance};

/// Default comb lookups per longest edge of the majorant box for `urm` (each query takes
/// about 3.42 combs: the control, two always-taken orders and the roulette's 1/3 + 1/12 + ...).
/// Dense media get more: see [`lookups_for`].
pub const URM_DEFAULT_LOOKUPS: u32 = 16;
/// Default comb lookups per longest edge for `jackknife` (two combs per query).
pub const JACKKNIFE_DEFAULT_LOOKUPS: u32 = 32;

/// Shared state of the comb estimators: the field and its majorants, the renderer's tracking
/// over them (delta tracking for distances; ratio tracking's walk where a query pairs both),
/// and the comb spacing `longest edge of the majorant box / lookups`.
pub(crate) struct Combed<F: ?Sized> {
    pub(crate) field: Arc<F>,
    pub(crate) majorants: Arc<MajorantGrid>,
    pub(crate) tracking: RatioTracking<F>,
    pub(crate) lookups: u32,
    pub(crate) spacing: f64,
}

impl<F: Density + ?Sized> Combed<F> {
    pub(crate) fn new(
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        lookups: u32,
    ) -> Result<Self, RenderError> {
        if !(1..=MAX_COMB_LOOKUPS as u32).contains(&lookups) {
            return Err(RenderError::Invalid {
                what: "comb lookups",
                why: format!("{lookups} lookups per edge must be in 1..={MAX_COMB_LOOKUPS}"),
            });
        }
        let (lo, hi) = majorants.bounds();
        let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        Ok(Combed {
            tracking: RatioTracking::new(field.clone(), majorants.clone()),
            field,
            majorants,
            lookups,
            spacing: longest / lookups as f64,
        })
    }

    /// The majorant grid's dimensions, as the estimators' names show them.
    pub(crate) fn dims_label(&self) -> String {
        let d = self.majorants.dims();
        format!("{}x{}x{}", d[0], d[1], d[2])
    }

    /// The majorant optical depth along the prepared ray (the combs' lookup rule reads it).
    pub(crate) fn majorant_depth(&self, r: &PreparedRay) -> f64 {
        self.majorants
            .segments(r.o, r.d, 0.0, r.t_max)
            .map(|seg| seg.majorant as f64 * (seg.t1 - seg.t0).max(0.0))
            .sum()
    }

    /// Transmittance over the ray's segment inside the majorant box (the combs span the
    /// clipped segment; the field is 0 outside that box): `urm` or, with `jackknife`, the
    /// jackknife. Static dispatch: the density lookup is the hot loop.
    #[inline]
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32, jackknife: bool) -> f32 {
        let Some(r) = prepare(o, d, t_max) else {
            return 1.0;
        };
        let (lo, hi) = self.majorants.bounds();
        let Some((t0, t1)) = clip_box(r.o, r.d, &lo, &hi, 0.0, r.t_max) else {
            return 1.0;
        };
        let len = t1 - t0;
        let maj_depth = self.majorant_depth(&r);
        let m = lookups_for(len, self.spacing, maj_depth);
        let field = &self.field;
        let mut sigma = |s: f64| clean(field.extinction(r.at(t0 + s).as_dvec3()));
        let mut uniform = || rng.next_f64();
        let t = if jackknife {
            jackknife_transmittance(len, m, &mut sigma, &mut uniform)
        } else {
            urm_transmittance(len, m, &mut sigma, &mut uniform)
        };
        t as f32
    }
}

/// Unbiased ray marching (Kettunen et al. 2021) for transmittance, delta tracking for
/// distances; see [`urm_transmittance`].
pub struct UnbiasedRayMarching<F: ?Sized = dyn Density>(Combed<F>);

/// Jackknife transmittance (Peters 2025) for transmittance, delta tracking for distances;
/// see [`jackknife_transmittance`].
pub struct JackknifeMarching<F: ?Sized = dyn Density>(Combed<F>);

impl<F: Density + ?Sized> UnbiasedRayMarching<F> {
    /// Combs of `lookups` per longest edge of the majorant box (`1 ..= 2^20`); the majorant
    /// grid bounds the combs and the tracking and should cover the field's support.
    pub fn new(
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        lookups: u32,
    ) -> Result<Self, RenderError> {
        Combed::new(field, majorants, lookups).map(UnbiasedRayMarching)
    }
}

impl<F: Density + ?Sized> JackknifeMarching<F> {
    /// As [`UnbiasedRayMarching::new`]; each query takes two combs.
    pub fn new(
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        lookups: u32,
    ) -> Result<Self, RenderError> {
        Combed::new(field, majorants, lookups).map(JackknifeMarching)
    }
}

impl<F: Density + ?Sized> TransportEstimator for UnbiasedRayMarching<F> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        self.0.tracking.sample_distance(o, d, t_max, rng)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        self.0.transmittance(o, d, t_max, rng, false)
    }
    fn name(&self) -> String {
        format!("urm@{}({})", self.0.lookups, self.0.dims_label())
    }
    /// The majorant grid's box: combs and tracking are clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some(self.0.majorants.bounds())
    }
}

impl<F: Density + ?Sized> TransportEstimator for JackknifeMarching<F> {
    fn sample_distance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> Option<f32> {
        self.0.tracking.sample_distance(o, d, t_max, rng)
    }
    fn transmittance(&self, o: Vec3, d: Vec3, t_max: f32, rng: &mut Pcg32) -> f32 {
        self.0.transmittance(o, d, t_max, rng, true)
    }
    fn name(&self) -> String {
        format!("jackknife@{}({})", self.0.lookups, self.0.dims_label())
    }
    /// The majorant grid's box: combs and tracking are clipped to it.
    fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        Some(self.0.majorants.bounds())
    }
}

/// The two comb estimators by name, for the command lines: `urm`, `urm@LOOKUPS`,
/// `jackknife`, `jackknife@LOOKUPS` (lookups per longest edge of the majorant box, per comb).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CombKind {
    Urm,
    Jackknife,
}

impl CombKind {
    /// `None` if `name` is not a comb estimator's name; an error message if it is one with a
    /// bad lookup count.
    pub fn parse(name: &str) -> Option<Result<(CombKind, u32), String>> {
        let (base, arg) = match name.split_once('@') {
            Some((b, a)) => (b, Some(a)),
            None => (name, None),
        };
        let kind = match base {
            "urm" => CombKind::Urm,
            "jackknife" => CombKind::Jackknife,
            _ => return None,
        };
        let lookups = match arg {
            None => Ok(kind.default_lookups()),
            Some(a) => match a.parse::<u32>() {
                Ok(n) if (1..=MAX_COMB_LOOKUPS as u32).contains(&n) => Ok(n),
                _ => Err(format!(
                    "estimator {name}: lookups must be an integer in 1..={MAX_COMB_LOOKUPS}"
                )),
            },
        };
        Some(lookups.map(|n| (kind, n)))
    }

    pub fn default_lookups(self) -> u32 {
        match self {
            CombKind::Urm => URM_DEFAULT_LOOKUPS,
            CombKind::Jackknife => JACKKNIFE_DEFAULT_LOOKUPS,
        }
    }

    /// The estimator over `field` with combs and delta tracking over `majorants`.
    pub fn build<F: Density + ?Sized + 'static>(
        self,
        field: Arc<F>,
        majorants: Arc<MajorantGrid>,
        lookups: u32,
    ) -> Result<Arc<dyn TransportEstimator>, RenderError> {
        Ok(match self {
            CombKind::Urm => Arc::new(UnbiasedRayMarching::new(field, majorants, lookups)?),
            CombKind::Jackknife => Arc::new(JackknifeMarching::new(field, majorants, lookups)?),
        })
    }
}
