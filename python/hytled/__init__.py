"""hytled from Python: prepare a soft-tissue model once, solve it again as its inputs change.

Units are SI throughout: metres, kilograms, seconds, newtons, pascals.

    import hytled
    model = hytled.Model("cases/brain-shift.toml")      # mesh + discretization, once
    first = model.solve()                               # from the unloaded state
    u = model.measured_displacements("exposed") * 1.1   # new measurements, same points
    model.set_measured("exposed", u)
    again = model.solve()                               # from the last equilibrium (warm)
    print(again.steps, again.probes["tumour_centre"])

A scene is a TOML file (the CLI's) or a dict with the same tables; `overrides` are the CLI's
`--set KEY.PATH=VALUE` strings, or a dict {"solver.tolerance": 1e-8}. Errors are raised as
`HytledError` subclasses carrying the CLI's `kind` and `exit_code`.
"""

from __future__ import annotations

import json
import os
from typing import Any, Dict, Iterable, Mapping, Optional, Sequence, Union

import numpy as np

from . import _hytled
from ._hytled import (
    DiscretizationError,
    FileError,
    FormatError,
    HytledError,
    InputError,
    InterruptedRun,
    InvalidValueError,
    LimitError,
    MeshError,
    SceneError,
    SelectionError,
    UnstableError,
    UnsupportedError,
)

from ._sweep import RayExecutor, Sweep, sweep  # noqa: E402  (after the compiled part it wraps)

__version__ = _hytled.__version__
__all__ = [
    "read_image",
    "sweep",
    "Sweep",
    "RayExecutor",
    "Scene",
    "Model",
    "Result",
    "HytledError",
    "InputError",
    "SceneError",
    "FormatError",
    "MeshError",
    "SelectionError",
    "InvalidValueError",
    "UnsupportedError",
    "DiscretizationError",
    "LimitError",
    "UnstableError",
    "FileError",
    "InterruptedRun",
]

def read_image(path: Union[str, "os.PathLike[str]"]):
    """The 3-D image at ``path`` (NIfTI-1 ``.nii``/``.nii.gz``, NRRD ``.nrrd``/``.nhdr``) as
    hytled reads it for ``geometry.image``, contact surfaces and ``output.image``.

    Returns ``(values, affine)``: the voxel values scaled as the file says (``scl_slope``,
    ``scl_inter``), a float64 array indexed ``[i, j, k]``, and the 4x4 map from voxel index
    to world position in RAS **metres** (nibabel's ``img.affine`` is in millimetres). Raises
    :class:`InputError` for a file hytled refuses (4-D, truncated, unknown datatype).
    """
    return _hytled.read_image(os.fspath(path))


Overrides = Union[None, Sequence[str], Mapping[str, Any]]


def _toml_value(v: Any) -> str:
    """A Python value as the right-hand side of a `--set` override (TOML)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float, np.integer, np.floating)):
        return repr(float(v)) if isinstance(v, (float, np.floating)) else str(int(v))
    if isinstance(v, str):
        # The CLI's `--set KEY=VALUE` takes TOML values: a string that is one ("1e-6",
        # "[0, 0, -0.01]", "{ gravity = [0, 0, -9.81] }") is taken as it is, as there.
        if _is_toml_value(v):
            return v
        return json.dumps(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"override value {v!r}: give a number, string, bool, list or dict")


def _is_toml_value(text: str) -> bool:
    """Whether `text` is a TOML value other than a bare word (a number, array, inline table,
    bool or quoted string)."""
    try:
        import tomllib
    except ImportError:  # Python < 3.11: strings stay strings
        return False
    try:
        tomllib.loads("v = " + text)
    except tomllib.TOMLDecodeError:
        return False
    return True


def _overrides(o: Overrides) -> list:
    if o is None:
        return []
    if isinstance(o, Mapping):
        return [f"{k}={_toml_value(v)}" for k, v in o.items()]
    if isinstance(o, str):
        return [o]
    return [str(x) for x in o]


def _plain(v: Any, at: str = "") -> Any:
    """numpy values in a scene dict as plain Python (JSON) values; a number that is not finite
    is a SceneError naming its key (JSON has no NaN)."""
    if isinstance(v, np.ndarray):
        return _plain(v.tolist(), at)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (float, np.floating)) and not np.isfinite(v):
        e = SceneError(f"scene dict: {at or 'a value'} = {float(v)} is not a finite number; give a finite value")
        e.kind, e.exit_code, e.key = "scene", 2, at or None
        raise e
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, Mapping):
        return {str(k): _plain(x, f"{at}.{k}" if at else str(k)) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x, f"{at}[{i}]") for i, x in enumerate(v)]
    return v


class Scene:
    """A validated scene (the CLI's scene file), with the same checks and messages.

    Scene("case.toml", overrides={"solver.tolerance": 1e-8}) reads a file;
    Scene({...}, base_dir=".") takes a dict of the file's tables (relative paths resolve
    against `base_dir`, default the working directory).
    """

    def __init__(
        self,
        source: Union[str, os.PathLike, Mapping[str, Any]],
        overrides: Overrides = None,
        base_dir: Union[str, os.PathLike, None] = None,
    ) -> None:
        o = _overrides(overrides)
        if isinstance(source, Mapping):
            text = json.dumps(_plain(source))
            self._inner = _hytled.Scene.from_json(text, os.fspath(base_dir or os.getcwd()), o)
        else:
            self._inner = _hytled.Scene.from_file(os.fspath(source), o)

    @property
    def name(self) -> str:
        """The scene's name."""
        return self._inner.name

    def to_dict(self) -> Dict[str, Any]:
        """The scene with every default filled in."""
        return json.loads(self._inner.to_json())


class Result:
    """One solve's answer. Arrays are numpy, per point of the output mesh (the FE nodes;
    for meshless and coupled models the points the VTU frames use), in SI units.

    points (P, 3) m: reference positions; displacement (P, 3) m; stress (P, 3, 3) Pa: nodal
    Cauchy stress; strain (P, 3, 3): Green-Lagrange strain; von_mises (P,) Pa; j (P,): volume
    change; cells: VTK connectivity, offsets and cell types; reactions {name: (3,) N} of the
    boundaries and rigid bodies; probes {name: (3,) m}; summary: the run's summary.json as a
    dict; steps, converged, warm (started from the last equilibrium).
    """

    def __init__(self, raw: Dict[str, Any]) -> None:
        self.points: np.ndarray = raw["points"]
        self.displacement: np.ndarray = raw["displacement"]
        self.stress: np.ndarray = raw["stress"]
        self.strain: np.ndarray = raw["strain"]
        self.von_mises: np.ndarray = raw["von_mises"]
        self.j: np.ndarray = raw["j"]
        self.connectivity: np.ndarray = raw["connectivity"]
        self.offsets: np.ndarray = raw["offsets"]
        self.cell_types: np.ndarray = raw["cell_types"]
        self.nodal_parameters: np.ndarray = raw["nodal_parameters"]
        self.summary: Dict[str, Any] = json.loads(raw["summary"])
        self.steps: int = raw["steps"]
        self.converged: bool = raw["converged"]
        self.warm: bool = raw["warm"]
        self.reactions: Dict[str, np.ndarray] = {
            k: np.asarray(v, dtype=float) for k, v in self.summary["reactions"].items()
        }
        self.probes: Dict[str, np.ndarray] = {
            k: np.asarray(v["displacement"], dtype=float)
            for k, v in self.summary["probes"].items()
        }

    @property
    def wall_seconds(self) -> Dict[str, float]:
        """Wall time of the solve, s (preprocess 0: the model was prepared before)."""
        return self.summary["wall_seconds"]

    @property
    def warnings(self) -> list:
        """The run's warnings (messages); their kinds are in `warning_kinds`."""
        return self.summary.get("warnings", [])

    @property
    def warning_kinds(self) -> list:
        """The kind of each warning, in order: "input", "discretization", "boundary",
        "contact", "steady_frames", "solve" or "resolve"; test these, not the messages."""
        return self.summary.get("warning_kinds", [])

    def _cells(self):
        """(VTK type, connectivity array) blocks in cell order."""
        blocks = []
        start = 0
        for end, t in zip(self.offsets, self.cell_types):
            ids = self.connectivity[start:end]
            if blocks and blocks[-1][0] == int(t) and len(blocks[-1][1][-1]) == len(ids):
                blocks[-1][1].append(ids)
            else:
                blocks.append((int(t), [ids]))
            start = end
        return [(t, np.asarray(c, dtype=np.int64)) for t, c in blocks]

    def point_data(self) -> Dict[str, np.ndarray]:
        """The point fields by the names the VTU frames use."""
        p = len(self.points)
        return {
            "displacement": self.displacement,
            "cauchy_stress": self.stress.reshape(p, 9),
            "green_strain": self.strain.reshape(p, 9),
            "von_mises": self.von_mises,
            "J": self.j,
        }

    def to_meshio(self):
        """A meshio.Mesh of the reference configuration with the point fields (needs meshio)."""
        import meshio

        names = {1: "vertex", 10: "tetra", 12: "hexahedron", 24: "tetra10"}
        cells = [(names[t], c) for t, c in self._cells()]
        return meshio.Mesh(self.points, cells, point_data=self.point_data())

    def to_pyvista(self, deformed: bool = False):
        """A pyvista.UnstructuredGrid with the point fields; `deformed=True` moves the points
        by the displacement (needs pyvista)."""
        import pyvista

        cells = []
        types = []
        for t, c in self._cells():
            for ids in c:
                cells.append(np.concatenate([[len(ids)], ids]))
                types.append(t)
        x = self.points + self.displacement if deformed else self.points
        grid = pyvista.UnstructuredGrid(
            np.concatenate(cells).astype(np.int64), np.asarray(types, dtype=np.uint8), x
        )
        for k, v in self.point_data().items():
            grid.point_data[k] = v
        return grid


class Model:
    """A scene meshed and discretized once, solved again as its inputs change.

    Between solves, change boundary displacements (set_displacement), measured
    displacements (set_measured), rigid-tool positions (set_tool_motion) and load factors
    (set_load_factor); a relaxation then starts from the last equilibrium. `device` "cpu" or
    "gpu" overrides the scene's solver.device.
    """

    def __init__(
        self,
        scene: Union[Scene, str, os.PathLike, Mapping[str, Any]],
        overrides: Overrides = None,
        device: Optional[str] = None,
        base_dir: Union[str, os.PathLike, None] = None,
    ) -> None:
        if not isinstance(scene, Scene):
            scene = Scene(scene, overrides=overrides, base_dir=base_dir)
        elif overrides:
            raise TypeError("give overrides when reading the scene: Scene(path, overrides)")
        self.scene = scene
        self._inner = _hytled.Model(scene._inner, device)

    def solve(self, cold: bool = False) -> Result:
        """Solves with the inputs as they are now: from the last equilibrium where there is
        one (relaxation), else from the unloaded state; `cold=True` always from the unloaded
        state. The GIL is released while it runs."""
        return Result(self._inner.solve(cold))

    def forget(self) -> None:
        """The next solve starts from the unloaded state."""
        self._inner.forget()

    @property
    def warm(self) -> bool:
        """Whether the next solve starts from the last equilibrium."""
        return self._inner.warm

    @property
    def prepare_seconds(self) -> float:
        return self._inner.prepare_seconds

    @property
    def nodes(self) -> np.ndarray:
        """Reference positions of the model's nodes, m (N, 3)."""
        return self._inner.nodes

    @property
    def warnings(self) -> list:
        """Warnings of the preparation (messages); their kinds are in `warning_kinds`."""
        return self._inner.warnings

    @property
    def warning_kinds(self) -> list:
        """The kind of each preparation warning, in order (see `Run.warning_kinds`)."""
        return self._inner.warning_kinds

    @property
    def boundaries(self) -> list:
        return self._inner.boundary_names

    @property
    def loads(self) -> list:
        return self._inner.load_names

    @property
    def tools(self) -> list:
        return self._inner.tool_names

    def set_displacement(
        self,
        name: str,
        value: Optional[Sequence[Optional[float]]] = None,
        *,
        x: Optional[float] = None,
        y: Optional[float] = None,
        z: Optional[float] = None,
    ) -> None:
        """New final displacement (m) of boundary `name`'s prescribed components: a sequence
        of three (None leaves a component as it is) or x=, y=, z=."""
        v = list(value) if value is not None else [x, y, z]
        if len(v) != 3:
            raise InvalidValueError(f"boundary '{name}': give three components, not {len(v)}")
        self._inner.set_displacement(name, [None if c is None else float(c) for c in v])

    def displacement(self, name: str) -> list:
        """The final displacement (m) of each component of boundary `name` (None: free)."""
        return self._inner.displacement(name)

    def measured_points(self, name: str) -> np.ndarray:
        """Positions (m) of the measured points of [measured.NAME], in its file's order."""
        return self._inner.measured_points(name)

    def measured_displacements(self, name: str) -> np.ndarray:
        """The displacements (m) in force at those points (M, 3)."""
        return self._inner.measured_displacements(name)

    def set_measured(self, name: str, displacements: Any) -> None:
        """New displacements (m, shape (M, 3)) measured at the points of [measured.NAME]."""
        a = np.ascontiguousarray(displacements, dtype=float)
        if a.ndim != 2:
            raise InvalidValueError(f"measured '{name}': an array of shape (M, 3) is needed, not {a.shape}")
        self._inner.set_measured(name, a)

    def set_tool_motion(self, name: str, motion: Iterable[float]) -> None:
        """New final displacement (m) of rigid body [contact.NAME] from its reference position."""
        m = [float(c) for c in motion]
        if len(m) != 3:
            raise InvalidValueError(f"contact '{name}': give three components, not {len(m)}")
        self._inner.set_tool_motion(name, m)

    def tool_motion(self, name: str) -> np.ndarray:
        return np.asarray(self._inner.tool_motion(name))

    def set_load_factor(self, name: str, factor: float) -> None:
        """Scales load [loads.NAME] by `factor` (1: as in the scene)."""
        self._inner.set_load_factor(name, float(factor))

    def load_factor(self, name: str) -> float:
        return self._inner.load_factor(name)
