"""Adaptive plans: the next points are decided from the data measured so far.

An adaptive plan is a small object with a *base* plan (its first points, a plan of any
in-plane kind: usually a coarse pass) and a method ``propose(history)`` that returns the
next points, or ``None`` (or nothing) when it is done. The engine runs the base plan's
points, then asks the plan; every proposed point is made into axis targets by the bench's
kinematics and checked by the same guard as any plan's (:mod:`instrument.bench.guard`).
A refused point is not measured and not an error: it is handed back to the plan in
``history.refused`` with the reason, at the next call. The accepted points are committed to
the run's journal before the first of them moves (ADR 0091) and measured; then the plan
is asked again.

**Determinism is the contract.** A resumed run rebuilds the plan from the description it
stored (:meth:`AdaptivePlan.describe`: a registered name, its parameters and a seed, see
:func:`register`), asks it again from the start with the stored measurements, checks that
it decides the same points it decided before the crash, and goes on from there. A plan
must therefore decide from ``history`` and its own seeded state only, never from the
clock or an unseeded random generator; the time it may spend is ``history.seconds``, the
estimate of the instrument's own time for the points so far (:meth:`Plan.estimate`),
which does not depend on how loaded the computer is.

Angles are the plan file's in-plane convention: θi ≥ 0 puts the source at φi = 0 (θi < 0
at 180°); θr > 0 is on the specular side of the normal (:mod:`instrument.plans.build`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, runtime_checkable

from instrument.bench import guard
from instrument.bench.kinematics import Angles, UnreachableError, kinematics_of
from instrument.plans.build import Plan, in_plane_angles
from instrument.plans.commands import ScanPoint
from instrument.plans.planfile import PlanSpec

__all__ = ["AdaptiveDriver", "AdaptivePlan", "AdaptiveReplayError", "History", "Measured",
           "Proposal", "Refused", "UnknownAdaptivePlan", "rebuild", "register",
           "signed_in_plane"]

#: Rounds in a row in which the guard refused every proposed point before the run stops
#: asking (a plan that keeps proposing the same unreachable points would never end).
MAX_REFUSED_ROUNDS = 3


@dataclass(frozen=True)
class Proposal:
    """One point a plan wants: in-plane signed angles in degrees."""

    theta_i: float
    theta_r: float
    label: str = "sample"


@dataclass(frozen=True)
class Measured:
    """One completed point as the plan sees it: signed in-plane angles read back from the
    axes (deg), the engine's signal (DN/µs, dark-subtracted), its σ when known (NaN
    otherwise) and whether it was measured (``ok``; False: skipped after a fault)."""

    index: int
    theta_i: float
    theta_r: float
    signal: float
    u_signal: float = math.nan
    ok: bool = True


@dataclass(frozen=True)
class Refused:
    """A proposed point the guard (or the bench's geometry) refused, and why."""

    proposal: Proposal
    reason: str


@dataclass(frozen=True)
class History:
    """What a plan is told at each call: every completed point in order, every refusal so
    far, and the instrument's estimated seconds for the points planned so far."""

    points: tuple[Measured, ...]
    refused: tuple[Refused, ...] = ()
    seconds: float = 0.0


@runtime_checkable
class AdaptivePlan(Protocol):
    """What the engine needs of an adaptive plan (module docstring)."""

    @property
    def base(self) -> PlanSpec:
        """The plan of the first points (measured before the first call)."""
        ...

    def describe(self) -> dict[str, Any]:
        """``{"name": <registered name>, "params": {...}, "seed": int}`` (JSON): what a
        resumed run rebuilds the plan from (:func:`rebuild`)."""
        ...

    def propose(self, history: History) -> Sequence[Proposal] | None:
        """The next points, or ``None``/empty when the plan is done."""
        ...


class UnknownAdaptivePlan(LookupError):
    """A run file names an adaptive plan this program does not know."""


class AdaptiveReplayError(RuntimeError):
    """On resume, the rebuilt plan decided other points than the run file holds."""


_REGISTRY: dict[str, Callable[..., AdaptivePlan]] = {}


def register(name: str) -> Callable[[Callable[..., AdaptivePlan]], Callable[..., AdaptivePlan]]:
    """Class decorator: ``rebuild`` makes plans stored under ``name`` with
    ``factory(seed=..., **params)``."""
    def deco(factory: Callable[..., AdaptivePlan]) -> Callable[..., AdaptivePlan]:
        _REGISTRY[name] = factory
        return factory
    return deco


def rebuild(description: str | dict[str, Any]) -> AdaptivePlan:
    """The plan a run file describes (:meth:`AdaptivePlan.describe`), among the plans
    registered so far (the runner imports the ones this package ships,
    :mod:`instrument.plans.adaptive_lobe`, before it asks).

    Raises
    ------
    UnknownAdaptivePlan
        Its name is not registered in this program: pass the plan object to resume
        (``bench.resume(path, adaptive=plan)``) after importing the module that defines it.
    """
    d = json.loads(description) if isinstance(description, str) else dict(description)
    name = d.get("name")
    if name not in _REGISTRY:
        raise UnknownAdaptivePlan(
            f"the run's adaptive plan {name!r} is not known here (known: "
            f"{', '.join(sorted(_REGISTRY)) or 'none'}); import the module that registers it, "
            "or pass the plan object to resume (bench.resume(path, adaptive=plan))")
    return _REGISTRY[name](seed=d.get("seed"), **d.get("params", {}))


def signed_in_plane(angles: Sequence[float]) -> tuple[float, float]:
    """(θi, θr) signed as in a plan file, from sample-frame (θi, φi, θr, φr) in degrees."""
    ti, pi, tr, pr = (float(a) for a in angles)
    sign_i = -1.0 if abs(((pi + 180.0) % 360.0) - 180.0) > 90.0 else 1.0
    opposite = abs(((pr - pi + 180.0) % 360.0) - 180.0) > 90.0
    return sign_i * ti, tr if opposite else -tr


# ------------------------------------------------------------------------------ driver
@dataclass
class _Decision:
    points: list[ScanPoint]
    rows: list[dict[str, Any]]
    record: dict[str, Any]


@dataclass
class AdaptiveDriver:
    """Runs an :class:`AdaptivePlan` for the engine: keeps the history, asks the plan,
    guards its points and turns them into the run's planned points.

    ``measured`` are the points a resumed run already holds and ``stored`` the journal's
    ``planned`` records; :meth:`replay` asks the rebuilt plan through them first.
    """

    plan: AdaptivePlan
    measured: list[Measured] = field(default_factory=list)
    refused: list[Refused] = field(default_factory=list)
    rounds: int = 0

    def observe(self, m: Measured) -> None:
        self.measured = [p for p in self.measured if p.index != m.index] + [m]

    def observe_point(self, index: int, angles: Sequence[float] | None, signal: float,
                      ok: bool) -> None:
        """A completed point from the engine (angles read back, NaN when unknown)."""
        ti, tr = (math.nan, math.nan) if angles is None else signed_in_plane(angles)
        self.observe(Measured(index, ti, tr, float(signal), math.nan, bool(ok)))

    def history(self, upto: int) -> History:
        pts = tuple(sorted((p for p in self.measured if p.index < upto),
                           key=lambda p: p.index))
        return History(pts, tuple(self.refused))

    def decide(self, plan: Plan) -> _Decision | None:
        """The next points after every point of ``plan`` (None: the plan is done)."""
        n = len(plan.points)
        refused_rounds = 0
        while True:
            hist = replace(self.history(n), seconds=plan.estimate().real_time_s)
            got = self.plan.propose(hist)
            self.rounds += 1
            if not got:
                return None
            points, rows, refused = self._guard(plan, list(got))
            self.refused.extend(refused)
            if points:
                return _Decision(points, rows, {
                    "round": self.rounds, "seconds": hist.seconds,
                    "refused": [[r.proposal.theta_i, r.proposal.theta_r, r.reason]
                                for r in refused]})
            refused_rounds += 1
            if refused_rounds >= MAX_REFUSED_ROUNDS:
                return None

    def replay(self, base: Plan, stored: list[dict[str, Any]]) -> None:
        """Ask the rebuilt plan again through the decisions a run file holds; each must
        come out the same (module docstring).

        Raises
        ------
        AdaptiveReplayError
            It decided differently: the plan is not deterministic for its seed, or the
            bench's limits changed since the run was made.
        """
        plan = base
        for rec in stored:
            first = int(rec["first"])
            if first != len(plan.points):
                raise AdaptiveReplayError(f"stored decision at point {first} does not "
                                          f"follow the {len(plan.points)} points before it")
            got = self.decide(plan)
            want = [(r["angles"], r["label"]) for r in rec["points"]]
            have = [(list(p.angles.as_tuple()) if p.angles else None, p.label)
                    for p in (got.points if got else [])]
            if len(want) != len(have) or any(
                    lw != lh or not all(math.isclose(a, b, abs_tol=1e-9)
                                        for a, b in zip(aw, ah or [], strict=False))
                    for (aw, lw), (ah, lh) in zip(want, have, strict=True)):
                raise AdaptiveReplayError(
                    f"resuming: the adaptive plan {self.plan.describe().get('name')!r} "
                    f"decided other points at point {first} than the run file holds "
                    f"({len(have)} against {len(want)} stored): it must decide from its "
                    "history and seed only")
            # got is None only if the stored decision was empty too; then this line raises
            # AttributeError (a known gap, left as is: fixing it changes behaviour)
            plan = replace(plan, points=plan.points + tuple(
                replace(p, index=first + k) for k, p in enumerate(got.points)))  # type: ignore[union-attr]

    def _guard(self, plan: Plan, props: list[Proposal]
               ) -> tuple[list[ScanPoint], list[dict[str, Any]], list[Refused]]:
        profile = plan.profile
        kin = kinematics_of(profile.geometry)
        limits = {r: d.limits for r, d in profile.axes.items() if d.limits is not None}
        first = len(plan.points)
        points: list[ScanPoint] = []
        refused: list[Refused] = []
        for prop in props:
            if not (math.isfinite(prop.theta_i) and math.isfinite(prop.theta_r)):
                refused.append(Refused(prop, "angles are not finite numbers"))
                continue
            a: Angles = in_plane_angles(float(prop.theta_i), float(prop.theta_r))
            try:
                pos = kin.positions(a, limits=limits)
            except UnreachableError as err:
                refused.append(Refused(prop, str(err)))
                continue
            targets = tuple((r, float(pos[r])) for r in kin.axes)
            if {r for r, _ in targets} - set(plan.axes):
                refused.append(Refused(prop, "moves an axis the run's plan does not"))
                continue
            p = ScanPoint(first + len(points), targets, a, str(prop.label))
            bad = guard.check([p], profile)
            if bad:
                refused.append(Refused(prop, "; ".join(v.detail for v in bad)))
                continue
            points.append(p)
        col = {r: k for k, r in enumerate(plan.axes)}
        rows = []
        for p in points:
            t = [math.nan] * len(plan.axes)
            for r, v in p.targets:
                t[col[r]] = v
            # a proposal's point has its angles (it was built from them above)
            rows.append({"targets": t, "angles": list(p.angles.as_tuple()),  # type: ignore[union-attr]
                         "label": p.label,
                         "light": True, "exposure_us": math.nan})
        return points, rows, refused
