"""Prefect flows composing the stages; the CLI and the deployments call these."""
