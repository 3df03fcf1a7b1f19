//! Scripted input (`--input-script EVENTS.json`): timed events replayed in the real window,
//! for tests and benchmarks. The file is a JSON list of objects
//! `{"at_s": T, "action": A, ...}`, in time order, `at_s` counted from the first image shown:
//!
//! * `orbit {"dx_deg", "dy_deg"}`: the camera turns about its target (degrees; as a drag);
//! * `zoom {"factor"}`: the camera moves `factor` times closer to its target (> 1: in);
//! * `pan {"dx", "dy"}`: camera and target move by fractions of the view;
//! * `sun {"dir": [x, y, z]}`: the direction towards the sun;
//! * `estimator {"name"}`: the estimator shown (as `--estimator`);
//! * `exposure {"stops"}`: the exposure becomes `--exposure` times 2^stops;
//! * `frame {"index"}`: a sequence's frame at this position, from 1 (as the label's "2 of 5");
//! * `resize {"width", "height"}`: the image's size in pixels;
//! * `drag {"from": [x, y], "to": [x, y]}`: the primary button pressed at image pixel `from`
//!   (from the top-left corner, as `--pin-at`), moved to `to` over a few frames and let go,
//!   as the mouse would: what it moves (the camera, the divider) is the window's to decide.
//! * `copy_command {}`: as the "copy command" button: the view's batch command line on the
//!   clipboard and stdout;
//! * `frame_all {}`: as the "frame all" button: the camera outside every instance's box;
//! * `reset {}`: as the "reset view" button (the `R` key): the camera the view opened with.
//!
//! Every event's keys are checked: an unknown key or action, a missing or out-of-range
//! parameter is refused with the file and the event's position.

use std::io::Read;
use std::path::Path;

use anyhow::{Result, anyhow, bail};
use pinrender::render::EstimatorSpec;
use serde_json::{Map, Value};

/// The largest events file read (a script of many thousand events fits well within it).
const MAX_BYTES: u64 = 4 << 20;
/// The latest `at_s` accepted: an hour.
const MAX_AT_S: f64 = 3600.0;

/// One scripted input event.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    Orbit { dx_deg: f64, dy_deg: f64 },
    Zoom { factor: f64 },
    Pan { dx: f64, dy: f64 },
    Sun { dir: [f64; 3] },
    Estimator { name: EstimatorSpec },
    Exposure { stops: f64 },
    Frame { index: usize },
    Resize { width: u32, height: u32 },
    Drag { from: [f64; 2], to: [f64; 2] },
    CopyCommand,
    FrameAll,
    Reset,
}

impl Action {
    /// The action's name, as in the file and in the JSON line's `events`.
    pub fn name(&self) -> &'static str {
        match self {
            Action::Orbit { .. } => "orbit",
            Action::Zoom { .. } => "zoom",
            Action::Pan { .. } => "pan",
            Action::Sun { .. } => "sun",
            Action::Estimator { .. } => "estimator",
            Action::Exposure { .. } => "exposure",
            Action::Frame { .. } => "frame",
            Action::Resize { .. } => "resize",
            Action::Drag { .. } => "drag",
            Action::CopyCommand => "copy_command",
            Action::FrameAll => "frame_all",
            Action::Reset => "reset",
        }
    }
}

/// An event and when it is due, in seconds after the first image.
#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    pub at_s: f64,
    pub action: Action,
}

/// Reads and checks the events of `path`.
pub fn read(path: &Path) -> Result<Vec<Event>> {
    let name = path.display();
    let file = std::fs::File::open(path).map_err(|e| anyhow!("{name}: {e}"))?;
    let meta = file.metadata().map_err(|e| anyhow!("{name}: {e}"))?;
    if !meta.is_file() {
        bail!("{name}: not a regular file");
    }
    let mut text = String::new();
    file.take(MAX_BYTES + 1)
        .read_to_string(&mut text)
        .map_err(|e| anyhow!("{name}: {e}"))?;
    if text.len() as u64 > MAX_BYTES {
        bail!("{name}: an events file is at most {MAX_BYTES} bytes");
    }
    parse(&text).map_err(|e| anyhow!("{name}: {e}"))
}

/// The events of a script's text.
pub fn parse(text: &str) -> Result<Vec<Event>> {
    let value: Value = serde_json::from_str(text.trim_start_matches('\u{feff}'))
        .map_err(|e| anyhow!("not JSON: {e}"))?;
    let Value::Array(list) = value else {
        bail!("expected a list of events ([{{\"at_s\": 0.5, \"action\": \"orbit\", ...}}])");
    };
    let mut events = Vec::with_capacity(list.len());
    let mut last = 0.0;
    for (k, v) in list.iter().enumerate() {
        let e = event(v).map_err(|e| anyhow!("event {}: {e}", k + 1))?;
        if e.at_s < last {
            bail!(
                "event {}: at_s {} comes before the previous event's {last}; list events in \
                 time order",
                k + 1,
                e.at_s
            );
        }
        last = e.at_s;
        events.push(e);
    }
    Ok(events)
}

fn event(v: &Value) -> Result<Event> {
    let Value::Object(o) = v else {
        bail!("expected an object");
    };
    let action = match o.get("action") {
        Some(Value::String(s)) => s.as_str(),
        _ => bail!(
            "\"action\" must be one of orbit, zoom, pan, sun, estimator, exposure, frame, resize, \
             drag, copy_command, frame_all, reset"
        ),
    };
    let at_s = number(o, "at_s")?;
    if !(0.0..=MAX_AT_S).contains(&at_s) {
        bail!("at_s must be in [0, {MAX_AT_S}], not {at_s}");
    }
    let (keys, action): (&[&str], Action) = match action {
        "orbit" => (
            &["dx_deg", "dy_deg"],
            Action::Orbit {
                dx_deg: number(o, "dx_deg")?,
                dy_deg: number(o, "dy_deg")?,
            },
        ),
        "zoom" => {
            let factor = number(o, "factor")?;
            if !(factor > 0.0) {
                bail!("zoom's factor must be > 0, not {factor}");
            }
            (&["factor"], Action::Zoom { factor })
        }
        "pan" => (
            &["dx", "dy"],
            Action::Pan {
                dx: number(o, "dx")?,
                dy: number(o, "dy")?,
            },
        ),
        "sun" => {
            let dir = match o.get("dir") {
                Some(Value::Array(a)) if a.len() == 3 => {
                    let mut d = [0.0; 3];
                    for (x, v) in d.iter_mut().zip(a) {
                        *x = v
                            .as_f64()
                            .filter(|x| x.is_finite())
                            .ok_or_else(|| anyhow!("sun's dir must be three finite numbers"))?;
                    }
                    d
                }
                _ => bail!("sun needs \"dir\": [x, y, z]"),
            };
            let dir = pin_scene::ranges::direction(dir).map_err(|e| anyhow!("sun's dir: {e}"))?;
            (&["dir"], Action::Sun { dir })
        }
        "estimator" => {
            let name = match o.get("name") {
                Some(Value::String(s)) => s
                    .parse::<EstimatorSpec>()
                    .map_err(|e| anyhow!("estimator's name: {e}"))?,
                _ => bail!("estimator needs \"name\" (a string, as --estimator)"),
            };
            (&["name"], Action::Estimator { name })
        }
        "exposure" => {
            let stops = number(o, "stops")?;
            if !(-30.0..=30.0).contains(&stops) {
                bail!("exposure's stops must be in [-30, 30], not {stops}");
            }
            (&["stops"], Action::Exposure { stops })
        }
        "frame" => {
            let index = integer(o, "index", 1, u64::from(u32::MAX))?;
            (
                &["index"],
                Action::Frame {
                    index: index as usize,
                },
            )
        }
        "resize" => (
            &["width", "height"],
            Action::Resize {
                width: integer(o, "width", 1, 16384)? as u32,
                height: integer(o, "height", 1, 16384)? as u32,
            },
        ),
        "drag" => (
            &["from", "to"],
            Action::Drag {
                from: pixel(o, "from")?,
                to: pixel(o, "to")?,
            },
        ),
        "copy_command" => (&[], Action::CopyCommand),
        "frame_all" => (&[], Action::FrameAll),
        "reset" => (&[], Action::Reset),
        other => bail!(
            "unknown action {:?} (orbit, zoom, pan, sun, estimator, exposure, frame, resize, \
             drag, copy_command, frame_all, reset)",
            pin_cli_quote(other)
        ),
    };
    if let Some(k) = o
        .keys()
        .find(|k| !["at_s", "action"].contains(&k.as_str()) && !keys.contains(&k.as_str()))
    {
        bail!(
            "unknown key {:?} for {} (it takes {})",
            pin_cli_quote(k),
            action.name(),
            if keys.is_empty() {
                "none".to_string()
            } else {
                keys.join(", ")
            }
        );
    }
    Ok(Event { at_s, action })
}

/// At most a few dozen characters of the input, quoted back.
fn pin_cli_quote(s: &str) -> String {
    const MAX: usize = 40;
    match s.char_indices().nth(MAX) {
        Some((at, _)) => format!("{}...", &s[..at]),
        None => s.to_string(),
    }
}

fn number(o: &Map<String, Value>, key: &str) -> Result<f64> {
    o.get(key)
        .and_then(Value::as_f64)
        .filter(|x| x.is_finite())
        .ok_or_else(|| anyhow!("{key:?} must be a finite number"))
}

/// An image pixel `[x, y]`: two finite numbers, at least 0 (one past the image's side is a
/// point beside the image, as the mouse could be).
fn pixel(o: &Map<String, Value>, key: &str) -> Result<[f64; 2]> {
    match o.get(key) {
        Some(Value::Array(a)) if a.len() == 2 => {
            let mut p = [0.0; 2];
            for (x, v) in p.iter_mut().zip(a) {
                *x = v
                    .as_f64()
                    .filter(|x| x.is_finite() && *x >= 0.0)
                    .ok_or_else(|| anyhow!("{key:?} must be [x, y], two numbers >= 0"))?;
            }
            Ok(p)
        }
        _ => bail!("{key:?} must be [x, y], two numbers >= 0"),
    }
}

fn integer(o: &Map<String, Value>, key: &str, min: u64, max: u64) -> Result<u64> {
    o.get(key)
        .and_then(Value::as_u64)
        .filter(|x| (min..=max).contains(x))
        .ok_or_else(|| anyhow!("{key:?} must be an integer in [{min}, {max}]"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_action_reads_with_its_parameters() {
        let e = parse(
            r#"[
            {"at_s": 0.5, "action": "orbit", "dx_deg": 10, "dy_deg": -5},
            {"at_s": 0.5, "action": "zoom", "factor": 1.25},
            {"at_s": 1, "action": "pan", "dx": 0.1, "dy": 0},
            {"at_s": 1.5, "action": "sun", "dir": [0, 2, 0]},
            {"at_s": 2, "action": "estimator", "name": "ratio"},
            {"at_s": 2, "action": "exposure", "stops": -1.5},
            {"at_s": 3, "action": "frame", "index": 2},
            {"at_s": 4, "action": "resize", "width": 64, "height": 32},
            {"at_s": 5, "action": "drag", "from": [24, 10.5], "to": [3, 10]},
            {"at_s": 5, "action": "copy_command"},
            {"at_s": 5, "action": "frame_all"},
            {"at_s": 6, "action": "reset"}
        ]"#,
        )
        .unwrap();
        let actions: Vec<Action> = e.iter().map(|e| e.action.clone()).collect();
        assert_eq!(
            actions,
            vec![
                Action::Orbit {
                    dx_deg: 10.0,
                    dy_deg: -5.0
                },
                Action::Zoom { factor: 1.25 },
                Action::Pan { dx: 0.1, dy: 0.0 },
                Action::Sun {
                    dir: [0.0, 2.0, 0.0]
                },
                Action::Estimator {
                    name: EstimatorSpec::RatioTracking
                },
                Action::Exposure { stops: -1.5 },
                Action::Frame { index: 2 },
                Action::Resize {
                    width: 64,
                    height: 32
                },
                Action::Drag {
                    from: [24.0, 10.5],
                    to: [3.0, 10.0]
                },
                Action::CopyCommand,
                Action::FrameAll,
                Action::Reset,
            ]
        );
        assert_eq!(e[7].at_s, 4.0);
    }

    #[test]
    fn bad_events_are_refused_with_their_position() {
        let bad = |t: &str, want: &str| {
            let e = parse(t).unwrap_err().to_string();
            assert!(e.contains(want), "{t}: {e}");
        };
        bad("{}", "a list of events");
        bad(
            r#"[{"at_s": 0, "action": "copy_command", "to": "x"}]"#,
            "(it takes none)",
        );
        bad(
            r#"[{"at_s": 0, "action": "spin"}]"#,
            "event 1: unknown action",
        );
        bad(
            r#"[{"at_s": 0, "action": "orbit", "dx_deg": 1}]"#,
            "\"dy_deg\"",
        );
        bad(
            r#"[{"at_s": 0, "action": "zoom", "factor": 1, "speed": 2}]"#,
            "unknown key \"speed\"",
        );
        bad(
            r#"[{"at_s": -1, "action": "zoom", "factor": 1}]"#,
            "at_s must be",
        );
        bad(r#"[{"at_s": 0, "action": "zoom", "factor": 0}]"#, "> 0");
        bad(
            r#"[{"at_s": 2, "action": "zoom", "factor": 2}, {"at_s": 1, "action": "zoom", "factor": 2}]"#,
            "event 2: at_s 1 comes before",
        );
        bad(
            r#"[{"at_s": 0, "action": "sun", "dir": [0, 0, 0]}]"#,
            "sun's dir",
        );
        bad(
            r#"[{"at_s": 0, "action": "frame", "index": 0}]"#,
            "\"index\"",
        );
        bad(
            r#"[{"at_s": 0, "action": "resize", "width": 0, "height": 4}]"#,
            "\"width\"",
        );
        bad(
            r#"[{"at_s": 0, "action": "estimator", "name": "nope"}]"#,
            "estimator's name",
        );
        bad(
            r#"[{"at_s": 0, "action": "drag", "from": [1, -2], "to": [0, 0]}]"#,
            "\"from\" must be [x, y]",
        );
        bad(
            r#"[{"at_s": 0, "action": "drag", "from": [1, 2]}]"#,
            "\"to\"",
        );
    }
}
