//! Getting a scene: meshes from files (baked with progress) or a proxy file, and reports.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use octoproxy_core::ProxyView;
use octoproxy_cpu::bake::offset::OffsetSurface;
use octoproxy_cpu::io::{load_mesh, Mesh};
use octoproxy_cpu::{bake, bake_offset, BuildParams, BuildReport, MeshRef};

use crate::progress::BakeBars;

/// A baked scene, with what it was made from.
pub struct Scene {
    pub words: Vec<u32>,
    pub meshes: Vec<Mesh>,
    pub triangles: usize,
    pub bake_time: Option<Duration>,
    pub report: Option<BuildReport>,
    /// The offset surface baked, for a particle radius (`bake_meshes` with a radius).
    pub offset: Option<OffsetSurface>,
}

impl Scene {
    pub fn view(&self) -> Result<ProxyView<'_>> {
        ProxyView::new(&self.words).context("validating the proxy")
    }
}

/// Loads every mesh, reporting each.
pub fn load_meshes(paths: &[PathBuf]) -> Result<Vec<Mesh>> {
    let mut meshes = Vec::new();
    for p in paths {
        let (mesh, report) = load_mesh(p)?;
        eprintln!(
            "loaded {}: {} vertices, {} triangles{}",
            p.display(),
            mesh.positions.len(),
            mesh.triangles.len(),
            if report.polygons_triangulated > 0 {
                format!(" ({} polygons triangulated)", report.polygons_triangulated)
            } else {
                String::new()
            }
        );
        meshes.push(mesh);
    }
    Ok(meshes)
}

/// Bakes meshes into one proxy, with progress bars; for particles of `radius`, the proxy of
/// their offset surface at that distance (kept with the scene, for starting particles).
pub fn bake_meshes(meshes: Vec<Mesh>, params: &BuildParams, radius: f32) -> Result<Scene> {
    let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
    let bars = BakeBars::default();
    let t = Instant::now();
    let result = if radius > 0.0 {
        OffsetSurface::new(&refs, radius, params.dmax, &bars).and_then(|surface| {
            let offset = t.elapsed();
            bake_offset(&surface, params, &bars).map(|(words, mut report)| {
                report.triangles_in = refs.iter().map(|m| m.triangles.len()).sum();
                report.timings.insert(0, ("offset", offset));
                (words, report, Some(surface))
            })
        })
    } else {
        bake(&refs, params, &bars).map(|(words, report)| (words, report, None))
    };
    bars.finish();
    let (words, report, offset) = result.context("baking the proxy")?;
    let bake_time = t.elapsed();
    let triangles = report.triangles_in;
    Ok(Scene {
        words,
        meshes,
        triangles,
        bake_time: Some(bake_time),
        report: Some(report),
        offset,
    })
}

/// Reads and validates a proxy file.
pub fn read_proxy(path: &Path) -> Result<Scene> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    if bytes.len() % 4 != 0 {
        bail!(
            "{}: not a proxy file (length {} is not a multiple of 4)",
            path.display(),
            bytes.len()
        );
    }
    let words: Vec<u32> = bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    ProxyView::new(&words).with_context(|| format!("{} is not a valid proxy", path.display()))?;
    Ok(Scene {
        words,
        meshes: Vec::new(),
        triangles: 0,
        bake_time: None,
        report: None,
        offset: None,
    })
}

/// Writes a proxy file (little-endian words), through a temporary file.
pub fn write_proxy(path: &Path, words: &[u32]) -> Result<()> {
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let tmp = path.with_extension("octoproxy-tmp");
    std::fs::write(&tmp, &bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Prints what a bake produced.
pub fn print_bake_summary(scene: &Scene) -> Result<()> {
    let view = scene.view()?;
    let h = view.header();
    if let Some(r) = &scene.report {
        eprintln!(
            "triangles: {} ({} degenerate skipped, {} in closed components)",
            r.triangles_in, r.degenerate_skipped, r.closed_triangles
        );
        eprintln!(
            "leaves: {} surface ({} two-sided), {} labelled empty ({} with conflicting votes)",
            r.surface_leaves, r.two_sided_leaves, r.labelled_leaves, r.conflicting_labels
        );
        if r.coarse_solid_leaves > 0 {
            eprintln!(
                "warning: {} solid leaves are larger than a dmax leaf after {} passes (rounding kept them from splitting: the scene is far from the origin for its size); particles that start inside them are not covered by the guarantee (move the scene nearer the origin)",
                r.coarse_solid_leaves, r.passes
            );
        }
    }
    if h.radius > 0.0 {
        let leaf = view.finest_leaf_size();
        match &scene.report {
            Some(r) => eprintln!(
                "radius: {} (the offset surface at that distance: {} triangles on a grid of {:.4e}; centres keep at least {:.4e} from the mesh, the radius less {:.2} dmax leaves)",
                h.radius,
                r.offset_triangles,
                r.offset_spacing,
                h.radius as f64 - r.offset_spacing * 3f64.sqrt(),
                r.offset_spacing * 3f64.sqrt() / leaf as f64
            ),
            None => eprintln!(
                "radius: {} (baked for particles of that radius: centres keep at least the radius less a dmax leaf diagonal from the mesh)",
                h.radius
            ),
        }
    }
    if h.radius > 0.0 && (h.radius as f64) < 3f64.sqrt() * view.finest_leaf_size() as f64 {
        eprintln!(
            "warning: the radius {} is less than a dmax leaf's diagonal ({:.4e}): centres may come as near the mesh as the radius less that diagonal, so the radius means little; raise dmax",
            h.radius,
            3f64.sqrt() * view.finest_leaf_size() as f64
        );
    }
    eprintln!(
        "proxy: {} nodes, depth {} (dmin {}, dmax {}, epsilon {}), lookup table depth {}",
        h.node_count, h.tree_depth, h.dmin, h.dmax, h.epsilon, h.lut_depth
    );
    eprintln!(
        "size: {} (node array {}, lookup table {})",
        bytes((view.words().len() * 4) as u64),
        bytes(view.node_bytes() as u64),
        bytes(view.lut_bytes() as u64)
    );
    if let Some(t) = scene.bake_time {
        let stages = scene.report.as_ref().map(|r| stages(&r.timings));
        eprintln!(
            "bake time: {:.3} s{}",
            t.as_secs_f64(),
            stages.map(|s| format!(" ({s})")).unwrap_or_default()
        );
    }
    Ok(())
}

/// The bake's stages, each summed over the passes that repeat it, in the order they first
/// ran: "offset 4.1 s, gather 0.05 s, subdivide 2.3 s over 2 passes, ...".
fn stages(timings: &[(&'static str, Duration)]) -> String {
    let mut sums: Vec<(&str, Duration, u32)> = Vec::new();
    for &(name, t) in timings {
        match sums.iter_mut().find(|s| s.0 == name) {
            Some(s) => (s.1, s.2) = (s.1 + t, s.2 + 1),
            None => sums.push((name, t, 1)),
        }
    }
    let parts: Vec<String> = sums
        .iter()
        .map(|&(name, t, n)| {
            let passes = if n > 1 {
                format!(" over {n} passes")
            } else {
                String::new()
            };
            format!("{name} {}{passes}", seconds(t))
        })
        .collect();
    parts.join(", ")
}

/// Seconds with three significant digits.
fn seconds(t: Duration) -> String {
    let s = t.as_secs_f64();
    if s >= 10.0 {
        format!("{s:.1} s")
    } else if s >= 1.0 {
        format!("{s:.2} s")
    } else {
        format!("{s:.3} s")
    }
}

/// Human-readable byte count.
pub fn bytes(n: u64) -> String {
    if n >= 1 << 30 {
        format!("{:.2} GiB", n as f64 / (1u64 << 30) as f64)
    } else if n >= 1 << 20 {
        format!("{:.2} MiB", n as f64 / (1u64 << 20) as f64)
    } else if n >= 1 << 10 {
        format!("{:.1} KiB", n as f64 / 1024.0)
    } else {
        format!("{n} B")
    }
}

#[cfg(test)]
mod tests {
    use super::stages;
    use std::time::Duration;

    #[test]
    fn a_stage_repeated_by_passes_is_summed_where_it_first_ran() {
        let ms = Duration::from_millis;
        let timings = [
            ("gather", ms(50)),
            ("subdivide", ms(1200)),
            ("label", ms(300)),
            ("subdivide", ms(800)),
            ("label", ms(250)),
            ("encode", ms(12_500)),
        ];
        assert_eq!(
            stages(&timings),
            "gather 0.050 s, subdivide 2.00 s over 2 passes, label 0.550 s over 2 passes, encode 12.5 s"
        );
    }
}
