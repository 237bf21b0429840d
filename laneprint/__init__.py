"""laneprint: driver-in-the-loop data pipeline for personalised automated lane changes.

This shared package holds what every stage uses: the command line (`cli`), the
workspace store (`workspace`), the table schemas (`schemas`), errors, progress
reporting, and the reference study's published numbers (`reference`).
"""

__version__ = "0.1.0"
