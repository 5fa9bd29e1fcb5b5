"""`dynplan/Road-v0`: the road world as a Gymnasium environment."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from dynplan.env.agent import (
    FIRST_DECISION_FRAME,
    N_ACTIONS,
    Outcome,
    action_deltas,
    judge,
    reward_of,
)
from dynplan.env.colors import colorize
from dynplan.env.config import RoadConfig
from dynplan.env.road import World, generate_world, round_px


class RoadEnv(gym.Env[dict, np.int64]):
    """
    ## Description
    A navigation task from Hansen et al. (2018), *Planning in Dynamic Environments with Conditional
    Autoregressive Models*: a 1 × 1 agent must reach a moving 2 × 2 goal that reflects off the walls of an
    H × W world (48 × 48 by default), crossing horizontal lanes of traffic without touching an obstacle. The
    world does not depend on the agent, so each episode's frames are generated in full at `reset` and exposed
    as `env.unwrapped.world_frames` — the "oracle" future a planner may be given.

    ## Action Space
    `Discrete(8)`: move `agent_speed` pixels along heading −180°, −135°, −90°, −45°, 0°, 45°, 90°, 135°
    (index 0 … 7; 0° is +x, 90° is +y, i.e. up, since row 0 is the bottom).

    ## Observation Space
    `Dict(frame=Box(0, 255, (H, W), uint8), agent=Box(float32, (2,)))`: the current world frame (free 0,
    obstacles 45 / 85 / 100 / 130 / 144 by class, goal 244; the agent is not drawn) and the agent's continuous
    position (y, x). Collision and goal checks use the position rounded to the nearest pixel (halves up).

    ## Rewards
    +20 on reaching a goal pixel, −20 on leaving the grid or landing on an obstacle pixel, 0 otherwise.

    ## Starting State
    The world is warmed up for W steps, so traffic is already flowing at frame 0. The agent starts on row 0 or
    row H−2 (chance ½ each) in a column drawn from [6, W−6), and makes its first decision at frame 4, having seen
    frames 0–4. The goal starts uniformly inside the world with heading 1° + 45°·k and speed 0.5.

    ## Episode End
    Each step the agent moves, then the world advances one frame, which judges the agent's new position.
    Terminated on goal (+20) or death (−20); truncated when the frame index reaches T − 1, where
    T = int(3·√(H² + W²) / agent_speed) (203 frames at speed 1.0, 407 at 0.5).

    ## Arguments
    `gymnasium.make("dynplan/Road-v0", agent_speed=1.0, level=6, height=48, width=48, goal_speed=0.5,
    render_mode="rgb_array")`, or `config=RoadConfig(...)`. Every value is validated (see `RoadConfig`).
    `reset(seed=s)` makes the episode — world and start — a pure function of `s`, identical to
    `dynplan.env.generate_world(config, s)`; `reset(options={"world": world})` plays a given (e.g. recorded)
    `World` instead, whose frames must cover at least T frames.

    ## Info
    `t` (frame index), `goal` (pixel (row, col) of the goal block's lower-left corner), `world_seed`, and
    `outcome` ("running", "goal", "death" or "timeout").

    ## Version History
    * v0: first release, after docs/protocol.md §1 (goal reflects off the walls, angular prior wraps;
      see docs/protocol.md §5).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, config: RoadConfig | dict | None = None, render_mode: str | None = None, **overrides: Any):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        if isinstance(config, RoadConfig):
            config = config.model_dump()
        self.config = RoadConfig.from_dict(config, **overrides)
        self.render_mode = render_mode
        H, W, s = self.config.height, self.config.width, self.config.agent_speed
        self.action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = spaces.Dict(
            frame=spaces.Box(0, 255, (H, W), np.uint8),
            # An agent that leaves the grid is one step beyond its last on-grid (rounded) position.
            agent=spaces.Box(np.float32(-1 - s), np.array([H + s, W + s], np.float32), (2,), np.float32),
        )
        self._deltas = action_deltas(s)
        self.world: World | None = None
        self.t = 0
        self.position = np.zeros(2)
        self.outcome = Outcome.RUNNING

    @property
    def world_frames(self) -> np.ndarray:
        """(T, H, W) uint8 frames of the whole current episode (available after `reset`)."""
        if self.world is None:
            raise RuntimeError("world_frames is available after reset()")
        return self.world.frames

    @property
    def max_steps(self) -> int:
        return self.config.max_steps

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        options = options or {}
        unknown = set(options) - {"world"}
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}; valid: ['world']")
        if "world" in options:
            world = options["world"]
            if len(world.frames) < self.max_steps or world.frames.shape[1:] != (self.config.height, self.config.width):
                raise ValueError(
                    f"options['world'] has frames {world.frames.shape}; this env needs at least "
                    f"({self.max_steps}, {self.config.height}, {self.config.width})"
                )
            self.world = world
        else:
            world_seed = seed if seed is not None else int(self.np_random.integers(2**63))
            self.world = generate_world(self.config, world_seed, self.max_steps)
        self.t = FIRST_DECISION_FRAME
        self.position = self.world.agent_start.astype(np.float64).copy()
        self.outcome = Outcome.RUNNING
        return self._obs(), self._info()

    def step(self, action: int) -> tuple[dict, float, bool, bool, dict]:
        if self.world is None:
            raise RuntimeError("call reset() before step()")
        if self.outcome != Outcome.RUNNING:
            raise RuntimeError(f"the episode has ended ({self.outcome.name.lower()}); call reset()")
        if not self.action_space.contains(action):
            raise ValueError(f"action must be an integer in [0, {N_ACTIONS - 1}], got {action!r}")
        self.position = self.position + self._deltas[int(action)]
        self.t += 1
        outcome = Outcome(judge(self.world.frames[self.t], self.position))
        if outcome == Outcome.RUNNING and self.t >= self.max_steps - 1:
            outcome = Outcome.TIMEOUT
        self.outcome = outcome
        terminated = outcome in (Outcome.GOAL, Outcome.DEATH)
        truncated = outcome == Outcome.TIMEOUT
        return self._obs(), reward_of(outcome), terminated, truncated, self._info()

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to make().")
            return None
        return colorize(self.world.frames[self.t], self.position)

    def _obs(self) -> dict:
        return {"frame": self.world.frames[self.t].copy(), "agent": self.position.astype(np.float32)}

    def _info(self) -> dict:
        return {
            "t": self.t,
            "goal": round_px(self.world.goal[self.t]),
            "world_seed": self.world.seed,
            "outcome": self.outcome.name.lower(),
        }
