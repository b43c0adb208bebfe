"""Colours shared by the GUI's panels (one place, so the meaning of a colour is fixed)."""

from __future__ import annotations


class Colour:
    OK = "#1a9e3a"
    FAULT = "#d00000"
    WARN = "#e08000"
    UNKNOWN = "#9a9a9a"
    RUNNING = "#1f5fbf"
    FORCE = "#1f77b4"
    TARGET = "#ff7f0e"
    RE = "#6a3d9a"
    I_EXT = "#d62728"
    I_FLEX = "#2ca02c"
    #: Engine state -> badge colour.
    STATE = {
        "idle": "#777777",
        "calibrating": "#8a5a00",
        "armed": "#1f5fbf",
        "stimulating": "#1a9e3a",
        "resting": "#3a7a8a",
        "paused": "#e08000",
        "tripped": "#d00000",
        "finished": "#444444",
    }
    #: Trial status -> table row background.
    STATUS = {
        "pending": "#ffffff",
        "running": "#cfe2ff",
        "done": "#d8f0dc",
        "completed": "#d8f0dc",
        "aborted": "#f8d0d0",
        "skipped": "#eeeeee",
    }


#: Width of the plots' left axes, px: fixed, so a new tick label (a new trial's force
#: range) never re-lays out the plots (a layout change repaints every axis and grid,
#: ~25 ms each on a busy machine: bench/bench_gui_lag.py).
LEFT_AXIS_PX = 62
