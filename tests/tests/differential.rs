//! The same proxy and particles stepped on the CPU and on the GPU (wgpu; lavapipe in CI) for
//! many steps, compared particle by particle.
//!
//! Both run the same routine on the same bytes. Grid planes are exact on both sides
//! (`grid_plane`), so leaves, labels and exit points agree exactly; what can differ is the
//! last bits of a particle's coordinates along its travel and of its velocity after a
//! response: Vulkan lets a GPU compute `x / y` and `sqrt` to within 2.5 ULP, and a driver
//! may fuse `a * b + c` into one rounding, where the CPU rounds every operation. On lavapipe
//! (x86 SSE, correctly rounded division and sqrt, no fusing) every particle comes out bit
//! for bit identical, and these tests print how many did. On a GPU with approximate
//! division, a particle that collides often can amplify an ULP into a visible difference,
//! so the check is: the same collision count, side and status flags for every particle,
//! and positions within `POSITION_TOLERANCE_LEAVES` of a finest leaf; on lavapipe, every
//! particle bit for bit.
//!
//! Bits that agree on common paths say nothing of a rare branch no particle took. Each scene
//! names the rare branches of the march it is built to reach ([`MarchBranch`]), and the
//! CPU's reference run (`step_particle_counted`) must take each of them, so a mirror that
//! drifts in one of those branches cannot pass; `every_rare_branch_has_a_scene` checks that
//! every branch has such a scene.

use glam::Vec3;
use octoproxy_core::{
    step_particle, step_particle_counted, Backend, MarchBranch, MarchCounts, Particle, ProxyView,
    StepParams, FLAG_INVALID, MAX_DEPTH, SIDE_CAGED, SIDE_EXITS_MASK,
};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::harness::{near_surface_particles, random_particles};
use octoproxy_cpu::scenes::{self, Mesh};
use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef, Sides};
use octoproxy_tests::meshes;
use octoproxy_wgpu::WgpuBackend;

mod common;
use common::{gpu_backend as gpu, is_lavapipe};

const DT: f32 = 1.0 / 60.0;

/// Positions may differ by this many finest-leaf edges (see the module documentation).
const POSITION_TOLERANCE_LEAVES: f32 = 1e-3;

/// How two runs differ.
#[derive(Debug, Default)]
struct Agreement {
    particles: usize,
    collisions_differ: usize,
    side_differs: usize,
    flags_differ: usize,
    /// Largest position difference, in finest-leaf edges, and the particle.
    worst_leaves: f32,
    worst_index: usize,
    /// Largest velocity difference relative to the speed.
    worst_velocity: f32,
    collisions: u64,
    /// Particles whose 32 bytes are identical on both sides.
    identical: usize,
}

fn compare(cpu: &[Particle], gpu: &[Particle], leaf: f32) -> Agreement {
    let mut a = Agreement {
        particles: cpu.len(),
        ..Agreement::default()
    };
    for (i, (c, g)) in cpu.iter().zip(gpu).enumerate() {
        a.collisions += c.collisions() as u64;
        a.identical += (bytemuck::bytes_of(c) == bytemuck::bytes_of(g)) as usize;
        a.collisions_differ += (c.collisions() != g.collisions()) as usize;
        a.side_differs += (c.side != g.side) as usize;
        a.flags_differ += (c.flags & 0xff != g.flags & 0xff) as usize;
        if c.flags & FLAG_INVALID != 0 {
            continue;
        }
        let d = (Vec3::from_array(c.position) - Vec3::from_array(g.position))
            .abs()
            .max_element()
            / leaf;
        // NaN counts as the worst.
        if !(d <= a.worst_leaves) {
            a.worst_leaves = d;
            a.worst_index = i;
        }
        let cv = Vec3::from_array(c.velocity);
        let dv = (cv - Vec3::from_array(g.velocity)).length() / cv.length().max(1e-6);
        if !(dv <= a.worst_velocity) {
            a.worst_velocity = dv;
        }
    }
    a
}

/// Particles placed where float edge cases live: exactly on leaf planes, moving along axes,
/// at rest, grazing a plane, outside the root box, and with NaN or infinite input.
fn hand_placed(view: &ProxyView<'_>, n: usize, seed: u64) -> Vec<Particle> {
    let mut rng = Rng::new(seed);
    let root = view.root_aabb();
    let dmax = view.header().dmax;
    let cells = 1u32 << dmax;
    let shift = MAX_DEPTH - dmax;
    let leaf = view.finest_leaf_size();
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let mut p = Vec3::new(
            rng.range(root.min.x, root.max.x),
            rng.range(root.min.y, root.max.y),
            rng.range(root.min.z, root.max.z),
        );
        // Snap one, two or three coordinates onto leaf planes.
        let snapped = 1 + k % 3;
        for a in 0..snapped {
            let i = ((rng.next_u64() % (cells as u64 + 1)) as u32) << shift;
            p[(a + k) % 3] = view.plane((a + k) % 3, i);
        }
        let speed = leaf / DT * [0.0, 0.3, 1.0, 4.0, 40.0][k % 5];
        let v = match (k / 5) % 6 {
            0 => {
                let mut v = Vec3::ZERO;
                v[k % 3] = if k % 2 == 0 { speed } else { -speed };
                v
            }
            1 => Vec3::ZERO,
            // Grazing: almost parallel to a leaf plane.
            2 => {
                let mut v = rng.unit_vector() * speed;
                v[k % 3] = speed * 1e-6;
                v
            }
            3 => rng.unit_vector() * speed,
            // Outside the root box, aimed at its centre.
            4 => {
                let c = (root.min + root.max) * 0.5;
                p = c + rng.unit_vector() * (root.max.x - root.min.x);
                (c - p).normalize() * speed.max(leaf / DT)
            }
            _ => rng.unit_vector() * speed,
        };
        let mut q = Particle::new(p.to_array(), v.to_array());
        q.side = octoproxy_core::initial_side(view, q.position);
        // Some carry cage bits of their own: where they are not in a solid leaf, the step
        // drops them; where they are, they are held as those bits say.
        if k % 7 == 3 {
            q.side |= SIDE_CAGED | (rng.next_u64() as u32 & SIDE_EXITS_MASK);
        }
        out.push(q);
    }
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        out.push(Particle::new([bad, 0.0, 0.0], [0.0; 3]));
        out.push(Particle::new([0.0; 3], [0.0, bad, 0.0]));
    }
    // Far outside, flying away; and a velocity whose step overflows.
    out.push(Particle::new([1e30, 1e30, 1e30], [1.0, 1.0, 1.0]));
    out.push(Particle::new(
        (root.min - Vec3::ONE).to_array(),
        [3e38, 3e38, 3e38],
    ));
    out
}

/// The rare branches each scene is built to reach, by the scene's name; `needs_meshes` for
/// the scenes of the shared meshes, which may be absent outside CI.
struct Reach {
    scene: &'static str,
    needs_meshes: bool,
    branches: &'static [MarchBranch],
}

/// Taken in every scene, by the hand-placed particles: outside the root aimed at it or flying
/// away, non-finite on input, overflowing in the step, ending on a leaf's face.
const EVERY_SCENE: &[MarchBranch] = &[
    MarchBranch::RootEntry,
    MarchBranch::RootMiss,
    MarchBranch::InvalidStart,
    MarchBranch::InvalidEnd,
    MarchBranch::EndOnFace,
    MarchBranch::CageLost,
];

const REACHES: &[Reach] = {
    use MarchBranch::*;
    &[
        Reach {
            scene: "bunny",
            needs_meshes: true,
            branches: &[SolidCollision, SlideOffSolid, Pinch, SlabEntry, SlabSide],
        },
        Reach {
            scene: "nefertiti",
            needs_meshes: true,
            branches: &[SolidCollision, Pinch],
        },
        Reach {
            scene: "sphere at 2e5",
            needs_meshes: false,
            branches: &[StartBesideShell, ShellBlock],
        },
        Reach {
            scene: "fandisk",
            needs_meshes: true,
            branches: &[Pinch],
        },
        Reach {
            scene: "narrow gaps",
            needs_meshes: false,
            branches: &[Pinch],
        },
        Reach {
            scene: "thin plates",
            needs_meshes: false,
            branches: &[
                SolidCollision,
                SlideOffSolid,
                Pinch,
                CageWall,
                CageExit,
                CageNudge,
                SlabEntry,
                SlabSide,
            ],
        },
        Reach {
            scene: "wedge + star",
            needs_meshes: false,
            branches: &[SolidCollision, Pinch, PinchStop, SlabEntry, SlabSide],
        },
        Reach {
            scene: "triangle soup + needle",
            needs_meshes: false,
            branches: &[
                StartBesideShell,
                SlideOffSolid,
                ShellBlock,
                SolidCollision,
                Pinch,
            ],
        },
        Reach {
            scene: "nested shells, chunked",
            needs_meshes: false,
            branches: &[
                ShellBlock,
                SolidCollision,
                Pinch,
                PinchStop,
                CageWall,
                CageExit,
                CageNudge,
                SlabEntry,
                SlabSide,
            ],
        },
        Reach {
            scene: "faces on cell planes",
            needs_meshes: false,
            branches: &[
                SlideOffSolid,
                ShellBlock,
                Pinch,
                LeafBound,
                LeafBoundInShell,
            ],
        },
        Reach {
            scene: "creases and apexes",
            needs_meshes: false,
            branches: &[
                ShellBlock,
                SlideOffSolid,
                Pinch,
                PinchStop,
                SlabEntry,
                SlabSide,
            ],
        },
    ]
};

/// Steps the same particles on both backends and checks the agreement, and that the CPU's
/// reference run took every branch its [`REACHES`] row names. Without an adapter (and not
/// under CI) only the CPU backend's agreement with unhinted stepping, and the branches, are
/// checked.
fn differential(name: &str, mesh: &Mesh, build: &BuildParams, steps: u32, chunk: Option<u32>) {
    let reaches = REACHES
        .iter()
        .find(|r| r.scene == name)
        .unwrap_or_else(|| panic!("{name}: no row in REACHES (which rare branches is it for?)"))
        .branches;
    let mut gpu = gpu();
    if let (Some(gpu), Some(n)) = (gpu.as_mut(), chunk) {
        gpu.set_chunk_particles(n);
        gpu.set_fold_width(3);
    }
    let (words, _) = bake(&[MeshRef::from(mesh)], build, &()).expect("bakes");
    let view = ProxyView::new(&words).expect("valid");
    let gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
    let leaf = view.finest_leaf_size();
    let scene = view.header().root_size;
    let speeds: Vec<f32> = [0.1 * leaf, leaf, 5.0 * leaf, 0.5 * scene]
        .iter()
        .map(|d| d / DT)
        .collect();
    let mut particles = random_particles(&view, &gt, 3000, &speeds, 5);
    particles.extend(hand_placed(&view, 2000, 6));
    // And some far faster than anything in a scene: eight scenes per step, so that one
    // bouncing between surfaces two or more leaves apart meets the leaf bound.
    particles.extend(random_particles(&view, &gt, 300, &[8.0 * scene / DT], 7));
    // And some where users start them: near the surface, with exact sides, caged where they
    // start inside a solid leaf.
    let refs = [MeshRef::from(mesh)];
    let sides = Sides::new(&refs);
    let mut near = near_surface_particles(&refs, &sides, 600, 1.5 * leaf, &speeds, 8);
    sides.cages(&view, &mut near, false);
    particles.extend(near);
    if let (Some(gpu), Some(n)) = (gpu.as_mut(), chunk) {
        gpu.upload_particles(&particles).unwrap();
        assert_eq!(
            gpu.chunk_count(),
            particles.len().div_ceil(n as usize),
            "{name}: chunks"
        );
        assert!(
            gpu.dispatch_size(n).1 > 1,
            "{name}: the dispatch is not folded"
        );
    }
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&words).unwrap();
    if let Some(gpu) = gpu.as_mut() {
        gpu.upload_proxy(&words).unwrap();
    }
    let mut worst = 0f32;
    let mut counts = MarchCounts::default();
    for (k, params) in [
        StepParams {
            dt: DT,
            ..StepParams::default()
        },
        StepParams {
            gravity: [0.0; 3],
            dt: DT,
            restitution: 1.0,
            friction: 0.0,
            radius: 0.0,
            _pad: 0,
        },
        StepParams {
            gravity: [0.0, -9.81, 0.0],
            dt: DT,
            restitution: 0.0,
            friction: 1.0,
            radius: 0.0,
            _pad: 0,
        },
    ]
    .into_iter()
    .enumerate()
    {
        // The last run descends from the root on both sides instead of using the table.
        let use_lut = k < 2;
        cpu.set_use_lut(use_lut);
        cpu.upload_particles(&particles).unwrap();
        cpu.step(&params, steps).unwrap();
        // The backends keep each particle's leaf between steps (`LeafHint`); a step without
        // hints must give the same bits. This reference run counts the march's rare branches.
        let plain_view = if use_lut { view } else { view.without_lut() };
        let mut plain = particles.clone();
        for _ in 0..steps {
            plain.iter_mut().for_each(|p| {
                step_particle_counted(&plain_view, p, &params, &mut counts);
            });
        }
        let unhinted_differ = plain
            .iter()
            .zip(cpu.particles())
            .filter(|(a, b)| bytemuck::bytes_of(*a) != bytemuck::bytes_of(*b))
            .count();
        assert_eq!(
            unhinted_differ, 0,
            "{name}: stepping with leaf hints changed {unhinted_differ} particles"
        );
        let Some(gpu) = gpu.as_mut() else { continue };
        gpu.set_use_lut(use_lut);
        gpu.upload_particles(&particles).unwrap();
        gpu.step(&params, steps).unwrap();
        let mut from_gpu = vec![Particle::default(); particles.len()];
        gpu.download_particles(&mut from_gpu).unwrap();
        let a = compare(cpu.particles(), &from_gpu, leaf);
        eprintln!(
            "{name}{}: {} particles x {steps} steps, {} collisions; bit-identical {}; differ: collisions {}, side {}, flags {}; worst position {:.2e} leaf (particle {}), worst velocity {:.2e} relative",
            if use_lut { "" } else { " (no LUT)" },
            a.particles, a.collisions, a.identical, a.collisions_differ, a.side_differs, a.flags_differ, a.worst_leaves, a.worst_index, a.worst_velocity
        );
        assert!(
            a.collisions > 0,
            "{name}: nothing collided, the test tests nothing"
        );
        let i = a.worst_index;
        assert_eq!(
            (a.collisions_differ, a.side_differs, a.flags_differ),
            (0, 0, 0),
            "{name}: backends disagree; e.g. particle {i}: start {:?}, cpu {:?}, gpu {:?}",
            particles[i],
            cpu.particles()[i],
            from_gpu[i]
        );
        assert!(
            a.worst_leaves <= POSITION_TOLERANCE_LEAVES,
            "{name}: particle {i} differs by {} leaves: start {:?}, cpu {:?}, gpu {:?}",
            a.worst_leaves,
            particles[i],
            cpu.particles()[i],
            from_gpu[i]
        );
        if is_lavapipe(gpu) {
            let first = (0..particles.len()).find(|&i| {
                bytemuck::bytes_of(&cpu.particles()[i]) != bytemuck::bytes_of(&from_gpu[i])
            });
            assert_eq!(
                a.identical, a.particles,
                "{name}: lavapipe must give the CPU's bits; e.g. particle {first:?}"
            );
        }
        worst = worst.max(a.worst_leaves);
    }
    let taken: Vec<String> = MarchBranch::ALL
        .iter()
        .filter(|b| counts[**b] > 0)
        .map(|b| format!("{b:?} {}", counts[*b]))
        .collect();
    eprintln!("{name}: rare branches taken: {}", taken.join(", "));
    let missed: Vec<_> = EVERY_SCENE
        .iter()
        .chain(reaches)
        .filter(|b| counts[**b] == 0)
        .collect();
    assert!(
        missed.is_empty(),
        "{name}: the scene is built to reach {missed:?}, and no particle took them: the test no longer tests them"
    );
    if gpu.is_some() {
        eprintln!("{name}: worst position difference {worst:.2e} of a finest leaf");
    } else {
        eprintln!("{name}: hinted CPU steps equal unhinted ones; no GPU to compare with");
    }
}

fn build(dmax: u32) -> BuildParams {
    BuildParams {
        dmin: 3,
        dmax,
        ..BuildParams::default()
    }
}

#[test]
fn bunny_open_mesh() {
    let Some(mesh) = meshes::load("stanford-bunny.obj.gz") else {
        return;
    };
    differential("bunny", &mesh, &build(7), 120, None);
}

#[test]
fn nefertiti_closed_scan() {
    let Some(mesh) = meshes::load("nefertiti.obj.gz") else {
        return;
    };
    differential("nefertiti", &mesh, &build(7), 120, None);
}

#[test]
fn far_from_the_origin() {
    // At 2e5 a dmax-5 leaf is 4.4 f32 steps wide: slow particles sit on cell planes beside the
    // shell, and steps start there (the step's `start_beside_shell`).
    let mesh = scenes::uv_sphere([2e5, 0.0, 0.0], 1.0, 48, 24);
    differential("sphere at 2e5", &mesh, &build(5), 120, None);
}

#[test]
fn fandisk_creases_at_a_coarse_depth() {
    // At dmax 6 the CAD part's narrow grooves put surface leaves that face each other side
    // by side: particles are pinched between them (the step's `pinch`).
    let Some(mesh) = meshes::load("fandisk.obj.gz") else {
        return;
    };
    differential("fandisk", &mesh, &build(6), 120, None);
}

#[test]
fn narrow_gaps_between_facing_surfaces() {
    // Slabs stacked with gaps from about half a leaf to two leaves: the surfaces across a gap
    // face each other from neighbouring leaves, and particles are pinched between them.
    let mut slabs = Vec::new();
    let mut y = -0.9;
    for gap in [0.015, 0.025, 0.035, 0.05, 0.07] {
        slabs.push(scenes::slab([0.0, y + 0.05, 0.0], [1.8, 0.1, 1.8]));
        y += 0.1 + gap;
    }
    slabs.push(scenes::slab([0.0, y + 0.05, 0.0], [1.8, 0.1, 1.8]));
    differential("narrow gaps", &scenes::merge(&slabs), &build(6), 120, None);
}

#[test]
fn thin_plates() {
    // Plates far thinner than a leaf, crossing each other.
    let mesh = scenes::merge(&[
        scenes::slab([0.0, 0.0, 0.0], [2.0, 0.004, 2.0]),
        scenes::slab([0.0, 0.0, 0.0], [0.004, 2.0, 1.5]),
        scenes::flat_sheet([0.0, 0.6, 0.0], 1.6, 8),
    ]);
    differential("thin plates", &mesh, &build(6), 150, None);
}

#[test]
fn sharp_wedges_and_star() {
    let mesh = scenes::merge(&[
        scenes::wedge(8.0, 2.0, 1.0),
        scenes::star_prism(7, 1.5, 0.4, 1.0),
    ]);
    differential("wedge + star", &mesh, &build(7), 150, None);
}

#[test]
fn triangle_soup_with_conflicting_labels() {
    // Triangles through each other in every direction: most surface leaves are two-sided and
    // many empty leaves get conflicting labels; a needle's tip is sharper than a leaf.
    let mesh = scenes::merge(&[scenes::triangle_soup(300, 5), scenes::cone(1.5, 0.01, 12)]);
    differential("triangle soup + needle", &mesh, &build(6), 120, None);
}

#[test]
fn nested_shells_in_small_chunks() {
    // Chunks of 256 particles (4 workgroups) in dispatch rows of 3 workgroups: 20 chunks, each
    // a folded 3 x 2 grid whose last two workgroups have no particles.
    let mesh = scenes::nested_shells(1.0, 0.02);
    differential("nested shells, chunked", &mesh, &build(6), 100, Some(256));
}

#[test]
fn faces_on_cell_planes() {
    // Float ties everywhere: the hand-placed particles start on the very planes the faces lie in.
    differential(
        "faces on cell planes",
        &scenes::on_cell_planes(&build(6)),
        &build(6),
        120,
        None,
    );
}

#[test]
fn resting_in_creases_and_apexes() {
    // Particles pressed between surfaces less than a leaf apart, pinched, sliding to a stop.
    let mesh = scenes::merge(&[
        scenes::rotated(&scenes::v_groove(5.0, 10.0), 29.0, 17.0),
        scenes::rotated(&scenes::funnel(15.0, 24), -20.0, 0.0),
    ]);
    differential("creases and apexes", &mesh, &build(6), 150, None);
}

#[test]
fn every_rare_branch_has_a_scene() {
    // Scenes of procedural meshes only: the shared meshes may be absent.
    let missing: Vec<_> = MarchBranch::ALL
        .iter()
        .filter(|b| {
            !EVERY_SCENE.contains(b)
                && !REACHES
                    .iter()
                    .any(|r| !r.needs_meshes && r.branches.contains(b))
        })
        .collect();
    assert!(
        missing.is_empty(),
        "rare branches of the march that no procedural scene is built to reach: {missing:?}"
    );
}

#[test]
fn leaf_hints_are_forgotten_when_the_proxy_changes() {
    // Steps with one proxy, then swaps in another with a sheet across the middle, where the
    // first is empty. Every particle then holds a hint to a large empty leaf of the first
    // proxy; used with the second, it would carry particles through the sheet. Both backends
    // must give what stepping without hints gives. (The first proxy's sheet, high up and
    // facing down, only makes both proxies stamp the particles' side the same: front.)
    let cubes = [
        scenes::cube([-1.0, -1.0, -1.0], [-0.9, -0.9, -0.9]),
        scenes::cube([0.9, 0.9, 0.9], [1.0, 1.0, 1.0]),
    ];
    let mut ceiling = scenes::flat_sheet([0.0, 0.95, 0.0], 1.8, 4);
    ceiling.triangles.iter_mut().for_each(|t| t.swap(1, 2));
    let corner = scenes::merge(&[cubes[0].clone(), cubes[1].clone(), ceiling]);
    let sheet = scenes::merge(&[
        cubes[0].clone(),
        cubes[1].clone(),
        scenes::flat_sheet([0.0, 0.0, 0.0], 1.8, 4),
    ]);
    let (a, _) = bake(&[MeshRef::from(&corner)], &build(6), &()).expect("bakes");
    let (b, _) = bake(&[MeshRef::from(&sheet)], &build(6), &()).expect("bakes");
    let (view_a, view_b) = (ProxyView::new(&a).unwrap(), ProxyView::new(&b).unwrap());
    assert_eq!(
        view_a.root_aabb(),
        view_b.root_aabb(),
        "the test needs the same root box"
    );
    // Falling particles above the sheet, slow enough to stay in their leaf for a while.
    let mut rng = Rng::new(11);
    let particles: Vec<Particle> = (0..2000)
        .map(|_| {
            Particle::new(
                [
                    rng.range(-0.8, 0.8),
                    rng.range(0.3, 0.6),
                    rng.range(-0.8, 0.8),
                ],
                [0.0, -0.5, 0.0],
            )
        })
        .collect();
    let params = StepParams {
        gravity: [0.0, -2.0, 0.0],
        dt: DT,
        restitution: 0.0,
        friction: 0.5,
        radius: 0.0,
        _pad: 0,
    };
    let mut expected = particles.clone();
    for (view, steps) in [(&view_a, 10), (&view_b, 60)] {
        for _ in 0..steps {
            expected.iter_mut().for_each(|p| {
                step_particle(view, p, &params);
            });
        }
    }
    let below: Vec<_> = expected.iter().filter(|p| p.position[1] < 0.0).collect();
    assert!(
        below.is_empty(),
        "without hints, {} particles fell through the sheet, e.g. {:?}",
        below.len(),
        below[0]
    );
    fn swapped<B: Backend>(
        mut backend: B,
        a: &[u32],
        b: &[u32],
        particles: &[Particle],
        params: &StepParams,
    ) -> Vec<Particle> {
        backend.upload_proxy(a).unwrap();
        backend.upload_particles(particles).unwrap();
        backend.step(params, 10).unwrap();
        backend.upload_proxy(b).unwrap();
        backend.step(params, 60).unwrap();
        let mut out = vec![Particle::default(); particles.len()];
        backend.download_particles(&mut out).unwrap();
        out
    }
    // The CPU runs the very code of `step_particle`: the same bits.
    let got = swapped(CpuBackend::new(), &a, &b, &particles, &params);
    let differ = got
        .iter()
        .zip(&expected)
        .filter(|(g, e)| bytemuck::bytes_of(*g) != bytemuck::bytes_of(*e))
        .count();
    assert_eq!(
        differ, 0,
        "cpu: {differ} particles differ from stepping without hints"
    );
    // The GPU within the tolerances of the module documentation; a stale hint would carry
    // particles through the sheet, collisions and all.
    if let Some(gpu) = gpu() {
        let got = swapped(gpu, &a, &b, &particles, &params);
        let agreement = compare(&expected, &got, view_b.finest_leaf_size());
        assert!(agreement.collisions > 0, "nothing collided with the sheet");
        assert_eq!(
            (
                agreement.collisions_differ,
                agreement.side_differs,
                agreement.flags_differ
            ),
            (0, 0, 0),
            "wgpu differs from stepping without hints: {agreement:?}"
        );
        assert!(
            agreement.worst_leaves <= POSITION_TOLERANCE_LEAVES,
            "wgpu: {agreement:?}"
        );
    }
}

#[test]
fn every_workgroup_size_steps_the_same_bits() {
    // The plain step rebuilt with other workgroup sizes (what the bench sweeps) steps every
    // particle to the same bytes as the default size: each invocation steps one particle
    // alone. Chunks of 1000 particles in dispatch rows of 3 workgroups make every size
    // dispatch a folded grid whose last workgroups are partly empty. The split step (the
    // particles that settle, then the queued rest, dispatched indirectly) and the single
    // dispatch (the default) step the same bytes at every size.
    let Some(mut gpu) = gpu() else { return };
    let mesh = scenes::merge(&[
        scenes::wedge(8.0, 2.0, 1.0),
        scenes::flat_sheet([0.0, 0.6, 0.0], 1.6, 8),
    ]);
    let (words, _) = bake(&[MeshRef::from(&mesh)], &build(6), &()).expect("bakes");
    let view = ProxyView::new(&words).expect("valid");
    let gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
    let speeds: Vec<f32> = [0.1, 1.0, 5.0]
        .iter()
        .map(|d| d * view.finest_leaf_size() / DT)
        .collect();
    let particles = random_particles(&view, &gt, 5000, &speeds, 9);
    gpu.set_chunk_particles(1000);
    gpu.set_fold_width(3);
    gpu.upload_proxy(&words).unwrap();
    let params = StepParams {
        dt: DT,
        ..StepParams::default()
    };
    let run = |gpu: &mut WgpuBackend, size: u32, floor: bool, split: bool| {
        gpu.set_split_step(split);
        gpu.set_workgroup_size(size).unwrap();
        assert_eq!(gpu.workgroup_size(), size);
        gpu.upload_particles(&particles).unwrap();
        if floor {
            gpu.integrate_only(&params, 20).unwrap();
        } else {
            gpu.step(&params, 40).unwrap();
        }
        let mut out = vec![Particle::default(); particles.len()];
        gpu.download_particles(&mut out).unwrap();
        out
    };
    let default = gpu.workgroup_size();
    assert_eq!(
        default,
        octoproxy_wgpu::shader::STEP_WORKGROUP_SIZE
            .min(gpu.device().limits().max_compute_invocations_per_workgroup)
    );
    assert!(!gpu.split_step(), "one dispatch by default");
    let expected = run(&mut gpu, default, false, false);
    let expected_floor = run(&mut gpu, default, true, false);
    let collided = expected.iter().filter(|p| p.collisions() > 0).count();
    assert!(collided > 100, "only {collided} particles collided");
    for size in [1, 32, 64, 128, 256] {
        for split in [true, false] {
            if size == default && !split {
                continue;
            }
            for (floor, want) in [(false, &expected), (true, &expected_floor)] {
                let got = run(&mut gpu, size, floor, split);
                let differ = got
                    .iter()
                    .zip(want.iter())
                    .filter(|(g, e)| bytemuck::bytes_of(*g) != bytemuck::bytes_of(*e))
                    .count();
                assert_eq!(
                    differ, 0,
                    "workgroup size {size} (floor: {floor}, split: {split}): {differ} particles differ"
                );
            }
        }
    }
    gpu.set_split_step(false);
    gpu.set_workgroup_size(128).unwrap();
    for bad in [0, 48, 1 << 20] {
        let e = gpu.set_workgroup_size(bad).unwrap_err().to_string();
        assert!(e.contains(&format!("workgroup size {bad}")), "{e}");
    }
    assert_eq!(gpu.workgroup_size(), 128, "a refused size changes nothing");
}
