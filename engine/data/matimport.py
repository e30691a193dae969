"""Import MultiPredNet / WhiskEye MATLAB recordings as a `Run`.

The layout read by the MultiPredNet scripts (github.com/TomKnowles1994/MultiPredNet,
``load_mat_data``): a folder with

    images.mat   variable ``images``: 45 x 80 x 3 x N (uint8 or float in [0, 1]), or a
                 1 x N cell array of 45 x 80 x 3 frames (what ``np.array(images.tolist())[0]``
                 in the original loader unpacks), or N x 45 x 80 x 3
    theta.mat    variable ``theta``: 4 x 6 x N  (column x row-board x sample) [rad]
    xy.mat       variable ``xy``:    2 x 4 x 6 x N  (axis x column x row-board x sample)
    poses.mat    N x 3 (or 3 x N) x, y, yaw - e.g. ``pose_return`` of ``extract_poses.m``;
                 without poses.mat, ``pose_return.mat`` (``save pose_return.mat pose_return``);
                 a 3 x 3 array (N = 3) fits both layouts and is refused unless
                 ``pose_layout`` ("Nx3" or "3xN") says which

Images are never guessed at. Arrays are read as the MATLAB class they declare (a v5 file may
store a double array in a smaller integer type; a v7.3 file names the class in an attribute).
An integer class holds 0..255. A double or single class holds [0, 1] when every value lies
there, 0..255 when every value is a whole number of 0..255 (``double(uint8_image)``); any
other float array (e.g. [0, 1] frames that bicubic resizing overshot to 1.004) is refused
unless ``image_range`` ("0-1": saturated like ``im2uint8``, or "0-255") says which. Values
outside both [0, 1] and [0, 255] are refused always, with their count; complex arrays and
logical images too, and theta or xy beyond float32's range (a run file's type for them).

When a file does not hold the expected variable name (``images``, ``theta``, ``xy``,
``poses``/``pose``/``pose_return``), its single non-``__dunder__`` variable is used. MATLAB
v5 files are read with scipy, v7.3 files (HDF5) with h5py: there every array is stored with
its dimensions reversed (MATLAB is column-major) and a cell array is an array of object
references into ``#refs#``; both are undone here. Whisker ``(column c, board r)`` becomes
vitaplace whisker index ``r * 4 + c`` (see `vitaplace.engine.sim.robot`).

Every error is one line naming the file, the variable and what was expected.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.data.dataset import DatasetError, Run

__all__ = ["import_mat", "load_mat_variable", "IMAGE_RANGES", "POSE_LAYOUTS"]

#: how ``image_range`` states the range of float frames
IMAGE_RANGES = ("0-1", "0-255")
#: how ``pose_layout`` states the layout of a 3 x 3 pose array
POSE_LAYOUTS = ("Nx3", "3xN")
#: numpy dtypes of the MATLAB numeric classes (a v7.3 file names its variables' class)
_CLASSES = {"double": np.float64, "single": np.float32, "uint8": np.uint8, "int8": np.int8, "uint16": np.uint16,
            "int16": np.int16, "uint32": np.uint32, "int32": np.int32, "uint64": np.uint64, "int64": np.int64,
            "logical": np.bool_}  # logical: stored as uint8 0/1, read as bool so that images can refuse it

_NAMES = {
    "images": ("images", "image", "imgs"),
    "theta": ("theta",),
    "xy": ("xy",),
    "poses": ("poses", "pose", "pose_return", "pose_head"),
}
#: What each variable must hold, for error messages.
_EXPECTED = {
    "images": "45 x 80 x 3 x N (H x W x 3 x N) or a 1 x N cell array of H x W x 3 frames",
    "theta": "4 x 6 x N",
    "xy": "2 x 4 x 6 x N",
    "poses": "N x 3 (x, y, yaw)",
}
#: Where the poses may be: poses.mat, else pose_return.mat (the output of extract_poses.m).
POSE_FILES = ("poses.mat", "pose_return.mat")
#: The largest float32, as a Python float (theta and xy are float32 in a run file).
_F32_MAX = float(np.finfo(np.float32).max)
#: Cells nested deeper than this in a v7.3 file are refused (frames are one level deep).
_MAX_CELL_DEPTH = 4


def load_mat_variable(path: Path, kind: str) -> np.ndarray:
    """The array stored in ``path`` for ``kind`` (one of images, theta, xy, poses)."""
    return _load(path, kind)[1]


def _load(path: Path, kind: str) -> tuple[str, np.ndarray]:
    """(variable name, array) of ``kind`` in the MATLAB file ``path``."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing MATLAB file; expected variable '{_NAMES[kind][0]}' ({_EXPECTED[kind]})")
    try:
        variables = _read_mat(path)
    except DatasetError:
        raise
    except Exception as exc:  # scipy and h5py raise ValueError/TypeError/OSError/... on garbage
        raise DatasetError(f"{path}: not a readable MATLAB .mat file: {exc}") from None
    found = next(((name, variables[name]) for name in _NAMES[kind] if name in variables), None)
    if found is None and len(variables) == 1:
        found = next(iter(variables.items()))
    if found is not None:
        _check_real(found[1], f"{path}: variable '{found[0]}'")
        return found
    raise DatasetError(
        f"{path}: cannot tell which variable holds {kind}: expected one named "
        f"{' or '.join(repr(n) for n in _NAMES[kind])} or a single variable, found {sorted(variables)}"
    )


def _read_mat(path: Path) -> dict[str, Any]:
    import h5py
    import scipy.io

    if h5py.is_hdf5(path):  # MATLAB v7.3
        return _read_mat73(path)
    data = {k: v for k, v in scipy.io.loadmat(path).items() if not k.startswith("__")}
    # each variable as its declared class, not the smaller type MATLAB may have stored it in
    # (complex arrays are left as they are, for `_check_real` to refuse)
    for name, _, declared in scipy.io.whosmat(path):
        value = data.get(name)
        if declared == "cell" and isinstance(value, np.ndarray):  # a cell's elements say their class in mat_dtype
            typed = scipy.io.loadmat(path, variable_names=[name], mat_dtype=True)[name]
            for index, cell in np.ndenumerate(typed):
                if isinstance(cell, np.ndarray) and cell.dtype == np.bool_:
                    value[index] = cell
        elif declared in _CLASSES and isinstance(value, np.ndarray) and not np.iscomplexobj(value):
            data[name] = value.astype(_CLASSES[declared], copy=False)
    return data


def _read_mat73(path: Path) -> dict[str, Any]:
    import h5py

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        for key, item in f.items():
            if key.startswith("#") or not isinstance(item, h5py.Dataset):
                continue
            out[key] = _mat73_value(f, item, f"{path}: variable {key!r}", 0)
    return out


def _mat73_value(f: Any, item: Any, where: str, depth: int) -> np.ndarray:
    """A v7.3 dataset as MATLAB sees it: dimensions reversed back, a cell array (object
    references into ``#refs#``) as an object array of its elements."""
    import h5py

    if item.attrs.get("MATLAB_empty", 0):  # an empty array stores its dimensions as data
        return np.zeros((0,))
    if item.dtype.names is not None and {"real", "imag"} <= set(item.dtype.names):
        raise DatasetError(f"{where} is complex; expected real values")
    data = np.asarray(item[()])
    if h5py.check_dtype(ref=item.dtype) is None:
        declared = item.attrs.get("MATLAB_class", b"")
        declared = declared.decode(errors="replace") if isinstance(declared, bytes) else str(declared)
        return data.T.astype(_CLASSES[declared], copy=False) if declared in _CLASSES else data.T
    if depth >= _MAX_CELL_DEPTH:
        raise DatasetError(f"{where}: cell arrays nested more than {_MAX_CELL_DEPTH} deep")
    cells = np.empty(data.shape, dtype=object)
    for index, ref in np.ndenumerate(data):
        if not ref:
            raise DatasetError(f"{where}: cell {index[::-1]} holds a null reference")
        cells[index] = _mat73_value(f, f[ref], where, depth + 1)
    return cells.T


def _check_real(arr: Any, where: str) -> None:
    """DatasetError when ``arr`` (or a cell of it) is complex: its imaginary part would be dropped."""
    cells = arr.ravel() if isinstance(arr, np.ndarray) and arr.dtype == object else [arr]
    if any(np.iscomplexobj(cell) for cell in cells):
        raise DatasetError(f"{where} is complex; expected real values")


def _check_finite(arr: np.ndarray, path: Path, name: str) -> None:
    """DatasetError naming file and variable when there are no samples (last axis) or one
    holds NaN or inf."""
    if arr.shape[-1] == 0:
        raise DatasetError(f"{path}: variable '{name}' holds no samples; expected at least one")
    bad = ~np.isfinite(arr.reshape(-1, arr.shape[-1])).all(axis=0)
    if bad.any():
        raise DatasetError(
            f"{path}: variable '{name}' has NaN or infinite values in {int(bad.sum())} sample(s) (first: sample "
            f"{int(np.argmax(bad))}, counting from 0); expected finite values"
        )


def _numeric(path: Path, kind: str) -> np.ndarray:
    """theta (4 x 6 x N) or xy (2 x 4 x 6 x N) from ``path``, checked: shape, numbers, finite."""
    lead = {"theta": (4, 6), "xy": (2, 4, 6)}[kind]
    name, raw = _load(path, kind)
    try:
        arr = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{path}: variable '{name}' is not a numeric array; expected {_EXPECTED[kind]}") from None
    if arr.shape == lead:  # MATLAB drops the trailing N = 1
        arr = arr[..., None]
    if arr.ndim != len(lead) + 1 or arr.shape[: len(lead)] != lead:
        raise DatasetError(f"{path}: variable '{name}' has shape {arr.shape}, expected {_EXPECTED[kind]}")
    if arr.shape[-1] == 0:
        raise DatasetError(f"{path}: variable '{name}' holds no samples; expected {_EXPECTED[kind]}")
    _check_finite(arr, path, name)
    largest = float(np.abs(arr).max())
    if largest > _F32_MAX:  # a run file stores theta and xy as float32: they would become inf
        raise DatasetError(
            f"{path}: variable '{name}' has {int(np.count_nonzero(np.abs(arr) > _F32_MAX))} value(s) beyond "
            f"float32's range (largest magnitude {largest:.6g}); expected values within +-{_F32_MAX:.6g}, as a run "
            f"file stores {kind} as float32"
        )
    return arr


def _poses(folder: Path, layout: str | None = None) -> tuple[Path, np.ndarray]:
    """(file, N x 3 poses) from poses.mat, or pose_return.mat when there is no poses.mat;
    ``layout`` ("Nx3" or "3xN") states which a 3 x 3 array is."""
    path = next((folder / f for f in POSE_FILES if (folder / f).is_file()), folder / POSE_FILES[0])
    if not path.is_file():
        raise DatasetError(
            f"{path}: missing MATLAB file (nor is there {POSE_FILES[1]}); expected variable 'poses' or "
            f"'pose_return' ({_EXPECTED['poses']})"
        )
    name, raw = _load(path, "poses")
    try:
        poses = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{path}: variable '{name}' is not a numeric array; expected {_EXPECTED['poses']}") from None
    if poses.ndim == 1 and poses.shape[0] == 3:
        poses = poses[None]
    if poses.shape == (3, 3) and layout is None:
        raise DatasetError(
            f"{path}: variable '{name}' is 3 x 3: three poses as rows (N x 3) or as columns (3 x N)? "
            "state it with --pose-layout Nx3 or --pose-layout 3xN"
        )
    if poses.ndim == 2 and poses.shape[0] == 3 and (layout == "3xN" or (layout is None and poses.shape[1] != 3)):
        poses = poses.T
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise DatasetError(f"{path}: variable '{name}' has shape {poses.shape}, expected {_EXPECTED['poses']}")
    _check_finite(poses.T, path, name)
    return path, poses


def _cell_frames(arr: np.ndarray, where: str) -> np.ndarray:
    """N x H x W x 3 from a cell array of H x W x 3 frames, all of one size."""
    frames = [np.asarray(x) for x in arr.ravel()]
    if not frames or any(fr.ndim != 3 or fr.shape[2] != 3 for fr in frames):
        shapes = sorted({fr.shape for fr in frames})[:3]
        raise DatasetError(f"{where} is a cell array of frames of shape {shapes}, expected H x W x 3 frames")
    if len({fr.shape for fr in frames}) != 1:
        raise DatasetError(f"{where}: the frames of the cell array differ in size, expected all H x W x 3 alike")
    return np.stack(frames)


def _frames(raw: np.ndarray, where: str) -> np.ndarray:
    """``raw`` as N x H x W x 3 (from a cell array, H x W x 3 x N, one H x W x 3 frame or N x H x W x 3)."""
    if raw.dtype == object:  # cell array of frames
        return _cell_frames(raw, where)
    if raw.ndim == 4 and raw.shape[2] == 3:
        return np.transpose(raw, (3, 0, 1, 2))  # H x W x 3 x N -> N x H x W x 3
    if raw.ndim == 3 and raw.shape[2] == 3:
        return raw[None]  # a single frame
    if not (raw.ndim == 4 and raw.shape[3] == 3):
        raise DatasetError(f"{where} has shape {raw.shape}, expected {_EXPECTED['images']}")
    return raw


def _check_frame_values(arr: np.ndarray, path: Path, name: str, where: str) -> None:
    """At least one frame, of a numeric class, finite, every value inside [0, 255]."""
    if len(arr) == 0:
        raise DatasetError(f"{where} holds no frames, expected {_EXPECTED['images']}")
    if arr.dtype == np.bool_:
        raise DatasetError(f"{where} is of MATLAB class logical (true/false); expected uint8 (0..255), or double "
                           "or single in [0, 1] or whole numbers of 0..255")
    if arr.dtype.kind not in "uif":
        raise DatasetError(f"{where} has dtype {arr.dtype}, expected uint8 or float in [0, 1]")
    if arr.dtype.kind == "f":
        _check_finite(np.moveaxis(arr, 0, -1), path, name)
    outside = int(np.count_nonzero((arr < 0) | (arr > 255)))
    if outside:
        raise DatasetError(
            f"{where} has {outside} value(s) outside both [0, 1] and [0, 255]; expected uint8 or float in [0, 1]")


def _images(raw: np.ndarray, path: Path, name: str = "images", image_range: str | None = None) -> np.ndarray:
    """N x H x W x 3 uint8 frames from the variable ``name`` of ``path`` (range: module docstring)."""
    where = f"{path}: variable '{name}'"
    arr = _frames(raw, where)
    _check_frame_values(arr, path, name, where)
    if image_range is None:
        image_range = _image_range(arr, where)
    if image_range == "0-1":
        arr = np.clip(arr.astype(np.float64) * 255.0, 0, 255)  # saturates what overshot 1, as im2uint8 does
    return np.ascontiguousarray(np.rint(arr), dtype=np.uint8)


def _image_range(arr: np.ndarray, where: str) -> str:
    """"0-1" or "0-255" as the class and the whole array say; DatasetError when they do not."""
    if arr.dtype.kind in "ui" or np.all(arr <= 1.0):
        return "0-255" if arr.dtype.kind in "ui" else "0-1"
    if np.all(arr == np.rint(arr)):
        return "0-255"
    above = int(np.count_nonzero(arr > 1.0))
    raise DatasetError(
        f"{where} is {arr.dtype} with {above} value(s) above 1 (largest {float(arr.max()):.6g}) that are not whole "
        "numbers of 0..255: cannot tell its range; state it with --image-range 0-1 (values above 1 saturate) or 0-255"
    )


def import_mat(
    directory: str | os.PathLike, name: str | None = None, image_range: str | None = None,
    pose_layout: str | None = None,
    tactile_model: str = "physical",
) -> Run:
    """Read a MultiPredNet/WhiskEye recording folder into an in-memory `Run`; ``image_range``
    and ``pose_layout`` state what the arrays cannot say (module docstring), ``tactile_model``
    what the whiskers' xy are (recorded as the run's ``robot.tactile_model``: physical, the
    WhiskEye's sprung whiskers, as MultiPredNet's Gazebo recordings; or penetration).

    Raises `DatasetError` naming the file when one is missing, unreadable or misshaped.
    Deflection series and contacts are not part of this layout: the run gets the single
    ``xy`` sample as its deflection series (S = 1) and no contacts.
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder with images.mat, theta.mat, xy.mat and poses.mat")
    images_name, raw = _load(folder / "images.mat", "images")
    images = _images(raw, folder / "images.mat", images_name, image_range)
    n = images.shape[0]
    theta = _numeric(folder / "theta.mat", "theta")
    xy = _numeric(folder / "xy.mat", "xy")
    poses_path, poses = _poses(folder, pose_layout)

    counts = {"images.mat": n, "theta.mat": theta.shape[2], "xy.mat": xy.shape[3], poses_path.name: poses.shape[0]}
    if len(set(counts.values())) != 1:
        raise DatasetError(
            f"{folder}: the files hold different numbers of samples: "
            + ", ".join(f"{k} {v}" for k, v in counts.items())
            + "; expected the same N in every file"
        )
    # (col, board, N) -> (N, board, col) -> (N, 24) with index board * 4 + col
    theta_run = np.transpose(theta, (2, 1, 0)).reshape(n, 24)
    # (axis, col, board, N) -> (N, board, col, axis) -> (N, 24, 2)
    xy_run = np.transpose(xy, (3, 2, 1, 0)).reshape(n, 24, 2)
    return Run.from_arrays(
        images=images,
        theta=theta_run,
        xy=xy_run,
        poses=poses,
        name=name or folder.name,
        attrs={
            "source": "multiprednet-mat",
            "source_path": str(folder.resolve()),
            "camera": {"width": int(images.shape[2]), "height": int(images.shape[1])},
            "robot": {"tactile_model": tactile_model},
        },
    )
