//! `hng order stop|teleop|release|goal|waypoints|reach-beacon|follow-wall|show`: the operator's
//! orders to the running Interface (adjustable autonomy, docs/autonomy.md).
//!
//! An order goes on `operator/order` with a fresh `seq`; the command waits for the
//! Interface's answer with that `seq` on `operator/order_status` and prints it. A refused order
//! exits 1 with the Interface's reason. The order is first checked here with the Interface's
//! own validation ([`hng_modules::interface::validate`]), so a malformed one is refused before
//! anything is sent.

use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use hng_modules::interface::{OrderLimits, validate};
use hng_runtime::msg::{
    MAX_ORDER_POINTS, ORDER_CHANNEL, ORDER_STATUS_CHANNEL, Order, OrderKind, OrderStatus, Pose2D,
    SIDE_LEFT, SIDE_RIGHT,
};
use hng_runtime::wait::{WaitMode, Waiter};
use hng_runtime::{Node, Publisher, Subscriber};

use hng_supervisor::doc::ensure_channel_exists;

/// How long a command waits for the Interface's answer.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(3);

/// `hng order ...`.
#[derive(Debug, Subcommand)]
pub enum OrderCommand {
    /// Software emergency stop: the robot stops and stays stopped until another order.
    Stop(OutArgs),
    /// Remote control: `hng/teleop` commands drive the robot (deadman 0.5 s).
    Teleop(OutArgs),
    /// Hand the robot back to autonomy (the Manager's mission).
    Release(OutArgs),
    /// Reach X,Y (map frame, m) under Human control, then back to autonomy.
    Goal {
        /// `X,Y` (put a negative x after `--`).
        point: String,
        /// Position tolerance, m (default: the Interface's, 0.2).
        #[arg(long)]
        tolerance: Option<f64>,
        #[command(flatten)]
        out: OutArgs,
    },
    /// Drive through X,Y points in order, then back to autonomy.
    Waypoints {
        /// `X,Y` points (1 to 16).
        points: Vec<String>,
        /// Position tolerance, m (default: the Interface's).
        #[arg(long)]
        tolerance: Option<f64>,
        #[command(flatten)]
        out: OutArgs,
    },
    /// Reach beacon N (only while it is seen: `hng behaviours`).
    #[command(name = "reach-beacon")]
    ReachBeacon {
        /// Beacon id.
        id: u32,
        /// Stop this far from it, m (default: the reacher's).
        #[arg(long)]
        distance: Option<f64>,
        #[command(flatten)]
        out: OutArgs,
    },
    /// Follow the wall on one side (only while one is detected there: `hng behaviours`).
    #[command(name = "follow-wall")]
    FollowWall {
        /// `left` or `right`.
        side: Side,
        /// Distance to keep, m (default: the follower's, 0.6).
        #[arg(long)]
        distance: Option<f64>,
        #[command(flatten)]
        out: OutArgs,
    },
    /// The order in force now.
    Show(OutArgs),
}

/// Output options.
#[derive(Debug, Args, Clone, Copy)]
pub struct OutArgs {
    /// The Interface's answer as JSON.
    #[arg(long)]
    json: bool,
}

/// A wall side.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Side {
    /// The wall on the robot's left.
    Left,
    /// The wall on the robot's right.
    Right,
}

/// `X,Y` in metres.
pub fn parse_point(s: &str) -> Result<Pose2D> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 2 {
        bail!("point {s:?}: expected X,Y");
    }
    let num = |i: usize, axis: &str| -> Result<f64> {
        let v: f64 = parts[i]
            .parse()
            .with_context(|| format!("point {s:?}: {axis} {:?} is not a number", parts[i]))?;
        if !v.is_finite() {
            bail!("point {s:?}: {axis} is not finite");
        }
        Ok(v)
    };
    Ok(Pose2D::new(num(0, "x")?, num(1, "y")?, 0.0))
}

/// Builds the order a command asks for (`None`: `show`).
fn build(cmd: &OrderCommand) -> Result<Option<Order>> {
    let with_points = |kind: OrderKind, pts: &[String], tol: Option<f64>| -> Result<Order> {
        if pts.len() > MAX_ORDER_POINTS {
            bail!("at most {MAX_ORDER_POINTS} points ({} given)", pts.len());
        }
        let mut o = Order::new(kind);
        for (i, p) in pts.iter().enumerate() {
            o.points[i] = parse_point(p)?;
        }
        o.count = pts.len() as u32;
        o.tolerance_m = tol.unwrap_or(0.0);
        Ok(o)
    };
    Ok(Some(match cmd {
        OrderCommand::Stop(_) => Order::new(OrderKind::Stop),
        OrderCommand::Teleop(_) => Order::new(OrderKind::Teleop),
        OrderCommand::Release(_) => Order::new(OrderKind::Release),
        OrderCommand::Goal {
            point, tolerance, ..
        } => with_points(OrderKind::Goal, std::slice::from_ref(point), *tolerance)?,
        OrderCommand::Waypoints {
            points, tolerance, ..
        } => with_points(OrderKind::Waypoints, points, *tolerance)?,
        OrderCommand::ReachBeacon { id, distance, .. } => {
            let mut o = Order::new(OrderKind::ReachBeacon);
            o.beacon_id = *id;
            o.distance_m = distance.unwrap_or(0.0);
            o
        }
        OrderCommand::FollowWall { side, distance, .. } => {
            let mut o = Order::new(OrderKind::FollowWall);
            o.side = match side {
                Side::Left => SIDE_LEFT,
                Side::Right => SIDE_RIGHT,
            };
            o.distance_m = distance.unwrap_or(0.0);
            o
        }
        OrderCommand::Show(_) => return Ok(None),
    }))
}

fn out_args(cmd: &OrderCommand) -> OutArgs {
    match cmd {
        OrderCommand::Stop(o)
        | OrderCommand::Teleop(o)
        | OrderCommand::Release(o)
        | OrderCommand::Show(o)
        | OrderCommand::Goal { out: o, .. }
        | OrderCommand::Waypoints { out: o, .. }
        | OrderCommand::ReachBeacon { out: o, .. }
        | OrderCommand::FollowWall { out: o, .. } => *o,
    }
}

/// A connection to the Interface: orders out, statuses in.
pub struct OrderLink {
    node: Node,
    orders: Publisher<Order>,
    status: Subscriber<OrderStatus>,
    waiter: Waiter,
    seq: u32,
}

impl OrderLink {
    /// Opens the order channels under `prefix` (the Interface must be running).
    pub fn open(prefix: &str, tool: &str) -> Result<OrderLink> {
        ensure_channel_exists(
            prefix,
            ORDER_STATUS_CHANNEL,
            "Interface",
            "start a system with `hng run` or pass --prefix",
        )?;
        let node = crate::tool::node(prefix, tool)?;
        let status = node
            .subscriber::<OrderStatus>(ORDER_STATUS_CHANNEL)
            .context("subscribing to the order status")?;
        let orders = node
            .publisher::<Order>(ORDER_CHANNEL)
            .context("opening the order channel")?;
        let mut waiter = Waiter::new(WaitMode::SLEEP)?;
        waiter.attach(&status)?;
        // A start that two front ends rarely share (the Interface echoes it).
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let seq = (std::process::id() << 12) ^ nanos;
        Ok(OrderLink {
            node,
            orders,
            status,
            waiter,
            seq: seq.max(1),
        })
    }

    /// The node (to open more ports).
    pub fn node(&self) -> &Node {
        &self.node
    }

    /// The latest status (the order in force), waiting up to `timeout` for one.
    pub fn current(&mut self, timeout: Duration) -> Result<OrderStatus> {
        self.next_where(timeout, |_| true)
    }

    fn next_where(
        &mut self,
        timeout: Duration,
        mut pred: impl FnMut(&OrderStatus) -> bool,
    ) -> Result<OrderStatus> {
        let deadline = Instant::now() + timeout;
        loop {
            while let Some(s) = self.status.receive()? {
                if pred(&s) {
                    return Ok(*s);
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!(
                    "no answer from the Interface of prefix {:?} within {timeout:?} (is it running?)",
                    self.node.prefix()
                );
            }
            self.waiter.wait(Some(left))?;
        }
    }

    /// Sends `order` with the next seq and waits for the Interface's answer to it.
    pub fn send(&mut self, mut order: Order, timeout: Duration) -> Result<OrderStatus> {
        self.seq = self.seq.wrapping_add(1).max(1);
        order.seq = self.seq;
        self.orders.update_connections();
        self.orders.publish(order).context("sending the order")?;
        let seq = self.seq;
        self.next_where(timeout, |s| s.seq == seq)
    }
}

fn print_status(s: &OrderStatus, json: bool) -> Result<()> {
    if json {
        outln!("{}", serde_json::to_string(s)?)?;
        return Ok(());
    }
    let in_force = if s.active != 0 {
        OrderKind::from_u32(s.in_force).map_or("?", OrderKind::name)
    } else {
        "none (autonomy)"
    };
    outln!("{}; order in force: {in_force}", s.reason())?;
    Ok(())
}

/// Runs `hng order`.
pub fn run(prefix: &str, cmd: OrderCommand) -> Result<()> {
    let out = out_args(&cmd);
    let order = build(&cmd)?;
    if let Some(o) = &order
        && let Err(why) = validate(o, &OrderLimits::default())
    {
        bail!("order not sent: {why}");
    }
    let mut link = OrderLink::open(prefix, "order")?;
    let Some(order) = order else {
        let s = link.current(ANSWER_TIMEOUT)?;
        return print_status(&s, out.json);
    };
    let s = link.send(order, ANSWER_TIMEOUT)?;
    if s.accepted == 0 {
        if out.json {
            print_status(&s, true)?;
        }
        bail!("order refused by the Interface: {}", s.reason());
    }
    print_status(&s, out.json)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_parse_and_bad_ones_are_named() {
        assert_eq!(parse_point("1.5, -2").unwrap(), Pose2D::new(1.5, -2.0, 0.0));
        let e = parse_point("1").unwrap_err().to_string();
        assert!(e.contains("expected X,Y"), "{e}");
        let e = parse_point("1,nan").unwrap_err().to_string();
        assert!(e.contains("y is not finite"), "{e}");
        let e = format!("{:#}", parse_point("a,2").unwrap_err());
        assert!(e.contains("x \"a\" is not a number"), "{e}");
    }

    #[test]
    fn commands_build_valid_orders() {
        let o = build(&OrderCommand::Waypoints {
            points: vec!["1,2".into(), "3,4".into()],
            tolerance: None,
            out: OutArgs { json: false },
        })
        .unwrap()
        .unwrap();
        assert_eq!(o.count, 2);
        assert!(validate(&o, &OrderLimits::default()).is_ok());
        let o = build(&OrderCommand::FollowWall {
            side: Side::Right,
            distance: Some(9.0),
            out: OutArgs { json: false },
        })
        .unwrap()
        .unwrap();
        assert!(validate(&o, &OrderLimits::default()).is_err());
    }
}
