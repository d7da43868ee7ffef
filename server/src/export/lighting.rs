//! The light the export shows: per layout texel, direct, indirect or both, from the ONE call
//! into [`crate::evaluate::evaluate`] (direct light with shadow rays, then the operators through the
//! client runtime, DRT where the bundle has it), so the export shows what `eval` reports.
//!
//! Units: outgoing radiance, W/(sr·m²) per RGB channel, in layout texel order.

use lightfarm_client::{Bundle, Method};
use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;

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

/// Evaluates the bundle under `lights`: the texels' (direct, indirect) radiance with `bounces`
/// bounces (`all`: the runtime's default, iterated until converged; `1`: the papers' one bounce),
/// through `eval::evaluate` and nothing else.
pub fn evaluate(
    bundle: Bundle,
    lights: &LightSet,
    bounces: BounceCount,
) -> Result<ResultFile, ExportError> {
    crate::evaluate::evaluate(bundle, lights, Method::Drt, bounces.into())
        .map_err(|e| ExportError::Evaluate(format!("{e:#}")))
}

/// Per layout texel, the radiance `options.mode` asks for (zero for texels the evaluation does
/// not model).
pub fn texel_radiance(
    bundle: Bundle,
    lights: &LightSet,
    options: ExportOptions,
) -> Result<Vec<[f32; 3]>, ExportError> {
    let layout = bundle.layout.clone();
    let result = evaluate(bundle, lights, options.bounces)?;
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
    Ok(out)
}
