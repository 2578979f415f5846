"""A 100-run sweep of the exact cube (Young's modulus x Poisson's ratio, 10 x 10) serially
and on a 2-worker Dask LocalCluster, one worker killed mid-sweep; the times of both and a
check that every run came back once with the serial numbers. Run from the repository root:

    python python/examples/sweep_dask.py [OUT]

On a SLURM cluster the same call takes `dask_jobqueue.SLURMCluster(...)` in place of the
LocalCluster: `hytled.sweep(..., executor=Client(cluster).get_executor())`.
"""

import concurrent.futures as cf
import json
import os
import signal
import sys
import threading
import time

import hytled

SCENE = "cases/cube-compression.toml"
VARY = {
    "material.youngs_modulus": [2000.0 + 250.0 * k for k in range(10)],
    "material.poisson_ratio": [0.40 + 0.01 * k for k in range(10)],
}
FIXED = {"discretization.method": "meshless", "discretization.size": 0.025}


def key(row):
    s = row["summary"]
    return (s["reactions"]["top"], s["probes"]["corner"]["displacement"])


def main(out="sweep-dask"):
    from distributed import Client, LocalCluster

    t0 = time.perf_counter()
    serial = list(
        hytled.sweep(SCENE, vary=VARY, set=FIXED, executor=cf.ThreadPoolExecutor(1),
                     out=os.path.join(out, "serial"))
    )
    t_serial = time.perf_counter() - t0
    print(f"serial: {len(serial)} runs in {t_serial:.1f} s")

    dask_out = os.path.join(out, "dask")
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        pids = list(client.run(os.getpid).values())
        killed = []

        def kill_one():
            # When 30 runs are in, the first worker dies mid-run; the nanny restarts it.
            while len([p for p in os.listdir(os.path.join(dask_out, "runs"))
                       if os.path.exists(os.path.join(dask_out, "runs", p, "row.json"))]) < 30:
                time.sleep(0.01)
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])

        os.makedirs(os.path.join(dask_out, "runs"), exist_ok=True)
        threading.Thread(target=kill_one, daemon=True).start()
        t0 = time.perf_counter()
        rows = list(hytled.sweep(SCENE, vary=VARY, set=FIXED,
                                 executor=client.get_executor(), out=dask_out,
                                 threads=1))  # two workers share this machine's cores
        t_dask = time.perf_counter() - t0
    by_run = {r["run"]: r for r in serial}
    assert sorted(r["run"] for r in rows) == sorted(by_run), "a run is missing or repeated"
    same = all(key(r) == key(by_run[r["run"]]) for r in rows)
    failed = [r for r in rows if r["error"]]
    print(f"dask (2 workers, worker {killed} killed): {len(rows)} runs in {t_dask:.1f} s, "
          f"{len(failed)} failed, numbers {'bitwise the serial ones' if same else 'DIFFER'}")
    print(json.dumps({"serial_s": t_serial, "dask_s": t_dask, "runs": len(rows),
                      "killed": len(killed), "bitwise": same}))


if __name__ == "__main__":
    main(*sys.argv[1:])
