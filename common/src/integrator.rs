//! The course's recursive ray tracer (scene-format.md §6, §16.2): ambient + Blinn-Phong from
//! point lights with shadow rays, then mirror, conductor and dielectric recursion bounded by
//! `MaxRecursionDepth`, with Beer's law inside dielectrics.

mod bounces;
mod direct;
mod paths;
mod pool;

pub use pool::CameraGroup;

use glam::{DVec2, DVec3};

use crate::geometry::Instance;
use crate::geometry::{RayLanes, SurfaceHit};
use crate::material::{Material, MaterialKind, MatteSlot, Refraction, fresnel_conductor, refract};
use crate::math::{Ray, orthonormal_pair, reflect};
use crate::sampler::{GROUP_LANES, Sampler};
use crate::scene::records::{
    DecalMode, EnvSampler, MAX_RECURSION_DEPTH_LIMIT, PathParams, Renderer, Roulette,
};
use crate::scene::{DielectricSides, Scene};
use bounces::{Arrival, brdf_bounce, brdf_chance, density, glossy, scatter};
use direct::{
    BounceDensity, LightWeights, Lighting, LitPoint, ONE_LIGHT_REQUESTS, light_pdf, power_heuristic,
};

use crate::texture::maps::{
    Source, TextureMap, TexturePoint, bump_by_gradient, image_height, perlin_gradient,
};

/// Rays traced, by kind, for throughput figures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayStats {
    pub primary: u64,
    pub shadow: u64,
    pub secondary: u64,
}

impl RayStats {
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.secondary
    }

    pub fn add(&mut self, o: &RayStats) {
        self.primary += o.primary;
        self.shadow += o.shadow;
        self.secondary += o.secondary;
    }
}

// What a denoiser reads beside the colour (Intel Open Image Denoise's `RT` filter): for each
// camera sample, the albedo and the world-space normal of the first surface the ray meets that
// is not a perfect mirror or perfect glass. Through those the ray goes on (a mirror's reflected
// direction, glass's refracted one, or its reflection under total internal reflection), so a
// denoiser sees the reflected or refracted scene's edges rather than a flat mirror. These are
// features, not light: no random numbers are drawn and no counter moves, so asking for them
// changes no bit of the colour.

/// One camera sample's features.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Aux {
    /// Reflectance in [0, 1] per channel: a material's diffuse plus specular colour after its
    /// texture maps; for an object light seen from its front, its radiance clamped to [0, 1];
    /// for a ray that leaves the scene, what it sees (environment or background) clamped.
    pub albedo: DVec3,
    /// The shading normal (after normal and bump maps) turned towards the ray; zero for a ray
    /// that leaves the scene.
    pub normal: DVec3,
}

/// How many perfect mirrors and glass surfaces a feature ray passes through before it takes
/// what it finds: a hall of mirrors must not cost without bound.
pub const AUX_CHAIN_LIMIT: u32 = 8;

fn clamp01(v: DVec3) -> DVec3 {
    // NaN (a degenerate texel) becomes 0, like the film's.
    let f = |x: f64| if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    DVec3::new(f(v.x), f(v.y), f(v.z))
}

impl Tracer<'_> {
    /// The features of camera ray `ray`, whose first surface is `hit` (as
    /// [`Self::camera_hits`] found it).
    pub fn aux(&self, ray: &Ray, hit: Option<SurfaceHit>) -> Aux {
        let scene = self.scene;
        let eps = scene.shadow_ray_epsilon;
        let (mut ray, mut hit) = (*ray, hit);
        let mut travelled = 0.0;
        // Whether the feature ray is inside a dielectric (for the `Flag` rule).
        let mut inside = false;
        for depth in 0..=AUX_CHAIN_LIMIT {
            let Some(h) = hit else {
                let seen = match &scene.env_light {
                    Some(env) => env.radiance(ray.dir),
                    None => self.background,
                };
                return Aux { albedo: clamp01(seen), normal: DVec3::ZERO };
            };
            travelled += h.t;
            let mut slot = None;
            let s = match self.begin_shade(&ray, &h, self.spread * travelled, &mut slot) {
                Ok(s) => s,
                // A `replace_all` texel is the surface's colour as it is shown.
                Err(texel) => {
                    let n = if ray.dir.dot(h.shading_normal) < 0.0 {
                        h.shading_normal
                    } else {
                        -h.shading_normal
                    };
                    return Aux { albedo: clamp01(texel), normal: n };
                }
            };
            let n = s.facing();
            if s.emitted != DVec3::ZERO {
                return Aux { albedo: clamp01(s.emitted), normal: n };
            }
            let mat = s.mat;
            let smooth = mat.roughness == 0.0;
            let next = match mat.kind {
                MaterialKind::Dielectric if smooth => {
                    // Entering or leaving by the scene's rule, as the colour's rays decide it.
                    let entering = match scene.rules.dielectric_sides {
                        DielectricSides::FaceSide => s.entering,
                        DielectricSides::Flag => !inside,
                    };
                    let (n1, n2) =
                        if entering { (1.0, mat.refraction_index) } else { (mat.refraction_index, 1.0) };
                    Some(match refract(ray.dir, n, n1, n2) {
                        Refraction::Total => ray.spawn(h.point + eps * n, reflect(ray.dir, n)),
                        Refraction::Split { dir, .. } => {
                            inside = entering;
                            ray.spawn(h.point - eps * n, dir)
                        }
                    })
                }
                MaterialKind::Mirror | MaterialKind::Conductor
                    if smooth && mat.diffuse == DVec3::ZERO && mat.specular == DVec3::ZERO =>
                {
                    Some(ray.spawn(h.point + eps * s.shading_normal, reflect(ray.dir, n)))
                }
                _ => None,
            };
            match next {
                Some(r) if depth < AUX_CHAIN_LIMIT => {
                    ray = r;
                    hit = self.closest(&ray, depth + 1);
                }
                _ => {
                    let albedo = match mat.kind {
                        // Glass and mirrors that stop the chain (rough, or at its end) reflect
                        // what they see: white, or the mirror's colour.
                        MaterialKind::Dielectric => DVec3::ONE,
                        MaterialKind::Mirror | MaterialKind::Conductor => {
                            mat.diffuse + mat.specular + mat.mirror
                        }
                        MaterialKind::Plain => mat.diffuse + mat.specular,
                    };
                    return Aux { albedo: clamp01(albedo), normal: n };
                }
            }
        }
        unreachable!("the loop returns at its last step")
    }
}

/// Traces rays through one scene; one per render thread (it only holds counters).
pub struct Tracer<'a> {
    pub scene: &'a Scene,
    pub stats: RayStats,
    /// What rays that miss everything return for the current pixel: BackgroundColor, or the
    /// pixel's texel of a `replace_background` map (used for secondary misses too, §11.8).
    pub background: DVec3,
    /// How the environment light (if any) is sampled: the scene's choice, else the course's
    /// uniform estimator; the render settings may override it.
    pub env_sampler: EnvSampler,
    /// Spread angle (radians) of the ray cone of one camera pixel, for the mip level of
    /// trilinear texture maps ([`Camera::pixel_spread`](crate::camera::Camera)); 0 reads
    /// level 0 everywhere.
    pub spread: f64,
    /// Rays the current camera sample may still trace (see [`SECONDARY_RAY_BUDGET`]).
    budget: u32,
    /// The camera's renderer: the recursive tracer or a path tracer (§13.1).
    pub renderer: Renderer,
    /// Where [`Self::trace_path_groups`] keeps its paths between calls.
    path_pool: pool::Pool,
    /// The horizons environment shadow rays ask before they are traced
    /// ([`crate::geometry::Horizons`]), when the render samples pixels often enough for them
    /// to pay (see `render::HORIZON_SAMPLES`).
    pub horizons: Option<&'a crate::geometry::Horizons>,
}

/// Most rays traced for one camera sample. Glass splits every ray in two, so the tree of a
/// deep `MaxRecursionDepth` grows as 2^depth; the course's depths (at most 6, 127 rays) never
/// reach this, and past it the recursion stops as it does at the depth limit, so a hostile
/// scene costs bounded work per sample.
pub const SECONDARY_RAY_BUDGET: u32 = 4096;

/// How many back faces a camera ray may look past (2025 scenes cull them) before it takes the
/// next one as its hit: each look is a whole traversal, and a hostile stack of back faces along
/// one ray must not make a pixel cost without bound.
pub const CULLED_HITS_LIMIT: u32 = 256;

/// Most bounces of a path under Russian roulette, which otherwise has no depth limit: a safety
/// cap (a path this long carries a negligible share of any pixel in the course's scenes).
pub const PATH_DEPTH_LIMIT: u32 = MAX_RECURSION_DEPTH_LIMIT;

impl<'a> Tracer<'a> {
    pub fn new(scene: &'a Scene) -> Self {
        let env_sampler = scene.env_light.as_ref().and_then(|l| l.sampler).unwrap_or(EnvSampler::Uniform);
        Tracer {
            scene,
            stats: RayStats::default(),
            background: scene.background,
            env_sampler,
            spread: 0.0,
            budget: 0,
            renderer: Renderer::Classic,
            path_pool: pool::Pool::default(),
            horizons: None,
        }
    }

    /// The surfaces camera rays `rays` (at most eight) see first, into `out`: what
    /// [`Self::trace_primary`] needs. The rays are traced together (see
    /// [`Accel::intersect_packet`](crate::geometry::Accel::intersect_packet)); a hit on a back
    /// face that the scene culls is looked past ray by ray.
    pub fn camera_hits(&self, rays: &[Ray], out: &mut [Option<SurfaceHit>]) {
        if !rays.is_empty() {
            self.camera_hits_lanes(rays, &RayLanes::new(rays), out);
        }
    }

    /// [`Self::camera_hits`] of `rays` also given side by side (see
    /// [`Accel::intersect_lanes`](crate::geometry::Accel::intersect_lanes)).
    #[inline(always)]
    pub fn camera_hits_lanes(&self, rays: &[Ray], wide: &RayLanes, out: &mut [Option<SurfaceHit>]) {
        let scene = self.scene;
        scene.accel.intersect_lanes(rays, wide, scene.intersection_test_epsilon, out);
        self.look_past_culled(rays, out);
    }

    /// Camera hits `out` of `rays` on back faces the scene culls, looked past ray by ray.
    #[inline(always)]
    fn look_past_culled(&self, rays: &[Ray], out: &mut [Option<SurfaceHit>]) {
        let scene = self.scene;
        if scene.cull_camera_back_faces {
            for (o, ray) in out.iter_mut().zip(rays) {
                if o.is_some_and(|h| ray.dir.dot(h.geo_normal) > 0.0 && scene.accel.is_triangle(h.instance)) {
                    *o = self.closest(ray, 0);
                }
            }
        }
    }

    /// [`Self::camera_hits_lanes`] of two groups at once, each group's hits what that call
    /// finds: their rays walk the world tree together
    /// ([`Accel::intersect_lanes_pair`](crate::geometry::Accel::intersect_lanes_pair)).
    #[inline(always)]
    pub fn camera_hits_pair(
        &self,
        rays: [&[Ray]; 2],
        wide: [&RayLanes; 2],
        out: [&mut [Option<SurfaceHit>]; 2],
    ) {
        let scene = self.scene;
        let [out0, out1] = out;
        scene.accel.intersect_lanes_pair(
            rays,
            wide,
            scene.intersection_test_epsilon,
            [&mut *out0, &mut *out1],
        );
        self.look_past_culled(rays[0], out0);
        self.look_past_culled(rays[1], out1);
    }

    /// [`Self::trace_primary`] of a pixel's group of camera rays (`hits.len()` of the eight in
    /// `rays`, with their samplers), lane by lane: the same values. Rays that miss everything
    /// see the environment light, and their lookups are made together
    /// ([`EnvLight::radiance_lanes`](crate::lights::EnvLight::radiance_lanes)); with the
    /// recursive renderer, the surfaces the rays find are lit together as well.
    ///
    /// Inlined into the tile loop, as is the chain a group's camera rays and lights go
    /// through (`camera_hits_lanes`, `Accel::intersect_lanes`, `classic_group`, `lights_lanes`,
    /// `lights_of`, `Lighting::reflected`, `clear_lanes`): left to the compiler they became
    /// calls as the code grew, and the arguments and lane arrays went through memory at each
    /// (3.6 % more instructions on spheres_dof, 1.1 % on head_env_direct, the same bytes).
    #[inline(always)]
    pub fn trace_primary_group(
        &mut self,
        rays: &[Ray; GROUP_LANES],
        hits: &[Option<SurfaceHit>],
        samplers: &mut [Sampler],
    ) -> [DVec3; GROUP_LANES] {
        // Both renderers show a camera ray that misses the environment's radiance as is.
        let seen = match &self.scene.env_light {
            Some(env) => {
                let misses = (0..hits.len()).fold(0u32, |m, i| m | u32::from(hits[i].is_none()) << i);
                (misses != 0).then(|| env.radiance_lanes(|i| rays[i].dir, misses))
            }
            _ => None,
        };
        if self.renderer == Renderer::Classic {
            return self.classic_group(rays, hits, samplers, seen.as_ref());
        }
        if let Some((params, mattes)) = self.path_lanes() {
            return self
                .with_path_lanes(mattes, |lanes, pool| lanes.trace(pool, rays, hits, params, samplers));
        }
        let mut out = [DVec3::ZERO; GROUP_LANES];
        for (i, (hit, rng)) in hits.iter().zip(samplers).enumerate() {
            out[i] = match (hit, &seen) {
                (None, Some(seen)) => {
                    self.stats.primary += 1;
                    seen[i]
                }
                _ => self.trace_primary(&rays[i], *hit, rng),
            };
        }
        out
    }

    /// This camera's path tracer's settings and the scene's matte forms, when its paths go
    /// side by side (a path-traced camera of a scene that [`paths::fits`]).
    fn path_lanes(&self) -> Option<(PathParams, &'a [MatteSlot])> {
        match self.renderer {
            Renderer::Path(params) => paths::fits(self.scene).map(|mattes| (params, mattes)),
            Renderer::Classic => None,
        }
    }

    /// Whether this camera's samples may go through [`Self::trace_path_groups`].
    pub fn pools_paths(&self) -> bool {
        self.path_lanes().is_some()
    }

    /// `f` with the path lanes of this tracer's scene and the tracer's pool of path groups; the
    /// rays they trace are added to the tracer's counts.
    fn with_path_lanes<T>(
        &mut self,
        mattes: &'a [MatteSlot],
        f: impl FnOnce(&mut paths::PathLanes<'a>, &mut pool::Pool) -> T,
    ) -> T {
        let mut lanes = paths::PathLanes {
            scene: self.scene,
            mattes,
            background: self.background,
            counts: paths::Counts::default(),
        };
        let out = f(&mut lanes, &mut self.path_pool);
        let c = lanes.counts;
        self.stats.add(&RayStats { primary: c.primary, shadow: c.shadow, secondary: c.secondary });
        out
    }

    /// [`Self::trace_primary`] of every camera sample of `groups` (see
    /// [`paths::PathLanes::trace_groups`]) into `out`, one entry a group, when
    /// [`Self::pools_paths`]: the same values as [`Self::trace_primary_group`] of each group,
    /// with the paths of all the groups gathered into full groups after each vertex.
    pub fn trace_path_groups(&mut self, groups: &mut [CameraGroup], out: &mut [[DVec3; GROUP_LANES]]) {
        let (params, mattes) = self.path_lanes().expect("pools_paths said the paths go side by side");
        self.with_path_lanes(mattes, |lanes, pool| lanes.trace_groups(pool, groups, params, out));
    }

    /// [`Self::trace_primary_group`] for the recursive renderer: [`Self::shade`] of every lane
    /// that hits, in three steps so the lanes' direct light is computed together
    /// ([`Lighting::reflected`]): each lane's surface, then the lights of all of them, then each
    /// lane's reflection and refraction. A lane draws its numbers in the order it would alone
    /// (its direct light's before its recursion's).
    #[inline(always)]
    fn classic_group(
        &mut self,
        rays: &[Ray; GROUP_LANES],
        hits: &[Option<SurfaceHit>],
        samplers: &mut [Sampler],
        seen: Option<&[DVec3; GROUP_LANES]>,
    ) -> [DVec3; GROUP_LANES] {
        let scene = self.scene;
        let n = hits.len();
        let mut out = [DVec3::ZERO; GROUP_LANES];
        // Materials changed by colour maps, one per lane.
        let mut slots: [Option<Material>; GROUP_LANES] = Default::default();
        let mut surfaced: [Option<Surfaced<'_>>; GROUP_LANES] = Default::default();
        for (i, (hit, slot)) in hits.iter().zip(&mut slots).enumerate() {
            self.stats.primary += 1;
            match hit {
                None => out[i] = seen.map_or(self.background, |seen| seen[i]),
                Some(hit) => match self.begin_shade(&rays[i], hit, self.spread * hit.t, slot) {
                    Ok(s) => surfaced[i] = Some(s),
                    Err(texel) => out[i] = texel,
                },
            }
        }
        // The lit lanes side by side (at depth 0 every surface is lit: nothing is seen from
        // inside a dielectric), the others' places taken by the first.
        let Some(first) = surfaced.iter().position(Option::is_some) else { return out };
        let point = |i: usize| {
            let (s, hit) = (surfaced[i].as_ref()?, hits[i].as_ref()?);
            Some(LitPoint {
                ray: &rays[i],
                x: hit.point,
                n: s.lit_normal(false)?,
                mat: s.mat,
                world: hit.world,
            })
        };
        let Some(filler) = point(first) else { return out };
        let mut pts = [filler; GROUP_LANES];
        let mut order = [0usize; GROUP_LANES];
        let mut m = 0;
        for i in first..n {
            if let Some(p) = point(i) {
                pts[m] = p;
                order[m] = i;
                m += 1;
            }
        }
        let light = if m == n {
            // Every lane: their own samplers.
            self.lights_lanes::<GROUP_LANES>(&pts[..m], true, samplers)
        } else {
            let mut rngs: [Sampler; GROUP_LANES] =
                std::array::from_fn(|j| samplers[order[j.min(m - 1)]].clone());
            let light = self.lights_lanes::<GROUP_LANES>(&pts[..m], true, &mut rngs[..m]);
            for (j, &i) in order[..m].iter().enumerate() {
                samplers[i] = rngs[j].clone();
            }
            light
        };
        let mut direct = [DVec3::ZERO; GROUP_LANES];
        for (j, &i) in order[..m].iter().enumerate() {
            direct[i] = pts[j].mat.ambient * scene.ambient_light + light[j];
        }
        for (i, (s, hit)) in surfaced.iter().zip(hits).enumerate() {
            if let (Some(s), Some(hit)) = (s, hit) {
                if s.mat.kind == MaterialKind::Plain {
                    // What `finish_shade` returns for a surface that neither reflects nor
                    // refracts, without the call.
                    out[i] = s.emitted + direct[i];
                    continue;
                }
                self.budget = SECONDARY_RAY_BUDGET;
                out[i] = self.finish_shade(
                    &rays[i],
                    hit,
                    0,
                    None,
                    self.spread * hit.t,
                    s,
                    s.emitted + direct[i],
                    &mut samplers[i],
                );
            }
        }
        out
    }

    /// Radiance along a camera ray whose first surface [`Self::camera_hits`] found (`None`: it
    /// misses everything).
    pub fn trace_primary(&mut self, ray: &Ray, hit: Option<SurfaceHit>, rng: &mut Sampler) -> DVec3 {
        self.stats.primary += 1;
        match self.renderer {
            Renderer::Classic => {
                self.budget = SECONDARY_RAY_BUDGET;
                self.trace_from(ray, hit, 0, None, 0.0, rng)
            }
            Renderer::Path(params) => self.trace_path(ray, hit, params, rng),
        }
    }

    /// Monte Carlo path tracing (§13.2): one path per camera sample. At each diffuse or glossy
    /// vertex the lights are sampled (with `NextEventEstimation`) and one direction is drawn
    /// (uniform, or from the cosine lobe with `ImportanceSampling`) with the throughput
    /// multiplied by `f·cos θ / pdf`; mirrors, conductors and dielectrics continue along their
    /// specular directions (a dielectric chooses reflection with probability `F`, refraction
    /// otherwise, which weighs each by exactly its Fresnel factor on average). Object lights
    /// and the environment count when a path reaches them unless the previous vertex already
    /// sampled them. Paths end after `MaxRecursionDepth` bounces, or at random by the rules of
    /// [`Roulette`] and after [`PATH_DEPTH_LIMIT`] bounces at the latest.
    ///
    /// Measured against the course's references (cornellbox_jaroslav_path_*): virtual lights
    /// (point, area, spot, directional) are sampled only with `NextEventEstimation` — without
    /// it they add nothing, since no path can hit them — and Russian roulette replaces the
    /// depth limit rather than adding to it.
    fn trace_path(
        &mut self,
        camera_ray: &Ray,
        camera_hit: Option<SurfaceHit>,
        params: PathParams,
        rng: &mut Sampler,
    ) -> DVec3 {
        let scene = self.scene;
        let nee = params.next_event;
        let max_bounces = match params.roulette {
            Roulette::Off => scene.max_recursion_depth,
            Roulette::Course | Roulette::Unbiased => PATH_DEPTH_LIMIT,
        };
        // The bounces that count towards `max_bounces` (all of them, or by the rule only the
        // diffuse and glossy ones); `bounce` counts every one, up to PATH_DEPTH_LIMIT.
        let mut counted = 0;
        let eps = scene.shadow_ray_epsilon;
        let mut ray = *camera_ray;
        let mut l = DVec3::ZERO;
        let mut beta = DVec3::ONE;
        // The absorption of the dielectric the path is inside (Beer's law per segment).
        let mut medium: Option<DVec3> = None;
        // Whether the last vertex was the camera or a specular one: lights reached now were
        // not sampled there, so they count.
        let mut specular = true;
        let mut cone = 0.0;
        let mut bounce = 0;
        // The product of the BRDF values of the path's diffuse and glossy vertices so far: the
        // course roulette's potential.
        let mut potential = DVec3::ONE;
        // With multiple importance sampling, where the last bounce left from and the density it
        // was drawn with, when it was drawn from a BRDF: what an object light it hits weighs.
        let mut drawn: Option<(DVec3, f64)> = None;
        let mis = params.mis && nee;
        let mut first = Some(camera_hit);
        loop {
            let found = match first.take() {
                Some(h) => h,
                None => self.closest(&ray, bounce),
            };
            let Some(hit) = found else {
                if let Some(env) = &scene.env_light {
                    if specular || !nee {
                        l += beta * env.radiance(ray.dir);
                    }
                } else {
                    l += beta * self.background;
                }
                break;
            };
            if let Some(c) = medium
                && c != DVec3::ZERO
            {
                beta *= (-c * hit.t).exp();
            }
            cone += self.spread * hit.t;
            // The light this vertex adds: what it emits, the ambient term and the lights
            // sampled here (weighted by the throughput once the roulette has spoken).
            let mut local = DVec3::ZERO;
            if let Some(le) = self.emitted(&ray, &hit) {
                if specular || !nee {
                    local += le;
                } else if let Some((from, pdf)) = drawn {
                    let light = light_pdf(
                        scene,
                        from,
                        ray.dir,
                        (hit.point, hit.geo_normal, hit.instance),
                        params.one_light,
                    );
                    local += le * power_heuristic(pdf, light);
                }
            }
            let mut slot = None;
            let (mat, shading_normal) = match self.surface(&ray, &hit, cone, &mut slot) {
                Ok(s) => s,
                Err(texel) => {
                    l += beta * texel;
                    break;
                }
            };
            let d = ray.dir;
            let front = d.dot(hit.geo_normal) < 0.0;
            // The shading normal on the side the path arrives from.
            let n = if front { shading_normal } else { -shading_normal };
            if bounce == 0 {
                local += mat.ambient * scene.ambient_light;
            }
            // Light sampled at this vertex: every light with NEE (virtual lights have no other
            // way in), nothing without; dielectrics only on their outside (§15 #20).
            let shaded = !(mat.kind == MaterialKind::Dielectric && medium.is_some());
            let continues = counted < max_bounces && bounce < PATH_DEPTH_LIMIT;
            if nee && shaded {
                let weights = mis.then(|| {
                    let chance = if continues { brdf_chance(mat, d, n) } else { 0.0 };
                    LightWeights { bounce: BounceDensity { cosine: params.importance, chance }, pick: 1.0 }
                });
                let pt = LitPoint { ray: &ray, x: hit.point, n, mat, world: hit.world };
                local += if params.one_light {
                    self.one_light(pt, weights, rng)
                } else {
                    self.lit_point(pt, true, None, weights, rng)
                };
            }
            if params.roulette == Roulette::Course {
                let q = potential.max_element().min(1.0);
                if rng.next_1d() >= q {
                    l += beta * local;
                    break;
                }
                beta /= q;
            }
            l += beta * local;
            if !continues {
                break;
            }
            // Whether this bounce is a refraction out of a dielectric.
            let mut leaves = false;
            if mat.kind == MaterialKind::Plain {
                let Some((wi, f, brdf)) = brdf_bounce(n, -d, mat, params.importance, rng) else { break };
                beta *= f;
                potential *= brdf;
                drawn = mis.then(|| (hit.point, density(params.importance, n, wi)));
                ray = ray.spawn(hit.point + eps * n, wi);
                specular = false;
            } else {
                let at = Arrival { x: hit.point, n, shading_normal, d, front, inside: medium.is_some() };
                let sides = scene.rules.dielectric_sides;
                let Some(next) = scatter(mat, &at, sides, params.importance, eps, rng) else { break };
                if let Some(w) = next.weight {
                    beta *= w;
                }
                if let Some((brdf, pdf)) = next.brdf {
                    potential *= brdf;
                    drawn = mis.then_some((hit.point, pdf));
                }
                if let Some(m) = next.refracted {
                    medium = m;
                }
                leaves = next.leaves();
                specular = next.specular();
                ray = ray.spawn(next.origin, next.dir);
            }
            self.stats.secondary += 1;
            bounce += 1;
            counted += scene.rules.path_depth.counts(specular, leaves);
            if params.roulette == Roulette::Unbiased {
                let q = beta.max_element().min(1.0);
                if rng.next_1d() >= q {
                    break;
                }
                beta /= q;
            }
            if beta == DVec3::ZERO || !beta.is_finite() {
                break;
            }
        }
        l
    }

    /// Radiance arriving along `ray`. `medium` is the absorption coefficient of the dielectric
    /// the ray travels inside, if any (Beer's law applies over the segment's length). `cone` is
    /// the width of the pixel's ray cone at the ray's origin (0 at a pinhole camera); it grows
    /// by `spread` per unit of distance (curved mirrors and lenses are not modelled).
    fn trace(&mut self, ray: &Ray, depth: u32, medium: Option<DVec3>, cone: f64, rng: &mut Sampler) -> DVec3 {
        let hit = self.closest(ray, depth);
        self.trace_from(ray, hit, depth, medium, cone, rng)
    }

    /// [`Self::trace`] with the ray's first surface `hit` already found.
    fn trace_from(
        &mut self,
        ray: &Ray,
        hit: Option<SurfaceHit>,
        depth: u32,
        medium: Option<DVec3>,
        cone: f64,
        rng: &mut Sampler,
    ) -> DVec3 {
        let scene = self.scene;
        let Some(hit) = hit else {
            // Rays that miss see the environment (§5.6), else the background.
            return match &scene.env_light {
                Some(env) => env.radiance(ray.dir),
                None => self.background,
            };
        };
        let cone = cone + self.spread * hit.t;
        let l = self.shade(ray, &hit, depth, medium, cone, rng);
        match medium {
            Some(c) if c != DVec3::ZERO => l * (-c * hit.t).exp(),
            _ => l,
        }
    }

    /// The surface a ray at `depth` (0: a camera ray) sees first, if any. Camera rays of 2025
    /// scenes look past triangles seen from behind (`Scene::cull_camera_back_faces`).
    fn closest(&self, ray: &Ray, depth: u32) -> Option<SurfaceHit> {
        let scene = self.scene;
        let cull = depth == 0 && scene.cull_camera_back_faces;
        let mut tmin = scene.intersection_test_epsilon;
        let mut culled = 0;
        loop {
            let hit = scene.accel.intersect(ray, tmin, f64::INFINITY)?;
            if cull
                && culled < CULLED_HITS_LIMIT
                && ray.dir.dot(hit.geo_normal) > 0.0
                && scene.accel.is_triangle(hit.instance)
            {
                // Culled: look again beyond it. The step is relative, and taken from the larger
                // of the hit and the old bound: the f64 re-intersection may put a hit the f32
                // traversal found just past `tmin` slightly before it, and stepping from such
                // a hit once gave the same bound again, for ever.
                culled += 1;
                tmin = hit.t.max(tmin) * (1.0 + 1e-6) + scene.intersection_test_epsilon;
                continue;
            }
            return Some(hit);
        }
    }

    /// The radiance an object light emits towards the ray that hit it: its `Radiance` on its
    /// front side (a mesh's counter-clockwise side, a sphere's outside; §9.6, §13.3), else 0.
    #[inline]
    fn emitted(&self, ray: &Ray, hit: &SurfaceHit) -> Option<DVec3> {
        let le = (*self.scene.instance_emission.get(hit.instance as usize)?)?;
        (ray.dir.dot(hit.geo_normal) < 0.0).then_some(le)
    }

    /// The material and shading normal at a hit after its texture maps (§11.6): the normal or
    /// bump map first, then up to two colour maps on a copy of the material, which goes into
    /// `slot`. `Err` holds the texel of a `replace_all` map, which is the surface's radiance (no
    /// lights, no recursion).
    #[inline]
    fn surface<'m>(&self, ray: &Ray, hit: &SurfaceHit, cone: f64, slot: &'m mut Option<Material>) -> Looks<'m>
    where
        'a: 'm,
    {
        match self.plain_surface(hit) {
            Some(plain) => Ok(plain),
            None => self.textured_surface(ray, hit, cone, slot),
        }
    }

    /// [`Self::surface`] of a hit on an object without texture maps: its material and normal
    /// as they are (`None` for a textured object).
    #[inline(always)]
    fn plain_surface(&self, hit: &SurfaceHit) -> Option<(&'a Material, DVec3)> {
        let scene = self.scene;
        let textures = scene.accel.instances[hit.instance as usize].textures;
        (textures.normal.is_none() && textures.colour[0].is_none())
            .then(|| (&scene.materials[hit.material as usize], hit.shading_normal))
    }

    /// [`Self::surface`] of a hit on an object with texture maps.
    #[inline(never)]
    fn textured_surface<'m>(
        &self,
        ray: &Ray,
        hit: &SurfaceHit,
        cone: f64,
        slot: &'m mut Option<Material>,
    ) -> Looks<'m>
    where
        'a: 'm,
    {
        let scene = self.scene;
        let mat = &scene.materials[hit.material as usize];
        let instance = &scene.accel.instances[hit.instance as usize];
        let textures = instance.textures;
        let mut shading_normal = hit.shading_normal;
        let d = ray.dir;
        let footprint = if self.spread > 0.0 { uv_footprint(hit, d, cone) } else { DVec2::ZERO };
        let object = instance.object_point(hit.point, ray.time);
        let p = TexturePoint { uv: hit.uv, object, footprint };
        if let Some(k) = textures.normal {
            shading_normal = perturbed_normal(&scene.textures[k as usize], hit, instance, &p, shading_normal);
        }
        if textures.colour[0].is_none() {
            return Ok((mat, shading_normal));
        }
        let mut m = mat.clone();
        let more = textures.more_colour.map_or(&[][..], |i| &scene.more_colour_maps[i as usize][..]);
        for k in textures.colour.into_iter().flatten().chain(more.iter().copied()) {
            let map = &scene.textures[k as usize];
            let t = map.value(&p);
            match map.decal {
                DecalMode::ReplaceAll => return Err(t),
                DecalMode::ReplaceKd => m.diffuse = t,
                DecalMode::BlendKd => m.diffuse = (m.diffuse + t) / 2.0,
                DecalMode::ReplaceKs => m.specular = t,
                _ => {}
            }
        }
        Ok((slot.insert(m), shading_normal))
    }

    fn shade(
        &mut self,
        ray: &Ray,
        hit: &SurfaceHit,
        depth: u32,
        medium: Option<DVec3>,
        cone: f64,
        rng: &mut Sampler,
    ) -> DVec3 {
        let mut slot = None;
        let s = match self.begin_shade(ray, hit, cone, &mut slot) {
            Ok(s) => s,
            Err(texel) => return texel,
        };
        let direct = match s.lit_normal(medium.is_some()) {
            Some(n) => self.direct(ray, hit.point, n, s.mat, rng),
            None => DVec3::ZERO,
        };
        self.finish_shade(ray, hit, depth, medium, cone, &s, s.emitted + direct, rng)
    }

    /// The first part of [`Self::shade`]: what the surface shows before its lights. `Err` holds
    /// the texel of a `replace_all` map, which is the surface's radiance. A material changed by
    /// colour maps goes into `slot`.
    #[inline(always)]
    fn begin_shade<'m>(
        &self,
        ray: &Ray,
        hit: &SurfaceHit,
        cone: f64,
        slot: &'m mut Option<Material>,
    ) -> Result<Surfaced<'m>, DVec3>
    where
        'a: 'm,
    {
        let entering = ray.dir.dot(hit.geo_normal) < 0.0;
        // An object light seen directly or through mirrors and glass shows its radiance.
        let emitted = self.emitted(ray, hit).unwrap_or(DVec3::ZERO);
        // The untextured case spelled out rather than through `surface`'s `Result`: its
        // `?` went through a stack copy whose 16-byte load straddled two stores (a failed
        // store-to-load forward on every hit).
        let (mat, shading_normal) = match self.plain_surface(hit) {
            Some(plain) => plain,
            None => self.textured_surface(ray, hit, cone, slot)?,
        };
        Ok(Surfaced { emitted, mat, shading_normal, entering })
    }

    /// The last part of [`Self::shade`]: `l` (emission and direct light) plus what mirrors,
    /// conductors and dielectrics reflect and refract. `medium` is what the ray travels inside.
    #[allow(clippy::too_many_arguments)]
    fn finish_shade(
        &mut self,
        ray: &Ray,
        hit: &SurfaceHit,
        depth: u32,
        medium: Option<DVec3>,
        cone: f64,
        s: &Surfaced<'_>,
        mut l: DVec3,
        rng: &mut Sampler,
    ) -> DVec3 {
        let scene = self.scene;
        let d = ray.dir;
        let (mat, n, entering) = (s.mat, s.facing(), s.entering);
        let eps = scene.shadow_ray_epsilon;
        // Depth is capped when the scene is read (MAX_RECURSION_DEPTH_LIMIT), and so is the
        // stack; the budget bounds the work of a tree of splitting rays.
        let can_recurse = depth < scene.max_recursion_depth
            && self.budget >= 2
            && matches!(mat.kind, MaterialKind::Mirror | MaterialKind::Conductor | MaterialKind::Dielectric);
        if can_recurse {
            self.budget -= 2;
        }
        match mat.kind {
            MaterialKind::Plain => {}
            MaterialKind::Mirror | MaterialKind::Conductor if can_recurse => {
                let weight = if mat.kind == MaterialKind::Conductor {
                    mat.mirror * fresnel_conductor(-d.dot(n), mat.refraction_index, mat.absorption_index)
                } else {
                    mat.mirror
                };
                if weight != DVec3::ZERO {
                    let r = glossy(reflect(d, n), mat.roughness, rng);
                    self.stats.secondary += 1;
                    // The reflected ray starts on the front side, with the normal as given, like
                    // the shadow rays (§6.8, measured on thin blades seen from behind).
                    let o = hit.point + eps * s.shading_normal;
                    l += weight * self.trace(&ray.spawn(o, r), depth + 1, None, cone, rng);
                }
            }
            MaterialKind::Dielectric if can_recurse => {
                let eta = mat.refraction_index;
                // The reflected ray stays on the incoming side; the refracted one crosses.
                let (into, refl_medium, refr_medium) = match scene.rules.dielectric_sides {
                    DielectricSides::FaceSide if entering => (true, None, Some(mat.absorption)),
                    DielectricSides::FaceSide => (false, Some(mat.absorption), None),
                    DielectricSides::Flag if medium.is_none() => (true, None, Some(mat.absorption)),
                    DielectricSides::Flag => (false, medium, None),
                };
                let (n1, n2) = if into { (1.0, eta) } else { (eta, 1.0) };
                // Rough glass blurs both directions, each with its own two random numbers, as a
                // rough mirror does (§6.7, measured on metal_glass_plates).
                let reflected = ray.spawn(hit.point + eps * n, glossy(reflect(d, n), mat.roughness, rng));
                match refract(d, n, n1, n2) {
                    Refraction::Total => {
                        self.stats.secondary += 1;
                        l += self.trace(&reflected, depth + 1, refl_medium, cone, rng);
                    }
                    Refraction::Split { fr, dir } => {
                        self.stats.secondary += 2;
                        l += fr * self.trace(&reflected, depth + 1, refl_medium, cone, rng);
                        let refracted = ray.spawn(hit.point - eps * n, glossy(dir, mat.roughness, rng));
                        l += (1.0 - fr) * self.trace(&refracted, depth + 1, refr_medium, cone, rng);
                    }
                }
            }
            _ => {}
        }
        l
    }

    /// Ambient plus Blinn-Phong from every light with shadow rays (§5, §6.2, §6.3): point,
    /// directional and spot lights exactly, one sample of every area light and one direction of
    /// the environment light. `n` faces the incoming `ray`.
    fn direct(&mut self, ray: &Ray, x: DVec3, n: DVec3, mat: &Material, rng: &mut Sampler) -> DVec3 {
        mat.ambient * self.scene.ambient_light + self.lights(ray, x, n, mat, true, rng)
    }

    /// Light reflected towards the viewer of `ray` at `x` from one sample of every light: point,
    /// directional and spot lights exactly, one point of every area and object light, and (when
    /// `env`) one direction of the environment light. `n` is the normal to shade with.
    fn lights(
        &mut self,
        ray: &Ray,
        x: DVec3,
        n: DVec3,
        mat: &Material,
        env: bool,
        rng: &mut Sampler,
    ) -> DVec3 {
        self.lit_point(LitPoint { ray, x, n, mat, world: u32::MAX }, env, None, None, rng)
    }

    /// [`Self::lights_of`] for one point with its sampler: every light or `only` one, object
    /// lights' samples weighed by `weights` under multiple importance sampling.
    fn lit_point(
        &mut self,
        pt: LitPoint<'_>,
        env: bool,
        only: Option<usize>,
        weights: Option<LightWeights>,
        rng: &mut Sampler,
    ) -> DVec3 {
        let mut rngs = [rng.clone()];
        let l = self.lights_of::<1>(&[pt], env, only, weights, &mut rngs);
        *rng = rngs[0].clone();
        l[0]
    }

    /// `SampleOneLight`'s estimate of [`Self::lights`]: one light chosen by power
    /// ([`crate::lights::choice::LightChoice`], one number drawn), its light divided by the choice's
    /// probability. The light's numbers come from the [`ONE_LIGHT_REQUESTS`] requests that
    /// follow the pick, whichever light it is.
    fn one_light(&mut self, pt: LitPoint<'_>, weights: Option<LightWeights>, rng: &mut Sampler) -> DVec3 {
        let pick = self.scene.light_choice.pick(rng.next_1d());
        let start = rng.drawn();
        let l = match pick {
            Some((light, p)) => {
                let weights = weights.map(|w| LightWeights { pick: p, ..w });
                self.lit_point(pt, true, Some(light), weights, rng) / p
            }
            None => DVec3::ZERO,
        };
        debug_assert!(rng.drawn() <= start + ONE_LIGHT_REQUESTS, "a light drew more than it reserves");
        rng.skip_to(start + ONE_LIGHT_REQUESTS);
        l
    }

    /// [`Lighting::reflected`] in this tracer's scene, counting its shadow rays.
    #[inline(always)]
    fn lights_lanes<const N: usize>(
        &mut self,
        pts: &[LitPoint<'_>],
        env: bool,
        rngs: &mut [Sampler],
    ) -> [DVec3; N] {
        self.lights_of(pts, env, None, None, rngs)
    }

    /// [`Self::lights_lanes`] of every light (`only` `None`) or of one.
    #[inline(always)]
    fn lights_of<const N: usize>(
        &mut self,
        pts: &[LitPoint<'_>],
        env: bool,
        only: Option<usize>,
        mis: Option<LightWeights>,
        rngs: &mut [Sampler],
    ) -> [DVec3; N] {
        let mut lighting = Lighting {
            scene: self.scene,
            env_sampler: self.env_sampler,
            shadow_rays: 0,
            only,
            mis,
            horizons: self.horizons,
        };
        let l = lighting.reflected(pts, env, rngs);
        self.stats.shadow += lighting.shadow_rays;
        l
    }
}

/// What [`Tracer::surface`] finds: the material and shading normal after the texture maps, or
/// (`Err`) the texel of a `replace_all` map.
type Looks<'m> = Result<(&'m Material, DVec3), DVec3>;

/// A surface a ray found, ready for its lights: see [`Tracer::begin_shade`].
struct Surfaced<'a> {
    /// What an object light emits towards the ray (zero for other surfaces).
    emitted: DVec3,
    /// The material after the colour maps.
    mat: &'a Material,
    /// The shading normal after normal and bump maps, on the geometric normal's side.
    shading_normal: DVec3,
    /// Whether the ray arrives on the front side of the geometry.
    entering: bool,
}

impl Surfaced<'_> {
    /// The shading normal facing the incoming ray: where a dielectric's reflected ray starts,
    /// and the normal dielectrics shade and refract with (they track entering and leaving).
    #[inline]
    fn facing(&self) -> DVec3 {
        if self.entering { self.shading_normal } else { -self.shading_normal }
    }

    /// The normal the lights are computed with, if any. Local shading is skipped for hits seen
    /// from inside a dielectric (§6.4, §15 #20). Opaque surfaces are lit with their normal as
    /// given, never turned towards the viewer (§6.8, measured on grass_desert): one seen from
    /// behind is lit by the lights on its front side, and its shadow rays start on that side.
    fn lit_normal(&self, inside: bool) -> Option<DVec3> {
        match self.mat.kind {
            MaterialKind::Dielectric if inside => None,
            MaterialKind::Dielectric => Some(self.facing()),
            _ => Some(self.shading_normal),
        }
    }
}

/// The shading normal after a normal map or bump map (§11.6a, §11.7); `n` is the unperturbed
/// unit shading normal, on the geometric normal's side.
fn perturbed_normal(
    map: &TextureMap,
    hit: &SurfaceHit,
    instance: &Instance,
    p: &TexturePoint,
    n: DVec3,
) -> DVec3 {
    let bent = match (map.decal, &map.source) {
        (DecalMode::ReplaceNormal, _) => {
            let Some(nt) = map.tangent_normal(p.uv, p.footprint) else { return n };
            let Some((t, b)) = tangent_basis(n, hit.dpdu, hit.dpdv) else { return n };
            nt.x * t + nt.y * b + nt.z * n
        }
        (DecalMode::BumpNormal, source @ Source::Image { image, normalizer, .. }) => {
            if hit.dpdu == DVec3::ZERO || hit.dpdv == DVec3::ZERO {
                return n;
            }
            // Blinn's bump mapping: height slopes added along the normal to the unnormalised
            // ∂p/∂u, ∂p/∂v.
            let (w, h) = (image.width as f64, image.height as f64);
            let height = |du: f64, dv: f64| image_height(source, p, du, dv);
            let h0 = height(0.0, 0.0);
            // Measured against the references: the height slope is the difference of
            // neighbouring texels on the 0-255 scale (h · Normalizer), per texel — not per unit
            // of u — so it does not grow with the image's resolution. sphere_nobump_bump: 39.7 dB
            // with true per-uv derivatives, 55.7 dB this way; bump_mapping_transformed 21.6 ->
            // 40.6 dB (PSNR after the 4x4 box).
            let dhdu = (height(1.0 / w, 0.0) - h0) * *normalizer;
            let dhdv = (height(0.0, 1.0 / h) - h0) * *normalizer;
            // The height displaces along `bump_axis`. For meshes that is the object-space normal
            // carried to world space (relief scales with the object: the floor of
            // bump_mapping_transformed, scaled by -0.05, needs exactly that length — 0.04 or
            // 0.06 instead fall to 45 / 50 dB). For spheres it is the unit world normal, with
            // ∂p/∂u, ∂p/∂v still carried by the transformation: on the (-2, 1, 1)-scaled sphere
            // of bump_mapping_transformed that takes 4.8 % of pixels off by >3 down to 0.24 %
            // (box4 40.6 -> 52.1 dB); its length is sharp (0.9 or 1.1 give ~47 dB, 4 %). The
            // handedness flip of the mirroring transforms needs nothing special: q_v × q_u is
            // oriented to the side of `n` below, which is the mirror image of the object-space
            // result.
            let axis = hit.bump_axis;
            let qu = hit.dpdu + map.bump_factor * dhdu * axis;
            let qv = hit.dpdv + map.bump_factor * dhdv * axis;
            let c = qv.cross(qu);
            if c.dot(n) < 0.0 { -c } else { c }
        }
        (DecalMode::BumpNormal, Source::Perlin { conversion, scale, octaves }) => {
            // The height field lives in object space (like the noise's colour); its gradient
            // is a covector, carried to world space by the normal matrix.
            let g = perlin_gradient(p.object, *scale, *conversion, *octaves);
            let g = match &instance.transform {
                Some(xf) => xf.normal_matrix * g,
                None => g,
            };
            return bump_by_gradient(n, g, map.bump_factor);
        }
        _ => return n,
    };
    let len = bent.length();
    if len > 1e-12 && len.is_finite() { bent / len } else { n }
}

/// Extent (Δu, Δv) in texture coordinates of a ray cone of width `cone` meeting the surface at
/// `hit` along the unit direction `d`: the mip footprint of trilinear maps (see
/// [`crate::texture::mip`]). The cone's cross-section is spanned by `e1`, the direction of the
/// normal seen across the ray, and `e2 = d × e1`; projected along `d` onto the tangent plane
/// they become `cone·(e1 − d (e1·n)/(d·n))` (stretched by 1/|cos θ|, at most 1000x) and
/// `cone·e2`, the two (full-width) axes of an ellipse, which are expressed in ∂p/∂u, ∂p/∂v by
/// least squares. (Δu, Δv) is the ellipse's bounding box in uv: `Δu = √(a1u² + a2u²)`, likewise Δv, so
/// a circular footprint does not depend on how the cross-section axes happen to be turned. Zero
/// where the surface has no usable parametrisation.
fn uv_footprint(hit: &SurfaceHit, d: DVec3, cone: f64) -> DVec2 {
    let (pu, pv) = (hit.dpdu, hit.dpdv);
    let (uu, uv, vv) = (pu.dot(pu), pu.dot(pv), pv.dot(pv));
    let det = uu * vv - uv * uv;
    // Also false for NaN: a degenerate or broken parametrisation reads level 0.
    let usable = det > 1e-12 * uu * vv;
    if !usable || !cone.is_finite() || cone <= 0.0 {
        return DVec2::ZERO;
    }
    let n = hit.geo_normal;
    let cos = d.dot(n);
    let across = n - d * cos;
    let (e1, e2) = match across.try_normalize() {
        Some(e1) => (e1, d.cross(e1)),
        None => orthonormal_pair(d),
    };
    let cos = if cos.abs() < 1e-3 { 1e-3f64.copysign(cos) } else { cos };
    let a1 = cone * (e1 - d * (e1.dot(n) / cos));
    let a2 = cone * e2;
    // Least squares a ≈ du·∂p/∂u + dv·∂p/∂v.
    let to_uv = |a: DVec3| {
        let (r1, r2) = (a.dot(pu), a.dot(pv));
        DVec2::new((vv * r1 - uv * r2) / det, (uu * r2 - uv * r1) / det)
    };
    let (f1, f2) = (to_uv(a1), to_uv(a2));
    let f = DVec2::new(f1.x.hypot(f2.x), f1.y.hypot(f2.y));
    if f.is_finite() { f } else { DVec2::ZERO }
}

/// Unit tangent and bitangent of a surface point from ∂p/∂u and ∂p/∂v, made perpendicular to
/// `n` (Gram-Schmidt); `None` where the surface has no texture parametrisation.
fn tangent_basis(n: DVec3, dpdu: DVec3, dpdv: DVec3) -> Option<(DVec3, DVec3)> {
    let t = (dpdu - n * n.dot(dpdu)).try_normalize()?;
    let b = (dpdv - n * n.dot(dpdv) - t * t.dot(dpdv)).try_normalize()?;
    Some((t, b))
}

#[cfg(test)]
mod tests {
    use super::{SurfaceHit, uv_footprint};
    use crate::assets::FsResolver;
    use glam::{DVec2, DVec3};

    /// A hit on the plane z = 0 (normal +z) with ∂p/∂u = (su, 0, 0), ∂p/∂v = (0, sv, 0).
    fn plane_hit(su: f64, sv: f64) -> SurfaceHit {
        SurfaceHit {
            t: 1.0,
            point: DVec3::ZERO,
            geo_normal: DVec3::Z,
            shading_normal: DVec3::Z,
            material: 0,
            instance: 0,
            uv: DVec2::ZERO,
            dpdu: DVec3::new(su, 0.0, 0.0),
            dpdv: DVec3::new(0.0, sv, 0.0),
            bump_axis: DVec3::Z,
            world: u32::MAX,
        }
    }

    #[test]
    fn footprints_scale_with_the_cone_and_stretch_at_grazing_angles() {
        let close = |a: DVec2, b: DVec2| (a - b).abs().max_element() < 1e-12;
        // Head-on: a cone of width 0.1 covers 0.1 / |∂p/∂u| in u, 0.1 / |∂p/∂v| in v.
        let hit = plane_hit(2.0, 4.0);
        let f = uv_footprint(&hit, DVec3::NEG_Z, 0.1);
        assert!(close(f, DVec2::new(0.05, 0.025)), "{f}");
        assert!(close(uv_footprint(&hit, DVec3::NEG_Z, 0.2), 2.0 * f));
        // 60° from the normal in the xz plane: stretched by 1 / cos 60° = 2 along u only.
        let d = DVec3::new(60f64.to_radians().sin(), 0.0, -60f64.to_radians().cos());
        let f = uv_footprint(&hit, d, 0.1);
        assert!(close(f, DVec2::new(0.1, 0.025)), "{f}");
        // Turned about the normal (∂p/∂u along the diagonal): a head-on circle stays a circle.
        let mut turned = plane_hit(1.0, 1.0);
        turned.dpdu = DVec3::new(1.0, 1.0, 0.0) / 2f64.sqrt();
        turned.dpdv = DVec3::new(-1.0, 1.0, 0.0) / 2f64.sqrt();
        assert!(close(uv_footprint(&turned, DVec3::NEG_Z, 0.1), DVec2::splat(0.1)));
        // No parametrisation, no cone, grazing or garbage: finite.
        assert_eq!(uv_footprint(&plane_hit(0.0, 1.0), DVec3::NEG_Z, 0.1), DVec2::ZERO);
        assert_eq!(uv_footprint(&hit, DVec3::NEG_Z, 0.0), DVec2::ZERO);
        assert_eq!(uv_footprint(&hit, DVec3::NEG_Z, f64::NAN), DVec2::ZERO);
        assert!(uv_footprint(&hit, DVec3::X, 0.1).is_finite());
        assert!(uv_footprint(&hit, DVec3::new(f64::NAN, 0.0, -1.0), 0.1).is_finite());
    }
    use crate::image::TileRect;
    use crate::render::{RenderSettings, render_tile};
    use crate::scene::DielectricSides;
    use crate::scene::load::load_scene_str;
    use crate::scene::records::EnvSampler;

    /// A white diffuse floor at y = 0 seen straight from above, lit only by `lights`.
    fn floor_pixel(lights: &str, extra_objects: &str) -> [f32; 3] {
        let xml = format!(
            r#"<Scene><MaxRecursionDepth>1</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 5 0</Position><Gaze>0 -1 0</Gaze><Up>0 0 -1</Up>
              <NearPlane>-0.1 0.1 -0.1 0.1</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>1 1</ImageResolution><ImageName>a.png</ImageName></Camera></Cameras>
            <Lights>{lights}</Lights>
            <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
            <VertexData>-50 0 -50  50 0 -50  50 0 50  -50 0 50  0 20 0</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 3 2  1 4 3</Faces></Mesh>{extra_objects}</Objects>
            </Scene>"#
        );
        let scene = load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
            .unwrap();
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        render_tile(&scene, 0, rect, &RenderSettings::default()).0[0]
    }

    /// The pixel a camera below a thin mirror blade sees (§6.8 tests): the blade lies at y = 0,
    /// faces up, is lit from above by I = 400 at distance 4 and has kd 0.5 and mirror 0.5;
    /// `camera` adds to the camera (samples, renderer). Also the renderer the camera got.
    fn blade_pixel(camera: &str) -> (crate::scene::records::Renderer, [f32; 3]) {
        let xml = format!(
            r#"<Scene><MaxRecursionDepth>1</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 -5 0</Position><Gaze>0 1 0</Gaze><Up>0 0 -1</Up>
              <NearPlane>-0.1 0.1 -0.1 0.1</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>1 1</ImageResolution>{camera}</Camera></Cameras>
            <Lights><PointLight id="1"><Position>0 4 0</Position><Intensity>400 400 400</Intensity></PointLight></Lights>
            <Materials><Material id="1" type="mirror"><DiffuseReflectance>0.5 0.5 0.5</DiffuseReflectance>
              <MirrorReflectance>0.5 0.5 0.5</MirrorReflectance></Material></Materials>
            <VertexData>-5 0 -5  5 0 -5  5 0 5  -5 0 5</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 3 2  1 4 3</Faces></Mesh></Objects>
            </Scene>"#
        );
        let scene = load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
            .unwrap();
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        (scene.cameras[0].renderer, render_tile(&scene, 0, rect, &RenderSettings::default()).0[0])
    }

    /// A thin mirror blade seen from behind (§6.8): its reflected ray starts on its front side,
    /// like its shadow rays, so heading back to the viewer's side it first meets the blade's own
    /// lit front face: kd·I/d² = 0.5·25 directly, plus mirror 0.5 times the front face's 12.5.
    #[test]
    fn a_mirror_seen_from_behind_reflects_from_its_front_side() {
        let (_, p) = blade_pixel("<ImageName>a.png</ImageName>");
        for c in p {
            assert!((c - 18.75).abs() < 1e-3, "{p:?}: the reflection sees the lit front face");
        }
    }

    /// The same blade in the path tracer (§6.8 holds in every renderer): its mirror bounce
    /// starts on the front side and meets the blade's own lit front face, whose light (sampled
    /// there with NEE, kd·I/d² = 12.5) is all the pixel gets. The vertex seen from behind picks
    /// the mirror lobe with probability 0.5 (mirror 0.5 against kd 0.5) and keeps its weight
    /// (0.5/0.5); its own lights and its BRDF bounce face away from the light and the scene, so
    /// the pixel is 0.5·12.5 on average. A reflection started on the viewer's side sees nothing.
    #[test]
    fn a_path_traced_mirror_seen_from_behind_reflects_from_its_front_side() {
        let (renderer, p) = blade_pixel(
            "<ImageName>a.exr</ImageName><NumSamples>256</NumSamples>
              <Renderer>PathTracing</Renderer><RendererParams>NextEventEstimation</RendererParams>",
        );
        assert!(matches!(renderer, crate::scene::records::Renderer::Path(_)));
        for c in p {
            assert!((c - 6.25).abs() < 0.5, "{p:?}: the path's reflection sees the lit front face");
        }
    }

    /// A dielectric met from behind by a ray from outside is entered (`DielectricSides::Flag`,
    /// the measured default): the ray carries whether it is inside, whatever side of a triangle
    /// it meets. A glass sheet whose normal faces away from the camera (normal incidence,
    /// F = 0.04), absorption 0.5, then a wall 2 further lit to 1: the refracted ray travels
    /// inside, 0.96·e^(−0.5·2) ≈ 0.353. Reading the face's side instead leaves it (0.96,
    /// unabsorbed). Both renderers; the path tracer picks refraction with probability 0.96.
    #[test]
    fn a_dielectric_met_from_behind_is_entered_by_a_ray_from_outside() {
        let camera = |id: u32, renderer: &str| {
            format!(
                r#"<Camera id="{id}"><Position>0 0 5</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-0.001 0.001 -0.001 0.001</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>1 1</ImageResolution><ImageName>{id}.exr</ImageName>
              <NumSamples>256</NumSamples>{renderer}</Camera>"#
            )
        };
        let xml = format!(
            r#"<Scene><MaxRecursionDepth>1</MaxRecursionDepth>
            <Cameras>{}{}</Cameras>
            <Lights><PointLight id="1"><Position>0 0 -1</Position><Intensity>1 1 1</Intensity></PointLight></Lights>
            <Materials><Material id="1" type="dielectric"><RefractionIndex>1.5</RefractionIndex>
              <AbsorptionCoefficient>0.5 0.5 0.5</AbsorptionCoefficient></Material>
              <Material id="2"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
            <VertexData>-9 -9 0  9 -9 0  9 9 0  -9 9 0  -9 -9 -2  9 -9 -2  9 9 -2  -9 9 -2</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 3 2  1 4 3</Faces></Mesh>
              <Mesh id="2"><Material>2</Material><Faces>5 6 7  5 7 8</Faces></Mesh></Objects>
            </Scene>"#,
            camera(1, ""),
            camera(2, "<Renderer>PathTracing</Renderer><RendererParams>NextEventEstimation</RendererParams>")
        );
        let mut scene =
            load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
                .unwrap();
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        let inside = 0.96 * (-0.5f32 * 1.999).exp();
        for (rules, want) in [(DielectricSides::Flag, inside), (DielectricSides::FaceSide, 0.96)] {
            scene.rules.dielectric_sides = rules;
            for (cam, tolerance) in [(0, 2e-3), (1, 0.03)] {
                let p = render_tile(&scene, cam, rect, &RenderSettings::default()).0[0];
                for c in p {
                    assert!((c - want).abs() < tolerance, "{rules:?}, camera {cam}: {p:?}, expected {want}");
                }
            }
        }
        assert_eq!(crate::scene::ShadingRules::default().dielectric_sides, DielectricSides::Flag);
    }

    /// Any number of colour maps, applied in the order the object names them; the last normal
    /// or bump map is the one used. A white floor lit to 25 (kd 1), with constant checkerboards.
    #[test]
    fn colour_maps_apply_in_order_and_the_last_normal_map_wins() {
        let pixel = |list: &str| {
            let xml = format!(
                r#"<Scene><MaxRecursionDepth>1</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 5 0</Position><Gaze>0 -1 0</Gaze><Up>0 0 -1</Up>
              <NearPlane>-0.1 0.1 -0.1 0.1</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>1 1</ImageResolution><ImageName>a.png</ImageName></Camera></Cameras>
            <Lights><PointLight id="1"><Position>0 4 0</Position><Intensity>400 400 400</Intensity></PointLight></Lights>
            <Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
            <Textures>
              <TextureMap id="r" type="checkerboard"><DecalMode>replace_kd</DecalMode><BlackColor>1 0 0</BlackColor><WhiteColor>1 0 0</WhiteColor></TextureMap>
              <TextureMap id="g" type="checkerboard"><DecalMode>replace_kd</DecalMode><BlackColor>0 1 0</BlackColor><WhiteColor>0 1 0</WhiteColor></TextureMap>
              <TextureMap id="b" type="checkerboard"><DecalMode>blend_kd</DecalMode><BlackColor>0 0 1</BlackColor><WhiteColor>0 0 1</WhiteColor></TextureMap>
              <TextureMap id="tilt" type="perlin"><DecalMode>bump_normal</DecalMode><NoiseScale>3</NoiseScale><BumpFactor>5</BumpFactor></TextureMap>
              <TextureMap id="flat" type="checkerboard"><DecalMode>bump_normal</DecalMode></TextureMap>
            </Textures>
            <VertexData>-50 0 -50  50 0 -50  50 0 50  -50 0 50</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Textures>{list}</Textures><Faces>1 3 2  1 4 3</Faces></Mesh></Objects>
            </Scene>"#
            );
            let scene =
                load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
                    .unwrap();
            let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
            render_tile(&scene, 0, rect, &RenderSettings::default()).0[0]
        };
        // r, then g, then b blended in: kd = (g + b) / 2.
        assert_eq!(pixel("r g b"), [0.0, 12.5, 12.5]);
        // b blended into white, then g, then r: red.
        assert_eq!(pixel("b g r"), [25.0, 0.0, 0.0]);
        // The checkerboard "bump" map is flat (its height has no slope): last, it leaves the
        // normal as it is; first, the Perlin map after it bends the normal and dims the floor.
        assert_eq!(pixel("g tilt flat"), [0.0, 25.0, 0.0]);
        assert!(pixel("g flat tilt")[1] < 24.9);
    }

    #[test]
    fn a_deep_tree_of_glass_rays_stops_at_the_budget() {
        // The camera inside two nested glass spheres: every hit splits in two, so depth 64 would
        // be 2^64 rays; the scene's depth is capped and the sample's rays are counted.
        let xml = r#"<Scene><MaxRecursionDepth>1000000</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-0.1 0.1 -0.1 0.1</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>1 1</ImageResolution><ImageName>a.png</ImageName></Camera></Cameras>
            <Lights><PointLight id="1"><Position>0 0.5 0</Position><Intensity>1 1 1</Intensity></PointLight></Lights>
            <Materials><Material id="1" type="dielectric"><RefractionIndex>1.5</RefractionIndex>
              <AbsorptionCoefficient>0 0 0</AbsorptionCoefficient></Material></Materials>
            <VertexData>0 0 0  0 0 0.3</VertexData>
            <Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>2</Radius></Sphere>
              <Sphere id="2"><Material>1</Material><Center>2</Center><Radius>1.5</Radius></Sphere></Objects>
            </Scene>"#;
        let scene =
            load_scene_str(xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() }).unwrap();
        assert_eq!(scene.max_recursion_depth, crate::scene::records::MAX_RECURSION_DEPTH_LIMIT);
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        let (px, stats) = render_tile(&scene, 0, rect, &RenderSettings::default());
        assert!(px[0].iter().all(|c| c.is_finite()));
        // Deeper than the course's depths (127 rays at depth 6), never past the budget.
        assert!(
            stats.secondary > 1000 && stats.secondary <= u64::from(super::SECONDARY_RAY_BUDGET),
            "{} secondary rays",
            stats.secondary
        );
    }

    #[test]
    fn point_light_falls_off_with_inverse_square() {
        // I / d² · cos = 400 / 4² · 1 = 25.
        let p = floor_pixel(
            "<PointLight id=\"1\"><Position>0 4 0</Position><Intensity>400 400 400</Intensity></PointLight>",
            "",
        );
        assert!((p[0] - 25.0).abs() < 1e-4, "{p:?}");
    }

    #[test]
    fn small_area_light_gives_radiance_times_solid_angle() {
        // E = L · s² · cos θ_l / d² with cos ≈ 1: 1e6 · 0.01² / 10² = 1.
        let p = floor_pixel(
            "<AreaLight id=\"1\"><Position>0 10 0</Position><Normal>0 -1 0</Normal><Size>0.01</Size><Radiance>1e6 1e6 1e6</Radiance></AreaLight>",
            "",
        );
        assert!((p[0] - 1.0).abs() < 1e-5, "{p:?}");
        // Two-sided: a light facing away lights the floor the same (§15 #15).
        let q = floor_pixel(
            "<AreaLight id=\"1\"><Position>0 10 0</Position><Normal>0 1 0</Normal><Size>0.01</Size><Radiance>1e6 1e6 1e6</Radiance></AreaLight>",
            "",
        );
        assert_eq!(p, q);
    }

    #[test]
    fn directional_light_has_no_falloff_and_shadow_rays_reach_infinity() {
        // E = radiance · cos: straight down 7, at 45° 7/√2.
        let p = floor_pixel(
            "<DirectionalLight id=\"1\"><Direction>0 -1 0</Direction><Radiance>7 7 7</Radiance></DirectionalLight>",
            "",
        );
        assert!((p[0] - 7.0).abs() < 1e-5, "{p:?}");
        let p = floor_pixel(
            "<DirectionalLight id=\"1\"><Direction>1 -1 0</Direction><Radiance>7 7 7</Radiance></DirectionalLight>",
            "",
        );
        assert!((p[0] - 7.0 / 2f32.sqrt()).abs() < 1e-5, "{p:?}");
        // A sphere 20 units up blocks it: the shadow ray does not stop at any distance.
        let p = floor_pixel(
            "<DirectionalLight id=\"1\"><Direction>0 -1 0</Direction><Radiance>7 7 7</Radiance></DirectionalLight>",
            "<Sphere id=\"9\"><Material>1</Material><Center>5</Center><Radius>1</Radius></Sphere>",
        );
        assert_eq!(p, [0.0; 3]);
        // Light travelling upwards does not reach the floor's top side.
        let p = floor_pixel(
            "<DirectionalLight id=\"1\"><Direction>0 1 0</Direction><Radiance>7 7 7</Radiance></DirectionalLight>",
            "",
        );
        assert_eq!(p, [0.0; 3]);
    }

    #[test]
    fn spot_light_on_axis_in_the_falloff_band_and_outside() {
        // Spot 4 units above the lit point, intensity 400 (25 on the axis), coverage 60°,
        // falloff 40° (half angles 30° and 20°), its axis tilted by `tilt` degrees.
        let spot = |tilt: f64| {
            let (s, c) = tilt.to_radians().sin_cos();
            floor_pixel(
                &format!(
                    "<SpotLight id=\"1\"><Position>0 4 0</Position><Direction>{s} {} 0</Direction><Intensity>400 400 400</Intensity><CoverageAngle>60</CoverageAngle><FalloffAngle>40</FalloffAngle></SpotLight>",
                    -c
                ),
                "",
            )[0] as f64
        };
        assert!((spot(0.0) - 25.0).abs() < 1e-4, "centre: {}", spot(0.0));
        assert!((spot(15.0) - 25.0).abs() < 1e-4, "inside the falloff cone: {}", spot(15.0));
        let (cc, cf) = (30f64.to_radians().cos(), 20f64.to_radians().cos());
        let t = (25f64.to_radians().cos() - cc) / (cf - cc);
        assert!(
            (spot(25.0) - 25.0 * t.powi(4)).abs() < 1e-4,
            "between: {} vs {}",
            spot(25.0),
            25.0 * t.powi(4)
        );
        assert!(spot(25.0) > 0.0 && spot(25.0) < 25.0);
        assert_eq!(spot(35.0), 0.0, "outside the coverage cone");
    }

    /// A unit sphere of `material` at the origin, lit only by the environment map `map` (its
    /// light's extra elements in `light`), seen from (0, 0, 5) along (0, 0, `gaze_z`) through a
    /// near plane of half-width `half` at distance 1, `res`² pixels of `spp` samples.
    #[allow(clippy::too_many_arguments)]
    fn sphere_in_map(
        dir: &tessera_testkit::TempDir,
        map: &crate::image::Image,
        material: &str,
        gaze_z: f64,
        half: f64,
        res: u32,
        spp: u32,
        light: &str,
    ) -> crate::scene::Scene {
        crate::hdr_io::write_exr(&dir.join("map.exr"), map).unwrap();
        let xml = format!(
            r#"<Scene><MaxRecursionDepth>2</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 {gaze_z}</Gaze><Up>0 1 0</Up>
              <NearPlane>-{half} {half} -{half} {half}</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>{res} {res}</ImageResolution><ImageName>a.exr</ImageName><NumSamples>{spp}</NumSamples></Camera></Cameras>
            <Textures><Images><Image id="1">map.exr</Image></Images></Textures>
            <Lights><SphericalDirectionalLight id="1"><ImageId>1</ImageId>{light}</SphericalDirectionalLight></Lights>
            <Materials>{material}</Materials>
            <VertexData>0 0 0</VertexData>
            <Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects>
            </Scene>"#
        );
        load_scene_str(&xml, &dir.join("t.xml"), &FsResolver { base_dir: dir.to_path_buf() }).unwrap()
    }

    /// A scene around a white diffuse unit sphere lit only by a constant environment map of
    /// radiance `l`, seen through one pixel by a camera at z = 5 looking along `gaze_z` (−1: at
    /// the sphere); `spp` samples with `sampler`.
    fn furnace_pixel(l: f32, gaze_z: f64, material: &str, spp: u32, sampler: EnvSampler) -> [f32; 3] {
        use crate::image::Image;
        let dir = tessera_testkit::TempDir::new("furnace");
        let map = Image { width: 8, height: 4, pixels: vec![[l; 3]; 32] };
        let scene = sphere_in_map(&dir, &map, material, gaze_z, 0.001, 1, spp, "");
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        let settings = RenderSettings { env_sampling: Some(sampler), ..RenderSettings::default() };
        render_tile(&scene, 0, rect, &settings).0[0]
    }

    const WHITE: &str = r#"<Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material>"#;

    /// The furnace test: a white diffuse sphere in a constant environment L reflects
    /// kd · ∫ L cos θ dω = π · L (the course's shading formula has no 1/π), whichever estimator.
    #[test]
    fn furnace_white_sphere_in_constant_environment() {
        let l = 0.5f32;
        let expected = std::f64::consts::PI * l as f64;
        // Cosine sampling: E·cos = L·π exactly for every sample.
        let p = furnace_pixel(l, -1.0, WHITE, 16, EnvSampler::Cosine);
        assert!((p[0] as f64 - expected).abs() < 1e-5, "cosine: {p:?}");
        // Uniform (σ of one sample πL/√3) and importance (σ = πL·√(5/3)), both at 16384 samples:
        // 4σ is 1.8 % and 4.0 %.
        let p = furnace_pixel(l, -1.0, WHITE, 16384, EnvSampler::Uniform);
        assert!((p[0] as f64 / expected - 1.0).abs() < 0.018, "uniform: {p:?} vs {expected}");
        let p = furnace_pixel(l, -1.0, WHITE, 16384, EnvSampler::Importance);
        assert!((p[0] as f64 / expected - 1.0).abs() < 0.04, "importance: {p:?} vs {expected}");
    }

    /// Several `SphericalDirectionalLight`s: each lights (a white sphere under constant maps of
    /// 0.5 and 0.25 reflects π·0.75, exactly with cosine sampling), and rays that miss see the
    /// first one only.
    #[test]
    fn every_environment_light_lights_and_the_first_is_seen() {
        use crate::image::Image;
        let dir = tessera_testkit::TempDir::new("two-envs");
        for (name, l) in [("a.exr", 0.5f32), ("b.exr", 0.25)] {
            let map = Image { width: 8, height: 4, pixels: vec![[l; 3]; 32] };
            crate::hdr_io::write_exr(&dir.join(name), &map).unwrap();
        }
        let pixel = |gaze_z: f64| {
            let xml = format!(
                r#"<Scene><Cameras><Camera id="1"><Position>0 0 5</Position><Gaze>0 0 {gaze_z}</Gaze><Up>0 1 0</Up>
              <NearPlane>-0.001 0.001 -0.001 0.001</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>1 1</ImageResolution><ImageName>a.exr</ImageName><NumSamples>16</NumSamples></Camera></Cameras>
            <Textures><Images><Image id="1">a.exr</Image><Image id="2">b.exr</Image></Images></Textures>
            <Lights><SphericalDirectionalLight id="1"><ImageId>1</ImageId></SphericalDirectionalLight>
              <SphericalDirectionalLight id="2"><ImageId>2</ImageId></SphericalDirectionalLight></Lights>
            <Materials>{WHITE}</Materials>
            <VertexData>0 0 0</VertexData>
            <Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects>
            </Scene>"#
            );
            let scene = load_scene_str(&xml, &dir.join("t.xml"), &FsResolver { base_dir: dir.to_path_buf() })
                .unwrap();
            assert_eq!(scene.extra_env_lights.len(), 1);
            let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
            let settings =
                RenderSettings { env_sampling: Some(EnvSampler::Cosine), ..RenderSettings::default() };
            render_tile(&scene, 0, rect, &settings).0[0]
        };
        let lit = pixel(-1.0);
        let expected = std::f64::consts::PI * 0.75;
        assert!(lit.iter().all(|&c| (c as f64 - expected).abs() < 1e-5), "{lit:?} vs {expected}");
        assert_eq!(pixel(1.0), [0.5; 3]);
    }

    /// A group of camera rays, some hitting a sphere and some missing it, traced together gives
    /// each ray's own radiance and ray counts, bit for bit, with both renderers and for groups
    /// shorter than eight.
    #[test]
    fn a_group_of_camera_rays_traces_what_each_ray_traces() {
        use super::Tracer;
        use crate::image::Image;
        use crate::math::Ray;
        use crate::sampler::{GROUP_LANES, Sampler};
        use crate::scene::records::{PathParams, Renderer, Roulette};
        let dir = tessera_testkit::TempDir::new("group");
        let pixels =
            (0..32 * 16).map(|i| [1.0 + (i % 32) as f32 * 0.05, 1.0 + (i / 32) as f32 * 0.1, 1.0]).collect();
        let map = Image { width: 32, height: 16, pixels };
        let scene = sphere_in_map(&dir, &map, WHITE, -1.0, 1.0, 8, 8, "<Sampler>importance</Sampler>");
        // Rays from the camera fanning across the sphere's edge: lanes alternate hit and miss.
        let rays: [Ray; GROUP_LANES] = std::array::from_fn(|i| {
            let x = if i % 2 == 0 { 0.05 * i as f64 } else { 0.3 + 0.05 * i as f64 };
            Ray::new(DVec3::new(0.0, 0.0, 5.0), DVec3::new(x, 0.02 * i as f64, -1.0).normalize())
        });
        let path = Renderer::Path(PathParams {
            next_event: true,
            importance: true,
            roulette: Roulette::Off,
            one_light: false,
            mis: false,
        });
        for renderer in [Renderer::Classic, path] {
            for group in [GROUP_LANES, 5, 2] {
                let samplers: Vec<Sampler> = (0..group as u32).map(|k| Sampler::new(9, 3, 4, k)).collect();
                let mut together = Tracer::new(&scene);
                together.renderer = renderer;
                let mut hits = [None; GROUP_LANES];
                together.camera_hits(&rays[..group], &mut hits[..group]);
                assert!(hits[..group].iter().any(Option::is_some), "a lane hits the sphere");
                assert!(hits[..group].iter().any(Option::is_none), "a lane misses it");
                let mut group_samplers = samplers.clone();
                let got = together.trace_primary_group(&rays, &hits[..group], &mut group_samplers);
                let mut alone = Tracer::new(&scene);
                alone.renderer = renderer;
                for i in 0..group {
                    let want = alone.trace_primary(&rays[i], hits[i], &mut samplers[i].clone());
                    assert_eq!(
                        got[i].to_array().map(f64::to_bits),
                        want.to_array().map(f64::to_bits),
                        "lane {i}"
                    );
                }
                assert_eq!(together.stats.total(), alone.stats.total(), "{renderer:?}, {group} lanes");
                if group == GROUP_LANES {
                    assert!(together.stats.shadow > 0, "{renderer:?}: the hits are lit");
                }
            }
        }
    }

    /// The recursive renderer lights a pixel's hits together: with every kind of light (point,
    /// area, directional, spot, an object light, the environment), surfaces that block some of
    /// the shadow rays, a colour map, a material that reflects nothing, mirrors and glass, each
    /// camera sample still gets its own radiance, random numbers and ray counts bit for bit.
    #[test]
    fn lighting_a_group_together_gives_each_sample_its_own_light() {
        use super::Tracer;
        use crate::image::Image;
        use crate::math::Ray;
        use crate::sampler::{GROUP_LANES, Sampler};
        let dir = tessera_testkit::TempDir::new("group-lights");
        let pixels = (0..16 * 8).map(|i| [0.2 + (i % 16) as f32 * 0.1, 0.5, 1.0 + (i / 16) as f32]).collect();
        crate::hdr_io::write_exr(&dir.join("map.exr"), &Image { width: 16, height: 8, pixels }).unwrap();
        let xml = r#"<Scene><MaxRecursionDepth>3</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 1 6</Position><Gaze>0 -0.2 -1</Gaze><Up>0 1 0</Up>
              <NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>8 8</ImageResolution><ImageName>a.exr</ImageName></Camera></Cameras>
            <Textures><Images><Image id="1">map.exr</Image></Images>
              <TextureMap id="1" type="image"><ImageId>1</ImageId><DecalMode>replace_kd</DecalMode></TextureMap></Textures>
            <Lights><AmbientLight>0.1 0.1 0.1</AmbientLight>
              <PointLight id="1"><Position>2 4 3</Position><Intensity>40 40 40</Intensity></PointLight>
              <AreaLight id="1"><Position>-2 4 1</Position><Normal>0 -1 0</Normal><Size>1</Size><Radiance>30 30 30</Radiance></AreaLight>
              <DirectionalLight id="1"><Direction>0.3 -1 -0.2</Direction><Radiance>0.5 0.5 0.5</Radiance></DirectionalLight>
              <SpotLight id="1"><Position>0 5 0</Position><Direction>0 -1 0</Direction><Intensity>60 60 60</Intensity><CoverageAngle>60</CoverageAngle><FalloffAngle>40</FalloffAngle></SpotLight>
              <SphericalDirectionalLight id="1"><ImageId>1</ImageId><Sampler>importance</Sampler></SphericalDirectionalLight></Lights>
            <Materials>
              <Material id="1"><DiffuseReflectance>0.8 0.7 0.6</DiffuseReflectance><SpecularReflectance>0.3 0.3 0.3</SpecularReflectance><PhongExponent>20</PhongExponent></Material>
              <Material id="2" type="mirror"><DiffuseReflectance>0.1 0.1 0.1</DiffuseReflectance><MirrorReflectance>0.8 0.8 0.8</MirrorReflectance></Material>
              <Material id="3" type="dielectric"><AbsorptionCoefficient>0.1 0 0.1</AbsorptionCoefficient><RefractionIndex>1.5</RefractionIndex></Material>
              <Material id="4"><AmbientReflectance>0.5 0.5 0.5</AmbientReflectance></Material></Materials>
            <VertexData>-5 -1 -5  5 -1 -5  5 -1 5  -5 -1 5  0 0 0  1.4 0 -0.5  -1.4 0 -0.5  0 1.3 -1  0 2.8 0  1.5 -0.6 1.5</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>1 3 2  1 4 3</Faces></Mesh>
              <Sphere id="1"><Material>1</Material><Textures>1</Textures><Center>5</Center><Radius>0.7</Radius></Sphere>
              <Sphere id="2"><Material>2</Material><Center>6</Center><Radius>0.5</Radius></Sphere>
              <Sphere id="3"><Material>3</Material><Center>7</Center><Radius>0.5</Radius></Sphere>
              <Sphere id="4"><Material>4</Material><Center>8</Center><Radius>0.3</Radius></Sphere>
              <LightSphere id="5"><Material>1</Material><Center>9</Center><Radius>0.25</Radius><Radiance>20 18 15</Radiance></LightSphere>
              <Sphere id="6"><Material>1</Material><Center>10</Center><Radius>0.3</Radius></Sphere></Objects>
            </Scene>"#;
        let scene =
            load_scene_str(xml, &dir.join("t.xml"), &FsResolver { base_dir: dir.to_path_buf() }).unwrap();
        let mut r = Sampler::new(1, 2, 3, 4);
        let (mut groups, mut blocked, mut mixed) = (0, 0, 0);
        let mut seen = std::collections::HashSet::new();
        for pixel in 0..400u32 {
            // A pixel's camera samples: rays from around the camera through a small patch of
            // the scene (a wide patch in some pixels, so lanes see different objects).
            let spread = if pixel % 2 == 0 { 2.0 } else { 0.03 };
            let (cx, cy) = r.next_2d();
            let aim = DVec3::new(cx * 6.0 - 3.0, cy * 3.0 - 1.0, -0.5);
            let group = [GROUP_LANES, 5, 1][pixel as usize % 3];
            let rays: [Ray; GROUP_LANES] = std::array::from_fn(|_| {
                let (a, b) = r.next_2d();
                let o = DVec3::new(a * 0.2, 1.0 + b * 0.2, 6.0);
                let (c, d) = r.next_2d();
                let target = aim + DVec3::new(c - 0.5, d - 0.5, 0.0) * spread;
                Ray::new(o, (target - o).normalize())
            });
            let samplers: Vec<Sampler> = (0..group as u32).map(|k| Sampler::new(7, pixel, 0, k)).collect();
            let mut together = Tracer::new(&scene);
            let mut hits = [None; GROUP_LANES];
            together.camera_hits(&rays[..group], &mut hits[..group]);
            let mut group_samplers = samplers.clone();
            let got = together.trace_primary_group(&rays, &hits[..group], &mut group_samplers);
            let mut alone = Tracer::new(&scene);
            let mut shadows = 0;
            for i in 0..group {
                let mut rng = samplers[i].clone();
                let before = alone.stats.shadow;
                let want = alone.trace_primary(&rays[i], hits[i], &mut rng);
                shadows += alone.stats.shadow - before;
                assert_eq!(
                    got[i].to_array().map(f64::to_bits),
                    want.to_array().map(f64::to_bits),
                    "pixel {pixel} lane {i}: {:?} vs {want:?}",
                    got[i]
                );
                assert_eq!(
                    group_samplers[i].next_1d().to_bits(),
                    rng.next_1d().to_bits(),
                    "pixel {pixel} lane {i}"
                );
            }
            assert_eq!(together.stats, alone.stats, "pixel {pixel}");
            groups += usize::from(group > 1);
            // Lanes whose shadow rays differ in number: some were above the surface and
            // others not, or hit different objects.
            blocked += usize::from(shadows % group as u64 != 0);
            let kinds: std::collections::HashSet<_> =
                hits[..group].iter().map(|h| h.map(|h| h.instance)).collect();
            mixed += usize::from(kinds.len() > 1);
            seen.extend(kinds);
        }
        assert!(groups > 200 && blocked > 20 && mixed > 50, "coverage: {groups} {blocked} {mixed}");
        // The floor, the six spheres, and the sky.
        assert_eq!(seen.len(), 8, "every object and the sky are seen: {seen:?}");
    }

    #[test]
    fn missed_rays_and_mirrors_see_the_environment() {
        // Looking away from the sphere: the map itself.
        let p = furnace_pixel(0.25, 1.0, WHITE, 1, EnvSampler::Uniform);
        assert_eq!(p, [0.25; 3]);
        // A perfect mirror sphere reflects the map (and gets no diffuse light).
        let mirror = r#"<Material id="1" type="mirror"><DiffuseReflectance>0 0 0</DiffuseReflectance><SpecularReflectance>0 0 0</SpecularReflectance><MirrorReflectance>0.5 0.5 0.5</MirrorReflectance></Material>"#;
        let p = furnace_pixel(0.25, -1.0, mirror, 1, EnvSampler::Uniform);
        assert!((p[0] - 0.125).abs() < 1e-7, "{p:?}");
    }

    /// A closed box (inward-facing, normalized ModifiedPhong walls of reflectance 0.5) with a
    /// small emitting square on its ceiling, seen by one pixel looking at the floor, path
    /// traced with `params` at `max_depth`; `k` renders with different seeds, each of `spp`
    /// samples: the mean pixel (red channel) of each render.
    fn box_path_means(params: &str, max_depth: u32, spp: u32, k: u64) -> (Vec<f64>, u64) {
        let xml = format!(
            r#"<Scene><MaxRecursionDepth>{max_depth}</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 0.5 0</Position><Gaze>0 -1 0</Gaze><Up>0 0 -1</Up>
              <NearPlane>-0.1 0.1 -0.1 0.1</NearPlane><NearDistance>1</NearDistance>
              <ImageResolution>1 1</ImageResolution><ImageName>a.exr</ImageName><NumSamples>{spp}</NumSamples>
              <Renderer>PathTracing</Renderer><RendererParams>{params}</RendererParams></Camera></Cameras>
            <BRDFs><ModifiedPhong id="1" normalized="true"><Exponent>1</Exponent></ModifiedPhong></BRDFs>
            <Materials><Material id="1" BRDF="1"><DiffuseReflectance>0.5 0.5 0.5</DiffuseReflectance></Material>
              <Material id="2"></Material></Materials>
            <VertexData>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1
              -0.5 0.99 -0.5  0.5 0.99 -0.5  0.5 0.99 0.5  -0.5 0.99 0.5</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>
              1 2 6  1 6 5  4 8 7  4 7 3  1 5 8  1 8 4  2 3 7  2 7 6  1 4 3  1 3 2  5 6 7  5 7 8</Faces></Mesh>
              <LightMesh id="2"><Material>2</Material><Radiance>4 4 4</Radiance><Faces>9 10 11  9 11 12</Faces></LightMesh>
            </Objects></Scene>"#
        );
        let scene = load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
            .unwrap();
        assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        let mut rays = 0;
        let means = (0..k)
            .map(|seed| {
                let settings = RenderSettings { seed, ..RenderSettings::default() };
                let (px, stats) = render_tile(&scene, 0, rect, &settings);
                rays += stats.secondary;
                px[0][0] as f64
            })
            .collect();
        (means, rays)
    }

    fn mean_and_error(xs: &[f64]) -> (f64, f64) {
        let n = xs.len() as f64;
        let m = xs.iter().sum::<f64>() / n;
        let var = xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0);
        (m, (var / n).sqrt())
    }

    /// `UnbiasedRussianRoulette` changes which paths are traced, not what they average to: with the
    /// walls reflecting half the light, 64 bounces (the cap) and roulette agree within noise,
    /// while roulette traces far fewer rays. A roulette that forgot to divide by the survival
    /// probability, or a depth limit of 2, would each be many standard errors off.
    #[test]
    fn russian_roulette_is_unbiased() {
        // Without NEE only paths that reach the light count: noisier, so more samples.
        for (params, spp) in [("NextEventEstimation ImportanceSampling", 512), ("ImportanceSampling", 4096)] {
            let (full, full_rays) = box_path_means(params, 64, spp, 16);
            let (rr, rr_rays) = box_path_means(&format!("{params} UnbiasedRussianRoulette"), 64, spp, 16);
            let (short, _) = box_path_means(params, 1, spp, 16);
            let (mf, ef) = mean_and_error(&full);
            let (mr, er) = mean_and_error(&rr);
            let (ms, _) = mean_and_error(&short);
            let tolerance = 4.0 * (ef * ef + er * er).sqrt();
            assert!((mf - mr).abs() < tolerance, "{params}: full depth {mf} ± {ef}, roulette {mr} ± {er}");
            assert!(
                mf - ms > 3.0 * tolerance,
                "{params}: the later bounces matter: {ms} at depth 1 vs {mf} (tolerance {tolerance})"
            );
            assert!(
                rr_rays * 2 < full_rays,
                "{params}: roulette traced {rr_rays} rays, full depth {full_rays}"
            );
        }
    }

    /// `SampleOneLight` gives every-light NEE's image in expectation with half the shadow rays
    /// or fewer: a closed box lit by a point light, an emitting square on its ceiling and a
    /// small emitting sphere, one pixel on its floor, 16 renders of 256 samples each way.
    /// Also pins how the choice weighs the lights: by power, none for a dark light.
    #[test]
    fn one_light_a_vertex_gives_the_image_of_every_light() {
        let means = |params: &str| {
            let xml = format!(
                r#"<Scene><MaxRecursionDepth>3</MaxRecursionDepth>
                <Cameras><Camera id="1"><Position>0 0.5 0</Position><Gaze>0 -1 0</Gaze><Up>0 0 -1</Up>
                  <NearPlane>-0.1 0.1 -0.1 0.1</NearPlane><NearDistance>1</NearDistance>
                  <ImageResolution>1 1</ImageResolution><ImageName>a.exr</ImageName><NumSamples>256</NumSamples>
                  <Renderer>PathTracing</Renderer><RendererParams>{params}</RendererParams></Camera></Cameras>
                <Lights><PointLight id="1"><Position>0.5 0.5 0.5</Position><Intensity>2 1 1</Intensity></PointLight>
                  <PointLight id="2"><Position>-0.5 0.5 0.5</Position><Intensity>0 0 0</Intensity></PointLight></Lights>
                <BRDFs><ModifiedPhong id="1" normalized="true"><Exponent>1</Exponent></ModifiedPhong></BRDFs>
                <Materials><Material id="1" BRDF="1"><DiffuseReflectance>0.5 0.5 0.5</DiffuseReflectance></Material>
                  <Material id="2"></Material></Materials>
                <VertexData>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1
                  -0.5 0.99 -0.5  0.5 0.99 -0.5  0.5 0.99 0.5  -0.5 0.99 0.5  -0.6 0.2 -0.6</VertexData>
                <Objects><Mesh id="1"><Material>1</Material><Faces>
                  1 2 6  1 6 5  4 8 7  4 7 3  1 5 8  1 8 4  2 3 7  2 7 6  1 4 3  1 3 2  5 6 7  5 7 8</Faces></Mesh>
                  <LightMesh id="2"><Material>2</Material><Radiance>4 4 4</Radiance><Faces>9 10 11  9 11 12</Faces></LightMesh>
                  <LightSphere id="3"><Material>2</Material><Center>13</Center><Radius>0.1</Radius><Radiance>1 3 1</Radiance></LightSphere>
                </Objects></Scene>"#
            );
            let scene =
                load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
                    .unwrap();
            let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
            let mut shadow = 0;
            let px: Vec<f64> = (0..16)
                .map(|seed| {
                    let (px, stats) =
                        render_tile(&scene, 0, rect, &RenderSettings { seed, ..RenderSettings::default() });
                    shadow += stats.shadow;
                    px[0][0] as f64
                })
                .collect();
            (scene, px, shadow)
        };
        let (scene, every, every_rays) = means("NextEventEstimation ImportanceSampling");
        let (_, one, one_rays) = means("NextEventEstimation ImportanceSampling SampleOneLight");
        let ((me, ee), (mo, eo)) = (mean_and_error(&every), mean_and_error(&one));
        assert!(me > 0.05, "the floor is lit: {me}");
        assert!(
            (me - mo).abs() < 4.0 * (ee * ee + eo * eo).sqrt(),
            "every light {me} ± {ee}, one light {mo} ± {eo}"
        );
        assert!(
            one_rays * 2 <= every_rays,
            "one light traced {one_rays} shadow rays, every light {every_rays}"
        );
        // Lights in order: the two point lights, the square, the sphere.
        let choice = &scene.light_choice;
        use std::f64::consts::PI;
        let lum = |r: f64, g: f64, b: f64| 0.2126 * r + 0.7152 * g + 0.0722 * b;
        let powers =
            [4.0 * PI * lum(2.0, 1.0, 1.0), 0.0, PI * 4.0 * 1.0, PI * lum(1.0, 3.0, 1.0) * 4.0 * PI * 0.01];
        let total: f64 = powers.iter().sum();
        let mut start = 0.0;
        for (i, p) in powers.iter().enumerate() {
            let share = p / total;
            if share > 0.0 {
                let (picked, prob) = choice.pick(start + share / 2.0).unwrap();
                assert_eq!(picked, i, "the middle of light {i}'s share picks it");
                assert!((prob - share).abs() < 1e-9, "light {i}: {prob} against {share}");
            }
            start += share;
        }
        assert!(
            (0..1000).all(|k| choice.pick(k as f64 / 1000.0).unwrap().0 != 1),
            "a dark light is never chosen"
        );
        assert_eq!(crate::lights::choice::LightChoice::default().pick(0.5), None, "no lights, no choice");
    }

    /// One pixel rendered `k` times (seeds 0..k) at `spp` samples a pixel: a camera at `eye`
    /// looking straight down at the floor of a box (a 2x2x2 cube of diffuse walls, reflectance
    /// 0.5, open at z = -1 unless `rest` closes it), with `rest` (lights, materials and
    /// objects: what is under test) inside. Vertices 1-8 are the cube's corners, material 1 its
    /// walls and 2 a black emitter.
    fn lit_box_pixels(params: &str, eye: f64, spp: u32, k: u64, rest: (&str, &str, &str, &str)) -> Vec<f64> {
        let (lights, materials, vertices, objects) = rest;
        let xml = format!(
            r#"<Scene><MaxRecursionDepth>3</MaxRecursionDepth>
            <Cameras><Camera id="1"><Position>0 {eye} 0</Position><Gaze>0 -1 0</Gaze><Up>0 0 -1</Up>
              <NearPlane>-0.01 0.01 -0.01 0.01</NearPlane><NearDistance>0.1</NearDistance>
              <ImageResolution>1 1</ImageResolution><ImageName>a.exr</ImageName><NumSamples>{spp}</NumSamples>
              <Renderer>PathTracing</Renderer><RendererParams>{params}</RendererParams></Camera></Cameras>
            <Lights>{lights}</Lights>
            <Transformations><Scaling id="1">3 1 1</Scaling><Translation id="1">0.3 -0.5 0.4</Translation></Transformations>
            <BRDFs><ModifiedPhong id="1" normalized="true"><Exponent>1</Exponent></ModifiedPhong></BRDFs>
            <Materials><Material id="1" BRDF="1"><DiffuseReflectance>0.5 0.5 0.5</DiffuseReflectance></Material>
              <Material id="2"></Material>{materials}</Materials>
            <VertexData>-1 -1 -1  1 -1 -1  1 1 -1  -1 1 -1  -1 -1 1  1 -1 1  1 1 1  -1 1 1 {vertices}</VertexData>
            <Objects><Mesh id="1"><Material>1</Material><Faces>
              1 2 6  1 6 5  4 8 7  4 7 3  1 5 8  1 8 4  2 3 7  2 7 6  5 6 7  5 7 8</Faces></Mesh>
              {objects}</Objects></Scene>"#
        );
        let scene = load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
            .unwrap();
        assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
        let rect = TileRect { x0: 0, y0: 0, width: 1, height: 1 };
        (0..k)
            .map(|seed| {
                render_tile(&scene, 0, rect, &RenderSettings { seed, ..RenderSettings::default() }).0[0][0]
                    as f64
            })
            .collect()
    }

    /// `MultipleImportanceSampling` gives the image of plain next-event estimation in
    /// expectation, with cosine or uniform bounces, with every light or one: a closed box with a point
    /// light, an emitting square under its ceiling, an emitting sphere, an ellipsoid light
    /// (sampled without a density, so by NEE alone) and a back wall that is half mirror, half
    /// diffuse (its bounces are drawn from the BRDF one time in two). Leaving out either side
    /// of the weighting (the light samples' weights, or the bounces that find a light) moves
    /// the mean by far more than the tolerance.
    #[test]
    fn multiple_importance_sampling_keeps_the_image() {
        let rest = (
            r#"<PointLight id="1"><Position>0.5 0.5 0.5</Position><Intensity>2 1 1</Intensity></PointLight>"#,
            r#"<Material id="3" type="mirror" BRDF="1"><DiffuseReflectance>0.3 0.3 0.3</DiffuseReflectance>
                 <MirrorReflectance>0.3 0.3 0.3</MirrorReflectance></Material>"#,
            "-0.8 0.99 -0.8  0.8 0.99 -0.8  0.8 0.99 0.8  -0.8 0.99 0.8  -0.5 0.2 -0.5  0 0 0",
            r#"<Mesh id="3"><Material>3</Material><Faces>1 4 3  1 3 2</Faces></Mesh>
               <LightMesh id="2"><Material>2</Material><Radiance>4 4 4</Radiance><Faces>9 10 11  9 11 12</Faces></LightMesh>
               <LightSphere id="4"><Material>2</Material><Center>13</Center><Radius>0.3</Radius><Radiance>1 3 1</Radiance></LightSphere>
               <LightSphere id="5"><Material>2</Material><Center>14</Center><Radius>0.1</Radius><Radiance>2 2 2</Radiance>
                 <Transformations>s1 t1</Transformations></LightSphere>"#,
        );
        for base in [
            "NextEventEstimation ImportanceSampling",
            "NextEventEstimation",
            "NextEventEstimation SampleOneLight",
        ] {
            let plain = lit_box_pixels(base, 0.5, 256, 16, rest);
            let mis = lit_box_pixels(&format!("{base} MultipleImportanceSampling"), 0.5, 256, 16, rest);
            let ((mp, ep), (mm, em)) = (mean_and_error(&plain), mean_and_error(&mis));
            assert!(mp > 0.05, "{base}: the floor is lit: {mp}");
            assert!(
                (mp - mm).abs() < 4.0 * (ep * ep + em * em).sqrt(),
                "{base}: plain {mp} ± {ep}, MIS {mm} ± {em}"
            );
        }
    }

    /// Where a bounce finds a light more easily than a sampled point does, the weights take the
    /// noise out: the floor just under an emitting square as large as the box's ceiling, seen
    /// from between them. Sampled points spread over the square see the floor at every
    /// distance and angle; cosine-drawn bounces nearly all meet it with the same weight. The
    /// pixel's spread over renders falls by more than half, and its mean is that of bounces
    /// alone (without NEE), nearly exact here.
    #[test]
    fn multiple_importance_sampling_lowers_the_noise_under_a_large_near_light() {
        let rest = (
            "",
            "",
            "-1 -0.8 -1  1 -0.8 -1  1 -0.8 1  -1 -0.8 1",
            r#"<LightMesh id="2"><Material>2</Material><Radiance>1 1 1</Radiance><Faces>9 10 11  9 11 12</Faces></LightMesh>"#,
        );
        let base = "NextEventEstimation ImportanceSampling";
        let plain = lit_box_pixels(base, -0.9, 4, 64, rest);
        let mis = lit_box_pixels(&format!("{base} MultipleImportanceSampling"), -0.9, 4, 64, rest);
        // Bounces alone (no NEE) are nearly exact here: the reference.
        let bounces = lit_box_pixels("ImportanceSampling", -0.9, 4, 64, rest);
        let ((mp, ep), (mm, em), (mb, eb)) =
            (mean_and_error(&plain), mean_and_error(&mis), mean_and_error(&bounces));
        assert!((mb - mm).abs() < 4.0 * (eb * eb + em * em).sqrt(), "bounces {mb} ± {eb}, MIS {mm} ± {em}");
        assert!(em < 0.5 * ep, "MIS's error {em} against plain NEE's {ep} (means {mm}, {mp})");
    }

    /// The course's roulette, pinned on a scene whose paths have three outcomes: a camera
    /// looking down at an open diffuse floor (reflectance 0.5, so `f = 0.5/π`) under an
    /// emitting square (radiance 4) facing it, cosine-sampled, no NEE. A bounce that meets the
    /// light reaches it with potential `q = f` and returns the light undivided (`kd·Le`) when
    /// the path ends there (probability `1 − q`), divided (`kd·Le/q = π·Le`) when it survives;
    /// everything else sees black. So every one-sample pixel is 0, 2 or 4π, the survivors are
    /// a share `q` of the hits, and the mean is `2 − q` times the depth-1 mean, where the
    /// unbiased roulette keeps it at 1x.
    #[test]
    fn the_course_roulette_divides_by_the_brdf_product_and_keeps_the_light_of_paths_it_ends() {
        let pixels = |params: &str, depth: u32| -> Vec<f64> {
            let xml = format!(
                r#"<Scene><MaxRecursionDepth>{depth}</MaxRecursionDepth>
                <Cameras><Camera id="1"><Position>0 0.5 0</Position><Gaze>0 -1 0</Gaze><Up>0 0 -1</Up>
                  <NearPlane>-0.1 0.1 -0.1 0.1</NearPlane><NearDistance>1</NearDistance>
                  <ImageResolution>96 96</ImageResolution><ImageName>a.exr</ImageName><NumSamples>1</NumSamples>
                  <Renderer>PathTracing</Renderer><RendererParams>ImportanceSampling {params}</RendererParams></Camera></Cameras>
                <BRDFs><ModifiedPhong id="1" normalized="true"><Exponent>1</Exponent></ModifiedPhong></BRDFs>
                <Materials><Material id="1" BRDF="1"><DiffuseReflectance>0.5 0.5 0.5</DiffuseReflectance></Material>
                  <Material id="2"></Material></Materials>
                <VertexData>-50 0 -50  50 0 -50  50 0 50  -50 0 50  -1 1 -1  1 1 -1  1 1 1  -1 1 1</VertexData>
                <Objects><Mesh id="1"><Material>1</Material><Faces>1 3 2  1 4 3</Faces></Mesh>
                  <LightMesh id="2"><Material>2</Material><Radiance>4 4 4</Radiance><Faces>5 6 7  5 7 8</Faces></LightMesh>
                </Objects></Scene>"#
            );
            let scene =
                load_scene_str(&xml, std::path::Path::new("t.xml"), &FsResolver { base_dir: ".".into() })
                    .unwrap();
            assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
            let rect = TileRect { x0: 0, y0: 0, width: 96, height: 96 };
            (0..6u64)
                .flat_map(|seed| {
                    let settings = RenderSettings { seed, ..RenderSettings::default() };
                    render_tile(&scene, 0, rect, &settings).0.into_iter().map(|p| p[0] as f64)
                })
                .collect()
        };
        let pi = std::f64::consts::PI;
        let q = 0.5 / pi;
        let course = pixels("RussianRoulette", 1);
        let (mut ended, mut survived) = (0usize, 0usize);
        for &p in &course {
            if (p - 2.0).abs() < 1e-4 {
                ended += 1;
            } else if (p - 4.0 * pi).abs() < 1e-4 {
                survived += 1;
            } else {
                assert_eq!(p, 0.0, "a pixel outside the rule's three outcomes");
            }
        }
        let hits = (ended + survived) as f64;
        assert!(hits > 2000.0, "the light is met often enough to measure: {hits}");
        let share = survived as f64 / hits;
        let share_error = (q * (1.0 - q) / hits).sqrt();
        assert!((share - q).abs() < 4.0 * share_error, "survivors {share}, expected {q} ± {share_error}");
        let (mc, ec) = mean_and_error(&course);
        let (md, ed) = mean_and_error(&pixels("", 1));
        let (mu, eu) = mean_and_error(&pixels("UnbiasedRussianRoulette", 1));
        let ratio_error = (ec / mc).hypot(ed / md) * (2.0 - q);
        assert!(
            ((mc / md) - (2.0 - q)).abs() < 4.0 * ratio_error,
            "course {mc} ± {ec} vs depth 1 {md} ± {ed}"
        );
        assert!((mu - md).abs() < 4.0 * eu.hypot(ed), "unbiased {mu} ± {eu} vs depth 1 {md} ± {ed}");
    }
}
