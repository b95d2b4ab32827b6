//! `hng teleop`: drive the robot from the keyboard (arrows or WASD, space stops, q quits).
//!
//! It first gives the Interface a teleop order (so autonomy lets go of the robot), then
//! publishes `hng/teleop` commands: a key sets the command, which is repeated every 100 ms
//! while the key is held (the terminal's key repeat) and for `--hold` seconds after its last
//! repeat; after that nothing is sent and the Interface's deadman (0.5 s) stops the robot. So
//! letting go of the key, or losing the terminal, stops the robot. Security still limits
//! every command.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::Args;
use hng_runtime::msg::{Order, OrderKind, Twist};

use crate::order::OrderLink;

/// `hng teleop` options.
#[derive(Debug, Args)]
pub struct TeleopArgs {
    /// Forward/backward speed, m/s.
    #[arg(long, default_value_t = 0.3)]
    linear: f64,
    /// Turn rate, rad/s.
    #[arg(long, default_value_t = 0.8)]
    angular: f64,
    /// Keep repeating a command this long after its key's last repeat, s.
    #[arg(long, default_value_t = 0.3)]
    hold: f64,
    /// Do not send the teleop order (only publish commands: they still override autonomy
    /// while they come).
    #[arg(long)]
    no_order: bool,
    /// The teleoperation channel.
    #[arg(long, default_value = "hng/teleop")]
    channel: String,
}

/// The command of a key (`None`: not a driving key).
fn key_command(
    code: ratatui::crossterm::event::KeyCode,
    linear: f64,
    angular: f64,
) -> Option<Twist> {
    use ratatui::crossterm::event::KeyCode;
    let (v, w) = match code {
        KeyCode::Up | KeyCode::Char('w' | 'W') => (linear, 0.0),
        KeyCode::Down | KeyCode::Char('s' | 'S') => (-linear, 0.0),
        KeyCode::Left | KeyCode::Char('a' | 'A') => (0.0, angular),
        KeyCode::Right | KeyCode::Char('d' | 'D') => (0.0, -angular),
        KeyCode::Char(' ') => (0.0, 0.0),
        _ => return None,
    };
    Some(Twist {
        linear_x: v,
        angular_z: w,
        ..Default::default()
    })
}

/// Runs `hng teleop`.
pub fn run(prefix: &str, args: &TeleopArgs) -> Result<()> {
    use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
    use ratatui::crossterm::terminal;

    for (what, v) in [
        ("--linear", args.linear),
        ("--angular", args.angular),
        ("--hold", args.hold),
    ] {
        if !v.is_finite() || v < 0.0 {
            bail!("{what} must be finite and >= 0 (got {v})");
        }
    }
    if !std::io::stdin().is_terminal() {
        bail!("hng teleop reads the keyboard: run it in a terminal");
    }
    let mut link = OrderLink::open(prefix, "teleop")?;
    if !args.no_order {
        let s = link.send(Order::new(OrderKind::Teleop), Duration::from_secs(3))?;
        if s.accepted == 0 {
            bail!("teleop order refused by the Interface: {}", s.reason());
        }
    }
    let cmds = link
        .node()
        .publisher::<Twist>(&args.channel)
        .with_context(|| format!("opening {}", args.channel))?;
    outln!(
        "hng teleop: arrows or WASD drive, space stops, q quits (speed {:.2} m/s, turn {:.2} rad/s)\r",
        args.linear,
        args.angular
    )?;
    terminal::enable_raw_mode().context("raw terminal mode")?;
    let result = (|| -> Result<()> {
        let mut current = Twist::default();
        let mut last_key: Option<Instant> = None;
        let mut next_send = Instant::now();
        loop {
            let now = Instant::now();
            let live = last_key.is_some_and(|t| now.duration_since(t).as_secs_f64() <= args.hold);
            if live && now >= next_send {
                cmds.publish(current)?;
                next_send = now + Duration::from_millis(100);
            }
            if event::poll(Duration::from_millis(20))?
                && let Event::Key(k) = event::read()?
                && matches!(k.kind, KeyEventKind::Press | KeyEventKind::Repeat)
            {
                let ctrl_c =
                    k.code == KeyCode::Char('c') && k.modifiers.contains(KeyModifiers::CONTROL);
                if ctrl_c || matches!(k.code, KeyCode::Char('q') | KeyCode::Esc) {
                    cmds.publish(Twist::default())?;
                    return Ok(());
                }
                if let Some(c) = key_command(k.code, args.linear, args.angular) {
                    if c != current {
                        out!(
                            "\rcommand: linear {:+.2} m/s, angular {:+.2} rad/s   ",
                            c.linear_x,
                            c.angular_z
                        )?;
                        use std::io::Write as _;
                        std::io::stdout().flush()?;
                    }
                    current = c;
                    last_key = Some(Instant::now());
                    cmds.publish(current)?;
                    next_send = Instant::now() + Duration::from_millis(100);
                }
            }
        }
    })();
    let _ = terminal::disable_raw_mode();
    outln!()?;
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use ratatui::crossterm::event::KeyCode;

    #[test]
    fn keys_map_to_commands() {
        let c = key_command(KeyCode::Char('w'), 0.3, 0.8).unwrap();
        assert_eq!((c.linear_x, c.angular_z), (0.3, 0.0));
        let c = key_command(KeyCode::Right, 0.3, 0.8).unwrap();
        assert_eq!((c.linear_x, c.angular_z), (0.0, -0.8));
        let c = key_command(KeyCode::Char(' '), 0.3, 0.8).unwrap();
        assert_eq!((c.linear_x, c.angular_z), (0.0, 0.0));
        assert!(key_command(KeyCode::Char('x'), 0.3, 0.8).is_none());
    }
}
