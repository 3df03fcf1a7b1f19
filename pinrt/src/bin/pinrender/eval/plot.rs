//! PNG plots (plotters, bitmap backend): error against time and the equal-time montage.

use std::path::Path;

use anyhow::{Result, anyhow};
use pinrt::render::{Image, tone_map};
use plotters::prelude::*;

use super::SceneResult;
use super::report::{Point, curve};

const COLORS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(0, 0, 0),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plot: {e}")
}

/// Log-log RMSE against wall time, one curve per estimator.
pub fn error_vs_time(path: &Path, r: &SceneResult) -> Result<()> {
    let ests: Vec<String> = r.images.iter().map(|(e, _)| e.clone()).collect();
    let curves: Vec<(String, Vec<Point>)> = ests
        .iter()
        .map(|e| {
            let c = curve(r, e)
                .into_iter()
                .filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite() && p.1.is_finite())
                .collect();
            (e.clone(), c)
        })
        .collect();
    let pts = curves.iter().flat_map(|(_, c)| c.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        x0 = x0.min(p.0);
        x1 = x1.max(p.0);
        y0 = y0.min(p.1);
        y1 = y1.max(p.1);
    }
    if !(x0 < f64::MAX) {
        (x0, x1, y0, y1) = (0.1, 1.0, 0.01, 1.0);
    }
    let (x0, x1) = (x0 / 1.3, x1 * 1.3);
    let (y0, y1) = (y0 / 1.3, y1 * 1.3);
    let root = BitMapBackend::new(path, (720, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("{}: RMSE vs wall time (CPU; \"(gpu)\": WGSL)", r.name),
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("seconds")
        .y_desc("RMSE")
        .x_label_formatter(&|x| format!("{x:.2}"))
        .y_label_formatter(&|y| format!("{y:.1e}"))
        .draw()
        .map_err(err)?;
    // One colour per estimator; its GPU curve is dashed with hollow markers.
    let mut bases: Vec<&str> = Vec::new();
    for (name, c) in &curves {
        let (base, gpu) = match name.strip_suffix(" (gpu)") {
            Some(b) => (b, true),
            None => (name.as_str(), false),
        };
        let i = bases.iter().position(|b| *b == base).unwrap_or_else(|| {
            bases.push(base);
            bases.len() - 1
        });
        let color = COLORS[i % COLORS.len()];
        let style = if base.starts_with("pin") {
            color.stroke_width(2)
        } else {
            color.stroke_width(1)
        };
        let points = c.iter().map(|p| (p.0, p.1));
        let series = if gpu {
            chart
                .draw_series(DashedLineSeries::new(points, 6, 4, style))
                .map_err(err)?
        } else {
            chart
                .draw_series(LineSeries::new(points, style))
                .map_err(err)?
        };
        series.label(name.as_str()).legend(move |(x, y)| {
            if gpu {
                PathElement::new(vec![(x, y), (x + 6, y)], color)
            } else {
                PathElement::new(vec![(x, y), (x + 16, y)], color)
            }
        });
        if gpu {
            chart
                .draw_series(c.iter().map(|p| Circle::new((p.0, p.1), 3, color)))
                .map_err(err)?;
        } else {
            chart
                .draw_series(c.iter().map(|p| Circle::new((p.0, p.1), 3, color.filled())))
                .map_err(err)?;
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// Panels no larger than this (nearest-neighbour downscale), to keep the PNG small.
const PANEL_MAX: u32 = 256;

/// Reference and each estimator's equal-time image side by side, tone mapped, labelled.
pub fn montage(path: &Path, r: &SceneResult) -> Result<()> {
    let mut panels: Vec<(&str, &Image)> = vec![("reference", &r.reference_image)];
    panels.extend(r.images.iter().map(|(n, i)| (n.as_str(), i)));
    let w = r.reference_image.width;
    let h = r.reference_image.height;
    let scale = w.max(h).div_ceil(PANEL_MAX).max(1);
    let (pw, ph) = (w.div_ceil(scale), h.div_ceil(scale));
    let label_h = 18u32;
    let gap = 2u32;
    let total_w = panels.len() as u32 * (pw + gap);
    let root = BitMapBackend::new(path, (total_w, ph + label_h)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    for (k, (name, img)) in panels.iter().enumerate() {
        let x0 = k as u32 * (pw + gap);
        for y in 0..ph {
            for x in 0..pw {
                let c = img.get(x * scale, y * scale).unwrap_or([0.0; 3]);
                let px = RGBColor(
                    tone_map(c[0], 1.0),
                    tone_map(c[1], 1.0),
                    tone_map(c[2], 1.0),
                );
                root.draw_pixel(((x0 + x) as i32, (label_h + y) as i32), &px)
                    .map_err(err)?;
            }
        }
        // Labels need a system font; without one the images are still useful.
        let _ = root.draw(&Text::new(
            name.to_string(),
            (x0 as i32 + 3, 2),
            ("sans-serif", 13).into_font().color(&BLACK),
        ));
    }
    root.present().map_err(err)?;
    Ok(())
}
