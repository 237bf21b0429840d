"""A simulated study written as log files (`laneprint simulate`).

The studies themselves are simulated by `laneprint.simulator` (the base); writing them as
CSV and MCAP logs uses ingest's log writers, so it lives here, above the stages:
`output.write_study(study, out, fmt)` and `output.read_ground_truth(folder)`,
`sumo_output.write_sumo_study` and `highway_output.write_highway_study`. Nothing is
imported here, so the command line starts without the log writers.
"""
