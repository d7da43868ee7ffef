//! The bench's markdown (BENCHMARKS.md-ready) and its one-paragraph terminal summary.
//!
//! Everything here is generated from [`BenchResults`]: the tables, the machine, the command,
//! and a reading whose sentences are templates filled from the numbers. A human edit would be
//! lost at the next run, and the file says so at the top.
//!
//! Every figure names its yardstick: each table row has a `bounces` column (the bounce count of
//! its reference and of the runtime's mode), the reading and the Pareto fronts are per scene
//! *and* bounce count, and plots are linked under the bounce count they show.

use std::fmt::Write as _;
use std::path::{Component, Path, PathBuf};

use lightfarm_proto::bounces::BounceCount;

use super::measure::bounces_label;
use super::pareto::pareto_front;
use super::plots::{CostAxis, PlotFiles};
use super::results::{BenchResults, Row};

fn scenes(results: &BenchResults) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    for row in &results.rows {
        if !out.contains(&row.point.scene.as_str()) {
            out.push(&row.point.scene);
        }
    }
    out
}

/// The bounce counts measured on `scene`, in the order of the rows (the main yardstick first).
fn bounce_counts(results: &BenchResults, scene: &str) -> Vec<BounceCount> {
    let mut out = Vec::new();
    for row in results.rows.iter().filter(|r| r.point.scene == scene) {
        if !out.contains(&row.point.bounces) {
            out.push(row.point.bounces);
        }
    }
    out
}

/// The rows of one scene at one bounce count.
fn rows_at<'a>(results: &'a BenchResults, scene: &str, bounces: BounceCount) -> Vec<&'a Row> {
    results
        .rows
        .iter()
        .filter(|r| r.point.scene == scene && r.point.bounces == bounces)
        .collect()
}

/// Per row of a scene (any mix of bounce counts): its Pareto marks, the fronts taken among the
/// rows of its own bounce count only.
fn fronts_by_bounces(rows: &[&Row]) -> Vec<[bool; 3]> {
    let mut marks = vec![[false; 3]; rows.len()];
    let mut counts: Vec<BounceCount> = Vec::new();
    for row in rows {
        if !counts.contains(&row.point.bounces) {
            counts.push(row.point.bounces);
        }
    }
    for bounces in counts {
        let index: Vec<usize> = (0..rows.len())
            .filter(|&i| rows[i].point.bounces == bounces)
            .collect();
        let group: Vec<&Row> = index.iter().map(|&i| rows[i]).collect();
        for (i, m) in index.into_iter().zip(fronts(&group)) {
            marks[i] = m;
        }
    }
    marks
}

/// Median, smallest and largest of how many times cheaper a relight is than path tracing to
/// the same error (over the rows where the path tracer is fitted).
pub fn times_cheaper_spread(rows: &[&Row]) -> Option<(f64, f64, f64)> {
    let mut v: Vec<f64> = rows
        .iter()
        .filter_map(|r| r.times_cheaper_than_path_tracing())
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let median = if v.len() % 2 == 1 {
        v[v.len() / 2]
    } else {
        0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
    };
    Some((median, v[0], v[v.len() - 1]))
}

/// "12.3k×": a large ratio in a few characters.
fn times(x: f64) -> String {
    if x >= 1e6 {
        format!("{:.1}M×", x / 1e6)
    } else if x >= 1e4 {
        format!("{:.0}k×", x / 1e3)
    } else if x >= 1e3 {
        format!("{:.1}k×", x / 1e3)
    } else {
        format!("{x:.0}×")
    }
}

/// Per row of a scene: on the Pareto front of error against bake time, apply time, bytes.
pub fn fronts(rows: &[&Row]) -> Vec<[bool; 3]> {
    let per_axis: Vec<Vec<bool>> = CostAxis::ALL
        .iter()
        .map(|axis| {
            let coordinates: Vec<(f64, f64)> = rows
                .iter()
                .map(|r| (axis.of(&r.point), r.point.relative_l2))
                .collect();
            pareto_front(&coordinates)
        })
        .collect();
    (0..rows.len())
        .map(|i| [per_axis[0][i], per_axis[1][i], per_axis[2][i]])
        .collect()
}

fn bytes(b: u64) -> String {
    if b >= 1 << 20 {
        format!("{:.2} MiB", b as f64 / (1u64 << 20) as f64)
    } else {
        format!("{:.1} KiB", b as f64 / 1024.0)
    }
}

/// `path` relative to `base_dir` when both are under the current directory (for links).
pub(super) fn relative_to(path: &Path, base_dir: &Path) -> PathBuf {
    let absolute = |p: &Path| -> PathBuf {
        let p = if p.is_absolute() {
            p.to_path_buf()
        } else {
            std::env::current_dir().unwrap_or_default().join(p)
        };
        p.components()
            .filter(|c| !matches!(c, Component::CurDir))
            .collect()
    };
    let (path, base) = (absolute(path), absolute(base_dir));
    let common = path
        .components()
        .zip(base.components())
        .take_while(|(a, b)| a == b)
        .count();
    let mut out = PathBuf::new();
    for _ in base.components().skip(common) {
        out.push("..");
    }
    for c in path.components().skip(common) {
        out.push(c);
    }
    out
}

fn front_settings(rows: &[&Row], marks: &[[bool; 3]], axis: usize) -> Vec<String> {
    let mut on: Vec<(&Row, f64)> = rows
        .iter()
        .zip(marks)
        .filter(|(_, m)| m[axis])
        .map(|(r, _)| (*r, CostAxis::ALL[axis].of(&r.point)))
        .collect();
    on.sort_by(|a, b| a.1.total_cmp(&b.1));
    on.iter()
        .map(|(r, _)| {
            format!(
                "{} {} (err {:.4})",
                r.point.method.label(),
                r.point.setting_label(),
                r.point.relative_l2
            )
        })
        .collect()
}

/// The title and the generated-file notice every BENCHMARKS.md starts with.
pub fn header() -> String {
    "# Benchmarks\n\n\
     <!-- GENERATED by `lightfarm bench`. Do not edit: rerun the command below. -->\n\
     > **Regenerated, never hand-edited.** Everything below, the reading included, is written \
     by `lightfarm bench` from the numbers of one run; rerun the command to update it.\n\n"
        .to_string()
}

/// The markdown document; image links are relative to `markdown_path`'s directory.
pub fn markdown(results: &BenchResults, plots: &[PlotFiles], markdown_path: &Path) -> String {
    let base = markdown_path.parent().unwrap_or(Path::new("."));
    let plan = &results.plan;
    let mut md = header();
    let w = &mut md;
    let _ = writeln!(w, "## Machine and command\n");
    let _ = writeln!(
        w,
        "- CPU: {} (`nproc` = {}), a machine shared with other work (times vary 5-30% between runs)\n\
         - command: `{}`\n\
         - preset: {:?}; wall time {:.1} min, not counting {:.1} min of reference runs read \
         from the cache (a cold run takes about {:.1} min)\n\
         - {} seeded random light sets per scene (1–4 point lights, 2–20 W/sr, 0.25 m from \
         walls and clutter; poses of dynamic objects); high-ray reference {} rays per texel \
         (cached by content); brute-force runs at {:?} rays per texel; apply time = median of \
         {} frames of `Runtime::apply` on one thread\n\
         - yardsticks: {}\n",
        results.machine.cpu,
        results.machine.nproc,
        results.command_line,
        plan.preset,
        results.wall_seconds / 60.0,
        results.reference_seconds_from_cache / 60.0,
        (results.wall_seconds + results.reference_seconds_from_cache) / 60.0,
        plan.light_sets,
        plan.reference_rays,
        plan.brute_force_rays,
        plan.frames,
        yardsticks_sentence(results)
    );
    let _ = writeln!(w, "## Reading (generated from the numbers)\n");
    for (scene, bounces) in scenes(results)
        .into_iter()
        .flat_map(|s| bounce_counts(results, s).into_iter().map(move |b| (s, b)))
    {
        let rows = rows_at(results, scene, bounces);
        let label = bounces_label(bounces);
        let marks = fronts(&rows);
        let best = rows
            .iter()
            .min_by(|a, b| a.point.relative_l2.total_cmp(&b.point.relative_l2))
            .expect("a scene has rows");
        let _ = writeln!(
            w,
            "- **{scene}, {label}**: lowest error {:.4} ({} {}). Pareto front, error against \
             bake time: {}. Against apply time: {}. Against bytes: {}.",
            best.point.relative_l2,
            best.point.method.label(),
            best.point.setting_label(),
            front_settings(&rows, &marks, 0).join("; "),
            front_settings(&rows, &marks, 1).join("; "),
            front_settings(&rows, &marks, 2).join("; "),
        );
        let beaten: Vec<&&Row> = rows
            .iter()
            .filter(|r| {
                r.brute_force_seconds
                    .is_some_and(|s| s < r.point.bake_seconds)
            })
            .collect();
        let unreachable = rows.iter().filter(|r| r.brute_force_rays.is_none()).count();
        let cheaper = match times_cheaper_spread(&rows) {
            Some((median, lo, hi)) => format!(
                " One relight by the operators ({label}) is {} cheaper than path tracing the \
                 light set to the same error at {label} (median over points; {} to {}).",
                times(median),
                times(lo),
                times(hi)
            ),
            None => String::new(),
        };
        let _ = writeln!(
            w,
            "  Path tracer ({label}) at equal error: for {} of {} points one reference render \
             of a light set is cheaper than the bake (the bake pays off after that many light \
             changes); {} points are more accurate than the high-ray reference can resolve.{}",
            beaten.len(),
            rows.len(),
            unreachable,
            cheaper
        );
    }
    if let Some(t) = &results.throughput {
        match t.embree_rays_per_second {
            Some(embree) => {
                let _ = writeln!(
                    w,
                    "- **Ray throughput** ({}, {} triangles, {} rays, one thread): ours {:.2} Mrays/s \
                     on the triangles, Embree {:.2} Mrays/s: ours : Embree = {:.3} : 1 ({:.2} Mrays/s \
                     on our native rectangles){}.",
                    t.scene,
                    t.triangles,
                    t.rays,
                    t.ours_triangles_rays_per_second / 1e6,
                    embree / 1e6,
                    t.ours_to_embree().unwrap_or(f64::NAN),
                    t.ours_native_rays_per_second / 1e6,
                    if t.measured_by.is_some() {
                        ", measured apart from the rest of this page"
                    } else {
                        ""
                    }
                );
            }
            None => {
                let _ = writeln!(
                    w,
                    "- **Ray throughput**: Embree NOT measured ({}); ours {:.2} Mrays/s on the \
                     triangles, {:.2} Mrays/s on the native rectangles.",
                    t.embree_missing.as_deref().unwrap_or("unknown reason"),
                    t.ours_triangles_rays_per_second / 1e6,
                    t.ours_native_rays_per_second / 1e6
                );
            }
        }
    }
    let _ = writeln!(w);
    let _ = writeln!(
        w,
        "## Definitions\n\n\
         - *bounces*: the yardstick of the row. The reference sums that many bounces of \
         indirect light (`all`: path tracing with Russian roulette, every bounce), and the \
         runtime applies the operators at the matching mode (`all` → `Converged` at tolerance \
         1e-3, `N` → `Fixed(N)`, `1` → `One`, the papers' single bounce); a row's error, apply \
         time, Pareto marks and path-tracer cost are all at its own bounce count. *iterations*: \
         one-bounce applications per timed frame (`Applied::bounces`).\n\
         - *× cheaper*: path-tracer seconds for one light set at the row's error and bounce \
         count, divided by the row's apply time: how many times cheaper relighting by the \
         operators is than path tracing to the same error.\n\
         - *relative L2*: `sqrt(Σ|ours − ref|² / Σ|ref|²)` of indirect radiance over the texels \
         the method models (block texels inside clutter boxes left out), mean over light sets; \
         *p95*: 95th percentile of the per-texel error over the mean reference magnitude.\n\
         - *bake s*: the engine stages the method needs, cold (no shape cache), plus the \
         encode; *bytes*: the stored bundle sections the method reads plus the container \
         (zstd-compressed; the dense operator is stored as sparse f32 rows whatever the codec, \
         so `full` does not change with the codec).\n\
         - *full*: the dense per-texel operator (Hašan et al. 2006 style, the paper's \
         baseline); *drt*/*dnrt* are on the lightfield bake; *mrt-\\** ignore clutter and \
         dynamic objects (which the reference contains); *dnrt* = MRT plus the DNRT grids.\n\
         - *brute force at equal error*: the reference solver (the path tracer, at the row's \
         bounce count) and its error against the high-ray reference (independent seed) is measured on a ladder of ray counts and fitted as \
         `e(r)² = a² (r^-2α + R^-2α)` (a power law plus the high-ray reference's own noise; α is \
         fitted, not assumed to be 1/2, because the scrambled Sobol' sequence converges faster \
         than plain Monte Carlo), its time as `t₀ + k r`; the column gives the rays per texel \
         and seconds it needs **per light set** to match the point's error (interpolated inside \
         the ladder, extrapolated outside it). `—`: below the reference's noise floor. The \
         brute-force error is over all texels; MRT's over the block texels it models.\n\
         - *Pareto* marks: **b** on the front of error vs bake time, **a** vs apply time, **s** \
         vs size.\n"
    );
    for scene in scenes(results) {
        let rows: Vec<&Row> = results
            .rows
            .iter()
            .filter(|r| r.point.scene == scene)
            .collect();
        let marks = fronts_by_bounces(&rows);
        let _ = writeln!(w, "## {scene}\n");
        let _ = writeln!(
            w,
            "| method | T | rays | tolerance | codec | rank max/mean | bake s | bytes | bounces | iterations | apply ms | relative L2 | p95 | brute force: rays, s/light set | × cheaper | Pareto |"
        );
        let _ = writeln!(
            w,
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
        );
        for (row, mark) in rows.iter().zip(&marks) {
            let p = &row.point;
            let brute = match (row.brute_force_rays, row.brute_force_seconds) {
                (Some(r), Some(s)) => format!("{r:.0}, {s:.2}"),
                _ => "—".into(),
            };
            let pareto: String = ["b", "a", "s"]
                .iter()
                .zip(mark)
                .map(|(l, &m)| if m { *l } else { "" })
                .collect();
            let cheaper = row
                .times_cheaper_than_path_tracing()
                .map_or_else(|| "—".to_string(), times);
            let _ = writeln!(
                w,
                "| {} | {} | {} | {:.0e} | {} | {}/{:.1} | {:.2} | {} | {} | {} | {:.3} | {:.4} | {:.4} | {} | {} | {} |",
                p.method.label(),
                p.texels_per_face,
                p.rays_per_texel,
                p.tolerance,
                p.codec,
                p.rank_max,
                p.rank_mean,
                p.bake_seconds,
                bytes(p.bundle_bytes),
                p.bounces,
                p.iterations,
                p.apply_ms,
                p.relative_l2,
                p.p95,
                brute,
                cheaper,
                pareto
            );
        }
        let _ = writeln!(w);
        for plot in plots.iter().filter(|p| p.scene == scene) {
            let png = relative_to(&plot.png, base);
            let svg = relative_to(&plot.svg, base);
            let _ = writeln!(
                w,
                "![{scene}, {}: error vs {}]({}) ([SVG]({}))\n",
                bounces_label(plot.bounces),
                plot.axis.description(),
                png.display(),
                svg.display()
            );
        }
    }
    let _ = writeln!(w, "## Reference solver (brute force) fits\n");
    let _ = writeln!(
        w,
        "| scene | T | bounces | texels | runs (rays: error, s) | a | α | s fixed | s per ray | noise floor | high-ray reference s/light set |"
    );
    let _ = writeln!(w, "|---|---|---|---|---|---|---|---|---|---|---|");
    for b in &results.brute_force {
        let runs: Vec<String> = b
            .runs
            .iter()
            .map(|(r, e, s)| format!("{r}: {e:.4}, {s:.2}"))
            .collect();
        let _ = writeln!(
            w,
            "| {} | {} | {} | {} | {} | {:.4} | {:.3} | {:.3} | {:.2e} | {:.4} | {:.1} |",
            b.scene,
            b.texels_per_face,
            b.bounces,
            b.texels,
            runs.join("; "),
            b.scale,
            b.exponent,
            b.seconds_fixed,
            b.seconds_per_ray,
            b.noise_floor,
            b.reference_seconds
        );
    }
    let _ = writeln!(w);
    if let Some(t) = &results.throughput {
        let _ = writeln!(w, "## Ray throughput: our tracer against Embree\n");
        let _ = writeln!(
            w,
            "Closest-hit rays from the texels of `{}` (cosine-distributed, seeded), the scene as \
             {} triangles, {} rays, one thread each, best of 3 per round. Embree through `embreex` \
             (`scripts/embree_throughput.py`, `EmbreeScene.run`, one ray at a time).\n",
            t.scene, t.triangles, t.rays
        );
        if let Some(command) = &t.measured_by {
            let _ = writeln!(
                w,
                "Measured apart from the rest of this page, by `{command}`.\n"
            );
        }
        let _ = writeln!(w, "| tracer | Mrays/s |\n|---|---|");
        let _ = writeln!(
            w,
            "| ours (`bake::tracer::Tracer`, 8-wide BVH{}), triangles | {:.3} |",
            t.instruction_set
                .as_deref()
                .map_or(String::new(), |isa| format!(", its {isa} copy")),
            t.ours_triangles_rays_per_second / 1e6
        );
        let _ = writeln!(
            w,
            "| ours, native rectangles | {:.3} |",
            t.ours_native_rays_per_second / 1e6
        );
        match t.embree_rays_per_second {
            Some(e) => {
                let _ = writeln!(w, "| Embree (embreex), triangles | {:.3} |", e / 1e6);
                let per_round: Vec<String> = t
                    .rounds
                    .iter()
                    .filter_map(|r| r.ratio())
                    .map(|r| format!("{r:.2}"))
                    .collect();
                if !per_round.is_empty() {
                    let order = if t.rounds.iter().any(|r| r.embree_first) {
                        "each tracing both, ours first in the first round and the order \
                         alternating"
                    } else {
                        "each tracing ours and then Embree"
                    };
                    let _ = writeln!(
                        w,
                        "\nMedians of {} rounds, {order}; ours : Embree per round {}.",
                        per_round.len(),
                        per_round.join(", ")
                    );
                }
                let _ = writeln!(
                    w,
                    "\nours : Embree = **{:.3} : 1** on the same triangles and rays; hit \
                     distances agree on {:.2}% of the rays; Embree's BVH build {:.3} s.\n",
                    t.ours_to_embree().unwrap_or(f64::NAN),
                    100.0 * t.agreement.unwrap_or(f64::NAN),
                    t.embree_build_seconds.unwrap_or(f64::NAN)
                );
            }
            None => {
                let _ = writeln!(
                    w,
                    "| Embree | not measured: {} |\n",
                    t.embree_missing.as_deref().unwrap_or("unknown reason")
                );
            }
        }
    }
    let _ = writeln!(w, "## Left out of this preset\n");
    for item in &plan.left_out {
        let _ = writeln!(w, "- {item}");
    }
    md
}

/// What the run measured against, in one sentence.
fn yardsticks_sentence(results: &BenchResults) -> String {
    let main = results.plan.bounces;
    let main_text = match main {
        BounceCount::All => "all-bounce references, the runtime converged (`Converged`, \
                             tolerance 1e-3) and the path tracer at all bounces"
            .to_string(),
        BounceCount::Fixed(1) => "one-bounce references, the runtime at one bounce (`One`) \
                                  and the path tracer at one bounce"
            .to_string(),
        BounceCount::Fixed(n) => format!(
            "{n}-bounce references, the runtime at `Fixed({n})` and the path tracer at {n} \
             bounces"
        ),
    };
    if results.plan.yardsticks().len() > 1 {
        format!(
            "{main_text} (rows with bounces = {main}); every point again at one bounce against \
             one-bounce references (rows with bounces = 1)"
        )
    } else {
        format!("{main_text} (rows with bounces = {main})")
    }
}

/// A few lines for the terminal.
pub fn summary(results: &BenchResults) -> String {
    let mut s = format!(
        "bench ({:?}): {} points in {:.1} min",
        results.plan.preset,
        results.rows.len(),
        results.wall_seconds / 60.0
    );
    for scene in scenes(results) {
        for bounces in bounce_counts(results, scene) {
            let rows = rows_at(results, scene, bounces);
            let marks = fronts(&rows);
            let cheaper = times_cheaper_spread(&rows).map_or_else(String::new, |(m, _, _)| {
                format!("; relight {} cheaper than path tracing (median)", times(m))
            });
            let _ = write!(
                s,
                "\n{scene}, {}: Pareto (error vs bake time): {}{cheaper}",
                bounces_label(bounces),
                front_settings(&rows, &marks, 0).join("; ")
            );
        }
    }
    if let Some(t) = &results.throughput {
        let _ = match t.embree_rays_per_second {
            Some(e) => write!(
                s,
                "\nrays/s: ours {:.0}, Embree {:.0}, ours:Embree = {:.3} (median of {} rounds)",
                t.ours_triangles_rays_per_second,
                e,
                t.ours_to_embree().unwrap_or(f64::NAN),
                t.rounds.len()
            ),
            None => write!(
                s,
                "\nrays/s: ours {:.0}; Embree not measured: {}",
                t.ours_triangles_rays_per_second,
                t.embree_missing.as_deref().unwrap_or("?")
            ),
        };
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn links_are_relative_to_the_markdown() {
        assert_eq!(
            relative_to(Path::new("docs/bench/a.png"), Path::new("")),
            PathBuf::from("docs/bench/a.png")
        );
        assert_eq!(
            relative_to(Path::new("out/a.png"), Path::new("out")),
            PathBuf::from("a.png")
        );
        assert_eq!(
            relative_to(Path::new("x/a.png"), Path::new("y")),
            PathBuf::from("../x/a.png")
        );
    }
}
