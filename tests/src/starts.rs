//! Campaigns that start particles where users start them: in the shell of surface leaves on
//! both sides (exact sides from the mesh), emitted from the surface, restarted from a rested
//! frame with new velocities, a fraction of a leaf inside a solid at its sharpest vertices,
//! and in scenes of overlapping closed parts. The penetration
//! tests run small ones; `cargo run --release -p octoproxy-tests --example starts` the sweep.

use octoproxy_core::{ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::harness::{self, run_check, run_check_kicked, CheckReport, Starter};
use octoproxy_cpu::io::Mesh;
use octoproxy_cpu::scenes::{self, MeshExt};
use octoproxy_cpu::{bake, BuildParams, MeshRef, Sides};

/// Where a campaign starts its particles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// Within 1.5 `dmax` leaves of the surface, both sides.
    Shell,
    /// Emitted by `emit_surface_for` (the command line's emitter), one `dmax` leaf in front
    /// of their faces, outside solid leaves.
    Emitted,
    /// Emitted, settled under gravity for 300 steps, then given new random velocities.
    Restarted,
    /// A fraction of a leaf from the mesh's vertices (knife edges, star tips, corners), inside
    /// the solid for a closed scene, either side for an open one.
    Corners,
}

impl Start {
    pub const ALL: [Start; 4] = [
        Start::Shell,
        Start::Emitted,
        Start::Restarted,
        Start::Corners,
    ];
}

/// The sweep's parameter sets: elastic without gravity, inelastic with full friction,
/// elastic with gravity, the defaults.
pub fn parameter_sets(dt: f32) -> [StepParams; 4] {
    let p = |gravity: [f32; 3], restitution: f32, friction: f32| StepParams {
        gravity,
        dt,
        restitution,
        friction,
        radius: 0.0,
        _pad: 0,
    };
    [
        p([0.0; 3], 1.0, 0.0),
        p([0.0, -9.81, 0.0], 0.0, 1.0),
        p([0.0, -9.81, 0.0], 1.0, 0.0),
        StepParams {
            dt,
            ..StepParams::default()
        },
    ]
}

/// Scenes of closed parts that overlap or touch: thin fins standing through a plate, a box
/// through a box, a peg in a hole that fits it, boxes touching face to face, a sphere
/// through a box; each closed, wound outward.
pub fn overlapping_parts() -> Vec<(&'static str, Vec<Mesh>)> {
    let fins = {
        let mut v = vec![scenes::slab([0.0; 3], [2.0, 0.2, 2.0])];
        v.extend(
            (0..5).map(|i| scenes::slab([i as f32 * 0.35 - 0.7, 0.25, 0.0], [0.012, 0.9, 1.6])),
        );
        v
    };
    let peg = {
        let mut v = vec![scenes::cube([0.4, -0.2, 0.4], [0.6, 1.2, 0.6])];
        v.extend(
            [
                ([0.0, 0.0, 0.0], [0.4, 0.5, 1.0]),
                ([0.6, 0.0, 0.0], [1.0, 0.5, 1.0]),
                ([0.4, 0.0, 0.0], [0.6, 0.5, 0.4]),
                ([0.4, 0.0, 0.6], [0.6, 0.5, 1.0]),
            ]
            .iter()
            .map(|&(a, b)| scenes::cube(a, b)),
        );
        v
    };
    vec![
        ("fins through a plate", fins),
        (
            "a box through a box",
            vec![
                scenes::cube([0.0; 3], [1.0; 3]),
                scenes::rotated(&scenes::cube([0.3, 0.3, -0.3], [0.7, 0.7, 1.3]), 20.0, 10.0),
            ],
        ),
        ("a peg in a hole", peg),
        (
            "boxes face to face",
            vec![
                scenes::cube([0.0; 3], [1.0; 3]),
                scenes::cube([1.0, 0.2, 0.2], [1.6, 0.8, 0.8]),
                scenes::cube([0.1, 1.0, 0.1], [0.5, 1.3, 0.5]),
            ],
        ),
        (
            "a sphere through a box",
            vec![
                scenes::cube([0.0; 3], [1.0; 3]),
                scenes::uv_sphere([1.0, 0.5, 0.5], 0.35, 24, 12),
            ],
        ),
    ]
}

/// One campaign: `meshes` baked at `dmax`, `n` particles started as `start` says, stepped
/// `steps` times (after the settling, for a restart) with each parameter set, checked against
/// exact ground truth. Speeds from a tenth of a leaf to the whole scene per step.
pub fn run(
    meshes: &[Mesh],
    dmax: u32,
    start: Start,
    n: usize,
    steps: u32,
    seed: u64,
) -> CheckReport {
    let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
    let (words, _) = bake(
        &refs,
        &BuildParams {
            dmax,
            ..BuildParams::default()
        },
        &(),
    )
    .expect("the campaign's scenes bake");
    let view = ProxyView::new(&words).expect("a baked proxy validates");
    let all = scenes::merge(meshes);
    let closed = all.is_closed();
    let gt = GroundTruth::new(&all.positions, &all.triangles);
    let sides = Sides::new(&refs);
    let dt = 1.0 / 60.0;
    let leaf = view.finest_leaf_size();
    let size = view.header().root_size;
    let speeds: Vec<f32> = [
        0.1 * leaf,
        0.5 * leaf,
        2.0 * leaf,
        5.0 * leaf,
        20.0 * leaf,
        size,
    ]
    .iter()
    .map(|d| d / dt)
    .collect();
    let mut total = CheckReport::default();
    for (i, params) in parameter_sets(dt).iter().enumerate() {
        let seed = seed.wrapping_mul(31).wrapping_add(i as u64);
        let starter = Starter {
            view: &view,
            meshes: &refs,
            sides: &sides,
            gt: &gt,
            closed,
        };
        let mut ps = match start {
            Start::Shell => starter.particles(harness::Start::Shell, n, &speeds, seed),
            Start::Corners => starter.particles(harness::Start::Corners, n, &speeds, seed),
            Start::Emitted => starter.particles(harness::Start::Emitted, n, &speeds, seed),
            // Emitted at rest, to settle first.
            Start::Restarted => starter.particles(harness::Start::Emitted, n, &[0.0], seed),
        };
        let r = if start == Start::Restarted {
            // Settle under gravity with no bounce, then kick: the rested frame is the
            // restart's start, checked against the sides the particles first had.
            const SETTLE: u32 = 300;
            let settle = StepParams {
                dt,
                restitution: 0.0,
                friction: 0.5,
                ..StepParams::default()
            };
            let params = *params;
            let speeds = &speeds;
            run_check_kicked(
                &view,
                &gt,
                &mut ps,
                SETTLE + steps,
                |step| if step < SETTLE { settle } else { params },
                closed,
                |step, k, p| {
                    if step == SETTLE {
                        let mut rng = Rng::new(seed ^ (k as u64).wrapping_mul(0x9E37_79B9));
                        p.velocity = (rng.unit_vector() * speeds[k % speeds.len()]).to_array();
                    }
                },
            )
        } else {
            run_check(&view, &gt, &mut ps, steps, params, closed)
        };
        add(&mut total, r);
    }
    total
}

fn add(total: &mut CheckReport, r: CheckReport) {
    total.particles += r.particles;
    total.particle_steps += r.particle_steps;
    add_counts(total, &r);
}

fn add_counts(total: &mut CheckReport, r: &CheckReport) {
    total.penetrations += r.penetrations;
    total.escapes += r.escapes;
    total.tunnels += r.tunnels;
    total.non_finite += r.non_finite;
    total.blocked_steps += r.blocked_steps;
    total.bound_hits += r.bound_hits;
    total.collisions += r.collisions;
    for e in &r.examples {
        if total.examples.len() < 5 {
            total.examples.push(*e);
        }
    }
}
