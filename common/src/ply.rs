//! PLY reader (and a small binary writer) for the meshes of `<Faces plyFile="…"/>` (scene format §8.3).
//!
//! Reads `ascii`, `binary_little_endian` and `binary_big_endian` files with any of the PLY scalar
//! types. The `vertex` element gives positions (`x y z`, required), optional normals (`nx ny nz`) and
//! optional texture coordinates (`u v`, or `s t`, `texture_u texture_v`, `texture_s texture_t`); the
//! `face` element's `vertex_indices` (or `vertex_index`) list gives polygons, which are fan-split into
//! triangles. Every other property and element is skipped, whatever its type.
//!
//! Input is untrusted: every problem is a [`PlyError`], never a panic, and no allocation is sized by a
//! header count larger than the remaining bytes could hold.

use std::fmt::Write as _;

/// A triangle mesh read from a PLY file. Indices are 0-based into `positions`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlyMesh {
    pub positions: Vec<[f32; 3]>,
    /// Per-vertex normals when the file has nx ny nz.
    pub normals: Option<Vec<[f32; 3]>>,
    /// Per-vertex texture coordinates when the file has u v (also accept s t, texture_u texture_v,
    /// texture_s texture_t).
    pub uvs: Option<Vec<[f32; 2]>>,
    /// Triangles; polygons are fan-split (v0, vk, vk+1) preserving winding. Faces with repeated
    /// indices are dropped.
    pub triangles: Vec<[u32; 3]>,
    /// How many faces were dropped as degenerate (repeated index or fewer than 3 vertices).
    pub skipped_degenerate: usize,
}

/// Why a PLY file cannot be read. The message does not name the file; the caller adds it.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct PlyError {
    pub message: String,
    /// 1-based line number in the file when the problem is in the header (or in an ascii body).
    pub line: Option<u32>,
}

impl PlyError {
    fn new(message: impl Into<String>) -> Self {
        PlyError { message: message.into(), line: None }
    }

    fn at(line: u32, message: impl Into<String>) -> Self {
        PlyError { message: message.into(), line: Some(line) }
    }
}

// ------------------------------------------------------------------------------------------------
// Header
// ------------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    kind: Kind,
    line: u32,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
    line: u32,
}

impl Element {
    /// Size of one record when it has no list property.
    fn fixed_size(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }

    fn find(&self, name: &str) -> Option<usize> {
        self.props.iter().position(|p| p.name == name)
    }

    /// Plural noun for "file ends after N of M …" messages.
    fn noun(&self) -> String {
        match self.name.as_str() {
            "vertex" => "vertices".to_string(),
            "face" => "faces".to_string(),
            other => format!("'{other}' elements"),
        }
    }
}

struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Byte offset of the body (just after the `end_header` line).
    body_start: usize,
    /// Line number of the first body line.
    body_line: u32,
}

/// Splits off the next line (without its `\n` / `\r\n`); returns it and the offset after it.
fn next_line(bytes: &[u8], start: usize) -> Option<(&[u8], usize)> {
    if start >= bytes.len() {
        return None;
    }
    let rest = &bytes[start..];
    let (mut line, next) = match rest.iter().position(|&b| b == b'\n') {
        Some(i) => (&rest[..i], start + i + 1),
        None => (rest, bytes.len()),
    };
    if let [head @ .., b'\r'] = line {
        line = head;
    }
    Some((line, next))
}

fn parse_header(bytes: &[u8]) -> Result<Header, PlyError> {
    let mut pos = 0usize;
    let mut line_no = 0u32;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let Some((raw, next)) = next_line(bytes, pos) else {
            if line_no == 0 {
                return Err(PlyError::new("the file is empty, not a PLY file"));
            }
            return Err(PlyError::new(
                "the PLY header has no end_header line (the file ends inside the header)",
            ));
        };
        pos = next;
        line_no = line_no.saturating_add(1);
        if line_no == 1 {
            if raw.trim_ascii() != b"ply" {
                return Err(PlyError::at(1, "not a PLY file: the first line must be 'ply'"));
            }
            continue;
        }
        let Ok(text) = std::str::from_utf8(raw) else {
            return Err(PlyError::at(line_no, "the PLY header contains a line that is not text"));
        };
        let mut words = text.split_ascii_whitespace();
        let Some(keyword) = words.next() else { continue };
        match keyword {
            "comment" | "obj_info" => {}
            "format" => {
                let f = match words.next() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::BinaryLe,
                    Some("binary_big_endian") => Format::BinaryBe,
                    Some(other) => {
                        return Err(PlyError::at(
                            line_no,
                            format!(
                                "unknown PLY format '{other}' (expected ascii, \
                                 binary_little_endian or binary_big_endian)"
                            ),
                        ));
                    }
                    None => return Err(PlyError::at(line_no, "the format line names no format")),
                };
                if format.is_some() {
                    return Err(PlyError::at(line_no, "the PLY header has two format lines"));
                }
                format = Some(f);
            }
            "element" => {
                let (Some(name), Some(count)) = (words.next(), words.next()) else {
                    return Err(PlyError::at(line_no, "expected 'element NAME COUNT'"));
                };
                let Ok(count) = count.parse::<u64>() else {
                    return Err(PlyError::at(
                        line_no,
                        format!("element '{name}' has an invalid count '{count}'"),
                    ));
                };
                if elements.iter().any(|e| e.name == name) {
                    return Err(PlyError::at(
                        line_no,
                        format!("the PLY header declares element '{name}' twice"),
                    ));
                }
                elements.push(Element { name: name.to_string(), count, props: Vec::new(), line: line_no });
            }
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(PlyError::at(line_no, "a property line comes before any element"));
                };
                let scalar = |name: &str| {
                    Scalar::parse(name)
                        .ok_or_else(|| PlyError::at(line_no, format!("unknown property type '{name}'")))
                };
                let kind;
                let name;
                match words.next() {
                    Some("list") => {
                        let (Some(c), Some(i), Some(n)) = (words.next(), words.next(), words.next()) else {
                            return Err(PlyError::at(
                                line_no,
                                "expected 'property list COUNT_TYPE INDEX_TYPE NAME'",
                            ));
                        };
                        let count = scalar(c)?;
                        if !count.is_integer() {
                            return Err(PlyError::at(
                                line_no,
                                format!("list property '{n}' has a non-integer count type '{c}'"),
                            ));
                        }
                        kind = Kind::List { count, item: scalar(i)? };
                        name = n;
                    }
                    Some(t) => {
                        let Some(n) = words.next() else {
                            return Err(PlyError::at(line_no, "expected 'property TYPE NAME'"));
                        };
                        kind = Kind::Scalar(scalar(t)?);
                        name = n;
                    }
                    None => return Err(PlyError::at(line_no, "expected 'property TYPE NAME'")),
                }
                if element.props.iter().any(|p| p.name == name) {
                    return Err(PlyError::at(
                        line_no,
                        format!("element '{}' has two properties named '{name}'", element.name),
                    ));
                }
                element.props.push(Property { name: name.to_string(), kind, line: line_no });
            }
            "end_header" => {
                let Some(format) = format else {
                    return Err(PlyError::at(line_no, "the PLY header has no format line"));
                };
                return Ok(Header {
                    format,
                    elements,
                    body_start: pos,
                    body_line: line_no.saturating_add(1),
                });
            }
            other => {
                return Err(PlyError::at(
                    line_no,
                    format!("unexpected PLY header line starting with '{other}'"),
                ));
            }
        }
    }
}

// ------------------------------------------------------------------------------------------------
// Layout: what each vertex property means
// ------------------------------------------------------------------------------------------------

/// Meaning of one vertex property.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    /// Component of the position (0..3), normal (3..6), uv (6..8) slot.
    Slot(usize),
    Skip,
}

const UV_NAMES: [(&str, &str); 4] =
    [("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t")];

struct VertexLayout {
    roles: Vec<Role>,
    has_normals: bool,
    has_uvs: bool,
}

fn vertex_layout(el: &Element) -> Result<VertexLayout, PlyError> {
    let mut roles = vec![Role::Skip; el.props.len()];
    let mut assign = |idx: usize, slot: usize| -> Result<(), PlyError> {
        let p = &el.props[idx];
        if let Kind::List { .. } = p.kind {
            return Err(PlyError::at(
                p.line,
                format!("vertex property '{}' must be a single value, not a list", p.name),
            ));
        }
        roles[idx] = Role::Slot(slot);
        Ok(())
    };
    for (slot, name) in ["x", "y", "z"].into_iter().enumerate() {
        let Some(idx) = el.find(name) else {
            return Err(PlyError::at(el.line, format!("the vertex element has no '{name}' property")));
        };
        assign(idx, slot)?;
    }
    let normal = (el.find("nx"), el.find("ny"), el.find("nz"));
    let has_normals = if let (Some(a), Some(b), Some(c)) = normal {
        assign(a, 3)?;
        assign(b, 4)?;
        assign(c, 5)?;
        true
    } else {
        false
    };
    let mut has_uvs = false;
    for (un, vn) in UV_NAMES {
        if let (Some(a), Some(b)) = (el.find(un), el.find(vn)) {
            assign(a, 6)?;
            assign(b, 7)?;
            has_uvs = true;
            break;
        }
    }
    Ok(VertexLayout { roles, has_normals, has_uvs })
}

/// Finds the face element's index list: (property index, count type, index type).
fn face_layout(el: &Element) -> Result<usize, PlyError> {
    let Some(idx) = el.find("vertex_indices").or_else(|| el.find("vertex_index")) else {
        return Err(PlyError::at(
            el.line,
            "the face element has no 'vertex_indices' (or 'vertex_index') list property",
        ));
    };
    let p = &el.props[idx];
    match p.kind {
        Kind::List { item, .. } if item.is_integer() => Ok(idx),
        Kind::List { .. } => {
            Err(PlyError::at(p.line, format!("face property '{}' must have an integer index type", p.name)))
        }
        Kind::Scalar(_) => Err(PlyError::at(p.line, format!("face property '{}' must be a list", p.name))),
    }
}

// ------------------------------------------------------------------------------------------------
// Body readers
// ------------------------------------------------------------------------------------------------

enum ReadErr {
    /// The data ran out.
    Eof,
    /// A malformed value (ascii only).
    Bad(PlyError),
}

/// A stream of body values, ascii or binary.
trait Body {
    fn float(&mut self, ty: Scalar) -> Result<f32, ReadErr>;
    /// Reads an integer-typed value (the header guarantees `ty` is an integer type where this is used).
    fn int(&mut self, ty: Scalar) -> Result<i64, ReadErr>;
    fn skip(&mut self, ty: Scalar) -> Result<(), ReadErr>;
    /// Bytes left (bounds allocations).
    fn remaining(&self) -> usize;
    /// The fewest bytes one value can take (1 in binary for the smallest type, 2 in ascii: a digit
    /// and a separator).
    fn min_value_bytes(&self, ty: Scalar) -> usize;
}

struct Binary<'a, const BE: bool> {
    data: &'a [u8],
    pos: usize,
}

impl<const BE: bool> Binary<'_, BE> {
    #[inline(always)]
    fn take<const N: usize>(&mut self) -> Result<[u8; N], ReadErr> {
        let end = self.pos.checked_add(N).ok_or(ReadErr::Eof)?;
        let bytes = self.data.get(self.pos..end).ok_or(ReadErr::Eof)?;
        self.pos = end;
        // The slice has exactly N bytes.
        bytes.try_into().map_err(|_| ReadErr::Eof)
    }
}

macro_rules! from_bytes {
    ($t:ty, $b:expr, $be:expr) => {
        if $be { <$t>::from_be_bytes($b) } else { <$t>::from_le_bytes($b) }
    };
}

/// Decodes one value of type `ty` from the start of `b` as f32.
#[inline(always)]
fn decode_f32(ty: Scalar, b: &[u8], be: bool) -> f32 {
    // Callers pass slices of at least ty.size() bytes; `get` keeps this panic-free anyway.
    fn arr<const N: usize>(b: &[u8]) -> [u8; N] {
        b.get(..N).and_then(|s| s.try_into().ok()).unwrap_or([0; N])
    }
    match ty {
        Scalar::I8 => i8::from_ne_bytes(arr(b)) as f32,
        Scalar::U8 => arr::<1>(b)[0] as f32,
        Scalar::I16 => from_bytes!(i16, arr(b), be) as f32,
        Scalar::U16 => from_bytes!(u16, arr(b), be) as f32,
        Scalar::I32 => from_bytes!(i32, arr(b), be) as f32,
        Scalar::U32 => from_bytes!(u32, arr(b), be) as f32,
        Scalar::F32 => from_bytes!(f32, arr(b), be),
        Scalar::F64 => from_bytes!(f64, arr(b), be) as f32,
    }
}

impl<const BE: bool> Body for Binary<'_, BE> {
    #[inline(always)]
    fn float(&mut self, ty: Scalar) -> Result<f32, ReadErr> {
        Ok(match ty {
            Scalar::I8 => i8::from_ne_bytes(self.take()?) as f32,
            Scalar::U8 => self.take::<1>()?[0] as f32,
            Scalar::I16 => from_bytes!(i16, self.take()?, BE) as f32,
            Scalar::U16 => from_bytes!(u16, self.take()?, BE) as f32,
            Scalar::I32 => from_bytes!(i32, self.take()?, BE) as f32,
            Scalar::U32 => from_bytes!(u32, self.take()?, BE) as f32,
            Scalar::F32 => from_bytes!(f32, self.take()?, BE),
            Scalar::F64 => from_bytes!(f64, self.take()?, BE) as f32,
        })
    }

    #[inline(always)]
    fn int(&mut self, ty: Scalar) -> Result<i64, ReadErr> {
        Ok(match ty {
            Scalar::I8 => i8::from_ne_bytes(self.take()?) as i64,
            Scalar::U8 => self.take::<1>()?[0] as i64,
            Scalar::I16 => from_bytes!(i16, self.take()?, BE) as i64,
            Scalar::U16 => from_bytes!(u16, self.take()?, BE) as i64,
            Scalar::I32 => from_bytes!(i32, self.take()?, BE) as i64,
            Scalar::U32 => from_bytes!(u32, self.take()?, BE) as i64,
            // Not reachable for well-formed layouts (checked in the header); truncate sensibly.
            Scalar::F32 => from_bytes!(f32, self.take()?, BE) as i64,
            Scalar::F64 => from_bytes!(f64, self.take()?, BE) as i64,
        })
    }

    #[inline(always)]
    fn skip(&mut self, ty: Scalar) -> Result<(), ReadErr> {
        self.skip_bytes(ty.size())
    }

    fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    fn min_value_bytes(&self, ty: Scalar) -> usize {
        ty.size()
    }
}

impl<const BE: bool> Binary<'_, BE> {
    fn skip_bytes(&mut self, n: usize) -> Result<(), ReadErr> {
        let end = self.pos.checked_add(n).ok_or(ReadErr::Eof)?;
        if end > self.data.len() {
            return Err(ReadErr::Eof);
        }
        self.pos = end;
        Ok(())
    }
}

struct Ascii<'a> {
    data: &'a [u8],
    pos: usize,
    line: u32,
}

impl<'a> Ascii<'a> {
    /// Next whitespace-separated token and the line it is on.
    fn token(&mut self) -> Result<(&'a [u8], u32), ReadErr> {
        let data = self.data;
        while let Some(&b) = data.get(self.pos) {
            if b == b'\n' {
                self.line = self.line.saturating_add(1);
            } else if !b.is_ascii_whitespace() {
                break;
            }
            self.pos += 1;
        }
        let start = self.pos;
        while let Some(&b) = data.get(self.pos) {
            if b.is_ascii_whitespace() {
                break;
            }
            self.pos += 1;
        }
        if start == self.pos {
            return Err(ReadErr::Eof);
        }
        Ok((&data[start..self.pos], self.line))
    }

    fn bad(token: &[u8], line: u32, what: &str) -> ReadErr {
        let shown: String = String::from_utf8_lossy(token).chars().take(40).collect();
        ReadErr::Bad(PlyError::at(line, format!("expected {what}, found '{shown}'")))
    }
}

impl Body for Ascii<'_> {
    fn float(&mut self, _ty: Scalar) -> Result<f32, ReadErr> {
        let (tok, line) = self.token()?;
        std::str::from_utf8(tok)
            .ok()
            .and_then(|s| s.parse::<f32>().ok())
            .ok_or_else(|| Self::bad(tok, line, "a number"))
    }

    fn int(&mut self, _ty: Scalar) -> Result<i64, ReadErr> {
        let (tok, line) = self.token()?;
        let Ok(s) = std::str::from_utf8(tok) else {
            return Err(Self::bad(tok, line, "an integer"));
        };
        if let Ok(v) = s.parse::<i64>() {
            return Ok(v);
        }
        // Some writers print integers as "3.0"; accept integral floats.
        match s.parse::<f64>() {
            Ok(f) if f.fract() == 0.0 && f.abs() < 9.0e15 => Ok(f as i64),
            _ => Err(Self::bad(tok, line, "an integer")),
        }
    }

    fn skip(&mut self, _ty: Scalar) -> Result<(), ReadErr> {
        self.token().map(|_| ())
    }

    fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    fn min_value_bytes(&self, _ty: Scalar) -> usize {
        2
    }
}

// ------------------------------------------------------------------------------------------------
// Element readers
// ------------------------------------------------------------------------------------------------

/// Turns a body read error into a PlyError naming how far the element got.
fn element_err(e: ReadErr, el: &Element, done: u64) -> PlyError {
    match e {
        ReadErr::Eof => PlyError::new(format!("file ends after {done} of {} {}", el.count, el.noun())),
        ReadErr::Bad(mut err) => {
            err.message = format!("{} (in {} {done})", err.message, el.name);
            err
        }
    }
}

/// A capacity for `count` records that the remaining bytes could actually hold.
fn bounded_capacity(count: u64, remaining: usize, min_record: usize) -> usize {
    let max = remaining / min_record.max(1);
    usize::try_from(count).unwrap_or(usize::MAX).min(max)
}

/// Skips one value of a property (scalar or list).
#[inline]
fn skip_property<B: Body>(body: &mut B, kind: Kind) -> Result<(), ReadErr> {
    match kind {
        Kind::Scalar(s) => body.skip(s),
        Kind::List { count, item } => {
            let n = body.int(count)?;
            for _ in 0..n.max(0) {
                body.skip(item)?;
            }
            Ok(())
        }
    }
}

fn skip_element<B: Body>(body: &mut B, el: &Element) -> Result<(), PlyError> {
    if el.props.is_empty() {
        return Ok(()); // records without properties take no space, however many
    }
    for i in 0..el.count {
        for p in &el.props {
            skip_property(body, p.kind).map_err(|e| element_err(e, el, i))?;
        }
    }
    Ok(())
}

/// Per-vertex output buffers.
struct VertexOut {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    uvs: Option<Vec<[f32; 2]>>,
}

impl VertexOut {
    fn new(layout: &VertexLayout, cap: usize) -> Self {
        VertexOut {
            positions: Vec::with_capacity(cap),
            normals: layout.has_normals.then(|| Vec::with_capacity(cap)),
            uvs: layout.has_uvs.then(|| Vec::with_capacity(cap)),
        }
    }

    #[inline(always)]
    fn push(&mut self, v: &[f32; 8]) {
        self.positions.push([v[0], v[1], v[2]]);
        if let Some(n) = &mut self.normals {
            n.push([v[3], v[4], v[5]]);
        }
        if let Some(t) = &mut self.uvs {
            t.push([v[6], v[7]]);
        }
    }
}

fn read_vertices<B: Body>(body: &mut B, el: &Element, layout: &VertexLayout) -> Result<VertexOut, PlyError> {
    let min_record: usize = el
        .props
        .iter()
        .map(|p| match p.kind {
            Kind::Scalar(s) => body.min_value_bytes(s),
            Kind::List { count, .. } => body.min_value_bytes(count),
        })
        .sum();
    let mut out = VertexOut::new(layout, bounded_capacity(el.count, body.remaining(), min_record));
    let mut v = [0f32; 8];
    for i in 0..el.count {
        for (p, role) in el.props.iter().zip(&layout.roles) {
            let r = match (role, p.kind) {
                (Role::Slot(slot), Kind::Scalar(s)) => body.float(s).map(|x| v[*slot] = x),
                (_, kind) => skip_property(body, kind),
            };
            r.map_err(|e| element_err(e, el, i))?;
        }
        out.push(&v);
    }
    Ok(out)
}

/// Fast path for binary vertex records without lists: fixed-size records read by offset.
fn read_vertices_fixed(
    data: &[u8],
    pos: &mut usize,
    be: bool,
    el: &Element,
    layout: &VertexLayout,
    record: usize,
) -> Result<VertexOut, PlyError> {
    let rest = data.get(*pos..).unwrap_or(&[]);
    let available = (rest.len() / record.max(1)) as u64;
    if available < el.count {
        return Err(PlyError::new(format!("file ends after {available} of {} {}", el.count, el.noun())));
    }
    // available >= count, so count fits in usize and count * record <= rest.len().
    let count = el.count as usize;
    let bytes = &rest[..count * record];
    // (offset, type, slot) for the properties we keep.
    let mut fields: Vec<(usize, Scalar, usize)> = Vec::new();
    let mut offset = 0;
    for (p, role) in el.props.iter().zip(&layout.roles) {
        if let (Kind::Scalar(s), Role::Slot(slot)) = (p.kind, role) {
            fields.push((offset, s, *slot));
        }
        if let Kind::Scalar(s) = p.kind {
            offset += s.size();
        }
    }
    let mut out = VertexOut::new(layout, count);
    let mut v = [0f32; 8];
    for rec in bytes.chunks_exact(record) {
        for &(off, ty, slot) in &fields {
            v[slot] = decode_f32(ty, &rec[off..], be);
        }
        out.push(&v);
    }
    *pos += count * record;
    Ok(out)
}

/// True when `idx` (a small polygon) repeats a vertex.
fn has_repeat(idx: &[u32], scratch: &mut Vec<u32>) -> bool {
    if idx.len() <= 16 {
        return idx.iter().enumerate().any(|(i, a)| idx[i + 1..].contains(a));
    }
    scratch.clear();
    scratch.extend_from_slice(idx);
    scratch.sort_unstable();
    scratch.windows(2).any(|w| w[0] == w[1])
}

fn read_faces<B: Body>(
    body: &mut B,
    el: &Element,
    list_prop: usize,
    vertex_count: u64,
    out: &mut Vec<[u32; 3]>,
    skipped: &mut usize,
) -> Result<(), PlyError> {
    let Kind::List { count: count_ty, item: index_ty } = el.props[list_prop].kind else {
        return Err(PlyError::new("internal: face list property is not a list"));
    };
    let min_record: usize = el
        .props
        .iter()
        .map(|p| match p.kind {
            Kind::Scalar(s) => body.min_value_bytes(s),
            Kind::List { count, .. } => body.min_value_bytes(count),
        })
        .sum();
    out.reserve(bounded_capacity(el.count, body.remaining(), min_record));
    let mut poly: Vec<u32> = Vec::new();
    let mut scratch: Vec<u32> = Vec::new();
    for face in 0..el.count {
        for (pi, p) in el.props.iter().enumerate() {
            if pi != list_prop {
                skip_property(body, p.kind).map_err(|e| element_err(e, el, face))?;
                continue;
            }
            let n = body.int(count_ty).map_err(|e| element_err(e, el, face))?;
            poly.clear();
            for _ in 0..n.max(0) {
                let raw = body.int(index_ty).map_err(|e| element_err(e, el, face))?;
                if raw < 0 {
                    return Err(PlyError::new(format!("face {face} has a negative vertex index {raw}")));
                }
                if raw as u64 >= vertex_count {
                    return Err(PlyError::new(format!(
                        "face {face} refers to vertex {raw} but the file has {vertex_count} vertices"
                    )));
                }
                // vertex_count <= u32::MAX + 1 (checked by the caller), so this fits.
                poly.push(raw as u32);
            }
            if poly.len() < 3 || has_repeat(&poly, &mut scratch) {
                *skipped += 1;
                continue;
            }
            let v0 = poly[0];
            for w in poly[1..].windows(2) {
                out.push([v0, w[0], w[1]]);
            }
        }
    }
    Ok(())
}

// ------------------------------------------------------------------------------------------------
// Entry point
// ------------------------------------------------------------------------------------------------

/// Parses a PLY file's bytes. Errors are plain messages (the caller adds the file name),
/// e.g. "face 12 refers to vertex 5000 but the file has 4821 vertices".
///
/// Accepts `ascii`, `binary_little_endian` and `binary_big_endian` bodies, LF or CRLF line ends,
/// and every PLY scalar type. Requires a `vertex` element with `x y z` and a `face` element with a
/// `vertex_indices` (or `vertex_index`) list; a file without faces is an error ("the PLY has no
/// faces"). Never panics.
pub fn parse_ply(bytes: &[u8]) -> Result<PlyMesh, PlyError> {
    let header = parse_header(bytes)?;
    let Some(vi) = header.elements.iter().position(|e| e.name == "vertex") else {
        return Err(PlyError::new("the PLY has no vertex element"));
    };
    let vertex_el = &header.elements[vi];
    let layout = vertex_layout(vertex_el)?;
    if vertex_el.count > u64::from(u32::MAX) + 1 {
        return Err(PlyError::at(
            vertex_el.line,
            format!("the PLY declares {} vertices, more than 32-bit indices can address", vertex_el.count),
        ));
    }
    let Some(fi) = header.elements.iter().position(|e| e.name == "face" && e.count > 0) else {
        return Err(PlyError::new("the PLY has no faces"));
    };
    let list_prop = face_layout(&header.elements[fi])?;

    let body = bytes.get(header.body_start..).unwrap_or(&[]);
    match header.format {
        Format::Ascii => {
            let mut r = Ascii { data: body, pos: 0, line: header.body_line };
            read_body(&mut r, &header, vi, &layout, fi, list_prop, None)
        }
        Format::BinaryLe => {
            let mut r = Binary::<false> { data: body, pos: 0 };
            read_body(&mut r, &header, vi, &layout, fi, list_prop, Some(false))
        }
        Format::BinaryBe => {
            let mut r = Binary::<true> { data: body, pos: 0 };
            read_body(&mut r, &header, vi, &layout, fi, list_prop, Some(true))
        }
    }
}

/// Access to a binary reader's buffer for the fixed-record fast path.
trait RawAccess {
    fn raw(&mut self) -> Option<(&[u8], &mut usize)>;
}

impl RawAccess for Ascii<'_> {
    fn raw(&mut self) -> Option<(&[u8], &mut usize)> {
        None
    }
}

impl<const BE: bool> RawAccess for Binary<'_, BE> {
    fn raw(&mut self) -> Option<(&[u8], &mut usize)> {
        Some((self.data, &mut self.pos))
    }
}

fn read_body<B: Body + RawAccess>(
    body: &mut B,
    header: &Header,
    vi: usize,
    layout: &VertexLayout,
    fi: usize,
    list_prop: usize,
    binary_be: Option<bool>,
) -> Result<PlyMesh, PlyError> {
    let mut mesh = PlyMesh::default();
    let vertex_count = header.elements[vi].count;
    for (i, el) in header.elements.iter().enumerate() {
        if i == vi {
            let fixed = binary_be.zip(el.fixed_size());
            let out = match (fixed, body.raw()) {
                (Some((be, record)), Some((data, pos))) => {
                    read_vertices_fixed(data, pos, be, el, layout, record)?
                }
                _ => read_vertices(body, el, layout)?,
            };
            mesh.positions = out.positions;
            mesh.normals = out.normals;
            mesh.uvs = out.uvs;
        } else if i == fi {
            read_faces(body, el, list_prop, vertex_count, &mut mesh.triangles, &mut mesh.skipped_degenerate)?;
        } else if let (Some(record), Some((data, pos))) = (el.fixed_size(), body.raw()) {
            // Binary element without lists: skip it in one step.
            let total = (record as u64).checked_mul(el.count);
            let rest = data.len().saturating_sub(*pos) as u64;
            match total {
                Some(t) if t <= rest => *pos += t as usize,
                _ => {
                    let done = rest / record.max(1) as u64;
                    return Err(PlyError::new(format!(
                        "file ends after {done} of {} {}",
                        el.count,
                        el.noun()
                    )));
                }
            }
        } else {
            skip_element(body, el)?;
        }
    }
    Ok(mesh)
}

// ------------------------------------------------------------------------------------------------
// Writer
// ------------------------------------------------------------------------------------------------

/// Writes `mesh` as a `binary_little_endian` PLY: `float x y z`, plus `float nx ny nz` when
/// `mesh.normals` is present and `float u v` when `mesh.uvs` is present (each only when it has one
/// entry per position), and one `list uchar int vertex_indices` face per triangle.
/// `skipped_degenerate` is not stored. [`parse_ply`] reads the result back into an equal mesh
/// (with `skipped_degenerate == 0`, provided no triangle repeats an index).
pub fn write_ply_binary_le(mesh: &PlyMesh) -> Vec<u8> {
    let n = mesh.positions.len();
    let normals = mesh.normals.as_ref().filter(|v| v.len() == n);
    let uvs = mesh.uvs.as_ref().filter(|v| v.len() == n);
    let mut header = String::new();
    header.push_str("ply\nformat binary_little_endian 1.0\ncomment written by tessera\n");
    let _ = writeln!(header, "element vertex {n}");
    header.push_str("property float x\nproperty float y\nproperty float z\n");
    if normals.is_some() {
        header.push_str("property float nx\nproperty float ny\nproperty float nz\n");
    }
    if uvs.is_some() {
        header.push_str("property float u\nproperty float v\n");
    }
    let _ = writeln!(header, "element face {}", mesh.triangles.len());
    header.push_str("property list uchar int vertex_indices\nend_header\n");

    let per_vertex = 12 + if normals.is_some() { 12 } else { 0 } + if uvs.is_some() { 8 } else { 0 };
    let mut out = Vec::with_capacity(header.len() + n * per_vertex + mesh.triangles.len() * 13);
    out.extend_from_slice(header.as_bytes());
    for i in 0..n {
        for c in mesh.positions[i] {
            out.extend_from_slice(&c.to_le_bytes());
        }
        if let Some(nm) = normals {
            for c in nm[i] {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        if let Some(t) = uvs {
            for c in t[i] {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    for t in &mesh.triangles {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    out
}

// ------------------------------------------------------------------------------------------------
// Tests
// ------------------------------------------------------------------------------------------------

#[cfg(test)]
mod tests {
    use super::*;

    // --- A tiny PLY builder: the same records rendered as ascii, binary LE or binary BE ---------

    /// One typed value of a record.
    #[derive(Clone, Copy, Debug)]
    enum V {
        I8(i8),
        U8(u8),
        I16(i16),
        U16(u16),
        I32(i32),
        U32(u32),
        F32(f32),
        F64(f64),
    }

    impl V {
        fn ascii(self) -> String {
            match self {
                V::I8(x) => x.to_string(),
                V::U8(x) => x.to_string(),
                V::I16(x) => x.to_string(),
                V::U16(x) => x.to_string(),
                V::I32(x) => x.to_string(),
                V::U32(x) => x.to_string(),
                V::F32(x) => x.to_string(),
                V::F64(x) => x.to_string(),
            }
        }

        fn binary(self, be: bool, out: &mut Vec<u8>) {
            macro_rules! put {
                ($x:expr) => {
                    if be {
                        out.extend_from_slice(&$x.to_be_bytes())
                    } else {
                        out.extend_from_slice(&$x.to_le_bytes())
                    }
                };
            }
            match self {
                V::I8(x) => put!(x),
                V::U8(x) => put!(x),
                V::I16(x) => put!(x),
                V::U16(x) => put!(x),
                V::I32(x) => put!(x),
                V::U32(x) => put!(x),
                V::F32(x) => put!(x),
                V::F64(x) => put!(x),
            }
        }
    }

    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Fmt {
        Ascii,
        Le,
        Be,
    }

    const ALL: [Fmt; 3] = [Fmt::Ascii, Fmt::Le, Fmt::Be];

    /// Builds a PLY from header lines after `format` (elements and properties) and body records.
    fn build(fmt: Fmt, header: &[&str], records: &[Vec<V>]) -> Vec<u8> {
        let name = match fmt {
            Fmt::Ascii => "ascii",
            Fmt::Le => "binary_little_endian",
            Fmt::Be => "binary_big_endian",
        };
        let mut out = format!("ply\nformat {name} 1.0\ncomment test fixture\n").into_bytes();
        for h in header {
            out.extend_from_slice(h.as_bytes());
            out.push(b'\n');
        }
        out.extend_from_slice(b"end_header\n");
        for r in records {
            match fmt {
                Fmt::Ascii => {
                    let line: Vec<String> = r.iter().map(|v| v.ascii()).collect();
                    out.extend_from_slice(line.join(" ").as_bytes());
                    out.push(b'\n');
                }
                Fmt::Le | Fmt::Be => r.iter().for_each(|v| v.binary(fmt == Fmt::Be, &mut out)),
            }
        }
        out
    }

    fn f(x: f32) -> V {
        V::F32(x)
    }

    /// The header lines of a float-xyz vertex element of 3 and a face element of `faces`.
    fn triangle_header(faces: usize) -> Vec<String> {
        ["element vertex 3", "property float x", "property float y", "property float z"]
            .iter()
            .map(|l| l.to_string())
            .chain([format!("element face {faces}"), "property list uchar int vertex_indices".into()])
            .collect()
    }

    /// The three vertices (0,0,0), (1,0,0), (0,1,0) as records.
    fn triangle_vertices() -> Vec<Vec<V>> {
        vec![vec![f(0.), f(0.), f(0.)], vec![f(1.), f(0.), f(0.)], vec![f(0.), f(1.), f(0.)]]
    }

    /// A binary file of that one triangle, with `before` header lines ahead of its elements.
    fn one_triangle(fmt: Fmt, before: &[&str]) -> Vec<u8> {
        let header = triangle_header(1);
        let lines: Vec<&str> = before.iter().copied().chain(header.iter().map(String::as_str)).collect();
        let mut records = triangle_vertices();
        records.push(face(&[0, 1, 2]));
        build(fmt, &lines, &records)
    }

    /// A face record with uchar count and int indices.
    fn face(idx: &[i32]) -> Vec<V> {
        let mut r = vec![V::U8(idx.len() as u8)];
        r.extend(idx.iter().map(|&i| V::I32(i)));
        r
    }

    fn parse_ok(bytes: &[u8]) -> PlyMesh {
        match parse_ply(bytes) {
            Ok(m) => m,
            Err(e) => panic!("parse failed: {e} (line {:?})", e.line),
        }
    }

    fn err_of(bytes: &[u8]) -> PlyError {
        match parse_ply(bytes) {
            Ok(m) => panic!("expected an error, got {m:?}"),
            Err(e) => e,
        }
    }

    // --- Successful parses -----------------------------------------------------------------------

    /// cube.ply as shipped (ascii, quads, `vertex_index`).
    const CUBE: &str = "ply
format ascii 1.0
comment made by Greg Turk
comment this file is a cube
element vertex 8
property float x
property float y
property float z
element face 6
property list uchar int vertex_index
end_header
0 0 0
0 0 1
0 1 1
0 1 0
1 0 0
1 0 1
1 1 1
1 1 0
4 0 1 2 3
4 7 6 5 4
4 0 4 5 1
4 1 5 6 2
4 2 6 7 3
4 3 7 4 0
";

    fn cube_expected() -> PlyMesh {
        PlyMesh {
            positions: vec![
                [0., 0., 0.],
                [0., 0., 1.],
                [0., 1., 1.],
                [0., 1., 0.],
                [1., 0., 0.],
                [1., 0., 1.],
                [1., 1., 1.],
                [1., 1., 0.],
            ],
            normals: None,
            uvs: None,
            triangles: vec![
                [0, 1, 2],
                [0, 2, 3],
                [7, 6, 5],
                [7, 5, 4],
                [0, 4, 5],
                [0, 5, 1],
                [1, 5, 6],
                [1, 6, 2],
                [2, 6, 7],
                [2, 7, 3],
                [3, 7, 4],
                [3, 4, 0],
            ],
            skipped_degenerate: 0,
        }
    }

    #[test]
    fn ascii_cube_quads_fan_split() {
        assert_eq!(parse_ok(CUBE.as_bytes()), cube_expected());
    }

    #[test]
    fn crlf_header_and_body() {
        let crlf = CUBE.replace('\n', "\r\n");
        assert_eq!(parse_ok(crlf.as_bytes()), cube_expected());
        // Binary body after a CRLF header.
        let bin = one_triangle(Fmt::Le, &[]);
        let split = bin.windows(10).position(|w| w == b"end_header").unwrap() + 11;
        let mut with_crlf =
            String::from_utf8(bin[..split].to_vec()).unwrap().replace('\n', "\r\n").into_bytes();
        with_crlf.extend_from_slice(&bin[split..]);
        let m = parse_ok(&with_crlf);
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        assert_eq!(m.positions[1], [1., 0., 0.]);
    }

    /// A triangle, a quad and a pentagon over 7 vertices with normals and uvs.
    fn poly_records() -> Vec<Vec<V>> {
        let mut r = Vec::new();
        for i in 0..7 {
            let x = i as f32;
            r.push(vec![f(x), f(x * 0.5), f(-x), f(0.), f(0.), f(1.), f(x / 8.), f(1. - x / 8.)]);
        }
        r.push(face(&[0, 1, 2]));
        r.push(face(&[0, 2, 3, 4]));
        r.push(face(&[6, 5, 4, 3, 2]));
        r
    }

    fn poly_expected() -> PlyMesh {
        let positions = (0..7).map(|i| [i as f32, i as f32 * 0.5, -(i as f32)]).collect();
        let normals = vec![[0., 0., 1.]; 7];
        let uvs = (0..7).map(|i| [i as f32 / 8., 1. - i as f32 / 8.]).collect();
        PlyMesh {
            positions,
            normals: Some(normals),
            uvs: Some(uvs),
            triangles: vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [6, 5, 4], [6, 4, 3], [6, 3, 2]],
            skipped_degenerate: 0,
        }
    }

    const POLY_HEADER: &[&str] = &[
        "element vertex 7",
        "property float x",
        "property float y",
        "property float z",
        "property float nx",
        "property float ny",
        "property float nz",
        "property float u",
        "property float v",
        "element face 3",
        "property list uchar int vertex_indices",
    ];

    #[test]
    fn normals_uvs_quads_and_pentagon_in_every_format() {
        for fmt in ALL {
            let bytes = build(fmt, POLY_HEADER, &poly_records());
            assert_eq!(parse_ok(&bytes), poly_expected(), "{fmt:?}");
        }
    }

    #[test]
    fn extra_properties_and_elements_are_skipped_in_every_format() {
        // Vertex: colours of several types, a double, a list on the vertex; x y z out of order,
        // double-typed z. Face: flags before and after the list, another list. Extra elements
        // before, between and after.
        let header = &[
            "element material 2",
            "property uchar red",
            "property float shininess",
            "property list ushort short weights",
            "element vertex 4",
            "property uchar red",
            "property char tag",
            "property double z",
            "property short s16",
            "property float x",
            "property list uint8 float extra",
            "property ushort u16",
            "property float y",
            "property int i32",
            "property uint u32",
            "property float confidence",
            "element edge 2",
            "property int vertex1",
            "property int vertex2",
            "property uchar red",
            "element face 2",
            "property int flags",
            "property list uint uint vertex_indices",
            "property list uchar float texcoord",
            "property double area",
            "element trailer 1",
            "property list int int stuff",
        ];
        let vertex = |x: f32, y: f32, z: f64, extra: &[f32]| {
            let mut r = vec![V::U8(200), V::I8(-3), V::F64(z), V::I16(-1000), f(x), V::U8(extra.len() as u8)];
            r.extend(extra.iter().map(|&e| f(e)));
            r.extend([V::U16(60000), f(y), V::I32(-7), V::U32(4_000_000_000), f(0.5)]);
            r
        };
        let records = vec![
            vec![V::U8(1), f(0.25), V::U16(2), V::I16(-1), V::I16(2)],
            vec![V::U8(2), f(0.75), V::U16(0)],
            vertex(0., 0., 0., &[]),
            vertex(1., 0., 0.5, &[9., 9.]),
            vertex(1., 1., 1., &[1.]),
            vertex(0., 1., -2.25, &[]),
            vec![V::I32(0), V::I32(1), V::U8(255)],
            vec![V::I32(1), V::I32(2), V::U8(0)],
            vec![
                V::I32(-1),
                V::U32(4),
                V::U32(0),
                V::U32(1),
                V::U32(2),
                V::U32(3),
                V::U8(2),
                f(0.),
                f(1.),
                V::F64(0.5),
            ],
            vec![V::I32(7), V::U32(3), V::U32(3), V::U32(2), V::U32(1), V::U8(0), V::F64(1.5)],
            vec![V::I32(3), V::I32(1), V::I32(2), V::I32(3)],
        ];
        let expected = PlyMesh {
            positions: vec![[0., 0., 0.], [1., 0., 0.5], [1., 1., 1.], [0., 1., -2.25]],
            normals: None,
            uvs: None,
            triangles: vec![[0, 1, 2], [0, 2, 3], [3, 2, 1]],
            skipped_degenerate: 0,
        };
        for fmt in ALL {
            let bytes = build(fmt, header, &records);
            assert_eq!(parse_ok(&bytes), expected, "{fmt:?}");
        }
    }

    /// Builds a value of some PLY type from a small position coordinate / count / index.
    type PosMaker = fn(i8) -> V;
    type IntMaker = fn(u8) -> V;

    #[test]
    fn every_scalar_type_for_positions_and_indices() {
        // (type name, value builder) for positions; every integer type for counts and indices.
        let pos_types: &[(&str, PosMaker)] = &[
            ("char", |x| V::I8(x)),
            ("int8", |x| V::I8(x)),
            ("uchar", |x| V::U8(x as u8)),
            ("uint8", |x| V::U8(x as u8)),
            ("short", |x| V::I16(x as i16)),
            ("int16", |x| V::I16(x as i16)),
            ("ushort", |x| V::U16(x as u16)),
            ("uint16", |x| V::U16(x as u16)),
            ("int", |x| V::I32(x as i32)),
            ("int32", |x| V::I32(x as i32)),
            ("uint", |x| V::U32(x as u32)),
            ("uint32", |x| V::U32(x as u32)),
            ("float", |x| V::F32(x as f32)),
            ("float32", |x| V::F32(x as f32)),
            ("double", |x| V::F64(x as f64)),
            ("float64", |x| V::F64(x as f64)),
        ];
        let int_types: &[(&str, IntMaker)] = &[
            ("char", |x| V::I8(x as i8)),
            ("uchar", |x| V::U8(x)),
            ("short", |x| V::I16(x as i16)),
            ("ushort", |x| V::U16(x as u16)),
            ("int", |x| V::I32(x as i32)),
            ("uint", |x| V::U32(x as u32)),
            ("int8", |x| V::I8(x as i8)),
            ("uint32", |x| V::U32(x as u32)),
        ];
        for (pt, pv) in pos_types {
            for (ct, cv) in int_types {
                for (it, iv) in int_types {
                    let header = [
                        "element vertex 4".to_string(),
                        format!("property {pt} x"),
                        format!("property {pt} y"),
                        format!("property {pt} z"),
                        "element face 1".to_string(),
                        format!("property list {ct} {it} vertex_indices"),
                    ];
                    let header: Vec<&str> = header.iter().map(|s| s.as_str()).collect();
                    let records = vec![
                        vec![pv(0), pv(0), pv(0)],
                        vec![pv(1), pv(0), pv(2)],
                        vec![pv(1), pv(1), pv(3)],
                        vec![pv(0), pv(1), pv(4)],
                        vec![cv(4), iv(0), iv(1), iv(2), iv(3)],
                    ];
                    for fmt in ALL {
                        let m = parse_ok(&build(fmt, &header, &records));
                        assert_eq!(
                            m.positions,
                            vec![[0., 0., 0.], [1., 0., 2.], [1., 1., 3.], [0., 1., 4.]],
                            "{pt} {ct} {it} {fmt:?}"
                        );
                        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]], "{pt} {ct} {it} {fmt:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn uv_spellings_and_partial_normals() {
        for (u, v) in UV_NAMES {
            let header = [
                "element vertex 3".to_string(),
                "property float x".into(),
                "property float y".into(),
                "property float z".into(),
                "property float nx".into(), // partial normals: ignored
                format!("property float {u}"),
                format!("property float {v}"),
                "element face 1".into(),
                "property list uchar int vertex_indices".into(),
            ];
            let header: Vec<&str> = header.iter().map(|s| s.as_str()).collect();
            let records = vec![
                vec![f(0.), f(0.), f(0.), f(1.), f(0.1), f(0.2)],
                vec![f(1.), f(0.), f(0.), f(1.), f(0.3), f(0.4)],
                vec![f(0.), f(1.), f(0.), f(1.), f(0.5), f(0.6)],
                face(&[0, 1, 2]),
            ];
            for fmt in ALL {
                let m = parse_ok(&build(fmt, &header, &records));
                assert_eq!(m.normals, None);
                assert_eq!(m.uvs, Some(vec![[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]]), "{u} {v} {fmt:?}");
            }
        }
    }

    #[test]
    fn degenerate_faces_are_dropped_and_counted() {
        let header = &[
            "element vertex 4",
            "property float x",
            "property float y",
            "property float z",
            "element face 7",
            "property list uchar int vertex_indices",
        ];
        let records = vec![
            vec![f(0.), f(0.), f(0.)],
            vec![f(1.), f(0.), f(0.)],
            vec![f(1.), f(1.), f(0.)],
            vec![f(0.), f(1.), f(0.)],
            face(&[0, 1, 1]),
            face(&[]),
            face(&[2, 3]),
            face(&[0, 1, 2]),
            face(&[0, 1, 2, 0]),
            face(&[3, 2, 1, 0]),
            face(&[0, 0, 0]),
        ];
        for fmt in ALL {
            let m = parse_ok(&build(fmt, header, &records));
            assert_eq!(m.triangles, vec![[0, 1, 2], [3, 2, 1], [3, 1, 0]], "{fmt:?}");
            assert_eq!(m.skipped_degenerate, 5, "{fmt:?}");
        }
        // A long polygon with a repeat far apart (sort-based check).
        let mut idx: Vec<u32> = (0..40).collect();
        let mut scratch = Vec::new();
        assert!(!has_repeat(&idx, &mut scratch));
        idx.push(17);
        assert!(has_repeat(&idx, &mut scratch));
    }

    #[test]
    fn header_variants() {
        // obj_info, blank lines, extra spaces, vertex_index, trailing garbage after the body,
        // faces declared before vertices.
        let text = "ply\r\nformat   ascii 1.0\nobj_info generated\n\ncomment x\nelement face 1\n\
                    property list uchar int vertex_index\nelement vertex 3\nproperty float x\n\
                    property float y\nproperty float z\nend_header\n3 2 1 0\n0 0 0\n1 0 0\n0 1 0\n\
                    trailing junk is ignored\n";
        let m = parse_ok(text.as_bytes());
        assert_eq!(m.triangles, vec![[2, 1, 0]]);
        assert_eq!(m.positions.len(), 3);
        // ascii values may be spread over lines arbitrarily, integers may be written as "3.0".
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                    property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                    end_header\n0 0 0 1\n0 0 0 1 0\n3.0 0 1 2";
        assert_eq!(parse_ok(text.as_bytes()).triangles, vec![[0, 1, 2]]);
        // Empty element with no properties and a huge count is skipped instantly in binary.
        let bin = one_triangle(Fmt::Le, &["element nothing 4000000000"]);
        assert_eq!(parse_ok(&bin).triangles, vec![[0, 1, 2]]);
    }

    // --- Errors ---------------------------------------------------------------------------------

    #[test]
    fn error_messages() {
        let tri = |fmt_line: &str, vprops: &str, face_prop: &str, body: &str| {
            format!(
                "ply\n{fmt_line}\nelement vertex 3\n{vprops}element face 1\n{face_prop}\nend_header\n{body}"
            )
        };
        let xyz = "property float x\nproperty float y\nproperty float z\n";
        let list = "property list uchar int vertex_indices";
        let ok_body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        // (input, expected message, expected line)
        let cases: Vec<(String, &str, Option<u32>)> = vec![
            (String::new(), "the file is empty, not a PLY file", None),
            ("PLY\nformat ascii 1.0\n".into(), "not a PLY file: the first line must be 'ply'", Some(1)),
            ("solid cube\n".into(), "not a PLY file: the first line must be 'ply'", Some(1)),
            ("ply\nformat ascii 1.0\nelement vertex 3\n".into(),
             "the PLY header has no end_header line (the file ends inside the header)", None),
            (tri("format binary_middle_endian 1.0", xyz, list, ok_body),
             "unknown PLY format 'binary_middle_endian' (expected ascii, binary_little_endian or binary_big_endian)",
             Some(2)),
            ("ply\nelement vertex 1\nproperty float x\nend_header\n".into(),
             "the PLY header has no format line", Some(4)),
            (tri("format ascii 1.0", "property float x\nproperty real y\nproperty float z\n", list, ok_body),
             "unknown property type 'real'", Some(5)),
            (tri("format ascii 1.0", xyz, "property list uchar integer vertex_indices", ok_body),
             "unknown property type 'integer'", Some(8)),
            (tri("format ascii 1.0", xyz, "property list float int vertex_indices", ok_body),
             "list property 'vertex_indices' has a non-integer count type 'float'", Some(8)),
            (tri("format ascii 1.0", xyz, "property list uchar float vertex_indices", ok_body),
             "face property 'vertex_indices' must have an integer index type", Some(8)),
            (tri("format ascii 1.0", xyz, "property int vertex_indices", ok_body),
             "face property 'vertex_indices' must be a list", Some(8)),
            (tri("format ascii 1.0", xyz, "property list uchar int indices", ok_body),
             "the face element has no 'vertex_indices' (or 'vertex_index') list property", Some(7)),
            (tri("format ascii 1.0", "property float x\nproperty float z\n", list, ok_body),
             "the vertex element has no 'y' property", Some(3)),
            (tri("format ascii 1.0", "property float x\nproperty float y\nproperty list uchar float z\n", list, ok_body),
             "vertex property 'z' must be a single value, not a list", Some(6)),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n".into(),
             "the PLY has no faces", None),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n".into(),
             "the PLY has no faces", None),
            ("ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n3 0 1 2\n".into(),
             "the PLY has no vertex element", None),
            ("ply\nformat ascii 1.0\nproperty float x\nend_header\n".into(),
             "a property line comes before any element", Some(3)),
            ("ply\nformat ascii 1.0\nelement vertex many\nend_header\n".into(),
             "element 'vertex' has an invalid count 'many'", Some(3)),
            ("ply\nformat ascii 1.0\nelement vertex -1\nend_header\n".into(),
             "element 'vertex' has an invalid count '-1'", Some(3)),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\nend_header\n".into(),
             "element 'vertex' has two properties named 'x'", Some(5)),
            ("ply\nformat ascii 1.0\nelement vertex 1\nelement vertex 1\nend_header\n".into(),
             "the PLY header declares element 'vertex' twice", Some(4)),
            ("ply\nformat ascii 1.0\nformat ascii 1.0\nend_header\n".into(),
             "the PLY header has two format lines", Some(3)),
            ("ply\nformat ascii 1.0\nvertex 3\nend_header\n".into(),
             "unexpected PLY header line starting with 'vertex'", Some(3)),
            (tri("format ascii 1.0", xyz, list, "0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n"),
             "face 0 refers to vertex 5 but the file has 3 vertices", None),
            (tri("format ascii 1.0", xyz, list, "0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"),
             "face 0 has a negative vertex index -1", None),
            (tri("format ascii 1.0", xyz, list, "0 0 0\n1 0 0\n0 1 0\n"),
             "file ends after 0 of 1 faces", None),
            (tri("format ascii 1.0", xyz, list, "0 0 0\n1 0 0\n0 1\n"),
             "file ends after 2 of 3 vertices", None),
            (tri("format ascii 1.0", xyz, list, "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n"),
             "expected a number, found 'zero' (in vertex 1)", Some(11)),
            (tri("format ascii 1.0", xyz, list, "0 0 0\n1 0 0\n0 1 0\nthree 0 1 2\n"),
             "expected an integer, found 'three' (in face 0)", Some(13)),
            (tri("format ascii 1.0", xyz, list, "0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n"),
             "expected an integer, found '1.5' (in face 0)", Some(13)),
            (tri("format binary_little_endian 1.0", xyz, list, ""),
             "file ends after 0 of 3 vertices", None),
            ("ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 4000000000\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0".into(),
             "file ends after 0 of 4000000000 vertices", None),
            ("ply\nformat ascii 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n".into(),
             "file ends after 1 of 4000000000 vertices", None),
            ("ply\nformat binary_little_endian 1.0\nelement vertex 5000000000\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".into(),
             "the PLY declares 5000000000 vertices, more than 32-bit indices can address", Some(3)),
            ("ply\nformat binary_little_endian 1.0\nelement edge 4000000000\nproperty int a\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0\0\0\0\0\0".into(),
             "file ends after 2 of 4000000000 'edge' elements", None),
            ("ply\nformat binary_little_endian 1.0\nelement edge 4000000000\nproperty list uchar int a\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\0\0\0".into(),
             "file ends after 3 of 4000000000 'edge' elements", None),
        ];
        for (input, message, line) in cases {
            let e = err_of(input.as_bytes());
            assert_eq!((e.message.as_str(), e.line), (message, line), "input:\n{input}");
            assert_eq!(e.to_string(), message);
        }
        // Binary: an index out of range and a truncated face list.
        let header_lines = triangle_header(2);
        let header: &[&str] = &header_lines.iter().map(String::as_str).collect::<Vec<_>>();
        let verts = triangle_vertices();
        for fmt in [Fmt::Le, Fmt::Be] {
            let mut r = verts.clone();
            r.push(face(&[0, 1, 2]));
            r.push(face(&[0, 1, 3000]));
            assert_eq!(
                err_of(&build(fmt, header, &r)).message,
                "face 1 refers to vertex 3000 but the file has 3 vertices"
            );
            let mut r = verts.clone();
            r.push(face(&[0, 1, 2]));
            let mut bytes = build(fmt, header, &r);
            bytes.extend_from_slice(&[4, 0, 0]);
            assert_eq!(err_of(&bytes).message, "file ends after 1 of 2 faces");
        }
    }

    // --- Robustness -----------------------------------------------------------------------------

    #[test]
    fn every_prefix_and_mutation_is_ok_or_err_never_panics() {
        let header_extra = POLY_HEADER;
        for fmt in ALL {
            let full = build(fmt, header_extra, &poly_records());
            assert!(parse_ply(&full).is_ok());
            for len in 0..full.len() {
                let r = parse_ply(&full[..len]);
                // A binary prefix that cut the body must fail; ascii prefixes may cut a number short.
                if fmt != Fmt::Ascii && len < full.len() {
                    assert!(r.is_err(), "{fmt:?} prefix {len} parsed");
                }
            }
            // Deterministic byte mutations (xorshift).
            let mut s: u64 = 0x9e37_79b9_7f4a_7c15;
            let mut next = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                s
            };
            for _ in 0..3000 {
                let mut bytes = full.clone();
                for _ in 0..1 + next() % 4 {
                    let i = (next() % bytes.len() as u64) as usize;
                    bytes[i] = next() as u8;
                }
                let _ = parse_ply(&bytes);
            }
        }
        // Pure garbage.
        for input in [
            &b"ply"[..],
            b"ply\n",
            b"\xff\xfe\n",
            b"ply\nformat\n",
            b"ply\nformat ascii\nend_header",
            b"ply\nproperty\n",
            b"ply\nelement\n",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list\n",
        ] {
            assert!(parse_ply(input).is_err());
        }
    }

    // --- Round trip -----------------------------------------------------------------------------

    /// A tiny ascii writer (test only) mirroring `write_ply_binary_le`.
    fn write_ascii(mesh: &PlyMesh) -> Vec<u8> {
        let mut s = String::from("ply\nformat ascii 1.0\n");
        let _ = writeln!(s, "element vertex {}", mesh.positions.len());
        s.push_str("property float x\nproperty float y\nproperty float z\n");
        if mesh.normals.is_some() {
            s.push_str("property float nx\nproperty float ny\nproperty float nz\n");
        }
        if mesh.uvs.is_some() {
            s.push_str("property float u\nproperty float v\n");
        }
        let _ = writeln!(s, "element face {}", mesh.triangles.len());
        s.push_str("property list uchar int vertex_indices\nend_header\n");
        for i in 0..mesh.positions.len() {
            let p = mesh.positions[i];
            let _ = write!(s, "{} {} {}", p[0], p[1], p[2]);
            if let Some(n) = &mesh.normals {
                let _ = write!(s, " {} {} {}", n[i][0], n[i][1], n[i][2]);
            }
            if let Some(t) = &mesh.uvs {
                let _ = write!(s, " {} {}", t[i][0], t[i][1]);
            }
            s.push('\n');
        }
        for t in &mesh.triangles {
            let _ = writeln!(s, "3 {} {} {}", t[0], t[1], t[2]);
        }
        s.into_bytes()
    }

    /// A generated grid mesh (awkward float values) with optional normals and uvs.
    fn grid(nx: u32, ny: u32, normals: bool, uvs: bool) -> PlyMesh {
        let mut m = PlyMesh::default();
        for j in 0..=ny {
            for i in 0..=nx {
                let (u, v) = (i as f32 / nx as f32, j as f32 / ny as f32);
                m.positions.push([u * 3.1, (u * 7.0 + v * 3.0).sin() * 0.1, -v * 1e-3 + 1e6 * u]);
            }
        }
        let n = m.positions.len();
        if normals {
            m.normals = Some((0..n).map(|k| [(k as f32).cos(), 0.25, -(k as f32).sin()]).collect());
        }
        if uvs {
            m.uvs = Some((0..n).map(|k| [k as f32 / 3.0, 1.0 / (k as f32 + 1.0)]).collect());
        }
        let w = nx + 1;
        for j in 0..ny {
            for i in 0..nx {
                let a = j * w + i;
                m.triangles.push([a, a + 1, a + w + 1]);
                m.triangles.push([a, a + w + 1, a + w]);
            }
        }
        m
    }

    #[test]
    fn round_trip_binary_and_ascii() {
        for (nx, ny, normals, uvs) in
            [(1, 1, false, false), (7, 3, true, false), (5, 9, false, true), (16, 16, true, true)]
        {
            let mesh = grid(nx, ny, normals, uvs);
            let bin = write_ply_binary_le(&mesh);
            let asc = write_ascii(&mesh);
            let from_bin = parse_ok(&bin);
            let from_asc = parse_ok(&asc);
            assert_eq!(from_bin, mesh);
            assert_eq!(from_asc, mesh);
            assert_eq!(from_bin, from_asc);
        }
    }

    #[test]
    fn large_binary_mesh_parses() {
        // 1M triangles: exercises the fixed-record vertex path and the face loop at scale.
        let mesh = grid(1000, 500, true, true);
        let bytes = write_ply_binary_le(&mesh);
        let t = std::time::Instant::now();
        let parsed = parse_ok(&bytes);
        eprintln!("parsed {} triangles in {:?}", parsed.triangles.len(), t.elapsed());
        assert_eq!(parsed, mesh);
    }

    // --- Real files -----------------------------------------------------------------------------

    fn collect_ply(dir: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else { return };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                collect_ply(&p, out);
            } else if p.extension().is_some_and(|x| x.eq_ignore_ascii_case("ply")) {
                out.push(p);
            }
        }
    }

    #[test]
    fn every_shipped_ply_parses() {
        let root = tessera_testkit::shared_scenes();
        if !tessera_testkit::corpus_has(&root) {
            return;
        }
        let mut files = Vec::new();
        collect_ply(&root, &mut files);
        files.sort();
        assert!(!files.is_empty(), "no .ply files under {}", root.display());
        for path in &files {
            let bytes = std::fs::read(path).unwrap();
            let m = match parse_ply(&bytes) {
                Ok(m) => m,
                Err(e) => panic!("{}: {e} (line {:?})", path.display(), e.line),
            };
            assert!(!m.triangles.is_empty(), "{}: no triangles", path.display());
            if m.skipped_degenerate > 0 {
                eprintln!("{}: {} degenerate faces skipped", path.display(), m.skipped_degenerate);
            }
            if let Some(n) = &m.normals {
                assert_eq!(n.len(), m.positions.len());
            }
            if let Some(t) = &m.uvs {
                assert_eq!(t.len(), m.positions.len());
            }
        }
        eprintln!("parsed {} PLY files", files.len());
    }

    #[test]
    fn shipped_files_contents() {
        let root = tessera_testkit::shared_scenes();
        let read = |rel: &str| {
            tessera_testkit::corpus_has(&root.join(rel)).then(|| std::fs::read(root.join(rel)).unwrap())
        };
        if let Some(bytes) = read("xml/ply/head.ply") {
            let m = parse_ok(&bytes);
            assert_eq!(m.positions.len(), 9223);
            assert_eq!(m.normals.as_ref().map(Vec::len), Some(9223));
            assert_eq!(m.uvs.as_ref().map(Vec::len), Some(9223));
            assert_eq!((m.triangles.len(), m.skipped_degenerate), (17_674, 0));
        }
        if let Some(bytes) = read("xml/ply/cube.ply") {
            let m = parse_ok(&bytes);
            assert_eq!((m.positions.len(), m.triangles.len()), (8, 12));
        }
        if let Some(bytes) = read("xml/ply/tap_water_200.ply") {
            let m = parse_ok(&bytes);
            // 39 660 triangles + 80 quads (each split in two).
            assert_eq!((m.triangles.len(), m.skipped_degenerate), (39_660 + 2 * 80, 0));
        }
    }
}
