//! The benchmark baselines (issue 6): a triangle-list octree, parry3d's `TriMesh` and a
//! signed-distance grid. Each must rest a particle on a cube, ignore NaN input, report its
//! memory; the exact ones must stop a particle shot at a cube at the whole scene per step; the
//! grid must stay within its memory budget.

use octoproxy_core::{Particle, StepParams, FLAG_INVALID};
use octoproxy_cpu::scenes::{self, Mesh};
use octoproxy_tests::baselines::parry::ParryTriMesh;
use octoproxy_tests::baselines::sdf_grid::SdfGrid;
use octoproxy_tests::baselines::triangle_octree::TriangleOctree;
use octoproxy_tests::baselines::Method;

/// The unit cube `[0, 1]³` (closed, normals out).
fn cube() -> Mesh {
    scenes::cube([0.0; 3], [1.0; 3])
}

/// Every method on `mesh`, the grid at `sdf_budget` bytes.
fn methods(mesh: &Mesh, sdf_budget: usize, closed: bool) -> Vec<Box<dyn Method>> {
    vec![
        Box::new(TriangleOctree::new(&mesh.positions, &mesh.triangles, 8, 4)),
        Box::new(
            ParryTriMesh::new(&mesh.positions, &mesh.triangles).expect("parry accepts the mesh"),
        ),
        Box::new(SdfGrid::new(
            &mesh.positions,
            &mesh.triangles,
            sdf_budget,
            closed,
        )),
    ]
}

fn inside_cube(x: [f32; 3]) -> bool {
    x.iter().all(|&c| c > 0.0 && c < 1.0)
}

#[test]
fn particle_dropped_on_a_cube_rests_on_top() {
    let mesh = cube();
    let params = StepParams::default();
    let grid = SdfGrid::new(&mesh.positions, &mesh.triangles, 64 << 10, true);
    let cell = grid.cell_size();
    // (method, how far below the top it may end, how far above). A particle at rest hops
    // by about `e (g dt) dt` every step (1.4e-3 here); the grid may be off by a cell.
    let cases: Vec<(Box<dyn Method>, f32, f32)> = vec![
        (
            Box::new(TriangleOctree::new(&mesh.positions, &mesh.triangles, 8, 4)),
            0.0,
            0.01,
        ),
        (
            Box::new(
                ParryTriMesh::new(&mesh.positions, &mesh.triangles)
                    .expect("parry accepts the mesh"),
            ),
            0.0,
            0.01,
        ),
        (Box::new(grid), cell, cell),
    ];
    for (m, below, above) in cases {
        for start in [[0.5, 1.5, 0.5], [0.3, 1.2, 0.71], [0.9, 2.0, 0.1]] {
            let mut p = Particle::new(start, [0.0; 3]);
            for _ in 0..200 {
                m.step(&mut p, &params);
            }
            let [x, y, z] = p.position;
            assert!(p.collisions() > 0, "{}: never collided: {p:?}", m.name());
            assert_eq!(p.flags & FLAG_INVALID, 0, "{}", m.name());
            assert!(
                y >= 1.0 - below && y <= 1.0 + above,
                "{}: from {start:?} ended at {:?}",
                m.name(),
                p.position
            );
            assert!(
                (x - start[0]).abs() < 0.05 && (z - start[2]).abs() < 0.05,
                "{}: slid to {:?}",
                m.name(),
                p.position
            );
            // At rest: what is left of its speed is one step of gravity at most.
            let speed = glam::Vec3::from_array(p.velocity).length();
            assert!(
                speed <= 9.81 / 60.0 + 1e-3,
                "{}: still moving at {speed}",
                m.name()
            );
        }
    }
}

#[test]
fn fast_particles_do_not_end_inside_the_cube() {
    let mesh = cube();
    let params = StepParams {
        gravity: [0.0; 3],
        restitution: 0.5,
        ..StepParams::default()
    };
    let exact: Vec<Box<dyn Method>> = vec![
        Box::new(TriangleOctree::new(&mesh.positions, &mesh.triangles, 8, 4)),
        Box::new(
            ParryTriMesh::new(&mesh.positions, &mesh.triangles).expect("parry accepts the mesh"),
        ),
    ];
    // From every side, at the whole scene (and more) per step, off the faces' diagonals.
    let mut shots = Vec::new();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            for (u, w) in [(0.31, 0.47), (0.5, 0.22), (0.83, 0.61)] {
                for speed in [60.0f32, 150.0, 600.0] {
                    let mut x = [0.0; 3];
                    let mut v = [0.0; 3];
                    x[axis] = 0.5 + sign * 1.7;
                    x[(axis + 1) % 3] = u;
                    x[(axis + 2) % 3] = w;
                    v[axis] = -sign * speed;
                    // A little sideways, so the paths are not axis aligned.
                    v[(axis + 1) % 3] = 0.1 * speed * (w - 0.5);
                    shots.push((x, v));
                }
            }
        }
    }
    for m in &exact {
        for &(x, v) in &shots {
            let mut p = Particle::new(x, v);
            for step in 0..20 {
                m.step(&mut p, &params);
                assert!(
                    !inside_cube(p.position),
                    "{}: shot {x:?} at {v:?} is inside at step {step}: {p:?}",
                    m.name()
                );
            }
            assert!(
                p.collisions() >= 1,
                "{}: shot {x:?} at {v:?} never hit: {p:?}",
                m.name()
            );
        }
    }
}

#[test]
fn particle_inside_stays_inside_the_exact_methods() {
    // Both sides collide: a particle inside the cube bounces around in it.
    let mesh = cube();
    let params = StepParams {
        gravity: [0.0, -9.81, 0.0],
        restitution: 0.9,
        friction: 0.0,
        ..StepParams::default()
    };
    let exact: Vec<Box<dyn Method>> = vec![
        Box::new(TriangleOctree::new(&mesh.positions, &mesh.triangles, 8, 4)),
        Box::new(
            ParryTriMesh::new(&mesh.positions, &mesh.triangles).expect("parry accepts the mesh"),
        ),
    ];
    for m in &exact {
        let mut p = Particle::new([0.4, 0.6, 0.45], [37.0, 23.0, -41.0]);
        for step in 0..300 {
            m.step(&mut p, &params);
            assert!(
                inside_cube(p.position),
                "{}: left the cube at step {step}: {p:?}",
                m.name()
            );
        }
        assert!(p.collisions() > 10, "{}", m.name());
    }
}

#[test]
fn nan_and_infinite_input_is_flagged_and_unchanged() {
    let mesh = cube();
    let params = StepParams::default();
    for m in methods(&mesh, 16 << 10, true) {
        for (x, v) in [
            ([f32::NAN, 0.5, 0.5], [0.0; 3]),
            ([0.5, 2.0, 0.5], [0.0, f32::NAN, 0.0]),
            ([f32::INFINITY, 2.0, 0.5], [0.0; 3]),
            ([0.5, 2.0, 0.5], [0.0, f32::NEG_INFINITY, 0.0]),
        ] {
            let before = Particle::new(x, v);
            let mut p = before;
            m.step(&mut p, &params);
            assert_ne!(p.flags & FLAG_INVALID, 0, "{}: {p:?}", m.name());
            assert_eq!(
                p.position.map(f32::to_bits),
                before.position.map(f32::to_bits),
                "{}",
                m.name()
            );
            assert_eq!(
                p.velocity.map(f32::to_bits),
                before.velocity.map(f32::to_bits),
                "{}",
                m.name()
            );
        }
        // A finite particle whose integrated velocity overflows is flagged too.
        let mut p = Particle::new([0.5, 2.0, 0.5], [0.0, -f32::MAX, 0.0]);
        let before = p;
        m.step(
            &mut p,
            &StepParams {
                gravity: [0.0, -f32::MAX, 0.0],
                dt: 2.0,
                ..params
            },
        );
        assert_ne!(p.flags & FLAG_INVALID, 0, "{}: {p:?}", m.name());
        assert_eq!(
            (p.position, p.velocity),
            (before.position, before.velocity),
            "{}",
            m.name()
        );
    }
}

#[test]
fn memory_is_reported() {
    let mesh = scenes::uv_sphere([0.0; 3], 1.0, 32, 16);
    for m in methods(&mesh, 32 << 10, true) {
        let bytes = m.memory_bytes();
        assert!(bytes > 0, "{}", m.name());
        // Every method keeps at least the mesh or a grid; none is absurdly large here.
        assert!(bytes < 16 << 20, "{}: {bytes} bytes", m.name());
    }
}

#[test]
fn sdf_grid_respects_its_budget() {
    let sphere = scenes::uv_sphere([0.0; 3], 1.0, 32, 16);
    let sheet = scenes::flat_sheet([0.0; 3], 2.0, 8);
    for (mesh, closed) in [(&sphere, true), (&sheet, false)] {
        for budget in [4usize << 10, 64 << 10, 1 << 20] {
            let g = SdfGrid::new(&mesh.positions, &mesh.triangles, budget, closed);
            let bytes = g.memory_bytes();
            assert!(
                bytes <= budget && bytes as f64 >= 0.9 * budget as f64,
                "budget {budget}, got {bytes} ({:?})",
                g.dims()
            );
        }
    }
}

#[test]
fn sdf_grid_signs_and_shell() {
    // Closed: negative inside, positive outside; open: a shell about a cell thick.
    let sphere = scenes::uv_sphere([0.0; 3], 1.0, 32, 16);
    let g = SdfGrid::new(&sphere.positions, &sphere.triangles, 256 << 10, true);
    assert!(g.sample(glam::Vec3::ZERO).unwrap() < -0.9);
    assert!(g.sample(glam::Vec3::new(1.1, 0.0, 0.0)).unwrap() > 0.05);
    assert!(g.sample(glam::Vec3::new(10.0, 0.0, 0.0)).is_none());
    let sheet = scenes::flat_sheet([0.0; 3], 2.0, 8);
    let g = SdfGrid::new(&sheet.positions, &sheet.triangles, 256 << 10, false);
    let h = g.cell_size();
    let normal_axis = if sheet.positions.iter().all(|p| p[1] == 0.0) {
        1
    } else {
        2
    };
    let mut at = glam::Vec3::ZERO;
    assert!(g.sample(at).unwrap() < 0.0);
    at[normal_axis] = 1.5 * h;
    assert!(g.sample(at).unwrap() > 0.0);
}

#[test]
fn sdf_grid_matches_ground_truth() {
    // Signs (grouped winding numbers) and distances (exact near the surface, a chamfer
    // transform beyond) against exact ground truth at random points, on closed meshes whose
    // faces do and do not lie on grid samples.
    use octoproxy_cpu::ground_truth::GroundTruth;
    let meshes = [
        scenes::cube([0.0; 3], [1.0; 3]),
        scenes::torus([0.1, 0.2, 0.3], 1.0, 0.35, 48, 24),
        scenes::merge(&[
            scenes::cube([0.0; 3], [1.0; 3]),
            scenes::cube([1.3, 0.0, 0.0], [2.0, 0.5, 0.5]),
        ]),
    ];
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut r = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    };
    for mesh in &meshes {
        let gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
        for budget in [64usize << 10, 512 << 10] {
            let g = SdfGrid::new(&mesh.positions, &mesh.triangles, budget, true);
            let h = g.cell_size() as f64;
            let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for p in &mesh.positions {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            for _ in 0..2000 {
                let p: [f32; 3] =
                    std::array::from_fn(|k| lo[k] - 0.1 + (hi[k] - lo[k] + 0.2) * r());
                let Some(v) = g.sample(glam::Vec3::from_array(p)) else {
                    continue;
                };
                let exact = gt.distance(p);
                let signed = if gt.is_inside(p) { -exact } else { exact };
                if exact > 1.5 * h {
                    assert_eq!(
                        v < 0.0,
                        signed < 0.0,
                        "sign at {p:?}: grid {v}, exact {signed}"
                    );
                }
                // Trilinear interpolation is off by up to about a cell; the chamfer fill is
                // long by up to about 10 %, by less than 8 % on these meshes.
                assert!(
                    (f64::from(v) - signed).abs() <= h + 0.08 * exact,
                    "at {p:?}: grid {v}, exact {signed}, cell {h}"
                );
            }
        }
    }
}

#[test]
fn a_particle_falling_through_an_open_sheet_is_stopped_by_the_exact_methods() {
    // An open mesh: a flat sheet, hit from above and from below.
    let sheet = scenes::flat_sheet([0.0; 3], 2.0, 8);
    let normal_axis = if sheet.positions.iter().all(|p| p[1] == 0.0) {
        1
    } else {
        2
    };
    let params = StepParams {
        gravity: [0.0; 3],
        ..StepParams::default()
    };
    let exact: Vec<Box<dyn Method>> = vec![
        Box::new(TriangleOctree::new(
            &sheet.positions,
            &sheet.triangles,
            8,
            4,
        )),
        Box::new(
            ParryTriMesh::new(&sheet.positions, &sheet.triangles).expect("parry accepts the mesh"),
        ),
    ];
    for m in &exact {
        for sign in [-1.0f32, 1.0] {
            let mut x = [0.13, 0.27, 0.31];
            x[normal_axis] = sign * 0.5;
            let mut v = [3.0, -2.0, 1.0];
            v[normal_axis] = -sign * 200.0;
            let mut p = Particle::new(x, v);
            for _ in 0..10 {
                m.step(&mut p, &params);
                assert!(
                    p.position[normal_axis] * sign > 0.0,
                    "{}: crossed the sheet: {p:?}",
                    m.name()
                );
            }
            assert_eq!(p.collisions(), 1, "{}", m.name());
        }
    }
}

#[test]
fn degenerate_and_bad_triangles_are_left_out() {
    let mut mesh = cube();
    let n = mesh.positions.len() as u32;
    mesh.positions.push([f32::NAN, 0.0, 0.0]);
    mesh.triangles.push([0, 0, 1]); // repeated vertex
    mesh.triangles.push([0, 1, n + 5]); // index past the end
    mesh.triangles.push([0, 1, n]); // NaN vertex
    let oct = TriangleOctree::new(&mesh.positions, &mesh.triangles, 8, 4);
    assert_eq!(oct.dropped_triangles(), 3);
    let parry =
        ParryTriMesh::new(&mesh.positions, &mesh.triangles).expect("parry accepts the rest");
    assert_eq!(parry.dropped_triangles(), 3);
    let params = StepParams::default();
    for m in [&oct as &dyn Method, &parry] {
        let mut p = Particle::new([0.5, 1.2, 0.5], [0.0; 3]);
        for _ in 0..100 {
            m.step(&mut p, &params);
        }
        assert!(
            p.position[1] >= 1.0 && p.position[1] < 1.01,
            "{}: {p:?}",
            m.name()
        );
    }
    // Nothing usable at all: parry says so instead of panicking; the others build empty.
    assert!(ParryTriMesh::new(&[[0.0; 3]; 3], &[[0, 1, 2]]).is_err());
    assert!(ParryTriMesh::new(&[], &[]).is_err());
    let empty = TriangleOctree::new(&[], &[], 8, 4);
    let mut p = Particle::new([0.0; 3], [1.0, 0.0, 0.0]);
    empty.step(&mut p, &params);
    assert_eq!(p.collisions(), 0);
    let grid = SdfGrid::new(&[], &[], 4096, true);
    grid.step(&mut p, &params);
    assert!(grid.memory_bytes() <= 4096);
}

/// Not a check: build time, memory and ns per particle-step of each baseline (and octoproxy
/// for reference) on the bunny, 100k particles, 2 threads. Run with
/// `cargo test -p octoproxy-tests --test baselines -- --ignored --nocapture` (set
/// `BASELINE_ONLY=<name prefix>` to step only the methods whose name starts with it).
#[test]
#[ignore = "a measurement, not a check"]
fn measure_on_the_bunny() {
    use rayon::prelude::*;
    use std::time::Instant;
    let Some(mesh) = octoproxy_tests::meshes::load("stanford-bunny.obj.gz") else {
        return;
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    pool.install(|| {
        let (mut lo, mut hi) = (glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY));
        for p in &mesh.positions {
            lo = lo.min(glam::Vec3::from_array(*p));
            hi = hi.max(glam::Vec3::from_array(*p));
        }
        let size = (hi - lo).max_element();
        println!("bunny: {} triangles, box {lo} .. {hi}", mesh.triangles.len());
        let t = Instant::now();
        let mref = octoproxy_cpu::MeshRef { positions: &mesh.positions, triangles: &mesh.triangles };
        let (words, _) = octoproxy_cpu::bake(&[mref], &octoproxy_cpu::BuildParams::default(), &()).unwrap();
        let proxy_ms = t.elapsed().as_secs_f64() * 1e3;
        let proxy_bytes = words.len() * 4;
        let view = octoproxy_core::ProxyView::new(&words).unwrap();
        println!("octoproxy-cpu: build {proxy_ms:.0} ms, {proxy_bytes} bytes");

        let params = StepParams::default();
        // 100k particles in the box grown by a tenth, random directions, a leaf of a depth-8
        // tree per step (moderate).
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut r = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let speed = size / 256.0 / params.dt;
        let particles: Vec<Particle> = (0..100_000)
            .map(|_| {
                let x = lo - (hi - lo) * 0.1 + (hi - lo) * 1.2 * glam::Vec3::new(r(), r(), r());
                let d = glam::Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5).normalize_or(glam::Vec3::X);
                Particle::new(x.to_array(), (d * speed * (0.5 + r())).to_array())
            })
            .collect();
        let steps = 10;
        let only = std::env::var("BASELINE_ONLY").ok();
        let run = |name: &str, f: &(dyn Fn(&mut Particle) + Sync)| {
            if only.as_deref().is_some_and(|o| !name.starts_with(o)) {
                return;
            }
            let mut ps = particles.clone();
            ps.par_iter_mut().for_each(f); // warm up
            let t = Instant::now();
            for _ in 0..steps {
                ps.par_iter_mut().for_each(f);
            }
            let ns = t.elapsed().as_secs_f64() * 1e9 / (steps as f64 * ps.len() as f64 + steps as f64 * 0.0);
            let hits: u64 = ps.iter().map(|p| u64::from(p.collisions())).sum();
            println!("{name}: {ns:.1} ns per particle-step ({hits} collisions)");
        };
        run("octoproxy-cpu", &|p| {
            octoproxy_core::step_particle(&view, p, &params);
        });
        run("floor", &|p| {
            let v = glam::Vec3::from_array(p.velocity) + glam::Vec3::from_array(params.gravity) * params.dt;
            p.position = (glam::Vec3::from_array(p.position) + v * params.dt).to_array();
            p.velocity = v.to_array();
        });
        let t = Instant::now();
        let oct = TriangleOctree::new(&mesh.positions, &mesh.triangles, 8, 16);
        let oct_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let parry = ParryTriMesh::new(&mesh.positions, &mesh.triangles).unwrap();
        let parry_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let sdf = SdfGrid::new(&mesh.positions, &mesh.triangles, proxy_bytes, false);
        let sdf_ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "triangle-octree: build {oct_ms:.0} ms, {} bytes, {} nodes, depth {}",
            oct.memory_bytes(),
            oct.node_count(),
            oct.depth()
        );
        println!(
            "parry3d: build {parry_ms:.0} ms, {} bytes, dropped {}",
            parry.memory_bytes(),
            parry.dropped_triangles()
        );
        println!(
            "sdf-grid: build {sdf_ms:.0} ms, {} bytes, dims {:?}, cell {}",
            sdf.memory_bytes(),
            sdf.dims(),
            sdf.cell_size()
        );
        for m in [&oct as &dyn Method, &parry, &sdf] {
            run(m.name(), &|p| m.step(p, &params));
        }
        // The grid on a closed mesh: the winding number for every sample as well.
        if let Some(closed) = octoproxy_tests::meshes::load("nefertiti.obj.gz") {
            let t = Instant::now();
            let g = SdfGrid::new(&closed.positions, &closed.triangles, 1 << 20, true);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            println!(
                "sdf-grid on nefertiti ({} triangles, closed): build {ms:.0} ms, {} bytes, dims {:?}",
                closed.triangles.len(),
                g.memory_bytes(),
                g.dims()
            );
        }
    });
}

/// The bench follows a baseline's path piece by piece: the pieces a traced step reports join
/// end to end, from where the particle was to where it ends, and give the bits `step` gives.
#[test]
fn a_traced_step_reports_the_whole_path() {
    let mesh = cube();
    let params = StepParams::default();
    for m in methods(&mesh, 64 << 10, true) {
        let mut bounced = 0;
        for (start, v) in [
            ([0.5, 1.5, 0.5], [0.0, -30.0, 0.0]),
            ([0.3, 1.2, 0.71], [3.0, -20.0, 1.0]),
            ([-0.5, 0.5, 0.5], [90.0, 0.0, 0.0]),
            ([2.0, 2.0, 2.0], [1.0, 1.0, 1.0]),
        ] {
            let mut p = Particle::new(start, v);
            for _ in 0..30 {
                let mut q = p;
                let mut pieces = Vec::new();
                m.step_traced(&mut p, &params, &mut |a, b| pieces.push((a, b)));
                let from = q.position;
                m.step(&mut q, &params);
                assert_eq!(p.position, q.position, "{}: step_traced differs", m.name());
                assert_eq!(p.velocity, q.velocity, "{}: step_traced differs", m.name());
                bounced += (pieces.len() > 1) as u32;
                let mut at = glam::Vec3::from_array(from);
                for &(a, b) in &pieces {
                    assert_eq!(a, at, "{}: a piece starts away from the last", m.name());
                    at = b;
                }
                assert_eq!(
                    at.to_array(),
                    p.position,
                    "{}: the path ends elsewhere",
                    m.name()
                );
            }
        }
        assert!(bounced > 0, "{}: no step of several pieces", m.name());
    }
}
