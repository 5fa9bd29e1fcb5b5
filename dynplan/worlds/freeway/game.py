"""Atari Freeway as a world that does not depend on the agent: the real game and, in lockstep, a shadow game whose
chicken never moves (it always plays NOOP), both in the Arcade Learning Environment (`ale-py`, the `atari` extra).

The cars of Freeway do not depend on the chicken: outside the real chicken's box, the idle chicken's box on the
bottom sidewalk and the score digits, the shadow's screen equals the real one at every step
(`tests/test_freeway.py` checks it). So the shadow's screen, cropped to the lanes, is the world's frame — what a
world model learns and imagines — and the real chicken is the agent, read from RAM. An episode is determined by its
`FreewayEpisode` (the game mode and the NOOP steps played before it starts): its world frames are the same bytes
every time (palette indices of the emulator's screen, no colour conversion), and a later NOOP start is the same
traffic one step further on. So the world of a mode is one recording, `record_mode`: the shadow's lanes from the
game's start to its end, in which an episode with NOOP start n starts at frame n.

A world frame is (154, 152) uint8 with row 0 the bottom lane's last row (the screen's rows 27–180 flipped, as every
dynplan world frame: row 0 is the bottom), columns the screen's 8–159.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field

from dynplan.arguments import ArgumentError, Array, Bounds, checked
from dynplan.config import Config
from dynplan.extras import require

#: The game modes (the traffic); an episode of the world is a mode.
MODES = range(8)

#: Emulator frames per agent step (Gymnasium's `ALE/Freeway-v5` default).
FRAMESKIP = 4
#: Agent steps from the game's start to its end (its 2 min 16 s timer at frameskip 4), the NOOP start included.
GAME_STEPS = 2048
#: The lanes, (rows, columns) of the screen: 10 lanes 16 rows apart, cars 8 × 10 pixels.
LANE_ROWS = slice(27, 181)
LANE_COLUMNS = slice(8, 160)
LANE_HEIGHT, LANE_WIDTH = LANE_ROWS.stop - LANE_ROWS.start, LANE_COLUMNS.stop - LANE_COLUMNS.start
#: RAM byte of the chicken's height above the bottom (6 on the sidewalk … 177 at the top).
CHICKEN_Y_RAM = 14
#: RAM byte of the chicken's timer: ≥ 128 while it waits on the sidewalk after a crossing, 1–127 while a car's hit
#: knocks it back and stuns it (it counts down by 2 a step), 0 when it obeys its actions.
CHICKEN_TIMER_RAM = 106
#: Screen columns of the player's chicken; its box spans rows 193 − y … 200 − y.
CHICKEN_COLUMNS = slice(44, 51)
#: The idle chicken's box (the shadow's, on the bottom sidewalk) and the score digits: where the screens differ.
IDLE_CHICKEN_ROWS = slice(187, 195)
SCORE_BOX = (slice(5, 13), slice(41, 55))
ACTIONS = ("NOOP", "UP", "DOWN")
#: The lane frame's values that are no car: the road, the lane marks and the median.
ROAD_VALUES = (6, 12, 30)
#: Every value of a lane frame, by name (the same in every mode): the road's, the cars' tyres and each lane's car
#: colour, lanes counted from the bottom.
CAR_COLOURS = (26, 216, 68, 136, 36, 130, 74, 18, 220, 66)
CAR_LANES = {f"car_lane_{i + 1}": v for i, v in enumerate(CAR_COLOURS)}
PIXEL_VALUES = {"road": 6, "lane_mark": 12, "median": 30, "tyres": 0, **CAR_LANES}
#: The chicken's sprite box in a lane frame: rows y − 20 … y − 13 at height y, the chicken's columns (and one more).
SPRITE_ROWS = (-20, -12)
SPRITE_COLUMNS = slice(CHICKEN_COLUMNS.start - LANE_COLUMNS.start, CHICKEN_COLUMNS.start - LANE_COLUMNS.start + 8)
#: The chicken's sprite at each height 0 … 177, (178, 8, 8) bool over its box (row r is the box's row y − 20 + r),
#: measured from the emulator by `python -m lab.freeway_sprites`.
SPRITES = Path(__file__).with_name("chicken.npy")
#: The chicken's column in a lane frame (the middle of its columns).
CHICKEN_COLUMN = 39.0
#: The chicken's rule (`chicken_step`), measured against the emulator: heights from the bottom sidewalk to the
#: crossing, the timer a hit sets, the timer below which a knocked chicken stops sliding back, the timer at which
#: its stun ends, the timer a crossing sets and the one at which its wait ends.
BOTTOM_Y, TOP_Y = 6, 177
HIT_TIMER, SLIDE_END, STUN_END, WAIT_TIMER, WAIT_END = 91, 80, 64, 142, 128
#: How far a lane's cars may move in one step, in columns (the fastest mode's 8, and a margin).
MAX_SHIFT = 10
#: The lanes of a lane frame: lane i (from the bottom) is rows 16 i … 16 i + 15, its cars' bodies on rows 16 i + 1 …
#: 16 i + 8 (their tyres reach a row further either side).
LANES, LANE_PITCH = 10, 16
CAR_ROWS = np.arange(LANES)[:, None] * LANE_PITCH + 1 + np.arange(8)
_NO_CAR = np.zeros(256, bool)
_NO_CAR[list(ROAD_VALUES)] = True


#: The emulator's random seeds: 0 … 2³¹ − 2 (a 32-bit signed integer; −1 asks for a seed from the clock).
EMULATOR_SEEDS = 2**31 - 1


class FreewayEpisode(Config):
    """Which Freeway episode: the game mode (traffic; modes 4–7 change speeds during the episode), the NOOP steps
    played before the agent starts (the traffic's phase) and the game's sticky actions (ALE's: at each emulator
    frame, with probability `sticky`, the action before is played again, drawn from `emulator_seed`)."""

    mode: int = Field(0, ge=0, le=7, description="the game mode (its traffic)")
    noop_start: int = Field(0, ge=0, le=30, description="NOOP steps before the agent's first")
    sticky: float = Field(
        0.0, ge=0.0, le=1.0, description="probability that the game repeats its last action at a frame (0: none)"
    )
    emulator_seed: int = Field(
        0, ge=0, le=EMULATOR_SEEDS - 1, description="the game's random seed (which frames repeat)"
    )


def episode_seed(seed: int, index: int) -> int:
    """Episode `index`'s own seed in an evaluation drawn from `seed`: its random actions' (`emulator_seed`: its
    sticky frames')."""
    return seed * 1000 + index


def emulator_seed(seed: int, index: int) -> int:
    """The emulator's random seed of episode `index` of an evaluation drawn from `seed` (which frames repeat with
    sticky actions): the episode's seed, within the emulator's range."""
    return episode_seed(seed, index) % EMULATOR_SEEDS


@dataclass(frozen=True)
class Chicken:
    """The chicken as the planner simulates it: its height `y` (6 on the bottom sidewalk … 177) and its `timer`
    (RAM byte 106: ≥ 128 waiting after a crossing, 1–127 knocked back or stunned, 0 free)."""

    y: int
    timer: int = 0

    @property
    def knocked(self) -> bool:
        """Knocked back or stunned by a car (not waiting after a crossing, not free)."""
        return 0 < self.timer < WAIT_END


@dataclass(frozen=True)
class FreewayStep:
    """One agent step: the world's frame (lanes only, palette indices), the chicken after it, the game's reward (1
    at each crossing) and whether the game has ended."""

    frame: np.ndarray
    chicken: Chicken
    reward: float
    done: bool


class ChickenGame:
    """The real game alone, playing `episode` (default: mode 0, no NOOP start): the chicken, the score and the end —
    what replaying a row's actions needs, at half the emulation of `FreewayGame`."""

    def __init__(self, episode: FreewayEpisode | None = None, real=None) -> None:
        """`real`: an emulator of the episode's mode and settings at the game's start, to play on (replays reuse
        one a mode); default a new one."""
        self.episode = episode = episode or FreewayEpisode()
        self.real = real if real is not None else emulator(episode.mode, episode.sticky, episode.emulator_seed)
        self._actions = self.real.getMinimalActionSet()
        for _ in range(episode.noop_start):
            self.advance(0)

    def advance(self, action: int) -> float:
        """Play action index `action` for one agent step (`FRAMESKIP` frames); the reward it earned."""
        return sum(self.real.act(self._actions[action]) for _ in range(FRAMESKIP))

    @property
    def chicken(self) -> Chicken:
        """The real chicken now, from the game's RAM."""
        ram = self.real.getRAM()
        return Chicken(int(ram[CHICKEN_Y_RAM]), int(ram[CHICKEN_TIMER_RAM]))

    def over(self) -> bool:
        """Whether the game has ended."""
        return self.real.game_over()


class FreewayGame(ChickenGame):
    """The real game and its NOOP shadow, in lockstep, playing `episode` (default: mode 0, no NOOP start)."""

    def __init__(self, episode: FreewayEpisode | None = None) -> None:
        self.shadow = emulator((episode or FreewayEpisode()).mode)  # plays NOOP: nothing to repeat but NOOP
        super().__init__(episode)  # the NOOP start advances both

    def advance(self, action: int) -> float:
        for _ in range(FRAMESKIP):
            self.shadow.act(self._actions[0])
        return super().advance(action)

    def world_frame(self) -> np.ndarray:
        """The world without the agent now: the shadow's lanes, (154, 152) uint8 palette indices, row 0 the bottom."""
        return lane_frame(self.shadow.getScreen())

    @checked
    def step(self, action: Action) -> FreewayStep:
        """Play `action` (0 NOOP, 1 UP, 2 DOWN) for one agent step in the real game; the shadow plays NOOP."""
        reward = self.advance(action)
        return FreewayStep(self.world_frame(), self.chicken, reward, self.over())


#: An agent's action, 0 NOOP, 1 UP, 2 DOWN; a lane frame (row 0 the bottom); the emulator's screen (palette
#: indices, or RGB).
Action = Annotated[int, Bounds(0, len(ACTIONS) - 1)]
LaneFrame = Annotated[np.ndarray, Array(shape=(LANE_HEIGHT, LANE_WIDTH), kinds="ui")]
Screen = Annotated[np.ndarray, Array(ndim=(2, 3), kinds="ui")]
#: The emulator's screen: 210 rows, 160 columns.
SCREEN_SHAPE = (210, 160)


@checked
def lane_frame(screen: Screen) -> np.ndarray:
    """A screen's lanes as a world frame: (154, 152), row 0 the bottom lane's last row."""
    if screen.shape[:2] != SCREEN_SHAPE:
        raise ArgumentError(
            f"lane_frame: screen of shape {screen.shape} is invalid; it takes the emulator's {SCREEN_SHAPE}"
        )
    return np.ascontiguousarray(screen[LANE_ROWS, LANE_COLUMNS][::-1])


def chicken_row(y: int | float) -> float:
    """The world-frame row of the middle of the chicken's sprite at height `y` (below 0 on the bottom sidewalk)."""
    return y + (SPRITE_ROWS[0] + SPRITE_ROWS[1] - 1) / 2


class FreewayConfig(Config):
    """Freeway's world: nothing to choose but the episode (a game mode, the log's seed); the frame is the lanes."""

    @property
    def height(self) -> int:
        return LANE_HEIGHT

    @property
    def width(self) -> int:
        return LANE_WIDTH

    @property
    def max_steps(self) -> int:
        """Frames of a mode's recording: the game's start and each of its steps."""
        return GAME_STEPS + 1


@dataclass(frozen=True)
class FreewayWorld:
    """One mode of Freeway's world, recorded: frames (T, 154, 152) uint8 from the game's start (frame n is where an
    episode with NOOP start n begins); Freeway has no goal; agent_start is the chicken's (row, column) on the
    sidewalk."""

    config: FreewayConfig
    seed: int
    frames: np.ndarray
    goal: None = None
    agent_start: np.ndarray = field(default_factory=lambda: np.array([chicken_row(BOTTOM_Y), CHICKEN_COLUMN]))

    @property
    def mode(self) -> int:
        return self.seed


@checked
def record_mode(
    mode: Annotated[int, Bounds(0, len(MODES) - 1)], n_frames: Annotated[int, Bounds(1, GAME_STEPS + 1)] | None = None
) -> FreewayWorld:
    """The world of game `mode` from the game's start: the NOOP shadow's lanes at each of its first `n_frames`
    steps (default the whole game, 2,049 frames)."""
    n_frames = GAME_STEPS + 1 if n_frames is None else n_frames
    ale = emulator(mode)
    frames = np.empty((n_frames, *lane_frame(ale.getScreen()).shape), np.uint8)
    frames[0] = lane_frame(ale.getScreen())
    noop = ale.getMinimalActionSet()[0]
    for t in range(1, n_frames):
        for _ in range(FRAMESKIP):
            ale.act(noop)
        frames[t] = lane_frame(ale.getScreen())
    return FreewayWorld(FreewayConfig(), mode, frames)


@checked
def chicken_step(chicken: Chicken, action: Action, before: LaneFrame, after: LaneFrame) -> tuple[Chicken, float]:
    """The chicken after one agent step of `action` (0 NOOP, 1 UP, 2 DOWN) from the world's lane frame `before` to
    `after` (as `FreewayGame.world_frame` gives them, or a world model imagines them), and the step's reward (1 for
    a crossing): `chicken_frames` over the step's frames as `step_frames` estimates them."""
    if not (BOTTOM_Y <= chicken.y <= TOP_Y and 0 <= chicken.timer <= 255):
        raise ArgumentError(
            f"chicken_step: chicken={chicken} is invalid; y in [{BOTTOM_Y}, {TOP_Y}], timer in [0, 255] (a RAM byte)"
        )
    return chicken_frames(chicken, action, step_frames(before, after))


def chicken_frames(chicken: Chicken, action: int, drawn: Sequence[np.ndarray]) -> tuple[Chicken, float]:
    """The chicken after one agent step of `action` whose four emulator frames were preceded by the lanes `drawn`
    (the frame before the step, then the three within it), and the step's reward. Frame by frame, as the game: a
    free chicken moves 1 pixel a frame, and is hit when a car's pixel met its sprite on the frame drawn before (the
    console's collision latch, read a frame late); a hit sets the timer to 91, the chicken slides back 1 pixel a
    frame while the timer is ≥ 80, then stands stunned until the timer passes 64; the timer counts down on every
    other frame; a crossing puts it on the sidewalk to wait until its timer reaches 128."""
    y, timer = chicken.y, chicken.timer
    for k in range(FRAMESKIP):
        tick = k % 2 == 1
        if timer >= WAIT_END:
            timer = 0 if timer - tick <= WAIT_END else timer - tick
        elif timer > 0:
            y = max(y - 1, BOTTOM_Y) if timer >= SLIDE_END else y
            timer = 0 if timer - tick <= STUN_END else timer - tick
        else:
            hit = sprite_hit(drawn[k], y)
            y = max(y + (0, 1, -1)[action], BOTTOM_Y)
            if y >= TOP_Y:
                return Chicken(BOTTOM_Y, WAIT_TIMER), 1.0
            timer = HIT_TIMER if hit else 0
    return Chicken(y, timer), 0.0


def chicken_mask(shape: tuple[int, int], y: int) -> np.ndarray:
    """Where the chicken's sprite at height `y` lies in a lane frame of `shape`: (H, W) bool (none of it on the
    bottom sidewalk, below the frame)."""
    mask, low = np.zeros(shape, bool), y + SPRITE_ROWS[0]
    rows = np.arange(low, low + 8)
    inside = (rows >= 0) & (rows < shape[0])
    mask[rows[inside], SPRITE_COLUMNS] = _sprites()[y][inside]
    return mask


def sprite_hit(frame: np.ndarray, y: int) -> bool:
    """Whether a car's pixel of the lane `frame` meets the chicken's sprite at height `y`."""
    low, high = y + SPRITE_ROWS[0], y + SPRITE_ROWS[1]
    if high <= 0 or low >= frame.shape[0]:
        return False
    sprite = _sprites()[y][max(-low, 0) : 8 - max(high - frame.shape[0], 0)]
    cars = ~_NO_CAR[frame[max(low, 0) : min(high, frame.shape[0]), SPRITE_COLUMNS]]
    return bool((cars & sprite).any())


@cache
def _sprites() -> np.ndarray:
    return np.load(SPRITES)


def lane_shifts(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(10,) how many columns each lane's cars moved from lane frame `before` to `after` (positive: right): the shift
    in [−10, 10] under which the most car columns of `before` meet those of `after`, the smallest on a tie. Columns
    wrap around the frame's 152 (the game's 160 less its 8 hidden ones), which misplaces only cars at the frame's
    edges, far from the chicken's columns."""

    def columns(frame: np.ndarray) -> np.ndarray:  # (10, W): where lane i's cars are
        return (~_NO_CAR[frame[CAR_ROWS]]).any(axis=1)

    was, now = columns(before), columns(after)
    shifts = np.array(sorted(range(-MAX_SHIFT, MAX_SHIFT + 1), key=abs))
    overlap = np.stack([(np.roll(was, s, axis=1) & now).sum(axis=1) for s in shifts])  # (shifts, lanes)
    return shifts[overlap.argmax(axis=0)]


def step_frames(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(4, H, W) the lanes drawn before each emulator frame of a step from `before` to `after`: `before`, then
    each lane's cars moved 1/4, 2/4 and 3/4 of their shift (`lane_shifts`), rounded."""
    drawn = np.repeat(before[None], FRAMESKIP, axis=0)
    for lane, shift in enumerate(lane_shifts(before, after)):
        rows = slice(lane * LANE_PITCH, (lane + 1) * LANE_PITCH)
        for k in range(1, FRAMESKIP):
            moved = int(np.sign(shift)) * int(np.floor(k * abs(int(shift)) / FRAMESKIP + 0.5))
            drawn[k, rows] = np.roll(before[rows], moved, axis=1)
    return drawn


@checked
def extrapolated(
    observed: Annotated[np.ndarray, Array(shape=(None, LANE_HEIGHT, LANE_WIDTH), kinds="ui")],
    k: Annotated[int, Bounds(1, 64)],
) -> np.ndarray:
    """(k, H, W): the last of the `observed` lane frames (≥ 2) with each lane's cars moved on at their mean shift a
    step over `observed` (the sum of `lane_shifts` between consecutive frames over the steps), rounded at each step
    ahead: a world that keeps every lane at its recent speed."""
    if len(observed) < 2:
        raise ArgumentError(f"extrapolated: observed holds {len(observed)} frames; it takes 2 or more")
    shifts = np.sum([lane_shifts(a, b) for a, b in itertools.pairwise(observed)], axis=0) / (len(observed) - 1)
    frames = np.repeat(observed[-1][None], k, axis=0)
    for lane, shift in enumerate(shifts):
        rows = slice(lane * LANE_PITCH, (lane + 1) * LANE_PITCH)
        for step in range(k):
            frames[step, rows] = np.roll(observed[-1][rows], int(np.floor(shift * (step + 1) + 0.5)), axis=1)
    return frames


def emulator(mode: int, sticky: float = 0.0, seed: int = 0):
    """An ALE emulator of Freeway in `mode`, one emulator frame per act: deterministic, or with probability
    `sticky` of repeating the action before at each frame, drawn from `seed`."""
    ale_py = require("ale_py", "atari", "Atari Freeway")
    ale_py.ALEInterface.setLoggerMode(ale_py.LoggerMode.Error)  # before the first emulator: no banner
    ale = ale_py.ALEInterface()
    ale.setInt("random_seed", seed)
    ale.setFloat("repeat_action_probability", sticky)
    ale.setInt("frame_skip", 1)
    ale.loadROM(ale_py.roms.get_rom_path("freeway"))
    ale.setMode(mode)
    ale.reset_game()
    return ale
