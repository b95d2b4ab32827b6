//! ROS map_server occupancy maps: a PGM image plus a YAML file, read into and written from an
//! [`OccupancyGrid`].
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

use super::grid::{FREE, GridError, OCCUPIED, OccupancyGrid, UNKNOWN};

/// Why a map file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum MapFileError {
    /// The file could not be read or written.
    #[error("{}: {action}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What was being done ("cannot read", "cannot write").
        action: &'static str,
        /// The operating-system error.
        #[source]
        source: std::io::Error,
    },
    /// The YAML or the PGM image is malformed. Line and column are 1-based.
    #[error("{}:{line}:{column}: field `{field}`: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line of the offending text.
        line: usize,
        /// 1-based column of the offending text.
        column: usize,
        /// The offending field, e.g. `resolution` or `height`.
        field: String,
        /// What is wrong and what is expected.
        message: String,
    },
    /// The image is well-formed but makes no valid grid (for example too large).
    #[error("{}: {source}", path.display())]
    Grid {
        /// The image.
        path: PathBuf,
        /// Why.
        #[source]
        source: GridError,
    },
}

impl MapFileError {
    fn io(path: &Path, action: &'static str, source: std::io::Error) -> Self {
        MapFileError::Io {
            path: path.to_path_buf(),
            action,
            source,
        }
    }
}

type Result<T, E = MapFileError> = std::result::Result<T, E>;

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
    /// Loads a map_server YAML and the image it names.
    pub fn load(yaml_path: impl AsRef<Path>) -> Result<Self> {
        let yaml_path = yaml_path.as_ref();
        let text = std::fs::read_to_string(yaml_path)
            .map_err(|e| MapFileError::io(yaml_path, "cannot read", e))?;
        let parse_err =
            |line: usize, column: usize, field: &str, message: String| MapFileError::Parse {
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
        let too_large = |source| MapFileError::Grid {
            path: image_path.clone(),
            source,
        };
        let width = u32::try_from(pgm.width).map_err(|_| {
            too_large(GridError::BadSize {
                width: u32::MAX,
                height: 0,
            })
        })?;
        let height = u32::try_from(pgm.height).map_err(|_| {
            too_large(GridError::BadSize {
                width: 0,
                height: u32::MAX,
            })
        })?;
        Ok(Self::from_data(
            width,
            height,
            meta.resolution,
            [meta.origin[0], meta.origin[1]],
            data,
        )
        .map_err(too_large)?
        .with_origin_yaw(meta.origin[2]))
    }

    /// Writes the grid as map_server YAML at `yaml_path` and a P5 PGM next to it (same stem,
    /// extension `pgm`): occupied 0, free 254, unknown 205; `negate: 0`,
    /// `occupied_thresh: 0.65`, `free_thresh: 0.196`.
    pub fn save(&self, yaml_path: impl AsRef<Path>) -> Result<()> {
        let yaml_path = yaml_path.as_ref();
        let pgm_path = yaml_path.with_extension("pgm");
        let (width, height) = (self.width() as usize, self.height() as usize);
        let data = self.data();
        let mut bytes = format!("P5\n# hng occupancy grid\n{width} {height}\n255\n").into_bytes();
        for img_row in 0..height {
            let row = height - 1 - img_row;
            bytes.extend(
                data[row * width..(row + 1) * width]
                    .iter()
                    .map(|&v| match v {
                        OCCUPIED => 0u8,
                        FREE => 254,
                        _ => 205,
                    }),
            );
        }
        std::fs::write(&pgm_path, bytes)
            .map_err(|e| MapFileError::io(&pgm_path, "cannot write", e))?;
        let image = pgm_path.file_name().map_or_else(
            || pgm_path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let yaml = format!(
            "image: {image}\nresolution: {}\norigin: [{}, {}, {}]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n",
            self.resolution(),
            self.origin()[0],
            self.origin()[1],
            self.origin_yaw()
        );
        std::fs::write(yaml_path, yaml).map_err(|e| MapFileError::io(yaml_path, "cannot write", e))
    }
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
        let bytes = std::fs::read(path).map_err(|e| MapFileError::io(path, "cannot read", e))?;
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
    fn err(&self, field: &str, message: String) -> MapFileError {
        MapFileError::Parse {
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
}
