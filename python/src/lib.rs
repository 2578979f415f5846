//! Python bindings of hytled: a thin layer over the library's public API
//! ([`hytled::scene`], [`hytled::simulation::Session`]). The Python package `hytled` wraps these
//! classes (python/hytled/__init__.py); units are SI throughout.

use std::path::PathBuf;

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyReadonlyArray2};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use hytled::simulation::Session;
use hytled::solver::Device;

create_exception!(
    _hytled,
    HytledError,
    PyException,
    "An error of hytled; `kind` and `exit_code` as the CLI gives them."
);
create_exception!(
    _hytled,
    InputError,
    HytledError,
    "An input that cannot be used (exit code 2); its subclass names the kind (`input_kind`)."
);
create_exception!(
    _hytled,
    SceneError,
    InputError,
    "A scene that cannot be read or does not follow the schema: `file`, `line`, `key`."
);
create_exception!(
    _hytled,
    FormatError,
    InputError,
    "A data file (mesh, cloud, image, CSV, INP) whose text cannot be parsed: `file`, `line`."
);
create_exception!(
    _hytled,
    MeshError,
    InputError,
    "A mesh, cloud, surface or image that cannot be used: degenerate cells, bad ids, holes."
);
create_exception!(
    _hytled,
    SelectionError,
    InputError,
    "A name that does not exist or a selection that selects nothing: `key`."
);
create_exception!(
    _hytled,
    InvalidValueError,
    InputError,
    "A value out of range or in contradiction with the model: `key`, `value`."
);
create_exception!(
    _hytled,
    UnsupportedError,
    InputError,
    "A combination the chosen method or element does not support."
);
create_exception!(
    _hytled,
    DiscretizationError,
    InputError,
    "Shape functions or constraints that cannot be built from these nodes: `node`."
);
create_exception!(
    _hytled,
    LimitError,
    InputError,
    "A model that would exceed a limit: memory, a count, a time."
);
create_exception!(
    _hytled,
    UnstableError,
    HytledError,
    "The explicit integration diverged or an element inverted (exit code 3)."
);
create_exception!(
    _hytled,
    FileError,
    HytledError,
    "A file that cannot be read or written (exit code 5)."
);
/// `InterruptedRun(HytledError, KeyboardInterrupt)`: a run stopped by SIGINT or SIGTERM (exit
/// codes 130, 143); a KeyboardInterrupt, so code that stops on Ctrl-C stops on it. Made at
/// import (two bases, which `create_exception!` cannot give).
static INTERRUPTED_RUN: pyo3::sync::PyOnceLock<Py<pyo3::types::PyType>> =
    pyo3::sync::PyOnceLock::new();

fn interrupted_run(py: Python<'_>) -> PyResult<&Bound<'_, pyo3::types::PyType>> {
    INTERRUPTED_RUN
        .get_or_try_init(py, || -> PyResult<_> {
            let bases = (
                py.get_type::<HytledError>(),
                py.get_type::<pyo3::exceptions::PyKeyboardInterrupt>(),
            );
            let namespace = PyDict::new(py);
            namespace.set_item(
                "__doc__",
                "A run stopped by SIGINT (Ctrl-C) or SIGTERM (exit codes 130, 143); also a \
                 KeyboardInterrupt. The model is left as it was before the solve.",
            )?;
            namespace.set_item("__module__", "hytled._hytled")?;
            let ty = py.import("builtins")?.getattr("type")?.call1((
                "InterruptedRun",
                bases,
                namespace,
            ))?;
            Ok(ty.cast_into::<pyo3::types::PyType>()?.unbind())
        })
        .map(|t| t.bind(py))
}

/// The Python exception class of an input kind.
fn input_class(kind: hytled::InputKind) -> fn(String) -> PyErr {
    use hytled::InputKind as K;
    match kind {
        K::Scene => SceneError::new_err,
        K::Format => FormatError::new_err,
        K::Mesh => MeshError::new_err,
        K::Selection => SelectionError::new_err,
        K::Value => InvalidValueError::new_err,
        K::Unsupported => UnsupportedError::new_err,
        K::Discretization => DiscretizationError::new_err,
        K::Limit => LimitError::new_err,
    }
}

/// The library's error as the Python exception of its kind, with `kind` and `exit_code`, and
/// the facts the error holds as attributes (None where it has none): `input_kind` ("scene",
/// "format", "mesh", "selection", "value", "unsupported", "discretization", "limit"), `key`,
/// `file`, `line`, `node`, `element`, `value`, `volume` (m^3) of an inverted element and
/// `signal` of an interrupted run.
fn to_py(e: hytled::Error) -> PyErr {
    let msg = e.to_string();
    let err = match &e {
        hytled::Error::Input(f) => input_class(f.kind)(msg),
        hytled::Error::InvalidElement { .. } => MeshError::new_err(msg),
        hytled::Error::Unstable(_) => UnstableError::new_err(msg),
        hytled::Error::Io { .. } => FileError::new_err(msg),
        hytled::Error::Interrupted { .. } => Python::attach(|py| match interrupted_run(py) {
            Ok(ty) => PyErr::from_type(ty.clone(), msg),
            Err(e) => e,
        }),
    };
    let mut facts = e.fault().map(|f| f.facts.clone()).unwrap_or_default();
    let input_kind = match &e {
        hytled::Error::Input(f) => Some(f.kind.name()),
        hytled::Error::InvalidElement { .. } => Some(hytled::InputKind::Mesh.name()),
        _ => None,
    };
    let mut volume = None;
    match &e {
        hytled::Error::Io { path, .. } => facts.file = Some(path.clone()),
        hytled::Error::InvalidElement { element, volume: v } => {
            facts.element = Some(*element);
            facts.value = Some(*v);
            volume = Some(*v);
        }
        _ => {}
    }
    let signal = match &e {
        hytled::Error::Interrupted { signal, .. } => Some(*signal),
        _ => None,
    };
    Python::attach(|py| {
        let v = err.value(py);
        let _ = v.setattr("kind", e.kind());
        let _ = v.setattr("exit_code", e.exit_code());
        let _ = v.setattr("input_kind", input_kind);
        let _ = v.setattr("key", facts.key);
        let _ = v.setattr("file", facts.file.map(|f| f.display().to_string()));
        let _ = v.setattr("line", facts.line);
        let _ = v.setattr("node", facts.node);
        let _ = v.setattr("element", facts.element);
        let _ = v.setattr("value", facts.value);
        let _ = v.setattr("volume", volume);
        let _ = v.setattr("signal", signal);
    });
    err
}

/// A validated scene: from a TOML file or a dict (as JSON), with `--set` style overrides.
#[pyclass(module = "hytled._hytled")]
struct Scene {
    inner: hytled::scene::Scene,
}

#[pymethods]
impl Scene {
    /// Reads and checks a scene file; `overrides` are the CLI's `--set KEY.PATH=VALUE`.
    #[staticmethod]
    #[pyo3(signature = (path, overrides = Vec::new()))]
    fn from_file(path: PathBuf, overrides: Vec<String>) -> PyResult<Self> {
        let inner = hytled::scene::load(&path, &overrides).map_err(to_py)?;
        Ok(Scene { inner })
    }

    /// Reads and checks a scene given as JSON text (a dict through json.dumps); relative
    /// paths resolve against `base_dir`.
    #[staticmethod]
    #[pyo3(signature = (json, base_dir, overrides = Vec::new()))]
    fn from_json(json: &str, base_dir: PathBuf, overrides: Vec<String>) -> PyResult<Self> {
        let inner = hytled::scene::from_json(json, &base_dir, &overrides).map_err(to_py)?;
        Ok(Scene { inner })
    }

    /// The scene's name (or "run").
    #[getter]
    fn name(&self) -> String {
        self.inner.name.clone().unwrap_or_else(|| "run".into())
    }

    /// The scene with every default filled in, as JSON text.
    fn to_json(&self) -> PyResult<String> {
        serde_json_string(&self.inner)
    }
}

fn serde_json_string<T: serde::Serialize>(v: &T) -> PyResult<String> {
    serde_json::to_string(v).map_err(|e| HytledError::new_err(e.to_string()))
}

/// A prepared model: meshed and discretized once, solved as often as its inputs change.
#[pyclass(module = "hytled._hytled")]
struct Model {
    /// The session behind a lock: a Python class may be shared between threads.
    session: std::sync::Mutex<Session>,
}

fn vec3_array(v: &[nalgebra::Vector3<f64>]) -> Array2<f64> {
    let flat: Vec<f64> = v.iter().flat_map(|x| [x.x, x.y, x.z]).collect();
    Array2::from_shape_vec((v.len(), 3), flat).expect("3 per entry")
}

fn rows_array(v: &[[f64; 3]]) -> Array2<f64> {
    let flat: Vec<f64> = v.iter().flatten().copied().collect();
    Array2::from_shape_vec((v.len(), 3), flat).expect("3 per entry")
}

impl Model {
    /// Solves on a worker thread while this one checks Python's signal handlers every 50 ms: a
    /// KeyboardInterrupt asks the solve to stop ([`hytled::interrupt::request`]), and the
    /// session goes back to its state before the solve.
    fn solve_watching_signals(
        &self,
        cold: bool,
    ) -> PyResult<(
        hytled::simulation::Solution,
        hytled::simulation::PointFields,
    )> {
        let mut guard = self.lock();
        let before = guard.checkpoint();
        let session = &mut *guard;
        let (result, stop) = std::thread::scope(|scope| {
            let worker = scope.spawn(|| -> hytled::Result<_> {
                let sol = if cold {
                    session.solve_cold()
                } else {
                    session.solve()
                }?;
                let fields = session.point_fields(&sol.output.u)?;
                Ok((sol, fields))
            });
            let mut stop: Option<PyErr> = None;
            while !worker.is_finished() {
                std::thread::sleep(std::time::Duration::from_millis(50));
                if stop.is_none() {
                    if let Err(e) = Python::attach(|py| py.check_signals()) {
                        hytled::interrupt::request(hytled::interrupt::SIGINT);
                        stop = Some(e);
                    }
                }
            }
            let result = worker.join().unwrap_or_else(|_| {
                Err(hytled::Error::input(
                    hytled::InputKind::Value,
                    "the solve panicked",
                ))
            });
            (result, stop)
        });
        let Some(signal) = stop else {
            return result.map_err(to_py);
        };
        hytled::interrupt::clear();
        guard.restore(before);
        // The handler's own error where it was not a KeyboardInterrupt (a handler of the
        // user's that raised something else).
        let keyboard =
            Python::attach(|py| signal.is_instance_of::<pyo3::exceptions::PyKeyboardInterrupt>(py));
        if !keyboard {
            return Err(signal);
        }
        Err(to_py(match result {
            Err(e @ hytled::Error::Interrupted { .. }) => e,
            _ => hytled::Error::Interrupted {
                signal: hytled::interrupt::SIGINT,
                at: "as the solve ended; its result was dropped".into(),
            },
        }))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Session> {
        loop {
            match self.session.try_lock() {
                Ok(g) => return g,
                // A panic while solving poisons the lock; the session is still whole (errors
                // are values), so it is used as it is.
                Err(std::sync::TryLockError::Poisoned(p)) => return p.into_inner(),
                // Another thread's solve: wait for it without holding the interpreter, which
                // that solve's signal watch needs.
                Err(std::sync::TryLockError::WouldBlock) => Python::attach(|py| {
                    py.detach(|| std::thread::sleep(std::time::Duration::from_millis(2)))
                }),
            }
        }
    }
}

#[pymethods]
impl Model {
    /// Prepares `scene` (meshing, shape functions, masses, boundaries); `device` "cpu" or
    /// "gpu" overrides the scene's `solver.device`.
    #[new]
    #[pyo3(signature = (scene, device = None))]
    fn new(py: Python<'_>, scene: &Scene, device: Option<&str>) -> PyResult<Self> {
        let mut s = scene.inner.clone();
        if let Some(d) = device {
            s.solver.device = match d {
                "cpu" => Device::Cpu,
                "gpu" => Device::Gpu,
                other => {
                    return Err(InvalidValueError::new_err(format!(
                        "device '{other}': give \"cpu\" or \"gpu\""
                    )))
                }
            };
        }
        let session = py.detach(|| Session::new(s)).map_err(to_py)?;
        Ok(Model {
            session: std::sync::Mutex::new(session),
        })
    }

    /// Solves with the inputs as they are: from the last equilibrium where there is one
    /// (relaxation), else from the unloaded state; `cold=True` always from the unloaded state.
    /// Returns a dict of numpy arrays and values (see hytled.Result).
    ///
    /// Ctrl-C (SIGINT) stops the solve within a step and raises InterruptedRun (a
    /// KeyboardInterrupt) with the model as it was before the solve. Another thread's solve
    /// of the same model waits for this one.
    #[pyo3(signature = (cold = false))]
    fn solve<'py>(&self, py: Python<'py>, cold: bool) -> PyResult<Bound<'py, PyDict>> {
        let (sol, fields) = py.detach(|| self.solve_watching_signals(cold))?;
        let d = PyDict::new(py);
        let p = fields.points.len();
        d.set_item("points", vec3_array(&fields.points).into_pyarray(py))?;
        d.set_item(
            "connectivity",
            Array1::from_vec(fields.connectivity.iter().map(|&c| c as i64).collect())
                .into_pyarray(py),
        )?;
        d.set_item(
            "offsets",
            Array1::from_vec(fields.offsets.iter().map(|&c| c as i64).collect()).into_pyarray(py),
        )?;
        d.set_item(
            "cell_types",
            Array1::from_vec(fields.types.clone()).into_pyarray(py),
        )?;
        d.set_item(
            "displacement",
            vec3_array(&fields.displacement).into_pyarray(py),
        )?;
        let tensor =
            |v: &[f64]| Array3::from_shape_vec((p, 3, 3), v.to_vec()).expect("9 per point");
        d.set_item("stress", tensor(&fields.fields.cauchy).into_pyarray(py))?;
        d.set_item("strain", tensor(&fields.fields.green).into_pyarray(py))?;
        d.set_item(
            "von_mises",
            Array1::from_vec(fields.fields.von_mises.clone()).into_pyarray(py),
        )?;
        d.set_item(
            "j",
            Array1::from_vec(fields.fields.j.clone()).into_pyarray(py),
        )?;
        d.set_item(
            "nodal_parameters",
            vec3_array(&sol.output.u).into_pyarray(py),
        )?;
        d.set_item("summary", serde_json_string(&sol.summary)?)?;
        d.set_item("steps", sol.output.steps)?;
        d.set_item("warm", sol.warm)?;
        d.set_item("converged", sol.summary.converged)?;
        Ok(d)
    }

    /// Forgets the last equilibrium: the next solve starts from the unloaded state.
    fn forget(&self) {
        self.lock().forget();
    }

    /// Whether the next solve starts from the last equilibrium.
    #[getter]
    fn warm(&self) -> bool {
        self.lock().is_warm()
    }

    /// Seconds the preparation took.
    #[getter]
    fn prepare_seconds(&self) -> f64 {
        self.lock().prepare_seconds()
    }

    /// Reference positions of the model's nodes, m (N, 3).
    #[getter]
    fn nodes<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f64>> {
        vec3_array(&self.lock().prepared().model.nodes()).into_pyarray(py)
    }

    /// Warnings of the preparation (messages).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        let s = self.lock();
        s.prepared()
            .warnings
            .iter()
            .map(|w| w.message.clone())
            .collect()
    }

    /// The kind of each warning of the preparation, in order ("input", "discretization",
    /// "boundary", "contact", "steady_frames", "solve", "resolve").
    #[getter]
    fn warning_kinds(&self) -> Vec<&'static str> {
        let s = self.lock();
        s.prepared()
            .warnings
            .iter()
            .map(|w| w.kind.name())
            .collect()
    }

    /// Names of the boundaries (measured ones included), loads and rigid bodies.
    #[getter]
    fn boundary_names(&self) -> Vec<String> {
        let s = self.lock();
        let m = &s.prepared().model;
        m.boundaries().iter().map(|b| b.name.clone()).collect()
    }

    #[getter]
    fn load_names(&self) -> Vec<String> {
        self.lock().prepared().model.loads().names().to_vec()
    }

    #[getter]
    fn tool_names(&self) -> Vec<String> {
        let s = self.lock();
        let m = &s.prepared().model;
        m.contact()
            .as_ref()
            .map(|c| c.names().map(String::from).collect())
            .unwrap_or_default()
    }

    /// New final displacement (m) of boundary `name`'s prescribed components; None leaves one.
    fn set_displacement(&self, name: &str, value: [Option<f64>; 3]) -> PyResult<()> {
        self.lock().set_displacement(name, value).map_err(to_py)
    }

    /// The final displacement (m) of each component of boundary `name` (None: free).
    fn displacement(&self, name: &str) -> PyResult<[Option<f64>; 3]> {
        self.lock().displacement(name).map_err(to_py)
    }

    /// Positions (m) of the measured points of `[measured.NAME]`, in its file's order (M, 3).
    fn measured_points<'py>(
        &self,
        py: Python<'py>,
        name: &str,
    ) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
        let p = self.lock().measured_points(name).map_err(to_py)?;
        Ok(rows_array(&p).into_pyarray(py))
    }

    /// Displacements (m) in force at the measured points of `[measured.NAME]` (M, 3).
    fn measured_displacements<'py>(
        &self,
        py: Python<'py>,
        name: &str,
    ) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
        let u = self.lock().measured_displacements(name).map_err(to_py)?;
        Ok(rows_array(&u).into_pyarray(py))
    }

    /// New displacements (m) measured at the points of `[measured.NAME]` (M, 3).
    fn set_measured(&self, name: &str, u: PyReadonlyArray2<'_, f64>) -> PyResult<()> {
        let a = u.as_array();
        if a.ncols() != 3 {
            return Err(InvalidValueError::new_err(format!(
                "measured '{name}': an array of shape (M, 3) is needed, not {:?}",
                a.shape()
            )));
        }
        let rows: Vec<[f64; 3]> = a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
        self.lock().set_measured(name, &rows).map_err(to_py)
    }

    /// New final displacement (m) of rigid body `[contact.NAME]` from its reference position.
    fn set_tool_motion(&self, name: &str, motion: [f64; 3]) -> PyResult<()> {
        self.lock().set_tool_motion(name, motion).map_err(to_py)
    }

    /// The final displacement (m) of rigid body `[contact.NAME]`.
    fn tool_motion(&self, name: &str) -> PyResult<[f64; 3]> {
        self.lock().tool_motion(name).map_err(to_py)
    }

    /// Scales load `[loads.NAME]` by `factor` (1: as in the scene).
    fn set_load_factor(&self, name: &str, factor: f64) -> PyResult<()> {
        self.lock().set_load_factor(name, factor).map_err(to_py)
    }

    /// The factor of load `[loads.NAME]`.
    fn load_factor(&self, name: &str) -> PyResult<f64> {
        self.lock().load_factor(name).map_err(to_py)
    }
}

/// The compiled part of the hytled package.
/// The 3-D image at `path` (NIfTI-1 `.nii`/`.nii.gz`, NRRD `.nrrd`/`.nhdr`) as hytled reads
/// it: the voxel values (scaled as the file says) indexed [i, j, k], and the 4x4 map from voxel
/// index to world position (RAS, m).
#[pyfunction]
fn read_image<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(
    Bound<'py, numpy::PyArray3<f64>>,
    Bound<'py, numpy::PyArray2<f64>>,
)> {
    let image = hytled::io::image::read_image(&path).map_err(to_py)?;
    let [ni, nj, nk] = image.dims;
    let values =
        Array3::from_shape_fn((ni, nj, nk), |(i, j, k)| image.values[image.index(i, j, k)]);
    let affine = Array2::from_shape_fn((4, 4), |(r, c)| image.to_world[(r, c)]);
    Ok((values.into_pyarray(py), affine.into_pyarray(py)))
}

/// The dimensions and runs of a sweep as JSON (`{"dimensions": [...], "runs": [...]}`), the
/// CLI's `hytled sweep` product: `vary` as `KEY.PATH=V1,V2,...`, `presets` as
/// `NAME=KEY.PATH=V;...`, `set` the fixed overrides.
#[pyfunction]
fn sweep_plan(
    scene: PathBuf,
    vary: Vec<String>,
    presets: Vec<String>,
    set: Vec<String>,
) -> PyResult<String> {
    let varies = vary
        .iter()
        .map(|v| hytled::sweep::parse_vary(v))
        .collect::<hytled::Result<Vec<_>>>()
        .map_err(to_py)?;
    let presets = parse_presets(&presets)?;
    let (dims, runs) = hytled::sweep::prepare(&scene, &set, &varies, &presets).map_err(to_py)?;
    serde_json::to_string(&serde_json::json!({ "dimensions": dims, "runs": runs }))
        .map_err(|e| HytledError::new_err(e.to_string()))
}

fn parse_presets(presets: &[String]) -> PyResult<std::collections::BTreeMap<String, Vec<String>>> {
    let mut out = std::collections::BTreeMap::new();
    for p in presets {
        let (name, sets) = hytled::sweep::parse_preset(p).map_err(to_py)?;
        if out.insert(name.clone(), sets).is_some() {
            return Err(to_py(hytled::Error::input(
                hytled::InputKind::Value,
                format!("preset {name} is given twice"),
            )));
        }
    }
    Ok(out)
}

/// Runs one planned run (JSON of `sweep_plan`'s `runs`) on `threads` threads, writing its
/// row and summary under `out/runs/<id>` when `out` is given; the row as JSON. A failed run
/// is a row with its error; the GIL is released meanwhile.
#[pyfunction]
#[pyo3(signature = (scene, planned, out=None, keep_outputs=false, repeat=1, threads=None))]
fn sweep_run(
    py: Python<'_>,
    scene: PathBuf,
    planned: &str,
    out: Option<PathBuf>,
    keep_outputs: bool,
    repeat: usize,
    threads: Option<usize>,
) -> PyResult<String> {
    let p: hytled::sweep::runs::Planned =
        serde_json::from_str(planned).map_err(|e| HytledError::new_err(e.to_string()))?;
    let opts = hytled::sweep::SweepOptions {
        out,
        keep_outputs,
        repeat,
        ..Default::default()
    };
    let row = py
        .detach(|| hytled::sweep::runs::execute_on(&scene, &p, &opts, threads, true))
        .map_err(to_py)?;
    serde_json_string(&row)
}

/// The rows a sweep in `out` finished before (JSON list), for `planned` (JSON list of runs):
/// those a resumed sweep keeps.
#[pyfunction]
fn sweep_finished(out: PathBuf, planned: &str) -> PyResult<String> {
    let runs: Vec<hytled::sweep::runs::Planned> =
        serde_json::from_str(planned).map_err(|e| HytledError::new_err(e.to_string()))?;
    let rows: Vec<hytled::sweep::SweepRow> = runs
        .iter()
        .filter_map(|p| hytled::sweep::runs::finished(&out, p))
        .collect();
    serde_json_string(&rows)
}

/// Rewrites the sweep's table (sweep.csv, sweep.md, sweep.json, the plots) in `out`,
/// atomically, from the rows so far (JSON list) of `planned` runs.
#[pyfunction]
fn sweep_table(
    out: PathBuf,
    scene: PathBuf,
    dimensions: &str,
    presets: Vec<String>,
    rows: &str,
    planned: usize,
) -> PyResult<()> {
    let dims: Vec<hytled::sweep::Vary> =
        serde_json::from_str(dimensions).map_err(|e| HytledError::new_err(e.to_string()))?;
    let rows: Vec<hytled::sweep::SweepRow> =
        serde_json::from_str(rows).map_err(|e| HytledError::new_err(e.to_string()))?;
    let presets = parse_presets(&presets)?;
    hytled::sweep::write_table(&out, &scene, &dims, &presets, &rows, planned).map_err(to_py)
}

#[pymodule]
fn _hytled(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<Scene>()?;
    m.add_class::<Model>()?;
    m.add_function(wrap_pyfunction!(read_image, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_plan, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_run, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_finished, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_table, m)?)?;
    m.add("HytledError", py.get_type::<HytledError>())?;
    m.add("SceneError", py.get_type::<SceneError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("UnstableError", py.get_type::<UnstableError>())?;
    m.add("FileError", py.get_type::<FileError>())?;
    let inputs = [
        (py.get_type::<SceneError>(), hytled::InputKind::Scene),
        (py.get_type::<FormatError>(), hytled::InputKind::Format),
        (py.get_type::<MeshError>(), hytled::InputKind::Mesh),
        (
            py.get_type::<SelectionError>(),
            hytled::InputKind::Selection,
        ),
        (py.get_type::<InvalidValueError>(), hytled::InputKind::Value),
        (
            py.get_type::<UnsupportedError>(),
            hytled::InputKind::Unsupported,
        ),
        (
            py.get_type::<DiscretizationError>(),
            hytled::InputKind::Discretization,
        ),
        (py.get_type::<LimitError>(), hytled::InputKind::Limit),
    ];
    for (ty, kind) in &inputs {
        m.add(ty.name()?, ty)?;
        ty.setattr("input_kind", kind.name())?;
        let class = if *kind == hytled::InputKind::Scene {
            "scene"
        } else {
            "input"
        };
        ty.setattr("kind", class)?;
    }
    m.add("InterruptedRun", interrupted_run(py)?)?;
    // Each class carries its CLI kind and exit code, so an error raised without them (an
    // argument checked here) still has both.
    for (ty, kind, code) in [
        (py.get_type::<HytledError>(), "error", 1),
        (py.get_type::<InputError>(), "input", 2),
        (py.get_type::<UnstableError>(), "unstable", 3),
        (py.get_type::<FileError>(), "io", 5),
    ] {
        ty.setattr("kind", kind)?;
        ty.setattr("exit_code", code)?;
    }
    // Every fact is an attribute of every error, None where it has none (an error raised in
    // Python, or one that does not know it).
    for fact in [
        "input_kind",
        "key",
        "file",
        "line",
        "node",
        "element",
        "value",
        "volume",
        "signal",
    ] {
        py.get_type::<HytledError>().setattr(fact, py.None())?;
    }
    interrupted_run(py)?.setattr("kind", "interrupted")?;
    interrupted_run(py)?.setattr("exit_code", 130)?;
    // numpy's C API is imported now: imported first inside a solve's result, a pending
    // Ctrl-C made the import fail and the numpy crate panic (issue 56).
    let _ = numpy::PyArray1::<f64>::zeros(py, 0, false);
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
