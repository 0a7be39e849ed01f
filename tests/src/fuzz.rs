//! Fuzz target bodies. Each is a plain function of the fuzzer's bytes, called both by the
//! libFuzzer targets in `fuzz/` (outside the workspace) and by `tests/tests/fuzz.rs` over the
//! checked-in corpus plus a seeded random sweep, so `cargo test` exercises them on stable.
//!
//! Every body decodes its input with [`arbitrary::Unstructured`] and panics, with a message
//! that says what broke, when a property fails. Running out of input is not a failure: the
//! body just stops.

use std::io::Write;
use std::sync::OnceLock;

use arbitrary::{Arbitrary, Result, Unstructured};
use glam::Vec3;
use octoproxy_core::format::{HEADER_WORDS, MAX_DEPTH, MAX_LUT_DEPTH};
use octoproxy_core::{
    initial_side, step_particle, step_particle_hinted, step_particle_traced, LeafHint, PairParams,
    Particle, ProxyView, StepOutcome, StepParams, FLAG_INVALID, SIDE_BACK, SIDE_CAGE_MASK,
    SIDE_FRONT, SIDE_MASK,
};
use octoproxy_cpu::bake::{self as baker, BuildError, BuildParams, MeshRef};
use octoproxy_cpu::emit::emit_surface_for;
use octoproxy_cpu::io::{encode_particles, parse_particles, PlyEncoding};
use octoproxy_cpu::io::{parse_mesh, Mesh};

use octoproxy_cpu::bake::offset::OffsetSurface;
use octoproxy_cpu::ground_truth::GroundTruth;
use octoproxy_cpu::harness::{
    aligned_velocity, deep_on_the_other_side, jumps_back, run_check_pairs, tolerance,
};
use octoproxy_cpu::scenes;
use octoproxy_cpu::Sides;

// ---------------------------------------------------------------------------------------------
// Shared input decoding.
// ---------------------------------------------------------------------------------------------

/// Uniform in `[0, 1)` from 24 bits of input.
fn unit(u: &mut Unstructured<'_>) -> Result<f32> {
    Ok((u32::arbitrary(u)? >> 8) as f32 * (1.0 / (1u32 << 24) as f32))
}

/// Uniform in `[lo, hi)`.
fn range(u: &mut Unstructured<'_>, lo: f32, hi: f32) -> Result<f32> {
    Ok(lo + (hi - lo) * unit(u)?)
}

/// A float that is often hostile: NaN, infinities, extremes, subnormals, signed zeros, raw
/// bits, or an ordinary value in `[-scale, scale]`.
fn wild_f32(u: &mut Unstructured<'_>, scale: f32) -> Result<f32> {
    Ok(match u.int_in_range(0u8..=19)? {
        0 => f32::NAN,
        1 => f32::INFINITY,
        2 => f32::NEG_INFINITY,
        3 => f32::MAX,
        4 => -f32::MAX,
        5 => f32::MIN_POSITIVE,
        6 => f32::from_bits(1),
        7 => 0.0,
        8 => -0.0,
        9 => f32::from_bits(u32::arbitrary(u)?),
        10 => range(u, -1e30, 1e30)?,
        11 => range(u, -1e-30, 1e-30)?,
        _ => range(u, -scale, scale)?,
    })
}

fn wild_vec(u: &mut Unstructured<'_>, scale: f32) -> Result<[f32; 3]> {
    Ok([
        wild_f32(u, scale)?,
        wild_f32(u, scale)?,
        wild_f32(u, scale)?,
    ])
}

fn finite(v: [f32; 3]) -> bool {
    v.iter().all(|c| c.is_finite())
}

fn bits(p: &Particle) -> [u32; 8] {
    [
        p.position[0].to_bits(),
        p.position[1].to_bits(),
        p.position[2].to_bits(),
        p.side,
        p.velocity[0].to_bits(),
        p.velocity[1].to_bits(),
        p.velocity[2].to_bits(),
        p.flags,
    ]
}

/// Step parameters: usually valid, sometimes anything (including NaN and negative dt).
fn step_params(u: &mut Unstructured<'_>, scene: f32) -> Result<StepParams> {
    if u.ratio(1u8, 4)? {
        return Ok(StepParams {
            gravity: wild_vec(u, 100.0)?,
            dt: wild_f32(u, 1.0)?,
            restitution: wild_f32(u, 2.0)?,
            friction: wild_f32(u, 2.0)?,
            radius: 0.0,
            _pad: 0,
        });
    }
    let g = if u.arbitrary()? {
        [0.0, -9.81, 0.0]
    } else {
        [
            range(u, -20.0, 20.0)?,
            range(u, -20.0, 20.0)?,
            range(u, -20.0, 20.0)?,
        ]
    };
    let g = g.map(|c| c * scene.max(1e-3));
    Ok(StepParams {
        gravity: if u.ratio(1u8, 3)? { [0.0; 3] } else { g },
        dt: *u.choose(&[1.0 / 240.0, 1.0 / 60.0, 1.0 / 30.0, 0.1, 1e-6, 1.0])?,
        restitution: *u.choose(&[0.0, 0.5, 1.0, 0.25, 0.9])?,
        friction: *u.choose(&[0.0, 0.1, 1.0, 0.5, 3.0])?,
        radius: 0.0,
        _pad: 0,
    })
}

/// Checks that `params.validate()` rejects exactly the parameters its documentation says.
fn check_params(params: &StepParams) -> bool {
    let ok = params.validate().is_ok();
    let expect = params.dt > 0.0
        && params.dt.is_finite()
        && finite(params.gravity)
        && (0.0..=1.0).contains(&params.restitution)
        && params.friction >= 0.0
        && params.friction.is_finite();
    assert_eq!(
        ok, expect,
        "StepParams::validate disagrees with its documented ranges for {params:?}"
    );
    ok
}

// ---------------------------------------------------------------------------------------------
// proxy_bytes
// ---------------------------------------------------------------------------------------------

/// A few small valid proxies that `proxy_bytes` mutates: closed, open, sharp, overlapping
/// (conflicting labels, so solid leaves), with and without lookup tables.
pub fn seed_proxies() -> &'static [Vec<u32>] {
    static PROXIES: OnceLock<Vec<Vec<u32>>> = OnceLock::new();
    PROXIES.get_or_init(|| {
        let p = |dmin, dmax, lut_depth| BuildParams {
            dmin,
            dmax,
            epsilon: 0.01,
            lut_depth,
            ..BuildParams::default()
        };
        let scenes: Vec<(Mesh, BuildParams)> = vec![
            (scenes::cube([-1.0; 3], [1.0; 3]), p(1, 3, 2)),
            (scenes::uv_sphere([0.2, 0.1, 0.0], 1.0, 8, 4), p(2, 4, 3)),
            (scenes::flat_sheet([0.0; 3], 2.0, 2), p(1, 4, 0)),
            (scenes::wedge(20.0, 2.0, 1.0), p(2, 5, 1)),
            (
                scenes::merge(&[
                    scenes::cube([-1.0; 3], [0.5; 3]),
                    scenes::cube([-0.5; 3], [1.0; 3]),
                ]),
                p(2, 4, 2),
            ),
            (scenes::slab([0.0; 3], [2.0, 0.01, 2.0]), p(1, 4, 4)),
        ];
        scenes
            .iter()
            .map(|(m, params)| {
                baker::bake(&[MeshRef::from(m)], params, &())
                    .expect("seed proxy bakes")
                    .0
            })
            .collect()
    })
}

fn interesting_word(u: &mut Unstructured<'_>, words: &[u32]) -> Result<u32> {
    Ok(match u.int_in_range(0u8..=11)? {
        0 => 0,
        1 => 1,
        2 => u32::MAX,
        3 => words.len() as u32,
        4 => (words.len() as u32).wrapping_sub(HEADER_WORDS as u32),
        5 => f32::NAN.to_bits(),
        6 => f32::INFINITY.to_bits(),
        7 => 1e30f32.to_bits(),
        8 => 1e-30f32.to_bits(),
        9 => MAX_DEPTH + u.int_in_range(0..=2)? - 1,
        10 => 1 << u.int_in_range(0..=31)?,
        _ => u32::arbitrary(u)?,
    })
}

/// Applies a few mutations (bit flips, word overwrites, header tweaks, truncation, appends,
/// copies) to `words`.
fn mutate(words: &mut Vec<u32>, u: &mut Unstructured<'_>) -> Result<()> {
    let n = u.int_in_range(0u8..=6)?;
    for _ in 0..n {
        if words.is_empty() {
            words.push(u32::arbitrary(u)?);
        }
        let len = words.len();
        match u.int_in_range(0u8..=7)? {
            0 | 1 => {
                let i = u.choose_index(len)?;
                words[i] ^= 1 << u.int_in_range(0..=31)?;
            }
            2 => {
                let i = u.choose_index(len)?;
                words[i] = interesting_word(u, words)?;
            }
            3 => {
                let i = u.choose_index(HEADER_WORDS.min(len))?;
                let d = u.int_in_range(-2i32..=2)?;
                words[i] = words[i].wrapping_add_signed(d);
            }
            4 => {
                let keep = u.int_in_range(0..=len)?;
                words.truncate(keep);
            }
            5 => {
                for _ in 0..u.int_in_range(1u8..=8)? {
                    words.push(u32::arbitrary(u)?);
                }
            }
            6 => {
                let (a, b) = (u.choose_index(len)?, u.choose_index(len)?);
                words.swap(a, b);
            }
            _ => {
                // Flip a bit of a node record (most of the file), away from the header.
                if len > HEADER_WORDS {
                    let i = HEADER_WORDS + u.choose_index(len - HEADER_WORDS)?;
                    words[i] ^= 1 << u.int_in_range(0..=31)?;
                }
            }
        }
    }
    Ok(())
}

/// A query point for `view`: in the root cube, exactly on grid planes, just outside, or wild.
fn query_point(u: &mut Unstructured<'_>, view: &ProxyView<'_>) -> Result<Vec3> {
    let root = view.root_aabb();
    let size = view.header().root_size;
    Ok(match u.int_in_range(0u8..=5)? {
        0 | 1 => Vec3::new(
            range(u, root.min.x, root.max.x)?,
            range(u, root.min.y, root.max.y)?,
            range(u, root.min.z, root.max.z)?,
        ),
        2 => {
            // On the finest grid's planes (cell boundaries, root faces included).
            let n = 1u32 << MAX_DEPTH;
            let mut p = [0.0; 3];
            for (a, c) in p.iter_mut().enumerate() {
                *c = view.plane(a, u.int_in_range(0..=n)?);
            }
            Vec3::from_array(p)
        }
        3 => {
            let n = 1u32 << MAX_DEPTH;
            let a = u.int_in_range(0usize..=2)?;
            let mut p = Vec3::new(
                range(u, root.min.x, root.max.x)?,
                range(u, root.min.y, root.max.y)?,
                range(u, root.min.z, root.max.z)?,
            );
            p[a] = view.plane(a, *u.choose(&[0, n])?);
            p
        }
        4 => Vec3::new(
            range(u, root.min.x - size, root.max.x + size)?,
            range(u, root.min.y - size, root.max.y + size)?,
            range(u, root.min.z - size, root.max.z + size)?,
        ),
        _ => Vec3::from_array(wild_vec(u, size.max(1.0) * 2.0)?),
    })
}

/// Queries and steps over an accepted view: no panic, in-bounds results, bounded steps, and
/// the lookup table changes nothing.
fn exercise_view(view: &ProxyView<'_>, u: &mut Unstructured<'_>) -> Result<()> {
    let h = *view.header();
    assert!(
        h.tree_depth >= 1
            && h.tree_depth <= MAX_DEPTH
            && h.dmax >= h.tree_depth
            && h.dmin <= h.dmax,
        "accepted header out of range: {h:?}"
    );
    assert!(
        h.lut_depth <= MAX_LUT_DEPTH && h.lut_depth <= h.tree_depth,
        "accepted lut depth out of range: {h:?}"
    );
    assert_eq!(
        view.nodes().len(),
        h.node_count as usize,
        "node slice length differs from the header's node count"
    );
    let plain = view.without_lut();
    let bound = view.max_leaves_per_step();
    let scene = h.root_size;
    let queries = u.int_in_range(1u8..=6)?;
    for _ in 0..queries {
        let p = query_point(u, view)?;
        let dir = if u.arbitrary()? {
            Vec3::from_array(wild_vec(u, 1.0)?)
        } else {
            Vec3::ZERO
        };
        let a = view.locate_leaf(p);
        let b = plain.locate_leaf(p);
        assert_eq!(
            format!("{a:?}"),
            format!("{b:?}"),
            "locate_leaf at {p:?} differs with and without the lookup table"
        );
        if let Some(leaf) = a {
            assert!(
                p.is_finite(),
                "locate_leaf found a leaf for the non-finite point {p:?}"
            );
            assert!(
                leaf.aabb.min.cmple(p).all() && p.cmple(leaf.aabb.max).all(),
                "locate_leaf({p:?}) returned a leaf whose box {:?} does not hold the point",
                leaf.aabb
            );
            assert!(
                leaf.depth <= h.tree_depth,
                "leaf depth {} exceeds tree depth {}",
                leaf.depth,
                h.tree_depth
            );
            assert!(
                leaf.node < h.node_count || leaf.kind == octoproxy_core::LeafKind::Empty,
                "leaf node {} out of range",
                leaf.node
            );
        } else if p.is_finite() {
            assert!(
                !view.root_contains(p, Vec3::ZERO),
                "locate_leaf({p:?}) found nothing inside the root cube"
            );
        }
        let a = view.locate_leaf_toward(p, dir);
        let b = plain.locate_leaf_toward(p, dir);
        assert_eq!(
            format!("{a:?}"),
            format!("{b:?}"),
            "locate_leaf_toward({p:?}, {dir:?}) differs with and without the lookup table"
        );
        if let Some(leaf) = a {
            assert!(
                leaf.aabb.min.cmple(p).all() && p.cmple(leaf.aabb.max).all(),
                "locate_leaf_toward({p:?}, {dir:?}) returned a leaf whose box {:?} does not hold the point",
                leaf.aabb
            );
            // The march's way to the next leaf: from this one, to a point on its box.
            let mut q = p;
            for k in 0..3 {
                q[k] = match u.int_in_range(0u8..=2)? {
                    0 => leaf.aabb.min[k],
                    1 => leaf.aabb.max[k],
                    _ => p[k],
                };
            }
            assert_eq!(
                format!("{:?}", view.locate_leaf_from(&leaf, q, dir)),
                format!("{:?}", view.locate_leaf_toward(q, dir)),
                "locate_leaf_from({leaf:?}, {q:?}, {dir:?}) differs from locate_leaf_toward"
            );
        }
        let side = initial_side(view, p.to_array());
        assert!(
            side == SIDE_FRONT || side == SIDE_BACK,
            "initial_side returned {side}"
        );

        // A particle at p with an arbitrary velocity (sometimes hostile), side and flags.
        let velocity = if u.ratio(1u8, 5)? {
            wild_vec(u, scene * 100.0)?
        } else {
            let speed = scene * 10f32.powf(range(u, -4.0, 2.0)?);
            let d = Vec3::from_array(wild_vec(u, 1.0)?);
            let d = if d.is_finite() && d.length_squared() > 0.0 {
                d.normalize_or_zero()
            } else {
                Vec3::X
            };
            (d * speed).to_array()
        };
        let mut particle = Particle {
            position: p.to_array(),
            side: if u.arbitrary()? {
                side
            } else {
                u32::arbitrary(u)?
            },
            velocity,
            flags: if u.arbitrary()? {
                0
            } else {
                u32::arbitrary(u)?
            },
        };
        let params = step_params(u, scene)?;
        if !check_params(&params) {
            continue;
        }
        let steps = u.int_in_range(1u8..=4)?;
        // The same particle stepped with a leaf hint, as the backends step it.
        let (mut hinted, mut hint) = (particle, LeafHint::NONE);
        for _ in 0..steps {
            let before = particle;
            let mut pieces = 0u64;
            let outcome =
                step_particle_traced(view, &mut particle, &params, &mut |_, _| pieces += 1);
            let mut again = before;
            step_particle(&plain, &mut again, &params);
            assert_eq!(
                bits(&particle),
                bits(&again),
                "the step differs with and without the lookup table from {before:?}, {params:?}"
            );
            step_particle_hinted(view, &mut hinted, &params, &mut hint);
            assert_eq!(
                bits(&hinted),
                bits(&particle),
                "the step differs with and without a leaf hint from {before:?}, {params:?}"
            );
            assert!(
                pieces <= bound as u64 + 2,
                "step took {pieces} path pieces, more than its bound of {bound} leaves, from {before:?}"
            );
            if !finite(before.position) || !finite(before.velocity) {
                assert_eq!(
                    outcome,
                    StepOutcome::Invalid,
                    "non-finite particle {before:?} was not reported invalid"
                );
            }
            if outcome == StepOutcome::Invalid {
                assert!(
                    particle.flags & FLAG_INVALID != 0,
                    "invalid step did not set FLAG_INVALID on {before:?}"
                );
                assert_eq!(
                    (bits(&particle)[..7]).to_vec(),
                    bits(&before)[..7].to_vec(),
                    "invalid step changed the particle {before:?}"
                );
                break;
            }
            assert!(
                finite(particle.position) && finite(particle.velocity),
                "step of {before:?} with {params:?} gave a non-finite particle {particle:?} without reporting it invalid"
            );
            // A side, and the cage bits only for a particle still caged: strictly inside a
            // solid leaf.
            let caged_in_solid = || {
                let x = Vec3::from_array(particle.position);
                view.locate_leaf(x).is_some_and(|l| {
                    l.two_sided && x.cmpgt(l.aabb.min).all() && x.cmplt(l.aabb.max).all()
                })
            };
            assert!(
                particle.side == SIDE_FRONT
                    || particle.side == SIDE_BACK
                    || (particle.side & !(SIDE_MASK | SIDE_CAGE_MASK) == 0
                        && particle.is_caged()
                        && caged_in_solid()),
                "step left side {:#x} at {:?}",
                particle.side,
                particle.position
            );
        }
    }
    Ok(())
}

fn proxy_bytes_inner(u: &mut Unstructured<'_>) -> Result<()> {
    let mode = u.int_in_range(0u8..=3)?;
    let words: Vec<u32> = if mode == 0 {
        let raw = u.bytes(u.len())?;
        // Whatever alignment the slice has: misaligned or ragged input must be an error.
        match ProxyView::from_bytes(raw) {
            Ok(view) => {
                let _ = view.header();
            }
            Err(e) => {
                let _ = e.to_string();
            }
        }
        let words: Vec<u32> = raw
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        // The aligned bytes of the same words give the same answer as the words.
        let aligned: &[u8] = bytemuck::cast_slice(&words);
        let from_bytes = ProxyView::from_bytes(aligned).map(|v| *v.header());
        let from_words = ProxyView::new(&words).map(|v| *v.header());
        assert_eq!(
            format!("{from_bytes:?}"),
            format!("{from_words:?}"),
            "from_bytes and new disagree"
        );
        if raw.len() % 4 != 0 {
            assert!(
                matches!(
                    ProxyView::from_bytes(raw),
                    Err(octoproxy_core::FormatError::Misaligned { .. })
                ),
                "from_bytes accepted {} bytes, not a whole number of words",
                raw.len()
            );
        }
        words
    } else {
        let seeds = seed_proxies();
        let mut words = u.choose(seeds)?.clone();
        mutate(&mut words, u)?;
        words
    };
    match ProxyView::new(&words) {
        Ok(view) => {
            assert_eq!(
                view.words().len(),
                words.len(),
                "view does not cover the buffer"
            );
            exercise_view(&view, u)?;
        }
        Err(e) => {
            let msg = e.to_string();
            assert!(
                msg.starts_with("proxy") || msg.starts_with("not an octoproxy"),
                "unexpected error text: {msg}"
            );
        }
    }
    Ok(())
}

/// Target `proxy_bytes`: arbitrary words (or a valid proxy, mutated) into the validated view;
/// over whatever it accepts, point queries and steps of arbitrary particles with arbitrary
/// (validated) parameters must not panic, stay in the leaf bound, give the same answers
/// with and without the lookup table, and report exactly the non-finite particles invalid.
pub fn proxy_bytes(data: &[u8]) {
    let _ = proxy_bytes_inner(&mut Unstructured::new(data));
}

// ---------------------------------------------------------------------------------------------
// build
// ---------------------------------------------------------------------------------------------

/// Largest dmax the `bake` target bakes (so one input bakes in well under a second).
pub const BUILD_MAX_DMAX: u32 = 7;
/// Most triangles per mesh the `bake` target makes.
pub const BUILD_MAX_TRIANGLES: usize = 300;

fn soup(u: &mut Unstructured<'_>) -> Result<Mesh> {
    let nv = u.int_in_range(0usize..=48)?;
    let style = u.int_in_range(0u8..=7)?;
    let offset = if style == 5 {
        [
            range(u, -1e7, 1e7)?,
            range(u, -1e7, 1e7)?,
            range(u, -1e7, 1e7)?,
        ]
    } else {
        [0.0; 3]
    };
    let mut positions = Vec::with_capacity(nv);
    let one = [
        range(u, -1.0, 1.0)?,
        range(u, -1.0, 1.0)?,
        range(u, -1.0, 1.0)?,
    ];
    for _ in 0..nv {
        let p = match style {
            0 | 1 => [
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
            ],
            2 => one,
            3 => [
                range(u, -1e30, 1e30)?,
                range(u, -1e30, 1e30)?,
                range(u, -1e30, 1e30)?,
            ],
            4 => [
                range(u, -1e-30, 1e-30)?,
                range(u, -1e-30, 1e-30)?,
                range(u, -1e-30, 1e-30)?,
            ],
            5 => [
                offset[0] + range(u, -1.0, 1.0)?,
                offset[1] + range(u, -1.0, 1.0)?,
                offset[2] + range(u, -1.0, 1.0)?,
            ],
            6 => [range(u, -1.0, 1.0)?, 0.0, range(u, -1.0, 1.0)?],
            // Hostile values (NaN and inf among them) now and then.
            _ if u.ratio(1u8, 4)? => wild_vec(u, 1.0)?,
            _ => [
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
            ],
        };
        positions.push(p);
    }
    let nt = u.int_in_range(0usize..=BUILD_MAX_TRIANGLES)?;
    // One soup in eight may have indices out of range (most then stop at that error).
    let bad_indices = u.ratio(1u8, 8)?;
    let mut triangles = Vec::with_capacity(nt);
    for _ in 0..nt {
        if u.is_empty() {
            break;
        }
        let mut t = [0u32; 3];
        for i in &mut t {
            *i = if bad_indices && u.ratio(1u8, 20)? {
                let any = u32::arbitrary(u)?;
                *u.choose(&[nv as u32, nv as u32 + 1, u32::MAX, any])?
            } else {
                u.int_in_range(0..=(nv as u32).saturating_sub(1))?
            };
        }
        if u.ratio(1u8, 8)? && !triangles.is_empty() {
            // Duplicate (or flip) an earlier triangle.
            let prev: [u32; 3] = triangles[u.choose_index(triangles.len())?];
            t = if u.arbitrary()? {
                prev
            } else {
                [prev[0], prev[2], prev[1]]
            };
        }
        triangles.push(t);
    }
    Ok(Mesh {
        positions,
        triangles,
    })
}

fn build_params(u: &mut Unstructured<'_>) -> Result<BuildParams> {
    if u.ratio(1u8, 5)? {
        // Anything, out of range included.
        return Ok(BuildParams {
            dmin: *u.choose(&[0, 1, 2, 8, 16, 17, 40, u32::MAX])?,
            dmax: *u.choose(&[0, 1, 2, 3, 16, 17, 40, u32::MAX])?,
            epsilon: wild_f32(u, 1.0)?,
            lut_depth: *u.choose(&[0, 1, 8, 9, 40, u32::MAX])?,
            max_nodes: u64::arbitrary(u)?,
        });
    }
    let dmax = u.int_in_range(2..=BUILD_MAX_DMAX)?;
    Ok(BuildParams {
        dmin: u.int_in_range(0..=dmax)?,
        dmax,
        epsilon: *u.choose(&[0.0, 1e-6, 0.01, 0.1, 1.0, 1e30])?,
        lut_depth: u.int_in_range(0..=MAX_LUT_DEPTH.min(6))?,
        max_nodes: *u.choose(&[1, 8, 100, 10_000, 200_000])?,
    })
}

/// The error `bake` must give for `meshes` from `gather`'s checks, in its order (per mesh:
/// a non-finite vertex anywhere, then out-of-range indices triangle by triangle).
fn expected_input_error(meshes: &[Mesh]) -> Option<String> {
    for (mi, m) in meshes.iter().enumerate() {
        if m.positions.iter().any(|p| !finite(*p)) {
            return Some(format!("NonFinite mesh {mi}"));
        }
        if m.triangles
            .iter()
            .any(|t| t.iter().any(|&i| i as usize >= m.positions.len()))
        {
            return Some(format!("IndexOutOfRange mesh {mi}"));
        }
    }
    None
}

/// The parameters and meshes the `bake` target makes of `data` (for reproducing a case).
pub fn bake_case(data: &[u8]) -> Option<(BuildParams, Vec<Mesh>)> {
    let u = &mut Unstructured::new(data);
    let params = build_params(u).ok()?;
    let count = u.int_in_range(1usize..=3).ok()?;
    let mut meshes = Vec::with_capacity(count);
    for _ in 0..count {
        meshes.push(soup(u).ok()?);
    }
    Some((params, meshes))
}

fn build_inner(u: &mut Unstructured<'_>) -> Result<()> {
    let params = build_params(u)?;
    let count = u.int_in_range(1usize..=3)?;
    let mut meshes = Vec::with_capacity(count);
    for _ in 0..count {
        meshes.push(soup(u)?);
    }
    let refs: Vec<MeshRef<'_>> = meshes.iter().map(MeshRef::from).collect();
    let valid = params.validate().is_ok();
    let expect_valid = params.dmax >= 2
        && params.dmax <= MAX_DEPTH
        && params.dmin <= params.dmax
        && params.epsilon >= 0.0
        && params.epsilon.is_finite()
        && params.lut_depth <= MAX_LUT_DEPTH;
    assert_eq!(
        valid, expect_valid,
        "BuildParams::validate disagrees with its documented ranges for {params:?}"
    );
    if valid && (params.dmax > BUILD_MAX_DMAX || (params.max_nodes > 200_000 && params.dmin > 5)) {
        // Valid but too slow to bake per input.
        return Ok(());
    }
    let params = if params.max_nodes > 200_000 {
        BuildParams {
            max_nodes: 200_000,
            ..params
        }
    } else {
        params
    };
    match baker::bake(&refs, &params, &()) {
        Ok((words, report)) => {
            assert!(valid, "bake accepted invalid parameters {params:?}");
            assert_eq!(
                expected_input_error(&meshes),
                None,
                "bake accepted a mesh it should reject"
            );
            let view = ProxyView::new(&words).unwrap_or_else(|e| {
                panic!("bake produced a proxy the view rejects: {e} ({params:?})")
            });
            let h = view.header();
            assert_eq!(h.dmax, params.dmax, "header dmax is not the build's dmax");
            assert!(
                h.tree_depth <= params.dmax,
                "tree depth {} exceeds dmax {}",
                h.tree_depth,
                params.dmax
            );
            assert_eq!(
                report.total_bytes,
                words.len() * 4,
                "report's total_bytes is not the proxy's size"
            );
            assert!(
                (report.nodes as u64) <= params.max_nodes.max(1) + 8,
                "{} nodes exceed max_nodes {}",
                report.nodes,
                params.max_nodes
            );
            let total: usize = meshes.iter().map(|m| m.triangles.len()).sum();
            assert_eq!(
                report.triangles_in, total,
                "report counts {} triangles in, there are {total}",
                report.triangles_in
            );
            assert!(
                view.header().root_size.is_finite() && view.header().root_size > 0.0,
                "root size is not positive"
            );
            // Every vertex of every non-degenerate triangle lies inside the root cube.
            let root = view.root_aabb();
            for m in &meshes {
                for t in &m.triangles {
                    let v = t.map(|i| Vec3::from_array(m.positions[i as usize]));
                    let area = (v[1].as_dvec3() - v[0].as_dvec3())
                        .cross(v[2].as_dvec3() - v[0].as_dvec3())
                        .length();
                    if area > 0.0 && area.is_finite() {
                        for p in v {
                            assert!(
                                root.min.cmple(p).all() && p.cmple(root.max).all(),
                                "vertex {p:?} lies outside the root cube {root:?}"
                            );
                        }
                    }
                }
            }
        }
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.is_empty(), "empty error message");
            if !valid {
                assert!(
                    matches!(e, BuildError::BadParam(_)),
                    "invalid parameters {params:?} gave {e:?}, not BadParam"
                );
                return Ok(());
            }
            match expected_input_error(&meshes) {
                Some(want) => {
                    let got = match &e {
                        BuildError::NonFinite { mesh, .. } => format!("NonFinite mesh {mesh}"),
                        BuildError::IndexOutOfRange { mesh, .. } => {
                            format!("IndexOutOfRange mesh {mesh}")
                        }
                        other => format!("{other:?}"),
                    };
                    assert_eq!(got, want, "bake gave the wrong error for bad input");
                }
                None => assert!(
                    matches!(
                        e,
                        BuildError::Empty { .. }
                            | BuildError::Resolution { .. }
                            | BuildError::TooLarge { .. }
                            | BuildError::TooSmall { .. }
                            | BuildError::TooManyNodes { .. }
                            | BuildError::Unsplittable
                    ),
                    "bake failed on valid input and parameters {params:?} with {e:?}"
                ),
            }
        }
    }
    if valid && expected_input_error(&meshes).is_none() && params.dmax <= 5 && u.ratio(1u8, 3)? {
        radius_case(u, &refs, &params)?;
    }
    Ok(())
}

/// The same soup baked for a particle radius (some of them hostile): a clear error, or an
/// offset surface that is closed, within `h√3` of the radius at its vertices, and a proxy
/// that records the radius.
fn radius_case(u: &mut Unstructured<'_>, refs: &[MeshRef<'_>], params: &BuildParams) -> Result<()> {
    use octoproxy_cpu::bake::offset::{is_closed, OffsetSurface, MAX_RADIUS_PER_EXTENT};
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for m in refs {
        for t in m.triangles {
            for &i in t {
                let p = Vec3::from_array(m.positions[i as usize]);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
    }
    let extent = (hi - lo).max_element();
    let radius = match u.int_in_range(0u8..=9)? {
        0 => f32::NAN,
        1 => -range(u, 0.0, 1.0)?,
        2 => f32::INFINITY,
        3 => extent * (MAX_RADIUS_PER_EXTENT as f32) * 2.0,
        4 => 0.0,
        _ => range(u, 0.01, 0.5)? * extent,
    };
    let sane = radius > 0.0
        && radius.is_finite()
        && extent > 0.0
        && (radius as f64) <= MAX_RADIUS_PER_EXTENT * extent as f64;
    let surface = match OffsetSurface::new(refs, radius, params.dmax, &()) {
        Ok(s) => s,
        Err(e) => {
            // A bad radius, or a soup the bake itself refuses (all of it degenerate).
            assert!(
                matches!(
                    e,
                    BuildError::BadParam(_)
                        | BuildError::Empty { .. }
                        | BuildError::TooLarge { .. }
                ),
                "radius {radius}: {e:?}, not BadParam"
            );
            assert!(!e.to_string().is_empty());
            return Ok(());
        }
    };
    assert!(
        sane,
        "an offset surface for radius {radius} (extent {extent})"
    );
    let mesh = surface.mesh();
    assert!(
        is_closed(&mesh.triangles),
        "an offset surface that is not closed"
    );
    let slack = mesh.spacing * 3f64.sqrt() * 1.001 + extent as f64 * 1e-5;
    for v in mesh.positions.iter().step_by(mesh.positions.len() / 50 + 1) {
        let d = surface.truth().distance(*v);
        assert!(
            (d - radius as f64).abs() <= slack,
            "an offset vertex {d} from the scene, radius {radius}, slack {slack}"
        );
    }
    let small = BuildParams {
        max_nodes: params.max_nodes.min(200_000),
        ..*params
    };
    match octoproxy_cpu::bake_offset(&surface, &small, &()) {
        Ok((words, _)) => {
            let view = ProxyView::new(&words).expect("a radius proxy validates");
            assert_eq!(view.header().radius, radius);
        }
        Err(e) => assert!(
            matches!(
                e,
                BuildError::Resolution { .. }
                    | BuildError::TooLarge { .. }
                    | BuildError::TooSmall { .. }
                    | BuildError::TooManyNodes { .. }
                    | BuildError::Unsplittable
            ),
            "the offset surface of radius {radius} did not bake: {e:?}"
        ),
    }
    Ok(())
}

/// Target `bake`: arbitrary triangle soups (degenerate, duplicated, NaN, huge, tiny, all in
/// one point, far from the origin, indices out of range) and parameters (out of range too)
/// into `bake`: the right error, or a proxy the view accepts; never a panic.
pub fn bake(data: &[u8]) {
    let _ = build_inner(&mut Unstructured::new(data));
}

// ---------------------------------------------------------------------------------------------
// penetration
// ---------------------------------------------------------------------------------------------

/// A random rotation (unit quaternion) and translation: the mesh stays closed and keeps its
/// orientation.
fn place(u: &mut Unstructured<'_>, mut m: Mesh) -> Result<Mesh> {
    let q = glam::Quat::from_xyzw(
        range(u, -1.0, 1.0)?,
        range(u, -1.0, 1.0)?,
        range(u, -1.0, 1.0)?,
        range(u, -1.0, 1.0)?,
    );
    let q = if q.length_squared() > 1e-3 && u.ratio(2u8, 3)? {
        q.normalize()
    } else {
        glam::Quat::IDENTITY
    };
    let t = Vec3::new(
        range(u, -0.5, 0.5)?,
        range(u, -0.5, 0.5)?,
        range(u, -0.5, 0.5)?,
    );
    for p in &mut m.positions {
        *p = (q * Vec3::from_array(*p) + t).to_array();
    }
    Ok(m)
}

/// The convex hull of a few random points, by brute force: every triple whose plane has all
/// points on one side is a face (fine for a dozen points in general position).
fn convex_hull(points: &[Vec3]) -> Option<Mesh> {
    let n = points.len();
    let pd: Vec<glam::DVec3> = points.iter().map(|p| p.as_dvec3()).collect();
    let mut triangles = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let nrm = (pd[j] - pd[i]).cross(pd[k] - pd[i]);
                if nrm.length_squared() < 1e-12 {
                    continue;
                }
                let (mut pos, mut neg, mut zero) = (0, 0, 0);
                for (l, q) in pd.iter().enumerate() {
                    if l == i || l == j || l == k {
                        continue;
                    }
                    let s = nrm.dot(*q - pd[i]);
                    if s > 1e-12 {
                        pos += 1;
                    } else if s < -1e-12 {
                        neg += 1;
                    } else {
                        zero += 1;
                    }
                }
                if zero > 0 {
                    // Coplanar points: not in general position, give up.
                    if pos == 0 || neg == 0 {
                        return None;
                    }
                    continue;
                }
                if pos == 0 {
                    triangles.push([i as u32, j as u32, k as u32]);
                } else if neg == 0 {
                    triangles.push([i as u32, k as u32, j as u32]);
                }
            }
        }
    }
    let mesh = Mesh {
        positions: points.iter().map(|p| p.to_array()).collect(),
        triangles,
    };
    (mesh.triangles.len() >= 4 && scenes::is_closed(&mesh)).then_some(mesh)
}

fn closed_part(u: &mut Unstructured<'_>) -> Result<Mesh> {
    let r = |u: &mut Unstructured<'_>, lo: f32, hi: f32| range(u, lo, hi);
    let m = match u.int_in_range(0u8..=9)? {
        0 => {
            let a = [r(u, -1.0, 0.0)?, r(u, -1.0, 0.0)?, r(u, -1.0, 0.0)?];
            let b = [
                a[0] + r(u, 0.05, 1.5)?,
                a[1] + r(u, 0.05, 1.5)?,
                a[2] + r(u, 0.05, 1.5)?,
            ];
            scenes::cube(a, b)
        }
        1 => {
            // A slab thinner than a leaf (or about one): thickness 1e-4 .. 0.05 of a unit scene.
            let mut size = [r(u, 0.3, 1.8)?, r(u, 0.3, 1.8)?, r(u, 0.3, 1.8)?];
            size[u.int_in_range(0usize..=2)?] = 10f32.powf(r(u, -4.0, -1.3)?);
            scenes::slab([0.0; 3], size)
        }
        2 => scenes::wedge(r(u, 2.0, 90.0)?, r(u, 0.3, 1.5)?, r(u, 0.1, 1.5)?),
        3 => scenes::uv_sphere(
            [0.0; 3],
            r(u, 0.2, 1.0)?,
            u.int_in_range(3..=10)?,
            u.int_in_range(2..=6)?,
        ),
        4 => {
            let major = r(u, 0.3, 0.8)?;
            scenes::torus(
                [0.0; 3],
                major,
                r(u, 0.05, major * 0.9)?,
                u.int_in_range(3..=16)?,
                u.int_in_range(3..=8)?,
            )
        }
        5 => {
            let ro = r(u, 0.3, 1.0)?;
            scenes::star_prism(
                u.int_in_range(2..=8)?,
                ro,
                r(u, 0.05, ro)?,
                r(u, 0.02, 1.0)?,
            )
        }
        6 => {
            let ro = r(u, 0.4, 1.0)?;
            scenes::nested_shells(ro, r(u, 0.005, ro * 0.5)?)
        }
        7 | 8 => {
            let n = u.int_in_range(4usize..=10)?;
            let mut pts = Vec::with_capacity(n);
            for _ in 0..n {
                pts.push(Vec3::new(
                    r(u, -1.0, 1.0)?,
                    r(u, -1.0, 1.0)?,
                    r(u, -1.0, 1.0)?,
                ));
            }
            match convex_hull(&pts) {
                Some(m) => m,
                None => scenes::cube([-0.5; 3], [0.5; 3]),
            }
        }
        _ => {
            // Knife-thin wedge.
            scenes::wedge(r(u, 0.2, 5.0)?, r(u, 0.5, 1.5)?, r(u, 0.2, 1.5)?)
        }
    };
    place(u, m)
}

fn penetration_inner(u: &mut Unstructured<'_>) -> Result<()> {
    let parts = u.int_in_range(1usize..=3)?;
    let mut meshes = Vec::with_capacity(parts);
    for _ in 0..parts {
        meshes.push(closed_part(u)?);
    }
    let mesh = scenes::merge(&meshes);
    // Deeper only for fewer parts: unions of thin parts force many solid leaves to dmax, and
    // one input must stay well under a second even instrumented.
    let dmax = u.int_in_range(5u32..=[7, 6, 5][parts - 1])?;
    let params = BuildParams {
        dmin: u.int_in_range(0..=dmax)?.min(4),
        dmax,
        epsilon: *u.choose(&[0.0, 0.01, 0.1])?,
        lut_depth: u.int_in_range(0..=4)?,
        ..BuildParams::default()
    };
    let Ok((words, _)) = baker::bake(&[MeshRef::from(&mesh)], &params, &()) else {
        return Ok(());
    };
    let view = ProxyView::new(&words).expect("bake gives a valid proxy");
    let gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
    let sides = Sides::new(&[MeshRef::from(&mesh)]);
    let tol = tolerance(&view) as f64;
    let leaf = view.finest_leaf_size();
    let root = view.root_aabb();
    let scene = view.header().root_size;

    let count = u.int_in_range(1usize..=12)?;
    for _ in 0..count {
        let step = step_params(u, scene)?;
        // Valid and physically sane (a huge dt or gravity overflows f32: tested elsewhere).
        let sane = check_params(&step)
            && (1e-6..=1.0).contains(&step.dt)
            && Vec3::from_array(step.gravity).length() <= 1e3 * scene;
        let step = if sane { step } else { StepParams::default() };
        let dt = step.dt;
        // Speed per step: 0.05 leaf .. 2 scenes.
        let per_step = leaf * 10f32.powf(range(u, -1.3, (2.0 * scene / leaf).log10())?);
        let mut position = Vec3::new(
            range(u, root.min.x, root.max.x)?,
            range(u, root.min.y, root.max.y)?,
            range(u, root.min.z, root.max.z)?,
        );
        // Float edge cases: a start on the cell planes of some depth (a face, edge or corner
        // of a cell, where point location breaks ties), and a path along an axis, an exact
        // face or space diagonal, or down a grid line from rest under gravity.
        if u.ratio(1u8, 3)? {
            let d = u.int_in_range(1..=view.header().tree_depth)?;
            for a in 0..3 {
                if u.arbitrary()? {
                    let cells = 1u32 << d;
                    let i = ((position[a] - root.min[a]) / scene * cells as f32)
                        .clamp(0.0, cells as f32) as u32;
                    position[a] = view.plane(a, i << (MAX_DEPTH - d));
                }
            }
        }
        // Where users start: half the particles within 1.5 leaves of the surface, in the shell
        // of surface leaves and beside it, on both sides; a sixth emitted from the surface as
        // the command line emits them (one leaf in front of their face, with the emitter's side).
        let mut emitted_side = None;
        if u.arbitrary()? {
            let mut near = Vec::new();
            gt.nearest_triangles(position.to_array(), &mut near);
            if let Some(t) = near.first() {
                let dir = Vec3::new(
                    range(u, -1.0, 1.0)?,
                    range(u, -1.0, 1.0)?,
                    range(u, -1.0, 1.0)?,
                )
                .normalize_or(Vec3::Y);
                position = t.closest.as_vec3() + dir * range(u, 0.0, 1.5 * leaf)?;
            }
        } else if u.ratio(1u8, 3)? {
            let seed = u.arbitrary::<u64>()?;
            if let Some(e) = emit_surface_for(&view, 1, &[MeshRef::from(&mesh)], None, 0.0, seed)
                .ok()
                .and_then(|e| e.first().copied())
            {
                position = Vec3::from_array(e.position);
                emitted_side = Some(e.side);
            }
        }
        // A restart: some particles first come to rest on the surface (no bounce, full
        // friction, gravity at the scene's scale in a drawn direction), and are then stepped
        // again with the velocity drawn below; every step of both is checked.
        let settle = if u.ratio(1u8, 4)? {
            let down = Vec3::new(
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
            )
            .normalize_or(Vec3::NEG_Y);
            let params = StepParams {
                gravity: (down * 9.81 * scene).to_array(),
                dt: 1.0 / 60.0,
                restitution: 0.0,
                friction: 1.0,
                radius: 0.0,
                _pad: 0,
            };
            Some((params, u.int_in_range(10u32..=90)?))
        } else {
            None
        };
        let speed = per_step / dt;
        // Signs drawn in axis order for the moving axes (a bool from `Unstructured` never fails).
        let mut velocity = match u.int_in_range(0u8..=7)? {
            0 => {
                let axis = u.int_in_range(0usize..=2)?;
                aligned_velocity(1, axis, speed, || !u.arbitrary::<bool>().unwrap_or(true))
            }
            1 | 2 => {
                // Equal magnitudes on two or three axes, so the path meets cell edges and corners.
                let axes = if u.arbitrary()? { 2 } else { 3 };
                let skip = u.int_in_range(0usize..=2)?;
                aligned_velocity(axes, skip, speed, || !u.arbitrary::<bool>().unwrap_or(true))
            }
            3 => Vec3::ZERO,
            _ => {
                Vec3::new(
                    range(u, -1.0, 1.0)?,
                    range(u, -1.0, 1.0)?,
                    range(u, -1.0, 1.0)?,
                )
                .normalize_or(Vec3::Y)
                    * speed
            }
        };
        if !velocity.is_finite() {
            continue;
        }
        let non_finite_input = u.ratio(1u8, 30)?;
        if non_finite_input {
            let i = u.int_in_range(0usize..=2)?;
            let bad = *u.choose(&[f32::NAN, f32::INFINITY, f32::NEG_INFINITY])?;
            if u.arbitrary()? {
                position[i] = bad;
            } else {
                velocity[i] = bad;
            }
        }
        let mut p = Particle::new(position.to_array(), velocity.to_array());
        if non_finite_input {
            let before = p;
            let out = step_particle(&view, &mut p, &step);
            assert_eq!(
                out,
                StepOutcome::Invalid,
                "non-finite particle {before:?} not reported invalid"
            );
            assert!(
                p.flags & FLAG_INVALID != 0,
                "non-finite particle {before:?} not flagged invalid"
            );
            assert_eq!(
                bits(&p)[..7],
                bits(&before)[..7],
                "non-finite particle {before:?} was changed"
            );
            continue;
        }
        // The exact starting side, from the mesh (or the emitter's), and the cage of a particle
        // that starts strictly inside a solid leaf.
        let side = emitted_side.unwrap_or_else(|| sides.side(p.position));
        p.side = side | sides.cage(&view, p.position, side);
        let inside = gt.is_inside(p.position);
        let start = p;
        let steps = u.int_in_range(1u32..=12)?;
        let (settle_params, settle_steps) = settle.unwrap_or((step, 0));
        if settle_steps > 0 {
            p.velocity = [0.0; 3];
        }
        // The same particle stepped with a leaf hint, as the backends step it: same bits.
        let (mut hinted, mut hint) = (p, LeafHint::NONE);
        for s in 0..settle_steps + steps {
            if s == settle_steps && settle_steps > 0 {
                // The rested frame, kicked.
                p.velocity = velocity.to_array();
                hinted.velocity = p.velocity;
            }
            let step = if s < settle_steps {
                settle_params
            } else {
                step
            };
            let before = p;
            let mut pieces = Vec::new();
            step_particle_traced(&view, &mut p, &step, &mut |a, b| pieces.push((a, b)));
            step_particle_hinted(&view, &mut hinted, &step, &mut hint);
            assert_eq!(
                bits(&hinted),
                bits(&p),
                "a leaf hint changed step {s}: {before:?} -> {p:?} without, {hinted:?} with ({step:?})"
            );
            assert!(
                p.flags & FLAG_INVALID == 0 && finite(p.position) && finite(p.velocity),
                "finite particle became invalid at step {s}: {before:?} -> {p:?} ({step:?})"
            );
            // Through the surface and back within a piece of the path: every point of it
            // deeper than the tolerance is on the starting side too. The jump back to the
            // shell entry is not travelled (see `jumps_back`).
            let jumps = jumps_back(&pieces, p.flags);
            for (&(a, b), _) in pieces.iter().zip(&jumps).filter(|(_, &jump)| !jump) {
                if a == b || gt.segment_crossings(a.to_array(), b.to_array()) == 0 {
                    continue;
                }
                if let Some(q) = deep_on_the_other_side(&gt, a, b, inside, tol) {
                    panic!(
                        "PENETRATION: particle that {} a closed mesh went through it in step {s}, {:.4} deep \
                         at {q:?} (tolerance {tol:.4}); start {start:?}, before {before:?}, after {p:?}, params {step:?}, build {params:?}",
                        if inside { "started inside" } else { "started outside" },
                        gt.distance(q)
                    );
                }
            }
            let far = gt.distance_capped(p.position, 2.0 * tol) > tol;
            if far && gt.is_inside(p.position) != inside {
                panic!(
                    "PENETRATION: particle {} a closed mesh ended step {s} {} it, {:.4} from the surface \
                     (tolerance {tol:.4}); start {start:?}, before {before:?}, after {p:?}, params {step:?}, build {params:?}",
                    if inside { "started inside" } else { "started outside" },
                    if inside { "outside" } else { "inside" },
                    gt.distance(p.position)
                );
            }
        }
    }
    // A third of the inputs with bytes left also set the same mesh moving: instances of its
    // proxy posed, turned, scaled and moved as the `moving` target draws them.
    if u.len() >= 64 && u.ratio(1u8, 3)? {
        moving_scene(u, &[&mesh], std::slice::from_ref(&words), scene)?;
    }
    // A third of the inputs with bytes left also drop a crowd of grains of a radius on the
    // mesh with the particle–particle pass on (the harness's `run_check_pairs`).
    if u.len() >= 32 && u.ratio(1u8, 3)? {
        crowd_with_pairs(u, &mesh, scene)?;
    }
    Ok(())
}

/// The mesh baked at dmax 5 for a drawn radius, and 2 to 160 grains of that radius started
/// outside its band anywhere in the box, at up to a scene per step, stepped with the pass on
/// with drawn pass parameters: no grain crosses the offset surface (exact winding number) or
/// comes nearer the mesh than the radius less a leaf diagonal.
fn crowd_with_pairs(u: &mut Unstructured<'_>, mesh: &Mesh, scene: f32) -> Result<()> {
    let radius = scene * range(u, 0.06, 0.25)?;
    let refs = [MeshRef::from(mesh)];
    let Ok(surface) = OffsetSurface::new(&refs, radius, 5, &()) else {
        return Ok(());
    };
    let params = BuildParams {
        dmax: 5,
        ..BuildParams::default()
    };
    let Ok((words, _)) = baker::bake_offset(&surface, &params, &()) else {
        return Ok(());
    };
    let view = ProxyView::new(&words).expect("a radius bake gives a valid proxy");
    let root = view.root_aabb();
    let steps = u.int_in_range(1u32..=8)?;
    let iterations = u.int_in_range(1u32..=8)?;
    let pairs = PairParams {
        restitution: range(u, 0.0, 1.0)?,
        friction: range(u, 0.0, 1.0)?,
        relaxation: range(u, 0.05, 1.0)?,
        stacking: range(u, 0.0, 1.0)?,
        iterations,
        max_iterations: iterations + u.int_in_range(0u32..=8)?,
        substeps: u.int_in_range(0u32..=3)?,
        max_candidates: u.int_in_range(1u32..=64)?,
        follow_speed: u.arbitrary()?,
    };
    let n = u.int_in_range(2usize..=160)?;
    let speed = scene * range(u, 0.0, 60.0)?;
    let mut ps = Vec::with_capacity(n);
    for _ in 0..n {
        let x = [
            range(u, root.min.x, root.max.x)?,
            range(u, root.min.y, root.max.y)?,
            range(u, root.min.z, root.max.z)?,
        ];
        let dir = Vec3::new(
            range(u, -1.0, 1.0)?,
            range(u, -1.0, 1.0)?,
            range(u, -1.0, 1.0)?,
        )
        .normalize_or(Vec3::Y);
        ps.push(Particle::new(
            x,
            (dir * speed * range(u, 0.0, 1.0)?).to_array(),
        ));
    }
    surface.place(&mut ps, Some(&view));
    // Grains `place` could not move out of the band (a start inside a part thinner than 2R,
    // or wedged where bands meet) stay behind the offset surface, inside the band, as the
    // rule for starts says: nearer the mesh than the radius from the start, they are not the
    // guarantee's. The others are.
    ps.retain(|p| surface.outside(p.position));
    if ps.len() < 2 {
        return Ok(());
    }
    let n = ps.len();
    let offset = [surface.mesh_ref()];
    let sides = Sides::new(&offset);
    sides.assign(&mut ps, false);
    sides.cages(&view, &mut ps, false);
    let step = StepParams {
        gravity: [0.0, -9.81 * scene, 0.0],
        radius,
        ..StepParams::default()
    };
    let off_gt = GroundTruth::new(&surface.mesh().positions, &surface.mesh().triangles);
    let mesh_gt = GroundTruth::new(&mesh.positions, &mesh.triangles);
    let clearance = radius as f64 - 3f64.sqrt() * view.finest_leaf_size() as f64;
    let report = run_check_pairs(
        &view, &off_gt, &mut ps, steps, &step, &pairs, &mesh_gt, clearance,
    );
    assert_eq!(
        report.penetrations, 0,
        "PENETRATION with the particle pass: {} of {n} grains (radius {radius}, {} too near the mesh), \
         examples (index, start, end) {:?}, pass {pairs:?}",
        report.penetrations, report.too_near, report.examples
    );
    assert_eq!(
        report.non_finite, 0,
        "a grain became non-finite, pass {pairs:?}"
    );
    Ok(())
}

/// Target `penetration`: closed meshes generated from the input (boxes, slabs thinner than a
/// leaf, wedges and knife edges, low-poly spheres, tori, star prisms, nested shells, convex
/// hulls of random points, unions of overlapping parts), baked at dmax 5–7, and particles at
/// speeds from a fraction of a leaf to two scenes per step (some started on cell planes, some
/// moving along an axis or an exact diagonal, some at rest under gravity, half within 1.5
/// leaves of the surface, inside the shell and beside it, with exact sides from the mesh, some
/// emitted from the surface by the command line's emitter, and a quarter first brought to rest
/// on the surface and then stepped again, a restart from a rested frame): a
/// particle never ends a step on the other side from where it started (by exact winding
/// number) farther than one dmax-leaf diagonal from the surface, nor passes through the other
/// side that deep on the way. A third of the inputs then set the same mesh moving as 1 to 5
/// instances (translating, turning, scaling, as in the `moving` target) and check every step
/// in each instance's frame, and a third drop a crowd of grains of a radius on it with the
/// particle–particle pass on, checked by the harness at that radius (`run_check_pairs`).
pub fn penetration(data: &[u8]) {
    let _ = penetration_inner(&mut Unstructured::new(data));
}

// ---------------------------------------------------------------------------------------------
// mesh_files
// ---------------------------------------------------------------------------------------------

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(data).expect("writing to a Vec");
    e.finish().expect("writing to a Vec")
}

fn check_mesh(name: &str, bytes: &[u8]) {
    if let Ok((mesh, _report)) = parse_mesh(name, bytes, None) {
        assert!(
            !mesh.triangles.is_empty(),
            "{name}: parse_mesh returned a mesh with no triangles"
        );
        for (i, p) in mesh.positions.iter().enumerate() {
            assert!(
                finite(*p),
                "{name}: parse_mesh returned non-finite vertex {i}: {p:?}"
            );
        }
        for (i, t) in mesh.triangles.iter().enumerate() {
            assert!(
                t.iter().all(|&k| (k as usize) < mesh.positions.len()),
                "{name}: parse_mesh returned triangle {i} {t:?} with an index out of range ({} vertices)",
                mesh.positions.len()
            );
        }
    }
}

fn check_particles(name: &str, bytes: &[u8]) {
    let Ok(cloud) = parse_particles(name, bytes) else {
        return;
    };
    assert_eq!(
        cloud.extra.values.len(),
        cloud.extra.properties.len() * cloud.particles.len(),
        "{name}: extra values do not match properties × particles"
    );
    if !cloud.has_side {
        assert!(
            cloud.particles.iter().all(|p| p.side == SIDE_FRONT),
            "{name}: a file without side gave a particle a side"
        );
    }
    // What was read writes back and reads back the same, in both encodings.
    for enc in [PlyEncoding::BinaryLittleEndian, PlyEncoding::Ascii] {
        let bytes = encode_particles(&cloud, enc);
        let again = parse_particles("roundtrip.ply", &bytes)
            .unwrap_or_else(|e| panic!("{name}: particles read from the fuzz input do not read back after writing ({enc:?}): {e}"));
        assert_eq!(
            again.particles.len(),
            cloud.particles.len(),
            "{name}: round trip changed the particle count"
        );
        // Exact, except that a NaN may come back as another NaN (ascii writes `nan`).
        let canon = |p: &Particle| {
            let mut q = *p;
            for c in q.position.iter_mut().chain(q.velocity.iter_mut()) {
                if c.is_nan() {
                    *c = f32::NAN;
                }
            }
            bits(&q)
        };
        for (a, b) in cloud.particles.iter().zip(&again.particles) {
            assert_eq!(
                canon(a),
                canon(b),
                "{name}: round trip ({enc:?}) changed a particle"
            );
        }
        assert_eq!(
            again.extra.properties, cloud.extra.properties,
            "{name}: round trip changed the extra properties"
        );
        let same_values = again
            .extra
            .values
            .iter()
            .zip(&cloud.extra.values)
            .all(|(a, b)| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
        assert!(
            same_values && again.extra.values.len() == cloud.extra.values.len(),
            "{name}: round trip ({enc:?}) changed extra values"
        );
    }
}

/// Target `mesh_files`: arbitrary bytes into the mesh readers (PLY, OBJ, STL, by name or by
/// content, gzipped or not) and the particle reader: `Ok` or `Err`, never a panic; a mesh
/// read has triangles, finite vertices and indices in range; particles read write back and
/// read back unchanged.
pub fn mesh_files(data: &[u8]) {
    let Some((&selector, rest)) = data.split_first() else {
        return;
    };
    let ext = ["ply", "obj", "stl", "bin"][(selector & 3) as usize];
    let compressed;
    let (bytes, name) = if selector & 4 != 0 {
        compressed = gzip(rest);
        (&compressed[..], format!("fuzz.{ext}.gz"))
    } else {
        (rest, format!("fuzz.{ext}"))
    };
    if selector & 8 != 0 {
        check_particles(&name, bytes);
    } else {
        check_mesh(&name, bytes);
    }
    if selector & 16 != 0 {
        // The raw bytes too (a gzip stream the fuzzer wrote itself, corrupt or not).
        check_mesh("raw", rest);
        check_particles("raw.ply", rest);
    }
}

// ---------------------------------------------------------------------------------------------
// scene_files
// ---------------------------------------------------------------------------------------------

/// The `scene_files` target: the first byte picks how the rest is read: a `.gltf` (bit 0
/// clear) or a `.glb` (set), or a baked scene (bit 1). No input may panic. A glTF that reads
/// must sample finite, valid poses for every instance at any time, and list its instances; a
/// baked scene that reads must encode to bytes that read back to the same scene.
pub fn scene_files(data: &[u8]) {
    use octoproxy_cpu::gltf::{parse_gltf, BakedScene};
    let Some((&selector, rest)) = data.split_first() else {
        return;
    };
    if selector & 2 != 0 {
        if let Ok(baked) = BakedScene::parse("fuzz.octoscene", rest) {
            let again = BakedScene::parse("again.octoscene", &baked.encode())
                .expect("a baked scene's own bytes read back");
            assert_eq!(again.encode(), baked.encode(), "a baked scene round-trips");
            check_poses(|t| baked.poses_at(t), baked.duration());
        }
        return;
    }
    let name = if selector & 1 != 0 {
        "fuzz.glb"
    } else {
        "fuzz.gltf"
    };
    // No base directory: external buffers are refused, never opened.
    if let Ok((scene, _warnings)) = parse_gltf(name, rest, None) {
        let _ = scene.list_instances();
        check_poses(|t| scene.poses_at(t), scene.duration());
        for m in &scene.meshes {
            assert!(m.mesh.positions.iter().flatten().all(|c| c.is_finite()));
            let n = m.mesh.positions.len() as u32;
            assert!(m.mesh.triangles.iter().flatten().all(|&i| i < n));
        }
    }
}

/// Poses at a few times, before, within and after the animation: valid where they sample (a
/// time can be refused with an error naming the node, never answered with a bad pose).
fn check_poses<E>(poses_at: impl Fn(f64) -> Result<Vec<octoproxy_core::Pose>, E>, duration: f64) {
    assert!(
        duration.is_finite() && duration >= 0.0,
        "duration {duration}"
    );
    for t in [-1.0, 0.0, duration * 0.37, duration, duration + 1.0] {
        if let Ok(poses) = poses_at(t) {
            for p in poses {
                assert!(p.is_valid(), "an invalid pose {p:?} at {t}");
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// moving
// ---------------------------------------------------------------------------------------------

/// The shapes of the `moving` target, each baked once at dmax 5 and 6: a box, a ball, a slab
/// thinner than a dmax-5 leaf, a torus and a star prism.
fn moving_shapes() -> &'static [(Mesh, [Vec<u32>; 2])] {
    static SHAPES: OnceLock<Vec<(Mesh, [Vec<u32>; 2])>> = OnceLock::new();
    SHAPES.get_or_init(|| {
        [
            scenes::cube([-0.4; 3], [0.4; 3]),
            scenes::uv_sphere([0.0; 3], 0.45, 16, 8),
            scenes::slab([0.0; 3], [1.0, 0.02, 0.8]),
            scenes::torus([0.0; 3], 0.4, 0.15, 20, 10),
            scenes::star_prism(5, 0.5, 0.2, 0.3),
        ]
        .into_iter()
        .map(|m| {
            let words = [5, 6].map(|dmax| crate::moving::bake_mesh(&m, dmax));
            (m, words)
        })
        .collect()
    })
}

fn moving_inner(u: &mut Unstructured<'_>) -> Result<()> {
    let shapes = moving_shapes();
    let dmax = u.int_in_range(0usize..=1)?;
    let meshes: Vec<&Mesh> = shapes.iter().map(|(m, _)| m).collect();
    let proxies: Vec<Vec<u32>> = shapes.iter().map(|(_, w)| w[dmax].clone()).collect();
    moving_scene(u, &meshes, &proxies, 1.0)
}

/// A moving scene drawn from the input over the given closed meshes and their proxies (each
/// about `size` wide): 1 to 5 instances in a region three sizes wide, most moving, turning and
/// some scaling, one in 40 a hostile pose that must be refused or take part; particles outside
/// them all at up to the region's width a step; every step checked against each instance's
/// mesh by exact ground truth, and every hit record well formed.
fn moving_scene(
    u: &mut Unstructured<'_>,
    meshes: &[&Mesh],
    proxies: &[Vec<u32>],
    size: f32,
) -> Result<()> {
    use crate::moving::{outside_all, pose, scene_check, Tally};
    use glam::Quat;
    use octoproxy_core::{Backend, Pose};
    use octoproxy_cpu::{CpuBackend, Scene, SceneBuildError};

    let mut scene = Scene::new();
    for w in proxies {
        scene
            .add_proxy(w.clone())
            .expect("the shapes bake to valid proxies");
    }
    // Instances: a proxy, a start pose, and a motion per step (velocity in scene widths, a
    // turn about an axis, a growth), or a hostile pose that must be refused.
    let n = u.int_in_range(1u32..=5)?;
    let region = 3.0 * size;
    let last_proxy = proxies.len() as u32 - 1;
    let mut motions = Vec::new();
    // A hostile pose that passed the pose checks (a scale of 1e-30, a translation of 1e30)
    // may still be refused when the scene is prepared: f32 cannot resolve a leaf there.
    let mut hostile_accepted = false;
    for _ in 0..n {
        let proxy = u.int_in_range(0u32..=last_proxy)?;
        let t = Vec3::new(
            range(u, 0.0, region)?,
            range(u, 0.0, region)?,
            range(u, 0.0, region)?,
        );
        let axis = Vec3::new(
            range(u, -1.0, 1.0)?,
            range(u, -1.0, 1.0)?,
            range(u, -1.0, 1.0)?,
        )
        .normalize_or(Vec3::Y);
        let q = Quat::from_axis_angle(axis, range(u, 0.0, std::f32::consts::TAU)?);
        let s = range(u, 0.5, 1.5)?;
        if u.ratio(1u8, 40)? {
            // A hostile pose: a clear error, never a panic, and the scene is unchanged.
            let bad = Pose {
                translation: [wild_f32(u, 10.0 * size)?, 0.0, 0.0],
                scale: wild_f32(u, 2.0)?,
                rotation: [wild_f32(u, 1.0)?, 0.0, 0.0, 1.0],
            };
            let before = scene.instances().len();
            if let Err(e) = scene.add_instance(proxy, bad) {
                assert!(matches!(e, SceneBuildError::BadPose { .. }), "{e}");
                assert_eq!(scene.instances().len(), before);
            } else {
                // Accepted: it was a valid pose after all; it takes part.
                hostile_accepted = true;
                motions.push((Vec3::ZERO, axis, 0.0, 0.0));
            }
            continue;
        }
        scene
            .add_instance(proxy, pose(t.to_array(), q, s))
            .expect("a valid pose");
        let moves = u.arbitrary::<bool>()?;
        let velocity = if moves {
            Vec3::new(
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
                range(u, -1.0, 1.0)?,
            ) * range(u, 0.0, 2.0 * region)?
        } else {
            Vec3::ZERO
        };
        let turn = if moves {
            range(u, 0.0, 60.0)?.to_radians()
        } else {
            0.0
        };
        let grow = if moves && u.ratio(1u8, 4)? {
            range(u, -0.05, 0.05)?
        } else {
            0.0
        };
        motions.push((velocity, axis, turn, grow));
    }
    let mut check = scene_check(meshes, proxies);
    let count = u.int_in_range(1usize..=48)?;
    let mut particles = Vec::new();
    for _ in 0..count {
        let x = Vec3::new(
            range(u, -0.5 * size, region + 0.5 * size)?,
            range(u, -0.5 * size, region + 0.5 * size)?,
            range(u, -0.5 * size, region + 0.5 * size)?,
        );
        let v = Vec3::new(
            range(u, -1.0, 1.0)?,
            range(u, -1.0, 1.0)?,
            range(u, -1.0, 1.0)?,
        ) * range(u, 0.0, region * 60.0)?;
        particles.push(Particle::new(x.to_array(), v.to_array()));
    }
    let particles = outside_all(particles, &check, scene.instances());
    if particles.is_empty() {
        return Ok(());
    }
    let params = StepParams {
        gravity: [0.0, -range(u, 0.0, 30.0)? * size, 0.0],
        dt: 1.0 / 60.0,
        restitution: range(u, 0.0, 1.0)?,
        friction: range(u, 0.0, 1.0)?,
        radius: 0.0,
        _pad: 0,
    };
    let mut cpu = CpuBackend::new();
    cpu.upload_particles(&particles).expect("upload");
    let mut tally = Tally::default();
    let mut before = particles;
    let steps = u.int_in_range(1u32..=10)?;
    for _ in 0..steps {
        for (i, &(velocity, axis, turn, grow)) in motions.iter().enumerate() {
            let inst = scene.instances()[i];
            if inst.flags & octoproxy_core::scene::INSTANCE_LIVE == 0 {
                continue;
            }
            let p = inst.end;
            let t = Vec3::from_array(p.translation) + velocity * params.dt;
            let q = Quat::from_axis_angle(axis, turn) * Quat::from_array(p.rotation);
            let s = (p.scale * (1.0 + grow)).clamp(0.3, 2.0);
            scene
                .move_to(i as u32, pose(t.to_array(), q, s))
                .expect("a valid pose");
        }
        match scene.prepare() {
            Ok(()) => {}
            Err(SceneBuildError::TooManyOverlapping { .. }) => return Ok(()),
            Err(SceneBuildError::Scene(octoproxy_core::SceneError::TooFarOut { .. }))
                if hostile_accepted =>
            {
                return Ok(())
            }
            Err(e) => panic!("a scene of valid poses was refused: {e}"),
        }
        let instances = scene.instances().to_vec();
        scene
            .step(&mut cpu, &params, true)
            .expect("a prepared scene steps");
        let after = cpu.particles().to_vec();
        for (p, h) in after.iter().zip(cpu.hits()) {
            assert!(
                p.flags & FLAG_INVALID == 0,
                "a finite particle became invalid: {p:?}"
            );
            if h.instance >= 0 {
                let n = Vec3::from_array(h.normal);
                assert!(
                    (n.length() - 1.0).abs() < 1e-3 && h.speed >= 0.0 && (0.0..=1.0).contains(&h.t),
                    "a bad hit record {h:?}"
                );
            } else {
                assert_eq!(*h, octoproxy_core::Hit::NONE);
            }
        }
        tally.add(&check.step(&instances, &before, &after, None));
        assert_eq!(
            tally.penetrations, 0,
            "PENETRATION in a moving scene ({params:?}, motions {motions:?}): {:?}",
            tally.examples
        );
        before = after;
    }
    Ok(())
}

/// Target `moving`: scenes of 1 to 5 instances of closed shapes (a box, a ball, a slab thinner
/// than a leaf, a torus, a star) baked at dmax 5 or 6, placed and posed from the input, most
/// moving at up to two scene widths a step, turning up to 60 degrees a step and some scaling,
/// with particles outside them at up to a whole scene a step: no particle ends a step inside an
/// instance's mesh deeper than a leaf diagonal, nor passes through one on a straight path (in
/// the instance's frame, by exact ground truth); hit records are well formed; a hostile pose
/// is refused with a clear error and leaves the scene as it was.
pub fn moving(data: &[u8]) {
    let _ = moving_inner(&mut Unstructured::new(data));
}
