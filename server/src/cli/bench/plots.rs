//! The bench's plots (plotters, SVG and PNG): per scene and yardstick (bounce count), relative
//! L2 error against bake seconds, apply milliseconds and bundle bytes, log-log, one colour per
//! method, the Pareto front joined by a line, and on the bake-time plot the reference solver's
//! fitted cost at equal error at the same bounce count (seconds per light set, one dashed curve
//! per texel count). The bounce count is in every title and file name
//! (`<scene>-<bounces>-error-vs-<axis>`, e.g. `cornell-all-bounces-error-vs-bake.svg`): errors
//! against different yardsticks never share a plot or a front.
//!
//! Text is drawn with the bundled DejaVu Sans (`server/assets/fonts`, through plotters'
//! `ab_glyph` feature), so a headless machine needs no fontconfig.

use std::path::{Path, PathBuf};
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::equal_error::BruteForceFit;
use super::measure::{bounces_label, BenchMethod};
use super::pareto::pareto_front;
use super::results::BenchResults;
use lightfarm_proto::bounces::BounceCount;

static FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

/// The three cost axes of the plots and tables.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CostAxis {
    BakeSeconds,
    ApplyMs,
    Bytes,
}

impl CostAxis {
    pub const ALL: [CostAxis; 3] = [CostAxis::BakeSeconds, CostAxis::ApplyMs, CostAxis::Bytes];

    pub fn slug(self) -> &'static str {
        match self {
            CostAxis::BakeSeconds => "bake",
            CostAxis::ApplyMs => "apply",
            CostAxis::Bytes => "bytes",
        }
    }

    pub fn description(self) -> &'static str {
        match self {
            CostAxis::BakeSeconds => "bake time (s)",
            CostAxis::ApplyMs => "apply time per frame (ms, 1 thread)",
            CostAxis::Bytes => "bundle bytes",
        }
    }

    pub fn of(self, point: &super::measure::BenchPoint) -> f64 {
        match self {
            CostAxis::BakeSeconds => point.bake_seconds,
            CostAxis::ApplyMs => point.apply_ms,
            CostAxis::Bytes => point.bundle_bytes as f64,
        }
    }
}

/// One written plot.
#[derive(Clone, Debug)]
pub struct PlotFiles {
    pub scene: String,
    pub bounces: BounceCount,
    pub axis: CostAxis,
    pub svg: PathBuf,
    pub png: PathBuf,
}

fn colour(method: BenchMethod) -> RGBColor {
    match method {
        BenchMethod::Full => RGBColor(214, 39, 40),
        BenchMethod::MrtLightfield => RGBColor(31, 119, 180),
        BenchMethod::MrtTraced => RGBColor(44, 160, 44),
        BenchMethod::Drt => RGBColor(148, 103, 189),
        BenchMethod::Dnrt => RGBColor(255, 127, 14),
    }
}

pub(super) fn short(v: f64) -> String {
    let a = v.abs();
    if a >= 1e9 {
        format!("{:.1}G", v / 1e9)
    } else if a >= 1e6 {
        format!("{:.1}M", v / 1e6)
    } else if a >= 1e3 {
        format!("{:.1}k", v / 1e3)
    } else if a >= 1.0 {
        format!("{v:.1}")
    } else if a >= 0.01 {
        format!("{v:.3}")
    } else {
        format!("{v:.1e}")
    }
}

struct PlotData {
    title: String,
    x_label: &'static str,
    /// Names the yardstick: "relative L2 error vs the all-bounce reference …".
    y_label: String,
    /// (cost, error, method, on the front)
    points: Vec<(f64, f64, BenchMethod, bool)>,
    /// Dashed reference curves: label and (cost, error) points.
    curves: Vec<(String, Vec<(f64, f64)>)>,
}

fn bounds(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if lo.is_finite() {
        (lo / 1.5, hi * 1.5)
    } else {
        (1e-3, 1.0)
    }
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, data: &PlotData) -> anyhow::Result<()> {
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("plot: {e}");
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (x0, x1) = bounds(
        data.points
            .iter()
            .map(|p| p.0)
            .chain(data.curves.iter().flat_map(|c| c.1.iter().map(|p| p.0))),
    );
    let (y0, y1) = bounds(data.points.iter().map(|p| p.1));
    let mut chart = ChartBuilder::on(&root)
        .caption(&data.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc(data.x_label)
        .y_desc(data.y_label.as_str())
        .x_labels(8)
        .y_labels(8)
        .x_label_formatter(&|v| short(*v))
        .y_label_formatter(&|v| short(*v))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(|e| err(&e))?;
    for method in BenchMethod::ALL {
        let points: Vec<(f64, f64)> = data
            .points
            .iter()
            .filter(|p| p.2 == method && p.0 > 0.0 && p.1 > 0.0)
            .map(|p| (p.0, p.1))
            .collect();
        if points.is_empty() {
            continue;
        }
        let c = colour(method);
        // Distinct shapes, so methods with equal numbers (one-block scenes) stay visible.
        match method {
            BenchMethod::Full | BenchMethod::MrtLightfield => {
                chart
                    .draw_series(points.iter().map(|&p| Circle::new(p, 4, c.filled())))
                    .map_err(|e| err(&e))?
                    .label(method.label())
                    .legend(move |(x, y)| Circle::new((x, y), 4, c.filled()));
            }
            BenchMethod::MrtTraced | BenchMethod::Dnrt => {
                chart
                    .draw_series(
                        points
                            .iter()
                            .map(|&p| TriangleMarker::new(p, 6, c.stroke_width(2))),
                    )
                    .map_err(|e| err(&e))?
                    .label(method.label())
                    .legend(move |(x, y)| TriangleMarker::new((x, y), 6, c.stroke_width(2)));
            }
            BenchMethod::Drt => {
                chart
                    .draw_series(points.iter().map(|&p| Cross::new(p, 5, c.stroke_width(2))))
                    .map_err(|e| err(&e))?
                    .label(method.label())
                    .legend(move |(x, y)| Cross::new((x, y), 5, c.stroke_width(2)));
            }
        }
    }
    let mut front: Vec<(f64, f64)> = data
        .points
        .iter()
        .filter(|p| p.3)
        .map(|p| (p.0, p.1))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    chart
        .draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(1)))
        .map_err(|e| err(&e))?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], BLACK));
    chart
        .draw_series(
            front
                .iter()
                .map(|&p| Circle::new(p, 7, BLACK.stroke_width(1))),
        )
        .map_err(|e| err(&e))?;
    for (k, (label, curve)) in data.curves.iter().enumerate() {
        let grey = RGBColor(90 + 40 * (k as u8 % 3), 90, 90);
        let inside: Vec<(f64, f64)> = curve
            .iter()
            .copied()
            .filter(|p| p.0 >= x0 && p.0 <= x1 && p.1 >= y0 && p.1 <= y1)
            .collect();
        if inside.len() < 2 {
            continue;
        }
        chart
            .draw_series(DashedLineSeries::new(inside, 6, 4, grey.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(label.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], grey));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 13))
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

pub(super) fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is compiled in; it parses or the build is broken.
        if plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_err() {
            panic!("the bundled DejaVu Sans does not parse");
        }
    });
}

/// `all-bounces`, `1-bounce`, `3-bounces`: a bounce count in a file name.
pub fn bounces_slug(bounces: BounceCount) -> String {
    bounces_label(bounces).replace(' ', "-")
}

/// Writes `<scene>-<bounces>-error-vs-<axis>.{svg,png}` into `out` for every scene, yardstick
/// and axis.
pub fn write_plots(results: &BenchResults, out: &Path) -> anyhow::Result<Vec<PlotFiles>> {
    register_font();
    let mut files = Vec::new();
    let mut groups: Vec<(&str, BounceCount)> = Vec::new();
    for row in &results.rows {
        let group = (row.point.scene.as_str(), row.point.bounces);
        if !groups.contains(&group) {
            groups.push(group);
        }
    }
    for (scene, bounces) in groups {
        let rows: Vec<_> = results
            .rows
            .iter()
            .filter(|r| r.point.scene == scene && r.point.bounces == bounces)
            .collect();
        for axis in CostAxis::ALL {
            let coordinates: Vec<(f64, f64)> = rows
                .iter()
                .map(|r| (axis.of(&r.point), r.point.relative_l2))
                .collect();
            let front = pareto_front(&coordinates);
            let points = rows
                .iter()
                .zip(&coordinates)
                .zip(&front)
                .map(|((r, c), &f)| (c.0, c.1, r.point.method, f))
                .collect();
            let mut curves = Vec::new();
            if axis == CostAxis::BakeSeconds {
                for fit in results
                    .brute_force
                    .iter()
                    .filter(|b| b.scene == scene && b.bounces == bounces)
                {
                    let model = BruteForceFit {
                        scale: fit.scale,
                        exponent: fit.exponent,
                        reference_rays: results.plan.reference_rays,
                        seconds_fixed: fit.seconds_fixed,
                        seconds_per_ray: fit.seconds_per_ray,
                    };
                    let curve = (0..=40)
                        .map(|i| 2f64.powf(1.0 + 0.3 * i as f64))
                        .map(|rays| (model.seconds_for_rays(rays), model.error_at(rays)))
                        .collect();
                    curves.push((
                        format!(
                            "path tracer T{}, {} (s per light set)",
                            fit.texels_per_face,
                            bounces_label(bounces)
                        ),
                        curve,
                    ));
                }
            }
            let data = PlotData {
                title: format!(
                    "{scene}, {}: error vs {}",
                    bounces_label(bounces),
                    axis.description()
                ),
                x_label: axis.description(),
                y_label: format!(
                    "relative L2 vs the reference at {} (mean over light sets)",
                    bounces_label(bounces)
                ),
                points,
                curves,
            };
            let stem = format!("{scene}-{}-error-vs-{}", bounces_slug(bounces), axis.slug());
            let svg = out.join(format!("{stem}.svg"));
            let png = out.join(format!("{stem}.png"));
            draw(SVGBackend::new(&svg, (860, 580)).into_drawing_area(), &data)?;
            draw(
                BitMapBackend::new(&png, (860, 580)).into_drawing_area(),
                &data,
            )?;
            files.push(PlotFiles {
                scene: scene.to_string(),
                bounces,
                axis,
                svg,
                png,
            });
        }
    }
    Ok(files)
}
