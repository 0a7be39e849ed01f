//! `octoproxy demo --sand`: sand poured from a spout onto a plate with a block standing on it
//! (or a mesh of the user's, `--mesh FILE`) forms a pile: particles of a radius that collide
//! with each other (the particle–particle pass) and with a proxy baked for their radius.
//! Writes a picture coloured by height.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use glam::Vec3;
use octoproxy_core::{pair_substeps, PairParams, Particle, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::scenes;
use octoproxy_cpu::BuildParams;

use crate::backends::{select_backend, BackendChoice};
use crate::render::{Camera, Canvas};
use crate::scene;

/// The grains' radius, and the spout: its centre, its radius, the speed grains leave it at,
/// and the steps between two layers of grains (so that a layer has moved on by a diameter).
const RADIUS: f32 = 0.05;
const SPOUT: [f32; 3] = [0.2, 1.1, 0.0];
/// A user's mesh is scaled to this size in its largest extent, and the spout stands this high
/// above its top.
const MESH_SIZE: f32 = 1.2;
const SPOUT_ABOVE: f32 = 0.4;
const SPOUT_RADIUS: f32 = 0.3;
const SPOUT_SPEED: f32 = 2.0;
/// The largest sideways speed a grain leaves the spout with, in each horizontal axis.
const SPOUT_SPREAD: f32 = 0.15;
const LAYER_STEPS: u32 = 4;

/// The sand's colours, low to high.
const SAND_LOW: [f32; 3] = [0.55, 0.38, 0.18];
const SAND_HIGH: [f32; 3] = [0.98, 0.84, 0.52];

/// Runs the sand demo: `n` grains poured, `steps` steps in all, the picture to `out`; onto
/// `mesh` (a file) standing on the plate, or the built-in block.
pub fn run(
    n: usize,
    steps: u32,
    out: &Path,
    backend: BackendChoice,
    mesh: Option<&Path>,
) -> Result<()> {
    let plate = scenes::slab([0.0, -0.1, 0.0], [3.0, 0.2, 3.0]);
    let (block, spout) = match mesh {
        Some(path) => {
            let loaded = scene::load_meshes(&[path.to_path_buf()])?;
            let mesh = loaded.into_iter().next().unwrap_or_default();
            let Some((standing, top)) = scenes::standing(&mesh, MESH_SIZE) else {
                bail!("{}: the mesh has no extent to scale", path.display());
            };
            (standing, [0.05, top + SPOUT_ABOVE, 0.0])
        }
        None => (scenes::slab([-0.35, 0.2, 0.0], [0.4, 0.4, 0.4]), SPOUT),
    };
    let build = BuildParams {
        dmax: 7,
        ..BuildParams::default()
    };
    let baked = scene::bake_meshes(vec![plate, block], &build, RADIUS)?;
    let offset = baked
        .offset
        .as_ref()
        .expect("a bake for a radius keeps its offset surface");
    let params = StepParams {
        radius: RADIUS,
        restitution: 0.1,
        friction: 0.6,
        ..StepParams::default()
    };
    let pairs = PairParams {
        restitution: params.restitution,
        friction: params.friction,
        ..PairParams::default()
    };
    // One layer of the spout: grains on a square lattice of 2.2 radii in its disc, jittered,
    // each leaving with a little sideways speed, so that grains do not land dead centre on the
    // grain below (friction holds a grain only in a pocket, not on a single grain: it rolls
    // off; docs/method.md).
    let spacing = 2.2 * RADIUS;
    let cells = (SPOUT_RADIUS / spacing) as i32;
    let mut stepper = select_backend(backend)?;
    stepper.upload_proxy(&baked.words)?;
    let mut rng = Rng::new(7);
    let mut grains: Vec<Particle> = Vec::new();
    let mut stepping = Duration::ZERO;
    let mut blocked = 0usize;
    let bar = crate::progress::bar(steps as u64, "pouring sand");
    for step in 0..steps {
        if grains.len() < n && step % LAYER_STEPS == 0 {
            if !grains.is_empty() {
                stepper.download_particles(&mut grains)?;
            }
            // A grain is poured only where no grain lies within a diameter: once the pile
            // reaches the spout, a grain made inside it would be thrown out of the overlap.
            let near: Vec<Vec3> = grains
                .iter()
                .map(|g| Vec3::from_array(g.position))
                .filter(|g| (g.y - spout[1]).abs() < 2.0 * RADIUS)
                .collect();
            let mut layer: Vec<Particle> = Vec::new();
            for i in -cells..=cells {
                for k in -cells..=cells {
                    let d = Vec3::new(i as f32, 0.0, k as f32) * spacing;
                    if d.length() > SPOUT_RADIUS || grains.len() + layer.len() >= n {
                        continue;
                    }
                    let jitter = Vec3::new(rng.range(-0.1, 0.1), 0.0, rng.range(-0.1, 0.1));
                    let p = Vec3::from_array(spout) + d + jitter * RADIUS;
                    if near.iter().any(|g| g.distance(p) < 2.0 * RADIUS) {
                        blocked += 1;
                        continue;
                    }
                    let (vx, vz) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
                    let v = Vec3::new(vx * SPOUT_SPREAD, -SPOUT_SPEED, vz * SPOUT_SPREAD);
                    layer.push(Particle::new(p.to_array(), v.to_array()));
                }
            }
            offset.assign_sides(&mut layer, false);
            grains.extend(layer);
            stepper.upload_particles(&grains)?;
        }
        let t = Instant::now();
        stepper.step_pairs(&params, &pairs, 1)?;
        stepper.finish()?;
        stepping += t.elapsed();
        bar.inc(1);
    }
    bar.finish_and_clear();
    // One read-back of the counts for the whole run (they add up across uploads).
    let report = stepper.take_pair_report()?;
    let (capped, fast) = (report.capped, report.fast);
    let substeps = report.substeps as f64 / report.steps.max(1) as f64;
    let iterations = report.iterations as f64 / report.substeps.max(1) as f64;
    stepper.download_particles(&mut grains)?;

    // The picture: the plate and the block, the grains coloured by height.
    // A user's mesh stands taller than the block: a wider view, and its own colour.
    let (look_at, frame) = if mesh.is_some() {
        (0.45, 1.6)
    } else {
        (0.35, 1.25)
    };
    let cam = Camera::new(Vec3::new(0.0, look_at, 0.0), frame, 0.6, 0.35, 960, 720);
    let mut canvas = Canvas::new(960, 720);
    for (k, part) in baked.meshes.iter().enumerate() {
        let colour = if k > 0 && mesh.is_some() {
            [0.55, 0.62, 0.78]
        } else {
            [0.62, 0.64, 0.68]
        };
        for t in &part.triangles {
            let v = t.map(|i| Vec3::from_array(part.positions[i as usize]));
            canvas.triangle(&cam, v, colour);
        }
    }
    let top = grains
        .iter()
        .map(|p| p.position[1])
        .fold(0.0f32, f32::max)
        .max(1e-3);
    let px = RADIUS * 0.5 * 720.0 / frame;
    for p in &grains {
        let h = (p.position[1] / top).clamp(0.0, 1.0);
        let c = [0, 1, 2].map(|k| SAND_LOW[k] + (SAND_HIGH[k] - SAND_LOW[k]) * h);
        canvas.splat(&cam, Vec3::from_array(p.position), px, c, 1.0);
    }
    canvas.legend(&[(SAND_LOW, "sand, low"), (SAND_HIGH, "sand, high")]);
    canvas.save_png(out)?;

    // How it ended: at rest, on what, overlapping how much.
    let speeds: Vec<f32> = grains
        .iter()
        .map(|p| Vec3::from_array(p.velocity).length())
        .collect();
    let slow = speeds.iter().filter(|&&s| s < 0.05).count();
    let on_plate = grains
        .iter()
        .filter(|p| p.position[1] > -0.2 && p.position[0].abs() < 1.5 && p.position[2].abs() < 1.5)
        .count();
    match mesh {
        Some(path) => println!(
            "octoproxy demo --sand: sand poured onto {} standing on a plate",
            path.display()
        ),
        None => println!("octoproxy demo --sand: sand poured onto a plate with a block on it"),
    }
    println!(
        "  triangles:     {} (the offset surface at the grains' radius: {})",
        baked.triangles,
        offset.mesh().triangles.len()
    );
    println!(
        "  bake time:     {:.1} s (for a radius of {RADIUS})",
        baked.bake_time.unwrap_or_default().as_secs_f64()
    );
    println!(
        "  grains:        {} of {n} poured, {on_plate} on the plate, {slow} slower than 5 cm/s, the pile {:.2} high",
        grains.len(),
        top
    );
    let layer = (-cells..=cells)
        .flat_map(|i| (-cells..=cells).map(move |k| (i, k)))
        .filter(|&(i, k)| Vec3::new(i as f32, 0.0, k as f32).length() * spacing <= SPOUT_RADIUS)
        .count();
    println!(
        "  spout:         a layer of up to {layer} grains every {LAYER_STEPS} steps, {:.2} high{}",
        spout[1],
        if blocked > 0 {
            format!("; {blocked} places in its layers left out, a grain lying within a diameter there (the pile reached the spout)")
        } else {
            String::new()
        }
    );
    println!(
        "  steps:         {steps} × {:.4} s, {substeps:.1} substeps each on average (gravity's: {}), {iterations:.1} iterations each on average (at least {}); {capped} particle-iterations at the neighbour cap, {fast} particle-substeps faster than a radius",
        params.dt,
        pair_substeps(&params, &pairs),
        pairs.iterations
    );
    println!(
        "  ms per step:   {:.2} (with {} grains at the end)",
        stepping.as_secs_f64() * 1e3 / steps.max(1) as f64,
        grains.len()
    );
    println!("  backend:       {}", stepper.name());
    println!("  picture:       {}", out.display());
    Ok(())
}
