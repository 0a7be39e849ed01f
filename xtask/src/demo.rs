//! `octoproxy demo`: particles raining onto an open dome and fired up into it from below,
//! colliding with both of its sides; prints a summary and writes a picture.

use std::ffi::OsString;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Result;
use glam::Vec3;
use octoproxy_core::{Particle, StepParams, SIDE_BACK};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::{starting_sides, BuildParams, MeshRef};

use crate::backends::{select_backend, BackendChoice};
use crate::flags;
use crate::render::{Camera, Canvas, BACK, FRONT};
use crate::scene;

const HELP: &str = "\
usage: octoproxy demo [--particles N] [--steps N] [-o PICTURE.png] [--backend auto|cpu|wgpu]

Runs a built-in scene: an open dome (no files needed). Half the particles rain onto it and
slide off its front side; half are fired up from beneath and hit its back side.";

pub fn run(args: Vec<OsString>) -> Result<()> {
    let mut n = 20_000usize;
    let mut steps = 90u32;
    let mut out = PathBuf::from("target/octoproxy-demo.png");
    let mut backend = BackendChoice::Auto;
    let mut parser = lexopt::Parser::from_args(args);
    while let Some((name, unexpected)) = flags::next_option(&mut parser)? {
        match name.as_str() {
            "--particles" => n = flags::number(&mut parser, "--particles")?,
            "--steps" => steps = flags::number(&mut parser, "--steps")?,
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
    if n == 0 {
        anyhow::bail!("--particles must be at least 1");
    }

    let mesh = octoproxy_cpu::scenes::hemisphere([0.0; 3], 1.0, 96, 24);
    let scene = scene::bake_meshes(
        vec![mesh],
        &BuildParams {
            dmax: 7,
            ..BuildParams::default()
        },
    )?;
    let view = scene.view()?;

    // Rain above the dome, and a fountain beneath it.
    let mut rng = Rng::new(1);
    let mut particles: Vec<Particle> = (0..n)
        .map(|i| {
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
        })
        .collect();
    let refs: Vec<MeshRef<'_>> = scene.meshes.iter().map(MeshRef::from).collect();
    starting_sides(&refs, &scene.view()?, &mut particles);

    let mut backend = select_backend(backend)?;
    backend.upload_proxy(&scene.words)?;
    backend.upload_particles(&particles)?;
    let params = StepParams::default();

    let cam = Camera::new(Vec3::new(0.0, 0.35, 0.0), 1.75, 0.55, 0.42, 960, 720);
    let mut canvas = Canvas::new(960, 720);
    for t in &scene.meshes[0].triangles {
        let v = t.map(|i| Vec3::from_array(scene.meshes[0].positions[i as usize]));
        // Cut away the half nearer the camera, so both sides show.
        if cam.project((v[0] + v[1] + v[2]) / 3.0).z > 0.0 {
            continue;
        }
        canvas.triangle(&cam, v, [0.78, 0.79, 0.82]);
    }

    let bar = crate::progress::bar(steps as u64, "stepping");
    let mut stepping = Duration::ZERO;
    let trail = n.min(4000);
    for s in 0..steps {
        let t = Instant::now();
        backend.step(&params, 1)?;
        backend.finish()?;
        stepping += t.elapsed();
        if s % 2 == 0 {
            backend.download_particles(&mut particles)?;
            for p in &particles[..trail] {
                let c = if p.side_only() == SIDE_BACK {
                    BACK
                } else {
                    FRONT
                };
                canvas.splat(&cam, Vec3::from_array(p.position), 0.8, c, 0.12);
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    backend.download_particles(&mut particles)?;
    for p in &particles {
        let c = if p.side_only() == SIDE_BACK {
            BACK
        } else {
            FRONT
        };
        canvas.splat(&cam, Vec3::from_array(p.position), 1.4, c, 0.9);
    }
    canvas.save_png(&out)?;

    let back = particles
        .iter()
        .filter(|p| p.side_only() == SIDE_BACK)
        .count();
    let collisions: u64 = particles.iter().map(|p| p.collisions() as u64).sum();
    println!("octoproxy demo: an open dome, particles on both of its sides");
    println!("  triangles:     {}", scene.triangles);
    println!(
        "  proxy:         {} (nodes {}, lookup table {})",
        scene::bytes(view.words().len() * 4),
        scene::bytes(view.node_bytes()),
        scene::bytes(view.lut_bytes())
    );
    println!(
        "  bake time:     {:.1} ms",
        scene.bake_time.unwrap_or_default().as_secs_f64() * 1e3
    );
    println!(
        "  particles:     {n} ({} in front, {back} behind at the end)",
        n - back
    );
    println!(
        "  steps:         {steps} × {:.4} s, {collisions} collisions",
        params.dt
    );
    println!(
        "  ms per step:   {:.3}",
        stepping.as_secs_f64() * 1e3 / steps.max(1) as f64
    );
    println!("  backend:       {}", backend.name());
    println!("  picture:       {}", out.display());
    Ok(())
}
