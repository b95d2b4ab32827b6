//! `hng module NAME`: the built-in modules, each run as its own process.
//!
//! A launch file starts a built-in module with `command = ["hng", "module", "NAME"]`; its
//! configuration arrives through `HNG_MODULE_CONFIG` like any module's.

use std::process::ExitCode;

/// The built-in modules' names.
pub const BUILTIN: &[&str] = &[
    "heartbeat-probe",
    "simulator",
    "rm",
    "contract-probe",
    // HNG v1.0 modules (paper, Table 1; docs/modules.md).
    "manager",
    "security",
    "robot",
    "interface",
    "laser",
    "camera",
    "planning",
    "servo",
    "slam",
    "gps",
    "localization",
    "maps",
    "walls",
    "wall_follower",
    "tracker_colour",
    "tracker_histogram",
    "reacher",
];

/// Runs built-in module `name` as this process.
pub fn run(name: &str) -> ExitCode {
    #[allow(clippy::match_single_binding)]
    match name {
        "heartbeat-probe" => hng_runtime::run_module::<crate::probe::Probe>(),
        "simulator" => hng_simulator::module::main(),
        // The RM measures wall-clock CPU: it never follows a simulation clock (which would
        // wake it for every clock sample).
        "rm" => hng_runtime::run_module_on_wall_clock::<hng_rm::RmModule>(),
        "contract-probe" => hng_runtime::run_module::<hng::contract_probe::Probe>(),
        "manager" => hng_runtime::run_module::<hng_modules::manager::ManagerModule>(),
        "security" => hng_runtime::run_module::<hng_modules::security::SecurityModule>(),
        "robot" => hng_runtime::run_module::<hng_modules::robot::RobotModule>(),
        "interface" => hng_runtime::run_module::<hng_modules::interface::InterfaceModule>(),
        "laser" => hng_runtime::run_module::<hng_modules::laser::LaserModule>(),
        "camera" => hng_runtime::run_module::<hng_modules::camera::CameraModule>(),
        "planning" => hng_runtime::run_module::<hng_modules::planning_module::PlanningModule>(),
        "servo" => hng_runtime::run_module::<hng_modules::servo::ServoModule>(),
        "slam" => hng_runtime::run_module::<hng_modules::slam_module::SlamModule>(),
        "gps" => hng_runtime::run_module::<hng_modules::gps::GpsModule>(),
        "localization" => {
            hng_runtime::run_module::<hng_modules::localization::LocalizationModule>()
        }
        "maps" => hng_runtime::run_module::<hng_modules::maps::MapsModule>(),
        "walls" => hng_runtime::run_module::<hng_modules::walls_module::WallsModule>(),
        "wall_follower" => {
            hng_runtime::run_module::<hng_modules::wall_follower::WallFollowerModule>()
        }
        "tracker_colour" => {
            hng_runtime::run_module::<hng_modules::tracker_module::ColourTrackerModule>()
        }
        "tracker_histogram" => {
            hng_runtime::run_module::<hng_modules::tracker_module::HistogramTrackerModule>()
        }
        "reacher" => hng_runtime::run_module::<hng_modules::reacher_module::ReacherModule>(),
        _ => {
            eprintln!(
                "hng: no built-in module {name:?}; built-in modules: {}",
                if BUILTIN.is_empty() {
                    "none yet".to_string()
                } else {
                    BUILTIN.join(", ")
                }
            );
            ExitCode::from(2)
        }
    }
}
