"""Complementarity of a vision-only and a touch-only method: hand-worked decisions, and which
methods pair by themselves (the plugins' declared senses) or by the scenario."""

import numpy as np
import pytest

from vitaplace.engine.config.methods import complementarity_pairs
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation.complementarity import COMPLEMENTARITY_KEYS, complementarity, count_text
from vitaplace.engine.extension.registry import discover
from vitaplace.plugin import ExtractorParams, FeatureExtractor

# tau 0.3 m; 5 queries x 3 references. True matches (gtm <= 0.3): q0 r0; q1 r1; q2 r2;
# q3 r0 and r1; q4 none (4 revisits).
GTM = np.array([
    [0.1, 1.0, 2.0],
    [1.0, 0.2, 1.0],
    [2.0, 1.0, 0.0],
    [0.1, 0.2, 1.0],
    [1.0, 1.0, 1.0],
])
# vision best matches: q0 r1 (wrong), q1 r1 (right), q2 r0 (tie r0/r1 -> lowest, wrong),
# q3 r1 (right), q4 r0 (no revisit) -> R@1 2/4, wrong q0 and q2
VISION = np.array([
    [0.5, 0.1, 0.9],
    [0.5, 0.1, 0.9],
    [0.2, 0.2, 0.3],
    [0.9, 0.1, 0.5],
    [0.1, 0.2, 0.3],
])
# touch best matches: q0 r0 (right: rescues q0), q1 r0 (wrong), q2 a tie of r1 (wrong) and r2
# (right): right half the time, rescuing q2 by 1/2 (the lowest index, r1, would never rescue
# it), q3 r2 (wrong), q4 r2 -> R@1 (1 + 1/2)/4 = 3/8; rescued 1 + 1/2 of 2: 3/4; the oracle is
# right on q0, q1, q3 and half of q2: 7/8
TOUCH = np.array([
    [0.1, 0.5, 0.5],
    [0.1, 0.5, 0.5],
    [0.4, 0.3, 0.3],
    [0.9, 0.5, 0.1],
    [0.3, 0.2, 0.1],
])


def decisions(tme, gtm=GTM):
    return ev.decide(tme, gtm, 0.3, np.inf)


def test_complementarity_hand_case():
    c = complementarity(decisions(VISION), decisions(TOUCH))
    assert list(c) == list(COMPLEMENTARITY_KEYS)
    assert c == {"n_revisit": 4, "vision_r1": 0.5, "touch_r1": 0.375, "vision_wrong": 2, "rescued": 1.5,
                 "rescue": 0.75, "oracle_r1": 0.875}
    # the roles swapped: touch wrong on q1, q3 and half of q2 (2.5); vision gets q1 and q3 right,
    # q2 never -> 2 of 2.5
    swapped = complementarity(decisions(TOUCH), decisions(VISION))
    assert (swapped["vision_wrong"], swapped["rescued"], swapped["rescue"]) == (2.5, 2, pytest.approx(0.8))
    assert swapped["oracle_r1"] == 0.875


def test_ties_on_both_sides_are_independent_draws():
    # one query, four references, r0 and r1 true matches; vision ties r0 (right) with r2, r3
    # (1/3 right), touch ties r1 (right) with r2 (1/2 right): vision wrong 2/3 of a query, touch
    # right on half of that (1/3 rescued, rescue 1/2), the oracle right 1 - (2/3)(1/2) = 2/3
    gtm = np.array([[0.1, 0.2, 1.0, 1.0]])
    vision = decisions(np.array([[0.1, 0.5, 0.1, 0.1]]), gtm)
    touch = decisions(np.array([[0.9, 0.2, 0.2, 0.7]]), gtm)
    c = complementarity(vision, touch)
    assert c == {"n_revisit": 1, "vision_r1": pytest.approx(1 / 3), "touch_r1": 0.5,
                 "vision_wrong": pytest.approx(2 / 3), "rescued": pytest.approx(1 / 3), "rescue": pytest.approx(0.5),
                 "oracle_r1": pytest.approx(2 / 3)}
    assert [count_text(c["vision_wrong"]), count_text(2), count_text(2.0)] == ["0.67", "2", "2"]


def test_complementarity_when_vision_is_never_wrong_or_no_query_has_a_true_match():
    # vision right on every revisit (best matches r0, r1, r2, r0): nothing to rescue
    perfect = np.array([[0, 1, 1], [1, 0, 1], [1, 1, 0], [0, 1, 1], [0, 1, 1]], dtype=float)
    c = complementarity(decisions(perfect), decisions(TOUCH))
    assert (c["vision_r1"], c["vision_wrong"], c["rescued"], c["rescue"], c["oracle_r1"]) == (1.0, 0, 0, None, 1.0)
    far = GTM + 10
    c = complementarity(decisions(VISION, far), decisions(TOUCH, far))
    assert c == {"n_revisit": 0, "vision_r1": None, "touch_r1": None, "vision_wrong": 0, "rescued": 0,
                 "rescue": None, "oracle_r1": None}


def test_complementarity_refuses_decisions_of_other_queries():
    with pytest.raises(ValueError, match="same queries"):
        complementarity(decisions(VISION), decisions(TOUCH[:4], GTM[:4]))
    with pytest.raises(ValueError, match="same queries"):
        complementarity(decisions(VISION), decisions(TOUCH, GTM + 10))


def scenario(methods, pairs=()):
    return Scenario.model_validate({
        "name": "t",
        "train": {"dataset": "train.h5"},
        "evaluations": [{"name": "E", "datasets": {"query": "q.h5", "reference": "r.h5"}}],
        "methods": methods,
        "scoring": {"complementarity": [{"vision": v, "touch": t} for v, t in pairs]},
    })


def test_vision_and_touch_only_methods_of_one_plugin_pair_by_themselves():
    methods = [
        {"name": "H", "plugin": "handcrafted"},
        {"name": "H-T", "plugin": "handcrafted", "params": {"use_visual": False}},
        {"name": "L-V", "plugin": "mupnet", "params": {"modalities": ["visual"]}},
        {"name": "H-V", "plugin": "handcrafted", "params": {"use_tactile": False}},
        {"name": "L-T", "plugin": "mupnet", "params": {"modalities": ["tactile"]}},
        {"name": "L", "plugin": "mupnet"},
    ]
    # in the order of the vision methods; never across plugins (H-V with L-T), never a
    # method with both senses; then the scenario's own pairs, each pair once
    pairs = complementarity_pairs(scenario(methods, [("H-V", "L-T"), ("H-V", "H-T")]), discover())
    assert pairs == [("L-V", "L-T"), ("H-V", "H-T"), ("H-V", "L-T")]


class Unsaid(FeatureExtractor):
    """An extractor that does not declare its senses."""

    name = "unsaid"

    def fit(self, train): ...
    def transform(self, run): ...
    def distance(self, query, reference): ...
    def save_state(self, directory): ...
    def load_state(self, directory): ...


def test_an_extractor_that_does_not_declare_its_senses_is_unknown():
    assert Unsaid.modalities(ExtractorParams()) is None
    handcrafted, mupnet = discover().get("handcrafted"), discover().get("mupnet")
    assert handcrafted.modalities(handcrafted.validate_params({})) == {"visual", "tactile"}
    assert handcrafted.modalities(handcrafted.validate_params({"use_visual": False})) == {"tactile"}
    assert mupnet.modalities(mupnet.validate_params({"modalities": ["visual"]})) == {"visual"}
