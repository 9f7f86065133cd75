"""The GUI's logic without Qt: the bench session and its device worker, device kinds, the
live camera and run data, plan forms, faults, analyses and the log. Tested without Qt;
an import contract keeps Qt out (``pyproject.toml``)."""
