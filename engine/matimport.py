"""Import MultiPredNet / WhiskEye MATLAB recordings as a `Run`.

The layout read by the MultiPredNet scripts (github.com/TomKnowles1994/MultiPredNet,
``load_mat_data``): a folder with

    images.mat   variable ``images``: 45 x 80 x 3 x N (uint8 or float in [0, 1]), or a
                 1 x N cell array of 45 x 80 x 3 frames (what ``np.array(images.tolist())[0]``
                 in the original loader unpacks), or N x 45 x 80 x 3
    theta.mat    variable ``theta``: 4 x 6 x N  (column x row-board x sample) [rad]
    xy.mat       variable ``xy``:    2 x 4 x 6 x N  (axis x column x row-board x sample)
    poses.mat    N x 3 (or 3 x N) x, y, yaw - e.g. ``pose_return`` of ``extract_poses.m``

When a file does not hold the expected variable name (``images``, ``theta``, ``xy``,
``poses``/``pose``), its single non-``__dunder__`` variable is used. MATLAB v7.3 files
(HDF5) are read with h5py. Whisker ``(column c, board r)`` becomes vitaplace whisker index
``r * 4 + c`` (see `vitaplace.engine.sim.robot`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.dataset import DatasetError, Run

__all__ = ["import_mat", "load_mat_variable"]

_NAMES = {
    "images": ("images", "image", "imgs"),
    "theta": ("theta",),
    "xy": ("xy",),
    "poses": ("poses", "pose", "pose_return", "pose_head"),
}


def load_mat_variable(path: Path, kind: str) -> np.ndarray:
    """The array stored in ``path`` for ``kind`` (one of images, theta, xy, poses)."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing MATLAB file ({kind})")
    try:
        variables = _read_mat(path)
    except DatasetError:
        raise
    except Exception as exc:  # scipy raises ValueError/TypeError/... on garbage
        raise DatasetError(f"{path}: not a readable MATLAB .mat file: {exc}") from None
    for name in _NAMES[kind]:
        if name in variables:
            return variables[name]
    if len(variables) == 1:
        return next(iter(variables.values()))
    raise DatasetError(
        f"{path}: cannot tell which variable holds {kind}: expected one named "
        f"{' or '.join(repr(n) for n in _NAMES[kind])} or a single variable, found {sorted(variables)}"
    )


def _read_mat(path: Path) -> dict[str, Any]:
    import scipy.io

    try:
        data = scipy.io.loadmat(path)
    except NotImplementedError:  # MATLAB v7.3 = HDF5
        return _read_mat73(path)
    return {k: v for k, v in data.items() if not k.startswith("__")}


def _read_mat73(path: Path) -> dict[str, Any]:
    import h5py

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        for key, item in f.items():
            if key.startswith("#") or not isinstance(item, h5py.Dataset):
                continue
            if item.dtype == h5py.ref_dtype:
                raise DatasetError(f"{path}: variable {key!r} is a v7.3 cell array; save it as a numeric array")
            out[key] = np.asarray(item[()]).T  # MATLAB is column-major
    return out


def _images(raw: np.ndarray, path: Path) -> np.ndarray:
    arr = raw
    if arr.dtype == object:  # cell array of frames
        frames = [np.asarray(x) for x in arr.ravel()]
        if not frames or any(fr.ndim != 3 or fr.shape[2] != 3 for fr in frames):
            raise DatasetError(f"{path}: the images cell array must hold H x W x 3 frames")
        if len({fr.shape for fr in frames}) != 1:
            raise DatasetError(f"{path}: the frames in the images cell array differ in size")
        arr = np.stack(frames)
    elif arr.ndim == 4 and arr.shape[2] == 3:
        arr = np.transpose(arr, (3, 0, 1, 2))  # H x W x 3 x N -> N x H x W x 3
    elif arr.ndim == 3 and arr.shape[2] == 3:
        arr = arr[None]  # a single frame
    elif not (arr.ndim == 4 and arr.shape[3] == 3):
        raise DatasetError(f"{path}: images have shape {raw.shape}, expected H x W x 3 x N (e.g. 45 x 80 x 3 x N)")
    if arr.dtype.kind == "f":
        scale = 255.0 if float(np.nanmax(arr, initial=0.0)) <= 1.0 else 1.0
        arr = np.clip(np.rint(arr * scale), 0, 255)
    elif arr.dtype.kind not in "ui":
        raise DatasetError(f"{path}: images have dtype {arr.dtype}, expected uint8 or float")
    return np.ascontiguousarray(arr, dtype=np.uint8)


def import_mat(directory: str | os.PathLike, name: str | None = None) -> Run:
    """Read a MultiPredNet/WhiskEye recording folder into an in-memory `Run`.

    Raises `DatasetError` naming the file when one is missing, unreadable or misshaped.
    Deflection series and contacts are not part of this layout: the run gets the single
    ``xy`` sample as its deflection series (S = 1) and no contacts.
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder with images.mat, theta.mat, xy.mat and poses.mat")
    images = _images(load_mat_variable(folder / "images.mat", "images"), folder / "images.mat")
    n = images.shape[0]

    theta = np.asarray(load_mat_variable(folder / "theta.mat", "theta"), dtype=np.float64)
    if theta.ndim == 2 and theta.shape[:2] == (4, 6):
        theta = theta[..., None]
    if theta.ndim != 3 or theta.shape[:2] != (4, 6):
        raise DatasetError(f"{folder / 'theta.mat'}: theta has shape {theta.shape}, expected 4 x 6 x N")
    xy = np.asarray(load_mat_variable(folder / "xy.mat", "xy"), dtype=np.float64)
    if xy.ndim == 3 and xy.shape[:3] == (2, 4, 6):
        xy = xy[..., None]
    if xy.ndim != 4 or xy.shape[:3] != (2, 4, 6):
        raise DatasetError(f"{folder / 'xy.mat'}: xy has shape {xy.shape}, expected 2 x 4 x 6 x N")
    poses = np.asarray(load_mat_variable(folder / "poses.mat", "poses"), dtype=np.float64)
    if poses.ndim == 1 and poses.shape[0] == 3:
        poses = poses[None]
    if poses.ndim == 2 and poses.shape[1] != 3 and poses.shape[0] == 3:
        poses = poses.T
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise DatasetError(f"{folder / 'poses.mat'}: poses have shape {poses.shape}, expected N x 3 (x, y, yaw)")

    counts = {"images.mat": n, "theta.mat": theta.shape[2], "xy.mat": xy.shape[3], "poses.mat": poses.shape[0]}
    if len(set(counts.values())) != 1:
        raise DatasetError(
            f"{folder}: the files hold different numbers of samples: "
            + ", ".join(f"{k} {v}" for k, v in counts.items())
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
        },
    )
