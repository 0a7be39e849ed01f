//! [`CpuBackend`]: the core step run over particles in parallel with rayon.

use octoproxy_core::scene::{step_plain, FLAG_CRUSHED, FLAG_SIDES_LOST, SLOT_INSTANCE_SHIFT};
use octoproxy_core::{
    step_particle_hinted, step_particle_scene, Backend, FormatError, Hit, LeafHint, OwnedProxy,
    Particle, SceneHint, SceneSides, SceneSlots, StepParams,
};

use crate::scene::{Scene, SceneBuildError};
use rayon::prelude::*;

/// What the CPU backend can report.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CpuError {
    /// The proxy did not validate.
    #[error("invalid proxy: {0}")]
    Format(#[from] FormatError),
    /// Stepping before a proxy was uploaded.
    #[error("no proxy uploaded")]
    NoProxy,
    /// Step parameters out of range.
    #[error("invalid step parameters: {0}")]
    Params(#[from] octoproxy_core::ParamError),
    /// The scene did not validate.
    #[error("invalid scene: {0}")]
    Scene(#[from] SceneBuildError),
    /// `download_particles` was given a slice of the wrong length.
    #[error("expected room for {expected} particles, got {got}")]
    LengthMismatch {
        /// Particles held.
        expected: usize,
        /// Length given.
        got: usize,
    },
}

/// Steps particles on the CPU, in parallel over particles. Stepping allocates nothing.
#[derive(Debug, Default)]
pub struct CpuBackend {
    proxy: Option<OwnedProxy>,
    particles: Vec<Particle>,
    /// Each particle's last leaf, so that its next step starts there (core's
    /// [`LeafHint`]); reset when the proxy or the particles are replaced.
    hints: Vec<LeafHint>,
    /// Each particle's sides for the instances of a scene ([`CpuBackend::step_scene`]), in
    /// core's two parts: the hint and first slot every step reads, and the other slots.
    scene_hints: Vec<SceneHint>,
    scene_slots: Vec<SceneSlots>,
    /// Each particle's last collision in its last scene step, when asked for.
    hits: Vec<Hit>,
    use_lut: bool,
}

/// What one scene step did, over all particles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SceneStepReport {
    /// Particles pressed between colliders and left at their last contact (`FLAG_CRUSHED`).
    pub crushed: usize,
    /// Particles in more shells than they keep sides for (`FLAG_SIDES_LOST`).
    pub sides_lost: usize,
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
        self.scene_hints
            .iter()
            .zip(&self.scene_slots)
            .map(|(h, s)| SceneSides::join(h, s))
            .collect()
    }

    /// Replaces the particles' scene sides (a restart, or starting sides from the meshes).
    pub fn set_scene_sides(&mut self, sides: &[SceneSides]) -> Result<(), CpuError> {
        if sides.len() != self.particles.len() {
            return Err(CpuError::LengthMismatch {
                expected: self.particles.len(),
                got: sides.len(),
            });
        }
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

    /// Each particle's last collision in the last scene step taken with hits on.
    pub fn hits(&self) -> &[Hit] {
        &self.hits
    }

    /// One step of every particle through `scene`, moving each instance from its start pose
    /// to its end pose (see [`Scene`]); afterwards every instance holds its end pose
    /// ([`Scene::hold`]). With `hits`, [`CpuBackend::hits`] holds each particle's last
    /// collision of the step. A scene of one proxy placed once at the identity steps exactly
    /// as [`Backend::step`] steps that proxy.
    pub fn step_scene(
        &mut self,
        scene: &mut Scene,
        params: &StepParams,
        hits: bool,
    ) -> Result<SceneStepReport, CpuError> {
        params.validate()?;
        let Self {
            particles,
            scene_hints,
            scene_slots,
            hits: hit_buf,
            ..
        } = self;
        if hits {
            hit_buf.resize(particles.len(), Hit::NONE);
        }
        let report = scene.with_view(|view| {
            // The report is counted in the same pass as the step.
            type State<'a> = ((&'a mut Particle, &'a mut SceneHint), &'a mut SceneSlots);
            let plain = view.plain_proxy();
            let step = |((p, sh), ss): State<'_>, h: Option<&mut Hit>| {
                match plain {
                    Some((c, proxy))
                        if sh.first_slot >> SLOT_INSTANCE_SHIFT == c && sh.hint_instance == c =>
                    {
                        step_plain(proxy, c, p, sh, params, h);
                    }
                    _ => {
                        step_particle_scene(view, p, sh, ss, params, h);
                    }
                }
                (
                    (p.flags & FLAG_CRUSHED != 0) as usize,
                    (p.flags & FLAG_SIDES_LOST != 0) as usize,
                )
            };
            let add = |a: (usize, usize), b: (usize, usize)| (a.0 + b.0, a.1 + b.1);
            let (crushed, sides_lost) = if hits {
                particles
                    .par_iter_mut()
                    .zip(scene_hints.par_iter_mut())
                    .zip(scene_slots.par_iter_mut())
                    .zip(hit_buf.par_iter_mut())
                    .with_min_len(1024)
                    .map(|(ps, h)| step(ps, Some(h)))
                    .reduce(|| (0, 0), add)
            } else {
                particles
                    .par_iter_mut()
                    .zip(scene_hints.par_iter_mut())
                    .zip(scene_slots.par_iter_mut())
                    .with_min_len(1024)
                    .map(|ps| step(ps, None))
                    .reduce(|| (0, 0), add)
            };
            SceneStepReport {
                crushed,
                sides_lost,
            }
        })?;
        scene.hold();
        Ok(report)
    }

    /// The floor: steps the particles `steps` times with integration only (the step's
    /// semi-implicit Euler, no proxy, no collision). Benchmarks measure the step against it.
    pub fn integrate_only(&mut self, params: &StepParams, steps: u32) -> Result<(), CpuError> {
        params.validate()?;
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
        self.particles.clear();
        self.particles.extend_from_slice(particles);
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
}
