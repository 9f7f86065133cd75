"""Writing analysis results into a run file: NeXus groups under ``/entry/analysis``.

The pipelines (:mod:`instrument.pipelines`) store what they computed next to the data it
came from. These helpers are the one way they do it: a group is replaced whole (writing
again supersedes an earlier analysis), text goes in as variable-length UTF-8 strings,
and plain-data results as JSON that any HDF5 reader can parse.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from instrument.run.runfile import as_text

__all__ = ["RunStillRunning", "analysis_group", "jsonable", "open_for_results", "put",
           "put_json", "replace_group"]


class RunStillRunning(RuntimeError):
    """The run file is still being written by a run; analyse it when the run ends."""


def replace_group(parent: h5py.Group, name: str, nx_class: str) -> h5py.Group:
    """A new, empty group ``name`` of NeXus class ``nx_class`` (an existing one is deleted)."""
    if name in parent:
        del parent[name]
    g = parent.create_group(name)
    g.attrs["NX_class"] = nx_class
    return g


def analysis_group(f: h5py.File, name: str | None = None) -> h5py.Group:
    """``/entry/analysis`` (created if missing), or its sub-group ``name`` (an NXprocess,
    created if missing, kept if present)."""
    entry = f["entry"]
    if "analysis" not in entry:
        entry.create_group("analysis").attrs["NX_class"] = "NXcollection"
    g = entry["analysis"]
    if name is None:
        return g
    if name not in g:
        g.create_group(name).attrs["NX_class"] = "NXprocess"
    return g[name]


@contextlib.contextmanager
def open_for_results(path: str | Path) -> Iterator[h5py.File]:
    """The run file open for writing results; refused while a run is still writing it."""
    with h5py.File(path, "r+") as f:
        if as_text(f["entry"].attrs.get("status", "")) == "running":
            raise RunStillRunning(f"{path} is still being written; analyse it when the run "
                                  "ends")
        yield f


def jsonable(x: Any) -> Any:
    """``json.dumps`` default for numpy values (anything else becomes its ``str``)."""
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return str(x)


def put(g: h5py.Group, name: str, value: Any) -> h5py.Dataset:
    """A dataset ``name``: text as a UTF-8 string, anything else as an array."""
    if isinstance(value, str):
        return g.create_dataset(name, data=value, dtype=h5py.string_dtype())
    return g.create_dataset(name, data=np.asarray(value))


def put_json(g: h5py.Group, name: str, value: Any) -> h5py.Dataset:
    """``value`` (plain data, numpy allowed) as JSON text in dataset ``name``."""
    return put(g, name, json.dumps(value, default=jsonable))
