"""What every single-run analysis command does around its pipeline (ADR 0013, ADR 0070).

:func:`writing_outputs` checks the run first (so a mistyped path creates no folder), then
holds the run's lock (:func:`instrument.run.results.run_lock`, the lock a batch task
takes), so ``scatterlab fit RUN`` and a ``scatterlab batch`` on the same run never write at
once, and clears the temporary files a killed writer left. Inside it the command runs its
pipeline and keeps the run's summary row next to ``results.h5``
(:func:`instrument.batch.analyses.keep_row`), as a batch task does, so a later batch with
the same options skips the run and still has its line of the table.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

__all__ = ["writing_outputs"]


@contextlib.contextmanager
def writing_outputs(run: str | Path, command: str, pipeline: str,
                    out: str | Path | None) -> Iterator[None]:
    """Check ``run`` for ``command`` and hold its lock (in ``out`` when the outputs go
    there) for the block.

    Raises
    ------
    RunFileError
        The run is missing, unreadable or of a kind ``command`` does not analyse.
    RunBusy
        Another analysis of the run held its lock too long.
    """
    from instrument.run.paths import results_dir
    from instrument.run.results import LOCK_WAIT_S, remove_stale_temporaries, run_lock
    from instrument.run.runfile import check_run_file

    check_run_file(run, command)

    def waiting(holder: str) -> None:  # said at once, not after the wait
        print(f"waiting: another analysis of {Path(run).name} ({holder}) is writing its "
              f"results; this one starts when it ends (at most {LOCK_WAIT_S:g} s)",
              flush=True)

    with run_lock(run, folder=out, what=f"scatterlab {command} {Path(run).name}",
                  on_wait=waiting):
        remove_stale_temporaries(out if out is not None else results_dir(run, pipeline))
        yield

