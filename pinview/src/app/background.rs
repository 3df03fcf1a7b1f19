//! Background work the window polls each frame: the first bake of a volume's pins, a
//! re-bake at another density scale, a sequence's next frame, a dropped file.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Result, anyhow};

use super::Viewer;
use crate::open::{BakeJob, PreviewBake};

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
        self.rebake = Some((scale, job));
        Ok(())
    }

    /// Background work: the bake, the re-bake, the sequence, dropped files.
    pub(super) fn poll_background(&mut self, ctx: &egui::Context) -> Result<()> {
        if let Some(warning) = self.verify.as_mut().and_then(crate::verify::Verify::poll) {
            self.note(warning);
        }
        if let Some((scale, job)) = &mut self.rebake
            && let Some(done) = job.finished()
        {
            let scale = *scale;
            self.rebake = None;
            match done {
                Ok(done) => {
                    // The first bake of the old scale is of no use any more.
                    self.bake = None;
                    self.set_medium(done.medium);
                    self.density_scale = scale;
                    if self.args.estimator.is_none() {
                        self.wanted = self.medium.default_estimator();
                    }
                    self.status = match &done.gpu_refused {
                        None => format!("re-baked on the GPU at density scale {scale}"),
                        Some(why) => {
                            format!("re-baked on the CPU at density scale {scale} ({why})")
                        }
                    };
                    self.rebaked = Some((scale, done.backend, done.gpu_refused));
                }
                Err(e) => {
                    if self.args.frames.is_some() {
                        return Err(e);
                    }
                    self.status = format!("re-bake failed: {e}");
                }
            }
        }
        if let Some(job) = &mut self.bake
            && let Some(done) = job.finished()
        {
            self.bake = None;
            match done {
                Ok(grid) => {
                    self.medium.set_pins(Arc::new(grid));
                    if self.args.estimator.is_none() {
                        self.wanted = self.medium.default_estimator();
                    }
                    self.status = "pins baked: every estimator is available".into();
                }
                Err(e) => {
                    if self.wanted.needs_pins() {
                        return Err(anyhow!("{}: baking pins: {e}", self.medium.path.display()));
                    }
                    self.status = format!("baking pins failed: {e}");
                }
            }
        }
        let frame_passes = self.args.frame_passes;
        let done = self.session.as_ref().map_or(0, |s| s.passes());
        // A scripted run plays the sequence once and stops on its last frame.
        let scripted = self.args.frames.is_some();
        let next = match &self.sequence {
            Some(s)
                if s.playing
                    && !self.paused
                    && done >= frame_passes
                    && s.len() > 1
                    && !(scripted && s.current + 1 == s.len()) =>
            {
                Some((s.current + 1) % s.len())
            }
            _ => None,
        };
        if let Some(i) = next {
            self.go_to_frame(i)?;
            self.play_steps.push(std::time::Instant::now());
        }
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
                    self.bake = if m.is_volume {
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
                    self.sequence = None;
                    self.set_medium(m);
                    self.view.origin = o;
                    self.view.target = t;
                    self.status = format!("opened {}", path.display());
                }
                // A scene's messages name the file and the JSON path themselves.
                Err(e) if crate::open::is_scene_file(&path) => self.status = e.to_string(),
                Err(e) => self.status = format!("{}: {e}", path.display()),
            }
        }
        Ok(())
    }

    pub(super) fn go_to_frame(&mut self, i: usize) -> Result<()> {
        let Some(s) = &mut self.sequence else {
            return Ok(());
        };
        let m = s.go_to(i)?;
        self.frames_played.push(s.frames[s.current].0);
        self.set_medium(m);
        Ok(())
    }
}
