//! What the in-process tests share: a temporary data directory and a store in it.

use tessera_testkit::TempDir;

use crate::db::Store;

/// A job store on a real SQLite file in a directory of its own.
pub fn store(tag: &str) -> (TempDir, Store) {
    let dir = TempDir::new(&format!("unit-{tag}"));
    let store = Store::open(&dir.path().join("tessera.db")).unwrap();
    (dir, store)
}

/// A job of `frames` named "j", one-pixel tiles, a bundle of zeros and the store's defaults
/// for every option; tests change what they test with `NewJob { .., ..job_of(frames) }`.
pub fn job_of(frames: Vec<crate::db::NewFrame>) -> crate::db::NewJob {
    crate::db::NewJob {
        name: "j".into(),
        tile_size: 1,
        bundle: "0".repeat(64),
        scene_path: "scene.xml".into(),
        frames,
        ..Default::default()
    }
}

/// A frame `name` of `width` x `height` pixels as one tile of one sample.
pub fn frame(name: &str, width: u32, height: u32) -> crate::db::NewFrame {
    crate::db::NewFrame {
        image_name: name.into(),
        width,
        height,
        tiles: vec![tessera::protocol::Rect { x0: 0, y0: 0, width, height }],
        samples: 1,
        pass_samples: 16,
        ..Default::default()
    }
}

/// A frame `name` of `width` x 1 pixels, a one-pixel tile each, of `samples` samples (in passes
/// of 16).
pub fn row_of_pixels(name: &str, width: u32, samples: u32) -> crate::db::NewFrame {
    crate::db::NewFrame {
        tiles: (0..width).map(|x| tessera::protocol::Rect { x0: x, y0: 0, width: 1, height: 1 }).collect(),
        samples,
        ..frame(name, width, 1)
    }
}
