//! The particle-particle pass (`Backend::step_pairs`) on the CPU and on the GPU (wgpu;
//! lavapipe in CI), compared bit for bit: every particle's position, velocity, side and flags,
//! and the pass's report.
//!
//! The pass sorts its particles by a total order and every particle sums its contacts in a
//! fixed order, reading only the last iteration's velocities (core's `pairs` module), so the
//! GPU's mirror (`backend-wgpu/src/wgsl/pairs.wgsl`) gives the CPU's bits wherever division
//! and square roots are correctly rounded and nothing is fused: on lavapipe. A pile amplifies
//! any difference of an ULP within a few steps, so a mirror that drifts anywhere the scenes
//! reach cannot pass there. On other adapters (Vulkan allows `x / y` and `sqrt` within 2.5
//! ULP) only the counts of the report are checked, and the agreement is printed.
//!
//! The scenes: (a) two particles head-on, with and without gravity, and one alone that lands
//! and rests on the floor; (b) a pile of 2,200
//! particles poured into a box, for two seconds, with friction, stacking and the iteration
//! count doing their work (3 and 4 iterations: the last iteration's velocities in either
//! buffer); (c) coincident particles, particles with NaN and infinite positions and
//! velocities (left out of the pass), and fast ones, with a neighbour cap low enough to be
//! hit; (d) a count that is not a power of two split into several chunks, with the dispatch
//! folded into two dimensions.

use std::sync::OnceLock;

use octoproxy_core::{Backend, PairParams, PairReport, Particle, StepParams};
use octoproxy_cpu::{scenes, CpuBackend};
use octoproxy_tests::radius::{bake_for, RadiusScene};
use octoproxy_wgpu::WgpuError;

mod common;
use common::{gpu_backend as gpu, is_lavapipe};

const DT: f32 = 1.0 / 60.0;

/// A closed box (particles inside it), baked for radius `r`.
fn box_scene(min: [f32; 3], max: [f32; 3], dmax: u32, r: f32) -> RadiusScene {
    bake_for(&[scenes::cube(min, max)], dmax, r)
}

/// The tall box of the pairs and lone grains, for radius 0.15, baked once.
fn tall_box() -> &'static RadiusScene {
    static BAKED: OnceLock<RadiusScene> = OnceLock::new();
    BAKED.get_or_init(|| box_scene([-0.5, 0.0, -0.5], [0.5, 4.0, 0.5], 6, 0.15))
}

/// The box of the piles, for radius 0.05, baked once.
fn pile_box() -> &'static RadiusScene {
    static BAKED: OnceLock<RadiusScene> = OnceLock::new();
    BAKED.get_or_init(|| box_scene([-0.6, 0.0, -0.6], [0.6, 3.0, 0.6], 7, 0.05))
}

/// How the two runs compare: the particles whose 32 bytes differ, and the first of them.
fn differing(cpu: &[Particle], gpu: &[Particle]) -> (usize, Option<usize>) {
    let mut count = 0;
    let mut first = None;
    for (i, (c, g)) in cpu.iter().zip(gpu).enumerate() {
        if bytemuck::bytes_of(c) != bytemuck::bytes_of(g) {
            count += 1;
            first.get_or_insert(i);
        }
    }
    (count, first)
}

/// One scene run on both backends.
struct Run<'a> {
    name: &'a str,
    baked: &'a RadiusScene,
    particles: Vec<Particle>,
    params: StepParams,
    pairs: PairParams,
    /// Calls of `step_pairs`, each of `steps_per_call` steps; the particles are compared
    /// after every call.
    calls: u32,
    steps_per_call: u32,
    /// The GPU's chunk size and dispatch fold, when forced.
    chunk_particles: Option<u32>,
    fold_width: Option<u32>,
}

impl Run<'_> {
    /// Runs both backends and compares them; returns the CPU's report and particles.
    fn compare(self) -> Option<(PairReport, Vec<Particle>)> {
        let mut gpu = gpu()?;
        let exact = is_lavapipe(&gpu);
        let mut cpu = CpuBackend::new();
        if let Some(n) = self.chunk_particles {
            gpu.set_chunk_particles(n);
        }
        if let Some(w) = self.fold_width {
            gpu.set_fold_width(w);
        }
        for b in [&mut cpu as &mut dyn Stepper, &mut gpu] {
            b.load(&self.baked.words, &self.particles);
        }
        if let Some(n) = self.chunk_particles {
            assert!(
                gpu.chunk_count() > 1,
                "{}: {} particles in one chunk of {n}",
                self.name,
                self.particles.len()
            );
        }
        let n = self.particles.len();
        let (mut a, mut b) = (vec![Particle::default(); n], vec![Particle::default(); n]);
        let t = std::time::Instant::now();
        let (mut cpu_time, mut gpu_time) = (0.0, 0.0);
        for call in 0..self.calls {
            let t0 = std::time::Instant::now();
            cpu.step_pairs(&self.params, &self.pairs, self.steps_per_call)
                .unwrap();
            let t1 = std::time::Instant::now();
            gpu.step_pairs(&self.params, &self.pairs, self.steps_per_call)
                .unwrap();
            gpu.finish().unwrap();
            cpu_time += (t1 - t0).as_secs_f64();
            gpu_time += t1.elapsed().as_secs_f64();
            cpu.download_particles(&mut a).unwrap();
            gpu.download_particles(&mut b).unwrap();
            let (count, first) = differing(&a, &b);
            if let Some(i) = first {
                let step = (call + 1) * self.steps_per_call;
                eprintln!(
                    "{}: {count} of {n} particles differ after step {step}; the first, {i}:\n  cpu {:?}\n  gpu {:?}",
                    self.name, a[i], b[i]
                );
                assert!(!exact, "{}: the GPU must give the CPU's bits", self.name);
            }
        }
        let (cr, gr) = (
            cpu.take_pair_report().unwrap(),
            gpu.take_pair_report().unwrap(),
        );
        eprintln!(
            "{}: {n} particles, {} steps in {:.1?} (cpu {cpu_time:.2} s, gpu {gpu_time:.2} s); {cr:?}",
            self.name,
            self.calls * self.steps_per_call,
            t.elapsed()
        );
        if exact {
            assert_eq!(gr, cr, "{}: the reports differ", self.name);
        } else {
            assert_eq!(
                (gr.steps, gr.substeps),
                (cr.steps, cr.substeps),
                "{}",
                self.name
            );
        }
        // Taken: both start again from zero.
        assert_eq!(cpu.take_pair_report().unwrap(), PairReport::default());
        assert_eq!(gpu.take_pair_report().unwrap(), PairReport::default());
        Some((cr, a))
    }
}

/// What both backends do the same way before the pass: take a proxy and particles.
trait Stepper {
    fn load(&mut self, words: &[u32], particles: &[Particle]);
}

impl<B: Backend> Stepper for B {
    fn load(&mut self, words: &[u32], particles: &[Particle]) {
        self.upload_proxy(words).unwrap();
        self.upload_particles(particles).unwrap();
    }
}

/// A block of `n` particles on a grid of `gap` from `corner`, each a little off it, at rest or
/// with velocities of up to `speed` in each direction.
fn block(n: [usize; 3], corner: [f32; 3], gap: f32, speed: f32) -> Vec<Particle> {
    let mut rng = octoproxy_cpu::emit::Rng::new(7);
    let mut ps = Vec::new();
    for iy in 0..n[1] {
        for iz in 0..n[2] {
            for ix in 0..n[0] {
                let jitter = ((ix * 7 + iy * 13 + iz * 29) % 11) as f32 * 0.01 * gap;
                ps.push(Particle::new(
                    [
                        corner[0] + ix as f32 * gap + jitter,
                        corner[1] + iy as f32 * gap,
                        corner[2] + iz as f32 * gap - jitter,
                    ],
                    [
                        rng.range(-speed, speed),
                        rng.range(-speed, speed),
                        rng.range(-speed, speed),
                    ],
                ));
            }
        }
    }
    ps
}

#[test]
fn a_head_on_pair_on_both_backends() {
    let r = 0.15;
    let baked = tall_box();
    for (gravity, e, mu) in [
        ([0.0; 3], 1.0, 0.0),
        ([0.0; 3], 0.5, 0.3),
        ([0.0, -9.81, 0.0], 0.1, 0.5),
    ] {
        let mut ps = vec![
            Particle::new([-0.3, 2.0, 0.01], [1.5, 0.2, 0.0]),
            Particle::new([0.3, 2.0, -0.01], [-0.5, -0.1, 0.0]),
        ];
        baked.start(&mut ps);
        let name = format!("head-on, gravity {gravity:?}, e {e}, mu {mu}");
        let Some((report, out)) = (Run {
            name: &name,
            baked,
            particles: ps.clone(),
            params: StepParams {
                gravity,
                dt: DT,
                radius: r,
                ..StepParams::default()
            },
            pairs: PairParams {
                restitution: e,
                friction: mu,
                ..PairParams::default()
            },
            calls: 30,
            steps_per_call: 1,
            chunk_particles: None,
            fold_width: None,
        })
        .compare() else {
            return;
        };
        assert_eq!(report.steps, 30);
        // They met.
        assert!(out[0].velocity[0] < 1.0, "{name}: they never met");
    }
}

/// Substeps that follow the fastest grain (`PairParams::follow_speed`): grains shot at each
/// other at up to 60 m/s (the GPU reads the largest speed back each step), and two calls of
/// several steps each, on both backends.
#[test]
fn substeps_that_follow_the_fastest_grain_on_both_backends() {
    let r = 0.15;
    let baked = tall_box();
    let mut ps = Vec::new();
    for (k, v) in [4.0f32, 15.0, 35.0, 60.0].into_iter().enumerate() {
        let x = [
            -0.18 + 0.36 * (k % 2) as f32,
            0.0,
            -0.18 + 0.36 * (k / 2) as f32,
        ];
        ps.push(Particle::new([x[0], 0.5, x[2]], [0.0, v, 0.0]));
        ps.push(Particle::new([x[0], 3.5, x[2]], [0.0, -v, 0.0]));
    }
    baked.start(&mut ps);
    let Some((report, out)) = (Run {
        name: "following speed",
        baked,
        particles: ps,
        params: StepParams {
            gravity: [0.0; 3],
            dt: DT,
            radius: r,
            ..StepParams::default()
        },
        pairs: PairParams {
            follow_speed: true,
            ..PairParams::default()
        },
        calls: 6,
        steps_per_call: 3,
        chunk_particles: None,
        fold_width: None,
    })
    .compare() else {
        return;
    };
    // 60 m/s is 6.7 radii a step: 7 substeps while it flies.
    assert!(report.substeps >= 7 + 17, "{report:?}");
    assert_eq!(report.fast, 0, "{report:?}");
    for lane in out.chunks(2) {
        assert!(lane[0].position[1] < lane[1].position[1], "{lane:?}");
    }
}

#[test]
fn a_lone_grain_lands_and_rests_on_both_backends() {
    // One particle: a table of one, nothing to sort; once it lands it rests on its support.
    let r = 0.15;
    let baked = tall_box();
    let mut ps = vec![Particle::new([0.1, 1.0, -0.05], [0.4, 0.0, 0.3])];
    baked.start(&mut ps);
    let Some((_, out)) = (Run {
        name: "a lone grain",
        baked,
        particles: ps,
        params: StepParams {
            dt: DT,
            radius: r,
            ..StepParams::default()
        },
        pairs: PairParams::default(),
        calls: 4,
        steps_per_call: 15,
        chunk_particles: None,
        fold_width: None,
    })
    .compare() else {
        return;
    };
    assert!(out[0].position[1] < 1.5 * r, "{:?}", out[0]);
}

#[test]
fn a_pile_in_a_box_on_both_backends() {
    let r = 0.05;
    let baked = pile_box();
    let mut ps = block([10, 22, 10], [-0.495, 0.2, -0.495], 2.2 * r, 1.0);
    baked.start(&mut ps);
    assert_eq!(ps.len(), 2200);
    for (iterations, friction, restitution) in [(4, 0.5, 0.1), (3, 0.8, 0.3)] {
        let name = format!("a pile, {iterations} iterations, mu {friction}, e {restitution}");
        let Some((report, out)) = (Run {
            name: &name,
            baked,
            particles: ps.clone(),
            params: StepParams {
                dt: DT,
                radius: r,
                restitution: 0.1,
                friction: 0.5,
                ..StepParams::default()
            },
            pairs: PairParams {
                iterations,
                friction,
                restitution,
                ..PairParams::default()
            },
            calls: 8,
            steps_per_call: 12,
            chunk_particles: None,
            fold_width: None,
        })
        .compare() else {
            return;
        };
        assert!(report.substeps > report.steps, "{name}: {report:?}");
        // It piled up: the lowest layer rests on the floor, with others stacked on it.
        let low = out.iter().filter(|p| p.position[1] < 3.0 * r).count();
        let high = out.iter().filter(|p| p.position[1] > 8.0 * r).count();
        assert!(low > 50 && high > 50, "{name}: {low} low, {high} high");
    }
}

/// A column 28 grains deep stood on the box's floor: each step takes its iterations from how
/// deep its particles stand (`pair_iterations_for`: 3 here, over the fewest asked, 1), the
/// GPU's from its probe's count of columns; capped at 2, both count every step as deeper than
/// it props up, also where the fewest is the most (2 to 2, which once left the GPU's
/// count of columns out, and with it the report's deep steps).
#[test]
fn iterations_that_follow_the_depth_on_both_backends() {
    let r = 0.05;
    let baked = pile_box();
    let gap = 2.0 * r * 1.001;
    let mut ps = block([3, 28, 3], [-gap, r * 1.001, -gap], gap, 0.0);
    baked.start(&mut ps);
    for (iterations, max_iterations) in [(1, 64), (1, 2), (2, 2)] {
        let name = format!("a column 28 deep, {iterations} to {max_iterations} iterations");
        let Some((report, _)) = (Run {
            name: &name,
            baked,
            particles: ps.clone(),
            params: StepParams {
                dt: DT,
                radius: r,
                ..StepParams::default()
            },
            pairs: PairParams {
                iterations,
                max_iterations,
                ..PairParams::default()
            },
            calls: 4,
            steps_per_call: 3,
            chunk_particles: None,
            fold_width: None,
        })
        .compare() else {
            return;
        };
        let capped = max_iterations < 3;
        assert_eq!(
            report.iterations,
            report.substeps * if capped { 2 } else { 3 },
            "{name}: {report:?}"
        );
        assert_eq!(report.deep, if capped { 12 } else { 0 }, "{name}");
    }
}

#[test]
fn coincident_invalid_and_fast_particles_on_both_backends() {
    let r = 0.05;
    let baked = pile_box();
    let mut ps = block([6, 4, 6], [-0.3, 0.5, -0.3], 2.05 * r, 0.0);
    // Six on one point, and pairs on one point.
    for _ in 0..6 {
        ps.push(Particle::new([0.1, 1.5, 0.1], [0.0; 3]));
    }
    for k in 0..4 {
        let x = [-0.4 + 0.2 * k as f32, 2.0, 0.3];
        ps.push(Particle::new(x, [0.0, -1.0, 0.0]));
        ps.push(Particle::new(x, [0.5, 0.0, 0.0]));
    }
    // Fast: past a radius per substep; one so fast its speed overflows to infinity.
    ps.push(Particle::new([0.0, 2.5, 0.0], [0.0, -40.0, 0.0]));
    ps.push(Particle::new([0.2, 2.5, -0.2], [3e20, 0.0, 1e20]));
    baked.start(&mut ps);
    // Left out of the pass: positions and velocities that are not finite (the march flags
    // them), in among the others.
    let bad = [
        Particle::new([f32::NAN, 1.0, 0.0], [0.0; 3]),
        Particle::new([0.0, f32::INFINITY, 0.0], [0.0; 3]),
        Particle::new([0.1, 1.0, f32::NEG_INFINITY], [0.0; 3]),
        Particle::new([0.1, 0.6, 0.1], [f32::NAN, 0.0, 0.0]),
        Particle::new([0.1, 0.7, 0.1], [0.0, f32::INFINITY, 0.0]),
    ];
    for (k, p) in bad.into_iter().enumerate() {
        ps.insert(17 * k + 3, p);
    }
    let Some((report, _)) = (Run {
        name: "coincident, invalid and fast",
        baked,
        particles: ps,
        params: StepParams {
            dt: DT,
            radius: r,
            ..StepParams::default()
        },
        pairs: PairParams {
            max_candidates: 6,
            iterations: 5,
            ..PairParams::default()
        },
        calls: 15,
        steps_per_call: 2,
        chunk_particles: None,
        fold_width: None,
    })
    .compare() else {
        return;
    };
    assert!(report.capped > 0, "{report:?}");
    assert!(report.fast > 0, "{report:?}");
}

#[test]
fn many_chunks_and_a_folded_dispatch_on_both_backends() {
    let r = 0.05;
    let baked = pile_box();
    let mut ps = block([9, 13, 9], [-0.44, 0.2, -0.44], 2.2 * r, 0.5);
    baked.start(&mut ps);
    assert_eq!(ps.len(), 1053);
    let _ = (Run {
        name: "1053 particles in chunks of 256, rows of 3 workgroups",
        baked,
        particles: ps,
        params: StepParams {
            dt: DT,
            radius: r,
            ..StepParams::default()
        },
        pairs: PairParams::default(),
        calls: 2,
        steps_per_call: 30,
        chunk_particles: Some(256),
        fold_width: Some(3),
    })
    .compare();
}

#[test]
fn both_backends_refuse_the_same_parameters() {
    let Some(mut gpu) = gpu() else {
        return;
    };
    let r = 0.15;
    let baked = tall_box();
    let ps = [Particle::new([0.0, 1.0, 0.0], [0.0; 3])];
    let step = StepParams {
        radius: r,
        ..StepParams::default()
    };
    let pairs = PairParams::default();
    assert!(matches!(
        gpu.step_pairs(&step, &pairs, 1),
        Err(WgpuError::NoProxy)
    ));
    let mut cpu = CpuBackend::new();
    cpu.load(&baked.words, &ps);
    gpu.load(&baked.words, &ps);
    let no_radius = StepParams {
        radius: 0.0,
        ..step
    };
    let e = gpu.step_pairs(&no_radius, &pairs, 1).unwrap_err();
    assert!(matches!(e, WgpuError::Pairs(_)), "{e}");
    assert!(cpu.step_pairs(&no_radius, &pairs, 1).is_err());
    let other = StepParams {
        radius: 0.2,
        ..step
    };
    let e = gpu.step_pairs(&other, &pairs, 1).unwrap_err();
    assert!(matches!(e, WgpuError::Radius(_)), "{e}");
    let bad = PairParams {
        iterations: 0,
        ..pairs
    };
    let (g, c) = (
        gpu.step_pairs(&step, &bad, 1).unwrap_err(),
        cpu.step_pairs(&step, &bad, 1).unwrap_err(),
    );
    match (g, c) {
        (WgpuError::Pairs(g), octoproxy_cpu::CpuError::Pairs(c)) => assert_eq!(g, c),
        (g, c) => panic!("{g} / {c}"),
    }
    // Nothing was stepped, and no step was counted.
    assert_eq!(gpu.take_pair_report().unwrap(), PairReport::default());
    // No particles: the steps count, nothing runs.
    gpu.upload_particles(&[]).unwrap();
    cpu.upload_particles(&[]).unwrap();
    gpu.step_pairs(&step, &pairs, 3).unwrap();
    cpu.step_pairs(&step, &pairs, 3).unwrap();
    assert_eq!(
        gpu.take_pair_report().unwrap(),
        cpu.take_pair_report().unwrap()
    );
}

/// The pass in a scene (`Backend::step_scene_pairs`, through `Scene::step_pairs`): the pile's
/// box at twice its size, turned 10° about z, and a small cube sweeping through the pile and
/// turning, in several chunks. Particles, sides and hints, hit records, events (as sets) and
/// the reports are compared after every step: each substep's supports come from the static
/// box in its frame (`pair_support_scene`), and the march is the scene step over the substep.
#[test]
fn a_pile_in_a_scene_with_a_moving_paddle_on_both_backends() {
    use octoproxy_core::{HitEvent, Pose, SceneSides};
    use octoproxy_cpu::Scene;
    let Some(mut gpu) = gpu() else {
        return;
    };
    let exact = is_lavapipe(&gpu);
    gpu.set_chunk_particles(256);
    let r = 0.1;
    let tray = pile_box();
    let paddle = bake_for(&[scenes::cube([-0.15; 3], [0.15; 3])], 6, r);
    let turn = |degrees: f32, axis: [f32; 3]| {
        let (s, c) = (degrees.to_radians() * 0.5).sin_cos();
        [axis[0] * s, axis[1] * s, axis[2] * s, c]
    };
    let tray_pose = Pose {
        translation: [0.1, 0.0, -0.05],
        scale: 2.0,
        rotation: turn(10.0, [0.0, 0.0, 1.0]),
    };
    let paddle_at = |k: u32| Pose {
        translation: [-0.7 + 0.04 * k as f32, 0.5, 0.0],
        scale: 1.0,
        rotation: turn(6.0 * k as f32, [0.0, 1.0, 0.0]),
    };
    let mut scene = Scene::new();
    let a = scene.add_proxy(tray.words.clone()).unwrap();
    let b = scene.add_proxy(paddle.words.clone()).unwrap();
    scene.add_instance(a, tray_pose).unwrap();
    let moving = scene.add_instance(b, paddle_at(0)).unwrap();
    let mut scenes = [scene.clone(), scene];
    // Grains in the turned box, above the paddle's path.
    let ps: Vec<Particle> = block([8, 8, 8], [-0.8, 1.0, -0.8], 2.1 * r, 0.5)
        .into_iter()
        .map(|mut p| {
            let x = glam::Vec3::from_array(p.position);
            p.position = tray_pose.to_world(x / 2.0).to_array();
            p
        })
        .collect();
    let n = ps.len();
    let mut cpu = CpuBackend::new();
    let capacity = 1 << 14;
    for b in [&mut cpu as &mut dyn SceneStepper, &mut gpu] {
        b.start(&ps, capacity);
    }
    assert!(gpu.chunk_count() > 1);
    let params = StepParams {
        dt: DT,
        radius: r,
        restitution: 0.2,
        friction: 0.5,
        ..StepParams::default()
    };
    let pairs = PairParams {
        friction: 0.6,
        ..PairParams::default()
    };
    let none = HitEvent {
        step: 0,
        particle: 0,
        hit: octoproxy_core::Hit::NONE,
    };
    let (mut hits_seen, mut events_seen) = (0usize, 0usize);
    // The paddle stops after step 30: the last steps' substeps share one scene (the GPU
    // keeps the tables it wrote for the substep before).
    let steps = 35u32;
    let paddle_at = |k: u32| paddle_at(k.min(30));
    for k in 1..=steps {
        for s in &mut scenes {
            s.move_to(moving, paddle_at(k)).unwrap();
        }
        scenes[0]
            .step_pairs(&mut cpu, &params, &pairs, true)
            .unwrap();
        scenes[1]
            .step_pairs(&mut gpu, &params, &pairs, true)
            .unwrap();
        let mut out = [
            (
                vec![Particle::default(); n],
                vec![SceneSides::EMPTY; n],
                vec![octoproxy_core::Hit::NONE; n],
                vec![none; capacity],
            ),
            (
                vec![Particle::default(); n],
                vec![SceneSides::EMPTY; n],
                vec![octoproxy_core::Hit::NONE; n],
                vec![none; capacity],
            ),
        ];
        let mut counts = Vec::new();
        for (b, o) in [&mut cpu as &mut dyn SceneStepper, &mut gpu]
            .into_iter()
            .zip(&mut out)
        {
            counts.push(b.read(&mut o.0, &mut o.1, &mut o.2, &mut o.3));
        }
        let [(pa, sa, ha, ea), (pb, sb, hb, eb)] = &mut out;
        // Every grain in the box and out of the paddle, at the radius less a leaf (each
        // proxy's own, exactly: a box's distance is its faces').
        for p in pa
            .iter()
            .filter(|p| p.flags & octoproxy_core::scene::FLAG_CRUSHED == 0)
        {
            let x = glam::Vec3::from_array(p.position);
            let l = tray_pose.to_local(x);
            let m = 0.05 - 3f32.sqrt() * tray.leaf;
            assert!(
                l.x.abs() <= 0.6 - m && l.z.abs() <= 0.6 - m && l.y >= m && l.y <= 3.0 - m,
                "step {k}: a grain out of the box at {l} (local)"
            );
            let q = paddle_at(k).to_local(x);
            let m = r - 3f32.sqrt() * paddle.leaf;
            assert!(
                q.abs().max_element() >= 0.15 + m * 0.5,
                "step {k}: a grain in the paddle at {q} (local)"
            );
        }
        hits_seen += ha.iter().filter(|h| h.instance >= 0).count();
        events_seen += counts[0].stored;
        assert!(
            ha.iter()
                .all(|h| h.instance < 0 || (0.0..=1.0).contains(&h.t)),
            "a hit's t is a fraction of the whole step"
        );
        let (count, first) = differing(pa, pb);
        if let Some(i) = first {
            eprintln!(
                "scene pile: {count} of {n} particles differ after step {k}; the first, {i}:\n  cpu {:?}\n  gpu {:?}",
                pa[i], pb[i]
            );
            assert!(!exact, "the GPU must give the CPU's bits");
            continue;
        }
        if exact {
            assert!(sa == sb, "step {k}: the sides and hints differ");
            assert!(
                bytemuck::cast_slice::<_, u8>(ha) == bytemuck::cast_slice::<_, u8>(hb),
                "step {k}: the hit records differ"
            );
            assert_eq!(counts[0], counts[1], "step {k}: event counts");
            let key = |e: &HitEvent| {
                (
                    e.particle,
                    e.hit.t.to_bits(),
                    e.hit.position.map(f32::to_bits),
                )
            };
            let (ea, eb) = (&mut ea[..counts[0].stored], &mut eb[..counts[1].stored]);
            ea.sort_by_key(key);
            eb.sort_by_key(key);
            assert!(
                bytemuck::cast_slice::<_, u8>(ea) == bytemuck::cast_slice::<_, u8>(eb),
                "step {k}: the events differ"
            );
        }
    }
    let (cr, gr) = (
        cpu.take_pair_report().unwrap(),
        gpu.take_pair_report().unwrap(),
    );
    let (cs, gs) = (
        cpu.take_scene_report().unwrap(),
        gpu.take_scene_report().unwrap(),
    );
    eprintln!("scene pile: {n} grains, {steps} steps; {cr:?}; {cs:?}; {hits_seen} hit records, {events_seen} events");
    assert!(cr.substeps > cr.steps && cr.steps == steps as u64, "{cr:?}");
    assert!(hits_seen > 0 && events_seen > 0);
    if exact {
        assert_eq!(gr, cr);
        assert_eq!(gs, cs);
    } else {
        assert_eq!((gr.steps, gr.substeps), (cr.steps, cr.substeps));
    }
}

/// What both backends do the same way around a scene step.
trait SceneStepper {
    fn start(&mut self, particles: &[Particle], capacity: usize);
    fn read(
        &mut self,
        particles: &mut [Particle],
        sides: &mut [octoproxy_core::SceneSides],
        hits: &mut [octoproxy_core::Hit],
        events: &mut [octoproxy_core::HitEvent],
    ) -> octoproxy_core::EventCount;
}

impl<B: Backend> SceneStepper for B {
    fn start(&mut self, particles: &[Particle], capacity: usize) {
        self.upload_particles(particles).unwrap();
        self.set_event_capacity(capacity).unwrap();
    }

    fn read(
        &mut self,
        particles: &mut [Particle],
        sides: &mut [octoproxy_core::SceneSides],
        hits: &mut [octoproxy_core::Hit],
        events: &mut [octoproxy_core::HitEvent],
    ) -> octoproxy_core::EventCount {
        self.download_particles(particles).unwrap();
        self.download_scene_sides(sides).unwrap();
        self.download_hits(hits).unwrap();
        self.take_events(events).unwrap()
    }
}
