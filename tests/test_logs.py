"""Episode logs: round trips, self-description through embedded schemas, and clear errors for bad files."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import register_schema

from dynplan.env import RoadConfig, generate_world
from dynplan.logs import AgentTrack, LogError, inspect_log, read_episode_log, write_episode_log
from dynplan.logs.format import EPOCH_NS, FRAME_PERIOD_NS, METADATA_NAME, TOPIC_FRAME


@pytest.fixture(scope="module")
def world():
    return generate_world(RoadConfig(agent_speed=0.5), 12)


@pytest.fixture
def log_file(tmp_path, world):
    return write_episode_log(tmp_path / "episode.mcap", world)


def test_round_trip_is_bit_exact(log_file, world):
    log = read_episode_log(log_file)
    np.testing.assert_array_equal(log.frames, world.frames)
    np.testing.assert_array_equal(log.goal, world.goal)
    np.testing.assert_array_equal(log.agent_start, world.agent_start)
    assert (log.seed, log.n_frames, log.config) == (12, 407, world.config)
    assert log.agent is None
    replay = log.world(RoadConfig(agent_speed=1.0))
    assert replay.config.max_steps == 203 and replay.frames.shape == (407, 48, 48)


def test_logs_are_byte_reproducible(tmp_path, world):
    a = write_episode_log(tmp_path / "a.mcap", world).read_bytes()
    b = write_episode_log(tmp_path / "b.mcap", generate_world(RoadConfig(agent_speed=0.5), 12)).read_bytes()
    assert a == b


def test_prefix_of_frames(tmp_path, world):
    log = read_episode_log(write_episode_log(tmp_path / "short.mcap", world, n_frames=203))
    np.testing.assert_array_equal(log.frames, world.frames[:203])
    with pytest.raises(ValueError, match=r"n_frames must be in \[1, 407\]"):
        write_episode_log(tmp_path / "bad.mcap", world, n_frames=500)


def test_agent_track_round_trip(tmp_path, world):
    track = AgentTrack(
        t=np.array([4, 5, 6, 7]),
        position=np.array([[0.0, 10.0], [0.5, 10.0], [1.0, 10.0], [1.5, 10.5]]),
        action=np.array([6, 6, 5]),
        reward=np.array([0.0, 0.0, -20.0]),
        outcome=("running", "running", "death"),
    )
    log = read_episode_log(write_episode_log(tmp_path / "agent.mcap", world, agent=track))
    for name in ("t", "position", "action", "reward"):
        np.testing.assert_array_equal(getattr(log.agent, name), getattr(track, name))
    assert log.agent.outcome == track.outcome
    assert log.metadata["kind"] == "agent"
    with pytest.raises(ValueError, match="AgentTrack"):
        AgentTrack(np.array([4, 5]), np.zeros((2, 2)), np.array([1, 2]), np.zeros(1), ("running",))


def test_opens_with_plain_mcap_using_only_embedded_schemas(log_file, world, tmp_path):
    """A reader with no dynplan (and no compiled Foxglove classes) decodes the log from the file alone."""
    expected = tmp_path / "expected.npy"
    np.save(expected, world.frames)
    script = textwrap.dedent(f"""
        import json, sys
        import numpy as np
        from mcap.reader import make_reader
        from mcap_protobuf.decoder import DecoderFactory
        with open({str(log_file)!r}, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            meta = {{m.name: dict(m.metadata) for m in reader.iter_metadata()}}
            frames, stamps = [], []
            for schema, channel, message, image in reader.iter_decoded_messages(topics=["/world/frame"]):
                assert schema.name == "foxglove.RawImage" and image.encoding == "mono8"
                assert image.timestamp.seconds * 10**9 + image.timestamp.nanos == message.log_time
                frames.append(np.frombuffer(image.data, np.uint8).reshape(image.height, image.width)[::-1])
                stamps.append(message.log_time)
        assert np.array_equal(np.stack(frames), np.load({str(expected)!r}))
        assert np.all(np.diff(stamps) == {FRAME_PERIOD_NS}) and stamps[0] == {EPOCH_NS}
        loaded = [m for m in sys.modules if m.startswith(("dynplan", "foxglove_schemas_protobuf"))]
        print(json.dumps({{"meta": meta, "loaded": loaded}}))
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["loaded"] == []
    assert out["meta"][METADATA_NAME]["seed"] == "12" and out["meta"][METADATA_NAME]["n_frames"] == "407"


def test_missing_empty_and_non_mcap_files(tmp_path):
    with pytest.raises(LogError, match="nope.mcap: no such file"):
        read_episode_log(tmp_path / "nope.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(LogError, match=r"empty.mcap: empty file \(0 bytes\)"):
        read_episode_log(tmp_path / "empty.mcap")
    (tmp_path / "notes.mcap").write_text("just some text, not a log")
    with pytest.raises(LogError, match="notes.mcap: not an MCAP file"):
        read_episode_log(tmp_path / "notes.mcap")


def test_truncated_log_names_the_file_and_lists_what_is_intact(tmp_path, log_file):
    data = log_file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(LogError) as error:
        read_episode_log(cut)
    message = str(error.value)
    assert message.startswith(f"{cut}: truncated or corrupt")
    assert "/world/frame (foxglove.RawImage) ×" in message
    listing = inspect_log(cut)
    assert not listing.complete
    schema, count = listing.topics["/world/frame"]
    assert schema == "foxglove.RawImage" and 100 < count < 407
    assert listing.metadata[METADATA_NAME]["seed"] == "12"


def test_corrupt_bytes_never_read_back_silently(tmp_path, log_file, world):
    """Flip 8 bytes at positions across the file: each read either fails naming the file or is still exact
    (bytes of indexes the stream reader does not need)."""
    data = log_file.read_bytes()
    bad = tmp_path / "flipped.mcap"
    detected = 0
    for position in range(0, len(data), 499):
        corrupt = bytearray(data)
        corrupt[position : position + 8] = bytes(b ^ 0xFF for b in corrupt[position : position + 8])
        bad.write_bytes(bytes(corrupt))
        try:
            log = read_episode_log(bad)
        except LogError as error:
            assert str(error).startswith(f"{bad}: ")
            detected += 1
        else:
            np.testing.assert_array_equal(log.frames, world.frames)
            np.testing.assert_array_equal(log.goal, world.goal)
    assert detected > len(data) // 499 // 2


def _foreign_mcap(path, topic=TOPIC_FRAME, metadata=True):
    with open(path, "wb") as stream:
        writer = McapWriter(stream)
        writer.start()
        schema = register_schema(writer, CompressedImage)
        channel = writer.register_channel(topic, "protobuf", schema)
        if metadata:
            writer.add_metadata(METADATA_NAME, {"format": "dynplan.episode", "format_version": "1",
                                                "config": "{}", "seed": "0", "n_frames": "1", "height": "48",
                                                "width": "48", "agent_start": "[0, 10]"})  # fmt: skip
        writer.add_message(channel, 0, CompressedImage(format="png").SerializeToString(), 0)
        writer.finish()
    return path


def test_wrong_schema_and_foreign_logs(tmp_path):
    with pytest.raises(LogError, match="other.mcap: no 'dynplan' metadata; not a dynplan episode log"):
        read_episode_log(_foreign_mcap(tmp_path / "other.mcap", metadata=False))
    with pytest.raises(LogError, match=r"schema.mcap: topic /world/frame has schema 'foxglove.CompressedImage', "):
        read_episode_log(_foreign_mcap(tmp_path / "schema.mcap"))
    with pytest.raises(LogError, match="topic.mcap: no /world/frame topic"):
        read_episode_log(_foreign_mcap(tmp_path / "topic.mcap", topic="/camera"))
