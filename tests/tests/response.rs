//! Particles bounce off a surface about the surface's own normal. An open mesh's leaves are
//! solid from every side (and answer with the normal of the box face a particle enters) only
//! where a rim edge passes through them: a large open triangle keeps its normal everywhere
//! else. When every leaf a rim triangle touched was solid, particles dropped on a tilted
//! sheet of two triangles bounced straight back up, 33° off the reflection.

use glam::Vec3;
use octoproxy_core::{step_particle, Particle, ProxyView, StepParams};
use octoproxy_cpu::emit::Rng;
use octoproxy_cpu::scenes::{self, Mesh};
use octoproxy_cpu::{bake, BuildParams, MeshRef};

/// A 2 × 2 open sheet of two triangles, tilted by `angle` about z: facing `(-sin, cos, 0)`.
fn tilted_sheet(angle: f32) -> Mesh {
    let mut m = scenes::flat_sheet([0.0; 3], 2.0, 1);
    for p in &mut m.positions {
        let (x, y) = (p[0], p[1]);
        p[0] = x * angle.cos() - y * angle.sin();
        p[1] = x * angle.sin() + y * angle.cos();
    }
    m
}

#[test]
fn particles_reflect_off_a_tilted_open_sheet_about_its_normal() {
    let angle = 0.3f32;
    let mesh = tilted_sheet(angle);
    let (words, report) =
        bake(&[MeshRef::from(&mesh)], &BuildParams::default(), &()).expect("bakes");
    let view = ProxyView::new(&words).expect("valid");
    // Its rim is still solid: only the leaves along it.
    assert!(report.two_sided_leaves > 0, "the rim's leaves are solid");
    assert!(
        report.two_sided_leaves * 2 < report.surface_leaves,
        "{} of {} surface leaves are solid",
        report.two_sided_leaves,
        report.surface_leaves
    );
    let n = Vec3::new(-angle.sin(), angle.cos(), 0.0);
    let params = StepParams {
        gravity: [0.0; 3],
        dt: 1.0 / 60.0,
        restitution: 1.0,
        friction: 0.0,
        radius: 0.0,
        _pad: 0,
    };
    let mut rng = Rng::new(11);
    let v = Vec3::new(0.0, -3.0, 0.0);
    let mut worst = 0.0f32;
    for _ in 0..2000 {
        // Above the middle 80 % of the sheet, 1 to 2 steps above it.
        let (u, z) = (rng.range(-0.8, 0.8), rng.range(-0.8, 0.8));
        let on = Vec3::new(u * angle.cos(), u * angle.sin(), z);
        let mut p = Particle::new(
            (on + Vec3::Y * rng.range(0.05, 0.1)).to_array(),
            v.to_array(),
        );
        for _ in 0..3 {
            step_particle(&view, &mut p, &params);
        }
        assert_eq!(
            p.collisions(),
            1,
            "particle above {on} collided {} times",
            p.collisions()
        );
        let want = v - 2.0 * v.dot(n) * n;
        let got = Vec3::from_array(p.velocity);
        let off = got
            .normalize()
            .dot(want.normalize())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        worst = worst.max(off);
    }
    // The normal is stored in 15-bit octahedral components: a few thousandths of a degree.
    assert!(worst < 0.05, "a response {worst}° off the reflection");
}
