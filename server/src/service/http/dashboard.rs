//! The web dashboard at `GET /`: the page, its scripts and the vendored three.js, embedded in
//! the binary (`server/web/`, `include_bytes!`) so `lightfarm serve` needs no build step and no
//! files beside it. Assets are served gzip- or zstd-compressed when the browser accepts it.
//!
//! Invariant: the dashboard is static; everything it shows comes from the `/v1` API with the
//! token the user types, so it can show nothing the API would not give that team.

use axum::extract::Path;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use tower_http::compression::CompressionLayer;

use super::AppState;

/// (path under `/ui/`, content type, bytes).
const ASSETS: &[(&str, &str, &[u8])] = &[
    (
        "index.html",
        HTML,
        include_bytes!("../../../web/index.html"),
    ),
    (
        "style.css",
        "text/css; charset=utf-8",
        include_bytes!("../../../web/style.css"),
    ),
    ("api.js", JS, include_bytes!("../../../web/api.js")),
    ("app.js", JS, include_bytes!("../../../web/app.js")),
    ("preview.js", JS, include_bytes!("../../../web/preview.js")),
    (
        "vendor/three/three.module.min.js",
        JS,
        include_bytes!("../../../web/vendor/three/three.module.min.js"),
    ),
    (
        "vendor/three/addons/controls/OrbitControls.js",
        JS,
        include_bytes!("../../../web/vendor/three/addons/controls/OrbitControls.js"),
    ),
    (
        "vendor/three/addons/loaders/GLTFLoader.js",
        JS,
        include_bytes!("../../../web/vendor/three/addons/loaders/GLTFLoader.js"),
    ),
    (
        "vendor/three/addons/utils/BufferGeometryUtils.js",
        JS,
        include_bytes!("../../../web/vendor/three/addons/utils/BufferGeometryUtils.js"),
    ),
    (
        "vendor/three/LICENSE",
        "text/plain; charset=utf-8",
        include_bytes!("../../../web/vendor/three/LICENSE"),
    ),
];

const HTML: &str = "text/html; charset=utf-8";
const JS: &str = "text/javascript; charset=utf-8";

fn asset(path: &str) -> Response {
    match ASSETS.iter().find(|(name, _, _)| *name == path) {
        Some((_, content_type, bytes)) => {
            // Vendored libraries change only with the binary; the app's own files are
            // revalidated so a new build shows at once.
            let cache = if path.starts_with("vendor/") {
                "public, max-age=86400"
            } else {
                "no-cache"
            };
            (
                [
                    (header::CONTENT_TYPE, *content_type),
                    (header::CACHE_CONTROL, cache),
                ],
                *bytes,
            )
                .into_response()
        }
        None => (StatusCode::NOT_FOUND, "not found\n").into_response(),
    }
}

/// `/` and `/ui/*`.
pub fn routes() -> Router<AppState> {
    Router::new()
        .route("/", get(|| async { asset("index.html") }))
        .route(
            "/ui/{*path}",
            get(|Path(path): Path<String>| async move { asset(&path) }),
        )
        .layer(CompressionLayer::new())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every file the page and scripts import is embedded (a missing one would only show in a
    /// browser).
    #[test]
    fn every_imported_file_is_embedded() {
        let text = |name: &str| {
            let (_, _, bytes) = ASSETS.iter().find(|(n, _, _)| *n == name).unwrap();
            std::str::from_utf8(bytes).unwrap().to_string()
        };
        let html = text("index.html");
        for piece in html.split("\"/ui/").skip(1) {
            let path = &piece[..piece.find('"').unwrap()];
            if path.ends_with('/') {
                continue; // the import map's prefix
            }
            assert!(ASSETS.iter().any(|(n, _, _)| *n == path), "{path}");
        }
        for (name, _, _) in ASSETS.iter().filter(|(n, _, _)| n.ends_with(".js")) {
            let dir = name.rsplit_once('/').map_or("", |(d, _)| d);
            // Import statements only (`import … from '…'`, or the closing line of a multi-line
            // import), not the word "from" in comments and strings.
            let source = text(name);
            let statements = source.lines().map(str::trim).filter(|line| {
                ["import ", "export ", "} from "]
                    .iter()
                    .any(|start| line.starts_with(start))
            });
            for piece in statements.filter_map(|line| line.split_once("from '").map(|(_, p)| p)) {
                let target = &piece[..piece.find('\'').unwrap()];
                if target == "three" {
                    continue;
                }
                let target = target.strip_prefix("three/addons/").map_or_else(
                    || {
                        let mut parts: Vec<&str> =
                            dir.split('/').filter(|p| !p.is_empty()).collect();
                        for part in target.split('/') {
                            match part {
                                "." => {}
                                ".." => {
                                    parts.pop();
                                }
                                p => parts.push(p),
                            }
                        }
                        parts.join("/")
                    },
                    |rest| format!("vendor/three/addons/{rest}"),
                );
                assert!(
                    ASSETS.iter().any(|(n, _, _)| *n == target),
                    "{name} imports {target}"
                );
            }
        }
        assert_eq!(asset("nope").status(), StatusCode::NOT_FOUND);
    }
}
