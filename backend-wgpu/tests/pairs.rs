//! The particle-particle pass on a device and a particle buffer the caller owns: its buffers
//! are checked against the device's binding limit, it steps a caller's buffer at an offset in
//! place, and it follows a new particle count. `tests/tests/differential_pairs.rs` compares
//! the pass with the CPU's on scenes; here the pass's plumbing is compared with it.

use octoproxy_core::{Backend, PairParams, PairReport, Particle, ProxyView, StepParams};
use octoproxy_cpu::bake::offset::OffsetSurface;
use octoproxy_cpu::{bake_offset, scenes, BuildParams, CpuBackend, MeshRef, Sides};
use octoproxy_wgpu::{wgpu, WgpuBackend, WgpuError, PARTICLE_BYTES};

fn ci() -> bool {
    std::env::var("CI").as_deref() == Ok("true")
}

/// The caller's own device with `limits` (any adapter, lavapipe included), and whether it is
/// lavapipe (where the pass gives the CPU's bits).
fn callers_device(limits: wgpu::Limits) -> Option<(wgpu::Device, wgpu::Queue, bool)> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = match pollster::block_on(instance.request_adapter(&Default::default())) {
        Ok(a) => a,
        Err(e) if ci() => panic!("CI=true needs a GPU adapter (lavapipe: apt install mesa-vulkan-drivers libvulkan1): {e}"),
        Err(e) => {
            eprintln!("skipped: no GPU adapter: {e}");
            return None;
        }
    };
    let lavapipe = adapter.get_info().name.to_lowercase().contains("llvmpipe");
    let descriptor = wgpu::DeviceDescriptor {
        required_limits: limits,
        ..Default::default()
    };
    let (device, queue) = pollster::block_on(adapter.request_device(&descriptor)).expect("device");
    Some((device, queue, lavapipe))
}

const R: f32 = 0.15;

/// A closed box baked for radius `R`, and `n` grains in it (placed out of the offset
/// surface's band, with their sides), moving.
fn scene(n: usize) -> (Vec<u32>, Vec<Particle>) {
    let cube = scenes::cube([-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]);
    let refs = [MeshRef::from(&cube)];
    let surface = OffsetSurface::new(&refs, R, 6, &()).unwrap();
    let params = BuildParams {
        dmax: 6,
        ..BuildParams::default()
    };
    let (words, _) = bake_offset(&surface, &params, &()).unwrap();
    let mut ps: Vec<Particle> = (0..n)
        .map(|i| {
            let (x, y, z) = (i % 5, i / 25, (i / 5) % 5);
            let at = |c: usize| -0.66 + 0.33 * c as f32;
            Particle::new(
                [at(x) + 0.01 * y as f32, 0.2 + 0.31 * y as f32, at(z)],
                [0.3 * (z as f32 - 2.0), 0.0, -0.2 * (x as f32 - 2.0)],
            )
        })
        .collect();
    let view = ProxyView::new(&words).unwrap();
    surface.place(&mut ps, Some(&view));
    let offset = [surface.mesh_ref()];
    let sides = Sides::new(&offset);
    sides.assign(&mut ps, false);
    sides.cages(&view, &mut ps, false);
    (words, ps)
}

fn step() -> StepParams {
    StepParams {
        dt: 1.0 / 60.0,
        radius: R,
        ..StepParams::default()
    }
}

#[test]
fn pass_buffers_past_the_binding_limit_are_too_large() {
    let limits = wgpu::Limits {
        max_storage_buffer_binding_size: 1 << 20,
        ..wgpu::Limits::default()
    };
    let Some((device, queue, _)) = callers_device(limits) else {
        return;
    };
    let (words, _) = scene(0);
    let mut gpu = WgpuBackend::from_device(&device, &queue).unwrap();
    gpu.upload_proxy(&words).unwrap();
    // 40,000 particles: chunks of at most 1 MiB each, but the pass's bodies (32 bytes each)
    // in one binding would take 1.28 MB.
    let ps = vec![Particle::new([0.0, 1.0, 0.0], [0.0; 3]); 40_000];
    gpu.upload_particles(&ps).unwrap();
    assert!(gpu.chunk_count() > 1);
    let e = gpu
        .step_pairs(&step(), &PairParams::default(), 1)
        .unwrap_err();
    match &e {
        WgpuError::TooLarge {
            what,
            needed,
            limit,
        } => {
            assert!(what.contains("bodies"), "{e}");
            assert_eq!((*needed, *limit), (40_000 * 32, 1 << 20));
        }
        _ => panic!("{e}"),
    }
    // A count that fits steps.
    gpu.upload_particles(&ps[..1000]).unwrap();
    gpu.step_pairs(&step(), &PairParams::default(), 1).unwrap();
    gpu.finish().unwrap();
}

#[test]
fn the_pass_steps_a_callers_buffer_in_place_and_follows_a_new_count() {
    let Some((device, queue, lavapipe)) = callers_device(wgpu::Limits::default()) else {
        return;
    };
    let (words, start) = scene(230);
    let offset = 256u64;
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("engine particles"),
        size: offset + start.len() as u64 * PARTICLE_BYTES,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    queue.write_buffer(&buffer, offset, bytemuck::cast_slice(&start));
    let mut gpu = WgpuBackend::from_device(&device, &queue).unwrap();
    gpu.upload_proxy(&words).unwrap();
    gpu.set_chunk_particles(64);
    gpu.use_particle_buffer(&buffer, offset, start.len())
        .unwrap();
    assert_eq!(gpu.chunk_count(), 4);
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&words).unwrap();
    cpu.upload_particles(&start).unwrap();
    let pairs = PairParams {
        iterations: 5,
        ..PairParams::default()
    };
    let compare = |cpu: &mut CpuBackend, gpu: &mut WgpuBackend, what: &str| {
        let n = cpu.particle_count();
        let (mut a, mut b) = (vec![Particle::default(); n], vec![Particle::default(); n]);
        cpu.download_particles(&mut a).unwrap();
        gpu.download_particles(&mut b).unwrap();
        let differ = a
            .iter()
            .zip(&b)
            .filter(|(a, b)| bytemuck::bytes_of(*a) != bytemuck::bytes_of(*b))
            .count();
        eprintln!("{what}: {differ} of {n} particles differ");
        assert!(
            !lavapipe || differ == 0,
            "{what}: the GPU must give the CPU's bits"
        );
        // They moved.
        assert!(a.iter().zip(&start).any(|(a, s)| a.position != s.position));
    };
    for _ in 0..3 {
        cpu.step_pairs(&step(), &pairs, 10).unwrap();
        gpu.step_pairs(&step(), &pairs, 10).unwrap();
    }
    compare(&mut cpu, &mut gpu, "a caller's buffer");
    // A new count: the pass's buffers follow it, and the report goes on counting.
    let fewer = &start[..97];
    cpu.upload_particles(fewer).unwrap();
    gpu.use_particle_buffer(&buffer, offset, fewer.len())
        .unwrap();
    gpu.upload_particles(fewer).unwrap();
    cpu.step_pairs(&step(), &pairs, 20).unwrap();
    gpu.step_pairs(&step(), &pairs, 20).unwrap();
    compare(&mut cpu, &mut gpu, "97 particles");
    let (c, g) = (
        cpu.take_pair_report().unwrap(),
        gpu.take_pair_report().unwrap(),
    );
    assert_eq!((g.steps, g.substeps), (c.steps, c.substeps));
    assert_eq!(g.steps, 50);
    if lavapipe {
        assert_eq!(g, c);
    }
    assert_eq!(gpu.take_pair_report().unwrap(), PairReport::default());
}
