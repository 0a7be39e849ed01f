//! The real meshes in `../shared/meshes` (relative to the repository root). Tests that need
//! them print "skipped" when they are absent, except under `CI=true`, where they must be there.

use std::path::PathBuf;

use octoproxy_cpu::io::{load_mesh, Mesh};

/// The directory of the shared meshes.
pub fn dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/meshes")
}

/// Loads `name` (e.g. `"spot.obj.gz"`), or `None` with a message when the meshes are absent.
/// Panics under `CI=true` when absent, and on any load error (the meshes must load).
pub fn load(name: &str) -> Option<Mesh> {
    let path = dir().join(name);
    if !path.exists() {
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!(
                "{} is missing, and CI=true requires the shared meshes",
                path.display()
            );
        }
        eprintln!(
            "skipped: {} not found (the shared meshes live in ../shared/meshes)",
            path.display()
        );
        return None;
    }
    match load_mesh(&path) {
        Ok((mesh, _)) => Some(mesh),
        Err(e) => panic!("{e}"),
    }
}

/// Every shared mesh: file name, closed or not.
pub const ALL: &[(&str, bool)] = &[
    ("stanford-bunny.obj.gz", false),
    ("ogre.obj.gz", false),
    ("nefertiti.obj.gz", true),
    ("beast.obj.gz", false),
    ("rocker-arm.obj.gz", true),
    ("fandisk.obj.gz", true),
    ("spot.obj.gz", true),
    ("teapot.obj.gz", false),
    ("suzanne.obj.gz", false),
];
