//! The penetration harness for scenes of moving and instanced colliders: every step of every
//! particle against exact ground truth in each instance's own frame, never the proxy.
//!
//! - **Closed meshes.** No particle may end a step inside an instance's mesh deeper than one
//!   finest-leaf diagonal of its proxy (the exact winding number, in the instance's frame at
//!   the end pose), unless it started the run inside it; and no piece of its path may pass
//!   through the mesh that deep: each straight piece of the world path is taken into the
//!   instance's frame at the pose of each moment (lerp and slerp, as the step moves it), in
//!   chords whose crossings with the mesh are exact, and where a chord crosses, point by
//!   point every half diagonal.
//! - **Open meshes.** The parity of the path's crossings with the mesh, in the same chords,
//!   may be odd only within a diagonal of the surface; a jump back (the shell rule's) returns
//!   the particle to a point of its path with the crossings it had there, as in the static
//!   harness.
//!
//! The path is the step's own: [`traced_pieces`] steps each particle again with
//! `step_particle_scene_traced` and asserts the very bits the backend gave. A particle flagged
//! crushed (pressed between converging instances, left riding with the one it touched) is
//! counted and no longer checked: it may be inside the other one, which passed over it. For a
//! moving instance the chords are an approximation of the frame's curve (64 a piece), within a
//! small fraction of a leaf for the speeds of the campaigns.

use std::collections::HashMap;

use glam::Vec3;
use octoproxy_core::scene::{Instance, SceneSides, SceneView, FLAG_CRUSHED};
use octoproxy_core::{Aabb, Hit, Particle, ProxyView, StepParams};
use rayon::prelude::*;

use crate::bake::MeshRef;
use crate::ground_truth::GroundTruth;

/// A straight piece of a world path: from, to, and the fractions of the step at its ends.
pub type Piece = (Vec3, Vec3, f32, f32);

/// What the checks found.
#[derive(Clone, Debug, Default)]
pub struct Tally {
    /// Particle-steps found too deep on the other side of a mesh (at a step's end, or on a
    /// piece of the path).
    pub penetrations: usize,
    /// Particle-steps flagged crushed.
    pub crushed: usize,
    /// Collisions counted.
    pub collisions: u64,
    /// Particle-steps checked.
    pub particle_steps: u64,
    /// Particles inside a closed instance when it appeared (shown after a step hidden at
    /// scale 0): nothing could keep them out, and no side they could have is right, so they
    /// are not checked against it until it appears again.
    pub swallowed: usize,
    /// The first few penetrations, for a failure message.
    pub examples: Vec<String>,
}

impl Tally {
    /// Adds `other`'s counts (and examples, up to four).
    pub fn add(&mut self, other: &Tally) {
        self.penetrations += other.penetrations;
        self.crushed += other.crushed;
        self.collisions += other.collisions;
        self.particle_steps += other.particle_steps;
        self.swallowed += other.swallowed;
        for e in &other.examples {
            if self.examples.len() < 4 {
                self.examples.push(e.clone());
            }
        }
    }
}

/// A particle's state across steps: crushed once (no longer checked), the closed meshes it
/// started inside of, and its crossings with each open mesh so far.
#[derive(Clone, Debug, Default)]
struct Track {
    crushed: bool,
    inside: Vec<u32>,
    crossings: HashMap<u32, u64>,
    /// Inside an instance that appeared in the step being checked (counted once).
    swallowed_now: bool,
    /// The instances that swallowed it, not checked against until they appear again.
    swallowed_by: Vec<u32>,
}

/// Ground truth for each proxy's mesh, and what each particle has done so far.
pub struct SceneCheck {
    /// Exact ground truth of each proxy's mesh, by proxy.
    pub truths: Vec<GroundTruth>,
    /// Whether each proxy's mesh is closed (winding numbers) or open (crossing parity).
    pub closed: Vec<bool>,
    /// One finest-leaf diagonal of each proxy, local units.
    pub diagonals: Vec<f32>,
    /// Each proxy's root cube, local units.
    roots: Vec<Aabb>,
    tracks: Vec<Track>,
    /// Whether each instance took part in the last step checked (or at the start).
    active: Vec<bool>,
}

impl SceneCheck {
    /// Ground truth for each proxy's mesh (`meshes[k]` was baked into `proxies[k]`); `closed`
    /// says which are closed.
    pub fn new(meshes: &[MeshRef<'_>], closed: &[bool], proxies: &[ProxyView<'_>]) -> Self {
        Self {
            truths: meshes
                .par_iter()
                .map(|m| GroundTruth::new(m.positions, m.triangles))
                .collect(),
            closed: closed.to_vec(),
            diagonals: proxies
                .iter()
                .map(|v| v.finest_leaf_size() * 3f32.sqrt())
                .collect(),
            roots: proxies.iter().map(|v| v.root_aabb()).collect(),
            tracks: Vec::new(),
            active: Vec::new(),
        }
    }

    /// Whether world point `x` is inside `inst`'s closed mesh deeper than a diagonal, at the
    /// instance's start pose.
    pub fn deep_inside_at_start(&self, inst: &Instance, x: Vec3) -> bool {
        let p = inst.proxy as usize;
        let l = inst.start.to_local(x).to_array();
        self.closed[p]
            && self.truths[p].is_inside(l)
            && self.truths[p].distance(l) > self.diagonals[p] as f64
    }

    /// Starts the run: each particle's side of every closed instance it starts inside of
    /// (`instances` at their start poses), and no crossings yet.
    pub fn begin(&mut self, instances: &[Instance], particles: &[Particle]) {
        self.active = instances.iter().map(|i| i.is_active()).collect();
        self.tracks = particles
            .par_iter()
            .map(|p| {
                let x = Vec3::from_array(p.position);
                let inside = instances
                    .iter()
                    .enumerate()
                    .filter(|(_, inst)| inst.is_active())
                    .filter(|(_, inst)| {
                        let k = inst.proxy as usize;
                        self.closed[k]
                            && self.truths[k].is_inside(inst.start.to_local(x).to_array())
                    })
                    .map(|(i, _)| i as u32)
                    .collect();
                Track {
                    inside,
                    ..Track::default()
                }
            })
            .collect();
    }

    /// Checks one step `before -> after` of every particle against `instances` (their poses
    /// in that step), with every particle's path as `pieces` ([`traced_pieces`]); without
    /// pieces, the straight path of a particle with no collision and every step's end.
    pub fn step(
        &mut self,
        instances: &[Instance],
        before: &[Particle],
        after: &[Particle],
        pieces: Option<&[Vec<Piece>]>,
    ) -> Tally {
        if self.tracks.len() != after.len() {
            self.tracks.resize(after.len(), Track::default());
        }
        let mut tracks = std::mem::take(&mut self.tracks);
        // Instances shown in this step after one hidden (or not yet there): a particle's
        // side of each is taken anew where the step starts.
        let appeared: Vec<bool> = instances
            .iter()
            .enumerate()
            .map(|(i, inst)| inst.is_active() && !self.active.get(i).copied().unwrap_or(false))
            .collect();
        let this = &*self;
        let tally = tracks
            .par_iter_mut()
            .enumerate()
            .map(|(k, track)| {
                let own = pieces.map(|p| p[k].as_slice());
                if !track.crushed {
                    this.appear(instances, &appeared, &before[k], track);
                }
                let mut t = this.check_particle(instances, &before[k], &after[k], own, track);
                t.swallowed += track.swallowed_now as usize;
                track.swallowed_now = false;
                t
            })
            .reduce(Tally::default, |mut a, b| {
                a.add(&b);
                a
            });
        self.tracks = tracks;
        self.active = instances.iter().map(|i| i.is_active()).collect();
        tally
    }

    /// For each instance that `appeared` in this step: the particle's side of it where the
    /// step starts (inside a closed one, or no crossings yet of an open one).
    fn appear(&self, instances: &[Instance], appeared: &[bool], a: &Particle, track: &mut Track) {
        let x = Vec3::from_array(a.position);
        for (i, inst) in instances.iter().enumerate() {
            if !appeared[i] {
                continue;
            }
            let k = inst.proxy as usize;
            let i = i as u32;
            track.inside.retain(|&j| j != i);
            track.swallowed_by.retain(|&j| j != i);
            track.crossings.remove(&i);
            if self.closed[k] && self.truths[k].is_inside(inst.start.to_local(x).to_array()) {
                track.swallowed_by.push(i);
                track.swallowed_now = true;
            }
        }
    }

    fn check_particle(
        &self,
        instances: &[Instance],
        a: &Particle,
        b: &Particle,
        pieces: Option<&[Piece]>,
        track: &mut Track,
    ) -> Tally {
        let mut t = Tally {
            particle_steps: 1,
            collisions: b.collisions().saturating_sub(a.collisions()) as u64,
            ..Tally::default()
        };
        if b.flags & FLAG_CRUSHED != 0 {
            t.crushed += 1;
            track.crushed = true;
        }
        if track.crushed {
            return t;
        }
        let (x0, x1) = (Vec3::from_array(a.position), Vec3::from_array(b.position));
        let straight = [(x0, x1, 0.0f32, 1.0f32)];
        let path: &[Piece] = match pieces {
            Some(p) => p,
            None if b.collisions() == a.collisions() => &straight,
            None => &[],
        };
        // The path's box, to skip instances it cannot meet.
        let mut lo = x0.min(x1);
        let mut hi = x0.max(x1);
        for &(pa, pb, _, _) in path {
            lo = lo.min(pa).min(pb);
            hi = hi.max(pa).max(pb);
        }
        let reach = Aabb { min: lo, max: hi };
        for (i, inst) in instances.iter().enumerate() {
            if !inst.is_active() || track.swallowed_by.contains(&(i as u32)) {
                continue;
            }
            let k = inst.proxy as usize;
            let truth = &self.truths[k];
            let diagonal = self.diagonals[k] as f64;
            let swept = inst.swept_box_of(&self.roots[k]);
            if swept.min.cmpgt(reach.max).any() || swept.max.cmplt(reach.min).any() {
                continue;
            }
            let found = if self.closed[k] {
                let inside = track.inside.contains(&(i as u32));
                self.closed_violation(inst, truth, diagonal, inside, x1, path)
            } else {
                let crossings = track.crossings.entry(i as u32).or_insert(0);
                self.open_violation(inst, truth, diagonal, crossings, x1, path)
            };
            if let Some((l, at)) = found {
                t.penetrations += 1;
                if t.examples.len() < 4 {
                    t.examples.push(format!(
                        "instance {i}: {x0} -> {x1}, too deep on the other side at local {l} ({at:.3} of the step); before {a:?}, after {b:?}, {inst:?}, path {path:?}"
                    ));
                }
            }
        }
        t
    }

    /// A closed mesh: the end point, or a point of the path, deeper than a diagonal on the
    /// other side from where the particle started (`inside`).
    fn closed_violation(
        &self,
        inst: &Instance,
        truth: &GroundTruth,
        diagonal: f64,
        inside: bool,
        x1: Vec3,
        path: &[Piece],
    ) -> Option<(Vec3, f32)> {
        let wrong = |l: Vec3| {
            truth.is_inside(l.to_array()) != inside && truth.distance(l.to_array()) > diagonal
        };
        let l1 = inst.end.to_local(x1);
        if wrong(l1) {
            return Some((l1, 1.0));
        }
        for &(pa, pb, ua, ub) in path {
            let mut found = None;
            chords(inst, pa, pb, ua, ub, |la, lb, at| {
                if found.is_some() || truth.segment_crossings(la.to_array(), lb.to_array()) == 0 {
                    return;
                }
                let step = (diagonal * 0.5) as f32;
                let n = ((lb - la).length() / step).ceil().clamp(1.0, 4096.0) as u32;
                for j in 0..=n {
                    let f = j as f32 / n as f32;
                    let l = la + (lb - la) * f;
                    if wrong(l) {
                        found = Some((l, at(f)));
                        return;
                    }
                }
            });
            if found.is_some() {
                return found;
            }
        }
        None
    }

    /// An open mesh: the parity of the crossings along the path, with a jump back (a piece
    /// that does not start where the last ended) returning to the crossings the particle had
    /// at the point it jumps to; odd at an end point farther than a diagonal from the mesh.
    fn open_violation(
        &self,
        inst: &Instance,
        truth: &GroundTruth,
        diagonal: f64,
        crossings: &mut u64,
        x1: Vec3,
        path: &[Piece],
    ) -> Option<(Vec3, f32)> {
        // (start of each piece, crossings there)
        let mut marks: Vec<(Vec3, u64)> = Vec::with_capacity(path.len());
        let mut last_end: Option<Vec3> = None;
        for &(pa, pb, ua, ub) in path {
            if let Some(e) = last_end {
                if e != pa {
                    if let Some(&(_, c)) = marks.iter().rev().find(|(s, _)| *s == pa) {
                        *crossings = c;
                    }
                }
            }
            marks.push((pa, *crossings));
            chords(inst, pa, pb, ua, ub, |la, lb, _| {
                *crossings += truth.segment_crossings(la.to_array(), lb.to_array()) as u64;
            });
            last_end = Some(pb);
        }
        let l1 = inst.end.to_local(x1);
        let far = truth.distance_capped(l1.to_array(), 2.0 * diagonal) > diagonal;
        (far && *crossings % 2 == 1).then_some((l1, 1.0))
    }
}

/// Calls `f(la, lb, at)` for each chord of the world piece `pa -> pb`, travelled from fraction
/// `ua` to `ub` of the step, in `inst`'s frame at the pose of each moment: one chord for a
/// static instance, 64 for a moving one; `at(f)` is the fraction of the step at a fraction
/// `f` along the chord.
fn chords(
    inst: &Instance,
    pa: Vec3,
    pb: Vec3,
    ua: f32,
    ub: f32,
    mut f: impl FnMut(Vec3, Vec3, &dyn Fn(f32) -> f32),
) {
    // The ends exactly: the next piece starts where this one ends, to the bit.
    let local = |t: f32| {
        if t == 1.0 {
            inst.pose_at(ub).to_local(pb)
        } else {
            inst.pose_at(ua + (ub - ua) * t)
                .to_local(pa + (pb - pa) * t)
        }
    };
    let n: u32 = if inst.is_static() { 1 } else { 64 };
    for j in 0..n {
        let (ta, tb) = (j as f32 / n as f32, (j + 1) as f32 / n as f32);
        let at = move |s: f32| ua + (ub - ua) * (ta + (tb - ta) * s);
        f(local(ta), local(tb), &at);
    }
}

/// Every particle's pieces of one scene step by `step_particle_scene_traced`, from the state
/// `before` (particles and sides), and the indices of the particles whose traced step did not
/// give the very bits `after` that the backend gave (none, on the CPU: the traced step is the
/// step).
pub fn traced_pieces(
    view: &SceneView<'_>,
    before: &[Particle],
    sides: &[SceneSides],
    after: &[Particle],
    params: &StepParams,
) -> (Vec<Vec<Piece>>, Vec<usize>) {
    let traced: Vec<(Vec<Piece>, bool)> = before
        .par_iter()
        .zip(sides)
        .zip(after)
        .map(|((p, s), expected)| {
            let mut q = *p;
            let (mut h, mut sl) = s.split();
            let mut pieces = Vec::new();
            let mut hit = Hit::NONE;
            octoproxy_core::step_particle_scene_traced(
                view,
                &mut q,
                &mut h,
                &mut sl,
                params,
                &mut hit,
                &mut |a, b, ua, ub| pieces.push((a, b, ua, ub)),
            );
            (
                pieces,
                bytemuck::bytes_of(&q) == bytemuck::bytes_of(expected),
            )
        })
        .collect();
    let differ = traced
        .iter()
        .enumerate()
        .filter(|(_, (_, same))| !same)
        .map(|(k, _)| k)
        .collect();
    (traced.into_iter().map(|(p, _)| p).collect(), differ)
}
