//! Scenes on the command line end to end: glTF files written by Blender and the Khronos
//! samples, `bake --scene` and the baked file, `sim --scene` with hit records, events and a
//! restart from its output, `check --scene`, and one-line errors for bad scenes.

mod common;

use std::path::Path;
use std::process::Output;

use common::{assert_one_line_error, octoproxy, scratch};
use octoproxy_cpu::io::read_particles;

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The glTF fixtures (`backend-cpu/tests/data/gltf`).
fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../backend-cpu/tests/data/gltf")
        .join(name)
        .display()
        .to_string()
}

/// The index of a property among a cloud's extra columns.
fn column(cloud: &octoproxy_cpu::io::ParticleCloud, name: &str) -> usize {
    cloud
        .extra
        .properties
        .iter()
        .position(|(n, _)| n == name)
        .unwrap_or_else(|| panic!("no {name} column"))
}

#[test]
fn list_instances_names_every_node_with_a_mesh_in_depth_first_order() {
    let dir = scratch("list");
    let text = ok(&octoproxy(
        &[
            "sim",
            "--scene",
            &fixture("blender/blender_keys.gltf"),
            "--list-instances",
        ],
        &dir,
    ));
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with(char::is_numeric))
        .collect();
    assert_eq!(rows.len(), 5, "{text}");
    for (i, name) in ["Parent", "Child", "DupStill", "DupStep", "DupLinear"]
        .iter()
        .enumerate()
    {
        assert!(rows[i].starts_with(&format!("{i}\t")), "{}", rows[i]);
        assert!(rows[i].contains(&format!("\"{name}\"")), "{}", rows[i]);
    }
    // The three Dup* share one mesh.
    assert!(rows[2..].iter().all(|r| r.contains("SharedIco")), "{text}");
}

#[test]
fn a_baked_scene_steps_with_hits_and_events_and_a_restart_continues_it() {
    let dir = scratch("baked");
    let d = &dir;
    let glb = fixture("blender/blender_sampled.glb");
    ok(&octoproxy(
        &[
            "bake",
            "--scene",
            &glb,
            "--dmax",
            "5",
            "-o",
            "scene.octoscene",
        ],
        d,
    ));
    let text = ok(&octoproxy(
        &[
            "sim",
            "--scene",
            "scene.octoscene",
            "--emit",
            "2000",
            "--emit-speed",
            "2",
            "--steps",
            "40",
            "--hits",
            "--events",
            "events.ply",
            "--frames",
            "frames",
            "--every",
            "20",
            "--backend",
            "cpu",
            "-o",
            "out.ply",
        ],
        d,
    ));
    assert!(text.contains("scene: 5 instances of 3 proxies"), "{text}");
    let out = read_particles(&d.join("out.ply")).unwrap();
    assert_eq!(out.particles.len(), 2000);
    let slot = column(&out, "scene_slot0");
    let hit = column(&out, "hit_instance");
    let hits = (0..out.particles.len())
        .filter(|&i| out.extra.row(i).unwrap()[hit] >= 0.0)
        .count();
    assert!(
        (0..out.particles.len()).all(|i| {
            let v = out.extra.row(i).unwrap()[hit];
            (-1.0..5.0).contains(&v)
        }),
        "hit_instance is an instance or -1"
    );
    // Every collision of every step is an event (none lost at this size).
    let collisions: u64 = out.particles.iter().map(|p| p.collisions() as u64).sum();
    let events = read_particles(&d.join("events.ply")).unwrap();
    assert_eq!(events.particles.len() as u64, collisions, "{text}");
    assert!(
        collisions > 0 && hits > 0,
        "{collisions} collisions, {hits} hits"
    );
    // Frame 0 has no hits; the last frame is the output.
    let first = read_particles(&d.join("frames/frame_00000.ply")).unwrap();
    let h0 = column(&first, "hit_instance");
    assert!((0..2000).all(|i| first.extra.row(i).unwrap()[h0] == -1.0));
    let last = read_particles(&d.join("frames/frame_00002.ply")).unwrap();
    assert_eq!(last.particles, out.particles);
    // Sides for some instance were kept.
    assert!((0..2000).any(|i| out.extra.row(i).unwrap()[slot] != u32::MAX as f64));

    // A restart from the output reads the sides back and goes on from its time.
    let text = ok(&octoproxy(
        &[
            "sim",
            "--scene",
            "scene.octoscene",
            "--particles",
            "out.ply",
            "--start-time",
            "0.6667",
            "--steps",
            "10",
            "--backend",
            "cpu",
            "-o",
            "again.ply",
        ],
        d,
    ));
    assert!(
        text.contains("sides: the file's, for every instance"),
        "{text}"
    );
    let again = read_particles(&d.join("again.ply")).unwrap();
    assert_eq!(again.particles.len(), 2000);
    // The columns are written once, not carried as extras and written again.
    assert_eq!(
        again
            .extra
            .properties
            .iter()
            .filter(|(n, _)| n == "scene_slot0")
            .count(),
        1
    );
    // Building a baked scene again is refused.
    assert_one_line_error(
        &octoproxy(
            &[
                "sim",
                "--scene",
                "scene.octoscene",
                "--dmax",
                "6",
                "--emit",
                "10",
                "-o",
                "x.ply",
            ],
            d,
        ),
        "is baked already",
    );
}

#[test]
fn a_scene_baked_for_a_radius_bakes_once_per_world_scale_and_steps_at_that_radius() {
    let dir = scratch("radius");
    let d = &dir;
    let gltf = fixture("blender/blender_keys.gltf");
    let text = ok(&octoproxy(
        &[
            "bake",
            "--scene",
            &gltf,
            "--dmax",
            "6",
            "--radius",
            "0.12",
            "-o",
            "r.octoscene",
        ],
        d,
    ));
    // Box and Cone at scale 1.5, the icosphere at 0.75 and 1.
    assert!(text.contains("baked 4 proxies"), "{text}");
    let text = ok(&octoproxy(
        &[
            "sim",
            "--scene",
            "r.octoscene",
            "--emit",
            "1500",
            "--emit-speed",
            "2",
            "--steps",
            "30",
            "--backend",
            "cpu",
            "-o",
            "out.ply",
        ],
        d,
    ));
    assert!(text.contains("scene: 5 instances of 4 proxies"), "{text}");
    assert!(
        text.contains("built the offset surfaces of 4 proxies"),
        "{text}"
    );
    assert!(
        text.contains("were moved out along the way from their nearest surface point"),
        "{text}"
    );
    assert!(text.contains("from its offset surface"), "{text}");
    assert_eq!(
        read_particles(&d.join("out.ply")).unwrap().particles.len(),
        1500
    );
    // Grains that collide with each other, in the animated scene, with hit records.
    let text = ok(&octoproxy(
        &[
            "sim",
            "--scene",
            "r.octoscene",
            "--emit",
            "400",
            "--emit-box",
            "-1,1.5,-1,1,3,1",
            "--collide-particles",
            "--hits",
            "--steps",
            "20",
            "--backend",
            "cpu",
            "-o",
            "grains.ply",
        ],
        d,
    ));
    assert!(text.contains("particle pass: "), "{text}");
    let grains = read_particles(&d.join("grains.ply")).unwrap();
    assert_eq!(grains.particles.len(), 400);
    column(&grains, "hit_instance");
    // The check: paths against each instance's offset surface, ends against its mesh.
    let text = ok(&octoproxy(
        &["check", "--scene", "r.octoscene", "--emit", "1500"],
        d,
    ));
    assert!(text.contains("penetrations: 0"), "{text}");
    assert!(
        text.contains("0 nearer than the radius less a leaf diagonal"),
        "{text}"
    );
    let text = ok(&octoproxy(
        &[
            "check",
            "--scene",
            "r.octoscene",
            "--emit",
            "1000",
            "--collide-particles",
        ],
        d,
    ));
    assert!(text.contains("the particle pass: on"), "{text}");
    assert!(text.contains("penetrations: 0"), "{text}");
    // Another radius against the baked one names the file.
    assert_one_line_error(
        &octoproxy(
            &[
                "sim",
                "--scene",
                "r.octoscene",
                "--radius",
                "0.2",
                "--emit",
                "10",
                "-o",
                "x.ply",
            ],
            d,
        ),
        "r.octoscene: baked for particles of radius 0.12, but --radius is 0.2",
    );
    assert_one_line_error(
        &octoproxy(
            &[
                "sim",
                "--scene",
                "r.octoscene",
                "--radius",
                "-1",
                "--emit",
                "10",
                "-o",
                "x.ply",
            ],
            d,
        ),
        "--radius must be a finite number >= 0, got -1",
    );
}

#[test]
fn a_scene_steps_the_same_on_the_gpu_as_on_the_cpu() {
    let dir = scratch("gpu");
    let d = &dir;
    let gltf = fixture("blender/blender_keys.gltf");
    let run = |backend: &str, out: &str| {
        octoproxy(
            &[
                "sim",
                "--scene",
                &gltf,
                "--dmax",
                "5",
                "--emit",
                "1500",
                "--emit-speed",
                "3",
                "--steps",
                "24",
                "--hits",
                "--backend",
                backend,
                "-o",
                out,
            ],
            d,
        )
    };
    let gpu = run("wgpu", "gpu.ply");
    if !gpu.status.success() {
        let err = String::from_utf8_lossy(&gpu.stderr);
        if std::env::var("CI").as_deref() == Ok("true") || !err.contains("GPU adapter") {
            panic!("sim --backend wgpu failed: {err}");
        }
        eprintln!("skipped: {err}");
        return;
    }
    ok(&run("cpu", "cpu.ply"));
    let (a, b) = (
        read_particles(&d.join("cpu.ply")).unwrap(),
        read_particles(&d.join("gpu.ply")).unwrap(),
    );
    assert_eq!(a.particles.len(), b.particles.len());
    let collisions: u64 = a.particles.iter().map(|p| p.collisions() as u64).sum();
    assert!(collisions > 0);
    let gpu_text = String::from_utf8_lossy(&gpu.stderr);
    if gpu_text.contains("llvmpipe") {
        // On lavapipe, the same bytes (particles, sides and hits).
        assert_eq!(a, b);
    } else {
        for (p, q) in a.particles.iter().zip(&b.particles) {
            assert_eq!(p.collisions(), q.collisions());
        }
    }
}

#[test]
fn check_scene_finds_no_penetration_in_animated_gltf_scenes() {
    let dir = scratch("check");
    for (file, steps) in [
        ("blender/blender_sampled.glb", "60"),
        ("khronos/AnimatedTriangle.gltf", "60"),
        ("khronos/SimpleMeshes.gltf", "30"),
    ] {
        let text = ok(&octoproxy(
            &[
                "check",
                "--scene",
                &fixture(file),
                "--dmax",
                "6",
                "--emit",
                "3000",
                "--steps",
                steps,
            ],
            &dir,
        ));
        assert!(text.contains("penetrations: 0"), "{file}: {text}");
    }
}

#[test]
fn bad_scenes_get_one_readable_line() {
    let dir = scratch("bad");
    let d = &dir;
    // A skin is a deforming mesh: the node is named.
    assert_one_line_error(
        &octoproxy(
            &[
                "sim",
                "--scene",
                &fixture("khronos/SimpleSkin.gltf"),
                "--emit",
                "10",
                "-o",
                "o.ply",
            ],
            d,
        ),
        "deforming meshes",
    );
    assert_one_line_error(
        &octoproxy(
            &["check", "--scene", &fixture("khronos/SimpleMorph.gltf")],
            d,
        ),
        "not supported yet",
    );
    // A scene too far from the origin for f32 at its dmax fails before its first step,
    // naming the file and the node.
    let far = r#"{"asset": {"version": "2.0"}, "buffers": [{"uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAAAAAAAAIA/AAACAAEAAAABAAMAAAADAAIAAQACAAMA", "byteLength": 72}], "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 24}], "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}, {"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"}], "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}], "nodes": [{"name": "far", "mesh": 0, "translation": [1000000.0, 0, 0]}], "scenes": [{"nodes": [0]}], "scene": 0}"#;
    std::fs::write(d.join("far.gltf"), far).unwrap();
    assert_one_line_error(
        &octoproxy(
            &["sim", "--scene", "far.gltf", "--emit", "10", "-o", "o.ply"],
            d,
        ),
        "far.gltf: the scene at 0 s, before the first step: instance 0 is too far",
    );
    let out = octoproxy(&["check", "--scene", "far.gltf"], d);
    assert_one_line_error(&out, "far.gltf: the scene at 0 s");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains(r#"(instance 0 is node 0 "far", mesh 0)"#)
    );
    // Scale 0 hides a node (glTF's way): it runs, and says so.
    std::fs::write(
        d.join("hidden.gltf"),
        far.replace(
            r#""translation": [1000000.0, 0, 0]"#,
            r#""scale": [0, 0, 0]"#,
        ),
    )
    .unwrap();
    let out = octoproxy(
        &[
            "sim",
            "--scene",
            "hidden.gltf",
            "--emit",
            "10",
            "-o",
            "o.ply",
        ],
        d,
    );
    let said = ok(&out);
    assert!(
        said.contains(r#"1 of 1 instances have scale 0 throughout, hidden: particles pass where they are (instance 0 is node 0 "far", mesh 0)"#),
        "{said}"
    );
    // One flung that far in its first step: the step and the node are named.
    let flung = r#"{"asset": {"version": "2.0"}, "buffers": [{"uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAAAAAAAAIA/AAACAAEAAAABAAMAAAADAAIAAQACAAMAAAAAAAAAgD8AAAAAAAAAAAAAAAAAJHRJAAAAAAAAAAA=", "byteLength": 104}], "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 24}, {"buffer": 0, "byteOffset": 72, "byteLength": 8}, {"buffer": 0, "byteOffset": 80, "byteLength": 24}], "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}, {"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"}, {"bufferView": 2, "componentType": 5126, "count": 2, "type": "SCALAR", "min": [0], "max": [1]}, {"bufferView": 3, "componentType": 5126, "count": 2, "type": "VEC3"}], "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}], "nodes": [{"name": "flung", "mesh": 0, "translation": [0, 0, 0]}], "scenes": [{"nodes": [0]}], "scene": 0, "animations": [{"samplers": [{"input": 2, "output": 3}], "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}]}]}"#;
    std::fs::write(d.join("flung.gltf"), flung).unwrap();
    for command in ["sim", "check"] {
        let mut args = vec![command, "--scene", "flung.gltf"];
        if command == "sim" {
            args.extend(["--emit", "10", "-o", "o.ply"]);
        }
        let out = octoproxy(&args, d);
        assert_one_line_error(
            &out,
            "flung.gltf: step 1 (to 0.0167 s): instance 0 is too far",
        );
        assert!(
            String::from_utf8_lossy(&out.stderr)
                .contains(r#"(instance 0 is node 0 "flung", mesh 0)"#),
            "{command}"
        );
    }
    // A truncated GLB names the file.
    let glb = std::fs::read(fixture("blender/blender_sampled.glb")).unwrap();
    std::fs::write(d.join("cut.glb"), &glb[..glb.len() / 2]).unwrap();
    assert_one_line_error(
        &octoproxy(
            &["sim", "--scene", "cut.glb", "--emit", "10", "-o", "o.ply"],
            d,
        ),
        "cut.glb",
    );
    // A damaged baked scene names the file.
    std::fs::write(d.join("bad.octoscene"), b"OCTOSCN\0 not a scene").unwrap();
    assert_one_line_error(
        &octoproxy(
            &[
                "sim",
                "--scene",
                "bad.octoscene",
                "--emit",
                "10",
                "-o",
                "o.ply",
            ],
            d,
        ),
        "bad.octoscene",
    );
    // check --scene takes built-in names and scene files, nothing else.
    assert_one_line_error(
        &octoproxy(&["check", "--scene", "teapot.obj"], d),
        "nor a scene file (.gltf, .glb, .octoscene)",
    );
    assert_one_line_error(
        &octoproxy(&["bake", "--scene", "teapot.obj", "-o", "x.octoscene"], d),
        "bake reads glTF 2.0 scenes",
    );
    assert_one_line_error(
        &octoproxy(&["sim", "--mesh", "a.obj", "--list-instances"], d),
        "--list-instances goes with --scene",
    );
    assert_one_line_error(
        &octoproxy(
            &[
                "sim",
                "--scene",
                &fixture("khronos/Box.gltf"),
                "--emit",
                "10",
                "--event-capacity",
                "5",
                "-o",
                "o.ply",
            ],
            d,
        ),
        "--event-capacity goes with --events",
    );
    assert_one_line_error(
        &octoproxy(
            &[
                "sim",
                "--scene",
                &fixture("khronos/Box.gltf"),
                "--proxy",
                "p",
                "-o",
                "o.ply",
            ],
            d,
        ),
        "give one of --mesh, --proxy and --scene",
    );
}

#[test]
fn an_instance_that_appears_is_checked_from_where_it_shows() {
    // A tetrahedron hidden (scale 0) at the start and shown from 0.05 s: the check spreads
    // its particles and speeds over where it shows (it had none to measure at the start,
    // and emitted infinite speeds), and particles it swallows as it appears are counted
    // apart, not as penetrations.
    let dir = scratch("appear");
    let appear = r#"{"asset": {"version": "2.0"}, "buffers": [{"uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAAAAAAAAIA/AAACAAEAAAABAAMAAAADAAIAAQACAAMAAAAAAM3MTD0AAAAAAAAAAAAAAAAAAIA/AACAPwAAgD8=", "byteLength": 104}], "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48}, {"buffer": 0, "byteOffset": 48, "byteLength": 24}, {"buffer": 0, "byteOffset": 72, "byteLength": 8}, {"buffer": 0, "byteOffset": 80, "byteLength": 24}], "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}, {"bufferView": 1, "componentType": 5123, "count": 12, "type": "SCALAR"}, {"bufferView": 2, "componentType": 5126, "count": 2, "type": "SCALAR", "min": [0], "max": [0.05]}, {"bufferView": 3, "componentType": 5126, "count": 2, "type": "VEC3"}], "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}], "nodes": [{"name": "pops", "mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0, "animations": [{"samplers": [{"input": 2, "output": 3, "interpolation": "STEP"}], "channels": [{"sampler": 0, "target": {"node": 0, "path": "scale"}}]}]}"#;
    std::fs::write(dir.join("appear.gltf"), appear).unwrap();
    let out = octoproxy(
        &[
            "check",
            "--scene",
            "appear.gltf",
            "--emit",
            "3000",
            "--steps",
            "20",
            "--dmax",
            "6",
        ],
        &dir,
    );
    let said = ok(&out);
    assert!(said.contains("penetrations: 0 "), "{said}");
    assert!(said.contains("NaN or infinite: 0 "), "{said}");
    let swallowed: usize = said
        .split("swallowed: ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count of swallowed particles: {said}"));
    assert!(swallowed > 20, "{said}");
    // Hidden throughout: nothing to check, said so.
    std::fs::write(
        dir.join("never.gltf"),
        appear
            .replace(r#""path": "scale""#, r#""path": "translation""#)
            .replace(r#""mesh": 0}"#, r#""mesh": 0, "scale": [0, 0, 0]}"#),
    )
    .unwrap();
    let out = octoproxy(&["check", "--scene", "never.gltf", "--emit", "10"], &dir);
    assert_one_line_error(&out, "no instance of the scene shows");
}
