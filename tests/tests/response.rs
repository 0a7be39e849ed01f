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

/// A particle the shell rule stops is put back where it entered the shell, its velocity
/// reflected off the face it tried to cross, and goes on from there with the time left, as
/// after a collision; stopped a second time in the step, it stays there. At the sharp edges
/// of a wedge and a star, steps the rule stopped go on past the jump back, none jumps back
/// more than twice, and every piece after a jump starts where the jump put the particle.
#[test]
fn a_particle_the_shell_rule_stops_goes_on_from_the_shell_entry() {
    use octoproxy_core::{initial_side, step_particle_traced, FLAG_BLOCKED};
    use octoproxy_cpu::harness::jumps_back;
    let mesh = scenes::merge(&[
        scenes::wedge(8.0, 2.0, 1.0),
        scenes::star_prism(7, 1.5, 0.4, 1.0),
    ]);
    let build = BuildParams {
        dmax: 7,
        ..BuildParams::default()
    };
    let (words, _) = bake(&[MeshRef::from(&mesh)], &build, &()).expect("bakes");
    let view = ProxyView::new(&words).expect("valid");
    let leaf = view.finest_leaf_size();
    let root = view.root_aabb();
    let params = StepParams {
        dt: 1.0,
        gravity: [0.0; 3],
        restitution: 0.2,
        friction: 0.1,
        ..StepParams::default()
    };
    let mut rng = Rng::new(11);
    let (mut blocked, mut went_on, mut twice) = (0u32, 0u32, 0u32);
    for _ in 0..4000 {
        let x = Vec3::new(
            rng.range(root.min.x, root.max.x),
            rng.range(root.min.y, root.max.y),
            rng.range(root.min.z, root.max.z),
        );
        let mut p = Particle::new(x.to_array(), (rng.unit_vector() * leaf * 2.0).to_array());
        p.side = initial_side(&view, p.position);
        for _ in 0..30 {
            let mut pieces = Vec::new();
            step_particle_traced(&view, &mut p, &params, &mut |a: Vec3, b: Vec3| {
                pieces.push((a, b))
            });
            if p.flags & FLAG_BLOCKED == 0 {
                continue;
            }
            blocked += 1;
            let jumps = jumps_back(&pieces, p.flags);
            let at: Vec<usize> = (0..jumps.len()).filter(|&i| jumps[i]).collect();
            assert!(!at.is_empty() && at.len() <= 2, "{} jumps back", at.len());
            for &i in &at {
                if let Some(next) = pieces.get(i + 1) {
                    assert_eq!(
                        next.0, pieces[i].1,
                        "a piece after the jump starts elsewhere"
                    );
                }
            }
            went_on += (at[0] + 1 < pieces.len()) as u32;
            twice += (at.len() == 2) as u32;
        }
    }
    eprintln!(
        "{blocked} blocked steps, {went_on} went on after the jump back, {twice} blocked twice"
    );
    assert!(blocked > 0 && went_on > 0, "no blocked step went on");
}
