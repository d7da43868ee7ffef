//! The OpenAPI 3.1 document at `/openapi.json`: paths and API types from utoipa, and the scene
//! description's schema from the same schemars definition `lightfarm schema` prints, so the two
//! can never disagree.

use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi};

use lightfarm_proto::api::{
    ApiError, AssetCreated, BakeEvent, BakeStatus, JobState, SceneCreated, ShapeEntry, StageTiming,
    SubmitBake,
};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;

struct Security;

impl Modify for Security {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
    }
}

#[derive(OpenApi)]
#[openapi(
    info(title = "lightfarm", description = "Bake precomputed indirect lighting (MRT, DRT, DNRT) into operator bundles."),
    paths(
        super::assets::upload_asset,
        super::scenes::create_scene,
        super::bakes::submit_bake,
        super::bakes::bake_status,
        super::bakes::cancel_bake,
        super::events::bake_events,
        super::evaluate::evaluate_bake,
        super::bake_bundle::stream_bake_bundle,
        super::bundles::get_bundle,
        super::ops::list_shapes,
        super::ops::healthz,
        super::ops::readyz,
        super::ops::metrics,
    ),
    components(schemas(
        ApiError, AssetCreated, BakeEvent, BakeStatus, JobState, SceneCreated, ShapeEntry,
        StageTiming, SubmitBake, LightSet, ResultFile
    )),
    modifiers(&Security)
)]
struct ApiDoc;

/// The document as JSON, with `components.schemas.Scene` (and its definitions) added from the
/// scene's JSON Schema.
pub fn openapi_json() -> serde_json::Value {
    let mut doc = serde_json::to_value(ApiDoc::openapi()).expect("openapi serialises");
    let mut scene = lightfarm_proto::scene::scene_schema();
    let defs = scene
        .as_object_mut()
        .and_then(|o| o.remove("$defs"))
        .unwrap_or_default();
    if let Some(o) = scene.as_object_mut() {
        o.remove("$schema");
    }
    let mut text = serde_json::to_string(&scene).expect("schema serialises");
    let mut defs_text = serde_json::to_string(&defs).expect("schema serialises");
    for t in [&mut text, &mut defs_text] {
        *t = t.replace("#/$defs/", "#/components/schemas/");
    }
    let schemas = doc
        .pointer_mut("/components/schemas")
        .and_then(|s| s.as_object_mut())
        .expect("components.schemas exists");
    schemas.insert("Scene".into(), serde_json::from_str(&text).expect("valid"));
    if let serde_json::Value::Object(defs) =
        serde_json::from_str::<serde_json::Value>(&defs_text).expect("valid")
    {
        for (name, schema) in defs {
            schemas.entry(name).or_insert(schema);
        }
    }
    doc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn document_has_every_path_and_the_scene_schema() {
        let doc = openapi_json();
        assert!(doc["openapi"].as_str().unwrap().starts_with("3.1"));
        for path in [
            "/v1/assets",
            "/v1/scenes",
            "/v1/bakes",
            "/v1/bakes/{id}",
            "/v1/bakes/{id}/events",
            "/v1/bakes/{id}/evaluate",
            "/v1/bakes/{id}/bundle",
            "/v1/bundles/{hash}",
            "/v1/shapes",
            "/healthz",
            "/readyz",
            "/metrics",
        ] {
            assert!(doc["paths"].get(path).is_some(), "missing {path}");
        }
        assert!(doc["components"]["schemas"]["Scene"]["properties"]["blocks"].is_object());
        assert!(doc["components"]["schemas"]["BakeStatus"].is_object());
        // Every $ref resolves inside the document.
        let text = doc.to_string();
        for piece in text.split("\"$ref\":\"").skip(1) {
            let target = &piece[..piece.find('"').unwrap()];
            let pointer = target.trim_start_matches('#');
            assert!(doc.pointer(pointer).is_some(), "dangling {target}");
        }
    }
}
