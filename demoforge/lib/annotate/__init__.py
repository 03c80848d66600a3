"""Annotating a recorded take: the task definition (named object keypoints, which arm acts on which
object), the ``annotations.json`` format and its atomic write, the automatic open/close suggestion
shown on the timeline, and the rule for when a take counts as annotated. Pure logic: the local web
page that uses it is served by :mod:`demoforge.runtime.annotate` (the page itself is ``page.html`` here).
"""

from demoforge.lib.annotate.model import (  # noqa: F401
    NOT_ANNOTATED, AnnotationStatus, annotation_status, build_annotations, mask_to_ranges, not_annotated_message,
    point_info, suggest_closed_ranges, write_annotations,
)
from demoforge.lib.takes.task_definition import (  # noqa: F401  (the task definition the page edits)
    SIDES, TaskDefinition, custom_task, library_task, load_task_file, parse_task_section, task_for_take,
)

__all__ = [
    "NOT_ANNOTATED", "SIDES", "AnnotationStatus", "TaskDefinition", "annotation_status", "build_annotations",
    "custom_task", "library_task", "load_task_file", "mask_to_ranges", "not_annotated_message",
    "parse_task_section", "point_info", "suggest_closed_ranges", "task_for_take", "write_annotations",
]
