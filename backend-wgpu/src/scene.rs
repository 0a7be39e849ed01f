//! The scene step on the GPU: the scene kernel (`shader::SCENE_FILES`), its buffers, and the
//! read-backs of hits, events, sides and reports ([`Backend`]'s scene methods).
//!
//! **Buffers.** The scene's proxies lie one after another in one storage buffer, uploaded
//! once ([`Backend::upload_scene_proxies`]). Each step writes the scene's tables into one word
//! buffer, as core's bytes: every proxy's word offset, the instances, the broad phase
//! ([`SceneParams`] says where each starts). Each chunk of particles gets, at its first scene
//! step, its particles' [`SceneHint`]s and [`SceneSlots`] (and [`Hit`]s, when asked for). One
//! output buffer holds the report's counts and the event buffer.

use std::num::NonZeroU64;

use bytemuck::{Pod, Zeroable};
use octoproxy_core::scene::NO_INSTANCE;
use octoproxy_core::{
    pair_substep_range, BroadNode, EventCount, Hit, HitEvent, Instance, OwnedProxy, PairParams,
    ProxyView, SceneHint, SceneSides, SceneSlots, SceneStepReport, SceneSubstep, SceneView,
    StepParams,
};

use crate::backend::{storage, uniform, ErrorScope, WgpuBackend, WgpuError, PARTICLE_BYTES};
use crate::shader;

/// Storage buffers the scene kernel binds (the device must allow as many in one stage).
pub const SCENE_STORAGE_BUFFERS: u32 = 7;

/// Where the scene's tables are in the scene buffer, and what the step records: WGSL's
/// `SceneParams`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct SceneParams {
    /// Word where the instances start (after one word offset per proxy).
    pub instances_at: u32,
    /// Word where the broad phase starts.
    pub nodes_at: u32,
    /// Nodes of the broad phase.
    pub node_count: u32,
    /// The instance of a one-proxy static scene at the identity, or `u32::MAX`.
    pub plain: u32,
    /// 1 to write each particle's hit record.
    pub hits: u32,
    /// Events the output buffer holds (0: none are recorded).
    pub event_capacity: u32,
    /// The scene step's number since the particles were uploaded (for events).
    pub step: u32,
    /// 1 to enter through the lookup table.
    pub use_lut: u32,
    /// The substep of a step with the particle-particle pass (0 otherwise): hits and events
    /// are of the whole step, and a hit record is kept from an earlier substep.
    pub substep: u32,
    /// The substeps of the step (1 without the pass).
    pub substeps: u32,
    /// Padding.
    pub _pad0: u32,
    /// Padding.
    pub _pad1: u32,
}

/// Words of the output buffer before its events: WGSL's `SceneOut` header.
pub const OUT_HEADER_WORDS: u64 = 8;

const SIDE_HINT_BYTES: u64 = core::mem::size_of::<SceneHint>() as u64;
const SIDE_SLOT_BYTES: u64 = core::mem::size_of::<SceneSlots>() as u64;
const HIT_BYTES: u64 = core::mem::size_of::<Hit>() as u64;
const EVENT_BYTES: u64 = core::mem::size_of::<HitEvent>() as u64;

/// The scene kernel's pipeline and layout, built at the first scene step.
#[derive(Debug)]
pub(crate) struct SceneKernel {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    /// `scene_support_kernel`: each grain's support for the particle-particle pass.
    support: wgpu::ComputePipeline,
    params: wgpu::Buffer,
}

/// A chunk's particles' scene state.
#[derive(Debug)]
pub(crate) struct ChunkScene {
    hints: wgpu::Buffer,
    slots: wgpu::Buffer,
    hits: Option<wgpu::Buffer>,
    bind_group: Option<wgpu::BindGroup>,
    /// The support kernel's bind group, with the pass's buffer of supports it writes.
    support_group: Option<(wgpu::Buffer, wgpu::BindGroup)>,
}

/// The backend's scene state.
#[derive(Debug, Default)]
pub(crate) struct SceneGpu {
    kernel: Option<SceneKernel>,
    /// The proxies: on the GPU, their word offsets there, on the host (for validation), and
    /// the caller's key.
    proxies: Option<wgpu::Buffer>,
    offsets: Vec<u32>,
    host: Vec<OwnedProxy>,
    key: Option<u64>,
    tables: Option<wgpu::Buffer>,
    out: Option<wgpu::Buffer>,
    event_capacity: usize,
    /// A one-hit buffer bound where a chunk has no hit records.
    no_hits: Option<wgpu::Buffer>,
    /// Scene steps since the particles were uploaded.
    pub(crate) steps: u32,
    /// Report counts read back before the output buffer was replaced.
    pending: SceneStepReport,
}

impl SceneGpu {
    /// Forgets the particles' scene state (new particles): the step count, and the events
    /// held.
    pub(crate) fn reset_particles(&mut self, queue: &wgpu::Queue) {
        self.steps = 0;
        if let Some(out) = &self.out {
            // Words 4 to 6: events stored, lost (low, high).
            queue.write_buffer(out, 16, &[0u8; 12]);
        }
    }
}

impl WgpuBackend {
    fn scene_kernel(&mut self) -> Result<&SceneKernel, WgpuError> {
        if self.scene.kernel.is_none() {
            let limit = self.device.limits().max_storage_buffers_per_shader_stage;
            if limit < SCENE_STORAGE_BUFFERS {
                return Err(WgpuError::TooLarge {
                    what: "the scene kernel's storage buffers",
                    needed: SCENE_STORAGE_BUFFERS as u64,
                    limit: limit as u64,
                });
            }
            let scope = ErrorScope::push(&self.device);
            let module = self
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("octoproxy scene step"),
                    source: wgpu::ShaderSource::Wgsl(shader::scene_source().into()),
                });
            let layout = self
                .device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("octoproxy scene"),
                    entries: &[
                        storage(0, true),
                        storage(1, false),
                        uniform(2, core::mem::size_of::<StepParams>() as u64),
                        uniform(3, core::mem::size_of::<crate::ChunkParams>() as u64),
                        storage(4, false),
                        storage(5, true),
                        uniform(6, core::mem::size_of::<SceneParams>() as u64),
                        storage(7, false),
                        storage(8, false),
                        storage(9, false),
                    ],
                });
            let pipeline_layout =
                self.device
                    .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                        label: Some("octoproxy scene"),
                        bind_group_layouts: &[Some(&layout)],
                        immediate_size: 0,
                    });
            let pipeline = self
                .device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some("scene_kernel"),
                    layout: Some(&pipeline_layout),
                    module: &module,
                    entry_point: Some("scene_kernel"),
                    compilation_options: Default::default(),
                    cache: None,
                });
            let support = self
                .device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some("scene_support_kernel"),
                    layout: None,
                    module: &module,
                    entry_point: Some("scene_support_kernel"),
                    compilation_options: Default::default(),
                    cache: None,
                });
            let params = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("octoproxy scene params"),
                size: core::mem::size_of::<SceneParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            scope.pop().map_err(WgpuError::Shader)?;
            self.scene.kernel = Some(SceneKernel {
                layout,
                pipeline,
                support,
                params,
            });
        }
        Ok(self.scene.kernel.as_ref().expect("built above"))
    }

    /// Drops every chunk's scene bind group: a buffer they bind was replaced.
    fn unbind_scene(&mut self) {
        for chunk in &mut self.chunks {
            if let Some(scene) = &mut chunk.scene {
                scene.bind_group = None;
                scene.support_group = None;
            }
        }
    }

    /// A buffer of `bytes` with `usage`, holding `data` (zeroed past it).
    fn buffer_with(
        &self,
        label: &str,
        bytes: u64,
        usage: wgpu::BufferUsages,
        data: &[u8],
    ) -> wgpu::Buffer {
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(4).next_multiple_of(4),
            usage: usage | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        if !data.is_empty() {
            self.queue.write_buffer(&buffer, 0, data);
        }
        buffer
    }

    /// Makes each chunk's scene state (empty sides), and its hit records when `hits`.
    fn ensure_chunk_scenes(&mut self, hits: bool) {
        let storage = wgpu::BufferUsages::STORAGE;
        for k in 0..self.chunks.len() {
            let n = self.chunks[k].count as usize;
            if self.chunks[k].scene.is_none() {
                let (h, s) = SceneSides::EMPTY.split();
                let hints = self.buffer_with(
                    "octoproxy scene hints",
                    n as u64 * SIDE_HINT_BYTES,
                    storage,
                    bytemuck::cast_slice(&vec![h; n]),
                );
                let slots = self.buffer_with(
                    "octoproxy scene slots",
                    n as u64 * SIDE_SLOT_BYTES,
                    storage,
                    bytemuck::cast_slice(&vec![s; n]),
                );
                self.chunks[k].scene = Some(ChunkScene {
                    hints,
                    slots,
                    hits: None,
                    bind_group: None,
                    support_group: None,
                });
            }
            let needs_hits = hits
                && self.chunks[k]
                    .scene
                    .as_ref()
                    .is_some_and(|s| s.hits.is_none());
            if needs_hits {
                let buffer = self.buffer_with(
                    "octoproxy hits",
                    n as u64 * HIT_BYTES,
                    storage,
                    bytemuck::cast_slice(&vec![Hit::NONE; n]),
                );
                let scene = self.chunks[k].scene.as_mut().expect("made above");
                scene.hits = Some(buffer);
                scene.bind_group = None;
            }
        }
    }

    /// The output buffer for `capacity` events (room for one at least: a binding's array
    /// has an element), its counts zero.
    fn make_out(&self, capacity: usize) -> wgpu::Buffer {
        self.buffer_with(
            "octoproxy scene output",
            OUT_HEADER_WORDS * 4 + capacity.max(1) as u64 * EVENT_BYTES,
            wgpu::BufferUsages::STORAGE,
            &[0u8; OUT_HEADER_WORDS as usize * 4],
        )
    }

    /// Builds the bind groups of the chunks that have none.
    fn bind_scene(&mut self) -> Result<(), WgpuError> {
        let Some(kernel) = &self.scene.kernel else {
            return Ok(());
        };
        let (Some(proxies), Some(tables), Some(out), Some(no_hits)) = (
            &self.scene.proxies,
            &self.scene.tables,
            &self.scene.out,
            &self.scene.no_hits,
        ) else {
            return Ok(());
        };
        for chunk in &mut self.chunks {
            let Some(scene) = &mut chunk.scene else {
                continue;
            };
            if scene.bind_group.is_some() {
                continue;
            }
            let particles = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &chunk.buffer,
                offset: chunk.offset,
                size: NonZeroU64::new(chunk.count as u64 * PARTICLE_BYTES),
            });
            let entry = |binding, resource| wgpu::BindGroupEntry { binding, resource };
            scene.bind_group = Some(self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("octoproxy scene chunk"),
                layout: &kernel.layout,
                entries: &[
                    entry(0, proxies.as_entire_binding()),
                    entry(1, particles),
                    entry(2, self.kernel.params.as_entire_binding()),
                    entry(3, chunk.params.as_entire_binding()),
                    entry(4, scene.hints.as_entire_binding()),
                    entry(5, tables.as_entire_binding()),
                    entry(6, kernel.params.as_entire_binding()),
                    entry(7, out.as_entire_binding()),
                    entry(8, scene.slots.as_entire_binding()),
                    entry(
                        9,
                        scene.hits.as_ref().unwrap_or(no_hits).as_entire_binding(),
                    ),
                ],
            }));
        }
        Ok(())
    }

    pub(crate) fn upload_scene_proxies_gpu(
        &mut self,
        key: u64,
        proxies: &[&[u32]],
    ) -> Result<(), WgpuError> {
        self.check_health()?;
        let mut host = Vec::with_capacity(proxies.len());
        let mut offsets = Vec::with_capacity(proxies.len());
        let mut words: Vec<u32> = Vec::new();
        for (index, p) in proxies.iter().enumerate() {
            let owned = OwnedProxy::new(p.to_vec())
                .map_err(|source| WgpuError::SceneProxy { index, source })?;
            offsets.push(words.len() as u32);
            words.extend_from_slice(p);
            host.push(owned);
        }
        let bytes = words.len() as u64 * 4;
        let limits = self.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes > limit || words.len() > u32::MAX as usize {
            return Err(WgpuError::TooLarge {
                what: "the scene's proxies",
                needed: bytes,
                limit,
            });
        }
        let scope = ErrorScope::push(&self.device);
        let buffer = self.buffer_with(
            "octoproxy scene proxies",
            bytes,
            wgpu::BufferUsages::STORAGE,
            bytemuck::cast_slice(&words),
        );
        scope.pop().map_err(WgpuError::Gpu)?;
        self.scene.proxies = Some(buffer);
        self.scene.offsets = offsets;
        self.scene.host = host;
        self.scene.key = Some(key);
        self.unbind_scene();
        // Hints belong to the proxies that made them: keep each particle's sides, forget its
        // hint.
        if self.chunks.iter().any(|c| c.scene.is_some()) {
            let mut sides = vec![SceneSides::EMPTY; self.count];
            self.download_scene_sides_gpu(&mut sides)?;
            for s in &mut sides {
                s.hint = Default::default();
                s.hint_instance = NO_INSTANCE;
            }
            self.upload_scene_sides_gpu(&sides)?;
        }
        Ok(())
    }

    pub(crate) fn scene_proxies_key_gpu(&self) -> Option<u64> {
        self.scene.key
    }

    /// The scene's tables for one step (or substep `substep` of `substeps`), as core's bytes
    /// (proxy offsets, instances, nodes), and the kernel's [`SceneParams`] for them; the scene
    /// validated first.
    fn scene_tables(
        &self,
        instances: &[Instance],
        broad: &[BroadNode],
        params: &StepParams,
        hits: bool,
        substep: u32,
        substeps: u32,
    ) -> Result<(Vec<u32>, SceneParams), WgpuError> {
        let views: Vec<ProxyView<'_>> = self.scene.host.iter().map(|p| p.view()).collect();
        let view = SceneView::new(&views, instances, broad)?;
        view.check_radius(params.radius)?;
        let plain = view.plain_proxy().map_or(NO_INSTANCE, |(c, _)| c);
        let mut words: Vec<u32> = self.scene.offsets.clone();
        let instances_at = words.len() as u32;
        words.extend_from_slice(bytemuck::cast_slice(instances));
        let nodes_at = words.len() as u32;
        words.extend_from_slice(bytemuck::cast_slice(broad));
        let scene_params = SceneParams {
            instances_at,
            nodes_at,
            node_count: broad.len() as u32,
            plain,
            hits: hits as u32,
            event_capacity: self.scene.event_capacity as u32,
            step: self.scene.steps,
            use_lut: self.use_lut as u32,
            substep,
            substeps,
            ..Default::default()
        };
        Ok((words, scene_params))
    }

    /// The scene kernel, every chunk's scene state and bind group, the output buffer, and a
    /// tables buffer of `words` words at least.
    fn prepare_scene(&mut self, hits: bool, words: usize) -> Result<(), WgpuError> {
        self.scene_kernel()?;
        self.ensure_chunk_scenes(hits);
        let bytes = words as u64 * 4;
        if self.scene.tables.as_ref().is_none_or(|t| t.size() < bytes) {
            let size = bytes.next_power_of_two().max(256);
            self.scene.tables = Some(self.buffer_with(
                "octoproxy scene tables",
                size,
                wgpu::BufferUsages::STORAGE,
                &[],
            ));
            self.unbind_scene();
        }
        if self.scene.out.is_none() {
            self.scene.out = Some(self.make_out(self.scene.event_capacity));
            self.unbind_scene();
        }
        if self.scene.no_hits.is_none() {
            self.scene.no_hits = Some(self.buffer_with(
                "octoproxy no hits",
                HIT_BYTES,
                wgpu::BufferUsages::STORAGE,
                &[],
            ));
        }
        self.bind_scene()
    }

    /// Writes one step's tables and [`SceneParams`].
    fn write_scene_tables(&self, words: &[u32], scene_params: &SceneParams) {
        let tables = self.scene.tables.as_ref().expect("made first");
        self.queue
            .write_buffer(tables, 0, bytemuck::cast_slice(words));
        let kernel = self.scene.kernel.as_ref().expect("built first");
        self.queue
            .write_buffer(&kernel.params, 0, bytemuck::bytes_of(scene_params));
    }

    /// Records one scene step of every chunk (one dispatch each) in `pass`.
    fn record_scene_step(&self, pass: &mut wgpu::ComputePass<'_>) {
        let kernel = self.scene.kernel.as_ref().expect("built first");
        pass.set_pipeline(&kernel.pipeline);
        for chunk in &self.chunks {
            let Some(group) = chunk.scene.as_ref().and_then(|s| s.bind_group.as_ref()) else {
                continue;
            };
            let (x, y) = self.dispatch_size(chunk.count);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
    }

    pub(crate) fn step_scene_gpu(
        &mut self,
        instances: &[Instance],
        broad: &[BroadNode],
        params: &StepParams,
        hits: bool,
    ) -> Result<(), WgpuError> {
        params.validate()?;
        self.check_health()?;
        let (words, scene_params) = self.scene_tables(instances, broad, params, hits, 0, 1)?;
        if self.count == 0 {
            self.scene.steps = self.scene.steps.wrapping_add(1);
            return Ok(());
        }
        let scope = ErrorScope::push(&self.device);
        self.prepare_scene(hits, words.len())?;
        self.write_scene_tables(&words, &scene_params);
        self.queue
            .write_buffer(&self.kernel.params, 0, bytemuck::bytes_of(params));
        let mut encoder = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("octoproxy scene step"),
                timestamp_writes: None,
            });
            self.record_scene_step(&mut pass);
        }
        self.queue.submit([encoder.finish()]);
        scope.pop().map_err(WgpuError::Gpu)?;
        self.scene.steps = self.scene.steps.wrapping_add(1);
        self.check_health()
    }

    /// One scene step with the particle-particle pass (`Backend::step_scene_pairs`): each
    /// substep's tables written, then the pass with the supports from the scene
    /// (`scene_support_kernel`) and the scene step as its march, one submission a substep.
    pub(crate) fn step_scene_pairs_gpu(
        &mut self,
        substeps: &[SceneSubstep<'_>],
        params: &StepParams,
        pairs: &PairParams,
        hits: bool,
    ) -> Result<(), WgpuError> {
        self.check_pass(params, pairs)?;
        let n = self.count;
        let (min, max) = pair_substep_range(params, pairs);
        if !(min as usize..=max as usize).contains(&substeps.len()) {
            return Err(WgpuError::Substeps {
                min,
                max,
                got: substeps.len(),
            });
        }
        let count = substeps.len() as u32;
        let march = StepParams {
            gravity: [0.0; 3],
            dt: params.dt / count as f32,
            ..*params
        };
        march.validate()?;
        let (_, iterations) = self.pair_plan_gpu(params, pairs)?;
        let tables = substeps
            .iter()
            .enumerate()
            .map(|(k, sub)| {
                self.scene_tables(sub.instances, sub.broad, params, hits, k as u32, count)
            })
            .collect::<Result<Vec<_>, _>>()?;
        if n > 0 {
            let scope = ErrorScope::push(&self.device);
            let words = tables.iter().map(|(w, _)| w.len()).max().unwrap_or(0);
            self.prepare_scene(hits, words)?;
            self.pair_kernel()?;
            self.pair_buffers(n)?;
            self.pair_chunk_groups();
            self.bind_scene_supports();
            self.write_pair_constants(params, pairs, &march);
            let kernel = self.scene.kernel.as_ref().expect("built above");
            let groups: Vec<&wgpu::BindGroup> = self
                .chunks
                .iter()
                .filter_map(|c| c.scene.as_ref()?.support_group.as_ref().map(|(_, g)| g))
                .collect();
            let mut last_words: Option<&[u32]> = None;
            for (words, scene_params) in &tables {
                // A substep whose instances and broad phase are the last one's (a static
                // scene) keeps the tables the last submission wrote; its constants change.
                if last_words == Some(words.as_slice()) {
                    let kernel = self.scene.kernel.as_ref().expect("built above");
                    self.queue
                        .write_buffer(&kernel.params, 0, bytemuck::bytes_of(scene_params));
                } else {
                    self.write_scene_tables(words, scene_params);
                }
                last_words = Some(words);
                let mut encoder = self.device.create_command_encoder(&Default::default());
                {
                    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                        label: Some("octoproxy scene pair substep"),
                        timestamp_writes: None,
                    });
                    self.encode_pair_substep(
                        &mut pass,
                        iterations,
                        Some((&kernel.support, &groups)),
                        |pass| self.record_scene_step(pass),
                    );
                }
                self.queue.submit([encoder.finish()]);
            }
            scope.pop().map_err(WgpuError::Gpu)?;
        }
        self.pair_steps_done(count, iterations);
        self.scene.steps = self.scene.steps.wrapping_add(1);
        self.check_health()
    }

    /// Each chunk's bind group for `scene_support_kernel`, made when missing or when the
    /// pass's supports buffer changed.
    fn bind_scene_supports(&mut self) {
        let (Some(kernel), Some(proxies), Some(tables)) =
            (&self.scene.kernel, &self.scene.proxies, &self.scene.tables)
        else {
            return;
        };
        let Some(given) = self.pair_given_supports() else {
            return;
        };
        for chunk in &mut self.chunks {
            let Some(scene) = &mut chunk.scene else {
                continue;
            };
            if scene
                .support_group
                .as_ref()
                .is_some_and(|(buffer, _)| *buffer == given)
            {
                continue;
            }
            let particles = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &chunk.buffer,
                offset: chunk.offset,
                size: NonZeroU64::new(chunk.count as u64 * PARTICLE_BYTES),
            });
            let entry = |binding, resource| wgpu::BindGroupEntry { binding, resource };
            let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("octoproxy scene supports"),
                layout: &kernel.support.get_bind_group_layout(0),
                entries: &[
                    entry(0, proxies.as_entire_binding()),
                    entry(1, particles),
                    entry(3, chunk.params.as_entire_binding()),
                    entry(4, scene.hints.as_entire_binding()),
                    entry(5, tables.as_entire_binding()),
                    entry(6, kernel.params.as_entire_binding()),
                    entry(8, scene.slots.as_entire_binding()),
                    entry(10, given.as_entire_binding()),
                ],
            });
            scene.support_group = Some((given.clone(), group));
        }
    }

    /// The output buffer's counts: crushed, sides lost, events stored, events lost.
    fn read_out_header(&self) -> Result<[u64; 4], WgpuError> {
        let Some(out) = &self.scene.out else {
            return Ok([0; 4]);
        };
        let bytes = self.read_back(&[(out, 0, OUT_HEADER_WORDS * 4)])?;
        let w: &[u32] = bytemuck::cast_slice(&bytes[0]);
        let wide = |lo: u32, hi: u32| (hi as u64) << 32 | lo as u64;
        Ok([
            wide(w[0], w[1]),
            wide(w[2], w[3]),
            w[4] as u64,
            wide(w[5], w[6]),
        ])
    }

    pub(crate) fn take_scene_report_gpu(&mut self) -> Result<SceneStepReport, WgpuError> {
        let [crushed, sides_lost, _, _] = self.read_out_header()?;
        if let Some(out) = &self.scene.out {
            self.queue.write_buffer(out, 0, &[0u8; 16]);
        }
        let pending = std::mem::take(&mut self.scene.pending);
        Ok(SceneStepReport {
            crushed: crushed + pending.crushed,
            sides_lost: sides_lost + pending.sides_lost,
        })
    }

    pub(crate) fn download_hits_gpu(&mut self, out: &mut [Hit]) -> Result<(), WgpuError> {
        if out.len() != self.count {
            return Err(WgpuError::LengthMismatch {
                expected: self.count,
                got: out.len(),
            });
        }
        let parts: Vec<_> = self
            .chunks
            .iter()
            .filter_map(|c| {
                c.scene
                    .as_ref()?
                    .hits
                    .as_ref()
                    .map(|h| (h, 0, c.count as u64 * HIT_BYTES))
            })
            .collect();
        if parts.len() != self.chunks.len() {
            // No step asked for hit records yet.
            out.fill(Hit::NONE);
            return Ok(());
        }
        let mut start = 0;
        for (chunk, bytes) in self.chunks.iter().zip(self.read_back(&parts)?) {
            let n = chunk.count as usize;
            bytemuck::cast_slice_mut::<Hit, u8>(&mut out[start..start + n]).copy_from_slice(&bytes);
            start += n;
        }
        Ok(())
    }

    pub(crate) fn set_event_capacity_gpu(&mut self, capacity: usize) -> Result<(), WgpuError> {
        self.check_health()?;
        let limits = self.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let needed = OUT_HEADER_WORDS * 4 + capacity as u64 * EVENT_BYTES;
        if needed > limit || capacity > u32::MAX as usize {
            return Err(WgpuError::TooLarge {
                what: "the event buffer",
                needed,
                limit,
            });
        }
        // The report's counts live in the buffer that is replaced: keep them.
        let [crushed, sides_lost, _, _] = self.read_out_header()?;
        self.scene.pending.crushed += crushed;
        self.scene.pending.sides_lost += sides_lost;
        self.scene.event_capacity = capacity;
        self.scene.out = Some(self.make_out(capacity));
        self.unbind_scene();
        Ok(())
    }

    pub(crate) fn take_events_gpu(
        &mut self,
        out: &mut [HitEvent],
    ) -> Result<EventCount, WgpuError> {
        if out.len() < self.scene.event_capacity {
            return Err(WgpuError::LengthMismatch {
                expected: self.scene.event_capacity,
                got: out.len(),
            });
        }
        let [_, _, stored, lost] = self.read_out_header()?;
        let Some(buffer) = &self.scene.out else {
            return Ok(EventCount::default());
        };
        let stored = (stored as usize).min(self.scene.event_capacity);
        if stored > 0 {
            let bytes =
                self.read_back(&[(buffer, OUT_HEADER_WORDS * 4, stored as u64 * EVENT_BYTES)])?;
            bytemuck::cast_slice_mut::<HitEvent, u8>(&mut out[..stored]).copy_from_slice(&bytes[0]);
        }
        // Words 4 to 6: stored, lost (low, high).
        self.queue.write_buffer(buffer, 16, &[0u8; 12]);
        Ok(EventCount { stored, lost })
    }

    pub(crate) fn download_scene_sides_gpu(
        &mut self,
        out: &mut [SceneSides],
    ) -> Result<(), WgpuError> {
        if out.len() != self.count {
            return Err(WgpuError::LengthMismatch {
                expected: self.count,
                got: out.len(),
            });
        }
        if self.chunks.iter().any(|c| c.scene.is_none()) {
            // No scene step yet: every particle's sides are empty.
            out.fill(SceneSides::EMPTY);
            return Ok(());
        }
        let mut parts = Vec::with_capacity(2 * self.chunks.len());
        for c in &self.chunks {
            let s = c.scene.as_ref().expect("checked above");
            parts.push((&s.hints, 0, c.count as u64 * SIDE_HINT_BYTES));
            parts.push((&s.slots, 0, c.count as u64 * SIDE_SLOT_BYTES));
        }
        let bytes = self.read_back(&parts)?;
        let mut start = 0;
        for (chunk, pair) in self.chunks.iter().zip(bytes.chunks(2)) {
            let hints: &[SceneHint] = bytemuck::cast_slice(&pair[0]);
            let slots: &[SceneSlots] = bytemuck::cast_slice(&pair[1]);
            let n = chunk.count as usize;
            for ((o, h), s) in out[start..start + n].iter_mut().zip(hints).zip(slots) {
                *o = SceneSides::join(h, s);
            }
            start += n;
        }
        Ok(())
    }

    pub(crate) fn upload_scene_sides_gpu(&mut self, sides: &[SceneSides]) -> Result<(), WgpuError> {
        if sides.len() != self.count {
            return Err(WgpuError::LengthMismatch {
                expected: self.count,
                got: sides.len(),
            });
        }
        self.check_health()?;
        self.ensure_chunk_scenes(false);
        let mut start = 0;
        for chunk in &self.chunks {
            let n = chunk.count as usize;
            let (hints, slots): (Vec<SceneHint>, Vec<SceneSlots>) =
                sides[start..start + n].iter().map(|s| s.split()).unzip();
            let scene = chunk.scene.as_ref().expect("made above");
            self.queue
                .write_buffer(&scene.hints, 0, bytemuck::cast_slice(&hints));
            self.queue
                .write_buffer(&scene.slots, 0, bytemuck::cast_slice(&slots));
            start += n;
        }
        Ok(())
    }
}
