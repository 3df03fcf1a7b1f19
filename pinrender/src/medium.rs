//! One medium instance as data: its density (what the CPU estimators read, and its GPU copy),
//! its majorants, its pins and their placement. The CPU estimators
//! ([`MediumDesc::cpu_medium`]) and the GPU packing ([`gpu_media`]) both derive from it, so
//! `pinrender render` and the eval's scenes describe a medium once for both renderers.

use std::sync::Arc;

use pinrt::{PinGrid, SamplerOptions};

#[cfg(feature = "gpu")]
use crate::gpu_render::{
    GpuControl, GpuDensity, GpuEstimator, GpuMedia, GpuMedium, GpuPins, GpuPlacedDensity,
};
#[cfg(feature = "gpu")]
use crate::render::{BakedResidualTracking, ResidualRatioTracking};
use crate::render::{
    Density, EstimatorSpec, MajorantGrid, Medium, PinsEstimator, RenderError, TransportEstimator,
};

/// A pin grid placed in the world.
#[derive(Clone)]
pub struct PlacedPins {
    pub grid: Arc<PinGrid>,
    /// Row-major 3x4 local-to-world; `None`: the file's own.
    pub local_to_world: Option<[f64; 12]>,
}

/// One medium instance. Instances of one scene may share their grids, GPU densities,
/// majorants and fields (`Arc`s): the GPU packing uploads each shared one once.
///
/// Without `placement` everything is in the world. With it, `field`, `majorants`, the pins'
/// placement and the GPU density with its `translation` are in an asset's own frame, and
/// `placement` puts that frame in the world (an instance of a scene file): the CPU estimators
/// are built in the asset's frame and placed ([`crate::instance::place_medium`]), the GPU asks
/// every density query in that frame, so instances of one asset share its description.
#[derive(Clone, Default)]
pub struct MediumDesc {
    /// The extinction the CPU estimators read, in the world (placement applied) or the
    /// asset's frame; `None`: a pin file without embedded density.
    pub field: Option<Arc<dyn Density>>,
    /// Majorants over `field` in its frame; `None`: built from `field` with
    /// `majorant_bricks` per axis when an estimator tracks.
    pub majorants: Option<Arc<MajorantGrid>>,
    pub majorant_bricks: u32,
    pub pins: Option<PlacedPins>,
    /// The GPU's copy of the density in its own frame, placed by `translation`
    /// (`field(p) = gpu_density(p - translation)`); `None` where no GPU render needs it.
    #[cfg(feature = "gpu")]
    pub gpu_density: Option<Arc<GpuDensity>>,
    pub translation: [f64; 3],
    /// Row-major 3x4 local-to-world of the asset's frame that the rest is in; `None`: the
    /// rest is in the world.
    pub placement: Option<[f64; 12]>,
}

fn missing(what: &'static str, why: &str) -> RenderError {
    RenderError::Invalid {
        what,
        why: why.to_string(),
    }
}

impl MediumDesc {
    /// The density field, or an error naming what is missing.
    pub fn field(&self) -> Result<Arc<dyn Density>, RenderError> {
        self.field
            .clone()
            .ok_or_else(|| missing("medium", "no density field"))
    }

    /// The majorants: the description's, else built from the field.
    pub fn majorants(&self) -> Result<Arc<MajorantGrid>, RenderError> {
        match &self.majorants {
            Some(m) => Ok(m.clone()),
            None => Ok(Arc::new(MajorantGrid::from_field(
                &*self.field()?,
                [self.majorant_bricks; 3],
            )?)),
        }
    }

    /// The pins as an estimator with lookup options `lookup`, in the description's frame
    /// (unplaced where it has a `placement`: [`MediumDesc::place`] places it).
    pub fn pins_estimator(
        &self,
        lookup: SamplerOptions,
    ) -> Result<Arc<dyn TransportEstimator>, RenderError> {
        Ok(self.placed_pins(lookup)?)
    }

    /// The placed pin grid with lookup options `lookup`, as its own type (an estimator that
    /// reads the pins beside the density builds on it), in the description's frame.
    pub fn placed_pins(&self, lookup: SamplerOptions) -> Result<Arc<PinsEstimator>, RenderError> {
        let p = self
            .pins
            .as_ref()
            .ok_or_else(|| missing("medium", "no pin grid"))?;
        Ok(Arc::new(PinsEstimator::new(
            p.grid.clone(),
            p.local_to_world.as_ref(),
            lookup,
        )?))
    }

    /// The CPU renderer's medium for `spec`: the estimator over the density, the pins,
    /// PinMS (the density's ratio tracking for primary rays, pins after the first
    /// scattering), or `pinres` (the density and the bake's control in one estimator);
    /// built in the asset's frame and placed where the description has a `placement`.
    pub fn cpu_medium(
        &self,
        spec: EstimatorSpec,
        lookup: SamplerOptions,
    ) -> Result<Medium, RenderError> {
        self.place(self.frame_medium(spec, lookup)?, lookup)
    }

    /// A medium built in the description's frame (from [`MediumDesc::field`],
    /// [`MediumDesc::majorants`], [`MediumDesc::placed_pins`]) placed in the world by
    /// `placement`, or as it is without one: how an extension's estimator over the
    /// description is placed as the renderer's own are.
    pub fn place(&self, local: Medium, lookup: SamplerOptions) -> Result<Medium, RenderError> {
        match &self.placement {
            Some(m) => crate::instance::place_medium(&local, m, lookup),
            None => Ok(local),
        }
    }

    /// The pins' placement in the world: their own composed with `placement`.
    pub fn world_pins(&self) -> Option<PlacedPins> {
        let p = self.pins.as_ref()?;
        Some(match &self.placement {
            None => p.clone(),
            Some(m) => PlacedPins {
                grid: p.grid.clone(),
                local_to_world: Some(crate::instance::compose(
                    m,
                    &p.local_to_world.unwrap_or(p.grid.desc().local_to_world),
                )),
            },
        })
    }

    /// [`MediumDesc::cpu_medium`] in the description's own frame (unplaced).
    fn frame_medium(
        &self,
        spec: EstimatorSpec,
        lookup: SamplerOptions,
    ) -> Result<Medium, RenderError> {
        if let Some(both) =
            spec.build_pin_controlled(&|| self.field(), &|| self.majorants(), &|| {
                self.placed_pins(lookup)
            })?
        {
            return Ok(Medium::single(both));
        }
        let density = spec.build_density_estimator(&|| self.field(), &|| self.majorants())?;
        Ok(match (density, spec.needs_pins()) {
            (Some(primary), true) => Medium::new(primary, self.pins_estimator(lookup)?),
            (Some(only), false) => Medium::single(only),
            (None, _) => Medium::single(self.pins_estimator(lookup)?),
        })
    }
}

#[cfg(feature = "gpu")]
impl MediumDesc {
    /// The residual control that `spec` reads on the GPU, built exactly as its CPU estimator
    /// builds it (`residual[@min|@mean]`: over the majorant grid at load time; `pinres`: from
    /// the pin file's control section, with the CPU's raising of the majorants and its
    /// choice of the majorants it tracks), or `Ok(None)` for an estimator that reads none.
    /// In the description's own frame (the asset's, where it has a `placement`).
    pub fn gpu_control(&self, spec: EstimatorSpec) -> Result<Option<GpuControl>, RenderError> {
        let take = |t: &ResidualRatioTracking<dyn Density>| {
            let (residual, majorants) = t.grids();
            GpuControl {
                spec,
                residual: residual.clone(),
                controls: t.controls().0.to_vec(),
                majorants: majorants.clone(),
            }
        };
        Ok(match spec {
            EstimatorSpec::ResidualRatioTracking { control } => Some(take(
                &ResidualRatioTracking::new(self.field()?, self.majorants()?, control)?,
            )),
            EstimatorSpec::PinRes => {
                let p = self
                    .pins
                    .as_ref()
                    .ok_or_else(|| missing("medium", "no pin grid (pinres reads its control)"))?;
                let baked = BakedResidualTracking::from_grid(
                    self.field()?,
                    &p.grid,
                    p.local_to_world.as_ref(),
                    self.majorants().ok(),
                )?;
                Some(take(baked.tracking()))
            }
            _ => None,
        })
    }
}

/// The GPU renderer's media for `media`: every pin grid and density they share uploaded
/// once, each instance placed as its CPU estimators are. `spec`: only what that estimator
/// reads (a render); `None`: everything the media have but the residual controls, which are
/// built per estimator ([`gpu_media_for`]).
#[cfg(feature = "gpu")]
pub fn gpu_media<'a>(
    media: &'a [MediumDesc],
    spec: Option<EstimatorSpec>,
    lookup: SamplerOptions,
) -> Result<GpuMedia<'a>, RenderError> {
    match spec {
        Some(s) => gpu_media_for(media, &[s.into()], lookup),
        None => pack_media(media, (true, true, true), &[], lookup),
    }
}

/// The GPU renderer's media for rendering each of `estimators` (the eval renders several
/// estimators with one upload): what any of them reads, with the residual control of each
/// residual estimator among them.
#[cfg(feature = "gpu")]
pub fn gpu_media_for<'a>(
    media: &'a [MediumDesc],
    estimators: &[GpuEstimator],
    lookup: SamplerOptions,
) -> Result<GpuMedia<'a>, RenderError> {
    let needs = (
        estimators.iter().any(|e| e.uses_pins()),
        estimators
            .iter()
            .any(|e| e.spec().is_none_or(|s| s.needs_density())),
        estimators.iter().any(|e| e.uses_majorants()),
    );
    let mut controls: Vec<EstimatorSpec> = Vec::new();
    for s in estimators.iter().filter_map(|e| e.spec()) {
        if matches!(
            s,
            EstimatorSpec::ResidualRatioTracking { .. } | EstimatorSpec::PinRes
        ) && !controls.contains(&s)
        {
            controls.push(s);
        }
    }
    pack_media(media, needs, &controls, lookup)
}

/// What the majorants and controls built for one description depend on, so that the
/// descriptions that share them (a scene's instances of one asset, in the asset's frame)
/// build and upload them once: the field, the majorants given or their brick count, the pins
/// and their placement in the description's frame.
#[cfg(feature = "gpu")]
#[derive(Clone, PartialEq, Eq, Hash)]
struct FrameKey {
    field: usize,
    majorants: usize,
    bricks: u32,
    pins: usize,
    pins_placement: Option<[u64; 12]>,
}

#[cfg(feature = "gpu")]
impl FrameKey {
    fn of(m: &MediumDesc) -> Self {
        let addr = |p: *const ()| p as usize;
        FrameKey {
            field: m
                .field
                .as_ref()
                .map_or(0, |f| addr(Arc::as_ptr(f) as *const ())),
            majorants: m
                .majorants
                .as_ref()
                .map_or(0, |g| addr(Arc::as_ptr(g) as *const ())),
            bricks: m.majorant_bricks,
            pins: m
                .pins
                .as_ref()
                .map_or(0, |p| addr(Arc::as_ptr(&p.grid) as *const ())),
            pins_placement: m
                .pins
                .as_ref()
                .and_then(|p| p.local_to_world)
                .map(|l| l.map(f64::to_bits)),
        }
    }
}

#[cfg(feature = "gpu")]
fn pack_media<'a>(
    media: &'a [MediumDesc],
    (pins, density, majorants): (bool, bool, bool),
    controls: &[EstimatorSpec],
    lookup: SamplerOptions,
) -> Result<GpuMedia<'a>, RenderError> {
    use std::collections::HashMap;
    let mut out = GpuMedia::default();
    let mut grids: Vec<&'a Arc<PinGrid>> = Vec::new();
    let mut densities: Vec<&'a Arc<GpuDensity>> = Vec::new();
    // Built once per frame (an asset shared by many instances), then shared by `Arc`: the
    // majorants and controls are pure functions of the key, so sharing changes no value.
    type Built = (Option<Arc<MajorantGrid>>, Vec<Arc<GpuControl>>);
    let mut built: HashMap<FrameKey, Built> = HashMap::new();
    for m in media {
        let gpu_pins = match (m.world_pins(), pins) {
            (Some(p), true) => {
                let grid = grids
                    .iter()
                    .position(|g| Arc::ptr_eq(g, &p.grid))
                    .unwrap_or_else(|| {
                        let own = &m.pins.as_ref().expect("world pins are the pins").grid;
                        grids.push(own);
                        out.grids.push(&**own);
                        grids.len() - 1
                    });
                Some(GpuPins {
                    grid,
                    local_to_world: p.local_to_world,
                    options: lookup,
                })
            }
            _ => None,
        };
        let placed = match (&m.gpu_density, density) {
            (Some(d), true) => {
                let index = densities
                    .iter()
                    .position(|x| Arc::ptr_eq(x, d))
                    .unwrap_or_else(|| {
                        densities.push(d);
                        out.densities.push((**d).clone());
                        densities.len() - 1
                    });
                let key = FrameKey::of(m);
                let (maj, ctl) = match built.get(&key) {
                    Some(b) => b.clone(),
                    None => {
                        let maj = if majorants {
                            Some(m.majorants()?)
                        } else {
                            None
                        };
                        // The controls see the majorants built here (as one description
                        // would build them itself).
                        let with = MediumDesc {
                            majorants: maj.clone().or_else(|| m.majorants.clone()),
                            ..m.clone()
                        };
                        let ctl = controls
                            .iter()
                            .filter_map(|&s| with.gpu_control(s).transpose())
                            .map(|c| c.map(Arc::new))
                            .collect::<Result<Vec<_>, _>>()?;
                        built.insert(key, (maj.clone(), ctl.clone()));
                        (maj, ctl)
                    }
                };
                Some(GpuPlacedDensity {
                    density: index,
                    translation: m.translation,
                    placement: m.placement,
                    majorants: maj,
                    controls: ctl,
                })
            }
            _ => None,
        };
        out.media.push(GpuMedium {
            pins: gpu_pins,
            density: placed,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::VoxelGrid;
    use pin_format::Directions;
    use pinrt::testing::random_grid;

    fn grid() -> Arc<PinGrid> {
        let owned = random_grid(Directions::THESIS_DEFAULT, [3, 3, 3], 1, false, 5);
        Arc::new(PinGrid::from_bytes(owned.to_bytes().unwrap()).unwrap())
    }

    /// Two instances sharing one grid and one density, one with its own grid.
    fn media() -> (Vec<MediumDesc>, Arc<PinGrid>) {
        let shared = grid();
        let voxels = VoxelGrid::new([2; 3], [0.0; 3], [0.5; 3], vec![1.0; 8]).unwrap();
        #[cfg(feature = "gpu")]
        let density = Arc::new(GpuDensity::from_voxel_grid(voxels.clone()).unwrap());
        let field: Arc<dyn Density> = Arc::new(voxels);
        let desc = |pins: Arc<PinGrid>, t: f64| MediumDesc {
            field: Some(field.clone()),
            majorant_bricks: 2,
            pins: Some(PlacedPins {
                grid: pins,
                local_to_world: Some([1.0, 0.0, 0.0, t, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
            }),
            #[cfg(feature = "gpu")]
            gpu_density: Some(density.clone()),
            translation: [t, 0.0, 0.0],
            ..MediumDesc::default()
        };
        let own = grid();
        (
            vec![
                desc(shared.clone(), 0.0),
                desc(own, 2.0),
                desc(shared.clone(), 4.0),
            ],
            shared,
        )
    }

    /// Shared grids and densities are uploaded once, each instance keeps its placement, and
    /// an estimator's media carry only what it reads.
    #[cfg(feature = "gpu")]
    #[test]
    fn gpu_packing_shares_and_places() {
        let (descs, shared) = media();
        let all = gpu_media(&descs, None, SamplerOptions::default()).unwrap();
        assert_eq!(all.grids.len(), 2);
        assert!(std::ptr::eq(all.grids[0], &*shared));
        assert_eq!(all.densities.len(), 1);
        let pins: Vec<usize> = all
            .media
            .iter()
            .map(|m| m.pins.as_ref().unwrap().grid)
            .collect();
        assert_eq!(pins, [0, 1, 0]);
        let t: Vec<f64> = all
            .media
            .iter()
            .map(|m| m.density.as_ref().unwrap().translation[0])
            .collect();
        assert_eq!(t, [0.0, 2.0, 4.0]);
        assert!(all.media.iter().all(|m| {
            m.density.as_ref().unwrap().majorants.is_some()
                && m.pins.as_ref().unwrap().local_to_world.unwrap()[3]
                    == m.density.as_ref().unwrap().translation[0]
        }));
        let ratio = gpu_media(
            &descs,
            Some(EstimatorSpec::RatioTracking),
            SamplerOptions::default(),
        )
        .unwrap();
        assert!(ratio.grids.is_empty() && ratio.media.iter().all(|m| m.pins.is_none()));
        let pins = gpu_media(&descs, Some(EstimatorSpec::Pins), SamplerOptions::default()).unwrap();
        assert!(pins.densities.is_empty() && pins.media.iter().all(|m| m.density.is_none()));
        let march = EstimatorSpec::RayMarching { rel_step: 0.1 };
        let march = gpu_media(&descs, Some(march), SamplerOptions::default()).unwrap();
        assert!(
            march
                .media
                .iter()
                .all(|m| m.density.as_ref().unwrap().majorants.is_none())
        );
    }

    /// The CPU medium: PinMS pairs the density's tracker with the pins; a description
    /// without pins or density is an error, not a panic.
    #[test]
    fn cpu_medium_follows_the_spec() {
        let (descs, _) = media();
        let opts = SamplerOptions::default();
        let m = descs[1].cpu_medium(EstimatorSpec::PinMs, opts).unwrap();
        assert_eq!(m.secondary.name(), "pins");
        assert_ne!(m.primary.name(), "pins");
        // Placed by the description: the pins' box moved with the instance.
        assert!((m.secondary.bounds().unwrap().0[0] - 2.0).abs() < 1e-3);
        let no_pins = MediumDesc {
            pins: None,
            ..descs[0].clone()
        };
        assert!(no_pins.cpu_medium(EstimatorSpec::Pins, opts).is_err());
        assert!(
            no_pins
                .cpu_medium(EstimatorSpec::DeltaTracking, opts)
                .is_ok()
        );
        let no_field = MediumDesc {
            field: None,
            ..descs[0].clone()
        };
        assert!(
            no_field
                .cpu_medium(EstimatorSpec::RatioTracking, opts)
                .is_err()
        );
        assert!(no_field.cpu_medium(EstimatorSpec::Pins, opts).is_ok());
    }
}
