"""The ``fixed`` backend: numpy's arithmetic with no sum through BLAS or LAPACK, so a training
gives the same bits under any OpenBLAS kernel of one machine.

The decisive test trains one network in two processes, each under another OpenBLAS kernel
(``OPENBLAS_CORETYPE``), on the ``numpy`` backend and on ``fixed``: numpy's two trainings
differ (the kernels really round differently on this workload, or the test would prove
nothing), fixed's agree bit for bit. The pieces are checked against closed forms.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vitaplace.engine.network.fixed_order import FixedOrderBackend, gram, matmul, rounded_step, spd_inverse
from vitaplace.engine.network.selection import get_backend
from vitaplace.engine.network.solver import curvature_preconditioners, curvature_steps


def test_spd_inverse_of_a_hand_inverted_matrix():
    """[[4, 2], [2, 3]]^-1 = [[3, -2], [-2, 4]] / 8 (its determinant is 8)."""
    inverse = spd_inverse(np.array([[4.0, 2.0], [2.0, 3.0]]))
    np.testing.assert_allclose(inverse, np.array([[3.0, -2.0], [-2.0, 4.0]]) / 8, rtol=1e-15)
    assert inverse[0, 1] == inverse[1, 0]


def test_spd_inverse_inverts_and_is_exactly_symmetric(seed):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((40, 60))
    b = a @ a.T + 0.1 * np.eye(40)
    inverse = spd_inverse(b)
    np.testing.assert_allclose(inverse @ b, np.eye(40), atol=1e-10)
    assert np.array_equal(inverse, inverse.T)


def test_spd_inverse_refuses_a_matrix_that_is_not_positive_definite():
    with pytest.raises(ValueError, match="pivot 1 is -1"):
        spd_inverse(np.array([[1.0, 1.0], [1.0, 0.0]]))  # eigenvalues (1 +- sqrt 5) / 2: one negative


def test_matmul_is_the_product_of_matrices_and_reads_transposed_views():
    """Small integers: every product and partial sum exact in float32, so any order gives it."""
    a = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], dtype=np.float32)
    b = np.array([[7.0, 8.0], [9.0, 10.0], [11.0, 12.0]], dtype=np.float32)
    np.testing.assert_array_equal(matmul(a, b), np.array([[58.0, 64.0], [139.0, 154.0]]))
    np.testing.assert_array_equal(matmul(b.T, a.T), np.array([[58.0, 139.0], [64.0, 154.0]]))
    assert matmul(a, b).dtype == np.float32


def test_gram_is_w_times_its_transpose():
    w = np.array([[1.0, 2.0, 3.0], [0.0, -1.0, 4.0]])
    np.testing.assert_array_equal(gram(w), np.array([[14.0, 10.0], [10.0, 17.0]]))


def test_a_rounded_step_keeps_12_significant_bits_and_never_grows():
    """0.1 = 0.8 x 2^-3, and floor(0.8 x 2^12) = 3276: 3276 x 2^-15; 0.75 is exact in 12 bits."""
    assert rounded_step(0.1) == 3276 / 2**15
    assert rounded_step(0.75) == 0.75
    steps = np.random.default_rng(0).uniform(1e-6, 10.0, 1000)
    rounded = np.array([rounded_step(float(s)) for s in steps])
    assert np.all(rounded <= steps) and np.all(rounded > steps * (1 - 2.0**-11))


def test_the_fixed_curvature_bounds_are_the_lapack_ones_to_rounding(seed):
    from vitaplace.engine.network.pc import Network

    net = Network(NETWORK, seed=seed % 1000, backend="numpy")
    present = ["visual", "tactile"]
    args = (net.host_weights(), net.active_edges(present), net.latent_nodes(present), "leaky_relu", 0.1, 0.5)
    lapack, fixed = curvature_preconditioners(*args), curvature_preconditioners(*args, fixed_order=True)
    for node in lapack:
        np.testing.assert_allclose(fixed[node], lapack[node], rtol=1e-9, atol=1e-12)
    steps, fixed_steps = curvature_steps(*args), curvature_steps(*args, fixed_order=True)
    for node, step in steps.items():
        assert step * (1 - 2.0**-11) < fixed_steps[node] <= step


def test_a_network_on_the_fixed_backend_gets_the_fixed_order_steps():
    """The solvers read the backend's ``fixed_order``: the momentum solver's steps on a fixed
    network are the rounded ones, on a numpy network LAPACK's own."""
    from vitaplace.engine.network.pc import Network
    from vitaplace.engine.network.solver import make_solver

    present = ["visual", "tactile"]
    steps = {}
    for backend in ("numpy", "fixed"):
        net = Network(NETWORK, seed=1, backend=backend)
        steps[backend] = make_solver("nesterov", 0.9, 1e-5).node_steps(net, present, 0.1)
        args = (net.host_weights(), net.active_edges(present), net.latent_nodes(present), "leaky_relu", 0.1, 0.1)
    assert steps["fixed"] == curvature_steps(*args, fixed_order=True) != steps["numpy"]
    assert steps["numpy"] == curvature_steps(*args)


def test_the_fixed_backend_is_numpy_with_its_own_sums():
    backend = get_backend("fixed")
    assert isinstance(backend, FixedOrderBackend) and backend.fixed_order and backend.device == "cpu"
    assert not get_backend("numpy").fixed_order
    with pytest.raises(ValueError, match="backend 'fixed' runs on the cpu only"):
        get_backend("fixed", "cuda")


NETWORK = {
    "modalities": {
        "visual": {"input_size": 300, "layers": [64], "eta_y": 0.01, "eta_w": 1e-3, "threshold": 0.0},
        "tactile": {"input_size": 30, "layers": [16], "eta_y": 0.01, "eta_w": 1e-3, "threshold": 0.0},
    },
    "joint": {"size": 32, "eta_y": 0.01, "eta_w": 1e-3, "threshold": 0.0},
    "activation": "leaky_relu",
    "slope": 0.1,
}

#: one training (momentum on the weights, the preconditioned solver's 5 steps per minibatch, 4
#: epochs of 200 samples) in a process of its own, printing a digest of its weights and latents
TRAINING = textwrap.dedent("""
    import hashlib, json, sys
    import numpy as np
    from vitaplace.engine.network.pc import Network
    from vitaplace.engine.network.solver import make_solver
    network, backend = json.loads(sys.argv[1]), sys.argv[2]
    rng = np.random.default_rng(7)
    x = {"visual": rng.random((200, 300), dtype=np.float32), "tactile": rng.random((200, 30), dtype=np.float32)}
    net = Network(network, seed=3, backend=backend)
    latents = {}
    net.train(x, {"epochs": 4, "batch_size": 50, "inference_steps": 5, "seed": 0, "converge_window": 0,
                  "converge_tol": 0.01, "latent_prior": 0.1, "weight_optimizer": "momentum"},
              latents=latents, solver=make_solver("preconditioned", 0.9, 3e-6))
    digest = hashlib.sha256()
    for name, w in sorted(net.host_weights().items()):
        digest.update(np.ascontiguousarray(w).tobytes())
    for name, y in sorted(latents.items()):
        digest.update(np.ascontiguousarray(y).tobytes())
    print(digest.hexdigest())
""")


#: one training of the backprop control (Adam, 4 epochs of 200 samples, the learned encoder)
#: on `NETWORK`'s sizes in a process of its own, printing a digest of its weights
AUTOENCODER_TRAINING = textwrap.dedent("""
    import hashlib, json, sys
    import numpy as np
    from vitaplace.plugins.autoencoder.model import Autoencoder, TrainingSettings, train
    network, backend = json.loads(sys.argv[1]), sys.argv[2]
    sizes = {m: [spec["input_size"], *spec["layers"]] for m, spec in network["modalities"].items()}
    rng = np.random.default_rng(7)
    x = {m: rng.random((200, s[0]), dtype=np.float32) for m, s in sizes.items()}
    model = Autoencoder(sizes, network["joint"]["size"], activation="leaky_relu", slope=0.1, encoder="learned",
                        seed=3, fixed_order=backend == "fixed")
    train(model, x, TrainingSettings(4, 50, 1e-3, "adam", 0, 0, 0.01))
    digest = hashlib.sha256()
    for name, w in sorted(model.weights.items()):
        digest.update(np.ascontiguousarray(w).tobytes())
    print(digest.hexdigest())
""")


#: VLAD's vocabulary of 20,000 integer-valued descriptors (as SIFT's are) in a process of its
#: own: k-means in float32 (its labels' digest) and through `vocabulary` (float64, its centres)
VOCABULARY = textwrap.dedent("""
    import hashlib, json
    import numpy as np
    from sklearn.cluster import KMeans
    from vitaplace.plugins.vlad.extractor import vocabulary
    x = np.random.default_rng(11).integers(0, 256, (20000, 128)).astype(np.float32)
    labels = KMeans(n_clusters=64, n_init=1, random_state=0).fit(x).labels_
    print(json.dumps({"float32": hashlib.sha256(labels.tobytes()).hexdigest(),
                      "centres": vocabulary(x, 64, 0).tolist()}))
""")


#: the preconditioners of a wider network (visual 400 -> 256 -> joint 128), in float64, printed
#: as one digest computed through LAPACK and one in fixed order
PRECONDITIONERS = textwrap.dedent("""
    import hashlib, json, sys
    import numpy as np
    from vitaplace.engine.network.pc import Network
    from vitaplace.engine.network.solver import curvature_preconditioners
    network = json.loads(sys.argv[1])
    network["modalities"]["visual"].update(input_size=400, layers=[256])
    network["joint"]["size"] = 128
    net = Network(network, seed=5, backend="numpy")
    present = ["visual", "tactile"]
    args = (net.host_weights(), net.active_edges(present), net.latent_nodes(present), "leaky_relu", 0.1, 0.1)
    for fixed in (False, True):
        digest = hashlib.sha256()
        for node, p in sorted(curvature_preconditioners(*args, fixed_order=fixed).items()):
            digest.update(p.tobytes())
        print(digest.hexdigest())
""")


def _openblas_kernels_switchable() -> bool:
    """numpy's OpenBLAS on an x86-64 CPU that runs both kernels tried (Haswell's needs AVX2 and FMA)."""
    from vitaplace.engine.base.cpus import blas_libraries

    try:
        flags = set(Path("/proc/cpuinfo").read_text().split())
    except OSError:
        return False
    return (platform.machine() in ("x86_64", "AMD64") and {"avx", "avx2", "fma"} <= flags
            and any(lib.get("library") == "openblas" for lib in blas_libraries()))


def _under_kernel(kernel: str, script: str, *args: str, threads: int = 1) -> str:
    """What ``script`` prints (given `NETWORK` and ``args``) in a process under OpenBLAS kernel
    ``kernel`` with ``threads`` BLAS and OpenMP threads."""
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel, **dict.fromkeys(
        ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "VITAPLACE_BLAS_THREADS"), str(threads))}
    done = subprocess.run([sys.executable, "-c", script, json.dumps(NETWORK), *args], env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip()


@pytest.mark.skipif(not _openblas_kernels_switchable(), reason="needs numpy's OpenBLAS on x86-64")
def test_the_fixed_order_preconditioners_are_the_same_under_two_blas_kernels():
    """LAPACK's inverses differ in their float64 bits between the kernels; the fixed-order ones do not."""
    (lapack_haswell, fixed_haswell), (lapack_sandy, fixed_sandy) = (
        _under_kernel(kernel, PRECONDITIONERS).splitlines() for kernel in ("Haswell", "Sandybridge"))
    assert lapack_haswell != lapack_sandy
    assert fixed_haswell == fixed_sandy


@pytest.mark.skipif(not _openblas_kernels_switchable(), reason="needs numpy's OpenBLAS on x86-64")
def test_a_training_on_the_fixed_backend_is_the_same_under_two_blas_kernels():
    def digest(backend: str, kernel: str) -> str:
        return _under_kernel(kernel, TRAINING, backend)

    numpy_runs = {kernel: digest("numpy", kernel) for kernel in ("Haswell", "Sandybridge")}
    assert numpy_runs["Haswell"] != numpy_runs["Sandybridge"]  # the kernels round this workload differently
    fixed_runs = {kernel: digest("fixed", kernel) for kernel in ("Haswell", "Sandybridge")}
    assert fixed_runs["Haswell"] == fixed_runs["Sandybridge"]


@pytest.mark.skipif(not _openblas_kernels_switchable(), reason="needs numpy's OpenBLAS on x86-64")
def test_the_backprop_control_on_the_fixed_backend_is_the_same_under_two_blas_kernels():
    """The autoencoder A (``backend: fixed``): its products of matrices in numpy's loops."""
    runs = {(backend, kernel): _under_kernel(kernel, AUTOENCODER_TRAINING, backend)
            for backend in ("numpy", "fixed") for kernel in ("Haswell", "Sandybridge")}
    assert runs[("numpy", "Haswell")] != runs[("numpy", "Sandybridge")]
    assert runs[("fixed", "Haswell")] == runs[("fixed", "Sandybridge")]



@pytest.mark.skipif(not _openblas_kernels_switchable(), reason="needs numpy's OpenBLAS on x86-64")
def test_vlads_vocabulary_is_the_same_under_two_blas_kernels_and_thread_counts():
    """k-means in float32 ends elsewhere under Haswell on one thread than under Sandybridge on
    two; VLAD's vocabulary (float64) keeps every centre to 1e-12."""
    haswell, sandy = (json.loads(_under_kernel(kernel, VOCABULARY, threads=threads))
                      for kernel, threads in (("Haswell", 1), ("Sandybridge", 2)))
    assert haswell["float32"] != sandy["float32"]
    np.testing.assert_allclose(np.array(sandy["centres"]), np.array(haswell["centres"]), rtol=1e-12, atol=1e-10)
