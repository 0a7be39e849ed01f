//! A larger penetration sweep than the tests run: every procedural and shared scene at dmax 6
//! and 8, 3,000 particles per parameter set (4 sets: elastic/no gravity, inelastic with full
//! friction, elastic with gravity, defaults), 60 steps, speeds from 0.1 leaf to the whole scene
//! per step. `cargo run --release -p octoproxy-tests --example sweep`.

use octoproxy_core::*;
use octoproxy_cpu::{bake, BuildParams, MeshRef};
use octoproxy_cpu::{ground_truth::GroundTruth, harness::*, scenes};
use octoproxy_tests::meshes;
use octoproxy_tests::starts::parameter_sets;
fn main() {
    let dt = 1.0 / 60.0;
    let mut cases: Vec<(String, scenes::Mesh, bool)> = vec![
        (
            "sphere".into(),
            scenes::uv_sphere([0.0; 3], 1.0, 48, 24),
            true,
        ),
        (
            "torus".into(),
            scenes::torus([0.0; 3], 1.0, 0.35, 48, 24),
            true,
        ),
        ("wedge".into(), scenes::wedge(8.0, 1.5, 1.0), true),
        (
            "slab".into(),
            scenes::slab([0.0; 3], [2.0, 0.01, 2.0]),
            true,
        ),
        ("star".into(), scenes::star_prism(6, 1.0, 0.35, 0.6), true),
        ("shells".into(), scenes::nested_shells(1.0, 0.3), true),
        ("sheet".into(), scenes::flat_sheet([0.0; 3], 2.0, 8), false),
        (
            "dome".into(),
            scenes::hemisphere([0.0; 3], 1.0, 48, 12),
            false,
        ),
    ];
    for (n, c) in meshes::ALL {
        if let Some(m) = meshes::load(n) {
            cases.push((n.to_string(), m, *c));
        }
    }
    for (name, mesh, closed) in &cases {
        for dmax in [6, 8] {
            let (words, _) = bake(
                &[MeshRef::from(mesh)],
                &BuildParams {
                    dmax,
                    ..Default::default()
                },
                &(),
            )
            .unwrap();
            let view = ProxyView::new(&words).unwrap();
            let g = GroundTruth::new(&mesh.positions, &mesh.triangles);
            let leaf = view.finest_leaf_size();
            let scene = view.header().root_size;
            let speeds: Vec<f32> = [
                0.1 * leaf,
                0.5 * leaf,
                2.0 * leaf,
                5.0 * leaf,
                20.0 * leaf,
                scene,
            ]
            .iter()
            .map(|d| d / dt)
            .collect();
            let mut pen = 0;
            let mut steps = 0;
            let mut ex = vec![];
            for (i, params) in parameter_sets(dt).iter().enumerate() {
                let mut ps = random_particles(&view, &g, 3000, &speeds, 100 + i as u64);
                let r = run_check(&view, &g, &mut ps, 60, params, *closed);
                pen += r.penetrations;
                steps += r.particle_steps;
                ex.extend(r.examples.into_iter().map(|e| (i, e)));
            }
            println!(
                "{name} dmax {dmax}: {pen} penetrations in {steps} particle-steps {:?}",
                ex.first()
            );
        }
    }
}
