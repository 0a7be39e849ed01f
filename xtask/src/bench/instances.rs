//! The bench's scene cases. `instances-N`: particles raining through a grid of N instances of
//! two shared proxies (Spot and the rocker arm, each baked once), stepped through
//! `Scene::step` with every instance still, and again with half of them moving (going round a
//! small circle, bobbing and turning). And the scene API's own cost: a mesh scene's proxy as
//! one static instance at the identity, stepped through `Scene::step`, against the plain
//! `Backend::step` of the same particles.

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::{Quat, Vec3};
use octoproxy_core::{Aabb, Backend, Particle, Pose, ProxyView, SceneSides, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::harness::scene::{traced_pieces, SceneCheck, Tally};
use octoproxy_cpu::io::{load_mesh, Mesh};
use octoproxy_cpu::scenes::is_closed;
use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef, Scene};
use rayon::prelude::*;

use super::DT;

/// The cases, by the number of instances on the grid.
pub const SCENES: [&str; 4] = [
    "instances-1",
    "instances-10",
    "instances-100",
    "instances-1000",
];

/// The shared meshes (name, file in `../shared/meshes`): both closed, so that exact ground
/// truth can say whether a particle of the penetration sample is inside one.
pub const MESHES: [(&str, &str); 2] =
    [("spot", "spot.obj.gz"), ("rocker-arm", "rocker-arm.obj.gz")];

/// The suffix of the methods that step a mesh scene's proxy through the scene API.
pub const SCENE_API: &str = "-scene-api";

/// Each mesh is scaled to fit a cube this wide, centred on its own origin.
const SIZE: f32 = 10.0;
/// The distance between neighbouring places of the grid.
const SPACING: f32 = 2.0 * SIZE;
/// A moving instance goes round a circle of this radius about its place…
const ORBIT: f32 = 0.1 * SIZE;
/// …at this many radians a step (0.15 units a step: about four depth-8 leaves)…
const ORBIT_RATE: f32 = 0.15;
/// …bobs up and down by this much…
const BOB: f32 = 0.05 * SIZE;
/// …and turns about its vertical axis by this many radians a step (2 degrees: its far end
/// moves about 0.25 units, six depth-8 leaves).
const TURN_RATE: f32 = 0.035;
/// Particles start at least this far outside every instance's mesh box (more than two leaf
/// diagonals at depth 8, which the penetration check asks of its particles).
const MARGIN: f32 = 0.2;

/// The number of instances of a scene name, if it is an instance case.
pub fn instance_count(name: &str) -> Option<usize> {
    SCENES
        .contains(&name)
        .then(|| name.strip_prefix("instances-")?.parse().ok())
        .flatten()
}

/// The proxies every instance case shares, baked once.
pub struct Shared {
    meshes: Vec<Mesh>,
    proxies: Vec<Vec<u32>>,
    /// Each mesh's box in its own frame, grown by [`MARGIN`].
    boxes: Vec<Aabb>,
    /// Triangles over all the meshes baked.
    pub triangles: usize,
    /// The bake of all of them, in milliseconds.
    pub bake_ms: f64,
    /// The proxies' bytes.
    pub bytes: usize,
    /// A depth-8 leaf of the larger proxy: the unit of the particles' speeds.
    leaf8: f32,
}

impl Shared {
    /// Proxy `k`'s words.
    pub fn proxy(&self, k: usize) -> &[u32] {
        &self.proxies[k]
    }
}

/// Loads the shared meshes, scales each to fit a cube [`SIZE`] wide about its own origin, and
/// bakes them.
pub fn load_shared(dir: &Path) -> Result<Shared> {
    let mut meshes = Vec::new();
    for (_, file) in MESHES {
        let path = dir.join(file);
        if !path.exists() {
            bail!(
                "the instance cases place meshes from ../shared/meshes, and {} is not there",
                path.display()
            );
        }
        let (mut mesh, _) = load_mesh(&path)?;
        let (lo, hi) = mesh.positions.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p))),
        );
        let (centre, extent) = ((lo + hi) * 0.5, (hi - lo).max_element());
        if !(extent > 0.0 && extent.is_finite()) {
            bail!("{}: the mesh has no extent", path.display());
        }
        for p in &mut mesh.positions {
            *p = ((Vec3::from(*p) - centre) * (SIZE / extent)).to_array();
        }
        meshes.push(mesh);
    }
    let t = Instant::now();
    let mut proxies = Vec::new();
    for (mesh, (name, _)) in meshes.iter().zip(MESHES) {
        let (words, _) = bake(&[MeshRef::from(mesh)], &BuildParams::default(), &())
            .with_context(|| format!("baking {name}"))?;
        proxies.push(words);
    }
    let bake_ms = t.elapsed().as_secs_f64() * 1e3;
    let mut leaf8 = 0.0f32;
    for words in &proxies {
        let view = ProxyView::new(words)?;
        leaf8 = leaf8.max(view.header().root_size / 256.0);
    }
    let boxes = meshes
        .iter()
        .map(|m| {
            let (lo, hi) = m.positions.iter().fold(
                (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
                |(lo, hi), p| (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p))),
            );
            Aabb {
                min: lo - MARGIN,
                max: hi + MARGIN,
            }
        })
        .collect();
    Ok(Shared {
        triangles: meshes.iter().map(|m| m.triangles.len()).sum(),
        bytes: proxies.iter().map(|w| w.len() * 4).sum(),
        meshes,
        proxies,
        boxes,
        bake_ms,
        leaf8,
    })
}

/// Where the instances of one case stand: `n` places on a square grid in x and z, row by row,
/// every other instance moving (the first among them, so that one instance moves too), the two
/// meshes taking turns in pairs, so that both are among the moving and the still.
#[derive(Clone, Copy, Debug)]
pub struct Grid {
    n: usize,
    side: usize,
}

impl Grid {
    /// The places of `n` instances: a square grid as small as holds them.
    pub fn new(n: usize) -> Self {
        let mut side = 1;
        while side * side < n {
            side += 1;
        }
        Grid { n, side }
    }

    /// How many instances move in the moving case.
    pub fn moving(&self) -> usize {
        self.n.div_ceil(2)
    }

    fn moves(i: usize) -> bool {
        i.is_multiple_of(2)
    }

    fn proxy(i: usize) -> u32 {
        ((i / 2) % 2) as u32
    }

    fn place(&self, i: usize) -> Vec3 {
        Vec3::new(
            (i % self.side) as f32 * SPACING,
            0.0,
            (i / self.side) as f32 * SPACING,
        )
    }

    /// Instance `i`'s pose at the end of step `step` (0: the start). Each faces its own way; a
    /// moving one goes round a circle about its place, bobs and turns, and a still one keeps
    /// its start.
    fn pose(&self, i: usize, step: u32, moving: bool) -> Pose {
        let heading = i as f32 * 2.399_963; // the golden angle: no two neighbours alike
        let s = if moving && Self::moves(i) {
            step as f32
        } else {
            0.0
        };
        let a = heading + ORBIT_RATE * s;
        let offset = Vec3::new(
            ORBIT * a.cos(),
            BOB * (1.3 * ORBIT_RATE * s).sin(),
            ORBIT * a.sin(),
        );
        Pose {
            translation: (self.place(i) + offset).to_array(),
            scale: 1.0,
            rotation: Quat::from_rotation_y(heading + TURN_RATE * s)
                .normalize()
                .to_array(),
        }
    }

    /// The box particles fill: every place's cell, from below the instances to above them.
    fn region(&self) -> (Vec3, Vec3) {
        let rows = self.n.div_ceil(self.side);
        (
            Vec3::new(-0.5 * SPACING, -0.75 * SIZE, -0.5 * SPACING),
            Vec3::new(
                (self.side as f32 - 0.5) * SPACING,
                1.25 * SIZE,
                (rows as f32 - 0.5) * SPACING,
            ),
        )
    }

    /// The box of the penetration sample: the cells of the (up to) two by two places in the
    /// grid's first corner, so that the exact check asks few instances about each particle.
    fn sample_region(&self) -> (Vec3, Vec3) {
        let (lo, hi) = self.region();
        let cells = Vec3::new(
            self.side.min(2) as f32,
            0.0,
            self.n.div_ceil(self.side).min(2) as f32,
        );
        (
            lo,
            Vec3::new(lo.x + cells.x * SPACING, hi.y, lo.z + cells.z * SPACING),
        )
    }

    /// The scene: the shared proxies, and every instance at its start.
    fn scene(&self, shared: &Shared) -> Result<Scene> {
        let mut scene = Scene::new();
        for words in &shared.proxies {
            scene.add_proxy(words.clone())?;
        }
        for i in 0..self.n {
            scene.add_instance(Self::proxy(i), self.pose(i, 0, false))?;
        }
        Ok(scene)
    }

    /// Poses the moving instances for step `step` (their pose at its end).
    fn pose_step(&self, scene: &mut Scene, step: u32, moving: bool) -> Result<()> {
        if moving {
            for i in (0..self.n).filter(|&i| Self::moves(i)) {
                scene.move_to(i as u32, self.pose(i, step, true))?;
            }
        }
        Ok(())
    }

    /// Whether `p` lies in the grown mesh box of an instance at its start (only the places
    /// next to the nearest can hold it).
    fn blocks(&self, shared: &Shared, starts: &[Pose], p: Vec3) -> bool {
        let (ix, iz) = (
            (p.x / SPACING).round() as i64,
            (p.z / SPACING).round() as i64,
        );
        for dz in -1..=1 {
            for dx in -1..=1 {
                let (x, z) = (ix + dx, iz + dz);
                if x < 0 || z < 0 || x >= self.side as i64 {
                    continue;
                }
                let i = z as usize * self.side + x as usize;
                if i >= self.n {
                    continue;
                }
                let b = &shared.boxes[Self::proxy(i) as usize];
                let l = starts[i].to_local(p);
                if l.cmpge(b.min).all() && l.cmple(b.max).all() {
                    return true;
                }
            }
        }
        false
    }

    /// `count` particles spread through `region` outside every instance's grown mesh box, in
    /// random directions at speeds in `bands` (depth-8 leaves a step), their sides left to
    /// the scene step (each takes its side from the labelled leaves it crosses on its way).
    fn particles(
        &self,
        shared: &Shared,
        count: usize,
        bands: &[(f32, f32)],
        region: (Vec3, Vec3),
        seed: u64,
    ) -> Vec<Particle> {
        let starts: Vec<Pose> = (0..self.n).map(|i| self.pose(i, 0, false)).collect();
        let (lo, hi) = region;
        (0..count)
            .into_par_iter()
            .chunks(4096)
            .flat_map_iter(|idx| {
                let mut rng = Rng::new(seed ^ (idx[0] as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
                idx.into_iter()
                    .map(|i| {
                        let p = loop {
                            let p = Vec3::new(
                                rng.range(lo.x, hi.x),
                                rng.range(lo.y, hi.y),
                                rng.range(lo.z, hi.z),
                            );
                            if !self.blocks(shared, &starts, p) {
                                break p;
                            }
                        };
                        let (a, b) = bands[i % bands.len()];
                        let speed = rng.range(a, b) * shared.leaf8 / DT;
                        Particle::new(p.to_array(), (rng.unit_vector() * speed).to_array())
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    }
}

/// The particles of one case, spread through the whole grid.
pub fn case_particles(
    grid: &Grid,
    shared: &Shared,
    count: usize,
    bands: &[(f32, f32)],
) -> Vec<Particle> {
    grid.particles(shared, count, bands, grid.region(), 7)
}

/// Nanoseconds per particle-step of `steps` scene steps of `particles` on `backend`, the
/// instances still or half of them moving, after one untimed step (as every method gets).
/// The time includes what `Scene::step` does on the host: the moving instances' poses, the
/// broad phase and the scene's checks, every step.
pub fn time_case<B: Backend>(
    backend: &mut B,
    grid: &Grid,
    shared: &Shared,
    particles: &[Particle],
    steps: u32,
    moving: bool,
    params: &StepParams,
) -> Result<f64> {
    let mut scene = grid.scene(shared)?;
    backend.upload_particles(particles)?;
    grid.pose_step(&mut scene, 1, moving)?;
    scene.step(backend, params, false)?;
    backend.finish()?;
    let t = Instant::now();
    for k in 0..steps {
        grid.pose_step(&mut scene, k + 2, moving)?;
        scene.step(backend, params, false)?;
    }
    backend.finish()?;
    Ok(t.elapsed().as_secs_f64() * 1e9 / (particles.len() as f64 * steps as f64))
}

/// Penetrations per million particle-steps of a sample of `count` particles in the grid's
/// first corner, stepped `steps` times on the CPU and checked after every step as the moving
/// tests check (`octoproxy_cpu::harness::scene`): against exact ground truth in each
/// instance's own frame, every piece of every path as `step_particle_scene_traced` gives it, no
/// particle may pass through a mesh, nor end a step, deeper than a finest-leaf diagonal on its
/// other side.
pub fn penetration_rate(
    grid: &Grid,
    shared: &Shared,
    count: usize,
    bands: &[(f32, f32)],
    steps: u32,
    moving: bool,
    params: &StepParams,
) -> Result<f64> {
    let sample = grid.particles(shared, count, bands, grid.sample_region(), 99);
    if sample.is_empty() {
        return Ok(f64::NAN);
    }
    let refs: Vec<MeshRef<'_>> = shared.meshes.iter().map(MeshRef::from).collect();
    let closed: Vec<bool> = shared.meshes.iter().map(is_closed).collect();
    let views = shared
        .proxies
        .iter()
        .map(|w| ProxyView::new(w))
        .collect::<Result<Vec<_>, _>>()?;
    let mut check = SceneCheck::new(&refs, &closed, &views);
    let mut scene = grid.scene(shared)?;
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&sample)?;
    check.begin(scene.instances(), &sample);
    let mut tally = Tally::default();
    let mut before = sample;
    for step in 0..steps {
        grid.pose_step(&mut scene, step + 1, moving)?;
        scene.prepare()?;
        // The scene with this step's poses (the step leaves every instance at its end).
        let mut replay = scene.clone();
        let instances = scene.instances().to_vec();
        let sides = cpu.scene_sides();
        scene.step(&mut cpu, params, false)?;
        let after = cpu.particles().to_vec();
        let (pieces, differ) =
            replay.with_view(|view| traced_pieces(view, &before, &sides, &after, params))?;
        if let Some(k) = differ.first() {
            bail!(
                "{} particles' traced scene step differs from the CPU backend's (the first: \
                 particle {k}, step {step})",
                differ.len()
            );
        }
        tally.add(&check.step(&instances, &before, &after, Some(&pieces)));
        before = after;
    }
    Ok(tally.penetrations as f64 * 1e6 / (tally.particle_steps as f64).max(1.0))
}

/// Nanoseconds per particle-step of `particles` on `words` through the scene API: the proxy as
/// one static instance at the identity, each particle's side for it given (its own), stepped
/// `steps` times by `Scene::step` after one untimed step. The plain step of the same particles
/// is the comparison: a one-proxy static scene at the identity steps as the plain step, bit
/// for bit, so any difference is the scene API's own cost.
pub fn time_scene_api<B: Backend>(
    backend: &mut B,
    words: &[u32],
    particles: &[Particle],
    steps: u32,
    params: &StepParams,
) -> Result<f64> {
    let mut scene = Scene::new();
    let proxy = scene.add_proxy(words.to_vec())?;
    scene.add_instance(proxy, Pose::IDENTITY)?;
    let sides: Vec<SceneSides> = particles
        .iter()
        .map(|p| {
            let mut s = SceneSides::EMPTY;
            s.set_side(0, p.side);
            s
        })
        .collect();
    backend.upload_particles(particles)?;
    backend.upload_scene_sides(&sides)?;
    scene.step(backend, params, false)?;
    backend.finish()?;
    let t = Instant::now();
    for _ in 0..steps {
        scene.step(backend, params, false)?;
    }
    backend.finish()?;
    Ok(t.elapsed().as_secs_f64() * 1e9 / (particles.len() as f64 * steps as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instance_cases_are_named_by_their_count() {
        assert_eq!(instance_count("instances-1"), Some(1));
        assert_eq!(instance_count("instances-1000"), Some(1000));
        assert_eq!(instance_count("instances-7"), None);
        assert_eq!(instance_count("bunny"), None);
    }

    #[test]
    fn the_grid_moves_half_its_instances_and_keeps_them_apart() {
        for n in [1, 10, 100, 1000] {
            let grid = Grid::new(n);
            assert!(grid.side * grid.side >= n && (grid.side - 1) * (grid.side - 1) < n);
            assert_eq!(
                (0..n).filter(|&i| Grid::moves(i)).count(),
                grid.moving(),
                "{n}"
            );
            // A moving instance never comes nearer its neighbours' places than its own reach:
            // its circle and half a mesh's diagonal across x and z.
            let reach = ORBIT + 0.5 * SIZE * 2f32.sqrt();
            assert!(reach < 0.5 * SPACING);
            for i in 0..n {
                for step in [0, 7, 100] {
                    let p = grid.pose(i, step, true);
                    let d = Vec3::from(p.translation) - grid.place(i);
                    assert!(d.x.hypot(d.z) <= ORBIT * 1.0001 && d.y.abs() <= BOB);
                    if !Grid::moves(i) {
                        assert_eq!(p, grid.pose(i, 0, false));
                    }
                }
            }
        }
        // One instance: it is the one that moves.
        assert_eq!(Grid::new(1).moving(), 1);
    }

    /// A small instance case, end to end on the CPU: particles start outside every mesh box,
    /// both the still and the moving scene step, and the sample the penetration check follows
    /// never passes through a mesh.
    #[test]
    fn a_small_instance_case_steps_still_and_moving_and_lets_nothing_through() {
        let dir = super::super::meshes_dir();
        if !dir.join(MESHES[0].1).exists() {
            assert_ne!(
                std::env::var("CI").as_deref(),
                Ok("true"),
                "CI=true requires ../shared/meshes"
            );
            eprintln!("skipped: {} not found", dir.display());
            return;
        }
        let shared = load_shared(&dir).unwrap();
        let grid = Grid::new(4);
        let bands = [(0.1, 0.5), (0.5, 2.0), (2.0, 5.0)];
        let particles = case_particles(&grid, &shared, 3000, &bands);
        assert_eq!(particles.len(), 3000);
        let starts: Vec<Pose> = (0..grid.n).map(|i| grid.pose(i, 0, false)).collect();
        assert!(particles
            .iter()
            .all(|p| !grid.blocks(&shared, &starts, Vec3::from(p.position))));
        let params = StepParams::default();
        let mut cpu = CpuBackend::new();
        for moving in [false, true] {
            let ns = time_case(&mut cpu, &grid, &shared, &particles, 3, moving, &params).unwrap();
            assert!(ns.is_finite() && ns > 0.0);
            let rate = penetration_rate(&grid, &shared, 300, &bands, 20, moving, &params).unwrap();
            assert_eq!(rate, 0.0, "moving: {moving}");
        }
    }
}
