//! Lightmap images from an evaluation: the indirect (and direct + indirect) radiance of every
//! texel as an atlas PNG for people and a raw f16 file for engines (`lightfarm_client::lightmap`
//! owns the atlas; this file only writes files).

use std::path::{Path, PathBuf};

use anyhow::Context;
use lightfarm_client::lightmap::{auto_exposure, Atlas};
use lightfarm_proto::bundle::{Layout, SurfaceAtlas};
use lightfarm_proto::result::ResultFile;

use super::write_atomic;

/// Which lightmap files to write (each optional).
#[derive(Clone, Debug, Default)]
pub struct LightmapFiles {
    /// Indirect radiance, 8-bit sRGB PNG.
    pub png_indirect: Option<PathBuf>,
    /// Direct + indirect radiance, 8-bit sRGB PNG.
    pub png_lit: Option<PathBuf>,
    /// Indirect radiance, raw f16 atlas.
    pub f16_indirect: Option<PathBuf>,
}

impl LightmapFiles {
    pub fn is_empty(&self) -> bool {
        self.png_indirect.is_none() && self.png_lit.is_none() && self.f16_indirect.is_none()
    }
}

/// Per-texel (indirect, direct + indirect) radiance from a result; texels the result does not
/// model are black.
fn per_texel(layout: &Layout, result: &ResultFile) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let by_texel = result.by_layout_texel(layout);
    let indirect = by_texel
        .iter()
        .map(|t| t.map_or([0.0; 3], |t| t.indirect.map(|x| x as f32)))
        .collect();
    let lit = by_texel
        .iter()
        .map(|t| {
            t.map_or([0.0; 3], |t| {
                [0, 1, 2].map(|c| (t.indirect[c] + t.direct[c]) as f32)
            })
        })
        .collect();
    (indirect, lit)
}

fn write_png(path: &Path, atlas: &Atlas, rgb: &[u8]) -> anyhow::Result<()> {
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, atlas.width, atlas.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut writer = encoder.write_header()?;
        writer.write_image_data(rgb)?;
    }
    write_atomic(path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes the requested files; returns a line describing them.
pub fn write_lightmaps(
    layout: &Layout,
    surface_atlases: &[SurfaceAtlas],
    result: &ResultFile,
    files: &LightmapFiles,
) -> anyhow::Result<String> {
    let atlas = Atlas::from_layout_with(layout, surface_atlases);
    let (indirect, lit) = per_texel(layout, result);
    let mut notes = vec![format!("atlas {}x{}", atlas.width, atlas.height)];
    if let Some(path) = &files.png_indirect {
        let exposure = auto_exposure(&indirect);
        write_png(path, &atlas, &atlas.to_srgb8(&indirect, exposure))?;
        notes.push(format!("{} (exposure {exposure:.3})", path.display()));
    }
    if let Some(path) = &files.png_lit {
        let exposure = auto_exposure(&lit);
        write_png(path, &atlas, &atlas.to_srgb8(&lit, exposure))?;
        notes.push(format!("{} (exposure {exposure:.3})", path.display()));
    }
    if let Some(path) = &files.f16_indirect {
        write_atomic(path, &atlas.to_f16_file(&indirect))?;
        notes.push(path.display().to_string());
    }
    Ok(notes.join(", "))
}
