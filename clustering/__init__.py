"""Clustering: drivers into styles, typical drivers and reference lines."""
