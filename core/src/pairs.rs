//! Particles that collide with each other: Green's uniform grid, hashed, with position-based
//! contacts and Coulomb static friction (Macklin et al. 2014), solved by Jacobi iterations.
//!
//! A step with the pass is `substeps` rounds of: integrate gravity over the substep
//! ([`pair_prepare`]), put every valid particle in a cell of edge [`PairStep::cell`] and hash
//! the cell into a table of a power-of-two size ([`pair_cell`], [`pair_hash`]), sort the
//! particles by (hash, index) — a total order, so any correct sort gives the same array —,
//! find each bucket's range in the sorted order ([`pair_range_marks`]), and run the step's
//! Jacobi iterations (at least [`PairParams::iterations`], one for every
//! [`PAIR_LAYERS_PER_ITERATION`] layers its particles stand deep: [`pair_iterations_for`]) in
//! which every particle visits the 27 cells around its own, in a fixed order, and changes only
//! its own velocity ([`pair_velocity`]). Then each particle's displacement over the substep is marched against
//! the scene with gravity already integrated (the step with zero gravity and the substep's
//! `dt`): the scene comes last, so no neighbour can push a particle through a surface. Last,
//! as many **debiasing iterations** ([`debias_pairs`]) solve the same contacts again from the
//! marched velocities without the overlaps' removal ([`PairStep::unbiased`]): what moved
//! overlapping particles apart in the march does not stay as their velocity (Box2D v3's
//! "relax" iterations after its soft step).
//!
//! **The contact** between particles `i` and `j` (centres `x`, velocities `v`, radius `R`,
//! substep `h`) is speculative: with `n` the unit vector from `j` to `i`, `gap = |x_i − x_j| −
//! 2R` and `v_n = (v_i − v_j)·n`, the pair is in contact when `gap + v_n·h < 0` (it would
//! close within the substep). Its relative normal velocity is then brought to a **target**
//! fixed for the substep ([`PairGeometry::target`]): `e·a + (1 − e)·(−gap/h)`, with `a` the
//! speed at which the pair approached entering the iterations (the bounce is of that speed,
//! not of an iteration's: in a falling column each grain would otherwise bounce off the one
//! below as it is raised, and the top take the sum) and restitution `e` (reflected, or
//! arriving just touching); when the pair overlaps, at least `−β·gap/h` (the overlap removed
//! at the rate `β`, [`PairParams::relaxation`]). A pair closing faster is pushed; an
//! overlapping pair parting faster is held back (so what removes the overlaps of a deep pile
//! does not throw its top). The tangential relative velocity loses up to `μ` times the normal
//! change (Coulomb's cone on impulses) when the contact pushes: all of it below the cone
//! (static friction: touching particles stop sliding, so piles stand), `μ·Δv_n` above it.
//! **Friction acts only on a grain held by two contacts or more** (two grains, or a grain and
//! the scene; counted in the iteration, contacts that move it): a grain on a single other
//! grain is not held by friction. Particles do not spin, and without spin friction would hold
//! a grain anywhere on another's top within `atan μ` of the vertical, where a real sphere
//! rolls off (a sphere on a sphere stands only at the very top, unstably, whatever the
//! friction): poured grains then stuck where they landed, each on the one before, and a tower
//! rose to the spout. With the rule a grain slides off a lone support as it would roll off,
//! and comes to rest in a pocket (two or three grains under it), where rolling on one contact
//! would slip on another and friction does hold it: poured sand makes a cone at 25-45° at
//! `μ = 0.6` (`poured_sand_stands_at_its_angle_of_repose`).
//! Particle `i` takes `share_i` of the pair's change and `j` the rest, `share_i = ½ + ½·s·σ`
//! with `s` the height of `i` above `j` along `−gravity` in diameters (clamped to ±1) and `σ`
//! [`PairParams::stacking`] (Macklin's mass scaling: a particle resting on another takes the
//! correction, so stacks do not sink into each other). **A grain resting on the scene**
//! ([`pair_support`], normal `m`) cannot move into it, nor freely along it (the scene's
//! friction `μ_s`), so the part of a push that would be lost there is the other grain's: with
//! `c = max(0, −d·m)` for a push along `d` (`d = n` for `i`, `−n` for `j`), `t = √(1 − c²)`
//! and `f = t·max(0, t − μ_s·c)`, how far the support's response lets the push move it along
//! `d` (`f = 1` for a grain on nothing), the shares are
//! `a_i = (½ + ½·s·σ)·f_i` and `a_j = (½ − ½·s·σ)·f_j` made to sum to 1 (each kept when both
//! are 0). A grain wedged between a wall and a grain the pile presses on would otherwise take
//! most of the pair's correction, lose it to the wall, and the pair stay overlapped (22 % of
//! the diameter in the 50k tray at 4 ms). A grain the shell rule stopped in its last march is
//! wedged ([`PAIR_WEDGED`]): its leaf's one normal cannot say which surfaces hold it (a
//! corner, a crease), and `f = 0` for any push with a part into its support. Without supports,
//! with `σ = 0` or without gravity, each takes half: momentum is kept exactly, and an elastic frictionless pair leaves with the
//! velocities its contact normal gives. Each particle takes the mean of its pairs' changes,
//! each pair weighted by its share against an even split ([`pair_weight`]: a grain under
//! another is not moved by that contact, and it does not halve what the contacts under it
//! do). Coincident centres take the normal `±y` by index (the higher index goes up), so the
//! pair's normals stay opposite.
//!
//! **No tunnelling between particles.** Within a substep, positions move in straight lines. A
//! pair whose constraint holds after the iterations (`gap + v_n·h ≥ 0`) ends in the half-space
//! `(x_i − x_j)·n ≥ 2R`, and so does every point between: the relative path never enters the
//! other particle. The cell edge is `2R + 2·v_max·h` (times a margin), with `v_max` the
//! largest speed of the substep, so every pair that could close within the substep lies in
//! neighbouring cells, closer than the cell edge: the pairs a particle considers
//! ([`pair_candidates`]), whatever the grid's alignment. The neighbours a particle visits per
//! iteration are capped ([`PairParams::max_candidates`]); a particle that hits the cap is counted
//! ([`PairReport::capped`]), never looped over without end.
//!
//! **Determinism.** A particle sums its contacts in one order (the 27 cells z, then y, then
//! x, from −1 to 1; within a bucket, the sorted order), reads only the last iteration's
//! velocities, and writes only its own. Every float operation is IEEE (`+ − × ÷ √`, floor,
//! comparisons), so any order of particles, a GPU's included, gives the same bits.
//!
//! Cell coordinates saturate at ±[`PAIR_CELL_LIMIT`]; particles whose position or velocity is
//! not finite are left out of the pass (the march then flags them), as are those with
//! [`crate::FLAG_INVALID`]'s cause.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::math;
use crate::particle::{Particle, FLAG_BLOCKED, SIDE_BACK, SIDE_MASK};
use crate::query::LeafKind;
use crate::scene::{kept_side, SceneHint, SceneSides, SceneSlots, SceneView};
use crate::step::{respond, LeafHint, StepParams};
use crate::view::ProxyView;

/// Cell coordinates are clamped to `±PAIR_CELL_LIMIT` (as floats, before the conversion to
/// integers, on both backends): particles beyond share the last cell.
pub const PAIR_CELL_LIMIT: f32 = 1_073_741_824.0;

/// The hash of a particle left out of the pass: after every table index in the sort.
pub const PAIR_HASH_NONE: u32 = u32::MAX;

/// The cell edge is this many times `2R + 2·v_max·h`: rounding of `x / cell` cannot lose a
/// pair at the search distance.
pub const PAIR_CELL_MARGIN: f32 = 1.0625;

/// A grain rests on a surface leaf's plane ([`pair_support`]) when it is at most this part
/// of the leaf's edge above it.
pub const PAIR_SUPPORT_REACH: f32 = 1.0 / 64.0;

/// The last word of a support ([`pair_support`]) for a grain the shell rule stopped in its
/// last march ([`crate::FLAG_BLOCKED`]): it is wedged, in a leaf whose one normal does not
/// say which surfaces hold it (a corner, a crease), and takes no part of a push that goes
/// into its support at all; 1 for any other supported grain, 0 for none.
pub const PAIR_WEDGED: f32 = 2.0;

/// Most substeps a step is split into.
pub const MAX_PAIR_SUBSTEPS: u32 = 256;

/// Most Jacobi iterations per substep.
pub const MAX_PAIR_ITERATIONS: u32 = 64;

/// Largest cap on the neighbours one particle visits per iteration.
pub const MAX_PAIR_CANDIDATES: u32 = 4096;

/// The automatic substeps keep `|g|·h² ≤ PAIR_COMPRESSION·R`: what gravity closes between
/// two resting particles in one substep, before the contacts see it, is a small part of the
/// radius.
pub const PAIR_COMPRESSION: f32 = 0.01;

/// The pass's parameters: what a caller chooses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairParams {
    /// Restitution `e` of particle–particle contacts, in `[0, 1]`.
    pub restitution: f32,
    /// Coulomb friction `μ` of particle–particle contacts, `>= 0`.
    pub friction: f32,
    /// Rate `β` in `(0, 1]` at which an overlap is removed per substep.
    pub relaxation: f32,
    /// Stack stabilisation `σ` in `[0, 1]`: how much of a pair's correction goes to the
    /// upper particle beyond half (0: half each, momentum exact; 1: a particle directly on
    /// another takes it all).
    pub stacking: f32,
    /// The fewest Jacobi iterations per substep, `1..=MAX_PAIR_ITERATIONS`: a step takes
    /// more where its particles stand deeper ([`pair_iterations_for`]).
    pub iterations: u32,
    /// The most Jacobi iterations per substep, `iterations..=MAX_PAIR_ITERATIONS`: what a
    /// deep pile may ask for ([`pair_iterations_for`]); steps that ask for more are counted
    /// ([`PairReport::deep`]).
    pub max_iterations: u32,
    /// Substeps per step; 0 chooses them ([`pair_substeps_for`]).
    pub substeps: u32,
    /// With automatic substeps, whether they also follow the fastest particle, so that no
    /// particle moves more than a radius in a substep and none passes through another
    /// ([`pair_substeps_for`]; the default); off, gravity's count alone ([`pair_substeps`]).
    pub follow_speed: bool,
    /// Most neighbours (bucket entries) one particle visits per iteration,
    /// `1..=MAX_PAIR_CANDIDATES`.
    pub max_candidates: u32,
}

impl Default for PairParams {
    fn default() -> Self {
        Self {
            restitution: 0.1,
            friction: 0.5,
            relaxation: 0.4,
            stacking: 1.0,
            iterations: 8,
            max_iterations: MAX_PAIR_ITERATIONS,
            substeps: 0,
            follow_speed: true,
            max_candidates: 1024,
        }
    }
}

/// Why pass parameters were rejected.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum PairParamError {
    /// The particles have no radius (the pass needs `StepParams::radius > 0`).
    NoRadius,
    /// Restitution outside `[0, 1]`.
    BadRestitution(f32),
    /// Friction negative, NaN or infinite.
    BadFriction(f32),
    /// Relaxation outside `(0, 1]`.
    BadRelaxation(f32),
    /// Stacking outside `[0, 1]`.
    BadStacking(f32),
    /// Iterations outside `1..=MAX_PAIR_ITERATIONS`.
    BadIterations(u32),
    /// The most iterations outside `iterations..=MAX_PAIR_ITERATIONS` (the most, the
    /// fewest).
    BadMaxIterations(u32, u32),
    /// Substeps above `MAX_PAIR_SUBSTEPS`.
    BadSubsteps(u32),
    /// Candidate cap outside `1..=MAX_PAIR_CANDIDATES`.
    BadCandidates(u32),
}

impl core::fmt::Display for PairParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Self::NoRadius => write!(
                f,
                "particles that collide with each other need a radius greater than 0 (--radius)"
            ),
            Self::BadRestitution(e) => {
                write!(f, "particle restitution must be in [0, 1], got {e}")
            }
            Self::BadFriction(m) => {
                write!(f, "particle friction must be finite and >= 0, got {m}")
            }
            Self::BadRelaxation(b) => write!(f, "particle relaxation must be in (0, 1], got {b}"),
            Self::BadStacking(s) => write!(f, "particle stacking must be in [0, 1], got {s}"),
            Self::BadIterations(n) => write!(
                f,
                "particle iterations must be 1 to {MAX_PAIR_ITERATIONS}, got {n}"
            ),
            Self::BadMaxIterations(n, least) => write!(
                f,
                "the most particle iterations must be {least} (the fewest) to {MAX_PAIR_ITERATIONS}, got {n}"
            ),
            Self::BadSubsteps(n) => write!(
                f,
                "particle substeps must be 0 (automatic) to {MAX_PAIR_SUBSTEPS}, got {n}"
            ),
            Self::BadCandidates(n) => write!(
                f,
                "the neighbour cap must be 1 to {MAX_PAIR_CANDIDATES}, got {n}"
            ),
        }
    }
}

impl core::error::Error for PairParamError {}

impl PairParams {
    /// Checks every field, and that the step's particles have a radius.
    pub fn validate(&self, step: &StepParams) -> Result<(), PairParamError> {
        if !(step.radius > 0.0) {
            return Err(PairParamError::NoRadius);
        }
        if !(0.0..=1.0).contains(&self.restitution) {
            return Err(PairParamError::BadRestitution(self.restitution));
        }
        if !(self.friction >= 0.0) || !self.friction.is_finite() {
            return Err(PairParamError::BadFriction(self.friction));
        }
        if !(self.relaxation > 0.0 && self.relaxation <= 1.0) {
            return Err(PairParamError::BadRelaxation(self.relaxation));
        }
        if !(0.0..=1.0).contains(&self.stacking) {
            return Err(PairParamError::BadStacking(self.stacking));
        }
        if !(1..=MAX_PAIR_ITERATIONS).contains(&self.iterations) {
            return Err(PairParamError::BadIterations(self.iterations));
        }
        if !(self.iterations..=MAX_PAIR_ITERATIONS).contains(&self.max_iterations) {
            return Err(PairParamError::BadMaxIterations(
                self.max_iterations,
                self.iterations,
            ));
        }
        if self.substeps > MAX_PAIR_SUBSTEPS {
            return Err(PairParamError::BadSubsteps(self.substeps));
        }
        if !(1..=MAX_PAIR_CANDIDATES).contains(&self.max_candidates) {
            return Err(PairParamError::BadCandidates(self.max_candidates));
        }
        Ok(())
    }
}

/// The substeps of a step with the pass: [`PairParams::substeps`] when set, else the fewest
/// that keep `|g|·h² ≤ PAIR_COMPRESSION·R` (at least 1, at most [`MAX_PAIR_SUBSTEPS`]).
/// Speed enters in [`pair_substeps_for`], which the backends use.
pub fn pair_substeps(step: &StepParams, pairs: &PairParams) -> u32 {
    if pairs.substeps != 0 {
        return pairs.substeps;
    }
    let g = Vec3::from_array(step.gravity).length();
    if !(step.radius > 0.0) || !(g > 0.0) {
        return 1;
    }
    // h = dt / s  ≤  sqrt(κ R / g)  ⇔  s ≥ dt · sqrt(g / (κ R)).
    let s = step.dt * math::sqrt(g / (PAIR_COMPRESSION * step.radius));
    if !(s < MAX_PAIR_SUBSTEPS as f32) {
        return MAX_PAIR_SUBSTEPS;
    }
    (libm::ceilf(s) as u32).max(1)
}

/// The substeps of a step with the pass whose particles' largest speed at the step's start
/// is `v_max` ([`pair_probe_speed`]): [`PairParams::substeps`] when set, gravity's
/// ([`pair_substeps`]) without [`PairParams::follow_speed`], else the most of gravity's and
/// the fewest that keep every particle within a radius per substep,
/// `(v_max + |g|·dt)·h ≤ R` (at most [`MAX_PAIR_SUBSTEPS`]). Within a radius per
/// substep the cells cover every pair that can close ([`pair_cell_edge`]), so particles do
/// not pass through each other: the substeps follow the fastest particle, as a CFL bound.
/// Gravity's part bounds what the step adds; contacts that speed a particle up beyond it
/// (rare, a push out of a deep overlap) are counted ([`PairReport::fast`]). A `v_max` that
/// is not finite counts as the most substeps.
pub fn pair_substeps_for(step: &StepParams, pairs: &PairParams, v_max: f32) -> u32 {
    let base = pair_substeps(step, pairs);
    if pairs.substeps != 0 || !pairs.follow_speed || !(step.radius > 0.0) {
        return base;
    }
    let g = Vec3::from_array(step.gravity).length();
    let reach = (v_max + g * step.dt) * step.dt / step.radius * PAIR_SPEED_MARGIN;
    if !(reach < MAX_PAIR_SUBSTEPS as f32) {
        return MAX_PAIR_SUBSTEPS;
    }
    base.max(libm::ceilf(reach) as u32)
}

/// The substep counts a step with the pass may be given (a scene step's,
/// `Backend::step_scene_pairs`): with [`PairParams::follow_speed`] and automatic substeps,
/// gravity's [`pair_substeps`] to [`MAX_PAIR_SUBSTEPS`]; else exactly [`pair_substeps`]
/// (the caller's count when set).
pub fn pair_substep_range(step: &StepParams, pairs: &PairParams) -> (u32, u32) {
    let base = pair_substeps(step, pairs);
    if pairs.substeps != 0 || !pairs.follow_speed {
        (base, base)
    } else {
        (base, MAX_PAIR_SUBSTEPS)
    }
}

/// [`pair_substeps_for`] asks for this much more than a radius per substep's worth of
/// substeps, so that `h = dt / S` rounded in `f32` still keeps `v·h ≤ R`.
pub const PAIR_SPEED_MARGIN: f32 = 1.001;

/// A particle's speed for [`pair_substeps_for`]: `|v|` of a particle the pass takes
/// ([`pair_prepare`] without gravity), 0 for one it leaves out.
#[inline]
pub fn pair_probe_speed(p: &Particle) -> f32 {
    pair_prepare(p, &PairStep::default()).map_or(0.0, |(_, speed)| speed)
}

/// A deep pile stands when each substep's iterations are at least its depth in layers (the
/// most grains in one column along gravity, [`PairProbe`]) over this ([`pair_iterations_for`]).
///
/// A Jacobi iteration carries a grain's support one contact further, so a substep of `N`
/// iterations props up `N` layers over the floor; the layers above fall through the substep
/// and are held by their overlaps alone. The pass's substeps follow gravity
/// ([`pair_substeps`]), so how far the unheld layers fall before the support reaches them,
/// in diameters, depends only on the ratio of layers to iterations. Stood up from rest on a
/// floor (the scratch column of `docs/method.md`, "Deep piles"), columns of 245 to 500
/// layers hold where the ratio is at most 12.5 (the largest speed 0.33 to 0.46 m/s, what the
/// top reaches in its first steps of free fall), swing to 0.5 to 1.15 m/s at 15 to 20 (1,000
/// layers at 64), and throw their top at 30 (245 layers at 8: 4.5 m/s).
pub const PAIR_LAYERS_PER_ITERATION: u32 = 12;

/// The unit vector against gravity (zero without gravity): [`PairStep::up`].
pub fn pair_up(step: &StepParams) -> [f32; 3] {
    let g = Vec3::from_array(step.gravity);
    let gl = g.length();
    if gl > 0.0 {
        (-g / gl).to_array()
    } else {
        [0.0; 3]
    }
}

/// What a step with the pass is planned from, at its start: the particles' largest speed
/// ([`pair_probe_speed`], for [`pair_substeps_for`]) and the most of them in one column along
/// gravity (for [`pair_iterations_for`]). Particles the pass leaves out take no part.
///
/// **Columns** are a grid one diameter wide across gravity ([`pair_across`]): a particle's
/// column is `floor(x·a / 2R)` for the two unit vectors `a` across gravity
/// ([`pair_column_key`]). A pile `D` grains deep puts about `D` grains in its middle columns,
/// while a particle that fell off the scene or a sparse cloud put few in any: the count is
/// the weight a column of contacts must carry, which is what the iterations must reach. Each
/// column is counted exactly (an open-addressing table keyed by the column, the caller's
/// scratch: [`pair_column_table_size`]), and the most is a maximum: any order of particles, a
/// GPU's included, gives the same probe.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PairProbe {
    /// The largest speed.
    pub speed: f32,
    /// The most valid particles in one column.
    pub deepest: u32,
}

impl PairProbe {
    /// The probe of `particles` under `step`'s gravity, on one thread; `table` is the
    /// columns' scratch, at least [`pair_column_table_size`]`(particles.len())` entries
    /// (`None` when shorter).
    pub fn of_all(
        particles: &[Particle],
        step: &StepParams,
        table: &mut [[u32; 2]],
    ) -> Option<Self> {
        let size = pair_column_table_size(particles.len());
        let table = table.get_mut(..size)?;
        table.fill([0, 0]);
        let across = pair_across(step);
        let inv_diameter = 1.0 / (2.0 * step.radius);
        // Without gravity nothing stacks: no columns, `deepest` 0.
        let counting = pair_up(step) != [0.0; 3];
        let mut probe = Self::default();
        for p in particles {
            let Some((_, speed)) = pair_prepare(p, &PairStep::default()) else {
                continue;
            };
            if speed > probe.speed {
                probe.speed = speed;
            }
            if !counting {
                continue;
            }
            let key = pair_column_key(p.position, &across, inv_diameter);
            let mut slot = pair_column_slot(key, size as u32 - 1) as usize;
            // The table holds twice the particles: an empty slot or the column's own is
            // always found.
            loop {
                let entry = &mut table[slot];
                if entry[0] == 0 || entry[0] == key {
                    entry[0] = key;
                    entry[1] += 1;
                    probe.deepest = probe.deepest.max(entry[1]);
                    break;
                }
                slot = (slot + 1) & (size - 1);
            }
        }
        Some(probe)
    }
}

/// Entries of the columns' table for `n` particles: twice [`pair_table_size`]`(n)`, so at
/// most half are taken.
pub fn pair_column_table_size(n: usize) -> usize {
    2 * pair_table_size(n)
}

/// Two unit vectors across gravity, at right angles to it and to each other (zeros without
/// gravity): `a₁ = (up × e) / |up × e|` with `e` the axis along which `up` has the least part
/// (the first of equals), `a₂ = up × a₁`.
pub fn pair_across(step: &StepParams) -> [[f32; 3]; 2] {
    let up = Vec3::from_array(pair_up(step));
    if up == Vec3::ZERO {
        return [[0.0; 3]; 2];
    }
    let a = up.abs();
    let e = if a.x <= a.y && a.x <= a.z {
        Vec3::X
    } else if a.y <= a.z {
        Vec3::Y
    } else {
        Vec3::Z
    };
    let a1 = up.cross(e).normalize();
    [a1.to_array(), up.cross(a1).to_array()]
}

/// The key of a position's column ([`PairProbe`]): the two column coordinates
/// `floor(x·a / 2R)` (`x·a` as [`pair_height`]; clamped as [`pair_cell`]'s), 15 and 16 bits
/// of them with the top bit set, never 0 (an empty slot). Columns 32,768 diameters apart
/// across the first vector share a key: particles that far apart add to one count.
#[inline]
pub fn pair_column_key(x: [f32; 3], across: &[[f32; 3]; 2], inv_diameter: f32) -> u32 {
    let c = |a: &[f32; 3]| {
        let f = math::floor(pair_height(x, *a) * inv_diameter);
        f.clamp(-PAIR_CELL_LIMIT, PAIR_CELL_LIMIT) as i32 as u32
    };
    0x8000_0000 | (c(&across[0]) & 0x7fff) << 16 | (c(&across[1]) & 0xffff)
}

/// Where a column's key starts its search in a table of `mask + 1` entries.
#[inline]
pub fn pair_column_slot(key: u32, mask: u32) -> u32 {
    region_mix(key) & mask
}

/// A position's part along a unit vector: `x·a` (WGSL's `pair_height`), the products summed
/// in this order on both backends.
#[inline]
pub fn pair_height(x: [f32; 3], a: [f32; 3]) -> f32 {
    x[0] * a[0] + x[1] * a[1] + x[2] * a[2]
}

/// The Jacobi iterations of each substep of a step whose particles' probe is `probe`
/// ([`PairProbe`]), and whether they stand deeper than [`PairParams::max_iterations`] props up
/// (then the step takes the most, and a pile that deep may not stand: [`PairReport::deep`]).
/// Under gravity, the most particles in one column over [`PAIR_LAYERS_PER_ITERATION`],
/// rounded up, within [`PairParams::iterations`] and [`PairParams::max_iterations`]; without
/// gravity nothing stacks, and the fewest. A column counts every particle in it, resting or
/// not: a dense stream falling onto a pile adds its grains to the pile's columns.
pub fn pair_iterations_for(
    step: &StepParams,
    pairs: &PairParams,
    probe: &PairProbe,
) -> (u32, bool) {
    let (least, most) = (pairs.iterations, pairs.max_iterations.max(pairs.iterations));
    let g = Vec3::from_array(step.gravity).length();
    if !(g > 0.0) || !(step.radius > 0.0) {
        return (least, false);
    }
    let wanted = probe.deepest.div_ceil(PAIR_LAYERS_PER_ITERATION);
    if wanted > most {
        return (most, true);
    }
    (wanted.max(least), false)
}

/// One substep's constants, the same bytes on both backends (WGSL's `PairStep`). The host
/// makes it with [`PairStep::new`] once the substep's largest speed is known.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PairStep {
    /// Gravity times the substep: what [`pair_prepare`] adds to each velocity.
    pub gravity_h: [f32; 3],
    /// The substep, seconds.
    pub h: f32,
    /// Unit vector against gravity (zero without gravity): "up" for the stacking share.
    pub up: [f32; 3],
    /// `1 / h`.
    pub inv_h: f32,
    /// The particles' radius.
    pub radius: f32,
    /// `2R`.
    pub diameter: f32,
    /// `1 / (2R)`.
    pub inv_diameter: f32,
    /// The cell edge.
    pub cell: f32,
    /// `1 / cell`.
    pub inv_cell: f32,
    /// The table's size less one (a power of two less one).
    pub mask: u32,
    /// Restitution `e`.
    pub restitution: f32,
    /// Friction `μ`.
    pub friction: f32,
    /// Relaxation `β`.
    pub relaxation: f32,
    /// Half of the stacking `σ`.
    pub half_stacking: f32,
    /// Neighbour cap per particle per iteration.
    pub max_candidates: u32,
    /// The scene's friction (`StepParams::friction`), for grains resting on it.
    pub scene_friction: f32,
}

const _: () = assert!(core::mem::size_of::<PairStep>() == 80);

/// The table size for `n` particles: the power of two at or above `n` (at least 1).
pub fn pair_table_size(n: usize) -> usize {
    n.max(1).next_power_of_two()
}

impl PairStep {
    /// The same substep without the overlap's removal (`relaxation` 0): the constants of the
    /// debiasing iterations after the march ([`debias_pairs`]).
    pub fn unbiased(&self) -> Self {
        Self {
            relaxation: 0.0,
            ..*self
        }
    }

    /// The constants of a substep of `h` seconds for `n` particles whose largest speed after
    /// gravity ([`pair_prepare`]'s) is `v_max`.
    pub fn new(step: &StepParams, pairs: &PairParams, h: f32, n: usize, v_max: f32) -> Self {
        let g = Vec3::from_array(step.gravity);
        let up = pair_up(step);
        let r = step.radius;
        let diameter = 2.0 * r;
        let cell = pair_cell_edge(diameter, r, v_max, h);
        Self {
            gravity_h: (g * h).to_array(),
            h,
            up,
            inv_h: 1.0 / h,
            radius: r,
            diameter,
            inv_diameter: 1.0 / diameter,
            cell,
            inv_cell: 1.0 / cell,
            mask: (pair_table_size(n) - 1) as u32,
            restitution: pairs.restitution,
            friction: pairs.friction,
            relaxation: pairs.relaxation,
            half_stacking: 0.5 * pairs.stacking,
            max_candidates: pairs.max_candidates,
            scene_friction: step.friction,
        }
    }
}

/// The cell edge of a substep `h` whose largest speed is `v_max`: `2R` plus what two
/// particles can close in the substep, `2·min(v_max·h, R)`, times [`PAIR_CELL_MARGIN`].
/// Capped at a radius per particle and substep, so one fast particle cannot make the cells
/// of a whole pile huge: particles faster than that are counted ([`PairReport::fast`]) and
/// may pass through other particles (never through the scene); more substeps bring them
/// under it.
#[inline]
pub fn pair_cell_edge(diameter: f32, radius: f32, v_max: f32, h: f32) -> f32 {
    let d = v_max * h;
    let d = if d < radius { d } else { radius };
    (diameter + 2.0 * d) * PAIR_CELL_MARGIN
}

/// Whether a particle of `speed` moves more than a radius in the substep (see
/// [`pair_cell_edge`]).
#[inline]
pub fn pair_is_fast(speed: f32, s: &PairStep) -> bool {
    speed * s.h > s.radius
}

/// A particle in the pass's sorted order (WGSL's `PairBody`): 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PairBody {
    /// Its position.
    pub position: [f32; 3],
    /// Its index in the caller's order.
    pub index: u32,
    /// Its cell.
    pub cell: [i32; 3],
    /// Its cell's hash (a table index).
    pub hash: u32,
}

/// A particle's velocity in the pass (WGSL's `vec4<f32>`; `w` is zero).
pub type PairVelocity = [f32; 4];

/// What the pass reports since it was last taken.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PairReport {
    /// Steps taken with the pass.
    pub steps: u64,
    /// Substeps taken (over all steps).
    pub substeps: u64,
    /// Particle-iterations whose neighbour loop stopped at the cap
    /// ([`PairParams::max_candidates`]): crowds denser than the cap, contacts missed.
    pub capped: u64,
    /// Particle-substeps that moved more than a radius ([`pair_cell_edge`]): they may have
    /// passed through other particles (never through the scene).
    pub fast: u64,
    /// Jacobi iterations, summed over substeps (each substep runs them twice, before the
    /// march and after it): over `substeps`, the mean per substep.
    pub iterations: u64,
    /// Steps whose particles stood deeper than [`PairParams::max_iterations`] props up
    /// ([`pair_iterations_for`]): a pile that deep may sink and throw its top.
    pub deep: u64,
}

/// The velocity a valid particle enters the substep with (gravity integrated) and its
/// speed, or `None` for a particle left out (position or velocity not finite after it).
#[inline]
pub fn pair_prepare(p: &Particle, s: &PairStep) -> Option<(Vec3, f32)> {
    let x = Vec3::from_array(p.position);
    let v = Vec3::from_array(p.velocity) + Vec3::from_array(s.gravity_h);
    if !x.is_finite() || !v.is_finite() {
        return None;
    }
    Some((v, math::sqrt(v.dot(v))))
}

/// The support of a grain resting on the scene: the unit normal of the one-sided surface
/// leaf its hint holds (the leaf it rests in, on its plane, as the march left it: within
/// [`PAIR_SUPPORT_REACH`] of the leaf's edge), facing the grain's side, with `w = 1`
/// ([`PAIR_WEDGED`] for a grain the shell rule stopped in its last march); zeros when it
/// rests on nothing. In the pass a supported grain
/// cannot move into its support: what its contacts push into it is the scene's normal
/// impulse, and the scene's friction acts with it ([`pair_velocity`]), so a grain under a
/// pile holds on a slope by the pile's weight, not only its own.
///
/// A grain whose last march ended where the shell rule put it back ([`crate::FLAG_BLOCKED`],
/// and no hint) lies where it entered the shell, often where it started, in the surface leaf
/// it rests on, found by descent. Without it such a grain had no support, its contacts pushed it into the
/// scene again, the shell rule put it back again, and it stood still while the pass took it to
/// move (its velocity kept, gravity adding to it): its neighbours closed on it by up to 40 % of
/// the diameter in the corners of a tray. Such a grain is supported wherever it lies in its
/// leaf, on the plane or not: in a vertical corner of a tray, a grain against one wall lies
/// in front of the corner leaf's diagonal plane by more than the reach; taken as falling, it
/// took its share of its neighbour's push, lost it to the wall (the shell rule put it back
/// and reflected it off the wall's leaf face, a tenth of the push back at its neighbour), and
/// drifted into the neighbour by about 2·10⁻⁵ m a step, 14 % of the diameter in 4 s of the
/// 50k pour onto Spot.
#[inline]
pub fn pair_support(view: &ProxyView<'_>, p: &Particle, hint: LeafHint) -> [f32; 4] {
    if p.side & !SIDE_MASK != 0 {
        return [0.0; 4];
    }
    let x = Vec3::from_array(p.position);
    let leaf = if hint.z_depth_label & LeafHint::SURFACE != 0 {
        hint.leaf(view, x)
    } else if p.flags & FLAG_BLOCKED != 0 {
        view.locate_leaf(x)
            .filter(|leaf| leaf.kind == LeafKind::Surface && !leaf.two_sided)
    } else {
        None
    };
    match leaf {
        Some(leaf) => {
            let (n, sign) = if p.side == SIDE_BACK {
                (-leaf.normal, -1.0)
            } else {
                (leaf.normal, 1.0)
            };
            // On the plane, as the march leaves a grain it collided: a grain inside a large
            // leaf well above its plane is falling, not resting. A grain the shell rule
            // stopped rests against the surface wherever it lies in its leaf: the leaf's one
            // plane may lie part of a leaf away from the surface it stands for (in a
            // corner, the diagonal between two walls).
            let centre = (leaf.aabb.min + leaf.aabb.max) * 0.5;
            let above = (leaf.normal.dot(x - centre) - leaf.plane_offset) * sign;
            let reach = (leaf.aabb.max.x - leaf.aabb.min.x) * PAIR_SUPPORT_REACH;
            let blocked = p.flags & FLAG_BLOCKED != 0;
            if !(above <= reach) && !blocked {
                return [0.0; 4];
            }
            let wedged = if blocked { PAIR_WEDGED } else { 1.0 };
            [n.x, n.y, n.z, wedged]
        }
        None => [0.0; 4],
    }
}

/// [`pair_support`] in a scene: the support of the instance whose leaf the grain's scene
/// hint holds (the one static instance the grain's last march was near, on the side the
/// grain keeps for it), found in that instance's frame and its normal turned to the world;
/// zeros when the hint names no instance, or one that is inactive or moves in this substep,
/// or the grain keeps no side for it. A grain near a moving instance has no support from it:
/// the march alone keeps it out, as it keeps every grain out of every instance.
#[inline]
pub fn pair_support_scene(
    scene: &SceneView<'_>,
    p: &Particle,
    hint: &SceneHint,
    slots: &SceneSlots,
) -> [f32; 4] {
    let c = hint.hint_instance;
    let Some(inst) = scene.instances().get(c as usize) else {
        return [0.0; 4];
    };
    if !inst.is_active() || !inst.is_static() {
        return [0.0; 4];
    }
    let Some(view) = scene.proxies().get(inst.proxy as usize) else {
        return [0.0; 4];
    };
    let Some(side) = kept_side(inst, &SceneSides::join(hint, slots).slots, c) else {
        return [0.0; 4];
    };
    let local = Particle {
        position: inst.start.to_local(Vec3::from_array(p.position)).to_array(),
        side,
        ..*p
    };
    let sup = pair_support(view, &local, hint.hint);
    if sup[3] == 0.0 {
        return sup;
    }
    let n = inst
        .start
        .normal_to_world(Vec3::new(sup[0], sup[1], sup[2]));
    [n.x, n.y, n.z, sup[3]]
}

/// [`pair_start`] in a scene: the support from [`pair_support_scene`].
#[inline]
pub fn pair_start_scene(
    scene: &SceneView<'_>,
    p: &Particle,
    hint: &SceneHint,
    slots: &SceneSlots,
    s: &PairStep,
) -> (PairVelocity, [f32; 4]) {
    pair_start_with(p, pair_support_scene(scene, p, hint, slots), s)
}

/// What a valid grain enters the iterations with: its velocity after gravity
/// ([`pair_prepare`]; zero for one left out), already kept out of its support with the
/// scene's friction as [`pair_velocity`] does after each iteration, and the support
/// ([`pair_support`]).
#[inline]
pub fn pair_start(
    view: &ProxyView<'_>,
    p: &Particle,
    hint: LeafHint,
    s: &PairStep,
) -> (PairVelocity, [f32; 4]) {
    pair_start_with(p, pair_support(view, p, hint), s)
}

/// What a valid grain with support `sup` enters the iterations with ([`pair_start`], for a
/// support found either way).
#[inline]
pub fn pair_start_with(p: &Particle, sup: [f32; 4], s: &PairStep) -> (PairVelocity, [f32; 4]) {
    let (v, _) = pair_prepare(p, s).unwrap_or((Vec3::ZERO, 0.0));
    let v = if sup[3] != 0.0 {
        respond(v, Vec3::new(sup[0], sup[1], sup[2]), 0.0, s.scene_friction)
    } else {
        v
    };
    ([v.x, v.y, v.z, 0.0], sup)
}

/// The cell of a position: `floor(x / cell)` per axis, clamped to `±PAIR_CELL_LIMIT`.
#[inline]
pub fn pair_cell(x: [f32; 3], s: &PairStep) -> [i32; 3] {
    let mut c = [0i32; 3];
    for a in 0..3 {
        let f = math::floor(x[a] * s.inv_cell);
        c[a] = f.clamp(-PAIR_CELL_LIMIT, PAIR_CELL_LIMIT) as i32;
    }
    c
}

/// The table index of a cell. Cells come in blocks of 4×4×4 (the coordinates shifted right
/// by two), blocks in regions of 8×8×8 (shifted right by three more). A region starts at a
/// place in the table its coordinates hash to; from there its blocks follow in Morton order
/// (three bits an axis, interleaved x, y, z from the lowest) and each block's cells in order
/// (two bits an axis, x lowest): `(hash(region) + block · 64 + cell) & mask`. The sort by
/// hash keeps each block's cells together and a region's blocks in a run where each block
/// lies near those around it, so a particle's 27 cells are mostly near it and near the last
/// particle's in the sorted order (and in memory). Regions land anywhere, with any offset, so
/// cells of different regions share buckets as a hash would have them, whatever the table's
/// size. Only the memory layout depends on it: a particle's candidates come in the order of
/// its 27 cells, then by index.
#[inline]
pub fn pair_hash(c: [i32; 3], mask: u32) -> u32 {
    let r = [c[0] >> 5, c[1] >> 5, c[2] >> 5];
    let region = region_mix(
        (r[0] as u32).wrapping_mul(HASH_X)
            ^ (r[1] as u32).wrapping_mul(HASH_Y)
            ^ (r[2] as u32).wrapping_mul(HASH_Z),
    );
    region.wrapping_add(cell_place(c[0], 0) | cell_place(c[1], 1) | cell_place(c[2], 2)) & mask
}

/// The multipliers of a region's coordinates in [`pair_hash`], x, y, z.
const HASH_X: u32 = 0x8da6_b343;
const HASH_Y: u32 = 0xd816_3841;
const HASH_Z: u32 = 0xcb1a_b31f;

/// The mix of a region's combined coordinates ([`pair_hash`]): where its run starts.
#[inline(always)]
fn region_mix(mut h: u32) -> u32 {
    h ^= h >> 16;
    h = h.wrapping_mul(0x7feb_352d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846c_a68b);
    h ^ h >> 16
}

/// Axis `a`'s bits of a cell's place in its region's run ([`pair_hash`]): its block
/// coordinate's three bits (`x >> 2`, within the region) at bits `6 + 3i + a`, its
/// coordinate within the block (two bits) at bits `2a`. The three axes' bits are disjoint:
/// a cell's place is their union.
#[inline(always)]
fn cell_place(x: i32, a: u32) -> u32 {
    let b = (x >> 2) as u32;
    let spread = (b & 1) | (b & 2) << 2 | (b & 4) << 4;
    (spread << (6 + a)) | ((x & 3) as u32) << (2 * a)
}

/// Whether sorted position `k` is the first and the last entry of its bucket in `keys` (the
/// sorted `(hash, index)` keys; entries with [`PAIR_HASH_NONE`] belong to no bucket): the
/// bucket of hash `h` is `[start, end)` with `start` its first `k` and `end` its last plus 1.
#[inline]
pub fn pair_range_marks(keys: &[[u32; 2]], k: usize) -> (bool, bool) {
    let h = keys[k][0];
    if h == PAIR_HASH_NONE {
        return (false, false);
    }
    let first = k == 0 || keys[k - 1][0] != h;
    let last = k + 1 == keys.len() || keys[k + 1][0] != h;
    (first, last)
}

/// What a pair's contact needs, fixed within a substep: the unit normal from `other` to
/// `me` (`±y` by index for coincident centres), the gap, `me`'s share of the pair's change,
/// and the relative normal velocity the contact aims at ([the contact](self)).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PairGeometry {
    /// The unit normal.
    pub n: [f32; 3],
    /// `|x_me − x_other| − 2R`.
    pub gap: f32,
    /// `me`'s share, `½ + ½·s·σ`.
    pub share: f32,
    /// The target relative normal velocity, from the gap and the velocities the pair
    /// entered the iterations with.
    pub target: f32,
    /// The target without the overlap's removal (β = 0): the debiasing iterations'
    /// ([`debias_pairs`]).
    pub unbiased: f32,
}

/// A pair's target relative normal velocity ([the contact](self)) at the relaxation `beta`,
/// from its gap and the speed `approach` at which it closed entering the iterations.
#[inline(always)]
fn pair_target(gap: f32, approach: f32, beta: f32, s: &PairStep) -> f32 {
    let closing = if gap >= 0.0 {
        gap * s.inv_h
    } else {
        beta * gap * s.inv_h
    };
    let mut target = s.restitution * approach + (1.0 - s.restitution) * -closing;
    // Overlapping: parting at least at the overlap's removal.
    if gap < 0.0 && target < -closing {
        target = -closing;
    }
    target
}

/// How far a push along the unit `dir` moves a grain on `support` ([`pair_support`]) along
/// `dir`, per unit: the support's response (`respond` with no restitution and the scene's
/// `friction`) takes the part `c` going into the support and up to `friction·c` of the rest,
/// `t = √(1 − c²)`, which leaves `t·max(0, t − friction·c)`; 0 for a wedged grain
/// ([`PAIR_WEDGED`]). 1 for a push out of the support or a grain on nothing.
#[inline(always)]
fn pair_free(support: &[f32; 4], dir: Vec3, friction: f32) -> f32 {
    if support[3] == 0.0 {
        return 1.0;
    }
    let into = -dir.dot(Vec3::new(support[0], support[1], support[2]));
    if !(into > 0.0) {
        return 1.0;
    }
    if support[3] == PAIR_WEDGED {
        return 0.0;
    }
    let across2 = 1.0 - into * into;
    let across = if across2 > 0.0 {
        math::sqrt(across2)
    } else {
        0.0
    };
    let kept = across - friction * into;
    if kept > 0.0 {
        across * kept
    } else {
        0.0
    }
}

/// The geometry of `me`'s contact with `other` ([`PairGeometry`]); `v0` and `w0` are their
/// velocities entering the substep's iterations ([`pair_start`]'s), `sup_me` and `sup_other`
/// their supports ([`pair_support`]).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn pair_geometry(
    me: &PairBody,
    other: &PairBody,
    v0: &PairVelocity,
    w0: &PairVelocity,
    sup_me: &[f32; 4],
    sup_other: &[f32; 4],
    s: &PairStep,
) -> PairGeometry {
    let x = Vec3::from_array(me.position) - Vec3::from_array(other.position);
    let d2 = x.dot(x);
    let (dist, n) = if d2 > 0.0 {
        let dist = math::sqrt(d2);
        (dist, x * (1.0 / dist))
    } else {
        let up = if me.index > other.index { 1.0 } else { -1.0 };
        (0.0, Vec3::new(0.0, up, 0.0))
    };
    let height = x.dot(Vec3::from_array(s.up)) * s.inv_diameter;
    let height = height.clamp(-1.0, 1.0);
    // A grain resting on the scene cannot take the part of a push that goes into its
    // support: that part is the other grain's (wedged against a wall, a grain would otherwise
    // take most of the correction and lose it to the wall, and the pair stay overlapped).
    // (`0.5 − height·σ/2`, the other's own even share, not `1 − even`: the same bits as
    // the other particle computes, and a shape Mesa's NIR does not refold.)
    let even = 0.5 + height * s.half_stacking;
    let mine = even * pair_free(sup_me, n, s.scene_friction);
    let theirs = (0.5 - height * s.half_stacking) * pair_free(sup_other, -n, s.scene_friction);
    let share = if mine + theirs > 0.0 {
        mine / (mine + theirs)
    } else {
        even
    };
    let gap = dist - s.diameter;
    // The bounce is of the speed the pair approached with entering the iterations, not of
    // an iteration's: in a falling column each grain would otherwise bounce off the one
    // below as it is raised, and the top take the sum.
    let vn0 = (Vec3::new(v0[0], v0[1], v0[2]) - Vec3::new(w0[0], w0[1], w0[2])).dot(n);
    let approach = if vn0 < 0.0 { -vn0 } else { 0.0 };
    PairGeometry {
        n: n.to_array(),
        gap,
        share,
        target: pair_target(gap, approach, s.relaxation, s),
        unbiased: pair_target(gap, approach, 0.0, s),
    }
}

/// The change of `me`'s velocity `v` from its contact with `other` (velocity `w`), if the
/// pair is in contact ([the contact](self)); `v0` and `w0` as in [`pair_geometry`].
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn pair_impulse(
    me: &PairBody,
    v: Vec3,
    v0: &PairVelocity,
    sup_me: &[f32; 4],
    other: &PairBody,
    w: Vec3,
    w0: &PairVelocity,
    sup_other: &[f32; 4],
    s: &PairStep,
) -> Option<PairChange> {
    pair_response(
        &pair_geometry(me, other, v0, w0, sup_me, sup_other, s),
        v,
        w,
        s,
    )
}

/// [`pair_impulse`] from the pair's geometry ([`pair_geometry`]): a pair that would close
/// within the substep (`gap + v_n·h < 0`) is brought to its target, pushed when it closes
/// faster, and held back when it overlaps and parts faster. Returns `me`'s share of the
/// normal change and of the friction apart ([`PairChange`]): friction holds a grain only
/// where more than one thing holds it ([the contact](self)).
#[inline(always)]
pub fn pair_response(g: &PairGeometry, v: Vec3, w: Vec3, s: &PairStep) -> Option<PairChange> {
    let n = Vec3::from_array(g.n);
    let gap = g.gap;
    let vr = v - w;
    let vn = vr.dot(n);
    if gap + vn * s.h >= 0.0 {
        return None;
    }
    let jn = g.target - vn;
    let (pushes, pulls) = (jn > 0.0, gap < 0.0 && jn < 0.0);
    if !(pushes || pulls) {
        return None;
    }
    let vt = vr - n * vn;
    let t2 = vt.dot(vt);
    let mut friction = Vec3::ZERO;
    if t2 > 0.0 && pushes {
        // Friction acts with a push; a pull (held back) moves along the normal only.
        let tl = math::sqrt(t2);
        let limit = s.friction * jn;
        let keep = if tl <= limit { 1.0 } else { limit / tl };
        friction = vt * -keep;
    }
    Some(PairChange {
        normal: n * (jn * g.share),
        friction: friction * g.share,
    })
}

/// `me`'s part of a contact's change of velocity ([`pair_response`]): along the normal, and
/// the friction's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairChange {
    /// Along the contact's normal: the push or the hold.
    pub normal: Vec3,
    /// Across it: the friction, which a particle's mean takes only when it is held by two
    /// contacts or more ([the contact](self)).
    pub friction: Vec3,
}

/// The candidates of the particle at sorted position `k`, in the pass's fixed order: the
/// 27 cells around its own (z, then y, then x, from −1 to 1), each bucket in sorted order
/// (`ranges[h]` is the bucket of hash `h`, `[start, end)` in the sorted order; `[0, 0]` when
/// empty), keeping the entries of that very cell (a bucket holds every cell of its hash)
/// closer than the cell edge, itself left out. `each` gets each candidate's sorted position.
/// Returns whether the loop stopped at the cap ([`PairParams::max_candidates`] bucket entries
/// visited, kept or not). The candidates depend on positions only, so they are the same in
/// every iteration of a substep: the CPU backend lists them once.
///
/// It is [`pair_neighbourhood`] of the particle's cell filtered by [`pair_in_reach`]: every
/// particle of one cell visits the same entries, so a lister may gather a cell's
/// neighbourhood once and filter it for each of its particles, with the same candidates in
/// the same order (the CPU backend does).
///
/// A pair farther apart than the cell edge is never a candidate: whether it lies in
/// neighbouring cells depends on where the grid falls, and it cannot close within the
/// substep at the speeds the cells were made for ([`pair_cell_edge`]).
#[inline]
pub fn pair_candidates(
    k: usize,
    bodies: &[PairBody],
    ranges: &[[u32; 2]],
    s: &PairStep,
    mut each: impl FnMut(usize),
) -> bool {
    let me = &bodies[k];
    let x = Vec3::from_array(me.position);
    pair_neighbourhood(me.cell, bodies, ranges, s, |m| {
        if pair_in_reach(k, x, m, bodies[m].position, s) {
            each(m);
        }
    })
}

/// The entries of the 27 cells around `cell` that lie in those very cells, in
/// [`pair_candidates`]' order, each given to `each` by its sorted position; `true` when the
/// visit stopped at the cap ([`PairParams::max_candidates`] bucket entries visited, kept or
/// not). What it visits depends on `cell` alone, not on which of the cell's particles asks.
#[inline]
pub fn pair_neighbourhood(
    cell: [i32; 3],
    bodies: &[PairBody],
    ranges: &[[u32; 2]],
    s: &PairStep,
    each: impl FnMut(usize),
) -> bool {
    pair_neighbourhood_where(cell, bodies, ranges, s, s.mask, |_| true, each)
}

/// [`pair_neighbourhood`] that does not read the entries of a cell `occupied` says holds no
/// particle: `occupied` gets the cell's [`pair_hash`] under `mask` (a power of two less one,
/// at or above [`PairStep::mask`], so that the table's hash is its low bits) and may say
/// `true` of an empty cell, never `false` of one that holds a particle. The same entries in
/// the same order, and the same count of visited entries against the cap: a bucket passed
/// over counts its entries as visited (none of them lies in that cell), and stops the visit
/// where the cap falls in it. The CPU backend asks a bitmap of the occupied cells, which
/// passes over most buckets of a sparse cloud without reading their entries.
#[inline]
pub fn pair_neighbourhood_where(
    cell: [i32; 3],
    bodies: &[PairBody],
    ranges: &[[u32; 2]],
    s: &PairStep,
    mask: u32,
    occupied: impl Fn(u32) -> bool,
    mut each: impl FnMut(usize),
) -> bool {
    let mut visited = 0u32;
    let hashes = neighbourhood_hashes(cell, mask);
    for dz in -1i32..=1 {
        for dy in -1i32..=1 {
            for dx in -1i32..=1 {
                let c = [cell[0] + dx, cell[1] + dy, cell[2] + dz];
                let h = hashes[(9 * (dz + 1) + 3 * (dy + 1) + dx + 1) as usize];
                let r = ranges[(h & s.mask) as usize];
                if !occupied(h) {
                    let len = r[1] - r[0];
                    if len > s.max_candidates - visited {
                        return true;
                    }
                    visited += len;
                    continue;
                }
                for m in r[0]..r[1] {
                    if visited == s.max_candidates {
                        return true;
                    }
                    visited += 1;
                    let m = m as usize;
                    if bodies[m].cell != c {
                        continue;
                    }
                    each(m);
                }
            }
        }
    }
    false
}

/// [`pair_hash`] of the 27 cells around `cell`, in [`pair_neighbourhood`]'s order (z, then
/// y, then x, from −1 to 1), from parts per axis: a region's combined coordinates and a
/// cell's place in its run are unions of one part per axis, so only the region's mix is
/// done per cell.
#[inline(always)]
fn neighbourhood_hashes(cell: [i32; 3], mask: u32) -> [u32; 27] {
    let region =
        |a: usize, mul: u32| [-1, 0, 1].map(|d| (((cell[a] + d) >> 5) as u32).wrapping_mul(mul));
    let place = |a: usize| [-1, 0, 1].map(|d| cell_place(cell[a] + d, a as u32));
    let (rx, ry, rz) = (region(0, HASH_X), region(1, HASH_Y), region(2, HASH_Z));
    let (px, py, pz) = (place(0), place(1), place(2));
    core::array::from_fn(|i| {
        let (x, y, z) = (i % 3, i / 3 % 3, i / 9);
        region_mix(rx[x] ^ ry[y] ^ rz[z]).wrapping_add(px[x] | py[y] | pz[z]) & mask
    })
}

/// Whether the entry at sorted position `m`, at `other`, is a candidate of the particle at
/// sorted position `k`, at `x`: not itself, and closer than the cell edge
/// ([`pair_candidates`]' filter of [`pair_neighbourhood`]).
#[inline(always)]
pub fn pair_in_reach(k: usize, x: Vec3, m: usize, other: [f32; 3], s: &PairStep) -> bool {
    let d = x - Vec3::from_array(other);
    m != k && !(d.dot(d) >= s.cell * s.cell)
}

/// A particle's contacts summed over an iteration, in its candidates' order.
struct PairSum {
    v: Vec3,
    sum: Vec3,
    /// The contacts' friction, apart: it acts only on a grain held by more than one thing.
    friction: Vec3,
    /// The contacts' weights ([`pair_weight`]).
    weight: f32,
    /// The contacts that move it (weight above 0).
    holds: u32,
}

/// How much a contact counts in a particle's mean: its share relative to an even split,
/// `min(1, 2·share)`. A grain under another (share 0 at full stacking) is not moved by that
/// contact, and it does not dilute what the contacts under it do: in a column each grain
/// takes all of its correction from below, not half.
#[inline(always)]
pub fn pair_weight(share: f32) -> f32 {
    let w = 2.0 * share;
    if w < 1.0 {
        w
    } else {
        1.0
    }
}

impl PairSum {
    #[inline(always)]
    fn new(vel: &[PairVelocity], k: usize) -> Self {
        Self {
            v: Vec3::new(vel[k][0], vel[k][1], vel[k][2]),
            sum: Vec3::ZERO,
            friction: Vec3::ZERO,
            weight: 0.0,
            holds: 0,
        }
    }

    #[inline(always)]
    fn add(&mut self, g: &PairGeometry, w: &PairVelocity, s: &PairStep) {
        let w = Vec3::new(w[0], w[1], w[2]);
        if let Some(dv) = pair_response(g, self.v, w, s) {
            self.sum += dv.normal;
            self.friction += dv.friction;
            let weight = pair_weight(g.share);
            self.weight += weight;
            self.holds += (weight > 0.0) as u32;
        }
    }

    /// The velocity: the contacts' mean change, then the support's response.
    #[inline(always)]
    fn finish(self, sup: [f32; 4], s: &PairStep) -> PairVelocity {
        // A grain on one other grain alone rolls off it (it is not held by friction at a
        // sphere's top); held by two or more, or by one and the scene, friction holds it.
        let held = self.holds >= 2 || (self.holds == 1 && sup[3] != 0.0);
        let sum = if held {
            self.sum + self.friction
        } else {
            self.sum
        };
        let mut out = if self.weight > 0.0 {
            self.v + sum * (1.0 / self.weight)
        } else {
            self.v
        };
        if sup[3] != 0.0 {
            out = respond(
                out,
                Vec3::new(sup[0], sup[1], sup[2]),
                0.0,
                s.scene_friction,
            );
        }
        [out.x, out.y, out.z, 0.0]
    }
}

/// One Jacobi iteration for the particle at sorted position `k`: its velocity after its contacts
/// with its candidates ([`pair_candidates`]; velocities from `vel`, the last iteration's, and from
/// `start`, those entering the iterations), and its support's response ([`pair_support`],
/// `support[k]`: what moves into the scene is taken as the scene's normal impulse, with its
/// friction, `respond` with no restitution), and whether its neighbour loop stopped at the cap.
#[inline]
pub fn pair_velocity(
    k: usize,
    bodies: &[PairBody],
    start: &[PairVelocity],
    vel: &[PairVelocity],
    support: &[[f32; 4]],
    ranges: &[[u32; 2]],
    s: &PairStep,
) -> (PairVelocity, bool) {
    let me = &bodies[k];
    let mut sum = PairSum::new(vel, k);
    let capped = pair_candidates(k, bodies, ranges, s, |m| {
        let g = pair_geometry(
            me,
            &bodies[m],
            &start[k],
            &start[m],
            &support[k],
            &support[m],
            s,
        );
        sum.add(&g, &vel[m], s);
    });
    (sum.finish(support[k], s), capped)
}

/// [`pair_velocity`] from the particle's candidates listed once for the substep (sorted
/// positions, in [`pair_candidates`]' order) with their geometry ([`pair_geometry`]): the
/// same bits, without the search or the geometry. `debias` takes each pair's unbiased
/// target: [`pair_velocity`]'s with [`PairStep::unbiased`].
#[inline]
pub fn pair_velocity_listed(
    k: usize,
    candidates: &[u32],
    geometry: &[PairGeometry],
    vel: &[PairVelocity],
    support: &[[f32; 4]],
    s: &PairStep,
    debias: bool,
) -> PairVelocity {
    let mut sum = PairSum::new(vel, k);
    for (&m, g) in candidates.iter().zip(geometry) {
        if debias {
            let g = PairGeometry {
                target: g.unbiased,
                ..*g
            };
            sum.add(&g, &vel[m as usize], s);
        } else {
            sum.add(g, &vel[m as usize], s);
        }
    }
    sum.finish(support[k], s)
}

/// The caller's scratch for [`collide_pairs`]: `n` keys, bodies and three velocity
/// buffers, and [`pair_table_size`]`(n)` ranges.
pub struct PairScratch<'a> {
    /// `(hash, index)` per particle, sorted in place.
    pub keys: &'a mut [[u32; 2]],
    /// The particles in sorted order.
    pub bodies: &'a mut [PairBody],
    /// Velocities entering the iterations, in sorted order.
    pub start: &'a mut [PairVelocity],
    /// An iteration's velocities in sorted order.
    pub vel: &'a mut [PairVelocity],
    /// The next iteration's velocities.
    pub vel_next: &'a mut [PairVelocity],
    /// Each grain's support ([`pair_support`]), in sorted order.
    pub support: &'a mut [[f32; 4]],
    /// The table: each hash's `[start, end)` in the sorted order.
    pub ranges: &'a mut [[u32; 2]],
}

impl PairScratch<'_> {
    /// Whether the slices hold `n` particles, and `s` was made for them.
    fn holds(&self, n: usize, s: &PairStep) -> bool {
        let t = pair_table_size(n);
        self.keys.len() >= n
            && self.bodies.len() >= n
            && self.start.len() >= n
            && self.vel.len() >= n
            && self.vel_next.len() >= n
            && self.support.len() >= n
            && self.ranges.len() >= t
            && s.mask as usize == t - 1
    }

    /// `iterations` Jacobi iterations of the `valid` sorted particles from `vel` with the
    /// constants `s`, the last one's velocities written to `particles`; returns the
    /// particle-iterations whose neighbour loop hit the cap.
    fn iterate(
        &mut self,
        particles: &mut [Particle],
        valid: usize,
        s: &PairStep,
        iterations: u32,
    ) -> u64 {
        let t = pair_table_size(particles.len());
        let (bodies, start) = (&self.bodies[..valid], &self.start[..valid]);
        let (support, ranges) = (&self.support[..valid], &self.ranges[..t]);
        let (mut a, mut b) = (&mut self.vel[..valid], &mut self.vel_next[..valid]);
        let mut capped = 0u64;
        for _ in 0..iterations {
            for (k, out) in b.iter_mut().enumerate() {
                let (v, cap) = pair_velocity(k, bodies, start, a, support, ranges, s);
                *out = v;
                capped += cap as u64;
            }
            core::mem::swap(&mut a, &mut b);
        }
        for k in 0..valid {
            particles[bodies[k].index as usize].velocity = [a[k][0], a[k][1], a[k][2]];
        }
        capped
    }
}

/// The pass over one substep, on one thread, for callers without a thread pool (the CPU
/// backend runs the same functions in parallel): integrates gravity into every valid particle's
/// velocity and applies the contacts. `view` is the proxy the particles step against and `hints`
/// their leaf hints from it (the march's), for their supports. Positions do not change; the caller
/// then steps every particle with `dt = s.h` and zero gravity. Returns the particles whose
/// neighbour loop hit the cap, summed over iterations. `s` must come from [`PairStep::new`]
/// with `n = particles.len()` and `v_max` at least [`pair_max_speed`]'s; scratch slices
/// shorter than asked give `None` and change nothing.
pub fn collide_pairs(
    particles: &mut [Particle],
    view: &ProxyView<'_>,
    hints: &[LeafHint],
    s: &PairStep,
    iterations: u32,
    mut scratch: PairScratch<'_>,
) -> Option<u64> {
    let n = particles.len();
    let t = pair_table_size(n);
    if !scratch.holds(n, s) || hints.len() < n || n >= PAIR_HASH_NONE as usize {
        return None;
    }
    let keys = &mut scratch.keys[..n];
    for (i, p) in particles.iter().enumerate() {
        keys[i] = match pair_prepare(p, s) {
            Some(_) => [pair_hash(pair_cell(p.position, s), s.mask), i as u32],
            None => [PAIR_HASH_NONE, i as u32],
        };
    }
    keys.sort_unstable();
    let valid = keys.partition_point(|k| k[0] != PAIR_HASH_NONE);
    let (bodies, start, vel, support) = (
        &mut scratch.bodies[..valid],
        &mut scratch.start[..valid],
        &mut scratch.vel[..valid],
        &mut scratch.support[..valid],
    );
    for k in 0..valid {
        let i = keys[k][1] as usize;
        let p = &particles[i];
        bodies[k] = PairBody {
            position: p.position,
            index: i as u32,
            cell: pair_cell(p.position, s),
            hash: keys[k][0],
        };
        (start[k], support[k]) = pair_start(view, p, hints[i], s);
    }
    vel.copy_from_slice(start);
    let ranges = &mut scratch.ranges[..t];
    ranges.fill([0, 0]);
    for k in 0..valid {
        let h = keys[k][0] as usize;
        let (first, last) = pair_range_marks(keys, k);
        if first {
            ranges[h][0] = k as u32;
        }
        if last {
            ranges[h][1] = k as u32 + 1;
        }
    }
    Some(scratch.iterate(particles, valid, s, iterations))
}

/// The debiasing iterations after the march, on one thread ([`collide_pairs`]' second
/// half): the substep's contacts solved again from the particles' velocities after the march,
/// without the overlap's removal ([`PairStep::unbiased`]), so what moved overlapping
/// particles apart does not stay as their velocity. `s`, `iterations` and `scratch` must be
/// those of the [`collide_pairs`] call before the march, its scratch unchanged since; then
/// positions are those it saw but for the march. Returns the particles whose neighbour loop
/// hit the cap, summed over iterations; `None` for scratch unlike [`collide_pairs`]'.
pub fn debias_pairs(
    particles: &mut [Particle],
    s: &PairStep,
    iterations: u32,
    mut scratch: PairScratch<'_>,
) -> Option<u64> {
    let n = particles.len();
    if !scratch.holds(n, s) {
        return None;
    }
    let valid = scratch.keys[..n].partition_point(|k| k[0] != PAIR_HASH_NONE);
    for k in 0..valid {
        let v = particles.get(scratch.bodies[k].index as usize)?.velocity;
        scratch.vel[k] = [v[0], v[1], v[2], 0.0];
    }
    Some(scratch.iterate(particles, valid, &s.unbiased(), iterations))
}

/// The largest speed of a valid particle after the substep's gravity (0 when none is
/// valid): [`PairStep::new`]'s `v_max`. Its `h` and gravity must be the substep's.
pub fn pair_max_speed(particles: &[Particle], s: &PairStep) -> f32 {
    particles
        .iter()
        .filter_map(|p| pair_prepare(p, s))
        .fold(0.0, |m, (_, speed)| if speed > m { speed } else { m })
}

/// The valid particles that move more than a radius in the substep ([`pair_is_fast`]).
pub fn pair_fast_count(particles: &[Particle], s: &PairStep) -> u64 {
    particles
        .iter()
        .filter_map(|p| pair_prepare(p, s))
        .filter(|&(_, speed)| pair_is_fast(speed, s))
        .count() as u64
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::vec;
    use std::vec::Vec;

    /// The pass over `ps` for one substep of `h` without gravity.
    fn pass(ps: &mut [Particle], pairs: &PairParams, radius: f32, h: f32) -> u64 {
        let step = StepParams {
            gravity: [0.0; 3],
            dt: h,
            radius,
            ..StepParams::default()
        };
        pairs.validate(&step).unwrap();
        let s0 = PairStep::new(&step, pairs, h, ps.len(), 0.0);
        let s = PairStep::new(&step, pairs, h, ps.len(), pair_max_speed(ps, &s0));
        let n = ps.len();
        let (mut keys, mut bodies) = (vec![[0u32; 2]; n], vec![PairBody::default(); n]);
        let (mut vel, mut vel_next) = (vec![[0f32; 4]; n], vec![[0f32; 4]; n]);
        let mut start = vec![[0f32; 4]; n];
        let mut ranges = vec![[0u32; 2]; pair_table_size(n)];
        let mut support = vec![[0f32; 4]; n];
        let scratch = PairScratch {
            keys: &mut keys,
            bodies: &mut bodies,
            start: &mut start,
            vel: &mut vel,
            vel_next: &mut vel_next,
            support: &mut support,
            ranges: &mut ranges,
        };
        // No particle rests on anything: no hints.
        let words = crate::tests::tiny();
        let view = ProxyView::new(&words).unwrap();
        let hints = vec![LeafHint::NONE; n];
        collide_pairs(ps, &view, &hints, &s, pairs.iterations, scratch).unwrap()
    }

    fn elastic() -> PairParams {
        PairParams {
            restitution: 1.0,
            friction: 0.0,
            iterations: 1,
            ..PairParams::default()
        }
    }

    #[test]
    fn an_elastic_frictionless_pair_leaves_with_the_velocities_its_normal_gives() {
        // Oblique: the normal is along x; the y parts are kept, the x parts exchanged.
        let mut ps = [
            Particle::new([0.0, 0.0, 0.0], [1.0, 0.5, 0.0]),
            Particle::new([0.21, 0.0, 0.0], [-2.0, -0.25, 0.0]),
        ];
        pass(&mut ps, &elastic(), 0.1, 0.01);
        let near = |a: [f32; 3], b: [f32; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-5);
        assert!(
            near(ps[0].velocity, [-2.0, 0.5, 0.0]),
            "{:?}",
            ps[0].velocity
        );
        assert!(
            near(ps[1].velocity, [1.0, -0.25, 0.0]),
            "{:?}",
            ps[1].velocity
        );
        // Too far to close within the substep: nothing.
        let mut far = [
            Particle::new([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]),
            Particle::new([0.5, 0.0, 0.0], [-1.0, 0.0, 0.0]),
        ];
        pass(&mut far, &elastic(), 0.1, 0.01);
        assert_eq!(far[0].velocity, [1.0, 0.0, 0.0]);
    }

    #[test]
    fn coincident_particles_part_along_y_by_index() {
        let mut ps = [
            Particle::new([1.0, 1.0, 1.0], [0.0; 3]),
            Particle::new([1.0, 1.0, 1.0], [0.0; 3]),
        ];
        pass(&mut ps, &PairParams::default(), 0.1, 0.01);
        assert!(ps[1].velocity[1] > 0.0 && ps[0].velocity[1] < 0.0);
        assert_eq!(ps[0].velocity[1], -ps[1].velocity[1]);
        assert_eq!((ps[0].velocity[0], ps[0].velocity[2]), (0.0, 0.0));
    }

    #[test]
    fn invalid_particles_are_left_out_and_far_cells_saturate() {
        let mut ps = [
            Particle::new([f32::NAN, 0.0, 0.0], [0.0; 3]),
            Particle::new([0.0, 0.0, 0.0], [0.0; 3]),
            Particle::new([0.15, 0.0, 0.0], [f32::INFINITY, 0.0, 0.0]),
            Particle::new([1e38, -1e38, 0.0], [0.0; 3]),
            Particle::new([1e38, -1e38, 0.0], [0.0; 3]),
        ];
        pass(&mut ps, &PairParams::default(), 0.1, 0.01);
        assert!(ps[0].velocity == [0.0; 3] && ps[1].velocity == [0.0; 3]);
        assert_eq!(ps[2].velocity[0], f32::INFINITY);
        // The two far ones share the saturated cell and see each other.
        assert!(ps[4].velocity[1] > 0.0);
        let s = PairStep::new(
            &StepParams {
                radius: 0.1,
                ..StepParams::default()
            },
            &PairParams::default(),
            0.01,
            4,
            0.0,
        );
        assert_eq!(
            pair_cell([1e38, -1e38, 3.0e9], &s),
            [1 << 30, -(1 << 30), 1 << 30]
        );
    }

    #[test]
    fn a_region_of_cells_hashes_to_one_run_of_the_table_in_morton_order_of_blocks() {
        let mask = (1 << 24) - 1;
        // Regions of 8×8×8 blocks of 4×4×4 cells: 32 cells an axis, from a multiple of 32.
        for base in [[0, 0, 0], [-32, 64, -96], [1 << 29, -(1 << 30), 32]] {
            let start = pair_hash(base, mask);
            let mut seen = vec![false; 1 << 15];
            for i in 0..1 << 15 {
                let c = [i % 32, i / 32 % 32, i / 1024];
                let (b, l) = (
                    [c[0] / 4, c[1] / 4, c[2] / 4],
                    [c[0] % 4, c[1] % 4, c[2] % 4],
                );
                let h = pair_hash([base[0] + c[0], base[1] + c[1], base[2] + c[2]], mask);
                let at = h.wrapping_sub(start) & mask;
                assert!(at < 1 << 15, "{base:?} + {c:?}");
                // The cell's place in its block, x lowest, in the low six bits of the run.
                assert_eq!(at & 63, (l[0] | l[1] << 2 | l[2] << 4) as u32);
                // Morton: bit `3i + a` of the block's place is bit `i` of its coordinate on
                // axis `a`.
                let block = at >> 6;
                for (a, &ba) in b.iter().enumerate() {
                    for bit in 0..3 {
                        assert_eq!((block >> (3 * bit + a)) & 1, (ba as u32 >> bit) & 1);
                    }
                }
                seen[at as usize] = true;
            }
            assert!(seen.iter().all(|&s| s));
            // The next region along each axis starts elsewhere.
            for a in 0..3 {
                let mut next = base;
                next[a] += 32;
                assert_ne!(pair_hash(next, mask), start);
            }
        }
    }

    /// `pair_hash` as first written (one mix per cell, the Morton code bit by bit): the
    /// definition the per-axis parts of `pair_hash` and `neighbourhood_hashes` must keep.
    fn pair_hash_by_bits(c: [i32; 3], mask: u32) -> u32 {
        let b = [c[0] >> 2, c[1] >> 2, c[2] >> 2];
        let r = [b[0] >> 3, b[1] >> 3, b[2] >> 3];
        let mut h = (r[0] as u32).wrapping_mul(0x8da6_b343)
            ^ (r[1] as u32).wrapping_mul(0xd816_3841)
            ^ (r[2] as u32).wrapping_mul(0xcb1a_b31f);
        h ^= h >> 16;
        h = h.wrapping_mul(0x7feb_352d);
        h ^= h >> 15;
        h = h.wrapping_mul(0x846c_a68b);
        h ^= h >> 16;
        let mut block = 0u32;
        for i in 0..3 {
            for (a, &ba) in b.iter().enumerate() {
                block |= ((ba >> i) as u32 & 1) << (3 * i + a);
            }
        }
        let local = (c[0] & 3) as u32 | ((c[1] & 3) as u32) << 2 | ((c[2] & 3) as u32) << 4;
        h.wrapping_add(block << 6 | local) & mask
    }

    #[test]
    fn a_cell_and_its_neighbourhood_hash_as_the_bitwise_definition_says() {
        let limit = PAIR_CELL_LIMIT as i32;
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let mut differs = 0;
        for i in 0..20_000 {
            // Near the origin, across region and block edges, and at the cell limits.
            let c: [i32; 3] = core::array::from_fn(|_| {
                let r = next();
                match i % 3 {
                    0 => (r % 200) as i32 - 100,
                    1 => (r % (2 * limit as u64 + 1)) as i32 - limit,
                    _ => [-limit, limit, -32, 31, 0][(r % 5) as usize] + (r >> 8) as i32 % 2,
                }
            });
            let c = c.map(|x| x.clamp(-limit, limit));
            let mask = [(1u32 << 20) - 1, (1 << 3) - 1, u32::MAX >> 1][i % 3];
            assert_eq!(pair_hash(c, mask), pair_hash_by_bits(c, mask), "{c:?}");
            let hashes = neighbourhood_hashes(c, mask);
            for (k, &h) in hashes.iter().enumerate() {
                let d = [
                    (k % 3) as i32 - 1,
                    (k / 3 % 3) as i32 - 1,
                    (k / 9) as i32 - 1,
                ];
                let n = [c[0] + d[0], c[1] + d[1], c[2] + d[2]];
                assert_eq!(h, pair_hash_by_bits(n, mask), "{c:?} + {d:?}");
                differs += (h != hashes[13]) as u32;
            }
        }
        assert!(differs > 0);
    }

    #[test]
    fn a_neighbourhood_that_passes_over_empty_cells_gives_the_same_entries_and_cap() {
        let mut rng = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let step = StepParams {
            radius: 0.05,
            ..StepParams::default()
        };
        let mut s = PairStep::new(&step, &PairParams::default(), 1.0 / 360.0, 300, 0.0);
        // A small table: cells of every part of the cloud share buckets.
        s.mask = 31;
        let bits_mask = (s.mask << 3) | 7;
        let mut passed_over = 0;
        for round in 0..40 {
            // Clumps and a sparse spread, so that most neighbourhoods hold empty cells.
            let n = 50 + (next() % 250) as usize;
            let spread = [0.3f32, 2.0, 8.0][round % 3];
            let positions: Vec<[f32; 3]> = (0..n)
                .map(|_| core::array::from_fn(|_| (next() % 10_000) as f32 * 1e-4 * spread))
                .collect();
            let mut keys: Vec<[u32; 2]> = positions
                .iter()
                .enumerate()
                .map(|(i, &x)| [pair_hash(pair_cell(x, &s), s.mask), i as u32])
                .collect();
            keys.sort_unstable();
            let bodies: Vec<PairBody> = keys
                .iter()
                .map(|&[hash, i]| PairBody {
                    position: positions[i as usize],
                    index: i,
                    cell: pair_cell(positions[i as usize], &s),
                    hash,
                })
                .collect();
            let mut ranges = vec![[0u32; 2]; s.mask as usize + 1];
            for (k, b) in bodies.iter().enumerate() {
                let r = &mut ranges[b.hash as usize];
                if r[1] == 0 {
                    r[0] = k as u32;
                }
                r[1] = k as u32 + 1;
            }
            // Every occupied cell's bit, and some empty cells' too (what a bitmap's shared
            // bits say).
            let occupied: Vec<u32> = bodies
                .iter()
                .map(|b| pair_hash(b.cell, bits_mask))
                .collect();
            let salt = next();
            let says = |h: u32| occupied.contains(&h) || (h as u64 ^ salt).is_multiple_of(5);
            for b in &bodies {
                for cap in [1u32, 2, 3, 5, 8, 13, 40, 1024] {
                    let s = PairStep {
                        max_candidates: cap,
                        ..s
                    };
                    let (mut all, mut some) = (Vec::new(), Vec::new());
                    let capped = pair_neighbourhood(b.cell, &bodies, &ranges, &s, |m| all.push(m));
                    let capped_where = pair_neighbourhood_where(
                        b.cell,
                        &bodies,
                        &ranges,
                        &s,
                        bits_mask,
                        says,
                        |m| some.push(m),
                    );
                    assert_eq!(
                        (capped_where, &some),
                        (capped, &all),
                        "{:?} cap {cap}",
                        b.cell
                    );
                }
                let hashes = neighbourhood_hashes(b.cell, bits_mask);
                passed_over += hashes.iter().filter(|&&h| !says(h)).count();
            }
        }
        assert!(passed_over > 1000, "{passed_over}");
    }

    #[test]
    fn a_crowd_beyond_the_cap_is_counted_not_looped_over() {
        let mut ps: Vec<Particle> = (0..40)
            .map(|i| Particle::new([i as f32 * 1e-4, 0.0, 0.0], [0.0; 3]))
            .collect();
        let pairs = PairParams {
            max_candidates: 8,
            iterations: 2,
            ..PairParams::default()
        };
        assert_eq!(pass(&mut ps, &pairs, 0.1, 0.01), 80);
        assert!(ps.iter().all(|p| p.velocity.iter().all(|c| c.is_finite())));
    }

    #[test]
    fn parameters_are_checked() {
        let step = StepParams {
            radius: 0.1,
            ..StepParams::default()
        };
        let ok = PairParams::default();
        assert_eq!(ok.validate(&step), Ok(()));
        let no_radius = StepParams::default();
        assert_eq!(ok.validate(&no_radius), Err(PairParamError::NoRadius));
        for (bad, err) in [
            (
                PairParams {
                    restitution: f32::NAN,
                    ..ok
                },
                "restitution",
            ),
            (
                PairParams {
                    friction: -1.0,
                    ..ok
                },
                "friction",
            ),
            (
                PairParams {
                    relaxation: 0.0,
                    ..ok
                },
                "relaxation",
            ),
            (
                PairParams {
                    stacking: 2.0,
                    ..ok
                },
                "stacking",
            ),
            (
                PairParams {
                    iterations: 0,
                    ..ok
                },
                "iterations",
            ),
            (
                PairParams {
                    iterations: 9,
                    max_iterations: 8,
                    ..ok
                },
                "the most particle iterations must be 9 (the fewest) to 64, got 8",
            ),
            (
                PairParams {
                    max_iterations: 65,
                    ..ok
                },
                "the most particle iterations",
            ),
            (
                PairParams {
                    substeps: 100_000,
                    ..ok
                },
                "substeps",
            ),
            (
                PairParams {
                    max_candidates: 0,
                    ..ok
                },
                "neighbour cap",
            ),
        ] {
            let e = bad.validate(&step).unwrap_err();
            assert!(std::format!("{e}").contains(err), "{e}");
        }
        // The iterations follow the depth: one for every 12 grains in a column, within the
        // fewest and the most; none more without gravity; a depth past the most is flagged.
        let column = |deepest: u32| PairProbe {
            speed: 0.0,
            deepest,
        };
        let pairs = PairParams::default();
        for (deepest, want) in [(0, 8), (1, 8), (96, 8), (97, 9), (250, 21), (768, 64)] {
            assert_eq!(
                pair_iterations_for(&step, &pairs, &column(deepest)),
                (want, false),
                "{deepest} deep"
            );
        }
        assert_eq!(pair_iterations_for(&step, &pairs, &column(769)), (64, true));
        let weightless = StepParams {
            gravity: [0.0; 3],
            ..step
        };
        assert_eq!(
            pair_iterations_for(&weightless, &pairs, &column(800)),
            (8, false)
        );
        let capped = PairParams {
            iterations: 2,
            max_iterations: 5,
            ..pairs
        };
        assert_eq!(pair_iterations_for(&step, &capped, &column(30)), (3, false));
        assert_eq!(pair_iterations_for(&step, &capped, &column(60)), (5, false));
        assert_eq!(pair_iterations_for(&step, &capped, &column(61)), (5, true));
        // The probe: the fastest speed, and the most particles in one column along gravity
        // (a diameter, 0.2, wide); one the pass leaves out takes no part.
        let mut ps = std::vec![Particle::new([5.05, -1.0, 0.05], [0.0, 1.0, 0.0])];
        for k in 0..5 {
            ps.push(Particle::new([0.05, k as f32 * 0.3, 0.15], [3.0, 0.0, 0.0]));
        }
        ps.push(Particle::new([0.05, f32::NAN, 0.15], [9.0, 0.0, 0.0]));
        let mut table = std::vec![[0u32; 2]; pair_column_table_size(ps.len())];
        let probe = PairProbe::of_all(&ps, &step, &mut table).unwrap();
        assert_eq!(
            probe,
            PairProbe {
                speed: 3.0,
                deepest: 5
            }
        );
        assert_eq!(PairProbe::of_all(&ps, &step, &mut table[..3]), None);
        assert_eq!(
            PairProbe::of_all(&[], &step, &mut table),
            Some(PairProbe::default())
        );
        // Across gravity: unit vectors at right angles to it and to each other.
        for g in [[0.0, -9.81, 0.0], [1.0, 2.0, -3.0], [0.0, 0.0, 5.0]] {
            let s = StepParams { gravity: g, ..step };
            let [a, b] = pair_across(&s).map(Vec3::from_array);
            let up = Vec3::from_array(pair_up(&s));
            for (x, y) in [(a, up), (b, up), (a, b)] {
                assert!(x.dot(y).abs() < 1e-6, "{g:?}");
            }
            assert!((a.length() - 1.0).abs() < 1e-6 && (b.length() - 1.0).abs() < 1e-6);
        }
        // Automatic substeps: g h² ≤ κ R.
        let s = pair_substeps(&step, &ok);
        let h = step.dt / s as f32;
        assert!(9.81 * h * h <= PAIR_COMPRESSION * 0.1 * 1.0001);
        let h_fewer = step.dt / (s - 1).max(1) as f32;
        assert!(s == 1 || 9.81 * h_fewer * h_fewer > PAIR_COMPRESSION * 0.1);
        // With speed: never fewer than gravity's, and every particle within a radius per
        // substep, for speeds up to what the cap allows.
        let gravity_only = PairParams {
            follow_speed: false,
            ..ok
        };
        assert_eq!(pair_substeps_for(&step, &gravity_only, 250.0), s);
        assert_eq!(pair_substeps_for(&step, &ok, 0.0), s);
        for v in [0.5f32, 3.0, 17.0, 60.0, 250.0] {
            let n = pair_substeps_for(&step, &ok, v);
            assert!(n >= s, "{v}: {n}");
            let h = step.dt / n as f32;
            let reach = (v + 9.81 * step.dt) * h;
            assert!(
                n == MAX_PAIR_SUBSTEPS || reach <= 0.1,
                "{v}: {n} substeps reach {reach}"
            );
            if n > s && n < MAX_PAIR_SUBSTEPS {
                let h = step.dt / (n - 1) as f32;
                assert!(
                    (v + 9.81 * step.dt) * h > 0.1 * 0.999,
                    "{v}: {n} is not the fewest"
                );
            }
        }
        assert_eq!(
            pair_substeps_for(&step, &ok, f32::INFINITY),
            MAX_PAIR_SUBSTEPS
        );
        assert_eq!(pair_substeps_for(&step, &ok, f32::NAN), MAX_PAIR_SUBSTEPS);
        // The caller's count stands.
        let fixed = PairParams { substeps: 3, ..ok };
        assert_eq!(pair_substeps_for(&step, &fixed, 250.0), 3);
        // The probe: |v| of a particle the pass takes, 0 for one it leaves out.
        let mut p = Particle::new([0.0; 3], [3.0, 4.0, 0.0]);
        assert_eq!(pair_probe_speed(&p), 5.0);
        p.velocity[1] = f32::NAN;
        assert_eq!(pair_probe_speed(&p), 0.0);
    }

    /// A push straight into a grain's support moves it nowhere, one along the support all
    /// the way, one between by what the support's friction leaves (a wedged grain: nowhere);
    /// a grain on nothing, or pushed out of its support, moves freely.
    #[test]
    fn the_support_takes_the_part_of_a_push_into_it() {
        let floor = [0.0, 1.0, 0.0, 1.0];
        let down = Vec3::new(0.0, -1.0, 0.0);
        assert_eq!(pair_free(&floor, down, 0.5), 0.0);
        assert_eq!(pair_free(&floor, Vec3::X, 0.5), 1.0);
        assert_eq!(pair_free(&floor, -down, 0.5), 1.0);
        assert_eq!(pair_free(&[0.0; 4], down, 0.5), 1.0);
        // 45° into the floor: c = t = √½, and μ = 0.5 leaves t·(t − μc) = ½·(1 − ½).
        let slant = Vec3::new(1.0, -1.0, 0.0).normalize();
        assert!((pair_free(&floor, slant, 0.5) - 0.25).abs() < 1e-6);
        // Steeper than the friction cone: held.
        assert_eq!(pair_free(&floor, slant, 1.5), 0.0);
        // Wedged (stopped by the shell rule): any push into it is held, one along it is free.
        let wedged = [0.0, 1.0, 0.0, PAIR_WEDGED];
        assert_eq!(pair_free(&wedged, slant, 0.0), 0.0);
        assert_eq!(pair_free(&wedged, Vec3::X, 0.5), 1.0);
        assert_eq!(pair_free(&wedged, -down, 0.5), 1.0);
    }

    /// The pair's two shares sum to one whatever their supports; a grain pressed straight into
    /// its floor by one above takes none of the push, and a push along the floor leaves the
    /// shares as they are without supports.
    #[test]
    fn a_grain_pressed_into_its_support_leaves_the_push_to_the_other() {
        let step = StepParams {
            radius: 0.1,
            ..StepParams::default()
        };
        let s = PairStep::new(&step, &PairParams::default(), 0.004, 2, 1.0);
        let body = |x: [f32; 3], index| PairBody {
            position: x,
            index,
            ..PairBody::default()
        };
        let v0 = [0.0f32; 4];
        let floor = [0.0, 1.0, 0.0, 1.0];
        let none = [0.0f32; 4];
        let share = |a: &PairBody, b: &PairBody, sa: &[f32; 4], sb: &[f32; 4]| {
            pair_geometry(a, b, &v0, &v0, sa, sb, &s).share
        };
        let low = body([0.0, 0.0, 0.0], 0);
        let high = body([0.01, 0.18, 0.0], 1);
        let beside = body([0.18, 0.01, 0.0], 1);
        for (other, sup) in [(&high, &none), (&high, &floor), (&beside, &floor)] {
            for sup_low in [&none, &floor] {
                let sum = share(&low, other, sup_low, sup) + share(other, &low, sup, sup_low);
                assert!((sum - 1.0).abs() < 1e-6, "{sum}");
            }
        }
        // The low grain on its floor, pressed down into it: the high one takes the push.
        let pressed = share(&low, &high, &floor, &none);
        assert_eq!(pressed, 0.0);
        // A grain against a wall, pressed into it from beside: about half the push without
        // the wall, none with it.
        let wall = [1.0, 0.0, 0.0, 1.0];
        assert!(share(&low, &beside, &none, &none) > 0.4);
        assert_eq!(share(&low, &beside, &wall, &none), 0.0);
        assert_eq!(share(&beside, &low, &none, &wall), 1.0);
        // Side by side on the floor: the push is along it, the shares as without supports.
        let along = share(&low, &beside, &floor, &floor);
        let free = share(&low, &beside, &none, &none);
        assert!((along - free).abs() < 0.02, "{along} vs {free}");
    }
}
