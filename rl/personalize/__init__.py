"""Personalised agents: a new driver's first K decisions on top of what the rest of the workspace knows."""
