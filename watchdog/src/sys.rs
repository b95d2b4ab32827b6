//! Thin safe wrappers over the Linux calls the supervisor needs: pidfd,
//! epoll, eventfd. All `unsafe` of the crate is here.

use std::io;
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, FromRawFd, OwnedFd, RawFd};
use std::time::Duration;

fn cvt(r: libc::c_long) -> io::Result<libc::c_long> {
    if r < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(r)
    }
}

/// A process file descriptor (Linux 5.3+): readable once the process has
/// exited; signals sent through it cannot hit a recycled pid.
#[derive(Debug)]
pub struct PidFd(OwnedFd);

impl PidFd {
    /// Open a pidfd for `pid`. Race-free for our own unreaped children: the
    /// pid cannot be recycled before we wait for it.
    pub fn open(pid: u32) -> io::Result<Self> {
        let pid = libc::pid_t::try_from(pid)
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "pid out of range"))?;
        // SAFETY: pidfd_open takes (pid_t, unsigned int) and returns a new fd or -1.
        let fd = cvt(unsafe { libc::syscall(libc::SYS_pidfd_open, pid, 0 as libc::c_uint) })?;
        let fd = RawFd::try_from(fd)
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "fd out of range"))?;
        // SAFETY: the kernel just returned this fd to us; nobody else owns it.
        let owned = unsafe { OwnedFd::from_raw_fd(fd) };
        // pidfds are created O_CLOEXEC by the kernel.
        Ok(Self(owned))
    }

    /// Send `signal` to the process.
    pub fn send_signal(&self, signal: i32) -> io::Result<()> {
        // SAFETY: pidfd_send_signal(int pidfd, int sig, siginfo_t *info, unsigned int flags);
        // a null info makes the kernel fill it in as for kill(2).
        cvt(unsafe {
            libc::syscall(
                libc::SYS_pidfd_send_signal,
                self.0.as_raw_fd(),
                signal,
                std::ptr::null::<libc::siginfo_t>(),
                0 as libc::c_uint,
            )
        })
        .map(drop)
    }
}

impl AsFd for PidFd {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.0.as_fd()
    }
}

/// An epoll instance, level-triggered, each fd registered with a `u64` token.
#[derive(Debug)]
pub struct Epoll(OwnedFd);

impl Epoll {
    pub fn new() -> io::Result<Self> {
        // SAFETY: plain syscall returning a new fd or -1.
        let fd = unsafe { libc::epoll_create1(libc::EPOLL_CLOEXEC) };
        cvt(fd.into())?;
        // SAFETY: the kernel just returned this fd to us.
        Ok(Self(unsafe { OwnedFd::from_raw_fd(fd) }))
    }

    pub fn add(&self, fd: BorrowedFd<'_>, token: u64) -> io::Result<()> {
        let mut ev = libc::epoll_event {
            events: libc::EPOLLIN as u32,
            u64: token,
        };
        // SAFETY: both fds are valid for the duration of the call; ev is a valid pointer.
        let r = unsafe {
            libc::epoll_ctl(
                self.0.as_raw_fd(),
                libc::EPOLL_CTL_ADD,
                fd.as_raw_fd(),
                &mut ev,
            )
        };
        cvt(r.into()).map(drop)
    }

    pub fn delete(&self, fd: BorrowedFd<'_>) -> io::Result<()> {
        // SAFETY: both fds valid; a null event is allowed for EPOLL_CTL_DEL since Linux 2.6.9.
        let r = unsafe {
            libc::epoll_ctl(
                self.0.as_raw_fd(),
                libc::EPOLL_CTL_DEL,
                fd.as_raw_fd(),
                std::ptr::null_mut(),
            )
        };
        cvt(r.into()).map(drop)
    }

    /// Wait up to `timeout` (rounded up to whole milliseconds) and return the
    /// tokens of ready fds. EINTR yields an empty list.
    pub fn wait(&self, timeout: Duration) -> io::Result<Vec<u64>> {
        let ms = timeout.as_nanos().div_ceil(1_000_000);
        let ms = libc::c_int::try_from(ms).unwrap_or(libc::c_int::MAX);
        let mut events = [libc::epoll_event { events: 0, u64: 0 }; 32];
        // SAFETY: events is a valid writable buffer of the length passed.
        let n = unsafe {
            libc::epoll_wait(
                self.0.as_raw_fd(),
                events.as_mut_ptr(),
                events.len() as libc::c_int,
                ms,
            )
        };
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                return Ok(Vec::new());
            }
            return Err(e);
        }
        let n = usize::try_from(n).unwrap_or(0).min(events.len());
        Ok(events[..n].iter().map(|e| e.u64).collect())
    }
}

impl AsFd for Epoll {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.0.as_fd()
    }
}

/// A non-blocking eventfd used to wake the supervisor from another thread.
#[derive(Debug)]
pub struct EventFd(OwnedFd);

impl EventFd {
    pub fn new() -> io::Result<Self> {
        // SAFETY: plain syscall returning a new fd or -1.
        let fd = unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) };
        cvt(fd.into())?;
        // SAFETY: the kernel just returned this fd to us.
        Ok(Self(unsafe { OwnedFd::from_raw_fd(fd) }))
    }

    pub fn signal(&self) -> io::Result<()> {
        let one: u64 = 1;
        // SAFETY: writes 8 bytes from a valid u64.
        let r = unsafe {
            libc::write(
                self.0.as_raw_fd(),
                (&one as *const u64).cast(),
                std::mem::size_of::<u64>(),
            )
        };
        if r < 0 {
            let e = io::Error::last_os_error();
            // Counter saturated: a wake-up is pending anyway.
            if e.kind() == io::ErrorKind::WouldBlock {
                return Ok(());
            }
            return Err(e);
        }
        Ok(())
    }

    /// Reset the counter; returns whether it was signalled.
    pub fn drain(&self) -> bool {
        let mut buf: u64 = 0;
        // SAFETY: reads 8 bytes into a valid u64.
        let r = unsafe {
            libc::read(
                self.0.as_raw_fd(),
                (&mut buf as *mut u64).cast(),
                std::mem::size_of::<u64>(),
            )
        };
        r == std::mem::size_of::<u64>() as isize
    }
}

impl AsFd for EventFd {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.0.as_fd()
    }
}

/// This process' pid.
pub fn getpid() -> libc::pid_t {
    // SAFETY: getpid cannot fail.
    unsafe { libc::getpid() }
}

/// `prctl(PR_SET_PDEATHSIG, SIGKILL)` for use between fork and exec: the
/// child is killed if the thread that spawned it exits. If the parent
/// (`parent`) already died before the prctl, fail the spawn instead of
/// leaving an orphan.
pub fn set_parent_death_kill(parent: libc::pid_t) -> io::Result<()> {
    // SAFETY: async-signal-safe syscalls with integer arguments.
    let r = unsafe {
        libc::prctl(
            libc::PR_SET_PDEATHSIG,
            libc::SIGKILL as libc::c_ulong,
            0,
            0,
            0,
        )
    };
    cvt(r.into())?;
    // SAFETY: as above.
    if unsafe { libc::getppid() } != parent {
        // No allocation here (we are between fork and exec): a plain errno.
        return Err(io::Error::from_raw_os_error(libc::ESRCH));
    }
    Ok(())
}

/// For use between fork and exec: an empty signal mask and the default action for every
/// signal, so a module starts like a program started from a shell, whatever the supervisor
/// blocks or ignores (it blocks SIGINT, SIGTERM and SIGHUP in every thread to read them from
/// a signalfd; Rust ignores SIGPIPE). Without this a module that is not an hng module (a
/// shell script) inherited a blocked SIGTERM and was SIGKILLed after its stop timeout.
pub fn reset_signals() -> io::Result<()> {
    // The kernel's struct sigaction (all zero: SIG_DFL, no flags, empty mask, whatever the
    // architecture's layout): rt_sigaction(2) itself, because glibc's wrapper refuses
    // the signals it reserves (32, 33), which a parent may have set to SIG_IGN too.
    #[repr(C)]
    struct KernelSigaction {
        handler: libc::c_ulong,
        flags: libc::c_ulong,
        restorer: libc::c_ulong,
        mask: u64,
    }
    let default = KernelSigaction {
        handler: 0, // SIG_DFL
        flags: 0,
        restorer: 0,
        mask: 0,
    };
    for sig in 1..=64 {
        if sig == libc::SIGKILL || sig == libc::SIGSTOP {
            continue;
        }
        // SAFETY: async-signal-safe syscall with a valid struct of the kernel's layout and
        // its sigset size (8 bytes); errors (none expected) leave the signal as it was.
        unsafe {
            libc::syscall(
                libc::SYS_rt_sigaction,
                sig,
                &default as *const KernelSigaction,
                std::ptr::null_mut::<KernelSigaction>(),
                std::mem::size_of::<u64>(),
            );
        }
    }
    // SAFETY: as above; `set` is a valid sigset_t.
    let r = unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        libc::pthread_sigmask(libc::SIG_SETMASK, &set, std::ptr::null_mut())
    };
    if r != 0 {
        return Err(io::Error::from_raw_os_error(r));
    }
    Ok(())
}

/// Send `signal` to process group `pgid`. `ESRCH` (group empty) is not an error.
pub fn kill_group(pgid: u32, signal: i32) -> io::Result<()> {
    let pgid = libc::pid_t::try_from(pgid)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "pgid out of range"))?;
    if pgid <= 1 {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "refusing to signal pgid <= 1",
        ));
    }
    // SAFETY: plain syscall with integer arguments.
    let r = unsafe { libc::kill(-pgid, signal) };
    if r < 0 {
        let e = io::Error::last_os_error();
        if e.raw_os_error() == Some(libc::ESRCH) {
            return Ok(());
        }
        return Err(e);
    }
    Ok(())
}
