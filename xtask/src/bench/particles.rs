//! The bench's cases of particles that collide with each other (`Backend::step_pairs`, the
//! uniform-grid pass and the march at a radius). `particles-pile`: a dense block of grains, one
//! per cell, 64 by 64 wide and as deep as the count asks, set down at rest on a floor. `particles-cloud`:
//! a sparse cloud, one grain per 8 radii cubed (about one in 30 cells), spread over a cube
//! above the same floor and falling onto it. Both at the radius [`RADIUS`], `dt` 1/60 and the
//! automatic substeps, timed as a whole and, on the CPU, apart: the sort, the neighbour loop
//! and the march ([`octoproxy_cpu::PairTimings`]).

use std::time::Instant;

use anyhow::{bail, Context, Result};
use octoproxy_core::{Backend, PairParams, Particle, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::{bake_with_radius, scenes, BuildParams, CpuBackend, MeshRef};

use super::{Row, DT};

/// The cases.
pub const SCENES: [&str; 2] = ["particles-pile", "particles-cloud"];

/// The particles' radius (metres; the floor is about 1.4 m wide).
pub const RADIUS: f32 = 0.01;

/// The pile is this many grains wide along x and z.
pub const PILE_WIDTH: usize = 64;

/// The floor's proxy depth: its finest leaf's diagonal is under the radius, as a radius bake
/// asks.
const DMAX: u32 = 8;

/// The method names: the whole step, and its three parts on the CPU.
pub const METHOD: &str = "-particles";
pub const PARTS: [&str; 3] = ["-sort", "-neighbours", "-march"];

/// Whether `name` is a case of this module.
pub fn is_case(name: &str) -> bool {
    SCENES.contains(&name)
}

/// The floor under both cases and its proxy baked for [`RADIUS`].
pub struct Floor {
    words: Vec<u32>,
    triangles: usize,
    bake_ms: f64,
    /// The floor's top, `y`.
    top: f32,
}

impl Floor {
    pub fn new() -> Result<Self> {
        let spacing = pile_spacing();
        let width = PILE_WIDTH as f32 * spacing + 10.0 * RADIUS;
        let thickness = 0.05;
        let mesh = scenes::slab([0.0, -thickness / 2.0, 0.0], [width, thickness, width]);
        let params = BuildParams {
            dmax: DMAX,
            ..BuildParams::default()
        };
        let t = Instant::now();
        let (words, _) = bake_with_radius(&[MeshRef::from(&mesh)], &params, RADIUS, &())
            .context("baking the particle cases' floor")?;
        Ok(Floor {
            words,
            triangles: mesh.triangles.len(),
            bake_ms: t.elapsed().as_secs_f64() * 1e3,
            top: 0.0,
        })
    }
}

/// The pile's lattice spacing: touching, and a thousandth of the diameter apart.
fn pile_spacing() -> f32 {
    2.0 * RADIUS * 1.001
}

/// The particles of a case, at rest (the pile) or moving slowly in random directions (the
/// cloud), every one outside the floor's band.
pub fn case_particles(name: &str, floor: &Floor, n: usize) -> Result<Vec<Particle>> {
    let mut rng = Rng::new(0x5eed_0023);
    let mut ps = Vec::with_capacity(n);
    match name {
        "particles-pile" => {
            let s = pile_spacing();
            let layer = PILE_WIDTH * PILE_WIDTH;
            let at = |i: usize| (i as f32 - (PILE_WIDTH - 1) as f32 / 2.0) * s;
            // The lowest layer a thousandth of a radius above where it rests on the floor
            // (centres a radius from it): the block stands on the floor from the start and
            // presses under gravity, instead of falling onto it within the timed steps.
            for k in 0..n {
                let (y, rest) = (k / layer, k % layer);
                let (z, x) = (rest / PILE_WIDTH, rest % PILE_WIDTH);
                let j = 1e-3 * RADIUS;
                ps.push(Particle::new(
                    [
                        at(x) + j * rng.range(-1.0, 1.0),
                        floor.top + RADIUS * 1.001 + y as f32 * s,
                        at(z) + j * rng.range(-1.0, 1.0),
                    ],
                    [0.0; 3],
                ));
            }
        }
        "particles-cloud" => {
            let side = (n as f32).cbrt() * 8.0 * RADIUS;
            for _ in 0..n {
                let v = rng.unit_vector() * rng.range(0.0, 0.5);
                ps.push(Particle::new(
                    [
                        rng.range(-side / 2.0, side / 2.0),
                        floor.top + 2.0 * RADIUS + rng.range(0.0, side),
                        rng.range(-side / 2.0, side / 2.0),
                    ],
                    v.to_array(),
                ));
            }
        }
        _ => bail!("not a particle case: {name}"),
    }
    Ok(ps)
}

/// The step parameters of the cases.
pub fn params() -> StepParams {
    StepParams {
        radius: RADIUS,
        dt: DT,
        ..StepParams::default()
    }
}

/// The substeps a step took on average (rounded), from the pass's report: they follow the
/// fastest particle (`octoproxy_core::pair_substeps_for`).
fn mean_substeps(report: &octoproxy_core::PairReport) -> u32 {
    (report.substeps as f64 / report.steps.max(1) as f64).round() as u32
}

/// The Jacobi iterations a substep took on average (rounded), from the pass's report: they
/// follow how deep the particles stand (`octoproxy_core::pair_iterations_for`).
fn mean_iterations(report: &octoproxy_core::PairReport) -> u32 {
    (report.iterations as f64 / report.substeps.max(1) as f64).round() as u32
}

/// Times one case: the floor (integration only), the step with the pass on the CPU (whole and
/// in parts) and, given one, on a GPU (whole). One untimed step first, from the same start.
pub fn time_case(
    name: &str,
    floor: &Floor,
    n: usize,
    steps: u32,
    cpu: bool,
    gpu: Option<&mut octoproxy_wgpu::WgpuBackend>,
) -> Result<Vec<Row>> {
    let particles = case_particles(name, floor, n)?;
    let params = params();
    let pairs = PairParams::default();
    // The floor's rows carry gravity's substeps, the fewest a step takes: a particle case's
    // rows are those with substeps.
    let base = octoproxy_core::pair_substeps(&params, &pairs);
    let row =
        |method: String, backend: &'static str, ns: f64, (substeps, iterations): (u32, u32)| Row {
            scene: name.to_string(),
            triangles: floor.triangles,
            particles: n,
            build_ms: if method == "floor" {
                0.0
            } else {
                floor.bake_ms
            },
            memory_bytes: if method == "floor" {
                0
            } else {
                floor.words.len() * 4
            },
            method,
            backend,
            ns_per_particle_step: ns,
            ratio_to_floor: f64::NAN,
            penetrations_per_million: f64::NAN,
            band: "mixed",
            instances: 0,
            moving: 0,
            ratio_to_static: f64::NAN,
            ratio_to_plain: f64::NAN,
            substeps,
            iterations,
            workgroup_size: 0,
            ns_min: f64::NAN,
            ns_max: f64::NAN,
            sweep: false,
        };
    let per_step = |secs: f64| secs * 1e9 / (n as f64 * steps as f64);
    let mut rows = Vec::new();
    if cpu {
        let mut c = CpuBackend::new();
        c.upload_particles(&particles)?;
        c.integrate_only(&params, 1)?;
        let t = Instant::now();
        c.integrate_only(&params, steps)?;
        rows.push(row(
            "floor".into(),
            "cpu",
            per_step(t.elapsed().as_secs_f64()),
            (base, 0),
        ));
        c.upload_proxy(&floor.words)?;
        c.upload_particles(&particles)?;
        c.step_pairs(&params, &pairs, 1)?;
        c.take_pair_timings();
        c.take_pair_report()?;
        let t = Instant::now();
        c.step_pairs(&params, &pairs, steps)?;
        let whole = per_step(t.elapsed().as_secs_f64());
        let parts = c.take_pair_timings();
        let report = c.take_pair_report()?;
        let substeps = (mean_substeps(&report), mean_iterations(&report));
        rows.push(row(
            format!("octoproxy-cpu{METHOD}"),
            "cpu",
            whole,
            substeps,
        ));
        for (part, d) in PARTS
            .iter()
            .zip([parts.sort, parts.neighbours, parts.march])
        {
            rows.push(row(
                format!("octoproxy-cpu{METHOD}{part}"),
                "cpu",
                per_step(d.as_secs_f64()),
                substeps,
            ));
        }
    }
    if let Some(g) = gpu {
        g.upload_proxy(&floor.words)?;
        g.upload_particles(&particles)?;
        super::warm_gpu(g, &params)?;
        g.upload_particles(&particles)?;
        g.integrate_only(&params, 1)?;
        g.wait()?;
        let t = Instant::now();
        g.integrate_only(&params, steps)?;
        g.wait()?;
        rows.push(row(
            "floor".into(),
            "wgpu",
            per_step(t.elapsed().as_secs_f64()),
            (base, 0),
        ));
        g.upload_particles(&particles)?;
        g.step_pairs(&params, &pairs, 1)?;
        g.wait()?;
        g.take_pair_report()?;
        let t = Instant::now();
        g.step_pairs(&params, &pairs, steps)?;
        g.wait()?;
        let whole = per_step(t.elapsed().as_secs_f64());
        let report = g.take_pair_report()?;
        let substeps = (mean_substeps(&report), mean_iterations(&report));
        rows.push(row(
            format!("octoproxy-wgpu{METHOD}"),
            "wgpu",
            whole,
            substeps,
        ));
    }
    Ok(rows)
}
