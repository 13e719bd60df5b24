//! The CI rows of the conformance table (tests/conformance/thresholds.tsv): each rendered image
//! must meet its thresholds against the course's official reference.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

use tessera_tests::conformance::{load_table, render_rows, summary_line};

/// A scratch directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("tessera-{tag}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn ci_rows_meet_their_thresholds() {
    let corpus = tessera_tests::shared_scenes();
    if !tessera_tests::corpus_has(&corpus.join("xml")) {
        return;
    }
    let rows: Vec<_> = load_table().expect("conformance table").into_iter().filter(|r| r.ci).collect();
    assert!(!rows.is_empty(), "the conformance table has no ci rows");

    let out = TempDir::new("conformance");
    // render_rows logs summary_line(row) for each row as it finishes.
    let results = render_rows(&rows, &out.0, &|line| println!("{line}"));
    assert_eq!(results.len(), rows.len());
    let failing: Vec<String> = results.iter().filter(|r| !r.passed()).map(summary_line).collect();
    assert!(
        failing.is_empty(),
        "{} of {} ci rows fail:\n{}",
        failing.len(),
        results.len(),
        failing.join("\n")
    );
}
