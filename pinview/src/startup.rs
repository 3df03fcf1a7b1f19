//! Where the time to the first image goes: marks taken from the process start at each step
//! of opening a view, reported as the seconds each step took.

use std::time::Instant;

/// Seconds from the process start at which each step of the first view ended (0: not yet).
#[derive(Clone, Copy, Debug, Default)]
pub struct StartupMarks {
    /// The file read (mapped and checked) before any window opens.
    pub file_open: f64,
    /// The window, the adapter and the device, opened by the window shell.
    pub window_and_device: f64,
    /// The media uploaded and the path tracer's WGSL module created.
    pub upload: f64,
    /// The estimator's compute pipeline compiled and the session's buffers made.
    pub pipeline: f64,
    /// The first whole pass rendered and tone-mapped.
    pub first_image: f64,
}

/// The process start and the marks taken since.
#[derive(Clone, Copy, Debug)]
pub struct StartupClock {
    pub started: Instant,
    pub marks: StartupMarks,
}

impl StartupClock {
    pub fn new(started: Instant) -> Self {
        Self {
            started,
            marks: StartupMarks::default(),
        }
    }

    /// Seconds since the process start.
    pub fn now(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}

impl StartupMarks {
    /// Each step's own seconds (the difference of consecutive marks), as the JSON object
    /// `first_image_breakdown`; a step not reached yet is 0.
    pub fn breakdown(&self) -> serde_json::Value {
        let marks = [
            ("file_open_s", self.file_open),
            ("window_and_device_s", self.window_and_device),
            ("upload_s", self.upload),
            ("pipeline_s", self.pipeline),
            ("first_pass_s", self.first_image),
        ];
        let mut out = serde_json::Map::new();
        let mut before = 0.0;
        for (name, mark) in marks {
            let step = if mark > 0.0 {
                (mark - before).max(0.0)
            } else {
                0.0
            };
            out.insert(name.into(), step.into());
            if mark > 0.0 {
                before = mark;
            }
        }
        serde_json::Value::Object(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_differences_of_marks_and_sum_to_the_first_image() {
        let m = StartupMarks {
            file_open: 0.25,
            window_and_device: 1.0,
            upload: 1.5,
            pipeline: 3.0,
            first_image: 3.75,
        };
        let b = m.breakdown();
        let steps: Vec<f64> = [
            "file_open_s",
            "window_and_device_s",
            "upload_s",
            "pipeline_s",
            "first_pass_s",
        ]
        .iter()
        .map(|k| b[k].as_f64().unwrap())
        .collect();
        assert_eq!(steps, [0.25, 0.75, 0.5, 1.5, 0.75]);
        assert_eq!(steps.iter().sum::<f64>(), m.first_image);
    }

    #[test]
    fn steps_not_reached_are_zero() {
        let m = StartupMarks {
            file_open: 0.5,
            window_and_device: 2.0,
            ..Default::default()
        };
        let b = m.breakdown();
        assert_eq!(b["window_and_device_s"], 1.5);
        assert_eq!(b["pipeline_s"], 0.0);
        assert_eq!(b["first_pass_s"], 0.0);
    }
}
