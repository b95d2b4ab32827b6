//! `hng topic pub CHANNEL JSON [--rate HZ] [--count N]`: publish a message by hand on a
//! channel of the running system (teleoperation, a goal), like `ros2 topic pub`.
//!
//! The channel must exist (some module subscribes to or publishes on it): its type tells how
//! to read the JSON. Numbers may be non-finite ("NaN", "inf", "-inf", or bare NaN, Infinity,
//! -Infinity), so that what modules do with them can be tried: the Robot and the Interface
//! count such commands as dropped and never forward them.

use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use hng_runtime::Node;
use hng_runtime::msg::{FrameId, Goal, Header, Message, PoseWithCovariance, Twist};
use hng_runtime::wait::{WaitMode, Waiter, Wake};
use hng_simulator::module::SimTeleport;
use serde_json::{Map, Value};

/// Rewrites bare `NaN`, `Infinity`, `-Infinity`, `inf`, `-inf` outside strings as strings,
/// so that serde_json reads them.
fn quote_non_finite(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 8);
    let mut in_string = false;
    let mut escaped = false;
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if in_string {
            out.push(c);
            if escaped {
                escaped = false;
            } else if c == '\\' {
                escaped = true;
            } else if c == '"' {
                in_string = false;
            }
            rest = &rest[c.len_utf8()..];
            continue;
        }
        if c == '"' {
            in_string = true;
            out.push(c);
            rest = &rest[1..];
            continue;
        }
        let word = ["-Infinity", "Infinity", "NaN", "-inf", "inf", "-nan", "nan"]
            .into_iter()
            .find(|w| {
                rest.starts_with(w)
                    && !rest[w.len()..]
                        .chars()
                        .next()
                        .is_some_and(|n| n.is_ascii_alphanumeric())
            });
        match word {
            Some(w) => {
                out.push('"');
                out.push_str(w);
                out.push('"');
                rest = &rest[w.len()..];
            }
            None => {
                out.push(c);
                rest = &rest[c.len_utf8()..];
            }
        }
    }
    out
}

/// A number from JSON: a number, or a string naming a non-finite value.
fn number(v: &Value, field: &str) -> Result<f64> {
    if let Some(x) = v.as_f64() {
        return Ok(x);
    }
    if let Some(s) = v.as_str() {
        match s.trim().to_ascii_lowercase().as_str() {
            "nan" | "-nan" => return Ok(f64::NAN),
            "inf" | "+inf" | "infinity" | "+infinity" => return Ok(f64::INFINITY),
            "-inf" | "-infinity" => return Ok(f64::NEG_INFINITY),
            t => {
                if let Ok(x) = t.parse::<f64>() {
                    return Ok(x);
                }
            }
        }
    }
    bail!("field `{field}`: expected a number (or \"NaN\", \"inf\", \"-inf\"), got {v}")
}

/// The JSON object's fields, each checked against `allowed`.
fn fields<'a>(
    obj: &'a Map<String, Value>,
    allowed: &[&str],
    ty: &str,
) -> Result<&'a Map<String, Value>> {
    for k in obj.keys() {
        if !allowed.contains(&k.as_str()) {
            bail!(
                "unknown field `{k}` for {ty}; its fields: {}",
                allowed.join(", ")
            );
        }
    }
    Ok(obj)
}

fn get(obj: &Map<String, Value>, field: &str) -> Result<f64> {
    obj.get(field).map_or(Ok(0.0), |v| number(v, field))
}

/// A Twist from `{"linear_x": .., "linear_y": .., "angular_z": ..}`.
pub fn twist(obj: &Map<String, Value>) -> Result<Twist> {
    let obj = fields(obj, &["linear_x", "linear_y", "angular_z"], "hng/Twist/v1")?;
    Ok(Twist {
        linear_x: get(obj, "linear_x")?,
        linear_y: get(obj, "linear_y")?,
        angular_z: get(obj, "angular_z")?,
        ..Twist::default()
    })
}

/// A Goal from `{"id", "x", "y", "theta", "tolerance_m", "use_theta"}`.
pub fn goal(obj: &Map<String, Value>) -> Result<Goal> {
    let obj = fields(
        obj,
        &["id", "x", "y", "theta", "tolerance_m", "use_theta"],
        "hng/Goal/v1",
    )?;
    let mut g = Goal::default();
    let id = get(obj, "id")?;
    if !(0.0..=f64::from(u32::MAX)).contains(&id) || id.fract() != 0.0 {
        bail!("field `id`: expected an integer from 0 to {}", u32::MAX);
    }
    g.id = id as u32;
    g.pose.x = get(obj, "x")?;
    g.pose.y = get(obj, "y")?;
    g.pose.theta = get(obj, "theta")?;
    g.tolerance_m = get(obj, "tolerance_m")?;
    g.use_theta = u8::from(get(obj, "use_theta")? != 0.0);
    Ok(g)
}

/// A pose in `map` from `{"x", "y", "theta", "sigma_m", "sigma_rad"}` (σ of x and y, and of
/// the heading; 0 or absent: the receiver's default).
pub fn pose(obj: &Map<String, Value>) -> Result<PoseWithCovariance> {
    let obj = fields(
        obj,
        &["x", "y", "theta", "sigma_m", "sigma_rad"],
        "hng/PoseWithCovariance/v1",
    )?;
    let mut p = PoseWithCovariance {
        header: Header {
            frame_id: FrameId::MAP,
            ..Header::default()
        },
        ..PoseWithCovariance::default()
    };
    p.pose.x = get(obj, "x")?;
    p.pose.y = get(obj, "y")?;
    p.pose.theta = get(obj, "theta")?;
    let (s, r) = (get(obj, "sigma_m")?, get(obj, "sigma_rad")?);
    p.covariance[0] = s * s;
    p.covariance[4] = s * s;
    p.covariance[8] = r * r;
    Ok(p)
}

fn type_name<T: iceoryx2::prelude::ZeroCopySend>() -> String {
    // SAFETY: only unsafe because implementors may lie; hng's are derived.
    unsafe { <T as iceoryx2::prelude::ZeroCopySend>::type_name() }.to_string()
}

/// `hng topic pub`.
pub fn run(
    prefix: &str,
    name: &str,
    json: &str,
    rate: Option<f64>,
    count: Option<u64>,
) -> Result<()> {
    if let Some(r) = rate
        && !(r.is_finite() && r > 0.0)
    {
        bail!("--rate must be a positive number of messages per second");
    }
    let value: Value = serde_json::from_str(&quote_non_finite(json))
        .with_context(|| format!("the message {json:?} is not JSON"))?;
    let Some(obj) = value.as_object() else {
        bail!("the message must be a JSON object, e.g. '{{\"linear_x\": 0.2}}'");
    };
    let list = crate::topic::channels(prefix)?;
    let Some(info) = list.iter().find(|c| c.name == name) else {
        bail!(
            "no channel {name:?} under prefix {prefix:?} (see `hng topic list`): publish on a channel some module uses"
        );
    };
    let node = crate::tool::node(prefix, "topic-pub")?;
    if info.type_name == type_name::<Twist>() {
        let msg = twist(obj)?;
        publish(&node, name, msg, rate, count)
    } else if info.type_name == type_name::<Goal>() {
        let msg = goal(obj)?;
        publish(&node, name, msg, rate, count)
    } else if info.type_name == type_name::<PoseWithCovariance>() {
        let msg = pose(obj)?;
        publish(&node, name, msg, rate, count)
    } else if info.type_name == type_name::<SimTeleport>() {
        let p = pose(obj)?;
        let msg = SimTeleport {
            pose: p.pose,
            ..SimTeleport::default()
        };
        publish(&node, name, msg, rate, count)
    } else {
        bail!(
            "channel {name:?} carries {}; `hng topic pub` writes hng/Twist/v1, hng/Goal/v1, hng/PoseWithCovariance/v1 and hng-simulator/SimTeleport/v1 (x, y, theta)",
            info.type_name
        )
    }
}

fn publish<T: Message>(
    node: &Node,
    name: &str,
    msg: T,
    rate: Option<f64>,
    count: Option<u64>,
) -> Result<()> {
    let publisher = node
        .publisher::<T>(name)
        .with_context(|| format!("publishing on {name}"))?;
    publisher.update_connections();
    let count = count.unwrap_or(if rate.is_some() { u64::MAX } else { 1 });
    let period = rate.map(|r| Duration::from_secs_f64(1.0 / r));
    let mut waiter = Waiter::new(WaitMode::SLEEP)?;
    waiter.catch_termination_signals()?;
    let mut next = Instant::now();
    let mut sent = 0u64;
    while sent < count {
        let left = next.saturating_duration_since(Instant::now());
        if !left.is_zero()
            && let Wake::Signal(_) = waiter.wait(Some(left))?
        {
            break;
        }
        if Instant::now() < next {
            continue;
        }
        publisher.update_connections();
        publisher.publish(msg)?;
        sent += 1;
        match period {
            Some(p) => next += p,
            None => next = Instant::now(),
        }
    }
    tracing::info!(channel = name, messages = sent, "published");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bare_non_finite_numbers_are_read_and_strings_left_alone() {
        let v: Value = serde_json::from_str(&quote_non_finite(
            r#"{"linear_x": NaN, "linear_y": -Infinity, "angular_z": inf, "s": "NaN inf"}"#,
        ))
        .expect("json");
        assert!(number(&v["linear_x"], "linear_x").expect("nan").is_nan());
        assert_eq!(
            number(&v["linear_y"], "y").expect("-inf"),
            f64::NEG_INFINITY
        );
        assert_eq!(number(&v["angular_z"], "z").expect("inf"), f64::INFINITY);
        assert_eq!(v["s"], "NaN inf");
    }

    #[test]
    fn twists_and_goals_from_json() {
        let v: Value =
            serde_json::from_str(r#"{"linear_x": 0.5, "angular_z": "-inf"}"#).expect("json");
        let t = twist(v.as_object().expect("object")).expect("twist");
        assert_eq!(t.linear_x, 0.5);
        assert_eq!(t.linear_y, 0.0);
        assert_eq!(t.angular_z, f64::NEG_INFINITY);
        let v: Value = serde_json::from_str(r#"{"linear_z": 1}"#).expect("json");
        let e = twist(v.as_object().expect("object")).expect_err("unknown field");
        assert!(e.to_string().contains("linear_z"), "{e}");
        let v: Value = serde_json::from_str(r#"{"id": 3, "x": 1, "y": 2}"#).expect("json");
        let g = goal(v.as_object().expect("object")).expect("goal");
        assert_eq!((g.id, g.pose.x, g.pose.y), (3, 1.0, 2.0));
        let v: Value = serde_json::from_str(r#"{"x": 1, "y": 2, "theta": 0.5, "sigma_m": 0.2}"#)
            .expect("json");
        let p = pose(v.as_object().expect("object")).expect("pose");
        assert_eq!((p.pose.x, p.pose.y, p.pose.theta), (1.0, 2.0, 0.5));
        assert_eq!(p.header.frame_id, FrameId::MAP);
        assert!((p.covariance[0] - 0.04).abs() < 1e-12 && p.covariance[8] == 0.0);
    }
}
