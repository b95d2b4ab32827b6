//! Checking a world's values: every error names the field.

use std::f64::consts::TAU;

use super::*;

impl World {
    /// Checks every value; errors name the field.
    pub fn validate(&self) -> Result<()> {
        check(
            self.dt_s.is_finite() && self.dt_s > 0.0 && self.dt_s <= 1.0,
            "dt_s",
            "must be in (0, 1] seconds",
        )?;
        check(self.dt_s * 1e9 >= 1.0, "dt_s", "must be at least 1 ns")?;
        let r = &self.robot;
        check_finite(&[r.start.x, r.start.y, r.start.theta], "robot.start")?;
        check_pos(r.radius, "robot.radius")?;
        check_pos(r.max_linear_speed, "robot.max_linear_speed")?;
        check_pos(r.max_angular_speed, "robot.max_angular_speed")?;
        check_pos(r.max_linear_accel, "robot.max_linear_accel")?;
        check_pos(r.max_angular_accel, "robot.max_angular_accel")?;
        check_pos(r.cmd_timeout_s, "robot.cmd_timeout_s")?;
        for (i, w) in self.walls.iter().enumerate() {
            check_finite(&[w.from[0], w.from[1]], &format!("walls[{i}].from"))?;
            check_finite(&[w.to[0], w.to[1]], &format!("walls[{i}].to"))?;
            check_pos(w.thickness, &format!("walls[{i}].thickness"))?;
        }
        for (i, b) in self.boxes.iter().enumerate() {
            b.validate(&format!("boxes[{i}]"))?;
        }
        for (i, b) in self.beacons.iter().enumerate() {
            check_finite(
                &[b.position[0], b.position[1]],
                &format!("beacons[{i}].position"),
            )?;
            check(
                b.radius.is_finite() && b.radius >= 0.0,
                &format!("beacons[{i}].radius"),
                "must be finite and >= 0",
            )?;
            check(
                !self.beacons[..i].iter().any(|o| o.id == b.id),
                &format!("beacons[{i}].id"),
                &format!("id {} is used twice", b.id),
            )?;
        }
        let s = &self.sensors;
        let l = &s.lidar;
        check(
            l.beams >= 1 && l.beams <= 100_000,
            "sensors.lidar.beams",
            "must be in 1..=100000",
        )?;
        check_fov(l.fov, "sensors.lidar.fov")?;
        check_rate(l.rate, "sensors.lidar.rate")?;
        check_pos(l.max_range, "sensors.lidar.max_range")?;
        check(
            l.min_range.is_finite() && l.min_range >= 0.0 && l.min_range < l.max_range,
            "sensors.lidar.min_range",
            "must be >= 0 and less than max_range",
        )?;
        check_nonneg(l.range_sigma, "sensors.lidar.range_sigma")?;
        let o = &s.odometry;
        check_rate(o.rate, "sensors.odometry.rate")?;
        check(
            o.linear_scale_error.is_finite() && o.linear_scale_error > -1.0,
            "sensors.odometry.linear_scale_error",
            "must be finite and > -1",
        )?;
        check(
            o.angular_scale_error.is_finite() && o.angular_scale_error > -1.0,
            "sensors.odometry.angular_scale_error",
            "must be finite and > -1",
        )?;
        check_finite(&[o.heading_drift], "sensors.odometry.heading_drift")?;
        check_nonneg(o.linear_noise, "sensors.odometry.linear_noise")?;
        check_nonneg(o.angular_noise, "sensors.odometry.angular_noise")?;
        check_nonneg(
            o.angular_noise_per_metre,
            "sensors.odometry.angular_noise_per_metre",
        )?;
        let g = &s.gps;
        check_rate(g.rate, "sensors.gps.rate")?;
        check_nonneg(g.position_sigma, "sensors.gps.position_sigma")?;
        check_nonneg(g.yaw_sigma, "sensors.gps.yaw_sigma")?;
        for (i, z) in g.zones.iter().enumerate() {
            let f = format!("sensors.gps.zones[{i}]");
            match (&z.rect, &z.circle) {
                (Some(r), None) => check(
                    r.min.iter().chain(&r.max).all(|v| v.is_finite())
                        && r.min[0] < r.max[0]
                        && r.min[1] < r.max[1],
                    &format!("{f}.rect"),
                    "needs finite min < max in x and y",
                )?,
                (None, Some(c)) => {
                    check_finite(&c.center, &format!("{f}.circle.center"))?;
                    check_pos(c.radius, &format!("{f}.circle.radius"))?;
                }
                _ => {
                    return Err(SimError::invalid(
                        f,
                        "give exactly one of `rect` and `circle`",
                    ));
                }
            }
            check(
                z.noise_multiplier.is_finite() && z.noise_multiplier >= 1.0,
                &format!("{f}.noise_multiplier"),
                "must be finite and >= 1",
            )?;
        }
        let c = &s.camera;
        check_rate(c.rate, "sensors.camera.rate")?;
        check_fov(c.fov, "sensors.camera.fov")?;
        check_pos(c.max_range, "sensors.camera.max_range")?;
        check_nonneg(c.bearing_sigma, "sensors.camera.bearing_sigma")?;
        check_nonneg(c.range_sigma, "sensors.camera.range_sigma")?;
        check_rate(c.image_rate, "sensors.camera.image_rate")?;
        for (v, f) in [
            (c.width, "sensors.camera.width"),
            (c.height, "sensors.camera.height"),
        ] {
            check(
                (8..=4096).contains(&v),
                f,
                &format!("must be in 8..=4096 pixels, got {v}"),
            )?;
        }
        check_nonneg(c.noise_sigma, "sensors.camera.noise_sigma")?;
        check_nonneg(c.lighting, "sensors.camera.lighting")?;
        if c.image {
            check(
                c.fov < 3.0,
                "sensors.camera.fov",
                "must be below 3.0 rad for images",
            )?;
        }
        check_rate(s.ground_truth.rate, "sensors.ground_truth.rate")?;
        crate::script::validate(&self.events, &self.lighting_zones)
    }
}

impl BoxObstacle {
    /// Checks the box's geometry; errors name `field`'s members.
    pub(crate) fn validate(&self, field: &str) -> Result<()> {
        check_finite(&self.center, &format!("{field}.center"))?;
        check(
            self.size.iter().all(|s| s.is_finite() && *s > 0.0),
            &format!("{field}.size"),
            "both sizes must be finite and > 0",
        )?;
        check_finite(&[self.angle], &format!("{field}.angle"))
    }
}

pub(crate) fn check(ok: bool, field: &str, message: &str) -> Result<()> {
    if ok {
        Ok(())
    } else {
        Err(SimError::invalid(field, message))
    }
}
pub(crate) fn check_pos(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v > 0.0,
        field,
        &format!("must be finite and > 0, got {v}"),
    )
}
pub(crate) fn check_nonneg(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v >= 0.0,
        field,
        &format!("must be finite and >= 0, got {v}"),
    )
}
pub(crate) fn check_finite(v: &[f64], field: &str) -> Result<()> {
    check(v.iter().all(|x| x.is_finite()), field, "must be finite")
}
fn check_rate(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v > 0.0 && v <= 1e9,
        field,
        &format!("must be in (0, 1e9] Hz, got {v}"),
    )
}
fn check_fov(v: f64, field: &str) -> Result<()> {
    check(
        v.is_finite() && v > 0.0 && v <= TAU + 1e-9,
        field,
        &format!("must be in (0, 2π] radians, got {v}"),
    )
}
