//! The prepare-once, re-solve loop of image-guided surgery on `cases/brain-shift.toml`: the
//! model is prepared once, solved from the unloaded state, then solved again from that
//! equilibrium after the measured cortical displacements grow by 10 %, and the warm answer
//! is checked against a cold solve of the same inputs.
//!
//! Run: `cargo run --release --example resolve [SCENE] [MEASURED-NAME]`

use hytled::simulation::Session;

fn main() -> hytled::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).map_or("cases/brain-shift.toml", String::as_str);
    let name = args.get(2).map_or("exposed", String::as_str);
    let overrides: Vec<String> = args.iter().skip(3).cloned().collect();
    let scene = hytled::scene::load(path.as_ref(), &overrides)?;
    let mut session = Session::new(scene)?;
    println!(
        "prepared {} nodes in {:.3} s",
        session.prepared().model.nodes().len(),
        session.prepare_seconds()
    );

    let first = session.solve()?;
    println!(
        "first solve (cold): {} steps, {:.3} s",
        first.output.steps, first.summary.wall_seconds.solve
    );

    // New measurements at the same points: 10 % more displacement.
    let mut u = session.measured_displacements(name)?;
    u.iter_mut().flatten().for_each(|c| *c *= 1.1);
    session.set_measured(name, &u)?;
    let warm = session.solve()?;
    println!(
        "re-solve (warm: {}): {} steps, {:.3} s",
        warm.warm, warm.output.steps, warm.summary.wall_seconds.solve
    );

    let cold = session.solve_cold()?;
    println!(
        "the same inputs from the unloaded state: {} steps, {:.3} s",
        cold.output.steps, cold.summary.wall_seconds.solve
    );
    let diff = warm
        .output
        .u
        .iter()
        .zip(&cold.output.u)
        .map(|(a, b)| (a - b).amax())
        .fold(0.0, f64::max);
    let largest = cold.output.u.iter().map(|a| a.amax()).fold(0.0, f64::max);
    println!(
        "largest difference warm - cold: {diff:.3e} m (largest displacement {largest:.3e} m, relaxation tolerance {:.1e} m)",
        session.scene().solver.tolerance
    );
    for (probe, r) in &warm.summary.probes {
        let c = &cold.summary.probes[probe];
        println!(
            "probe {probe}: warm {:?} m, cold {:?} m",
            r.displacement, c.displacement
        );
    }
    Ok(())
}
