"""What Foxglove shows of a replay log: the shipped layout's topics all exist in a replay, the annotations sit on
the agent and the goals, and the search's statistics are the planner's own."""

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from dynplan.data.collect import record_episode
from dynplan.env.agent import ACTION_ANGLES_DEG
from dynplan.evaluation.agent import AgentSpec
from dynplan.evaluation.cases import EVAL_SEED_START
from dynplan.evaluation.replay import replay
from dynplan.logs import read_episode_log
from dynplan.logs.format import REPLAY_LAYOUT, layout_topics
from dynplan.logs.reader import inspect_log

PLAYOUTS = 20


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fox")
    log = record_episode(folder / "logs", EVAL_SEED_START).path
    out = folder / "replay.mcap"
    result = replay(log, AgentSpec(technique="oracle", rollout_steps=3, playouts=PLAYOUTS), out=out)
    return out, result


def messages(path, topic):
    """The decoded messages of a protobuf `topic`."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [decoded for _schema, _channel, _message, decoded in reader.iter_decoded_messages(topics=[topic])]


def json_rows(path, topic):
    """The parsed messages of a JSON `topic`."""
    with open(path, "rb") as f:
        return [json.loads(message.data) for _, _, message in make_reader(f).iter_messages(topics=[topic])]


def test_the_layouts_topics_all_exist_in_a_replay_log(replayed):
    out, _ = replayed
    topics = inspect_log(out).topics
    assert layout_topics() <= set(topics), layout_topics() - set(topics)
    assert topics["/world/annotations"][0] == "foxglove.ImageAnnotations"
    assert topics["/planner/search"][0] == "dynplan.Search"
    assert json.loads(REPLAY_LAYOUT.read_text())["layout"]  # a panel arrangement, not just configs


def test_annotations_sit_on_the_agent_and_the_goals(replayed):
    out, result = replayed
    log = read_episode_log(out)
    H = log.world().config.height
    marks = messages(out, "/world/annotations")
    assert len(marks) == len(log.agent.t) == result.steps + 1
    for i in (0, len(marks) // 2, len(marks) - 1):
        y, x = log.agent.position[i]
        circle = marks[i].circles[0]
        assert (circle.position.x, circle.position.y) == pytest.approx((x + 0.5, H - 0.5 - y))
        goal_y, goal_x = log.world().goal[int(log.agent.t[i])]
        corners = {(p.x, p.y) for p in marks[i].points[0].points}
        assert corners == {(goal_x, H - 2 - goal_y), (goal_x + 2, H - 2 - goal_y), (goal_x + 2, H - goal_y),
                           (goal_x, H - goal_y)}  # fmt: skip
    first = marks[0]
    arrow = first.points[-1].points  # the chosen action, from the agent along its heading
    angle = np.deg2rad(ACTION_ANGLES_DEG[log.agent.action[0]])
    assert (arrow[1].x - arrow[0].x, arrow[0].y - arrow[1].y) == pytest.approx((4 * np.cos(angle), 4 * np.sin(angle)))
    assert "action" in first.texts[0].text
    assert not marks[-1].texts  # the episode's last pose: no decision


def test_the_search_topic_holds_each_decisions_root(replayed):
    out, result = replayed
    log = read_episode_log(out)
    rows = json_rows(out, "/planner/search")
    assert len(rows) == result.steps
    assert [row["action"] for row in rows] == [int(a) for a in log.agent.action]
    for row in rows:
        assert sum(row["visits"]) >= PLAYOUTS - 1 and len(row["q"]) == len(row["prior"]) == 8  # the first expands
        assert sum(row["prior"]) == pytest.approx(1.0, abs=1e-5)  # rounded to 6 places
        assert "goal" not in row or set(row["goal"]) == {"x", "y"}
        assert row["search_ms"] > 0
    assert any("goal" in row for row in rows)
