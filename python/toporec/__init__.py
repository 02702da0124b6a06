"""toporec: topological place descriptors from LiDAR, over toporec's Rust core.

* :func:`alpha_persistence`, :class:`AlphaComplex`: persistence diagrams of the 3D alpha
  complex, equal to GUDHI's ``AlphaComplex(points).create_simplex_tree().persistence()`` in its
  ``exact`` precision (squared radii by default).
* :class:`Atol`, :class:`PaperDescriptor`: ATOL vectorization as a scikit-learn estimator,
  equal to ``gudhi.representations.Atol`` for given centres; the TopoRec paper's dimension
  rule (H2, else H1, else H0).
* :class:`Index`: a toporec index's tables as pyarrow Tables, and queries against it.
* :class:`LoopDetector`: loop closures online, scan by scan, as ``toporec loops`` finds them.
* :func:`run`: runs a pipeline file, as ``toporec run`` does.
* :func:`describe_batch`: an Arrow batch of scans to the index's rows (the unit distributed
  engines call).

The GIL is released around every computation; the batch functions use all cores.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from typing import TYPE_CHECKING, Any, Dict, Iterable, Iterator, List, NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np
import pyarrow as pa

from . import _toporec

if TYPE_CHECKING:
    from ._estimator import Atol, PaperDescriptor, paper_diagram

_ESTIMATORS = ("Atol", "PaperDescriptor", "paper_diagram")


def __getattr__(name: str) -> Any:
    # The estimators import scikit-learn (most of a second): only when first used, so that a
    # distributed job's workers, which call describe_batch, start without it.
    if name in _ESTIMATORS:
        from . import _estimator

        return getattr(_estimator, name)
    raise AttributeError(f"module 'toporec' has no attribute {name!r}")


def __dir__() -> List[str]:
    return sorted(list(globals()) + list(_ESTIMATORS))

__version__ = _toporec.__version__
__all__ = [
    "AlphaComplex",
    "Atol",
    "Index",
    "LoopDetector",
    "OptimizedGraph",
    "PaperDescriptor",
    "alpha_persistence",
    "alpha_persistence_batch",
    "alpha_persistence_located",
    "computed_methods",
    "describe_batch",
    "fit",
    "loops",
    "optimize",
    "paper_diagram",
    "read_points",
    "read_scans",
    "run",
]

PathLike = Union[str, "os.PathLike[str]"]


def _points(points: Any, what: str = "points") -> np.ndarray:
    try:
        a = np.ascontiguousarray(points, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what}: cannot be read as float64 coordinates ({e})") from None
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{what}: expected an (n, 3) array of points, got shape {a.shape}")
    return a


def _dims(dims: Iterable[int]) -> List[int]:
    out = [int(d) for d in dims]
    if not out or any(d not in (0, 1, 2) for d in out):
        raise ValueError(f"dims: expected a non-empty list of 0, 1, 2; got {list(dims)}")
    return out


def alpha_persistence(
    points: Any, dims: Sequence[int] = (0, 1, 2), squared: bool = True
) -> Dict[int, np.ndarray]:
    """Persistence diagram of the 3D alpha complex of ``points``.

    Args:
        points: a float64 ``(n, 3)`` array, or anything numpy turns into one (n ≥ 4).
        dims: the homology dimensions wanted.
        squared: squared radii (GUDHI's default) or radii.

    Returns:
        ``{dim: (k, 2) float64 array of (birth, death)}`` for each of ``dims``, rows sorted by
        (birth, death); the essential H0 class dies at ``inf``. Zero-length pairs are dropped,
        as GUDHI's ``persistence()`` does by default.

    Raises:
        ValueError: NaN or infinite coordinates, a shape other than ``(n, 3)``, fewer than 4
            points, or a cloud the exact engine refuses (distinct points closer than 2⁻¹⁰⁰ of
            its extent).
    """
    return _toporec.alpha_persistence(_points(points), _dims(dims), bool(squared))


def alpha_persistence_batch(
    clouds: Iterable[Any], dims: Sequence[int] = (0, 1, 2), squared: bool = True
) -> List[Dict[int, np.ndarray]]:
    """:func:`alpha_persistence` of many clouds, computed in parallel on all cores.

    A bad cloud raises ``ValueError`` naming its position (``cloud 3: ...``).
    """
    arrays = [_points(c, f"cloud {i}") for i, c in enumerate(clouds)]
    return _toporec.alpha_persistence_batch(arrays, _dims(dims), bool(squared))


def alpha_persistence_located(points: Any) -> Tuple[np.ndarray, np.ndarray]:
    """The pairs of :func:`alpha_persistence` (every dimension, squared radii) with where each
    class dies: the centroid of the simplex whose entrance kills it (H0: the merging edge's
    midpoint; H1: the triangle that fills the loop; H2: the tetrahedron that fills the void),
    in the input's coordinates: the topology of a cloud with its place, for descriptors that
    lay it out in space.

    Returns:
        ``(pairs, locations)``: an ``(n, 3)`` array of ``dim, birth, death`` rows and an
        ``(n, 3)`` array of ``x, y, z``, row for row, in no particular order. The pairs are those
        of ``alpha_persistence(points)``; the essential H0 class dies at ``inf`` and has no
        location (NaN).

    Raises:
        ValueError: as :func:`alpha_persistence`.
    """
    return _toporec.alpha_persistence_located(_points(points))


class AlphaSimplexTree:
    """The persistence side of ``gudhi.SimplexTree`` for an alpha complex: what GUDHI code
    calls after ``AlphaComplex(points).create_simplex_tree()``."""

    def __init__(self, points: np.ndarray, squared: bool) -> None:
        self._points = points
        self._squared = squared
        self._diagram: Optional[Dict[int, np.ndarray]] = None

    def _pairs(self) -> Dict[int, np.ndarray]:
        if self._diagram is None:
            self._diagram = alpha_persistence(self._points, (0, 1, 2), self._squared)
        return self._diagram

    def compute_persistence(
        self, homology_coeff_field: int = 11, min_persistence: float = 0.0, persistence_dim_max: bool = False
    ) -> "AlphaSimplexTree":
        """Computes the diagram (GUDHI's signature; only ``min_persistence=0`` is supported:
        zero-length pairs are dropped)."""
        if min_persistence != 0:
            raise ValueError("min_persistence: only 0 is supported (zero-length pairs dropped, as GUDHI's default)")
        self._pairs()
        return self

    def persistence(
        self, homology_coeff_field: int = 11, min_persistence: float = 0.0, persistence_dim_max: bool = False
    ) -> List[Tuple[int, Tuple[float, float]]]:
        """GUDHI's list of ``(dim, (birth, death))``: dimension descending, then length
        ``death − birth`` descending (the essential class first)."""
        self.compute_persistence(homology_coeff_field, min_persistence, persistence_dim_max)
        out = [
            (dim, (float(b), float(d)))
            for dim in (2, 1, 0)
            for b, d in self._pairs()[dim]
        ]
        out.sort(key=lambda x: (-x[0], -(x[1][1] - x[1][0])))
        return out

    def persistence_intervals_in_dimension(self, dimension: int) -> np.ndarray:
        """The ``(k, 2)`` array of dimension ``dimension``'s pairs (``(0, 2)`` when none).

        Rows are sorted by (birth, death); GUDHI returns the same rows in the order of its
        internal pairing."""
        if dimension not in (0, 1, 2):
            return np.empty((0, 2))
        return self._pairs()[dimension].copy()

    def betti_numbers(self) -> List[int]:
        """Betti numbers of the complete complex (the Delaunay triangulation: ``[1, 0, 0]``)."""
        return [int(np.isinf(self._pairs()[d][:, 1]).sum()) for d in (0, 1, 2)]

    def num_vertices(self) -> int:
        """Vertices of the Delaunay complex (duplicate points merged)."""
        return int(_toporec.simplex_counts(self._points)[0])

    def num_simplices(self) -> int:
        """Simplices of the Delaunay complex, all dimensions."""
        return int(sum(_toporec.simplex_counts(self._points)))

    def dimension(self) -> int:
        """Dimension of the complex (3, or less for flat clouds)."""
        counts = _toporec.simplex_counts(self._points)
        return max(i for i, c in enumerate(counts) if c > 0)


class AlphaComplex:
    """Drop-in for ``gudhi.AlphaComplex`` in 3D: ``AlphaComplex(points).create_simplex_tree()``
    then ``.persistence()`` / ``.persistence_intervals_in_dimension(d)``, as in GUDHI, or
    ``AlphaComplex(points).persistence()`` directly.

    Results are those of GUDHI's ``exact`` precision whatever ``precision`` says (toporec's
    engine is exact and faster than GUDHI's ``safe``). Weighted alpha complexes are not
    supported.
    """

    def __init__(self, points: Any = None, weights: Any = None, precision: str = "safe") -> None:
        if weights is not None:
            raise ValueError("weights: weighted alpha complexes are not supported")
        if precision not in ("fast", "safe", "exact"):
            raise ValueError(f"precision: expected 'fast', 'safe' or 'exact'; got {precision!r}")
        self._points = _points([] if points is None else points)
        if len(self._points) < 4:
            raise ValueError(f"points: {len(self._points)} points; the 3D alpha complex needs at least 4")

    def get_point(self, vertex: int) -> List[float]:
        """The coordinates of input point ``vertex``."""
        return [float(x) for x in self._points[vertex]]

    def create_simplex_tree(
        self,
        max_alpha_square: float = float("inf"),
        default_filtration_value: bool = False,
        output_squared_values: bool = True,
    ) -> AlphaSimplexTree:
        """The filtered complex (only the full complex: ``max_alpha_square=inf``)."""
        if max_alpha_square != float("inf") or default_filtration_value:
            raise ValueError("only the full filtered complex is supported (max_alpha_square=inf, default_filtration_value=False)")
        return AlphaSimplexTree(self._points, bool(output_squared_values))

    def persistence(self, **kwargs: Any) -> List[Tuple[int, Tuple[float, float]]]:
        """``create_simplex_tree().persistence()``."""
        return self.create_simplex_tree().persistence(**kwargs)

    def persistence_intervals_in_dimension(self, dimension: int) -> np.ndarray:
        """``create_simplex_tree().persistence_intervals_in_dimension(dimension)``."""
        return self.create_simplex_tree().persistence_intervals_in_dimension(dimension)


def _table(stream: Any) -> pa.Table:
    """A pyarrow Table from an object with ``__arrow_c_stream__`` (buffers shared, not copied)."""
    reader = pa.RecordBatchReader._import_from_c_capsule(stream.__arrow_c_stream__())
    return reader.read_all()


class Index:
    """A toporec index folder (what ``toporec run`` writes).

    Tables come as pyarrow Tables in toporec's schemas (``schemas/`` of the repository), with
    the Hive partition column ``session`` last; their buffers are handed over through the
    Arrow C Data Interface, without a copy.
    """

    def __init__(self, path: PathLike) -> None:
        self.path = os.fspath(path)
        if not os.path.isdir(self.path):
            raise ValueError(f"{self.path}: no such index folder")
        self._engines: Dict[Tuple[str, Tuple[str, ...]], Any] = {}

    def __repr__(self) -> str:
        return f"toporec.Index({self.path!r})"

    def methods(self) -> List[str]:
        """The descriptor methods the index holds (``toporec``, ``scancontext``, ...)."""
        return list(_toporec.index_methods(self.path))

    def info(self) -> Dict[str, Any]:
        """What the index holds, as ``toporec info --json`` prints it: ``sessions`` with scans
        per status, ``methods`` (length, codebook or method id, settings, rows), ``generation``,
        ``files`` and ``bytes`` on disk, and the ``pipeline`` it was made with."""
        return json.loads(_toporec.index_info(self.path))

    def files(self, table: Optional[str] = None, method: Optional[str] = None) -> List[str]:
        """The committed files of one generation (absolute paths), as ``toporec info --files``
        prints them: all of them, or those of ``table`` (``scans``, ``diagrams``,
        ``descriptors``; of ``method`` for descriptors). Hand them to another reader to see
        exactly what toporec sees, for example
        ``duckdb.read_parquet(Index(p).files("scans"), hive_partitioning=True)``. A file a
        later commit replaced is gone: list the files again and read again."""
        return [os.fspath(p) for p in _toporec.index_files(self.path, table, method)]

    def scans(self) -> pa.Table:
        """One row per scan read: ok, skipped or error."""
        return _table(_toporec.index_table(self.path, "scans", None))

    def diagrams(self) -> pa.Table:
        """One row per persistence pair."""
        return _table(_toporec.index_table(self.path, "diagrams", None))

    def descriptors(self, method: Optional[str] = None) -> pa.Table:
        """One row per ok scan: the descriptor of ``method`` (a fixed-size list of float32;
        of uint8 for ``lidar-iris``, its image and its bit-packed template and mask). Without
        ``method``: the index's only method (``toporec-plus`` for what ``toporec.loops`` and
        ``toporec loops <log>`` make), or ``toporec`` among several. A method the index does not
        hold is an error naming the ones it does (see :meth:`methods`)."""
        return _table(_toporec.index_table(self.path, "descriptors", method))

    def query(
        self,
        scans: Union[Any, PathLike, Sequence[Union[Any, PathLike]]],
        k: int = 25,
        method: str = "toporec",
        sessions: Sequence[str] = (),
    ) -> pa.Table:
        """The ``k`` nearest indexed scans of each query, laid out as ``toporec query``'s CSV:
        ``query_id, rank, scan_id, session, distance, pose_x, pose_y, pose_z, yaw_deg, x_m, y_m``
        (``x_m``, ``y_m``: the query's estimated position in the hit's sensor frame, x forward and
        y left, for the methods that estimate one).

        ``scans``: an ``(n, 3)`` array of points in the sensor frame (described as the index
        describes its scans), a path (scan file, cloud, folder or log, as ``toporec query``
        reads it), or a list of either. Array queries are named ``query/<i>``. A query that
        cannot be described is left out with a warning.
        """
        if k < 1:
            raise ValueError(f"k: expected ≥ 1, got {k}")
        key = (method, tuple(sessions))
        engine = self._engines.get(key)
        if engine is None:
            engine = _toporec.QueryEngine(self.path, method, list(sessions))
            self._engines[key] = engine
        items = [scans] if isinstance(scans, (str, os.PathLike, np.ndarray)) else list(scans)
        paths = [os.fspath(s) for s in items if isinstance(s, (str, os.PathLike))]
        arrays = [s for s in items if not isinstance(s, (str, os.PathLike))]
        if paths and arrays:
            raise ValueError("scans: give either points or paths, not both")
        if paths:
            stream, failures = engine.query_paths(paths, int(k))
        else:
            clouds = [_points(a, f"query {i}") for i, a in enumerate(arrays)]
            ids = [f"query/{i}" for i in range(len(clouds))]
            stream, failures = engine.query_points(clouds, ids, int(k))
        for f in failures:
            warnings.warn(f"toporec query: {f}", stacklevel=2)
        return _table(stream)


def run(
    pipeline: PathLike,
    threads: Optional[int] = None,
    index: Optional[PathLike] = None,
    full: bool = False,
) -> Dict[str, Any]:
    """Runs a pipeline file as ``toporec run`` does and returns its summary.

    Args:
        pipeline: the pipeline file (TOML; see docs/pipeline-files.md).
        threads: worker threads (default: all cores).
        index: write the index here instead of the file's ``output.index``.
        full: rebuild the index from scratch instead of updating it.
    """
    threads = (os.cpu_count() or 1) if threads is None else int(threads)
    text = _toporec.run(os.fspath(pipeline), threads, None if index is None else os.fspath(index), bool(full))
    return json.loads(text)


def loops(
    path: Union[PathLike, Sequence[PathLike]],
    method: Union[str, Sequence[str]] = "toporec-plus",
    poses: Optional[PathLike] = None,
    verify: bool = True,
    index: Optional[PathLike] = None,
    threads: Optional[int] = None,
    with_poses: bool = False,
    **options: Any,
) -> Union[pa.Table, Tuple[pa.Table, pa.Table]]:
    """Loop closures of a log (or several sources), as ``toporec loops <source>…`` finds them:
    the sources indexed (into ``index``, default ``out/<first source's name>``, brought up to
    date on the next call), each scan's best earlier match below the method's threshold,
    verified by ICP unless ``verify=False``; where the scans have poses, the map made of the
    odometry and the loops (docs/loops.md), unless ``no_optimize=True``.

    Args:
        path: a ROS 1 bag, a rosbag2 folder, an MCAP file, an NCLT session, a KITTI sequence, a
            folder of PCD/PLY files, or a list of them.
        method: the descriptor method(s) (:func:`computed_methods`).
        poses: a pose file (TUM, KITTI or NCLT layout) instead of the log's own poses.
        verify: check each match by aligning the two scans.
        index: the index folder.
        threads: worker threads (default: all cores).
        with_poses: also return the map's corrected poses.
        options: other options of the command, by name (``topic="/points"``,
            ``poses_topic="/odom"``, ``pose_frames="odom:velodyne"``, ``exclude_seconds=10``,
            ``no_optimize=True``, ``cloud="map.ply"``, ``odometry_drift="0.005,0.001"``);
            ``True`` gives a flag, ``False`` leaves it out.

    Returns:
        The loops table (``schemas/loops.json``): the same columns and rows as the command.
        With ``with_poses=True``, ``(loops, poses)``: ``poses`` is the ``corrected_poses`` table
        (``schemas/corrected_poses.json``: method, session, scan_id, time, x, y, z, qx, qy, qz,
        qw), each method's scans in the map at their corrected sensor poses, the same as the
        command's ``.tum`` files; it has no rows where no map was made (no poses,
        ``no_optimize=True``, or a solve that did not converge: the summary says which).
    """
    import tempfile

    import pyarrow.parquet as pq

    paths = [path] if isinstance(path, (str, os.PathLike)) else list(path)
    methods = [method] if isinstance(method, str) else list(method)
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "loops.parquet")
        args = [os.fspath(p) for p in paths] + ["-o", out, "--no-progress"]
        for m in methods:
            args += ["--method", m]
        if poses is not None:
            args += ["--poses", os.fspath(poses)]
        if not verify:
            args.append("--no-verify")
        if index is not None:
            args += ["--index", os.fspath(index)]
        for name, value in options.items():
            flag = f"--{name.replace('_', '-')}"
            if value is True:
                args.append(flag)
            elif value is not False:
                args += [flag, os.fspath(value) if isinstance(value, os.PathLike) else str(value)]
        _, corrected = _toporec.loops(args, (os.cpu_count() or 1) if threads is None else int(threads))
        table = pq.read_table(out)
        return (table, _table(corrected)) if with_poses else table


class OptimizedGraph(NamedTuple):
    """A pose graph optimized by :func:`optimize`."""

    poses: pa.Table
    """Each vertex's id and optimized pose: ``id, x, y, theta`` (SE(2)) or ``id, x, y, z, qx,
    qy, qz, qw`` (SE(3)), in the file's order."""
    kind: str
    """``"SE(2)"`` or ``"SE(3)"``."""
    cost_before: float
    """½ Σ eᵀ Ω e at the file's poses (GTSAM's ``graph.error``)."""
    cost_after: float
    """The same at the optimized poses."""
    iterations: int
    """Levenberg–Marquardt iterations."""
    rejected: List[Tuple[int, int]]
    """With ``robust=True``: the loops rejected, as (from id, to id)."""
    cost_start: Optional[float] = None
    """With ``start="chordal"``: the cost at the chordal start."""


def optimize(
    graph: PathLike,
    out: Optional[PathLike] = None,
    robust: bool = False,
    max_iterations: int = 1000,
    start: str = "file",
) -> OptimizedGraph:
    """Optimizes a pose graph in g2o's format, as ``toporec optimize`` does (docs/map.md).

    Args:
        graph: the g2o file: ``VERTEX_SE2``/``EDGE_SE2`` or ``VERTEX_SE3:QUAT``/``EDGE_SE3:QUAT``
            lines, ``FIX`` lines for the held vertices (default: the first one).
        out: also write the optimized graph here (the same lines, the vertices moved).
        robust: reject the loops that disagree with the rest (graduated non-convexity).
        max_iterations: Levenberg–Marquardt iterations at most.
        start: ``"file"`` (the file's vertices) or ``"chordal"`` (the chordal relaxation of all
            edges, for a graph whose vertices are far off; docs/map.md).

    Raises:
        ValueError: a malformed line (named by number), a graph in disconnected parts, or a
            solve that does not converge (nothing is written).
    """
    text, ids, values = _toporec.optimize(
        os.fspath(graph), None if out is None else os.fspath(out), bool(robust), int(max_iterations), str(start)
    )
    summary = json.loads(text)
    names = ["x", "y", "theta"] if summary["kind"] == "SE(2)" else ["x", "y", "z", "qx", "qy", "qz", "qw"]
    columns = {"id": pa.array(ids, pa.int64())}
    for k, name in enumerate(names):
        columns[name] = pa.array([v[k] for v in values], pa.float64())
    return OptimizedGraph(
        poses=pa.table(columns),
        kind=summary["kind"],
        cost_before=summary["cost_before"],
        cost_after=summary["cost_after"],
        iterations=summary["iterations"],
        rejected=[tuple(r) for r in summary["rejected"]],
        cost_start=summary["cost_start"],
    )


def fit(
    pipeline: PathLike, sample: float, index: Optional[PathLike] = None, threads: Optional[int] = None
) -> Tuple[str, int]:
    """Fits the pipeline's codebook on a sample of its scans and freezes it in the index, as
    ``toporec fit --pipeline FILE --sample F`` does: the first step of a sharded or Spark job.

    Args:
        pipeline: the pipeline file.
        sample: the fraction of scans, (0, 1], chosen by a hash of the scan id (deterministic).
        index: the index folder (default: the file's ``output.index``).
        threads: worker threads (default: all cores).

    Returns:
        ``(codebook id, scans fitted on)``.
    """
    threads = (os.cpu_count() or 1) if threads is None else int(threads)
    return tuple(
        _toporec.fit_sample(os.fspath(pipeline), None if index is None else os.fspath(index), float(sample), threads)
    )


_describers: Dict[str, Any] = {}

# The input contract of describe_batch, as the library declares it (schemas/batch_inputs.json).
_INPUT_TYPES = {f.name: f.type for f in pa.RecordBatchReader.from_stream(_toporec.batch_input_schema()).schema}


def describe_batch(
    batch: Union[pa.RecordBatch, pa.Table],
    config: PathLike,
    *,
    write_to: Optional[PathLike] = None,
    part_name: Optional[str] = None,
) -> Dict[str, Any]:
    """Describes a batch of scans with an index's settings, frozen codebook and methods.

    Args:
        batch: a pyarrow RecordBatch or Table with a ``path`` column and either ``content``
            (the bytes of a scan file: NCLT ``velodyne_sync/<utime>.bin`` or KITTI
            ``velodyne/<frame>.bin``, as Spark's ``binaryFile`` source reads them; its id,
            session, time and pose come from the path, as ``toporec run`` makes them; a row
            whose ``content`` is missing or null is read from its ``path``) or
            ``points`` (list<float64> of x, y, z, x, y, z ...; with ``scan_id``, and optionally
            ``session``, ``utime``, ``pose_x/y/z/yaw``), or ``format`` = ``mcap`` with
            ``first_message`` and ``message_count``: the scans of that MCAP file whose index
            among its point-cloud messages lies in the range, read from the file (with the
            topic, poses and session of the index's MCAP source that lists it). Optional:
            ``format`` (``nclt``, ``kitti`` or ``mcap``; default: from the path) and ``seq``
            (the position of the row's first scan in the job; default: its row).
        config: the index folder whose settings and codebook are used.
        write_to: a folder to write the diagrams and descriptors to instead of returning
            them (a distributed job's task: ``diagrams/session=<s>/<name>.parquet`` and
            ``descriptors/method=<m>/session=<s>/<name>.parquet`` under it, one file per table
            and session, toporec's own layout, each complete or absent; ``diagrams`` and the
            ``descriptors`` tables are then empty). The same ``part_name`` again replaces the
            files.
        part_name: the file name (without ``.parquet``) with ``write_to``; default: a hash of
            the batch's paths and scan ids, so that a retried task rewrites its own files.

    Returns:
        ``{"scans": Table, "diagrams": Table, "descriptors": {method: Table}}`` in the index's
        schemas with ``session`` last: the rows ``toporec run`` writes for those scans. A scan
        that cannot be read or described is an ``error`` (or ``skipped``) row.
    """
    key = os.path.abspath(os.fspath(config))
    describer = _describers.get(key)
    if describer is None:
        describer = _toporec.BatchDescriber(key)
        _describers[key] = describer
    table = pa.Table.from_batches([batch]) if isinstance(batch, pa.RecordBatch) else batch
    if not isinstance(table, pa.Table):
        raise ValueError(f"batch: expected a pyarrow RecordBatch or Table, got {type(batch).__name__}")
    columns, names = [], []
    for name in table.column_names:
        if name in _INPUT_TYPES:
            column = table.column(name)
            try:
                column = column.cast(_INPUT_TYPES[name])
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as e:
                raise ValueError(f"column `{name}`: cannot be read as {_INPUT_TYPES[name]} ({e})") from None
            columns.append(column)
            names.append(name)
    table = pa.Table.from_arrays(columns, names=names).combine_chunks()
    target = None
    if write_to is not None:
        if part_name is None:
            key = "\n".join(str(v) for c in ("path", "scan_id", "first_message") if c in table.column_names for v in table.column(c).to_pylist())
            part_name = "part-" + hashlib.sha1(key.encode()).hexdigest()[:16]
        target = (os.fspath(write_to), part_name)
    scans, diagrams, descriptors = describer.describe(table.__arrow_c_stream__(), target)
    return {
        "scans": _table(scans),
        "diagrams": _table(diagrams),
        "descriptors": {m: _table(s) for m, s in descriptors},
    }


def computed_methods() -> List[str]:
    """The names of the descriptor methods computed from raw scans (toporec-plus and the
    baselines), as pipeline files, ``toporec query --method`` and :class:`LoopDetector` take them."""
    return list(_toporec.computed_methods())


def read_points(path: PathLike) -> np.ndarray:
    """The points of one scan file (KITTI ``.bin``, NCLT ``velodyne_sync`` ``.bin``, ``.csv``)
    as an ``(n, 3)`` float64 array, in the sensor frame as toporec's sources read them.

    Raises:
        ValueError: the file cannot be read as a cloud (the message names it).
    """
    return _toporec.read_points(os.fspath(path))


def read_scans(path: PathLike, topic: Optional[str] = None) -> Iterator[Dict[str, Any]]:
    """The scans of a source, one at a time, as ``toporec run`` reads them: a ROS 1 bag, a rosbag2
    folder or ``.db3`` file, an MCAP, an NCLT session or a KITTI sequence (docs/sources.md).

    Each scan is a dict: ``scan_id``, ``session``, ``path``, ``utime`` (µs), ``message_index``
    (logs; else None), ``points`` (``(n, 3)`` float64, sensor frame), ``intensity`` (or None),
    ``pose`` (``(x, y, z, yaw)`` when joined, else None). A scan that cannot be read is a dict
    with ``error`` (naming the file and the message) instead of the data, and reading goes on.
    Memory is one scan (one chunk) at a time.

    Args:
        path: the source.
        topic: a log's point-cloud topic (default: its only one).

    Raises:
        ValueError: the path is not a source (a single cloud file: use :func:`read_points`).
    """
    return _toporec.ScanReader(os.fspath(path), topic)


class LoopDetector:
    """Loop closures online: each scan, as it arrives, is described, matched against the earlier
    scans outside its exclusion window, and added. Given the same scans in the same order it
    finds what ``toporec loops`` finds (docs/loops.md).

    Args:
        method: ``"toporec-plus"`` (default) or another method computed from raw scans
            (:func:`computed_methods` lists them).
        exclude_seconds: earlier scans of the same session closer in time are left out.
        threshold: a match below this descriptor distance is a loop; default the method's
            documented one at the default settings (toporec-plus 0.3289, ScanContext 0.5335, RING 0.4544,
            RING++ 0.4390; docs/loops.md), else required.
        exclude_scans: leave out this many preceding scans of the session instead of seconds.
        index: take the method's settings from this index (so the descriptors match its own).
        **settings: the method's settings (the keys of its pipeline-file section).

    The search grows with every scan, without rebuilding; ``add`` releases the GIL.
    """

    def __init__(
        self,
        method: str = "toporec-plus",
        exclude_seconds: float = 30.0,
        threshold: Optional[float] = None,
        exclude_scans: Optional[int] = None,
        index: Optional[PathLike] = None,
        **settings: Any,
    ) -> None:
        if exclude_scans is not None and int(exclude_scans) < 0:
            raise ValueError(f"exclude_scans {exclude_scans}: must be >= 0")
        self._detector = _toporec.LoopDetector(
            method,
            json.dumps(settings or None),
            None if index is None else os.fspath(index),
            float(exclude_seconds),
            None if exclude_scans is None else int(exclude_scans),
            None if threshold is None else float(threshold),
        )
        self.method = method
        #: The threshold below which a match is a loop.
        self.threshold: float = self._detector.threshold
        #: The last scan's best allowed match (accepted or not), or None.
        self.last_match: Optional[Dict[str, Any]] = None

    def add(
        self,
        points: Any,
        time: Optional[float] = None,
        pose: Optional[Sequence[float]] = None,
        session: str = "session",
    ) -> Optional[Dict[str, Any]]:
        """Describes and adds one scan (sensor frame, metres, z up; ``time`` in seconds).

        Returns the accepted loop as a dict — ``match`` (the position of the earlier scan among
        those added, 0 the first), ``distance``, ``yaw_degrees``, ``x_m`` and ``y_m`` (the
        scan's estimated position in the match's sensor frame, x forward and y left, for the
        methods that estimate one, else None), ``rank2_distance``, ``true_distance_m`` (when both
        scans were given a pose) — or None.

        Raises:
            ValueError: the points are not an ``(n, 3)`` array, or the method cannot describe
                the scan (it is then not added).
        """
        a = _points(points)
        p = None if pose is None else tuple(float(v) for v in list(pose)[:3])
        found = self._detector.add(a, None if time is None else float(time), session, p)
        if found is None:
            self.last_match = None
            return None
        row, distance, yaw, offset, rank2, true_distance, accepted = found
        x, y = offset if offset is not None else (None, None)
        self.last_match = {
            "match": row,
            "distance": distance,
            "yaw_degrees": yaw,
            "x_m": x,
            "y_m": y,
            "rank2_distance": rank2,
            "true_distance_m": true_distance,
            "accepted": accepted,
        }
        return self.last_match if accepted else None

    def __len__(self) -> int:
        return len(self._detector)

    @property
    def last_times(self) -> Tuple[float, float]:
        """Seconds the last ``add`` spent describing, and searching plus inserting."""
        return self._detector.last_times()

