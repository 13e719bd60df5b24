//! Step 4 of the build: the images texture maps and environment lights use, decoded once each
//! (or taken from the cache), and the maps made from them.

use std::collections::HashMap;
use std::sync::Arc;

use rayon::prelude::*;

use super::context::{Ctx, degamma_exponent};
use crate::error::{Loc, SceneError, Warning};
use crate::geometry::ObjectTextures;
use crate::lights::EnvLight;
use crate::math::v3;
use crate::scene::cache::read_rekeyed;
use crate::scene::records::*;
use crate::texture::image::TextureImage;
use crate::texture::maps::{Source, TextureMap};
use crate::texture::mip::MipChain;

/// Whether an object's maps include an image (which needs texture coordinates).
pub(super) fn uses_image(textures: &BuiltTextures, t: &ObjectTextures) -> bool {
    let more = t.more_colour.map_or(Vec::new(), |i| {
        textures.more_colour.lock().map(|m| m[i as usize].clone()).unwrap_or_default()
    });
    [t.colour[0], t.colour[1], t.normal]
        .into_iter()
        .flatten()
        .chain(more)
        .any(|k| matches!(textures.maps[k as usize].source, Source::Image { .. }))
}

/// Texture maps ready for shading, by position, and how the scene's ids find them.
pub(super) struct BuiltTextures<'a> {
    pub(super) maps: Vec<TextureMap>,
    pub(super) ids: HashMap<&'a str, u32>,
    pub(super) background: Option<u32>,
    pub(super) env_light: Option<EnvLight>,
    pub(super) extra_env_lights: Vec<EnvLight>,
    /// Objects' colour maps after their first two (`ObjectTextures::more_colour`), filled as
    /// objects are placed.
    pub(super) more_colour: std::sync::Mutex<Vec<Vec<u32>>>,
}

/// Step 4: decodes every image a texture map or the environment light uses (each file once, in
/// parallel), builds the maps and the environment light.
pub(super) fn build_textures<'a>(
    ctx: &Ctx<'a>,
    warnings: &mut Vec<Warning>,
) -> Result<BuiltTextures<'a>, SceneError> {
    let rec = ctx.rec;
    let image_recs: HashMap<&str, &ImageRec> = rec.images.iter().rev().map(|i| (i.id.as_str(), i)).collect();
    // The images the maps and the environment light need, each file once, with the first user
    // of each (for messages).
    let mut wanted: Vec<(&ImageRec, String)> = Vec::new();
    let mut want = |img: &'a ImageRec, user: String| {
        if !wanted.iter().any(|(w, _)| w.path == img.path) {
            wanted.push((img, user));
        }
    };
    for m in &rec.texture_maps {
        if let TextureSource::Image { image, .. } = &m.source {
            let img = image_recs.get(image.as_str()).ok_or_else(|| {
                ctx.err(&m.loc, format!("ImageId {image} names no <Image>; add <Image id=\"{image}\"> under <Textures><Images>"))
            })?;
            want(img, format!("texture map {}", m.id));
        }
    }
    for l in &rec.env_lights {
        let img = image_recs.get(l.image.as_str()).ok_or_else(|| {
            ctx.err(
                &l.loc,
                format!("ImageId {} names no <Image>; add <Image id=\"{}\"> with the environment map's path under <Textures><Images>", l.image, l.image),
            )
        })?;
        want(img, format!("environment light {}", l.id).trim_end().to_string());
    }
    // Every environment light's map is decoded once, like the texture maps' images.
    let decoded: Vec<Result<(String, Arc<TextureImage>), SceneError>> = wanted
        .par_iter()
        .map(|(img, user)| {
            let unreadable = |e: std::io::Error| {
                ctx.err(
                    &img.loc,
                    format!(
                        "cannot read image {} (image id {}, used by {user}): {e}; check the path (it is relative to the scene file)",
                        ctx.resolver.display_path(&img.path).display(),
                        img.id
                    ),
                )
            };
            // With a cache: the decoded image of the same content, if it has it.
            let (mut content, read) = match ctx.cache {
                Some(cache) => {
                    let (content, read) = cache.content_key(ctx.resolver, &img.path).map_err(unreadable)?;
                    if let Some(image) = cache.image(&content) {
                        return Ok((img.path.clone(), image));
                    }
                    (Some(content), read)
                }
                None => (None, None),
            };
            let (bytes, found) = match (read, &mut content) {
                (Some(r), _) => r,
                (None, Some(content)) => read_rekeyed(ctx.resolver, &img.path, content).map_err(unreadable)?,
                (None, None) => ctx.resolver.read(&img.path).map_err(unreadable)?,
            };
            let decoded = TextureImage::decode(&bytes).map_err(|e| {
                ctx.err(
                    &img.loc,
                    format!("cannot decode image {} (image id {}, used by {user}): {e}", found.display(), img.id),
                )
            })?;
            let decoded = Arc::new(decoded);
            let decoded = match (ctx.cache, content) {
                (Some(cache), Some(content)) => cache.put_image(&content, decoded),
                _ => decoded,
            };
            Ok((img.path.clone(), decoded))
        })
        .collect();
    let mut by_path: HashMap<String, Arc<TextureImage>> = HashMap::new();
    for d in decoded {
        let (path, img) = d?;
        by_path.insert(path, img);
    }
    // Mip pyramids (§11.5) for the images that trilinear maps read, each built once.
    let mut trilinear_paths: Vec<&str> = Vec::new();
    for m in &rec.texture_maps {
        if let TextureSource::Image { image, interpolation: Interpolation::Trilinear, .. } = &m.source {
            let path = image_recs[image.as_str()].path.as_str();
            if !trilinear_paths.contains(&path) {
                trilinear_paths.push(path);
            }
        }
    }
    let mips: HashMap<&str, Arc<MipChain>> = trilinear_paths
        .par_iter()
        .map(|&path| (path, Arc::new(MipChain::new(by_path[path].clone()))))
        .collect();
    let mut env_lights = rec
        .env_lights
        .iter()
        .map(|l| EnvLight::new(by_path[&image_recs[l.image.as_str()].path].clone(), l.mapping, l.sampler));
    let env_light = env_lights.next();
    let extra_env_lights = env_lights.collect();
    let mut out = BuiltTextures {
        maps: Vec::new(),
        ids: HashMap::new(),
        background: None,
        env_light,
        extra_env_lights,
        more_colour: Default::default(),
    };
    for m in &rec.texture_maps {
        let source = match &m.source {
            TextureSource::Image { image, interpolation, normalizer, clamp } => {
                let path = &image_recs[image.as_str()].path;
                if *normalizer == 0.0 {
                    return Err(ctx.err(&m.loc, "Normalizer must not be 0"));
                }
                Source::Image {
                    image: by_path[path].clone(),
                    mips: match interpolation {
                        Interpolation::Trilinear => mips.get(path.as_str()).cloned(),
                        _ => None,
                    },
                    interpolation: *interpolation,
                    normalizer: *normalizer,
                    clamp: *clamp,
                }
            }
            TextureSource::Perlin { conversion, scale, octaves } => {
                Source::Perlin { conversion: *conversion, scale: *scale, octaves: *octaves }
            }
            TextureSource::Checkerboard { black, white, scale, offset, dimension3 } => Source::Checkerboard {
                black: v3(*black),
                white: v3(*white),
                scale: *scale,
                offset: *offset,
                dimension3: *dimension3,
            },
        };
        if out.ids.contains_key(m.id.as_str()) {
            ctx.warn(
                warnings,
                &m.loc,
                format!("texture map id \"{}\" is defined again; references use the first definition", m.id),
            );
        } else {
            out.ids.insert(m.id.as_str(), out.maps.len() as u32);
        }
        if m.decal == DecalMode::ReplaceBackground && out.background.is_none() {
            out.background = Some(out.maps.len() as u32);
        }
        out.maps.push(TextureMap {
            source,
            decal: m.decal,
            bump_factor: m.bump_factor,
            degamma: m.degamma.then_some(degamma_exponent(rec)),
        });
    }
    Ok(out)
}

impl BuiltTextures<'_> {
    /// Sorts an object's `<Textures>` ids into its colour maps, applied in the order given, and
    /// its normal map, the last one given (§11.1).
    pub(super) fn for_object(
        &self,
        ctx: &Ctx,
        ids: &[String],
        loc: &Loc,
        warnings: &mut Vec<Warning>,
    ) -> Result<ObjectTextures, SceneError> {
        let mut t = ObjectTextures::default();
        let mut colour = Vec::new();
        for id in ids {
            let k = *self.ids.get(id.as_str()).ok_or_else(|| {
                ctx.err(
                    loc,
                    format!("texture \"{id}\" is not defined; add <TextureMap id=\"{id}\"> under <Textures>"),
                )
            })?;
            match self.maps[k as usize].decal {
                // The last normal or bump map wins (the course material has no object with two).
                DecalMode::ReplaceNormal | DecalMode::BumpNormal => t.normal = Some(k),
                DecalMode::ReplaceBackground => {
                    ctx.warn(warnings, loc, format!("texture {id} is a replace_background map; it applies to the background, not to this object"));
                }
                _ => colour.push(k),
            }
        }
        for (slot, &k) in t.colour.iter_mut().zip(&colour) {
            *slot = Some(k);
        }
        if colour.len() > 2 {
            let mut more =
                self.more_colour.lock().map_err(|_| ctx.err(loc, "internal: texture lists poisoned"))?;
            t.more_colour = Some(more.len() as u32);
            more.push(colour[2..].to_vec());
        }
        Ok(t)
    }
}
