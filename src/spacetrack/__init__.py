"""spacetrack: find and track moving space targets in camera video."""

__version__ = "0.1.0"
