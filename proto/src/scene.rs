//! The scene description `lightfarm.scene/1`: types, parsing and validation.
//!
//! Units: metres for positions, albedo is RGB reflectance in [0, 1). Blocks are axis-aligned
//! boxes (a warp of the unit cube) whose closed faces are lit from the inside. Two blocks connect
//! where an open face of one coincides exactly with an open face of the other; an open face with
//! no neighbour opens onto the void.
//!
//! Invariant: a [`Scene`] returned by [`Scene::from_json`] or [`Scene::validate`] has finite
//! coordinates, positive extents, albedo in [0, 1), unique ids and a consistent connectivity
//! graph; downstream code (the bake engine, the service) never re-checks these. Error messages
//! name the object and field (`block "a": max.y (0) <= min.y (3)`), and the CLI and the HTTP
//! API show the same text.

use std::collections::{BTreeMap, HashSet};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::face::Face;

/// Most grid points the probe volume may have (`settings.probe_spacing` over the blocks'
/// bounds); the bake allocates a slot per point.
pub const MAX_PROBE_GRID_POINTS: u64 = 1 << 22;

/// The only format string this version reads.
pub const SCENE_FORMAT: &str = "lightfarm.scene/1";

/// A whole level: blocks, clutter, dynamic objects and bake settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Must be `lightfarm.scene/1`.
    pub format: String,
    /// Human-readable name.
    pub name: String,
    /// Bake settings; every field has a default.
    #[serde(default)]
    pub settings: Settings,
    /// Warped boxes the level is built from.
    pub blocks: Vec<Block>,
    /// Static props inside the blocks.
    #[serde(default)]
    pub clutter: Vec<Clutter>,
    /// Moving objects (posed per frame in LIGHTS.json).
    #[serde(default)]
    pub dynamic: Vec<DynamicObject>,
    /// Where lights will be (optional; default: anywhere inside the blocks).
    #[serde(default)]
    pub light_regions: Vec<Aabb>,
}

/// How inter-block light is carried.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// MRT's scene-independent way: reduced lightfields on openings composed over the graph.
    /// Cheaper to bake, but light crossing an opening is binned into `lightfield_cells² ×
    /// lightfield_directions²` bins, which blurs it where it lands close to the opening.
    Lightfield,
    /// The default: per receiving block, rays from its texels through its openings into the
    /// level's blocks. On the maze at 16 texels per face DRT's all-bounce error is 0.0235
    /// against 0.0398 through lightfields, in a smaller bundle (4.28 against 6.08 MB).
    Traced,
}

/// Basis for direct light on clutter (DRT §4.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ClutterBasis {
    /// A lighting prior over the clutter's texels from the scene's light distribution.
    Prior,
    /// One constant per clutter face (the paper's choice).
    FaceConstant,
}

/// How clutter texels gather light from the scene (DRT §4.3).
///
/// The choice trades accuracy for the cost of relighting by a change. The maze at T = 16,
/// 1,024 rays, 1,000 texels checked against Mitsuba:
/// - error at all bounces: exact 0.0229, implicit 0.0251 (Mitsuba's noise 0.0113);
/// - error at one bounce: exact 0.0248, implicit 0.0315.
///
/// Moving one light (`frame-time --update one-light`, one bounce), the operators' part per
/// light is 0.88 / 2.71 / 0.60 / 1.57 ms with exact and 0.53 / 0.71 / 0.50 / 0.55 ms with
/// implicit. The exact gather's rows read about 490 texels each, and a moving light's change
/// reaches many of them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ClutterGather {
    /// From the actual direct light of the texels hit (sparse rows; holds contact shadows).
    Exact,
    /// From the blocks' implicit lights `L_imp b` (the paper's C_b).
    Implicit,
}

/// How block texels that see clutter get their indirect light.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum SceneGather {
    /// MRT plus the paper's deltas: `ΔU_b b + ΔU_c c` (DRT §4.1–§4.2).
    #[default]
    Delta,
    /// Ours: MRT's light on those texels is replaced by an exact one-bounce gather over the
    /// actual direct light of the texels their cosine rays hit (like `clutter_gather: exact`),
    /// so MRT's own error there (a dim block lit through openings, a bright patch its prior
    /// smooths) goes too. Costs a bigger DRT section; bundle minor 3.
    Exact,
}

impl SceneGather {
    fn is_delta(&self) -> bool {
        *self == SceneGather::Delta
    }
}

/// When the bake includes the SH probe volume U_dyn.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum ProbeVolumeMode {
    /// When the scene lists dynamic objects (the volume's readers at run time).
    Auto,
    /// Whenever the scene has clutter or dynamic objects (also shades clutter for the MRT
    /// baseline, `eval --method mrt`: with dynamic objects' regions, the volume also covers
    /// every clutter object; under `Auto` it covers the regions only).
    Always,
    Never,
}

/// How operator matrices are stored in the bundle (see `crate::codec`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum BundleCodec {
    /// Per matrix, the smallest codec (8-bit, f16, f32) within `codec_error`.
    Auto,
    F32,
    F16,
    U8,
}

/// Bake settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Settings {
    /// Texels along each edge of a block face (T×T texels per closed face, whatever the face's
    /// size). Texels much wider than a light's distance to the surfaces near it blur that
    /// light's bounce, so the bake cuts a block more than 4 (and at most 64) times as long as
    /// its narrowest other side into pieces of the room's scale (open to each other; their
    /// texels keep the block's surface names). A closed 30 × 1.2 × 4 m box with a point light 0.5 m from a
    /// wall was off Mitsuba's indirect light by 56% at one bounce and 28% at all bounces at T
    /// = 8 as one block; baked as 7 pieces it is within 6.0% and 3.4%.
    pub texels_per_face: u32,
    /// Cosine-weighted rays traced per texel for every operator.
    pub rays_per_texel: u32,
    /// Fraction of energy (squared Frobenius norm) an operator truncation may drop; ranks and
    /// propagation depth are chosen from it.
    pub tolerance: f64,
    /// Inter-block transport.
    pub transport: Transport,
    /// Spatial cells along each edge of an opening's lightfield.
    pub lightfield_cells: u32,
    /// Direction bins along each edge of the lightfield's (concentric-square) hemisphere map.
    pub lightfield_directions: u32,
    /// Point lights sampled per block to build the lighting prior.
    pub prior_lights: u32,
    /// Seed of every quasi-random sequence; a bake is a pure function of scene and seed.
    pub seed: u64,
    /// Basis for direct light on clutter.
    pub clutter_basis: ClutterBasis,
    /// Spacing (metres) of the SH probe volume U_dyn.
    pub probe_spacing: f64,
    /// When to bake the probe volume.
    pub probe_volume: ProbeVolumeMode,
    /// Fraction of DRT gather rays aimed at clutter (importance sampling; 0 disables).
    pub clutter_importance: f64,
    /// How clutter texels gather light from the scene.
    pub clutter_gather: ClutterGather,
    /// How block texels that see clutter get their indirect light. Not serialised when
    /// `delta` (the default), so bake ids of scenes without it do not change.
    #[serde(skip_serializing_if = "SceneGather::is_delta")]
    pub scene_gather: SceneGather,
    /// Ship inter-block transport as one low-rank operator per receiving block (rank from
    /// `tolerance`) instead of the composed per-opening operators.
    pub compact_transport: bool,
    /// Ship DRT delta operators and the exact clutter gather (bundle minor 2), and the probe
    /// volume's entries (minor 3), in low-rank form where that is smaller (rank from
    /// `tolerance`).
    pub compact_deltas: bool,
    /// How operator matrices are stored in the bundle.
    pub bundle_codec: BundleCodec,
    /// With `bundle_codec: auto`, the relative RMS error (‖Q(M) − M‖ / ‖M‖) a codec may add to
    /// one operator matrix. The default (0.04) adds about 1.5% to the error of the indirect
    /// light against the reference on the maze at 8 texels per face (relative L2 0.0875 →
    /// 0.0888 on the 7 light sets it was chosen on, 0.0760 → 0.0771 on 12 others) for a
    /// bundle 13% smaller than at 0.02; above 0.05 the 8-bit grids get coarse enough that the
    /// clutter error jumps (`tests/data/bundle_figures.md`).
    pub codec_error: f64,
    /// With `bundle_codec: auto`, the budget of the transport matrices: the smaller of this and
    /// `codec_error`. Transport into a block stacks its source blocks' coefficients in one
    /// matrix, so a budget relative to the matrix goes to the strongest source and the weak
    /// ones, all the light of a block far from every light, lose precision first: on the maze,
    /// transport at 0.05 raises the error within 1 m of clutter from 0.175 to 0.285. Not
    /// serialised at its default (0.02), so a scene that sets `codec_error: 0.02` keeps its
    /// bake id and its bytes.
    #[serde(skip_serializing_if = "is_default_transport_codec_error")]
    pub transport_codec_error: f64,
    /// DNRT grids of dynamic objects (paper 003).
    pub dnrt: DnrtSettings,
    /// Bake SH (order 2, `crate::sh`) incident-radiance responses per lit texel for
    /// normal-mapped surfaces (DRT §5 "vector responses"; bundle section `sh`, minor 2).
    /// Off by default: a scene without it bakes the same bytes as before the setting existed
    /// (and it is not serialised when off, so bake ids do not change either).
    #[serde(skip_serializing_if = "is_false")]
    pub sh_responses: bool,
}

/// Default of [`Settings::transport_codec_error`].
pub const DEFAULT_TRANSPORT_CODEC_ERROR: f64 = 0.02;

fn is_default_transport_codec_error(e: &f64) -> bool {
    *e == DEFAULT_TRANSPORT_CODEC_ERROR
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// How the DNRT grid of every dynamic object is baked and stored (paper 003 §5.1).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct DnrtSettings {
    /// Grid points along each axis (16, 32 or 64 in the paper's terms; any of 2..=128).
    pub resolution: u32,
    /// SH coefficients per channel: 4 (order 1) or 9 (order 2).
    pub sh: u32,
    /// Half-size of the inner cube the grid spans, in bounding-sphere radii.
    pub extent: f64,
    /// Half-size of the outer cube where the effect fades out, in bounding-sphere radii
    /// (≥ `extent`).
    pub outer_extent: f64,
    /// Monte Carlo rays per grid point.
    pub rays: u32,
    /// Storage of the coefficients.
    pub codec: crate::dnrt_grid::DnrtCodec,
    /// Grid point placement (regular, or quadratic as Appendix B.1).
    pub placement: crate::dnrt_grid::DnrtPlacement,
    /// Receiver normals: the paper's intermediate normal, or SH convolution (Appendix A).
    pub normals: crate::dnrt_grid::DnrtNormals,
}

impl Default for DnrtSettings {
    fn default() -> Self {
        DnrtSettings {
            resolution: 32,
            sh: 9,
            extent: 3.0,
            outer_extent: 6.0,
            rays: 256,
            codec: crate::dnrt_grid::DnrtCodec::U8,
            placement: crate::dnrt_grid::DnrtPlacement::Regular,
            normals: crate::dnrt_grid::DnrtNormals::Intermediate,
        }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            texels_per_face: 16,
            rays_per_texel: 1024,
            tolerance: 0.001,
            transport: Transport::Traced,
            lightfield_cells: 4,
            lightfield_directions: 6,
            prior_lights: 768,
            seed: 0,
            clutter_basis: ClutterBasis::Prior,
            probe_spacing: 1.0,
            probe_volume: ProbeVolumeMode::Auto,
            clutter_importance: 0.25,
            clutter_gather: ClutterGather::Exact,
            scene_gather: SceneGather::Delta,
            compact_transport: true,
            compact_deltas: true,
            bundle_codec: BundleCodec::Auto,
            codec_error: 0.04,
            transport_codec_error: DEFAULT_TRANSPORT_CODEC_ERROR,
            dnrt: DnrtSettings::default(),
            sh_responses: false,
        }
    }
}

/// An axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Aabb {
    pub fn extent(&self) -> [f64; 3] {
        [
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        ]
    }

    /// The intersection with `other`, if it has positive volume.
    pub fn intersection(&self, other: &Aabb) -> Option<Aabb> {
        let mut out = *self;
        for k in 0..3 {
            out.min[k] = self.min[k].max(other.min[k]);
            out.max[k] = self.max[k].min(other.max[k]);
            if out.max[k] <= out.min[k] {
                return None;
            }
        }
        Some(out)
    }

    /// The rectangle of one face: (plane coordinate, min and max along the tangent axes).
    pub fn face_rect(&self, face: Face) -> ([f64; 2], [f64; 2], f64) {
        let (u, v) = face.tangent_axes();
        let c = if face.is_max_side() {
            self.max[face.axis()]
        } else {
            self.min[face.axis()]
        };
        ([self.min[u], self.min[v]], [self.max[u], self.max[v]], c)
    }
}

/// A warped box of the level.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Block {
    pub id: String,
    pub min: [f64; 3],
    pub max: [f64; 3],
    /// Removed faces.
    #[serde(default)]
    pub open: Vec<Face>,
    /// RGB albedo of every closed face.
    pub albedo: [f64; 3],
    /// Per-face albedo overrides.
    #[serde(default)]
    pub face_albedo: BTreeMap<Face, [f64; 3]>,
    /// Set only by the bake engine when it bakes a long block as several pieces (the server's
    /// `bake::scene::pieces`): which block of the scene this one is a piece of, so that its
    /// texels keep that block's surface names. Never read from or written to JSON.
    #[serde(skip)]
    pub piece: Option<BlockPiece>,
}

/// Where a piece lies in the block it was cut from ([`Block::piece`]): the block is cut into
/// `cells[0] × cells[1] × cells[2]` equal boxes and this piece is box `cell`.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockPiece {
    /// The scene block's id.
    pub of: String,
    pub cell: [u32; 3],
    pub cells: [u32; 3],
    /// The block's extent over `cells`, the same bits for every piece: the extent the piece's
    /// shape operators are keyed and baked by, so the pieces share them (their own
    /// `max − min` differ from it, and from each other, by the rounding of the cuts).
    pub extent: [f64; 3],
}

impl BlockPiece {
    /// Among the pieces whose face `face` is part of the block's face `face` (those on that
    /// side), this piece's index, row-major over the face's tangent axes.
    pub fn index_on_face(&self, face: Face) -> u32 {
        let (u, v) = face.tangent_axes();
        self.cell[v] * self.cells[u] + self.cell[u]
    }
}

impl Block {
    pub fn aabb(&self) -> Aabb {
        Aabb {
            min: self.min,
            max: self.max,
        }
    }

    pub fn is_open(&self, face: Face) -> bool {
        self.open.contains(&face)
    }

    /// Closed faces in canonical order (the order their texels are laid out in).
    pub fn closed_faces(&self) -> Vec<Face> {
        Face::ALL
            .into_iter()
            .filter(|f| !self.is_open(*f))
            .collect()
    }

    /// Albedo of a face (its override or the block's).
    pub fn face_albedo(&self, face: Face) -> [f64; 3] {
        *self.face_albedo.get(&face).unwrap_or(&self.albedo)
    }
}

/// Translation, rotation (unit quaternion x, y, z, w) and scale, applied scale first.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Transform {
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
    pub scale: [f64; 3],
}

impl Default for Transform {
    fn default() -> Self {
        Transform {
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: [1.0; 3],
        }
    }
}

impl Transform {
    /// Applies the transform to a point.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let s = [
            p[0] * self.scale[0],
            p[1] * self.scale[1],
            p[2] * self.scale[2],
        ];
        let r = rotate(self.rotation, s);
        [
            r[0] + self.translation[0],
            r[1] + self.translation[1],
            r[2] + self.translation[2],
        ]
    }
}

/// Rotates `v` by the unit quaternion `q = (x, y, z, w)`.
pub fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let [x, y, z, w] = q;
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let qv = [x, y, z];
    let t = cross(qv, v).map(|c| 2.0 * c);
    let c2 = cross(qv, t);
    [
        v[0] + w * t[0] + c2[0],
        v[1] + w * t[1] + c2[1],
        v[2] + w * t[2] + c2[2],
    ]
}

/// A static prop: a box or a mesh file (glTF/GLB/OBJ, path relative to the scene file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Clutter {
    pub id: String,
    #[serde(rename = "box", default, skip_serializing_if = "Option::is_none")]
    pub box_: Option<Aabb>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transform: Option<Transform>,
    pub albedo: [f64; 3],
}

/// A moving object; its pose comes per frame (LIGHTS.json `poses`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DynamicObject {
    pub id: String,
    pub mesh: String,
    pub albedo: [f64; 3],
    /// Boxes the object stays within (its whole extent, world metres). Empty (the default): it
    /// may go anywhere in the blocks. When every dynamic object lists regions, the probe volume
    /// it reads (U_dyn) is baked only over them ([`Scene::probe_regions`]), so a large level
    /// with a few moving objects pays for their neighbourhoods, not for the level.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub regions: Vec<Aabb>,
}

/// Two blocks joined through coincident open faces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Connection {
    pub block_a: usize,
    pub face_a: Face,
    pub block_b: usize,
    pub face_b: Face,
}

/// Where an open face of a block leads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Opening {
    /// Into another block through its coincident open face.
    Neighbour { block: usize, face: Face },
    /// Out of the level: light leaves.
    Void,
}

/// Why a scene was refused. The message names the object and field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneError {
    #[error("scene JSON: {0}")]
    Json(String),
    #[error("format: expected \"{SCENE_FORMAT}\", got \"{0}\"")]
    Format(String),
    #[error("{object}: {message}")]
    Invalid { object: String, message: String },
}

fn invalid(object: impl Into<String>, message: impl Into<String>) -> SceneError {
    SceneError::Invalid {
        object: object.into(),
        message: message.into(),
    }
}

const AXES: [&str; 3] = ["x", "y", "z"];

fn fmt_num(x: f64) -> String {
    format!("{x}")
}

fn check_finite(object: &str, field: &str, values: &[f64]) -> Result<(), SceneError> {
    for (k, v) in values.iter().enumerate() {
        if !v.is_finite() {
            let sub = if values.len() == 3 {
                format!("{field}.{}", AXES[k])
            } else {
                format!("{field}[{k}]")
            };
            return Err(invalid(object, format!("{sub} is not finite ({v})")));
        }
    }
    Ok(())
}

fn check_box(object: &str, min: &[f64; 3], max: &[f64; 3], prefix: &str) -> Result<(), SceneError> {
    check_finite(object, &format!("{prefix}min"), min)?;
    check_finite(object, &format!("{prefix}max"), max)?;
    for k in 0..3 {
        if max[k] <= min[k] {
            return Err(invalid(
                object,
                format!(
                    "{prefix}max.{a} ({}) <= {prefix}min.{a} ({})",
                    fmt_num(max[k]),
                    fmt_num(min[k]),
                    a = AXES[k]
                ),
            ));
        }
    }
    Ok(())
}

fn check_albedo(object: &str, field: &str, albedo: &[f64; 3]) -> Result<(), SceneError> {
    check_finite(object, field, albedo)?;
    for (k, a) in albedo.iter().enumerate() {
        if !(0.0..1.0).contains(a) {
            return Err(invalid(
                object,
                format!("{field}[{k}] ({a}) is outside [0, 1)"),
            ));
        }
    }
    Ok(())
}

fn check_id(kind: &str, id: &str, seen: &mut HashSet<String>) -> Result<(), SceneError> {
    if id.is_empty()
        || id.len() > 128
        || id.contains(['/', '"', '\\'])
        || id.chars().any(char::is_control)
    {
        return Err(invalid(
            format!("{kind} \"{id}\""),
            "id must be 1-128 characters without '/', '\"', '\\' or control characters",
        ));
    }
    if !seen.insert(format!("{kind}:{id}")) {
        return Err(invalid(format!("{kind} \"{id}\""), "duplicate id"));
    }
    Ok(())
}

impl Scene {
    /// Parses and validates a scene.
    pub fn from_json(text: &str) -> Result<Scene, SceneError> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| SceneError::Json(e.to_string()))?;
        if let Some(format) = value.get("format") {
            match format.as_str() {
                Some(SCENE_FORMAT) => {}
                Some(other) => return Err(SceneError::Format(other.to_string())),
                None => return Err(SceneError::Format(format.to_string())),
            }
        }
        let scene: Scene =
            serde_json::from_value(value).map_err(|e| SceneError::Json(e.to_string()))?;
        scene.validate()?;
        Ok(scene)
    }

    /// Checks every invariant the bake engine relies on.
    pub fn validate(&self) -> Result<(), SceneError> {
        if self.format != SCENE_FORMAT {
            return Err(SceneError::Format(self.format.clone()));
        }
        self.settings.validate()?;
        if self.blocks.is_empty() {
            return Err(invalid("blocks", "a scene needs at least one block"));
        }
        let mut seen = HashSet::new();
        for block in &self.blocks {
            match &block.piece {
                None => check_id("block", &block.id, &mut seen)?,
                // A piece of a long block the engine cut ([`Block::piece`]): the scene block's
                // id is checked once, at its first piece; the piece's own id is
                // `<block id>/<n>`.
                Some(piece) => {
                    if !seen.contains(&format!("block:{}", piece.of)) {
                        check_id("block", &piece.of, &mut seen)?;
                    }
                    if !seen.insert(format!("piece:{}", block.id)) {
                        return Err(invalid(format!("block \"{}\"", block.id), "duplicate id"));
                    }
                }
            }
            let object = format!("block \"{}\"", block.id);
            check_box(&object, &block.min, &block.max, "")?;
            check_albedo(&object, "albedo", &block.albedo)?;
            for (face, albedo) in &block.face_albedo {
                check_albedo(&object, &format!("face_albedo.{face}"), albedo)?;
            }
            let mut open = HashSet::new();
            for face in &block.open {
                if !open.insert(*face) {
                    return Err(invalid(&object, format!("open lists {face} twice")));
                }
            }
        }
        for clutter in &self.clutter {
            check_id("clutter", &clutter.id, &mut seen)?;
            let object = format!("clutter \"{}\"", clutter.id);
            check_albedo(&object, "albedo", &clutter.albedo)?;
            match (&clutter.box_, &clutter.mesh) {
                (Some(b), None) => {
                    check_box(&object, &b.min, &b.max, "box.")?;
                    if clutter.transform.is_some() {
                        return Err(invalid(
                            &object,
                            "transform applies to meshes only; give the box in world coordinates",
                        ));
                    }
                }
                (None, Some(path)) => {
                    check_mesh_path(&object, path)?;
                    if let Some(t) = &clutter.transform {
                        check_transform(&object, t)?;
                    }
                }
                (Some(_), Some(_)) => {
                    return Err(invalid(&object, "give either box or mesh, not both"))
                }
                (None, None) => return Err(invalid(&object, "needs a box or a mesh")),
            }
        }
        for object in &self.dynamic {
            check_id("dynamic", &object.id, &mut seen)?;
            let name = format!("dynamic \"{}\"", object.id);
            check_albedo(&name, "albedo", &object.albedo)?;
            check_mesh_path(&name, &object.mesh)?;
            for (k, region) in object.regions.iter().enumerate() {
                check_box(&name, &region.min, &region.max, &format!("regions[{k}]."))?;
            }
        }
        for (k, region) in self.light_regions.iter().enumerate() {
            check_box(&format!("light_regions[{k}]"), &region.min, &region.max, "")?;
        }
        self.check_block_overlaps()?;
        self.openings()?;
        self.check_probe_grid()?;
        Ok(())
    }

    /// Grid points of the probe volume U_dyn (`ceil(extent / probe_spacing)` per axis over the
    /// blocks' bounds, at least 1), as the bake lays it out.
    pub fn probe_grid_dims(&self) -> [f64; 3] {
        let b = self.bounds();
        [0, 1, 2].map(|k| {
            ((b.max[k] - b.min[k]) / self.settings.probe_spacing)
                .ceil()
                .max(1.0)
        })
    }

    /// Where the probe volume is baked: `Some(boxes)` when the scene has dynamic objects and
    /// every one lists [`DynamicObject::regions`] — each region grown by one `probe_spacing` on
    /// every side, so that a lookup anywhere inside a region finds the 8 grid points around it
    /// — and `None` for the whole level (an object that may go anywhere, or no dynamic object:
    /// the probes then shade clutter). With `probe_volume: always` the bake adds each clutter
    /// object's bounds, grown the same, to the boxes: the MRT baseline shades clutter from the
    /// probes. By default (`auto`) it does not: only the dynamic objects read the volume.
    pub fn probe_regions(&self) -> Option<Vec<Aabb>> {
        if self.dynamic.is_empty() || self.dynamic.iter().any(|d| d.regions.is_empty()) {
            return None;
        }
        let grow = self.settings.probe_spacing;
        Some(
            self.dynamic
                .iter()
                .flat_map(|d| &d.regions)
                .map(|r| Aabb {
                    min: r.min.map(|x| x - grow),
                    max: r.max.map(|x| x + grow),
                })
                .collect(),
        )
    }

    /// The probe volume is baked when the scene has clutter or dynamic objects; refuse a grid
    /// too large to allocate (1 m spacing over a 10 km level is 10¹² grid points).
    fn check_probe_grid(&self) -> Result<(), SceneError> {
        if self.clutter.is_empty() && self.dynamic.is_empty() {
            return Ok(());
        }
        let dims = self.probe_grid_dims();
        let points = dims[0] * dims[1] * dims[2];
        if points > MAX_PROBE_GRID_POINTS as f64 {
            return Err(invalid(
                "settings",
                format!(
                    "probe_spacing ({}) gives a {}×{}×{} probe grid over the blocks, more than \
                     {MAX_PROBE_GRID_POINTS} points; raise probe_spacing",
                    self.settings.probe_spacing, dims[0], dims[1], dims[2]
                ),
            ));
        }
        Ok(())
    }

    /// Refuses two blocks whose boxes share a volume (thicker than a relative 1e-9 on every
    /// axis): the first such pair in block order, as the loop over every pair finds it (tested
    /// against it). Two boxes can share a volume only where their x-intervals meet, so each block
    /// tests, in block order, the later blocks whose lower x lies between its own lower x less
    /// the widest block's width and its upper x: `O(n log n)` for a level of `n` blocks of
    /// similar widths rather than `O(n²)`.
    fn check_block_overlaps(&self) -> Result<(), SceneError> {
        let boxes: Vec<Aabb> = self.blocks.iter().map(Block::aabb).collect();
        let widest = boxes
            .iter()
            .map(|b| b.max[0] - b.min[0])
            .fold(0.0f64, f64::max);
        let slack = self.window_slack();
        let by_x = ByCoordinate::new(boxes.iter().map(|b| b.min[0]));
        let mut near = Vec::new();
        for (i, a) in boxes.iter().enumerate() {
            let later = |j: usize| j > i;
            by_x.within(
                a.min[0] - widest - slack,
                a.max[0] + slack,
                later,
                &mut near,
            );
            for &j in &near {
                let b = &boxes[j];
                if let Some(overlap) = a.intersection(b) {
                    let e = overlap.extent();
                    let tol = 1e-9 * scale_of(a).max(scale_of(b));
                    if e.iter().all(|x| *x > tol) {
                        return Err(invalid(
                            format!("block \"{}\"", self.blocks[i].id),
                            format!("overlaps block \"{}\"", self.blocks[j].id),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// Where every open face of every block leads, indexed `[block][face]`
    /// (`None` for closed faces). Refuses partial overlaps and open-against-closed faces.
    ///
    /// A face can meet only faces of the opposite direction lying on its plane (within the
    /// tolerance), so each face tests the blocks whose opposite face lies in a window of
    /// coordinates around its plane, in block order, rather than every block: the same tests in
    /// the same order as the pairwise loop over every block (tested against it), in
    /// `O(n log n)` for a level of `n` blocks rather than `O(n²)` (0.16 s per call at 1,000
    /// blocks, called once per unit by a farm worker).
    pub fn openings(&self) -> Result<Vec<[Option<Opening>; 6]>, SceneError> {
        let window = self.window_slack();
        // Per face direction: the blocks by that face's plane coordinate.
        let planes: Vec<ByCoordinate> = Face::ALL
            .iter()
            .map(|&f| ByCoordinate::new(self.blocks.iter().map(|b| b.aabb().face_rect(f).2)))
            .collect();
        let mut near = Vec::new();
        let mut out = vec![[None; 6]; self.blocks.len()];
        for (i, a) in self.blocks.iter().enumerate() {
            for face in Face::ALL {
                let rect = a.aabb().face_rect(face);
                let ac = rect.2;
                let plane = &planes[face.opposite().index()];
                plane.within(ac - window, ac + window, |_| true, &mut near);
                out[i][face.index()] = self.opening_of(i, face, rect, &near)?;
            }
        }
        Ok(out)
    }

    /// How far the searches by coordinate ([`ByCoordinate`]) widen their windows: twice the
    /// largest tolerance of any pair of blocks (`1e-9` of the larger one's scale), far above the
    /// rounding of a coordinate plus or minus it. A wider window only tests more pairs.
    fn window_slack(&self) -> f64 {
        2e-9 * self
            .blocks
            .iter()
            .map(|b| scale_of(&b.aabb()))
            .fold(1.0f64, f64::max)
    }

    /// Where face `face` of block `i` leads (`rect`: the face's `Aabb::face_rect`), among the
    /// blocks `candidates` (ascending; every block whose opposite face can lie on its plane):
    /// the last neighbour found, `Void` when open onto nothing, `None` when closed.
    fn opening_of(
        &self,
        i: usize,
        face: Face,
        (amin, amax, ac): ([f64; 2], [f64; 2], f64),
        candidates: &[usize],
    ) -> Result<Option<Opening>, SceneError> {
        let a = &self.blocks[i];
        let mut found = None;
        for &j in candidates {
            let b = &self.blocks[j];
            if i == j {
                continue;
            }
            let other = face.opposite();
            let (bmin, bmax, bc) = b.aabb().face_rect(other);
            // Symmetric in a and b, so both blocks agree on whether they connect.
            let tol = 1e-9 * scale_of(&a.aabb()).max(scale_of(&b.aabb()));
            if (ac - bc).abs() > tol {
                continue;
            }
            let overlap = (0..2).all(|k| amin[k].max(bmin[k]) < amax[k].min(bmax[k]) - tol);
            if !overlap {
                continue;
            }
            let same = (0..2)
                .all(|k| (amin[k] - bmin[k]).abs() <= tol && (amax[k] - bmax[k]).abs() <= tol);
            let a_open = a.is_open(face);
            let b_open = b.is_open(other);
            let names = || (format!("block \"{}\"", a.id), format!("block \"{}\"", b.id));
            if !a_open && !b_open {
                continue; // back-to-back walls
            }
            if !same {
                let (na, nb) = names();
                return Err(invalid(
                    na,
                    format!("face {face} partially overlaps face {other} of {nb}; openings must coincide exactly"),
                ));
            }
            if a_open != b_open {
                let (na, nb) = names();
                let (open_name, closed_name, open_face, closed_face) = if a_open {
                    (na, nb, face, other)
                } else {
                    (nb, na, other, face)
                };
                return Err(invalid(
                    open_name,
                    format!("open face {open_face} lies against closed face {closed_face} of {closed_name}"),
                ));
            }
            found = Some(Opening::Neighbour {
                block: j,
                face: other,
            });
        }
        Ok(a.is_open(face).then(|| found.unwrap_or(Opening::Void)))
    }

    /// Every pair of connected blocks once (`block_a < block_b`).
    pub fn connections(&self) -> Result<Vec<Connection>, SceneError> {
        let mut out = Vec::new();
        for (a, faces) in self.openings()?.iter().enumerate() {
            for face in Face::ALL {
                if let Some(Opening::Neighbour { block, face: fb }) = faces[face.index()] {
                    if a < block {
                        out.push(Connection {
                            block_a: a,
                            face_a: face,
                            block_b: block,
                            face_b: fb,
                        });
                    }
                }
            }
        }
        Ok(out)
    }

    /// Bounding box of all blocks.
    pub fn bounds(&self) -> Aabb {
        let mut b = self.blocks[0].aabb();
        for block in &self.blocks {
            for k in 0..3 {
                b.min[k] = b.min[k].min(block.min[k]);
                b.max[k] = b.max[k].max(block.max[k]);
            }
        }
        b
    }
}

/// The blocks listed by one coordinate each (ascending, ties by block index), so that those whose
/// coordinate lies in an interval are found by binary search: how the checks that would compare
/// every pair of blocks ([`Scene::openings`], the overlap check) test only nearby ones.
struct ByCoordinate(Vec<(f64, usize)>);

impl ByCoordinate {
    /// Block `j`'s coordinate is the `j`-th of `values`.
    fn new(values: impl Iterator<Item = f64>) -> ByCoordinate {
        let mut v: Vec<(f64, usize)> = values.enumerate().map(|(j, x)| (x, j)).collect();
        v.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
        ByCoordinate(v)
    }

    /// The blocks whose coordinate lies in `[lo, hi]` and that `keep` keeps, ascending by
    /// block index, into `out` (cleared first).
    fn within(&self, lo: f64, hi: f64, keep: impl Fn(usize) -> bool, out: &mut Vec<usize>) {
        let first = self.0.partition_point(|p| p.0 < lo);
        out.clear();
        out.extend(
            self.0[first..]
                .iter()
                .take_while(|p| p.0 <= hi)
                .map(|p| p.1)
                .filter(|&j| keep(j)),
        );
        out.sort_unstable();
    }
}

fn scale_of(b: &Aabb) -> f64 {
    b.min
        .iter()
        .chain(b.max.iter())
        .fold(1.0f64, |m, x| m.max(x.abs()))
}

fn check_mesh_path(object: &str, path: &str) -> Result<(), SceneError> {
    let lower = path.to_ascii_lowercase();
    if path.is_empty() {
        return Err(invalid(object, "mesh path is empty"));
    }
    let escapes = path.starts_with('/')
        || path.starts_with('\\')
        || path.contains(':')
        || path.split(['/', '\\']).any(|part| part == "..");
    if escapes {
        return Err(invalid(
            object,
            format!("mesh \"{path}\" must be a relative path inside the scene's directory"),
        ));
    }
    if !(lower.ends_with(".obj") || lower.ends_with(".gltf") || lower.ends_with(".glb")) {
        return Err(invalid(
            object,
            format!("mesh \"{path}\" is not .obj, .gltf or .glb"),
        ));
    }
    Ok(())
}

fn check_transform(object: &str, t: &Transform) -> Result<(), SceneError> {
    check_finite(object, "transform.translation", &t.translation)?;
    check_finite(object, "transform.rotation", &t.rotation)?;
    check_finite(object, "transform.scale", &t.scale)?;
    let norm = t.rotation.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > 1e-3 {
        return Err(invalid(
            object,
            format!("transform.rotation is not a unit quaternion (norm {norm})"),
        ));
    }
    for (k, s) in t.scale.iter().enumerate() {
        if *s == 0.0 {
            return Err(invalid(
                object,
                format!("transform.scale.{} is zero", AXES[k]),
            ));
        }
    }
    Ok(())
}

impl Settings {
    pub fn validate(&self) -> Result<(), SceneError> {
        let object = "settings";
        if !(1..=128).contains(&self.texels_per_face) {
            return Err(invalid(
                object,
                format!(
                    "texels_per_face ({}) must be in 1..=128",
                    self.texels_per_face
                ),
            ));
        }
        if !(1..=1 << 20).contains(&self.rays_per_texel) {
            return Err(invalid(
                object,
                format!(
                    "rays_per_texel ({}) must be in 1..=1048576",
                    self.rays_per_texel
                ),
            ));
        }
        if !(self.tolerance > 0.0 && self.tolerance < 1.0) {
            return Err(invalid(
                object,
                format!("tolerance ({}) must be in (0, 1)", self.tolerance),
            ));
        }
        if !(1..=32).contains(&self.lightfield_cells) {
            return Err(invalid(
                object,
                format!(
                    "lightfield_cells ({}) must be in 1..=32",
                    self.lightfield_cells
                ),
            ));
        }
        if !(1..=32).contains(&self.lightfield_directions) {
            return Err(invalid(
                object,
                format!(
                    "lightfield_directions ({}) must be in 1..=32",
                    self.lightfield_directions
                ),
            ));
        }
        if !(self.probe_spacing.is_finite() && self.probe_spacing > 0.0) {
            return Err(invalid(
                object,
                format!("probe_spacing ({}) must be positive", self.probe_spacing),
            ));
        }
        if !(self.codec_error > 0.0 && self.codec_error < 1.0) {
            return Err(invalid(
                object,
                format!("codec_error ({}) must be in (0, 1)", self.codec_error),
            ));
        }
        if !(self.transport_codec_error > 0.0 && self.transport_codec_error < 1.0) {
            return Err(invalid(
                object,
                format!(
                    "transport_codec_error ({}) must be in (0, 1)",
                    self.transport_codec_error
                ),
            ));
        }
        if !(0.0..1.0).contains(&self.clutter_importance) {
            return Err(invalid(
                object,
                format!(
                    "clutter_importance ({}) must be in [0, 1)",
                    self.clutter_importance
                ),
            ));
        }
        if !(1..=65536).contains(&self.prior_lights) {
            return Err(invalid(
                object,
                format!("prior_lights ({}) must be in 1..=65536", self.prior_lights),
            ));
        }
        let d = &self.dnrt;
        if !(2..=128).contains(&d.resolution) {
            return Err(invalid(
                object,
                format!("dnrt.resolution ({}) must be in 2..=128", d.resolution),
            ));
        }
        if d.sh != 4 && d.sh != 9 {
            return Err(invalid(
                object,
                format!("dnrt.sh ({}) must be 4 or 9", d.sh),
            ));
        }
        let extent_ok = d.extent.is_finite() && d.extent > 0.0;
        let outer_ok = d.outer_extent.is_finite() && d.outer_extent >= d.extent;
        if !extent_ok || !outer_ok {
            return Err(invalid(
                object,
                format!(
                    "dnrt.extent ({}) must be positive and dnrt.outer_extent ({}) at least as large",
                    d.extent, d.outer_extent
                ),
            ));
        }
        if !(1..=1 << 20).contains(&d.rays) {
            return Err(invalid(
                object,
                format!("dnrt.rays ({}) must be in 1..=1048576", d.rays),
            ));
        }
        Ok(())
    }
}

/// The JSON Schema of `lightfarm.scene/1`.
pub fn scene_schema() -> serde_json::Value {
    serde_json::to_value(schemars::schema_for!(Scene)).expect("schema serialises")
}
