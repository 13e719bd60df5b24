//! The worker's name lookups: the server's address, found on a thread of its own and kept, so
//! that a name server that does not answer never holds up a request.
//!
//! ureq looks the host up with the C library's `getaddrinfo` for every new connection, on the
//! calling thread, and no timeout of ureq's covers it; glibc waits 5 s for each try at each
//! name server, for each search domain. A name server that stops answering for a while then
//! stalls every thread that opens a connection: the heartbeat, the bundle download, the upload,
//! and a worker whose heartbeats stall loses its leases though the server is up and reachable.
//! That is what happened on podman networks (netavark before 1.9): the network's bridge takes
//! the lowest MAC address of its ports, so when a container starts or stops it may change, and
//! a container that has the old one cached for its gateway, where aardvark-dns answers, loses
//! every DNS query until its ARP entry is renewed (10 s and 30 s seen); container-to-container
//! traffic is not affected.
//!
//! [`CachingResolver`] instead keeps the addresses of the last lookup that succeeded and
//! answers with them at once; when they are older than [`FRESH`] it starts a new lookup in the
//! background (one at a time per name) whose result the following connections use. Only the
//! first lookup of a name is waited for, up to the connect timeout. A server that moved (a new
//! container, a new address) is found by the next lookup: requests fail meanwhile and are
//! retried as after any connection error.

use std::collections::HashMap;
use std::io;
use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// How long the addresses of a lookup are used before another lookup is started.
pub const FRESH: Duration = Duration::from_secs(5);

/// What is known of one `host:port`.
#[derive(Default)]
struct Name {
    /// The addresses the last successful lookup found, and when it finished.
    known: Option<(Vec<SocketAddr>, Instant)>,
    /// A lookup is running.
    looking: bool,
    /// Lookups finished so far (a waiter sees its lookup end when this changes).
    finished: u64,
    /// Why the last lookup failed, if it did.
    error: Option<String>,
}

#[derive(Default)]
struct Names {
    names: Mutex<HashMap<String, Name>>,
    done: Condvar,
}

/// A ureq resolver that looks names up on a thread of its own and answers from the last
/// successful lookup (see the module's documentation).
#[derive(Clone)]
pub struct CachingResolver {
    names: Arc<Names>,
    /// How long the first lookup of a name is waited for.
    cold_wait: Duration,
    lookup: fn(&str) -> io::Result<Vec<SocketAddr>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn system_lookup(netloc: &str) -> io::Result<Vec<SocketAddr>> {
    netloc.to_socket_addrs().map(Iterator::collect)
}

impl CachingResolver {
    /// Waits up to `cold_wait` for the first lookup of a name.
    pub fn new(cold_wait: Duration) -> CachingResolver {
        CachingResolver { names: Arc::default(), cold_wait, lookup: system_lookup }
    }

    /// Starts a lookup of `netloc` on a thread of its own, unless one is running.
    fn start(&self, netloc: &str, name: &mut Name) {
        if name.looking {
            return;
        }
        let (names, key, lookup) = (self.names.clone(), netloc.to_string(), self.lookup);
        let spawned = std::thread::Builder::new().name("resolver".into()).spawn(move || {
            let result = lookup(&key);
            let mut all = lock(&names.names);
            let name = all.entry(key.clone()).or_default();
            name.looking = false;
            name.finished += 1;
            match result {
                Ok(addrs) if !addrs.is_empty() => {
                    name.known = Some((addrs, Instant::now()));
                    name.error = None;
                }
                Ok(_) => name.error = Some(format!("{key} has no address")),
                Err(e) => name.error = Some(e.to_string()),
            }
            names.done.notify_all();
        });
        match spawned {
            Ok(_) => name.looking = true,
            // No thread to spare: the caller looks at what is known, and tries again later.
            Err(e) => name.error = Some(format!("cannot start a lookup: {e}")),
        }
    }
}

impl ureq::Resolver for CachingResolver {
    fn resolve(&self, netloc: &str) -> io::Result<Vec<SocketAddr>> {
        // An address needs no lookup.
        if let Ok(addr) = netloc.parse::<SocketAddr>() {
            return Ok(vec![addr]);
        }
        let mut all = lock(&self.names.names);
        let name = all.entry(netloc.to_string()).or_default();
        if let Some((addrs, at)) = &name.known {
            let addrs = addrs.clone();
            if at.elapsed() >= FRESH {
                self.start(netloc, name);
            }
            return Ok(addrs);
        }
        // Never found yet: wait for a lookup (joining the one running, if any).
        self.start(netloc, name);
        let seen = name.finished;
        if !name.looking {
            let why = name.error.clone().unwrap_or_default();
            return Err(io::Error::other(format!("cannot look up {netloc}: {why}")));
        }
        let deadline = Instant::now() + self.cold_wait;
        loop {
            let name = all.entry(netloc.to_string()).or_default();
            if name.finished != seen {
                return match (&name.known, &name.error) {
                    (Some((addrs, _)), _) => Ok(addrs.clone()),
                    (None, why) => Err(io::Error::other(format!(
                        "cannot look up {netloc}: {}",
                        why.as_deref().unwrap_or("no answer")
                    ))),
                };
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "looking up {netloc} took longer than {} s (the name server does not answer)",
                        self.cold_wait.as_secs_f64()
                    ),
                ));
            }
            all = self.names.done.wait_timeout(all, left).unwrap_or_else(|e| e.into_inner()).0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU64, Ordering};
    use ureq::Resolver;

    static CALLS: AtomicU64 = AtomicU64::new(0);
    static SLOW: Mutex<bool> = Mutex::new(false);

    /// One lookup that answers 10.0.0.N (N: the lookups so far), and takes 2 s while SLOW.
    fn counting(netloc: &str) -> io::Result<Vec<SocketAddr>> {
        assert!(netloc.starts_with("server:"));
        let n = CALLS.fetch_add(1, Ordering::SeqCst) + 1;
        if *lock(&SLOW) {
            std::thread::sleep(Duration::from_secs(2));
        }
        Ok(vec![SocketAddr::from(([10, 0, 0, n as u8], 8080))])
    }

    #[test]
    fn a_slow_name_server_holds_up_only_the_first_lookup_and_later_answers_are_used() {
        let r = CachingResolver { lookup: counting, ..CachingResolver::new(Duration::from_millis(500)) };
        // Addresses need no lookup.
        assert_eq!(r.resolve("10.1.2.3:80").unwrap(), vec![SocketAddr::from(([10, 1, 2, 3], 80))]);
        assert_eq!(CALLS.load(Ordering::SeqCst), 0);
        // The first lookup is waited for; the next ones use its answer.
        let first = r.resolve("server:8080").unwrap();
        assert_eq!(first, vec![SocketAddr::from(([10, 0, 0, 1], 8080))]);
        assert_eq!(r.resolve("server:8080").unwrap(), first);
        assert_eq!(CALLS.load(Ordering::SeqCst), 1);
        // Old answers are still answered at once while a slow lookup runs in the background,
        // and only one lookup runs at a time.
        *lock(&SLOW) = true;
        lock(&r.names.names).get_mut("server:8080").unwrap().known.as_mut().unwrap().1 -= FRESH;
        let t = Instant::now();
        for _ in 0..5 {
            assert_eq!(r.resolve("server:8080").unwrap(), first);
        }
        assert!(t.elapsed() < Duration::from_millis(500), "{:?}", t.elapsed());
        std::thread::sleep(Duration::from_millis(100));
        assert_eq!(CALLS.load(Ordering::SeqCst), 2);
        // Its answer (a new address) is used once it comes.
        let deadline = Instant::now() + Duration::from_secs(10);
        while r.resolve("server:8080").unwrap() == first {
            assert!(Instant::now() < deadline, "the background lookup's answer never came");
            std::thread::sleep(Duration::from_millis(20));
        }
        assert_eq!(r.resolve("server:8080").unwrap(), vec![SocketAddr::from(([10, 0, 0, 2], 8080))]);
        // A first lookup that takes longer than the wait is an error naming the time, not a hang.
        let t = Instant::now();
        let e = r.resolve("server:9090").unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::TimedOut, "{e}");
        assert!(t.elapsed() < Duration::from_millis(1500), "{:?}", t.elapsed());
        *lock(&SLOW) = false;
    }

    /// Finds `known:N` and nothing else.
    fn only_known(netloc: &str) -> io::Result<Vec<SocketAddr>> {
        match netloc.strip_prefix("known:") {
            Some(port) => Ok(vec![SocketAddr::from(([10, 9, 9, 9], port.parse().unwrap()))]),
            None => Err(io::Error::other("Name or service not known")),
        }
    }

    #[test]
    fn a_name_that_does_not_resolve_is_an_error_saying_so_and_a_failed_refresh_keeps_the_last_answer() {
        let mut r = CachingResolver { lookup: only_known, ..CachingResolver::new(Duration::from_secs(30)) };
        let e = r.resolve("gone:8080").unwrap_err();
        assert_eq!(e.to_string(), "cannot look up gone:8080: Name or service not known");
        let known = r.resolve("known:8080").unwrap();
        assert_eq!(known, vec![SocketAddr::from(([10, 9, 9, 9], 8080))]);
        // A refresh that fails leaves the last answer in use.
        let mut all = lock(&r.names.names);
        let name = all.get_mut("known:8080").unwrap();
        name.known.as_mut().unwrap().1 -= FRESH;
        let stale = name.finished;
        r.lookup = |_: &str| Err(io::Error::other("no answer"));
        drop(all);
        assert_eq!(r.resolve("known:8080").unwrap(), known);
        let deadline = Instant::now() + Duration::from_secs(10);
        while lock(&r.names.names)["known:8080"].finished == stale {
            assert!(Instant::now() < deadline, "the refresh never ended");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(r.resolve("known:8080").unwrap(), known);
    }
}
