//! `hng bench ipc`: one-way latency (round trip / 2) of a ping-pong between two processes.
//!
//! Transports: `hng` (hng channels: loan, write the sequence number in place, publish),
//! `iceoryx2` (the raw iceoryx2 API doing the same: the floor), `iceoryx2-header` (the same
//! carrying hng's message header: what the header costs), `iceoryx2-spare` (that, loaning
//! the next sample ahead as hng's publishers do; these two are not in the default list), `uds` (a
//! Unix stream socket with postcard framing: the classic socket IPC, which must copy every
//! byte). Cases run in rounds and ratios are paired (see [`run_mode`]). Modes:
//! `blocking` (hng: adaptive spin then sleep; iceoryx2: its event listener; uds: blocking
//! reads) and `spin` (busy polling on both sides). The payload is not touched beyond its
//! first eight bytes (the round number, checked on the way back), as in iceoryx2's own
//! benchmark: zero-copy transports are then flat in size, sockets are not.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, anyhow, bail};
use clap::{Args, ValueEnum};
use hng_runtime::channel::{Node, NodeOptions, SlicePublisher, SliceSubscriber};
use hng_runtime::msg::BytesInfo;
use hng_runtime::shm;
use hng_runtime::stats::{BenchRow, Percentiles};
use hng_runtime::wait::{WaitMode, Waiter};

/// Transports compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Transport {
    /// hng channels.
    Hng,
    /// Raw iceoryx2.
    Iceoryx2,
    /// Raw iceoryx2 carrying hng's message header (sequence number, time stamp, source) as
    /// its user header, written on send and read on receive: what the header itself costs
    /// (not in the default list).
    Iceoryx2Header,
    /// Raw iceoryx2 carrying hng's header and loaning the sample for its next message right
    /// after each send, as hng's publishers do (their spare sample): hng's data path
    /// without hng (not in the default list).
    Iceoryx2Spare,
    /// Unix domain stream socket with postcard framing.
    Uds,
}

/// Wait modes compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Mode {
    /// Sleep until notified; hng first spins adaptively (up to 200 µs, its default), the raw
    /// iceoryx2 ends sleep on their listener at once: spin against sleep.
    Blocking,
    /// Sleep until notified on both sides: hng with a zero spin budget (only its waiter's
    /// initial poll of 64 reads before sleeping), like for like with iceoryx2's listener.
    Sleep,
    /// Busy-poll.
    Spin,
}

impl Transport {
    fn name(self) -> &'static str {
        match self {
            Transport::Hng => "hng",
            Transport::Iceoryx2 => "iceoryx2",
            Transport::Iceoryx2Header => "iceoryx2-header",
            Transport::Iceoryx2Spare => "iceoryx2-spare",
            Transport::Uds => "uds",
        }
    }
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Blocking => "blocking",
            Mode::Sleep => "sleep",
            Mode::Spin => "spin",
        }
    }

    /// The transports wait by sleeping (hng possibly after a spin).
    fn sleeps(self) -> bool {
        matches!(self, Mode::Blocking | Mode::Sleep)
    }

    /// hng spins in this mode while the raw ends may not.
    fn hng_spins(self) -> bool {
        matches!(self, Mode::Blocking | Mode::Spin)
    }
}

/// Arguments of `hng bench ipc`.
#[derive(Debug, Clone, Args)]
pub struct IpcArgs {
    /// Payload sizes in bytes (comma separated).
    #[arg(long, value_delimiter = ',', default_values_t = [64usize, 1024, 65536, 1_048_576, 4_194_304])]
    pub sizes: Vec<usize>,
    /// Round trips measured per case (fewer if --max-seconds runs out first).
    #[arg(long, default_value_t = 10_000)]
    pub samples: usize,
    /// Time limit per case (transport, size, mode), seconds, shared by its rounds.
    #[arg(long, default_value_t = 3.0)]
    pub max_seconds: f64,
    /// Sessions per case, each round running every case of a mode once (see `run_mode`);
    /// the samples are pooled.
    #[arg(long, default_value_t = 5)]
    pub rounds: usize,
    /// Transports (comma separated).
    /// The ratios compare with `iceoryx2-spare` (raw iceoryx2 loaning ahead as hng does:
    /// like for like) when it is in the list, else with `iceoryx2`.
    #[arg(long, value_delimiter = ',', default_values_t = [Transport::Hng, Transport::Iceoryx2Spare, Transport::Iceoryx2, Transport::Uds])]
    pub transport: Vec<Transport>,
    /// Modes (comma separated).
    #[arg(long, value_delimiter = ',', default_values_t = [Mode::Blocking, Mode::Sleep, Mode::Spin])]
    pub mode: Vec<Mode>,
    /// One JSON object per case.
    #[arg(long)]
    pub json: bool,
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Arguments of the hidden peer process.
#[derive(Debug, Clone, Args)]
pub struct PeerArgs {
    #[arg(long)]
    transport: Transport,
    #[arg(long)]
    mode: Mode,
    #[arg(long)]
    size: usize,
    #[arg(long)]
    prefix: String,
    #[arg(long)]
    socket: Option<String>,
}

mod raw;

use raw::RawEnd;

const STOP: u64 = u64::MAX;
const PING: &str = "bench/ping";
const PONG: &str = "bench/pong";

fn wait_mode(mode: Mode) -> WaitMode {
    match mode {
        Mode::Blocking => WaitMode::default(),
        Mode::Sleep => WaitMode::SLEEP,
        Mode::Spin => WaitMode::Spin,
    }
}

fn stamp(buf: &mut [u8], round: u64) {
    let n = buf.len().min(8);
    buf[..n].copy_from_slice(&round.to_le_bytes()[..n]);
}

fn read_stamp(buf: &[u8]) -> u64 {
    let mut b = [0u8; 8];
    let n = buf.len().min(8);
    b[..n].copy_from_slice(&buf[..n]);
    u64::from_le_bytes(b)
}

/// One side of a ping-pong; `exchange` sends `round` and returns the round number echoed back.
pub trait Endpoint {
    /// Sends a payload stamped with `round`.
    fn send(&mut self, round: u64) -> Result<()>;
    /// Waits (up to `timeout`) for the next payload and returns its stamp.
    fn recv(&mut self, timeout: Duration) -> Result<Option<u64>>;
}

struct HngEnd {
    _node: Node,
    tx: SlicePublisher<BytesInfo>,
    rx: SliceSubscriber<BytesInfo>,
    waiter: Waiter,
    size: usize,
}

impl HngEnd {
    fn new(
        prefix: &str,
        name: &str,
        tx: &str,
        rx: &str,
        size: usize,
        mode: Mode,
    ) -> Result<HngEnd> {
        let node = Node::new(NodeOptions::new(name).prefix(prefix))?;
        let tx = node.slice_publisher::<BytesInfo>(tx, size)?;
        let rx = node.slice_subscriber::<BytesInfo>(rx)?;
        let mut waiter = Waiter::new(wait_mode(mode))?;
        waiter.share_cpus(&node)?;
        waiter.attach(&rx)?;
        Ok(HngEnd {
            _node: node,
            tx,
            rx,
            waiter,
            size,
        })
    }
}

impl Drop for HngEnd {
    fn drop(&mut self) {
        if std::env::var_os("HNG_BENCH_DEBUG").is_some() {
            eprintln!(
                "{}: {:?}, notifications sent {}",
                self._node.name(),
                self.waiter.stats(),
                self.tx.notifications()
            );
        }
    }
}

impl Endpoint for HngEnd {
    fn send(&mut self, round: u64) -> Result<()> {
        let loan = self.tx.loan_uninit(self.size)?;
        // SAFETY: plain bytes; only the stamp is meaningful to the reader (see module docs).
        let mut loan = unsafe { loan.assume_init() };
        stamp(loan.payload_mut(), round);
        loan.publish()?;
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<u64>> {
        let sample = self.rx.receive_timeout(&mut self.waiter, timeout)?;
        Ok(sample.map(|s| read_stamp(s.data())))
    }
}

struct UdsEnd {
    stream: UnixStream,
    payload: Vec<u8>,
    frame: Vec<u8>,
    mode: Mode,
}

impl UdsEnd {
    fn new(stream: UnixStream, size: usize, mode: Mode) -> Result<UdsEnd> {
        stream.set_nonblocking(!mode.sleeps())?;
        Ok(UdsEnd {
            stream,
            payload: vec![0u8; size],
            frame: Vec::with_capacity(size + 16),
            mode,
        })
    }

    fn read_exact_spin(&mut self, buf_len: usize, end: Instant) -> Result<bool> {
        let mut got = 0;
        while got < buf_len {
            match self.stream.read(&mut self.frame[got..buf_len]) {
                Ok(0) => bail!("peer closed the socket"),
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if got == 0 && Instant::now() >= end {
                        return Ok(false);
                    }
                    std::hint::spin_loop();
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(true)
    }
}

impl Endpoint for UdsEnd {
    fn send(&mut self, round: u64) -> Result<()> {
        stamp(&mut self.payload, round);
        self.frame.clear();
        self.frame.extend_from_slice(&[0u8; 4]);
        let frame = postcard::to_extend(self.payload.as_slice(), std::mem::take(&mut self.frame))?;
        self.frame = frame;
        let len = (self.frame.len() - 4) as u32;
        self.frame[..4].copy_from_slice(&len.to_le_bytes());
        if !self.mode.sleeps() {
            self.stream.set_nonblocking(false)?;
            self.stream.write_all(&self.frame)?;
            self.stream.set_nonblocking(true)?;
        } else {
            self.stream.write_all(&self.frame)?;
        }
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<u64>> {
        let end = Instant::now() + timeout;
        self.frame.resize(4, 0);
        if self.mode.sleeps() {
            self.stream
                .set_read_timeout(Some(timeout.max(Duration::from_millis(1))))?;
            match self.stream.read_exact(&mut self.frame[..4]) {
                Ok(()) => {}
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Ok(None);
                }
                Err(e) => return Err(e.into()),
            }
            let len =
                u32::from_le_bytes([self.frame[0], self.frame[1], self.frame[2], self.frame[3]])
                    as usize;
            self.frame.resize(len, 0);
            self.stream.set_read_timeout(None)?;
            self.stream.read_exact(&mut self.frame[..len])?;
        } else {
            if !self.read_exact_spin(4, end)? {
                return Ok(None);
            }
            let len =
                u32::from_le_bytes([self.frame[0], self.frame[1], self.frame[2], self.frame[3]])
                    as usize;
            self.frame.resize(len.max(4), 0);
            self.read_exact_spin(len, Instant::now() + Duration::from_secs(10))?;
            self.frame.truncate(len);
        }
        let bytes: &[u8] =
            postcard::from_bytes(&self.frame).context("decoding a postcard frame")?;
        Ok(Some(read_stamp(bytes)))
    }
}

/// A running peer process and the local end talking to it.
pub struct Session {
    child: Child,
    end: Box<dyn Endpoint>,
    prefix: String,
    socket: Option<String>,
    round: u64,
}

impl Session {
    /// Starts the peer `exe __bench-peer ...` and connects to it.
    pub fn start(
        exe: &std::path::Path,
        transport: Transport,
        size: usize,
        mode: Mode,
    ) -> Result<Session> {
        let size = size.max(8);
        let prefix = shm::unique_prefix("bench");
        let socket = (transport == Transport::Uds).then(|| {
            std::env::temp_dir()
                .join(format!("{prefix}ipc.sock"))
                .to_string_lossy()
                .into_owned()
        });
        let listener = match &socket {
            Some(path) => {
                let _ = std::fs::remove_file(path);
                Some(UnixListener::bind(path).with_context(|| format!("binding {path}"))?)
            }
            None => None,
        };
        let mut cmd = Command::new(exe);
        cmd.args([
            "__bench-peer",
            "--transport",
            transport.name(),
            "--mode",
            mode.name(),
        ])
        .args(["--size", &size.to_string(), "--prefix", &prefix])
        .stdin(Stdio::null());
        if let Some(s) = &socket {
            cmd.args(["--socket", s]);
        }
        let child = cmd
            .spawn()
            .with_context(|| format!("starting the peer {}", exe.display()))?;
        let mut session = Session {
            child,
            end: Box::new(NoEnd),
            prefix: prefix.clone(),
            socket: socket.clone(),
            round: 0,
        };
        let stream = match listener {
            Some(l) => Some(l.accept().context("accepting the peer's connection")?.0),
            None => None,
        };
        session.end = endpoint(transport, &prefix, Side::Ping, size, mode, stream)?;
        // Handshake: the peer may not be subscribed yet, so ping until it answers.
        let mut ok = false;
        for _ in 0..1000 {
            session.end.send(0)?;
            if session.end.recv(Duration::from_millis(10))? == Some(0) {
                ok = true;
                break;
            }
        }
        if !ok {
            bail!("the {} peer never answered", transport.name());
        }
        while session.end.recv(Duration::from_millis(5))?.is_some() {}
        Ok(session)
    }

    /// One round trip; returns its duration.
    pub fn round_trip(&mut self) -> Result<Duration> {
        self.round += 1;
        let t0 = Instant::now();
        self.end.send(self.round)?;
        loop {
            match self.end.recv(Duration::from_secs(5))? {
                Some(r) if r == self.round => return Ok(t0.elapsed()),
                Some(_) => continue,
                None => bail!("no answer to round {} within 5 s", self.round),
            }
        }
    }

    /// Stops the peer and removes what the session created.
    pub fn finish(mut self) -> Result<()> {
        let _ = self.end.send(STOP);
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            if self.child.try_wait()?.is_some() {
                break;
            }
            if Instant::now() >= deadline {
                let _ = self.child.kill();
                let _ = self.child.wait();
                break;
            }
            let _ = self.end.send(STOP);
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(())
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        self.end = Box::new(NoEnd);
        shm::remove_prefix_files(&self.prefix);
        if let Some(s) = &self.socket {
            let _ = std::fs::remove_file(s);
        }
    }
}

/// Which end of the ping-pong.
#[derive(Debug, Clone, Copy)]
enum Side {
    Ping,
    Pong,
}

/// The local end of a session for `transport` (`stream`: the connected socket for `uds`).
fn endpoint(
    transport: Transport,
    prefix: &str,
    side: Side,
    size: usize,
    mode: Mode,
    stream: Option<UnixStream>,
) -> Result<Box<dyn Endpoint>> {
    let (name, tx, rx) = match side {
        Side::Ping => ("bench-ping", PING, PONG),
        Side::Pong => ("bench-pong", PONG, PING),
    };
    Ok(match transport {
        Transport::Hng => Box::new(HngEnd::new(prefix, name, tx, rx, size, mode)?),
        Transport::Iceoryx2 => {
            Box::new(RawEnd::<()>::new(prefix, name, tx, rx, size, mode, false)?)
        }
        Transport::Iceoryx2Header | Transport::Iceoryx2Spare => Box::new(RawEnd::<BytesInfo>::new(
            prefix,
            name,
            tx,
            rx,
            size,
            mode,
            transport == Transport::Iceoryx2Spare,
        )?),
        Transport::Uds => Box::new(UdsEnd::new(
            stream.ok_or_else(|| anyhow!("uds needs a connected socket"))?,
            size,
            mode,
        )?),
    })
}

struct NoEnd;
impl Endpoint for NoEnd {
    fn send(&mut self, _: u64) -> Result<()> {
        Ok(())
    }
    fn recv(&mut self, _: Duration) -> Result<Option<u64>> {
        Ok(None)
    }
}

/// The peer process: echo stamps until STOP.
pub fn peer(a: &PeerArgs) -> Result<()> {
    let stream = match &a.socket {
        Some(path) => {
            Some(UnixStream::connect(path).with_context(|| format!("connecting {path}"))?)
        }
        None => None,
    };
    let mut end = endpoint(a.transport, &a.prefix, Side::Pong, a.size, a.mode, stream)?;
    let idle_limit = Duration::from_secs(30);
    let mut idle = Instant::now();
    loop {
        match end.recv(Duration::from_millis(100))? {
            Some(STOP) => return Ok(()),
            Some(r) => {
                end.send(r)?;
                idle = Instant::now();
            }
            None if idle.elapsed() > idle_limit => bail!("no ping for {} s", idle_limit.as_secs()),
            None => {}
        }
    }
}

/// Measures one mode for every size and transport and returns one row per (size,
/// transport), sizes first.
///
/// The samples of each case are collected in `rounds` sessions, each with fresh processes;
/// a round runs every case once, the transports of a size back to back (in reverse order
/// every other round). Where the two processes land (which cores, which host CPUs under a
/// VM) moves the floor by 10-20 % from one session to the next on this project's machine,
/// and the host moves it by up to 2x for minutes: taking turns gives every case the same
/// share of good and bad conditions, so the ratios between transports and between sizes
/// measure the transports and the sizes, not the luck of one placement. The ratios are
/// paired: `p50_vs_iceoryx2` compares with raw iceoryx2 at the same size in the same round,
/// `p50_vs_smallest` with the same transport at the smallest size in the same round.
pub fn run_mode(
    exe: &std::path::Path,
    transports: &[Transport],
    sizes: &[usize],
    mode: Mode,
    samples: usize,
    rounds: usize,
    max: Duration,
) -> Result<Vec<BenchRow>> {
    let rounds = rounds.clamp(1, samples.max(1));
    let per_round = samples.div_ceil(rounds);
    let max_round = max / rounds as u32;
    let cases = sizes.len() * transports.len();
    let case = |si: usize, ti: usize| si * transports.len() + ti;
    let mut pooled: Vec<Vec<u64>> = vec![Vec::with_capacity(samples); cases];
    let mut round_p50: Vec<Vec<u64>> = vec![Vec::with_capacity(rounds); cases];
    for round in 0..rounds {
        for (si, &size) in sizes.iter().enumerate() {
            let order: Vec<usize> = if round % 2 == 0 {
                (0..transports.len()).collect()
            } else {
                (0..transports.len()).rev().collect()
            };
            for ti in order {
                let mut s = Session::start(exe, transports[ti], size, mode)?;
                for _ in 0..per_round.clamp(10, 200) / 10 {
                    s.round_trip()?;
                }
                let mut one_way = Vec::with_capacity(per_round);
                let start = Instant::now();
                while one_way.len() < per_round && start.elapsed() < max_round {
                    one_way.push(s.round_trip()?.as_nanos() as u64 / 2);
                }
                s.finish()?;
                round_p50[case(si, ti)].push(Percentiles::of(&mut one_way).p50_ns);
                pooled[case(si, ti)].extend(one_way);
            }
        }
    }
    let floor = transports.iter().position(|&t| t == Transport::Iceoryx2);
    // The like-for-like baseline: raw iceoryx2 loaning ahead as hng does.
    let baseline = transports
        .iter()
        .position(|&t| t == Transport::Iceoryx2Spare)
        .or(floor);
    let smallest = sizes
        .iter()
        .enumerate()
        .min_by_key(|&(_, &size)| size)
        .map(|(si, _)| si);
    let mut rows = Vec::with_capacity(cases);
    for (si, &size) in sizes.iter().enumerate() {
        for (ti, &t) in transports.iter().enumerate() {
            let c = case(si, ti);
            let p50s = &round_p50[c];
            let mut row = BenchRow::new(
                "ipc",
                &format!("{}/{}/{}", t.name(), size, mode.name()),
                Percentiles::of(&mut pooled[c]),
            )
            .with("transport", t.name())
            .with("size", size as u64)
            .with("mode", mode.name())
            .with("rounds", rounds as u64)
            .with("round_p50_min_ns", p50s.iter().copied().min().unwrap_or(0))
            .with("round_p50_max_ns", p50s.iter().copied().max().unwrap_or(0))
            .with("hng_spins", t == Transport::Hng && mode.hng_spins());
            if let Some(b) = baseline.filter(|&b| b != ti) {
                row = row.with("baseline", transports[b].name()).with(
                    "p50_vs_baseline",
                    paired_ratio(p50s, &round_p50[case(si, b)]),
                );
            }
            if let Some(f) = floor.filter(|&f| f != ti) {
                row = row.with(
                    "p50_vs_iceoryx2",
                    paired_ratio(p50s, &round_p50[case(si, f)]),
                );
            }
            if let Some(m) = smallest.filter(|&m| m != si) {
                row = row.with(
                    "p50_vs_smallest",
                    paired_ratio(p50s, &round_p50[case(m, ti)]),
                );
            }
            rows.push(row);
        }
    }
    Ok(rows)
}

/// The median over rounds of `a`'s p50 divided by `b`'s p50 in the same round: sessions of
/// one round run back to back, so each ratio compares the transports under the same
/// conditions, and the median ignores a round in which the conditions changed midway.
fn paired_ratio(a: &[u64], b: &[u64]) -> f64 {
    let mut r: Vec<f64> = a
        .iter()
        .zip(b)
        .filter(|&(_, &b)| b > 0)
        .map(|(&a, &b)| a as f64 / b as f64)
        .collect();
    if r.is_empty() {
        return f64::NAN;
    }
    r.sort_by(f64::total_cmp);
    let n = r.len();
    if n % 2 == 1 {
        r[n / 2]
    } else {
        (r[n / 2 - 1] + r[n / 2]) / 2.0
    }
}

pub fn run(a: &IpcArgs) -> Result<()> {
    let exe = std::env::current_exe().context("locating the hng executable")?;
    let max = Duration::from_secs_f64(a.max_seconds.max(0.01));
    let mut rows = Vec::new();
    for &mode in &a.mode {
        let mode_rows = run_mode(&exe, &a.transport, &a.sizes, mode, a.samples, a.rounds, max)?;
        if a.json {
            for row in &mode_rows {
                println!("{}", row.to_json());
            }
        }
        rows.extend(mode_rows);
    }
    if !a.json {
        super::print_rows(&rows, false);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::paired_ratio;

    #[test]
    fn paired_ratio_compares_rounds_and_ignores_one_odd_round() {
        // Conditions changed between rounds (the floor doubled) and within round 3.
        let hng = [110, 220, 500, 110, 220];
        let raw = [100, 200, 100, 100, 200];
        assert!((paired_ratio(&hng, &raw) - 1.1).abs() < 1e-9);
        assert!((paired_ratio(&hng[..2], &raw[..2]) - 1.1).abs() < 1e-9);
        assert!(paired_ratio(&[1], &[0]).is_nan());
    }
}
