//! XML front end: the 2020/21 CENG795 dialect (homeworks 1-4), and the 2019 one.
//!
//! Parsing happens in two steps:
//!
//! 1. `read_tree` turns the text into the element tree (`Node`) with line numbers, using
//!    `quick-xml`. Everything about well-formedness is decided here.
//! 2. `parse_tree` (module [`super::elements`], shared with the JSON front end) walks the tree and
//!    fills [`SceneRecords`], with the 2019 legacy rules for materials (scene-format.md §6.1,
//!    §6.9) and the 2019 `<Texture>` / `<BackgroundTexture>` elements, translated into 2020
//!    texture maps (§11.11), when the file is of that dialect.
//!
//! Nothing is resolved here: ids stay strings, PLY files are not opened. Everything a user can
//! get wrong is a [`SceneError`] naming the file, the line and the element. No input makes this
//! module panic.

use std::borrow::Cow;
use std::path::Path;

use quick_xml::errors::{Error as XmlError, IllFormedError, SyntaxError};
use quick_xml::escape::resolve_predefined_entity;
use quick_xml::events::{BytesStart, Event};
use quick_xml::{Reader, XmlVersion};

use super::elements::parse_tree;
use super::records::SceneRecords;
use super::tree::{Dialect, Node, excerpt};
use crate::error::{Loc, SceneError};

type Result<T> = std::result::Result<T, SceneError>;

/// Parses a scene file of the XML dialect into plain records.
///
/// `source` is only used to name the file in errors and warnings and is stored in
/// [`SceneRecords::source`]; nothing is read from disk. Unknown elements and elements that are
/// not supported yet end up in [`SceneRecords::warnings`], in file order.
///
/// # Errors
///
/// A [`SceneError`] with line and element for malformed XML, a root other than `<Scene>`,
/// malformed numbers, missing required children or attributes, and invalid attribute values.
pub fn parse_xml(text: &str, source: &Path) -> Result<SceneRecords> {
    let root = read_tree(text, source)?;
    if root.name != "Scene" {
        return Err(SceneError::new(
            source,
            root.loc(),
            format!("the root element must be <Scene>, found <{}>; is this a scene file?", root.name),
        ));
    }
    parse_tree(&root, source, Dialect::Xml)
}

// ---------------------------------------------------------------------------------------------
// Step 1: text -> element tree
// ---------------------------------------------------------------------------------------------

/// Deeper nesting than this is certainly not a scene file; refusing it keeps the recursive
/// walks (and dropping the tree) far away from stack overflows on hostile input.
const MAX_DEPTH: usize = 64;

/// Turns byte offsets into 1-based line numbers. Offsets mostly grow, so it counts forwards
/// from the last answer and only restarts from the top when asked about an earlier offset.
struct Lines<'a> {
    bytes: &'a [u8],
    offset: usize,
    line: u32,
}

impl<'a> Lines<'a> {
    fn new(text: &'a str) -> Self {
        Lines { bytes: text.as_bytes(), offset: 0, line: 1 }
    }

    fn line_at(&mut self, offset: u64) -> u32 {
        let offset = usize::try_from(offset).unwrap_or(usize::MAX).min(self.bytes.len());
        if offset < self.offset {
            self.offset = 0;
            self.line = 1;
        }
        let newlines = newline_count(&self.bytes[self.offset..offset]);
        self.line = self.line.saturating_add(u32::try_from(newlines).unwrap_or(u32::MAX));
        self.offset = offset;
        self.line
    }
}

fn newline_count(bytes: &[u8]) -> usize {
    bytes.iter().filter(|&&b| b == b'\n').count()
}

/// Reads the whole document into a tree and returns its root element.
fn read_tree(text: &str, file: &Path) -> Result<Node> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut reader = Reader::from_str(text);
    let mut lines = Lines::new(text);
    let mut stack: Vec<Node> = Vec::new();
    let mut root: Option<Node> = None;
    let file_err = |line: u32, message: String| SceneError::new(file, line_loc(line), message);

    loop {
        // Text is not trimmed, so the next event starts exactly here: for tags, at the `<`.
        let start = reader.buffer_position();
        let event = match reader.read_event() {
            Ok(event) => event,
            Err(e) => {
                let line = lines.line_at(reader.error_position());
                return Err(file_err(line, format!("malformed XML: {e}. Hint: {}", xml_hint(&e))));
            }
        };
        match event {
            Event::Start(tag) => {
                let line = lines.line_at(start);
                let content_line = lines.line_at(reader.buffer_position());
                let node = new_node(&tag, stack.last(), line, content_line, file)?;
                if stack.len() >= MAX_DEPTH {
                    return Err(SceneError::new(
                        file,
                        node.loc(),
                        format!(
                            "elements are nested more than {MAX_DEPTH} levels deep; this is not a scene file"
                        ),
                    ));
                }
                stack.push(node);
            }
            Event::Empty(tag) => {
                let line = lines.line_at(start);
                let node = new_node(&tag, stack.last(), line, line, file)?;
                attach(node, &mut stack, &mut root, file)?;
            }
            Event::End(_) => {
                // quick-xml has already checked that the name matches the open element.
                if let Some(node) = stack.pop() {
                    attach(node, &mut stack, &mut root, file)?;
                }
            }
            Event::Text(t) => push_text(&mut stack, &t, lines.line_at(start), file)?,
            Event::CData(t) => push_text(&mut stack, &t, lines.line_at(start), file)?,
            Event::GeneralRef(r) => {
                let line = lines.line_at(start);
                let resolved = match r.resolve_char_ref() {
                    Ok(Some(c)) => Cow::Owned(c.to_string()),
                    Ok(None) => match resolve_predefined_entity(&r) {
                        Some(s) => Cow::Borrowed(s),
                        None => {
                            return Err(file_err(
                                line,
                                format!("unknown entity &{};. Hint: write a literal & as &amp;", &*r),
                            ));
                        }
                    },
                    Err(e) => return Err(file_err(line, format!("bad character reference &{};: {e}", &*r))),
                };
                push_text(&mut stack, &resolved, line, file)?;
            }
            Event::Comment(c) => {
                if let Some(top) = stack.last_mut() {
                    top.text.push(' ');
                    top.text.extend(std::iter::repeat_n('\n', newline_count(c.as_bytes())));
                }
            }
            Event::Decl(_) | Event::PI(_) | Event::DocType(_) => {}
            Event::Eof => break,
        }
    }

    if let Some(open) = stack.last() {
        return Err(SceneError::new(
            file,
            open.loc(),
            format!("<{}> is never closed: the file ends first (is it truncated?)", open.name),
        ));
    }
    root.ok_or_else(|| {
        SceneError::file(file, "no XML element found: the file is empty or is not an XML scene")
    })
}

fn line_loc(line: u32) -> Loc {
    Loc { line: Some(line), element: None }
}

/// A short, practical hint for each kind of XML error.
fn xml_hint(e: &XmlError) -> &'static str {
    match e {
        XmlError::Syntax(
            SyntaxError::UnclosedTag
            | SyntaxError::UnclosedComment
            | SyntaxError::UnclosedCData
            | SyntaxError::UnclosedPI
            | SyntaxError::UnclosedXmlDecl
            | SyntaxError::UnclosedDoctype
            | SyntaxError::UnclosedSingleQuotedAttributeValue
            | SyntaxError::UnclosedDoubleQuotedAttributeValue,
        ) => {
            "the file ends inside a tag, comment or quoted value; is it truncated, or is a `>`, `-->` or quote missing?"
        }
        XmlError::IllFormed(IllFormedError::MismatchedEndTag { .. }) => {
            "every <Element> must be closed by its own </Element>, innermost first"
        }
        XmlError::IllFormed(IllFormedError::UnmatchedEndTag(_)) => {
            "this closing tag has no opening tag; is an opening tag misspelt or missing?"
        }
        XmlError::IllFormed(IllFormedError::UnclosedReference) | XmlError::Escape(_) => {
            "write a literal & as &amp; and < as &lt;"
        }
        XmlError::InvalidAttr(_) => r#"attributes are written name="value", with the value quoted"#,
        _ => {
            "check that the file is well-formed XML: tags closed and properly nested, attribute values quoted"
        }
    }
}

fn new_node(
    tag: &BytesStart,
    parent: Option<&Node>,
    line: u32,
    content_line: u32,
    file: &Path,
) -> Result<Node> {
    let name = tag.name().as_ref().to_string();
    let mut attrs = Vec::new();
    for attr in tag.attributes() {
        let attr = attr.map_err(|e| {
            SceneError::new(
                file,
                Loc::new(line, name.clone()),
                format!("malformed attribute: {e}. Hint: attributes are written name=\"value\""),
            )
        })?;
        let value = attr.normalized_value(XmlVersion::Implicit1_0).map_err(|e| {
            SceneError::new(file, Loc::new(line, name.clone()), format!("malformed attribute value: {e}"))
        })?;
        attrs.push((attr.key.as_ref().to_string(), value.into_owned()));
    }
    let own = match attrs.iter().find(|(k, _)| k == "id") {
        Some((_, id)) => format!(r#"{name} id="{id}""#),
        None => name.clone(),
    };
    let depth = parent.map_or(1, |p| p.depth + 1);
    // Records (Camera, Material, Sphere, ...) sit at depth 3; inside them, name the path from
    // the record so that `<Position>` says which camera it belongs to.
    let label = match parent {
        Some(p) if p.depth >= 3 => format!("{}> / <{own}", p.label),
        _ => own,
    };
    Ok(Node { name, label, depth, line, content_line, attrs, text: String::new(), children: Vec::new() })
}

fn attach(node: Node, stack: &mut [Node], root: &mut Option<Node>, file: &Path) -> Result<()> {
    if let Some(parent) = stack.last_mut() {
        parent.children.push(node);
    } else if root.is_none() {
        *root = Some(node);
    } else {
        return Err(SceneError::new(
            file,
            node.loc(),
            format!("a second top-level element <{}>; a scene file has exactly one <Scene>", node.name),
        ));
    }
    Ok(())
}

fn push_text(stack: &mut [Node], text: &str, line: u32, file: &Path) -> Result<()> {
    match stack.last_mut() {
        Some(top) => top.text.push_str(text),
        None if text.trim().is_empty() => {}
        None => {
            return Err(SceneError::new(
                file,
                line_loc(line),
                format!("text \"{}\" outside of any element; is this an XML scene file?", excerpt(text)),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
#[path = "xml_tests.rs"]
mod tests;
