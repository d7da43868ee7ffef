//! LIGHTS.json: the point lights of one frame and the poses of dynamic objects.
//!
//! Units: positions in metres (world frame), intensity in W/sr (radiant intensity per RGB
//! channel). Direct radiance at a Lambertian texel is `ρ/π · I · cosθ / r² · V`.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// The lights and object poses of one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct LightSet {
    pub lights: Vec<Light>,
    #[serde(default)]
    pub poses: Vec<Pose>,
}

/// Kinds of light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    Point,
}

/// One light.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Light {
    pub kind: LightKind,
    #[cfg_attr(feature = "openapi", schema(min_items = 3, max_items = 3))]
    pub position: [f64; 3],
    /// Radiant intensity, W/sr per channel.
    #[cfg_attr(feature = "openapi", schema(min_items = 3, max_items = 3))]
    pub intensity: [f64; 3],
}

/// The pose of a dynamic object this frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Pose {
    pub id: String,
    #[cfg_attr(feature = "openapi", schema(min_items = 3, max_items = 3))]
    pub translation: [f64; 3],
    #[serde(default = "identity_rotation")]
    #[cfg_attr(feature = "openapi", schema(min_items = 4, max_items = 4))]
    pub rotation: [f64; 4],
}

fn identity_rotation() -> [f64; 4] {
    [0.0, 0.0, 0.0, 1.0]
}

/// Why a light set was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LightsError {
    #[error("lights JSON: {0}")]
    Json(String),
    #[error("{0}")]
    Invalid(String),
}

impl LightSet {
    /// Parses and validates LIGHTS.json.
    pub fn from_json(text: &str) -> Result<LightSet, LightsError> {
        let set: LightSet =
            serde_json::from_str(text).map_err(|e| LightsError::Json(e.to_string()))?;
        for (k, light) in set.lights.iter().enumerate() {
            if !light.position.iter().all(|x| x.is_finite()) {
                return Err(LightsError::Invalid(format!(
                    "lights[{k}]: position is not finite"
                )));
            }
            if !light.intensity.iter().all(|x| x.is_finite() && *x >= 0.0) {
                return Err(LightsError::Invalid(format!(
                    "lights[{k}]: intensity must be finite and non-negative"
                )));
            }
        }
        for pose in &set.poses {
            if !pose
                .translation
                .iter()
                .chain(pose.rotation.iter())
                .all(|x| x.is_finite())
            {
                return Err(LightsError::Invalid(format!(
                    "pose \"{}\": not finite",
                    pose.id
                )));
            }
        }
        Ok(set)
    }
}
