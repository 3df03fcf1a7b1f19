//! The controls panel: the file, the bake and re-bake, the sequence, the estimator and the
//! second side, the look, the overlays, the error view and export.

use pinrender::render::EstimatorSpec;

use super::Viewer;
use crate::{error_view, pin_overlay};

impl Viewer {
    pub(super) fn controls(&mut self, ui: &mut egui::Ui) {
        ui.heading("pinview");
        ui.label(self.medium.path.display().to_string());
        if let Some(v) = &self.verify {
            v.show(ui);
        }
        if let Some(job) = &self.bakes.bake {
            ui.add(egui::ProgressBar::new(job.progress()).text("baking pins"));
        }
        if self.medium.is_volume && self.playback.sequence.is_none() {
            let mut scale = self.bakes.density_scale;
            let r = ui.add(
                egui::Slider::new(&mut scale, 0.01..=100.0)
                    .logarithmic(true)
                    .text("density scale"),
            );
            if r.changed() {
                self.bakes.density_scale = scale;
            }
            // A re-bake when the slider is let go (or typed in), not on every step of a drag.
            let settled = r.drag_stopped() || (r.changed() && !r.dragged());
            let baking = self.bakes.rebake.as_ref().map(|(s, _)| *s);
            if settled
                && baking != Some(self.bakes.density_scale)
                && let Err(e) = self.start_rebake(self.bakes.density_scale)
            {
                self.toasts.say(e.to_string());
            }
            if let Some((s, job)) = &self.bakes.rebake {
                ui.add(
                    egui::ProgressBar::new(job.progress())
                        .text(format!("re-baking on the GPU at {s:.3}")),
                );
            }
        }
        ui.horizontal(|ui| {
            if ui.button("reset view").clicked() {
                self.reset_view();
            }
            if ui
                .button(if self.paused { "resume" } else { "pause" })
                .clicked()
            {
                self.paused = !self.paused;
            }
        });
        // What a scene leaves out is off whether or not its section is open.
        if self.medium.scene().is_some() {
            self.compare_wanted = None;
            self.overlays.pins_on = false;
            self.overlays.grid_on = false;
            self.error_on = false;
        }
        if !self.error_on {
            self.overlays.heat_on = false;
        }
        if self.playback.sequence.is_some() {
            section("sequence", true).show(ui, |ui| self.sequence_controls(ui));
        }
        section("estimator", true).show(ui, |ui| self.estimator_controls(ui));
        section("sun", true).show(ui, |ui| self.sun_controls(ui));
        section("export", true).show(ui, |ui| self.export_controls(ui));
        section("readouts", true).show(ui, |ui| self.readouts(ui));
        section("camera and look", false).show(ui, |ui| self.look_controls(ui));
        let overlays = self.overlays.pins_on || self.overlays.grid_on;
        section("overlays", overlays).show(ui, |ui| self.overlay_controls(ui));
        section("error view", self.error_on).show(ui, |ui| self.error_controls(ui));
    }

    /// A sequence's frame, play and pause, steps, rate, passes per frame and scrub.
    fn sequence_controls(&mut self, ui: &mut egui::Ui) {
        let mut go_to = None;
        if let Some(s) = &mut self.playback.sequence {
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
            ui.add(
                egui::Slider::new(&mut self.playback.fps, super::playback::FPS)
                    .text("fps (at most)"),
            );
            // The same value as --frame-passes: the passes each frame holds before the next.
            ui.add(
                egui::Slider::new(&mut self.args.frame_passes, 1..=256)
                    .logarithmic(true)
                    .text("passes per frame"),
            );
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
            self.toasts.say(e.to_string());
        }
    }

    /// The estimator and the second side's.
    fn estimator_controls(&mut self, ui: &mut egui::Ui) {
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
        if self.medium.scene().is_none() {
            self.compare_controls(ui, &available);
        }
    }

    /// The camera, the lights, the material, the exposure and the image's size.
    fn look_controls(&mut self, ui: &mut egui::Ui) {
        let v = &mut self.view;
        ui.add(egui::Slider::new(&mut v.look.fov, 5.0..=120.0).text("fov"));
        ui.add(egui::Slider::new(&mut v.look.albedo, 0.0..=1.0).text("albedo"));
        ui.add(egui::Slider::new(&mut v.look.g, -0.95..=0.95).text("g"));
        ui.add(egui::Slider::new(&mut v.look.max_bounces, 0..=64).text("bounces"));
        ui.add(egui::Slider::new(&mut v.look.sun_radiance, 0.0..=20.0).text("sun radiance"));
        ui.add(egui::Slider::new(&mut v.look.env_radiance, 0.0..=5.0).text("sky radiance"));
        crate::look_controls::exposure_stops(ui, &mut v.exposure);
        self.viewport_controls(ui);
    }

    /// The sun's direction: its numbers and the gizmo, a section of its own and open, since
    /// the sun is what an artist turns most.
    fn sun_controls(&mut self, ui: &mut egui::Ui) {
        let v = &mut self.view;
        ui.label(format!(
            "sun direction {:.2}, {:.2}, {:.2} (drag the point, or ctrl-drag the image)",
            v.look.sun_dir[0], v.look.sun_dir[1], v.look.sun_dir[2]
        ));
        crate::sun_gizmo::sun_gizmo(ui, &mut v.look.sun_dir, v.origin, v.target);
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
            ui.label("pins under the cursor and the cell grid: one medium only, not a scene");
            return;
        }
        ui.checkbox(
            &mut self.overlays.pins_on,
            "pins under the cursor (click holds)",
        );
        ui.checkbox(&mut self.overlays.grid_on, "box and cell grid");
        if self.medium.pins().is_none() && (self.overlays.pins_on || self.overlays.grid_on) {
            ui.label("no pins yet (the bake is running)");
            return;
        }
        if !self.overlays.pins_on {
            return;
        }
        match &self.overlays.pick {
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
            ui.label("error view: one medium only, not a scene");
            return;
        }
        ui.checkbox(&mut self.error_on, "reference and RMSE plot");
        if !self.error_on {
            self.overlays.heat_on = false;
            return;
        }
        ui.checkbox(
            &mut self.overlays.heat_on,
            "error view (|estimate - reference|)",
        );
        if let Some(why) = error_view::no_reference_reason(&self.medium) {
            ui.label(egui::RichText::new(why).color(egui::Color32::YELLOW));
            return;
        }
        let passes = self.reference.passes();
        ui.label(format!(
            "reference: ratio tracking, {passes} passes (itself noisy; read every {} ms, \
             {:.1} ms a read)",
            error_view::ERROR_PERIOD.as_millis(),
            1e3 * self.error.update_seconds
        ));
        let names = [Some(self.view.estimator), self.compare.estimator()];
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

    /// The image's size: following the window at a resolution scale, or fixed.
    pub(super) fn viewport_controls(&mut self, ui: &mut egui::Ui) {
        let v = &mut self.viewport;
        ui.horizontal(|ui| {
            ui.checkbox(&mut v.follow, "fill the window");
            ui.add_enabled(
                v.follow,
                egui::Slider::new(&mut v.scale_percent, super::viewport::SCALE_PERCENT)
                    .suffix("%")
                    .text("resolution"),
            );
        });
        ui.label(format!(
            "image {} x {} pixels",
            self.view.width, self.view.height
        ));
    }
}

/// A collapsible section of the panel, open at first where `open`.
fn section(title: &str, open: bool) -> egui::CollapsingHeader {
    egui::CollapsingHeader::new(title).default_open(open)
}
