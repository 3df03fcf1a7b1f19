//! The renderers and sessions on screen: the shown estimator's, the second side's and the
//! reference's. Each is built off the window's thread ([`BuildJob`]: the upload and the
//! pipeline compile) when its estimator or the medium changes, and swapped in when ready;
//! until then the window keeps painting the image it had. A change of the view only resets
//! a session (a buffer clear), on the window's thread.

use anyhow::Result;
use pinrender::gpu_render::{GpuRenderer, GpuScene, GpuSession};
use pinrender::render::EstimatorSpec;

use super::Viewer;
use super::window::write_image;
use crate::build::{BuildJob, Built};
use crate::compare::{self, CompareSide};
use crate::error_view::{self, ErrorTrack, Reference};
use crate::open::Medium;

/// A pending build's result, where it is the one still wanted (`want`): a job for another
/// estimator is retired (its worker finishes alone), a finished one is taken.
fn take_built(
    slot: &mut Option<BuildJob>,
    want: EstimatorSpec,
    retired: &mut Vec<BuildJob>,
) -> Option<Result<Built>> {
    if slot.as_ref().is_some_and(|j| j.estimator != want) {
        retired.extend(slot.take());
    }
    let done = slot.as_mut()?.poll()?;
    *slot = None;
    Some(done)
}

/// `session` started again on `scene`: reset in place at its size, a new session of the
/// renderer at another (the image was resized).
fn restart_session(
    renderer: &GpuRenderer,
    mut session: GpuSession,
    est: EstimatorSpec,
    scene: &GpuScene,
    seed: u64,
) -> Result<GpuSession> {
    if (session.width(), session.height()) == (scene.camera.width, scene.camera.height) {
        session.reset(scene, seed)?;
        Ok(session)
    } else {
        renderer
            .session(scene, est, seed)
            .map_err(|e| anyhow::anyhow!("{e}"))
    }
}

impl Viewer {
    /// The estimator shown now: the one asked for once the medium answers it, else the
    /// medium's default (ratio while a volume's pins bake).
    pub(super) fn estimator_now(&self) -> EstimatorSpec {
        if self.medium.estimators().contains(&self.wanted) {
            self.wanted
        } else {
            self.medium.default_estimator()
        }
    }

    /// Whether a bake or re-bake runs in the background, which may bring estimators the
    /// medium does not answer yet (a volume's pins).
    pub(super) fn baking(&self) -> bool {
        self.bake.is_some() || self.rebake.is_some()
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
            self.compare.as_ref().map(|c| c.estimator) != Some(e)
                && (self.compare_answered(e) || self.baking())
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

    /// Whether the shown estimator's renderer is being built (the panel says "compiling").
    pub(super) fn compiling(&self) -> Option<EstimatorSpec> {
        self.pending.as_ref().map(|j| j.estimator)
    }

    /// Starts building the renderer of the current estimator (when it changed), swaps in a
    /// finished one, and resets the session when the view changed; then the same for the
    /// second side and the reference.
    pub(super) fn ensure_session(&mut self) -> Result<()> {
        let est = self.estimator_now();
        self.view.estimator = est;
        if est != self.wanted && !self.baking() {
            self.note_unanswered(self.wanted, &format!("{est} shown instead"));
        }
        if let Some(e) = self.compare_wanted
            && !self.compare_answered(e)
            && self.medium.scene().is_none()
            && !self.baking()
        {
            self.note_unanswered(e, "no second side");
        }
        if self.dirty {
            self.generation += 1;
        }
        // The second side starts again with the first, so both have spent equal time.
        let mut restart = false;
        if let Some(done) = take_built(&mut self.pending, est, &mut self.retired) {
            let mut built = done?;
            if built.generation != self.generation {
                built.session = restart_session(
                    &built.renderer,
                    built.session,
                    est,
                    &self.view.scene(),
                    self.view.seed,
                )?;
            }
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
            let size = (built.session.width(), built.session.height());
            let fresh = built.generation == self.generation;
            self.renderer = Some((est, built.renderer));
            self.coarse = None;
            self.session = Some(built.session);
            self.relay = built.relay;
            self.render_seconds = 0.0;
            self.first_clock = compare::PassClock::default();
            restart = true;
            if self.target.size != size {
                self.target = Self::make_target(
                    &self.gpu.device,
                    &self.egui_renderer,
                    size.0,
                    size.1,
                    Some(self.target.id),
                );
            }
            // The coarse preview of this view stands until the first whole pass is in.
            if let Some(rgba) = built.preview.filter(|_| fresh) {
                let t = &self.target;
                write_image(&self.gpu.queue, &t.texture, t.size.0, t.size.1, &rgba);
                self.shown.get_or_insert(super::events::Shown::Preview);
                if self.first_preview_s.is_none() {
                    self.first_preview_s = Some(self.clock.now());
                }
            }
        }
        let current = self.renderer.as_ref().is_some_and(|(e, _)| *e == est);
        if !current && self.pending.is_none() {
            // The old session stops; its image stays on screen until the new one's first pass.
            self.session = None;
            self.renderer = None;
            self.relay = None;
            self.coarse = None;
            // Refused here (before the first frame) where the medium cannot answer.
            let media = self.medium.media_job(est)?;
            if self.painted() {
                self.pending = Some(BuildJob::spawn(
                    &self.gpu,
                    media,
                    self.view.scene(),
                    self.view.seed,
                    self.view.exposure,
                    self.generation,
                )?);
            }
        }
        if self.dirty
            && let Some(mut s) = self.session.take()
        {
            let scene = self.view.scene();
            s = match &self.renderer {
                Some((_, renderer)) => restart_session(renderer, s, est, &scene, self.view.seed)?,
                None => {
                    s.reset(&scene, self.view.seed)?;
                    s
                }
            };
            let size = (s.width(), s.height());
            self.session = Some(s);
            if self.target.size != size {
                self.target = Self::make_target(
                    &self.gpu.device,
                    &self.egui_renderer,
                    size.0,
                    size.1,
                    Some(self.target.id),
                );
            }
            self.render_seconds = 0.0;
            self.first_clock = compare::PassClock::default();
            restart = true;
        }
        self.dirty = false;
        if restart {
            self.error.clear(0);
        }
        self.ensure_compare(restart)?;
        self.ensure_reference(restart)
    }

    /// Starts the reference when the error view is on and the medium has a density (built
    /// off the window's thread), and restarts it with the first side.
    pub(super) fn ensure_reference(&mut self, restart: bool) -> Result<()> {
        if !self.error_on || error_view::no_reference_reason(&self.medium).is_some() {
            self.reference = None;
            self.retired.extend(self.reference_pending.take());
            return Ok(());
        }
        let scene = self.view.scene();
        let seed = self.view.seed;
        let est = error_view::REFERENCE_ESTIMATOR;
        if let Some(done) = take_built(&mut self.reference_pending, est, &mut self.retired) {
            let built = done?;
            let mut r = Reference::from_built(built.renderer, built.session);
            if built.generation != self.generation {
                r.reset(&scene, seed)?;
            }
            self.reference = Some(r);
            self.error = ErrorTrack::default();
        }
        let painted = self.painted();
        match &mut self.reference {
            Some(r) if restart => {
                r.reset(&scene, seed)?;
                self.error = ErrorTrack::default();
            }
            Some(_) => {}
            None if self.reference_pending.is_none() && painted => {
                let media = self.medium.media_job(est)?;
                self.reference_pending = Some(BuildJob::spawn(
                    &self.gpu,
                    media,
                    scene,
                    seed ^ error_view::REFERENCE_SEED_XOR,
                    self.view.exposure,
                    self.generation,
                )?);
            }
            None => {}
        }
        Ok(())
    }

    /// Starts the second side when one is asked for and the medium answers it (a volume's
    /// pins estimators once baked; built off the window's thread), and restarts it with the
    /// first.
    pub(super) fn ensure_compare(&mut self, restart: bool) -> Result<()> {
        let Some(est) = self
            .compare_wanted
            .filter(|e| self.medium.scene().is_none() && self.medium.estimators().contains(e))
        else {
            self.compare = None;
            self.retired.extend(self.compare_pending.take());
            return Ok(());
        };
        let scene = self.view.scene();
        let seed = self.view.seed;
        if let Some(done) = take_built(&mut self.compare_pending, est, &mut self.retired) {
            let built = done?;
            let mut side = CompareSide::from_built(est, built.renderer, built.session);
            side.relay = built.relay;
            if built.generation != self.generation {
                side.reset(&scene, seed)?;
            }
            self.error.clear(1);
            self.compare = Some(side);
        }
        match &mut self.compare {
            Some(c) if c.estimator == est => {
                if restart {
                    c.reset(&scene, seed)?;
                }
            }
            _ => {
                self.compare = None;
                if self.compare_pending.is_none() && self.painted() {
                    let media = self.medium.media_job(est)?;
                    self.compare_pending = Some(BuildJob::spawn(
                        &self.gpu,
                        media,
                        scene,
                        seed,
                        self.view.exposure,
                        self.generation,
                    )?);
                }
                return Ok(());
            }
        }
        let size = (self.view.width, self.view.height);
        if self.compare_target.as_ref().is_none_or(|t| t.size != size) {
            let old = self.compare_target.as_ref().map(|t| t.id);
            self.compare_target = Some(Self::make_target(
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
        self.held = None;
        self.renderer = None;
        self.coarse = None;
        self.session = None;
        self.relay = None;
        self.compare = None;
        self.reference = None;
        let pending = [
            self.pending.take(),
            self.compare_pending.take(),
            self.reference_pending.take(),
        ];
        self.retired.extend(pending.into_iter().flatten());
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
