//! The guarantee wherever particles start: in the shell of surface leaves on both sides (with
//! exact sides from the mesh, caged where they start inside a solid leaf), emitted from the
//! surface, restarted from a rested frame with new velocities, a fraction of a leaf inside
//! the solid at its vertices, in scenes of overlapping closed parts and on open models whose
//! parts pass through each other. Checked against exact ground truth
//! (winding numbers, crossings), never against the proxy. The sweep runs the same at a larger
//! size: `cargo run --release -p octoproxy-tests --example starts`.

use octoproxy_cpu::scenes;
use octoproxy_tests::meshes;
use octoproxy_tests::starts::{overlapping_parts, run, Start};

fn assert_holds(name: &str, parts: &[scenes::Mesh], dmax: u32, n: usize) {
    for start in Start::ALL {
        let r = run(parts, dmax, start, n, 30, 3);
        assert!(
            r.particle_steps >= (n * 30 * 4) as u64,
            "{name} {start:?}: too few steps"
        );
        assert_eq!(
            (r.penetrations, r.non_finite),
            (0, 0),
            "{name} dmax {dmax} {start:?}: {} penetrations ({} escapes, {} tunnels), e.g. {:?}",
            r.penetrations,
            r.escapes,
            r.tunnels,
            r.examples
        );
    }
}

#[test]
fn overlapping_closed_parts_hold_wherever_particles_start() {
    for (name, parts) in overlapping_parts() {
        for dmax in [6, 8] {
            assert_holds(name, &parts, dmax, 300);
        }
    }
}

#[test]
fn sharp_solids_and_open_rims_hold_wherever_particles_start() {
    let scenes: Vec<(&str, scenes::Mesh)> = vec![
        ("star", scenes::star_prism(6, 1.0, 0.35, 0.6)),
        ("knife wedge", scenes::wedge(8.0, 1.5, 1.0)),
        ("shells", scenes::nested_shells(1.0, 0.3)),
        ("sheet", scenes::flat_sheet([0.0; 3], 2.0, 8)),
        ("dome", scenes::hemisphere([0.0; 3], 1.0, 48, 12)),
    ];
    for (name, mesh) in scenes {
        for dmax in [6, 8] {
            assert_holds(name, std::slice::from_ref(&mesh), dmax, 300);
        }
    }
}

#[test]
fn closed_shared_meshes_hold_wherever_particles_start() {
    for (name, closed) in meshes::ALL {
        if !closed {
            continue;
        }
        let Some(mesh) = meshes::load(name) else {
            println!("skipped: {name}");
            continue;
        };
        assert_holds(name, std::slice::from_ref(&mesh), 6, 200);
    }
}

#[test]
fn open_shared_meshes_hold_wherever_particles_start() {
    // Open scans and models whose parts pass through each other (the teapot's spout through
    // its body, Suzanne's eyes in her head, the ogre's parts): the truth is the parity of the
    // crossings along each path.
    for &(name, closed) in meshes::ALL {
        if closed {
            continue;
        }
        let Some(mesh) = meshes::load(name) else {
            println!("skipped: {name}");
            continue;
        };
        assert_holds(name, std::slice::from_ref(&mesh), 6, 200);
    }
}
