//! The `Backend` trait: the one interface every caller (command line, tests, benchmarks)
//! steps particles through, whatever runs the step.

use crate::pairs::{PairParams, PairReport};
use crate::particle::Particle;
use crate::scene::{BroadNode, Hit, HitEvent, Instance, SceneSides};
use crate::step::StepParams;

/// What scene steps did, over all particles, since it was last taken
/// ([`Backend::take_scene_report`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SceneStepReport {
    /// Particle-steps that ended pressed between colliders, left at their last contact
    /// ([`crate::scene::FLAG_CRUSHED`]).
    pub crushed: u64,
    /// Particle-steps that ended in more shells than a particle keeps sides for
    /// ([`crate::scene::FLAG_SIDES_LOST`]).
    pub sides_lost: u64,
}

/// What [`Backend::take_events`] took: the events written, and how many did not fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EventCount {
    /// Events written to the caller's slice, at most the capacity.
    pub stored: usize,
    /// Events that happened after the buffer was full: counted exactly, never stored.
    pub lost: u64,
}

/// The scene in one substep of [`Backend::step_scene_pairs`]: its instances, each moving
/// over the substep, and their broad phase.
#[derive(Clone, Copy, Debug)]
pub struct SceneSubstep<'a> {
    /// The instances, posed at the substep's start and end.
    pub instances: &'a [Instance],
    /// Their broad phase (validated by the backend, with `crate::SceneView::new`).
    pub broad: &'a [BroadNode],
}

/// A place that steps particles against a proxy or a scene: the CPU (rayon) or a GPU (wgpu).
///
/// **API boundary.** Particles go in and come out in the same order; any reordering a
/// backend does for speed stays inside it.
///
/// **Scenes** (moving and instanced colliders, `crate::scene`): the backend holds the
/// scene's proxies ([`Backend::upload_scene_proxies`], once, or when proxies are added) and
/// each particle's sides for the instances it is near ([`SceneSides`]); every call of
/// [`Backend::step_scene`] is one step that moves each instance from the start pose to the
/// end pose it is given. A multi-step run is one call per step, with the poses of that step:
/// the caller samples its animation at step ends (`octoproxy_cpu::Scene::step` does this
/// bookkeeping).
pub trait Backend {
    /// What can go wrong.
    type Error: core::error::Error + Send + Sync + 'static;

    /// A short name for reports (`"cpu"`, `"wgpu"`).
    fn name(&self) -> &str;

    /// Validates and takes a proxy, exactly as core encodes it.
    fn upload_proxy(&mut self, words: &[u32]) -> Result<(), Self::Error>;

    /// Replaces the particles. Their scene sides are emptied, hits cleared, stored events
    /// dropped, and the scene step count restarts at 0.
    fn upload_particles(&mut self, particles: &[Particle]) -> Result<(), Self::Error>;

    /// Copies the particles out, in the order they went in. `out.len()` must equal
    /// [`Backend::particle_count`].
    fn download_particles(&mut self, out: &mut [Particle]) -> Result<(), Self::Error>;

    /// Number of particles held.
    fn particle_count(&self) -> usize;

    /// Steps every particle `steps` times. A backend may return before the work is done
    /// (a GPU queues it); [`Backend::finish`] waits, and a download always sees it.
    fn step(&mut self, params: &StepParams, steps: u32) -> Result<(), Self::Error>;

    /// Steps every particle `steps` times with the particle–particle pass
    /// ([`crate::pairs`]): each step is [`Backend::pair_substeps_now`] substeps of the pass
    /// (it changes velocities only), each followed by the march of every particle against
    /// the proxy over the substep. Each substep's iterations are
    /// [`crate::pair_iterations_for`] of the [`crate::PairProbe`] of the particles held at the
    /// step's start. Needs `params.radius > 0` and a proxy baked for that radius. May
    /// return before the work is done, as [`Backend::step`].
    fn step_pairs(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
        steps: u32,
    ) -> Result<(), Self::Error>;

    /// The substeps the next step with the pass takes: [`crate::pair_substeps_for`] of the
    /// largest [`crate::pair_probe_speed`] of the particles held (a GPU reads it back, so this
    /// waits for the work queued before it).
    fn pair_substeps_now(
        &mut self,
        params: &StepParams,
        pairs: &PairParams,
    ) -> Result<u32, Self::Error>;

    /// What the pass did since the last call (and starts counting again).
    fn take_pair_report(&mut self) -> Result<PairReport, Self::Error>;

    /// Waits until every step asked for is done (for timing). Backends that step
    /// synchronously have nothing to wait for.
    fn finish(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Validates and takes a scene's proxies, by index (an instance's `proxy` names one),
    /// under `key`, a name the caller gives this set ([`Backend::scene_proxies_key`]). Every
    /// particle's leaf hint is forgotten (it belongs to the proxies that made it).
    fn upload_scene_proxies(&mut self, key: u64, proxies: &[&[u32]]) -> Result<(), Self::Error>;

    /// The key of the scene proxies held, if any.
    fn scene_proxies_key(&self) -> Option<u64>;

    /// One step of every particle through the scene of the proxies held and `instances`,
    /// with `broad` its broad phase (validated here, with `crate::SceneView::new`). With
    /// `hits`, each particle's last collision of the step is kept ([`Backend::download_hits`]);
    /// with an event capacity, every collision is ([`Backend::take_events`]). May return
    /// before the work is done, as [`Backend::step`].
    fn step_scene(
        &mut self,
        instances: &[Instance],
        broad: &[BroadNode],
        params: &StepParams,
        hits: bool,
    ) -> Result<(), Self::Error>;

    /// One scene step with the particle–particle pass ([`crate::pairs`]): `S` substeps
    /// ([`Backend::pair_substeps_now`] chooses it; 1 to [`crate::pairs::MAX_PAIR_SUBSTEPS`]),
    /// each the pass (changing velocities only; a grain's
    /// support is the static instance its scene hint holds, [`crate::pairs::pair_support_scene`]),
    /// then every particle marched through the scene over the substep with no gravity (the
    /// pass integrated it), then the debiasing iterations (as many as [`Backend::step_pairs`]
    /// takes, from the particles held at the step's start). `substeps[k]` is the scene in
    /// substep `k`: each instance moving from its pose at `k / S` of the step to its pose at
    /// `(k + 1) / S` (`Instance::pose_at` of the step's instance; a static one as it is). Needs `params.radius > 0`, every instance's proxy baked for
    /// it at its scale. With `hits`, each particle keeps its last collision of any substep,
    /// its `t` the fraction of the whole step; events carry the step's number, their `t` too
    /// of the whole step. May return before the work is done, as [`Backend::step`].
    fn step_scene_pairs(
        &mut self,
        substeps: &[SceneSubstep<'_>],
        params: &StepParams,
        pairs: &PairParams,
        hits: bool,
    ) -> Result<(), Self::Error>;

    /// What the scene steps since the last call did (and starts counting again).
    fn take_scene_report(&mut self) -> Result<SceneStepReport, Self::Error>;

    /// Each particle's last collision in the last scene step taken with hits
    /// ([`Hit::NONE`] when it had none), in upload order; `out.len()` must equal
    /// [`Backend::particle_count`].
    fn download_hits(&mut self, out: &mut [Hit]) -> Result<(), Self::Error>;

    /// How many collision events the buffer keeps until they are taken; 0 (the default)
    /// records none. Drops the events held.
    fn set_event_capacity(&mut self, capacity: usize) -> Result<(), Self::Error>;

    /// Moves the events recorded since the last call into `out` (at least the capacity
    /// long), in no particular order (a GPU's appends race; compare them as sets), and says
    /// how many there were and how many did not fit.
    fn take_events(&mut self, out: &mut [HitEvent]) -> Result<EventCount, Self::Error>;

    /// Each particle's sides for the scene's instances, in upload order.
    fn download_scene_sides(&mut self, out: &mut [SceneSides]) -> Result<(), Self::Error>;

    /// Replaces each particle's sides (starting sides from the meshes, or a restart).
    fn upload_scene_sides(&mut self, sides: &[SceneSides]) -> Result<(), Self::Error>;
}
