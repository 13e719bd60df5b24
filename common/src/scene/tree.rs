//! The element tree both front ends build, and what every element rule reads it with.
//!
//! The tree is [`Node`]s, one per XML element (or JSON object); the walk that turns it into
//! [`SceneRecords`] is [`super::elements`], one file per family of elements. This module holds
//! what those files share: the [`Parser`] (the file, its [`Dialect`], the records being filled),
//! its reporting (errors, warnings, "not supported yet" warnings, messages in JSON words), the
//! [`Schema`] check that warns about children an element does not read, and the value readers
//! (numbers, ids, keywords, attributes, transformation references).
//!
//! Nothing is resolved here: ids stay strings, PLY files are not opened. No input makes this
//! module panic.

use std::path::Path;

use super::records::{SceneRecords, ShadingMode, TransformRef};
use crate::error::{Loc, SceneError, Warning};

pub(super) type Result<T> = std::result::Result<T, SceneError>;

/// `MaxRecursionDepth` of a JSON scene that does not give one. The course parser's default is
/// 0 (§3) and the 2022 references follow it, but the 2025 references do not: bunny_with_plane
/// (mirror floor and wall, no MaxRecursionDepth) is 17.6 dB (PSNR after the 4x4 box) from its
/// reference with 0 and 52.3 dB with any depth from 2 up (1: 52.0 dB). 6 is what 30 of the 34
/// shipped JSON scenes that give a depth give.
pub const DEFAULT_MAX_RECURSION_DEPTH: u32 = 6;

/// `true` / `false` element text (2019 `<ZeroBasedIndexing>`, `<Dimension3>`).
pub(super) const BOOLEANS: &[(&str, bool)] = &[("true", true), ("false", false)];

/// Which front end built the [`Node`] tree: only changes how messages name elements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Dialect {
    Xml,
    /// The 2025 JSON encoding (scene-format.md §14): node labels are JSON paths, and messages
    /// say `"Faces"` / `"_id"` where the XML ones say `<Faces>` / `attribute id`.
    Json,
}

// ---------------------------------------------------------------------------------------------
// The element tree
// ---------------------------------------------------------------------------------------------

/// One XML element with what the walk needs: name, attributes, text and where it was written.
#[derive(Debug)]
pub(super) struct Node {
    pub(super) name: String,
    /// How errors name this element: `Sphere id="2"`, or for an element inside a record its
    /// path from the record, `Camera id="1"> / <Position` (displayed by [`SceneError`] as
    /// `<Camera id="1"> / <Position>`).
    pub(super) label: String,
    /// Nesting depth: `<Scene>` is 1, `<Cameras>` 2, `<Camera>` 3, `<Position>` 4.
    pub(super) depth: usize,
    /// Line of the start tag.
    pub(super) line: u32,
    /// Line on which the element's text starts (after the start tag's `>`).
    pub(super) content_line: u32,
    pub(super) attrs: Vec<(String, String)>,
    /// The element's own character data, concatenated. Comments inside it are replaced by a
    /// space plus their newlines, so tokens keep their line numbers and a comment separates
    /// numbers (`1 2<!-- note -->3` reads as three numbers).
    pub(super) text: String,
    pub(super) children: Vec<Node>,
}

impl Node {
    pub(super) fn loc(&self) -> Loc {
        Loc::new(self.line, self.label.clone())
    }

    pub(super) fn attr(&self, key: &str) -> Option<&str> {
        self.attrs.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
    }

    /// The first child with this name (later duplicates are reported by [`Parser::check`]).
    pub(super) fn child(&self, name: &str) -> Option<&Node> {
        self.children.iter().find(|c| c.name == name)
    }

    pub(super) fn children_named<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Node> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }
}

/// Up to about 60 characters of `text`, whitespace runs collapsed, for quoting in messages.
pub(super) fn excerpt(text: &str) -> String {
    const MAX: usize = 60;
    let mut out = String::new();
    for token in text.split_ascii_whitespace() {
        if !out.is_empty() {
            out.push(' ');
        }
        if out.len() + token.len() > MAX {
            out.extend(token.chars().take(MAX.saturating_sub(out.len())));
            out.push_str("...");
            break;
        }
        out.push_str(token);
    }
    out
}

/// `text` quoted for a message (see [`excerpt`]), or `nothing` when it is blank.
pub(super) fn quoted(text: &str) -> String {
    match excerpt(text) {
        e if e.is_empty() => "nothing".to_string(),
        e => format!("\"{e}\""),
    }
}

/// Whitespace-separated tokens of `text` with the 0-based line (relative to the text start)
/// each one is on. Any ASCII whitespace separates (spaces, tabs, LF, CRLF).
fn tokens(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.split_inclusive('\n')
        .enumerate()
        .flat_map(|(i, line)| line.split_ascii_whitespace().map(move |t| (i, t)))
}

// ---------------------------------------------------------------------------------------------
// Numbers
// ---------------------------------------------------------------------------------------------

/// A value that appears as a whitespace-separated token in element text.
pub(super) trait Token: Copy + Default {
    /// "a number", "an integer"...
    const ONE: &'static str;
    /// "numbers", "integers"...
    const MANY: &'static str;
    fn parse(token: &str) -> Option<Self>;
}

impl Token for f64 {
    const ONE: &'static str = "a number";
    const MANY: &'static str = "numbers";
    fn parse(token: &str) -> Option<Self> {
        // Rust also accepts "inf" and "NaN"; no scene means those.
        token.parse::<f64>().ok().filter(|x| x.is_finite())
    }
}

impl Token for i64 {
    const ONE: &'static str = "an integer";
    const MANY: &'static str = "integers";
    fn parse(token: &str) -> Option<Self> {
        token.parse().ok()
    }
}

impl Token for u32 {
    const ONE: &'static str = "a non-negative integer";
    const MANY: &'static str = "non-negative integers";
    fn parse(token: &str) -> Option<Self> {
        token.parse().ok()
    }
}

fn expected<T: Token>(n: usize) -> String {
    if n == 1 { T::ONE.to_string() } else { format!("{n} {}", T::MANY) }
}

// ---------------------------------------------------------------------------------------------
// Step 2: tree -> records
// ---------------------------------------------------------------------------------------------

/// An element or attribute of the format that is not implemented, with what the picture lacks
/// without it ("without it, ..."): [`Parser::check`] reports it as [`Warning::unsupported`].
pub(super) type Unsupported = (&'static str, &'static str);

/// What an element may contain, for the unknown / not-supported-yet warnings.
pub(super) struct Schema {
    /// Children read by the parser, at most one of each (later copies are warned about).
    pub(super) single: &'static [&'static str],
    /// Children read by the parser that may repeat (list entries and containers).
    pub(super) many: &'static [&'static str],
    /// Children that belong to the format but are not implemented yet; each changes the
    /// picture (elements that would not are read and warned about where they are read).
    pub(super) unsupported: &'static [Unsupported],
    pub(super) attrs: &'static [&'static str],
    pub(super) unsupported_attrs: &'static [Unsupported],
    /// Children that belong to a sibling variant (another kind of texture) and mean nothing
    /// here; warned about with `inapplicable_why` ("does not apply to ...").
    pub(super) inapplicable: &'static [&'static str],
    pub(super) inapplicable_why: &'static str,
}

impl Schema {
    /// Every child name the element knows (read, unsupported or belonging to a sibling
    /// variant): what a misspelt name is compared with.
    fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.single
            .iter()
            .chain(self.many)
            .copied()
            .chain(self.unsupported.iter().map(|(n, _)| *n))
            .chain(self.inapplicable.iter().copied())
    }

    pub(super) const EMPTY: Schema = Schema {
        single: &[],
        many: &[],
        unsupported: &[],
        attrs: &[],
        unsupported_attrs: &[],
        inapplicable: &[],
        inapplicable_why: "",
    };
}

/// The name of `known` that `name` most likely misspells: equal but for letter case, or within
/// an edit distance (insertions, deletions, substitutions and swaps of neighbours) of 1 for
/// names of up to 4 letters, 2 for longer ones; the nearest wins, the first on a tie.
pub(super) fn closest_name<'k>(name: &str, known: impl Iterator<Item = &'k str>) -> Option<&'k str> {
    let lower = name.to_ascii_lowercase();
    let limit = if name.chars().count() <= 4 { 1 } else { 2 };
    let mut best: Option<(usize, &str)> = None;
    for k in known {
        if k == name {
            continue;
        }
        let d = if k.eq_ignore_ascii_case(name) { 0 } else { edit_distance(&lower, &k.to_ascii_lowercase()) };
        if d <= limit && best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, k));
        }
    }
    best.map(|(_, k)| k)
}

/// Optimal string alignment distance: Levenshtein's with swaps of two neighbouring letters
/// counting one edit (`Ligth` is one edit from `Light`).
fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.chars().collect();
    let b: Vec<char> = b.chars().collect();
    // Rows i-2, i-1 and i of the table, over b's prefixes.
    let mut before: Vec<usize> = vec![0; b.len() + 1];
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    let mut row = vec![0; b.len() + 1];
    for i in 1..=a.len() {
        row[0] = i;
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            row[j] = (prev[j] + 1).min(row[j - 1] + 1).min(prev[j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                row[j] = row[j].min(before[j - 2] + 1);
            }
        }
        std::mem::swap(&mut before, &mut prev);
        std::mem::swap(&mut prev, &mut row);
    }
    prev[b.len()]
}

/// "a", "a or b", "a, b or c".
pub(super) fn one_of<T>(options: &[(&str, T)]) -> String {
    let names: Vec<&str> = options.iter().map(|(name, _)| *name).collect();
    match names.split_last() {
        None => String::new(),
        Some((last, [])) => (*last).to_string(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
    }
}

pub(super) struct Parser<'a> {
    pub(super) file: &'a Path,
    /// 2019 dialect: untyped MirrorReflectance / Transparency make mirrors / dielectrics.
    pub(super) legacy: bool,
    /// 2019 `<Texture bumpmap="true">` ids with the id of the extra bump map made for each,
    /// so that an object's `<Texture>k</Texture>` can refer to both maps.
    pub(super) legacy_bumps: Vec<(String, String)>,
    pub(super) dialect: Dialect,
    pub(super) out: SceneRecords,
}

impl Parser<'_> {
    // --- reporting ---

    pub(super) fn err(&self, node: &Node, message: impl Into<String>) -> SceneError {
        SceneError::new(self.file, node.loc(), self.say(message.into()))
    }

    pub(super) fn warn(&mut self, node: &Node, message: impl Into<String>) {
        let message = self.say(message.into());
        self.out.warnings.push(Warning::new(self.file, node.loc(), message));
    }

    /// Something of the format that is not implemented and whose absence changes the picture:
    /// `message` says what and, after "without it, ", what the picture lacks. The loaders refuse
    /// the scene unless unsupported elements are allowed ([`Warning::unsupported`]).
    pub(super) fn unsupported(&mut self, node: &Node, message: impl Into<String>) {
        let message = self.say(message.into());
        self.out.warnings.push(Warning::unsupported(self.file, node.loc(), message));
    }

    /// What an element is called in the file's dialect: an XML element, a JSON key.
    fn element_word(&self) -> &'static str {
        match self.dialect {
            Dialect::Xml => "element",
            Dialect::Json => "key",
        }
    }

    /// A message in the words of the file's dialect (see [`json_words`]).
    pub(super) fn say(&self, message: String) -> String {
        match self.dialect {
            Dialect::Xml => message,
            Dialect::Json => json_words(&message),
        }
    }

    /// Warns about every child or attribute of `node` that `schema` does not read, and about
    /// repeated single children. Children of the single children (which hold plain values)
    /// are warned about here too; list entries and containers are checked by their own parsers.
    pub(super) fn check(&mut self, node: &Node, schema: &Schema) {
        self.check_attrs(node, schema.attrs, schema.unsupported_attrs);
        for (i, child) in node.children.iter().enumerate() {
            let name = child.name.as_str();
            if schema.single.contains(&name) {
                if node.children[..i].iter().any(|c| c.name == name) {
                    self.warn(child, format!("<{name}> is given more than once; only the first one is used"));
                }
                for grandchild in &child.children {
                    let word = self.element_word();
                    self.warn(grandchild, format!("unknown {word} <{}>; it is ignored", grandchild.name));
                }
            } else if let Some((_, without)) = schema.unsupported.iter().find(|(n, _)| *n == name) {
                self.unsupported(child, format!("<{name}> is not supported yet; {without}"));
            } else if schema.inapplicable.contains(&name) {
                self.warn(child, format!("<{name}> {}; it is ignored", schema.inapplicable_why));
            } else if !schema.many.contains(&name) {
                let hint = match closest_name(name, schema.names()) {
                    Some(known) => format!("; did you mean <{known}>? It is ignored"),
                    // In JSON an attribute is a key with a leading `_`: `"id"` for `"_id"`.
                    None => match self.dialect {
                        Dialect::Json => match closest_name(name, schema.attrs.iter().copied())
                            .or_else(|| schema.attrs.iter().copied().find(|a| *a == name))
                        {
                            Some(attr) => format!("; did you mean attribute {attr}? It is ignored"),
                            None => "; it is ignored".to_string(),
                        },
                        Dialect::Xml => "; it is ignored".to_string(),
                    },
                };
                self.warn(child, format!("unknown {} <{name}>{hint}", self.element_word()));
            }
        }
    }

    pub(super) fn check_attrs(&mut self, node: &Node, known: &[&str], unsupported: &[Unsupported]) {
        for (key, _) in &node.attrs {
            if let Some((_, without)) = unsupported.iter().find(|(k, _)| k == key) {
                self.unsupported(node, format!("attribute {key} is not supported yet; {without}"));
            } else if !known.contains(&key.as_str()) {
                let hint = match closest_name(key, known.iter().copied()) {
                    Some(k) => format!("; did you mean attribute {k}? It is ignored"),
                    None => "; it is ignored".to_string(),
                };
                self.warn(node, format!("unknown attribute {key}{hint}"));
            }
        }
    }

    // --- values ---

    /// The child `name` of `parent`; an error when it is missing. When a child of `parent` is
    /// spelt nearly so (`<Positon>`), the error is about that child, the one most likely meant:
    /// "unknown element <Positon>; did you mean <Position>?", on its line.
    pub(super) fn required<'n>(&self, parent: &'n Node, name: &str) -> Result<&'n Node> {
        parent.child(name).ok_or_else(|| {
            let misspelt =
                parent.children.iter().find(|c| closest_name(&c.name, std::iter::once(name)).is_some());
            match (self.dialect, misspelt) {
                (Dialect::Xml, Some(found)) => self.err(
                    found,
                    format!(
                        "unknown element <{}>; did you mean <{name}>? <{}> needs <{name}>",
                        found.name, parent.name
                    ),
                ),
                (Dialect::Xml, None) => self.err(parent, format!("missing <{name}>")),
                // Name the JSON path of the key: e.g. `Scene.Objects.Mesh[3].Faces`.
                (Dialect::Json, Some(found)) => SceneError::new(
                    self.file,
                    found.loc(),
                    format!(
                        "unknown key \"{}\"; did you mean \"{name}\"? Rename the key in {} (it needs \"{name}\")",
                        found.name, parent.label
                    ),
                ),
                (Dialect::Json, None) => SceneError::new(
                    self.file,
                    Loc::new(parent.line, format!("{}.{name}", parent.label)),
                    format!("missing \"{name}\"; add the key \"{name}\" to {}", parent.label),
                ),
            }
        })
    }

    /// The first `N` tokens of `node`'s text; extra tokens are ignored (scene-format.md §2).
    pub(super) fn numbers<T: Token, const N: usize>(&self, node: &Node) -> Result<[T; N]> {
        let mut out = [T::default(); N];
        let mut toks = node.text.split_ascii_whitespace();
        for slot in &mut out {
            *slot = toks.next().and_then(T::parse).ok_or_else(|| {
                self.err(node, format!("expected {}, found {}", expected::<T>(N), quoted(&node.text)))
            })?;
        }
        Ok(out)
    }

    pub(super) fn number<T: Token>(&self, node: &Node) -> Result<T> {
        let [x] = self.numbers::<T, 1>(node)?;
        Ok(x)
    }

    pub(super) fn required_numbers<T: Token, const N: usize>(
        &self,
        parent: &Node,
        name: &str,
    ) -> Result<[T; N]> {
        self.numbers(self.required(parent, name)?)
    }

    pub(super) fn optional_numbers<T: Token, const N: usize>(
        &self,
        parent: &Node,
        name: &str,
    ) -> Result<Option<[T; N]>> {
        parent.child(name).map(|c| self.numbers(c)).transpose()
    }

    pub(super) fn required_number<T: Token>(&self, parent: &Node, name: &str) -> Result<T> {
        self.number(self.required(parent, name)?)
    }

    pub(super) fn optional_number<T: Token>(&self, parent: &Node, name: &str) -> Result<Option<T>> {
        parent.child(name).map(|c| self.number(c)).transpose()
    }

    /// All tokens of `node`'s text, whose count must be a multiple of `group` (`per` says what
    /// a group is, for the message). An error points at the line of the offending token.
    pub(super) fn number_list<T: Token>(&self, node: &Node, group: usize, per: &str) -> Result<Vec<T>> {
        let mut out = Vec::new();
        for (line, token) in tokens(&node.text) {
            let value = T::parse(token).ok_or_else(|| {
                let line = node.content_line.saturating_add(u32::try_from(line).unwrap_or(u32::MAX));
                SceneError::new(
                    self.file,
                    Loc::new(line, node.label.clone()),
                    format!("expected {}, found \"{}\"", T::MANY, excerpt(token)),
                )
            })?;
            out.push(value);
        }
        if out.len() % group != 0 {
            return Err(self.err(
                node,
                format!("the number of values must be a multiple of {group} ({per}), found {}", out.len()),
            ));
        }
        Ok(out)
    }

    /// Trimmed text that must not be empty; `what` names it for the message.
    pub(super) fn text<'n>(&self, node: &'n Node, what: &str) -> Result<&'n str> {
        match node.text.trim() {
            "" => Err(self.err(node, format!("expected {what}, found nothing"))),
            text => Ok(text),
        }
    }

    /// A reference to another element by id: one token.
    pub(super) fn id_ref(&self, node: &Node, what: &str) -> Result<String> {
        let text = self.text(node, what)?;
        if text.split_ascii_whitespace().nth(1).is_some() {
            return Err(self.err(node, format!("expected {what}, found {}", quoted(text))));
        }
        Ok(text.to_string())
    }

    /// The `id` attribute; elements that others refer to (materials, transformations, meshes)
    /// must have one, for the rest it is only used in messages.
    pub(super) fn id(&self, node: &Node, required: bool) -> Result<String> {
        match node.attr("id") {
            Some(id) => Ok(id.trim().to_string()),
            None if required => {
                Err(self.err(node, "missing attribute id (other elements refer to it by id)"))
            }
            None => Ok(String::new()),
        }
    }

    pub(super) fn bool_attr(&self, node: &Node, key: &str) -> Result<Option<bool>> {
        match node.attr(key).map(str::trim) {
            None => Ok(None),
            Some("true") => Ok(Some(true)),
            Some("false") => Ok(Some(false)),
            Some(other) => {
                Err(self.err(node, format!("attribute {key} must be true or false, found \"{other}\"")))
            }
        }
    }

    /// An integer attribute such as `vertexOffset`.
    pub(super) fn int_attr(&self, node: &Node, key: &str) -> Result<Option<i64>> {
        node.attr(key)
            .map(|v| {
                <i64 as Token>::parse(v.trim()).ok_or_else(|| {
                    self.err(node, format!("attribute {key} must be an integer, found \"{}\"", excerpt(v)))
                })
            })
            .transpose()
    }

    /// A number attribute such as `bumpmapMultiplier`.
    pub(super) fn number_attr(&self, node: &Node, key: &str) -> Result<Option<f64>> {
        node.attr(key)
            .map(|v| {
                <f64 as Token>::parse(v.trim()).ok_or_else(|| {
                    self.err(node, format!("attribute {key} must be a number, found \"{}\"", excerpt(v)))
                })
            })
            .transpose()
    }

    /// The text of `node`, which must be one of the `options` (e.g. a DecalMode).
    pub(super) fn keyword<T: Copy>(&self, node: &Node, options: &[(&str, T)]) -> Result<T> {
        let value = node.text.trim();
        match options.iter().find(|(name, _)| *name == value) {
            Some(&(_, v)) => Ok(v),
            None => Err(self.err(
                node,
                format!("{} must be {}, found {}", node.name, one_of(options), quoted(&node.text)),
            )),
        }
    }

    pub(super) fn optional_keyword<T: Copy>(
        &self,
        parent: &Node,
        name: &str,
        options: &[(&str, T)],
    ) -> Result<Option<T>> {
        parent.child(name).map(|c| self.keyword(c, options)).transpose()
    }

    /// `<Normalizer>`, which divides texel values and so must be positive.
    pub(super) fn normalizer(&self, parent: &Node) -> Result<Option<f64>> {
        let Some(n) = parent.child("Normalizer") else { return Ok(None) };
        match self.number::<f64>(n)? {
            v if v > 0.0 => Ok(Some(v)),
            v => Err(self.err(
                n,
                format!("Normalizer must be positive, found {v} (texel values are divided by it; 255 for 8-bit images)"),
            )),
        }
    }

    pub(super) fn shading_attr(&self, node: &Node) -> Result<Option<ShadingMode>> {
        match node.attr("shadingMode").map(str::trim) {
            None => Ok(None),
            Some("smooth") => Ok(Some(ShadingMode::Smooth)),
            Some("flat") => Ok(Some(ShadingMode::Flat)),
            Some(other) => {
                Err(self
                    .err(node, format!("attribute shadingMode must be smooth or flat, found \"{other}\"")))
            }
        }
    }

    /// The first of two alternative children (e.g. `GazePoint` / `Gaze`), warning when both
    /// are given and the second is ignored.
    pub(super) fn either<'n>(&mut self, parent: &'n Node, first: &str, second: &str) -> Option<&'n Node> {
        match (parent.child(first), parent.child(second)) {
            (Some(a), Some(b)) => {
                self.warn(b, format!("<{second}> is ignored because <{first}> is given"));
                Some(a)
            }
            (a, b) => a.or(b),
        }
    }

    /// The optional `<Transformations>` reference string, e.g. `t1 r2 s3 c1`, in written order.
    pub(super) fn transform_refs(&self, n: &Node) -> Result<Vec<TransformRef>> {
        let Some(t) = n.child("Transformations") else { return Ok(Vec::new()) };
        t.text
            .split_ascii_whitespace()
            .map(|token| {
                let mut chars = token.chars();
                match (chars.next(), chars.as_str()) {
                    (Some(letter @ ('t' | 's' | 'r' | 'c')), id)
                        if !id.is_empty() && id.chars().all(|c| c.is_ascii_alphanumeric()) =>
                    {
                        Ok(TransformRef { letter, id: id.to_string() })
                    }
                    _ => Err(self.err(
                        t,
                        format!(
                            "bad transformation reference \"{}\": expected t, s, r or c followed by an id, e.g. \"t1\"",
                            excerpt(token)
                        ),
                    )),
                }
            })
            .collect()
    }
}

// ---------------------------------------------------------------------------------------------
// Messages in JSON words
// ---------------------------------------------------------------------------------------------

/// ` key="value">` at the start of `s`: (key, value, what follows the `>`).
fn one_attribute(s: &str) -> Option<(&str, &str, &str)> {
    let s = s.strip_prefix(' ')?;
    let (key, s) = s.split_once("=\"")?;
    if key.is_empty() || !key.bytes().all(|b| b.is_ascii_alphanumeric()) {
        return None;
    }
    let (value, s) = s.split_once('"')?;
    let tail = s.strip_prefix('>')?;
    (!value.contains(['<', '>'])).then_some((key, value, tail))
}

/// Rewrites a message of the shared element rules in JSON words: `<Faces>` → `"Faces"`,
/// `attribute id` → `key "_id"`.
pub(super) fn json_words(message: &str) -> String {
    let mut out = String::with_capacity(message.len() + 8);
    let mut rest = message;
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix('<') {
            let name_len = after.bytes().take_while(|b| b.is_ascii_alphanumeric()).count();
            if name_len > 0 && after.as_bytes().get(name_len) == Some(&b'>') {
                out.push('"');
                out.push_str(&after[..name_len]);
                out.push('"');
                rest = &after[name_len + 1..];
                continue;
            }
            // `<Name key="value">` (what to add, in build messages): `"Name" with "_key": "value"`.
            if let Some((key, value, tail)) = one_attribute(&after[name_len..]).filter(|_| name_len > 0) {
                out.push_str(&format!("\"{}\" with \"_{key}\": \"{value}\"", &after[..name_len]));
                rest = tail;
                continue;
            }
        }
        if let Some(after) = rest.strip_prefix("attribute ") {
            let name_len = after.bytes().take_while(|b| b.is_ascii_alphanumeric()).count();
            if name_len > 0 {
                out.push_str("key \"_");
                out.push_str(&after[..name_len]);
                out.push('"');
                rest = &after[name_len..];
                continue;
            }
        }
        let mut chars = rest.chars();
        if let Some(c) = chars.next() {
            out.push(c);
        }
        rest = chars.as_str();
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_misspelt_name_finds_the_one_meant() {
        let lights = ["AmbientLight", "PointLight", "AreaLight", "DirectionalLight", "SpotLight"];
        assert_eq!(closest_name("PointLigth", lights.iter().copied()), Some("PointLight"));
        assert_eq!(closest_name("pointlight", lights.iter().copied()), Some("PointLight"));
        assert_eq!(closest_name("Positon", ["Position", "Intensity"].into_iter()), Some("Position"));
        assert_eq!(closest_name("Foo", lights.iter().copied()), None);
        assert_eq!(closest_name("Sphre", ["Sphere", "Mesh"].into_iter()), Some("Sphere"));
        // Short names allow one edit only: `Id` is not `Ids`'s neighbour by two.
        assert_eq!(closest_name("Ix", ["Id", "Ids"].into_iter()), Some("Id"));
        assert_eq!(closest_name("Xyz", ["Id"].into_iter()), None);
        assert_eq!(edit_distance("ligth", "light"), 1);
        assert_eq!(edit_distance("", "abc"), 3);
        assert_eq!(edit_distance("kitten", "sitting"), 3);
    }

    use super::*;

    #[test]
    fn words_are_translated_to_json() {
        assert_eq!(json_words("missing <Faces>"), "missing \"Faces\"");
        assert_eq!(
            json_words("attribute type must be latlong or probe"),
            "key \"_type\" must be latlong or probe"
        );
        assert_eq!(json_words("a < b and <x y>"), "a < b and <x y>");
        assert_eq!(json_words("ünïcode <Ä>"), "ünïcode <Ä>");
        assert_eq!(
            json_words(r#"add <Material id="7"> under <Materials> or use an existing id"#),
            r#"add "Material" with "_id": "7" under "Materials" or use an existing id"#
        );
        // Not one plain attribute: left as written.
        assert_eq!(
            json_words(r#"<A b="1" c="2">, <A b=1>, <A b="1""#),
            r#"<A b="1" c="2">, <A b=1>, <A b="1""#
        );
    }
}
