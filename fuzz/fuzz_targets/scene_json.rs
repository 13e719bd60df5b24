//! The 2025 JSON front end and the scene builder on arbitrary text.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = std::path::Path::new("fuzz.json");
    if let Ok(records) = tessera::scene::json::parse_json(text, path) {
        let resolver = tessera::assets::MemResolver::for_scene(Default::default(), "fuzz.json");
        let _ = tessera::scene::build::build_scene(&records, &resolver);
    }
});
