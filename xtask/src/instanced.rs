//! Scenes of instances on the command line: a glTF file (baked here, each mesh once), a baked
//! scene file (`bake --scene`), or meshes and a proxy as a static scene of one instance; the
//! animation sampled at step ends; and the per-particle columns `sim` writes for them.

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::Vec3;
use octoproxy_core::{Hit, HitEvent, Particle, Pose, ProxyView, SceneSides};
use octoproxy_cpu::bake::offset::OffsetSurface;
use octoproxy_cpu::gltf::{bake_scene_for_radius, load_gltf, BakedScene, SCENE_MAGIC};
use octoproxy_cpu::io::ply::{self, Scalar};
use octoproxy_cpu::io::{Mesh, ParticleCloud};
use octoproxy_cpu::scenes::MeshExt;
use octoproxy_cpu::{BuildParams, MeshRef, Scene, Sides};

use crate::progress::BakeBars;

/// What kind of file a `--scene` value names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneFile {
    /// glTF 2.0, `.gltf` or `.glb`.
    Gltf,
    /// A baked scene (`octoproxy bake --scene`), `.octoscene`.
    Baked,
}

impl SceneFile {
    /// The kind a path's extension says, if any.
    pub fn of(path: &Path) -> Option<SceneFile> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "gltf" | "glb" => Some(SceneFile::Gltf),
            "octoscene" => Some(SceneFile::Baked),
            _ => None,
        }
    }
}

/// A scene of instances ready to step: the host scene, what its instances are, the animation
/// when it has one, and the meshes behind each proxy (for sides and ground truth).
pub struct Instanced {
    pub scene: Scene,
    /// The baked scene, when the scene came from a file: its animation and meshes.
    pub baked: Option<BakedScene>,
    /// The meshes baked into each proxy.
    pub meshes: Vec<Vec<Mesh>>,
    /// Whether each proxy's meshes are closed.
    pub closed: Vec<bool>,
    /// For particles of a radius, each proxy's offset surface (built when first needed, for
    /// a scene read from a file).
    pub offsets: Option<Vec<OffsetSurface>>,
}

impl Instanced {
    /// A scene file: glTF (baked with `params`, each mesh once, shared by every node that
    /// uses it, for particles of `radius` when given) or a baked scene (`params` must be
    /// `None`: it is baked already; a `radius` must be the one it was baked for).
    pub fn from_file(
        path: &Path,
        params: Option<&BuildParams>,
        radius: Option<f32>,
    ) -> Result<Instanced> {
        let (baked, offsets) = match SceneFile::of(path) {
            Some(SceneFile::Baked) => {
                if params.is_some() {
                    bail!(
                        "--dmin/--dmax/--epsilon/--lut-depth shape a bake; {} is baked already",
                        path.display()
                    );
                }
                let t = Instant::now();
                let baked = BakedScene::read(path)?;
                eprintln!(
                    "read {}: {} meshes, {} instances, {:.3} s of animation ({:.0} ms)",
                    path.display(),
                    baked.meshes().len(),
                    baked.instances().len(),
                    baked.duration(),
                    t.elapsed().as_secs_f64() * 1e3
                );
                check_baked_radius(path, &baked, radius)?;
                (baked, None)
            }
            Some(SceneFile::Gltf) => {
                let (baked, offsets) = bake_gltf(
                    path,
                    params.copied().unwrap_or_default(),
                    radius.unwrap_or(0.0),
                )?;
                (baked, Some(offsets))
            }
            None => bail!(
                "{}: a scene file is .gltf or .glb (glTF 2.0) or .octoscene (octoproxy bake --scene)",
                path.display()
            ),
        };
        let mut inst = Self::from_baked(baked)?;
        if inst.radius() > 0.0 {
            inst.offsets = offsets;
        }
        if let Some(note) = inst.hidden_note()? {
            eprintln!("{}: {note}", path.display());
        }
        Ok(inst)
    }

    /// Which instances a scale of 0 hides for the whole animation (glTF's way to hide a
    /// node), if any: particles pass where they are, which a user should hear about.
    pub fn hidden_note(&self) -> Result<Option<String>> {
        let Some(baked) = &self.baked else {
            return Ok(None);
        };
        let mut hidden = Vec::new();
        for (k, i) in self.scene.instances().iter().enumerate() {
            if i.start.scale == 0.0 && baked.graph().scale_range(k as u32)?.max == 0.0 {
                hidden.push(k as u32);
            }
        }
        if hidden.is_empty() {
            return Ok(None);
        }
        let shown = &hidden[..hidden.len().min(3)];
        let more = if hidden.len() > shown.len() {
            format!("; and {} more", hidden.len() - shown.len())
        } else {
            String::new()
        };
        Ok(Some(format!(
            "{} of {} instances have scale 0 throughout, hidden: particles pass where they are ({}{more})",
            hidden.len(),
            self.scene.instances().len(),
            baked.describe_instances(shown)
        )))
    }

    /// The scene of a baked scene, at time 0.
    pub fn from_baked(baked: BakedScene) -> Result<Instanced> {
        let (scene, ids) = baked.build_scene()?;
        debug_assert!(ids.iter().enumerate().all(|(i, &id)| id == i as u32));
        let meshes: Vec<Vec<Mesh>> = baked
            .proxies()
            .iter()
            .map(|p| vec![baked.meshes()[p.mesh as usize].mesh.clone()])
            .collect();
        // Closed and wound consistently: what `check` reads by winding numbers.
        let closed = meshes
            .iter()
            .map(|m| m[0].is_closed() && m[0].is_consistently_oriented())
            .collect();
        Ok(Instanced {
            scene,
            baked: Some(baked),
            meshes,
            closed,
            offsets: None,
        })
    }

    /// The particle radius the scene's proxies are baked for (0 for none).
    pub fn radius(&self) -> f32 {
        self.baked.as_ref().map_or(0.0, |b| b.radius())
    }

    /// Each proxy's offset surface, built now if the scene was read from a file; `None`
    /// without a radius.
    pub fn offsets(&mut self) -> Result<Option<&[OffsetSurface]>> {
        if self.radius() == 0.0 {
            return Ok(None);
        }
        if self.offsets.is_none() {
            if let Some(baked) = &self.baked {
                let t = Instant::now();
                let bars = BakeBars::default();
                let built = baked.offset_surfaces(&bars);
                bars.finish();
                self.offsets = Some(built?);
                eprintln!(
                    "built the offset surfaces of {} proxies again from their meshes ({:.0} ms)",
                    baked.proxies().len(),
                    t.elapsed().as_secs_f64() * 1e3
                );
            }
        }
        Ok(self.offsets.as_deref())
    }

    /// Moves every particle that starts inside an instance's band out of it
    /// ([`octoproxy_cpu::scene::place_in_bands`]); nothing without a radius.
    pub fn place_out_of_bands(
        &mut self,
        particles: &mut [Particle],
    ) -> Result<octoproxy_cpu::bake::offset::PlaceCounts> {
        self.offsets()?;
        Ok(match self.offsets.as_deref() {
            Some(offsets) => octoproxy_cpu::scene::place_in_bands(&self.scene, offsets, particles),
            None => Default::default(),
        })
    }

    /// One proxy (of `meshes`, or a proxy file's with no meshes) placed once at the identity.
    pub fn one(words: Vec<u32>, meshes: Vec<Mesh>) -> Result<Instanced> {
        let mut scene = Scene::new();
        let proxy = scene.add_proxy(words)?;
        scene.add_instance(proxy, Pose::IDENTITY)?;
        let merged = octoproxy_cpu::scenes::merge(&meshes);
        let closed =
            vec![!meshes.is_empty() && merged.is_closed() && merged.is_consistently_oriented()];
        Ok(Instanced {
            scene,
            baked: None,
            meshes: vec![meshes],
            closed,
            offsets: None,
        })
    }

    /// The animation's length in seconds (0 for a still scene).
    pub fn duration(&self) -> f64 {
        self.baked.as_ref().map_or(0.0, |b| b.duration())
    }

    /// Poses every instance for a step that ends at animation time `t` (seconds): each moves
    /// from where it is to its pose at `t`.
    pub fn pose_at(&mut self, t: f64) -> Result<()> {
        let Some(baked) = &self.baked else {
            return Ok(());
        };
        if baked.duration() == 0.0 {
            return Ok(());
        }
        let poses = baked
            .poses_at(t)
            .with_context(|| format!("posing the scene at {t} s"))?;
        for (i, pose) in poses.into_iter().enumerate() {
            self.scene.move_to(i as u32, pose)?;
        }
        Ok(())
    }

    /// Every instance at its pose at animation time `t`, still (the start of a run).
    pub fn hold_at(&mut self, t: f64) -> Result<()> {
        let Some(baked) = &self.baked else {
            return Ok(());
        };
        let poses = baked
            .poses_at(t)
            .with_context(|| format!("posing the scene at {t} s"))?;
        for (i, pose) in poses.into_iter().enumerate() {
            self.scene.set_motion(i as u32, pose, pose)?;
        }
        self.prepare()
            .with_context(|| format!("the scene at {t} s, before the first step"))
    }

    /// Builds the broad phase and checks the scene as it stands ([`Scene::prepare`]; the
    /// step then finds it done). An error that names instances says which nodes they are.
    pub fn prepare(&mut self) -> Result<()> {
        self.scene.prepare().map_err(|e| {
            let ids = e.instances();
            match &self.baked {
                Some(baked) if !ids.is_empty() => {
                    anyhow::anyhow!("{e} ({})", baked.describe_instances(&ids))
                }
                _ => anyhow::Error::new(e),
            }
        })
    }

    /// The box of every instance's root cube at its start pose, grown by 10 %.
    pub fn world_box(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for inst in self.scene.instances().iter().filter(|i| i.is_active()) {
            let view = self.scene.proxies()[inst.proxy as usize].view();
            let b = inst.swept_box(&view);
            lo = lo.min(b.min);
            hi = hi.max(b.max);
        }
        if !lo.cmple(hi).all() {
            return (Vec3::splat(-1.0), Vec3::splat(1.0));
        }
        let grow = (hi - lo) * 0.05;
        (lo - grow, hi + grow)
    }

    /// Exact sides from each proxy's meshes, by proxy (`None` where a proxy came without its
    /// meshes: a proxy file); for particles of a radius, from each proxy's offset surface.
    pub fn sides(&self) -> Vec<Option<Sides>> {
        if let Some(offsets) = &self.offsets {
            return offsets
                .iter()
                .map(|o| Some(Sides::new(&[o.mesh_ref()])))
                .collect();
        }
        self.meshes
            .iter()
            .map(|ms| {
                (!ms.is_empty()).then(|| {
                    let refs: Vec<MeshRef<'_>> = ms.iter().map(MeshRef::from).collect();
                    Sides::new(&refs)
                })
            })
            .collect()
    }
}

/// The instance table `--list-instances` prints for a scene file (no bake needed): index,
/// node, mesh and pose at time 0.
pub fn list_instances(path: &Path) -> Result<String> {
    let infos = if SceneFile::of(path) == Some(SceneFile::Baked) || looks_baked(path) {
        BakedScene::read(path)?.list_instances()?
    } else {
        let (description, warnings) = load_gltf(path)?;
        for w in &warnings {
            eprintln!("warning: {w}");
        }
        description.list_instances()?
    };
    let mut out = String::from(
        "index\tnode\tname\tcopy\tmesh\tmesh name\ttranslation\tscale\trotation (x, y, z, w)\n",
    );
    for i in infos {
        let (t, q) = (i.pose.translation, i.pose.rotation);
        out.push_str(&format!(
            "{}\t{}\t{:?}\t{}\t{}\t{:?}\t{},{},{}\t{}\t{},{},{},{}\n",
            i.index,
            i.node,
            i.node_name,
            i.copy,
            i.mesh,
            i.mesh_name,
            t[0],
            t[1],
            t[2],
            i.pose.scale,
            q[0],
            q[1],
            q[2],
            q[3]
        ));
    }
    Ok(out)
}

/// A baked scene's radius against `--radius`: a flag that does not match it is an error
/// naming the file.
fn check_baked_radius(path: &Path, baked: &BakedScene, radius: Option<f32>) -> Result<()> {
    if let Some(r) = radius {
        if octoproxy_core::check_radius(baked.radius(), r).is_err() {
            bail!(
                "{}: baked for particles of radius {}, but --radius is {r}: bake the glTF scene again with --radius {r}",
                path.display(),
                baked.radius()
            );
        }
    }
    Ok(())
}

/// Loads and bakes a glTF file for particles of `radius` (0 for none), with progress bars;
/// returns the scene and, with a radius, each proxy's offset surface.
pub fn bake_gltf(
    path: &Path,
    params: BuildParams,
    radius: f32,
) -> Result<(BakedScene, Vec<OffsetSurface>)> {
    let t = Instant::now();
    let (description, warnings) = load_gltf(path)?;
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    let triangles: usize = description
        .meshes
        .iter()
        .map(|m| m.mesh.triangles.len())
        .sum();
    eprintln!(
        "loaded {}: {} meshes ({triangles} triangles), {} instances, {:.3} s of animation ({:.0} ms)",
        path.display(),
        description.meshes.len(),
        description.instances().len(),
        description.duration(),
        t.elapsed().as_secs_f64() * 1e3
    );
    let bars = BakeBars::default();
    let t = Instant::now();
    let result = bake_scene_for_radius(&description, &params, radius, &bars);
    bars.finish();
    let (baked, reports, offsets) = result.with_context(|| format!("baking {}", path.display()))?;
    let nodes: usize = reports.iter().map(|r| r.nodes).sum();
    eprintln!(
        "baked {} proxies ({nodes} nodes) in {:.3} s{}",
        reports.len(),
        t.elapsed().as_secs_f64(),
        if radius > 0.0 {
            format!(
                " for particles of radius {radius}: one per mesh and distinct world scale of its instances ({} meshes)",
                baked.meshes().len()
            )
        } else {
            String::new()
        }
    );
    Ok((baked, offsets))
}

/// Whether a file starts as a baked scene does.
pub fn looks_baked(path: &Path) -> bool {
    use std::io::Read as _;
    let mut head = [0u8; 8];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| head == SCENE_MAGIC)
}

/// The names of the columns of each particle's sides for the scene's instances: its eight
/// slots (`SceneSides::slots`, each `instance << 10 | required << 9 | side word`, or
/// `4294967295` for none).
pub const SLOT_COLUMNS: [&str; 8] = [
    "scene_slot0",
    "scene_slot1",
    "scene_slot2",
    "scene_slot3",
    "scene_slot4",
    "scene_slot5",
    "scene_slot6",
    "scene_slot7",
];

/// The hit-record columns, as `sim --hits` writes them.
pub const HIT_COLUMNS: [(&str, Scalar); 9] = [
    ("hit_instance", Scalar::I32),
    ("hit_x", Scalar::F32),
    ("hit_y", Scalar::F32),
    ("hit_z", Scalar::F32),
    ("hit_nx", Scalar::F32),
    ("hit_ny", Scalar::F32),
    ("hit_nz", Scalar::F32),
    ("hit_t", Scalar::F32),
    ("hit_speed", Scalar::F32),
];

fn hit_values(h: &Hit) -> [f64; 9] {
    [
        h.instance as f64,
        h.position[0] as f64,
        h.position[1] as f64,
        h.position[2] as f64,
        h.normal[0] as f64,
        h.normal[1] as f64,
        h.normal[2] as f64,
        h.t as f64,
        h.speed as f64,
    ]
}

/// Takes a cloud's scene slots out of its extra columns: `Some` when it has all eight (a
/// frame `sim` wrote for a scene), else `None` and the cloud as it was.
pub fn take_slots(cloud: &mut ParticleCloud) -> Result<Option<Vec<SceneSides>>> {
    let props = &cloud.extra.properties;
    let at: Vec<Option<usize>> = SLOT_COLUMNS
        .iter()
        .map(|c| props.iter().position(|(n, _)| n == c))
        .collect();
    if at.iter().all(Option::is_none) {
        return Ok(None);
    }
    if at.iter().any(Option::is_none) {
        bail!("the particle file has some of the columns {SLOT_COLUMNS:?} but not all");
    }
    let n = cloud.particles.len();
    let mut sides = vec![SceneSides::EMPTY; n];
    for (i, s) in sides.iter_mut().enumerate() {
        let row = cloud
            .extra
            .row(i)
            .context("a particle without its extra values")?;
        for (k, a) in at.iter().enumerate() {
            let v = row[a.expect("all present")];
            if !(0.0..=u32::MAX as f64).contains(&v) || v.fract() != 0.0 {
                bail!("particle {i}: {} = {v} is not a slot word", SLOT_COLUMNS[k]);
            }
            s.slots[k] = v as u32;
        }
    }
    let keep: Vec<usize> = (0..props.len())
        .filter(|j| !at.contains(&Some(*j)))
        .collect();
    cloud.extra = select_columns(cloud, &keep);
    Ok(Some(sides))
}

fn select_columns(cloud: &ParticleCloud, keep: &[usize]) -> octoproxy_cpu::io::ExtraProperties {
    let mut out = octoproxy_cpu::io::ExtraProperties {
        properties: keep
            .iter()
            .map(|&j| cloud.extra.properties[j].clone())
            .collect(),
        values: Vec::with_capacity(cloud.particles.len() * keep.len()),
    };
    for i in 0..cloud.particles.len() {
        if let Some(row) = cloud.extra.row(i) {
            out.values.extend(keep.iter().map(|&j| row[j]));
        }
    }
    out
}

/// `cloud` with columns appended (replacing any of the same names): each particle's scene
/// slots, and its hit record when `hits` is given.
pub fn with_scene_columns(
    cloud: &ParticleCloud,
    sides: &[SceneSides],
    hits: Option<&[Hit]>,
) -> ParticleCloud {
    let mut names: Vec<(String, Scalar)> = SLOT_COLUMNS
        .iter()
        .map(|c| (c.to_string(), Scalar::U32))
        .collect();
    if hits.is_some() {
        names.extend(HIT_COLUMNS.iter().map(|(c, s)| (c.to_string(), *s)));
    }
    let keep: Vec<usize> = (0..cloud.extra.properties.len())
        .filter(|&j| !names.iter().any(|(n, _)| *n == cloud.extra.properties[j].0))
        .collect();
    let mut extra = select_columns(cloud, &keep);
    let old = keep.len();
    extra.properties.extend(names);
    let width = extra.properties.len();
    let mut values = Vec::with_capacity(cloud.particles.len() * width);
    for i in 0..cloud.particles.len() {
        values.extend_from_slice(&extra.values[i * old..(i + 1) * old]);
        values.extend(sides[i].slots.iter().map(|&s| s as f64));
        if let Some(h) = hits {
            values.extend(hit_values(&h[i]));
        }
    }
    extra.values = values;
    ParticleCloud {
        particles: cloud.particles.clone(),
        has_side: cloud.has_side,
        extra,
    }
}

/// Writes events as a PLY point cloud (gzipped when the name ends in `.gz`): one vertex per
/// event at the hit's world position, with `step` and `particle` and the hit fields.
pub fn write_events(path: &Path, events: &[HitEvent]) -> Result<()> {
    let mut properties = vec![
        ply::Property {
            name: "x".into(),
            kind: ply::PropertyKind::Scalar(Scalar::F32),
        },
        ply::Property {
            name: "y".into(),
            kind: ply::PropertyKind::Scalar(Scalar::F32),
        },
        ply::Property {
            name: "z".into(),
            kind: ply::PropertyKind::Scalar(Scalar::F32),
        },
    ];
    for name in ["step", "particle"] {
        properties.push(ply::Property {
            name: name.into(),
            kind: ply::PropertyKind::Scalar(Scalar::U32),
        });
    }
    for (name, s) in HIT_COLUMNS {
        properties.push(ply::Property {
            name: name.into(),
            kind: ply::PropertyKind::Scalar(s),
        });
    }
    let vertex = ply::Element {
        name: "vertex".into(),
        count: events.len(),
        properties,
    };
    let mut w = ply::Writer::new(
        ply::Encoding::BinaryLittleEndian,
        &[vertex],
        &["collision events written by octoproxy sim --events"],
    );
    for e in events {
        for c in e.hit.position {
            w.scalar(Scalar::F32, c as f64);
        }
        w.scalar(Scalar::U32, e.step as f64);
        w.scalar(Scalar::U32, e.particle as f64);
        for ((_, s), v) in HIT_COLUMNS.iter().zip(hit_values(&e.hit)) {
            w.scalar(*s, v);
        }
        w.end_entry();
    }
    let mut bytes = w.finish();
    if path.to_string_lossy().to_ascii_lowercase().ends_with(".gz") {
        use std::io::Write as _;
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(&bytes)
            .and_then(|()| gz.flush())
            .with_context(|| format!("compressing {}", path.display()))?;
        bytes = gz
            .finish()
            .with_context(|| format!("compressing {}", path.display()))?;
    }
    let tmp = path.with_extension("octoproxy-tmp");
    std::fs::write(&tmp, &bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// A particle's view of the proxy of instance 0 (a scene of one instance), for sides from a
/// proxy file.
pub fn only_view(scene: &Scene) -> ProxyView<'_> {
    scene.proxies()[0].view()
}

/// Particles in `particles` that start inside a closed instance's mesh (by the exact winding
/// number at its start pose) or within a leaf diagonal of any instance's surface: the scene
/// checks need particles that start outside every part.
pub fn outside_all(
    particles: Vec<Particle>,
    check: &octoproxy_cpu::harness::scene::SceneCheck,
    scene: &Scene,
) -> Vec<Particle> {
    use rayon::prelude::*;
    particles
        .into_par_iter()
        .filter(|p| {
            scene
                .instances()
                .iter()
                .filter(|i| i.is_active())
                .all(|inst| {
                    let k = inst.proxy as usize;
                    let l = inst.start.to_local(Vec3::from_array(p.position)).to_array();
                    let truth = &check.truths[k];
                    !(check.closed[k] && truth.is_inside(l))
                        && truth.distance_capped(l, 4.0 * check.diagonals[k] as f64)
                            > 2.0 * check.diagonals[k] as f64
                })
        })
        .collect()
}
