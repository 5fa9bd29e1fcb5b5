"""dynplan's own worlds, one package each, registered under the entry points `dynplan.worlds` (pyproject.toml):
`road` (the default; its frames, agent and planner are `dynplan.env`, `dynplan.planning` and `dynplan.evaluation`)
and `freeway` (Atari Freeway). The registry and the interface they implement are `dynplan.world` and
`dynplan.world_parts`."""
