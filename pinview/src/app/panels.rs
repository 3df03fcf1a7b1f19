//! The controls panel: the file, the bake and re-bake, the sequence, the estimator and the
//! second side, the look, the overlays, the error view and export.

use std::path::PathBuf;

use anyhow::anyhow;

use pinrender::render::EstimatorSpec;

use super::Viewer;
use crate::{error_view, export, pin_overlay};

impl Viewer {
    pub(super) fn controls(&mut self, ui: &mut egui::Ui) {
        ui.heading("pinview");
        ui.label(self.medium.path.display().to_string());
        if let Some(v) = &self.verify {
            v.show(ui);
        }
        if let Some(job) = &self.bake {
            ui.add(egui::ProgressBar::new(job.progress()).text("baking pins"));
        }
        if self.medium.is_volume && self.sequence.is_none() {
            let mut scale = self.density_scale;
            let r = ui.add(
                egui::Slider::new(&mut scale, 0.01..=100.0)
                    .logarithmic(true)
                    .text("density scale"),
            );
            if r.changed() {
                self.density_scale = scale;
            }
            // A re-bake when the slider is let go (or typed in), not on every step of a drag.
            let settled = r.drag_stopped() || (r.changed() && !r.dragged());
            let baking = self.rebake.as_ref().map(|(s, _)| *s);
            if settled
                && baking != Some(self.density_scale)
                && let Err(e) = self.start_rebake(self.density_scale)
            {
                self.status = e.to_string();
            }
            if let Some((s, job)) = &self.rebake {
                ui.add(
                    egui::ProgressBar::new(job.progress())
                        .text(format!("re-baking on the GPU at {s:.3}")),
                );
            }
        }
        let mut go_to = None;
        if let Some(s) = &mut self.sequence {
            ui.separator();
            ui.label(format!(
                "frame {} ({} of {})",
                s.frames[s.current].0,
                s.current + 1,
                s.len()
            ));
            ui.horizontal(|ui| {
                if ui
                    .button(if s.playing { "pause" } else { "play" })
                    .clicked()
                {
                    s.playing = !s.playing;
                }
                if ui.button("<").clicked() {
                    go_to = Some((s.current + s.len() - 1) % s.len());
                }
                if ui.button(">").clicked() {
                    go_to = Some((s.current + 1) % s.len());
                }
            });
            // Positions from 1, as the label's "(2 of 5)".
            let mut at = s.current + 1;
            if ui
                .add(egui::Slider::new(&mut at, 1..=s.len()).text("scrub"))
                .changed()
            {
                go_to = Some(at - 1);
            }
        }
        if let Some(i) = go_to
            && let Err(e) = self.go_to_frame(i)
        {
            self.status = e.to_string();
        }
        ui.separator();
        let available = self.medium.estimators();
        egui::ComboBox::from_label("estimator")
            .selected_text(self.view.estimator.to_string())
            .show_ui(ui, |ui| {
                for e in &available {
                    ui.selectable_value(&mut self.wanted, *e, e.to_string());
                }
            });
        if crate::scene_framing::scene_panel(ui, &self.medium, &available) {
            crate::scene_framing::frame_all(&mut self.view, &self.medium);
        }
        if self.medium.scene().is_some() {
            self.compare_wanted = None;
        } else {
            self.compare_controls(ui, &available);
        }
        let v = &mut self.view;
        ui.add(egui::Slider::new(&mut v.look.fov, 5.0..=120.0).text("fov"));
        ui.add(egui::Slider::new(&mut v.look.albedo, 0.0..=1.0).text("albedo"));
        ui.add(egui::Slider::new(&mut v.look.g, -0.95..=0.95).text("g"));
        ui.add(egui::Slider::new(&mut v.look.max_bounces, 0..=64).text("bounces"));
        ui.add(egui::Slider::new(&mut v.look.sun_radiance, 0.0..=20.0).text("sun radiance"));
        ui.add(egui::Slider::new(&mut v.look.env_radiance, 0.0..=5.0).text("sky radiance"));
        crate::look_controls::exposure_stops(ui, &mut v.exposure);
        ui.label(format!(
            "sun direction {:.2}, {:.2}, {:.2} (drag the point, or ctrl-drag the image)",
            v.look.sun_dir[0], v.look.sun_dir[1], v.look.sun_dir[2]
        ));
        crate::sun_gizmo::sun_gizmo(ui, &mut v.look.sun_dir, v.origin, v.target);
        ui.horizontal(|ui| {
            if ui.button("reset view").clicked() {
                let (o, t) = self.medium.home();
                self.view.origin = o;
                self.view.target = t;
            }
            if ui
                .button(if self.paused { "resume" } else { "pause" })
                .clicked()
            {
                self.paused = !self.paused;
            }
        });
        ui.separator();
        self.overlay_controls(ui);
        ui.separator();
        self.error_controls(ui);
        ui.separator();
        self.readouts(ui);
        ui.separator();
        self.export(ui);
        if !self.status.is_empty() {
            ui.separator();
            ui.label(egui::RichText::new(&self.status).color(egui::Color32::YELLOW));
        }
    }

    /// The second estimator's menu (split view).
    pub(super) fn compare_controls(&mut self, ui: &mut egui::Ui, available: &[EstimatorSpec]) {
        egui::ComboBox::from_label("compare with")
            .selected_text(
                self.compare_wanted
                    .map_or("none".to_string(), |e| e.to_string()),
            )
            .show_ui(ui, |ui| {
                ui.selectable_value(&mut self.compare_wanted, None, "none");
                for e in available {
                    ui.selectable_value(&mut self.compare_wanted, Some(*e), e.to_string());
                }
            });
        if let Some(e) = self.compare_wanted
            && !available.contains(&e)
        {
            ui.label(format!("{e}: not answered by this file (yet)"));
        }
    }

    /// The overlays' toggles and the picked entry's readout.
    pub(super) fn overlay_controls(&mut self, ui: &mut egui::Ui) {
        if self.medium.scene().is_some() {
            self.pins_on = false;
            self.grid_on = false;
            ui.label("pins under the cursor and the cell grid: one medium only, not a scene");
            return;
        }
        ui.checkbox(&mut self.pins_on, "pins under the cursor (click holds)");
        ui.checkbox(&mut self.grid_on, "box and cell grid");
        if self.medium.pins().is_none() && (self.pins_on || self.grid_on) {
            ui.label("no pins yet (the bake is running)");
            return;
        }
        if !self.pins_on {
            return;
        }
        match &self.pick {
            Some(p) => {
                for line in pin_overlay::describe(p) {
                    ui.label(egui::RichText::new(line).monospace().size(10.0));
                }
            }
            None => {
                ui.label("the cursor's ray misses the box");
            }
        }
    }

    /// The error view's toggles, the reference's state and the RMSE-against-time plot.
    pub(super) fn error_controls(&mut self, ui: &mut egui::Ui) {
        if self.medium.scene().is_some() {
            self.error_on = false;
            self.heat_on = false;
            ui.label("error view: one medium only, not a scene");
            return;
        }
        ui.checkbox(&mut self.error_on, "reference and RMSE plot");
        if !self.error_on {
            self.heat_on = false;
            return;
        }
        ui.checkbox(&mut self.heat_on, "error view (|estimate - reference|)");
        if let Some(why) = error_view::no_reference_reason(&self.medium) {
            ui.label(egui::RichText::new(why).color(egui::Color32::YELLOW));
            return;
        }
        let passes = self.reference.as_ref().map_or(0, |r| r.session.passes());
        ui.label(format!(
            "reference: ratio tracking, {passes} passes (itself noisy; read every {} ms, \
             {:.1} ms a read)",
            error_view::ERROR_PERIOD.as_millis(),
            1e3 * self.error.update_seconds
        ));
        let names = [
            Some(self.view.estimator),
            self.compare.as_ref().map(|c| c.estimator),
        ];
        for (k, name) in names.iter().enumerate() {
            if let (Some(n), Some(e)) = (name, self.error.rmse[k]) {
                ui.label(format!("RMSE {n}: {e:.4e}"));
            }
        }
        let points = &self.error.points;
        egui_plot::Plot::new("pinview rmse")
            .height(160.0)
            .x_axis_label("seconds")
            .y_axis_label("RMSE")
            .legend(egui_plot::Legend::default())
            .show(ui, |plot| {
                for (k, name) in names.iter().enumerate() {
                    if let Some(n) = name {
                        plot.line(egui_plot::Line::new(n.to_string(), points[k].clone()));
                    }
                }
            });
    }

    pub(super) fn export(&mut self, ui: &mut egui::Ui) {
        let passes = self.session.as_ref().map_or(0, |s| s.passes());
        ui.horizontal(|ui| {
            if ui.button("save PNG").clicked() {
                let (w, h) = self.target.size;
                let path = absolute(format!("pinview-{passes}spp.png"));
                self.status = match export::read_texture_rgb(
                    &self.gpu.device,
                    &self.gpu.queue,
                    &self.target.texture,
                    w,
                    h,
                )
                .and_then(|rgb| export::write_png(&path, w, h, &rgb))
                {
                    Ok(()) => format!("wrote {}", path.display()),
                    Err(e) => e.to_string(),
                };
            }
            if ui.button("save EXR").clicked()
                && let Some(s) = &mut self.session
            {
                // The image holds whole passes (one in progress is finished first): the name
                // says how many it holds, as `copy command`'s --spp does.
                self.status = match s.image().map_err(|e| anyhow!("{e}")).and_then(|i| {
                    let path = absolute(format!("pinview-{}spp.exr", s.passes()));
                    i.write_exr(&path)
                        .map(|()| path)
                        .map_err(|e| anyhow!("{e}"))
                }) {
                    Ok(path) => format!("wrote {}", path.display()),
                    Err(e) => e.to_string(),
                };
            }
            if ui.button("copy command").clicked() {
                let session = self.session.as_mut();
                match crate::clipboard::copy_command(ui.ctx(), session, &self.view, &self.medium) {
                    Ok(command) => self.command = command,
                    Err(e) => self.status = e.to_string(),
                }
            }
        });
        if !self.command.is_empty() {
            ui.add(
                egui::TextEdit::multiline(&mut self.command.as_str())
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
