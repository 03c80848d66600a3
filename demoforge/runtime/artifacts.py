"""Prefect UI artifacts shared by the flows."""

from __future__ import annotations


class ProgressArtifact:
    """A progress artifact in the Prefect UI, advanced one step of `total` at a time."""

    def __init__(self, key: str, total: int, description: str):
        from prefect.artifacts import create_progress_artifact

        self.total, self.done = max(int(total), 1), 0
        # artifact keys allow lowercase letters, digits and dashes only
        self.id = create_progress_artifact(0.0, key=key.lower().replace("_", "-"), description=description)

    def step(self) -> None:
        from prefect.artifacts import update_progress_artifact

        self.done += 1
        update_progress_artifact(self.id, min(100.0, 100.0 * self.done / self.total))
