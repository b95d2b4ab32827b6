//! Browsers watching the operator page during a bench (`hng bench loop --browsers N`): the
//! page server (hng-gui, in this process, on the bench's prefix and a free loopback port,
//! streaming the bench's channels) and N headless Chromium instances with the page open,
//! driven by `tests/system/js/watch.mjs` (node and the npm package playwright-core, as the
//! browser test uses them). [`Watchers::start`] says why when the machine has no browser.

use std::io::{BufRead as _, BufReader, Write as _};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use anyhow::{Context as _, Result, bail};
use hng_gui::{Channels, Server};
use nix::sched::CpuSet;
use serde_json::Value;

/// The folder of the browser drivers (the repository's tests/system/js).
pub fn js_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/system/js")
}

/// Why no headless browser can be driven on this machine, if none can: the one check of the
/// bench's browsers and of the real-browser tests (tests/system/gui.rs). It needs Chromium
/// (`/usr/bin/chromium`, or the one `CHROMIUM` names), node, and the npm package
/// playwright-core in [`js_dir`]; `.ci/run` installs all three when it can.
pub fn missing() -> Option<String> {
    let chromium = std::env::var_os("CHROMIUM")
        .map_or_else(|| PathBuf::from("/usr/bin/chromium"), PathBuf::from);
    if !chromium.exists() {
        return Some(format!(
            "no {} (CHROMIUM names another; .ci/run installs Debian's chromium with apt-get as root)",
            chromium.display()
        ));
    }
    let node_ok = Command::new("node")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !node_ok {
        return Some("no node (.ci/run installs nodejs and npm with apt-get as root)".into());
    }
    let js = js_dir();
    if !js.join("node_modules/playwright-core").exists() {
        return Some(format!(
            "no {}/node_modules/playwright-core (npm ci there installs it; .ci/run runs it)",
            js.display()
        ));
    }
    None
}

/// How the browsers are scheduled beside the loop (`hng bench loop --browser-priority`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BrowserPriority {
    /// `SCHED_IDLE`: they run only on a core nothing else wants, and any other task that wakes
    /// takes the core from them at once (standing for browsers on the operator's machine).
    Idle,
    /// Nice 19: the smallest share, but a waking loop process may still wait for the end of a
    /// browser's time slice (milliseconds: the kernel lets the current task run to parity).
    Low,
    /// The loop's own priority.
    Normal,
}

/// Starts `cmd` at `priority` and on `cpus` (all when `None`), for it and every process it
/// starts. Chromium raises its display threads to nice -8 when it may (as root, with
/// CAP_SYS_NICE): the capability is dropped from the bounding set first, so nothing below the
/// driver can raise its priority.
fn schedule(cmd: &mut Command, priority: BrowserPriority, cpus: Option<CpuSet>) {
    use std::os::unix::process::CommandExt as _;
    if priority == BrowserPriority::Normal && cpus.is_none() {
        return;
    }
    // SAFETY: between fork and exec only async-signal-safe calls (system calls) with plain
    // integers and stack values; the capability drop's failure (not root: nothing to drop)
    // changes nothing.
    unsafe {
        cmd.pre_exec(move || {
            if let Some(set) = &cpus {
                nix::sched::sched_setaffinity(nix::unistd::Pid::from_raw(0), set)?;
            }
            if priority == BrowserPriority::Normal {
                return Ok(());
            }
            let _ = nix::libc::prctl(nix::libc::PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0);
            let rc = match priority {
                BrowserPriority::Idle => {
                    let param = nix::libc::sched_param { sched_priority: 0 };
                    nix::libc::sched_setscheduler(0, nix::libc::SCHED_IDLE, &param)
                }
                _ => nix::libc::setpriority(nix::libc::PRIO_PROCESS, 0, 19),
            };
            if rc != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// `CAP_SYS_NICE` (linux/capability.h).
const CAP_SYS_NICE: nix::libc::c_ulong = 23;

/// The page server and the browsers; both stopped on drop.
pub struct Watchers {
    server: Option<Server>,
    driver: Child,
    stdin: Option<ChildStdin>,
    events: mpsc::Receiver<Value>,
    /// Scan frames each page had received when watching began.
    pub scans_at_start: Vec<u64>,
}

impl Watchers {
    /// Serves the page for `prefix` (the scan shown read from `scan`) and opens it in
    /// `browsers` headless Chromium instances scheduled at `priority` on `cpus`; returns
    /// once every page is connected to the live stream.
    pub fn start(
        prefix: &str,
        scan: &str,
        browsers: usize,
        priority: BrowserPriority,
        cpus: Option<CpuSet>,
    ) -> Result<Watchers> {
        let server = super::gui::serve_page(
            prefix,
            Channels {
                scan: scan.to_owned(),
                ..Channels::default()
            },
        )?;
        let url = format!("http://{}/", server.local_addr());
        let mut node = Command::new("node");
        schedule(&mut node, priority, cpus);
        let mut driver = node
            .arg(js_dir().join("watch.mjs"))
            .arg(&url)
            .arg(browsers.to_string())
            .current_dir(js_dir())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .context("starting node watch.mjs")?;
        let stdin = driver.stdin.take();
        let out = driver.stdout.take().context("the driver's stdout")?;
        let (tx, events) = mpsc::channel();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                let v = serde_json::from_str(&l).unwrap_or(Value::String(l));
                if tx.send(v).is_err() {
                    break;
                }
            }
        });
        let mut w = Watchers {
            server: Some(server),
            driver,
            stdin,
            events,
            scans_at_start: Vec::new(),
        };
        let e = w.next_event("watching", Duration::from_secs(120), "start")?;
        w.scans_at_start = scans(&e);
        Ok(w)
    }

    /// The driver's next event, which must be `event` and come within `timeout` (`what`: the
    /// step it ends, for the errors).
    fn next_event(&self, event: &str, timeout: Duration, what: &str) -> Result<Value> {
        let e = self
            .events
            .recv_timeout(timeout)
            .with_context(|| format!("the browsers did not {what} within {timeout:?}"))?;
        if e["event"] != event {
            bail!("the browsers did not {what}: {e}");
        }
        Ok(e)
    }

    /// Closes the browsers; returns the scan frames each page received while watching.
    pub fn finish(mut self) -> Result<Vec<u64>> {
        if let Some(mut s) = self.stdin.take() {
            let _ = writeln!(s, "stop");
        }
        let e = self.next_event("done", Duration::from_secs(60), "stop")?;
        let end = scans(&e);
        Ok(end
            .iter()
            .zip(&self.scans_at_start)
            .map(|(b, a)| b.saturating_sub(*a))
            .collect())
    }
}

fn scans(e: &Value) -> Vec<u64> {
    e["scans"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_u64).collect())
        .unwrap_or_default()
}

impl Drop for Watchers {
    fn drop(&mut self) {
        drop(self.stdin.take());
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        loop {
            match self.driver.try_wait() {
                Ok(Some(_)) => break,
                Ok(None) if std::time::Instant::now() < deadline => {
                    // Waiting for the driver to close its browsers: poll its status.
                    std::thread::sleep(Duration::from_millis(20));
                }
                _ => {
                    let _ = self.driver.kill();
                    let _ = self.driver.wait();
                    break;
                }
            }
        }
        if let Some(s) = self.server.take() {
            s.stop();
        }
    }
}
