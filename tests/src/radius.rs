//! Scenes baked for a particle radius, as the tests of particles that collide with each
//! other use them: the proxy of the offset surface, the surface itself (to place and side
//! starting particles), and the exact ground truth of the meshes.

use octoproxy_core::{Particle, ProxyView};
use octoproxy_cpu::bake::offset::{OffsetSurface, PlaceCounts};
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::io::Mesh;
use octoproxy_cpu::{bake_offset, scenes, BuildParams, MeshRef};

/// A scene baked for a radius.
pub struct RadiusScene {
    /// The proxy's words.
    pub words: Vec<u32>,
    /// The offset surface it was baked from.
    pub surface: OffsetSurface,
    /// The meshes' own exact ground truth (never the proxy).
    pub truth: GroundTruth,
    /// The proxy's finest leaf edge.
    pub leaf: f32,
    /// The radius.
    pub radius: f32,
}

/// Bakes `meshes` at `dmax` for `radius`. Panics on a bake error (for tests).
pub fn bake_for(meshes: &[Mesh], dmax: u32, radius: f32) -> RadiusScene {
    let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
    let params = BuildParams {
        dmax,
        ..BuildParams::default()
    };
    let surface = OffsetSurface::new(&refs, radius, dmax, &()).unwrap();
    let (words, _) = bake_offset(&surface, &params, &()).unwrap();
    let leaf = ProxyView::new(&words).unwrap().finest_leaf_size();
    let all = scenes::merge(meshes);
    let truth = GroundTruth::new(&all.positions, &all.triangles);
    RadiusScene {
        words,
        surface,
        truth,
        leaf,
        radius,
    }
}

impl RadiusScene {
    /// Starting particles: moved out of the band, with their sides and cages from the offset
    /// surface. Says how many were moved and how many could not be.
    pub fn start(&self, ps: &mut [Particle]) -> PlaceCounts {
        let view = ProxyView::new(&self.words).unwrap();
        let placed = self.surface.place(ps, Some(&view));
        self.surface.assign_sides(ps, false);
        self.surface.cages(&view, ps, false);
        placed
    }
}
