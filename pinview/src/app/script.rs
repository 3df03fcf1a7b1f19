//! The scripted run's end (`--frames`): the screenshot, the EXR, the JSON line, the window
//! screenshot, and closing the window.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};

use super::Viewer;
use crate::{error_view, export};

impl Viewer {
    /// The scripted run's end: outputs, the JSON line, close.
    pub(super) fn finish_script(&mut self, ctx: &egui::Context) -> Result<()> {
        let Some(n) = self.args.frames else {
            return Ok(());
        };
        let passes = self.main.passes();
        // Scripted input ends the run at the latest `events::GRACE` after its last event,
        // with what there is by then.
        let timed_out = self
            .script
            .as_ref()
            .is_some_and(|s| s.timed_out(Instant::now()));
        let waiting = self
            .script
            .as_ref()
            .is_some_and(|s| !s.all_applied() || !s.answered())
            || passes < self.script_passes(n)
            || self.main.in_progress()
            || (self.args.rebake_scale.is_some() && self.bakes.rebaked.is_none())
            || self.awaiting_wanted()
            || self.switching()
            || !self.viewport.settled()
            || !self.compare_done()
            || !self.reference_done()
            || self
                .verify
                .as_ref()
                .is_some_and(crate::verify::Verify::running);
        if waiting && !timed_out {
            return Ok(());
        }
        // The error of the final images, whatever the read-back period.
        if self.error_on {
            self.update_error(ctx, true)?;
        }
        if !timed_out
            && self
                .playback
                .sequence
                .as_ref()
                .is_some_and(|s| s.playing && s.current + 1 < s.len())
        {
            return Ok(());
        }
        let (w, h) = self.images.main.size;
        if let Some(path) = &self.args.screenshot {
            let heat = |k: usize| self.error.heat[k].clone().filter(|_| self.overlays.heat_on);
            let mut rgb = match heat(0) {
                Some(rgb) => rgb,
                None => export::read_texture_rgb(
                    &self.gpu.device,
                    &self.gpu.queue,
                    &self.images.main.texture,
                    w,
                    h,
                )?,
            };
            // Split view: the second estimator's image right of the divider, as shown.
            if let Some(t) = &self.images.compare {
                let right = match heat(1) {
                    Some(rgb) => rgb,
                    None => export::read_texture_rgb(
                        &self.gpu.device,
                        &self.gpu.queue,
                        &t.texture,
                        w,
                        h,
                    )?,
                };
                let x0 = self.split_column(w) as usize;
                let row = w as usize * 3;
                for y in 0..h as usize {
                    let span = y * row + x0 * 3..(y + 1) * row;
                    rgb[span.clone()].copy_from_slice(&right[span]);
                }
            }
            export::write_png(path, w, h, &rgb)?;
            self.toasts
                .say(format!("wrote {}", absolute(path).display()));
        }
        if let Some(path) = &self.args.save {
            let session = self
                .main
                .session_mut()
                .ok_or_else(|| anyhow!("no session"))?;
            let image = session.image().map_err(|e| anyhow!("{e}"))?;
            image
                .write_exr(path)
                .map_err(|e| anyhow!("{}: {e}", path.display()))?;
            self.toasts
                .say(format!("wrote {}", absolute(path).display()));
        }
        let frame = self
            .playback
            .sequence
            .as_ref()
            .map(|s| &s.frames[s.current]);
        let mut json = serde_json::json!({
            "adapter": self.info.name,
            "backend": format!("{:?}", self.info.backend),
            "device_type": format!("{:?}", self.info.device_type),
            "estimator": self.view.estimator.to_string(),
            "width": w,
            "height": h,
            "passes": passes,
            "first_image_s": self.first_image_s.unwrap_or(0.0),
            "first_image_breakdown": self.clock.marks.breakdown(),
            "first_preview_s": self.first_preview_s,
            "warm_up_s": self.warm_up_s,
            "first_image_estimator": self.first_image_estimator.map(|e| e.to_string()),
            "estimator_switch_s": self.estimator_switch_s,
            "ms_per_pass": self.main.ms_per_pass(),
            "pass_time_source": self.pass_time_source().as_str(),
            "frame": frame.map(|f| f.0),
            "frame_path": frame.map(|f| f.1.display().to_string()),
            "frames_played": self.playback.frames_played,
            "playback_fps": self.playback.fps(),
            "pipelines_compiled": self.gpu.stores.compiled(),
            "file": self.medium.path.display().to_string(),
            "samples_per_second": self.samples_per_second(),
            "gpu_bytes": self.gpu_bytes(),
            "longest_frame_gap_ms": self.pacer.longest_ms(),
            "frames_painted": self.pacer.frames(),
            "offscreen": false,
            "viewport": self.viewport.json(),
            "notes": self.notes,
            "messages": self.toasts.said,
            "first_look": crate::open::first_look_json(self.args.first_look),
            // The batch render of the view shown, at the passes shown.
            "command": self.view.command_line(&self.medium, passes),
        });
        if let Some(script) = &self.script {
            json["events"] = script.json();
            json["script_end"] = if timed_out { "timeout" } else { "passes" }.into();
        }
        if let Some(scene) = self.medium.scene() {
            json["instances"] = scene.instances.len().into();
        }
        if let Some((scale, backend, why)) = &self.bakes.rebaked {
            json["rebake"] = serde_json::json!({
                "density_scale": scale,
                "backend": backend,
                "gpu_refused": why,
            });
        }
        if let Some([x, y]) = self.args.pin_at {
            json["pin"] = match self.overlays.held.clone().or_else(|| self.pick_at(x, y)) {
                Some(p) => serde_json::json!({
                    "pixel": [x, y],
                    "cell": p.cell,
                    "direction": p.direction,
                    "reversed": p.reversed,
                    "pins": p.pins.iter().map(|q| serde_json::json!({
                        "t_min": q.entry.t_min,
                        "mask": q.entry.mask,
                    })).collect::<Vec<_>>(),
                }),
                None => serde_json::Value::Null,
            };
        }
        if self.args.window_screenshot.is_some()
            && let Some(r) = self.input.image_rect
        {
            let k = ctx.pixels_per_point();
            json["window_image_rect"] =
                serde_json::json!([r.min.x * k, r.min.y * k, r.max.x * k, r.max.y * k]);
        }
        if self.error_on {
            json["error"] = match (
                self.reference.session(),
                error_view::no_reference_reason(&self.medium),
            ) {
                (Some(r), _) => serde_json::json!({
                    "reference": "ratio",
                    "reference_passes": r.passes(),
                    "reference_seed": r.seed(),
                    "rmse": self.error.rmse[0],
                    "compare_rmse": self.error.rmse[1],
                    "points": self.error.points[0].len(),
                    "update_ms": 1e3 * self.error.update_seconds,
                }),
                (None, why) => serde_json::json!({ "reference": null, "why": why }),
            };
        }
        if let Some(c) = &self.compare.live {
            json["compare"] = serde_json::json!({
                "estimator": c.estimator.to_string(),
                "passes": c.session.passes(),
                "ms_per_pass": self.compare.ms_per_pass(),
                "pass_time_source": c.session.pass_time_source().as_str(),
                "seconds": self.compare.seconds(),
                "first_seconds": self.main.seconds(),
                "clock_ms_per_pass": 1e3 * self.compare.clock.pass_seconds,
                "first_clock_ms_per_pass": 1e3 * self.main.clock.pass_seconds,
                "split_column": self.split_column(w),
            });
        }
        if let Ok(mut o) = self.outcome.lock() {
            if self.args.json {
                o.json = Some(json.to_string());
            }
            o.finished = true;
        }
        self.args.frames = None;
        if let Some(path) = self.args.window_screenshot.clone() {
            // The next frame is captured whole; the window closes once it is written.
            let done = Arc::new(Mutex::new(None));
            let slot = done.clone();
            ctx.send_viewport_cmd(egui::ViewportCommand::Screenshot(
                egui::ScreenshotCallback::new(move |image| {
                    let [w, h] = image.size;
                    let rgb: Vec<u8> = image
                        .pixels
                        .iter()
                        .flat_map(|c| [c.r(), c.g(), c.b()])
                        .collect();
                    let r = export::write_png(&path, w as u32, h as u32, &rgb)
                        .map_err(|e| e.to_string());
                    if let Ok(mut s) = slot.lock() {
                        *s = Some(r);
                    }
                }),
            ));
            self.window_shot = Some((Instant::now(), done));
            return Ok(());
        }
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        Ok(())
    }

    /// Closes the window once a scripted window screenshot is written (or has failed).
    pub(super) fn finish_window_shot(&mut self, ctx: &egui::Context) -> Result<()> {
        let Some((asked, done)) = &self.window_shot else {
            return Ok(());
        };
        let result = done.lock().ok().and_then(|mut d| d.take());
        match result {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(anyhow!(e)),
            // Generous: a screenshot comes a frame or two after it is asked for, but a loaded
            // CPU adapter (lavapipe beside other test processes) can stall frames for seconds.
            None if asked.elapsed() > Duration::from_secs(60) => {
                return Err(anyhow!("the window screenshot did not arrive within 60 s"));
            }
            None => return Ok(()),
        }
        self.window_shot = None;
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        Ok(())
    }
}

/// `path` as an absolute path (the messages say where a file went, whatever the working
/// directory).
fn absolute(path: &std::path::Path) -> std::path::PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}
