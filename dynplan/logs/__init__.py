"""Episode logs: one MCAP file per episode with Foxglove protobuf schemas (see `format`)."""

from dynplan.logs.format import AgentTrack
from dynplan.logs.reader import EpisodeLog, LogError, LogListing, inspect_log, read_episode_log
from dynplan.logs.writer import write_episode_log

__all__ = ["AgentTrack", "EpisodeLog", "LogError", "LogListing", "inspect_log", "read_episode_log", "write_episode_log"]
