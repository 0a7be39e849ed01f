//! Bake time and proxy size for every mesh in `../shared/meshes` and for nefertiti
//! subdivided twice (1.6M triangles), then CPU milliseconds per step for 1M particles against
//! that largest scene. `cargo bench -p octoproxy-cpu --bench bake`. Prints a Markdown table.

use std::path::PathBuf;
use std::time::Instant;

use octoproxy_core::{initial_side, Backend, ProxyView, StepParams};
use octoproxy_cpu::emit::emit_box;
use octoproxy_cpu::io::{load_mesh, Mesh};
use octoproxy_cpu::{bake, BuildParams, CpuBackend, MeshRef};

fn subdivide(m: &Mesh) -> Mesh {
    let mut positions = m.positions.clone();
    let mut mids = std::collections::HashMap::new();
    let mut triangles = Vec::with_capacity(m.triangles.len() * 4);
    let mut mid = |a: u32, b: u32, positions: &mut Vec<[f32; 3]>| -> u32 {
        *mids.entry((a.min(b), a.max(b))).or_insert_with(|| {
            let (p, q) = (positions[a as usize], positions[b as usize]);
            positions.push([
                (p[0] + q[0]) * 0.5,
                (p[1] + q[1]) * 0.5,
                (p[2] + q[2]) * 0.5,
            ]);
            positions.len() as u32 - 1
        })
    };
    for &[a, b, c] in &m.triangles {
        let (ab, bc, ca) = (
            mid(a, b, &mut positions),
            mid(b, c, &mut positions),
            mid(c, a, &mut positions),
        );
        triangles.extend_from_slice(&[[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    Mesh {
        positions,
        triangles,
    }
}

fn main() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/meshes");
    if !dir.exists() {
        println!("skipped: {} not found", dir.display());
        return;
    }
    let params = BuildParams::default();
    println!("| scene | triangles | bake (s) | nodes | node array | lookup table | total |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
        .filter(|n| n.ends_with(".obj.gz"))
        .collect();
    names.sort();
    let mut largest = None;
    for name in &names {
        let (mesh, _) = load_mesh(&dir.join(name)).expect("loads");
        row(name, &mesh, &params);
        if name.starts_with("nefertiti") {
            let big = subdivide(&subdivide(&mesh));
            let words = row("nefertiti ×16 (two subdivisions)", &big, &params);
            largest = Some(words);
        }
    }
    let Some(words) = largest else { return };
    let view = ProxyView::new(&words).unwrap();
    let r = view.root_aabb();
    let leaf = view.finest_leaf_size();
    let mut particles = emit_box(1_000_000, r.min, r.max, 2.0 * leaf * 60.0, 1).expect("fits");
    for p in &mut particles {
        p.side = initial_side(&view, p.position);
    }
    let mut backend = CpuBackend::new();
    backend.upload_proxy(&words).unwrap();
    backend.upload_particles(&particles).unwrap();
    let step = StepParams::default();
    backend.step(&step, 2).unwrap();
    let steps = 10;
    let t = Instant::now();
    backend.step(&step, steps).unwrap();
    let ms = t.elapsed().as_secs_f64() * 1e3 / steps as f64;
    println!(
        "\n1M particles, nefertiti ×16, speed 2 leaves/step, gravity, {} threads: {ms:.1} ms per step",
        rayon::current_num_threads()
    );
}

fn row(name: &str, mesh: &Mesh, params: &BuildParams) -> Vec<u32> {
    let t = Instant::now();
    let (words, report) = bake(&[MeshRef::from(mesh)], params, &()).expect("bakes");
    let s = t.elapsed().as_secs_f64();
    let kb = |b: usize| format!("{:.1} KiB", b as f64 / 1024.0);
    println!(
        "| {name} | {} | {s:.2} | {} | {} | {} | {} |",
        report.triangles_in,
        report.nodes,
        kb(report.node_bytes),
        kb(report.lut_bytes),
        kb(report.total_bytes)
    );
    words
}
