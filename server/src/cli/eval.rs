//! `lightfarm eval OUT.lfb --lights LIGHTS.json [--method full|mrt|drt] [--bounces N|all]
//! -o RESULT.json`: apply a bundle through the client crate, exactly as a game would, and write
//! per-texel radiance. Dynamic objects listed in `poses` add their DNRT reflection and
//! occlusion to `indirect`.
//!
//! With more than one bounce, everything downstream of the texels sees the bounced light: the
//! probe volume (MRT's clutter shading, DNRT's input) is fed the radiance leaving the texels,
//! direct plus indirect, and a dynamic object reflects the point lights plus the probes'
//! irradiance. One bounce reproduces the papers' light exactly as before.

use std::path::PathBuf;

use anyhow::Context;
use lightfarm_client::{
    direct_from_point_lights, direct_from_point_lights_averaged, irradiance_at, irradiance_sh_at,
    point_light_irradiance_sh, radiance_sh_at, Applied, Bounces, Bundle, DirectLight, DnrtInstance,
    DnrtVolume, IndirectLight, Method, Occluders, ProbeField, Runtime,
};
use lightfarm_proto::bundle::Layout;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::lights::Pose;
use lightfarm_proto::result::{ResultFile, TexelRecord};

use super::lightmap_files::{write_lightmaps, LightmapFiles};
use super::{read_text, write_json};

/// Arguments of `eval`.
pub struct EvalArgs {
    pub bundle: PathBuf,
    pub lights: PathBuf,
    pub method: Method,
    pub bounces: Bounces,
    pub out: PathBuf,
    pub lightmaps: LightmapFiles,
    /// Also write every texel's SH incident radiance (`eval_sh`); needs an `sh` section.
    pub sh_out: Option<PathBuf>,
}

/// Direct light is averaged over a 4×4 grid per texel before it enters the operators.
pub const DIRECT_SAMPLES_PER_EDGE: u32 = 4;

/// The direct light the operators are fed for `lights`: texel averages over a
/// [`DIRECT_SAMPLES_PER_EDGE`]² grid, shadowed by the bundle's own geometry.
pub fn operator_direct(layout: &Layout, occluders: &Occluders, lights: &LightSet) -> DirectLight {
    direct_from_point_lights_averaged(layout, occluders, &lights.lights, DIRECT_SAMPLES_PER_EDGE)
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
    let occluders = Occluders::from_layout(&bundle.layout);
    // RESULT.json reports direct light at texel centres; the operators are fed the texel
    // average, which is what a ray landing in the texel sees.
    let direct: DirectLight = direct_from_point_lights(&bundle.layout, &occluders, &lights.lights);
    let averaged = operator_direct(&bundle.layout, &occluders, lights);
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
    // MRT shades clutter from the probe volume (U_dyn), as the MRT paper does; DRT gathers.
    let mut probe_lit: Option<Vec<[f32; 3]>> = None;
    if method == Method::Mrt && runtime.has_probes() {
        let mut field = ProbeField::default();
        runtime.apply_probes(&leaving, &mut field)?;
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
    let dnrt = dnrt_delta(&mut runtime, &leaving, bounced, &occluders, lights)?;
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
                indirect: {
                    let base = match (&probe_lit, is_clutter) {
                        (Some(lit), true) => lit[t],
                        _ => indirect.radiance[t],
                    };
                    let add = dnrt.as_ref().map_or([0.0; 3], |d| d[t]);
                    f([0, 1, 2].map(|c| base[c] + add[c]))
                },
            });
        }
    }
    Ok((ResultFile { texels }, applied))
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

/// DNRT (paper 003) for every posed dynamic object: per texel, the light the objects add and
/// take away. `leaving` is the radiance leaving the texels that the probe volume is fed.
/// One bounce (`bounced` false, `leaving` the direct light), consistent with the one-bounce
/// solution: an object reflects the point lights' direct light (their irradiance lobe at its
/// centre) and hides the radiance of the direct-lit surfaces behind it (the probe volume's
/// radiance SH at its centre, Appendix B.2); light the object would reflect from the walls is a
/// second bounce. All bounces (`bounced`, `leaving` direct plus indirect): the object also
/// reflects the walls' light (the probes' irradiance at its centre, the full light-probe input
/// the paper assumes) and hides their bounced light too. A point light it hides is its direct
/// shadow, never indirect light.
/// `None` when there are no poses; an error when a pose names an object without a grid.
pub fn dnrt_delta(
    runtime: &mut Runtime,
    leaving: &DirectLight,
    bounced: bool,
    occluders: &Occluders,
    lights: &LightSet,
) -> anyhow::Result<Option<Vec<[f32; 3]>>> {
    let poses: &[Pose] = &lights.poses;
    if poses.is_empty() {
        return Ok(None);
    }
    let mut field = ProbeField::default();
    runtime.apply_probes(leaving, &mut field)?;
    let bundle = runtime.bundle();
    let volume = bundle
        .probes
        .as_ref()
        .expect("apply_probes checked the probe volume");
    let grids = bundle.dnrt.as_deref().unwrap_or(&[]);
    let mut out = vec![[0.0f32; 3]; bundle.layout.n_texels()];
    for pose in poses {
        let grid = grids.iter().find(|g| g.object == pose.id).ok_or_else(|| {
            anyhow::anyhow!("pose \"{}\": the bundle has no DNRT grid for it", pose.id)
        })?;
        let dnrt = DnrtVolume::new(grid)?;
        let zero = [[0.0; 9]; 3];
        let at = DnrtInstance::new(&dnrt, pose.translation, pose.rotation, zero, zero);
        let centre = at.centre_world();
        let mut lit = point_light_irradiance_sh(occluders, &lights.lights, centre);
        if bounced {
            let walls = irradiance_sh_at(volume, &field, centre);
            for (l, w) in lit.iter_mut().zip(walls) {
                for (a, b) in l.iter_mut().zip(w) {
                    *a += b;
                }
            }
        }
        let hidden = radiance_sh_at(volume, &field, centre);
        let instance = DnrtInstance::new(&dnrt, pose.translation, pose.rotation, lit, hidden);
        instance.apply_texels(&bundle.layout, &mut out)?;
    }
    Ok(Some(out))
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let bytes = std::fs::read(&args.bundle)
        .with_context(|| format!("cannot read {}", args.bundle.display()))?;
    let bundle = Bundle::decode(&bytes).with_context(|| format!("{}", args.bundle.display()))?;
    let lights = LightSet::from_json(&read_text(&args.lights)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.lights.display()))?;
    let layout = bundle.layout.clone();
    if let Some(path) = &args.sh_out {
        let sh = super::eval_sh::sh_incident(bundle.clone(), &lights, args.bounces)?;
        super::eval_sh::write_sh_file(path, &sh)?;
    }
    let surface_atlases = bundle.surface_atlases.clone();
    let (result, applied) = evaluate_with_report(bundle, &lights, args.method, args.bounces)?;
    match lightfarm_client::Bounces::from(args.bounces) {
        lightfarm_client::Bounces::Converged { .. } => eprintln!(
            "bounces: all, {} applied (operator applications; estimated error {:.2e})",
            applied.bounces, applied.remaining_fraction
        ),
        _ => eprintln!("bounces: {} applied", applied.bounces),
    }
    write_json(&args.out, &result)?;
    if !args.lightmaps.is_empty() {
        eprintln!(
            "lightmaps: {}",
            write_lightmaps(&layout, &surface_atlases, &result, &args.lightmaps)?
        );
    }
    Ok(())
}
