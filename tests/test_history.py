"""The history rule shared by the prior's training windows and the world model's contexts."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dynplan.data.history import context_indices, first_target, last_frames
from dynplan.env.agent import FIRST_DECISION_FRAME


@given(st.integers(1, 40), st.integers(1, 16))
def test_the_history_is_the_frames_before_the_target_with_frame_0_repeated(target, context):
    indices = context_indices(target, context)
    assert indices.shape == (context,)
    assert (np.diff(indices) >= 0).all() and indices[-1] == target - 1
    kept = indices[indices > 0]
    np.testing.assert_array_equal(kept, np.arange(target - len(kept), target))
    assert (indices == 0).sum() == max(context - target + 1, 0)


def test_context_indices_broadcast_over_targets():
    indices = context_indices(np.array([[5, 9], [1, 2]]), 4)
    assert indices.shape == (2, 2, 4)
    np.testing.assert_array_equal(indices[0, 0], [1, 2, 3, 4])
    np.testing.assert_array_equal(indices[1, 0], [0, 0, 0, 0])
    np.testing.assert_array_equal(indices[1, 1], [0, 0, 0, 1])


def test_last_frames_pads_a_short_observation_and_keeps_a_long_one():
    frames = np.arange(6)[:, None, None] * np.ones((6, 2, 2), np.uint8)
    assert [int(f[0, 0]) for f in last_frames(frames, 4)] == [2, 3, 4, 5]
    assert [int(f[0, 0]) for f in last_frames(frames[:2], 4)] == [0, 0, 0, 1]
    with pytest.raises(ValueError, match="no frames observed"):
        last_frames(frames[:0], 4)
    with pytest.raises(ValueError, match="context must be"):
        context_indices(3, 0)


def test_training_starts_where_padding_is_needed_only_for_longer_contexts():
    assert first_target(4) == 4  # the paper's windows: no padded history
    assert first_target(8) == FIRST_DECISION_FRAME + 1  # the first frame the planner predicts
