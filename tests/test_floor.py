"""The floor of what can be predicted, and a model's misses by cause."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dynplan.analysis.prediction import errors_by_horizon, foreseeable_frames, miss_causes
from dynplan.env import RoadConfig, generate_world
from dynplan.models.metrics import frame_errors
from dynplan.planning.forward import ZeroModel


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_causes_add_up_to_the_false_negatives(seed):
    rng = np.random.default_rng(seed)
    truth, predicted, seen = (rng.choice([0, 0, 0, 45, 100, 244], size=(2, 6, 9)).astype(np.uint8) for _ in range(3))
    causes = miss_causes(truth, predicted, seen)
    parts = causes["unforeseeable"] + causes["displaced"] + causes["lost"]
    assert np.isclose(parts, frame_errors(truth, predicted)["fn_rate"])
    assert causes["unforeseeable"] <= causes["floor"] + 1e-12


def test_a_miss_beside_a_predicted_obstacle_is_displaced_and_a_far_one_lost():
    truth = np.zeros((1, 3, 20), np.uint8)
    truth[0, 1, 10:13] = 100
    predicted = np.zeros_like(truth)
    predicted[0, 1, 12:15] = 100
    assert miss_causes(truth, predicted, truth) == {"floor": 0.0, "unforeseeable": 0.0, "displaced": 2 / 3, "lost": 0.0}
    near = miss_causes(truth, predicted, truth, reach=1)
    assert np.isclose(near["displaced"], 1 / 3) and np.isclose(near["lost"], 1 / 3)
    assert miss_causes(truth, predicted, np.zeros_like(truth))["unforeseeable"] == 2 / 3


def test_the_foreseeable_future_holds_only_obstacles_already_on_the_road():
    world = generate_world(RoadConfig(), 7)
    t, horizon = 40, 10
    foreseeable = foreseeable_frames(world, t, horizon)
    truth = world.frames[t + 1 : t + 1 + horizon]
    seen = (foreseeable != 0) & (foreseeable != 244)
    real = (truth != 0) & (truth != 244)
    assert foreseeable.shape == truth.shape and not (seen & ~real).any()  # nothing that is not there
    missing = [(real[h] & ~seen[h]).sum() for h in range(horizon)]
    assert missing[0] <= missing[-1] and missing[-1] > 0  # more has entered the further ahead
    assert np.array_equal(foreseeable_frames(world, t, 0), truth[:0])


def test_an_empty_road_misses_the_floor_as_unforeseeable_and_the_rest_as_lost():
    curve = errors_by_horizon(ZeroModel(), episodes=2, points=3, horizon=5)
    floor, unforeseeable, lost = (np.array(curve[k]) for k in ("floor_fn_rate", "fn_unforeseeable", "fn_lost"))
    np.testing.assert_allclose(unforeseeable, floor, atol=1e-5)
    np.testing.assert_allclose(lost, 1 - floor, atol=1e-5)
    assert curve["fn_displaced"] == [0.0] * 5 and floor[0] > 0 and floor[-1] > floor[0]
