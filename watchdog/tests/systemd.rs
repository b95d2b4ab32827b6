//! sd_notify messages, in their own test binary because they set
//! `NOTIFY_SOCKET` in the process environment.

use std::os::unix::net::UnixDatagram;
use std::time::{Duration, Instant};

use hng_watchdog::systemd::SdNotify;

#[test]
fn notifies_only_with_socket_and_pings_at_half_interval() -> std::io::Result<()> {
    let dir = std::env::temp_dir().join(format!("hng-sdnotify-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let sock_path = dir.join("notify.sock");
    let _ = std::fs::remove_file(&sock_path);
    let sock = UnixDatagram::bind(&sock_path)?;
    sock.set_read_timeout(Some(Duration::from_secs(2)))?;

    // SAFETY: the only test of this binary; no other thread reads the environment.
    unsafe {
        std::env::remove_var("NOTIFY_SOCKET");
    }
    let mut off = SdNotify::from_env();
    assert!(!off.enabled());
    off.ready();
    assert!(!off.ping_if_due(Instant::now()));
    assert_eq!(off.next_ping_in(Instant::now()), None);

    // SAFETY: as above.
    unsafe {
        std::env::set_var("NOTIFY_SOCKET", &sock_path);
        std::env::set_var("WATCHDOG_USEC", "2000000");
        std::env::remove_var("WATCHDOG_PID");
    }
    let mut sd = SdNotify::from_env();
    assert!(sd.enabled());
    assert_eq!(sd.watchdog_interval(), Some(Duration::from_secs(1)));
    let mut buf = [0u8; 256];
    sd.ready();
    let n = sock.recv(&mut buf)?;
    assert_eq!(&buf[..n], b"READY=1\n");
    let t0 = Instant::now();
    assert!(sd.ping_if_due(t0));
    let n = sock.recv(&mut buf)?;
    assert_eq!(&buf[..n], b"WATCHDOG=1\n");
    assert!(!sd.ping_if_due(t0 + Duration::from_millis(500)));
    assert_eq!(
        sd.next_ping_in(t0 + Duration::from_millis(500)),
        Some(Duration::from_millis(500))
    );
    assert!(sd.ping_if_due(t0 + Duration::from_secs(1)));
    let n = sock.recv(&mut buf)?;
    assert_eq!(&buf[..n], b"WATCHDOG=1\n");
    sd.stopping();
    let n = sock.recv(&mut buf)?;
    assert_eq!(&buf[..n], b"STOPPING=1\n");
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
