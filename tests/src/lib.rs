//! Development support for octoproxy's tests and bench: the baselines users would pick
//! instead (a triangle-list octree, parry3d, a signed-distance grid), the fuzz target bodies,
//! and the shared test meshes. The exact ground truth, the penetration harness and the
//! procedural scenes are product features and live in `octoproxy-cpu`.

pub mod baselines;
pub mod fuzz;
pub mod meshes;
pub mod moving;
pub mod radius;
pub mod starts;
