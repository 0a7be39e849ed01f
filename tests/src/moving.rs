//! Moving-scene checks and campaigns: exact ground truth in each instance's own frame for
//! the scene step (`octoproxy_core::scene`), and random scenes of moving, turning and scaling
//! instances to run it on. The tests run small ones
//! (`tests/tests/moving.rs`); `cargo run --release -p octoproxy-tests --example moving` the
//! campaign.

use glam::{Quat, Vec3};
use octoproxy_core::scene::{Instance, Pose};
use octoproxy_core::{Backend, Particle, ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
pub use octoproxy_cpu::harness::scene::{traced_pieces, Piece, SceneCheck, Tally};
use octoproxy_cpu::io::Mesh;
use octoproxy_cpu::scenes;
use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef, Scene, SceneBuildError};

/// The scene harness (`octoproxy_cpu::harness::scene`) for these tests' closed shapes:
/// `meshes[k]` baked into `proxies[k]`.
pub fn scene_check(meshes: &[&Mesh], proxies: &[Vec<u32>]) -> SceneCheck {
    let refs: Vec<MeshRef<'_>> = meshes.iter().map(|m| MeshRef::from(*m)).collect();
    let views: Vec<ProxyView<'_>> = proxies
        .iter()
        .map(|w| ProxyView::new(w).expect("a valid proxy"))
        .collect();
    SceneCheck::new(&refs, &vec![true; meshes.len()], &views)
}

/// Particles on a jittered lattice in `[lo, hi]`, at rest, outside every given instance's
/// mesh (in its start pose).
pub fn lattice(lo: Vec3, hi: Vec3, n: u32, seed: u32) -> Vec<Particle> {
    let mut out = Vec::new();
    let mut r = seed.wrapping_mul(2_654_435_761).max(1);
    let mut rnd = || {
        r ^= r << 13;
        r ^= r >> 17;
        r ^= r << 5;
        (r as f32) / (u32::MAX as f32)
    };
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let f = Vec3::new(
                    (i as f32 + rnd()) / n as f32,
                    (j as f32 + rnd()) / n as f32,
                    (k as f32 + rnd()) / n as f32,
                );
                out.push(Particle::new((lo + (hi - lo) * f).to_array(), [0.0; 3]));
            }
        }
    }
    out
}

/// The particles outside every instance's mesh by two leaf diagonals (start poses).
pub fn outside_all(
    particles: Vec<Particle>,
    check: &SceneCheck,
    instances: &[Instance],
) -> Vec<Particle> {
    particles
        .into_iter()
        .filter(|p| {
            instances.iter().all(|inst| {
                let l = inst.start.to_local(Vec3::from_array(p.position));
                let truth = &check.truths[inst.proxy as usize];
                !truth.is_inside(l.to_array())
                    && truth.distance(l.to_array())
                        > 2.0 * check.diagonals[inst.proxy as usize] as f64
            })
        })
        .collect()
}

/// Bakes `mesh` at `dmax`, the other parameters default.
pub fn bake_mesh(mesh: &Mesh, dmax: u32) -> Vec<u32> {
    let params = BuildParams {
        dmax,
        ..BuildParams::default()
    };
    bake(&[MeshRef::from(mesh)], &params, &()).expect("bakes").0
}

/// The tests' step parameters: 60 steps a second, restitution 0.5, friction 0.1, `gravity`.
pub fn params(gravity: [f32; 3]) -> StepParams {
    StepParams {
        gravity,
        dt: 1.0 / 60.0,
        restitution: 0.5,
        friction: 0.1,
        ..StepParams::default()
    }
}

/// A pose from a translation, a rotation (normalised here) and a scale.
pub fn pose(t: [f32; 3], q: Quat, s: f32) -> Pose {
    Pose {
        translation: t,
        scale: s,
        rotation: q.normalize().to_array(),
    }
}

/// Runs `steps` scene steps on the CPU, posing every instance with `poses(step, instance)`
/// (its pose at the end of that step) before each, and checks every step: every piece of
/// every path (`step_particle_scene_traced`, which must give the backend's bits).
#[allow(clippy::too_many_arguments)]
pub fn run(
    meshes: &[&Mesh],
    proxies: &[Vec<u32>],
    placements: &[(u32, Pose)],
    particles: Vec<Particle>,
    steps: u32,
    params: &StepParams,
    poses: impl Fn(u32, u32) -> Pose,
) -> Result<(Tally, Vec<Particle>), SceneBuildError> {
    let mut check = scene_check(meshes, proxies);
    let mut scene = Scene::new();
    for w in proxies {
        scene.add_proxy(w.clone())?;
    }
    for &(proxy, p) in placements {
        scene.add_instance(proxy, p)?;
    }
    let particles = outside_all(particles, &check, scene.instances());
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&particles).expect("upload");
    let mut tally = Tally::default();
    let mut before = particles;
    for step in 0..steps {
        for i in 0..placements.len() as u32 {
            scene.move_to(i, poses(step, i))?;
        }
        scene.prepare()?;
        let instances = scene.instances().to_vec();
        let sides = cpu.scene_sides();
        scene.step(&mut cpu, params, false).map_err(|e| match e {
            octoproxy_cpu::SceneStepError::Scene(s) => s,
            other => panic!("{other}"),
        })?;
        let after = cpu.particles().to_vec();
        // The poses of the step just taken (the backend holds them at their ends after it).
        let mut replay = scene.clone();
        for (i, inst) in instances.iter().enumerate() {
            if inst.flags & octoproxy_core::scene::INSTANCE_LIVE != 0 {
                replay.set_motion(i as u32, inst.start, inst.end)?;
            }
        }
        let (pieces, differ) =
            replay.with_view(|view| traced_pieces(view, &before, &sides, &after, params))?;
        assert!(
            differ.is_empty(),
            "the traced scene step differs from the backend's for particles {differ:?}"
        );
        tally.add(&check.step(&instances, &before, &after, Some(&pieces)));
        before = after;
    }
    Ok((tally, before))
}

/// What one random scene of a campaign was, and what it found.
#[derive(Debug)]
pub struct RandomScene {
    /// Instances, and how many of them move.
    pub instances: usize,
    pub moving: usize,
    /// The fastest instance's speed, in scene sizes per step, and the fastest turn, degrees
    /// per step.
    pub fastest: f32,
    pub fastest_turn: f32,
    /// The scene was refused (too many shells at one point): nothing ran.
    pub refused: bool,
    pub tally: Tally,
}

/// One random scene: 1 to `max_instances` closed parts (boxes, balls, tori, thin slabs,
/// stars) baked at `dmax`, placed in a region 4 units wide, a third static, the rest moving
/// at up to `speed` region widths a step and turning up to `turn_deg` degrees a step about a
/// random axis, some of them scaling; particles on a lattice outside all of them, with random
/// gravity, restitution and friction; `steps` steps, each checked.
pub fn random_scene(
    seed: u64,
    max_instances: u32,
    dmax: u32,
    speed: f32,
    turn_deg: f32,
    lattice_n: u32,
    steps: u32,
) -> RandomScene {
    let mut rng = Rng::new(seed);
    let shapes = [
        scenes::cube([-0.4; 3], [0.4; 3]),
        scenes::uv_sphere([0.0; 3], 0.45, 20, 10),
        scenes::torus([0.0; 3], 0.4, 0.15, 24, 12),
        scenes::slab([0.0; 3], [1.2, 0.05, 0.8]),
        scenes::star_prism(5, 0.5, 0.2, 0.3),
    ];
    let proxies: Vec<Vec<u32>> = shapes.iter().map(|m| bake_mesh(m, dmax)).collect();
    let meshes: Vec<&Mesh> = shapes.iter().collect();
    let n = 1 + (rng.next_u64() % max_instances as u64) as u32;
    let region = 4.0f32;
    struct Motion {
        proxy: u32,
        t0: Vec3,
        q0: Quat,
        s0: f32,
        velocity: Vec3,
        axis: Vec3,
        turn: f32,
        grow: f32,
    }
    let mut motions = Vec::new();
    let (mut fastest, mut fastest_turn, mut moving) = (0.0f32, 0.0f32, 0);
    for k in 0..n {
        let moves = k % 3 != 0;
        let velocity = if moves {
            rng.unit_vector() * rng.range(0.0, speed * region)
        } else {
            Vec3::ZERO
        };
        let turn = if moves {
            rng.range(0.0, turn_deg).to_radians()
        } else {
            0.0
        };
        let grow = if moves && rng.f32() < 0.3 {
            rng.range(-0.03, 0.03)
        } else {
            0.0
        };
        if moves {
            moving += 1;
            fastest = fastest.max(velocity.length() / region);
            fastest_turn = fastest_turn.max(turn.to_degrees());
        }
        motions.push(Motion {
            proxy: (rng.next_u64() % shapes.len() as u64) as u32,
            t0: Vec3::new(
                rng.range(0.0, region),
                rng.range(0.0, region * 0.5),
                rng.range(0.0, region),
            ),
            q0: Quat::from_axis_angle(rng.unit_vector(), rng.range(0.0, std::f32::consts::TAU)),
            s0: rng.range(0.6, 1.4),
            velocity,
            axis: rng.unit_vector(),
            turn,
            grow,
        });
    }
    // Moving instances bounce back and forth so that they stay near the particles.
    let at = |m: &Motion, step: u32| {
        let u = (step + 1) as f32;
        let swing = (u * 0.7).sin() * 3.0;
        let t = m.t0 + m.velocity * swing;
        let q = Quat::from_axis_angle(m.axis, m.turn * u) * m.q0;
        let s = (m.s0 * (1.0 + m.grow * u)).max(0.2);
        pose(t.to_array(), q, s)
    };
    let placements: Vec<(u32, Pose)> = motions
        .iter()
        .map(|m| (m.proxy, pose(m.t0.to_array(), m.q0, m.s0)))
        .collect();
    let particles = lattice(
        Vec3::new(-0.5, -0.5, -0.5),
        Vec3::new(region + 0.5, region * 0.5 + 1.0, region + 0.5),
        lattice_n,
        seed as u32,
    );
    let params = StepParams {
        gravity: [0.0, -rng.range(0.0, 30.0), 0.0],
        dt: 1.0 / 60.0,
        restitution: rng.range(0.0, 1.0),
        friction: rng.range(0.0, 1.0),
        radius: 0.0,
        _pad: 0,
    };
    let result = run(
        &meshes,
        &proxies,
        &placements,
        particles,
        steps,
        &params,
        |step, i| at(&motions[i as usize], step),
    );
    let (refused, tally) = match result {
        Ok((tally, _)) => (false, tally),
        Err(SceneBuildError::TooManyOverlapping { .. }) => (true, Tally::default()),
        Err(e) => panic!("scene {seed}: {e}"),
    };
    RandomScene {
        instances: n as usize,
        moving,
        fastest,
        fastest_turn,
        refused,
        tally,
    }
}
