"""Run-time helpers of the flows and the CLI: which task runner executes a flow (threads or Dask),
the whole-run cache of `demoforge evaluate`, and the Prefect artifacts a run publishes."""
