//! [`Estimator`]: every estimator the `pinrender` binary names, the renderer's own
//! ([`EstimatorSpec`]) and the lab's (`urm[@N]`, `jackknife[@N]`, `pinurm[@N]`), parsed once
//! from the names of `--estimator` and the evaluation, and the one catalogue that
//! `pinrender estimators` prints ([`ESTIMATORS`]).

use std::sync::Arc;

use pinrender::gpu_render::{GpuEstimator, ShaderKernel};
use pinrender::medium::MediumDesc;
use pinrender::render::{EstimatorSpec, Medium, RenderError, RenderPlan, SampleLoop};
use pinrt::SamplerOptions;

use crate::comb::MAX_COMB_LOOKUPS;
use crate::comb_estimators::{CombKind, JACKKNIFE_DEFAULT_LOOKUPS, URM_DEFAULT_LOOKUPS};
use crate::pin_control::{PINURM_DEFAULT_LOOKUPS, PinControlledUrm};

/// The shader's codes of the comb kernels (`RT_EST_URM`, `RT_EST_JACKKNIFE` of
/// `shaders/render.wgsl`).
const SHADER_URM: u32 = 4;
const SHADER_JACKKNIFE: u32 = 5;
/// The GPU kernels of `urm` and `jackknife`, for the path tracer's extension region.
pub const COMBS_WGSL: &str = include_str!("../../shaders/lab_combs.wgsl");

/// A transport estimator by kind and parameters: the renderer's, or one of the lab's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Estimator {
    /// One of the renderer's estimators.
    Core(EstimatorSpec),
    /// Unbiased ray marching (combs of `lookups` per longest edge of the majorant box) for
    /// transmittance, delta tracking for distances. Needs a density and majorants.
    Urm { lookups: u32 },
    /// Jackknife transmittance (two combs of `lookups` per longest edge of the majorant
    /// box), delta tracking for distances. Needs a density and majorants.
    Jackknife { lookups: u32 },
    /// Unbiased ray marching around the pin's answer (the pin gives the control optical
    /// depth, combs of `lookups` per longest edge of the majorant box correct it) for
    /// transmittance, delta tracking for distances. Needs pins, a density and majorants.
    /// CPU only.
    PinUrm { lookups: u32 },
}

/// The names [`Estimator`] reads, for messages.
pub const ESTIMATOR_SYNTAX: &str = "rm@STEP, delta, ratio, residual[@min|@mean], urm[@N], jackknife[@N], pins, pinms, pinurm[@N], pinres";

impl From<EstimatorSpec> for Estimator {
    fn from(spec: EstimatorSpec) -> Self {
        Estimator::Core(spec)
    }
}

impl std::str::FromStr for Estimator {
    type Err = String;

    /// A known name; an out-of-range `rm@STEP` or comb count is an error naming the range.
    fn from_str(name: &str) -> Result<Self, String> {
        if let Some(arg) = name.strip_prefix("pinurm") {
            let lookups = match arg.strip_prefix('@') {
                None if arg.is_empty() => PINURM_DEFAULT_LOOKUPS,
                None => return Err(format!("unknown estimator '{name}' ({ESTIMATOR_SYNTAX})")),
                Some(a) => match a.parse::<u32>() {
                    Ok(n) if (1..=MAX_COMB_LOOKUPS as u32).contains(&n) => n,
                    _ => {
                        return Err(format!(
                            "estimator {name}: lookups must be an integer in 1..={MAX_COMB_LOOKUPS}"
                        ));
                    }
                },
            };
            return Ok(Self::PinUrm { lookups });
        }
        if let Some(parsed) = CombKind::parse(name) {
            return Ok(match parsed? {
                (CombKind::Urm, lookups) => Self::Urm { lookups },
                (CombKind::Jackknife, lookups) => Self::Jackknife { lookups },
            });
        }
        match name.parse::<EstimatorSpec>() {
            Ok(spec) => Ok(Self::Core(spec)),
            Err(why) if why.starts_with("unknown estimator") => {
                Err(format!("unknown estimator '{name}' ({ESTIMATOR_SYNTAX})"))
            }
            Err(why) => Err(why),
        }
    }
}

impl std::fmt::Display for Estimator {
    /// The name [`Estimator`] parses back (a comb's default count is the bare name, as the
    /// evaluation's rows spell it).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Self::Core(spec) => spec.fmt(f),
            Self::Urm { lookups } if lookups == URM_DEFAULT_LOOKUPS => f.write_str("urm"),
            Self::Jackknife { lookups } if lookups == JACKKNIFE_DEFAULT_LOOKUPS => {
                f.write_str("jackknife")
            }
            Self::Urm { lookups } => write!(f, "urm@{lookups}"),
            Self::Jackknife { lookups } => write!(f, "jackknife@{lookups}"),
            Self::PinUrm { lookups } if lookups == PINURM_DEFAULT_LOOKUPS => f.write_str("pinurm"),
            Self::PinUrm { lookups } => write!(f, "pinurm@{lookups}"),
        }
    }
}

impl Estimator {
    /// The renderer's estimator, if it is one.
    pub fn core(self) -> Option<EstimatorSpec> {
        match self {
            Self::Core(spec) => Some(spec),
            _ => None,
        }
    }

    /// Whether its expected value is the exact answer of the medium it reads: the
    /// renderer's trackers, unbiased ray marching and `pinurm` (which reads the pins only for
    /// its control). The jackknife is biased by its combs' departure from normality.
    pub fn is_unbiased(self) -> bool {
        match self {
            Self::Core(spec) => spec.is_unbiased(),
            Self::Urm { .. } | Self::PinUrm { .. } => true,
            Self::Jackknife { .. } => false,
        }
    }

    /// Whether it reads the bake (pin grids, or the pin file's control section).
    pub fn needs_pins(self) -> bool {
        self.plan().reads_bake
    }

    /// Whether it tracks over majorants.
    pub fn needs_majorants(self) -> bool {
        self.plan().majorants
    }

    /// What a render with it loads and which CPU sample loop runs it: the renderer's plan, or
    /// for the lab's estimators the path loop over the density and majorants (`pinurm` also
    /// queries the pins, one query at a time).
    pub fn plan(self) -> RenderPlan {
        match self {
            Self::Core(spec) => spec.plan(),
            Self::Urm { .. } | Self::Jackknife { .. } | Self::PinUrm { .. } => {
                let pins = matches!(self, Self::PinUrm { .. });
                RenderPlan {
                    reads_bake: pins,
                    queries_pins: pins,
                    control: false,
                    density: true,
                    majorants: true,
                    sample_loop: SampleLoop::Paths,
                }
            }
        }
    }

    /// The GPU path tracer's estimator, or `None` where it has none (`pinurm`).
    pub fn gpu(self) -> Option<GpuEstimator> {
        let kernel = |code, lookups: u32, name| {
            Some(GpuEstimator::Kernel(ShaderKernel {
                code,
                rel_step: 1.0 / lookups.max(1) as f64,
                name,
                wgsl: COMBS_WGSL,
            }))
        };
        match self {
            Self::Core(spec) => Some(spec.into()),
            Self::Urm { lookups } => kernel(SHADER_URM, lookups, "urm"),
            Self::Jackknife { lookups } => kernel(SHADER_JACKKNIFE, lookups, "jackknife"),
            Self::PinUrm { .. } => None,
        }
    }

    /// Whether the GPU path tracer runs it (all but `pinurm`).
    pub fn runs_on_gpu(self) -> bool {
        self.gpu().is_some()
    }

    /// The GPU estimator, or the error a GPU render of a CPU-only estimator gives.
    pub fn gpu_or_err(self) -> Result<GpuEstimator, RenderError> {
        self.gpu().ok_or_else(|| RenderError::Invalid {
            what: "estimator",
            why: format!("{self} runs on the CPU path tracer only (--backend cpu)"),
        })
    }

    /// The CPU renderer's medium for this estimator over `desc` (its density, majorants and
    /// pins), with pin lookup options `lookup`.
    pub fn cpu_medium(
        self,
        desc: &MediumDesc,
        lookup: SamplerOptions,
    ) -> Result<Medium, RenderError> {
        // The lab's estimators are built in the description's frame and placed as the
        // renderer's own are (`MediumDesc::place`).
        let local = match self {
            Self::Core(spec) => return desc.cpu_medium(spec, lookup),
            Self::Urm { lookups } => {
                Medium::single(CombKind::Urm.build(desc.field()?, desc.majorants()?, lookups)?)
            }
            Self::Jackknife { lookups } => Medium::single(CombKind::Jackknife.build(
                desc.field()?,
                desc.majorants()?,
                lookups,
            )?),
            Self::PinUrm { lookups } => Medium::single(Arc::new(PinControlledUrm::new(
                desc.field()?,
                desc.majorants()?,
                desc.placed_pins(lookup)?,
                lookups,
            )?)),
        };
        desc.place(local, lookup)
    }
}

/// One row of the estimator catalogue (`pinrender estimators --json`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatorInfo {
    /// The name `--estimator` takes (`rm@STEP` stands for any step).
    pub name: &'static str,
    /// An instance of it (the default step or lookups for a parametrised family).
    pub estimator: Estimator,
    /// What it does, in one line.
    pub summary: &'static str,
}

/// The lab's rows of the catalogue, each placed before the renderer's row it follows.
const LAB_ROWS: [(&str, EstimatorInfo); 3] = [
    (
        "pins",
        EstimatorInfo {
            name: "urm",
            estimator: Estimator::Urm {
                lookups: URM_DEFAULT_LOOKUPS,
            },
            summary: "unbiased ray marching (power-series correction of jittered combs)",
        },
    ),
    (
        "pins",
        EstimatorInfo {
            name: "jackknife",
            estimator: Estimator::Jackknife {
                lookups: JACKKNIFE_DEFAULT_LOOKUPS,
            },
            summary: "jackknife transmittance from two combs (biased by the combs' departure from normality)",
        },
    ),
    (
        "pinres",
        EstimatorInfo {
            name: "pinurm",
            estimator: Estimator::PinUrm {
                lookups: PINURM_DEFAULT_LOOKUPS,
            },
            summary: "unbiased ray marching around the pins' answer: their optical depth as the control, combs correct it",
        },
    ),
];

/// Every estimator the `pinrender` binary runs, by the name `--estimator` takes: the
/// renderer's catalogue ([`pinrender::render::ESTIMATORS`]) with the lab's rows among them.
pub fn estimators() -> Vec<EstimatorInfo> {
    let mut out = Vec::new();
    for e in pinrender::render::ESTIMATORS {
        out.extend(
            LAB_ROWS
                .iter()
                .filter(|(before, _)| *before == e.name)
                .map(|(_, row)| *row),
        );
        out.push(EstimatorInfo {
            name: e.name,
            estimator: Estimator::Core(e.spec),
            summary: e.summary,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every catalogue name parses to its row, prints back, and the lab's rows keep their
    /// places (the order `pinrender estimators` has always printed).
    #[test]
    fn the_catalogue_names_parse_and_keep_their_order() {
        let rows = estimators();
        let names: Vec<&str> = rows.iter().map(|e| e.name).collect();
        assert_eq!(
            names,
            [
                "rm@STEP",
                "delta",
                "ratio",
                "residual",
                "residual@min",
                "urm",
                "jackknife",
                "pins",
                "pinms",
                "pinurm",
                "pinres"
            ]
        );
        for e in &rows {
            let name = if e.name == "rm@STEP" {
                "rm@0.015"
            } else {
                e.name
            };
            assert_eq!(name.parse::<Estimator>(), Ok(e.estimator), "{name}");
            assert_eq!(e.estimator.to_string(), name);
        }
        let pinurm: Estimator = "pinurm".parse().unwrap();
        assert!(pinurm.is_unbiased() && pinurm.needs_pins() && pinurm.needs_majorants());
        assert!(!pinurm.runs_on_gpu());
        assert!(Estimator::Urm { lookups: 8 }.runs_on_gpu());
    }

    #[test]
    fn names_round_trip_and_bad_ones_say_why() {
        for name in ["urm@8", "jackknife@3", "pinurm@4", "residual@min", "pinres"] {
            let e: Estimator = name.parse().unwrap();
            assert_eq!(e.to_string(), name);
        }
        for (bad, why) in [
            ("rm@0", "[1e-5, 1]"),
            ("urm@0", "lookups"),
            ("tracking", "unknown estimator 'tracking' (rm@STEP"),
            ("pinurm@0", "lookups"),
            ("pinurmx", "unknown estimator"),
        ] {
            let e = bad.parse::<Estimator>().unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
    }
}
