//! The world script applied to a running [`Simulator`] (see [`crate::script`]).

use super::{Simulator, box_collider, secs_to_ns};
use crate::script::{WorldChange, lighting_at};
use crate::world::BoxObstacle;

impl Simulator {
    /// The camera's lighting factor now: the script's global factor times the lighting zones
    /// the robot is in (1 = normal).
    #[must_use]
    pub fn lighting(&self) -> f64 {
        lighting_at(
            self.lighting,
            &self.world.lighting_zones,
            self.pose.x,
            self.pose.y,
        )
    }

    /// The boxes the world script has added and not removed, with their names.
    pub fn script_boxes(&self) -> impl Iterator<Item = (&str, &BoxObstacle)> {
        self.script_boxes.iter().map(|(n, _, b)| (n.as_str(), b))
    }

    /// Applies every scripted event due by now, in order.
    pub(super) fn apply_due_events(&mut self) {
        let mut moved = false;
        while let Some(e) = self.world.events.get(self.next_event) {
            if secs_to_ns(e.at_s) > self.now_ns {
                break;
            }
            self.next_event += 1;
            match e.change() {
                Some(WorldChange::Lighting(l)) => {
                    tracing::info!(at_s = e.at_s, lighting = l, "world script: lighting");
                    self.lighting = l;
                }
                Some(WorldChange::AddBox(b)) => {
                    tracing::info!(at_s = e.at_s, name = %b.name, "world script: box added");
                    let obstacle = b.obstacle();
                    let h = self.phys.insert_collider(box_collider(&obstacle), None);
                    self.script_boxes.push((b.name.clone(), h, obstacle));
                    moved = true;
                }
                Some(WorldChange::RemoveBox(name)) => {
                    tracing::info!(at_s = e.at_s, name, "world script: box removed");
                    if let Some(i) = self.script_boxes.iter().position(|(n, ..)| n == name) {
                        let (_, h, _) = self.script_boxes.remove(i);
                        self.phys.remove_collider(h);
                        moved = true;
                    }
                }
                None => {}
            }
        }
        if moved {
            // Keep the spatial index current for the sensors of this step.
            self.phys.detect_collisions(&(), &());
        }
    }

    /// Rebuilds the script's state at the current time (after a restore): the world as it
    /// was built, then every event up to now again.
    pub(super) fn replay_events(&mut self) {
        for (_, h, _) in self.script_boxes.drain(..) {
            self.phys.remove_collider(h);
        }
        self.lighting = 1.0;
        self.next_event = 0;
        self.apply_due_events();
    }
}

#[cfg(test)]
mod tests {
    use crate::script::{ScriptBox, WorldEvent};
    use crate::{Pose2D, Simulator, World};

    fn world() -> World {
        let mut w = World::empty(Pose2D::new(0.0, 0.0, 0.0));
        let event = |at_s, add: Option<ScriptBox>, remove: Option<&str>, lighting| WorldEvent {
            at_s,
            lighting,
            add_box: add,
            remove_box: remove.map(str::to_owned),
        };
        w.events = vec![
            event(
                0.5,
                Some(ScriptBox {
                    name: "door".into(),
                    center: [2.0, 0.0],
                    size: [0.2, 2.0],
                    angle: 0.0,
                    color: None,
                }),
                None,
                None,
            ),
            event(1.0, None, None, Some(0.25)),
            event(1.5, None, Some("door"), None),
        ];
        w
    }

    #[test]
    fn scripted_boxes_appear_and_vanish_for_the_sensors_and_lighting_changes() {
        let mut sim = Simulator::new(world()).expect("valid world");
        assert_eq!(sim.cast_ray([0.0, 0.0], 0.0, 10.0), None);
        assert!((sim.lighting() - 1.0).abs() < 1e-12);
        sim.run_until(600_000_000);
        let d = sim
            .cast_ray([0.0, 0.0], 0.0, 10.0)
            .expect("the door is there");
        assert!((d - 1.9).abs() < 0.01, "ray hits the door at {d}");
        assert_eq!(sim.script_boxes().count(), 1);
        sim.run_until(1_100_000_000);
        assert!((sim.lighting() - 0.25).abs() < 1e-12);
        sim.run_until(1_600_000_000);
        assert_eq!(sim.cast_ray([0.0, 0.0], 0.0, 10.0), None);
        assert_eq!(sim.script_boxes().count(), 0);
    }

    #[test]
    fn a_restored_simulator_rebuilds_the_scripted_world_of_its_time() {
        let mut sim = Simulator::new(world()).expect("valid world");
        sim.run_until(1_200_000_000);
        let snap = sim.snapshot();
        let mut fresh = Simulator::new(world()).expect("valid world");
        fresh.restore(&snap).expect("restores");
        assert_eq!(fresh.script_boxes().count(), 1);
        assert!((fresh.lighting() - 0.25).abs() < 1e-12);
        assert!(fresh.cast_ray([0.0, 0.0], 0.0, 10.0).is_some());
    }
}
