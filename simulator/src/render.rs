//! Camera images: a forward pinhole camera rendered by ray casting the 2D world, one ray per
//! image column (the way Wolfenstein-style renderers draw a 2.5D world).
//!
//! Walls and boxes stand `wall_height` tall on a flat floor; the camera is `camera_height` above
//! the floor at the robot centre, looking along the heading, with horizontal field of view
//! `fov`. Each column's ray finds the nearest obstacle edge; its depth (distance along the
//! optical axis, so straight walls stay straight) sets the rows the wall covers. Walls carry
//! their colour (`color` in the world file, else a shade picked from their position) with a
//! darker vertical stripe every half metre along them, so a moving camera sees texture. The
//! floor is a grey checkerboard of 1 m squares, the sky a gradient. Beacons are upright
//! cylinders `beacon_height` tall and `radius` wide, painted in two bands whose colours are
//! picked from the beacon's id ([`beacon_colors`]): the pattern a tracker looks for. They are
//! markers, not obstacles, and are hidden by any wall in front of them.
//!
//! Everything is scaled by a lighting factor (1 = normal; lower is darker) and, if asked, by
//! Gaussian pixel noise. The output is RGB8, row-major, top row first (ROS `sensor_msgs/Image`
//! encoding `rgb8`).

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use smart_default::SmartDefault;

pub use hng_runtime::msg::beacon_colors;

use crate::error::{Result, SimError};
use crate::world::{BoxObstacle, Pose2D, World};

/// Parameters of a rendered camera. Metres, radians.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, SmartDefault)]
#[serde(deny_unknown_fields, default)]
pub struct ImageParams {
    /// Image width in pixels (default 320).
    #[default(320)]
    pub width: u32,
    /// Image height in pixels (default 240).
    #[default(240)]
    pub height: u32,
    /// Horizontal field of view, rad (default 1.2, about 69 degrees).
    #[default(1.2)]
    pub fov: f64,
    /// Height of the optical centre above the floor, m (default 0.3).
    #[default(0.3)]
    pub camera_height: f64,
    /// Height of walls and boxes, m (default 1.0).
    #[default(1.0)]
    pub wall_height: f64,
    /// Height of the beacon markers, m (default 0.6).
    #[default(0.6)]
    pub beacon_height: f64,
    /// Standard deviation of the pixel noise, in 8-bit intensity steps (default 0: none).
    #[default(0.0)]
    pub noise_sigma: f64,
}

impl ImageParams {
    /// Bytes of one RGB8 image.
    #[must_use]
    pub fn image_bytes(&self) -> usize {
        self.width as usize * self.height as usize * 3
    }

    /// Focal length in pixels.
    #[must_use]
    pub fn focal_px(&self) -> f64 {
        f64::from(self.width) / 2.0 / (self.fov / 2.0).tan()
    }

    /// Checks the values; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, message: &str| Err(SimError::invalid(field, message));
        if !(8..=4096).contains(&self.width) {
            return bad("width", "must be in 8..=4096 pixels");
        }
        if !(8..=4096).contains(&self.height) {
            return bad("height", "must be in 8..=4096 pixels");
        }
        if !(self.fov.is_finite() && self.fov > 0.05 && self.fov < 3.0) {
            return bad("fov", "must be in (0.05, 3.0) rad");
        }
        for (field, v) in [
            ("camera_height", self.camera_height),
            ("wall_height", self.wall_height),
            ("beacon_height", self.beacon_height),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, "must be finite and > 0");
            }
        }
        if !(self.noise_sigma.is_finite() && self.noise_sigma >= 0.0) {
            return bad("noise_sigma", "must be finite and >= 0");
        }
        Ok(())
    }
}

/// One edge of an obstacle.
#[derive(Debug, Clone, Copy)]
struct Edge {
    a: [f64; 2],
    d: [f64; 2],
    color: [u8; 3],
}

#[derive(Debug, Clone, Copy)]
struct BeaconMark {
    id: u32,
    center: [f64; 2],
    radius: f64,
}

/// A camera over one world: its edges and beacons, ready to render from any pose.
#[derive(Debug, Clone)]
pub struct Renderer {
    params: ImageParams,
    edges: Vec<Edge>,
    /// Edges of the drawn world; those after are the world script's boxes.
    world_edges: usize,
    beacons: Vec<BeaconMark>,
    /// Per column: direction (x, y) in the camera frame (unit), and cos of its angle.
    columns: Vec<(f64, f64, f64)>,
}

/// The default colour of an obstacle without one: a warm or cool grey from its position.
fn shade_of(b: &BoxObstacle) -> [u8; 3] {
    let h = (b.center[0] * 7.3 + b.center[1] * 3.1).rem_euclid(1.0);
    let base = 150.0 + 60.0 * h;
    [
        base as u8,
        (base * 0.95) as u8,
        (base * (0.85 + 0.2 * h)) as u8,
    ]
}

impl Renderer {
    /// A renderer of `world` with `params`.
    pub fn new(world: &World, params: ImageParams) -> Result<Self> {
        params.validate()?;
        let mut edges = Vec::new();
        for b in world.obstacle_boxes() {
            push_box(&mut edges, &b);
        }
        let world_edges = edges.len();
        let beacons = world
            .beacons
            .iter()
            .map(|b| BeaconMark {
                id: b.id,
                center: b.position,
                radius: b.radius,
            })
            .collect();
        let f = params.focal_px();
        let cx = f64::from(params.width) / 2.0;
        let columns = (0..params.width)
            .map(|u| {
                let a = ((cx - f64::from(u) - 0.5) / f).atan();
                (a.cos(), a.sin(), a.cos())
            })
            .collect();
        Ok(Renderer {
            params,
            edges,
            world_edges,
            beacons,
            columns,
        })
    }

    /// Sets the boxes a world script added (drawn like the world's own, replacing the last
    /// set).
    pub fn set_script_boxes<'a>(&mut self, boxes: impl IntoIterator<Item = &'a BoxObstacle>) {
        self.edges.truncate(self.world_edges);
        for b in boxes {
            push_box(&mut self.edges, b);
        }
    }

    /// The parameters.
    #[must_use]
    pub fn params(&self) -> &ImageParams {
        &self.params
    }

    /// Renders the view from `pose` into `out` (RGB8, `params.image_bytes()` long; a shorter
    /// buffer is filled as far as it goes). `lighting` scales every colour; `rng` draws the
    /// pixel noise (none when `noise_sigma` is 0 or `rng` is `None`).
    pub fn render<R: Rng>(&self, pose: Pose2D, lighting: f64, rng: Option<&mut R>, out: &mut [u8]) {
        let p = &self.params;
        let (w, h) = (p.width as usize, p.height as usize);
        let f = p.focal_px();
        let cy = h as f64 / 2.0;
        let light = if lighting.is_finite() {
            lighting.clamp(0.0, 4.0)
        } else {
            1.0
        };
        let (st, ct) = pose.theta.sin_cos();
        // Sky: a gradient from pale blue at the top to white at the horizon.
        let sky = |v: usize| {
            let t = v as f64 / cy;
            [
                (150.0 + 90.0 * t) * light,
                (190.0 + 55.0 * t) * light,
                (235.0 + 15.0 * t) * light,
            ]
        };
        let mut depths = Vec::with_capacity(w);
        for (u, &(cu, su, cos_a)) in self.columns.iter().enumerate() {
            // Ray direction in the world.
            let dir = [ct * cu - st * su, st * cu + ct * su];
            let (best, hit) = self.cast(pose, dir);
            let depth = best * cos_a;
            depths.push(depth);
            let (top, bottom) = if depth.is_finite() {
                (
                    cy - f * (p.wall_height - p.camera_height) / depth,
                    cy + f * p.camera_height / depth,
                )
            } else {
                (cy, cy)
            };
            let wall_rgb = hit.map(|(i, s)| {
                let e = &self.edges[i];
                let along = s * e.d[0].hypot(e.d[1]);
                let stripe = if (along / 0.5).floor() as i64 % 2 == 0 {
                    1.0
                } else {
                    0.85
                };
                let fade = 1.0 / (1.0 + 0.06 * depth);
                let k = stripe * fade * light;
                e.color.map(|c| f64::from(c) * k)
            });
            for v in 0..h {
                let vc = v as f64 + 0.5;
                let rgb = if vc < top {
                    sky(v)
                } else if vc < bottom {
                    wall_rgb.unwrap_or_else(|| sky(v))
                } else {
                    // Floor: where this pixel's ray meets the ground.
                    let below = vc - cy;
                    let ground = f * p.camera_height / below / cos_a;
                    let gx = pose.x + dir[0] * ground;
                    let gy = pose.y + dir[1] * ground;
                    let even = (gx.floor() as i64 + gy.floor() as i64) % 2 == 0;
                    let g = if even { 120.0 } else { 95.0 } / (1.0 + 0.03 * ground);
                    [g * light, g * light, g * 0.95 * light]
                };
                put(out, (v * w + u) * 3, rgb);
            }
        }
        self.draw_beacons(pose, light, &depths, out);
        if let Some(rng) = rng
            && p.noise_sigma > 0.0
            && let Ok(n) = Normal::new(0.0, p.noise_sigma)
        {
            let len = out.len().min(p.image_bytes());
            for b in &mut out[..len] {
                let v = f64::from(*b) + n.sample(rng);
                *b = v.clamp(0.0, 255.0) as u8;
            }
        }
    }

    /// [`Renderer::render`] with the pixel noise drawn from a generator seeded with `seed`
    /// (for callers without a random number generator of their own: tools, benches).
    pub fn render_seeded(&self, pose: Pose2D, lighting: f64, seed: u64, out: &mut [u8]) {
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed);
        self.render(pose, lighting, Some(&mut rng), out);
    }

    /// The image rectangle (columns `u0..u1`, rows `v0..v1`) where beacon `id` is drawn from
    /// `pose`, if any part of it is in view and not hidden by a wall. Ground truth for tests of
    /// trackers.
    #[must_use]
    pub fn beacon_box(&self, pose: Pose2D, id: u32) -> Option<(usize, usize, usize, usize)> {
        let b = self.beacons.iter().find(|b| b.id == id)?;
        let (u0, u1, v0, v1, z) = self.beacon_extent(pose, b)?;
        let visible = (u0..u1).any(|u| self.column_depth(pose, u) > z);
        visible.then_some((u0, u1, v0, v1))
    }

    /// Columns, rows and depth of a beacon's marker, clipped to the image.
    fn beacon_extent(
        &self,
        pose: Pose2D,
        b: &BeaconMark,
    ) -> Option<(usize, usize, usize, usize, f64)> {
        let p = &self.params;
        let (st, ct) = pose.theta.sin_cos();
        let (dx, dy) = (b.center[0] - pose.x, b.center[1] - pose.y);
        let (x, y) = (ct * dx + st * dy, -st * dx + ct * dy);
        if x < 0.05 + b.radius {
            return None;
        }
        let f = p.focal_px();
        let (w, h) = (f64::from(p.width), f64::from(p.height));
        let (cx, cy) = (w / 2.0, h / 2.0);
        let uc = cx - f * y / x;
        let half = f * b.radius / x;
        let u0 = (uc - half).floor().clamp(0.0, w) as usize;
        let u1 = (uc + half).ceil().clamp(0.0, w) as usize;
        let v0 = (cy - f * (p.beacon_height - p.camera_height) / x)
            .floor()
            .clamp(0.0, h) as usize;
        let v1 = (cy + f * p.camera_height / x).ceil().clamp(0.0, h) as usize;
        (u0 < u1 && v0 < v1).then_some((u0, u1, v0, v1, x))
    }

    /// Depth of the wall seen in column `u` (infinite when none).
    fn column_depth(&self, pose: Pose2D, u: usize) -> f64 {
        let Some(&(cu, su, cos_a)) = self.columns.get(u) else {
            return f64::INFINITY;
        };
        let (st, ct) = pose.theta.sin_cos();
        self.cast(pose, [ct * cu - st * su, st * cu + ct * su]).0 * cos_a
    }

    /// The nearest edge hit by the ray from `pose` along the unit vector `dir`: its distance
    /// (infinite when none), and the edge's index with the hit's position along it (0..1).
    fn cast(&self, pose: Pose2D, dir: [f64; 2]) -> (f64, Option<(usize, f64)>) {
        let mut best = f64::INFINITY;
        let mut hit = None;
        for (i, e) in self.edges.iter().enumerate() {
            let den = dir[0] * e.d[1] - dir[1] * e.d[0];
            if den.abs() < 1e-12 {
                continue;
            }
            let (px, py) = (e.a[0] - pose.x, e.a[1] - pose.y);
            let t = (px * e.d[1] - py * e.d[0]) / den;
            let s = (px * dir[1] - py * dir[0]) / den;
            if t > 1e-6 && t < best && (0.0..=1.0).contains(&s) {
                best = t;
                hit = Some((i, s));
            }
        }
        (best, hit)
    }

    /// Draws the beacons over the image; `depths` is each column's wall depth.
    fn draw_beacons(&self, pose: Pose2D, light: f64, depths: &[f64], out: &mut [u8]) {
        let w = self.params.width as usize;
        // Far beacons first, so near ones cover them.
        let mut order: Vec<_> = self
            .beacons
            .iter()
            .filter_map(|b| self.beacon_extent(pose, b).map(|e| (b, e)))
            .collect();
        order.sort_by(|a, b| b.1.4.total_cmp(&a.1.4));
        for (b, (u0, u1, v0, v1, z)) in order {
            let (top, bottom) = beacon_colors(b.id);
            let mid = (v0 + v1) / 2;
            let fade = light / (1.0 + 0.06 * z);
            for u in u0..u1 {
                if depths.get(u).copied().unwrap_or(f64::INFINITY) <= z {
                    continue;
                }
                for v in v0..v1 {
                    let c = if v < mid { top } else { bottom };
                    put(out, (v * w + u) * 3, c.map(|x| f64::from(x) * fade));
                }
            }
        }
    }
}

/// The four edges of a box, in its colour.
fn push_box(edges: &mut Vec<Edge>, b: &BoxObstacle) {
    let color = b.color.unwrap_or_else(|| shade_of(b));
    let c = b.corners();
    for i in 0..4 {
        let (p, q) = (c[i], c[(i + 1) % 4]);
        edges.push(Edge {
            a: p,
            d: [q[0] - p[0], q[1] - p[1]],
            color,
        });
    }
}

#[inline]
fn put(out: &mut [u8], i: usize, rgb: [f64; 3]) {
    if let Some(px) = out.get_mut(i..i + 3) {
        for (o, c) in px.iter_mut().zip(rgb) {
            *o = c.clamp(0.0, 255.0) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Beacon, Wall};
    use rand::SeedableRng;

    fn room() -> World {
        let mut w = World::empty(Pose2D::new(0.0, 0.0, 0.0));
        w.walls = vec![
            Wall {
                color: Some([200, 30, 30]),
                ..Wall::new([4.0, -3.0], [4.0, 3.0])
            },
            Wall::new([-4.0, -3.0], [4.0, -3.0]),
            Wall::new([-4.0, 3.0], [4.0, 3.0]),
            Wall::new([-4.0, -3.0], [-4.0, 3.0]),
        ];
        w.beacons = vec![Beacon {
            id: 2,
            position: [2.0, 0.5],
            radius: 0.1,
        }];
        w
    }

    fn render(w: &World, pose: Pose2D, params: ImageParams) -> (Renderer, Vec<u8>) {
        let r = Renderer::new(w, params).expect("renderer");
        let mut img = vec![0; params.image_bytes()];
        r.render::<rand_chacha::ChaCha8Rng>(pose, 1.0, None, &mut img);
        (r, img)
    }

    fn px(img: &[u8], w: usize, u: usize, v: usize) -> [u8; 3] {
        let i = (v * w + u) * 3;
        [img[i], img[i + 1], img[i + 2]]
    }

    #[test]
    fn a_wall_ahead_spans_the_rows_its_distance_gives() {
        let p = ImageParams::default();
        // Looking at the red wall 4 m ahead, away from the beacon.
        let (_, img) = render(&room(), Pose2D::new(0.0, -1.5, 0.0), p);
        let f = p.focal_px();
        let top = 120.0 - f * 0.7 / 4.0;
        let bottom = 120.0 + f * 0.3 / 4.0;
        let centre = px(&img, 320, 160, 120);
        assert!(
            centre[0] > 100 && centre[0] > 4 * centre[1],
            "red wall at the centre: {centre:?}"
        );
        let above = px(&img, 320, 160, (top - 2.0) as usize);
        assert!(above[2] > 200, "sky above the wall: {above:?}");
        let inside_top = px(&img, 320, 160, (top + 2.0) as usize);
        assert!(
            inside_top[0] > 100 && inside_top[0] > 4 * inside_top[1],
            "{inside_top:?}"
        );
        let floor = px(&img, 320, 160, (bottom + 2.0) as usize);
        assert!(
            floor[0] < 130 && floor[0] == floor[1],
            "grey floor: {floor:?}"
        );
    }

    #[test]
    fn a_beacon_appears_where_its_bearing_puts_it_with_its_colours() {
        let p = ImageParams::default();
        let pose = Pose2D::new(0.0, 0.0, 0.0);
        let (r, img) = render(&room(), pose, p);
        let (u0, u1, v0, v1) = r.beacon_box(pose, 2).expect("beacon 2 in view");
        // Bearing atan2(0.5, 2) left of the centre column.
        let uc = 160.0 - p.focal_px() * 0.5 / 2.0;
        assert!(
            ((u0 + u1) as f64 / 2.0 - uc).abs() < 1.5,
            "{u0}..{u1} vs {uc}"
        );
        let (top, bottom) = beacon_colors(2);
        let fade = 1.0 / (1.0 + 0.06 * 2.0);
        let mid_u = (u0 + u1) / 2;
        let t = px(&img, 320, mid_u, v0 + 1);
        let b = px(&img, 320, mid_u, v1 - 2);
        for (got, want) in [(t, top), (b, bottom)] {
            for k in 0..3 {
                let want = f64::from(want[k]) * fade;
                assert!((f64::from(got[k]) - want).abs() <= 1.0, "{got:?} vs {want}");
            }
        }
    }

    #[test]
    fn a_wall_between_hides_the_beacon() {
        let mut w = room();
        w.walls.push(Wall::new([1.0, 0.0], [1.0, 1.5]));
        let (r, _) = render(&w, Pose2D::new(0.0, 0.0, 0.0), ImageParams::default());
        assert_eq!(r.beacon_box(Pose2D::new(0.0, 0.0, 0.0), 2), None);
        // Turned away, it is out of view.
        let (r, _) = render(&room(), Pose2D::new(0.0, 0.0, 3.0), ImageParams::default());
        assert_eq!(r.beacon_box(Pose2D::new(0.0, 0.0, 3.0), 2), None);
    }

    #[test]
    fn darkness_and_noise_change_the_image_as_asked() {
        let p = ImageParams {
            noise_sigma: 4.0,
            ..ImageParams::default()
        };
        let r = Renderer::new(&room(), p).expect("renderer");
        let pose = Pose2D::new(0.0, 0.0, 0.0);
        let mut bright = vec![0; p.image_bytes()];
        let mut dark = vec![0; p.image_bytes()];
        r.render::<rand_chacha::ChaCha8Rng>(pose, 1.0, None, &mut bright);
        r.render::<rand_chacha::ChaCha8Rng>(pose, 0.3, None, &mut dark);
        let mean = |img: &[u8]| img.iter().map(|&b| f64::from(b)).sum::<f64>() / img.len() as f64;
        let ratio = mean(&dark) / mean(&bright);
        assert!((ratio - 0.3).abs() < 0.02, "{ratio}");
        let mut noisy = vec![0; p.image_bytes()];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        r.render(pose, 1.0, Some(&mut rng), &mut noisy);
        let diff: Vec<f64> = noisy
            .iter()
            .zip(&bright)
            .map(|(&a, &b)| f64::from(a) - f64::from(b))
            .collect();
        let sd = (diff.iter().map(|d| d * d).sum::<f64>() / diff.len() as f64).sqrt();
        assert!((sd - 4.0).abs() < 0.3, "noise sd {sd}");
    }

    #[test]
    fn bad_parameters_are_refused_with_the_field() {
        for (p, field) in [
            (
                ImageParams {
                    width: 0,
                    ..ImageParams::default()
                },
                "width",
            ),
            (
                ImageParams {
                    fov: f64::NAN,
                    ..ImageParams::default()
                },
                "fov",
            ),
            (
                ImageParams {
                    noise_sigma: -1.0,
                    ..ImageParams::default()
                },
                "noise_sigma",
            ),
        ] {
            let e = Renderer::new(&room(), p).err().map(|e| e.to_string());
            assert!(e.as_deref().is_some_and(|e| e.contains(field)), "{e:?}");
        }
    }
}
