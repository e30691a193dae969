"""Recorded runs: the in-memory `Run` type and its HDF5 file format.

One HDF5 file per run. Datasets (N samples, S deflection samples per whisk cycle,
W whiskers, M contacts in total):

    images           (N, H, W_img, 3) uint8   camera frame at maximum protraction
    theta            (N, W)   float32         protraction angle per whisker [rad]
    xy               (N, W, 2) float32        two-axis base deflection per whisker [rad]
    deflection       (N, S, W, 2) float32     xy deflection series over the whisk cycle
    contact_points   (M, 3) float32           world-frame contact points of all cycles
    contact_normals  (M, 3) float32           world-frame unit normals
    contact_offsets  (N + 1,) int64           sample i owns contacts [off[i], off[i+1])
    poses            (N, 3) float64           ground-truth x [m], y [m], yaw [rad]
    times            (N,) float64             simulation time of the sample [s]

Root attributes: ``schema_version`` (integer), ``run_key`` (text; ``scenario_hash`` in older files), ``seed``
(integer), ``name`` (text), ``vitaplace_version`` (text) and ``params`` (text: a JSON
object: robot, camera, environment, ...). Files are written under a temporary name and
renamed when complete.

`open_run` checks a file as thoroughly as the pipeline checks a simulated run before it
reads any array: every attribute's type, every field a dataset (not a group) of the
schema's kind of numbers and shape, and every field's storage actually in the file (a small
file declaring 10^7 samples would otherwise be read as gigabytes of fill values).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from vitaplace.engine import __version__
from vitaplace.engine.base.atomic import atomic_path
from vitaplace.engine.base.errors import UserError

SCHEMA_VERSION = 1

#: field name -> the dtype it is stored and read as (shapes: `_check_shapes`)
FIELDS: dict[str, np.dtype] = {
    "images": np.dtype(np.uint8),
    "theta": np.dtype(np.float32),
    "xy": np.dtype(np.float32),
    "deflection": np.dtype(np.float32),
    "contact_points": np.dtype(np.float32),
    "contact_normals": np.dtype(np.float32),
    "contact_offsets": np.dtype(np.int64),
    "poses": np.dtype(np.float64),
    "times": np.dtype(np.float64),
}


#: the sensors a sample can lack (`Run.missing`, `Run.lacks`): the camera's frame, and the
#: whiskers' signals (theta, xy, the deflection series) and contacts
SENSORS = ("camera", "whiskers")

#: the most samples a simulated run's per-cycle deflection series holds (the robot's
#: ``deflection_samples``)
MAX_DEFLECTION_SAMPLES = 1000

#: a whisker deflection |xy| above this counts as touch at the sampling instant (the same
#: threshold for both touch models and for imported recordings)
TOUCH_THRESHOLD = 0.01


class DatasetError(UserError, ValueError):
    """A dataset file or array set that cannot be used; the message names the file and the problem."""


@dataclass
class Run:
    """One recorded run. Fields are numpy arrays, loaded lazily when the run comes from a file.

    Build one in memory with ``Run.from_arrays(...)``; open a file with ``open_run(path)``.
    """

    name: str
    attrs: dict[str, Any]
    _source: Mapping[str, Any] = field(repr=False)
    _cache: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    path: Path | None = None
    #: feature -> warning about data of this run that feature cannot use (`features.warn_once`); not stored
    warnings: dict[str, str] = field(default_factory=dict, repr=False)
    #: sensor (`SENSORS`) -> (N,) bool, True where the sample lacks that sensor (a drop-out at query
    #: time, set by the pipeline: `dropout_masks`); its data is still there, an extractor must not
    #: use it (docs/plugins.md, Missing modalities). Not stored; read it through `lacks`.
    missing: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @classmethod
    def from_arrays(
        cls,
        *,
        images: np.ndarray,
        theta: np.ndarray,
        xy: np.ndarray,
        poses: np.ndarray,
        times: np.ndarray | None = None,
        deflection: np.ndarray | None = None,
        contact_points: np.ndarray | None = None,
        contact_normals: np.ndarray | None = None,
        contact_offsets: np.ndarray | None = None,
        name: str = "run",
        attrs: Mapping[str, Any] | None = None,
    ) -> Run:
        """Validate shapes and dtypes and build an in-memory run.

        Missing optional fields get neutral values: times = sample index, deflection = the
        single sample ``xy`` (S = 1), no contacts.
        """
        n = len(poses)
        arrays: dict[str, np.ndarray] = {
            "images": np.asarray(images),
            "theta": np.asarray(theta),
            "xy": np.asarray(xy),
            "poses": np.asarray(poses),
            "times": np.arange(n, dtype=np.float64) if times is None else np.asarray(times),
            "deflection": np.asarray(xy)[:, None] if deflection is None else np.asarray(deflection),
            "contact_points": np.zeros((0, 3)) if contact_points is None else np.asarray(contact_points),
            "contact_normals": np.zeros((0, 3)) if contact_normals is None else np.asarray(contact_normals),
            "contact_offsets": (
                np.zeros(n + 1, dtype=np.int64) if contact_offsets is None else np.asarray(contact_offsets)
            ),
        }
        arrays = {key: arrays[key].astype(FIELDS[key], copy=False) for key in FIELDS}
        _check_shapes(arrays, where=name)
        for key, data in arrays.items():
            _check_finite(data, key, name)
        return cls(name=name, attrs=dict(attrs or {}), _source=arrays)

    def __len__(self) -> int:
        return int(self._source["poses"].shape[0])

    def _get(self, key: str) -> np.ndarray:
        if key not in self._cache:
            try:
                data = np.asarray(self._source[key][...])
            except (OSError, RuntimeError, KeyError, ValueError) as exc:  # h5py on damaged data or its header
                message = f"{self.path or self.name}: field '{key}' unreadable ({type(exc).__name__}: {exc})"
                raise DatasetError(message.splitlines()[0]) from None
            _check_finite(data, key, str(self.path or self.name))
            self._cache[key] = data
        return self._cache[key]

    @property
    def images(self) -> np.ndarray:
        return self._get("images")

    @property
    def theta(self) -> np.ndarray:
        return self._get("theta")

    @property
    def xy(self) -> np.ndarray:
        return self._get("xy")

    @property
    def deflection(self) -> np.ndarray:
        return self._get("deflection")

    @property
    def poses(self) -> np.ndarray:
        return self._get("poses")

    @property
    def times(self) -> np.ndarray:
        return self._get("times")

    @property
    def contact_offsets(self) -> np.ndarray:
        return self._get("contact_offsets")

    @property
    def n_whiskers(self) -> int:
        return int(self._source["theta"].shape[1])

    @property
    def image_shape(self) -> tuple[int, int, int]:
        return tuple(self._source["images"].shape[1:])

    def touch_mask(self, threshold: float = TOUCH_THRESHOLD) -> np.ndarray:
        """(N,) bool: samples in which some whisker touches something at the sampling instant,
        i.e. its deflection ``|xy|`` then exceeds ``threshold``. Works for simulated and
        imported runs alike (both touch models and real whiskers record ``xy``)."""
        return np.linalg.norm(self.xy, axis=2).max(axis=1) > threshold

    def lacks(self, sensor: str) -> np.ndarray:
        """(N,) bool: the samples that lack ``sensor`` ("camera" or "whiskers"); all False
        when nothing dropped out."""
        if sensor not in SENSORS:
            raise ValueError(f"unknown sensor {sensor!r}; sensors: {', '.join(SENSORS)}")
        return self.missing.get(sensor, np.zeros(len(self), dtype=bool))

    def validate(self) -> None:
        """Read every numeric field once (images excepted): NaN or infinite values raise
        `DatasetError` naming the field and the first bad sample."""
        for key, dtype in FIELDS.items():
            if dtype.kind == "f":
                self._get(key)

    def image_batch(self, start: int, stop: int) -> np.ndarray:
        """Images ``start:stop`` without loading the whole image stack."""
        if "images" in self._cache:
            return self._cache["images"][start:stop]
        return np.asarray(self._source["images"][start:stop])

    def contacts(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Contact points and normals (each (k, 3)) of sample ``i``'s whisk cycle."""
        off = self.contact_offsets
        lo, hi = int(off[i]), int(off[i + 1])
        return self._get("contact_points")[lo:hi], self._get("contact_normals")[lo:hi]

    def subset(self, index: np.ndarray | slice) -> Run:
        """A new in-memory run holding the samples selected by ``index`` (contacts re-packed, the
        drop-out masks selected too)."""
        idx = np.arange(len(self))[index]
        points, normals, counts = [], [], [0]
        for i in idx:
            p, nrm = self.contacts(int(i))
            points.append(p)
            normals.append(nrm)
            counts.append(len(p))
        run = Run.from_arrays(
            images=self.images[idx],
            theta=self.theta[idx],
            xy=self.xy[idx],
            poses=self.poses[idx],
            times=self.times[idx],
            deflection=self.deflection[idx],
            contact_points=np.concatenate(points) if points else np.zeros((0, 3)),
            contact_normals=np.concatenate(normals) if normals else np.zeros((0, 3)),
            contact_offsets=np.cumsum(counts),
            name=self.name,
            attrs=self.attrs,
        )
        run.missing = {sensor: mask[idx] for sensor, mask in self.missing.items()}
        return run


def dropout_masks(n: int, shares: Mapping[str, float], seed: int) -> dict[str, np.ndarray]:
    """Which of ``n`` samples lack each sensor: ``round(share * n)`` samples per sensor of
    ``shares`` (sensor -> share in [0, 1], summing to at most 1), disjoint (a sample loses at
    most one sensor), taken in `SENSORS` order from one permutation drawn from ``seed``."""
    order = np.random.default_rng(seed).permutation(n)
    masks, start = {}, 0
    for sensor in SENSORS:
        count = min(int(round(shares.get(sensor, 0.0) * n)), n - start)
        mask = np.zeros(n, dtype=bool)
        mask[order[start:start + count]] = True
        masks[sensor], start = mask, start + count
    return masks


def _check_finite(data: np.ndarray, key: str, where: str) -> None:
    """DatasetError naming the field and the first sample with a NaN or infinite value."""
    if data.dtype.kind != "f" or data.size == 0:
        return
    bad = ~np.isfinite(data.reshape(len(data), -1)).all(axis=1) if data.ndim > 1 else ~np.isfinite(data)
    if bad.any():
        raise DatasetError(
            f"{where}: field '{key}' has NaN or infinite values ({int(bad.sum())} rows, first at index "
            f"{int(np.argmax(bad))}); re-record or clean the dataset"
        )


def _check_shapes(arrays: Mapping[str, Any], where: str) -> None:
    """Raise DatasetError unless the arrays have the shapes of the schema."""
    poses = arrays["poses"].shape
    n = poses[0] if poses else None
    points = arrays["contact_points"].shape
    expected = {
        "poses": (n, 3),
        "images": (n, None, None, 3),
        "theta": (n, None),
        "times": (n,),
        "contact_points": (None, 3),
        "contact_normals": (points[0] if points else None, 3),
        "contact_offsets": (n + 1 if n is not None else None,),
    }
    n_whiskers = arrays["theta"].shape[1] if arrays["theta"].ndim == 2 else None
    expected["xy"] = (n, n_whiskers, 2)
    expected["deflection"] = (n, None, n_whiskers, 2)
    for key, shape in expected.items():
        actual = arrays[key].shape
        if len(actual) != len(shape) or any(e is not None and e != a for e, a in zip(shape, actual, strict=True)):
            wanted = "x".join("?" if e is None else str(e) for e in shape)
            raise DatasetError(f"{where}: field '{key}' has shape {actual}, expected {wanted}")
    offsets = np.asarray(arrays["contact_offsets"][...])
    if offsets[0] != 0 or offsets[-1] != arrays["contact_points"].shape[0] or np.any(np.diff(offsets) < 0):
        raise DatasetError(f"{where}: field 'contact_offsets' is not a non-decreasing 0..M index")


def write_run(path: str | os.PathLike, run: Run) -> Path:
    """Write ``run`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        for key in FIELDS:
            data = run._get(key)
            chunks = (1, *data.shape[1:]) if key == "images" and len(data) else None
            f.create_dataset(key, data=data, chunks=chunks)
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["name"] = run.name
        f.attrs["vitaplace_version"] = __version__
        f.attrs["run_key"] = str(run.attrs.get("run_key", ""))
        f.attrs["seed"] = int(run.attrs.get("seed", -1))
        params = {k: v for k, v in run.attrs.items() if k not in ("run_key", "seed")}
        f.attrs["params"] = json.dumps(params, sort_keys=True, default=_json_default)
    return path


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def open_run(path: str | os.PathLike) -> Run:
    """Open a run file lazily; check it is a vitaplace dataset of this schema version."""
    if not isinstance(path, (str, os.PathLike)):
        raise DatasetError(f"path={path!r:.80}: expected the path of a run file (text or a Path)")
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: no such dataset file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise DatasetError(f"{path}: not a readable HDF5 file (truncated or foreign?): {exc}") from None
    try:
        version = f.attrs.get("schema_version")
        if version is None:
            raise DatasetError(f"{path}: not a vitaplace dataset (no 'schema_version' attribute)")
        if _integer(version) != SCHEMA_VERSION:
            shown = _integer(version) if _integer(version) is not None else f"{_shown(version)} (not an integer)"
            raise DatasetError(
                f"{path}: dataset schema version {shown}, this vitaplace reads version {SCHEMA_VERSION}; "
                "re-generate it with `vitaplace simulate`"
            )
        missing = [key for key in FIELDS if key not in f]
        if missing:
            raise DatasetError(f"{path}: dataset lacks field(s) {', '.join(missing)}")
        for key in FIELDS:
            _check_field(f, key, str(path))
        _check_shapes(f, where=str(path))
        attrs = _attributes(f, str(path))
    except DatasetError:
        f.close()
        raise
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:  # h5py on a damaged header or attribute
        f.close()
        raise DatasetError(f"{path}: unreadable HDF5 structure ({type(exc).__name__}: {exc})".splitlines()[0]) from None
    return Run(name=attrs.pop("name", path.stem), attrs=attrs, _source=f, path=path)


def _shown(value: Any) -> str:
    """An attribute's value for a one-line message: its repr, whitespace collapsed, capped."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 40 else text[:37] + "..."


def _integer(value: Any) -> int | None:
    """An HDF5 attribute as an integer, or None when it is not a single integer."""
    value = np.asarray(value)
    return int(value) if value.shape == () and value.dtype.kind in "iu" else None


def _text(value: Any) -> str | None:
    """An HDF5 attribute as text, or None when it is not text."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    return value if isinstance(value, str) else None


def _attributes(f: Any, where: str) -> dict[str, Any]:
    """The run's attributes, each of its schema type (module docstring): ``params``' object
    with ``run_key``, ``seed`` and ``name`` added (files written before the engine split
    call ``run_key`` ``scenario_hash``; it is read under either name)."""
    found: dict[str, Any] = {}
    for key, kind, read in (("run_key", "text", _text), ("scenario_hash", "text", _text), ("name", "text", _text),
                            ("seed", "an integer", _integer),
                            ("params", "text", _text), ("vitaplace_version", "text", _text)):
        if key in f.attrs:
            found[key] = read(f.attrs[key])
            if found[key] is None:
                raise DatasetError(f"{where}: attribute '{key}' is {_shown(f.attrs[key])}, expected {kind}")
    try:
        attrs = json.loads(found.get("params", "{}"))
    except ValueError as exc:
        raise DatasetError(f"{where}: attribute 'params' is not valid JSON ({exc})") from None
    if not isinstance(attrs, dict):
        raise DatasetError(f"{where}: attribute 'params' is {type(attrs).__name__} JSON, expected a JSON object")
    attrs["run_key"] = found.get("run_key", found.get("scenario_hash", ""))
    attrs["seed"] = found.get("seed", -1)
    if "name" in found:
        attrs["name"] = found["name"]
    return attrs


def _check_field(f: Any, key: str, where: str) -> None:
    """Field ``key`` is a dataset of the schema's kind of numbers whose storage is all in the file."""
    item = f.get(key, getlink=False)
    if not isinstance(item, h5py.Dataset):
        raise DatasetError(f"{where}: field '{key}' is a {type(item).__name__.lower()}, expected a dataset")
    wanted = FIELDS[key]
    kinds = "u" if wanted.kind == "u" else ("iu" if wanted.kind == "i" else "f")
    if item.dtype.kind not in kinds or (key == "images" and item.dtype != wanted):
        raise DatasetError(f"{where}: field '{key}' has dtype {item.dtype}, expected {wanted}")
    if item.nbytes == 0:
        return
    if item.chunks is None:
        stored = item.id.get_storage_size() == item.nbytes
    else:
        chunks = int(np.prod([-(-n // c) for n, c in zip(item.shape, item.chunks, strict=True)]))
        stored = item.id.get_num_chunks() == chunks
    if not stored:
        raise DatasetError(
            f"{where}: field '{key}' declares shape {item.shape} but the file does not hold its data "
            "(truncated or forged); re-record or re-import the run"
        )


def shape_problem(run: Run, whiskers: int, image: tuple[int, ...], other: str) -> str | None:
    """Why ``run`` and ``other`` (``whiskers`` whiskers, images of shape ``image``) cannot be
    read by the same fitted method: their whiskers or image sizes differ, in words; None when
    they agree. The one check of a run's shape, for a scenario's runs (`check_runs`) and the
    reference drive of ``WhiskEye-Localise-v0``, a fitted extractor's runs in the API."""
    shown = lambda shape: "x".join(map(str, shape))  # noqa: E731
    name = run.path or repr(run.name)
    if run.n_whiskers != whiskers:
        return f"{name} has {run.n_whiskers} whiskers, {other} {whiskers}"
    if run.image_shape != tuple(image):
        return f"{name} has {shown(run.image_shape)} images, {other} {shown(image)}"
    return None


def recorded_tactile_model(run: Run) -> str | None:
    """The tactile model a run file says its whiskers' xy come from (``robot.tactile_model`` of
    its attributes: simulated runs and `vitaplace import` record it); None for a file that does
    not say (written before it was recorded)."""
    robot = run.attrs.get("robot")
    model = robot.get("tactile_model") if isinstance(robot, dict) else None
    return model if isinstance(model, str) else None


def run_facts(run: Run) -> dict[str, int]:
    """What the manifest (``runs``) and the report say about a run: samples, whisker contacts and
    deflection samples per whisk cycle."""
    return {"samples": len(run), "whisker_contacts": int(run.contact_offsets[-1]),
            "deflection_samples": int(run.deflection.shape[1])}
