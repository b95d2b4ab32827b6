//! `hng bench record`: the flight recorder's throughput to disk (64 B and 1 MiB messages) and
//! its drops (docs/recording.md).

use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use clap::Args;
use hng_recorder::{RecordOptions, RecorderThread};
use hng_runtime::msg::BytesInfo;
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

/// `hng bench record`: a publisher in this process, the recorder in a thread (as in the
/// supervisor), payloads of pseudo-random bytes (no compression gain); the publisher keeps
/// at most the channel's buffer (2) ahead of the recorder, so drops measure the recorder
/// losing messages, not the publisher outrunning it on purpose.
pub fn run(args: &BenchRecordArgs) -> Result<()> {
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

fn bench_case(dir: &std::path::Path, case: &str, size: usize, n: u64) -> Result<BenchRow> {
    let prefix = hng_runtime::shm::unique_prefix("benchrec");
    let file = dir.join(format!(
        "hng-bench-record-{}-{case}.mcap",
        std::process::id()
    ));
    let result = (|| -> Result<BenchRow> {
        let node = Node::new(NodeOptions::new("bench-record-pub").prefix(&prefix))?;
        let channel = "bench/record";
        let publisher = node.slice_publisher::<BytesInfo>(channel, size)?;
        let mut opts = RecordOptions::new(&prefix);
        opts.output = Some(file.clone());
        opts.channels = vec![channel.to_string()];
        opts.poll = Duration::from_micros(200);
        let mut rec = RecorderThread::spawn(opts)?;
        let t0 = Instant::now();
        while !rec.progress().has(channel) {
            if t0.elapsed() > Duration::from_secs(10) {
                bail!("the recorder did not subscribe within 10 s");
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let window = hng_runtime::qos::ChannelKind::Bulk.qos().buffer as u64;
        let mut payload = vec![0u8; size];
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut samples = Vec::with_capacity(n as usize);
        let start = Instant::now();
        let mut last = start;
        for i in 0..n {
            for b in payload.chunks_mut(8) {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let bytes = x.to_le_bytes();
                b.copy_from_slice(&bytes[..b.len()]);
            }
            // Flow control: at most `window` messages ahead of the recorder.
            while i >= rec.progress().messages() + window {
                if start.elapsed() > Duration::from_secs(120) {
                    bail!("the recorder stopped taking messages ({i} of {n})");
                }
                std::thread::yield_now();
            }
            publisher.publish_copy(BytesInfo::default(), &payload)?;
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
        let elapsed = start.elapsed().as_secs_f64();
        let summary = rec.finish()?;
        let file_bytes = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
        let payload_mb = (n as f64 * size as f64) / 1e6;
        Ok(BenchRow::new("record", case, Percentiles::of(&mut samples))
            .with("messages", summary.messages)
            .with("dropped", summary.dropped)
            .with("payload_mb_s", payload_mb / elapsed)
            .with("disk_mb_s", file_bytes as f64 / 1e6 / elapsed)
            .with("file_bytes", file_bytes)
            .with("wall_s", elapsed))
    })();
    let _ = std::fs::remove_file(&file);
    hng_runtime::shm::remove_prefix_files(&prefix);
    result
}
