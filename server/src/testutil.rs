//! What the in-process tests share: a temporary data directory, a store in it, a tiny scene.

use tessera_testkit::TempDir;

use crate::db::Store;

/// A job store on a real SQLite file in a directory of its own.
pub fn store(tag: &str) -> (TempDir, Store) {
    let dir = TempDir::new(&format!("unit-{tag}"));
    let store = Store::open(&dir.path().join("tessera.db")).unwrap();
    (dir, store)
}

/// A scene of one sphere, `w` x `h` pixels, with nothing to load.
pub fn tiny_scene(w: u32, h: u32) -> Vec<u8> {
    format!(
        r#"<Scene><Cameras><Camera id="1"><Position>0 0 0</Position><Gaze>0 0 -1</Gaze><Up>0 1 0</Up>
<NearPlane>-1 1 -1 1</NearPlane><NearDistance>1</NearDistance><ImageResolution>{w} {h}</ImageResolution>
<ImageName>tiny.png</ImageName></Camera></Cameras><Materials><Material id="1"><DiffuseReflectance>1 1 1</DiffuseReflectance></Material></Materials>
<VertexData>0 0 -5</VertexData><Objects><Sphere id="1"><Material>1</Material><Center>1</Center><Radius>1</Radius></Sphere></Objects></Scene>"#
    )
    .into_bytes()
}
