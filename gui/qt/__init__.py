"""The GUI's Qt layer: the bridge from worker threads to signals, the main window, the
views and panels. It draws and forwards; the logic is in :mod:`gui.model`."""
