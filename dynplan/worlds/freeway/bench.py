"""`freeway`: milliseconds per Freeway decision on one core: the chicken's exact search at k = 8 and k = 16, and a
learned decision (the world model's prediction and the search) at k = 8.

Decisions at every 4th step of one game (mode 0, NOOP start 0) with the true future, the chicken as the game has it
there (played by the search itself); against the 100 ms target of a learned decision and the naive search in the
same run: the same rule over every action sequence, without merging those that coincide. The learned agent (the
committed Freeway world model) plays the game's first `LEARNED_STEPS` steps twice in the same process: as it plays
(a decision whose newest frame the last one predicted continues that chain) and with the kept chains dropped before
every decision (each generates all k grids), the baseline; then `LOCKSTEP` episodes play together (`Lockstep`: one
batched prediction a step), timed by the wall clock per decision.
"""

from __future__ import annotations

import itertools
import time

import numpy as np
import torch

from dynplan.bench.timing import pin_to_one_core
from dynplan.models.chain import forget_greedy
from dynplan.planning.forward import ForwardModel
from dynplan.worlds.freeway.evaluation import Lockstep, play_turns, world_model_for
from dynplan.worlds.freeway.game import Chicken, FreewayEpisode, FreewayGame, chicken_frames, record_mode, step_frames
from dynplan.worlds.freeway.search import STUN_PENALTY, ChickenSearch, plan_chicken

TARGET_MS = 100.0
#: Decisions the naive search is timed on (3^k sequences: k = 8 only).
NAIVE_DECISIONS = 20
#: Steps of the game the learned agent plays in each of its two cases.
LEARNED_STEPS = 400
#: Episodes the lockstep case plays together, for how many steps, and its target (ms a decision, amortised).
LOCKSTEP, LOCKSTEP_STEPS, LOCKSTEP_MS = 10, 200, 20.0


def naive_action(chicken: Chicken, frames: np.ndarray, k: int) -> int:
    """The first action of the plan crossing most, then ending highest, over all 3^k sequences (no merging)."""
    drawn = [step_frames(frames[d], frames[d + 1]) for d in range(k)]

    def best(state: Chicken, depth: int) -> tuple[float, int]:
        if depth == k:
            return 0.0, state.y - (STUN_PENALTY if state.knocked else 0)
        values = []
        for action in (1, 0, 2):
            after, gained = chicken_frames(state, action, drawn[depth])
            reward, height = best(after, depth + 1)
            values.append((reward + gained, height))
        return max(values)

    values = [best(chicken_frames(chicken, a, drawn[0])[0], 1) for a in (1, 0, 2)]
    return (1, 0, 2)[int(np.argmax([v[0] * 1000 + v[1] for v in values]))]


def bench_freeway() -> dict[str, dict[str, float]]:
    """Time the search along one game at k = 8 and 16, and the naive search on the first decisions at k = 8."""
    pin_to_one_core()
    future = record_mode(0).frames
    results = {}
    for k in (8, 16):
        game, times, states = FreewayGame(FreewayEpisode()), [], []
        for t in range(len(future) - 1):
            frames = future[t : t + k + 1]
            decision = plan_chicken(game.chicken, frames, ChickenSearch(horizon=k))
            if t % 4 == 0:
                times.append(decision.search_ms)
                states.append(decision.states)
            if game.step(decision.action).done:
                break
        results[f"search_k{k}"] = {
            "median_ms": round(float(np.median(times)), 3),
            "decisions": len(times),
            "median_states": int(np.median(states)),
            "target_ms": TARGET_MS,
        }
    results.update(_learned())
    naive = []
    for t in range(0, 4 * NAIVE_DECISIONS, 4):
        start = time.perf_counter()
        naive_action(Chicken(6), future[t : t + 9], 8)
        naive.append((time.perf_counter() - start) * 1e3)
    median = float(np.median(naive))
    speedup = round(median / results["search_k8"]["median_ms"], 1)
    results["naive_k8"] = {"median_ms": round(median, 3), "decisions": len(naive), "search_speedup": speedup}
    return results


def _learned(k: int = 8) -> dict[str, dict[str, float]]:
    """The learned agent's decisions (prediction and search) over the game's first steps: as it plays, with every
    kept chain dropped before each decision, and `LOCKSTEP` episodes played together (wall time per decision)."""
    torch.set_num_threads(1)  # one core: the prior's kernel runs its grids on torch's threads
    model, search, out = world_model_for("learned"), ChickenSearch(horizon=k), {}
    for case, keep in (("learned_k8", True), ("learned_k8_fresh", False)):
        times, score = [], 0.0
        forget_greedy()
        for turn in itertools.islice(play_turns("learned", FreewayEpisode(), search, model=model), LEARNED_STEPS):
            times.append(turn.decision_ms)
            score += turn.step.reward
            if not keep:
                forget_greedy()
        out[case] = {
            "median_ms": round(float(np.median(times)), 3),
            "mean_ms": round(float(np.mean(times)), 3),
            "decisions": len(times),
            "score": score,
            "target_ms": TARGET_MS,
        }
    out["learned_k8"]["ratio_fresh"] = round(out["learned_k8_fresh"]["median_ms"] / out["learned_k8"]["median_ms"], 2)
    out["learned_k8_lockstep"] = _lockstep(model, search)
    out["learned_k8_lockstep"]["ratio_single"] = round(
        out["learned_k8"]["mean_ms"] / out["learned_k8_lockstep"]["amortised_ms"], 2
    )
    return out


def _lockstep(model: ForwardModel, search: ChickenSearch) -> dict[str, float]:
    """`LOCKSTEP` episodes (NOOP starts 0, 1, …) played together for `LOCKSTEP_STEPS` steps: the wall time per
    decision (against the single episode's mean, `learned_k8`, in the same process)."""
    forget_greedy()
    episodes = [FreewayEpisode(noop_start=n) for n in range(LOCKSTEP)]
    lockstep, decisions = Lockstep("learned", episodes, search, list(range(LOCKSTEP)), model), 0
    start = time.perf_counter()
    for _ in range(LOCKSTEP_STEPS):
        decisions += len(lockstep.advance())
    amortised = (time.perf_counter() - start) * 1e3 / decisions
    return {"amortised_ms": round(amortised, 3), "episodes": LOCKSTEP, "decisions": decisions, "target_ms": LOCKSTEP_MS}
