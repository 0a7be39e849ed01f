//! How far above the true surface particles come to rest: drops particles on a plate, a
//! sphere and the shared meshes, settles them without bounce, and prints the median and 90th
//! percentile of their distance to the mesh in dmax leaves.
//! `cargo run --release -p octoproxy-tests --example rest_gap`.
use octoproxy_core::{step_particle, Particle, ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::scenes::{self, Mesh};
use octoproxy_cpu::{bake, starting_sides, BuildParams, MeshRef};
use octoproxy_tests::meshes;

fn main() {
    let mut cases: Vec<(String, Mesh)> = vec![
        ("plate".into(), scenes::slab([0.0; 3], [2.0, 0.1, 2.0])),
        (
            "one triangle".into(),
            Mesh {
                positions: vec![[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [0.0, 0.0, 1.0]],
                triangles: vec![[0, 2, 1]],
            },
        ),
        ("sphere".into(), scenes::uv_sphere([0.0; 3], 1.0, 48, 24)),
    ];
    for (n, _) in meshes::ALL {
        if let Some(m) = meshes::load(n) {
            cases.push((n.to_string(), m));
        }
    }
    for (name, mesh) in &cases {
        for dmax in [6, 8] {
            let refs = [MeshRef::from(mesh)];
            let (words, _) = bake(
                &refs,
                &BuildParams {
                    dmax,
                    ..Default::default()
                },
                &(),
            )
            .unwrap();
            let view = ProxyView::new(&words).unwrap();
            let gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
            let leaf = view.finest_leaf_size();
            let root = view.root_aabb();
            let mut rng = Rng::new(3);
            let mut ps: Vec<Particle> = (0..2000)
                .map(|_| {
                    Particle::new(
                        [
                            rng.range(root.min.x, root.max.x),
                            root.max.y - leaf,
                            rng.range(root.min.z, root.max.z),
                        ],
                        [0.0; 3],
                    )
                })
                .collect();
            starting_sides(&refs, &view, &mut ps);
            let params = StepParams {
                restitution: 0.0,
                friction: 0.8,
                ..StepParams::default()
            };
            for _ in 0..600 {
                for p in &mut ps {
                    step_particle(&view, p, &params);
                }
            }
            let mut d: Vec<f64> = ps
                .iter()
                .filter(|p| {
                    p.position[1] > root.min.y + leaf
                        && glam::Vec3::from_array(p.velocity).length() < 0.5
                })
                .map(|p| gt.distance(p.position) / leaf as f64)
                .collect();
            d.sort_by(f64::total_cmp);
            if d.is_empty() {
                println!("{name} dmax {dmax}: none rest");
                continue;
            }
            println!("{name} dmax {dmax}: {} resting, distance in dmax leaves: median {:.2}, 90th {:.2}, max {:.2}", d.len(), d[d.len() / 2], d[d.len() * 9 / 10], d[d.len() - 1]);
        }
    }
}
