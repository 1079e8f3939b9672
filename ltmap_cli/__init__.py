"""ltmap: replay robot logs through a layered long-term 3D map."""

__version__ = "0.1.0"
