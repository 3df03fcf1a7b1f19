//! A sequence's playback: its frames, the frame shown and the steps a playing sequence
//! takes, and what the JSON line reports of them (the frames shown, `playback_fps`).

use std::time::Instant;

use anyhow::Result;

use super::Viewer;
use crate::sequence::Sequence;

/// The playing rate's range and default, frames per second.
pub const FPS: std::ops::RangeInclusive<f64> = 1.0..=60.0;
pub const DEFAULT_FPS: f64 = 24.0;

/// A sequence (where the file is a frame pattern), the rate it plays at, when the first image
/// was shown, when each step of a playing sequence was taken, and the frame numbers shown,
/// in order.
pub struct Playback {
    pub sequence: Option<Sequence>,
    /// Frames per second at most: a playing sequence steps on at this rate, or slower where
    /// its frames' passes (`--frame-passes`) take longer.
    pub fps: f64,
    pub shown_first_at: Option<Instant>,
    pub steps: Vec<Instant>,
    pub frames_played: Vec<i64>,
}

impl Playback {
    /// `sequence`'s playback, playing from the start where `play`.
    pub fn new(mut sequence: Option<Sequence>, play: bool) -> Self {
        let mut frames_played = Vec::new();
        if let Some(s) = &mut sequence {
            s.playing = play;
            frames_played.push(s.frames[s.current].0);
        }
        Self {
            sequence,
            fps: DEFAULT_FPS,
            shown_first_at: None,
            steps: Vec::new(),
            frames_played,
        }
    }

    /// Whether a playing sequence may step on at `now`: a frame period (`1 / fps`) after the
    /// last step, or after the first image before one.
    pub fn due(&self, now: Instant) -> bool {
        let period =
            std::time::Duration::from_secs_f64(1.0 / self.fps.clamp(*FPS.start(), *FPS.end()));
        self.steps
            .last()
            .or(self.shown_first_at.as_ref())
            .is_none_or(|t| now.saturating_duration_since(*t) >= period)
    }

    /// Frames shown per second of wall time while playing: the steps a playing sequence
    /// took over the time from the first image to the last step (`None` before a step).
    pub fn fps(&self) -> Option<f64> {
        let (start, last) = (self.shown_first_at?, *self.steps.last()?);
        let seconds = last.saturating_duration_since(start).as_secs_f64();
        (seconds > 0.0).then(|| self.steps.len() as f64 / seconds)
    }
}

impl Viewer {
    /// A playing sequence steps on once the shown frame has its `--frame-passes` passes and a
    /// frame period has passed since the last step (whichever comes later); a scripted run
    /// plays the sequence once and stops on its last frame.
    pub(super) fn step_playback(&mut self) -> Result<()> {
        let frame_passes = self.args.frame_passes;
        let done = self.main.passes();
        let scripted = self.args.frames.is_some();
        let next = match &self.playback.sequence {
            Some(s)
                if s.playing
                    && !self.paused
                    && done >= frame_passes
                    && self.playback.due(Instant::now())
                    && s.len() > 1
                    && !(scripted && s.current + 1 == s.len()) =>
            {
                Some((s.current + 1) % s.len())
            }
            _ => None,
        };
        if let Some(i) = next {
            self.go_to_frame(i)?;
            self.playback.steps.push(Instant::now());
        }
        Ok(())
    }

    /// Shows the sequence's frame at position `i` (from 0).
    pub(super) fn go_to_frame(&mut self, i: usize) -> Result<()> {
        let Some(s) = &mut self.playback.sequence else {
            return Ok(());
        };
        let m = s.go_to(i)?;
        self.playback.frames_played.push(s.frames[s.current].0);
        self.set_medium(m);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_step_waits_for_the_frame_period() {
        let mut p = Playback::new(None, true);
        let t0 = Instant::now();
        assert!(p.due(t0), "before the first image, the passes alone decide");
        p.shown_first_at = Some(t0);
        p.fps = 10.0;
        assert!(!p.due(t0 + Duration::from_millis(90)));
        assert!(p.due(t0 + Duration::from_millis(100)));
        p.steps.push(t0 + Duration::from_millis(100));
        assert!(!p.due(t0 + Duration::from_millis(150)));
        p.fps = 20.0;
        assert!(p.due(t0 + Duration::from_millis(150)));
    }
}
