//! The background check of a pin file's sections: every section's checksum and value
//! (`pinrt::PinGrid::verify`, pin-format's full check: the pins, cell index, majorants,
//! density and control the estimators read, and the small rest), run on a worker thread
//! when a pin file opens, so the first image never waits for it. Opening maps the file and
//! checks its header and lengths only; a section whose bytes were damaged since the bake
//! (a flipped bit in the pins) renders without error, and this check is what says so.

use std::sync::Arc;
use std::thread::JoinHandle;

use crate::open::Medium;

/// A check running on a worker.
pub struct Verify {
    handle: Option<JoinHandle<Option<String>>>,
    /// The finished check's warning, where the file failed it (kept for the window).
    warning: Option<String>,
}

impl Verify {
    /// Starts checking `medium`'s pin file; `None` for a volume (its pins are baked here, in
    /// memory, and a volume file has no checksums of its own) or a scene.
    pub fn start(medium: &Medium) -> Option<Self> {
        if medium.is_volume || medium.scene().is_some() {
            return None;
        }
        let grid = Arc::clone(medium.pins()?);
        let path = medium.path.display().to_string();
        let handle = std::thread::Builder::new()
            .name("pinview verify".into())
            .spawn(move || warning(&path, grid.verify().err().map(|e| e.to_string())))
            .ok()?;
        Some(Self {
            handle: Some(handle),
            warning: None,
        })
    }

    /// The warning, once, in the frame the worker is found finished with the file failing
    /// its check (the window's note).
    pub fn poll(&mut self) -> Option<String> {
        if !self.handle.as_ref()?.is_finished() {
            return None;
        }
        let handle = self.handle.take()?;
        self.warning = handle
            .join()
            .unwrap_or_else(|_| Some("the background check of the pin file panicked".to_string()));
        self.warning.clone()
    }

    /// The warning over the controls, in red, once the check has failed.
    pub fn show(&self, ui: &mut egui::Ui) {
        if let Some(w) = &self.warning {
            ui.label(egui::RichText::new(w).color(egui::Color32::from_rgb(255, 90, 70)));
        }
    }

    /// Whether the check is still running.
    pub fn running(&self) -> bool {
        self.handle.is_some()
    }
}

/// The warning for `path` when its check failed with `error`.
fn warning(path: &str, error: Option<String>) -> Option<String> {
    let e = error?;
    // pinrt's error names the file already.
    let line = if e.contains(path) {
        e
    } else {
        format!("{path}: {e}")
    };
    Some(format!(
        "warning: the pin file fails its check; the image may be wrong ({line})"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_warning_names_the_file_once() {
        let w = warning("/a/b.pin", Some("/a/b.pin: pins checksum".into())).unwrap();
        assert_eq!(w.matches("/a/b.pin").count(), 1, "{w}");
        assert!(warning("/a/b.pin", None).is_none());
        let w = warning("/a/b.pin", Some("bad".into())).unwrap();
        assert!(w.contains("/a/b.pin: bad"), "{w}");
    }
}
