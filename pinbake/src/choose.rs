//! Choosing a bake for a volume: spatial cells, direction cells and pins per
//! entry from what the volume holds, so that a user who names none of them gets a bake sized
//! to the volume instead of one fixed size for every volume.
//!
//! Three steps, each in this module:
//! 1. [`analyse`] measures the volume over the bake box: how many voxels it spans per axis
//!    (never more cells than that) and the **model variation** `s`, what a pin looked up for
//!    a nearby ray gets wrong. The volume is projected along each axis into a map of line
//!    transmittances `exp(-tau)` over a probe grid; a pixel's local variation is its absolute
//!    transmittance difference to its neighbours per unit of sideways offset, times the
//!    longest box edge. `s` is the sum of two averages over the three axes: the mean local
//!    variation `g` (transmittance 1 outside the box, so a hard silhouette counts) and the
//!    root mean square of the local variation between pixels inside the box, which weights the
//!    few large differences of a sparse sharp feature (a thin hard-edged tube, a peak) that the
//!    mean dilutes. Line integrals, not densities: detail finer than a line's length averages
//!    out along it, and a line that is opaque either way cannot be wrong by much. Other
//!    statistics are reported beside it (optical depths, the density itself); they, the mean
//!    alone, and percentiles, maxima and RMS that include the box's silhouette fitted the
//!    sweep worse (docs/evaluation.md).
//! 2. [`predicted_error`] is the bias model fitted to `scripts/bias_sweep.sh`'s measurements
//!    (`docs/evaluation.md`, "Bias against bytes"; the fit data is `docs/eval/bias_sweep.csv`
//!    and a test refits it): the 8x8-block RMS error of a pins-only render is
//!    `A * s^P * sqrt(h^2 + (K * theta)^2)`, with `h` the cell edge over the longest box edge
//!    and `theta` the angular size of a direction cell, `sqrt(2 pi / directions)` radians: the
//!    spatial and the directional lookup errors add in quadrature (independent offsets), each
//!    in proportion to its cell size.
//! 3. [`choose`] takes the smallest bake (in predicted bytes) whose predicted error is at most
//!    the target, among octahedral direction sets (the measured best kind, docs/evaluation.md)
//!    and cells no finer than the voxels; parameters the user gave are held fixed.
//!    [`choose_default`] (what `pinbake bake` does for pins alone without `--target-error`:
//!    with a grid parameter named, or for a source with no lattice for the default asset of
//!    [`crate::default_asset`]) searches only at or above a floor, because the model is fitted on one view per volume and errors seen from
//!    other sides are larger ([`DEFAULT_MIN_CELLS`]).

use glam::DVec3;
use pin_format::Directions;

use crate::error::BakeError;
use crate::placement::bake_box;
use pin_volume::DensitySource;

/// Probe points per axis at most (64^3 = 262144 density lookups: well under a second even for
/// a VDB, and fine enough to see features a few percent of the box wide).
pub const PROBE_MAX: u32 = 64;

/// Spatial cells along the longest axis at most (other axes in proportion); the universe the
/// choice searches, independent of the target so that the choice stays monotone in it.
pub const MAX_CHOICE_CELLS: u32 = 64;

/// Octahedral resolution `n` (n x n direction cells) at most.
pub const MAX_CHOICE_OCTAHEDRAL: u32 = 32;

/// The block error a default bake aims for when the user names no `--target-error`: the
/// goal of 10% over the model's largest under-prediction of a swept bake of a fitted
/// volume (1.65, the torus; docs/evaluation.md, "The bias model that `pinbake bake` uses").
/// Above the floor this is what keeps the smoke's default at 10x20x10 (0.73x its f16 density);
/// at 0.05 the model asks for octahedral:18 there (0.92x), where the sweep measured no gain.
pub const DEFAULT_TARGET_ERROR: f64 = 0.06;

/// The default bake's floor: at least this many cells along the longest axis (fewer only where
/// the volume has fewer voxels) and at least octahedral:16. The model is fitted on one view
/// per volume (`scripts/bias_sweep.sh`); seen from four sides (`scripts/direction_sweep.sh`)
/// the same bakes measure 1.7-3.6x its block error (docs/evaluation.md), and bakes the model
/// alone chose below this floor measured 24-67% there. `--target-error` searches without it.
pub const DEFAULT_MIN_CELLS: u32 = 20;
pub const DEFAULT_MIN_OCTAHEDRAL: u32 = 16;

/// Volumes of `docs/eval/bias_sweep.csv` left out of the fit, to check its predictions on
/// volumes it has not seen (docs/evaluation.md).
pub const HELD_OUT: &[&str] = &["water", "blob"];

/// The fitted bias model `A * s^P * sqrt(h^2 + (K * theta)^2)` (see the module docs), `s` the
/// model variation. Fitted to docs/eval/bias_sweep.csv (60 bakes with pins through cell
/// centres on smoke, hydrogen, cosine, the box, the torus and the sphere; water and the blob
/// held out): A 0.10193, K 0.21, P 0.6655; the RMS of the log residuals is 0.268, a factor of
/// 1.31.
pub const MODEL_A: f64 = 0.1019;
pub const MODEL_K: f64 = 0.21;
pub const MODEL_P: f64 = 0.6655;

/// What [`analyse`] measured.
#[derive(Clone, Debug, serde::Serialize)]
pub struct VolumeStats {
    /// Extent of the bake box (cropped to the occupied region unless told otherwise).
    pub extent: [f64; 3],
    /// Voxels the bake box spans per axis, `None` for an analytic field.
    pub voxels: Option<[u32; 3]>,
    /// Probe points per axis.
    pub probe: [u32; 3],
    /// The variation statistic `g` of line transmittances (module docs), the model's input.
    pub variation: f64,
    /// Mean absolute density difference per unit length between neighbouring probe points
    /// times the longest edge squared (not used by the model).
    pub density_variation: f64,
    /// `g` on the lines' optical depths instead of their transmittances (not used by the
    /// model).
    pub depth_variation: f64,
    /// Mean extinction over the probe points times the longest box edge.
    pub mean_optical_depth: f64,
    /// The root mean square, over the projections' pixels inside the box, of the local
    /// transmittance variation between pixels inside the box (the silhouette of the box left
    /// out), averaged over the three axes. The square weights the few large differences of a
    /// sparse sharp feature (a hard-edged tube, a peak) that the mean `variation` dilutes; the
    /// box's own silhouette is left out because a face of the bake box is a cell boundary,
    /// which a lookup resolves (a homogeneous box has 0 here).
    pub variation_rms: f64,
    /// The bias model's input: `variation + variation_rms` (module docs).
    pub model_variation: f64,
}

/// Measures `source` over its bake box (see the module docs).
pub fn analyse(source: &dyn DensitySource, crop: bool) -> Result<VolumeStats, BakeError> {
    let (bbox, _) = bake_box(source, crop)?;
    let extent = bbox.extent();
    let longest = extent.max_element();
    let voxels = source.voxel_size().and_then(|v| {
        let n = [0, 1, 2].map(|a| extent[a] / v[a]);
        n.iter()
            .all(|x| x.is_finite() && *x > 0.0)
            // Rounded: a box of whole voxels divides to an integer up to rounding error.
            .then(|| n.map(|x| x.round().clamp(1.0, f64::from(u32::MAX)) as u32))
    });
    let probe = [0, 1, 2].map(|a| {
        let by_shape = (f64::from(PROBE_MAX) * extent[a] / longest).round() as u32;
        let p = by_shape.clamp(2, PROBE_MAX);
        // A probe finer than the voxels only samples the trilinear ramps between them.
        voxels.map_or(p, |v| p.min(v[a].max(2)))
    });
    let [px, py, pz] = probe.map(|p| p as usize);
    let step = DVec3::new(
        extent.x / px as f64,
        extent.y / py as f64,
        extent.z / pz as f64,
    );
    let mut values = vec![0.0f64; px * py * pz];
    for (i, v) in values.iter_mut().enumerate() {
        let c = DVec3::new(
            (i % px) as f64 + 0.5,
            ((i / px) % py) as f64 + 0.5,
            (i / (px * py)) as f64 + 0.5,
        );
        *v = f64::from(source.extinction(bbox.min + c * step));
    }
    let at = |x: isize, y: isize, z: isize| -> f64 {
        // Outside the bake box the density is zero: the box's own edge is a jump there.
        if x < 0 || y < 0 || z < 0 || x >= px as isize || y >= py as isize || z >= pz as isize {
            0.0
        } else {
            values[x as usize + px * (y as usize + py * z as usize)]
        }
    };
    // Forward differences along each axis, the box faces included (one more difference than
    // points per axis: from the outside into the first point and out of the last).
    let mut per_axis = [0.0f64; 3];
    for z in 0..pz as isize {
        for y in 0..py as isize {
            for x in -1..px as isize {
                per_axis[0] += (at(x + 1, y, z) - at(x, y, z)).abs();
            }
        }
    }
    for z in 0..pz as isize {
        for y in -1..py as isize {
            for x in 0..px as isize {
                per_axis[1] += (at(x, y + 1, z) - at(x, y, z)).abs();
            }
        }
    }
    for z in -1..pz as isize {
        for y in 0..py as isize {
            for x in 0..px as isize {
                per_axis[2] += (at(x, y, z + 1) - at(x, y, z)).abs();
            }
        }
    }
    let points = (px * py * pz) as f64;
    // Per unit length: each difference spans one probe step; averaged over the points.
    let gradient: f64 = (0..3).map(|a| per_axis[a] / step[a] / points).sum();
    let mean = values.iter().sum::<f64>() / points;
    let pv = projected_variation(&values, probe, step, longest);
    Ok(VolumeStats {
        extent: extent.to_array(),
        voxels,
        probe,
        variation: pv.mean,
        density_variation: gradient * longest * longest,
        depth_variation: pv.depth,
        mean_optical_depth: mean * longest,
        variation_rms: pv.rms_inside,
        model_variation: pv.mean + pv.rms_inside,
    })
}

/// What [`projected_variation`] measures, each averaged over the three axes.
struct ProjectedVariation {
    /// Mean over the map's pixels of the local transmittance variation (`g`).
    mean: f64,
    /// The same on optical depths.
    depth: f64,
    /// Root mean square of the local transmittance variation between pixels inside the box.
    rms_inside: f64,
}

/// The variation of the volume's projections: for each axis, the optical depth map of lines
/// along it (and its transmittance `exp(-tau)`). The local variation of a pixel is the sum of
/// the absolute differences to its +1 neighbours along both map axes, each per unit length,
/// times the longest edge; the map is framed by one ring of pixels outside the box (optical
/// depth 0), so that the silhouette counts on every side of the mean; the RMS counts only
/// differences between pixels inside the box (see [`VolumeStats::variation_rms`]).
fn projected_variation(
    values: &[f64],
    probe: [u32; 3],
    step: DVec3,
    longest: f64,
) -> ProjectedVariation {
    let p = probe.map(|x| x as usize);
    let idx = |c: [usize; 3]| c[0] + p[0] * (c[1] + p[1] * c[2]);
    let mut out = ProjectedVariation {
        mean: 0.0,
        depth: 0.0,
        rms_inside: 0.0,
    };
    for a in 0..3 {
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let mut tau = vec![0.0f64; p[b] * p[c]];
        for j in 0..p[c] {
            for i in 0..p[b] {
                let mut sum = 0.0;
                for k in 0..p[a] {
                    let mut q = [0usize; 3];
                    q[a] = k;
                    q[b] = i;
                    q[c] = j;
                    sum += values[idx(q)];
                }
                tau[i + p[b] * j] = sum * step[a];
            }
        }
        // Zero optical depth (transmittance 1) outside the box: its silhouette is an edge.
        let at = |i: isize, j: isize| -> f64 {
            if i < 0 || j < 0 || i >= p[b] as isize || j >= p[c] as isize {
                0.0
            } else {
                tau[i as usize + p[b] * j as usize]
            }
        };
        let mut d = 0.0;
        let (mut t_sum, mut inside_sq) = (0.0, 0.0);
        let inside =
            |i: isize, j: isize| i >= 0 && j >= 0 && i < p[b] as isize && j < p[c] as isize;
        for j in -1..p[c] as isize {
            for i in -1..p[b] as isize {
                let (mut t, mut ti) = (0.0, 0.0);
                if j >= 0 {
                    let (x, y) = (at(i, j), at(i + 1, j));
                    d += (y - x).abs() / step[b];
                    let dt = ((-x).exp() - (-y).exp()).abs() / step[b];
                    t += dt;
                    if inside(i, j) && inside(i + 1, j) {
                        ti += dt;
                    }
                }
                if i >= 0 {
                    let (x, y) = (at(i, j), at(i, j + 1));
                    d += (y - x).abs() / step[c];
                    let dt = ((-x).exp() - (-y).exp()).abs() / step[c];
                    t += dt;
                    if inside(i, j) && inside(i, j + 1) {
                        ti += dt;
                    }
                }
                t_sum += t * longest;
                inside_sq += (ti * longest).powi(2);
            }
        }
        // Normalised by the pixels inside the box (not the framed map), as `g` always was.
        let n = (p[b] * p[c]) as f64;
        out.mean += t_sum / n;
        out.depth += d / n * longest;
        out.rms_inside += (inside_sq / n).sqrt();
    }
    for v in [&mut out.mean, &mut out.depth, &mut out.rms_inside] {
        *v /= 3.0;
    }
    out
}

/// Angular size (radians) of one of `count` direction cells over the hemisphere.
pub fn direction_cell_angle(count: u32) -> f64 {
    (std::f64::consts::TAU / f64::from(count.max(1))).sqrt()
}

/// Spatial cell edge over the longest box edge (the largest over the axes).
pub fn cell_fraction(cells: [u32; 3], extent: [f64; 3]) -> f64 {
    let longest = extent.iter().copied().fold(0.0, f64::max);
    (0..3)
        .map(|a| extent[a] / f64::from(cells[a].max(1)) / longest)
        .fold(0.0, f64::max)
}

/// The model's predicted 8x8-block RMS error of pins alone for a bake of `cells` and
/// `directions` on a volume of model variation `s` ([`VolumeStats::model_variation`], see the
/// module docs). Pins per entry do not
/// enter: the sweep found no bias gain from them at equal cells and directions.
pub fn predicted_error(variation: f64, cells: [u32; 3], extent: [f64; 3], directions: u32) -> f64 {
    model(
        (MODEL_A, MODEL_K, MODEL_P),
        variation,
        cell_fraction(cells, extent),
        direction_cell_angle(directions),
    )
}

/// `A * g^P * sqrt(h^2 + (K theta)^2)` for `(A, K, P)`.
pub fn model((a, k, p): (f64, f64, f64), variation: f64, h: f64, theta: f64) -> f64 {
    a * variation.max(0.0).powf(p) * h.hypot(k * theta)
}

/// What the user fixed; `None` fields are chosen.
#[derive(Clone, Copy, Debug, Default)]
pub struct Fixed {
    pub cells: Option<[u32; 3]>,
    pub directions: Option<Directions>,
    pub pins_per_entry: Option<u32>,
}

/// A chosen bake and why.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Choice {
    pub cells: [u32; 3],
    #[serde(skip)]
    pub directions: Directions,
    pub pins_per_entry: u32,
    /// The model's block error for this bake.
    pub predicted_error: f64,
    /// The target the choice aimed at.
    pub target_error: f64,
    /// Whether some bake in the searched range met the target.
    pub target_met: bool,
    /// Pin, index and header bytes the choice expects (dense: every cell stored).
    pub predicted_pin_bytes: u64,
    /// The cells were chosen (not given) and are one per voxel on every axis: the rule
    /// "never more cells than voxels" allows no finer spatial grid. On volumes that small the
    /// measured block error exceeds the prediction (`docs/evaluation.md`, "The sphere: capped
    /// by its voxels"); `reason_cells` says so and how to go finer.
    pub capped_by_voxels: bool,
    /// One line for the user when the cells or directions were chosen (not given) and the
    /// choice cannot resolve the volume's detail as the target asks: no bake in the searched
    /// range meets it, or the cells are capped by the voxels. `pinbake bake` prints it on
    /// stderr; `--json` carries it as `choice.warning` (null otherwise).
    pub warning: Option<String>,
    /// One sentence per parameter.
    pub reason_cells: String,
    pub reason_directions: String,
    pub reason_pins_per_entry: String,
    pub stats: VolumeStats,
    /// What the default asset rule weighed and chose ([`crate::default_asset`]), when it
    /// chose the bake.
    pub asset: Option<crate::asset_choice::AssetChoice>,
}

/// Cells along each axis for `n` along the longest: in proportion to the box, at least 1, and
/// never more than the voxels the axis spans.
pub fn proportional_cells(n: u32, extent: [f64; 3], voxels: Option<[u32; 3]>) -> [u32; 3] {
    let longest = extent.iter().copied().fold(0.0, f64::max);
    [0, 1, 2].map(|a| {
        let c = ((f64::from(n) * extent[a] / longest).round() as u32).max(1);
        voxels.map_or(c, |v| c.min(v[a].max(1)))
    })
}

/// Dense pin-section bytes plus the cell index of a bake (what the choice minimises).
pub fn pin_bytes(cells: [u32; 3], directions: u32, pins_per_entry: u32) -> u64 {
    let n: u64 = cells.iter().map(|&c| u64::from(c)).product();
    n * u64::from(directions) * u64::from(pins_per_entry) * 8 + n * 4
}

/// The most pin bytes ([`pin_bytes`]: dense pins and the cell index) of a bake chosen for an
/// explicit `--target-error`: 256 MiB, about 25 s of baking on 2 cores. The search's largest
/// bake (64^3 cells, octahedral:32) is 2.1 GB and ran for 180 s; a target that asks for more
/// than this is refused before the bake starts ([`check_target`]), and `--cells`/`--dirs`
/// name a larger bake explicitly.
pub const MAX_TARGET_PIN_BYTES: u64 = 256 << 20;

/// Refuses a choice made for an explicit target (`--target-error`, Python's `target_error`)
/// whose pins would exceed [`MAX_TARGET_PIN_BYTES`]: one line with the target, the bake it
/// needs and the limit. A target nothing in the search reaches with a bake within the limit
/// keeps the closest bake and its warning, as before.
pub fn check_target(choice: &Choice) -> Result<(), String> {
    let bytes = choice.predicted_pin_bytes;
    if bytes <= MAX_TARGET_PIN_BYTES {
        return Ok(());
    }
    let [x, y, z] = choice.cells;
    let bake = format!(
        "{x}x{y}x{z} cells, {} directions, {} pins per entry: {} MiB of pins",
        choice.directions.count(),
        choice.pins_per_entry,
        bytes.div_ceil(1 << 20)
    );
    let t = choice.target_error;
    // 1e-9, not 0.000000001.
    let target = if t < 1e-3 {
        format!("{t:e}")
    } else {
        pin_format::text::num(t)
    };
    let limit = MAX_TARGET_PIN_BYTES >> 20;
    Err(if choice.target_met {
        format!(
            "target_error {target} needs a bake of {bake}, more than the {limit} MiB a chosen bake may have; ask for a larger target error, or name the cells and directions (--cells, --dirs) to bake it anyway"
        )
    } else {
        format!(
            "target_error {target} cannot be met: no bake up to {MAX_CHOICE_CELLS} cells and octahedral:{MAX_CHOICE_OCTAHEDRAL} reaches it, and the closest (predicted error {:.3}) is {bake}, more than the {limit} MiB a chosen bake may have; ask for a target error of at least {:.3}, or name the cells and directions (--cells, --dirs)",
            choice.predicted_error, choice.predicted_error
        )
    })
}

/// The smallest bake whose predicted error is at most `target` (module docs). When no bake in
/// the searched range meets it, the one with the lowest predicted error (fewest bytes among
/// equals): a smaller target never yields a smaller bake.
pub fn choose(stats: &VolumeStats, fixed: Fixed, target: f64) -> Choice {
    choose_above(stats, fixed, target, 1, 1)
}

/// What `pinbake bake` does for pins alone without `--target-error`: [`choose`] at [`DEFAULT_TARGET_ERROR`]
/// among bakes of at least [`DEFAULT_MIN_CELLS`] (capped by the voxels) and
/// octahedral:[`DEFAULT_MIN_OCTAHEDRAL`], for the parameters not given.
pub fn choose_default(stats: &VolumeStats, fixed: Fixed) -> Choice {
    choose_above(
        stats,
        fixed,
        DEFAULT_TARGET_ERROR,
        DEFAULT_MIN_CELLS,
        DEFAULT_MIN_OCTAHEDRAL,
    )
}

/// [`choose`] among cells of at least `min_cells` along the longest axis (capped by the
/// voxels) and octahedral sets of at least `min_oct`.
fn choose_above(
    stats: &VolumeStats,
    fixed: Fixed,
    target: f64,
    min_cells: u32,
    min_oct: u32,
) -> Choice {
    let extent = stats.extent;
    let cell_options: Vec<[u32; 3]> = match fixed.cells {
        Some(c) => vec![c],
        None => {
            let mut v: Vec<[u32; 3]> = (min_cells.clamp(1, MAX_CHOICE_CELLS)..=MAX_CHOICE_CELLS)
                .map(|n| proportional_cells(n, extent, stats.voxels))
                .collect();
            v.dedup();
            v
        }
    };
    let dir_options: Vec<Directions> = match fixed.directions {
        Some(d) => vec![d],
        None => (min_oct.clamp(1, MAX_CHOICE_OCTAHEDRAL)..=MAX_CHOICE_OCTAHEDRAL)
            .map(|n| Directions::Octahedral { n })
            .collect(),
    };
    let ppe = fixed.pins_per_entry.unwrap_or(1);
    // (bytes, error, cells, directions)
    let mut best_fit: Option<(u64, f64, [u32; 3], Directions)> = None;
    let mut most_accurate: Option<(u64, f64, [u32; 3], Directions)> = None;
    for &c in &cell_options {
        for &d in &dir_options {
            let e = predicted_error(stats.model_variation, c, extent, d.count());
            let b = pin_bytes(c, d.count(), ppe);
            let cand = (b, e, c, d);
            if e <= target && best_fit.is_none_or(|f| (b, e) < (f.0, f.1)) {
                best_fit = Some(cand);
            }
            if most_accurate.is_none_or(|f| (e, b) < (f.1, f.0)) {
                most_accurate = Some(cand);
            }
        }
    }
    let target_met = best_fit.is_some();
    let (bytes, error, cells, directions) = best_fit
        .or(most_accurate)
        .expect("at least one cell and one direction option");
    let voxels = match stats.voxels {
        Some(v) => format!("{}x{}x{} voxels", v[0], v[1], v[2]),
        None => "an analytic field (no voxels)".to_string(),
    };
    let floor = if min_cells > 1 || min_oct > 1 {
        format!(
            " at or above the default's floor ({min_cells} cells along the longest axis or the \
             voxels, octahedral:{min_oct})"
        )
    } else {
        String::new()
    };
    // `num`: a target of 1e-300 is not 300 digits in a message.
    let target_shown = pin_format::text::num(target);
    let goal = if target_met {
        format!("the fewest bytes{floor} with a predicted block error <= {target_shown}")
    } else {
        format!(
            "no bake up to {MAX_CHOICE_CELLS} cells and octahedral:{MAX_CHOICE_OCTAHEDRAL} \
             reaches {target_shown}: the lowest predicted error"
        )
    };
    let capped_by_voxels = fixed.cells.is_none()
        && stats
            .voxels
            .is_some_and(|v| (0..3).all(|a| cells[a] >= v[a].max(1)));
    let reason_cells = match fixed.cells {
        Some(_) => "given (--cells)".to_string(),
        None => format!(
            "{goal}; model variation {:.3} (mean {:.3} + sparse-feature rms {:.3}) over \
             {voxels}; never more cells than voxels{}",
            stats.model_variation,
            stats.variation,
            stats.variation_rms,
            if capped_by_voxels {
                ": one cell per voxel here, and on volumes this small the measured block \
                 error exceeds the prediction (docs/evaluation.md, \"The sphere: capped by \
                 its voxels\"); --cells above the voxels lowers it"
            } else {
                ""
            }
        ),
    };
    let chosen = fixed.cells.is_none() || fixed.directions.is_none();
    let warning = if !chosen {
        None
    } else if !target_met {
        Some(format!(
            "no bake up to {MAX_CHOICE_CELLS} cells and octahedral:{MAX_CHOICE_OCTAHEDRAL} \
             resolves this volume's detail to the target block error {target_shown} (the closest \
             predicts {error:.3}, model variation {:.1}): expect visible pin bias; name finer \
             --cells/--dirs, or render final frames with an unbiased estimator",
            stats.model_variation
        ))
    } else if capped_by_voxels {
        Some(format!(
            "the cells are capped at one per voxel ({voxels}); on volumes this small the \
             measured block error exceeds the predicted {error:.3}: --cells above the voxels \
             lowers it"
        ))
    } else {
        None
    };
    let reason_directions = match fixed.directions {
        Some(_) => "given (--dirs)".to_string(),
        None => format!(
            "{goal}; octahedral, the kind with the lowest measured bias at equal bytes \
             (docs/evaluation.md)"
        ),
    };
    let reason_pins_per_entry = match fixed.pins_per_entry {
        Some(_) => "given (--pins-per-entry)".to_string(),
        None => "1: more pins per entry did not lower the measured bias at equal bytes \
                 (docs/evaluation.md, Bias against bytes)"
            .to_string(),
    };
    Choice {
        cells,
        directions,
        pins_per_entry: ppe,
        predicted_error: error,
        target_error: target,
        target_met,
        capped_by_voxels,
        predicted_pin_bytes: bytes,
        warning,
        reason_cells,
        reason_directions,
        reason_pins_per_entry,
        stats: stats.clone(),
        asset: None,
    }
}

/// One measured bake for [`fit`]: the volume's model variation, the bake's cell fraction `h`, its
/// direction cell angle `theta` and the measured block error.
#[derive(Clone, Copy, Debug)]
pub struct FitRow {
    pub variation: f64,
    pub h: f64,
    pub theta: f64,
    pub error: f64,
}

/// Least squares of `ln error - ln sqrt(h^2 + (K theta)^2)` on `ln g` over a grid of `K`
/// (0.01 to 2): returns `(A, K, P, rms of the log residuals)`. With a single volume (one `g`)
/// `P` is undetermined and set to 1. Rows with a non-positive error or variation are skipped
/// (the log is undefined there); `None` with fewer than 3 rows left.
pub fn fit(rows: &[FitRow]) -> Option<(f64, f64, f64, f64)> {
    let rows: Vec<&FitRow> = rows
        .iter()
        .filter(|r| r.error > 0.0 && r.variation > 0.0)
        .collect();
    if rows.len() < 3 {
        return None;
    }
    let n = rows.len() as f64;
    let xs: Vec<f64> = rows.iter().map(|r| r.variation.ln()).collect();
    let mx = xs.iter().sum::<f64>() / n;
    let sxx: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
    let mut best: Option<(f64, f64, f64, f64)> = None;
    for step in 1..=200 {
        let k = 0.01 * f64::from(step);
        let ys: Vec<f64> = rows
            .iter()
            .map(|r| r.error.ln() - r.h.hypot(k * r.theta).ln())
            .collect();
        let my = ys.iter().sum::<f64>() / n;
        let p = if sxx > 1e-12 {
            xs.iter()
                .zip(&ys)
                .map(|(x, y)| (x - mx) * (y - my))
                .sum::<f64>()
                / sxx
        } else {
            1.0
        };
        let ln_a = my - p * mx;
        let rss: f64 = xs
            .iter()
            .zip(&ys)
            .map(|(x, y)| (y - ln_a - p * x).powi(2))
            .sum();
        let rms = (rss / n).sqrt();
        if best.is_none_or(|b| rms < b.3) {
            best = Some((ln_a.exp(), k, p, rms));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use pin_volume::Aabb;
    use pin_volume::DenseGrid;
    use pin_volume::procedural::HomogeneousBox;

    /// A `n^3` grid over the unit cube: a Gaussian blob, times `1 + 0.9 cos(2 pi f x) cos(2 pi
    /// f y)` when `f > 0` (detail at `f` cycles per box).
    fn blob(n: u32, f: f64) -> DenseGrid {
        let h = 1.0 / f64::from(n);
        let nu = n as usize;
        let data = (0..nu * nu * nu)
            .map(|i| {
                let p = DVec3::new(
                    (i % nu) as f64 + 0.5,
                    ((i / nu) % nu) as f64 + 0.5,
                    (i / (nu * nu)) as f64 + 0.5,
                ) * h;
                let r2 = (p - DVec3::splat(0.5)).length_squared();
                let detail = if f > 0.0 {
                    1.0 + 0.9
                        * (std::f64::consts::TAU * f * p.x).cos()
                        * (std::f64::consts::TAU * f * p.y).cos()
                } else {
                    1.0
                };
                (8.0 * (-r2 / (2.0 * 0.15 * 0.15)).exp() * detail) as f32
            })
            .collect();
        DenseGrid::new([n; 3], data, DVec3::splat(h), DVec3::ZERO, "blob").unwrap()
    }

    fn total(c: [u32; 3]) -> u64 {
        c.iter().map(|&x| u64::from(x)).product()
    }

    #[test]
    fn variation_of_a_homogeneous_box_is_its_edges() {
        // Inside a homogeneous cube (edge D) nothing varies. Its projection along an axis is a
        // square of transmittance exp(-sigma D) on 1: each of the p rows of the map crosses
        // the silhouette twice per in-plane axis, so the map sums 2 x 2 p jumps of
        // 1 - exp(-sigma D), each over a step D / p; per pixel (p^2) and times D that is
        // g = 4 (1 - exp(-sigma D)). On the density itself the six faces are jumps of sigma:
        // D^2 x 3 axes x 2 sigma / D = 6 sigma D; on optical depths 4 sigma D.
        let b = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::splat(2.0)), 3.0).unwrap();
        let s = analyse(&b, true).unwrap();
        let want = 4.0 * (1.0 - (-6.0f64).exp());
        assert!(
            (s.variation - want).abs() < 1e-9,
            "{} vs {want}",
            s.variation
        );
        assert!(
            (s.density_variation - 36.0).abs() < 1e-9,
            "{}",
            s.density_variation
        );
        assert!(
            (s.depth_variation - 24.0).abs() < 1e-9,
            "{}",
            s.depth_variation
        );
        assert!((s.mean_optical_depth - 6.0).abs() < 1e-9);
        // Inside the silhouette the projection is flat: no sparse feature, the model's input
        // is the mean alone.
        assert_eq!(s.variation_rms, 0.0);
        assert_eq!(s.model_variation, s.variation);
        assert_eq!(s.voxels, None);
        // An empty field varies nowhere.
        let e = HomogeneousBox::new(Aabb::new(DVec3::ZERO, DVec3::ONE), 0.0).unwrap();
        assert_eq!(analyse(&e, true).unwrap().variation, 0.0);
    }

    #[test]
    fn detail_raises_the_variation() {
        let smooth = analyse(&blob(32, 0.0), true).unwrap();
        let detailed = analyse(&blob(32, 6.0), true).unwrap();
        // 2.79 against 2.01 when written: the detail survives in the projection along z
        // (it varies in x and y) and averages out along x and y.
        assert!(
            detailed.variation > 1.25 * smooth.variation,
            "{} vs {}",
            detailed.variation,
            smooth.variation
        );
        assert_eq!(smooth.voxels, Some([32; 3]));
        assert_eq!(smooth.probe, [32; 3]);
    }

    #[test]
    fn the_rms_sees_a_sparse_sharp_feature() {
        // A hard-edged 3x3x3-voxel knot of extinction 60 beside the smooth blob: it covers
        // under 1% of each projection, so the mean variation hardly moves, while the RMS of the
        // local variation, which squares the knot's large differences, rises four times as
        // much. (When written: mean 2.011 -> 2.271, x1.13; rms 2.646 -> 4.071, x1.54. The
        // result is deterministic; the margins below only absorb changes of the probe.)
        let smooth = blob(32, 0.0);
        let mut data = smooth.data().to_vec();
        for z in 4..7 {
            for y in 20..23 {
                for x in 22..25 {
                    data[x + 32 * (y + 32 * z)] += 60.0;
                }
            }
        }
        let h = 1.0 / 32.0;
        let knot = DenseGrid::new([32; 3], data, DVec3::splat(h), DVec3::ZERO, "knot").unwrap();
        let (a, b) = (
            analyse(&smooth, false).unwrap(),
            analyse(&knot, false).unwrap(),
        );
        let mean_gain = b.variation / a.variation;
        let rms_gain = b.variation_rms / a.variation_rms;
        assert!(mean_gain < 1.2, "mean {} -> {}", a.variation, b.variation);
        assert!(
            rms_gain > 1.3 * mean_gain,
            "rms {} -> {} (mean x{mean_gain})",
            a.variation_rms,
            b.variation_rms
        );
        assert!((b.model_variation - b.variation - b.variation_rms).abs() < 1e-12);
    }

    #[test]
    fn never_more_cells_than_voxels() {
        // A tiny target on a detailed 5x7x3 grid: the search wants many cells and gets the
        // voxels at most.
        let n = 5 * 7 * 3;
        let data = (0..n).map(|i| (i % 4) as f32).collect();
        let g = DenseGrid::new([5, 7, 3], data, DVec3::ONE, DVec3::ZERO, "t").unwrap();
        let s = analyse(&g, false).unwrap();
        assert_eq!(s.voxels, Some([5, 7, 3]));
        for target in [1e-6, 1e-3, 0.05, 0.5] {
            let c = choose(&s, Fixed::default(), target);
            assert!(
                c.cells[0] <= 5 && c.cells[1] <= 7 && c.cells[2] <= 3,
                "{:?}",
                c.cells
            );
        }
        let c = choose(&s, Fixed::default(), 1e-6);
        assert!(!c.target_met);
        assert_eq!(c.cells, [5, 7, 3]);
        // Capped, and the reason says how to go finer; not when the cells are given, nor
        // when the choice stops below the voxels.
        assert!(c.capped_by_voxels);
        assert!(
            c.reason_cells.contains("--cells above the voxels"),
            "{}",
            c.reason_cells
        );
        let given = Fixed {
            cells: Some([5, 7, 3]),
            ..Fixed::default()
        };
        assert!(!choose(&s, given, 1e-6).capped_by_voxels);
        let coarse = choose(&s, Fixed::default(), 0.5);
        assert!(
            coarse.cells != [5, 7, 3] && !coarse.capped_by_voxels,
            "{:?}",
            coarse.cells
        );
        assert!(!coarse.reason_cells.contains("--cells above"));
        assert_eq!(
            c.directions,
            Directions::Octahedral {
                n: MAX_CHOICE_OCTAHEDRAL
            }
        );
    }

    #[test]
    fn a_choice_that_cannot_resolve_the_volume_says_so() {
        // A detailed blob at a target no bake in the range reaches: one line that names the
        // target and what to do; a reachable target, or given cells and directions, says
        // nothing.
        let s = analyse(&blob(32, 6.0), true).unwrap();
        let c = choose(&s, Fixed::default(), 1e-4);
        assert!(!c.target_met);
        let w = c.warning.expect("an unreachable target warns");
        assert!(w.contains("0.0001") && w.contains("--cells"), "{w}");
        assert!(!w.contains('\n'), "{w}");
        assert_eq!(choose(&s, Fixed::default(), 0.5).warning, None);
        let smooth = analyse(&blob(64, 0.0), true).unwrap();
        assert_eq!(choose_default(&smooth, Fixed::default()).warning, None);
        let given = Fixed {
            cells: Some([8; 3]),
            directions: Some(Directions::Octahedral { n: 4 }),
            pins_per_entry: None,
        };
        assert_eq!(choose(&s, given, 1e-4).warning, None);
        // Capped by the voxels: the other reason to warn.
        let tiny = DenseGrid::new(
            [5, 7, 3],
            (0..105).map(|i| (i % 4) as f32).collect(),
            DVec3::ONE,
            DVec3::ZERO,
            "t",
        )
        .unwrap();
        let t = choose(&analyse(&tiny, false).unwrap(), Fixed::default(), 1e-6);
        assert!(t.capped_by_voxels && t.warning.is_some());
    }

    #[test]
    fn smooth_volume_gets_fewer_cells_than_a_detailed_one() {
        let smooth = analyse(&blob(32, 0.0), true).unwrap();
        let detailed = analyse(&blob(32, 6.0), true).unwrap();
        for target in [0.03, 0.05, 0.1] {
            let a = choose(&smooth, Fixed::default(), target);
            let b = choose(&detailed, Fixed::default(), target);
            // More detail buys more bytes; with the fitted K the model may spend them on
            // directions rather than cells, but never on fewer cells.
            assert!(
                total(a.cells) <= total(b.cells) && a.predicted_pin_bytes < b.predicted_pin_bytes,
                "target {target}: smooth {:?} {:?}, detailed {:?} {:?}",
                a.cells,
                a.directions,
                b.cells,
                b.directions
            );
        }
    }

    #[test]
    fn smaller_target_never_gives_a_smaller_bake() {
        for f in [0.0, 6.0] {
            let s = analyse(&blob(32, f), true).unwrap();
            let mut last = 0u64;
            for k in 0..40 {
                let target = 0.5 * 0.85f64.powi(k);
                let c = choose(&s, Fixed::default(), target);
                assert!(c.predicted_pin_bytes >= last, "target {target}");
                assert!(!c.target_met || c.predicted_error <= target);
                last = c.predicted_pin_bytes;
            }
        }
    }

    #[test]
    fn default_never_goes_below_its_floor() {
        // A smooth volume whose model choice at 0.05 is small: the default still has 20 cells
        // along the longest axis and octahedral:16; the voxels cap the floor.
        let s = analyse(&blob(32, 0.0), true).unwrap();
        let free = choose(&s, Fixed::default(), DEFAULT_TARGET_ERROR);
        let d = choose_default(&s, Fixed::default());
        assert!(free.predicted_pin_bytes < d.predicted_pin_bytes);
        assert_eq!(d.cells.iter().max(), Some(&DEFAULT_MIN_CELLS));
        assert!(
            matches!(d.directions, Directions::Octahedral { n } if n >= DEFAULT_MIN_OCTAHEDRAL)
        );
        assert!(d.reason_cells.contains("floor"), "{}", d.reason_cells);
        let s = analyse(&blob(12, 0.0), false).unwrap();
        assert_eq!(choose_default(&s, Fixed::default()).cells, [12; 3]);
        // Given directions stay given.
        let fixed = Fixed {
            directions: Some(Directions::Octahedral { n: 2 }),
            ..Fixed::default()
        };
        assert_eq!(
            choose_default(&s, fixed).directions,
            Directions::Octahedral { n: 2 }
        );
    }

    #[test]
    fn given_parameters_are_kept() {
        let s = analyse(&blob(32, 6.0), true).unwrap();
        let fixed = Fixed {
            cells: Some([3, 4, 5]),
            directions: None,
            pins_per_entry: Some(2),
        };
        let c = choose(&s, fixed, 0.05);
        assert_eq!(c.cells, [3, 4, 5]);
        assert_eq!(c.pins_per_entry, 2);
        assert!(c.reason_cells.contains("--cells"));
        assert!(matches!(c.directions, Directions::Octahedral { .. }));
        let d = Directions::Polar {
            n_phi: 16,
            n_theta: 4,
        };
        let c = choose(
            &s,
            Fixed {
                directions: Some(d),
                ..Fixed::default()
            },
            0.05,
        );
        assert_eq!(c.directions, d);
        assert_eq!(c.pins_per_entry, 1);
    }

    #[test]
    fn fit_recovers_a_known_model() {
        // Rows generated from a known (A, K, P) with +-3% multiplicative noise from a fixed
        // seed: the fit lands within the noise. The mutation (rows from K = 1.2) must move K.
        let truth = (0.004, 0.4, 0.6);
        let mut rng = crate::rng::CounterRng::new(7, 0, 0);
        let rows = |t: (f64, f64, f64), rng: &mut crate::rng::CounterRng| -> Vec<FitRow> {
            let mut v = Vec::new();
            for g in [20.0, 60.0, 150.0, 1500.0] {
                for cells in [8.0, 12.0, 16.0, 24.0] {
                    for dirs in [16u32, 64, 256] {
                        let (h, theta) = (1.0 / cells, direction_cell_angle(dirs));
                        let noise = 1.0 + 0.03 * (2.0 * rng.next_f64() - 1.0);
                        v.push(FitRow {
                            variation: g,
                            h,
                            theta,
                            error: model(t, g, h, theta) * noise,
                        });
                    }
                }
            }
            v
        };
        let (a, k, p, rms) = fit(&rows(truth, &mut rng)).unwrap();
        assert!((k - truth.1).abs() <= 0.05, "K {k}");
        assert!((p - truth.2).abs() <= 0.03, "P {p}");
        assert!((a / truth.0 - 1.0).abs() <= 0.2, "A {a}");
        assert!(rms < 0.03);
        let (_, k2, _, _) = fit(&rows((0.004, 1.2, 0.6), &mut rng)).unwrap();
        assert!((k2 - 1.2).abs() <= 0.1 && (k2 - k).abs() > 0.5, "K {k2}");
        // Too few usable rows: no fit.
        assert!(fit(&rows(truth, &mut rng)[..2]).is_none());
    }

    /// The model's constants are the fit of the committed sweep (docs/eval/bias_sweep.csv,
    /// written by scripts/bias_sweep.sh): octahedral bakes, one pin per entry, one cell of
    /// lookup jitter. Refit here so that new data cannot silently disagree with the code.
    #[test]
    fn model_constants_are_the_fit_of_the_committed_sweep() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/eval/bias_sweep.csv");
        let text = std::fs::read_to_string(path).unwrap();
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let col = |n: &str| header.iter().position(|h| *h == n).unwrap();
        let (scene, cells, dirs, count, ppe, jit, block, var) = (
            col("scene"),
            col("cells"),
            col("dirs"),
            col("directions"),
            col("pins_per_entry"),
            col("jitter"),
            col("block8_rms_error"),
            col("model_variation"),
        );
        let rows: Vec<FitRow> = lines
            .map(|l| l.split(',').collect::<Vec<_>>())
            // Bakes of the sweep's grid only: `--cells N`, octahedral, one pin per entry, one
            // cell of jitter (the rows of bakes pinbake chose name their cells as XxYxZ).
            .filter(|f| {
                !HELD_OUT.contains(&f[scene])
                    && f[cells].parse::<u32>().is_ok()
                    && f[dirs].starts_with("octahedral")
                    && f[ppe] == "1"
                    && f[jit] == "1"
            })
            .map(|f| FitRow {
                variation: f[var].parse().unwrap(),
                h: 1.0 / f[cells].parse::<f64>().unwrap(),
                theta: direction_cell_angle(f[count].parse().unwrap()),
                error: f[block].parse().unwrap(),
            })
            .collect();
        assert!(rows.len() >= 24, "{} rows", rows.len());
        let (a, k, p, rms) = fit(&rows).unwrap();
        let close = |x: f64, y: f64| (x / y - 1.0).abs() < 0.01;
        assert!(
            close(a, MODEL_A) && close(k, MODEL_K) && close(p, MODEL_P),
            "fit A {a:.5} K {k:.3} P {p:.4} (rms log residual {rms:.3})"
        );
    }
}
