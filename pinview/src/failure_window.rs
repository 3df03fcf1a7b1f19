//! The failure window: an interactive start whose file is refused (a damaged pin file or
//! volume, a bad scene) shows the line until the window is closed (then the same line on
//! stderr and exit 1), so that a start from a desktop, without a terminal in view, says
//! what went wrong. ("Error" in the viewer means the error view: the estimate against a
//! reference.)

struct FailureWindow {
    line: String,
}

impl crate::shell::App for FailureWindow {
    fn ui(&mut self, ui: &mut egui::Ui) {
        egui::CentralPanel::default().show(ui, |ui| {
            ui.heading("pinview");
            ui.label(egui::RichText::new(&self.line).color(egui::Color32::YELLOW));
            ui.label("fix the file (or pick another) and start pinview again");
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
        Box::new(move |_| Ok(Box::new(FailureWindow { line }))),
    )
}
