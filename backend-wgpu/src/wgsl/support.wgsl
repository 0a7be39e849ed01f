// A grain's support on the scene (core's `pairs::pair_support`), shared by the pass's module
// (a proxy's grains) and the scene module (a scene's grains, in an instance's frame).

// `load_header` must have run (the support is a leaf of the proxy).
// A grain the shell rule stopped has no hint: its leaf is found by descent (Rust's).
fn pair_support(p: Particle, hint: vec2<u32>) -> vec4<f32> {
    if (p.side & ~SIDE_MASK) != 0u {
        return vec4<f32>(0.0);
    }
    var leaf = LeafOption();
    if (hint.y & HINT_SURFACE) != 0u {
        leaf = leaf_hint_leaf(hint, p.position);
    } else if (p.flags & FLAG_BLOCKED) != 0u {
        leaf = locate_leaf_toward(p.position, vec3<f32>(0.0));
        leaf.some = leaf.some && leaf.value.kind == LEAF_SURFACE && !leaf.value.two_sided;
    }
    if !leaf.some {
        return vec4<f32>(0.0);
    }
    var n = leaf.value.normal;
    var sign = 1.0;
    if p.side == SIDE_BACK {
        n = -leaf.value.normal;
        sign = -1.0;
    }
    let centre = (leaf.value.aabb.min + leaf.value.aabb.max) * 0.5;
    let above = (dot3(leaf.value.normal, p.position - centre) - leaf.value.plane_offset) * sign;
    let reach = (leaf.value.aabb.max.x - leaf.value.aabb.min.x) * PAIR_SUPPORT_REACH;
    let blocked = (p.flags & FLAG_BLOCKED) != 0u;
    if !(above <= reach) && !blocked {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(n, select(1.0, PAIR_WEDGED, blocked));
}

