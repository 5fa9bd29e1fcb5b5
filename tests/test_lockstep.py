"""Lockstep episodes: playing many recorded episodes together gives each the result it gets alone, with one
batched world-model call per step; finished episodes leave the batch without disturbing the others."""

import numpy as np
import pytest

from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.evaluation.cases import EVAL_SEED_START, Case
from dynplan.evaluation.protocol import case_agent
from dynplan.models.world_model import LearnedWorldModel, load_world_model
from dynplan.planning.episode import run_episode, run_episodes

SEEDS = [EVAL_SEED_START + i for i in range(4)]


def worlds(speed: float = 1.0):
    return [generate_world(RoadConfig(agent_speed=speed), seed) for seed in SEEDS]


def agents(technique: str, model: str | None, k: int | None, speed: float = 1.0):
    return [case_agent(Case(technique, speed, k, world.seed, model), world) for world in worlds(speed)]


def same(a, b) -> None:
    assert (a.outcome, a.steps, a.reward) == (b.outcome, b.steps, b.reward)
    np.testing.assert_array_equal(a.track.action, b.track.action)
    np.testing.assert_array_equal(a.track.position, b.track.position)


SLOW = pytest.mark.slow


@pytest.mark.parametrize(("technique", "model", "k"), [
    ("oracle", None, 3), ("zero", None, 3), ("random", None, None), pytest.param("mid", "paper", 3, marks=SLOW),
    pytest.param("samples5", "paper", 3, marks=SLOW), pytest.param("futures5", "paper", 1, marks=SLOW)])  # fmt: skip
def test_lockstep_equals_each_episode_alone(technique, model, k):
    alone = [run_episode(world, planner, forward, 1.0, k or 1)
             for world, (planner, forward) in zip(worlds(), agents(technique, model, k), strict=True)]  # fmt: skip
    planners, forwards = zip(*agents(technique, model, k), strict=True)
    finished = []
    together = run_episodes(worlds(), planners, forwards, 1.0, k or 1, on_finish=lambda i, r: finished.append(i))
    for a, b in zip(alone, together, strict=True):
        same(a, b)
    assert sorted(finished) == list(range(len(SEEDS)))  # each reported once, as it finished
    assert [together[i].steps for i in finished] == sorted(r.steps for r in together)


@pytest.mark.slow
def test_a_finished_episode_leaves_the_batch_without_disturbing_the_others():
    k = 3
    planners, forwards = zip(*agents("samples5", "paper", k), strict=True)
    batches: list[int] = []
    original = LearnedWorldModel.predict_batch

    def counting(models, observed, ks):
        batches.append(len(models))
        return original(models, observed, ks)

    LearnedWorldModel.predict_batch = staticmethod(counting)
    try:
        together = run_episodes(worlds(), planners, forwards, 1.0, k)
    finally:
        LearnedWorldModel.predict_batch = staticmethod(original)
    steps = sorted(r.steps for r in together)
    assert len(set(steps)) > 1, "the episodes should end at different steps"
    assert batches[0] == len(SEEDS) and batches[-1] == 1 and batches == sorted(batches, reverse=True)
    assert len(batches) == steps[-1]  # one world-model call per step while any episode lives
    for world, (planner, forward), result in zip(worlds(), agents("samples5", "paper", k), together, strict=True):
        same(run_episode(world, planner, forward, 1.0, k), result)


def test_a_batch_of_predictions_equals_each_alone():
    frames = [w.frames for w in worlds()]
    for model, samples, futures in (("default", 5, 0), ("paper", 0, 3)):
        alone = [load_world_model(model=model, samples=samples, futures=futures, seed=i) for i in range(4)]
        batched = [load_world_model(model=model, samples=samples, futures=futures, seed=i) for i in range(4)]
        ts, ks = [4, 40, 90, 200], [3, 3, 2, 1]
        expected = [m.predict(f[: t + 1], k) for m, f, t, k in zip(alone, frames, ts, ks, strict=True)]
        got = LearnedWorldModel.predict_batch(batched, [f[: t + 1] for f, t in zip(frames, ts, strict=True)], ks)
        for a, b in zip(expected, got, strict=True):
            np.testing.assert_array_equal(a.frames, b.frames)
            np.testing.assert_array_equal(a.goal, b.goal)
    with pytest.raises(ValueError, match="differ in weights or settings"):
        LearnedWorldModel.predict_batch([alone[0], load_world_model(model="paper")], [frames[0][:5]] * 2, [1, 1])
