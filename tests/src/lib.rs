//! Cross-crate test support for octoproxy: exact ground truth, procedural scenes, the
//! penetration harness, and the shared test meshes.

pub mod baselines;
pub mod fuzz;
pub mod ground_truth;
pub mod harness;
pub mod meshes;
pub mod scenes;
