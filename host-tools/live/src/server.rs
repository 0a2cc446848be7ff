//! The web side: the page, its assets (bundled into the binary: the rig
//! may be offline), and the view's updates as server-sent events. Each
//! page gets the whole view when it opens, then what changed; any number
//! of pages see the same.

use std::convert::Infallible;
use std::sync::Arc;

use anyhow::{Context, Result};
use axum::extract::rejection::JsonRejection;
use axum::extract::{Json, Path, State};
use axum::http::{header, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::{Stream, StreamExt};

use needle_analysis::page;

use crate::commands::{Answer, Request};
use crate::{Asked, NotAsked, Shared};

const INDEX: &str = include_str!("../assets/index.html");

/// The page's files: name, type, contents; all but the live view's own
/// are every page's (`needle_analysis::page`).
const ASSETS: [(&str, &str, &str); 7] = [
    (
        "app.js",
        "text/javascript",
        include_str!("../assets/app.js"),
    ),
    ("live.css", "text/css", include_str!("../assets/live.css")),
    ("page.css", "text/css", page::STYLE_CSS),
    ("charts.js", "text/javascript", page::CHARTS_JS),
    ("uPlot.iife.min.js", "text/javascript", page::UPLOT_JS),
    ("uPlot.min.css", "text/css", page::UPLOT_CSS),
    ("uPlot-LICENSE", "text/plain", page::UPLOT_LICENSE),
];

/// Serve the live view on `listener` until the process stops.
pub async fn serve(listener: tokio::net::TcpListener, shared: Arc<Shared>) -> Result<()> {
    axum::serve(listener, router(shared))
        .await
        .context("the web server stopped")
}

/// The routes: `/` (the page), `/assets/NAME`, `/events` (the updates),
/// `POST /command` (a [`Request`] as JSON; the [`Answer`] as JSON).
pub fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/", get(|| async { Html(INDEX) }))
        .route("/assets/{name}", get(asset))
        .route("/events", get(events))
        .route("/command", post(command))
        .fallback(|| async { not_found("no such page: the live view is at /") })
        .with_state(shared)
}

async fn asset(Path(name): Path<String>) -> Response {
    match ASSETS.iter().find(|(file, _, _)| *file == name) {
        Some((_, kind, body)) => ([(header::CONTENT_TYPE, *kind)], *body).into_response(),
        None => not_found(&format!("no asset named {name:?}")),
    }
}

fn not_found(why: &str) -> Response {
    (StatusCode::NOT_FOUND, why.to_string()).into_response()
}

async fn command(
    State(shared): State<Arc<Shared>>,
    request: Result<Json<Request>, JsonRejection>,
) -> (StatusCode, Json<Answer>) {
    let Json(request) = match request {
        Ok(request) => request,
        // 400 for JSON that is no command, 415 for a body that is not
        // JSON, 413 for one over axum's 2 MB: each with what was wrong.
        Err(e) => {
            return (
                e.status(),
                Json(Answer::not(
                    "the request",
                    format!("not a command: {}", e.body_text()),
                )),
            )
        }
    };
    let what = request.what();
    let job = match request.job() {
        Ok(job) => job,
        Err(e) => return bad(Answer::not(&what, format!("{e:#}"))),
    };
    let (answer, answered) = tokio::sync::oneshot::channel();
    let unavailable = |why: &str| {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            Json(Answer::not(&what, why)),
        )
    };
    let asked = Asked {
        job,
        what: what.clone(),
        answer,
    };
    match shared.ask(asked) {
        Ok(()) => {}
        Err(NotAsked::Busy) => {
            return unavailable("the device is busy with earlier commands: ask again")
        }
        Err(NotAsked::Gone) => return unavailable("the device is gone"),
    }
    match answered.await {
        Ok(answer) => (StatusCode::OK, Json(answer)),
        Err(_) => unavailable("the device is gone"),
    }
}

fn bad(answer: Answer) -> (StatusCode, Json<Answer>) {
    (StatusCode::BAD_REQUEST, Json(answer))
}

async fn events(
    State(shared): State<Arc<Shared>>,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let (snapshot, updates) = shared.subscribe();
    let first = tokio_stream::once(Ok(Event::default().event("snapshot").data(snapshot)));
    let rest = BroadcastStream::new(updates).map(|update| {
        Ok(match update {
            Ok(json) => Event::default().event("update").data(&*json),
            // Fell behind by more than the channel holds: the page starts
            // afresh from a new snapshot.
            Err(_) => Event::default().event("lagged").data("{}"),
        })
    });
    Sse::new(first.chain(rest)).keep_alive(KeepAlive::default())
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::body::Body;
    use axum::http::Request as HttpRequest;
    use tower::ServiceExt;

    /// The status and the answer's words for a `POST /command` of `body`
    /// as `content_type`, with no device behind the server.
    async fn command_answer(content_type: &str, body: Vec<u8>) -> (StatusCode, String) {
        let (shared, _asked) = Shared::new("test");
        let request = HttpRequest::post("/command")
            .header(header::CONTENT_TYPE, content_type)
            .body(Body::from(body))
            .unwrap();
        let response = router(shared).oneshot(request).await.unwrap();
        let status = response.status();
        let bytes = axum::body::to_bytes(response.into_body(), 1 << 16)
            .await
            .unwrap();
        (status, String::from_utf8_lossy(&bytes).into_owned())
    }

    #[tokio::test]
    async fn a_request_that_is_no_command_is_told_what_was_wrong_with_its_status() {
        let tare = br#"{"command":"tare"}"#.to_vec();
        let (status, said) = command_answer("text/plain", tare).await;
        assert_eq!(status, StatusCode::UNSUPPORTED_MEDIA_TYPE, "{said}");
        assert!(
            said.contains("not a command") && said.contains("application/json"),
            "{said}"
        );

        let mut huge =
            br#"{"command":"upload","file_name":"big.toml","entry":null,"toml":""#.to_vec();
        huge.resize(3 << 20, b'#');
        huge.extend_from_slice(br#""}"#);
        let (status, said) = command_answer("application/json", huge).await;
        assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE, "{said}");
        assert!(said.contains("not a command"), "{said}");

        let (status, said) = command_answer("application/json", b"{not json".to_vec()).await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{said}");
    }
}
