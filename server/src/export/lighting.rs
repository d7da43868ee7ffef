//! The light the export shows: per layout texel, direct, indirect or both, from the ONE call
//! into [`crate::evaluate::evaluate_frame`] (direct light with shadow rays, then the operators
//! through the client runtime, DRT where the bundle has it), so the export shows what `eval`
//! reports; and from the same frame the light leaving the posed dynamic objects.
//!
//! Units: outgoing radiance, W/(sr·m²) per RGB channel, in layout texel order (objects: per
//! triangle corner).

use lightfarm_client::{Bundle, Method};
use lightfarm_proto::lights::LightSet;

use super::{ExportError, ExportOptions};

/// Which light the textures hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightMode {
    /// Direct + indirect.
    Lit,
    Direct,
    Indirect,
}

impl LightMode {
    pub fn name(self) -> &'static str {
        match self {
            LightMode::Lit => "lit",
            LightMode::Direct => "direct",
            LightMode::Indirect => "indirect",
        }
    }

    pub fn parse(text: &str) -> Option<LightMode> {
        match text {
            "lit" => Some(LightMode::Lit),
            "direct" => Some(LightMode::Direct),
            "indirect" => Some(LightMode::Indirect),
            _ => None,
        }
    }
}

/// What the export draws lit: per layout texel, and per posed dynamic object per triangle
/// corner, the radiance the mode asks for.
pub struct Lit {
    /// Per layout texel (zero for texels the evaluation does not model).
    pub texels: Vec<[f32; 3]>,
    /// The posed dynamic objects.
    pub objects: Vec<LitObject>,
}

/// A posed dynamic object as the export draws it.
pub struct LitObject {
    /// The scene's dynamic-object id.
    pub id: String,
    /// World-frame triangles at this frame's pose.
    pub triangles: Vec<[[f32; 3]; 3]>,
    /// Per triangle corner, the radiance the mode asks for.
    pub corners: Vec<[f32; 3]>,
}

/// The radiance `options.mode` asks for, of the texels and of the posed dynamic objects, from
/// one evaluation.
pub fn texel_radiance(
    bundle: Bundle,
    lights: &LightSet,
    options: ExportOptions,
) -> Result<Lit, ExportError> {
    let layout = bundle.layout.clone();
    let (result, _, shaded) =
        crate::evaluate::evaluate_frame(bundle, lights, Method::Drt, options.bounces.into(), true)
            .map_err(|e| ExportError::Evaluate(format!("{e:#}")))?;
    let pick = |d: [f32; 3], i: [f32; 3]| -> [f32; 3] {
        [0, 1, 2].map(|c| match options.mode {
            LightMode::Lit => d[c] + i[c],
            LightMode::Direct => d[c],
            LightMode::Indirect => i[c],
        })
    };
    let objects = shaded
        .into_iter()
        .map(|o| {
            let corners = o
                .direct
                .iter()
                .zip(&o.indirect)
                .map(|(d, i)| pick(*d, *i))
                .collect();
            LitObject {
                id: o.id,
                triangles: o.triangles,
                corners,
            }
        })
        .collect();
    let out = result
        .by_layout_texel(&layout)
        .iter()
        .map(|t| {
            t.map_or([0.0; 3], |t| {
                [0, 1, 2].map(|c| {
                    (match options.mode {
                        LightMode::Lit => t.direct[c] + t.indirect[c],
                        LightMode::Direct => t.direct[c],
                        LightMode::Indirect => t.indirect[c],
                    }) as f32
                })
            })
        })
        .collect();
    Ok(Lit {
        texels: out,
        objects,
    })
}
