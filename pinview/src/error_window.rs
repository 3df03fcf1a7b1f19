//! The window of an interactive start whose scene file is refused: the error line shown
//! until the window is closed (then the same line on stderr and exit 1), so that a scene
//! edited by hand can be read and fixed without a terminal in view.

struct ErrorWindow {
    line: String,
}

impl crate::shell::App for ErrorWindow {
    fn ui(&mut self, ui: &mut egui::Ui) {
        egui::CentralPanel::default().show(ui, |ui| {
            ui.heading("pinview");
            ui.label(egui::RichText::new(&self.line).color(egui::Color32::YELLOW));
            ui.label("fix the file and start pinview again");
        });
    }
}

/// Shows `line` in a window titled by `file` until it is closed.
pub fn show(file: &std::path::Path, line: &str) -> Result<(), String> {
    let options = crate::shell::WindowOptions {
        title: format!("pinview - {}", file.display()),
        inner_size: [720.0, 160.0],
        wgpu: egui_wgpu::WgpuConfiguration::default(),
    };
    let line = line.to_string();
    crate::shell::run(
        options,
        Box::new(move |_| Ok(Box::new(ErrorWindow { line }))),
    )
}
