//! The window of an interactive start whose scene file is refused: the error line shown
//! until the window is closed (then the same line on stderr and exit 1), so that a scene
//! edited by hand can be read and fixed without a terminal in view.

use eframe::egui;

struct ErrorWindow {
    line: String,
}

impl eframe::App for ErrorWindow {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        egui::CentralPanel::default().show(ui, |ui| {
            ui.heading("pinview");
            ui.label(egui::RichText::new(&self.line).color(egui::Color32::YELLOW));
            ui.label("fix the file and start pinview again");
        });
    }
}

/// Shows `line` in a window titled by `file` until it is closed.
pub fn show(file: &std::path::Path, line: &str) -> Result<(), String> {
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title(format!("pinview - {}", file.display()))
            .with_inner_size([720.0, 160.0]),
        renderer: eframe::Renderer::Wgpu,
        ..Default::default()
    };
    let line = line.to_string();
    eframe::run_native(
        "pinview",
        options,
        Box::new(move |_| Ok(Box::new(ErrorWindow { line }))),
    )
    .map_err(|e| e.to_string())
}
