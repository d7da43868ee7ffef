//! Who is calling: the team behind a bearer token, or the one local user in open mode.
//!
//! Invariants:
//! - Tokens are compared as BLAKE3 hashes in constant time against every configured token (no
//!   early exit), so response time does not depend on how much of a token was right.
//! - No or unknown token → 401 with `WWW-Authenticate: Bearer`. What a team may see is decided by
//!   the store and the job queue, which report other teams' objects as absent (404).

use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use subtle::ConstantTimeEq;

use super::error::ApiFailure;
use super::AppState;
use crate::service::config::LOCAL_TEAM;

/// The calling team's name.
#[derive(Clone, Debug)]
pub struct Caller(pub String);

/// 401 with the challenge header.
pub struct Unauthorized(&'static str);

impl IntoResponse for Unauthorized {
    fn into_response(self) -> Response {
        let mut response = ApiFailure::new(StatusCode::UNAUTHORIZED, self.0).into_response();
        response.headers_mut().insert(
            header::WWW_AUTHENTICATE,
            HeaderValue::from_static("Bearer realm=\"lightfarm\""),
        );
        response
    }
}

/// The team whose token hash equals `presented`'s, checked against every token.
pub fn team_for_token<'a>(
    teams: &'a [crate::service::config::Team],
    presented: &str,
) -> Option<&'a str> {
    let hash = blake3::hash(presented.as_bytes());
    let mut found: Option<&str> = None;
    for team in teams {
        for stored in &team.token_hashes {
            if bool::from(stored.ct_eq(hash.as_bytes())) {
                found = Some(&team.name);
            }
        }
    }
    found
}

impl FromRequestParts<AppState> for Caller {
    type Rejection = Unauthorized;

    async fn from_request_parts(
        parts: &mut Parts,
        state: &AppState,
    ) -> Result<Caller, Unauthorized> {
        if state.config.is_open() {
            return Ok(Caller(LOCAL_TEAM.to_string()));
        }
        let value = parts
            .headers
            .get(header::AUTHORIZATION)
            .ok_or(Unauthorized(
                "missing bearer token (Authorization: Bearer <token>)",
            ))?;
        let token = value
            .to_str()
            .ok()
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(str::trim)
            .ok_or(Unauthorized("Authorization must be `Bearer <token>`"))?;
        team_for_token(&state.config.teams, token)
            .map(|team| Caller(team.to_string()))
            .ok_or(Unauthorized("unknown token"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::config::ServiceConfig;

    #[test]
    fn finds_the_team_of_a_token() {
        let c = ServiceConfig::from_toml(
            "[[teams]]\nname = \"a\"\ntoken = \"ta\"\n[[teams]]\nname = \"b\"\ntokens = [\"tb\", \"tb2\"]",
        )
        .unwrap();
        assert_eq!(team_for_token(&c.teams, "ta"), Some("a"));
        assert_eq!(team_for_token(&c.teams, "tb2"), Some("b"));
        assert_eq!(team_for_token(&c.teams, "t"), None);
        assert_eq!(team_for_token(&c.teams, ""), None);
    }
}
