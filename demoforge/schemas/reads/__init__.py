"""The warehouse's read layer: what stages, flows, the report, the command line and the scripts read from
the tables, each reader said once (the tables' contracts are the modules of schemas/, the stages that
write them live in tasks/).

- :mod:`~demoforge.schemas.reads.per_hand`: the per-(frame, hand) tables of one take as (T, 2, ...) arrays,
  and back.
- :mod:`~demoforge.schemas.reads.episodes`: a task database's episodes and steps: actions by episode id,
  the selections the exports write (:class:`EpisodeSelection`), the episodes a robot check passed, the
  source takes' cameras.
- :mod:`~demoforge.schemas.reads.demonstration`: an ingested take as the augmentation's DemoSource
  (gripper trajectory, object keypoints, segments).
"""
