//! Unit tests of core: the normal encoding, exact planes, record accessors, validation of
//! hand-made buffers, the collision response and leaf hints.

use glam::Vec3;

use crate::format::*;
use crate::*;

/// The next value of a xorshift generator: the tests' reproducible randomness.
pub(crate) fn xorshift(s: &mut u64) -> u64 {
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    *s
}

#[test]
fn normal_encoding_round_trips_within_three_hundredths_of_a_degree() {
    let mut s = 12345u64;
    let mut r = || (xorshift(&mut s) >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0;
    let mut worst = 0.0f32;
    for _ in 0..20000 {
        let n = Vec3::new(r(), r(), r());
        if n.length() < 1e-3 {
            continue;
        }
        let n = n.normalize();
        let d = decode_normal(encode_normal(n));
        assert!((d.length() - 1.0).abs() < 1e-5);
        worst = worst.max(n.angle_between(d).to_degrees());
    }
    // 15-bit octahedral components: the measured worst case is 0.028°, near the folds.
    assert!(worst < 0.03, "worst error {worst}°");
    // Axes and their negatives are exact.
    for a in [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z] {
        assert_eq!(decode_normal(encode_normal(a)), a);
    }
}

#[test]
fn grid_planes_are_exact_for_quantised_sizes() {
    for size in [1.0f32, 2.2, 3.7e-3, 495.3, 1.0e6] {
        let q = quantize_root_size(size);
        assert!(q >= size && q < size * 1.02, "{size} → {q}");
        assert_eq!(quantize_root_size(q), q);
        let unit = q * (1.0 / (1u32 << MAX_DEPTH) as f32);
        for i in [0u32, 1, 3, 12345, 65535, 65536] {
            // The product is exact: f64 agrees.
            assert_eq!((i as f32 * unit) as f64, i as f64 * unit as f64);
        }
    }
}

#[test]
fn record_accessors() {
    let r = NodeRecord::internal(
        42,
        0b1010_0110,
        0b0010_0100,
        (1 << 0) | (2 << 2) | (1 << 14),
    );
    assert!(!r.is_leaf());
    assert_eq!(r.first_child(), 42);
    assert_eq!(r.child_mask(), 0b1010_0110);
    assert_eq!(r.internal_mask(), 0b0010_0100);
    assert_eq!(r.label_bits(0), 1);
    assert_eq!(r.label_bits(1), 2);
    assert_eq!(r.label_bits(7), 1);
    // Children with records: octants 1, 2, 5, 7 at 42, 43, 44, 45.
    assert_eq!(r.child_index(1), 42);
    assert_eq!(r.child_index(2), 43);
    assert_eq!(r.child_index(5), 44);
    assert_eq!(r.child_index(7), 45);
    let leaf = NodeRecord::surface(encode_normal(Vec3::Y), -0.25);
    assert!(leaf.is_leaf() && !leaf.is_two_sided());
    assert_eq!(leaf.normal(), Vec3::Y);
    assert_eq!(leaf.plane_offset(), -0.25);
    // A solid leaf's second word holds its faces' clearances, 5 bits each, cut to 31.
    let solid = NodeRecord::solid(encode_normal(-Vec3::X), [0, 1, 7, 31, 40, 16]);
    assert!(solid.is_leaf() && solid.is_two_sided());
    assert_eq!(solid.normal(), -Vec3::X);
    assert_eq!(solid.plane_offset(), 0.0);
    let clearances: Vec<u32> = (0..6).map(|k| solid.clearance(k)).collect();
    assert_eq!(clearances, [0, 1, 7, 31, 31, 16]);
    assert_eq!(solid.b >> 30, 0);
    assert_eq!(lut_entry(7, 3) & LUT_INDEX_MASK, 7);
    assert_eq!(lut_entry(7, 3) >> LUT_DEPTH_SHIFT, 3);
}

/// The smallest valid proxy: a root with one surface-leaf child at octant 0.
pub(crate) fn tiny() -> [u32; HEADER_WORDS + 4] {
    let mut w = [0u32; HEADER_WORDS + 4];
    w[header::MAGIC] = MAGIC;
    w[header::VERSION] = FORMAT_VERSION;
    w[header::HEADER_WORDS] = HEADER_WORDS as u32;
    w[header::TOTAL_WORDS] = (HEADER_WORDS + 4) as u32;
    w[header::NODE_COUNT] = 2;
    w[header::NODES_OFFSET] = HEADER_WORDS as u32;
    w[header::LUT_OFFSET] = (HEADER_WORDS + 4) as u32;
    w[header::TREE_DEPTH] = 1;
    w[header::DMAX] = 1;
    w[header::ROOT_SIZE] = 1.0f32.to_bits();
    let root = NodeRecord::internal(1, 1, 0, 0);
    let leaf = NodeRecord::surface(encode_normal(Vec3::Y), 0.0);
    w[HEADER_WORDS..].copy_from_slice(&[root.a, root.b, leaf.a, leaf.b]);
    crate::format::seal(&mut w);
    w
}

#[test]
fn cell_boxes_are_the_grid_planes_at_every_depth() {
    // The settled step computes a cell's box in vector operations; it must be the very floats
    // of the planes that the march and the descent compare against, for any valid root.
    let mut s = 99u64;
    let mut r = || xorshift(&mut s) >> 16;
    let roots = [
        ([0.0f32; 3], 1.0f32),
        ([-3.25, 17.0, -0.001], 2.2),
        ([1.0e5, -7.5e4, 3.0], 495.3),
        ([-1.0e-3, 2.0e-3, 5.0e-4], 3.7e-3),
    ];
    for (min, size) in roots {
        let mut w = tiny();
        for a in 0..3 {
            w[header::ROOT_MIN + a] = min[a].to_bits();
        }
        w[header::ROOT_SIZE] = quantize_root_size(size).to_bits();
        crate::format::seal(&mut w);
        let view = ProxyView::new(&w).unwrap();
        for depth in 1..=MAX_DEPTH {
            let n = 1u64 << depth;
            for k in 0..64u64 {
                // The corners of the grid, then random cells.
                let c = if k < 8 {
                    [k & 1, k >> 1 & 1, k >> 2].map(|b| b * (n - 1))
                } else {
                    [r() % n, r() % n, r() % n]
                };
                let cell = glam::UVec3::new(c[0] as u32, c[1] as u32, c[2] as u32);
                let b = view.cell_aabb(cell, depth);
                let sh = MAX_DEPTH - depth;
                for a in 0..3 {
                    assert_eq!(
                        b.min[a].to_bits(),
                        view.plane(a, cell[a] << sh).to_bits(),
                        "{min:?} {size} {depth} {cell}"
                    );
                    assert_eq!(
                        b.max[a].to_bits(),
                        view.plane(a, (cell[a] + 1) << sh).to_bits(),
                        "{min:?} {size} {depth} {cell}"
                    );
                }
            }
        }
    }
}

#[test]
fn validation_of_hand_made_buffers() {
    let w = tiny();
    let view = ProxyView::new(&w).expect("the tiny proxy is valid");
    assert_eq!(
        view.locate_leaf(Vec3::splat(0.25)).unwrap().kind,
        LeafKind::Surface
    );
    assert_eq!(
        view.locate_leaf(Vec3::splat(0.75)).unwrap().kind,
        LeafKind::Empty
    );
    assert!(view.locate_leaf(Vec3::splat(1.5)).is_none());
    let bad = |f: &dyn Fn(&mut [u32; HEADER_WORDS + 4])| {
        let mut w = tiny();
        f(&mut w);
        ProxyView::new(&w).unwrap_err()
    };
    assert_eq!(bad(&|w| w[0] = 0), FormatError::BadMagic { found: 0 });
    assert_eq!(
        bad(&|w| w[1] = 1),
        FormatError::UnsupportedVersion { found: 1 }
    );
    assert!(matches!(
        bad(&|w| w[header::ROOT_SIZE] = f32::NAN.to_bits()),
        FormatError::BadRootBox
    ));
    assert!(matches!(
        bad(&|w| w[header::ROOT_SIZE] = 1.1f32.to_bits()),
        FormatError::BadRootBox
    ));
    // Child pointer not where breadth-first order puts it.
    assert!(matches!(
        bad(&|w| w[HEADER_WORDS] = 0),
        FormatError::ChildOutOfRange { .. }
    ));
    // A label on a child that has a record.
    assert!(matches!(
        bad(&|w| w[HEADER_WORDS + 1] |= 1 << LABEL_SHIFT),
        FormatError::BadNode { .. }
    ));
    // Kind mask says internal, the record is a leaf.
    assert!(matches!(
        bad(&|w| w[HEADER_WORDS + 1] |= 1 << INTERNAL_MASK_SHIFT),
        FormatError::BadNode { .. }
    ));
    // Plane offset outside the leaf.
    assert!(matches!(
        bad(&|w| w[HEADER_WORDS + 3] = 5.0f32.to_bits()),
        FormatError::BadNode { .. }
    ));
    // Root a leaf.
    assert_eq!(
        bad(&|w| w[HEADER_WORDS] = LEAF_BIT),
        FormatError::RootIsLeaf
    );
    // Header counts that disagree with the length.
    assert!(matches!(
        bad(&|w| w[header::NODE_COUNT] = 3),
        FormatError::BadHeader { .. }
    ));
    // Byte entry: misaligned lengths are an error.
    let bytes: &[u8] = bytemuck::cast_slice(&w);
    assert!(ProxyView::from_bytes(bytes).is_ok());
    assert_eq!(
        ProxyView::from_bytes(&bytes[..bytes.len() - 1]).unwrap_err(),
        FormatError::Misaligned {
            len: bytes.len() - 1
        }
    );
}

#[test]
fn response_restitution_and_friction() {
    let n = Vec3::Y;
    let v = Vec3::new(3.0, -2.0, 0.0);
    // Elastic, frictionless: a mirror.
    assert_eq!(respond(v, n, 1.0, 0.0), Vec3::new(3.0, 2.0, 0.0));
    // Perfectly inelastic: the normal part goes; friction 0.5 takes 0.5 × 2 off the tangent.
    // (One rounding in `1 - impulse / |v_t|`: a few ulps.)
    assert!(respond(v, n, 0.0, 0.5).abs_diff_eq(Vec3::new(2.0, 0.0, 0.0), 1e-6));
    // Enough friction stops it.
    assert_eq!(respond(v, n, 0.0, 10.0), Vec3::ZERO);
    // Moving away: unchanged.
    assert_eq!(respond(-v, n, 0.5, 0.5), -v);
}

#[test]
fn the_leaf_bound_covers_a_straight_crossing() {
    for d in 1..=MAX_DEPTH {
        assert!(max_leaves_per_step(d) >= 3 * (1 << d));
    }
    assert_eq!(MAX_LEAVES_PER_STEP, max_leaves_per_step(MAX_DEPTH));
    let p = StepParams::default();
    assert!(p.validate().is_ok());
    assert!(StepParams { dt: f32::NAN, ..p }.validate().is_err());
    assert!(StepParams { dt: 0.0, ..p }.validate().is_err());
    assert!(StepParams {
        restitution: 1.5,
        ..p
    }
    .validate()
    .is_err());
    assert!(StepParams {
        friction: -1.0,
        ..p
    }
    .validate()
    .is_err());
    assert!(StepParams {
        gravity: [0.0, f32::INFINITY, 0.0],
        ..p
    }
    .validate()
    .is_err());
}

#[test]
fn leaf_hints_change_nothing_but_the_work() {
    let w = tiny();
    let view = ProxyView::new(&w).unwrap();
    let params = StepParams {
        gravity: [0.0; 3],
        ..StepParams::default()
    };
    let slow = Particle::new([0.75, 0.75, 0.75], [0.6, 0.0, 0.0]);
    // A step that ends in an empty leaf leaves it as the hint; one that ends in a one-sided
    // surface leaf leaves that leaf: its record (1), depth (1) and cell (0).
    let mut hint = LeafHint::NONE;
    let mut p = slow;
    step_particle_hinted(&view, &mut p, &params, &mut hint);
    assert_eq!(hint.xy, 1 | 1 << LeafHint::Y_SHIFT);
    assert_eq!(
        hint.z_depth_label,
        1 | 1 << LeafHint::DEPTH_SHIFT | LeafHint::VALID
    );
    let rising = Particle::new([0.25, 0.3, 0.25], [0.0, 0.6, 0.0]);
    let mut q = rising;
    let mut surface = hint;
    step_particle_hinted(&view, &mut q, &params, &mut surface);
    assert_eq!(
        surface,
        LeafHint {
            xy: 1 | 1 << LeafHint::RECORD_DEPTH_SHIFT,
            z_depth_label: LeafHint::SURFACE | LeafHint::VALID,
        },
        "the surface leaf is hinted"
    );
    // Every hint that is malformed, or whose leaf does not hold the particle, gives what no
    // hint gives; so does the right one.
    let (good_xy, good_z) = (hint.xy, hint.z_depth_label);
    let mut hints = vec![
        hint,
        LeafHint {
            xy: good_xy,
            z_depth_label: good_z & !LeafHint::VALID,
        },
        LeafHint {
            xy: good_xy,
            z_depth_label: good_z | 3 << LeafHint::LABEL_SHIFT,
        },
        LeafHint {
            xy: 2,
            z_depth_label: good_z,
        },
        LeafHint {
            xy: 0,
            z_depth_label: 1 << LeafHint::DEPTH_SHIFT | LeafHint::VALID,
        },
        LeafHint {
            xy: u32::MAX,
            z_depth_label: u32::MAX,
        },
    ];
    // The root is never a leaf.
    hints.push(LeafHint {
        xy: 0,
        z_depth_label: LeafHint::VALID,
    });
    for depth in 17..32 {
        hints.push(LeafHint {
            xy: 0,
            z_depth_label: depth << LeafHint::DEPTH_SHIFT | LeafHint::VALID,
        });
    }
    // Surface hints: the good one, and malformed ones (the root's record, which is internal;
    // a record beyond the proxy's; depth 0, 11 (deeper than a surface hint holds) and 2 (a
    // cell that does not hold the particle); a cell out of range).
    let (sxy, sz) = (surface.xy, surface.z_depth_label);
    let mut surface_hints = vec![surface, LeafHint::NONE, hint];
    for (xy, z) in [
        (1 << LeafHint::RECORD_DEPTH_SHIFT, sz),
        (2 | 1 << LeafHint::RECORD_DEPTH_SHIFT, sz),
        (
            LeafHint::RECORD_MASK | 1 << LeafHint::RECORD_DEPTH_SHIFT,
            sz,
        ),
        (1, sz),
        (1 | 11 << LeafHint::RECORD_DEPTH_SHIFT, sz),
        (1 | 2 << LeafHint::RECORD_DEPTH_SHIFT, sz),
        (sxy, sz | 2),
        (sxy, sz & !LeafHint::VALID),
    ] {
        surface_hints.push(LeafHint {
            xy,
            z_depth_label: z,
        });
    }
    hints.extend_from_slice(&surface_hints);
    // Starts in the empty leaves with every hint; starts in the surface leaf with the
    // surface hints (the made-up empty hint of its cell above is believed: see below).
    let cases = [
        (slow, &hints),
        (
            Particle::new([0.75, 0.75, 0.75], [-40.0, -40.0, -40.0]),
            &hints,
        ),
        (Particle::new([0.5, 0.75, 0.75], [1.0, 0.0, 0.0]), &hints),
        (rising, &surface_hints),
        (
            Particle::new([0.25, 0.26, 0.25], [0.0, -1.0, 0.0]),
            &surface_hints,
        ),
        (
            Particle::new([0.2, 0.3, 0.1], [3.0, -0.5, 1.0]),
            &surface_hints,
        ),
    ];
    for (start, hints) in cases {
        let mut expected = start;
        step_particle(&view, &mut expected, &params);
        for h in hints {
            let mut got = start;
            let mut h = *h;
            step_particle_hinted(&view, &mut got, &params, &mut h);
            assert_eq!(
                bytemuck::bytes_of(&got),
                bytemuck::bytes_of(&expected),
                "hint {h:?}"
            );
        }
    }
    // Unvalidated parameters (dt <= 0) take the march, which does not move the particle; so
    // does the hinted step.
    for dt in [0.0, -1.0 / 60.0] {
        let bad = StepParams { dt, ..params };
        let start = Particle::new([0.75, 0.75, 0.75], [0.6, 0.0, 0.0]);
        let mut expected = start;
        step_particle(&view, &mut expected, &bad);
        let (mut got, mut h) = (start, hint);
        step_particle_hinted(&view, &mut got, &bad, &mut h);
        assert_eq!(
            bytemuck::bytes_of(&got),
            bytemuck::bytes_of(&expected),
            "dt {dt}"
        );
    }
    // A hint is believed once it passes those checks: one made up by hand that calls the
    // surface leaf's cell empty hides the surface (so the test above did use the good hint).
    // A hair above the leaf's plane (`y = 0.25`), so it reaches it within the step.
    let falling = Particle::new([0.25, 0.26, 0.25], [0.0, -1.0, 0.0]);
    let mut plain = falling;
    step_particle(&view, &mut plain, &params);
    assert_eq!(plain.collisions(), 1);
    let (mut fooled, mut made_up) = (
        falling,
        LeafHint {
            xy: 0,
            z_depth_label: 1 << LeafHint::DEPTH_SHIFT | LeafHint::VALID,
        },
    );
    step_particle_hinted(&view, &mut fooled, &params, &mut made_up);
    assert_eq!(fooled.collisions(), 0);
}

#[test]
fn particles_leaving_the_root_step_as_the_march_steps_them() {
    let w = tiny();
    let view = ProxyView::new(&w).unwrap();
    let side = |p: [f32; 3], v: [f32; 3], s: u32, flags: u32| Particle {
        side: s,
        flags,
        ..Particle::new(p, v)
    };
    let mut starts = vec![
        // Beyond a face and moving away, or along it: settled without the march.
        side(
            [-0.5, 0.5, 0.5],
            [-1.0, 0.0, 0.0],
            SIDE_BACK,
            FLAG_BLOCKED | 3 << COLLISION_SHIFT,
        ),
        side([0.5, 1.5, 0.5], [0.0, 0.0, 2.0], 7, FLAG_BOUND_HIT),
        side(
            [0.5, 0.5, -2.0],
            [0.3, -0.2, -0.1],
            SIDE_FRONT,
            FLAG_INVALID,
        ),
        // Coming back, on the face itself (inside by the tie rule), or a corner away from one
        // face and toward another: the march.
        side([-0.5, 0.5, 0.5], [40.0, 0.0, 0.0], SIDE_FRONT, 0),
        side([1.0, 0.5, 0.5], [1.0, 0.0, 0.0], SIDE_FRONT, 0),
        side([0.0, 0.5, 0.5], [-1.0, 0.0, 0.0], SIDE_FRONT, 0),
        side([-0.5, -0.5, 0.5], [-1.0, 60.0, 0.0], SIDE_FRONT, 0),
        // Steps that overflow or carry NaN are invalid there and here.
        side([-0.5, 0.5, 0.5], [-3e38, 0.0, 0.0], SIDE_FRONT, 0),
        side([-0.5, 0.5, 0.5], [-1.0, f32::NAN, 0.0], SIDE_FRONT, 0),
        side([-f32::INFINITY, 0.5, 0.5], [-1.0, 0.0, 0.0], SIDE_FRONT, 0),
    ];
    starts.push(side([2.0, 2.0, 2.0], [1.0, 1.0, 1.0], SIDE_BACK, 0));
    // Coming toward the root and missing it (settled without the march), ending on its face,
    // passing a corner, or entering: rain above a scene. And strictly outside at random,
    // every way.
    starts.extend([
        side([0.5, 3.0, 0.5], [0.0, -60.0, 0.0], SIDE_FRONT, 0),
        side([0.5, 1.5, 0.5], [0.0, -30.0, 0.0], SIDE_FRONT, 0),
        side([-0.5, 1.6, 0.5], [60.0, -30.0, 0.0], SIDE_BACK, 0),
        side([-0.5, 1.2, 0.5], [60.0, -60.0, 0.0], SIDE_FRONT, 0),
        side([1.5, 1.5, 1.5], [-30.0, -30.0, -30.0], SIDE_FRONT, 0),
        // Ending a hair beyond the face, within the margin and beyond it.
        side([0.5, 1.5, 0.5], [0.0, -29.999_98, 0.0], SIDE_FRONT, 0),
        side([0.5, 1.5, 0.5], [0.0, -29.99, 0.0], SIDE_FRONT, 0),
        side([0.5, 1.5, 0.5], [0.0, -29.9, 0.0], SIDE_FRONT, 0),
        side([0.5, 1e6, 0.5], [0.0, -6e7 + 61.0, 0.0], SIDE_FRONT, 0),
    ]);
    let mut seed = 77u64;
    let mut r = |lo: f32, hi: f32| {
        lo + (hi - lo) * ((xorshift(&mut seed) >> 40) as f32 / (1u64 << 24) as f32)
    };
    for _ in 0..400 {
        let x = [r(-1.0, 2.0), r(-1.0, 2.0), r(-1.0, 2.0)];
        let v = [r(-90.0, 90.0), r(-90.0, 90.0), r(-90.0, 90.0)];
        starts.push(side(x, v, SIDE_FRONT, 0));
    }
    for params in [
        StepParams {
            gravity: [0.0; 3],
            ..StepParams::default()
        },
        StepParams::default(),
        StepParams {
            gravity: [0.0, 1e38, 0.0],
            ..StepParams::default()
        },
        // Unvalidated: the march does not move a particle for dt <= 0, nor does this.
        StepParams {
            dt: 0.0,
            ..StepParams::default()
        },
        StepParams {
            dt: -1.0,
            ..StepParams::default()
        },
    ] {
        for start in &starts {
            let mut expected = *start;
            let want = step_particle(&view, &mut expected, &params);
            let (mut got, mut hint) = (*start, LeafHint::NONE);
            let outcome = step_particle_hinted(&view, &mut got, &params, &mut hint);
            assert_eq!(outcome, want, "{start:?} {params:?}");
            assert_eq!(
                bytemuck::bytes_of(&got),
                bytemuck::bytes_of(&expected),
                "{start:?} {params:?}"
            );
            if !view.root_contains(
                Vec3::from_array(got.position),
                Vec3::from_array(got.velocity),
            ) {
                assert_eq!(hint, LeafHint::NONE);
            }
        }
    }
}

/// A root of depth 1 with two surface leaves stacked in `y` that face each other: octant 0
/// (lower) with normal `+y`, octant 2 (upper) with normal `-y`. Their shared face is a gap
/// of no width, the limit of any gap thinner than a leaf between two facing surfaces.
fn facing_leaves() -> [u32; HEADER_WORDS + 6] {
    let mut w = [0u32; HEADER_WORDS + 6];
    w[..HEADER_WORDS].copy_from_slice(&tiny()[..HEADER_WORDS]);
    w[header::TOTAL_WORDS] = (HEADER_WORDS + 6) as u32;
    w[header::NODE_COUNT] = 3;
    w[header::LUT_OFFSET] = (HEADER_WORDS + 6) as u32;
    let root = NodeRecord::internal(1, 0b101, 0, 0);
    // Both planes on the shared face (`y = 0.5`: a quarter along each normal from the centre).
    let below = NodeRecord::surface(encode_normal(Vec3::Y), 0.25);
    let above = NodeRecord::surface(encode_normal(-Vec3::Y), 0.25);
    w[HEADER_WORDS..].copy_from_slice(&[root.a, root.b, below.a, below.b, above.a, above.b]);
    crate::format::seal(&mut w);
    w
}

#[test]
fn a_particle_pinched_between_facing_surfaces_slides_instead_of_bouncing_to_the_bound() {
    let w = facing_leaves();
    let view = ProxyView::new(&w).unwrap();
    let params = StepParams {
        gravity: [0.0; 3],
        restitution: 0.5,
        friction: 0.0,
        ..StepParams::default()
    };
    // On the shared face, moving down into the lower leaf. Reflecting off one surface sends it
    // into the other; each reflection halves the speed across them, so without the pinch rule
    // it bounced some 300 times at this point until the leaf bound (72 at depth 1) stopped it.
    let mut p = Particle::new([0.2, 0.5, 0.25], [1.0, -3.0, 0.0]);
    let outcome = step_particle(&view, &mut p, &params);
    assert_eq!(outcome, StepOutcome::Done);
    assert_eq!(p.flags & FLAG_BOUND_HIT, 0);
    assert_eq!(
        p.collisions(),
        2,
        "one reflection off each surface, then the pinch"
    );
    // It keeps the part of its velocity along both surfaces, and slides along the face.
    assert_eq!(p.velocity, [1.0, 0.0, 0.0]);
    assert_eq!(p.position[1], 0.5);
    assert!(p.position[0] > 0.2);
    // The pinch itself: facing normals keep the common plane's part; meeting ones the crease's.
    assert_eq!(
        pinch(Vec3::new(1.0, -0.75, 2.0), -Vec3::Y, Vec3::Y),
        Vec3::new(1.0, 0.0, 2.0)
    );
    let crease = pinch(Vec3::new(0.5, -1.0, 3.0), Vec3::X, Vec3::Y);
    assert_eq!(crease, Vec3::new(0.0, 0.0, 3.0));
}

#[test]
fn counted_and_traced_steps_are_the_step() {
    // The pinch of the test above, stepped three ways: the same bits, and the counted step saw
    // the pinch and the end on the shared face it slides along (nothing else rare); the traced
    // one's pieces join up from start to end.
    let w = facing_leaves();
    let view = ProxyView::new(&w).unwrap();
    let params = StepParams {
        gravity: [0.0; 3],
        restitution: 0.5,
        friction: 0.0,
        ..StepParams::default()
    };
    let start = Particle::new([0.2, 0.5, 0.25], [1.0, -3.0, 0.0]);
    let (mut plain, mut counted, mut traced) = (start, start, start);
    let outcome = step_particle(&view, &mut plain, &params);
    let mut counts = MarchCounts::default();
    assert_eq!(
        step_particle_counted(&view, &mut counted, &params, &mut counts),
        outcome
    );
    let mut pieces = Vec::new();
    assert_eq!(
        step_particle_traced(&view, &mut traced, &params, &mut |a, b| pieces.push((a, b))),
        outcome
    );
    for p in [counted, traced] {
        assert_eq!(bytemuck::bytes_of(&p), bytemuck::bytes_of(&plain));
    }
    for b in MarchBranch::ALL {
        let expected = u64::from(b == MarchBranch::Pinch || b == MarchBranch::EndOnFace);
        assert_eq!(counts[b], expected, "{b:?}");
    }
    assert_eq!(pieces.first().unwrap().0, Vec3::from_array(start.position));
    assert_eq!(pieces.last().unwrap().1, Vec3::from_array(plain.position));
    assert!(pieces.windows(2).all(|w| w[0].1 == w[1].0));
}

/// A root of depth 1 whose octant 0 (`[0, 0.5]³`) is a solid leaf, the others empty leaves
/// labelled front: a cage and the leaves around it.
fn solid_corner() -> [u32; HEADER_WORDS + 4] {
    let mut w = tiny();
    let labels = (1..8).fold(0u16, |l, o| l | (Label::Front.bits() as u16) << (2 * o));
    let root = NodeRecord::internal(1, 1, 0, labels);
    let leaf = NodeRecord::solid(encode_normal(Vec3::Y), [0; 6]);
    w[HEADER_WORDS..].copy_from_slice(&[root.a, root.b, leaf.a, leaf.b]);
    crate::format::seal(&mut w);
    w
}

#[test]
fn a_caged_particle_leaves_its_cage_only_through_its_exits() {
    let w = solid_corner();
    let view = ProxyView::new(&w).unwrap();
    let cage = view.locate_leaf(Vec3::splat(0.25)).unwrap();
    assert!(cage.two_sided && cage.aabb.max == Vec3::splat(0.5));
    let elastic = StepParams {
        gravity: [0.0; 3],
        restitution: 1.0,
        friction: 0.0,
        ..StepParams::default()
    };
    let strictly_in = |p: &Particle| {
        let x = Vec3::from_array(p.position);
        x.cmpgt(cage.aabb.min).all() && x.cmplt(cage.aabb.max).all()
    };

    // No exit: it bounces off every face, and ends every step strictly inside, still caged.
    let mut p = Particle::new([0.25, 0.2, 0.1], [3.0, 2.0, 1.0]);
    p.side = SIDE_BACK | SIDE_CAGED;
    let mut counts = MarchCounts::default();
    for _ in 0..200 {
        let mut pieces = Vec::new();
        step_particle_traced(&view, &mut p, &elastic, &mut |a, b| pieces.push((a, b)));
        let mut again = p;
        step_particle_counted(&view, &mut again, &elastic, &mut counts);
        for (_, b) in pieces {
            assert!(
                b.cmpge(cage.aabb.min).all() && b.cmple(cage.aabb.max).all(),
                "left at {b}"
            );
        }
        assert!(strictly_in(&p), "{p:?}");
        assert_eq!(p.side, SIDE_BACK | SIDE_CAGED);
    }
    assert!(counts[MarchBranch::CageWall] > 20);
    assert_eq!(counts[MarchBranch::CageExit], 0);
    assert!(p.collisions() > 20);

    // One exit, the +x face: it leaves through it, into octant 1, and the label stamps it.
    let mut p = Particle::new([0.25, 0.2, 0.1], [1.0, 3.0, 0.5]);
    p.side = SIDE_BACK | SIDE_CAGED | side_exit(0, true);
    let mut left_at = None;
    for step in 0..200 {
        let mut pieces = Vec::new();
        step_particle_traced(&view, &mut p, &elastic, &mut |a, b| pieces.push((a, b)));
        if left_at.is_none() && !p.is_caged() {
            left_at = Some(step);
            let out = pieces
                .iter()
                .map(|&(_, b)| b)
                .find(|b| b.x == 0.5)
                .expect("left through x = 0.5");
            assert!(out.y > 0.0 && out.y < 0.5 && out.z > 0.0 && out.z < 0.5);
            assert_eq!(p.side, SIDE_FRONT, "stamped by the empty leaf");
        }
        if left_at.is_none() {
            assert!(strictly_in(&p));
        }
    }
    assert!(left_at.is_some(), "never left by its exit");

    // At rest under gravity on the cage's floor (the root's face): on the face, moved to the
    // next float inside, so that the next step finds the cage.
    let mut p = Particle::new([0.25, 0.001, 0.1], [0.0; 3]);
    p.side = SIDE_FRONT | SIDE_CAGED;
    let resting = StepParams {
        restitution: 0.0,
        ..StepParams::default()
    };
    let mut counts = MarchCounts::default();
    for _ in 0..30 {
        step_particle_counted(&view, &mut p, &resting, &mut counts);
        assert!(strictly_in(&p) && p.is_caged(), "{p:?}");
    }
    assert_eq!(p.position[1], f32::MIN_POSITIVE);
    assert!(counts[MarchBranch::CageNudge] > 0);

    // Cage bits on a particle that is not in a solid leaf: dropped, the step as for any other.
    let mut p = Particle::new([0.75, 0.25, 0.25], [1.0, 0.0, 0.0]);
    p.side = SIDE_BACK | SIDE_CAGED | SIDE_EXITS_MASK;
    let mut plain = p;
    plain.side = SIDE_BACK;
    let mut counts = MarchCounts::default();
    step_particle_counted(&view, &mut p, &elastic, &mut counts);
    step_particle(&view, &mut plain, &elastic);
    assert_eq!(counts[MarchBranch::CageLost], 1);
    assert_eq!(bytemuck::bytes_of(&p), bytemuck::bytes_of(&plain));
    assert_eq!(p.side, SIDE_FRONT);
}

/// [`solid_corner`] with two more surface leaves: octant 3 (`x` and `y` upper, across an edge
/// of the cage) and octant 4 (`z` upper, across its `+z` face), one-sided, normal `+y`.
fn solid_corner_beside_surfaces() -> [u32; HEADER_WORDS + 8] {
    let mut w = [0u32; HEADER_WORDS + 8];
    w[..HEADER_WORDS].copy_from_slice(&tiny()[..HEADER_WORDS]);
    w[header::TOTAL_WORDS] = (HEADER_WORDS + 8) as u32;
    w[header::NODE_COUNT] = 4;
    w[header::LUT_OFFSET] = (HEADER_WORDS + 8) as u32;
    let labels = [1, 2, 5, 6, 7]
        .iter()
        .fold(0u16, |l, o| l | (Label::Front.bits() as u16) << (2 * o));
    let root = NodeRecord::internal(1, 0b0001_1001, 0, labels);
    let cage = NodeRecord::solid(encode_normal(Vec3::Y), [0; 6]);
    let surface = NodeRecord::surface(encode_normal(Vec3::Y), 0.0);
    w[HEADER_WORDS..].copy_from_slice(&[
        root.a, root.b, cage.a, cage.b, surface.a, surface.b, surface.a, surface.b,
    ]);
    crate::format::seal(&mut w);
    w
}

#[test]
fn a_caged_particle_leaves_by_its_exit_face_and_never_by_an_edge_or_a_stale_exit() {
    let w = solid_corner_beside_surfaces();
    let view = ProxyView::new(&w).unwrap();
    let sliding = StepParams {
        gravity: [0.0; 3],
        restitution: 0.0,
        friction: 0.0,
        ..StepParams::default()
    };
    // Up into the +y wall (no bounce: its velocity across it is +0), along it to the +x exit,
    // out on the cage's edge at y = 0.5. The leaf beyond the face is octant 1, empty, which
    // stamps front; by the tie rule for +0 the point was in octant 3, a surface leaf, where the
    // particle kept its side.
    let mut p = Particle::new([0.2, 0.45, 0.25], [24.0, 12.0, 0.0]);
    p.side = SIDE_BACK | SIDE_CAGED | side_exit(0, true);
    let mut counts = MarchCounts::default();
    step_particle_counted(&view, &mut p, &sliding, &mut counts);
    assert_eq!(counts[MarchBranch::CageWall], 1);
    assert_eq!(counts[MarchBranch::CageExit], 1);
    assert!(!p.is_caged());
    assert_eq!(
        p.side, SIDE_FRONT,
        "stamped by the leaf across the face: {p:?}"
    );
    assert!(p.position[0] > 0.55 && p.position[1] < 0.5, "{p:?}");

    // A stale exit (+z: octant 4 is a surface leaf, not empty) is a wall.
    let elastic = StepParams {
        restitution: 1.0,
        ..sliding
    };
    let mut p = Particle::new([0.25, 0.25, 0.4], [0.0, 0.0, 12.0]);
    p.side = SIDE_BACK | SIDE_CAGED | side_exit(2, true);
    let mut counts = MarchCounts::default();
    step_particle_counted(&view, &mut p, &elastic, &mut counts);
    assert_eq!(counts[MarchBranch::CageExit], 0);
    assert_eq!(counts[MarchBranch::CageWall], 1);
    assert!(
        p.is_caged() && p.velocity[2] < 0.0 && p.position[2] < 0.5,
        "{p:?}"
    );
}

/// [`solid_corner`] whose solid leaf (octant 0, `[0, 0.5]³`) has clearance 16 on its upper
/// `y` face: the slab `y` in `[0.25, 0.5]` holds no triangle.
fn solid_corner_with_slab() -> [u32; HEADER_WORDS + 4] {
    let mut w = solid_corner();
    let leaf = NodeRecord::solid(encode_normal(Vec3::Y), [0, 0, 0, 16, 0, 0]);
    w[HEADER_WORDS + 2..].copy_from_slice(&[leaf.a, leaf.b]);
    crate::format::seal(&mut w);
    w
}

#[test]
fn a_particle_entering_a_solid_leaf_by_a_face_with_clearance_collides_in_its_slab() {
    let w = solid_corner_with_slab();
    let view = ProxyView::new(&w).unwrap();
    let resting = StepParams {
        restitution: 0.0,
        friction: 1.0,
        ..StepParams::default()
    };
    // Dropped onto the solid leaf's top: it comes to rest on the slab's inner side, y = 0.25
    // (a hair above, strictly inside the slab), not on the face at 0.5; in the slab it stays.
    let mut p = Particle::new([0.2, 0.6, 0.3], [0.0; 3]);
    let mut counts = MarchCounts::default();
    for _ in 0..120 {
        step_particle_counted(&view, &mut p, &resting, &mut counts);
        assert!(p.position[1] > 0.25, "{p:?}");
    }
    assert!(
        p.position[1] < 0.25 + 1e-6,
        "rests on the slab's inner side: {p:?}"
    );
    assert_eq!(
        p.side & !SIDE_MASK,
        SIDE_CAGED | SIDE_SLAB | side_exit(1, true)
    );
    assert_eq!(p.side_only(), SIDE_FRONT);
    assert!(counts[MarchBranch::SlabEntry] >= 1 && counts[MarchBranch::CageWall] >= 1);
    assert_eq!(counts[MarchBranch::SolidCollision], 0);

    // Sliding along the slab's floor to its side at x = 0.5: put back onto the face it came in
    // by, y = 0.5, and on from there, out of the leaf: no longer in the slab.
    let sliding = StepParams {
        gravity: [0.0; 3],
        restitution: 0.0,
        friction: 0.0,
        ..StepParams::default()
    };
    p.velocity = [3.0, 0.0, 0.0];
    let mut counts = MarchCounts::default();
    let mut pieces = Vec::new();
    for _ in 0..10 {
        let mut counted = p;
        step_particle_counted(&view, &mut counted, &sliding, &mut counts);
        step_particle_traced(&view, &mut p, &sliding, &mut |a, b| pieces.push((a, b)));
        assert_eq!(bytemuck::bytes_of(&counted), bytemuck::bytes_of(&p));
    }
    assert_eq!(counts[MarchBranch::SlabSide], 1);
    assert!(
        !p.is_caged() && p.position[0] > 0.5 && p.position[1] == 0.5,
        "{p:?}"
    );
    assert!(pieces
        .iter()
        .any(|&(a, b)| a.x == 0.5 && b.x == 0.5 && b.y == 0.5 && a.y < 0.5));

    // Bouncing: in through the face, off the inner side, out through the face, stamped by
    // the leaf above.
    let elastic = StepParams {
        gravity: [0.0; 3],
        restitution: 1.0,
        friction: 0.0,
        ..StepParams::default()
    };
    let mut p = Particle::new([0.2, 0.55, 0.3], [0.0, -36.0, 0.0]);
    let mut counts = MarchCounts::default();
    step_particle_counted(&view, &mut p, &elastic, &mut counts);
    assert_eq!(counts[MarchBranch::SlabEntry], 1);
    assert_eq!(counts[MarchBranch::CageWall], 1);
    assert_eq!(counts[MarchBranch::CageExit], 1);
    assert!(
        !p.is_caged() && p.position[1] > 0.5 && p.velocity[1] == 36.0,
        "{p:?}"
    );

    // Into the leaf through an edge (two faces at once): no slab, a collision at the faces.
    let mut p = Particle::new([0.55, 0.55, 0.3], [-36.0, -36.0, 0.0]);
    let mut counts = MarchCounts::default();
    step_particle_counted(&view, &mut p, &elastic, &mut counts);
    assert_eq!(counts[MarchBranch::SlabEntry], 0);
    assert_eq!(counts[MarchBranch::SolidCollision], 1);
}

/// A root of depth 1 with two solid leaves that meet at an edge: octant 0 (`[0, 0.5]³`) with
/// clearance 16 on its upper `y` face, octant 3 (`x` and `y` upper) with clearance 16 on its
/// lower `x` face; the other octants empty, labelled front.
fn solid_leaves_meeting_at_an_edge() -> [u32; HEADER_WORDS + 6] {
    let mut w = [0u32; HEADER_WORDS + 6];
    w[..HEADER_WORDS].copy_from_slice(&tiny()[..HEADER_WORDS]);
    w[header::TOTAL_WORDS] = (HEADER_WORDS + 6) as u32;
    w[header::NODE_COUNT] = 3;
    w[header::LUT_OFFSET] = (HEADER_WORDS + 6) as u32;
    let labels = [1, 2, 4, 5, 6, 7]
        .iter()
        .fold(0u16, |l, o| l | (Label::Front.bits() as u16) << (2 * o));
    let root = NodeRecord::internal(1, 0b0000_1001, 0, labels);
    let below = NodeRecord::solid(encode_normal(Vec3::Y), [0, 0, 0, 16, 0, 0]);
    let beside = NodeRecord::solid(encode_normal(-Vec3::X), [16, 0, 0, 0, 0, 0]);
    w[HEADER_WORDS..].copy_from_slice(&[root.a, root.b, below.a, below.b, beside.a, beside.b]);
    crate::format::seal(&mut w);
    w
}

#[test]
fn a_particle_leaving_a_slab_at_an_edge_is_not_handed_between_slabs() {
    let w = solid_leaves_meeting_at_an_edge();
    let view = ProxyView::new(&w).unwrap();
    let params = StepParams {
        gravity: [0.0; 3],
        restitution: 0.5,
        friction: 0.0,
        ..StepParams::default()
    };
    // Into the lower leaf's slab by its top face, across the slab to its side at x = 0.5, put
    // back onto the top face there: on the edge both leaves share. The leaf beyond, as the
    // velocity leads, is the upper one, entered by its lower x face at its edge, where it
    // would be at a side of that face's slab at once and be put back into the lower leaf's
    // slab, and so on, with no time spent, until the leaf bound (it was: 1,088 leaves, and
    // back to where it entered the shell). On an edge it collides at the face instead.
    let mut p = Particle::new([0.35, 0.52, 0.25], [12.0, -6.0, 0.0]);
    let mut counts = MarchCounts::default();
    let outcome = step_particle_counted(&view, &mut p, &params, &mut counts);
    assert_eq!(outcome, StepOutcome::Done, "{p:?} {counts:?}");
    assert_eq!(counts[MarchBranch::LeafBound], 0);
    assert_eq!(counts[MarchBranch::SlabEntry], 1);
    assert_eq!(counts[MarchBranch::SlabSide], 1);
    assert!(counts[MarchBranch::SolidCollision] >= 1);
    // It ends in the crease the two leaves make (pinched there), inside neither.
    for leaf in [Vec3::new(0.25, 0.25, 0.25), Vec3::new(0.75, 0.75, 0.25)] {
        let b = view.locate_leaf(leaf).unwrap().aabb;
        let x = Vec3::from_array(p.position);
        assert!(!(x.cmpgt(b.min) & x.cmplt(b.max)).all(), "{p:?}");
    }
    assert_eq!(p.side_only(), SIDE_FRONT);
}

#[test]
fn particles_resting_on_a_surface_leafs_plane_step_as_the_march_steps_them() {
    // `settle_on_plane`: dropped onto the plane of the tiny proxy's surface leaf (`y = 0.25`)
    // with bounce, then at rest with friction; at every step the hinted step (which settles
    // such a particle without the march while its hint is the surface leaf) gives the bits
    // of the unhinted march, and the hint stays that leaf once it rests.
    let w = tiny();
    let view = ProxyView::new(&w).unwrap();
    for (restitution, friction) in [(0.5, 0.1), (0.0, 0.8), (1.0, 0.0)] {
        for (start, v, side, g) in [
            ([0.2, 0.3, 0.3], [0.3, 0.0, -0.2], SIDE_FRONT, -9.81),
            // Behind the plane, pressed up against it from below.
            ([0.3, 0.2, 0.2], [0.0, 0.5, 0.1], SIDE_BACK, 9.81),
            ([0.1, 0.26, 0.4], [0.0, 0.0, 0.0], SIDE_FRONT, -9.81),
        ] {
            let params = StepParams {
                gravity: [0.0, g, 0.0],
                restitution,
                friction,
                ..StepParams::default()
            };
            let mut plain = Particle::new(start, v);
            plain.side = side;
            let mut hinted = plain;
            let mut hint = LeafHint::NONE;
            let mut on_surface = 0;
            for _ in 0..200 {
                step_particle(&view, &mut plain, &params);
                step_particle_hinted(&view, &mut hinted, &params, &mut hint);
                assert_eq!(bytemuck::bytes_of(&plain), bytemuck::bytes_of(&hinted));
                on_surface += (hint.z_depth_label & LeafHint::SURFACE != 0) as u32;
            }
            // Sliding ones leave the leaf in time; the one dropped straight stays.
            let expected = if v == [0.0; 3] { 190 } else { 10 };
            assert!(
                on_surface > expected,
                "{on_surface} steps in the surface leaf: {plain:?}"
            );
            assert!(plain.collisions() > 0);
        }
    }
}

#[test]
fn a_profiled_step_is_the_step_and_names_its_kind() {
    let w = tiny();
    let view = ProxyView::new(&w).unwrap();
    let params = StepParams {
        gravity: [0.0; 3],
        ..StepParams::default()
    };
    /// Start, velocity, whether the step has the hint of one step before, the kind, the
    /// leaves.
    type Case = ([f32; 3], [f32; 3], bool, StepKind, u32);
    let cases: [Case; 7] = [
        // Inside one empty leaf: marched without a hint, settled with one.
        (
            [0.75, 0.75, 0.75],
            [0.6, 0.0, 0.0],
            false,
            StepKind::OneLeaf,
            1,
        ),
        (
            [0.75, 0.75, 0.75],
            [0.6, 0.0, 0.0],
            true,
            StepKind::Settled,
            1,
        ),
        // Into the next empty leaf.
        (
            [0.55, 0.75, 0.75],
            [-12.0, 0.0, 0.0],
            false,
            StepKind::TwoLeaves,
            2,
        ),
        // Through three.
        (
            [0.95, 0.75, 0.25],
            [-30.0, 0.0, 30.0],
            false,
            StepKind::Several,
            3,
        ),
        // Down into the surface leaf against its normal, and back out.
        (
            [0.25, 0.75, 0.25],
            [0.0, -40.0, 0.0],
            false,
            StepKind::Colliding,
            3,
        ),
        // Rising out of the surface leaf.
        (
            [0.25, 0.3, 0.25],
            [0.0, 0.6, 0.0],
            false,
            StepKind::InSurface,
            1,
        ),
        // Outside the root, moving away.
        (
            [2.0, 2.0, 2.0],
            [1.0, 0.0, 0.0],
            false,
            StepKind::Settled,
            0,
        ),
    ];
    for (x, v, hinted, kind, leaves) in cases {
        let start = Particle::new(x, v);
        let mut hint = LeafHint::NONE;
        let mut first = start;
        if hinted {
            // The hint a step inside the leaf leaves, from a copy one step behind.
            step_particle_hinted(&view, &mut first, &params, &mut hint);
        }
        let (mut plain, mut profiled) = (first, first);
        let (mut h0, mut h1) = (hint, hint);
        let outcome = step_particle_hinted(&view, &mut plain, &params, &mut h0);
        let (o, profile) = step_particle_profiled(&view, &mut profiled, &params, &mut h1);
        assert_eq!(o, outcome);
        assert_eq!(bytemuck::bytes_of(&profiled), bytemuck::bytes_of(&plain));
        assert_eq!(h1, h0);
        assert_eq!(profile.kind, kind, "{x:?} {v:?}");
        assert_eq!(profile.leaves, leaves, "{x:?} {v:?}");
        assert_eq!(
            profile.kind == StepKind::Colliding,
            plain.collisions() > first.collisions(),
            "{x:?} {v:?}"
        );
    }
}

/// `math::floor` is `libm::floorf`, bit for bit: every float whose bits are a multiple of a
/// stride (a million of them, both signs, every exponent), and the edges.
#[test]
fn inline_floor_is_floorf() {
    let edges = [
        0.0f32,
        -0.0,
        0.5,
        -0.5,
        1.0,
        -1.0,
        0.999_999_94,
        -0.999_999_94,
        8_388_607.5,
        -8_388_607.5,
        8_388_608.0,
        -8_388_609.0,
        2_147_483_600.0,
        -2_147_483_600.0,
        f32::MIN_POSITIVE,
        -f32::MIN_POSITIVE,
        f32::MAX,
        f32::MIN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ];
    let strided = (0..u32::MAX / 4093).map(|k| f32::from_bits(k * 4093));
    for x in edges.into_iter().chain(strided) {
        let (a, b) = (crate::math::floor(x), libm::floorf(x));
        assert!(
            a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
            "{x:e}: {a:e} {b:e}"
        );
    }
}

#[test]
fn wide_length_is_length_where_that_is_finite_and_finite_beyond() {
    use crate::view::wide_length;
    for v in [
        Vec3::new(3.0, 4.0, 12.0),
        Vec3::new(-1e-30, 2e-20, 0.0),
        Vec3::new(1e18, -1e18, 1e18),
        Vec3::ZERO,
    ] {
        assert_eq!(wide_length(v).to_bits(), v.length().to_bits(), "{v}");
    }
    for (v, want) in [
        (Vec3::new(3e20, 4e20, 0.0), 5e20f32),
        (Vec3::new(0.0, -1e30, 0.0), 1e30),
        (Vec3::new(1e38, 0.0, 0.0), 1e38),
    ] {
        assert!(!v.length().is_finite());
        let l = wide_length(v);
        assert!((l - want).abs() <= 1e-6 * want, "{v}: {l:e}");
    }
    assert!(wide_length(Vec3::new(f32::NAN, 0.0, 0.0)).is_nan());
    assert!(wide_length(Vec3::new(f32::INFINITY, 0.0, 0.0)).is_infinite());
}
