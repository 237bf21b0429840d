"""A synthetic driver-in-the-loop study: traffic scenes and a driver behaviour model."""
