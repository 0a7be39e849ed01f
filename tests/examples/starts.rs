//! The sweep of starts where users start particles (see `octoproxy_tests::starts`): every
//! procedural, overlapping-parts and shared scene at dmax 6 and 8, particles in the shell on
//! both sides, emitted, and restarted from a rested frame, with the sweep's four parameter
//! sets, speeds from 0.1 leaf to the whole scene per step.
//! `cargo run --release -p octoproxy-tests --example starts [-- N STEPS [SCENE-FILTER]]`.

use octoproxy_cpu::scenes;
use octoproxy_tests::meshes;
use octoproxy_tests::starts::{overlapping_parts, run, Start};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n: usize = args.first().map_or(2000, |a| a.parse().expect("N"));
    let steps: u32 = args.get(1).map_or(40, |a| a.parse().expect("STEPS"));
    let filter = args.get(2).cloned().unwrap_or_default();
    let mut cases: Vec<(String, Vec<scenes::Mesh>)> = vec![
        (
            "sphere".into(),
            vec![scenes::uv_sphere([0.0; 3], 1.0, 48, 24)],
        ),
        (
            "torus".into(),
            vec![scenes::torus([0.0; 3], 1.0, 0.35, 48, 24)],
        ),
        ("wedge".into(), vec![scenes::wedge(8.0, 1.5, 1.0)]),
        (
            "slab".into(),
            vec![scenes::slab([0.0; 3], [2.0, 0.01, 2.0])],
        ),
        ("star".into(), vec![scenes::star_prism(6, 1.0, 0.35, 0.6)]),
        ("shells".into(), vec![scenes::nested_shells(1.0, 0.3)]),
        ("sheet".into(), vec![scenes::flat_sheet([0.0; 3], 2.0, 8)]),
        (
            "dome".into(),
            vec![scenes::hemisphere([0.0; 3], 1.0, 48, 12)],
        ),
    ];
    for (name, parts) in overlapping_parts() {
        cases.push((name.into(), parts));
    }
    for (name, _) in meshes::ALL {
        if let Some(m) = meshes::load(name) {
            cases.push((name.to_string(), vec![m]));
        }
    }
    let mut total = 0;
    for (name, parts) in &cases {
        if !name.contains(filter.as_str()) {
            continue;
        }
        for dmax in [6, 8] {
            for start in Start::ALL {
                let r = run(parts, dmax, start, n, steps, 1);
                total += r.penetrations;
                println!(
                    "{name} dmax {dmax} {start:?}: {} penetrations ({} escapes, {} tunnels) in {} particle-steps{}",
                    r.penetrations,
                    r.escapes,
                    r.tunnels,
                    r.particle_steps,
                    r.examples
                        .first()
                        .map_or(String::new(), |e| format!(", e.g. {e:?}"))
                );
            }
        }
    }
    println!("total: {total} penetrations");
}
