//! The layering check: no module of `common` imports one of its own or of a higher layer, and
//! the server's modules import each other without circles; and the size check: no file of
//! `common/src` holds more than [`MAX_FILE_LINES`] lines of non-test code.
//!
//! The layers are docs/ARCHITECTURE.md's, "Layers"; keeping to them means no import circles.
//!
//! Reads every `.rs` file under `common/src`, finds the crate-internal modules each one names in
//! its code (`use crate::…`, `use super::…`, `use self::…`, a child module's name, groups
//! `{a, b::c}`, and the same paths written inline in expressions, types and patterns), and checks
//! them against [`LAYERS`]. Comments and string literals are not code; `#[cfg(test)]` items (and
//! the files they include with `#[path]`) are left out: unit tests are clients of the whole crate,
//! like the tests under `tests/`. The crate root (`lib.rs`) declares the modules and may re-export
//! anything.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// The layers of `common`, bottom up: `(name, modules)`. A module may import only modules of
/// strictly lower layers (and itself). Every module of the crate is listed exactly once; the
/// same table is in docs/ARCHITECTURE.md (checked below).
const LAYERS: &[(&str, &[&str])] = &[
    (
        "foundations",
        &[
            "protocol",
            "error",
            "math",
            "sampler",
            "passes",
            "assets",
            "atomic_write",
            "ply",
            "tonemap::params",
            "texture::image",
            "texture",
            "geometry::bvh8::kernels",
        ],
    ),
    ("BVH walks", &["geometry::bvh8::wide"]),
    ("BVH", &["geometry::bvh8"]),
    ("pixels and records", &["image", "scene::records", "texture::mip", "lights::object"]),
    ("element tree", &["scene::tree"]),
    (
        "element rules",
        &[
            "scene::elements::camera",
            "scene::elements::tonemap",
            "scene::elements::lights",
            "scene::elements::materials",
            "scene::elements::textures",
            "scene::elements::geometry",
        ],
    ),
    ("element walk", &["scene::elements"]),
    (
        "front ends and scene parts",
        &[
            "scene::xml",
            "scene::json",
            "scene::legacy_data",
            "scene::assets_named",
            "camera",
            "material",
            "lights",
            "texture::maps",
            "geometry::mesh",
            "geometry::rays",
            "geometry::shapes",
            "geometry::instance",
            "geometry::horizon",
            "tonemap",
            "hdr_io",
        ],
    ),
    ("world tree", &["geometry::world"]),
    ("geometry", &["geometry", "lights::choice"]),
    ("scene", &["scene", "scene::cache"]),
    ("build context", &["scene::build::context"]),
    ("build steps", &["scene::build::textures", "scene::build::meshes"]),
    ("placed objects", &["scene::build::objects"]),
    ("build", &["scene::build"]),
    ("load", &["scene::load"]),
    ("bundle", &["bundle"]),
    ("direct light", &["integrator::direct"]),
    ("bounces", &["integrator::bounces"]),
    ("path groups", &["integrator::pool"]),
    ("path lanes", &["integrator::paths"]),
    ("integrator", &["integrator"]),
    ("render", &["render"]),
    ("output", &["output"]),
];

/// The most lines of non-test code (a file's lines outside its `#[cfg(test)]` items) a file of
/// `common/src` may hold. A file past it holds more than one concern: split it by concern (the
/// way `scene/elements/` holds the element rules by family), don't squeeze it.
const MAX_FILE_LINES: usize = 1200;

/// Files allowed past [`MAX_FILE_LINES`] for now, each with its own ceiling: a debt written down,
/// not a second limit. None today.
const OVER_THE_LIMIT: &[(&str, usize)] = &[];

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, modules)| modules.contains(&module))
}

fn describe(module: &str) -> String {
    match layer_of(module) {
        Some(l) => format!("{module} (layer {l}, {})", LAYERS[l].0),
        None => format!("{module} (in no layer)"),
    }
}

#[test]
fn no_module_imports_upward() {
    let crate_ = Crate::read(&src_dir());
    let mut upward = Vec::new();
    for import in crate_.imports() {
        let (Some(from), Some(to)) = (layer_of(&import.from), layer_of(&import.to)) else {
            panic!("{import}: a module missing from LAYERS (see the_table_lists_every_module_once)");
        };
        if import.from != import.to && to >= from {
            upward.push(format!(
                "common/src/{}:{}: {} imports {}: `{}`",
                import.file,
                import.line,
                describe(&import.from),
                describe(&import.to),
                import.path
            ));
        }
    }
    assert!(
        upward.is_empty(),
        "imports that do not go to a lower layer (docs/ARCHITECTURE.md, \"Layers\", says what may \
         import what, and why):\n{}",
        upward.join("\n")
    );
}

#[test]
fn the_table_lists_every_module_once() {
    let crate_ = Crate::read(&src_dir());
    let files: BTreeSet<&str> = crate_.modules.keys().map(String::as_str).filter(|m| !m.is_empty()).collect();
    let mut listed = BTreeSet::new();
    for (_, modules) in LAYERS {
        for m in *modules {
            assert!(listed.insert(*m), "{m} is listed twice in LAYERS");
        }
    }
    let missing: Vec<_> = files.difference(&listed).collect();
    let stale: Vec<_> = listed.difference(&files).collect();
    assert!(
        missing.is_empty(),
        "modules in no layer (add them to LAYERS and docs/ARCHITECTURE.md): {missing:?}"
    );
    assert!(stale.is_empty(), "LAYERS lists modules that have no file: {stale:?}");
}

#[test]
fn no_file_is_over_the_size_limit() {
    let crate_ = Crate::read(&src_dir());
    let sizes = crate_.non_test_lines();
    assert!(sizes.len() > 40, "the scan found too few files: {sizes:?}");
    let over: Vec<String> = sizes
        .iter()
        .filter(|(file, n)| {
            let ceiling =
                OVER_THE_LIMIT.iter().find(|(f, _)| *f == file.as_str()).map_or(MAX_FILE_LINES, |(_, c)| *c);
            *n > ceiling
        })
        .map(|(file, n)| format!("common/src/{file}: {n} lines of non-test code"))
        .collect();
    assert!(
        over.is_empty(),
        "files over {MAX_FILE_LINES} lines of non-test code (split them by concern; \
         docs/ARCHITECTURE.md's code map names what each file owns):\n{}",
        over.join("\n")
    );
}

/// The counter itself, on made-up files: `#[cfg(test)]` items (inline or a whole file included
/// with `#[path]`) are not counted, everything else is, blank lines and comments included.
#[test]
fn non_test_lines_leave_out_test_items_only() {
    let files = [
        ("lib.rs", "pub mod a;\n#[cfg(test)]\n#[path = \"a_tests.rs\"]\nmod tests;\n"),
        (
            "a.rs",
            "//! A.\n\npub fn f() {}\n#[cfg(test)]\nfn helper() {\n    f();\n}\n\n/// Not a test.\n#[cfg(not(test))]\nfn g() {}\n#[cfg(test)]\nmod tests {\n    #[test]\n    fn t() {}\n}\n",
        ),
        ("a_tests.rs", "#[test]\nfn long() {}\n"),
    ];
    let crate_ = Crate::from_files(files.iter().map(|(p, s)| (PathBuf::from(p), s.to_string())).collect());
    let sizes: Vec<(String, usize)> = crate_.non_test_lines();
    assert_eq!(sizes, [("a.rs".to_string(), 7), ("lib.rs".to_string(), 1)]);
}

/// The first circle of `edges` (module -> the modules it imports) found by a depth-first walk,
/// as the modules around it (the first one again at the end); `None` when there is none.
fn circle(edges: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn walk(
        m: &str,
        edges: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(at) = path.iter().position(|p| p == m) {
            let mut c = path[at..].to_vec();
            c.push(m.to_string());
            return Some(c);
        }
        if done.contains(m) {
            return None;
        }
        path.push(m.to_string());
        for next in edges.get(m).into_iter().flatten() {
            if let Some(c) = walk(next, edges, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(m.to_string());
        None
    }
    let mut done = BTreeSet::new();
    edges.keys().find_map(|m| walk(m, edges, &mut Vec::new(), &mut done))
}

/// The server's modules import each other one way (docs/ARCHITECTURE.md, `server/`): no
/// circle among its top-level modules, a folder (`api/`) counting as one. The crate root
/// (`lib.rs`, which wires them and holds the configuration) is left out.
#[test]
fn the_server_has_no_import_circles() {
    let server = Crate::read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../server/src"));
    let top = |m: &str| m.split("::").next().unwrap_or_default().to_string();
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for import in server.imports() {
        let (from, to) = (top(&import.from), top(&import.to));
        if !from.is_empty() && !to.is_empty() && from != to {
            edges.entry(from).or_default().insert(to);
        }
    }
    assert!(edges.contains_key("api") && edges.contains_key("merge"), "the scan found too little: {edges:?}");
    if let Some(c) = circle(&edges) {
        panic!("server modules import each other in a circle: {}", c.join(" -> "));
    }
}

#[test]
fn circles_are_found() {
    let graph = |pairs: &[(&str, &str)]| {
        let mut e: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for (a, b) in pairs {
            e.entry(a.to_string()).or_default().insert(b.to_string());
        }
        e
    };
    assert_eq!(circle(&graph(&[("a", "b"), ("b", "c"), ("a", "c")])), None);
    let found = circle(&graph(&[("a", "b"), ("b", "c"), ("c", "d"), ("d", "b")])).unwrap();
    assert_eq!(found, ["b", "c", "d", "b"]);
}

/// docs/ARCHITECTURE.md's table: rows `| <n> | <name> | `module`, `module` | … |` under the
/// heading `### Layers`.
#[test]
fn architecture_md_has_the_same_table() {
    let md_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/ARCHITECTURE.md");
    let md = fs::read_to_string(&md_path).unwrap_or_else(|e| panic!("{}: {e}", md_path.display()));
    let section = md.split("\n### Layers\n").nth(1).expect("docs/ARCHITECTURE.md has a `### Layers` section");
    let mut rows: Vec<(String, Vec<String>)> = Vec::new();
    for line in section.lines().take_while(|l| !l.starts_with('#')) {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() < 4 || cells[1].parse::<usize>().is_err() {
            continue;
        }
        let modules = cells[3].split('`').skip(1).step_by(2).map(str::to_string).collect();
        rows.push((cells[2].to_string(), modules));
    }
    let expected: Vec<(String, Vec<String>)> = LAYERS
        .iter()
        .map(|(name, modules)| (name.to_string(), modules.iter().map(|m| m.to_string()).collect()))
        .collect();
    assert_eq!(
        rows, expected,
        "docs/ARCHITECTURE.md's layer table differs from LAYERS in common/tests/layers.rs"
    );
}

/// The scanner itself, on made-up files: every way of naming a module is seen, and nothing that
/// only looks like one.
#[test]
fn the_scanner_sees_every_kind_of_import() {
    let files = [
        ("lib.rs", "pub mod a;\npub mod low;\npub mod high;\npub use low::Thing;"),
        ("low.rs", "pub struct Thing;"),
        ("high.rs", "pub struct Top;"),
        ("a/mod.rs", "pub mod b;\nmod c;\n#[cfg(test)]\n#[path = \"a_tests.rs\"]\nmod tests;"),
        (
            "a/b.rs",
            r##"
use crate::low::Thing;
use super::{c::{self, Inner}, b as _};
use crate::{high, low};
// crate::high::Top in a comment
/* and crate::high::Top /* nested */ crate::high::Top */
fn f() -> usize {
    let s = "crate::high::Top in a string";
    let r = r#"crate::high::Top"#;
    let c = '"';
    let l: &'static str = s;
    let t = crate::high::Top;
    let u = super::super::high::Top;
    let v = self::g();
    let w = crate::Thing;
    0
}
fn g() {}
#[cfg(test)]
mod tests {
    use crate::high::Top;
}
"##,
        ),
        ("a/c.rs", "pub struct Inner;\nfn h() { let _ = super::b::g; }"),
        ("a/a_tests.rs", "use crate::high::Top;"),
    ];
    let crate_ = Crate::from_files(files.iter().map(|(p, s)| (PathBuf::from(p), s.to_string())).collect());
    let got: Vec<String> =
        crate_.imports().iter().map(|i| format!("{}:{} {} -> {}", i.file, i.line, i.from, i.to)).collect();
    assert_eq!(
        got,
        [
            "a/b.rs:2 a::b -> low",
            "a/b.rs:3 a::b -> a::c",
            "a/b.rs:3 a::b -> a::c",
            "a/b.rs:3 a::b -> a::b",
            "a/b.rs:4 a::b -> high",
            "a/b.rs:4 a::b -> low",
            "a/b.rs:12 a::b -> high",
            "a/b.rs:13 a::b -> high",
            "a/b.rs:14 a::b -> a::b",
            "a/b.rs:15 a::b -> low",
            "a/c.rs:2 a::c -> a::b",
        ]
    );
}

// ---------------------------------------------------------------------------------------------
// The scanner
// ---------------------------------------------------------------------------------------------

/// One crate-internal module named in a module's code.
struct Import {
    file: String,
    line: usize,
    from: String,
    to: String,
    path: String,
}

impl std::fmt::Display for Import {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}: {} -> {} (`{}`)", self.file, self.line, self.from, self.to, self.path)
    }
}

/// The crate's files as modules: module path (`scene::build`, `""` for the root) → (file,
/// tokens). Test-only files are left out.
struct Crate {
    modules: BTreeMap<String, (String, Vec<Token>)>,
    /// Each module's file's length in lines.
    lines: BTreeMap<String, usize>,
    /// What the root re-exports: name → module (`Loc` → `error`).
    root_exports: BTreeMap<String, String>,
}

impl Crate {
    fn read(src: &Path) -> Crate {
        let mut files = Vec::new();
        let mut dirs = vec![src.to_path_buf()];
        while let Some(dir) = dirs.pop() {
            for entry in fs::read_dir(&dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    dirs.push(path);
                } else if path.extension().is_some_and(|e| e == "rs") {
                    let text = fs::read_to_string(&path).unwrap();
                    files.push((path.strip_prefix(src).unwrap().to_path_buf(), text));
                }
            }
        }
        Crate::from_files(files)
    }

    /// `files`: paths relative to `src/`, with their text.
    fn from_files(files: Vec<(PathBuf, String)>) -> Crate {
        let lengths: BTreeMap<PathBuf, usize> =
            files.iter().map(|(p, text)| (p.clone(), text.lines().count())).collect();
        let mut tokenised: Vec<(PathBuf, Vec<Token>)> =
            files.into_iter().map(|(p, text)| (p, tokenise(&text))).collect();
        tokenised.sort_by(|a, b| a.0.cmp(&b.0));
        // Files that `#[cfg(test)] mod x;` declarations include are test code.
        let mut test_files = BTreeSet::new();
        for (path, tokens) in &tokenised {
            let dir = module_dir(path);
            for decl in mod_declarations(tokens) {
                if decl.test {
                    test_files.insert(match decl.path {
                        Some(p) => path.parent().unwrap().join(p),
                        None => dir.join(format!("{}.rs", decl.name)),
                    });
                }
            }
        }
        let mut modules = BTreeMap::new();
        let mut lines = BTreeMap::new();
        for (path, tokens) in tokenised {
            if !test_files.contains(&path) {
                lines.insert(module_path(&path), lengths[&path]);
                modules.insert(module_path(&path), (path.display().to_string(), tokens));
            }
        }
        let mut root_exports = BTreeMap::new();
        if let Some((_, tokens)) = modules.get("") {
            for (i, t) in tokens.iter().enumerate() {
                if t.is("use") && i > 0 && tokens[i - 1].is("pub") {
                    for path in use_tree(tokens, i + 1, Vec::new()).0 {
                        if let (Some(module), Some(name)) = (path.first(), path.last()) {
                            root_exports.insert(name.clone(), module.clone());
                        }
                    }
                }
            }
        }
        Crate { modules, lines, root_exports }
    }

    /// Every non-test file (by path under `src/`) with its count of lines outside `#[cfg(test)]`
    /// items: its length less the lines from each such item's attribute to its end.
    fn non_test_lines(&self) -> Vec<(String, usize)> {
        let mut out: Vec<(String, usize)> = self
            .modules
            .iter()
            .map(|(module, (file, tokens))| {
                let skip = test_items(tokens);
                // A test item's lines run from its first token's to its last token's.
                let mut test_lines = BTreeSet::new();
                let mut i = 0;
                while i < tokens.len() {
                    let start = i;
                    while i < tokens.len() && skip[i] {
                        i += 1;
                    }
                    if i > start {
                        test_lines.extend(tokens[start].line..=tokens[i - 1].line);
                    } else {
                        i += 1;
                    }
                }
                (file.clone(), self.lines[module] - test_lines.len())
            })
            .collect();
        out.sort();
        out
    }

    /// Every crate-internal module named in the non-test code of every module but the root, in
    /// file and line order.
    fn imports(&self) -> Vec<Import> {
        let mut out = Vec::new();
        for (module, (file, tokens)) in &self.modules {
            if module.is_empty() {
                continue;
            }
            let here: Vec<String> = module.split("::").map(str::to_string).collect();
            let children: BTreeSet<String> =
                mod_declarations(tokens).into_iter().filter(|d| !d.test).map(|d| d.name).collect();
            let skip = test_items(tokens);
            let mut i = 0;
            while i < tokens.len() {
                if skip[i] {
                    i += 1;
                    continue;
                }
                let t = &tokens[i];
                let starts_path =
                    matches!(t.text.as_str(), "crate" | "super" | "self") || children.contains(&t.text);
                let after_sep = i > 0 && tokens[i - 1].is("::");
                let visibility = i > 0 && tokens[i - 1].is("in");
                let followed = tokens.get(i + 1).is_some_and(|n| n.is("::"));
                let in_use = i > 0 && tokens[i - 1].is("use");
                if t.ident && starts_path && !after_sep && !visibility && (followed || in_use) {
                    let (paths, next) = use_tree(tokens, i, Vec::new());
                    for path in paths {
                        if let Some(to) = self.resolve(&here, &path) {
                            out.push(Import {
                                file: file.clone(),
                                line: t.line,
                                from: module.clone(),
                                to,
                                path: path.join("::"),
                            });
                        } else {
                            panic!(
                                "{file}:{}: cannot place `{}` in a module of the crate",
                                t.line,
                                path.join("::")
                            );
                        }
                    }
                    i = next.max(i + 1);
                } else {
                    i += 1;
                }
            }
        }
        out
    }

    /// The module of the crate that `path`, written in module `here`, names: its longest prefix
    /// that is a module, or for an item of the root, the module the root re-exports it from.
    fn resolve(&self, here: &[String], path: &[String]) -> Option<String> {
        let mut abs: Vec<String> = match path[0].as_str() {
            "crate" => Vec::new(),
            "self" => here.to_vec(),
            "super" => {
                let n = path.iter().take_while(|s| *s == "super").count();
                here[..here.len().checked_sub(n)?].to_vec()
            }
            _ => here.to_vec(), // a child module's name
        };
        let rest = path.iter().skip_while(|s| matches!(s.as_str(), "crate" | "self" | "super"));
        abs.extend(rest.filter(|s| *s != "self").cloned());
        for len in (1..=abs.len()).rev() {
            let candidate = abs[..len].join("::");
            if self.modules.contains_key(&candidate) {
                return Some(candidate);
            }
        }
        // An item of the root itself (the server's `crate::Config`) is the root's.
        abs.first()
            .and_then(|name| self.root_exports.get(name))
            .cloned()
            .or_else(|| (path[0] == "crate").then(String::new))
    }
}

/// `scene/build.rs` → `scene::build`, `scene/mod.rs` → `scene`, `lib.rs` → `""`.
fn module_path(file: &Path) -> String {
    let mut parts: Vec<String> = file.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" {
        parts.push(stem.to_string());
    }
    parts.join("::")
}

/// Where the files of a module's children live: `scene/mod.rs` → `scene/`, `scene/xml.rs` →
/// `scene/xml/`.
fn module_dir(file: &Path) -> PathBuf {
    let parent = file.parent().unwrap().to_path_buf();
    match file.file_stem().unwrap().to_str().unwrap() {
        "mod" | "lib" => parent,
        stem => parent.join(stem),
    }
}

/// A path tree starting at `tokens[i]` (`a::b::{c, d::e as f, self, *}`), as full paths with
/// `prefix` in front; and the index after it.
fn use_tree(tokens: &[Token], mut i: usize, mut prefix: Vec<String>) -> (Vec<Vec<String>>, usize) {
    loop {
        let Some(t) = tokens.get(i) else { return (vec![prefix], i) };
        if t.is("{") {
            let mut out = Vec::new();
            i += 1;
            while i < tokens.len() && !tokens[i].is("}") {
                let (paths, next) = use_tree(tokens, i, prefix.clone());
                out.extend(paths);
                i = next;
                if tokens.get(i).is_some_and(|t| t.is(",")) {
                    i += 1;
                }
            }
            return (out, i + 1);
        }
        if t.is("*") {
            return (vec![prefix], i + 1);
        }
        if !t.ident {
            return (vec![prefix], i);
        }
        prefix.push(t.text.clone());
        i += 1;
        if tokens.get(i).is_some_and(|t| t.is("::")) {
            i += 1;
            continue;
        }
        if tokens.get(i).is_some_and(|t| t.is("as")) {
            i += 2;
        }
        return (vec![prefix], i);
    }
}

struct ModDecl {
    name: String,
    test: bool,
    /// `#[path = "…"]`, relative to the declaring file's directory.
    path: Option<String>,
}

/// The `mod name;` declarations of a file, with their `cfg(test)` and `path` attributes.
/// Inline modules other than test modules are refused: this check does not follow them.
fn mod_declarations(tokens: &[Token]) -> Vec<ModDecl> {
    let in_test = test_items(tokens);
    let mut out = Vec::new();
    for (i, t) in tokens.iter().enumerate() {
        if !t.is("mod") || !tokens.get(i + 1).is_some_and(|n| n.ident) {
            continue;
        }
        let attrs = attributes_before(tokens, i);
        let test = attrs.iter().any(|a| is_cfg_test(a));
        if in_test[i] && !test {
            continue; // a module inside a test module: test code too
        }
        let path = attrs.iter().find_map(|a| match a.as_slice() {
            [p, eq, lit] if p.is("path") && eq.is("=") => Some(lit.text.trim_matches('"').to_string()),
            _ => None,
        });
        match tokens.get(i + 2) {
            Some(n) if n.is(";") => out.push(ModDecl { name: tokens[i + 1].text.clone(), test, path }),
            Some(n) if n.is("{") && !test => {
                panic!(
                    "line {}: an inline `mod {}` {{ … }}: give it a file of its own",
                    t.line,
                    tokens[i + 1].text
                )
            }
            _ => {}
        }
    }
    out
}

/// The attributes (`#[…]`, inner tokens) right before the item whose keyword is at `i`,
/// skipping a visibility (`pub`, `pub(crate)`).
fn attributes_before(tokens: &[Token], mut i: usize) -> Vec<Vec<Token>> {
    while i > 0 && (tokens[i - 1].is("pub") || (tokens[i - 1].is(")") && visibility_group(tokens, i - 1))) {
        i = if tokens[i - 1].is(")") { open_of(tokens, i - 1) } else { i - 1 };
    }
    let mut attrs = Vec::new();
    while i >= 2 && tokens[i - 1].is("]") {
        let open = open_of(tokens, i - 1);
        if open == 0 || !tokens[open - 1].is("#") {
            break;
        }
        attrs.push(tokens[open + 1..i - 1].to_vec());
        i = open - 1;
    }
    attrs
}

fn visibility_group(tokens: &[Token], close: usize) -> bool {
    let open = open_of(tokens, close);
    open > 0 && tokens[open - 1].is("pub")
}

/// The index of the bracket that the bracket at `close` closes.
fn open_of(tokens: &[Token], close: usize) -> usize {
    let mut depth = 0;
    for j in (0..=close).rev() {
        match tokens[j].text.as_str() {
            ")" | "]" | "}" => depth += 1,
            "(" | "[" | "{" => {
                depth -= 1;
                if depth == 0 {
                    return j;
                }
            }
            _ => {}
        }
    }
    0
}

/// `cfg(test)` and `cfg(all(test, …))`, not `cfg(not(test))`.
fn is_cfg_test(attr: &[Token]) -> bool {
    attr.first().is_some_and(|t| t.is("cfg"))
        && attr.iter().any(|t| t.is("test"))
        && !attr.iter().any(|t| t.is("not"))
}

/// For each token: whether it belongs to a `#[cfg(test)]` item (the attribute included).
fn test_items(tokens: &[Token]) -> Vec<bool> {
    let mut skip = vec![false; tokens.len()];
    let mut i = 0;
    while i + 1 < tokens.len() {
        if !(tokens[i].is("#") && tokens[i + 1].is("[")) {
            i += 1;
            continue;
        }
        let close = close_of(tokens, i + 1);
        if !is_cfg_test(&tokens[i + 2..close]) {
            i = close + 1;
            continue;
        }
        // The item: up to its `;` or the end of its first `{ … }` at depth 0.
        let mut j = close + 1;
        let end = loop {
            match tokens.get(j).map(|t| t.text.as_str()) {
                None => break tokens.len() - 1,
                Some(";") => break j,
                Some("{") => break close_of(tokens, j),
                Some("(" | "[") => j = close_of(tokens, j) + 1,
                _ => j += 1,
            }
        };
        skip[i..=end].iter_mut().for_each(|s| *s = true);
        i = end + 1;
    }
    skip
}

/// The index of the bracket that closes the one at `open`.
fn close_of(tokens: &[Token], open: usize) -> usize {
    let mut depth = 0;
    for (j, t) in tokens.iter().enumerate().skip(open) {
        match t.text.as_str() {
            "(" | "[" | "{" => depth += 1,
            ")" | "]" | "}" => {
                depth -= 1;
                if depth == 0 {
                    return j;
                }
            }
            _ => {}
        }
    }
    tokens.len() - 1
}

// ---------------------------------------------------------------------------------------------
// Tokens: enough of Rust's lexical grammar to tell code from comments and literals
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Debug)]
struct Token {
    text: String,
    /// An identifier or keyword (`crate`, `super`, `use`, names).
    ident: bool,
    line: usize,
}

impl Token {
    fn is(&self, s: &str) -> bool {
        self.text == s
    }
}

/// Identifiers, `::`, string literals (as one token) and single punctuation characters; no
/// comments, no whitespace, no character literals or lifetimes.
fn tokenise(text: &str) -> Vec<Token> {
    let c: Vec<char> = text.chars().collect();
    let mut out = Vec::new();
    let (mut i, mut line) = (0, 1);
    let is_ident_start = |ch: char| ch.is_alphabetic() || ch == '_';
    let is_ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    let count_lines = |s: &[char]| s.iter().filter(|&&ch| ch == '\n').count();
    while i < c.len() {
        let ch = c[i];
        let start = i;
        if ch == '\n' {
            line += 1;
            i += 1;
        } else if ch.is_whitespace() {
            i += 1;
        } else if c[i..].starts_with(&['/', '/']) {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if c[i..].starts_with(&['/', '*']) {
            let mut depth = 0;
            while i < c.len() {
                if c[i..].starts_with(&['/', '*']) {
                    depth += 1;
                    i += 2;
                } else if c[i..].starts_with(&['*', '/']) {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
            line += count_lines(&c[start..i]);
        } else if let Some(end) = raw_string_end(&c, i) {
            out.push(Token { text: c[i..end].iter().collect(), ident: false, line });
            line += count_lines(&c[i..end]);
            i = end;
        } else if ch == '"' || ((ch == 'b' || ch == 'c') && c.get(i + 1) == Some(&'"')) {
            i += if ch == '"' { 1 } else { 2 };
            while i < c.len() && c[i] != '"' {
                i += if c[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
            out.push(Token { text: c[start..i.min(c.len())].iter().collect(), ident: false, line });
            line += count_lines(&c[start..i.min(c.len())]);
        } else if ch == '\'' || (ch == 'b' && c.get(i + 1) == Some(&'\'')) {
            // A character literal ('x', '\n', '\u{1F600}', b'x') or a lifetime ('a, 'static).
            let q = if ch == 'b' { i + 1 } else { i };
            if c.get(q + 1) == Some(&'\\') {
                i = q + 3; // past the backslash and the escaped character (which may be a quote)
                while i < c.len() && c[i] != '\'' {
                    i += 1;
                }
                i += 1;
            } else if c.get(q + 2) == Some(&'\'') {
                i = q + 3;
            } else {
                i = q + 1;
                while i < c.len() && is_ident(c[i]) {
                    i += 1;
                }
            }
        } else if is_ident_start(ch) {
            if ch == 'r' && c.get(i + 1) == Some(&'#') && c.get(i + 2).is_some_and(|&n| is_ident_start(n)) {
                i += 2; // a raw identifier
            }
            let begin = i;
            while i < c.len() && is_ident(c[i]) {
                i += 1;
            }
            out.push(Token { text: c[begin..i].iter().collect(), ident: true, line });
        } else if ch.is_ascii_digit() {
            while i < c.len()
                && (is_ident(c[i]) || c[i] == '.' && c.get(i + 1).is_some_and(char::is_ascii_digit))
            {
                i += 1;
            }
        } else if c[i..].starts_with(&[':', ':']) {
            out.push(Token { text: "::".into(), ident: false, line });
            i += 2;
        } else {
            out.push(Token { text: ch.to_string(), ident: false, line });
            i += 1;
        }
    }
    out
}

/// The end of a raw string literal (`r"…"`, `r#"…"#`, `br##"…"##`, `cr"…"`) starting at `i`.
fn raw_string_end(c: &[char], i: usize) -> Option<usize> {
    let mut j = i;
    if matches!(c.get(j), Some('b' | 'c')) {
        j += 1;
    }
    if c.get(j) != Some(&'r') {
        return None;
    }
    j += 1;
    let hashes = c[j..].iter().take_while(|&&ch| ch == '#').count();
    j += hashes;
    if c.get(j) != Some(&'"') {
        return None;
    }
    j += 1;
    while j < c.len() {
        if c[j] == '"' && c[j + 1..].iter().take(hashes).filter(|&&ch| ch == '#').count() == hashes {
            return Some(j + 1 + hashes);
        }
        j += 1;
    }
    Some(c.len())
}
