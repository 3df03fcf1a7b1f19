//! Frame pacing: the passes each frame adds within its budget (whole passes or bands of
//! rows, each slice waited for), the turns of the two sides and the reference, and the
//! meter of the longest time between two painted frames.

use std::time::{Duration, Instant};

use anyhow::Result;
use pinrender::gpu_render::PassTimeSource;

use super::Viewer;
use super::events::Shown;
use crate::compare::{self, Turn};
use crate::error_view;

/// Wall time the renderer may take per frame, and per submission within it: the window
/// answers well within 100 ms.
pub const FRAME_BUDGET: Duration = Duration::from_millis(40);
pub const SLICE: Duration = Duration::from_millis(20);
/// How soon a frame that rendered nothing (paused, or waiting for a build) asks for the
/// next: 20 Hz keeps a progress bar moving, input wakes the window at once anyway, and the
/// cores stay with the builds (on lavapipe a frame's paint is CPU work, 60-100 ms of it).
pub const IDLE_REPAINT: Duration = Duration::from_millis(50);

/// The longest time between two painted frames, from when the window was created (its
/// first frame counts from there) to the last frame.
#[derive(Clone, Copy, Debug)]
pub struct FramePacer {
    last: Instant,
    longest: Duration,
    frames: u64,
}

impl FramePacer {
    pub fn new(created: Instant) -> Self {
        Self {
            last: created,
            longest: Duration::ZERO,
            frames: 0,
        }
    }

    /// A frame starts at `now`.
    pub fn tick(&mut self, now: Instant) {
        self.longest = self.longest.max(now.saturating_duration_since(self.last));
        self.last = now;
        self.frames += 1;
    }

    /// The longest gap so far, milliseconds.
    pub fn longest_ms(&self) -> f64 {
        1e3 * self.longest.as_secs_f64()
    }

    /// Frames counted so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }
}

impl Viewer {
    /// Adds passes for this frame and draws the accumulation into the texture.
    pub(super) fn render(&mut self) -> Result<bool> {
        self.ensure_session()?;
        // Scripted input: the run's N passes count from the shown session's passes once the
        // last event is in (0 where the event started the accumulation again).
        if let (Some(script), Some(s)) = (&mut self.script, self.main.session())
            && script.all_applied()
            && script.base.is_none()
        {
            script.base = Some(s.passes());
        }
        // A changed view answers within the frame: a coarse image, painted before any pass
        // of the new view is added (in a drag the next step would start them again); the
        // accumulation refines it from the next frame on.
        if std::mem::take(&mut self.coarse.due)
            && self.main.session().is_some_and(|s| s.passes() == 0)
            && self.draw_coarse()?
        {
            return Ok(true);
        }
        let limit = match self.args.frames {
            Some(n) => {
                // A scripted run renders the estimator it asked for, once a running bake
                // brings it (else the medium's default, noted).
                if self.awaiting_wanted() {
                    return Ok(false);
                }
                self.script_passes(n)
            }
            None => u32::MAX,
        };
        // A scripted re-bake renders its passes on the new pins.
        if self.args.frames.is_some()
            && self.args.rebake_scale.is_some()
            && self.bakes.rebaked.is_none()
        {
            return Ok(false);
        }
        // A scripted comparison waits for its second estimator (a volume's pins).
        if self.args.frames.is_some() && self.awaiting_compare() {
            return Ok(false);
        }
        // A frame that reads the error back (tens of milliseconds at 512 x 512 on lavapipe)
        // renders one slice and no reference: the window still answers within 100 ms.
        let error_due = self.error_due();
        let Some(passes) = self.main.session().map(|s| s.passes()) else {
            return Ok(false);
        };
        // The window screenshot shows the passes the other outputs hold.
        let running =
            !(self.paused && self.playback.sequence.is_none()) && self.window_shot.is_none();
        let remaining = if running {
            limit.saturating_sub(passes)
        } else {
            0
        };
        let turn = match self.compare.live {
            None => Turn::First(remaining),
            Some(_) => compare::next_turn(
                self.main.time(remaining),
                self.compare.time(if running { u32::MAX } else { 0 }),
            ),
        };
        let budget = if error_due { SLICE } else { FRAME_BUDGET };
        let t = Instant::now();
        let mut busy = true;
        match turn {
            Turn::First(n) if n > 0 => self.main.add(budget, SLICE, n)?,
            Turn::Second(n) => self.compare.add(budget, SLICE, n)?,
            _ => busy = false,
        }
        // The reference gets what is left of the frame's budget (at least one slice), the
        // whole frame when the shown sides add nothing; a scripted run stops it on whole
        // passes once the shown sides are done.
        if self.reference.live.is_some() && running && !error_due {
            let idle = turn == Turn::Neither || matches!(turn, Turn::First(0));
            let max = if self.args.frames.is_some() && idle {
                u32::from(self.reference.passes() == 0 || self.reference.in_progress())
            } else {
                u32::MAX
            };
            let budget = if idle {
                FRAME_BUDGET
            } else {
                FRAME_BUDGET.saturating_sub(t.elapsed())
            };
            if max > 0 {
                self.reference.add_uncharged(budget, SLICE, max)?;
                busy = true;
            }
        }
        let exposure = self.view.exposure;
        if let Some(target) = &self.images.compare {
            self.compare
                .show(&self.tone, target, &self.gpu.queue, exposure)?;
        }
        // After a reset the old image (or the preview) stays up until the first new pass is
        // in: no black frames while a long pass renders in bands.
        if self
            .main
            .show(&self.tone, &self.images.main, &self.gpu.queue, exposure)?
        {
            self.shown = Some(Shown::Pass);
            self.input.moving = false;
            if self.first_image_s.is_none() {
                let now = self.clock.now();
                self.first_image_s = Some(now);
                self.first_image_estimator = self.main.estimator();
                self.playback.shown_first_at = Some(Instant::now());
                self.clock.marks.first_image = now;
            }
        }
        Ok(busy)
    }

    /// The passes a scripted run renders on the current session: `--frame-passes` on each
    /// frame of a playing sequence but the last (it then steps on), `n` (`--frames`) on the
    /// last frame or a single file.
    /// With scripted input, `n` counts from the last event (no limit before it).
    pub(super) fn script_passes(&self, n: u32) -> u32 {
        let base = match &self.script {
            None => 0,
            Some(s) => match s.base {
                Some(base) if s.all_applied() => base,
                _ => return u32::MAX,
            },
        };
        match &self.playback.sequence {
            Some(s) if s.playing && s.current + 1 < s.len() => self.args.frame_passes,
            _ => base.saturating_add(n),
        }
    }

    /// Whether a scripted comparison has its second side at the nearest equal time, with
    /// whole passes (or no comparison was asked for, or the medium cannot answer it).
    pub(super) fn compare_done(&self) -> bool {
        let Some(want) = self.compare_wanted else {
            return true;
        };
        if !self.awaiting_compare() && self.compare.live.is_none() {
            return true;
        }
        if self.compare.live.is_none() || self.main.live.is_none() {
            return false;
        }
        self.compare.estimator() == Some(want)
            && self.compare.passes() > 0
            && compare::next_turn(self.main.time(0), self.compare.time(u32::MAX)) == Turn::Neither
    }

    /// Whether a scripted run's reference holds whole passes, at least one (or there is
    /// none to wait for).
    pub(super) fn reference_done(&self) -> bool {
        match &self.reference.live {
            _ if !self.error_on => true,
            None => error_view::no_reference_reason(&self.medium).is_some(),
            Some(_) => self.reference.passes() > 0 && !self.reference.in_progress(),
        }
    }

    pub(super) fn pass_time_source(&self) -> PassTimeSource {
        self.main
            .session()
            .map_or(PassTimeSource::Wall, |s| s.pass_time_source())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_longest_gap_counts_from_creation_and_between_frames() {
        let t0 = Instant::now();
        let mut p = FramePacer::new(t0);
        p.tick(t0 + Duration::from_millis(30));
        p.tick(t0 + Duration::from_millis(40));
        p.tick(t0 + Duration::from_millis(140));
        p.tick(t0 + Duration::from_millis(150));
        assert_eq!(p.longest_ms(), 100.0);
        assert_eq!(p.frames(), 4);
        let mut q = FramePacer::new(t0);
        q.tick(t0 + Duration::from_millis(250));
        assert_eq!(q.longest_ms(), 250.0);
    }
}
