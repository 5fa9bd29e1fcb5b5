"""Swapping a prediction's parts for the truth's: the frames, and the replay of an evaluated case."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from dynplan.env.config import FREE, GOAL_VALUE
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.protocol import plan_episode
from lab.parts import VIEWS, play_views, swap_parts

pixels = st.sampled_from([FREE, GOAL_VALUE, 45, 144])


@given(arrays(np.uint8, (2, 6, 6), elements=pixels), arrays(np.uint8, (2, 6, 6), elements=pixels))
def test_each_view_takes_the_obstacles_of_one_and_the_goal_of_the_other(learned, truth):
    def obstacles(frames):
        return np.where((frames != FREE) & (frames != GOAL_VALUE), frames, 0)

    assert swap_parts(learned, truth, "learned") is learned and swap_parts(learned, truth, "truth") is truth
    for view, (road, goal) in (("true_goal", (learned, truth)), ("true_obstacles", (truth, learned))):
        frames = swap_parts(learned, truth, view)
        np.testing.assert_array_equal(obstacles(frames), obstacles(road))  # every obstacle of the one
        np.testing.assert_array_equal(frames == GOAL_VALUE, (goal == GOAL_VALUE) & (obstacles(road) == 0))
    np.testing.assert_array_equal(swap_parts(truth, truth, "true_goal"), truth)  # both true: the truth
    with pytest.raises(ValueError, match="view must be one of"):
        swap_parts(learned, truth, "both")


@pytest.mark.slow
def test_the_learned_view_replays_the_evaluated_case():
    seeds = [2000000, 2000001]
    played = play_views("samples5", "default", 1.0, 1, seeds)
    assert set(played) == set(VIEWS) and all(set(o) == set(seeds) for o in played.values())
    for seed in seeds:
        assert (
            played["learned"][seed] == plan_episode(seed, AgentSpec(technique="samples5", rollout_steps=1), 1.0).outcome
        )
