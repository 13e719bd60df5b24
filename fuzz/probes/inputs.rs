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

/// The decoder of a pass's result uploaded by a worker (block sums, then maybe features): the
/// first byte is the pixel count the lease expects, the next four (little-endian) the blocks of
/// samples the pass covers, the rest the body. What it accepts is whole pixels whose sums are
/// within the pass's limit (`i128::MIN` included in what it must refuse), re-encodes to itself,
/// and adds up over every block a pixel can have without overflow.
#[allow(dead_code)]
pub fn pass_upload(data: &[u8]) {
    use tessera::passes::{MAX_PIXEL_BLOCKS, PIXEL_SUM_BYTES, decode_pass_result, encode_sums, sum_limit};
    if data.len() < 5 {
        return;
    }
    let pixels = usize::from(data[0]);
    let blocks = u32::from_le_bytes([data[1], data[2], data[3], data[4]]);
    let body = &data[5..];
    let Ok((sums, rest)) = decode_pass_result(body, pixels, blocks) else { return };
    assert_eq!(sums.len(), pixels);
    assert_eq!(body.len(), pixels * PIXEL_SUM_BYTES + rest.len());
    assert!(rest.is_empty() || rest.len() == pixels * 24);
    assert_eq!([encode_sums(&sums).as_slice(), rest].concat(), body);
    let limit = sum_limit(blocks);
    assert!(limit <= 1 << 126);
    let passes = u128::from(MAX_PIXEL_BLOCKS / blocks.clamp(1, MAX_PIXEL_BLOCKS));
    for s in &sums {
        for v in s.rgb.iter().chain([&s.odd_luminance]) {
            assert!(v.unsigned_abs() <= limit, "{v} is past {limit}");
            assert!(v.unsigned_abs() * passes <= i128::MAX as u128, "{v} x {passes} passes overflows");
        }
        let _ = s.film(blocks.saturating_mul(tessera::passes::BLOCK));
        // As many passes like this one as a pixel's blocks hold add up without overflow.
        if passes >= 2 {
            let mut twice = *s;
            twice.add(s);
        }
    }
    let _ = tessera::passes::tile_error(&sums, 64);
    // The features after the sums, as the server checks them.
    if let Some(px) = tessera::protocol::decode_tile(rest, rest.len() / 12) {
        let all_finite = px.iter().flatten().all(|v| v.is_finite());
        assert_eq!(tessera::protocol::check_tile_values(&px).is_ok(), all_finite);
    }
}
