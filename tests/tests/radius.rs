//! Particles of a radius: a proxy baked for the offset surface at the radius keeps every
//! centre at least the radius less a `dmax`-leaf diagonal from the mesh, checked against the
//! mesh's exact distance (never against the proxy), wherever the particles start: anywhere
//! in the scene's box (those nearer than the radius moved out by the documented rule),
//! emitted from the surface, at speeds from a tenth of a leaf to the whole scene per step.
//! And the radius is a checked parameter: mismatches and bad values are clear errors.

use glam::Vec3;
use octoproxy_core::format::header;
use octoproxy_core::{
    step_particle_traced, Backend, FormatError, ParamError, Particle, Pose, ProxyView, SceneError,
    StepParams,
};
use octoproxy_cpu::bake::offset::OffsetSurface;
use octoproxy_cpu::emit::{emit_surface_for, Rng};
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::io::Mesh;
use octoproxy_cpu::sides::in_solid_leaf;
use octoproxy_cpu::{
    bake, bake_offset, bake_with_radius, scenes, BuildError, BuildParams, CpuBackend, CpuError,
    MeshRef, Scene, SceneStepError, Sides,
};
use octoproxy_tests::meshes;

/// What one scene's campaign found.
struct Found {
    particles: usize,
    pieces: usize,
    /// The least distance from a centre to the mesh, over every sampled point of every path.
    nearest: f64,
    /// Points nearer than the radius less a leaf diagonal.
    too_near: usize,
    /// Steps that ended on the other side of a closed part than they began.
    crossed: usize,
    moved: usize,
    stuck: usize,
    radius: f64,
    leaf: f64,
}

/// Bakes `meshes` for a radius of `leaves` `dmax` leaves (of the plain proxy), starts
/// particles as a user would, steps them `steps` times and checks every piece of every path.
fn campaign(meshes: &[Mesh], dmax: u32, leaves: f32, n: usize, steps: u32, seed: u64) -> Found {
    let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
    let params = BuildParams {
        dmax,
        ..BuildParams::default()
    };
    let (plain, _) = bake(&refs, &params, &()).unwrap();
    let plain_leaf = ProxyView::new(&plain).unwrap().finest_leaf_size();
    let radius = leaves * plain_leaf;
    let surface = OffsetSurface::new(&refs, radius, dmax, &()).unwrap();
    let (words, report) = bake_offset(&surface, &params, &()).unwrap();
    let view = ProxyView::new(&words).unwrap();
    assert_eq!(view.header().radius, radius);
    assert_eq!(report.offset_triangles, surface.mesh().triangles.len());
    // The offset surface is closed, and within h√3 of the radius; h is at most a leaf.
    assert_eq!(report.closed_triangles, report.offset_triangles);
    let leaf = view.finest_leaf_size() as f64;
    let h = surface.mesh().spacing;
    assert!(h <= leaf, "grid {h} coarser than the leaf {leaf}");
    let all = scenes::merge(meshes);
    let gt = GroundTruth::new(&all.positions, &all.triangles);
    let slack = h * 3f64.sqrt();
    for v in surface.mesh().positions.iter().step_by(97) {
        let d = gt.distance(*v);
        assert!(
            d >= radius as f64 - slack * 1.0001 && d <= radius as f64 + slack * 1.0001,
            "an offset vertex at {d} from the mesh, radius {radius}, slack {slack}"
        );
    }

    // Starts: anywhere in the root cube, and emitted from the surface.
    let hd = view.header();
    let size = hd.root_size;
    let dt = 1.0 / 60.0;
    let mut rng = Rng::new(seed);
    let mut ps: Vec<Particle> = (0..n)
        .map(|i| {
            let p = Vec3::from_array(hd.root_min.to_array())
                + Vec3::new(rng.f32(), rng.f32(), rng.f32()) * size;
            // A tenth of a leaf to the whole scene per step.
            let per_step = if i % 4 == 0 {
                size * rng.f32()
            } else {
                leaf as f32 * rng.range(0.1, 5.0)
            };
            Particle::new(p.to_array(), (rng.unit_vector() * per_step / dt).to_array())
        })
        .collect();
    let emitted = emit_surface_for(&view, n / 2, &refs, Some(&surface), size / dt * 0.05, seed)
        .expect("fits in memory");
    assert!(!emitted.is_empty());
    for e in &emitted {
        let d = gt.distance(e.position);
        assert!(
            d >= radius as f64 && d <= radius as f64 + leaf * 1.0001,
            "emitted at {d} from the mesh, radius {radius}, leaf {leaf}"
        );
    }
    ps.extend(emitted);
    let raw = ps.clone();
    let placed = surface.place(&mut ps, Some(&view));
    let offset_mesh = [surface.mesh_ref()];
    let sides = Sides::new(&offset_mesh);
    // The offset surface's own sides and cages (by its band, with no ground truth of its
    // own unless a particle is in a solid leaf) are those of its mesh: placed, and where the
    // particles started (many in the band, some in solid leaves).
    for (what, set) in [("placed", &ps), ("unplaced", &raw)] {
        let (mut a, mut b) = (set.clone(), set.clone());
        let counts = (
            sides.assign(&mut a, false),
            sides.cages(&view, &mut a, false),
        );
        let band = (
            surface.assign_sides(&mut b, false),
            surface.cages(&view, &mut b, false),
        );
        assert_eq!(counts, band, "{what}");
        let differ = a.iter().zip(&b).filter(|(p, q)| p.side != q.side).count();
        assert_eq!(differ, 0, "{what}: sides or cages differ");
        eprintln!("{what}: {counts:?}");
    }
    sides.assign(&mut ps, false);
    sides.cages(&view, &mut ps, false);

    let closed = scenes::is_closed(&all);
    let step = StepParams {
        gravity: [0.0, -size * 2.0, 0.0],
        dt,
        radius,
        ..StepParams::default()
    };
    let bound = radius as f64 - leaf * 3f64.sqrt();
    let mut found = Found {
        particles: ps.len(),
        pieces: 0,
        nearest: f64::INFINITY,
        too_near: 0,
        crossed: 0,
        moved: placed.moved,
        stuck: placed.stuck,
        radius: radius as f64,
        leaf,
    };
    // Particles left inside the band are behind the offset surface: no claim is made there.
    let mut live: Vec<Particle> = ps
        .into_iter()
        .filter(|p| surface.outside(p.position))
        .collect();
    for p in &live {
        let d = gt.distance(p.position);
        assert!(
            d >= radius as f64 - slack,
            "a start at {d} outside the band"
        );
        assert!(!in_solid_leaf(&view, p.position) || p.is_caged());
    }
    for _ in 0..steps {
        for p in live.iter_mut() {
            let inside_before = closed && gt.is_inside(p.position);
            let mut pieces = Vec::new();
            step_particle_traced(&view, p, &step, &mut |a: Vec3, b: Vec3| pieces.push((a, b)));
            for (a, b) in pieces {
                found.pieces += 1;
                for k in 0..=4 {
                    let x = a.lerp(b, k as f32 / 4.0).to_array();
                    let d = gt.distance(x);
                    found.nearest = found.nearest.min(d);
                    if d < bound {
                        found.too_near += 1;
                    }
                }
            }
            if closed && gt.is_inside(p.position) != inside_before {
                found.crossed += 1;
            }
        }
    }
    found
}

fn check(name: &str, f: Found) {
    eprintln!(
        "{name}: {} particles ({} moved out of the band, {} stuck), {} pieces; radius {:.2} leaves, the nearest centre at {:.2} leaves (the bound: {:.2})",
        f.particles,
        f.moved,
        f.stuck,
        f.pieces,
        f.radius / f.leaf,
        f.nearest / f.leaf,
        f.radius / f.leaf - 3f64.sqrt()
    );
    assert_eq!(
        f.too_near, 0,
        "{name}: points nearer than the radius less a leaf diagonal"
    );
    assert_eq!(f.crossed, 0, "{name}: steps into or out of a closed part");
    assert!(
        f.pieces > f.particles,
        "{name}: too few pieces to mean anything"
    );
}

#[test]
fn an_open_sheet_and_fins_through_a_plate_keep_centres_at_the_radius() {
    let sheet = vec![scenes::flat_sheet([0.0; 3], 1.0, 4)];
    check("sheet", campaign(&sheet, 6, 2.0, 1500, 30, 1));
    let mut fins = vec![scenes::slab([0.0; 3], [2.0, 0.2, 2.0])];
    fins.extend((0..4).map(|i| scenes::slab([i as f32 * 0.4 - 0.6, 0.2, 0.0], [0.01, 0.8, 1.5])));
    check("fins through a plate", campaign(&fins, 6, 2.0, 1500, 30, 2));
    let star = vec![scenes::star_prism(7, 1.5, 0.4, 1.0)];
    check("star prism", campaign(&star, 6, 2.0, 1500, 30, 3));
}

#[test]
fn shared_meshes_keep_centres_at_the_radius() {
    for (name, leaves) in [("stanford-bunny.obj.gz", 3.0), ("spot.obj.gz", 2.0)] {
        let Some(mesh) = meshes::load(name) else {
            return;
        };
        check(name, campaign(&[mesh], 6, leaves, 1500, 30, 4));
    }
}

/// A cube, for the error cases.
fn cube_proxy(radius: f32) -> Vec<u32> {
    let cube = scenes::cube([0.0; 3], [1.0; 3]);
    let refs = [MeshRef::from(&cube)];
    let params = BuildParams {
        dmax: 5,
        ..BuildParams::default()
    };
    bake_with_radius(&refs, &params, radius, &()).unwrap().0
}

#[test]
fn the_radius_is_checked_like_every_parameter() {
    for r in [-0.1, f32::NAN, f32::INFINITY] {
        let p = StepParams {
            radius: r,
            ..StepParams::default()
        };
        assert!(matches!(p.validate(), Err(ParamError::BadRadius(_))), "{r}");
    }
    let cube = scenes::cube([0.0; 3], [1.0; 3]);
    let refs = [MeshRef::from(&cube)];
    // 1e-3 is far below a leaf's diagonal of the unit cube at dmax 8.
    for r in [-0.1, f32::NAN, f32::INFINITY, 1e4, 1e-3] {
        let e = bake_with_radius(&refs, &BuildParams::default(), r, &()).unwrap_err();
        assert!(matches!(e, BuildError::BadParam(_)), "{r}: {e}");
        assert!(e.to_string().contains("radius"), "{e}");
    }
    // A hostile header: a NaN or negative radius does not validate.
    let mut words = cube_proxy(0.1);
    for bad in [f32::NAN.to_bits(), (-1.0f32).to_bits(), (-0.0f32).to_bits()] {
        words[header::RADIUS] = bad;
        octoproxy_core::format::seal(&mut words);
        assert_eq!(
            ProxyView::new(&words).unwrap_err(),
            FormatError::BadHeader {
                word: header::RADIUS,
                value: bad
            }
        );
    }
}

#[test]
fn particles_of_another_radius_are_refused() {
    let words = cube_proxy(0.1);
    let mut cpu = CpuBackend::new();
    cpu.upload_proxy(&words).unwrap();
    cpu.upload_particles(&[Particle::new([2.0, 0.5, 0.5], [-1.0, 0.0, 0.0])])
        .unwrap();
    let with = |radius: f32| StepParams {
        radius,
        ..StepParams::default()
    };
    let e = cpu.step(&with(0.0), 1).unwrap_err();
    assert!(matches!(e, CpuError::Radius(_)), "{e}");
    assert!(e.to_string().contains("baked for radius 0.1"), "{e}");
    assert!(matches!(cpu.step(&with(0.2), 1), Err(CpuError::Radius(_))));
    cpu.step(&with(0.1), 1).unwrap();
    // A point proxy refuses particles of a radius.
    let cube = scenes::cube([0.0; 3], [1.0; 3]);
    let (points, _) = bake(&[MeshRef::from(&cube)], &BuildParams::default(), &()).unwrap();
    cpu.upload_proxy(&points).unwrap();
    assert!(matches!(cpu.step(&with(0.1), 1), Err(CpuError::Radius(_))));
}

#[test]
fn an_instance_scales_its_radius_and_may_not_scale_in_a_step() {
    let words = cube_proxy(0.1);
    let mut scene = Scene::new();
    let proxy = scene.add_proxy(words).unwrap();
    let pose = |scale: f32| Pose {
        translation: [0.0; 3],
        scale,
        rotation: [0.0, 0.0, 0.0, 1.0],
    };
    let i = scene.add_instance(proxy, pose(2.0)).unwrap();
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&[Particle::new([5.0, 1.0, 1.0], [-1.0, 0.0, 0.0])])
        .unwrap();
    let with = |radius: f32| StepParams {
        radius,
        ..StepParams::default()
    };
    // Twice the size: twice the radius.
    scene.step(&mut cpu, &with(0.2), false).unwrap();
    let e = scene.step(&mut cpu, &with(0.1), false).unwrap_err();
    assert!(
        matches!(
            e,
            SceneStepError::Backend(CpuError::Scene(SceneError::RadiusMismatch {
                instance: 0,
                ..
            }))
        ),
        "{e}"
    );
    scene.set_motion(i, pose(2.0), pose(2.5)).unwrap();
    let e = scene.step(&mut cpu, &with(0.2), false).unwrap_err();
    assert!(
        matches!(
            e,
            SceneStepError::Backend(CpuError::Scene(SceneError::ScaledRadius { instance: 0 }))
        ),
        "{e}"
    );
}

/// A glTF scene baked for a radius: instances at world scales 1.5 (one a child of a scaled,
/// turning parent), 0.75 and 1, three of them animated. Particles start anywhere around it
/// (those in a band moved out), fall and fly at up to a third of the scene per step, and
/// every step of every path is checked against each instance's offset surface in its own
/// frame at the pose of each moment (the scene harness: no crossing deeper than a leaf
/// diagonal), and every step's end against each instance's own mesh, exactly: no centre
/// nearer than the radius less a leaf diagonal, in world units.
#[test]
fn a_gltf_scene_baked_for_a_radius_keeps_centres_at_the_radius_from_every_scaled_moving_instance() {
    use octoproxy_cpu::gltf::{bake_scene_for_radius, load_gltf};
    use octoproxy_cpu::harness::scene::{traced_pieces, SceneCheck};
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../backend-cpu/tests/data/gltf/blender/blender_keys.gltf"
    );
    let (description, _) = load_gltf(std::path::Path::new(path)).unwrap();
    let radius = 0.12;
    let params = BuildParams {
        dmax: 6,
        ..BuildParams::default()
    };
    let (baked, _, offsets) = bake_scene_for_radius(&description, &params, radius, &()).unwrap();
    // Box and Cone at 1.5, the icosphere at 0.75 and at 1: four proxies for three meshes.
    assert_eq!(baked.proxies().len(), 4);
    let (mut scene, _) = baked.build_scene().unwrap();
    let views: Vec<ProxyView<'_>> = baked
        .proxies()
        .iter()
        .map(|p| ProxyView::new(&p.words).unwrap())
        .collect();
    let offset_refs: Vec<MeshRef<'_>> = offsets.iter().map(|o| o.mesh_ref()).collect();
    let mut check = SceneCheck::new(&offset_refs, &vec![true; offsets.len()], &views);
    let truths: Vec<GroundTruth> = baked
        .proxies()
        .iter()
        .map(|p| {
            let m = &baked.meshes()[p.mesh as usize].mesh;
            GroundTruth::new(&m.positions, &m.triangles)
        })
        .collect();
    // Every instance at its pose at time `t`, the scene checked.
    let pose_at = |scene: &mut Scene, t: f64| {
        for (i, pose) in baked.poses_at(t).unwrap().into_iter().enumerate() {
            scene.move_to(i as u32, pose).unwrap();
        }
        scene.prepare().unwrap();
    };
    // A centre's exact distance from an instance's mesh in world units (at its end pose),
    // the least the guarantee allows (the radius less a leaf diagonal, in world units), and
    // whether it is inside the mesh.
    let world_distance = |inst: &octoproxy_core::Instance, p: &Particle| {
        let k = inst.proxy as usize;
        let l = inst.end.to_local(Vec3::from_array(p.position)).to_array();
        let s = inst.end.scale as f64;
        let diagonal = 3f64.sqrt() * views[k].finest_leaf_size() as f64 * s;
        (
            truths[k].distance(l) * s,
            radius as f64 - diagonal,
            truths[k].is_inside(l),
        )
    };

    // Starts in the scene's box, with sides from the offset surfaces.
    let (lo, hi) = (Vec3::new(-5.0, -1.5, -3.5), Vec3::new(6.0, 3.5, 3.5));
    let dt = 1.0 / 30.0;
    let mut rng = octoproxy_cpu::emit::Rng::new(7);
    let mut ps: Vec<Particle> = (0..3000)
        .map(|_| {
            let p = lo + Vec3::new(rng.f32(), rng.f32(), rng.f32()) * (hi - lo);
            let v = rng.unit_vector() * rng.range(0.01, 3.5) / dt;
            Particle::new(p.to_array(), v.to_array())
        })
        .collect();
    let placed = octoproxy_cpu::place_in_bands(&scene, &offsets, &mut ps);
    assert!(placed.moved > 0, "no start was in a band");
    let sides_by_proxy: Vec<Sides> = offsets
        .iter()
        .map(|o| Sides::new(&[o.mesh_ref()]))
        .collect();
    let (sides, _) = octoproxy_cpu::starting_scene_sides(&scene, &sides_by_proxy, &ps);
    // The offset surfaces answer from their bands what their meshes answer.
    let (by_band, _) = octoproxy_cpu::starting_scene_sides(&scene, &offsets, &ps);
    assert!(
        sides == by_band,
        "the bands' sides differ from the offset meshes'"
    );
    // Those wedged between bands start behind an offset surface: no claim is made for them.
    let keep: Vec<bool> = ps
        .iter()
        .map(|p| {
            scene.instances().iter().all(|inst| {
                let k = inst.proxy as usize;
                let l = inst.start.to_local(Vec3::from_array(p.position)).to_array();
                !inst.is_active() || offsets[k].outside(l) || !in_root(&views[k], l)
            })
        })
        .collect();
    let ps: Vec<Particle> = ps
        .iter()
        .zip(&keep)
        .filter(|k| *k.1)
        .map(|k| *k.0)
        .collect();
    let sides: Vec<_> = sides
        .iter()
        .zip(&keep)
        .filter(|k| *k.1)
        .map(|k| *k.0)
        .collect();
    assert_eq!(ps.len(), 3000 - placed.stuck);

    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&ps).unwrap();
    cpu.upload_scene_sides(&sides).unwrap();
    check.begin(scene.instances(), &ps);
    let step = StepParams {
        gravity: [0.0, -9.81, 0.0],
        dt,
        radius,
        ..StepParams::default()
    };
    let mut before = ps;
    let (mut nearest, mut too_near, mut crushed, mut penetrations) = (f64::INFINITY, 0, 0, 0);
    let steps = (baked.duration() / dt as f64).ceil() as u32;
    for k in 1..=steps {
        pose_at(&mut scene, k as f64 * dt as f64);
        let instances = scene.instances().to_vec();
        let sides = cpu.scene_sides();
        scene.step(&mut cpu, &step, false).unwrap();
        let after = cpu.particles().to_vec();
        let mut replay = scene.clone();
        for (i, inst) in instances.iter().enumerate() {
            replay.set_motion(i as u32, inst.start, inst.end).unwrap();
        }
        let (pieces, differ) = replay
            .with_view(|view| traced_pieces(view, &before, &sides, &after, &step))
            .unwrap();
        assert!(differ.is_empty(), "the traced step differs for {differ:?}");
        let tally = check.step(&instances, &before, &after, Some(&pieces));
        penetrations += tally.penetrations;
        crushed += tally.crushed;
        assert_eq!(tally.penetrations, 0, "step {k}: {:?}", tally.examples);
        for p in after
            .iter()
            .filter(|p| p.flags & octoproxy_core::scene::FLAG_CRUSHED == 0)
        {
            for inst in instances.iter().filter(|i| i.is_active()) {
                let (d, bound, _) = world_distance(inst, p);
                nearest = nearest.min(d);
                too_near += (d < bound) as usize;
            }
        }
        before = after;
    }
    eprintln!(
        "glTF scene at radius {radius}: {} particles ({} moved out of a band, {} wedged and left out), {steps} steps; the nearest centre {nearest:.4}; {crushed} particle-steps crushed",
        before.len(),
        placed.moved,
        placed.stuck
    );
    assert_eq!(penetrations, 0);
    assert_eq!(
        too_near, 0,
        "centres nearer than the radius less a leaf diagonal"
    );

    // Again with the particle-particle pass: grains poured over the scene collide with each
    // other and with the moving, scaled instances. The pass changes velocities, the march
    // comes last: every step's end (exact distance, winding numbers) keeps the guarantee.
    let mut grains: Vec<Particle> = Vec::new();
    for iy in 0..6 {
        for iz in 0..14 {
            for ix in 0..40 {
                let x = Vec3::new(
                    -4.5 + ix as f32 * 0.25,
                    2.0 + iy as f32 * 0.25,
                    -1.7 + iz as f32 * 0.25,
                );
                grains.push(Particle::new(x.to_array(), [0.0; 3]));
            }
        }
    }
    let (mut scene, _) = baked.build_scene().unwrap();
    let placed = octoproxy_cpu::place_in_bands(&scene, &offsets, &mut grains);
    let (sides, _) = octoproxy_cpu::starting_scene_sides(&scene, &sides_by_proxy, &grains);
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&grains).unwrap();
    cpu.upload_scene_sides(&sides).unwrap();
    let pairs = octoproxy_core::PairParams::default();
    let (mut nearest, mut too_near, mut inside, mut crushed) = (f64::INFINITY, 0, 0, 0);
    for k in 1..=steps {
        pose_at(&mut scene, k as f64 * dt as f64);
        let instances = scene.instances().to_vec();
        scene.step_pairs(&mut cpu, &step, &pairs, false).unwrap();
        for p in cpu.particles() {
            if p.flags & octoproxy_core::scene::FLAG_CRUSHED != 0 {
                crushed += 1;
                continue;
            }
            for inst in instances.iter().filter(|i| i.is_active()) {
                let (d, bound, is_inside) = world_distance(inst, p);
                nearest = nearest.min(d);
                too_near += (d < bound) as usize;
                inside += is_inside as usize;
            }
        }
    }
    let report = cpu.take_pair_report().unwrap();
    eprintln!(
        "with the pass: {} grains ({} moved out of a band), {steps} steps, {report:?}; the nearest centre {nearest:.4}; {crushed} particle-steps crushed",
        grains.len(),
        placed.moved
    );
    assert!(report.substeps > report.steps);
    assert_eq!(
        too_near, 0,
        "with the pass: centres nearer than the radius less a leaf diagonal"
    );
    assert_eq!(inside, 0, "with the pass: centres inside a closed mesh");
}

fn in_root(view: &ProxyView<'_>, l: [f32; 3]) -> bool {
    let r = view.root_aabb();
    let l = Vec3::from_array(l);
    l.cmpge(r.min).all() && l.cmple(r.max).all()
}
