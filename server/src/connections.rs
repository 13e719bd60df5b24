//! Accepting connections under limits: no client can take every file descriptor or hold a
//! connection that says nothing.
//!
//! The server accepts HTTP/1.1 connections itself (instead of `axum::serve`) so that it can:
//! - bound the connections open at once ([`ConnectionLimits::max_total`], below the process's
//!   descriptor limit, which [`raise_descriptor_limit`] lifts to its hard maximum at start-up)
//!   and those of one client address ([`ConnectionLimits::max_per_ip`]). A connection over
//!   either takes the place of the connection idle the longest (one with no request in
//!   progress: a kept-alive connection waiting for its next request, or one that has not sent
//!   a whole request head since it was accepted), of its own address or, at the total cap, of
//!   any: that one is closed and the newcomer served, so connections left open, silent or
//!   kept alive, cannot lock other clients out. With none idle, the new connection is accepted
//!   and closed at once, so the listen queue never fills and the server never runs out of
//!   descriptors for its database and files;
//! - close a connection whose request head does not arrive in
//!   [`ConnectionLimits::header_timeout`], and a kept-alive connection idle for as long (hyper's
//!   header-read timer, which runs while a connection waits for its next request);
//! - answer 408 and close a connection whose request body stops arriving: nothing for
//!   [`ConnectionLimits::body_timeout`] while the handler waits for it ([`TimeoutBody`]);
//! - stop gracefully: no new connections, each open one finishes its request and closes.

use std::collections::{BTreeSet, HashMap};
use std::convert::Infallible;
use std::future::Future;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderValue, Request, Response, StatusCode, header};
use hyper::body::{Frame, SizeHint};
use hyper_util::rt::{TokioIo, TokioTimer};
use tower::ServiceExt;

/// Descriptors kept for the server's own use (the database and its journal, blobs, outputs,
/// local workers' pipes, the listener) when the connection limit is derived from the
/// descriptor limit.
pub const RESERVED_DESCRIPTORS: u64 = 128;

/// Default most connections of one client address.
pub const DEFAULT_MAX_PER_IP: usize = 256;

/// Default time a client has to send a request head, and most time a kept-alive connection
/// may wait for its next request.
pub const DEFAULT_HEADER_TIMEOUT: Duration = Duration::from_secs(20);

/// Default longest pause in a request body while the server waits for it.
pub const DEFAULT_BODY_TIMEOUT: Duration = Duration::from_secs(60);

/// Most idle connections closed to make room that may still be closing: past it a new
/// connection over a cap is refused, so the connections open stay within a few of the caps.
const MAX_CLOSING: usize = 64;

#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    pub max_total: usize,
    pub max_per_ip: usize,
    pub header_timeout: Duration,
    pub body_timeout: Duration,
}

/// Raises the soft limit on open descriptors to the hard one (as Go's runtime and nginx's
/// `worker_rlimit_nofile` do) and returns the limit in force.
pub fn raise_descriptor_limit() -> u64 {
    #[cfg(unix)]
    {
        let mut lim = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
        // SAFETY: getrlimit and setrlimit only read and write the struct passed.
        unsafe {
            if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) != 0 {
                return 1024;
            }
            if lim.rlim_cur < lim.rlim_max {
                let raised = libc::rlimit { rlim_cur: lim.rlim_max, rlim_max: lim.rlim_max };
                if libc::setrlimit(libc::RLIMIT_NOFILE, &raised) == 0 {
                    lim.rlim_cur = lim.rlim_max;
                }
            }
        }
        #[allow(clippy::unnecessary_cast)] // rlim_t is not u64 on every unix
        let limit = lim.rlim_cur as u64;
        limit
    }
    #[cfg(not(unix))]
    {
        1024
    }
}

/// The connection limit for a process allowed `descriptors` open files: what is left after
/// [`RESERVED_DESCRIPTORS`], capped at `configured` when the operator set one. At least 16.
pub fn max_connections(descriptors: u64, configured: Option<usize>) -> usize {
    let room = descriptors.saturating_sub(RESERVED_DESCRIPTORS).max(16);
    let room = usize::try_from(room).unwrap_or(usize::MAX);
    configured.map_or(room, |c| c.min(room)).max(1)
}

/// One open connection as the accept loop sees it.
struct Conn {
    ip: IpAddr,
    /// Requests being answered: from the head read to the answer's last byte written.
    busy: usize,
    /// Since when it has had no request in progress: since it was accepted, or since its last
    /// answer was written (`None`: busy, or asked to close).
    idle_since: Option<Instant>,
    /// Asked to close to make room; it is not chosen again.
    closing: bool,
    close: Arc<tokio::sync::Notify>,
}

/// The open connections: counts in all and by client address, and the idle ones oldest first.
#[derive(Default)]
struct Open {
    total: usize,
    by_ip: HashMap<IpAddr, usize>,
    conns: HashMap<u64, Conn>,
    /// (idle since, connection) of every idle connection, and of each address's.
    idle: BTreeSet<(Instant, u64)>,
    idle_by_ip: HashMap<IpAddr, BTreeSet<(Instant, u64)>>,
    /// Connections asked to close that have not yet.
    closing: usize,
    next_id: u64,
}

impl Open {
    fn add(&mut self, ip: IpAddr) -> (u64, Arc<tokio::sync::Notify>) {
        let id = self.next_id;
        self.next_id += 1;
        self.total += 1;
        *self.by_ip.entry(ip).or_default() += 1;
        let close = Arc::new(tokio::sync::Notify::new());
        // Idle from the start: a connection that sends nothing (or never finishes its head)
        // may make room for a newcomer like one kept alive after its request.
        let now = Instant::now();
        self.conns
            .insert(id, Conn { ip, busy: 0, idle_since: Some(now), closing: false, close: close.clone() });
        self.idle.insert((now, id));
        self.idle_by_ip.entry(ip).or_default().insert((now, id));
        (id, close)
    }

    fn unmark_idle(&mut self, id: u64) {
        let Some(c) = self.conns.get_mut(&id) else { return };
        if let Some(since) = c.idle_since.take() {
            self.idle.remove(&(since, id));
            if let Some(set) = self.idle_by_ip.get_mut(&c.ip) {
                set.remove(&(since, id));
                if set.is_empty() {
                    self.idle_by_ip.remove(&c.ip);
                }
            }
        }
    }

    fn remove(&mut self, id: u64) {
        self.unmark_idle(id);
        let Some(c) = self.conns.remove(&id) else { return };
        self.total -= 1;
        if c.closing {
            self.closing -= 1;
        }
        if let Some(n) = self.by_ip.get_mut(&c.ip) {
            *n -= 1;
            if *n == 0 {
                self.by_ip.remove(&c.ip);
            }
        }
    }

    /// A request of connection `id` starts.
    fn request_started(&mut self, id: u64) {
        self.unmark_idle(id);
        if let Some(c) = self.conns.get_mut(&id) {
            c.busy += 1;
        }
    }

    /// A request of connection `id` has its answer written (or dropped).
    fn request_ended(&mut self, id: u64) {
        let Some(c) = self.conns.get_mut(&id) else { return };
        c.busy = c.busy.saturating_sub(1);
        if c.busy == 0 && !c.closing {
            let now = Instant::now();
            c.idle_since = Some(now);
            self.idle.insert((now, id));
            self.idle_by_ip.entry(c.ip).or_default().insert((now, id));
        }
    }

    /// Asks the connection idle the longest (of `ip` only, when given) to close; false when
    /// there is none, or too many are closing already.
    fn close_oldest_idle(&mut self, ip: Option<IpAddr>) -> bool {
        if self.closing >= MAX_CLOSING {
            return false;
        }
        let oldest = match ip {
            Some(ip) => self.idle_by_ip.get(&ip).and_then(|s| s.first()).copied(),
            None => self.idle.first().copied(),
        };
        let Some((_, id)) = oldest else { return false };
        self.unmark_idle(id);
        let Some(c) = self.conns.get_mut(&id) else { return false };
        c.closing = true;
        c.close.notify_one();
        self.closing += 1;
        true
    }
}

fn lock(open: &Mutex<Open>) -> std::sync::MutexGuard<'_, Open> {
    open.lock().unwrap_or_else(|e| e.into_inner())
}

/// One accepted connection's place in [`Open`], given back when dropped.
struct Slot {
    open: Arc<Mutex<Open>>,
    id: u64,
}

impl Drop for Slot {
    fn drop(&mut self) {
        lock(&self.open).remove(self.id);
    }
}

/// A request in progress on a connection: the connection is not idle until it is dropped
/// (with the answer's body, once written).
struct Busy {
    open: Arc<Mutex<Open>>,
    id: u64,
}

impl Busy {
    fn start(open: &Arc<Mutex<Open>>, id: u64) -> Busy {
        lock(open).request_started(id);
        Busy { open: open.clone(), id }
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        lock(&self.open).request_ended(self.id);
    }
}

/// Says at most once per interval that connections are being refused.
struct Throttled {
    last: Option<Instant>,
    refused: u64,
}

impl Throttled {
    fn refused(&mut self, why: &str) {
        self.refused += 1;
        if self.last.is_none_or(|t| t.elapsed() > Duration::from_secs(10)) {
            tracing::warn!("closing new connections: {why} ({} refused so far)", self.refused);
            self.last = Some(Instant::now());
        }
    }

    fn made_room(&mut self, why: &str) {
        self.refused += 1;
        if self.last.is_none_or(|t| t.elapsed() > Duration::from_secs(10)) {
            tracing::info!("closing idle connections to let new ones in: {why} ({} so far)", self.refused);
            self.last = Some(Instant::now());
        }
    }
}

/// What a request body that stopped arriving fails with (its handler sees a body error; the
/// answer becomes [`body_timeout_answer`]).
#[derive(Debug)]
pub struct BodyTimedOut(pub Duration);

impl std::fmt::Display for BodyTimedOut {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "the request body sent nothing for {} s", self.0.as_secs_f64())
    }
}

impl std::error::Error for BodyTimedOut {}

/// A request body that fails with [`BodyTimedOut`] once its server has waited `timeout` for
/// its next bytes. The clock runs only while the body is being read and nothing is there, and
/// starts again with every frame: a handler that reads late loses nothing, a client that keeps
/// sending is never cut, a client that stops is.
pub struct TimeoutBody<B> {
    inner: B,
    timeout: Duration,
    sleep: Option<Pin<Box<tokio::time::Sleep>>>,
    timed_out: Arc<AtomicBool>,
}

impl<B> TimeoutBody<B> {
    /// `inner` with the timeout; `timed_out` is set when it fires.
    pub fn new(inner: B, timeout: Duration, timed_out: Arc<AtomicBool>) -> TimeoutBody<B> {
        TimeoutBody { inner, timeout, sleep: None, timed_out }
    }
}

impl<B> hyper::body::Body for TimeoutBody<B>
where
    B: hyper::body::Body + Unpin,
    B::Error: Into<axum::BoxError>,
{
    type Data = B::Data;
    type Error = axum::BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        let this = &mut *self;
        if this.timed_out.load(Ordering::Relaxed) {
            return Poll::Ready(Some(Err(BodyTimedOut(this.timeout).into())));
        }
        if let Poll::Ready(frame) = Pin::new(&mut this.inner).poll_frame(cx) {
            this.sleep = None;
            return Poll::Ready(frame.map(|f| f.map_err(Into::into)));
        }
        let timeout = this.timeout;
        let sleep = this.sleep.get_or_insert_with(|| Box::pin(tokio::time::sleep(timeout)));
        if sleep.as_mut().poll(cx).is_ready() {
            this.timed_out.store(true, Ordering::Relaxed);
            return Poll::Ready(Some(Err(BodyTimedOut(timeout).into())));
        }
        Poll::Pending
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

/// The answer to a request whose body stopped arriving: 408 in the API's error shape, and the
/// connection closed (the rest of its body will not be read).
pub fn body_timeout_answer(timeout: Duration) -> Response<Body> {
    let error = tessera::protocol::ApiError {
        error: format!(
            "the request's body stopped arriving: nothing came for {} s (the server's --body-timeout-seconds); \
             nothing of it was stored. Send the body without pausing, or ask the operator for a longer --body-timeout-seconds",
            timeout.as_secs_f64()
        ),
        problems: Vec::new(),
    };
    let mut resp = Response::new(Body::from(serde_json::to_vec(&error).unwrap_or_default()));
    *resp.status_mut() = StatusCode::REQUEST_TIMEOUT;
    let headers = resp.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static("application/json"));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    headers.insert(header::CONNECTION, HeaderValue::from_static("close"));
    resp
}

/// An answer's body that keeps its request's [`Busy`] until it is written (or dropped).
struct Tracked<B> {
    inner: B,
    _busy: Busy,
}

impl<B> hyper::body::Body for Tracked<B>
where
    B: hyper::body::Body + Unpin,
{
    type Data = B::Data;
    type Error = B::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        Pin::new(&mut self.inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

/// Answers one request of connection `id` with `app`: the connection is busy until the
/// answer is written, and a body that stops arriving for `body_timeout` is answered 408.
async fn answer(
    app: Router,
    open: Arc<Mutex<Open>>,
    id: u64,
    body_timeout: Duration,
    req: Request<hyper::body::Incoming>,
) -> Result<Response<Tracked<Body>>, Infallible> {
    let busy = Busy::start(&open, id);
    let timed_out = Arc::new(AtomicBool::new(false));
    let req = req.map(|b| Body::new(TimeoutBody::new(b, body_timeout, timed_out.clone())));
    let resp = match app.oneshot(req).await {
        Ok(resp) => resp,
        Err(never) => match never {},
    };
    let resp = if timed_out.load(Ordering::Relaxed) { body_timeout_answer(body_timeout) } else { resp };
    Ok(resp.map(|inner| Tracked { inner, _busy: busy }))
}

/// Serves `app` on `listener` until `shutdown` completes, then stops accepting and lets every
/// open connection finish its request.
pub async fn serve(
    listener: tokio::net::TcpListener,
    app: Router,
    limits: ConnectionLimits,
    shutdown: impl std::future::Future<Output = ()>,
) {
    let open = Arc::new(Mutex::new(Open::default()));
    // Each connection holds a receiver: the sender is closed once every connection has ended.
    let (stop_tx, _) = tokio::sync::watch::channel(false);
    let mut shutdown = std::pin::pin!(shutdown);
    let mut refusals = Throttled { last: None, refused: 0 };
    let mut room = Throttled { last: None, refused: 0 };
    let mut accept_errors = Throttled { last: None, refused: 0 };
    loop {
        let accepted = tokio::select! {
            a = listener.accept() => a,
            _ = shutdown.as_mut() => break,
        };
        let (stream, peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                // Out of descriptors despite the limit (files of the server's own), or a
                // connection reset before it was accepted: wait a moment and go on.
                accept_errors.refused(&format!("accept failed: {e}"));
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let ip = peer.ip();
        let admitted = {
            let mut o = lock(&open);
            let of_ip = o.by_ip.get(&ip).copied().unwrap_or(0);
            let over_total = o.total >= limits.max_total;
            let over_ip = of_ip >= limits.max_per_ip;
            let why = if over_ip {
                format!(
                    "{ip} has {of_ip} connections open, the most one address may (--max-connections-per-ip)"
                )
            } else {
                format!("{} connections are open, the most this server keeps (--max-connections)", o.total)
            };
            if !(over_total || over_ip) {
                Some(o.add(ip))
            } else if o.close_oldest_idle(over_ip.then_some(ip)) {
                // Over its address's cap: that address's oldest idle connection goes; over the
                // total cap only: the oldest idle of any address.
                room.made_room(&why);
                Some(o.add(ip))
            } else {
                refusals.refused(&why);
                None
            }
        };
        let Some((id, close)) = admitted else {
            drop(stream);
            continue;
        };
        let slot = Slot { open: open.clone(), id };
        let _ = stream.set_nodelay(true);
        let (app, open, body_timeout) = (app.clone(), open.clone(), limits.body_timeout);
        let service =
            hyper::service::service_fn(move |req| answer(app.clone(), open.clone(), id, body_timeout, req));
        let conn = hyper::server::conn::http1::Builder::new()
            .timer(TokioTimer::new())
            .header_read_timeout(limits.header_timeout)
            .serve_connection(TokioIo::new(stream), service);
        let mut stop = stop_tx.subscribe();
        tokio::spawn(async move {
            let _slot = slot;
            let mut conn = std::pin::pin!(conn);
            let mut closing = false;
            // A connection closed by its client, by a timeout, to make room or by the
            // shutdown ends here.
            loop {
                tokio::select! {
                    _ = conn.as_mut() => break,
                    _ = close.notified(), if !closing => {
                        closing = true;
                        conn.as_mut().graceful_shutdown();
                    }
                    _ = stop.wait_for(|s| *s), if !closing => {
                        closing = true;
                        conn.as_mut().graceful_shutdown();
                    }
                }
            }
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    stop_tx.closed().await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_connection_limit_stays_below_the_descriptor_limit() {
        assert_eq!(max_connections(1024, None), 1024 - RESERVED_DESCRIPTORS as usize);
        assert_eq!(max_connections(1024, Some(100)), 100);
        assert_eq!(max_connections(1024, Some(5000)), 1024 - RESERVED_DESCRIPTORS as usize);
        // A tiny descriptor limit still leaves a few connections.
        assert_eq!(max_connections(64, None), 16);
        assert_eq!(max_connections(u64::MAX, None), usize::try_from(u64::MAX - 128).unwrap_or(usize::MAX));
    }
}
