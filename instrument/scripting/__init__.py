"""Scans from Python scripts and notebooks: the objects behind the public facade of
:mod:`instrument` (``from instrument import open_bench, plans, open_run``).

The facade is small on purpose; what it returns is documented here and in the user guide
("Scripting scans in Python"). The modules behind it (``instrument.run``,
``instrument.pipelines``, …) stay free to change.
"""

from instrument.scripting.bench import DryRun, ScriptBench, open_bench

# connect (instrument.scripting.remote) is not imported here: it brings the HTTP client.
from instrument.scripting.handle import RunHandle, RunProgress, RunTimeout
from instrument.scripting.results import Run, fit, locate, open_run, reconstruct, spheres

__all__ = ["DryRun", "Run", "RunHandle", "RunProgress", "RunTimeout", "ScriptBench", "fit",
           "locate", "open_bench", "open_run", "reconstruct", "spheres"]
