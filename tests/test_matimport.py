"""Importing MultiPredNet/WhiskEye MATLAB recordings (images/theta/xy/poses .mat files)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from vitaplace.engine.dataset import DatasetError, open_run, write_run
from vitaplace.engine.matimport import import_mat


def write_layout(folder, n=7, seed=0, images_as_cell=False, float_images=False):
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, size=(45, 80, 3, n), dtype=np.uint8)
    theta = rng.normal(size=(4, 6, n))
    xy = rng.normal(size=(2, 4, 6, n))
    poses = rng.normal(size=(n, 3))
    if images_as_cell:
        cell = np.empty((1, n), dtype=object)
        for i in range(n):
            cell[0, i] = images[..., i]
        scipy.io.savemat(folder / "images.mat", {"images": cell})
    elif float_images:
        scipy.io.savemat(folder / "images.mat", {"images": images / 255.0})
    else:
        scipy.io.savemat(folder / "images.mat", {"images": images})
    scipy.io.savemat(folder / "theta.mat", {"theta": theta})
    scipy.io.savemat(folder / "xy.mat", {"xy": xy})
    scipy.io.savemat(folder / "poses.mat", {"pose_return": poses})  # named as in extract_poses.m
    return images, theta, xy, poses


@pytest.mark.parametrize("variant", ["array", "cell", "float"])
def test_import_shapes_and_values(tmp_path, variant):
    images, theta, xy, poses = write_layout(
        tmp_path, images_as_cell=variant == "cell", float_images=variant == "float"
    )
    run = import_mat(tmp_path)
    n = 7
    assert len(run) == n
    assert run.images.shape == (n, 45, 80, 3) and run.images.dtype == np.uint8
    assert run.theta.shape == (n, 24) and run.xy.shape == (n, 24, 2) and run.poses.shape == (n, 3)
    assert np.array_equal(run.images[3], images[..., 3])
    # whisker (column c, board r) -> index r * 4 + c
    for c, r, i in [(0, 0, 0), (3, 0, 3), (0, 1, 4), (2, 5, 22), (3, 5, 23)]:
        assert run.theta[4, r * 4 + c] == pytest.approx(theta[c, r, 4], rel=1e-6)
        assert run.xy[4, r * 4 + c, 0] == pytest.approx(xy[0, c, r, 4], rel=1e-6)
        assert run.xy[4, r * 4 + c, 1] == pytest.approx(xy[1, c, r, 4], rel=1e-6)
        del i
    assert np.allclose(run.poses, poses)
    assert run.deflection.shape == (n, 1, 24, 2)
    assert run.contact_offsets.tolist() == [0] * (n + 1)
    # and it can be stored like a simulated run
    back = open_run(write_run(tmp_path / "out" / "real.h5", run))
    assert np.array_equal(back.theta, run.theta)


def test_poses_as_3_by_n_and_plain_name(tmp_path):
    _, _, _, poses = write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "poses.mat", {"poses": poses.T})
    assert np.allclose(import_mat(tmp_path).poses, poses)


def test_missing_file(tmp_path):
    write_layout(tmp_path)
    (tmp_path / "xy.mat").unlink()
    with pytest.raises(DatasetError, match=r"xy\.mat: missing MATLAB file"):
        import_mat(tmp_path)


def test_misshaped_theta(tmp_path):
    write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "theta.mat", {"theta": np.zeros((6, 4, 7))})
    with pytest.raises(DatasetError, match=r"theta\.mat: theta has shape \(6, 4, 7\), expected 4 x 6 x N"):
        import_mat(tmp_path)


def test_sample_count_mismatch(tmp_path):
    write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "poses.mat", {"poses": np.zeros((5, 3))})
    with pytest.raises(DatasetError, match="different numbers of samples.*poses.mat 5"):
        import_mat(tmp_path)


def test_ambiguous_and_garbage_files(tmp_path):
    write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "xy.mat", {"a": np.zeros((2, 4, 6, 7)), "b": np.zeros(3)})
    with pytest.raises(DatasetError, match=r"xy\.mat: cannot tell which variable holds xy"):
        import_mat(tmp_path)
    (tmp_path / "xy.mat").write_text("garbage")
    with pytest.raises(DatasetError, match=r"xy\.mat: not a readable MATLAB \.mat file"):
        import_mat(tmp_path)
    with pytest.raises(DatasetError, match="not a folder"):
        import_mat(tmp_path / "nowhere")
