//! `POST /api/edit`: an upload received at a minimum rate, admitted by the memory its photos
//! will need, checked as `matedit edit` checks its inputs, and queued. Each step refuses with
//! its own status and message; nothing is left on disk for a refused upload.

use super::form::{self, Fields};
use super::jobs::Job;
use super::{App, error, from_the_page, rate, upload};
use axum::extract::Multipart;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use tokio::sync::OwnedSemaphorePermit;
use tokio::time::Instant;

/// The route: each step below either hands on what the next needs or is the answer.
pub(super) async fn submit(
    axum::extract::State(app): axum::extract::State<Arc<App>>,
    request: axum::extract::Request,
) -> Response {
    if let Some(r) = from_the_page(request.headers()) {
        return r;
    }
    if let Err(full) = app.queue.has_room() {
        return error(StatusCode::SERVICE_UNAVAILABLE, full.to_string());
    }
    // The whole upload, its admission included, has one deadline.
    let deadline = Instant::now() + app.upload_deadline;
    let held = rate::Held::default();
    let fields = match receive(&app, request, deadline, &held).await {
        Ok(f) => f,
        Err(r) => return r,
    };
    let reservation = match reserve(&app, &fields, deadline).await {
        Ok(r) => r,
        Err(r) => return r,
    };
    check_and_queue(app, fields, held, reservation).await
}

/// The form's fields, read whole. No turns: an upload is admitted by the memory its bytes take
/// as they arrive and read at a minimum rate ([`rate`]), so clients that stall cost a
/// connection each for a few seconds and delay nobody.
async fn receive(
    app: &App,
    request: axum::extract::Request,
    deadline: Instant,
    held: &rate::Held,
) -> Result<Fields, Response> {
    use axum::extract::FromRequest as _;
    let (parts, body) = request.into_parts();
    let body = rate::limited(body, app.min_rate, app.receiving.clone(), held.clone());
    let mp = Multipart::from_request(axum::extract::Request::from_parts(parts, body), &())
        .await
        .map_err(IntoResponse::into_response)?;
    let read = tokio::time::timeout_at(deadline, form::read_fields(mp)).await;
    let slow = |why: String| {
        error(
            StatusCode::REQUEST_TIMEOUT,
            format!("{why}; try again (or on a faster connection)"),
        )
    };
    match read {
        _ if held.too_slow() => Err(slow(format!(
            "the upload arrived slower than {:.0} KiB/s after its first {} s, so it was closed",
            app.min_rate.bytes_per_second / 1024.0,
            app.min_rate.grace.as_secs()
        ))),
        Ok(fields) => fields,
        Err(_) => Err(slow(format!(
            "the upload did not arrive whole within {} s",
            app.upload_deadline.as_secs()
        ))),
    }
}

/// The memory the edit will need, reserved until it ends: told by the photos' headers before
/// anything is decoded. Masks and normal maps count as photos do (an upper bound): they are
/// decoded at the photo's size before the edit starts.
async fn reserve(app: &App, fields: &Fields, deadline: Instant) -> Result<OwnedSemaphorePermit, Response> {
    let need = upload::memory_mb(
        ["photo", "source", "mask", "source_mask", "normals"]
            .iter()
            .filter_map(|role| fields.files.get(role).map(|p| p.bytes.as_ref())),
        app.max_pixels,
    );
    if need > app.max_memory_mb {
        return Err(error(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!(
                "editing these photos needs about {need} MB of memory, more than this server allows ({} MB); send a smaller photo",
                app.max_memory_mb
            ),
        ));
    }
    match tokio::time::timeout_at(deadline, app.memory.clone().acquire_many_owned(need as u32)).await {
        Ok(Ok(r)) => Ok(r),
        Ok(Err(_)) => Err(error(StatusCode::SERVICE_UNAVAILABLE, "the server is stopping")),
        Err(_) => Err(error(
            StatusCode::SERVICE_UNAVAILABLE,
            "the edits in progress use the memory this server allows; try again in a minute",
        )),
    }
}

/// The uploads saved and checked ([`form::prepare`]) and the job queued, or the reason not.
/// Checking and queueing finish even if the client goes away meanwhile: the permit and the
/// clean-up live in the blocking task, not in this future.
async fn check_and_queue(
    app: Arc<App>,
    fields: Fields,
    held: rate::Held,
    reservation: OwnedSemaphorePermit,
) -> Response {
    let Ok(permit) = app.checking.clone().acquire_owned().await else {
        return error(StatusCode::SERVICE_UNAVAILABLE, "the server is stopping");
    };
    let id = app.job_id();
    let done = tokio::task::spawn_blocking(move || {
        let _permit = permit;
        let dir = app.work.join(&id);
        let prepared = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| form::prepare(&app, &dir, fields)));
        // The uploads are on disk (or refused): their bytes no longer count against the budget.
        held.release();
        let answer = match prepared {
            Ok(Ok((work, names))) => match app
                .queue
                .submit(Job::new(id.clone(), dir.clone(), work, names).holding(reservation))
            {
                Ok((_, place)) => Ok((id.clone(), place)),
                Err(full) => Err((StatusCode::SERVICE_UNAVAILABLE, full.to_string())),
            },
            Ok(Err(e)) => Err((StatusCode::UNPROCESSABLE_ENTITY, app.scrub(&format!("{e:#}"), &dir))),
            Err(_) => Err((
                StatusCode::UNPROCESSABLE_ENTITY,
                "the upload could not be read (its decoder failed)".to_string(),
            )),
        };
        if answer.is_err() {
            let _ = std::fs::remove_dir_all(&dir);
        }
        answer
    })
    .await;
    match done {
        Ok(Ok((id, place))) => (
            StatusCode::ACCEPTED,
            axum::Json(json!({ "id": id, "place": place, "url": format!("/api/jobs/{id}") })),
        )
            .into_response(),
        Ok(Err((status, msg))) => error(status, msg),
        Err(_) => error(StatusCode::INTERNAL_SERVER_ERROR, "the upload could not be checked"),
    }
}

impl App {
    /// A job's id: the server's secret key over a counter, so ids neither repeat nor can be
    /// guessed from one another.
    fn job_id(&self) -> String {
        let n = self.counter.fetch_add(1, Ordering::Relaxed);
        let mut h = blake3::Hasher::new_keyed(&self.secret);
        h.update(&n.to_le_bytes());
        h.finalize().to_hex()[..24].to_string()
    }
}
