"""The learned forward model: merging decoder samples, predicting through the planner's seam, loading."""

import functools
import re

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from dynplan.env import GOAL_VALUE, RoadConfig, generate_world
from dynplan.models.caution import Caution, merge_samples, widen_obstacles
from dynplan.models.chain import chain
from dynplan.models.checkpoint import CheckpointError
from dynplan.models.configs import PixelCNNConfig, VQVAEConfig
from dynplan.models.pixelcnn import ConditionalPixelCNN
from dynplan.models.registry import WORLD_MODELS, caution_for, world_model_names
from dynplan.models.streams import observation_stream
from dynplan.models.vqvae import VQVAE
from dynplan.models.world_model import LearnedWorldModel, load_world_model
from dynplan.planning.config import MCTSConfig
from dynplan.planning.episode import run_episode
from dynplan.planning.mcts import MCTSPlanner


def test_merge_takes_the_union_of_obstacles_and_the_median_goal():
    mid = np.zeros((1, 12, 12), np.uint8)
    samples = np.zeros((3, 1, 12, 12), np.uint8)
    mid[0, 2, 3] = 144
    samples[0, 0, 5, 5] = 45
    samples[1, 0, 2, 3] = 100
    for i, (y, x) in enumerate([(8, 8), (9, 9), (8, 8)]):
        samples[i, 0, y : y + 2, x : x + 2] = GOAL_VALUE
    mid[0, 8:10, 8:10] = GOAL_VALUE
    merged = merge_samples(mid, samples)[0]
    assert merged[2, 3] == 144 and merged[5, 5] == 45  # any obstacle anywhere, at the largest value seen
    goal = np.argwhere(merged == GOAL_VALUE)
    assert goal.min(axis=0).tolist() == [8, 8] and len(goal) == 4  # the median of the four blocks seen
    assert not merge_samples(np.zeros((2, 12, 12), np.uint8), np.zeros((1, 2, 12, 12), np.uint8)).any()


@pytest.fixture(scope="module")
def tiny_model():
    torch.manual_seed(0)
    tokenizer = VQVAE(VQVAEConfig(channels=(8, 8, 8), strides=(2, 2, 2), latent_dim=4, codebook_size=16,
                                  likelihood="categorical"))  # fmt: skip
    prior = ConditionalPixelCNN(PixelCNNConfig(codebook_size=16, channels=8, layers=3, condition_channels=8))
    return tokenizer, prior


@pytest.mark.parametrize(("samples", "futures"), [(0, 0), (5, 0), (0, 3), (2, 2)])
def test_predicts_k_frames_from_the_last_four(tiny_model, samples, futures):
    tokenizer, prior = tiny_model
    model = LearnedWorldModel(tokenizer, prior, samples=samples, futures=futures)
    frames = generate_world(RoadConfig(), 0).frames
    prediction = model.predict(frames[:9], 3)
    assert prediction.frames.shape == (3, 48, 48) and prediction.frames.dtype == np.uint8
    assert prediction.goal.shape == (3, 2)
    twins = [LearnedWorldModel(tokenizer, prior, samples=samples, futures=futures, seed=4) for _ in range(2)]
    same = twins[0].predict(frames[5:9], 3)  # only the last four frames matter
    np.testing.assert_array_equal(same.frames, twins[1].predict(frames[:9], 3).frames)
    # A short observation is the first frame repeated before its start (dynplan.data.history), as in training.
    short = [LearnedWorldModel(tokenizer, prior, samples=samples, futures=futures, seed=4) for _ in range(2)]
    padded = np.concatenate([frames[:1], frames[:1], frames[:2]])
    np.testing.assert_array_equal(short[0].predict(frames[:2], 2).frames, short[1].predict(padded, 2).frames)
    with pytest.raises(ValueError, match="no frames observed"):
        model.predict(frames[:0], 1)


def test_sampled_futures_are_merged_conservatively(tiny_model):
    tokenizer, prior = tiny_model
    frames = generate_world(RoadConfig(), 0).frames[:9]
    greedy = LearnedWorldModel(tokenizer, prior).predict(frames, 2).frames
    merged = LearnedWorldModel(tokenizer, prior, futures=4).predict(frames, 2).frames
    obstacle = (greedy != 0) & (greedy != GOAL_VALUE)
    assert (merged[obstacle] != 0).all()  # every obstacle of the greedy future is still there
    assert LearnedWorldModel(tokenizer, prior).predict_codes(frames, 2).shape == (2, 6, 6)


@pytest.fixture(scope="module")
def tiny_local_model():
    torch.manual_seed(0)
    tokenizer = VQVAE(VQVAEConfig(channels=(8, 8), strides=(2, 2), latent_dim=4, codebook_size=16,
                                  likelihood="categorical", local=True))  # fmt: skip
    prior = ConditionalPixelCNN(PixelCNNConfig(codebook_size=16, channels=8, layers=3, condition_channels=8))
    return tokenizer, prior


def test_occupancy_is_the_priors_obstacle_probability_along_the_greedy_future(tiny_local_model):
    tokenizer, prior = tiny_local_model
    model = LearnedWorldModel(tokenizer, prior, caution=Caution(occupancy=0.5))
    frames = generate_world(RoadConfig(), 0).frames[:9]
    context, codes = model.encode_context(frames), model.predict_codes(frames, 2)
    _, fused = chain(prior, context[None], [2], model.chain_spec(occupancy=True))  # from the generation's logits
    probability = fused[0]
    # the slow way: each position's distribution given the greedy prefix, each code's patch decoded on its own
    patches = [tokenizer.decode(torch.tensor([[[q]]]))[0].numpy() for q in range(16)]
    expected = np.zeros((2, 48, 48))
    window = context
    for i in range(2):
        with torch.inference_mode():
            logits = prior.logits(codes[i][None], prior.condition(window[None]))[0]  # (K, h, w)
        for r in range(12):
            for c in range(12):
                p = torch.softmax(logits[:, r, c].double(), 0).numpy()
                for q in range(16):
                    expected[i, 4 * r : 4 * r + 4, 4 * c : 4 * c + 4] += p[q] * (
                        (patches[q] != 0) & (patches[q] != GOAL_VALUE)
                    )
        window = torch.cat([window[1:], codes[i][None]])
    np.testing.assert_allclose(probability, expected, atol=1e-5)
    threshold = float(probability.min() + probability.max()) / 2  # untrained weights: one that splits the pixels
    assert 0 < threshold < 1 and 0 < (probability >= threshold).mean() < 1
    plain = LearnedWorldModel(tokenizer, prior).predict(frames, 2).frames
    occupied = LearnedWorldModel(tokenizer, prior, caution=Caution(occupancy=threshold)).predict(frames, 2).frames
    obstacle = (plain != 0) & (plain != GOAL_VALUE)
    unsure = probability >= threshold
    occupied_obstacle = (occupied != 0) & (occupied != GOAL_VALUE)
    assert occupied_obstacle[obstacle].all() and occupied_obstacle[unsure].all()  # the greedy's and the unsure
    assert not (occupied_obstacle & ~obstacle & ~unsure).any()  # and nothing else


def test_sampled_futures_are_the_priors_chain_drawn_from_the_observations_streams(tiny_local_model):
    tokenizer, prior = tiny_local_model
    frames = generate_world(RoadConfig(), 0).frames[:9]
    probe = LearnedWorldModel(tokenizer, prior)
    context = probe.encode_context(frames)[None]
    streams = [(observation_stream(3, context[0].numpy().tobytes(), "futures", j), 1) for j in range(4)]
    grids, _ = chain(prior, context.expand(4, -1, -1, -1), [3] * 4, probe.chain_spec(streams))
    by_hand = merge_samples(probe.predict(frames, 3).frames, tokenizer.decode(grids.flatten(0, 1)).numpy()
                            .reshape(4, 3, 48, 48))  # fmt: skip
    model = LearnedWorldModel(tokenizer, prior, futures=4, seed=3)
    np.testing.assert_array_equal(model.predict(frames, 3).frames, by_hand)
    # Fewer futures are a prefix of more, alone or batched with models of other settings and horizons.
    two = LearnedWorldModel(tokenizer, prior, futures=2, seed=3)
    alone = two.predict(frames, 2).frames
    by_hand_two = merge_samples(probe.predict(frames, 2).frames, tokenizer.decode(grids[:2, :2].flatten(0, 1))
                                .numpy().reshape(2, 2, 48, 48))  # fmt: skip
    np.testing.assert_array_equal(alone, by_hand_two)
    other = LearnedWorldModel(tokenizer, prior, samples=2, seed=3, caution=Caution(margin=1))
    together = LearnedWorldModel.predict_batch([two, model, other], [frames] * 3, [2, 3, 3])
    np.testing.assert_array_equal(together[0].frames, alone)
    np.testing.assert_array_equal(together[1].frames, by_hand)
    np.testing.assert_array_equal(together[2].frames, other.predict(frames, 3).frames)


def test_occupancy_names_its_range_and_needs_patch_local_codes(tiny_model):
    with pytest.raises(ValueError, match=r"occupancy=.* is invalid .*valid range \[0.0, 1.0\)"):
        Caution(occupancy=1.0)
    with pytest.raises(ValueError, match="occupancy=0.1 needs a tokenizer with patch-local codes"):
        LearnedWorldModel(*tiny_model, caution=Caution(occupancy=0.1))


@given(st.integers(0, 4), st.lists(st.tuples(st.integers(0, 11), st.integers(0, 11), st.integers(1, 243)), max_size=6))
def test_widening_draws_each_obstacle_on_its_row_neighbours_only(margin, obstacles):
    frames = np.zeros((2, 12, 12), np.uint8)
    frames[1, 4:6, 4:6] = GOAL_VALUE
    for y, x, value in obstacles:
        frames[1, y, x] = value if value != GOAL_VALUE else 1
    widened = widen_obstacles(frames, margin)
    assert not widened[0].any()  # frames are widened each on its own
    expected = frames[1].astype(int).copy()
    expected[expected == GOAL_VALUE] = 0
    for y, x, _ in obstacles:  # by hand: the largest obstacle value within `margin` columns in the same row
        for c in range(max(x - margin, 0), min(x + margin + 1, 12)):
            expected[y, c] = max(expected[y, c], frames[1, y, x])
    goal_kept = (frames[1] == GOAL_VALUE) & (expected == 0)
    np.testing.assert_array_equal(widened[1], np.where(goal_kept, GOAL_VALUE, expected))
    np.testing.assert_array_equal(widen_obstacles(frames, 0), frames)


def test_margin_widens_the_planners_frames_and_names_its_range(tiny_model):
    tokenizer, prior = tiny_model
    frames = generate_world(RoadConfig(), 0).frames[:9]
    plain = LearnedWorldModel(tokenizer, prior, samples=2, seed=3).predict(frames, 2).frames
    model = LearnedWorldModel(tokenizer, prior, samples=2, seed=3, caution=Caution(margin=1))
    np.testing.assert_array_equal(model.predict(frames, 2).frames, widen_obstacles(plain, 1))
    assert model.name == "model(samples=2, futures=0, margin=1)"
    with pytest.raises(ValueError, match=r"margin=.* is invalid .*valid range \[0, 4\]"):
        Caution(margin=5)


def test_each_configuration_has_its_caution_and_overrides_are_checked():
    assert WORLD_MODELS["paper"].caution == Caution()  # the paper's method: the argmax alone
    assert caution_for("default", {"margin": 2}).occupancy == WORLD_MODELS["default"].caution.occupancy
    assert caution_for("default", {"margin": 2}).recorded()["margin"] == 2
    assert Caution().recorded() == {}  # a result played without caution records nothing (no caution fields: none used)
    with pytest.raises(ValueError, match=r"margin=7 is invalid .* valid range \[0, 4\]"):
        caution_for("default", {"margin": 7})


def test_plans_an_episode_through_the_seam(tiny_model):
    tokenizer, prior = tiny_model
    world = generate_world(RoadConfig(), 3)
    planner = MCTSPlanner(MCTSConfig(rollout_steps=2, playouts=10), 1.0, 203)
    result = run_episode(world, planner, LearnedWorldModel(tokenizer, prior, samples=2), 1.0, 2)
    assert result.outcome in {"goal", "death", "timeout"} and result.steps == len(result.decision_ms)


def test_mismatched_parts_and_missing_checkpoints(tiny_model, tmp_path):
    tokenizer, _ = tiny_model
    with pytest.raises(ValueError, match="the prior predicts 32 codes; the tokenizer has 16"):
        LearnedWorldModel(tokenizer, ConditionalPixelCNN(PixelCNNConfig(codebook_size=32, channels=8, layers=2)))
    with pytest.raises(CheckpointError, match="no world model checkpoints"):
        load_world_model(tmp_path)
    import dynplan.models

    assert dynplan.models.load_world_model is load_world_model  # the package's API (loaded on first use)


def test_prediction_error_curves_and_figure(tiny_model, tmp_path):
    from dynplan.evaluation.prediction import errors_by_horizon, figure1, plot_errors
    from dynplan.planning.forward import ForwardModel, OracleModel

    class Oracle(ForwardModel):
        """The truth as a 'model' of the evaluation episodes: every error must be zero."""

        def predict(self, observed, k):
            world = generate_world(RoadConfig(), self.seed)
            return OracleModel(world).predict(observed, k)

    oracle = Oracle()
    oracle.seed = 1_000_000
    perfect = errors_by_horizon(oracle, episodes=1, points=3, horizon=4)
    assert perfect["fn_rate"] == [0.0] * 4 and perfect["fp_rate"] == [0.0] * 4 and perfect["goal_error_px"] == [0.0] * 4
    tokenizer, prior = tiny_model
    learned = errors_by_horizon(LearnedWorldModel(tokenizer, prior), episodes=1, points=2, horizon=3)
    assert len(learned["fn_rate"]) == 3 and learned["decision_points"] == 2
    plot_errors({"oracle": perfect, "tiny": learned}, tmp_path / "errors.png")
    figure1(LearnedWorldModel(tokenizer, prior, samples=2), tmp_path / "figure1.png", steps=(1, 2))
    assert (tmp_path / "errors.png").stat().st_size > 1000 and (tmp_path / "figure1.png").stat().st_size > 1000


def test_observed_frames_are_encoded_once_and_as_alone(tiny_model, monkeypatch):
    tokenizer, prior = tiny_model
    frames = generate_world(RoadConfig(), 3).frames
    from dynplan.models.encoding import _ENCODED

    _ENCODED.pop(tokenizer, None)  # what earlier tests encoded with this tokenizer
    model = LearnedWorldModel(tokenizer, prior)
    encoded = []
    encode = tokenizer.encode
    monkeypatch.setattr(tokenizer, "encode", lambda x: encoded.append(len(x)) or encode(x))
    first = model.encode_context(frames[:4])
    second = model.encode_context(frames[:5])  # the next decision's context: one new frame
    assert encoded == [4, 1]
    with torch.inference_mode():
        direct = encode(torch.from_numpy(np.ascontiguousarray(frames[1:5])))
    assert torch.equal(second, direct) and torch.equal(first[1:], second[:3])
    LearnedWorldModel(tokenizer, prior, samples=2).encode_context(frames[2:6])  # another model on the same tokenizer
    assert encoded == [4, 1, 1]


VALUES = "(0, 45, 85, 100, 130, 144, 244)"


def _refusal(call, *args) -> str:
    with pytest.raises(ValueError) as error:
        call(*args)
    return str(error.value)


def test_predict_refuses_frames_that_are_not_the_worlds_naming_what_it_takes(tiny_model):
    model = LearnedWorldModel(*tiny_model)
    frames = generate_world(RoadConfig(), 0).frames[:9]
    expect = f"(t+1, 48, 48) frames of world pixel values {VALUES}"
    bad = {
        f"predict: observed must be {expect}; got shape (9, 32, 32)": frames[:, :32, :32],
        f"predict: observed must be {expect}; got shape (48, 48) (one frame is observed[None])": frames[8],
        f"predict: observed must hold integer pixel values {VALUES}; got float32": frames.astype(np.float32),
        f"predict: observed must be a numpy array of {expect}; got list": list(frames),
        f"predict: no frames observed: observed must hold at least one of {expect}": frames[:0],
    }
    for message, observed in bad.items():
        assert _refusal(model.predict, observed, 2) == message
    odd = frames.copy()
    odd[8, 10, 20] = 3
    assert _refusal(model.predict, odd, 2) == (f"predict: observed frame 8 holds 3 at row 10, column 20, which is not "
                                               f"a world pixel value {VALUES}")  # fmt: skip
    negative = frames.astype(np.int64)
    negative[6, 0, 0] = -244
    assert "observed frame 6 holds -244 at row 0, column 0" in _refusal(model.predict, negative, 2)
    odd[0, 10, 20] = 3  # a frame the model does not read (before its last four)
    odd[8, 10, 20] = frames[8, 10, 20]
    np.testing.assert_array_equal(model.predict(odd, 2).frames, model.predict(frames, 2).frames)
    wide = frames.astype(np.int64)  # the world's values in any integer type: the same prediction
    np.testing.assert_array_equal(model.predict(wide, 2).frames, model.predict(frames, 2).frames)


def test_predict_refuses_a_horizon_that_is_not_an_integer_in_range(tiny_model):
    from dynplan.models.world_model import MAX_HORIZON

    model = LearnedWorldModel(*tiny_model)
    frames = generate_world(RoadConfig(), 0).frames[:9]
    for k in (0, -1, 2.5, 10**6, True, "3", None, MAX_HORIZON + 1):
        assert (
            _refusal(model.predict, frames, k) == f"predict: k must be an integer in [1, 512] (frames ahead); got {k!r}"
        )
    assert _refusal(model.predict_codes, frames, 0).startswith("predict_codes: k must be an integer in [1, 512]")
    assert len(model.predict(frames, np.int64(3)).frames) == 3  # numpy integers are integers
    assert len(model.predict(frames[:1], MAX_HORIZON).frames) == MAX_HORIZON


def test_predict_batch_names_the_episode_whose_argument_is_bad(tiny_model):
    model = LearnedWorldModel(*tiny_model)
    frames = generate_world(RoadConfig(), 0).frames[:9]
    batch = LearnedWorldModel.predict_batch
    assert _refusal(batch, [model, model], [frames, frames], [2, 0]) == ("predict_batch: ks[1] must be an integer in "
                                                                         "[1, 512] (frames ahead); got 0")  # fmt: skip
    assert _refusal(batch, [model, model], [frames[:, :32, :32], frames], [2, 2]) == (
        f"predict_batch: observed[0] must be (t+1, 48, 48) frames of world pixel values {VALUES}; got shape (9, 32, 32)"
    )
    with pytest.raises(ValueError, match="predict_batch: 2 models, 1 observations, 2 horizons"):
        LearnedWorldModel.predict_batch([model, model], [frames], [2, 2])
    assert LearnedWorldModel.predict_batch([], [], []) == []


def test_load_world_model_names_the_registered_configurations_and_suggests_only_what_works(tmp_path):
    known = re.escape(str(sorted(world_model_names())))  # every installed world's configurations
    with pytest.raises(ValueError, match=rf"^model must be one of {known}, got 'nosuch'$") as error:
        load_world_model(model="nosuch")
    assert "flows.train" not in str(error.value)
    for settings, message in [({"samples": 2.5}, "samples=2.5 is invalid (a float, not an integer)"),
                              ({"futures": -1}, "futures=-1 is invalid (valid range [0, 64])"),
                              ({"samples": 10**6}, "samples=1000000 is invalid (valid range [0, 64])")]:  # fmt: skip
        refused = _refusal(functools.partial(load_world_model, model="paper", **settings))
        assert refused == f"load_world_model: {message}"
    from dynplan.models.world_model import world_model_parts

    with pytest.raises(CheckpointError, match="configuration 'nosuch' is not registered$") as error:
        world_model_parts((tmp_path / "vqvae.pt", tmp_path / "pixelcnn.pt"), "nosuch")
    assert "flows.train" not in str(error.value)
