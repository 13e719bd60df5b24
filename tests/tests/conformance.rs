//! The CI rows of the conformance table (tests/conformance/thresholds.tsv): each rendered image
//! must meet its thresholds against the course's official reference.

use tessera_testkit::TempDir;
use tessera_tests::conformance::{load_table, render_rows, summary_line};

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
    let results = render_rows(&rows, &out, &|line| println!("{line}"));
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
