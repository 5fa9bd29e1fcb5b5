"""PUCT Monte-Carlo tree search over a predicted future (docs/protocol.md §3), compiled with numba.

The world does not depend on the agent, so a decision's whole future is one array of predicted frames
(k, H, W); a tree node is only (position, depth), and stepping a node is an addition plus one pixel lookup.
The tree lives in flat arrays (capacity C nodes):

    child:    (C, 8) int32   child index per action, −1 until the node is expanded
    visits:   (C,)   int64   N, playouts through the node
    value:    (C,)   float64 W, sum of backed-up values (Q = W / N; 0 while unvisited)
    prior:    (C,)   float64 P of the node under its parent
    position: (C, 2) float64 agent (y, x) at the node
    depth:    (C,)   int32   steps from the root; the node's frame is prediction[depth − 1]

Each playout descends by score = Q + c·P·√N_parent / (1 + N_child), judges each node on its predicted frame
(death −20, goal 20 − 10·t/T with t the absolute frame index, so sooner is better), expands the first
unexpanded live node with the goal prior, finishes with uniformly random actions up to the horizon, and backs
the single value up the path. The action is drawn from visit counts at temperature 0.01, and the chosen
child's subtree becomes the next root. Terminal semantics: a node is judged on its own frame whenever a
playout reaches it, so a reused subtree is always judged against the newest prediction.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from dynplan.env.agent import ACTION_ANGLES_DEG, N_ACTIONS, REWARD_DEATH, REWARD_GOAL, action_deltas
from dynplan.env.config import FREE, GOAL_VALUE
from dynplan.planning.config import PAPER_PRIOR, MCTSConfig
from dynplan.planning.forward import Prediction

RUNNING, GOAL, DEATH = 0, 1, 2


@dataclass(frozen=True)
class Decision:
    """One decision: the action and the root's statistics per action (visits, Q, prior), and its cost."""

    action: int
    visits: np.ndarray
    q: np.ndarray
    prior: np.ndarray
    search_ms: float


def goal_prior(position: np.ndarray, goal: np.ndarray, weights: tuple[float, ...] = PAPER_PRIOR) -> np.ndarray:
    """(8,) prior over actions from the bearing to `goal` (uniform if the goal is unknown). NumPy twin of the
    compiled `_prior`, for tests and tools."""
    out = np.empty(N_ACTIONS)
    _prior(
        float(position[0]),
        float(position[1]),
        float(goal[0]),
        float(goal[1]),
        ACTION_ANGLES_DEG.astype(np.float64),
        np.asarray(weights, np.float64),
        out,
    )
    return out


@numba.njit(cache=True)
def _prior(y, x, goal_y, goal_x, angles, weights, out):
    if np.isnan(goal_y) or np.isnan(goal_x):
        out[:] = 1.0 / len(out)
        return
    bearing = np.degrees(np.arctan2(goal_y - y, goal_x - x))
    distance = np.abs((angles - bearing + 180.0) % 360.0 - 180.0)  # wrapped angular distance
    order = np.argsort(distance, kind="mergesort")
    total = weights.sum()
    for rank in range(len(order)):
        out[order[rank]] = weights[rank] / total


@numba.njit(cache=True)
def _judge(frames, index, y, x):
    H, W = frames.shape[1], frames.shape[2]
    r = int(np.floor(y + 0.5))
    c = int(np.floor(x + 0.5))
    if r < 0 or r >= H or c < 0 or c >= W:
        return DEATH
    v = frames[index, r, c]
    if v == FREE:
        return RUNNING
    if v == GOAL_VALUE:
        return GOAL
    return DEATH


@numba.njit(cache=True)
def _terminal_value(outcome, t_abs, max_steps):
    if outcome == DEATH:
        return REWARD_DEATH
    return REWARD_GOAL - 10.0 * t_abs / max_steps


@numba.njit(cache=True, nogil=True)  # episodes on a thread pool search in parallel
def _playouts(tree, n_nodes, frames, horizon, goal, t0, max_steps, search):
    """Run len(random_actions) playouts from node 0; returns the new node count. `tree`: the arrays of `Tree.arrays`;
    `goal`: (y, x); `search`: (deltas, angles, prior weights, c_puct, random_actions (playouts, horizon))."""
    child, visits, value, prior, position, depth = tree
    goal_y, goal_x = goal
    deltas, angles, weights, c_puct, random_actions = search
    path = np.empty(horizon + 1, np.int64)
    node_prior = np.empty(deltas.shape[0])
    for playout in range(random_actions.shape[0]):
        node, length = 0, 1
        path[0] = node
        while True:
            d = depth[node]
            if d > 0:
                outcome = _judge(frames, d - 1, position[node, 0], position[node, 1])
                if outcome != RUNNING:
                    result = _terminal_value(outcome, t0 + d, max_steps)
                    break
            if d >= horizon:
                result = 0.0
                break
            if child[node, 0] < 0:
                # Expand with the goal prior seen from this node, then roll out at random to the horizon.
                _prior(position[node, 0], position[node, 1], goal_y, goal_x, angles, weights, node_prior)
                for a in range(deltas.shape[0]):
                    new = n_nodes
                    n_nodes += 1
                    child[node, a] = new
                    prior[new] = node_prior[a]
                    position[new, 0] = position[node, 0] + deltas[a, 0]
                    position[new, 1] = position[node, 1] + deltas[a, 1]
                    depth[new] = d + 1
                result = 0.0
                y, x = position[node, 0], position[node, 1]
                for s in range(d, horizon):
                    a = random_actions[playout, s]
                    y += deltas[a, 0]
                    x += deltas[a, 1]
                    outcome = _judge(frames, s, y, x)
                    if outcome != RUNNING:
                        result = _terminal_value(outcome, t0 + s + 1, max_steps)
                        break
                break
            # Select by PUCT.
            best, best_score = -1, -np.inf
            sqrt_n = np.sqrt(visits[node])
            for a in range(deltas.shape[0]):
                ch = child[node, a]
                q = value[ch] / visits[ch] if visits[ch] > 0 else 0.0
                score = q + c_puct * prior[ch] * sqrt_n / (1.0 + visits[ch])
                if score > best_score:
                    best, best_score = ch, score
            node = best
            path[length] = node
            length += 1
        for i in range(length):
            visits[path[i]] += 1
            value[path[i]] += result
    return n_nodes


@numba.njit(cache=True)
def _copy_subtree(tree, root, out):
    """Copy the subtree under `root` of `tree` into the arrays `out` (both as `Tree.arrays`: root becomes node 0,
    depths shift by one)."""
    child, visits, value, prior, position, depth = tree
    out_child, out_visits, out_value, out_prior, out_position, out_depth = out
    queue = np.empty(child.shape[0], np.int64)
    new_index = np.full(child.shape[0], -1, np.int64)
    queue[0] = root
    new_index[root] = 0
    head, tail = 0, 1
    while head < tail:
        old = queue[head]
        new = new_index[old]
        head += 1
        out_visits[new] = visits[old]
        out_value[new] = value[old]
        out_prior[new] = prior[old]
        out_position[new, 0] = position[old, 0]
        out_position[new, 1] = position[old, 1]
        out_depth[new] = depth[old] - depth[root]
        for a in range(child.shape[1]):
            ch = child[old, a]
            if ch < 0:
                out_child[new, a] = -1
                continue
            new_index[ch] = tail
            out_child[new, a] = tail
            queue[tail] = ch
            tail += 1
    return tail


class Tree:
    """The flat arrays of a search tree (see module docstring), with room for `capacity` nodes."""

    def __init__(self, capacity: int):
        self.child = np.full((capacity, N_ACTIONS), -1, np.int32)
        self.visits = np.zeros(capacity, np.int64)
        self.value = np.zeros(capacity, np.float64)
        self.prior = np.zeros(capacity, np.float64)
        self.position = np.zeros((capacity, 2), np.float64)
        self.depth = np.zeros(capacity, np.int32)
        self.size = 0

    @property
    def capacity(self) -> int:
        return len(self.visits)

    def arrays(self) -> tuple[np.ndarray, ...]:
        return self.child, self.visits, self.value, self.prior, self.position, self.depth

    def clear(self) -> None:
        self.child[:] = -1
        self.visits[:] = 0
        self.value[:] = 0.0
        self.size = 0

    def reset(self, position: np.ndarray) -> None:
        """A tree of just the root at `position`."""
        self.clear()
        self.position[0] = position
        self.depth[0] = 0
        self.prior[0] = 1.0
        self.size = 1


class MCTSPlanner:
    """PUCT MCTS agent. Call `act` once per decision with the agent's position, the frame index and the forward
    model's prediction; the chosen child's subtree, with its statistics, is the next call's root."""

    def __init__(self, config: MCTSConfig | None = None, agent_speed: float = 1.0, max_steps: int = 203, seed: int = 0):
        self.config = config or MCTSConfig()
        self.max_steps = max_steps
        self.deltas = action_deltas(agent_speed)
        self.angles = ACTION_ANGLES_DEG.astype(np.float64)
        self.weights = np.asarray(self.config.prior_weights, np.float64)
        self.rng = np.random.default_rng(seed)
        capacity = 1 + N_ACTIONS * (self.config.playouts + 1)
        # Two trees: a reused subtree may hold up to `capacity` nodes before this decision adds its own.
        self.tree, self.spare = Tree(2 * capacity), Tree(2 * capacity)
        self._next_root: int | None = None

    def reset(self) -> None:
        """Forget the tree (call between episodes)."""
        self._next_root = None

    def _root(self, position: np.ndarray) -> None:
        """Make the root: the previous decision's chosen child with its subtree, or a fresh node."""
        old, new = self.tree, self.spare
        if self._next_root is not None and np.allclose(old.position[self._next_root], position):
            new.clear()
            new.size = _copy_subtree(old.arrays(), self._next_root, new.arrays())
            self.tree, self.spare = new, old
        else:
            old.reset(position)
        if self.tree.size + N_ACTIONS * (self.config.playouts + 1) > self.tree.capacity:
            self.tree.reset(position)  # no room for this decision's expansions: start afresh

    def act(self, position: np.ndarray, t: int, prediction: Prediction) -> Decision:
        """Search from `position` at frame `t` against `prediction` (frames t+1 …) and pick an action."""
        start = time.perf_counter()
        cfg = self.config
        horizon = min(cfg.rollout_steps, len(prediction.frames))
        if horizon < 1:
            raise ValueError(f"the prediction holds no frames after t={t}; the episode has ended")
        frames = np.ascontiguousarray(prediction.frames[:horizon])
        goal = _goal_at(prediction.goal[:horizon], horizon // 2)
        self._root(np.asarray(position, np.float64))
        tree = self.tree
        random_actions = self.rng.integers(0, N_ACTIONS, size=(cfg.playouts, horizon))
        search = (self.deltas, self.angles, self.weights, cfg.c_puct, random_actions)
        tree.size = _playouts(tree.arrays(), tree.size, frames, horizon, (goal[0], goal[1]), t, self.max_steps, search)
        children = tree.child[0]
        visits = tree.visits[children].astype(np.float64)
        q = np.where(visits > 0, tree.value[children] / np.maximum(visits, 1), 0.0)
        action = self._choose(visits)
        self._next_root = int(children[action])
        return Decision(
            action, visits.astype(np.int64), q, tree.prior[children].copy(), (time.perf_counter() - start) * 1e3
        )

    def _choose(self, visits: np.ndarray) -> int:
        """Sample from visits^(1/temperature), computed in log space (temperature 0.01: the most visited)."""
        logits = np.log(visits + 1e-10) / self.config.temperature
        p = np.exp(logits - logits.max())
        return int(self.rng.choice(len(p), p=p / p.sum()))


def _goal_at(goals: np.ndarray, index: int) -> np.ndarray:
    """The predicted goal at `index`, else the nearest frame's that shows one, else NaN (uniform prior)."""
    known = np.nonzero(~np.isnan(goals[:, 0]))[0]
    if len(known) == 0:
        return np.array([np.nan, np.nan])
    return goals[known[np.argmin(np.abs(known - index))]]


class RandomPlanner:
    """The baseline: a uniformly random action at every decision."""

    def __init__(self, seed: int = 0):
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        pass

    def act(self, position: np.ndarray, t: int, prediction: Prediction | None = None) -> Decision:
        start = time.perf_counter()
        action = int(self.rng.integers(N_ACTIONS))
        uniform = np.full(N_ACTIONS, 1.0 / N_ACTIONS)
        return Decision(
            action, np.zeros(N_ACTIONS, np.int64), np.zeros(N_ACTIONS), uniform, (time.perf_counter() - start) * 1e3
        )
