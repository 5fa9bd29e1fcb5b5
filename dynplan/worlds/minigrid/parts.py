"""MiniGrid's `WorldParts`: what it brings above its frames (each part added as it is built)."""

from __future__ import annotations

from dynplan.world_parts import WorldParts

PARTS = WorldParts()
