//! What the mesh scenes' particles do in a step, and what each kind of step costs: the recipe
//! case's gravity, the rain case's particles, and the profile of leaves visited per step.
//!
//! - **The recipe case** (the mesh scenes' `mixed` rows and the speed bands) steps with gravity
//!   scaled to the scene ([`recipe_params`]): the 60 steps of a penetration check add a tenth
//!   of a depth-8 leaf per step to a particle's speed, so the bands' speeds (0.1 to 5 leaves per
//!   step) hold after gravity on every scene, whatever its units. Under the default 9.81 m/s²
//!   every bunny particle (a 16 cm model) crossed 4 to 20 leaves per step.
//! - **The rain case** (scenes `<mesh>-rain`, [`rain_particles`]): particles falling through
//!   the scene at 5 % to 100 % of the scene's size per step, as rain at its terminal speed
//!   (about 9 m/s) falls through a 16 cm model at 60 steps a second, with a tenth of that
//!   across. They start spread over the column they fall through during the run, so the rain
//!   in the scene's box stays as dense from the first timed step to the last.
//! - **The profile** ([`profile`]): octoproxy's step replayed with [`step_particle_profiled`]
//!   from the state the timed run starts in: the share of particle-steps by leaves visited,
//!   and each kind of step ([`StepKind`]: settled in its hinted leaf, one leaf, two, several,
//!   colliding, inside a surface leaf) replayed alone from that state, ns per step.

use std::fmt::Write as _;
use std::time::Instant;

use glam::Vec3;
use octoproxy_core::{
    initial_side, step_particle_hinted, step_particle_profiled, LeafHint, Particle, ProxyView,
    StepKind, StepParams,
};
use octoproxy_cpu::emit::Rng;
use rayon::prelude::*;

use super::{json_num, json_str, Report, Row, DT};

/// The rain case's scenes: each mesh scene's name with this suffix.
pub const RAIN: &str = "-rain";

/// Leaves visited per step, as the profile counts them: each bin's least and most, and its
/// name.
pub const LEAF_BINS: [(u32, u32, &str); 7] = [
    (0, 0, "0"),
    (1, 1, "1"),
    (2, 2, "2"),
    (3, 4, "3–4"),
    (5, 8, "5–8"),
    (9, 16, "9–16"),
    (17, u32::MAX, "17+"),
];

/// The steps of a penetration check, over which [`recipe_params`]' gravity adds a tenth of a
/// depth-8 leaf per step to a speed.
const RECIPE_STEPS: f32 = 60.0;

/// The recipe case's step parameters on `view`'s scene: the defaults, with gravity (down
/// along y) scaled to the scene so that [`RECIPE_STEPS`] steps add a tenth of a depth-8 leaf
/// per step to a particle's speed.
pub fn recipe_params(view: &ProxyView<'_>) -> StepParams {
    let leaf8 = view.header().root_size / 256.0;
    let g = 0.1 * leaf8 / (RECIPE_STEPS * DT * DT);
    StepParams {
        gravity: [0.0, -g, 0.0],
        ..StepParams::default()
    }
}

/// `n` raindrops for a run of `steps` steps after one untimed step: straight down at 5 % to
/// 100 % of the root's size per step, up to a tenth of that across, spread over the root's
/// width and over the column each falls through in the run (the root's height plus its
/// fall), sides from the proxy.
pub fn rain_particles(view: &ProxyView<'_>, n: usize, steps: u32, seed: u64) -> Vec<Particle> {
    let root = view.root_aabb();
    let size = view.header().root_size;
    (0..n)
        .into_par_iter()
        .chunks(4096)
        .flat_map_iter(|idx| {
            let mut rng = Rng::new(seed ^ (idx[0] as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            idx.into_iter()
                .map(|_| {
                    let fall = rng.range(0.05, 1.0) * size / DT;
                    let v = Vec3::new(
                        rng.range(-0.1, 0.1) * fall,
                        -fall,
                        rng.range(-0.1, 0.1) * fall,
                    );
                    let column = size + fall * DT * (steps as f32 + 2.0);
                    let p = Vec3::new(
                        rng.range(root.min.x, root.max.x),
                        root.min.y + rng.range(0.0, column),
                        rng.range(root.min.z, root.max.z),
                    );
                    let mut q = Particle::new(p.to_array(), v.to_array());
                    q.side = initial_side(view, q.position);
                    q
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// The profile of one case: leaves visited per step and the cost of each kind of step.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    /// The case's scene (`bunny`, `bunny-rain`, ...).
    pub scene: String,
    pub particles: usize,
    /// The steps counted (those of the timed run).
    pub steps: u32,
    /// The share of particle-steps in each of [`LEAF_BINS`].
    pub leaves: [f64; LEAF_BINS.len()],
    /// Leaves visited per step, the mean.
    pub mean_leaves: f64,
    /// The share of each kind of step ([`StepKind::ALL`]'s order) in the first counted step.
    pub share: [f64; StepKind::ALL.len()],
    /// Each kind's particles replayed alone from that step's start: ns per step (NaN for a
    /// kind no particle took).
    pub ns: [f64; StepKind::ALL.len()],
}

impl Profile {
    /// One JSON object, flat: `leaves_K` for [`LEAF_BINS`], `share_K` and `ns_K` for
    /// [`StepKind::ALL`].
    pub fn json(&self) -> String {
        let mut s = format!(
            "{{\"scene\": {}, \"particles\": {}, \"steps\": {}, \"mean_leaves\": {}",
            json_str(&self.scene),
            self.particles,
            self.steps,
            json_num(self.mean_leaves)
        );
        // Shares to 1e-9, so that one step in a million still reads back as more than none.
        let share = |x: f64| format!("{x:.9}");
        for (k, x) in self.leaves.iter().enumerate() {
            let _ = write!(s, ", \"leaves_{k}\": {}", share(*x));
        }
        for k in 0..StepKind::ALL.len() {
            let _ = write!(
                s,
                ", \"share_{k}\": {}, \"ns_{k}\": {}",
                share(self.share[k]),
                json_num(self.ns[k])
            );
        }
        s.push('}');
        s
    }

    /// The time of a step of the mix by its parts: each kind's share times its cost alone.
    pub fn ns_by_parts(&self) -> f64 {
        self.share
            .iter()
            .zip(&self.ns)
            .filter(|(s, _)| **s > 0.0)
            .map(|(s, ns)| s * ns)
            .sum()
    }
}

/// Steps every particle once with its hint, in parallel, as the CPU backend does.
fn step_all(view: &ProxyView<'_>, ps: &mut [Particle], hints: &mut [LeafHint], p: &StepParams) {
    ps.par_iter_mut()
        .zip(hints.par_iter_mut())
        .with_min_len(256)
        .for_each(|(q, h)| {
            step_particle_hinted(view, q, p, h);
        });
}

/// The profile of `particles` stepped `steps` times on `view` after one untimed step, as
/// the bench times them ([`Profile`]).
pub fn profile(
    scene: &str,
    view: &ProxyView<'_>,
    particles: &[Particle],
    params: &StepParams,
    steps: u32,
) -> Profile {
    let n = particles.len();
    let mut ps = particles.to_vec();
    let mut hints = vec![LeafHint::NONE; n];
    step_all(view, &mut ps, &mut hints, params);
    let (start, start_hints) = (ps.clone(), hints.clone());
    let mut first = vec![0u8; n];
    let mut bins = [0u64; LEAF_BINS.len()];
    let mut kinds = [0u64; StepKind::ALL.len()];
    let mut leaves = 0u64;
    type Counts = ([u64; LEAF_BINS.len()], [u64; StepKind::ALL.len()], u64);
    let zero = || -> Counts { ([0; LEAF_BINS.len()], [0; StepKind::ALL.len()], 0) };
    for s in 0..steps.max(1) {
        let (b, k, l) = ps
            .par_iter_mut()
            .zip(hints.par_iter_mut())
            .zip(first.par_iter_mut())
            .with_min_len(1024)
            .fold(zero, |mut acc, ((q, h), f)| {
                let (_, pr) = step_particle_profiled(view, q, params, h);
                let bin = LEAF_BINS
                    .iter()
                    .position(|b| (b.0..=b.1).contains(&pr.leaves))
                    .unwrap_or(LEAF_BINS.len() - 1);
                acc.0[bin] += 1;
                acc.2 += pr.leaves as u64;
                if s == 0 {
                    let k = StepKind::ALL
                        .iter()
                        .position(|k| *k == pr.kind)
                        .unwrap_or(0);
                    acc.1[k] += 1;
                    *f = k as u8;
                }
                acc
            })
            .reduce(zero, |mut a, b| {
                a.0.iter_mut().zip(b.0).for_each(|(x, y)| *x += y);
                a.1.iter_mut().zip(b.1).for_each(|(x, y)| *x += y);
                a.2 += b.2;
                a
            });
        bins.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        kinds.iter_mut().zip(k).for_each(|(x, y)| *x += y);
        leaves += l;
    }
    let counted = (n as f64 * steps.max(1) as f64).max(1.0);
    let mut ns = [f64::NAN; StepKind::ALL.len()];
    for (k, out) in ns.iter_mut().enumerate() {
        let idx: Vec<usize> = (0..n).filter(|&i| first[i] as usize == k).collect();
        if idx.is_empty() {
            continue;
        }
        let sub: Vec<Particle> = idx.iter().map(|&i| start[i]).collect();
        let sub_hints: Vec<LeafHint> = idx.iter().map(|&i| start_hints[i]).collect();
        // At least about two million particle-steps a kind, and three runs.
        let runs = (2_000_000 / idx.len()).clamp(3, 50);
        let mut times: Vec<f64> = (0..runs)
            .map(|_| {
                let (mut q, mut h) = (sub.clone(), sub_hints.clone());
                let t = Instant::now();
                step_all(view, &mut q, &mut h, params);
                t.elapsed().as_secs_f64() * 1e9 / idx.len() as f64
            })
            .collect();
        times.sort_by(f64::total_cmp);
        *out = times[times.len() / 2];
    }
    Profile {
        scene: scene.to_string(),
        particles: n,
        steps: steps.max(1),
        leaves: bins.map(|b| b as f64 / counted),
        mean_leaves: leaves as f64 / counted,
        share: kinds.map(|k| k as f64 / (n as f64).max(1.0)),
        ns,
    }
}

/// The count the docs' tables show: 1M particles where the run has them, else its largest
/// octoproxy-cpu count.
fn shown_count(report: &Report) -> Option<usize> {
    let counts = report
        .rows
        .iter()
        .filter(|r| r.method == "octoproxy-cpu" && r.backend == "cpu" && r.is_mesh_case())
        .map(|r| r.particles);
    let all: Vec<usize> = counts.collect();
    if all.contains(&1_000_000) {
        Some(1_000_000)
    } else {
        all.into_iter().max()
    }
}

/// The CPU row of `method` in `scene`'s recipe (`mixed`) or rain case at `n` particles.
fn cpu_row<'a>(report: &'a Report, scene: &str, method: &str, n: usize) -> Option<&'a Row> {
    report.rows.iter().find(|r| {
        r.scene == scene
            && r.method == method
            && r.backend == "cpu"
            && r.particles == n
            && (r.band == "mixed" || r.band == "rain")
            && r.is_mesh_case()
    })
}

/// The mesh scenes of the run in its order, recipe cases (`rain` false) or rain cases.
fn case_scenes(report: &Report, rain: bool) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    for r in &report.rows {
        let wanted = if rain { "rain" } else { "mixed" };
        if r.band == wanted
            && r.method == "octoproxy-cpu"
            && r.is_mesh_case()
            && !out.contains(&r.scene.as_str())
        {
            out.push(&r.scene);
        }
    }
    out
}

/// `a / b` of two rows' medians, with the widest span their runs allow:
/// `a.min / b.max` to `a.max / b.min` (each a row's median where it has one run).
fn ratio(a: &Row, b: &Row) -> (f64, f64, f64) {
    let lo = |r: &Row| {
        if r.ns_min.is_finite() {
            r.ns_min
        } else {
            r.ns_per_particle_step
        }
    };
    let hi = |r: &Row| {
        if r.ns_max.is_finite() {
            r.ns_max
        } else {
            r.ns_per_particle_step
        }
    };
    (
        a.ns_per_particle_step / b.ns_per_particle_step,
        lo(a) / hi(b),
        hi(a) / lo(b),
    )
}

fn fmt_ratio((x, lo, hi): (f64, f64, f64)) -> String {
    if (hi - lo).abs() < 0.005 * x.abs() {
        format!("{x:.2}×")
    } else {
        format!("{x:.2}× ({lo:.2}–{hi:.2})")
    }
}

fn percent(x: f64) -> String {
    if x == 0.0 {
        "0".into()
    } else if x < 0.001 {
        "<0.1 %".into()
    } else {
        format!("{:.1} %", x * 100.0)
    }
}

/// The docs' table of leaves visited per step and the cost of each kind of step
/// (`bench:table:profile`).
pub fn profile_tables(report: &Report) -> String {
    if report.profiles.is_empty() {
        return format!(
            "The committed run ({}) predates the profile of leaves per step: the next full \
             `cargo xtask bench` run to commit puts it here.",
            report.date
        );
    }
    let mut s = String::from(
        "Leaves `octoproxy-cpu` visits per step, as a share of the particle-steps of the timed \
         run (the same particles, parameters and start; 0 is a particle outside the scene's \
         root cube):\n\n| case | particles | mean |",
    );
    for b in LEAF_BINS {
        let _ = write!(s, " {} |", b.2);
    }
    s.push_str("\n|---|---:|---:|");
    s.push_str(&"---:|".repeat(LEAF_BINS.len()));
    s.push('\n');
    for p in &report.profiles {
        let _ = write!(
            s,
            "| {} | {} | {:.2} |",
            p.scene, p.particles, p.mean_leaves
        );
        for x in p.leaves {
            let _ = write!(s, " {} |", percent(x));
        }
        s.push('\n');
    }
    s.push_str(
        "\nEach kind of step, its particles replayed alone from the first timed step's start \
         (ns per step, and the kind's share of that step); `by parts` is the shares times \
         their costs, against the timed run's median:\n\n| case |",
    );
    for k in StepKind::ALL {
        let _ = write!(s, " {} |", k.name());
    }
    s.push_str(" by parts | timed |\n|---|");
    s.push_str(&"---:|".repeat(StepKind::ALL.len() + 2));
    s.push('\n');
    for p in &report.profiles {
        let _ = write!(s, "| {} |", p.scene);
        for (share, ns) in p.share.iter().zip(p.ns) {
            if *share > 0.0 {
                let _ = write!(s, " {ns:.1} ({}) |", percent(*share));
            } else {
                s.push_str(" – |");
            }
        }
        let timed = cpu_row(report, &p.scene, "octoproxy-cpu", p.particles)
            .map_or("–".to_string(), |r| {
                format!("{:.1}", r.ns_per_particle_step)
            });
        let _ = writeln!(s, " {:.1} | {timed} |", p.ns_by_parts());
    }
    s
}

/// The docs' table of the rain cases (`bench:table:rain`).
pub fn rain_table(report: &Report) -> String {
    let scenes = case_scenes(report, true);
    let Some(n) = shown_count(report).filter(|_| !scenes.is_empty()) else {
        return format!(
            "The committed run ({}) predates the rain cases: the next full `cargo xtask bench` \
             run to commit puts them here.",
            report.date
        );
    };
    let others = ["parry3d", "triangle-octree", "sdf-grid"];
    let mut s = format!(
        "{n} raindrops, ns per particle-step (the median of {} runs), and each other method's \
         time as a multiple of `octoproxy-cpu`'s (the span its runs allow):\n\n| scene | floor | \
         octoproxy-cpu | × floor |",
        super::ROUNDS
    );
    for m in others {
        let _ = write!(s, " {m} |");
    }
    s.push_str(" penetrations / M |\n|---|---:|---:|---:|");
    s.push_str(&"---|".repeat(others.len()));
    s.push_str("---:|\n");
    for scene in scenes {
        let Some(octo) = cpu_row(report, scene, "octoproxy-cpu", n) else {
            continue;
        };
        let floor = cpu_row(report, scene, "floor", n);
        let _ = write!(
            s,
            "| {scene} | {} | {:.1} | {} |",
            floor.map_or("–".into(), |f| format!("{:.1}", f.ns_per_particle_step)),
            octo.ns_per_particle_step,
            floor.map_or("–".into(), |f| format!(
                "{:.1}",
                octo.ns_per_particle_step / f.ns_per_particle_step
            )),
        );
        for m in others {
            match cpu_row(report, scene, m, n) {
                Some(r) => {
                    let _ = write!(
                        s,
                        " {:.1} ns, {} |",
                        r.ns_per_particle_step,
                        fmt_ratio(ratio(r, octo))
                    );
                }
                None => s.push_str(" – |"),
            }
        }
        let _ = writeln!(
            s,
            " {} |",
            super::docs::penetrations(octo.penetrations_per_million)
        );
    }
    s
}

/// The speed issue's targets against the run (`bench:text:speed`): per scene, the recipe
/// case within 5× the floor and 15× faster than parry3d, the rain case 5× faster than
/// parry3d, no penetrations; the bakes of 1.6M and 6.4M triangles; the scene API and moving
/// instances.
pub fn speed_targets(report: &Report) -> String {
    let Some(n) = shown_count(report) else {
        return "The committed run has no octoproxy-cpu rows.".into();
    };
    let met = |ok: usize, of: usize| match (ok, of) {
        (_, 0) => "no case to judge".to_string(),
        (0, _) => "not met".to_string(),
        (a, b) if a == b => "met everywhere".to_string(),
        (a, b) => format!("met on {a} of {b}"),
    };
    let mut s = String::new();
    let mut line = |title: &str, items: Vec<(String, bool)>| {
        let ok = items.iter().filter(|i| i.1).count();
        let list: Vec<String> = items.iter().map(|i| i.0.clone()).collect();
        let _ = writeln!(
            s,
            "- **{title}** ({}): {}.",
            met(ok, items.len()),
            if list.is_empty() {
                "not in this run".to_string()
            } else {
                list.join(", ")
            }
        );
    };
    let recipe = case_scenes(report, false);
    let rain = case_scenes(report, true);
    let mut floor_items = Vec::new();
    let mut parry_items = Vec::new();
    for scene in &recipe {
        let Some(octo) = cpu_row(report, scene, "octoproxy-cpu", n) else {
            continue;
        };
        if let Some(f) = cpu_row(report, scene, "floor", n) {
            let r = ratio(octo, f);
            floor_items.push((format!("{scene} {}", fmt_ratio(r)), r.0 <= 5.0));
        }
        if let Some(p) = cpu_row(report, scene, "parry3d", n) {
            let r = ratio(p, octo);
            parry_items.push((format!("{scene} {}", fmt_ratio(r)), r.0 >= 15.0));
        }
    }
    line("The recipe case within 5× the floor", floor_items);
    line("The recipe case 15× faster than parry3d", parry_items);
    let mut rain_items = Vec::new();
    for scene in &rain {
        let (Some(octo), Some(p)) = (
            cpu_row(report, scene, "octoproxy-cpu", n),
            cpu_row(report, scene, "parry3d", n),
        ) else {
            continue;
        };
        let r = ratio(p, octo);
        rain_items.push((format!("{scene} {}", fmt_ratio(r)), r.0 >= 5.0));
    }
    line("The rain case 5× faster than parry3d", rain_items);
    let pens: Vec<(String, bool)> = recipe
        .iter()
        .chain(&rain)
        .filter_map(|scene| {
            let r = cpu_row(report, scene, "octoproxy-cpu", n)?;
            let p = r.penetrations_per_million;
            Some((
                format!("{scene} {}", super::docs::penetrations(p)),
                p == 0.0,
            ))
        })
        .collect();
    line(
        "No penetrations (octoproxy-cpu, per million particle-steps)",
        pens,
    );
    let bake = |scene: &str, limit_s: f64| {
        let r = cpu_row(report, scene, "octoproxy-cpu", n)?;
        let secs = r.build_ms / 1e3;
        Some((
            format!("{scene} {secs:.2} s (target {limit_s} s)"),
            secs < limit_s,
        ))
    };
    line(
        "Bake 1.6M triangles under 1 s and 6.4M under 4 s",
        [bake("nefertiti-1.6m", 1.0), bake("nefertiti-6.4m", 4.0)]
            .into_iter()
            .flatten()
            .collect(),
    );
    let api: Vec<(String, bool)> = report
        .rows
        .iter()
        .filter(|r| r.backend == "cpu" && r.particles == n && r.ratio_to_plain.is_finite())
        .map(|r| {
            (
                format!("{} {:.2}× the plain step", r.scene, r.ratio_to_plain),
                r.ratio_to_plain <= 1.05,
            )
        })
        .collect();
    line(
        "A static scene through the scene API at the plain step's cost",
        api,
    );
    let moving: Vec<(String, bool)> = report
        .rows
        .iter()
        .filter(|r| {
            r.backend == "cpu"
                && r.instances == 100
                && r.particles == n
                && r.ratio_to_static.is_finite()
        })
        .map(|r| {
            (
                format!(
                    "{} instances, half moving, {:.2}× still",
                    r.instances, r.ratio_to_static
                ),
                r.ratio_to_static <= 2.0,
            )
        })
        .collect();
    line(
        "100 instances, half of them moving, at most twice still",
        moving,
    );
    s
}
