//! Tests of the glTF reader, the pose sampling and the baked scene file: hand-built documents
//! (JSON and GLB made in code), the Blender exports and Khronos samples under
//! `backend-cpu/tests/data/gltf/`, and hostile inputs.

use std::path::{Path, PathBuf};

use octoproxy_core::scene::Pose;

use super::*;
use crate::BuildParams;

// ---------------------------------------------------------------------------------------------
// A glTF document built in code.
// ---------------------------------------------------------------------------------------------

/// A glTF document being built: one binary buffer and the JSON arrays.
#[derive(Default, Clone)]
struct Doc {
    bin: Vec<u8>,
    accessors: Vec<String>,
    views: Vec<String>,
    meshes: Vec<String>,
    nodes: Vec<String>,
    animations: Vec<String>,
    /// Top-level members added as they are (`"extensionsUsed": [...]`).
    extra: Vec<String>,
}

impl Doc {
    /// Appends bytes as a new buffer view (4-byte aligned); returns the view's index.
    fn view(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.views.push(format!(
            r#"{{"buffer": 0, "byteOffset": {offset}, "byteLength": {}}}"#,
            bytes.len()
        ));
        self.views.len() - 1
    }

    /// An accessor over new data; `component` is the glTF code.
    fn accessor(&mut self, bytes: &[u8], component: u32, count: usize, ty: &str) -> usize {
        let view = self.view(bytes);
        self.accessors.push(format!(
            r#"{{"bufferView": {view}, "componentType": {component}, "count": {count}, "type": "{ty}"}}"#
        ));
        self.accessors.len() - 1
    }

    fn floats(&mut self, data: &[f32], ty: &str) -> usize {
        let width = match ty {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            _ => 4,
        };
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.accessor(&bytes, 5126, data.len() / width, ty)
    }

    fn vec3s(&mut self, data: &[[f32; 3]]) -> usize {
        self.floats(&data.concat(), "VEC3")
    }

    fn u16s(&mut self, data: &[u16]) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.accessor(&bytes, 5123, data.len(), "SCALAR")
    }

    fn raw_accessor(&mut self, json: String) -> usize {
        self.accessors.push(json);
        self.accessors.len() - 1
    }

    fn mesh(&mut self, json: String) -> usize {
        self.meshes.push(json);
        self.meshes.len() - 1
    }

    /// A mesh of one indexed triangle primitive.
    fn tri_mesh(&mut self, name: &str, positions: &[[f32; 3]], indices: &[u16]) -> usize {
        let p = self.vec3s(positions);
        let i = self.u16s(indices);
        self.mesh(format!(
            r#"{{"name": "{name}", "primitives": [{{"attributes": {{"POSITION": {p}}}, "indices": {i}}}]}}"#
        ))
    }

    /// A closed tetrahedron, faces wound outward.
    fn tet(&mut self, name: &str) -> usize {
        self.tri_mesh(name, &TET, &TET_INDICES)
    }

    fn node(&mut self, json: &str) -> usize {
        self.nodes.push(json.to_string());
        self.nodes.len() - 1
    }

    fn animation(&mut self, json: String) {
        self.animations.push(json);
    }

    /// One channel in its own animation.
    fn channel(&mut self, node: usize, path: &str, interp: &str, times: &[f32], values: &[f32]) {
        let input = self.floats(times, "SCALAR");
        let ty = if path == "rotation" { "VEC4" } else { "VEC3" };
        let output = self.floats(values, ty);
        self.animation(format!(
            r#"{{"name": "{path} of {node}", "channels": [{{"sampler": 0, "target": {{"node": {node}, "path": "{path}"}}}}],
               "samplers": [{{"input": {input}, "output": {output}, "interpolation": "{interp}"}}]}}"#
        ));
    }

    fn json_with(&self, scene_nodes: &[usize], buffer: &str) -> String {
        let list = |v: &[String]| v.join(",\n");
        let roots: Vec<String> = scene_nodes.iter().map(|n| n.to_string()).collect();
        let mut members = vec![
            r#""asset": {"version": "2.0"}"#.to_string(),
            format!(
                r#""scene": 0, "scenes": [{{"nodes": [{}]}}]"#,
                roots.join(",")
            ),
            format!(r#""nodes": [{}]"#, list(&self.nodes)),
            format!(r#""meshes": [{}]"#, list(&self.meshes)),
            format!(r#""accessors": [{}]"#, list(&self.accessors)),
            format!(r#""bufferViews": [{}]"#, list(&self.views)),
            format!(r#""buffers": [{buffer}]"#),
        ];
        if !self.animations.is_empty() {
            members.push(format!(r#""animations": [{}]"#, list(&self.animations)));
        }
        members.extend(self.extra.iter().cloned());
        format!("{{{}}}", members.join(",\n"))
    }

    /// The document as `.gltf` text with the buffer embedded.
    fn gltf(&self, scene_nodes: &[usize]) -> String {
        self.json_with(
            scene_nodes,
            &format!(
                r#"{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}"#,
                self.bin.len(),
                encode_base64(&self.bin)
            ),
        )
    }

    /// The document as `.glb` bytes.
    fn glb(&self, scene_nodes: &[usize]) -> Vec<u8> {
        let json = self.json_with(
            scene_nodes,
            &format!(r#"{{"byteLength": {}}}"#, self.bin.len()),
        );
        glb_bytes(json.as_bytes(), Some(&self.bin))
    }
}

fn glb_bytes(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
    let mut json = json.to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if let Some(bin) = bin {
        let mut bin = bin.to_vec();
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    let len = out.len() as u32;
    out[8..12].copy_from_slice(&len.to_le_bytes());
    out
}

const TET: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
];
const TET_INDICES: [u16; 12] = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];

fn parse(text: &str) -> Result<(SceneDescription, Vec<GltfWarning>), GltfError> {
    parse_gltf("test.gltf", text.as_bytes(), None)
}

fn load_ok(text: &str) -> SceneDescription {
    match parse(text) {
        Ok((s, _)) => s,
        Err(e) => panic!("{e}"),
    }
}

fn load_err(text: &str) -> String {
    match parse(text) {
        Ok(_) => panic!("loaded, but should not have"),
        Err(e) => e.to_string(),
    }
}

/// Asserts `message` contains every one of `parts`.
fn assert_says(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "{message:?} should say {p:?}");
    }
}

/// `eps`: poses are composed in f64 and rounded to f32 once, so a few f32 ulps of the values
/// involved (here at most about 10) is all the error there is.
fn assert_pose(p: &Pose, translation: [f32; 3], scale: f32, rotation: [f32; 4], eps: f32) {
    for k in 0..3 {
        assert!(
            (p.translation[k] - translation[k]).abs() <= eps,
            "translation {:?} != {translation:?}",
            p.translation
        );
    }
    assert!(
        (p.scale - scale).abs() <= eps,
        "scale {} != {scale}",
        p.scale
    );
    let dot: f32 = (0..4).map(|k| p.rotation[k] * rotation[k]).sum();
    assert!(
        (dot.abs() - 1.0).abs() <= eps,
        "rotation {:?} != {rotation:?}",
        p.rotation
    );
    assert!(p.is_valid(), "{p:?} is not a valid pose");
}

fn axis_angle(axis: [f32; 3], degrees: f32) -> [f32; 4] {
    let h = degrees.to_radians() / 2.0;
    let s = h.sin();
    [axis[0] * s, axis[1] * s, axis[2] * s, h.cos()]
}

// ---------------------------------------------------------------------------------------------
// Hierarchy, transforms, instances, meshes.
// ---------------------------------------------------------------------------------------------

#[test]
fn a_rotated_parent_and_a_scaled_child_compose_as_computed_by_hand() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    let r = axis_angle([0.0, 0.0, 1.0], 90.0);
    // Node 0: translated (1, 2, 3), turned 90° about z, scaled 3; node 1 its child.
    d.node(&format!(
        r#"{{"name": "parent", "mesh": {m}, "children": [1], "translation": [1, 2, 3], "rotation": [{}, {}, {}, {}], "scale": [3, 3, 3]}}"#,
        r[0], r[1], r[2], r[3]
    ));
    d.node(&format!(
        r#"{{"name": "child", "mesh": {m}, "translation": [1, 0, 0], "scale": [2, 2, 2]}}"#
    ));
    let s = load_ok(&d.gltf(&[0]));
    let poses = s.poses_at(0.0).unwrap();
    assert_pose(&poses[0], [1.0, 2.0, 3.0], 3.0, r, 1e-6);
    // The child's origin: (1, 2, 3) + R(90° z) (3 · (1, 0, 0)) = (1, 5, 3); scale 3 · 2.
    assert_pose(&poses[1], [1.0, 5.0, 3.0], 6.0, r, 1e-5);
    assert_eq!(s.graph.nodes()[1].parent, Some(0));
    assert_eq!(s.duration(), 0.0);
    assert_eq!(s.pose_at(1, 0.0).unwrap(), poses[1]);
}

#[test]
fn matrix_nodes_compose_like_their_trs() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    // The 90° turn about z, scale 3 and translation (1, 2, 3) as a column-major matrix.
    d.node(&format!(
        r#"{{"name": "parent", "mesh": {m}, "children": [1], "matrix": [0,3,0,0, -3,0,0,0, 0,0,3,0, 1,2,3,1]}}"#
    ));
    d.node(&format!(
        r#"{{"name": "child", "mesh": {m}, "matrix": [2,0,0,0, 0,2,0,0, 0,0,2,0, 1,0,0,1]}}"#
    ));
    let s = load_ok(&d.gltf(&[0]));
    let poses = s.poses_at(0.0).unwrap();
    let r = axis_angle([0.0, 0.0, 1.0], 90.0);
    assert_pose(&poses[0], [1.0, 2.0, 3.0], 3.0, r, 1e-6);
    assert_pose(&poses[1], [1.0, 5.0, 3.0], 6.0, r, 1e-5);
    assert!(matches!(
        s.graph.nodes()[0].transform,
        NodeTransform::Matrix(_)
    ));
}

#[test]
fn instances_are_numbered_in_pre_order_and_meshes_are_shared() {
    let mut d = Doc::default();
    let a = d.tet("a");
    let b = d.tri_mesh("b", &TET, &[0, 1, 2]);
    // Mesh 2 is broken, and used by no node: it is never read.
    d.mesh(r#"{"name": "unused", "primitives": [{"attributes": {"POSITION": 99}}]}"#.into());
    d.node(&format!(
        r#"{{"name": "n0", "mesh": {a}, "children": [2, 1]}}"#
    ));
    d.node(&format!(r#"{{"name": "n1", "mesh": {b}}}"#));
    d.node(r#"{"name": "n2", "children": [3]}"#);
    d.node(&format!(r#"{{"name": "n3", "mesh": {a}}}"#));
    d.node(&format!(r#"{{"name": "n4", "mesh": {b}}}"#));
    let s = load_ok(&d.gltf(&[0, 4]));
    // Pre-order: n0, n2 (no mesh), n3, n1, then n4.
    let nodes: Vec<u32> = s.instances().iter().map(|i| i.node).collect();
    assert_eq!(nodes, [0, 3, 1, 4]);
    let meshes: Vec<u32> = s.instances().iter().map(|i| i.mesh).collect();
    assert_eq!(meshes, [0, 0, 1, 1]);
    assert_eq!(s.meshes.len(), 2);
    assert_eq!(s.gltf_meshes, [0, 1]);
    assert_eq!(s.meshes[0].name, "a");
    assert_eq!(s.meshes[0].mesh.triangles.len(), 4);
    assert_eq!(s.meshes[1].mesh.triangles, [[0, 1, 2]]);
    let list = s.list_instances().unwrap();
    assert_eq!(list[1].node_name, "n3");
    assert_eq!(list[2].mesh_name, "b");
    assert_eq!(list[3].index, 3);
}

#[test]
fn top_level_mesh_nodes_are_numbered_as_their_nodes() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    for k in 0..5 {
        d.node(&format!(
            r#"{{"name": "n{k}", "mesh": {m}, "translation": [{k}, 0, 0]}}"#
        ));
    }
    let s = load_ok(&d.gltf(&[0, 1, 2, 3, 4]));
    for (k, inst) in s.instances().iter().enumerate() {
        assert_eq!(inst.node, k as u32);
        assert_eq!(
            s.pose_at(k as u32, 0.0).unwrap().translation,
            [k as f32, 0.0, 0.0]
        );
    }
}

#[test]
fn strips_and_fans_are_triangulated_and_primitives_are_joined() {
    let mut d = Doc::default();
    let quad = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
    ];
    let p = d.vec3s(&quad);
    let i = d.u16s(&[0, 1, 2, 3]);
    let m = d.mesh(format!(
        r#"{{"name": "strips", "primitives": [
            {{"attributes": {{"POSITION": {p}}}, "indices": {i}, "mode": 5}},
            {{"attributes": {{"POSITION": {p}}}, "indices": {i}, "mode": 6}},
            {{"attributes": {{"POSITION": {p}}}, "mode": 5}},
            {{"attributes": {{"POSITION": {p}}}, "mode": 4, "indices": {i}}}]}}"#
    ));
    let _ = m;
    d.node(r#"{"mesh": 0}"#);
    let err = load_err(&d.gltf(&[0]));
    // Four indices are not a multiple of three for TRIANGLES.
    assert_says(&err, &["mesh 0 \"strips\"", "primitive 3", "multiple of 3"]);

    let mut d2 = d.clone();
    d2.meshes[0] = format!(
        r#"{{"name": "strips", "primitives": [
            {{"attributes": {{"POSITION": {p}}}, "indices": {i}, "mode": 5}},
            {{"attributes": {{"POSITION": {p}}}, "indices": {i}, "mode": 6}},
            {{"attributes": {{"POSITION": {p}}}, "mode": 5}}]}}"#
    );
    let s = load_ok(&d2.gltf(&[0]));
    let mesh = &s.meshes[0].mesh;
    assert_eq!(mesh.positions.len(), 12);
    assert_eq!(
        mesh.triangles,
        [
            // The strip: (0 1 2), then (2 1 3) keeps the winding.
            [0, 1, 2],
            [2, 1, 3],
            // The fan about vertex 0 (the second primitive's vertices start at 4).
            [5, 6, 4],
            [6, 7, 4],
            // The strip without indices.
            [8, 9, 10],
            [10, 9, 11],
        ]
    );
}

#[test]
fn points_and_lines_are_skipped_with_a_warning() {
    let mut d = Doc::default();
    let p = d.vec3s(&TET);
    let i = d.u16s(&TET_INDICES);
    d.mesh(format!(
        r#"{{"name": "mixed", "primitives": [
            {{"attributes": {{"POSITION": {p}}}, "mode": 0}},
            {{"attributes": {{"POSITION": {p}}}, "indices": {i}}},
            {{"attributes": {{"POSITION": {p}}}, "mode": 1}},
            {{"attributes": {{"POSITION": {p}}}, "mode": 3}}]}}"#
    ));
    d.mesh(format!(
        r#"{{"name": "lines", "primitives": [{{"attributes": {{"POSITION": {p}}}, "mode": 2}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    let (s, warnings) = parse(&d.gltf(&[0])).unwrap();
    assert_eq!(s.meshes[0].mesh.triangles.len(), 4);
    assert_eq!(warnings.len(), 3);
    let text = warnings[0].to_string();
    assert_says(
        &text,
        &["test.gltf", "mesh 0 \"mixed\"", "primitive 0", "POINTS"],
    );
    assert_says(&warnings[2].to_string(), &["primitive 3", "LINE_STRIP"]);
    // A mesh of lines only has nothing to bake.
    d.node(r#"{"mesh": 1, "name": "wire"}"#);
    let err = load_err(&d.gltf(&[0, 1]));
    assert_says(&err, &["mesh 1 \"lines\"", "no triangles"]);
}

#[test]
fn gpu_instancing_places_each_copy_after_the_node() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    let t = d.vec3s(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]);
    let r90 = axis_angle([0.0, 0.0, 1.0], 90.0);
    let r = d.floats(
        &[
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, r90[0], r90[1], r90[2], r90[3],
        ],
        "VEC4",
    );
    let sc = d.vec3s(&[[1.0; 3], [2.0; 3], [0.5; 3]]);
    d.node(&format!(r#"{{"name": "plain", "mesh": {m}}}"#));
    d.node(&format!(
        r#"{{"name": "crowd", "mesh": {m}, "translation": [10, 0, 0], "rotation": [{}, {}, {}, {}],
            "extensions": {{"EXT_mesh_gpu_instancing": {{"attributes": {{"TRANSLATION": {t}, "ROTATION": {r}, "SCALE": {sc}}}}}}}}}"#,
        r90[0], r90[1], r90[2], r90[3]
    ));
    d.node(&format!(r#"{{"name": "after", "mesh": {m}}}"#));
    d.extra
        .push(r#""extensionsUsed": ["EXT_mesh_gpu_instancing"]"#.into());
    let s = load_ok(&d.gltf(&[0, 1, 2]));
    let copies: Vec<(u32, u32)> = s.instances().iter().map(|i| (i.node, i.copy)).collect();
    assert_eq!(copies, [(0, 0), (1, 0), (1, 1), (1, 2), (2, 0)]);
    let poses = s.poses_at(0.0).unwrap();
    // Copy 0: the node's turn takes (1, 0, 0) to (0, 1, 0).
    assert_pose(&poses[1], [10.0, 1.0, 0.0], 1.0, r90, 1e-6);
    // Copy 1: (0, 1, 0) turns to (-1, 0, 0); scale 2.
    assert_pose(&poses[2], [9.0, 0.0, 0.0], 2.0, r90, 1e-6);
    // Copy 2: at the node's origin, turned twice: 180° about z; scale 0.5.
    assert_pose(
        &poses[3],
        [10.0, 0.0, 0.0],
        0.5,
        axis_angle([0.0, 0.0, 1.0], 180.0),
        1e-6,
    );
    assert_eq!(poses[4].translation, [0.0; 3]);
}

#[test]
fn gpu_instancing_with_mismatched_counts_names_the_node() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    let t = d.vec3s(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let sc = d.vec3s(&[[1.0; 3]]);
    d.node(&format!(
        r#"{{"name": "crowd", "mesh": {m}, "extensions": {{"EXT_mesh_gpu_instancing": {{"attributes": {{"TRANSLATION": {t}, "SCALE": {sc}}}}}}}}}"#
    ));
    let err = load_err(&d.gltf(&[0]));
    assert_says(
        &err,
        &[
            "node 0 \"crowd\"",
            "EXT_mesh_gpu_instancing",
            "SCALE has 1 elements",
        ],
    );
}

// ---------------------------------------------------------------------------------------------
// Animation sampling.
// ---------------------------------------------------------------------------------------------

/// One node with the tetrahedron, animated by `channels`.
fn animated(channels: impl FnOnce(&mut Doc)) -> SceneDescription {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "mover", "mesh": {m}}}"#));
    channels(&mut d);
    load_ok(&d.gltf(&[0]))
}

#[test]
fn linear_translation_lerps_and_holds_before_and_after() {
    let s = animated(|d| {
        d.channel(
            0,
            "translation",
            "LINEAR",
            &[1.0, 3.0],
            &[0.0, 0.0, 0.0, 4.0, 2.0, 0.0],
        )
    });
    let at = |t: f64| s.pose_at(0, t).unwrap().translation;
    assert_eq!(at(-5.0), [0.0; 3]);
    assert_eq!(at(0.0), [0.0; 3]);
    assert_eq!(at(1.0), [0.0; 3]);
    assert_eq!(at(2.0), [2.0, 1.0, 0.0]);
    assert_eq!(at(2.5), [3.0, 1.5, 0.0]);
    assert_eq!(at(3.0), [4.0, 2.0, 0.0]);
    assert_eq!(at(100.0), [4.0, 2.0, 0.0]);
    assert_eq!(s.duration(), 3.0);
}

#[test]
fn a_step_time_that_lands_on_a_key_takes_its_value_exactly() {
    // Keys on frames at 60 per second, a scale going 1, 0, 1 (LINEAR): sampled at the step
    // ends a run with an f32 `dt` of 1/60 makes (`k * dt` in f64, a little off `k / 60`),
    // every key's value comes back exactly, so the scale keyed to 0 is 0 (hidden), not a
    // millionth (refused as too small to resolve).
    let times: Vec<f32> = (0..=30).map(|k| k as f32 / 60.0).collect();
    let values: Vec<f32> = (0..=30)
        .flat_map(|k| {
            let s = if (k / 5) % 2 == 1 && k % 5 != 0 {
                0.0
            } else {
                (k % 5) as f32 * 0.25
            };
            [s, s, s]
        })
        .collect();
    let s = animated(|d| d.channel(0, "scale", "LINEAR", &times, &values));
    let dt = 1.0f32 / 60.0;
    for k in 0..=30usize {
        let t = k as f64 * dt as f64;
        assert_eq!(
            s.pose_at(0, t).unwrap().scale,
            values[3 * k],
            "key {k} at {t}"
        );
    }
    // Between keys it still interpolates.
    let half = s.pose_at(0, 1.5 / 60.0).unwrap().scale;
    assert!((half - 0.375).abs() < 1e-6, "{half}");
}

#[test]
fn step_holds_each_key_until_the_next() {
    let s = animated(|d| {
        d.channel(
            0,
            "translation",
            "STEP",
            &[0.0, 1.0, 2.0],
            &[0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 7.0, 0.0, 0.0],
        )
    });
    let x = |t: f64| s.pose_at(0, t).unwrap().translation[0];
    assert_eq!(x(-1.0), 0.0);
    assert_eq!(x(0.99), 0.0);
    assert_eq!(x(1.0), 5.0);
    assert_eq!(x(1.5), 5.0);
    assert_eq!(x(1.999), 5.0);
    assert_eq!(x(2.0), 7.0);
    assert_eq!(x(9.0), 7.0);
}

#[test]
fn cubic_spline_is_hermite_with_tangents_scaled_by_the_interval() {
    // Key 0 at t = 0: value 0, out-tangent (1, 0, 0); key 1 at t = 2: in-tangent (2, 0, 0),
    // value (1, 0, 0). The in-tangent of key 0 and the out-tangent of key 1 are never used.
    #[rustfmt::skip]
    let values = [
        9.0, 9.0, 9.0,   0.0, 0.0, 0.0,   1.0, 0.0, 0.0,
        2.0, 0.0, 0.0,   1.0, 0.0, 0.0,   9.0, 9.0, 9.0,
    ];
    let s = animated(|d| d.channel(0, "translation", "CUBICSPLINE", &[0.0, 2.0], &values));
    let x = |t: f64| s.pose_at(0, t).unwrap().translation[0];
    assert_eq!(x(0.0), 0.0);
    assert_eq!(x(2.0), 1.0);
    assert_eq!(x(-1.0), 0.0);
    assert_eq!(x(3.0), 1.0);
    // u = 1/2: h00 = 1/2, h10 = 1/8, h01 = 1/2, h11 = -1/8, interval 2:
    // 0 + 1/8 · 2 · 1 + 1/2 · 1 - 1/8 · 2 · 2 = 0.25.
    assert_eq!(x(1.0), 0.25);
    // u = 1/4: h10 = 9/64, h01 = 5/32, h11 = -3/64: 9/32 + 5/32 - 12/64 = 0.25.
    assert!((x(0.5) - 0.25).abs() < 1e-7);
}

#[test]
fn linear_rotation_slerps_the_shorter_way() {
    let q90 = axis_angle([0.0, 1.0, 0.0], 90.0);
    // The second key is the same turn written as -q: slerp must still go 45° at the middle.
    let neg: Vec<f32> = q90.iter().map(|c| -c).collect();
    let values = [0.0, 0.0, 0.0, 1.0, neg[0], neg[1], neg[2], neg[3]];
    let s = animated(|d| d.channel(0, "rotation", "LINEAR", &[0.0, 1.0], &values));
    let p = s.pose_at(0, 0.5).unwrap();
    assert_pose(&p, [0.0; 3], 1.0, axis_angle([0.0, 1.0, 0.0], 45.0), 1e-6);
    let p = s.pose_at(0, 0.25).unwrap();
    assert_pose(&p, [0.0; 3], 1.0, axis_angle([0.0, 1.0, 0.0], 22.5), 1e-6);
    assert_pose(&s.pose_at(0, 1.0).unwrap(), [0.0; 3], 1.0, q90, 1e-6);
}

#[test]
fn cubic_spline_rotations_are_normalized() {
    // Zero tangents from the identity to 90° about x: the value at the middle is the
    // normalized average of the two keys, 45°.
    let q = axis_angle([1.0, 0.0, 0.0], 90.0);
    #[rustfmt::skip]
    let values = [
        0.0, 0.0, 0.0, 0.0,   0.0, 0.0, 0.0, 1.0,   0.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 0.0,   q[0], q[1], q[2], q[3],   0.0, 0.0, 0.0, 0.0,
    ];
    let s = animated(|d| d.channel(0, "rotation", "CUBICSPLINE", &[0.0, 1.0], &values));
    assert_pose(
        &s.pose_at(0, 0.5).unwrap(),
        [0.0; 3],
        1.0,
        axis_angle([1.0, 0.0, 0.0], 45.0),
        1e-6,
    );
}

#[test]
fn animations_play_together_and_move_children() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(r#"{"name": "arm", "children": [1]}"#);
    d.node(&format!(
        r#"{{"name": "hand", "mesh": {m}, "translation": [1, 0, 0]}}"#
    ));
    let q = axis_angle([0.0, 0.0, 1.0], 90.0);
    d.channel(
        0,
        "rotation",
        "LINEAR",
        &[0.0, 2.0],
        &[0.0, 0.0, 0.0, 1.0, q[0], q[1], q[2], q[3]],
    );
    d.channel(
        1,
        "scale",
        "LINEAR",
        &[0.0, 4.0],
        &[1.0, 1.0, 1.0, 3.0, 3.0, 3.0],
    );
    let s = load_ok(&d.gltf(&[0]));
    assert_eq!(s.duration(), 4.0);
    // At t = 2 the arm has turned 90°, so the hand is at (0, 1, 0), scaled 2.
    assert_pose(&s.pose_at(0, 2.0).unwrap(), [0.0, 1.0, 0.0], 2.0, q, 1e-6);
    assert_eq!(s.poses_at(2.0).unwrap()[0], s.pose_at(0, 2.0).unwrap());
}

#[test]
fn sampling_a_bad_time_or_instance_is_an_error() {
    let s = animated(|d| d.channel(0, "translation", "LINEAR", &[0.0, 1.0], &[0.0; 6]));
    assert!(matches!(
        s.pose_at(0, f64::NAN),
        Err(PoseError::BadTime { .. })
    ));
    assert!(matches!(
        s.poses_at(f64::INFINITY),
        Err(PoseError::BadTime { .. })
    ));
    assert!(matches!(
        s.pose_at(1, 0.0),
        Err(PoseError::NoSuchInstance { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// Errors that name the node, mesh or animation.
// ---------------------------------------------------------------------------------------------

#[test]
fn two_channels_on_one_path_name_the_node() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "busy", "mesh": {m}}}"#));
    d.channel(0, "translation", "LINEAR", &[0.0, 1.0], &[0.0; 6]);
    d.channel(
        0,
        "rotation",
        "LINEAR",
        &[0.0, 1.0],
        &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    );
    d.channel(0, "translation", "STEP", &[0.0], &[1.0, 2.0, 3.0]);
    let err = load_err(&d.gltf(&[0]));
    assert_says(
        &err,
        &[
            "test.gltf",
            "node 0 \"busy\"",
            "two channels",
            "translation",
            "animation 0",
            "animation 2",
        ],
    );
}

#[test]
fn deforming_meshes_are_errors_that_name_the_node_or_mesh() {
    // A weights channel.
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "blob", "mesh": {m}}}"#));
    let input = d.floats(&[0.0, 1.0], "SCALAR");
    let output = d.floats(&[0.0, 1.0], "SCALAR");
    d.animation(format!(
        r#"{{"channels": [{{"sampler": 0, "target": {{"node": 0, "path": "weights"}}}}], "samplers": [{{"input": {input}, "output": {output}}}]}}"#
    ));
    assert_says(
        &load_err(&d.gltf(&[0])),
        &[
            "node 0 \"blob\"",
            "weights",
            "deforming meshes",
            "not supported yet",
        ],
    );

    // A skin.
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "skinned", "mesh": {m}, "skin": 0}}"#));
    d.node(r#"{"name": "bone"}"#);
    d.extra.push(r#""skins": [{"joints": [1]}]"#.into());
    assert_says(
        &load_err(&d.gltf(&[0, 1])),
        &[
            "node 0 \"skinned\"",
            "skin",
            "deforming meshes",
            "not supported yet",
        ],
    );

    // Morph targets.
    let mut d = Doc::default();
    let p = d.vec3s(&TET);
    let i = d.u16s(&TET_INDICES);
    d.mesh(format!(
        r#"{{"name": "morph", "primitives": [{{"attributes": {{"POSITION": {p}}}, "indices": {i}, "targets": [{{"POSITION": {p}}}]}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &[
            "mesh 0 \"morph\"",
            "morph targets",
            "deforming meshes",
            "not supported yet",
        ],
    );
}

/// A child of a parent with `parent_json` (its transform members) holding the tetrahedron.
fn child_of(parent_json: &str, child_json: &str) -> String {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(
        r#"{{"name": "parent", "children": [1], {parent_json}}}"#
    ));
    d.node(&format!(
        r#"{{"name": "child", "mesh": {m}, {child_json}}}"#
    ));
    d.gltf(&[0])
}

#[test]
fn non_uniform_shearing_and_mirroring_worlds_name_the_node() {
    let err = load_err(&child_of(
        r#""scale": [1, 2, 1]"#,
        r#""translation": [0, 0, 0]"#,
    ));
    assert_says(
        &err,
        &[
            "test.gltf",
            "node 1 \"child\"",
            "non-uniform scale",
            "at rest",
            "deforming meshes (non-rigid transforms) are not supported yet",
        ],
    );

    let r = axis_angle([0.0, 0.0, 1.0], 45.0);
    let err = load_err(&child_of(
        r#""scale": [2, 1, 1]"#,
        &format!(r#""rotation": [{}, {}, {}, {}]"#, r[0], r[1], r[2], r[3]),
    ));
    assert_says(&err, &["node 1 \"child\"", "shears", "not supported yet"]);

    let err = load_err(&child_of(
        r#""scale": [-1, 1, 1]"#,
        r#""translation": [1, 0, 0]"#,
    ));
    assert_says(&err, &["node 1 \"child\"", "mirrors"]);
    let err = load_err(&child_of(
        r#""scale": [-1, -1, -1]"#,
        r#""translation": [1, 0, 0]"#,
    ));
    assert_says(&err, &["node 1 \"child\"", "mirrors"]);

    // Two non-uniform scales that cancel make a rigid world: accepted.
    let s = load_ok(&child_of(r#""scale": [1, 2, 1]"#, r#""scale": [2, 1, 2]"#));
    assert_pose(
        &s.pose_at(0, 0.0).unwrap(),
        [0.0; 3],
        2.0,
        [0.0, 0.0, 0.0, 1.0],
        1e-6,
    );
}

#[test]
fn a_non_rigid_key_names_the_node_and_the_time() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "squash", "mesh": {m}}}"#));
    d.channel(
        0,
        "scale",
        "LINEAR",
        &[0.0, 1.5],
        &[1.0, 1.0, 1.0, 1.0, 0.5, 1.0],
    );
    let err = load_err(&d.gltf(&[0]));
    assert_says(&err, &["node 0 \"squash\"", "non-uniform scale", "at t = "]);
}

#[test]
fn a_non_rigid_pose_between_keys_is_found_at_the_halfway_point() {
    // A cubic spline from scale 1 to scale 1 whose tangents bulge the x axis only: rigid at
    // both keys, x = 2 (non-uniform) halfway.
    #[rustfmt::skip]
    let values = [
        0.0, 0.0, 0.0,   1.0, 1.0, 1.0,   4.0, 0.0, 0.0,
        -4.0, 0.0, 0.0,  1.0, 1.0, 1.0,   0.0, 0.0, 0.0,
    ];
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "bulge", "mesh": {m}}}"#));
    d.channel(0, "scale", "CUBICSPLINE", &[0.0, 1.0], &values);
    let err = load_err(&d.gltf(&[0]));
    assert_says(&err, &["node 0 \"bulge\"", "non-uniform", "at t = 0.5 s"]);
}

#[test]
fn a_zero_scale_hides_the_instance_with_the_identity_rotation() {
    let r = axis_angle([0.0, 1.0, 0.0], 30.0);
    let s = load_ok(&child_of(
        &format!(
            r#""scale": [0, 0, 0], "rotation": [{}, {}, {}, {}], "translation": [1, 2, 3]"#,
            r[0], r[1], r[2], r[3]
        ),
        r#""translation": [5, 5, 5]"#,
    ));
    let p = s.pose_at(0, 0.0).unwrap();
    assert_eq!(
        p,
        Pose {
            translation: [1.0, 2.0, 3.0],
            scale: 0.0,
            rotation: [0.0, 0.0, 0.0, 1.0]
        }
    );
    assert!(p.is_valid());
}

/// Indices stored as floats take 4 bytes each, twice the `UNSIGNED_SHORT` they replace: the
/// error names the kind, not the bytes that kind would need.
#[test]
fn an_accessor_of_the_wrong_kind_is_named_before_its_bytes_are_read() {
    let mut d = Doc::default();
    let p = d.vec3s(&TET);
    let bytes: Vec<u8> = TET_INDICES.iter().flat_map(|x| x.to_le_bytes()).collect();
    let view = d.view(&bytes);
    let ix = d.raw_accessor(format!(
        r#"{{"bufferView": {view}, "componentType": 5126, "count": 12, "type": "SCALAR"}}"#
    ));
    d.mesh(format!(
        r#"{{"primitives": [{{"attributes": {{"POSITION": {p}}}, "indices": {ix}}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    let e = load_err(&d.gltf(&[0]));
    assert_says(&e, &["indices", "UNSIGNED_INT SCALAR, not FLOAT SCALAR"]);
    assert!(!e.contains("run past"), "{e}");
    // Four positions said to be VEC4: 64 bytes, past the view of four VEC3.
    let mut d = Doc::default();
    let bytes: Vec<u8> = TET.concat().iter().flat_map(|x| x.to_le_bytes()).collect();
    let view = d.view(&bytes);
    let p = d.raw_accessor(format!(
        r#"{{"bufferView": {view}, "componentType": 5126, "count": 4, "type": "VEC4"}}"#
    ));
    d.mesh(format!(
        r#"{{"primitives": [{{"attributes": {{"POSITION": {p}}}}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    let e = load_err(&d.gltf(&[0]));
    assert_says(
        &e,
        &[
            "POSITION",
            "is FLOAT VEC4, but positions must be FLOAT VEC3",
        ],
    );
}

#[test]
fn quantized_and_compressed_meshes_name_the_mesh() {
    let mut d = Doc::default();
    let bytes: Vec<u8> = [0u16, 0, 0, 1, 0, 0, 0, 1, 0]
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let view = d.view(&bytes);
    let p = d.raw_accessor(format!(r#"{{"bufferView": {view}, "componentType": 5123, "normalized": true, "count": 3, "type": "VEC3"}}"#));
    d.mesh(format!(
        r#"{{"name": "small", "primitives": [{{"attributes": {{"POSITION": {p}}}}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    d.extra.push(r#""extensionsUsed": ["KHR_mesh_quantization"], "extensionsRequired": ["KHR_mesh_quantization"]"#.into());
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"small\"", "FLOAT VEC3", "KHR_mesh_quantization"],
    );

    let mut d = Doc::default();
    let p = d.vec3s(&TET);
    d.mesh(format!(
        r#"{{"name": "squeezed", "primitives": [{{"attributes": {{"POSITION": {p}}}, "extensions": {{"KHR_draco_mesh_compression": {{"bufferView": 0, "attributes": {{"POSITION": 0}}}}}}}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"squeezed\"", "KHR_draco_mesh_compression"],
    );

    let mut d = Doc::default();
    d.tet("opt");
    d.views[0] = d.views[0].replace('}', r#", "extensions": {"EXT_meshopt_compression": {"buffer": 0, "byteLength": 48, "byteStride": 12, "count": 4, "mode": "ATTRIBUTES"}}}"#);
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"opt\"", "EXT_meshopt_compression"],
    );
}

#[test]
fn bad_indices_and_accessors_name_the_mesh() {
    // An index past the vertices.
    let mut d = Doc::default();
    d.tri_mesh("far", &TET, &[0, 1, 4]);
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"far\"", "index 2 is 4", "4 vertices"],
    );

    // Positions as VEC2.
    let mut d = Doc::default();
    let p = d.floats(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0], "VEC2");
    d.mesh(format!(
        r#"{{"name": "flat", "primitives": [{{"attributes": {{"POSITION": {p}}}}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"flat\"", "POSITION", "FLOAT VEC3", "VEC2"],
    );

    // Float indices.
    let mut d = Doc::default();
    let p = d.vec3s(&TET);
    let i = d.floats(&[0.0, 1.0, 2.0], "SCALAR");
    d.mesh(format!(
        r#"{{"name": "fi", "primitives": [{{"attributes": {{"POSITION": {p}}}, "indices": {i}}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"fi\"", "indices", "UNSIGNED"],
    );

    // An accessor that runs past its view, and a view past its buffer.
    let mut d = Doc::default();
    d.tet("long");
    d.accessors[0] = d.accessors[0].replace(r#""count": 4"#, r#""count": 5"#);
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"long\"", "accessor 0", "run past"],
    );
    let mut d = Doc::default();
    d.tet("wide");
    d.views[1] = d.views[1].replace(r#""byteLength": 24"#, r#""byteLength": 2400"#);
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"wide\"", "buffer view 1", "run past"],
    );

    // An unknown component type, and a NaN position.
    let mut d = Doc::default();
    d.tet("dbl");
    d.accessors[0] = d.accessors[0].replace("5126", "5130");
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"dbl\"", "componentType"],
    );
    let mut d = Doc::default();
    d.tri_mesh(
        "nan",
        &[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0]],
        &[0, 1, 2],
    );
    d.node(r#"{"mesh": 0}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["mesh 0 \"nan\"", "vertex 1 is not finite"],
    );
}

#[test]
fn sparse_accessors_replace_their_elements() {
    let mut d = Doc::default();
    let p = d.vec3s(&[
        [0.0, 0.0, 0.0],
        [9.0, 9.0, 9.0],
        [0.0, 1.0, 0.0],
        [9.0, 9.0, 9.0],
    ]);
    let iv = d.view(&[1u8, 3, 0, 0]);
    let vv = d.view(
        &[[1.0f32, 0.0, 0.0], [0.0, 0.0, 1.0]]
            .concat()
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect::<Vec<u8>>(),
    );
    d.accessors[p] = d.accessors[p].replace(
        '}',
        &format!(r#", "sparse": {{"count": 2, "indices": {{"bufferView": {iv}, "componentType": 5121}}, "values": {{"bufferView": {vv}}}}}}}"#),
    );
    let i = d.u16s(&TET_INDICES);
    d.mesh(format!(
        r#"{{"primitives": [{{"attributes": {{"POSITION": {p}}}, "indices": {i}}}]}}"#
    ));
    d.node(r#"{"mesh": 0}"#);
    let s = load_ok(&d.gltf(&[0]));
    assert_eq!(s.meshes[0].mesh.positions, TET);

    // Without a buffer view the base is zeros.
    let mut d2 = d.clone();
    d2.accessors[p] = d2.accessors[p].replace(r#""bufferView": 0, "#, "");
    let s = load_ok(&d2.gltf(&[0]));
    assert_eq!(s.meshes[0].mesh.positions[2], [0.0; 3]);
    assert_eq!(s.meshes[0].mesh.positions[3], [0.0, 0.0, 1.0]);

    // A sparse index past the count.
    let mut d3 = d.clone();
    let off = 48; // The index view follows the 48 bytes of positions.
    d3.bin[off + 1] = 7;
    assert_says(
        &load_err(&d3.gltf(&[0])),
        &["mesh 0", "sparse index 1 is 7"],
    );
}

#[test]
fn bad_keys_name_the_animation_channel_and_node() {
    let nan = |d: &mut Doc| d.channel(0, "translation", "LINEAR", &[0.0, f32::NAN], &[0.0; 6]);
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "mover", "mesh": {m}}}"#));
    nan(&mut d);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &[
            "test.gltf",
            "animation 0 \"translation of 0\"",
            "channel 0",
            "node 0 \"mover\"",
            "key time 1 is not finite",
        ],
    );

    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "mover", "mesh": {m}}}"#));
    d.channel(0, "translation", "LINEAR", &[0.0, 2.0, 1.0], &[0.0; 9]);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["channel 0", "strictly increase", "key 2"],
    );

    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "mover", "mesh": {m}}}"#));
    d.channel(
        0,
        "translation",
        "LINEAR",
        &[0.0, 1.0],
        &[0.0, 0.0, 0.0, f32::INFINITY, 0.0, 0.0],
    );
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["channel 0", "value 3 of key 1 is not finite"],
    );

    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "mover", "mesh": {m}}}"#));
    d.channel(0, "translation", "CUBICSPLINE", &[0.0, 1.0], &[0.0; 6]);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &[
            "channel 0",
            "2 keys of CUBICSPLINE translation need 18 values",
        ],
    );

    // A channel that animates a matrix node.
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(
        r#"{{"name": "fixed", "mesh": {m}, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}}"#
    ));
    d.channel(0, "translation", "LINEAR", &[0.0, 1.0], &[0.0; 6]);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["channel 0", "node 0 \"fixed\"", "matrix"],
    );
}

#[test]
fn cycles_and_second_parents_are_errors_naming_the_node() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "a", "mesh": {m}, "children": [1]}}"#));
    d.node(r#"{"name": "b", "children": [0]}"#);
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["node 0 \"a\"", "its own ancestor"],
    );

    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(r#"{"name": "a", "children": [2]}"#);
    d.node(r#"{"name": "b", "children": [2]}"#);
    d.node(&format!(r#"{{"name": "c", "mesh": {m}}}"#));
    assert_says(
        &load_err(&d.gltf(&[0, 1])),
        &[
            "node 2 \"c\"",
            "two parents",
            "node 0 \"a\"",
            "node 1 \"b\"",
        ],
    );

    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "a", "mesh": {m}, "children": [5]}}"#));
    assert_says(
        &load_err(&d.gltf(&[0])),
        &["node 0 \"a\"", "child 5 does not exist"],
    );
    assert_says(&load_err(&d.gltf(&[3])), &["scene 0 lists node 3"]);
}

#[test]
fn the_default_scene_is_used_and_scene_zero_without_one() {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "in0", "mesh": {m}}}"#));
    d.node(&format!(r#"{{"name": "in1", "mesh": {m}}}"#));
    let text = d.gltf(&[0]);
    let two_scenes = text.replace(
        r#""scene": 0, "scenes": [{"nodes": [0]}]"#,
        r#""scene": 1, "scenes": [{"nodes": [0]}, {"nodes": [1, 0]}]"#,
    );
    let s = load_ok(&two_scenes);
    assert_eq!(s.instances().len(), 2);
    assert_eq!(s.instances()[0].node, 1);
    let no_default = text.replace(r#""scene": 0, "#, "");
    assert_eq!(load_ok(&no_default).instances().len(), 1);
}

// ---------------------------------------------------------------------------------------------
// Containers and buffers.
// ---------------------------------------------------------------------------------------------

fn two_node_doc() -> Doc {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "a", "mesh": {m}, "children": [1]}}"#));
    d.node(&format!(
        r#"{{"name": "b", "mesh": {m}, "translation": [1, 0, 0]}}"#
    ));
    d.channel(
        1,
        "translation",
        "LINEAR",
        &[0.0, 1.0],
        &[1.0, 0.0, 0.0, 2.0, 0.0, 0.0],
    );
    d
}

#[test]
fn glb_and_embedded_gltf_read_the_same_scene() {
    let d = two_node_doc();
    let (a, _) = parse_gltf("t.gltf", d.gltf(&[0]).as_bytes(), None).unwrap();
    let (b, _) = parse_gltf("t.glb", &d.glb(&[0]), None).unwrap();
    assert_eq!(a, b);
    assert_eq!(b.pose_at(1, 0.5).unwrap().translation, [1.5, 0.0, 0.0]);
}

#[test]
fn every_truncation_of_a_glb_is_an_error_never_a_panic() {
    let bytes = two_node_doc().glb(&[0]);
    for len in 0..bytes.len() {
        let r = parse_gltf("cut.glb", &bytes[..len], None);
        let e = r.err().unwrap_or_else(|| panic!("{len} bytes loaded"));
        assert!(e.to_string().starts_with("cut.glb: "), "{e}");
    }
    // A header length shorter than the header itself (which the gltf crate's own splitter
    // would subtract from before checking).
    let mut short = bytes.clone();
    short[8..12].copy_from_slice(&4u32.to_le_bytes());
    assert_says(
        &parse_gltf("s.glb", &short, None).unwrap_err().to_string(),
        &["s.glb", "too short"],
    );
    let mut v1 = bytes;
    v1[4] = 1;
    assert_says(
        &parse_gltf("v.glb", &v1, None).unwrap_err().to_string(),
        &["GLB version 1"],
    );
}

#[test]
fn mutated_inputs_are_errors_or_scenes_never_panics() {
    // A cheap fuzz: bytes of the GLB and of the JSON replaced at random; every outcome must
    // be a value.
    let glb = two_node_doc().glb(&[0]);
    let text = two_node_doc().gltf(&[0]).into_bytes();
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for input in [&glb, &text] {
        for _ in 0..3000 {
            let mut b = input.clone();
            for _ in 0..1 + next() % 4 {
                let at = (next() % b.len() as u64) as usize;
                b[at] = match next() % 4 {
                    0 => b'9',
                    1 => b'-',
                    2 => 0xff,
                    _ => next() as u8,
                };
            }
            let _ = parse_gltf("m.glb", &b, None);
        }
    }
}

#[test]
fn external_buffers_are_read_beside_the_file_and_never_above_it() {
    let dir = test_dir("external");
    let d = two_node_doc();
    std::fs::write(dir.join("data.bin"), &d.bin).unwrap();
    let buffer = format!(
        r#"{{"byteLength": {}, "uri": "sub%20dir/../data.bin"}}"#,
        d.bin.len()
    );
    let text = d.json_with(&[0], &buffer);
    std::fs::write(dir.join("climb.gltf"), &text).unwrap();
    assert_says(
        &load_gltf(&dir.join("climb.gltf")).unwrap_err().to_string(),
        &["climb.gltf", "buffer 0", "`..`"],
    );

    let text = d.json_with(
        &[0],
        &format!(r#"{{"byteLength": {}, "uri": "data.bin"}}"#, d.bin.len()),
    );
    std::fs::write(dir.join("ok.gltf"), &text).unwrap();
    let (s, _) = load_gltf(&dir.join("ok.gltf")).unwrap();
    assert_eq!(s.instances().len(), 2);

    let text = d.json_with(
        &[0],
        &format!(r#"{{"byteLength": {}, "uri": "missing.bin"}}"#, d.bin.len()),
    );
    std::fs::write(dir.join("missing.gltf"), &text).unwrap();
    assert_says(
        &load_gltf(&dir.join("missing.gltf"))
            .unwrap_err()
            .to_string(),
        &["missing.gltf", "mesh 0", "cannot read", "missing.bin"],
    );

    let text = d.json_with(
        &[0],
        &format!(r#"{{"byteLength": {}, "uri": "/etc/passwd"}}"#, d.bin.len()),
    );
    std::fs::write(dir.join("abs.gltf"), &text).unwrap();
    assert_says(
        &load_gltf(&dir.join("abs.gltf")).unwrap_err().to_string(),
        &["abs.gltf", "absolute paths are refused"],
    );

    let text = d.json_with(
        &[0],
        &format!(
            r#"{{"byteLength": {}, "uri": "https://example.com/x.bin"}}"#,
            d.bin.len()
        ),
    );
    assert_says(
        &parse_gltf("web.gltf", text.as_bytes(), Some(&dir))
            .unwrap_err()
            .to_string(),
        &["web.gltf", "only relative paths"],
    );

    // In memory, without a folder, an external buffer cannot be found.
    let text = d.json_with(
        &[0],
        &format!(r#"{{"byteLength": {}, "uri": "data.bin"}}"#, d.bin.len()),
    );
    assert_says(
        &parse(&text).unwrap_err().to_string(),
        &["test.gltf", "without a folder"],
    );

    // A buffer shorter than its byteLength.
    let text = d.json_with(
        &[0],
        &format!(
            r#"{{"byteLength": {}, "uri": "data.bin"}}"#,
            d.bin.len() + 4
        ),
    );
    assert_says(
        &parse_gltf("short.gltf", text.as_bytes(), Some(&dir))
            .unwrap_err()
            .to_string(),
        &["should hold"],
    );
}

#[test]
fn malformed_documents_name_the_file() {
    assert_says(&load_err("{"), &["test.gltf", "not valid glTF JSON"]);
    assert_says(
        &load_err(r#"{"asset": {"version": "1.0"}}"#),
        &["test.gltf", "version \"1.0\""],
    );
    assert_says(
        &load_err(r#"{"asset": {"version": "2.0"}}"#),
        &["test.gltf", "no scene"],
    );
    assert_says(
        &load_err(r#"{"asset": {"version": "2.0"}, "scene": 2, "scenes": [{"nodes": []}]}"#),
        &["default scene 2"],
    );
    let err = load_gltf(Path::new("/nonexistent/x.gltf"))
        .unwrap_err()
        .to_string();
    assert_says(&err, &["/nonexistent/x.gltf", "cannot read"]);
}

#[test]
fn base64_round_trips_and_rejects_bad_text() {
    for n in 0..20 {
        let bytes: Vec<u8> = (0..n).map(|k| (k * 37 + 5) as u8).collect();
        assert_eq!(
            decode_base64(encode_base64(&bytes).as_bytes()).unwrap(),
            bytes
        );
    }
    assert_eq!(decode_base64(b"TWFu").unwrap(), b"Man");
    assert_eq!(decode_base64(b"TWE").unwrap(), b"Ma");
    assert!(decode_base64(b"TW=u").is_err());
    assert!(decode_base64(b"T").is_err());
    assert!(decode_base64(b"TWE=x").is_err());
    assert!(decode_base64(b"TW\nu").is_err());
}

fn test_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("octoproxy-gltf-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

// ---------------------------------------------------------------------------------------------
// The baked scene file.
// ---------------------------------------------------------------------------------------------

fn small_params() -> BuildParams {
    BuildParams {
        dmin: 1,
        dmax: 3,
        lut_depth: 1,
        ..Default::default()
    }
}

/// A small baked scene with a hierarchy, a matrix node, instancing and every interpolation.
fn small_baked() -> (SceneDescription, BakedScene) {
    let mut d = Doc::default();
    let m = d.tet("tet");
    let t = d.vec3s(&[[0.0, 2.0, 0.0], [0.0, 4.0, 0.0]]);
    d.node(&format!(
        r#"{{"name": "root", "mesh": {m}, "children": [1, 2]}}"#
    ));
    d.node(&format!(
        r#"{{"name": "ärm", "mesh": {m}, "translation": [1, 0, 0]}}"#
    ));
    d.node(&format!(
        r#"{{"mesh": {m}, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,3,1],
            "extensions": {{"EXT_mesh_gpu_instancing": {{"attributes": {{"TRANSLATION": {t}}}}}}}}}"#
    ));
    let q = axis_angle([0.0, 0.0, 1.0], 60.0);
    d.channel(
        0,
        "rotation",
        "LINEAR",
        &[0.0, 1.0],
        &[0.0, 0.0, 0.0, 1.0, q[0], q[1], q[2], q[3]],
    );
    d.channel(
        1,
        "translation",
        "STEP",
        &[0.0, 0.5],
        &[1.0, 0.0, 0.0, 2.0, 0.0, 0.0],
    );
    #[rustfmt::skip]
    d.channel(1, "scale", "CUBICSPLINE", &[0.0, 1.0], &[
        0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.5,
        0.5, 0.5, 0.5, 2.0, 2.0, 2.0, 0.0, 0.0, 0.0,
    ]);
    let (s, _) = parse(&d.gltf(&[0])).unwrap();
    let (baked, reports) = bake_scene(&s, &small_params(), &()).unwrap();
    assert_eq!(reports.len(), 1);
    (s, baked)
}

#[test]
fn a_baked_scene_round_trips_exactly_and_samples_the_same_poses() {
    let (s, baked) = small_baked();
    assert_eq!(baked.proxies().len(), 1);
    assert_eq!(baked.instances().len(), 4);
    let bytes = baked.encode();
    let back = BakedScene::parse("small.oscn", &bytes).unwrap();
    assert_eq!(back, baked);
    assert_eq!(back.encode(), bytes);
    assert_eq!(back.meshes(), s.meshes.as_slice());
    assert_eq!(back.graph(), &s.graph);
    for k in 0..=24 {
        let t = k as f64 / 16.0 - 0.25;
        assert_eq!(back.poses_at(t).unwrap(), s.poses_at(t).unwrap(), "t = {t}");
    }
    assert_eq!(back.duration(), 1.0);

    let dir = test_dir("baked");
    let path = dir.join("small.oscn");
    baked.write(&path).unwrap();
    assert_eq!(BakedScene::read(&path).unwrap(), baked);
}

#[test]
fn a_baked_scene_builds_a_scene_with_the_gltf_instance_indices() {
    let (s, baked) = small_baked();
    let (mut scene, ids) = baked.build_scene().unwrap();
    assert_eq!(ids, [0, 1, 2, 3]);
    assert_eq!(scene.proxies().len(), 1);
    let poses = s.poses_at(0.0).unwrap();
    for (k, inst) in scene.instances().iter().enumerate() {
        assert_eq!(inst.start, poses[k]);
        assert_eq!(inst.end, poses[k]);
    }
    scene.prepare().unwrap();
    let list = baked.list_instances().unwrap();
    assert_eq!(list[1].node_name, "ärm");
    assert_eq!(list[2].copy, 0);
    assert_eq!(list[3].copy, 1);
    assert_eq!(list[3].pose.translation, [0.0, 4.0, 3.0]);
    assert_eq!(list[0].mesh_name, "tet");
}

#[test]
fn every_truncation_and_every_flipped_bit_of_a_baked_file_is_an_error() {
    let (_, baked) = small_baked();
    let bytes = baked.encode();
    assert!(
        bytes.len() < 4096,
        "{} bytes: keep the file small",
        bytes.len()
    );
    for len in 0..bytes.len() {
        let e = BakedScene::parse("cut.oscn", &bytes[..len]).unwrap_err();
        assert!(e.to_string().starts_with("cut.oscn: "), "{e}");
    }
    let mut kinds = std::collections::BTreeSet::new();
    for bit in 0..bytes.len() * 8 {
        let mut b = bytes.clone();
        b[bit / 8] ^= 1 << (bit % 8);
        match BakedScene::parse("flip.oscn", &b) {
            Ok(_) => panic!("bit {bit} flipped and the file still read"),
            Err(e) => {
                assert!(e.to_string().starts_with("flip.oscn: "), "{e}");
                kinds.insert(
                    format!("{e:?}")
                        .split([' ', '{', '('])
                        .next()
                        .unwrap_or("")
                        .to_string(),
                );
            }
        }
    }
    // Damage shows as its own error where structure can tell, as a checksum mismatch where not.
    for k in [
        "Magic",
        "Version",
        "Length",
        "Checksum",
        "Truncated",
        "Proxy",
    ] {
        assert!(
            kinds.contains(k),
            "no flipped bit gave a {k} error: {kinds:?}"
        );
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert_says(
        &BakedScene::parse("long.oscn", &longer)
            .unwrap_err()
            .to_string(),
        &["long.oscn", "trailing bytes"],
    );
}

#[test]
fn baked_files_with_consistent_but_bad_content_are_refused() {
    let (_, baked) = small_baked();
    // Re-seal a damaged file so that only the structure can catch it.
    let reseal = |mut b: Vec<u8>| {
        let n = b.len() - 8;
        let sum = super::baked::fnv1a64(&b[..n]);
        b[n..].copy_from_slice(&sum.to_le_bytes());
        b
    };
    let bytes = baked.encode();
    // The first instance's node (after the header, the mesh section and the nodes).
    let s = BakedScene::parse("x", &bytes).unwrap();
    let instance_at = bytes.len() - 8 - channels_bytes(&s) - 56 * s.instances().len();
    let mut b = bytes.clone();
    b[instance_at..instance_at + 4].copy_from_slice(&99u32.to_le_bytes());
    assert_says(
        &BakedScene::parse("bad.oscn", &reseal(b))
            .unwrap_err()
            .to_string(),
        &["bad.oscn", "instance 0", "node 99"],
    );
    // A proxy word changed: the proxy's own checksum catches it, named by proxy index.
    let mut b = bytes.clone();
    // The header, the mesh (its name, two counts, 4 vertices and 4 triangles), the proxy's
    // mesh, scale and word count, then its word 5.
    let proxy_word = 48 + 4 + 4 + 8 + 48 + 48 + 12 + 4 * 5;
    b[proxy_word] ^= 1;
    assert_says(
        &BakedScene::parse("p.oscn", &reseal(b))
            .unwrap_err()
            .to_string(),
        &["p.oscn", "proxy 0"],
    );
    // A NaN key time.
    let mut b = bytes.clone();
    let first_time = bytes.len() - 8 - channels_bytes(&s) + 16;
    b[first_time..first_time + 4].copy_from_slice(&f32::NAN.to_bits().to_le_bytes());
    assert_says(
        &BakedScene::parse("t.oscn", &reseal(b))
            .unwrap_err()
            .to_string(),
        &["t.oscn", "channel 0", "not finite"],
    );
    // Another version and other magic.
    let mut b = bytes.clone();
    b[8] = 7;
    assert_says(
        &BakedScene::parse("v.oscn", &b).unwrap_err().to_string(),
        &["v.oscn", "version 7"],
    );
    assert_says(
        &BakedScene::parse("m.oscn", b"glTF....")
            .unwrap_err()
            .to_string(),
        &["m.oscn", "not an octoproxy scene file"],
    );
}

/// A tetrahedron placed four times: at scale 1, twice at scale 2 (one of them turning over
/// the animation, under a parent of scale 2), and at scale 0.5.
fn scaled_tets() -> SceneDescription {
    let mut d = Doc::default();
    let m = d.tet("tet");
    d.node(&format!(r#"{{"name": "one", "mesh": {m}}}"#));
    d.node(&format!(
        r#"{{"name": "two", "mesh": {m}, "scale": [2, 2, 2], "translation": [4, 0, 0]}}"#
    ));
    d.node(r#"{"name": "parent", "scale": [2, 2, 2], "translation": [0, 4, 0], "children": [3]}"#);
    d.node(&format!(r#"{{"name": "turning", "mesh": {m}}}"#));
    d.node(&format!(
        r#"{{"name": "half", "mesh": {m}, "scale": [0.5, 0.5, 0.5], "translation": [0, 0, 4]}}"#
    ));
    let q = axis_angle([0.3, 0.8, 0.5], 170.0);
    d.channel(
        3,
        "rotation",
        "LINEAR",
        &[0.0, 0.5, 1.0],
        &[
            0.0, 0.0, 0.0, 1.0, q[0], q[1], q[2], q[3], 0.0, 0.0, 0.0, 1.0,
        ],
    );
    parse(&d.gltf(&[0, 1, 2, 4])).unwrap().0
}

fn radius_params() -> BuildParams {
    BuildParams {
        dmin: 2,
        dmax: 6,
        lut_depth: 1,
        ..Default::default()
    }
}

#[test]
fn a_scene_baked_for_a_radius_has_one_proxy_per_mesh_and_world_scale() {
    let s = scaled_tets();
    let radius = 0.1f32;
    let (baked, reports, surfaces) =
        bake_scene_for_radius(&s, &radius_params(), radius, &()).unwrap();
    // Scales 1, 2 (twice: a node's own and a parent's) and 0.5: three proxies.
    assert_eq!(baked.instance_proxies(), &[0, 1, 1, 2]);
    let scales: Vec<f32> = baked.proxies().iter().map(|p| p.scale).collect();
    assert_eq!(scales, [1.0, 2.0, 0.5]);
    assert_eq!((reports.len(), surfaces.len()), (3, 3));
    assert_eq!(baked.radius(), radius);
    for (p, surface) in baked.proxies().iter().zip(&surfaces) {
        let view = octoproxy_core::ProxyView::new(&p.words).unwrap();
        let local = view.header().radius;
        assert!(
            octoproxy_core::check_radius(local * p.scale, radius).is_ok(),
            "proxy at scale {} baked for {local}",
            p.scale
        );
        assert_eq!(surface.radius(), local);
    }
    // The file keeps it all, and the surfaces are built again from it alike.
    let back = BakedScene::parse("r.oscn", &baked.encode()).unwrap();
    assert_eq!(back, baked);
    let again = back.offset_surfaces(&()).unwrap();
    assert_eq!(again.len(), 3);
    for (a, b) in again.iter().zip(&surfaces) {
        assert_eq!(a.radius(), b.radius());
        assert_eq!(a.mesh().triangles.len(), b.mesh().triangles.len());
    }
    // Every pose the animation samples has exactly its proxy's scale (the turning one's
    // world scale is rounded from a turning matrix), so a scene step at the radius takes it.
    for k in 0..=40 {
        let t = k as f64 / 32.0 - 0.1;
        for (i, pose) in baked.poses_at(t).unwrap().iter().enumerate() {
            let p = baked.instance_proxies()[i] as usize;
            assert_eq!(
                pose.scale.to_bits(),
                baked.proxies()[p].scale.to_bits(),
                "t {t}"
            );
            assert_eq!(baked.pose_at(i as u32, t).unwrap(), *pose);
        }
    }
    let (mut scene, _) = baked.build_scene().unwrap();
    let mut cpu = crate::CpuBackend::new();
    let particles: Vec<octoproxy_core::Particle> = (0..64)
        .map(|i| octoproxy_core::Particle::new([i as f32 * 0.1 - 1.0, 6.0, 0.5], [0.0; 3]))
        .collect();
    use octoproxy_core::Backend as _;
    cpu.upload_particles(&particles).unwrap();
    let params = octoproxy_core::StepParams {
        dt: 1.0 / 32.0,
        radius,
        ..Default::default()
    };
    for k in 1..=32 {
        for (i, pose) in baked
            .poses_at(k as f64 / 32.0)
            .unwrap()
            .into_iter()
            .enumerate()
        {
            scene.move_to(i as u32, pose).unwrap();
        }
        scene.step(&mut cpu, &params, false).unwrap();
    }
    // Another radius is refused by the step, naming the instance.
    let wrong = octoproxy_core::StepParams {
        radius: 0.2,
        ..params
    };
    let e = scene.step(&mut cpu, &wrong, false).unwrap_err().to_string();
    assert_says(&e, &["instance 0", "radius"]);
}

#[test]
fn a_radius_with_an_animated_scale_is_an_error_naming_the_node() {
    // small_baked's "ärm" grows from 1 to 2 over its animation.
    let (s, _) = small_baked();
    let e = match bake_scene_for_radius(&s, &small_params(), 0.05, &()) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("an animated scale baked for a radius"),
    };
    assert_says(
        &e,
        &["instance 1", "ärm", "world scale changes", "radius 0.05"],
    );
    for bad in [-1.0, f32::NAN, f32::INFINITY] {
        let e = match bake_scene_for_radius(&s, &small_params(), bad, &()) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("radius {bad} baked"),
        };
        assert_says(&e, &["radius must be a finite number"]);
    }
}

#[test]
fn a_baked_file_whose_radius_does_not_fit_its_proxies_is_refused() {
    let s = scaled_tets();
    let (baked, _, _) = bake_scene_for_radius(&s, &radius_params(), 0.1, &()).unwrap();
    let reseal = |mut b: Vec<u8>| {
        let n = b.len() - 8;
        let sum = super::baked::fnv1a64(&b[..n]);
        b[n..].copy_from_slice(&sum.to_le_bytes());
        b
    };
    let bytes = baked.encode();
    for (radius, needle) in [
        (0.2f32, "proxy 0 is baked for radius"),
        (0.0, "proxy 0 is baked for radius"),
        (f32::NAN, "the particle radius is NaN"),
        (-0.1, "must be a finite number >= 0"),
    ] {
        let mut b = bytes.clone();
        b[36..40].copy_from_slice(&radius.to_bits().to_le_bytes());
        assert_says(
            &BakedScene::parse("r.oscn", &reseal(b))
                .unwrap_err()
                .to_string(),
            &["r.oscn", needle],
        );
    }
    // An instance given another mesh's proxy or another scale's.
    let instances_at = bytes.len() - 8 - channels_bytes(&baked) - 56 * 4;
    let mut b = bytes.clone();
    b[instances_at + 12..instances_at + 16].copy_from_slice(&1u32.to_le_bytes());
    assert_says(
        &BakedScene::parse("i.oscn", &reseal(b))
            .unwrap_err()
            .to_string(),
        &[
            "i.oscn",
            "instance 0 has world scale 1",
            "proxy 1 is baked for scale 2",
        ],
    );
    let mut b = bytes.clone();
    b[instances_at + 12..instances_at + 16].copy_from_slice(&7u32.to_le_bytes());
    assert_says(
        &BakedScene::parse("i.oscn", &reseal(b))
            .unwrap_err()
            .to_string(),
        &["i.oscn", "instance 0", "proxy 7"],
    );
}

fn channels_bytes(s: &BakedScene) -> usize {
    s.graph()
        .channels()
        .iter()
        .map(|c| 16 + 4 * (c.times.len() + c.values.len()))
        .sum()
}

// ---------------------------------------------------------------------------------------------
// Files from real exporters.
// ---------------------------------------------------------------------------------------------

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/gltf")
}

mod blender;
mod khronos;
