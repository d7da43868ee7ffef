//! glTF 2.0 (binary, `.glb`) export of a lit level: what `lightfarm export` writes and
//! `POST /v1/bakes/{id}/preview.glb` serves, so any glTF viewer (and the dashboard) shows the
//! baked light.
//!
//! The bundle is evaluated under a light set through the client crate exactly as `eval` does
//! ([`lighting`]). Every block and clutter box becomes one mesh with its own lightmap texture:
//! its faces as rectangles rebuilt from their texels ([`faces`]), one texture pixel per texel
//! ([`textures`]). Mesh clutter becomes its triangles coloured per vertex from the nearest
//! texel ([`mesh_colours`]). Posed dynamic objects become their triangles coloured per corner
//! by the light leaving them (`evaluate::objects`). Point lights become `KHR_lights_punctual`
//! lights. [`document`]
//! assembles the glTF JSON, [`glb`] the binary container.
//!
//! Frames and units: glTF's right-handed, Y-up frame in metres is the scene's own frame (no
//! conversion). Textures hold radiance × exposure through the tone curve of
//! `lightfarm_client::lightmap` (sRGB, as glTF's base colour expects); materials are
//! `KHR_materials_unlit`, so a viewer shows the baked light as it is, not relit.
//!
//! # Layout
//! - [`lighting`]: the one call into `eval` (light mode, bounces) → per-texel radiance.
//! - [`faces`]: rectangles of a surface's texels; [`textures`]: per-surface texture images.
//! - [`mesh_colours`]: per-vertex colours of mesh clutter and of posed dynamic objects.
//! - [`document`]: the glTF JSON and binary buffer; [`glb`]: the GLB container.

pub mod document;
pub mod faces;
pub mod glb;
pub mod lighting;
pub mod mesh_colours;
pub mod textures;

use lightfarm_client::Bundle;
use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;

pub use lighting::LightMode;

/// What to export.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExportOptions {
    pub mode: LightMode,
    /// Bounces of indirect light (`lightfarm_client::Bounces` through its `From`).
    pub bounces: BounceCount,
}

impl Default for ExportOptions {
    fn default() -> ExportOptions {
        ExportOptions {
            mode: LightMode::Lit,
            bounces: BounceCount::All,
        }
    }
}

/// Why an export failed, naming the surface or stage.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("evaluating the bundle: {0}")]
    Evaluate(String),
    #[error("surface \"{surface}\": {detail}")]
    Faces { surface: String, detail: String },
    #[error("texture of surface \"{surface}\": {detail}")]
    Texture { surface: String, detail: String },
}

/// The lit level as GLB bytes, and the exposure the textures were tone-mapped with.
pub fn export_glb(
    bundle: Bundle,
    lights: &LightSet,
    options: ExportOptions,
) -> Result<(Vec<u8>, f32), ExportError> {
    let layout = bundle.layout.clone();
    let surface_atlases = bundle.surface_atlases.clone();
    let lit = lighting::texel_radiance(bundle, lights, options)?;
    let built = document::build(
        &layout,
        &surface_atlases,
        &lit.texels,
        &lit.objects,
        lights,
        options,
    )?;
    Ok((glb::write(&built.json, &built.binary), built.exposure))
}
