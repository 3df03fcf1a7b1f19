//! Export: the displayed image as PNG, the accumulation as EXR, and the equivalent batch
//! command (copied to the clipboard and printed).

use std::path::PathBuf;

use anyhow::anyhow;

use super::Viewer;

/// The last command copied, shown under the buttons.
#[derive(Debug, Default)]
pub struct Export {
    pub command: String,
}

impl Viewer {
    pub(super) fn export_controls(&mut self, ui: &mut egui::Ui) {
        let passes = self.main.passes();
        ui.horizontal(|ui| {
            if ui.button("save PNG").clicked() {
                let (w, h) = self.images.main.size;
                let path = absolute(format!("pinview-{passes}spp.png"));
                self.say_saved(
                    match crate::export::read_texture_rgb(
                        &self.gpu.device,
                        &self.gpu.queue,
                        &self.images.main.texture,
                        w,
                        h,
                    )
                    .and_then(|rgb| crate::export::write_png(&path, w, h, &rgb))
                    {
                        Ok(()) => format!("wrote {}", path.display()),
                        Err(e) => e.to_string(),
                    },
                );
            }
            if ui.button("save EXR").clicked()
                && let Some(s) = self.main.session_mut()
            {
                // The image holds whole passes (one in progress is finished first): the name
                // says how many it holds, as `copy command`'s --spp does.
                let said = match s.image().map_err(|e| anyhow!("{e}")).and_then(|i| {
                    let path = absolute(format!("pinview-{}spp.exr", s.passes()));
                    i.write_exr(&path)
                        .map(|()| path)
                        .map_err(|e| anyhow!("{e}"))
                }) {
                    Ok(path) => format!("wrote {}", path.display()),
                    Err(e) => e.to_string(),
                };
                self.say_saved(said);
            }
            if ui.button("copy command").clicked() {
                let session = self.main.session_mut();
                match crate::clipboard::copy_command(ui.ctx(), session, &self.view, &self.medium) {
                    Ok(command) => self.export.command = command,
                    Err(e) => self.toasts.say(e.to_string()),
                }
            }
        });
        if !self.export.command.is_empty() {
            ui.add(
                egui::TextEdit::multiline(&mut self.export.command.as_str())
                    .desired_rows(4)
                    .font(egui::TextStyle::Monospace),
            );
        }
    }
}

/// A file name in the working directory as an absolute path (the status line shows where it
/// went).
fn absolute(name: String) -> PathBuf {
    std::path::absolute(&name).unwrap_or_else(|_| PathBuf::from(name))
}

impl Viewer {
    /// A save's message: a toast, and a line on stdout (the terminal keeps where it went).
    fn say_saved(&mut self, message: String) {
        let _ = pin_cli::outln!("{message}");
        self.toasts.say(message);
    }
}
