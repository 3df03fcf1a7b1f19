//! Which estimators an input answers, and which one renders when none is asked for: one
//! rule for `pinrender render`, `pinrender render --scene` and the viewer's menu, fed from
//! the renderer's catalogue ([`crate::render::ESTIMATORS`]).
//!
//! The lab's estimators (`urm`, `jackknife`, `pinurm`) are rows of the lab's catalogue
//! (`pinlab::estimators`), which extends this crate; the viewer links this crate and not the
//! lab, so its menu is this catalogue, and `pinrender render` checks a lab estimator's needs
//! where it builds it.

use crate::render::{EstimatorInfo, EstimatorSpec};

/// What an input holds, as far as the estimators care: pins (a pin file, or a volume's pins
/// baked), a density (a volume, or a pin file's embedded one), whether that density is the
/// source volume itself (`volume`; false for a pin file's embedded density), and the pins'
/// control section (`pinbake bake --embed-control`, or the in-memory bake that stores it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Holds {
    pub pins: bool,
    pub density: bool,
    pub volume: bool,
    pub control: bool,
}

impl Holds {
    /// Whether an input holding this answers `e`.
    pub fn answers(self, e: EstimatorSpec) -> bool {
        (!e.needs_pins() || self.pins)
            && (!e.needs_density() || self.density)
            && (!e.needs_control() || self.control)
    }

    /// What every one of several inputs holds (a scene's assets).
    pub fn all(items: impl IntoIterator<Item = Holds>) -> Holds {
        items.into_iter().fold(
            Holds {
                pins: true,
                density: true,
                volume: true,
                control: true,
            },
            |a, b| Holds {
                pins: a.pins && b.pins,
                density: a.density && b.density,
                volume: a.volume && b.volume,
                control: a.control && b.control,
            },
        )
    }
}

/// The estimators of `catalogue` that an input holding `holds` answers, in catalogue order.
pub fn available(holds: Holds, catalogue: &[EstimatorInfo]) -> Vec<EstimatorSpec> {
    catalogue
        .iter()
        .map(|e| e.spec)
        .filter(|&e| holds.answers(e))
        .collect()
}

/// The estimator when none is asked for, the best image for what the input holds: for a pin
/// file that embeds its density (what a bake with no flags writes), ratio tracking of that
/// density, then pins; otherwise the first of PinMS (pins for the scattered rays, tracking
/// of the source volume where it is cheap), pins, ratio tracking; each the first that
/// `catalogue` has and `holds` answers (ratio tracking when none is). PinMS through the
/// default asset's small pin grid measured 3.1% to 6.8% 8x8-block error where ratio tracking
/// of the same file reached 0.46% to 0.94% (docs/scale.md, "The default asset"). At equal
/// CPU time (`pinrender eval --default-asset`, docs/evaluation.md) ratio tracking of a default
/// file has the lowest RMSE at 1 s; at 0.1 s pins alone's is lower, from samples alone, at 4-6x
/// the block error; beside a volume PinMS is at or below ratio tracking at 0.1 and 1 s through
/// the pins a bake for pins chooses, and above it at 1 s through a default file's small pin
/// grid (docs/decisions.md, R7).
pub fn default_estimator(holds: Holds, catalogue: &[EstimatorInfo]) -> EstimatorSpec {
    const SOURCE: [EstimatorSpec; 3] = [
        EstimatorSpec::PinMs,
        EstimatorSpec::Pins,
        EstimatorSpec::RatioTracking,
    ];
    const EMBEDDED: [EstimatorSpec; 3] = [
        EstimatorSpec::RatioTracking,
        EstimatorSpec::Pins,
        EstimatorSpec::RatioTracking,
    ];
    let preference = if holds.density && !holds.volume {
        EMBEDDED
    } else {
        SOURCE
    };
    preference
        .into_iter()
        .find(|&e| holds.answers(e) && catalogue.iter().any(|c| c.spec == e))
        .unwrap_or(EstimatorSpec::RatioTracking)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::ESTIMATORS;

    /// A volume's holdings (its density is the source), with or without pins.
    const fn holds(pins: bool, density: bool, control: bool) -> Holds {
        Holds {
            pins,
            density,
            volume: density,
            control,
        }
    }

    /// A pin file's holdings: an embedded density is not the source volume.
    const fn file(density: bool) -> Holds {
        Holds {
            pins: true,
            density,
            volume: false,
            control: false,
        }
    }

    #[test]
    fn the_default_follows_what_the_input_holds() {
        let d = |h| default_estimator(h, ESTIMATORS);
        assert_eq!(d(holds(true, true, false)), EstimatorSpec::PinMs);
        assert_eq!(d(holds(true, false, false)), EstimatorSpec::Pins);
        assert_eq!(d(holds(false, true, false)), EstimatorSpec::RatioTracking);
        assert_eq!(d(holds(false, false, false)), EstimatorSpec::RatioTracking);
        // A pin file: ratio tracking of its embedded density, pins when it holds nothing else.
        assert_eq!(d(file(true)), EstimatorSpec::RatioTracking);
        assert_eq!(d(file(false)), EstimatorSpec::Pins);
    }

    #[test]
    fn what_is_offered_is_what_the_input_answers() {
        let all = available(holds(true, true, true), ESTIMATORS);
        assert_eq!(all.len(), ESTIMATORS.len());
        assert_eq!(
            available(holds(true, false, false), ESTIMATORS),
            [EstimatorSpec::Pins]
        );
        let volume = available(holds(false, true, false), ESTIMATORS);
        assert!(volume.iter().all(|e| !e.needs_pins()), "{volume:?}");
        assert!(volume.contains(&EstimatorSpec::RatioTracking));
        let no_control = available(holds(true, true, false), ESTIMATORS);
        assert!(!no_control.contains(&EstimatorSpec::PinRes));
        assert!(no_control.contains(&EstimatorSpec::PinMs));
        // A scene answers what every asset answers.
        let scene = Holds::all([holds(true, true, true), holds(true, false, false)]);
        assert_eq!(scene, holds(true, false, false));
    }
}
