//! Consecutive problems of one world on one running system: one `hng run --episodes` (its
//! mission monitor puts the robot at each problem's start, gives the goal, judges it and
//! writes one JSON line per problem as it ends; `supervisor/src/monitor/episodes.rs`), its
//! lines read as they come. A problem's `wall_s` is from the previous problem's end (from the
//! spawn for the first: it carries the start-up) to its own; its `cpu_s` the CPU time of each
//! module process over that stretch (differences of the /proc samples).
//!
//! If the run ends or hangs before the last problem, the current problem fails with the
//! reason and the caller goes on with the rest on a new system.

use std::collections::BTreeMap;
use std::io::Read as _;

use std::time::Instant;

use anyhow::{Context as _, Result};
use serde_json::{Value, json};

use super::problems::Problem;
use super::runner::{
    CPU_SAMPLE_PERIOD, ProblemResult, RunCpu, RunOptions, SUMMARY_POLL, Stopping, duration_s,
    failed, from_summary, last_lines, spawn_run, stop_child, wall_limit_s,
};

/// How a world's run ended.
#[derive(Debug)]
pub struct WorldEnd {
    /// Problems given a result (the first `done` of the list).
    pub done: usize,
    /// The run, still stopping after its last problem.
    pub stopping: Option<Stopping>,
    /// The eval was asked to stop by this signal (the interrupted problem has no result).
    pub signal: Option<i32>,
}

/// Runs the problems `ps` (all of one world) on one system, calling `emit` with each result
/// as it comes.
pub fn run_world(
    ps: &[Problem],
    o: &RunOptions,
    emit: &mut dyn FnMut(ProblemResult) -> Result<()>,
) -> Result<WorldEnd> {
    let Some(first) = ps.first() else {
        return Ok(WorldEnd {
            done: 0,
            stopping: None,
            signal: None,
        });
    };
    let prefix = hng_runtime::shm::unique_prefix("evalnav");
    let dir = o.dir.join(format!("w{:04}", first.id));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let episodes = dir.join("episodes.jsonl");
    let out = dir.join("results.jsonl");
    let _ = std::fs::remove_file(&out);
    let mut text = String::new();
    for p in ps {
        let line = json!({
            "id": p.id,
            "start": p.start,
            "goal": p.goal,
            "duration_s": duration_s(p, o),
        });
        text.push_str(&line.to_string());
        text.push('\n');
    }
    std::fs::write(&episodes, text).with_context(|| format!("writing {}", episodes.display()))?;
    let mut cmd = super::runner::run_command(o, &prefix, &dir, &first.world, first.start)?;
    cmd.arg("--episodes")
        .arg(&episodes)
        .arg("--episode-out")
        .arg(&out);
    let (mut child, started) = spawn_run(&mut cmd, o)?;
    let mut cpu = RunCpu::new(child.id());
    let mut next_sample = started;
    let mut cpu_before: BTreeMap<String, f64> = BTreeMap::new();
    let mut mark = started;
    let mut k = 0;
    let mut reader: Option<std::fs::File> = None;
    let mut buf = String::new();
    let mut all_ok = true;
    let mut signal = None;
    // Problem `k`'s result, with its CPU and wall time since the previous one.
    let mut finish = |k: usize,
                      r: Option<&Value>,
                      why: Option<String>,
                      cpu: &RunCpu,
                      mark: &mut Instant|
     -> Result<bool> {
        let now = cpu.seconds();
        let spent: BTreeMap<String, f64> = now
            .iter()
            .map(|(n, v)| (n.clone(), v - cpu_before.get(n).copied().unwrap_or(0.0)))
            .collect();
        cpu_before = now;
        let wall_s = mark.elapsed().as_secs_f64();
        *mark = Instant::now();
        let p = &ps[k];
        let result = match (r, why) {
            (Some(v), _) => from_summary(p, v, "", wall_s, spent),
            (None, why) => failed(p, why.unwrap_or_else(|| "no result".into()), wall_s, spent),
        };
        let ok = result.success;
        emit(result)?;
        Ok(ok)
    };
    let ended = loop {
        let exited = child.try_wait()?;
        if reader.is_none() {
            reader = std::fs::File::open(&out).ok();
        }
        if let Some(f) = &mut reader {
            f.read_to_string(&mut buf)
                .with_context(|| format!("reading {}", out.display()))?;
        }
        while let Some(end) = buf.find('\n') {
            let line: String = buf.drain(..=end).collect();
            let v: Value = serde_json::from_str(&line)
                .with_context(|| format!("a line of {}: {line}", out.display()))?;
            if k >= ps.len() {
                break;
            }
            if v.get("episode").and_then(Value::as_u64) != Some(ps[k].id as u64) {
                tracing::warn!(line = %line, expected = ps[k].id, "an episode line out of order");
            }
            cpu.sample();
            all_ok &= finish(k, Some(&v), None, &cpu, &mut mark)?;
            k += 1;
        }
        if k >= ps.len() {
            break None;
        }
        if let Some(st) = exited {
            cpu.sample();
            let why = format!(
                "hng run ended ({st}) during this problem; stderr: {}",
                last_lines(&dir.join("stderr.txt"), 3)
            );
            finish(k, None, Some(why), &cpu, &mut mark)?;
            all_ok = false;
            k += 1;
            break Some(st);
        }
        if Instant::now() >= next_sample {
            cpu.sample();
            next_sample = Instant::now() + CPU_SAMPLE_PERIOD;
        }
        if let Some(sig) = super::stop::requested() {
            signal = Some(sig);
            break stop_child(&mut child, sig);
        }
        // This problem's wall limit: its duration at 0.25x real time, and a minute.
        let limit = wall_limit_s(duration_s(&ps[k], o));
        if mark.elapsed().as_secs_f64() > limit {
            let _ = child.kill();
            let st = child.wait().ok();
            let why = format!("no result after {limit:.0} s of wall time: the run was killed");
            finish(k, None, Some(why), &cpu, &mut mark)?;
            all_ok = false;
            k += 1;
            break st;
        }
        std::thread::sleep(SUMMARY_POLL);
    };
    let remove = (!o.keep && all_ok && k >= ps.len()).then_some(dir);
    if ended.is_none() && signal.is_none() {
        // Every problem done: the run stops by itself (its monitor ordered it).
        return Ok(WorldEnd {
            done: k,
            stopping: Some(Stopping {
                child,
                prefix,
                remove,
                since: Instant::now(),
            }),
            signal: None,
        });
    }
    hng_runtime::shm::remove_prefix_files(&prefix);
    if let Some(d) = remove {
        let _ = std::fs::remove_dir_all(d);
    }
    Ok(WorldEnd {
        done: k,
        stopping: None,
        signal,
    })
}
