//! `pinrender plot-bias`: the plot of `scripts/bias_sweep.sh`'s CSV: the
//! 8x8-block error of pins alone against the pin file's size relative to the f16 density, one
//! colour per scene, one line per octahedral direction set through its cell counts, other
//! bakes (polar, several pins per entry, other jitter) as crosses, the bakes `pinbake bake`
//! chose as triangles, and each scene's noise floor (ratio tracking at the same spp) as a
//! dashed line.

use std::path::PathBuf;

use anyhow::{Context, Result, anyhow, bail};
use clap::Args;
use plotters::prelude::*;

#[derive(Args, Debug)]
pub struct PlotBiasArgs {
    /// The CSV written by scripts/bias_sweep.sh.
    pub csv: PathBuf,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
}

/// One CSV row (the columns the plot uses).
#[derive(Clone, Debug, PartialEq)]
pub struct SweepRow {
    pub scene: String,
    pub config: String,
    pub cells: Option<u32>,
    pub dirs: String,
    pub pins_per_entry: Option<u32>,
    pub jitter: Option<f64>,
    pub ratio: f64,
    pub block: f64,
}

/// Parses the sweep's CSV; a malformed line is an error naming its line number.
pub fn parse(text: &str) -> Result<Vec<SweepRow>> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().context("empty CSV")?.split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or_else(|| anyhow!("CSV has no column '{name}'"))
    };
    let (scene, config, cells, dirs, ppe, jitter, ratio, block) = (
        col("scene")?,
        col("config")?,
        col("cells")?,
        col("dirs")?,
        col("pins_per_entry")?,
        col("jitter")?,
        col("ratio")?,
        col("block8_rms_error")?,
    );
    let mut rows = Vec::new();
    for (i, line) in lines.enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != header.len() {
            bail!(
                "line {}: {} fields, the header has {}",
                i + 2,
                f.len(),
                header.len()
            );
        }
        let num = |k: usize| -> Result<f64> {
            f[k].trim()
                .parse::<f64>()
                .map_err(|e| anyhow!("line {}: '{}': {e}", i + 2, f[k]))
        };
        let opt = |k: usize| f[k].trim().parse::<f64>().ok();
        rows.push(SweepRow {
            scene: f[scene].to_string(),
            config: f[config].to_string(),
            cells: opt(cells).map(|c| c as u32),
            dirs: f[dirs].to_string(),
            pins_per_entry: opt(ppe).map(|c| c as u32),
            jitter: opt(jitter),
            ratio: num(ratio)?,
            block: num(block)?,
        });
    }
    Ok(rows)
}

const COLORS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

pub fn run(a: PlotBiasArgs) -> Result<()> {
    let text = std::fs::read_to_string(&a.csv).with_context(|| format!("{}", a.csv.display()))?;
    let rows = parse(&text).with_context(|| format!("{}", a.csv.display()))?;
    draw(&rows, &a.out).with_context(|| format!("{}", a.out.display()))
}

fn plot_err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plot: {e}")
}

/// The plot (module docs) of `rows` into `out`.
pub fn draw(rows: &[SweepRow], out: &std::path::Path) -> Result<()> {
    let bakes: Vec<&SweepRow> = rows
        .iter()
        .filter(|r| r.ratio > 0.0 && r.block > 0.0)
        .collect();
    if bakes.is_empty() {
        bail!("no bake rows with positive bytes and error");
    }
    let mut scenes: Vec<&str> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
    }
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for r in rows.iter().filter(|r| r.block > 0.0) {
        if r.ratio > 0.0 {
            x0 = x0.min(r.ratio);
            x1 = x1.max(r.ratio);
        }
        y0 = y0.min(r.block);
        y1 = y1.max(r.block);
    }
    let mut canvas = crate::plot_canvas::Canvas::new(out, (900, 600));
    let root = canvas.area();
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "pins alone: 8x8-block error against pin bytes / f16 density bytes",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(
            (x0 * 0.8..x1 * 1.25).log_scale(),
            (y0 * 0.8..y1 * 1.25).log_scale(),
        )
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("pin file bytes / f16 density bytes")
        .y_desc("8x8-block RMS relative error")
        .draw()
        .map_err(plot_err)?;
    for (si, scene) in scenes.iter().enumerate() {
        let color = COLORS[si % COLORS.len()];
        let mine: Vec<&SweepRow> = bakes
            .iter()
            .copied()
            .filter(|r| r.scene == *scene)
            .collect();
        // Octahedral sets at jitter 1 and one pin per entry: a line through the cell counts.
        let mut sets: Vec<&str> = Vec::new();
        for r in &mine {
            if r.cells.is_some()
                && r.dirs.starts_with("octahedral")
                && !sets.contains(&r.dirs.as_str())
            {
                sets.push(&r.dirs);
            }
        }
        let mut labelled = false;
        for set in sets {
            let mut pts: Vec<(f64, f64)> = mine
                .iter()
                .filter(|r| {
                    r.cells.is_some()
                        && r.dirs == set
                        && r.pins_per_entry == Some(1)
                        && r.jitter == Some(1.0)
                })
                .map(|r| (r.ratio, r.block))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            let s = chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                .map_err(plot_err)?;
            if !labelled {
                s.label(*scene).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
                labelled = true;
            }
            chart
                .draw_series(pts.iter().map(|p| Circle::new(*p, 3, color.filled())))
                .map_err(plot_err)?;
            if let Some(last) = pts.last() {
                chart
                    .draw_series(std::iter::once(Text::new(
                        set.replace("octahedral:", "oct"),
                        (last.0 * 1.05, last.1),
                        ("sans-serif", 11).into_font().color(&color),
                    )))
                    .map_err(plot_err)?;
            }
        }
        // Bakes pinbake chose (their cells are written XxYxZ, not one number): triangles.
        let chosen: Vec<(f64, f64)> = mine
            .iter()
            .filter(|r| r.cells.is_none())
            .map(|r| (r.ratio, r.block))
            .collect();
        chart
            .draw_series(
                chosen
                    .iter()
                    .map(|p| TriangleMarker::new(*p, 7, color.filled())),
            )
            .map_err(plot_err)?;
        let others: Vec<(f64, f64)> = mine
            .iter()
            .filter(|r| {
                r.cells.is_some()
                    && !(r.dirs.starts_with("octahedral")
                        && r.pins_per_entry == Some(1)
                        && r.jitter == Some(1.0))
            })
            .map(|r| (r.ratio, r.block))
            .collect();
        chart
            .draw_series(
                others
                    .iter()
                    .map(|p| Cross::new(*p, 5, color.stroke_width(2))),
            )
            .map_err(plot_err)?;
        if let Some(floor) = rows
            .iter()
            .find(|r| r.scene == *scene && r.config == "noise-floor")
        {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(x0 * 0.8, floor.block), (x1 * 1.25, floor.block)],
                    6,
                    4,
                    color.stroke_width(1),
                ))
                .map_err(plot_err)?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerLeft)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    drop(chart);
    drop(root);
    canvas.save()
}
