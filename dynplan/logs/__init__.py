"""Episode logs: one MCAP file per episode with Foxglove protobuf schemas (see `format`)."""

from dynplan.lazy import lazy_names

#: Each public name by its module, imported when first used (`dynplan.lazy`).
_PUBLIC = {
    "AgentTrack": "dynplan.logs.format",
    "EpisodeLog": "dynplan.logs.reader",
    "LogError": "dynplan.logs.reader",
    "LogListing": "dynplan.logs.reader",
    "inspect_log": "dynplan.logs.reader",
    "read_episode_log": "dynplan.logs.reader",
    "write_episode_log": "dynplan.logs.writer",
}
__getattr__, __dir__ = lazy_names(__name__, _PUBLIC)
__all__ = sorted(_PUBLIC)
