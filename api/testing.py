"""The feature-extractor contract as checks a plugin author runs in their own tests
(in the spirit of scikit-learn's ``check_estimator``):

    from vitaplace.testing import check_extractor

    def test_my_extractor_keeps_the_contract():
        check_extractor(MyExtractor, {"my_param": 2})

`check_extractor` runs every check of `CHECKS` on a small synthetic run (`synthetic_run`)
and raises `ContractError` at the first broken rule; its message names the check and the
extractor. Each check is a function ``check_...(cls, params, run)`` that can also be run
alone: `parametrize_with_checks` makes each check of each extractor a test of its own, with
an id naming both (as scikit-learn's ``parametrize_with_checks``):

    @parametrize_with_checks([("mine", MyExtractor, {"my_param": 2})])
    def test_contract(extractor, params, check):
        check(extractor, params, synthetic_run())
 Features and distances computed twice
count as the same within `RTOL` / `ATOL` (batch sizes may change the order of float sums).
"""

from __future__ import annotations

import copy
import tempfile
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from vitaplace.engine.data.dataset import Run
from vitaplace.engine.extension.features import TACTILE, VISUAL, FeatureExtractor, Features

__all__ = [
    "ATOL", "CHECKS", "RTOL", "ContractError", "check_declared_senses", "check_distance_before_fit",
    "check_distance_output", "check_distance_rows", "check_extractor", "check_features_output",
    "check_fit_leaves_params", "check_missing_modalities", "check_same_seed_same_features",
    "check_save_load_round_trip", "check_transform_before_fit", "check_transform_subset", "parametrize_with_checks",
    "synthetic_run",
]

RTOL = 1e-5
ATOL = 1e-6
#: errors that come from code tripping over missing state, not from a deliberate message
ACCIDENTAL_ERRORS = (AttributeError, TypeError, KeyError, IndexError, NameError)

RawParams = Mapping[str, Any] | None


class ContractError(AssertionError):
    """An extractor breaks a rule of the plugin contract; the message names the check and the extractor."""


def _fail(check: Callable[..., None], cls: type[FeatureExtractor], problem: str) -> ContractError:
    return ContractError(f"{check.__name__}: extractor '{getattr(cls, 'name', cls.__name__)}' {problem}")


def synthetic_run(n_samples: int = 8, seed: int = 0, image_shape: tuple[int, int] = (24, 32)) -> Run:
    """A small run of random but valid data: RGB noise images, 24 whiskers with theta, xy and
    a 3-sample deflection series, 2-4 contacts per whisk cycle with unit normals."""
    rng = np.random.default_rng(seed)
    whiskers = 24  # the WhiskEye's
    counts = rng.integers(2, 5, n_samples)
    normals = rng.normal(size=(int(counts.sum()), 3))
    return Run.from_arrays(
        images=rng.integers(0, 256, (n_samples, *image_shape, 3), dtype=np.uint8),
        theta=rng.uniform(-0.6, 0.6, (n_samples, whiskers)),
        xy=rng.normal(0.0, 0.05, (n_samples, whiskers, 2)),
        deflection=rng.normal(0.0, 0.05, (n_samples, 3, whiskers, 2)),
        contact_points=rng.uniform(-0.2, 0.2, (int(counts.sum()), 3)),
        contact_normals=normals / np.linalg.norm(normals, axis=1, keepdims=True),
        contact_offsets=np.concatenate([[0], np.cumsum(counts)]),
        poses=np.column_stack([rng.uniform(-1, 1, (n_samples, 2)), rng.uniform(-np.pi, np.pi, n_samples)]),
        name=f"synthetic-{seed}",
    )


def _fitted(cls: type[FeatureExtractor], params: RawParams, run: Run) -> FeatureExtractor:
    extractor = cls(params)
    extractor.progress = False
    extractor.fit(run)
    return extractor


def _kind(value: Any) -> str:
    """What ``value`` is, for a message: its type, and its dtype if it is an array."""
    return f"an array of {value.dtype}" if isinstance(value, np.ndarray) else f"a {type(value).__name__}"


def _differences(expected: Features, actual: Mapping[str, Any]) -> list[str]:
    """The keys on which two feature sets differ (beyond RTOL / ATOL), with how."""
    if expected.keys() != actual.keys():
        return [f"keys {sorted(actual)} instead of {sorted(expected)}"]
    out = []
    for key, want in expected.items():
        got, want = np.asarray(actual[key], dtype=float), np.asarray(want, dtype=float)
        if got.shape != want.shape:
            out.append(f"'{key}' has shape {got.shape} instead of {want.shape}")
        elif not np.allclose(got, want, rtol=RTOL, atol=ATOL, equal_nan=True):
            out.append(f"'{key}' differs by up to {np.max(np.abs(got - want)):.3g}")
    return out


def _same_distances(expected: np.ndarray, actual: np.ndarray) -> bool:
    return np.shape(actual) == np.shape(expected) and np.allclose(actual, expected, rtol=RTOL, atol=ATOL)


def check_features_output(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """``transform`` gives a non-empty dict of arrays with one row per sample, finite numbers."""
    features = _fitted(cls, params, run).transform(run)
    if not isinstance(features, Mapping) or not features:
        what = "an empty dict" if isinstance(features, Mapping) else type(features).__name__
        raise _fail(check_features_output, cls, f"transform returned {what}, expected a non-empty dict of arrays")
    for key, value in features.items():
        if not isinstance(value, np.ndarray) or value.dtype.kind not in "biuf":
            raise _fail(check_features_output, cls, f"feature '{key}' is {_kind(value)}, expected a numpy array "
                        "of numbers or booleans")
        if value.ndim == 0 or len(value) != len(run):
            raise _fail(check_features_output, cls, f"feature '{key}' has shape {value.shape} for a run of "
                        f"{len(run)} samples; its first axis must be the sample index")
        if not np.isfinite(value).all():
            raise _fail(check_features_output, cls, f"feature '{key}' has NaN or infinite values "
                        f"(first in sample {int(np.argmin(np.isfinite(value.reshape(len(run), -1)).all(axis=1)))})")


def check_distance_output(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """``distance(query, reference)`` is a finite (n_query, n_reference) matrix of numbers."""
    extractor = _fitted(cls, params, run)
    query = run.subset(slice(0, max(1, len(run) // 2)))
    distances = extractor.distance(extractor.transform(query), extractor.transform(run))
    expected = (len(query), len(run))
    if not isinstance(distances, np.ndarray) or distances.dtype.kind not in "iuf":
        raise _fail(check_distance_output, cls, f"distance returned {_kind(distances)}, expected a numpy array "
                    "of numbers")
    if distances.shape != expected:
        raise _fail(check_distance_output, cls, f"distance of {expected[0]} query and {expected[1]} reference "
                    f"samples has shape {distances.shape}, expected {expected}")
    if not np.isfinite(distances).all():
        raise _fail(check_distance_output, cls, f"distance has {int((~np.isfinite(distances)).sum())} NaN or "
                    "infinite entries")


def check_distance_rows(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """A query's row of ``distance`` depends on that query alone: the distances of a block of
    queries are those rows of the distances of them all (the pipeline asks for them a block of
    queries at a time, so that a large pair is scored in memory linear in its samples)."""
    extractor = _fitted(cls, params, run)
    features = extractor.transform(run)
    whole = np.asarray(extractor.distance(features, features))
    start, stop = len(run) // 4, max(len(run) // 4 + 1, len(run) // 2)
    block = np.asarray(extractor.distance({key: value[start:stop] for key, value in features.items()}, features))
    if not _same_distances(whole[start:stop], block):
        how = (f"has shape {block.shape}" if block.shape != whole[start:stop].shape
               else f"differs by up to {np.max(np.abs(block - whole[start:stop])):.3g}")
        raise _fail(check_distance_rows, cls, f"distance of query samples {start}..{stop - 1} is not those rows of "
                    f"distance of all {len(run)}: it {how}; a row must depend on its query alone")


def check_transform_subset(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """Transforming some samples gives the matching rows of transforming them all (features
    of a sample do not depend on which other samples are transformed with it)."""
    extractor = _fitted(cls, params, run)
    index = np.arange(len(run))[::-2]  # every other sample, in reverse order
    whole = extractor.transform(run)
    part = extractor.transform(run.subset(index))
    problems = _differences({key: np.asarray(value)[index] for key, value in whole.items()}, part)
    if problems:
        raise _fail(check_transform_subset, cls, f"transform(run.subset({index.tolist()})) is not those rows of "
                    f"transform(run): {'; '.join(problems)}")


def check_save_load_round_trip(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """``cls.load`` of what ``save`` wrote gives an extractor of the same class and parameters
    whose features and distances are those of the saved one."""
    extractor = _fitted(cls, params, run)
    features = extractor.transform(run)
    with tempfile.TemporaryDirectory() as folder:
        extractor.save(folder)
        loaded = cls.load(folder)
    loaded.progress = False
    if type(loaded) is not cls or loaded.params != extractor.params:
        raise _fail(check_save_load_round_trip, cls, f"load gave {type(loaded).__name__} with params "
                    f"{getattr(loaded, 'params', None)!r}, expected {cls.__name__} with {extractor.params!r}")
    reloaded = loaded.transform(run)
    problems = _differences(features, reloaded)
    if problems:
        raise _fail(check_save_load_round_trip, cls, f"after save and load, transform differs: {'; '.join(problems)}")
    if not _same_distances(extractor.distance(features, features), loaded.distance(reloaded, reloaded)):
        raise _fail(check_save_load_round_trip, cls, "after save and load, distance gives other values: "
                    "save_state / load_state lose part of the fitted state")


def _check_before_fit(check: Callable[..., None], cls: type[FeatureExtractor], call: str,
                      unfitted: Callable[[], Any], same_as_fitted: Callable[[Any], bool]) -> None:
    """``unfitted()`` must raise a clear error (a deliberate exception whose message mentions
    fit) or, for a method that needs no fitted state, give what the fitted extractor gives."""
    try:
        result = unfitted()
    except ACCIDENTAL_ERRORS as exc:
        raise _fail(check, cls, f"{call} before fit raised {type(exc).__name__}: {exc}; raise a clear error "
                    "instead (e.g. RuntimeError('... call fit() or load() first'))") from exc
    except Exception as exc:  # noqa: BLE001 - any deliberate exception is fine if its message is clear
        if "fit" not in str(exc).lower():
            raise _fail(check, cls, f"{call} before fit raised {type(exc).__name__}: {exc!s:.200}; its message "
                        "should say that fit() (or load()) comes first") from exc
        return
    if not same_as_fitted(result):
        raise _fail(check, cls, f"{call} before fit returned a result unlike the fitted extractor's; it uses "
                    "fitted state that is not there yet: raise a clear error instead")


def check_distance_before_fit(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """``distance`` on a new, unfitted extractor raises a clear error, unless it needs no
    fitted state (then it gives the fitted extractor's distances)."""
    extractor = _fitted(cls, params, run)
    features = extractor.transform(run)
    expected = extractor.distance(features, features)
    fresh = cls(params)
    fresh.progress = False
    _check_before_fit(check_distance_before_fit, cls, "distance", lambda: fresh.distance(features, features),
                      lambda got: _same_distances(expected, got))


def check_transform_before_fit(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """``transform`` on a new, unfitted extractor raises a clear error, unless it needs no
    fitted state (then it gives the fitted extractor's features)."""
    expected = _fitted(cls, params, run).transform(run)
    fresh = cls(params)
    fresh.progress = False
    _check_before_fit(check_transform_before_fit, cls, "transform", lambda: fresh.transform(run),
                      lambda got: isinstance(got, Mapping) and not _differences(expected, got))


def check_same_seed_same_features(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """Two extractors with the same parameters (seed included) fitted on the same run give
    the same features and distances: all randomness comes from ``params``."""
    first, second = _fitted(cls, params, run), _fitted(cls, params, run)
    features, again = first.transform(run), second.transform(run)
    problems = _differences(features, again)
    if problems:
        raise _fail(check_same_seed_same_features, cls, f"fitted twice with the same parameters, gives other "
                    f"features: {'; '.join(problems)}; draw random numbers from a generator seeded by params")
    if not _same_distances(first.distance(features, features), second.distance(again, again)):
        raise _fail(check_same_seed_same_features, cls, "fitted twice with the same parameters, gives other "
                    "distances; draw random numbers from a generator seeded by params")


def check_fit_leaves_params(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """``fit`` changes neither the parameters it was given nor ``self.params`` (they are what
    the cache key and the saved params.json describe)."""
    given = copy.deepcopy(params)
    extractor = cls(params)
    extractor.progress = False
    before = extractor.params.model_dump()
    extractor.fit(run)
    if params != given:
        raise _fail(check_fit_leaves_params, cls, f"fit changed the parameters it was given: {given!r} became "
                    f"{params!r}")
    after = extractor.params.model_dump()
    if after != before:
        changed = sorted(key for key in before.keys() | after.keys() if before.get(key) != after.get(key))
        raise _fail(check_fit_leaves_params, cls, f"fit changed self.params ({', '.join(changed)}); keep what "
                    "fit learns in attributes of its own")


def check_declared_senses(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """``modalities`` (optional) says None (unknown) or a non-empty set of `VISUAL` and
    `TACTILE`: the senses by which the pipeline pairs vision-only and touch-only methods."""
    senses = cls.modalities(cls.validate_params(params or {}))
    if senses is not None and not (isinstance(senses, (set, frozenset)) and senses and senses <= {VISUAL, TACTILE}):
        raise _fail(check_declared_senses, cls, f"modalities returned {senses!r}, expected None (unknown) or a "
                    f"non-empty set of {VISUAL!r} and {TACTILE!r}")
def _other_lost_data(run: Run, lost: Mapping[str, np.ndarray]) -> Run:
    """``run`` with other data where its samples lack a sensor: the lost frames inverted, the
    lost whisker signals negated and their contacts mirrored through the origin."""
    camera, whiskers = lost["camera"], lost["whiskers"]
    points, normals = run._get("contact_points").copy(), run._get("contact_normals").copy()
    owner = np.repeat(np.arange(len(run)), np.diff(run.contact_offsets))
    points[whiskers[owner]] *= -1
    normals[whiskers[owner]] *= -1
    sign = np.where(whiskers, -1.0, 1.0)
    other = Run.from_arrays(
        images=np.where(camera[:, None, None, None], 255 - run.images, run.images), theta=run.theta * sign[:, None],
        xy=run.xy * sign[:, None, None], deflection=run.deflection * sign[:, None, None, None], poses=run.poses,
        times=run.times, contact_points=points, contact_normals=normals, contact_offsets=run.contact_offsets,
        name=run.name, attrs=run.attrs)
    other.missing = dict(lost)
    return other


def check_missing_modalities(cls: type[FeatureExtractor], params: RawParams, run: Run) -> None:
    """An extractor that declares ``handles_missing`` describes a sample that lacks a sensor
    (`Run.lacks`) without that sensor's data: changing the lost frames and whisker data of
    such samples changes neither the features nor the distances. Extractors that do not
    declare it are not asked (scenarios with a query drop-out refuse them)."""
    if not getattr(cls, "handles_missing", False):
        return
    extractor = _fitted(cls, params, run)
    index = np.arange(len(run))
    lost = {"camera": index % 3 == 1, "whiskers": index % 3 == 2}
    query = run.subset(slice(None))
    query.missing = dict(lost)
    features, changed = extractor.transform(query), extractor.transform(_other_lost_data(query, lost))
    problems = _differences(features, changed)
    if problems:
        raise _fail(check_missing_modalities, cls, "declares handles_missing, but changing the data of the sensors "
                    f"samples lack (Run.lacks) changed the features: {'; '.join(problems)}")
    reference = extractor.transform(run)
    if not _same_distances(extractor.distance(features, reference), extractor.distance(changed, reference)):
        raise _fail(check_missing_modalities, cls, "declares handles_missing, but changing the data of the sensors "
                    "samples lack (Run.lacks) changed the distances")


#: every check, in the order `check_extractor` runs them
CHECKS: tuple[Callable[[type[FeatureExtractor], RawParams, Run], None], ...] = (
    check_features_output,
    check_distance_output,
    check_distance_rows,
    check_transform_subset,
    check_save_load_round_trip,
    check_transform_before_fit,
    check_distance_before_fit,
    check_same_seed_same_features,
    check_fit_leaves_params,
    check_declared_senses,
    check_missing_modalities,
)


def check_extractor(cls: type[FeatureExtractor], params: RawParams = None, run: Run | None = None) -> None:
    """Check that the extractor class ``cls`` with ``params`` keeps the plugin contract of
    docs/plugins.md; raise `ContractError` naming the first check it fails. ``run``: the
    training and test run (default `synthetic_run()`: 8 samples, 24 x 32 images, 24
    whiskers); pass your own when the extractor needs other data."""
    if not (isinstance(cls, type) and issubclass(cls, FeatureExtractor)):
        raise ContractError(f"check_extractor: {cls!r} is not a FeatureExtractor subclass")
    run = synthetic_run() if run is None else run
    for check in CHECKS:
        check(cls, copy.deepcopy(params), run)  # a check changing its params must not hide it from the next


def parametrize_with_checks(extractors: Sequence[tuple[str, type[FeatureExtractor], RawParams]]) -> Any:
    """A pytest ``parametrize`` mark over every check of `CHECKS` for each ``(name, class,
    params)`` of ``extractors``: the test takes ``extractor``, ``params`` and ``check`` and
    runs ``check(extractor, params, run)``; each test's id is ``NAME-CHECK`` (e.g.
    ``handcrafted-check_save_load_round_trip``), so a report names the broken rule."""
    import pytest  # only where the checks are run as tests

    return pytest.mark.parametrize("extractor, params, check", [
        pytest.param(cls, copy.deepcopy(params), check, id=f"{name}-{check.__name__}")
        for name, cls, params in extractors for check in CHECKS
    ])
