//! The background check of a pin file's sections: every section's checksum and value
//! (`pinrt::PinGrid::verify`, pin-format's full check: the pins, cell index, majorants,
//! density and control the estimators read, and the small rest), run on a worker thread
//! when a pin file or a scene of pin files opens, so the first image never waits for it.
//! Opening maps the file and checks its header and lengths only; a section whose bytes were
//! damaged since the bake (a flipped bit in the pins) renders without error, and this check
//! is what says so.

use std::thread::JoinHandle;

use crate::open::Medium;

/// A check running on a worker.
pub struct Verify {
    handle: Option<JoinHandle<Option<String>>>,
    /// The finished check's warning, where the file failed it (kept for the window).
    warning: Option<String>,
}

impl Verify {
    /// Starts checking the pin files `medium` renders from (a pin file, or the pin files a
    /// scene's assets name); `None` where there is none (a volume: its pins are baked here,
    /// in memory, and a volume file has no checksums of its own).
    pub fn start(medium: &Medium) -> Option<Self> {
        let files = medium.pin_files();
        if files.is_empty() {
            return None;
        }
        let handle = std::thread::Builder::new()
            .name("pinview verify".into())
            .spawn(move || {
                let failures: Vec<(String, String)> = files
                    .iter()
                    .filter_map(|g| {
                        let path = g.path().map_or(String::new(), |p| p.display().to_string());
                        g.verify().err().map(|e| (path, e.to_string()))
                    })
                    .collect();
                warning(&failures)
            })
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

/// The warning for the files that failed their check (`(path, error)`, in order): the
/// first one's line, and how many more failed.
fn warning(failures: &[(String, String)]) -> Option<String> {
    let (path, e) = failures.first()?;
    // pinrt's error names the file already.
    let line = if e.contains(path.as_str()) {
        e.clone()
    } else {
        format!("{path}: {e}")
    };
    let more = match failures.len() - 1 {
        0 => String::new(),
        n => format!(
            "; {n} more pin file{} fail too",
            if n == 1 { "" } else { "s" }
        ),
    };
    Some(format!(
        "warning: the pin file fails its check; the image may be wrong ({line}{more})"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_warning_names_the_first_file_once_and_counts_the_rest() {
        let one = |p: &str, e: &str| (p.to_string(), e.to_string());
        let w = warning(&[one("/a/b.pin", "/a/b.pin: pins checksum")]).unwrap();
        assert_eq!(w.matches("/a/b.pin").count(), 1, "{w}");
        assert!(!w.contains("more"), "{w}");
        assert!(warning(&[]).is_none());
        let w = warning(&[
            one("/a/b.pin", "bad"),
            one("/c.pin", "bad"),
            one("/d.pin", "x"),
        ])
        .unwrap();
        assert!(
            w.contains("/a/b.pin: bad; 2 more pin files fail too"),
            "{w}"
        );
    }
}
