//! Compare's equal time: a side's time charged by the measured time of its passes (not by
//! pass count), and the scheduler that gives the second estimator of the split view the
//! same GPU time as the first (each side's renderer and session is the window's
//! `app::side::Side`).

use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};
use pinrender::gpu_render::{GpuSession, PassTimeSource};

/// A side's time, charged by its measured pass time: each call that adds rows measures
/// its wall time over those rows (each slice is waited for: the device's time plus the
/// submission), the pass time is the running average of these, and the rows are charged at
/// it. A session's first call is not measured: on lavapipe its first band carries the
/// pipeline's first dispatch and costs as much as many whole passes; its rows are charged
/// at the pass time of the next call. Wall time rather than the timestamp mean of
/// [`GpuSession::pass_seconds`], which keeps that first dispatch for the session's life.
#[derive(Clone, Copy, Debug, Default)]
pub struct PassClock {
    /// The current pass time, seconds (0: not measured yet).
    pub pass_seconds: f64,
    /// Seconds charged so far.
    charged: f64,
    /// Rows of the unmeasured first call, not charged yet.
    uncharged_rows: u64,
    calls: u32,
}

impl PassClock {
    /// Adds up to `max_passes` passes to `session` within `budget` (slices of `slice`),
    /// counting the call's wall time into `wall`, and charges them.
    pub fn add(
        &mut self,
        session: &mut GpuSession,
        wall: &mut f64,
        budget: Duration,
        slice: Duration,
        max_passes: u32,
    ) -> Result<()> {
        let rows = |s: &GpuSession| {
            u64::from(s.passes()) * u64::from(s.height()) + u64::from(s.next_row())
        };
        let rows0 = rows(session);
        let t = Instant::now();
        session
            .add_for(budget, slice, max_passes)
            .map_err(|e| anyhow!("{e}"))?;
        let spent = t.elapsed().as_secs_f64();
        *wall += spent;
        let added = rows(session).saturating_sub(rows0);
        if added == 0 {
            return Ok(());
        }
        self.calls += 1;
        if self.calls == 1 {
            self.uncharged_rows += added;
            return Ok(());
        }
        let h = f64::from(session.height());
        let pass = spent / added as f64 * h;
        self.pass_seconds = if self.pass_seconds > 0.0 {
            0.5 * (self.pass_seconds + pass)
        } else {
            pass
        };
        let rows = added + std::mem::take(&mut self.uncharged_rows);
        self.charged += rows as f64 / h * self.pass_seconds;
        Ok(())
    }

    /// Seconds charged to the side so far.
    pub fn seconds(&self) -> f64 {
        self.charged
    }
}

/// Milliseconds per pass of a session: GPU time where it has timestamps, else the wall time
/// over the passes.
pub fn ms_per_pass(session: &GpuSession, wall: f64) -> f64 {
    if session.pass_time_source() == PassTimeSource::GpuTimestamps {
        1e3 * session.pass_seconds()
    } else if session.passes() == 0 {
        0.0
    } else {
        1e3 * wall / f64::from(session.passes())
    }
}

/// Which side adds passes this frame, and how many at most.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Turn {
    First(u32),
    Second(u32),
    Neither,
}

/// One side's state for the scheduler: seconds spent, measured seconds per pass (0: not
/// measured yet), passes it may still add (`u32::MAX`: no limit), and whether it must still
/// has a pass in progress.
#[derive(Clone, Copy, Debug)]
pub struct SideTime {
    pub seconds: f64,
    pub pass_seconds: f64,
    pub remaining: u32,
    /// A pass is partly rendered (a band of rows).
    pub in_progress: bool,
    /// Whole passes rendered so far.
    pub passes: u32,
}

/// Passes that bring a side `gap` seconds behind level with the other: at least one, at
/// most `remaining`.
fn passes_for(gap: f64, pass_seconds: f64, remaining: u32) -> u32 {
    let n = if pass_seconds > 0.0 && gap > 0.0 {
        (gap / pass_seconds).ceil().min(f64::from(u32::MAX)) as u32
    } else {
        1
    };
    n.clamp(1, remaining.max(1)).min(remaining)
}

/// Equal time: the side that has spent less time renders, as many passes as close the gap
/// by its measured pass time (one before that is measured); the other side while one has
/// nothing left to add. The second side renders only while it is behind by more than half
/// of its pass, so a scripted run (where the first side stops at its passes) ends with both
/// at the nearest equal time; a second side with no pass renders one once the first is done.
pub fn next_turn(first: SideTime, second: SideTime) -> Turn {
    let gap = first.seconds - second.seconds;
    let second_behind = second.remaining > 0
        && (gap > 0.5 * second.pass_seconds || second.pass_seconds == 0.0 && gap > 0.0);
    if second_behind {
        return Turn::Second(passes_for(gap, second.pass_seconds, second.remaining));
    }
    if first.remaining > 0 {
        return Turn::First(passes_for(-gap, first.pass_seconds, first.remaining));
    }
    // The first side is done: a second side without a pass renders one, whatever the time.
    // A side's first call is not measured (`PassClock`), so after a single pass of the first
    // side both times are still 0 and no gap would ever ask for it.
    if second.passes == 0 && second.remaining > 0 {
        return Turn::Second(1);
    }
    // A pass in progress is finished: what is shown and saved holds whole passes.
    if second.in_progress {
        Turn::Second(1)
    } else if first.in_progress {
        Turn::First(1)
    } else {
        Turn::Neither
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn side(seconds: f64, pass_seconds: f64, remaining: u32) -> SideTime {
        SideTime {
            seconds,
            pass_seconds,
            remaining,
            in_progress: false,
            passes: 1,
        }
    }

    #[test]
    fn the_side_behind_renders_the_passes_that_close_the_gap() {
        // The second is 1 s behind at 0.3 s a pass: four passes.
        let t = next_turn(side(2.0, 0.1, 10), side(1.0, 0.3, u32::MAX));
        assert_eq!(t, Turn::Second(4));
        // The first is behind by 0.25 s at 0.1 s a pass: three.
        let t = next_turn(side(1.0, 0.1, 10), side(1.25, 0.3, u32::MAX));
        assert_eq!(t, Turn::First(3));
        // At most what it may still add.
        let t = next_turn(side(0.0, 0.1, 2), side(5.0, 0.3, u32::MAX));
        assert_eq!(t, Turn::First(2));
    }

    #[test]
    fn a_scripted_second_side_stops_at_the_nearest_equal_time() {
        // The first is done at 1 s; the second at 0.8 s with 0.3 s passes is nearer after one
        // more (1.1 s) than now.
        let t = next_turn(side(1.0, 0.1, 0), side(0.8, 0.3, u32::MAX));
        assert_eq!(t, Turn::Second(1));
        // At 0.9 s one more (1.2 s) is farther: done.
        let t = next_turn(side(1.0, 0.1, 0), side(0.9, 0.3, u32::MAX));
        assert_eq!(t, Turn::Neither);
        // A pass in progress is finished whatever the time.
        let mut busy = side(1.5, 0.3, u32::MAX);
        busy.in_progress = true;
        assert_eq!(next_turn(side(1.0, 0.1, 0), busy), Turn::Second(1));
    }

    #[test]
    fn a_second_side_without_a_pass_renders_one_once_the_first_is_done() {
        // One pass of the first side: neither time is measured yet (both 0).
        let mut second = side(0.0, 0.0, u32::MAX);
        second.passes = 0;
        assert_eq!(next_turn(side(0.0, 0.0, 0), second), Turn::Second(1));
        second.passes = 1;
        assert_eq!(next_turn(side(0.0, 0.0, 0), second), Turn::Neither);
    }
}
