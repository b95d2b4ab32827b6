//! The flight recorder end to end (docs/recording.md): `hng run --record`, `hng info`, an
//! independent MCAP reader (Python), `hng replay --module slam` against the recorded mission,
//! damaged files, replay into a channel of another type, the live view with an independent
//! Foxglove client (node), and the channel limits that let all these tools watch at once.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;

use hng_runtime::msg::{ModuleReport, Twist};
use hng_runtime::{Node, NodeOptions, shm};

use crate::common::Reaped;
use serde_json::Value;

/// Largest 95th percentile of the distance between the recorded SLAM poses and those of
/// SLAM replayed alone against the recording, m. The recorder is a lockstep participant (it
/// loses nothing) and the replay drives a lockstep barrier of its own, so the replayed SLAM
/// gets every scan and odometry message at its recorded simulated time: measured on this
/// project's loaded machine (load average 10-24 on 2 cores), every pose paired with no stamp
/// gap, p95 0.011-0.017 m, max 0.054 m, 93-203 poses bit-identical, in three runs in a row. Not bit-identical throughout:
/// which messages SLAM takes together in one wake-up within a round still depends on the
/// scheduling.
const SLAM_TOLERANCE_M: f64 = 0.05;

/// Simulation speed of the recorded mission (the recorder, a lockstep participant, loses
/// nothing at any speed; the world waits for it).
const SPEED: &str = "4";

fn hng() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hng"));
    c.env("HNG_LOG", "warn")
        .env("HNG_NO_GUI", "true")
        .stdin(Stdio::null());
    c
}

fn text(o: &Output) -> String {
    format!(
        "status {}\nstdout:\n{}\nstderr:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn tmp_dir(tag: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("test dir");
    d
}

fn info_json(file: &Path) -> (Output, Value) {
    let out = hng()
        .arg("info")
        .arg(file)
        .arg("--json")
        .output()
        .expect("hng info");
    let v = serde_json::from_slice(&out.stdout).unwrap_or(Value::Null);
    (out, v)
}

/// The default mission, run once with `--record` and shared by the tests that read it.
struct Recorded {
    file: PathBuf,
    run_dir: PathBuf,
    info: Value,
    run_output: String,
}

fn recorded_mission() -> &'static Recorded {
    static R: OnceLock<Recorded> = OnceLock::new();
    R.get_or_init(|| {
        let _heavy = crate::common::heavy();
        let dir = tmp_dir("hng-recording");
        let file = dir.join("mission.mcap");
        let prefix = shm::unique_prefix("rec_mission");
        let out = hng()
            .arg("--prefix")
            .arg(&prefix)
            .arg("run")
            .arg("--run-dir")
            .arg(dir.join("run"))
            .args(["--speed", SPEED, "--record"])
            .arg(&file)
            // Modules log at their default level (info) to their log files, which are
            // recorded; the terminal stays quiet.
            .env_remove("HNG_LOG")
            .output()
            .expect("hng run --record");
        shm::remove_prefix_files(&prefix);
        let run_output = text(&out);
        assert!(out.status.success(), "{run_output}");
        assert!(run_output.contains("mission SUCCEEDED"), "{run_output}");
        let (iout, info) = info_json(&file);
        assert!(iout.status.success(), "{}", text(&iout));
        Recorded {
            file,
            run_dir: dir.join("run"),
            info,
            run_output,
        }
    })
}

/// The middle of the body of the first chunk record (MCAP opcode 0x06) that holds or starts
/// after byte `from`, walking the records from the magic.
fn middle_of_a_chunk(b: &[u8], from: usize) -> usize {
    let mut o = 8;
    while o + 9 <= b.len() {
        let mut len8 = [0u8; 8];
        len8.copy_from_slice(&b[o + 1..o + 9]);
        let len = usize::try_from(u64::from_le_bytes(len8)).expect("record length");
        let end = o + 9 + len;
        if b[o] == 0x06 && end > from && len > 200 {
            return o + 9 + len / 2;
        }
        o = end;
    }
    panic!("no chunk after byte {from}");
}

/// The offset of the first record with opcode `op` that starts at or after byte `from`.
fn record_at_or_after(b: &[u8], op: u8, from: usize) -> usize {
    let mut o = 8;
    while o + 9 <= b.len() {
        let mut len8 = [0u8; 8];
        len8.copy_from_slice(&b[o + 1..o + 9]);
        let len = usize::try_from(u64::from_le_bytes(len8)).expect("record length");
        if b[o] == op && o >= from {
            return o;
        }
        o += 9 + len;
    }
    panic!("no record 0x{op:02x} after byte {from}");
}

fn channel<'a>(info: &'a Value, name: &str) -> &'a Value {
    info["channels"]
        .as_array()
        .and_then(|a| a.iter().find(|c| c["channel"] == name))
        .unwrap_or_else(|| panic!("no channel {name} in {info}"))
}

#[test]
fn a_recorded_mission_holds_every_channel_with_foxglove_schemas_and_its_drops() {
    let r = recorded_mission();
    let info = &r.info;
    assert_eq!(info["complete"], true, "{info}");
    for (name, schema) in [
        ("laser/scan", "foxglove.LaserScan"),
        ("sim/scan", "foxglove.LaserScan"),
        ("slam/pose", "foxglove.PoseInFrame"),
        ("robot/odom", "foxglove.FrameTransforms"),
        ("slam/map", "foxglove.Grid"),
        ("planning/path", "foxglove.PosesInFrame"),
        ("hng/clock", "hng/Clock/v2"),
        ("hng/report", "hng/ModuleReport/v1"),
    ] {
        let c = channel(info, name);
        assert_eq!(c["schema"], schema, "{c}");
        assert!(c["messages"].as_u64().unwrap_or(0) > 0, "{c}");
        assert!(c["dropped"].is_u64(), "drops stored per channel: {c}");
    }
    assert_eq!(channel(info, "hng/report")["message_encoding"], "json");
    // Drops are stored in the file and printed at the end of the run.
    let total: u64 = info["channels"]
        .as_array()
        .expect("channels")
        .iter()
        .filter_map(|c| c["dropped"].as_u64())
        .sum();
    assert_eq!(info["dropped"].as_u64(), Some(total), "{info}");
    assert!(r.run_output.contains("dropped"), "{}", r.run_output);
    // The recorder is a lockstep participant: nothing published in simulated time is lost,
    // however loaded the machine.
    for name in [
        "laser/scan",
        "sim/scan",
        "robot/odom",
        "slam/pose",
        "hng/clock",
        "hng/clock_ack",
        "sim/ground_truth",
        "camera/image",
    ] {
        let c = channel(info, name);
        assert_eq!(c["dropped"].as_u64(), Some(0), "{c}");
    }
    // The modules' internal data: their log lines, in Foxglove's Log schema, one channel per
    // module, and their checkpoints as attachments.
    let logs: Vec<&Value> = info["channels"]
        .as_array()
        .expect("channels")
        .iter()
        .filter(|c| {
            c["channel"]
                .as_str()
                .is_some_and(|n| n.starts_with("hng/log/"))
        })
        .collect();
    assert!(logs.len() >= 2, "log channels: {logs:?}");
    for c in &logs {
        assert_eq!(c["schema"], "foxglove.Log", "{c}");
        assert!(c["messages"].as_u64().unwrap_or(0) > 0, "{c}");
    }
    // Every module that wrote lines during the run has them recorded (the run directory was
    // new: its log files hold this run's lines only; the last lines of a stopping module may
    // reach its file after the recorder's last read).
    let mut with_lines = 0;
    for e in std::fs::read_dir(r.run_dir.join("logs"))
        .expect("log dir")
        .flatten()
    {
        let path = e.path();
        let Some(module) = hng_recorder::internal::log_module(&path) else {
            continue;
        };
        let lines = std::fs::read_to_string(&path)
            .unwrap_or_default()
            .lines()
            .filter(|l| !l.trim().is_empty())
            .count() as u64;
        if lines == 0 || module == "hng" {
            continue;
        }
        with_lines += 1;
        let got = channel(info, &format!("hng/log/{module}"))["messages"]
            .as_u64()
            .unwrap_or(0);
        assert!(got >= 1 && got <= lines, "{module}: {got} of {lines} lines");
    }
    assert!(with_lines >= 1, "no module wrote a line: {logs:?}");
    let ckpt = &info["attachments"]["checkpoint/slam"];
    assert!(
        ckpt["count"].as_u64().unwrap_or(0) >= 1,
        "{}",
        info["attachments"]
    );
    assert!(ckpt["bytes"].as_u64().unwrap_or(0) > 28, "{ckpt}");
    assert!(r.run_output.contains("internal data:"), "{}", r.run_output);
    // The plan's module configurations are kept for `hng replay --module`.
    assert!(
        info["metadata"]["hng.modules"]["slam"]
            .as_str()
            .is_some_and(|c| c.contains("initial_pose")),
        "{}",
        info["metadata"]
    );
    assert_eq!(
        info["metadata"]["hng.run"]["clock"], "sim",
        "{}",
        info["metadata"]
    );
}

#[test]
fn an_independent_python_reader_agrees_with_hng_info() {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/system/py/.venv/bin/python");
    let ready = Command::new(&python)
        .args(["-c", "import mcap, mcap_protobuf"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ready {
        crate::common::skip(
            "an_independent_python_reader_agrees_with_hng_info",
            &format!(
                "{} cannot import mcap and mcap_protobuf (.ci/run creates the venv with python3 \
                 -m venv and pip-installs mcap mcap-protobuf-support)",
                python.display()
            ),
        );
        return;
    }
    let r = recorded_mission();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/system/py/read_mcap.py");
    let out = Command::new(&python)
        .arg(&script)
        .arg(&r.file)
        .output()
        .expect("python");
    assert!(out.status.success(), "{}", text(&out));
    let py: Value = serde_json::from_slice(&out.stdout).expect("the reader's JSON");
    let mut ours: Vec<(String, u64)> = r.info["channels"]
        .as_array()
        .expect("channels")
        .iter()
        .map(|c| {
            (
                c["channel"].as_str().unwrap_or_default().to_string(),
                c["messages"].as_u64().unwrap_or(u64::MAX),
            )
        })
        .collect();
    let mut theirs: Vec<(String, u64)> = py["channels"]
        .as_object()
        .expect("channels")
        .iter()
        .map(|(k, v)| (k.clone(), v["messages"].as_u64().unwrap_or(u64::MAX)))
        .collect();
    ours.sort();
    theirs.sort();
    assert_eq!(ours, theirs, "channel lists and counts differ");
    assert_eq!(py["decoded"], r.info["messages"], "{py}");
    assert!(py["scans_with_ranges"].as_u64().unwrap_or(0) > 0, "{py}");
    assert!(py["poses_with_position"].as_u64().unwrap_or(0) > 0, "{py}");
    assert_eq!(py["metadata"]["hng.drops"], r.info["metadata"]["hng.drops"]);
    assert!(py["logs_with_text"].as_u64().unwrap_or(0) > 0, "{py}");
    assert!(py["paths_with_poses"].as_u64().unwrap_or(0) > 0, "{py}");
    let counts: std::collections::BTreeMap<String, u64> = r.info["attachments"]
        .as_object()
        .expect("attachments")
        .iter()
        .map(|(k, v)| (k.clone(), v["count"].as_u64().unwrap_or(0)))
        .collect();
    let theirs: std::collections::BTreeMap<String, u64> =
        serde_json::from_value(py["attachments"].clone()).expect("attachments");
    assert_eq!(counts, theirs, "attachments differ");
}

#[test]
fn slam_replayed_alone_against_the_recorded_mission_finds_the_recorded_poses() {
    let r = recorded_mission();
    let _heavy = crate::common::heavy();
    let dir = tmp_dir("hng-replay-slam");
    let b = dir.join("slam.mcap");
    let out = hng()
        .arg("replay")
        .arg(&r.file)
        .args(["--module", "slam", "--speed", "max", "-o"])
        .arg(&b)
        .output()
        .expect("hng replay --module slam");
    assert!(out.status.success(), "{}", text(&out));
    let (iout, info) = info_json(&b);
    assert!(iout.status.success(), "{}", text(&iout));
    // Only SLAM's own outputs are in the new file.
    for c in info["channels"].as_array().expect("channels") {
        let name = c["channel"].as_str().unwrap_or_default();
        assert!(name.starts_with("slam/"), "{c}");
    }
    let out = hng()
        .args(["eval", "replay"])
        .arg(&r.file)
        .arg(&b)
        .args(["--channel", "slam/pose", "--json"])
        .output()
        .expect("hng eval replay");
    assert!(out.status.success(), "{}", text(&out));
    let c: Value = serde_json::from_slice(&out.stdout).expect("comparison JSON");
    eprintln!("slam replay vs recording: {c}");
    let a_n = c["a_messages"].as_u64().unwrap_or(0);
    let pairs = c["pairs"].as_u64().unwrap_or(0);
    assert!(pairs > 100 && pairs * 10 >= a_n * 9, "{c}");
    let p95 = c["p95_position_error_m"].as_f64().unwrap_or(f64::NAN);
    assert!(p95 <= SLAM_TOLERANCE_M, "{c}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_damaged_recording_names_the_offset_and_what_precedes_it_is_read_and_replayed() {
    let r = recorded_mission();
    let dir = tmp_dir("hng-damaged");
    let bytes = std::fs::read(&r.file).expect("recording");
    // Cut short (a crash, a full disk).
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).expect("write");
    let (out, info) = info_json(&cut);
    assert!(!out.status.success(), "{}", text(&out));
    assert_eq!(info["complete"], false, "{info}");
    let damage = info["damage"].as_str().unwrap_or_default().to_string();
    assert!(damage.contains("damaged at byte offset"), "{damage}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("byte offset"),
        "{}",
        text(&out)
    );
    let n = info["messages"].as_u64().unwrap_or(0);
    assert!(
        n > 0 && n < r.info["messages"].as_u64().unwrap_or(0),
        "{info}"
    );
    // Corrupted in the middle: a chunk's bytes overwritten (the chunk that holds or follows
    // the file's middle; message indexes between chunks carry no CRC in MCAP, so bytes
    // overwritten there may go unseen: that is MCAP's format, not this test's subject).
    let bad = dir.join("corrupt.mcap");
    let mut b2 = bytes.clone();
    let mid = middle_of_a_chunk(&b2, b2.len() / 2);
    for x in &mut b2[mid..mid + 64] {
        *x = 0xA5;
    }
    std::fs::write(&bad, &b2).expect("write");
    let (out, info) = info_json(&bad);
    assert!(!out.status.success(), "{}", text(&out));
    assert!(
        info["damage"]
            .as_str()
            .is_some_and(|d| d.contains("damaged at byte offset")),
        "{info}"
    );
    // Bytes overwritten in a message index (a record MCAP gives no CRC): its entries are
    // checked against the chunk they point into, and the damage named with the index's offset.
    let bad = dir.join("index.mcap");
    let mut b3 = bytes.clone();
    let at = record_at_or_after(&b3, 0x07, b3.len() / 2);
    // Body: channel id (2), entries' byte length (4), then (log time, offset) pairs.
    for x in &mut b3[at + 9 + 6..at + 9 + 6 + 16] {
        *x = 0xA5;
    }
    std::fs::write(&bad, &b3).expect("write");
    let (out, info) = info_json(&bad);
    assert!(!out.status.success(), "{}", text(&out));
    let d = info["damage"].as_str().unwrap_or_default();
    assert!(
        d.contains(&format!("damaged at byte offset {at}")) && d.contains("message index"),
        "{info}"
    );
    // Replay of the cut file: what precedes the damage goes out, then the error.
    let prefix = shm::unique_prefix("rec_damaged");
    let out = hng()
        .arg("--prefix")
        .arg(&prefix)
        .arg("replay")
        .arg(&cut)
        .args(["--channels", "laser/scan", "--speed", "max"])
        .output()
        .expect("hng replay");
    shm::remove_prefix_files(&prefix);
    let t = text(&out);
    assert!(!out.status.success(), "{t}");
    assert!(t.contains("byte offset"), "{t}");
    let scans = channel(&info_json(&cut).1, "laser/scan")["messages"]
        .as_u64()
        .unwrap_or(0);
    assert!(scans > 0, "{t}");
    assert!(t.contains(&format!("replayed {scans} message(s)")), "{t}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn replay_into_a_channel_of_another_type_is_refused_naming_both_types() {
    let r = recorded_mission();
    let prefix = shm::unique_prefix("rec_mismatch");
    {
        let node = Node::new(NodeOptions::new("squatter").prefix(&prefix)).expect("node");
        let _p = node.publisher::<Twist>("laser/scan").expect("publisher");
        let out = hng()
            .arg("--prefix")
            .arg(&prefix)
            .arg("replay")
            .arg(&r.file)
            .args(["--channels", "laser/scan", "--speed", "max"])
            .output()
            .expect("hng replay");
        let t = text(&out);
        assert!(!out.status.success(), "{t}");
        for needle in ["laser/scan", "hng/LaserScan/v1", "hng/Twist/v1", "refused"] {
            assert!(t.contains(needle), "{needle}: {t}");
        }
    }
    shm::remove_prefix_files(&prefix);
}

fn terminate(c: &mut Child) -> std::process::ExitStatus {
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(c.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    c.wait().expect("wait")
}

#[test]
fn the_live_view_serves_scans_to_the_foxglove_npm_client_while_hng_record_writes_them() {
    let js = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/system/js");
    let node_ok = Command::new("node")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !node_ok || !js.join("node_modules/@foxglove/ws-protocol").exists() {
        crate::common::skip(
            "the_live_view_serves_scans_to_the_foxglove_npm_client",
            &format!(
                "{} (.ci/run installs @foxglove/ws-protocol, ws and protobufjs with npm into \
                 tests/system/js)",
                if node_ok {
                    "no tests/system/js/node_modules"
                } else {
                    "no node"
                }
            ),
        );
        return;
    }
    let _heavy = crate::common::heavy();
    let prefix = shm::unique_prefix("rec_live");
    let dir = tmp_dir("hng-live");
    let file = dir.join("live.mcap");
    let sim = Reaped(
        hng()
            .args(["module", "simulator"])
            .env("HNG_PREFIX", &prefix)
            .env("HNG_MODULE_NAME", "simulator")
            .env("HNG_MODULE_CONFIG", "speed = 2")
            .env("HNG_CLOCK", "sim")
            .spawn()
            .expect("simulator"),
    );
    let mut rec = Reaped(
        hng()
            .arg("--prefix")
            .arg(&prefix)
            .args(["record", "--all", "--foxglove", "ws://127.0.0.1:0", "-o"])
            .arg(&file)
            .stdout(Stdio::piped())
            .spawn()
            .expect("hng record --foxglove"),
    );
    let stdout = rec.0.stdout.take().expect("stdout");
    let mut lines = BufReader::new(stdout).lines();
    let url = loop {
        let line = lines
            .next()
            .expect("hng record ended before the live view started")
            .expect("read");
        if let Some(u) = line.strip_prefix("live view: ") {
            break u.trim().to_string();
        }
    };
    let out = Command::new("node")
        .arg(js.join("client.mjs"))
        .args([url.as_str(), "sim/scan", "5", "30000"])
        .current_dir(&js)
        .output()
        .expect("node");
    assert!(out.status.success(), "{}", text(&out));
    let got: Value = serde_json::from_slice(&out.stdout).expect("the client's JSON");
    assert_eq!(got["schemaName"], "foxglove.LaserScan", "{got}");
    assert_eq!(got["encoding"], "protobuf", "{got}");
    let msgs = got["messages"].as_array().expect("messages");
    assert_eq!(msgs.len(), 5, "{got}");
    for m in msgs {
        assert!(m["ranges"].as_u64().unwrap_or(0) > 10, "{m}");
        assert!(m["end_angle"].as_f64() > m["start_angle"].as_f64(), "{m}");
    }
    // SIGTERM: the recorder closes its file with its summary and index.
    let status = terminate(&mut rec.0);
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    assert!(status.success(), "{status}: {rest:?}");
    assert!(rest.iter().any(|l| l.starts_with("recorded ")), "{rest:?}");
    drop(sim);
    let (iout, info) = info_json(&file);
    assert!(iout.status.success(), "{}", text(&iout));
    assert!(
        channel(&info, "sim/scan")["messages"].as_u64().unwrap_or(0) >= 5,
        "{info}"
    );
    shm::remove_prefix_files(&prefix);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_full_channel_names_the_channel_and_its_limit() {
    let prefix = shm::unique_prefix("rec_limits");
    {
        let node = Node::new(NodeOptions::new("fanout").prefix(&prefix)).expect("node");
        let limit = hng_runtime::qos::ChannelKind::Report.qos().max_subscribers;
        assert!(limit >= 16, "room for the tools: {limit}");
        let subs: Vec<_> = (0..limit)
            .map(|i| {
                node.subscriber::<ModuleReport>("test/reports")
                    .unwrap_or_else(|e| panic!("subscriber {i} of {limit}: {e}"))
            })
            .collect();
        let e = node
            .subscriber::<ModuleReport>("test/reports")
            .expect_err("one subscriber too many");
        let msg = e.to_string();
        assert!(
            matches!(e, hng_runtime::Error::ChannelFull { limit: l, .. } if l == limit),
            "{msg}"
        );
        for needle in [
            "\"test/reports\"",
            &format!("at most {limit} subscribers"),
            "HNG_CHANNEL_LIMITS=\"report.subscribers=N\"",
        ] {
            assert!(msg.contains(needle), "{needle}: {msg}");
        }
        drop(subs);
    }
    shm::remove_prefix_files(&prefix);

    // A bad HNG_CHANNEL_LIMITS is refused by name, before anything opens.
    let prefix = shm::unique_prefix("rec_badlimits");
    let out = hng()
        .arg("--prefix")
        .arg(&prefix)
        .args(["record", "--all", "--duration", "0.1", "-o", "/dev/null"])
        .env("HNG_CHANNEL_LIMITS", "sensor.subscribers=lots")
        .output()
        .expect("hng record");
    shm::remove_prefix_files(&prefix);
    let t = text(&out);
    assert!(!out.status.success(), "{t}");
    assert!(
        t.contains("HNG_CHANNEL_LIMITS") && t.contains("sensor.subscribers=lots"),
        "{t}"
    );
}

/// A full disk, without root: `hng record` runs with its file size limit (RLIMIT_FSIZE) at
/// 3 MiB and SIGXFSZ ignored, so the write that would pass the limit fails with EFBIG as a
/// full disk's fails with ENOSPC. The recorder must stop cleanly, say why, and leave a file
/// that `hng info` and the Python reader read up to its last complete record.
#[test]
fn a_full_disk_stops_the_recorder_cleanly_and_leaves_a_readable_file() {
    use std::os::unix::process::CommandExt;
    const LIMIT: u64 = 3 << 20;
    let prefix = shm::unique_prefix("rec_fulldisk");
    let dir = tmp_dir("hng-fulldisk");
    let file = dir.join("full.mcap");
    let node = Node::new(NodeOptions::new("filler").prefix(&prefix)).expect("node");
    let publisher = node
        .slice_publisher::<hng_runtime::msg::BytesInfo>("test/bytes", 64 << 10)
        .expect("publisher");
    let mut cmd = hng();
    cmd.arg("--prefix")
        .arg(&prefix)
        .args(["record", "test/bytes", "--duration", "120", "-o"])
        .arg(&file)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    // SAFETY: only async-signal-safe calls (setrlimit, sigaction) between fork and exec.
    unsafe {
        cmd.pre_exec(|| {
            nix::sys::resource::setrlimit(nix::sys::resource::Resource::RLIMIT_FSIZE, LIMIT, LIMIT)
                .map_err(std::io::Error::from)?;
            nix::sys::signal::signal(
                nix::sys::signal::Signal::SIGXFSZ,
                nix::sys::signal::SigHandler::SigIgn,
            )
            .map_err(std::io::Error::from)?;
            Ok(())
        });
    }
    let mut rec = Reaped(cmd.spawn().expect("hng record"));
    // Incompressible payloads (xorshift), published until the recorder gives up.
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut payload = vec![0u8; 64 << 10];
    let t0 = std::time::Instant::now();
    let status = loop {
        if let Some(s) = rec.0.try_wait().expect("try_wait") {
            break s;
        }
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(100),
            "the recorder did not stop at the file size limit"
        );
        for b in payload.chunks_mut(8) {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            b.copy_from_slice(&x.to_le_bytes()[..b.len()]);
        }
        publisher
            .publish_copy(hng_runtime::msg::BytesInfo::default(), &payload)
            .expect("publish");
        node.update_connections();
        std::thread::sleep(std::time::Duration::from_millis(2));
    };
    let mut out = String::new();
    for s in [rec.0.stdout.take(), None].into_iter().flatten() {
        let _ = std::io::Read::read_to_string(&mut BufReader::new(s), &mut out);
    }
    let mut err = String::new();
    if let Some(s) = rec.0.stderr.take() {
        let _ = std::io::Read::read_to_string(&mut BufReader::new(s), &mut err);
    }
    drop(publisher);
    drop(node);
    shm::remove_prefix_files(&prefix);
    let t = format!("{status}\nstdout:\n{out}\nstderr:\n{err}");
    // Stopped by itself, with an error that says why, and its summary.
    assert!(!status.success(), "{t}");
    assert!(status.code().is_some(), "ended by a signal: {t}");
    assert!(err.contains("recording stopped early"), "{t}");
    assert!(err.contains("File too large"), "{t}");
    assert!(out.contains("recorded "), "{t}");
    let size = std::fs::metadata(&file).expect("the file is left").len();
    assert!(size > 1 << 20 && size <= LIMIT, "{size} bytes: {t}");
    // Readable up to its last complete record.
    let (iout, info) = info_json(&file);
    let it = text(&iout);
    assert_eq!(info["complete"], false, "{it}");
    assert!(
        info["damage"]
            .as_str()
            .is_some_and(|d| d.contains("damaged at byte offset")),
        "{it}"
    );
    let n = channel(&info, "test/bytes")["messages"]
        .as_u64()
        .unwrap_or(0);
    assert!(n >= 16, "whole chunks read back: {it}");
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/system/py/.venv/bin/python");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/system/py/read_mcap.py");
    let py_ok = Command::new(&python)
        .args(["-c", "import mcap, mcap_protobuf"])
        .output()
        .is_ok_and(|o| o.status.success());
    if py_ok {
        let out = Command::new(&python)
            .arg(&script)
            .arg("--partial")
            .arg(&file)
            .output()
            .expect("python");
        assert!(out.status.success(), "{}", text(&out));
        let py: Value = serde_json::from_slice(&out.stdout).expect("the reader's JSON");
        assert_eq!(
            py["channels"]["test/bytes"]["messages"].as_u64(),
            Some(n),
            "{py}"
        );
    } else {
        eprintln!(
            "SKIPPED the Python half of a_full_disk_stops_the_recorder_cleanly: {} cannot \
             import mcap and mcap_protobuf",
            python.display()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
