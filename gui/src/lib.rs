//! hng's operator station (issue #20): a web page that shows the robot (maps, laser, pose
//! and its uncertainty, plan, goals, beacons, camera, modules, contracts, timeline) and sends
//! the operator's orders.
//!
//! The server is an hng node like any tool: it subscribes to the channels it shows and
//! publishes the operator's orders on the operator channels (`operator/order`,
//! `hng/teleop`, `operator/designation`) and module commands on the supervisor's command
//! channel. It is the Interface module's front end, not a side door.
//!
//! Threads: the bus thread ([`bus`]) reads the channels and keeps the latest frame of each
//! topic in the [`hub::Hub`]; the orders and control threads ([`send`]) publish; a small
//! tokio runtime serves HTTP and the WebSockets ([`server`]). A page gets the latest frame of
//! each topic at a bounded rate and never a backlog; a page that stops reading blocks only
//! its own task, and is dropped after [`server::SEND_TIMEOUT`].
//!
//! See docs/operator.md.

pub mod bus;
pub mod hub;
pub mod orders;
pub mod send;
pub mod server;

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

pub use bus::Channels;
pub use hub::Hub;

/// Default address of the page.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8080";

/// An error of the operator station.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The data plane.
    #[error(transparent)]
    Runtime(#[from] hng_runtime::Error),
    /// Sockets, threads.
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// What to serve.
#[derive(Debug, Clone)]
pub struct Options {
    /// The system's prefix.
    pub prefix: String,
    /// The access token required on `/api` and `/ws` (`None`: none).
    pub token: Option<String>,
    /// The channels shown.
    pub channels: Channels,
}

/// A running operator station.
pub struct Server {
    addr: SocketAddr,
    hub: Arc<Hub>,
    stop: Arc<AtomicBool>,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    runtime: Option<tokio::runtime::Runtime>,
    threads: Vec<Worker>,
}

/// A worker thread and its name.
type Worker = (&'static str, JoinHandle<Result<(), Error>>);

/// A random access token (128 bits from the OS, hex).
pub fn new_token() -> Result<String, Error> {
    use std::io::Read as _;
    let mut b = [0u8; 16];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut b)?;
    Ok(b.iter().map(|x| format!("{x:02x}")).collect())
}

fn first_seq() -> u32 {
    // A front end starts its order numbers at a random place (Order::seq).
    new_token()
        .ok()
        .and_then(|t| u32::from_str_radix(&t[..7], 16).ok())
        .unwrap_or(1)
        .max(1)
}

/// Nice value of the threads that build and send the view (the bus reader and the HTTP
/// workers): a page never takes a core from the control loop. Orders go out on threads of
/// normal priority (`orders`, `control`); an order's HTTP request is read by a worker at this
/// value, which under full load can delay it by a scheduler slice (milliseconds).
pub const VIEW_NICE: i32 = 10;

fn view_priority() {
    if let Err(e) = hng_runtime::cpus::lower_thread_priority(VIEW_NICE) {
        tracing::debug!("operator page: the view's thread keeps its priority: {e}");
    }
}

impl Server {
    /// Serves on `listener` (already bound: the caller printed its address).
    pub fn start(listener: std::net::TcpListener, opts: Options) -> Result<Server, Error> {
        let addr = listener.local_addr()?;
        listener.set_nonblocking(true)?;
        let hub = Arc::new(Hub::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (out_tx, out_rx) = std::sync::mpsc::channel();
        let (ctl_tx, ctl_rx) = std::sync::mpsc::channel();
        let mut threads = Vec::new();
        let spawn = |name: &'static str,
                     f: Box<dyn FnOnce() -> Result<(), Error> + Send>|
         -> Result<Worker, Error> {
            Ok((
                name,
                std::thread::Builder::new()
                    .name(format!("gui-{name}"))
                    .spawn(f)?,
            ))
        };
        {
            let (hub, stop) = (Arc::clone(&hub), Arc::clone(&stop));
            let bus = bus::BusOptions {
                prefix: opts.prefix.clone(),
                channels: opts.channels.clone(),
            };
            threads.push(spawn(
                "bus",
                Box::new(move || {
                    view_priority();
                    bus::run(&bus, &hub, &stop)
                }),
            )?);
        }
        {
            let (prefix, stop) = (opts.prefix.clone(), Arc::clone(&stop));
            threads.push(spawn(
                "orders",
                Box::new(move || send::orders(&prefix, &out_rx, &stop)),
            )?);
        }
        {
            let (prefix, stop) = (opts.prefix.clone(), Arc::clone(&stop));
            threads.push(spawn(
                "control",
                Box::new(move || send::control(&prefix, &ctl_rx, &stop)),
            )?);
        }
        let app = Arc::new(server::App::new(
            Arc::clone(&hub),
            send::Senders {
                out: out_tx,
                control: ctl_tx,
            },
            opts.token.clone(),
            opts.prefix.clone(),
            first_seq(),
        ));
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("gui-http")
            .on_thread_start(view_priority)
            .enable_all()
            .build()?;
        let (shutdown, on_shutdown) = tokio::sync::oneshot::channel::<()>();
        let listener = {
            let _guard = runtime.enter();
            tokio::net::TcpListener::from_std(listener)?
        };
        runtime.spawn(async move {
            let serve = axum::serve(listener, server::router(app)).with_graceful_shutdown(async {
                let _ = on_shutdown.await;
            });
            if let Err(e) = serve.await {
                tracing::error!("operator page: server stopped: {e}");
            }
        });
        Ok(Server {
            addr,
            hub,
            stop,
            shutdown: Some(shutdown),
            runtime: Some(runtime),
            threads,
        })
    }

    /// The address served.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The live frames (benchmarks read their latencies here).
    pub fn hub(&self) -> &Arc<Hub> {
        &self.hub
    }

    /// Whether a worker thread ended (with its error): the station no longer works.
    pub fn failed(&mut self) -> Option<String> {
        let i = self.threads.iter().position(|(_, t)| t.is_finished())?;
        let (name, t) = self.threads.remove(i);
        Some(match t.join() {
            Ok(Ok(())) => format!("the {name} thread ended"),
            Ok(Err(e)) => format!("the {name} thread failed: {e}"),
            Err(_) => format!("the {name} thread panicked"),
        })
    }

    /// Stops serving: clients are disconnected, the threads end and their nodes go.
    pub fn stop(mut self) {
        self.stop_inner();
    }

    fn stop_inner(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(s) = self.shutdown.take() {
            let _ = s.send(());
        }
        if let Some(rt) = self.runtime.take() {
            // WebSocket tasks do not end by themselves: the runtime's end cancels them.
            rt.shutdown_timeout(std::time::Duration::from_secs(1));
        }
        for (name, t) in self.threads.drain(..) {
            match t.join() {
                Ok(Ok(())) => {}
                Ok(Err(e)) => tracing::warn!("operator page: {name} thread: {e}"),
                Err(_) => tracing::warn!("operator page: {name} thread panicked"),
            }
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop_inner();
    }
}

/// Whether an address is served without a token (loopback only).
pub fn is_loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}
