//! Accepting connections under limits: no client can take every file descriptor or hold a
//! connection that says nothing.
//!
//! The server accepts HTTP/1.1 connections itself (instead of `axum::serve`) so that it can:
//! - bound the connections open at once ([`ConnectionLimits::max_total`], below the process's
//!   descriptor limit, which [`raise_descriptor_limit`] lifts to its hard maximum at start-up)
//!   and those of one client address ([`ConnectionLimits::max_per_ip`]); a connection over
//!   either is accepted and closed at once, so the listen queue never fills and the server never
//!   runs out of descriptors for its database and files;
//! - close a connection whose request head does not arrive in
//!   [`ConnectionLimits::header_timeout`], and a kept-alive connection idle for as long (hyper's
//!   header-read timer, which runs while a connection waits for its next request);
//! - stop gracefully: no new connections, each open one finishes its request and closes.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;

/// Descriptors kept for the server's own use (the database and its journal, blobs, outputs,
/// local workers' pipes, the listener) when the connection limit is derived from the
/// descriptor limit.
pub const RESERVED_DESCRIPTORS: u64 = 128;

/// Default most connections of one client address.
pub const DEFAULT_MAX_PER_IP: usize = 256;

/// Default time a client has to send a request head, and most time a kept-alive connection
/// may wait for its next request.
pub const DEFAULT_HEADER_TIMEOUT: Duration = Duration::from_secs(20);

#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    pub max_total: usize,
    pub max_per_ip: usize,
    pub header_timeout: Duration,
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

/// Counts of open connections, in all and by client address.
#[derive(Default)]
struct Open {
    total: usize,
    by_ip: HashMap<IpAddr, usize>,
}

/// One accepted connection's place in [`Open`], given back when dropped.
struct Slot {
    open: Arc<Mutex<Open>>,
    ip: IpAddr,
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        open.total -= 1;
        if let Some(n) = open.by_ip.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                open.by_ip.remove(&self.ip);
            }
        }
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
    let graceful = GracefulShutdown::new();
    let mut shutdown = std::pin::pin!(shutdown);
    let mut refusals = Throttled { last: None, refused: 0 };
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
        let slot = {
            let mut o = open.lock().unwrap_or_else(|e| e.into_inner());
            let of_ip = o.by_ip.get(&ip).copied().unwrap_or(0);
            if o.total >= limits.max_total {
                refusals.refused(&format!(
                    "{} connections are open, the most this server keeps (--max-connections)",
                    o.total
                ));
                None
            } else if of_ip >= limits.max_per_ip {
                refusals.refused(&format!(
                    "{ip} has {of_ip} connections open, the most one address may (--max-connections-per-ip)"
                ));
                None
            } else {
                o.total += 1;
                *o.by_ip.entry(ip).or_default() += 1;
                Some(Slot { open: open.clone(), ip })
            }
        };
        let Some(slot) = slot else {
            drop(stream);
            continue;
        };
        let _ = stream.set_nodelay(true);
        let service = TowerToHyperService::new(app.clone());
        let conn = hyper::server::conn::http1::Builder::new()
            .timer(TokioTimer::new())
            .header_read_timeout(limits.header_timeout)
            .serve_connection(TokioIo::new(stream), service);
        let conn = graceful.watch(conn);
        tokio::spawn(async move {
            let _slot = slot;
            // A connection closed by its client, or by the header timeout, ends here.
            let _ = conn.await;
        });
    }
    drop(listener);
    graceful.shutdown().await;
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
