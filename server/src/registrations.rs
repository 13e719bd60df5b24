//! Bounds on worker registrations: each registration is a row of the store and a line of the
//! workers list, so a holder of the worker token must not be able to add them without end.
//!
//! - a rate: registrations with the worker token take a token of a bucket of
//!   [`REGISTRATION_BURST`] refilled at [`REGISTRATIONS_PER_SECOND`] (a 429 with `Retry-After`
//!   past it);
//! - a cap on live workers (`--max-workers`; a 503 past it), past which lost workers' rows are
//!   forgotten too ([`crate::db::Store::register_worker_within`]);
//! - stale workers forgotten (`--forget-workers-after`, by the housekeeping task).
//!
//! The server's own local workers register with a token of their own, which none of these
//! refuse: a local worker restarted by the server always gets back in.

use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Registrations with the worker token that may come at once (a farm's workers starting
/// together), and how many a second after that.
pub const REGISTRATION_BURST: f64 = 256.0;
pub const REGISTRATIONS_PER_SECOND: f64 = 16.0;

/// A token bucket: `capacity` tokens, refilled at `per_second`.
#[derive(Debug)]
pub struct TokenBucket {
    capacity: f64,
    per_second: f64,
    /// Tokens at the instant.
    state: Mutex<(f64, Instant)>,
}

impl TokenBucket {
    pub fn new(capacity: f64, per_second: f64) -> TokenBucket {
        TokenBucket { capacity, per_second, state: Mutex::new((capacity, Instant::now())) }
    }

    /// The bucket of worker registrations.
    pub fn registrations() -> TokenBucket {
        TokenBucket::new(REGISTRATION_BURST, REGISTRATIONS_PER_SECOND)
    }

    /// Takes a token, or says how long until there is one.
    pub fn take(&self) -> Result<(), Duration> {
        self.take_at(Instant::now())
    }

    fn take_at(&self, now: Instant) -> Result<(), Duration> {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let (tokens, at) = *state;
        let tokens =
            (tokens + now.saturating_duration_since(at).as_secs_f64() * self.per_second).min(self.capacity);
        if tokens >= 1.0 {
            *state = (tokens - 1.0, now);
            Ok(())
        } else {
            *state = (tokens, now);
            Err(Duration::from_secs_f64((1.0 - tokens) / self.per_second))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bucket_gives_its_burst_then_its_rate() {
        let bucket = TokenBucket::new(3.0, 2.0);
        let t = Instant::now();
        for _ in 0..3 {
            bucket.take_at(t).unwrap();
        }
        let wait = bucket.take_at(t).unwrap_err();
        assert!((wait.as_secs_f64() - 0.5).abs() < 1e-6, "{wait:?}");
        // Half a second later, one more; not two.
        let later = t + Duration::from_millis(500);
        bucket.take_at(later).unwrap();
        assert!(bucket.take_at(later).is_err());
        // Never more than the burst, however long it rested.
        let rested = later + Duration::from_secs(3600);
        for _ in 0..3 {
            bucket.take_at(rested).unwrap();
        }
        assert!(bucket.take_at(rested).is_err());
    }
}
