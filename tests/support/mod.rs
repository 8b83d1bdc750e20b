//! What the integration tests share: synthetic models (no weights), test backends, and
//! the loopback-only network namespace the ROS tests run in. Benches include single
//! files of it by path.

pub mod bytext;
pub mod faults;
pub mod llama_server;
pub mod netns;
pub mod scripted;
pub mod synthetic;
pub mod uniform;
pub mod webdriver;
