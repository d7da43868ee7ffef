//! Tests of the direct light ([`super`]): closed forms (a point light over a texel, the
//! rectangle's solid angle near the light), shadows, light buffers against the hierarchy bit
//! for bit, the adaptive average against every sample where the corners see what the samples
//! see, and finite values for lights on or behind a surface. Fixtures (`light`, `floor`) are
//! shared with the other direct-light modules' tests.

#![allow(clippy::needless_range_loop)]

use super::*;
use crate::texel_samples::{
    dominant_axis, near_light_mean, sample_offset, sample_point, unshadowed_samples,
};
use lightfarm_proto::bundle::Rect;

/// Adds `n` random axis-aligned occluder rects to `layout`: corner and plane in
/// `[-extent, extent]`, sides up to `side`.
fn push_random_rects(
    rng: &mut crate::occluders::tests::Lcg,
    layout: &mut Layout,
    n: usize,
    extent: f32,
    side: f32,
) {
    for _ in 0..n {
        let (a, b) = (rng.range(-extent, extent), rng.range(-extent, extent));
        layout.rects.push(Rect {
            axis: (rng.next_u32() % 3) as u8,
            coord: rng.range(-extent, extent),
            min: [a, b],
            max: [a + rng.range(0.0, side), b + rng.range(0.0, side)],
        });
    }
}

/// A point light (the client's tests share it).
pub(crate) fn light(position: [f64; 3], intensity: [f64; 3]) -> Light {
    Light {
        kind: LightKind::Point,
        position,
        intensity,
    }
}

/// Texels on the floor z = 0 (normal +z) of a 4 m box (the client's tests share it).
pub(crate) fn floor(points: &[[f32; 3]]) -> Layout {
    Layout {
        scene_name: "test".into(),
        surfaces: vec![],
        positions: points.to_vec(),
        normals: vec![[0.0, 0.0, 1.0]; points.len()],
        albedo: vec![[0.5, 0.25, 0.8]; points.len()],
        texel_size: vec![[0.0, 0.0]; points.len()],
        rects: vec![Rect {
            axis: 2,
            coord: 0.0,
            min: [0.0, 0.0],
            max: [4.0, 4.0],
        }],
        triangles: vec![],
    }
}

fn close(a: f32, b: f64) -> bool {
    (a as f64 - b).abs() <= 1e-5 * b.abs().max(1e-12)
}

/// A floor of `k × k` texels of `side` metres from the origin, at z = 0, as the bake lays
/// them out (centres, normal +z, sizes).
fn tiled_floor(k: usize, side: f32) -> Layout {
    let centres: Vec<[f32; 3]> = (0..k * k)
        .map(|i| {
            let (a, b) = ((i % k) as f32, (i / k) as f32);
            [(a + 0.5) * side, (b + 0.5) * side, 0.0]
        })
        .collect();
    let mut layout = floor(&centres);
    layout.texel_size = vec![[side, side]; k * k];
    layout.rects[0].max = [k as f32 * side; 2];
    layout
}

/// Solid angle of the rectangle `[x0, x1] × [y0, y1]` of the plane z = 0 from `(0, 0, d)`.
fn rect_solid_angle(x0: f64, x1: f64, y0: f64, y1: f64, d: f64) -> f64 {
    let f = |x: f64, y: f64| (x * y / (d * (d * d + x * x + y * y).sqrt())).atan();
    f(x1, y1) - f(x0, y1) - f(x1, y0) + f(x0, y0)
}

/// A light 5 cm above a floor of 0.5 m texels, over a texel corner: every texel's value
/// times its area sums to the light the whole floor receives (`I` times the solid angle
/// the floor subtends, in closed form), to 1e-6, on the adaptive, full and per-light
/// paths; the 4 × 4 grid alone gives the four texels around the light's foot 77% of
/// theirs. Far from the light nothing changes: a texel 11 m away keeps the grid mean.
#[test]
fn a_light_near_a_surface_gives_it_all_its_light() {
    let (k, side) = (8usize, 0.5f32);
    let layout = tiled_floor(k, side);
    let occ = Occluders::from_layout(&layout);
    let d = 0.05;
    let foot = [2.0, 1.5];
    let lights = [light([foot[0], foot[1], d], [3.0, 3.0, 3.0])];
    let extent = k as f64 * side as f64;
    let floor_flux =
        3.0 * rect_solid_angle(-foot[0], extent - foot[0], -foot[1], extent - foot[1], d);
    let area = (side * side) as f64;
    // ρ/π · E, back to irradiance with the red albedo 0.5.
    let received = |r: &DirectLight| {
        r.radiance
            .iter()
            .map(|v| v[0] as f64 / 0.5 * std::f64::consts::PI * area)
            .sum::<f64>()
    };
    let adaptive = direct_from_point_lights_adaptive(&layout, &occ, &lights, 4);
    let averaged = direct_from_point_lights_averaged(&layout, &occ, &lights, 4);
    let mut irr = vec![[0.0; 3]; layout.n_texels()];
    let all = [TexelSpan {
        texels: 0..layout.n_texels(),
        in_sight: false,
    }];
    let scale = direct_scale(&layout, &occ);
    add_light_term_in(
        &layout,
        Shadows::Occluders(&occ),
        &lights[0],
        4,
        scale,
        &all,
        true,
        &mut BoxShadows::new(),
        &mut irr,
    );
    let per_light = finish_irradiance(&layout, &irr);
    for (name, r) in [
        ("adaptive", &adaptive),
        ("averaged", &averaged),
        ("per light", &per_light),
    ] {
        let got = received(r);
        assert!(
            (got / floor_flux - 1.0).abs() < 1e-6,
            "{name}: {got} received against {floor_flux}"
        );
    }
    // The grid alone, for scale: the four texels at the foot.
    let grid: f64 = [(3, 2), (4, 2), (3, 3), (4, 3)]
        .iter()
        .map(|&(a, b): &(usize, usize)| {
            let m = 4;
            (0..m * m)
                .map(|s| {
                    let x = (a as f64 + (s % m) as f64 / 4.0 + 0.125) * 0.5 - foot[0];
                    let y = (b as f64 + (s / m) as f64 / 4.0 + 0.125) * 0.5 - foot[1];
                    d / (d * d + x * x + y * y).powf(1.5) / 16.0 * area
                })
                .sum::<f64>()
        })
        .sum();
    let exact = rect_solid_angle(-0.5, 0.5, -0.5, 0.5, d);
    assert!(grid < 0.8 * exact, "the grid gave {grid} of {exact}");
    // A far texel: the near-light mean does not apply, the grid's value stands.
    let far = tiled_floor(40, 0.25);
    let t = far.n_texels() - 1;
    let at = TexelAt::of(&far, t);
    assert_eq!(near_light_mean(&at, &lights[0]), None);
}

#[test]
fn unoccluded_texel_matches_closed_form() {
    let layout = floor(&[[1.0, 1.0, 0.0]]);
    let occ = Occluders::from_layout(&layout);
    let i = [10.0, 20.0, 5.0];
    let p = [2.0, 3.0, 2.5];
    let d = light(p, i);
    let out = direct_from_point_lights(&layout, &occ, std::slice::from_ref(&d));
    let to = [1.0f64, 2.0, 2.5];
    let r2 = to.iter().map(|v| v * v).sum::<f64>();
    let cos = 2.5 / r2.sqrt();
    for c in 0..3 {
        let want = layout.albedo[0][c] as f64 / std::f64::consts::PI * i[c] * cos / r2;
        assert!(
            close(out.radiance[0][c], want),
            "channel {c}: {} vs {want}",
            out.radiance[0][c]
        );
    }
    // Two lights add.
    let twice = direct_from_point_lights(&layout, &occ, &[d.clone(), d]);
    for c in 0..3 {
        assert!(close(twice.radiance[0][c], 2.0 * out.radiance[0][c] as f64));
    }
}

#[test]
fn texel_behind_an_occluder_gets_zero() {
    let mut layout = floor(&[[1.0, 1.0, 0.0], [3.0, 3.0, 0.0]]);
    layout.rects.push(Rect {
        axis: 2,
        coord: 1.0,
        min: [0.5, 0.5],
        max: [1.5, 1.5],
    });
    let occ = Occluders::from_layout(&layout);
    let out = direct_from_point_lights(&layout, &occ, &[light([1.0, 1.0, 3.0], [1.0; 3])]);
    assert_eq!(out.radiance[0], [0.0; 3]);
    assert!(
        out.radiance[1].iter().all(|&v| v > 0.0),
        "the other texel is lit"
    );
}

/// A 16 × 16 grid of 0.25 m texels on the floor, under a 1 m square blocker at z = 1 and
/// a 2 cm bar at z = 0.5 along y, whose shadows from the test's lights fall between corner
/// samples onto inner ones (one texel column each).
fn shadowed_floor() -> Layout {
    let mut points = Vec::new();
    for j in 0..16 {
        for i in 0..16 {
            points.push([0.125 + 0.25 * i as f32, 0.125 + 0.25 * j as f32, 0.0]);
        }
    }
    let mut layout = floor(&points);
    layout.texel_size = vec![[0.25, 0.25]; points.len()];
    layout.rects.push(Rect {
        axis: 2,
        coord: 1.0,
        min: [1.0, 1.0],
        max: [2.0, 2.0],
    });
    layout.rects.push(Rect {
        axis: 2,
        coord: 0.5,
        min: [2.6853, 0.0],
        max: [2.7053, 4.0],
    });
    layout
}

/// Light buffers answer what the hierarchy answers: on random occluders (rects and
/// triangles) over random texels, axis-aligned and slanted, facing any way, the averaged
/// and the adaptive direct light are bit-identical either way.
#[test]
fn light_buffers_light_texels_bit_for_bit_as_the_hierarchy() {
    use crate::occluders::tests::Lcg;
    let mut rng = Lcg(0xb0ff_e12);
    let mut lit = 0;
    for case in 0..12 {
        let mut layout = Layout::default();
        for k in 0..300 {
            let mut n = [0.0f32; 3];
            if k % 3 == 0 {
                n = rng.point(-1.0, 1.0);
            } else {
                n[(rng.next_u32() % 3) as usize] = if k % 2 == 0 { 1.0 } else { -1.0 };
            }
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if len < 0.1 {
                n = [0.0, 1.0, 0.0];
            }
            layout.positions.push(rng.point(-4.0, 4.0));
            layout.normals.push(n.map(|x| x / len.max(0.1)));
            layout.albedo.push([0.5, 0.6, 0.7]);
            let size = [rng.range(0.05, 0.5), rng.range(0.05, 0.5)];
            // A few texels without a size (their centre alone).
            layout
                .texel_size
                .push(if k % 37 == 5 { [0.0, 0.0] } else { size });
        }
        push_random_rects(&mut rng, &mut layout, 10 + 5 * case, 5.0, 3.0);
        for _ in 0..(3 * case) {
            let c = rng.point(-4.0, 4.0);
            let mut p = || {
                let o = rng.point(-1.0, 1.0);
                [c[0] + o[0], c[1] + o[1], c[2] + o[2]]
            };
            layout.triangles.push([p(), p(), p()]);
        }
        let occ = Occluders::from_layout(&layout);
        let lights: Vec<Light> = (0..3)
            .map(|_| {
                let p = rng.point(-4.5, 4.5).map(f64::from);
                light(p, [1.0, 2.0, 3.0])
            })
            .collect();
        let scale = direct_scale(&layout, &occ);
        for m in [1, 4] {
            let by_buffers = direct_from_point_lights_averaged(&layout, &occ, &lights, m);
            let by_tree = averaged_with(&layout, Shadows::Occluders(&occ), scale, &lights, m);
            assert_eq!(by_buffers, by_tree, "case {case}, averaged, m = {m}");
            lit += by_tree.radiance.iter().filter(|v| v[0] > 0.0).count();
        }
        let all = [TexelSpan {
            texels: 0..layout.n_texels(),
            in_sight: false,
        }];
        let by_buffers = direct_from_point_lights_adaptive(&layout, &occ, &lights, 4);
        let mut by_tree = vec![[0.0f32; 3]; layout.n_texels()];
        adaptive_in_with(
            &layout,
            Shadows::Occluders(&occ),
            &lights,
            4,
            scale,
            &all,
            &mut BoxShadows::new(),
            &mut by_tree,
        );
        assert_eq!(by_buffers.radiance, by_tree, "case {case}, adaptive");
        // One light over its buffer: runs of texels by box queries (a run in sight by
        // `clear_run`, a listed one texel by texel), against every texel's own rays.
        for light in &lights {
            let one = std::slice::from_ref(light);
            let by_buffer = direct_from_point_lights_adaptive(&layout, &occ, one, 4);
            let mut by_tree = vec![[0.0f32; 3]; layout.n_texels()];
            let tree = Shadows::Occluders(&occ);
            let mut boxes = BoxShadows::new();
            adaptive_in_with(&layout, tree, one, 4, scale, &all, &mut boxes, &mut by_tree);
            assert_eq!(by_buffer.radiance, by_tree, "case {case}, one light");
            let mut buffer = LightBuffer::new();
            buffer.build(&occ, light.position.map(|x| x as f32), None);
            let terms = terms_both_ways(&layout, &occ, &buffer, light, 4, scale, &mut boxes);
            assert_eq!(terms[0], terms[1], "case {case}, one light's terms");
        }
    }
    assert!(lit > 1000, "{lit} texels lit");
}

/// One light's term over every texel of `layout` (`m` samples per edge), made over its
/// `buffer` and over the whole hierarchy, in that order.
fn terms_both_ways(
    layout: &Layout,
    occ: &Occluders,
    buffer: &LightBuffer,
    light: &Light,
    m: u32,
    scale: f64,
    boxes: &mut BoxShadows,
) -> [Vec<[f64; 3]>; 2] {
    let all = [TexelSpan {
        texels: 0..layout.n_texels(),
        in_sight: false,
    }];
    let buffers = std::slice::from_ref(buffer);
    let mut terms = [vec![[0.0f64; 3]; layout.n_texels()], vec![]];
    terms[1] = terms[0].clone();
    for (shadows, irr) in [Shadows::Buffers(occ, buffers), Shadows::Occluders(occ)]
        .into_iter()
        .zip(&mut terms)
    {
        add_light_term_in(layout, shadows, light, m, scale, &all, false, boxes, irr);
    }
    terms
}

/// One light over its buffer, on floors and walls of texels in runs (as the bake lays them
/// out) under random rects and triangles: the runs' box queries, the listed runs' texel
/// boxes and the runs in sight (`clear_run`) give every texel what its own rays against the
/// hierarchy give it, bit for bit, as values and as one light's terms; near lights and far,
/// 2 and 4 samples per edge.
#[test]
fn one_lights_runs_of_texels_give_what_each_texels_own_rays_give() {
    use crate::occluders::tests::Lcg;
    let mut rng = Lcg(0x0e1a_57ed);
    let (k, side) = (24usize, 0.2f32);
    let mut lit = 0;
    for case in 0..8 {
        let mut layout = tiled_floor(k, side);
        // A wall's texels facing +x at x = 0 and a ceiling's facing −z at z = 3.
        for (n, lift) in [([1.0f32, 0.0, 0.0], 0usize), ([0.0, 0.0, -1.0], 1)] {
            for i in 0..k * k {
                let (a, b) = ((i % k) as f32 + 0.5, (i / k) as f32 + 0.5);
                let p = if lift == 0 {
                    [0.0, a * side, b * side * 0.6]
                } else {
                    [a * side, b * side, 3.0]
                };
                layout.positions.push(p);
                layout.normals.push(n);
                layout.albedo.push([0.5, 0.6, 0.7]);
                layout.texel_size.push([side, side]);
            }
        }
        let extent = k as f32 * side;
        for _ in 0..6 + 2 * case {
            let (a, b) = (rng.range(0.0, extent), rng.range(0.0, extent));
            layout.rects.push(Rect {
                axis: (rng.next_u32() % 3) as u8,
                coord: rng.range(0.2, 2.5),
                min: [a, b],
                max: [a + rng.range(0.02, 1.0), b + rng.range(0.02, 1.0)],
            });
        }
        for _ in 0..case {
            let c = [
                rng.range(0.5, 4.0),
                rng.range(0.5, 4.0),
                rng.range(0.3, 2.5),
            ];
            let mut p = || {
                let o = rng.point(-0.5, 0.5);
                [c[0] + o[0], c[1] + o[1], c[2] + o[2]]
            };
            layout.triangles.push([p(), p(), p()]);
        }
        let occ = Occluders::from_layout(&layout);
        let scale = direct_scale(&layout, &occ);
        let all = [TexelSpan {
            texels: 0..layout.n_texels(),
            in_sight: false,
        }];
        for round in 0..6 {
            let height = if round % 3 == 0 {
                0.05
            } else {
                rng.range(0.3, 2.8)
            };
            let p = [rng.range(0.2, 4.6), rng.range(0.2, 4.6), height];
            let light = light(p.map(f64::from), [1.0, 2.0, 3.0]);
            let one = std::slice::from_ref(&light);
            let tree = Shadows::Occluders(&occ);
            let mut buffer = LightBuffer::new();
            buffer.build(&occ, p, None);
            let buffers = std::slice::from_ref(&buffer);
            let mut boxes = BoxShadows::new();
            for m in [2, 4] {
                let mut values = [vec![[0.0f32; 3]; layout.n_texels()], vec![]];
                values[1] = values[0].clone();
                for (shadows, out) in [Shadows::Buffers(&occ, buffers), tree]
                    .into_iter()
                    .zip(&mut values)
                {
                    adaptive_in_with(&layout, shadows, one, m, scale, &all, &mut boxes, out);
                }
                assert_eq!(values[0], values[1], "case {case}.{round}, m = {m}");
                lit += values[0].iter().filter(|v| v[0] > 0.0).count();
                let terms = terms_both_ways(&layout, &occ, &buffer, &light, m, scale, &mut boxes);
                assert_eq!(terms[0], terms[1], "case {case}.{round}, m = {m}, terms");
            }
        }
    }
    assert!(lit > 20_000, "{lit} texels lit");
}

/// The adaptive average as first written (every sample point made, the unshadowed terms
/// per point, corners traced, every sample where they disagree) for one light; which
/// samples count is `visible_sum`, shared.
fn adaptive_by_points(lighting: &Lighting, li: usize, t: &TexelAt, m: usize) -> [f64; 3] {
    let mut points = vec![[0.0f32; 3]; m * m];
    sample_points(t.x, t.n, t.size, m, &mut points);
    let light = &lighting.lights[li];
    let mut g = vec![0.0f64; m * m];
    unshadowed_samples(&points, t.n, light, lighting.r2_min, &mut g);
    if g.iter().all(|&v| v == 0.0) {
        return [0.0; 3];
    }
    let seen = corner_indices(m).map(|k| !lighting.occluded(li, points[k]));
    let sum = visible_sum(&g, m, seen, |k| !lighting.occluded(li, points[k]));
    let w = texel_mean(t, light, lighting.r2_min, sum, g.iter().sum());
    light.intensity.map(|i| i * w)
}

/// The per-row-and-column unshadowed terms, the corner points made alone and the points
/// made only when corners disagree give the first-written adaptive average bit for bit:
/// axis-aligned and slanted texels, lights near, far, in the texel's plane and behind,
/// `m` from 2 to 8, against random occluders.
#[test]
fn grid_terms_and_lazy_points_give_the_per_point_average_bit_for_bit() {
    use crate::occluders::tests::Lcg;
    let mut rng = Lcg(0x9a1d_7e57);
    let mut layout = Layout::default();
    push_random_rects(&mut rng, &mut layout, 40, 3.0, 2.0);
    let occ = Occluders::from_layout(&layout);
    let (mut partial, mut checked) = (0, 0);
    for case in 0..3000 {
        let mut n = [0.0f32; 3];
        let axis = (rng.next_u32() % 3) as usize;
        n[axis] = if case % 2 == 0 { 1.0 } else { -1.0 };
        if case % 5 == 0 {
            n = rng.point(-1.0, 1.0);
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(0.1);
            n = n.map(|x| x / len);
        }
        let t = TexelAt {
            x: rng.point(-3.0, 3.0),
            n,
            rho: [0.5, 0.5, 0.5],
            size: [rng.range(0.01, 0.6), rng.range(0.01, 0.6)],
        };
        let mut p = rng.point(-4.0, 4.0).map(f64::from);
        if case % 7 == 0 {
            // In the texel's plane.
            let a = dominant_axis(n);
            p[a] = t.x[a] as f64;
        }
        if case % 11 == 0 {
            // Far away.
            p = p.map(|x| x * 1e4);
        }
        let lights = [light(p, [1.0, 2.0, 0.5])];
        let m = 2 + case % 7;
        let lighting = Lighting::new(&lights, Shadows::Occluders(&occ), 6.0);
        let mut samples = TexelSamples::new();
        // Leftovers of another texel must not leak into this one.
        samples.all_points = case % 3 == 0;
        samples.start(&t, m);
        let mut irr = [0.0f64; 3];
        add_adaptive(&lighting, 0, &t, m, &mut samples, &mut irr);
        let want = adaptive_by_points(&lighting, 0, &t, m);
        assert_eq!(irr.map(f64::to_bits), want.map(f64::to_bits), "case {case}");
        // The every-sample average through the same scratch.
        let mut every = [0.0f64; 3];
        add_every_sample(&lighting, 0, &t, m, &mut samples, &mut every);
        let mut points = vec![[0.0f32; 3]; m * m];
        sample_points(t.x, t.n, t.size, m, &mut points);
        let mut g = vec![0.0f64; m * m];
        unshadowed_samples(&points, t.n, &lights[0], lighting.r2_min, &mut g);
        assert_eq!(samples.g[..m * m], g[..], "case {case}: unshadowed terms");
        assert_eq!(samples.points[..m * m], points[..], "case {case}: points");
        for (k, q) in points.iter().enumerate() {
            let o = |i| sample_offset(i, m);
            assert_eq!(*q, sample_point(t.x, t.n, t.size, o(k % m), o(k / m)));
        }
        checked += usize::from(irr != [0.0; 3]);
        partial += usize::from(irr != [0.0; 3] && every != irr);
    }
    assert!(
        checked > 800 && partial > 10,
        "{checked} lit, {partial} partly shadowed"
    );
}

#[test]
fn adaptive_average_equals_the_full_average_where_corners_see_what_samples_see() {
    let layout = shadowed_floor();
    let occ = Occluders::from_layout(&layout);
    let lights = [
        light([1.6, 1.4, 3.0], [10.0, 8.0, 6.0]),
        light([3.0, 3.5, 2.0], [2.0; 3]),
    ];
    let full = direct_from_point_lights_averaged(&layout, &occ, &lights, 4);
    let adaptive = direct_from_point_lights_adaptive(&layout, &occ, &lights, 4);
    // Without occluders between texels and lights every texel agrees to rounding.
    let open = Occluders::new(&layout.rects[..1], &[]);
    let (a, b) = (
        direct_from_point_lights_averaged(&layout, &open, &lights, 4),
        direct_from_point_lights_adaptive(&layout, &open, &lights, 4),
    );
    for (x, y) in a.radiance.iter().zip(&b.radiance) {
        for c in 0..3 {
            assert!(close(y[c], x[c] as f64), "{x:?} vs {y:?}");
        }
    }
    // With the blockers: penumbra texels (corners disagree) are traced sample by sample,
    // so only the texels whose inner samples alone the bar's thin shadows cross differ.
    let mut differ = 0;
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in full.radiance.iter().zip(&adaptive.radiance) {
        let d: f64 = (0..3).map(|c| (x[c] as f64 - y[c] as f64).powi(2)).sum();
        if d.sqrt() > 1e-5 * (x[0] as f64).abs().max(1e-6) {
            differ += 1;
            // A missed thin shadow only brightens, by at most the shadowed inner samples
            // (at most a half of a 4 × 4 grid's samples lie between its corners' columns).
            for c in 0..3 {
                assert!(y[c] >= x[c] && y[c] - x[c] <= 0.5 * y[c], "{x:?} vs {y:?}");
            }
        }
        num += d;
        den += (0..3).map(|c| (x[c] as f64).powi(2)).sum::<f64>();
    }
    let rel = (num / den).sqrt();
    assert!(differ > 0 && differ <= 32, "{differ} texels differ");
    // The designed worst case (two shadows missed along whole columns): a few percent.
    assert!(rel < 0.1, "relative L2 {rel}");
    // Under the first light alone, the blocker's umbra is dark in both, texel for texel.
    let one = &lights[..1];
    let (x, y) = (
        direct_from_point_lights_averaged(&layout, &occ, one, 4),
        direct_from_point_lights_adaptive(&layout, &occ, one, 4),
    );
    let dark = x.radiance.iter().filter(|v| v[0] == 0.0).count();
    assert!(dark >= 9, "{dark} dark texels");
    for (x, y) in x.radiance.iter().zip(&y.radiance) {
        assert_eq!(x[0] == 0.0, y[0] == 0.0, "{x:?} vs {y:?}");
    }
}

#[test]
fn light_behind_the_surface_gives_zero() {
    let layout = floor(&[[1.0, 1.0, 0.0]]);
    let occ = Occluders::new(&[], &[]);
    let out = direct_from_point_lights(&layout, &occ, &[light([1.0, 1.0, -2.0], [5.0; 3])]);
    assert_eq!(out.radiance[0], [0.0; 3]);
    // Grazing (in the plane) gives zero too.
    let out = direct_from_point_lights(&layout, &occ, &[light([3.0, 1.0, 0.0], [5.0; 3])]);
    assert_eq!(out.radiance[0], [0.0; 3]);
}

#[test]
fn light_on_or_at_a_texel_stays_finite() {
    let layout = floor(&[[1.0, 1.0, 0.0], [2.0, 2.0, 0.0]]);
    let occ = Occluders::from_layout(&layout);
    // Exactly at texel 0, just above texel 1's plane next to it.
    let lights = [
        light([1.0, 1.0, 0.0], [1.0; 3]),
        light([2.0, 2.0, 1e-7], [1.0; 3]),
    ];
    let out = direct_from_point_lights(&layout, &occ, &lights);
    for v in out.radiance.iter().flatten() {
        assert!(v.is_finite() && *v >= 0.0, "{v}");
    }
    assert!(out.radiance[1][0] > 0.0);
}

#[test]
fn one_value_per_texel_and_nothing_without_lights() {
    let layout = floor(&[[1.0, 1.0, 0.0], [2.0, 1.0, 0.0], [3.0, 1.0, 0.0]]);
    let out = direct_from_point_lights(&layout, &Occluders::from_layout(&layout), &[]);
    assert_eq!(out.radiance, vec![[0.0; 3]; 3]);
}

/// Irradiance at points that are not texels: the closed form `I cosθ / r²`, zero behind an
/// occluder and behind the surface, clamped (finite) with the light on the point, and at
/// texel centres exactly what the texels' direct light holds before `ρ/π`.
#[test]
fn point_irradiance_is_the_texels_rule_at_any_point() {
    let layout = floor(&[[1.0, 1.0, 0.0], [3.0, 3.0, 0.0]]);
    let mut shadowed = layout.clone();
    shadowed.rects.push(Rect {
        axis: 2,
        coord: 1.0,
        min: [0.5, 0.5],
        max: [1.5, 1.5],
    });
    let (occ, blocked) = (
        Occluders::from_layout(&layout),
        Occluders::from_layout(&shadowed),
    );
    let scale = direct_scale(&layout, &occ);
    let lights = [light([2.0, 3.0, 2.5], [10.0, 20.0, 5.0])];
    let up = [0.0, 0.0, 1.0];
    let got = point_irradiance(&occ, &lights, scale, [([1.0, 1.0, 0.0], up)]);
    let (to, i) = ([1.0f64, 2.0, 2.5], lights[0].intensity);
    let r2 = to.iter().map(|v| v * v).sum::<f64>();
    for c in 0..3 {
        let want = i[c] * 2.5 / r2.sqrt() / r2;
        assert!(
            (got[0][c] - want).abs() <= 1e-12 * want,
            "{c}: {:?}",
            got[0]
        );
    }
    // The blocker hides the light from (1, 1, 0) only; facing down sees nothing.
    let over = [light([1.0, 1.0, 3.0], [1.0; 3])];
    let seen = point_irradiance(
        &blocked,
        &over,
        scale,
        [([1.0, 1.0, 0.0], up), ([3.0, 3.0, 0.0], up)],
    );
    assert_eq!(seen[0], [0.0; 3]);
    assert!(seen[1].iter().all(|&e| e > 0.0));
    let down = point_irradiance(&occ, &over, scale, [([3.0, 3.0, 0.0], [0.0, 0.0, -1.0])]);
    assert_eq!(down[0], [0.0; 3]);
    // On the point: zero; a hair above it: the clamp, `I / (1e-4 · scale)²`.
    let hair = [
        light([3.0, 3.0, 0.0], [1.0; 3]),
        light([1.0, 1.0, 1e-9], [1.0; 3]),
    ];
    let at = point_irradiance(&occ, &hair[..1], scale, [([3.0, 3.0, 0.0], up)]);
    assert_eq!(at[0], [0.0; 3]);
    let near = point_irradiance(&occ, &hair[1..], scale, [([1.0, 1.0, 0.0], up)]);
    let clamp = 1.0 / (R_MIN_REL * scale).powi(2);
    assert!(
        (near[0][0] - clamp).abs() <= 1e-9 * clamp,
        "{:?} against {clamp}",
        near[0]
    );
    // At texel centres: the texels' direct light is `ρ/π` times it, bit for bit.
    let both = [lights[0].clone(), over[0].clone()];
    let texels = direct_from_point_lights(&shadowed, &blocked, &both);
    let points = (0..2).map(|t| (shadowed.positions[t], shadowed.normals[t]));
    for (t, e) in point_irradiance(&blocked, &both, direct_scale(&shadowed, &blocked), points)
        .iter()
        .enumerate()
    {
        assert_eq!(
            outgoing(shadowed.albedo[t], *e).map(|v| v as f32),
            texels.radiance[t]
        );
    }
}
