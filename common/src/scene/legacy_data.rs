//! The 2019 scene data the build reads before anything else (scene-format.md §3, §8.2, §8.4):
//! `binaryFile` vertices, texture coordinates and faces, read from their files through the
//! asset resolver, and `ZeroBasedIndexing` vertex ids made 1-based, so the rest of the build
//! sees 2020 records.

use std::borrow::Cow;

use super::records::{BinaryFileRec, FacesRec, SceneRecords};
use crate::assets::AssetResolver;
use crate::error::{Loc, SceneError};

/// Step 0: the 2019 forms the rest of the build reads as 2020 ones (§8.2, §8.4): `binaryFile`
/// vertices, texture coordinates and faces read from their files, and the vertex ids of a
/// `ZeroBasedIndexing` scene (faces and `Triangle` `Indices`) made 1-based. Borrowed when the
/// scene has none of them.
pub fn legacy_data<'r>(
    rec: &'r SceneRecords,
    resolver: &dyn AssetResolver,
) -> Result<Cow<'r, SceneRecords>, SceneError> {
    let binary_faces = rec.meshes.iter().any(|m| matches!(m.faces, FacesRec::Binary { .. }));
    if !(rec.zero_based_indexing || rec.vertex_file.is_some() || rec.tex_coord_file.is_some() || binary_faces)
    {
        return Ok(Cow::Borrowed(rec));
    }
    let mut out = rec.clone();
    let read =
        |f: &BinaryFileRec, per: usize, what: &str| read_binary(rec, resolver, &f.path, &f.loc, per, what);
    if let Some(f) = &rec.vertex_file {
        let words = read(f, 3, "vertices of 3 float32")?;
        out.vertices =
            words.chunks_exact(3).map(|c| [0, 1, 2].map(|k| f64::from(f32::from_bits(c[k])))).collect();
    }
    if let Some(f) = &rec.tex_coord_file {
        let words = read(f, 2, "texture coordinates of 2 float32")?;
        out.tex_coords =
            words.chunks_exact(2).map(|c| [0, 1].map(|k| f64::from(f32::from_bits(c[k])))).collect();
    }
    for m in &mut out.meshes {
        if let FacesRec::Binary { path, vertex_offset, texture_offset } = &m.faces {
            let f = BinaryFileRec { path: path.clone(), loc: m.faces_loc.clone() };
            let words = read(&f, 3, "triangles of 3 int32 vertex ids")?;
            let indices = words.iter().map(|&w| i64::from(w as i32)).collect();
            m.faces =
                FacesRec::Inline { indices, vertex_offset: *vertex_offset, texture_offset: *texture_offset };
        }
    }
    if rec.zero_based_indexing {
        for m in &mut out.meshes {
            if let FacesRec::Inline { indices, .. } = &mut m.faces {
                indices.iter_mut().for_each(|i| *i = i.saturating_add(1));
            }
        }
        for t in &mut out.triangles {
            t.indices.iter_mut().for_each(|i| *i = i.saturating_add(1));
        }
    }
    Ok(Cow::Owned(out))
}

/// The records of a 2019 binary file: little-endian `int32 N`, then `N` records of `per`
/// 32-bit words, returned as raw words.
fn read_binary(
    rec: &SceneRecords,
    resolver: &dyn AssetResolver,
    path: &str,
    loc: &Loc,
    per: usize,
    what: &str,
) -> Result<Vec<u32>, SceneError> {
    let shown = resolver.display_path(path);
    let err = |msg: String| SceneError::new(&rec.source, loc.clone(), msg);
    let (bytes, _) = resolver.read(path).map_err(|e| {
        err(format!(
            "cannot read binary file {}: {e}; check the binaryFile path (it is relative to the scene file)",
            shown.display()
        ))
    })?;
    let Some(head) = bytes.get(..4) else {
        return Err(err(format!(
            "binary file {} is {} bytes, too short for its int32 count of {what}",
            shown.display(),
            bytes.len()
        )));
    };
    let count = i32::from_le_bytes([head[0], head[1], head[2], head[3]]);
    let needed =
        usize::try_from(count).ok().and_then(|n| n.checked_mul(per * 4)).and_then(|b| b.checked_add(4));
    match needed {
        Some(needed) if needed <= bytes.len() => Ok(bytes[4..needed]
            .chunks_exact(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()),
        _ => Err(err(format!(
            "binary file {} says it holds {count} {what}, but it is {} bytes long; it is truncated or not a 2019 binary file",
            shown.display(),
            bytes.len()
        ))),
    }
}
