//! Steps 6 and 7 of the build: every object placed as an instance (meshes, mesh instances,
//! triangles, spheres, planes), and the object lights made from those that emit.

use std::collections::HashMap;
use std::sync::Arc;

use glam::{DAffine3, DVec2, DVec3};

use super::context::{Ctx, unplaced_message};
use super::meshes::Meshes;
use super::textures::{BuiltTextures, uses_image};
use crate::error::{Loc, SceneError, Warning};
use crate::geometry::mesh::{MeshGeom, drop_degenerate};
use crate::geometry::{Accel, Instance, ObjectTextures, Shape};
use crate::lights::ObjectLight;
use crate::math::v3;
use crate::scene::records::*;

/// What step 6 makes: all the mesh geometry, the instances with the location of each one's
/// record, and the emitting instances.
pub(super) struct Placed {
    pub(super) geoms: Vec<Arc<MeshGeom>>,
    pub(super) instances: Vec<Instance>,
    pub(super) locs: Vec<Loc>,
    pub(super) emitters: Vec<Emitter>,
}

/// What step 6 reads: the id tables and the built texture maps.
pub(super) struct Objects<'c, 'a> {
    pub(super) ctx: &'c Ctx<'a>,
    pub(super) transforms: &'c HashMap<(char, &'a str), TransformOp>,
    pub(super) mat_ids: &'c HashMap<&'a str, u32>,
    pub(super) textures: &'c BuiltTextures<'a>,
}

impl Objects<'_, '_> {
    /// Step 6: every object as an [`Instance`] with its material, transform, motion and texture
    /// maps: meshes themselves, mesh instances, single triangles (each a one-triangle mesh of its
    /// own, added to `meshes.geoms`), spheres and planes, in that order. Returns all the mesh
    /// geometry, the instances, and which of them emit (LightMesh, LightSphere) with their
    /// radiance and the record's location.
    pub(super) fn place(&self, meshes: Meshes, warnings: &mut Vec<Warning>) -> Result<Placed, SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let Meshes { mut geoms, world, instances: resolved, .. } = meshes;
        let mut instances = Vec::new();
        let mut locs = Vec::new();
        let mut emitters = Vec::new();
        let mut mesh_textures = Vec::with_capacity(rec.meshes.len());
        for m in &rec.meshes {
            mesh_textures.push(self.textures.for_object(ctx, &m.textures, &m.loc, warnings)?);
        }
        for (i, m) in rec.meshes.iter().enumerate() {
            let material = ctx.material(self.mat_ids, &m.material, &m.loc)?;
            if uses_image(self.textures, &mesh_textures[i]) && geoms[i].uvs.is_none() {
                ctx.warn(warnings, &m.loc, "an image texture is applied but the mesh has no texture coordinates (TexCoordData or PLY u v); it is sampled at the barycentric coordinates");
            }
            if let Some(r) = m.radiance {
                emitters.push(Emitter {
                    instance: instances.len() as u32,
                    radiance: v3(r),
                    loc: m.loc.clone(),
                });
            }
            instances.push(Instance {
                shape: Shape::Mesh { mesh: i as u32, smooth: m.shading == ShadingMode::Smooth },
                material,
                transform: ctx.make_transform(world[i], &m.loc)?,
                motion: motion(m.motion_blur),
                textures: mesh_textures[i],
            });
            locs.push(m.loc.clone());
        }
        for (r, inst) in resolved.iter().zip(&rec.instances) {
            // An instance's own `Textures` replace its base mesh's.
            let textures = match r.textures_from {
                None => mesh_textures[r.mesh],
                Some(k) => {
                    let own = &rec.instances[k];
                    let t = self.textures.for_object(ctx, &own.textures, &own.loc, warnings)?;
                    if uses_image(self.textures, &t) && geoms[r.mesh].uvs.is_none() {
                        ctx.warn(warnings, &own.loc, "an image texture is applied but the base mesh has no texture coordinates (TexCoordData or PLY u v); it is sampled at the barycentric coordinates");
                    }
                    t
                }
            };
            instances.push(Instance {
                shape: Shape::Mesh { mesh: r.mesh as u32, smooth: r.smooth },
                material: r.material,
                transform: ctx.make_transform(r.world, &inst.loc)?,
                motion: motion(inst.motion_blur),
                textures,
            });
            locs.push(inst.loc.clone());
        }
        for t in &rec.triangles {
            if let Some((geom, instance)) = self.triangle(t, geoms.len() as u32, warnings)? {
                geoms.push(geom);
                instances.push(instance);
                locs.push(t.loc.clone());
            }
        }
        for s in &rec.spheres {
            if let Some(r) = s.radiance {
                emitters.push(Emitter {
                    instance: instances.len() as u32,
                    radiance: v3(r),
                    loc: s.loc.clone(),
                });
            }
            instances.push(self.sphere(s, warnings)?);
            locs.push(s.loc.clone());
        }
        for p in &rec.planes {
            instances.push(self.plane(p, warnings)?);
            locs.push(p.loc.clone());
        }
        Ok(Placed { geoms, instances, locs, emitters })
    }

    /// A `<Triangle>` as a one-triangle mesh (the mesh index `mesh` in the scene) and its
    /// instance; `None` (with a warning) when it is degenerate.
    pub(super) fn triangle(
        &self,
        t: &TriangleRec,
        mesh: u32,
        warnings: &mut Vec<Warning>,
    ) -> Result<Option<(Arc<MeshGeom>, Instance)>, SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let material = ctx.material(self.mat_ids, &t.material, &t.loc)?;
        let mut ids = [0u32; 3];
        for (id, &index) in ids.iter_mut().zip(&t.indices) {
            *id = ctx.vertex(index, &t.loc, "<Indices>")?;
        }
        let positions: Vec<DVec3> = ids.iter().map(|&g| v3(rec.vertices[g as usize])).collect();
        let mut indices = vec![[0, 1, 2]];
        if drop_degenerate(&positions, &mut indices) > 0 {
            ctx.warn(warnings, &t.loc, "degenerate triangle skipped");
            return Ok(None);
        }
        let world = ctx.transform(self.transforms, &t.transforms, &t.loc)?;
        // Texture coordinates are parallel to the vertex list (§8.2).
        let uvs = ids
            .iter()
            .map(|&g| rec.tex_coords.get(g as usize).map(|t| DVec2::from_array(*t)))
            .collect::<Option<Vec<_>>>();
        let object_textures = self.textures.for_object(ctx, &t.textures, &t.loc, warnings)?;
        if uvs.is_none() && uses_image(self.textures, &object_textures) {
            ctx.warn(warnings, &t.loc, "an image texture is applied but <TexCoordData> has no entry for its vertices; it is sampled at the barycentric coordinates");
        }
        let geom = Arc::new(MeshGeom::with_uvs(positions, indices, None, uvs));
        if geom.unplaced() > 0 {
            ctx.warn(warnings, &t.loc, unplaced_message(1, 1, false));
        }
        let instance = Instance {
            shape: Shape::Mesh { mesh, smooth: false },
            material,
            transform: ctx.make_transform(world, &t.loc)?,
            motion: motion(t.motion_blur),
            textures: object_textures,
        };
        Ok(Some((geom, instance)))
    }

    pub(super) fn sphere(&self, s: &SphereRec, warnings: &mut Vec<Warning>) -> Result<Instance, SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let material = ctx.material(self.mat_ids, &s.material, &s.loc)?;
        let c = ctx.vertex(s.center, &s.loc, "<Center>")?;
        if !(s.radius > 0.0 && s.radius.is_finite()) {
            return Err(ctx.err(&s.loc, format!("<Radius> must be a positive number, found {}", s.radius)));
        }
        let world = ctx.transform(self.transforms, &s.transforms, &s.loc)?;
        let (center, textures) =
            (v3(rec.vertices[c as usize]), self.textures.for_object(ctx, &s.textures, &s.loc, warnings)?);
        let motion = motion(s.motion_blur);
        // An untextured, unmoving sphere under a similarity is a world-space sphere: the ray
        // is tested directly instead of being carried into object space first. (Textures keep
        // the transform: their coordinates and solid noise live in object space.)
        if textures == ObjectTextures::default()
            && motion.is_none()
            && let Some(scale) = crate::math::uniform_scale(&world.matrix3)
            && world != DAffine3::IDENTITY
        {
            return Ok(Instance {
                shape: Shape::Sphere { center: world.transform_point3(center), radius: s.radius * scale },
                material,
                transform: None,
                motion,
                textures,
            });
        }
        Ok(Instance {
            shape: Shape::Sphere { center, radius: s.radius },
            material,
            transform: ctx.make_transform(world, &s.loc)?,
            motion,
            textures,
        })
    }

    pub(super) fn plane(&self, p: &PlaneRec, warnings: &mut Vec<Warning>) -> Result<Instance, SceneError> {
        let (ctx, rec) = (self.ctx, self.ctx.rec);
        let material = ctx.material(self.mat_ids, &p.material, &p.loc)?;
        let point = ctx.vertex(p.point, &p.loc, "<Point>")?;
        let normal = v3(p.normal).normalize_or_zero();
        if normal == DVec3::ZERO || !normal.is_finite() {
            return Err(ctx.err(&p.loc, "<Normal> must be a non-zero direction"));
        }
        let world = ctx.transform(self.transforms, &p.transforms, &p.loc)?;
        Ok(Instance {
            shape: Shape::Plane { point: v3(rec.vertices[point as usize]), normal },
            material,
            transform: ctx.make_transform(world, &p.loc)?,
            motion: motion(p.motion_blur),
            textures: self.textures.for_object(ctx, &p.textures, &p.loc, warnings)?,
        })
    }
}

/// An emitting object found by [`Objects::place`].
pub(super) struct Emitter {
    pub(super) instance: u32,
    pub(super) radiance: DVec3,
    pub(super) loc: Loc,
}

/// Step 7: the object lights (§13.3), each a world-space copy of its surface for sampling, and
/// the radiance of every instance by index (`None` for objects that do not emit). A light with
/// no area (every triangle degenerate) still shows where it is seen but lights nothing, with a
/// warning.
pub(super) fn object_lights(
    ctx: &Ctx,
    accel: &Accel,
    emitters: &[Emitter],
    warnings: &mut Vec<Warning>,
) -> (Vec<ObjectLight>, Vec<Option<DVec3>>, Vec<u32>) {
    let mut emission = vec![None; if emitters.is_empty() { 0 } else { accel.instances.len() }];
    let mut light_of = vec![u32::MAX; emission.len()];
    let mut lights = Vec::with_capacity(emitters.len());
    for e in emitters {
        emission[e.instance as usize] = Some(e.radiance);
        if e.radiance == DVec3::ZERO {
            continue;
        }
        let inst = &accel.instances[e.instance as usize];
        let to_world = inst.transform.as_ref().map(|t| t.to_world);
        let light = match &inst.shape {
            Shape::Mesh { mesh, .. } => {
                let g = &accel.meshes[*mesh as usize];
                let place = |p: DVec3| to_world.map_or(p, |m| m.transform_point3(p));
                let tris = g.indices.iter().map(|t| t.map(|k| place(g.positions[k as usize]))).collect();
                ObjectLight::triangles(tris, e.radiance, e.instance)
            }
            Shape::Sphere { center, radius } => {
                Some(ObjectLight::sphere(*center, *radius, to_world, e.radiance, e.instance))
            }
            Shape::Plane { .. } => None,
        };
        match light {
            Some(l) => {
                light_of[e.instance as usize] = lights.len() as u32;
                lights.push(l);
            }
            None => ctx.warn(warnings, &e.loc, "the light has no area; it is visible but lights nothing"),
        }
    }
    (lights, emission, light_of)
}

/// An object's `<MotionBlur>` velocity; none when absent or zero.
pub(super) fn motion(motion_blur: Option<Vec3>) -> Option<DVec3> {
    motion_blur.map(v3).filter(|v| *v != DVec3::ZERO)
}
