//! Direct lighting of up to eight shading points at once: the camera samples of one pixel that
//! hit a surface, or a single point (the recursion and the path tracer).
//!
//! Each light is taken in turn for all the points: their directions and shadow rays first,
//! then the shadow rays as one packet query
//! ([`Accel::occluded_packet`](crate::geometry::Accel::occluded_packet)), then the BRDF of the
//! points the light reaches. The points of a pixel are close together and see a light along
//! nearly parallel rays, which then share their nodes; their independent chains of square roots
//! and divisions overlap; and an environment light's eight lookups are in flight together.
//!
//! Every point gets exactly the value, random numbers and ray counts it would get on its own:
//! per point the operations are the same and in the same order, a point draws its numbers from
//! its own sampler in the same order (a light at a time), and each shadow ray's answer is its
//! own query's.

use glam::DVec3;

use crate::lights::{EnvDirections, EnvLight};
use crate::material::Material;
use crate::math::{Ray, lane, lanes};
use crate::sampler::{GROUP_LANES, Sampler};
use crate::scene::Scene;
use crate::scene::records::EnvSampler;

/// A point to light: where, its normal (on the side the light may come from), its material
/// and the ray that found it (the viewer's direction, and the time of the shadow rays).
#[derive(Clone, Copy)]
pub struct LitPoint<'m> {
    pub ray: &'m Ray,
    pub x: DVec3,
    pub n: DVec3,
    pub mat: &'m Material,
    /// The point's triangle in the world tree ([`crate::geometry::SurfaceHit::world`]), or
    /// `u32::MAX`: lets its environment shadow rays ask the triangle's horizon first.
    pub world: u32,
}

/// The requests a `SampleOneLight` vertex reserves for its light, after the one that picks it:
/// the most any light draws at one point (an object light's two, an environment light's two
/// with its two-number sampler). Whichever light is picked, the vertex draws this many, so
/// every path's later numbers stand at the same dimensions and a group of paths keeps drawing
/// side by side.
pub(super) const ONE_LIGHT_REQUESTS: u64 = 2;

/// `M` requests of two numbers from each sampler in `mask` (`rngs` holds one sampler per
/// point, at most [`GROUP_LANES`]), by request, coordinate and lane: `out[m][0][k]` and
/// `out[m][1][k]` are sampler `k`'s `m`-th pair, zero for the lanes outside `mask`, the layout
/// the path lanes read. One [`Sampler::next_2d_groups_of`] call when the mask holds two or more
/// (it draws them together when they stand at the same dimension), the lone sampler's own draw
/// otherwise.
#[inline(always)]
pub(super) fn draw_lanes<const M: usize>(rngs: &mut [Sampler], mask: u32) -> [[[f64; GROUP_LANES]; 2]; M] {
    if mask & mask.wrapping_sub(1) != 0 {
        return Sampler::next_2d_groups_of::<M>(rngs, mask);
    }
    let mut out = [[[0.0; GROUP_LANES]; 2]; M];
    for k in lanes(mask) {
        for o in &mut out {
            (o[0][k], o[1][k]) = rngs[k].next_2d();
        }
    }
    out
}

/// [`draw_lanes`] as pairs by point (`out[k][m]` is sampler `k`'s `m`-th), for `N` points of
/// at most [`GROUP_LANES`].
#[inline(always)]
fn draw_requests<const N: usize, const M: usize>(rngs: &mut [Sampler], mask: u32) -> [[(f64, f64); M]; N] {
    const { assert!(N <= GROUP_LANES, "at most a group's lanes") };
    let drawn = draw_lanes::<M>(rngs, mask);
    std::array::from_fn(|k| std::array::from_fn(|m| (drawn[m][0][k], drawn[m][1][k])))
}

/// The next two numbers of each sampler in `mask`: one request of [`draw_requests`].
#[inline(always)]
fn draw_2d<const N: usize>(rngs: &mut [Sampler], mask: u32) -> [(f64, f64); N] {
    draw_requests::<N, 1>(rngs, mask).map(|[r]| r)
}

/// The numbers of one environment direction ([`EnvLight::sample_directions`]) for each sampler
/// in `mask`: `requests` requests per sampler, the two numbers of the first and the first number
/// of the second (what [`Sampler::next_1d`] would draw).
#[inline(always)]
fn draw_env<const N: usize>(rngs: &mut [Sampler], mask: u32, requests: usize) -> [[f64; 3]; N] {
    if requests > 1 {
        draw_requests::<N, 2>(rngs, mask).map(|[a, b]| [a.0, a.1, b.0])
    } else {
        draw_requests::<N, 1>(rngs, mask).map(|[a]| [a.0, a.1, 0.0])
    }
}

/// Adds to `l[k]`, for every lane `k` of `mask`, the light `e[k]` arriving from direction
/// `wis[k]` reflected towards the point's viewer: [`Material::reflectance`] times `e[k]`. When
/// the lanes share one classic material (a pixel's samples on one object), its reflectance is
/// computed for all of them side by side
/// ([`Material::classic_reflectance_lanes`]); the same bits either way.
#[inline(always)]
fn reflect_lanes<const N: usize>(
    pts: &[LitPoint<'_>],
    views: &Views<N>,
    mask: u32,
    wis: &[DVec3; N],
    e: &[DVec3; N],
    l: &mut [DVec3; N],
) {
    if mask == 0 {
        return;
    }
    let mat = pts[mask.trailing_zeros() as usize].mat;
    if mask & (mask - 1) != 0
        && lanes(mask).all(|k| std::ptr::eq(pts[k].mat, mat))
        && let Some(f) = mat.classic_reflectance_lanes(&views.n, wis, &views.wo)
    {
        for k in lanes(mask) {
            l[k] += f[k] * e[k];
        }
        return;
    }
    for k in lanes(mask) {
        let p = &pts[k];
        l[k] += p.mat.reflectance(p.n, wis[k], -p.ray.dir) * e[k];
    }
}

/// The points' normals and directions towards their viewers, lane by lane: gathered once per
/// [`Lighting::reflected`] call for every light's [`reflect_lanes`].
struct Views<const N: usize> {
    n: [DVec3; N],
    wo: [DVec3; N],
}

impl<const N: usize> Views<N> {
    fn of(pts: &[LitPoint<'_>]) -> Self {
        let mut v = Views { n: [DVec3::ZERO; N], wo: [DVec3::ZERO; N] };
        for (k, p) in pts.iter().enumerate() {
            v.n[k] = p.n;
            v.wo[k] = -p.ray.dir;
        }
        v
    }
}

/// Of a kind of lights numbered from `base`, the one `only` names, or all of them. A slice,
/// so that the usual case (every light) loops over the lights alone: a filter tested at every
/// light of every kind cost the classic renderer 1.3 % of its instructions on spheres_dof.
#[inline(always)]
fn chosen<T>(lights: &[T], only: Option<usize>, base: usize) -> &[T] {
    match only {
        None => lights,
        Some(o) => o.checked_sub(base).and_then(|i| lights.get(i..=i)).unwrap_or(&[]),
    }
}

/// Shadow rays of a group, lane by lane: origin, unit direction, far bound.
struct Shadows<const N: usize> {
    origin: [DVec3; N],
    dir: [DVec3; N],
    far: [f64; N],
    /// The lanes that trace one.
    mask: u32,
}

impl<const N: usize> Shadows<N> {
    fn new(origin: [DVec3; N]) -> Self {
        Shadows { origin, dir: [DVec3::ZERO; N], far: [0.0; N], mask: 0 }
    }

    #[inline]
    fn add(&mut self, k: usize, dir: DVec3, far: f64) {
        self.dir[k] = dir;
        self.far[k] = far;
        self.mask |= 1 << k;
    }
}

/// How a diffuse or glossy vertex draws its bounce direction, for the weights of multiple
/// importance sampling (`MultipleImportanceSampling`): from the cosine lobe (density
/// cos θ/π) or uniformly over the hemisphere (1/2π), taken with probability `chance` (a
/// mirror's or conductor's BRDF lobe is one of two; 0 when no bounce follows).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BounceDensity {
    pub cosine: bool,
    pub chance: f64,
}

impl BounceDensity {
    /// The solid-angle density of drawing `wi` at a vertex of normal `n`.
    #[inline]
    pub fn pdf(&self, n: DVec3, wi: DVec3) -> f64 {
        let p = if self.cosine {
            n.dot(wi).max(0.0) * std::f64::consts::FRAC_1_PI
        } else {
            0.5 * std::f64::consts::FRAC_1_PI
        };
        self.chance * p
    }
}

/// Veach's power heuristic (exponent 2): the weight of a sample drawn with density `f` when
/// another strategy would have drawn it with density `g`. 1 when `g` is 0 (the other strategy
/// cannot make it), 0 when `f` is.
#[inline]
pub fn power_heuristic(f: f64, g: f64) -> f64 {
    let (f2, g2) = (f * f, g * g);
    if g2 == 0.0 {
        return if f2 > 0.0 { 1.0 } else { 0.0 };
    }
    let w = f2 / (f2 + g2);
    if w.is_finite() {
        w
    } else if f2.is_infinite() {
        1.0
    } else {
        0.0
    }
}

/// The density with which a path vertex at `from` samples, as next-event estimation, the
/// point `point` (geometric normal `normal`) of the object `instance` that its bounce along
/// `dir` found, when that object is an object light: the light's own density
/// ([`crate::lights::ObjectLight::pdf`]) times the chance of choosing it (with
/// `SampleOneLight`). Infinite for a light sampled without a density (an ellipsoid), whose
/// bounce then weighs nothing; 0 for a surface that is no object light.
pub(super) fn light_pdf(
    scene: &Scene,
    from: DVec3,
    dir: DVec3,
    (point, normal, instance): (DVec3, DVec3, u32),
    one_light: bool,
) -> f64 {
    let Some(&j) = scene.instance_light.get(instance as usize) else { return 0.0 };
    let Some(light) = scene.object_lights.get(j as usize) else { return 0.0 };
    // The distance from the vertex itself, as its light samples measure it (the ray left
    // from a point just off the surface).
    let (cos_y, dist) = (-dir.dot(normal), (point - from).length());
    let Some(pdf) = light.pdf(from, dist, cos_y) else { return f64::INFINITY };
    if one_light {
        pdf * scene.light_choice.probability(scene.first_object_light() + j as usize)
    } else {
        pdf
    }
}

/// Object lights' samples under multiple importance sampling: the bounce they are weighed
/// against, and the probability with which their light was chosen (1 when every light is
/// sampled).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightWeights {
    pub bounce: BounceDensity,
    pub pick: f64,
}

impl LightWeights {
    /// The power-heuristic weight of an object light's sample towards `wi`, drawn with density
    /// `1 / inv_pdf` times the pick, at a vertex of normal `n`.
    #[inline]
    pub fn weight(&self, n: DVec3, wi: DVec3, inv_pdf: f64) -> f64 {
        power_heuristic(self.pick / inv_pdf, self.bounce.pdf(n, wi))
    }
}

/// Direct lighting in one scene: the light reflected at shading points, and how many shadow
/// rays it took.
pub struct Lighting<'s> {
    pub scene: &'s Scene,
    /// How the environment light (if any) picks its direction.
    pub env_sampler: EnvSampler,
    /// Shadow rays traced so far (and degenerate ones counted as blocked).
    pub shadow_rays: u64,
    /// Only this light, numbered as [`crate::lights::choice::LightChoice`] numbers them (`None`: every
    /// light).
    pub only: Option<usize>,
    /// With multiple importance sampling, how object lights' samples are weighed (`None`:
    /// each counts in full). Every lane shares it: the path tracer lights one point at a time.
    pub mis: Option<LightWeights>,
    /// Horizons the environment lights' shadow rays ask first ([`Tracer::horizons`]).
    pub horizons: Option<&'s crate::geometry::Horizons>,
}

impl Lighting<'_> {
    /// The light reflected towards each point's viewer from one sample of every light, for up
    /// to eight points with their samplers. Lights in the scene's order: point, area,
    /// directional, spot, object lights, then (when `env`) one direction of the environment
    /// light.
    #[inline(always)]
    pub fn reflected<const N: usize>(
        &mut self,
        pts: &[LitPoint<'_>],
        env: bool,
        rngs: &mut [Sampler],
    ) -> [DVec3; N] {
        const { assert!(N <= GROUP_LANES, "at most eight lanes") };
        assert!(pts.len() <= N && rngs.len() == pts.len(), "one sampler per point, at most N");
        let scene = self.scene;
        let mut l = [DVec3::ZERO; N];
        // Points whose material reflects nothing draw no numbers and trace no rays.
        let mut live = 0u32;
        for (k, p) in pts.iter().enumerate() {
            if p.mat.diffuse != DVec3::ZERO || p.mat.specular != DVec3::ZERO {
                live |= 1 << k;
            }
        }
        if live == 0 {
            return l;
        }
        let eps = scene.shadow_ray_epsilon;
        let mut origin = [DVec3::ZERO; N];
        for k in lanes(live) {
            origin[k] = pts[k].x + eps * pts[k].n;
        }
        let views = Views::of(pts);
        // The lights in order, each with its number; with `only`, that one alone.
        let only = self.only;
        let area_base = scene.point_lights.len();
        let directional_base = area_base + scene.area_lights.len();
        let spot_base = directional_base + scene.directional_lights.len();
        let object_base = scene.first_object_light();
        let env_base = object_base + scene.object_lights.len();
        for light in chosen(&scene.point_lights, only, 0) {
            let (wis, d2, shadows) = towards_lanes(pts, &origin, &[light.position; N], live);
            let clear = self.clear_lanes(pts, &shadows, true);
            // Every lane (a loop of fixed length: the divisions overlap); unlit ones unused.
            let e: [DVec3; N] = std::array::from_fn(|k| light.intensity / d2[k]);
            reflect_lanes(pts, &views, clear, &wis, &e, &mut l);
        }
        for light in chosen(&scene.area_lights, only, area_base) {
            // One point of the square per shading event; the pixel's samples average them.
            let uv = draw_2d::<N>(rngs, live);
            let mut q = [DVec3::ZERO; N];
            for k in lanes(live) {
                q[k] = light.point(uv[k].0, uv[k].1);
            }
            let (wis, d2, shadows) = towards_lanes(pts, &origin, &q, live);
            let clear = self.clear_lanes(pts, &shadows, true);
            let e: [DVec3; N] = std::array::from_fn(|k| {
                light.radiance * (light.size * light.size * light.normal.dot(wis[k]).abs() / d2[k])
            });
            reflect_lanes(pts, &views, clear, &wis, &e, &mut l);
        }
        for light in chosen(&scene.directional_lights, only, directional_base) {
            let mut shadows = Shadows::new(origin);
            for k in lanes(live) {
                // Only a light below the surface is skipped (a NaN cosine still traces its ray).
                let cos = pts[k].n.dot(light.to_light);
                if cos > 0.0 || cos.is_nan() {
                    shadows.add(k, light.to_light, f64::INFINITY);
                }
            }
            let clear = self.clear_lanes(pts, &shadows, true);
            reflect_lanes(pts, &views, clear, &[light.to_light; N], &[light.radiance; N], &mut l);
        }
        for light in chosen(&scene.spot_lights, only, spot_base) {
            let mut factor = [0.0; N];
            let mut inside = 0u32;
            for k in lanes(live) {
                factor[k] = light.factor((pts[k].x - light.position).normalize());
                if factor[k] > 0.0 {
                    inside |= 1 << k;
                }
            }
            let (wis, d2, shadows) = towards_lanes(pts, &origin, &[light.position; N], inside);
            let clear = self.clear_lanes(pts, &shadows, true);
            let e: [DVec3; N] = std::array::from_fn(|k| light.intensity * (factor[k] / d2[k]));
            reflect_lanes(pts, &views, clear, &wis, &e, &mut l);
        }
        for light in chosen(&scene.object_lights, only, object_base) {
            // One point per shading event (§13.3); the random numbers are drawn whatever the
            // outcome, so later dimensions keep their places.
            let mut u = [0.0; N];
            for k in lanes(live) {
                u[k] = rngs[k].next_1d();
            }
            let uv = draw_2d::<N>(rngs, live);
            let mut wis = [DVec3::ZERO; N];
            let mut irradiance = [DVec3::ZERO; N];
            let mut shadows = Shadows::new(origin);
            for k in lanes(live) {
                let p = &pts[k];
                if let Some(s) = light.sample(p.x, u[k], uv[k].0, uv[k].1)
                    && p.n.dot(s.wi) > 0.0
                {
                    // The shadow ray stops just short of the light's surface, so that surface
                    // does not block it.
                    let to_light = p.x + s.wi * s.dist - origin[k];
                    let len = to_light.length();
                    if len.is_nan() || len <= 0.0 {
                        // A degenerate segment: counted as a shadow ray that is blocked.
                        self.shadow_rays += 1;
                    } else {
                        wis[k] = s.wi;
                        irradiance[k] = match (self.mis, s.inv_pdf) {
                            (Some(m), Some(inv)) => s.irradiance * m.weight(p.n, s.wi, inv),
                            _ => s.irradiance,
                        };
                        shadows.add(k, to_light / len, len * (1.0 - 1e-6));
                    }
                }
            }
            let clear = self.clear_lanes(pts, &shadows, true);
            reflect_lanes(pts, &views, clear, &wis, &irradiance, &mut l);
        }
        // The directions first, for every point (each starts loading what its lookup reads),
        // then the shadow rays, then radiance and pdf: the cache misses overlap each other and
        // the traversal, and a blocked ray needs no lookup.
        // Every environment light, the first (the one rays that miss see) first: each draws its
        // own directions.
        let envs = scene.env_light.iter().chain(&scene.extra_env_lights).enumerate();
        let envs = envs.filter(|&(i, _)| only.is_none_or(|o| o == env_base + i)).map(|(_, l)| l);
        let horizons = if env { self.horizons } else { None };
        for light in envs.filter(|_| env) {
            let xi = draw_env::<N>(rngs, live, EnvLight::requests(self.env_sampler));
            let mut dirs = EnvDirections::NONE;
            light.sample_directions(&views.n, self.env_sampler, &xi, live, &mut dirs);
            let mut shadows = Shadows::new(origin);
            for k in lanes(dirs.mask) {
                // Only a direction below the surface is skipped (a NaN cosine still traces its
                // ray); a mask bit, not a branch per lane.
                let wi = dirs.wi(k);
                let cos = pts[k].n.dot(wi);
                shadows.dir[k] = wi;
                shadows.far[k] = f64::INFINITY;
                shadows.mask |= u32::from(cos > 0.0 || cos.is_nan()) << k;
            }
            // Rays above their triangle's horizon are clear without a walk (the walk would say
            // the same); they are counted as the shadow rays they are. Without horizons (fewer
            // samples a pixel) this is one branch.
            let mut above = 0u32;
            if let Some(h) = horizons {
                for k in lanes(shadows.mask) {
                    let p = &pts[k];
                    if p.world != u32::MAX && scene.accel.horizon_clear(h, p.world, p.n, shadows.dir[k]) {
                        above |= 1 << k;
                    }
                }
                shadows.mask &= !above;
                self.shadow_rays += u64::from(above.count_ones());
            }
            let clear = self.clear_lanes(pts, &shadows, false) | above;
            if clear != 0 {
                let (lit, w) = light.weights(&mut dirs, clear);
                let mut weights = [DVec3::ZERO; N];
                for k in lanes(lit) {
                    weights[k] = lane(&w, k);
                }
                reflect_lanes(pts, &views, lit, &shadows.dir, &weights, &mut l);
            }
        }
        l
    }

    /// The lanes of `shadows` whose ray reaches its far bound unblocked; counts the rays.
    /// Rays towards one light point (or one direction) are traced as a packet; the environment
    /// light's directions are random, and such rays go one by one (a packet of them visits the
    /// union of their nodes).
    #[inline(always)]
    fn clear_lanes<const N: usize>(
        &mut self,
        pts: &[LitPoint<'_>],
        shadows: &Shadows<N>,
        coherent: bool,
    ) -> u32 {
        let mask = shadows.mask;
        if mask == 0 {
            return 0;
        }
        let scene = self.scene;
        let tmin = scene.intersection_test_epsilon;
        self.shadow_rays += u64::from(mask.count_ones());
        if !coherent || mask & (mask - 1) == 0 {
            let mut clear = 0;
            for k in lanes(mask) {
                let ray = pts[k].ray.spawn(shadows.origin[k], shadows.dir[k]);
                if !scene.accel.occluded(&ray, tmin, shadows.far[k]) {
                    clear |= 1 << k;
                }
            }
            return clear;
        }
        // The packet holds the lanes that trace, side by side.
        let mut rays = [*pts[0].ray; N];
        let mut far = [0.0; N];
        let mut m = 0;
        for k in lanes(mask) {
            rays[m] = pts[k].ray.spawn(shadows.origin[k], shadows.dir[k]);
            far[m] = shadows.far[k];
            m += 1;
        }
        let blocked = scene.accel.occluded_packet(&rays[..m], tmin, &far[..m]);
        let mut clear = 0;
        for (j, k) in lanes(mask).enumerate() {
            if blocked & (1 << j) == 0 {
                clear |= 1 << k;
            }
        }
        clear
    }
}

/// Towards light points `p[k]` from the points `pts[k]` of `mask` (shadow rays leaving from
/// `origin[k]`): each lane's unit direction from its point, its squared distance (`(p[k] -
/// pts[k].x).length_squared()`), and its shadow ray (unit direction and length) when the light
/// point is above the surface (not when it is the point itself,
/// whose cosine is NaN). Computed for every lane side by side, one component at a time, so the
/// compiler makes vector code of the square roots and divisions; per lane the operations are
/// glam's `normalize`, `dot`, `length` and division, in their order, so the bits are the same.
#[inline(always)]
fn towards_lanes<const N: usize>(
    pts: &[LitPoint<'_>],
    origin: &[DVec3; N],
    p: &[DVec3; N],
    mask: u32,
) -> ([DVec3; N], [f64; N], Shadows<N>) {
    let mut x = [[0.0; N]; 3];
    let mut n = [[0.0; N]; 3];
    for (k, pt) in pts.iter().enumerate() {
        for a in 0..3 {
            x[a][k] = pt.x[a];
            n[a][k] = pt.n[a];
        }
    }
    let (mut wi, mut dir, mut len, mut cos) = ([[0.0; N]; 3], [[0.0; N]; 3], [0.0; N], [0.0; N]);
    let mut d2 = [0.0; N];
    for k in 0..N {
        let v = [p[k].x - x[0][k], p[k].y - x[1][k], p[k].z - x[2][k]];
        d2[k] = (v[0] * v[0]) + (v[1] * v[1]) + (v[2] * v[2]);
        let recip = 1.0 / d2[k].sqrt();
        let w = [v[0] * recip, v[1] * recip, v[2] * recip];
        cos[k] = (n[0][k] * w[0]) + (n[1][k] * w[1]) + (n[2][k] * w[2]);
        let t = [p[k].x - origin[k].x, p[k].y - origin[k].y, p[k].z - origin[k].z];
        len[k] = ((t[0] * t[0]) + (t[1] * t[1]) + (t[2] * t[2])).sqrt();
        for a in 0..3 {
            wi[a][k] = w[a];
            dir[a][k] = t[a] / len[k];
        }
    }
    let mut wis = [DVec3::ZERO; N];
    let mut shadows = Shadows::new(*origin);
    for k in lanes(mask) {
        // Not NaN and positive.
        if cos[k] > 0.0 {
            wis[k] = DVec3::new(wi[0][k], wi[1][k], wi[2][k]);
            shadows.add(k, DVec3::new(dir[0][k], dir[1][k], dir[2][k]), len[k]);
        }
    }
    (wis, d2, shadows)
}
