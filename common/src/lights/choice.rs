//! The choice of one light per shading event, by power: the `SampleOneLight` renderer parameter.

use std::f64::consts::PI;

use glam::DVec3;

use super::{AreaLight, DirectionalLight, EmitterShape, EnvLight, ObjectLight, PointLight, SpotLight};
use crate::math::sincos_turns;
use crate::tonemap::params::luminance;

/// One light chosen per shading event with probability proportional to its power (Tessera's
/// `SampleOneLight` renderer parameter): an unbiased stand-in for the course's estimator, which
/// samples every light at every vertex. Lights are numbered in the order the direct lighting
/// visits them: point, area, directional, spot, object, then environment lights (the first
/// one, then the others).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LightChoice {
    /// Cumulative powers, one entry per light; the last is the total.
    cdf: Vec<f64>,
}

impl LightChoice {
    /// The choice among a scene's lights, given kind by kind in the order above, in a scene
    /// whose objects fit in a sphere of `radius`. A light's power is estimated from its
    /// luminance: a point light's intensity over the sphere (4π I), a spot's over its coverage
    /// cone, an area or object light's radiance over its area (π L A), and a light from
    /// infinitely far (directional, environment) over a disk of the scene's radius (its mean
    /// radiance over the sphere of directions for an environment). Any positive weights keep
    /// the estimate unbiased; these put the samples where the light is. A light of no power is
    /// never chosen (it adds nothing).
    pub fn new<'e>(
        point: &[PointLight],
        area: &[AreaLight],
        directional: &[DirectionalLight],
        spot: &[SpotLight],
        object: &[ObjectLight],
        env: impl Iterator<Item = &'e EnvLight>,
        radius: f64,
    ) -> Self {
        let lum = |c: DVec3| luminance(c.to_array()).max(0.0);
        let radius = if radius.is_finite() && radius > 0.0 { radius } else { 1.0 };
        let disk = PI * radius * radius;
        let mut power: Vec<f64> = Vec::new();
        power.extend(point.iter().map(|l| 4.0 * PI * lum(l.intensity)));
        power.extend(area.iter().map(|l| PI * lum(l.radiance) * l.size * l.size));
        power.extend(directional.iter().map(|l| disk * lum(l.radiance)));
        power.extend(spot.iter().map(|l| 2.0 * PI * (1.0 - l.cos_coverage) * lum(l.intensity)));
        power.extend(object.iter().map(|l| {
            let area = match &l.shape {
                EmitterShape::Triangles { cdf, .. } => cdf.last().copied().unwrap_or(0.0),
                EmitterShape::Sphere { radius, .. } | EmitterShape::Ellipsoid { radius, .. } => {
                    4.0 * PI * radius * radius
                }
            };
            PI * lum(l.radiance) * area
        }));
        power.extend(env.map(|l| 4.0 * PI * disk * mean_luminance(l)));
        let mut total = 0.0;
        let cdf = power
            .into_iter()
            .map(|p| {
                total += if p.is_finite() { p } else { 0.0 };
                total
            })
            .collect();
        LightChoice { cdf }
    }

    /// The probability of picking light `i` (0 for a light of no power or no such light).
    pub fn probability(&self, i: usize) -> f64 {
        let Some(&total) = self.cdf.last() else { return 0.0 };
        let Some(&upto) = self.cdf.get(i) else { return 0.0 };
        let below = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let p = (upto - below) / total;
        if p.is_finite() && p > 0.0 { p } else { 0.0 }
    }

    /// The light that `u` in [0, 1) picks, and the probability of picking it; `None` when no
    /// light has any power.
    pub fn pick(&self, u: f64) -> Option<(usize, f64)> {
        let total = *self.cdf.last()?;
        if total <= 0.0 || !total.is_finite() {
            return None;
        }
        let target = u * total;
        let i = self.cdf.partition_point(|&c| c <= target).min(self.cdf.len() - 1);
        let below = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let p = (self.cdf[i] - below) / total;
        (p > 0.0).then_some((i, p))
    }
}

/// An environment light's mean luminance over the sphere of directions, from 4096 directions
/// spread evenly over it (a Fibonacci sphere). Plain IEEE arithmetic and [`sincos_turns`], so
/// every worker computes the same value, and so picks the same lights.
fn mean_luminance(light: &EnvLight) -> f64 {
    const N: usize = 4096;
    // The golden angle in turns.
    let golden = (3.0 - 5f64.sqrt()) / 2.0;
    let mut sum = 0.0;
    for k in 0..N {
        let z = 1.0 - (2.0 * k as f64 + 1.0) / N as f64;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let (sin, cos) = sincos_turns((golden * k as f64).fract());
        sum += luminance(light.radiance(DVec3::new(r * cos, z, r * sin)).to_array()).max(0.0);
    }
    sum / N as f64
}
