//! The decoder of tiles uploaded by workers: the first two bytes choose the pixel count the
//! lease expects, the rest is the body.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let pixels = usize::from(u16::from_le_bytes([data[0], data[1]]));
    let body = &data[2..];
    let _ = tessera::protocol::checksum(body);
    if let Some(px) = tessera::protocol::decode_tile(body, pixels) {
        assert_eq!(px.len(), pixels);
        assert_eq!(tessera::protocol::encode_tile(&px), body);
    }
});
