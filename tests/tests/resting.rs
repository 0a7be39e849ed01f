//! Particles resting on a surface under gravity stay there, for thousands of steps, without
//! sinking through, and rest within one dmax leaf of it: checked against exact ground truth,
//! on a flat top, a sphere, a comb of fins thinner than a leaf, and the bunny.

use octoproxy_core::{initial_side, Particle, ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::harness::{run_check, tolerance};
use octoproxy_cpu::scenes::{self, Mesh};
use octoproxy_cpu::{bake, BuildParams, MeshRef};
use octoproxy_tests::meshes;

const STEPS: u32 = 3000;

/// Drops `n` particles at rest from just above the mesh's top (found by casting down against
/// the ground truth) and steps them `STEPS` times under gravity.
fn rest(name: &str, mesh: &Mesh, closed: bool, n: usize, params: &StepParams) -> Vec<Particle> {
    let (words, _) = bake(
        &[MeshRef::from(mesh)],
        &BuildParams {
            dmin: 3,
            dmax: 7,
            ..BuildParams::default()
        },
        &(),
    )
    .unwrap();
    let view = ProxyView::new(&words).unwrap();
    let gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
    let root = view.root_aabb();
    let leaf = view.finest_leaf_size();
    let mut rng = Rng::new(5);
    let mut particles = Vec::new();
    let mut tries = 0;
    while particles.len() < n && tries < n * 100 {
        tries += 1;
        let x = rng.range(root.min.x + leaf, root.max.x - leaf);
        let z = rng.range(root.min.z + leaf, root.max.z - leaf);
        // The highest surface point under (x, z), by bisection on the crossing count.
        let top = root.max.y - leaf;
        let bottom = root.min.y + leaf;
        if gt.segment_crossings([x, top, z], [x, bottom, z]) == 0 {
            continue;
        }
        let (mut hi, mut lo) = (top, bottom);
        for _ in 0..40 {
            let mid = 0.5 * (hi + lo);
            if gt.segment_crossings([x, top, z], [x, mid, z]) > 0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        // Start three tolerances above it: outside the shell, where the guarantee holds.
        let start = [x, hi + 3.0 * tolerance(&view), z];
        if start[1] >= root.max.y {
            continue;
        }
        let mut p = Particle::new(start, [0.0; 3]);
        p.side = initial_side(&view, p.position);
        particles.push(p);
    }
    assert!(particles.len() >= n / 2, "{name}: too few drop points");
    let report = run_check(&view, &gt, &mut particles, STEPS, params, closed);
    eprintln!(
        "{name}: {} particles x {STEPS} steps, {} penetrations, {} NaN, {} collisions",
        report.particles, report.penetrations, report.non_finite, report.collisions
    );
    assert_eq!(
        report.penetrations, 0,
        "{name}: sank through, e.g. {:?}",
        report.examples
    );
    assert_eq!(report.non_finite, 0, "{name}: NaN");
    assert!(
        report.collisions as usize > particles.len(),
        "{name}: nothing came to rest"
    );
    // Contact where the surface is: those still on the surface (resting or sliding: within
    // eight leaves of it, where a coarse leaf's face used to hold them) lie within one dmax
    // leaf of the true surface (the 90th percentile, measured against the mesh).
    if params.restitution < 1.0 {
        let mut gaps: Vec<f64> = particles
            .iter()
            .map(|p| gt.distance_capped(p.position, 8.0 * leaf as f64) / leaf as f64)
            .filter(|&d| d < 8.0)
            .collect();
        gaps.sort_by(f64::total_cmp);
        assert!(
            gaps.len() * 5 >= particles.len(),
            "{name}: only {} on the surface",
            gaps.len()
        );
        let p90 = gaps[gaps.len() * 9 / 10];
        eprintln!(
            "{name}: {} on the surface, median {:.3} and 90th percentile {p90:.3} dmax leaves from it",
            gaps.len(),
            gaps[gaps.len() / 2]
        );
        assert!(
            p90 <= 1.0,
            "{name}: resting particles float {p90:.2} leaves above the surface"
        );
    }
    particles
}

fn settings() -> [StepParams; 2] {
    [
        StepParams {
            restitution: 0.0,
            friction: 1.0,
            ..StepParams::default()
        },
        StepParams {
            restitution: 1.0,
            friction: 0.0,
            ..StepParams::default()
        },
    ]
}

#[test]
fn particles_rest_on_a_flat_top() {
    let mesh = scenes::cube([-1.0, -1.0, -1.0], [1.0, 0.0, 1.0]);
    for params in settings() {
        let ps = rest("flat top", &mesh, true, 200, &params);
        if params.restitution == 0.0 {
            // With no bounce, everything that landed on the top is still on it.
            let on_top = ps
                .iter()
                .filter(|p| p.position[1] >= -1e-4 && p.position[1] < 1e-4)
                .count();
            assert!(
                on_top * 10 >= ps.len() * 9,
                "only {on_top} of {} rest on the top",
                ps.len()
            );
        }
    }
}

#[test]
fn particles_rest_on_a_sphere_and_between_thin_fins() {
    let sphere = scenes::uv_sphere([0.0; 3], 1.0, 48, 24);
    let comb = scenes::merge(
        &(0..7)
            .map(|i| scenes::slab([i as f32 * 0.25 - 0.75, 0.0, 0.0], [0.004, 1.2, 1.5]))
            .collect::<Vec<_>>(),
    );
    let floor = scenes::cube([-1.2, -1.0, -1.2], [1.2, -0.6, 1.2]);
    let comb = scenes::merge(&[comb, floor]);
    for params in settings() {
        rest("sphere", &sphere, true, 150, &params);
        rest("comb of fins on a floor", &comb, true, 150, &params);
    }
}

#[test]
fn particles_rest_on_the_bunny() {
    let Some(bunny) = meshes::load("stanford-bunny.obj.gz") else {
        return;
    };
    // On a floor just under it, so that what slides off its flanks comes to rest too.
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in &bunny.positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let pad = 0.2 * (hi[0] - lo[0]);
    let floor = scenes::cube(
        [lo[0] - pad, lo[1] - pad, lo[2] - pad],
        [hi[0] + pad, lo[1] + 0.01 * pad, hi[2] + pad],
    );
    rest(
        "bunny on a floor",
        &scenes::merge(&[bunny, floor]),
        false,
        150,
        &StepParams {
            restitution: 0.1,
            friction: 1.0,
            ..StepParams::default()
        },
    );
}
