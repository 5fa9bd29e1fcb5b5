"""RoadConfig: the tables of docs/protocol.md §1 as golden values, and validation that names the field and its range."""

import pytest

from dynplan.config import ConfigError
from dynplan.env import RoadConfig, episode_frames, obstacle_classes
from dynplan.env.config import lane_rows, spawn_probability


def test_defaults_are_the_papers_experiment():
    cfg = RoadConfig()
    assert (cfg.height, cfg.width, cfg.level, cfg.agent_speed, cfg.goal_speed) == (48, 48, 6, 1.0, 0.5)
    assert cfg.max_steps == 203
    assert RoadConfig(agent_speed=0.5).max_steps == 407


@pytest.mark.parametrize(("h", "w", "speed", "expected"), [(48, 48, 1.0, 203), (48, 48, 0.5, 407), (30, 40, 1.0, 150)])
def test_episode_length_formula(h, w, speed, expected):
    assert episode_frames(h, w, speed) == expected


def test_class_table_at_width_48():
    table = {c.name: c for c in obstacle_classes(48)}
    assert [c.name for c in obstacle_classes(48)] == ["tesla", "wagon", "sport", "truck", "sedan"]
    golden = {"truck": (45, 7, 0.2, 0.5), "wagon": (85, 6, 0.3, 0.82), "tesla": (100, 5, 0.6, 1.3),
              "sport": (130, 4, 1.3, 2.0), "sedan": (144, 3, 1.0, 2.3)}  # fmt: skip
    for name, (value, length, lo, hi) in golden.items():
        c = table[name]
        assert (c.value, c.length, len(c.speeds)) == (value, length, 10)
        assert c.speeds[0] == pytest.approx(lo) and c.speeds[-1] == pytest.approx(hi)


def test_lane_rows_at_48():
    rows = lane_rows(48)
    assert list(rows) == list(range(2, 23)) + list(range(25, 46))
    assert len(rows) == 42


def test_spawn_probabilities_match_the_protocol():
    golden = {3: 0.0504, 4: 0.0055, 5: 4.7e-4, 6: 3.3e-5, 7: 2.1e-6}
    for length, p in golden.items():
        assert spawn_probability(length, 6) == pytest.approx(p, rel=0.02)
    assert spawn_probability(3, 0) == 0.0


@pytest.mark.parametrize(
    ("kwargs", "names"),
    [
        (dict(level=-1), ["level=-1", "[0, 100]"]),
        (dict(agent_speed=0), ["agent_speed=0", "(0.0, 8.0]"]),
        (dict(agent_speed=-0.5), ["agent_speed=-0.5"]),
        (dict(goal_speed=0.0), ["goal_speed=0.0"]),
        (dict(height=10), ["height=10", "[11, 1024]"]),
        (dict(width=12), ["width=12", "[13, 1024]"]),
        (dict(width="wide"), ["width='wide'"]),
        (dict(colour=3), ["unknown key 'colour'", "height, width, level, agent_speed, goal_speed"]),
    ],
)
def test_bad_values_name_the_field_and_range(kwargs, names):
    with pytest.raises(ConfigError) as err:
        RoadConfig(**kwargs)
    message = str(err.value)
    assert message.startswith("RoadConfig: ")
    assert "\n" not in message
    for name in names:
        assert name in message


def test_round_trips_through_a_plain_dict():
    cfg = RoadConfig(level=3, agent_speed=0.5)
    assert RoadConfig.from_dict(cfg.model_dump()) == cfg
    assert RoadConfig.from_dict({"level": 3}, agent_speed=0.5) == cfg
    with pytest.raises(ConfigError, match="unknown key 'speed'"):
        RoadConfig.from_dict({"speed": 1})


def test_config_is_frozen():
    with pytest.raises(Exception, match="frozen"):
        RoadConfig().level = 3
