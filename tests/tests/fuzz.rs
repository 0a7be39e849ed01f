//! The fuzz targets as ordinary tests: each body (`octoproxy_tests::fuzz`) over every file of
//! its checked-in corpus (`fuzz/corpus/<target>/`, crashes found by campaigns included) and
//! over a seeded random sweep. The bodies assert their properties; these tests fail on the
//! first panic, naming the input.
//!
//! `cargo test -p octoproxy-tests --test fuzz -- --ignored write_seed_corpus` rewrites the
//! generated seed files of the corpus.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;

use octoproxy_cpu::emit::Rng;
use octoproxy_tests::fuzz;

fn corpus_dir(target: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus")
        .join(target)
}

/// Runs `body` on `input`, turning a panic into a failure that names the input.
fn run_one(target: &str, what: &str, input: &[u8], body: fn(&[u8])) {
    if let Err(e) = catch_unwind(AssertUnwindSafe(|| body(input))) {
        if let Some(dir) = std::env::var_os("OCTOPROXY_FUZZ_DUMP") {
            // Keep the failing input, to add it to the corpus or run it under cargo fuzz.
            let _ = std::fs::write(PathBuf::from(dir).join(format!("{target}-failure")), input);
        }
        let msg = e
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default();
        panic!(
            "fuzz target {target} failed on {what} ({} bytes): {msg}",
            input.len()
        );
    }
}

/// Every file of the target's corpus; returns how many ran.
fn run_corpus(target: &str, body: fn(&[u8])) -> usize {
    let dir = corpus_dir(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("corpus {} is missing: {e}", dir.display()))
        .map(|e| e.expect("readable corpus entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    for f in &files {
        let input = std::fs::read(f).expect("readable corpus file");
        run_one(target, &f.display().to_string(), &input, body);
    }
    files.len()
}

/// `n` random inputs of lengths up to `max_len` from a fixed seed; returns how many ran.
fn run_sweep(target: &str, body: fn(&[u8]), n: usize, max_len: usize, seed: u64) -> usize {
    let mut rng = Rng::new(seed);
    for i in 0..n {
        let len = (rng.next_u64() % max_len as u64) as usize;
        let input: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
        run_one(
            target,
            &format!("sweep input {i} (seed {seed})"),
            &input,
            body,
        );
    }
    n
}

#[test]
fn fuzz_proxy_bytes_corpus_and_sweep() {
    let corpus = run_corpus("proxy_bytes", fuzz::proxy_bytes);
    assert!(corpus >= 3, "the proxy_bytes corpus has {corpus} files");
    // Mostly mutated valid proxies: the first byte picks the mode, 1..=3 mutate a seed proxy.
    let swept = run_sweep("proxy_bytes", fuzz::proxy_bytes, 3000, 512, 1);
    assert_eq!(swept, 3000);
    // The seed proxies themselves are valid.
    for (i, w) in fuzz::seed_proxies().iter().enumerate() {
        octoproxy_core::ProxyView::new(w)
            .unwrap_or_else(|e| panic!("seed proxy {i} is invalid: {e}"));
    }
}

#[test]
fn fuzz_build_corpus_and_sweep() {
    let corpus = run_corpus("bake", fuzz::bake);
    assert!(corpus >= 3, "the bake corpus has {corpus} files");
    let swept = run_sweep("bake", fuzz::bake, 1500, 2048, 2);
    assert_eq!(swept, 1500);
}

#[test]
fn fuzz_penetration_corpus_and_sweep() {
    let corpus = run_corpus("penetration", fuzz::penetration);
    assert!(corpus >= 3, "the penetration corpus has {corpus} files");
    let swept = run_sweep("penetration", fuzz::penetration, 300, 1024, 3);
    assert_eq!(swept, 300);
}

#[test]
fn fuzz_moving_corpus_and_sweep() {
    let corpus = run_corpus("moving", fuzz::moving);
    assert!(corpus >= 3, "the moving corpus has {corpus} files");
    let swept = run_sweep("moving", fuzz::moving, 200, 1024, 6);
    assert_eq!(swept, 200);
}

#[test]
fn fuzz_scene_files_corpus_and_sweep() {
    let corpus = run_corpus("scene_files", fuzz::scene_files);
    assert!(corpus >= 4, "the scene_files corpus has {corpus} files");
    let swept = run_sweep("scene_files", fuzz::scene_files, 2000, 1024, 8);
    assert_eq!(swept, 2000);
    // Mutations of the corpus: bytes flipped, replaced, and files cut short.
    let ran = run_mutations("scene_files", fuzz::scene_files, 150, 8);
    assert!(ran >= 600, "only {ran} mutated inputs ran");
}

#[test]
fn fuzz_mesh_files_corpus_and_sweep() {
    let corpus = run_corpus("mesh_files", fuzz::mesh_files);
    assert!(corpus >= 3, "the mesh_files corpus has {corpus} files");
    let swept = run_sweep("mesh_files", fuzz::mesh_files, 3000, 1024, 4);
    assert_eq!(swept, 3000);
    // Mutations of the well-formed corpus files reach past the headers.
    let ran = run_mutations("mesh_files", fuzz::mesh_files, 200, 5);
    assert!(ran >= 600, "only {ran} mutated inputs ran");
}

/// Runs `body` on `per_seed` mutations of each corpus file of `target` (after its first
/// byte, the selector: bytes flipped or replaced, the file cut short); returns how many ran.
fn run_mutations(target: &str, body: fn(&[u8]), per_seed: usize, seed: u64) -> usize {
    let mut rng = Rng::new(seed);
    let dir = corpus_dir(target);
    let mut seeds: Vec<Vec<u8>> = std::fs::read_dir(&dir)
        .expect("corpus")
        .map(|e| std::fs::read(e.expect("entry").path()).expect("file"))
        .collect();
    seeds.sort();
    let mut ran = 0;
    for (k, seed) in seeds.iter().enumerate() {
        for i in 0..per_seed {
            let mut input = seed.clone();
            for _ in 0..1 + rng.next_u64() % 4 {
                if input.len() < 2 {
                    break;
                }
                let at = 1 + (rng.next_u64() as usize) % (input.len() - 1);
                match rng.next_u64() % 3 {
                    0 => input[at] ^= 1 << (rng.next_u64() % 8),
                    1 => input[at] = rng.next_u64() as u8,
                    _ => input.truncate(at),
                }
            }
            let what = format!("mutation {i} of corpus file {k}");
            run_one(target, &what, &input, body);
            ran += 1;
        }
    }
    ran
}

/// Writes the generated seed files of `fuzz/corpus/` (well-formed inputs that take each
/// target deep at once; campaigns grow their own corpora elsewhere).
#[test]
#[ignore = "rewrites fuzz/corpus; run by hand"]
fn write_seed_corpus() {
    use octoproxy_cpu::scenes;
    let write = |target: &str, name: &str, bytes: &[u8]| {
        let dir = corpus_dir(target);
        std::fs::create_dir_all(&dir).expect("corpus dir");
        std::fs::write(dir.join(name), bytes).expect("write seed");
    };
    let mut rng = Rng::new(99);
    let mut random = |len: usize| -> Vec<u8> { (0..len).map(|_| rng.next_u64() as u8).collect() };

    // proxy_bytes: a raw valid proxy (mode byte 0), and mutation inputs (modes 1..=3).
    let mut raw = vec![0u8];
    raw.extend(fuzz::seed_proxies()[0].iter().flat_map(|w| w.to_le_bytes()));
    write("proxy_bytes", "raw-cube-proxy", &raw);
    for (i, mode) in [1u8, 2, 3].iter().enumerate() {
        let mut v = vec![*mode];
        v.extend(random(300));
        write("proxy_bytes", &format!("mutate-{i}"), &v);
    }

    // build, penetration: random bytes (every byte string is a valid input).
    for i in 0..4 {
        write("bake", &format!("seed-{i}"), &random(600 + 300 * i));
        write("penetration", &format!("seed-{i}"), &random(400 + 200 * i));
    }

    // mesh_files: selector byte, then a file. Selector bits: 0-1 extension (ply, obj, stl,
    // none), 2 gzip it, 3 read as particles, 4 also read the raw bytes.
    let cube = scenes::cube([0.0; 3], [1.0; 3]);
    let mut obj = String::new();
    for p in &cube.positions {
        obj.push_str(&format!("v {} {} {}\n", p[0], p[1], p[2]));
    }
    for t in &cube.triangles {
        obj.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    let mut ply = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        cube.positions.len(),
        cube.triangles.len()
    );
    for p in &cube.positions {
        ply.push_str(&format!("{} {} {}\n", p[0], p[1], p[2]));
    }
    for t in &cube.triangles {
        ply.push_str(&format!("3 {} {} {}\n", t[0], t[1], t[2]));
    }
    let mut stl = String::from("solid cube\n");
    for t in cube.triangles.iter().take(4) {
        stl.push_str("facet normal 0 0 0\nouter loop\n");
        for &i in t {
            let p = cube.positions[i as usize];
            stl.push_str(&format!("vertex {} {} {}\n", p[0], p[1], p[2]));
        }
        stl.push_str("endloop\nendfacet\n");
    }
    stl.push_str("endsolid cube\n");
    let mut bin_stl = vec![0u8; 80];
    bin_stl.extend(2u32.to_le_bytes());
    for t in cube.triangles.iter().take(2) {
        bin_stl.extend([0u8; 12]);
        for &i in t {
            for c in cube.positions[i as usize] {
                bin_stl.extend(c.to_le_bytes());
            }
        }
        bin_stl.extend([0u8; 2]);
    }
    let particles = octoproxy_cpu::io::encode_particles(
        &octoproxy_cpu::io::ParticleCloud::from_particles(vec![
            octoproxy_core::Particle::new([0.0, 1.0, 2.0], [0.5, 0.0, -1.0]),
            octoproxy_core::Particle::new([f32::NAN, 0.0, f32::INFINITY], [0.0; 3]),
        ]),
        octoproxy_cpu::io::PlyEncoding::BinaryLittleEndian,
    );
    let ascii_particles = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty float temperature\nend_header\n1 2 3 300\n-1 0.5 nan 20\n";
    let with = |sel: u8, body: &[u8]| -> Vec<u8> {
        let mut v = vec![sel];
        v.extend_from_slice(body);
        v
    };
    write("mesh_files", "ply-ascii-cube", &with(0, ply.as_bytes()));
    write("mesh_files", "obj-cube", &with(1, obj.as_bytes()));
    write("mesh_files", "obj-cube-gz", &with(1 | 4, obj.as_bytes()));
    write("mesh_files", "stl-ascii", &with(2, stl.as_bytes()));
    write(
        "mesh_files",
        "stl-binary-by-content",
        &with(3 | 16, &bin_stl),
    );
    write("mesh_files", "particles-binary", &with(8, &particles));
    write(
        "mesh_files",
        "particles-ascii-extra-gz",
        &with(8 | 4, ascii_particles.as_bytes()),
    );
}

/// Found by the `bake` campaign (fixed in 3f08705): one triangle whose plane passes exactly
/// through a corner of a depth-1 cell. The f64 overlap test said it touched the cell but
/// none of the cell's eight children, so the builder made an internal node with no children,
/// which `ProxyView::new` rejected (`BadNode`). A bake must give an error or a valid proxy.
/// (`fuzz/corpus/bake/crash-internal-node-without-children` is the same bug at 1e30.)
#[test]
fn regression_bake_internal_node_without_children() {
    let positions = [
        [-1.728208e-31, 5.546874e-31, 7.65607e-31],
        [-1e-30, -9.999875e-31, 9.954186e-31],
        [9.964293e-31, -1e-30, -1e-30],
        [9.921876e-31, -1e-30, 1.1372541e-31],
    ];
    let params = octoproxy_cpu::BuildParams {
        dmin: 3,
        dmax: 6,
        epsilon: 1.0,
        lut_depth: 4,
        max_nodes: 200_000,
    };
    let mesh = octoproxy_cpu::MeshRef {
        positions: &positions,
        triangles: &[[2, 3, 0]],
    };
    if let Ok((words, _)) = octoproxy_cpu::bake(&[mesh], &params, &()) {
        if let Err(e) = octoproxy_core::ProxyView::new(&words) {
            panic!("bake produced a proxy that ProxyView::new rejects: {e}");
        }
    }
}

/// Runs one target on one file, timed: `FUZZ_TARGET=bake FUZZ_CASE=path cargo test -p
/// octoproxy-tests --test fuzz -- --ignored reproduce --nocapture` (an artifact from a
/// campaign, say, outside libFuzzer and its instrumentation).
#[test]
#[ignore = "needs FUZZ_TARGET and FUZZ_CASE"]
fn reproduce() {
    let data =
        std::fs::read(std::env::var("FUZZ_CASE").expect("FUZZ_CASE")).expect("read FUZZ_CASE");
    let t = std::time::Instant::now();
    match std::env::var("FUZZ_TARGET").expect("FUZZ_TARGET").as_str() {
        "proxy_bytes" => fuzz::proxy_bytes(&data),
        "bake" => fuzz::bake(&data),
        "penetration" => fuzz::penetration(&data),
        "mesh_files" => fuzz::mesh_files(&data),
        "moving" => fuzz::moving(&data),
        "scene_files" => fuzz::scene_files(&data),
        other => panic!("unknown target {other}"),
    }
    println!("took {:?}", t.elapsed());
}
