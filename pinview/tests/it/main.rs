//! pinview in a real window: under Xvfb (one private server per test) on the machine's
//! adapter (lavapipe on CI). Each test compares what the viewer writes with `pinrender
//! render --backend gpu` for the same flags, seed and passes, or checks a failure line.

mod clipboard;
mod command;
mod compare;
mod contract;
mod divider;
mod ending;
mod error_view;
mod failures;
mod front;
mod input_script;
mod offscreen;
mod overlay;
mod pacing;
mod rebake;
mod scene;
mod scene_framing;
mod sequence;
mod sun_gizmo;
mod support;
mod toasts;
mod verify;
mod viewport;
