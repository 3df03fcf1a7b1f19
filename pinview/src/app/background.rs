//! Background work the window polls each frame: the first bake of a volume's pins, a
//! re-bake at another density scale, a playing sequence's next frame, a dropped file.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Result, anyhow};

use super::Viewer;
use crate::args::ViewArgs;
use crate::open::{BakeJob, Medium, PreviewBake, Rebaked};

/// A volume's bakes: the first bake of its pins, a re-bake at another density scale (its
/// scale and job), the density scale as shown, and the last re-bake swapped in (its scale,
/// backend and why the GPU refused, if it did).
pub struct Bakes {
    pub bake: Option<BakeJob>,
    pub rebake: Option<(f64, BakeJob<Rebaked>)>,
    pub density_scale: f64,
    pub rebaked: Option<(f64, &'static str, Option<String>)>,
}

impl Bakes {
    /// The first bake started for a volume (nothing to bake for a pin file or a scene).
    pub fn new(medium: &Medium, args: &ViewArgs) -> Result<Self> {
        let bake = if medium.is_volume {
            Some(BakeJob::start(medium, args.preview_bake())?)
        } else {
            None
        };
        Ok(Self {
            bake,
            rebake: None,
            density_scale: args.read.density_scale.get(),
            rebaked: None,
        })
    }

    /// Whether a bake or re-bake runs in the background.
    pub fn running(&self) -> bool {
        self.bake.is_some() || self.rebake.is_some()
    }
}

impl Viewer {
    /// Re-bakes the shown volume at density scale `scale` on the GPU in the background; the
    /// current medium stays on screen until the new one is ready.
    pub(super) fn start_rebake(&mut self, scale: f64) -> Result<()> {
        let mut read = self.args.read.clone();
        read.density_scale = pin_volume::DensityScale::new(scale).map_err(|e| anyhow!("{e}"))?;
        let args = pinrender::volume::VolumeArgs {
            volume: Some(self.medium.path.clone()),
            read,
        };
        let bake = PreviewBake {
            seed: self.view.seed,
            ..self.args.preview_bake()
        };
        let job = BakeJob::rebake(self.medium.path.clone(), args, bake)?;
        self.bakes.rebake = Some((scale, job));
        Ok(())
    }

    /// Background work: the bake, the re-bake, the sequence, dropped files.
    pub(super) fn poll_background(&mut self, ctx: &egui::Context) -> Result<()> {
        if let Some(warning) = self.verify.as_mut().and_then(crate::verify::Verify::poll) {
            self.note(warning);
        }
        if let Some((scale, job)) = &mut self.bakes.rebake
            && let Some(done) = job.finished()
        {
            let scale = *scale;
            self.bakes.rebake = None;
            match done {
                Ok(done) => {
                    // The first bake of the old scale is of no use any more.
                    self.bakes.bake = None;
                    self.set_medium(done.medium);
                    self.bakes.density_scale = scale;
                    if self.args.estimator.is_none() {
                        self.wanted = self.medium.default_estimator();
                    }
                    self.toasts.say(match &done.gpu_refused {
                        None => format!("re-baked on the GPU at density scale {scale}"),
                        Some(why) => {
                            format!("re-baked on the CPU at density scale {scale} ({why})")
                        }
                    });
                    self.bakes.rebaked = Some((scale, done.backend, done.gpu_refused));
                }
                Err(e) => {
                    if self.args.frames.is_some() {
                        return Err(e);
                    }
                    self.toasts.say(format!("re-bake failed: {e}"));
                }
            }
        }
        if let Some(job) = &mut self.bakes.bake
            && let Some(done) = job.finished()
        {
            self.bakes.bake = None;
            match done {
                Ok(grid) => {
                    self.medium.set_pins(Arc::new(grid));
                    if self.args.estimator.is_none() {
                        self.wanted = self.medium.default_estimator();
                    }
                    self.toasts.say("pins baked: every estimator is available");
                }
                Err(e) => {
                    if self.wanted.needs_pins() {
                        return Err(anyhow!("{}: baking pins: {e}", self.medium.path.display()));
                    }
                    self.toasts.say(format!("baking pins failed: {e}"));
                }
            }
        }
        self.step_playback()?;
        let dropped: Vec<PathBuf> = ctx.input(|i| {
            i.raw
                .dropped_files
                .iter()
                .map(|f| f.path().to_path_buf())
                .collect()
        });
        if let Some(path) = dropped.into_iter().next() {
            match (self.opener)(&path) {
                Ok(m) => {
                    let (o, t) = m.home();
                    self.bakes.bake = if m.is_volume {
                        BakeJob::start(
                            &m,
                            PreviewBake {
                                seed: self.view.seed,
                                ..self.args.preview_bake()
                            },
                        )
                        .ok()
                    } else {
                        None
                    };
                    self.playback.sequence = None;
                    self.set_medium(m);
                    // The new medium's home is where "reset view" returns.
                    self.opened_camera = None;
                    self.view.origin = o;
                    self.view.target = t;
                    let opened = std::path::absolute(&path).unwrap_or(path);
                    self.toasts.say(format!("opened {}", opened.display()));
                }
                // A scene's messages name the file and the JSON path themselves.
                Err(e) if crate::open::is_scene_file(&path) => self.toasts.say(e.to_string()),
                Err(e) => self.toasts.say(format!("{}: {e}", path.display())),
            }
        }
        Ok(())
    }
}
