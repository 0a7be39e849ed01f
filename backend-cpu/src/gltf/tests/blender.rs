//! Scenes exported by Blender 3.4's own glTF exporter (made by
//! `tests/data/gltf/blender/make_blender_scene.py`), whose sampled poses must match Blender's
//! world matrices of the same objects at the same moments, converted to y-up as the exporter
//! converts.

use glam::{DMat4, DQuat, DVec3};
use gltf::json::Value;

use super::*;

/// Blender's world matrix of object `name` at each sampled frame: (frame, time, matrix).
fn blender_frames(name: &str) -> Vec<(f64, f64, DMat4)> {
    let text = std::fs::read_to_string(data_dir().join("blender/blender_frames.json")).unwrap();
    let json: Value = gltf::json::deserialize::from_str(&text).unwrap();
    let samples = json["objects"][name]
        .as_array()
        .unwrap_or_else(|| panic!("no object {name}"));
    samples
        .iter()
        .map(|s| {
            let m: Vec<f64> = s["matrix"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            // Row-major in the file; glam's constructor takes columns.
            let cols = [0, 1, 2, 3].map(|c| [m[c], m[4 + c], m[8 + c], m[12 + c]]);
            (
                s["frame"].as_f64().unwrap(),
                s["time"].as_f64().unwrap(),
                DMat4::from_cols_array_2d(&cols),
            )
        })
        .collect()
}

fn pose_matrix(p: &Pose) -> DMat4 {
    let [x, y, z, w] = p.rotation.map(|c| c as f64);
    DMat4::from_scale_rotation_translation(
        DVec3::splat(p.scale as f64),
        DQuat::from_xyzw(x, y, z, w),
        DVec3::from_array(p.translation.map(|c| c as f64)),
    )
}

/// Our pose of the instance on node `name` matches Blender's matrix at every sample for which
/// `use_frame` holds, within 1e-4 relative (the exporter writes f32, and Blender composes in
/// f32).
fn compare(scene: &SceneDescription, name: &str, use_frame: impl Fn(f64) -> bool) -> usize {
    let k = scene
        .list_instances()
        .unwrap()
        .iter()
        .position(|i| i.node_name == name)
        .unwrap_or_else(|| panic!("no instance {name}")) as u32;
    let mut compared = 0;
    for (frame, time, theirs) in blender_frames(name) {
        if !use_frame(frame) {
            continue;
        }
        let pose = scene.pose_at(k, time).unwrap();
        let ours = pose_matrix(&pose);
        let scale = theirs.x_axis.truncate().length().max(1.0);
        for c in 0..3 {
            let d = (ours.col(c) - theirs.col(c)).abs().max_element();
            assert!(
                d <= 1e-4 * scale,
                "{name} at frame {frame}: column {c} differs by {d}\nours {ours}\ntheirs {theirs}"
            );
        }
        let t = theirs.w_axis.truncate();
        let d = (ours.w_axis.truncate() - t).abs().max_element();
        assert!(
            d <= 1e-4 * t.length().max(1.0),
            "{name} at frame {frame}: translation differs by {d}"
        );
        compared += 1;
    }
    compared
}

const OBJECTS: [&str; 5] = ["Parent", "Child", "DupStill", "DupStep", "DupLinear"];

fn check_structure(scene: &SceneDescription) {
    let list = scene.list_instances().unwrap();
    let names: Vec<&str> = list.iter().map(|i| i.node_name.as_str()).collect();
    // Pre-order: the parent (scene node 1) and its child, then the duplicates.
    assert_eq!(names, OBJECTS);
    let meshes: Vec<&str> = list.iter().map(|i| i.mesh_name.as_str()).collect();
    assert_eq!(
        meshes,
        ["Box", "Cone", "SharedIco", "SharedIco", "SharedIco"]
    );
    assert_eq!(scene.meshes.len(), 3);
    assert_eq!(scene.meshes[0].mesh.triangles.len(), 12);
    assert_eq!(scene.meshes[2].mesh.triangles.len(), 20);
    assert!((scene.duration() - 49.0 / 24.0).abs() < 1e-6);
}

#[test]
fn blenders_keyed_export_samples_as_blender_evaluates_between_keys() {
    // Sampling off: Bezier keys are CUBICSPLINE, CONSTANT keys STEP, LINEAR keys LINEAR; the
    // buffer is in a .bin beside the .gltf.
    let (scene, warnings) = load_gltf(&data_dir().join("blender/blender_keys.gltf")).unwrap();
    assert!(warnings.is_empty());
    check_structure(&scene);
    let interps: std::collections::BTreeSet<&str> = scene
        .graph
        .channels()
        .iter()
        .map(|c| c.interpolation.name())
        .collect();
    assert_eq!(
        interps.into_iter().collect::<Vec<_>>(),
        ["CUBICSPLINE", "LINEAR", "STEP"]
    );
    for name in OBJECTS {
        // Every sample, half frames and quarter frames included.
        assert_eq!(compare(&scene, name, |_| true), 16, "{name}");
    }
}

#[test]
fn blenders_sampled_export_matches_blender_at_every_frame() {
    // The default export samples every frame (LINEAR keys, STEP for the all-CONSTANT object),
    // so whole frames are keys.
    let (scene, warnings) = load_gltf(&data_dir().join("blender/blender_sampled.glb")).unwrap();
    assert!(warnings.is_empty());
    check_structure(&scene);
    let step = scene
        .graph
        .channels()
        .iter()
        .filter(|c| c.interpolation == Interpolation::Step)
        .count();
    assert_eq!(step, 1);
    for name in OBJECTS {
        assert!(compare(&scene, name, |f| f.fract() == 0.0) >= 10, "{name}");
    }
    // The two exports of one scene agree at whole frames.
    let (keys, _) = load_gltf(&data_dir().join("blender/blender_keys.gltf")).unwrap();
    for f in 1..=49 {
        let t = f as f64 / 24.0;
        for (a, b) in scene
            .poses_at(t)
            .unwrap()
            .iter()
            .zip(keys.poses_at(t).unwrap())
        {
            let d = (pose_matrix(a) - pose_matrix(&b)).abs();
            let worst = d
                .x_axis
                .max_element()
                .max(d.y_axis.max_element())
                .max(d.z_axis.max_element())
                .max(d.w_axis.max_element());
            assert!(worst < 1e-4, "frame {f}: {worst}");
        }
    }
}

#[test]
fn blenders_export_bakes_and_round_trips() {
    let (scene, _) = load_gltf(&data_dir().join("blender/blender_keys.gltf")).unwrap();
    let (baked, _) = bake_scene(&scene, &small_params(), &()).unwrap();
    let back = BakedScene::parse("blender.oscn", &baked.encode()).unwrap();
    assert_eq!(back, baked);
    for k in 0..40 {
        let t = k as f64 * 0.06;
        assert_eq!(back.poses_at(t).unwrap(), scene.poses_at(t).unwrap());
    }
    let (_, ids) = back.build_scene().unwrap();
    assert_eq!(ids, [0, 1, 2, 3, 4]);
}
