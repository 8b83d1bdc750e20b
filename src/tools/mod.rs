//! The concrete tools, in packages a robot enables: `calc` (arithmetic, statistics,
//! trigonometry, units, geometry), `system` (time, wait) and `log` (reading log files in
//! configured directories). ROS tools join when the ROS layer lands.
//!
//! Layout:
//! - `calc`: calc_eval, calc_stats, calc_convert, calc_geometry
//! - `declared`: tools defined in a TOML file, acting through a ROS graph
//! - `expr`: the expression evaluator behind calc_eval
//! - `guard`: policy_deny_add (the model may add deny patterns, never remove them)
//! - `system`: system_time, system_wait
//! - `log`: log_read

pub mod calc;
pub mod declared;
pub mod expr;
pub mod guard;
pub mod log;
pub mod system;

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
