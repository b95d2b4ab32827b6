//! Generated worlds for navigation benchmarks (`hng eval nav --generate N --seed S`): rooms
//! on both sides of a corridor, doors between them, and clutter of controlled density, as an
//! occupancy grid (written as a map_server map, which the simulator loads as a world).
//!
//! Each world is drawn from its own seed (`ChaCha8`), so world `i` of seed `S` is the same on
//! every machine. The layout: a rectangle of `width` x `height` m with outer walls; a corridor
//! `corridor_m` wide across it at a random height; above and below it, 2-4 rooms each,
//! separated by walls at random positions; every room has a door to the corridor, and
//! neighbouring rooms a door between them with probability `extra_door_p`; then boxes of
//! 0.3-0.8 m in the rooms (never in front of a door) until `clutter` of the rooms' floor is
//! covered. Whether two points are connected for the robot is the planner's business (clutter
//! can close a room): the evaluation picks problems whose goal it can reach.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use smart_default::SmartDefault;

use hng_runtime::map::{FREE, OCCUPIED, OccupancyGrid};

/// What the generated worlds look like.
#[derive(Debug, Clone, Copy, PartialEq, SmartDefault)]
pub struct GenConfig {
    /// Cell size of the grid, m.
    #[default(0.1)]
    pub resolution: f64,
    /// Range of the world's width, m.
    #[default((12.0, 20.0))]
    pub width_m: (f64, f64),
    /// Range of the world's height, m.
    #[default((10.0, 15.0))]
    pub height_m: (f64, f64),
    /// Range of the corridor's width, m.
    #[default((1.2, 2.2))]
    pub corridor_m: (f64, f64),
    /// Range of the doors' width, m.
    #[default((0.9, 1.4))]
    pub door_m: (f64, f64),
    /// Wall thickness, m.
    #[default(0.2)]
    pub wall_m: f64,
    /// Fraction of the rooms' floor covered by clutter boxes (0..0.3).
    #[default(0.04)]
    pub clutter: f64,
    /// Probability of a door between two neighbouring rooms.
    #[default(0.4)]
    pub extra_door_p: f64,
}

/// A generated world: its grid and what was drawn.
#[derive(Debug, Clone)]
pub struct GeneratedWorld {
    /// The occupancy grid (origin 0, 0; 0 free, 100 occupied).
    pub grid: OccupancyGrid,
    /// Rooms as rectangles `[x0, y0, x1, y1]` (free floor), m; the corridor first.
    pub rooms: Vec<[f64; 4]>,
    /// Doors drawn.
    pub doors: usize,
    /// Clutter boxes placed.
    pub boxes: usize,
}

/// The seed of world `index` of a run seeded `seed`.
pub fn world_seed(seed: u64, index: u64) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ index.wrapping_add(1).wrapping_mul(0xD1B5_4A32_D192_ED03)
}

struct Painter {
    grid: OccupancyGrid,
    res: f64,
}

impl Painter {
    fn cells(&self, x: f64) -> i64 {
        (x / self.res).round() as i64
    }

    /// Fills `[x0, x1) x [y0, y1)` (m) with `v`.
    fn fill(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, v: i8) {
        let (cx0, cy0, cx1, cy1) = (
            self.cells(x0),
            self.cells(y0),
            self.cells(x1),
            self.cells(y1),
        );
        for y in cy0.max(0)..cy1 {
            for x in cx0.max(0)..cx1 {
                self.grid.set(x, y, v);
            }
        }
    }

    fn free_rect(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> bool {
        let (cx0, cy0, cx1, cy1) = (
            self.cells(x0),
            self.cells(y0),
            self.cells(x1),
            self.cells(y1),
        );
        (cy0..cy1).all(|y| (cx0..cx1).all(|x| self.grid.get(x, y) == Some(FREE)))
    }
}

fn range(rng: &mut ChaCha8Rng, r: (f64, f64)) -> f64 {
    if r.1 > r.0 {
        rng.random_range(r.0..r.1)
    } else {
        r.0
    }
}

/// Generates one world from `seed`.
pub fn generate(cfg: &GenConfig, seed: u64) -> GeneratedWorld {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let res = cfg.resolution.max(0.01);
    let w = range(&mut rng, cfg.width_m).max(4.0);
    let h = range(&mut rng, cfg.height_m).max(6.0);
    let t = cfg.wall_m.max(res);
    let (gw, gh) = ((w / res).round() as u32, (h / res).round() as u32);
    let grid = match OccupancyGrid::new(gw, gh, res, [0.0, 0.0], FREE) {
        Ok(g) => g,
        // Dimensions are bounded above, so this cannot fail; an empty 1x1 world if it did.
        Err(_) => {
            OccupancyGrid::new(1, 1, res, [0.0, 0.0], FREE).unwrap_or_else(|_| unreachable!())
        }
    };
    let mut p = Painter { grid, res };
    // Outer walls.
    p.fill(0.0, 0.0, w, t, OCCUPIED);
    p.fill(0.0, h - t, w, h, OCCUPIED);
    p.fill(0.0, 0.0, t, h, OCCUPIED);
    p.fill(w - t, 0.0, w, h, OCCUPIED);
    // The corridor: its two walls across the world.
    let cw = range(&mut rng, cfg.corridor_m);
    let c0 = rng.random_range(h * 0.35..h * 0.65 - cw).max(2.5);
    let c1 = c0 + cw;
    p.fill(0.0, c0 - t, w, c0, OCCUPIED);
    p.fill(0.0, c1, w, c1 + t, OCCUPIED);
    let mut rooms = vec![[t, c0, w - t, c1]];
    let mut doors = 0;
    // Door openings to paint after the walls, and the clear zones in front of doors.
    let mut keep_clear: Vec<[f64; 4]> = Vec::new();
    for (lo, hi, below) in [(t, c0 - t, true), (c1 + t, h - t, false)] {
        let n = rng.random_range(2..=4usize);
        // Room boundaries along x: n rooms of at least 2.5 m.
        let mut xs = vec![t];
        let inner = w - 2.0 * t;
        let mut cuts: Vec<f64> = (1..n)
            .map(|i| {
                t + inner * i as f64 / n as f64 + rng.random_range(-0.15..0.15) * inner / n as f64
            })
            .collect();
        cuts.sort_by(f64::total_cmp);
        xs.extend(cuts);
        xs.push(w - t);
        for i in 0..n {
            let (x0, x1) = (xs[i], xs[i + 1]);
            if i + 1 < n {
                // Wall between room i and i+1 (its left side at x1).
                p.fill(x1, lo, x1 + t, hi, OCCUPIED);
            }
            let rx0 = if i == 0 { x0 } else { x0 + t };
            rooms.push([rx0, lo, x1, hi]);
            // A door to the corridor.
            let dw = range(&mut rng, cfg.door_m);
            let span = (x1 - rx0 - dw - 0.4).max(0.0);
            let dx = rx0 + 0.2 + rng.random_range(0.0..=span);
            let (wy0, wy1) = if below { (c0 - t, c0) } else { (c1, c1 + t) };
            p.fill(dx, wy0, dx + dw, wy1, FREE);
            keep_clear.push([dx - 0.2, wy0 - 1.0, dx + dw + 0.2, wy1 + 1.0]);
            doors += 1;
            // A door to the next room.
            if i + 1 < n && rng.random_bool(cfg.extra_door_p.clamp(0.0, 1.0)) {
                let dw = range(&mut rng, cfg.door_m);
                let span = (hi - lo - dw - 0.4).max(0.0);
                let dy = lo + 0.2 + rng.random_range(0.0..=span);
                p.fill(x1, dy, x1 + t, dy + dw, FREE);
                keep_clear.push([x1 - 1.0, dy - 0.2, x1 + t + 1.0, dy + dw + 0.2]);
                doors += 1;
            }
        }
    }
    // Clutter in the rooms (not the corridor), never in front of a door.
    let mut boxes = 0;
    let clutter = cfg.clutter.clamp(0.0, 0.3);
    for r in rooms.iter().skip(1) {
        let area = (r[2] - r[0]) * (r[3] - r[1]);
        let mut covered = 0.0;
        let mut tries = 0;
        while covered < clutter * area && tries < 200 {
            tries += 1;
            let (bw, bh) = (rng.random_range(0.3..0.8), rng.random_range(0.3..0.8));
            if r[2] - r[0] < bw + 0.2 || r[3] - r[1] < bh + 0.2 {
                break;
            }
            let x = rng.random_range(r[0]..r[2] - bw);
            let y = rng.random_range(r[1]..r[3] - bh);
            let hits_door = keep_clear
                .iter()
                .any(|k| x < k[2] && x + bw > k[0] && y < k[3] && y + bh > k[1]);
            if hits_door || !p.free_rect(x, y, x + bw, y + bh) {
                continue;
            }
            p.fill(x, y, x + bw, y + bh, OCCUPIED);
            covered += bw * bh;
            boxes += 1;
        }
    }
    GeneratedWorld {
        grid: p.grid,
        rooms,
        doors,
        boxes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_world_and_walls_enclose_it() {
        let cfg = GenConfig::default();
        let a = generate(&cfg, world_seed(7, 3));
        let b = generate(&cfg, world_seed(7, 3));
        assert_eq!(a.grid, b.grid);
        let c = generate(&cfg, world_seed(7, 4));
        assert_ne!(a.grid, c.grid);
        let g = &a.grid;
        let (w, h) = (i64::from(g.width()), i64::from(g.height()));
        for x in 0..w {
            assert_eq!(g.get(x, 0), Some(OCCUPIED));
            assert_eq!(g.get(x, h - 1), Some(OCCUPIED));
        }
        assert!(
            a.rooms.len() >= 5 && a.doors >= 4,
            "{} rooms",
            a.rooms.len()
        );
        // Clutter covers about what was asked of the rooms.
        let occupied = g.data().iter().filter(|&&v| v == OCCUPIED).count();
        assert!(occupied < g.data().len() / 3);
    }

    #[test]
    fn clutter_density_is_controlled() {
        let none = GenConfig {
            clutter: 0.0,
            ..GenConfig::default()
        };
        let lots = GenConfig {
            clutter: 0.15,
            ..GenConfig::default()
        };
        let a = generate(&none, 11);
        let b = generate(&lots, 11);
        assert_eq!(a.boxes, 0);
        assert!(b.boxes > 5, "{}", b.boxes);
        let occ = |g: &OccupancyGrid| g.data().iter().filter(|&&v| v == OCCUPIED).count();
        assert!(occ(&b.grid) > occ(&a.grid));
    }
}
