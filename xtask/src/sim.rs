//! `octoproxy sim`: step particles against a scene and write them out.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use glam::Vec3;
use octoproxy_core::{
    initial_side, StepParams, FLAG_BLOCKED, FLAG_BOUND_HIT, FLAG_INVALID, SIDE_BACK,
};
use octoproxy_cpu::emit::{emit_box, emit_surface_for};
use octoproxy_cpu::io::{read_particles, write_particles, ParticleCloud, PlyEncoding};
use octoproxy_cpu::sides::{count_in_shell, count_in_solid, CageCounts, Sides};
use octoproxy_cpu::MeshRef;

use crate::backends::{select_backend, BackendChoice};
use crate::bake::same_file;
use crate::flags::{self, BuildFlags};
use crate::scene;

fn help() -> String {
    format!(
        "usage: octoproxy sim (--mesh MESH... | --proxy FILE) (--particles IN.ply | --emit N ...) -o OUT.ply [options]

scene:
  --mesh MESH       a mesh of the scene (repeat for several); baked before stepping
  --proxy FILE      a proxy file from `octoproxy bake` (build options are then an error)
{}

particles:
  --particles FILE  a PLY point cloud: x y z, optional vx vy vz, side, flags, and any others
  --emit N          emit N particles instead
  --emit-box X0,Y0,Z0,X1,Y1,Z1   where to emit (default: the scene's box grown by 10 %)
  --emit-surface    emit in front of the meshes' surface, outside every other part, within
                    one dmax leaf of the face (needs --mesh)
  --emit-speed S    speed of emitted particles in random directions (default 0)
  --seed K          emitter seed (default 1)

stepping:
  --steps N         steps (default 100)
  --dt S            seconds per step (default 1/60)
  --gravity X,Y,Z   acceleration (default 0,-9.81,0)
  --restitution R   in [0, 1] (default 0.5)
  --friction F      Coulomb coefficient >= 0 (default 0.1)
  --backend B       auto, cpu or wgpu (default auto: a hardware GPU if present, else cpu)

output:
  -o, --out FILE    the stepped particles (binary little-endian PLY)
  --ascii           write ascii PLY instead
  --frames DIR      also write DIR/frame_00000.ply ... (initial state first, final last)
  --every K         write a frame every K steps (default 1)
  --force           allow --frames into a directory that already holds frames",
        flags::BUILD_HELP
    )
}

#[derive(Default)]
struct Opts {
    meshes: Vec<PathBuf>,
    proxy: Option<PathBuf>,
    build: BuildFlags,
    particles: Option<PathBuf>,
    emit: Option<usize>,
    emit_box: Option<[f32; 6]>,
    emit_surface: bool,
    emit_speed: Option<f32>,
    seed: Option<u64>,
    out: Option<PathBuf>,
    ascii: bool,
    frames: Option<PathBuf>,
    every: Option<u32>,
    force: bool,
    steps: Option<u32>,
    dt: Option<f32>,
    gravity: Option<[f32; 3]>,
    restitution: Option<f32>,
    friction: Option<f32>,
    backend: Option<BackendChoice>,
}

fn parse(args: Vec<OsString>) -> Result<Option<Opts>> {
    let mut o = Opts::default();
    let mut parser = lexopt::Parser::from_args(args);
    while let Some((name, unexpected)) = flags::next_option(&mut parser)? {
        if o.build.parse(&name, &mut parser)? {
            continue;
        }
        let p = &mut parser;
        match name.as_str() {
            "--mesh" => o.meshes.push(flags::path(p, "--mesh")?),
            "--proxy" => o.proxy = Some(flags::path(p, "--proxy")?),
            "--particles" => o.particles = Some(flags::path(p, "--particles")?),
            "--emit" => o.emit = Some(flags::number(p, "--emit")?),
            "--emit-box" => o.emit_box = Some(flags::floats::<6>(p, "--emit-box")?),
            "--emit-surface" => o.emit_surface = true,
            "--emit-speed" => o.emit_speed = Some(flags::number(p, "--emit-speed")?),
            "--seed" => o.seed = Some(flags::number(p, "--seed")?),
            "-o" | "--out" => o.out = Some(flags::path(p, "--out")?),
            "--ascii" => o.ascii = true,
            "--frames" => o.frames = Some(flags::path(p, "--frames")?),
            "--every" => o.every = Some(flags::number(p, "--every")?),
            "--force" => o.force = true,
            "--steps" => o.steps = Some(flags::number(p, "--steps")?),
            "--dt" => o.dt = Some(flags::number(p, "--dt")?),
            "--gravity" => o.gravity = Some(flags::floats::<3>(p, "--gravity")?),
            "--restitution" => o.restitution = Some(flags::number(p, "--restitution")?),
            "--friction" => o.friction = Some(flags::number(p, "--friction")?),
            "--backend" => o.backend = Some(BackendChoice::parse(&flags::string(p, "--backend")?)?),
            "-h" | "--help" => {
                println!("{}", help());
                return Ok(None);
            }
            _ => return Err(unexpected.into()),
        }
    }
    Ok(Some(o))
}

pub fn run(args: Vec<OsString>) -> Result<()> {
    let Some(o) = parse(args)? else { return Ok(()) };
    // Check everything before any work.
    match (o.meshes.is_empty(), &o.proxy) {
        (true, None) => bail!("sim needs a scene: --mesh MESH or --proxy FILE"),
        (false, Some(_)) => bail!("give either --mesh or --proxy, not both"),
        (_, Some(_)) if o.build.any() => {
            bail!("--dmin/--dmax/--epsilon/--lut-depth shape a bake; a --proxy is already baked")
        }
        _ => {}
    }
    match (&o.particles, o.emit) {
        (None, None) => bail!("sim needs particles: --particles FILE or --emit N"),
        (Some(_), Some(_)) => bail!("give either --particles or --emit, not both"),
        (Some(_), None)
            if o.emit_box.is_some()
                || o.emit_surface
                || o.emit_speed.is_some()
                || o.seed.is_some() =>
        {
            bail!("--emit-box, --emit-surface, --emit-speed and --seed go with --emit")
        }
        _ => {}
    }
    if o.emit_box.is_some() && o.emit_surface {
        bail!("give either --emit-box or --emit-surface, not both");
    }
    if o.emit_surface && o.meshes.is_empty() {
        bail!("--emit-surface needs --mesh (a proxy file keeps no triangles)");
    }
    if let Some(b) = o.emit_box {
        if !(b[0] <= b[3] && b[1] <= b[4] && b[2] <= b[5]) {
            bail!("--emit-box: the minimum corner must not exceed the maximum corner");
        }
    }
    if let Some(s) = o.emit_speed {
        if !(s >= 0.0) || !s.is_finite() {
            bail!("--emit-speed must be a finite number >= 0, got {s}");
        }
    }
    let Some(out) = o.out.clone() else {
        bail!("sim needs --out FILE (or -o FILE)")
    };
    if let Some(input) = &o.particles {
        if same_file(input, &out) {
            bail!(
                "--out {} is the input particle file; refusing to overwrite it",
                out.display()
            );
        }
    }
    if o.every.is_some() && o.frames.is_none() {
        bail!("--every goes with --frames");
    }
    let every = o.every.unwrap_or(1);
    if every == 0 {
        bail!("--every must be at least 1");
    }
    let defaults = StepParams::default();
    let params = StepParams {
        gravity: o.gravity.unwrap_or(defaults.gravity),
        dt: o.dt.unwrap_or(defaults.dt),
        restitution: o.restitution.unwrap_or(defaults.restitution),
        friction: o.friction.unwrap_or(defaults.friction),
        _pad: [0; 2],
    };
    params.validate()?;
    let build_params = o.build.params()?;
    let steps = o.steps.unwrap_or(100);
    if let Some(dir) = &o.frames {
        prepare_frames_dir(dir, o.force)?;
    }

    // The scene.
    let scene = match &o.proxy {
        Some(path) => scene::read_proxy(path)?,
        None => scene::bake_meshes(scene::load_meshes(&o.meshes)?, &build_params)?,
    };
    scene::print_bake_summary(&scene)?;
    let view = scene.view()?;

    // The particles.
    let mut cloud = match (&o.particles, o.emit) {
        (Some(path), _) => {
            let cloud = read_particles(path)?;
            eprintln!(
                "read {} particles from {}",
                cloud.particles.len(),
                path.display()
            );
            cloud
        }
        (None, Some(n)) => {
            let speed = o.emit_speed.unwrap_or(0.0);
            let seed = o.seed.unwrap_or(1);
            let particles = if o.emit_surface {
                let refs: Vec<MeshRef<'_>> = scene.meshes.iter().map(MeshRef::from).collect();
                emit_surface_for(&view, n, &refs, speed, seed)
            } else {
                let (min, max) = match o.emit_box {
                    Some(b) => (Vec3::new(b[0], b[1], b[2]), Vec3::new(b[3], b[4], b[5])),
                    None => scene_box(&scene, &view),
                };
                emit_box(n, min, max, speed, seed)
            };
            ParticleCloud::from_particles(particles)
        }
        (None, None) => unreachable!("checked above"),
    };
    if o.emit_surface {
        eprintln!(
            "sides: emitted {} particles in front of the surface, each within one dmax leaf of its face",
            cloud.particles.len()
        );
        if cloud.particles.len() < o.emit.unwrap_or(0) {
            eprintln!("  (the surface had room for no more)");
        }
        let refs: Vec<MeshRef<'_>> = scene.meshes.iter().map(MeshRef::from).collect();
        let cages = Sides::new(&refs).cages(&view, &mut cloud.particles, false);
        report_cages(&cages, cloud.particles.len());
    } else {
        starting_sides(&scene, &view, &mut cloud)?;
    }

    let mut backend = select_backend(o.backend.unwrap_or(BackendChoice::Auto))?;
    backend.upload_proxy(&scene.words)?;
    backend.upload_particles(&cloud.particles)?;
    let encoding = if o.ascii {
        PlyEncoding::Ascii
    } else {
        PlyEncoding::BinaryLittleEndian
    };

    let mut frame = 0u32;
    let mut write_frame = |cloud: &ParticleCloud| -> Result<()> {
        if let Some(dir) = &o.frames {
            let path = dir.join(format!("frame_{frame:05}.ply"));
            write_particles(&path, cloud, encoding)
                .with_context(|| format!("writing {}", path.display()))?;
            frame += 1;
        }
        Ok(())
    };
    write_frame(&cloud)?;
    let bar = crate::progress::bar(steps as u64, "stepping");
    let mut stepping = Duration::ZERO;
    let mut done = 0u32;
    while done < steps {
        let chunk = if o.frames.is_some() {
            every.min(steps - done)
        } else {
            steps - done
        };
        let t = Instant::now();
        backend.step(&params, chunk)?;
        backend.finish()?;
        stepping += t.elapsed();
        done += chunk;
        bar.inc(chunk as u64);
        if o.frames.is_some() {
            backend.download_particles(&mut cloud.particles)?;
            write_frame(&cloud)?;
        }
    }
    bar.finish_and_clear();
    backend.download_particles(&mut cloud.particles)?;
    write_particles(&out, &cloud, encoding)
        .with_context(|| format!("writing {}", out.display()))?;

    let n = cloud.particles.len();
    let count = |f: u32| cloud.particles.iter().filter(|p| p.flags & f != 0).count();
    let back = cloud
        .particles
        .iter()
        .filter(|p| p.side_only() == SIDE_BACK)
        .count();
    let collisions: u64 = cloud.particles.iter().map(|p| p.collisions() as u64).sum();
    eprintln!("particles: {n} ({} in front, {back} behind)", n - back);
    eprintln!(
        "steps: {steps} × {} s on {}: {:.3} ms per step",
        params.dt,
        backend.name(),
        stepping.as_secs_f64() * 1e3 / steps.max(1) as f64
    );
    eprintln!(
        "collisions: {collisions}; flagged: {} invalid (NaN/inf), {} stopped at the leaf bound, {} kept from crossing",
        count(FLAG_INVALID),
        count(FLAG_BOUND_HIT),
        count(FLAG_BLOCKED)
    );
    if let Some(dir) = &o.frames {
        eprintln!("frames: {frame} in {}", dir.display());
    }
    println!("wrote {}", out.display());
    Ok(())
}

/// The particles' starting sides: from the mesh when there is one (exact; a file's own sides
/// are kept and checked against it), else from the proxy (the mean plane of a surface leaf,
/// an approximation within a leaf of the surface), with what was done said.
fn starting_sides(
    scene: &scene::Scene,
    view: &octoproxy_core::ProxyView<'_>,
    cloud: &mut ParticleCloud,
) -> Result<()> {
    let n = cloud.particles.len();
    if !scene.meshes.is_empty() {
        let t = Instant::now();
        let refs: Vec<MeshRef<'_>> = scene.meshes.iter().map(MeshRef::from).collect();
        let sides = Sides::new(&refs);
        let counts = sides.assign(&mut cloud.particles, cloud.has_side);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if cloud.has_side {
            eprintln!(
                "sides: the file's, kept; {} of {n} contradict the mesh (exact: nearest surface and winding numbers, {ms:.0} ms)",
                counts.contradicting
            );
        } else {
            eprintln!(
                "sides: from the mesh (exact: nearest surface and winding numbers, {ms:.0} ms): {} in front, {} behind",
                n - counts.behind - counts.non_finite,
                counts.behind
            );
        }
        let cages = sides.cages(view, &mut cloud.particles, cloud.has_side);
        report_cages(&cages, n);
        return Ok(());
    }
    if !cloud.has_side {
        for p in &mut cloud.particles {
            p.side = initial_side(view, p.position);
        }
    }
    let in_shell = count_in_shell(view, &cloud.particles);
    let in_solid = count_in_solid(view, &cloud.particles);
    let caged = cloud.particles.iter().filter(|p| p.is_caged()).count();
    if in_solid > caged {
        eprintln!(
            "cages: {} of {n} particles start strictly inside solid leaves, where surfaces cross, fold or end within a leaf and one side bit cannot be right for each; only --mesh can cage them there",
            in_solid - caged
        );
    }
    eprintln!(
        "sides: {}; {in_shell} of {n} start inside the shell of surface leaves{}",
        if cloud.has_side {
            "the file's"
        } else {
            "from the proxy (the leaf's label, or a surface leaf's mean plane)"
        },
        if in_shell > 0 && !cloud.has_side {
            ", where the mean plane is an approximation within a leaf of the surface (give --mesh for exact sides)"
        } else {
            ""
        }
    );
    Ok(())
}

/// The scene's box grown by 10 % (the meshes' box when there are meshes, else the root cube).
fn scene_box(scene: &scene::Scene, view: &octoproxy_core::ProxyView<'_>) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for m in &scene.meshes {
        for t in &m.triangles {
            for &i in t {
                if let Some(p) = m.positions.get(i as usize) {
                    lo = lo.min(Vec3::from_array(*p));
                    hi = hi.max(Vec3::from_array(*p));
                }
            }
        }
    }
    if !(lo.cmple(hi).all()) {
        let r = view.root_aabb();
        (lo, hi) = (r.min, r.max);
    }
    let grow = (hi - lo) * 0.05;
    (lo - grow, hi + grow)
}

/// Creates the frames directory, refusing one that already holds frames unless forced.
fn prepare_frames_dir(dir: &Path, force: bool) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let has_frames = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok())
        .any(|e| {
            let name = e.file_name();
            let name = name.to_string_lossy();
            name.starts_with("frame_") && name.ends_with(".ply")
        });
    if has_frames && !force {
        bail!(
            "{} already holds frame files; pass --force to overwrite them",
            dir.display()
        );
    }
    Ok(())
}

/// Says what [`Sides::cages`] did, when it caged any.
pub(crate) fn report_cages(cages: &CageCounts, n: usize) {
    if cages.kept > 0 {
        eprintln!("cages: the file's, kept, for {} particles", cages.kept);
    }
    if cages.caged == 0 {
        return;
    }
    eprintln!(
        "cages: {} of {n} particles start strictly inside solid leaves (where surfaces cross, fold or end within a leaf); each leaves its leaf only through a face it can reach without crossing the surface{}",
        cages.caged,
        if cages.without_exit > 0 {
            format!(", and {} that can reach none stay in it", cages.without_exit)
        } else {
            String::new()
        }
    );
}
