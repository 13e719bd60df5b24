//! Job-end notifications in the store: which ended jobs are still to be announced, and the
//! record that they were (or could not be), so a restart neither repeats nor forgets one.

use super::*;

/// An ended job whose notification is still due.
#[derive(Clone, Debug, PartialEq)]
pub struct DueNotification {
    pub job: u64,
    pub state: JobState,
    /// The job's own `notify_url`, if it gave one.
    pub url: Option<String>,
}

/// How a job's end was announced.
#[derive(Clone, Debug, PartialEq)]
pub enum Notified {
    /// Every receiver answered 2xx (the message says who).
    Delivered(String),
    /// A receiver kept failing; the message says why.
    GaveUp(String),
    /// Nobody was to be told.
    NoReceiver,
}

impl Store {
    /// Ended jobs (done, failed, cancelled) not announced yet, oldest first, at most `limit`.
    pub fn due_notifications(&self, limit: usize) -> Result<Vec<DueNotification>> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(
            "SELECT id, state, notify_url FROM jobs
             WHERE notified = 0 AND state IN ('done', 'failed', 'canceled') ORDER BY finished_at, id LIMIT ?1",
        )?;
        let rows = stmt.query_map([limit as i64], |r| {
            Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?, r.get::<_, Option<String>>(2)?))
        })?;
        let mut due = Vec::new();
        for row in rows {
            let (job, state, url) = row?;
            if let Some(state) = JobState::parse(&state) {
                due.push(DueNotification { job: job as u64, state, url });
            }
        }
        Ok(due)
    }

    /// Records the outcome of a job's notification and logs it as an event (`notified` or
    /// `notify_failed`, with its message), or without one when there was no receiver to tell.
    pub fn notification_sent(&self, job: u64, outcome: Notified) -> Result<()> {
        let mut conn = self.conn();
        let tx = conn.transaction()?;
        let (code, event) = match &outcome {
            Notified::Delivered(m) => (1, Some(Event::new("notified", m))),
            Notified::GaveUp(m) => (2, Some(Event::new("notify_failed", m))),
            Notified::NoReceiver => (3, None),
        };
        let changed = tx.execute(
            "UPDATE jobs SET notified = ?2 WHERE id = ?1 AND notified = 0",
            params![job as i64, code],
        )?;
        if let (true, Some(e)) = (changed > 0, event) {
            log_event(&tx, job as i64, e)?;
        }
        tx.commit()?;
        Ok(())
    }

    /// Sets the job's own notification URL (checked against `--notify-allow` by the caller).
    pub fn set_notify_url(&self, job: u64, url: &str) -> Result<()> {
        self.conn().execute("UPDATE jobs SET notify_url = ?2 WHERE id = ?1", params![job as i64, url])?;
        Ok(())
    }
}
