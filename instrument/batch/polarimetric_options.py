"""The polarimetric fit's options of ``scatterlab fit`` and ``scatterlab batch fit``: which
polarimeter calibration, the pBRDF start values, the parameters held and the facet
distribution.

They are parsed once, from the command line, into plain JSON-able data
(:func:`polarimetric_fit_options`; a batch sends them to its worker processes and records
them) and resolved per run (:func:`fit_keywords`): a calibration NAME is a file in the
``calibrations/`` folder beside *each* run, so runs of several folders each use their own
folder's file of that name. The calibration is chosen per polarimeter mode (ADR 0114,
amendment): ``--calibration NAME`` applies to runs of both modes, and a run of the mode
the file does not calibrate is refused by name; ``--calibration drr=NAME --calibration
pem=NAME`` gives each mode its own, the mode not named keeping its default.
:func:`check_runs` resolves and loads the calibration for every polarimetric run of a
batch before anything is analysed, so that a wrong name, bench or mode stops the batch
with nothing written.

Scalar runs do not take these options (:func:`given` lists those set, for the one line
``scatterlab batch fit`` prints when the batch holds scalar runs too).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from analysis.polarimetry.pbrdf import PBRDF_BOUNDS, PBRDF_PARAMS
from instrument.pipelines.polarimetry.calibration import (
    CalibrationError,
    calibration_folder,
    load_calibration,
)

__all__ = ["DISTRIBUTIONS", "MODES", "BatchRuns", "PolarimetricOptionError", "batch_notes",
           "calibration_choice", "calibration_choices", "check_runs", "fit_keywords",
           "given", "is_pem", "mode_choice", "parse_fixed", "parse_start",
           "polarimetric_fit_options", "resolve_calibration", "run_mode"]

#: The facet-slope distributions of the pBRDF (``--distribution``).
DISTRIBUTIONS = ("beckmann", "ggx")
#: The option names as on the command line, by key of the plain options.
#: The polarimeter modes a calibration is chosen for (``--calibration MODE=...``), in words.
MODES = {"drr": "dual-rotating-retarder", "pem": "PEM"}
OPTION_NAMES = {"calibration": "--calibration", "start": "--pbrdf-start",
                "fixed": "--pbrdf-fixed", "distribution": "--distribution"}


class PolarimetricOptionError(ValueError):
    """A polarimetric fit option that cannot be used: ``option`` names it as on the command
    line and ``parameter`` the pBRDF parameter at fault (None when it is not one)."""

    def __init__(self, option: str, message: str, parameter: str | None = None) -> None:
        super().__init__(f"{option}: {message}")
        self.option = option
        self.parameter = parameter


def _default_start() -> tuple[float, ...]:
    from instrument.pipelines.polarimetry.pipeline import DEFAULT_START

    return DEFAULT_START


def parse_start(text: str | None) -> list[float] | None:
    """``--pbrdf-start``: four or five numbers ``n,k,alpha,albedo[,frame_deg]``, or
    ``name=value`` pairs (``alpha=0.3,albedo=0.05``) that change only those parameters of
    the default start (:data:`instrument.pipelines.polarimetry.pipeline.DEFAULT_START`).
    None: the default.

    Raises
    ------
    PolarimetricOptionError
        Not numbers, an unknown parameter name, a parameter given twice, a non-finite
        value or one outside the parameter's bounds (the parameter named).
    """
    if text is None:
        return None
    opt = OPTION_NAMES["start"]
    parts = [p.strip() for p in str(text).split(",") if p.strip()]
    keyed = [p for p in parts if "=" in p]
    if not parts or (keyed and len(keyed) != len(parts)):
        raise PolarimetricOptionError(opt, "give four or five numbers n,k,alpha,albedo"
                                      "[,frame_deg] or name=value pairs (e.g. alpha=0.3), "
                                      f"not both; got {text!r}")
    values = list(_default_start())
    if keyed:
        seen: set[str] = set()
        for part in keyed:
            name, _, raw = (s.strip() for s in part.partition("="))
            if name not in PBRDF_PARAMS:
                raise PolarimetricOptionError(opt, f"no pBRDF parameter {name!r}; the "
                                              f"parameters are {', '.join(PBRDF_PARAMS)}",
                                              name)
            if name in seen:
                raise PolarimetricOptionError(opt, f"{name} is given twice", name)
            seen.add(name)
            values[PBRDF_PARAMS.index(name)] = _number(opt, name, raw)
    else:
        if len(parts) not in (4, 5):
            raise PolarimetricOptionError(opt, "give four or five numbers n,k,alpha,albedo"
                                          f"[,frame_deg], got {len(parts)}: {text!r}")
        values = [_number(opt, name, raw) for name, raw in zip(PBRDF_PARAMS, parts,
                                                                strict=False)]
        if len(values) == 4:
            values.append(0.0)  # the frame at the polarimeter's own, as the fit takes it
    for name, v in zip(PBRDF_PARAMS, values, strict=True):
        lo, hi = PBRDF_BOUNDS[name]
        if not lo <= v <= hi:
            raise PolarimetricOptionError(opt, f"{name} = {v:g} is outside the fit's "
                                          f"bounds [{lo:g}, {hi:g}]", name)
    return values


def _number(option: str, name: str, raw: str) -> float:
    try:
        v = float(raw)
    except ValueError:
        raise PolarimetricOptionError(option, f"{name} must be a number, got {raw!r}",
                                      name) from None
    if not math.isfinite(v):
        raise PolarimetricOptionError(option, f"{name} must be finite, got {raw!r}", name)
    return v


def parse_fixed(text: str | None) -> list[str] | None:
    """``--pbrdf-fixed``: comma-separated pBRDF parameter names ('' holds none and fits
    all five); None: the variant the data need.

    Raises
    ------
    PolarimetricOptionError
        An unknown name (named).
    """
    if text is None:
        return None
    names = [n.strip() for n in str(text).split(",") if n.strip()]
    for n in names:
        if n not in PBRDF_PARAMS:
            raise PolarimetricOptionError(OPTION_NAMES["fixed"], f"no pBRDF parameter "
                                          f"{n!r}; the parameters are "
                                          f"{', '.join(PBRDF_PARAMS)}", n)
    return list(dict.fromkeys(names))


def calibration_choice(text: str | None) -> str | None:
    """``--calibration``: None (the newest valid calibration of the run's bench beside each
    run), ``"none"`` (the nominal optics), a file (made absolute, for worker processes in
    other folders) or a NAME of a file in ``calibrations/`` beside each run (kept as
    given). A value with a folder in it, or naming a file that exists here, is a file.

    Raises
    ------
    PolarimetricOptionError
        A file path that does not exist.
    """
    if text is None or text == "none":
        return text
    p = Path(text)
    if p.is_file():
        return str(p.resolve())
    if len(p.parts) > 1 or p.is_absolute():
        raise PolarimetricOptionError(OPTION_NAMES["calibration"], f"no such file {text}; "
                                      "give a calibration file, the name of one in "
                                      "calibrations/ beside the runs, or 'none'")
    return text


def calibration_choices(values: str | Sequence[str] | Mapping[str, Any] | None
                        ) -> dict[str, str | None]:
    """``--calibration``, given once or more, as the choice per polarimeter mode
    (:data:`MODES`), each as :func:`calibration_choice` makes it. A plain value applies to
    both modes; ``drr=VALUE`` or ``pem=VALUE`` to that mode only, over a plain value; a
    mode given nothing keeps the default (None: the newest valid calibration of the run's
    bench and mode). A mapping by mode (the plain data again) is taken as it is.

    A value that names an existing file is that file even with ``=`` in its name.

    Raises
    ------
    PolarimetricOptionError
        A value given twice for one mode, a mode other than ``drr`` or ``pem`` before
        ``=``, or a file that does not exist.
    """
    if isinstance(values, Mapping):
        unknown = sorted(set(values) - set(MODES))
        if unknown:
            raise PolarimetricOptionError(OPTION_NAMES["calibration"], f"no polarimeter "
                                          f"mode {unknown[0]!r}; the modes are "
                                          f"{', '.join(MODES)}")
        # already plain data (a worker's, or a recorded batch's): files were made absolute
        return {m: None if values.get(m) is None else str(values[m]) for m in MODES}
    texts = [values] if isinstance(values, str) else list(values or [])
    plain: list[str] = []
    keyed: dict[str, str] = {}
    opt = OPTION_NAMES["calibration"]
    for text in texts:
        mode, sep, rest = str(text).partition("=")
        if not sep or Path(text).is_file():
            plain.append(str(text))
            continue
        if mode not in MODES:
            raise PolarimetricOptionError(opt, f"{text!r}: before '=' give the polarimeter "
                                          f"mode ({' or '.join(MODES)}), e.g. drr=lab-a")
        if mode in keyed:
            raise PolarimetricOptionError(opt, f"the {mode} calibration is given twice "
                                          f"({keyed[mode]!r} and {rest!r})")
        keyed[mode] = rest
    if len(plain) > 1:
        raise PolarimetricOptionError(opt, f"{len(plain)} calibrations for every mode "
                                      f"({', '.join(map(repr, plain))}): give one, or one "
                                      "per mode as drr=NAME and pem=NAME")
    both = calibration_choice(plain[0]) if plain else None
    return {m: calibration_choice(keyed[m]) if m in keyed else both for m in MODES}


def polarimetric_fit_options(calibration: str | Sequence[str] | Mapping[str, Any] | None
                             = None, start: str | None = None,
                             fixed: str | None = None, distribution: str = "beckmann"
                             ) -> dict[str, Any]:
    """The options as plain data from their command-line text (module docstring); the
    calibration as the choice per mode (:func:`calibration_choices`).

    Raises
    ------
    PolarimetricOptionError
        An option that cannot be used (named, with the pBRDF parameter at fault).
    """
    if distribution not in DISTRIBUTIONS:
        raise PolarimetricOptionError(OPTION_NAMES["distribution"], f"one of "
                                      f"{', '.join(DISTRIBUTIONS)}, got {distribution!r}")
    return {"calibration": calibration_choices(calibration), "start": parse_start(start),
            "fixed": parse_fixed(fixed), "distribution": distribution}


def options_from_arguments(args: Any) -> dict[str, Any]:
    """The polarimetric fit's options from parsed command-line arguments (``scatterlab fit``
    and ``scatterlab batch fit`` share them): :func:`polarimetric_fit_options` of
    ``--calibration``, ``--pbrdf-start``, ``--pbrdf-fixed`` and ``--distribution``.

    Raises
    ------
    PolarimetricOptionError
        An option that cannot be used (named, with the pBRDF parameter at fault).
    """
    return polarimetric_fit_options(getattr(args, "calibration", None),
                                    getattr(args, "pbrdf_start", None),
                                    getattr(args, "pbrdf_fixed", None),
                                    getattr(args, "distribution", "beckmann"))


def given(options: Mapping[str, Any] | None) -> list[str]:
    """The options set to other than their defaults, as on the command line."""
    defaults = polarimetric_fit_options()
    return [OPTION_NAMES[k] for k in OPTION_NAMES
            if (options or {}).get(k, defaults[k]) != defaults[k]]


def resolve_calibration(run_path: str | Path, choice: str | None) -> str | None:
    """The calibration argument of
    :func:`instrument.pipelines.polarimetry.pipeline.fit_polarimetric_run` for one run:
    None, ``"none"`` and files as they are; a NAME the file ``NAME`` (or ``NAME.json``) in
    ``calibrations/`` beside the run.

    Raises
    ------
    CalibrationError
        No calibration of that name beside the run (the folder and what it holds named).
    """
    if choice is None or choice == "none" or Path(choice).is_absolute():
        return choice
    folder = calibration_folder(Path(run_path).resolve().parent)
    for name in (choice, f"{choice}.json"):
        if (folder / name).is_file():
            return str(folder / name)
    there = sorted(p.name for p in folder.glob("*.json")) if folder.is_dir() else []
    held = (f"it holds {', '.join(there)}" if there else "it holds no calibration"
            if folder.is_dir() else "there is no such folder")
    raise CalibrationError(f"--calibration {choice}: no polarimeter calibration of that "
                           f"name in {folder} beside run {Path(run_path).name} ({held}); "
                           "give a calibration file, a name from that folder, or 'none'")


def run_mode(run_path: str | Path) -> str:
    """The polarimeter mode of a polarimetric run's plan: ``"pem"`` or ``"drr"``."""
    from instrument.run.runfile import read_run

    return "pem" if (read_run(run_path).plan().polarimetry or {}).get("mode") == "pem" \
        else "drr"


def is_pem(run_path: str | Path) -> bool:
    """Whether the run's plan is a PEM plan (reduced with a PEM calibration or its nominal
    train, never a dual rotating retarder's calibration)."""
    return run_mode(run_path) == "pem"


def mode_choice(run_path: str | Path, options: Mapping[str, Any] | None) -> str | None:
    """The calibration choice (as :func:`calibration_choice` makes it) for the run's mode;
    the run file is read only when the two modes' choices differ."""
    choices = calibration_choices((options or {}).get("calibration"))
    if choices["drr"] == choices["pem"]:
        return choices["drr"]
    return choices[run_mode(run_path)]


def fit_keywords(run_path: str | Path, options: Mapping[str, Any] | None
                 ) -> dict[str, Any]:
    """Keyword arguments of :func:`~instrument.pipelines.polarimetry.pipeline.
    fit_polarimetric_run` for one run from the plain options (None or missing keys: the
    defaults): the calibration chosen for the run's mode, a NAME resolved beside the run.
    A calibration of the other mode is passed on: the pipeline refuses it by name."""
    o = {**polarimetric_fit_options(), **(options or {})}
    start = _default_start() if o["start"] is None else tuple(float(v) for v in o["start"])
    return {"calibration": resolve_calibration(run_path, mode_choice(run_path, o)),
            "start": start, "fixed": None if o["fixed"] is None else tuple(o["fixed"]),
            "distribution": str(o["distribution"])}


@dataclass(frozen=True)
class BatchRuns:
    """A batch's runs by kind: ``polarimetric`` (DRR and PEM), of which ``pem``, and
    ``scalar``."""

    polarimetric: list[Path]
    pem: list[Path]
    scalar: list[Path]


def check_runs(runs: Iterable[str | Path], options: Mapping[str, Any] | None) -> BatchRuns:
    """The runs by kind; for each polarimetric run the calibration chosen for its mode is
    resolved, read and checked to be of the run's bench and mode, before any run is
    analysed.

    Raises
    ------
    CalibrationError
        A calibration name or file that cannot be used with one or more of the runs: every
        such run named (up to five), with what to give instead.
    """
    from instrument.pipelines.polarimetry.readings import is_polarimetric
    from instrument.run.runfile import read_run

    out = BatchRuns([], [], [])
    choices = calibration_choices((options or {}).get("calibration"))
    loaded: dict[str, Any] = {}
    refused: list[str] = []
    for run in map(Path, runs):
        data = None
        try:
            pol = is_polarimetric(run)
            if pol:  # one read gives the plan's mode and the bench
                data = read_run(run)
            pem = data is not None and (data.plan().polarimetry or {}).get("mode") == "pem"
        except (OSError, KeyError, ValueError):
            pol = pem = False  # the analysis reports the run file's problem in its words
        (out.polarimetric if pol else out.scalar).append(run)
        if pem:
            out.pem.append(run)
        mode = "pem" if pem else "drr"
        choice = choices[mode]
        if not pol or choice is None or choice == "none":
            continue
        try:
            path = resolve_calibration(run, choice)
            assert path is not None
            cal = loaded.get(path) or load_calibration(path)
        except CalibrationError as err:
            refused.append(str(err))
            continue
        loaded[path] = cal
        assert data is not None
        bench = str(data.profile().get("bench", {}).get("name", ""))
        if cal.mode != mode:  # first: the mode says what to give instead
            refused.append(f"--calibration {choice}: {path} calibrates a {MODES[cal.mode]} "
                           f"polarimeter, run {run.name} is a {MODES[mode]} run; give one "
                           f"calibration per mode (--calibration {cal.mode}={choice} "
                           f"--calibration {mode}=NAME, or {mode}=none for its nominal "
                           "train)")
        elif cal.bench != bench:
            refused.append(f"--calibration {choice}: {path} calibrates bench {cal.bench!r}, "
                           f"run {run.name} was taken on {bench!r}")
    if refused:
        more = f"\n… and {len(refused) - 5} more run(s)" if len(refused) > 5 else ""
        raise CalibrationError("\n".join(refused[:5]) + more)
    return out


def batch_notes(runs: BatchRuns, options: Mapping[str, Any] | None) -> list[str]:
    """What a batch says once about runs that do not take the options given: scalar runs
    take none of them."""
    notes = []
    set_here = given(options)
    if set_here and runs.scalar:
        n = len(runs.scalar)
        notes.append(f"note: {', '.join(set_here)} appl{'ies' if len(set_here) == 1 else 'y'}"
                     f" to polarimetric runs only; the {n} scalar run{'s' if n > 1 else ''} "
                     "of this batch " + ("are" if n > 1 else "is") + " fitted without "
                     + ("it" if len(set_here) == 1 else "them"))
    return notes
