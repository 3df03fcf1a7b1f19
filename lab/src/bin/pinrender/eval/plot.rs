//! PNG plots (plotters, bitmap backend): error against time and the equal-time montage.

use std::path::Path;

use anyhow::{Result, anyhow};
use pinrender::render::{Image, tone_map};
use plotters::prelude::*;

use crate::plot_canvas::Canvas;
use plotters::style::text_anchor::{HPos, Pos, VPos};

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
const LEGEND_W: u32 = 170;
/// The headline figure's legend column, wide enough for "rm@0.015 (best without a bake)".
const HEADLINE_LEGEND_W: u32 = 230;

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

/// One curve of a chart: its legend label, colour, backend and points.
struct Curve {
    label: String,
    color: RGBColor,
    /// A `(gpu)` row: dashed with hollow markers.
    gpu: bool,
    /// Drawn thicker (the estimators that read the bake).
    bold: bool,
    points: Vec<Point>,
}

/// The measured points of `label`'s curve that a log-log chart can place.
fn plottable(r: &SceneResult, label: &str) -> Vec<Point> {
    curve(r, label)
        .into_iter()
        .filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite() && p.1.is_finite())
        .collect()
}

/// Every estimator of `r` as a curve, coloured by its place in `palette`.
fn every_curve(r: &SceneResult, palette: &[String]) -> Vec<Curve> {
    r.images
        .iter()
        .map(|(label, _)| {
            let (base, gpu) = match label.strip_suffix(" (gpu)") {
                Some(b) => (b, true),
                None => (label.as_str(), false),
            };
            Curve {
                label: label.clone(),
                color: color_of(palette, base),
                gpu,
                bold: base.starts_with("pin"),
                points: plottable(r, label),
            }
        })
        .collect()
}

/// The headline curves of `r`: the best CPU estimator that needs no bake (lowest RMSE at the
/// largest budget, the scenes' exact estimators left out), then `pins`, `pinms` and `pinres`
/// where the scene ran them, each in a colour of its own role.
fn headline_curves(r: &SceneResult) -> Vec<Curve> {
    const ROLES: [RGBColor; 4] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
    ];
    let mut out = Vec::new();
    if let Some(best) = best_without_bake(r) {
        out.push(Curve {
            label: format!("{best} (best without a bake)"),
            color: ROLES[0],
            gpu: false,
            bold: false,
            points: plottable(r, &best),
        });
    }
    for (k, name) in ["pins", "pinms", "pinres"].into_iter().enumerate() {
        if r.images.iter().any(|(l, _)| l == name) {
            out.push(Curve {
                label: name.to_string(),
                color: ROLES[k + 1],
                gpu: false,
                bold: true,
                points: plottable(r, name),
            });
        }
    }
    out
}

/// The CPU estimator without a bake whose RMSE is lowest at the largest budget.
fn best_without_bake(r: &SceneResult) -> Option<String> {
    let largest = r
        .rows
        .iter()
        .filter(|x| x.backend == "cpu")
        .map(|x| x.budget_s)
        .fold(f64::NAN, f64::max);
    r.rows
        .iter()
        .filter(|x| {
            x.backend == "cpu"
                && x.budget_s == largest
                && x.rmse.is_finite()
                && super::report::reads_bake(&x.estimator) == Some(false)
        })
        .min_by(|a, b| a.rmse.total_cmp(&b.rmse))
        .map(|x| x.estimator.clone())
}

/// `[lo, hi]` widened about its geometric middle to span at least a factor of 10, so that a
/// log axis has labelled ticks on it.
fn at_least_a_decade(lo: f64, hi: f64) -> (f64, f64) {
    if hi >= 10.0 * lo {
        return (lo, hi);
    }
    let mid = (lo * hi).sqrt();
    (mid / 10f64.sqrt(), mid * 10f64.sqrt())
}

/// A chart's axis names and the x axis' tick labels.
struct Axes {
    x: &'static str,
    y: &'static str,
    x_label: fn(&f64) -> String,
}

/// RMSE against wall time (the error-against-time charts).
const TIME_AXES: Axes = Axes {
    x: "seconds",
    y: "RMSE",
    x_label: |x| format!("{x:.2}"),
};

/// Block error against file bytes (`eval --bytes`).
const BYTES_AXES: Axes = Axes {
    x: "file bytes",
    y: "8x8-block relative error",
    x_label: |x| format!("{x:.0e}"),
};

/// The chart of `curves` in `area` (log-log on `axes`, GPU curves dashed with hollow
/// markers), its axes spanning exactly the curves drawn, with the legend in a column of
/// `legend_w` pixels on the right.
fn draw_chart(
    area: &Area<'_>,
    title: &str,
    curves: &[Curve],
    (font, legend_w): (u32, u32),
    axes: &Axes,
) -> Result<()> {
    let (w, _) = area.dim_in_pixel();
    let (plot_area, legend_area) = area.split_horizontally(w.saturating_sub(legend_w));
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in curves.iter().flat_map(|c| c.points.iter()) {
        x0 = x0.min(p.0);
        x1 = x1.max(p.0);
        y0 = y0.min(p.1);
        y1 = y1.max(p.1);
    }
    if !(x0 < f64::MAX) {
        (x0, x1, y0, y1) = (0.1, 1.0, 0.01, 1.0);
    }
    let (x0, x1) = at_least_a_decade(x0 / 1.3, x1 * 1.3);
    let (y0, y1) = at_least_a_decade(y0 / 1.3, y1 * 1.3);
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(title, ("sans-serif", font + 4))
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(56)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(axes.x)
        .y_desc(axes.y)
        .x_labels(8)
        .y_labels(8)
        .x_label_formatter(&axes.x_label)
        .y_label_formatter(&|y| format!("{y:.1e}"))
        .label_style(("sans-serif", font))
        .draw()
        .map_err(err)?;
    for c in curves {
        let style = c.color.stroke_width(if c.bold { 3 } else { 2 });
        let points = c.points.iter().map(|p| (p.0, p.1));
        if c.gpu {
            chart
                .draw_series(DashedLineSeries::new(points, 6, 4, style))
                .map_err(err)?;
            chart
                .draw_series(c.points.iter().map(|p| Circle::new((p.0, p.1), 3, c.color)))
                .map_err(err)?;
        } else {
            chart
                .draw_series(LineSeries::new(points, style))
                .map_err(err)?;
            chart
                .draw_series(
                    c.points
                        .iter()
                        .map(|p| Circle::new((p.0, p.1), 3, c.color.filled())),
                )
                .map_err(err)?;
        }
    }
    // The legend: a sample of each curve's line and its name, one per row, the text well
    // inside the column so that no glyph is cut.
    let row_h = (font + 6) as i32;
    for (k, c) in curves.iter().enumerate() {
        let y = 28 + k as i32 * row_h;
        let segments: Vec<(i32, i32)> = if c.gpu {
            vec![(6, 12), (16, 22)]
        } else {
            vec![(6, 22)]
        };
        for (a, b) in segments {
            legend_area
                .draw(&PathElement::new(
                    vec![(a, y), (b, y)],
                    c.color.stroke_width(3),
                ))
                .map_err(err)?;
        }
        // The chart is still useful if the legend's text cannot be drawn.
        let _ = legend_area.draw(&Text::new(
            c.label.clone(),
            (30, y),
            ("sans-serif", font)
                .into_font()
                .color(&BLACK)
                .pos(Pos::new(HPos::Left, VPos::Center)),
        ));
    }
    Ok(())
}

/// Log-log RMSE against wall time of one scene, one curve per estimator.
pub fn error_vs_time(path: &Path, r: &SceneResult) -> Result<()> {
    let mut canvas = Canvas::new(path, (860, 520));
    {
        let root = canvas.area();
        let curves = every_curve(r, &palette(&[r]));
        draw_chart(
            &root,
            &format!("{}: RMSE vs wall time", r.name),
            &curves,
            (13, LEGEND_W),
            &TIME_AXES,
        )?;
        root.present().map_err(err)?;
    }
    canvas.save()
}

/// Every scene's chart in one image (two columns), `curves(scene)` on each.
fn grid_of_scenes(
    path: &Path,
    results: &[SceneResult],
    legend_w: u32,
    curves: impl Fn(&SceneResult) -> Vec<Curve>,
) -> Result<()> {
    let cols = if results.len() > 1 { 2 } else { 1 };
    let rows = results.len().div_ceil(cols).max(1);
    let (cw, ch) = (760u32, 440u32);
    let mut canvas = Canvas::new(path, (cw * cols as u32, ch * rows as u32));
    {
        let root = canvas.area();
        let cells = root.split_evenly((rows, cols));
        for (r, cell) in results.iter().zip(&cells) {
            let title = format!("{}: RMSE vs wall time", r.name);
            draw_chart(cell, &title, &curves(r), (12, legend_w), &TIME_AXES)?;
        }
        root.present().map_err(err)?;
    }
    canvas.save()
}

/// The headline figure (`errors.png`): per scene the best estimator without a bake against
/// `pins`, `pinms` and `pinres` (CPU), four colours, the axes spanning those curves only.
pub fn headline(path: &Path, results: &[SceneResult]) -> Result<()> {
    grid_of_scenes(path, results, HEADLINE_LEGEND_W, headline_curves)
}

/// Every estimator of every scene (`errors_all.png`), colours shared across scenes.
pub fn error_vs_time_all(path: &Path, results: &[SceneResult]) -> Result<()> {
    let refs: Vec<&SceneResult> = results.iter().collect();
    let pal = palette(&refs);
    grid_of_scenes(path, results, LEGEND_W, |r| every_curve(r, &pal))
}

/// A curve's points by (scene, representation name): (bytes, block error).
pub type CurvePoints<'a> = dyn Fn(&str, &str) -> Vec<(f64, f64)> + 'a;

/// `eval --bytes`' figure (`bytes.png`): per scene, the 8x8-block error against the file's
/// bytes, one curve per representation (colours shared across scenes), the source file's
/// own point (ratio tracking at the same samples: the noise floor) a curve of one point.
/// `names` are the representations in legend order; `points(scene, name)` gives a curve's
/// (bytes, block error) points (the caller owns the rows, so this module imports no eval
/// mode).
pub fn bytes_chart(
    path: &Path,
    scenes: &[String],
    names: &[String],
    points: &CurvePoints<'_>,
) -> Result<()> {
    let cols = if scenes.len() > 1 { 2 } else { 1 };
    let grid_rows = scenes.len().div_ceil(cols).max(1);
    let (cw, ch) = (900u32, 480u32);
    let mut canvas = Canvas::new(path, (cw * cols as u32, ch * grid_rows as u32));
    {
        let root = canvas.area();
        let cells = root.split_evenly((grid_rows, cols));
        for (scene, cell) in scenes.iter().zip(&cells) {
            let curves: Vec<Curve> = names
                .iter()
                .enumerate()
                .map(|(k, name)| Curve {
                    label: name.clone(),
                    color: COLORS[k % COLORS.len()],
                    gpu: false,
                    bold: name.starts_with("pins"),
                    points: points(scene, name)
                        .into_iter()
                        .filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.1.is_finite())
                        .map(|(x, y)| (x, y, 0))
                        .collect(),
                })
                .filter(|c| !c.points.is_empty())
                .collect();
            let title = format!("{scene}: block error vs file bytes");
            draw_chart(cell, &title, &curves, (12, 250), &BYTES_AXES)?;
        }
        root.present().map_err(err)?;
    }
    canvas.save()
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
    let mut canvas = Canvas::new(path, (cols * cell_w, rows * cell_h));
    let root = canvas.area();
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
        // The images are still useful if a label cannot be drawn.
        let _ = root.draw(&Text::new(
            name.to_string(),
            (x0 as i32 + 3, y0 as i32 + 2),
            ("sans-serif", 13).into_font().color(&BLACK),
        ));
    }
    root.present().map_err(err)?;
    drop(root);
    canvas.save()
}
