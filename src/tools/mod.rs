//! The concrete tools, in packages a robot enables: `calc` (arithmetic, statistics,
//! trigonometry, units, geometry), `system` (time, wait), `log` (reading log files in
//! configured directories), `ros` (the ROS graph), `place` (named places), `memory` (facts and past
//! requests) and `turtle`
//! (the sim robot's own).
//!
//! Layout:
//! - `calc`: calc_eval, calc_stats, calc_convert, calc_geometry
//! - `declared`: tools defined in a TOML file, acting through a ROS graph
//! - `expr`: the expression evaluator behind calc_eval
//! - `deny`: policy_deny_add (the model may add deny patterns, never remove them)
//! - `stop`: robot_stop (the e-stop as a tool)
//! - `system`: system_time, system_wait
//! - `log`: log_read
//! - `memory`: memory_note, memory_recall (the robot's memory file)
//! - `place`: place_list, place_go, place_remember, place_forget (named places, Nav2)
//! - `ros`: ros_node_*, ros_topic_*, ros_service_*, ros_param_*, ros_interface_show, ros_log_read
//! - `turtle`: turtle_move, turtle_rotate, turtle_pose, turtle_teleport, turtle_pen, turtle_reset

pub mod calc;
pub mod declared;
pub mod deny;
pub mod expr;
pub mod log;
pub mod memory;
pub mod place;
pub mod ros;
pub mod stop;
pub mod system;
pub mod turtle;

use std::path::PathBuf;

use crate::tool::Package;

/// The tools every robot gets: calculation and system.
pub fn standard() -> Vec<Package> {
    vec![calc::package(), system::package()]
}

/// `log_read` over these directories.
pub fn logs(dirs: Vec<PathBuf>) -> Package {
    Package::new("log").with(log::LogRead::new(dirs))
}
