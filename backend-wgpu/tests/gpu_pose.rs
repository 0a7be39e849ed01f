//! The scene kernel's pose arithmetic (`pose.wgsl`) against core's, bit for bit, on the
//! adapter there is (lavapipe in CI): an instance's pose at a fraction of the step (lerp and
//! polynomial slerp), and a point, a velocity and a normal taken into and out of it. The scene
//! step compares whole runs (`tests/tests/differential_scene.rs`); this finds which operation
//! drifts when one does. Without an adapter: a failure under `CI=true`, "skipped" otherwise.

use glam::{Quat, Vec3};
use octoproxy_core::{Instance, Pose};
use octoproxy_wgpu::shader::{self, SCENE_FILES};
use octoproxy_wgpu::{wgpu, SceneParams, WgpuBackend};

/// The test's entry point: case `i` is instance `i` of the scene buffer and a row of 8 floats
/// (`u`, a point, a vector, `phi`, a chord `k` of `n`, `dt`, a root cube and `dmax`); it
/// writes 48 floats.
const KERNEL: &str = "
struct Gravity {
    gravity: vec3<f32>,
    dt: f32,
}

@group(0) @binding(10) var<storage, read> cases: array<f32>;
@group(0) @binding(11) var<storage, read_write> out: array<f32>;

fn put(base: u32, k: u32, v: vec3<f32>) {
    out[base + k] = v.x;
    out[base + k + 1u] = v.y;
    out[base + k + 2u] = v.z;
}

@compute @workgroup_size(64)
fn pose_test(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= arrayLength(&cases) / 16u {
        return;
    }
    let c = 16u * i;
    let u = cases[c];
    let x = vec3<f32>(cases[c + 1u], cases[c + 2u], cases[c + 3u]);
    let v = vec3<f32>(cases[c + 4u], cases[c + 5u], cases[c + 6u]);
    let phi = cases[c + 7u];
    let inst = load_instance(i);
    let p = instance_pose_at(inst, u);
    let o = 48u * i;
    put(o, 0u, p.translation);
    out[o + 3u] = p.scale;
    out[o + 4u] = p.rotation.x;
    out[o + 5u] = p.rotation.y;
    out[o + 6u] = p.rotation.z;
    out[o + 7u] = p.rotation.w;
    put(o, 8u, pose_to_world(p, x));
    put(o, 11u, pose_to_local(p, x));
    put(o, 14u, pose_vector_to_world(p, v));
    put(o, 17u, pose_vector_to_local(p, v));
    put(o, 20u, pose_normal_to_world(p, normalize(v)));
    out[o + 23u] = sin_poly(phi);
    out[o + 24u] = f32(instance_is_static(inst));
    out[o + 25u] = ulp(x.x);
    // A chord of march_in_frame (the second of three from u/2 to 1) and its hit record.
    let u0 = u * 0.5;
    let u1 = 1.0;
    let n = u32(cases[c + 9u]);
    let k = u32(cases[c + 8u]);
    let dt = cases[c + 10u];
    let span = u1 - u0;
    let fa = span * (f32(k) / f32(n));
    let fb = span * (f32(k + 1u) / f32(n));
    let ua = u0 + fa;
    let ub = u0 + fb;
    let h = (fb - fa) * dt;
    let pa = instance_pose_at(inst, ua);
    let pb = instance_pose_at(inst, ub);
    let la = pose_to_local(pa, x + v * (fa * dt));
    let lv = (pose_to_local(pb, x + v * (fb * dt)) - la) / h;
    put(o, 26u, lv);
    out[o + 29u] = ((pose_to_world(pb, la) - pose_to_world(pa, la)) / h + pose_vector_to_world(pb, lv)).x;
    var f = HitFrame(7u, pa, true, inst, ua, ub, h, dt);
    let hit = hit_frame_hit(f, la, normalize(x), lv, h * 0.3);
    out[o + 30u] = hit.position[1] + hit.t;
    // A zero gravity integrated, as a march in a frame does.
    let g = Gravity(vec3<f32>(0.0), h);
    out[o + 31u] = 1.0 / (plus_zero(v) + g.gravity * g.dt).y;
    out[o + 32u] = ua;
    out[o + 33u] = ub;
    out[o + 34u] = h;
    put(o, 35u, la);
    put(o, 38u, pose_to_local(pb, x + v * (fb * dt)));
    put(o, 41u, x + v * (fb * dt));
    out[o + 44u] = fb * dt;
    // substeps, with a root cube of edge 2^k / 4 about x, and a round's pad and reach.
    header.root_min = vec3<f32>(cases[c + 11u], cases[c + 12u], cases[c + 13u]);
    header.root_size = cases[c + 14u];
    header.cell_unit = header.root_size * INV_GRID_CELLS;
    header.dmax = u32(cases[c + 15u]);
    out[o + 45u] = f32(substeps(inst, v, u0, u1, dt));
    let end = x + v * ((1.0 - u) * dt);
    let pad = 4.0 * ulp(max_element(vmax(abs(x), abs(end)))) + PATH_PAD;
    out[o + 46u] = pad;
    out[o + 47u] = length3(v) * ((1.0 - u) * dt) + pad;
}
";

#[test]
fn pose_arithmetic_is_cores_bit_for_bit() {
    let gpu = match WgpuBackend::new() {
        Ok(gpu) => gpu,
        Err(e) if std::env::var("CI").as_deref() == Ok("true") => {
            panic!("CI=true needs a GPU adapter (lavapipe): {e}")
        }
        Err(e) => {
            eprintln!("skipped: {e}");
            return;
        }
    };
    let lavapipe = gpu.description().to_lowercase().contains("llvmpipe");
    // Random instances (some static, some turning half a turn or next to none), fractions and
    // vectors.
    let mut rng = octoproxy_cpu::emit::Rng::new(17);
    // Proxies of boxes of several sizes and places, for `substeps`' root cubes and leaves.
    let roots: Vec<octoproxy_core::OwnedProxy> = (0..5)
        .map(|j| {
            let lo = -0.3 * (j as f32 + 1.0) + j as f32;
            let cube = octoproxy_cpu::scenes::cube([lo; 3], [lo + 0.5 * (j as f32 + 1.0); 3]);
            let params = octoproxy_cpu::BuildParams {
                dmax: 4 + j,
                ..Default::default()
            };
            let (words, _) =
                octoproxy_cpu::bake(&[octoproxy_cpu::MeshRef::from(&cube)], &params, &())
                    .expect("bakes");
            octoproxy_core::OwnedProxy::new(words).expect("valid")
        })
        .collect();
    let mut instances = Vec::new();
    let mut cases: Vec<f32> = Vec::new();
    for k in 0..512 {
        let pose = |rng: &mut octoproxy_cpu::emit::Rng| Pose {
            translation: (rng.unit_vector() * rng.range(0.0, 50.0)).to_array(),
            scale: rng.range(0.1, 4.0),
            rotation: Quat::from_axis_angle(rng.unit_vector(), rng.range(-7.0, 7.0))
                .normalize()
                .to_array(),
        };
        let start = pose(&mut rng);
        let mut end = match k % 4 {
            0 => start,
            1 => pose(&mut rng),
            2 => Pose {
                rotation: (Quat::from_array(start.rotation)
                    * Quat::from_axis_angle(rng.unit_vector(), rng.range(0.0, 2e-3)))
                .normalize()
                .to_array(),
                ..start
            },
            _ => Pose {
                translation: (Vec3::from_array(start.translation) + rng.unit_vector()).to_array(),
                ..start
            },
        };
        if k % 9 == 0 {
            end.scale = 0.0;
        }
        instances.push(Instance::new(0, start, end));
        let u = match k % 5 {
            0 => 0.0,
            1 => 1.0,
            _ => rng.f32(),
        };
        let x = rng.unit_vector() * rng.range(0.0, 20.0);
        let mut v = rng.unit_vector() * rng.range(0.0, 100.0);
        if k % 7 == 0 {
            // Zeros of both signs.
            v.y = -0.0;
            v.z = 0.0;
        }
        let n = 1 + (rng.next_u64() % 9) as u32;
        let k = (rng.next_u64() % n as u64) as u32;
        cases.extend([
            u,
            x.x,
            x.y,
            x.z,
            v.x,
            v.y,
            v.z,
            rng.range(0.0, 1.6),
            k as f32,
            n as f32,
            1.0 / 60.0,
        ]);
        let j = (instances.len() - 1) % roots.len();
        let root = roots[j].view().root_aabb();
        let dmax = roots[j].view().header().dmax;
        cases.extend([
            root.min.x,
            root.min.y,
            root.min.z,
            root.max.x - root.min.x,
            dmax as f32,
        ]);
    }
    let out = run(&gpu, &instances, &cases);
    let mut differ = Vec::new();
    for (i, inst) in instances.iter().enumerate() {
        let c = &cases[16 * i..16 * i + 16];
        let x = Vec3::new(c[1], c[2], c[3]);
        let v = Vec3::new(c[4], c[5], c[6]);
        let p = inst.pose_at(c[0]);
        let mut want = vec![0.0f32; 26];
        want[..3].copy_from_slice(&p.translation);
        want[3] = p.scale;
        want[4..8].copy_from_slice(&p.rotation);
        want[8..11].copy_from_slice(&p.to_world(x).to_array());
        want[11..14].copy_from_slice(&p.to_local(x).to_array());
        want[14..17].copy_from_slice(&p.vector_to_world(v).to_array());
        want[17..20].copy_from_slice(&p.vector_to_local(v).to_array());
        want[20..23].copy_from_slice(&p.normal_to_world(v.normalize()).to_array());
        want[23] = octoproxy_core::scene::sin_poly(c[7]);
        want[24] = inst.is_static() as u32 as f32;
        want[25] = octoproxy_core::ulp(x.x);
        let (u0, u1, n, k, dt) = (c[0] * 0.5, 1.0f32, c[9] as u32, c[8] as u32, c[10]);
        let span = u1 - u0;
        let (fa, fb) = (
            span * (k as f32 / n as f32),
            span * ((k + 1) as f32 / n as f32),
        );
        let (ua, ub) = (u0 + fa, u0 + fb);
        let h = (fb - fa) * dt;
        let (pa, pb) = (inst.pose_at(ua), inst.pose_at(ub));
        let la = pa.to_local(x + v * (fa * dt));
        let lv = (pb.to_local(x + v * (fb * dt)) - la) / h;
        want.extend(lv.to_array());
        want.push(((pb.to_world(la) - pa.to_world(la)) / h + pb.vector_to_world(lv)).x);
        // core's HitFrame::hit for a moving instance.
        let uh = ua + (h - h * 0.3) / dt;
        let uh = if uh < ub { uh } else { ub };
        want.push(inst.pose_at(uh).to_world(la).y + uh);
        // core's plus_zero, then a zero gravity integrated.
        let vz = Vec3::from_array(v.to_array().map(|c| if c == 0.0 { 0.0 } else { c }));
        want.push(1.0 / (vz + Vec3::ZERO * h).y);
        want.extend([ua, ub, h]);
        want.extend(la.to_array());
        want.extend(pb.to_local(x + v * (fb * dt)).to_array());
        want.extend((x + v * (fb * dt)).to_array());
        want.push(fb * dt);
        let view = roots[i % roots.len()].view();
        want.push(octoproxy_core::scene::substeps(inst, &view, v, u0, u1, dt) as f32);
        let end = x + v * ((1.0 - c[0]) * dt);
        let pad = 4.0 * octoproxy_core::ulp(x.abs().max(end.abs()).max_element())
            + octoproxy_core::scene::PATH_PAD;
        want.push(pad);
        want.push(v.length() * ((1.0 - c[0]) * dt) + pad);
        let got = &out[48 * i..48 * i + 48];
        const WHAT: [&str; 16] = [
            "pose_at",
            "pose_at",
            "to_world",
            "to_local",
            "vector_to_world",
            "vector_to_local",
            "normal_to_world",
            "sin_poly / is_static",
            "ulp",
            "a chord's velocity",
            "a chord's end velocity",
            "a hit record",
            "zero gravity",
            "chord parts",
            "substeps",
            "a round's pad and reach",
        ];
        for (k, (w, g)) in want.iter().zip(got).enumerate() {
            // normalize() is WGSL's own, not core's: the normal's inputs may differ.
            if (20..23).contains(&k) {
                continue;
            }
            if w.to_bits() != g.to_bits() && !(w.is_nan() && g.is_nan()) {
                let what = match k {
                    0..8 => WHAT[0],
                    8..11 => WHAT[2],
                    11..14 => WHAT[3],
                    14..17 => WHAT[4],
                    17..20 => WHAT[5],
                    23 | 24 => WHAT[7],
                    25 => WHAT[8],
                    26..29 => WHAT[9],
                    29 => WHAT[10],
                    30 => WHAT[11],
                    31 => WHAT[12],
                    32..45 => WHAT[13],
                    45 => WHAT[14],
                    _ => WHAT[15],
                };
                differ.push(format!(
                    "case {i} ({what}, value {k}): core {w:e}, wgsl {g:e}"
                ));
            }
        }
    }
    if lavapipe {
        assert!(
            differ.is_empty(),
            "{} values differ on lavapipe, first: {}",
            differ.len(),
            differ[..differ.len().min(40)].join("\n")
        );
    } else {
        println!("{} values differ on {}", differ.len(), gpu.description());
    }
}

/// Runs the test kernel over `cases` with `instances` in the scene buffer.
fn run(gpu: &WgpuBackend, instances: &[Instance], cases: &[f32]) -> Vec<f32> {
    let device = gpu.device();
    let queue = gpu.queue();
    // The scene kernel's files but its entry point, then the test's.
    let files: Vec<(&str, &str)> = SCENE_FILES
        .iter()
        .copied()
        .filter(|(name, _)| *name != "scene_kernel.wgsl")
        .chain([("pose_test", KERNEL)])
        .collect();
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let source = shader::join(&files, files.len());
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("pose test"),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("pose test"),
        layout: None,
        module: &module,
        entry_point: Some("pose_test"),
        compilation_options: Default::default(),
        cache: None,
    });
    let storage = |data: &[u8], usage| {
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: data.len().max(4) as u64,
            usage: usage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        queue.write_buffer(&buffer, 0, data);
        buffer
    };
    if let Some(e) = pollster::block_on(scope.pop()) {
        panic!("the test kernel does not build: {e}");
    }
    let scene = storage(bytemuck::cast_slice(instances), wgpu::BufferUsages::STORAGE);
    let params = SceneParams::default();
    let uniform = storage(bytemuck::bytes_of(&params), wgpu::BufferUsages::UNIFORM);
    let input = storage(bytemuck::cast_slice(cases), wgpu::BufferUsages::STORAGE);
    let n = cases.len() / 16;
    let out_bytes = (n * 48 * 4) as u64;
    let output = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: out_bytes,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: out_bytes,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry {
                binding: 5,
                resource: scene.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 6,
                resource: uniform.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 10,
                resource: input.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 11,
                resource: output.as_entire_binding(),
            },
        ],
    });
    let mut encoder = device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups((n as u32).div_ceil(64), 1, 1);
    }
    encoder.copy_buffer_to_buffer(&output, 0, &staging, 0, out_bytes);
    queue.submit([encoder.finish()]);
    staging.map_async(wgpu::MapMode::Read, .., |r| r.expect("maps"));
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .expect("the GPU finishes");
    let view = staging.get_mapped_range(..).expect("mapped");
    bytemuck::cast_slice(&view).to_vec()
}
