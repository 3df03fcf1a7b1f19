//! [`EstimatorSpec`]: the one description of a renderer's transport estimator, parsed once
//! from the names the CLI uses (`rm@STEP`, `delta`, `ratio`, `residual[@CONTROL]`, `pins`,
//! `pinms`, `pinres`), shared by the CPU estimators and the GPU path tracer
//! (`gpu_render::GpuEstimator` wraps it). Research estimators extend the list from outside
//! (the `pinlab` crate) through [`TransportEstimator`].

use std::sync::Arc;

use super::baked_control::BakedResidualTracking;
use super::error::RenderError;
use super::estimator::{
    DeltaTracking, RatioTracking, RayMarching, ResidualControl, ResidualRatioTracking,
    TransportEstimator,
};
use super::majorant::MajorantGrid;
use super::pins::PinsEstimator;
use pin_volume::Density;

/// Smallest relative ray-marching step, one bound for the baker and the renderer
/// (`pin_format::MIN_REL_STEP`; smaller steps ran for minutes per pixel).
pub use pin_format::MIN_REL_STEP;

/// A transport estimator by kind and parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EstimatorSpec {
    /// Ray marching, midpoint rule, step `rel_step` (in `[1e-5, 1]`) times the longest edge of
    /// each density's box. Needs a density.
    RayMarching { rel_step: f64 },
    /// Delta tracking for both queries. Needs a density and majorants.
    DeltaTracking,
    /// Ratio tracking for transmittance, delta tracking for distances. Needs a density and
    /// majorants.
    RatioTracking,
    /// Residual ratio tracking for transmittance (a control extinction per majorant brick,
    /// exact, times ratio tracking of the residual), delta tracking for distances. Needs a
    /// density and majorants.
    ResidualRatioTracking { control: ResidualControl },
    /// The pin grid for every query. Needs pins.
    Pins,
    /// Ratio tracking for camera rays and the first vertex's shadow rays, pins after the
    /// first scattering event. Needs pins, a density and majorants.
    PinMs,
    /// Residual ratio tracking over the control the bake stores (the pin file's control
    /// section) for transmittance, delta tracking over the section's majorants for
    /// distances. Needs the bake (its control section) and a density.
    PinRes,
}

/// The names [`EstimatorSpec`] reads, for messages.
pub const ESTIMATOR_SYNTAX: &str =
    "rm@STEP, delta, ratio, residual[@min|@mean], pins, pinms, pinres";

/// The control `residual` means without `@CONTROL`.
pub const RESIDUAL_DEFAULT_CONTROL: ResidualControl = ResidualControl::Mean;

impl std::str::FromStr for EstimatorSpec {
    type Err = String;

    /// A known name; an out-of-range `rm@STEP` is an error naming the range.
    fn from_str(name: &str) -> Result<Self, String> {
        Ok(match name {
            "delta" => Self::DeltaTracking,
            "ratio" => Self::RatioTracking,
            "residual" => Self::ResidualRatioTracking {
                control: RESIDUAL_DEFAULT_CONTROL,
            },
            "residual@min" => Self::ResidualRatioTracking {
                control: ResidualControl::Min,
            },
            "residual@mean" => Self::ResidualRatioTracking {
                control: ResidualControl::Mean,
            },
            "pins" => Self::Pins,
            "pinms" => Self::PinMs,
            "pinres" => Self::PinRes,
            s => {
                let Some(step) = s.strip_prefix("rm@") else {
                    return Err(format!("unknown estimator '{s}' ({ESTIMATOR_SYNTAX})"));
                };
                let rel_step: f64 = step.parse().map_err(|e| format!("'{step}': {e}"))?;
                if !(MIN_REL_STEP..=1.0).contains(&rel_step) {
                    return Err(format!("rm@STEP: {step} must be in [1e-5, 1]"));
                }
                Self::RayMarching { rel_step }
            }
        })
    }
}

impl std::fmt::Display for EstimatorSpec {
    /// The name [`EstimatorSpec`] parses back.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Self::RayMarching { rel_step } => write!(f, "rm@{rel_step}"),
            Self::DeltaTracking => f.write_str("delta"),
            Self::RatioTracking => f.write_str("ratio"),
            Self::ResidualRatioTracking { control } if control == RESIDUAL_DEFAULT_CONTROL => {
                f.write_str("residual")
            }
            Self::ResidualRatioTracking { control } => write!(f, "residual@{}", control.name()),
            Self::Pins => f.write_str("pins"),
            Self::PinMs => f.write_str("pinms"),
            Self::PinRes => f.write_str("pinres"),
        }
    }
}

/// One row of the estimator catalogue (`pinrender estimators --json`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatorInfo {
    /// The name `--estimator` takes (`rm@STEP` stands for any step).
    pub name: &'static str,
    /// An instance of it (the default step or lookups for a parametrised family).
    pub spec: EstimatorSpec,
    /// What it does, in one line.
    pub summary: &'static str,
}

/// Every estimator the renderers run, by the name `--estimator` takes: the one list that
/// `pinrender estimators` prints and scripts read.
pub const ESTIMATORS: &[EstimatorInfo] = &[
    EstimatorInfo {
        name: "rm@STEP",
        spec: EstimatorSpec::RayMarching { rel_step: 0.015 },
        summary: "ray marching, midpoint rule, STEP of the longest box edge",
    },
    EstimatorInfo {
        name: "delta",
        spec: EstimatorSpec::DeltaTracking,
        summary: "delta tracking for transmittance and distances",
    },
    EstimatorInfo {
        name: "ratio",
        spec: EstimatorSpec::RatioTracking,
        summary: "ratio tracking for transmittance, delta tracking for distances",
    },
    EstimatorInfo {
        name: "residual",
        spec: EstimatorSpec::ResidualRatioTracking {
            control: RESIDUAL_DEFAULT_CONTROL,
        },
        summary: "residual ratio tracking: a per-brick control extinction (the brick's mean) taken out exactly",
    },
    EstimatorInfo {
        name: "residual@min",
        spec: EstimatorSpec::ResidualRatioTracking {
            control: ResidualControl::Min,
        },
        summary: "residual ratio tracking with the brick's minimum as the control",
    },
    EstimatorInfo {
        name: "pins",
        spec: EstimatorSpec::Pins,
        summary: "the pin grid for every query",
    },
    EstimatorInfo {
        name: "pinms",
        spec: EstimatorSpec::PinMs,
        summary: "ratio tracking to the first scattering vertex, pins after it",
    },
    EstimatorInfo {
        name: "pinres",
        spec: EstimatorSpec::PinRes,
        summary: "residual ratio tracking over the bake's per-brick control and residual majorant (--embed-control)",
    },
];

impl EstimatorSpec {
    /// Whether its expected value is the exact answer of the medium it reads (no bias floor):
    /// the trackers. Ray marching, `pins` and `pinms` are biased.
    pub fn is_unbiased(self) -> bool {
        matches!(
            self,
            Self::DeltaTracking
                | Self::RatioTracking
                | Self::ResidualRatioTracking { .. }
                | Self::PinRes
        )
    }

    /// Whether it reads the bake: queries pin grids, or (`pinres`) reads the pin file's
    /// control section.
    pub fn needs_pins(self) -> bool {
        matches!(self, Self::Pins | Self::PinMs | Self::PinRes)
    }

    /// Whether it reads the pin file's control section (`pinbake bake --embed-control`).
    pub fn needs_control(self) -> bool {
        self == Self::PinRes
    }

    /// Whether it reads the density (every estimator but `pins`).
    pub fn needs_density(self) -> bool {
        self != Self::Pins
    }

    /// Whether it tracks over majorants.
    pub fn needs_majorants(self) -> bool {
        !matches!(self, Self::Pins | Self::RayMarching { .. })
    }

    /// The CPU estimator over a density (`field`, with `majorants` built on demand) for every
    /// kind but the pin ones, whose grids the caller places ([`EstimatorSpec::needs_pins`]):
    /// for `pinms` this is its ratio-tracking part. `Ok(None)` for `pins` and `pinres`
    /// (which reads both: [`EstimatorSpec::build_pin_controlled`]).
    pub fn build_density_estimator<E: From<RenderError>>(
        self,
        field: &dyn Fn() -> Result<Arc<dyn Density>, E>,
        majorants: &dyn Fn() -> Result<Arc<MajorantGrid>, E>,
    ) -> Result<Option<Arc<dyn TransportEstimator>>, E> {
        Ok(Some(match self {
            Self::Pins | Self::PinRes => return Ok(None),
            Self::RayMarching { rel_step } => Arc::new(RayMarching::new(field()?, rel_step)?),
            Self::DeltaTracking => Arc::new(DeltaTracking::new(field()?, majorants()?)),
            Self::RatioTracking | Self::PinMs => {
                Arc::new(RatioTracking::new(field()?, majorants()?))
            }
            Self::ResidualRatioTracking { control } => {
                Arc::new(ResidualRatioTracking::new(field()?, majorants()?, control)?)
            }
        }))
    }

    /// The CPU estimator of a kind that reads the density and the placed pin grid together
    /// (`pinres`, from the grid's control section), or `Ok(None)` for every other kind
    /// (nothing is built then).
    pub fn build_pin_controlled<E: From<RenderError>>(
        self,
        field: &dyn Fn() -> Result<Arc<dyn Density>, E>,
        majorants: &dyn Fn() -> Result<Arc<MajorantGrid>, E>,
        pins: &dyn Fn() -> Result<Arc<PinsEstimator>, E>,
    ) -> Result<Option<Arc<dyn TransportEstimator>>, E> {
        Ok(match self {
            Self::PinRes => {
                let pins = pins()?;
                Some(Arc::new(BakedResidualTracking::from_grid(
                    field()?,
                    pins.grid(),
                    Some(pins.placement()),
                    majorants().ok(),
                )?))
            }
            _ => None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_catalogue_names_parse_to_their_specs() {
        for e in ESTIMATORS {
            if e.name == "rm@STEP" {
                assert_eq!("rm@0.015".parse::<EstimatorSpec>(), Ok(e.spec));
            } else {
                assert_eq!(e.name.parse::<EstimatorSpec>(), Ok(e.spec), "{}", e.name);
            }
            // The estimators that answer from the pins have a floor of their own besides rm.
            if matches!(e.spec, EstimatorSpec::Pins | EstimatorSpec::PinMs) {
                assert!(!e.spec.is_unbiased());
            }
        }
        assert!(
            ESTIMATORS
                .iter()
                .any(|e| e.name == "ratio" && e.spec.is_unbiased())
        );
    }

    #[test]
    fn names_round_trip_and_bad_ones_say_why() {
        for name in [
            "rm@0.015",
            "delta",
            "ratio",
            "residual",
            "residual@min",
            "pins",
            "pinms",
            "pinres",
        ] {
            let spec: EstimatorSpec = name.parse().unwrap();
            assert_eq!(spec.to_string(), name);
        }
        for (bad, why) in [
            ("rm@0", "[1e-5, 1]"),
            ("rm@x", "'x'"),
            ("urm", "unknown estimator"),
            ("tracking", "unknown estimator"),
            ("residual@max", "unknown estimator"),
        ] {
            let e = bad.parse::<EstimatorSpec>().unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
        assert!(EstimatorSpec::PinMs.needs_pins() && EstimatorSpec::PinMs.needs_density());
        assert!(!EstimatorSpec::Pins.needs_density());
        assert!(!EstimatorSpec::RayMarching { rel_step: 0.1 }.needs_majorants());
    }
}
