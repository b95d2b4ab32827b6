//! Attention: which behaviours the situation allows now (issue 17, HARPIC's attention).
//!
//! A behaviour is offered only while some module could sign its contract now with aptitude 1:
//! a provider of its service listens (the contract plane's provider count for the Interface's
//! needs) and the perception it rests on holds. "Follow wall (left)" needs a "Follow wall"
//! provider and a wall detected beside the robot on the left within `wall_range_m` in the
//! latest "Detect wall" data (no older than `fresh_s`); "reach beacon 3" needs a "Reach beacon"
//! provider and beacon 3 seen within the last `fresh_s` (the camera's observations, or a
//! tracker's `BeaconTrack` in state seen). Stop, teleop and release are always offered; goal
//! and waypoints while a "Reach goal" provider listens.
//!
//! The same core answers the Interface's question "may this order be put in force now?", so an
//! order for a behaviour not offered is refused with the reason.

use smart_default::SmartDefault;
use std::collections::BTreeMap;

use hng_runtime::msg::{Behaviour, Behaviours, MAX_BEHAVIOURS, OrderKind, SIDE_LEFT, Walls};

/// Which behaviour services have a provider listening now.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Providers {
    /// "Reach goal" (Planning).
    pub reach_goal: bool,
    /// "Follow wall" (the Wall follower).
    pub follow_wall: bool,
    /// "Reach beacon" (the Beacon reacher).
    pub reach_beacon: bool,
}

/// Attention's thresholds.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct AttentionConfig {
    /// A wall farther than this is not offered for following, m.
    #[default(1.5)]
    pub wall_range_m: f64,
    /// Perception older than this is forgotten, s.
    #[default(1.0)]
    pub fresh_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Seen {
    at_s: f64,
    quality: f32,
}

/// The perception attention rests on, and the behaviours it derives.
#[derive(Debug, Clone, Default)]
pub struct Attention {
    cfg: AttentionConfig,
    /// Wall beside the robot, by side (index 0 left, 1 right).
    walls: [Option<Seen>; 2],
    beacons: BTreeMap<u32, Seen>,
}

fn side_index(side: i32) -> Option<usize> {
    match side {
        1 => Some(0),
        -1 => Some(1),
        _ => None,
    }
}

impl Attention {
    /// Attention with these thresholds.
    pub fn new(cfg: AttentionConfig) -> Attention {
        Attention {
            cfg,
            ..Default::default()
        }
    }

    /// The walls of one scan, at simulated/common time `now_s`.
    pub fn on_walls(&mut self, walls: &Walls, now_s: f64) {
        for side in [SIDE_LEFT, -SIDE_LEFT] {
            let Some(i) = side_index(side) else { continue };
            let best = walls
                .walls()
                .iter()
                .filter(|w| w.side == side && w.beside != 0 && w.distance <= self.cfg.wall_range_m)
                .map(|w| (1.0 - (w.rmse as f64 / 0.05)).clamp(0.1, 1.0) as f32)
                .fold(None, |a: Option<f32>, q| Some(a.map_or(q, |a| a.max(q))));
            self.walls[i] = best.map(|quality| Seen {
                at_s: now_s,
                quality,
            });
        }
    }

    /// Beacon `id` seen (by the camera or a tracker) with this quality at `now_s`.
    pub fn on_beacon(&mut self, id: u32, quality: f32, now_s: f64) {
        self.beacons.insert(
            id,
            Seen {
                at_s: now_s,
                quality,
            },
        );
    }

    fn fresh(&self, s: &Seen, now_s: f64) -> bool {
        now_s - s.at_s <= self.cfg.fresh_s
    }

    /// Whether beacon `id` was seen recently.
    pub fn beacon_seen(&self, id: u32, now_s: f64) -> bool {
        self.beacons.get(&id).is_some_and(|s| self.fresh(s, now_s))
    }

    /// Whether a wall is detected beside the robot on `side` now.
    pub fn wall_on(&self, side: i32, now_s: f64) -> bool {
        side_index(side)
            .and_then(|i| self.walls[i])
            .is_some_and(|s| self.fresh(&s, now_s))
    }

    /// May an order of `kind` with `param` (side or beacon id) be put in force now? `Err`
    /// says why not.
    pub fn available(
        &self,
        kind: OrderKind,
        param: i64,
        providers: Providers,
        now_s: f64,
    ) -> Result<(), String> {
        match kind {
            OrderKind::Stop | OrderKind::Teleop | OrderKind::Release => Ok(()),
            OrderKind::Goal | OrderKind::Waypoints => {
                if providers.reach_goal {
                    Ok(())
                } else {
                    Err("no \"Reach goal\" provider (Planning) is running".into())
                }
            }
            OrderKind::FollowWall => {
                let name = if param == i64::from(SIDE_LEFT) {
                    "left"
                } else {
                    "right"
                };
                if !providers.follow_wall {
                    Err("no \"Follow wall\" provider (wall_follower) is running".into())
                } else if !self.wall_on(param as i32, now_s) {
                    Err(format!(
                        "follow wall {name} is not available: no wall detected on the {name} \
                         within {:.1} m",
                        self.cfg.wall_range_m
                    ))
                } else {
                    Ok(())
                }
            }
            OrderKind::ReachBeacon => {
                if !self.beacons.contains_key(&(param as u32)) {
                    Err(format!("beacon {param} is not known (never seen)"))
                } else if !self.beacon_seen(param as u32, now_s) {
                    Err(format!(
                        "reach beacon {param} is not available: not seen for {:.1} s",
                        now_s - self.beacons[&(param as u32)].at_s
                    ))
                } else if !providers.reach_beacon {
                    Err("no \"Reach beacon\" provider (beacon reacher) is running".into())
                } else {
                    Ok(())
                }
            }
        }
    }

    /// The behaviours offered now, in a fixed order (stop, teleop, release, goal, waypoints,
    /// follow wall left/right, reach beacon by id), at most [`MAX_BEHAVIOURS`].
    pub fn behaviours(&self, providers: Providers, now_s: f64) -> Behaviours {
        let mut out = Behaviours::default();
        let mut push = |kind: OrderKind, param: i32, quality: f32| {
            let n = out.count as usize;
            if n < MAX_BEHAVIOURS {
                out.items[n] = Behaviour {
                    kind: kind as u32,
                    param,
                    quality,
                };
                out.count += 1;
            }
        };
        push(OrderKind::Stop, 0, 1.0);
        push(OrderKind::Teleop, 0, 1.0);
        push(OrderKind::Release, 0, 1.0);
        if providers.reach_goal {
            push(OrderKind::Goal, 0, 1.0);
            push(OrderKind::Waypoints, 0, 1.0);
        }
        if providers.follow_wall {
            for side in [SIDE_LEFT, -SIDE_LEFT] {
                if let Some(s) = side_index(side).and_then(|i| self.walls[i])
                    && self.fresh(&s, now_s)
                {
                    push(OrderKind::FollowWall, side, s.quality);
                }
            }
        }
        if providers.reach_beacon {
            for (&id, s) in &self.beacons {
                if self.fresh(s, now_s) {
                    push(OrderKind::ReachBeacon, id as i32, s.quality);
                }
            }
        }
        out
    }
}

/// Two lists offer the same behaviours (qualities within 0.1 count as the same, so the list
/// is republished on a change of what is offered, not on every flicker of quality).
pub fn same_offer(a: &Behaviours, b: &Behaviours) -> bool {
    a.count == b.count
        && a.items().iter().zip(b.items()).all(|(x, y)| {
            x.kind == y.kind && x.param == y.param && (x.quality - y.quality).abs() < 0.1
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::msg::WallSegment;

    fn wall(side: i32, distance: f64) -> Walls {
        let mut w = Walls {
            count: 1,
            ..Default::default()
        };
        w.walls[0] = WallSegment {
            distance,
            side,
            beside: 1,
            length: 3.0,
            ..Default::default()
        };
        w
    }

    const ALL: Providers = Providers {
        reach_goal: true,
        follow_wall: true,
        reach_beacon: true,
    };

    fn kinds(b: &Behaviours) -> Vec<(OrderKind, i32)> {
        b.items()
            .iter()
            .map(|i| (OrderKind::from_u32(i.kind).unwrap(), i.param))
            .collect()
    }

    #[test]
    fn follow_wall_is_offered_only_on_the_side_of_a_near_fresh_wall() {
        let mut a = Attention::new(AttentionConfig::default());
        assert!(!kinds(&a.behaviours(ALL, 0.0)).contains(&(OrderKind::FollowWall, 1)));
        a.on_walls(&wall(1, 0.7), 1.0);
        let k = kinds(&a.behaviours(ALL, 1.2));
        assert!(k.contains(&(OrderKind::FollowWall, 1)), "{k:?}");
        assert!(!k.contains(&(OrderKind::FollowWall, -1)), "{k:?}");
        assert!(a.available(OrderKind::FollowWall, 1, ALL, 1.2).is_ok());
        let e = a
            .available(OrderKind::FollowWall, -1, ALL, 1.2)
            .unwrap_err();
        assert!(e.contains("no wall detected on the right"), "{e}");
        // Stale: forgotten.
        assert!(!kinds(&a.behaviours(ALL, 2.5)).contains(&(OrderKind::FollowWall, 1)));
        // Too far: not offered.
        a.on_walls(&wall(1, 3.0), 3.0);
        assert!(!a.wall_on(1, 3.0));
        // No provider: not offered even with a wall.
        a.on_walls(&wall(-1, 0.5), 4.0);
        let none = Providers::default();
        assert!(!kinds(&a.behaviours(none, 4.0)).contains(&(OrderKind::FollowWall, -1)));
        assert!(a.available(OrderKind::FollowWall, -1, none, 4.0).is_err());
    }

    #[test]
    fn beacons_are_offered_while_seen_and_unknown_ones_are_refused() {
        let mut a = Attention::new(AttentionConfig::default());
        a.on_beacon(3, 0.9, 10.0);
        assert!(kinds(&a.behaviours(ALL, 10.5)).contains(&(OrderKind::ReachBeacon, 3)));
        let e = a
            .available(OrderKind::ReachBeacon, 9, ALL, 10.5)
            .unwrap_err();
        assert!(e.contains("beacon 9 is not known"), "{e}");
        let e = a
            .available(OrderKind::ReachBeacon, 3, ALL, 12.0)
            .unwrap_err();
        assert!(e.contains("not seen for 2.0 s"), "{e}");
        assert!(a.available(OrderKind::ReachBeacon, 3, ALL, 10.9).is_ok());
    }

    #[test]
    fn goals_need_a_planner_and_offers_compare_by_content() {
        let a = Attention::new(AttentionConfig::default());
        let none = Providers::default();
        let b = a.behaviours(none, 0.0);
        assert_eq!(
            kinds(&b),
            vec![
                (OrderKind::Stop, 0),
                (OrderKind::Teleop, 0),
                (OrderKind::Release, 0)
            ]
        );
        assert!(a.available(OrderKind::Goal, 0, none, 0.0).is_err());
        assert!(same_offer(&b, &a.behaviours(none, 5.0)));
        assert!(!same_offer(&b, &a.behaviours(ALL, 5.0)));
    }
}
