"""A trial: a one-step "marginal head" learned from the frames, told to the planner on the prior's sampled rooms.

The learned technique tells the planner, for each sampled future and step, the chance of a ball the prior's softmax
gave as it drew each cell — conditioned on the cells it drew before in the same grid. The true rule's analogue
(`lab.minigrid_chances`: each walk future's one-step chances given its room the step before) plans better. This
trial learns that analogue from the frames: a small convolutional net (`Head`) from a room to each cell's chance of
a ball one step on (trained with binary cross-entropy on recorded rooms), applied to each of the prior's sampled
rooms the step before.

`python -m lab.minigrid_head train --rooms 300 --steps 4000 --out /tmp/head.pt`
`python -m lab.minigrid_head plan --head /tmp/head.pt --first-seed 3000000 --episodes 100 [--samples 10]`
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
from torch import nn

from dynplan.worlds.minigrid.agent import AGENT_START_POSE, Outcome, step
from dynplan.worlds.minigrid.grid import PIXEL_VALUES, MiniGridConfig, record_world
from dynplan.worlds.minigrid.imagine import MiniGridModel
from dynplan.worlds.minigrid.search import BALL, GridSearch, layout_of, plan_chances
from lab.minigrid_marginal import occupancy
from lab.minigrid_planners import summary

KINDS = ("wall", "ball", "goal")


def one_hot(frames: np.ndarray) -> torch.Tensor:
    """(N, 3, H, W) float: each frame's walls, balls and goal."""
    return torch.from_numpy(np.stack([frames == PIXEL_VALUES[k] for k in KINDS], axis=1).astype(np.float32))


class Head(nn.Module):
    """A room to each cell's logit of a ball one step on: 3 × 3 convolutions, a 9 × 9 receptive field."""

    def __init__(self, channels: int = 32, layers: int = 4):
        super().__init__()
        parts, width = [], len(KINDS)
        for _ in range(layers):
            parts += [nn.Conv2d(width, channels, 3, padding=1), nn.ReLU()]
            width = channels
        self.net = nn.Sequential(*parts, nn.Conv2d(width, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)[:, 0]


def pairs(first: int, rooms: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Each recorded step of rooms first … first + rooms − 1: (room, next room's balls)."""
    frames = [record_world(MiniGridConfig(), seed).frames for seed in range(first, first + rooms)]
    now = np.concatenate([f[:-1] for f in frames])
    nxt = np.concatenate([f[1:] for f in frames]) == BALL
    return one_hot(now), torch.from_numpy(nxt.astype(np.float32))


def train(args) -> None:
    torch.manual_seed(0)
    x, y = pairs(0, args.rooms)
    vx, vy = pairs(900, 20)  # the prior's validation rooms (900 … 999)
    head = Head(args.channels, args.layers)
    opt = torch.optim.Adam(head.parameters(), lr=args.lr)
    loss_fn = nn.BCEWithLogitsLoss()
    gen = torch.Generator().manual_seed(0)
    start = time.perf_counter()
    for i in range(1, args.steps + 1):
        idx = torch.randint(0, len(x), (args.batch,), generator=gen)
        loss = loss_fn(head(x[idx]), y[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        if i % 500 == 0 or i == args.steps:
            with torch.inference_mode():
                val = loss_fn(head(vx), vy).item()
            print(json.dumps({"step": i, "train": round(loss.item(), 5), "val": round(val, 5),
                              "s": round(time.perf_counter() - start, 1)}), flush=True)  # fmt: skip
    torch.save({"state": head.state_dict(), "channels": args.channels, "layers": args.layers}, args.out)
    _rule_loss(vx, vy)


def _rule_loss(vx: torch.Tensor, vy: torch.Tensor) -> None:
    """The rule's own one-step spread (`lab.minigrid_marginal.occupancy`) scored on the same pairs, for scale."""
    codes = {0: PIXEL_VALUES["wall"], 1: PIXEL_VALUES["ball"], 2: PIXEL_VALUES["goal"]}
    frames = np.full(vx.shape[:1] + vx.shape[2:], PIXEL_VALUES["floor"], np.uint8)
    for channel, value in codes.items():
        frames[vx[:, channel].numpy() > 0] = value
    p = np.stack([occupancy(f, 1)[1] for f in frames]).clip(1e-6, 1 - 1e-6)
    t = vy.numpy()
    print(json.dumps({"rule_val": round(float(-(t * np.log(p) + (1 - t) * np.log(1 - p)).mean()), 5)}), flush=True)


def load(path: str) -> Head:
    saved = torch.load(path, weights_only=True)
    head = Head(saved["channels"], saved["layers"])
    head.load_state_dict(saved["state"])
    return head.eval()


@torch.inference_mode()
def head_chances(head: Head, rooms: np.ndarray) -> np.ndarray:
    """(S, k + 1, H, W): the rooms' balls now, then each step's chances given the sampled room the step before."""
    s, k1 = rooms.shape[:2]
    out = np.empty(rooms.shape, np.float32)
    out[:, 0] = rooms[:, 0] == BALL
    before = rooms[:, :-1].reshape(-1, *rooms.shape[2:])
    out[:, 1:] = torch.sigmoid(head(one_hot(before))).numpy().reshape(s, k1 - 1, *rooms.shape[2:])
    return out


def plan(args) -> None:
    head, model = load(args.head), MiniGridModel(args.model_dir)
    search, rows = GridSearch(horizon=5, risk=args.risk, commit=5), []
    for seed in range(args.first_seed, args.first_seed + args.episodes):
        room = record_world(MiniGridConfig(), seed)
        pose, outcome, t, ms = AGENT_START_POSE, Outcome.RUNNING, 0, []
        while outcome == Outcome.RUNNING and t < len(room.frames) - 1:
            start = time.perf_counter()
            rooms = model.imagine(room.frames[: t + 1], search.horizon, args.samples).rooms
            balls = head_chances(head, rooms)
            action = plan_chances(pose, layout_of(room.frames[t]), balls, room.goal[0], search).action
            ms.append((time.perf_counter() - start) * 1e3)
            pose, outcome = step(pose, action, room.frames[t], room.frames[t + 1])
            t += 1
        ended = Outcome.TIMEOUT if outcome == Outcome.RUNNING else outcome
        rows.append({"outcome": ended.name.lower(), "steps": t, "decision_ms": float(np.median(ms))})
    print(json.dumps({"learned_head": summary(rows), "samples": args.samples, "risk": args.risk,
                      "first_seed": args.first_seed, "episodes": args.episodes}), flush=True)  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m lab.minigrid_head", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train")
    t.add_argument("--rooms", type=int, default=300)
    t.add_argument("--steps", type=int, default=4000)
    t.add_argument("--batch", type=int, default=128)
    t.add_argument("--lr", type=float, default=2e-3)
    t.add_argument("--channels", type=int, default=32)
    t.add_argument("--layers", type=int, default=4)
    t.add_argument("--out", default="/tmp/head.pt")
    p = sub.add_parser("plan")
    p.add_argument("--head", default="/tmp/head.pt")
    p.add_argument("--model-dir", default=None)
    p.add_argument("--first-seed", type=int, default=3_000_000)
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--samples", type=int, default=10)
    p.add_argument("--risk", type=float, default=1.0)
    args = parser.parse_args(argv)
    train(args) if args.command == "train" else plan(args)


if __name__ == "__main__":
    main()
