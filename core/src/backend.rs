//! The `Backend` trait: the one interface every caller (command line, tests, benchmarks)
//! steps particles through, whatever runs the step.

use crate::particle::Particle;
use crate::step::StepParams;

/// A place that steps particles against a proxy: the CPU (rayon) or a GPU (wgpu).
///
/// **API boundary.** Particles go in and come out in the same order; any reordering a
/// backend does for speed stays inside it.
pub trait Backend {
    /// What can go wrong.
    type Error: core::error::Error + Send + Sync + 'static;

    /// A short name for reports (`"cpu"`, `"wgpu"`).
    fn name(&self) -> &str;

    /// Validates and takes a proxy, exactly as core encodes it.
    fn upload_proxy(&mut self, words: &[u32]) -> Result<(), Self::Error>;

    /// Replaces the particles.
    fn upload_particles(&mut self, particles: &[Particle]) -> Result<(), Self::Error>;

    /// Copies the particles out, in the order they went in. `out.len()` must equal
    /// [`Backend::particle_count`].
    fn download_particles(&mut self, out: &mut [Particle]) -> Result<(), Self::Error>;

    /// Number of particles held.
    fn particle_count(&self) -> usize;

    /// Steps every particle `steps` times. A backend may return before the work is done
    /// (a GPU queues it); [`Backend::finish`] waits, and a download always sees it.
    fn step(&mut self, params: &StepParams, steps: u32) -> Result<(), Self::Error>;

    /// Waits until every step asked for is done (for timing). Backends that step
    /// synchronously have nothing to wait for.
    fn finish(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
