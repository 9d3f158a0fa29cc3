//! The HTTP API (axum) under `/v1`, plus `/healthz`, `/readyz`, `/metrics` and the OpenAPI
//! document. Every error has one JSON shape, `{"error": {"code", "message"}}`.

use std::sync::Arc;
use std::time::Instant;

use axum::body::Bytes;
use axum::extract::{
    ConnectInfo, DefaultBodyLimit, FromRequest, Multipart, Path, RawQuery, Request, State,
};
use axum::http::{header, HeaderMap, Method, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Extension, Json, Router};
use serde_json::json;

use super::audit::{self, Action, Peer};
use super::auth::Owner;
use super::codec::ResultMessage;
use super::error::ApiError;
use super::registry::{requested_session_id, SessionInfo, SESSION_HEADER};
use super::result_codec::{encode_binary_result, ResultFormat};
use super::service::AppState;
use super::upload::{check_file_name, CreateSessionJson, SceneUpload};
use crate::scene::SceneFormat;

/// Every route: method and path (axum syntax), as the OpenAPI document must list them.
pub const ROUTES: &[(&str, &str)] = &[
    ("GET", "/healthz"),
    ("GET", "/readyz"),
    ("GET", "/metrics"),
    ("GET", "/v1/openapi.json"),
    ("POST", "/v1/sessions"),
    ("GET", "/v1/sessions"),
    ("GET", "/v1/sessions/{id}"),
    ("DELETE", "/v1/sessions/{id}"),
    ("POST", "/v1/sessions/{id}/reset"),
    ("POST", "/v1/sessions/{id}/frames"),
    ("GET", "/v1/sessions/{id}/stream"),
];

type ApiResult<T> = Result<T, ApiError>;

/// The router of the HTTP API.
pub(crate) fn router(state: Arc<AppState>) -> Router {
    let limit = state.config.limits.max_body_bytes;
    let authed = Router::new()
        .route("/v1/sessions", post(create_session).get(list_sessions))
        .route("/v1/sessions/{id}", get(get_session).delete(delete_session))
        .route("/v1/sessions/{id}/reset", post(reset_session))
        .route("/v1/sessions/{id}/frames", post(submit_frame))
        .route("/v1/sessions/{id}/stream", get(super::ws::stream))
        .layer(middleware::from_fn_with_state(state.clone(), body_deadline))
        .layer(middleware::from_fn_with_state(state.clone(), require_token));
    let metrics = if state.config.metrics_require_token {
        Router::new()
            .route("/metrics", get(metrics))
            .layer(middleware::from_fn_with_state(state.clone(), require_token))
    } else {
        Router::new().route("/metrics", get(metrics))
    };
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/v1/openapi.json", get(openapi))
        .merge(metrics)
        .merge(authed)
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(DefaultBodyLimit::max(limit))
        .layer(middleware::from_fn(log_request))
        .with_state(state)
}

async fn log_request(req: Request, next: Next) -> Response {
    let t = Instant::now();
    let method = req.method().clone();
    let path = req.uri().path().to_string();
    let r = next.run(req).await;
    let status = r.status().as_u16();
    let ms = t.elapsed().as_secs_f64() * 1e3;
    if status >= 500 {
        tracing::warn!(%method, path, status, ms, "http");
    } else {
        tracing::debug!(%method, path, status, ms, "http");
    }
    r
}

/// Reads a request's whole body (at most `limits.max_body_bytes`) within
/// `limits.body_timeout_s`: a client that sends its body too slowly gets 408
/// `request_timeout` and holds nothing longer. Requests without a body pass untouched.
async fn body_deadline(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    let has_body = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .is_some_and(|v| v.as_bytes() != b"0")
        || req.headers().contains_key(header::TRANSFER_ENCODING);
    if !has_body {
        return next.run(req).await;
    }
    let limits = &state.config.limits;
    let (parts, body) = req.into_parts();
    let deadline = std::time::Duration::from_secs_f64(limits.body_timeout_s);
    let read = axum::body::to_bytes(body, limits.max_body_bytes);
    match tokio::time::timeout(deadline, read).await {
        Ok(Ok(bytes)) => {
            next.run(Request::from_parts(parts, axum::body::Body::from(bytes)))
                .await
        }
        Ok(Err(e)) => {
            // `to_bytes` fails on the length limit ("length limit exceeded") or a broken
            // connection.
            let too_large = e.to_string().contains("length limit");
            let err = if too_large {
                body_too_large(limits.max_body_bytes)
            } else {
                ApiError::bad_request(format!("cannot read the request body: {e}"))
            };
            state.count(err).into_response()
        }
        Err(_) => state
            .count(ApiError::new(
                StatusCode::REQUEST_TIMEOUT,
                "request_timeout",
                format!(
                    "the request body did not arrive within {} s (limits.body_timeout_s)",
                    limits.body_timeout_s
                ),
            ))
            .into_response(),
    }
}

async fn require_token(
    State(state): State<Arc<AppState>>,
    mut req: Request,
    next: Next,
) -> Response {
    let header = req
        .headers()
        .get(header::AUTHORIZATION)
        .map(|v| v.as_bytes());
    let peer = request_peer(&req);
    match state.auth.authenticate(header) {
        Ok(owner) => {
            req.extensions_mut().insert(owner);
            req.extensions_mut().insert(peer);
            next.run(req).await
        }
        Err(e) => {
            audit::event(
                Action::Authenticate,
                e.code,
                peer,
                None,
                None,
                &format!("{} {}: {}", req.method(), req.uri().path(), e.message),
            );
            state.count(e).into_response()
        }
    }
}

/// The client's address of `req` (axum's connection info; unknown when the router is served
/// without it).
fn request_peer(req: &Request) -> Peer {
    req.extensions()
        .get::<ConnectInfo<Peer>>()
        .map_or(Peer(None), |c| c.0)
}

async fn healthz() -> Json<serde_json::Value> {
    Json(json!({"status": "ok"}))
}

async fn readyz(State(state): State<Arc<AppState>>) -> Response {
    if state.is_draining() {
        ApiError::shutting_down().into_response()
    } else {
        Json(json!({"status": "ready", "sessions": state.registry.len()})).into_response()
    }
}

async fn metrics(State(state): State<Arc<AppState>>) -> Response {
    let mut text = state.metrics.render();
    // The load a horizontal autoscaler should follow: registration slots in use.
    let slots = state.config.worker_threads;
    let busy = slots.saturating_sub(state.slots.free());
    text.push_str(&format!(
        "# HELP livereg_registration_slots Registration slots (worker_threads).\n# TYPE livereg_registration_slots gauge\nlivereg_registration_slots {slots}\n\
         # HELP livereg_registration_slots_busy Registration slots registering a frame now.\n# TYPE livereg_registration_slots_busy gauge\nlivereg_registration_slots_busy {busy}\n\
         # HELP livereg_registration_waiting Sessions with a frame waiting for a slot.\n# TYPE livereg_registration_waiting gauge\nlivereg_registration_waiting {}\n\
         # HELP livereg_draining 1 while the server drains (refuses new work before it stops).\n# TYPE livereg_draining gauge\nlivereg_draining {}\n\
         # HELP livereg_memory_budget_bytes Memory the open sessions' estimates may hold together (limits.max_memory_mb).\n# TYPE livereg_memory_budget_bytes gauge\nlivereg_memory_budget_bytes {}\n\
         # HELP livereg_memory_estimated_bytes Estimated memory of the open sessions and those being created.\n# TYPE livereg_memory_estimated_bytes gauge\nlivereg_memory_estimated_bytes {}\n",
        state.slots.waiting(),
        u8::from(state.is_draining()),
        // (no budget known: reported as 0 = none, rather than 2^64 - 1)
        match state.registry.memory_budget() {
            u64::MAX => 0,
            b => b,
        },
        state.registry.memory_in_use()
    ));
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text).into_response()
}

async fn openapi() -> Json<serde_json::Value> {
    Json(super::openapi::document())
}

async fn not_found(method: Method, uri: axum::http::Uri) -> ApiError {
    ApiError::not_found(format!("no route {method} {}", uri.path()))
}

async fn method_not_allowed(method: Method, uri: axum::http::Uri) -> ApiError {
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        "method_not_allowed",
        format!("{} does not accept {method}", uri.path()),
    )
}

fn content_type(headers: &HeaderMap) -> String {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// 413 `payload_too_large` for a request body over `limit` bytes.
fn body_too_large(limit: usize) -> ApiError {
    ApiError::too_large(
        "payload_too_large",
        format!("the request body exceeds {limit} bytes (limits.max_body_bytes)"),
    )
}

fn body_error(e: axum::extract::rejection::BytesRejection, limit: usize) -> ApiError {
    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
        body_too_large(limit)
    } else {
        ApiError::bad_request(format!("cannot read the request body: {e}"))
    }
}

async fn read_multipart(mut mp: Multipart, limit: usize) -> ApiResult<SceneUpload> {
    let mut up = SceneUpload::default();
    let mut scene = None;
    let field_err = |e: axum::extract::multipart::MultipartError| {
        if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::too_large(
                "payload_too_large",
                format!("the upload exceeds {limit} bytes (limits.max_body_bytes)"),
            )
        } else {
            ApiError::bad_request(format!("malformed multipart body: {}", e.body_text()))
        }
    };
    while let Some(field) = mp.next_field().await.map_err(field_err)? {
        let name = field.name().unwrap_or("").to_string();
        let file_name = field.file_name().map(str::to_string);
        let ctype = field.content_type().unwrap_or("").to_ascii_lowercase();
        let bytes = field.bytes().await.map_err(field_err)?;
        let text = || {
            String::from_utf8(bytes.to_vec())
                .map_err(|_| ApiError::bad_request(format!("part `{name}` is not UTF-8 text")))
        };
        match name.as_str() {
            "scene" => {
                let json = ctype.contains("json")
                    || file_name
                        .as_deref()
                        .is_some_and(|f| f.to_ascii_lowercase().ends_with(".json"));
                up.format = Some(if json {
                    SceneFormat::Json
                } else {
                    SceneFormat::Toml
                });
                scene = Some(text()?);
            }
            "budget_ms" => {
                let t = text()?;
                up.budget_ms = Some(t.trim().parse().map_err(|_| {
                    ApiError::bad_request(format!("budget_ms must be a number, got {t:?}"))
                })?);
            }
            "rigid_only" => {
                let t = text()?;
                up.rigid_only = match t.trim() {
                    "true" | "1" => true,
                    "false" | "0" => false,
                    _ => {
                        return Err(ApiError::bad_request(format!(
                            "rigid_only must be true or false, got {t:?}"
                        )))
                    }
                };
            }
            _ => {
                let Some(f) = file_name else {
                    return Err(ApiError::bad_request(format!(
                        "multipart part `{name}` has no file name (expected `scene`, `budget_ms`, `rigid_only`, or files with a filename)"
                    )));
                };
                check_file_name(&f)?;
                if up.files.insert(f.clone(), bytes.to_vec()).is_some() {
                    return Err(ApiError::invalid_scene(format!(
                        "file `{f}` is given twice"
                    )));
                }
            }
        }
    }
    up.scene = scene.ok_or_else(|| {
        ApiError::bad_request("the multipart upload has no `scene` part (the scene file)")
    })?;
    Ok(up)
}

async fn create_session(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
    Extension(peer): Extension<Peer>,
    req: Request,
) -> ApiResult<(StatusCode, Json<SessionInfo>)> {
    let r = create_session_from(&state, &owner, req).await;
    audit::event(
        Action::CreateSession,
        audit::outcome(&r),
        peer,
        Some(owner.name()),
        r.as_ref().ok().map(|(_, i)| i.id.as_str()),
        r.as_ref().err().map_or("http", |e| e.message.as_str()),
    );
    r
}

async fn create_session_from(
    state: &Arc<AppState>,
    owner: &Owner,
    req: Request,
) -> ApiResult<(StatusCode, Json<SessionInfo>)> {
    let limit = state.config.limits.max_body_bytes;
    let requested = requested_session_id(req.headers().get(SESSION_HEADER).map(|v| v.as_bytes()))?;
    let ctype = content_type(req.headers());
    let upload = if ctype.starts_with("multipart/form-data") {
        let mp = Multipart::from_request(req, state)
            .await
            .map_err(|e| state.count(ApiError::bad_request(format!("multipart: {e}"))))?;
        read_multipart(mp, limit)
            .await
            .map_err(|e| state.count(e))?
    } else if ctype.starts_with("application/json") || ctype.is_empty() {
        let body = Bytes::from_request(req, state)
            .await
            .map_err(|e| state.count(body_error(e, limit)))?;
        let c: CreateSessionJson = serde_json::from_slice(&body).map_err(|e| {
            state.count(ApiError::bad_request(format!(
                "malformed session request: {e}"
            )))
        })?;
        c.into_upload().map_err(|e| state.count(e))?
    } else {
        return Err(state.count(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported_media_type",
            format!("Content-Type {ctype:?}: send application/json (inline scene) or multipart/form-data (scene files)"),
        )));
    };
    let info = state
        .create_session(owner, upload, requested.as_deref())
        .await
        .map_err(|e| state.count(e))?;
    Ok((StatusCode::CREATED, Json(info)))
}

async fn list_sessions(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
) -> Json<serde_json::Value> {
    let list: Vec<SessionInfo> = state
        .registry
        .list(&owner)
        .iter()
        .map(|h| SessionInfo::of(h))
        .collect();
    Json(json!({ "sessions": list }))
}

async fn get_session(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> ApiResult<Json<SessionInfo>> {
    let h = state.session(&owner, &id).map_err(|e| state.count(e))?;
    Ok(Json(SessionInfo::of(&h)))
}

async fn delete_session(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
    Extension(peer): Extension<Peer>,
    Path(id): Path<String>,
) -> ApiResult<Json<SessionInfo>> {
    let r = state.close_session(&owner, &id);
    audit::event(
        Action::CloseSession,
        audit::outcome(&r),
        peer,
        Some(owner.name()),
        Some(&id),
        "http",
    );
    r.map(Json).map_err(|e| state.count(e))
}

async fn reset_session(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
    Extension(peer): Extension<Peer>,
    Path(id): Path<String>,
) -> ApiResult<Json<SessionInfo>> {
    let r = state.session(&owner, &id);
    audit::event(
        Action::ResetSession,
        audit::outcome(&r),
        peer,
        Some(owner.name()),
        Some(&id),
        "http",
    );
    let h = r.map_err(|e| state.count(e))?;
    h.request_reset();
    Ok(Json(SessionInfo::of(&h)))
}

/// `POST /v1/sessions/{id}/frames[?results=json|binary]`: registers one frame and answers
/// with its result, as JSON or (`results=binary`) in the binary result encoding
/// (`application/octet-stream`, [`super::result_codec`]).
async fn submit_frame(
    State(state): State<Arc<AppState>>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
    body: Result<Bytes, axum::extract::rejection::BytesRejection>,
) -> ApiResult<Response> {
    let limits = &state.config.limits;
    // Unknown sessions are answered before the body is looked at.
    let h = state.session(&owner, &id).map_err(|e| state.count(e))?;
    let format = ResultFormat::from_query(query.as_deref()).map_err(|e| state.count(e))?;
    let body = body.map_err(|e| state.count(body_error(e, limits.max_body_bytes)))?;
    let binary = content_type(&headers).starts_with("application/octet-stream");
    // The rate before the decode: a flood costs a counter, never a decode.
    state.admit_rate(&h).map_err(|e| state.count(e))?;
    let incoming = state
        .decode(&h, body, binary)
        .await
        .map_err(|e| state.count(e))?;
    let (h, done) = state
        .register_once(&owner, &id, incoming)
        .await
        .map_err(|e| state.count(e))?;
    let msg = ResultMessage::new(
        done.seq,
        done.skipped,
        done.server_ms,
        done.queue_ms,
        &done.result,
        h.info.length_scale,
    );
    match format {
        ResultFormat::Json => Ok(Json(msg).into_response()),
        ResultFormat::Binary => {
            let bytes = encode_binary_result(&msg)
                .map_err(|e| state.count(ApiError::internal(format!("cannot encode: {e}"))))?;
            Ok(([(header::CONTENT_TYPE, "application/octet-stream")], bytes).into_response())
        }
    }
}
