//! The groups that [`super::paths::PathLanes::trace_groups`] advances: up to eight paths each,
//! by axis then lane, wherever their camera samples came from. After each step, [`gather`]
//! hands back the paths that ended and moves the others into as few groups as hold them, so
//! the next step's lanes and packets are full.

use glam::DVec3;

use crate::geometry::{Axes, HitLanes, SurfaceHit};
use crate::math::{Ray, lanes};
use crate::sampler::{GROUP_LANES, Sampler, SamplerLanes};

const N: usize = GROUP_LANES;

/// The state of a group's paths besides their radiance, by axis then lane: what a specular
/// vertex's bounce changes (`paths::specular_bounces`).
#[derive(Clone, Copy)]
pub(super) struct Paths {
    /// Throughput.
    pub(super) beta: Axes,
    /// The product of the BRDF values of the path's diffuse and glossy vertices so far: the
    /// course roulette's potential.
    pub(super) potential: Axes,
    /// The lanes' rays (unused lanes repeat a living one's).
    pub(super) o: Axes,
    pub(super) d: Axes,
    /// With multiple importance sampling, where each lane's last BRDF bounce left from and
    /// the density it was drawn with: what an object light it hits weighs.
    pub(super) from: Axes,
    pub(super) drawn: [f64; N],
    /// The lanes whose last vertex was the camera or a specular one: lights they reach count
    /// in full, not having been sampled there.
    pub(super) specular: u32,
    /// The lanes inside a dielectric, and its absorption coefficient (Beer's law).
    pub(super) inside: u32,
    pub(super) absorb: [DVec3; N],
    /// The bounces that count towards the depth limit (`ShadingRules::path_depth`).
    pub(super) counted: [u32; N],
}

/// A group of up to eight camera samples for [`super::paths::PathLanes::trace_groups`]: their
/// rays, the surfaces the rays found first (`None` for a miss) and their samplers; lanes `n..`
/// are unused.
#[derive(Clone)]
pub struct CameraGroup {
    pub rays: [Ray; N],
    pub hits: [Option<SurfaceHit>; N],
    pub n: usize,
    pub samplers: [Sampler; N],
}

/// The groups of paths that [`super::paths::PathLanes::trace_groups`] works in, kept from call
/// to call.
#[derive(Default)]
pub struct Pool(pub(super) Vec<Lanes>);

/// Up to eight paths between two vertices, wherever their camera samples came from.
pub(super) struct Lanes {
    pub(super) p: Paths,
    /// Radiance so far, by axis then lane.
    pub(super) l: Axes,
    /// What the lanes' last rays found.
    pub(super) found: HitLanes,
    /// The lanes whose paths go on.
    pub(super) alive: u32,
    /// The lanes holding a path whose radiance has not been handed back (`alive`, and those
    /// that ended at the last vertex).
    pub(super) held: u32,
    /// Each lane's camera sample: group times eight plus lane, in the caller's groups.
    pub(super) slot: [u32; N],
    pub(super) samplers: SamplerLanes,
}

impl Lanes {
    /// Lanes with no path, ready for [`Self::restart`].
    pub(super) fn blank() -> Lanes {
        let zero = [[0.0; N]; 3];
        Lanes {
            p: Paths {
                beta: zero,
                potential: zero,
                o: zero,
                d: zero,
                from: zero,
                drawn: [0.0; N],
                specular: 0,
                inside: 0,
                absorb: [DVec3::ZERO; N],
                counted: [0; N],
            },
            l: zero,
            found: HitLanes {
                mask: 0,
                point: zero,
                normal: zero,
                t: [0.0; N],
                material: [0; N],
                instance: [0; N],
            },
            alive: 0,
            held: 0,
            slot: [0; N],
            samplers: SamplerLanes::new(&std::array::from_fn(|_| Sampler::new(0, 0, 0, 0))),
        }
    }

    /// The paths of camera group number `i` (which has one at least), before their first
    /// vertex. What a path reads before it writes (where a bounce left from and its density,
    /// the absorption inside glass) is left as it was.
    pub(super) fn restart(&mut self, g: &CameraGroup, i: usize) {
        let n = g.n;
        let p = &mut self.p;
        (p.beta, p.potential, self.l) = ([[1.0; N]; 3], [[1.0; N]; 3], [[0.0; N]; 3]);
        (p.specular, p.inside, p.counted) = (u32::MAX, 0, [0; N]);
        (self.alive, self.held) = ((1u32 << n) - 1, (1u32 << n) - 1);
        self.slot = std::array::from_fn(|k| (i * N + k) as u32);
        self.samplers = SamplerLanes::new(&g.samplers);
        // Unused lanes repeat the last ray.
        let f = &mut self.found;
        f.mask = 0;
        for k in 0..N {
            let r = &g.rays[k.min(n - 1)];
            for a in 0..3 {
                p.o[a][k] = r.origin[a];
                p.d[a][k] = r.dir[a];
            }
            if let Some(h) = g.hits[k].filter(|_| k < n) {
                f.mask |= 1 << k;
                f.material[k] = h.material;
                f.instance[k] = h.instance;
                f.t[k] = h.t;
                for a in 0..3 {
                    f.point[a][k] = h.point[a];
                    f.normal[a][k] = h.geo_normal[a];
                }
            }
        }
    }

    /// Puts the path of lane `k` of `from` into the free lane `j` of `self`.
    fn take(&mut self, j: usize, from: &Lanes, k: usize) {
        #[cfg(test)]
        tests::MOVED.with(|c| c.set(c.get() + 1));
        let (p, q) = (&mut self.p, &from.p);
        for a in 0..3 {
            p.beta[a][j] = q.beta[a][k];
            p.potential[a][j] = q.potential[a][k];
            p.o[a][j] = q.o[a][k];
            p.d[a][j] = q.d[a][k];
            p.from[a][j] = q.from[a][k];
            self.l[a][j] = from.l[a][k];
        }
        p.drawn[j] = q.drawn[k];
        let bit = 1u32 << j;
        p.specular = (p.specular & !bit) | (((q.specular >> k) & 1) << j);
        p.inside = (p.inside & !bit) | (((q.inside >> k) & 1) << j);
        p.absorb[j] = q.absorb[k];
        p.counted[j] = q.counted[k];
        self.slot[j] = from.slot[k];
        self.samplers.take(j, &from.samplers, k);
        let (f, h) = (&mut self.found, &from.found);
        for a in 0..3 {
            f.point[a][j] = h.point[a][k];
            f.normal[a][j] = h.normal[a][k];
        }
        (f.t[j], f.material[j], f.instance[j]) = (h.t[k], h.material[k], h.instance[k]);
        f.mask = (f.mask & !bit) | (((h.mask >> k) & 1) << j);
        self.alive |= bit;
        self.held |= bit;
    }
}

/// After a step of the groups in `pool` (their misses, or a vertex): hands the radiance and
/// samplers of the paths that ended back to their camera samples (`out`, `cams`), then moves
/// the paths that go on into the first groups of `pool`, so that `ceil(paths / 8)` groups hold
/// them, each one path at least. Gives how many groups that is.
pub(super) fn gather(pool: &mut [Lanes], cams: &mut [CameraGroup], out: &mut [[DVec3; N]]) -> usize {
    let mut total = 0;
    for g in pool.iter_mut() {
        for k in lanes(g.held & !g.alive) {
            let (i, j) = (g.slot[k] as usize / N, g.slot[k] as usize % N);
            out[i][j] = lane(&g.l, k);
            cams[i].samplers[j] = g.samplers.get(k);
        }
        g.held = g.alive;
        total += g.alive.count_ones() as usize;
    }
    let full = total.div_ceil(N);
    let (head, tail) = pool.split_at_mut(full);
    let mut dst = 0;
    for src in tail {
        for k in lanes(src.alive) {
            while head[dst].alive == (1 << N) - 1 {
                dst += 1;
            }
            let j = (!head[dst].alive).trailing_zeros() as usize;
            head[dst].take(j, src, k);
        }
        (src.alive, src.held) = (0, 0);
    }
    full
}

/// Lane `k` of `v` as a vector.
#[inline(always)]
pub(super) fn lane(v: &Axes, k: usize) -> DVec3 {
    DVec3::new(v[0][k], v[1][k], v[2][k])
}

#[cfg(test)]
pub(super) mod tests {
    use std::cell::Cell;

    thread_local! {
        /// How many paths [`super::gather`] moved from one group to another on this thread.
        pub static MOVED: Cell<u64> = const { Cell::new(0) };
    }
}
