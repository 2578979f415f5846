//! Issue 43, prepare once and solve again: changes made on a prepared model between solves
//! (boundary values, measured displacements, tool positions, load factors) are taken, checked
//! against the exact cube (docs/reference.md) and against cold solves of scenes written with the new
//! values; warm-started relaxations reach the cold answer in a fraction of its steps; changes
//! the model cannot take are errors.

mod common;
use common::{largest_difference, path, warnings_with};

use std::path::PathBuf;

use hytled::simulation::{prepare, settings, solve, Session};

const A: f64 = 1.11574668; // docs/reference.md: lateral stretch of the cube compressed by 20 %
const F_EXACT: f64 = -7.63269; // docs/reference.md: top force of the cube compressed by 20 %, N

fn folder(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hytled-resolve-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `x, y, z, ux, uy, uz` of `scale` x the exact field u = ((a - 1) x, (a - 1) y, -0.2 z) at the
/// top face's 5 x 5 nodes (25 mm grid).
fn exact_top(scale: f64) -> (String, Vec<[f64; 3]>) {
    let mut s = String::from("x,y,z,ux,uy,uz\n");
    let mut u = Vec::new();
    for j in 0..=4 {
        for i in 0..=4 {
            let (x, y) = (0.025 * i as f64, 0.025 * j as f64);
            let v = [(A - 1.0) * x * scale, (A - 1.0) * y * scale, -0.02 * scale];
            s += &format!("{x},{y},0.1,{},{},{}\n", v[0], v[1], v[2]);
            u.push(v);
        }
    }
    (s, u)
}

/// The cube case's text without its `[boundaries.top]` table, with `insert` in its place,
/// written to `name.toml` in a folder of this test.
fn cube_without_top(name: &str, insert: &str) -> PathBuf {
    let text = std::fs::read_to_string(path("cases/cube-compression.toml")).unwrap();
    let start = text.find("[boundaries.top]").unwrap();
    let end = start + text[start..].find("\n\n").unwrap();
    let file = folder(name).join(format!("{name}.toml"));
    std::fs::write(&file, format!("{}{insert}{}", &text[..start], &text[end..])).unwrap();
    file
}

/// The cube case at 25 mm with its top face driven by `[measured.top]` at `scale` x the exact
/// field, and `extra` overrides.
fn measured_cube(name: &str, scale: f64, extra: &[&str]) -> hytled::scene::Scene {
    std::fs::write(folder(name).join("top.csv"), exact_top(scale).0).unwrap();
    let file = cube_without_top(
        name,
        "[measured.top]\nfile = \"top.csv\"\ntolerance = 0.003\ncurve = \"smooth\"\n",
    );
    let mut o: Vec<String> = vec![
        "discretization.size=0.025".into(),
        "solver.tolerance=1e-9".into(),
        "references={}".into(),
    ];
    o.extend(extra.iter().map(|s| s.to_string()));
    hytled::scene::load(&file, &o).unwrap_or_else(|e| panic!("{e}"))
}

/// The silent failure: through `prepare` and `solve`, new `node_values` on the
/// model's measured boundary were ignored (the answer stayed that of the first values). Now the
/// next solve takes them: half the exact field, then the exact field, which gives the exact
/// cube (top force and corner).
#[test]
fn node_values_changed_on_the_model_are_taken_by_the_next_solve() {
    let scene = measured_cube("node-values", 0.5, &[]);
    let mut prep = prepare(&scene).unwrap();
    let s = settings(&scene, false);
    let half = solve(&mut prep, &s).unwrap();
    let k = prep
        .model
        .boundaries()
        .iter()
        .position(|b| b.name == "top")
        .unwrap();
    let f_half = prep.model.reactions(&half.f_int)[k].z;
    // Written on the model directly, as a Rust user would.
    let b = &mut prep.model.boundaries_mut()[k];
    let exact: Vec<[f64; 3]> = b
        .nodes
        .iter()
        .map(|&i| {
            let x = prep.mesh.nodes[i];
            [(A - 1.0) * x.x, (A - 1.0) * x.y, -0.02]
        })
        .collect();
    b.node_values = Some(exact);
    let full = solve(&mut prep, &s).unwrap();
    let f = prep.model.reactions(&full.f_int)[k].z;
    let corner = prep
        .mesh
        .nodes
        .iter()
        .position(|x| (x - nalgebra::Vector3::new(0.1, 0.1, 0.1)).norm() < 1e-12)
        .unwrap();
    let ux = full.u[corner].x;
    println!("half {f_half:.6} N, full {f:.6} N, corner u_x {ux:.6e} m");
    assert!(
        ((f - F_EXACT) / F_EXACT).abs() < 1e-5,
        "force {f} N against the exact {F_EXACT} N"
    );
    assert!(((ux - (A - 1.0) * 0.1) / ((A - 1.0) * 0.1)).abs() < 1e-5);
    assert!(f_half > 0.6 * F_EXACT, "half the compression: {f_half} N");
}

/// New measurements through the session (one per measured point, in the file's order), on
/// nodes the boundary imposes directly (fe) and through the meshless correction (SEBCIEM):
/// the warm re-solve gives the answer of a scene prepared with those measurements, and for the
/// exact field the exact cube.
#[test]
fn new_measurements_give_the_answer_of_a_scene_written_with_them() {
    for (method, exact_tol) in [
        (&["discretization.method=fe"][..], 1e-5),
        (&["discretization.method=meshless"][..], 3e-3),
    ] {
        let scene = measured_cube(&format!("m-{}", method[0].len()), 0.5, method);
        let mut session = Session::new(scene).unwrap();
        let first = session.solve().unwrap();
        assert!(!first.warm);
        assert_eq!(session.measured_points("top").unwrap().len(), 25);
        session.set_measured("top", &exact_top(1.0).1).unwrap();
        let warm = session.solve().unwrap();
        assert!(
            warm.warm,
            "{method:?}: the re-solve starts from the first equilibrium"
        );
        let f = warm.summary.reactions["top"][2];
        let ux = warm.summary.probes["corner"].displacement[0];
        println!(
            "{method:?}: first {} steps, warm {} steps, force {f:.6} N, corner {ux:.6e} m",
            first.output.steps, warm.output.steps
        );
        assert!(
            ((f - F_EXACT) / F_EXACT).abs() < exact_tol,
            "{method:?}: {f}"
        );
        assert!(((ux - (A - 1.0) * 0.1) / ((A - 1.0) * 0.1)).abs() < exact_tol);
        // The same measurements written in the scene's file, solved cold.
        let direct = measured_cube(&format!("d-{}", method[0].len()), 1.0, method);
        let mut cold = Session::new(direct).unwrap();
        let c = cold.solve().unwrap();
        let d = largest_difference(&warm.output.u, &c.output.u);
        assert!(d < 1e-8, "{method:?}: warm and cold differ by {d:e} m");
    }
}

/// A rigid plate moved further between solves, and gravity scaled: each warm re-solve gives
/// the answer of the scene written with the new value (the plate at 20 %: the exact cube).
#[test]
fn tool_positions_and_load_factors_change_between_solves() {
    let plate = |z: f64| {
        format!(
            "contact.plate={{ shape = \"plane\", point = [0.0, 0.0, 0.1], normal = [0.0, 0.0, -1.0], motion = [0.0, 0.0, {z}] }}"
        )
    };
    let scene_with = |z: f64| {
        let file = cube_without_top("plate", "");
        let o: Vec<String> = vec![
            "references={}".into(),
            "discretization.size=0.025".into(),
            "solver.tolerance=1e-9".into(),
            plate(z),
        ];
        hytled::scene::load(&file, &o).unwrap()
    };
    let mut session = Session::new(scene_with(-0.01)).unwrap();
    let first = session.solve().unwrap();
    assert_eq!(session.tool_motion("plate").unwrap(), [0.0, 0.0, -0.01]);
    session.set_tool_motion("plate", [0.0, 0.0, -0.02]).unwrap();
    let warm = session.solve().unwrap();
    let f = warm.summary.reactions["plate"][2];
    println!(
        "plate: first {} steps ({:.6} N), warm {} steps, {f:.6} N",
        first.output.steps, first.summary.reactions["plate"][2], warm.output.steps
    );
    assert!(warm.warm);
    assert!(
        ((f - F_EXACT) / F_EXACT).abs() < 1e-5,
        "{f} N against {F_EXACT} N"
    );

    // Gravity on the cube held at its base: twice the load, warm, against the scene with 2 g.
    let gravity = |g: f64| {
        let o: Vec<String> = vec![
            "references={}".into(),
            "discretization.size=0.025".into(),
            "solver.tolerance=1e-9".into(),
            "boundaries.top=".into(),
            format!("loads.g={{ gravity = [0.0, 0.0, {g}] }}"),
        ];
        o
    };
    let load = |o: Vec<String>| {
        let file = cube_without_top("gravity", "");
        let o: Vec<String> = o.into_iter().filter(|s| s != "boundaries.top=").collect();
        hytled::scene::load(&file, &o).unwrap()
    };
    let mut session = Session::new(load(gravity(-9.81))).unwrap();
    session.solve().unwrap();
    session.set_load_factor("g", 2.0).unwrap();
    assert_eq!(session.load_factor("g").unwrap(), 2.0);
    let warm = session.solve().unwrap();
    let mut cold = Session::new(load(gravity(-19.62))).unwrap();
    let c = cold.solve().unwrap();
    let d = largest_difference(&warm.output.u, &c.output.u);
    let w = warm.summary.reactions["bottom"][2];
    let r = c.summary.reactions["bottom"][2];
    println!(
        "gravity x2: warm {} steps, cold {} steps, reactions {w:.6} / {r:.6} N, |du| {d:.3e} m",
        warm.output.steps, c.output.steps
    );
    assert!(warm.warm);
    assert!(d < 1e-8, "{d:e} m");
    assert!(((w - r) / r).abs() < 1e-6);
}

/// A uniform boundary's new value through the session, and the changes a prepared model
/// cannot take, each an error that says what to do.
#[test]
fn changes_the_model_cannot_take_are_errors() {
    let scene = hytled::scene::load(
        &path("cases/cube-compression.toml"),
        &["discretization.size=0.025".into()],
    )
    .unwrap();
    let mut session = Session::new(scene).unwrap();
    let s20 = session.solve().unwrap();
    session
        .set_displacement("top", [None, None, Some(-0.01)])
        .unwrap();
    let s10 = session.solve().unwrap();
    assert!(s10.warm);
    let (f20, f10) = (
        s20.summary.reactions["top"][2],
        s10.summary.reactions["top"][2],
    );
    // Half the compression: a bit less than half the force (the neo-Hookean cube stiffens).
    assert!(
        f10.abs() > 0.4 * f20.abs() && f10.abs() < 0.5 * f20.abs(),
        "{f10} vs {f20}"
    );

    let msg = |e: hytled::Error| e.to_string();
    let e = msg(session
        .set_displacement("top", [Some(0.001), None, None])
        .unwrap_err());
    assert!(e.contains("leaves its x component free"), "{e}");
    let e = msg(session
        .set_displacement("lid", [None, None, Some(0.0)])
        .unwrap_err());
    assert!(
        e.contains("no boundary named 'lid'") && e.contains("symmetry_x"),
        "{e}"
    );
    let e = msg(session
        .set_displacement("top", [None, None, Some(f64::NAN)])
        .unwrap_err());
    assert!(e.contains("not finite"), "{e}");
    let e = msg(session.set_measured("top", &[[0.0; 3]]).unwrap_err());
    assert!(e.contains("not a [measured] boundary"), "{e}");
    let e = msg(session.set_load_factor("gravity", 2.0).unwrap_err());
    assert!(e.contains("no load named 'gravity'"), "{e}");
    let e = msg(session.set_tool_motion("plate", [0.0; 3]).unwrap_err());
    assert!(e.contains("no [contact]"), "{e}");

    // The model's own boundaries: a new selection is refused at the next solve.
    session.model_mut().boundaries_mut()[0].nodes.pop();
    let e = msg(session
        .solve()
        .err()
        .expect("a changed selection must be refused"));
    assert!(
        e.contains("its nodes changed") && e.contains("prepare the model again"),
        "{e}"
    );

    // A measured boundary takes one displacement per point.
    let mut m = Session::new(measured_cube("count", 1.0, &[])).unwrap();
    let e = msg(m.set_measured("top", &[[0.0; 3]; 3]).unwrap_err());
    assert!(
        e.contains("3 displacements for its 25 measured points"),
        "{e}"
    );

    // A warm start belongs to relaxation.
    let dynamic = hytled::scene::load(
        &path("cases/cube-compression.toml"),
        &[
            "discretization.size=0.025".into(),
            "solver.mode=\"dynamic\"".into(),
            "solver.duration=0.01".into(),
        ],
    )
    .unwrap();
    let mut prep = prepare(&dynamic).unwrap();
    let mut s = settings(&dynamic, false);
    s.warm_start = Some(hytled::solver::WarmStart {
        u: vec![nalgebra::Vector3::zeros(); prep.model.nodes().len()],
        omega_min: None,
    });
    let e = msg(solve(&mut prep, &s).unwrap_err());
    assert!(e.contains("dynamic run"), "{e}");
}

/// The figure: cases/brain-shift.toml (3,520 nodes, fe tet4-anp, Ogden brain under
/// gravity, measured cortical displacements). After the first solve, the measurements grow by
/// 10 %; the warm re-solve ends within the relaxation tolerance of a cold solve of the same
/// inputs in at most a third of its steps.
#[test]
fn a_ten_percent_change_of_the_brain_shift_measurements_resolves_warm() {
    // The relaxation's warm start (the case itself solves statically).
    let scene = hytled::scene::load(
        &path("cases/brain-shift.toml"),
        &["solver.mode=relaxation".into()],
    )
    .unwrap();
    let tolerance = scene.solver.tolerance;
    let mut session = Session::new(scene).unwrap();
    let first = session.solve().unwrap();
    let mut u = session.measured_displacements("exposed").unwrap();
    u.iter_mut().flatten().for_each(|c| *c *= 1.1);
    session.set_measured("exposed", &u).unwrap();
    let warm = session.solve().unwrap();
    let cold = session.solve_cold().unwrap();
    let d = largest_difference(&warm.output.u, &cold.output.u);
    println!(
        "brain-shift: first {} steps {:.2} s; +10 %: warm {} steps {:.2} s, cold {} steps {:.2} s; |u_warm - u_cold| {d:.3e} m",
        first.output.steps,
        first.summary.wall_seconds.solve,
        warm.output.steps,
        warm.summary.wall_seconds.solve,
        cold.output.steps,
        cold.summary.wall_seconds.solve
    );
    assert!(warm.warm && warm.summary.converged && cold.summary.converged);
    assert!(
        d <= tolerance,
        "{d:e} m against the tolerance {tolerance:e} m"
    );
    assert!(
        3 * warm.output.steps <= cold.output.steps,
        "warm {} steps, cold {}",
        warm.output.steps,
        cold.output.steps
    );
}

/// Issue 56: a warm re-solve after a tool moved further than it may jump is solved from the
/// unloaded state (a warm start put the ball at its final place at once: it passed through the
/// cube's top, "converged" with reaction 0); a small move stays warm.
#[test]
fn a_tool_moved_far_is_not_warm_started_through_the_surface() {
    let file = cube_without_top("ball", "");
    let o: Vec<String> = vec![
        "references={}".into(),
        "discretization.size=0.025".into(),
        "contact.ball={ shape = \"sphere\", center = [0.05, 0.05, 0.12], radius = 0.02, motion = [0.0, 0.0, -0.024] }".into(),
    ];
    let mut session = Session::new(hytled::scene::load(&file, &o).unwrap()).unwrap();
    let first = session.solve().unwrap();
    let f0 = first.summary.reactions["ball"][2];
    assert!(f0 > 0.0, "the ball pushes: {f0}");
    session.set_tool_motion("ball", [0.0, 0.0, -0.027]).unwrap();
    let small = session.solve().unwrap();
    assert!(small.warm, "a 3 mm move of a 20 mm ball stays warm");
    let cold = session.solve_cold().unwrap();
    let (fw, fc) = (
        small.summary.reactions["ball"][2],
        cold.summary.reactions["ball"][2],
    );
    println!(
        "ball: {f0} N at 24 mm; at 27 mm warm {fw} N ({} steps), cold {fc} N ({} steps)",
        small.output.steps, cold.output.steps
    );
    assert!(((fw - fc) / fc).abs() < 0.01, "warm {fw} N, cold {fc} N");
    session.set_tool_motion("ball", [0.0, 0.0, -0.1]).unwrap();
    // Solved cold, the 20 mm ball slips between the 25 mm mesh's top nodes (contact acts on
    // nodes) and ends inside the cube having pressed nothing: an error naming it, as for the
    // scene written with that motion, not a "converged" answer with no force.
    let e = session
        .solve()
        .map(|s| format!("ran: warm {}", s.warm))
        .unwrap_or_else(|e| e.to_string());
    assert!(
        e.contains("contact 'ball' ends inside the body") && e.contains("passed through"),
        "{e}"
    );
    // Issue 57: the static solve says so too (it "converged" with no force).
    for mode in ["solver.mode=relaxation", "solver.mode=static"] {
        let mut written = Session::new(
            hytled::scene::load(
                &file,
                &[
                    "references={}".to_string(),
                    "discretization.size=0.025".into(),
                    "contact.ball={ shape = \"sphere\", center = [0.05, 0.05, 0.12], radius = 0.02, motion = [0.0, 0.0, -0.1] }".into(),
                    mode.into(),
                ],
            )
            .unwrap(),
        )
        .unwrap();
        let cold = written
            .solve()
            .map(|s| {
                format!(
                    "ran: {:?} {:?} {:?}",
                    s.summary.reactions.get("ball"),
                    s.summary.contact,
                    s.summary.statics.as_ref().map(|x| x.load_reached)
                )
            })
            .unwrap_or_else(|e| e.to_string());
        assert!(
            cold.contains("contact 'ball' ends inside the body"),
            "{mode}: {cold}"
        );
    }
}

/// Warnings carry a kind (issue 58): `output.frames` in a relaxation is a `SteadyFrames`
/// warning, which a warm re-solve leaves out by its kind (it wrote no frames), while the
/// cold solve keeps it; summary.json lists each warning's kind beside its message.
#[test]
fn a_warm_resolve_drops_the_steady_frames_warning_by_its_kind() {
    use hytled::report::WarningKind;
    let scene = measured_cube("warning-kinds", 0.5, &["output.frames=5"]);
    let mut session = Session::new(scene).unwrap();
    let kinds = |w: &[hytled::report::Warning]| w.iter().map(|w| w.kind).collect::<Vec<_>>();
    assert!(
        kinds(&session.prepared().warnings).contains(&WarningKind::SteadyFrames),
        "{:?}",
        session.prepared().warnings
    );
    let cold = session.solve().unwrap();
    assert!(kinds(&cold.summary.warnings).contains(&WarningKind::SteadyFrames));
    let json: serde_json::Value = serde_json::to_value(&cold.summary).unwrap();
    let (messages, names) = (&json["warnings"], &json["warning_kinds"]);
    assert_eq!(
        messages.as_array().map(|a| a.len()),
        names.as_array().map(|a| a.len())
    );
    let k = cold
        .summary
        .warnings
        .iter()
        .position(|w| w.kind == WarningKind::SteadyFrames)
        .unwrap();
    assert_eq!(names[k], "steady_frames");
    assert_eq!(messages[k], cold.summary.warnings[k].message.as_str());
    let (_, exact) = exact_top(1.0);
    session.set_measured("top", &exact).unwrap();
    let warm = session.solve().unwrap();
    assert!(warm.warm, "{:?}", warm.summary.warnings);
    assert!(
        !kinds(&warm.summary.warnings).contains(&WarningKind::SteadyFrames),
        "{:?}",
        warm.summary.warnings
    );
}

/// Issue 57: a static re-solve of a contact scene starts from the last equilibrium with the
/// contact forces it held. The cube hangs sideways under gravity (x) against a wall 0.5 mm off
/// its far face: its points sit on the wall at the equilibrium, where the penalty alone pushes
/// nothing, so without multipliers estimated from the state's residual the first tangent had
/// no contact and the warm step's predictor pushed the face through the wall. The warm answer
/// is the cold one's.
#[test]
fn a_static_resolve_with_contact_stays_warm() {
    let file = cube_without_top("wall-static", "");
    let o: Vec<String> = vec![
        "references={}".into(),
        "discretization.size=0.025".into(),
        "solver.mode=static".into(),
        "boundaries={}".into(),
        "boundaries.post={ select = { box = { min = [-0.001, -0.001, -0.001], max = [0.026, 0.026, 0.101] } }, fix = [\"all\"] }".into(),
        "loads.g={ gravity = [0.0, 0.0, -9.81] }".into(),
        "contact.wall={ shape = \"plane\", point = [0.0, 0.0, -0.0005], normal = [0.0, 0.0, 1.0] }".into(),
    ];
    let mut session = Session::new(hytled::scene::load(&file, &o).unwrap()).unwrap();
    let first = session.solve().unwrap();
    assert!(first.summary.converged);
    session.set_load_factor("g", 1.1).unwrap();
    let warm = session.solve().unwrap();
    let fell_back = warnings_with(&warm.summary, "warm start");
    let cold = session.solve_cold().unwrap();
    let (fw, fc) = (
        warm.summary.reactions["wall"][2],
        cold.summary.reactions["wall"][2],
    );
    let (sw, sc) = (
        warm.summary.statics.as_ref().unwrap(),
        cold.summary.statics.as_ref().unwrap(),
    );
    println!(
        "wall at 1.1 g: first {} N; warm {fw} N ({} Newton iterations, {} load steps), cold {fc} N \
         ({} Newton iterations, {} load steps); {fell_back:?}",
        first.summary.reactions["wall"][2],
        sw.newton_iterations,
        sw.load_steps,
        sc.newton_iterations,
        sc.load_steps
    );
    assert!(warm.warm && warm.summary.converged && cold.summary.converged);
    assert!(fell_back.is_empty(), "{fell_back:?}");
    assert_eq!(sw.load_steps, 1);
    assert!(((fw - fc) / fc).abs() < 1e-6, "warm {fw} N, cold {fc} N");
}

/// Issue 57: a cold static re-solve (`Session::solve_cold`) is the solve of a fresh session.
/// It used the kept factor of the last equilibrium for its first steps: the ball moved from
/// 24 to 25 mm into the cube then stopped unconverged at -1.07 N, where a fresh session
/// gives 0.8392 N.
#[test]
fn a_cold_static_resolve_is_a_fresh_solve() {
    let file = cube_without_top("ball-cold", "");
    let ball = |z: f64| {
        let o: Vec<String> = vec![
            "references={}".into(),
            "discretization.size=0.025".into(),
            "solver.mode=static".into(),
            format!("contact.ball={{ shape = \"sphere\", center = [0.05, 0.05, 0.12], radius = 0.02, motion = [0.0, 0.0, {z}] }}"),
        ];
        hytled::scene::load(&file, &o).unwrap()
    };
    let mut session = Session::new(ball(-0.024)).unwrap();
    assert!(session.solve().unwrap().summary.converged);
    session.set_tool_motion("ball", [0.0, 0.0, -0.025]).unwrap();
    let cold = session.solve_cold().unwrap();
    let fresh = Session::new(ball(-0.025)).unwrap().solve().unwrap();
    let (a, b) = (
        cold.summary.reactions["ball"],
        fresh.summary.reactions["ball"],
    );
    println!("ball at 25 mm: cold re-solve {a:?} N, fresh {b:?} N");
    assert!(cold.summary.converged && fresh.summary.converged);
    assert_eq!(a, b);
    assert_eq!(cold.output.u, fresh.output.u);
}
