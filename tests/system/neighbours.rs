//! Two systems side by side on one machine: one system's stop and clean-up leave alone a
//! neighbour whose prefix starts with its own (real `hng run` processes).

use hng_runtime::shm;
use hng_runtime::system::EventKind;

use crate::signals::{Events, Run, is_alive, launch_file, run_log, test_dir};

/// Two systems side by side, the prefix of one the start of the other's (`P` and `Px_`):
/// stopping `P` removes its files and none of `Px_`'s, whose module goes on running (before,
/// `P`'s clean-up removed every file in /dev/shm whose name started with `P` but the other's
/// root folder, its wake segments and data segments among them).
#[test]
fn stopping_a_system_leaves_a_neighbour_whose_prefix_starts_with_its_own_running() {
    let prefix = shm::unique_prefix("signb");
    let neighbour = format!("{prefix}x_");
    let dir = test_dir(&prefix);
    let file = launch_file(
        &dir.join("launch"),
        "system = \"neighbours\"\n\n[[module]]\nname = \"counter\"\ncommand = [\"TESTMOD\", \"counter\"]\n",
    );
    let mut events = Events::new(&prefix);
    let mut near = Events::new(&neighbour);
    let args = ["--no-rm", file.to_str().expect("path")];
    let mut run = Run::start_on(&prefix, &args);
    let mut other = Run::start_on(&neighbour, &args);
    events.wait("counter", EventKind::Started, &|| run_log(&run.dir));
    let started = near.wait("counter", EventKind::Started, &|| run_log(&other.dir));
    drop(events);
    let theirs = shm::prefix_files(&neighbour);
    assert!(!theirs.is_empty(), "the neighbour has files");

    let out = run.hng(&["stop"]);
    assert!(out.status.success(), "hng stop: {out:?}");
    assert_eq!(run.wait().code(), Some(0));
    run.assert_left_nothing();
    let gone: Vec<_> = theirs.iter().filter(|f| !f.exists()).collect();
    assert!(gone.is_empty(), "the neighbour's files removed: {gone:?}");
    assert!(
        is_alive(started.pid as i32),
        "the neighbour's module runs on"
    );
    // It still works: a restart of its module through its own supervisor.
    let out = other.hng(&["restart", "counter"]);
    assert!(
        out.status.success(),
        "hng restart on the neighbour: {out:?}"
    );
    near.wait("counter", EventKind::Started, &|| run_log(&other.dir));
    drop(near);
    other.stop_ok();
}
