//! What the fuzz targets for other inputs do with them (included by path by the targets and by
//! the replay test, tests/tests/fuzz_regressions.rs).

/// The PLY reader (ASCII and binary, both byte orders).
#[allow(dead_code)]
pub fn ply(data: &[u8]) {
    let _ = tessera::ply::parse_ply(data);
}

/// The texture decoders (PNG, JPEG, OpenEXR, Radiance HDR, chosen by content), and a lookup in
/// whatever decodes.
#[allow(dead_code)]
pub fn texture_image(data: &[u8]) {
    if let Ok(img) = tessera::texture::image::TextureImage::decode(data) {
        let _ = img.bilinear(0.37, 0.81);
        let _ = img.nearest(0.99, 0.0);
    }
}

/// The server's reading of uploaded archives (tar, tar.gz, zip) into bundle files.
#[allow(dead_code)]
pub fn bundle(data: &[u8]) {
    let mut files = Default::default();
    if tessera_server::bundle::add_archive(&mut files, data).is_ok() {
        let _ = tessera_server::bundle::find_scene(&files, None);
        // What the unpacker accepts, the server packs into its canonical tar (where a member
        // name holding a NUL byte used to panic), and that tar reads back as the same files.
        let tar = tessera_server::bundle::canonical_tar(&files).expect("accepted files pack");
        let back = tessera::bundle::read_tar(&tar).expect("the canonical tar reads back");
        assert_eq!(back.len(), files.len());
        for (path, bytes) in &files {
            assert_eq!(back[path].as_slice(), bytes.as_slice(), "{path:?}");
        }
    }
}

/// The decoder of tiles uploaded by workers: the first two bytes choose the pixel count the
/// lease expects, the rest is the body. A body that decodes re-encodes to itself.
#[allow(dead_code)]
pub fn tile_upload(data: &[u8]) {
    if data.len() < 2 {
        return;
    }
    let pixels = usize::from(u16::from_le_bytes([data[0], data[1]]));
    let body = &data[2..];
    let _ = tessera::protocol::checksum(body);
    if let Some(px) = tessera::protocol::decode_tile(body, pixels) {
        assert_eq!(px.len(), pixels);
        assert_eq!(tessera::protocol::encode_tile(&px), body);
        // The server stores a tile only when every value is finite.
        let all_finite = px.iter().flatten().all(|v| v.is_finite());
        assert_eq!(tessera::protocol::check_tile_values(&px).is_ok(), all_finite);
    }
}
