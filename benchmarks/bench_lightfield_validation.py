"""Localisation validation matrix: detection, false alarms, position errors, confident errors.

Scenes rendered by the continuous renderer (``hw_mocks.sim.lightfield_scene``: exact disc
geometry, quadrature over the BRDF) behind 200 mm of wall at d2 = 100 mm, with seeded
Gaussian noise of a fixed level (2·10⁻⁴; a 3 mm disc of radiance 1 gives a measured
radiance of ≈ 0.1–0.4), reconstructed (Wiener, noise from the data) and located with the
reconstruction's noise model at the default false-alarm probability (0.01 per scan), the
depth range widened while an object sits at its far edge
(:func:`analysis.lightfield.detect_widening`).  A scene's noise-free render depends only on
wall and scene, so it is made once and every seed adds its own noise to it (``--cache DIR``
keeps the renders between runs).

Matrix: walls from matte to a near mirror (the four built-in materials, then the brushed
metal's lobe narrowed to 0.5°, 0.1° and 0.01°) × scenes: none (false alarms); one object
inside the default range (−400 … −60 mm) at −200 and −100 mm; one beyond it (−600 mm); two
at 0.5, 1 and 2 transverse blurs apart at equal brightness (the blur of that wall: from a
one-object reconstruction's p̂); two 40 mm apart at brightness ratios 10, 100 and 1000;
three objects (brightness 1, 0.3, 0.1) 40 mm apart at three depths.  Each scene × wall ×
seed is scored (:func:`score`):

* detected — a true object with a reported object within δy (plus its extent) across whose
  depth interval holds it (a blend of a sub-resolution pair counts for both);
* position within blur — a detected object within δy across and δz in depth;
* phantom — a reported object that explains no true object; a false alarm per scan — a
  scan with at least one phantom;
* confidently wrong — a reported object marked "resolved" that is a phantom, a split (a
  second reported object explaining the same true object), has a brightness ≤ 0 (wrong
  sign), or lies over a true object (within δy across) with an interval excluding its
  depth (excluded truth), or explains a true object but lies outside its blur (off blur);
  and a true object missing without a word (neither reported nor among the candidates
  examined below the threshold: missed silently; of those, the ones whose significance at
  the true position, the search taken out, is under the threshold are counted as below
  the detection limit, :func:`truth_significance`, and are not counted as confidently
  wrong: behind the matte paper the bright disc's model mismatch alone puts an amplitude
  of 1.4–3.4·10⁻⁴ at the dim disc's position — 10–17 % of what it leaks there, 1–2.4×
  the 100× dimmer disc's own 1.45·10⁻⁴ — so a dim object that faint is indistinguishable
  from that artefact, which is what the leak share of the significance says).  Each kind
  is counted separately;
* false alarms per scan on the empty scene, per wall and in all, with the 95 %
  Clopper–Pearson interval of the rate (:func:`false_alarm_table`);
* the significance of each true object: that of the reported object explaining it, else of
  the strongest candidate below the threshold within its blur (NaN: none examined), for
  the detection probability against significance;
* the strongest candidate each scan examined (``strongest_sigma``) and the strongest more
  than three blurs across from every true object (``strongest_away_sigma``), tabulated
  against the threshold for the empty and the one-object scene (:func:`strongest_table`):
  the noise's maximum, beyond the count of crossings.  On the empty scene the Wiener
  filter passes no order of pure noise (p̂ = −1) and nothing is examined, so the
  threshold's calibration shows on the one-object scene, where the filter is open.

Run: ``python benchmarks/bench_lightfield_validation.py`` (2 seeds, all walls and scenes);
``--seeds 20`` for the matrix, ``--walls``/``--scenes`` for a part of it, ``--jsonl FILE`` to
append one line per scan (a rerun skips the scans already there; ``--report`` only tabulates
them), ``--empty-seeds N`` for more scans of the empty scene.  A reduced matrix runs in CI
as ``tests/analysis/lightfield/test_validation_matrix.py``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.lightfield import (
    FlatlandBRDF,
    LightField2D,
    detect_widening,
    effective_p_max,
    material,
    reconstruct,
    theoretical_resolution,
)
from hw_mocks.sim.lightfield_scene import HiddenScene, PointObject, Wall

DOMAIN = (-0.6, 0.6)
NOISE = 2e-4
N_THETA = 128
D2 = 100.0
WALL_POINTS = np.arange(-100.0, 100.1, 1.0)
Y_GRID = np.arange(-90.0, 90.1, 2.0)
Z_GRID = np.arange(-400.0, -59.0, 4.0)
MEASURED_Y = np.linspace(-180.0, 180.0, 361)
#: bins of true-object significance (σ) for the detection probability
SIGNIFICANCE_BINS = (0.0, 2.0, 3.0, 4.0, 5.0, 6.0, 10.0, np.inf)


def walls() -> dict[str, FlatlandBRDF]:
    """The walls of the matrix, matte first, the near mirror last."""
    base = material("brushed_metal")
    out = {name: material(name) for name in ("coated_paper_matte", "coated_paper_glossy",
                                             "brushed_metal", "pearl_paint_glass")}
    for deg in (0.5, 0.1, 0.01):
        out[f"brushed_metal_{deg:g}deg"] = FlatlandBRDF(
            base.specular_reflectance, np.deg2rad(deg), base.diffuse_reflectance, 0.0,
            f"brushed_metal_{deg:g}deg")
    return out


def scenes(blur_mm: float) -> dict[str, list[PointObject]]:
    """The scenes; pair separations in units of the wall's transverse blur at −200 mm."""
    out: dict[str, list[PointObject]] = {
        "empty": [],
        "one": [PointObject(0.0, -200.0, 1.5, 1.0)],
        "near": [PointObject(-30.0, -100.0, 1.5, 1.0)],
        "beyond": [PointObject(10.0, -600.0, 1.5, 1.0)],
    }
    for f in (0.5, 1.0, 2.0):
        out[f"pair_{f:g}blur"] = [PointObject(-0.5 * f * blur_mm, -200.0, 1.5, 1.0),
                                  PointObject(0.5 * f * blur_mm, -200.0, 1.5, 1.0)]
    for ratio in (10, 100, 1000):
        out[f"ratio_{ratio}"] = [PointObject(-20.0, -200.0, 1.5, 1.0),
                                 PointObject(20.0, -220.0, 1.5, 1.0 / ratio)]
    out["three"] = [PointObject(-40.0, -200.0, 1.5, 1.0), PointObject(0.0, -260.0, 1.5, 0.3),
                    PointObject(40.0, -150.0, 1.5, 0.1)]
    return out


@dataclass
class Score:
    truths: int = 0
    detected: int = 0
    within_blur: int = 0
    phantoms: int = 0
    scans_with_phantom: int = 0
    split: int = 0
    phantom_resolved: int = 0
    wrong_sign: int = 0
    excluded: int = 0
    #: a "resolved" object over a true object it explains but not within the blur of it
    off_blur: int = 0
    #: a true object neither reported nor among the candidates examined below the
    #: threshold (nothing in the output points at it)
    missed_silently: int = 0
    #: of the missed silently, those whose significance at the true position (the search
    #: taken out, :func:`truth_significance`) is below the threshold: below the detection
    #: limit
    missed_below_limit: int = 0
    scans: int = 0
    seconds: float = 0.0
    #: (significance, detected) per true object
    truth_significance: list[tuple[float, bool]] = field(default_factory=list)

    @property
    def confidently_wrong(self) -> int:
        """Kinds of confidently wrong results; a silent miss counts only where the object was
        detectable (its significance at the true position, leak share included, clears the
        threshold): below that limit no search at this false-alarm rate could report it."""
        return (self.split + self.phantom_resolved + self.wrong_sign + self.excluded
                + self.off_blur + self.missed_silently - self.missed_below_limit)

    def add(self, other: Score) -> None:
        for name in ("truths", "detected", "within_blur", "phantoms", "scans_with_phantom",
                     "split", "phantom_resolved", "wrong_sign", "excluded", "off_blur",
                     "missed_silently", "missed_below_limit", "scans", "seconds"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.truth_significance += other.truth_significance


def score(det, objects: list[PointObject], blur_at, s: Score) -> dict:
    """Add one scan's outcome to ``s`` (module doc) and return it as a dict.

    ``blur_at(z)`` is the theoretical resolution at depth z (for candidates below the
    threshold, which carry none of their own).
    """
    n = det.count
    explains = np.zeros((n, len(objects)), dtype=bool)
    over = np.zeros((n, len(objects)), dtype=bool)
    for k in range(n):
        r = det.resolutions[k]
        far, near = det.depth_interval_mm[k]
        extent = det.extent_mm[k, 0] if det.extent_mm.size else 0.0
        # the y bounds the object's data allow (a near-threshold object's position is
        # uncertain across by more than the blur: ``Detection.across_interval_mm``)
        y_lo, y_hi = (det.across_interval_mm[k] if det.across_interval_mm.size
                      else det.positions_mm[k, :1].repeat(2))
        for j, o in enumerate(objects):
            over[k, j] = (abs(det.positions_mm[k, 0] - o.y_mm) < r.transverse_mm + extent
                          or y_lo <= o.y_mm <= y_hi)
            explains[k, j] = over[k, j] and far <= o.z_mm <= near
    out = Score(scans=1, truths=len(objects))
    for j, o in enumerate(objects):
        hits = np.nonzero(explains[:, j])[0]
        if hits.size:
            out.detected += 1
            k = int(hits[np.argmin(np.abs(det.positions_mm[hits, 0] - o.y_mm))])
            r = det.resolutions[k]
            if (abs(det.positions_mm[k, 0] - o.y_mm) < r.transverse_mm
                    and abs(det.positions_mm[k, 1] - o.z_mm) < r.depth_mm):
                out.within_blur += 1
            sig = float(det.significance[k])
        else:
            r = blur_at(o.z_mm)
            close = [i for i, (yb, zb) in enumerate(det.below_positions_mm)
                     if abs(yb - o.y_mm) < r.transverse_mm
                     and abs(1 / abs(zb) - 1 / abs(o.z_mm)) < r.depth_mm / o.z_mm**2]
            sig = max((float(det.below_significance[i]) for i in close), default=np.nan)
        out.truth_significance.append((sig, bool(hits.size)))
        out.missed_silently += int(not hits.size and np.isnan(sig))
    resolved = np.array([q == "resolved" for q in det.quality], dtype=bool)
    # each reported object is assigned to the nearest true object it explains; a second
    # one assigned to the same truth is a split
    owner = np.full(n, -1)
    for k in range(n):
        js = np.nonzero(explains[k])[0]
        if js.size:
            owner[k] = int(js[np.argmin([abs(det.positions_mm[k, 0] - objects[j].y_mm)
                                         for j in js])])
    for j in range(len(objects)):
        mine = np.nonzero(owner == j)[0]
        if mine.size > 1:
            best = mine[np.argmax(det.significance[mine])]
            out.split += int(sum(resolved[k] for k in mine if k != best))
    for k in np.nonzero((owner >= 0) & resolved)[0]:
        o, r = objects[owner[k]], det.resolutions[k]
        out.off_blur += int(not (abs(det.positions_mm[k, 0] - o.y_mm) < r.transverse_mm
                                 and abs(det.positions_mm[k, 1] - o.z_mm) < r.depth_mm))
    phantom = owner < 0
    out.phantoms = int(phantom.sum())
    out.scans_with_phantom = int(phantom.any())
    for k in range(n):
        if not resolved[k]:
            continue
        if det.brightness_rp[k] <= 0:
            out.wrong_sign += 1
        elif phantom[k] and over[k].any():
            out.excluded += 1
        elif phantom[k]:
            out.phantom_resolved += 1
    s.add(out)
    return {"truths": out.truths, "detected": out.detected, "within_blur": out.within_blur,
            "phantoms": out.phantoms, "split": out.split,
            "phantom_resolved": out.phantom_resolved, "wrong_sign": out.wrong_sign,
            "excluded": out.excluded, "off_blur": out.off_blur,
            "missed_silently": out.missed_silently,
            "truth_significance": [[sg, d] for sg, d in out.truth_significance],
            "count": n, "quality": list(det.quality),
            "positions_mm": det.positions_mm.tolist(),
            "across_mm": det.across_interval_mm.tolist(),
            "significance": det.significance.tolist(),
            # the strongest candidate examined, reported or below the threshold: on the
            # empty scene the noise's own maximum, whose tail the threshold is set on
            "strongest_sigma": float(max(np.max(det.significance, initial=-np.inf),
                                         np.max(det.below_significance, initial=-np.inf))),
            # and the strongest away from every true object (beyond three blurs across, the
            # detector's shadow range): in a scene with objects, where the filter passes
            # orders, the noise's maximum over the rest of the search
            "strongest_away_sigma": strongest_away(det, objects, blur_at)}


def strongest_away(det, objects: list[PointObject], blur_at) -> float:
    """The highest significance among the reported objects and the candidates below the
    threshold that lie more than three transverse blurs across from every true object
    (−inf: none examined there)."""
    pos = np.vstack([det.positions_mm.reshape(-1, 2), det.below_positions_mm.reshape(-1, 2)])
    sig = np.concatenate([det.significance, det.below_significance])
    away = np.ones(sig.size, dtype=bool)
    for o in objects:
        away &= np.abs(pos[:, 0] - o.y_mm) > 3.0 * blur_at(o.z_mm).transverse_mm
    return float(np.max(sig[away], initial=-np.inf))


def render(brdf: FlatlandBRDF, objects: list[PointObject], cache: Path | None,
           key: str) -> LightField2D:
    """The noise-free measured field of a scene, from ``cache`` when it holds it."""
    path = None if cache is None else cache / f"{key}.npy"
    y = MEASURED_Y
    if path is not None and path.exists():
        from analysis.lightfield import theta_grid

        return LightField2D(np.load(path), y, theta_grid(DOMAIN, N_THETA), DOMAIN, D2)
    if objects:
        scene = HiddenScene(tuple(objects), Wall(-150.0, 150.0, brdf), d2_mm=D2)
        lf = scene.measured_field(y, DOMAIN, N_THETA)
    else:
        from analysis.lightfield import theta_grid

        lf = LightField2D(np.zeros((y.size, N_THETA)), y, theta_grid(DOMAIN, N_THETA),
                          DOMAIN, D2)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, lf.radiance)
    return lf


def locate(lf: LightField2D, brdf: FlatlandBRDF, seed: int, truths: list | None = None,
           false_alarm: float = 0.01):
    """Seeded noise on ``lf``, reconstruction, widened detection at ``false_alarm`` per scan
    (the default threshold's): (detection, p̂, solvable domain, significance of each true
    object at its true position)."""
    rng = np.random.default_rng(seed)
    noisy = lf.with_radiance(lf.radiance + rng.normal(0.0, NOISE, lf.shape))
    rec = reconstruct(noisy, brdf, d2_mm=D2, points_mm=WALL_POINTS)
    p_hat = effective_p_max(rec.regularization.filter_factors, rec.orders)
    det, _ = detect_widening(
        rec.incident_field, z_mm=Z_GRID, y_mm=Y_GRID, p_max=p_hat,
        solvable_domain_rad=rec.solvable_domain_rad,
        filter_factors=rec.regularization.filter_factors,
        noise_power=rec.regularization.noise_power, min_measure_fraction=0.1,
        false_alarm=false_alarm)
    return det, p_hat, rec.solvable_domain_rad, truth_significance(rec, truths or [])


def truth_significance(rec, objects: list[PointObject]) -> list[float]:
    """Each true object's significance with the search taken out: the point responses of
    all true objects fitted jointly at their true positions, with the noise model the
    detector uses (:func:`analysis.lightfield.significance.amplitude_fit`).  A true object
    below the threshold here cannot be told from noise by any search at that false-alarm
    rate: it is below the detection limit, not missed by the search.  The significance is
    the detector's own: with the systematic share of a bright neighbour's leak
    (``localize.MODEL_MISMATCH``)."""
    if not objects:
        return []
    from analysis.lightfield.localize import MODEL_MISMATCH
    from analysis.lightfield.ray_fit import ray_model
    from analysis.lightfield.significance import amplitude_fit, with_leak

    f = rec.incident_field
    a, b = rec.solvable_domain_rad
    use = (f.theta_rad >= a) & (f.theta_rad <= b)
    phi = np.atleast_2d(np.asarray(rec.regularization.filter_factors, dtype=float)).mean(0)
    g = (np.asarray(f.radiance, dtype=float) * np.cos(f.theta_rad)[None, :])[:, use]
    pos = np.asarray([(o.y_mm, o.z_mm) for o in objects], dtype=float)
    r, _, _ = ray_model(f, use, phi, pos)
    noise = np.broadcast_to(np.asarray(rec.regularization.noise_power, dtype=float), phi.shape)
    fit = amplitude_fit(g, r, use, phi, noise)
    return [float(v) for v in with_leak(fit, r, MODEL_MISMATCH)]


def blur_of(p_hat: float, solvable: tuple[float, float]):
    """The theoretical resolution at depth z for a reconstruction with ``p_hat``."""
    aperture = float(WALL_POINTS[-1] - WALL_POINTS[0])

    def at(z: float):
        return theoretical_resolution(p_hat, domain_rad=DOMAIN, distance_mm=abs(z),
                                      aperture_mm=aperture, solvable_domain_rad=solvable)
    return at


def wall_blur(brdf: FlatlandBRDF, cache: Path | None, wname: str) -> float:
    """Transverse blur at −200 mm behind this wall (p̂ of a one-object scan, seed 0)."""
    one = scenes(10.0)["one"]
    _, p_hat, solvable, _ = locate(render(brdf, one, cache, f"{wname}__one"), brdf, 0)
    return blur_of(p_hat, solvable)(-200.0).transverse_mm


def detection_table(pairs: list[tuple[float, bool]]) -> list[str]:
    """Markdown rows: detection probability of true objects by significance bin."""
    rows = ["| significance (σ) | true objects | detected | probability |", "|---|---|---|---|"]
    sig = np.array([p[0] for p in pairs], dtype=float)
    hit = np.array([p[1] for p in pairs], dtype=bool)
    none = np.isnan(sig)
    if none.any():
        rows.append(f"| none examined | {none.sum()} | {hit[none].sum()} | "
                    f"{hit[none].mean():.2f} |")
    for lo, hi in itertools.pairwise(SIGNIFICANCE_BINS):
        m = ~none & (sig >= lo) & (sig < hi)
        if m.any():
            rows.append(f"| {lo:g} – {hi:g} | {m.sum()} | {hit[m].sum()} | "
                        f"{hit[m].mean():.2f} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--first-seed", type=int, default=1,
                    help="seeds run are first-seed … first-seed + seeds − 1 (to split a run "
                         "over processes)")
    ap.add_argument("--empty-seeds", type=int, default=None,
                    help="seeds of the empty scene (default --seeds; cheap: no render)")
    ap.add_argument("--walls", nargs="*", default=None, help="wall names (default all)")
    ap.add_argument("--scenes", nargs="*", default=None, help="scene names (default all)")
    ap.add_argument("--cache", type=Path, default=None, help="folder for the renders")
    ap.add_argument("--jsonl", type=Path, default=None,
                    help="append one line per scan; scans already there are skipped")
    ap.add_argument("--report", action="store_true",
                    help="only tabulate the scans already in --jsonl (compute nothing)")
    args = ap.parse_args()
    if args.report and args.jsonl is None:
        ap.error("--report needs --jsonl")
    done: dict[tuple[str, str, int], dict] = {}
    if args.jsonl is not None and args.jsonl.exists():
        for line in args.jsonl.read_text().splitlines():
            rec = json.loads(line)
            done[(rec["wall"], rec["scene"], rec["seed"])] = rec
    total = Score()
    empties: dict[str, tuple[int, int]] = {}
    strongest: dict[str, list[tuple[float, float]]] = {}
    print("| wall | scene | truths | detected | within blur | phantoms | scans w/ phantom "
          "| confidently wrong (split/phantom/sign/excluded/off blur/missed silently "
          "detectable) | of the missed silently, below the detection limit | s/scan |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for wname, brdf in walls().items():
        if args.walls and wname not in args.walls:
            continue
        blur = 10.0 if args.report else wall_blur(brdf, args.cache, wname)
        for sname, objects in scenes(blur).items():
            if args.scenes and sname not in args.scenes:
                continue
            s = Score()
            lf = None
            n_seeds = (args.empty_seeds if sname == "empty" and args.empty_seeds is not None
                       else args.seeds)
            # --report tabulates every seed stored, however many
            seeds = (sorted(sd for (w, sc, sd) in done if (w, sc) == (wname, sname))
                     if args.report else range(args.first_seed, args.first_seed + n_seeds))
            for seed in seeds:
                rec = done.get((wname, sname, seed))
                if rec is None and args.report:
                    continue
                if rec is None:
                    if lf is None:
                        lf = render(brdf, objects, args.cache, f"{wname}__{sname}")
                    t0 = time.process_time()
                    det, p_hat, solvable, oracle = locate(lf, brdf, seed, objects)
                    rec = score(det, objects, blur_of(p_hat, solvable), Score())
                    rec.update(wall=wname, scene=sname, seed=seed, p_hat=p_hat,
                               seconds=time.process_time() - t0, truth_limit_sigma=oracle,
                               threshold_sigma=float(det.threshold_sigma))
                    if args.jsonl is not None:
                        with args.jsonl.open("a") as f:
                            f.write(json.dumps(rec) + "\n")
                s.add(from_record(rec))
                if sname == "empty" and "strongest_sigma" in rec:
                    strongest.setdefault(wname, []).append((rec["strongest_sigma"],
                                                            rec["threshold_sigma"]))
                elif sname == "one" and "strongest_away_sigma" in rec:
                    strongest.setdefault(f"{wname} (one object; away from it)", []).append(
                        (rec["strongest_away_sigma"], rec["threshold_sigma"]))
            if not s.scans:
                continue
            total.add(s)
            if sname == "empty":
                empties[wname] = (s.scans_with_phantom, s.scans)
            print(f"| {wname} | {sname} | {s.truths} | {s.detected} | {s.within_blur} | "
                  f"{s.phantoms} | {s.scans_with_phantom}/{s.scans} | {s.confidently_wrong} "
                  f"({s.split}/{s.phantom_resolved}/{s.wrong_sign}/{s.excluded}/"
                  f"{s.off_blur}/{s.missed_silently - s.missed_below_limit}) | "
                  f"{s.missed_below_limit} | "
                  f"{s.seconds / max(s.scans, 1):.1f} |", flush=True)
    summary(total)
    print("\n".join(false_alarm_table(empties)))
    if strongest:
        print("\n".join(strongest_table(strongest)))


def strongest_table(strongest: dict[str, list[tuple[float, float]]]) -> list[str]:
    """Markdown rows: on the empty scene (and, away from the object, on the one-object
    scene), the significance of the strongest candidate each scan examined (the noise's
    maximum over the searched cells) against the scan's threshold: how far below it the
    noise stays, beyond the count of crossings."""
    rows = ["| wall | scans | strongest candidate: median (σ) | 99th percentile (σ) | "
            "max (σ) | threshold (σ) | within 1σ of it |", "|---|---|---|---|---|---|---|"]
    for wname, pairs in strongest.items():
        v = np.array([p[0] for p in pairs], dtype=float)
        t = np.array([p[1] for p in pairs], dtype=float)
        fin = np.isfinite(v)
        if not fin.any():
            rows.append(f"| {wname} | {v.size} | none examined | | | {np.median(t):.2f} | 0 |")
            continue
        rows.append(f"| {wname} | {v.size} | {np.median(v[fin]):.2f} | "
                    f"{np.percentile(v[fin], 99):.2f} | {v[fin].max():.2f} | "
                    f"{np.median(t):.2f} | {int(np.sum(v[fin] >= t[fin] - 1.0))} |")
    return rows


def false_alarm_table(empties: dict[str, tuple[int, int]]) -> list[str]:
    """Markdown rows: scans of the empty scene with a reported object, per wall and in
    all, with the 95 % Clopper–Pearson interval of the rate per scan."""
    rows = ["| wall | empty scans | with a reported object | rate | 95 % Clopper–Pearson |",
            "|---|---|---|---|---|"]
    items = [*empties.items()]
    if len(items) > 1:
        items.append(("all", (sum(k for k, _ in empties.values()),
                              sum(n for _, n in empties.values()))))
    for wname, (k, n) in items:
        lo, hi = clopper_pearson(k, n)
        rows.append(f"| {wname} | {n} | {k} | {100 * k / n:.2f} % | "
                    f"{100 * lo:.2f} – {100 * hi:.2f} % |")
    return rows


def from_record(rec: dict) -> Score:
    """A scan's :class:`Score` from its stored line."""
    return Score(truths=rec["truths"], detected=rec["detected"],
                 within_blur=rec["within_blur"], phantoms=rec["phantoms"],
                 scans_with_phantom=int(rec["phantoms"] > 0), split=rec["split"],
                 phantom_resolved=rec["phantom_resolved"], wrong_sign=rec["wrong_sign"],
                 excluded=rec["excluded"], off_blur=rec.get("off_blur", 0),
                 missed_silently=missed_silently(rec),
                 missed_below_limit=missed_below_limit(rec), scans=1, seconds=rec["seconds"],
                 truth_significance=[(float("nan") if sg is None else float(sg), bool(d))
                                     for sg, d in rec["truth_significance"]])


def missed_silently(rec: dict) -> int:
    """True objects of a stored scan neither found nor examined below the threshold (also
    for lines written before the count was stored: their significance is NaN or null)."""
    return sum(1 for sg, d in rec["truth_significance"]
               if not d and (sg is None or np.isnan(sg)))


def missed_below_limit(rec: dict) -> int:
    """Missed silently, though below the detection limit: the true object's significance at
    its true position is under the scan's threshold (0 for lines without those fields).
    Lines written before the leak share was included hold ``truth_oracle_sigma``, an upper
    bound of it: a miss is claimed below the limit there only when even the bound is."""
    oracle = rec.get("truth_limit_sigma", rec.get("truth_oracle_sigma"))
    s_star = rec.get("threshold_sigma")
    if oracle is None or s_star is None:
        return 0
    return sum(1 for (sg, d), so in zip(rec["truth_significance"], oracle, strict=True)
               if not d and (sg is None or np.isnan(sg)) and so < s_star)


def clopper_pearson(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact binomial interval of a rate from k events in n trials (Clopper & Pearson
    1934, the equal-tailed beta quantiles)."""
    from scipy.stats import beta

    tail = 0.5 * (1.0 - confidence)
    lo = 0.0 if k == 0 else float(beta.ppf(tail, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - tail, k + 1, n - k))
    return lo, hi


def summary(total: Score) -> None:
    within = total.within_blur / max(total.detected, 1)
    print(f"\ntotal: {total.detected}/{total.truths} detected, {total.within_blur} within the "
          f"blur ({100 * within:.1f} % of those detected), {total.phantoms} phantoms in "
          f"{total.scans_with_phantom}/{total.scans} scans "
          f"({100 * total.scans_with_phantom / max(total.scans, 1):.2f} % per scan), "
          f"{total.confidently_wrong} confidently wrong (split {total.split}, phantom "
          f"{total.phantom_resolved}, wrong sign {total.wrong_sign}, excluded truth "
          f"{total.excluded}, resolved off the blur {total.off_blur}, detectable and missed "
          f"silently {total.missed_silently - total.missed_below_limit}); missed silently "
          f"below the detection limit at their true position: {total.missed_below_limit}; "
          f"CPU {total.seconds:.0f} s\n")
    print("\n".join(detection_table(total.truth_significance)))


if __name__ == "__main__":
    main()
