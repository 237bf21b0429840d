"""Ingest: read simulator logs (CSV, MCAP), map names, validate, store in the workspace."""
