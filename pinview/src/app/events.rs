//! Scripted input in the window (`--input-script`): each event applied when it is due, and
//! the time from it to the first changed image shown and to the first whole pass shown.
//! `at_s` counts from the first image shown; the run ends `--frames` passes after the last
//! event, or [`GRACE`] after the last event is due, whichever comes first.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};

use super::Viewer;
use crate::input_script::{Action, Event};

/// How long after the last event is due the run ends at the latest.
pub const GRACE: Duration = Duration::from_secs(10);

/// What a frame put in the displayed image: a coarse preview, or whole passes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shown {
    Preview,
    Pass,
}

/// An applied event and what it took to answer it.
#[derive(Debug)]
struct Record {
    action: &'static str,
    at_s: f64,
    applied: Instant,
    first_pixels: Option<(Duration, Shown)>,
    first_full_pass: Option<Duration>,
}

/// The events of a script and where the replay stands.
#[derive(Debug)]
pub struct ScriptedInput {
    events: Vec<Event>,
    next: usize,
    /// When `at_s` counts from: the first image shown (painted).
    origin: Option<Instant>,
    records: Vec<Record>,
    /// The shown session's passes that the run's N count from, once the last event is in.
    pub base: Option<u32>,
    /// Pointer events of a `drag` still to be given to the window, a frame's worth each.
    pointer: VecDeque<Vec<egui::Event>>,
}

impl ScriptedInput {
    pub fn new(events: Vec<Event>) -> Self {
        Self {
            events,
            next: 0,
            origin: None,
            records: Vec::new(),
            base: None,
            pointer: VecDeque::new(),
        }
    }

    /// The pointer events for the window's next frame (`crate::shell::App::raw_events`).
    pub fn next_pointer_events(&mut self) -> Vec<egui::Event> {
        self.pointer.pop_front().unwrap_or_default()
    }

    /// Queues a drag of the primary button from `from` to `to` (window points): the pointer
    /// comes to `from`, is pressed, moves in four steps, and is let go, a frame each, so the
    /// window sees it as a mouse drag (past egui's drag threshold, one frame at a time).
    fn drag(&mut self, from: egui::Pos2, to: egui::Pos2) {
        let button = |pos, pressed| egui::Event::PointerButton {
            pos,
            button: egui::PointerButton::Primary,
            pressed,
            modifiers: egui::Modifiers::NONE,
        };
        self.pointer
            .push_back(vec![egui::Event::PointerMoved(from)]);
        self.pointer.push_back(vec![button(from, true)]);
        for k in 1..=4 {
            let p = from.lerp(to, k as f32 / 4.0);
            self.pointer.push_back(vec![egui::Event::PointerMoved(p)]);
        }
        self.pointer.push_back(vec![button(to, false)]);
    }

    /// A frame painted at `now` showed `shown` (drawn in the frame before): the first image
    /// starts the script's clock; each applied event not answered yet is answered now.
    pub fn painted(&mut self, now: Instant, shown: Shown) {
        if shown == Shown::Pass && self.origin.is_none() {
            self.origin = Some(now);
        }
        for r in &mut self.records {
            let since = now.saturating_duration_since(r.applied);
            r.first_pixels.get_or_insert((since, shown));
            if shown == Shown::Pass {
                r.first_full_pass.get_or_insert(since);
            }
        }
    }

    /// The events due at `now` (none before the first image).
    pub fn due(&mut self, now: Instant) -> Vec<Event> {
        let Some(origin) = self.origin else {
            return Vec::new();
        };
        let elapsed = now.saturating_duration_since(origin).as_secs_f64();
        let mut due = Vec::new();
        while let Some(e) = self.events.get(self.next).filter(|e| e.at_s <= elapsed) {
            due.push(e.clone());
            self.next += 1;
        }
        due
    }

    /// `event` was applied at `now`.
    pub fn applied(&mut self, event: &Event, now: Instant) {
        self.records.push(Record {
            action: event.action.name(),
            at_s: event.at_s,
            applied: now,
            first_pixels: None,
            first_full_pass: None,
        });
    }

    /// Whether every event has been applied (a drag's pointer events all given to the
    /// window).
    pub fn all_applied(&self) -> bool {
        self.next == self.events.len() && self.pointer.is_empty()
    }

    /// Whether every applied event has been answered by a whole pass shown: the run's last
    /// passes are painted (heard a frame later) before it ends, so the last event has its
    /// times too.
    pub fn answered(&self) -> bool {
        self.records.iter().all(|r| r.first_full_pass.is_some())
    }

    /// Whether the run is past its end: every event applied and [`GRACE`] after the last
    /// one was due.
    pub fn timed_out(&self, now: Instant) -> bool {
        let last = self.events.last().map_or(0.0, |e| e.at_s);
        self.all_applied()
            && self
                .origin
                .is_some_and(|o| now >= o + Duration::from_secs_f64(last) + GRACE)
    }

    /// The JSON line's `events`: one object per applied event.
    pub fn json(&self) -> serde_json::Value {
        let ms = |d: Option<Duration>| d.map(|d| 1e3 * d.as_secs_f64());
        self.records
            .iter()
            .map(|r| {
                serde_json::json!({
                    "action": r.action,
                    "at_s": r.at_s,
                    "first_pixels_ms": ms(r.first_pixels.map(|(d, _)| d)),
                    "first_pixels": r.first_pixels.map(|(_, shown)| match shown {
                        Shown::Preview => "coarse",
                        Shown::Pass => "pass",
                    }),
                    "first_full_pass_ms": ms(r.first_full_pass),
                })
            })
            .collect()
    }
}

impl Viewer {
    /// Checks, before the window's first frame, that every event applies to what is open:
    /// a `frame` event needs a sequence with that many frames.
    pub(super) fn check_events(&self, events: &[Event]) -> Result<()> {
        let path = self
            .args
            .input_script
            .as_deref()
            .unwrap_or(std::path::Path::new(""));
        let budget = self.args.flags.budget();
        for (k, e) in events.iter().enumerate() {
            // A size asked for fits `--max-memory` as the starting size and a followed one do.
            if let Action::Resize { width, height } = e.action {
                pinrender::front::flags::check_image(&budget, width, height)
                    .map_err(|err| anyhow!("{}: event {}: {err}", path.display(), k + 1))?;
            }
            if let Action::Frame { index } = e.action {
                let frames = self.playback.sequence.as_ref().map_or(0, |s| s.len());
                if index > frames {
                    return Err(anyhow!(
                        "{}: event {}: frame {index}: {} has {}",
                        path.display(),
                        k + 1,
                        self.args.file.display(),
                        match frames {
                            0 => "no frames (not a frame pattern)".to_string(),
                            n => format!("{n} frames"),
                        }
                    ));
                }
            }
        }
        Ok(())
    }

    /// Applies the scripted events due now, as the controls would.
    pub(super) fn replay_events(&mut self, ctx: &egui::Context) -> Result<()> {
        let Some(script) = &mut self.script else {
            return Ok(());
        };
        let now = Instant::now();
        let due = script.due(now);
        for e in due {
            self.apply_event(ctx, &e.action)?;
            if let Some(s) = &mut self.script {
                s.applied(&e, Instant::now());
            }
        }
        Ok(())
    }

    fn apply_event(&mut self, ctx: &egui::Context, action: &Action) -> Result<()> {
        let v = &mut self.view;
        match *action {
            Action::Orbit { dx_deg, dy_deg } => v.orbit(dx_deg.to_radians(), dy_deg.to_radians()),
            Action::Zoom { factor } => v.zoom(1.0 / factor),
            Action::Pan { dx, dy } => v.pan(dx, dy),
            Action::Sun { dir } => v.look.sun_dir = dir,
            Action::Estimator { name } => self.wanted = name,
            Action::Exposure { stops } => {
                v.exposure = (f64::from(self.args.flags.exposure) * stops.exp2()) as f32;
            }
            Action::Frame { index } => self.go_to_frame(index - 1)?,
            Action::Resize { width, height } => {
                // A size asked for is kept: the image no longer follows the window.
                self.viewport.follow = false;
                v.width = width;
                v.height = height;
            }
            Action::Drag { from, to } => {
                let rect = self
                    .input
                    .image_rect
                    .ok_or_else(|| anyhow!("a drag before the image is shown"))?;
                let (w, h) = self.images.main.size;
                let at = |p: [f64; 2]| {
                    egui::pos2(
                        rect.left() + (p[0] / f64::from(w)) as f32 * rect.width(),
                        rect.top() + (p[1] / f64::from(h)) as f32 * rect.height(),
                    )
                };
                if let Some(s) = &mut self.script {
                    s.drag(at(from), at(to));
                }
            }
            Action::FrameAll => crate::scene_framing::frame_all(&mut self.view, &self.medium),
            Action::Reset => self.reset_view(),
            Action::CopyCommand => {
                self.export.command = crate::clipboard::copy_command(
                    ctx,
                    self.main.session_mut(),
                    &self.view,
                    &self.medium,
                )?;
            }
        }
        Ok(())
    }

    /// The frame before painted what it drew: the script hears of it.
    pub(super) fn note_painted(&mut self, now: Instant) {
        if let (Some(script), Some(shown)) = (&mut self.script, self.shown.take()) {
            script.painted(now, shown);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input_script::parse;

    #[test]
    fn events_fall_due_from_the_first_image_and_are_answered_by_later_paints() {
        let events = parse(
            r#"[{"at_s": 0.1, "action": "zoom", "factor": 2},
                {"at_s": 0.3, "action": "exposure", "stops": 1}]"#,
        )
        .unwrap();
        let mut s = ScriptedInput::new(events);
        let t0 = Instant::now();
        // Nothing is due before the first image, nor does a preview start the clock.
        assert!(s.due(t0 + Duration::from_secs(5)).is_empty());
        s.painted(t0, Shown::Preview);
        assert!(s.due(t0 + Duration::from_secs(5)).is_empty());
        s.painted(t0, Shown::Pass);
        assert!(s.due(t0 + Duration::from_millis(50)).is_empty());
        let due = s.due(t0 + Duration::from_millis(120));
        assert_eq!(due.len(), 1);
        s.applied(&due[0], t0 + Duration::from_millis(120));
        s.painted(t0 + Duration::from_millis(170), Shown::Preview);
        s.painted(t0 + Duration::from_millis(420), Shown::Pass);
        assert!(!s.all_applied());
        let due = s.due(t0 + Duration::from_millis(400));
        assert_eq!(due.len(), 1);
        s.applied(&due[0], t0 + Duration::from_millis(400));
        assert!(s.all_applied());
        assert!(!s.timed_out(t0 + Duration::from_millis(10_200)));
        assert!(s.timed_out(t0 + Duration::from_millis(10_300)));
        let j = s.json();
        assert_eq!(j[0]["action"], "zoom");
        assert_eq!(j[0]["first_pixels_ms"].as_f64().map(f64::round), Some(50.0));
        assert_eq!(
            j[0]["first_full_pass_ms"].as_f64().map(f64::round),
            Some(300.0)
        );
        assert!(j[1]["first_pixels_ms"].is_null());
    }
}
