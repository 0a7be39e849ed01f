//! The moving-scene campaign (see `octoproxy_tests::moving`): random scenes of boxes, balls,
//! tori, thin slabs and stars, a third static and the rest moving up to `SPEED` scene widths
//! a step and turning up to `TURN` degrees a step, some scaling, with particles on a lattice
//! around them; every step checked against exact ground truth in every instance's frame.
//! `cargo run --release -p octoproxy-tests --example moving [-- SCENES SPEED TURN DMAX]`.

use octoproxy_tests::moving::random_scene;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: f32| {
        args.get(i)
            .map_or(default, |a| a.parse().expect("a number"))
    };
    let scenes = arg(0, 40.0) as u64;
    let speed = arg(1, 1.0);
    let turn = arg(2, 45.0);
    let dmax = arg(3, 7.0) as u32;
    let (mut penetrations, mut steps, mut collisions, mut crushed, mut refused) = (0, 0, 0, 0, 0);
    for seed in 1..=scenes {
        let r = random_scene(seed, 12, dmax, speed, turn, 16, 30);
        if r.refused {
            refused += 1;
            println!("scene {seed}: refused (too many shells at one point)");
            continue;
        }
        println!(
            "scene {seed}: {} instances ({} moving, fastest {:.2} widths and {:.0} degrees a step): {} penetrations, {} crushed, {} collisions in {} particle-steps",
            r.instances, r.moving, r.fastest, r.fastest_turn, r.tally.penetrations, r.tally.crushed, r.tally.collisions, r.tally.particle_steps
        );
        for e in &r.tally.examples {
            println!("  {e}");
        }
        penetrations += r.tally.penetrations;
        steps += r.tally.particle_steps;
        collisions += r.tally.collisions;
        crushed += r.tally.crushed;
    }
    println!("total: {penetrations} penetrations, {crushed} crushed, {collisions} collisions in {steps} particle-steps over {scenes} scenes ({refused} refused)");
}
