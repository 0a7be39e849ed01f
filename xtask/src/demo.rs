//! `octoproxy demo`: particles raining onto an open dome and fired up into it from below,
//! colliding with both of its sides, while a paddle spins through the fountain beneath the
//! dome. Both are instances of one scene, stepped through `Scene::step` with hit records on;
//! prints a summary and writes a picture in which the particles the paddle hit show in their
//! own colour.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use glam::{Quat, Vec3};
use octoproxy_core::{
    Backend, Hit, Particle, Pose, ProxyView, SceneSides, SceneStepReport, StepParams, SIDE_BACK,
    SIDE_MASK,
};
use octoproxy_cpu::emit::{reserve_particles, Rng};
use octoproxy_cpu::io::Mesh;
use octoproxy_cpu::{
    bake, starting_scene_sides, starting_sides, BuildParams, MeshRef, Scene, Sides,
};

use crate::backends::{select_backend, BackendChoice, Stepper};
use crate::flags;
use crate::render::{Camera, Canvas, BACK, FRONT, HIT};
use crate::scene;

const HELP: &str = "\
usage: octoproxy demo [--sand [--mesh FILE]] [--particles N] [--steps N] [-o PICTURE.png] [--backend auto|cpu|wgpu]

Runs a built-in scene (no files needed): an open dome, and a paddle spinning beneath it, both
instances of one scene. Half the particles rain onto the dome and slide off its front side;
half are fired up from beneath and hit its back side, and the paddle bats some of them away on
their way up. The picture colours the particles the paddle hit.

With --sand: grains of a radius poured from a spout onto a plate with a block on it collide
with each other (the particle-particle pass) and pile up (default 3000 grains, 480 steps; the
picture goes to target/octoproxy-sand.png). With --mesh FILE (PLY, OBJ or STL, optionally
gzipped), onto that mesh in place of the block, scaled to 1.2 units and standing on the plate.";

/// The paddle: two blades (each long in x, tall in y, thin in z) either side of a gap at the
/// hub, so that the fountain's core rises past it; where it spins (about the vertical axis
/// through this point, between the fountain and the dome's rim), and how fast.
const BLADE_SIZE: [f32; 3] = [1.0, 0.16, 0.06];
const HUB_GAP: f32 = 0.3;
const PADDLE_AT: [f32; 3] = [0.0, -0.22, 0.0];
const PADDLE_TURN_DEG: f32 = 6.0;

/// The paddle's mesh, about its own origin: two closed blades.
fn paddle_mesh() -> Mesh {
    let x = HUB_GAP + 0.5 * BLADE_SIZE[0];
    octoproxy_cpu::scenes::merge(&[
        octoproxy_cpu::scenes::slab([x, 0.0, 0.0], BLADE_SIZE),
        octoproxy_cpu::scenes::slab([-x, 0.0, 0.0], BLADE_SIZE),
    ])
}

/// The paddle's pose at the end of step `step` (0: the start).
fn paddle_pose(step: u32) -> Pose {
    let turn = (PADDLE_TURN_DEG * step as f32).to_radians();
    Pose {
        translation: PADDLE_AT,
        scale: 1.0,
        rotation: Quat::from_rotation_y(0.3 + turn).normalize().to_array(),
    }
}

/// What the run keeps for the picture and the summary.
struct Run {
    particles: Vec<Particle>,
    /// Each particle's side of the dome: from its mesh at the start, then from the scene step.
    dome_side: Vec<u32>,
    /// Each particle's last collision in the last step.
    hits: Vec<Hit>,
    /// Particle-steps that ended with a collision, on the dome and on the paddle.
    dome_hits: u64,
    paddle_hits: u64,
    report: SceneStepReport,
    stepping: Duration,
}

/// What stays the same through the run.
struct Setup<'a> {
    scene: Scene,
    sides: Vec<SceneSides>,
    dome: u32,
    paddle: u32,
    steps: u32,
    params: StepParams,
    cam: &'a Camera,
}

/// The picture's folder, made as its save would make it, and whether the picture can be
/// written there: found before the run, not after it.
fn picture_writable(out: &Path) -> Result<()> {
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    flags::writable(out, "--out")
}

pub fn run(args: Vec<OsString>) -> Result<()> {
    let mut n = 20_000usize;
    let mut steps = 90u32;
    let mut out = PathBuf::from("target/octoproxy-demo.png");
    let mut backend = BackendChoice::Auto;
    let mut sand = false;
    let mut mesh: Option<PathBuf> = None;
    let (mut n_set, mut steps_set) = (None, None);
    let mut parser = lexopt::Parser::from_args(args);
    while let Some((name, unexpected)) = flags::next_option(&mut parser)? {
        match name.as_str() {
            "--particles" => n_set = Some(flags::number(&mut parser, "--particles")?),
            "--steps" => steps_set = Some(flags::number(&mut parser, "--steps")?),
            "--sand" => sand = true,
            "--mesh" => mesh = Some(flags::path(&mut parser, "--mesh")?),
            "-o" | "--out" => out = flags::path(&mut parser, "--out")?,
            "--backend" => {
                backend = BackendChoice::parse(&flags::string(&mut parser, "--backend")?)?
            }
            "-h" | "--help" => {
                println!("{HELP}");
                return Ok(());
            }
            _ => return Err(unexpected.into()),
        }
    }
    if n_set == Some(0) {
        anyhow::bail!("--particles must be at least 1");
    }
    if let Some(n) = n_set {
        flags::particles_fit("--particles", n)?;
    }
    if mesh.is_some() && !sand {
        anyhow::bail!("--mesh is for --sand (the built-in demo's scene is its own)");
    }
    if sand {
        let out = if out == Path::new("target/octoproxy-demo.png") {
            PathBuf::from("target/octoproxy-sand.png")
        } else {
            out
        };
        picture_writable(&out)?;
        return crate::sand::run(
            n_set.unwrap_or(3000),
            steps_set.unwrap_or(480),
            &out,
            backend,
            mesh.as_deref(),
        );
    }
    n = n_set.unwrap_or(n);
    steps = steps_set.unwrap_or(steps);
    picture_writable(&out)?;

    let build = BuildParams {
        dmax: 7,
        ..BuildParams::default()
    };
    let dome_mesh = octoproxy_cpu::scenes::hemisphere([0.0; 3], 1.0, 96, 24);
    let dome = scene::bake_meshes(vec![dome_mesh], &build, 0.0)?;
    let view = dome.view()?;
    let paddle_mesh = paddle_mesh();
    let t = Instant::now();
    let (paddle_words, _) =
        bake(&[MeshRef::from(&paddle_mesh)], &build, &()).context("baking the paddle")?;
    let bake_time = dome.bake_time.unwrap_or_default() + t.elapsed();
    let paddle_view = ProxyView::new(&paddle_words).context("validating the paddle's proxy")?;

    // Rain above the dome, and a fountain beneath it.
    let mut rng = Rng::new(1);
    let mut particles = reserve_particles(n).with_context(|| format!("--particles {n}"))?;
    particles.extend((0..n).map(|i| {
        if i % 2 == 0 {
            let p = Vec3::new(
                rng.range(-1.1, 1.1),
                rng.range(1.3, 2.4),
                rng.range(-1.1, 1.1),
            );
            Particle::new(p.to_array(), [0.0; 3])
        } else {
            let (r, th) = (
                0.55 * rng.f32().sqrt(),
                rng.range(0.0, std::f32::consts::TAU),
            );
            let p = Vec3::new(r * th.cos(), rng.range(-0.7, -0.35), r * th.sin());
            let v = Vec3::new(
                rng.range(-0.6, 0.6),
                rng.range(5.0, 6.0),
                rng.range(-0.6, 0.6),
            );
            Particle::new(p.to_array(), v.to_array())
        }
    }));
    // Each particle's side of the dome, from its mesh (the colour it starts with).
    let dome_refs: Vec<MeshRef<'_>> = dome.meshes.iter().map(MeshRef::from).collect();
    starting_sides(&dome_refs, &view, &mut particles);
    let dome_side: Vec<u32> = particles.iter().map(|p| p.side & SIDE_MASK).collect();

    // The scene: the dome still at the origin, the paddle spinning beneath it.
    let mut world = Scene::new();
    let dome_proxy = world.add_proxy(dome.words.clone())?;
    let paddle_proxy = world.add_proxy(paddle_words.clone())?;
    let dome_instance = world.add_instance(dome_proxy, Pose::IDENTITY)?;
    let paddle_instance = world.add_instance(paddle_proxy, paddle_pose(0))?;
    let mesh_sides = [
        Sides::new(&dome_refs),
        Sides::new(&[MeshRef::from(&paddle_mesh)]),
    ];
    let (sides, _) = starting_scene_sides(&world, &mesh_sides, &particles);

    let cam = Camera::new(Vec3::new(0.0, 0.35, 0.0), 1.75, 0.55, 0.42, 960, 720);
    let mut canvas = Canvas::new(960, 720);
    for t in &dome.meshes[0].triangles {
        let v = t.map(|i| Vec3::from_array(dome.meshes[0].positions[i as usize]));
        // Cut away the half nearer the camera, so both sides show.
        if cam.project((v[0] + v[1] + v[2]) / 3.0).z > 0.0 {
            continue;
        }
        canvas.triangle(&cam, v, [0.78, 0.79, 0.82]);
    }
    // The paddle where the run leaves it.
    let end = paddle_pose(steps);
    draw_mesh(&mut canvas, &cam, &paddle_mesh, &end, [0.36, 0.38, 0.44]);

    let setup = Setup {
        scene: world,
        sides,
        dome: dome_instance,
        paddle: paddle_instance,
        steps,
        params: StepParams::default(),
        cam: &cam,
    };
    let start = Run {
        particles,
        dome_side,
        hits: vec![Hit::NONE; n],
        dome_hits: 0,
        paddle_hits: 0,
        report: SceneStepReport::default(),
        stepping: Duration::ZERO,
    };
    let mut stepper = select_backend(backend)?;
    let backend_name = stepper.name();
    let run = match &mut stepper {
        Stepper::Cpu(b) => simulate(b, setup, start, &mut canvas)?,
        Stepper::Wgpu(b) => simulate(b.as_mut(), setup, start, &mut canvas)?,
    };

    for (p, (side, hit)) in run
        .particles
        .iter()
        .zip(run.dome_side.iter().zip(&run.hits))
    {
        let (c, r) = if hit.instance == paddle_instance as i32 {
            (HIT, 2.2)
        } else if *side == SIDE_BACK {
            (BACK, 1.4)
        } else {
            (FRONT, 1.4)
        };
        canvas.splat(&cam, Vec3::from_array(p.position), r, c, 0.9);
    }
    canvas.legend(&[
        (FRONT, "front side of the dome"),
        (BACK, "back side of the dome"),
        (HIT, "hit by the spinning paddle in that step"),
    ]);
    canvas.save_png(&out)?;

    let back = run.dome_side.iter().filter(|s| **s == SIDE_BACK).count();
    let collisions: u64 = run.particles.iter().map(|p| p.collisions() as u64).sum();
    let paddle_now = run
        .hits
        .iter()
        .filter(|h| h.instance == paddle_instance as i32)
        .count();
    println!("octoproxy demo: an open dome, particles on both of its sides, and a spinning paddle");
    println!(
        "  triangles:     {} (dome), {} (paddle)",
        dome.triangles,
        paddle_mesh.triangles.len()
    );
    println!(
        "  proxy:         dome {} (nodes {}, lookup table {}), paddle {}",
        scene::bytes((view.words().len() * 4) as u64),
        scene::bytes(view.node_bytes() as u64),
        scene::bytes(view.lut_bytes() as u64),
        scene::bytes((paddle_view.words().len() * 4) as u64)
    );
    println!("  bake time:     {:.1} ms", bake_time.as_secs_f64() * 1e3);
    println!("  instances:     2 (the dome, still; the paddle, turning {PADDLE_TURN_DEG}° a step)");
    println!(
        "  particles:     {n} ({} in front of the dome, {back} behind it at the end)",
        n - back
    );
    println!(
        "  steps:         {steps} × {:.4} s, {collisions} collisions",
        StepParams::default().dt
    );
    println!(
        "  hits:          {} particle-steps ended on the dome, {} on the paddle ({paddle_now} in the last step)",
        run.dome_hits, run.paddle_hits
    );
    println!(
        "  crushed:       {} (sides lost: {})",
        run.report.crushed, run.report.sides_lost
    );
    println!(
        "  ms per step:   {:.3}",
        run.stepping.as_secs_f64() * 1e3 / steps.max(1) as f64
    );
    println!("  backend:       {backend_name}");
    println!("  picture:       {}", out.display());
    Ok(())
}

/// Steps the scene on `backend`, posing the paddle before each step, with hit records on;
/// draws trails into `canvas` as it goes (every other step: the first particles by their side
/// of the dome, and every particle the paddle hit in that step).
fn simulate<B: Backend>(
    backend: &mut B,
    mut setup: Setup<'_>,
    mut run: Run,
    canvas: &mut Canvas,
) -> Result<Run> {
    let n = run.particles.len();
    backend.upload_particles(&run.particles)?;
    backend.upload_scene_sides(&setup.sides)?;
    let mut sides = vec![SceneSides::EMPTY; n];
    let trail = n.min(4000);
    let bar = crate::progress::bar(setup.steps as u64, "stepping");
    for s in 0..setup.steps {
        setup.scene.move_to(setup.paddle, paddle_pose(s + 1))?;
        let t = Instant::now();
        setup.scene.step(backend, &setup.params, true)?;
        backend.finish()?;
        run.stepping += t.elapsed();
        backend.download_hits(&mut run.hits)?;
        for h in &run.hits {
            if h.instance == setup.dome as i32 {
                run.dome_hits += 1;
            } else if h.instance == setup.paddle as i32 {
                run.paddle_hits += 1;
            }
        }
        if s % 2 == 0 || s + 1 == setup.steps {
            backend.download_particles(&mut run.particles)?;
            backend.download_scene_sides(&mut sides)?;
            for (k, s) in sides.iter().enumerate() {
                if let Some(side) = s.side_of(setup.dome) {
                    run.dome_side[k] = side & SIDE_MASK;
                }
            }
        }
        if s % 2 == 0 {
            for (k, p) in run.particles.iter().enumerate() {
                let at = Vec3::from_array(p.position);
                if run.hits[k].instance == setup.paddle as i32 {
                    canvas.splat(setup.cam, at, 1.6, HIT, 0.8);
                } else if k < trail {
                    let c = if run.dome_side[k] == SIDE_BACK {
                        BACK
                    } else {
                        FRONT
                    };
                    canvas.splat(setup.cam, at, 0.8, c, 0.12);
                }
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    run.report = backend.take_scene_report()?;
    Ok(run)
}

/// Draws `mesh` placed by `pose`, every triangle.
fn draw_mesh(canvas: &mut Canvas, cam: &Camera, mesh: &Mesh, pose: &Pose, color: [f32; 3]) {
    for t in &mesh.triangles {
        let v = t.map(|i| pose.to_world(Vec3::from_array(mesh.positions[i as usize])));
        canvas.triangle(cam, v, color);
    }
}
