//! `hng sim ...`: simulator tools.
//!
//! `hng sim map [--world W] [--resolution R] OUT.yaml` writes the ground-truth occupancy map of
//! a world (the built-in one by default) as a ROS map_server pair: `OUT.yaml` and `OUT.pgm`.

use std::path::PathBuf;

use anyhow::{Context as _, Result};
use clap::Subcommand;
use hng_simulator::{Pose2D, World};

/// `hng sim` subcommands.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Write a world's ground-truth occupancy map (map_server PGM + YAML) for scoring maps.
    Map {
        /// World: a TOML world file or a map_server YAML (default: the built-in world).
        #[arg(long)]
        world: Option<PathBuf>,
        /// Metres per pixel.
        #[arg(long, default_value_t = 0.05)]
        resolution: f64,
        /// The map YAML to write; the image goes beside it with the extension `pgm`.
        out: PathBuf,
    },
}

/// Loads a world file: map_server YAML (`.yaml`/`.yml`) or TOML; `None` is the built-in world.
pub fn load_world(path: Option<&PathBuf>) -> Result<World> {
    let Some(path) = path else {
        return Ok(World::default_world());
    };
    let yaml = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("yaml") || e.eq_ignore_ascii_case("yml"));
    let world = if yaml {
        World::from_occupancy_map(path, Pose2D::default())?
    } else {
        World::load(path)?
    };
    Ok(world)
}

/// Runs an `hng sim` subcommand.
pub fn run(cmd: SimCommand) -> Result<()> {
    match cmd {
        SimCommand::Map {
            world,
            resolution,
            out,
        } => {
            let w = load_world(world.as_ref())?;
            w.write_occupancy_map(&out, resolution)
                .with_context(|| format!("writing the ground-truth map of world {:?}", w.name))?;
            println!(
                "wrote {} and {}",
                out.display(),
                out.with_extension("pgm").display()
            );
            Ok(())
        }
    }
}
