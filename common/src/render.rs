//! Tile rendering: the unit of work of the farm (one tile per lease) and of the CLI (rayon over tiles).
//!
//! Invariant: a pixel's value depends only on (scene, camera, pixel, seed). Tiles share nothing
//! mutable, samples draw from a [`Sampler`] keyed by pixel and sample index, and samples are
//! summed in a fixed order, so any tile size and any thread count give identical bits.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use crate::geometry::RayLanes;
use crate::image::{Image, TileRect};
use crate::integrator::{CameraGroup, RayStats, Tracer};
use crate::math::Ray;
use crate::passes::{BLOCK, PixelSum, SampleRange};
use crate::sampler::{FrameKey, PixelSeeds, Sampler, frame_seed};
use crate::scene::Scene;
use crate::scene::records::EnvSampler;

/// Knobs that change what is rendered (not how fast).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderSettings {
    /// Base seed; the frame seed of each camera derives from it.
    pub seed: u64,
    /// Samples per pixel instead of each camera's `NumSamples` (quick previews, CI subsets).
    pub samples: Option<u32>,
    /// How the environment light picks directions, instead of the scene's `Sampler` (whose
    /// absence means the course's uniform estimator).
    pub env_sampling: Option<EnvSampler>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings { seed: 0x7e55_e7a0, samples: None, env_sampling: None }
    }
}

/// Cuts a `width` x `height` frame into tiles of at most `tile` x `tile` pixels, row by row.
pub fn tiles(width: u32, height: u32, tile: u32) -> Vec<TileRect> {
    let tile = tile.max(1);
    let mut out = Vec::new();
    let mut y0 = 0;
    while y0 < height {
        let h = tile.min(height - y0);
        let mut x0 = 0;
        while x0 < width {
            let w = tile.min(width - x0);
            out.push(TileRect { x0, y0, width: w, height: h });
            x0 += w;
        }
        y0 += h;
    }
    out
}

/// A frame being filled by its tiles from several threads at once, with no lock: the tiles are
/// the grid [`tiles`] cuts (which partition the frame, so no two share a pixel), and each is
/// put once, claimed through its own flag. Each thread writes, and first touches, only its own
/// tile's pixels, so none waits for another's page faults.
struct FrameTiles<'a> {
    pixels: *mut [f32; 3],
    width: u32,
    rects: Vec<TileRect>,
    put: Vec<AtomicBool>,
    _frame: std::marker::PhantomData<&'a mut Image>,
}

// SAFETY: the threads write through `pixels` only in `put`, each to the pixels of one tile of
// the grid, claimed once; the grid's tiles are disjoint, and the image is borrowed mutably for
// the sink's life, so nothing else reads or writes it meanwhile.
unsafe impl Sync for FrameTiles<'_> {}

impl<'a> FrameTiles<'a> {
    /// The grid of `tile`-pixel tiles over `image`.
    fn new(image: &'a mut Image, tile: u32) -> Self {
        let rects = tiles(image.width, image.height, tile);
        assert_eq!(image.pixels.len(), image.width as usize * image.height as usize, "an entry a pixel");
        let put = rects.iter().map(|_| AtomicBool::new(false)).collect();
        FrameTiles {
            pixels: image.pixels.as_mut_ptr(),
            width: image.width,
            rects,
            put,
            _frame: std::marker::PhantomData,
        }
    }

    /// Copies tile `index`'s pixels (row by row) into place. Panics when the tile was put
    /// before or `px` is not its size.
    fn put(&self, index: usize, px: &[[f32; 3]]) {
        let r = self.rects[index];
        let w = r.width as usize;
        assert_eq!(px.len(), w * r.height as usize, "a value a pixel of the tile");
        assert!(!self.put[index].swap(true, Ordering::AcqRel), "tile {index} put twice");
        for (row, start) in r.row_starts(self.width).enumerate() {
            let src = &px[row * w..(row + 1) * w];
            // SAFETY: the tile lies inside the frame (`tiles` cuts within it), so the row's `w`
            // pixels from `start` are in the image; no other tile covers them and this one is
            // put once (the flag above), so no other write or read overlaps this one.
            unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), self.pixels.add(start), w) };
        }
    }
}

/// When a render in progress must give up: a flag someone else raises (a cancelled job, a
/// revoked lease) and a deadline (the farm's longest tile render). Checked between samples, so
/// a tile stops within one sample's time of either, however many samples a pixel asks for.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stop<'a> {
    pub flag: Option<&'a AtomicBool>,
    pub deadline: Option<Instant>,
}

/// Why a render stopped before it finished.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stopped {
    /// The flag was raised.
    Cancelled,
    /// The deadline passed.
    OutOfTime,
}

impl Stop<'_> {
    /// Never stops.
    pub const NEVER: Stop<'static> = Stop { flag: None, deadline: None };

    fn check(&self) -> Result<(), Stopped> {
        if self.flag.is_some_and(|f| f.load(Ordering::Relaxed)) {
            return Err(Stopped::Cancelled);
        }
        if self.deadline.is_some_and(|d| Instant::now() >= d) {
            return Err(Stopped::OutOfTime);
        }
        Ok(())
    }
}

/// How many samples pass between two looks at a [`Stop`] (a sample costs a microsecond or more,
/// the look tens of nanoseconds).
const STOP_CHECK_EVERY: u32 = BLOCK;

/// Camera samples of a pixel traced together (a [`Packet8`](crate::geometry::bvh8::Packet8));
/// divides [`STOP_CHECK_EVERY`]. The stop is looked at between batches of groups: every 16
/// samples one group at a time, every 256 when [`POOL_GROUPS`] groups' paths go together.
const GROUP: usize = crate::sampler::GROUP_LANES;

/// Groups of camera samples whose paths are traced together (see
/// [`Tracer::trace_path_groups`]): the more, the fuller the groups stay as paths end.
const POOL_GROUPS: usize = 32;

pub use crate::passes::film_value;

/// Samples per pixel from which environment shadow rays ask their triangle's horizon first
/// ([`crate::geometry::Horizons`]): bounding a horizon costs about as much as a few hundred
/// shadow rays, which fewer samples do not leave to save. The images are the same either way.
pub const HORIZON_SAMPLES: u32 = 64;

/// The samples per pixel a camera renders under `settings`.
pub fn samples_per_pixel(scene: &Scene, camera: usize, settings: &RenderSettings) -> u32 {
    settings.samples.unwrap_or(scene.cameras[camera].num_samples).max(1)
}

/// Renders one tile of camera `camera`: linear float RGB, row-major within the tile.
///
/// Panics only if `camera` or `rect` is out of range for the scene (a caller bug, not input).
pub fn render_tile(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
) -> (Vec<[f32; 3]>, RayStats) {
    match render_tile_until(scene, camera, rect, settings, Stop::NEVER) {
        Ok(r) => r,
        Err(_) => unreachable!("Stop::NEVER never stops"),
    }
}

/// [`render_tile`] that gives up when `stop` says so; the pixels it returns are the same bits.
pub fn render_tile_until(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    stop: Stop<'_>,
) -> Result<(Vec<[f32; 3]>, RayStats), Stopped> {
    let n = samples_per_pixel(scene, camera, settings);
    if n == 1 {
        return render_one_sample_tile_until(scene, camera, rect, settings, stop, None);
    }
    let (sums, stats) =
        render_tile_sums_until(scene, camera, rect, settings, SampleRange::all(n), stop, None)?;
    Ok((sums.iter().map(|s| s.film(n)).collect(), stats))
}

/// A tile's features for a denoiser, pixel by pixel beside its colour: the average over the
/// pixel's first block of samples (at most [`BLOCK`], whatever the passes) of each sample's
/// [`Aux`](crate::integrator::Aux) (albedo, then normal), as film values.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AuxTile {
    pub albedo: Vec<[f32; 3]>,
    pub normal: Vec<[f32; 3]>,
}

/// [`render_tile_until`] that also returns the tile's [`AuxTile`]. The colour is the same bits:
/// the features draw no random numbers.
pub fn render_tile_with_aux_until(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    stop: Stop<'_>,
) -> Result<(Vec<[f32; 3]>, AuxTile, RayStats), Stopped> {
    let mut aux = AuxTile::default();
    let n = samples_per_pixel(scene, camera, settings);
    if n == 1 {
        let (film, stats) =
            render_one_sample_tile_until(scene, camera, rect, settings, stop, Some(&mut aux))?;
        return Ok((film, aux, stats));
    }
    let (sums, stats) =
        render_tile_sums_until(scene, camera, rect, settings, SampleRange::all(n), stop, Some(&mut aux))?;
    Ok((sums.iter().map(|s| s.film(n)).collect(), aux, stats))
}

/// Renders the samples `range` (starting at a whole block) of every pixel of a tile, as
/// [`PixelSum`]s: the unit of a pass. The sums of a pixel's passes add up to the same bits as
/// the whole range rendered at once. `aux`, when given, is filled from the first block, so only
/// a range that starts at sample 0 may ask for it.
///
/// Panics only if `camera`, `rect` or `range` is out of range (a caller bug, not input).
pub fn render_tile_sums_until(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    range: SampleRange,
    stop: Stop<'_>,
    aux: Option<&mut AuxTile>,
) -> Result<(Vec<PixelSum>, RayStats), Stopped> {
    render_tile_sums_masked(scene, camera, rect, settings, range, None, stop, aux)
}

/// [`render_tile_sums_until`] for the pixels of `mask` only (row-major over the tile; `None`:
/// every pixel): the others' sums are zero. A pixel's samples are those it has rendered whole,
/// so its sums are the same bits with or without the others.
///
/// Panics only if `camera`, `rect`, `range` or the mask's length is out of range (a caller bug).
#[allow(clippy::too_many_arguments)]
pub fn render_tile_sums_masked(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    range: SampleRange,
    mask: Option<&[bool]>,
    stop: Stop<'_>,
    aux: Option<&mut AuxTile>,
) -> Result<(Vec<PixelSum>, RayStats), Stopped> {
    let mut out = TileOut::Sums(vec![PixelSum::default(); (rect.width * rect.height) as usize]);
    let stats = render_tile_into(scene, camera, rect, settings, range, mask, stop, aux, &mut out)?;
    match out {
        TileOut::Sums(sums) => Ok((sums, stats)),
        TileOut::Film(_) => unreachable!("asked for sums"),
    }
}

/// The film of a tile of a camera that renders one sample a pixel (the sums' film, bit for bit:
/// [`PixelSum::film_of_one`]), with its features when `aux` is given.
fn render_one_sample_tile_until(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    stop: Stop<'_>,
    aux: Option<&mut AuxTile>,
) -> Result<(Vec<[f32; 3]>, RayStats), Stopped> {
    let mut out = TileOut::Film(vec![[0.0; 3]; (rect.width * rect.height) as usize]);
    let stats =
        render_tile_into(scene, camera, rect, settings, SampleRange::all(1), None, stop, aux, &mut out)?;
    match out {
        TileOut::Film(film) => Ok((film, stats)),
        TileOut::Sums(_) => unreachable!("asked for the film"),
    }
}

/// Where a tile's pixels go, each at its place in the tile (row by row): their sums, or, when
/// the camera renders one sample a pixel, straight their film values (no fixed-point sums to
/// make and read back: a sixth of a one-sample frame's work).
enum TileOut {
    Sums(Vec<PixelSum>),
    Film(Vec<[f32; 3]>),
}

impl TileOut {
    /// After sample `ls` of pixel (`x`, `y`) is added to `sum`: closes the block it ends, if
    /// it ends one (into `pixel`'s sums, or for one-sample pixels straight to the film), and
    /// when it is the last sample of the range (`end`) writes the pixel at its place in the
    /// tile and starts the next one. The pixel's index in the tile when it ended.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn close_sample(
        &mut self,
        pixel: &mut PixelSum,
        sum: &mut glam::DVec3,
        ls: u32,
        end: u32,
        rect: TileRect,
        x: u32,
        y: u32,
    ) -> Option<usize> {
        let done = ls + 1;
        // The sum of the block this sample ends, if it ends one.
        let mut block_sum = glam::DVec3::ZERO;
        if done.is_multiple_of(BLOCK) || done == end {
            if let TileOut::Sums(_) = self {
                pixel.add_block(ls / BLOCK, *sum);
            }
            block_sum = *sum;
            *sum = glam::DVec3::ZERO;
        }
        if done != end {
            return None;
        }
        let p = ((y - rect.y0) * rect.width + (x - rect.x0)) as usize;
        match self {
            TileOut::Sums(v) => v[p] = *pixel,
            // One sample a pixel: its only block.
            TileOut::Film(v) => v[p] = PixelSum::film_of_one(block_sum),
        }
        *pixel = PixelSum::default();
        Some(p)
    }
}

/// [`render_tile_sums_until`] into `out`, which holds an entry for every pixel of the tile.
#[allow(clippy::too_many_arguments)]
fn render_tile_into(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    range: SampleRange,
    mask: Option<&[bool]>,
    stop: Stop<'_>,
    aux: Option<&mut AuxTile>,
    out: &mut TileOut,
) -> Result<RayStats, Stopped> {
    // Where the world tree is walked sixteen lanes at a time (hosts with AVX-512), the groups
    // go in pairs: both groups' camera rays are made, then walk the tree together
    // ([`Tracer::camera_hits_pair`]), then each group is shaded in turn. Each ray's hit is its
    // own, so this changes no bit. (A background image is looked up per group: its scenes
    // trace one group at a time.) The loop is compiled for each way, so that the other keeps
    // its own layout.
    if crate::geometry::bvh8::pair_walks_at_once() && scene.background_texture.is_none() {
        render_tile_groups::<true>(scene, camera, rect, settings, range, mask, stop, aux, out)
    } else {
        render_tile_groups::<false>(scene, camera, rect, settings, range, mask, stop, aux, out)
    }
}

/// [`render_tile_into`], the groups' camera rays walked in pairs (`PAIRED`) or one group at a
/// time.
#[allow(clippy::too_many_arguments)]
fn render_tile_groups<const PAIRED: bool>(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    range: SampleRange,
    mask: Option<&[bool]>,
    stop: Stop<'_>,
    mut aux: Option<&mut AuxTile>,
    out: &mut TileOut,
) -> Result<RayStats, Stopped> {
    let cam = &scene.cameras[camera];
    assert!(
        rect.x0 + rect.width <= cam.width && rect.y0 + rect.height <= cam.height,
        "tile outside the frame"
    );
    let pixels = (rect.width * rect.height) as usize;
    assert!(mask.is_none_or(|m| m.len() == pixels), "a mask of the tile's pixels");
    assert!(aux.is_none() || mask.is_none(), "features come from every pixel");
    let seed = frame_seed(settings.seed, camera);
    let n = samples_per_pixel(scene, camera, settings);
    assert!(
        range.start.is_multiple_of(BLOCK) && range.start < range.end && range.end <= n,
        "bad sample range"
    );
    assert!(aux.is_none() || range.start == 0, "features come from the first block");
    assert!(
        matches!(out, TileOut::Sums(_)) || (n == 1 && range == SampleRange::all(1)),
        "film values straight from the samples of one-sample pixels only"
    );
    let aux_samples = n.min(BLOCK);
    let moving = scene.accel.instances.iter().any(|i| i.motion.is_some());
    let mut tracer = Tracer::new(scene);
    tracer.renderer = cam.renderer;
    if let Some(s) = settings.env_sampling {
        tracer.env_sampler = s;
    }
    if n >= HORIZON_SAMPLES {
        tracer.horizons = scene.horizons();
    }
    // The ray cone (and the footprint computed from it at every textured hit) only matters to
    // trilinear maps.
    if scene.textures.iter().any(|t| t.needs_footprint()) {
        tracer.spread = cam.pixel_spread;
    }
    let pixel_uv = glam::DVec2::new(1.0 / cam.width as f64, 1.0 / cam.height as f64);
    // Every pixel's entry is written once, at its place in the tile (row by row), in the order
    // the pixels are rendered (see `order` below).
    assert_eq!(
        match out {
            TileOut::Sums(v) => v.len(),
            TileOut::Film(v) => v.len(),
        },
        pixels,
        "an entry a pixel"
    );
    if let Some(a) = aux.as_deref_mut() {
        a.albedo = vec![[0.0; 3]; pixels];
        a.normal = vec![[0.0; 3]; pixels];
    }
    // A pixel's samples go in groups of up to eight: their camera rays are traced together
    // (nearly parallel, they share their nodes), then each sample is shaded. When a pixel
    // renders fewer than eight samples here, a group takes the samples of several pixels in
    // a row instead, so the packet stays full; a background image is looked up per pixel, so
    // its scenes keep one pixel a group. Each sample's dimensions keep their order and each
    // pixel's samples are summed in their order, so the grouping changes no bit. A group never
    // straddles two blocks of a pixel (eight divides the block).
    let per_pixel = range.end - range.start;
    let across_pixels = per_pixel < GROUP as u32 && scene.background_texture.is_none();
    // A path-traced camera of a scene whose paths go side by side takes up to `POOL_GROUPS`
    // groups at once: after each vertex their paths are gathered into full groups
    // ([`Tracer::trace_path_groups`]). Every path computes what it computes alone, so this
    // changes no bit either. A background image is looked up per group, so its scenes trace
    // one group at a time.
    let pooled = tracer.pools_paths() && scene.background_texture.is_none();
    let paired = PAIRED;
    let batch = if pooled {
        POOL_GROUPS
    } else if paired {
        2
    } else {
        1
    };
    // The groups' rays, camera hits and samplers, each lane's pixel and sample index, and
    // their radiance, made once per tile: every group writes the entries it reads
    // (`camera_hits` writes a hit or `None` to each of its slots), and a group's arrays zeroed
    // anew cost more stores than all the rest of its setup.
    let blank = CameraGroup {
        rays: [Ray::new(cam.position, glam::DVec3::Z); GROUP],
        hits: [None; GROUP],
        n: 0,
        samplers: std::array::from_fn(|_| Sampler::new(seed, 0, 0, 0)),
    };
    let mut groups = vec![blank; batch];
    let mut lanes = vec![[(0u32, 0u32, 0u32); GROUP]; batch];
    let mut radiance = vec![[glam::DVec3::ZERO; GROUP]; batch];
    let mut drawn = [[[0.0; GROUP]; 2]; 3];
    // The group's camera rays side by side (a pinhole's directions made in place); paired,
    // each group's.
    let mut wide_one = RayLanes::from_origin(cam.position, &[[0.0; GROUP]; 3], GROUP);
    let mut wides = if paired { vec![wide_one.clone(); batch] } else { Vec::new() };
    // The pixel being summed: its position, samples so far, and features.
    let mut pixel = PixelSum::default();
    let mut sum = glam::DVec3::ZERO;
    let (mut albedo, mut normal) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
    // The order the tile's pixels are rendered in, as their positions in the frame: only those
    // of the mask when there is one; at one sample a pixel, when a group takes eight pixels,
    // blocks of 4x4 pixels, so that a group is a compact bundle of rays (a 4x2 half, whose rays
    // share more of their nodes than a row of eight), and so is a pair of groups; else row by
    // row. With two or four samples a group's pixels are row neighbours either way. Every
    // pixel's value is its own, so the order changes no bit.
    let in_frame = |(x, y): (u32, u32)| (rect.x0 + x, rect.y0 + y);
    let order: Vec<(u32, u32)> = match mask {
        Some(m) => (0..pixels as u32)
            .filter(|&i| m[i as usize])
            .map(|i| in_frame((i % rect.width, i / rect.width)))
            .collect(),
        None if across_pixels && per_pixel == 1 => {
            block_order(rect.width, rect.height).into_iter().map(in_frame).collect()
        }
        None => (0..rect.height).flat_map(|y| (0..rect.width).map(move |x| in_frame((x, y)))).collect(),
    };
    // The (pixel, sample) pairs of the tile in order: pixel by pixel, a pixel's samples in turn
    // (one sample a pixel is the common case, and needs no division).
    let total = order.len() as u64 * u64::from(per_pixel);
    let at = |i: u64| {
        let (p, s) =
            if per_pixel == 1 { (i, 0) } else { (i / u64::from(per_pixel), i % u64::from(per_pixel)) };
        let (x, y) = order[p as usize];
        (x, y, range.start + s as u32)
    };
    // The frame's part of the pixels' sampler keys, hashed once a tile.
    let frame_key = FrameKey::new(seed);
    // The pixel whose sampler and first requests' seeds the groups of one pixel use.
    let unseeded = Sampler::new(seed, 0, 0, 0);
    let mut seeded = (u32::MAX, u32::MAX, PixelSeeds::of(&unseeded), unseeded);
    let mut since_check = STOP_CHECK_EVERY;
    let mut next = 0u64;
    while next < total {
        if since_check >= STOP_CHECK_EVERY {
            stop.check()?;
            since_check = 0;
        }
        let mut made = 0;
        while made < batch && next < total {
            let (x, y, s) = at(next);
            let group = if across_pixels {
                (total - next).min(GROUP as u64) as usize
            } else {
                (range.end - s).min(GROUP as u32) as usize
            };
            if let Some(k) = scene.background_texture {
                // The background image is stretched over the frame with pixel (x, y) at
                // u = x / width, v = y / height (its corner, not its centre): measured,
                // galactica_static matches at 55.9 dB this way and 35.5 dB with centres.
                let uv = glam::DVec2::new(x as f64 / cam.width as f64, y as f64 / cam.height as f64);
                tracer.background = scene.textures[k as usize].background(uv, pixel_uv);
            }
            let (cg, lanes) = (&mut groups[made], &mut lanes[made]);
            cg.n = group;
            // The group's sample values first, then its rays: the rays' square roots and
            // divisions are one chain each, and with nothing else in between the processor
            // overlaps the eight chains.
            // Dimensions in a fixed order: pixel position, lens, time, then shading; the group
            // draws each of the first ones for its eight samples at once. One sample goes
            // through the pixel centre (§4.5); several are stratified over the pixel by the
            // sampler, like every other dimension. The requests in use are drawn together
            // (their scrambles overlap), each as two coordinates of eight lanes.
            let count = usize::from(n > 1) + usize::from(cam.lens.is_some()) + usize::from(moving);
            if across_pixels {
                // The current lane's pixel and its sampler, made once per pixel of the group.
                let mut keyed: Option<(u32, u32, Sampler)> = None;
                for (i, (sampler, lane)) in
                    cg.samplers.iter_mut().zip(lanes.iter_mut()).enumerate().take(group)
                {
                    let (lx, ly, ls) = at(next + i as u64);
                    let pixel_sampler = match &keyed {
                        Some((kx, ky, k)) if (*kx, *ky) == (lx, ly) => k,
                        _ => &keyed.insert((lx, ly, frame_key.sampler(lx, ly, 0))).2,
                    };
                    *sampler = pixel_sampler.with_sample(ls);
                    *lane = (lx, ly, ls);
                }
                let samplers_in_use = &mut cg.samplers[..group];
                match count {
                    3 => drawn = Sampler::next_2d_groups::<3>(samplers_in_use),
                    2 => drawn[..2].copy_from_slice(&Sampler::next_2d_groups::<2>(samplers_in_use)),
                    1 => drawn[..1].copy_from_slice(&Sampler::next_2d_groups::<1>(samplers_in_use)),
                    _ => {}
                }
            } else {
                // Samples s.. of one pixel: the lanes differ by their sample index alone. The
                // pixel's sampler and the seeds of its first requests are made once for all
                // its groups, and the group's values come from the seeds (the same values).
                if (seeded.0, seeded.1) != (x, y) {
                    let pixel_sampler = frame_key.sampler(x, y, 0);
                    seeded = (x, y, PixelSeeds::of(&pixel_sampler), pixel_sampler);
                }
                for (i, sampler) in cg.samplers.iter_mut().enumerate().take(group) {
                    *sampler = seeded.3.with_sample(s + i as u32);
                    sampler.skip_to(count as u64);
                }
                let seeds = &seeded.2;
                match count {
                    3 => drawn = seeds.draw::<3>(s),
                    2 => drawn[..2].copy_from_slice(&seeds.draw::<2>(s)),
                    1 => drawn[..1].copy_from_slice(&seeds.draw::<1>(s)),
                    _ => {}
                }
                // Each lane's pixel and sample when the features read them lane by lane; else
                // the last lane's alone, which closes the group's samples below.
                if aux.is_some() {
                    for (i, lane) in lanes.iter_mut().enumerate().take(group) {
                        *lane = (x, y, s + i as u32);
                    }
                } else {
                    lanes[group - 1] = (x, y, s + group as u32 - 1);
                }
            }
            let mut drawn_next = drawn.iter();
            // The next drawn request if this one is wanted, else the fixed value.
            let mut take = |wanted: bool, otherwise: f64| match wanted.then(|| drawn_next.next()).flatten() {
                Some(v) => *v,
                None => [[otherwise; GROUP]; 2],
            };
            let film = take(n > 1, 0.5);
            let lens = take(cam.lens.is_some(), 0.5);
            let time = take(moving, 0.0)[0];
            // All eight lanes, used or not: loops of fixed length the compiler vectorises.
            let (px, py): ([f64; GROUP], [f64; GROUP]) = if across_pixels {
                (
                    std::array::from_fn(|i| f64::from(lanes[i.min(group - 1)].0)),
                    std::array::from_fn(|i| f64::from(lanes[i.min(group - 1)].1)),
                )
            } else {
                ([f64::from(x); GROUP], [f64::from(y); GROUP])
            };
            let pinhole = cam.lens.is_none();
            let wide = if paired { &mut wides[made] } else { &mut wide_one };
            if pinhole {
                wide.refill_dirs(group, |d| cam.ray_dirs8(&px, &py, &film[0], &film[1], d));
            } else {
                let (pixel, film, lens) = ((&px, &py), (&film[0], &film[1]), (&lens[0], &lens[1]));
                wide.refill(group, |o, d| cam.lens_rays8(pixel, film, lens, o, d));
            }
            cg.rays = std::array::from_fn(|i| {
                let mut ray = Ray::new(if pinhole { cam.position } else { wide.origin(i) }, wide.dir(i));
                // A 1-D request is the first coordinate of the 2-D one.
                ray.time = time[i];
                ray
            });
            if !paired {
                tracer.camera_hits_lanes(&cg.rays[..group], wide, &mut cg.hits[..group]);
                if !pooled {
                    radiance[made] =
                        tracer.trace_primary_group(&cg.rays, &cg.hits[..group], &mut cg.samplers[..group]);
                }
            }
            since_check += group as u32;
            next += group as u64;
            made += 1;
        }
        if paired {
            for (pair, wides) in groups[..made].chunks_mut(2).zip(wides.chunks(2)) {
                match pair {
                    [a, b] => tracer.camera_hits_pair(
                        [&a.rays[..a.n], &b.rays[..b.n]],
                        [&wides[0], &wides[1]],
                        [&mut a.hits[..a.n], &mut b.hits[..b.n]],
                    ),
                    [a] => tracer.camera_hits_lanes(&a.rays[..a.n], &wides[0], &mut a.hits[..a.n]),
                    _ => unreachable!("chunks of one or two"),
                }
            }
            if !pooled {
                for (cg, radiance) in groups.iter_mut().zip(radiance.iter_mut()).take(made) {
                    *radiance =
                        tracer.trace_primary_group(&cg.rays, &cg.hits[..cg.n], &mut cg.samplers[..cg.n]);
                }
            }
        }
        if pooled {
            tracer.trace_path_groups(&mut groups[..made], &mut radiance[..made]);
        }
        for ((cg, lanes), radiance) in groups.iter().zip(&lanes).zip(&radiance).take(made) {
            if !across_pixels && aux.is_none() {
                // The group's samples are consecutive samples of one pixel within one block
                // (eight divides the block and a range starts at a whole block): summed in
                // their order as below, the block's and the pixel's ends checked once.
                match cam.clamp_samples {
                    None => radiance[..cg.n].iter().for_each(|r| sum += *r),
                    Some(c) => radiance[..cg.n].iter().for_each(|r| sum += r.min(glam::DVec3::splat(c))),
                }
                let (lx, ly, ls) = lanes[cg.n - 1];
                out.close_sample(&mut pixel, &mut sum, ls, range.end, rect, lx, ly);
                continue;
            }
            for i in 0..cg.n {
                let (lx, ly, ls) = lanes[i];
                if aux.is_some() && ls < aux_samples {
                    let a = tracer.aux(&cg.rays[i], cg.hits[i]);
                    albedo += a.albedo;
                    normal += a.normal;
                }
                sum += match cam.clamp_samples {
                    None => radiance[i],
                    // 2019 `ClampSamples`: each sample's radiance clamped before the average.
                    Some(c) => radiance[i].min(glam::DVec3::splat(c)),
                };
                if let Some(p) = out.close_sample(&mut pixel, &mut sum, ls, range.end, rect, lx, ly) {
                    if let Some(a) = aux.as_deref_mut() {
                        a.albedo[p] = film_value(albedo / f64::from(aux_samples));
                        a.normal[p] = film_value(normal / f64::from(aux_samples));
                    }
                    (albedo, normal) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
                }
            }
        }
    }
    Ok(tracer.stats)
}

/// The pixels of a `width` x `height` tile, as (x, y) from its corner, in blocks of 4x4: the
/// blocks row by row, each block's pixels row by row (blocks at the right and bottom edges are
/// cut).
fn block_order(width: u32, height: u32) -> Vec<(u32, u32)> {
    let mut order = Vec::with_capacity((width * height) as usize);
    for by in (0..height).step_by(4) {
        for bx in (0..width).step_by(4) {
            for y in by..(by + 4).min(height) {
                for x in bx..(bx + 4).min(width) {
                    order.push((x, y));
                }
            }
        }
    }
    order
}

/// Renders a whole camera with rayon over tiles. `progress(done, total)` is called after every
/// finished tile (from worker threads).
pub fn render_camera(
    scene: &Scene,
    camera: usize,
    tile_size: u32,
    settings: &RenderSettings,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Image, RayStats) {
    let f = render_camera_inner(scene, camera, tile_size, settings, None, false, progress);
    (f.image, f.stats)
}

/// A frame's features for a denoiser: albedo and normal images beside its colour.
#[derive(Clone, Debug, PartialEq)]
pub struct AuxImages {
    pub albedo: Image,
    pub normal: Image,
}

/// [`render_camera`] that also renders the frame's [`AuxImages`] (the same colour bits).
pub fn render_camera_with_aux(
    scene: &Scene,
    camera: usize,
    tile_size: u32,
    settings: &RenderSettings,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Image, AuxImages, RayStats) {
    let f = render_camera_inner(scene, camera, tile_size, settings, None, true, progress);
    (f.image, f.aux.expect("asked for"), f.stats)
}

/// How a frame's tiles are rendered pass by pass: passes of `pass_samples` samples (whole
/// blocks), and optionally a noise target that stops pixels early
/// ([`crate::passes::active_pixels`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PassPlan {
    pub pass_samples: u32,
    pub noise_target: Option<f64>,
}

/// What one tile of a pass-by-pass render got: the most samples any of its pixels has, each
/// pixel's samples (row by row), and its last noise estimate ([`crate::passes::tile_error_of`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TileOutcome {
    pub rect: TileRect,
    pub samples: u32,
    pub pixel_samples: Vec<u32>,
    pub error: Option<f64>,
}

impl TileOutcome {
    /// The samples of all its pixels together.
    pub fn total_samples(&self) -> u64 {
        self.pixel_samples.iter().map(|&n| u64::from(n)).sum()
    }
}

/// A frame rendered pass by pass: the image, its features when asked for, and each tile's
/// samples and noise (row by row, as [`tiles`] cuts them).
#[derive(Clone, Debug)]
pub struct PassedFrame {
    pub image: Image,
    pub aux: Option<AuxImages>,
    pub tiles: Vec<TileOutcome>,
    pub stats: RayStats,
}

/// Renders one tile pass after pass as the farm does, each pass for the pixels
/// [`crate::passes::active_pixels`] keeps going, until none is; the tile's film (each pixel the
/// average of its own samples), its features (from the first pass), samples and noise.
pub fn render_tile_passes(
    scene: &Scene,
    camera: usize,
    rect: TileRect,
    settings: &RenderSettings,
    plan: PassPlan,
    mut aux: Option<&mut AuxTile>,
) -> (Vec<[f32; 3]>, TileOutcome, RayStats) {
    let n = samples_per_pixel(scene, camera, settings);
    let pixels = (rect.width * rect.height) as usize;
    if n == 1 {
        // One pass of one sample, too few for a noise estimate (`tile_error` of one sample).
        let (film, stats) =
            match render_one_sample_tile_until(scene, camera, rect, settings, Stop::NEVER, aux) {
                Ok(r) => r,
                Err(_) => unreachable!("Stop::NEVER never stops"),
            };
        return (film, TileOutcome { rect, samples: 1, pixel_samples: vec![1; pixels], error: None }, stats);
    }
    let mut sums = Vec::new();
    let mut counts = vec![0u32; pixels];
    let mut mask: Option<Vec<bool>> = None;
    let mut stats = RayStats::default();
    for k in 0..crate::passes::pass_count(n, plan.pass_samples) {
        let range = crate::passes::pass_range(n, plan.pass_samples, k);
        let first = if k == 0 { aux.as_deref_mut() } else { None };
        let (pass, st) = match render_tile_sums_masked(
            scene,
            camera,
            rect,
            settings,
            range,
            mask.as_deref(),
            Stop::NEVER,
            first,
        ) {
            Ok(r) => r,
            Err(_) => unreachable!("Stop::NEVER never stops"),
        };
        if k == 0 {
            // The first pass renders every pixel: its sums are the tile's so far.
            sums = pass;
            counts.fill(range.end);
        } else {
            for (i, (acc, p)) in sums.iter_mut().zip(&pass).enumerate() {
                if mask.as_ref().is_none_or(|m| m[i]) {
                    acc.add(p);
                    counts[i] = range.end;
                }
            }
        }
        stats.add(&st);
        let next =
            crate::passes::active_pixels(&sums, &counts, rect.width, n, plan.pass_samples, plan.noise_target);
        if !next.contains(&false) {
            mask = None;
        } else if next.contains(&true) {
            mask = Some(next);
        } else {
            break;
        }
    }
    let film = sums.iter().zip(&counts).map(|(s, &c)| s.film(c)).collect();
    let error = crate::passes::tile_error_of(&sums, &counts);
    let samples = counts.iter().copied().max().unwrap_or(0);
    (film, TileOutcome { rect, samples, pixel_samples: counts, error }, stats)
}

/// Renders a whole camera pass by pass ([`render_tile_passes`] on every tile, rayon over tiles):
/// with a noise target, the same bits as a farm render of the same tile size and pass size.
/// Without one it is [`render_camera`]'s image.
pub fn render_camera_passes(
    scene: &Scene,
    camera: usize,
    tile_size: u32,
    settings: &RenderSettings,
    plan: PassPlan,
    with_aux: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> PassedFrame {
    render_camera_inner(scene, camera, tile_size, settings, Some(plan), with_aux, progress)
}

fn render_camera_inner(
    scene: &Scene,
    camera: usize,
    tile_size: u32,
    settings: &RenderSettings,
    plan: Option<PassPlan>,
    with_aux: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> PassedFrame {
    // The tiles' samples and noise are the pass-by-pass caller's; the others drop them.
    let keep_tiles = plan.is_some();
    let cam = &scene.cameras[camera];
    let n = samples_per_pixel(scene, camera, settings);
    // A single pass of every sample unless asked otherwise.
    let plan =
        plan.unwrap_or(PassPlan { pass_samples: crate::passes::round_to_blocks(n), noise_target: None });
    let mut image = Image::new(cam.width, cam.height);
    let mut aux = with_aux.then(|| AuxImages {
        albedo: Image::new(cam.width, cam.height),
        normal: Image::new(cam.width, cam.height),
    });
    // Each tile goes into the frame as soon as it is rendered and its buffers are freed, so
    // the allocator hands the same memory to the next tile. Kept to the end, every tile's
    // buffers would be fresh pages (100 MB at 3840x2160), each page a fault into the kernel:
    // about a fifth of a one-sample render. The threads put their tiles with no lock (a lock
    // would be held through the first touches of the frame's pages, and the other thread
    // would wait out those faults); the tiles are disjoint, so the order changes no bit.
    let frame = FrameTiles::new(&mut image, tile_size);
    let features = aux
        .as_mut()
        .map(|a| (FrameTiles::new(&mut a.albedo, tile_size), FrameTiles::new(&mut a.normal, tile_size)));
    let done = AtomicUsize::new(0);
    let total = frame.rects.len();
    let results: Vec<(Option<TileOutcome>, RayStats)> = (0..total)
        .into_par_iter()
        .map(|i| {
            let r = frame.rects[i];
            let mut tile_aux = with_aux.then(AuxTile::default);
            let (px, outcome, st) = render_tile_passes(scene, camera, r, settings, plan, tile_aux.as_mut());
            frame.put(i, &px);
            if let (Some((albedo, normal)), Some(t)) = (&features, &tile_aux) {
                albedo.put(i, &t.albedo);
                normal.put(i, &t.normal);
            }
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            (keep_tiles.then_some(outcome), st)
        })
        .collect();
    drop((frame, features));
    let mut stats = RayStats::default();
    let mut outcomes = Vec::with_capacity(if keep_tiles { results.len() } else { 0 });
    for (outcome, st) in results {
        stats.add(&st);
        outcomes.extend(outcome);
    }
    PassedFrame { image, aux, tiles: outcomes, stats }
}

#[cfg(test)]
mod tests {

    #[test]
    fn the_film_keeps_finite_values_only() {
        use glam::DVec3;
        assert_eq!(film_value(DVec3::new(0.25, -1.0, 1e30)), [0.25, -1.0, 1e30]);
        // Beyond f32's range: the largest value of the sign; NaN: 0.
        assert_eq!(film_value(DVec3::new(1e300, -1e300, f64::NAN)), [f32::MAX, f32::MIN, 0.0]);
        assert_eq!(film_value(DVec3::new(f64::INFINITY, f64::NEG_INFINITY, 0.0)), [f32::MAX, f32::MIN, 0.0]);
    }

    use super::*;
    use crate::assets::FsResolver;
    use crate::scene::load::load_scene_str;

    /// A 4x4 diffuse triangle asking for `samples` samples per pixel.
    fn small_scene(samples: u32) -> Scene {
        let xml = format!(
            r#"<Scene><Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>4 4</ImageResolution>
              <NumSamples>{samples}</NumSamples><ImageName>a.png</ImageName></Camera></Cameras>
            <Lights><AmbientLight>25 25 25</AmbientLight></Lights>
            <Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance></Material></Materials>
            <VertexData>-1 -1 0  1 -1 0  0 1 0</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh></Objects></Scene>"#
        );
        load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() }).unwrap()
    }

    /// One pixel whose left half sees a surface of radiance 25 (ambient) and right half nothing,
    /// 16 stratified samples, the camera's `ClampSamples` given by `clamp`.
    fn half_covered_pixel(clamp: &str) -> Result<[f32; 3], crate::error::SceneError> {
        let xml = format!(
            r#"<Scene><Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>1 1</ImageResolution>
              <NumSamples>16</NumSamples>{clamp}<ImageName>a.png</ImageName></Camera></Cameras>
            <Lights><AmbientLight>25 25 25</AmbientLight></Lights>
            <Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance></Material></Materials>
            <VertexData>-20 -20 0  0 -20 0  0 20 0  -20 20 0</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3  1 3 4</Faces></Mesh></Objects></Scene>"#
        );
        let scene =
            load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })?;
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        Ok(render_tile(&scene, 0, rect, &RenderSettings::default()).0[0])
    }

    /// A square of two `Triangle`s (radiance 25) straight ahead of a one-pixel camera, each
    /// triangle with `motion`, seen with 400 samples.
    fn square_of_triangles(motion: &str) -> [f32; 3] {
        let xml = format!(
            r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-0.001 0.001 -0.001 0.001</NearPlane><NearDistance>1</NearDistance><ImageResolution>1 1</ImageResolution>
              <NumSamples>400</NumSamples><ImageName>a.png</ImageName></Camera></Cameras>
            <Lights><AmbientLight>25 25 25</AmbientLight></Lights>
            <Materials><Material id="1"><AmbientReflectance>1 1 1</AmbientReflectance></Material></Materials>
            <VertexData>-1 -1 -5  1 -1 -5  1 1 -5  -1 1 -5</VertexData>
            <Objects><Triangle id="1"><Material>1</Material><Indices>1 2 3</Indices>{motion}</Triangle>
              <Triangle id="2"><Material>1</Material><Indices>1 3 4</Indices>{motion}</Triangle></Objects></Scene>"#
        );
        let scene = load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
            .unwrap();
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        render_tile(&scene, 0, rect, &RenderSettings::default()).0[0]
    }

    /// `MotionBlur` on a `Triangle` moves it over the exposure, as it moves meshes: a square
    /// sliding 4 units to the right leaves the pixel's line of sight once its left edge (at
    /// x = -1) passes it, a quarter of the way through, so the pixel gets a quarter of 25.
    #[test]
    fn moving_triangles_cover_a_pixel_for_part_of_the_exposure() {
        assert_eq!(square_of_triangles(""), [25.0; 3]);
        let p = square_of_triangles("<MotionBlur>4 0 0</MotionBlur>");
        assert!(p.iter().all(|&c| (c - 6.25).abs() < 0.5), "{p:?}");
    }

    /// 2019 `ClampSamples`: each sample is clamped before the average (8 samples of 25 clamped
    /// to 10 and 8 of 0 give 5, where clamping the average would give 10).
    #[test]
    fn clamp_samples_clamps_each_sample_before_the_average() {
        assert_eq!(half_covered_pixel("").unwrap(), [12.5; 3]);
        assert_eq!(half_covered_pixel("<ClampSamples>10</ClampSamples>").unwrap(), [5.0; 3]);
        assert_eq!(half_covered_pixel("<ClampSamples>100</ClampSamples>").unwrap(), [12.5; 3]);
        for bad in ["0", "-1"] {
            let e = half_covered_pixel(&format!("<ClampSamples>{bad}</ClampSamples>")).unwrap_err();
            assert!(
                e.to_string()
                    .contains("t.xml:3: <Camera id=\"1\"> / <ClampSamples>: ClampSamples must be positive"),
                "{e}"
            );
        }
    }

    #[test]
    fn a_raised_flag_or_a_passed_deadline_stops_a_tile_that_would_run_for_days() {
        // 10^12 samples a pixel: only a stop inside the pixel's sample loop ends this.
        let scene = small_scene(1_000_000_000);
        let settings = RenderSettings { samples: Some(u32::MAX), ..RenderSettings::default() };
        let rect = TileRect { x0: 0, y0: 0, width: 4, height: 4 };
        let flag = AtomicBool::new(false);
        std::thread::scope(|s| {
            s.spawn(|| {
                std::thread::sleep(std::time::Duration::from_millis(50));
                flag.store(true, Ordering::Relaxed);
            });
            let stop = Stop { flag: Some(&flag), deadline: None };
            assert_eq!(render_tile_until(&scene, 0, rect, &settings, stop).err(), Some(Stopped::Cancelled));
        });
        let stop = Stop { flag: None, deadline: Some(Instant::now() + std::time::Duration::from_millis(50)) };
        assert_eq!(render_tile_until(&scene, 0, rect, &settings, stop).err(), Some(Stopped::OutOfTime));
    }

    #[test]
    fn a_stop_that_never_fires_changes_no_bit() {
        let scene = small_scene(8);
        let settings = RenderSettings::default();
        let rect = TileRect { x0: 0, y0: 0, width: 4, height: 4 };
        let flag = AtomicBool::new(false);
        let far = Instant::now() + std::time::Duration::from_secs(3600);
        let stopped =
            render_tile_until(&scene, 0, rect, &settings, Stop { flag: Some(&flag), deadline: Some(far) });
        let (plain, _) = render_tile(&scene, 0, rect, &settings);
        let (px, _) = stopped.expect("not stopped");
        assert_eq!(px, plain);
        assert!(plain.iter().any(|p| p[0] > 0.0), "the triangle is lit");
    }

    /// A 2x1 frame: the left pixel sees a red diffuse wall straight ahead (z = -5), the right
    /// one a perfect mirror turned 45 degrees that shows a green wall to the side; `sky` is the
    /// background.
    fn features_scene(mirror_diffuse: &str) -> Scene {
        let xml = format!(
            r#"<Scene><BackgroundColor>0 0 0</BackgroundColor>
            <Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-0.02 0.02 -0.01 0.01</NearPlane><NearDistance>1</NearDistance><ImageResolution>2 1</ImageResolution>
              <NumSamples>16</NumSamples><ImageName>a.png</ImageName></Camera></Cameras>
            <Lights><AmbientLight>10 10 10</AmbientLight><PointLight id="1"><Position>0 0 0</Position><Intensity>100 100 100</Intensity></PointLight></Lights>
            <Materials><Material id="1"><AmbientReflectance>0.1 0 0</AmbientReflectance><DiffuseReflectance>0.8 0 0</DiffuseReflectance></Material>
              <Material id="2" type="mirror"><DiffuseReflectance>{mirror_diffuse}</DiffuseReflectance><MirrorReflectance>1 1 1</MirrorReflectance></Material>
              <Material id="3"><DiffuseReflectance>0 0.5 0</DiffuseReflectance><SpecularReflectance>0 0.25 0</SpecularReflectance></Material></Materials>
            <VertexData>-1 -1 -5  0 -1 -5  0 1 -5  -1 1 -5
              0 -1 -4.5  1 -1 -5.5  1 1 -5.5  0 1 -4.5
              10 -50 -100  10 -50 100  10 50 100  10 50 -100</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3  1 3 4</Faces></Mesh>
              <Mesh id="2"><Material>2</Material><Faces>5 6 7  5 7 8</Faces></Mesh>
              <Mesh id="3"><Material>3</Material><Faces>9 11 10  9 12 11</Faces></Mesh></Objects></Scene>"#
        );
        load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() }).unwrap()
    }

    #[test]
    fn features_are_the_first_surface_past_perfect_mirrors_and_change_no_colour_bit() {
        let scene = features_scene("0 0 0");
        let rect = TileRect { x0: 0, y0: 0, width: 2, height: 1 };
        let settings = RenderSettings::default();
        let (plain, _) = render_tile(&scene, 0, rect, &settings);
        let (px, aux, _) = render_tile_with_aux_until(&scene, 0, rect, &settings, Stop::NEVER).unwrap();
        assert_eq!(px, plain, "asking for features changes no colour bit");
        // Left: the red wall's diffuse colour, its normal towards the camera.
        assert_eq!(aux.albedo[0], [0.8, 0.0, 0.0]);
        assert_eq!(aux.normal[0], [0.0, 0.0, 1.0]);
        // Right: the mirror shows the green wall (diffuse + specular), whose normal faces -x.
        let (a, n) = (aux.albedo[1], aux.normal[1]);
        assert!((a[1] - 0.75).abs() < 1e-6 && a[0] == 0.0 && a[2] == 0.0, "{a:?}");
        assert!((n[0] + 1.0).abs() < 1e-6 && n[1].abs() < 1e-6 && n[2].abs() < 1e-6, "{n:?}");
        // A mirror with a diffuse part is a surface of its own: the chain stops there.
        let scene = features_scene("0.2 0.2 0.2");
        let (_, aux, _) = render_tile_with_aux_until(&scene, 0, rect, &settings, Stop::NEVER).unwrap();
        assert_eq!(aux.albedo[1], [1.0, 1.0, 1.0], "0.2 + mirror 1, clamped");
        let n = aux.normal[1];
        assert!(n[2] > 0.7 && n[0] > 0.7, "the mirror's own normal, towards the camera: {n:?}");
    }

    #[test]
    fn rays_that_leave_the_scene_have_the_background_as_albedo_and_no_normal() {
        let scene = small_scene(4);
        // The triangle covers the middle of the 4x4 frame; the corner pixel sees the background.
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        let (_, aux, _) =
            render_tile_with_aux_until(&scene, 0, rect, &RenderSettings::default(), Stop::NEVER).unwrap();
        assert_eq!(aux.albedo[0], [0.0; 3]);
        assert_eq!(aux.normal[0], [0.0; 3]);
    }

    /// The triangle's scene at 100 samples lit by a point light through a lens (so every
    /// sample differs), rendered whole and pass by pass in several pass sizes and tile sizes.
    #[test]
    fn passes_of_any_size_add_up_to_the_whole_renders_bits() {
        let xml = r#"<Scene><Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>6 5</ImageResolution>
              <NumSamples>100</NumSamples><FocusDistance>3</FocusDistance><ApertureSize>0.4</ApertureSize><ImageName>a.exr</ImageName></Camera></Cameras>
            <Lights><PointLight id="1"><Position>0.3 0.2 3</Position><Intensity>30 20 10</Intensity></PointLight></Lights>
            <Materials><Material id="1"><DiffuseReflectance>0.8 0.7 0.6</DiffuseReflectance><SpecularReflectance>0.3 0.3 0.3</SpecularReflectance><PhongExponent>20</PhongExponent></Material></Materials>
            <VertexData>-1 -1 0  1 -1 0  0 1 0</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 2 3</Faces></Mesh></Objects></Scene>"#;
        let scene =
            load_scene_str(xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() }).unwrap();
        let settings = RenderSettings::default();
        let (whole, _) = render_camera(&scene, 0, 4, &settings, &|_, _| {});
        assert!(whole.pixels.iter().any(|p| p[0] > 0.0) && whole.pixels.iter().any(|p| p[0] == 0.0));
        for (pass_samples, tile) in [(16, 4), (48, 2), (32, 6), (100, 3)] {
            let plan = PassPlan { pass_samples, noise_target: None };
            let f = render_camera_passes(&scene, 0, tile, &settings, plan, false, &|_, _| {});
            assert_eq!(f.image.pixels, whole.pixels, "passes of {pass_samples}, tiles of {tile}");
            assert!(f.tiles.iter().all(|t| t.samples == 100));
        }
        // One tile's passes summed by hand, in the reverse order: the same bits again.
        let rect = TileRect { x0: 1, y0: 1, width: 3, height: 2 };
        let mut sums = vec![PixelSum::default(); 6];
        for k in (0..crate::passes::pass_count(100, 32)).rev() {
            let range = crate::passes::pass_range(100, 32, k);
            let (pass, _) =
                render_tile_sums_until(&scene, 0, rect, &settings, range, Stop::NEVER, None).unwrap();
            sums.iter_mut().zip(&pass).for_each(|(a, p)| a.add(p));
        }
        let (tile, _) = render_tile(&scene, 0, rect, &settings);
        assert_eq!(sums.iter().map(|s| s.film(100)).collect::<Vec<_>>(), tile);
    }

    /// A frame's colour and features are put together tile by tile as the tiles finish: any
    /// tile size and thread count give the bits of the frame rendered as one tile.
    #[test]
    fn a_frames_features_and_colour_do_not_depend_on_its_tiles() {
        let scene = features_scene("0.2 0.2 0.2");
        let settings = RenderSettings::default();
        let (whole, whole_aux, _) = render_camera_with_aux(&scene, 0, 64, &settings, &|_, _| {});
        // Both pixels have a surface: the features are not the zeroed buffer.
        assert!(whole_aux.albedo.pixels.iter().all(|p| p.iter().any(|&c| c != 0.0)));
        assert!(whole_aux.normal.pixels.iter().all(|p| p.iter().any(|&c| c != 0.0)));
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let (tiled, tiled_aux, _) =
            pool.install(|| render_camera_with_aux(&scene, 0, 1, &settings, &|_, _| {}));
        assert_eq!(tiled.pixels, whole.pixels);
        assert_eq!(tiled_aux, whole_aux);
        // Each tile's own render is its region of the frame.
        for x0 in 0..2 {
            let rect = TileRect { x0, y0: 0, width: 1, height: 1 };
            let (px, aux, _) = render_tile_with_aux_until(&scene, 0, rect, &settings, Stop::NEVER).unwrap();
            assert_eq!(px[0], whole.pixels[x0 as usize]);
            assert_eq!(
                (aux.albedo[0], aux.normal[0]),
                (whole_aux.albedo.pixels[x0 as usize], whole_aux.normal.pixels[x0 as usize])
            );
        }
    }

    /// Tiles put from two threads in any order give what `Image::put_tile` gives.
    #[test]
    fn frame_tiles_put_every_tile_in_its_place() {
        let (w, h) = (37, 23);
        let value = |x: u32, y: u32| [x as f32, y as f32, (x * y) as f32];
        let mut expected = Image::new(w, h);
        for r in tiles(w, h, 8) {
            let px: Vec<[f32; 3]> =
                (0..r.height).flat_map(|y| (0..r.width).map(move |x| value(r.x0 + x, r.y0 + y))).collect();
            expected.put_tile(r, &px);
        }
        let mut image = Image::new(w, h);
        let frame = FrameTiles::new(&mut image, 8);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        pool.install(|| {
            (0..frame.rects.len()).into_par_iter().rev().for_each(|i| {
                let r = frame.rects[i];
                let px: Vec<[f32; 3]> = (0..r.height)
                    .flat_map(|y| (0..r.width).map(move |x| value(r.x0 + x, r.y0 + y)))
                    .collect();
                frame.put(i, &px);
            })
        });
        drop(frame);
        assert_eq!(image, expected);
    }

    #[test]
    #[should_panic(expected = "tile 1 put twice")]
    fn frame_tiles_refuse_a_tile_put_twice() {
        let mut image = Image::new(4, 2);
        let frame = FrameTiles::new(&mut image, 2);
        frame.put(1, &[[1.0; 3]; 4]);
        frame.put(1, &[[2.0; 3]; 4]);
    }

    #[test]
    #[should_panic(expected = "a value a pixel of the tile")]
    fn frame_tiles_refuse_a_tile_of_the_wrong_size() {
        let mut image = Image::new(4, 2);
        FrameTiles::new(&mut image, 2).put(0, &[[1.0; 3]; 5]);
    }

    /// A one-sample tile's film comes straight from its samples: the same bits as its sums'.
    #[test]
    fn one_sample_film_values_are_the_sums_film() {
        let scene = features_scene("0.2 0.2 0.2");
        let settings = RenderSettings { samples: Some(1), ..RenderSettings::default() };
        let rect = TileRect { x0: 0, y0: 0, width: 2, height: 1 };
        let (sums, _) =
            render_tile_sums_until(&scene, 0, rect, &settings, SampleRange::all(1), Stop::NEVER, None)
                .unwrap();
        let film: Vec<[f32; 3]> = sums.iter().map(|s| s.film(1)).collect();
        assert!(film.iter().all(|p| p[0] > 0.0 || p[1] > 0.0), "both pixels see something: {film:?}");
        assert_eq!(render_tile(&scene, 0, rect, &settings).0, film);
        let (px, aux, _) = render_tile_with_aux_until(&scene, 0, rect, &settings, Stop::NEVER).unwrap();
        assert_eq!(px, film);
        let mut passed = AuxTile::default();
        let plan = PassPlan { pass_samples: 16, noise_target: Some(0.1) };
        let (px, outcome, _) = render_tile_passes(&scene, 0, rect, &settings, plan, Some(&mut passed));
        assert_eq!((px, passed), (film, aux));
        assert_eq!(outcome, TileOutcome { rect, samples: 1, pixel_samples: vec![1, 1], error: None });
    }

    #[test]
    fn the_block_order_takes_every_pixel_of_a_tile_once() {
        for (w, h) in [(32, 32), (17, 5), (1, 1), (3, 7), (8, 2), (8, 4)] {
            let order = block_order(w, h);
            assert!(order.iter().all(|&(x, y)| x < w && y < h));
            let mut seen: Vec<u32> = order.iter().map(|&(x, y)| y * w + x).collect();
            seen.sort_unstable();
            assert_eq!(seen, (0..w * h).collect::<Vec<_>>(), "{w}x{h}");
        }
        // Full blocks: sixteen pixels in four rows of four, so each half of eight is two rows.
        let first: Vec<u32> = block_order(8, 4)[..16].iter().map(|&(x, y)| y * 8 + x).collect();
        assert_eq!(first, [0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26, 27]);
    }

    #[test]
    fn tiles_cover_frame_exactly_once() {
        for (w, h, t) in [(800, 600, 64), (17, 5, 4), (1, 1, 16), (64, 64, 64)] {
            let ts = tiles(w, h, t);
            let mut seen = vec![0u8; (w * h) as usize];
            for r in &ts {
                assert!(r.width <= t && r.height <= t);
                for y in r.y0..r.y0 + r.height {
                    for x in r.x0..r.x0 + r.width {
                        seen[(y * w + x) as usize] += 1;
                    }
                }
            }
            assert!(seen.iter().all(|&c| c == 1));
        }
    }
}
