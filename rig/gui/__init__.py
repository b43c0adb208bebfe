"""The operator GUI (``nmsid gui``): PySide6 + pyqtgraph over the same engine as the
headless run.

Modules, one job each: ``main_window`` (assembles the panels; the Python API scripts use),
``session_controller`` (engine in a worker thread, operator commands), ``observer``
(engine thread -> queued Qt signals + live buffer), ``live_buffer`` (thread-safe rolling
window), ``safety_panel`` (E-STOP, interlock lights, trip banner, re-arm),
``setup_panel``, ``calibration_panel``, ``schedule_panel``, ``live_plots``,
``identification_panel``, ``results_panel``, ``event_log``, ``script`` (scripted runs),
``analysis_hooks`` (calls into ``analysis``), ``app`` (QApplication, ``run_gui``).

Importing this package imports no Qt; import the modules you need.
"""
