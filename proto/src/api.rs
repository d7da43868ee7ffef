//! The bake service's HTTP API types (`/v1`): what `lightfarm serve` sends and receives and what
//! the client's `service` module reads. The OpenAPI document at `/openapi.json` is generated from
//! these (feature `openapi` derives `utoipa::ToSchema`).
//!
//! Invariants:
//! - Identifiers are lowercase hex BLAKE3 hashes (64 characters) of content: an asset's bytes, a
//!   scene's canonical JSON, a bake's (scene id, effective settings), a bundle's bytes. The same
//!   content always gets the same id, whichever team sends it.
//! - Times are seconds (f64); progress fractions are in [0, 1].
//! - Every error body is an [`ApiError`].

use serde::{Deserialize, Serialize};

/// Lifecycle of a bake job. `Succeeded`, `Failed` and `Cancelled` are final.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    Queued,
    Running,
    Succeeded,
    Failed,
    Cancelled,
}

impl JobState {
    /// Whether the job will never change state again.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            JobState::Succeeded | JobState::Failed | JobState::Cancelled
        )
    }

    /// Every state, for metrics.
    pub const ALL: [JobState; 5] = [
        JobState::Queued,
        JobState::Running,
        JobState::Succeeded,
        JobState::Failed,
        JobState::Cancelled,
    ];

    /// The lowercase name used on the wire.
    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }
}

/// `POST /v1/assets` response: the content hash the scene's mesh paths name.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct AssetCreated {
    pub hash: String,
    /// `glb`, `gltf` or `obj`, as detected from the bytes.
    pub format: String,
    pub bytes: u64,
    pub triangles: u64,
}

/// `POST /v1/scenes` response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct SceneCreated {
    /// Content hash of the scene's canonical JSON.
    pub id: String,
    pub name: String,
    pub blocks: u64,
    pub clutter: u64,
    pub dynamic: u64,
    /// Texels the scene's surfaces hold at its own `texels_per_face`.
    pub texels: u64,
}

/// `POST /v1/bakes` request.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct SubmitBake {
    /// A scene id from `POST /v1/scenes`.
    pub scene: String,
    /// Overrides of the scene's `settings` (any subset of its fields, same names and types);
    /// `null` or `{}` bakes the scene as described.
    #[serde(default)]
    #[cfg_attr(feature = "openapi", schema(value_type = Object))]
    pub settings: serde_json::Value,
}

/// Seconds a finished stage took.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct StageTiming {
    pub stage: String,
    pub seconds: f64,
}

/// `GET /v1/bakes/{id}` (and the body of `POST /v1/bakes`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct BakeStatus {
    pub id: String,
    pub scene: String,
    pub state: JobState,
    /// The stage running now (or the last one that ran).
    pub stage: Option<String>,
    /// Work items of the current stage done, and in all.
    #[serde(default)]
    pub stage_done: u64,
    #[serde(default)]
    pub stage_total: u64,
    /// Fraction of the current stage done.
    pub stage_progress: f64,
    /// Fraction of the whole bake done (stages weighted by their expected share).
    pub progress: f64,
    pub stages: Vec<StageTiming>,
    /// Why the bake failed or was re-queued.
    pub error: Option<String>,
    /// The bundle's content hash once the bake succeeded (`GET /v1/bundles/{hash}`).
    pub bundle: Option<String>,
    pub bundle_bytes: Option<u64>,
    /// True when this answer came from an earlier identical bake (no work was done).
    #[serde(default)]
    pub cached: bool,
    /// Unix seconds.
    pub submitted_at: f64,
    pub finished_at: Option<f64>,
}

/// One server-sent event of `GET /v1/bakes/{id}/events` (the SSE `event:` field is `kind`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum BakeEvent {
    /// The job's state changed.
    State {
        state: JobState,
        error: Option<String>,
        bundle: Option<String>,
    },
    /// A stage began with `total` work items.
    Stage { stage: String, total: u64 },
    /// The first `bytes` bytes of the bundle are final and can be read from
    /// `GET /v1/bakes/{id}/bundle` (the sections named; later ones follow as they finish).
    Sections { sections: Vec<String>, bytes: u64 },
    /// Progress within the current stage.
    Progress {
        stage: String,
        done: u64,
        total: u64,
        /// Fraction of the whole bake.
        overall: f64,
    },
}

impl BakeEvent {
    /// The SSE event name.
    pub fn kind(&self) -> &'static str {
        match self {
            BakeEvent::State { .. } => "state",
            BakeEvent::Stage { .. } => "stage",
            BakeEvent::Sections { .. } => "sections",
            BakeEvent::Progress { .. } => "progress",
        }
    }
}

/// One cached shape operator (`GET /v1/shapes`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ShapeEntry {
    pub key: String,
    pub bytes: u64,
    /// How many finished bakes used it.
    pub uses: u64,
}

/// Every error response's body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ApiError {
    pub error: String,
}

/// `GET /v1/bakes`: one page of the team's bakes, newest first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct BakeList {
    pub bakes: Vec<BakeStatus>,
    /// The next page (path and query), absent on the last page.
    pub next: Option<String>,
}

/// One scene of `GET /v1/scenes` (the summary `POST /v1/scenes` answers with).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct SceneList {
    pub scenes: Vec<SceneCreated>,
    /// The next page (path and query), absent on the last page.
    pub next: Option<String>,
}

/// Which light a preview's textures hold.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum PreviewLight {
    /// Direct + indirect.
    #[default]
    Lit,
    Direct,
    Indirect,
}

/// How many bounces of indirect light a preview shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum PreviewBounces {
    One,
    #[default]
    All,
}

impl PreviewBounces {
    /// The bounce count it names: `one` is 1, `all` is all (the runtime's converged default).
    pub fn count(self) -> crate::bounces::BounceCount {
        match self {
            PreviewBounces::One => crate::bounces::BounceCount::ONE,
            PreviewBounces::All => crate::bounces::BounceCount::All,
        }
    }
}

/// `POST /v1/bakes/{id}/preview.glb`: the light set to evaluate the bake's bundle under.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct PreviewRequest {
    /// A LIGHTS.json document (`lightfarm.lights`: point lights and dynamic-object poses).
    #[cfg_attr(feature = "openapi", schema(value_type = Object))]
    pub lights: crate::lights::LightSet,
    #[serde(default)]
    pub light: PreviewLight,
    #[serde(default)]
    pub bounces: PreviewBounces,
}
