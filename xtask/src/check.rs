//! `octoproxy check`: the penetration harness on any scene. Steps particles many times and
//! counts, against exact ground truth (not the proxy), particles that change side deeper
//! than one dmax-leaf diagonal and particles that become NaN. The tests run the same code
//! (`octoproxy_cpu::harness::run_check`).

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use octoproxy_core::{PairParams, StepParams};
use octoproxy_cpu::bake::offset::OffsetSurface;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::harness::{run_check, run_check_pairs, run_check_radius, Start, Starter};
use octoproxy_cpu::io::read_particles;
use octoproxy_cpu::io::Mesh;
use octoproxy_cpu::scenes::{self, MeshExt};
use octoproxy_cpu::{MeshRef, Sides};

use crate::flags::{self, BuildFlags};
use crate::instanced::{outside_all, Instanced, SceneFile};
use crate::scene;

fn help() -> String {
    format!(
        "\
usage: octoproxy check (--mesh MESH... | --scene NAME | --scene FILE) [options]

Counts penetrations against exact ground truth: generalized winding numbers for closed
meshes (at every step's end, and along every piece of a path that crosses the surface, so a
particle that goes through the mesh within one step counts), crossing parity of every path
segment for open ones, both through a BVH.

scene:
  --mesh FILE       a mesh (PLY/OBJ/STL, .gz); repeat for several
  --scene NAME      a built-in scene: sphere, torus, slab, wedge, star, shells, sheet, dome, comb
  --scene FILE      a glTF 2.0 scene (.gltf, .glb) or a baked one (.octoscene), its
                    instances moving as its animations say: every piece of every path is
                    checked in every instance's frame at the pose of each moment
{}

particles:
  --particles FILE  a PLY point cloud (x y z, optional vx vy vz, side; without a side,
                    each takes it from the mesh)
  --emit N          N particles (default 20000), speeds from 0.1 leaf to the whole scene
                    per step, started where --starts says
  --starts WHERE    outside: at least two leaf diagonals from the surface (default);
                    shell: within 1.5 leaves of it, both sides; emitted: from it, as
                    sim --emit-surface emits; corners: a fraction of a leaf from its
                    vertices (inside a closed scene). Sides and cages from the mesh
  --seed K          (default 1)

particles that collide with each other (needs a radius: --radius, or a scene file baked for one):
{}

stepping:
  --steps N         (default 100)
  --restitution R   (default 0.5)
  --friction F      (default 0.1)
  --gravity X,Y,Z   (default 0,-9.81,0)
  --dt S            (default 1/60)

Exits non-zero when any particle penetrates or becomes NaN.",
        flags::BUILD_HELP,
        flags::PAIR_HELP
    )
}

fn builtin(name: &str) -> Result<Mesh> {
    Ok(match name {
        "sphere" => scenes::uv_sphere([0.0; 3], 1.0, 48, 24),
        "torus" => scenes::torus([0.0; 3], 1.0, 0.3, 48, 24),
        "slab" => scenes::slab([0.0; 3], [2.0, 0.004, 2.0]),
        "wedge" => scenes::wedge(8.0, 2.0, 1.0),
        "star" => scenes::star_prism(7, 1.5, 0.4, 1.0),
        "shells" => scenes::nested_shells(1.0, 0.02),
        "sheet" => scenes::flat_sheet([0.0; 3], 2.0, 8),
        "dome" => scenes::hemisphere([0.0; 3], 1.0, 48, 12),
        "comb" => scenes::merge(&(0..9).map(|i| scenes::slab([i as f32 * 0.2 - 0.8, 0.0, 0.0], [0.003, 1.5, 1.5])).collect::<Vec<_>>()),
        _ => bail!("--scene: {name:?} is neither a built-in scene (sphere, torus, slab, wedge, star, shells, sheet, dome, comb) nor a scene file (.gltf, .glb, .octoscene)"),
    })
}

pub fn run(args: Vec<OsString>) -> Result<()> {
    let mut meshes: Vec<PathBuf> = Vec::new();
    let mut builtin_name: Option<String> = None;
    let mut build = BuildFlags::default();
    let mut pair_flags = flags::PairFlags::default();
    let mut particles_file: Option<PathBuf> = None;
    let mut emit: Option<usize> = None;
    let mut starts: Option<Start> = None;
    let mut seed = 1u64;
    let mut steps = 100u32;
    let mut params = StepParams::default();
    let mut p = lexopt::Parser::from_args(args);
    while let Some((name, unexpected)) = flags::next_option(&mut p)? {
        if build.parse(&name, &mut p)? || pair_flags.parse(&name, &mut p)? {
            continue;
        }
        match name.as_str() {
            "--mesh" => meshes.push(flags::path(&mut p, "--mesh")?),
            "--scene" => builtin_name = Some(flags::string(&mut p, "--scene")?),
            "--particles" => particles_file = Some(flags::path(&mut p, "--particles")?),
            "--emit" => emit = Some(flags::number(&mut p, "--emit")?),
            "--starts" => {
                let name = flags::string(&mut p, "--starts")?;
                starts = Some(Start::from_name(&name).ok_or_else(|| {
                    anyhow::anyhow!(
                        "--starts: unknown place {name:?} (outside, shell, emitted, corners)"
                    )
                })?);
            }
            "--seed" => seed = flags::number(&mut p, "--seed")?,
            "--steps" => steps = flags::number(&mut p, "--steps")?,
            "--restitution" => params.restitution = flags::number(&mut p, "--restitution")?,
            "--friction" => params.friction = flags::number(&mut p, "--friction")?,
            "--gravity" => params.gravity = flags::floats::<3>(&mut p, "--gravity")?,
            "--dt" => params.dt = flags::number(&mut p, "--dt")?,
            "-h" | "--help" => {
                println!("{}", help());
                return Ok(());
            }
            _ => return Err(unexpected.into()),
        }
    }
    params.validate()?;
    let radius = build.radius()?;
    let radius_flag = build.radius;
    params.radius = radius;
    if particles_file.is_some() && (emit.is_some() || starts.is_some()) {
        bail!("give either --particles or --emit (with --starts), not both");
    }
    if let Some(n) = emit {
        flags::particles_fit("--emit", n)?;
        // Where memory is not known up front (not Linux), a count whose particles cannot be
        // held is the error here, not an abort in the harness's emitters (which reserve as
        // much; untouched pages cost nothing).
        drop(octoproxy_cpu::emit::reserve_particles(n).with_context(|| format!("--emit {n}"))?);
    }
    if let Some(name) = &builtin_name {
        let path = PathBuf::from(name);
        if SceneFile::of(&path).is_some() {
            if !meshes.is_empty() {
                bail!("give either --mesh or --scene, not both");
            }
            if starts.is_some_and(|s| s != Start::Outside) {
                bail!(
                    "--starts with a scene file: only outside (particles start outside every part)"
                );
            }
            let build = if SceneFile::of(&path) == Some(SceneFile::Baked) {
                if build.any() {
                    bail!(
                        "--dmin/--dmax/--epsilon/--lut-depth shape a bake; {} is baked already",
                        path.display()
                    );
                }
                None
            } else {
                Some(build.params()?)
            };
            let mut scene = Instanced::from_file(&path, build.as_ref(), radius_flag)?;
            scene.prepare().with_context(|| {
                format!(
                    "{}: the scene at 0 s, before the first step",
                    path.display()
                )
            })?;
            params.radius = scene.radius();
            let pairs = pair_flags.params(&params)?;
            return check_scene(
                scene,
                &path,
                particles_file.as_deref(),
                emit,
                seed,
                steps,
                &params,
                pairs.as_ref(),
            );
        }
    }
    let pairs = pair_flags.params(&params)?;
    let mesh_list = match (meshes.is_empty(), &builtin_name) {
        (true, None) => bail!("check needs a scene: --mesh MESH or --scene NAME"),
        (false, Some(_)) => bail!("give either --mesh or --scene, not both"),
        (true, Some(name)) => vec![builtin(name)?],
        (false, None) => scene::load_meshes(&meshes)?,
    };
    let mesh = scenes::merge(&mesh_list);
    let closed = checked_closed(&mesh, "the mesh");
    let baked = scene::bake_meshes(mesh_list, &build.params()?, radius)?;
    let view = baked.view()?;
    if let Some(offset) = &baked.offset {
        return check_radius(
            &view,
            offset,
            &mesh,
            particles_file.as_deref(),
            (starts, emit, seed),
            steps,
            &params,
            pairs.as_ref(),
        );
    }
    let t = Instant::now();
    let gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
    eprintln!(
        "ground truth: {} triangles, {} mesh ({}), BVH in {:.0} ms",
        gt.triangle_count(),
        if closed { "closed" } else { "open" },
        if closed {
            "winding numbers, at step ends and along paths that cross it"
        } else {
            "crossing parity"
        },
        t.elapsed().as_secs_f64() * 1e3
    );
    let mut particles = match &particles_file {
        Some(path) => {
            let cloud = read_particles(path)?;
            let mut ps = cloud.particles;
            let sides = Sides::new(&[MeshRef::from(&mesh)]);
            let counts = sides.assign(&mut ps, cloud.has_side);
            if cloud.has_side {
                eprintln!(
                    "sides: the file's, kept; {} of {} contradict the mesh",
                    counts.contradicting,
                    ps.len()
                );
            } else {
                eprintln!(
                    "sides: from the mesh (nearest surface and winding numbers): {} behind of {}",
                    counts.behind,
                    ps.len()
                );
            }
            let cages = sides.cages(&view, &mut ps, cloud.has_side);
            crate::sim::report_cages(&cages, ps.len());
            ps
        }
        None => {
            let leaf = view.finest_leaf_size();
            let size = view.header().root_size;
            let speeds: Vec<f32> = [0.1 * leaf, leaf, 5.0 * leaf, 0.25 * size, size]
                .iter()
                .map(|d| d / params.dt)
                .collect();
            let refs: Vec<MeshRef<'_>> = baked.meshes.iter().map(MeshRef::from).collect();
            let sides = Sides::new(&refs);
            let starter = Starter {
                view: &view,
                meshes: &refs,
                sides: &sides,
                gt: &gt,
                closed,
            };
            let start = starts.unwrap_or(Start::Outside);
            let n = emit.unwrap_or(20_000);
            let ps = starter.particles(start, n, &speeds, seed);
            let caged = ps.iter().filter(|p| p.is_caged()).count();
            eprintln!(
                "particles: {} started {}{}",
                ps.len(),
                match start {
                    Start::Outside =>
                        "outside the shell, at least two leaf diagonals from the surface",
                    Start::Shell => "within 1.5 leaves of the surface, both sides",
                    Start::Emitted => "from the surface, one leaf in front of their faces",
                    Start::Corners => "a fraction of a leaf from the mesh's vertices",
                },
                if caged > 0 {
                    format!("; {caged} caged in the solid leaves they start in")
                } else {
                    String::new()
                }
            );
            ps
        }
    };
    let t = Instant::now();
    let report = run_check(&view, &gt, &mut particles, steps, &params, closed);
    let secs = t.elapsed().as_secs_f64();
    println!(
        "{} particles × {steps} steps = {} particle-steps in {secs:.1} s ({:.2} µs per checked particle-step)",
        report.particles,
        report.particle_steps,
        secs * 1e6 / report.particle_steps.max(1) as f64
    );
    println!(
        "penetrations: {} ({:.3} per million particle-steps){}",
        report.penetrations,
        report.per_million(),
        if closed {
            format!(
                ", of which {} escaped from inside and {} went through the mesh within a step",
                report.escapes, report.tunnels
            )
        } else {
            String::new()
        }
    );
    println!("NaN or infinite: {}", report.non_finite);
    println!(
        "collisions: {}; steps stopped by the shell rule: {}; by the leaf bound: {}",
        report.collisions, report.blocked_steps, report.bound_hits
    );
    for (i, a, b) in &report.examples {
        println!("  e.g. particle {i}: {a:?} -> {b:?}");
    }
    if report.penetrations > 0 || report.non_finite > 0 {
        bail!(
            "{} penetrations and {} NaN particles",
            report.penetrations,
            report.non_finite
        );
    }
    Ok(())
}

/// The box of the instances' root cubes over a run of `seconds` (sampled at its start, its
/// end and 62 times between, as the animation poses them; the box grown by 10 %), and the
/// finest leaf any of them has there: what the particles of `check --scene` are spread over
/// and their speeds are measured in. An instance hidden (scale 0) at one time counts where it
/// shows at another; a scene hidden throughout is an error.
fn run_extent(inst: &Instanced, seconds: f64) -> Result<(glam::Vec3, glam::Vec3, f32)> {
    use glam::Vec3;
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let mut leaf = f32::INFINITY;
    let samples = if inst.duration() > 0.0 && seconds > 0.0 {
        64
    } else {
        1
    };
    for k in 0..samples {
        let t = seconds * k as f64 / (samples - 1).max(1) as f64;
        let poses: Vec<octoproxy_core::Pose> = match &inst.baked {
            Some(baked) => baked.poses_at(t)?,
            None => inst.scene.instances().iter().map(|i| i.start).collect(),
        };
        for (i, pose) in inst.scene.instances().iter().zip(poses) {
            let live = octoproxy_core::scene::Instance {
                start: pose,
                end: pose,
                ..*i
            };
            if !live.is_active() {
                continue;
            }
            let view = inst.scene.proxies()[i.proxy as usize].view();
            let b = live.swept_box(&view);
            lo = lo.min(b.min);
            hi = hi.max(b.max);
            leaf = leaf.min(view.finest_leaf_size() * pose.scale);
        }
    }
    if !(lo.cmple(hi).all() && leaf.is_finite()) {
        bail!(
            "no instance of the scene shows (every one has scale 0) over the {seconds} s checked"
        );
    }
    let grow = (hi - lo) * 0.05;
    Ok((lo - grow, hi + grow, leaf))
}

/// Whether `mesh` is checked as closed (by winding numbers): closed, and wound consistently
/// (every edge once in each direction). A closed mesh whose neighbours disagree about
/// orientation has no meaningful winding number (a box with one face flipped reads 0.35 to
/// 0.7 deep inside it): it is checked by the parity of crossings, as an open mesh, and a note
/// says so.
pub(crate) fn checked_closed(mesh: &octoproxy_cpu::io::Mesh, what: &str) -> bool {
    if !mesh.is_closed() {
        return false;
    }
    if mesh.is_consistently_oriented() {
        return true;
    }
    eprintln!(
        "note: {what} is closed but its triangles are not wound consistently (neighbours disagree about which way an edge runs): it is checked by crossing parity, as an open mesh"
    );
    false
}

/// `check --scene FILE`: particles stepped through a scene of moving instances on the CPU,
/// every piece of every path checked against each instance's own mesh in its frame at the
/// pose of each moment (`octoproxy_cpu::harness::scene`).
#[allow(clippy::too_many_arguments)]
fn check_scene(
    mut inst: Instanced,
    file: &std::path::Path,
    particles_file: Option<&std::path::Path>,
    emit: Option<usize>,
    seed: u64,
    steps_given: u32,
    params: &StepParams,
    pairs: Option<&octoproxy_core::PairParams>,
) -> Result<()> {
    use glam::Vec3;
    use octoproxy_core::{Backend, ProxyView, SceneSides};
    use octoproxy_cpu::emit::{emit_box, reserve_particles};
    use octoproxy_cpu::harness::scene::{traced_pieces, SceneCheck, Tally};
    use octoproxy_cpu::CpuBackend;

    inst.offsets()?;
    let t = Instant::now();
    let views: Vec<ProxyView<'_>> = inst.scene.proxies().iter().map(|p| p.view()).collect();
    // With a radius, paths are checked against each instance's offset surface (closed), and
    // step ends against its mesh's exact distance.
    let (mut check, near) = match &inst.offsets {
        Some(offsets) => {
            let refs: Vec<MeshRef<'_>> = offsets.iter().map(|o| o.mesh_ref()).collect();
            let truths: Vec<GroundTruth> = inst
                .meshes
                .iter()
                .map(|m| GroundTruth::new(&m[0].positions, &m[0].triangles))
                .collect();
            let diagonals: Vec<f64> = views
                .iter()
                .map(|v| 3f64.sqrt() * v.finest_leaf_size() as f64)
                .collect();
            (
                SceneCheck::new(&refs, &vec![true; refs.len()], &views),
                Some((truths, diagonals)),
            )
        }
        None => {
            for (k, m) in inst.meshes.iter().enumerate() {
                if m[0].is_closed() && !inst.closed[k] {
                    checked_closed(&m[0], &format!("the mesh of proxy {k}"));
                }
            }
            let refs: Vec<MeshRef<'_>> = inst.meshes.iter().map(|m| MeshRef::from(&m[0])).collect();
            (SceneCheck::new(&refs, &inst.closed, &views), None)
        }
    };
    drop(views);
    if near.is_some() {
        eprintln!(
            "ground truth: the offset surfaces of {} proxies at radius {} (closed: winding numbers), and their meshes' exact distance, {:.0} ms",
            check.closed.len(),
            params.radius,
            t.elapsed().as_secs_f64() * 1e3
        );
    } else {
        eprintln!(
            "ground truth: {} meshes ({} closed: winding numbers; the others open: crossing parity), {:.0} ms",
            inst.closed.len(),
            inst.closed.iter().filter(|&&c| c).count(),
            t.elapsed().as_secs_f64() * 1e3
        );
    }
    let duration = inst.duration();
    let steps = if duration > 0.0 && steps_given == 100 {
        flags::animation_steps(file, duration, 0.0, params.dt)?
    } else {
        steps_given
    };
    // Speeds from a tenth of the finest leaf to the whole scene per step, in the box the
    // instances take over the run (one hidden at the start counts where it shows).
    let (lo, hi, leaf) = run_extent(&inst, steps as f64 * params.dt as f64)?;
    let size = (hi - lo).max_element();
    let particles = match particles_file {
        Some(path) => read_particles(path)?.particles,
        None => {
            let n = emit.unwrap_or(20_000);
            let speeds = [0.1 * leaf, leaf, 5.0 * leaf, 0.25 * size, size];
            let mut ps = reserve_particles(n).with_context(|| format!("--emit {n}"))?;
            for (k, s) in speeds.iter().enumerate() {
                let count = n / speeds.len() + (k < n % speeds.len()) as usize;
                ps.extend(
                    emit_box(count, lo, hi, s / params.dt, seed + k as u64)
                        .with_context(|| format!("--emit {n}"))?,
                );
            }
            ps
        }
    };
    let given = particles.len();
    let particles = outside_all(particles, &check, &inst.scene);
    eprintln!(
        "particles: {} of {given} start outside every part (two leaf diagonals from every surface{}); {steps} steps",
        particles.len(),
        if near.is_some() {
            ", the offset surfaces"
        } else {
            ""
        }
    );
    if let Some(pairs) = pairs {
        eprintln!(
            "the particle pass: on (substeps: {}; {} to {} iterations each, by how deep the particles stand); with it every step's end is checked, not the path between",
            crate::flags::substeps_said(params, pairs),
            pairs.iterations,
            pairs.max_iterations
        );
    }
    let mut too_near = 0usize;
    let mut nearest = f64::INFINITY;
    let Some(sides_by_proxy): Option<Vec<Sides>> = inst.sides().into_iter().collect() else {
        bail!("the scene's proxies came without their meshes");
    };
    let (sides, _) = octoproxy_cpu::starting_scene_sides(&inst.scene, &sides_by_proxy, &particles);
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&particles)?;
    cpu.upload_scene_sides(&sides)?;
    check.begin(inst.scene.instances(), &particles);
    // A particle the step flags invalid counts as a failure when it started valid (finite,
    // unflagged): the step made it so.
    let started_valid: Vec<bool> = particles
        .iter()
        .map(|p| {
            Vec3::from_array(p.position).is_finite()
                && Vec3::from_array(p.velocity).is_finite()
                && p.flags & octoproxy_core::FLAG_INVALID == 0
        })
        .collect();
    let mut before = particles;
    let mut tally = Tally::default();
    let mut differ = 0usize;
    let bar = crate::progress::bar(steps as u64, "checking");
    let t = Instant::now();
    for k in 1..=steps {
        let now = k as f64 * params.dt as f64;
        inst.pose_at(now)?;
        inst.prepare()
            .with_context(|| format!("{}: step {k} (to {now:.4} s)", file.display()))?;
        inst.scene.upload_proxies(&mut cpu)?;
        let instances = inst.scene.instances().to_vec();
        let mut after = vec![octoproxy_core::Particle::default(); before.len()];
        let pieces = match pairs {
            Some(pairs) => {
                // The pass's substeps are not replayed: every step's end is checked.
                inst.scene
                    .step_pairs(&mut cpu, params, pairs, false)
                    .map_err(|e| anyhow::anyhow!("{e}"))?;
                cpu.download_particles(&mut after)?;
                vec![Vec::new(); before.len()]
            }
            None => {
                let mut sides = vec![SceneSides::EMPTY; before.len()];
                cpu.download_scene_sides(&mut sides)?;
                cpu.step_scene(&instances, inst.scene.broad_phase(), params, false)?;
                cpu.download_particles(&mut after)?;
                let (pieces, bad) = inst
                    .scene
                    .with_view(|view| traced_pieces(view, &before, &sides, &after, params))?;
                // As `Scene::step` does after a step (it marks instances the step had hidden).
                inst.scene.hold();
                differ += bad.len();
                pieces
            }
        };
        tally.add(&check.step(&instances, &before, &after, Some(&pieces)));
        if let Some((truths, diagonals)) = &near {
            let r = params.radius as f64;
            for p in after
                .iter()
                .filter(|p| p.flags & octoproxy_core::scene::FLAG_CRUSHED == 0)
            {
                for i in instances.iter().filter(|i| i.is_active()) {
                    let k = i.proxy as usize;
                    let l = i.end.to_local(Vec3::from_array(p.position)).to_array();
                    let s = i.end.scale as f64;
                    let d = truths[k].distance_capped(l, 2.0 * r / s) * s;
                    nearest = nearest.min(d);
                    if d < r - diagonals[k] * s {
                        too_near += 1;
                    }
                }
            }
        }
        inst.scene.hold();
        before = after;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let secs = t.elapsed().as_secs_f64();
    println!(
        "{} particles × {steps} steps = {} particle-steps in {secs:.1} s ({:.2} µs per checked particle-step)",
        before.len(),
        tally.particle_steps,
        secs * 1e6 / tally.particle_steps.max(1) as f64
    );
    println!(
        "penetrations: {} (particle-steps too deep on the other side of an instance's mesh, at a step's end or on its path in the instance's frame)",
        tally.penetrations
    );
    println!(
        "collisions: {}; particle-steps crushed between instances (counted, not checked after): {}",
        tally.collisions, tally.crushed
    );
    if tally.swallowed > 0 {
        println!(
            "swallowed: {} particles were inside an instance when it appeared (shown after a step at scale 0; nothing can keep them out, and no side they take is right), and are not checked against it until it appears again",
            tally.swallowed
        );
    }
    if near.is_some() {
        println!(
            "radius {}: the nearest centre to a mesh at a step's end {nearest:.4e}; {too_near} nearer than the radius less a leaf diagonal (too_near)",
            params.radius
        );
    }
    let non_finite = before
        .iter()
        .zip(&started_valid)
        .filter(|(p, &valid)| {
            !Vec3::from_array(p.position).is_finite()
                || (valid && p.flags & octoproxy_core::FLAG_INVALID != 0)
        })
        .count();
    println!(
        "NaN or infinite: {non_finite} (or flagged invalid by the step, having started valid)"
    );
    for e in &tally.examples {
        println!("  e.g. {e}");
    }
    if differ > 0 {
        bail!("{differ} particle-steps of the traced step differ from the step: a bug, please report it");
    }
    if tally.penetrations > 0 || non_finite > 0 || too_near > 0 {
        bail!(
            "{} penetrations, {too_near} centres too near a mesh and {non_finite} NaN particles",
            tally.penetrations
        );
    }
    Ok(())
}

/// `check --radius`: particles of a radius against the proxy of the offset surface, started
/// as `--starts` says relative to that surface (a closed mesh: its outside is outside the
/// band), moved out of the band where they start in it (as `sim` does), and checked against
/// the offset surface (closed: no crossing) and against the mesh itself (no point of any
/// path nearer than the radius less a `dmax` leaf diagonal).
#[allow(clippy::too_many_arguments)]
fn check_radius(
    view: &octoproxy_core::ProxyView<'_>,
    offset: &OffsetSurface,
    mesh: &Mesh,
    particles_file: Option<&Path>,
    (starts, emit, seed): (Option<Start>, Option<usize>, u64),
    steps: u32,
    params: &StepParams,
    pairs: Option<&PairParams>,
) -> Result<()> {
    let t = Instant::now();
    let surface = [offset.mesh_ref()];
    let off_gt = GroundTruth::new(&offset.mesh().positions, &offset.mesh().triangles);
    let mesh_gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
    let sides = Sides::new(&surface);
    eprintln!(
        "ground truth: the offset surface ({} triangles, closed: winding numbers) and the mesh ({} triangles: exact distance) in {:.0} ms",
        off_gt.triangle_count(),
        mesh_gt.triangle_count(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let mut ps = match particles_file {
        Some(path) => read_particles(path)?.particles,
        None => {
            let leaf = view.finest_leaf_size();
            let size = view.header().root_size;
            let speeds: Vec<f32> = [0.1 * leaf, leaf, 5.0 * leaf, 0.25 * size, size]
                .iter()
                .map(|d| d / params.dt)
                .collect();
            let starter = Starter {
                view,
                meshes: &surface,
                sides: &sides,
                gt: &off_gt,
                closed: true,
            };
            starter.particles(
                starts.unwrap_or(Start::Outside),
                emit.unwrap_or(20_000),
                &speeds,
                seed,
            )
        }
    };
    let placed = offset.place(&mut ps, Some(view));
    sides.assign(&mut ps, false);
    let cages = sides.cages(view, &mut ps, false);
    eprintln!(
        "particles: {} ({} moved out of the band, {} could not be)",
        ps.len(),
        placed.moved,
        placed.stuck
    );
    crate::sim::report_cages(&cages, ps.len());
    let clearance = params.radius as f64 - 3f64.sqrt() * view.finest_leaf_size() as f64;
    let t = Instant::now();
    let report = match pairs {
        Some(pairs) => {
            eprintln!(
                "the particle pass: on (substeps: {}; {} to {} iterations each, by how deep the particles stand)",
                crate::flags::substeps_said(params, pairs),
                pairs.iterations,
                pairs.max_iterations
            );
            run_check_pairs(
                view, &off_gt, &mut ps, steps, params, pairs, &mesh_gt, clearance,
            )
        }
        None => run_check_radius(view, &off_gt, &mut ps, steps, params, &mesh_gt, clearance),
    };
    let secs = t.elapsed().as_secs_f64();
    println!(
        "{} particles × {steps} steps = {} particle-steps in {secs:.1} s",
        report.particles, report.particle_steps
    );
    println!(
        "penetrations: {} ({:.3} per million particle-steps), of which {} came nearer the mesh than the radius less a leaf diagonal ({clearance:.4e}) and {} went through the offset surface within a step",
        report.penetrations,
        report.per_million(),
        report.too_near,
        report.tunnels
    );
    println!("NaN or infinite: {}", report.non_finite);
    println!(
        "collisions: {}; steps stopped by the shell rule: {}, by the leaf bound: {}",
        report.collisions, report.blocked_steps, report.bound_hits
    );
    for (i, a, b) in &report.examples {
        println!("  particle {i}: {a:?} -> {b:?}");
    }
    if report.penetrations > 0 {
        bail!("{} penetrations", report.penetrations);
    }
    Ok(())
}
