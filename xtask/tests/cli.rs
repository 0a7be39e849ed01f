//! The command line end to end: the demo, bake → sim round trips, frames, and readable
//! one-line errors for bad input.

mod common;

use std::path::Path;

use common::{assert_one_line_error, octoproxy, scratch};

/// A closed box as ascii OBJ (outward faces, quads).
const BOX_OBJ: &str =
    "v -1 -1 -1\nv 1 -1 -1\nv -1 1 -1\nv 1 1 -1\nv -1 -1 1\nv 1 -1 1\nv -1 1 1\nv 1 1 1\n\
f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

#[test]
fn demo_writes_a_picture() {
    let dir = scratch("demo");
    let out = octoproxy(
        &[
            "demo",
            "--particles",
            "2000",
            "--steps",
            "20",
            "-o",
            "demo.png",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    for key in [
        "triangles:",
        "proxy:",
        "bake time:",
        "particles:",
        "ms per step:",
        "backend:",
        "picture:",
        "instances:",
        "hits:",
        "crushed:",
    ] {
        assert!(stdout.contains(key), "summary lacks {key}: {stdout}");
    }
    let png = std::fs::read(dir.join("demo.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
}

#[test]
fn every_help_lists_its_options_indented() {
    let dir = scratch("help");
    let mut commands = vec!["demo", "bake", "sim", "check"];
    if cfg!(feature = "dev") {
        commands.push("bench");
    }
    for command in commands {
        let out = octoproxy(&[command, "--help"], &dir);
        assert!(out.status.success(), "{command} --help failed");
        let text = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(
            text.starts_with("usage: octoproxy"),
            "{command} --help: {text}"
        );
        for line in text.lines().skip(1) {
            assert!(
                !line.starts_with('-'),
                "{command} --help: an option out of line: {line:?}"
            );
        }
    }
}

#[test]
fn bake_then_sim_keeps_every_particle_in_order() {
    let dir = scratch("sim");
    std::fs::write(dir.join("box.obj"), BOX_OBJ).unwrap();
    let out = octoproxy(
        &[
            "bake",
            "--mesh",
            "box.obj",
            "-o",
            "box.octoproxy",
            "--dmax",
            "6",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // An input with an extra property, no velocities, no side.
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty int id\nend_header\n\
0 3 0 7\n0.5 0 0 8\n5 5 5 9\n";
    std::fs::write(dir.join("in.ply"), ply).unwrap();
    let out = octoproxy(
        &[
            "sim",
            "--proxy",
            "box.octoproxy",
            "--particles",
            "in.ply",
            "-o",
            "out.ply",
            "--ascii",
            "--steps",
            "30",
            "--frames",
            "frames",
            "--every",
            "7",
            "--gravity",
            "0,-9.81,0",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.join("out.ply")).unwrap();
    let body: Vec<&str> = text
        .split("end_header")
        .nth(1)
        .unwrap()
        .lines()
        .filter(|l| !l.is_empty())
        .collect();
    assert_eq!(body.len(), 3);
    let ids: Vec<&str> = body
        .iter()
        .map(|l| l.split_whitespace().last().unwrap())
        .collect();
    assert_eq!(ids, ["7", "8", "9"], "order and extra property kept");
    // The particle above the box lands on it, the one inside stays inside.
    let y0: f32 = body[0].split_whitespace().nth(1).unwrap().parse().unwrap();
    assert!(y0 >= 1.0 - 1e-4, "landed on the top, y = {y0}");
    let y1: f32 = body[1].split_whitespace().nth(1).unwrap().parse().unwrap();
    assert!((-1.0..=1.0).contains(&y1), "stayed inside, y = {y1}");
    // Frames: 0, 7, 14, 21, 28 and the final 30.
    let mut frames: Vec<String> = std::fs::read_dir(dir.join("frames"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    frames.sort();
    assert_eq!(
        frames,
        [
            "frame_00000.ply",
            "frame_00001.ply",
            "frame_00002.ply",
            "frame_00003.ply",
            "frame_00004.ply",
            "frame_00005.ply"
        ]
    );
    // Output continues in the next run, and existing frames are refused without --force.
    let out = octoproxy(
        &[
            "sim",
            "--proxy",
            "box.octoproxy",
            "--particles",
            "out.ply",
            "-o",
            "out2.ply",
            "--frames",
            "frames",
        ],
        &dir,
    );
    assert_one_line_error(&out, "--force");
    // A negative first gravity component parses (it is a value, not an option).
    let out = octoproxy(
        &[
            "sim",
            "--proxy",
            "box.octoproxy",
            "--particles",
            "out.ply",
            "-o",
            "out2.ply",
            "--gravity",
            "-9.81,0,0",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_closed_mesh_wound_inconsistently_is_checked_by_crossings() {
    // A box with one face flipped: closed, but with no meaningful winding number (0.35 to
    // 0.7 deep inside it), which made every check fail where nothing crossed. It is checked
    // by crossing parity, and a note says why.
    let dir = scratch("flipped");
    let flipped = BOX_OBJ.replace("f 1 3 4 2", "f 2 4 3 1");
    assert_ne!(flipped, BOX_OBJ);
    std::fs::write(dir.join("flipped.obj"), flipped).unwrap();
    let out = octoproxy(
        &[
            "check",
            "--mesh",
            "flipped.obj",
            "--dmax",
            "5",
            "--emit",
            "1000",
            "--steps",
            "30",
            "--restitution",
            "0",
            "--friction",
            "0",
        ],
        &dir,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{err}{said}");
    assert!(err.contains("not wound consistently"), "{err}");
    assert!(err.contains("open mesh (crossing parity)"), "{err}");
    assert!(said.contains("penetrations: 0 "), "{said}");
}

#[test]
fn a_files_per_particle_radii_are_named_not_silently_dropped() {
    let dir = scratch("pscale");
    std::fs::write(dir.join("box.obj"), BOX_OBJ).unwrap();
    let ply = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty float pscale\nend_header\n\
0 3 0 0.05\n0.5 3 0 0.25\n";
    std::fs::write(dir.join("in.ply"), ply).unwrap();
    let out = octoproxy(
        &[
            "sim",
            "--mesh",
            "box.obj",
            "--particles",
            "in.ply",
            "-o",
            "o.ply",
            "--dmax",
            "6",
        ],
        &dir,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("in.ply has per-particle radii (`pscale`: 0.05 to 0.25)")
            && err.contains("(0: points); --radius 0.25 keeps every particle's distance"),
        "{err}"
    );
    // Carried to the output unchanged.
    let out = octoproxy_cpu::io::read_particles(&dir.join("o.ply")).unwrap();
    assert_eq!(out.extra.properties[0].0, "pscale");
    assert_eq!(out.extra.values, [0.05f32 as f64, 0.25]);
    // A proxy brings its radius: the note gives it, and the advice is a bake for the file's
    // largest (--radius alone would not match the proxy); none where the proxy's covers it.
    for (baked, advice) in [("0.1", true), ("0.3", false)] {
        let proxy = format!("r{baked}.octoproxy");
        let args = [
            "bake", "--mesh", "box.obj", "--dmax", "6", "--radius", baked, "-o", &proxy,
        ];
        let out = octoproxy(&args, &dir);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let args = [
            "sim",
            "--proxy",
            &proxy,
            "--particles",
            "in.ply",
            "-o",
            "o.ply",
            "--steps",
            "2",
        ];
        let out = octoproxy(&args, &dir);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        assert!(
            err.contains(&format!("the run's one radius (radius {baked})")),
            "{err}"
        );
        assert_eq!(
            err.contains(
                "; baked again with --radius 0.25, the scene keeps every particle's distance"
            ),
            advice,
            "{err}"
        );
        assert!(!err.contains("; --radius"), "{err}");
    }
}

#[test]
fn hits_add_columns_not_other_particles() {
    // `--hits` steps a mesh through the scene API; it emits where the plain step does and
    // gives its particles the very same bits, fast ones included.
    let dir = scratch("hits-same");
    std::fs::write(dir.join("box.obj"), BOX_OBJ).unwrap();
    for speed in ["3", "1e20"] {
        let mut files = Vec::new();
        for hits in [false, true] {
            let out_name = format!("o-{speed}-{hits}.ply");
            let mut args = vec![
                "sim",
                "--mesh",
                "box.obj",
                "--emit",
                "400",
                "--emit-speed",
                speed,
                "--steps",
                "5",
                "--dmax",
                "6",
                "-o",
                &out_name,
            ];
            if hits {
                args.push("--hits");
            }
            let out = octoproxy(&args, &dir);
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            files.push(octoproxy_cpu::io::read_particles(&dir.join(&out_name)).unwrap());
        }
        let (plain, scene) = (&files[0].particles, &files[1].particles);
        assert_eq!((plain.len(), scene.len()), (400, 400));
        for (k, (a, b)) in plain.iter().zip(scene).enumerate() {
            let bits = |p: &octoproxy_core::Particle| {
                let f = [p.position, p.velocity].concat();
                let f: Vec<u32> = f.iter().map(|x| x.to_bits()).collect();
                (f, p.side, p.flags)
            };
            assert_eq!(bits(a), bits(b), "speed {speed}, particle {k}");
            assert_eq!(
                a.flags & octoproxy_core::FLAG_INVALID,
                0,
                "speed {speed}, particle {k}"
            );
        }
    }
}

#[test]
fn bad_input_gets_one_readable_line() {
    let dir = scratch("errors");
    std::fs::write(dir.join("box.obj"), BOX_OBJ).unwrap();
    std::fs::write(dir.join("bad.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n").unwrap();
    std::fs::write(
        dir.join("nan.obj"),
        "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
    )
    .unwrap();
    std::fs::write(dir.join("junk.octoproxy"), b"not a proxy at all!").unwrap();
    std::fs::write(dir.join("noz.ply"), "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n").unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["bake", "--mesh", "missing.obj", "-o", "x"], "missing.obj"),
        (&["bake", "--mesh", "bad.obj", "-o", "x"], "bad.obj"),
        (&["bake", "--mesh", "nan.obj", "-o", "x"], "nan.obj"),
        (
            &["bake", "--mesh", "box.obj", "-o", "x", "--dmax", "40"],
            "dmax",
        ),
        (
            &["bake", "--mesh", "box.obj", "-o", "x", "--dmax", "0"],
            "dmax",
        ),
        (
            &["bake", "--mesh", "box.obj", "-o", "x", "--epsilon", "-1"],
            "epsilon",
        ),
        (&["bake", "--mesh", "box.obj"], "--out"),
        (&["demo", "--mesh", "box.obj"], "--mesh is for --sand"),
        (&["demo", "--sand", "--mesh", "missing.obj"], "missing.obj"),
        (&["demo", "--sand", "--mesh", "nan.obj"], "nan.obj"),
        (
            &[
                "sim",
                "--proxy",
                "junk.octoproxy",
                "--emit",
                "5",
                "-o",
                "o.ply",
            ],
            "junk.octoproxy",
        ),
        (
            &[
                "sim", "--mesh", "box.obj", "--emit", "5", "-o", "o.ply", "--dt", "NaN",
            ],
            "dt",
        ),
        (
            &[
                "sim", "--mesh", "box.obj", "--emit", "5", "-o", "o.ply", "--dt", "-1",
            ],
            "dt",
        ),
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--emit",
                "5",
                "-o",
                "o.ply",
                "--restitution",
                "2",
            ],
            "restitution",
        ),
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--emit",
                "5",
                "-o",
                "o.ply",
                "--gravity",
                "1,2",
            ],
            "--gravity",
        ),
        (
            &[
                "sim", "--mesh", "box.obj", "--proxy", "p", "--emit", "5", "-o", "o.ply",
            ],
            "give one of --mesh, --proxy and --scene",
        ),
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--particles",
                "noz.ply",
                "-o",
                "o.ply",
            ],
            "z",
        ),
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--particles",
                "noz.ply",
                "-o",
                "noz.ply",
            ],
            "overwrite",
        ),
        (&["frobnicate"], "unknown command"),
        // Outputs that cannot be written: found before the bake and the steps.
        (
            &["bake", "--mesh", "box.obj", "-o", "missing/x.octoproxy"],
            "the folder missing does not exist",
        ),
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--emit",
                "5",
                "-o",
                "missing/o.ply",
            ],
            "the folder missing does not exist",
        ),
        (
            &["sim", "--mesh", "box.obj", "--emit", "5", "-o", "."],
            "is a folder",
        ),
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--emit",
                "5",
                "-o",
                "o.ply",
                "--events",
                "missing/e.ply",
            ],
            "--events missing/e.ply",
        ),
        // Counts beyond any machine's memory: an error before any work, not an abort.
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--emit",
                "1000000000000000",
                "-o",
                "o.ply",
            ],
            "--emit 1000000000000000",
        ),
        (
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--emit",
                "5",
                "-o",
                "o.ply",
                "--events",
                "e.ply",
                "--event-capacity",
                "1000000000000000",
            ],
            "--event-capacity 1000000000000000",
        ),
        (
            &["demo", "--particles", "1000000000000000"],
            "--particles 1000000000000000",
        ),
        (
            &["check", "--mesh", "box.obj", "--emit", "1000000000000000"],
            "--emit 1000000000000000",
        ),
    ];
    for (args, needle) in cases {
        let out = octoproxy(args, &dir);
        assert_one_line_error(&out, needle);
    }
    // A bad particle file is found before the mesh is baked.
    let out = octoproxy(
        &[
            "sim",
            "--mesh",
            "box.obj",
            "--particles",
            "noz.ply",
            "-o",
            "o.ply",
        ],
        &dir,
    );
    assert_one_line_error(&out, "noz.ply");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !err.contains("bake time") && !err.contains("loaded"),
        "{err}"
    );
    // So is an output that cannot be written.
    let out = octoproxy(
        &[
            "sim",
            "--mesh",
            "box.obj",
            "--emit",
            "5",
            "-o",
            "missing/o.ply",
        ],
        &dir,
    );
    assert!(!String::from_utf8_lossy(&out.stderr).contains("loaded"));
}

/// Whether wgpu finds an adapter here; under `CI=true` it must (lavapipe).
fn gpu_present(dir: &Path) -> bool {
    let probe = octoproxy(
        &[
            "demo",
            "--particles",
            "64",
            "--steps",
            "1",
            "--backend",
            "wgpu",
            "-o",
            "probe.png",
        ],
        dir,
    );
    if probe.status.success() {
        return true;
    }
    let err = String::from_utf8_lossy(&probe.stderr);
    assert!(!err.contains("panicked"), "stderr: {err}");
    assert!(err.contains("no GPU adapter"), "stderr: {err}");
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true needs a GPU adapter (lavapipe: apt install mesa-vulkan-drivers libvulkan1): {err}");
    }
    eprintln!("skipped: no GPU adapter ({})", err.trim());
    false
}

#[test]
fn sim_on_wgpu_writes_the_same_file_as_on_cpu() {
    let dir = scratch("wgpu");
    if !gpu_present(&dir) {
        return;
    }
    std::fs::write(dir.join("box.obj"), BOX_OBJ).unwrap();
    let mut outputs = Vec::new();
    for backend in ["cpu", "wgpu"] {
        let out_file = format!("out-{backend}.ply");
        let out = octoproxy(
            &[
                "sim",
                "--mesh",
                "box.obj",
                "--dmax",
                "6",
                "--emit",
                "5000",
                "--emit-speed",
                "3",
                "--steps",
                "60",
                "--backend",
                backend,
                "-o",
                &out_file,
                "--frames",
                &format!("frames-{backend}"),
                "--every",
                "20",
            ],
            &dir,
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        assert!(
            err.contains(&format!("backend: {backend}")),
            "says which backend: {err}"
        );
        outputs.push(std::fs::read(dir.join(out_file)).unwrap());
    }
    assert!(
        outputs[0] == outputs[1],
        "the GPU's output file differs from the CPU's"
    );
    // The frames (read back between steps) agree too.
    for k in 0..4 {
        let name = format!("frame_{k:05}.ply");
        let a = std::fs::read(dir.join("frames-cpu").join(&name)).unwrap();
        let b = std::fs::read(dir.join("frames-wgpu").join(&name)).unwrap();
        assert!(a == b, "{name} differs");
    }
}

#[test]
#[cfg(not(feature = "dev"))]
fn bench_without_the_dev_feature_says_where_it_is() {
    let dir = scratch("nobench");
    assert_one_line_error(&octoproxy(&["bench"], &dir), "cargo xtask bench");
}

#[test]
#[cfg(feature = "dev")]
fn bench_writes_json_table_and_plots_with_every_method() {
    let meshes =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/meshes/stanford-bunny.obj.gz");
    if !meshes.exists() {
        assert_ne!(
            std::env::var("CI").as_deref(),
            Ok("true"),
            "CI=true requires ../shared/meshes"
        );
        eprintln!("skipped: {} not found", meshes.display());
        return;
    }
    let dir = scratch("bench");
    let out = octoproxy(
        &[
            "bench",
            "--scenes",
            "bunny",
            "--particles",
            "3000",
            "--steps",
            "2",
            "--samples",
            "100",
            "--backends",
            "cpu",
            "--out",
            "b",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json = std::fs::read_to_string(dir.join("b/results.json")).unwrap();
    for key in [
        "\"machine\"",
        "\"date\"",
        "\"rows\"",
        "\"build_ms\"",
        "\"memory_bytes\"",
        "\"ns_per_particle_step\"",
        "\"penetrations_per_million_particle_steps\"",
    ] {
        assert!(json.contains(key), "results.json lacks {key}");
    }
    for method in [
        "octoproxy-cpu",
        "octoproxy-cpu-nolut",
        "triangle-octree",
        "parry3d",
        "sdf-grid",
        "floor",
    ] {
        assert!(
            json.contains(&format!("\"method\": \"{method}\"")),
            "results.json lacks {method}"
        );
    }
    let table = std::fs::read_to_string(dir.join("b/results.md")).unwrap();
    assert!(
        table.contains("| bunny | 69451 | 3000 | octoproxy-cpu |"),
        "{table}"
    );
    for png in ["b/particles.png", "b/triangles.png"] {
        assert_eq!(
            &std::fs::read(dir.join(png)).unwrap()[..8],
            b"\x89PNG\r\n\x1a\n"
        );
    }
    // Bad options are one readable line.
    assert_one_line_error(
        &octoproxy(&["bench", "--scenes", "moon"], &dir),
        "unknown scene",
    );
    assert_one_line_error(
        &octoproxy(&["bench", "--particles", "0"], &dir),
        "out of range",
    );
}

#[test]
fn sim_takes_sides_from_the_mesh_and_says_what_it_did() {
    let dir = scratch("sides");
    std::fs::write(dir.join("box.obj"), BOX_OBJ).unwrap();
    // Two particles inside the box (one a hair inside a face, in the shell), one outside.
    let header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    let points = "0 0 0\n0.999 0.2 0.1\n0 1.5 0\n";
    std::fs::write(
        dir.join("plain.ply"),
        format!("{header}end_header\n{points}"),
    )
    .unwrap();
    let sided: Vec<String> = points.lines().map(|l| format!("{l} 0")).collect();
    std::fs::write(
        dir.join("sided.ply"),
        format!(
            "{header}property int side\nend_header\n{}\n",
            sided.join("\n")
        ),
    )
    .unwrap();
    let sim = |args: &[&str]| {
        let mut all = vec![
            "sim", "--steps", "2", "--dmax", "5", "-o", "out.ply", "--ascii",
        ];
        all.extend_from_slice(args);
        let out = octoproxy(&all, &dir);
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{err}");
        err
    };
    // The sides written after no steps: column 6 of the output (x y z vx vy vz side flags).
    let written_sides = || -> Vec<String> {
        let out = std::fs::read_to_string(dir.join("out.ply")).unwrap();
        assert!(
            out.contains("property float vz\nproperty uint side\n"),
            "{out}"
        );
        let body = out.split("end_header\n").nth(1).unwrap();
        body.lines()
            .map(|l| l.split_whitespace().nth(6).unwrap().to_string())
            .collect()
    };
    let err = sim(&["--mesh", "box.obj", "--particles", "plain.ply"]);
    assert!(err.contains("sides: from the mesh"), "{err}");
    assert!(err.contains("1 in front, 2 behind"), "{err}");
    sim(&[
        "--mesh",
        "box.obj",
        "--particles",
        "plain.ply",
        "--steps",
        "0",
    ]);
    assert_eq!(written_sides(), ["1", "1", "0"]);
    // All three say front: the two inside contradict the mesh, and keep their side.
    let err = sim(&["--mesh", "box.obj", "--particles", "sided.ply"]);
    assert!(err.contains("2 of 3 contradict the mesh"), "{err}");
    sim(&[
        "--mesh",
        "box.obj",
        "--particles",
        "sided.ply",
        "--steps",
        "0",
    ]);
    assert_eq!(written_sides(), ["0", "0", "0"]);
    // With only a proxy: the mean plane, and how many start in the shell.
    let out = octoproxy(
        &[
            "bake",
            "--mesh",
            "box.obj",
            "-o",
            "box.octoproxy",
            "--dmax",
            "5",
        ],
        &dir,
    );
    assert!(out.status.success());
    let out = octoproxy(
        &[
            "sim",
            "--proxy",
            "box.octoproxy",
            "--particles",
            "plain.ply",
            "-o",
            "p.ply",
            "--steps",
            "1",
        ],
        &dir,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("1 of 3 start inside the shell"), "{err}");
    assert!(err.contains("give --mesh for exact sides"), "{err}");
}

#[test]
fn check_starts_particles_where_asked() {
    let dir = scratch("starts");
    let check = |starts: &str| {
        let out = octoproxy(
            &[
                "check", "--scene", "comb", "--dmax", "6", "--emit", "400", "--steps", "10",
                "--starts", starts,
            ],
            &dir,
        );
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout).to_string(),
            String::from_utf8_lossy(&out.stderr).to_string(),
        );
        assert!(out.status.success(), "{starts}: {stderr}{stdout}");
        assert!(stdout.contains("penetrations: 0 "), "{starts}: {stdout}");
        stderr
    };
    assert!(check("outside").contains("400 started outside the shell"));
    assert!(check("shell").contains("within 1.5 leaves of the surface"));
    assert!(check("emitted").contains("from the surface, one leaf in front"));
    // The comb's teeth are thinner than a leaf: solid, and particles by their corners start
    // inside them, caged.
    let corners = check("corners");
    assert!(
        corners.contains("a fraction of a leaf from the mesh's vertices"),
        "{corners}"
    );
    assert!(
        corners.contains("caged in the solid leaves they start in"),
        "{corners}"
    );
    let out = octoproxy(&["check", "--scene", "comb", "--starts", "nowhere"], &dir);
    assert_one_line_error(
        &out,
        "--starts: unknown place \"nowhere\" (outside, shell, emitted, corners)",
    );
}

#[test]
fn sim_cages_particles_that_start_inside_a_solid_leaf_and_keeps_the_cage_in_its_files() {
    let dir = scratch("cages");
    // A plate 0.004 thick: its leaves are solid; one particle in the plate, one above it.
    let plate = "v -1 -0.002 -1\nv 1 -0.002 -1\nv -1 0.002 -1\nv 1 0.002 -1\nv -1 -0.002 1\nv 1 -0.002 1\nv -1 0.002 1\nv 1 0.002 1\n\
f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";
    std::fs::write(dir.join("plate.obj"), plate).unwrap();
    std::fs::write(
        dir.join("two.ply"),
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n0.1 0.0005 0.2\n0.1 0.5 0.2\n",
    )
    .unwrap();
    let sim = |args: &[&str]| {
        let mut all = vec!["sim", "--mesh", "plate.obj", "--dmax", "6", "--ascii"];
        all.extend_from_slice(args);
        let out = octoproxy(&all, &dir);
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{err}");
        err
    };
    let err = sim(&["--particles", "two.ply", "--steps", "0", "-o", "caged.ply"]);
    assert!(
        err.contains("cages: 1 of 2 particles start strictly inside solid leaves"),
        "{err}"
    );
    let written = std::fs::read_to_string(dir.join("caged.ply")).unwrap();
    let sides: Vec<u32> = written
        .split("end_header\n")
        .nth(1)
        .unwrap()
        .lines()
        .map(|l| l.split_whitespace().nth(6).unwrap().parse().unwrap())
        .collect();
    assert!(
        sides[0] >= 128 && sides[0] & 1 == 1,
        "{sides:?}: caged, behind"
    );
    assert_eq!(sides[1], 0);
    // Read back, the cage is the file's and is kept; stepped, the particle stays in the plate.
    let err = sim(&[
        "--particles",
        "caged.ply",
        "--steps",
        "60",
        "-o",
        "after.ply",
    ]);
    assert!(
        err.contains("cages: the file's, kept, for 1 particles"),
        "{err}"
    );
    let after = std::fs::read_to_string(dir.join("after.ply")).unwrap();
    let first = after
        .split("end_header\n")
        .nth(1)
        .unwrap()
        .lines()
        .next()
        .unwrap();
    let y: f32 = first.split_whitespace().nth(1).unwrap().parse().unwrap();
    assert!(y.abs() < 0.03, "{first}");
}

/// Particles of a radius: `bake --radius` records it, `sim --proxy` steps it (and refuses
/// another), `sim --mesh --radius` moves starts out of the band and says so, and `check
/// --radius` checks paths against the mesh's distance; bad radii are one-line errors.
#[test]
fn a_radius_bakes_steps_and_checks() {
    let dir = scratch("radius");
    std::fs::write(dir.join("cube.obj"), BOX_OBJ).unwrap();
    let out = octoproxy(
        &[
            "bake", "--mesh", "cube.obj", "--dmax", "5", "--radius", "0.2", "-o", "r.octp",
        ],
        &dir,
    );
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("radius: 0.2 (the offset surface"),
        "{stderr}"
    );
    let out = octoproxy(
        &[
            "sim", "--proxy", "r.octp", "--emit", "200", "--steps", "5", "-o", "a.ply",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = octoproxy(
        &[
            "sim", "--proxy", "r.octp", "--radius", "0.1", "--emit", "200", "-o", "b.ply",
        ],
        &dir,
    );
    assert_one_line_error(&out, "but the proxy was baked for radius 0.2");
    let out = octoproxy(
        &[
            "sim", "--mesh", "cube.obj", "--dmax", "5", "--radius", "0.2", "--emit", "300",
            "--steps", "5", "-o", "c.ply",
        ],
        &dir,
    );
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("were moved out along the way"), "{stderr}");
    // Through the scene API, with hit records: the centre at contact.
    let out = octoproxy(
        &[
            "sim",
            "--mesh",
            "cube.obj",
            "--dmax",
            "5",
            "--radius",
            "0.2",
            "--hits",
            "--emit",
            "300",
            "--emit-speed",
            "2",
            "--steps",
            "10",
            "-o",
            "h.ply",
        ],
        &dir,
    );
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("were moved out along the way"), "{stderr}");
    assert!(
        stderr.contains("particles collided in the last step"),
        "{stderr}"
    );
    let out = octoproxy(
        &[
            "check", "--scene", "comb", "--dmax", "5", "--radius", "0.15", "--emit", "400",
            "--steps", "10", "--starts", "shell",
        ],
        &dir,
    );
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("penetrations: 0 "), "{stdout}");
    assert!(
        stdout.contains("of which 0 came nearer the mesh"),
        "{stdout}"
    );
    for bad in ["-1", "nan", "inf"] {
        let out = octoproxy(
            &[
                "bake", "--mesh", "cube.obj", "--radius", bad, "-o", "d.octp",
            ],
            &dir,
        );
        assert_one_line_error(&out, "radius");
    }
    // A scene with a radius reads its file first (scenes baked for a radius: scene_cli.rs).
    let out = octoproxy(
        &[
            "sim", "--scene", "x.gltf", "--radius", "0.1", "--emit", "5", "-o", "e.ply",
        ],
        &dir,
    );
    assert_one_line_error(&out, "x.gltf: cannot read the file");
}

#[test]
fn particles_collide_with_each_other_and_bad_pass_options_are_errors() {
    let dir = scratch("collide");
    std::fs::write(dir.join("cube.obj"), BOX_OBJ).unwrap();
    let out = octoproxy(
        &[
            "bake", "--mesh", "cube.obj", "--dmax", "5", "--radius", "0.2", "-o", "r.octp",
        ],
        &dir,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = octoproxy(
        &[
            "sim",
            "--proxy",
            "r.octp",
            "--emit",
            "300",
            "--steps",
            "10",
            "--collide-particles",
            "--particle-friction",
            "0.8",
            "-o",
            "a.ply",
        ],
        &dir,
    );
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("particle pass: "), "{stderr}");
    assert!(stderr.contains("iterations each"), "{stderr}");
    for (args, error) in [
        (
            vec!["--particle-friction", "0.8"],
            "--particle-* options go with --collide-particles",
        ),
        (
            vec!["--collide-particles", "--particle-restitution", "2"],
            "particle restitution must be in [0, 1]",
        ),
        (
            vec!["--collide-particles", "--particle-iterations", "0"],
            "particle iterations must be 1 to 64",
        ),
        (
            vec![
                "--collide-particles",
                "--particle-iterations",
                "12",
                "--particle-max-iterations",
                "10",
            ],
            "the most particle iterations must be 12 (the fewest) to 64, got 10",
        ),
        (
            vec!["--collide-particles", "--particle-max-iterations", "0"],
            "the most particle iterations must be 1 (the fewest) to 64, got 0",
        ),
        (
            vec!["--collide-particles", "--particle-substeps", "0"],
            "--particle-substeps must be at least 1",
        ),
    ] {
        let mut all = vec!["sim", "--proxy", "r.octp", "--emit", "10", "-o", "b.ply"];
        all.extend(args);
        assert_one_line_error(&octoproxy(&all, &dir), error);
    }
    // With hit records the pass runs through the scene API: a proxy is a scene of one.
    let out = octoproxy(
        &[
            "sim",
            "--proxy",
            "r.octp",
            "--emit",
            "10",
            "--collide-particles",
            "--hits",
            "-o",
            "h.ply",
        ],
        &dir,
    );
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{text}");
    assert!(text.contains("particle pass: "), "{text}");
    let hits = octoproxy_cpu::io::read_particles(&dir.join("h.ply")).unwrap();
    assert!(hits
        .extra
        .properties
        .iter()
        .any(|(name, _)| name == "hit_instance"));
    // No radius: points cannot collide with each other.
    let out = octoproxy(
        &[
            "sim",
            "--mesh",
            "cube.obj",
            "--dmax",
            "5",
            "--emit",
            "10",
            "--collide-particles",
            "-o",
            "c.ply",
        ],
        &dir,
    );
    assert_one_line_error(&out, "need a radius greater than 0");
    // `check` runs the penetration harness with the pass on, and refuses it without a radius.
    let out = octoproxy(
        &[
            "check",
            "--mesh",
            "cube.obj",
            "--dmax",
            "5",
            "--radius",
            "0.2",
            "--emit",
            "200",
            "--steps",
            "20",
            "--collide-particles",
        ],
        &dir,
    );
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout).to_string(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    );
    assert!(out.status.success(), "{stdout}{stderr}");
    assert!(stderr.contains("the particle pass: on"), "{stderr}");
    assert!(stdout.contains("penetrations: 0 "), "{stdout}");
    let out = octoproxy(
        &[
            "check",
            "--mesh",
            "cube.obj",
            "--dmax",
            "5",
            "--collide-particles",
        ],
        &dir,
    );
    assert_one_line_error(&out, "need a radius greater than 0");
}
