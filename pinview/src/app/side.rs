//! One side of the image: an estimator's renderer and progressive session, built off the
//! window's thread (`crate::build`) and swapped in when ready, with the time its passes took.
//! The shown estimator, the split view's second estimator and the error view's reference
//! are each a [`Side`]; which estimator each wants and when it restarts is `sessions`'.

use std::time::Duration;

use anyhow::{Result, anyhow};
use pinrender::gpu_render::{GpuRenderer, GpuScene, GpuSession, GpuToneMap};
use pinrender::render::EstimatorSpec;

use super::window::{Target, show};
use crate::build::{BuildJob, Built, Gpu, Relay};
use crate::compare::{self, PassClock, SideTime};
use crate::open::MediaJob;

/// A built renderer of one estimator and its session.
pub struct Live {
    pub estimator: EstimatorSpec,
    pub renderer: GpuRenderer,
    pub session: GpuSession,
    /// The tone map on the renderer's own device, where it has one (`crate::build`).
    pub relay: Option<Relay>,
}

/// A side: its live renderer and session, the build of the one it wants next, and the
/// time its passes took.
pub struct Side {
    /// Flipped into the view's seed (the reference's noise is independent of the estimates').
    seed_xor: u64,
    pub live: Option<Live>,
    /// The renderer and session being built; what is shown stays until they are in.
    pub pending: Option<BuildJob>,
    /// Wall time spent adding the live session's passes (the time where the device has no
    /// timestamp queries).
    pub render_seconds: f64,
    /// The side's time as charged by its measured pass time (compare's equal time).
    pub clock: PassClock,
}

impl Side {
    /// A side with nothing built, rendering with the view's seed xor `seed_xor`.
    pub fn new(seed_xor: u64) -> Self {
        Self {
            seed_xor,
            live: None,
            pending: None,
            render_seconds: 0.0,
            clock: PassClock::default(),
        }
    }

    pub fn session(&self) -> Option<&GpuSession> {
        self.live.as_ref().map(|l| &l.session)
    }

    pub fn session_mut(&mut self) -> Option<&mut GpuSession> {
        self.live.as_mut().map(|l| &mut l.session)
    }

    /// The live estimator, if any.
    pub fn estimator(&self) -> Option<EstimatorSpec> {
        self.live.as_ref().map(|l| l.estimator)
    }

    /// Whole passes of the live session (0 without one).
    pub fn passes(&self) -> u32 {
        self.session().map_or(0, GpuSession::passes)
    }

    /// Whether the live session has a pass partly rendered (a band of rows).
    pub fn in_progress(&self) -> bool {
        self.session().is_some_and(|s| s.next_row() != 0)
    }

    /// The estimator being built, if any.
    pub fn building(&self) -> Option<EstimatorSpec> {
        self.pending.as_ref().map(|j| j.estimator)
    }

    /// The pending build's result, where it is the one still wanted (`want`): a job for
    /// another estimator is retired (its worker finishes alone), a finished one is taken.
    pub fn take_built(
        &mut self,
        want: EstimatorSpec,
        retired: &mut Vec<BuildJob>,
    ) -> Option<Result<Built>> {
        if self.pending.as_ref().is_some_and(|j| j.estimator != want) {
            retired.extend(self.pending.take());
        }
        let done = self.pending.as_mut()?.poll()?;
        self.pending = None;
        Some(done)
    }

    /// Makes `built` (of `estimator`) the live renderer and session, its clock at zero; a
    /// session started for an older view than `generation` is restarted on `scene`. Returns
    /// the build's coarse preview where it is of the current view.
    pub fn install(
        &mut self,
        estimator: EstimatorSpec,
        built: Built,
        scene: &GpuScene,
        seed: u64,
        generation: u64,
    ) -> Result<Option<Vec<u8>>> {
        let fresh = built.generation == generation;
        let mut live = Live {
            estimator,
            renderer: built.renderer,
            session: built.session,
            relay: built.relay,
        };
        if !fresh {
            live.restart(scene, seed ^ self.seed_xor)?;
        }
        self.live = Some(live);
        self.render_seconds = 0.0;
        self.clock = PassClock::default();
        Ok(built.preview.filter(|_| fresh))
    }

    /// Starts building `media`'s renderer and a session of `view` (its scene, seed and
    /// exposure).
    pub fn spawn(
        &mut self,
        gpu: &Gpu,
        media: MediaJob,
        view: &crate::view::View,
        generation: u64,
    ) -> Result<()> {
        self.pending = Some(BuildJob::spawn(
            gpu,
            media,
            view.scene(),
            view.seed ^ self.seed_xor,
            view.exposure,
            generation,
        )?);
        Ok(())
    }

    /// Starts the live accumulation again on `scene` (the view changed) with its clock at
    /// zero; returns whether there was one.
    pub fn reset(&mut self, scene: &GpuScene, seed: u64) -> Result<bool> {
        let Some(live) = &mut self.live else {
            return Ok(false);
        };
        live.restart(scene, seed ^ self.seed_xor)?;
        self.render_seconds = 0.0;
        self.clock = PassClock::default();
        Ok(true)
    }

    /// Drops the live renderer and session and retires the build in progress.
    pub fn stop(&mut self, retired: &mut Vec<BuildJob>) {
        self.live = None;
        retired.extend(self.pending.take());
    }

    /// Adds up to `max_passes` passes within `budget` (slices of `slice`) and charges them
    /// to the side's clock.
    pub fn add(&mut self, budget: Duration, slice: Duration, max_passes: u32) -> Result<()> {
        if let Some(live) = &mut self.live {
            self.clock.add(
                &mut live.session,
                &mut self.render_seconds,
                budget,
                slice,
                max_passes,
            )?;
        }
        Ok(())
    }

    /// Adds up to `max_passes` passes within `budget`, not charged to any clock (the
    /// reference's).
    pub fn add_uncharged(
        &mut self,
        budget: Duration,
        slice: Duration,
        max_passes: u32,
    ) -> Result<()> {
        if let Some(s) = self.session_mut() {
            s.add_for(budget, slice, max_passes)
                .map_err(|e| anyhow!("{e}"))?;
        }
        Ok(())
    }

    /// The side's time: its passes at its current pass time (0 without a session).
    pub fn seconds(&self) -> f64 {
        self.session().map_or(0.0, |_| self.clock.seconds())
    }

    /// Milliseconds per pass: GPU timestamps where the session has them, else the wall time
    /// over the passes.
    pub fn ms_per_pass(&self) -> f64 {
        self.session()
            .map_or(0.0, |s| compare::ms_per_pass(s, self.render_seconds))
    }

    /// The side's state for the equal-time scheduler, with `remaining` passes it may add.
    pub fn time(&self, remaining: u32) -> SideTime {
        SideTime {
            seconds: self.seconds(),
            pass_seconds: self.clock.pass_seconds,
            remaining,
            in_progress: self.in_progress(),
            passes: self.passes(),
        }
    }

    /// Draws the live image into `target` where it holds a pass; returns whether it drew.
    pub fn show(
        &mut self,
        tone: &GpuToneMap,
        target: &Target,
        queue: &wgpu::Queue,
        exposure: f32,
    ) -> Result<bool> {
        let Some(live) = self.live.as_mut().filter(|l| l.session.passes() > 0) else {
            return Ok(false);
        };
        show(
            tone,
            live.relay.as_mut(),
            &live.session,
            target,
            queue,
            exposure,
        )?;
        Ok(true)
    }
}

impl Live {
    /// The session started again on `scene`: reset in place at its size, a new session of
    /// the renderer at another (the image was resized).
    fn restart(&mut self, scene: &GpuScene, seed: u64) -> Result<()> {
        if (self.session.width(), self.session.height())
            == (scene.camera.width, scene.camera.height)
        {
            self.session
                .reset(scene, seed)
                .map_err(|e| anyhow!("{e}"))?;
        } else {
            self.session = self
                .renderer
                .session(scene, self.estimator, seed)
                .map_err(|e| anyhow!("{e}"))?;
        }
        Ok(())
    }
}
