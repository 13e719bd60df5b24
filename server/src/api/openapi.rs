//! The OpenAPI 3.1 description of the HTTP API, served at `GET /api/v1/openapi.json`.
//!
//! Nothing here lists routes: each handler carries its operation (`#[utoipa::path]`: path,
//! method, parameters, answers), the router is built from those attributes (`routes!` in
//! [`super::routes`]), and the schemas are the protocol types' own (`tessera::protocol`, whose
//! `ToSchema` derives the server enables with common's `openapi` feature). What is left for this
//! file is the document's frame: title, version, tags, the two bearer tokens and the worker secret.

use std::sync::Arc;

use axum::Extension;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use utoipa::openapi::security::{ApiKey, ApiKeyValue, HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi};

#[derive(OpenApi)]
#[openapi(
    info(
        title = "Tessera render farm",
        description = "The job API (submit scenes, follow and cancel jobs, download their frames, read their logs) \
                       and the worker protocol (lease tiles, renew, upload or fail them). Every error answer, \
                       whatever its status, is an ApiError as JSON.",
        license(name = "MIT OR Apache-2.0"),
    ),
    tags(
        (name = "jobs", description = "The job API: needs the API token when the server has one (`Authorization: Bearer`, or `?access_token=` where headers cannot be sent)"),
        (name = "status", description = "What the status page follows"),
        (name = "worker", description = "The worker protocol: every request needs the worker token, and every request after registration the worker's secret"),
        (name = "server", description = "Health, metrics, the status page and this description"),
    ),
    modifiers(&Tokens),
)]
pub(super) struct ApiDoc;

/// The two bearer tokens as security schemes.
struct Tokens;

impl Modify for Tokens {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        for (name, what) in [
            ("api_token", "The server's --api-token (TESSERA_API_TOKEN); not needed when it has none"),
            ("worker_token", "The server's --worker-token (TESSERA_WORKER_TOKEN)"),
        ] {
            components.add_security_scheme(
                name,
                SecurityScheme::Http(
                    HttpBuilder::new().scheme(HttpAuthScheme::Bearer).description(Some(what)).build(),
                ),
            );
        }
        components.add_security_scheme(
            "worker_secret",
            SecurityScheme::ApiKey(ApiKey::Header(ApiKeyValue::with_description(
                tessera::protocol::WORKER_SECRET_HEADER,
                "The worker_secret that registration answered: proves which registered worker calls",
            ))),
        );
        openapi.info.version = env!("CARGO_PKG_VERSION").to_string();
    }
}

/// The description as JSON, made once when the router is built.
#[derive(Clone)]
pub(super) struct Spec(Arc<String>);

impl Spec {
    pub(super) fn new(spec: utoipa::openapi::OpenApi) -> Spec {
        Spec(Arc::new(spec.to_pretty_json().unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))))
    }
}

#[utoipa::path(get, path = "/api/v1/openapi.json", tag = "server",
    responses((status = 200, description = "This description (OpenAPI 3.1)", content_type = "application/json", body = Object)))]
pub(super) async fn openapi_json(Extension(spec): Extension<Spec>) -> Response {
    ([(header::CONTENT_TYPE, HeaderValue::from_static("application/json"))], spec.0.as_str().to_owned())
        .into_response()
}

/// Bytes that are not JSON (pictures, tiles, bundles), for the description only.
#[derive(utoipa::ToSchema)]
#[schema(value_type = String, format = Binary)]
#[allow(dead_code)]
pub(super) struct Binary(Vec<u8>);
