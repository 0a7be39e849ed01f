//! [`CpuBackend`]: the core step run over particles in parallel with rayon.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;

use octoproxy_core::scene::{
    plain_first_slot, step_plain, FLAG_CRUSHED, FLAG_SIDES_LOST, SLOT_INSTANCE_SHIFT,
    SLOT_SIDE_MASK,
};
use octoproxy_core::{
    step_particle_hinted, step_particle_scene, Backend, BroadNode, EventCount, FormatError, Hit,
    HitEvent, HitEvents, Instance, LeafHint, OwnedProxy, Particle, ProxyView, SceneError,
    SceneHint, SceneSides, SceneSlots, SceneStepReport, SceneSubstep, SceneView, StepOutcome,
    StepParams,
};

use octoproxy_core::pairs::PairGeometry;
use octoproxy_core::pairs::{
    pair_across, pair_column_key, pair_column_slot, pair_column_table_size, pair_up,
};
use octoproxy_core::pairs::{
    pair_cell, pair_geometry, pair_hash, pair_in_reach, pair_is_fast, pair_neighbourhood_where,
    pair_prepare, pair_start, pair_start_scene, pair_table_size, pair_velocity_listed,
    PAIR_HASH_NONE,
};
use octoproxy_core::{
    pair_iterations_for, pair_probe_speed, pair_substep_range, pair_substeps_for, PairBody,
    PairParams, PairProbe, PairReport, PairStep, PairVelocity,
};

use rayon::prelude::*;

/// The [`PairProbe`] of `particles` under `step`'s gravity, in parallel (core's
/// `PairProbe::of_all`, the same probe): what [`pair_substeps_for`] and
/// [`pair_iterations_for`] take. `columns` is the columns' table, resized here. Without
/// `depth` (or gravity, where nothing stacks) the columns are left uncounted, `deepest` 0, as
/// the GPU backend's probe leaves them.
fn probe(
    particles: &[Particle],
    step: &StepParams,
    columns: &mut Vec<[AtomicU32; 2]>,
    depth: bool,
) -> PairProbe {
    if !depth || pair_up(step) == [0.0; 3] {
        let speed = particles
            .par_iter()
            .with_min_len(4096)
            .map(pair_probe_speed)
            .reduce(|| 0.0, f32::max);
        return PairProbe { speed, deepest: 0 };
    }
    let size = pair_column_table_size(particles.len());
    columns.resize_with(size, Default::default);
    columns.par_iter().with_min_len(4096).for_each(|e| {
        e[0].store(0, Ordering::Relaxed);
        e[1].store(0, Ordering::Relaxed);
    });
    let columns = &columns[..size];
    let across = pair_across(step);
    let inv_diameter = 1.0 / (2.0 * step.radius);
    let mask = size - 1;
    let (speed, deepest) = particles
        .par_iter()
        .with_min_len(4096)
        .map(|p| {
            let Some((_, speed)) = pair_prepare(p, &PairStep::default()) else {
                return (0.0, 0);
            };
            let key = pair_column_key(p.position, &across, inv_diameter);
            let mut slot = pair_column_slot(key, mask as u32) as usize;
            // At most half the entries are taken: an empty one or the column's own is found.
            while let Err(k) =
                columns[slot][0].compare_exchange(0, key, Ordering::Relaxed, Ordering::Relaxed)
            {
                if k == key {
                    break;
                }
                slot = (slot + 1) & mask;
            }
            (speed, columns[slot][1].fetch_add(1, Ordering::Relaxed) + 1)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0.max(b.0), a.1.max(b.1)));
    PairProbe { speed, deepest }
}

/// A step's plan with the pass, from its particles at its start: its substeps and each
/// substep's iterations, which it counts in `report` (a step whose particles stand deeper than
/// the iterations may be).
fn plan(
    particles: &[Particle],
    params: &StepParams,
    pairs: &PairParams,
    report: &mut PairReport,
    columns: &mut Vec<[AtomicU32; 2]>,
) -> (u32, u32) {
    let probe = probe(particles, params, columns, true);
    let (iterations, deep) = pair_iterations_for(params, pairs, &probe);
    report.deep += deep as u64;
    (pair_substeps_for(params, pairs, probe.speed), iterations)
}

/// What the CPU backend can report.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CpuError {
    /// The proxy did not validate.
    #[error("invalid proxy: {0}")]
    Format(#[from] FormatError),
    /// A scene proxy did not validate.
    #[error("scene proxy {index}: {source}")]
    SceneProxy {
        /// Its index.
        index: usize,
        /// Why.
        source: FormatError,
    },
    /// Stepping before a proxy was uploaded.
    #[error("no proxy uploaded")]
    NoProxy,
    /// Step parameters out of range.
    #[error("invalid step parameters: {0}")]
    Params(#[from] octoproxy_core::ParamError),
    /// The particles' radius is not the one the proxy was baked for.
    #[error("{0}")]
    Radius(#[from] octoproxy_core::RadiusMismatch),
    /// The scene did not validate against the scene proxies held.
    #[error("invalid scene: {0}")]
    Scene(#[from] SceneError),
    /// The particle–particle pass's parameters are out of range.
    #[error("invalid particle collision parameters: {0}")]
    Pairs(#[from] octoproxy_core::PairParamError),
    /// A scene step with the pass given a number of substeps it does not take.
    #[error("the scene was posed for {got} substeps of the pass; a step with these parameters takes {min} to {max}")]
    Substeps {
        /// The fewest: the caller's `PairParams::substeps` when set, else gravity's
        /// (`octoproxy_core::pair_substeps`).
        min: u32,
        /// The most: the caller's count when set, else `MAX_PAIR_SUBSTEPS`.
        max: u32,
        /// Substeps given.
        got: usize,
    },
    /// A slice of the wrong length.
    #[error("expected room for {expected} particles, got {got}")]
    LengthMismatch {
        /// Particles held (or the event capacity).
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// More particles than 32-bit indices name (hit events and the pass index particles by
    /// `u32`).
    #[error("{particles} particles: at most {} can be stepped (particles are indexed by 32-bit numbers)", u32::MAX)]
    TooManyParticles {
        /// Particles given.
        particles: usize,
    },
    /// The backend's copy of the particles and their state could not be allocated; what it
    /// held before is kept.
    #[error("{particles} particles: their state ({bytes} bytes) could not be allocated")]
    OutOfMemory {
        /// Particles given.
        particles: usize,
        /// The bytes the backend asked for (saturated).
        bytes: u64,
    },
}

/// Steps particles on the CPU, in parallel over particles. Stepping allocates nothing (but
/// for the events it records, when asked to).
#[derive(Debug, Default)]
pub struct CpuBackend {
    proxy: Option<OwnedProxy>,
    particles: Vec<Particle>,
    /// Each particle's last leaf, so that its next step starts there (core's
    /// [`LeafHint`]); reset when the proxy or the particles are replaced.
    hints: Vec<LeafHint>,
    /// A scene's proxies ([`Backend::upload_scene_proxies`]) and their key.
    scene_proxies: Vec<OwnedProxy>,
    scene_key: Option<u64>,
    /// The grid over a scene step's broad phase (core's `SceneView::with_grid`): its cell
    /// starts and entries, rebuilt every step, kept for their allocations.
    grid_starts: Vec<u32>,
    grid_entries: Vec<u32>,
    /// Each particle's sides for the instances of a scene, in core's two parts: the hint and
    /// first slot every step reads, and the other slots.
    scene_hints: Vec<SceneHint>,
    scene_slots: Vec<SceneSlots>,
    /// A one-proxy static scene at the identity being stepped as the plain step
    /// ([`PlainScene`]); and the instance and proxy of such a scene whose particles all took
    /// the plain step, none of them invalid, in the last scene step, so that the next may.
    plain_scene: Option<PlainScene>,
    plain_ready: Option<(u32, u32)>,
    /// The hints' allocation between two such runs (a new one costs its pages' first
    /// touch, which a run of a few steps notices).
    plain_spare: Vec<LeafHint>,
    /// Each particle's last collision in its last scene step, when asked for.
    hits: Vec<Hit>,
    /// The last collision over a step's substeps with the pass (scratch, kept so that a step
    /// allocates nothing).
    last_hits: Vec<Hit>,
    /// Scene steps since the particles were uploaded, and what they did since last taken.
    scene_steps: u32,
    report: SceneStepReport,
    /// The event buffer: its capacity, the events held, and those lost since last taken.
    event_capacity: usize,
    events: Vec<HitEvent>,
    events_lost: u64,
    use_lut: bool,
    /// The particle–particle pass's scratch, kept between steps, and its report.
    pairs: PairBuffers,
    pair_report: PairReport,
}

/// The pass's buffers on the CPU: core's scratch, with the keys as one `u64` each (hash
/// above index: the same total order as core's `[hash, index]`), and each particle's place
/// in the sorted order (to gather the velocities back in the caller's order).
#[derive(Debug, Default)]
pub(crate) struct PairBuffers {
    keys: Vec<u64>,
    bodies: Vec<PairBody>,
    vel: Vec<PairVelocity>,
    vel_next: Vec<PairVelocity>,
    support: Vec<[f32; 4]>,
    ranges: Vec<[u32; 2]>,
    rank: Vec<AtomicU32>,
    /// The probe's columns ([`PairProbe`]): a key and a count per entry.
    columns: Vec<[AtomicU32; 2]>,
    /// A bit per [`pair_hash`] of the cells under [`occupied_mask`], set for the cells that
    /// hold a particle: the listing passes over a bucket whose cell's bit is clear without
    /// reading its entries ([`pair_neighbourhood_where`]).
    occupied: Vec<AtomicU64>,
    /// Each chunk of the sorted order's candidates
    /// ([`pair_candidates`](octoproxy_core::pairs::pair_candidates)), listed once a substep:
    /// the iterations read them instead of searching the 27 cells again.
    lists: Vec<CandidateList>,
    /// The valid particles of the substep, and those whose candidate search stopped at the
    /// cap: what the debiasing iterations after the march ([`PairBuffers::debias`]) reuse.
    valid: usize,
    capped_once: u64,
    timings: PairTimings,
}

/// The candidates of [`LIST_CHUNK`] particles in sorted order: particle `j` of the chunk has
/// `list[offsets[j]..offsets[j + 1]]`.
#[derive(Debug, Default)]
struct CandidateList {
    offsets: Vec<u32>,
    list: Vec<u32>,
    /// Each candidate's contact geometry ([`pair_geometry`]): positions do not change within
    /// the substep.
    geometry: Vec<PairGeometry>,
    /// The last cell's [`pair_neighbourhood`] (sorted position and position of each entry),
    /// whether its visit stopped at the cap, and the cell: the particles of one cell, next to
    /// each other in the sorted order, filter it instead of visiting the 27 cells again.
    hood: Vec<(u32, [f32; 3])>,
    hood_capped: bool,
    hood_cell: Option<[i32; 3]>,
}

/// Particles (in sorted order) whose candidates one list holds.
const LIST_CHUNK: usize = 1024;

/// Where the CPU's particle–particle pass spends its time, summed over the substeps since
/// last taken ([`CpuBackend::take_pair_timings`]): what the bench reports apart.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PairTimings {
    /// Gravity, the largest speed, the cell keys and their sort.
    pub sort: std::time::Duration,
    /// The sorted bodies, the supports, the table's ranges, the Jacobi iterations over the
    /// 27 cells and the gather back to the caller's order.
    pub neighbours: std::time::Duration,
    /// The march of every particle against the scene over the substep.
    pub march: std::time::Duration,
}

/// The mask of the occupied cells' bitmap for a table of mask `table`: eight bits per bucket
/// (a sparse cloud's neighbouring cells, one in dozens occupied, then rarely share a bit),
/// all of `u32` beyond.
fn occupied_mask(table: u32) -> u32 {
    if table >= u32::MAX >> 3 {
        u32::MAX
    } else {
        table << 3 | 7
    }
}

/// Buckets of the pass's table each thread fills at a time.
const RANGE_CHUNK: usize = 4096;

impl PairBuffers {
    /// One substep of the pass over `particles` with the constants `s`: their velocities
    /// change, nothing else. Returns the particle-iterations that hit the neighbour cap.
    pub(crate) fn substep(
        &mut self,
        particles: &mut [Particle],
        start: impl Fn(usize, &Particle) -> (PairVelocity, [f32; 4]) + Sync,
        s: &PairStep,
        iterations: u32,
        started: std::time::Instant,
    ) -> u64 {
        let n = particles.len();
        let t = pair_table_size(n);
        self.keys.resize(n, 0);
        self.bodies.resize(n, PairBody::default());
        self.vel.resize(n, [0.0; 4]);
        self.vel_next.resize(n, [0.0; 4]);
        self.support.resize(n, [0.0; 4]);
        self.ranges.resize(t, [0, 0]);
        self.rank.resize_with(n, || AtomicU32::new(u32::MAX));
        let keys = &mut self.keys;
        keys.par_iter_mut()
            .zip(particles.par_iter())
            .enumerate()
            .with_min_len(4096)
            .for_each(|(i, (key, p))| {
                let hash = match pair_prepare(p, s) {
                    Some(_) => pair_hash(pair_cell(p.position, s), s.mask),
                    None => PAIR_HASH_NONE,
                };
                *key = (hash as u64) << 32 | i as u64;
            });
        keys.par_sort_unstable();
        let sorted = std::time::Instant::now();
        self.timings.sort += sorted - started;
        let none = (PAIR_HASH_NONE as u64) << 32;
        let valid = keys.partition_point(|&k| k < none);
        let keys = &keys[..valid];
        let (bodies, vel) = (&mut self.bodies[..valid], &mut self.vel[..valid]);
        let support = &mut self.support[..valid];
        let rank = &self.rank;
        // The occupied cells' bits, cleared, then set as the bodies are made. Sorted by the
        // table's hash, the low bits of the bitmap's, a block's cells lie together in the
        // sorted order and in one word of the bitmap: each run of one word is set with one
        // `fetch_or`.
        let bits_mask = occupied_mask(s.mask);
        let words = (bits_mask as usize >> 6) + 1;
        if self.occupied.len() < words {
            self.occupied.resize_with(words, || AtomicU64::new(0));
        }
        let occupied = &self.occupied[..words];
        occupied
            .par_iter()
            .with_min_len(4096)
            .for_each(|w| w.store(0, Ordering::Relaxed));
        const BODY_CHUNK: usize = 4096;
        bodies
            .par_chunks_mut(BODY_CHUNK)
            .zip(vel.par_chunks_mut(BODY_CHUNK))
            .zip(support.par_chunks_mut(BODY_CHUNK))
            .enumerate()
            .for_each(|(c, ((bodies, vel), support))| {
                let (mut word, mut bits) = (usize::MAX, 0u64);
                let chunk = bodies.iter_mut().zip(vel).zip(support);
                for (j, ((body, v), sup)) in chunk.enumerate() {
                    let k = c * BODY_CHUNK + j;
                    let i = keys[k] as u32;
                    let p = &particles[i as usize];
                    *body = PairBody {
                        position: p.position,
                        index: i,
                        cell: pair_cell(p.position, s),
                        hash: (keys[k] >> 32) as u32,
                    };
                    (*v, *sup) = start(i as usize, p);
                    rank[i as usize].store(k as u32, Ordering::Relaxed);
                    let h = pair_hash(body.cell, bits_mask) as usize;
                    if h >> 6 != word {
                        if bits != 0 {
                            occupied[word].fetch_or(bits, Ordering::Relaxed);
                        }
                        (word, bits) = (h >> 6, 0);
                    }
                    bits |= 1 << (h & 63);
                }
                if bits != 0 {
                    occupied[word].fetch_or(bits, Ordering::Relaxed);
                }
            });
        // Each chunk of the table is a run of the sorted keys: find where it starts, walk it.
        self.ranges
            .par_chunks_mut(RANGE_CHUNK)
            .enumerate()
            .for_each(|(c, chunk)| {
                chunk.fill([0, 0]);
                let h0 = (c * RANGE_CHUNK) as u64;
                let mut k = keys.partition_point(|&key| key >> 32 < h0);
                while k < keys.len() && ((keys[k] >> 32) - h0) < chunk.len() as u64 {
                    let h = ((keys[k] >> 32) - h0) as usize;
                    let start = k;
                    while k < keys.len() && keys[k] >> 32 == keys[start] >> 32 {
                        k += 1;
                    }
                    chunk[h] = [start as u32, k as u32];
                }
            });
        let ranges = &self.ranges[..];
        let bodies = &self.bodies[..valid];
        // The velocities entering the iterations, for each pair's target (`pair_geometry`).
        let start = &self.vel[..valid];
        let support = &self.support[..valid];
        let chunks = valid.div_ceil(LIST_CHUNK);
        if self.lists.len() < chunks {
            self.lists.resize_with(chunks, CandidateList::default);
        }
        let lists = &mut self.lists[..chunks];
        // Whether a cell's bit (its hash under `bits_mask`) is set in the bitmap.
        let is_occupied = |h: u32| {
            let h = h as usize;
            occupied[h >> 6].load(Ordering::Relaxed) >> (h & 63) & 1 != 0
        };
        // Candidates depend on positions only: a particle that hits the cap hits it in every
        // iteration, as the search in each would.
        let capped_once: u64 = lists
            .par_iter_mut()
            .enumerate()
            .map(|(c, l)| {
                l.offsets.clear();
                l.list.clear();
                l.geometry.clear();
                l.hood_cell = None;
                let mut capped = 0u64;
                for k in c * LIST_CHUNK..((c + 1) * LIST_CHUNK).min(valid) {
                    l.offsets.push(l.list.len() as u32);
                    let me = &bodies[k];
                    // `pair_candidates`, whose neighbourhood depends on the cell alone:
                    // gathered once for a run of particles of one cell.
                    if l.hood_cell != Some(me.cell) {
                        let hood = &mut l.hood;
                        hood.clear();
                        l.hood_capped = pair_neighbourhood_where(
                            me.cell,
                            bodies,
                            ranges,
                            s,
                            bits_mask,
                            is_occupied,
                            |m| hood.push((m as u32, bodies[m].position)),
                        );
                        l.hood_cell = Some(me.cell);
                    }
                    let x = glam::Vec3::from_array(me.position);
                    for &(m, position) in &l.hood {
                        let m = m as usize;
                        if !pair_in_reach(k, x, m, position, s) {
                            continue;
                        }
                        l.list.push(m as u32);
                        let (v0, w0) = (&start[k], &start[m]);
                        let (sup_me, sup_other) = (&support[k], &support[m]);
                        let g = pair_geometry(me, &bodies[m], v0, w0, sup_me, sup_other, s);
                        l.geometry.push(g);
                    }
                    capped += l.hood_capped as u64;
                }
                l.offsets.push(l.list.len() as u32);
                capped
            })
            .sum();
        self.valid = valid;
        self.capped_once = capped_once;
        self.iterate(particles, s, iterations, false);
        self.timings.neighbours += sorted.elapsed();
        capped_once * iterations as u64
    }

    /// `iterations` Jacobi iterations from `vel` over the substep's lists, the last one's
    /// velocities written to the caller's particles; `debias` takes the unbiased targets.
    fn iterate(&mut self, particles: &mut [Particle], s: &PairStep, iterations: u32, debias: bool) {
        let valid = self.valid;
        let chunks = valid.div_ceil(LIST_CHUNK);
        let lists = &self.lists[..chunks];
        let support = &self.support[..valid];
        let (mut a, mut b) = (&mut self.vel, &mut self.vel_next);
        for _ in 0..iterations {
            let read = &a[..valid];
            b[..valid]
                .par_chunks_mut(LIST_CHUNK)
                .zip(lists.par_iter())
                .enumerate()
                .for_each(|(c, (out, l))| {
                    for (j, o) in out.iter_mut().enumerate() {
                        let (from, to) = (l.offsets[j] as usize, l.offsets[j + 1] as usize);
                        let k = c * LIST_CHUNK + j;
                        let (list, geometry) = (&l.list[from..to], &l.geometry[from..to]);
                        *o = pair_velocity_listed(k, list, geometry, read, support, s, debias);
                    }
                });
            std::mem::swap(&mut a, &mut b);
        }
        let vel = &a[..valid];
        // The debiasing iterations end the substep: the ranks are reset for the next.
        particles
            .par_iter_mut()
            .zip(self.rank.par_iter())
            .with_min_len(4096)
            .for_each(|(p, rank)| {
                let k = if debias {
                    rank.swap(u32::MAX, Ordering::Relaxed)
                } else {
                    rank.load(Ordering::Relaxed)
                };
                if k != u32::MAX {
                    let v = vel[k as usize];
                    p.velocity = [v[0], v[1], v[2]];
                }
            });
    }

    /// The debiasing iterations after the march ([`debias_pairs`]'s, in parallel): the
    /// substep's lists solved again from the marched velocities with the unbiased targets.
    /// Returns the particle-iterations that hit the neighbour cap.
    pub(crate) fn debias(
        &mut self,
        particles: &mut [Particle],
        s: &PairStep,
        iterations: u32,
    ) -> u64 {
        let started = std::time::Instant::now();
        let valid = self.valid;
        let bodies = &self.bodies[..valid];
        self.vel[..valid]
            .par_iter_mut()
            .zip(bodies.par_iter())
            .with_min_len(4096)
            .for_each(|(v, body)| {
                let p = &particles[body.index as usize];
                *v = [p.velocity[0], p.velocity[1], p.velocity[2], 0.0];
            });
        self.iterate(particles, s, iterations, true);
        self.timings.neighbours += started.elapsed();
        self.capped_once * iterations as u64
    }
}

/// The event sink of one particle's step on the CPU: events go to the thread's own list, up
/// to the capacity over all threads (a shared count reserves each place), and are counted as
/// lost past it.
struct CpuEvents<'a> {
    step: u32,
    particle: u32,
    reserved: &'a AtomicU64,
    capacity: u64,
    out: &'a mut Vec<HitEvent>,
    lost: &'a mut u64,
}

impl HitEvents for CpuEvents<'_> {
    fn hit(&mut self, hit: &Hit) {
        if self.reserved.fetch_add(1, Ordering::Relaxed) < self.capacity {
            self.out.push(HitEvent {
                step: self.step,
                particle: self.particle,
                hit: *hit,
            });
        } else {
            *self.lost += 1;
        }
    }
}

/// Particles per task of the scene step's parallel loop.
const SCENE_CHUNK: usize = 1024;

/// Particles stepped through a one-proxy static scene at the identity as the plain step
/// (`Backend::step`'s loop), once every particle's state is that instance's: each one's side
/// in the particle and its hint here, 8 bytes, instead of core's 16-byte [`SceneHint`], whose
/// first slots are made only when the scene's form is asked for
/// ([`CpuBackend::leave_plain_scene`]). The particles, hints, slots and counts are core's
/// [`step_plain`]'s, bit for bit: its first slot is made from the particle and the hint its
/// last step left ([`plain_first_slot`]), which is what the particle and its hint still are
/// when it is made. A step that leaves a particle invalid (a finite start whose path
/// overflows) ends the mode: that particle's slot is made from its hint before that step, as
/// `step_plain` leaves the slot of its last valid step.
#[derive(Debug)]
struct PlainScene {
    /// The instance and its proxy.
    instance: u32,
    proxy: u32,
    /// Each particle's hint (the scene hint's `hint` while the mode lasts).
    hints: Vec<LeafHint>,
    /// The particles the last step left invalid, and their first slots.
    invalid: Vec<(usize, u32)>,
}

/// The particles a step of [`CpuBackend::step_plain_scene`] left invalid: each one's index,
/// first slot, and its counts of the report (crushed, sides lost).
type InvalidParticles = Mutex<Vec<(usize, u32, (u64, u64))>>;

/// One particle's step in [`CpuBackend::step_plain_scene`], the `i`th: `step_plain` with the
/// side already in the particle and the slot left to be made, and an invalid particle's slot
/// and counts put in `invalid`.
#[inline(always)]
fn plain_scene_particle(
    view: &ProxyView<'_>,
    c: u32,
    params: &StepParams,
    i: usize,
    p: &mut Particle,
    hint: &mut LeafHint,
    invalid: &InvalidParticles,
) {
    let before = *hint;
    if step_particle_hinted(view, p, params, hint) == StepOutcome::Invalid {
        // The slot of its last valid step: the particle is as that step left it.
        let slot = plain_first_slot(view, c, p, before);
        let counts = (
            (p.flags & FLAG_CRUSHED != 0) as u64,
            (p.flags & FLAG_SIDES_LOST != 0) as u64,
        );
        if let Ok(mut list) = invalid.lock() {
            list.push((i, slot, counts));
        }
    } else {
        p.flags &= !(FLAG_CRUSHED | FLAG_SIDES_LOST);
    }
}

/// One particle's scene step: the plain step where the scene is one static proxy at the
/// identity (`plain`, `view.plain_proxy()` hoisted out of the loop) and the particle's state
/// is that instance's, else the scene step. The counts of the report it adds to (crushed,
/// sides lost), and 1 unless its next step may be the plain step (it is valid, and its state
/// is the plain instance's).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn step_one(
    view: &SceneView<'_>,
    plain: Option<(u32, &ProxyView<'_>)>,
    p: &mut Particle,
    sh: &mut SceneHint,
    ss: &mut SceneSlots,
    params: &StepParams,
    hit: Option<&mut Hit>,
    events: &mut impl HitEvents,
) -> (u64, u64, u64) {
    let counts = |p: &Particle| {
        (
            (p.flags & FLAG_CRUSHED != 0) as u64,
            (p.flags & FLAG_SIDES_LOST != 0) as u64,
            1,
        )
    };
    match plain {
        Some((c, proxy)) if sh.first_slot >> SLOT_INSTANCE_SHIFT == c && sh.hint_instance == c => {
            // The plain step clears both flags unless the particle is invalid: the common
            // case has nothing to count (a static scene stepped 1.2 times the plain step's
            // cost with the count).
            if step_plain(proxy, c, p, sh, params, hit, events) == StepOutcome::Invalid {
                counts(p)
            } else {
                (0, 0, 0)
            }
        }
        _ => {
            let outcome = step_particle_scene(view, p, sh, ss, params, hit, events);
            // Whether its next step may be the plain step: valid, and that instance's state.
            let next_plain = outcome != StepOutcome::Invalid
                && plain.is_some_and(|(c, _)| {
                    sh.first_slot >> SLOT_INSTANCE_SHIFT == c && sh.hint_instance == c
                });
            let (crushed, lost, _) = counts(p);
            (crushed, lost, u64::from(!next_plain))
        }
    }
}

impl CpuBackend {
    /// A backend with no proxy and no particles.
    pub fn new() -> Self {
        Self {
            use_lut: true,
            ..Self::default()
        }
    }

    /// Whether to enter through the lookup table (on by default; off only to measure it).
    pub fn set_use_lut(&mut self, on: bool) {
        self.use_lut = on;
    }

    /// The particles, in upload order.
    pub fn particles(&self) -> &[Particle] {
        &self.particles
    }

    /// Each particle's sides for a scene's instances, in upload order.
    pub fn scene_sides(&self) -> Vec<SceneSides> {
        // While a static scene is stepped as the plain step, what leaving it would write.
        let plain = self.plain_scene.as_ref().and_then(|ps| {
            let owned = self.scene_proxies.get(ps.proxy as usize)?;
            Some((ps, owned.view()))
        });
        let hint = |i: usize| match &plain {
            Some((ps, view)) => {
                let h = ps.hints[i];
                SceneHint {
                    hint: h,
                    first_slot: plain_first_slot(view, ps.instance, &self.particles[i], h),
                    ..self.scene_hints[i]
                }
            }
            None => self.scene_hints[i],
        };
        (0..self.scene_hints.len())
            .map(|i| SceneSides::join(&hint(i), &self.scene_slots[i]))
            .collect()
    }

    /// Ends the plain stepping of a one-proxy static scene ([`PlainScene`]): each particle's
    /// hint goes back into its scene hint, with the first slot `step_plain` would have left.
    fn leave_plain_scene(&mut self) {
        let Some(proxy) = self.plain_scene.as_ref().map(|ps| ps.proxy as usize) else {
            return;
        };
        let proxies = std::mem::take(&mut self.scene_proxies);
        match proxies.get(proxy) {
            Some(owned) => self.leave_plain_scene_with(&owned.view()),
            // The proxies are replaced only after the mode has ended; stay total anyway.
            None => self.drop_plain_scene(),
        }
        self.scene_proxies = proxies;
    }

    /// [`Self::leave_plain_scene`] with the instance's proxy at hand.
    fn leave_plain_scene_with(&mut self, view: &ProxyView<'_>) {
        let Some(ps) = self.plain_scene.take() else {
            return;
        };
        let c = ps.instance;
        self.scene_hints
            .par_iter_mut()
            .zip(self.particles.par_iter())
            .zip(ps.hints.par_iter())
            .with_min_len(4096)
            .for_each(|((sh, p), &h)| {
                sh.hint = h;
                sh.first_slot = plain_first_slot(view, c, p, h);
            });
        for &(i, slot) in &ps.invalid {
            self.scene_hints[i].first_slot = slot;
        }
        self.plain_spare = ps.hints;
    }

    /// Drops the plain stepping of a one-proxy static scene without making the slots: every
    /// particle's state is being replaced.
    fn drop_plain_scene(&mut self) {
        if let Some(ps) = self.plain_scene.take() {
            self.plain_spare = ps.hints;
        }
        self.plain_ready = None;
    }

    /// What every change of the particles or of their scene state outside a scene step does
    /// first: the plain stepping ends, and the next scene step takes the scene's form.
    fn scene_state_changes(&mut self) {
        self.leave_plain_scene();
        self.plain_ready = None;
    }

    /// A scene step of a one-proxy static scene at the identity, instance `c` of proxy
    /// `proxy` (`view`), as the plain step ([`PlainScene`]); entered when the last scene step
    /// of that instance left every particle ready for the plain step. Returns the report's
    /// counts.
    fn step_plain_scene(
        &mut self,
        view: &ProxyView<'_>,
        c: u32,
        proxy: u32,
        params: &StepParams,
    ) -> (u64, u64) {
        let Self {
            particles,
            scene_hints,
            plain_scene,
            plain_spare,
            ..
        } = self;
        // Entered in the step's own pass over the particles: the hints taken from the scene
        // hints as each particle is stepped.
        let entering = plain_scene.is_none();
        let ps = plain_scene.get_or_insert_with(|| {
            let mut hints = std::mem::take(plain_spare);
            hints.resize(particles.len(), LeafHint::NONE);
            PlainScene {
                instance: c,
                proxy,
                hints,
                invalid: Vec::new(),
            }
        });
        // `step_plain`'s loop: its counts come from the particles it leaves invalid, a
        // path that overflowed from a finite start (every particle started finite, or the
        // last scene step would not have let this one be taken).
        let invalid: InvalidParticles = Mutex::new(Vec::new());
        let step = |i: usize, p: &mut Particle, hint: &mut LeafHint| {
            plain_scene_particle(view, c, params, i, p, hint, &invalid);
        };
        if entering {
            particles
                .par_iter_mut()
                .zip(ps.hints.par_iter_mut())
                .zip(scene_hints.par_iter())
                .enumerate()
                .with_min_len(1024)
                .for_each(|(i, ((p, hint), sh))| {
                    // `step_plain` puts the slot's side in the particle before each step.
                    p.side = sh.first_slot & SLOT_SIDE_MASK;
                    *hint = sh.hint;
                    step(i, p, hint);
                });
        } else {
            // Chunks stepped in a plain loop, as in the scene's form (an index per particle
            // through rayon's `enumerate` cost more).
            particles
                .par_chunks_mut(SCENE_CHUNK)
                .zip(ps.hints.par_chunks_mut(SCENE_CHUNK))
                .enumerate()
                .for_each(|(k, (pc, hc))| {
                    for (j, (p, hint)) in pc.iter_mut().zip(hc).enumerate() {
                        step(k * SCENE_CHUNK + j, p, hint);
                    }
                });
        }
        let invalid = invalid.into_inner().unwrap_or_default();
        if invalid.is_empty() {
            return (0, 0);
        }
        ps.invalid = invalid.iter().map(|&(i, slot, _)| (i, slot)).collect();
        invalid
            .iter()
            .fold((0, 0), |a, &(_, _, c)| (a.0 + c.0, a.1 + c.1))
    }

    /// Each particle's last collision in the last scene step taken with hits.
    pub fn hits(&self) -> &[Hit] {
        &self.hits
    }

    /// The scene step of every particle, with `E` the events' sink (`()` for none).
    fn step_scene_with(
        &mut self,
        view: &SceneView<'_>,
        params: &StepParams,
        hits: bool,
    ) -> (u64, u64, u64) {
        let add = |a: (u64, u64, u64), b: (u64, u64, u64)| (a.0 + b.0, a.1 + b.1, a.2 + b.2);
        let particles_len = self.particles.len();
        let plain = view.plain_proxy();
        let Self {
            particles,
            scene_hints,
            scene_slots,
            hits: hit_buf,
            events,
            events_lost,
            event_capacity,
            scene_steps,
            ..
        } = self;
        let states = particles
            .par_iter_mut()
            .zip(scene_hints.par_iter_mut())
            .zip(scene_slots.par_iter_mut());
        if *event_capacity > 0 {
            // Every collision, to per-thread lists joined afterwards.
            let reserved = AtomicU64::new(events.len() as u64);
            let capacity = *event_capacity as u64;
            let step = *scene_steps;
            // (A hit record to fill only when asked for; the buffer is there either way.)
            hit_buf.resize(particles_len, Hit::NONE);
            let (counts, lists, lost) = states
                .zip(hit_buf.par_iter_mut())
                .enumerate()
                .with_min_len(1024)
                .fold(
                    || ((0u64, 0u64, 0u64), Vec::new(), 0u64),
                    |(counts, mut out, mut lost), (i, (((p, sh), ss), h))| {
                        let mut sink = CpuEvents {
                            step,
                            particle: i as u32,
                            reserved: &reserved,
                            capacity,
                            out: &mut out,
                            lost: &mut lost,
                        };
                        let h = if hits { Some(h) } else { None };
                        let c = step_one(view, plain, p, sh, ss, params, h, &mut sink);
                        (add(counts, c), out, lost)
                    },
                )
                .map(|(c, out, lost)| (c, vec![out], lost))
                .reduce(
                    || ((0, 0, 0), Vec::new(), 0),
                    |(ca, mut la, xa), (cb, lb, xb)| {
                        la.extend(lb);
                        (add(ca, cb), la, xa + xb)
                    },
                );
            for list in lists {
                events.extend(list);
            }
            *events_lost += lost;
            counts
        } else if hits {
            // Chunks stepped in a plain loop, so that the step inlines into it as it does
            // into `Backend::step`'s (a closure called per particle through rayon's map did
            // not, and a static scene cost 1.3 times the plain step).
            particles
                .par_chunks_mut(SCENE_CHUNK)
                .zip(scene_hints.par_chunks_mut(SCENE_CHUNK))
                .zip(scene_slots.par_chunks_mut(SCENE_CHUNK))
                .zip(hit_buf.par_chunks_mut(SCENE_CHUNK))
                .map(|(((ps, shs), sss), hs)| {
                    let mut counts = (0, 0, 0);
                    for (((p, sh), ss), h) in ps.iter_mut().zip(shs).zip(sss).zip(hs) {
                        let c = step_one(view, plain, p, sh, ss, params, Some(h), &mut ());
                        counts = add(counts, c);
                    }
                    counts
                })
                .reduce(|| (0, 0, 0), add)
        } else {
            particles
                .par_chunks_mut(SCENE_CHUNK)
                .zip(scene_hints.par_chunks_mut(SCENE_CHUNK))
                .zip(scene_slots.par_chunks_mut(SCENE_CHUNK))
                .map(|((ps, shs), sss)| {
                    let mut counts = (0, 0, 0);
                    for ((p, sh), ss) in ps.iter_mut().zip(shs).zip(sss) {
                        counts = add(
                            counts,
                            step_one(view, plain, p, sh, ss, params, None, &mut ()),
                        );
                    }
                    counts
                })
                .reduce(|| (0, 0, 0), add)
        }
    }

    /// What every step with the pass checks first: the parameters, and fewer particles than
    /// the pass's keys can number.
    fn check_pass(&self, params: &StepParams, pairs: &PairParams) -> Result<(), CpuError> {
        params.validate()?;
        pairs.validate(params)?;
        let n = self.particles.len();
        if n >= PAIR_HASH_NONE as usize {
            return Err(CpuError::LengthMismatch {
                expected: PAIR_HASH_NONE as usize - 1,
                got: n,
            });
        }
        Ok(())
    }

    /// The substeps of [`Backend::step_scene_pairs`], its checks done, against the scene's
    /// proxies (taken out of `self` for the call).
    fn scene_pair_substeps(
        &mut self,
        proxies: &[OwnedProxy],
        substeps: &[SceneSubstep<'_>],
        params: &StepParams,
        march: &StepParams,
        pairs: &PairParams,
        hits: bool,
    ) -> Result<(), CpuError> {
        let views: Vec<ProxyView<'_>> = proxies.iter().map(|p| p.view()).collect();
        let scenes = substeps
            .iter()
            .map(|sub| {
                let view = SceneView::new(&views, sub.instances, sub.broad)?;
                view.check_radius(params.radius)?;
                Ok(view)
            })
            .collect::<Result<Vec<_>, SceneError>>()?;
        let n = self.particles.len();
        let mut last = std::mem::take(&mut self.last_hits);
        if hits {
            last.clear();
            last.resize(n, Hit::NONE);
            self.hits.resize(n, Hit::NONE);
        }
        let (_, iterations) = plan(
            &self.particles,
            params,
            pairs,
            &mut self.pair_report,
            &mut self.pairs.columns,
        );
        for (k, scene) in scenes.iter().enumerate() {
            let started = std::time::Instant::now();
            let s0 = PairStep::new(params, pairs, march.dt, n, 0.0);
            let (v_max, fast) = self
                .particles
                .par_iter()
                .with_min_len(4096)
                .filter_map(|p| pair_prepare(p, &s0).map(|(_, speed)| speed))
                .map(|speed| (speed, pair_is_fast(speed, &s0) as u64))
                .reduce(|| (0.0, 0), |a, b| (a.0.max(b.0), a.1 + b.1));
            let s = PairStep::new(params, pairs, march.dt, n, v_max);
            self.pair_report.fast += fast;
            let Self {
                particles,
                scene_hints,
                scene_slots,
                pairs: buffers,
                pair_report,
                ..
            } = self;
            let (hints, slots) = (&*scene_hints, &*scene_slots);
            let start =
                |i: usize, p: &Particle| pair_start_scene(scene, p, &hints[i], &slots[i], &s);
            pair_report.capped += buffers.substep(particles, start, &s, iterations, started);
            let marched = std::time::Instant::now();
            let first_event = self.events.len();
            let (crushed, sides_lost, _) = self.step_scene_with(scene, march, hits);
            self.report.crushed += crushed;
            self.report.sides_lost += sides_lost;
            // Hits and events at fractions of the whole step.
            let (k, count) = (k as u32, scenes.len() as u32);
            for e in &mut self.events[first_event..] {
                e.hit = e.hit.in_whole_step(k, count);
            }
            if hits {
                for (l, hit) in last.iter_mut().zip(&self.hits) {
                    if hit.instance >= 0 {
                        *l = hit.in_whole_step(k, count);
                    }
                }
            }
            self.pairs.timings.march += marched.elapsed();
            self.pair_report.capped += self.pairs.debias(&mut self.particles, &s, iterations);
            self.pair_report.substeps += 1;
            self.pair_report.iterations += iterations as u64;
        }
        if hits {
            std::mem::swap(&mut self.hits, &mut last);
        }
        self.last_hits = last;
        Ok(())
    }

    /// Where the particle–particle pass spent its time since this was last taken.
    pub fn take_pair_timings(&mut self) -> PairTimings {
        std::mem::take(&mut self.pairs.timings)
    }

    /// The floor: steps the particles `steps` times with integration only (the step's
    /// semi-implicit Euler, no proxy, no collision). Benchmarks measure the step against it.
    pub fn integrate_only(&mut self, params: &StepParams, steps: u32) -> Result<(), CpuError> {
        params.validate()?;
        self.scene_state_changes();
        let g = glam::Vec3::from_array(params.gravity) * params.dt;
        for _ in 0..steps {
            self.particles
                .par_iter_mut()
                .with_min_len(1024)
                .for_each(|p| {
                    let v = glam::Vec3::from_array(p.velocity) + g;
                    p.velocity = v.to_array();
                    p.position = (glam::Vec3::from_array(p.position) + v * params.dt).to_array();
                });
        }
        Ok(())
    }
}

impl Backend for CpuBackend {
    type Error = CpuError;

    fn name(&self) -> &str {
        "cpu"
    }

    fn upload_proxy(&mut self, words: &[u32]) -> Result<(), CpuError> {
        // Validated once here; every step after reuses it.
        self.proxy = Some(OwnedProxy::new(words.to_vec())?);
        // Hints belong to the proxy that made them.
        self.hints.fill(LeafHint::NONE);
        Ok(())
    }

    fn upload_particles(&mut self, particles: &[Particle]) -> Result<(), CpuError> {
        let n = particles.len();
        if n > u32::MAX as usize {
            return Err(CpuError::TooManyParticles { particles: n });
        }
        // Room for everything first, so that a failed allocation leaves the state as it was.
        fn room<T>(v: &mut Vec<T>, n: usize) -> bool {
            v.try_reserve(n.saturating_sub(v.len())).is_ok()
        }
        if !(room(&mut self.particles, n)
            && room(&mut self.hints, n)
            && room(&mut self.scene_hints, n)
            && room(&mut self.scene_slots, n))
        {
            let each = core::mem::size_of::<Particle>()
                + core::mem::size_of::<LeafHint>()
                + core::mem::size_of::<SceneHint>()
                + core::mem::size_of::<SceneSlots>();
            return Err(CpuError::OutOfMemory {
                particles: n,
                bytes: (n as u64).saturating_mul(each as u64),
            });
        }
        // Every particle's state is replaced.
        self.drop_plain_scene();
        self.particles.clear();
        self.particles.extend_from_slice(particles);
        self.scene_steps = 0;
        self.events.clear();
        self.events_lost = 0;
        self.hints.clear();
        self.hints.resize(particles.len(), LeafHint::NONE);
        self.scene_hints.clear();
        self.scene_hints
            .resize(particles.len(), SceneHint::default());
        self.scene_slots.clear();
        self.scene_slots
            .resize(particles.len(), SceneSlots::default());
        self.hits.clear();
        Ok(())
    }

    fn download_particles(&mut self, out: &mut [Particle]) -> Result<(), CpuError> {
        if out.len() != self.particles.len() {
            return Err(CpuError::LengthMismatch {
                expected: self.particles.len(),
                got: out.len(),
            });
        }
        out.copy_from_slice(&self.particles);
        Ok(())
    }

    fn particle_count(&self) -> usize {
        self.particles.len()
    }

    fn step(&mut self, params: &StepParams, steps: u32) -> Result<(), CpuError> {
        params.validate()?;
        self.scene_state_changes();
        let Self {
            proxy,
            particles,
            hints,
            use_lut,
            ..
        } = self;
        let Some(proxy) = proxy else {
            return Err(CpuError::NoProxy);
        };
        let view = proxy.view();
        octoproxy_core::check_radius(view.header().radius, params.radius)?;
        let view = if *use_lut { view } else { view.without_lut() };
        for _ in 0..steps {
            particles
                .par_iter_mut()
                .zip(hints.par_iter_mut())
                .with_min_len(1024)
                .for_each(|(p, hint)| {
                    step_particle_hinted(&view, p, params, hint);
                });
        }
        Ok(())
    }

    fn upload_scene_proxies(&mut self, key: u64, proxies: &[&[u32]]) -> Result<(), CpuError> {
        // The slots are made with the proxies that stepped them.
        self.scene_state_changes();
        let owned = proxies
            .iter()
            .enumerate()
            .map(|(index, words)| {
                OwnedProxy::new(words.to_vec())
                    .map_err(|source| CpuError::SceneProxy { index, source })
            })
            .collect::<Result<Vec<_>, _>>()?;
        self.scene_proxies = owned;
        self.scene_key = Some(key);
        // Hints belong to the proxies that made them.
        self.scene_hints
            .iter_mut()
            .for_each(|h| (h.hint, h.hint_instance) = (LeafHint::NONE, u32::MAX));
        Ok(())
    }

    fn scene_proxies_key(&self) -> Option<u64> {
        self.scene_key
    }

    fn step_scene(
        &mut self,
        instances: &[Instance],
        broad: &[BroadNode],
        params: &StepParams,
        hits: bool,
    ) -> Result<(), CpuError> {
        params.validate()?;
        let proxies = std::mem::take(&mut self.scene_proxies);
        let mut starts = std::mem::take(&mut self.grid_starts);
        let mut entries = std::mem::take(&mut self.grid_entries);
        let views: Vec<ProxyView<'_>> = proxies.iter().map(|p| p.view()).collect();
        let result = SceneView::new(&views, instances, broad)
            .and_then(|view| view.check_radius(params.radius).map(|()| view))
            .map(|view| {
                if hits {
                    self.hits.resize(self.particles.len(), Hit::NONE);
                }
                let view = match view.grid_sizes() {
                    Some((s, e)) => {
                        starts.resize(s, 0);
                        entries.resize(e, 0);
                        view.with_grid(&mut starts, &mut entries)
                    }
                    None => view,
                };
                // A one-proxy static scene at the identity, without hit records or events:
                // once every particle took the plain step in it, the plain step's loop.
                let plain = view
                    .plain_proxy()
                    .filter(|_| !hits && self.event_capacity == 0)
                    .map(|(c, proxy_view)| (c, view.instances()[c as usize].proxy, proxy_view));
                let key = plain.map(|(c, proxy, _)| (c, proxy));
                if let Some(ps) = &self.plain_scene {
                    if Some((ps.instance, ps.proxy)) != key {
                        match views.get(ps.proxy as usize) {
                            Some(v) => self.leave_plain_scene_with(v),
                            None => self.drop_plain_scene(),
                        }
                    }
                }
                match plain {
                    Some((c, proxy, proxy_view))
                        if self.plain_scene.is_some() || self.plain_ready == key =>
                    {
                        let counts = self.step_plain_scene(proxy_view, c, proxy, params);
                        if self
                            .plain_scene
                            .as_ref()
                            .is_some_and(|ps| !ps.invalid.is_empty())
                        {
                            // Invalid particles end the mode: the scene's form from here on.
                            self.leave_plain_scene_with(proxy_view);
                            self.plain_ready = None;
                        }
                        counts
                    }
                    _ => {
                        let (crushed, sides_lost, off_plain) =
                            self.step_scene_with(&view, params, hits);
                        self.plain_ready = if off_plain == 0 { key } else { None };
                        (crushed, sides_lost)
                    }
                }
            });
        drop(views);
        self.scene_proxies = proxies;
        (self.grid_starts, self.grid_entries) = (starts, entries);
        let (crushed, sides_lost) = result?;
        self.report.crushed += crushed;
        self.report.sides_lost += sides_lost;
        self.scene_steps = self.scene_steps.wrapping_add(1);
        Ok(())
    }

    fn step_pairs(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
        steps: u32,
    ) -> Result<(), CpuError> {
        self.check_pass(params, pairs)?;
        self.scene_state_changes();
        let n = self.particles.len();
        let Self {
            proxy,
            particles,
            hints,
            use_lut,
            pairs: buffers,
            pair_report,
            ..
        } = self;
        let Some(proxy) = proxy else {
            return Err(CpuError::NoProxy);
        };
        let view = proxy.view();
        octoproxy_core::check_radius(view.header().radius, params.radius)?;
        let view = if *use_lut { view } else { view.without_lut() };
        for _ in 0..steps {
            let (substeps, iterations) =
                plan(particles, params, pairs, pair_report, &mut buffers.columns);
            let h = params.dt / substeps as f32;
            // Gravity is integrated by the pass; the march moves each particle with what it
            // left.
            let march = StepParams {
                gravity: [0.0; 3],
                dt: h,
                ..*params
            };
            march.validate()?;
            for _ in 0..substeps {
                let started = std::time::Instant::now();
                let s0 = PairStep::new(params, pairs, h, n, 0.0);
                let (v_max, fast) = particles
                    .par_iter()
                    .with_min_len(4096)
                    .filter_map(|p| pair_prepare(p, &s0).map(|(_, speed)| speed))
                    .map(|speed| (speed, pair_is_fast(speed, &s0) as u64))
                    .reduce(|| (0.0, 0), |a, b| (a.0.max(b.0), a.1 + b.1));
                let s = PairStep::new(params, pairs, h, n, v_max);
                pair_report.fast += fast;
                let start = |i: usize, p: &Particle| pair_start(&view, p, hints[i], &s);
                pair_report.capped += buffers.substep(particles, start, &s, iterations, started);
                let marched = std::time::Instant::now();
                particles
                    .par_iter_mut()
                    .zip(hints.par_iter_mut())
                    .with_min_len(1024)
                    .for_each(|(p, hint)| {
                        step_particle_hinted(&view, p, &march, hint);
                    });
                buffers.timings.march += marched.elapsed();
                pair_report.capped += buffers.debias(particles, &s, iterations);
                pair_report.substeps += 1;
                pair_report.iterations += iterations as u64;
            }
            pair_report.steps += 1;
        }
        Ok(())
    }

    fn step_scene_pairs(
        &mut self,
        substeps: &[SceneSubstep<'_>],
        params: &StepParams,
        pairs: &PairParams,
        hits: bool,
    ) -> Result<(), CpuError> {
        self.check_pass(params, pairs)?;
        self.scene_state_changes();
        let (min, max) = pair_substep_range(params, pairs);
        if !(min as usize..=max as usize).contains(&substeps.len()) {
            return Err(CpuError::Substeps {
                min,
                max,
                got: substeps.len(),
            });
        }
        let h = params.dt / substeps.len() as f32;
        let march = StepParams {
            gravity: [0.0; 3],
            dt: h,
            ..*params
        };
        march.validate()?;
        let proxies = std::mem::take(&mut self.scene_proxies);
        let result = self.scene_pair_substeps(&proxies, substeps, params, &march, pairs, hits);
        self.scene_proxies = proxies;
        result?;
        self.pair_report.steps += 1;
        self.scene_steps = self.scene_steps.wrapping_add(1);
        Ok(())
    }

    fn pair_substeps_now(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
    ) -> Result<u32, CpuError> {
        self.check_pass(params, pairs)?;
        Ok(pair_substeps_for(
            params,
            pairs,
            probe(&self.particles, params, &mut self.pairs.columns, false).speed,
        ))
    }

    fn take_pair_report(&mut self) -> Result<PairReport, CpuError> {
        Ok(std::mem::take(&mut self.pair_report))
    }

    fn take_scene_report(&mut self) -> Result<SceneStepReport, CpuError> {
        Ok(std::mem::take(&mut self.report))
    }

    fn download_hits(&mut self, out: &mut [Hit]) -> Result<(), CpuError> {
        if out.len() != self.particles.len() {
            return Err(CpuError::LengthMismatch {
                expected: self.particles.len(),
                got: out.len(),
            });
        }
        if self.hits.len() == out.len() {
            out.copy_from_slice(&self.hits);
        } else {
            out.fill(Hit::NONE);
        }
        Ok(())
    }

    fn set_event_capacity(&mut self, capacity: usize) -> Result<(), CpuError> {
        self.event_capacity = capacity;
        self.events = Vec::with_capacity(capacity.min(1 << 20));
        self.events_lost = 0;
        Ok(())
    }

    fn take_events(&mut self, out: &mut [HitEvent]) -> Result<EventCount, CpuError> {
        if out.len() < self.event_capacity {
            return Err(CpuError::LengthMismatch {
                expected: self.event_capacity,
                got: out.len(),
            });
        }
        let stored = self.events.len();
        out[..stored].copy_from_slice(&self.events);
        self.events.clear();
        let lost = std::mem::take(&mut self.events_lost);
        Ok(EventCount { stored, lost })
    }

    fn download_scene_sides(&mut self, out: &mut [SceneSides]) -> Result<(), CpuError> {
        if out.len() != self.particles.len() {
            return Err(CpuError::LengthMismatch {
                expected: self.particles.len(),
                got: out.len(),
            });
        }
        self.leave_plain_scene();
        for ((o, h), s) in out.iter_mut().zip(&self.scene_hints).zip(&self.scene_slots) {
            *o = SceneSides::join(h, s);
        }
        Ok(())
    }

    fn upload_scene_sides(&mut self, sides: &[SceneSides]) -> Result<(), CpuError> {
        if sides.len() != self.particles.len() {
            return Err(CpuError::LengthMismatch {
                expected: self.particles.len(),
                got: sides.len(),
            });
        }
        // Every particle's scene state is replaced.
        self.drop_plain_scene();
        for ((h, s), sides) in self
            .scene_hints
            .iter_mut()
            .zip(&mut self.scene_slots)
            .zip(sides)
        {
            (*h, *s) = sides.split();
        }
        Ok(())
    }
}
