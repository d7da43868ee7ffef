//! `lightfarm eval OUT.lfb --lights LIGHTS.json [--method full|mrt] -o RESULT.json`: apply a
//! bundle through the client crate, exactly as a game would, and write per-texel radiance.

use std::path::PathBuf;

use anyhow::Context;
use lightfarm_client::{
    direct_from_point_lights, direct_from_point_lights_averaged, irradiance_at, Bundle,
    DirectLight, IndirectLight, Method, Occluders, ProbeField, Runtime,
};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{ResultFile, TexelRecord};

use super::lightmap_files::{write_lightmaps, LightmapFiles};
use super::{read_text, write_json};

/// Arguments of `eval`.
pub struct EvalArgs {
    pub bundle: PathBuf,
    pub lights: PathBuf,
    pub method: Method,
    pub out: PathBuf,
    pub lightmaps: LightmapFiles,
}

/// Direct light is averaged over a 4×4 grid per texel before it enters the operators.
pub const DIRECT_SAMPLES_PER_EDGE: u32 = 4;

/// Applies a bundle to a light set; returns the records the method models.
pub fn evaluate(bundle: Bundle, lights: &LightSet, method: Method) -> anyhow::Result<ResultFile> {
    let occluders = Occluders::from_layout(&bundle.layout);
    // RESULT.json reports direct light at texel centres; the operators are fed the texel
    // average, which is what a ray landing in the texel sees.
    let direct: DirectLight = direct_from_point_lights(&bundle.layout, &occluders, &lights.lights);
    let averaged = direct_from_point_lights_averaged(
        &bundle.layout,
        &occluders,
        &lights.lights,
        DIRECT_SAMPLES_PER_EDGE,
    );
    let mut runtime = Runtime::try_new(bundle)?;
    // A scene without clutter has no DRT operators: DRT is MRT there.
    let method = if method == Method::Drt && !runtime.has_drt() {
        Method::Mrt
    } else {
        method
    };
    let mut indirect = IndirectLight::default();
    runtime.apply(method, &averaged, &mut indirect)?;
    // MRT shades clutter from the probe volume (U_dyn), as the MRT paper does; DRT gathers.
    let mut probe_lit: Option<Vec<[f32; 3]>> = None;
    if method == Method::Mrt && runtime.has_probes() {
        let mut field = ProbeField::default();
        runtime.apply_probes(&averaged, &mut field)?;
        let layout = &runtime.bundle().layout;
        let volume = runtime.probe_volume().expect("has probes");
        probe_lit = Some(
            (0..layout.n_texels())
                .map(|t| {
                    let e = irradiance_at(volume, &field, layout.positions[t], layout.normals[t]);
                    [0, 1, 2].map(|c| layout.albedo[t][c] * std::f32::consts::FRAC_1_PI * e[c])
                })
                .collect(),
        );
    }
    let layout = &runtime.bundle().layout;
    let mut texels = Vec::with_capacity(layout.n_texels());
    for surface in &layout.surfaces {
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
                index: k as u32,
                position: f(layout.positions[t]),
                normal: f(layout.normals[t]),
                albedo: f(layout.albedo[t]),
                direct: f(direct.radiance[t]),
                indirect: match (&probe_lit, is_clutter) {
                    (Some(lit), true) => f(lit[t]),
                    _ => f(indirect.radiance[t]),
                },
            });
        }
    }
    Ok(ResultFile { texels })
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let bytes = std::fs::read(&args.bundle)
        .with_context(|| format!("cannot read {}", args.bundle.display()))?;
    let bundle = Bundle::decode(&bytes).with_context(|| format!("{}", args.bundle.display()))?;
    let lights = LightSet::from_json(&read_text(&args.lights)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.lights.display()))?;
    let layout = bundle.layout.clone();
    let result = evaluate(bundle, &lights, args.method)?;
    write_json(&args.out, &result)?;
    if !args.lightmaps.is_empty() {
        eprintln!(
            "lightmaps: {}",
            write_lightmaps(&layout, &result, &args.lightmaps)?
        );
    }
    Ok(())
}
