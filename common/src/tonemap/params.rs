//! Tone-mapping parameters: what a `<Tonemap>` asks for, and the Rec. 709 luminance.
//!
//! Operator, key, burn, saturation and gamma, and the luminance they are defined over: plain
//! parameter types, low enough in the crate for the scene records (and the environment light's
//! importance sampling) to use without the tone mapper.
//!
//! The operator that applies them is [`crate::tonemap`].

use std::fmt;
use std::str::FromStr;

/// Luminance with the Rec. 709 weights of §12.3.
#[inline]
pub fn luminance(c: [f64; 3]) -> f64 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// The display transfer applied last: `c^(1/γ)` or the sRGB curve (the scenes' `<Gamma>`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Gamma {
    /// `c^(1/γ)`; the scenes use 2.2.
    Power(f64),
    /// The sRGB OETF: `12.92 c` below 0.0031308, else `1.055 c^(1/2.4) − 0.055`.
    Srgb,
}

impl Gamma {
    /// Encodes a display value `c` in [0, 1] (values outside are clamped; NaN gives 0).
    #[inline]
    pub fn encode(self, c: f64) -> f64 {
        if c >= 1.0 {
            // Exactly 1, so that white is 255 (the sRGB formula gives 0.99999999999999989).
            return 1.0;
        }
        let c = if c > 0.0 { c } else { 0.0 };
        match self {
            Gamma::Power(g) => c.powf(1.0 / g),
            Gamma::Srgb => {
                if c <= 0.003_130_8 {
                    12.92 * c
                } else {
                    1.055 * c.powf(1.0 / 2.4) - 0.055
                }
            }
        }
    }
}

impl Default for Gamma {
    fn default() -> Self {
        Gamma::Power(2.2)
    }
}

impl fmt::Display for Gamma {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Gamma::Power(g) => write!(f, "{g}"),
            Gamma::Srgb => f.write_str("sRGB"),
        }
    }
}

impl FromStr for Gamma {
    type Err = String;

    /// `"2.2"` (any positive finite number) or `"sRGB"` (any case), as in `<Gamma>`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("srgb") {
            return Ok(Gamma::Srgb);
        }
        match t.parse::<f64>() {
            Ok(g) if g.is_finite() && g > 0.0 => Ok(Gamma::Power(g)),
            _ => Err(format!("gamma \"{s}\": expected a positive number (e.g. 2.2) or sRGB")),
        }
    }
}

/// Which tone-mapping curve (`<TMO>`, §12.2): the course's photographic operator, or the 2025
/// additions ([`crate::tonemap`]'s module docs, "Filmic and ACES").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Operator {
    #[default]
    Photographic,
    /// Hable's filmic (Uncharted 2) curve on luminance.
    Filmic,
    /// Narkowicz's fitted ACES curve on luminance.
    Aces,
}

impl Operator {
    /// The `<TMO>` spellings, as the scenes write them.
    pub const NAMES: [(&'static str, Operator); 3] =
        [("Photographic", Operator::Photographic), ("Filmic", Operator::Filmic), ("ACES", Operator::Aces)];
}

impl fmt::Display for Operator {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = Operator::NAMES.iter().find(|(_, op)| op == self).map_or("?", |(n, _)| n);
        f.write_str(name)
    }
}

impl FromStr for Operator {
    type Err = String;

    /// `Photographic`, `Filmic` or `ACES`, in any case.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.trim();
        Operator::NAMES
            .iter()
            .find(|(name, _)| name.eq_ignore_ascii_case(t))
            .map(|&(_, op)| op)
            .ok_or_else(|| format!("tone-mapping operator \"{t}\": expected Photographic, Filmic or ACES"))
    }
}

/// The parameters shared by every operator (`<Tonemap>` of §12.2); named after the operator
/// they were made for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Photographic {
    /// Key value `a`: the display luminance the log-average maps to (first `TMOOptions` number).
    pub key: f64,
    /// Burn-out percentage `b` in [0, 100]: the share of pixels allowed to reach white (second
    /// `TMOOptions` number); 0 means no white point (plain `L / (1 + L)`).
    pub burn_percent: f64,
    /// Saturation exponent `s` of the colour re-application (`<Saturation>`).
    pub saturation: f64,
    /// Display gamma (`<Gamma>`).
    pub gamma: Gamma,
}

impl Default for Photographic {
    /// The student-parser defaults of §12.2: `TMOOptions 0.18 1`, `Saturation 1`, `Gamma 2.2`.
    fn default() -> Self {
        Photographic { key: 0.18, burn_percent: 1.0, saturation: 1.0, gamma: Gamma::Power(2.2) }
    }
}

impl Photographic {
    /// Checks the parameters: key > 0, burn in [0, 100], saturation ≥ 0, gamma > 0, all finite.
    /// [`tonemap`](super::tonemap) does not refuse other values (it never panics and never
    /// writes NaN), but their images mean nothing.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.key.is_finite() && self.key > 0.0) {
            return Err(format!("key {}: must be a positive number (the scenes use 0.18)", self.key));
        }
        if !(0.0..=100.0).contains(&self.burn_percent) {
            return Err(format!("burn percentage {}: must be between 0 and 100", self.burn_percent));
        }
        if !(self.saturation.is_finite() && self.saturation >= 0.0) {
            return Err(format!(
                "saturation {}: must be a number >= 0 (1 keeps the colours)",
                self.saturation
            ));
        }
        match self.gamma {
            Gamma::Power(g) if !(g.is_finite() && g > 0.0) => {
                Err(format!("gamma {g}: must be a positive number (e.g. 2.2) or sRGB"))
            }
            _ => Ok(()),
        }
    }
}
