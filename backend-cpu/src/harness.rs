//! The penetration harness: any scene, any particles, many steps, checked against exact
//! ground truth rather than the proxy.
//!
//! A **penetration** is a particle that ends a step on the other side of the surface from
//! where it started, more than `tolerance` (one `dmax`-leaf diagonal) from the surface. For a
//! closed mesh the side is inside or outside, by the exact winding number at the step's end,
//! and at points every half tolerance along every piece of the path that crosses the surface:
//! a path that goes through a closed mesh within one step is a penetration (a **tunnel**)
//! even if it ends on the right side.
//! For an open mesh it is the parity of the surface crossings along every straight piece of
//! the particle's real path (from `step_particle_traced`), counted exactly, with paths through
//! shared edges and vertices counted once per passage (see `GroundTruth::segment_crossings`).
//! Passing through a hole crosses no triangle, so open meshes may be passed only through holes.
//! A particle the shell rule or the leaf bound puts back where it entered the shell is back at
//! a point of its path, with the crossings it had there: the jump is not counted as a path
//! (its chord would count a passage round a rim that no piece of the path made).

pub mod scene;

use crate::emit::{emit_surface_for, Rng, SurfaceSampler};
use glam::Vec3;
use octoproxy_core::pairs::{pair_column_table_size, pair_max_speed, pair_start};
use octoproxy_core::{
    initial_side, pair_iterations_for, pair_substeps_for, step_particle_traced, LeafHint,
    PairParams, PairProbe, PairStep, Particle, ProxyView, StepParams, FLAG_BLOCKED, FLAG_BOUND_HIT,
    FLAG_INVALID, MAX_DEPTH,
};
use rayon::prelude::*;

use crate::backend::PairBuffers;
use crate::bake::MeshRef;
use crate::ground_truth::GroundTruth;
use crate::sides::Sides;

/// What a run found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CheckReport {
    /// Particles checked.
    pub particles: usize,
    /// Particle-steps taken.
    pub particle_steps: u64,
    /// Particles that changed side deeper than the tolerance (counted once each).
    pub penetrations: u64,
    /// Of those, particles that started inside a closed mesh and ended outside.
    pub escapes: u64,
    /// Of those, particles whose path went through a closed mesh: some point of it deeper
    /// than the tolerance on the other side, though maybe no step ended there.
    pub tunnels: u64,
    /// Of those, particles of a radius whose path came nearer the mesh than the radius less
    /// a leaf diagonal ([`run_check_radius`]).
    pub too_near: u64,
    /// Particles whose state became NaN or infinite.
    pub non_finite: u64,
    /// Steps stopped by the shell rule.
    pub blocked_steps: u64,
    /// Steps stopped by the leaf bound.
    pub bound_hits: u64,
    /// Collisions in all.
    pub collisions: u64,
    /// The first few offenders: index, start position, end position.
    pub examples: Vec<(usize, [f32; 3], [f32; 3])>,
}

impl CheckReport {
    /// Penetrations per million particle-steps.
    pub fn per_million(&self) -> f64 {
        self.penetrations as f64 * 1e6 / self.particle_steps.max(1) as f64
    }
}

/// Random particles in the root cube at least `2 * tolerance` from the surface, moving in
/// random directions at speeds drawn from `speeds` (units per second).
pub fn random_particles(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    n: usize,
    speeds: &[f32],
    seed: u64,
) -> Vec<Particle> {
    let root = view.root_aabb();
    let tol = tolerance(view);
    let mut rng = Rng::new(seed);
    let mut out = Vec::with_capacity(n);
    let mut tries = 0;
    while out.len() < n && tries < n * 50 {
        tries += 1;
        let p = Vec3::new(
            rng.range(root.min.x, root.max.x),
            rng.range(root.min.y, root.max.y),
            rng.range(root.min.z, root.max.z),
        );
        if gt.distance_capped(p.to_array(), 4.0 * tol as f64) <= 2.0 * tol as f64 {
            continue;
        }
        let speed = speeds[out.len() % speeds.len().max(1)];
        let mut q = Particle::new(p.to_array(), (rng.unit_vector() * speed).to_array());
        q.side = initial_side(view, q.position);
        out.push(q);
    }
    out
}

/// Particles where users start them: near the surface of `meshes`, within `reach` of a
/// random point of it (triangles picked by area, directions uniform, so on both sides, in the
/// shell of surface leaves and beside it), with exact starting sides ([`Sides`]), moving in
/// random directions at speeds drawn from `speeds`.
pub fn near_surface_particles(
    meshes: &[MeshRef<'_>],
    sides: &Sides,
    n: usize,
    reach: f32,
    speeds: &[f32],
    seed: u64,
) -> Vec<Particle> {
    let surface = SurfaceSampler::new(meshes);
    if surface.is_empty() {
        return Vec::new();
    }
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|i| {
            let on = surface.sample(&mut rng).0.as_vec3();
            let x = on + rng.unit_vector() * rng.range(0.0, reach);
            let speed = speeds[i % speeds.len().max(1)];
            let mut p = Particle::new(x.to_array(), (rng.unit_vector() * speed).to_array());
            p.side = sides.side(p.position);
            p
        })
        .collect()
}

/// Where [`Starter::particles`] starts particles: where users start them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// At least two `dmax`-leaf diagonals from the surface ([`random_particles`]), sides from
    /// the proxy: outside the shell of surface leaves.
    Outside,
    /// Within 1.5 `dmax` leaves of the surface, both sides, in the shell and beside it
    /// ([`near_surface_particles`]).
    Shell,
    /// Emitted from the surface by the command line's emitter ([`emit_surface_for`]): one
    /// `dmax` leaf in front of their faces.
    Emitted,
    /// A fraction of a leaf (0.05–0.9) from the mesh's vertices, where knife edges, star tips
    /// and the creases of overlapping parts are: inside the solid for a closed scene, either
    /// side for an open one.
    Corners,
}

impl Start {
    /// Every kind, in the order of the variants.
    pub const ALL: [Start; 4] = [Start::Outside, Start::Shell, Start::Emitted, Start::Corners];

    /// The kind a command line names (`outside`, `shell`, `emitted`, `corners`).
    pub fn from_name(name: &str) -> Option<Start> {
        Start::ALL.into_iter().find(|s| s.name() == name)
    }

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Start::Outside => "outside",
            Start::Shell => "shell",
            Start::Emitted => "emitted",
            Start::Corners => "corners",
        }
    }
}

/// A scene prepared for starting particles where users start them ([`Start`]): the proxy, the
/// meshes, their exact sides and ground truth, and whether every part is closed.
pub struct Starter<'a> {
    /// The scene's proxy.
    pub view: &'a ProxyView<'a>,
    /// The meshes it was baked from.
    pub meshes: &'a [MeshRef<'a>],
    /// Exact sides (and cages) from the meshes.
    pub sides: &'a Sides,
    /// The meshes' ground truth, all together.
    pub gt: &'a GroundTruth,
    /// Whether the scene is closed (its corners start inside the solid).
    pub closed: bool,
}

impl Starter<'_> {
    /// `n` particles started as `start` says, moving in random directions at speeds drawn in
    /// turn from `speeds`, with exact sides from the mesh (from the proxy for
    /// [`Start::Outside`], where a leaf's label is exact), caged where they start strictly
    /// inside a solid leaf ([`Sides::cages`]). Deterministic for a seed; fewer than `n` only
    /// where the scene has no room for them.
    pub fn particles(&self, start: Start, n: usize, speeds: &[f32], seed: u64) -> Vec<Particle> {
        let leaf = self.view.finest_leaf_size();
        let speed = |k: usize| speeds[k % speeds.len().max(1)];
        let mut ps = match start {
            Start::Outside => random_particles(self.view, self.gt, n, speeds, seed),
            Start::Shell => {
                near_surface_particles(self.meshes, self.sides, n, 1.5 * leaf, speeds, seed)
            }
            Start::Emitted => {
                // None where `n` particles do not fit in memory.
                let mut ps = emit_surface_for(self.view, n, self.meshes, None, 0.0, seed)
                    .unwrap_or_default();
                let mut rng = Rng::new(seed);
                for (k, p) in ps.iter_mut().enumerate() {
                    p.velocity = (rng.unit_vector() * speed(k)).to_array();
                }
                ps
            }
            Start::Corners => {
                let vertices: Vec<[f32; 3]> = self
                    .meshes
                    .iter()
                    .flat_map(|m| m.positions.iter().copied())
                    .filter(|v| v.iter().all(|c| c.is_finite()))
                    .collect();
                let mut rng = Rng::new(seed);
                let mut ps = Vec::with_capacity(n);
                for _ in 0..n.saturating_mul(50) {
                    if ps.len() == n || vertices.is_empty() {
                        break;
                    }
                    let v = vertices[(rng.next_u64() % vertices.len() as u64) as usize];
                    let x = Vec3::from_array(v) + rng.unit_vector() * rng.range(0.05, 0.9) * leaf;
                    if self.closed && !self.gt.is_inside(x.to_array()) {
                        continue;
                    }
                    let v = rng.unit_vector() * speed(ps.len());
                    let mut p = Particle::new(x.to_array(), v.to_array());
                    p.side = self.sides.side(p.position);
                    ps.push(p);
                }
                ps
            }
        };
        self.sides.cages(self.view, &mut ps, false);
        ps
    }
}

/// Particles on the cell planes of random depths (one, two or three coordinates snapped: on
/// a cell's face, edge or corner, where point location breaks ties), at least `2 * tolerance`
/// from the surface, moving along an axis, along an exact face or space diagonal (through
/// cell edges and corners), or at rest (to fall down a grid line under gravity), at speeds
/// drawn from `speeds`: the float edge cases of point location and of the march.
pub fn grid_aligned_particles(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    n: usize,
    speeds: &[f32],
    seed: u64,
) -> Vec<Particle> {
    let root = view.root_aabb();
    let size = view.header().root_size;
    let depth = view.header().tree_depth;
    let tol = tolerance(view);
    let mut rng = Rng::new(seed);
    let mut below = |k: u32| (rng.next_u64() % k as u64) as u32;
    let mut out = Vec::with_capacity(n);
    let mut tries = 0;
    while out.len() < n && tries < n * 50 {
        tries += 1;
        let d = 1 + below(depth);
        let cells = 1u32 << d;
        let first = below(3) as usize;
        let snapped = 1 + below(3) as usize;
        let mut p = [0.0f32; 3];
        for (a, c) in p.iter_mut().enumerate() {
            let on_plane = (a + 3 - first) % 3 < snapped;
            let i = below(cells << 8);
            *c = if on_plane {
                view.plane(a, (i >> 8) << (MAX_DEPTH - d))
            } else {
                root.min[a] + size * (i as f32 / (cells << 8) as f32)
            };
        }
        if gt.distance_capped(p, 4.0 * tol as f64) <= 2.0 * tol as f64 {
            continue;
        }
        let speed = speeds[out.len() % speeds.len().max(1)];
        let (axes, skip) = (below(4) as usize, below(3) as usize);
        let v = aligned_velocity(axes, skip, speed, || below(2) != 0);
        let mut q = Particle::new(p, v.to_array());
        q.side = initial_side(view, q.position);
        out.push(q);
    }
    out
}

/// A velocity of `speed` along `axes` axes with equal magnitudes: none (at rest), the axis
/// `skip`, the two axes other than `skip` (an exact face diagonal) or all three (a space
/// diagonal), so that a path meets cell faces, edges and corners exactly. `negative()` is
/// asked once for each moving axis, in axis order, whether it moves down that axis.
pub fn aligned_velocity(
    axes: usize,
    skip: usize,
    speed: f32,
    mut negative: impl FnMut() -> bool,
) -> Vec3 {
    let s = if axes == 0 {
        0.0
    } else {
        speed / (axes as f32).sqrt()
    };
    let mut v = Vec3::ZERO;
    for a in 0..3 {
        let moving = match axes {
            1 => a == skip,
            2 => a != skip,
            _ => axes == 3,
        };
        if moving {
            v[a] = if negative() { -s } else { s };
        }
    }
    v
}

/// One `dmax`-leaf diagonal.
pub fn tolerance(view: &ProxyView<'_>) -> f32 {
    view.finest_leaf_size() * 3f32.sqrt()
}

/// Which of a step's traced `pieces` are jumps back to where the particle entered the shell,
/// which the shell rule and the leaf bound put it to (`flags` says whether either did): a
/// piece that ends where an earlier one began. The shell rule's march goes on from there (the
/// leaf bound's ends the step). The particle is put there, it does not travel the jump: it is
/// back where it was earlier in the step, with the crossings it had there (an open mesh's side
/// along the path, see [`run_check`]), and the jump is not a path through the mesh.
pub fn jumps_back(pieces: &[(Vec3, Vec3)], flags: u32) -> Vec<bool> {
    let stopped = flags & (FLAG_BLOCKED | FLAG_BOUND_HIT) != 0;
    (0..pieces.len())
        .map(|i| stopped && pieces[..i].iter().any(|&(from, _)| from == pieces[i].1))
        .collect()
}

/// The first of the points every half `tol` along the piece `a → b` of a path (ends
/// excluded) that is on the other side of a closed mesh from `inside` and farther than `tol`
/// from its surface: a path that goes through the mesh, or into it and back. Only a piece that
/// crosses the surface (`GroundTruth::segment_crossings`) can have one.
pub fn deep_on_the_other_side(
    gt: &GroundTruth,
    a: Vec3,
    b: Vec3,
    inside: bool,
    tol: f64,
) -> Option<[f32; 3]> {
    let n = ((((b - a).length() as f64) / (0.5 * tol)).ceil() as usize).clamp(1, 4096);
    (1..n)
        .map(|i| (a + (b - a) * (i as f32 / n as f32)).to_array())
        .find(|&q| gt.is_inside(q) != inside && gt.distance_capped(q, 2.0 * tol) > tol)
}

/// Steps `particles` `steps` times against `view`, checking every path against `gt`: a
/// particle more than [`tolerance`] from the surface must be on the side it started on.
/// `closed`: the side is inside or outside, by the exact winding number. Open: the side is the
/// parity of the surface crossings along every piece of the path.
pub fn run_check(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    particles: &mut [Particle],
    steps: u32,
    params: &StepParams,
    closed: bool,
) -> CheckReport {
    run_check_kicked(
        view,
        gt,
        particles,
        steps,
        |_| *params,
        closed,
        |_, _, _| {},
    )
}

/// [`run_check`] with parameters per step, `params(step)`, and `kick(step, index, particle)`
/// called before every step of every particle: to settle particles and restart them from the
/// rested frame with new velocities, say, while the check goes on against the sides they
/// started the run on.
pub fn run_check_kicked(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    particles: &mut [Particle],
    steps: u32,
    params: impl Fn(u32) -> StepParams + Sync,
    closed: bool,
    kick: impl Fn(u32, usize, &mut Particle) + Sync,
) -> CheckReport {
    check_paths(view, gt, particles, steps, params, closed, kick, None, None)
}

/// [`run_check`] for particles of a radius, stepped against a proxy baked for it: `gt` is
/// the offset surface's ground truth (closed: crossing it is a penetration, as for any closed
/// mesh), and every piece of every path is also checked against the scene's own triangles,
/// `mesh`: a point of it nearer than `clearance` (the radius less a `dmax` leaf diagonal) is
/// too near ([`CheckReport::too_near`], counted in the penetrations too). Pieces are sampled
/// at their ends and every half leaf between.
pub fn run_check_radius(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    particles: &mut [Particle],
    steps: u32,
    params: &StepParams,
    mesh: &GroundTruth,
    clearance: f64,
) -> CheckReport {
    check_at_radius(view, gt, particles, steps, params, mesh, clearance, None)
}

/// [`run_check_radius`] with the particle–particle pass on: every step is
/// [`octoproxy_core::pair_substeps_for`] substeps of the pass over all the particles (the CPU
/// backend's parallel pass, bit for bit core's one-thread
/// [`collide_pairs`](octoproxy_core::collide_pairs), with gravity) and then each particle's
/// march, traced and checked piece by piece as [`run_check_radius`] checks it. The pass runs
/// without leaf hints, so without supports but for grains the shell rule stopped: it may push
/// grains towards the scene freely, and the march alone keeps them out, a harder case than the
/// backends' (whose supports take such pushes off first).
/// Particles found bad stay in the pass as obstacles, and stop moving.
#[allow(clippy::too_many_arguments)]
pub fn run_check_pairs(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    particles: &mut [Particle],
    steps: u32,
    params: &StepParams,
    pairs: &PairParams,
    mesh: &GroundTruth,
    clearance: f64,
) -> CheckReport {
    check_at_radius(
        view,
        gt,
        particles,
        steps,
        params,
        mesh,
        clearance,
        Some(pairs),
    )
}

/// [`run_check_radius`], with the pass or without.
#[allow(clippy::too_many_arguments)]
fn check_at_radius(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    particles: &mut [Particle],
    steps: u32,
    params: &StepParams,
    mesh: &GroundTruth,
    clearance: f64,
    pairs: Option<&PairParams>,
) -> CheckReport {
    let p = *params;
    check_paths(
        view,
        gt,
        particles,
        steps,
        |_| p,
        true,
        |_, _, _| {},
        Some((mesh, clearance)),
        pairs,
    )
}

/// One particle's record in a check.
struct State {
    start: [f32; 3],
    inside: bool,
    crossings: u64,
    bad: bool,
    escaped: bool,
    non_finite: bool,
    blocked: u64,
    bound: u64,
    tunnelled: bool,
    near: bool,
}

/// What every step of a check compares against.
struct Checker<'a> {
    view: &'a ProxyView<'a>,
    gt: &'a GroundTruth,
    closed: bool,
    tol: f64,
    half_leaf: f32,
    clear: Option<(&'a GroundTruth, f64)>,
}

impl Checker<'_> {
    /// One traced step of `p` with `params`, checked piece by piece.
    fn step(&self, p: &mut Particle, s: &mut State, params: &StepParams) {
        let (gt, closed, tol) = (self.gt, self.closed, self.tol);
        let mut pieces = Vec::new();
        step_particle_traced(self.view, p, params, &mut |a: Vec3, b: Vec3| {
            pieces.push((a, b))
        });
        let jumps = jumps_back(&pieces, p.flags);
        // Crossings of each piece; a jump back is put, not travelled: it takes the particle
        // back to a point of this step's path, with the crossings it had there.
        let mut counts = Vec::with_capacity(pieces.len());
        for (i, &(a, b)) in pieces.iter().enumerate() {
            let is_jump = jumps[i];
            let k = if a == b {
                0
            } else if is_jump && !closed {
                let back = pieces.iter().position(|&(from, _)| from == b).unwrap_or(i);
                counts[back..i].iter().sum()
            } else {
                gt.segment_crossings(a.to_array(), b.to_array())
            };
            counts.push(k);
            if let Some((mesh, min)) = self.clear {
                if !is_jump && !s.near {
                    let n = (((b - a).length() / self.half_leaf).ceil() as usize).clamp(1, 4096);
                    s.near = (0..=n).any(|i| {
                        let q = a.lerp(b, i as f32 / n as f32).to_array();
                        mesh.distance_capped(q, min) < min
                    });
                }
            }
            if !closed {
                s.crossings += k as u64;
            } else if k > 0 && !s.tunnelled && !is_jump {
                s.tunnelled = deep_on_the_other_side(gt, a, b, s.inside, tol).is_some();
            }
        }
        s.bad |= s.tunnelled || s.near;
        if p.flags & FLAG_INVALID != 0 || !Vec3::from_array(p.position).is_finite() {
            s.non_finite = true;
            return;
        }
        s.blocked += (p.flags & FLAG_BLOCKED != 0) as u64;
        s.bound += (p.flags & FLAG_BOUND_HIT != 0) as u64;
        let far = gt.distance_capped(p.position, 2.0 * tol) > tol;
        if !closed && far && s.crossings % 2 == 1 {
            s.bad = true;
        }
        if closed && far && gt.is_inside(p.position) != s.inside {
            s.bad = true;
            s.escaped = s.inside;
        }
    }
}

/// The pass's scratch: the CPU backend's own buffers, so that a check runs the backend's
/// parallel pass (candidates listed once a substep) over its particles.
#[derive(Default)]
struct PassScratch {
    buffers: PairBuffers,
    /// The last pass's constants, for its debiasing iterations, and the step's iterations.
    step: PairStep,
    iterations: u32,
}

impl PassScratch {
    /// The pass over `particles` for one substep `h`. No particle has a leaf hint here, so
    /// only a grain the shell rule stopped in its last march rests on a support.
    fn pass(
        &mut self,
        view: &ProxyView<'_>,
        particles: &mut [Particle],
        params: &StepParams,
        pairs: &PairParams,
        h: f32,
    ) {
        let n = particles.len();
        let s0 = PairStep::new(params, pairs, h, n, 0.0);
        let s = PairStep::new(params, pairs, h, n, pair_max_speed(particles, &s0));
        self.step = s;
        let start = |_: usize, p: &Particle| pair_start(view, p, LeafHint::NONE, &s);
        let started = std::time::Instant::now();
        self.buffers
            .substep(particles, start, &s, self.iterations, started);
    }

    /// The last pass's debiasing iterations, after the march.
    fn debias(&mut self, particles: &mut [Particle]) {
        let (s, iterations) = (self.step, self.iterations);
        self.buffers.debias(particles, &s, iterations);
    }
}

/// The check itself, with an optional clearance from a mesh ([`run_check_radius`]) and the
/// particle–particle pass ([`run_check_pairs`]).
#[allow(clippy::too_many_arguments)]
fn check_paths(
    view: &ProxyView<'_>,
    gt: &GroundTruth,
    particles: &mut [Particle],
    steps: u32,
    params: impl Fn(u32) -> StepParams + Sync,
    closed: bool,
    kick: impl Fn(u32, usize, &mut Particle) + Sync,
    clear: Option<(&GroundTruth, f64)>,
    pairs: Option<&PairParams>,
) -> CheckReport {
    let checker = Checker {
        view,
        gt,
        closed,
        tol: tolerance(view) as f64,
        half_leaf: 0.5 * view.finest_leaf_size(),
        clear,
    };
    let mut states: Vec<State> = particles
        .par_iter()
        .map(|p| State {
            start: p.position,
            inside: closed && gt.is_inside(p.position),
            crossings: 0,
            bad: false,
            escaped: false,
            non_finite: false,
            blocked: 0,
            bound: 0,
            tunnelled: false,
            near: false,
        })
        .collect();
    let mut pass = PassScratch::default();
    for step in 0..steps {
        let params = params(step);
        particles
            .par_iter_mut()
            .zip(states.par_iter())
            .enumerate()
            .filter(|(_, (_, s))| !(s.bad || s.non_finite))
            .for_each(|(index, (p, _))| kick(step, index, p));
        let (substeps, march) = match pairs {
            None => (1, params),
            Some(pairs) => {
                // The particles it still steps set the substeps and the iterations, as a
                // backend's would.
                let stepped: Vec<Particle> = particles
                    .iter()
                    .zip(&states)
                    .filter(|(_, s)| !(s.bad || s.non_finite))
                    .map(|(p, _)| *p)
                    .collect();
                let mut table = vec![[0u32; 2]; pair_column_table_size(stepped.len())];
                let probe = PairProbe::of_all(&stepped, &params, &mut table)
                    .expect("a table of the size asked");
                let substeps = pair_substeps_for(&params, pairs, probe.speed);
                pass.iterations = pair_iterations_for(&params, pairs, &probe).0;
                let h = params.dt / substeps as f32;
                let march = StepParams {
                    gravity: [0.0; 3],
                    dt: h,
                    ..params
                };
                (substeps, march)
            }
        };
        for _ in 0..substeps {
            // Stopped particles keep still in the pass: as they are, without gravity.
            let held = |particles: &[Particle], states: &[State]| -> Vec<(usize, Particle)> {
                states
                    .iter()
                    .enumerate()
                    .filter(|(_, s)| s.bad || s.non_finite)
                    .map(|(i, _)| (i, particles[i]))
                    .collect()
            };
            if let Some(pairs) = pairs {
                let held = held(particles, &states);
                pass.pass(view, particles, &params, pairs, march.dt);
                for (i, p) in held {
                    particles[i] = p;
                }
            }
            particles
                .par_iter_mut()
                .zip(states.par_iter_mut())
                .filter(|(_, s)| !(s.bad || s.non_finite))
                .for_each(|(p, s)| checker.step(p, s, &march));
            if pairs.is_some() {
                let held = held(particles, &states);
                pass.debias(particles);
                for (i, p) in held {
                    particles[i] = p;
                }
            }
        }
    }
    let mut report = CheckReport {
        particles: particles.len(),
        particle_steps: particles.len() as u64 * steps as u64,
        ..CheckReport::default()
    };
    for (i, (s, p)) in states.iter().zip(particles.iter()).enumerate() {
        report.collisions += p.collisions() as u64;
        report.blocked_steps += s.blocked;
        report.bound_hits += s.bound;
        report.non_finite += s.non_finite as u64;
        if s.bad {
            report.penetrations += 1;
            report.escapes += s.escaped as u64;
            report.tunnels += s.tunnelled as u64;
            report.too_near += s.near as u64;
            if report.examples.len() < 5 {
                report.examples.push((i, s.start, p.position));
            }
        }
    }
    report
}
