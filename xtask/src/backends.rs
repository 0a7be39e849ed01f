//! `--backend auto|cpu|wgpu`: picking where particles are stepped, and saying so.

use anyhow::{bail, Result};
use octoproxy_core::{
    Backend, EventCount, Hit, HitEvent, Particle, SceneSides, SceneStepReport, StepParams,
};
use octoproxy_cpu::{CpuBackend, Scene, SceneStepError};
use octoproxy_wgpu::WgpuBackend;

/// Which backend to step on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackendChoice {
    /// A hardware GPU when there is one, else the CPU.
    Auto,
    /// The rayon CPU backend.
    Cpu,
    /// The wgpu backend on the best adapter, software ones (lavapipe) included.
    Wgpu,
}

impl BackendChoice {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(BackendChoice::Auto),
            "cpu" => Ok(BackendChoice::Cpu),
            "wgpu" | "gpu" => Ok(BackendChoice::Wgpu),
            _ => bail!("--backend: expected auto, cpu or wgpu, got {s:?}"),
        }
    }
}

/// One of the backends, behind one set of methods.
// One per process: the CPU variant's size does not matter.
#[allow(clippy::large_enum_variant)]
pub enum Stepper {
    Cpu(CpuBackend),
    Wgpu(Box<WgpuBackend>),
}

/// The backend for a choice, saying on stderr which it picked and why.
pub fn select_backend(choice: BackendChoice) -> Result<Stepper> {
    match choice {
        BackendChoice::Cpu => {
            eprintln!("backend: cpu");
            Ok(Stepper::Cpu(CpuBackend::new()))
        }
        BackendChoice::Wgpu => match WgpuBackend::new() {
            Ok(gpu) => {
                eprintln!("backend: wgpu on {}", gpu.description());
                Ok(Stepper::Wgpu(Box::new(gpu)))
            }
            Err(e) => bail!("--backend wgpu: {e}"),
        },
        BackendChoice::Auto => match WgpuBackend::new_hardware() {
            Ok(gpu) => {
                eprintln!(
                    "backend: wgpu on {} (auto: a GPU is present)",
                    gpu.description()
                );
                Ok(Stepper::Wgpu(Box::new(gpu)))
            }
            Err(e) => {
                eprintln!("backend: cpu (auto: {e})");
                Ok(Stepper::Cpu(CpuBackend::new()))
            }
        },
    }
}

macro_rules! both {
    ($self:ident, $b:ident => $e:expr) => {
        match $self {
            Stepper::Cpu($b) => Ok($e?),
            Stepper::Wgpu($b) => Ok($e?),
        }
    };
}

impl Stepper {
    /// Name for reports: `cpu`, or `wgpu (adapter)`.
    pub fn name(&self) -> String {
        match self {
            Stepper::Cpu(b) => b.name().to_string(),
            Stepper::Wgpu(b) => format!("{} ({})", b.name(), b.description()),
        }
    }

    pub fn upload_proxy(&mut self, words: &[u32]) -> Result<()> {
        both!(self, b => b.upload_proxy(words))
    }

    pub fn upload_particles(&mut self, particles: &[Particle]) -> Result<()> {
        both!(self, b => b.upload_particles(particles))
    }

    pub fn download_particles(&mut self, out: &mut [Particle]) -> Result<()> {
        both!(self, b => b.download_particles(out))
    }

    pub fn step(&mut self, params: &StepParams, steps: u32) -> Result<()> {
        both!(self, b => b.step(params, steps))
    }

    /// Steps with the particle-particle pass.
    pub fn step_pairs(
        &mut self,
        params: &StepParams,
        pairs: &octoproxy_core::PairParams,
        steps: u32,
    ) -> Result<()> {
        both!(self, b => b.step_pairs(params, pairs, steps))
    }

    /// What the particle-particle pass did since last asked.
    pub fn take_pair_report(&mut self) -> Result<octoproxy_core::PairReport> {
        both!(self, b => b.take_pair_report())
    }

    /// Waits for queued steps (for timing).
    pub fn finish(&mut self) -> Result<()> {
        both!(self, b => b.finish())
    }

    /// One step through `scene` (see `Scene::step`), with hit records when `hits`.
    pub fn step_scene(&mut self, scene: &mut Scene, params: &StepParams, hits: bool) -> Result<()> {
        match self {
            Stepper::Cpu(b) => scene.step(b, params, hits).map_err(flat),
            Stepper::Wgpu(b) => scene.step(b.as_mut(), params, hits).map_err(flat),
        }
    }

    /// One step through `scene` with the particle-particle pass (see `Scene::step_pairs`).
    pub fn step_scene_pairs(
        &mut self,
        scene: &mut Scene,
        params: &StepParams,
        pairs: &octoproxy_core::PairParams,
        hits: bool,
    ) -> Result<()> {
        match self {
            Stepper::Cpu(b) => scene.step_pairs(b, params, pairs, hits).map_err(flat),
            Stepper::Wgpu(b) => scene
                .step_pairs(b.as_mut(), params, pairs, hits)
                .map_err(flat),
        }
    }

    pub fn upload_scene_sides(&mut self, sides: &[SceneSides]) -> Result<()> {
        both!(self, b => b.upload_scene_sides(sides))
    }

    pub fn download_scene_sides(&mut self, out: &mut [SceneSides]) -> Result<()> {
        both!(self, b => b.download_scene_sides(out))
    }

    pub fn download_hits(&mut self, out: &mut [Hit]) -> Result<()> {
        both!(self, b => b.download_hits(out))
    }

    pub fn set_event_capacity(&mut self, capacity: usize) -> Result<()> {
        both!(self, b => b.set_event_capacity(capacity))
    }

    pub fn take_events(&mut self, out: &mut [HitEvent]) -> Result<EventCount> {
        both!(self, b => b.take_events(out))
    }

    pub fn take_scene_report(&mut self) -> Result<SceneStepReport> {
        both!(self, b => b.take_scene_report())
    }
}

/// A scene step's error as one error: the scene's or the backend's own, or the message.
fn flat<E: std::error::Error + Send + Sync + 'static>(e: SceneStepError<E>) -> anyhow::Error {
    match e {
        SceneStepError::Scene(s) => anyhow::Error::new(s),
        SceneStepError::Backend(b) => anyhow::Error::new(b),
        other => anyhow::anyhow!("{other}"),
    }
}
