//! `octoproxy bench`: octoproxy against what users would pick instead, in one process, on
//! the same scenes, particles and step parameters. Writes `target/bench/results.json`, a
//! Markdown table and PNG plots, and prints a summary.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::Vec3;
use octoproxy_core::{initial_side, Backend, Particle, ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::ground_truth::GroundTruth;
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

const USAGE: &str = "\
usage: octoproxy bench [--quick] [--backends cpu,wgpu] [--scenes S,S...] [--particles N,N...]

  --quick          one scene (the bunny), 100k particles, every method: a few minutes
  --backends L     which of cpu, wgpu to run (default: both; wgpu only when an adapter exists)
  --scenes L       of bunny, nefertiti, ogre, beast, nefertiti-1.6m, nefertiti-6.4m
                   (default: all)
  --particles L    particle counts (default 10000,100000,1000000,4000000, and 3M and 10M on a
                   hardware GPU; suffixes k and m work)
  --steps N        timed steps per case (default: about 4M particle-steps per case, 2..50)
  --samples N      particles in each penetration check (default 2000; 60 steps each)
  --out DIR        where results go (default target/bench)

Scenes come from ../shared/meshes. Methods: octoproxy-cpu, octoproxy-cpu-nolut,
triangle-octree, parry3d, sdf-grid and floor on the CPU; octoproxy-wgpu and floor on the GPU.";

const ALL_SCENES: [&str; 6] = [
    "bunny",
    "nefertiti",
    "ogre",
    "beast",
    "nefertiti-1.6m",
    "nefertiti-6.4m",
];
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
    /// Particle counts run on a hardware GPU only.
    gpu_only: Vec<usize>,
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
        gpu_only: Vec::new(),
    };
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
                        "wgpu" | "gpu" => o.wgpu = true,
                        other => bail!("--backends: expected cpu and/or wgpu, got {other:?}"),
                    }
                }
            }
            "--scenes" => {
                for s in flags::string(&mut p, "--scenes")?.split(',') {
                    let s = s.trim();
                    if !ALL_SCENES.contains(&s) {
                        bail!(
                            "--scenes: unknown scene {s:?} (scenes: {})",
                            ALL_SCENES.join(", ")
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
            "--out" | "-o" => o.out = flags::path(&mut p, "--out")?,
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
            ALL_SCENES.iter().map(|s| s.to_string()).collect()
        };
    }
    if o.particles.is_empty() {
        o.particles = if o.quick {
            vec![100_000]
        } else {
            vec![10_000, 100_000, 1_000_000, 4_000_000]
        };
        if !o.quick {
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
    name: String,
    mesh: Mesh,
    closed: bool,
}

fn meshes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/meshes")
}

fn load_scene(name: &str) -> Result<SceneData> {
    let (file, closed, subdivisions) = match name {
        "bunny" => ("stanford-bunny.obj.gz", false, 0),
        "nefertiti" => ("nefertiti.obj.gz", true, 0),
        "ogre" => ("ogre.obj.gz", false, 0),
        "beast" => ("beast.obj.gz", false, 0),
        "nefertiti-1.6m" => ("nefertiti.obj.gz", true, 2),
        "nefertiti-6.4m" => ("nefertiti.obj.gz", true, 3),
        _ => bail!("unknown scene {name}"),
    };
    let path = meshes_dir().join(file);
    if !path.exists() {
        bail!(
            "the benchmark scenes come from ../shared/meshes, and {} is not there (the bench needs those meshes)",
            path.display()
        );
    }
    let (mut mesh, _) = load_mesh(&path)?;
    for _ in 0..subdivisions {
        mesh = subdivide(&mesh);
    }
    Ok(SceneData {
        name: name.to_string(),
        mesh,
        closed,
    })
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

/// Penetrations per million particle-steps: particles whose step chord crosses the mesh an
/// odd number of times (or, for closed meshes, whose inside/outside changes) and that end
/// farther than `tol` from the surface. Each particle counts once at most.
fn penetration_rate(
    gt: &GroundTruth,
    closed: bool,
    tol: f32,
    start: &[Particle],
    steps: u32,
    step: &(dyn Fn(&mut Particle) + Sync),
) -> f64 {
    let tol = tol as f64;
    let bad: u64 = start
        .par_iter()
        .map(|p0| {
            let mut p = *p0;
            let mut inside = closed && gt.is_inside(p.position);
            for _ in 0..steps {
                let a = p.position;
                step(&mut p);
                let b = p.position;
                if !b.iter().all(|c| c.is_finite()) {
                    return 0;
                }
                let far = gt.distance_capped(b, 2.0 * tol) > tol;
                let crossed = a != b && gt.segment_crossings(a, b) % 2 == 1;
                let now_inside = closed && gt.is_inside(b);
                if far && (crossed || now_inside != inside) {
                    return 1;
                }
                if far {
                    inside = now_inside;
                }
            }
            0
        })
        .sum();
    bad as f64 * 1e6 / (start.len() as f64 * steps as f64).max(1.0)
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
    std::fs::create_dir_all(&o.out).with_context(|| format!("creating {}", o.out.display()))?;
    let params = StepParams::default();
    let mut gpu = if o.wgpu {
        match WgpuBackend::new() {
            Ok(g) => {
                eprintln!("wgpu: {}", g.description());
                Some(g)
            }
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
    let total_cases = o.scenes.len() * (o.particles.len() + gpu_extra + 2);
    let bar = crate::progress::bar(total_cases as u64, "bench");
    let mut rows: Vec<Row> = Vec::new();
    for name in &o.scenes {
        bar.set_message(format!("{name}: loading"));
        let scene = load_scene(name)?;
        let (positions, triangles) = (&scene.mesh.positions, &scene.mesh.triangles);
        let tris = triangles.len();
        bar.set_message(format!("{name}: building"));
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

        // Penetrations, per method, on a sample.
        bar.set_message(format!("{name}: penetration checks"));
        let gt = GroundTruth::new(positions, triangles);
        let tol = view.finest_leaf_size() * 3f32.sqrt();
        let all_bands: Vec<(f32, f32)> = BANDS.iter().map(|b| (b.1, b.2)).collect();
        // The guarantee is for particles that start outside the surface shell: more than one
        // dmax-leaf diagonal from the surface. Closer in, a particle takes the side of its
        // leaf's mean plane, which a curved surface may contradict by a hair.
        let mut sample = make_particles(&view, o.samples * 2, &all_bands, 99);
        sample.retain(|p| gt.distance_capped(p.position, 2.0 * tol as f64) > tol as f64);
        sample.truncate(o.samples);
        let check_steps = 60;
        let lut_view = view;
        let nolut_view = view.without_lut();
        let pen_octo = penetration_rate(&gt, scene.closed, tol, &sample, check_steps, &|p| {
            octoproxy_core::step_particle(&lut_view, p, &params);
        });
        let mut pen_methods = Vec::new();
        for (m, _) in &methods {
            pen_methods.push(penetration_rate(
                &gt,
                scene.closed,
                tol,
                &sample,
                check_steps,
                &|p| m.step(p, &params),
            ));
        }
        bar.inc(1);

        let mut cpu = CpuBackend::new();
        cpu.upload_proxy(&words)?;
        if let Some(g) = gpu.as_mut() {
            g.upload_proxy(&words)?;
        }
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
            bar.set_message(format!("{name}: {n} particles"));
            let steps = o
                .steps
                .unwrap_or(((4_000_000 / n.max(1)) as u32).clamp(2, 50));
            // The mixed case, then (at the largest count) each speed band alone.
            let mut cases: Vec<(&'static str, Vec<(f32, f32)>)> =
                vec![("mixed", all_bands.clone())];
            if n == largest && run_cpu {
                cases.extend(BANDS.iter().map(|b| (b.0, vec![(b.1, b.2)])));
            }
            for (band, bands) in cases {
                let particles = make_particles(&view, n, &bands, 7);
                let row = |method: &str,
                           backend: &'static str,
                           build_ms: f64,
                           memory: usize,
                           ns: f64,
                           pen: f64| Row {
                    scene: scene.name.clone(),
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
                };
                let mut case_rows = Vec::new();
                if run_cpu {
                    // Every method gets one untimed step first; octoproxy's leaf hints are
                    // warm after it, as they are in any simulation after its first step.
                    cpu.upload_particles(&particles)?;
                    cpu.integrate_only(&params, 1)?;
                    let t = Instant::now();
                    cpu.integrate_only(&params, steps)?;
                    let floor_ns = t.elapsed().as_secs_f64() * 1e9 / (n as f64 * steps as f64);
                    cpu.upload_particles(&particles)?;
                    cpu.step(&params, 1)?;
                    let t = Instant::now();
                    cpu.step(&params, steps)?;
                    let octo_ns = t.elapsed().as_secs_f64() * 1e9 / (n as f64 * steps as f64);
                    case_rows.push(row("floor", "cpu", 0.0, 0, floor_ns, f64::NAN));
                    case_rows.push(row(
                        "octoproxy-cpu",
                        "cpu",
                        bake_ms,
                        proxy_bytes,
                        octo_ns,
                        pen_octo,
                    ));
                    if band == "mixed" {
                        cpu.set_use_lut(false);
                        cpu.upload_particles(&particles)?;
                        cpu.step(&params, 1)?;
                        let t = Instant::now();
                        cpu.step(&params, steps)?;
                        let ns = t.elapsed().as_secs_f64() * 1e9 / (n as f64 * steps as f64);
                        cpu.set_use_lut(true);
                        let pen =
                            penetration_rate(&gt, scene.closed, tol, &sample, check_steps, &|p| {
                                octoproxy_core::step_particle(&nolut_view, p, &params);
                            });
                        case_rows.push(row(
                            "octoproxy-cpu-nolut",
                            "cpu",
                            bake_ms,
                            proxy_bytes - view.lut_bytes(),
                            ns,
                            pen,
                        ));
                        for ((m, build_ms), pen) in methods.iter().zip(&pen_methods) {
                            let ns = time_steps(&particles, steps, &mut |ps| {
                                ps.par_iter_mut()
                                    .with_min_len(256)
                                    .for_each(|p| m.step(p, &params));
                                Ok(())
                            })?;
                            case_rows.push(row(
                                m.name(),
                                "cpu",
                                *build_ms,
                                m.memory_bytes(),
                                ns,
                                *pen,
                            ));
                        }
                    }
                }
                if let Some(g) = gpu.as_mut() {
                    g.upload_particles(&particles)?;
                    g.integrate_only(&params, 1)?;
                    g.wait()?;
                    let t = Instant::now();
                    g.integrate_only(&params, steps)?;
                    g.wait()?;
                    let floor_ns = t.elapsed().as_secs_f64() * 1e9 / (n as f64 * steps as f64);
                    g.upload_particles(&particles)?;
                    g.step(&params, 1)?;
                    g.wait()?;
                    let t = Instant::now();
                    g.step(&params, steps)?;
                    g.wait()?;
                    let octo_ns = t.elapsed().as_secs_f64() * 1e9 / (n as f64 * steps as f64);
                    case_rows.push(row("floor", "wgpu", 0.0, 0, floor_ns, f64::NAN));
                    case_rows.push(row(
                        "octoproxy-wgpu",
                        "wgpu",
                        bake_ms,
                        proxy_bytes,
                        octo_ns,
                        pen_octo,
                    ));
                }
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
                rows.extend(case_rows);
            }
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    let report = Report {
        machine: machine(),
        date: today(),
        gpu: gpu.as_ref().map(|g| g.description().to_string()),
        rows,
    };
    report.write(&o.out)?;
    report.print_summary();
    Ok(())
}

/// Everything one run measured.
pub struct Report {
    pub machine: String,
    pub date: String,
    pub gpu: Option<String>,
    pub rows: Vec<Row>,
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
                "    {{\"scene\": {}, \"triangles\": {}, \"particles\": {}, \"method\": {}, \"backend\": {}, \"speed_band\": {}, \"build_ms\": {}, \"memory_bytes\": {}, \"ns_per_particle_step\": {}, \"ratio_to_floor\": {}, \"penetrations_per_million_particle_steps\": {}}}",
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
            s.push_str(if i + 1 < self.rows.len() { ",\n" } else { "\n" });
        }
        s.push_str("  ]\n}\n");
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
        s.push_str("| scene | triangles | particles | method | build (ms) | memory | ns / particle-step | ms / step | × floor | penetrations / M steps |\n");
        s.push_str("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|\n");
        for r in self.rows.iter().filter(|r| r.band == "mixed") {
            let method = if r.method == "floor" {
                format!("floor ({})", r.backend)
            } else {
                r.method.clone()
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {:.1} | {:.2} | {} | {} |",
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
                r.ns_per_particle_step * r.particles as f64 * 1e-6,
                fmt_opt(r.ratio_to_floor, 2),
                fmt_opt(r.penetrations_per_million, 1)
            );
        }
        let bands: Vec<&Row> = self
            .rows
            .iter()
            .filter(|r| r.band != "mixed" && r.method != "floor")
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
        for r in self.rows.iter().filter(|r| r.band == "mixed" && filter(r)) {
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
        if let Some(big) = self.rows.iter().max_by_key(|r| r.triangles) {
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
        if let Some(n) = self.rows.iter().map(|r| r.particles).max() {
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
        // The targets: 1M particles (or the largest count the CPU ran) on the largest scene.
        let cpu_rows = || {
            self.rows
                .iter()
                .filter(|r| r.method == "octoproxy-cpu" && r.band == "mixed")
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
