//! Checks of the built-in modules a launch file starts, made while the file is validated
//! (before anything starts): `["hng", "module", NAME]` must name a built-in module, and its
//! `[module.config]` must parse as that module's configuration type. Problems are reported
//! with the launch file's line and field like every other launch-file error (exit code 2);
//! before this, an unknown name or a wrong config failed only at run time, six times, and
//! named "line 1, column 1" of the passed-on config.

use std::path::Path;
use std::sync::Arc;

use hng_runtime::Module;
use hng_watchdog::ModuleSpec;
use hng_watchdog::launch::{ModuleCheck, ModuleProblem};

use crate::modules::BUILTIN;

/// Parses `text` as `M`'s configuration (an empty text means its defaults, as at run time).
fn config_of<M: Module>(text: &str) -> Result<(), ModuleProblem> {
    if text.trim().is_empty() {
        return Ok(());
    }
    toml::from_str::<M::Config>(text)
        .map(drop)
        .map_err(|e| ModuleProblem::Config {
            span: e.span(),
            message: hng_runtime::module::renamed_to_seconds(e.message())
                .unwrap_or_else(|| format!("invalid configuration: {}", e.message())),
        })
}

/// Checks the configuration of built-in module `name`; `None` if there is no such module.
fn check_config(name: &str, text: &str) -> Option<Result<(), ModuleProblem>> {
    use hng_modules as m;
    Some(match name {
        "heartbeat-probe" => config_of::<crate::probe::Probe>(text),
        "simulator" => config_of::<hng_simulator::module::SimulatorModule>(text),
        "rm" => config_of::<hng_rm::RmModule>(text),
        "contract-probe" => config_of::<hng::contract_probe::Probe>(text),
        "manager" => config_of::<m::manager::ManagerModule>(text),
        "security" => config_of::<m::security::SecurityModule>(text),
        "robot" => config_of::<m::robot::RobotModule>(text),
        "interface" => config_of::<m::interface::InterfaceModule>(text),
        "laser" => config_of::<m::laser::LaserModule>(text),
        "camera" => config_of::<m::camera::CameraModule>(text),
        "planning" => config_of::<m::planning_module::PlanningModule>(text),
        "servo" => config_of::<m::servo::ServoModule>(text),
        "slam" => config_of::<m::slam_module::SlamModule>(text),
        "gps" => config_of::<m::gps::GpsModule>(text),
        "localization" => config_of::<m::localization::LocalizationModule>(text),
        "maps" => config_of::<m::maps::MapsModule>(text),
        "walls" => config_of::<m::walls_module::WallsModule>(text),
        "wall_follower" => config_of::<m::wall_follower::WallFollowerModule>(text),
        "tracker_colour" => config_of::<m::tracker_module::ColourTrackerModule>(text),
        "tracker_histogram" => config_of::<m::tracker_module::HistogramTrackerModule>(text),
        "reacher" => config_of::<m::reacher_module::ReacherModule>(text),
        _ => return None,
    })
}

/// Checks a module started as `hng module NAME` by this executable (`exe`); other programs
/// are not hng's to check.
pub fn check_module(spec: &ModuleSpec, exe: &Path) -> Result<(), ModuleProblem> {
    if spec.program != exe || spec.args.first().map(String::as_str) != Some("module") {
        return Ok(());
    }
    let Some(name) = spec.args.get(1) else {
        return Err(ModuleProblem::Command {
            index: 1,
            message: format!(
                "`hng module` needs the module's name; built-in modules: {}",
                BUILTIN.join(", ")
            ),
        });
    };
    match check_config(name, &spec.config) {
        Some(r) => r,
        None => Err(ModuleProblem::Command {
            index: 2,
            message: format!(
                "no built-in module {name:?}; built-in modules: {}",
                BUILTIN.join(", ")
            ),
        }),
    }
}

/// The check `hng run` gives the launch-file loader (nothing when its own path is unknown).
pub fn module_check() -> Option<ModuleCheck> {
    let exe = std::env::current_exe().ok()?;
    Some(Arc::new(move |spec: &ModuleSpec| check_module(spec, &exe)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_module_has_a_config_check() {
        for name in BUILTIN {
            assert!(
                check_config(name, "").is_some(),
                "built-in module {name} has no configuration check"
            );
        }
        assert!(check_config("nosuch", "").is_none());
    }

    #[test]
    fn a_wrong_field_is_found_with_its_place() {
        let text = "teleop_in = \"x\"\ncolour = \"red\"\n";
        let Some(Err(ModuleProblem::Config { span, message })) = check_config("interface", text)
        else {
            panic!("the unknown field is an error");
        };
        assert!(message.contains("colour"), "{message}");
        let span = span.expect("a span");
        assert_eq!(&text[span.start..span.start + 6], "colour");
    }

    #[test]
    fn an_old_duration_key_names_its_new_spelling() {
        let text = "speed = 2\nduration = 60.0\n";
        let Some(Err(ModuleProblem::Config { span, message })) = check_config("simulator", text)
        else {
            panic!("the old key is an error");
        };
        assert_eq!(message, "`duration` is now `duration_s` (seconds)");
        let span = span.expect("a span");
        assert_eq!(&text[span.start..span.start + 8], "duration");
    }
}
