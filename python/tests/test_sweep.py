"""hytled.sweep: the CLI's sweep on any executor, resumable, and on a real Dask cluster with a
worker killed mid-run (issue 59)."""

import concurrent.futures as cf
import glob
import hashlib
import json
import os
import signal
import threading
import time

import pytest

import hytled

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
CUBE = os.path.join(ROOT, "cases", "cube-compression.toml")
# The cube at two resolutions x two methods; meshless at 0.0125 m runs for seconds, long
# enough to be killed mid-run.
VARY = {"discretization.method": ["fe", "meshless"], "discretization.size": [0.025, 0.0125]}
SLOW = {"discretization.method": "meshless", "discretization.size": "0.0125"}


def numbers(row):
    s = row["summary"]
    return (s["reactions"]["top"], s["probes"]["corner"]["displacement"], s["steps"])


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    rows = list(hytled.sweep(CUBE, vary=VARY, executor=cf.ThreadPoolExecutor(1), out=out))
    return {r["run"]: r for r in rows}, out


def test_rows_ids_and_files_are_the_clis(serial):
    rows, out = serial
    assert sorted(rows) == [1, 2, 3, 4]
    for r in rows.values():
        assert r["status"] == "converged" and r["error"] is None, r
        overrides = [f"{k}={v}" for k, v in zip(VARY, (r[k] for k in VARY))]
        # The id: the SHA-256 of the overrides, one per line, computed here independently.
        assert r["id"] == hashlib.sha256("\n".join(overrides).encode()).hexdigest()[:16]
        d = os.path.join(out, "runs", r["id"])
        assert json.load(open(os.path.join(d, "summary.json")))["steps"] == r["steps"]
        assert json.load(open(os.path.join(d, "row.json")))["id"] == r["id"]
        assert not os.path.exists(os.path.join(d, "running.json"))
        assert r["wall_seconds"] > 0 and r["force_evaluations"] > 0 and r["nodes"] > 0
        assert r["error_vs_reference"] is not None and r["error_vs_reference"] < 0.01
    table = open(os.path.join(out, "sweep.csv")).read().splitlines()
    assert len(table) == 5
    pd = pytest.importorskip("pandas")
    df = hytled.sweep(CUBE, vary=VARY, executor=cf.ThreadPoolExecutor(1)).to_pandas()
    assert isinstance(df, pd.DataFrame) and list(df["run"]) == [1, 2, 3, 4]


def test_a_stopped_sweep_resumes_with_only_the_missing_runs(serial, tmp_path):
    rows, _ = serial
    pool = cf.ThreadPoolExecutor(1)
    s = hytled.sweep(CUBE, vary=VARY, executor=pool, out=tmp_path)
    first = [next(s), next(s)]
    s.close()
    pool.shutdown(wait=True)
    on_disk = len(glob.glob(os.path.join(tmp_path, "runs", "*", "row.json")))
    assert 2 <= on_disk < 4
    table = open(os.path.join(tmp_path, "sweep.md")).read()
    assert "Partial: 2 of 4 runs" in table
    again = list(hytled.sweep(CUBE, vary=VARY, executor=cf.ThreadPoolExecutor(1), out=tmp_path, resume=True))
    assert sorted(r["run"] for r in again) == [1, 2, 3, 4]
    assert sum(r["reused"] for r in again) == on_disk
    assert {r["run"] for r in first} <= {r["run"] for r in again if r["reused"]}
    for r in again:
        assert numbers(r) == numbers(rows[r["run"]])
    assert len(open(os.path.join(tmp_path, "sweep.csv")).read().splitlines()) == 5
    with pytest.raises(ValueError, match="needs out"):
        hytled.sweep(CUBE, vary=VARY, resume=True)


def test_the_default_process_pool_gives_the_serial_numbers(serial, tmp_path):
    rows, _ = serial
    got = list(hytled.sweep(CUBE, vary=VARY, jobs=2, out=tmp_path))
    assert sorted(r["run"] for r in got) == [1, 2, 3, 4]
    for r in got:
        assert numbers(r) == numbers(rows[r["run"]])
        assert r["peak_memory_mib"] is not None and r["peak_memory_mib"] > 0


def test_a_dask_worker_killed_mid_run_costs_only_its_run(serial, tmp_path):
    distributed = pytest.importorskip("distributed")
    rows, _ = serial
    slow_id = hashlib.sha256(
        "\n".join(f"{k}={v}" for k, v in SLOW.items()).encode()
    ).hexdigest()[:16]
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        killed = []

        def kill_when_running():
            marker = os.path.join(tmp_path, "runs", slow_id, "running.json")
            deadline = time.time() + 60
            while time.time() < deadline:
                try:
                    pid = json.load(open(marker))["pid"]
                except (OSError, ValueError, KeyError):
                    time.sleep(0.01)
                    continue
                time.sleep(0.3)  # inside the run
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return

        killer = threading.Thread(target=kill_when_running)
        killer.start()
        got = list(hytled.sweep(CUBE, vary=VARY, executor=client.get_executor(), out=tmp_path))
        killer.join()
    assert len(killed) == 1, "the slow run was never seen running"
    assert sorted(r["run"] for r in got) == [1, 2, 3, 4], [r["run"] for r in got]
    for r in got:
        assert r["error"] is None, r["error"]
        assert numbers(r) == numbers(rows[r["run"]])
    slow = next(r for r in got if r["id"] == slow_id)
    assert slow["status"] == "converged"


def test_a_run_that_kills_its_worker_twice_is_a_failed_row(tmp_path):
    slow_id = hashlib.sha256(
        "\n".join(f"{k}={v}" for k, v in SLOW.items()).encode()
    ).hexdigest()[:16]
    marker = os.path.join(tmp_path, "runs", slow_id, "running.json")
    killed = []

    def kill_twice():
        deadline = time.time() + 120
        while len(killed) < 2 and time.time() < deadline:
            try:
                pid = json.load(open(marker))["pid"]
            except (OSError, ValueError, KeyError):
                pid = None
            if pid is None or pid in killed:
                time.sleep(0.01)
                continue
            time.sleep(0.2)
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    killer = threading.Thread(target=kill_twice)
    killer.start()
    vary = {"discretization.method": ["fe", "meshless"], "discretization.size": [0.0125]}
    got = list(hytled.sweep(CUBE, vary=vary, jobs=1, out=tmp_path))
    killer.join()
    assert len(killed) == 2
    rows = {r["id"]: r for r in got}
    assert len(got) == 2
    slow = rows[slow_id]
    assert slow["status"] == "failed" and slow["attempts"] == 2
    assert "lost 2 times" in slow["error"], slow["error"]
    other = next(r for r in got if r["id"] != slow_id)
    assert other["status"] == "converged"
    # The table says what happened; a resumed sweep runs the failed run again.
    assert "lost 2 times" in open(os.path.join(tmp_path, "sweep.csv")).read()


def test_ray_runs_the_sweep_through_its_futures(serial, tmp_path):
    ray = pytest.importorskip("ray")
    rows, _ = serial
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        got = list(hytled.sweep(CUBE, vary=VARY, executor=hytled.RayExecutor(), threads=1, out=tmp_path))
    finally:
        ray.shutdown()
    assert sorted(r["run"] for r in got) == [1, 2, 3, 4]
    for r in got:
        assert numbers(r) == numbers(rows[r["run"]])
