//! `octoproxy sim`: step particles against a scene and write them out.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use glam::Vec3;
use octoproxy_core::{
    initial_side, StepParams, FLAG_BLOCKED, FLAG_BOUND_HIT, FLAG_INVALID, SIDE_BACK,
};
use octoproxy_cpu::bake::offset::OffsetSurface;
use octoproxy_cpu::emit::{emit_box, emit_surface_for};
use octoproxy_cpu::io::{read_particles, write_particles, Mesh, ParticleCloud, PlyEncoding};
use octoproxy_cpu::sides::{count_in_shell, count_in_solid, CageCounts, Sides};
use octoproxy_cpu::MeshRef;

use crate::backends::{select_backend, BackendChoice};
use crate::bake::same_file;
use crate::flags::{self, BuildFlags};
use crate::instanced::{
    list_instances, looks_baked, only_view, take_slots, with_scene_columns, write_events,
    Instanced, SceneFile,
};
use crate::scene;

fn help() -> String {
    format!(
        "usage: octoproxy sim (--mesh MESH... | --proxy FILE | --scene FILE) (--particles IN.ply | --emit N ...) -o OUT.ply [options]

scene:
  --mesh MESH       a mesh of the scene (repeat for several); baked before stepping
  --proxy FILE      a proxy file from `octoproxy bake` (build options are then an error)
  --scene FILE      a glTF 2.0 scene (.gltf, .glb: each mesh baked once, nodes with a mesh
                    its instances, animations played from time 0), or a baked scene
                    (.octoscene, from `octoproxy bake --scene`: build options are an error)
  --list-instances  print the scene's instances (index, node, mesh, pose) and stop
  --start-time S    animation time at the start of the first step (default 0)
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
  --steps N         steps (default 100; with an animated --scene, its length)
  --dt S            seconds per step (default 1/60)
  --gravity X,Y,Z   acceleration (default 0,-9.81,0)
  --restitution R   in [0, 1] (default 0.5)
  --friction F      Coulomb coefficient >= 0 (default 0.1)
  --backend B       auto, cpu or wgpu (default auto: a hardware GPU if present, else cpu)

particles that collide with each other (needs a radius: --radius, or a proxy baked for one):
{pairs}

output:
  -o, --out FILE    the stepped particles (binary little-endian PLY)
  --ascii           write ascii PLY instead
  --frames DIR      also write DIR/frame_00000.ply ... (initial state first, final last)
  --every K         write a frame every K steps (default 1)
  --force           allow --frames into a directory that already holds frames
  --hits            write each particle's last collision of its last step (hit_instance,
                    -1 for none; hit_x hit_y hit_z, hit_nx hit_ny hit_nz, hit_t, hit_speed)
  --events FILE     write every collision of every step as a PLY point cloud (step,
                    particle and the hit fields, at the hit's position)
  --event-capacity N  events kept per step before they count as lost (default 1048576)

A scene, or --hits or --events, steps through the scene API: the output then carries each
particle's sides for the instances it is near (scene_slot0..7), which a later run of the
same scene reads back to continue where this one stopped.",
        flags::BUILD_HELP,
        pairs = flags::PAIR_HELP
    )
}

#[derive(Default)]
struct Opts {
    meshes: Vec<PathBuf>,
    proxy: Option<PathBuf>,
    scene: Option<PathBuf>,
    list_instances: bool,
    start_time: Option<f64>,
    hits: bool,
    events: Option<PathBuf>,
    event_capacity: Option<usize>,
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
    pairs: flags::PairFlags,
}

fn parse(args: Vec<OsString>) -> Result<Option<Opts>> {
    let mut o = Opts::default();
    let mut parser = lexopt::Parser::from_args(args);
    while let Some((name, unexpected)) = flags::next_option(&mut parser)? {
        if o.build.parse(&name, &mut parser)? || o.pairs.parse(&name, &mut parser)? {
            continue;
        }
        let p = &mut parser;
        match name.as_str() {
            "--mesh" => o.meshes.push(flags::path(p, "--mesh")?),
            "--proxy" => o.proxy = Some(flags::path(p, "--proxy")?),
            "--scene" => o.scene = Some(flags::path(p, "--scene")?),
            "--list-instances" => o.list_instances = true,
            "--start-time" => o.start_time = Some(flags::number(p, "--start-time")?),
            "--hits" => o.hits = true,
            "--events" => o.events = Some(flags::path(p, "--events")?),
            "--event-capacity" => o.event_capacity = Some(flags::number(p, "--event-capacity")?),
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
    let sources = !o.meshes.is_empty() as u32 + o.proxy.is_some() as u32 + o.scene.is_some() as u32;
    match sources {
        0 => bail!("sim needs a scene: --mesh MESH, --proxy FILE or --scene FILE"),
        1 => {}
        _ => bail!("give one of --mesh, --proxy and --scene"),
    }
    if o.proxy.is_some() && o.build.any() {
        bail!("--dmin/--dmax/--epsilon/--lut-depth shape a bake; a --proxy is already baked");
    }
    if let Some(t) = o.start_time {
        if !t.is_finite() {
            bail!("--start-time must be a finite number of seconds, got {t}");
        }
    }
    if o.event_capacity.is_some() && o.events.is_none() {
        bail!("--event-capacity goes with --events");
    }
    if o.event_capacity == Some(0) {
        bail!("--event-capacity must be at least 1");
    }
    if o.list_instances {
        let Some(path) = &o.scene else {
            bail!("--list-instances goes with --scene (a mesh or proxy is one instance, 0, at the identity)");
        };
        print!("{}", list_instances(path)?);
        return Ok(());
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
    flags::writable(&out, "--out")?;
    if let Some(events) = &o.events {
        flags::writable(events, "--events")?;
    }
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
    if o.pairs.any_option() && !o.pairs.collide {
        bail!("--particle-* options go with --collide-particles");
    }
    if let Some(n) = o.emit {
        flags::particles_fit("--emit", n)?;
    }
    if let (Some(c), Some(_)) = (o.event_capacity, &o.events) {
        let each = 2 * std::mem::size_of::<octoproxy_core::HitEvent>() as u64;
        flags::fits_in_memory(
            "--event-capacity",
            c,
            each,
            "the events (44 bytes each, the backend's and this command's)",
        )?;
    }
    // The particle file before the scene: a bad file is found before a long bake.
    let file = match &o.particles {
        Some(path) => {
            let cloud = read_particles(path)?;
            eprintln!(
                "read {} particles from {}",
                cloud.particles.len(),
                path.display()
            );
            print_radius_note(&o, Some(&cloud), None);
            Some(cloud)
        }
        None => None,
    };
    if o.scene.is_some() || o.hits || o.events.is_some() {
        return run_scene(o, file);
    }
    if o.start_time.is_some() {
        bail!("--start-time goes with an animated --scene");
    }
    let defaults = StepParams::default();
    let mut params = StepParams {
        gravity: o.gravity.unwrap_or(defaults.gravity),
        dt: o.dt.unwrap_or(defaults.dt),
        restitution: o.restitution.unwrap_or(defaults.restitution),
        friction: o.friction.unwrap_or(defaults.friction),
        radius: o.build.radius()?,
        _pad: 0,
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
        None => scene::bake_meshes(scene::load_meshes(&o.meshes)?, &build_params, params.radius)?,
    };
    scene::print_bake_summary(&scene)?;
    let view = scene.view()?;
    params.radius = stepped_radius(&o, view.header().radius)?;
    print_radius_note(&o, file.as_ref(), Some(params.radius));
    let pairs = o.pairs.params(&params)?;

    // The particles.
    let refs: Vec<MeshRef<'_>> = scene.meshes.iter().map(MeshRef::from).collect();
    let mut cloud = particles_in(&o, file, &view, &refs, scene.offset.as_ref(), || {
        scene_box(&scene.meshes, &view)
    })?;
    if o.emit_surface {
        eprintln!(
            "sides: emitted {} particles in front of the surface, each within one dmax leaf of its face{}",
            cloud.particles.len(),
            if params.radius > 0.0 {
                " beyond the radius"
            } else {
                ""
            }
        );
        if cloud.particles.len() < o.emit.unwrap_or(0) {
            eprintln!("  (the surface had room for no more)");
        }
        let refs: Vec<MeshRef<'_>> = match &scene.offset {
            Some(s) => vec![s.mesh_ref()],
            None => scene.meshes.iter().map(MeshRef::from).collect(),
        };
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
        match &pairs {
            Some(pairs) => backend.step_pairs(&params, pairs, chunk)?,
            None => backend.step(&params, chunk)?,
        }
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
    if let Some(pairs) = &pairs {
        report_pass(&mut backend, &params, pairs)?;
    }
    if let Some(dir) = &o.frames {
        eprintln!("frames: {frame} in {}", dir.display());
    }
    println!("wrote {}", out.display());
    Ok(())
}

/// Says what the particle-particle pass did.
fn report_pass(
    backend: &mut crate::backends::Stepper,
    params: &StepParams,
    pairs: &octoproxy_core::PairParams,
) -> Result<()> {
    let report = backend.take_pair_report()?;
    eprintln!(
        "particle pass: {} substeps over {} steps ({}), {:.1} iterations each on average ({} to {}, by how deep the particles stand){}; {} particle-iterations stopped at the neighbour cap, {} particle-substeps faster than a radius per substep (they may pass through other particles, never the scene{})",
        report.substeps,
        report.steps,
        crate::flags::substeps_said(params, pairs),
        report.iterations as f64 / report.substeps.max(1) as f64,
        pairs.iterations,
        pairs.max_iterations,
        if report.deep > 0 {
            format!(
                "; {} steps stood deeper than {} iterations prop up (a pile that deep may sink and throw its top: raise --particle-max-iterations)",
                report.deep, pairs.max_iterations
            )
        } else {
            String::new()
        },
        report.capped,
        report.fast,
        if pairs.follow_speed && pairs.substeps == 0 {
            ""
        } else {
            ": --particle-substeps speed keeps every particle within a radius per substep"
        }
    );
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
    if let Some(offset) = &scene.offset {
        // Particles of a radius: out of the band first, then sides from the offset surface.
        let t = Instant::now();
        let placed = offset.place(&mut cloud.particles, Some(view));
        eprintln!(
            "radius: {} of {n} particles started nearer the mesh than the offset surface (about the radius) and were moved out along the way from their nearest surface point{}",
            placed.moved,
            if placed.stuck > 0 {
                format!(
                    "; {} could not be moved out (wedged between surfaces) and stay inside the band, behind the offset surface",
                    placed.stuck
                )
            } else {
                String::new()
            }
        );
        let counts = offset.assign_sides(&mut cloud.particles, cloud.has_side);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        eprintln!(
            "sides: from the offset surface (its band, exact but for its vertices' rounding to f32, {ms:.0} ms): {} in front, {} behind{}",
            n - counts.behind - counts.non_finite,
            counts.behind,
            if cloud.has_side {
                format!(
                    "; {} of the file's sides contradict it and are kept",
                    counts.contradicting
                )
            } else {
                String::new()
            }
        );
        let cages = offset.cages(view, &mut cloud.particles, cloud.has_side);
        report_cages(&cages, n);
        return Ok(());
    }
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
fn scene_box(meshes: &[Mesh], view: &octoproxy_core::ProxyView<'_>) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for m in meshes {
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

/// A scene file, baked here when it is glTF (with the build flags), read when it is baked.
fn instanced_from(path: &Path, build: &BuildFlags) -> Result<Instanced> {
    let kind = SceneFile::of(path).or_else(|| looks_baked(path).then_some(SceneFile::Baked));
    match kind {
        Some(SceneFile::Baked) => {
            if build.any() {
                bail!(
                    "--dmin/--dmax/--epsilon/--lut-depth shape a bake; {} is baked already",
                    path.display()
                );
            }
            // A radius given must be a valid one before it is compared with the file's.
            let radius = build.radius.map(|_| build.radius()).transpose()?;
            Instanced::from_file(path, None, radius)
        }
        _ => Instanced::from_file(path, Some(&build.params()?), Some(build.radius()?)),
    }
}

/// `--mesh` or `--proxy` as a scene of one instance at the identity.
/// The radius stepped against a proxy baked for `baked`: `--radius`, else the proxy's own;
/// one that does not match it is an error naming the proxy file.
fn stepped_radius(o: &Opts, baked: f32) -> Result<f32> {
    let radius = o.build.radius.unwrap_or(baked);
    octoproxy_core::check_radius(baked, radius).map_err(|e| {
        anyhow::anyhow!(
            "{}: {e}",
            o.proxy
                .as_deref()
                .unwrap_or(Path::new("the proxy"))
                .display()
        )
    })?;
    Ok(radius)
}

/// With `--radius`, a mesh is baked for it, and its offset surface comes back too; the
/// radius stepped is the flag's, else the proxy's own.
fn one_instance(o: &Opts) -> Result<(Instanced, Option<OffsetSurface>, f32)> {
    let mut scene = match &o.proxy {
        Some(path) => scene::read_proxy(path)?,
        None => scene::bake_meshes(
            scene::load_meshes(&o.meshes)?,
            &o.build.params()?,
            o.build.radius()?,
        )?,
    };
    scene::print_bake_summary(&scene)?;
    let radius = stepped_radius(o, scene.view()?.header().radius)?;
    let offset = scene.offset.take();
    Ok((Instanced::one(scene.words, scene.meshes)?, offset, radius))
}

/// `sim` through the scene API: a scene file, or a mesh or proxy as a scene of one instance,
/// with hit records, events and each particle's sides for the instances it is near.
fn run_scene(o: Opts, file: Option<ParticleCloud>) -> Result<()> {
    let out = o.out.clone().context("sim needs --out FILE (or -o FILE)")?;
    let defaults = StepParams::default();
    let mut params = StepParams {
        gravity: o.gravity.unwrap_or(defaults.gravity),
        dt: o.dt.unwrap_or(defaults.dt),
        restitution: o.restitution.unwrap_or(defaults.restitution),
        friction: o.friction.unwrap_or(defaults.friction),
        radius: 0.0,
        _pad: 0,
    };
    params.validate()?;
    let every = o.every.unwrap_or(1);
    if let Some(dir) = &o.frames {
        prepare_frames_dir(dir, o.force)?;
    }
    if o.emit_surface && o.scene.is_some() {
        bail!("--emit-surface needs --mesh (with --scene, emit in a box)");
    }
    let (mut inst, mut offset) = match &o.scene {
        Some(path) => {
            let inst = instanced_from(path, &o.build)?;
            params.radius = inst.radius();
            (inst, None)
        }
        None => {
            let (inst, offset, radius) = one_instance(&o)?;
            params.radius = radius;
            (inst, offset)
        }
    };
    print_radius_note(&o, file.as_ref(), Some(params.radius));
    let pairs = o.pairs.params(&params)?;
    let start = o.start_time.unwrap_or(0.0);
    inst.hold_at(start).with_context(|| scene_name(&o))?;
    let duration = inst.duration();
    let steps = match o.steps {
        Some(n) => n,
        None if duration > 0.0 => {
            let file = o
                .scene
                .as_deref()
                .unwrap_or(std::path::Path::new("the scene"));
            flags::animation_steps(file, duration, start, params.dt)?
        }
        None => 100,
    };
    let instances = inst.scene.instances().len();
    eprintln!(
        "scene: {instances} instances of {} proxies{}",
        inst.scene.proxies().len(),
        if duration > 0.0 {
            format!(
                ", animated for {duration:.3} s: {steps} steps of {} s from {start} s",
                params.dt
            )
        } else {
            String::new()
        }
    );

    // The particles and their sides.
    let refs: Vec<MeshRef<'_>> = inst.meshes[0].iter().map(MeshRef::from).collect();
    let mut cloud = particles_in(
        &o,
        file,
        &only_view(&inst.scene),
        &refs,
        offset.as_ref(),
        // A mesh or proxy as a scene of one instance emits where the plain step would
        // (`--hits` and `--events` add columns and files, not other particles); a glTF scene
        // in the box its instances sweep.
        || match &o.scene {
            None => scene_box(&inst.meshes[0], &only_view(&inst.scene)),
            Some(_) => inst.world_box(),
        },
    )?;
    let sides = match take_slots(&mut cloud)? {
        Some(sides) => {
            eprintln!(
                "sides: the file's, for every instance each particle was near (scene_slot0..7), kept"
            );
            sides
        }
        None if instances == 1 && o.scene.is_none() => {
            // One mesh or proxy at the identity: a side per particle, as the plain step has.
            let view = only_view(&inst.scene);
            if o.emit_surface {
                let refs: Vec<MeshRef<'_>> = match &offset {
                    Some(s) => vec![s.mesh_ref()],
                    None => inst.meshes[0].iter().map(MeshRef::from).collect(),
                };
                let cages = Sides::new(&refs).cages(&view, &mut cloud.particles, false);
                report_cages(&cages, cloud.particles.len());
            } else {
                let words = inst.scene.proxies()[0].words().to_vec();
                let one = scene::Scene {
                    words,
                    meshes: inst.meshes[0].clone(),
                    triangles: 0,
                    bake_time: None,
                    report: None,
                    offset: offset.take(),
                };
                starting_sides(&one, &view, &mut cloud)?;
            }
            cloud
                .particles
                .iter()
                .map(|p| {
                    let mut s = octoproxy_core::SceneSides::EMPTY;
                    s.set_side(0, p.side);
                    s
                })
                .collect()
        }
        None => {
            if cloud.has_side {
                eprintln!(
                    "sides: the file's `side` is for a scene of one instance; with {instances} instances each particle takes its sides from the meshes"
                );
            }
            if params.radius > 0.0 {
                let t = Instant::now();
                let placed = inst.place_out_of_bands(&mut cloud.particles)?;
                let (moved, stuck) = (placed.moved, placed.stuck);
                eprintln!(
                    "radius: {moved} of {} particles started nearer an instance's mesh than its offset surface (about the radius) and were moved out along the way from their nearest surface point ({:.0} ms){}",
                    cloud.particles.len(),
                    t.elapsed().as_secs_f64() * 1e3,
                    if stuck > 0 {
                        format!("; {stuck} are still inside an instance's band (wedged between instances) and start behind its offset surface")
                    } else {
                        String::new()
                    }
                );
            }
            let t = Instant::now();
            let (sides, from_mesh) = match &inst.offsets {
                // Particles of a radius: from each proxy's band.
                Some(offsets) => {
                    octoproxy_cpu::starting_scene_sides(&inst.scene, offsets, &cloud.particles)
                }
                None => {
                    let per_proxy = inst.sides();
                    let Some(all): Option<Vec<Sides>> = per_proxy.into_iter().collect() else {
                        bail!("the scene's proxies came without their meshes");
                    };
                    octoproxy_cpu::starting_scene_sides(&inst.scene, &all, &cloud.particles)
                }
            };
            eprintln!(
                "sides: {from_mesh} of {} particles start in an instance's surface leaf and take their side from its {} (exact, {:.0} ms); the others take it from the empty leaf they are in",
                cloud.particles.len(),
                if params.radius > 0.0 {
                    "offset surface"
                } else {
                    "mesh"
                },
                t.elapsed().as_secs_f64() * 1e3
            );
            sides
        }
    };

    let mut backend = select_backend(o.backend.unwrap_or(BackendChoice::Auto))?;
    backend.upload_particles(&cloud.particles)?;
    backend.upload_scene_sides(&sides)?;
    let capacity = o.event_capacity.unwrap_or(1 << 20);
    if o.events.is_some() {
        backend.set_event_capacity(capacity)?;
    }
    let encoding = if o.ascii {
        PlyEncoding::Ascii
    } else {
        PlyEncoding::BinaryLittleEndian
    };
    let n = cloud.particles.len();
    let mut sides = sides;
    let mut hits = vec![octoproxy_core::Hit::NONE; n];
    let mut frame = 0u32;
    let mut write_frame = |cloud: &ParticleCloud,
                           sides: &[octoproxy_core::SceneSides],
                           hits: &[octoproxy_core::Hit]|
     -> Result<()> {
        if let Some(dir) = &o.frames {
            let path = dir.join(format!("frame_{frame:05}.ply"));
            let columns = with_scene_columns(cloud, sides, o.hits.then_some(hits));
            write_particles(&path, &columns, encoding)
                .with_context(|| format!("writing {}", path.display()))?;
            frame += 1;
        }
        Ok(())
    };
    write_frame(&cloud, &sides, &hits)?;
    let mut events = Vec::new();
    let none = octoproxy_core::HitEvent {
        step: 0,
        particle: 0,
        hit: octoproxy_core::Hit::NONE,
    };
    let mut event_buf = Vec::new();
    if o.events.is_some() {
        event_buf.try_reserve_exact(capacity).map_err(|_| {
            anyhow::anyhow!("--event-capacity {capacity}: the events could not be allocated")
        })?;
        event_buf.resize(capacity, none);
    }
    let mut lost = 0u64;
    let bar = crate::progress::bar(steps as u64, "stepping");
    let mut stepping = Duration::ZERO;
    for k in 1..=steps {
        let t = Instant::now();
        let now = start + k as f64 * params.dt as f64;
        inst.pose_at(now)?;
        inst.prepare().with_context(|| stepping_at(&o, k, now))?;
        match &pairs {
            Some(pairs) => backend.step_scene_pairs(&mut inst.scene, &params, pairs, o.hits),
            None => backend.step_scene(&mut inst.scene, &params, o.hits),
        }
        .with_context(|| stepping_at(&o, k, now))?;
        if o.events.is_some() {
            let count = backend.take_events(&mut event_buf)?;
            events.extend_from_slice(&event_buf[..count.stored]);
            lost += count.lost;
        }
        stepping += t.elapsed();
        bar.inc(1);
        if o.frames.is_some() && (k % every == 0 || k == steps) {
            backend.download_particles(&mut cloud.particles)?;
            backend.download_scene_sides(&mut sides)?;
            if o.hits {
                backend.download_hits(&mut hits)?;
            }
            write_frame(&cloud, &sides, &hits)?;
        }
    }
    bar.finish_and_clear();
    backend.finish()?;
    backend.download_particles(&mut cloud.particles)?;
    backend.download_scene_sides(&mut sides)?;
    if o.hits {
        backend.download_hits(&mut hits)?;
    }
    let report = backend.take_scene_report()?;
    let columns = with_scene_columns(&cloud, &sides, o.hits.then_some(&hits[..]));
    write_particles(&out, &columns, encoding)
        .with_context(|| format!("writing {}", out.display()))?;
    if let Some(path) = &o.events {
        write_events(path, &events)?;
    }

    let count = |f: u32| cloud.particles.iter().filter(|p| p.flags & f != 0).count();
    let collisions: u64 = cloud.particles.iter().map(|p| p.collisions() as u64).sum();
    eprintln!("particles: {n}");
    eprintln!(
        "steps: {steps} × {} s on {}: {:.3} ms per step",
        params.dt,
        backend.name(),
        stepping.as_secs_f64() * 1e3 / steps.max(1) as f64
    );
    eprintln!(
        "collisions: {collisions}; particle-steps crushed between instances: {}, with sides lost: {}; flagged now: {} invalid (NaN/inf), {} at a bound or carried, {} kept from crossing",
        report.crushed,
        report.sides_lost,
        count(FLAG_INVALID),
        count(FLAG_BOUND_HIT),
        count(FLAG_BLOCKED)
    );
    if o.hits {
        let hit = hits.iter().filter(|h| h.instance >= 0).count();
        eprintln!("hits: {hit} of {n} particles collided in the last step");
    }
    if let Some(pairs) = &pairs {
        report_pass(&mut backend, &params, pairs)?;
    }
    if let Some(path) = &o.events {
        eprintln!(
            "events: {} written to {}, {lost} lost (more than --event-capacity {capacity} in one step)",
            events.len(),
            path.display()
        );
    }
    if let Some(dir) = &o.frames {
        eprintln!("frames: {frame} in {}", dir.display());
    }
    println!("wrote {}", out.display());
    Ok(())
}

/// Whether the command bakes its scene itself (meshes, or a glTF scene), so that `--radius`
/// is the run's radius; else a proxy or a baked scene file brings its own.
fn bakes_here(o: &Opts) -> bool {
    match &o.scene {
        Some(path) => {
            SceneFile::of(path) == Some(SceneFile::Gltf)
                || (SceneFile::of(path).is_none() && !looks_baked(path))
        }
        None => o.proxy.is_none(),
    }
}

/// [`radius_property_note`] printed once the run's radius is known: before the scene for a
/// scene baked here (`bakes_here`; `baked` is `None` then), else once the file's is read.
fn print_radius_note(o: &Opts, cloud: Option<&ParticleCloud>, baked: Option<f32>) {
    let (Some(cloud), Some(path)) = (cloud, &o.particles) else {
        return;
    };
    let here = bakes_here(o);
    if here != baked.is_none() {
        return;
    }
    let run = baked.unwrap_or_else(|| o.build.radius.unwrap_or(0.0));
    if let Some(note) = radius_property_note(cloud, path, run, here) {
        eprintln!("{note}");
    }
}

/// A note for a particle file that carries per-particle radii (a `radius` or, as Houdini
/// writes it, `pscale` property): they are carried to the output, not used, since every
/// particle of a run steps at its one radius; the note gives the range and what keeps every
/// particle's distance: `--radius` where the scene is baked here (`bakes_here`), else a
/// proxy or scene baked for that radius. `run`: the run's radius. `None` for a file without
/// one.
fn radius_property_note(
    cloud: &ParticleCloud,
    path: &Path,
    run: f32,
    bakes_here: bool,
) -> Option<String> {
    let props = &cloud.extra.properties;
    let k = props.iter().position(|(name, _)| {
        name.eq_ignore_ascii_case("radius") || name.eq_ignore_ascii_case("pscale")
    })?;
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..cloud.particles.len() {
        if let Some(r) = cloud
            .extra
            .row(i)
            .map(|row| row[k])
            .filter(|r| r.is_finite())
        {
            lo = lo.min(r);
            hi = hi.max(r);
        }
    }
    // As the `f32` a radius is (the largest rounded up, so that it covers the file's).
    let (lo, hi) = (lo as f32, {
        let h = hi as f32;
        if (h as f64) < hi {
            h.next_up()
        } else {
            h
        }
    });
    let name = &props[k].0;
    let advice = if !(hi.is_finite() && hi > run) {
        String::new()
    } else if bakes_here {
        format!("; --radius {hi} keeps every particle's distance from the scene")
    } else {
        format!("; baked again with --radius {hi}, the scene keeps every particle's distance")
    };
    let run = if run > 0.0 {
        format!("radius {run}")
    } else {
        "0: points".to_string()
    };
    let range = if !(lo <= hi) {
        "none finite".to_string()
    } else if lo == hi {
        format!("all {lo}")
    } else {
        format!("{lo} to {hi}")
    };
    Some(format!(
        "note: {} has per-particle radii (`{name}`: {range}); they are carried to the output, not used: every particle steps at the run's one radius ({run}){advice}",
        path.display()
    ))
}

/// What a failed scene step says first: the scene and the step (an error about an instance
/// of a scene file names its node; `--list-instances` prints them all).
fn stepping_at(o: &Opts, k: u32, t: f64) -> String {
    format!("{}: step {k} (to {t:.4} s)", scene_name(o))
}

/// The file the scene came from, as errors name it.
fn scene_name(o: &Opts) -> String {
    match (&o.scene, &o.proxy, o.meshes.first()) {
        (Some(p), _, _) | (None, Some(p), _) | (None, None, Some(p)) => p.display().to_string(),
        _ => "the scene".to_string(),
    }
}

/// The particles: the file's (`file`, read before the scene), or `--emit N` of them, on the
/// surface of `meshes` (baked into `view`) or in the box given, else in `scene_box()`.
fn particles_in(
    o: &Opts,
    file: Option<ParticleCloud>,
    view: &octoproxy_core::ProxyView<'_>,
    meshes: &[MeshRef<'_>],
    offset: Option<&OffsetSurface>,
    scene_box: impl FnOnce() -> (Vec3, Vec3),
) -> Result<ParticleCloud> {
    if let Some(cloud) = file {
        return Ok(cloud);
    }
    let n = o
        .emit
        .context("sim needs particles: --particles FILE or --emit N")?;
    let speed = o.emit_speed.unwrap_or(0.0);
    let seed = o.seed.unwrap_or(1);
    let particles = if o.emit_surface {
        emit_surface_for(view, n, meshes, offset, speed, seed)
    } else {
        let (min, max) = match o.emit_box {
            Some(b) => (Vec3::new(b[0], b[1], b[2]), Vec3::new(b[3], b[4], b[5])),
            None => scene_box(),
        };
        emit_box(n, min, max, speed, seed)
    }
    .with_context(|| format!("--emit {n}"))?;
    Ok(ParticleCloud::from_particles(particles))
}
