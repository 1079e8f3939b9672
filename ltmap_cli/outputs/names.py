"""Fixed names of files ``ltmap replay`` writes in its output folder.

Which files a run wrote is the folder's manifest (``outputs.folder``): the run writes into a fresh
staging folder, so no name can be taken by an earlier run's file or a folder made by hand.
"""

from __future__ import annotations

# plots.write_summary_plots writes these into OUT/plots (name -> file)
PLOT_FILES = {name: f"{name}.png" for name in
              ("layer_history", "latency_boxes", "processing_latency", "map_events", "map_3d")}  # fmt: skip
