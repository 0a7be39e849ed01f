//! [`WgpuBackend`]: the WGSL mirror of core's step, run through wgpu.

use std::num::NonZeroU64;
use std::sync::mpsc;
use std::sync::{Arc, Mutex};

use bytemuck::{Pod, Zeroable};
use octoproxy_core::{
    Backend, BroadNode, EventCount, FormatError, Hit, HitEvent, Instance, LeafHint, ParamError,
    Particle, ProxyView, SceneError, SceneSides, SceneStepReport, StepParams,
};

use crate::shader::{self, STEP_WORKGROUP_SIZE, WORKGROUP_SIZE};

/// Bytes of one particle record, on both sides.
pub const PARTICLE_BYTES: u64 = core::mem::size_of::<Particle>() as u64;

/// Bytes of one particle's leaf hint (core's `LeafHint`), kept on the GPU beside it.
pub const HINT_BYTES: u64 = core::mem::size_of::<LeafHint>() as u64;

/// Steps recorded in one command buffer. Each step is one dispatch per chunk (one step per
/// invocation), and nothing is read back between steps.
///
/// Why not a loop of steps inside the kernel: Mesa 22.3's lavapipe miscompiled it. Lanes of
/// a SIMD group lost whole steps when another lane of the group ran a long march, which
/// the differential tests caught; one step per dispatch agrees with the CPU bit for bit.
pub const STEPS_PER_SUBMIT: u32 = 64;

/// Default cap on the particles of one chunk (one storage binding); the device's binding
/// limit lowers it further.
pub const DEFAULT_CHUNK_PARTICLES: u32 = 1 << 22;

/// Per-call settings shared by every chunk: WGSL's `RunParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct RunParams {
    /// 1 to enter through the lookup table, 0 to descend from the root.
    pub use_lut: u32,
    /// The plain step's invocations per workgroup (the split step's `args_kernel` sizes
    /// `march_kernel`'s dispatch with it).
    pub workgroup_size: u32,
    /// The widest row of workgroups of one dispatch (likewise).
    pub fold_width: u32,
    /// Padding.
    pub _pad2: u32,
}

/// Per-chunk settings: WGSL's `ChunkParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct ChunkParams {
    /// Particles in the chunk.
    pub count: u32,
    /// The index of the chunk's first particle among all the particles.
    pub first: u32,
    /// Padding.
    pub _pad1: u32,
    /// Padding.
    pub _pad2: u32,
}

/// What the GPU backend can report. Nothing in this crate panics on a GPU failure: no
/// adapter, a lost device, a rejected shader and an out-of-memory are all values here.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WgpuError {
    /// No adapter at all.
    #[error("no GPU adapter: {0}")]
    NoAdapter(String),
    /// Only a software adapter, and a hardware one was asked for.
    #[error("only a software GPU adapter is present ({0}), and the CPU backend is faster")]
    SoftwareOnly(String),
    /// The adapter would not open a device.
    #[error("could not open the GPU device: {0}")]
    RequestDevice(String),
    /// The device rejected the WGSL or the pipeline.
    #[error("the GPU rejected the kernel: {0}")]
    Shader(String),
    /// A validation, out-of-memory or internal error while uploading, stepping or reading.
    #[error("GPU error: {0}")]
    Gpu(String),
    /// The device was lost (driver reset, removal).
    #[error("the GPU device was lost: {0}")]
    DeviceLost(String),
    /// The proxy did not validate.
    #[error("invalid proxy: {0}")]
    Format(#[from] FormatError),
    /// Stepping before a proxy was uploaded.
    #[error("no proxy uploaded")]
    NoProxy,
    /// Step parameters out of range.
    #[error("invalid step parameters: {0}")]
    Params(#[from] ParamError),
    /// The particles' radius is not the one the proxy was baked for.
    #[error("{0}")]
    Radius(#[from] octoproxy_core::RadiusMismatch),
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
    /// `download_particles` was given a slice of the wrong length.
    #[error("expected room for {expected} particles, got {got}")]
    LengthMismatch {
        /// Particles held.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// Something does not fit the device's limits.
    #[error("{what} needs {needed} bytes, more than the device allows ({limit} bytes)")]
    TooLarge {
        /// What did not fit.
        what: &'static str,
        /// Bytes needed.
        needed: u64,
        /// The device's limit.
        limit: u64,
    },
    /// A caller's particle buffer cannot be used as given.
    #[error("particle buffer: {0}")]
    BadBuffer(String),
    /// A scene proxy did not validate.
    #[error("scene proxy {index}: {source}")]
    SceneProxy {
        /// Its index.
        index: usize,
        /// Why.
        source: FormatError,
    },
    /// The scene did not validate against the scene proxies held.
    #[error("invalid scene: {0}")]
    Scene(#[from] SceneError),
    /// The particle-particle pass's parameters are out of range.
    #[error("invalid particle-particle parameters: {0}")]
    Pairs(#[from] octoproxy_core::PairParamError),
    /// A workgroup size the kernel cannot be built with.
    #[error("workgroup size {size}: expected a power of two from 1 to the device's {limit}")]
    WorkgroupSize {
        /// The size asked for.
        size: u32,
        /// The device's limit on invocations per workgroup.
        limit: u32,
    },
}

/// The pipelines, layouts and uniform buffers: built once per backend, reused every step.
#[derive(Debug)]
pub(crate) struct Kernel {
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
    /// `args_kernel`'s: the run's settings, the queue and the indirect arguments.
    args_layout: wgpu::BindGroupLayout,
    args_pipeline_layout: wgpu::PipelineLayout,
    /// Invocations per workgroup of the plain step's kernels and the floor's.
    workgroup_size: u32,
    pipelines: PlainPipelines,
    /// Whether a step is the split step's three dispatches ([`WgpuBackend::set_split_step`]).
    split: bool,
    pub(crate) params: wgpu::Buffer,
    run: wgpu::Buffer,
}

/// The plain kernel's pipelines, at one workgroup size.
#[derive(Debug)]
pub(crate) struct PlainPipelines {
    pub(crate) step: wgpu::ComputePipeline,
    integrate: wgpu::ComputePipeline,
    settle: wgpu::ComputePipeline,
    args: wgpu::ComputePipeline,
    march: wgpu::ComputePipeline,
}

/// A run of particles bound as one storage binding.
#[derive(Debug)]
pub(crate) struct Chunk {
    pub(crate) buffer: wgpu::Buffer,
    pub(crate) offset: u64,
    pub(crate) count: u32,
    pub(crate) params: wgpu::Buffer,
    /// The chunk's particles' `LeafHint`s (8 bytes each), kept between steps.
    pub(crate) hints: wgpu::Buffer,
    /// The split step's queue: the particles that did not settle (4 bytes each), its length
    /// (`Queue`), `march_kernel`'s indirect arguments and `args_kernel`'s bind group.
    queued: wgpu::Buffer,
    queue: wgpu::Buffer,
    args: wgpu::Buffer,
    args_group: wgpu::BindGroup,
    bind_group: Option<wgpu::BindGroup>,
    /// The chunk's particles' scene state, made at the first scene step.
    pub(crate) scene: Option<crate::scene::ChunkScene>,
}

/// Steps particles on a GPU through wgpu. Particles stay on the GPU between steps; they are
/// read back only by [`Backend::download_particles`].
///
/// Build it with [`WgpuBackend::new`] (its own device) or [`WgpuBackend::from_device`] (a
/// device the caller owns), and give it a caller's buffer to step in place with
/// [`WgpuBackend::use_particle_buffer`].
#[derive(Debug)]
pub struct WgpuBackend {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    description: String,
    software: bool,
    pub(crate) kernel: Kernel,
    proxy: Option<wgpu::Buffer>,
    /// The radius the uploaded proxy was baked for.
    proxy_radius: f32,
    pub(crate) chunks: Vec<Chunk>,
    pub(crate) count: usize,
    external: bool,
    chunk_particles: u32,
    pub(crate) fold_width: u32,
    pub(crate) use_lut: bool,
    lost: Arc<Mutex<Option<String>>>,
    uncaptured: Arc<Mutex<Option<String>>>,
    /// The scene kernel and its buffers ([`Backend::step_scene`]).
    pub(crate) scene: crate::scene::SceneGpu,
    /// The particle-particle pass's kernels and buffers ([`Backend::step_pairs`]).
    pub(crate) pairs: crate::pairs::PairGpu,
}

/// The most invocations a workgroup of the plain step may have on a device with `limits`
/// (its workgroups are one-dimensional).
fn step_size_limit(limits: &wgpu::Limits) -> u32 {
    limits
        .max_compute_invocations_per_workgroup
        .min(limits.max_compute_workgroup_size_x)
}

/// The plain kernel's pipelines (`step_kernel`, `integrate_kernel` and the split step's
/// three), built with `workgroup_size` invocations per workgroup; `args_kernel` with
/// `args_layout`, the others with `layout`.
fn plain_pipelines(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    args_layout: &wgpu::PipelineLayout,
    workgroup_size: u32,
) -> PlainPipelines {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("octoproxy step"),
        source: wgpu::ShaderSource::Wgsl(shader::source_with_workgroup_size(workgroup_size).into()),
    });
    let pipeline = |entry: &str, layout: &wgpu::PipelineLayout| {
        device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: Some(layout),
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        })
    };
    PlainPipelines {
        step: pipeline("step_kernel", layout),
        integrate: pipeline("integrate_kernel", layout),
        settle: pipeline("settle_kernel", layout),
        args: pipeline("args_kernel", args_layout),
        march: pipeline("march_kernel", layout),
    }
}

/// A compute shader's storage-buffer binding.
pub(crate) fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// A compute shader's uniform binding of `size` bytes.
pub(crate) fn uniform(binding: u32, size: u64) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: NonZeroU64::new(size),
        },
        count: None,
    }
}

fn lock(m: &Mutex<Option<String>>) -> std::sync::MutexGuard<'_, Option<String>> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl WgpuBackend {
    /// Opens the best adapter there is (a discrete GPU first), software ones included.
    pub fn new() -> Result<Self, WgpuError> {
        Self::open(false)
    }

    /// Like [`WgpuBackend::new`], but refuses a software adapter (such as Mesa's lavapipe),
    /// which steps slower than the CPU backend: what `--backend auto` uses.
    pub fn new_hardware() -> Result<Self, WgpuError> {
        Self::open(true)
    }

    fn open(hardware_only: bool) -> Result<Self, WgpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        };
        let adapter = pollster::block_on(instance.request_adapter(&options))
            .map_err(|e| WgpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let software = info.device_type == wgpu::DeviceType::Cpu;
        if hardware_only && software {
            return Err(WgpuError::SoftwareOnly(info.name));
        }
        let limits = adapter.limits();
        let descriptor = wgpu::DeviceDescriptor {
            label: Some("octoproxy"),
            required_features: wgpu::Features::empty(),
            required_limits: wgpu::Limits {
                max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
                max_buffer_size: limits.max_buffer_size,
                max_compute_workgroups_per_dimension: limits.max_compute_workgroups_per_dimension,
                // The scene kernel and the particle-particle pass bind 7 storage buffers
                // (the plain kernel 3).
                max_storage_buffers_per_shader_stage: limits
                    .max_storage_buffers_per_shader_stage
                    .min(
                        crate::scene::SCENE_STORAGE_BUFFERS
                            .max(crate::pairs::PAIR_STORAGE_BUFFERS)
                            .max(4),
                    ),
                ..wgpu::Limits::downlevel_defaults()
            },
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&descriptor))
            .map_err(|e| WgpuError::RequestDevice(e.to_string()))?;
        let uncaptured = Arc::new(Mutex::new(None));
        let sink = Arc::clone(&uncaptured);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            lock(&sink).get_or_insert_with(|| e.to_string());
        }));
        let lost = Arc::new(Mutex::new(None));
        let lost_sink = Arc::clone(&lost);
        device.set_device_lost_callback(move |reason, message| {
            if reason != wgpu::DeviceLostReason::Destroyed {
                *lock(&lost_sink) = Some(format!("{reason:?}: {message}"));
            }
        });
        let description = format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type);
        let mut backend = Self::build(device, queue, description, lost, uncaptured)?;
        backend.software = software;
        Ok(backend)
    }

    /// A backend on a device the caller owns (an engine's renderer, say). It installs no
    /// error handler or lost-device callback on it: errors of its own work are caught in
    /// error scopes and returned.
    pub fn from_device(device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Self, WgpuError> {
        let lost = Arc::new(Mutex::new(None));
        let uncaptured = Arc::new(Mutex::new(None));
        Self::build(
            device.clone(),
            queue.clone(),
            "caller's device".into(),
            lost,
            uncaptured,
        )
    }

    fn build(
        device: wgpu::Device,
        queue: wgpu::Queue,
        description: String,
        lost: Arc<Mutex<Option<String>>>,
        uncaptured: Arc<Mutex<Option<String>>>,
    ) -> Result<Self, WgpuError> {
        let scope = ErrorScope::push(&device);
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("octoproxy"),
            entries: &[
                storage(0, true),
                storage(1, false),
                uniform(2, core::mem::size_of::<StepParams>() as u64),
                uniform(3, core::mem::size_of::<RunParams>() as u64),
                uniform(4, core::mem::size_of::<ChunkParams>() as u64),
                storage(5, false),
                storage(6, false),
                storage(7, false),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("octoproxy"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let args_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("octoproxy march args"),
            entries: &[
                uniform(3, core::mem::size_of::<RunParams>() as u64),
                storage(7, false),
                storage(8, false),
            ],
        });
        let args_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("octoproxy march args"),
            bind_group_layouts: &[Some(&args_layout)],
            immediate_size: 0,
        });
        let limits = device.limits();
        // The default size, lowered to a power of two the device allows.
        let step_size = STEP_WORKGROUP_SIZE.min(step_size_limit(&limits)).max(1);
        let step_size = 1 << step_size.ilog2();
        let pipelines =
            plain_pipelines(&device, &pipeline_layout, &args_pipeline_layout, step_size);
        let uniform_buffer = |label, size: usize| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let params = uniform_buffer("octoproxy step params", core::mem::size_of::<StepParams>());
        let run = uniform_buffer("octoproxy run params", core::mem::size_of::<RunParams>());
        scope.pop().map_err(WgpuError::Shader)?;
        Ok(Self {
            device,
            queue,
            description,
            software: false,
            kernel: Kernel {
                layout,
                pipeline_layout,
                args_layout,
                args_pipeline_layout,
                workgroup_size: step_size,
                pipelines,
                split: false,
                params,
                run,
            },
            proxy: None,
            proxy_radius: 0.0,
            chunks: Vec::new(),
            count: 0,
            external: false,
            chunk_particles: DEFAULT_CHUNK_PARTICLES,
            fold_width: limits.max_compute_workgroups_per_dimension.max(1),
            use_lut: true,
            lost,
            uncaptured,
            scene: Default::default(),
            pairs: Default::default(),
        })
    }

    /// The adapter, for reports: its name, API and kind.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// Whether the adapter is a software one (such as lavapipe).
    pub fn is_software(&self) -> bool {
        self.software
    }

    /// The device.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// Whether to enter through the lookup table (on by default; off only to measure it).
    pub fn set_use_lut(&mut self, on: bool) {
        self.use_lut = on;
    }

    /// Rebuilds the plain step (and the floor's kernel) with `size` invocations per
    /// workgroup: a power of two up to the device's limit on invocations per workgroup. The
    /// default is [`STEP_WORKGROUP_SIZE`] (or the device's limit, if lower); benchmarks sweep
    /// it. Every size steps the same bits: each invocation steps one particle alone. The scene
    /// kernel and the particle-particle pass's own stages keep [`WORKGROUP_SIZE`].
    pub fn set_workgroup_size(&mut self, size: u32) -> Result<(), WgpuError> {
        let limit = step_size_limit(&self.device.limits());
        if !size.is_power_of_two() || size > limit {
            return Err(WgpuError::WorkgroupSize { size, limit });
        }
        if size == self.kernel.workgroup_size {
            return Ok(());
        }
        self.check_health()?;
        let scope = ErrorScope::push(&self.device);
        let pipelines = plain_pipelines(
            &self.device,
            &self.kernel.pipeline_layout,
            &self.kernel.args_pipeline_layout,
            size,
        );
        scope.pop().map_err(WgpuError::Shader)?;
        self.kernel.pipelines = pipelines;
        self.kernel.workgroup_size = size;
        Ok(())
    }

    /// Whether the plain step is split in three dispatches per chunk (off by default): one
    /// that steps the particles that settle in their hinted leaf and queues the others, one
    /// that sizes the next from the queue, and one, dispatched indirectly, that steps the
    /// queued particles. The same bits either way (each particle gets the same step); on a
    /// GPU, a workgroup of the third holds only particles that march, so lanes that settle do
    /// not wait on lanes that march. Off: one dispatch per chunk, every particle stepped by
    /// `step_kernel`. Not yet measured on a hardware GPU, so not the default.
    pub fn set_split_step(&mut self, on: bool) {
        self.kernel.split = on;
    }

    /// Whether the plain step is split ([`WgpuBackend::set_split_step`]).
    pub fn split_step(&self) -> bool {
        self.kernel.split
    }

    /// Invocations per workgroup of the plain step ([`WgpuBackend::set_workgroup_size`]).
    pub fn workgroup_size(&self) -> u32 {
        self.kernel.workgroup_size
    }

    /// Caps the particles of one chunk (one storage binding). It is rounded down to a
    /// multiple of the workgroup size (at least one workgroup) and lowered to what the
    /// device's binding limit allows. Small values make tests exercise chunking with few
    /// particles. Takes effect at the next upload.
    pub fn set_chunk_particles(&mut self, n: u32) {
        self.chunk_particles = (n / WORKGROUP_SIZE).max(1) * WORKGROUP_SIZE;
    }

    /// Caps the workgroups of one dispatch row; a chunk that needs more is dispatched as a
    /// 2D grid. The default is the device's limit (65,535 on most); small values make tests
    /// exercise the fold.
    pub fn set_fold_width(&mut self, groups: u32) {
        let limit = self
            .device
            .limits()
            .max_compute_workgroups_per_dimension
            .max(1);
        self.fold_width = groups.clamp(1, limit);
    }

    /// Particles per chunk as the device allows.
    fn chunk_capacity(&self) -> u32 {
        let limits = self.device.limits();
        let by_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / PARTICLE_BYTES;
        let by_binding = (by_binding.min(u32::MAX as u64) as u32 / WORKGROUP_SIZE) * WORKGROUP_SIZE;
        self.chunk_particles.min(by_binding.max(WORKGROUP_SIZE))
    }

    /// Number of chunks the particles are split into.
    pub fn chunk_count(&self) -> usize {
        self.chunks.len()
    }

    /// Steps a caller's buffer of `count` particles (core's `Particle` records) starting at
    /// byte `offset`, in place: a renderer can draw them with no copy. The buffer needs
    /// `STORAGE` usage (and `COPY_SRC` for [`Backend::download_particles`], `COPY_DST` for
    /// [`Backend::upload_particles`]); `offset` must meet the device's storage offset
    /// alignment. Replaces any particles held before.
    pub fn use_particle_buffer(
        &mut self,
        buffer: &wgpu::Buffer,
        offset: u64,
        count: usize,
    ) -> Result<(), WgpuError> {
        if !buffer.usage().contains(wgpu::BufferUsages::STORAGE) {
            return Err(WgpuError::BadBuffer("it needs STORAGE usage".into()));
        }
        let align = self.device.limits().min_storage_buffer_offset_alignment as u64;
        if !offset.is_multiple_of(align) {
            return Err(WgpuError::BadBuffer(format!(
                "offset {offset} is not a multiple of {align}"
            )));
        }
        let end = (count as u64)
            .checked_mul(PARTICLE_BYTES)
            .and_then(|bytes| offset.checked_add(bytes));
        if end.is_none_or(|end| end > buffer.size()) {
            return Err(WgpuError::BadBuffer(format!(
                "{count} particles at offset {offset} do not fit in its {} bytes",
                buffer.size()
            )));
        }
        let cap = self.chunk_capacity() as usize;
        let mut chunks = Vec::new();
        let mut start = 0usize;
        while start < count {
            let n = (count - start).min(cap);
            chunks.push(self.chunk(
                buffer.clone(),
                offset + start as u64 * PARTICLE_BYTES,
                n as u32,
                start as u32,
            ));
            start += n;
        }
        self.chunks = chunks;
        self.count = count;
        self.external = true;
        self.forget_scene_particles();
        self.bind();
        Ok(())
    }

    fn chunk(&self, buffer: wgpu::Buffer, offset: u64, count: u32, first: u32) -> Chunk {
        let params = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("octoproxy chunk params"),
            size: core::mem::size_of::<ChunkParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let values = ChunkParams {
            count,
            first,
            ..Default::default()
        };
        self.queue
            .write_buffer(&params, 0, bytemuck::bytes_of(&values));
        // New buffers start zeroed: no hints.
        let hints = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("octoproxy leaf hints"),
            size: (count as u64 * HINT_BYTES).max(HINT_BYTES),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let storage_buffer = |label, size: u64, usage: wgpu::BufferUsages| {
            self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE | usage,
                mapped_at_creation: false,
            })
        };
        let queued = storage_buffer(
            "octoproxy split queue",
            (count as u64 * 4).max(4),
            wgpu::BufferUsages::empty(),
        );
        // Zeroed: an empty queue, and no workgroups.
        let queue = storage_buffer(
            "octoproxy split queue length",
            16,
            wgpu::BufferUsages::empty(),
        );
        let args = storage_buffer("octoproxy march args", 16, wgpu::BufferUsages::INDIRECT);
        let args_group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("octoproxy march args"),
            layout: &self.kernel.args_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: self.kernel.run.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: queue.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 8,
                    resource: args.as_entire_binding(),
                },
            ],
        });
        Chunk {
            buffer,
            offset,
            count,
            params,
            hints,
            queued,
            queue,
            args,
            args_group,
            bind_group: None,
            scene: None,
        }
    }

    /// New particles: no scene sides, hits or events, and the scene steps count from 0.
    fn forget_scene_particles(&mut self) {
        for chunk in &mut self.chunks {
            chunk.scene = None;
        }
        self.scene.reset_particles(&self.queue);
    }

    /// Forgets every particle's leaf hint (a hint belongs to the proxy that made it).
    fn clear_hints(&self) {
        if self.chunks.is_empty() {
            return;
        }
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("octoproxy hint reset"),
            });
        for chunk in &self.chunks {
            encoder.clear_buffer(&chunk.hints, 0, None);
        }
        self.queue.submit([encoder.finish()]);
    }

    /// (Re)builds every chunk's bind group once both a proxy and particles are present.
    fn bind(&mut self) {
        let Some(proxy) = &self.proxy else { return };
        for chunk in &mut self.chunks {
            let size = NonZeroU64::new(chunk.count as u64 * PARTICLE_BYTES);
            chunk.bind_group = Some(self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("octoproxy chunk"),
                layout: &self.kernel.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: proxy.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: &chunk.buffer,
                            offset: chunk.offset,
                            size,
                        }),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: self.kernel.params.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: self.kernel.run.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: chunk.params.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: chunk.hints.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 6,
                        resource: chunk.queued.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 7,
                        resource: chunk.queue.as_entire_binding(),
                    },
                ],
            }));
        }
    }

    /// Workgroups for `count` particles at [`WORKGROUP_SIZE`] (the scene kernel's and the
    /// particle-particle pass's): `(x, y)`, folded into rows of at most `fold_width`.
    pub fn dispatch_size(&self, count: u32) -> (u32, u32) {
        self.fold(count.div_ceil(WORKGROUP_SIZE))
    }

    /// `groups` workgroups as `(x, y)`, folded into rows of at most `fold_width`.
    pub(crate) fn fold(&self, groups: u32) -> (u32, u32) {
        if groups <= self.fold_width {
            (groups, 1)
        } else {
            (self.fold_width, groups.div_ceil(self.fold_width))
        }
    }

    pub(crate) fn check_health(&self) -> Result<(), WgpuError> {
        if let Some(message) = lock(&self.lost).clone() {
            return Err(WgpuError::DeviceLost(message));
        }
        if let Some(message) = lock(&self.uncaptured).take() {
            return Err(WgpuError::Gpu(message));
        }
        Ok(())
    }

    /// Copies `size` bytes at `offset` of each buffer back to the host, in one submission and
    /// one wait. Sizes must be multiples of 4.
    pub(crate) fn read_back(
        &self,
        parts: &[(&wgpu::Buffer, u64, u64)],
    ) -> Result<Vec<Vec<u8>>, WgpuError> {
        let scope = ErrorScope::push(&self.device);
        let mut encoder = self.device.create_command_encoder(&Default::default());
        let mut staging = Vec::with_capacity(parts.len());
        for &(source, offset, size) in parts {
            let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("octoproxy read-back"),
                size: size.max(4),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            if size > 0 {
                encoder.copy_buffer_to_buffer(source, offset, &buffer, 0, size);
            }
            staging.push(buffer);
        }
        self.queue.submit([encoder.finish()]);
        let (tx, rx) = mpsc::channel();
        for (i, buffer) in staging.iter().enumerate() {
            let tx = tx.clone();
            buffer.map_async(wgpu::MapMode::Read, .., move |result| {
                let _ = tx.send((i, result));
            });
        }
        drop(tx);
        self.wait()?;
        scope.pop().map_err(WgpuError::Gpu)?;
        let mut mapped = 0;
        for (i, result) in rx.iter() {
            result.map_err(|e| WgpuError::Gpu(format!("read-back of part {i}: {e}")))?;
            mapped += 1;
        }
        if mapped != staging.len() {
            return Err(WgpuError::Gpu("read-back did not complete".into()));
        }
        let mut out = Vec::with_capacity(parts.len());
        for (&(_, _, size), buffer) in parts.iter().zip(&staging) {
            let view = buffer
                .get_mapped_range(..)
                .map_err(|e| WgpuError::Gpu(e.to_string()))?;
            out.push(view[..size as usize].to_vec());
            drop(view);
            buffer.unmap();
        }
        Ok(out)
    }

    /// Waits until all submitted work is done.
    pub fn wait(&self) -> Result<(), WgpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| WgpuError::Gpu(e.to_string()))?;
        self.check_health()
    }

    /// The uploaded proxy and the radius it was baked for, or `None` without a proxy.
    pub(crate) fn proxy(&self) -> Option<(&wgpu::Buffer, f32)> {
        self.proxy.as_ref().map(|p| (p, self.proxy_radius))
    }

    /// Writes the plain kernel's step parameters and run settings for the steps recorded
    /// next ([`WgpuBackend::record_step`]).
    pub(crate) fn write_step_params(&self, params: &StepParams) {
        self.queue
            .write_buffer(&self.kernel.params, 0, bytemuck::bytes_of(params));
        let run = RunParams {
            use_lut: self.use_lut as u32,
            workgroup_size: self.kernel.workgroup_size,
            fold_width: self.fold_width,
            ..Default::default()
        };
        self.queue
            .write_buffer(&self.kernel.run, 0, bytemuck::bytes_of(&run));
    }

    /// Records one plain step of every chunk (one dispatch each) in `pass`; with `floor`,
    /// the integration alone ([`WgpuBackend::integrate_only`]).
    pub(crate) fn record_step(&self, pass: &mut wgpu::ComputePass<'_>, floor: bool) {
        let k = &self.kernel.pipelines;
        let split = self.kernel.split && !floor;
        if !split {
            pass.set_pipeline(if floor { &k.integrate } else { &k.step });
        }
        for chunk in &self.chunks {
            let Some(group) = &chunk.bind_group else {
                continue;
            };
            let (x, y) = self.fold(chunk.count.div_ceil(self.kernel.workgroup_size));
            if !split {
                pass.set_bind_group(0, group, &[]);
                pass.dispatch_workgroups(x, y, 1);
                continue;
            }
            pass.set_pipeline(&k.settle);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(x, y, 1);
            pass.set_pipeline(&k.args);
            pass.set_bind_group(0, &chunk.args_group, &[]);
            pass.dispatch_workgroups(1, 1, 1);
            pass.set_pipeline(&k.march);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups_indirect(&chunk.args, 0);
        }
    }

    /// The floor: steps the particles `steps` times with integration only (the same
    /// semi-implicit Euler, no proxy, no collision). Benchmarks measure the step against it.
    pub fn integrate_only(&mut self, params: &StepParams, steps: u32) -> Result<(), WgpuError> {
        self.dispatch(params, steps, true)
    }

    fn dispatch(&mut self, params: &StepParams, steps: u32, floor: bool) -> Result<(), WgpuError> {
        params.validate()?;
        self.check_health()?;
        if self.proxy.is_none() {
            return Err(WgpuError::NoProxy);
        }
        if !floor {
            octoproxy_core::check_radius(self.proxy_radius, params.radius)?;
        }
        if self.count == 0 || steps == 0 {
            return Ok(());
        }
        let scope = ErrorScope::push(&self.device);
        self.write_step_params(params);
        let mut left = steps;
        while left > 0 {
            let batch = left.min(STEPS_PER_SUBMIT);
            left -= batch;
            let mut encoder = self.device.create_command_encoder(&Default::default());
            for _ in 0..batch {
                // One pass per step: each step reads what the last one wrote.
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("octoproxy step"),
                    timestamp_writes: None,
                });
                self.record_step(&mut pass, floor);
            }
            self.queue.submit([encoder.finish()]);
        }
        scope.pop().map_err(WgpuError::Gpu)?;
        self.check_health()
    }
}

/// Validation, out-of-memory and internal error scopes around a piece of work, popped
/// together. Fields drop in declaration order, so an early return pops them innermost
/// first too, as wgpu requires.
pub(crate) struct ErrorScope {
    internal: wgpu::ErrorScopeGuard,
    memory: wgpu::ErrorScopeGuard,
    validation: wgpu::ErrorScopeGuard,
}

impl ErrorScope {
    pub(crate) fn push(device: &wgpu::Device) -> Self {
        let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
        Self {
            internal,
            memory,
            validation,
        }
    }

    pub(crate) fn pop(self) -> Result<(), String> {
        // Innermost first.
        let internal = pollster::block_on(self.internal.pop());
        let memory = pollster::block_on(self.memory.pop());
        let validation = pollster::block_on(self.validation.pop());
        match internal.or(memory).or(validation) {
            Some(e) => Err(e.to_string()),
            None => Ok(()),
        }
    }
}

impl Backend for WgpuBackend {
    type Error = WgpuError;

    fn name(&self) -> &str {
        "wgpu"
    }

    fn upload_proxy(&mut self, words: &[u32]) -> Result<(), WgpuError> {
        // The very bytes the CPU validated, uploaded as they are.
        let radius = ProxyView::new(words)?.header().radius;
        self.check_health()?;
        let bytes: &[u8] = bytemuck::cast_slice(words);
        let limits = self.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes.len() as u64 > limit {
            return Err(WgpuError::TooLarge {
                what: "the proxy",
                needed: bytes.len() as u64,
                limit,
            });
        }
        let scope = ErrorScope::push(&self.device);
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("octoproxy proxy"),
            size: bytes.len() as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        self.queue.write_buffer(&buffer, 0, bytes);
        self.clear_hints();
        scope.pop().map_err(WgpuError::Gpu)?;
        self.proxy = Some(buffer);
        self.proxy_radius = radius;
        self.bind();
        Ok(())
    }

    fn upload_particles(&mut self, particles: &[Particle]) -> Result<(), WgpuError> {
        self.check_health()?;
        let bytes: &[u8] = bytemuck::cast_slice(particles);
        let scope = ErrorScope::push(&self.device);
        if self.external {
            if let Some(chunk) = self.chunks.first() {
                if !chunk.buffer.usage().contains(wgpu::BufferUsages::COPY_DST) {
                    return Err(WgpuError::BadBuffer(
                        "uploading into it needs COPY_DST usage".into(),
                    ));
                }
            }
            if particles.len() != self.count {
                return Err(WgpuError::LengthMismatch {
                    expected: self.count,
                    got: particles.len(),
                });
            }
            for chunk in &self.chunks {
                let start = (chunk.offset - self.chunks[0].offset) as usize;
                let end = start + chunk.count as usize * PARTICLE_BYTES as usize;
                self.queue
                    .write_buffer(&chunk.buffer, chunk.offset, &bytes[start..end]);
            }
        } else {
            let cap = self.chunk_capacity() as usize;
            // Reuse the buffers when the chunk sizes are exactly those this upload needs.
            let same_layout = self.chunks.len() == particles.len().div_ceil(cap)
                && self
                    .chunks
                    .iter()
                    .zip(particles.chunks(cap))
                    .all(|(c, part)| c.count as usize == part.len());
            if !same_layout {
                let mut chunks = Vec::new();
                for (k, part) in particles.chunks(cap).enumerate() {
                    let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some("octoproxy particles"),
                        size: part.len() as u64 * PARTICLE_BYTES,
                        usage: wgpu::BufferUsages::STORAGE
                            | wgpu::BufferUsages::COPY_DST
                            | wgpu::BufferUsages::COPY_SRC,
                        mapped_at_creation: false,
                    });
                    chunks.push(self.chunk(buffer, 0, part.len() as u32, (k * cap) as u32));
                }
                self.chunks = chunks;
                self.count = particles.len();
                self.bind();
            }
            for (chunk, part) in self.chunks.iter().zip(particles.chunks(cap)) {
                self.queue
                    .write_buffer(&chunk.buffer, 0, bytemuck::cast_slice(part));
            }
        }
        // Not needed for correctness (a step checks that a particle is inside its hinted
        // leaf), but new particles start with no history.
        self.clear_hints();
        self.forget_scene_particles();
        scope.pop().map_err(WgpuError::Gpu)
    }

    fn download_particles(&mut self, out: &mut [Particle]) -> Result<(), WgpuError> {
        if out.len() != self.count {
            return Err(WgpuError::LengthMismatch {
                expected: self.count,
                got: out.len(),
            });
        }
        self.check_health()?;
        if self.count == 0 {
            return Ok(());
        }
        if !self.chunks[0]
            .buffer
            .usage()
            .contains(wgpu::BufferUsages::COPY_SRC)
        {
            return Err(WgpuError::BadBuffer(
                "reading it back needs COPY_SRC usage".into(),
            ));
        }
        let parts: Vec<_> = self
            .chunks
            .iter()
            .map(|c| (&c.buffer, c.offset, c.count as u64 * PARTICLE_BYTES))
            .collect();
        let mut start = 0;
        for (chunk, bytes) in self.chunks.iter().zip(self.read_back(&parts)?) {
            let n = chunk.count as usize;
            bytemuck::cast_slice_mut::<Particle, u8>(&mut out[start..start + n])
                .copy_from_slice(&bytes);
            start += n;
        }
        Ok(())
    }

    fn particle_count(&self) -> usize {
        self.count
    }

    fn step(&mut self, params: &StepParams, steps: u32) -> Result<(), WgpuError> {
        self.dispatch(params, steps, false)
    }

    fn finish(&mut self) -> Result<(), WgpuError> {
        self.wait()
    }

    fn step_pairs(
        &mut self,
        params: &StepParams,
        pairs: &octoproxy_core::PairParams,
        steps: u32,
    ) -> Result<(), WgpuError> {
        self.step_pairs_gpu(params, pairs, steps)
    }

    fn step_scene_pairs(
        &mut self,
        substeps: &[octoproxy_core::SceneSubstep<'_>],
        params: &StepParams,
        pairs: &octoproxy_core::PairParams,
        hits: bool,
    ) -> Result<(), WgpuError> {
        self.step_scene_pairs_gpu(substeps, params, pairs, hits)
    }

    fn pair_substeps_now(
        &mut self,
        params: &StepParams,
        pairs: &octoproxy_core::PairParams,
    ) -> Result<u32, WgpuError> {
        self.pair_substeps_gpu(params, pairs)
    }

    fn take_pair_report(&mut self) -> Result<octoproxy_core::PairReport, WgpuError> {
        self.take_pair_report_gpu()
    }

    fn upload_scene_proxies(&mut self, key: u64, proxies: &[&[u32]]) -> Result<(), WgpuError> {
        self.upload_scene_proxies_gpu(key, proxies)
    }

    fn scene_proxies_key(&self) -> Option<u64> {
        self.scene_proxies_key_gpu()
    }

    fn step_scene(
        &mut self,
        instances: &[Instance],
        broad: &[BroadNode],
        params: &StepParams,
        hits: bool,
    ) -> Result<(), WgpuError> {
        self.step_scene_gpu(instances, broad, params, hits)
    }

    fn take_scene_report(&mut self) -> Result<SceneStepReport, WgpuError> {
        self.take_scene_report_gpu()
    }

    fn download_hits(&mut self, out: &mut [Hit]) -> Result<(), WgpuError> {
        self.download_hits_gpu(out)
    }

    fn set_event_capacity(&mut self, capacity: usize) -> Result<(), WgpuError> {
        self.set_event_capacity_gpu(capacity)
    }

    fn take_events(&mut self, out: &mut [HitEvent]) -> Result<EventCount, WgpuError> {
        self.take_events_gpu(out)
    }

    fn download_scene_sides(&mut self, out: &mut [SceneSides]) -> Result<(), WgpuError> {
        self.download_scene_sides_gpu(out)
    }

    fn upload_scene_sides(&mut self, sides: &[SceneSides]) -> Result<(), WgpuError> {
        self.upload_scene_sides_gpu(sides)
    }
}
