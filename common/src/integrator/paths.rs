//! Path tracing groups of camera samples side by side: the paths of up to eight camera samples
//! a group advance one vertex at a time together, so that their bounce and shadow rays are
//! traced as packets ([`crate::geometry::Accel::closest_lanes`],
//! [`crate::geometry::Accel::occluded_lanes`]), their lights are sampled side by side, and their
//! random numbers are drawn together when they stand at the same dimension. Many groups advance
//! together ([`PathLanes::trace_groups`]): between steps, the paths that go on are gathered into
//! as few groups as hold them ([`super::pool::gather`]), so lanes stay busy as paths end. The
//! state of the paths (radiance, throughput, rays, hits) is kept by axis, then lane.
//!
//! Every path gets exactly the value, random numbers and ray counts that the tracer's
//! `trace_primary` gives it alone: per lane the operations are the same and in the same order,
//! each ray query answers what the single ray's query answers, and a lane draws its numbers
//! from its own sampler in its own order. The group a path travels in changes when the work is
//! done, never what it computes, so a tile renders to the same bits whatever its size.
//!
//! The lanes take the scenes whose paths stay simple ([`fits`]), with any of the path tracer's
//! estimators (lights found by bounces alone, or next-event estimation of every light or of
//! one a vertex, with or without multiple importance sampling; either roulette or none): no
//! texture maps; point and object lights only; flat meshes and spheres that
//! [`crate::geometry::Accel::lanes_fit`]. Any other scene's paths go one by one. Diffuse and
//! glossy vertices bounce side by side; mirror, conductor and dielectric vertices (whose paths
//! then differ in what they draw, and in which bounces count towards the depth) bounce one
//! lane at a time, the lanes still sharing the packets of their next rays.

// Loops run over lanes and axes by index: each step reads and writes several arrays of the
// same lane side by side, which is what the compiler turns into vector code.
#![allow(clippy::needless_range_loop)]

use glam::DVec3;

use super::bounces::{Arrival, brdf_chance, density, scatter};
use super::direct::{BounceDensity, LightWeights, ONE_LIGHT_REQUESTS, light_pdf, power_heuristic};
use super::pool::{CameraGroup, Lanes, Paths, Pool, gather, lane};
use crate::geometry::{Axes, HitLanes, SurfaceHit};
use crate::lights::{EmitterShape, ObjectLight};
use crate::material::{Material, MaterialKind, MatteForm, MatteSlot};
use crate::math::{Ray, lane_words, lanes, pick, sincos_turns, word};
use crate::sampler::{GROUP_LANES, Sampler, SamplerLanes};
use crate::scene::Scene;
use crate::scene::records::{MAX_RECURSION_DEPTH_LIMIT, PathParams, Roulette};

const N: usize = GROUP_LANES;

/// `M` requests' numbers of a group's lanes, by request, coordinate and lane
/// ([`SamplerLanes::next_2d`]).
type Drawn<const M: usize> = [[[f64; N]; 2]; M];

/// Each lane's material and its matte form, if it has one.
struct Shading<'m> {
    mats: [&'m Material; N],
    matte: [&'m MatteSlot; N],
}

impl Shading<'_> {
    /// Lane `k`'s [`Material::reflectance`] at normal `n`, from `wi` towards `wo`.
    #[inline(always)]
    fn reflectance(&self, k: usize, n: DVec3, wi: DVec3, wo: DVec3) -> DVec3 {
        match self.matte[k] {
            MatteSlot { none: true, .. } => self.mats[k].reflectance(n, wi, wo),
            MatteSlot { matte, .. } => matte.at(n.dot(wi)),
        }
    }
}

/// Each of `scene`'s materials' [`MatteSlot`], by index, when [`PathLanes::trace`] traces
/// its paths (see the module's documentation); `None` when they go one by one. Every path
/// estimator takes the lanes, so this depends on the scene alone, and is worked out once per
/// scene, on the first call.
pub fn fits(scene: &Scene) -> Option<&[MatteSlot]> {
    let mattes = scene.path_lanes.get_or_init(|| {
        let fit = scene.env_light.is_none()
            && scene.extra_env_lights.is_empty()
            && scene.area_lights.is_empty()
            && scene.directional_lights.is_empty()
            && scene.spot_lights.is_empty()
            && scene.accel.lanes_fit()
            && scene.accel.instances.iter().all(|i| scene.materials.get(i.material as usize).is_some());
        fit.then(|| scene.materials.iter().map(|m| MatteSlot::from(m.matte())).collect())
    });
    mattes.as_deref()
}

/// Ray counts, by kind (what the tracer's `RayStats` adds them to).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub primary: u64,
    pub shadow: u64,
    pub secondary: u64,
}

/// Paths of one scene traced side by side (see the module's documentation).
pub struct PathLanes<'a> {
    pub scene: &'a Scene,
    /// Each material's [`MatteSlot`] ([`fits`]).
    pub mattes: &'a [MatteSlot],
    /// What rays that miss everything see (the tracer's background for the current pixel).
    pub background: DVec3,
    /// The rays traced so far.
    pub counts: Counts,
}

impl<'a> PathLanes<'a> {
    /// What the tracer's `trace_primary` gives each of a group of camera samples
    /// (`hits.len()` of the eight rays in `rays`, with their samplers) in a scene that
    /// [`fits`], the paths side by side: [`Self::trace_groups`] of one group.
    pub fn trace(
        &mut self,
        pool: &mut Pool,
        rays: &[Ray; N],
        hits: &[Option<SurfaceHit>],
        params: PathParams,
        samplers: &mut [Sampler],
    ) -> [DVec3; N] {
        let n = hits.len();
        if n == 0 {
            return [DVec3::ZERO; N];
        }
        let mut group = CameraGroup {
            rays: *rays,
            hits: std::array::from_fn(|k| hits.get(k).copied().flatten()),
            n,
            samplers: std::array::from_fn(|k| samplers[k.min(n - 1)].clone()),
        };
        let mut out = [[DVec3::ZERO; N]];
        self.trace_groups(pool, std::slice::from_mut(&mut group), params, &mut out);
        samplers.clone_from_slice(&group.samplers[..n]);
        out[0]
    }

    /// What the tracer's `trace_primary` gives each camera sample of `groups` (the first `n`
    /// lanes of each), into `out` (one entry a group, by lane); each lane's sampler moves on
    /// as it does alone. The groups' paths advance together, one vertex at a time: after each
    /// vertex, the paths that go on are gathered into as few groups as hold them, so that the
    /// lanes, packets and draws of the next vertex are as full as they can be (a path keeps
    /// its own state, numbers and order of operations wherever it goes).
    pub fn trace_groups(
        &mut self,
        pool: &mut Pool,
        groups: &mut [CameraGroup],
        params: PathParams,
        out: &mut [[DVec3; N]],
    ) {
        assert_eq!(groups.len(), out.len(), "one output a group");
        let tmin = self.scene.intersection_test_epsilon;
        let mut open = 0;
        for (i, g) in groups.iter().enumerate() {
            out[i] = [DVec3::ZERO; N];
            if g.n > 0 {
                #[cfg(test)]
                tests::PATH_GROUPS.with(|c| c.set(c.get() + 1));
                self.counts.primary += g.n as u64;
                if pool.0.len() == open {
                    pool.0.push(Lanes::blank());
                }
                pool.0[open].restart(g, i);
                open += 1;
            }
        }
        let pool = &mut pool.0[..open];
        let mut bounce = 0u32;
        loop {
            // The paths that found nothing end there; those that found a surface are gathered
            // before their vertex, then those that go on before their next rays.
            for g in &mut pool[..open] {
                self.misses(g);
            }
            open = gather(&mut pool[..open], groups, out);
            if open == 0 {
                break;
            }
            for g in &mut pool[..open] {
                self.vertex(g, bounce, params);
            }
            bounce += 1;
            open = gather(&mut pool[..open], groups, out);
            if open == 0 {
                break;
            }
            for g in &mut pool[..open] {
                fill_unused(&mut g.p.o, &mut g.p.d, g.alive);
                self.scene.accel.closest_lanes(&g.p.o, &g.p.d, g.alive, tmin, &mut g.found);
            }
        }
    }

    /// The paths of `g` whose last ray found nothing: they see the background, and end.
    #[inline(always)]
    fn misses(&self, g: &mut Lanes) {
        let misses = g.alive & !g.found.mask;
        if misses != 0 {
            let bg = self.background.to_array();
            let on = lane_words(misses);
            for a in 0..3 {
                for k in 0..N {
                    g.l[a][k] = pick(on[k], g.l[a][k] + g.p.beta[a][k] * bg[a], g.l[a][k]);
                }
            }
            g.alive &= g.found.mask;
        }
    }

    /// One vertex of the living paths of `g` (at `bounce` vertices from the camera): what they
    /// find there and what its lights bring, then the bounces of those that go on (the others
    /// leave `g.alive`).
    #[inline(never)]
    fn vertex(&mut self, g: &mut Lanes, bounce: u32, params: PathParams) {
        let scene = self.scene;
        let eps = scene.shadow_ray_epsilon;
        let max_bounces = match params.roulette {
            Roulette::Off => scene.max_recursion_depth,
            Roulette::Course | Roulette::Unbiased => MAX_RECURSION_DEPTH_LIMIT,
        };
        // Lights are sampled only with next-event estimation, and so one a vertex and multiple
        // importance sampling only with it.
        let nee = params.next_event;
        let (one_light, mis) = (params.one_light && nee, params.mis && nee);
        let (mut l, mut alive) = (g.l, g.alive);
        let (p, found, samplers) = (&mut g.p, &g.found, &mut g.samplers);
        'vertex: {
            if alive & p.inside != 0 {
                p.beta = absorbed(p.beta, &p.absorb, &found.t, alive & p.inside);
            }
            // Each lane's normal on the side the path arrives from, and where it looks from.
            let (mut ns, mut front) = ([[0.0; N]; 3], [false; N]);
            let mut wo = [DVec3::ZERO; N];
            let g = &found.normal;
            for k in 0..N {
                let cos = (p.d[0][k] * g[0][k]) + (p.d[1][k] * g[1][k]) + (p.d[2][k] * g[2][k]);
                front[k] = cos < 0.0;
                for a in 0..3 {
                    ns[a][k] = if front[k] { g[a][k] } else { -g[a][k] };
                }
                wo[k] = -lane(&p.d, k);
            }
            // Each lane's material; what it emits (after the camera or a specular vertex, or
            // without next-event estimation; with multiple importance sampling, weighed
            // against the light's own samples) and the ambient term.
            let mut local = [[0.0; N]; 3];
            // (Every lane's, from the materials of the hits: a lane that hit nothing has 0,
            // and some lane hit, so there is a material 0. Filled in place, not copied from a
            // default.)
            let sh = Shading {
                mats: std::array::from_fn(|k| &scene.materials[found.material[k] as usize]),
                matte: std::array::from_fn(|k| &self.mattes[found.material[k] as usize]),
            };
            // The lanes whose vertex is diffuse or glossy, and those whose lights are sampled
            // (every one but a dielectric seen from inside).
            let (mut plain, mut shaded) = (0u32, 0u32);
            let mut live = 0u32;
            for k in lanes(alive) {
                let mat = sh.mats[k];
                if (!nee || p.specular & (1 << k) != 0)
                    && let Some(le) = emitted(scene, found, &front, k)
                {
                    #[cfg(test)]
                    if bounce > 0 && !nee {
                        // Without next-event estimation, a light counts where a bounce finds it.
                        tests::LIGHTS_FOUND.with(|c| c.set(c.get() + 1));
                    }
                    for a in 0..3 {
                        local[a][k] += le[a];
                    }
                }
                if bounce == 0 {
                    let ambient = mat.ambient * scene.ambient_light;
                    for a in 0..3 {
                        local[a][k] += ambient[a];
                    }
                }
                plain |= u32::from(mat.kind == MaterialKind::Plain) << k;
                let lit = !(mat.kind == MaterialKind::Dielectric && p.inside & (1 << k) != 0);
                shaded |= u32::from(lit) << k;
                let reflects = mat.diffuse != DVec3::ZERO || mat.specular != DVec3::ZERO;
                live |= u32::from(lit && reflects) << k;
            }
            // The matte coefficients of the lanes whose lights are sampled or that bounce off a
            // diffuse or glossy surface, for both.
            let matte = MatteLanes::of(&sh, alive & (live | plain));
            // The lanes whose paths go on after this vertex.
            let mut continues = 0u32;
            if bounce < MAX_RECURSION_DEPTH_LIMIT {
                for k in 0..N {
                    continues |= u32::from(p.counted[k] < max_bounces) << k;
                }
            }
            // With `SampleOneLight`, each lane's light (drawn wherever lights are sampled,
            // whatever the material reflects).
            let picks = one_light.then(|| Picks::draw(scene, shaded, samplers));
            // With multiple importance sampling, the chance of a BRDF bounce that object
            // lights' samples are weighed against (none after the last vertex).
            let weigh = mis.then(|| {
                let mut chance = [0.0; N];
                for k in lanes(alive & continues & plain) {
                    chance[k] = 1.0;
                }
                if alive & continues & !plain != 0 {
                    specular_chances(&sh, &p.d, &ns, alive & continues & !plain, &mut chance);
                }
                (params.importance, chance)
            });
            if mis && bounce > 0 {
                let drawn_by = alive & !p.specular;
                weighed_emission(
                    scene,
                    found,
                    &p.d,
                    &front,
                    drawn_by,
                    (&p.from, &p.drawn),
                    one_light,
                    &mut local,
                );
            }
            // (Zero where nothing is reflected, added all the same: the same sums as alone.)
            let lit = if nee && live != 0 {
                self.lights_of_lanes(
                    &found.point,
                    &ns,
                    &wo,
                    (&sh, &matte),
                    live,
                    picks.as_ref(),
                    weigh,
                    samplers,
                )
            } else {
                [[0.0; N]; 3]
            };
            if params.roulette == Roulette::Course {
                // The course's roulette on the product of the path's BRDF values: a path that
                // ends keeps this vertex's light at the throughput it arrived with.
                let u = samplers.next_2d::<1>(alive);
                for k in lanes(alive) {
                    let q = lane(&p.potential, k).max_element().min(1.0);
                    if u[0][0][k] >= q {
                        for a in 0..3 {
                            l[a][k] += p.beta[a][k] * (local[a][k] + lit[a][k]);
                        }
                        alive &= !(1 << k);
                    } else {
                        for b in &mut p.beta {
                            b[k] /= q;
                        }
                    }
                }
            }
            let on = lane_words(alive);
            for a in 0..3 {
                for k in 0..N {
                    let local_k = local[a][k] + lit[a][k];
                    l[a][k] = pick(on[k], l[a][k] + p.beta[a][k] * local_k, l[a][k]);
                }
            }
            alive &= continues;
            if alive == 0 {
                break 'vertex;
            }
            // The diffuse and glossy lanes' bounces side by side.
            let bent = alive & plain;
            let u = samplers.next_2d::<1>(bent);
            let course = params.roulette == Roulette::Course;
            let mut brdf = [[0.0; N]; 3];
            let (wi, f, ok) =
                bounce_lanes(&ns, &wo, (&sh, &matte), params.importance, course.then_some(&mut brdf), &u);
            let bent = bent & ok;
            alive &= ok | !plain;
            let on = lane_words(bent);
            for a in 0..3 {
                for k in 0..N {
                    p.beta[a][k] = pick(on[k], p.beta[a][k] * f[a][k], p.beta[a][k]);
                    let origin = found.point[a][k] + eps * ns[a][k];
                    p.o[a][k] = pick(on[k], origin, p.o[a][k]);
                    p.d[a][k] = pick(on[k], wi[a][k], p.d[a][k]);
                }
            }
            for (k, c) in p.counted.iter_mut().enumerate() {
                *c += (bent >> k) & 1;
            }
            p.specular &= !bent;
            if course {
                for k in lanes(bent) {
                    for a in 0..3 {
                        p.potential[a][k] *= brdf[a][k];
                    }
                }
            }
            if mis {
                remember_bounces(
                    params.importance,
                    &found.point,
                    &ns,
                    &wi,
                    bent,
                    (&mut p.from, &mut p.drawn),
                );
            }
            // The mirror, conductor and dielectric lanes' bounces, one by one.
            let turned = alive & !plain;
            if turned != 0 {
                alive &= !turned;
                alive |= specular_bounces(scene, found, &sh, &ns, (&front, turned), params, p, samplers);
            }
            self.counts.secondary += u64::from(alive.count_ones());
            if params.roulette == Roulette::Unbiased && alive != 0 {
                // Roulette on the throughput, after the bounce.
                let u = samplers.next_2d::<1>(alive);
                for k in lanes(alive) {
                    let q = lane(&p.beta, k).max_element().min(1.0);
                    if u[0][0][k] >= q {
                        alive &= !(1 << k);
                    } else {
                        for b in &mut p.beta {
                            b[k] /= q;
                        }
                    }
                }
            }
            let mut dead = 0u32;
            for k in 0..N {
                let zero = (p.beta[0][k] == 0.0) & (p.beta[1][k] == 0.0) & (p.beta[2][k] == 0.0);
                let finite = p.beta[0][k].is_finite() & p.beta[1][k].is_finite() & p.beta[2][k].is_finite();
                dead |= u32::from(zero | !finite) << k;
            }
            alive &= !dead;
        }
        (g.l, g.alive) = (l, alive);
    }

    /// What [`super::direct::Lighting::reflected`] gives the points `x[k]` (normals `n[k]`,
    /// towards their viewers `wo[k]`, materials in `sh`) of the lanes in `live`, with the same
    /// numbers drawn and shadow rays counted: point lights, then object lights, in the scene's
    /// order. Each step runs over all eight lanes without branches (the compiler makes vector
    /// code of the square roots and divisions); lanes outside `live` compute values nobody
    /// reads. With `picks` (`SampleOneLight`), each lane samples only the light it picked, all
    /// lanes' shadow rays go through the tree as one packet, and a lane's light is divided by
    /// the probability of its pick, as the tracer's `one_light` does. With `weigh` (multiple
    /// importance sampling: whether bounces are cosine-distributed, and each lane's chance of
    /// a BRDF bounce), object lights' samples are weighed against the lanes' bounces.
    #[allow(clippy::too_many_arguments)]
    fn lights_of_lanes(
        &mut self,
        xs: &Axes,
        ns: &Axes,
        wo: &[DVec3; N],
        (sh, matte): (&Shading<'_>, &MatteLanes),
        live: u32,
        picks: Option<&Picks>,
        weigh: Option<(bool, [f64; N])>,
        samplers: &mut SamplerLanes,
    ) -> Axes {
        let scene = self.scene;
        let eps = scene.shadow_ray_epsilon;
        // The shadow rays' origins, by axis.
        let mut origin = [[0.0; N]; 3];
        for a in 0..3 {
            for k in 0..N {
                origin[a][k] = xs[a][k] + eps * ns[a][k];
            }
        }
        // With multiple importance sampling, whether bounces are cosine-distributed, each
        // lane's chance of a BRDF bounce and its chance of its light.
        let weigh = weigh.map(|(cosine, chance)| (cosine, chance, picks.map_or([1.0; N], |p| p.p)));
        let at = Vertices { xs, ns, origin: &origin, wo, sh, matte, weigh };
        let mut l = [[0.0; N]; 3];
        // The lanes that sample light number `i` (numbered as `LightChoice` numbers them).
        let lit_by = |i: usize| picks.map_or(live, |p| live & p.of(i));
        // Each light's shadow rays in turn; with `picks`, every lane's, whichever light it
        // aims at.
        let mut s = Shadows::NONE;
        for (i, light) in scene.point_lights.iter().enumerate() {
            let live = lit_by(i);
            if live == 0 {
                continue;
            }
            point_shadows(light, &at, live, &mut s);
            if picks.is_none() {
                self.shine(&at, &mut s, &mut l);
            }
        }
        let object_base = scene.first_object_light();
        for (i, light) in scene.object_lights.iter().enumerate() {
            let live = lit_by(object_base + i);
            if live == 0 {
                continue;
            }
            // One point per shading event; the numbers are drawn whatever the outcome (with
            // `picks`, drawn with the pick).
            let u = match picks {
                Some(p) => p.u,
                None => samplers.next_2d::<2>(live),
            };
            let Some(samples) = light_samples(light, xs, &u, live) else {
                // Another kind of light, one lane at a time.
                self.object_light_by_lane(light, &at, &u, live, &mut l);
                continue;
            };
            let degenerate = object_shadows(light, &samples, &at, live, &mut s);
            // A degenerate segment: counted as a shadow ray that is blocked.
            self.counts.shadow += u64::from(degenerate.count_ones());
            if picks.is_none() {
                self.shine(&at, &mut s, &mut l);
            }
        }
        if let Some(p) = picks {
            self.shine(&at, &mut s, &mut l);
            for k in lanes(p.mask & live) {
                for a in 0..3 {
                    l[a][k] /= p.p[k];
                }
            }
        }
        l
    }

    /// Traces the shadow rays of `s` from the vertices `at` and adds what the clear ones bring
    /// to `l`. Not inlined: its three calls would copy the reflectance's code into the
    /// vertex loop three times (a loop larger than the instruction cache ran 5 % slower).
    #[inline(never)]
    fn shine(&mut self, at: &Vertices<'_, '_>, s: &mut Shadows, l: &mut Axes) {
        let tmin = self.scene.intersection_test_epsilon;
        let clear = self.clear_lanes_of(at.origin, &mut s.dir, &s.far, s.mask, tmin);
        let f = at.matte.reflectance(at.sh, at.ns, &s.wi, at.wo);
        let on = lane_words(clear);
        for a in 0..3 {
            for k in 0..N {
                let add = l[a][k] + f[a][k] * s.e[a][k];
                l[a][k] = pick(on[k], add, l[a][k]);
            }
        }
    }

    /// An object light that is not a small mesh (a sphere, an ellipsoid, a mesh of more than
    /// 32 triangles) for the lanes of `live`, one at a time, with [`ObjectLight::sample`]; adds
    /// to `l`.
    #[inline(never)]
    fn object_light_by_lane(
        &mut self,
        light: &ObjectLight,
        at: &Vertices<'_, '_>,
        u: &Drawn<2>,
        live: u32,
        l: &mut Axes,
    ) {
        let (xs, ns, origin, wo, sh) = (at.xs, at.ns, at.origin, at.wo, at.sh);
        let mut dir = [[0.0; N]; 3];
        let mut far = [0.0; N];
        let mut wi = [DVec3::ZERO; N];
        let mut irradiance = [DVec3::ZERO; N];
        let mut mask = 0u32;
        for k in lanes(live) {
            let (u0, u1, u2) = (u[0][0][k], u[1][0][k], u[1][1][k]);
            let (x, n) = (lane(xs, k), lane(ns, k));
            if let Some(s) = light.sample(x, u0, u1, u2)
                && n.dot(s.wi) > 0.0
            {
                let to_light = x + s.wi * s.dist - lane(origin, k);
                let len = to_light.length();
                if len.is_nan() || len <= 0.0 {
                    self.counts.shadow += 1;
                } else {
                    wi[k] = s.wi;
                    irradiance[k] = match s.inv_pdf {
                        Some(inv) if at.weigh.is_some() => s.irradiance * at.weight(k, s.wi, inv),
                        _ => s.irradiance,
                    };
                    let unit = to_light / len;
                    for a in 0..3 {
                        dir[a][k] = unit[a];
                    }
                    far[k] = len * (1.0 - 1e-6);
                    mask |= 1 << k;
                }
            }
        }
        let clear = self.clear_lanes_of(origin, &mut dir, &far, mask, self.scene.intersection_test_epsilon);
        for k in lanes(clear) {
            let add = sh.reflectance(k, lane(ns, k), wi[k], wo[k]) * irradiance[k];
            for a in 0..3 {
                l[a][k] += add[a];
            }
        }
    }

    /// The lanes of `mask` whose shadow rays (from `origin`, along `dir`, up to `far`) are not
    /// blocked; counts the rays.
    #[inline]
    fn clear_lanes_of(&mut self, origin: &Axes, dir: &mut Axes, far: &[f64; N], mask: u32, tmin: f64) -> u32 {
        if mask == 0 {
            return 0;
        }
        self.counts.shadow += u64::from(mask.count_ones());
        let mut o = *origin;
        fill_unused(&mut o, dir, mask);
        mask & !self.scene.accel.occluded_lanes(&o, dir, far, mask, tmin)
    }
}

/// `beta` after Beer's law over the segments (of lengths `t`) of the lanes of `mask`, which are
/// inside a dielectric of absorption coefficient `absorb` (out of line: glass is rare).
#[inline(never)]
fn absorbed(mut beta: Axes, absorb: &[DVec3; N], t: &[f64; N], mask: u32) -> Axes {
    for k in lanes(mask) {
        let c = absorb[k];
        if c != DVec3::ZERO {
            let f = (-c * t[k]).exp();
            for a in 0..3 {
                beta[a][k] *= f[a];
            }
        }
    }
    beta
}

/// With multiple importance sampling, the chance of a BRDF bounce at the mirror, conductor
/// and dielectric vertices of the lanes of `mask` (arrived along `d`, normals `ns`), into
/// `chance`: 1 minus the mirror lobe's at mirrors and conductors, none at glass.
#[inline(never)]
fn specular_chances(sh: &Shading<'_>, d: &Axes, ns: &Axes, mask: u32, chance: &mut [f64; N]) {
    for k in lanes(mask) {
        chance[k] = brdf_chance(sh.mats[k], lane(d, k), lane(ns, k));
    }
}

/// The tracer's bounces at the mirror, conductor and dielectric vertices of the lanes of
/// `turned`, one lane at a time with `trace_path`'s operations (at `found`, normals `ns` on
/// the side each path arrives from, which is the front where `front`): each lane's new ray,
/// throughput, medium and counted bounces go into `p`. Gives the lanes whose paths go on.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn specular_bounces(
    scene: &Scene,
    found: &HitLanes,
    sh: &Shading<'_>,
    ns: &Axes,
    (front, turned): (&[bool; N], u32),
    params: PathParams,
    p: &mut Paths,
    samplers: &mut SamplerLanes,
) -> u32 {
    let (eps, sides) = (scene.shadow_ray_epsilon, scene.rules.dielectric_sides);
    let mis = params.mis && params.next_event;
    let mut on = 0u32;
    for k in lanes(turned) {
        let bit = 1u32 << k;
        let at = Arrival {
            x: lane(&found.point, k),
            n: lane(ns, k),
            shading_normal: lane(&found.normal, k),
            d: lane(&p.d, k),
            front: front[k],
            inside: p.inside & bit != 0,
        };
        let mut sampler = samplers.get(k);
        let next = scatter(sh.mats[k], &at, sides, params.importance, eps, &mut sampler);
        samplers.set(k, &sampler);
        let Some(next) = next else { continue };
        if let Some(w) = next.weight {
            for a in 0..3 {
                p.beta[a][k] *= w[a];
            }
        }
        if let Some((brdf, pdf)) = next.brdf {
            for a in 0..3 {
                p.potential[a][k] *= brdf[a];
            }
            if mis {
                p.drawn[k] = pdf;
                for a in 0..3 {
                    p.from[a][k] = at.x[a];
                }
            }
        }
        match next.refracted {
            Some(Some(absorption)) => {
                #[cfg(test)]
                tests::ENTRIES.with(|c| c.set(c.get() + 1));
                p.inside |= bit;
                p.absorb[k] = absorption;
            }
            Some(None) => p.inside &= !bit,
            None => {}
        }
        for a in 0..3 {
            p.o[a][k] = next.origin[a];
            p.d[a][k] = next.dir[a];
        }
        let specular = next.specular();
        p.specular = if specular { p.specular | bit } else { p.specular & !bit };
        p.counted[k] += scene.rules.path_depth.counts(specular, next.leaves());
        on |= bit;
        #[cfg(test)]
        tests::TURNS.with(|c| c.set(c.get() + 1));
    }
    on
}

/// What the surface lane `k` found emits towards it (the tracer's `emitted`): an object
/// light's radiance on its front side.
#[inline(always)]
fn emitted(scene: &Scene, found: &HitLanes, front: &[bool; N], k: usize) -> Option<DVec3> {
    let le = (*scene.instance_emission.get(found.instance[k] as usize)?)?;
    front[k].then_some(le)
}

/// With multiple importance sampling, what the object lights that the lanes of `alive` found
/// (at `found`, along `d`, on their front side where `front`) emit, weighed against the
/// lights' own samples from where the lanes' bounces left (`from`, with their densities
/// `drawn`); added to `local`.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn weighed_emission(
    scene: &Scene,
    found: &HitLanes,
    d: &Axes,
    front: &[bool; N],
    alive: u32,
    (from, drawn): (&Axes, &[f64; N]),
    one_light: bool,
    local: &mut Axes,
) {
    for k in lanes(alive) {
        if let Some(le) = emitted(scene, found, front, k) {
            let hit = (lane(&found.point, k), lane(&found.normal, k), found.instance[k]);
            let light = light_pdf(scene, lane(from, k), lane(d, k), hit, one_light);
            let add = le * power_heuristic(drawn[k], light);
            for a in 0..3 {
                local[a][k] += add[a];
            }
        }
    }
}

/// With multiple importance sampling, where the bounces of the lanes of `alive` leave from
/// (`points`) and the densities of their directions `wi` at normals `ns`.
#[inline(never)]
fn remember_bounces(
    cosine: bool,
    points: &Axes,
    ns: &Axes,
    wi: &Axes,
    alive: u32,
    (from, drawn): (&mut Axes, &mut [f64; N]),
) {
    for k in lanes(alive) {
        drawn[k] = density(cosine, lane(ns, k), lane(wi, k));
        for a in 0..3 {
            from[a][k] = points[a][k];
        }
    }
}

/// The vertices of a group's lanes where lights are sampled.
struct Vertices<'v, 'm> {
    /// The points, their normals (on the side the path arrives from) and the shadow rays'
    /// origins, by axis.
    xs: &'v Axes,
    ns: &'v Axes,
    origin: &'v Axes,
    /// Towards each lane's viewer.
    wo: &'v [DVec3; N],
    sh: &'v Shading<'m>,
    /// The lanes' matte coefficients (those of `live`, at least).
    matte: &'v MatteLanes,
    /// With multiple importance sampling, what object lights' samples are weighed against:
    /// whether bounces are cosine-distributed, each lane's chance of a BRDF bounce, and the
    /// probability with which each lane's light was chosen.
    weigh: Option<(bool, [f64; N], [f64; N])>,
}

impl Vertices<'_, '_> {
    /// The weight of lane `k`'s sample of an object light towards `wi` drawn with density
    /// `1 / inv_pdf` (1 without multiple importance sampling).
    #[inline(always)]
    fn weight(&self, k: usize, wi: DVec3, inv_pdf: f64) -> f64 {
        match &self.weigh {
            Some((cosine, chance, pick)) => {
                let bounce = BounceDensity { cosine: *cosine, chance: chance[k] };
                LightWeights { bounce, pick: pick[k] }.weight(lane(self.ns, k), wi, inv_pdf)
            }
            None => 1.0,
        }
    }
}

/// Shadow rays of a group's lanes towards lights, and what each brings when it is clear.
struct Shadows {
    /// Unit directions from the vertices' shadow-ray origins, by axis, and how far they go.
    dir: Axes,
    far: [f64; N],
    /// Unit directions from the vertices themselves towards the light, by axis: what the
    /// BRDFs see.
    wi: Axes,
    /// What the BRDF value is multiplied by, by axis.
    e: Axes,
    /// The lanes with a ray.
    mask: u32,
}

impl Shadows {
    const NONE: Shadows =
        Shadows { dir: [[0.0; N]; 3], far: [0.0; N], wi: [[0.0; N]; 3], e: [[0.0; N]; 3], mask: 0 };
}

/// The shadow rays of the lanes of `live` towards a point light, into those lanes of `s`:
/// `towards_lanes`' operations, lane by lane.
#[inline(always)]
fn point_shadows(light: &crate::lights::PointLight, at: &Vertices<'_, '_>, live: u32, s: &mut Shadows) {
    let (xs, ns, origin) = (at.xs, at.ns, at.origin);
    let p = light.position.to_array();
    let i = light.intensity.to_array();
    let mut cos = [0.0; N];
    for k in 0..N {
        let v = [p[0] - xs[0][k], p[1] - xs[1][k], p[2] - xs[2][k]];
        let d2 = (v[0] * v[0]) + (v[1] * v[1]) + (v[2] * v[2]);
        let recip = 1.0 / d2.sqrt();
        let w = [v[0] * recip, v[1] * recip, v[2] * recip];
        cos[k] = (ns[0][k] * w[0]) + (ns[1][k] * w[1]) + (ns[2][k] * w[2]);
        let t = [p[0] - origin[0][k], p[1] - origin[1][k], p[2] - origin[2][k]];
        let len = ((t[0] * t[0]) + (t[1] * t[1]) + (t[2] * t[2])).sqrt();
        let on = live & (1 << k) != 0;
        for a in 0..3 {
            s.dir[a][k] = if on { t[a] / len } else { s.dir[a][k] };
            s.wi[a][k] = if on { w[a] } else { s.wi[a][k] };
            s.e[a][k] = if on { i[a] / d2 } else { s.e[a][k] };
        }
        s.far[k] = if on { len } else { s.far[k] };
    }
    let lit = crate::math::lane_bits(cos.map(|c| c > 0.0));
    s.mask = (s.mask & !live) | (lit & live);
}

/// The shadow rays of the lanes of `live` towards their points of a light mesh, into those
/// lanes of `s`; the lanes whose segment is degenerate.
#[inline(always)]
fn object_shadows(
    light: &ObjectLight,
    samples: &LightLanes,
    at: &Vertices<'_, '_>,
    live: u32,
    s: &mut Shadows,
) -> u32 {
    let (xs, ns, origin) = (at.xs, at.ns, at.origin);
    let e = light.radiance.to_array();
    let (mut mask, mut degenerate) = (0u32, 0u32);
    for k in 0..N {
        // The shadow ray stops just short of the light's surface.
        let wi = &samples.wi;
        let cos = (ns[0][k] * wi[0][k]) + (ns[1][k] * wi[1][k]) + (ns[2][k] * wi[2][k]);
        let to: [f64; 3] = std::array::from_fn(|a| xs[a][k] + wi[a][k] * samples.dist[k] - origin[a][k]);
        let len = ((to[0] * to[0]) + (to[1] * to[1]) + (to[2] * to[2])).sqrt();
        let on = live & (1 << k) != 0;
        for a in 0..3 {
            s.dir[a][k] = if on { to[a] / len } else { s.dir[a][k] };
            s.wi[a][k] = if on { wi[a][k] } else { s.wi[a][k] };
            s.e[a][k] = if on { e[a] * samples.g[k] } else { s.e[a][k] };
        }
        s.far[k] = if on { len * (1.0 - 1e-6) } else { s.far[k] };
        let valid = samples.ok & (1 << k) != 0 && cos > 0.0;
        let bad = len.is_nan() || len <= 0.0;
        mask |= u32::from(valid && !bad) << k;
        degenerate |= u32::from(valid && bad) << k;
    }
    s.mask = (s.mask & !live) | (mask & live);
    if at.weigh.is_some() {
        for k in lanes(mask & live) {
            let w = at.weight(k, lane(&samples.wi, k), samples.g[k]);
            for a in 0..3 {
                s.e[a][k] *= w;
            }
        }
    }
    degenerate & live
}

/// `SampleOneLight`'s choice at one vertex of each lane: the light it samples, numbered as
/// [`crate::lights::choice::LightChoice`] numbers them, and the probability of that choice.
struct Picks {
    light: [usize; N],
    p: [f64; N],
    /// The lanes that picked a light (none is picked when no light has any power).
    mask: u32,
    /// Each lane's numbers for its light: the [`ONE_LIGHT_REQUESTS`] requests after the pick.
    u: Drawn<2>,
}

impl Picks {
    /// One number drawn for each lane of `alive`, the light it picks and the requests reserved
    /// for that light (the tracer's `one_light`), every lane's together whichever light it
    /// picks: the lanes' samplers stay at the same dimension.
    fn draw(scene: &Scene, alive: u32, samplers: &mut SamplerLanes) -> Picks {
        const { assert!(ONE_LIGHT_REQUESTS == 2, "the light's requests are drawn with the pick's") };
        let drawn = samplers.next_2d::<3>(alive);
        let mut picks = Picks { light: [usize::MAX; N], p: [0.0; N], mask: 0, u: [drawn[1], drawn[2]] };
        for k in lanes(alive) {
            if let Some((i, p)) = scene.light_choice.pick(drawn[0][0][k]) {
                picks.light[k] = i;
                picks.p[k] = p;
                picks.mask |= 1 << k;
            }
        }
        picks
    }

    /// The lanes that picked light `i`.
    fn of(&self, i: usize) -> u32 {
        (0..N).fold(0, |m, k| m | u32::from(self.light[k] == i) << k) & self.mask
    }
}

/// [`super::bounces::brdf_bounce`] of every lane (materials in `sh`), the directions side by side (a
/// loop of fixed length without branches, which the compiler makes vector code of): each
/// lane's direction, throughput factor and the mask of lanes for which they are defined; with
/// `brdf`, each lane's BRDF value there too (the course roulette's factor).
#[inline(always)]
fn bounce_lanes(
    ns: &Axes,
    wo: &[DVec3; N],
    (sh, matte): (&Shading<'_>, &MatteLanes),
    importance: bool,
    brdf: Option<&mut Axes>,
    u: &Drawn<1>,
) -> (Axes, Axes, u32) {
    let mut wi = [[0.0; N]; 3];
    let mut cos_t = [0.0; N];
    let mut pdf = [0.0; N];
    for k in 0..N {
        let nk = lane(ns, k);
        let (u1, u2) = (u[0][0][k], u[0][1][k]);
        // `orthonormal_pair`, its choice of component made by selection.
        let a = nk.abs();
        let cx = a.x <= a.y && a.x <= a.z;
        let cy = !cx && a.y <= a.z;
        let cz = !cx && !cy;
        let r =
            DVec3::new(if cx { 1.0 } else { nk.x }, if cy { 1.0 } else { nk.y }, if cz { 1.0 } else { nk.z });
        let t = r.cross(nk).normalize();
        let b = nk.cross(t);
        let (ct, pdf_over_cos) =
            if importance { ((1.0 - u1).sqrt(), 1.0 / std::f64::consts::PI) } else { (u1, 0.0) };
        let sin_t = (1.0 - ct * ct).max(0.0).sqrt();
        let (sp, cp) = sincos_turns(u2);
        let w = (sin_t * cp) * t + (sin_t * sp) * b + ct * nk;
        cos_t[k] = ct;
        pdf[k] = if importance { ct * pdf_over_cos } else { 1.0 / std::f64::consts::TAU };
        for ax in 0..3 {
            wi[ax][k] = w[ax];
        }
    }
    // Every lane's BRDF value side by side (the lanes below the surface, or unused, compute
    // one that is not kept).
    let f_cos = matte.reflectance(sh, ns, &wi, wo);
    let up: [u64; N] = std::array::from_fn(|k| word((cos_t[k] > 0.0) | cos_t[k].is_nan()));
    let mut f = [[0.0; N]; 3];
    for ax in 0..3 {
        for k in 0..N {
            f[ax][k] = pick(up[k], f_cos[ax][k] / pdf[k], 0.0);
        }
    }
    if let Some(brdf) = brdf {
        for ax in 0..3 {
            for k in 0..N {
                brdf[ax][k] = pick(up[k], f_cos[ax][k] / cos_t[k], brdf[ax][k]);
            }
        }
    }
    let mut ok = 0u32;
    for k in 0..N {
        // `fk != 0 && fk.is_finite()`, without short-circuits.
        let nonzero = (f[0][k] != 0.0) | (f[1][k] != 0.0) | (f[2][k] != 0.0);
        let finite = f[0][k].is_finite() & f[1][k].is_finite() & f[2][k].is_finite();
        ok |= u32::from((up[k] != 0) & nonzero & finite) << k;
    }
    (wi, f, ok)
}

/// Samples of a light mesh of at most 32 triangles for eight lanes (see [`light_samples`]).
struct LightLanes {
    /// Unit directions towards the points, by axis.
    wi: Axes,
    dist: [f64; N],
    /// `cos θ_y / (d² · p_A)`: what the light's radiance is multiplied by.
    g: [f64; N],
    /// The lanes where the sample is defined ([`ObjectLight::sample`] gives `Some`).
    ok: u32,
}

/// [`ObjectLight::sample`] from each lane `k` at `x[k]` (by axis), with lane `k`'s numbers in `u` (the
/// first of the first request picks a triangle, the second request the point), for a light of
/// at most 32 triangles, all lanes side by side with `sample`'s operations (its `irradiance` is
/// the light's radiance times `g`). `None` for other lights.
#[inline(always)]
fn light_samples(light: &ObjectLight, x: &Axes, u: &Drawn<2>, mask: u32) -> Option<LightLanes> {
    let EmitterShape::Triangles { tris, cdf, normals } = &light.shape else { return None };
    let &total = cdf.last().filter(|_| cdf.len() <= 32)?;
    // The first running area above each lane's target, counted.
    let target: [f64; N] = std::array::from_fn(|k| u[0][0][k] * total);
    let mut idx = [0usize; N];
    for &c in cdf {
        for k in 0..N {
            idx[k] += usize::from(c <= target[k]);
        }
    }
    let last = tris.len() - 1;
    let (mut p0, mut p1, mut p2, mut ny) = ([[0.0; N]; 3], [[0.0; N]; 3], [[0.0; N]; 3], [[0.0; N]; 3]);
    for k in 0..N {
        let i = idx[k].min(last);
        let [a, b, c] = tris[i];
        for ax in 0..3 {
            p0[ax][k] = a[ax];
            p1[ax][k] = b[ax];
            p2[ax][k] = c[ax];
            ny[ax][k] = normals[i][ax];
        }
    }
    let pdf_area = 1.0 / total;
    let mut out = LightLanes { wi: [[0.0; N]; 3], dist: [0.0; N], g: [0.0; N], ok: 0 };
    let mut ok = [false; N];
    for k in 0..N {
        let (u1, u2) = (u[1][0][k], u[1][1][k]);
        let s = u1.sqrt();
        let (w0, w1, w2) = (1.0 - s, s * (1.0 - u2), s * u2);
        let to: [f64; 3] = std::array::from_fn(|a| w0 * p0[a][k] + w1 * p1[a][k] + w2 * p2[a][k] - x[a][k]);
        let d2 = (to[0] * to[0]) + (to[1] * to[1]) + (to[2] * to[2]);
        let dist = d2.sqrt();
        let wi = [to[0] / dist, to[1] / dist, to[2] / dist];
        let cos_y = -((ny[0][k] * wi[0]) + (ny[1][k] * wi[1]) + (ny[2][k] * wi[2]));
        ok[k] = !(cos_y.is_nan() || cos_y <= 0.0 || d2.is_nan() || d2 <= 0.0 || !pdf_area.is_finite());
        out.g[k] = cos_y / (d2 * pdf_area);
        out.dist[k] = dist;
        for a in 0..3 {
            out.wi[a][k] = wi[a];
        }
    }
    out.ok = crate::math::lane_bits(ok) & mask;
    Some(out)
}

/// Each lane's matte reflectance coefficients by axis, for [`MatteLanes::reflectance`].
struct MatteLanes {
    c: Axes,
    zero: Axes,
    /// Lanes whose cosine is checked (zero below the surface), and those that add `zero`.
    checked: u32,
    plus_zero: u32,
    /// Lanes of `live` whose material has no matte form.
    other: u32,
}

impl MatteLanes {
    fn of(sh: &Shading<'_>, live: u32) -> Self {
        let mut m = MatteLanes { c: [[0.0; N]; 3], zero: [[0.0; N]; 3], checked: 0, plus_zero: 0, other: 0 };
        for k in 0..N {
            let MatteSlot { matte: mt, none } = sh.matte[k];
            for a in 0..3 {
                m.c[a][k] = mt.c[a];
                m.zero[a][k] = mt.zero[a];
            }
            m.checked |= u32::from(mt.form != MatteForm::Plain) << k;
            m.plus_zero |= u32::from(mt.form == MatteForm::CheckedPlusZero) << k;
            m.other |= u32::from(*none) << k;
        }
        m.other &= live;
        m
    }

    /// Each lane's [`Material::reflectance`] at normal `n`, from `wi` towards `wo`, by axis:
    /// [`crate::material::Matte::at`]'s operations side by side, and the lanes without a matte
    /// form one by one.
    #[inline(always)]
    fn reflectance(&self, sh: &Shading<'_>, n: &Axes, wi: &Axes, wo: &[DVec3; N]) -> Axes {
        let mut f = [[0.0; N]; 3];
        let (checked, plus) = (lane_words(self.checked), lane_words(self.plus_zero));
        let mut cos = [0.0; N];
        let mut below = [0u64; N];
        for k in 0..N {
            cos[k] = (n[0][k] * wi[0][k]) + (n[1][k] * wi[1][k]) + (n[2][k] * wi[2][k]);
            below[k] = checked[k] & word(cos[k].is_nan() | (cos[k] <= 0.0));
        }
        for a in 0..3 {
            for k in 0..N {
                let v = self.c[a][k] * cos[k];
                let v = pick(plus[k], v + self.zero[a][k], v);
                f[a][k] = pick(below[k], 0.0, v);
            }
        }
        for k in lanes(self.other) {
            let v = sh.mats[k].reflectance(lane(n, k), lane(wi, k), wo[k]);
            for a in 0..3 {
                f[a][k] = v[a];
            }
        }
        f
    }
}

/// The lanes outside `mask` (which is not empty) take the first lane of `mask`'s ray, so a
/// packet holds finite rays only.
#[inline(always)]
fn fill_unused(o: &mut Axes, d: &mut Axes, mask: u32) {
    let first = mask.trailing_zeros() as usize;
    let used = lane_words(mask);
    for a in 0..3 {
        let (of, df) = (o[a][first], d[a][first]);
        for k in 0..N {
            o[a][k] = pick(used[k], o[a][k], of);
            d[a][k] = pick(used[k], d[a][k], df);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::cell::Cell;

    use glam::DVec3;

    use crate::assets::FsResolver;
    use crate::math::Ray;
    use crate::sampler::{GROUP_LANES, Sampler};
    use crate::scene::load::load_scene_str;
    use crate::scene::records::{PathParams, Renderer, Roulette};

    thread_local! {
        /// How many groups [`super::PathLanes::trace`] traced on this thread.
        pub static PATH_GROUPS: Cell<u64> = const { Cell::new(0) };
        /// How many lanes found an object light by a bounce, without next-event estimation.
        pub static LIGHTS_FOUND: Cell<u64> = const { Cell::new(0) };
        /// How many lanes bounced off a mirror, conductor or dielectric, and how many of them
        /// went into a dielectric.
        pub static TURNS: Cell<u64> = const { Cell::new(0) };
        pub static ENTRIES: Cell<u64> = const { Cell::new(0) };
    }

    /// A box open towards the camera, two spheres (one in the light's way), a point light and
    /// a light mesh; materials with and without BRDFs, one glossy, one reflecting nothing.
    /// `extra` adds materials; the second sphere's material is `second`.
    fn scene(extra: &str, second: u32) -> crate::scene::Scene {
        scene_with(extra, second, "")
    }

    /// [`scene`] with more objects.
    fn scene_with(extra: &str, second: u32, objects: &str) -> crate::scene::Scene {
        let xml = format!(
            r#"<Scene><MaxRecursionDepth>3</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 -3 0</Position><Gaze>0 1 0</Gaze><Up>0 0 1</Up>
              <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>4 4</ImageResolution><ImageName>a.exr</ImageName><NumSamples>8</NumSamples>
              <Renderer>PathTracing</Renderer><RendererParams>NextEventEstimation</RendererParams></Camera></Cameras>
            <Lights><AmbientLight>0.1 0.1 0.1</AmbientLight>
              <PointLight id="1"><Position>0.3 0 0.8</Position><Intensity>2 2 2</Intensity></PointLight></Lights>
            <BRDFs><ModifiedPhong id="1" normalized="true"><Exponent>20</Exponent></ModifiedPhong>
              <OriginalBlinnPhong id="2"><Exponent>5</Exponent></OriginalBlinnPhong></BRDFs>
            <Materials><Material id="1" BRDF="1"><AmbientReflectance>0.2 0.2 0.2</AmbientReflectance>
                <DiffuseReflectance>0.7 0.6 0.5</DiffuseReflectance></Material>
              <Material id="2"></Material>
              <Material id="3"><DiffuseReflectance>0.2 0.8 0.3</DiffuseReflectance>
                <SpecularReflectance>0.3 0.3 0.3</SpecularReflectance><PhongExponent>10</PhongExponent></Material>
              <Material id="4" BRDF="2"><DiffuseReflectance>0.5 0.5 0.9</DiffuseReflectance>
                <SpecularReflectance>0.4 0.4 0.4</SpecularReflectance></Material>{extra}</Materials>
            <VertexData>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1
              -0.2 -0.2 0.95  0.2 -0.2 0.95  0.2 0.2 0.95  -0.2 0.2 0.95  -0.4 0.3 -0.6  0.4 0.2 -0.5
              0.6 0.5 0.6</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>
              4 8 7  4 7 3  1 5 8  1 8 4  2 3 7  2 7 6  1 4 3  1 3 2  5 6 7  5 7 8</Faces></Mesh>
              <LightMesh id="2"><Material>2</Material><Radiance>6 6 6</Radiance><Faces>9 12 11  9 11 10</Faces></LightMesh>
              <Sphere id="1"><Material>3</Material><Center>13</Center><Radius>0.35</Radius></Sphere>
              <Sphere id="2"><Material>{second}</Material><Center>14</Center><Radius>0.3</Radius></Sphere>
              {objects}
            </Objects></Scene>"#
        );
        let scene = load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
            .unwrap();
        assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
        scene
    }

    /// Camera rays into the box: at the walls, the spheres, the light, and out of the box.
    fn rays() -> [Ray; GROUP_LANES] {
        let dirs = [
            (0.0, 1.0, 0.0),
            (-0.15, 1.0, -0.3),
            (0.13, 1.0, -0.2),
            (0.0, 1.0, 0.33),
            (0.2, 1.0, 0.1),
            (-0.3, 1.0, 0.25),
            (0.0, -1.0, 0.0),
            (0.31, 1.0, -0.3),
        ];
        dirs.map(|(x, y, z)| Ray::new(DVec3::new(0.0, -3.0, 0.0), DVec3::new(x, y, z).normalize()))
    }

    /// Paths traced side by side give each camera sample the radiance, random numbers and ray
    /// counts it gets alone, bit for bit: with uniform and cosine bounces, with either roulette
    /// (paths of different lengths), with every light or one a vertex (`SampleOneLight`), with
    /// and without multiple importance sampling, for groups shorter than eight, for samples of one pixel
    /// (which draw their numbers together) and of several.
    #[test]
    fn paths_side_by_side_trace_what_each_path_traces_alone() {
        // Also a sphere light, which the lanes sample one by one, and a light mesh of more
        // than 32 triangles.
        let many: String = (0..40).map(|_| "9 12 11  ").collect();
        let lights = format!(
            r#"<LightSphere id="3"><Material>2</Material><Center>15</Center><Radius>0.1</Radius>
                <Radiance>3 2 1</Radiance></LightSphere>
              <LightMesh id="4"><Material>2</Material><Radiance>0.5 0.5 0.5</Radiance><Faces>{many}</Faces></LightMesh>"#
        );
        // A large sphere light, which bounces find often.
        let large = r#"<LightSphere id="3"><Material>2</Material><Center>15</Center><Radius>0.3</Radius>
                <Radiance>2 3 4</Radiance></LightSphere>"#;
        let found = LIGHTS_FOUND.with(Cell::get);
        for scene in [scene("", 4), scene_with("", 4, &lights), scene_with("", 4, large)] {
            side_by_side_matches_alone(&scene, &rays(), 7);
        }
        assert!(LIGHTS_FOUND.with(Cell::get) > found, "bounces found lights without NEE");
    }

    fn side_by_side_matches_alone(scene: &crate::scene::Scene, rays: &[Ray; GROUP_LANES], seed: u64) {
        assert!(super::fits(scene).is_some());
        for (next_event, importance, roulette, one_light, mis) in [
            (true, false, Roulette::Off, false, false),
            (true, true, Roulette::Off, false, false),
            (true, true, Roulette::Course, false, false),
            (true, false, Roulette::Unbiased, false, false),
            (true, true, Roulette::Off, true, false),
            (true, false, Roulette::Course, true, false),
            (true, true, Roulette::Unbiased, true, false),
            (true, true, Roulette::Off, false, true),
            (true, false, Roulette::Course, false, true),
            (true, true, Roulette::Off, true, true),
            (true, false, Roulette::Unbiased, true, true),
            (false, false, Roulette::Off, false, false),
            (false, true, Roulette::Course, false, false),
            (false, true, Roulette::Unbiased, false, false),
        ] {
            let params = PathParams { next_event, importance, roulette, one_light, mis };
            gathered_groups_match_alone(scene, rays, params);
            for group in [GROUP_LANES, 5, 2, 1] {
                for one_pixel in [true, false] {
                    let samplers: Vec<Sampler> = (0..group as u32)
                        .map(|k| {
                            if one_pixel { Sampler::new(seed, 1, 2, k) } else { Sampler::new(seed, k, 2, 3) }
                        })
                        .collect();
                    let mut together = crate::integrator::Tracer::new(scene);
                    together.renderer = Renderer::Path(params);
                    let mut hits = [None; GROUP_LANES];
                    together.camera_hits(&rays[..group], &mut hits[..group]);
                    let before = PATH_GROUPS.with(Cell::get);
                    let mut group_samplers = samplers.clone();
                    let got = together.trace_primary_group(rays, &hits[..group], &mut group_samplers);
                    assert_eq!(PATH_GROUPS.with(Cell::get), before + 1, "the group went side by side");
                    let mut alone = crate::integrator::Tracer::new(scene);
                    alone.renderer = Renderer::Path(params);
                    for i in 0..group {
                        let mut rng = samplers[i].clone();
                        let want = alone.trace_primary(&rays[i], hits[i], &mut rng);
                        let lane = format!("lane {i} of {group}, {params:?}, one pixel {one_pixel}");
                        assert_eq!(
                            got[i].to_array().map(f64::to_bits),
                            want.to_array().map(f64::to_bits),
                            "{lane}"
                        );
                        // The same numbers drawn: the next one agrees.
                        assert_eq!(group_samplers[i].next_1d(), rng.next_1d(), "{lane}");
                    }
                    assert_eq!(together.stats, alone.stats, "{group} lanes");
                    if group == GROUP_LANES {
                        assert!(hits.iter().any(Option::is_none), "a camera ray leaves the box");
                        assert!(together.stats.secondary > 0, "the paths bounce");
                        assert_eq!(together.stats.shadow > 0, next_event, "lights sampled with NEE only");
                        assert!(got.iter().any(|l| l.max_element() > 0.0), "light arrives");
                    }
                }
            }
        }
    }

    /// Several camera groups traced together ([`super::PathLanes::trace_groups`]), their living
    /// paths gathered into full groups after every step: each sample still gets the radiance,
    /// numbers and rays it gets alone, whichever lanes it travels in.
    fn gathered_groups_match_alone(
        scene: &crate::scene::Scene,
        rays: &[Ray; GROUP_LANES],
        params: PathParams,
    ) {
        use crate::integrator::CameraGroup;
        // Groups of several sizes, of two pixels each (their lanes draw from different pixels
        // once gathered), each with the rays in another order.
        let sizes = [8, 5, 8, 1, 8, 3];
        let mut groups: Vec<CameraGroup> = sizes
            .iter()
            .enumerate()
            .map(|(g, &n)| CameraGroup {
                rays: std::array::from_fn(|k| rays[(k + g) % GROUP_LANES]),
                hits: [None; GROUP_LANES],
                n,
                samplers: std::array::from_fn(|k| Sampler::new(11, (g % 2) as u32, 5, (g * 8 + k) as u32)),
            })
            .collect();
        let mut together = crate::integrator::Tracer::new(scene);
        together.renderer = Renderer::Path(params);
        for g in &mut groups {
            together.camera_hits(&g.rays[..g.n], &mut g.hits[..g.n]);
        }
        let before: Vec<Vec<Sampler>> = groups.iter().map(|g| g.samplers[..g.n].to_vec()).collect();
        let moved = super::super::pool::tests::MOVED.with(Cell::get);
        let mut got = vec![[DVec3::ZERO; GROUP_LANES]; groups.len()];
        together.trace_path_groups(&mut groups, &mut got);
        assert!(
            super::super::pool::tests::MOVED.with(Cell::get) > moved,
            "paths moved between groups, {params:?}"
        );
        let mut alone = crate::integrator::Tracer::new(scene);
        alone.renderer = Renderer::Path(params);
        for (g, group) in groups.iter_mut().enumerate() {
            for i in 0..group.n {
                let mut rng = before[g][i].clone();
                let want = alone.trace_primary(&group.rays[i], group.hits[i], &mut rng);
                let lane = format!("group {g} lane {i}, {params:?}");
                assert_eq!(
                    got[g][i].to_array().map(f64::to_bits),
                    want.to_array().map(f64::to_bits),
                    "{lane}"
                );
                assert_eq!(group.samplers[i].next_1d(), rng.next_1d(), "{lane}");
            }
        }
        assert_eq!(together.stats, alone.stats, "{params:?}");
    }

    /// Mirrors, conductors and glass (with and without roughness and absorption) among the
    /// plain materials: their lanes bounce one at a time, into and out of the glass, and every
    /// path still gets its own radiance, numbers and rays, bit for bit, under each of the
    /// shading rules that decide how glass is entered and which bounces count.
    #[test]
    fn specular_paths_side_by_side_trace_what_each_path_traces_alone() {
        use crate::scene::{DielectricSides, PathDepth, ShadingRules};
        let materials = r#"<Material id="5" type="dielectric"><SpecularReflectance>0.3 0.3 0.3</SpecularReflectance>
                <PhongExponent>3</PhongExponent><AbsorptionCoefficient>0.4 0.1 0.01</AbsorptionCoefficient>
                <RefractionIndex>1.5</RefractionIndex></Material>
              <Material id="6" type="mirror"><DiffuseReflectance>0.7 0.5 0.5</DiffuseReflectance>
                <MirrorReflectance>0.9 0.9 0.8</MirrorReflectance></Material>
              <Material id="7" type="dielectric"><RefractionIndex>1.33</RefractionIndex>
                <Roughness>0.1</Roughness></Material>
              <Material id="8" type="conductor"><MirrorReflectance>1 0.86 0.57</MirrorReflectance>
                <DiffuseReflectance>0.1 0.1 0.1</DiffuseReflectance><RefractionIndex>0.37</RefractionIndex>
                <AbsorptionIndex>2.82</AbsorptionIndex><Roughness>0.05</Roughness></Material>"#;
        let third = |m: u32| {
            format!(
                r#"<Sphere id="3"><Material>{m}</Material><Center>15</Center><Radius>0.3</Radius></Sphere>"#
            )
        };
        // Camera rays at the upper halves of the second sphere (which the light sees) and the
        // third, at a wall, and out of the box.
        let eye = DVec3::new(0.0, -3.0, 0.0);
        let towards = |c: DVec3, r: f64, n: DVec3| Ray::new(eye, (c + r * n.normalize() - eye).normalize());
        let (second_at, third_at) = (DVec3::new(0.4, 0.2, -0.5), DVec3::new(0.6, 0.5, 0.6));
        let rays: [Ray; GROUP_LANES] = [
            towards(second_at, 0.29, DVec3::new(0.0, -0.5, 0.87)),
            towards(second_at, 0.29, DVec3::new(0.4, -0.6, 0.7)),
            towards(second_at, 0.29, DVec3::new(-0.5, -0.5, 0.7)),
            towards(second_at, 0.29, DVec3::new(0.1, -0.2, 1.0)),
            towards(third_at, 0.29, DVec3::new(0.0, -0.8, 0.6)),
            towards(third_at, 0.2, DVec3::new(-0.3, -1.0, -0.2)),
            Ray::new(eye, DVec3::new(-0.3, 1.0, 0.25).normalize()),
            Ray::new(eye, DVec3::new(0.0, -1.0, 0.0)),
        ];
        let (turns, entries) = (TURNS.with(Cell::get), ENTRIES.with(Cell::get));
        for (second, other) in [(6, 5), (8, 7)] {
            for dielectric_sides in [DielectricSides::Flag, DielectricSides::FaceSide] {
                for path_depth in [PathDepth::EveryBounce, PathDepth::DiffuseBounces, PathDepth::GlassOnce] {
                    let mut scene = scene_with(materials, second, &third(other));
                    scene.rules = ShadingRules { dielectric_sides, path_depth };
                    let before = TURNS.with(Cell::get);
                    for seed in 0..4 {
                        side_by_side_matches_alone(&scene, &rays, seed);
                    }
                    assert!(TURNS.with(Cell::get) > before, "{second}, {other}: specular bounces");
                }
            }
        }
        assert!(TURNS.with(Cell::get) > turns, "the lanes bounced off mirrors and glass");
        assert!(ENTRIES.with(Cell::get) > entries, "the lanes went into the glass");
    }

    /// Scenes whose paths the lanes do not take: an object of smooth shading.
    #[test]
    fn other_paths_go_one_by_one() {
        assert!(super::fits(&scene("", 4)).is_some());
        // A mirror fits.
        let mirror =
            r#"<Material id="5" type="mirror"><MirrorReflectance>1 1 1</MirrorReflectance></Material>"#;
        assert!(super::fits(&scene(mirror, 5)).is_some());
        let smooth =
            r#"<Mesh id="9" shadingMode="smooth"><Material>1</Material><Faces>13 14 15</Faces></Mesh>"#;
        assert!(super::fits(&scene_with("", 4, smooth)).is_none());
    }
}
