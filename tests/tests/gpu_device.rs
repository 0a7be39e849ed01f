//! The GPU backend on a device and a particle buffer the caller owns, as an engine would use
//! it: the engine's buffer (usable as a vertex buffer too) is stepped in place and read back
//! by the engine itself; and every misuse is an error value.

use glam::Vec3;
use octoproxy_core::{Backend, Particle, StepParams};
use octoproxy_cpu::emit::emit_box;
use octoproxy_cpu::scenes;
use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef};
use octoproxy_wgpu::wgpu;
use octoproxy_wgpu::{WgpuBackend, WgpuError, PARTICLE_BYTES};

fn ci() -> bool {
    std::env::var("CI").as_deref() == Ok("true")
}

/// The caller's own device, opened with plain wgpu (any adapter, lavapipe included).
fn callers_device() -> Option<(wgpu::Device, wgpu::Queue)> {
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
    Some(pollster::block_on(adapter.request_device(&Default::default())).expect("device"))
}

fn proxy() -> Vec<u32> {
    let mesh = scenes::merge(&[
        scenes::uv_sphere([0.0, 0.0, 0.0], 0.5, 24, 12),
        scenes::flat_sheet([0.0, -0.7, 0.0], 1.8, 4),
    ]);
    bake(
        &[MeshRef::from(&mesh)],
        &BuildParams {
            dmin: 3,
            dmax: 6,
            ..BuildParams::default()
        },
        &(),
    )
    .expect("bakes")
    .0
}

fn particles(n: usize) -> Vec<Particle> {
    emit_box(
        n,
        Vec3::new(-0.9, -0.5, -0.9),
        Vec3::new(0.9, 0.9, 0.9),
        2.0,
        3,
    )
    .expect("fits in memory")
}

#[test]
fn steps_a_callers_buffer_in_place() {
    let Some((device, queue)) = callers_device() else {
        return;
    };
    let words = proxy();
    let start = particles(3000);
    // The engine's buffer: particles at byte offset 256, drawable as vertices.
    let offset = 256u64;
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("engine particles"),
        size: offset + start.len() as u64 * PARTICLE_BYTES,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::VERTEX
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    queue.write_buffer(&buffer, offset, bytemuck::cast_slice(&start));

    let mut gpu =
        WgpuBackend::from_device(&device, &queue).expect("backend on the caller's device");
    gpu.set_chunk_particles(1024); // three chunks, all views into the caller's buffer
    gpu.upload_proxy(&words).unwrap();
    gpu.use_particle_buffer(&buffer, offset, start.len())
        .unwrap();
    assert_eq!(gpu.chunk_count(), 3);
    let params = StepParams::default();
    gpu.step(&params, 90).unwrap();

    // The engine reads its own buffer back, with no help from the backend.
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("engine read-back"),
        size: buffer.size(),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(&buffer, 0, &staging, 0, buffer.size());
    queue.submit([encoder.finish()]);
    staging.map_async(wgpu::MapMode::Read, .., |r| r.expect("map"));
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
    let bytes = staging.get_mapped_range(offset..).unwrap().to_vec();
    let on_gpu: &[Particle] = bytemuck::cast_slice(&bytes);

    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&words).unwrap();
    cpu.upload_particles(&start).unwrap();
    cpu.step(&params, 90).unwrap();
    let collisions: u32 = cpu.particles().iter().map(|p| p.collisions()).sum();
    assert!(collisions > 0, "nothing collided");
    for (i, (c, g)) in cpu.particles().iter().zip(on_gpu).enumerate() {
        assert_eq!(
            (c.collisions(), c.side, c.flags),
            (g.collisions(), g.side, g.flags),
            "particle {i}"
        );
        let d = (0..3)
            .map(|a| (c.position[a] - g.position[a]).abs())
            .fold(0.0, f32::max);
        assert!(d < 1e-4, "particle {i} differs by {d}");
    }
    // The backend's own read-back sees the same thing.
    let mut out = vec![Particle::default(); start.len()];
    gpu.download_particles(&mut out).unwrap();
    assert_eq!(
        bytemuck::cast_slice::<Particle, u8>(&out),
        bytemuck::cast_slice::<Particle, u8>(on_gpu)
    );
}

#[test]
fn misuse_is_an_error_not_a_panic() {
    let Some((device, queue)) = callers_device() else {
        return;
    };
    let mut gpu = WgpuBackend::from_device(&device, &queue).unwrap();
    let params = StepParams::default();
    // Stepping before a proxy.
    gpu.upload_particles(&particles(10)).unwrap();
    assert!(matches!(gpu.step(&params, 1), Err(WgpuError::NoProxy)));
    // A hostile proxy is refused before it reaches the GPU.
    let mut words = proxy();
    words[1] ^= 0xff;
    assert!(matches!(
        gpu.upload_proxy(&words),
        Err(WgpuError::Format(_))
    ));
    assert!(matches!(
        gpu.upload_proxy(&words[..5]),
        Err(WgpuError::Format(_))
    ));
    gpu.upload_proxy(&proxy()).unwrap();
    // Bad step parameters.
    let bad = StepParams {
        dt: f32::NAN,
        ..params
    };
    assert!(matches!(gpu.step(&bad, 1), Err(WgpuError::Params(_))));
    // A read-back slice of the wrong length.
    let mut out = vec![Particle::default(); 9];
    assert!(matches!(
        gpu.download_particles(&mut out),
        Err(WgpuError::LengthMismatch {
            expected: 10,
            got: 9
        })
    ));
    // Caller's buffers it cannot use: no STORAGE usage, a misaligned offset, too small.
    let make = |size, usage| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size,
            usage,
            mapped_at_creation: false,
        })
    };
    let vertex_only = make(1024, wgpu::BufferUsages::VERTEX);
    assert!(matches!(
        gpu.use_particle_buffer(&vertex_only, 0, 4),
        Err(WgpuError::BadBuffer(_))
    ));
    let storage = make(
        1024,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
    );
    assert!(matches!(
        gpu.use_particle_buffer(&storage, 4, 4),
        Err(WgpuError::BadBuffer(_))
    ));
    assert!(matches!(
        gpu.use_particle_buffer(&storage, 0, 33),
        Err(WgpuError::BadBuffer(_))
    ));
    assert!(matches!(
        gpu.use_particle_buffer(&storage, 0, usize::MAX / 2),
        Err(WgpuError::BadBuffer(_))
    ));
    // Uploading into a buffer without COPY_DST, reading back one without COPY_SRC.
    gpu.use_particle_buffer(&storage, 0, 32).unwrap();
    assert!(matches!(
        gpu.upload_particles(&particles(32)),
        Err(WgpuError::BadBuffer(_))
    ));
    let no_copy_src = make(
        1024,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    );
    gpu.use_particle_buffer(&no_copy_src, 0, 32).unwrap();
    let mut out = vec![Particle::default(); 32];
    assert!(matches!(
        gpu.download_particles(&mut out),
        Err(WgpuError::BadBuffer(_))
    ));
    // After all that, it still works.
    let good = make(
        1024,
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
    );
    gpu.use_particle_buffer(&good, 0, 32).unwrap();
    gpu.upload_particles(&particles(32)).unwrap();
    gpu.step(&params, 3).unwrap();
    let mut out = vec![Particle::default(); 32];
    gpu.download_particles(&mut out).unwrap();
    assert!(out.iter().all(|p| p.position.iter().all(|c| c.is_finite())));
}

#[test]
fn a_new_chunk_size_takes_effect_at_the_next_upload() {
    let Some((device, queue)) = callers_device() else {
        return;
    };
    let mut gpu = WgpuBackend::from_device(&device, &queue).unwrap();
    gpu.upload_proxy(&proxy()).unwrap();
    let ps = particles(1000);
    gpu.set_chunk_particles(128);
    gpu.upload_particles(&ps).unwrap();
    assert_eq!(gpu.chunk_count(), 8);
    // Same particle count, other chunk size: the buffers must be remade, not reused.
    gpu.set_chunk_particles(256);
    gpu.upload_particles(&ps).unwrap();
    assert_eq!(gpu.chunk_count(), 4);
    gpu.step(&StepParams::default(), 5).unwrap();
    let mut out = vec![Particle::default(); ps.len()];
    gpu.download_particles(&mut out).unwrap();
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&proxy()).unwrap();
    cpu.upload_particles(&ps).unwrap();
    cpu.step(&StepParams::default(), 5).unwrap();
    assert_eq!(
        bytemuck::cast_slice::<Particle, u8>(&out),
        bytemuck::cast_slice::<Particle, u8>(cpu.particles())
    );
}
