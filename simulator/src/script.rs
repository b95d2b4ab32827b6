//! World scripts: timed changes of the world while the robot runs (a door closes, a box
//! appears, the light fades), and lighting zones that darken the camera's view near a place.
//!
//! ```toml
//! [[events]]
//! at_s = 12.0
//! lighting = 0.2                     # camera lighting factor from 12 s on (1 = normal)
//!
//! [[events]]
//! at_s = 20.0
//! add_box = { name = "door", center = [4.0, 1.0], size = [0.2, 1.6] }
//!
//! [[events]]
//! at_s = 40.0
//! remove_box = "door"
//!
//! [[lighting_zones]]
//! circle = { center = [8.0, 3.0], radius = 2.0 }
//! lighting = 0.15                    # while the camera is inside the circle
//! ```
//!
//! Events happen at the first physics step at or after `at_s` of simulated time, in file
//! order for equal times. They are a function of simulated time only, so a restored simulator
//! (checkpoint) rebuilds the same world by applying every event up to its time again. Boxes
//! added by a script are obstacles for physics, lidar and clearance; they are not in the known
//! map (`grid_from_world`): a script models what nobody drew.

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::world::{BoxObstacle, Circle, check, check_finite, check_nonneg, check_pos};

/// Largest lighting factor accepted (the renderer clamps to the same range).
pub const MAX_LIGHTING: f64 = 4.0;

/// A box a script adds, with the name a later event removes it by.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScriptBox {
    /// Name, unique among the script's boxes.
    pub name: String,
    /// Centre [x, y], metres.
    pub center: [f64; 2],
    /// Full size [along its x axis, along its y axis], metres.
    pub size: [f64; 2],
    /// Rotation, radians (default 0).
    #[serde(default)]
    pub angle: f64,
    /// Colour [r, g, b] in camera images.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<[u8; 3]>,
}

impl ScriptBox {
    /// The obstacle this box is.
    #[must_use]
    pub fn obstacle(&self) -> BoxObstacle {
        BoxObstacle {
            center: self.center,
            size: self.size,
            angle: self.angle,
            color: self.color,
        }
    }
}

/// One timed change of the world. Exactly one of `lighting`, `add_box`, `remove_box` is set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldEvent {
    /// Simulated time of the change, s.
    pub at_s: f64,
    /// New global lighting factor of the camera (1 = normal, lower is darker).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lighting: Option<f64>,
    /// A box that appears.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub add_box: Option<ScriptBox>,
    /// The name of a box an earlier event added, which disappears.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub remove_box: Option<String>,
}

/// What an event does, once validated.
#[derive(Debug, Clone, PartialEq)]
pub enum WorldChange<'a> {
    /// The global lighting factor becomes this.
    Lighting(f64),
    /// This box appears.
    AddBox(&'a ScriptBox),
    /// The box of this name disappears.
    RemoveBox(&'a str),
}

impl WorldEvent {
    /// The change this event makes (`None` only for an event that does not validate).
    #[must_use]
    pub fn change(&self) -> Option<WorldChange<'_>> {
        match (&self.lighting, &self.add_box, &self.remove_box) {
            (Some(l), None, None) => Some(WorldChange::Lighting(*l)),
            (None, Some(b), None) => Some(WorldChange::AddBox(b)),
            (None, None, Some(n)) => Some(WorldChange::RemoveBox(n)),
            _ => None,
        }
    }
}

/// A place where the camera sees darker (or brighter) while it is inside.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightingZone {
    /// The zone.
    pub circle: Circle,
    /// Lighting factor inside the zone (multiplies the global factor).
    pub lighting: f64,
}

/// Checks a script: times, one action per event, lighting ranges, box geometry, and that every
/// `remove_box` names a box added earlier and still there. Errors name the field
/// (`events[2].remove_box`).
pub fn validate(events: &[WorldEvent], zones: &[LightingZone]) -> Result<()> {
    let mut present: Vec<&str> = Vec::new();
    let mut last_at = 0.0;
    for (i, e) in events.iter().enumerate() {
        let field = |f: &str| format!("events[{i}].{f}");
        check_nonneg(e.at_s, &field("at_s"))?;
        check(
            e.at_s >= last_at,
            &field("at_s"),
            "events must be in time order",
        )?;
        last_at = e.at_s;
        let change = e.change();
        check(
            change.is_some(),
            &format!("events[{i}]"),
            "needs exactly one of lighting, add_box, remove_box",
        )?;
        match change {
            Some(WorldChange::Lighting(l)) => check_lighting(l, &field("lighting"))?,
            Some(WorldChange::AddBox(b)) => {
                let f = field("add_box");
                check(
                    !b.name.is_empty(),
                    &format!("{f}.name"),
                    "must not be empty",
                )?;
                check(
                    !present.contains(&b.name.as_str()),
                    &format!("{f}.name"),
                    &format!("a box named {:?} is already there", b.name),
                )?;
                b.obstacle().validate(&f)?;
                present.push(&b.name);
            }
            Some(WorldChange::RemoveBox(n)) => {
                let at = present.iter().position(|p| *p == n);
                check(
                    at.is_some(),
                    &field("remove_box"),
                    &format!("no box named {n:?} was added before"),
                )?;
                if let Some(at) = at {
                    present.remove(at);
                }
            }
            None => {}
        }
    }
    for (i, z) in zones.iter().enumerate() {
        check_finite(
            &z.circle.center,
            &format!("lighting_zones[{i}].circle.center"),
        )?;
        check_pos(
            z.circle.radius,
            &format!("lighting_zones[{i}].circle.radius"),
        )?;
        check_lighting(z.lighting, &format!("lighting_zones[{i}].lighting"))?;
    }
    Ok(())
}

fn check_lighting(l: f64, field: &str) -> Result<()> {
    check(
        l.is_finite() && (0.0..=MAX_LIGHTING).contains(&l),
        field,
        &format!("must be in [0, {MAX_LIGHTING}], got {l}"),
    )
}

/// The lighting factor at `(x, y)`: the global factor times every zone containing the point.
#[must_use]
pub fn lighting_at(global: f64, zones: &[LightingZone], x: f64, y: f64) -> f64 {
    zones
        .iter()
        .filter(|z| (x - z.circle.center[0]).hypot(y - z.circle.center[1]) <= z.circle.radius)
        .fold(global, |l, z| l * z.lighting)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ev(src: &str) -> Vec<WorldEvent> {
        #[derive(Deserialize)]
        struct F {
            events: Vec<WorldEvent>,
        }
        toml::from_str::<F>(src).expect("parses").events
    }

    #[test]
    fn a_script_that_adds_then_removes_a_box_validates() {
        let e = ev(r#"
            [[events]]
            at_s = 1.0
            add_box = { name = "door", center = [1.0, 2.0], size = [0.2, 1.0] }
            [[events]]
            at_s = 2.0
            remove_box = "door"
            [[events]]
            at_s = 2.0
            lighting = 0.3
        "#);
        validate(&e, &[]).expect("valid");
        assert_eq!(e[2].change(), Some(WorldChange::Lighting(0.3)));
    }

    #[test]
    fn bad_scripts_name_the_field() {
        let cases = [
            (
                "[[events]]\nat_s = 1.0\nremove_box = \"door\"",
                "events[0].remove_box",
            ),
            ("[[events]]\nat_s = 1.0", "events[0]"),
            (
                "[[events]]\nat_s = 1.0\nlighting = 0.5\nremove_box = \"x\"",
                "events[0]",
            ),
            ("[[events]]\nat_s = -1.0\nlighting = 0.5", "events[0].at_s"),
            (
                "[[events]]\nat_s = 1.0\nlighting = 9.0",
                "events[0].lighting",
            ),
            (
                "[[events]]\nat_s = 2.0\nlighting = 0.5\n[[events]]\nat_s = 1.0\nlighting = 0.5",
                "events[1].at_s",
            ),
        ];
        for (src, field) in cases {
            let err = validate(&ev(src), &[]).expect_err(src).to_string();
            assert!(err.contains(field), "{src}: {err} does not name {field}");
        }
    }

    #[test]
    fn lighting_multiplies_inside_zones_only() {
        let z = [LightingZone {
            circle: Circle {
                center: [0.0, 0.0],
                radius: 1.0,
            },
            lighting: 0.2,
        }];
        assert!((lighting_at(0.5, &z, 0.5, 0.0) - 0.1).abs() < 1e-12);
        assert!((lighting_at(0.5, &z, 2.0, 0.0) - 0.5).abs() < 1e-12);
    }
}
