//! The operator page from the command line (the server is the `hng-gui` crate; see
//! docs/operator.md):
//!
//! - `hng gui [--addr ADDR]`: serve the page for the system already running under the prefix;
//! - `hng run` serves it by default ([`start_for_run`]): the supervisor binds the address
//!   (so it can print it among its first lines, and report a busy port once and go on without
//!   the page), then hands the socket to a child process, `hng gui --listen-fd 3`, so that no
//!   fault of the page can take the supervisor down. The child dies with the supervisor
//!   (parent-death signal) and is stopped before the prefix's files are removed.

use std::net::{SocketAddr, TcpListener, ToSocketAddrs};
use std::os::fd::{AsRawFd, FromRawFd};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::Args;
use hng_gui::{DEFAULT_ADDR, Options, Server};
use nix::sys::signal::{SigSet, Signal};

/// The descriptor the listening socket has in the child.
const CHILD_FD: i32 = 3;

/// The environment variable that hands the token to the child (not its command line).
const TOKEN_ENV: &str = "HNG_GUI_TOKEN";

/// `hng gui`.
#[derive(Debug, Args)]
pub struct GuiArgs {
    /// Address to serve on, HOST:PORT (port 0: any free port). A non-loopback address
    /// requires an access token (printed at start).
    #[arg(long, default_value = DEFAULT_ADDR)]
    pub addr: String,
    /// The access token (default: a random one when the address is not loopback; none on
    /// loopback unless given).
    #[arg(long, env = TOKEN_ENV, hide_env_values = true)]
    pub token: Option<String>,
    /// Stop after this many seconds (default: until Ctrl-C or the system stops).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Serve on this already listening socket (what `hng run` passes).
    #[arg(long, hide = true)]
    pub listen_fd: Option<i32>,
}

/// The page's flags of `hng run`.
#[derive(Debug, Args)]
pub struct RunGuiArgs {
    /// Serve the operator page on ADDR (HOST:PORT; port 0 picks a free port; the address is
    /// printed at start; a non-loopback address requires the access token it prints).
    #[arg(long, value_name = "ADDR", env = "HNG_GUI", default_value = DEFAULT_ADDR)]
    pub gui: String,
    /// Do not serve the operator page.
    #[arg(long, env = "HNG_NO_GUI")]
    pub no_gui: bool,
    /// The page's access token (default: random when the address is not loopback).
    #[arg(long, env = TOKEN_ENV, hide_env_values = true)]
    pub gui_token: Option<String>,
}

/// `HOST:PORT`, `http://HOST:PORT/` or `PORT` as a socket address.
pub fn parse_addr(addr: &str) -> Result<SocketAddr> {
    let a = addr
        .trim()
        .trim_start_matches("http://")
        .trim_end_matches('/');
    let a = if a.parse::<u16>().is_ok() {
        format!("127.0.0.1:{a}")
    } else {
        a.to_owned()
    };
    a.to_socket_addrs()
        .with_context(|| {
            format!("operator page address {addr:?}: expected HOST:PORT, e.g. {DEFAULT_ADDR}")
        })?
        .next()
        .with_context(|| format!("operator page address {addr:?} resolves to nothing"))
}

/// The token to use on `addr`: the given one, or a random one off loopback.
fn token_for(addr: &SocketAddr, given: Option<&str>) -> Result<Option<String>> {
    match given.filter(|t| !t.is_empty()) {
        Some(t) => Ok(Some(t.to_owned())),
        None if hng_gui::is_loopback(addr) => Ok(None),
        None => Ok(Some(hng_gui::new_token()?)),
    }
}

fn url(addr: &SocketAddr, token: Option<&str>) -> String {
    let host = if addr.ip().is_unspecified() {
        "127.0.0.1".to_owned()
    } else if addr.is_ipv6() {
        format!("[{}]", addr.ip())
    } else {
        addr.ip().to_string()
    };
    match token {
        Some(t) => format!("http://{host}:{}/?token={t}", addr.port()),
        None => format!("http://{host}:{}/", addr.port()),
    }
}

/// `hng gui`.
pub fn run(prefix: &str, args: &GuiArgs) -> Result<()> {
    // `hng run` blocks the termination signals in every thread it starts; this process
    // reads them itself (below), so they stay blocked and are waited for.
    let mut mask = SigSet::empty();
    mask.add(Signal::SIGINT);
    mask.add(Signal::SIGTERM);
    mask.add(Signal::SIGHUP);
    mask.thread_block()
        .context("blocking the termination signals")?;
    let child = args.listen_fd.is_some();
    let listener = match args.listen_fd {
        // SAFETY: `hng run` put a listening socket on this descriptor for this process
        // (see `start_for_run`), and nothing else owns it.
        Some(fd) => unsafe { TcpListener::from_raw_fd(fd) },
        None => {
            hng_supervisor::status::ensure_system_exists(prefix)?;
            let addr = parse_addr(&args.addr)?;
            TcpListener::bind(addr)
                .with_context(|| format!("operator page: cannot listen on {addr}"))?
        }
    };
    let addr = listener.local_addr()?;
    let token = token_for(&addr, args.token.as_deref())?;
    let mut server = Server::start(
        listener,
        Options {
            prefix: prefix.to_owned(),
            token: token.clone(),
            channels: hng_gui::Channels::default(),
        },
    )?;
    if !child {
        outln!("operator page: {}", url(&addr, token.as_deref()))?;
        if let Some(t) = &token {
            outln!("access token: {t} (required on every order and on the live stream)")?;
        }
    }
    let (tx, rx) = mpsc::channel();
    std::thread::Builder::new()
        .name("gui-signals".into())
        .spawn(move || {
            if let Ok(sig) = mask.wait() {
                let _ = tx.send(sig);
            }
        })?;
    let end = args
        .duration
        .filter(|d| d.is_finite() && *d > 0.0)
        .map(|d| Instant::now() + Duration::from_secs_f64(d));
    loop {
        match rx.recv_timeout(Duration::from_millis(500)) {
            Ok(_) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
        if let Some(why) = server.failed() {
            server.stop();
            bail!("operator page: {why}");
        }
        if end.is_some_and(|e| Instant::now() >= e) {
            break;
        }
        if !child && hng_supervisor::lock::running_supervisor(prefix).is_none() {
            outln!("operator page: the system under prefix {prefix:?} stopped")?;
            break;
        }
    }
    server.stop();
    Ok(())
}

/// The page's process under `hng run`.
pub struct GuiChild {
    child: Child,
    reported: bool,
}

/// Binds the page's address, prints it and starts the page's process. A busy or bad address
/// is reported once and the run goes on without the page.
pub fn start_for_run(prefix: &str, args: &RunGuiArgs) -> Option<GuiChild> {
    if args.no_gui || args.gui.trim() == "off" {
        return None;
    }
    let started = (|| -> Result<GuiChild> {
        let addr = parse_addr(&args.gui)?;
        let listener = TcpListener::bind(addr).with_context(|| {
            format!("cannot listen on {addr} (--gui HOST:PORT picks another address, port 0 any free port, --no-gui none)")
        })?;
        let bound = listener.local_addr()?;
        let token = token_for(&bound, args.gui_token.as_deref())?;
        let exe = std::env::current_exe().context("finding the hng executable")?;
        let mut cmd = Command::new(exe);
        cmd.args(["--prefix", prefix, "gui", "--listen-fd"])
            .arg(CHILD_FD.to_string())
            .env_remove(TOKEN_ENV)
            .stdin(Stdio::null());
        if let Some(t) = &token {
            cmd.env(TOKEN_ENV, t);
        }
        let fd = listener.as_raw_fd();
        let parent = nix::unistd::getpid();
        // SAFETY: between fork and exec only async-signal-safe calls: dup2 (which leaves the
        // new descriptor open across exec), prctl and getppid.
        unsafe {
            use std::os::unix::process::CommandExt as _;
            cmd.pre_exec(move || {
                if nix::libc::dup2(fd, CHILD_FD) < 0 {
                    return Err(std::io::Error::last_os_error());
                }
                nix::sys::prctl::set_pdeathsig(Signal::SIGTERM).map_err(std::io::Error::from)?;
                // The supervisor died before the prctl: no signal will come, so do not start.
                if nix::unistd::getppid() != parent {
                    return Err(std::io::Error::from_raw_os_error(nix::libc::ESRCH));
                }
                Ok(())
            });
        }
        let child = cmd.spawn().context("starting the page's process")?;
        drop(listener);
        outln!("operator page: {}", url(&bound, token.as_deref()))?;
        if token.is_some() {
            outln!(
                "  (not a loopback address: the token in this address is required on every order and on the live stream)"
            )?;
        }
        Ok(GuiChild {
            child,
            reported: false,
        })
    })();
    match started {
        Ok(g) => Some(g),
        Err(e) => {
            let _ = outln!("operator page: not served: {e:#}; the run goes on without it");
            None
        }
    }
}

impl GuiChild {
    /// Says once if the page's process ended before the system.
    pub fn check(&mut self) {
        if self.reported {
            return;
        }
        if let Ok(Some(status)) = self.child.try_wait() {
            self.reported = true;
            // Never a panic on a closed stdout: the supervisor goes on.
            let _ = outln!(
                "operator page: its process ended ({status}); the system goes on without it"
            );
        }
    }

    fn stop(&mut self) {
        if let Ok(Some(_)) = self.child.try_wait() {
            return;
        }
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(3);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        tracing::warn!("operator page: its process did not stop within 3 s: killed");
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for GuiChild {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse() {
        assert_eq!(
            parse_addr("127.0.0.1:8080").unwrap(),
            "127.0.0.1:8080".parse().unwrap()
        );
        assert_eq!(
            parse_addr("http://127.0.0.1:0/").unwrap(),
            "127.0.0.1:0".parse().unwrap()
        );
        assert_eq!(parse_addr("9000").unwrap().port(), 9000);
        assert!(parse_addr("nowhere").is_err());
    }

    #[test]
    fn a_token_is_required_off_loopback_only() {
        let lo: SocketAddr = "127.0.0.1:1".parse().unwrap();
        let any: SocketAddr = "0.0.0.0:1".parse().unwrap();
        assert_eq!(token_for(&lo, None).unwrap(), None);
        assert_eq!(token_for(&lo, Some("t")).unwrap().as_deref(), Some("t"));
        assert_eq!(token_for(&any, None).unwrap().map(|t| t.len()), Some(32));
    }
}
