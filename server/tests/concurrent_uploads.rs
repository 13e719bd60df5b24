//! A class submitting just before a deadline (issue #20), with the real binaries: hundreds of
//! uploads at the same moment, most of them byte-identical (one content address), the rest a
//! handful of different scenes. Every answer must be a 201 and every job must finish; before the
//! stores wrote each file through a temporary file of its own, identical uploads raced on one
//! temporary name and about one in a hundred answered 500.

mod support;

use std::sync::{Arc, Barrier};

use support::*;

/// The demo Cornell box at `size` x `size` pixels: a different size is a different bundle.
fn cornell(size: u32) -> Vec<u8> {
    let text = std::fs::read_to_string(repo().join("scenes/cornell_box.xml")).unwrap();
    assert!(text.contains("<ImageResolution>512 512</ImageResolution>"));
    text.replace(
        "<ImageResolution>512 512</ImageResolution>",
        &format!("<ImageResolution>{size} {size}</ImageResolution>"),
    )
    .into_bytes()
}

#[test]
fn hundreds_of_identical_and_different_uploads_at_once_are_all_accepted_and_rendered() {
    let _s = serial();
    let data = TempDir::new("farm-concurrent-uploads");
    let server = Server::start(&data, &["--local-workers", "1", "--local-worker-threads", "1"]);

    const SAME: usize = 200;
    const DIFFERENT: usize = 5;
    const EACH: usize = 8;
    let same = Arc::new(cornell(16));
    let mut plan: Vec<Arc<Vec<u8>>> = vec![same; SAME];
    for k in 0..DIFFERENT {
        let scene = Arc::new(cornell(8 + k as u32));
        plan.extend(std::iter::repeat_n(scene, EACH));
    }

    // Every submitter waits at the barrier, then all send at once.
    let barrier = Arc::new(Barrier::new(plan.len()));
    let threads: Vec<_> = plan
        .into_iter()
        .map(|scene| {
            let url = server.url.clone();
            let barrier = barrier.clone();
            std::thread::spawn(move || {
                barrier.wait();
                submit(&url, None, &[("scene", Some("cornell_box.xml"), &scene[..]), ("samples", None, b"1")])
            })
        })
        .collect();
    let answers: Vec<(u16, serde_json::Value)> = threads.into_iter().map(|t| t.join().unwrap()).collect();

    let refused: Vec<_> = answers.iter().filter(|(code, _)| *code != 201).collect();
    assert!(
        refused.is_empty(),
        "{} of {} uploads were not accepted, e.g. {:?}\n--- server log ---\n{}",
        refused.len(),
        answers.len(),
        refused.first(),
        server.log()
    );
    assert!(!server.log().contains("internal error"), "{}", server.log());

    // One stored file per distinct scene and one manifest per distinct job's files, whatever
    // the number of writers, and no temporary files left.
    let mut stored = Vec::new();
    for folder in std::fs::read_dir(data.join("files")).unwrap() {
        for f in std::fs::read_dir(folder.unwrap().path()).unwrap() {
            stored.push(f.unwrap().file_name().to_string_lossy().into_owned());
        }
    }
    assert_eq!(stored.iter().filter(|n| n.len() == 64 && !n.starts_with('.')).count(), 2 * (1 + DIFFERENT));
    assert!(stored.iter().all(|n| !n.ends_with(".tmp")), "temporary files left behind: {stored:?}");

    for (_, job) in &answers {
        let id = job["id"].as_u64().unwrap();
        let done = wait_job(&server, id, 240, |j| j["state"] == "done");
        let outputs = done["frames"][0]["outputs"].as_array().cloned().unwrap_or_default();
        assert!(!outputs.is_empty(), "job {id} finished without outputs: {done}");
    }
}
