//! The built-in world.

use super::*;

impl World {
    /// The built-in world: a 20 x 15 m area. The western part (x < 8) is an open yard with
    /// pillars and good GPS; the eastern part is a building with three rooms joined by doorways,
    /// where GPS is degraded (south rooms) or lost (north room). Six beacons.
    #[must_use]
    pub fn default_world() -> Self {
        let mut w = Self::empty(Pose2D::new(2.0, 2.0, 0.0));
        w.name = "default".to_owned();
        w.seed = 1;
        let wall = |a: [f64; 2], b: [f64; 2]| Wall::new(a, b);
        w.walls = vec![
            // Outer boundary.
            wall([0.0, 0.0], [20.0, 0.0]),
            wall([20.0, 0.0], [20.0, 15.0]),
            wall([20.0, 15.0], [0.0, 15.0]),
            wall([0.0, 15.0], [0.0, 0.0]),
            // Building west wall x = 8 with doorways at y 2..3.2 and 11..12.2.
            wall([8.0, 0.0], [8.0, 2.0]),
            wall([8.0, 3.2], [8.0, 11.0]),
            wall([8.0, 12.2], [8.0, 15.0]),
            // Wall y = 8 between north room and south rooms, doorway at x 12..13.2.
            wall([8.0, 8.0], [12.0, 8.0]),
            wall([13.2, 8.0], [20.0, 8.0]),
            // Wall x = 14 splitting the south part, doorway at y 4..5.2.
            wall([14.0, 0.0], [14.0, 4.0]),
            wall([14.0, 5.2], [14.0, 8.0]),
        ];
        let pillar = |center: [f64; 2], size: [f64; 2], angle: f64| BoxObstacle {
            center,
            size,
            angle,
            color: None,
        };
        w.boxes = vec![
            // Pillars in the yard.
            pillar([4.0, 5.0], [0.6, 0.6], 0.0),
            pillar([5.5, 10.0], [1.0, 0.5], 0.5),
            pillar([2.5, 12.5], [0.8, 0.8], PI / 4.0),
            // A table in the north room and a shelf in the south-east room.
            pillar([15.0, 11.5], [2.0, 1.0], 0.0),
            pillar([17.5, 2.0], [0.4, 2.0], 0.0),
        ];
        w.beacons = [
            [7.9, 6.0],
            [0.1, 7.5],
            [4.0, 14.9],
            [19.9, 12.0],
            [11.0, 0.1],
            [19.9, 4.0],
        ]
        .into_iter()
        .zip(1..)
        .map(|(position, id)| Beacon {
            id,
            position,
            radius: 0.1,
        })
        .collect();
        w.sensors.gps.zones = vec![
            GpsZone {
                name: "building south".to_owned(),
                kind: GpsZoneKind::Degraded,
                rect: Some(Rect {
                    min: [8.0, 0.0],
                    max: [20.0, 8.0],
                }),
                circle: None,
                noise_multiplier: 5.0,
            },
            GpsZone {
                name: "building north".to_owned(),
                kind: GpsZoneKind::Outage,
                rect: Some(Rect {
                    min: [8.0, 8.0],
                    max: [20.0, 15.0],
                }),
                circle: None,
                noise_multiplier: 1.0,
            },
            GpsZone {
                name: "tree".to_owned(),
                kind: GpsZoneKind::Degraded,
                rect: None,
                circle: Some(Circle {
                    center: [3.0, 9.0],
                    radius: 1.5,
                }),
                noise_multiplier: 3.0,
            },
        ];
        w
    }
}
