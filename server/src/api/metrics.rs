//! `/metrics`: the farm's counters and gauges in Prometheus' text format.

use std::collections::HashMap;
use std::sync::atomic::Ordering;

use axum::extract::State;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};

use super::{ApiResult, AppState, off_thread};
use crate::scheduler::WorkerState;
use tessera::protocol::ApiError;

#[utoipa::path(get, path = "/metrics", tag = "server", security((), ("api_token" = [])),
    responses(
        (status = 200, description = "Prometheus text format: jobs by state, tiles, lease expiries, refused results, workers by state, render seconds", content_type = "text/plain", body = String),
        (status = 401, description = "The server has an API token and was started without --public-metrics: send it", body = ApiError)))]
pub(super) async fn metrics(State(state): State<AppState>) -> ApiResult<Response> {
    let (store_metrics, workers) = {
        let state = state.clone();
        // The workers the list shows: forgotten ones are not counted as lost for ever.
        let since = crate::db::now() - state.settings.forget_workers_after;
        off_thread(move || Ok((state.store.metrics()?, state.store.workers_seen_since(since)?))).await?
    };
    let crate::db::StoreMetrics {
        jobs_by_state: states,
        tiles_done,
        render_seconds_sum: render_sum,
        render_seconds_count: render_count,
    } = store_metrics;
    let t = crate::db::now();
    let mut by_state: HashMap<WorkerState, i64> = HashMap::new();
    for w in &workers {
        *by_state.entry(state.scheduler.worker_state(w, t)).or_default() += 1;
    }
    let mut out = String::new();
    out += "# HELP tessera_jobs Jobs by state.\n# TYPE tessera_jobs gauge\n";
    for s in ["queued", "running", "paused", "done", "failed", "canceled"] {
        let n = states.iter().find(|(k, _)| k == s).map_or(0, |(_, n)| *n);
        out += &format!("tessera_jobs{{state=\"{s}\"}} {n}\n");
    }
    out += "# HELP tessera_tiles_done_total Tiles rendered and accepted.\n# TYPE tessera_tiles_done_total counter\n";
    out += &format!("tessera_tiles_done_total {tiles_done}\n");
    out += "# HELP tessera_lease_expiries_total Leases that expired and went back to the queue.\n# TYPE tessera_lease_expiries_total counter\n";
    out += &format!(
        "tessera_lease_expiries_total {}\n",
        state.scheduler.counters().lease_expiries.load(Ordering::Relaxed)
    );
    out += "# HELP tessera_results_refused_total Tile results refused (expired or revoked leases).\n# TYPE tessera_results_refused_total counter\n";
    out += &format!(
        "tessera_results_refused_total {}\n",
        state.scheduler.counters().results_refused.load(Ordering::Relaxed)
    );
    out += "# HELP tessera_workers Registered workers by state.\n# TYPE tessera_workers gauge\n";
    for s in WorkerState::ALL {
        let n = by_state.get(&s).copied().unwrap_or(0);
        out += &format!("tessera_workers{{state=\"{}\"}} {n}\n", s.as_str());
    }
    out += "# HELP tessera_tile_render_seconds Time workers spent rendering tiles.\n# TYPE tessera_tile_render_seconds summary\n";
    out += &format!(
        "tessera_tile_render_seconds_sum {render_sum}\ntessera_tile_render_seconds_count {render_count}\n"
    );
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("text/plain; version=0.0.4"))], out).into_response())
}
