"""A short demonstration episode: a one-step-lookahead agent on the road world, saved as a GIF.

Until the planner exists this is what the README's main command shows. The agent peeks one frame into the
true future (the oracle frames), drops the actions that would kill it there, and of the rest takes the one
that lands closest to the goal — greedy, with no search, so it still loses some episodes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from dynplan.env.agent import Outcome, judge
from dynplan.env.road_env import RoadEnv
from dynplan.render import write_gif


@dataclass(frozen=True)
class DemoResult:
    """What happened in the demo episode and where its GIF is."""

    seed: int
    outcome: str
    steps: int
    total_reward: float
    gif: str

    def to_dict(self) -> dict:
        return asdict(self)


def greedy_lookahead_action(env: RoadEnv, rng: np.random.Generator) -> int:
    """The action landing nearest the goal among those that survive the next true frame (random if none)."""
    landing = env.position + env._deltas  # (8, 2)
    outcome = judge(env.world_frames[env.t + 1], landing)
    goal_centre = env.world.goal[env.t + 1] + 0.5
    distance = np.linalg.norm(landing - goal_centre, axis=1)
    distance[outcome == Outcome.GOAL] = -1.0
    distance[outcome == Outcome.DEATH] = np.inf
    if np.isinf(distance).all():
        return int(rng.integers(len(distance)))
    return int(np.argmin(distance))


def run_demo(out_dir: str | Path, seed: int = 0, agent_speed: float = 1.0, level: int = 6) -> DemoResult:
    """Play one episode with the greedy lookahead agent and write `demo_seed{seed}.gif` into `out_dir`."""
    env = gym.make("dynplan/Road-v0", agent_speed=agent_speed, level=level, render_mode="rgb_array")
    road: RoadEnv = env.unwrapped
    _, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    images = [env.render()]
    total, steps, done = 0.0, 0, False
    while not done:
        _, reward, terminated, truncated, info = env.step(greedy_lookahead_action(road, rng))
        images.append(env.render())
        total += reward
        steps += 1
        done = terminated or truncated
    gif = write_gif(Path(out_dir) / f"demo_seed{seed}.gif", np.stack(images), fps=10)
    env.close()
    return DemoResult(seed, info["outcome"], steps, total, str(gif))
