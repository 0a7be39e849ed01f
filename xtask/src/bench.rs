//! `octoproxy bench`: octoproxy against what users would pick instead, in one process, on
//! the same scenes, particles and step parameters. Writes `target/bench/results.json`, a
//! Markdown table and PNG plots, and prints a summary.
//!
//! The committed run lives in `docs/bench/`, and every benchmark figure in `README.md` and
//! `docs/**.md` is rendered from its `results.json`: between markers such as
//! `<!-- bench:table:summary -->` and `<!-- /bench:table:summary -->`. A run with
//! `--out docs/bench` rewrites those regions; `--docs-only` rewrites them (and `results.md`)
//! from the committed `results.json` without running anything; and a test fails when a region
//! disagrees with its rendering.
//!
//! Beside the mesh scenes, the scene cases (module `instances`): particles raining through a
//! grid of 1 to 1,000 instances of two shared proxies, all still and then half of them moving,
//! and the scene API's cost on a static scene against the plain step.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::Vec3;
use octoproxy_core::{initial_side, Backend, Particle, ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::harness::{deep_on_the_other_side, run_check};
use octoproxy_cpu::io::{load_mesh, Mesh};
use octoproxy_cpu::scenes::subdivide;
use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef};
use octoproxy_tests::baselines::{
    parry::ParryTriMesh, sdf_grid::SdfGrid, triangle_octree::TriangleOctree, Method,
};
use octoproxy_wgpu::WgpuBackend;
use rayon::prelude::*;

use crate::flags;
use crate::plot;

/// The method name of the split GPU step's rows (`WgpuBackend::set_split_step`), timed at the
/// default workgroup size beside `octoproxy-wgpu` in the mixed band.
pub const SPLIT_METHOD: &str = "octoproxy-wgpu-split";

mod instances;
mod particles;
mod profile;

const USAGE: &str = "\
usage: octoproxy bench [--quick] [--backends cpu,wgpu] [--scenes S,S...] [--particles N,N...]

  --quick          one scene (the bunny), 100k particles, every method: a few minutes
  --backends L     which of cpu, wgpu to run (default: both; wgpu only when an adapter exists)
  --scenes L       of bunny, nefertiti, ogre, beast, nefertiti-1.6m, nefertiti-6.4m, their
                   rain cases (bunny-rain, ...: particles falling through the scene at up
                   to its size per step), the instance cases instances-1, instances-10, instances-100, instances-1000,
                   and the cases of particles that collide with each other, particles-pile
                   and particles-cloud (default: all)
  --particles L    particle counts (default 10000,100000,1000000,4000000, and 3M and 10M on a
                   hardware GPU; the instance cases 1000000, the particle cases 100000 and
                   1000000, or 100000 with --quick; suffixes k and m work)
  --gpu-particles L
                   the mesh scenes' counts on a hardware GPU alone (default 3000000,10000000
                   when --particles is not given, else none)
  --steps N        timed steps per case (default: about 4M particle-steps per case, 2..50,
                   on the CPU; about 20M, 10..100, on a GPU)
  --gpu-repeats N  each GPU time is the median of N timed runs from the same start (default 1)
  --workgroup-sizes L
                   also time the plain GPU step and its floor at these workgroup sizes (powers
                   of two up to 256; the plain step's default is 256, lowered to the
                   device's limit): the sweep's rows
  --meshes DIR     where the meshes are (default: ../shared/meshes beside the repository)
  --no-scene-api   skip the scene API's comparison on the mesh scenes (on NVIDIA's Vulkan
                   driver its GPU kernel took 2.5 to 4 minutes to build)
  --samples N      particles in each penetration check (default 2000; 60 steps each)
  --out DIR        where results go (default target/bench); with docs/bench, the committed
                   results, it also rewrites the figures in README.md and docs/
  --docs-only      run nothing: rewrite docs/bench/results.md and the figures in README.md
                   and docs/ from the committed docs/bench/results.json

Scenes come from ../shared/meshes; the mesh scenes step under gravity scaled to the scene
(60 steps add a tenth of a depth-8 leaf per step), each CPU time the median of 3 runs, the
methods taking turns, and octoproxy's steps are profiled (leaves per step, the cost of each
kind of step) at 1M particles. Methods: octoproxy-cpu, octoproxy-cpu-nolut,
triangle-octree, parry3d, sdf-grid and floor on the CPU; octoproxy-wgpu and floor on the GPU;
on one scene (nefertiti, else the first), the same proxy as a one-instance static scene through
the scene API (octoproxy-cpu-scene-api, octoproxy-wgpu-scene-api). An instance case places
N instances of Spot and the rocker arm on a grid and times octoproxy through Scene::step with
every instance still, then with half of them moving. The particle cases time
Backend::step_pairs (the particle-particle pass and the march at a radius) on a dense pile and
a sparse cloud, the CPU's sort, neighbour loop and march apart.";

/// The mesh scenes: one proxy each, every method.
const MESH_SCENES: [&str; 6] = [
    "bunny",
    "nefertiti",
    "ogre",
    "beast",
    "nefertiti-1.6m",
    "nefertiti-6.4m",
];
/// The rain case of each mesh scene ([`profile::rain_particles`]).
const RAIN_SCENES: [&str; 6] = [
    "bunny-rain",
    "nefertiti-rain",
    "ogre-rain",
    "beast-rain",
    "nefertiti-1.6m-rain",
    "nefertiti-6.4m-rain",
];
const _: () = assert!(RAIN_SCENES.len() == MESH_SCENES.len());
const DT: f32 = 1.0 / 60.0;
/// Speed bands, in depth-8 leaves per step.
const BANDS: [(&str, f32, f32); 3] = [("slow", 0.1, 0.5), ("medium", 0.5, 2.0), ("fast", 2.0, 5.0)];

struct Opts {
    quick: bool,
    cpu: bool,
    wgpu: bool,
    scenes: Vec<String>,
    particles: Vec<usize>,
    steps: Option<u32>,
    samples: usize,
    out: PathBuf,
    /// Rewrite the docs from the committed results instead of running.
    docs_only: bool,
    /// Particle counts run on a hardware GPU only.
    gpu_only: Vec<usize>,
    /// Particle counts of the instance cases.
    instance_particles: Vec<usize>,
    /// Particle counts of the cases of particles that collide with each other.
    pair_particles: Vec<usize>,
    /// Whether `--backends` named wgpu (the scene cases run on a software adapter only then).
    wgpu_asked: bool,
    /// Timed runs per GPU time, of which the median counts.
    gpu_repeats: u32,
    /// Workgroup sizes the plain GPU step is also timed at.
    workgroup_sizes: Vec<u32>,
    /// The shared meshes' folder.
    meshes: PathBuf,
    /// Skip the scene API's comparison (its GPU kernel takes minutes to build on some drivers).
    no_scene_api: bool,
}

/// Every scene, mesh scenes first.
fn all_scenes() -> impl Iterator<Item = &'static str> {
    MESH_SCENES
        .into_iter()
        .chain(RAIN_SCENES)
        .chain(instances::SCENES)
        .chain(particles::SCENES)
}

fn parse_count(s: &str) -> Result<usize> {
    let s = s.trim().to_ascii_lowercase();
    let (num, mul) = if let Some(x) = s.strip_suffix('m') {
        (x, 1_000_000.0)
    } else if let Some(x) = s.strip_suffix('k') {
        (x, 1_000.0)
    } else {
        (s.as_str(), 1.0)
    };
    let v: f64 = num
        .parse()
        .with_context(|| format!("--particles: {s:?} is not a count"))?;
    let n = v * mul;
    if !(1.0..=1e9).contains(&n) {
        bail!("--particles: {s:?} is out of range (1 to 1e9)");
    }
    Ok(n as usize)
}

fn parse(args: Vec<std::ffi::OsString>) -> Result<Option<Opts>> {
    let mut o = Opts {
        quick: false,
        cpu: true,
        wgpu: true,
        scenes: Vec::new(),
        particles: Vec::new(),
        steps: None,
        samples: 2000,
        out: PathBuf::from("target/bench"),
        docs_only: false,
        gpu_only: Vec::new(),
        instance_particles: Vec::new(),
        pair_particles: Vec::new(),
        wgpu_asked: false,
        gpu_repeats: 1,
        workgroup_sizes: Vec::new(),
        meshes: meshes_dir(),
        no_scene_api: false,
    };
    let mut gpu_only_given = false;
    let mut p = lexopt::Parser::from_args(args);
    while let Some((name, _)) = flags::next_option(&mut p)? {
        match name.as_str() {
            "--quick" => o.quick = true,
            "--backends" => {
                let list = flags::string(&mut p, "--backends")?;
                o.cpu = false;
                o.wgpu = false;
                for b in list.split(',') {
                    match b.trim() {
                        "cpu" => o.cpu = true,
                        "wgpu" | "gpu" => (o.wgpu, o.wgpu_asked) = (true, true),
                        other => bail!("--backends: expected cpu and/or wgpu, got {other:?}"),
                    }
                }
            }
            "--scenes" => {
                for s in flags::string(&mut p, "--scenes")?.split(',') {
                    let s = s.trim();
                    if !all_scenes().any(|a| a == s) {
                        bail!(
                            "--scenes: unknown scene {s:?} (scenes: {})",
                            all_scenes().collect::<Vec<_>>().join(", ")
                        );
                    }
                    o.scenes.push(s.to_string());
                }
            }
            "--particles" => {
                for s in flags::string(&mut p, "--particles")?.split(',') {
                    o.particles.push(parse_count(s)?);
                }
            }
            "--steps" => {
                let n: u32 = flags::number(&mut p, "--steps")?;
                if !(1..=10_000).contains(&n) {
                    bail!("--steps: expected 1 to 10000, got {n}");
                }
                o.steps = Some(n);
            }
            "--samples" => o.samples = flags::number(&mut p, "--samples")?,
            "--gpu-particles" => {
                let list = flags::string(&mut p, "--gpu-particles")?;
                o.gpu_only = list
                    .split(',')
                    .filter(|s| !s.trim().is_empty())
                    .map(parse_count)
                    .collect::<Result<_>>()?;
                gpu_only_given = true;
            }
            "--gpu-repeats" => {
                let n: u32 = flags::number(&mut p, "--gpu-repeats")?;
                if !(1..=15).contains(&n) {
                    bail!("--gpu-repeats: expected 1 to 15, got {n}");
                }
                o.gpu_repeats = n;
            }
            "--workgroup-sizes" => {
                for s in flags::string(&mut p, "--workgroup-sizes")?.split(',') {
                    let n: u32 = s.trim().parse().map_err(|_| {
                        anyhow::anyhow!("--workgroup-sizes: expected numbers, got {s:?}")
                    })?;
                    if !n.is_power_of_two() || n > 256 {
                        bail!("--workgroup-sizes: expected powers of two up to 256, got {n}");
                    }
                    o.workgroup_sizes.push(n);
                }
            }
            "--meshes" => o.meshes = flags::path(&mut p, "--meshes")?,
            "--no-scene-api" => o.no_scene_api = true,
            "--out" | "-o" => o.out = flags::path(&mut p, "--out")?,
            "--docs-only" => o.docs_only = true,
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(None);
            }
            other => bail!("unknown option {other} (see `octoproxy bench --help`)"),
        }
    }
    if o.scenes.is_empty() {
        o.scenes = if o.quick {
            vec!["bunny".into()]
        } else {
            all_scenes().map(|s| s.to_string()).collect()
        };
    }
    // The instance cases: the counts asked for, else a million particles (the issue's
    // count), or the quick run's count.
    o.instance_particles = if !o.particles.is_empty() {
        o.particles.clone()
    } else if o.quick {
        vec![100_000]
    } else {
        vec![1_000_000]
    };
    // The particle cases: the counts asked for, else 100k and 1M (the issue's), or 100k.
    o.pair_particles = if !o.particles.is_empty() {
        o.particles.clone()
    } else if o.quick {
        vec![100_000]
    } else {
        vec![100_000, 1_000_000]
    };
    if o.particles.is_empty() {
        o.particles = if o.quick {
            vec![100_000]
        } else {
            vec![10_000, 100_000, 1_000_000, 4_000_000]
        };
        if !o.quick && !gpu_only_given {
            // A hardware GPU also runs the sizes it is made for (not the CPU methods).
            o.gpu_only = vec![3_000_000, 10_000_000];
        }
    }
    if o.quick && o.samples == 2000 {
        o.samples = 500;
    }
    Ok(Some(o))
}

/// One scene: its mesh, closed or not, and its ground truth.
struct SceneData {
    mesh: Mesh,
    closed: bool,
}

fn meshes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/meshes")
}

fn load_scene(name: &str, dir: &Path) -> Result<SceneData> {
    let (file, closed, subdivisions) = match name {
        "bunny" => ("stanford-bunny.obj.gz", false, 0),
        "nefertiti" => ("nefertiti.obj.gz", true, 0),
        "ogre" => ("ogre.obj.gz", false, 0),
        "beast" => ("beast.obj.gz", false, 0),
        "nefertiti-1.6m" => ("nefertiti.obj.gz", true, 2),
        "nefertiti-6.4m" => ("nefertiti.obj.gz", true, 3),
        _ => bail!("unknown scene {name}"),
    };
    let path = dir.join(file);
    if !path.exists() {
        bail!(
            "the benchmark scenes come from {} (--meshes), and {} is not there (the bench needs those meshes)",
            dir.display(),
            path.display()
        );
    }
    let (mut mesh, _) = load_mesh(&path)?;
    for _ in 0..subdivisions {
        mesh = subdivide(&mesh);
    }
    Ok(SceneData { mesh, closed })
}

/// One line of results.
#[derive(Clone, Debug)]
pub struct Row {
    pub scene: String,
    pub triangles: usize,
    pub particles: usize,
    pub method: String,
    pub backend: &'static str,
    pub build_ms: f64,
    pub memory_bytes: usize,
    pub ns_per_particle_step: f64,
    pub ratio_to_floor: f64,
    pub penetrations_per_million: f64,
    pub band: &'static str,
    /// Instances in the scene (0: a mesh scene, its proxy stepped alone), and how many of
    /// them move.
    pub instances: usize,
    pub moving: usize,
    /// A moving case's time over the same instances still (NaN elsewhere).
    pub ratio_to_static: f64,
    /// The scene API's time over the plain step's on the same proxy and particles (NaN
    /// elsewhere).
    pub ratio_to_plain: f64,
    /// A particle case's substeps per step (0 elsewhere): its rows time the step with the
    /// particle–particle pass.
    pub substeps: u32,
    /// A particle case's Jacobi iterations per substep on average (0 elsewhere, and in runs
    /// before a step took them from how deep its particles stand).
    pub iterations: u32,
    /// A GPU row's workgroup size (invocations per workgroup of the plain step; 0 on the CPU
    /// rows and in runs that predate the sweep).
    pub workgroup_size: u32,
    /// A row of the workgroup-size sweep (`--workgroup-sizes`): the plain GPU step or its
    /// floor at a size other than the backend's default, which the mesh scenes' rows use.
    pub sweep: bool,
    /// The fastest and slowest of the timed runs whose median `ns_per_particle_step` is (NaN
    /// where one run was timed).
    pub ns_min: f64,
    pub ns_max: f64,
}

impl Row {
    /// A row of the mesh scenes' table: one proxy, stepped by `Backend::step` (not an
    /// instance case, nor the scene API's comparison).
    pub fn is_mesh_case(&self) -> bool {
        self.instances == 0
            && self.substeps == 0
            && !self.method.ends_with(instances::SCENE_API)
            && !self.sweep
    }

    /// Milliseconds per step of all the row's particles.
    pub fn ms_per_step(&self) -> f64 {
        self.ns_per_particle_step * self.particles as f64 * 1e-6
    }
}

/// Particles spread through the root box, random directions, speeds in `bands` (depth-8
/// leaves per step), sides from the proxy.
fn make_particles(
    view: &ProxyView<'_>,
    n: usize,
    bands: &[(f32, f32)],
    seed: u64,
) -> Vec<Particle> {
    let root = view.root_aabb();
    let leaf8 = view.header().root_size / 256.0;
    (0..n)
        .into_par_iter()
        .chunks(4096)
        .flat_map_iter(|idx| {
            let mut rng = Rng::new(seed ^ (idx[0] as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            idx.into_iter()
                .map(|i| {
                    let p = Vec3::new(
                        rng.range(root.min.x, root.max.x),
                        rng.range(root.min.y, root.max.y),
                        rng.range(root.min.z, root.max.z),
                    );
                    let (lo, hi) = bands[i % bands.len()];
                    let speed = rng.range(lo, hi) * leaf8 / DT;
                    let mut q = Particle::new(p.to_array(), (rng.unit_vector() * speed).to_array());
                    q.side = initial_side(view, q.position);
                    q
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// Penetrations per million particle-steps of a baseline method, by the rules of the
/// campaigns' harness ([`run_check`]) on the pieces of its path that the method traces: a
/// particle counts once it ends a step farther than `tol` from the surface on the other side
/// from where it started (for a closed mesh by the exact winding number, or when a piece of its
/// path went that deep through the mesh; for an open mesh by the parity of the crossings along
/// its path). Each particle counts once at most.
fn penetration_rate(
    gt: &GroundTruth,
    closed: bool,
    tol: f32,
    start: &[Particle],
    steps: u32,
    method: &dyn Method,
    params: &StepParams,
) -> f64 {
    let tol = tol as f64;
    let bad: u64 = start
        .par_iter()
        .map(|p0| {
            let mut p = *p0;
            let inside = closed && gt.is_inside(p.position);
            let mut crossings = 0u64;
            let mut tunnel = false;
            for _ in 0..steps {
                method.step_traced(&mut p, params, &mut |a, b| {
                    if a == b || tunnel {
                        return;
                    }
                    let k = gt.segment_crossings(a.to_array(), b.to_array());
                    if !closed {
                        crossings += k as u64;
                    } else if k > 0 {
                        tunnel = deep_on_the_other_side(gt, a, b, inside, tol).is_some();
                    }
                });
                if !p.position.iter().all(|c| c.is_finite()) {
                    return 0;
                }
                let far = gt.distance_capped(p.position, 2.0 * tol) > tol;
                let other = if closed {
                    gt.is_inside(p.position) != inside
                } else {
                    crossings % 2 == 1
                };
                if tunnel || (far && other) {
                    return 1;
                }
            }
            0
        })
        .sum();
    bad as f64 * 1e6 / (start.len() as f64 * steps as f64).max(1.0)
}

/// Penetrations per million particle-steps of octoproxy's step on `view`: the harness the
/// campaigns use ([`run_check`]), every piece of each particle's traced path against exact
/// ground truth (winding numbers for a closed mesh, paths through it included; the crossing
/// parity along the path for an open one).
fn octo_penetration_rate(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    closed: bool,
    start: &[Particle],
    steps: u32,
    params: &StepParams,
) -> f64 {
    let mut ps = start.to_vec();
    run_check(view, gt, &mut ps, steps, params, closed).per_million()
}

/// Times `steps` steps of `run` over a copy of `particles`, after one untimed step (as every
/// method gets): nanoseconds per particle-step.
fn time_steps(
    particles: &[Particle],
    steps: u32,
    run: &mut dyn FnMut(&mut Vec<Particle>) -> Result<()>,
) -> Result<f64> {
    let mut ps = particles.to_vec();
    run(&mut ps)?;
    let t = Instant::now();
    for _ in 0..steps {
        run(&mut ps)?;
    }
    Ok(t.elapsed().as_secs_f64() * 1e9 / (particles.len() as f64 * steps as f64))
}

/// Shows what the bench is doing on its bar; where the bar is hidden (stderr is no
/// terminal: a log, the device check), as a line with the seconds since the bar began.
fn say(bar: &indicatif::ProgressBar, message: impl Into<String>) {
    let message = message.into();
    if bar.is_hidden() {
        eprintln!("[{:6.1} s] {message}", bar.elapsed().as_secs_f64());
    }
    bar.set_message(message);
}

/// Nanoseconds per particle-step of repeated timed runs: the median, and the fastest and
/// slowest run.
#[derive(Clone, Copy, Debug)]
struct Timing {
    median: f64,
    min: f64,
    max: f64,
}

/// Timed runs of each CPU method per case, taking turns: each time is their median.
const ROUNDS: usize = 3;

impl Timing {
    /// The median, fastest and slowest of `times` (NaN for none).
    fn of(times: &[f64]) -> Timing {
        let mut t = times.to_vec();
        t.sort_by(f64::total_cmp);
        if t.is_empty() {
            return Timing {
                median: f64::NAN,
                min: f64::NAN,
                max: f64::NAN,
            };
        }
        Timing {
            median: t[t.len() / 2],
            min: t[0],
            max: t[t.len() - 1],
        }
    }

    /// `row` with the median as its time and the runs' range.
    fn on(self, mut row: Row) -> Row {
        row.ns_per_particle_step = self.median;
        if self.max > self.min {
            (row.ns_min, row.ns_max) = (self.min, self.max);
        }
        row
    }
}

/// How long a hardware GPU steps before it is timed: its clocks drop while it idles (during
/// the CPU's penetration checks and the uploads), and steps timed cold time them rising.
const GPU_WARM_UP: std::time::Duration = std::time::Duration::from_millis(150);

/// Warms a hardware GPU up for [`GPU_WARM_UP`] with the floor's kernel on the particles it
/// holds (which moves them: upload them again before timing anything that depends on where
/// they are).
pub fn warm_gpu(g: &mut WgpuBackend, params: &StepParams) -> Result<()> {
    if g.is_software() {
        return Ok(());
    }
    let warm = Instant::now();
    while warm.elapsed() < GPU_WARM_UP {
        g.integrate_only(params, 10)?;
        g.wait()?;
    }
    Ok(())
}

/// `steps` GPU steps of `particles` (with `floor`, the floor's kernel: integration alone),
/// after a warm-up ([`warm_gpu`]) and one untimed step: nanoseconds per particle-step,
/// the median of `repeats` timed runs, each from the same start. A run whose parts take
/// seconds is reported on stderr.
fn time_gpu(
    g: &mut WgpuBackend,
    particles: &[Particle],
    params: &StepParams,
    steps: u32,
    repeats: u32,
    floor: bool,
) -> Result<Timing> {
    let run = |g: &mut WgpuBackend, steps| {
        if floor {
            g.integrate_only(params, steps)
        } else {
            g.step(params, steps)
        }
    };
    g.upload_particles(particles)?;
    warm_gpu(g, params)?;
    let mut times = Vec::new();
    for k in 0..repeats.max(1) {
        let t0 = Instant::now();
        g.upload_particles(particles)?;
        run(g, 1)?;
        g.wait()?;
        let t = Instant::now();
        run(g, steps)?;
        g.wait()?;
        let (prepare, timed) = (t - t0, t.elapsed());
        if (prepare + timed).as_secs_f64() > 2.0 {
            eprintln!(
                "  slow run {k} of {} particles ({}, workgroups of {}): upload and first step \
                 {:.2} s, {steps} timed steps {:.2} s",
                particles.len(),
                if floor { "floor" } else { "step" },
                g.workgroup_size(),
                prepare.as_secs_f64(),
                timed.as_secs_f64()
            );
        }
        times.push(timed.as_secs_f64() * 1e9 / (particles.len() as f64 * steps as f64));
    }
    Ok(Timing::of(&times))
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    format!(
        "{cpu}, {} threads, {}",
        rayon::current_num_threads(),
        std::env::consts::OS
    )
}

/// Today's date (UTC) as YYYY-MM-DD, from the system clock.
fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    // Days to civil date (Howard Hinnant's algorithm).
    let z = (secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!("{y:04}-{m:02}-{d:02}")
}

pub fn run(args: Vec<std::ffi::OsString>) -> Result<()> {
    let Some(o) = parse(args)? else { return Ok(()) };
    if o.docs_only {
        return docs::refresh_from_committed();
    }
    std::fs::create_dir_all(&o.out).with_context(|| format!("creating {}", o.out.display()))?;
    let params = StepParams::default();
    let mut gpu = if o.wgpu {
        match WgpuBackend::new() {
            Ok(g) => {
                eprintln!("wgpu: {}", g.description());
                Some(g)
            }
            Err(e) if !o.cpu => bail!("--backends wgpu: no GPU adapter ({e})"),
            Err(e) => {
                eprintln!("wgpu: skipped ({e})");
                None
            }
        }
    } else {
        None
    };
    let gpu_extra = if gpu.as_ref().is_some_and(|g| !g.is_software()) {
        o.gpu_only.len()
    } else {
        0
    };
    if gpu.as_ref().is_some_and(|g| g.is_software()) && !o.gpu_only.is_empty() {
        eprintln!("wgpu: a software adapter; skipping the GPU-only sizes (3M, 10M particles)");
    }
    // The mesh scenes in the order asked, each once: (the mesh, its recipe case, its rain
    // case), so that a mesh asked for both is baked once.
    let mut mesh_scenes: Vec<(&'static str, bool, bool)> = Vec::new();
    for s in &o.scenes {
        let (base, rain) = match s.strip_suffix(profile::RAIN) {
            Some(b) => (b, true),
            None => (s.as_str(), false),
        };
        let Some(base) = MESH_SCENES.iter().copied().find(|m| *m == base) else {
            continue;
        };
        match mesh_scenes.iter_mut().find(|m| m.0 == base) {
            Some(m) if rain => m.2 = true,
            Some(m) => m.1 = true,
            None => mesh_scenes.push((base, !rain, rain)),
        }
    }
    let pair_scenes: Vec<&String> = o.scenes.iter().filter(|s| particles::is_case(s)).collect();
    let instance_scenes: Vec<(&String, usize)> = o
        .scenes
        .iter()
        .filter_map(|s| Some((s, instances::instance_count(s)?)))
        .collect();
    // The scene cases take minutes on a software adapter (a CPU emulating a GPU): there they
    // run only when asked for.
    let software = gpu.as_ref().is_some_and(|g| g.is_software());
    let gpu_scenes = !software || o.wgpu_asked;
    if software && !o.wgpu_asked {
        eprintln!(
            "wgpu: a software adapter; the scene cases (instances, the scene API) run on it only with --backends wgpu"
        );
    }
    let total_cases = mesh_scenes
        .iter()
        .map(|m| 1 + (usize::from(m.1) + usize::from(m.2)) * (o.particles.len() + gpu_extra + 1))
        .sum::<usize>()
        + instance_scenes.len() * (o.instance_particles.len() + 1)
        + usize::from(!instance_scenes.is_empty())
        + pair_scenes.len() * o.pair_particles.len()
        + usize::from(!pair_scenes.is_empty());
    // The scene API's comparison runs on one scene: nefertiti, else the run's first.
    let api_scene = mesh_scenes
        .iter()
        .filter(|m| m.1)
        .find(|m| m.0 == "nefertiti")
        .or(mesh_scenes.iter().find(|m| m.1))
        .map(|m| m.0.to_string());
    // The profile of leaves per step runs at 1M particles, else at the run's largest count.
    let profile_n = if o.particles.contains(&1_000_000) {
        1_000_000
    } else {
        o.particles.iter().copied().max().unwrap_or(0)
    };
    let mut profiles = Vec::new();
    let bar = crate::progress::bar(total_cases as u64, "bench");
    let mut rows: Vec<Row> = Vec::new();
    for (name, recipe, rain) in mesh_scenes {
        say(&bar, format!("{name}: loading"));
        let scene = load_scene(name, &o.meshes)?;
        let (positions, triangles) = (&scene.mesh.positions, &scene.mesh.triangles);
        let tris = triangles.len();
        say(&bar, format!("{name}: building"));
        let t = Instant::now();
        let (words, _) =
            bake(&[MeshRef::from(&scene.mesh)], &BuildParams::default(), &()).context("baking")?;
        let bake_ms = t.elapsed().as_secs_f64() * 1e3;
        let view = ProxyView::new(&words)?;
        let proxy_bytes = words.len() * 4;
        let mut methods: Vec<(Box<dyn Method>, f64)> = Vec::new();
        if o.cpu {
            let t = Instant::now();
            let m = TriangleOctree::new(positions, triangles, 10, 16);
            methods.push((Box::new(m), t.elapsed().as_secs_f64() * 1e3));
            let t = Instant::now();
            match ParryTriMesh::new(positions, triangles) {
                Ok(m) => methods.push((Box::new(m), t.elapsed().as_secs_f64() * 1e3)),
                Err(e) => eprintln!("{name}: parry3d skipped: {e}"),
            }
            let t = Instant::now();
            let m = SdfGrid::new(positions, triangles, proxy_bytes, scene.closed);
            methods.push((Box::new(m), t.elapsed().as_secs_f64() * 1e3));
        }
        bar.inc(1);

        let gt = GroundTruth::new(positions, triangles);
        let tol = view.finest_leaf_size() * 3f32.sqrt();
        let all_bands: Vec<(f32, f32)> = BANDS.iter().map(|b| (b.1, b.2)).collect();
        let lut_view = view;
        let nolut_view = view.without_lut();
        let mut cpu = CpuBackend::new();
        cpu.upload_proxy(&words)?;
        if let Some(g) = gpu.as_mut() {
            g.upload_proxy(&words)?;
        }
        // Both cases step with the recipe's gravity, scaled to the scene.
        let params = profile::recipe_params(&view);
        for (rain_case, asked) in [(false, recipe), (true, rain)] {
            if !asked {
                continue;
            }
            let case_scene = if rain_case {
                format!("{name}{}", profile::RAIN)
            } else {
                name.to_string()
            };
            let check_steps = 60;
            // Penetrations, per method, on a sample.
            say(&bar, format!("{case_scene}: penetration checks"));
            // The guarantee is for particles that start outside the surface shell: more than one
            // dmax-leaf diagonal from the surface. Closer in, a particle takes the side of its
            // leaf's mean plane, which a curved surface may contradict by a hair.
            let mut sample = if rain_case {
                profile::rain_particles(&view, o.samples * 2, check_steps, 99)
            } else {
                make_particles(&view, o.samples * 2, &all_bands, 99)
            };
            sample.retain(|p| gt.distance_capped(p.position, 2.0 * tol as f64) > tol as f64);
            sample.truncate(o.samples);
            let pen_octo =
                octo_penetration_rate(&lut_view, &gt, scene.closed, &sample, check_steps, &params);
            let mut pen_methods = Vec::new();
            for (m, _) in &methods {
                pen_methods.push(penetration_rate(
                    &gt,
                    scene.closed,
                    tol,
                    &sample,
                    check_steps,
                    m.as_ref(),
                    &params,
                ));
            }
            bar.inc(1);

            let largest = *o.particles.iter().max().unwrap_or(&0);
            let hardware = gpu.as_ref().is_some_and(|g| !g.is_software());
            let gpu_only: Vec<usize> = if hardware {
                o.gpu_only.clone()
            } else {
                Vec::new()
            };
            let counts: Vec<(usize, bool)> = o
                .particles
                .iter()
                .map(|&n| (n, o.cpu))
                .chain(gpu_only.iter().map(|&n| (n, false)))
                .collect();
            for (n, run_cpu) in counts {
                say(&bar, format!("{case_scene}: {n} particles"));
                let steps = o
                    .steps
                    .unwrap_or(((4_000_000 / n.max(1)) as u32).clamp(2, 50));
                // The mixed case, then (at the largest count) each speed band alone.
                let mut cases: Vec<(&'static str, Vec<(f32, f32)>)> = if rain_case {
                    vec![("rain", Vec::new())]
                } else {
                    vec![("mixed", all_bands.clone())]
                };
                if n == largest && run_cpu && !rain_case {
                    cases.extend(BANDS.iter().map(|b| (b.0, vec![(b.1, b.2)])));
                }
                for (band, bands) in cases {
                    let particles = if rain_case {
                        profile::rain_particles(&view, n, steps, 7)
                    } else {
                        make_particles(&view, n, &bands, 7)
                    };
                    // Every method's case: the recipe's mixed speeds, or the rain.
                    let full = band == "mixed" || band == "rain";
                    let row = |method: &str,
                               backend: &'static str,
                               build_ms: f64,
                               memory: usize,
                               ns: f64,
                               pen: f64| Row {
                        scene: case_scene.clone(),
                        triangles: tris,
                        particles: n,
                        method: method.to_string(),
                        backend,
                        build_ms,
                        memory_bytes: memory,
                        ns_per_particle_step: ns,
                        ratio_to_floor: f64::NAN,
                        penetrations_per_million: pen,
                        band,
                        instances: 0,
                        moving: 0,
                        ratio_to_static: f64::NAN,
                        ratio_to_plain: f64::NAN,
                        substeps: 0,
                        iterations: 0,
                        workgroup_size: 0,
                        ns_min: f64::NAN,
                        ns_max: f64::NAN,
                        sweep: false,
                    };
                    let scene_api =
                        band == "mixed" && !o.no_scene_api && api_scene.as_deref() == Some(name);
                    let mut case_rows = Vec::new();
                    if run_cpu {
                        // Every method gets one untimed step first; octoproxy's leaf hints are
                        // warm after it, as they are in any simulation after its first step. Each
                        // time is the median of ROUNDS runs, the methods taking turns.
                        let per_step = |t: Instant| {
                            t.elapsed().as_secs_f64() * 1e9 / (n as f64 * steps as f64)
                        };
                        let others = if full { methods.len() } else { 0 };
                        let mut times: Vec<Vec<f64>> = vec![Vec::new(); 4 + others];
                        const FLOOR: usize = 0;
                        const OCTO: usize = 1;
                        const API: usize = 2;
                        const NOLUT: usize = 3;
                        for _ in 0..ROUNDS {
                            cpu.upload_particles(&particles)?;
                            cpu.integrate_only(&params, 1)?;
                            let t = Instant::now();
                            cpu.integrate_only(&params, steps)?;
                            times[FLOOR].push(per_step(t));
                            cpu.upload_particles(&particles)?;
                            cpu.step(&params, 1)?;
                            let t = Instant::now();
                            cpu.step(&params, steps)?;
                            times[OCTO].push(per_step(t));
                            if scene_api {
                                times[API].push(instances::time_scene_api(
                                    &mut cpu, &words, &particles, steps, &params,
                                )?);
                            }
                            if !full {
                                continue;
                            }
                            cpu.set_use_lut(false);
                            cpu.upload_particles(&particles)?;
                            cpu.step(&params, 1)?;
                            let t = Instant::now();
                            cpu.step(&params, steps)?;
                            times[NOLUT].push(per_step(t));
                            cpu.set_use_lut(true);
                            for (k, (m, _)) in methods.iter().enumerate() {
                                times[4 + k].push(time_steps(&particles, steps, &mut |ps| {
                                    ps.par_iter_mut()
                                        .with_min_len(256)
                                        .for_each(|p| m.step(p, &params));
                                    Ok(())
                                })?);
                            }
                        }
                        let timing = |k: usize| Timing::of(&times[k]);
                        case_rows.push(timing(FLOOR).on(row(
                            "floor",
                            "cpu",
                            0.0,
                            0,
                            0.0,
                            f64::NAN,
                        )));
                        let octo = timing(OCTO).on(row(
                            "octoproxy-cpu",
                            "cpu",
                            bake_ms,
                            proxy_bytes,
                            0.0,
                            pen_octo,
                        ));
                        let octo_ns = octo.ns_per_particle_step;
                        case_rows.push(octo);
                        if scene_api {
                            let mut r = timing(API).on(row(
                                "octoproxy-cpu-scene-api",
                                "cpu",
                                bake_ms,
                                proxy_bytes,
                                0.0,
                                f64::NAN,
                            ));
                            r.ratio_to_plain = r.ns_per_particle_step / octo_ns;
                            case_rows.push(r);
                        }
                        if full {
                            let pen = octo_penetration_rate(
                                &nolut_view,
                                &gt,
                                scene.closed,
                                &sample,
                                check_steps,
                                &params,
                            );
                            case_rows.push(timing(NOLUT).on(row(
                                "octoproxy-cpu-nolut",
                                "cpu",
                                bake_ms,
                                proxy_bytes - view.lut_bytes(),
                                0.0,
                                pen,
                            )));
                            for (k, ((m, build_ms), pen)) in
                                methods.iter().zip(&pen_methods).enumerate()
                            {
                                case_rows.push(timing(4 + k).on(row(
                                    m.name(),
                                    "cpu",
                                    *build_ms,
                                    m.memory_bytes(),
                                    0.0,
                                    *pen,
                                )));
                            }
                        }
                        if full && n == profile_n {
                            say(&bar, format!("{case_scene}: {n} particles, the profile"));
                            profiles.push(profile::profile(
                                &case_scene,
                                &lut_view,
                                &particles,
                                &params,
                                steps,
                            ));
                        }
                    }
                    let mut sweep_rows = Vec::new();
                    if let Some(g) = gpu.as_mut() {
                        let gpu_steps = o
                            .steps
                            .unwrap_or(((20_000_000 / n.max(1)) as u32).clamp(10, 100));
                        let time = |g: &mut WgpuBackend, floor| {
                            time_gpu(g, &particles, &params, gpu_steps, o.gpu_repeats, floor)
                        };
                        // The floor and the plain step at the kernel's workgroup size, each row
                        // naming it.
                        let timed = |g: &mut WgpuBackend| -> Result<[Row; 2]> {
                            let size = g.workgroup_size();
                            let floor =
                                time(g, true)?.on(row("floor", "wgpu", 0.0, 0, 0.0, f64::NAN));
                            let octo = time(g, false)?.on(row(
                                "octoproxy-wgpu",
                                "wgpu",
                                bake_ms,
                                proxy_bytes,
                                0.0,
                                pen_octo,
                            ));
                            Ok([floor, octo].map(|mut r| {
                                r.workgroup_size = size;
                                r
                            }))
                        };
                        let plain = timed(g)?;
                        let octo_ns = plain[1].ns_per_particle_step;
                        case_rows.extend(plain);
                        if band == "mixed" {
                            let default = g.workgroup_size();
                            for &size in o.workgroup_sizes.iter().filter(|&&s| s != default) {
                                say(&bar, format!("{name}: {n} particles, workgroups of {size}"));
                                g.set_workgroup_size(size)?;
                                let mut sweep = timed(g)?;
                                set_floor_ratios(&mut sweep);
                                sweep_rows.extend(sweep.map(|mut r| {
                                    r.sweep = true;
                                    r
                                }));
                            }
                            g.set_workgroup_size(default)?;
                            // The split step (`WgpuBackend::set_split_step`) at the default
                            // size, timed beside the single dispatch in the same run.
                            say(&bar, format!("{name}: {n} particles, the split step"));
                            g.set_split_step(true);
                            let split = time(g, false);
                            g.set_split_step(false);
                            let mut split = split?.on(row(
                                SPLIT_METHOD,
                                "wgpu",
                                bake_ms,
                                proxy_bytes,
                                0.0,
                                pen_octo,
                            ));
                            split.workgroup_size = default;
                            split.sweep = true;
                            sweep_rows.push(split);
                        }
                        if scene_api && gpu_scenes {
                            say(&bar, format!("{name}: {n} particles, the scene API"));
                            let t = Instant::now();
                            let ns =
                                instances::time_scene_api(g, &words, &particles, steps, &params)?;
                            say(
                                &bar,
                                format!(
                                    "{name}: {n} particles, the scene API took {:.1} s",
                                    t.elapsed().as_secs_f64()
                                ),
                            );
                            let mut r = row(
                                "octoproxy-wgpu-scene-api",
                                "wgpu",
                                bake_ms,
                                proxy_bytes,
                                ns,
                                f64::NAN,
                            );
                            r.ratio_to_plain = ns / octo_ns;
                            case_rows.push(r);
                        }
                    }
                    set_floor_ratios(&mut case_rows);
                    rows.extend(case_rows);
                    rows.extend(sweep_rows);
                }
                bar.inc(1);
            }
        }
    }
    if !instance_scenes.is_empty() {
        say(&bar, "instances: baking the shared meshes");
        let shared = instances::load_shared(&o.meshes)?;
        bar.inc(1);
        let all_bands: Vec<(f32, f32)> = BANDS.iter().map(|b| (b.1, b.2)).collect();
        for (name, n) in instance_scenes {
            let grid = instances::Grid::new(n);
            say(&bar, format!("{name}: penetration checks"));
            let check_steps = 60;
            let pen_still = instances::penetration_rate(
                &grid,
                &shared,
                o.samples,
                &all_bands,
                check_steps,
                false,
                &params,
            )?;
            let pen_moving = instances::penetration_rate(
                &grid,
                &shared,
                o.samples,
                &all_bands,
                check_steps,
                true,
                &params,
            )?;
            bar.inc(1);
            for &count in &o.instance_particles {
                say(&bar, format!("{name}: {count} particles"));
                let steps = o
                    .steps
                    .unwrap_or(((4_000_000 / count.max(1)) as u32).clamp(2, 50));
                let particles = instances::case_particles(&grid, &shared, count, &all_bands);
                let row =
                    |method: &str, backend: &'static str, moving: usize, ns: f64, pen: f64| Row {
                        scene: name.clone(),
                        triangles: shared.triangles,
                        particles: count,
                        method: method.to_string(),
                        backend,
                        build_ms: if method == "floor" {
                            0.0
                        } else {
                            shared.bake_ms
                        },
                        memory_bytes: if method == "floor" { 0 } else { shared.bytes },
                        ns_per_particle_step: ns,
                        ratio_to_floor: f64::NAN,
                        penetrations_per_million: pen,
                        band: "mixed",
                        instances: n,
                        moving,
                        ratio_to_static: f64::NAN,
                        ratio_to_plain: f64::NAN,
                        substeps: 0,
                        iterations: 0,
                        workgroup_size: 0,
                        ns_min: f64::NAN,
                        ns_max: f64::NAN,
                        sweep: false,
                    };
                let per_step =
                    |t: Instant| t.elapsed().as_secs_f64() * 1e9 / (count as f64 * steps as f64);
                let mut case_rows = Vec::new();
                if o.cpu {
                    let mut cpu = CpuBackend::new();
                    cpu.upload_particles(&particles)?;
                    cpu.integrate_only(&params, 1)?;
                    let t = Instant::now();
                    cpu.integrate_only(&params, steps)?;
                    case_rows.push(row("floor", "cpu", 0, per_step(t), f64::NAN));
                    let [still, moving] = [false, true].map(|moving| {
                        instances::time_case(
                            &mut cpu, &grid, &shared, &particles, steps, moving, &params,
                        )
                    });
                    let (still, moving) = (still?, moving?);
                    case_rows.push(row("octoproxy-cpu", "cpu", 0, still, pen_still));
                    let mut r = row("octoproxy-cpu", "cpu", grid.moving(), moving, pen_moving);
                    r.ratio_to_static = moving / still;
                    case_rows.push(r);
                }
                if let Some(g) = gpu.as_mut().filter(|_| gpu_scenes) {
                    // The floor's kernel binds a proxy, though it reads none.
                    g.upload_proxy(shared.proxy(0))?;
                    g.upload_particles(&particles)?;
                    warm_gpu(g, &params)?;
                    g.upload_particles(&particles)?;
                    g.integrate_only(&params, 1)?;
                    g.wait()?;
                    let t = Instant::now();
                    g.integrate_only(&params, steps)?;
                    g.wait()?;
                    case_rows.push(row("floor", "wgpu", 0, per_step(t), f64::NAN));
                    let still =
                        instances::time_case(g, &grid, &shared, &particles, steps, false, &params)?;
                    let moving =
                        instances::time_case(g, &grid, &shared, &particles, steps, true, &params)?;
                    // The GPU steps the very bits the CPU does (bit for bit on lavapipe): the
                    // CPU's sample stands for both, as it does for the mesh scenes.
                    case_rows.push(row("octoproxy-wgpu", "wgpu", 0, still, pen_still));
                    let mut r = row("octoproxy-wgpu", "wgpu", grid.moving(), moving, pen_moving);
                    r.ratio_to_static = moving / still;
                    case_rows.push(r);
                }
                set_floor_ratios(&mut case_rows);
                rows.extend(case_rows);
                bar.inc(1);
            }
        }
    }
    if !pair_scenes.is_empty() {
        say(&bar, "particles: baking the floor for the radius");
        let floor = particles::Floor::new()?;
        bar.inc(1);
        for name in pair_scenes {
            for &count in &o.pair_particles {
                say(&bar, format!("{name}: {count} particles"));
                // A step with the pass costs tens of times a plain one: few steps.
                let steps = o
                    .steps
                    .unwrap_or(((2_000_000 / count.max(1)) as u32).clamp(1, 10));
                let g = gpu.as_mut().filter(|_| gpu_scenes);
                let mut case_rows = particles::time_case(name, &floor, count, steps, o.cpu, g)?;
                set_floor_ratios(&mut case_rows);
                rows.extend(case_rows);
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    let report = Report {
        machine: machine(),
        date: today(),
        gpu: gpu.as_ref().map(|g| g.description().to_string()),
        rows,
        profiles,
    };
    report.write(&o.out)?;
    report.print_summary();
    if docs::is_committed_dir(&o.out) {
        docs::refresh(&report)?;
    }
    Ok(())
}

/// Each row's time over its backend's floor in the same case.
fn set_floor_ratios(case_rows: &mut [Row]) {
    for backend in ["cpu", "wgpu"] {
        let floor = case_rows
            .iter()
            .find(|r| r.backend == backend && r.method == "floor")
            .map(|r| r.ns_per_particle_step);
        if let Some(f) = floor {
            for r in case_rows.iter_mut().filter(|r| r.backend == backend) {
                r.ratio_to_floor = r.ns_per_particle_step / f;
            }
        }
    }
}

/// Everything one run measured.
pub struct Report {
    pub machine: String,
    pub date: String,
    pub gpu: Option<String>,
    pub rows: Vec<Row>,
    /// The profiles of leaves visited per step ([`profile::profile`]; none in runs before
    /// them).
    pub profiles: Vec<profile::Profile>,
}

fn json_num(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.6}")
    } else {
        "null".into()
    }
}

fn json_str(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => out.push_str(&format!("\\u{:04x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn human_bytes(n: usize) -> String {
    if n == 0 {
        "–".into()
    } else if n >= 1 << 20 {
        format!("{:.1} MiB", n as f64 / (1u64 << 20) as f64)
    } else {
        format!("{:.0} KiB", n as f64 / 1024.0)
    }
}

fn fmt_opt(x: f64, digits: usize) -> String {
    if x.is_finite() {
        format!("{x:.digits$}")
    } else {
        "–".into()
    }
}

impl Report {
    fn json(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{{\n  \"machine\": {},\n  \"date\": {},",
            json_str(&self.machine),
            json_str(&self.date)
        );
        let _ = writeln!(
            s,
            "  \"gpu\": {},",
            self.gpu
                .as_deref()
                .map(json_str)
                .unwrap_or_else(|| "null".into())
        );
        s.push_str("  \"rows\": [\n");
        for (i, r) in self.rows.iter().enumerate() {
            let _ = write!(
                s,
                "    {{\"scene\": {}, \"triangles\": {}, \"particles\": {}, \"method\": {}, \"backend\": {}, \"speed_band\": {}, \"build_ms\": {}, \"memory_bytes\": {}, \"ns_per_particle_step\": {}, \"ratio_to_floor\": {}, \"penetrations_per_million_particle_steps\": {}",
                json_str(&r.scene),
                r.triangles,
                r.particles,
                json_str(&r.method),
                json_str(r.backend),
                json_str(r.band),
                json_num(r.build_ms),
                r.memory_bytes,
                json_num(r.ns_per_particle_step),
                json_num(r.ratio_to_floor),
                json_num(r.penetrations_per_million)
            );
            // The scene cases' fields, on their rows only.
            if r.instances > 0 {
                let _ = write!(
                    s,
                    ", \"instances\": {}, \"moving\": {}",
                    r.instances, r.moving
                );
            }
            if r.ratio_to_static.is_finite() {
                let _ = write!(s, ", \"ratio_to_static\": {}", json_num(r.ratio_to_static));
            }
            if r.ratio_to_plain.is_finite() {
                let _ = write!(s, ", \"ratio_to_plain\": {}", json_num(r.ratio_to_plain));
            }
            if r.substeps > 0 {
                let _ = write!(s, ", \"substeps\": {}", r.substeps);
            }
            if r.iterations > 0 {
                let _ = write!(s, ", \"iterations\": {}", r.iterations);
            }
            if r.workgroup_size > 0 {
                let _ = write!(s, ", \"workgroup_size\": {}", r.workgroup_size);
            }
            if r.sweep {
                s.push_str(", \"sweep\": true");
            }
            if r.ns_min.is_finite() && r.ns_max.is_finite() {
                let _ = write!(
                    s,
                    ", \"ns_min\": {}, \"ns_max\": {}",
                    json_num(r.ns_min),
                    json_num(r.ns_max)
                );
            }
            s.push('}');
            s.push_str(if i + 1 < self.rows.len() { ",\n" } else { "\n" });
        }
        s.push_str("  ]");
        if !self.profiles.is_empty() {
            s.push_str(",\n  \"profiles\": [\n");
            for (i, p) in self.profiles.iter().enumerate() {
                s.push_str("    ");
                s.push_str(&p.json());
                s.push_str(if i + 1 < self.profiles.len() {
                    ",\n"
                } else {
                    "\n"
                });
            }
            s.push_str("  ]");
        }
        s.push_str("\n}\n");
        s
    }

    fn markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Measured {} on {}{}.\n",
            self.date,
            self.machine,
            self.gpu
                .as_ref()
                .map(|g| format!("; GPU: {g}"))
                .unwrap_or_default()
        );
        let mesh_rows: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| (r.band == "mixed" || r.band == "rain") && r.is_mesh_case())
            .collect();
        if !mesh_rows.is_empty() {
            s.push_str("| scene | triangles | particles | method | build (ms) | memory | ns / particle-step | runs (fastest–slowest) | ms / step | × floor | penetrations / M steps |\n");
            s.push_str("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|\n");
        }
        for r in mesh_rows {
            let method = if r.method == "floor" {
                format!("floor ({})", r.backend)
            } else {
                r.method.clone()
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {:.1} | {} | {:.2} | {} | {} |",
                r.scene,
                r.triangles,
                r.particles,
                method,
                if r.build_ms > 0.0 {
                    format!("{:.0}", r.build_ms)
                } else {
                    "–".into()
                },
                human_bytes(r.memory_bytes),
                r.ns_per_particle_step,
                if r.ns_min.is_finite() && r.ns_max.is_finite() {
                    format!("{:.1}–{:.1}", r.ns_min, r.ns_max)
                } else {
                    "–".into()
                },
                r.ms_per_step(),
                fmt_opt(r.ratio_to_floor, 2),
                fmt_opt(r.penetrations_per_million, 1)
            );
        }
        let bands: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| {
                r.band != "mixed" && r.band != "rain" && r.method != "floor" && r.is_mesh_case()
            })
            .collect();
        if !bands.is_empty() {
            s.push_str("\nBy speed band (slow 0.1–0.5, medium 0.5–2, fast 2–5 depth-8 leaves per step):\n\n");
            s.push_str("| scene | particles | band | method | ns / particle-step | × floor |\n|---|---:|---|---|---:|---:|\n");
            for r in bands {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {:.1} | {} |",
                    r.scene,
                    r.particles,
                    r.band,
                    r.method,
                    r.ns_per_particle_step,
                    fmt_opt(r.ratio_to_floor, 2)
                );
            }
        }
        s.push_str(&self.markdown_scene_cases());
        let pairs = self.particle_cases();
        if !pairs.is_empty() {
            s.push('\n');
            s.push_str(&pairs);
        }
        if !self.profiles.is_empty() {
            s.push('\n');
            s.push_str(&profile::profile_tables(self));
        }
        s
    }

    /// The cases of particles that collide with each other, one line per case and backend:
    /// the whole step, per particle-step and per particle-substep, and on the CPU its parts
    /// (empty when the run has none).
    pub fn particle_cases(&self) -> String {
        let cases: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| r.substeps > 0 && r.method.ends_with(particles::METHOD))
            .collect();
        if cases.is_empty() {
            return String::new();
        }
        let part = |r: &Row, name: &str| {
            self.rows
                .iter()
                .find(|q| {
                    q.scene == r.scene
                        && q.particles == r.particles
                        && q.backend == r.backend
                        && q.method == format!("{}{name}", r.method)
                })
                .map(|q| q.ns_per_particle_step)
        };
        let mut s = String::new();
        let _ = write!(
            s,
            "Particles that collide with each other (`step_pairs`: the uniform-grid pass, then the \
             march at the radius), radius {} m, `dt` 1/60 s, the automatic substeps (gravity's, more \
             while a grain moves more than a radius in one; the table gives the mean a step), as many \
             Jacobi iterations before the march as debiasing ones after it (at least 8, one for every 12 grains in the deepest \
             column; the table gives the mean a substep). `particles-pile`: a block {} grains wide set down at rest on a \
             floor, one grain per cell; `particles-cloud`: one grain per (8R)³ falling onto it. Nanoseconds per \
             particle-step; the pass is the sort and the neighbour loop (both sets of iterations), per particle-substep:\n\n",
            particles::RADIUS,
            particles::PILE_WIDTH,
        );
        s.push_str("| case | particles | backend | substeps | iterations | step | per substep | pass per substep | sort | neighbour loop | march | × floor |\n");
        s.push_str("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
        let ns = |x: Option<f64>| x.map(|v| format!("{v:.0}")).unwrap_or_else(|| "–".into());
        for r in cases {
            let sub = r.substeps as f64;
            let (sort, nb, march) = (
                part(r, particles::PARTS[0]),
                part(r, particles::PARTS[1]),
                part(r, particles::PARTS[2]),
            );
            let pass = match (sort, nb) {
                (Some(a), Some(b)) => Some((a + b) / sub),
                _ => None,
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.0} | {:.0} | {} | {} | {} | {} | {} |",
                r.scene,
                r.particles,
                r.backend,
                r.substeps,
                if r.iterations > 0 {
                    r.iterations.to_string()
                } else {
                    "–".into()
                },
                r.ns_per_particle_step,
                r.ns_per_particle_step / sub,
                ns(pass),
                ns(sort),
                ns(nb),
                ns(march),
                fmt_opt(r.ratio_to_floor, 0)
            );
        }
        s
    }

    /// The plain step's row that a scene-API row is compared with.
    fn plain_of(&self, api: &Row) -> Option<&Row> {
        let method = api.method.strip_suffix(instances::SCENE_API)?;
        self.rows.iter().find(|r| {
            r.scene == api.scene
                && r.particles == api.particles
                && r.backend == api.backend
                && r.band == api.band
                && r.method == method
        })
    }

    /// The instance cases and the scene API's comparison, where the run has them (nothing
    /// otherwise, so that a run before them renders as it did).
    fn markdown_scene_cases(&self) -> String {
        let mut s = String::new();
        let cases: Vec<&Row> = self.rows.iter().filter(|r| r.instances > 0).collect();
        if !cases.is_empty() {
            let meshes: Vec<&str> = instances::MESHES.iter().map(|m| m.0).collect();
            let _ = write!(
                s,
                "\nInstance cases: particles raining through a grid of instances of {} (one proxy \
                 each, baked once), stepped through `Scene::step`, every instance static, then \
                 half of them moving (going round, bobbing and turning):\n\n",
                meshes.join(" and ")
            );
            s.push_str("| scene | instances | moving | particles | method | ns / particle-step | ms / step | × floor | moving ÷ static | penetrations / M steps |\n");
            s.push_str("|---|---:|---:|---:|---|---:|---:|---:|---:|---:|\n");
            for r in cases {
                let method = if r.method == "floor" {
                    format!("floor ({})", r.backend)
                } else {
                    r.method.clone()
                };
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {} | {:.1} | {:.2} | {} | {} | {} |",
                    r.scene,
                    r.instances,
                    r.moving,
                    r.particles,
                    method,
                    r.ns_per_particle_step,
                    r.ms_per_step(),
                    fmt_opt(r.ratio_to_floor, 2),
                    fmt_opt(r.ratio_to_static, 2),
                    fmt_opt(r.penetrations_per_million, 1)
                );
            }
        }
        let api: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| r.method.ends_with(instances::SCENE_API))
            .collect();
        if !api.is_empty() {
            s.push_str(
                "\nThe scene API on a static scene: the proxy as one instance at the identity, \
                 stepped through `Scene::step`, against the plain `Backend::step` of the same \
                 particles:\n\n",
            );
            s.push_str("| scene | particles | method | plain ns / particle-step | scene API ns / particle-step | scene API ÷ plain |\n");
            s.push_str("|---|---:|---|---:|---:|---:|\n");
            for r in api {
                let plain = self
                    .plain_of(r)
                    .map_or(f64::NAN, |p| p.ns_per_particle_step);
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {} | {:.1} | {} |",
                    r.scene,
                    r.particles,
                    r.method,
                    fmt_opt(plain, 1),
                    r.ns_per_particle_step,
                    fmt_opt(r.ratio_to_plain, 2)
                );
            }
        }
        s
    }

    fn write(&self, dir: &Path) -> Result<()> {
        let json = dir.join("results.json");
        std::fs::write(&json, self.json())
            .with_context(|| format!("writing {}", json.display()))?;
        let md = dir.join("results.md");
        std::fs::write(&md, self.markdown())
            .with_context(|| format!("writing {}", md.display()))?;
        self.plots(dir)?;
        eprintln!(
            "wrote {}, {} and plots in {}",
            json.display(),
            md.display(),
            dir.display()
        );
        Ok(())
    }

    fn series_by_method(
        &self,
        filter: impl Fn(&Row) -> bool,
        x: impl Fn(&Row) -> f64,
    ) -> Vec<plot::Series> {
        let mut series: Vec<plot::Series> = Vec::new();
        for r in self
            .rows
            .iter()
            .filter(|r| r.band == "mixed" && r.is_mesh_case() && filter(r))
        {
            let label = if r.method == "floor" {
                format!("floor ({})", r.backend)
            } else {
                r.method.clone()
            };
            let point = (x(r), r.ns_per_particle_step);
            match series.iter_mut().find(|s| s.label == label) {
                Some(s) => s.points.push(point),
                None => series.push(plot::Series {
                    label,
                    points: vec![point],
                }),
            }
        }
        for s in &mut series {
            s.points.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        series
    }

    fn plots(&self, dir: &Path) -> Result<()> {
        // Cost against particles, on the scene with the most triangles.
        if let Some(big) = self
            .rows
            .iter()
            .filter(|r| r.is_mesh_case())
            .max_by_key(|r| r.triangles)
        {
            let scene = big.scene.clone();
            let series = self.series_by_method(|r| r.scene == scene, |r| r.particles as f64);
            plot::line_chart(
                &dir.join("particles.png"),
                &format!("{scene}: cost per particle-step against particles"),
                "particles",
                "ns per particle-step",
                &series,
            )?;
        }
        // Cost against triangles, at the largest particle count: on the Nefertiti family
        // (one surface, subdivided) when the run has two of them, else across the scenes.
        if let Some(n) = self
            .rows
            .iter()
            .filter(|r| r.is_mesh_case())
            .map(|r| r.particles)
            .max()
        {
            let family: Vec<&str> = ["nefertiti", "nefertiti-1.6m", "nefertiti-6.4m"]
                .into_iter()
                .filter(|s| self.rows.iter().any(|r| r.scene == *s))
                .collect();
            let (scenes, what) = if family.len() >= 2 {
                (family, "Nefertiti subdivided")
            } else {
                (Vec::new(), "all scenes")
            };
            let series = self.series_by_method(
                |r| r.particles == n && (scenes.is_empty() || scenes.contains(&r.scene.as_str())),
                |r| r.triangles as f64,
            );
            plot::line_chart(
                &dir.join("triangles.png"),
                &format!("{what}, {n} particles: cost against triangles"),
                "triangles",
                "ns per particle-step",
                &series,
            )?;
        }
        Ok(())
    }

    fn print_summary(&self) {
        println!("{}", self.markdown());
        self.print_mesh_targets();
        self.print_scene_targets();
    }

    /// The scene cases' ratios against their targets: moving instances at most twice the same
    /// instances still (at 100 instances), and a static scene through the scene API at the
    /// plain step's cost.
    fn print_scene_targets(&self) {
        let moving: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| r.instances > 0 && r.ratio_to_static.is_finite())
            .collect();
        if !moving.is_empty() {
            println!("moving instances (half of them moving, against all static; target at 100 instances: at most 2×):");
            for r in moving {
                println!(
                    "  {} on {}, {} particles: {:.1} ns per particle-step, {:.2}× static",
                    r.scene, r.backend, r.particles, r.ns_per_particle_step, r.ratio_to_static
                );
            }
        }
        let api: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| r.ratio_to_plain.is_finite())
            .collect();
        if !api.is_empty() {
            println!("the scene API on a static scene (target: the plain step's cost):");
            for r in api {
                println!(
                    "  {} on {}, {} particles: {:.1} ns per particle-step, {:.2}× the plain step",
                    r.scene, r.backend, r.particles, r.ns_per_particle_step, r.ratio_to_plain
                );
            }
        }
    }

    /// The targets of the mesh scenes: 1M particles (or the largest count the CPU ran) on the
    /// largest scene.
    fn print_mesh_targets(&self) {
        let cpu_rows = || {
            self.rows
                .iter()
                .filter(|r| r.method == "octoproxy-cpu" && r.band == "mixed" && r.is_mesh_case())
        };
        let Some(triangles) = cpu_rows().map(|r| r.triangles).max() else {
            return;
        };
        let Some(big) = cpu_rows()
            .filter(|r| r.triangles == triangles)
            .max_by_key(|r| (r.particles == 1_000_000, r.particles))
        else {
            return;
        };
        let case = |m: &str| {
            self.rows
                .iter()
                .find(|r| {
                    r.scene == big.scene
                        && r.particles == big.particles
                        && r.band == "mixed"
                        && r.method == m
                })
                .map(|r| r.ns_per_particle_step)
        };
        if let Some(octo) = case("octoproxy-cpu") {
            println!("{} triangles, {} particles:", big.triangles, big.particles);
            if let Some(f) = self.rows.iter().find(|r| {
                r.scene == big.scene
                    && r.particles == big.particles
                    && r.band == "mixed"
                    && r.method == "floor"
                    && r.backend == "cpu"
            }) {
                println!(
                    "  octoproxy-cpu is {:.2}× the floor (target: within 2×)",
                    octo / f.ns_per_particle_step
                );
            }
            for (m, target) in [
                ("parry3d", 30.0),
                ("triangle-octree", 3.0),
                ("sdf-grid", 0.0),
            ] {
                if let Some(x) = case(m) {
                    let target = if target > 0.0 {
                        format!(" (target: {target}×)")
                    } else {
                        String::new()
                    };
                    println!("  {m} takes {:.1}× octoproxy-cpu's time{target}", x / octo);
                }
            }
        }
    }
}

/// The committed run (`docs/bench/results.json`) and every benchmark figure in the docs, which
/// is rendered from it: between `<!-- bench:NAME -->` and `<!-- /bench:NAME -->`, each on a line
/// of its own, in `README.md` and any Markdown file under `docs/`.
mod docs {
    use std::fmt::Write as _;
    use std::path::{Path, PathBuf};

    use anyhow::{anyhow, bail, Context, Result};

    use super::{human_bytes, instances, Report, Row, BANDS, SPLIT_METHOD};

    /// Where the committed run lives, from the repository root.
    pub const COMMITTED_DIR: &str = "docs/bench";

    /// Where the committed GPU run (the device check, `xtask/gpu-check/`) lives.
    pub const GPU_DIR: &str = "docs/bench/gpu";

    /// Every generated region, and the file (from the repository root) that must hold it. The
    /// same region may appear in other Markdown files too.
    pub const REGIONS: [(&str, &str); 11] = [
        ("README.md", "table:headline"),
        ("README.md", "table:gpu"),
        ("docs/bench/README.md", "table:summary"),
        ("docs/bench/README.md", "text:findings"),
        ("docs/bench/README.md", "table:bands"),
        ("docs/bench/README.md", "text:targets"),
        ("docs/bench/README.md", "table:instances"),
        ("docs/bench/README.md", "table:particles"),
        ("docs/bench/README.md", "table:rain"),
        ("docs/bench/README.md", "table:profile"),
        ("docs/bench/README.md", "text:speed"),
    ];

    /// The CPU methods in the order the tables list them; others follow as they appear.
    const METHODS: [&str; 6] = [
        "octoproxy-cpu",
        "octoproxy-cpu-nolut",
        "triangle-octree",
        "parry3d",
        "sdf-grid",
        "floor",
    ];

    pub fn repo_root() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
    }

    /// Whether `out` is the committed run's directory.
    pub fn is_committed_dir(out: &Path) -> bool {
        match (
            out.canonicalize(),
            repo_root().join(COMMITTED_DIR).canonicalize(),
        ) {
            (Ok(a), Ok(b)) => a == b,
            _ => false,
        }
    }

    /// The committed run, parsed.
    pub fn load_committed() -> Result<Report> {
        let path = repo_root().join(COMMITTED_DIR).join("results.json");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        super::json::parse_report(&text).with_context(|| format!("parsing {}", path.display()))
    }

    /// `--docs-only`: `results.md` and every marked region from the committed `results.json`.
    pub fn refresh_from_committed() -> Result<()> {
        let report = load_committed()?;
        let md = repo_root().join(COMMITTED_DIR).join("results.md");
        write_if_changed(&md, &report.markdown())?;
        refresh(&report)
    }

    /// Rewrites every marked region in `README.md` and `docs/**.md` from `report`.
    pub fn refresh(report: &Report) -> Result<()> {
        let root = repo_root();
        for file in markdown_files(&root)? {
            let text = std::fs::read_to_string(&file)
                .with_context(|| format!("reading {}", file.display()))?;
            let new = rewrite(&text, report).with_context(|| format!("in {}", file.display()))?;
            write_if_changed(&file, &new)?;
        }
        let missing = missing_regions(&root);
        if !missing.is_empty() {
            bail!("{}", missing.join("; "));
        }
        Ok(())
    }

    fn write_if_changed(path: &Path, text: &str) -> Result<()> {
        if std::fs::read_to_string(path).ok().as_deref() != Some(text) {
            std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
            eprintln!("rewrote {}", path.display());
        }
        Ok(())
    }

    /// `README.md` and every `.md` file under `docs/`, sorted.
    pub fn markdown_files(root: &Path) -> Result<Vec<PathBuf>> {
        fn walk(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
            for entry in
                std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?
            {
                let path = entry?.path();
                if path.is_dir() {
                    walk(&path, out)?;
                } else if path.extension().is_some_and(|e| e == "md") {
                    out.push(path);
                }
            }
            Ok(())
        }
        let mut files = vec![root.join("README.md")];
        let docs = root.join("docs");
        if docs.is_dir() {
            walk(&docs, &mut files)?;
        }
        files[1..].sort();
        Ok(files)
    }

    /// One marked region: its name, the 1-based line of its opening marker, and the byte
    /// range of its content (between the markers' lines).
    pub struct Region {
        pub name: String,
        pub line: usize,
        pub content: std::ops::Range<usize>,
    }

    fn marker<'a>(line: &'a str, prefix: &str) -> Option<&'a str> {
        line.trim()
            .strip_prefix(prefix)?
            .strip_suffix("-->")
            .map(str::trim)
    }

    /// The marked regions of a Markdown text, in order. Markers do not nest, and inside a
    /// fenced code block they are text (so the docs can show them).
    pub fn regions(text: &str) -> Result<Vec<Region>> {
        let mut out = Vec::new();
        let mut open: Option<(String, usize, usize)> = None;
        let mut fenced = false;
        let mut at = 0;
        for (i, line) in text.split_inclusive('\n').enumerate() {
            let next = at + line.len();
            if line.trim_start().starts_with("```") {
                fenced = !fenced;
            }
            if fenced || line.trim_start().starts_with("```") {
                at = next;
                continue;
            }
            if let Some(name) = marker(line, "<!-- bench:") {
                if let Some((outer, l, _)) = &open {
                    bail!(
                        "line {}: bench:{name} opens inside bench:{outer} (opened on line {l})",
                        i + 1
                    );
                }
                open = Some((name.to_string(), i + 1, next));
            } else if let Some(name) = marker(line, "<!-- /bench:") {
                match open.take() {
                    Some((n, l, start)) if n == name => out.push(Region {
                        name: n,
                        line: l,
                        content: start..at,
                    }),
                    Some((n, l, _)) => bail!(
                        "line {}: /bench:{name} closes bench:{n} (opened on line {l})",
                        i + 1
                    ),
                    None => bail!("line {}: /bench:{name} closes nothing", i + 1),
                }
            }
            at = next;
        }
        if let Some((n, l, _)) = open {
            bail!("line {l}: bench:{n} is never closed (<!-- /bench:{n} -->)");
        }
        Ok(out)
    }

    /// `text` with every marked region replaced by its rendering.
    pub fn rewrite(text: &str, report: &Report) -> Result<String> {
        let mut out = String::with_capacity(text.len());
        let mut at = 0;
        for r in regions(text)? {
            out.push_str(&text[at..r.content.start]);
            out.push_str(&render(&r.name, report).with_context(|| format!("line {}", r.line))?);
            at = r.content.end;
        }
        out.push_str(&text[at..]);
        Ok(out)
    }

    /// The `REGIONS` that are not in their home file.
    pub fn missing_regions(root: &Path) -> Vec<String> {
        let mut missing = Vec::new();
        for (file, name) in REGIONS {
            let text = std::fs::read_to_string(root.join(file)).unwrap_or_default();
            let found = regions(&text).is_ok_and(|rs| rs.iter().any(|r| r.name == name));
            if !found {
                missing.push(format!(
                    "{file} lacks the region <!-- bench:{name} --> ... <!-- /bench:{name} -->"
                ));
            }
        }
        missing
    }

    /// A region's content: a blank line, the rendering, a blank line (so Markdown sees the
    /// markers as their own blocks).
    pub fn render(name: &str, report: &Report) -> Result<String> {
        if name == "table:gpu" {
            return Ok(format!("\n{}\n", gpu_region(load_gpu()?.as_ref())));
        }
        if name == "table:instances" {
            // The scene cases stand apart from the mesh scenes' run.
            return Ok(format!("\n{}\n", scene_cases(report)));
        }
        if name == "table:particles" {
            let table = report.particle_cases();
            let body = if table.is_empty() {
                format!(
                    "The committed run ({}) predates the particle cases: `cargo xtask bench \
                     --scenes particles-pile,particles-cloud` runs them, and the next full run to \
                     commit puts their figures here.",
                    report.date
                )
            } else {
                table
            };
            return Ok(format!("\n{body}\n"));
        }
        match name {
            "table:rain" => return Ok(format!("\n{}\n", super::profile::rain_table(report))),
            "table:profile" => {
                return Ok(format!("\n{}\n", super::profile::profile_tables(report)))
            }
            "text:speed" => return Ok(format!("\n{}\n", super::profile::speed_targets(report))),
            _ => {}
        }
        let run = Run::new(report)?;
        let body = match name {
            "table:headline" => run.headline(),
            "table:summary" => run.summary(),
            "text:findings" => run.findings(),
            "table:bands" => run.bands(),
            "text:targets" => run.targets(),
            _ => bail!(
                "unknown region bench:{name} (regions: {})",
                REGIONS.map(|r| r.1).join(", ")
            ),
        };
        Ok(format!("\n{body}\n"))
    }

    /// The committed GPU run, parsed, if there is one.
    pub fn load_gpu() -> Result<Option<Report>> {
        let path = repo_root().join(GPU_DIR).join("results.json");
        if !path.exists() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        super::json::parse_report(&text)
            .with_context(|| format!("parsing {}", path.display()))
            .map(Some)
    }

    /// The aim on a real GPU: 10M particles a step in under 1 ms, within 3x the GPU floor.
    const GPU_AIM_PARTICLES: usize = 10_000_000;
    const GPU_AIM_MS: f64 = 1.0;
    const GPU_AIM_FLOOR: f64 = 3.0;

    /// The README's GPU region: the committed GPU run's plain step per scene and count, the
    /// workgroup-size sweep, the aim, the scene cases and the particle cases; or how to make
    /// one.
    pub fn gpu_region(gpu: Option<&Report>) -> String {
        let Some(r) = gpu else {
            return "No GPU run is committed yet: the device check (`xtask/gpu-check/`, below) \
                    writes `docs/bench/gpu/results.json`, and the tables appear here."
                .into();
        };
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Measured {} on {} (host: {}); each time is the median of the run's repeats, \
             nanoseconds per particle-step ([results.json](docs/bench/gpu/results.json)).\n",
            r.date,
            r.gpu.as_deref().unwrap_or("no GPU"),
            r.machine
        );
        let plain = |q: &&Row| q.backend == "wgpu" && q.is_mesh_case() && q.band == "mixed";
        let steps: Vec<&Row> = r
            .rows
            .iter()
            .filter(plain)
            .filter(|q| q.method == "octoproxy-wgpu")
            .collect();
        if steps.is_empty() {
            s.push_str("The run has no plain GPU step.\n");
            return s;
        }
        // Every size timed for a case: the default's row and the sweep's.
        let sizes_of = |q: &Row| -> Vec<&Row> {
            r.rows
                .iter()
                .filter(|x| {
                    x.backend == "wgpu"
                        && x.method == q.method
                        && x.scene == q.scene
                        && x.particles == q.particles
                        && x.band == q.band
                        && x.instances == 0
                        && x.substeps == 0
                        && x.workgroup_size > 0
                })
                .collect()
        };
        s.push_str(
            "| scene | triangles | particles | floor | octoproxy-wgpu | × floor | ms / step | best workgroup size | at best | ms / step at best |\n",
        );
        s.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
        for q in &steps {
            let floor = q.ns_per_particle_step / q.ratio_to_floor;
            let best = sizes_of(q)
                .into_iter()
                .min_by(|a, b| a.ns_per_particle_step.total_cmp(&b.ns_per_particle_step))
                .unwrap_or(q);
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.2} | {:.2} | {:.1}× | {:.3} | {} | {:.2} | {:.3} |",
                q.scene,
                thousands(q.triangles as u64),
                thousands(q.particles as u64),
                floor,
                q.ns_per_particle_step,
                q.ratio_to_floor,
                q.ms_per_step(),
                best.workgroup_size,
                best.ns_per_particle_step,
                best.ms_per_step()
            );
        }
        // The sweep at the largest count: ms per step at each size.
        let largest = steps.iter().map(|q| q.particles).max().unwrap_or(0);
        let mut sizes: Vec<u32> = steps
            .iter()
            .flat_map(|q| sizes_of(q))
            .map(|x| x.workgroup_size)
            .collect();
        sizes.sort_unstable();
        sizes.dedup();
        if sizes.len() > 1 {
            let _ = writeln!(
                s,
                "\nThe plain step's workgroup size, swept in the same run: milliseconds per step \
                 of {} particles (the run's default was {}).\n",
                thousands(largest as u64),
                steps[0].workgroup_size
            );
            let _ = writeln!(
                s,
                "| scene | {} |",
                sizes
                    .iter()
                    .map(|z| z.to_string())
                    .collect::<Vec<_>>()
                    .join(" | ")
            );
            let _ = writeln!(s, "|---|{}", "---:|".repeat(sizes.len()));
            for q in steps.iter().filter(|q| q.particles == largest) {
                let at = sizes_of(q);
                let cells: Vec<String> = sizes
                    .iter()
                    .map(|z| {
                        at.iter()
                            .find(|x| x.workgroup_size == *z)
                            .map(|x| format!("{:.3}", x.ms_per_step()))
                            .unwrap_or_else(|| "–".into())
                    })
                    .collect();
                let _ = writeln!(s, "| {} | {} |", q.scene, cells.join(" | "));
            }
        }
        // The split step beside the single dispatch, where the run timed it.
        let split: Vec<String> = steps
            .iter()
            .filter_map(|q| {
                let t = r.rows.iter().find(|x| {
                    x.method == SPLIT_METHOD
                        && x.backend == "wgpu"
                        && x.scene == q.scene
                        && x.particles == q.particles
                        && x.band == q.band
                })?;
                Some(format!(
                    "{} at {}: {:.3} against {:.3} ms ({:.2}×)",
                    q.scene,
                    thousands(q.particles as u64),
                    t.ms_per_step(),
                    q.ms_per_step(),
                    t.ns_per_particle_step / q.ns_per_particle_step
                ))
            })
            .collect();
        if !split.is_empty() {
            let _ = writeln!(
                s,
                "\nThe split step (`WgpuBackend::set_split_step`: the particles that settle, then \
                 the rest queued and dispatched indirectly), in the same run at the default \
                 workgroup size, milliseconds per step against the single dispatch: {}.",
                split.join("; ")
            );
        }
        let aim: Vec<&&Row> = steps
            .iter()
            .filter(|q| q.particles == GPU_AIM_PARTICLES)
            .collect();
        if !aim.is_empty() {
            let met: Vec<String> = aim
                .iter()
                .filter(|q| q.ms_per_step() < GPU_AIM_MS && q.ratio_to_floor <= GPU_AIM_FLOOR)
                .map(|q| q.scene.clone())
                .collect();
            let _ = writeln!(
                s,
                "\nThe aim, {} particles a step in under {GPU_AIM_MS} ms within {GPU_AIM_FLOOR}× \
                 the GPU floor, at the default workgroup size: met on {} of {} scenes{}.",
                thousands(GPU_AIM_PARTICLES as u64),
                met.len(),
                aim.len(),
                if met.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", and_list(&met))
                }
            );
        }
        let scene_rows = r
            .rows
            .iter()
            .any(|q| q.instances > 0 || q.ratio_to_plain.is_finite());
        if scene_rows && !software_gpu(r) {
            let _ = write!(s, "\n{}\n", scene_cases(r));
        }
        let particles = r.particle_cases();
        if !particles.is_empty() {
            let _ = write!(s, "\n{particles}\n");
        }
        s
    }

    /// `1234567` as `1,234,567`.
    fn thousands(n: u64) -> String {
        let digits = n.to_string();
        let mut out = String::new();
        for (i, c) in digits.chars().enumerate() {
            if i > 0 && (digits.len() - i).is_multiple_of(3) {
                out.push(',');
            }
            out.push(c);
        }
        out
    }

    fn fixed(x: f64, digits: usize) -> String {
        format!("{x:.digits$}")
    }

    /// The smallest and largest of `values`, as `a–b` (or `a` when they print the same).
    fn span(values: impl IntoIterator<Item = f64>, digits: usize) -> String {
        let (lo, hi) = values
            .into_iter()
            .filter(|x| x.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            });
        if lo > hi {
            return "–".into();
        }
        let (a, b) = (fixed(lo, digits), fixed(hi, digits));
        if a == b {
            a
        } else {
            format!("{a}–{b}")
        }
    }

    /// Penetrations per million particle-steps as the tables print them.
    pub(super) fn penetrations(x: f64) -> String {
        if x.is_finite() {
            thousands(x.round() as u64)
        } else {
            "–".into()
        }
    }

    fn seconds(ms: f64) -> String {
        if ms > 0.0 {
            format!("{:.2} s", ms / 1e3)
        } else {
            "–".into()
        }
    }

    fn label(method: &str) -> &str {
        if method == "floor" {
            "floor (integration only)"
        } else {
            method
        }
    }

    /// A sentence's list: `a`, `a and b`, `a, b and c`.
    fn and_list(items: &[String]) -> String {
        match items {
            [] => String::new(),
            [a] => a.clone(),
            [rest @ .., last] => format!("{} and {last}", rest.join(", ")),
        }
    }

    /// Whether the run's only GPU was a software one (its rows time a CPU emulating a GPU).
    fn software_gpu(report: &Report) -> bool {
        report.gpu.as_deref().is_some_and(|g| g.contains(", Cpu)"))
    }

    /// The scene cases: the instance cases, still and moving, and the scene API on a static
    /// scene, with their targets; or, for a run before them, how to run them.
    fn scene_cases(report: &Report) -> String {
        let shown = |r: &Row| r.backend == "cpu" || !software_gpu(report);
        let cases: Vec<&Row> = report
            .rows
            .iter()
            .filter(|r| r.instances > 0 && r.method != "floor" && shown(r))
            .collect();
        let mut api: Vec<&Row> = report
            .rows
            .iter()
            .filter(|r| r.ratio_to_plain.is_finite() && shown(r))
            .collect();
        // The scene API at one count: a million particles where the run has them.
        let api_n = if api.iter().any(|r| r.particles == 1_000_000) {
            1_000_000
        } else {
            api.iter().map(|r| r.particles).max().unwrap_or(0)
        };
        api.retain(|r| r.particles == api_n);
        if cases.is_empty() && api.is_empty() {
            return format!(
                "The committed run ({}) predates the instance cases and the scene API's \
                 comparison: `cargo xtask bench --scenes {}` runs them, and the next full run \
                 to commit puts their figures here.",
                report.date,
                instances::SCENES.join(",")
            );
        }
        let mut s = String::new();
        if !cases.is_empty() {
            let n = if cases.iter().any(|r| r.particles == 1_000_000) {
                1_000_000
            } else {
                cases.iter().map(|r| r.particles).max().unwrap_or(0)
            };
            let at_n: Vec<&Row> = cases.into_iter().filter(|r| r.particles == n).collect();
            let first = at_n[0];
            let meshes: Vec<String> = instances::MESHES.iter().map(|m| m.0.to_string()).collect();
            let _ = write!(
                s,
                "{} particles raining through a grid of instances of {} (one proxy each, baked \
                 once: {} triangles, {}), stepped through `Scene::step`, ns per particle-step: \
                 every instance static, then half of them moving (going round, bobbing and \
                 turning):\n\n",
                thousands(n as u64),
                and_list(&meshes),
                thousands(first.triangles as u64),
                human_bytes(first.memory_bytes)
            );
            s.push_str("| instances | method | static | moving | moving ÷ static | × floor (moving) | penetrations / M (static, moving) |\n");
            s.push_str("|---:|---|---:|---:|---:|---:|---:|\n");
            let mut targets = Vec::new();
            for r in at_n.iter().filter(|r| r.moving > 0) {
                let Some(still) = at_n.iter().find(|q| {
                    q.scene == r.scene
                        && q.backend == r.backend
                        && q.method == r.method
                        && q.moving == 0
                }) else {
                    continue;
                };
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.1} | {:.1} | {:.2}× | {:.0}× | {}, {} |",
                    thousands(r.instances as u64),
                    r.method,
                    still.ns_per_particle_step,
                    r.ns_per_particle_step,
                    r.ratio_to_static,
                    r.ratio_to_floor,
                    penetrations(still.penetrations_per_million),
                    penetrations(r.penetrations_per_million)
                );
                if r.instances == 100 {
                    targets.push(r);
                }
            }
            let verdict = if targets.is_empty() {
                "no 100-instance case in this run".to_string()
            } else if targets.iter().all(|r| r.ratio_to_static <= 2.0) {
                "met".to_string()
            } else if targets.iter().any(|r| r.ratio_to_static <= 2.0) {
                "met on some backends".to_string()
            } else {
                "not met on this machine".to_string()
            };
            let figures: Vec<String> = targets
                .iter()
                .map(|r| format!("`{}` {:.2}×", r.method, r.ratio_to_static))
                .collect();
            let _ = writeln!(
                s,
                "\n- **Moving instances** (target: 100 instances, half of them moving, at most 2× \
                 the same instances static; {verdict}){}.",
                if figures.is_empty() {
                    String::new()
                } else {
                    format!(": {}", and_list(&figures))
                }
            );
        } else {
            s.push_str("The run has no instance cases.\n\n");
        }
        for r in api {
            let plain = report
                .rows
                .iter()
                .find(|p| {
                    Some(p.method.as_str()) == r.method.strip_suffix(instances::SCENE_API)
                        && p.scene == r.scene
                        && p.particles == r.particles
                        && p.backend == r.backend
                        && p.band == r.band
                })
                .map_or(f64::NAN, |p| p.ns_per_particle_step);
            let _ = writeln!(
                s,
                "- **A static scene through the scene API** (target: the plain step's cost; \
                 `{}`): {}, {} particles, its proxy as one instance at the identity through \
                 `Scene::step`, {:.1} ns per particle-step against {} for `Backend::step`: \
                 {:.2}×.",
                r.method,
                r.scene,
                thousands(r.particles as u64),
                r.ns_per_particle_step,
                if plain.is_finite() {
                    format!("{plain:.1}")
                } else {
                    "–".into()
                },
                r.ratio_to_plain
            );
        }
        s
    }

    /// The figures of one run: the CPU methods at one particle count (1M where the run has
    /// it), every scene.
    struct Run<'a> {
        report: &'a Report,
        n: usize,
        scenes: Vec<&'a str>,
        methods: Vec<&'a str>,
        largest: &'a Row,
    }

    impl<'a> Run<'a> {
        fn new(report: &'a Report) -> Result<Self> {
            let octo = || {
                report.rows.iter().filter(|r| {
                    r.method == "octoproxy-cpu"
                        && r.backend == "cpu"
                        && r.band == "mixed"
                        && r.is_mesh_case()
                })
            };
            let n = if octo().any(|r| r.particles == 1_000_000) {
                1_000_000
            } else {
                octo()
                    .map(|r| r.particles)
                    .max()
                    .ok_or_else(|| anyhow!("the results have no octoproxy-cpu rows"))?
            };
            let mut scenes: Vec<&str> = Vec::new();
            for r in octo().filter(|r| r.particles == n) {
                if !scenes.contains(&r.scene.as_str()) {
                    scenes.push(&r.scene);
                }
            }
            let mut methods: Vec<&str> = METHODS.to_vec();
            for r in &report.rows {
                if r.backend == "cpu" && r.is_mesh_case() && !methods.contains(&r.method.as_str()) {
                    methods.push(&r.method);
                }
            }
            let largest = octo()
                .filter(|r| r.particles == n)
                .max_by_key(|r| r.triangles)
                .expect("a scene at n");
            Ok(Run {
                report,
                n,
                scenes,
                methods,
                largest,
            })
        }

        /// The CPU, mixed-speed row of `method` on `scene` at the run's count.
        fn row(&self, scene: &str, method: &str) -> Option<&'a Row> {
            self.report.rows.iter().find(|r| {
                r.scene == scene
                    && r.method == method
                    && r.backend == "cpu"
                    && r.band == "mixed"
                    && r.particles == self.n
                    && r.is_mesh_case()
            })
        }

        /// `method`'s time over octoproxy-cpu's on `scene`.
        fn vs_octo(&self, scene: &str, method: &str) -> Option<f64> {
            let octo = self.row(scene, "octoproxy-cpu")?.ns_per_particle_step;
            Some(self.row(scene, method)?.ns_per_particle_step / octo)
        }

        /// `f` of `method`'s row on every scene that has one, optionally leaving one out.
        fn each(&self, method: &str, except: Option<&str>, f: impl Fn(&Row) -> f64) -> Vec<f64> {
            self.scenes
                .iter()
                .filter(|s| Some(**s) != except)
                .filter_map(|s| self.row(s, method))
                .map(f)
                .collect()
        }

        /// The methods other than octoproxy-cpu itself and the floor that this run has.
        fn others(&self) -> Vec<&'a str> {
            self.methods
                .iter()
                .copied()
                .filter(|m| *m != "octoproxy-cpu" && *m != "floor")
                .filter(|m| self.scenes.iter().any(|s| self.row(s, m).is_some()))
                .collect()
        }

        /// The scene where octoproxy-cpu is slowest.
        fn slowest(&self) -> &'a Row {
            self.scenes
                .iter()
                .filter_map(|s| self.row(s, "octoproxy-cpu"))
                .max_by(|a, b| a.ns_per_particle_step.total_cmp(&b.ns_per_particle_step))
                .unwrap_or(self.largest)
        }

        fn floor_ns(&self, scene: &str) -> Option<f64> {
            self.row(scene, "floor").map(|r| r.ns_per_particle_step)
        }

        fn table_row(&self, s: &mut String, r: &Row, with_scene: bool) {
            if with_scene {
                let _ = write!(s, "| {} | {} ", r.scene, thousands(r.triangles as u64));
            }
            let vs = self.vs_octo(&r.scene, &r.method).unwrap_or(f64::NAN);
            let floor = self
                .floor_ns(&r.scene)
                .map_or(f64::NAN, |f| r.ns_per_particle_step / f);
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:.1} | {:.2}× | {:.0}× | {} |",
                label(&r.method),
                seconds(r.build_ms),
                human_bytes(r.memory_bytes),
                r.ns_per_particle_step,
                vs,
                floor,
                penetrations(r.penetrations_per_million)
            );
        }

        /// The README's table: every method on the largest scene.
        fn headline(&self) -> String {
            let big = self.largest;
            let mut s = format!(
                "{} ({} triangles), {} particles on {}, {}:\n\n",
                big.scene,
                thousands(big.triangles as u64),
                thousands(self.n as u64),
                self.report.machine,
                self.report.date
            );
            s.push_str("| method | build | memory | ns / particle-step | vs octoproxy-cpu | × floor | penetrations / M |\n");
            s.push_str("|---|---:|---:|---:|---:|---:|---:|\n");
            for m in &self.methods {
                if let Some(r) = self.row(&big.scene, m) {
                    self.table_row(&mut s, r, false);
                }
            }
            s
        }

        /// Every scene, every CPU method.
        fn summary(&self) -> String {
            let gpu = match &self.report.gpu {
                None => "no GPU adapter was found, so there are no GPU rows".to_string(),
                Some(g) if g.contains(", Cpu)") => format!(
                    "the only GPU adapter was a software one ({g}), so the GPU rows time a CPU \
                     emulating a GPU and are not worth reporting here"
                ),
                Some(g) => format!("GPU: {g}"),
            };
            let mut s = format!(
                "Measured {} on {}; {gpu}. {} particles, the CPU methods:\n\n",
                self.report.date,
                self.report.machine,
                thousands(self.n as u64)
            );
            s.push_str("| scene | triangles | method | build | memory | ns / particle-step | vs octoproxy-cpu | × floor | penetrations / M |\n");
            s.push_str("|---|---:|---|---:|---:|---:|---:|---:|---:|\n");
            for scene in &self.scenes {
                for m in &self.methods {
                    if let Some(r) = self.row(scene, m) {
                        self.table_row(&mut s, r, true);
                    }
                }
            }
            s
        }

        /// The figures the account of the run cites, as a list.
        fn findings(&self) -> String {
            let big = self.largest;
            let n = thousands(self.n as u64);
            let mut s = String::new();
            // Leaks.
            let mut clean = Vec::new();
            let mut leaky = Vec::new();
            for m in self.methods.iter().filter(|m| **m != "floor") {
                let pens = self.each(m, None, |r| r.penetrations_per_million);
                if pens.is_empty() {
                    continue;
                }
                if pens.iter().all(|p| *p == 0.0) {
                    clean.push(format!("`{m}`"));
                } else {
                    let lo = pens.iter().copied().fold(f64::INFINITY, f64::min);
                    let hi = pens.iter().copied().fold(0.0, f64::max);
                    let range = if penetrations(lo) == penetrations(hi) {
                        penetrations(lo)
                    } else {
                        format!("{}–{}", penetrations(lo), penetrations(hi))
                    };
                    leaky.push(format!("`{m}` {range}"));
                }
            }
            let _ = writeln!(
                s,
                "- **Penetrations** per million particle-steps, {n} particles: 0 for {} on every \
                 scene{}.",
                and_list(&clean),
                if leaky.is_empty() {
                    String::new()
                } else {
                    format!("; {}", and_list(&leaky))
                }
            );
            // Memory.
            let per_scene = |m: &str| {
                let items: Vec<String> = self
                    .scenes
                    .iter()
                    .filter_map(|sc| self.row(sc, m))
                    .map(|r| {
                        format!(
                            "{} {} ({} triangles)",
                            r.scene,
                            human_bytes(r.memory_bytes),
                            thousands(r.triangles as u64)
                        )
                    })
                    .collect();
                items.join(", ")
            };
            let grow: Vec<String> = self
                .others()
                .into_iter()
                .filter(|m| *m != "octoproxy-cpu-nolut")
                .filter_map(|m| {
                    let r = self.row(&big.scene, m)?;
                    Some(format!("`{m}` {}", human_bytes(r.memory_bytes)))
                })
                .collect();
            let _ = writeln!(
                s,
                "- **Memory:** the proxy takes {}. On {}: {}.",
                per_scene("octoproxy-cpu"),
                big.scene,
                and_list(&grow)
            );
            // Speed on the largest scene, and across the scenes.
            let on_big: Vec<String> = self
                .others()
                .into_iter()
                .filter_map(|m| Some(format!("`{m}` {:.2}×", self.vs_octo(&big.scene, m)?)))
                .collect();
            let _ = writeln!(
                s,
                "- **On the largest scene** ({}, {} triangles, {n} particles) `octoproxy-cpu` \
                 takes {:.1} ns per particle-step; the others take, as a multiple of that: {}.",
                big.scene,
                thousands(big.triangles as u64),
                big.ns_per_particle_step,
                and_list(&on_big)
            );
            let across: Vec<String> = self
                .others()
                .into_iter()
                .map(|m| {
                    let r = self.each(m, None, |r| {
                        self.vs_octo(&r.scene, &r.method).unwrap_or(f64::NAN)
                    });
                    format!("`{m}` {}×", span(r, 2))
                })
                .collect();
            let _ = writeln!(
                s,
                "- **Across the scenes**, as a multiple of `octoproxy-cpu`'s time: {}.",
                and_list(&across)
            );
            let slow = self.slowest();
            let _ = writeln!(
                s,
                "- **The slowest scene** for `octoproxy-cpu` is {} ({:.1} ns per particle-step); \
                 the others take {} ns.",
                slow.scene,
                slow.ns_per_particle_step,
                span(
                    self.each("octoproxy-cpu", Some(&slow.scene), |r| r
                        .ns_per_particle_step),
                    1
                )
            );
            let bakes: Vec<String> = self
                .scenes
                .iter()
                .filter_map(|sc| self.row(sc, "octoproxy-cpu"))
                .map(|r| {
                    format!(
                        "{} {} ({} triangles)",
                        r.scene,
                        seconds(r.build_ms),
                        thousands(r.triangles as u64)
                    )
                })
                .collect();
            let _ = writeln!(s, "- **Bake:** {}.", bakes.join(", "));
            s
        }

        /// octoproxy-cpu by speed band, where the run timed the bands alone.
        fn bands(&self) -> String {
            let bands = BANDS
                .iter()
                .map(|b| format!("{} {}–{}", b.0, b.1, b.2))
                .collect::<Vec<_>>();
            let mut s = format!(
                "`octoproxy-cpu` by speed band ({} depth-8 leaves per step), each band's \
                 particles alone, ns per particle-step (× floor):\n\n",
                and_list(&bands)
            );
            s.push_str("| scene | particles |");
            for b in BANDS {
                let _ = write!(s, " {} |", b.0);
            }
            s.push_str("\n|---|---:|");
            s.push_str(&"---:|".repeat(BANDS.len()));
            s.push('\n');
            for scene in &self.scenes {
                let rows: Vec<&Row> = self
                    .report
                    .rows
                    .iter()
                    .filter(|r| {
                        r.scene == *scene
                            && r.method == "octoproxy-cpu"
                            && r.band != "mixed"
                            && r.is_mesh_case()
                    })
                    .collect();
                let Some(n) = rows.iter().map(|r| r.particles).max() else {
                    continue;
                };
                let _ = write!(s, "| {scene} | {} |", thousands(n as u64));
                for b in BANDS {
                    match rows.iter().find(|r| r.band == b.0 && r.particles == n) {
                        Some(r) => {
                            let _ = write!(
                                s,
                                " {:.1} ({:.1}×) |",
                                r.ns_per_particle_step, r.ratio_to_floor
                            );
                        }
                        None => s.push_str(" – |"),
                    }
                }
                s.push('\n');
            }
            s
        }

        /// The targets of issue 6, against this run.
        fn targets(&self) -> String {
            let slow = self.slowest();
            let mut s = String::new();
            let multiples = self.each("octoproxy-cpu", None, |r| {
                self.floor_ns(&r.scene)
                    .map_or(f64::NAN, |f| r.ns_per_particle_step / f)
            });
            let met = |ok: usize, of: usize| match (ok, of) {
                (_, 0) => "no scene to judge".to_string(),
                (0, _) => "not met on this machine".to_string(),
                (a, b) if a == b => "met on every scene".to_string(),
                (a, b) => format!("met on {a} of {b} scenes"),
            };
            let within = multiples.iter().filter(|x| **x <= 2.0).count();
            let slow_multiple = self
                .floor_ns(&slow.scene)
                .map_or(f64::NAN, |f| slow.ns_per_particle_step / f);
            let _ = writeln!(
                s,
                "- **The step against the floor** (target: within 2×; {}): `octoproxy-cpu` takes \
                 {}× the floor's time ({}: {:.0}×, against a floor of {:.1} ns). The floor itself \
                 comes out at {} ns per particle-step across the scenes. The leaking `sdf-grid`, \
                 one trilinear lookup per step, takes {}× the floor.",
                met(within, multiples.len()),
                span(
                    self.each("octoproxy-cpu", Some(&slow.scene), |r| {
                        self.floor_ns(&r.scene)
                            .map_or(f64::NAN, |f| r.ns_per_particle_step / f)
                    }),
                    0
                ),
                slow.scene,
                slow_multiple,
                self.floor_ns(&slow.scene).unwrap_or(f64::NAN),
                span(self.each("floor", None, |r| r.ns_per_particle_step), 1),
                span(
                    self.each("sdf-grid", None, |r| {
                        self.floor_ns(&r.scene)
                            .map_or(f64::NAN, |f| r.ns_per_particle_step / f)
                    }),
                    0
                )
            );
            for (m, target, what) in [
                ("parry3d", 30.0, "its step, a ray cast through a BVH, takes"),
                (
                    "triangle-octree",
                    3.0,
                    "its step, exact segment tests in its leaves, takes",
                ),
            ] {
                let ratios = self.each(m, None, |r| {
                    self.vs_octo(&r.scene, &r.method).unwrap_or(f64::NAN)
                });
                if ratios.is_empty() {
                    continue;
                }
                let ok = ratios.iter().filter(|x| **x >= target).count();
                let _ = writeln!(
                    s,
                    "- **`{m}`** (target: {target}× `octoproxy-cpu`'s time; {}): {}×; {what} {} ns \
                     ({}: {:.1} ns).",
                    met(ok, ratios.len()),
                    span(ratios, 2),
                    span(self.each(m, Some(&slow.scene), |r| r.ns_per_particle_step), 0),
                    slow.scene,
                    self.row(&slow.scene, m)
                        .map_or(f64::NAN, |r| r.ns_per_particle_step)
                );
            }
            s
        }
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        /// What to run when a region is stale.
        const REFRESH: &str = "cargo xtask bench --docs-only";

        /// Every benchmark figure in the docs is the committed run's: each marked region of
        /// README.md and docs/**.md equals its rendering from docs/bench/results.json, and
        /// results.md is that run's table.
        #[test]
        fn the_figures_in_the_docs_are_the_committed_runs() {
            let root = repo_root();
            let report = load_committed().unwrap_or_else(|e| panic!("{e:#}"));
            let mut problems = missing_regions(&root);
            for file in markdown_files(&root).unwrap() {
                let rel = file
                    .strip_prefix(&root)
                    .unwrap_or(&file)
                    .display()
                    .to_string();
                let text = std::fs::read_to_string(&file).unwrap();
                let regions = match regions(&text) {
                    Ok(r) => r,
                    Err(e) => {
                        problems.push(format!("{rel}: {e:#}"));
                        continue;
                    }
                };
                for r in regions {
                    match render(&r.name, &report) {
                        Ok(want) if want == text[r.content.clone()] => {}
                        Ok(_) => problems.push(format!(
                            "{rel}: the table bench:{} (line {}) is not the rendering of \
                             {COMMITTED_DIR}/results.json",
                            r.name, r.line
                        )),
                        Err(e) => problems.push(format!("{rel}: line {}: {e:#}", r.line)),
                    }
                }
            }
            let md = std::fs::read_to_string(root.join(COMMITTED_DIR).join("results.md"))
                .unwrap_or_default();
            if md != report.markdown() {
                problems.push(format!(
                    "{COMMITTED_DIR}/results.md is not the rendering of {COMMITTED_DIR}/results.json"
                ));
            }
            assert!(
                problems.is_empty(),
                "{}\nrun `{REFRESH}` to rewrite them from the committed results",
                problems.join("\n")
            );
        }

        #[test]
        fn markers_must_pair() {
            let report = load_committed().unwrap();
            let ok = "a\n<!-- bench:table:bands -->\nold\n<!-- /bench:table:bands -->\nb\n";
            let new = rewrite(ok, &report).unwrap();
            assert!(new.starts_with("a\n<!-- bench:table:bands -->\n\n`octoproxy-cpu` by"));
            assert!(new.ends_with("|\n\n<!-- /bench:table:bands -->\nb\n"));
            assert_eq!(rewrite(&new, &report).unwrap(), new);
            for bad in [
                "<!-- bench:table:bands -->\n",
                "<!-- /bench:table:bands -->\n",
                "<!-- bench:table:bands -->\n<!-- /bench:table:summary -->\n",
                "<!-- bench:table:bands -->\n<!-- bench:table:bands -->\n",
                "<!-- bench:table:nothing -->\n<!-- /bench:table:nothing -->\n",
            ] {
                assert!(rewrite(bad, &report).is_err(), "{bad}");
            }
            // Markers in a fenced code block are an example, not a region.
            let shown = "```text\n<!-- bench:table:bands -->\n<!-- /bench:table:nothing -->\n```\n";
            assert_eq!(rewrite(shown, &report).unwrap(), shown);
        }

        /// A run with the scene cases: the mesh scenes' figures leave them out, and their own
        /// region shows them, with the targets judged.
        #[test]
        fn the_gpu_region_shows_the_best_workgroup_size_and_the_sweep() {
            assert!(gpu_region(None).contains("No GPU run is committed yet"));
            let row = |method: &str, size: u32, ns: f64| Row {
                scene: "beast".into(),
                triangles: 64_618,
                particles: 10_000_000,
                method: method.into(),
                backend: "wgpu",
                build_ms: 0.0,
                memory_bytes: 0,
                ns_per_particle_step: ns,
                ratio_to_floor: ns / 0.05,
                penetrations_per_million: 0.0,
                band: "mixed",
                instances: 0,
                moving: 0,
                ratio_to_static: f64::NAN,
                ratio_to_plain: f64::NAN,
                substeps: 0,
                iterations: 0,
                workgroup_size: size,
                ns_min: f64::NAN,
                ns_max: f64::NAN,
                sweep: false,
            };
            let report = Report {
                machine: "host".into(),
                date: "2026-12-04".into(),
                gpu: Some("NVIDIA H200 (Vulkan, DiscreteGpu)".into()),
                profiles: Vec::new(),
                rows: vec![
                    row("floor", 64, 0.05),
                    row("octoproxy-wgpu", 64, 0.2),
                    row("floor", 32, 0.05),
                    row("octoproxy-wgpu", 32, 0.09),
                    row("floor", 256, 0.05),
                    row("octoproxy-wgpu", 256, 0.3),
                    row(SPLIT_METHOD, 64, 0.1),
                ]
                .into_iter()
                .map(|mut q| {
                    q.sweep = q.workgroup_size != 64 || q.method == SPLIT_METHOD;
                    q
                })
                .collect(),
            };
            let text = gpu_region(Some(&report));
            // One line per case (the default size's), with the sweep's best beside it.
            assert!(
                text.contains("| beast | 64,618 | 10,000,000 | 0.05 | 0.20 | 4.0× | 2.000 | 32 | 0.09 | 0.900 |"),
                "{text}"
            );
            assert_eq!(text.matches("| beast | 64,618 |").count(), 1, "{text}");
            assert!(text.contains("| scene | 32 | 64 | 256 |"), "{text}");
            assert!(text.contains("(the run's default was 64)"), "{text}");
            assert!(text.contains("| beast | 0.900 | 2.000 | 3.000 |"), "{text}");
            // 2 ms a step at the default size misses the aim of 1 ms.
            assert!(text.contains("met on 0 of 1 scenes"), "{text}");
            // The split step beside the single dispatch, and in no other table.
            assert!(
                text.contains("beast at 10,000,000: 1.000 against 2.000 ms (0.50×)"),
                "{text}"
            );
            assert_eq!(text.matches("1.000").count(), 1, "{text}");
        }

        #[test]
        fn the_scene_cases_render_apart_from_the_mesh_scenes() {
            let row = |scene: &str, method: &str, ns: f64| Row {
                scene: scene.into(),
                triangles: 25_944,
                particles: 1_000_000,
                method: method.into(),
                backend: "cpu",
                build_ms: 100.0,
                memory_bytes: 1 << 20,
                ns_per_particle_step: ns,
                ratio_to_floor: ns / 1.5,
                penetrations_per_million: 0.0,
                band: "mixed",
                instances: 0,
                moving: 0,
                ratio_to_static: f64::NAN,
                ratio_to_plain: f64::NAN,
                substeps: 0,
                iterations: 0,
                workgroup_size: 0,
                ns_min: f64::NAN,
                ns_max: f64::NAN,
                sweep: false,
            };
            // The committed run without its scene cases, whether it has them or not.
            let mut committed = load_committed().unwrap();
            committed
                .rows
                .retain(|r| r.instances == 0 && !r.method.ends_with(instances::SCENE_API));
            let before = render("table:summary", &committed).unwrap();
            let plain = committed
                .rows
                .iter()
                .find(|r| {
                    r.scene == "nefertiti"
                        && r.method == "octoproxy-cpu"
                        && r.particles == 1_000_000
                })
                .map(|r| r.ns_per_particle_step)
                .expect("the committed run has Nefertiti at 1M particles");
            let mut report = Report {
                rows: committed.rows.clone(),
                ..load_committed().unwrap()
            };
            let mut api = row("nefertiti", "octoproxy-cpu-scene-api", 13.0);
            api.ratio_to_plain = 1.04;
            report.rows.push(api);
            for (n, still, moving) in [(1, 20.0, 30.0), (100, 40.0, 100.0)] {
                let scene = format!("instances-{n}");
                let mut r = row(&scene, "octoproxy-cpu", still);
                r.instances = n;
                report.rows.push(r.clone());
                r.moving = n.div_ceil(2);
                r.ns_per_particle_step = moving;
                r.ratio_to_static = moving / still;
                r.penetrations_per_million = 1.0;
                report.rows.push(r);
            }
            // The mesh scenes' regions are what they were.
            assert_eq!(render("table:summary", &report).unwrap(), before);
            let text = render("table:instances", &report).unwrap();
            assert!(
                text.contains("| 1 | octoproxy-cpu | 20.0 | 30.0 | 1.50× |"),
                "{text}"
            );
            assert!(
                text.contains("| 100 | octoproxy-cpu | 40.0 | 100.0 | 2.50× |"),
                "{text}"
            );
            assert!(
                text.contains("not met on this machine): `octoproxy-cpu` 2.50×"),
                "{text}"
            );
            assert!(
                text.contains(&format!("13.0 ns per particle-step against {plain:.1}")),
                "{text}"
            );
            // A run before the scene cases says how to run them.
            let old = render("table:instances", &committed).unwrap();
            assert!(old.contains("predates the instance cases"), "{old}");
        }

        #[test]
        fn numbers_print_as_the_tables_print_them() {
            assert_eq!(thousands(6_396_032), "6,396,032");
            assert_eq!(thousands(999), "999");
            assert_eq!(thousands(1000), "1,000");
            assert_eq!(span([1.04, 0.96, f64::NAN], 1), "1.0");
            assert_eq!(span([5.59, 14.26], 2), "5.59–14.26");
            assert_eq!(span([], 2), "–");
            assert_eq!(
                and_list(&["a".into(), "b".into(), "c".into()]),
                "a, b and c"
            );
        }
    }
}

/// The JSON that `Report::json` writes, read back: objects, arrays, strings, numbers and null
/// (the crate has no serde, and needs none for its own output).
mod json {
    use anyhow::{anyhow, bail, Context, Result};

    use super::profile::{Profile, LEAF_BINS};
    use super::{Report, Row};
    use octoproxy_core::StepKind;

    #[derive(Debug, PartialEq)]
    pub enum Value {
        Null,
        Bool(bool),
        Number(f64),
        String(String),
        Array(Vec<Value>),
        Object(Vec<(String, Value)>),
    }

    impl Value {
        fn get(&self, key: &str) -> Result<&Value> {
            match self {
                Value::Object(fields) => fields
                    .iter()
                    .find(|(k, _)| k == key)
                    .map(|(_, v)| v)
                    .ok_or_else(|| anyhow!("no \"{key}\"")),
                _ => bail!("not an object (looking for \"{key}\")"),
            }
        }

        fn str(&self, key: &str) -> Result<&str> {
            match self.get(key)? {
                Value::String(s) => Ok(s),
                v => bail!("\"{key}\" is {v:?}, not a string"),
            }
        }

        /// A number; null reads as NaN (how `Report::json` writes a missing figure).
        fn num(&self, key: &str) -> Result<f64> {
            match self.get(key)? {
                Value::Number(x) => Ok(*x),
                Value::Null => Ok(f64::NAN),
                v => bail!("\"{key}\" is {v:?}, not a number"),
            }
        }

        /// Whether the object has `key`.
        fn has(&self, key: &str) -> bool {
            matches!(self, Value::Object(fields) if fields.iter().any(|(k, _)| k == key))
        }

        /// [`Value::num`], or `default` when there is no `key`.
        fn num_or(&self, key: &str, default: f64) -> Result<f64> {
            if self.has(key) {
                self.num(key)
            } else {
                Ok(default)
            }
        }

        /// A boolean, or `default` when there is no `key`.
        fn bool_or(&self, key: &str, default: bool) -> Result<bool> {
            if !self.has(key) {
                return Ok(default);
            }
            match self.get(key)? {
                Value::Bool(b) => Ok(*b),
                v => bail!("\"{key}\" is {v:?}, not true or false"),
            }
        }

        /// [`Value::count`], or `default` when there is no `key`.
        fn count_or(&self, key: &str, default: usize) -> Result<usize> {
            if self.has(key) {
                self.count(key)
            } else {
                Ok(default)
            }
        }

        fn count(&self, key: &str) -> Result<usize> {
            let x = self.num(key)?;
            if !(x >= 0.0 && x.fract() == 0.0 && x <= 1e15) {
                bail!("\"{key}\" is {x}, not a count");
            }
            Ok(x as usize)
        }
    }

    struct Parser<'a> {
        s: &'a [u8],
        at: usize,
    }

    impl Parser<'_> {
        fn skip_space(&mut self) {
            while self.s.get(self.at).is_some_and(|c| c.is_ascii_whitespace()) {
                self.at += 1;
            }
        }

        fn expect(&mut self, c: u8) -> Result<()> {
            self.skip_space();
            if self.s.get(self.at) != Some(&c) {
                bail!("expected '{}' at byte {}", c as char, self.at);
            }
            self.at += 1;
            Ok(())
        }

        fn value(&mut self, depth: usize) -> Result<Value> {
            if depth > 64 {
                bail!("nested too deep at byte {}", self.at);
            }
            self.skip_space();
            let rest = &self.s[self.at..];
            match rest.first() {
                Some(b'{') => {
                    self.at += 1;
                    let mut fields = Vec::new();
                    self.skip_space();
                    if self.s.get(self.at) == Some(&b'}') {
                        self.at += 1;
                        return Ok(Value::Object(fields));
                    }
                    loop {
                        self.skip_space();
                        let key = self.string()?;
                        self.expect(b':')?;
                        fields.push((key, self.value(depth + 1)?));
                        self.skip_space();
                        match self.s.get(self.at) {
                            Some(b',') => self.at += 1,
                            Some(b'}') => {
                                self.at += 1;
                                return Ok(Value::Object(fields));
                            }
                            _ => bail!("expected ',' or '}}' at byte {}", self.at),
                        }
                    }
                }
                Some(b'[') => {
                    self.at += 1;
                    let mut items = Vec::new();
                    self.skip_space();
                    if self.s.get(self.at) == Some(&b']') {
                        self.at += 1;
                        return Ok(Value::Array(items));
                    }
                    loop {
                        items.push(self.value(depth + 1)?);
                        self.skip_space();
                        match self.s.get(self.at) {
                            Some(b',') => self.at += 1,
                            Some(b']') => {
                                self.at += 1;
                                return Ok(Value::Array(items));
                            }
                            _ => bail!("expected ',' or ']' at byte {}", self.at),
                        }
                    }
                }
                Some(b'"') => Ok(Value::String(self.string()?)),
                _ if rest.starts_with(b"null") => {
                    self.at += 4;
                    Ok(Value::Null)
                }
                _ if rest.starts_with(b"true") => {
                    self.at += 4;
                    Ok(Value::Bool(true))
                }
                _ if rest.starts_with(b"false") => {
                    self.at += 5;
                    Ok(Value::Bool(false))
                }
                Some(c) if *c == b'-' || c.is_ascii_digit() => {
                    let len = rest
                        .iter()
                        .take_while(|c| c.is_ascii_digit() || b"+-.eE".contains(c))
                        .count();
                    let text = std::str::from_utf8(&rest[..len]).expect("ASCII");
                    let x: f64 = text
                        .parse()
                        .with_context(|| format!("{text:?} at byte {} is not a number", self.at))?;
                    self.at += len;
                    Ok(Value::Number(x))
                }
                _ => bail!("expected a value at byte {}", self.at),
            }
        }

        fn string(&mut self) -> Result<String> {
            if self.s.get(self.at) != Some(&b'"') {
                bail!("expected a string at byte {}", self.at);
            }
            self.at += 1;
            let mut out = Vec::new();
            loop {
                let Some(&c) = self.s.get(self.at) else {
                    bail!("a string is never closed");
                };
                self.at += 1;
                match c {
                    b'"' => break,
                    b'\\' => {
                        let Some(&e) = self.s.get(self.at) else {
                            bail!("a string is never closed");
                        };
                        self.at += 1;
                        let ch = match e {
                            b'"' => '"',
                            b'\\' => '\\',
                            b'/' => '/',
                            b'n' => '\n',
                            b't' => '\t',
                            b'r' => '\r',
                            b'b' => '\u{8}',
                            b'f' => '\u{c}',
                            b'u' => {
                                let hex = self
                                    .s
                                    .get(self.at..self.at + 4)
                                    .and_then(|h| std::str::from_utf8(h).ok())
                                    .and_then(|h| u32::from_str_radix(h, 16).ok())
                                    .ok_or_else(|| anyhow!("bad \\u escape at byte {}", self.at))?;
                                self.at += 4;
                                char::from_u32(hex).unwrap_or('\u{fffd}')
                            }
                            _ => bail!("bad escape at byte {}", self.at - 1),
                        };
                        let mut buf = [0; 4];
                        out.extend_from_slice(ch.encode_utf8(&mut buf).as_bytes());
                    }
                    c => out.push(c),
                }
            }
            String::from_utf8(out).context("a string is not UTF-8")
        }
    }

    pub fn parse(text: &str) -> Result<Value> {
        let mut p = Parser {
            s: text.as_bytes(),
            at: 0,
        };
        let v = p.value(0)?;
        p.skip_space();
        if p.at != p.s.len() {
            bail!("trailing text at byte {}", p.at);
        }
        Ok(v)
    }

    /// A name the bench writes, as the `&'static str` its rows hold.
    fn known(what: &str, s: &str, names: &[&'static str]) -> Result<&'static str> {
        names.iter().copied().find(|n| *n == s).ok_or_else(|| {
            anyhow!(
                "unknown {what} {s:?} (expected one of {})",
                names.join(", ")
            )
        })
    }

    fn row(r: &Value, bands: &[&'static str]) -> Result<Row> {
        Ok(Row {
            scene: r.str("scene")?.to_string(),
            triangles: r.count("triangles")?,
            particles: r.count("particles")?,
            method: r.str("method")?.to_string(),
            backend: known("backend", r.str("backend")?, &["cpu", "wgpu"])?,
            build_ms: r.num("build_ms")?,
            memory_bytes: r.count("memory_bytes")?,
            ns_per_particle_step: r.num("ns_per_particle_step")?,
            ratio_to_floor: r.num("ratio_to_floor")?,
            penetrations_per_million: r.num("penetrations_per_million_particle_steps")?,
            band: known("speed band", r.str("speed_band")?, bands)?,
            // The scene cases' fields: absent on the other rows, and in runs before them.
            instances: r.count_or("instances", 0)?,
            moving: r.count_or("moving", 0)?,
            ratio_to_static: r.num_or("ratio_to_static", f64::NAN)?,
            ratio_to_plain: r.num_or("ratio_to_plain", f64::NAN)?,
            substeps: r.count_or("substeps", 0)? as u32,
            iterations: r.count_or("iterations", 0)? as u32,
            workgroup_size: r.count_or("workgroup_size", 0)? as u32,
            sweep: r.bool_or("sweep", false)?,
            ns_min: r.num_or("ns_min", f64::NAN)?,
            ns_max: r.num_or("ns_max", f64::NAN)?,
        })
    }

    /// A profile of leaves per step ([`Profile::json`]) back into the profile.
    fn profile(v: &Value) -> Result<Profile> {
        let mut leaves = [0.0; LEAF_BINS.len()];
        for (k, x) in leaves.iter_mut().enumerate() {
            *x = v.num(&format!("leaves_{k}"))?;
        }
        let mut share = [0.0; StepKind::ALL.len()];
        let mut ns = [0.0; StepKind::ALL.len()];
        for k in 0..StepKind::ALL.len() {
            share[k] = v.num(&format!("share_{k}"))?;
            ns[k] = v.num(&format!("ns_{k}"))?;
        }
        Ok(Profile {
            scene: v.str("scene")?.to_string(),
            particles: v.count("particles")?,
            steps: v.count("steps")? as u32,
            leaves,
            mean_leaves: v.num("mean_leaves")?,
            share,
            ns,
        })
    }

    /// A `results.json` back into the report that wrote it.
    pub fn parse_report(text: &str) -> Result<Report> {
        let v = parse(text)?;
        let gpu = match v.get("gpu")? {
            Value::Null => None,
            Value::String(s) => Some(s.clone()),
            g => bail!("\"gpu\" is {g:?}"),
        };
        let Value::Array(items) = v.get("rows")? else {
            bail!("\"rows\" is not an array");
        };
        let bands: Vec<&'static str> = ["mixed", "rain"]
            .into_iter()
            .chain(super::BANDS.iter().map(|b| b.0))
            .collect();
        let rows = items
            .iter()
            .enumerate()
            .map(|(i, r)| row(r, &bands).with_context(|| format!("row {i}")))
            .collect::<Result<Vec<_>>>()?;
        let profiles = if v.has("profiles") {
            let Value::Array(items) = v.get("profiles")? else {
                bail!("\"profiles\" is not an array");
            };
            items
                .iter()
                .enumerate()
                .map(|(i, p)| profile(p).with_context(|| format!("profile {i}")))
                .collect::<Result<Vec<_>>>()?
        } else {
            Vec::new()
        };
        Ok(Report {
            machine: v.str("machine")?.to_string(),
            date: v.str("date")?.to_string(),
            gpu,
            rows,
            profiles,
        })
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn a_report_reads_back_as_written() {
            let report = Report {
                machine: "a \"quoted\" \\ machine\t".into(),
                date: "2026-11-25".into(),
                gpu: None,
                profiles: Vec::new(),
                rows: vec![Row {
                    scene: "bunny".into(),
                    triangles: 69_451,
                    particles: 1_000_000,
                    method: "floor".into(),
                    backend: "cpu",
                    build_ms: 0.0,
                    memory_bytes: 0,
                    ns_per_particle_step: 1.25,
                    ratio_to_floor: 1.0,
                    penetrations_per_million: f64::NAN,
                    band: "slow",
                    instances: 0,
                    moving: 0,
                    ratio_to_static: f64::NAN,
                    ratio_to_plain: f64::NAN,
                    substeps: 0,
                    iterations: 0,
                    workgroup_size: 0,
                    ns_min: f64::NAN,
                    ns_max: f64::NAN,
                    sweep: false,
                }],
            };
            let back = parse_report(&report.json()).unwrap();
            assert_eq!(back.machine, report.machine);
            assert_eq!(back.gpu, None);
            assert_eq!(back.rows.len(), 1);
            let r = &back.rows[0];
            assert_eq!(
                (r.triangles, r.particles, r.band),
                (69_451, 1_000_000, "slow")
            );
            assert_eq!(r.ns_per_particle_step, 1.25);
            assert!(r.penetrations_per_million.is_nan());
            assert_eq!((r.instances, r.moving), (0, 0));
            assert!(r.ratio_to_static.is_nan() && r.ratio_to_plain.is_nan());
            assert_eq!(back.json(), report.json());
            assert!(back.profiles.is_empty());
            // A profile of leaves per step reads back, a kind no particle took included.
            let mut profiled = parse_report(&report.json()).unwrap();
            profiled.profiles.push(Profile {
                scene: "bunny-rain".into(),
                particles: 1_000_000,
                steps: 4,
                leaves: [0.5, 0.25, 0.125, 0.0625, 0.03125, 0.03125, 0.0],
                mean_leaves: 0.875,
                share: [0.5, 0.0, 0.25, 0.125, 0.0625, 0.0625],
                ns: [5.5, f64::NAN, 60.25, 140.5, 500.0, 300.0],
            });
            let p = &parse_report(&profiled.json()).unwrap().profiles[0];
            assert_eq!(p.scene, "bunny-rain");
            assert_eq!((p.particles, p.steps), (1_000_000, 4));
            assert_eq!(p.leaves, profiled.profiles[0].leaves);
            assert_eq!(p.share, profiled.profiles[0].share);
            assert!(p.ns[1].is_nan() && p.ns[4] == 500.0);
            assert_eq!(p.mean_leaves, 0.875);
            // A GPU row's workgroup size and the range of its runs read back too.
            let mut gpu = report.rows[0].clone();
            (gpu.backend, gpu.workgroup_size, gpu.ns_min, gpu.ns_max) = ("wgpu", 256, 1.0, 1.5);
            let one = Report {
                rows: vec![gpu],
                ..Report {
                    machine: report.machine.clone(),
                    date: report.date.clone(),
                    gpu: Some("NVIDIA H200".into()),
                    rows: Vec::new(),
                    profiles: Vec::new(),
                }
            };
            let r = &parse_report(&one.json()).unwrap().rows[0];
            assert_eq!((r.workgroup_size, r.ns_min, r.ns_max), (256, 1.0, 1.5));
            assert!(!r.sweep && r.is_mesh_case());
            let mut swept = one;
            swept.rows[0].sweep = true;
            let r = &parse_report(&swept.json()).unwrap().rows[0];
            assert!(r.sweep && !r.is_mesh_case());
            // The scene cases' fields read back too.
            let mut report = report;
            let r = &mut report.rows[0];
            (r.instances, r.moving, r.ratio_to_static) = (100, 50, 1.5);
            let mut api = r.clone();
            (api.instances, api.moving, api.ratio_to_static) = (0, 0, f64::NAN);
            (api.method, api.ratio_to_plain) = ("octoproxy-cpu-scene-api".into(), 1.02);
            report.rows.push(api);
            let back = parse_report(&report.json()).unwrap();
            let (a, b) = (&back.rows[0], &back.rows[1]);
            assert_eq!((a.instances, a.moving, a.ratio_to_static), (100, 50, 1.5));
            assert_eq!(b.ratio_to_plain, 1.02);
            assert!(!a.is_mesh_case() && !b.is_mesh_case());
            assert_eq!(back.json(), report.json());
            // A particle case's substeps read back, and keep it out of the mesh tables.
            let mut pile = report.rows[0].clone();
            (pile.instances, pile.moving, pile.ratio_to_static) = (0, 0, f64::NAN);
            (pile.method, pile.substeps) = ("octoproxy-cpu-particles".into(), 6);
            report.rows.push(pile);
            let back = parse_report(&report.json()).unwrap();
            assert_eq!(back.rows[2].substeps, 6);
            assert!(!back.rows[2].is_mesh_case());
            assert!(
                back.particle_cases().contains("| cpu | 6 |"),
                "{}",
                back.particle_cases()
            );
            assert_eq!(back.json(), report.json());
        }

        #[test]
        fn bad_json_is_an_error() {
            for bad in ["", "{", "{\"a\": }", "[1,]", "\"open", "{} x", "nul", "-"] {
                assert!(parse(bad).is_err(), "{bad:?}");
            }
            assert_eq!(
                parse(" {\"a\": [1, -2.5e1, null, true, \"\\u00e9\"]} ").unwrap(),
                Value::Object(vec![(
                    "a".into(),
                    Value::Array(vec![
                        Value::Number(1.0),
                        Value::Number(-25.0),
                        Value::Null,
                        Value::Bool(true),
                        Value::String("é".into()),
                    ])
                )])
            );
            assert!(parse_report("{\"machine\": \"m\"}").is_err());
        }
    }
}
