//! Moving and instanced colliders (`octoproxy_core::scene`, `octoproxy_cpu::Scene`): the scene
//! step against exact ground truth in each instance's own frame, at speeds up to several
//! times a collider's size per step; a one-proxy static scene against the plain step, bit for
//! bit; hit records; crushing; and the scene validator on bad input.

use glam::{Quat, Vec3};
use octoproxy_core::scene::{
    BroadNode, Instance, Pose, SceneError, SceneView, BROAD_INTERNAL, BROAD_LEAF,
};
use octoproxy_core::{
    initial_side, step_particle_hinted, Backend, LeafHint, Particle, ProxyView, SceneSides,
    StepParams, SIDE_BACK,
};
use octoproxy_cpu::scenes;
use octoproxy_cpu::{CpuBackend, Scene, SceneBuildError};
use octoproxy_tests::moving::{
    bake_mesh, lattice, params, pose, random_scene, run, scene_check, Tally,
};

#[test]
fn a_box_translating_three_sizes_a_step_pushes_particles_and_none_tunnels() {
    let cube = scenes::cube([-0.5; 3], [0.5; 3]);
    let words = bake_mesh(&cube, 7);
    let particles = lattice(
        Vec3::new(-1.0, -1.0, -1.0),
        Vec3::new(30.0, 1.0, 1.0),
        24,
        1,
    );
    // 3 units a step: three times the box's size, through particles at rest.
    let (tally, after) = run(
        &[&cube],
        &[words],
        &[(0, pose([-3.0, 0.0, 0.0], Quat::IDENTITY, 1.0))],
        particles,
        12,
        &params([0.0; 3]),
        |step, _| {
            pose(
                [-3.0 + 3.0 * (step + 1) as f32, 0.1, 0.0],
                Quat::IDENTITY,
                1.0,
            )
        },
    )
    .expect("the scene is valid");
    assert_eq!(tally.penetrations, 0, "{tally:?}");
    assert!(tally.collisions > 1000, "the box met particles: {tally:?}");
    // Particles it met move ahead of it, in +x.
    assert!(after.iter().filter(|p| p.velocity[0] > 100.0).count() > 500);
}

#[test]
fn a_paddle_turning_fast_sweeps_particles_and_none_tunnels() {
    let paddle = scenes::slab([0.0; 3], [2.0, 0.5, 0.12]);
    let words = bake_mesh(&paddle, 8);
    let particles = lattice(Vec3::new(-1.1, -0.3, -1.1), Vec3::new(1.1, 0.3, 1.1), 28, 2);
    // 25 degrees a step about y: the paddle's tips move 0.44 a step, 3.6 times its thickness.
    let (tally, _) = run(
        &[&paddle],
        &[words],
        &[(0, Pose::IDENTITY)],
        particles,
        14,
        &params([0.0; 3]),
        |step, _| {
            let a = (25.0f32 * (step + 1) as f32).to_radians();
            pose([0.0; 3], Quat::from_rotation_y(a), 1.0)
        },
    )
    .expect("the scene is valid");
    assert_eq!(tally.penetrations, 0, "{tally:?}");
    assert!(
        tally.collisions > 500,
        "the paddle met particles: {tally:?}"
    );
}

#[test]
fn a_sphere_growing_and_moving_pushes_particles_out_and_none_tunnels() {
    let ball = scenes::uv_sphere([0.0; 3], 0.5, 24, 12);
    let words = bake_mesh(&ball, 7);
    let particles = lattice(Vec3::splat(-1.6), Vec3::splat(1.6), 22, 3);
    let (tally, _) = run(
        &[&ball],
        &[words],
        &[(0, pose([0.0; 3], Quat::IDENTITY, 0.5))],
        particles,
        10,
        &params([0.0; 3]),
        |step, _| {
            let u = (step + 1) as f32;
            pose(
                [0.05 * u, 0.0, 0.0],
                Quat::from_rotation_z(0.2 * u),
                0.5 + 0.2 * u,
            )
        },
    )
    .expect("the scene is valid");
    assert_eq!(tally.penetrations, 0, "{tally:?}");
    assert!(tally.collisions > 300, "{tally:?}");
}

#[test]
fn rain_on_a_grid_of_instances_half_of_them_moving_never_crosses_a_surface() {
    let cube = scenes::cube([-0.4; 3], [0.4; 3]);
    let ball = scenes::uv_sphere([0.0; 3], 0.45, 16, 8);
    let proxies = vec![bake_mesh(&cube, 6), bake_mesh(&ball, 6)];
    let mut placements = Vec::new();
    for i in 0..3 {
        for k in 0..3 {
            placements.push((
                (i + k) % 2,
                pose([i as f32 * 1.5, 0.0, k as f32 * 1.5], Quat::IDENTITY, 1.0),
            ));
        }
    }
    let base = placements.clone();
    let particles = lattice(Vec3::new(-0.8, 0.6, -0.8), Vec3::new(3.8, 2.5, 3.8), 26, 4);
    let (tally, _) = run(
        &[&cube, &ball],
        &proxies,
        &placements,
        particles,
        40,
        &params([0.0, -30.0, 0.0]),
        |step, i| {
            let (_, p) = base[i as usize];
            if i % 2 == 1 {
                let u = (step + 1) as f32;
                let mut t = p.translation;
                t[1] += 0.3 * (0.4 * u).sin();
                pose(
                    t,
                    Quat::from_rotation_y(0.15 * u) * Quat::from_rotation_x(0.1 * u),
                    1.0,
                )
            } else {
                p
            }
        },
    )
    .expect("the scene is valid");
    assert_eq!(tally.penetrations, 0, "{tally:?}");
    assert!(tally.collisions > 2000, "{tally:?}");
}

/// A ball on a slab baked at depth 7, and particles on a jittered lattice of `n` a side around
/// it, moving sideways, with their sides from the proxy, also as one instance's scene sides.
fn ball_on_a_slab(n: u32) -> (Vec<u32>, Vec<Particle>, Vec<SceneSides>) {
    let mesh = scenes::merge(&[
        scenes::uv_sphere([0.0, 0.0, 0.0], 0.6, 20, 10),
        scenes::slab([0.0, -0.8, 0.0], [3.0, 0.1, 3.0]),
    ]);
    let words = bake_mesh(&mesh, 7);
    let view = ProxyView::new(&words).unwrap();
    let mut particles = lattice(Vec3::new(-1.4, -0.7, -1.4), Vec3::new(1.4, 1.5, 1.4), n, 5);
    for (k, p) in particles.iter_mut().enumerate() {
        p.side = initial_side(&view, p.position);
        p.velocity = [
            ((k % 7) as f32 - 3.0) * 0.5,
            0.0,
            ((k % 5) as f32 - 2.0) * 0.5,
        ];
    }
    let sides = particles
        .iter()
        .map(|p| {
            let mut s = SceneSides::EMPTY;
            s.set_side(0, p.side);
            s
        })
        .collect();
    (words, particles, sides)
}

#[test]
fn a_one_proxy_scene_at_the_identity_steps_as_the_plain_step_bit_for_bit() {
    let (words, particles, sides) = ball_on_a_slab(20);
    let view = ProxyView::new(&words).unwrap();
    let params = params([0.0, -9.81, 0.0]);
    let mut plain = particles.clone();
    let mut hints = vec![LeafHint::NONE; plain.len()];
    let mut scene = Scene::new();
    scene.add_proxy(words.clone()).unwrap();
    scene.add_instance(0, Pose::IDENTITY).unwrap();
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&particles).unwrap();
    cpu.upload_scene_sides(&sides).unwrap();
    for step in 0..90 {
        for (p, h) in plain.iter_mut().zip(&mut hints) {
            step_particle_hinted(&view, p, &params, h);
        }
        scene.step(&mut cpu, &params, false).unwrap();
        for (k, (a, b)) in plain.iter().zip(cpu.particles()).enumerate() {
            assert_eq!(
                bytemuck::bytes_of(a),
                bytemuck::bytes_of(b),
                "particle {k} after step {step}: plain {a:?}, scene {b:?}"
            );
        }
    }
    assert!(plain.iter().map(|p| p.collisions()).sum::<u32>() > 1000);
}

/// The CPU backend steps a one-proxy static scene at the identity as the plain step once every
/// particle took it (the side in the particle, an 8-byte hint, the first slots made when
/// asked for): the same particles, sides and report as core's `step_plain` on the scene's
/// form, which a step with hit records takes. Sides are read every step (made on the fly) and
/// downloaded now and then (which ends the mode until the next step takes it again), and the
/// instance moves away and back (the scene's form while it moves).
#[test]
fn a_static_scene_stepped_as_the_plain_step_keeps_the_scenes_sides_and_report() {
    let (words, particles, sides) = ball_on_a_slab(16);
    let params = params([0.0, -9.81, 0.0]);
    // One scene for each backend, moved alike.
    let make = || {
        let mut scene = Scene::new();
        scene.add_proxy(words.clone()).unwrap();
        scene.add_instance(0, Pose::IDENTITY).unwrap();
        scene
    };
    let (mut scene, mut twin) = (make(), make());
    let (mut plain, mut form) = (CpuBackend::new(), CpuBackend::new());
    for cpu in [&mut plain, &mut form] {
        cpu.upload_particles(&particles).unwrap();
        cpu.upload_scene_sides(&sides).unwrap();
    }
    let away = pose([0.3, 0.1, 0.0], Quat::from_rotation_y(0.2), 1.0);
    let mut downloaded = vec![SceneSides::EMPTY; particles.len()];
    for step in 0..160 {
        // Away for two steps at 60, back for two at 62: a moving scene takes the scene's form.
        for s in [&mut scene, &mut twin] {
            match step {
                60 => s.move_to(0, away).unwrap(),
                62 => s.move_to(0, Pose::IDENTITY).unwrap(),
                _ => {}
            }
        }
        scene.step(&mut plain, &params, false).unwrap();
        twin.step(&mut form, &params, true).unwrap();
        for (k, (a, b)) in form.particles().iter().zip(plain.particles()).enumerate() {
            assert_eq!(
                bytemuck::bytes_of(a),
                bytemuck::bytes_of(b),
                "particle {k} after step {step}: scene's form {a:?}, plain {b:?}"
            );
        }
        assert_eq!(form.scene_sides(), plain.scene_sides(), "step {step}");
        if step % 25 == 7 {
            plain.download_scene_sides(&mut downloaded).unwrap();
            assert_eq!(form.scene_sides(), downloaded, "step {step}");
        }
    }
    assert_eq!(
        form.take_scene_report().unwrap(),
        plain.take_scene_report().unwrap()
    );
    assert!(form.particles().iter().map(|p| p.collisions()).sum::<u32>() > 500);
}

#[test]
fn hits_say_where_when_and_how_fast_a_particle_met_a_moving_floor() {
    let floor = scenes::slab([0.0; 3], [2.0, 0.2, 2.0]);
    let words = bake_mesh(&floor, 7);
    let mut scene = Scene::new();
    scene.add_proxy(words).unwrap();
    scene.add_instance(0, Pose::IDENTITY).unwrap();
    // A particle falling at 6 units/s onto a floor rising at 3 units/s: contact in the step,
    // at 9 units/s relative, on the floor's top face (y = 0.1 in its frame).
    let dt = 0.05;
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&[Particle::new([0.1, 0.5, 0.0], [0.0, -6.0, 0.0])])
        .unwrap();
    let p = StepParams {
        gravity: [0.0; 3],
        dt,
        restitution: 1.0,
        friction: 0.0,
        ..StepParams::default()
    };
    let mut steps = 0;
    loop {
        let y = 3.0 * dt * (steps + 1) as f32;
        scene
            .move_to(0, pose([0.0, y, 0.0], Quat::IDENTITY, 1.0))
            .unwrap();
        scene.step(&mut cpu, &p, true).unwrap();
        steps += 1;
        let h = cpu.hits()[0];
        if h.instance >= 0 {
            assert_eq!(h.instance, 0);
            assert!(h.t > 0.0 && h.t <= 1.0, "{h:?}");
            // The floor's top at the hit's time, within a leaf.
            let top = 0.1 + 3.0 * dt * (steps as f32 - 1.0 + h.t);
            let leaf = 4.0 / 128.0;
            assert!((h.position[1] - top).abs() < leaf, "{h:?}, top {top}");
            assert!(
                Vec3::from_array(h.normal).abs_diff_eq(Vec3::Y, 1e-3),
                "{h:?}"
            );
            assert!((h.speed - 9.0).abs() < 0.05, "{h:?}");
            // Elastic against a floor moving up at 3: it leaves at 3 + 9 = 12 up.
            let v = cpu.particles()[0].velocity[1];
            assert!((v - 12.0).abs() < 0.05, "velocity {v}");
            break;
        }
        assert!(steps < 20, "no hit");
    }
    // The next step: no hit.
    scene.step(&mut cpu, &p, true).unwrap();
    assert_eq!(cpu.hits()[0].instance, -1);
}

#[test]
fn a_particle_pressed_between_converging_walls_is_flagged_and_never_pushed_through() {
    let wall = scenes::slab([0.0; 3], [0.1, 1.0, 1.0]);
    let words = bake_mesh(&wall, 7);
    let mut scene = Scene::new();
    scene.add_proxy(words.clone()).unwrap();
    scene
        .add_instance(0, pose([-0.3, 0.0, 0.0], Quat::IDENTITY, 1.0))
        .unwrap();
    scene
        .add_instance(0, pose([0.3, 0.0, 0.0], Quat::IDENTITY, 1.0))
        .unwrap();
    let mut check = scene_check(&[&wall], &[words]);
    let particles = vec![Particle::new([0.0, 0.0, 0.0], [0.0; 3])];
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&particles).unwrap();
    let mut tally = Tally::default();
    let mut before = particles;
    let p = params([0.0; 3]);
    // The walls (0.1 thick) close from 0.6 apart at 1.5 units a second, until they overlap
    // by half their thickness: no point between them is outside both.
    for step in 0..11 {
        let x = 0.3 - 0.025 * (step + 1) as f32;
        scene
            .move_to(0, pose([-x, 0.0, 0.0], Quat::IDENTITY, 1.0))
            .unwrap();
        scene
            .move_to(1, pose([x, 0.0, 0.0], Quat::IDENTITY, 1.0))
            .unwrap();
        scene.prepare().unwrap();
        let instances = scene.instances().to_vec();
        scene.step(&mut cpu, &p, false).unwrap();
        let after = cpu.particles().to_vec();
        tally.add(&check.step(&instances, &before, &after, None));
        before = after;
    }
    assert_eq!(tally.penetrations, 0, "{tally:?}");
    assert!(tally.crushed > 0, "the walls met: {tally:?}");
}

fn tiny_scene() -> (Vec<u32>, Vec<Instance>) {
    let words = bake_mesh(&scenes::cube([-0.5; 3], [0.5; 3]), 5);
    let instances = vec![
        Instance::new(0, Pose::IDENTITY, Pose::IDENTITY),
        Instance::new(
            0,
            pose([3.0, 0.0, 0.0], Quat::IDENTITY, 1.0),
            pose([3.0, 0.0, 0.0], Quat::IDENTITY, 1.0),
        ),
    ];
    (words, instances)
}

fn broad_of(views: &[ProxyView<'_>], instances: &mut [Instance]) -> Vec<BroadNode> {
    let b0 = instances[0].swept_box(&views[0]);
    let b1 = instances[1].swept_box(&views[0]);
    instances[0].leaf = 1;
    instances[1].leaf = 2;
    let node = |b: octoproxy_core::Aabb, index, kind| BroadNode {
        min: b.min.to_array(),
        index,
        max: b.max.to_array(),
        kind,
    };
    let all = octoproxy_core::Aabb {
        min: b0.min.min(b1.min),
        max: b0.max.max(b1.max),
    };
    vec![
        node(all, 2, BROAD_INTERNAL),
        node(b0, 0, BROAD_LEAF),
        node(b1, 1, BROAD_LEAF),
    ]
}

#[test]
fn the_scene_validator_names_what_is_wrong() {
    let (words, mut instances) = tiny_scene();
    let views = [ProxyView::new(&words).unwrap()];
    let nodes = broad_of(&views, &mut instances);
    assert!(SceneView::new(&views, &instances, &nodes).is_ok());
    let err = |instances: &[Instance], nodes: &[BroadNode]| {
        SceneView::new(&views, instances, nodes).unwrap_err()
    };

    let mut bad = instances.clone();
    bad[1].start.translation[0] = f32::NAN;
    assert_eq!(err(&bad, &nodes), SceneError::BadPose { instance: 1 });
    let mut bad = instances.clone();
    bad[0].end.rotation = [0.0, 0.0, 0.5, 0.5];
    assert_eq!(err(&bad, &nodes), SceneError::BadPose { instance: 0 });
    let mut bad = instances.clone();
    bad[0].proxy = 7;
    assert_eq!(
        err(&bad, &nodes),
        SceneError::BadProxy {
            instance: 0,
            proxy: 7
        }
    );
    let mut bad = instances.clone();
    bad[1].half_turn = 0.5;
    assert_eq!(err(&bad, &nodes), SceneError::BadTurn { instance: 1 });
    // Moved without rebuilding the broad phase: its box no longer holds the instance.
    let mut bad = instances.clone();
    bad[1].end.translation[0] = 9.0;
    bad[1] = Instance {
        leaf: 2,
        ..Instance::new(0, bad[1].start, bad[1].end)
    };
    assert_eq!(err(&bad, &nodes), SceneError::BroadBoxTooSmall { node: 2 });
    // A cycle, a second child out of range, a leaf naming the wrong instance, one missing.
    let mut n = nodes.clone();
    n[0].index = 0;
    assert_eq!(err(&instances, &n), SceneError::BadBroadPhase { node: 0 });
    let mut n = nodes.clone();
    n[0].index = 3;
    assert_eq!(err(&instances, &n), SceneError::BadBroadPhase { node: 0 });
    let mut n = nodes.clone();
    n[2].index = 0;
    assert_eq!(
        err(&instances, &n),
        SceneError::NotInBroadPhase { instance: 0 }
    );
    assert_eq!(
        err(&instances, &nodes[1..2]),
        SceneError::NotInBroadPhase { instance: 0 }
    );
    assert_eq!(
        err(&instances, &[]),
        SceneError::NotInBroadPhase { instance: 0 }
    );
    // Hidden (scale 0) or removed instances must not be in it; then an empty one is right.
    let mut hidden = instances.clone();
    hidden[0].end.scale = 0.0;
    assert_eq!(
        err(&hidden, &nodes),
        SceneError::NotInBroadPhase { instance: 0 }
    );
    hidden[1].flags = 0;
    assert!(SceneView::new(&views, &hidden, &[]).is_ok());
    // Too far out for f32 to resolve a leaf.
    let far = pose([3.0e7, 0.0, 0.0], Quat::IDENTITY, 1.0);
    let far = vec![Instance {
        leaf: 1,
        ..Instance::new(0, far, far)
    }];
    let fb = far[0].swept_box(&views[0]);
    let fnode = vec![BroadNode {
        min: fb.min.to_array(),
        index: 0,
        max: fb.max.to_array(),
        kind: BROAD_LEAF,
    }];
    let mut f = far.clone();
    f[0].leaf = 0;
    assert_eq!(err(&f, &fnode), SceneError::TooFarOut { instance: 0 });
}

#[test]
fn the_host_scene_keeps_indices_and_refuses_too_many_overlapping_shells() {
    let cube = scenes::cube([-0.5; 3], [0.5; 3]);
    let mut scene = Scene::new();
    scene.add_proxy(bake_mesh(&cube, 5)).unwrap();
    let a = scene.add_instance(0, Pose::IDENTITY).unwrap();
    let b = scene
        .add_instance(0, pose([2.0, 0.0, 0.0], Quat::IDENTITY, 1.0))
        .unwrap();
    scene.remove(a).unwrap();
    let c = scene.add_instance(0, Pose::IDENTITY).unwrap();
    assert_eq!((a, b, c), (0, 1, 2), "a removed index is not reused");
    assert!(matches!(
        scene.move_to(a, Pose::IDENTITY),
        Err(SceneBuildError::Removed(0))
    ));
    assert!(matches!(
        scene.move_to(9, Pose::IDENTITY),
        Err(SceneBuildError::NoSuchInstance(9))
    ));
    let bad = Pose {
        scale: -1.0,
        ..Pose::IDENTITY
    };
    assert!(matches!(
        scene.move_to(b, bad),
        Err(SceneBuildError::BadPose { instance: 1, .. })
    ));
    scene.prepare().unwrap();
    // Nine boxes on one spot: more shells at one point than a particle keeps sides for.
    for _ in 0..8 {
        scene
            .add_instance(0, pose([0.01, 0.0, 0.0], Quat::IDENTITY, 1.0))
            .unwrap();
    }
    match scene.prepare() {
        Err(SceneBuildError::TooManyOverlapping { instances }) => {
            assert!(
                instances.len() > 8 && instances.contains(&2),
                "{instances:?}"
            );
            assert!(
                !instances.contains(&0) && !instances.contains(&1),
                "{instances:?}"
            );
        }
        other => panic!("expected too many overlapping, got {other:?}"),
    }
}

#[test]
fn random_scenes_of_moving_turning_and_scaling_instances_never_let_a_particle_through() {
    let mut total = Tally::default();
    let mut ran = 0;
    for seed in 1..=6 {
        let r = random_scene(seed, 8, 6, 0.5, 30.0, 12, 12);
        if r.refused {
            continue;
        }
        ran += 1;
        assert_eq!(r.tally.penetrations, 0, "seed {seed}: {r:?}");
        total.collisions += r.tally.collisions;
        total.particle_steps += r.tally.particle_steps;
    }
    assert!(ran >= 4, "only {ran} scenes ran");
    assert!(total.collisions > 1000, "{total:?}");
}

#[test]
fn particles_starting_in_an_instances_shell_take_their_side_from_its_mesh_and_keep_it() {
    use octoproxy_cpu::{starting_scene_sides, MeshRef, Sides};
    let cube = scenes::cube([-0.5; 3], [0.5; 3]);
    let words = bake_mesh(&cube, 6);
    let leaf = ProxyView::new(&words).unwrap().finest_leaf_size();
    let mut scene = Scene::new();
    scene.add_proxy(words.clone()).unwrap();
    let start = pose([1.0, 0.0, 0.0], Quat::from_rotation_y(0.3), 1.2);
    scene.add_instance(0, start).unwrap();
    // Particles a fraction of a leaf inside and outside the top face, in the world.
    let mut particles = Vec::new();
    for i in 0..200 {
        let f = (i as f32 + 0.5) / 200.0;
        let depth = if i % 2 == 0 { -0.3 } else { 0.3 } * leaf;
        let l = Vec3::new(-0.4 + 0.8 * f, 0.5 + depth, 0.4 - 0.8 * f);
        particles.push(Particle::new(start.to_world(l).to_array(), [0.0; 3]));
    }
    let sides = [Sides::new(&[MeshRef::from(&cube)])];
    let (scene_sides, from_mesh) = starting_scene_sides(&scene, &sides, &particles);
    assert!(from_mesh > 150, "{from_mesh} sides from the mesh");
    for (i, s) in scene_sides.iter().enumerate() {
        if let Some(side) = s.side_of(0) {
            assert_eq!(side & 1, if i % 2 == 0 { 1 } else { 0 }, "particle {i}");
        }
    }
    // Stepped under gravity while the box rises and turns: the ones inside stay inside, the
    // others outside (exact winding numbers in the box's frame at every step's end).
    let check = scene_check(&[&cube], &[words]);
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&particles).unwrap();
    cpu.upload_scene_sides(&scene_sides).unwrap();
    let params = params([0.0, -9.81, 0.0]);
    let mut before = particles.clone();
    for step in 1..=30 {
        let p = pose(
            [1.0, 0.02 * step as f32, 0.0],
            Quat::from_rotation_y(0.3 + 0.05 * step as f32),
            1.2,
        );
        scene.move_to(0, p).unwrap();
        scene.prepare().unwrap();
        let inst = scene.instances()[0];
        scene.step(&mut cpu, &params, false).unwrap();
        let after = cpu.particles().to_vec();
        for (i, (a, b)) in before.iter().zip(&after).enumerate() {
            let l = inst.end.to_local(Vec3::from_array(b.position));
            let inside = check.truths[0].is_inside(l.to_array());
            let far = check.truths[0].distance(l.to_array()) > check.diagonals[0] as f64;
            assert!(
                !far || inside == (i % 2 == 0),
                "particle {i} at step {step}: {a:?} -> {b:?}, local {l}"
            );
        }
        before = after;
    }
}

#[test]
fn a_hidden_or_removed_instance_lets_particles_pass_and_a_shown_one_stops_them() {
    let floor = scenes::slab([0.0; 3], [2.0, 0.2, 2.0]);
    let mut scene = Scene::new();
    scene.add_proxy(bake_mesh(&floor, 6)).unwrap();
    let shown = scene.add_instance(0, Pose::IDENTITY).unwrap();
    let hidden = scene
        .add_instance(
            0,
            Pose {
                translation: [0.0, -1.0, 0.0],
                scale: 0.0,
                ..Pose::IDENTITY
            },
        )
        .unwrap();
    let removed = scene
        .add_instance(0, pose([0.0, -2.0, 0.0], Quat::IDENTITY, 1.0))
        .unwrap();
    scene.remove(removed).unwrap();
    // Particles falling from above the shown floor, and from between it and the others.
    let mut particles: Vec<Particle> = (0..50)
        .map(|i| Particle::new([-0.8 + 0.032 * i as f32, 0.5, 0.0], [0.0; 3]))
        .collect();
    particles
        .extend((0..50).map(|i| Particle::new([-0.8 + 0.032 * i as f32, -0.5, 0.0], [0.0; 3])));
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&particles).unwrap();
    let params = params([0.0, -9.81, 0.0]);
    for _ in 0..90 {
        scene.step(&mut cpu, &params, false).unwrap();
    }
    let out = cpu.particles();
    assert!(
        out[..50].iter().all(|p| p.position[1] > 0.05),
        "the shown floor holds them"
    );
    assert!(
        out[50..].iter().all(|p| p.position[1] < -2.5),
        "the hidden and removed ones do not"
    );
    // Shown again (scale 1 at both ends of the step) under them, it holds what falls onto it.
    let lowest = out[50..]
        .iter()
        .map(|p| p.position[1])
        .fold(f32::INFINITY, f32::min);
    let at = pose([0.0, lowest - 1.0, 0.0], Quat::IDENTITY, 1.0);
    scene.set_motion(hidden, at, at).unwrap();
    // They land at 15 units a second and bounce (restitution 0.5) for about 3 seconds.
    for _ in 0..400 {
        scene.step(&mut cpu, &params, false).unwrap();
    }
    let top = lowest - 1.0 + 0.1;
    let out = cpu.particles();
    assert!(
        out[50..].iter().all(|p| (p.position[1] - top).abs() < 0.05),
        "they rest on its top at {top}: {:?}",
        &out[50..52]
    );
    let _ = shown;
}

#[test]
fn a_particle_that_moved_while_an_instance_was_hidden_takes_its_side_anew_when_it_shows() {
    // A particle keeps the side it had of a slab from inside it (behind its faces) while the
    // slab is hidden (scale 0), and is just above the slab's top face, falling, when the slab
    // shows again. Kept, the stale side lets it through the top face (a face seen from behind
    // lets a particle in); taken anew where it is, it lands on the top.
    let slab = scenes::slab([0.0; 3], [2.0, 0.4, 2.0]);
    let mut scene = Scene::new();
    let words = bake_mesh(&slab, 6);
    let leaf = ProxyView::new(&words).unwrap().finest_leaf_size();
    scene.add_proxy(words).unwrap();
    let c = scene.add_instance(0, Pose::IDENTITY).unwrap();
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&[Particle::new([0.1, 0.0, 0.05], [0.0; 3])])
        .unwrap();
    let params = params([0.0, -9.81, 0.0]);
    let hidden = Pose {
        scale: 0.0,
        ..Pose::IDENTITY
    };
    scene.set_motion(c, hidden, hidden).unwrap();
    for _ in 0..3 {
        scene.step(&mut cpu, &params, false).unwrap();
    }
    // Where it is when the slab shows: a third of a leaf above the top face, falling, with
    // the side it had inside.
    let above = Particle::new([0.1, 0.2 + leaf / 3.0, 0.05], [0.0, -2.0, 0.0]);
    cpu.upload_particles(&[above]).unwrap();
    let mut sides = SceneSides::EMPTY;
    assert!(sides.set_side(c, SIDE_BACK));
    cpu.upload_scene_sides(&[sides]).unwrap();
    scene.set_motion(c, Pose::IDENTITY, Pose::IDENTITY).unwrap();
    for _ in 0..60 {
        scene.step(&mut cpu, &params, false).unwrap();
    }
    let p = cpu.particles()[0];
    assert!(
        p.position[1] > 0.2 - leaf,
        "it rests on the top face at 0.2, not inside or through: {p:?}"
    );
    assert!(p.collisions() > 0);
}
