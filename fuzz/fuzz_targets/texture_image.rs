//! The texture decoders (PNG, JPEG, OpenEXR, Radiance HDR, chosen by content) on arbitrary
//! bytes, and a lookup in whatever decodes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use tessera::texture::image::TextureImage;

fuzz_target!(|data: &[u8]| {
    if let Ok(img) = TextureImage::decode(data) {
        let _ = img.bilinear(0.37, 0.81);
        let _ = img.nearest(0.99, 0.0);
    }
});
