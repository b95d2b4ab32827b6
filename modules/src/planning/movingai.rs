//! MovingAI benchmark files (<https://movingai.com/benchmarks/formats.html>):
//! `.map` grids and `.scen` problem lists, plus [`eval_movingai`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::astar::{GridPlanner, PlanError, PlannerConfig};
use hng_runtime::map::{FREE, OCCUPIED, OccupancyGrid};

/// A parse or I/O error, naming the file, line (1-based) and field.
#[derive(Debug, thiserror::Error)]
pub enum MovingAiError {
    /// The file could not be read.
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The content does not follow the format.
    #[error("{}:{line}: field `{field}`: {msg}", path.display())]
    Parse {
        /// File.
        path: PathBuf,
        /// 1-based line number (0 if the file ended early).
        line: usize,
        /// Field being parsed.
        field: &'static str,
        /// What is wrong.
        msg: String,
    },
    /// A scenario problem could not be planned.
    #[error("{}:{line}: planning failed: {source}", path.display())]
    Plan {
        /// Scenario file.
        path: PathBuf,
        /// Line of the problem.
        line: usize,
        /// Planner error.
        source: PlanError,
    },
}

/// A MovingAI grid map. `(x, y)` = (column, row), row 0 is the first map row
/// in the file (the top).
#[derive(Debug, Clone, PartialEq)]
pub struct MovingAiMap {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Row-major passability, `passable[y * width + x]`, row 0 = top.
    pub passable: Vec<bool>,
}

impl MovingAiMap {
    /// Whether `(x, y)` (column, row from top) is passable; false outside.
    pub fn is_passable(&self, x: i64, y: i64) -> bool {
        x >= 0
            && y >= 0
            && x < self.width as i64
            && y < self.height as i64
            && self.passable[y as usize * self.width as usize + x as usize]
    }

    /// Converts to an [`OccupancyGrid`] with 1 m cells at the origin. Rows are
    /// flipped (grid row 0 is the bottom, the last file row), so MovingAI cell
    /// `(x, y)` is grid cell `(x, height - 1 - y)`; see [`Self::to_grid_cell`].
    pub fn to_occupancy_grid(&self, resolution: f64) -> Result<OccupancyGrid, super::GridError> {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut data = vec![FREE; w * h];
        for y in 0..h {
            for x in 0..w {
                if !self.passable[y * w + x] {
                    data[(h - 1 - y) * w + x] = OCCUPIED;
                }
            }
        }
        OccupancyGrid::from_data(self.width, self.height, resolution, [0.0, 0.0], data)
    }

    /// Grid cell of MovingAI cell `(x, y)` in [`Self::to_occupancy_grid`].
    pub fn to_grid_cell(&self, x: i64, y: i64) -> (i64, i64) {
        (x, self.height as i64 - 1 - y)
    }
}

fn read(path: &Path) -> Result<String, MovingAiError> {
    std::fs::read_to_string(path).map_err(|source| MovingAiError::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn perr(path: &Path, line: usize, field: &'static str, msg: impl Into<String>) -> MovingAiError {
    MovingAiError::Parse {
        path: path.to_path_buf(),
        line,
        field,
        msg: msg.into(),
    }
}

/// Reads a `.map` file.
pub fn read_map(path: &Path) -> Result<MovingAiMap, MovingAiError> {
    parse_map(&read(path)?, path)
}

/// Parses `.map` text; `path` is only used in errors. Passable: `.` `G` `S`;
/// impassable: `@` `O` `T` `W` (water is impassable for a ground robot).
pub fn parse_map(text: &str, path: &Path) -> Result<MovingAiMap, MovingAiError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')));
    let mut header = |field: &'static str| -> Result<(usize, String), MovingAiError> {
        let (n, l) = lines
            .next()
            .ok_or_else(|| perr(path, 0, field, "file ended before the header was complete"))?;
        let mut it = l.split_whitespace();
        if it.next() != Some(field) {
            return Err(perr(
                path,
                n,
                field,
                format!("expected `{field} ...`, found {l:?}"),
            ));
        }
        Ok((n, it.collect::<Vec<_>>().join(" ")))
    };
    let (n, ty) = header("type")?;
    if ty != "octile" {
        return Err(perr(
            path,
            n,
            "type",
            format!("expected `octile`, found {ty:?}"),
        ));
    }
    let parse_dim = |(n, v): (usize, String), field: &'static str| -> Result<u32, MovingAiError> {
        v.parse::<u32>().ok().filter(|&d| d > 0).ok_or_else(|| {
            perr(
                path,
                n,
                field,
                format!("expected a positive integer, found {v:?}"),
            )
        })
    };
    let height = parse_dim(header("height")?, "height")?;
    let width = parse_dim(header("width")?, "width")?;
    let (n, rest) = header("map")?;
    if !rest.is_empty() {
        return Err(perr(
            path,
            n,
            "map",
            format!("unexpected text after `map`: {rest:?}"),
        ));
    }
    let total = (width as usize)
        .checked_mul(height as usize)
        .ok_or_else(|| perr(path, n, "width", "width*height overflows"))?;
    let mut passable = Vec::with_capacity(total);
    for row in 0..height as usize {
        let (n, l) = lines.next().ok_or_else(|| {
            perr(
                path,
                0,
                "map",
                format!("file ended after {row} of {height} rows"),
            )
        })?;
        let len = l.chars().count();
        if len != width as usize {
            return Err(perr(
                path,
                n,
                "map",
                format!("row has {len} cells, expected width {width}"),
            ));
        }
        for (col, c) in l.chars().enumerate() {
            passable.push(match c {
                '.' | 'G' | 'S' => true,
                '@' | 'O' | 'T' | 'W' => false,
                other => {
                    return Err(perr(
                        path,
                        n,
                        "map",
                        format!("column {col}: unknown terrain {other:?}"),
                    ));
                }
            });
        }
    }
    Ok(MovingAiMap {
        width,
        height,
        passable,
    })
}

/// One `.scen` problem. Coordinates: `x` = column, `y` = row from the top.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenProblem {
    /// 1-based line in the scenario file.
    pub line: usize,
    /// Difficulty bucket.
    pub bucket: u32,
    /// Map file name as written.
    pub map: String,
    /// Map width declared by the problem.
    pub width: u32,
    /// Map height declared by the problem.
    pub height: u32,
    /// Start (column, row).
    pub start: (i64, i64),
    /// Goal (column, row).
    pub goal: (i64, i64),
    /// Optimal path length (orthogonal 1, diagonal √2, no corner cutting).
    pub optimal_length: f64,
}

/// Reads a `.scen` file.
pub fn read_scen(path: &Path) -> Result<Vec<ScenProblem>, MovingAiError> {
    parse_scen(&read(path)?, path)
}

/// Parses `.scen` text (`version 1`, then tab-separated problem lines).
pub fn parse_scen(text: &str, path: &Path) -> Result<Vec<ScenProblem>, MovingAiError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')));
    let (n, first) = lines
        .next()
        .ok_or_else(|| perr(path, 0, "version", "empty file"))?;
    let v: Vec<&str> = first.split_whitespace().collect();
    if v.len() != 2 || v[0] != "version" || v[1].parse::<f64>().is_err() {
        return Err(perr(
            path,
            n,
            "version",
            format!("expected `version 1`, found {first:?}"),
        ));
    }
    const FIELDS: [&str; 9] = [
        "bucket",
        "map",
        "width",
        "height",
        "start_x",
        "start_y",
        "goal_x",
        "goal_y",
        "optimal_length",
    ];
    let mut out = Vec::new();
    for (n, l) in lines {
        if l.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = if l.contains('\t') {
            l.split('\t').collect()
        } else {
            l.split_whitespace().collect()
        };
        if f.len() != FIELDS.len() {
            let field = FIELDS.get(f.len()).copied().unwrap_or("optimal_length");
            return Err(perr(
                path,
                n,
                field,
                format!("expected {} fields, found {}", FIELDS.len(), f.len()),
            ));
        }
        let int = |i: usize| -> Result<u32, MovingAiError> {
            f[i].trim().parse::<u32>().map_err(|e| {
                perr(
                    path,
                    n,
                    FIELDS[i],
                    format!("{:?} is not a non-negative integer: {e}", f[i]),
                )
            })
        };
        let optimal_length = f[8]
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| {
                perr(
                    path,
                    n,
                    FIELDS[8],
                    format!("{:?} is not a finite length >= 0", f[8]),
                )
            })?;
        out.push(ScenProblem {
            line: n,
            bucket: int(0)?,
            map: f[1].to_string(),
            width: int(2)?,
            height: int(3)?,
            start: (int(4)? as i64, int(5)? as i64),
            goal: (int(6)? as i64, int(7)? as i64),
            optimal_length,
        });
    }
    Ok(out)
}

/// Result of running the planner on a MovingAI scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannerEval {
    /// Problems run.
    pub problems: usize,
    /// Problems whose length differs from the optimum by more than
    /// [`length_tolerance`].
    pub mismatches: usize,
    /// Largest `|length - optimal|` over all problems.
    pub max_abs_err: f64,
    /// Mean wall time per problem in microseconds (planning only, not parsing).
    pub mean_us: f64,
    /// Mean cells expanded per problem.
    pub mean_expanded: f64,
}

/// Allowed `|length - optimal|`: `1e-4 * max(1, optimal)`, i.e. 1e-4 absolute
/// for lengths up to 1 and 1e-4 relative above. Scenario files print optimal
/// lengths with about 6 significant digits, so exact paths are within 5e-6
/// relative; a wrong path differs by at least `2 - √2 ≈ 0.59` cells.
pub fn length_tolerance(optimal: f64) -> f64 {
    1e-4 * optimal.max(1.0)
}

/// Plans every problem of `scen_path` on `map_path` and compares with the
/// optimal lengths. Problems whose size disagrees with the map are an error;
/// unreachable problems are an error naming the line.
pub fn eval_movingai(map_path: &Path, scen_path: &Path) -> Result<PlannerEval, MovingAiError> {
    let map = read_map(map_path)?;
    let problems = read_scen(scen_path)?;
    let grid = map
        .to_occupancy_grid(1.0)
        .map_err(|e| perr(map_path, 0, "map", e.to_string()))?;
    let mut planner = GridPlanner::new(PlannerConfig::default());
    let mut mismatches = 0;
    let mut max_abs_err: f64 = 0.0;
    let mut total_us = 0.0;
    let mut expanded = 0usize;
    for p in &problems {
        if p.width != map.width || p.height != map.height {
            return Err(perr(
                scen_path,
                p.line,
                "width",
                format!(
                    "problem is for a {}x{} map, map file is {}x{}",
                    p.width, p.height, map.width, map.height
                ),
            ));
        }
        let s = map.to_grid_cell(p.start.0, p.start.1);
        let g = map.to_grid_cell(p.goal.0, p.goal.1);
        let t0 = Instant::now();
        let res = planner.plan_cells(&grid, s, g);
        total_us += t0.elapsed().as_secs_f64() * 1e6;
        let path = res.map_err(|source| MovingAiError::Plan {
            path: scen_path.to_path_buf(),
            line: p.line,
            source,
        })?;
        expanded += path.expanded;
        let err = (path.length_cells - p.optimal_length).abs();
        max_abs_err = max_abs_err.max(err);
        if err > length_tolerance(p.optimal_length) {
            mismatches += 1;
        }
    }
    let n = problems.len().max(1) as f64;
    Ok(PlannerEval {
        problems: problems.len(),
        mismatches,
        max_abs_err,
        mean_us: total_us / n,
        mean_expanded: expanded as f64 / n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_small_map() {
        let m = parse_map(
            "type octile\nheight 2\nwidth 3\nmap\n.@G\nSTW\n",
            Path::new("t.map"),
        )
        .expect("map");
        assert_eq!((m.width, m.height), (3, 2));
        assert_eq!(m.passable, vec![true, false, true, true, false, false]);
        let g = m.to_occupancy_grid(1.0).expect("grid");
        // File row 0 becomes grid row 1 (the top).
        assert_eq!(g.get(1, 1), Some(OCCUPIED));
        assert_eq!(g.get(0, 0), Some(FREE));
        assert_eq!(g.get(1, 0), Some(OCCUPIED));
    }

    #[test]
    fn map_errors_name_line_and_field() {
        let e = parse_map("type octile\nheight 2\nwidth x\nmap\n", Path::new("a.map"))
            .expect_err("bad width");
        assert_eq!(
            e.to_string(),
            "a.map:3: field `width`: expected a positive integer, found \"x\""
        );
        let e = parse_map(
            "type octile\nheight 1\nwidth 2\nmap\n.?\n",
            Path::new("a.map"),
        )
        .expect_err("bad cell");
        assert!(
            e.to_string().starts_with("a.map:5: field `map`: column 1"),
            "{e}"
        );
        let e = parse_map(
            "type octile\nheight 2\nwidth 2\nmap\n..\n",
            Path::new("a.map"),
        )
        .expect_err("short");
        assert!(e.to_string().contains("ended after 1 of 2 rows"), "{e}");
    }

    #[test]
    fn scen_parse_and_errors() {
        let p = parse_scen(
            "version 1\n0\tm.map\t49\t49\t1\t11\t1\t12\t1\n",
            Path::new("s.scen"),
        )
        .expect("scen");
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].start, (1, 11));
        assert_eq!(p[0].goal, (1, 12));
        assert_eq!(p[0].line, 2);
        let e = parse_scen(
            "version 1\n0\tm.map\t49\t49\t1\tq\t1\t12\t1\n",
            Path::new("s.scen"),
        )
        .expect_err("bad start_y");
        assert!(
            e.to_string().starts_with("s.scen:2: field `start_y`"),
            "{e}"
        );
        let e = parse_scen("version 1\n0\tm.map\t49\n", Path::new("s.scen")).expect_err("short");
        assert!(e.to_string().starts_with("s.scen:2: field `height`"), "{e}");
        let e = parse_scen("v 1\n", Path::new("s.scen")).expect_err("header");
        assert!(
            e.to_string().starts_with("s.scen:1: field `version`"),
            "{e}"
        );
    }

    #[test]
    fn missing_file_is_io_error() {
        let e = read_map(Path::new("/nonexistent/x.map")).expect_err("missing");
        assert!(
            e.to_string().starts_with("/nonexistent/x.map: cannot read"),
            "{e}"
        );
    }
}
