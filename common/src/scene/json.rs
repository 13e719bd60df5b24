//! JSON front end: the 2025 CENG795 dialect (scene-format.md §14) into the shared element tree.
//!
//! The dialect is a mechanical XML→JSON encoding of the same element tree.
//!
//! The JSON text is turned into the very `Node` tree the XML front end builds, and then walked
//! by the same `parse_tree` (module [`super::elements`]), so every element rule, default, warning
//! and error is shared and a JSON scene gives exactly the records of its XML twin. The mapping (§14.1):
//!
//! - the root is an object with the single key `"Scene"`;
//! - a key is an element; a string (or, leniently, a number or boolean) is its text;
//! - in an object, `_`-prefixed keys are attributes (`"_id"` → `id`) and `"_data"` is the text
//!   beside them; every other key is a child element;
//! - an array is the element repeated (`"Mesh": [{…}, {…}]`), one occurrence is a plain value;
//! - `null` is an absent element.
//!
//! Parsing happens in two passes. `serde_json` first checks the whole text (so a syntax error
//! reports serde_json's line and column, and nesting deeper than its recursion limit is refused
//! before anything recursive of ours runs); then a small scanner of our own walks the text,
//! which keeps the key order (element order inside arrays matters; order between kinds does not,
//! §14.1.9) and the line of every key, for messages. Element labels are JSON paths such as
//! `Scene.Objects.Mesh[3].Faces` (array indices 0-based), so an error reads
//! `scene.json:42: <Scene.Objects.Mesh[3]>: …`. No input makes this module panic.
//!
//! One default differs from XML files:
//! [`DEFAULT_MAX_RECURSION_DEPTH`](super::tree::DEFAULT_MAX_RECURSION_DEPTH), applied by the
//! walk; messages use JSON words (`Dialect::Json`).

use std::path::Path;

use super::elements::parse_tree;
use super::records::SceneRecords;
use super::tree::{Dialect, Node, closest_name};
use crate::error::{Loc, SceneError};

type Result<T> = std::result::Result<T, SceneError>;

/// Parses a scene file of the 2025 JSON dialect into plain records (the same records the XML
/// front end gives for the same scene).
///
/// # Errors
///
/// A [`SceneError`] with line and column for malformed JSON; with line and JSON path for a root
/// that is not `{"Scene": {…}}`, values of the wrong JSON type (an object or array where an
/// attribute or `_data` string belongs, an array inside an array), and everything the shared
/// element rules reject (missing required keys, malformed numbers, …).
pub fn parse_json(text: &str, source: &Path) -> Result<SceneRecords> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    if let Err(e) = serde_json::from_str::<serde::de::IgnoredAny>(text) {
        return Err(syntax_error(&e, source));
    }
    let mut scanner = Scanner { text, bytes: text.as_bytes(), pos: 0, line: 1, file: source, depth: 0 };
    let root = scanner.value()?;
    let root = scene_node(root, source)?;
    parse_tree(&root, source, Dialect::Json)
}

fn syntax_error(e: &serde_json::Error, file: &Path) -> SceneError {
    let hint = match e.classify() {
        serde_json::error::Category::Eof => {
            "the file ends inside an object, array or string; is it truncated, or is a `}`, `]` or quote missing?"
        }
        _ => {
            "check the JSON: keys and strings in double quotes, `,` between members but not after the last one, brackets balanced"
        }
    };
    let line = u32::try_from(e.line()).unwrap_or(u32::MAX).max(1);
    // serde_json's message ends with "at line L column C"; keep it, it has the column.
    SceneError::new(
        file,
        Loc { line: Some(line), element: None },
        format!("malformed JSON: {e}. Hint: {hint}"),
    )
}

// ---------------------------------------------------------------------------------------------
// Pass 2: a scanner over text serde_json has accepted
// ---------------------------------------------------------------------------------------------

/// A JSON value with the line it starts on.
enum Value {
    /// Strings, numbers and booleans, as element text (numbers and booleans as written).
    Scalar(String, u32),
    Null,
    /// Members in file order, each with the line of its key.
    Object(Vec<(String, u32, Value)>, u32),
    Array(Vec<Value>, u32),
}

struct Scanner<'a> {
    text: &'a str,
    bytes: &'a [u8],
    pos: usize,
    line: u32,
    file: &'a Path,
    /// Open objects and arrays around the current position.
    depth: usize,
}

/// Deeper nesting than this is certainly not a scene file (the XML front end has the same
/// limit); refusing it keeps the recursive scanner far away from stack overflows.
const MAX_DEPTH: usize = 64;

impl Scanner<'_> {
    /// Only reachable if serde_json accepted something this scanner does not: a bug, reported
    /// as an error rather than a panic.
    fn bad(&self) -> SceneError {
        SceneError::new(
            self.file,
            Loc { line: Some(self.line), element: None },
            "malformed JSON (unexpected character); check the JSON syntax here",
        )
    }

    fn skip_ws(&mut self) {
        while let Some(&b) = self.bytes.get(self.pos) {
            match b {
                b'\n' => self.line = self.line.saturating_add(1),
                b' ' | b'\t' | b'\r' => {}
                _ => break,
            }
            self.pos += 1;
        }
    }

    fn eat(&mut self, b: u8) -> bool {
        self.skip_ws();
        if self.bytes.get(self.pos) == Some(&b) {
            self.pos += 1;
            true
        } else {
            false
        }
    }

    fn value(&mut self) -> Result<Value> {
        self.skip_ws();
        if matches!(self.bytes.get(self.pos), Some(b'{' | b'[')) {
            if self.depth >= MAX_DEPTH {
                return Err(SceneError::new(
                    self.file,
                    Loc { line: Some(self.line), element: None },
                    format!(
                        "objects and arrays are nested more than {MAX_DEPTH} levels deep; this is not a scene file"
                    ),
                ));
            }
            self.depth += 1;
            let v = self.nested();
            self.depth -= 1;
            return v;
        }
        self.scalar()
    }

    fn nested(&mut self) -> Result<Value> {
        let line = self.line;
        match self.bytes.get(self.pos) {
            Some(b'{') => {
                self.pos += 1;
                let mut members = Vec::new();
                if self.eat(b'}') {
                    return Ok(Value::Object(members, line));
                }
                loop {
                    self.skip_ws();
                    let key_line = self.line;
                    let key = self.string()?;
                    if !self.eat(b':') {
                        return Err(self.bad());
                    }
                    let v = self.value()?;
                    members.push((key, key_line, v));
                    if self.eat(b',') {
                        continue;
                    }
                    if self.eat(b'}') {
                        return Ok(Value::Object(members, line));
                    }
                    return Err(self.bad());
                }
            }
            Some(b'[') => {
                self.pos += 1;
                let mut items = Vec::new();
                if self.eat(b']') {
                    return Ok(Value::Array(items, line));
                }
                loop {
                    items.push(self.value()?);
                    if self.eat(b',') {
                        continue;
                    }
                    if self.eat(b']') {
                        return Ok(Value::Array(items, line));
                    }
                    return Err(self.bad());
                }
            }
            _ => Err(self.bad()),
        }
    }

    fn scalar(&mut self) -> Result<Value> {
        let line = self.line;
        match self.bytes.get(self.pos) {
            Some(b'"') => Ok(Value::Scalar(self.string()?, line)),
            Some(_) => {
                let start = self.pos;
                while let Some(&b) = self.bytes.get(self.pos) {
                    if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'+' | b'.') {
                        self.pos += 1;
                    } else {
                        break;
                    }
                }
                match self.text.get(start..self.pos) {
                    Some("null") => Ok(Value::Null),
                    Some(t) if !t.is_empty() => Ok(Value::Scalar(t.to_string(), line)),
                    _ => Err(self.bad()),
                }
            }
            None => Err(self.bad()),
        }
    }

    /// A string token at the current position, unescaped.
    fn string(&mut self) -> Result<String> {
        self.skip_ws();
        if self.bytes.get(self.pos) != Some(&b'"') {
            return Err(self.bad());
        }
        let start = self.pos;
        self.pos += 1;
        let mut escaped = false;
        loop {
            match self.bytes.get(self.pos) {
                None => return Err(self.bad()),
                Some(b'\\') => {
                    escaped = true;
                    self.pos += 2;
                }
                Some(b'"') => {
                    self.pos += 1;
                    break;
                }
                Some(_) => self.pos += 1,
            }
        }
        let raw = self.text.get(start..self.pos).ok_or_else(|| self.bad())?;
        if escaped {
            serde_json::from_str::<String>(raw).map_err(|_| self.bad())
        } else {
            Ok(raw[1..raw.len() - 1].to_string())
        }
    }
}

// ---------------------------------------------------------------------------------------------
// JSON values -> element tree
// ---------------------------------------------------------------------------------------------

fn kind(v: &Value) -> &'static str {
    match v {
        Value::Scalar(..) => "a string",
        Value::Null => "null",
        Value::Object(..) => "an object",
        Value::Array(..) => "an array",
    }
}

fn scene_node(root: Value, file: &Path) -> Result<Node> {
    let top = |message: String| SceneError::new(file, Loc { line: Some(1), element: None }, message);
    let Value::Object(members, _) = root else {
        return Err(top(format!(
            "the file is {}, not a JSON scene: expected an object with the key \"Scene\", like {{\"Scene\": {{…}}}}",
            kind(&root)
        )));
    };
    let mut scene = None;
    for (key, line, value) in members {
        if key != "Scene" {
            let hint = match closest_name(&key, std::iter::once("Scene")) {
                Some(_) => " (did you mean \"Scene\"?)",
                None => "",
            };
            return Err(SceneError::new(
                file,
                Loc::new(line, key.clone()),
                format!(
                    "unexpected top-level key \"{key}\"{hint}; a JSON scene has exactly one key, \"Scene\""
                ),
            ));
        }
        if scene.is_some() {
            return Err(SceneError::new(file, Loc::new(line, "Scene"), "the key \"Scene\" is given twice"));
        }
        scene = Some((line, value));
    }
    let Some((line, value)) = scene else {
        return Err(top("no \"Scene\" key: a JSON scene is {\"Scene\": {…}}".into()));
    };
    if !matches!(value, Value::Object(..)) {
        return Err(SceneError::new(
            file,
            Loc::new(line, "Scene"),
            format!("\"Scene\" must be an object holding the scene's elements, found {}", kind(&value)),
        ));
    }
    let mut nodes = Vec::new();
    element("Scene", value, "Scene".into(), line, 1, file, &mut nodes)?;
    nodes.pop().ok_or_else(|| SceneError::new(file, Loc::new(line, "Scene"), "\"Scene\" is empty"))
}

/// Appends the element(s) that key `name` with `value` stands for to `out`: none for `null`,
/// several for an array.
fn element(
    name: &str,
    value: Value,
    path: String,
    line: u32,
    depth: usize,
    file: &Path,
    out: &mut Vec<Node>,
) -> Result<()> {
    let leaf = |text: String, text_line: u32, path: String| Node {
        name: name.to_string(),
        label: path,
        depth,
        line,
        content_line: text_line,
        attrs: Vec::new(),
        text,
        children: Vec::new(),
    };
    match value {
        Value::Null => {}
        Value::Scalar(text, text_line) => out.push(leaf(text, text_line, path)),
        Value::Array(items, _) => {
            for (i, item) in items.into_iter().enumerate() {
                let item_path = format!("{path}[{i}]");
                match item {
                    Value::Array(_, l) => {
                        return Err(SceneError::new(
                            file,
                            Loc::new(l, item_path),
                            format!(
                                "an array inside an array; write repeated \"{name}\" elements as one array of objects or strings"
                            ),
                        ));
                    }
                    Value::Scalar(text, l) => out.push(Node { line: l, ..leaf(text, l, item_path) }),
                    Value::Object(_, l) => {
                        let mut one = Vec::new();
                        element(name, item, item_path, l, depth, file, &mut one)?;
                        out.extend(one);
                    }
                    Value::Null => {}
                }
            }
        }
        Value::Object(members, _) => {
            let mut node = leaf(String::new(), line, path);
            for (key, key_line, v) in members {
                let member_path = format!("{}.{key}", node.label);
                if let Some(attr) = key.strip_prefix('_') {
                    let text = match v {
                        Value::Scalar(text, l) => {
                            if attr == "data" {
                                node.content_line = l;
                            }
                            text
                        }
                        Value::Null => continue,
                        other => {
                            let what = if attr == "data" { "the element's text" } else { "an attribute" };
                            return Err(SceneError::new(
                                file,
                                Loc::new(key_line, member_path),
                                format!(
                                    "\"{key}\" is {what} and must be a string, found {}; write it as \"{key}\": \"…\"",
                                    kind(&other)
                                ),
                            ));
                        }
                    };
                    if attr == "data" {
                        node.text.push_str(&text);
                    } else {
                        node.attrs.push((attr.to_string(), text));
                    }
                } else {
                    element(&key, v, member_path, key_line, depth + 1, file, &mut node.children)?;
                }
            }
            out.push(node);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::tree::DEFAULT_MAX_RECURSION_DEPTH;
    use crate::scene::xml;

    const FILE: &str = "scene.json";

    fn parse(json: &str) -> Result<SceneRecords> {
        parse_json(json, Path::new(FILE))
    }

    fn err(json: &str) -> String {
        match parse(json) {
            Ok(_) => panic!("expected an error for {json}"),
            Err(e) => e.to_string(),
        }
    }

    const CAMERA: &str = r#""Cameras": {"Camera": {"_id": "1", "Position": "0 0 0", "Gaze": "0 0 -1",
        "Up": "0 1 0", "NearPlane": "-1 1 -1 1", "NearDistance": "1", "ImageResolution": "8 8",
        "ImageName": "a.png"}}"#;

    #[test]
    fn objects_arrays_attributes_data_and_null() {
        let json = format!(
            r#"{{"Scene": {{
  "MaxRecursionDepth": "6",
  {CAMERA},
  "Lights": {{"AmbientLight": "1 2 3", "PointLight": [
      {{"_id": "1", "Position": "0 0 0", "Intensity": "1 1 1"}},
      {{"_id": "2", "Position": "1 0 0", "Intensity": "2 2 2"}}]}},
  "Materials": {{"Material": {{"_id": "1", "_type": "mirror", "MirrorReflectance": "1 1 1"}}}},
  "VertexData": {{"_data": "0 0 0\n 1 0 0 0 1 0", "_type": "xyz"}},
  "TexCoordData": null,
  "Objects": {{"Mesh": {{"_id": "1", "Material": "1", "Faces": {{"_data": "1 2 3", "_type": "triangle"}}}},
              "Sphere": {{"_id": "1", "Material": "1", "Center": "1", "Radius": 0.5}}}}
}}}}"#
        );
        let r = parse(&json).unwrap();
        assert_eq!(r.max_recursion_depth, 6);
        let r = parse(&json.replace(r#""MaxRecursionDepth": "6","#, r#""MaxRecursionDepth": "0","#)).unwrap();
        assert_eq!(r.max_recursion_depth, 0);
        let r = parse(&json.replace(r#""MaxRecursionDepth": "6","#, "")).unwrap();
        assert_eq!(r.max_recursion_depth, DEFAULT_MAX_RECURSION_DEPTH);
        assert_eq!(r.ambient_light, [1.0, 2.0, 3.0]);
        assert_eq!(r.point_lights.len(), 2);
        assert_eq!(r.point_lights[1].intensity, [2.0; 3]);
        assert_eq!(r.point_lights[1].loc, Loc::new(8, "Scene.Lights.PointLight[1]"));
        assert_eq!(r.materials[0].kind, super::super::records::MaterialKind::Mirror);
        assert_eq!(r.vertices.len(), 3);
        assert_eq!(r.meshes.len(), 1);
        assert_eq!(r.meshes[0].loc, Loc::new(12, "Scene.Objects.Mesh"));
        assert_eq!(r.spheres[0].radius, 0.5);
        assert!(r.warnings.is_empty(), "{:?}", r.warnings);
    }

    /// `Transformations` on cameras and lights (§10.4), a 2025 JSON element, reach the same
    /// records from JSON as from XML.
    #[test]
    fn camera_and_light_transformations_match_their_xml_twin() {
        let json = r#"{"Scene": {
  "MaxRecursionDepth": "2",
  "Cameras": {"Camera": [
    {"_id": "1", "Position": "0 0 0", "Gaze": "0 0 -1", "Up": "0 1 0", "NearPlane": "-1 1 -1 1",
     "NearDistance": "1", "ImageResolution": "8 8", "ImageName": "a.png", "Transformations": "r1 t1"},
    {"_id": "2", "_type": "lookAt", "Position": "1 2 3", "GazePoint": "0 0 0", "Up": "0 1 0", "FovY": "40",
     "NearDistance": "1", "ImageResolution": "8 8", "ImageName": "b.png", "Transformations": "t1"}]},
  "Lights": {
    "PointLight": {"_id": "1", "Position": "1 2 3", "Intensity": "5 5 5", "Transformations": "t1"},
    "AreaLight": {"_id": "2", "Position": "0 5 0", "Normal": "0 0 1", "Size": "2", "Radiance": "1 1 1",
                  "Transformations": "r1"},
    "DirectionalLight": {"_id": "3", "Direction": "0 0 -1", "Radiance": "1 1 1", "Transformations": "r1"},
    "SpotLight": {"_id": "4", "Position": "1 2 3", "Direction": "0 0 -1", "Intensity": "1 1 1",
                  "CoverageAngle": "30", "FalloffAngle": "20", "Transformations": "r1 t1"}},
  "Transformations": {"Rotation": {"_id": "1", "_data": "90 0 1 0"},
                      "Translation": {"_id": "1", "_data": "10 0 0"}}
}}"#;
        let xml = r#"<Scene>
  <MaxRecursionDepth>2</MaxRecursionDepth>
  <Cameras>
    <Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up><NearPlane>-1 1 -1 1</NearPlane>
      <NearDistance>1</NearDistance><ImageResolution>8 8</ImageResolution><ImageName>a.png</ImageName>
      <Transformations>r1 t1</Transformations></Camera>
    <Camera id="2" type="lookAt"><Position>1 2 3</Position><GazePoint>0 0 0</GazePoint><Up>0 1 0</Up><FovY>40</FovY>
      <NearDistance>1</NearDistance><ImageResolution>8 8</ImageResolution><ImageName>b.png</ImageName>
      <Transformations>t1</Transformations></Camera>
  </Cameras>
  <Lights>
    <PointLight id="1"><Position>1 2 3</Position><Intensity>5 5 5</Intensity><Transformations>t1</Transformations></PointLight>
    <AreaLight id="2"><Position>0 5 0</Position><Normal>0 0 1</Normal><Size>2</Size><Radiance>1 1 1</Radiance>
      <Transformations>r1</Transformations></AreaLight>
    <DirectionalLight id="3"><Direction>0 0 -1</Direction><Radiance>1 1 1</Radiance>
      <Transformations>r1</Transformations></DirectionalLight>
    <SpotLight id="4"><Position>1 2 3</Position><Direction>0 0 -1</Direction><Intensity>1 1 1</Intensity>
      <CoverageAngle>30</CoverageAngle><FalloffAngle>20</FalloffAngle><Transformations>r1 t1</Transformations></SpotLight>
  </Lights>
  <Transformations><Rotation id="1">90 0 1 0</Rotation><Translation id="1">10 0 0</Translation></Transformations>
</Scene>"#;
        // Locations differ (lines, JSON paths); everything else must not.
        let content = |mut r: SceneRecords| {
            assert!(r.warnings.is_empty(), "{:?}", r.warnings);
            r.cameras.iter_mut().for_each(|x| x.loc = Loc::default());
            r.point_lights.iter_mut().for_each(|x| x.loc = Loc::default());
            r.area_lights.iter_mut().for_each(|x| x.loc = Loc::default());
            r.directional_lights.iter_mut().for_each(|x| x.loc = Loc::default());
            r.spot_lights.iter_mut().for_each(|x| x.loc = Loc::default());
            r.transformations.iter_mut().for_each(|x| x.loc = Loc::default());
            r.json = false;
            r
        };
        let from_json = content(parse(json).unwrap());
        let from_xml = content(xml::parse_xml(xml, Path::new(FILE)).unwrap());
        assert_eq!(from_json, from_xml);
        assert_eq!(from_json.cameras[0].transforms.len(), 2);
        assert_eq!(from_json.spot_lights[0].transforms.len(), 2);
        // And a reference to a transformation the scene lacks is reported with its JSON path.
        let undefined = json.replace(r#""Transformations": "r1 t1"},"#, r#""Transformations": "r1 t7"},"#);
        let resolver = crate::assets::FsResolver { base_dir: ".".into() };
        let built = crate::scene::build::build_scene(&parse(&undefined).unwrap(), &resolver);
        let e = built.err().expect("t7 is not defined").to_string();
        assert_eq!(
            e,
            r#"scene.json:4: <Scene.Cameras.Camera[0]>: transformation "t7" is not defined; add "Translation" with "_id": "7" under "Transformations""#
        );
        // The build's warnings use JSON words too.
        let no_cameras = r#"{"Scene": {"Cameras": {}}}"#;
        let scene = crate::scene::build::build_scene(&parse(no_cameras).unwrap(), &resolver).unwrap();
        let messages: Vec<&str> = scene.warnings.iter().map(|w| w.message.as_str()).collect();
        assert!(messages.contains(&"the scene has no \"Camera\"; nothing will be rendered"), "{messages:?}");
    }

    #[test]
    fn syntax_errors_have_line_and_column() {
        let e = err("{\"Scene\": {\n  \"BackgroundColor\": \"0 0 0\",\n}}");
        assert!(e.starts_with("scene.json:3: malformed JSON"), "{e}");
        assert!(e.contains("column"), "{e}");
        let e = err("{\"Scene\": {\n  \"BackgroundColor\": \"0 0");
        assert!(e.starts_with("scene.json:2: malformed JSON"), "{e}");
        assert!(e.contains("truncated"), "{e}");
        let deep = format!("{}{}", "[".repeat(100_000), "]".repeat(100_000));
        assert!(err(&deep).contains("nested more than 64 levels"), "{}", err(&deep));
    }

    #[test]
    fn wrong_types_and_missing_keys_name_the_json_path() {
        let cases: &[(&str, &str)] = &[
            ("[1, 2]", "scene.json:1: the file is an array, not a JSON scene"),
            ("{}", "no \"Scene\" key"),
            ("{\"Scene\": {}, \"Other\": 1}", "scene.json:1: <Other>: unexpected top-level key"),
            (
                "{\"Scene\": {\"Objects\": {\"Sphere\": [[\"1\"]]}}}",
                "<Scene.Objects.Sphere[0]>: an array inside an array",
            ),
            (
                "{\"Scene\": {\"Objects\": {\"Sphere\": {\"_id\": {\"x\": 1}}}}}",
                "<Scene.Objects.Sphere._id>: \"_id\" is an attribute and must be a string, found an object",
            ),
            (
                "{\"Scene\": {\"VertexData\": {\"_data\": [\"1\"]}}}",
                "<Scene.VertexData._data>: \"_data\" is the element's text and must be a string, found an array",
            ),
            (
                "{\"Scene\": {\"Materials\": {\"Material\": {\"_id\": \"1\"}},\n \"Objects\": {\"Mesh\": [{\"_id\": \"1\", \"Material\": \"1\", \"Faces\": \"1 2 3\"},\n {\"_id\": \"2\",\n \"Material\": \"1\"}]}}}",
                "scene.json:3: <Scene.Objects.Mesh[1].Faces>: missing \"Faces\"; add the key \"Faces\" to Scene.Objects.Mesh[1]",
            ),
            (
                "{\"Scene\": {\"Objects\": {\"Sphere\": {\"_id\": \"1\", \"Material\": \"1\", \"Center\": \"1\", \"Radius\": {\"a\": \"b\"}}}}}",
                "<Scene.Objects.Sphere.Radius>: expected a number, found nothing",
            ),
            (
                "{\"Scene\": {\"Materials\": {\"Material\": {\"AmbientReflectance\": \"1 1 1\"}}}}",
                "<Scene.Materials.Material>: missing key \"_id\"",
            ),
        ];
        for (json, want) in cases {
            let e = err(json);
            assert!(e.contains(want), "{json}\n got: {e}\nwant: {want}");
        }
    }

    /// A misspelt key is named with the one most likely meant: an element's (`"PointLigth"`,
    /// `"Positon"`), an attribute's (`"_Id"`, or `"id"` without its `_`) and the root's.
    #[test]
    fn misspelt_keys_say_which_key_was_meant() {
        let warnings = |json: &str| -> Vec<String> {
            parse(json)
                .unwrap_or_else(|e| panic!("{json}: {e}"))
                .warnings
                .iter()
                .map(|w| w.to_string())
                .collect()
        };
        let lights = |body: &str| format!("{{\"Scene\": {{{CAMERA},\n\"Lights\": {{{body}}}}}}}");
        assert_eq!(
            warnings(&lights(r#""PointLigth": {"_id": "1", "Position": "0 0 0", "Intensity": "1 1 1"}"#)),
            [
                r#"warning: scene.json:4: <Scene.Lights.PointLigth>: unknown key "PointLigth"; did you mean "PointLight"? It is ignored"#
            ]
        );
        assert_eq!(
            warnings(&lights(r#""PointLight": {"_Id": "1", "Position": "0 0 0", "Intensity": "1 1 1"}"#)),
            [
                r#"warning: scene.json:4: <Scene.Lights.PointLight>: unknown key "_Id"; did you mean key "_id"? It is ignored"#
            ]
        );
        assert_eq!(
            warnings(&lights(
                r#""PointLight": {"_id": "1", "Position": "0 0 0", "Intensity": "1 1 1", "Texture": "1"}"#
            )),
            [
                r#"warning: scene.json:4: <Scene.Lights.PointLight.Texture>: unknown key "Texture"; it is ignored"#
            ]
        );
        // An attribute written without its `_`.
        let mesh = r#"{"Scene": {"Materials": {"Material": {"_id": "1"}},
  "Objects": {"Sphere": {"_id": "1", "Material": "1", "Center": "1", "Radius": "1",
    "id": "2"}}}}"#;
        assert_eq!(
            warnings(mesh),
            [
                r#"warning: scene.json:3: <Scene.Objects.Sphere.id>: unknown key "id"; did you mean key "_id"? It is ignored"#
            ]
        );
        // A misspelt required key is an error about that key, not only about the missing one.
        assert_eq!(
            err(&lights(
                "\"PointLight\": {\"_id\": \"1\",\n\"Positon\": \"0 0 0\", \"Intensity\": \"1 1 1\"}"
            )),
            r#"scene.json:5: <Scene.Lights.PointLight.Positon>: unknown key "Positon"; did you mean "Position"? Rename the key in Scene.Lights.PointLight (it needs "Position")"#
        );
        assert_eq!(
            err(r#"{"Scnee": {}}"#),
            r#"scene.json:1: <Scnee>: unexpected top-level key "Scnee" (did you mean "Scene"?); a JSON scene has exactly one key, "Scene""#
        );
    }

    /// Truncating a valid scene anywhere, or replacing any string by another JSON type, gives
    /// an error or records, never a panic.
    #[test]
    fn truncations_and_type_swaps_never_panic() {
        let json = format!(
            r#"{{"Scene": {{ {CAMERA}, "VertexData": {{"_data": "0 0 0 1 0 0 0 1 0", "_type": "xyz"}},
  "Materials": {{"Material": {{"_id": "1"}}}},
  "Objects": {{"Mesh": {{"_id": "1", "Material": "1", "Faces": {{"_data": "1 2 3"}}}},
    "Plane": {{"_id": "1", "Material": "1", "Point": "1", "Normal": "0 1 0"}}}}}}}}"#
        );
        assert!(parse(&json).is_ok());
        for cut in 0..json.len() {
            if json.is_char_boundary(cut) {
                let _ = parse(&json[..cut]);
            }
        }
        let quoted: Vec<(usize, usize)> = json
            .match_indices('"')
            .collect::<Vec<_>>()
            .chunks_exact(2)
            .map(|p| (p[0].0, p[1].0 + 1))
            .collect();
        for (a, b) in quoted {
            for replacement in ["1", "null", "[]", "{}", "[[]]", "true", "\"\""] {
                let swapped = format!("{}{replacement}{}", &json[..a], &json[b..]);
                let _ = parse(&swapped);
            }
        }
    }
}
