//! Starting a module's process: environment, signals, process group, log capture, pidfd.

use super::*;

impl<H: SupervisorHooks> Supervisor<H> {
    pub(super) fn spawn(&mut self, i: usize, now: Instant) {
        let spec = &self.slots[i].spec;
        let mut cmd = Command::new(&spec.program);
        cmd.args(&spec.args)
            .envs(&self.opts.env)
            .envs(&spec.env)
            .env("HNG_MODULE_NAME", &spec.name)
            .env("HNG_RESTART_COUNT", self.slots[i].restarts.to_string())
            .env("HNG_SUPERVISOR_PID", std::process::id().to_string())
            .stdin(Stdio::null());
        if let Some(hb) = spec.heartbeat {
            cmd.env("HNG_HEARTBEAT_PERIOD_MS", hb.period.as_millis().to_string());
        }
        if let Some(p) = spec.checkpoint_period {
            cmd.env("HNG_CHECKPOINT_PERIOD_MS", p.as_millis().to_string());
        }
        if self.opts.process_group {
            cmd.process_group(0);
        }
        if let Some(logs) = &self.opts.logs
            && let Err(e) = logs.capture(&spec.name, &mut cmd)
        {
            tracing::warn!(
                module = %spec.name,
                file = %logs.path(&spec.name).display(),
                "cannot write the module's log file ({e}); its output goes to the supervisor's stderr"
            );
        }
        let kill_on_exit = self.opts.kill_on_supervisor_exit;
        let parent = sys::getpid();
        // SAFETY: the closure only makes async-signal-safe syscalls and
        // does not allocate.
        unsafe {
            cmd.pre_exec(move || {
                sys::reset_signals()?;
                if kill_on_exit {
                    sys::set_parent_death_kill(parent)?;
                }
                Ok(())
            });
        }
        let spawned = self
            .hooks
            .before_spawn(spec, &mut cmd)
            .and_then(|()| cmd.spawn())
            .and_then(|mut child| match PidFd::open(child.id()) {
                Ok(fd) => Ok((child, fd)),
                Err(e) => {
                    let _ = child.kill();
                    let _ = child.wait();
                    Err(e)
                }
            })
            .and_then(|(child, pidfd)| {
                self.epoll.add(pidfd.as_fd(), i as u64)?;
                Ok((child, pidfd))
            });
        match spawned {
            Ok((child, pidfd)) => {
                let pid = child.id();
                let slot = &mut self.slots[i];
                slot.state = if slot.spec.heartbeat.is_some() {
                    ModuleState::Starting
                } else {
                    ModuleState::Running
                };
                if slot.start_seq.is_none() {
                    slot.start_seq = Some(self.seq);
                    self.seq += 1;
                }
                slot.proc_ = Some(Proc {
                    child,
                    pidfd,
                    pid,
                    started: now,
                    last_heartbeat: None,
                    promised: None,
                    kill_cause: None,
                    sent_sigkill: false,
                    stop: None,
                    kill_at: None,
                });
                let restarts = slot.restarts;
                self.push(now, i, EventKind::Started { pid, restarts });
            }
            Err(e) => {
                let error = format!("{}: {e}", self.slots[i].spec.program.display());
                tracing::warn!(module = %self.slots[i].spec.name, %error, "spawn failed");
                self.push(
                    now,
                    i,
                    EventKind::SpawnFailed {
                        error: error.clone(),
                    },
                );
                self.after_exit(
                    i,
                    now,
                    ExitCause::SpawnFailed { error },
                    Duration::ZERO,
                    None,
                );
            }
        }
    }
}
