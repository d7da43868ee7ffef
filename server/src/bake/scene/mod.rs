//! The scene as the bake sees it: texels and primitives, and the meshes behind them.
//!
//! # Layout
//! - [`geometry`]: lit surfaces cut into texels, the primitives rays hit, and which texel a hit
//!   lands in.
//! - [`mesh`]: clutter and dynamic-object meshes (OBJ, glTF/GLB) loaded as triangles;
//!   [`mesh_albedo`]: a mesh's albedo per hit (glTF base colour, vertex colours, textures).
//! - [`mesh_atlas`]: lightmap atlases (texels) of mesh clutter.
//! - [`pieces`]: the scene the engine bakes, long blocks cut into pieces of the room's scale.

pub mod geometry;
pub mod mesh;
pub mod mesh_albedo;
pub mod mesh_atlas;
pub mod pieces;
