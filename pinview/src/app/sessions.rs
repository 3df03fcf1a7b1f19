//! The renderers and sessions on screen: the shown estimator's, the second side's and the
//! reference's. Each is built off the window's thread ([`BuildJob`]: the upload and the
//! pipeline compile) when its estimator or the medium changes, and swapped in when ready;
//! until then the window keeps painting the image it had. A change of the view only resets
//! a session (a buffer clear), on the window's thread.

use anyhow::Result;
use pinrender::render::EstimatorSpec;

use super::Viewer;
use super::window::write_image;
use crate::error_view::{self, ErrorTrack};
use crate::open::Medium;

impl Viewer {
    /// The estimator shown now: the one asked for once the medium answers it, else the
    /// medium's default (ratio while a volume's pins bake).
    pub(super) fn estimator_now(&self) -> EstimatorSpec {
        if let Some((cheap, _)) = self.interim {
            return cheap;
        }
        if self.medium.estimators().contains(&self.wanted) {
            self.wanted
        } else {
            self.medium.default_estimator()
        }
    }

    /// Whether a bake or re-bake runs in the background, which may bring estimators the
    /// medium does not answer yet (a volume's pins).
    pub(super) fn baking(&self) -> bool {
        self.bakes.running()
    }

    /// Whether the estimator asked for is not shown yet but will be once the running bake
    /// is in (a scripted run waits for it). Anything else the medium cannot answer (a frame
    /// of a sequence without the density the first one had) falls back to the medium's
    /// default, with a note.
    pub(super) fn awaiting_wanted(&self) -> bool {
        self.estimator_now() != self.wanted && self.baking()
    }

    /// Whether the medium answers `e` on a second side (one medium, not a scene).
    pub(super) fn compare_answered(&self, e: EstimatorSpec) -> bool {
        self.medium.scene().is_none() && self.medium.estimators().contains(&e)
    }

    /// Whether the second side asked for is not in yet but will come: being built, or
    /// waiting for the running bake. A medium that cannot answer it drops it, with a note.
    pub(super) fn awaiting_compare(&self) -> bool {
        self.compare_wanted.is_some_and(|e| {
            self.compare.estimator() != Some(e) && (self.compare_answered(e) || self.baking())
        })
    }

    /// Notes an estimator asked for that the medium cannot answer (and no bake will bring):
    /// `shown` is what stands in its place.
    fn note_unanswered(&mut self, asked: EstimatorSpec, shown: &str) {
        let why = if asked.needs_density() && !self.medium.has_density() {
            format!("no embedded density, which {asked} needs")
        } else {
            format!("{asked} is not answered by it")
        };
        let note = format!("{}: {why}; {shown}", self.medium.path.display());
        self.note(note);
    }

    /// Whether the shown estimator's renderer is being built, or the default's while the
    /// interim one is shown (the panel says "compiling").
    pub(super) fn compiling(&self) -> Option<EstimatorSpec> {
        self.main.building().or_else(|| self.next.building())
    }

    /// Whether the interim estimator is shown and the default will replace it (a scripted
    /// run renders its passes on the default).
    pub(super) fn switching(&self) -> bool {
        self.interim.is_some()
    }

    /// The first look of a pin file: while the interim (cheapest) estimator is shown, the
    /// default's renderer is built once the interim one has shown its first image, and
    /// swapped in as the shown side when ready (its preview, or the interim image until its
    /// first pass: never a blank image). An estimator chosen meanwhile ends the switch.
    fn switch_when_ready(&mut self) -> Result<()> {
        let Some((cheap, target)) = self.interim else {
            return Ok(());
        };
        if self.wanted != target {
            self.interim = None;
            self.next.stop(&mut self.retired);
            return Ok(());
        }
        if let Some(done) = self.next.take_built(target, &mut self.retired) {
            let built = done?;
            self.interim = None;
            self.estimator_switch_s = Some(self.clock.now());
            self.main.stop(&mut self.retired);
            self.install_main(target, built)?;
            // The accumulation started again: a scripted run's passes count from here.
            if let Some(s) = &mut self.script
                && s.base.is_some()
            {
                s.base = Some(0);
            }
            self.toasts.say(format!(
                "{target} shown: its pipeline is ready ({cheap} until then)"
            ));
            return Ok(());
        }
        if self.next.pending.is_none() && self.first_image_s.is_some() {
            let media = self.medium.media_job(target)?;
            self.next
                .spawn(&self.gpu, media, &self.view, self.generation)?;
        }
        Ok(())
    }

    /// Makes `built` (of `est`) the shown side, with its coarse preview where it has one.
    fn install_main(&mut self, est: EstimatorSpec, built: crate::build::Built) -> Result<()> {
        let preview = self.main.install(
            est,
            built,
            &self.view.scene(),
            self.view.seed,
            self.generation,
        )?;
        self.coarse.forget();
        self.fit_main_image();
        // The coarse preview of this view stands until the first whole pass is in.
        if let Some(rgba) = preview {
            let t = &self.images.main;
            write_image(&self.gpu.queue, &t.texture, t.size.0, t.size.1, &rgba);
            self.shown.get_or_insert(super::events::Shown::Preview);
            if self.first_preview_s.is_none() {
                self.first_preview_s = Some(self.clock.now());
            }
        }
        Ok(())
    }

    /// Starts building the renderer of the current estimator (when it changed), swaps in a
    /// finished one, and resets the session when the view changed; then the same for the
    /// second side and the reference.
    pub(super) fn ensure_session(&mut self) -> Result<()> {
        if self.input.dirty {
            self.generation += 1;
        }
        let switched = self.interim.is_some();
        self.switch_when_ready()?;
        let switched = switched && self.interim.is_none() && self.main.live.is_some();
        let est = self.estimator_now();
        self.view.estimator = est;
        if est != self.wanted && !self.baking() && self.interim.is_none() {
            self.note_unanswered(self.wanted, &format!("{est} shown instead"));
        }
        if let Some(e) = self.compare_wanted
            && !self.compare_answered(e)
            && self.medium.scene().is_none()
            && !self.baking()
        {
            self.note_unanswered(e, "no second side");
        }
        // The second side starts again with the first, so both have spent equal time.
        let mut restart = switched;
        if let Some(done) = self.main.take_built(est, &mut self.retired) {
            let built = done?;
            if self.clock.marks.upload == 0.0 {
                let since = |t: std::time::Instant| {
                    t.saturating_duration_since(self.clock.started)
                        .as_secs_f64()
                };
                self.clock.marks.upload = since(built.uploaded);
                self.clock.marks.pipeline = since(built.compiled);
                self.warm_up_s = Some(
                    built
                        .warmed
                        .saturating_duration_since(built.compiled)
                        .as_secs_f64(),
                );
            }
            self.install_main(est, built)?;
            restart = true;
        }
        if self.main.estimator() != Some(est) && self.main.pending.is_none() {
            // The old session stops; its image stays on screen until the new one's first pass.
            self.main.live = None;
            self.coarse.forget();
            // Refused here (before the first frame) where the medium cannot answer.
            let media = self.medium.media_job(est)?;
            if self.painted() {
                self.main
                    .spawn(&self.gpu, media, &self.view, self.generation)?;
            }
        }
        if self.input.dirty && self.main.reset(&self.view.scene(), self.view.seed)? {
            self.fit_main_image();
            restart = true;
        }
        self.input.dirty = false;
        if restart {
            self.error.clear(0);
        }
        self.ensure_compare(restart)?;
        self.ensure_reference(restart)
    }

    /// The displayed image at the shown session's size (it was resized).
    fn fit_main_image(&mut self) {
        let Some(s) = self.main.session() else {
            return;
        };
        let size = (s.width(), s.height());
        if self.images.main.size != size {
            self.images.main = Self::make_target(
                &self.gpu.device,
                &self.egui_renderer,
                size.0,
                size.1,
                Some(self.images.main.id),
            );
        }
    }

    /// Starts the reference when the error view is on and the medium has a density (built
    /// off the window's thread), and restarts it with the first side.
    pub(super) fn ensure_reference(&mut self, restart: bool) -> Result<()> {
        if !self.error_on || error_view::no_reference_reason(&self.medium).is_some() {
            self.reference.stop(&mut self.retired);
            return Ok(());
        }
        let scene = self.view.scene();
        let seed = self.view.seed;
        let est = error_view::REFERENCE_ESTIMATOR;
        if let Some(done) = self.reference.take_built(est, &mut self.retired) {
            self.reference
                .install(est, done?, &scene, seed, self.generation)?;
            self.error = ErrorTrack::default();
        }
        if self.reference.live.is_some() {
            if restart {
                self.reference.reset(&scene, seed)?;
                self.error = ErrorTrack::default();
            }
        } else if self.reference.pending.is_none() && self.painted() {
            let media = self.medium.media_job(est)?;
            self.reference
                .spawn(&self.gpu, media, &self.view, self.generation)?;
        }
        Ok(())
    }

    /// Starts the second side when one is asked for and the medium answers it (a volume's
    /// pins estimators once baked; built off the window's thread), and restarts it with the
    /// first.
    pub(super) fn ensure_compare(&mut self, restart: bool) -> Result<()> {
        let Some(est) = self.compare_wanted.filter(|&e| self.compare_answered(e)) else {
            self.compare.stop(&mut self.retired);
            return Ok(());
        };
        let scene = self.view.scene();
        let seed = self.view.seed;
        if let Some(done) = self.compare.take_built(est, &mut self.retired) {
            self.compare
                .install(est, done?, &scene, seed, self.generation)?;
            self.error.clear(1);
        }
        if self.compare.estimator() != Some(est) {
            self.compare.live = None;
            if self.compare.pending.is_none() && self.painted() {
                let media = self.medium.media_job(est)?;
                self.compare
                    .spawn(&self.gpu, media, &self.view, self.generation)?;
            }
            return Ok(());
        }
        if restart {
            self.compare.reset(&scene, seed)?;
        }
        let size = (self.view.width, self.view.height);
        if self.images.compare.as_ref().is_none_or(|t| t.size != size) {
            let old = self.images.compare.as_ref().map(|t| t.id);
            self.images.compare = Some(Self::make_target(
                &self.gpu.device,
                &self.egui_renderer,
                size.0,
                size.1,
                old,
            ));
        }
        Ok(())
    }

    /// Replaces the medium (a frame of a sequence, a dropped file, finished pins); builds
    /// for the old one are dropped.
    pub(super) fn set_medium(&mut self, medium: Medium) {
        self.medium = medium;
        self.verify = crate::verify::Verify::start(&self.medium);
        self.overlays.held = None;
        self.coarse.forget();
        self.interim = None;
        for side in [
            &mut self.main,
            &mut self.compare,
            &mut self.reference,
            &mut self.next,
        ] {
            side.stop(&mut self.retired);
        }
    }

    /// Whether the window has painted its first frame: builds start after it. That frame
    /// compiles the window's own shaders (egui's; on lavapipe LLVM at its first draw, on the
    /// window's queue), and builds started beside it would share the cores with it and hold
    /// the window's first frame back by as much (measured 1.0-1.9 s on 2 loaded cores with
    /// Mesa's shader cache off).
    fn painted(&self) -> bool {
        self.pacer.frames() >= 2
    }

    /// Forgets the retired builds whose workers have ended.
    pub(super) fn prune_retired(&mut self) {
        self.retired.retain(|j| !j.is_finished());
    }
}
