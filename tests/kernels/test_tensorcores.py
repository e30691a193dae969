"""The tensor-core precisions (``CublasBackend``: tf32, bf16) against the float64 reference.

On the CPU the whole path runs on Warp's CPU device with cuBLAS replaced by ``HostBlas``, a
host implementation of ``cublasGemmEx``'s column-major semantics that rounds the operands
as the tensor cores do (bf16: 8 significant bits, tf32: 11, to nearest even) and
accumulates exactly (float64). That checks the row-major -> column-major mapping, the
bfloat16 copies and the epilogues, and the error model of the precision. The ``cuda`` tests
run the real cuBLAS (skipped without a CUDA device).

Accuracy gates (relative error of one minibatch's latent and weight *updates* against the
float64 numpy backend, ||d - d_ref|| / ||d_ref|| per array, the largest over arrays): with
unit roundoff u = 2^-24 (float32), 2^-11 (tf32), 2^-8 (bf16), the gates are ~20 u for the
low precisions. The error is set by rounding the latents: they sit near their start 0.1
and a minibatch moves them by far less, so the rounding of Y (relative u) is a large part
of the update. Emulated (HostBlas, 5 steps, small network): float32 2e-6, tf32 3.3e-4,
bf16 2.2e-2.
"""

import ctypes

import numpy as np
import pytest

from vitaplace.engine.network.backends import PRECISIONS, BackendError, NumpyBackend
from vitaplace.engine.network.pc import LATENT_INIT, Network
from vitaplace.engine.network.selection import check_precision, get_backend
from vitaplace.engine.network.tensorcores import CublasBackend, row_major_gemm
from vitaplace.plugins.mupnet.extractor import MupnetParams

wp = pytest.importorskip("warp")

#: unit roundoff 2^-p of p significant bits: float32 24, tf32 11, bfloat16 8
UNIT_ROUNDOFF = {"float32": 2.0**-24, "tf32": 2.0**-11, "bf16": 2.0**-8}
#: relative error of one minibatch's updates against float64 (see the module docstring)
UPDATE_GATE = {"float32": 1e-5, "tf32": 1e-2, "bf16": 8e-2}


def round_mantissa(x: np.ndarray, bits: int) -> np.ndarray:
    """float32 ``x`` rounded to ``bits`` significant bits (to nearest, ties to even)."""
    drop = 24 - bits
    u = np.ascontiguousarray(x, np.float32).view(np.uint32).astype(np.uint64)
    u = (u + (1 << (drop - 1)) - 1 + ((u >> drop) & 1)) >> drop << drop
    return u.astype(np.uint32).view(np.float32)


def bf16(x: np.ndarray) -> np.ndarray:
    return round_mantissa(x, 8)


def tf32(x: np.ndarray) -> np.ndarray:
    return round_mantissa(x, 11)


class HostBlas:
    """``cublasGemmEx`` on host memory: column-major, operand types float32 (0) or
    bfloat16 (14), compute 32F (68) or 32F_FAST_TF32 (77, operands rounded to tf32)."""

    calls = 0

    @staticmethod
    def _matrix(ptr: int, dtype: int, ld: int, rows: int, cols: int) -> np.ndarray:
        count = ld * (cols - 1) + rows
        ctype = {0: ctypes.c_float, 14: ctypes.c_uint16}[dtype]
        flat = np.ctypeslib.as_array((ctype * count).from_address(ptr))
        size = flat.itemsize
        view = np.lib.stride_tricks.as_strided(flat, shape=(rows, cols), strides=(size, ld * size))
        return view

    def _operand(self, ptr, dtype, ld, trans, rows, cols, compute) -> np.ndarray:
        stored = self._matrix(ptr, dtype, ld, cols if trans else rows, rows if trans else cols)
        x = stored.T if trans else stored
        if dtype == 14:
            x = (x.astype(np.uint32) << 16).view(np.float32) if x.flags.c_contiguous else \
                (np.ascontiguousarray(x).astype(np.uint32) << 16).view(np.float32)
        elif compute == 77:
            x = tf32(np.ascontiguousarray(x))
        return np.asarray(x, np.float64)

    def gemm_ex(self, ta, tb, m, n, k, alpha, a, a_type, lda, b, b_type, ldb, beta, c, c_type, ldc, compute):
        assert c_type == 0 and compute in (68, 77) and a_type == b_type
        HostBlas.calls += 1
        A = self._operand(a, a_type, lda, ta, m, k, compute)
        B = self._operand(b, b_type, ldb, tb, k, n, compute)
        C = self._matrix(c, 0, ldc, m, n)
        C[...] = (alpha * (A @ B) + beta * C.astype(np.float64)).astype(np.float32)


def to_wp(a, dtype=wp.float32):
    return wp.array(np.ascontiguousarray(a), dtype=dtype, device="cpu")


# ------------------------------------------------------------------------------- pieces


@pytest.mark.parametrize("trans_a", [False, True])
@pytest.mark.parametrize("trans_b", [False, True])
def test_row_major_gemm_computes_alpha_op_a_op_b_plus_beta_c(trans_a, trans_b):
    """Row-major C = alpha op(A) op(B) + beta C through the column-major BLAS, every
    transpose, no square shape (a swapped dimension or leading dimension shows)."""
    rng = np.random.default_rng(0)
    m, n, k = 5, 7, 3
    A = rng.standard_normal((k, m) if trans_a else (m, k)).astype(np.float32)
    B = rng.standard_normal((n, k) if trans_b else (k, n)).astype(np.float32)
    C0 = rng.standard_normal((m, n)).astype(np.float32)
    C = to_wp(C0)
    row_major_gemm(HostBlas(), "float32", C, to_wp(A), to_wp(B), trans_a, trans_b, alpha=0.5, beta=2.0)
    opa = A.T if trans_a else A
    opb = B.T if trans_b else B
    expected = 0.5 * (opa.astype(np.float64) @ opb) + 2.0 * C0
    np.testing.assert_allclose(C.numpy(), expected, rtol=1e-6, atol=1e-6)


def test_to_bfloat16_rounds_to_nearest_even():
    """Hand cases: 1 + 2^-8 is halfway between 1 and 1 + 2^-7 (ties to the even 1);
    1 + 3 * 2^-8 halfway between 1 + 2^-7 and 1 + 2^-6 (ties to the even 1 + 2^-6);
    pi -> 3.140625; and random values agree with the bit-level reference."""
    from vitaplace.kernels import warp_kernels as wk

    hand = np.array([[1 + 2**-8, 1 + 3 * 2**-8, np.pi, -2.5e-3]], np.float32)
    expected = np.array([[1.0, 1 + 2**-6, 3.140625, -0.00250244140625]], np.float32)
    np.testing.assert_array_equal(bf16(hand), expected)
    rng = np.random.default_rng(1)
    x = np.concatenate([hand, rng.standard_normal((1, 4)).astype(np.float32) * 10.0], axis=1)
    out = wp.zeros(x.shape, dtype=wp.bfloat16, device="cpu")
    wk.to_bfloat16(to_wp(x), out)
    got = (out.numpy().view(np.uint16).astype(np.uint32) << 16).view(np.float32)
    np.testing.assert_array_equal(got, bf16(x))


@pytest.mark.parametrize("precision,bits", [("bf16", 8), ("tf32", 11)])
def test_product_error_of_rounded_operands_follows_the_error_model(precision, bits):
    """Operands rounded to p significant bits, products accumulated exactly: per element
    |C - C_ref| <= (2u + u^2) (|A| |B|), u = 2^-p, and at the paper's shapes the normwise
    error is a sizeable part of that bound (the rounding really happened)."""
    rng = np.random.default_rng(2)
    Y = (0.1 + 0.05 * rng.standard_normal((150, 1000))).astype(np.float32)
    W = (rng.uniform(-1, 1, (1000, 600)) * np.sqrt(6 / 1300)).astype(np.float32)
    exact = Y.astype(np.float64) @ W
    low = round_mantissa(Y, bits).astype(np.float64) @ round_mantissa(W, bits)
    u = UNIT_ROUNDOFF[precision]
    bound = (2 * u + u * u) * (np.abs(Y).astype(np.float64) @ np.abs(W))
    assert np.all(np.abs(low - exact) <= bound * (1 + 1e-12))
    normwise = np.linalg.norm(low - exact) / np.linalg.norm(exact)
    assert u / 20 < normwise < np.linalg.norm(bound) / np.linalg.norm(exact)


# ------------------------------------------------------------------------- one minibatch

SMALL = {
    "modalities": {
        "visual": {"input_size": 96, "layers": [40, 24], "eta_y": 0.02, "eta_w": 0.01, "threshold": 1e-3},
        "tactile": {"input_size": 12, "layers": [8], "eta_y": 0.02, "eta_w": 0.01, "threshold": 1e-3},
    },
    "joint": {"size": 16, "eta_y": 0.02, "eta_w": 0.01, "threshold": 1e-3},
    "activation": "leaky_relu",
    "slope": 0.2,
}


def start_state(config: dict, batch: int, seed: int = 3):
    net = Network(config, seed=seed, backend=NumpyBackend())
    rng = np.random.default_rng(seed + 1)
    inputs = {m: rng.random((batch, net.sizes[f"{m}.0"]), dtype=np.float32) for m in net.modalities}
    latents = {node: (LATENT_INIT + rng.normal(0.0, 0.01, (batch, net.sizes[node]))).astype(np.float32)
               for node in net.latent_nodes(net.modalities)}
    return inputs, latents, {k: w.copy() for k, w in net.weights.items()}


def minibatch_updates(config, backend, start, steps: int, replays: int = 1):
    """The latent and weight updates of one training minibatch (``train_steps``) on
    ``backend``; with ``replays`` > 1 the captured minibatch is run again from the same
    start (on CUDA the second run is recorded as a graph and replayed)."""
    inputs, latents, weights = start
    batch = next(iter(inputs.values())).shape[0]
    net = Network(config, seed=0, backend=backend)
    state = net.batch_state(batch)
    run = backend.capture(lambda: state.train_steps(steps))
    for _ in range(replays):
        net.set_weights(weights)
        state.load(inputs, latents)
        run()
    dy = {k: backend.download(y).astype(np.float64) - latents[k] for k, y in state.Y.items()}
    dw = {k: backend.weights_to_host(w).astype(np.float64) - weights[k] for k, w in state.weights.items()}
    return dy, dw


def update_error(got, ref) -> float:
    return max(float(np.linalg.norm(got[k] - ref[k]) / np.linalg.norm(ref[k])) for k in ref)


def reference_updates(config, start, steps):
    return minibatch_updates(config, NumpyBackend(np.float64), start, steps)


@pytest.mark.parametrize("precision", PRECISIONS)
def test_minibatch_updates_on_emulated_tensor_cores_match_float64(precision):
    """The whole CublasBackend path on the CPU with HostBlas: one minibatch's updates
    within the precision's gate of the float64 reference, and (tf32, bf16) not closer than
    float32 is: the operands really were rounded."""
    start = start_state(SMALL, 40)
    ref_dy, ref_dw = reference_updates(SMALL, start, 5)
    calls = HostBlas.calls
    dy, dw = minibatch_updates(SMALL, CublasBackend(precision, "cpu", blas=HostBlas()), start, 5)
    assert HostBlas.calls > calls, "the GEMMs went through the BLAS"
    err = max(update_error(dy, ref_dy), update_error(dw, ref_dw))
    assert err < UPDATE_GATE[precision], f"{precision}: {err:.2e}"
    if precision != "float32":
        assert err > 50 * UNIT_ROUNDOFF["float32"], f"{precision}: {err:.2e} is float32 accuracy"


def low_to_float(arr) -> np.ndarray:
    return (arr.numpy().view(np.uint16).astype(np.uint32) << 16).view(np.float32)


def test_bf16_weight_copies_follow_every_weight_step():
    """After a minibatch the bfloat16 weights the next one multiplies with are the updated
    float32 weights rounded, bit for bit."""
    start = start_state(SMALL, 40)
    backend = CublasBackend("bf16", "cpu", blas=HostBlas())
    net = Network(SMALL, seed=0, backend=backend)
    state = net.batch_state(40)
    net.set_weights(start[2])
    state.load(start[0], start[1])
    backend.capture(lambda: state.train_steps(2))()
    for name, handle in state.weights.items():
        assert not np.array_equal(handle.W.numpy(), start[2][name]), "the weights moved"
        np.testing.assert_array_equal(low_to_float(handle.low), bf16(handle.W.numpy()), err_msg=name)


def test_nothing_runs_while_kernels_are_planned():
    """Recording which kernels a minibatch needs must not run it: no cuBLAS call either
    (a weight step would otherwise be applied once more)."""
    from vitaplace.kernels import warp_kernels as wk

    rng = np.random.default_rng(4)
    backend = CublasBackend("bf16", "cpu", blas=HostBlas())
    W0 = rng.standard_normal((6, 5)).astype(np.float32)
    W = backend.weights(W0)
    Y, G = rng.standard_normal((3, 6)).astype(np.float32), rng.standard_normal((3, 5)).astype(np.float32)
    Y_dev, G_dev = to_wp(Y), to_wp(G)
    wk.to_bfloat16(G_dev, backend._low_buffer("gain", G_dev))  # the bf16 gains a prediction writes
    backend._operand(Y_dev)  # bf16 Y ready too: a GEMM run while planning would change W
    with wk.planned_kernels() as plan:
        backend.weight_update(W, Y_dev, G_dev, 0.5)
    assert plan, "the kernels were recorded"
    np.testing.assert_array_equal(W.W.numpy(), W0)
    backend.weight_update(W, Y_dev, G_dev, 0.5)
    expected = W0 + bf16(Y).T.astype(np.float64) @ bf16(G)
    np.testing.assert_allclose(W.W.numpy(), expected, rtol=1e-5, atol=1e-6)


def test_stream_order_waits_for_writers_and_for_readers_of_what_it_writes():
    """Hand-traced hazards: read-after-write and write-after-read across streams wait,
    reads after reads and anything on one stream do not; a join moves the other stream's
    accesses to the joining one."""
    from vitaplace.engine.network.tensorcores import StreamOrder

    main, side = object(), object()
    order = StreamOrder()
    assert order.waits(main, (), ("Y1",)) == []  # gather writes Y1 on main
    assert order.waits(main, ("Y1", "W1"), ("E1",)) == []  # big predict: same stream
    assert order.waits(side, ("Y2", "W2", "Y1"), ("E2",)) == [main]  # small predict reads Y1 (main wrote it)
    assert order.waits(side, ("Y2",), ("E3",)) == []  # reads after reads: no wait
    assert order.waits(main, ("E2",), ("Y1",)) == [side]  # big latent step: E2 from side; rewrites Y1 side read
    assert order.waits(side, ("E3",), ("Y2",)) == []  # small latent step: nothing of main's
    assert order.waits(main, (), ("W2",)) == [side]  # a write after the side's read of W2
    assert order.waits(main, (), ("Y2",)) == [side]  # scatter after the side wrote Y2
    order.joined(main, side)
    assert order.waits(main, ("E2", "E3"), ()) == []  # the join covered the side's writes
    assert order.waits(side, ("E1",), ()) == [main]  # but the side still waits for main


def test_tensor_core_precisions_need_cuda_and_not_numpy():
    """One-line BackendErrors at validation: tf32/bf16 with the numpy backend, or without a
    CUDA device; float32 runs everywhere."""
    check_precision("float32", "numpy")
    with pytest.raises(BackendError, match="backend 'numpy' computes in float32 only"):
        check_precision("bf16", "numpy")
    with pytest.raises(BackendError, match="unknown precision 'fp8'"):
        check_precision("fp8")


def test_tensor_core_precisions_without_cuda_are_refused(monkeypatch):
    from vitaplace.engine.network import selection

    monkeypatch.setattr(selection, "cuda_available", lambda: False)
    for precision in ("tf32", "bf16"):
        with pytest.raises(BackendError, match=f"precision '{precision}' needs a CUDA device and none was found"):
            get_backend("auto", precision=precision)
    assert isinstance(get_backend("numpy", precision="float32"), NumpyBackend)


# ---------------------------------------------------------------------------- real cuBLAS


@pytest.fixture
def cuda():
    from vitaplace.engine.network.selection import cuda_available

    if not cuda_available():
        pytest.skip("no CUDA device")
    return "cuda"


@pytest.mark.cuda
@pytest.mark.parametrize("precision", PRECISIONS)
def test_minibatch_updates_through_cublas_match_float64(cuda, precision):
    """cuBLAS at each precision, the minibatch replayed from a CUDA graph: updates within
    the gate of the float64 reference."""
    start = start_state(SMALL, 40)
    ref = reference_updates(SMALL, start, 5)
    dy, dw = minibatch_updates(SMALL, CublasBackend(precision, cuda), start, 5, replays=3)
    err = max(update_error(dy, ref[0]), update_error(dw, ref[1]))
    assert err < UPDATE_GATE[precision], f"{precision}: {err:.2e}"


@pytest.mark.cuda
@pytest.mark.parametrize("precision", ["float32", "bf16"])
def test_small_edges_on_a_second_stream_give_the_same_updates(cuda, precision):
    """The small edges on their own stream (every edge but visual.1 here), the minibatch
    captured with the fork and join and replayed: the same updates as on one stream."""
    start = start_state(SMALL, 40)
    serial = minibatch_updates(SMALL, CublasBackend(precision, cuda), start, 5, replays=3)
    beside = minibatch_updates(SMALL, CublasBackend(precision, cuda, small_edges_beside=1000), start, 5, replays=3)
    for one, other in zip(serial, beside, strict=True):
        for name in one:
            np.testing.assert_allclose(other[name], one[name], rtol=1e-6, atol=1e-9, err_msg=name)


#: the paper's network (MuPNet's defaults): 45 x 80 RGB frames, 24 whiskers x 3 tactile channels
PAPER = MupnetParams().network_config(tactile_size=72)
#: per-epoch energy of a low-precision training: within this relative band of float32's
ENERGY_BAND = {"tf32": 0.01, "bf16": 0.03}


@pytest.mark.cuda
@pytest.mark.slow
@pytest.mark.parametrize("precision", ["tf32", "bf16"])
def test_paper_shape_training_energy_stays_in_band_of_float32(cuda, precision):
    """Five epochs at the paper's shapes (B = 150, T = 20) on 600 random samples: every
    epoch's energy per sample within ENERGY_BAND of the float32 run's, and falling."""
    rng = np.random.default_rng(0)
    inputs = {"visual": rng.random((600, 10800), dtype=np.float32), "tactile": rng.random((600, 72), dtype=np.float32)}
    train = MupnetParams(epochs=5).training_config()
    curves = {}
    for p in ("float32", precision):
        net = Network(PAPER, seed=0, backend=get_backend("warp", cuda, precision=p))
        curves[p] = np.array(net.train(inputs, train).total())
    band = np.abs(curves[precision] - curves["float32"]) / curves["float32"]
    assert band.max() < ENERGY_BAND[precision], f"{precision}: {band}"
    assert np.all(np.diff(curves[precision]) < 0)


def test_mupnet_refuses_tensor_core_precision_without_cuda_at_validation(monkeypatch):
    """``precision: bf16`` on a machine without CUDA (or with backend numpy) fails when the
    scenario is validated, in one line naming the extractor and the key; float32 is fine."""
    from vitaplace.engine.extension.features import ExtractorParamsError
    from vitaplace.engine.network import selection
    from vitaplace.plugins.mupnet import MupnetExtractor

    monkeypatch.setattr(selection, "cuda_available", lambda: False)
    assert MupnetExtractor.validate_params({"precision": "float32"}).precision == "float32"
    for params, why in (({"precision": "bf16"}, "precision 'bf16' needs a CUDA device and none was found"),
                        ({"precision": "tf32", "backend": "numpy"}, "backend 'numpy' computes in float32 only")):
        with pytest.raises(ExtractorParamsError) as info:
            MupnetExtractor.validate_params(params)
        message = str(info.value)
        assert "'mupnet'" in message and "precision" in message and why in message
        assert "\n" not in message


def test_the_precisions_are_spelled_once():
    """MuPNet's ``precision`` parameter is the backends' `Precision` type, whose values are
    `PRECISIONS`, and an unknown one is refused by the one check every path uses."""
    from typing import get_args

    from vitaplace.engine.network.backends import Precision, known_precision
    from vitaplace.engine.network.selection import check_precision
    from vitaplace.plugins.mupnet import MupnetExtractor

    assert MupnetExtractor.Params.model_fields["precision"].annotation is Precision
    assert get_args(Precision) == PRECISIONS == ("float32", "tf32", "bf16")
    for check in (known_precision, check_precision):
        with pytest.raises(BackendError, match=r"^unknown precision 'fp16'; valid: float32, tf32, bf16$"):
            check("fp16")


@pytest.mark.parametrize("optimizer", ["momentum", "adam"])
def test_weight_optimisers_on_the_tensor_core_backend_match_numpy(optimizer):
    """The momentum and Adam weight steps through CublasBackend (HostBlas, float32 on the
    CPU) train as on numpy, and bf16's rounded copies follow the optimiser's weights."""
    rng = np.random.default_rng(3)
    inputs = {m: rng.random((30, SMALL["modalities"][m]["input_size"])).astype(np.float32) for m in SMALL["modalities"]}
    cfg = {"epochs": 2, "batch_size": 15, "inference_steps": 3, "seed": 0, "converge_window": 0,
           "converge_tol": 0.01, "weight_optimizer": optimizer}
    weights = {}
    for name, backend in (("numpy", NumpyBackend()), ("float32", CublasBackend("float32", "cpu", blas=HostBlas())),
                          ("bf16", CublasBackend("bf16", "cpu", blas=HostBlas()))):
        net = Network(SMALL, seed=0, backend=backend)
        net.train(inputs, cfg)
        weights[name] = net.weights
        if name == "bf16":
            for handle in net.device_weights().values():
                np.testing.assert_array_equal(low_to_float(handle.low), bf16(handle.W.numpy()))
    for edge, w in weights["numpy"].items():
        np.testing.assert_allclose(weights["float32"][edge], w, rtol=1e-5, atol=1e-6, err_msg=edge)
