//! PNG plots (plotters, bitmap backend): error against time and the equal-time montage.

use std::path::Path;

use anyhow::{Result, anyhow};
use pinrender::render::{Image, tone_map};
use plotters::prelude::*;

use super::SceneResult;
use super::report::{Point, curve};

/// Sixteen colours that stay distinct next to each other (Tableau 10, then six darker or
/// more saturated companions), assigned by estimator so a curve keeps its colour in every
/// scene's plot.
const COLORS: [RGBColor; 16] = [
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
    RGBColor(0, 0, 139),
    RGBColor(139, 0, 0),
    RGBColor(0, 100, 0),
    RGBColor(255, 215, 0),
    RGBColor(112, 128, 144),
    RGBColor(255, 0, 255),
];

/// Width of the legend column to the right of each chart: the legend never covers data.
const LEGEND_W: u32 = 150;

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plot: {e}")
}

/// Estimator names without the backend suffix, in order of first appearance over `results`:
/// index `i` is colour `COLORS[i % 16]`.
fn palette(results: &[&SceneResult]) -> Vec<String> {
    let mut bases: Vec<String> = Vec::new();
    for r in results {
        for (label, _) in &r.images {
            let base = label.strip_suffix(" (gpu)").unwrap_or(label);
            if !bases.iter().any(|b| b == base) {
                bases.push(base.to_string());
            }
        }
    }
    bases
}

fn color_of(palette: &[String], base: &str) -> RGBColor {
    let i = palette.iter().position(|b| b == base).unwrap_or(0);
    COLORS[i % COLORS.len()]
}

/// The chart of one scene in `area` (log-log RMSE against wall time, one curve per
/// estimator, GPU curves dashed with hollow markers) with its legend in a column on the right.
fn draw_scene(area: &Area<'_>, r: &SceneResult, palette: &[String], font: u32) -> Result<()> {
    let (w, _) = area.dim_in_pixel();
    let (plot_area, legend_area) = area.split_horizontally(w.saturating_sub(LEGEND_W));
    let curves: Vec<(String, Vec<Point>)> = r
        .images
        .iter()
        .map(|(e, _)| {
            let c = curve(r, e)
                .into_iter()
                .filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite() && p.1.is_finite())
                .collect();
            (e.clone(), c)
        })
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in curves.iter().flat_map(|(_, c)| c.iter()) {
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
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(
            format!("{}: RMSE vs wall time", r.name),
            ("sans-serif", font + 4),
        )
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(56)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("seconds")
        .y_desc("RMSE")
        .x_label_formatter(&|x| format!("{x:.2}"))
        .y_label_formatter(&|y| format!("{y:.1e}"))
        .label_style(("sans-serif", font))
        .draw()
        .map_err(err)?;
    for (name, c) in &curves {
        let (base, gpu) = match name.strip_suffix(" (gpu)") {
            Some(b) => (b, true),
            None => (name.as_str(), false),
        };
        let color = color_of(palette, base);
        let style = color.stroke_width(if base.starts_with("pin") { 3 } else { 2 });
        let points = c.iter().map(|p| (p.0, p.1));
        if gpu {
            chart
                .draw_series(DashedLineSeries::new(points, 6, 4, style))
                .map_err(err)?;
            chart
                .draw_series(c.iter().map(|p| Circle::new((p.0, p.1), 3, color)))
                .map_err(err)?;
        } else {
            chart
                .draw_series(LineSeries::new(points, style))
                .map_err(err)?;
            chart
                .draw_series(c.iter().map(|p| Circle::new((p.0, p.1), 3, color.filled())))
                .map_err(err)?;
        }
    }
    // The legend: a sample of each curve's line and its name, one per row.
    let row_h = (font + 5) as i32;
    for (k, (name, _)) in curves.iter().enumerate() {
        let y = 28 + k as i32 * row_h;
        let (base, gpu) = match name.strip_suffix(" (gpu)") {
            Some(b) => (b, true),
            None => (name.as_str(), false),
        };
        let color = color_of(palette, base);
        let segments: Vec<(i32, i32)> = if gpu {
            vec![(4, 10), (14, 20)]
        } else {
            vec![(4, 20)]
        };
        for (a, b) in segments {
            legend_area
                .draw(&PathElement::new(
                    vec![(a, y), (b, y)],
                    color.stroke_width(3),
                ))
                .map_err(err)?;
        }
        // Text needs a system font; without one the chart is still useful.
        let _ = legend_area.draw(&Text::new(
            name.clone(),
            (30, y - font as i32 / 2),
            ("sans-serif", font).into_font().color(&BLACK),
        ));
    }
    Ok(())
}

/// Log-log RMSE against wall time of one scene, one curve per estimator.
pub fn error_vs_time(path: &Path, r: &SceneResult) -> Result<()> {
    let root = BitMapBackend::new(path, (860, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    draw_scene(&root, r, &palette(&[r]), 13)?;
    root.present().map_err(err)?;
    Ok(())
}

/// Every scene's chart in one image (two columns), colours shared across scenes.
pub fn error_vs_time_all(path: &Path, results: &[SceneResult]) -> Result<()> {
    let refs: Vec<&SceneResult> = results.iter().collect();
    let pal = palette(&refs);
    let cols = if results.len() > 1 { 2 } else { 1 };
    let rows = results.len().div_ceil(cols).max(1);
    let (cw, ch) = (760u32, 440u32);
    let root = BitMapBackend::new(path, (cw * cols as u32, ch * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let cells = root.split_evenly((rows, cols));
    for (r, cell) in results.iter().zip(&cells) {
        draw_scene(cell, r, &pal, 12)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Panels no larger than this (nearest-neighbour downscale), to keep the PNG small, and no
/// smaller than `PANEL_MIN` (nearest-neighbour upscale), so small renders stay readable.
const PANEL_MAX: u32 = 256;
const PANEL_MIN: u32 = 128;
/// Panels per montage row.
const MONTAGE_COLUMNS: u32 = 6;

/// Reference and each estimator's equal-time image side by side, tone mapped, labelled.
pub fn montage(path: &Path, r: &SceneResult) -> Result<()> {
    let mut panels: Vec<(&str, &Image)> = vec![("reference", &r.reference_image)];
    panels.extend(r.images.iter().map(|(n, i)| (n.as_str(), i)));
    let w = r.reference_image.width;
    let h = r.reference_image.height;
    // Either a whole-number downscale (large renders) or a whole-number upscale (small ones).
    let down = w.max(h).div_ceil(PANEL_MAX).max(1);
    let up = (PANEL_MIN / w.max(h).max(1)).max(1);
    let (pw, ph) = (w.div_ceil(down) * up, h.div_ceil(down) * up);
    let label_h = 18u32;
    let gap = 4u32;
    // A grid of at most MONTAGE_COLUMNS panels per row, each labelled above.
    let cols = (panels.len() as u32).clamp(1, MONTAGE_COLUMNS);
    let rows = (panels.len() as u32).div_ceil(cols);
    let (cell_w, cell_h) = (pw + gap, ph + label_h + gap);
    let root = BitMapBackend::new(path, (cols * cell_w, rows * cell_h)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    for (k, (name, img)) in panels.iter().enumerate() {
        let x0 = (k as u32 % cols) * cell_w;
        let y0 = (k as u32 / cols) * cell_h;
        for y in 0..ph {
            for x in 0..pw {
                let c = img.get(x / up * down, y / up * down).unwrap_or([0.0; 3]);
                let px = RGBColor(
                    tone_map(c[0], 1.0),
                    tone_map(c[1], 1.0),
                    tone_map(c[2], 1.0),
                );
                root.draw_pixel(((x0 + x) as i32, (y0 + label_h + y) as i32), &px)
                    .map_err(err)?;
            }
        }
        // Labels need a system font; without one the images are still useful.
        let _ = root.draw(&Text::new(
            name.to_string(),
            (x0 as i32 + 3, y0 as i32 + 2),
            ("sans-serif", 13).into_font().color(&BLACK),
        ));
    }
    root.present().map_err(err)?;
    Ok(())
}
