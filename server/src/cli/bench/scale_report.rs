//! The scale sweep's figure and markdown section (from `OUT/scale.json`, see [`super::scale`]):
//! four log–log panels against block count (bake seconds per stage, peak resident memory,
//! stored bytes per section, frame milliseconds) and two tables, with each quantity's growth
//! exponent (the least-squares slope of log cost against log blocks) said in words; and a tiled
//! sweep's section (from `OUT/scale_tiled.json`): one table of the same lights moved in levels
//! of more and more copies, with the growth exponents.

use std::fmt::Write;
use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use super::plots::{register_font, short};
use super::report::relative_to;
use super::scale::{MovedLights, ScalePoint, ScaleSweep};

/// Stages or sections shorter than this share of the largest one are left out of the tables
/// and panels (they are in `scale.json`).
const MINOR: f64 = 0.01;

/// One named series of (blocks, value) points.
type Series = (String, Vec<(f64, f64)>);

/// The least-squares slope of `ln y` against `ln x` (None with fewer than two usable points
/// or one block count).
pub fn growth_exponent(points: &[(f64, f64)]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    let n = logs.len() as f64;
    if logs.len() < 2 {
        return None;
    }
    let (mx, my) = (
        logs.iter().map(|p| p.0).sum::<f64>() / n,
        logs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// The names of `named` (per point) whose largest value is at least [`MINOR`] of the largest
/// value of any, in first-seen order.
fn major(points: &[ScalePoint], named: impl Fn(&ScalePoint) -> Vec<(String, f64)>) -> Vec<String> {
    let all: Vec<Vec<(String, f64)>> = points.iter().map(named).collect();
    let top = all.iter().flatten().map(|(_, v)| *v).fold(0.0f64, f64::max);
    let mut names: Vec<String> = Vec::new();
    for (name, v) in all.iter().flatten() {
        if *v >= MINOR * top && !names.contains(name) {
            names.push(name.clone());
        }
    }
    names
}

fn stages(p: &ScalePoint) -> Vec<(String, f64)> {
    p.stage_seconds.clone()
}

fn sections(p: &ScalePoint) -> Vec<(String, f64)> {
    p.sections
        .iter()
        .map(|(n, b)| (n.clone(), *b as f64))
        .collect()
}

/// The value of `name` (0 when absent).
fn value_of(named: &[(String, f64)], name: &str) -> f64 {
    named
        .iter()
        .filter(|(n, _)| n == name)
        .fold(0.0, |sum, (_, v)| sum + v)
}

/// The series of one panel: each major name's values, then the total.
fn named_series(
    sweep: &ScaleSweep,
    named: impl Fn(&ScalePoint) -> Vec<(String, f64)> + Copy,
    total: impl Fn(&ScalePoint) -> f64,
) -> Vec<Series> {
    let x = |p: &ScalePoint| p.blocks as f64;
    let mut out: Vec<Series> = major(&sweep.points, named)
        .into_iter()
        .map(|name| {
            let v = sweep
                .points
                .iter()
                .map(|p| (x(p), value_of(&named(p), &name)))
                .collect();
            (name, v)
        })
        .collect();
    out.push((
        "total".to_string(),
        sweep.points.iter().map(|p| (x(p), total(p))).collect(),
    ));
    out
}

fn frame_series(sweep: &ScaleSweep) -> Vec<Series> {
    let s = |name: &str, f: &dyn Fn(&ScalePoint) -> f64| -> Series {
        (
            name.to_string(),
            sweep
                .points
                .iter()
                .map(|p| (p.blocks as f64, f(p)))
                .collect(),
        )
    };
    vec![
        s("apply, 1 bounce", &|p| p.apply_one_ms),
        s("apply, all bounces", &|p| p.apply_converged_ms),
        s("relight all (direct + 1 bounce)", &|p| {
            p.relight_all.total_ms
        }),
        s("one light moves (direct + 1 bounce)", &|p| {
            p.one_light.total_ms
        }),
    ]
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
    y_label: &str,
    series: &[Series],
) -> anyhow::Result<()> {
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("plot: {e}");
    let finite = || {
        series
            .iter()
            .flat_map(|s| s.1.iter())
            .filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.1.is_finite())
    };
    let (x0, x1) = finite().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| {
        (lo.min(p.0), hi.max(p.0))
    });
    let (y0, y1) = finite().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| {
        (lo.min(p.1), hi.max(p.1))
    });
    if !(x0.is_finite() && y0.is_finite()) {
        return Ok(());
    }
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(
            (x0 / 1.3..x1 * 1.3).log_scale(),
            (y0 / 1.5..y1 * 1.5).log_scale(),
        )
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc("blocks")
        .y_desc(y_label)
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&|v| short(*v))
        .y_label_formatter(&|v| short(*v))
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(|e| err(&e))?;
    for (k, (name, points)) in series.iter().enumerate() {
        let c = PALETTE[k % PALETTE.len()];
        let points: Vec<(f64, f64)> = points
            .iter()
            .copied()
            .filter(|p| p.1 > 0.0 && p.1.is_finite())
            .collect();
        let label = match growth_exponent(&points) {
            Some(e) => format!("{name} (∝ N^{e:.2})"),
            None => name.clone(),
        };
        chart
            .draw_series(LineSeries::new(points.clone(), c.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x - 8, y), (x + 8, y)], c.stroke_width(2))
            });
        chart
            .draw_series(points.iter().map(|&p| Circle::new(p, 3, c.filled())))
            .map_err(|e| err(&e))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 11))
        .draw()
        .map_err(|e| err(&e))?;
    Ok(())
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    sweep: &ScaleSweep,
) -> anyhow::Result<()> {
    root.fill(&WHITE)
        .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    let panels = root.split_evenly((2, 2));
    panel(
        &panels[0],
        "bake (cold, 2 cores)",
        "seconds",
        &named_series(sweep, stages, |p| p.bake_seconds),
    )?;
    panel(
        &panels[1],
        "peak resident memory of the bake",
        "GB",
        &[(
            "peak RSS".to_string(),
            sweep
                .points
                .iter()
                .map(|p| (p.blocks as f64, p.peak_rss_bytes as f64 / 1e9))
                .collect(),
        )],
    )?;
    panel(
        &panels[2],
        "bundle bytes per section (stored)",
        "bytes",
        &named_series(sweep, sections, |p| p.bundle_bytes as f64),
    )?;
    panel(
        &panels[3],
        "frame time (median, 1 thread)",
        "ms",
        &frame_series(sweep),
    )?;
    root.present().map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    Ok(())
}

/// Writes `scale.svg` and `scale.png` into `out`.
pub fn write_scale_plot(sweep: &ScaleSweep, out: &Path) -> anyhow::Result<(PathBuf, PathBuf)> {
    register_font();
    let svg = out.join("scale.svg");
    let png = out.join("scale.png");
    draw(
        SVGBackend::new(&svg, (1200, 900)).into_drawing_area(),
        sweep,
    )?;
    draw(
        BitMapBackend::new(&png, (1200, 900)).into_drawing_area(),
        sweep,
    )?;
    Ok((svg, png))
}

/// "12.3 MB", or "—" for none.
fn megabytes(b: f64) -> String {
    if b > 0.0 {
        format!("{:.1} MB", b / 1e6)
    } else {
        "—".to_string()
    }
}

/// "∝ N^1.02" for a series, or "" when it has no slope.
fn grows(points: &[(f64, f64)]) -> String {
    growth_exponent(points).map_or("(not measured)".to_string(), |e| format!("∝ N^{e:.2}"))
}

/// "∝ N^1.02" for `f` of each point against its block count.
fn growth(points: &[ScalePoint], f: impl Fn(&ScalePoint) -> f64) -> String {
    grows(
        &points
            .iter()
            .map(|p| (p.blocks as f64, f(p)))
            .collect::<Vec<_>>(),
    )
}

/// The growth of the moved lights' figures both sections report: the median light at one
/// bounce, at all bounces, by feedback, and the median light's time per texel reached.
fn moved_growth(points: &[ScalePoint]) -> [String; 4] {
    let median = |m: Option<MovedLights>| m.map_or(f64::NAN, |m| m.median_ms);
    [
        growth(points, |p| median(p.moved_lights)),
        growth(points, |p| median(p.moved_lights_all)),
        growth(points, |p| median(p.moved_lights_feedback)),
        growth(points, |p| {
            p.moved_lights.map_or(f64::NAN, |m| m.us_per_texel)
        }),
    ]
}

/// "T=8, 1024 rays, tolerance 0.001; measured by `…` on CPU (`nproc` = 2) in 3.5 min": how a
/// sweep was baked and where it ran.
fn baked_and_measured(sweep: &ScaleSweep) -> String {
    format!(
        "T={}, {} rays, tolerance {}; measured by `{}` on {} (`nproc` = {}) in {:.1} min",
        sweep.settings.texels_per_face,
        sweep.settings.rays_per_texel,
        sweep.settings.tolerance,
        sweep.command_line,
        sweep.machine.cpu,
        sweep.machine.nproc,
        sweep.wall_seconds / 60.0,
    )
}

/// The markdown section; image links are relative to `base` (the markdown's directory).
pub fn scale_markdown(sweep: &ScaleSweep, png: &Path, base: &Path) -> String {
    let mut md = String::new();
    let w = &mut md;
    let points = &sweep.points;
    let blocks: Vec<String> = points.iter().map(|p| p.blocks.to_string()).collect();
    let _ = writeln!(w, "## Scale: levels of {} blocks\n", blocks.join(", "));
    let _ = writeln!(
        w,
        "Generated grid levels (`scripts/gen_level.py --seed {} --dynamic 0`; the 1,000-block \
         one is `scenes/grid1000`), {}. Bake: cold (no shape cache), peak resident memory of the \
         process during the bake and its encoding. Frames: one thread, every light of the \
         level, DRT (MRT in a level without clutter); \"one light\" moves light 0 and relights by its change \
         (`frame-time --update one-light`), \"relight all\" lights every light where it reaches \
         (its rooms' texels, shadow rays against the occluders there: the same bits as \
         lighting every texel) and applies everything; both include their direct light. Error: DRT at all bounces against the \
         path tracer at all bounces ({} rays) on up to {} texels within {} m of up to {} of \
         the level's lights (those lights alone); the reference's own noise (two seeds) beside \
         it.\n",
        sweep.settings.seed,
        baked_and_measured(sweep),
        sweep.settings.reference_rays,
        super::scale::ERROR_TEXELS,
        super::scale::ERROR_RADIUS,
        super::scale::ERROR_LIGHTS,
    );
    let _ = writeln!(w, "![scale sweep]({})\n", relative_to(png, base).display());

    let stage_names = major(points, stages);
    let section_names = major(points, sections);
    let _ = write!(w, "| blocks | texels | pillars | lights | bake s |");
    for s in &stage_names {
        let _ = write!(w, " {s} s |");
    }
    let _ = write!(w, " peak RSS | bundle |");
    for s in &section_names {
        let _ = write!(w, " {s} |");
    }
    let _ = writeln!(w, " bytes per block |");
    let columns = 8 + stage_names.len() + section_names.len();
    let _ = writeln!(w, "|{}", "---|".repeat(columns));
    for p in points {
        let _ = write!(
            w,
            "| {} | {} | {} | {} | {:.1} |",
            p.blocks, p.texels, p.clutter, p.lights, p.bake_seconds
        );
        for s in &stage_names {
            let _ = write!(w, " {:.1} |", value_of(&stages(p), s));
        }
        let _ = write!(
            w,
            " {:.2} GB | {} |",
            p.peak_rss_bytes as f64 / 1e9,
            megabytes(p.bundle_bytes as f64)
        );
        for s in &section_names {
            let _ = write!(w, " {} |", megabytes(value_of(&sections(p), s)));
        }
        let _ = writeln!(
            w,
            " {:.0} kB |",
            p.bundle_bytes as f64 / p.blocks.max(1) as f64 / 1e3
        );
    }
    let _ = writeln!(w);
    let _ = writeln!(
        w,
        "| blocks | apply, 1 bounce | apply, all bounces (applications) | relight all: direct + operators | one light: direct + operators | texels it reaches | drift | error, all bounces (texels) | reference noise |\n\
         |---|---|---|---|---|---|---|---|---|"
    );
    for p in points {
        let _ = writeln!(
            w,
            "| {} | {:.2} ms | {:.2} ms ({}) | {:.1} + {:.2} = {:.1} ms | {:.3} + {:.3} = {:.3} ms | {} | {:.1e} | {:.4} ({}) | {:.4} |",
            p.blocks,
            p.apply_one_ms,
            p.apply_converged_ms,
            p.converged_applications,
            p.relight_all.direct_ms,
            p.relight_all.operator_ms,
            p.relight_all.total_ms,
            p.one_light.direct_ms,
            p.one_light.operator_ms,
            p.one_light.total_ms,
            p.one_light_texels,
            p.one_light_drift,
            p.relative_l2,
            p.error_texels,
            p.reference_noise
        );
    }
    let _ = writeln!(w);
    let moved: Vec<_> = points
        .iter()
        .filter_map(|p| p.moved_lights.map(|m| (p, m)))
        .collect();
    if !moved.is_empty() {
        let _ = writeln!(
            w,
            "Moving each of up to {} lights spread over the level's list, one at a time, relit \
             by its change (direct light included; each light's median of {} frames; one \
             bounce; all \
             bounces: `Converged` to 0.001, bounce by bounce where the change's light goes, or \
             the whole-level solve where that costs less; and `Feedback` by the change: one \
             sparse bounce a frame of the change and of the light not yet bounced where it is \
             due, all bounces arriving over the next frames, its largest lag behind all \
             bounces after the last frame and its largest error once settled, relative L2 over \
             the level):\n\n\
             | blocks | lights moved | median light | slowest light | median light, all bounces | slowest light, all bounces | median light, feedback | slowest light, feedback | feedback lag / settled | texels reached (median) | per texel reached (median) |\n\
             |---|---|---|---|---|---|---|---|---|---|---|",
            super::scale::MOVED_LIGHTS,
            super::scale::MOVED_FRAMES_FACTOR * sweep.settings.frames,
        );
        for (p, m) in &moved {
            let ms = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.3} ms"));
            let (all, feedback) = (p.moved_lights_all, p.moved_lights_feedback);
            let errors = match (p.feedback_lag, p.feedback_settled) {
                (Some(lag), Some(settled)) => format!("{lag:.1e} / {settled:.1e}"),
                _ => "—".to_string(),
            };
            let _ = writeln!(
                w,
                "| {} | {} | {:.3} ms | {:.3} ms | {} | {} | {} | {} | {errors} | {} | {:.3} µs |",
                p.blocks,
                m.lights,
                m.median_ms,
                m.max_ms,
                ms(all.map(|a| a.median_ms)),
                ms(all.map(|a| a.max_ms)),
                ms(feedback.map(|a| a.median_ms)),
                ms(feedback.map(|a| a.max_ms)),
                m.median_texels,
                m.us_per_texel
            );
        }
        let _ = writeln!(w);
    }
    let growths = moved_growth(points);
    let _ = writeln!(
        w,
        "Growth with the block count N (least-squares slope on the log–log points): bake {}, \
         peak memory {}, bundle bytes {}, apply at one bounce {}, at all bounces {}, relighting \
         everything {}, moving light 0 {}, moving a light (the median light) {}, at all bounces \
         {}, by feedback {}, per texel it reaches {}. Relighting everything lights each of the level's \
         lights (which grow with it) where that light reaches and applies every operator: it \
         grows with the lights times what each one reaches, not with the lights times the \
         level's texels; moving one light lights only the texels it reaches, which depend on \
         where the light is, not on the level's size.\n",
        growth(points, |p| p.bake_seconds),
        growth(points, |p| p.peak_rss_bytes as f64),
        growth(points, |p| p.bundle_bytes as f64),
        growth(points, |p| p.apply_one_ms),
        growth(points, |p| p.apply_converged_ms),
        growth(points, |p| p.relight_all.total_ms),
        growth(points, |p| p.one_light.total_ms),
        growths[0],
        growths[1],
        growths[2],
        growths[3],
    );
    md
}

/// The markdown section of a tiled sweep (`bench --scale ... --tile B`): the same lights in
/// the same neighbourhood, moved in levels that differ only in how many copies surround it.
pub fn tiled_markdown(sweep: &ScaleSweep) -> String {
    let mut md = String::new();
    let w = &mut md;
    let points = &sweep.points;
    let tile = sweep.settings.tile.unwrap_or(0);
    let blocks: Vec<String> = points.iter().map(|p| p.blocks.to_string()).collect();
    let _ = writeln!(
        w,
        "## Scale, one neighbourhood: copies of a {tile}-block level, {} blocks\n",
        blocks.join(", ")
    );
    let _ = writeln!(
        w,
        "Each level is copies of one generated {tile}-block level joined in a row \
         (`scripts/gen_level.py --seed {} --dynamic 0 --tile {tile}`), {}. The lights moved \
         are the first copy's (up to {}), so every level moves the same lights through the \
         same rooms and only the level around them grows; one thread, direct light included, \
         each light's median of {} frames.\n",
        sweep.settings.seed,
        baked_and_measured(sweep),
        super::scale::MOVED_LIGHTS,
        super::scale::MOVED_FRAMES_FACTOR * sweep.settings.frames,
    );
    let _ = writeln!(
        w,
        "| blocks | copies | texels | lights | bake s | apply, 1 bounce | lights moved | median light | slowest light | median light, all bounces | median light, feedback | texels reached (median) | per texel reached |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    let ms = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.3} ms"));
    for p in points {
        let m = p.moved_lights;
        let _ = writeln!(
            w,
            "| {} | {} | {} | {} | {:.1} | {:.2} ms | {} | {} | {} | {} | {} | {} | {} |",
            p.blocks,
            p.blocks / tile.max(1) as usize,
            p.texels,
            p.lights,
            p.bake_seconds,
            p.apply_one_ms,
            m.map_or(0, |m| m.lights),
            ms(m.map(|m| m.median_ms)),
            ms(m.map(|m| m.max_ms)),
            ms(p.moved_lights_all.map(|m| m.median_ms)),
            ms(p.moved_lights_feedback.map(|m| m.median_ms)),
            m.map_or("—".to_string(), |m| m.median_texels.to_string()),
            m.map_or("—".to_string(), |m| format!("{:.3} µs", m.us_per_texel)),
        );
    }
    let growths = moved_growth(points);
    let _ = writeln!(
        w,
        "\nGrowth with the block count N: the full apply {}, the median moved light {}, at \
         all bounces {}, by feedback {}, per texel reached {}.\n",
        growth(points, |p| p.apply_one_ms),
        growths[0],
        growths[1],
        growths[2],
        growths[3],
    );
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_growth_exponent_of_a_power_law_is_its_power() {
        let cube: Vec<(f64, f64)> = [20.0, 80.0, 320.0, 1000.0]
            .iter()
            .map(|&n: &f64| (n, 3.0 * n.powi(3)))
            .collect();
        assert!((growth_exponent(&cube).unwrap() - 3.0).abs() < 1e-12);
        let flat = [(20.0, 0.5), (1000.0, 0.5)];
        assert!(growth_exponent(&flat).unwrap().abs() < 1e-12);
        assert_eq!(growth_exponent(&[(20.0, 1.0)]), None);
        assert_eq!(growth_exponent(&[(20.0, 1.0), (20.0, 2.0)]), None);
        // Zero and non-finite values are left out, not fitted.
        let gaps = [
            (20.0, 0.0),
            (80.0, 80.0),
            (320.0, f64::NAN),
            (1000.0, 1000.0),
        ];
        assert!((growth_exponent(&gaps).unwrap() - 1.0).abs() < 1e-12);
    }
}
