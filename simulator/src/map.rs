//! ROS map_server occupancy maps: a PGM image plus a YAML file.
//!
//! YAML fields: `image` (path relative to the YAML), `resolution` (metres per pixel), `origin`
//! [x, y, yaw] of the lower-left pixel, `negate` (0/1), `occupied_thresh`, `free_thresh`, and an
//! optional `mode` (`trinary`, `scale` or `raw`). Image row 0 is the top of the map, so rows are
//! flipped when read. The PGM reader is a small hand-written parser (P5 binary and P2 text, 8- or
//! 16-bit): the format is a dozen lines to read, and this keeps the `image` crate and its
//! dependency tree out of the build; PNG maps are not supported (convert them with
//! `convert map.png map.pgm`).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{Result, SimError};
use crate::world::{BoxObstacle, World};

/// Occupancy value of an occupied cell.
pub const OCCUPIED: i8 = 100;
/// Occupancy value of a free cell.
pub const FREE: i8 = 0;
/// Occupancy value of an unknown cell.
pub const UNKNOWN: i8 = -1;

/// An occupancy grid laid out like ROS `nav_msgs/OccupancyGrid`: row-major, cell (0, 0) is the
/// lower-left cell at `origin`, x grows with the column, y with the row; values 0 (free), 100
/// (occupied) or -1 (unknown).
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    /// Cells per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Metres per cell.
    pub resolution: f64,
    /// Pose [x, y, yaw] of the lower-left corner of cell (0, 0) in the map frame.
    pub origin: [f64; 3],
    /// `width * height` occupancy values, bottom row first.
    pub data: Vec<i8>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MapYaml {
    image: PathBuf,
    resolution: f64,
    origin: [f64; 3],
    #[serde(default)]
    negate: IntOrBool,
    occupied_thresh: f64,
    free_thresh: f64,
    #[serde(default)]
    mode: Option<String>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(untagged)]
enum IntOrBool {
    Int(i64),
    Bool(bool),
    #[default]
    Unset,
}

impl OccupancyGrid {
    /// Cell value at column `col`, row `row` (row 0 at the bottom).
    #[must_use]
    pub fn get(&self, col: usize, row: usize) -> Option<i8> {
        if col < self.width && row < self.height {
            self.data.get(row * self.width + col).copied()
        } else {
            None
        }
    }

    /// Loads a map_server YAML and the image it names.
    pub fn load(yaml_path: impl AsRef<Path>) -> Result<Self> {
        let yaml_path = yaml_path.as_ref();
        let text = std::fs::read_to_string(yaml_path)
            .map_err(|e| SimError::io(yaml_path, "cannot read", e))?;
        let parse_err =
            |line: usize, column: usize, field: &str, message: String| SimError::Parse {
                path: yaml_path.to_path_buf(),
                line,
                column,
                field: field.to_owned(),
                message,
            };
        let meta: MapYaml = serde_yaml_ng::from_str(&text).map_err(|e| {
            let (line, column) = e.location().map_or((1, 1), |l| (l.line(), l.column()));
            let message = e.to_string();
            let field = yaml_field_in(&message)
                .or_else(|| yaml_key_on_line(&text, line))
                .unwrap_or_else(|| "(document)".to_owned());
            parse_err(line, column, &field, message)
        })?;
        let at = |field: &str| yaml_key_line(&text, field);
        let invalid = |field: &str, message: String| {
            let (line, column) = at(field);
            parse_err(line, column, field, message)
        };
        if !(meta.resolution.is_finite() && meta.resolution > 0.0) {
            return Err(invalid(
                "resolution",
                format!("must be finite and > 0, got {}", meta.resolution),
            ));
        }
        if !meta.origin.iter().all(|v| v.is_finite()) {
            return Err(invalid(
                "origin",
                "must be three finite numbers [x, y, yaw]".to_owned(),
            ));
        }
        for (name, v) in [
            ("occupied_thresh", meta.occupied_thresh),
            ("free_thresh", meta.free_thresh),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(invalid(name, format!("must be in [0, 1], got {v}")));
            }
        }
        if meta.free_thresh > meta.occupied_thresh {
            return Err(invalid(
                "free_thresh",
                "must not exceed occupied_thresh".to_owned(),
            ));
        }
        let negate = match meta.negate {
            IntOrBool::Int(0) | IntOrBool::Bool(false) | IntOrBool::Unset => false,
            IntOrBool::Int(1) | IntOrBool::Bool(true) => true,
            IntOrBool::Int(n) => return Err(invalid("negate", format!("must be 0 or 1, got {n}"))),
        };
        let raw = match meta.mode.as_deref() {
            None | Some("trinary" | "scale") => false,
            Some("raw") => true,
            Some(other) => {
                return Err(invalid(
                    "mode",
                    format!("must be trinary, scale or raw, got {other:?}"),
                ));
            }
        };
        let image_path = yaml_path
            .parent()
            .unwrap_or(Path::new("."))
            .join(&meta.image);
        let pgm = Pgm::load(&image_path)?;
        let mut data = vec![UNKNOWN; pgm.width * pgm.height];
        for img_row in 0..pgm.height {
            let row = pgm.height - 1 - img_row; // image row 0 is the top
            for col in 0..pgm.width {
                let v = f64::from(pgm.pixels[img_row * pgm.width + col]);
                let cell = if raw {
                    let occ = v / 100.0;
                    if v > 100.0 {
                        UNKNOWN
                    } else if occ > meta.occupied_thresh {
                        OCCUPIED
                    } else {
                        FREE
                    }
                } else {
                    let max = f64::from(pgm.maxval);
                    let p = if negate { v / max } else { (max - v) / max };
                    if p > meta.occupied_thresh {
                        OCCUPIED
                    } else if p < meta.free_thresh {
                        FREE
                    } else {
                        UNKNOWN
                    }
                };
                data[row * pgm.width + col] = cell;
            }
        }
        Ok(Self {
            width: pgm.width,
            height: pgm.height,
            resolution: meta.resolution,
            origin: meta.origin,
            data,
        })
    }

    /// Writes the map as map_server YAML at `yaml_path` and a P5 PGM next to it (same stem,
    /// extension `pgm`): occupied 0, free 254, unknown 205; `negate: 0`,
    /// `occupied_thresh: 0.65`, `free_thresh: 0.196`.
    pub fn save(&self, yaml_path: impl AsRef<Path>) -> Result<()> {
        let yaml_path = yaml_path.as_ref();
        let pgm_path = yaml_path.with_extension("pgm");
        let mut bytes = format!(
            "P5\n# hng-simulator ground truth\n{} {}\n255\n",
            self.width, self.height
        )
        .into_bytes();
        for img_row in 0..self.height {
            let row = self.height - 1 - img_row;
            bytes.extend(
                self.data[row * self.width..(row + 1) * self.width]
                    .iter()
                    .map(|&v| match v {
                        OCCUPIED => 0u8,
                        FREE => 254,
                        _ => 205,
                    }),
            );
        }
        std::fs::write(&pgm_path, bytes).map_err(|e| SimError::io(&pgm_path, "cannot write", e))?;
        let image = pgm_path.file_name().map_or_else(
            || pgm_path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let yaml = format!(
            "image: {image}\nresolution: {}\norigin: [{}, {}, {}]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
            self.resolution, self.origin[0], self.origin[1], self.origin[2]
        );
        std::fs::write(yaml_path, yaml).map_err(|e| SimError::io(yaml_path, "cannot write", e))
    }

    /// Rasterises the obstacles of `world` at `resolution` metres per cell: a cell is occupied
    /// when any obstacle overlaps it, free otherwise. The grid covers the obstacles plus a
    /// two-cell margin; its origin has yaw 0.
    pub fn from_world(world: &World, resolution: f64) -> Result<Self> {
        if !(resolution.is_finite() && resolution > 0.0) {
            return Err(SimError::invalid(
                "resolution",
                format!("must be finite and > 0, got {resolution}"),
            ));
        }
        let boxes = world.obstacle_boxes();
        let corners: Vec<[f64; 2]> = boxes.iter().flat_map(BoxObstacle::corners).collect();
        if corners.is_empty() {
            return Err(SimError::invalid(
                "walls",
                "the world has no obstacles to draw",
            ));
        }
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for c in &corners {
            x0 = x0.min(c[0]);
            y0 = y0.min(c[1]);
            x1 = x1.max(c[0]);
            y1 = y1.max(c[1]);
        }
        let margin = 2.0 * resolution;
        let (ox, oy) = (x0 - margin, y0 - margin);
        let width = ((x1 + margin - ox) / resolution).ceil() as usize;
        let height = ((y1 + margin - oy) / resolution).ceil() as usize;
        if width.saturating_mul(height) > 100_000_000 {
            return Err(SimError::invalid(
                "resolution",
                format!("a {width} x {height} grid is too large"),
            ));
        }
        let mut data = vec![FREE; width * height];
        for b in &boxes {
            let cs = b.corners();
            let bx0 = cs.iter().map(|c| c[0]).fold(f64::MAX, f64::min);
            let bx1 = cs.iter().map(|c| c[0]).fold(f64::MIN, f64::max);
            let by0 = cs.iter().map(|c| c[1]).fold(f64::MAX, f64::min);
            let by1 = cs.iter().map(|c| c[1]).fold(f64::MIN, f64::max);
            let c0 = (((bx0 - ox) / resolution).floor().max(0.0) as usize).min(width);
            let c1 = (((bx1 - ox) / resolution).ceil().max(0.0) as usize).min(width);
            let r0 = (((by0 - oy) / resolution).floor().max(0.0) as usize).min(height);
            let r1 = (((by1 - oy) / resolution).ceil().max(0.0) as usize).min(height);
            for row in r0..r1 {
                for col in c0..c1 {
                    let cx = ox + (col as f64) * resolution;
                    let cy = oy + (row as f64) * resolution;
                    if box_overlaps_cell(b, &cs, [cx, cy], resolution) {
                        data[row * width + col] = OCCUPIED;
                    }
                }
            }
        }
        Ok(Self {
            width,
            height,
            resolution,
            origin: [ox, oy, 0.0],
            data,
        })
    }

    /// The occupied cells as boxes: runs of occupied cells in a row become one box, and runs
    /// with the same columns in consecutive rows are merged, to keep the collider count low.
    #[must_use]
    pub fn to_boxes(&self) -> Vec<BoxObstacle> {
        // (start col, end col exclusive) -> first row of the open rectangle
        let mut open: Vec<(usize, usize, usize)> = Vec::new();
        let mut rects: Vec<(usize, usize, usize, usize)> = Vec::new(); // c0, c1, r0, r1 (excl.)
        for row in 0..=self.height {
            let mut runs = Vec::new();
            if row < self.height {
                let cells = &self.data[row * self.width..(row + 1) * self.width];
                let mut col = 0;
                while col < self.width {
                    if cells[col] == OCCUPIED {
                        let start = col;
                        while col < self.width && cells[col] == OCCUPIED {
                            col += 1;
                        }
                        runs.push((start, col));
                    } else {
                        col += 1;
                    }
                }
            }
            let mut next_open = Vec::with_capacity(runs.len());
            for &(c0, c1) in &runs {
                if let Some(pos) = open.iter().position(|&(a, b, _)| a == c0 && b == c1) {
                    let (_, _, r0) = open.swap_remove(pos);
                    next_open.push((c0, c1, r0));
                } else {
                    next_open.push((c0, c1, row));
                }
            }
            rects.extend(open.drain(..).map(|(c0, c1, r0)| (c0, c1, r0, row)));
            open = next_open;
        }
        let res = self.resolution;
        let (s, c) = self.origin[2].sin_cos();
        let mut boxes: Vec<BoxObstacle> = rects
            .into_iter()
            .map(|(c0, c1, r0, r1)| {
                let u = (c0 + c1) as f64 * res / 2.0;
                let v = (r0 + r1) as f64 * res / 2.0;
                BoxObstacle {
                    center: [
                        self.origin[0] + c * u - s * v,
                        self.origin[1] + s * u + c * v,
                    ],
                    size: [(c1 - c0) as f64 * res, (r1 - r0) as f64 * res],
                    angle: self.origin[2],
                }
            })
            .collect();
        // Deterministic order regardless of the merge bookkeeping.
        boxes.sort_by(|a, b| {
            a.center[1]
                .total_cmp(&b.center[1])
                .then(a.center[0].total_cmp(&b.center[0]))
        });
        boxes
    }
}

/// Separating-axis test of an oriented box against the axis-aligned square cell at `min`.
fn box_overlaps_cell(b: &BoxObstacle, corners: &[[f64; 2]; 4], min: [f64; 2], size: f64) -> bool {
    let cell = [
        min,
        [min[0] + size, min[1]],
        [min[0] + size, min[1] + size],
        [min[0], min[1] + size],
    ];
    let (s, c) = b.angle.sin_cos();
    let axes = [[1.0, 0.0], [0.0, 1.0], [c, s], [-s, c]];
    axes.iter().all(|a| {
        let proj = |p: &[f64; 2]| p[0] * a[0] + p[1] * a[1];
        let (mut amin, mut amax, mut bmin, mut bmax) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in corners {
            amin = amin.min(proj(p));
            amax = amax.max(proj(p));
        }
        for p in &cell {
            bmin = bmin.min(proj(p));
            bmax = bmax.max(proj(p));
        }
        // Strict: touching edges do not count as overlap.
        amin < bmax - 1e-9 && bmin < amax - 1e-9
    })
}

/// The field named at the start of a serde_yaml error message ("origin: invalid type ...").
fn yaml_field_in(message: &str) -> Option<String> {
    if let Some(f) = message
        .split("missing field `")
        .nth(1)
        .or_else(|| message.split("unknown field `").nth(1))
        .and_then(|r| r.split('`').next())
    {
        return Some(f.to_owned());
    }
    let head = message.split(": ").next()?;
    (!head.contains(' ') && head != message).then(|| head.to_owned())
}

/// The key defined on 1-based `line` of a YAML text.
fn yaml_key_on_line(text: &str, line: usize) -> Option<String> {
    let l = text.lines().nth(line.checked_sub(1)?)?;
    let key = l.split(':').next()?.trim();
    (!key.is_empty() && !key.starts_with('#')).then(|| key.to_owned())
}

/// 1-based (line, column) of a top-level YAML key, or (1, 1).
fn yaml_key_line(text: &str, key: &str) -> (usize, usize) {
    text.lines()
        .position(|l| l.split(':').next().is_some_and(|k| k.trim() == key))
        .map_or((1, 1), |i| (i + 1, 1))
}

/// A decoded PGM image (row 0 at the top).
struct Pgm {
    width: usize,
    height: usize,
    maxval: u16,
    pixels: Vec<u16>,
}

impl Pgm {
    fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| SimError::io(path, "cannot read", e))?;
        Self::parse(&bytes, path)
    }

    fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        let mut r = PgmReader {
            bytes,
            pos: 0,
            line: 1,
            path,
        };
        let magic = r.token("magic")?;
        let binary = match magic.as_str() {
            "P5" => true,
            "P2" => false,
            other => {
                return Err(r.err(
                    "magic",
                    format!("expected P5 (binary) or P2 (text) PGM, found {other:?}; convert PNG maps to PGM"),
                ));
            }
        };
        let width = r.number("width", 1, 1 << 16)?;
        let height = r.number("height", 1, 1 << 16)?;
        let maxval = r.number("maxval", 1, 65535)?;
        let count = width * height;
        let mut pixels = Vec::with_capacity(count);
        if binary {
            // Exactly one whitespace byte ends the header.
            r.pos += 1;
            let wide = maxval > 255;
            let need = count * if wide { 2 } else { 1 };
            let data = r.bytes.get(r.pos..).unwrap_or(&[]);
            if data.len() < need {
                return Err(r.err(
                    "raster",
                    format!(
                        "{width} x {height} image needs {need} bytes of pixels, found {}",
                        data.len()
                    ),
                ));
            }
            if wide {
                pixels.extend(
                    data.chunks_exact(2)
                        .take(count)
                        .map(|p| u16::from_be_bytes([p[0], p[1]])),
                );
            } else {
                pixels.extend(data.iter().take(count).map(|&p| u16::from(p)));
            }
        } else {
            for i in 0..count {
                let v = r.number(&format!("raster pixel {i}"), 0, maxval)?;
                pixels.push(v as u16);
            }
        }
        if let Some(bad) = pixels.iter().find(|&&p| usize::from(p) > maxval) {
            return Err(r.err(
                "raster",
                format!("pixel value {bad} exceeds maxval {maxval}"),
            ));
        }
        Ok(Self {
            width,
            height,
            maxval: maxval as u16,
            pixels,
        })
    }
}

struct PgmReader<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: usize,
    path: &'a Path,
}

impl PgmReader<'_> {
    fn err(&self, field: &str, message: String) -> SimError {
        SimError::Parse {
            path: self.path.to_path_buf(),
            line: self.line,
            column: 1,
            field: field.to_owned(),
            message,
        }
    }

    /// Next whitespace-separated token, skipping `#` comments.
    fn token(&mut self, field: &str) -> Result<String> {
        loop {
            match self.bytes.get(self.pos) {
                Some(b'#') => {
                    while let Some(&b) = self.bytes.get(self.pos) {
                        if b == b'\n' {
                            break;
                        }
                        self.pos += 1;
                    }
                }
                Some(b) if b.is_ascii_whitespace() => {
                    if *b == b'\n' {
                        self.line += 1;
                    }
                    self.pos += 1;
                }
                Some(_) => break,
                None => return Err(self.err(field, "unexpected end of file".to_owned())),
            }
        }
        let start = self.pos;
        while self
            .bytes
            .get(self.pos)
            .is_some_and(|b| !b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
        Ok(String::from_utf8_lossy(&self.bytes[start..self.pos]).into_owned())
    }

    fn number(&mut self, field: &str, min: usize, max: usize) -> Result<usize> {
        let t = self.token(field)?;
        match t.parse::<usize>() {
            Ok(v) if (min..=max).contains(&v) => Ok(v),
            _ => Err(self.err(
                field,
                format!("expected an integer in {min}..={max}, found {t:?}"),
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pgm_header_errors_name_line_and_field() {
        let err = Pgm::parse(b"P5\n# c\n4 x\n255\n", Path::new("m.pgm")).err();
        let msg = err.map(|e| e.to_string()).unwrap_or_default();
        assert!(msg.contains("m.pgm:3:1: field `height`"), "{msg}");
    }

    #[test]
    fn p2_and_p5_decode_alike() -> Result<()> {
        let p2 = Pgm::parse(b"P2\n3 2\n255\n0 1 2\n3 4 255\n", Path::new("a"))?;
        let p5 = Pgm::parse(b"P5\n3 2\n255\n\x00\x01\x02\x03\x04\xff", Path::new("b"))?;
        assert_eq!(p2.pixels, p5.pixels);
        assert_eq!((p2.width, p2.height), (3, 2));
        Ok(())
    }

    #[test]
    fn runs_merge_into_rectangles() {
        // A 3 x 2 occupied block and one lone cell: two boxes.
        let mut g = OccupancyGrid {
            width: 5,
            height: 3,
            resolution: 1.0,
            origin: [0.0, 0.0, 0.0],
            data: vec![FREE; 15],
        };
        for row in 0..2 {
            for col in 0..3 {
                g.data[row * 5 + col] = OCCUPIED;
            }
        }
        g.data[2 * 5 + 4] = OCCUPIED;
        let boxes = g.to_boxes();
        assert_eq!(boxes.len(), 2);
        assert_eq!(boxes[0].center, [1.5, 1.0]);
        assert_eq!(boxes[0].size, [3.0, 2.0]);
        assert_eq!(boxes[1].center, [4.5, 2.5]);
    }
}
