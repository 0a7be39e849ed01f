//! The glTF reader: the GLB container, buffers (embedded, in the GLB, or in files beside the
//! glTF file), accessors (strided, sparse, normalized), meshes, the scene's node tree,
//! `EXT_mesh_gpu_instancing` and animations, into a [`SceneDescription`].
//!
//! The JSON is deserialized into the `gltf` crate's model (`gltf::json::Root`) without its
//! validation, and every index this reader follows is checked here, where the error can name
//! the node, mesh or animation it belongs to. The GLB container is split here too (the crate's
//! splitter subtracts before it checks a header length).

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

use gltf::json::{self, accessor::ComponentType, accessor::Type, validation::Checked, Value};

use super::graph::{
    check_channel, check_transform, Channel, ChannelPath, Interpolation, NodeTransform, SceneGraph,
    SceneInstance, SceneNode, Trs,
};
use super::{decode_base64, GltfError, GltfWarning, SceneDescription, SceneMesh};
use crate::io::Mesh;

const GLB_MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// Reads a `.gltf` or `.glb` file; buffers in other files are looked for beside it.
pub fn load_gltf(path: &Path) -> Result<(SceneDescription, Vec<GltfWarning>), GltfError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| GltfError::Io {
        file: file.clone(),
        source,
    })?;
    let base = path.parent().map(|p| {
        if p.as_os_str().is_empty() {
            Path::new(".")
        } else {
            p
        }
    });
    parse_gltf(&file, &bytes, base)
}

/// Reads glTF from the bytes of a `.gltf` or `.glb` file (told apart by the GLB magic).
/// `name` is used in messages; buffers in other files are looked for in `base_dir` (`None`:
/// such a buffer is an error).
pub fn parse_gltf(
    name: &str,
    bytes: &[u8],
    base_dir: Option<&Path>,
) -> Result<(SceneDescription, Vec<GltfWarning>), GltfError> {
    let format = |message: String| GltfError::Format {
        file: name.to_string(),
        message,
    };
    let (json_bytes, bin) = if bytes.starts_with(GLB_MAGIC) {
        split_glb(bytes).map_err(format)?
    } else {
        (bytes, None)
    };
    let json_bytes = json_bytes
        .strip_prefix(b"\xEF\xBB\xBF")
        .unwrap_or(json_bytes);
    let root: json::Root = json::Root::from_slice(json_bytes)
        .map_err(|e| format(format!("not valid glTF JSON: {e}")))?;
    let major = root.asset.version.split('.').next().unwrap_or("");
    if major != "2" {
        return Err(format(format!(
            "glTF version {:?} is not supported (only 2.x)",
            root.asset.version
        )));
    }
    let mut loader = Loader {
        file: name.to_string(),
        root: &root,
        bin,
        base_dir,
        buffers: vec![None; root.buffers.len()],
        input_bytes: bytes.len(),
        warnings: Vec::new(),
    };
    let scene = loader.load()?;
    Ok((scene, loader.warnings))
}

fn le_u32(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// The JSON chunk and the optional BIN chunk of a GLB file.
fn split_glb(bytes: &[u8]) -> Result<(&[u8], Option<&[u8]>), String> {
    let truncated = || {
        format!(
            "the GLB file is truncated ({} bytes, shorter than its header says)",
            bytes.len()
        )
    };
    let version = le_u32(bytes, 4).ok_or_else(truncated)?;
    if version != 2 {
        return Err(format!("GLB version {version} is not supported (only 2)"));
    }
    let length = le_u32(bytes, 8).ok_or_else(truncated)? as usize;
    if length > bytes.len() {
        return Err(format!(
            "the GLB file is truncated: its header says {length} bytes, but it has {}",
            bytes.len()
        ));
    }
    if length < 20 {
        return Err(format!(
            "the GLB header's length {length} is too short for a JSON chunk"
        ));
    }
    let body = &bytes[..length];
    let mut at = 12usize;
    let mut json = None;
    let mut bin = None;
    let mut chunk = 0;
    while at < body.len() {
        let len = le_u32(body, at).ok_or_else(truncated)? as usize;
        let kind = le_u32(body, at + 4).ok_or_else(truncated)?;
        let start = at + 8;
        let end = start
            .checked_add(len)
            .filter(|&e| e <= body.len())
            .ok_or_else(|| {
                format!(
                    "GLB chunk {chunk} of {len} bytes at byte {at} runs past the end of the file ({} bytes)",
                    body.len()
                )
            })?;
        let data = &body[start..end];
        match (chunk, kind) {
            (0, CHUNK_JSON) => json = Some(data),
            (0, _) => return Err("the first GLB chunk is not JSON".into()),
            (1, CHUNK_BIN) => bin = Some(data),
            (_, CHUNK_JSON) => return Err(format!("GLB chunk {chunk} is a second JSON chunk")),
            (_, CHUNK_BIN) => {
                return Err(format!(
                    "GLB chunk {chunk} is a BIN chunk, but only the second chunk may be"
                ))
            }
            // Chunks of unknown types are skipped, as the specification asks.
            _ => {}
        }
        chunk += 1;
        // Chunks are padded to 4 bytes.
        at = end.div_ceil(4).saturating_mul(4);
    }
    let json = json.ok_or("the GLB file has no JSON chunk")?;
    Ok((json, bin))
}

/// `node 3 "Arm"`, for messages.
fn named(kind: &str, index: usize, name: &Option<String>) -> String {
    format!(
        "{kind} {index}{}",
        super::graph::quoted(name.as_deref().unwrap_or(""))
    )
}

/// An accessor's elements, tightly packed.
struct Packed {
    component: ComponentType,
    normalized: bool,
    ty: Type,
    count: usize,
    bytes: Vec<u8>,
}

fn component_size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

fn type_name(t: Type) -> &'static str {
    match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

fn component_name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

fn components(t: Type) -> usize {
    match t {
        Type::Scalar => 1,
        Type::Vec2 => 2,
        Type::Vec3 => 3,
        Type::Vec4 | Type::Mat2 => 4,
        Type::Mat3 => 9,
        Type::Mat4 => 16,
    }
}

/// `normalized UNSIGNED_SHORT VEC4`, for messages.
fn describe(component: ComponentType, ty: Type, normalized: bool) -> String {
    format!(
        "{}{} {}",
        if normalized { "normalized " } else { "" },
        component_name(component),
        type_name(ty)
    )
}

/// What a use of an accessor asks of its elements. It is checked before the accessor's bytes
/// are read, so an accessor of the wrong kind is named as such, not by where bytes of that
/// kind would run.
#[derive(Clone, Copy)]
enum Want {
    /// `FLOAT` of this type.
    Floats(Type),
    /// `FLOAT VEC3` positions (quantized ones are an extension octoproxy does not read).
    Positions,
    /// `FLOAT`, or a normalized 8- or 16-bit integer, of this type (rotations).
    FloatsOrNormalized(Type),
    /// An unsigned integer `SCALAR`, not normalized (indices).
    Indices,
}

impl Want {
    fn check(self, component: ComponentType, ty: Type, normalized: bool) -> Result<(), String> {
        use ComponentType as C;
        let float = |t: Type| ty == t && component == C::F32;
        let ok = match self {
            Want::Floats(t) => float(t),
            Want::Positions => float(Type::Vec3) && !normalized,
            Want::FloatsOrNormalized(t) => {
                float(t)
                    || (ty == t
                        && normalized
                        && matches!(component, C::I8 | C::U8 | C::I16 | C::U16))
            }
            Want::Indices => {
                ty == Type::Scalar && !normalized && matches!(component, C::U8 | C::U16 | C::U32)
            }
        };
        if ok {
            return Ok(());
        }
        let is = describe(component, ty, normalized);
        Err(match self {
            Want::Floats(t) => format!("must be FLOAT {}, not {is}", type_name(t)),
            Want::Positions => format!(
                "is {is}, but positions must be FLOAT VEC3 (KHR_mesh_quantization is not supported)"
            ),
            Want::FloatsOrNormalized(t) => format!(
                "must be FLOAT {0}, or normalized BYTE, UNSIGNED_BYTE, SHORT or UNSIGNED_SHORT {0}, not {is}",
                type_name(t)
            ),
            Want::Indices => {
                format!("must be UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT SCALAR, not {is}")
            }
        })
    }
}

impl Packed {
    /// The floats of a `FLOAT` accessor of type `ty`.
    fn floats(&self, ty: Type) -> Result<Vec<f32>, String> {
        Want::Floats(ty).check(self.component, self.ty, self.normalized)?;
        Ok(self
            .bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    }

    /// The floats of a `FLOAT` accessor or a normalized integer one (decoded as glTF says).
    fn floats_or_normalized(&self, ty: Type) -> Result<Vec<f32>, String> {
        Want::FloatsOrNormalized(ty).check(self.component, self.ty, self.normalized)?;
        let b = &self.bytes;
        Ok(match self.component {
            ComponentType::I8 => b
                .iter()
                .map(|&x| (x as i8 as f32 / 127.0).max(-1.0))
                .collect(),
            ComponentType::U8 => b.iter().map(|&x| x as f32 / 255.0).collect(),
            ComponentType::I16 => b
                .chunks_exact(2)
                .map(|c| (i16::from_le_bytes([c[0], c[1]]) as f32 / 32767.0).max(-1.0))
                .collect(),
            ComponentType::U16 => b
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]) as f32 / 65535.0)
                .collect(),
            _ => return self.floats(ty),
        })
    }

    /// The values of an unsigned integer `SCALAR` accessor (indices).
    fn indices(&self) -> Result<Vec<u32>, String> {
        Want::Indices.check(self.component, self.ty, self.normalized)?;
        let b = &self.bytes;
        Ok(match self.component {
            ComponentType::U8 => b.iter().map(|&x| x as u32).collect(),
            ComponentType::U16 => b
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]) as u32)
                .collect(),
            _ => b
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        })
    }
}

struct Loader<'a> {
    file: String,
    root: &'a json::Root,
    bin: Option<&'a [u8]>,
    base_dir: Option<&'a Path>,
    /// Buffers read so far, by index.
    buffers: Vec<Option<Vec<u8>>>,
    /// Bytes of input seen (the file and the buffers read): the bound on what an accessor
    /// without a buffer view may allocate.
    input_bytes: usize,
    warnings: Vec<GltfWarning>,
}

impl Loader<'_> {
    fn format_error(&self, message: impl Into<String>) -> GltfError {
        GltfError::Format {
            file: self.file.clone(),
            message: message.into(),
        }
    }

    fn node_error(&self, node: usize, message: impl Into<String>) -> GltfError {
        GltfError::Node {
            file: self.file.clone(),
            node: node as u32,
            node_name: self
                .root
                .nodes
                .get(node)
                .and_then(|n| n.name.clone())
                .unwrap_or_default(),
            message: message.into(),
        }
    }

    fn mesh_error(&self, mesh: usize, message: impl Into<String>) -> GltfError {
        GltfError::Mesh {
            file: self.file.clone(),
            mesh: mesh as u32,
            mesh_name: self
                .root
                .meshes
                .get(mesh)
                .and_then(|m| m.name.clone())
                .unwrap_or_default(),
            message: message.into(),
        }
    }

    fn animation_error(&self, animation: usize, message: impl Into<String>) -> GltfError {
        GltfError::Animation {
            file: self.file.clone(),
            animation: animation as u32,
            animation_name: self
                .root
                .animations
                .get(animation)
                .and_then(|a| a.name.clone())
                .unwrap_or_default(),
            message: message.into(),
        }
    }

    fn load(&mut self) -> Result<SceneDescription, GltfError> {
        let root = self.root;
        let scene_index = match root.scene {
            Some(s) => s.value(),
            None if root.scenes.is_empty() => {
                return Err(self.format_error("the file has no scene"));
            }
            None => 0,
        };
        let scene = root.scenes.get(scene_index).ok_or_else(|| {
            self.format_error(format!(
                "its default scene {scene_index} does not exist ({} scenes)",
                root.scenes.len()
            ))
        })?;

        // Every node's transform, whether the scene reaches it or not: channels may move it.
        let mut nodes: Vec<SceneNode> = Vec::with_capacity(root.nodes.len());
        for (k, node) in root.nodes.iter().enumerate() {
            let transform = node_transform(node).map_err(|m| self.node_error(k, m))?;
            nodes.push(SceneNode {
                name: node.name.clone().unwrap_or_default(),
                parent: None,
                transform,
            });
        }

        // The scene's tree, depth first, children in the order listed.
        let mut reached = vec![false; root.nodes.len()];
        let mut preorder: Vec<usize> = Vec::new();
        let mut stack: Vec<(usize, Option<usize>)> = Vec::new();
        for r in scene.nodes.iter().rev() {
            stack.push((r.value(), None));
        }
        while let Some((n, parent)) = stack.pop() {
            let Some(node) = root.nodes.get(n) else {
                return Err(match parent {
                    Some(p) => self.node_error(
                        p,
                        format!("its child {n} does not exist ({} nodes)", root.nodes.len()),
                    ),
                    None => self.format_error(format!(
                        "scene {scene_index} lists node {n}, which does not exist ({} nodes)",
                        root.nodes.len()
                    )),
                });
            };
            if reached[n] {
                return Err(self.node_error(n, self.reached_twice(n, parent, &nodes)));
            }
            reached[n] = true;
            nodes[n].parent = parent.map(|p| p as u32);
            preorder.push(n);
            if let Some(children) = &node.children {
                for c in children.iter().rev() {
                    stack.push((c.value(), Some(n)));
                }
            }
        }

        // Instances, in pre-order; meshes in the order instances first use them.
        let mut instances: Vec<SceneInstance> = Vec::new();
        let mut mesh_slot: HashMap<usize, u32> = HashMap::new();
        let mut gltf_meshes: Vec<u32> = Vec::new();
        for &n in &preorder {
            let node = &root.nodes[n];
            if node.skin.is_some() {
                return Err(self.node_error(
                    n,
                    "it has a skin: deforming meshes (skins, morph targets) are not supported yet",
                ));
            }
            let Some(mesh) = node.mesh else { continue };
            let m = mesh.value();
            if m >= root.meshes.len() {
                return Err(self.node_error(
                    n,
                    format!("its mesh {m} does not exist ({} meshes)", root.meshes.len()),
                ));
            }
            let slot = match mesh_slot.get(&m) {
                Some(&s) => s,
                None => {
                    let s = gltf_meshes.len() as u32;
                    mesh_slot.insert(m, s);
                    gltf_meshes.push(m as u32);
                    s
                }
            };
            let ext = node.extensions.as_ref().map(|e| &e.others);
            match ext.and_then(|e| e.get("EXT_mesh_gpu_instancing")) {
                Some(inst) => {
                    let copies = self
                        .gpu_instances(inst)
                        .map_err(|m| self.node_error(n, format!("EXT_mesh_gpu_instancing: {m}")))?;
                    for (copy, local) in copies.into_iter().enumerate() {
                        instances.push(SceneInstance {
                            node: n as u32,
                            mesh: slot,
                            copy: copy as u32,
                            local,
                        });
                    }
                }
                None => instances.push(SceneInstance {
                    node: n as u32,
                    mesh: slot,
                    copy: 0,
                    local: Trs::IDENTITY,
                }),
            }
        }
        if instances.len() >= octoproxy_core::scene::MAX_INSTANCES as usize {
            return Err(self.format_error(format!(
                "the scene has {} instances; a scene holds fewer than {}",
                instances.len(),
                octoproxy_core::scene::MAX_INSTANCES
            )));
        }

        let mut meshes = Vec::with_capacity(gltf_meshes.len());
        for &m in &gltf_meshes {
            meshes.push(self.mesh(m as usize)?);
        }
        let channels = self.channels()?;
        let graph =
            SceneGraph::new(nodes, instances, channels, meshes.len()).map_err(|source| {
                GltfError::Graph {
                    file: self.file.clone(),
                    source,
                }
            })?;
        graph.check_rigid().map_err(|source| GltfError::Pose {
            file: self.file.clone(),
            source,
        })?;
        Ok(SceneDescription {
            meshes,
            gltf_meshes,
            graph,
        })
    }

    /// Why node `n`, reached again from `parent`, cannot be: a cycle or a second parent.
    fn reached_twice(&self, n: usize, parent: Option<usize>, nodes: &[SceneNode]) -> String {
        let Some(p) = parent else {
            return "the scene lists it twice, or it is also another node's child (a node has at most one parent)".into();
        };
        // Walk up from the new parent: meeting `n` means a cycle.
        let mut cur = Some(p as u32);
        let mut steps = 0;
        while let Some(c) = cur {
            if c as usize == n {
                return format!(
                    "it is its own ancestor (a cycle through {})",
                    named("node", p, &self.root.nodes[p].name)
                );
            }
            steps += 1;
            if steps > nodes.len() {
                break;
            }
            cur = nodes[c as usize].parent;
        }
        let first = match nodes[n].parent {
            Some(q) => named("node", q as usize, &self.root.nodes[q as usize].name),
            None => "the scene".to_string(),
        };
        format!(
            "it has two parents ({first} and {}); a node has at most one",
            named("node", p, &self.root.nodes[p].name)
        )
    }

    /// The copies of an `EXT_mesh_gpu_instancing` node.
    fn gpu_instances(&mut self, ext: &Value) -> Result<Vec<Trs>, String> {
        let attrs = ext
            .get("attributes")
            .and_then(Value::as_object)
            .ok_or("it has no `attributes` object")?;
        let mut count: Option<usize> = None;
        let mut translation = None;
        let mut rotation = None;
        let mut scale = None;
        for (name, want) in [("TRANSLATION", 0), ("ROTATION", 1), ("SCALE", 2)] {
            let Some(v) = attrs.get(name) else { continue };
            let acc = v
                .as_u64()
                .and_then(|a| usize::try_from(a).ok())
                .ok_or_else(|| format!("{name} is not an accessor index"))?;
            let kind = match want {
                1 => Want::FloatsOrNormalized(Type::Vec4),
                _ => Want::Floats(Type::Vec3),
            };
            let packed = self.packed(acc, kind).map_err(|m| format!("{name}: {m}"))?;
            let values = match want {
                1 => packed.floats_or_normalized(Type::Vec4),
                _ => packed.floats(Type::Vec3),
            }
            .map_err(|m| format!("{name}: accessor {acc} {m}"))?;
            if count.is_some_and(|c| c != packed.count) {
                return Err(format!(
                    "{name} has {} elements, but another attribute has {}",
                    packed.count,
                    count.unwrap_or(0)
                ));
            }
            count = Some(packed.count);
            if let Some(bad) = values.iter().position(|x| !x.is_finite()) {
                return Err(format!(
                    "{name}: copy {} is not finite",
                    bad / if want == 1 { 4 } else { 3 }
                ));
            }
            match want {
                0 => translation = Some(values),
                1 => rotation = Some(values),
                _ => scale = Some(values),
            }
        }
        let count = count.ok_or("it has none of TRANSLATION, ROTATION, SCALE")?;
        let mut copies = Vec::with_capacity(count);
        for k in 0..count {
            let mut t = Trs::IDENTITY;
            if let Some(v) = &translation {
                t.translation = [v[3 * k], v[3 * k + 1], v[3 * k + 2]];
            }
            if let Some(v) = &rotation {
                t.rotation = [v[4 * k], v[4 * k + 1], v[4 * k + 2], v[4 * k + 3]];
                let len2: f64 = t.rotation.iter().map(|&c| c as f64 * c as f64).sum();
                if !(len2 > 1e-24) {
                    return Err(format!("ROTATION: copy {k} has a zero-length quaternion"));
                }
            }
            if let Some(v) = &scale {
                t.scale = [v[3 * k], v[3 * k + 1], v[3 * k + 2]];
            }
            copies.push(t);
        }
        Ok(copies)
    }

    /// The bytes of buffer `index`, read on first use.
    fn buffer(&mut self, index: usize) -> Result<&[u8], String> {
        let root = self.root;
        let buffer = root.buffers.get(index).ok_or_else(|| {
            format!(
                "buffer {index} does not exist ({} buffers)",
                root.buffers.len()
            )
        })?;
        if self.buffers[index].is_none() {
            let what = named("buffer", index, &buffer.name);
            let ext = buffer.extensions.as_ref();
            if ext.is_some_and(|e| e.others.contains_key("EXT_meshopt_compression")) {
                return Err(format!(
                    "{what} uses EXT_meshopt_compression, which is not supported"
                ));
            }
            let data: Vec<u8> = match &buffer.uri {
                None => {
                    if index != 0 {
                        return Err(format!(
                            "{what} has no uri (only buffer 0 of a GLB file may refer to its BIN chunk)"
                        ));
                    }
                    self.bin
                        .ok_or_else(|| {
                            format!("{what} has no uri, and the file has no GLB BIN chunk")
                        })?
                        .to_vec()
                }
                Some(uri) if uri.starts_with("data:") => {
                    let comma = uri
                        .find(',')
                        .ok_or_else(|| format!("{what}: its data URI has no comma"))?;
                    let (head, body) = uri.split_at(comma);
                    if !head.ends_with(";base64") {
                        return Err(format!("{what}: its data URI is not base64"));
                    }
                    decode_base64(&body.as_bytes()[1..]).map_err(|m| format!("{what}: {m}"))?
                }
                Some(uri) => {
                    let path = self
                        .resolve(uri)
                        .map_err(|m| format!("{what}: uri {uri:?}: {m}"))?;
                    std::fs::read(&path)
                        .map_err(|e| format!("{what}: cannot read {}: {e}", path.display()))?
                }
            };
            let want = usize::try_from(buffer.byte_length.0).unwrap_or(usize::MAX);
            if data.len() < want {
                return Err(format!(
                    "{what} should hold {} bytes, but has only {}",
                    buffer.byte_length.0,
                    data.len()
                ));
            }
            self.input_bytes = self.input_bytes.saturating_add(want);
            let mut data = data;
            data.truncate(want);
            self.buffers[index] = Some(data);
        }
        Ok(self.buffers[index].as_deref().unwrap_or(&[]))
    }

    /// The path of an external file: relative to the glTF file's folder, never above it.
    fn resolve(&self, uri: &str) -> Result<PathBuf, String> {
        let base = self
            .base_dir
            .ok_or("the buffer is in another file, and the glTF was given without a folder")?;
        let decoded = percent_decode(uri)?;
        let has_scheme = decoded
            .split_once(':')
            .is_some_and(|(s, _)| !s.is_empty() && !s.contains(['/', '\\']));
        if has_scheme {
            return Err("only relative paths and data: URIs are supported".into());
        }
        let rel = Path::new(&decoded);
        if decoded.starts_with(['/', '\\']) || rel.is_absolute() {
            return Err(
                "absolute paths are refused (a buffer must be beside the glTF file or below it)"
                    .into(),
            );
        }
        if decoded.is_empty() {
            return Err("the path is empty".into());
        }
        for part in decoded.split(['/', '\\']) {
            if part == ".." {
                return Err("paths that climb out with `..` are refused (a buffer must be beside the glTF file or below it)".into());
            }
        }
        if rel
            .components()
            .any(|c| !matches!(c, Component::Normal(_) | Component::CurDir))
        {
            return Err("only plain relative paths are supported".into());
        }
        Ok(base.join(rel))
    }

    /// Accessor `index`'s elements, tightly packed (its view's stride removed, its sparse
    /// substitution applied).
    fn packed(&mut self, index: usize, want: Want) -> Result<Packed, String> {
        let root = self.root;
        let acc = root.accessors.get(index).ok_or_else(|| {
            format!(
                "accessor {index} does not exist ({} accessors)",
                root.accessors.len()
            )
        })?;
        let what = format!("accessor {index}");
        let Checked::Valid(component) = acc.component_type else {
            return Err(format!("{what} has an unknown componentType"));
        };
        let component = component.0;
        let Checked::Valid(ty) = acc.type_ else {
            return Err(format!("{what} has an unknown type"));
        };
        want.check(component, ty, acc.normalized)
            .map_err(|m| format!("{what} {m}"))?;
        let elem = component_size(component) * components(ty);
        let count = usize::try_from(acc.count.0).map_err(|_| format!("{what}: count too large"))?;
        let total = count
            .checked_mul(elem)
            .ok_or_else(|| format!("{what}: count {count} is too large"))?;
        let mut bytes = match acc.buffer_view {
            Some(view_index) => {
                let (data, stride) = self
                    .view(view_index.value(), elem)
                    .map_err(|m| format!("{what}: {m}"))?;
                let offset = usize::try_from(acc.byte_offset.map_or(0, |o| o.0))
                    .map_err(|_| format!("{what}: byteOffset too large"))?;
                if count > 0 {
                    let last_end = (count - 1)
                        .checked_mul(stride)
                        .and_then(|x| x.checked_add(offset))
                        .and_then(|x| x.checked_add(elem));
                    if last_end.is_none_or(|e| e > data.len()) {
                        return Err(format!(
                            "{what}: {count} elements of {elem} bytes (stride {stride}) from byte {offset} run past its buffer view of {} bytes",
                            data.len()
                        ));
                    }
                }
                let mut out = Vec::with_capacity(total);
                for k in 0..count {
                    let at = offset + k * stride;
                    out.extend_from_slice(&data[at..at + elem]);
                }
                out
            }
            None => {
                if acc.sparse.is_none() {
                    return Err(format!("{what} has neither a bufferView nor sparse values"));
                }
                // Zeros the file does not hold: bounded by the input's size.
                let limit = self.input_bytes.saturating_mul(64).saturating_add(1 << 16);
                if total > limit {
                    return Err(format!(
                        "{what}: {count} elements without a buffer view ({total} bytes) is far more than the file holds"
                    ));
                }
                vec![0u8; total]
            }
        };
        if let Some(sparse) = &acc.sparse {
            let n = usize::try_from(sparse.count.0)
                .ok()
                .filter(|&n| n <= count)
                .ok_or_else(|| {
                    format!(
                        "{what}: sparse count {} exceeds its count {count}",
                        sparse.count.0
                    )
                })?;
            let Checked::Valid(ic) = sparse.indices.component_type else {
                return Err(format!(
                    "{what}: sparse indices have an unknown componentType"
                ));
            };
            let isize_ = component_size(ic.0);
            let read_range = |loader: &mut Self,
                              view: usize,
                              offset: u64,
                              len: usize,
                              part: &str| {
                let offset = usize::try_from(offset)
                    .map_err(|_| format!("{what}: sparse {part} byteOffset too large"))?;
                let (data, _) = loader
                    .view(view, 1)
                    .map_err(|m| format!("{what}: sparse {part}: {m}"))?;
                let end = len.checked_add(offset).filter(|&e| e <= data.len()).ok_or_else(|| {
                    format!("{what}: sparse {part} of {len} bytes from byte {offset} run past their buffer view of {} bytes", data.len())
                })?;
                Ok::<Vec<u8>, String>(data[offset..end].to_vec())
            };
            let idx = read_range(
                self,
                sparse.indices.buffer_view.value(),
                sparse.indices.byte_offset.0,
                n.saturating_mul(isize_),
                "indices",
            )?;
            let vals = read_range(
                self,
                sparse.values.buffer_view.value(),
                sparse.values.byte_offset.0,
                n.saturating_mul(elem),
                "values",
            )?;
            for k in 0..n {
                let i = match isize_ {
                    1 => idx[k] as usize,
                    2 => u16::from_le_bytes([idx[2 * k], idx[2 * k + 1]]) as usize,
                    _ => u32::from_le_bytes([
                        idx[4 * k],
                        idx[4 * k + 1],
                        idx[4 * k + 2],
                        idx[4 * k + 3],
                    ]) as usize,
                };
                if i >= count {
                    return Err(format!(
                        "{what}: sparse index {k} is {i}, but the accessor has {count} elements"
                    ));
                }
                bytes[i * elem..(i + 1) * elem].copy_from_slice(&vals[k * elem..(k + 1) * elem]);
            }
        }
        Ok(Packed {
            component,
            normalized: acc.normalized,
            ty,
            count,
            bytes,
        })
    }

    /// Buffer view `index`'s bytes and its stride for elements of `elem` bytes.
    fn view(&mut self, index: usize, elem: usize) -> Result<(&[u8], usize), String> {
        let root = self.root;
        let view = root.buffer_views.get(index).ok_or_else(|| {
            format!(
                "buffer view {index} does not exist ({} views)",
                root.buffer_views.len()
            )
        })?;
        let what = named("buffer view", index, &view.name);
        let ext = view.extensions.as_ref();
        if ext.is_some_and(|e| e.others.contains_key("EXT_meshopt_compression")) {
            return Err(format!(
                "{what} uses EXT_meshopt_compression, which is not supported"
            ));
        }
        let stride = match view.byte_stride {
            Some(s) if s.0 < elem || s.0 > 252 => {
                return Err(format!(
                    "{what}: byteStride {} is not within {elem}..=252 for elements of {elem} bytes",
                    s.0
                ))
            }
            Some(s) => s.0,
            None => elem,
        };
        let offset = view.byte_offset.map_or(0, |o| o.0);
        let length = view.byte_length.0;
        let buffer = self
            .buffer(view.buffer.value())
            .map_err(|m| format!("{what}: {m}"))?;
        let end = offset
            .checked_add(length)
            .filter(|&e| e <= buffer.len() as u64)
            .ok_or_else(|| {
                format!(
                    "{what}: {length} bytes from byte {offset} run past its buffer of {} bytes",
                    buffer.len()
                )
            })?;
        Ok((&buffer[offset as usize..end as usize], stride))
    }

    /// glTF mesh `m` as one triangle mesh.
    fn mesh(&mut self, m: usize) -> Result<SceneMesh, GltfError> {
        let root = self.root;
        let mesh = &root.meshes[m];
        let mut out = Mesh::default();
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let err =
                |loader: &Self, msg: String| loader.mesh_error(m, format!("primitive {p}: {msg}"));
            let ext = prim.extensions.as_ref();
            if ext.is_some_and(|e| e.others.contains_key("KHR_draco_mesh_compression")) {
                return Err(err(
                    self,
                    "it is compressed with KHR_draco_mesh_compression, which is not supported"
                        .into(),
                ));
            }
            if prim.targets.as_ref().is_some_and(|t| !t.is_empty()) {
                return Err(err(self, "it has morph targets: deforming meshes (skins, morph targets) are not supported yet".into()));
            }
            let Checked::Valid(mode) = prim.mode else {
                return Err(err(self, "its mode is not one glTF defines".into()));
            };
            use json::mesh::Mode;
            let skipped = match mode {
                Mode::Points => Some("POINTS"),
                Mode::Lines => Some("LINES"),
                Mode::LineLoop => Some("LINE_LOOP"),
                Mode::LineStrip => Some("LINE_STRIP"),
                _ => None,
            };
            if let Some(mode) = skipped {
                self.warnings.push(GltfWarning::SkippedPrimitive {
                    file: self.file.clone(),
                    mesh: m as u32,
                    mesh_name: mesh.name.clone().unwrap_or_default(),
                    primitive: p as u32,
                    mode,
                });
                continue;
            }
            let pos = prim
                .attributes
                .get(&Checked::Valid(json::mesh::Semantic::Positions))
                .ok_or_else(|| err(self, "it has no POSITION attribute".into()))?
                .value();
            let packed = self
                .packed(pos, Want::Positions)
                .map_err(|msg| err(self, format!("POSITION: {msg}")))?;
            let floats = packed
                .floats(Type::Vec3)
                .map_err(|msg| err(self, format!("POSITION: accessor {pos} {msg}")))?;
            if let Some(bad) = floats.iter().position(|x| !x.is_finite()) {
                return Err(err(
                    self,
                    format!("POSITION: vertex {} is not finite", bad / 3),
                ));
            }
            let vertices = packed.count;
            let indices: Vec<u32> = match prim.indices {
                Some(ix) => {
                    let ix = ix.value();
                    let packed = self
                        .packed(ix, Want::Indices)
                        .map_err(|msg| err(self, format!("indices: {msg}")))?;
                    let v = packed
                        .indices()
                        .map_err(|msg| err(self, format!("indices: accessor {ix} {msg}")))?;
                    if let Some((k, &i)) =
                        v.iter().enumerate().find(|(_, &i)| i as usize >= vertices)
                    {
                        return Err(err(
                            self,
                            format!("index {k} is {i}, but the primitive has {vertices} vertices"),
                        ));
                    }
                    v
                }
                None => {
                    let n = u32::try_from(vertices)
                        .map_err(|_| err(self, "too many vertices".into()))?;
                    (0..n).collect()
                }
            };
            let base = out.positions.len();
            if base + vertices > u32::MAX as usize {
                return Err(err(
                    self,
                    "the mesh has more vertices than u32 indices reach".into(),
                ));
            }
            let base = base as u32;
            out.positions
                .extend(floats.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
            let tri = |a: u32, b: u32, c: u32| [base + a, base + b, base + c];
            match mode {
                Mode::Triangles => {
                    if !indices.len().is_multiple_of(3) {
                        return Err(err(
                            self,
                            format!(
                                "TRIANGLES need a multiple of 3 vertices, but it has {}",
                                indices.len()
                            ),
                        ));
                    }
                    out.triangles
                        .extend(indices.chunks_exact(3).map(|t| tri(t[0], t[1], t[2])));
                }
                Mode::TriangleStrip => {
                    for (k, w) in indices.windows(3).enumerate() {
                        // Every other triangle is reversed, so all keep the first's winding.
                        out.triangles.push(if k % 2 == 0 {
                            tri(w[0], w[1], w[2])
                        } else {
                            tri(w[1], w[0], w[2])
                        });
                    }
                }
                Mode::TriangleFan => {
                    if let Some((&first, rest)) = indices.split_first() {
                        for w in rest.windows(2) {
                            out.triangles.push(tri(w[0], w[1], first));
                        }
                    }
                }
                _ => {}
            }
        }
        if out.triangles.is_empty() {
            return Err(
                self.mesh_error(m, "it has no triangles (an instance needs a mesh to bake)")
            );
        }
        Ok(SceneMesh {
            name: mesh.name.clone().unwrap_or_default(),
            mesh: out,
        })
    }

    /// Every animation's channels, checked.
    fn channels(&mut self) -> Result<Vec<Channel>, GltfError> {
        let root = self.root;
        let mut out: Vec<Channel> = Vec::new();
        // (node, path) → (animation, channel), to name both of two channels on one path.
        let mut seen: HashMap<(u32, ChannelPath), (usize, usize)> = HashMap::new();
        for (a, anim) in root.animations.iter().enumerate() {
            for (c, ch) in anim.channels.iter().enumerate() {
                let err = |loader: &Self, msg: String| {
                    loader.animation_error(a, format!("channel {c}: {msg}"))
                };
                let n = ch.target.node.value();
                let Some(node) = root.nodes.get(n) else {
                    return Err(err(
                        self,
                        format!(
                            "its target node {n} does not exist ({} nodes)",
                            root.nodes.len()
                        ),
                    ));
                };
                let node_named = named("node", n, &node.name);
                let path = match ch.target.path {
                    Checked::Valid(json::animation::Property::Translation) => {
                        ChannelPath::Translation
                    }
                    Checked::Valid(json::animation::Property::Rotation) => ChannelPath::Rotation,
                    Checked::Valid(json::animation::Property::Scale) => ChannelPath::Scale,
                    Checked::Valid(json::animation::Property::MorphTargetWeights) => {
                        return Err(self.node_error(n, format!(
                            "animation {a}{} channel {c} animates its morph target weights: deforming meshes (skins, morph targets) are not supported yet",
                            super::graph::quoted(anim.name.as_deref().unwrap_or(""))
                        )));
                    }
                    Checked::Invalid => {
                        return Err(err(
                            self,
                            format!("its target path on {node_named} is not one glTF 2.0 defines"),
                        ));
                    }
                };
                if node.matrix.is_some() {
                    return Err(err(self, format!(
                        "it animates the {} of {node_named}, which has a matrix (an animated node must use TRS)",
                        path.name()
                    )));
                }
                if let Some(&(a0, c0)) = seen.get(&(n as u32, path)) {
                    return Err(self.node_error(n, format!(
                        "two channels animate its {}: animation {a0}{} channel {c0} and animation {a}{} channel {c}",
                        path.name(),
                        super::graph::quoted(root.animations[a0].name.as_deref().unwrap_or("")),
                        super::graph::quoted(anim.name.as_deref().unwrap_or(""))
                    )));
                }
                seen.insert((n as u32, path), (a, c));
                let s = ch.sampler.value();
                let sampler = anim.samplers.get(s).ok_or_else(|| {
                    err(
                        self,
                        format!(
                            "its sampler {s} does not exist ({} samplers)",
                            anim.samplers.len()
                        ),
                    )
                })?;
                let Checked::Valid(interp) = sampler.interpolation else {
                    return Err(err(
                        self,
                        format!("sampler {s} has an unknown interpolation"),
                    ));
                };
                let interpolation = match interp {
                    json::animation::Interpolation::Linear => Interpolation::Linear,
                    json::animation::Interpolation::Step => Interpolation::Step,
                    json::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
                };
                let input = sampler.input.value();
                let times = self
                    .packed(input, Want::Floats(Type::Scalar))
                    .and_then(|p| {
                        p.floats(Type::Scalar)
                            .map_err(|m| format!("accessor {input} {m}"))
                    })
                    .map_err(|m| err(self, format!("key times ({node_named}): {m}")))?;
                let output = sampler.output.value();
                let want = if path == ChannelPath::Rotation {
                    Type::Vec4
                } else {
                    Type::Vec3
                };
                let values = self
                    .packed(
                        output,
                        if path == ChannelPath::Rotation {
                            Want::FloatsOrNormalized(want)
                        } else {
                            Want::Floats(want)
                        },
                    )
                    .and_then(|p| {
                        if path == ChannelPath::Rotation {
                            p.floats_or_normalized(want)
                        } else {
                            p.floats(want)
                        }
                        .map_err(|m| format!("accessor {output} {m}"))
                    })
                    .map_err(|m| {
                        err(self, format!("{} values ({node_named}): {m}", path.name()))
                    })?;
                let channel = Channel {
                    node: n as u32,
                    path,
                    interpolation,
                    times,
                    values,
                };
                check_channel(&channel)
                    .map_err(|m| err(self, format!("{} of {node_named}: {m}", path.name())))?;
                out.push(channel);
            }
        }
        Ok(out)
    }
}

/// A node's transform from its `matrix` or its TRS (not both), checked.
fn node_transform(node: &json::Node) -> Result<NodeTransform, String> {
    let t = match node.matrix {
        Some(m) => {
            if node.translation.is_some() || node.rotation.is_some() || node.scale.is_some() {
                return Err("it has both a matrix and translation/rotation/scale".into());
            }
            NodeTransform::Matrix(m)
        }
        None => NodeTransform::Trs(Trs {
            translation: node.translation.unwrap_or([0.0; 3]),
            rotation: node.rotation.map_or([0.0, 0.0, 0.0, 1.0], |r| r.0),
            scale: node.scale.unwrap_or([1.0; 3]),
        }),
    };
    check_transform(&t)?;
    Ok(t)
}

/// Decodes `%XX` escapes; the result must be UTF-8.
fn percent_decode(s: &str) -> Result<String, String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut k = 0;
    while k < b.len() {
        if b[k] == b'%' {
            let hex = b
                .get(k + 1..k + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or("a bad percent escape")?;
            out.push(hex);
            k += 3;
        } else {
            out.push(b[k]);
            k += 1;
        }
    }
    String::from_utf8(out).map_err(|_| "the decoded path is not UTF-8".to_string())
}
