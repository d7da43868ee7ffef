//! A bundle applied to a light set through the client crate, exactly as a game would: the
//! per-texel radiance the `eval` command writes, the bench scores, and `POST
//! /v1/bakes/{id}/evaluate` returns. Dynamic objects listed in the light set's `poses` cast
//! their direct shadows (their shapes posed into the occluders, so the operators are fed the
//! shadowed light too) and add their DNRT reflection and occlusion to `indirect`.
//!
//! With more than one bounce, everything downstream of the texels sees the bounced light: the
//! probe volume (MRT's clutter shading, DNRT's input) is fed the radiance leaving the texels,
//! direct plus indirect, and a dynamic object reflects the point lights plus the probes'
//! irradiance, and the light the objects add and take away bounces on through the operators
//! (`lightfarm_client::ObjectLight`). One bounce reproduces the papers' light exactly.
//!
//! # Layout
//! - here: [`evaluate`] and its pieces ([`operator_direct`], [`leaving_light`]).
//! - [`objects`]: the light leaving the posed objects' own surfaces, for drawing them.
//! - [`sh`]: SH incident radiance per texel (bundle section `sh`).
//!
//! Invariant: no file I/O and no HTTP here; callers read bundles and write results.

use lightfarm_client::{
    direct_scale, every_sample_by_reach, frame_occluders, irradiance_at, occluders_with_poses,
    Applied, Bounces, Bundle, DirectLight, IndirectLight, Method, ObjectLight, Occluders,
    ProbeField, ReachDirect, Runtime,
};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{ResultFile, TexelRecord};

pub mod objects;
pub mod sh;

pub use objects::{shade_objects, ShadedObject};

/// Direct light is averaged over a 4×4 grid per texel before it enters the operators.
pub const DIRECT_SAMPLES_PER_EDGE: u32 = 4;

/// The direct light the operators are fed for `lights`: texel averages over a
/// [`DIRECT_SAMPLES_PER_EDGE`]² grid, shadowed by the bundle's own geometry (`level`, made
/// from its layout) and the dynamic objects at the light set's poses
/// ([`occluders_with_poses`]), every sample traced, each light where it reaches. Without poses
/// it is [`lightfarm_client::direct_from_point_lights_by_reach`].
pub fn operator_direct(bundle: &Bundle, level: &Occluders, lights: &LightSet) -> DirectLight {
    let posed = occluders_with_poses(level, bundle, &lights.poses);
    let layout = &bundle.layout;
    every_sample_by_reach(
        ReachDirect::new_posed(bundle, level, posed.as_ref()).as_mut(),
        layout,
        frame_occluders(level, posed.as_ref()),
        &lights.lights,
        DIRECT_SAMPLES_PER_EDGE,
        direct_scale(layout, level),
    )
}

/// Applies a bundle to a light set with `bounces` bounces; returns the records the method
/// models.
pub fn evaluate(
    bundle: Bundle,
    lights: &LightSet,
    method: Method,
    bounces: Bounces,
) -> anyhow::Result<ResultFile> {
    Ok(evaluate_with_report(bundle, lights, method, bounces)?.0)
}

/// [`evaluate`], also saying how many bounces the runtime summed.
pub fn evaluate_with_report(
    bundle: Bundle,
    lights: &LightSet,
    method: Method,
    bounces: Bounces,
) -> anyhow::Result<(ResultFile, Applied)> {
    let (result, applied, _) = evaluate_frame(bundle, lights, method, bounces, false)?;
    Ok((result, applied))
}

/// [`evaluate_with_report`], and when `shade_posed` the posed dynamic objects' own light
/// ([`objects::shade_objects`], for drawing them), from the same frame.
pub fn evaluate_frame(
    bundle: Bundle,
    lights: &LightSet,
    method: Method,
    bounces: Bounces,
    shade_posed: bool,
) -> anyhow::Result<(ResultFile, Applied, Vec<ShadedObject>)> {
    // Direct light is shadowed by the level and by the posed dynamic objects; the scale that
    // clamps r² is the level's, whatever the poses.
    let level = Occluders::from_layout(&bundle.layout);
    let posed = occluders_with_poses(&level, &bundle, &lights.poses);
    let occluders = frame_occluders(&level, posed.as_ref());
    // RESULT.json reports direct light at texel centres; the operators are fed the texel
    // average, which is what a ray landing in the texel sees.
    // Both with the one reach (rooms and their occluders) and direct scale.
    let layout = &bundle.layout;
    let (mut reach, scale) = (
        ReachDirect::new_posed(&bundle, &level, posed.as_ref()),
        direct_scale(layout, &level),
    );
    let direct = every_sample_by_reach(reach.as_mut(), layout, occluders, &lights.lights, 1, scale);
    let averaged = every_sample_by_reach(
        reach.as_mut(),
        layout,
        occluders,
        &lights.lights,
        DIRECT_SAMPLES_PER_EDGE,
        scale,
    );
    let mut runtime = Runtime::try_new(bundle)?;
    // A scene without clutter has no DRT operators: DRT is MRT there.
    let method = if method == Method::Drt && !runtime.has_drt() {
        Method::Mrt
    } else {
        method
    };
    let mut indirect = IndirectLight::default();
    let applied = runtime.apply(method, bounces, &averaged, &mut indirect)?;
    // What the probe volume sees: the radiance leaving the texels, direct plus the bounced
    // indirect light (direct alone for one bounce, the papers' U_dyn).
    let bounced = is_bounced(bounces);
    let leaving = if bounced {
        leaving_light(&averaged, &indirect)
    } else {
        averaged.clone()
    };
    // The probe volume fed that light, once: MRT's clutter shading, DNRT's light-probe input
    // and the posed objects' own light read it (posed objects without a probe volume are an
    // error, as DNRT needs it).
    let field = if (method == Method::Mrt && runtime.has_probes()) || !lights.poses.is_empty() {
        let mut field = ProbeField::default();
        runtime.apply_probes(&leaving, &mut field)?;
        Some(field)
    } else {
        None
    };
    // MRT shades clutter from the probe volume (U_dyn), as the MRT paper does; DRT gathers.
    let mut probe_lit: Option<Vec<[f32; 3]>> = None;
    if let Some(field) = field.as_ref().filter(|_| method == Method::Mrt) {
        let layout = &runtime.bundle().layout;
        let volume = runtime.probe_volume().expect("has probes");
        probe_lit = Some(
            (0..layout.n_texels())
                .map(|t| {
                    let e = irradiance_at(volume, field, layout.positions[t], layout.normals[t]);
                    [0, 1, 2].map(|c| layout.albedo[t][c] * std::f32::consts::FRAC_1_PI * e[c])
                })
                .collect(),
        );
    }
    // The posed objects' DNRT light (an object's own light probe sits at its centre, inside
    // it: the level and the other objects shadow it, not its own triangles), and its bounces.
    let dnrt = match &field {
        Some(field) if !lights.poses.is_empty() => {
            let bundle = runtime.bundle();
            let mut objects = ObjectLight::new(bundle)?;
            objects.update(
                bundle,
                field,
                bounced,
                &level,
                &lights.lights,
                &lights.poses,
            )?;
            objects.bounce(&mut runtime, method, bounces, &mut indirect)?;
            Some(objects)
        }
        _ => None,
    };
    let shaded = if shade_posed {
        shade_objects(runtime.bundle(), field.as_ref(), occluders, lights, scale)
    } else {
        Vec::new()
    };
    let layout = &runtime.bundle().layout;
    let mut texels = Vec::with_capacity(layout.n_texels());
    for (surface, first) in layout.surfaces.iter().zip(layout.surface_first_index()) {
        let is_clutter = !surface.name.starts_with("block:");
        // MRT without a probe volume models the blocks only.
        if method == Method::Mrt && is_clutter && probe_lit.is_none() {
            continue;
        }
        for k in 0..surface.texel_count as usize {
            let t = surface.texel_offset as usize + k;
            let f = |v: [f32; 3]| v.map(|x| x as f64);
            texels.push(TexelRecord {
                surface: surface.name.clone(),
                index: first + k as u32,
                position: f(layout.positions[t]),
                normal: f(layout.normals[t]),
                albedo: f(layout.albedo[t]),
                direct: f(direct.radiance[t]),
                indirect: {
                    let base = match (&probe_lit, is_clutter) {
                        (Some(lit), true) => lit[t],
                        _ => indirect.radiance[t],
                    };
                    let add = dnrt.as_ref().map_or([0.0; 3], |o| o.light().radiance[t]);
                    f([0, 1, 2].map(|c| base[c] + add[c]))
                },
            });
        }
    }
    Ok((ResultFile { texels }, applied, shaded))
}

/// Whether `bounces` sums more than the first bounce (then the probe volume and DNRT are fed
/// the bounced light, [`leaving_light`]).
pub fn is_bounced(bounces: Bounces) -> bool {
    !matches!(bounces, Bounces::One | Bounces::Fixed(1))
}

/// The radiance leaving the texels: direct plus indirect.
pub fn leaving_light(direct: &DirectLight, indirect: &IndirectLight) -> DirectLight {
    DirectLight {
        radiance: direct
            .radiance
            .iter()
            .zip(&indirect.radiance)
            .map(|(d, i)| [d[0] + i[0], d[1] + i[1], d[2] + i[2]])
            .collect(),
    }
}
