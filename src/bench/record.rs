//! `hng bench record`: the flight recorder's throughput to disk (64 B and 1 MiB messages) and
//! its drops (docs/recording.md).

use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use clap::Args;
use hng_recorder::{RecordOptions, RecorderThread};
use hng_runtime::msg::BytesInfo;
use hng_runtime::msg::SliceMessage as _;
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_runtime::{Node, NodeOptions};

use std::path::PathBuf;

/// `hng bench record`.
#[derive(Debug, Args)]
pub struct BenchRecordArgs {
    /// Messages of 64 B.
    #[arg(long, default_value_t = 20000)]
    pub small: u64,
    /// Messages of 1 MiB.
    #[arg(long, default_value_t = 200)]
    pub large: u64,
    /// Directory for the files (default: the temporary directory).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// One JSON object per case.
    #[arg(long)]
    pub json: bool,
}

/// Samples the recorder's subscriber may hold per case: the window the publisher keeps ahead
/// of the recorder (64 B: many, cheap in shared memory; 1 MiB: few, each costs 1 MiB per
/// subscriber slot).
const WINDOW_SMALL: usize = 1024;
const WINDOW_LARGE: usize = 8;

fn channel_of(case: &str) -> String {
    format!("bench/record/{case}")
}

/// `hng bench record`: a publisher in this process, the recorder in a thread (as in the
/// supervisor), its writer thread compressing and writing; payloads are pseudo-random bytes
/// generated before the clock starts (no compression gain, and the generator's cost is not
/// in the figure). The publisher keeps at most the recorder's buffer ahead of the recorder,
/// so drops measure the recorder losing messages, not the publisher outrunning it on purpose.
pub fn run(args: &BenchRecordArgs) -> Result<()> {
    // This process creates the bench's channels: it sizes the recorder's buffers for them.
    hng_runtime::qos::ChannelLimits::install(&format!(
        "{}.record_buffer={WINDOW_SMALL},{}.record_buffer={WINDOW_LARGE}",
        channel_of("64B"),
        channel_of("1MiB")
    ))
    .map_err(|e| anyhow::anyhow!("hng bench record: {e}"))?;
    let dir = args.dir.clone().unwrap_or_else(std::env::temp_dir);
    let mut rows = Vec::new();
    for (case, size, n) in [("64B", 64usize, args.small), ("1MiB", 1 << 20, args.large)] {
        if n == 0 {
            continue;
        }
        rows.push(bench_case(&dir, case, size, n)?);
    }
    super::print_rows(&rows, args.json);
    Ok(())
}

/// `n` bytes of xorshift output.
fn random_bytes(n: usize) -> Vec<u8> {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut out = vec![0u8; n];
    for b in out.chunks_mut(8) {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        b.copy_from_slice(&x.to_le_bytes()[..b.len()]);
    }
    out
}

fn bench_case(dir: &std::path::Path, case: &str, size: usize, n: u64) -> Result<BenchRow> {
    let prefix = hng_runtime::shm::unique_prefix("benchrec");
    let file = dir.join(format!(
        "hng-bench-record-{}-{case}.mcap",
        std::process::id()
    ));
    let result = (|| -> Result<BenchRow> {
        let node = Node::new(NodeOptions::new("bench-record-pub").prefix(&prefix))?;
        let channel = channel_of(case);
        let publisher = node.slice_publisher::<BytesInfo>(&channel, size)?;
        let mut opts = RecordOptions::new(&prefix);
        opts.output = Some(file.clone());
        opts.channels = vec![channel.clone()];
        opts.poll = Duration::from_micros(200);
        let mut rec = RecorderThread::spawn(opts)?;
        let t0 = Instant::now();
        while !rec.progress().has(&channel) {
            if t0.elapsed() > Duration::from_secs(10) {
                bail!("the recorder did not subscribe within 10 s");
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let window = BytesInfo::KIND.qos_of(&channel).record_buffer as u64;
        // 64 MiB of random bytes (or one message's worth more): each message a different
        // slice of it, so no chunk holds a repeated payload.
        let pool = random_bytes((64 << 20).max(size * 2));
        let slots = ((pool.len() - size) / 4093).max(1);
        let mut samples = Vec::with_capacity(n as usize);
        let start = Instant::now();
        let mut last = start;
        for i in 0..n {
            let at = (i as usize % slots) * 4093;
            let payload = &pool[at..at + size];
            // Flow control: at most `window` messages ahead of the recorder.
            while i >= rec.progress().messages() + window {
                if start.elapsed() > Duration::from_secs(120) {
                    bail!("the recorder stopped taking messages ({i} of {n})");
                }
                std::thread::yield_now();
            }
            publisher.publish_copy(BytesInfo::default(), payload)?;
            let now = Instant::now();
            samples.push((now - last).as_nanos() as u64);
            last = now;
        }
        while rec.progress().messages() < n {
            if start.elapsed() > Duration::from_secs(120) {
                break;
            }
            std::thread::yield_now();
        }
        // The figure includes closing the file: the writer's queue written and compressed.
        let summary = rec.finish()?;
        let elapsed = start.elapsed().as_secs_f64();
        let file_bytes = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
        let payload_mb = (n as f64 * size as f64) / 1e6;
        Ok(BenchRow::new("record", case, Percentiles::of(&mut samples))
            .with("messages", summary.messages)
            .with("dropped", summary.dropped)
            .with(
                "queue_dropped",
                summary
                    .channels
                    .iter()
                    .map(|c| c.queue_dropped)
                    .sum::<u64>(),
            )
            .with("window", window)
            .with("messages_per_s", summary.messages as f64 / elapsed)
            .with("payload_mb_s", payload_mb / elapsed)
            .with("disk_mb_s", file_bytes as f64 / 1e6 / elapsed)
            .with("file_bytes", file_bytes)
            .with("wall_s", elapsed))
    })();
    let _ = std::fs::remove_file(&file);
    hng_runtime::shm::remove_prefix_files(&prefix);
    result
}
