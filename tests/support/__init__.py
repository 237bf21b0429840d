"""Test tools, out of the product packages: synthetic analysed workspaces for rl
(`rl_workspaces`), hostile mutations of logs for the ingest fuzzing (`ingest_mutations`),
the worked ROS 2 and protobuf stacks as MCAP files (`stack_examples`) and synthetic
decisions for the indicators and clustering (`synthetic_decisions`).

Tests import them as `tests.support.<module>` (pytest's `pythonpath` puts the checkout on
the path); benchmarks put the checkout on `sys.path` first.
"""
