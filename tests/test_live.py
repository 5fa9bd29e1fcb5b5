"""The live view: a real Foxglove WebSocket server, a real WebSocket client (`websockets`) that connects, sees the
replay layout's channels advertised, subscribes and receives the episode's messages as it is planned."""

import asyncio
import json
import re
import struct
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from dynplan.evaluation.agent import AgentSpec
from dynplan.logs.format import TOPIC_FRAME, TOPIC_SEARCH, layout_topics

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

ROOT = Path(__file__).resolve().parents[1]


async def _watch(url: str, until: set[str], timeout: float = 60.0) -> tuple[set[str], dict[str, list[bytes]]]:
    """Connect to `url`, subscribe to every channel advertised, and collect messages per topic until each topic of
    `until` has one (or the server closes). Returns the advertised topics and the payloads."""
    received: dict[str, list[bytes]] = {}
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=timeout) as ws:
        topics: dict[int, str] = {}
        while not until <= set(topics.values()):
            message = json.loads(await asyncio.wait_for(ws.recv(), timeout))
            if message["op"] == "advertise":
                topics |= {channel["id"]: channel["topic"] for channel in message["channels"]}
        subscriptions = [{"id": i, "channelId": channel} for i, channel in enumerate(topics)]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        by_subscription = {i: topics[channel] for i, channel in enumerate(topics)}
        try:
            while not until <= set(received):
                data = await asyncio.wait_for(ws.recv(), timeout)
                if isinstance(data, bytes) and data[0] == 0x01:  # message data: subscription, log time, payload
                    subscription, _ = struct.unpack("<IQ", data[1:13])
                    received.setdefault(by_subscription[subscription], []).append(data[13:])
        except websockets.ConnectionClosed:
            pass
    return set(topics.values()), received


def _check(advertised: set[str], received: dict[str, list[bytes]]) -> None:
    assert layout_topics() <= advertised
    frame = RawImage.FromString(received[TOPIC_FRAME][0])
    assert (frame.width, frame.height, frame.encoding) == (48, 48, "mono8")
    row = json.loads(received[TOPIC_SEARCH][0])
    assert len(row["visits"]) == 8 and sum(row["visits"]) > 0


def test_the_live_view_serves_a_replay_as_it_is_planned(recorded_logs, tmp_path):
    from dynplan.evaluation.replay import replay
    from dynplan.logs.live import LiveView

    with LiveView(port=0) as view:
        done = []

        def play() -> None:
            view.wait_for_viewer(60)
            done.append(replay(recorded_logs / "episode_0000000000.mcap", AgentSpec(technique="oracle"),
                               out=tmp_path / "r.mcap", live=view, pace_s=0.01))  # fmt: skip

        player = threading.Thread(target=play)
        player.start()
        advertised, received = asyncio.run(_watch(view.url, layout_topics()))
        player.join(120)
    _check(advertised, received)
    assert done and done[0].outcome in ("goal", "death", "timeout")


@pytest.mark.slow
def test_flows_replay_live_serves_the_episode_to_a_client(recorded_logs, tmp_path):
    log, out = recorded_logs / "episode_0000000001.mcap", tmp_path / "r.mcap"
    command = [sys.executable, "-m", "flows.replay", str(log), "--live", "--live-port", "0", "--live-wait", "120",
               "--live-fps", "100", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if found := re.search(r"ws://127\.0\.0\.1:(\d+)", line):
                break
        else:
            pytest.fail("no live URL printed:\n" + "".join(lines))
        advertised, received = asyncio.run(_watch(found.group(0), layout_topics()))
        rest = proc.communicate(timeout=180)[0]
    finally:
        proc.kill()
    assert proc.returncode == 0, "".join(lines) + rest
    _check(advertised, received)
    assert out.exists()


def test_play_serves_every_step_live(monkeypatch):
    pytest.importorskip("pygame")
    from dynplan.logs.format import TOPIC_AGENT_STEP
    from dynplan.logs.live import LiveView
    from dynplan.worlds.road.play import build_state
    from flows.worlds import PlayOptions, play_window

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    state = build_state(seed=2_000_003, imagination=False)
    with LiveView(port=0) as view:

        def watched_play() -> None:
            view.wait_for_viewer(60)
            state.live = view
            play_window(state, PlayOptions(scale=2, fps=1000, watch=True, script=["f"] * 60))

        player = threading.Thread(target=watched_play)
        player.start()
        advertised, received = asyncio.run(_watch(view.url, {TOPIC_FRAME, TOPIC_SEARCH, TOPIC_AGENT_STEP}))
        player.join(120)
    _check(advertised, received)
    assert json.loads(received[TOPIC_AGENT_STEP][0])["t"] == 5  # the first step: frame 4 to 5
