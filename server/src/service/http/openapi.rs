//! The OpenAPI 3.1 document at `/openapi.json`: paths and API types from utoipa, and the scene
//! description's schema from the same schemars definition `lightfarm schema` prints, so the two
//! can never disagree.
//!
//! Invariants: the document tells the truth about the server that serves it. In open mode (no
//! teams configured) it declares no security and no 401; in team mode every `/v1` operation
//! requires the bearer scheme and declares 401. `POST /v1/scenes` takes the `Scene` schema.
//! Every `/v1` operation declares the 408 of the request timeout and the 500 of an internal
//! failure, which any of them can give. `GET /v1/bakes/{id}/events` describes one server-sent
//! event (name and JSON data), not a JSON body.

use axum::extract::State;
use axum::Json;
use serde_json::{json, Value};
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi};

use lightfarm_proto::api::{
    ApiError, AssetCreated, BakeEvent, BakeList, BakeStatus, JobState, PreviewBounces,
    PreviewLight, PreviewRequest, SceneCreated, SceneList, ShapeEntry, StageTiming, SubmitBake,
};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;

use super::AppState;

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
        super::scene_list::list_scenes,
        super::bakes::submit_bake,
        super::bake_list::list_bakes,
        super::bakes::bake_status,
        super::bakes::cancel_bake,
        super::events::bake_events,
        super::evaluate::evaluate_bake,
        super::bake_bundle::stream_bake_bundle,
        super::preview::preview_glb,
        super::bundles::get_bundle,
        super::ops::list_shapes,
        super::ops::healthz,
        super::ops::readyz,
        super::ops::metrics,
    ),
    components(schemas(
        ApiError, AssetCreated, BakeEvent, BakeList, BakeStatus, JobState, SceneCreated,
        SceneList, ShapeEntry, StageTiming, SubmitBake, PreviewRequest, PreviewLight,
        PreviewBounces, LightSet, ResultFile
    )),
    modifiers(&Security)
)]
struct ApiDoc;

/// Whether the server asks for tokens.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AuthMode {
    /// One local user, no tokens.
    Open,
    /// `[[teams]]` configured: every `/v1` request carries a bearer token.
    Teams,
}

/// `GET /openapi.json`: the document for the mode this server runs in.
pub async fn serve_openapi(State(state): State<AppState>) -> Json<Value> {
    let mode = if state.config.is_open() {
        AuthMode::Open
    } else {
        AuthMode::Teams
    };
    Json(openapi_json(mode))
}

/// The document as JSON for `mode` (see the module doc).
pub fn openapi_json(mode: AuthMode) -> Value {
    let mut doc = base_document();
    let error_body =
        json!({ "application/json": { "schema": { "$ref": "#/components/schemas/ApiError" } } });
    let scene_body = json!({ "$ref": "#/components/schemas/Scene" });
    if let Some(schema) =
        doc.pointer_mut("/paths/~1v1~1scenes/post/requestBody/content/application~1json/schema")
    {
        *schema = scene_body;
    }
    // An event stream's schema describes one server-sent event as the server writes it: its
    // `event` name (`BakeEvent::kind`) and its `data`, a `BakeEvent` as JSON text.
    if let Some(schema) = doc.pointer_mut(
        "/paths/~1v1~1bakes~1{id}~1events/get/responses/200/content/text~1event-stream/schema",
    ) {
        *schema = json!({
            "type": "object",
            "required": ["event", "data"],
            "properties": {
                "event": { "type": "string", "enum": ["state", "stage", "sections", "progress"] },
                "data": {
                    "type": "string",
                    "contentMediaType": "application/json",
                    "contentSchema": { "$ref": "#/components/schemas/BakeEvent" }
                }
            }
        });
    }
    let paths = doc["paths"].as_object_mut().expect("paths");
    for (path, item) in paths.iter_mut() {
        let Some(item) = item.as_object_mut() else {
            continue;
        };
        for (_, operation) in item.iter_mut() {
            let Some(operation) = operation.as_object_mut() else {
                continue;
            };
            let secured = operation.contains_key("security");
            let responses = operation
                .entry("responses")
                .or_insert_with(|| json!({}))
                .as_object_mut()
                .expect("responses is an object");
            match mode {
                AuthMode::Open => {
                    responses.remove("401");
                }
                AuthMode::Teams if secured => {
                    responses.entry("401").or_insert_with(|| {
                        json!({ "description": "No or unknown token", "content": error_body.clone() })
                    });
                }
                AuthMode::Teams => {}
            }
            if path.starts_with("/v1/") {
                responses.entry("408").or_insert_with(|| {
                    json!({ "description": "The request took longer than limits.request_timeout_seconds" })
                });
                responses.entry("500").or_insert_with(|| {
                    json!({ "description": "Internal error (the body names the request id; the detail is in the server log)", "content": error_body.clone() })
                });
            }
            if mode == AuthMode::Open {
                operation.remove("security");
            }
        }
    }
    if mode == AuthMode::Open {
        if let Some(components) = doc["components"].as_object_mut() {
            components.remove("securitySchemes");
        }
    }
    doc
}

/// The utoipa document with `components.schemas.Scene` and `LightSet` (and their definitions)
/// added from the same JSON Schemas `lightfarm schema` and the CLI's lights reader use.
fn base_document() -> Value {
    let mut doc = serde_json::to_value(ApiDoc::openapi()).expect("openapi serialises");
    let lights = serde_json::to_value(schemars::schema_for!(lightfarm_proto::lights::LightSet))
        .expect("schema serialises");
    add_schema(&mut doc, "Scene", lightfarm_proto::scene::scene_schema());
    add_schema(&mut doc, "LightSet", lights);
    if let Some(property) = doc.pointer_mut("/components/schemas/PreviewRequest/properties/lights")
    {
        *property = json!({ "$ref": "#/components/schemas/LightSet" });
    }
    doc
}

/// Adds a schemars JSON Schema as `components.schemas.<name>`, its `$defs` beside it.
fn add_schema(doc: &mut Value, name: &str, mut schema: Value) {
    let defs = schema
        .as_object_mut()
        .and_then(|o| o.remove("$defs"))
        .unwrap_or_default();
    if let Some(o) = schema.as_object_mut() {
        o.remove("$schema");
    }
    let mut text = serde_json::to_string(&schema).expect("schema serialises");
    let mut defs_text = serde_json::to_string(&defs).expect("schema serialises");
    for t in [&mut text, &mut defs_text] {
        *t = t.replace("#/$defs/", "#/components/schemas/");
    }
    let schemas = doc
        .pointer_mut("/components/schemas")
        .and_then(|s| s.as_object_mut())
        .expect("components.schemas exists");
    schemas.insert(name.into(), serde_json::from_str(&text).expect("valid"));
    if let Value::Object(defs) = serde_json::from_str::<Value>(&defs_text).expect("valid") {
        for (name, schema) in defs {
            schemas.entry(name).or_insert(schema);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn document_has_every_path_and_the_scene_schema() {
        let doc = openapi_json(AuthMode::Teams);
        assert!(doc["openapi"].as_str().unwrap().starts_with("3.1"));
        for path in [
            "/v1/assets",
            "/v1/scenes",
            "/v1/bakes",
            "/v1/bakes/{id}/preview.glb",
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

    /// Open mode declares no security anywhere; team mode secures every `/v1` operation and
    /// declares its 401; both take the real scene schema.
    #[test]
    fn security_follows_the_mode_and_scenes_take_the_scene_schema() {
        let open = openapi_json(AuthMode::Open);
        let teams = openapi_json(AuthMode::Teams);
        assert!(open["components"].get("securitySchemes").is_none());
        assert!(teams["components"]["securitySchemes"]["bearer"].is_object());
        for (path, item) in teams["paths"].as_object().unwrap() {
            for (method, op) in item.as_object().unwrap() {
                let o = &open["paths"][path][method];
                assert!(o.get("security").is_none(), "{method} {path}");
                assert!(o["responses"].get("401").is_none(), "{method} {path}");
                if path.starts_with("/v1/") {
                    assert!(op["security"].is_array(), "{method} {path} unsecured");
                    assert!(op["responses"]["401"].is_object(), "{method} {path}");
                    assert!(op["responses"]["500"].is_object(), "{method} {path}");
                }
            }
        }
        for doc in [&open, &teams] {
            assert_eq!(
                doc["paths"]["/v1/scenes"]["post"]["requestBody"]["content"]["application/json"]
                    ["schema"]["$ref"],
                "#/components/schemas/Scene"
            );
            let required = doc["components"]["schemas"]["Scene"]["required"]
                .as_array()
                .unwrap();
            assert!(required.iter().any(|r| r == "blocks"), "{required:?}");
        }
    }
}
