//! `hng bench gui`: the operator page's live stream. A publisher sends 360-beam scans on
//! `laser/scan` at 10 Hz (stamped on the wall clock); the page server (hng-gui, in this
//! process, on a private prefix and a free loopback port) streams them to 1 and then 3
//! WebSocket clients that read everything. One sample per scan frame sent to a client: the
//! time from the scan's stamp (its publication) to the end of the WebSocket send of its
//! frame (case `scan_to_ws_send_Nclients`). Target (issue #20): p99 under 20 ms.

use std::io::{Read as _, Write as _};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::Args;
use hng_gui::{Channels, Options, Server};
use hng_runtime::msg::{FrameId, LaserScan};
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_runtime::{Node, NodeOptions, shm};

/// Arguments of `hng bench gui`.
#[derive(Debug, Clone, Args)]
pub struct GuiBenchArgs {
    /// Scans published per case (at 10 Hz).
    #[arg(long, default_value_t = 200)]
    pub scans: u32,
    /// One JSON object per case instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// A WebSocket client that reads (and discards) everything until `stop`.
fn reader(
    addr: std::net::SocketAddr,
    stop: Arc<AtomicBool>,
) -> Result<std::thread::JoinHandle<()>> {
    let mut s = TcpStream::connect(addr)?;
    write!(
        s,
        "GET /ws HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )?;
    s.set_read_timeout(Some(Duration::from_secs(5)))?;
    let mut first = [0u8; 12];
    s.read_exact(&mut first)?;
    s.set_read_timeout(Some(Duration::from_millis(200)))?;
    if !first.starts_with(b"HTTP/1.1 101") {
        bail!(
            "WebSocket handshake refused: {}",
            String::from_utf8_lossy(&first)
        );
    }
    Ok(std::thread::spawn(move || {
        let mut buf = vec![0u8; 1 << 16];
        while !stop.load(Ordering::Acquire) {
            match s.read(&mut buf) {
                Ok(0) => break,
                Ok(_) => {}
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(_) => break,
            }
        }
    }))
}

/// The operator page, in this process, for the system under `prefix`, on a free loopback
/// port without a token (the benchmarks' page, and the browser tests' without a mission).
pub fn serve_page(prefix: &str, channels: Channels) -> Result<Server> {
    let listener = TcpListener::bind("127.0.0.1:0").context("a free loopback port")?;
    Ok(Server::start(
        listener,
        Options {
            prefix: prefix.to_owned(),
            token: None,
            channels,
        },
    )?)
}

fn case(prefix: &str, clients: usize, scans: u32) -> Result<BenchRow> {
    let server = serve_page(prefix, Channels::default())?;
    let node = Node::new(NodeOptions::new("bench-gui-laser").prefix(prefix))?;
    let publisher = node.publisher::<LaserScan>("laser/scan")?;
    let stop = Arc::new(AtomicBool::new(false));
    let mut readers = Vec::new();
    for _ in 0..clients {
        readers.push(reader(server.local_addr(), Arc::clone(&stop))?);
    }
    // Every client is connected before measuring.
    let deadline = Instant::now() + Duration::from_secs(10);
    while server.hub().clients() < clients {
        if Instant::now() > deadline {
            bail!(
                "only {} of {clients} clients connected",
                server.hub().clients()
            );
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    server.hub().measure_latency();
    let mut scan = LaserScan::full_circle(&[0.0; 360], 0.1, 10.0);
    scan.header.frame_id = FrameId::LASER;
    let start = Instant::now();
    for k in 0..scans {
        // 10 Hz on the wall clock: the publication time of scan k.
        let at = start + Duration::from_millis(100 * u64::from(k));
        std::thread::sleep(at.saturating_duration_since(Instant::now()));
        for (i, r) in scan.ranges[..360].iter_mut().enumerate() {
            *r = 2.0 + ((i as u32 + k) % 50) as f32 * 0.05;
        }
        publisher.publish(scan)?;
    }
    // The last frames' sends.
    std::thread::sleep(Duration::from_millis(200));
    let mut samples = server.hub().take_latencies();
    let stats = server.hub().stats();
    stop.store(true, Ordering::Release);
    server.stop();
    for r in readers {
        let _ = r.join();
    }
    if samples.is_empty() {
        bail!("no scan frame was sent");
    }
    let p = Percentiles::of(&mut samples);
    Ok(
        BenchRow::new("gui", &format!("scan_to_ws_send_{clients}clients"), p)
            .with("clients", clients as u64)
            .with("scan_hz", 10)
            .with("beams", 360)
            .with("scans", u64::from(scans))
            .with("frames_skipped", stats.frames_skipped)
            .with("target_p99_ns", 20_000_000)
            .with("meets_target", p.p99_ns < 20_000_000),
    )
}

/// `hng bench gui`.
pub fn run(args: &GuiBenchArgs) -> Result<()> {
    let mut rows = Vec::new();
    for clients in [1, 3] {
        let prefix = shm::unique_prefix("bench_gui");
        let r = case(&prefix, clients, args.scans.max(1))
            .with_context(|| format!("{clients} client(s)"));
        shm::remove_prefix_files(&prefix);
        rows.push(r?);
    }
    super::print_rows(&rows, args.json);
    Ok(())
}
