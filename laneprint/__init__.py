"""laneprint: driver-in-the-loop data pipeline for personalised automated lane changes.

This shared package is the base every stage uses: the workspace store (`workspace`),
the table schemas (`schemas`), errors, locks, parallel workers, progress reporting, the
study simulator (`simulator`) and the reference study's published numbers (`reference`).
It imports no stage. The application above the stages (the command line, the end-to-end
run, the check) is `laneprint.app`; the layers are tested in `tests/laneprint/test_layers.py`.
"""

__version__ = "0.1.0"
