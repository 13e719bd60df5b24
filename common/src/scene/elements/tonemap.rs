//! The rules of a camera's `<Tonemap>`: operator, its options, saturation, gamma, file ending.

use crate::scene::records::TonemapRec;
use crate::scene::tree::{Node, Parser, Result, Schema, quoted};
use crate::tonemap::params::{Operator, Photographic};

const TONEMAP: Schema =
    Schema { single: &["TMO", "TMOOptions", "Saturation", "Gamma", "Extension"], ..Schema::EMPTY };

impl Parser<'_> {
    /// A camera's `<Tonemap>` (§12.2); absent children take the student-parser defaults.
    pub(super) fn tonemap(&mut self, n: &Node) -> Result<TonemapRec> {
        self.check(n, &TONEMAP);
        let mut params = Photographic::default();
        let mut operator = Operator::Photographic;
        if let Some(t) = n.child("TMO") {
            match t.text.parse::<Operator>() {
                Ok(op) => operator = op,
                Err(_) => self.unsupported(
                    t,
                    format!(
                        "tone-mapping operator {} is not supported (Photographic, Filmic or ACES); without it, \
                         the photographic operator is used",
                        quoted(t.text.trim())
                    ),
                ),
            }
        }
        if let Some(o) = n.child("TMOOptions") {
            let [key, burn] = self.numbers::<f64, 2>(o)?;
            params.key = key;
            params.burn_percent = burn;
        }
        if let Some(s) = self.optional_number::<f64>(n, "Saturation")? {
            params.saturation = s;
        }
        if let Some(g) = n.child("Gamma") {
            params.gamma = g.text.parse().map_err(|e: String| self.err(g, e))?;
        }
        if let Err(e) = params.validate() {
            return Err(
                self.err(n, format!("{e}; fix <TMOOptions> (key, burn percent), <Saturation> or <Gamma>"))
            );
        }
        let extension = match n.child("Extension") {
            Some(e) => Some(self.text(e, "a file name ending such as _phot.png")?.to_string()),
            None => None,
        };
        Ok(TonemapRec { loc: n.loc(), operator, params, extension })
    }
}
