//! `hng behaviours [--json] [--once]`: the behaviours attention offers now (the Interface's
//! `hng/behaviours` state channel, docs/autonomy.md). Follows the list: in a terminal one
//! readable line per change, otherwise (or with `--json`) one JSON object per change.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use clap::Args;
use hng_runtime::msg::{BEHAVIOURS_CHANNEL, Behaviours, OrderKind};

use hng_supervisor::doc::ensure_channel_exists;

/// `hng behaviours` options.
#[derive(Debug, Args)]
pub struct BehavioursArgs {
    /// One JSON object per change (the default when stdout is not a terminal).
    #[arg(long)]
    json: bool,
    /// Print the current list and exit.
    #[arg(long)]
    once: bool,
    /// With --once: how long to wait for the list, s.
    #[arg(long, default_value_t = 3.0)]
    timeout: f64,
}

/// One behaviour as the operator would order it (`follow-wall left`, `reach-beacon 3`).
pub fn label(kind: u32, param: i32) -> String {
    match OrderKind::from_u32(kind) {
        Some(OrderKind::FollowWall) => {
            format!("follow-wall {}", if param > 0 { "left" } else { "right" })
        }
        Some(OrderKind::ReachBeacon) => format!("reach-beacon {param}"),
        Some(k) => k.name().replace('_', "-"),
        None => format!("unknown kind {kind}"),
    }
}

fn text(b: &Behaviours) -> String {
    let items: Vec<String> = b
        .items()
        .iter()
        .map(|i| {
            if i.quality < 0.999 {
                format!("{} (Q {:.2})", label(i.kind, i.param), i.quality)
            } else {
                label(i.kind, i.param)
            }
        })
        .collect();
    format!(
        "[{:8.2} s] {}",
        b.header.stamp_ns as f64 * 1e-9,
        items.join(", ")
    )
}

/// Runs `hng behaviours`.
pub fn run(prefix: &str, args: &BehavioursArgs) -> Result<()> {
    if !args.timeout.is_finite() || args.timeout <= 0.0 {
        bail!("--timeout must be > 0");
    }
    ensure_channel_exists(
        prefix,
        BEHAVIOURS_CHANNEL,
        "Interface",
        "start a system with `hng run` or pass --prefix",
    )?;
    let (_node, sub, mut waiter) =
        crate::tool::reader::<Behaviours>(prefix, "behaviours", BEHAVIOURS_CHANNEL)?;
    let json = args.json || !std::io::stdout().is_terminal();
    let deadline = Instant::now() + Duration::from_secs_f64(args.timeout);
    loop {
        while let Some(b) = sub.receive()? {
            if json {
                outln!("{}", serde_json::to_string(&*b)?)?;
            } else {
                outln!("{}", text(&b))?;
            }
            if args.once {
                return Ok(());
            }
        }
        if args.once {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!(
                    "no behaviours list from the Interface within {:.1} s",
                    args.timeout
                );
            }
            waiter.wait(Some(left))?;
        } else {
            waiter.wait(Some(Duration::from_secs(1)))?;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_read_like_orders() {
        assert_eq!(label(OrderKind::FollowWall as u32, -1), "follow-wall right");
        assert_eq!(label(OrderKind::ReachBeacon as u32, 3), "reach-beacon 3");
        assert_eq!(label(OrderKind::Stop as u32, 0), "stop");
        assert_eq!(label(99, 0), "unknown kind 99");
    }
}
