"""Lowest layer, numpy only: the 36/18-state layouts, frame conversions, array types."""
