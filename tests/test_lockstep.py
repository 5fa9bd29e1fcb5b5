"""Lockstep episodes: playing many recorded episodes together gives each the result it gets alone, with one
batched world-model call per step; finished episodes leave the batch without disturbing the others."""

import numpy as np
import pytest

from dynplan.env.config import GOAL_VALUE, RoadConfig
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
def test_a_finished_episode_leaves_the_batch_without_disturbing_the_others(monkeypatch):
    k = 3
    planners, forwards = zip(*agents("samples5", "paper", k), strict=True)
    batches: list[int] = []
    original = LearnedWorldModel.predict_batch

    def counting(cls, models, observed, ks):
        batches.append(len(models))
        return original(models, observed, ks)

    monkeypatch.setattr(LearnedWorldModel, "predict_batch", classmethod(counting))
    together = run_episodes(worlds(), planners, forwards, 1.0, k)
    monkeypatch.undo()
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
    with pytest.raises(ValueError, match="differ in weights"):
        LearnedWorldModel.predict_batch([load_world_model(model="default"), load_world_model(model="paper")],
                                        [frames[0][:5]] * 2, [1, 1])  # fmt: skip


def test_models_of_any_settings_on_one_prior_predict_together_each_observation_once(monkeypatch):
    """Mid, samples, futures and caution on the same weights share one batch: each distinct observation's greedy
    chain is generated once, as long as its longest horizon, and each model still gets what it gets alone."""
    from dynplan.models import chain

    frames = [w.frames for w in worlds()]
    off = {"occupancy": 0.0, "margin": 0}
    settings = [
        dict(caution=off),
        dict(samples=5),
        dict(samples=10, caution=off),
        dict(futures=5),
        dict(samples=5, futures=2, caution=off),
        dict(samples=5, caution={"occupancy": 0.3, "margin": 0}),
    ]
    cases = [(s, w, 8 + 3 * w, k) for s in settings for w, k in ((0, 1), (0, 3), (1, 2))]  # 2 observations
    build = [lambda s=s, w=w: load_world_model(model="default", seed=w, **s) for s, w, *_ in cases]  # a world's seed
    alone = [make().predict(frames[w][: t + 1], k) for make, (_, w, t, k) in zip(build, cases, strict=True)]
    rows: list[int] = []
    for name in ("generate_fast", "generate_batched"):
        original = getattr(chain, name)
        monkeypatch.setattr(chain, name, lambda m, c, *a, original=original, **kw: rows.append(len(c))
                            or original(m, c, *a, **kw))  # fmt: skip
    together = LearnedWorldModel.predict_batch([make() for make in build], [frames[w][: t + 1] for _, w, t, _ in cases],
                                               [k for *_, k in cases])  # fmt: skip
    for a, b in zip(alone, together, strict=True):
        np.testing.assert_array_equal(a.frames, b.frames)
    # One greedy chain per observation, 3 and 2 grids long, then its 5 futures as long (2 futures are their first 2)
    assert rows == [2, 2, 1, 2 * 5, 2 * 5, 5], rows


def test_draws_are_a_function_of_the_seed_and_the_observation():
    """Decoder samples and futures draw from the observation's own stream: two models of one seed agree, fewer
    frames are a longer horizon's first, and fewer samples a subset of more (their obstacles too), so the cases
    that see the same frame can share them."""
    observed = worlds()[0].frames[:12]

    def model(seed: int = 1, **settings):
        return load_world_model(model="paper", seed=seed, **settings)

    for settings in ({"futures": 5}, {"samples": 5}):
        long = model(**settings).predict(observed, 3).frames
        np.testing.assert_array_equal(model(**settings).predict(observed, 3).frames, long)
        np.testing.assert_array_equal(model(**settings).predict(observed, 1).frames, long[:1])
        assert not np.array_equal(model(seed=2, **settings).predict(observed, 3).frames, long)

    def obstacles(frames):
        return (frames != 0) & (frames != GOAL_VALUE)

    five, ten = (obstacles(model(samples=n).predict(observed, 3).frames) for n in (5, 10))
    assert (ten[five]).all() and ten.sum() > five.sum()


@pytest.mark.slow
def test_cases_of_every_technique_speed_and_k_in_one_batch_equal_each_alone():
    """An evaluation's batch holds every case of its worlds: episodes at both speeds and several k, on the same
    recorded worlds, share each frame's prediction and still play as they would alone."""
    specs = [("mid", 1.0, 1), ("samples5", 1.0, 3), ("futures5", 1.0, 1), ("samples5", 0.5, 3), ("oracle", 1.0, 3)]
    cases = [Case(name, speed, k, seed, None if name == "oracle" else "paper")
             for name, speed, k in specs for seed in SEEDS[:2]]  # fmt: skip
    recorded = {w.seed: w for w in worlds(0.5)}  # long enough for either speed, as the evaluation records them
    alone = [run_episode(recorded[c.seed], *case_agent(c, recorded[c.seed]), c.agent_speed, c.rollout_steps)
             for c in cases]  # fmt: skip
    planners, forwards = zip(*(case_agent(c, recorded[c.seed]) for c in cases), strict=True)
    together = run_episodes([recorded[c.seed] for c in cases], planners, forwards, [c.agent_speed for c in cases],
                            [c.rollout_steps for c in cases])  # fmt: skip
    for a, b in zip(alone, together, strict=True):
        same(a, b)
    with pytest.raises(ValueError, match="2 agent speeds"):
        run_episodes(worlds()[:1], planners[:1], forwards[:1], [1.0, 0.5], 1)
