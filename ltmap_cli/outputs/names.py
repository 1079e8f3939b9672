"""The fixed names ``ltmap replay`` writes in its output folder, checked before the run.

A folder where a file goes (``OUT/replay.mcap`` or ``OUT/map.pgm`` made by hand) or a file where
a folder goes (``OUT/plots``, ``OUT/snapshots``) would otherwise fail only when that output is
written, after the whole replay, naming a temporary file. ``check_replay_outputs`` refuses them
first, in one line that names the path.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import OutputError

MAP_SUFFIXES = (".pgm", ".yaml", ".png")  # what write_map writes per map
# plots.write_summary_plots writes these into OUT/plots (name -> file)
PLOT_FILES = {name: f"{name}.png" for name in
              ("layer_history", "latency_boxes", "processing_latency", "map_events", "map_3d")}  # fmt: skip


def replay_output_files(*, static: bool, mcap: bool, plots: bool, localize: bool = False) -> list[str]:
    """Paths, relative to the output folder, of the files a replay writes at fixed names."""
    stems = ["map", "long_term"] + (["static"] if static else [])
    names = [f"{stem}{suffix}" for stem in stems for suffix in MAP_SUFFIXES]
    names += ["events.csv", "report.json", "config.yaml"]
    if localize:
        names.append("localization.csv")
    if mcap:
        names.append("replay.mcap")
    if plots:
        names += [f"plots/{name}" for name in PLOT_FILES.values()]
    return names


def replay_output_folders(*, plots: bool) -> list[str]:
    """Folders a replay writes into or swaps in (``snapshots`` is replaced as a whole)."""
    return ["snapshots"] + (["plots"] if plots else [])


def check_replay_outputs(out_dir: str | os.PathLike, cfg, static: bool) -> None:
    """Raise ``OutputError`` if a fixed output name in ``out_dir`` is taken by the wrong kind of
    entry. ``cfg``: the run's ``Config`` (``replay.mcap_out``, ``replay.plots``); ``static``:
    whether a static map was given. A missing ``out_dir`` (or one that is not a folder: the
    -o check reports that) passes."""
    out = Path(out_dir)
    if not out.is_dir():
        return
    plots = bool(cfg.replay.plots)
    for name in replay_output_folders(plots=plots):
        p = out / name
        if p.exists() and not p.is_dir():
            raise OutputError(f"{p} is a file, where ltmap replay writes its folder {name}/; move or remove that "
                              "file, or choose another output folder (-o)")  # fmt: skip
    for name in replay_output_files(static=static, mcap=bool(cfg.replay.mcap_out), plots=plots,
                                    localize=bool(cfg.replay.localize)):
        p = out / name
        if p.is_dir():
            raise OutputError(f"{p} is a folder, where ltmap replay writes the file {name}; move or remove that "
                              "folder, or choose another output folder (-o)")  # fmt: skip
