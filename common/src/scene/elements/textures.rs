//! The rules of `<Textures>` (images, 2020 texture maps, 2019 textures and `<BackgroundTexture>`)
//! and of the texture ids an object names.

use crate::scene::records::{
    DecalMode, ImageRec, Interpolation, NoiseConversion, TextureMapRec, TextureSource,
};
use crate::scene::tree::{BOOLEANS, Node, Parser, Result, Schema, excerpt, one_of, quoted};

// --- textures (HW4, scene-format.md §11) ---

const TEXTURES: Schema = Schema { many: &["Images", "TextureMap", "Texture"], ..Schema::EMPTY };
const IMAGES: Schema = Schema { many: &["Image"], ..Schema::EMPTY };
const IMAGE: Schema = Schema { attrs: &["id"], ..Schema::EMPTY };
const TEXTURE_MAP_ATTRS: &[&str] = &["id", "type", "degamma"];
const IMAGE_MAP: Schema = Schema {
    single: &["DecalMode", "ImageId", "Interpolation", "Normalizer", "BumpFactor"],
    attrs: TEXTURE_MAP_ATTRS,
    inapplicable: &[
        "NoiseConversion",
        "NoiseScale",
        "NumOctaves",
        "BlackColor",
        "WhiteColor",
        "Scale",
        "Offset",
    ],
    inapplicable_why: "does not apply to image texture maps",
    ..Schema::EMPTY
};
const PERLIN_MAP: Schema = Schema {
    // `NumOctaves` (2025: a fractal sum of octaves) is read by `Parser::num_octaves`.
    single: &["DecalMode", "NoiseConversion", "NoiseScale", "BumpFactor", "NumOctaves"],
    attrs: TEXTURE_MAP_ATTRS,
    inapplicable: &["ImageId", "Interpolation", "Normalizer", "BlackColor", "WhiteColor", "Scale", "Offset"],
    inapplicable_why: "does not apply to perlin texture maps",
    ..Schema::EMPTY
};
const CHECKERBOARD_MAP: Schema = Schema {
    single: &["DecalMode", "BlackColor", "WhiteColor", "Scale", "Offset", "BumpFactor"],
    attrs: TEXTURE_MAP_ATTRS,
    inapplicable: &["ImageId", "Interpolation", "Normalizer", "NoiseConversion", "NoiseScale", "NumOctaves"],
    inapplicable_why: "does not apply to checkerboard texture maps",
    ..Schema::EMPTY
};
/// 2019 `<Texture>` (§11.11); which children apply depends on `ImageName`.
const LEGACY_TEXTURE_ATTRS: &[&str] = &["id", "bumpmap", "bumpmapMultiplier", "degamma"];
const LEGACY_IMAGE_TEXTURE: Schema = Schema {
    single: &["ImageName", "DecalMode", "Interpolation", "Normalizer", "Appearance"],
    attrs: LEGACY_TEXTURE_ATTRS,
    inapplicable: &["ScalingFactor", "Offset", "BlackColor", "WhiteColor", "Dimension3"],
    inapplicable_why: "does not apply to image textures",
    ..Schema::EMPTY
};
const LEGACY_PERLIN_TEXTURE: Schema = Schema {
    single: &["ImageName", "DecalMode", "Normalizer", "Appearance", "ScalingFactor"],
    attrs: LEGACY_TEXTURE_ATTRS,
    inapplicable: &["Interpolation", "Offset", "BlackColor", "WhiteColor", "Dimension3"],
    inapplicable_why: "does not apply to perlin textures",
    ..Schema::EMPTY
};
// `Dimension3` false: a 2-D checkerboard in the texture coordinates.
const LEGACY_CHECKERBOARD_TEXTURE: Schema = Schema {
    single: &[
        "ImageName",
        "DecalMode",
        "Normalizer",
        "ScalingFactor",
        "Offset",
        "BlackColor",
        "WhiteColor",
        "Dimension3",
    ],
    attrs: LEGACY_TEXTURE_ATTRS,
    inapplicable: &["Interpolation", "Appearance"],
    inapplicable_why: "does not apply to checkerboard textures",
    ..Schema::EMPTY
};

const DECAL_MODES: &[(&str, DecalMode)] = &[
    ("replace_kd", DecalMode::ReplaceKd),
    ("blend_kd", DecalMode::BlendKd),
    ("replace_ks", DecalMode::ReplaceKs),
    ("replace_all", DecalMode::ReplaceAll),
    ("replace_normal", DecalMode::ReplaceNormal),
    ("bump_normal", DecalMode::BumpNormal),
    ("replace_background", DecalMode::ReplaceBackground),
];
/// 2019 files: the 2020 names plus the short spellings of the 2019 assignment text.
static LEGACY_DECAL_MODES: std::sync::LazyLock<Vec<(&str, DecalMode)>> = std::sync::LazyLock::new(|| {
    let mut modes = DECAL_MODES.to_vec();
    modes.extend([("replace", DecalMode::ReplaceKd), ("blend", DecalMode::BlendKd)]);
    modes
});
const INTERPOLATIONS: &[(&str, Interpolation)] = &[
    ("nearest", Interpolation::Nearest),
    ("bilinear", Interpolation::Bilinear),
    ("trilinear", Interpolation::Trilinear),
];
const NOISE_CONVERSIONS: &[(&str, NoiseConversion)] =
    &[("linear", NoiseConversion::Linear), ("absval", NoiseConversion::AbsVal)];
/// 2019 `<Appearance>` of perlin textures.
const LEGACY_PERLIN_APPEARANCES: &[(&str, NoiseConversion)] =
    &[("patch", NoiseConversion::Linear), ("vein", NoiseConversion::AbsVal)];
/// Most octaves a perlin map's `<NumOctaves>` may ask for: octave 31 is already 2^-30 of the
/// first, far below any display's resolution.
const MAX_OCTAVES: u32 = 32;
/// 2019 `<Appearance>` of image textures: is it `clamp`?
const LEGACY_IMAGE_APPEARANCES: &[(&str, bool)] = &[("repeat", false), ("clamp", true)];

/// Image and texture-map id of a 2019 `<BackgroundTexture>`.
const BACKGROUND_TEXTURE_ID: &str = "2019:background";

#[derive(Clone, Copy)]
enum MapKind {
    Image,
    Perlin,
    Checkerboard,
}

impl Parser<'_> {
    /// A scene-level `<Textures>` block: 2020 `Images` and `TextureMap`s, 2019 `Texture`s.
    pub(super) fn textures(&mut self, block: &Node) -> Result<()> {
        self.check(block, &TEXTURES);
        for child in &block.children {
            match child.name.as_str() {
                "Images" => {
                    self.check(child, &IMAGES);
                    for image in child.children_named("Image") {
                        self.check(image, &IMAGE);
                        let rec = ImageRec {
                            id: self.id(image, true)?,
                            loc: image.loc(),
                            path: self.text(image, "an image file path")?.to_string(),
                        };
                        self.out.images.push(rec);
                    }
                }
                "TextureMap" => {
                    let map = self.texture_map(child)?;
                    self.out.texture_maps.push(map);
                }
                "Texture" => self.legacy_texture(child)?,
                _ => {}
            }
        }
        Ok(())
    }

    /// The required `<DecalMode>` of a 2020 texture map.
    pub(super) fn decal_mode(&self, n: &Node) -> Result<DecalMode> {
        match n.child("DecalMode") {
            Some(d) => self.keyword(d, DECAL_MODES),
            None => Err(self.err(
                n,
                format!("missing <DecalMode> (how the texture changes the surface: {})", one_of(DECAL_MODES)),
            )),
        }
    }

    /// A 2020 `<TextureMap>` (scene-format.md §11).
    pub(super) fn texture_map(&mut self, n: &Node) -> Result<TextureMapRec> {
        const TYPES: &[(&str, MapKind)] = &[
            ("image", MapKind::Image),
            ("perlin", MapKind::Perlin),
            ("checkerboard", MapKind::Checkerboard),
        ];
        let kind = match n.attr("type").map(str::trim) {
            None => {
                return Err(self.err(n, format!("missing attribute type ({})", one_of(TYPES))));
            }
            Some(t) => match TYPES.iter().find(|(name, _)| *name == t) {
                Some(&(_, kind)) => kind,
                None => {
                    return Err(self.err(
                        n,
                        format!("attribute type must be {}, found \"{}\"", one_of(TYPES), excerpt(t)),
                    ));
                }
            },
        };
        self.check(
            n,
            match kind {
                MapKind::Image => &IMAGE_MAP,
                MapKind::Perlin => &PERLIN_MAP,
                MapKind::Checkerboard => &CHECKERBOARD_MAP,
            },
        );
        let id = self.id(n, true)?;
        let decal = self.decal_mode(n)?;
        let source = match kind {
            MapKind::Image => {
                let image = n.child("ImageId").ok_or_else(|| {
                    self.err(n, "missing <ImageId> (the id of an <Image> in <Textures> / <Images>)")
                })?;
                TextureSource::Image {
                    image: self.id_ref(image, "an image id")?,
                    interpolation: self
                        .optional_keyword(n, "Interpolation", INTERPOLATIONS)?
                        // Absent means nearest: measured against the references (sphere_nearest_bilinear,
                        // cube_waves, cube_cushion, sphere_normal match only this way).
                        .unwrap_or(Interpolation::Nearest),
                    normalizer: self.normalizer(n)?.unwrap_or(255.0),
                    clamp: false,
                }
            }
            MapKind::Perlin => TextureSource::Perlin {
                conversion: self
                    .optional_keyword(n, "NoiseConversion", NOISE_CONVERSIONS)?
                    .unwrap_or(NoiseConversion::Linear),
                scale: self.optional_number(n, "NoiseScale")?.unwrap_or(1.0),
                octaves: self.num_octaves(n)?,
            },
            MapKind::Checkerboard => TextureSource::Checkerboard {
                black: self.optional_numbers(n, "BlackColor")?.unwrap_or([0.0; 3]),
                white: self.optional_numbers(n, "WhiteColor")?.unwrap_or([1.0; 3]),
                scale: self.optional_number(n, "Scale")?.unwrap_or(1.0),
                offset: self.optional_number(n, "Offset")?.unwrap_or(0.0),
                dimension3: true,
            },
        };
        Ok(TextureMapRec {
            id,
            loc: n.loc(),
            source,
            decal,
            bump_factor: self.optional_number(n, "BumpFactor")?.unwrap_or(1.0),
            degamma: self.bool_attr(n, "degamma")?.unwrap_or(false),
        })
    }

    /// A perlin map's `<NumOctaves>` (2025, §11.9: a fractal sum of octaves), 1 to
    /// [`MAX_OCTAVES`]; absent means 1.
    pub(super) fn num_octaves(&mut self, n: &Node) -> Result<u32> {
        let Some(o) = n.child("NumOctaves") else { return Ok(1) };
        let v: u32 = self.number(o)?;
        if !(1..=MAX_OCTAVES).contains(&v) {
            return Err(self.err(
                o,
                format!("<NumOctaves> must be a whole number from 1 to {MAX_OCTAVES} (octaves of the noise), found {v}"),
            ));
        }
        Ok(v)
    }

    /// A 2019 `<Texture>` (scene-format.md §11.11), translated into one texture map, or two
    /// with `bumpmap="true"`: in 2019 such a texture colours the surface *and* bumps it, so a
    /// `bump_normal` map with id `<id>:bump` and `BumpFactor = bumpmapMultiplier` is added and
    /// remembered in `legacy_bumps`. An image file becomes an [`ImageRec`] with id `2019:<id>`.
    pub(super) fn legacy_texture(&mut self, n: &Node) -> Result<()> {
        let id = self.id(n, true)?;
        let name_node = n.child("ImageName").ok_or_else(|| {
            self.err(n, "missing <ImageName> (an image file, or the word perlin or checkerboard)")
        })?;
        let name = self.text(name_node, "an image file, or the word perlin or checkerboard")?;
        let (kind, schema) = match name {
            "perlin" => (MapKind::Perlin, &LEGACY_PERLIN_TEXTURE),
            "checkerboard" => (MapKind::Checkerboard, &LEGACY_CHECKERBOARD_TEXTURE),
            _ => (MapKind::Image, &LEGACY_IMAGE_TEXTURE),
        };
        self.check(n, schema);
        let decal =
            self.optional_keyword(n, "DecalMode", &LEGACY_DECAL_MODES)?.unwrap_or(DecalMode::ReplaceKd);
        let bumpmap = self.bool_attr(n, "bumpmap")?.unwrap_or(false);
        // Read (and checked) even with bumpmap="false", where the 2019 files also write it.
        let multiplier = self.number_attr(n, "bumpmapMultiplier")?.unwrap_or(1.0);
        let degamma = self.bool_attr(n, "degamma")?.unwrap_or(false);
        let source = match kind {
            MapKind::Image => {
                let clamp =
                    self.optional_keyword(n, "Appearance", LEGACY_IMAGE_APPEARANCES)?.unwrap_or(false);
                let image = format!("2019:{id}");
                let path = name.to_string();
                self.out.images.push(ImageRec { id: image.clone(), loc: n.loc(), path });
                TextureSource::Image {
                    image,
                    interpolation: self
                        .optional_keyword(n, "Interpolation", INTERPOLATIONS)?
                        // Absent means nearest: measured against the references (sphere_nearest_bilinear,
                        // cube_waves, cube_cushion, sphere_normal match only this way).
                        .unwrap_or(Interpolation::Nearest),
                    normalizer: self.normalizer(n)?.unwrap_or(255.0),
                    clamp,
                }
            }
            MapKind::Perlin => {
                self.legacy_unused_normalizer(n, "perlin")?;
                TextureSource::Perlin {
                    conversion: self
                        .optional_keyword(n, "Appearance", LEGACY_PERLIN_APPEARANCES)?
                        .unwrap_or(NoiseConversion::Linear),
                    scale: self.optional_number(n, "ScalingFactor")?.unwrap_or(1.0),
                    octaves: 1,
                }
            }
            MapKind::Checkerboard => {
                self.legacy_unused_normalizer(n, "checkerboard")?;
                TextureSource::Checkerboard {
                    black: self.optional_numbers(n, "BlackColor")?.unwrap_or([0.0; 3]),
                    white: self.optional_numbers(n, "WhiteColor")?.unwrap_or([1.0; 3]),
                    scale: self.optional_number(n, "ScalingFactor")?.unwrap_or(1.0),
                    offset: self.optional_number(n, "Offset")?.unwrap_or(0.0),
                    dimension3: self.optional_keyword(n, "Dimension3", BOOLEANS)?.unwrap_or(true),
                }
            }
        };
        let colour = TextureMapRec { id: id.clone(), loc: n.loc(), source, decal, bump_factor: 1.0, degamma };
        let bump = bumpmap.then(|| TextureMapRec {
            id: format!("{id}:bump"),
            decal: DecalMode::BumpNormal,
            bump_factor: multiplier,
            ..colour.clone()
        });
        self.out.texture_maps.push(colour);
        if let Some(bump) = bump {
            self.legacy_bumps.push((id, bump.id.clone()));
            self.out.texture_maps.push(bump);
        }
        Ok(())
    }

    /// The 2019 perlin and checkerboard textures write `<Normalizer>1</Normalizer>`; their
    /// values are used as they are, so anything else is warned about.
    pub(super) fn legacy_unused_normalizer(&mut self, n: &Node, kind: &str) -> Result<()> {
        if let Some(norm) = n.child("Normalizer") {
            let v = self.number::<f64>(norm)?;
            if v != 1.0 {
                self.warn(
                    norm,
                    format!("<Normalizer> has no effect on {kind} textures (their values are used as they are); it is ignored"),
                );
            }
        }
        Ok(())
    }

    /// 2019 `<BackgroundTexture>path</BackgroundTexture>`: a `replace_background` image map
    /// whose texels are used raw (normalizer 1, scene-format.md §11.8).
    pub(super) fn background_texture(&mut self, n: &Node) -> Result<()> {
        self.check_attrs(n, &[], &[]);
        let path = self.text(n, "an image file path")?.to_string();
        let id = BACKGROUND_TEXTURE_ID.to_string();
        self.out.images.push(ImageRec { id: id.clone(), loc: n.loc(), path });
        self.out.texture_maps.push(TextureMapRec {
            id: id.clone(),
            loc: n.loc(),
            source: TextureSource::Image {
                image: id,
                interpolation: Interpolation::Bilinear,
                normalizer: 1.0,
                clamp: false,
            },
            decal: DecalMode::ReplaceBackground,
            bump_factor: 1.0,
            degamma: false,
        });
        Ok(())
    }

    /// An object's texture-map ids: `<Textures>1 2</Textures>`, or the 2019 `<Texture>1</Texture>`.
    /// A reference to a 2019 `bumpmap="true"` texture also names the bump map made for it. A
    /// repeat with the same ids (the cube_* scenes) is accepted silently; one with other ids is
    /// warned about and the first is used.
    pub(super) fn object_textures(&mut self, n: &Node) -> Result<Vec<String>> {
        let name = match (n.child("Textures"), n.child("Texture")) {
            (None, None) => return Ok(Vec::new()),
            (Some(_), Some(t)) => {
                self.warn(t, "<Texture> (the 2019 spelling) is ignored because <Textures> is given");
                "Textures"
            }
            (Some(_), None) => "Textures",
            (None, Some(_)) => "Texture",
        };
        let mut first: Option<&Node> = None;
        for list in n.children_named(name) {
            for grandchild in &list.children {
                self.warn(grandchild, format!("unknown element <{}>; it is ignored", grandchild.name));
            }
            match first {
                None => first = Some(list),
                Some(f) if f.text.split_ascii_whitespace().eq(list.text.split_ascii_whitespace()) => {}
                Some(f) => self.warn(
                    list,
                    format!(
                        "<{name}> is given more than once with different ids; only the first one ({}) is used",
                        quoted(&f.text)
                    ),
                ),
            }
        }
        let Some(list) = first else { return Ok(Vec::new()) };
        let mut ids = Vec::new();
        for id in list.text.split_ascii_whitespace() {
            ids.push(id.to_string());
            if let Some((_, bump)) = self.legacy_bumps.iter().find(|(t, _)| t == id) {
                ids.push(bump.clone());
            }
        }
        Ok(ids)
    }
}
