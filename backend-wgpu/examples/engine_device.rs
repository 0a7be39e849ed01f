//! An engine that already owns a wgpu device steps its own particle buffer in place: the
//! buffer it draws as vertices is the buffer octoproxy steps, with no copy.
//!
//! `cargo run --release -p octoproxy-wgpu --example engine_device`

use octoproxy_core::{initial_side, Backend, Particle, ProxyView, StepParams};
use octoproxy_cpu::{bake, BuildParams, MeshRef};
use octoproxy_wgpu::{wgpu, WgpuBackend, PARTICLE_BYTES};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The engine's device, however it made it.
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(instance.request_adapter(&Default::default()))?;
    let (device, queue) = pollster::block_on(adapter.request_device(&Default::default()))?;
    println!("adapter: {}", adapter.get_info().name);

    // A scene: a floor under a tilted plate, baked once (offline, usually).
    let positions = vec![
        [-2.0, 0.0, -2.0],
        [2.0, 0.0, -2.0],
        [2.0, 0.0, 2.0],
        [-2.0, 0.0, 2.0],
        [-1.0, 1.0, -1.0],
        [1.0, 0.6, -1.0],
        [1.0, 0.6, 1.0],
        [-1.0, 1.0, 1.0],
    ];
    let triangles = vec![[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]];
    let (words, report) = bake(
        &[MeshRef {
            positions: &positions,
            triangles: &triangles,
        }],
        &BuildParams::default(),
        &(),
    )?;
    println!(
        "proxy: {} nodes, {} bytes",
        report.nodes, report.total_bytes
    );

    // The engine's particle buffer: drawable as vertices, steppable as storage.
    let view = ProxyView::new(&words)?;
    let n = 100_000;
    let particles: Vec<Particle> = (0..n)
        .map(|i| {
            let (u, v) = ((i % 316) as f32 / 316.0, (i / 316) as f32 / 316.0);
            let mut p = Particle::new(
                [u * 3.0 - 1.5, 2.0 + (i % 7) as f32 * 0.05, v * 3.0 - 1.5],
                [0.0; 3],
            );
            p.side = initial_side(&view, p.position);
            p
        })
        .collect();
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("engine particles"),
        size: n as u64 * PARTICLE_BYTES,
        usage: wgpu::BufferUsages::VERTEX
            | wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    queue.write_buffer(&buffer, 0, bytemuck::cast_slice(&particles));

    // octoproxy on the engine's device, stepping the engine's buffer.
    let mut gpu = WgpuBackend::from_device(&device, &queue)?;
    gpu.upload_proxy(&words)?;
    gpu.use_particle_buffer(&buffer, 0, n)?;
    let params = StepParams::default();
    for _frame in 0..120 {
        gpu.step(&params, 1)?;
        // ... the engine would draw `buffer` here, as a vertex buffer.
    }

    // Read back once, only to report.
    let mut out = vec![Particle::default(); n];
    gpu.download_particles(&mut out)?;
    let resting = out
        .iter()
        .filter(|p| p.position[1] >= -1e-3 && p.position[1] < 1.2)
        .count();
    let collisions: u64 = out.iter().map(|p| p.collisions() as u64).sum();
    println!("after 120 frames: {resting} of {n} particles on the plate or the floor, {collisions} collisions");
    Ok(())
}
