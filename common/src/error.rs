//! Errors and warnings about scene input.
//!
//! Every problem a user can cause names *where* it is (file, line, element) and *what* is wrong,
//! so that a student can fix the scene without reading our source. The tracer never panics on
//! input: every parse or build step returns [`SceneError`].

use std::fmt;
use std::path::{Path, PathBuf};

/// Where in a scene (or asset) file something is.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Loc {
    /// 1-based line number, when known.
    pub line: Option<u32>,
    /// The element (tag) name, with its id when it has one, e.g. `Mesh id="3"`.
    pub element: Option<String>,
}

impl Loc {
    pub fn new(line: u32, element: impl Into<String>) -> Self {
        Loc { line: Some(line), element: Some(element.into()) }
    }

    /// A location without a known line (e.g. something built after parsing).
    pub fn element(element: impl Into<String>) -> Self {
        Loc { line: None, element: Some(element.into()) }
    }
}

/// A scene (or scene asset) that cannot be used, and why.
///
/// Displayed as `file:line: <Element>: message`, the form editors and terminals make clickable.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub struct SceneError {
    pub file: PathBuf,
    pub loc: Loc,
    pub message: String,
}

impl SceneError {
    pub fn new(file: impl AsRef<Path>, loc: Loc, message: impl Into<String>) -> Self {
        SceneError { file: file.as_ref().to_path_buf(), loc, message: message.into() }
    }

    /// An error about a file as a whole (unreadable, wrong format).
    pub fn file(file: impl AsRef<Path>, message: impl Into<String>) -> Self {
        Self::new(file, Loc::default(), message)
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(line) = self.loc.line {
            write!(f, ":{line}")?;
        }
        write!(f, ": ")?;
        if let Some(el) = &self.loc.element {
            write!(f, "<{el}>: ")?;
        }
        write!(f, "{}", self.message)
    }
}

/// Something in a scene that we render anyway but the user should know about
/// (an element we do not know, a value we clamp, a feature not supported yet).
#[derive(Clone, Debug, PartialEq)]
pub struct Warning {
    pub file: PathBuf,
    pub loc: Loc,
    pub message: String,
    /// An element of the format that Tessera does not implement and whose absence changes the
    /// picture (a mesh left out, a texture repeated instead of clamped). The loaders refuse a
    /// scene with any of these unless unsupported elements are allowed
    /// (`scene::load::LoadOptions`); then it is a warning like the others.
    pub unsupported: bool,
}

impl Warning {
    /// A warning about something that does not change the picture (or that the format itself
    /// says to ignore).
    pub fn new(file: impl AsRef<Path>, loc: Loc, message: impl Into<String>) -> Self {
        Warning { file: file.as_ref().to_path_buf(), loc, message: message.into(), unsupported: false }
    }

    /// An element Tessera does not implement whose absence changes the picture: `message` says
    /// what is not supported and what the picture would lack.
    pub fn unsupported(file: impl AsRef<Path>, loc: Loc, message: impl Into<String>) -> Self {
        Warning { unsupported: true, ..Warning::new(file, loc, message) }
    }

    /// This unsupported element as the error it is when unsupported elements are not allowed:
    /// same file, line and element, and what to do about it.
    pub fn to_error(&self) -> SceneError {
        SceneError::new(&self.file, self.loc.clone(), format!("{}; {UNSUPPORTED_HINT}", self.message))
    }
}

/// What an unsupported element's error tells the user to do.
pub const UNSUPPORTED_HINT: &str = "remove it, or allow unsupported elements (tessera-worker render --allow-unsupported, a farm \
     upload's allow_unsupported=true) to render without it";

/// The unsupported elements among `warnings` (see [`Warning::unsupported`]) as errors, in order.
pub fn unsupported_errors(warnings: &[Warning]) -> Vec<SceneError> {
    warnings.iter().filter(|w| w.unsupported).map(Warning::to_error).collect()
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Same shape as SceneError.
        let as_err =
            SceneError { file: self.file.clone(), loc: self.loc.clone(), message: self.message.clone() };
        write!(f, "warning: {as_err}")
    }
}
