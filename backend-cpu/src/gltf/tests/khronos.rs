//! Khronos glTF sample models (`tests/data/gltf/khronos/`, sources and licences in the README
//! there): each loads with the expected instances and poses read off its own keyframes, or
//! gives the error it should.

use super::*;

fn load(name: &str) -> Result<(SceneDescription, Vec<GltfWarning>), GltfError> {
    load_gltf(&data_dir().join("khronos").join(name))
}

#[test]
fn box_composes_its_matrix_nodes_and_bakes() {
    let (s, warnings) = load("Box.gltf").unwrap();
    assert!(warnings.is_empty());
    assert_eq!(s.instances().len(), 1);
    assert_eq!(s.instances()[0].node, 1);
    assert_eq!(s.meshes[0].name, "Mesh");
    assert_eq!(s.meshes[0].mesh.triangles.len(), 12);
    // Node 0's matrix turns y to -z and z to y: -90° about x; node 1's is the identity.
    let p = s.pose_at(0, 0.0).unwrap();
    assert_pose(&p, [0.0; 3], 1.0, axis_angle([1.0, 0.0, 0.0], -90.0), 1e-6);
    assert_eq!(s.duration(), 0.0);
    let (baked, reports) = bake_scene(&s, &small_params(), &()).unwrap();
    assert_eq!(reports[0].closed_triangles, 12);
    assert_eq!(
        BakedScene::parse("box.oscn", &baked.encode()).unwrap(),
        baked
    );
}

#[test]
fn animated_triangle_slerps_its_keys_the_shorter_way() {
    let (s, _) = load("AnimatedTriangle.gltf").unwrap();
    assert_eq!(s.instances().len(), 1);
    // Its keys, read from the file: t = 0, 0.25, 0.5, 0.75, 1 with rotations about z of 0°,
    // 90°, 180°, 270° (written (0, 0, 0.707, -0.707)) and 360° (the identity again).
    assert_eq!(s.graph.channels()[0].times, [0.0, 0.25, 0.5, 0.75, 1.0]);
    assert_eq!(s.duration(), 1.0);
    let z = |deg: f32| axis_angle([0.0, 0.0, 1.0], deg);
    // 0.707 is not quite sin 45°: a few 1e-5 of slack on the keys' own rounding.
    let eps = 1e-4;
    assert_pose(&s.pose_at(0, 0.0).unwrap(), [0.0; 3], 1.0, z(0.0), eps);
    assert_pose(&s.pose_at(0, 0.125).unwrap(), [0.0; 3], 1.0, z(45.0), eps);
    assert_pose(&s.pose_at(0, 0.25).unwrap(), [0.0; 3], 1.0, z(90.0), eps);
    assert_pose(&s.pose_at(0, 0.5).unwrap(), [0.0; 3], 1.0, z(180.0), eps);
    assert_pose(&s.pose_at(0, 0.625).unwrap(), [0.0; 3], 1.0, z(225.0), eps);
    // From 270° to the identity the shorter way is on through 315°, not back through 135°.
    assert_pose(&s.pose_at(0, 0.875).unwrap(), [0.0; 3], 1.0, z(315.0), eps);
    assert_pose(&s.pose_at(0, 7.0).unwrap(), [0.0; 3], 1.0, z(0.0), eps);
}

#[test]
fn simple_meshes_shares_one_mesh_between_two_nodes() {
    let (s, _) = load("SimpleMeshes.gltf").unwrap();
    assert_eq!(s.instances().len(), 2);
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.instances()[1].mesh, 0);
    assert_eq!(s.pose_at(1, 0.0).unwrap().translation, [1.0, 0.0, 0.0]);
    // One triangle is open: it bakes into one proxy placed twice.
    let (baked, _) = bake_scene(&s, &small_params(), &()).unwrap();
    assert_eq!(baked.proxies().len(), 1);
    let (scene, ids) = baked.build_scene().unwrap();
    assert_eq!(ids, [0, 1]);
    assert_eq!(scene.instances()[0].proxy, scene.instances()[1].proxy);
}

#[test]
fn simple_skin_is_refused_naming_its_node() {
    let err = load("SimpleSkin.gltf").unwrap_err().to_string();
    assert_says(
        &err,
        &[
            "SimpleSkin.gltf",
            "node 0",
            "skin",
            "deforming meshes",
            "not supported yet",
        ],
    );
}

#[test]
fn simple_morph_is_refused_naming_its_mesh() {
    let err = load("SimpleMorph.gltf").unwrap_err().to_string();
    assert_says(
        &err,
        &[
            "SimpleMorph.gltf",
            "mesh 0",
            "morph targets",
            "not supported yet",
        ],
    );
}
