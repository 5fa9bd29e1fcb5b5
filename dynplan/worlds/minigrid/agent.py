"""MiniGrid's agent: a cell and a heading, three actions, and the rule that judges a step against the frames.

The agent turns left, turns right or moves forward one cell, as MiniGrid's does; the world's frames move on one
frame a step whatever it does. Judged as the paper judges its agent (not as MiniGrid's own game, where only moving
forward into a ball or wall ends the episode, before the balls move): after a step the agent dies if it stands on a
ball, if it swapped cells with one (it moved onto a ball's cell as a ball moved onto its own), or if it moved
forward into a wall; it wins on reaching the goal's cell. `step` judges one agent; `roll` judges many action
sequences against many futures at once; `roll_chances` does the same against each future's chance of a ball in
every cell, as the search does.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

import numpy as np

from dynplan.worlds.minigrid.grid import PIXEL_VALUES

WALL, BALL, GOAL = PIXEL_VALUES["wall"], PIXEL_VALUES["ball"], PIXEL_VALUES["goal"]
#: (row, column) step of each heading, MiniGrid's order: right, down, left, up (row 0 is the bottom).
HEADINGS = np.array([[0, 1], [-1, 0], [0, -1], [1, 0]])
LEFT, RIGHT, FORWARD = 0, 1, 2


class Outcome(IntEnum):
    RUNNING = 0
    GOAL = 1
    DEATH = 2
    TIMEOUT = 3


class Pose(NamedTuple):
    """Where the agent is (row, column) and which way it faces (an index of `HEADINGS`; MiniGrid starts it at 0,
    facing right)."""

    row: int
    col: int
    heading: int


#: Where the agent starts: MiniGrid's (1, 1), the top-left cell inside the walls of a 16 × 16 room, facing right.
AGENT_START_POSE = Pose(14, 1, 0)


def step(pose: Pose, action: int, before: np.ndarray, after: np.ndarray) -> tuple[Pose, Outcome]:
    """One step from frame `before` to frame `after` (H, W): the agent's new pose and how the step went."""
    poses, outcomes = roll(np.array([pose]), np.array([[action]]), np.stack([before, after])[None])
    row, col, heading = (int(v) for v in poses[0, 0])
    return Pose(row, col, heading), Outcome(int(outcomes[0, 0]))


def roll(poses: np.ndarray, actions: np.ndarray, futures: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every action sequence from every start against every future: `poses` (P, 3) start poses, `actions` (A, K)
    sequences, `futures` (F, K + 1, H, W) frames — now and K after it. Returns the poses (A, F, 3) after each
    sequence (where an agent's episode ended, as it ended) and the outcomes (A, F) (RUNNING where it did not);
    with one start pose it is every sequence's, else sequence a starts from pose a."""
    n_seq, k = actions.shape
    pose = np.broadcast_to(poses[:, None, :], (n_seq, futures.shape[0], 3)).copy()
    outcome = np.zeros(pose.shape[:2], np.int8)
    for t in range(k):
        live = outcome == Outcome.RUNNING
        action = np.broadcast_to(actions[:, t][:, None], live.shape)
        heading = pose[..., 2]
        forward = action == FORWARD
        target = pose[..., :2] + HEADINGS[heading] * forward[..., None]
        ended, into_wall = _judge(pose, target, forward, futures[:, t], futures[:, t + 1])
        turned = np.where(action == LEFT, (heading + 3) % 4, np.where(action == RIGHT, (heading + 1) % 4, heading))
        pose[..., :2] = np.where((live & ~into_wall)[..., None], target, pose[..., :2])
        pose[..., 2] = np.where(live, turned, heading)
        outcome = np.where(live, ended, outcome).astype(np.int8)
    return pose, outcome


def _judge(
    pose: np.ndarray, target: np.ndarray, forward: np.ndarray, now: np.ndarray, after: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """How each step from `pose` to `target` (A, F, 2) ends, between the futures' frames `now` and `after`
    (F, H, W): death on a ball, on swapping with one, or forward into a wall; the goal's cell wins. Also where it
    was forward into a wall (the agent does not move there)."""
    futures = np.arange(now.shape[0])[None, :]
    rows, cols = target[..., 0], target[..., 1]
    into_wall = forward & (now[futures, rows, cols] == WALL)
    swapped = forward & (now[futures, rows, cols] == BALL) & (after[futures, pose[..., 0], pose[..., 1]] == BALL)
    died = into_wall | (after[futures, rows, cols] == BALL) | swapped
    won = now[futures, rows, cols] == GOAL
    return np.where(died, Outcome.DEATH, np.where(won, Outcome.GOAL, Outcome.RUNNING)), into_wall


class Rolled(NamedTuple):
    """Action sequences against futures of chances (A, F each): where each ended (A, F, 3) and its chances of having
    reached the goal and of having died (the rest it is still running)."""

    poses: np.ndarray
    won: np.ndarray
    died: np.ndarray


def roll_chances(pose: Pose, actions: np.ndarray, layout: np.ndarray, balls: np.ndarray) -> Rolled:
    """`roll` in expectation: every sequence of `actions` (A, K) from `pose` against every future of `balls`
    (F, K + 1, H, W), each cell's chance of a ball now and at each step, in a room of `layout` (H, W: its walls and
    goal, which do not move). A step kills with the chance of a ball on the cell it ends on, or of swapping with one
    (a ball on the cell it moves onto now, times one on the cell it leaves after), taken as independent; with 0/1
    chances it is `roll` exactly."""
    n_seq, k = actions.shape
    futures = np.arange(balls.shape[0])[None, :]
    at = np.broadcast_to(np.array(pose, np.int64), (n_seq, balls.shape[0], 3)).copy()
    won, died = np.zeros(at.shape[:2]), np.zeros(at.shape[:2])
    for t in range(k):
        running = 1.0 - won - died
        action = actions[:, t][:, None]
        forward = np.broadcast_to(action == FORWARD, running.shape)
        target = at[..., :2] + HEADINGS[at[..., 2]] * forward[..., None]
        into_wall = forward & (layout[target[..., 0], target[..., 1]] == WALL)
        now, after = balls[:, t], balls[:, t + 1]
        swap = forward * now[futures, target[..., 0], target[..., 1]] * after[futures, at[..., 0], at[..., 1]]
        hit = after[futures, target[..., 0], target[..., 1]]
        survive = np.where(into_wall, 0.0, (1.0 - hit) * (1.0 - swap))
        won += running * survive * (layout[target[..., 0], target[..., 1]] == GOAL)
        died += running * (1.0 - survive)
        heading = at[..., 2]
        turned = np.where(action == LEFT, (heading + 3) % 4, np.where(action == RIGHT, (heading + 1) % 4, heading))
        at[..., :2] = np.where(into_wall[..., None], at[..., :2], target)
        at[..., 2] = turned
    return Rolled(at, won, died)
