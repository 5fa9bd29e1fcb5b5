"""The floor of what can be predicted, and a model's misses by cause."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from dynplan.env import RoadConfig, generate_world
from dynplan.env.road import fold_goal, goal_box, round_px
from dynplan.evaluation.prediction import errors_by_horizon, foreseeable_frames, miss_causes
from dynplan.models.metrics import frame_errors
from dynplan.planning.forward import ZeroModel
from lab.context_bound import GOAL_GRID, ContextBoundModel


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


def test_the_context_bound_falls_with_the_context_toward_the_floor():
    curves = {n: errors_by_horizon(lambda world, n=n: ContextBoundModel(world, n), episodes=3, points=5, horizon=3)
              for n in (1, 4, 16)}  # fmt: skip
    fn = {n: np.array(curve["fn_rate"]) for n, curve in curves.items()}
    floor = np.array(curves[1]["floor_fn_rate"])
    assert (fn[1] > fn[4]).all() and (fn[4] > fn[16]).all() and (fn[16] >= floor - 1e-9).all()
    assert (np.array(curves[16]["fn_unforeseeable"]) <= floor + 1e-9).all()  # it predicts only what is on the road
    assert max(curves[4]["fp_rate"]) < 0.01  # one placement per obstacle, no spread


def test_an_obstacle_tracked_long_enough_is_placed_where_it_is():
    world = generate_world(RoadConfig(), 3)
    t = 150
    on_road, placed = ContextBoundModel(world, t + 1).placements(t, 1)
    traffic = world.traffic
    age = world.config.width + t + 1 - traffic.step[on_road]
    truth = round_px(traffic.x_at_age(age, on_road))
    assert len(on_road) > 5 and np.abs(placed[:, 0] - truth).max() <= 1 and (placed[:, 0] == truth).mean() >= 0.8
    assert (ContextBoundModel(world, 1).placements(t, 1)[1][:, 0] != truth).any()  # one frame leaves speeds open


def test_the_context_bound_refuses_what_it_cannot_bound():
    world = generate_world(RoadConfig(), 3)
    with pytest.raises(ValueError, match="context must be a whole number of frames >= 1, got 0"):
        ContextBoundModel(world, 0)
    with pytest.raises(ValueError, match="needs a generated world"):
        ContextBoundModel(replace(world, traffic=None), 4)
    with pytest.raises(ValueError, match=r"occupancy must be in \[0, 1\)"):
        ContextBoundModel(world, 4, 1.0)


def test_the_context_bounds_occupancy_buys_its_misses_back_with_few_false_positives():
    def curve(occupancy):
        return errors_by_horizon(lambda world: ContextBoundModel(world, 4, occupancy), episodes=3, points=5, horizon=3)

    placed, covered = curve(0.0), curve(0.1)
    assert (np.array(covered["fn_rate"]) < np.array(placed["fn_rate"])).all()
    assert (np.array(covered["fp_rate"]) >= np.array(placed["fp_rate"])).all() and max(covered["fp_rate"]) < 0.02
    np.testing.assert_allclose(covered["fn_rate"], covered["floor_fn_rate"], atol=0.01)  # at the floor, within a point


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(4, 190), st.sampled_from([1, 2, 4, 8]))
def test_the_true_goal_is_always_among_its_hypotheses(seed, t, context):
    """The goal's own (position, velocity) matches its rounded blocks, so the shares give its true block some
    weight at every step ahead, and each step's shares sum to one — up to the hypotheses' grid: a goal that comes
    within 1/GOAL_GRID px of a rounding boundary (seed 3553, t = 4) lies between two hypotheses that round apart."""
    world = generate_world(RoadConfig(), seed)
    near_boundary = np.abs(world.goal[max(0, t - context + 1) : t + 6] % 1.0 - 0.5) < 1.0 / GOAL_GRID
    assume(not near_boundary.any())
    shares = ContextBoundModel(world, context).goal_shares(t, 5)
    truth = round_px(world.goal[t + 1 : t + 6])
    np.testing.assert_allclose(shares.sum(axis=(1, 2)), 1.0)
    assert (shares[np.arange(5), truth[:, 0], truth[:, 1]] > 0).all()


def test_the_goal_bound_sharpens_with_the_context():
    """One frame leaves the heading open (the block is off at most decisions); four pin it but for its phase, as
    do sixteen."""
    off = {}
    for context in (1, 4, 16):
        wrong = []
        for seed in range(6):
            world = generate_world(RoadConfig(), 2_000_000 + seed)
            model = ContextBoundModel(world, context)
            for t in range(10, 200, 19):
                placed = model.goal_placements(t, 3)
                wrong.append((placed != round_px(world.goal[t + 1 : t + 4])).any(axis=1))
        off[context] = np.mean(wrong)
    assert off[1] > 0.5 and max(off[4], off[16]) < 0.15


@pytest.mark.parametrize(
    ("seed", "t", "context"), [(2_000_001, 40, 2), (2_000_003, 100, 4), (5, 7, 8), (0, 20, 3), (0, 24, 4)]
)
def test_the_goal_shares_are_the_joint_hypotheses_counted_one_by_one(monkeypatch, seed, t, context):
    """The per-axis product equals counting every (position on the 2-D grid, folded velocity) hypothesis whose
    rounded blocks over the context match, including where the goal bounces (seed 0 at frame 22)."""
    import lab.context_bound as bound

    monkeypatch.setattr(bound, "GOAL_GRID", 16)
    world = generate_world(RoadConfig(), seed)
    config, seen = world.config, world.goal_px
    cell = (np.arange(16) + 0.5) / 16 - 0.5
    points = np.stack(np.meshgrid(seen[t, 0] + cell, seen[t, 1] + cell, indexing="ij"), axis=-1).reshape(-1, 2)
    points = points[np.all((points >= 0) & (points <= goal_box(config)), axis=1)]
    expected = np.zeros((3, config.height - 1, config.width - 1))
    frames = np.arange(max(0, t - context + 1), t + 1)
    for velocity in bound.folded_goal_velocities(config):
        for point in points:
            past = round_px(fold_goal(config, point + (frames - t)[:, None] * velocity))
            if (past == seen[frames]).all():
                ahead = round_px(fold_goal(config, point + np.arange(1, 4)[:, None] * velocity))
                expected[np.arange(3), ahead[:, 0], ahead[:, 1]] += 1
    np.testing.assert_allclose(ContextBoundModel(world, context).goal_shares(t, 3), expected / expected[0].sum())


def test_the_goal_bound_predicts_no_frame_past_the_episode():
    world = generate_world(RoadConfig(), 3)
    model = ContextBoundModel(world, 4)
    assert model.goal_placements(50, 0).shape == (0, 2)
    assert len(model.predict(world.frames, 3).frames) == 0
