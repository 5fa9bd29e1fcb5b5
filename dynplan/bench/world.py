"""`world`: frames per second of episode generation (407-frame episodes, one core), vs the stepwise baseline."""

from __future__ import annotations

from dynplan.bench.timing import median_seconds, pin_to_one_core
from dynplan.env.config import RoadConfig
from dynplan.env.road import generate_world
from dynplan.env.stepwise import simulate_world

#: The vectorised generator's target speed, frames per second.
TARGET_FRAMES_PER_S = 50_000


def bench_world(episodes: int = 20, repeats: int = 5) -> dict[str, dict[str, float]]:
    """Generate `episodes` 407-frame episodes per repeat with both implementations; report median speeds."""
    pin_to_one_core()
    config = RoadConfig(agent_speed=0.5)
    n_frames = config.max_steps

    def vectorised() -> None:
        for seed in range(episodes):
            generate_world(config, seed, n_frames)

    def stepwise() -> None:
        for seed in range(max(episodes // 10, 1)):
            simulate_world(config, seed, n_frames)

    fast = episodes * n_frames / median_seconds(vectorised, repeats)
    slow = max(episodes // 10, 1) * n_frames / median_seconds(stepwise, repeats)
    return {
        "world": {
            "frames_per_s": round(fast),
            "stepwise_frames_per_s": round(slow),
            "speedup_vs_stepwise": round(fast / slow, 1),
            "target_frames_per_s": TARGET_FRAMES_PER_S,
            "meets_target": float(fast >= TARGET_FRAMES_PER_S),
        }
    }
