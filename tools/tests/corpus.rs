//! The fuzz corpus replayed on stable Rust (issue 25): every input under `tests/fuzz/corpus/<target>/`
//! (seeds, hostile sizes, and whatever `cargo +nightly fuzz run --fuzz-dir tests/fuzz <target>` found and was fixed)
//! goes through the loader its target names and must end in `Ok` or an error: no panic, no
//! abort, no hang (a watchdog fails an input that runs a minute). Inputs whose name starts with
//! `huge`, `big`, `sparse` or `overcount` claim gigabytes and must be refused.

#[path = "../../tests/fuzz/targets.rs"]
mod targets;

use std::path::Path;
use std::time::Duration;

#[test]
fn the_fuzz_corpus_loads_or_fails_cleanly() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fuzz/corpus");
    let mut count = 0;
    for target in targets::TARGETS {
        let dir = root.join(target);
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file())
            .collect();
        files.sort();
        assert!(!files.is_empty(), "no corpus for {target}");
        for f in files {
            let bytes = std::fs::read(&f).unwrap();
            let name = f.file_name().unwrap().to_string_lossy().to_string();
            let t = target.to_string();
            let (tx, rx) = std::sync::mpsc::channel();
            std::thread::spawn(move || {
                let r = std::panic::catch_unwind(|| targets::load(&t, &bytes));
                let _ = tx.send(r);
            });
            let r = rx
                .recv_timeout(Duration::from_secs(60))
                .unwrap_or_else(|_| panic!("{target}/{name}: no result within 60 s"));
            let r = r.unwrap_or_else(|_| panic!("{target}/{name}: panicked"));
            if ["huge", "big", "sparse", "overcount"].iter().any(|p| name.starts_with(p)) {
                let e = r.expect_err(&format!("{target}/{name} claims gigabytes but loaded"));
                println!("{target}/{name}: {e}");
            } else {
                println!("{target}/{name}: {}", r.err().unwrap_or_else(|| "ok".into()));
            }
            count += 1;
        }
    }
    assert!(count >= 20, "{count} inputs");
}
