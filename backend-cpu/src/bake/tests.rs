//! Unit tests of the baker: the metric, labels, encoding round trip and validation.

use glam::Vec3;
use octoproxy_core::*;

use super::*;

/// A closed, outward-facing axis-aligned box.
fn cube(min: [f32; 3], max: [f32; 3]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut p = Vec::new();
    for i in 0..8 {
        p.push([
            if i & 1 == 0 { min[0] } else { max[0] },
            if i & 2 == 0 { min[1] } else { max[1] },
            if i & 4 == 0 { min[2] } else { max[2] },
        ]);
    }
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut t = Vec::new();
    for q in quads {
        t.push([q[0], q[1], q[2]]);
        t.push([q[0], q[2], q[3]]);
    }
    (p, t)
}

fn bake_one(p: &[[f32; 3]], t: &[[u32; 3]], params: &BuildParams) -> (Vec<u32>, BuildReport) {
    bake(
        &[MeshRef {
            positions: p,
            triangles: t,
        }],
        params,
        &(),
    )
    .expect("bakes")
}

#[test]
fn cube_is_closed_and_outward() {
    let (p, t) = cube([0.0; 3], [1.0; 3]);
    let (closed, rim, _) = edge_classes(&MeshRef {
        positions: &p,
        triangles: &t,
    });
    assert!(closed.iter().all(|&c| c));
    assert!(rim.iter().all(|&r| r == 0));
    let tris = gather(
        &[MeshRef {
            positions: &p,
            triangles: &t,
        }],
        &mut BuildReport::default(),
    )
    .unwrap();
    for tri in &tris {
        let v = tri.v();
        let c = (v[0] + v[1] + v[2]) / 3.0 - DVec3::splat(0.5);
        assert!(tri.n.dot(c) > 0.0, "normals point out");
    }
    // Dropping one triangle opens it.
    let (closed, rim, _) = edge_classes(&MeshRef {
        positions: &p,
        triangles: &t[1..],
    });
    assert!(closed.iter().all(|&c| !c));
    // The three triangles that shared an edge with the removed one now have a rim edge, one
    // each: the one they shared with it.
    assert_eq!(rim.iter().filter(|&&r| r != 0).count(), 3);
    assert!(rim.iter().all(|&r| r.count_ones() <= 1));
    let removed: Vec<u32> = t[0].to_vec();
    for (tri, &r) in t[1..].iter().zip(&rim).filter(|(_, &r)| r != 0) {
        let k = r.trailing_zeros() as usize;
        let edge = [tri[k], tri[(k + 1) % 3]];
        assert!(
            edge.iter().all(|i| removed.contains(i)),
            "rim edge {edge:?} is not the removed triangle's"
        );
    }
}

/// A seam of duplicated vertices where one copy says `-0.0` and the other `0.0` (what a
/// mirror modifier writes on its plane) is one position: the mesh stays closed, as `weld`
/// (the scene's vertex ids) already had it.
#[test]
fn a_seam_of_minus_zero_and_zero_is_welded() {
    let (mut p, mut t) = cube([0.0; 3], [1.0; 3]);
    // The faces of the box that touch x = 0 use copies of their vertices with x = -0.0.
    let base = p.len() as u32;
    for i in 0..8 {
        let mut q = p[i];
        q[0] = -q[0];
        p.push(q);
    }
    let on_plane = |i: u32| p[i as usize][0] == 0.0;
    for tri in t.iter_mut().filter(|tri| tri.iter().all(|&i| on_plane(i))) {
        *tri = tri.map(|i| i + base);
    }
    assert!(p.iter().any(|q| q[0].to_bits() == (-0.0f32).to_bits()));
    let mesh = MeshRef {
        positions: &p,
        triangles: &t,
    };
    let (closed, rim, component) = edge_classes(&mesh);
    assert!(closed.iter().all(|&c| c), "{closed:?}");
    assert!(rim.iter().all(|&r| r == 0), "{rim:?}");
    assert!(component.iter().all(|&c| c == component[0]));
}

#[test]
fn variance_metric_is_area_normalised() {
    let (p, t) = cube([0.0; 3], [1.0; 3]);
    let tris = gather(
        &[MeshRef {
            positions: &p,
            triangles: &t,
        }],
        &mut BuildReport::default(),
    )
    .unwrap();
    let grid = root_grid(&tris, 6).unwrap();
    let boxes: Vec<[f32; 6]> = tris.iter().map(|t| crowd::outward_box(&t.v())).collect();
    let ctx = Subdiv {
        tris: &tris,
        boxes: &boxes,
        grid,
        params: BuildParams::default(),
        force: &Forced::default(),
        nodes: AtomicU64::new(0),
        over: AtomicBool::new(false),
        progress: &(),
    };
    // One face (two coplanar triangles): zero variance.
    assert_eq!(ctx.variance(&[0, 1]), 0.0);
    // Two perpendicular faces of equal area: mean normal at 45°, each off by |n - avg|² = 2 - √2.
    let v = ctx.variance(&[0, 1, 4, 5]);
    assert!((v - (2.0 - 2f64.sqrt())).abs() < 1e-12, "{v}");
    // Opposite faces cancel: infinite, so the node always subdivides.
    assert!(ctx.variance(&[0, 1, 2, 3]).is_infinite());
}

#[test]
fn cube_labels_inside_back_outside_front() {
    let (p, t) = cube([-1.0; 3], [1.0; 3]);
    let params = BuildParams {
        dmin: 2,
        dmax: 5,
        ..BuildParams::default()
    };
    let (words, report) = bake_one(&p, &t, &params);
    let view = ProxyView::new(&words).expect("valid");
    assert_eq!(report.conflicting_labels, 0);
    assert!(report.labelled_leaves > 0);
    let h = view.finest_leaf_size();
    // Walking away from each face, the first empty leaf is back inside and front outside.
    let first_empty = |axis: usize, from: f32, step: f32| -> Option<LeafInfo> {
        (1..64).find_map(|k| {
            let mut q = Vec3::splat(0.05);
            q[axis] = from + step * k as f32;
            view.locate_leaf(q).filter(|l| l.kind == LeafKind::Empty)
        })
    };
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let inside = first_empty(axis, sign, -sign * h / 8.0).expect("an empty leaf inside");
            let outside = first_empty(axis, sign, sign * h / 8.0).expect("an empty leaf outside");
            assert_eq!(inside.label, Label::Back, "axis {axis} sign {sign}");
            assert_eq!(outside.label, Label::Front, "axis {axis} sign {sign}");
        }
    }
    // On the face: a surface leaf whose normal is the face's.
    let on = view.locate_leaf(Vec3::new(1.0, 0.3, 0.2)).unwrap();
    let on = if on.kind == LeafKind::Surface {
        on
    } else {
        view.locate_leaf_toward(Vec3::new(1.0, 0.3, 0.2), -Vec3::X)
            .unwrap()
    };
    assert_eq!(on.kind, LeafKind::Surface);
    assert!((on.normal - Vec3::X).length() < 1e-3, "{}", on.normal);
}

#[test]
fn lut_and_root_descent_agree() {
    let (p, t) = cube([-1.0, -0.5, -0.25], [1.0, 0.7, 0.3]);
    let (words, _) = bake_one(
        &p,
        &t,
        &BuildParams {
            dmin: 1,
            dmax: 6,
            lut_depth: 3,
            ..BuildParams::default()
        },
    );
    let view = ProxyView::new(&words).unwrap();
    let nolut = view.without_lut();
    let mut s = 99u64;
    let mut r = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32 * 3.0 - 1.5
    };
    for _ in 0..5000 {
        let q = Vec3::new(r(), r(), r());
        let d = Vec3::new(r(), r(), r());
        assert_eq!(
            view.locate_leaf_toward(q, d),
            nolut.locate_leaf_toward(q, d)
        );
    }
}

#[test]
fn validation_rejects_every_single_bit_flip_or_survives_it() {
    let (p, t) = cube([-1.0; 3], [1.0; 3]);
    let (words, _) = bake_one(
        &p,
        &t,
        &BuildParams {
            dmin: 1,
            dmax: 4,
            lut_depth: 2,
            ..BuildParams::default()
        },
    );
    assert!(ProxyView::new(&words).is_ok());
    // Truncation at any length is an error, never a panic.
    for len in 0..words.len() {
        assert!(ProxyView::new(&words[..len]).is_err(), "truncated to {len}");
    }
    // Any bit flip either fails validation or leaves a proxy whose queries still work.
    for i in 0..words.len() {
        for bit in [0, 1, 7, 16, 30, 31] {
            let mut w = words.clone();
            w[i] ^= 1 << bit;
            if let Ok(v) = ProxyView::new(&w) {
                let _ = v.locate_leaf(Vec3::new(0.1, 0.2, 0.3));
                let mut part = Particle::new([0.0, 3.0, 0.0], [0.0, -50.0, 0.0]);
                step_particle(&v, &mut part, &StepParams::default());
            }
        }
    }
    // Version mismatch has its own error.
    let mut w = words.clone();
    w[1] = 99;
    assert_eq!(
        ProxyView::new(&w).unwrap_err(),
        FormatError::UnsupportedVersion { found: 99 }
    );
}

#[test]
fn bad_input_is_an_error() {
    let (p, t) = cube([0.0; 3], [1.0; 3]);
    let mut bad = p.clone();
    bad[3][1] = f32::NAN;
    let r = bake(
        &[MeshRef {
            positions: &bad,
            triangles: &t,
        }],
        &BuildParams::default(),
        &(),
    );
    assert!(matches!(r, Err(BuildError::NonFinite { vertex: 3, .. })));
    let mut badt = t.clone();
    badt[5][2] = 8;
    let r = bake(
        &[MeshRef {
            positions: &p,
            triangles: &badt,
        }],
        &BuildParams::default(),
        &(),
    );
    assert!(matches!(
        r,
        Err(BuildError::IndexOutOfRange {
            triangle: 5,
            index: 8,
            ..
        })
    ));
    let degenerate = vec![[0, 0, 1], [1, 1, 1]];
    let r = bake(
        &[MeshRef {
            positions: &p,
            triangles: &degenerate,
        }],
        &BuildParams::default(),
        &(),
    );
    assert!(matches!(r, Err(BuildError::Empty { degenerate: 2 })));
    for params in [
        BuildParams {
            dmax: 0,
            ..Default::default()
        },
        BuildParams {
            dmax: 40,
            ..Default::default()
        },
        BuildParams {
            dmin: 9,
            dmax: 8,
            ..Default::default()
        },
        BuildParams {
            epsilon: -1.0,
            ..Default::default()
        },
        BuildParams {
            epsilon: f32::NAN,
            ..Default::default()
        },
        BuildParams {
            lut_depth: 9,
            ..Default::default()
        },
    ] {
        assert!(matches!(
            bake(
                &[MeshRef {
                    positions: &p,
                    triangles: &t
                }],
                &params,
                &()
            ),
            Err(BuildError::BadParam(_))
        ));
    }
    // Scenes beyond what f32 can grid: too large, too small, and far for their size.
    let scaled = |s: f32, o: f32| p.iter().map(|v| v.map(|c| c * s + o)).collect::<Vec<_>>();
    let bake_at = |q: &[[f32; 3]]| {
        bake(
            &[MeshRef {
                positions: q,
                triangles: &t,
            }],
            &BuildParams::default(),
            &(),
        )
    };
    let r = bake_at(&scaled(3e38, 0.0));
    assert!(matches!(r, Err(BuildError::TooLarge { .. })), "{r:?}");
    assert!(r.unwrap_err().to_string().contains("too large"));
    let r = bake_at(&scaled(1e-36, 0.0));
    assert!(
        matches!(r, Err(BuildError::TooSmall { dmax: 8, .. })),
        "{r:?}"
    );
    let r = bake_at(&scaled(1.0, 1e6));
    assert!(matches!(r, Err(BuildError::Resolution { .. })), "{r:?}");
    assert!(
        bake_at(&scaled(1e-30, 0.0)).is_ok(),
        "a tiny scene at the origin still bakes"
    );
    // A runaway tree stops at the node cap.
    let big = BuildParams {
        dmax: 16,
        dmin: 16,
        max_nodes: 10_000,
        ..Default::default()
    };
    assert!(matches!(
        bake(
            &[MeshRef {
                positions: &p,
                triangles: &t
            }],
            &big,
            &()
        ),
        Err(BuildError::TooManyNodes { .. })
    ));
}

#[test]
fn particles_bounce_off_a_closed_box_from_both_sides() {
    let (p, t) = cube([-1.0; 3], [1.0; 3]);
    let (words, _) = bake_one(
        &p,
        &t,
        &BuildParams {
            dmin: 2,
            dmax: 6,
            ..BuildParams::default()
        },
    );
    let view = ProxyView::new(&words).unwrap();
    let params = StepParams {
        gravity: [0.0, -9.81, 0.0],
        dt: 0.01,
        restitution: 0.5,
        friction: 0.1,
        radius: 0.0,
        _pad: 0,
    };
    // Outside, falling onto the top; inside, falling onto the floor from within.
    let mut outside = Particle::new([0.1, 2.0, 0.2], [0.0, -3.0, 0.0]);
    let mut inside = Particle::new([0.1, 0.5, 0.2], [0.0, -3.0, 0.0]);
    inside.side = initial_side(&view, inside.position);
    assert_eq!(
        inside.side, SIDE_FRONT,
        "the centre is unlabelled: front until a label stamps it"
    );
    for _ in 0..2000 {
        step_particle(&view, &mut outside, &params);
        step_particle(&view, &mut inside, &params);
        assert!(
            outside.position[1] >= 1.0 - 1e-6,
            "outside sank to {:?}",
            outside.position
        );
        assert!(
            inside.position[1] >= -1.0 - 1e-6 && inside.position[1] <= 1.0,
            "inside left: {:?}",
            inside.position
        );
    }
    assert!(outside.collisions() > 0 && inside.collisions() > 0);
    assert_eq!(inside.side, SIDE_BACK);
    // Both came to rest on their surfaces.
    assert!(
        (outside.position[1] - 1.0).abs() < 0.05,
        "{:?}",
        outside.position
    );
    assert!(
        (inside.position[1] + 1.0).abs() < 0.05,
        "{:?}",
        inside.position
    );
}

#[test]
fn nan_particles_are_flagged_and_unchanged() {
    let (p, t) = cube([-1.0; 3], [1.0; 3]);
    let (words, _) = bake_one(
        &p,
        &t,
        &BuildParams {
            dmin: 2,
            dmax: 4,
            ..BuildParams::default()
        },
    );
    let view = ProxyView::new(&words).unwrap();
    for bad in [
        Particle::new([f32::NAN, 0.0, 0.0], [0.0; 3]),
        Particle::new([0.0; 3], [0.0, f32::INFINITY, 0.0]),
        Particle::new([f32::NEG_INFINITY, 0.0, 0.0], [1.0; 3]),
    ] {
        let mut q = bad;
        assert_eq!(
            step_particle(&view, &mut q, &StepParams::default()),
            StepOutcome::Invalid
        );
        assert_eq!(q.position.map(f32::to_bits), bad.position.map(f32::to_bits));
        assert_eq!(q.velocity.map(f32::to_bits), bad.velocity.map(f32::to_bits));
        assert_ne!(q.flags & FLAG_INVALID, 0);
    }
}

#[test]
fn particles_starting_inside_big_surface_leaves_get_the_plane_side() {
    // A large epsilon stops subdivision early: the cube's faces lie in big flat leaves.
    // A small second cube far away keeps the first one off the root boundary.
    let (p, t) = cube([-1.0; 3], [1.0; 3]);
    let (p2, t2) = cube([5.0; 3], [5.5; 3]);
    let params = BuildParams {
        dmin: 1,
        dmax: 6,
        epsilon: 10.0,
        ..BuildParams::default()
    };
    let meshes = [
        MeshRef {
            positions: &p,
            triangles: &t,
        },
        MeshRef {
            positions: &p2,
            triangles: &t2,
        },
    ];
    let (words, _) = bake(&meshes, &params, &()).unwrap();
    let view = ProxyView::new(&words).unwrap();
    let mut checked = 0;
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            for (offset, expect) in [(-0.15f32, SIDE_BACK), (0.15, SIDE_FRONT)] {
                let mut q = Vec3::splat(0.3);
                q[axis] = sign * (1.0 + offset);
                let leaf = view.locate_leaf(q).unwrap();
                if leaf.kind == LeafKind::Surface {
                    assert!(leaf.depth < 6, "the face leaf is big");
                    assert_eq!(
                        initial_side(&view, q.to_array()),
                        expect,
                        "{q} in {:?}",
                        leaf.aabb
                    );
                    checked += 1;
                }
            }
        }
    }
    assert!(checked >= 6, "only {checked} points fell in surface leaves");
}

#[test]
fn a_flat_patch_stops_early_only_where_it_spans_the_leaf() {
    // A big cube sets the grid; the test boxes are cut to one of its depth-3 cells.
    let (p, t) = cube([-8.0; 3], [8.0; 3]);
    let params = BuildParams {
        dmax: 8,
        ..BuildParams::default()
    };
    let big = gather(
        &[MeshRef {
            positions: &p,
            triangles: &t,
        }],
        &mut BuildReport::default(),
    )
    .unwrap();
    let grid = root_grid(&big, params.dmax).unwrap();
    let (cell, depth) = (UVec3::new(3, 4, 3), 3);
    let (lo, hi) = grid.cell_box(cell, depth);
    let size = hi.x - lo.x;
    let flat = MAX_EARLY_LEAF_THICKNESS * grid.root_size as f64 / 256.0;
    // Closed boxes whose top face lies in the cell: across all of it, or ending in its middle,
    // barely above its floor (the side face there is a sliver thinner than the flat tolerance:
    // flat, and with a large epsilon nearly flat enough in normal too, but the patch leaves the
    // cell through the floor it nearly lies in). Found by particles started on grid planes,
    // against Suzanne baked with dmin 0 and epsilon 1.
    let slab = |x_end: f64, top: f64| {
        let min = [
            (lo.x - size) as f32,
            (lo.y - size) as f32,
            (lo.z - size) as f32,
        ];
        let (p, t) = cube(min, [x_end as f32, top as f32, (hi.z + size) as f32]);
        let tris = gather(
            &[MeshRef {
                positions: &p,
                triangles: &t,
            }],
            &mut BuildReport::default(),
        )
        .unwrap();
        let boxes: Vec<[f32; 6]> = tris.iter().map(|t| crowd::outward_box(&t.v())).collect();
        let ctx = Subdiv {
            tris: &tris,
            boxes: &boxes,
            grid,
            params,
            force: &Forced::default(),
            nodes: AtomicU64::new(0),
            over: AtomicBool::new(false),
            progress: &(),
        };
        let list: Vec<u32> = (0..tris.len() as u32)
            .filter(|&i| geom::triangle_overlaps_box(&tris[i as usize].v(), lo, hi))
            .collect();
        assert!(!list.is_empty());
        ctx.thickness(&list, cell, depth)
    };
    let across = slab(hi.x + size, lo.y + 0.3 * size);
    assert!(
        across <= 1e-6 * size,
        "a face across the cell is flat and spans it: {across}"
    );
    let low = slab(hi.x + size, lo.y + 0.2 * flat);
    assert!(
        low <= 1e-6 * size,
        "a face just above the floor still spans the cell: {low}"
    );
    let ends = slab(0.5 * (lo.x + hi.x), lo.y + 0.2 * flat);
    assert!(
        ends.is_infinite(),
        "a face that ends in the middle of the cell does not span it: {ends}"
    );
    // Ending 1.8 dmax leaves short of the far side (a knife thinner than a leaf whose end is
    // in the cell): a quarter of the section, which an area test let pass, is farther than a
    // leaf from the patch (found by the penetration fuzz target). Half a leaf short is within
    // the rim the test allows.
    let leaf = 2.0 * flat;
    let short = slab(hi.x - 1.8 * leaf, lo.y + 0.2 * flat);
    assert!(
        short.is_infinite(),
        "a face that ends 1.8 leaves short of the far side does not span the cell: {short}"
    );
    let rim = slab(hi.x - 0.5 * leaf, lo.y + 0.2 * flat);
    assert!(
        rim.is_finite(),
        "a face that ends half a leaf short of the far side spans the cell: {rim}"
    );
}

#[test]
fn owned_proxy_views_like_a_fresh_validation() {
    let (p, t) = cube([-1.0; 3], [1.0; 3]);
    let (words, _) = bake_one(
        &p,
        &t,
        &BuildParams {
            dmin: 2,
            dmax: 5,
            ..BuildParams::default()
        },
    );
    let owned = OwnedProxy::new(words.clone()).expect("valid");
    let fresh = ProxyView::new(&words).unwrap();
    let view = owned.view();
    assert_eq!(view.header(), fresh.header());
    assert_eq!(view.words(), fresh.words());
    assert_eq!(view.lut(), fresh.lut());
    let mut rng = crate::emit::Rng::new(4);
    for _ in 0..2000 {
        let q = Vec3::new(
            rng.range(-1.3, 1.3),
            rng.range(-1.3, 1.3),
            rng.range(-1.3, 1.3),
        );
        assert_eq!(view.locate_leaf(q), fresh.locate_leaf(q));
    }
    let mut bad = words;
    bad[1] = 99;
    assert_eq!(
        OwnedProxy::new(bad).unwrap_err(),
        FormatError::UnsupportedVersion { found: 99 }
    );
}

/// Fuzzing found scenes near 1e30 whose triangles pass the parent's exact overlap test but no
/// child's (rounding), which left internal nodes with no children: an invalid proxy. Such a
/// node now stays a surface leaf, and every bake validates.
#[test]
fn extreme_coordinates_bake_to_a_valid_proxy_or_an_error() {
    let p = [
        [-2.5763879e29, 7.5514705e29, -9.525689e29],
        [3.3367426e29, -2.3047377e29, 4.8999003e29],
        [-5.0081777e29, 8.359352e29, -1e30],
        [-1e30, -1e30, -1e30],
        [-1e30, 1.686274e29, 1.686274e29],
        [1.686274e29, 1.686274e29, 1.686274e29],
    ];
    let mut rng = crate::emit::Rng::new(11);
    for _ in 0..300 {
        let t: Vec<[u32; 3]> = (0..1 + rng.next_u64() % 9)
            .map(|_| [0, 1, 2].map(|_| (rng.next_u64() % 6) as u32))
            .collect();
        let params = BuildParams {
            dmin: 3,
            dmax: 4,
            epsilon: 0.0,
            lut_depth: 0,
            ..BuildParams::default()
        };
        if let Ok((words, _)) = bake(
            &[MeshRef {
                positions: &p,
                triangles: &t,
            }],
            &params,
            &(),
        ) {
            ProxyView::new(&words).expect("a bake always validates");
        }
    }
}

#[test]
fn locating_from_the_last_leaf_agrees_with_locating_from_scratch() {
    // The march finds each next leaf from the one it leaves, in integers; that must be the leaf
    // a descent finds for every point on a leaf's box (faces, edges, corners), in every
    // direction (zero, either sign, NaN), with and without the lookup table.
    let (mut p, mut t) = cube([-1.0, -0.5, -0.25], [1.0, 0.7, 0.3]);
    // A tilted second box, so that leaves of many depths meet.
    let (q, u) = cube([-0.3, -0.9, -0.8], [0.9, -0.2, 0.6]);
    let off = p.len() as u32;
    p.extend(
        q.iter()
            .map(|v| [v[0] + 0.3 * v[1], v[1] - 0.2 * v[2], v[2] + 0.25 * v[0]]),
    );
    t.extend(u.iter().map(|tri| tri.map(|i| i + off)));
    let (words, _) = bake_one(
        &p,
        &t,
        &BuildParams {
            dmin: 1,
            dmax: 7,
            lut_depth: 3,
            ..BuildParams::default()
        },
    );
    let view = ProxyView::new(&words).unwrap();
    let mut s = 7u64;
    let mut r = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s >> 40
    };
    let (mut on_faces, mut moved) = (0, 0);
    for v in [view, view.without_lut()] {
        let root = v.root_aabb();
        for _ in 0..3000 {
            let f = |k: u64| k as f32 / (1u64 << 24) as f32;
            let x = root.min + (root.max - root.min) * Vec3::new(f(r()), f(r()), f(r()));
            let Some(from) = v.locate_leaf(x) else {
                continue;
            };
            // Per axis: the lower plane, the upper one, or a point between them.
            let mut q = x;
            for a in 0..3 {
                q[a] = match r() % 3 {
                    0 => from.aabb.min[a],
                    1 => from.aabb.max[a],
                    _ => q[a],
                };
            }
            let pick = |k: u64| [0.0, 1.0, -1.0, -0.0, f32::NAN][(k % 5) as usize];
            let dir = Vec3::new(pick(r()), pick(r()), pick(r()));
            let expected = v.locate_leaf_toward(q, dir);
            assert_eq!(
                v.locate_leaf_from(&from, q, dir),
                expected,
                "from {from:?} at {q:?} toward {dir:?}"
            );
            on_faces += (q != x) as u32;
            moved += expected.is_some_and(|l| l.cell != from.cell || l.depth != from.depth) as u32;
        }
    }
    // Most points were put on a face, and many of those are in another leaf.
    assert!(
        on_faces > 4000 && moved > 1500,
        "{on_faces} points on faces, {moved} in another leaf"
    );
}

#[test]
fn forced_cells_overlap_exactly_the_cells_that_nest_with_them() {
    // Against the definition: closed-open plane ranges that overlap on every axis.
    let range = |depth: u32, cell: UVec3| {
        let s = MAX_DEPTH - depth;
        (cell << s, (cell + 1) << s)
    };
    let overlap =
        |a: (UVec3, UVec3), b: (UVec3, UVec3)| a.0.cmplt(b.1).all() && b.0.cmplt(a.1).all();
    let mut rng = crate::emit::Rng::new(5);
    let mut cell_at = |depth: u32| {
        let n = 1u32 << depth;
        UVec3::new(
            rng.next_u64() as u32 % n,
            rng.next_u64() as u32 % n,
            rng.next_u64() as u32 % n,
        )
    };
    let forced: Vec<(u32, UVec3)> = [2u32, 3, 5, 5, 7]
        .iter()
        .map(|&d| (d, cell_at(d)))
        .collect();
    let mut set = Forced::default();
    assert!(!set.overlaps(0, UVec3::ZERO), "nothing forced yet");
    for &(d, c) in &forced {
        set.add(d, c);
    }
    let mut hits = 0;
    for depth in 0..=8 {
        for probe in 0..400 {
            // Half the probes inside or around a forced cell, so that both answers occur.
            let c = if probe % 2 == 0 {
                let (fd, fc) = forced[probe % forced.len()];
                if depth >= fd {
                    (fc << (depth - fd))
                        + (cell_at(depth - fd) & UVec3::splat((1 << (depth - fd)) - 1))
                } else {
                    fc >> (fd - depth)
                }
            } else {
                cell_at(depth)
            };
            let want = forced
                .iter()
                .any(|&(d, f)| overlap(range(d, f), range(depth, c)));
            assert_eq!(set.overlaps(depth, c), want, "cell {c} at depth {depth}");
            hits += want as u32;
        }
    }
    assert!(hits > 1000 && hits < 3000, "{hits} of 3600 probes overlap");
}

/// Whether the leaf of `view` that holds `p` is a solid surface leaf.
fn solid_at(view: &ProxyView<'_>, p: [f32; 3]) -> bool {
    view.locate_leaf(Vec3::from_array(p))
        .is_some_and(|l| l.kind == LeafKind::Surface && l.two_sided)
}

#[test]
fn leaves_near_two_sheets_are_solid_and_near_one_are_not() {
    use crate::scenes;
    let params = BuildParams {
        dmax: 6,
        ..BuildParams::default()
    };
    let one = scenes::flat_sheet([0.0; 3], 2.0, 4);
    let bake_parts = |parts: &[scenes::Mesh]| {
        let refs: Vec<MeshRef<'_>> = parts.iter().map(MeshRef::from).collect();
        bake(&refs, &params, &()).unwrap().0
    };
    // One sheet: solid only along its rim.
    let words = bake_parts(std::slice::from_ref(&one));
    let view = ProxyView::new(&words).unwrap();
    let leaf = view.finest_leaf_size();
    assert!(!solid_at(&view, [0.3, 0.0, 0.2]));
    assert!(solid_at(&view, [1.0, 0.0, 0.2]));
    // A second sheet above it, closer than a leaf: in front of the one and behind the other
    // between them, so their leaves are solid; farther than two leaves, they are not.
    for (gap, solid) in [(0.6 * leaf, true), (1.5 * leaf, true), (3.5 * leaf, false)] {
        let above = scenes::flat_sheet([0.05, gap, 0.05], 1.6, 4);
        let words = bake_parts(&[one.clone(), above]);
        let view = ProxyView::new(&words).unwrap();
        assert_eq!(solid_at(&view, [0.3, 0.0, 0.2]), solid, "gap {gap}");
        assert_eq!(solid_at(&view, [0.3, gap, 0.2]), solid, "gap {gap}");
    }
    // Two sheets through one line, sharing its vertices (an edge of four triangles): two
    // sheets, solid along the line.
    let crossing = scenes::rotated(&one, 60.0, 0.0);
    let words = bake_parts(&[one.clone(), crossing]);
    let view = ProxyView::new(&words).unwrap();
    for z in [-0.7, -0.2, 0.4] {
        assert!(solid_at(&view, [0.2 * leaf, 0.3 * leaf, z]));
        assert!(solid_at(&view, [-0.4 * leaf, -0.2 * leaf, z]));
    }
}

#[test]
fn solid_leaves_store_how_deep_each_face_is_clear_of_triangles() {
    // A plate thinner than a leaf: its leaves are solid, and from their top and bottom faces
    // each is clear down (up) to the plate, less at most a step and the margin; the sides,
    // which the plate crosses, have none.
    let (lo, hi) = (-0.013f32, -0.009f32);
    let (p, t) = cube([-0.9, lo, -0.9], [0.9, hi, 0.9]);
    let (words, report) = bake_one(
        &p,
        &t,
        &BuildParams {
            dmax: 5,
            ..BuildParams::default()
        },
    );
    assert!(report.two_sided_leaves > 0);
    let view = ProxyView::new(&words).unwrap();
    let mut clear = 0;
    for x in [-0.5f32, 0.0, 0.4] {
        let leaf = view
            .locate_leaf(Vec3::new(x, 0.5 * (lo + hi), 0.2))
            .unwrap();
        assert!(leaf.two_sided, "{leaf:?}");
        let rec = view.nodes()[leaf.node as usize];
        let (bmin, bmax) = (leaf.aabb.min.y as f64, leaf.aabb.max.y as f64);
        let edge = bmax - bmin;
        // From each face to the nearest point of the plate in the leaf.
        for (face, near) in [
            (2, (lo as f64).max(bmin) - bmin),
            (3, bmax - (hi as f64).min(bmax)),
        ] {
            let steps = rec.clearance(face);
            let depth = f64::from(steps) / 32.0 * edge;
            assert!(
                depth < near || (steps == 0 && near == 0.0),
                "face {face}: {steps} steps, {depth} deep, plate at {near}"
            );
            assert!(
                depth > near - 1.1 * edge / 32.0,
                "face {face}: {steps} steps, plate at {near}"
            );
            clear += (steps > 0) as u32;
        }
        for face in [0, 1, 4, 5] {
            assert_eq!(rec.clearance(face), 0, "face {face}");
        }
        assert_eq!(leaf.plane_offset, 0.0);
    }
    assert!(clear >= 3, "{clear} faces with clearance");
}

#[test]
fn a_clearance_never_reaches_the_surface_where_f32_planes_round() {
    // At the origin a clearance is the whole steps below the distance; at 2e5 from it, where
    // half an ulp is an eighth of a 6 cm leaf, it is lowered until the step's f32 inner plane
    // falls short of the surface; where the plane cannot leave the face, none.
    for (lo, edge) in [
        (0.0f64, 0.0625f64),
        (2e5, 0.0625),
        (-2e5, 0.0625),
        (2e5, 0.004),
    ] {
        let (lo32, hi32) = (lo as f32, (lo + edge) as f32);
        let (lo, hi) = (lo32 as f64, hi32 as f64);
        for upper in [false, true] {
            for frac in [0.02, 0.3, 0.5, 0.77, 1.0] {
                let near = frac * (hi - lo);
                let c = flat::clearance_steps(near, lo, hi, upper);
                if c == 0 {
                    continue;
                }
                let depth = (hi32 - lo32) * (c as f32 / 32.0);
                let reach = if upper {
                    hi - f64::from(hi32 - depth)
                } else {
                    f64::from(lo32 + depth) - lo
                };
                assert!(
                    reach > 0.0 && reach < near,
                    "{lo} {edge} {upper} {frac}: {c} reaches {reach}"
                );
            }
        }
    }
    assert_eq!(flat::clearance_steps(0.5 * 0.0625, 0.0, 0.0625, false), 15);
    assert_eq!(flat::clearance_steps(0.0, 0.0, 0.0625, true), 0);
}

/// Scenes whose first pass leaves coarse leaves solid: thin parts through each other, a sheet
/// soup, a sphere through a plate.
fn several_pass_scenes() -> [crate::io::Mesh; 3] {
    use crate::scenes::{merge, slab, triangle_soup, uv_sphere};
    [
        merge(&[
            slab([0.0; 3], [1.0, 0.02, 1.0]),
            slab([0.0; 3], [0.02, 1.0, 1.0]),
            slab([0.1, 0.0, 0.0], [0.02, 1.0, 0.7]),
        ]),
        triangle_soup(60, 5),
        merge(&[
            uv_sphere([0.0; 3], 0.5, 24, 12),
            slab([0.0; 3], [1.4, 0.03, 0.3]),
        ]),
    ]
}

#[test]
fn the_last_pass_leaves_no_solid_leaf_coarser_than_dmax() {
    // Thin parts through each other, a sheet soup and a sphere at a coarse dmin: scenes whose
    // first pass leaves coarse leaves solid. With one pass before the last, the last refines
    // every surface leaf to dmax; with all of them, the same holds.
    let scenes = several_pass_scenes();
    let params = BuildParams {
        dmin: 2,
        dmax: 7,
        ..BuildParams::default()
    };
    let mut reached_last_pass = 0;
    for (i, mesh) in scenes.iter().enumerate() {
        for max_passes in [1, MAX_PASSES] {
            let refs = [MeshRef::from(mesh)];
            let (words, report) = bake_in_passes(&refs, &params, &(), max_passes).unwrap();
            let view = ProxyView::new(&words).unwrap();
            assert_eq!(
                report.coarse_solid_leaves, 0,
                "scene {i}, {max_passes} passes"
            );
            assert!(report.passes <= max_passes + 1);
            if report.passes == max_passes + 1 {
                reached_last_pass += 1;
                // Every surface leaf at dmax: the last pass stopped at nothing else.
                let (lo, hi) = (view.root_aabb().min, view.root_aabb().max);
                let leaf = view.finest_leaf_size();
                let n = ((hi.x - lo.x) / leaf).round() as u32;
                for c in 0..n * n * n {
                    let p = lo
                        + (Vec3::new((c % n) as f32, (c / n % n) as f32, (c / n / n) as f32) + 0.5)
                            * leaf;
                    let l = view.locate_leaf(p).unwrap();
                    assert!(l.kind == LeafKind::Empty || l.depth == params.dmax);
                }
            }
        }
    }
    assert!(
        reached_last_pass > 0,
        "no scene needed more than one pass: the last pass went untested"
    );
}

#[test]
fn passes_that_reuse_what_the_last_found_give_the_same_bytes() {
    // Scenes that take several passes (parts through each other, a soup, a sphere through a
    // plate, a shared mesh): a later pass reuses subtrees, normals, votes and crowding of the
    // leaves the last pass found, and must give the proxy that finding everything again gives.
    let mut scenes = several_pass_scenes().to_vec();
    let shared =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/meshes/suzanne.obj.gz");
    match crate::io::load_mesh(&shared) {
        Ok((mesh, _)) => scenes.push(mesh),
        Err(_) if std::env::var("CI").as_deref() != Ok("true") => {
            eprintln!("skipped suzanne: {} not found", shared.display())
        }
        Err(e) => panic!("{}: {e}", shared.display()),
    }
    let mut several = 0;
    for (i, mesh) in scenes.iter().enumerate() {
        for (dmin, dmax) in [(2, 7), (4, 8)] {
            let params = BuildParams {
                dmin,
                dmax,
                ..BuildParams::default()
            };
            let refs = [MeshRef::from(mesh)];
            let (a, ra) = bake_reusing(&refs, &params, &(), MAX_PASSES, true).unwrap();
            let (b, rb) = bake_reusing(&refs, &params, &(), MAX_PASSES, false).unwrap();
            assert_eq!(ra.passes, rb.passes, "scene {i}, dmax {dmax}");
            assert!(a == b, "scene {i}, dmax {dmax}: the proxies differ");
            several += (ra.passes > 1) as u32;
        }
    }
    assert!(several >= 3, "only {several} bakes took more than one pass");
}

/// Offset surfaces with hollows in their band (each thick part leaves one, so `matter_of`
/// has closed parts to take), and one of overlapping parts whose offset merges them: baked
/// without the winding numbers of the "in matter" rule (`Regions::OneBand`, as
/// `bake_offset` does) they give the bytes of the bake that asks them, for the reason
/// `Regions::OneBand` gives.
#[test]
fn an_offset_bake_skips_only_what_cannot_apply() {
    use crate::scenes::{merge, slab, uv_sphere};
    let scenes = [
        // A tray: a floor and four walls overlapping at the corners.
        (
            vec![
                slab([0.0, -0.2, 0.0], [3.0, 0.4, 3.0]),
                slab([1.35, 0.4, 0.0], [0.3, 0.8, 3.0]),
                slab([-1.35, 0.4, 0.0], [0.3, 0.8, 3.0]),
                slab([0.0, 0.4, 1.35], [3.0, 0.8, 0.3]),
                slab([0.0, 0.4, -1.35], [3.0, 0.8, 0.3]),
            ],
            6,
            0.1,
        ),
        // A thick plate through a ball, and a thin fin through both.
        (
            vec![merge(&[
                uv_sphere([0.0; 3], 0.5, 24, 12),
                slab([0.0; 3], [1.4, 0.3, 0.6]),
                slab([0.1, 0.0, 0.0], [0.01, 1.2, 0.5]),
            ])],
            6,
            0.05,
        ),
    ];
    for (i, (meshes, dmax, radius)) in scenes.iter().enumerate() {
        let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
        let surface = offset::OffsetSurface::new(&refs, *radius, *dmax, &()).unwrap();
        let band = [surface.mesh_ref()];
        let tris = gather(&band, &mut BuildReport::default()).unwrap();
        assert!(
            matter_of(&tris).is_some(),
            "scene {i}: no hollow in the band"
        );
        let params = BuildParams {
            dmax: *dmax,
            ..BuildParams::default()
        };
        let (a, _) = bake_regions(&band, &params, &(), MAX_PASSES, true, Regions::OneBand).unwrap();
        let (b, _) = bake_regions(&band, &params, &(), MAX_PASSES, true, Regions::Parts).unwrap();
        assert!(a == b, "scene {i}: the proxies differ");
    }
}
