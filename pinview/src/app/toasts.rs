//! Status and save messages as toasts: each is drawn over the image, bottom right, for
//! [`SHOWN_FOR`] and then goes, so the panel keeps its room; every message is also kept for
//! the JSON line's `messages`.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// How long a toast stays up.
pub const SHOWN_FOR: Duration = Duration::from_secs(6);
/// Toasts up at once at most (the oldest goes first).
const MAX_SHOWN: usize = 4;
/// Messages kept for the JSON line at most (a long session says the first ones).
const MAX_KEPT: usize = 256;

/// The toasts up now, with when each came, and every message said so far.
#[derive(Debug, Default)]
pub struct Toasts {
    up: VecDeque<(String, Instant)>,
    pub said: Vec<String>,
}

impl Toasts {
    /// Puts `message` up (once while the same one is still up).
    pub fn say(&mut self, message: impl Into<String>) {
        let message = message.into();
        if message.is_empty() {
            return;
        }
        if self.said.len() < MAX_KEPT {
            self.said.push(message.clone());
        }
        self.up.retain(|(m, _)| *m != message);
        self.up.push_back((message, Instant::now()));
        while self.up.len() > MAX_SHOWN {
            self.up.pop_front();
        }
    }

    /// The messages up at `now`, oldest first.
    pub fn up(&mut self, now: Instant) -> impl Iterator<Item = &str> {
        self.up
            .retain(|(_, t)| now.saturating_duration_since(*t) < SHOWN_FOR);
        self.up.iter().map(|(m, _)| m.as_str())
    }

    /// Draws the toasts up now over the window's bottom right corner.
    pub fn draw(&mut self, ctx: &egui::Context) {
        let up: Vec<String> = self.up(Instant::now()).map(str::to_owned).collect();
        if up.is_empty() {
            return;
        }
        egui::Area::new(egui::Id::unique("pinview toasts"))
            .anchor(egui::Align2::RIGHT_BOTTOM, egui::vec2(-12.0, -12.0))
            .order(egui::Order::Foreground)
            .interactable(false)
            .show(ctx, |ui| {
                for m in up {
                    egui::Frame::popup(ui.style()).show(ui, |ui| {
                        ui.set_max_width(460.0);
                        ui.label(egui::RichText::new(m).color(egui::Color32::YELLOW));
                    });
                }
            });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_toast_goes_after_its_time_and_every_message_is_kept() {
        let mut t = Toasts::default();
        t.say("one");
        t.say("two");
        t.say("one");
        let now = Instant::now();
        assert_eq!(t.up(now).collect::<Vec<_>>(), ["two", "one"]);
        assert_eq!(t.said, ["one", "two", "one"]);
        assert_eq!(t.up(now + SHOWN_FOR).count(), 0);
        for k in 0..10 {
            t.say(format!("m{k}"));
        }
        assert_eq!(t.up(Instant::now()).count(), MAX_SHOWN);
    }
}
