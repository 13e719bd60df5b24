//! What the in-process tests share: a temporary data directory and a store in it.

use tessera_testkit::TempDir;

use crate::db::Store;

/// A job store on a real SQLite file in a directory of its own.
pub fn store(tag: &str) -> (TempDir, Store) {
    let dir = TempDir::new(&format!("unit-{tag}"));
    let store = Store::open(&dir.path().join("tessera.db")).unwrap();
    (dir, store)
}
