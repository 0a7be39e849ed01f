//! Particles that collide with each other (`octoproxy_core::pairs`): a head-on pair keeps
//! momentum and energy, a column settles in a box, and poured sand comes to rest in piles
//! that stand, every centre at its radius from the mesh by exact ground truth.

use glam::Vec3;
use octoproxy_core::{Backend, PairParams, Particle, ProxyView, StepParams};
use octoproxy_cpu::{scenes, CpuBackend};
use octoproxy_tests::radius::{bake_for, RadiusScene};

/// Largest overlap between neighbours, as a fraction of the diameter (brute force).
fn max_overlap(ps: &[Particle], radius: f32) -> f32 {
    let mut worst = 0.0f32;
    for (i, a) in ps.iter().enumerate() {
        for b in &ps[i + 1..] {
            let d = (Vec3::from_array(a.position) - Vec3::from_array(b.position)).length();
            worst = worst.max((2.0 * radius - d) / (2.0 * radius));
        }
    }
    worst
}

/// The scene of the column and head-on tests: a closed box, particles inside it.
fn tall_box(r: f32) -> RadiusScene {
    bake_for(&[scenes::cube([-0.5, 0.0, -0.5], [0.5, 4.0, 0.5])], 6, r)
}

#[test]
fn a_column_settles_in_a_box() {
    let r = 0.15;
    let baked = tall_box(r);
    let mut ps: Vec<Particle> = (0..10)
        .map(|i| Particle::new([0.0, 0.2 + 0.32 * i as f32, 0.0], [0.0; 3]))
        .collect();
    assert_eq!(baked.start(&mut ps).stuck, 0);
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&baked.words).unwrap();
    cpu.upload_particles(&ps).unwrap();
    let step = StepParams {
        radius: r,
        ..StepParams::default()
    };
    let bound = (r - baked.leaf * 3f32.sqrt()) as f64;
    for _ in 0..300 {
        cpu.step_pairs(&step, &PairParams::default(), 1).unwrap();
        cpu.download_particles(&mut ps).unwrap();
        for p in &ps {
            assert!(
                baked.truth.distance(p.position) >= bound,
                "{p:?} too near a wall"
            );
            assert!(baked.truth.is_inside(p.position), "{p:?} left the box");
        }
    }
    let vmax = ps
        .iter()
        .map(|p| Vec3::from_array(p.velocity).length())
        .fold(0.0, f32::max);
    // At rest: what gravity adds in one substep, and no more.
    let h = step.dt / octoproxy_core::pair_substeps(&step, &PairParams::default()) as f32;
    assert!(vmax <= 9.81 * h, "the column still moves at {vmax}");
    let overlap = max_overlap(&ps, r);
    assert!(overlap < 0.01, "overlap {overlap} of the diameter");
    assert!(ps
        .windows(2)
        .all(|w| w[1].position[1] > w[0].position[1] + 1.9 * r));
    // Stacked on the floor, in order: the bottom one a radius above it.
    assert!((ps[0].position[1] - r).abs() < baked.leaf * 3f32.sqrt());
    assert_eq!(cpu.take_pair_report().unwrap().capped, 0);
}

/// A block `k` by `k` grains of radius `r` and `layers` deep, at rest on a simple lattice a
/// thousandth of a diameter apart, centred on the y axis, its lowest layer at `bottom`.
fn stack(k: usize, layers: usize, r: f32, bottom: f32) -> Vec<Particle> {
    let spacing = 2.0 * r * 1.001;
    let at = |i: usize| (i as f32 - (k - 1) as f32 / 2.0) * spacing;
    let mut ps = Vec::with_capacity(k * k * layers);
    for y in 0..layers {
        for z in 0..k {
            for x in 0..k {
                ps.push(Particle::new(
                    [at(x), bottom + y as f32 * spacing, at(z)],
                    [0.0; 3],
                ));
            }
        }
    }
    ps
}

/// A block 28 grains deep on a floor: what removes its overlaps must not stay as velocity
/// (each grain parting from the one below at its overlap's rate, the top taking the sum): no
/// grain is thrown up, and the block comes to rest. Without the hold on parting pairs the
/// fastest grain went up at 0.13 m/s here (0.8 m/s on a wider block), with it 0.04.
#[test]
fn a_deep_stack_does_not_throw_its_top() {
    let r = 0.025;
    let baked = bake_for(&[scenes::slab([0.0, -0.1, 0.0], [1.2, 0.2, 1.2])], 7, r);
    let (k, layers) = (20, 28);
    let mut ps = stack(k, layers, r, r * 1.2);
    assert_eq!(baked.start(&mut ps).stuck, 0);
    let top0 = ps.iter().map(|p| p.position[1]).fold(0.0, f32::max);
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&baked.words).unwrap();
    cpu.upload_particles(&ps).unwrap();
    let step = StepParams {
        radius: r,
        ..StepParams::default()
    };
    let mut fastest_up = 0.0f32;
    for _ in 0..60 {
        cpu.step_pairs(&step, &PairParams::default(), 1).unwrap();
        cpu.download_particles(&mut ps).unwrap();
        fastest_up = ps.iter().map(|p| p.velocity[1]).fold(fastest_up, f32::max);
    }
    let top = ps.iter().map(|p| p.position[1]).fold(0.0, f32::max);
    let vmax = ps
        .iter()
        .map(|p| Vec3::from_array(p.velocity).length())
        .fold(0.0, f32::max);
    eprintln!(
        "a stack of {layers} layers: fastest upward {fastest_up:.3} m/s, the top moved {:.3} R, at the end the fastest {vmax:.4} m/s",
        (top - top0) / r
    );
    assert!(
        fastest_up < 0.1,
        "a grain was thrown up at {fastest_up} m/s"
    );
    assert!(
        top < top0 + 0.5 * r,
        "the stack rose {} R",
        (top - top0) / r
    );
    assert!(vmax < 0.05, "the stack still moves at {vmax}");
}

/// A column 250 grains deep, stood on a floor at rest: a Jacobi iteration carries support one
/// contact further, so the layers the iterations of a substep do not reach fall until they
/// do, and their overlaps then throw them up. A step takes an iteration for every
/// `PAIR_LAYERS_PER_ITERATION` layers (21 here): the column stands, no grain faster than
/// the top's first two steps of free fall. Capped at the default fewest (8), the report
/// counts each step as deeper than its iterations prop up, and the top is thrown.
#[test]
fn a_column_250_grains_deep_stands() {
    let r = 0.01;
    let baked = bake_for(&[scenes::slab([0.0, -0.025, 0.0], [0.2, 0.05, 0.2])], 6, r);
    let (k, layers) = (3, 250);
    let mut ps = stack(k, layers, r, r * 1.001);
    assert_eq!(baked.start(&mut ps).stuck, 0);
    let top0 = ps.iter().map(|p| p.position[1]).fold(0.0, f32::max);
    let step = StepParams {
        radius: r,
        dt: 1.0 / 60.0,
        ..StepParams::default()
    };
    let run = |pairs: &PairParams, steps: u64| {
        let mut cpu = CpuBackend::new();
        cpu.upload_proxy(&baked.words).unwrap();
        cpu.upload_particles(&ps).unwrap();
        let mut out = ps.clone();
        let mut fastest = 0.0f32;
        for _ in 0..steps {
            cpu.step_pairs(&step, pairs, 1).unwrap();
            cpu.download_particles(&mut out).unwrap();
            fastest = out
                .iter()
                .map(|p| Vec3::from_array(p.velocity).length())
                .fold(fastest, f32::max);
        }
        let top = out.iter().map(|p| p.position[1]).fold(0.0, f32::max);
        let report = cpu.take_pair_report().unwrap();
        (fastest, top, report)
    };
    let (fastest, top, report) = run(&PairParams::default(), 30);
    let mean = report.iterations as f64 / report.substeps as f64;
    eprintln!(
        "{layers} layers: {mean} iterations a substep, fastest {fastest:.3} m/s, the top moved {:.2} mm",
        (top - top0) * 1e3
    );
    assert_eq!(mean, 21.0);
    assert_eq!(report.deep, 0);
    // Two steps of free fall: 2/60 s at 9.81 m/s².
    assert!(fastest < 0.35, "a grain moved at {fastest} m/s");
    assert!((top - top0).abs() < 0.01, "the top moved {} m", top - top0);

    let capped = PairParams {
        max_iterations: 8,
        ..PairParams::default()
    };
    let (fastest, top, report) = run(&capped, 8);
    eprintln!(
        "capped at 8: fastest {fastest:.3} m/s, the top moved {:.2} mm",
        (top - top0) * 1e3
    );
    assert_eq!(report.iterations, 8 * report.substeps);
    assert_eq!(report.deep, 8);
    assert!(
        fastest > 1.0,
        "capped, the fastest grain moved at {fastest} m/s only"
    );
}

/// The penetration harness with the pass on (`run_check_pairs`): grains thrown about a box
/// at up to the box's width per step, bumping into each other, every piece of every path
/// checked against exact ground truth (the offset surface's winding number, the mesh's
/// distance): none leaves the box or comes nearer a wall than R less a leaf diagonal.
#[test]
fn the_harness_with_the_pass_on_finds_no_penetration() {
    let r = 0.15;
    let baked = tall_box(r);
    let mut rng = octoproxy_cpu::emit::Rng::new(23);
    let mut ps: Vec<Particle> = (0..800)
        .map(|_| {
            let x = [
                rng.range(-0.3, 0.3),
                rng.range(0.2, 3.8),
                rng.range(-0.3, 0.3),
            ];
            let v = rng.unit_vector() * rng.range(0.0, 60.0);
            Particle::new(x, v.to_array())
        })
        .collect();
    assert_eq!(baked.start(&mut ps).stuck, 0);
    let step = StepParams {
        radius: r,
        ..StepParams::default()
    };
    let off = baked.surface.mesh();
    let off_gt = octoproxy_cpu::ground_truth::GroundTruth::new(&off.positions, &off.triangles);
    let view = ProxyView::new(&baked.words).unwrap();
    let clearance = (r - baked.leaf * 3f32.sqrt()) as f64;
    for pairs in [
        PairParams::default(),
        PairParams {
            restitution: 1.0,
            friction: 0.0,
            substeps: 1,
            ..PairParams::default()
        },
    ] {
        let mut run = ps.clone();
        let report = octoproxy_cpu::harness::run_check_pairs(
            &view,
            &off_gt,
            &mut run,
            60,
            &step,
            &pairs,
            &baked.truth,
            clearance,
        );
        eprintln!(
            "the harness with the pass ({pairs:?}): {} particle-steps, {} collisions, {} penetrations ({} too near)",
            report.particle_steps, report.collisions, report.penetrations, report.too_near
        );
        assert_eq!(report.penetrations, 0, "{:?}", report.examples);
        assert_eq!(report.non_finite, 0);
        assert!(report.collisions > 0);
        // The grains did meet: some ended closer than a diameter and a half.
        let close = run
            .iter()
            .enumerate()
            .filter(|(i, a)| {
                run[i + 1..].iter().any(|b| {
                    (Vec3::from_array(a.position) - Vec3::from_array(b.position)).length() < 3.0 * r
                })
            })
            .count();
        assert!(close > 0);
    }
}

#[test]
fn a_head_on_pair_keeps_momentum_and_energy() {
    let r = 0.15;
    let baked = tall_box(r);
    for (e, mu) in [(1.0, 0.0), (0.5, 0.3)] {
        let mut ps = vec![
            Particle::new([-0.3, 2.0, 0.01], [1.5, 0.2, 0.0]),
            Particle::new([0.3, 2.0, -0.01], [-0.5, -0.1, 0.0]),
        ];
        assert_eq!(baked.start(&mut ps).stuck, 0);
        let mut cpu = CpuBackend::new();
        cpu.upload_proxy(&baked.words).unwrap();
        cpu.upload_particles(&ps).unwrap();
        let step = StepParams {
            gravity: [0.0; 3],
            dt: 1.0 / 60.0,
            radius: r,
            ..StepParams::default()
        };
        let pairs = PairParams {
            restitution: e,
            friction: mu,
            ..PairParams::default()
        };
        let momentum =
            |ps: &[Particle]| Vec3::from_array(ps[0].velocity) + Vec3::from_array(ps[1].velocity);
        let energy = |ps: &[Particle]| {
            ps.iter()
                .map(|p| Vec3::from_array(p.velocity).length_squared())
                .sum::<f32>()
        };
        let (p0, e0) = (momentum(&ps), energy(&ps));
        let v0 = [
            Vec3::from_array(ps[0].velocity),
            Vec3::from_array(ps[1].velocity),
        ];
        let mut touched = None;
        for _ in 0..12 {
            let before = ps.clone();
            cpu.step_pairs(&step, &pairs, 1).unwrap();
            cpu.download_particles(&mut ps).unwrap();
            if touched.is_none() && ps[0].velocity != before[0].velocity {
                touched = Some(before);
            }
            let d = (Vec3::from_array(ps[0].position) - Vec3::from_array(ps[1].position)).length();
            assert!(d > 2.0 * r * 0.999, "they passed into each other: {d}");
        }
        let before = touched.expect("they never met");
        let p1 = momentum(&ps);
        assert!(
            (p1 - p0).length() <= 0.02 * p0.length().max(1e-3),
            "momentum {p0} -> {p1}"
        );
        // The normal at contact, and the velocities it gives.
        let n = (Vec3::from_array(before[0].position) - Vec3::from_array(before[1].position))
            .normalize();
        let vn = (v0[0] - v0[1]).dot(n);
        let want0 = v0[0] - n * ((1.0 + e) * vn * 0.5);
        let got0 = Vec3::from_array(ps[0].velocity);
        if e == 1.0 && mu == 0.0 {
            let e1 = energy(&ps);
            assert!((e1 - e0).abs() <= 0.02 * e0, "energy {e0} -> {e1}");
            assert!(
                (got0 - want0).length() <= 0.02 * v0[0].length(),
                "{got0} != {want0}"
            );
        } else {
            assert!(energy(&ps) < e0, "an inelastic contact must lose energy");
            // They part, at most as fast as restitution says (a contact found ahead of
            // time also gives up closing the gap it had left: docs/method.md).
            let vn1 = (got0 - Vec3::from_array(ps[1].velocity)).dot(n);
            assert!(
                vn1 > 0.0 && vn1 <= -e * vn * 1.02,
                "normal speed {vn} -> {vn1}"
            );
        }
    }
}

/// Grains shot at each other along nine lanes, at 5 to 150 m/s (up to 21 radii a step at dt
/// 1/60, without gravity, where gravity's substeps are 1): with substeps that follow the
/// fastest grain (`PairParams::follow_speed`, the default; `pair_substeps_for`) every pair
/// meets in the cells and none passes through the other. With gravity's substeps alone (one
/// here) the fast lanes' grains pass through each other, counted as fast: the check sees
/// what it checks.
#[test]
fn fast_grains_do_not_pass_through_each_other() {
    let r = 0.12;
    let baked = tall_box(r);
    let speeds = [5.0f32, 10.0, 20.0, 35.0, 50.0, 70.0, 90.0, 120.0, 150.0];
    let lane = |k: usize| [-0.3 + 0.3 * (k % 3) as f32, -0.3 + 0.3 * (k / 3) as f32];
    let mut start = Vec::new();
    for (k, &v) in speeds.iter().enumerate() {
        let [x, z] = lane(k);
        start.push(Particle::new([x, 0.4, z], [0.0, v, 0.0]));
        start.push(Particle::new([x, 3.6, z], [0.0, -v, 0.0]));
    }
    assert_eq!(baked.start(&mut start).stuck, 0);
    let step = StepParams {
        gravity: [0.0; 3],
        dt: 1.0 / 60.0,
        radius: r,
        ..StepParams::default()
    };
    // Lanes whose grains crossed (the lower one above the upper), or came within 99 % of a
    // diameter of each other at a step's end.
    let run = |pairs: &PairParams| {
        let mut cpu = CpuBackend::new();
        cpu.upload_proxy(&baked.words).unwrap();
        cpu.upload_particles(&start).unwrap();
        let mut ps = start.clone();
        let (mut crossed, mut near) = (vec![false; speeds.len()], 0);
        let (mut fast, mut most) = (0, 0);
        for _ in 0..30 {
            cpu.step_pairs(&step, pairs, 1).unwrap();
            let report = cpu.take_pair_report().unwrap();
            (fast, most) = (fast + report.fast, most.max(report.substeps));
            cpu.download_particles(&mut ps).unwrap();
            for (k, c) in crossed.iter_mut().enumerate() {
                let (a, b) = (ps[2 * k].position, ps[2 * k + 1].position);
                *c |= a[1] > b[1];
                let d = (Vec3::from_array(a) - Vec3::from_array(b)).length();
                near += (d < 2.0 * r * 0.99) as usize;
            }
        }
        (crossed, near, fast, most)
    };
    let (crossed, near, fast, most) = run(&PairParams::default());
    assert!(crossed.iter().all(|c| !c), "lanes crossed: {crossed:?}");
    assert_eq!(near, 0, "grains ended steps inside each other");
    assert_eq!(fast, 0, "particle-substeps faster than a radius");
    // The fastest lane set the substeps of a step while it flew: 150 m/s is 21 radii a step.
    assert!(most >= 21, "at most {most} substeps in a step");
    let (crossed, _, fast, most) = run(&PairParams {
        follow_speed: false,
        ..PairParams::default()
    });
    assert_eq!(most, 1, "gravity's count without gravity");
    assert!(
        crossed.iter().filter(|&&c| c).count() >= 3,
        "with one substep the fast lanes should cross: {crossed:?}"
    );
    assert!(fast > 0, "no particle-substep was fast");
}

/// What a pour found once it came to rest.
struct Rest {
    /// How far the pile's top came down in the last second.
    sank: f32,
    radius: f32,
    particles: usize,
    slow: usize,
    unsupported: usize,
    overlap: f32,
    /// The largest overlap between two grains at rest.
    overlap_resting: f32,
    /// The 99.9th percentile of each grain's largest overlap.
    overlap_999: f32,
    too_near: usize,
    inside: usize,
    impact: f32,
}

impl Rest {
    /// 98 % of the grains at rest, each supported, no two grains (those still moving
    /// included) overlapping by 10 % of the diameter, 99.9 % of the grains by less than 5 %,
    /// no centre too near the mesh or inside it, and the pile's top standing.
    fn check(&self, name: &str) {
        eprintln!(
            "{name}: {} particles, {} slower than 2 % of the impact speed {:.2}, {} unsupported, the largest overlap {:.3} of the diameter ({:.3} between grains at rest, 99.9 % under {:.3}), {} nearer the mesh than R less a leaf diagonal, {} inside it, the top sank {:.4} R in the last second",
            self.particles, self.slow, self.impact, self.unsupported, self.overlap, self.overlap_resting, self.overlap_999, self.too_near, self.inside, self.sank / self.radius
        );
        assert!(
            self.slow * 100 >= self.particles * 98,
            "{name}: not at rest"
        );
        assert_eq!(self.unsupported, 0, "{name}: particles resting on nothing");
        assert!(self.overlap < 0.1, "{name}: overlaps");
        assert!(self.overlap_999 < 0.05, "{name}: overlaps");
        assert_eq!(
            self.too_near + self.inside,
            0,
            "{name}: centres too near the mesh"
        );
        assert!(
            self.sank.abs() < 0.25 * self.radius,
            "{name}: the pile creeps"
        );
    }
}

/// Pours a body-centred block `nx·ny·nz` (every other layer one narrower) from `drop` above
/// `top` (the highest point of the scene under them) and steps `seconds` of simulated time at
/// `dt`.
fn pour(
    baked: &RadiusScene,
    n: [usize; 3],
    centre: [f32; 2],
    top: f32,
    drop: f32,
    dt: f32,
    seconds: f32,
) -> Rest {
    let r = baked.radius;
    let gap = 2.2 * r;
    let mut ps = Vec::new();
    // Body-centred layers: every other layer is one grain narrower and offset by half a
    // spacing, so each of its grains falls into the pocket of four below (a settled packing).
    // On a simple lattice each grain lands on one alone, rolls off it and the block erodes.
    for iy in 0..n[1] {
        let (shift, m) = if iy % 2 == 1 {
            (0.5 * gap, [n[0] - 1, n[2] - 1])
        } else {
            (0.0, [n[0], n[2]])
        };
        for iz in 0..m[1] {
            for ix in 0..m[0] {
                // Up to 0.1 R each way across.
                let jitter = |k: usize| ((k % 21) as f32 - 10.0) * 0.01 * r;
                ps.push(Particle::new(
                    [
                        centre[0]
                            + (ix as f32 - n[0] as f32 / 2.0) * gap
                            + shift
                            + jitter(ix * 7 + iy * 13 + iz * 29),
                        top + drop + r + iy as f32 * gap,
                        centre[1]
                            + (iz as f32 - n[2] as f32 / 2.0) * gap
                            + shift
                            + jitter(ix * 11 + iy * 5 + iz * 17),
                    ],
                    [0.0; 3],
                ));
            }
        }
    }
    assert_eq!(baked.start(&mut ps).stuck, 0);
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&baked.words).unwrap();
    cpu.upload_particles(&ps).unwrap();
    let step = StepParams {
        dt,
        radius: r,
        restitution: 0.1,
        friction: 0.5,
        ..StepParams::default()
    };
    let pairs = PairParams::default();
    let steps = (seconds / dt).round() as u32;
    let t0 = std::time::Instant::now();
    // The pile's height (its highest tenth of centres) a second before the end.
    let height = |ps: &[Particle]| {
        let mut ys: Vec<f32> = ps.iter().map(|p| p.position[1]).collect();
        ys.sort_by(f32::total_cmp);
        ys[ys.len() * 9 / 10]
    };
    let mut standing = 0.0;
    for s in 0..steps {
        cpu.step_pairs(&step, &pairs, 1).unwrap();
        if s + 1 == steps - (1.0 / dt).round() as u32 {
            cpu.download_particles(&mut ps).unwrap();
            standing = height(&ps);
        }
    }
    let report = cpu.take_pair_report().unwrap();
    eprintln!("  {steps} steps in {:.1?}; {report:?}", t0.elapsed());
    assert_eq!(report.capped, 0);
    cpu.download_particles(&mut ps).unwrap();
    let sank = standing - height(&ps);
    let impact = (2.0 * 9.81 * drop).sqrt();
    let slow_enough = |p: &Particle| Vec3::from_array(p.velocity).length() < 0.02 * impact;
    let slow = ps.iter().filter(|p| slow_enough(p)).count();
    // Neighbours within a diameter and a bit, by a grid of cells of the diameter.
    let cell = 2.0 * r;
    let mut grid: std::collections::HashMap<[i32; 3], Vec<usize>> = Default::default();
    let key = |x: [f32; 3]| x.map(|c| (c / cell).floor() as i32);
    for (i, p) in ps.iter().enumerate() {
        grid.entry(key(p.position)).or_default().push(i);
    }
    let mut overlap = 0.0f32;
    let mut overlap_resting = 0.0f32;
    let mut worst = Vec::with_capacity(ps.len());
    let mut unsupported = 0;
    let mut too_near = 0;
    let mut inside = 0;
    let bound = (r - baked.leaf * 3f32.sqrt()) as f64;
    for (i, p) in ps.iter().enumerate() {
        let x = Vec3::from_array(p.position);
        let k = key(p.position);
        let mut touching = false;
        let mut mine = 0.0f32;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                        continue;
                    };
                    for &j in list {
                        if j == i {
                            continue;
                        }
                        let d = (x - Vec3::from_array(ps[j].position)).length();
                        let o = (2.0 * r - d) / (2.0 * r);
                        mine = mine.max(o);
                        if slow_enough(p) && slow_enough(&ps[j]) {
                            overlap_resting = overlap_resting.max(o);
                        }
                        touching |= d <= 2.0 * r * 1.05;
                    }
                }
            }
        }
        overlap = overlap.max(mine);
        worst.push(mine);
        let dist = baked.truth.distance(p.position);
        if dist < bound {
            too_near += 1;
        }
        if baked.truth.is_inside(p.position) {
            inside += 1;
        }
        // A resting grain touches a neighbour or the scene.
        let resting = slow_enough(p);
        if resting && !touching && dist > (r + 2.0 * baked.leaf * 3f32.sqrt()) as f64 {
            unsupported += 1;
        }
    }
    worst.sort_by(f32::total_cmp);
    Rest {
        overlap_resting,
        overlap_999: worst[worst.len() * 999 / 1000],
        sank,
        radius: r,
        particles: ps.len(),
        slow,
        unsupported,
        overlap,
        too_near,
        inside,
        impact,
    }
}

/// A tray `w` wide with walls `h` high: a floor (its top at 0) and four walls, overlapping
/// at the corners. Sand comes to rest in it at its angle of repose; on a plate as wide, a
/// block of it spills over the edges.
fn tray(w: f32, h: f32) -> Vec<scenes::Mesh> {
    let t = 0.1;
    vec![
        scenes::slab([0.0, -0.1, 0.0], [w, 0.2, w]),
        scenes::slab([0.5 * (w - t), 0.5 * h, 0.0], [t, h, w]),
        scenes::slab([-0.5 * (w - t), 0.5 * h, 0.0], [t, h, w]),
        scenes::slab([0.0, 0.5 * h, 0.5 * (w - t)], [w, h, t]),
        scenes::slab([0.0, 0.5 * h, -0.5 * (w - t)], [w, h, t]),
    ]
}

#[test]
fn sand_poured_in_a_tray_comes_to_rest() {
    let r = 0.05;
    let t = std::time::Instant::now();
    let baked = bake_for(&tray(3.0, 0.8), 7, r);
    eprintln!("baked in {:.1?}", t.elapsed());
    for dt in [1.0 / 60.0, 0.004] {
        let rest = pour(&baked, [17, 17, 17], [0.0, 0.0], 0.0, 0.3, dt, 4.0);
        rest.check(&format!("a tray at dt {dt}"));
    }
}

/// The same pour ten times finer: 49,339 grains (a block 37 wide) of a radius 2.17 times
/// smaller, in the same tray baked at depth 8, at dt 1/60 and at 4 ms. No two grains overlap
/// by 10 % of the diameter (3.3 % and 3.5 %; 22 % at 4 ms before grains against a wall left
/// it the other grain's push, blocked grains found their support and wedged ones took none
/// of a push into it).
#[test]
fn fifty_thousand_grains_poured_in_a_tray_come_to_rest() {
    let r = 0.023;
    let t = std::time::Instant::now();
    let baked = bake_for(&tray(3.0, 0.8), 8, r);
    eprintln!("baked in {:.1?}", t.elapsed());
    for dt in [1.0 / 60.0, 0.004] {
        let rest = pour(&baked, [37, 37, 37], [0.0, 0.0], 0.0, 0.3, dt, 4.0);
        rest.check(&format!("50k grains in a tray at dt {dt}"));
    }
}

/// Spot, 1.2 long, standing in a tray 3 wide, baked for `radius` at `dmax`; and the cow's
/// highest point.
fn spot_in_a_tray(dmax: u32, radius: f32) -> Option<(RadiusScene, f32)> {
    let spot = octoproxy_tests::meshes::load("spot.obj.gz")?;
    let (cow, top) = scenes::standing(&spot, 1.2).expect("Spot has an extent");
    let mut parts = tray(3.0, 0.8);
    parts.insert(0, cow);
    Some((bake_for(&parts, dmax, radius), top))
}

/// Sand poured onto Spot standing in a tray keeps every centre at its radius from the mesh
/// and its neighbours, and the pile stands.
#[test]
fn sand_poured_on_a_shared_mesh_keeps_its_distance() {
    let Some((baked, top)) = spot_in_a_tray(7, 0.05) else {
        return;
    };
    let rest = pour(&baked, [13, 13, 13], [0.05, 0.0], top, 0.3, 1.0 / 60.0, 6.0);
    rest.check("Spot in a tray");
}

/// 50,449 grains (a block 52 × 19 × 52) poured onto Spot in a tray, at dt 1/60 and at 4 ms:
/// 98 % at rest after 4 s, every resting grain supported, no centre inside the mesh or
/// nearer it than R less a leaf diagonal (exact ground truth), 99.9 % of the grains
/// overlapping less than 2.2 % of the diameter and none 10 % (4.5 % and 3.7 %; 14 % at 1/60
/// once substeps followed speed, before grains the shell rule stopped were supported wherever
/// they lie in their leaf: `pair_support`). Before the
/// march went on after a shell block and wedged grains took no part of a push into their
/// support, two grains in a vertical corner of the tray, one on the other, both stopped by
/// the shell rule in every substep (the corner's surface leaves hold one averaged normal),
/// stayed 11 % into each other at 4 ms. A deeper block (37³) dumped from higher threw
/// grains over the walls before the debiasing iterations; beyond what the iterations reach in
/// a substep it still springs back.
#[test]
fn fifty_thousand_grains_poured_on_a_shared_mesh_come_to_rest() {
    let Some((baked, top)) = spot_in_a_tray(8, 0.023) else {
        return;
    };
    for dt in [1.0 / 60.0, 0.004] {
        let rest = pour(&baked, [52, 19, 52], [0.05, 0.0], top, 0.3, dt, 4.0);
        rest.check(&format!("50k grains on Spot at dt {dt}"));
    }
}

/// The CPU backend's parallel pass is core's one-thread pass (`collide_pairs`), the march
/// with the substep and no gravity, and core's debiasing iterations (`debias_pairs`), bit for
/// bit: with the default cap, and with a cap of 6 bucket entries, which most particles hit
/// part way through their 27 cells (the CPU lists each cell's neighbourhood once for all of
/// its particles; the serial pass visits it for each particle in every iteration).
#[test]
fn the_parallel_pass_is_cores_serial_pass() {
    assert_eq!(parallel_pass_against_serial(&PairParams::default()), (0, 0));
    let capped = PairParams {
        max_candidates: 6,
        ..PairParams::default()
    };
    let (serial, parallel) = parallel_pass_against_serial(&capped);
    assert!(serial > 1000, "{serial}");
    assert_eq!(serial, parallel);
}

/// 40 steps of 300 particles in a tall box by the CPU backend and by core's serial pass,
/// compared bit for bit after each; the particle-iterations each found capped.
fn parallel_pass_against_serial(pairs: &PairParams) -> (u64, u64) {
    let r = 0.15;
    let baked = tall_box(r);
    let mut ps: Vec<Particle> = (0..300)
        .map(|i| {
            let a = i as f32 * 2.399;
            Particle::new(
                [
                    0.3 * a.cos() * (i % 7) as f32 / 7.0,
                    0.3 + i as f32 * 0.011,
                    0.3 * a.sin() * (i % 5) as f32 / 5.0,
                ],
                [a.sin(), 0.0, a.cos()],
            )
        })
        .collect();
    ps.push(Particle::new([0.0, f32::NAN, 0.0], [0.0; 3]));
    assert_eq!(baked.start(&mut ps).stuck, 0);
    let step = StepParams {
        radius: r,
        ..StepParams::default()
    };
    let pairs = *pairs;
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&baked.words).unwrap();
    cpu.upload_particles(&ps).unwrap();
    let view = ProxyView::new(&baked.words).unwrap();
    let mut serial_caps = 0u64;
    let n = ps.len();
    let (mut keys, mut bodies) = (
        vec![[0u32; 2]; n],
        vec![octoproxy_core::PairBody::default(); n],
    );
    let (mut vel, mut vel_next) = (vec![[0f32; 4]; n], vec![[0f32; 4]; n]);
    let mut start = vec![[0f32; 4]; n];
    let mut ranges = vec![[0u32; 2]; octoproxy_core::pairs::pair_table_size(n)];
    let mut support = vec![[0f32; 4]; n];
    let mut hints = vec![octoproxy_core::LeafHint::NONE; n];
    let mut got = ps.clone();
    // The caller's scratch, lent to the pass and then to its debiasing iterations.
    macro_rules! scratch {
        () => {
            octoproxy_core::PairScratch {
                keys: &mut keys,
                bodies: &mut bodies,
                start: &mut start,
                vel: &mut vel,
                vel_next: &mut vel_next,
                support: &mut support,
                ranges: &mut ranges,
            }
        };
    }
    for _ in 0..40 {
        cpu.step_pairs(&step, &pairs, 1).unwrap();
        // The step's substeps from its particles' largest speed and its iterations from
        // their depth, as the backend chooses them.
        let mut columns = vec![[0u32; 2]; octoproxy_core::pairs::pair_column_table_size(n)];
        let probe = octoproxy_core::PairProbe::of_all(&ps, &step, &mut columns).unwrap();
        let substeps = octoproxy_core::pair_substeps_for(&step, &pairs, probe.speed);
        let (iterations, _) = octoproxy_core::pair_iterations_for(&step, &pairs, &probe);
        let h = step.dt / substeps as f32;
        let march = StepParams {
            gravity: [0.0; 3],
            dt: h,
            ..step
        };
        for _ in 0..substeps {
            let s0 = octoproxy_core::PairStep::new(&step, &pairs, h, n, 0.0);
            let v_max = octoproxy_core::pairs::pair_max_speed(&ps, &s0);
            let s = octoproxy_core::PairStep::new(&step, &pairs, h, n, v_max);
            serial_caps +=
                octoproxy_core::collide_pairs(&mut ps, &view, &hints, &s, iterations, scratch!())
                    .unwrap();
            for (p, hint) in ps.iter_mut().zip(&mut hints) {
                octoproxy_core::step_particle_hinted(&view, p, &march, hint);
            }
            serial_caps +=
                octoproxy_core::debias_pairs(&mut ps, &s, iterations, scratch!()).unwrap();
        }
        cpu.download_particles(&mut got).unwrap();
        for (a, b) in got.iter().zip(&ps) {
            assert_eq!(
                bytemuck::bytes_of(a),
                bytemuck::bytes_of(b),
                "{a:?} != {b:?}"
            );
        }
    }
    (serial_caps, cpu.take_pair_report().unwrap().capped)
}

#[test]
fn the_pass_refuses_what_it_cannot_do() {
    let baked = tall_box(0.15);
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&baked.words).unwrap();
    cpu.upload_particles(&[Particle::new([0.0, 1.0, 0.0], [0.0; 3])])
        .unwrap();
    let pairs = PairParams::default();
    let e = cpu
        .step_pairs(&StepParams::default(), &pairs, 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("radius greater than 0"), "{e}");
    let other = StepParams {
        radius: 0.2,
        ..StepParams::default()
    };
    let e = cpu.step_pairs(&other, &pairs, 1).unwrap_err().to_string();
    assert!(e.contains("0.15") && e.contains("0.2"), "{e}");
    let step = StepParams {
        radius: 0.15,
        ..StepParams::default()
    };
    let bad = PairParams {
        friction: f32::NAN,
        ..pairs
    };
    let e = cpu.step_pairs(&step, &bad, 1).unwrap_err().to_string();
    assert!(e.contains("particle friction"), "{e}");
}

/// Sand poured from a point onto a plate, and the pile it makes: the profile (the highest
/// centre in rings of one diameter around the spout's axis), the flank's angle (the profile
/// fitted by a line between a fifth and four fifths of the pile's radius), the top and the
/// base's radius (97 % of the grains within it).
struct PouredPile {
    flank: f32,
    top: f32,
    base: f32,
    profile: Vec<f32>,
}

fn pour_from_a_point(friction: f32, grains: usize) -> PouredPile {
    let r = 0.05;
    let plate = scenes::slab([0.0, -0.1, 0.0], [3.0, 0.2, 3.0]);
    let baked = bake_for(&[plate], 7, r);
    let step = StepParams {
        radius: r,
        restitution: 0.1,
        friction,
        ..StepParams::default()
    };
    let pairs = PairParams {
        restitution: 0.1,
        friction,
        ..PairParams::default()
    };
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&baked.words).unwrap();
    // One grain at a time, as soon as the last has left the spout, falling at 3 m/s.
    let spout = Vec3::new(0.0, 1.2, 0.0);
    let mut ps: Vec<Particle> = Vec::new();
    let mut side = None;
    let mut k = 0u32;
    for s in 0.. {
        let free = ps
            .iter()
            .all(|p| (Vec3::from_array(p.position) - spout).length() > 2.2 * r);
        if ps.len() < grains && free {
            k += 1;
            let (a, j) = (k as f32 * 2.399, 0.2 * r * (k % 7) as f32 / 7.0);
            let mut grain = Particle::new(
                [spout.x + j * a.cos(), spout.y, spout.z + j * a.sin()],
                [0.0, -3.0, 0.0],
            );
            // Every grain leaves the spout on the side of the first (outside the plate).
            grain.flags = *side.get_or_insert_with(|| {
                let mut first = vec![grain];
                assert_eq!(baked.start(&mut first).stuck, 0);
                first[0].flags
            });
            ps.push(grain);
            cpu.upload_particles(&ps).unwrap();
        }
        cpu.step_pairs(&step, &pairs, 1).unwrap();
        cpu.download_particles(&mut ps).unwrap();
        let still = ps
            .iter()
            .all(|p| Vec3::from_array(p.velocity).length() < 0.05);
        if ps.len() == grains && s % 60 == 0 && still {
            break;
        }
        assert!(s < 20 * grains, "the pour did not come to rest");
    }
    let radial = |p: &Particle| (p.position[0].powi(2) + p.position[2].powi(2)).sqrt();
    let mut rs: Vec<f32> = ps.iter().map(radial).collect();
    rs.sort_by(f32::total_cmp);
    let base = rs[rs.len() * 97 / 100];
    let top = ps.iter().map(|p| p.position[1]).fold(0.0, f32::max) + r;
    let bins = (base / (2.0 * r)).ceil() as usize + 1;
    let mut profile = vec![0.0f32; bins];
    for p in &ps {
        let b = ((radial(p) / (2.0 * r)) as usize).min(bins - 1);
        profile[b] = profile[b].max(p.position[1] + r);
    }
    let (mut sx, mut sy, mut sxx, mut sxy, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (b, &h) in profile.iter().enumerate() {
        let x = (b as f32 + 0.5) * 2.0 * r;
        if (0.2 * base..=0.8 * base).contains(&x) {
            (sx, sy, sxx, sxy, n) = (sx + x, sy + h, sxx + x * x, sxy + x * h, n + 1.0);
        }
    }
    let slope = -(n * sxy - sx * sy) / (n * sxx - sx * sx);
    PouredPile {
        flank: slope.atan().to_degrees(),
        top,
        base,
        profile,
    }
}

/// 1,000 grains poured one at a time from a point 1.2 m above a plate, at the demo's
/// friction (0.6): they make a cone whose flank stands at 25-45 degrees (dry sand's angle of
/// repose is 30-35). Before grains on a single grain were let roll off it, each grain stuck
/// where it landed on the one before: a tower rose to the spout within 50 grains.
#[test]
fn poured_sand_stands_at_its_angle_of_repose() {
    let t = std::time::Instant::now();
    let pile = pour_from_a_point(0.6, 1000);
    let cone = (pile.top / pile.base).atan().to_degrees();
    eprintln!(
        "flank {:.1}°, top {:.2} m, base radius {:.2} m (a cone of {cone:.1}°), in {:.1?}; profile {:?}",
        pile.flank, pile.top, pile.base, t.elapsed(), pile.profile
    );
    assert!(
        (25.0..=45.0).contains(&pile.flank),
        "flank at {:.1}°",
        pile.flank
    );
    assert!((25.0..=45.0).contains(&cone), "a cone of {cone:.1}°");
    // The profile falls from the top to the edge: a cone, not a column beside a flat layer.
    assert!(
        pile.profile.windows(3).all(|w| w[2] <= w[0] + 0.01),
        "{:?}",
        pile.profile
    );
}
