"""A minimal TOML writer for the fuzz tests: nested tables as ``[a.b]`` sections, values
as the plan builders write them (:func:`instrument.plans.scripted.toml_value`)."""

from __future__ import annotations

import json

from instrument.plans.scripted import toml_value as _scalar


def dumps(data: dict, prefix: str = "") -> str:
    lines = []
    tables = []
    for k, v in data.items():
        nested = isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values())
        if nested or (isinstance(v, dict) and not prefix):
            tables.append((k, v))
        else:
            lines.append(f"{json.dumps(k)} = {_scalar(v)}")
    out = "\n".join(lines) + "\n"
    for k, v in tables:
        name = f"{prefix}.{json.dumps(k)}" if prefix else json.dumps(k)
        out += f"\n[{name}]\n" + dumps(v, name)
    return out
