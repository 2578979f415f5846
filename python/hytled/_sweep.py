"""Sweeps and cohorts on any ``concurrent.futures.Executor`` (``hytled.sweep``).

The runs are the CLI's ``hytled sweep`` product (same keys, ids and row fields); each is a
task that a worker runs one at a time: its row and summary are on disk under
``out/runs/<id>`` before the task returns, so a stopped sweep loses only the runs under way,
and ``resume=True`` reruns only what is missing or failed.
"""

from __future__ import annotations

import concurrent.futures as cf
from concurrent.futures.process import BrokenProcessPool
import json
import os
import socket
import time
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Union

from . import _hytled

PathLike = Union[str, "os.PathLike[str]"]

#: Fields of a row besides the varied values (see :func:`sweep`).
ROW_FIELDS = (
    "run",
    "id",
    "status",
    "error",
    "error_vs_reference",
    "wall_seconds",
    "solve_seconds",
    "steps",
    "force_evaluations",
    "nodes",
    "integration_points",
    "peak_memory_mib",
    "method",
    "element",
    "mode",
    "converged",
    "attempts",
    "reused",
)


def _values_text(v: Any) -> str:
    """A varied value as the CLI's ``--vary`` takes it: text (and a path) as it is, so that
    the run ids are those of the same sweep from the CLI; numbers, lists as TOML."""
    from . import _toml_value

    if isinstance(v, os.PathLike):
        return os.fspath(v)
    if isinstance(v, str):
        return v
    return _toml_value(v)


def _vary_args(vary: Union[None, Mapping[str, Sequence[Any]], Sequence[str]]) -> List[str]:
    """``{"key.path": [v1, v2]}`` or the CLI's ``["key.path=v1,v2"]`` as CLI arguments. A
    value may be a file (a path): a cohort is a sweep over ``geometry.image`` and the like."""
    if vary is None:
        return []
    if isinstance(vary, Mapping):
        out = []
        for key, values in vary.items():
            if isinstance(values, (str, bytes, os.PathLike)) or not isinstance(values, Sequence):
                values = [values]
            if len(values) == 0:
                raise ValueError(f"vary[{key!r}]: give at least one value")
            out.append(f"{key}=" + ",".join(_values_text(v) for v in values))
        return out
    return [str(v) for v in vary]


def _preset_args(presets: Union[None, Mapping[str, Any], Sequence[str]]) -> List[str]:
    """``{"name": {"key.path": value}}`` (or a list of ``key.path=value``) as the CLI's
    ``NAME=key.path=value;...``."""
    from . import _overrides

    if presets is None:
        return []
    if isinstance(presets, Mapping):
        return [
            f"{name}="
            + ";".join(
                [f"{k}={_values_text(v)}" for k, v in sets.items()]
                if isinstance(sets, Mapping)
                else _overrides(sets)
            )
            for name, sets in presets.items()
        ]
    return [str(p) for p in presets]


def _row(raw: Dict[str, Any], attempts: int, reused: bool) -> Dict[str, Any]:
    """A flat row: the varied values, then :data:`ROW_FIELDS`, then the full ``summary``."""
    s = raw.get("summary")
    refs = (s or {}).get("reference") or {}
    errors = [abs(c["relative_error"]) for c in refs.values() if "relative_error" in c]
    row: Dict[str, Any] = dict(raw.get("values", {}))
    row.update(
        run=raw["run"],
        id=raw["id"],
        status="failed" if raw.get("error") else (s or {}).get("status", "missing"),
        error=raw.get("error"),
        error_vs_reference=max(errors) if errors else None,
        wall_seconds=(s or {}).get("wall_seconds", {}).get("total"),
        solve_seconds=(s or {}).get("wall_seconds", {}).get("solve"),
        steps=(s or {}).get("steps"),
        force_evaluations=(s or {}).get("force_evaluations"),
        nodes=(s or {}).get("nodes"),
        integration_points=(s or {}).get("integration_points"),
        peak_memory_mib=raw.get("peak_memory_mib"),
        method=(s or {}).get("method"),
        element=(s or {}).get("element"),
        mode=(s or {}).get("mode"),
        converged=(s or {}).get("converged"),
        attempts=attempts,
        reused=reused,
        summary=s,
    )
    return row


def _run_task(
    scene: str,
    planned: str,
    out: Optional[str],
    keep_outputs: bool,
    repeat: int,
    threads: Optional[int],
) -> str:
    """One run on a worker (module level, so that any executor can pickle it): marks the run
    under way (``runs/<id>/running.json``: host and process), runs it, and returns its row
    as JSON once row and summary are on disk."""
    marker = None
    if out is not None:
        run_id = json.loads(planned)["id"]
        d = os.path.join(out, "runs", run_id)
        os.makedirs(d, exist_ok=True)
        marker = os.path.join(d, "running.json")
        with open(marker, "w") as f:
            json.dump({"host": socket.gethostname(), "pid": os.getpid(), "started": time.time()}, f)
    try:
        return _hytled.sweep_run(scene, planned, out, keep_outputs, repeat, threads)
    finally:
        if marker is not None:
            try:
                os.remove(marker)
            except OSError:
                pass


def _failed_row(planned: Dict[str, Any], reason: str) -> Dict[str, Any]:
    return {
        "run": planned["run"],
        "id": planned["id"],
        "values": planned["values"],
        "overrides": planned["overrides"],
        "error": reason,
        "peak_memory_mib": None,
        "repeats": 0,
        "pareto": False,
    }


class Sweep:
    """A sweep under way: iterate it for the rows as they finish (dicts: the varied values,
    :data:`ROW_FIELDS` and ``summary``), or call :meth:`wait` / :meth:`to_pandas` for all of
    them. ``rows`` holds those finished so far, ``planned`` the number of runs."""

    def __init__(
        self,
        scene: str,
        plan: Dict[str, Any],
        presets: List[str],
        executor: Optional[cf.Executor],
        jobs: Optional[int],
        out: Optional[str],
        resume: bool,
        keep_outputs: bool,
        repeat: int,
        threads: Optional[int],
        retries: int,
    ) -> None:
        self.scene = scene
        self.dimensions = plan["dimensions"]
        self.runs: List[Dict[str, Any]] = plan["runs"]
        self.planned = len(self.runs)
        self.rows: List[Dict[str, Any]] = []
        self._raw: List[Dict[str, Any]] = []
        self._presets = presets
        self._out = out
        self._keep = keep_outputs
        self._repeat = repeat
        self._retries = retries
        self._own = executor is None
        cores = os.cpu_count() or 1
        if executor is None:
            import multiprocessing

            workers = max(1, jobs or cores)
            self._threads = threads or max(1, cores // workers)
            # Spawned, not forked: the parent may hold threads (rayon's) a fork would copy
            # in whatever state they were.
            self._executor: cf.Executor = cf.ProcessPoolExecutor(
                max_workers=workers, mp_context=multiprocessing.get_context("spawn")
            )
            self._window = workers
        else:
            self._executor = executor
            self._threads = threads
            self._window = max(1, jobs or 2 * cores)
        self._resume = resume
        self._iter = self._generate()

    def __iter__(self) -> Iterator[Dict[str, Any]]:
        return self._iter

    def __next__(self) -> Dict[str, Any]:
        return next(self._iter)

    def close(self) -> None:
        """Stops the sweep: no run is submitted any more and those not started are cancelled;
        the runs under way finish (and are on disk for a resumed sweep)."""
        self._iter.close()

    def wait(self) -> "Sweep":
        """Runs the sweep to its end; returns itself."""
        for _ in self._iter:
            pass
        return self

    def to_pandas(self):
        """The rows as a ``pandas.DataFrame`` (one row per run, in run order; the sweep is run
        to its end first)."""
        import pandas as pd

        self.wait()
        rows = sorted(self.rows, key=lambda r: r["run"])
        return pd.DataFrame([{k: v for k, v in r.items() if k != "summary"} for r in rows])

    def _submit(self, planned: Dict[str, Any]) -> cf.Future:
        return self._executor.submit(
            _run_task,
            self.scene,
            json.dumps(planned),
            self._out,
            self._keep,
            self._repeat,
            self._threads,
        )

    def _record(self, raw: Dict[str, Any], attempts: int, reused: bool) -> Dict[str, Any]:
        row = _row(raw, attempts, reused)
        self._raw.append(raw)
        self.rows.append(row)
        if self._out is not None:
            _hytled.sweep_table(
                self._out,
                self.scene,
                json.dumps(self.dimensions),
                self._presets,
                json.dumps(self._raw),
                self.planned,
            )
        return row

    def _generate(self) -> Iterator[Dict[str, Any]]:
        todo = list(self.runs)
        running: Dict[cf.Future, Dict[str, Any]] = {}
        try:
            if self._resume and self._out is not None:
                kept = json.loads(_hytled.sweep_finished(self._out, json.dumps(todo)))
                have = {r["id"] for r in kept}
                todo = [p for p in todo if p["id"] not in have]
                for raw in kept:
                    yield self._record(raw, 0, True)
            attempts: Dict[str, int] = {}
            queue = list(reversed(todo))
            while queue or running:
                while queue and len(running) < self._window:
                    p = queue.pop()
                    attempts[p["id"]] = attempts.get(p["id"], 0) + 1
                    running[self._submit(p)] = p
                finished, _ = cf.wait(list(running), return_when=cf.FIRST_COMPLETED)
                for fut in finished:
                    p = running.pop(fut)
                    try:
                        raw = json.loads(fut.result())
                    except _hytled.HytledError as e:
                        # The run's own folder could not be written: the row says so.
                        raw = _failed_row(p, f"{type(e).__name__}: {e}")
                    except Exception as e:  # the worker died or the engine lost the task
                        if isinstance(e, BrokenProcessPool) and self._own:
                            self._restart_pool()
                        reason = f"{type(e).__name__}: {e}".strip()
                        if attempts[p["id"]] <= self._retries:
                            queue.append(p)
                            continue
                        raw = _failed_row(
                            p,
                            f"the run's worker was lost {attempts[p['id']]} times (last: {reason})",
                        )
                    yield self._record(raw, attempts[p["id"]], False)
        finally:
            for fut in running:
                fut.cancel()
            if self._own:
                self._executor.shutdown(wait=False, cancel_futures=True)

    def _restart_pool(self) -> None:
        """A killed worker breaks a ProcessPoolExecutor for good: a new one takes the runs."""
        import multiprocessing

        workers = self._window
        self._executor.shutdown(wait=False, cancel_futures=True)
        self._executor = cf.ProcessPoolExecutor(
            max_workers=workers, mp_context=multiprocessing.get_context("spawn")
        )


class RayExecutor(cf.Executor):
    """Ray as a ``concurrent.futures.Executor`` for :func:`sweep`: each run a Ray task (its
    ``ObjectRef.future()``). Call ``ray.init(...)`` first; ``options`` go to ``ray.remote``
    (e.g. ``num_cpus=4`` per run, then pass ``threads=4`` to the sweep). Ray itself retries a
    task whose worker died (its ``max_retries``, default 3) before the sweep sees the loss."""

    def __init__(self, **options: Any) -> None:
        self._options = options

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[override]
        import ray

        remote = ray.remote(**self._options)(fn) if self._options else ray.remote(fn)
        return remote.remote(*args, **kwargs).future()


def sweep(
    scene: PathLike,
    vary: Union[None, Mapping[str, Sequence[Any]], Sequence[str]] = None,
    presets: Union[None, Mapping[str, Any], Sequence[str]] = None,
    set: Union[None, Sequence[str], Mapping[str, Any]] = None,
    executor: Optional[cf.Executor] = None,
    out: Optional[PathLike] = None,
    resume: bool = False,
    keep_outputs: bool = False,
    repeat: int = 1,
    jobs: Optional[int] = None,
    threads: Optional[int] = None,
    retries: int = 1,
) -> Sweep:
    """Runs the cartesian product of ``vary`` (and ``presets``) on the scene file ``scene``,
    as ``hytled sweep`` does, on ``executor``; returns a :class:`Sweep` that yields the rows
    as they finish.

    - ``vary``: ``{"key.path": [v1, v2, ...]}`` (or the CLI's ``["key.path=v1,v2"]``); any
      ``--set`` path, and values may be files (``geometry.image``, ``measured.NAME.file``: a
      cohort of patients).
    - ``presets``: named groups of overrides, ``{"mmls": {"discretization.method":
      "meshless", "discretization.basis": "quadratic"}}``: one varied dimension ``preset``.
    - ``set``: overrides applied to every run.
    - ``executor``: any ``concurrent.futures.Executor``: ``None`` starts a local pool of
      ``jobs`` spawned processes (default: one per core, each run on ``cores / jobs``
      threads); ``dask.distributed.Client(...).get_executor()`` runs on a Dask cluster (and
      so on SLURM or PBS through dask-jobqueue); :class:`RayExecutor` runs on Ray. Workers
      need the hytled package and the scene's files at the same paths.
    - ``out``: the sweep's folder: ``runs/<id>/`` per run (``row.json``, ``summary.json``,
      with ``keep_outputs`` every output; ``<id>`` is the first 16 hex digits of the SHA-256
      of the run's overrides, one per line) and the table (``sweep.csv``, ``sweep.md``,
      ``sweep.json``, rewritten by rename after every row).
    - ``resume``: keep the rows ``out`` holds for finished runs; run only the missing and
      failed ones.
    - ``retries``: a run whose worker is lost (killed, out of memory) is submitted again up
      to this many times; after that it is a failed row naming the reason.

    Row fields: the varied values, ``run``, ``id``, ``status`` ("converged", "completed",
    "not converged" or "failed"), ``error`` (why it failed), ``error_vs_reference`` (largest
    relative error over the scene's references), ``wall_seconds``, ``solve_seconds``,
    ``steps``, ``force_evaluations``, ``nodes``, ``integration_points``, ``peak_memory_mib``,
    ``method``, ``element``, ``mode``, ``converged``, ``attempts``, ``reused`` (kept from an
    earlier sweep by ``resume``) and ``summary`` (the run's summary.json as a dict). Units SI.
    """
    from . import _overrides

    if resume and out is None:
        raise ValueError("resume=True needs out=, the folder of the sweep to go on with")
    if repeat < 1:
        raise ValueError("repeat: give at least 1 run per combination")
    if retries < 0:
        raise ValueError("retries: give 0 or more")
    scene_path = os.path.abspath(os.fspath(scene))
    preset_args = _preset_args(presets)
    fixed = (
        [f"{k}={_values_text(v)}" for k, v in set.items()]
        if isinstance(set, Mapping)
        else _overrides(set)
    )
    plan = json.loads(_hytled.sweep_plan(scene_path, _vary_args(vary), preset_args, fixed))
    out_path = None
    if out is not None:
        out_path = os.path.abspath(os.fspath(out))
        os.makedirs(out_path, exist_ok=True)
    return Sweep(
        scene_path,
        plan,
        preset_args,
        executor,
        jobs,
        out_path,
        resume,
        keep_outputs,
        repeat,
        threads,
        retries,
    )
