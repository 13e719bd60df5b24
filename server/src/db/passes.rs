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
//! - `pixel_samples`: each pixel's samples so far (NULL: `samples_done` for every pixel).
//!
//! Under a noise target a tile's next pass is `waiting` until the one before it is added; then
//! [`tessera::passes::active_pixels`] decides which pixels still need samples, and the next
//! pass is queued with that `mask` (the pixels its lease renders), or the tile is finished
//! when none does. The decisions depend on the passes' sums only, so the CLI, rendering tile by
//! tile pass after pass, takes the same ones. A pass's sums of pixels outside its mask are not
//! added (a worker that ignores the mask renders them to no effect).

use anyhow::{Context, Result, anyhow};
use rusqlite::{OptionalExtension, Transaction, params};
use tessera::passes::{
    PIXEL_SUM_BYTES, PixelSum, active_pixels, decode_counts, decode_mask, decode_sums, encode_counts,
    encode_mask, encode_sums, tile_error_of,
};
use tessera::protocol::{Rect, encode_tile};

use super::{Cached, Event, log_event};

/// A pass's row as the merge reads it: its state, its sums, its last sample and its mask.
type PassRow = (String, Option<Vec<u8>>, u32, Option<Vec<u8>>);

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
    type TileState = (u32, u32, Option<Vec<u8>>, Option<Vec<u8>>, u32, Option<Vec<u8>>);
    let (mut passes_done, mut samples_done, sums, film, pass_samples, counts): TileState = tx
        .query_row_cached(
            "SELECT passes_done, samples_done, sums, pixels, end_sample, pixel_samples FROM tiles
             WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = 0",
            params![job, frame, tile],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?)),
        )?;
    let mut counts = match counts {
        Some(b) => {
            decode_counts(&b, px).ok_or_else(|| anyhow!("tile {tile}'s stored sample counts are damaged"))?
        }
        None => vec![samples_done; px],
    };
    let counts_before: u64 = counts.iter().map(|&c| u64::from(c)).sum();
    // The pixels that were still sampling before these passes (the last one added rendered
    // them): those that stop now skip the samples they will never take.
    let mut sampling: Vec<bool> = counts.iter().map(|&c| c == samples_done).collect();
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
        let next: Option<PassRow> = tx
            .query_row_cached(
                "SELECT state, pixels, end_sample, mask FROM tiles WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = ?4",
                params![job, frame, tile, passes_done],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
            )
            .optional()?;
        let Some((state, Some(bytes), end, mask)) = next else { break };
        if state != "done" {
            break;
        }
        let mask = match mask {
            Some(m) => Some(
                decode_mask(&m, px)
                    .ok_or_else(|| anyhow!("pass {passes_done} of tile {tile} has a damaged mask"))?,
            ),
            None => None,
        };
        let (sum_bytes, rest) = bytes.split_at((px * PIXEL_SUM_BYTES).min(bytes.len()));
        let pass = decode_sums(sum_bytes)
            .filter(|s| s.len() == px)
            .with_context(|| format!("pass {passes_done} of tile {tile} holds damaged sums"))?;
        for (i, (a, p)) in acc.iter_mut().zip(&pass).enumerate() {
            if mask.as_ref().is_none_or(|m| m[i]) {
                a.add(p);
                counts[i] = end;
            }
        }
        if let Some(m) = &mask {
            sampling = m.clone();
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
    let error = tile_error_of(&acc, &counts);
    let active = active_pixels(&acc, &counts, rect.width, samples, pass_samples, target);
    let more = active.contains(&true);
    let film: Vec<[f32; 3]> = acc.iter().zip(&counts).map(|(s, &c)| s.film(c)).collect();
    let mut film = encode_tile(&film);
    film.extend_from_slice(aux.as_deref().unwrap_or_default());
    let uneven = counts.iter().any(|&c| c != samples_done);
    tx.execute_cached(
        "UPDATE tiles SET pixels = ?4, sums = ?5, passes_done = ?6, samples_done = ?7, error = ?8, finished = ?9,
                pixel_samples = ?10
         WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = 0",
        params![
            job,
            frame,
            tile,
            film,
            encode_sums(&acc),
            passes_done,
            samples_done,
            error,
            !more,
            uneven.then(|| encode_counts(&counts))
        ],
    )?;
    // The frame's progress counters: the samples now in the tile's film, and for each pixel
    // that stops short of the frame's samples (the noise target), those it will never take.
    let counts_after: u64 = counts.iter().map(|&c| u64::from(c)).sum();
    let skipped: u64 = (0..px)
        .filter(|&i| sampling[i] && !active[i])
        .map(|i| u64::from(samples.saturating_sub(counts[i])))
        .sum();
    tx.execute_cached(
        "UPDATE frames SET samples_done = samples_done + ?3, samples_skipped = samples_skipped + ?4
         WHERE job_id = ?1 AND idx = ?2",
        params![job, frame, (counts_after - counts_before) as i64, skipped as i64],
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
        let spp = if uneven {
            format!(
                "{:.1} samples per pixel on average (at most {samples_done}; {counts_after} over its {px} pixels)",
                counts_after as f64 / px as f64
            )
        } else {
            format!("{samples_done} samples per pixel")
        };
        let message = format!(
            "tile {tile} of frame {frame} finished after {passes_done} of {passes_total} pass(es): {spp}, noise {noise}"
        );
        log_event(tx, job, Event { seconds: None, ..Event::new("tile_done", &message).tile(frame, tile) })?;
    } else if target.is_some() {
        let mask = active.contains(&false).then(|| encode_mask(&active));
        tx.execute_cached(
            "UPDATE tiles SET state = 'queued', mask = ?5 WHERE job_id = ?1 AND frame = ?2 AND tile = ?3 AND pass = ?4 AND state = 'waiting'",
            params![job, frame, tile, passes_done, mask],
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
