//! Moving-scene checks and campaigns: exact ground truth in each instance's own frame for
//! the scene step (`octoproxy_core::scene`), and random scenes of moving, turning and scaling
//! instances to run it on. The tests run small ones
//! (`tests/tests/moving.rs`); `cargo run --release -p octoproxy-tests --example moving` the
//! campaign.

use glam::{Quat, Vec3};
use octoproxy_core::scene::{Instance, Pose, FLAG_CRUSHED};
use octoproxy_core::{Backend, Particle, ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::io::Mesh;
use octoproxy_cpu::scenes;
use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef, Scene, SceneBuildError};

/// Counts, after one scene step, the particles that are inside a closed instance's mesh
/// deeper than one finest-leaf diagonal, in the instance's frame at the end pose. Every
/// particle of these tests starts outside every mesh, so none may be inside at any step's
/// end. A particle with no collision in the step went straight in the world: its path in each
/// instance's frame (the pose at each moment, lerp and slerp) is checked too, in chords whose
/// crossings with the mesh are exact, and where a chord crosses, point by point every half
/// leaf diagonal: that is where a fast particle tunnelling through a thin collider would
/// show, ending outside on the other side. Particles flagged crushed (pressed between two
/// instances, left at their last contact with one) are counted in `crushed` and not checked
/// from then on: one may be inside the other instance, which passed over it.
pub struct SceneCheck {
    pub truths: Vec<GroundTruth>,
    pub diagonals: Vec<f32>,
    /// Per particle: whether it was ever flagged crushed (it is then counted, not checked).
    crushed: std::cell::RefCell<Vec<bool>>,
}

#[derive(Debug, Default)]
pub struct Tally {
    /// Particles found too deep inside a mesh (at a step's end or on a straight path).
    pub penetrations: usize,
    /// Particles flagged crushed.
    pub crushed: usize,
    /// Collisions counted.
    pub collisions: u64,
    /// Particle-steps checked.
    pub particle_steps: u64,
    /// The first few penetrations, for the failure message.
    pub examples: Vec<String>,
}

impl SceneCheck {
    /// Ground truth for each proxy's mesh.
    pub fn new(meshes: &[&Mesh], proxies: &[Vec<u32>]) -> Self {
        Self {
            truths: meshes
                .iter()
                .map(|m| GroundTruth::new(&m.positions, &m.triangles))
                .collect(),
            diagonals: proxies
                .iter()
                .map(|w| ProxyView::new(w).unwrap().finest_leaf_size() * 3f32.sqrt())
                .collect(),
            crushed: Default::default(),
        }
    }

    /// Checks one step of `before -> after` against `instances` (their poses in that step):
    /// every step's end, and the straight path of a particle with no collision.
    pub fn step(
        &self,
        instances: &[Instance],
        before: &[Particle],
        after: &[Particle],
        t: &mut Tally,
    ) {
        self.step_with_pieces(instances, before, after, None, t)
    }

    /// [`SceneCheck::step`] with every particle's path as `step_particle_scene_traced` gives
    /// it: every piece of every path is followed in every instance's frame.
    pub fn step_with_pieces(
        &self,
        instances: &[Instance],
        before: &[Particle],
        after: &[Particle],
        pieces: Option<&[Vec<Piece>]>,
        t: &mut Tally,
    ) {
        let mut crushed = self.crushed.borrow_mut();
        crushed.resize(after.len(), false);
        for (k, (a, b)) in before.iter().zip(after).enumerate() {
            t.particle_steps += 1;
            t.collisions += (b.collisions() - a.collisions()) as u64;
            if b.flags & FLAG_CRUSHED != 0 {
                t.crushed += 1;
                crushed[k] = true;
            }
            if crushed[k] {
                continue;
            }
            let straight = b.collisions() == a.collisions();
            for inst in instances.iter().filter(|i| i.is_active()) {
                let truth = &self.truths[inst.proxy as usize];
                let diagonal = self.diagonals[inst.proxy as usize] as f64;
                let l1 = inst.end.to_local(Vec3::from_array(b.position));
                let deep = |l: Vec3| {
                    truth.is_inside(l.to_array()) && truth.distance(l.to_array()) > diagonal
                };
                let mut found = deep(l1).then_some((l1, 1.0f32));
                match pieces {
                    Some(pieces) => {
                        for &(pa, pb, ua, ub) in &pieces[k] {
                            if found.is_some() {
                                break;
                            }
                            found = self.deepest_on_piece(inst, pa, pb, ua, ub, &deep);
                        }
                    }
                    None if found.is_none() && straight => {
                        let (x0, x1) = (Vec3::from_array(a.position), Vec3::from_array(b.position));
                        found = self.deepest_on_piece(inst, x0, x1, 0.0, 1.0, &deep);
                    }
                    None => {}
                }
                if let Some((l, at)) = found {
                    t.penetrations += 1;
                    if t.examples.len() < 4 {
                        let l0 = inst.start.to_local(Vec3::from_array(a.position));
                        let path = pieces
                            .map(|p| format!(", pieces {:?}", p[k]))
                            .unwrap_or_default();
                        t.examples.push(format!(
                            "{} -> {} (local {l0} -> {l1}; deep at {l}, {at:.3} of the step), before {a:?}, after {b:?}, instance {inst:?}{path}",
                            Vec3::from_array(a.position),
                            Vec3::from_array(b.position)
                        ));
                    }
                }
            }
        }
    }

    /// A point of the straight world piece `x0 -> x1`, travelled from fraction `u0` to `u1`
    /// of the step, in `inst`'s frame (its pose at each moment), that `deep` says is too deep,
    /// and the fraction of the step where it is.
    fn deepest_on_piece(
        &self,
        inst: &Instance,
        x0: Vec3,
        x1: Vec3,
        u0: f32,
        u1: f32,
        deep: &dyn Fn(Vec3) -> bool,
    ) -> Option<(Vec3, f32)> {
        let truth = &self.truths[inst.proxy as usize];
        let step = self.diagonals[inst.proxy as usize] * 0.5;
        let at = |t: f32| {
            inst.pose_at(u0 + (u1 - u0) * t)
                .to_local(x0 + (x1 - x0) * t)
        };
        let chords: u32 = if inst.is_static() { 1 } else { 64 };
        let chords_f = chords as f32;
        for j in 0..chords {
            let (ta, tb) = (j as f32 / chords_f, (j + 1) as f32 / chords_f);
            let (la, lb) = (at(ta), at(tb));
            if truth.segment_crossings(la.to_array(), lb.to_array()) == 0 {
                continue;
            }
            let n = ((lb - la).length() / step).ceil().max(1.0) as u32;
            for k in 0..=n {
                let t = ta + (tb - ta) * k as f32 / n as f32;
                let l = at(t);
                if deep(l) {
                    return Some((l, u0 + (u1 - u0) * t));
                }
            }
        }
        None
    }
}

/// A straight piece of a world path: from, to, and the fractions of the step at its ends.
pub type Piece = (Vec3, Vec3, f32, f32);

/// Every particle's pieces of one scene step by `step_particle_scene_traced`, from the state
/// `before` (particles and sides), checked to give the very bits `after` that the backend gave.
pub fn traced_pieces(
    view: &octoproxy_core::SceneView<'_>,
    before: &[Particle],
    sides: &[octoproxy_core::SceneSides],
    after: &[Particle],
    params: &StepParams,
) -> Vec<Vec<Piece>> {
    use rayon::prelude::*;
    before
        .par_iter()
        .zip(sides)
        .zip(after)
        .map(|((p, s), expected)| {
            let mut q = *p;
            let (mut h, mut sl) = s.split();
            let mut pieces = Vec::new();
            let mut hit = octoproxy_core::Hit::NONE;
            octoproxy_core::step_particle_scene_traced(view, &mut q, &mut h, &mut sl, params, &mut hit, &mut |a, b, ua, ub| {
                pieces.push((a, b, ua, ub))
            });
            assert_eq!(
                bytemuck::bytes_of(&q),
                bytemuck::bytes_of(expected),
                "the traced scene step differs from the backend's: {p:?} -> {q:?} traced, {expected:?} stepped"
            );
            pieces
        })
        .collect()
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
    let check = SceneCheck::new(meshes, proxies);
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
        let pieces =
            replay.with_view(|view| traced_pieces(view, &before, &sides, &after, params))?;
        check.step_with_pieces(&instances, &before, &after, Some(&pieces), &mut tally);
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
        _pad: [0; 2],
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
