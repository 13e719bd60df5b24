//! Passes in the store: a tile of several passes is several rows (one per pass, the unit of
//! leasing); the row of pass 0 also holds the tile's running state.
//!
//! - `sums`: the fixed-point sums of the passes added so far ([`tessera::passes`]), exact in
//!   any order of arrival;
//! - `passes_done`, `samples_done`: the passes added (always the first ones: a pass that
//!   arrives before its predecessors waits in its own row, `pixels` holding its sums, until
//!   they are added) and the samples per pixel they make;
//! - `pixels`: the tile's film at `samples_done` samples (as a whole tile's result is stored,
//!   with the features of pass 0 after it for a denoised job), which previews and merges read;
//! - `error`: the tile's noise estimate; `finished`: no more passes will be added.
//!
//! Under a noise target a tile's next pass is `waiting` until the one before it is added and
//! found too noisy ([`tessera::passes::needs_more`]): the decisions depend on the passes' sums
//! only, so the CLI, rendering tile by tile pass after pass, takes the same ones.

use anyhow::{Context, Result, anyhow};
use rusqlite::{OptionalExtension, Transaction, params};
use tessera::passes::{PIXEL_SUM_BYTES, PixelSum, decode_sums, encode_sums, needs_more, tile_error};
use tessera::protocol::{Rect, encode_tile};

use super::{Cached, Event, log_event};

/// What a lease's result must hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResultShape {
    /// Pixels of the tile.
    pub pixels: usize,
    /// For a pass: the most blocks of samples it covers (its sums are checked against what
    /// that many blocks can reach). `None`: finished pixels of a whole tile.
    pub blocks: Option<u32>,
    /// Features follow (albedo, normal).
    pub aux: bool,
}

impl ResultShape {
    pub fn bytes(&self) -> usize {
        match self.blocks {
            Some(_) => tessera::passes::pass_tile_bytes(self.pixels, self.aux),
            None => tessera::protocol::tile_bytes(self.pixels, self.aux),
        }
    }
}

/// Adds into `tile` every pass that has arrived and follows the ones already added, then
/// decides whether the tile needs more; returns the passes every tile of the frame has now
/// finished when that number grew (the frame is worth publishing again).
pub(super) fn absorb(
    tx: &Transaction<'_>,
    job: i64,
    frame: i64,
    tile: i64,
    rect: Rect,
) -> Result<Option<u32>> {
    let px = (rect.width * rect.height) as usize;
    let (samples, passes_total, published): (u32, u32, u32) = tx.query_row_cached(
        "SELECT samples, passes_total, passes_published FROM frames WHERE job_id = ?1 AND idx = ?2",
        params![job, frame],
        |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
    )?;
    let (target, denoise): (Option<f64>, bool) =
        tx.query_row_cached("SELECT noise_target, denoise FROM jobs WHERE id = ?1", [job], |r| {
            Ok((r.get(0)?, r.get(1)?))
        })?;
    let (mut passes_done, mut samples_done, sums, film, pass_samples): (
        u32,
        u32,
        Option<Vec<u8>>,
        Option<Vec<u8>>,
        u32,
    ) = tx.query_row_cached(
        "SELECT passes_done, samples_done, sums, pixels, end_sample FROM tiles
             WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = 0",
        params![job, frame, tile],
        |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?)),
    )?;
    let samples_before = samples_done;
    let mut acc = match sums {
        Some(b) => decode_sums(&b)
            .filter(|s| s.len() == px)
            .ok_or_else(|| anyhow!("tile {tile}'s stored sums are damaged"))?,
        None => vec![PixelSum::default(); px],
    };
    // The features, from pass 0, once it is added.
    let mut aux: Option<Vec<u8>> =
        film.filter(|_| passes_done > 0 && denoise).map(|f| f.get(px * 12..).unwrap_or_default().to_vec());
    let mut added = false;
    loop {
        let next: Option<(String, Option<Vec<u8>>, u32)> = tx
            .query_row_cached(
                "SELECT state, pixels, end_sample FROM tiles WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = ?4",
                params![job, frame, tile, passes_done],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
            )
            .optional()?;
        let Some((state, Some(bytes), end)) = next else { break };
        if state != "done" {
            break;
        }
        let (sum_bytes, rest) = bytes.split_at((px * PIXEL_SUM_BYTES).min(bytes.len()));
        let pass = decode_sums(sum_bytes)
            .filter(|s| s.len() == px)
            .with_context(|| format!("pass {passes_done} of tile {tile} holds damaged sums"))?;
        for (a, p) in acc.iter_mut().zip(&pass) {
            a.add(p);
        }
        if passes_done == 0 && denoise {
            aux = Some(rest.to_vec());
        }
        if passes_done > 0 {
            tx.execute_cached(
                "UPDATE tiles SET pixels = NULL WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = ?4",
                params![job, frame, tile, passes_done],
            )?;
        }
        passes_done += 1;
        samples_done = end;
        added = true;
    }
    if !added {
        return Ok(None);
    }
    let error = tile_error(&acc, samples_done);
    let more = needs_more(samples, pass_samples, samples_done, error, target);
    let film: Vec<[f32; 3]> = acc.iter().map(|s| s.film(samples_done)).collect();
    let mut film = encode_tile(&film);
    film.extend_from_slice(aux.as_deref().unwrap_or_default());
    tx.execute_cached(
        "UPDATE tiles SET pixels = ?4, sums = ?5, passes_done = ?6, samples_done = ?7, error = ?8, finished = ?9
         WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = 0",
        params![job, frame, tile, film, encode_sums(&acc), passes_done, samples_done, error, !more],
    )?;
    // The frame's progress counters: the samples now in the tile's film, and once the tile
    // stops short of the frame's samples (the noise target), those it will never take.
    let skipped = if more { 0 } else { samples.saturating_sub(samples_done) };
    tx.execute_cached(
        "UPDATE frames SET samples_done = samples_done + ?3, samples_skipped = samples_skipped + ?4
         WHERE job_id = ?1 AND idx = ?2",
        params![
            job,
            frame,
            px as i64 * i64::from(samples_done.saturating_sub(samples_before)),
            px as i64 * i64::from(skipped)
        ],
    )?;
    if !more {
        tx.execute_cached(
            "UPDATE tiles SET state = 'skipped' WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass >= ?4 AND state IN ('waiting', 'queued')",
            params![job, frame, tile, passes_done],
        )?;
        tx.execute_cached(
            "UPDATE frames SET tiles_done = tiles_done + 1 WHERE job_id = ?1 AND idx = ?2",
            params![job, frame],
        )?;
        let noise = error.map(|e| format!("{e:.4}")).unwrap_or_else(|| "not estimated".into());
        let message = format!(
            "tile {tile} of frame {frame} finished after {passes_done} of {passes_total} pass(es): {samples_done} samples per pixel, noise {noise}"
        );
        log_event(tx, job, Event { seconds: None, ..Event::new("tile_done", &message).tile(frame, tile) })?;
    } else if target.is_some() {
        tx.execute_cached(
            "UPDATE tiles SET state = 'queued' WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = ?4 AND state = 'waiting'",
            params![job, frame, tile, passes_done],
        )?;
    }
    let reached: Option<i64> = tx.query_row_cached(
        "SELECT min(CASE WHEN finished THEN ?3 ELSE passes_done END) FROM tiles WHERE job_id = ?1 AND frame = ?2 AND pass = 0",
        params![job, frame, passes_total],
        |r| r.get(0),
    )?;
    let reached = reached.unwrap_or(0).max(0) as u32;
    if reached > published {
        tx.execute_cached(
            "UPDATE frames SET passes_published = ?3 WHERE job_id = ?1 AND idx = ?2",
            params![job, frame, reached],
        )?;
        return Ok(Some(reached));
    }
    Ok(None)
}
