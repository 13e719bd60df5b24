//! The server's reading of uploaded archives (tar, tar.gz, zip) into bundle files.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut files = Default::default();
    if tessera_server::bundle::add_archive(&mut files, data).is_ok() {
        let _ = tessera_server::bundle::find_scene(&files, None);
    }
});
