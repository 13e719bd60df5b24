//! The XML front end and the scene builder on arbitrary text: any input gives records or a
//! `SceneError`, never a panic, a hang or an allocation out of proportion to the input.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let path = std::path::Path::new("fuzz.xml");
    if let Ok(records) = tessera::scene::xml::parse_xml(text, path) {
        let resolver = tessera::assets::MemResolver::for_scene(Default::default(), "fuzz.xml");
        let _ = tessera::scene::build::build_scene(&records, &resolver);
    }
});
