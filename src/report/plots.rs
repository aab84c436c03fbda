//! The report's figures, drawn as SVG with `plotters` and rasterised to PNG with `resvg` (using the DejaVu Sans
//! font shipped in `assets/fonts`, so PNGs look the same on every machine).
use super::data::{ResultRow, StepCurve};
use super::paper::paper_placed;
use crate::pipeline::store::read::CurveRow;
use anyhow::{Context, Result};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;
use std::sync::Arc;

const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
const SIZE: (u32, u32) = (900, 560);
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(140, 86, 75),
];
const PAPER: RGBColor = RGBColor(90, 90, 90);

/// Writes `name.svg` and `name.png` into `dir` from SVG text.
fn save(dir: &Path, name: &str, svg: &str) -> Result<()> {
    let svg_path = dir.join(format!("{name}.svg"));
    std::fs::write(&svg_path, svg).with_context(|| format!("writing {}", svg_path.display()))?;
    let mut options = resvg::usvg::Options { font_family: "DejaVu Sans".into(), ..resvg::usvg::Options::default() };
    let mut db = resvg::usvg::fontdb::Database::new();
    db.load_font_data(FONT.to_vec());
    db.set_sans_serif_family("DejaVu Sans");
    options.fontdb = Arc::new(db);
    let tree = resvg::usvg::Tree::from_str(svg, &options).context("parsing the plot's SVG")?;
    let mut pixmap = resvg::tiny_skia::Pixmap::new(SIZE.0, SIZE.1).context("allocating the PNG")?;
    pixmap.fill(resvg::tiny_skia::Color::WHITE);
    resvg::render(&tree, resvg::tiny_skia::Transform::default(), &mut pixmap.as_mut());
    let png_path = dir.join(format!("{name}.png"));
    pixmap.save_png(&png_path).with_context(|| format!("writing {}", png_path.display()))
}

fn draw<F>(dir: &Path, name: &str, paint: F) -> Result<()>
where
    F: FnOnce(DrawingArea<SVGBackend, plotters::coord::Shift>) -> Result<(), Box<dyn std::error::Error>>,
{
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
        paint(root).map_err(|e| anyhow::anyhow!("drawing {name}: {e}"))?;
    }
    save(dir, name, &svg)
}

/// Draws the series legend of `chart` in the style every figure shares.
fn draw_legend<'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, CT>,
    position: SeriesLabelPosition,
    font_size: u32,
) -> Result<(), Box<dyn std::error::Error>> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", font_size))
        .draw()?;
    Ok(())
}

/// What a bar figure shows: its file name, caption and rows.
pub struct Bars<'a> {
    pub name: &'a str,
    pub caption: &'a str,
    pub rows: Vec<&'a ResultRow>,
}

/// Bars of `placed` (with 95% whiskers) for every row of `bars`, `missing` written where a row has no results;
/// the paper's value as a grey marker.
pub fn success_bars(dir: &Path, bars: &Bars) -> Result<()> {
    let shown = &bars.rows;
    draw(dir, bars.name, |root| {
        let n = shown.len().max(1) as f64;
        let mut chart = ChartBuilder::on(&root)
            .caption(bars.caption, ("sans-serif", 24))
            .margin(16)
            .x_label_area_size(70)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5..n - 0.5, 0.0..100.0)?;
        let labels: Vec<String> = shown.iter().map(|r| r.label.clone()).collect();
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(shown.len().max(1))
            .x_label_formatter(&|x| {
                let i = x.round();
                if (x - i).abs() < 1e-6 && i >= 0.0 {
                    labels.get(i as usize).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .x_desc("configuration (variant @ training trajectories per robot)")
            .y_desc("placed (% of episodes)")
            .y_label_formatter(&|y| format!("{y:.0}"))
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()?;
        for (i, r) in shown.iter().enumerate() {
            let x = i as f64;
            let Some(pooled) = r.pooled else {
                let style = TextStyle::from(("sans-serif", 16).into_font()).pos(Pos::new(HPos::Center, VPos::Bottom));
                chart.draw_series(std::iter::once(Text::new("missing", (x, 3.0), style)))?;
                continue;
            };
            let p = pooled[2];
            chart.draw_series(std::iter::once(Rectangle::new(
                [(x - 0.3, 0.0), (x + 0.3, 100.0 * p.value)],
                PALETTE[0].mix(0.8).filled(),
            )))?;
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(x, 100.0 * p.low), (x, 100.0 * p.high)],
                BLACK.stroke_width(2),
            )))?;
            for y in [p.low, p.high] {
                chart.draw_series(std::iter::once(PathElement::new(
                    vec![(x - 0.08, 100.0 * y), (x + 0.08, 100.0 * y)],
                    BLACK.stroke_width(2),
                )))?;
            }
            if let Some(paper) = paper_placed(r) {
                chart.draw_series(std::iter::once(Cross::new((x + 0.38, paper), 7, PAPER.stroke_width(3))))?;
            }
        }
        chart
            .draw_series(Vec::<Rectangle<(f64, f64)>>::new())?
            .label("ours (pooled over seeds)")
            .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], PALETTE[0].filled()));
        if shown.iter().any(|r| paper_placed(r).is_some()) {
            chart
                .draw_series(Vec::<Cross<(f64, f64), i32>>::new())?
                .label("paper (Table 1)")
                .legend(|(x, y)| Cross::new((x + 7, y), 6, PAPER.stroke_width(3)));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 15)
    })
}

/// Placed vs training trajectories, one line (with a 95% band) per variant.
pub fn success_vs_size(dir: &Path, rows: &[ResultRow]) -> Result<()> {
    let mut variants: Vec<String> = rows.iter().filter_map(|r| r.variant.clone()).collect();
    variants.dedup();
    variants.sort();
    variants.dedup();
    let sizes: Vec<usize> = rows.iter().filter_map(|r| r.size).collect();
    let (lo, hi) = (sizes.iter().min().copied().unwrap_or(0) as f64, sizes.iter().max().copied().unwrap_or(1) as f64);
    let pad = ((hi - lo) * 0.08).max(8.0);
    draw(dir, "success_vs_size", |root| {
        let mut chart = ChartBuilder::on(&root)
            .caption("Task success vs training data, 95% CI bands", ("sans-serif", 24))
            .margin(16)
            .x_label_area_size(55)
            .y_label_area_size(60)
            .build_cartesian_2d(lo - pad..hi + pad, 0.0..100.0)?;
        chart
            .configure_mesh()
            .x_desc("training trajectories per robot (N)")
            .y_desc("placed (% of episodes)")
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format!("{y:.0}"))
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()?;
        for (i, v) in variants.iter().enumerate() {
            let colour = PALETTE[i % PALETTE.len()];
            let mut pts: Vec<(f64, [f64; 3])> = rows
                .iter()
                .filter(|r| r.variant.as_ref() == Some(v))
                .filter_map(|r| {
                    let p = r.pooled?[2];
                    Some((r.size? as f64, [100.0 * p.value, 100.0 * p.low, 100.0 * p.high]))
                })
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            let band: Vec<(f64, f64)> =
                pts.iter().map(|(x, p)| (*x, p[2])).chain(pts.iter().rev().map(|(x, p)| (*x, p[1]))).collect();
            chart.draw_series(std::iter::once(Polygon::new(band, colour.mix(0.15).filled())))?;
            chart
                .draw_series(LineSeries::new(pts.iter().map(|(x, p)| (*x, p[0])), colour.stroke_width(3)))?
                .label(v.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(3)));
            chart.draw_series(pts.iter().map(|(x, p)| Circle::new((*x, p[0]), 4, colour.filled())))?;
        }
        let paper: Vec<(f64, f64)> = rows.iter().filter_map(|r| Some((r.size? as f64, paper_placed(r)?))).collect();
        if !paper.is_empty() {
            chart
                .draw_series(paper.iter().map(|&(x, y)| Cross::new((x, y), 7, PAPER.stroke_width(3))))?
                .label("paper (Table 1)")
                .legend(|(x, y)| Cross::new((x + 7, y), 6, PAPER.stroke_width(3)));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 15)
    })
}

/// Success against training steps: one panel per stage (reach, pick, place), a line with its 95% band per
/// configuration.
pub fn success_vs_steps(dir: &Path, curves: &[StepCurve]) -> Result<()> {
    let max_step = curves.iter().flat_map(|c| c.points.iter().map(|p| p.0)).max().unwrap_or(1).max(1) as f64;
    draw(dir, "success_vs_steps", |root| {
        let root = root.titled("Success against training steps, 95% CI bands", ("sans-serif", 24))?;
        let panels = root.split_evenly((1, 3));
        for (stage, (panel, name)) in panels.iter().zip(["reached", "picked", "placed"]).enumerate() {
            let mut chart = ChartBuilder::on(panel)
                .caption(name, ("sans-serif", 19))
                .margin(10)
                .x_label_area_size(45)
                .y_label_area_size(if stage == 0 { 50 } else { 30 })
                .build_cartesian_2d(0.0..max_step * 1.04, 0.0..100.0)?;
            chart
                .configure_mesh()
                .x_labels(4)
                .x_desc("training step")
                .y_desc(if stage == 0 { "% of episodes" } else { "" })
                .x_label_formatter(&|x| format!("{x:.0}"))
                .y_label_formatter(&|y| format!("{y:.0}"))
                .label_style(("sans-serif", 13))
                .axis_desc_style(("sans-serif", 15))
                .draw()?;
            for (i, curve) in curves.iter().enumerate() {
                let colour = PALETTE[i % PALETTE.len()];
                let pts: Vec<(f64, [f64; 3])> = curve
                    .points
                    .iter()
                    .map(|(step, r)| {
                        (*step as f64, [100.0 * r[stage].value, 100.0 * r[stage].low, 100.0 * r[stage].high])
                    })
                    .collect();
                let band: Vec<(f64, f64)> =
                    pts.iter().map(|(x, p)| (*x, p[2])).chain(pts.iter().rev().map(|(x, p)| (*x, p[1]))).collect();
                chart.draw_series(std::iter::once(Polygon::new(band, colour.mix(0.15).filled())))?;
                let line =
                    chart.draw_series(LineSeries::new(pts.iter().map(|(x, p)| (*x, p[0])), colour.stroke_width(3)))?;
                if stage == 2 {
                    line.label(curve.label.as_str())
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(3)));
                }
                chart.draw_series(pts.iter().map(|(x, p)| Circle::new((*x, p[0]), 4, colour.filled())))?;
            }
            if stage == 2 && !curves.is_empty() {
                draw_legend(&mut chart, SeriesLabelPosition::UpperLeft, 13)?;
            }
        }
        Ok(())
    })
}

/// Behaviour-cloning loss vs step, train (thin line) and validation (thick line), one colour per curve.
pub fn loss_curves(dir: &Path, curves: &[(String, Vec<CurveRow>)]) -> Result<()> {
    let all = curves.iter().flat_map(|(_, c)| c.iter());
    let max_step = all.clone().map(|p| p.step).max().unwrap_or(1).max(1) as f64;
    let (ymin, ymax) = all.fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.bc), b.max(p.bc)));
    let (ymin, ymax) = if ymin <= ymax {
        (ymin - 0.05 * (ymax - ymin).max(0.1), ymax + 0.05 * (ymax - ymin).max(0.1))
    } else {
        (0.0, 1.0)
    };
    draw(dir, "loss_curves", |root| {
        let mut chart = ChartBuilder::on(&root)
            .caption("Behaviour-cloning loss (largest training set)", ("sans-serif", 24))
            .margin(16)
            .x_label_area_size(55)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..max_step, ymin..ymax)?;
        chart
            .configure_mesh()
            .x_desc("training step")
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format!("{y:.2}"))
            .y_desc("BC negative log-likelihood (nats per action dimension)")
            .label_style(("sans-serif", 15))
            .axis_desc_style(("sans-serif", 17))
            .draw()?;
        for (i, (label, points)) in curves.iter().enumerate() {
            let colour = PALETTE[i % PALETTE.len()];
            for (split, dashed) in [("val", false), ("train", true)] {
                let pts: Vec<(f64, f64)> =
                    points.iter().filter(|p| p.split == split).map(|p| (p.step as f64, p.bc)).collect();
                let style = colour.stroke_width(if dashed { 1 } else { 3 });
                chart
                    .draw_series(LineSeries::new(pts, style))?
                    .label(format!("{label} ({split})"))
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
            }
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 15)
    })
}
