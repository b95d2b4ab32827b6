//! Planner benchmarks on 512x512 grids (hng-modules::planning).

use std::hint::black_box;

use criterion::measurement::WallTime;
use criterion::{BenchmarkGroup, Criterion, criterion_group, criterion_main};
use hng_modules::planning::{
    FREE, GridPath, GridPlanner, InflationConfig, OCCUPIED, OccupancyGrid, PlannerConfig, inflate,
    simplify,
};

/// Deterministic splitmix64, so the obstacle field is the same on every run.
fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// 512x512, 0.05 m cells, `density` of the cells occupied at random (fixed
/// seed), corners kept free.
fn random_field(density: f64, seed: u64) -> OccupancyGrid {
    let n = 512u32;
    let mut g = OccupancyGrid::new(n, n, 0.05, [0.0, 0.0], FREE).expect("grid");
    let mut s = seed;
    for y in 0..n as i64 {
        for x in 0..n as i64 {
            if (splitmix(&mut s) as f64 / u64::MAX as f64) < density {
                g.set(x, y, OCCUPIED);
            }
        }
    }
    for (x, y) in [
        (0, 0),
        (1, 0),
        (0, 1),
        (1, 1),
        (511, 511),
        (510, 511),
        (511, 510),
        (510, 510),
    ] {
        g.set(x, y, FREE);
    }
    g
}

/// 512x512 with long walls (gaps alternating ends): a serpentine corridor.
fn serpentine() -> OccupancyGrid {
    let n = 512i64;
    let mut g = OccupancyGrid::new(n as u32, n as u32, 0.05, [0.0, 0.0], FREE).expect("grid");
    let mut k = 0;
    let mut y = 16;
    while y < n - 8 {
        for x in 0..n {
            let gap = if k % 2 == 0 { x >= n - 12 } else { x < 12 };
            if !gap {
                g.set(x, y, OCCUPIED);
                g.set(x, y + 1, OCCUPIED);
            }
        }
        k += 1;
        y += 16;
    }
    g
}

/// Plans from corner to corner of `grid` once (printing the path's length and the cells
/// expanded), then benchmarks that plan as `astar_NAME_corner_to_corner`.
fn corner_to_corner(
    grp: &mut BenchmarkGroup<'_, WallTime>,
    planner: &mut GridPlanner,
    name: &str,
    grid: &OccupancyGrid,
) -> GridPath {
    let p = planner
        .plan_cells(grid, (0, 0), (511, 511))
        .unwrap_or_else(|e| panic!("{name}: no path corner to corner: {e}"));
    println!(
        "{name}: length {:.2} cells, {} expanded",
        p.length_cells, p.expanded
    );
    grp.bench_function(format!("astar_{name}_corner_to_corner"), |b| {
        b.iter(|| {
            planner
                .plan_cells(black_box(grid), (0, 0), (511, 511))
                .expect("path")
        })
    });
    p
}

fn benches(c: &mut Criterion) {
    let cfg = PlannerConfig::default();
    let mut planner = GridPlanner::new(cfg);
    let mut grp = c.benchmark_group("planning_512");

    let open = OccupancyGrid::new(512, 512, 0.05, [0.0, 0.0], FREE).expect("grid");
    corner_to_corner(&mut grp, &mut planner, "open", &open);
    corner_to_corner(&mut grp, &mut planner, "random25", &random_field(0.25, 7));
    let maze = serpentine();
    let p = corner_to_corner(&mut grp, &mut planner, "serpentine", &maze);
    grp.bench_function("simplify_serpentine_path", |b| {
        b.iter(|| simplify(black_box(&maze), &cfg, black_box(&p)))
    });

    let sparse = random_field(0.02, 11);
    let icfg = InflationConfig {
        radius_m: 0.3,
        ..Default::default()
    };
    grp.bench_function("inflate_r0.3m_sparse2pct", |b| {
        b.iter(|| inflate(black_box(&sparse), &icfg))
    });
    grp.finish();
}

criterion_group!(planning, benches);
criterion_main!(planning);
