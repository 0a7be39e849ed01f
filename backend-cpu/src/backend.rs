//! [`CpuBackend`]: the core step run over particles in parallel with rayon.

use octoproxy_core::scene::{FLAG_CRUSHED, FLAG_SIDES_LOST};
use octoproxy_core::{
    step_particle_hinted, step_particle_scene, Backend, FormatError, Hit, LeafHint, OwnedProxy,
    Particle, SceneSides, StepParams,
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
    /// Each particle's sides for the instances of a scene ([`CpuBackend::step_scene`]).
    scene_sides: Vec<SceneSides>,
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
    pub fn scene_sides(&self) -> &[SceneSides] {
        &self.scene_sides
    }

    /// Replaces the particles' scene sides (a restart, or starting sides from the meshes).
    pub fn set_scene_sides(&mut self, sides: &[SceneSides]) -> Result<(), CpuError> {
        if sides.len() != self.particles.len() {
            return Err(CpuError::LengthMismatch {
                expected: self.particles.len(),
                got: sides.len(),
            });
        }
        self.scene_sides.copy_from_slice(sides);
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
            scene_sides,
            hits: hit_buf,
            ..
        } = self;
        if hits {
            hit_buf.resize(particles.len(), Hit::NONE);
        }
        let report = scene.with_view(|view| {
            let step = |(p, s): (&mut Particle, &mut SceneSides), h: &mut Hit| {
                step_particle_scene(view, p, s, params, h);
            };
            if hits {
                particles
                    .par_iter_mut()
                    .zip(scene_sides.par_iter_mut())
                    .zip(hit_buf.par_iter_mut())
                    .with_min_len(1024)
                    .for_each(|(ps, h)| step(ps, h));
            } else {
                particles
                    .par_iter_mut()
                    .zip(scene_sides.par_iter_mut())
                    .with_min_len(1024)
                    .for_each(|ps| step(ps, &mut Hit::default()));
            }
            SceneStepReport {
                crushed: particles
                    .iter()
                    .filter(|p| p.flags & FLAG_CRUSHED != 0)
                    .count(),
                sides_lost: particles
                    .iter()
                    .filter(|p| p.flags & FLAG_SIDES_LOST != 0)
                    .count(),
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
        self.scene_sides.clear();
        self.scene_sides.resize(particles.len(), SceneSides::EMPTY);
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
