"""reports/: REPORT.md, one CSV per report view and the figures, written from the warehouse's report
views (demoforge.schemas.reports declares every section, in report order; nothing here holds prose of
its own).

- :mod:`~demoforge.report.writer`: ``write_report``: the sections in report order, the run's provenance
  lines, the Prefect artifacts of a flow run.
- :mod:`~demoforge.report.reader`: :class:`ViewReader`, one run's reads of the catalog (each view once).
- :mod:`~demoforge.report.figures`: the figures the sections name (the synthetic takes, the keypoint
  plots, the data-scaling plot).
- :mod:`~demoforge.report.episode_pictures`: each task's episode database in pictures (trajectories,
  workspace coverage, success maps).
"""
