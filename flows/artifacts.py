"""Prefect artifacts of the flows: an evaluation's summary (the road's Table 1) as a table, the report as Markdown,
and progress while episodes play and models train — shown in the Prefect UI beside the runs that made them.

Table and report artifacts carry a stable key per preset or run (`table1-quick`, `report-quick`,
`table1-evaluation`; another world's summary `<its summary key>-<run>`), so successive runs form a history under one
key on the UI's Artifacts page. Progress artifacts belong to the flow or task run that creates them and are updated
in place. Prefect is imported when an artifact is first made or read, not with this module.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import TYPE_CHECKING
from uuid import UUID

if TYPE_CHECKING:
    from prefect.client.schemas.objects import Artifact


def artifact_key(kind: str, name: str) -> str:
    """`kind-name` in the only characters Prefect accepts in a key (lowercase letters, digits, dashes)."""
    key = re.sub(r"[^a-z0-9-]+", "-", f"{kind}-{name}".lower()).strip("-")
    return re.sub(r"-{2,}", "-", key)


def publish_summary(rows: Sequence[dict], key: str, description: str) -> UUID:
    """An evaluation's summary rows (the road's: Table 1's) as a table artifact keyed `key`, with the rendered
    summary as its description."""
    from prefect.artifacts import create_table_artifact

    return create_table_artifact(list(rows), key=key, description=description)


def publish_report(markdown: str, name: str) -> UUID:
    """The pipeline's report as a Markdown artifact keyed `report-<name>`."""
    from prefect.artifacts import create_markdown_artifact

    return create_markdown_artifact(markdown, key=artifact_key("report", name), description=f"report of {name!r}")


class ProgressArtifact:
    """A progress artifact of the current flow or task run: `advance()` once per finished unit of `total`, or
    `update(done)` with the units finished so far (a resumed run starts past zero)."""

    def __init__(self, description: str, total: int, done: int = 0):
        from prefect.artifacts import create_progress_artifact

        self.description, self.total, self.done = description, max(total, 1), min(done, max(total, 1))
        self.id = create_progress_artifact(self.percent, description=self._describe())

    @property
    def percent(self) -> float:
        return 100.0 * self.done / self.total

    def _describe(self) -> str:
        return f"{self.description}: {self.done} of {self.total}"

    def update(self, done: int) -> None:
        from prefect.artifacts import update_progress_artifact

        self.done = min(max(done, 0), self.total)
        update_progress_artifact(self.id, self.percent, description=self._describe())

    def advance(self, n: int = 1) -> None:
        self.update(self.done + n)


def read_artifacts(key: str | None = None, kind: str | None = None, limit: int = 200) -> list[Artifact]:
    """The current Prefect API's artifacts with `key` (every version) or of type `kind` ("table", "markdown",
    "progress"), oldest first."""
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import ArtifactFilter, ArtifactFilterKey, ArtifactFilterType
    from prefect.client.schemas.sorting import ArtifactSort

    found = ArtifactFilter(
        key=ArtifactFilterKey(any_=[key]) if key else None, type=ArtifactFilterType(any_=[kind]) if kind else None
    )
    with get_client(sync_client=True) as client:
        return client.read_artifacts(artifact_filter=found, sort=ArtifactSort.CREATED_DESC, limit=limit)[::-1]
