"""Tests of the Python package against the exact cube (docs/reference.md, docs/reference.md) and
the Rust library's own answers, and of the re-solve loop (issue 43)."""

import os
import pathlib
import runpy
import sys

import numpy as np
import pytest

import hytled

ROOT = pathlib.Path(__file__).resolve().parents[2]
CUBE = ROOT / "cases" / "cube-compression.toml"
A = 1.11574668  # lateral stretch of the cube compressed by 20 % (docs/reference.md)
F_EXACT = -7.63269  # its top force, N


def cube(**overrides):
    o = {"discretization.size": 0.025}
    o.update(overrides)
    return hytled.Model(CUBE, overrides=o)


def test_the_cube_from_a_file_is_exact_and_its_arrays_are_shaped():
    r = cube().solve()
    assert r.converged and not r.warm
    assert abs(r.reactions["top"][2] - F_EXACT) < 1e-5 * abs(F_EXACT)
    p = len(r.points)
    assert p == 125
    assert r.displacement.shape == (p, 3) and r.stress.shape == (p, 3, 3)
    assert r.strain.shape == (p, 3, 3) and r.von_mises.shape == (p,) and r.j.shape == (p,)
    corner = np.argmin(np.linalg.norm(r.points - [0.1, 0.1, 0.1], axis=1))
    assert abs(r.displacement[corner, 0] - (A - 1) * 0.1) < 1e-7
    # Homogeneous: J = a^2 0.8 and sigma_xx = 0 at every node.
    assert np.allclose(r.j, A * A * 0.8, rtol=1e-5)
    assert np.abs(r.stress[:, 0, 0]).max() < 1e-3 * np.abs(r.stress[:, 2, 2]).max()
    assert r.summary["units"].startswith("SI")
    assert r.probes["corner"].shape == (3,)


def test_a_scene_as_a_dict_gives_the_file_s_answer():
    tomllib = pytest.importorskip("tomllib")

    with open(CUBE, "rb") as f:
        d = tomllib.load(f)
    d["discretization"]["size"] = np.float64(0.025)
    r = hytled.Model(d, base_dir=CUBE.parent).solve()
    assert abs(r.reactions["top"][2] - F_EXACT) < 1e-5 * abs(F_EXACT)
    s = hytled.Scene(d)
    assert s.name == "cube-compression"
    assert s.to_dict()["discretization"]["size"] == 0.025


def test_errors_carry_the_cli_s_kind_and_exit_code():
    with pytest.raises(hytled.SceneError) as e:
        hytled.Scene(CUBE, overrides={"solver.dt_fator": 0.5})
    assert e.value.kind == "scene" and e.value.exit_code == 2
    assert "dt_factor" in str(e.value)  # the CLI's suggestion
    assert e.value.file.endswith("cube-compression.toml") and e.value.element is None
    with pytest.raises(hytled.FileError) as e:
        hytled.Scene("no-such-scene.toml")
    assert e.value.exit_code == 5
    assert e.value.file.endswith("no-such-scene.toml")
    m = cube()
    with pytest.raises(hytled.InputError) as e:
        m.set_displacement("lid", z=0.0)
    assert "symmetry_x" in str(e.value) and e.value.kind == "input"
    with pytest.raises(hytled.InputError):
        m.set_displacement("top", x=0.01)  # a free component
    with pytest.raises(hytled.HytledError):
        m.set_load_factor("gravity", 2.0)
    with pytest.raises(hytled.InputError):
        m.set_measured("top", np.zeros((3, 3)))
    with pytest.raises(hytled.InputError):
        hytled.Model(CUBE, device="tpu")


def test_errors_are_chosen_by_kind_with_their_facts(tmp_path):
    """Issue 58: the exception's class says what must change (an InputError subclass per
    kind) and its facts are attributes, never to be parsed out of the text."""
    m = cube()
    with pytest.raises(hytled.SelectionError) as e:
        m.set_displacement("lid", z=0.0)
    assert isinstance(e.value, hytled.InputError) and e.value.input_kind == "selection"
    assert e.value.key == "boundaries.lid" and e.value.exit_code == 2
    with pytest.raises(hytled.InvalidValueError) as e:
        m.set_displacement("top", z=float("nan"))
    assert e.value.input_kind == "value" and e.value.node is None
    # A scene key refused by validation: the key as data.
    with pytest.raises(hytled.SceneError) as e:
        hytled.Scene(CUBE, overrides={"solver.dt_factor": 11})
    assert e.value.key == "solver.dt_factor" and e.value.line is None
    assert isinstance(e.value, hytled.InputError) and e.value.kind == "scene"
    # A schema error in a file: its key and its line as written.
    text = CUBE.read_text().replace("[solver]\n", "[solver]\ndt_fator = 0.5\n", 1)
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(hytled.SceneError) as e:
        hytled.Scene(bad)
    line = text.splitlines().index("dt_fator = 0.5") + 1
    assert e.value.line == line and e.value.file.endswith("bad.toml"), (e.value.line, line)
    assert str(e.value).startswith(f"{e.value.file}:{line}: ")
    # A file that cannot be parsed: a FormatError naming it.
    short = tmp_path / "short.nii"
    short.write_bytes(b"\0" * 10)
    with pytest.raises(hytled.FormatError) as e:
        hytled.read_image(short)
    assert e.value.file.endswith("short.nii") and e.value.input_kind == "format"
    # Errors raised in Python have every fact attribute too.
    with pytest.raises(hytled.InvalidValueError) as e:
        m.set_displacement("top", [0.0, 0.0])
    assert e.value.key is None and e.value.line is None


def test_a_changed_boundary_resolves_warm_to_the_cold_answer():
    m = cube(**{"solver.tolerance": 1e-9})
    m.solve()
    assert m.warm
    m.set_displacement("top", z=-0.01)
    warm = m.solve()
    cold = cube(**{"solver.tolerance": 1e-9, "boundaries.top.displacement.z": -0.01}).solve()
    assert warm.warm and not cold.warm
    assert np.abs(warm.displacement - cold.displacement).max() < 1e-8
    assert abs(warm.reactions["top"][2] - cold.reactions["top"][2]) < 1e-6


def test_warnings_carry_their_kinds():
    m = cube(**{"output.frames": 5})
    assert len(m.warning_kinds) == len(m.warnings)
    k = m.warning_kinds.index("steady_frames")
    assert "output.frames" in m.warnings[k]
    r = m.solve()
    assert len(r.warning_kinds) == len(r.warnings)
    assert "output.frames" in r.warnings[r.warning_kinds.index("steady_frames")]


def test_load_factors_and_the_gpu_flag_pass_through():
    d = {
        "geometry": {"shape": "box", "min": [0, 0, 0], "max": [0.1, 0.1, 0.1]},
        "discretization": {"method": "fe", "element": "hex8", "size": 0.025},
        "material": {"model": "neo-hookean", "youngs_modulus": 3000.0,
                     "poisson_ratio": 0.49, "density": 1000.0},
        "boundaries": {"base": {"select": {"plane": {"axis": "z", "value": 0.0}},
                                "fix": ["all"]}},
        "loads": {"g": {"gravity": [0.0, 0.0, -9.81]}},
        "solver": {"mode": "relaxation", "tolerance": 1e-9},
    }
    m = hytled.Model(d)
    r1 = m.solve()
    m.set_load_factor("g", 2.0)
    r2 = m.solve()
    assert r2.warm and m.load_factor("g") == 2.0
    # The base carries the weight: rho g V = 1000 x 9.81 x 1e-3 N, twice with factor 2.
    assert abs(r1.reactions["base"][2] - 9.81) < 1e-6
    assert abs(r2.reactions["base"][2] - 19.62) < 1e-6
    try:
        g = hytled.Model(d, device="gpu")
    except hytled.HytledError as e:  # no GPU here: said before any work
        assert "GPU" in str(e) or "CUDA" in str(e) or "driver" in str(e), str(e)
    else:
        assert abs(g.solve().reactions["base"][2] - 9.81) < 1e-6


def test_results_convert_to_meshio_and_pyvista():
    r = cube().solve()
    meshio = pytest.importorskip("meshio")
    mm = r.to_meshio()
    assert isinstance(mm, meshio.Mesh)
    assert mm.cells[0].type == "hexahedron" and len(mm.cells[0].data) == 64
    assert np.array_equal(mm.point_data["displacement"], r.displacement)
    pv = pytest.importorskip("pyvista")
    g = r.to_pyvista(deformed=True)
    assert g.n_cells == 64 and g.n_points == 125
    assert np.allclose(g.points, r.points + r.displacement)


def test_the_resolve_example_runs_warm_in_a_third_of_the_steps(monkeypatch):
    monkeypatch.chdir(ROOT)
    example = runpy.run_path(str(ROOT / "python" / "examples" / "resolve.py"))
    first, again = example["main"](mode="relaxation")
    assert again.warm and again.converged
    assert 3 * again.steps <= first.steps


def test_a_static_resolve_reuses_the_factor_kept_at_the_equilibrium(monkeypatch):
    """Issue 57: the static re-solve after a 10 % change of brain-shift's measurements takes
    modified-Newton steps with the factor the first solve left at its equilibrium: no
    assembly, no factorization (tests/static_solve.rs checks its answer against a cold one)."""
    monkeypatch.chdir(ROOT)
    example = runpy.run_path(str(ROOT / "python" / "examples" / "resolve.py"))
    first, again = example["main"]()
    st = again.summary["static"]
    assert again.warm and again.converged
    assert st["kept_solves"] > 0 and st["assemblies"] == 0 and st["factorizations"] == 0
    assert again.summary["force_evaluations"] * 3 <= first.summary["force_evaluations"]


def test_ctrl_c_stops_a_solve_and_leaves_the_model_as_it_was():
    """Issue 56: SIGINT during Model.solve() stops it within a step and raises InterruptedRun
    (a KeyboardInterrupt, exit code 130); the model is as it was (not warm), and solves
    again. It was honoured only when the solve ended, and the result was lost."""
    import signal
    import threading
    import time

    m = cube(**{"discretization.size": 0.005, "solver.tolerance": 1e-10})
    assert not m.warm
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    t0 = time.monotonic()
    timer.start()
    with pytest.raises(hytled.InterruptedRun) as e:
        m.solve()
    stopped = time.monotonic() - t0
    timer.join()
    assert isinstance(e.value, KeyboardInterrupt) and isinstance(e.value, hytled.HytledError)
    assert e.value.exit_code == 130 and e.value.kind == "interrupted"
    assert stopped < 1.3, stopped
    assert not m.warm
    r = m.solve()
    assert r.converged and not r.warm


def test_two_threads_may_solve_one_model():
    """Issue 56: the second thread waits for the first (it got pyo3's "Already borrowed")."""
    import threading

    m = cube()
    results, errors = [], []

    def solve():
        try:
            results.append(m.solve(cold=True))
        except Exception as exc:  # noqa: BLE001 - any error fails the test below
            errors.append(exc)

    threads = [threading.Thread(target=solve) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert len(results) == 2
    for r in results:
        assert abs(r.reactions["top"][2] - F_EXACT) < 1e-5 * abs(F_EXACT)


def test_confusing_python_inputs_say_what_is_wrong():
    """Issue 56: a dict scene with NaN names the key (was a raw JSON parse error); dict
    overrides take the CLI's TOML value strings; errors raised before the library have their
    kind and exit code (were None)."""
    tomllib = pytest.importorskip("tomllib")

    with open(CUBE, "rb") as f:
        d = tomllib.load(f)
    d["material"]["youngs_modulus"] = float("nan")
    d["discretization"]["size"] = np.float64(0.025)
    with pytest.raises(hytled.SceneError) as e:
        hytled.Scene(d, base_dir=CUBE.parent)
    assert "material.youngs_modulus" in str(e.value) and e.value.exit_code == 2
    s = hytled.Scene(CUBE, overrides={"solver.tolerance": "1e-9", "discretization.size": "0.05"})
    assert s.to_dict()["solver"]["tolerance"] == 1e-9
    assert hytled.Scene(CUBE, overrides={"name": "plain words"}).name == "plain words"
    with pytest.raises(hytled.InputError) as e:
        hytled.Model(hytled.Scene(CUBE), device="tpu")
    assert e.value.kind == "input" and e.value.exit_code == 2
