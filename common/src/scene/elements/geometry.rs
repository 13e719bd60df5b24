//! The rules of vertex data, `<Transformations>` and `<Objects>`: meshes, triangles, spheres,
//! planes, mesh instances and object lights.

use crate::scene::records::{
    BinaryFileRec, FacesRec, InstanceRec, MeshRec, PlaneRec, ShadingMode, SphereRec, TransformOp,
    TransformRec, TriangleRec, Vec3,
};
use crate::scene::tree::{Node, Parser, Result, Schema, Unsupported, excerpt, quoted};

const TRANSFORMATIONS: Schema =
    Schema { many: &["Translation", "Scaling", "Rotation", "Composite"], ..Schema::EMPTY };
const TRANSFORMATION: Schema = Schema { attrs: &["id"], ..Schema::EMPTY };
const OBJECTS: Schema = Schema {
    // Plane only exists in the 2025 JSON dialect so far (§9.8); XML files may use it too.
    many: &["Mesh", "Triangle", "Sphere", "MeshInstance", "Plane", "LightMesh", "LightSphere"],
    ..Schema::EMPTY
};
// `Texture` is the 2019 spelling of an object's `Textures`. Both are read (and their repeats
// checked) by `Parser::object_textures`.
const MESH: Schema = Schema {
    single: &["Material", "Faces", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id", "shadingMode"],
    ..Schema::EMPTY
};
/// Object lights (§9.6, §9.7): a mesh or a sphere that also emits `Radiance`. They do not move
/// (no MotionBlur) and carry no textures.
const LIGHT_MESH: Schema = Schema {
    single: &["Material", "Faces", "Transformations", "Radiance"],
    unsupported: LIGHT_UNSUPPORTED,
    attrs: &["id", "shadingMode"],
    ..Schema::EMPTY
};
const LIGHT_SPHERE: Schema = Schema {
    single: &["Material", "Center", "Radius", "Transformations", "Radiance"],
    unsupported: LIGHT_UNSUPPORTED,
    attrs: &["id"],
    ..Schema::EMPTY
};
/// What other objects have and object lights do not (yet): each changes the picture.
const LIGHT_UNSUPPORTED: &[Unsupported] = &[
    ("MotionBlur", "without it, the light stands still"),
    ("Textures", "without them, the light's surface is untextured"),
    ("Texture", "without it, the light's surface is untextured"),
];
const TRIANGLE: Schema = Schema {
    single: &["Material", "Indices", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id"],
    ..Schema::EMPTY
};
const SPHERE: Schema = Schema {
    single: &["Material", "Center", "Radius", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id"],
    ..Schema::EMPTY
};
const PLANE: Schema = Schema {
    single: &["Material", "Point", "Normal", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id"],
    ..Schema::EMPTY
};
const MESH_INSTANCE: Schema = Schema {
    single: &["Material", "Transformations", "MotionBlur"],
    many: &["Textures", "Texture"],
    attrs: &["id", "baseMeshId", "resetTransform", "shadingMode"],
    ..Schema::EMPTY
};
// Also used for `TexCoordData`.
// `type` is the 2025 JSON `_type` (`xyz`, `uv`), checked by `Parser::data_type`; `binaryFile`
// (2019) names a file the values are read from at build time.
const VERTEX_DATA_ATTRS: &[&str] = &["type", "binaryFile"];
const FACES_ATTRS: &[&str] = &["vertexOffset", "textureOffset", "plyFile", "binaryFile", "type"];
const FACES_UNSUPPORTED_ATTRS: &[Unsupported] = &[];

impl Parser<'_> {
    pub(super) fn transformations(&mut self, block: &Node) -> Result<()> {
        self.check(block, &TRANSFORMATIONS);
        for t in &block.children {
            if let Some(t) = self.transformation(t)? {
                self.out.transformations.push(t);
            }
        }
        Ok(())
    }

    /// One child of `<Transformations>`; `None` for elements that are not transformations
    /// (already warned about by [`Parser::check`]).
    pub(super) fn transformation(&mut self, n: &Node) -> Result<Option<TransformRec>> {
        let op = match n.name.as_str() {
            "Translation" => TransformOp::Translation(self.numbers(n)?),
            "Scaling" => TransformOp::Scaling(self.numbers(n)?),
            "Rotation" => {
                let [degrees, x, y, z] = self.numbers(n)?;
                TransformOp::Rotation { degrees, axis: [x, y, z] }
            }
            "Composite" => TransformOp::Composite(self.numbers(n)?),
            _ => return Ok(None),
        };
        self.check(n, &TRANSFORMATION);
        Ok(Some(TransformRec { id: self.id(n, true)?, loc: n.loc(), op }))
    }

    /// The 2025 `type` attribute of `VertexData` / `TexCoordData` / `Faces` (§14.2), which
    /// only has one value each: anything else would change how the numbers are read.
    pub(super) fn data_type(&self, n: &Node, only: &str, meaning: &str) -> Result<()> {
        match n.attr("type").map(str::trim) {
            None => Ok(()),
            Some(t) if t == only => Ok(()),
            Some(other) => Err(self
                .err(n, format!("attribute type must be {only} ({meaning}), found \"{}\"", excerpt(other)))),
        }
    }

    pub(super) fn vertex_data(&mut self, n: &Node) -> Result<()> {
        self.check_attrs(n, VERTEX_DATA_ATTRS, &[]);
        self.data_type(n, "xyz", "x y z per vertex")?;
        if let Some(file) = self.binary_file(n)? {
            self.out.vertex_file = Some(file);
            return Ok(());
        }
        let values = self.number_list::<f64>(n, 3, "x y z per vertex")?;
        self.out.vertices = values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Ok(())
    }

    pub(super) fn tex_coord_data(&mut self, n: &Node) -> Result<()> {
        self.check_attrs(n, VERTEX_DATA_ATTRS, &[]);
        self.data_type(n, "uv", "u v per texture coordinate")?;
        if let Some(file) = self.binary_file(n)? {
            self.out.tex_coord_file = Some(file);
            return Ok(());
        }
        let values = self.number_list::<f64>(n, 2, "u v per texture coordinate")?;
        self.out.tex_coords = values.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        Ok(())
    }

    /// A 2019 `binaryFile="..."` attribute: `None` when absent; empty is an error.
    fn binary_file(&self, n: &Node) -> Result<Option<BinaryFileRec>> {
        match n.attr("binaryFile").map(str::trim) {
            None => Ok(None),
            Some("") => Err(self.err(n, "attribute binaryFile is empty; expected a file path")),
            Some(path) => Ok(Some(BinaryFileRec { path: path.to_string(), loc: n.loc() })),
        }
    }

    pub(super) fn objects(&mut self, objects: &Node) -> Result<()> {
        self.check(objects, &OBJECTS);
        for n in &objects.children {
            match n.name.as_str() {
                "Mesh" | "LightMesh" => {
                    let mesh = self.mesh(n)?;
                    self.out.meshes.push(mesh);
                }
                "Triangle" => {
                    let triangle = self.triangle(n)?;
                    self.out.triangles.push(triangle);
                }
                "Sphere" | "LightSphere" => {
                    let sphere = self.sphere(n)?;
                    self.out.spheres.push(sphere);
                }
                "MeshInstance" => {
                    let instance = self.instance(n)?;
                    self.out.instances.push(instance);
                }
                "Plane" => {
                    let plane = self.plane(n)?;
                    self.out.planes.push(plane);
                }
                _ => {}
            }
        }
        Ok(())
    }

    pub(super) fn material_ref(&self, n: &Node) -> Result<String> {
        self.id_ref(self.required(n, "Material")?, "a material id")
    }

    pub(super) fn mesh(&mut self, n: &Node) -> Result<MeshRec> {
        let light = n.name == "LightMesh";
        self.check(n, if light { &LIGHT_MESH } else { &MESH });
        let id = self.id(n, true)?;
        let faces = self.required(n, "Faces")?;
        self.check_attrs(faces, FACES_ATTRS, FACES_UNSUPPORTED_ATTRS);
        self.data_type(faces, "triangle", "three vertex ids per face")?;
        let faces_rec = if let Some(path) = faces.attr("plyFile") {
            match path.trim() {
                "" => return Err(self.err(faces, "attribute plyFile is empty; expected a PLY file path")),
                path => FacesRec::Ply { path: path.to_string() },
            }
        } else if let Some(b) = self.binary_file(faces)? {
            FacesRec::Binary {
                path: b.path,
                vertex_offset: self.int_attr(faces, "vertexOffset")?.unwrap_or(0),
                texture_offset: self.int_attr(faces, "textureOffset")?,
            }
        } else {
            FacesRec::Inline {
                indices: self.number_list(faces, 3, "three vertex ids per triangle")?,
                vertex_offset: self.int_attr(faces, "vertexOffset")?.unwrap_or(0),
                texture_offset: self.int_attr(faces, "textureOffset")?,
            }
        };
        Ok(MeshRec {
            id,
            loc: n.loc(),
            material: self.material_ref(n)?,
            faces: faces_rec,
            faces_loc: faces.loc(),
            shading: self.shading_attr(n)?.unwrap_or(ShadingMode::Flat),
            transforms: self.transform_refs(n)?,
            motion_blur: if light { None } else { self.optional_numbers(n, "MotionBlur")? },
            textures: if light { Vec::new() } else { self.object_textures(n)? },
            radiance: if light { Some(self.radiance(n)?) } else { None },
        })
    }

    /// The `<Radiance>` of an object light: three non-negative numbers.
    pub(super) fn radiance(&self, n: &Node) -> Result<Vec3> {
        let r = self.required(n, "Radiance")?;
        let v: Vec3 = self.numbers(r)?;
        if v.iter().any(|c| !(*c >= 0.0 && c.is_finite())) {
            return Err(self
                .err(r, format!("Radiance must be three non-negative numbers, found {}", quoted(&r.text))));
        }
        Ok(v)
    }

    pub(super) fn triangle(&mut self, n: &Node) -> Result<TriangleRec> {
        self.check(n, &TRIANGLE);
        Ok(TriangleRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            material: self.material_ref(n)?,
            indices: self.required_numbers(n, "Indices")?,
            transforms: self.transform_refs(n)?,
            textures: self.object_textures(n)?,
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
        })
    }

    pub(super) fn sphere(&mut self, n: &Node) -> Result<SphereRec> {
        let light = n.name == "LightSphere";
        self.check(n, if light { &LIGHT_SPHERE } else { &SPHERE });
        Ok(SphereRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            material: self.material_ref(n)?,
            center: self.required_number(n, "Center")?,
            radius: self.required_number(n, "Radius")?,
            transforms: self.transform_refs(n)?,
            motion_blur: if light { None } else { self.optional_numbers(n, "MotionBlur")? },
            textures: if light { Vec::new() } else { self.object_textures(n)? },
            radiance: if light { Some(self.radiance(n)?) } else { None },
        })
    }

    /// An infinite plane (2025, §9.8): `Point` is a vertex id, `Normal` a direction.
    pub(super) fn plane(&mut self, n: &Node) -> Result<PlaneRec> {
        self.check(n, &PLANE);
        let normal: Vec3 = self.required_numbers(n, "Normal")?;
        if normal == [0.0; 3] {
            return Err(self.err(n, "<Normal> is the zero vector; give the direction the plane faces"));
        }
        Ok(PlaneRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            material: self.material_ref(n)?,
            point: self.required_number(n, "Point")?,
            normal,
            transforms: self.transform_refs(n)?,
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
            textures: self.object_textures(n)?,
        })
    }

    pub(super) fn instance(&mut self, n: &Node) -> Result<InstanceRec> {
        self.check(n, &MESH_INSTANCE);
        let base_mesh = match n.attr("baseMeshId").map(str::trim) {
            None | Some("") => {
                return Err(self.err(n, "missing attribute baseMeshId (the id of the Mesh to reuse)"));
            }
            Some(id) => id.to_string(),
        };
        Ok(InstanceRec {
            id: self.id(n, false)?,
            loc: n.loc(),
            base_mesh,
            reset_transform: self.bool_attr(n, "resetTransform")?.unwrap_or(false),
            material: n.child("Material").map(|m| self.id_ref(m, "a material id")).transpose()?,
            transforms: self.transform_refs(n)?,
            shading: self.shading_attr(n)?,
            motion_blur: self.optional_numbers(n, "MotionBlur")?,
            textures: self.object_textures(n)?,
        })
    }
}
