//! The readouts: the adapter, the passes, the time per pass and samples per second, the
//! time to the first image, the builds in progress and the GPU bytes uploaded.

use pinrender::gpu_render::PassTimeSource;

use super::Viewer;

impl Viewer {
    pub(super) fn readouts(&self, ui: &mut egui::Ui) {
        ui.label(format!(
            "adapter: {} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        ));
        if self.info.device_type == wgpu::DeviceType::Cpu {
            ui.label(
                egui::RichText::new("a CPU adapter: figures are not GPU speed")
                    .color(egui::Color32::LIGHT_RED),
            );
        }
        let passes = self.main.passes();
        let ms = self.main.ms_per_pass();
        if let Some(est) = self.compiling() {
            ui.label(
                egui::RichText::new(format!("compiling {est}... (the image shown stays)"))
                    .color(egui::Color32::YELLOW),
            );
        }
        ui.label(format!("spp {passes}"));
        ui.label(format!(
            "{ms:.2} ms per pass ({})",
            match self.pass_time_source() {
                PassTimeSource::GpuTimestamps => "GPU timestamps",
                PassTimeSource::Wall => "wall time",
            }
        ));
        if ms > 0.0 {
            ui.label(format!("{:.3e} samples/s", self.samples_per_second()));
        }
        if let Some(t) = self.first_preview_s {
            ui.label(format!("first preview after {t:.3} s"));
        }
        if let Some(t) = self.first_image_s {
            ui.label(format!("first image after {t:.3} s"));
        }
        ui.label(format!(
            "longest gap between frames {:.0} ms",
            self.pacer.longest_ms()
        ));
        if let Some(c) = &self.compare.live {
            ui.label(format!(
                "compare {}: spp {}, {:.2} ms per pass; {:.3} s vs {:.3} s",
                c.estimator,
                c.session.passes(),
                self.compare.ms_per_pass(),
                self.compare.seconds(),
                self.main.seconds(),
            ));
        }
        if let Some(r) = self.main.live.as_ref().map(|l| &l.renderer) {
            ui.label("GPU bytes:");
            for (name, bytes) in r.section_bytes() {
                ui.label(format!("  {name}: {bytes}"));
            }
        }
    }

    /// Samples per second of the shown estimator: the image's pixels over its time per pass.
    pub(super) fn samples_per_second(&self) -> f64 {
        samples_per_second(self.view.width, self.view.height, self.main.ms_per_pass())
    }

    /// The bytes of each section the shown estimator's renderer uploaded, as a JSON object.
    pub(super) fn gpu_bytes(&self) -> serde_json::Value {
        gpu_bytes(self.main.live.as_ref().map(|l| &l.renderer))
    }
}

/// Samples per second of a `width` x `height` image at `ms` milliseconds per pass (0 before
/// a pass is measured).
pub fn samples_per_second(width: u32, height: u32, ms: f64) -> f64 {
    if ms > 0.0 {
        f64::from(width) * f64::from(height) / (ms * 1e-3)
    } else {
        0.0
    }
}

/// The bytes of each section `renderer` uploaded, as a JSON object (empty without one).
pub fn gpu_bytes(renderer: Option<&pinrender::gpu_render::GpuRenderer>) -> serde_json::Value {
    let mut out = serde_json::Map::new();
    for (name, bytes) in renderer.map_or(&[][..], |r| r.section_bytes()) {
        out.insert((*name).to_string(), (*bytes).into());
    }
    serde_json::Value::Object(out)
}
