"""The simulated camera: renders the virtual bench through a pinhole onto an EMVA 1288 sensor.

A :class:`SimulatedCamera` implements :class:`drivers.base.Camera` (the only project import
it may use besides :mod:`hw_mocks`). On every frame it

1. takes a snapshot of the world (:mod:`hw_mocks.sim.world`): axis positions read from the
   firmware emulators, source state, scene;
2. traces the chief ray of every pixel from the entrance-pupil centre, which sits on the
   detector arm at ``world.arm_length_mm + camera_z`` from the sample and looks at the sample
   centre (image up = lab y), and asks the scene for the radiance along it (continuous
   geometry: each pixel its own direction, nothing from an analysis grid);
3. integrates over the entrance pupil (``pupil="sampled"``, the default): an ideal thin
   lens focused at distance F (the sample centre unless ``focus_distance_mm`` says
   otherwise) images each pixel onto a point X of the focus plane, and the pixel collects
   every ray from X through the pupil disk of radius ρ. With the pixel's object-side area
   (pF/f)² on the plane ⟂ to the axis at F, the ray from pupil point a to X carries
   ``dΦ = L(a → X) cos γ · cos γ · dA_X da / |X − a|² = (p/f)² L cos⁴γ da`` (γ its angle to
   the optical axis; the two planes are parallel, |X − a| = F/cos γ), so

       Φ = (p/f)² ∫_pupil L(a → X) cos⁴γ da,

   which for the chief ray alone is the camera equation ``Φ = L · A · (p/f)² · cos⁴α``.
   Points of the sample off the focus plane are seen defocused (their rays through the
   pupil reach other pixels), as through a real lens. The pupil integral is computed per
   pixel with the rules of :mod:`hw_mocks.sim.pupil`, refined until two successive rules
   agree within ``pupil_rtol`` of the pixel's value (or 10⁻⁹ of the frame's brightest
   radiance): Radon's degree-5 rule, then Gauss product rules of
   doubling order. Only pixels whose chief-ray radiance exceeds the frame's darkest by
   more than 10⁻⁷ of its range, grown by the defocus blur of the scene's depth extent
   (``depth_extent_mm`` of the scene, else a tenth of the focus distance), are refined;
   the others (unlit, or a uniform field) take
   their chief-ray radiance with the pupil's obliquity ∫cos⁴γ da integrated exactly —
   their radiance changes across the pupil by less than that bound, so the summed signal
   of a frame moves by < 10⁻⁸. ``pupil="chief"`` keeps the pinhole (chief ray, ``Φ = L A
   (p/f)² cos⁴α``), which flatland scenes (the light-field bench) ask for;
4. converts radiance to photons per second, ``n = Φ λ / (h c)``;
5. under a laser (the source's ``coherence``), speckles the sample's light
   (:mod:`hw_mocks.sim.speckle`): a frozen pattern per geometry, or the average of the
   independent patterns a spinning sample (:meth:`VirtualBench.spin`) sweeps through
   during the exposure;
6. exposes the sensor (:mod:`hw_mocks.sim.sensor`) for the set exposure time and gain.

The noise-free rendering is cached per world state, ROI and binning: a still scene streams
at the speed of the noise generator.

Two renderers compute the same thing (``renderer``, default ``fast``; ADR 0071). The
``reference`` renderer does it exhaustively, every pixel for every view. The ``fast`` one
traces chief rays only in the box that the scene's lit outlines (``lit_outlines``, where a
scene has them) project to, and one ray outside it for the uniform veil; it takes the
chief rays' and the pupil's obliquity from :func:`hw_mocks.sim.lens.lens_grid` (they depend
on the lens, sensor and focus alone); it grows the refined region by a disk dilation of
its bounding box, row by row (the same pixels as the reference's dilation of the whole
frame);
it reuses the chief ray as the pupil centre's point of Radon's rule, and splits large
pixel sets between worker threads. The rules, the refined region and the tolerances are
the reference's, so the two agree within the pupil tolerance
(tests/hw_mocks/test_sim_camera_fast.py).

URL: ``simcam://<name>?world=sim&seed=1`` with optional ``width``, ``height`` (sensor px),
``focal_length_mm`` (default 50), ``aperture_mm`` (entrance pupil, default 12.5, i.e. f/4),
``pupil`` (``sampled`` or ``chief``, default sampled), ``pupil_rtol`` (default 1e-6),
``focus_distance_mm`` (default: the sample centre), ``renderer`` (``fast`` or
``reference``, default fast),
``format`` (MONO8/10/12/16, default MONO12), ``stale`` (frames a V4L2-like backend keeps
buffered, default 0: see below) and ``realtime`` (1: ``acquire`` takes the exposure time in
wall-clock time; default 0).

Stale frames: with ``stale=N`` the camera behaves like a driver queue holding N frames:
each acquired frame was captured N acquisitions earlier, until :meth:`invalidate` (which
the engine calls after every move and the base class after every settings change)
discards the queue. Tests use it to prove that callers invalidate after moves.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.base import Camera, DeviceIdentity, Frame, PixelFormat, Roi
from drivers.errors import DeviceTimeout
from hw_mocks import registry
from hw_mocks.sim import lens, speckle, workers
from hw_mocks.sim import pupil as pupil_rules
from hw_mocks.sim.sensor import Sensor, SensorParams
from hw_mocks.sim.world import VirtualBench, WorldState, get_world

__all__ = ["OpticsParams", "SimulatedCamera", "open_from_url"]

PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_S = 299792458.0


@dataclass(frozen=True)
class OpticsParams:
    """An ideal thin lens: focal length and entrance-pupil diameter (mm), how the pupil is
    integrated (``"sampled"`` or ``"chief"``: a pinhole), the refinement tolerance of the
    sampled pupil and the focus distance (None: the sample centre). Module docstring."""

    focal_length_mm: float = 50.0
    aperture_diameter_mm: float = 12.5
    pupil: str = "sampled"
    pupil_rtol: float = 1e-6
    focus_distance_mm: float | None = None

    def __post_init__(self) -> None:
        if not (self.focal_length_mm > 0 and self.aperture_diameter_mm > 0):
            raise ValueError("focal length and aperture must be > 0")
        if self.pupil not in ("sampled", "chief"):
            raise ValueError(f"pupil must be 'sampled' or 'chief', got {self.pupil!r}")
        if not 0.0 < self.pupil_rtol < 1.0:
            raise ValueError("pupil_rtol must lie in (0, 1)")
        if self.focus_distance_mm is not None and not self.focus_distance_mm > 0:
            raise ValueError("focus_distance_mm must be > 0")


class SimulatedCamera(Camera):
    """A physics-true camera on the virtual bench.

    Parameters
    ----------
    name
        Role name.
    world
        The virtual bench it looks at (default ``get_world("sim")``).
    seed
        Fixes the sensor's fixed pattern and each frame's noise.
    sensor
        EMVA 1288 parameters.
    optics
        Pinhole optics.
    pixel_format
        Initial output format.
    stale_buffers
        Frames held in a simulated driver queue (see the module docstring).
    realtime
        Whether acquisition waits for the exposure time.
    renderer
        ``"fast"`` (default) or ``"reference"``: the same rendering, computed where the
        scene's light can reach and with the lens-only quantities cached, or exhaustively
        (every pixel, every view; kept to check the fast path against).
    """

    exposure_range_us = (10.0, 10e6)
    gain_range = (0.0, 24.0)

    def __init__(
        self,
        name: str = "camera",
        *,
        world: VirtualBench | None = None,
        seed: int = 0,
        sensor: SensorParams | None = None,
        optics: OpticsParams | None = None,
        pixel_format: PixelFormat = PixelFormat.MONO12,
        stale_buffers: int = 0,
        realtime: bool = False,
        ring_capacity: int = 16,
        renderer: str = "fast",
    ) -> None:
        super().__init__(name, ring_capacity=ring_capacity)
        self.world = world if world is not None else get_world("sim")
        self.seed = int(seed)
        self.sensor = Sensor(sensor or SensorParams(), seed=self.seed)
        self.optics = optics or OpticsParams()
        if stale_buffers < 0:
            raise ValueError("stale_buffers must be >= 0")
        self.stale_buffers = int(stale_buffers)
        self.realtime = bool(realtime)
        if renderer not in ("fast", "reference"):
            raise ValueError(f"renderer must be 'fast' or 'reference', got {renderer!r}")
        self.renderer = renderer
        p = self.sensor.params
        self._exposure_us = 1000.0
        self._gain_db = 0.0
        self._roi = Roi(0, 0, p.width, p.height)
        self._binning = 1
        self._format = pixel_format
        self._index = 0
        self._lock = threading.RLock()
        self._pending: deque[Frame] = deque()  # software-triggered frames
        self._backlog: deque[Frame] = deque()  # simulated driver queue (stale frames)
        self._cache_key: tuple | None = None
        self._cache_rate: NDArray[np.float32] | None = None
        self._speckle_key: tuple | None = None
        self._speckle_rate: NDArray[np.float32] | None = None

    # ------------------------------------------------------------------ rendering
    def camera_frame(self, state: WorldState) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """(pinhole position mm, forward, right, down) unit vectors in the lab frame."""
        pose = state.pose
        center = pose.detector_dir * pose.detector_distance_mm
        # a scene may carry the camera elsewhere (the light-field bench's camera_z track)
        place = getattr(state.scene, "camera_center_mm", None)
        if place is not None:
            center = np.asarray(place(state), dtype=float)
        forward = -pose.detector_dir
        right = np.cross(forward, [0.0, 1.0, 0.0])
        if np.linalg.norm(right) < 1e-9:
            # looking straight down (a type (i) detector at the pole): image up = +z
            right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        return center, forward, right, down

    def photon_rate(self, state: WorldState | None = None, *, roi: Roi | None = None
                    ) -> NDArray[np.float32]:
        """Photons per second on each unbinned pixel of the ROI (noise-free ground truth).

        Returns
        -------
        ndarray, shape (roi.height, roi.width), float32
        """
        state = state if state is not None else self.world.snapshot()
        roi = roi if roi is not None else self._roi
        key = (state.key, roi, self.optics, self.renderer)
        with self._lock:
            if key == self._cache_key and self._cache_rate is not None:
                return self._cache_rate
        render = self._render_reference if self.renderer == "reference" else self._render
        collected = render(state, roi)
        rate = (collected * self._photons_per_radiance(state)).astype(np.float32)
        with self._lock:
            self._cache_key, self._cache_rate = key, rate
        return rate

    def _photons_per_radiance(self, state: WorldState) -> float:
        """Photons/s on a pixel per W m⁻² sr⁻¹ of collected radiance: the pixel's étendue
        A (p/f)² over the photon energy hc/λ (module docstring, steps 3–4)."""
        p = self.sensor.params
        aperture_m2 = math.pi * (0.5e-3 * self.optics.aperture_diameter_mm) ** 2
        etendue = aperture_m2 * (p.pixel_pitch_um * 1e-3 / self.optics.focal_length_mm) ** 2
        photon_j = PLANCK_J_S * SPEED_OF_LIGHT_M_S / (state.source.wavelength_nm * 1e-9)
        return etendue / photon_j

    # -- laser speckle ------------------------------------------------------------------
    def speckle_optics(self, state: WorldState) -> speckle.SpeckleOptics:
        """Wavelength, f-number and pixel pitch of the speckle grain.

        The f-number is f/D, not the working z_i/D of a lens focused closer: this camera
        maps a pixel to the angle p/f (its étendue A (p/f)², module docstring), so the
        grain λ·f/D on its sensor is the one whose count over the image of the spot is
        the spot's étendue into the pupil over λ² (what a real camera's λ·z_i/D gives
        with its own magnification z_i/z_o)."""
        return speckle.SpeckleOptics(
            state.source.wavelength_nm,
            self.optics.focal_length_mm / self.optics.aperture_diameter_mm,
            self.sensor.params.pixel_pitch_um)

    def speckle_decorrelation_deg(self, state: WorldState) -> float:
        """The spin angle Δφ_c (degrees) after which the sample's speckle is a new,
        independent pattern at this geometry (:mod:`hw_mocks.sim.speckle`)."""
        pose = state.pose
        s_loc = pose.to_sample(pose.source_dir)
        d_loc = pose.to_sample(pose.detector_dir)
        half_angle = 0.5 * self.optics.aperture_diameter_mm / pose.detector_distance_mm
        return speckle.decorrelation_angle_deg(
            state.source.wavelength_nm, state.source.beam_radius_mm, float(s_loc[2]),
            math.hypot(s_loc[0] + d_loc[0], s_loc[1] + d_loc[1]), half_angle)

    def speckle_patterns(self, state: WorldState, spin: tuple[float, float],
                         exposure_us: float) -> tuple[int, float]:
        """(first decorrelation step, N): the steps of the spin angle an exposure starting
        at ``spin = (angle°, rate °/s)`` sweeps, N ≥ 1 independent patterns."""
        angle, rate = spin
        step = self.speckle_decorrelation_deg(state)
        swept = abs(rate) * exposure_us * 1e-6
        start = angle if rate >= 0 else angle - swept
        return math.floor(start / step), max(1.0, swept / step)

    def _speckled(self, state: WorldState, roi: Roi, rate: NDArray[np.float32],
                  spin: tuple[float, float], exposure_us: float) -> NDArray[np.float32]:
        """``rate`` under a laser: the sample's light speckled, the veil (ambient, stray
        light) left as it is; cached per geometry and decorrelation steps, so a static
        sample shows one frozen pattern."""
        first, n = self.speckle_patterns(state, spin, exposure_us)
        drawn = min(math.floor(n), speckle.EXACT_PATTERNS)
        key = (state.key, roi, self.optics, first, drawn, round(n, 6))
        with self._lock:
            if key == self._speckle_key and self._speckle_rate is not None:
                return self._speckle_rate
        veil = self._veil_rate(state, roi)
        geometry = [state.positions[k] for k in sorted(state.positions)]
        seeds = [speckle.speckle_seed(self.seed, geometry, first + k) for k in range(drawn)]
        coherent = np.maximum(rate.astype(np.float64) - veil, 0.0)
        out = (speckle.speckle_image(coherent, self.speckle_optics(state), seeds, patterns=n)
               + veil).astype(np.float32)
        with self._lock:
            self._speckle_key, self._speckle_rate = key, out
        return out

    def _veil_rate(self, state: WorldState, roi: Roi) -> NDArray[np.float64]:
        """Photons/s per pixel of the scene's uniform veil (``veil_radiance``, 0 for a
        scene without one) through the chief ray's obliquity cos⁴α (the pupil's varies
        from it by (ρ/F)², 10⁻⁴ of a veil)."""
        veil_of = getattr(state.scene, "veil_radiance", None)
        veil = 0.0 if veil_of is None else float(veil_of(self.camera_frame(state)[0], state))
        if veil == 0.0:
            return np.zeros((roi.height, roi.width))
        p = self.sensor.params
        scale = p.pixel_pitch_um * 1e-3 / self.optics.focal_length_mm
        u = (np.arange(roi.x, roi.x + roi.width) - (p.width - 1) / 2.0) * scale
        v = (np.arange(roi.y, roi.y + roi.height) - (p.height - 1) / 2.0) * scale
        cos2 = 1.0 / (1.0 + u[None, :] ** 2 + v[:, None] ** 2)
        return veil * cos2 * cos2 * self._photons_per_radiance(state)

    def _samples_pupil(self, state: WorldState) -> bool:
        # a flatland scene (rays (y, θ) in one plane) has no pupil to sample
        return self.optics.pupil == "sampled" and getattr(state.scene, "pupil_sampling", True)

    def _focus_mm(self, center: NDArray) -> float:
        return (self.optics.focus_distance_mm if self.optics.focus_distance_mm is not None
                else float(np.linalg.norm(center)))

    def _blur_px(self, state: WorldState, focus: float) -> int:
        """How far (pixels, rounded up, + 1) rays through the pupil reach the scene off
        their chief ray's point: ρ·Δ/(F − Δ) on the focus plane (Δ: the scene's depth
        extent about the focus point, else a tenth of the focus distance)."""
        rho = 0.5 * self.optics.aperture_diameter_mm
        depth = float(getattr(state.scene, "depth_extent_mm", 0.1 * focus))
        pitch_focus = (self.sensor.params.pixel_pitch_um * 1e-3 * focus
                       / self.optics.focal_length_mm)
        return math.ceil(rho * depth / max(focus - depth, 1e-9) / pitch_focus) + 1

    # -- the fast renderer (default) ------------------------------------------------
    def _render(self, state: WorldState, roi: Roi) -> NDArray[np.float64]:
        """Radiance collected per pixel (the pupil integral, or the chief ray's
        ``L cos⁴α``), W m⁻² sr⁻¹ times the pupil's relative obliquity.

        The quantity of :meth:`_render_reference`, by the same rules and tolerances,
        computed only where it can differ from the scene's uniform veil: chief rays are
        traced in the box that the scene's lit outlines (``lit_outlines``, where the scene
        has them) project to, and one ray outside it gives the veil; what depends on the
        lens alone comes cached from :func:`hw_mocks.sim.lens.lens_grid`; the refined
        region is grown by a disk dilation of its bounding box, row by row
        (:func:`_disk_dilation`: the same pixels as the reference's disk dilation of the
        whole frame)."""
        p = self.sensor.params
        center, forward, right, down = self.camera_frame(state)
        # to the picometre: the arm's length read back from unit vectors scatters by an
        # ulp between views, which would miss the cache for no physical change
        focus = round(self._focus_mm(center), 9)
        grid = lens.lens_grid((roi.x, roi.y, roi.width, roi.height), (p.width, p.height),
                              p.pixel_pitch_um, self.optics.focal_length_mm,
                              0.5 * self.optics.aperture_diameter_mm, focus)
        frame = (center, forward, right, down)
        radiance = self._chief_radiance(state, frame, grid)
        if not self._samples_pupil(state):
            return radiance * grid.cos_alpha ** 4
        return self._pupil_integral_fast(state, frame, grid, radiance,
                                         self._blur_px(state, focus))

    def _chief_radiance(self, state: WorldState, frame: tuple[NDArray, ...],
                        grid: lens.LensGrid) -> NDArray[np.float64]:
        """Scene radiance along every chief ray of the ROI, traced only where the scene
        can send more than its uniform veil."""
        center, forward, right, down = frame
        h, w = grid.v.size, grid.u.size
        rows, cols = slice(0, h), slice(0, w)
        outlines = getattr(state.scene, "lit_outlines", None)
        hulls = outlines(state) if outlines is not None else ()
        if hulls is None:  # nothing lit: the veil everywhere
            rows, cols = slice(0, 0), slice(0, 0)
        for hull in hulls or ():
            box = lens.pixel_box(hull, center, right, down, forward, grid, margin_px=2)
            if box is None:  # a lit point at or behind the pupil: trace every ray
                rows, cols = slice(0, h), slice(0, w)
                break
            rows = slice(max(rows.start, box[0].start), min(rows.stop, box[0].stop))
            cols = slice(max(cols.start, box[1].start), min(cols.stop, box[1].stop))
        rows = rows if rows.stop > rows.start and cols.stop > cols.start else slice(0, 0)
        projected = getattr(state.scene, "radiance_projected", None)

        def trace(rows: slice, cols: slice) -> NDArray[np.float64]:
            if projected is not None:  # the rays through the pupil centre, projected
                r = np.arange(rows.start, rows.stop)[:, None]
                c = np.arange(cols.start, cols.stop)[None, :]
                project, cos_g = grid.pupil_bundle(r, c, right, down, forward).rays(0.0, 0.0)
                return projected(center, project, cos_g.shape, state)
            dirs = grid.chief_directions(rows, cols, right, down, forward)
            return state.scene.radiance(center, dirs, state)

        def traced(rows: slice, cols: slice) -> NDArray[np.float64]:
            # the box's rows in blocks (threads and cache, as the pupil rays)
            step = max(1, workers.BLOCK_PIXELS // max(cols.stop - cols.start, 1))
            return np.concatenate(workers.in_blocks([
                (trace, slice(r, min(r + step, rows.stop)), cols)
                for r in range(rows.start, rows.stop, step)]))

        if (rows.stop - rows.start, cols.stop - cols.start) == (h, w):
            return traced(rows, cols)
        # a box smaller than the frame leaves out an edge row or column, so a corner
        r, c = next((r, c) for r in (0, h - 1) for c in (0, w - 1)
                    if not (rows.start <= r < rows.stop and cols.start <= c < cols.stop))
        veil = state.scene.radiance(
            center, grid.chief_directions(slice(r, r + 1), slice(c, c + 1), right, down,
                                          forward), state)
        out = np.full((h, w), float(veil.reshape(-1)[0]))
        if rows.stop > rows.start:
            out[rows, cols] = traced(rows, cols)
        return out

    def _pupil_integral_fast(self, state: WorldState, frame: tuple[NDArray, ...],
                             grid: lens.LensGrid, chief: NDArray, grow: int
                             ) -> NDArray[np.float64]:
        """(1/A) ∫_pupil L(a → X) cos⁴γ da per pixel: the rules, region and tolerances
        of :meth:`_pupil_integral`, on the cached lens grid."""
        center, forward, right, down = frame
        out = chief * grid.obliquity
        lo, hi = float(chief.min()), float(chief.max())
        span = hi - lo
        if span <= 0.0:
            return out  # a uniform field: the radiance does not change across the pupil
        todo = chief > lo + 1e-7 * span
        # every pixel within ``grow`` of a lit one (the reference's disk dilation), from
        # the disk dilation of the lit pixels' bounding box grown by ``grow``
        lit_r, lit_c = np.flatnonzero(todo.any(axis=1)), np.flatnonzero(todo.any(axis=0))
        r0, r1 = max(lit_r[0] - grow, 0), min(lit_r[-1] + grow + 1, todo.shape[0])
        c0, c1 = max(lit_c[0] - grow, 0), min(lit_c[-1] + grow + 1, todo.shape[1])
        near = _disk_dilation(todo[r0:r1, c0:c1], grow)
        atol = 1e-9 * float(np.abs(chief).max())
        rho = grid.pupil_radius_mm
        projected = getattr(state.scene, "radiance_projected", None)

        def part(rule: pupil_rules.DiskRule, rows: NDArray[np.intp],
                 cols: NDArray[np.intp]) -> NDArray:
            acc = np.zeros(rows.size)
            bundle = (grid.pupil_bundle(rows, cols, right, down, forward)
                      if projected is not None else None)
            for k in range(len(rule)):
                if rule.x[k] == 0.0 and rule.y[k] == 0.0:
                    # the pupil centre's ray is the chief ray, traced already
                    cos2 = grid.cos_alpha[rows, cols] ** 2
                    acc += rule.weights[k] * chief[rows, cols] * (cos2 * cos2)
                    continue
                a = center + rho * (rule.x[k] * right + rule.y[k] * down)
                if bundle is not None:  # the scene takes the rays' projections
                    project, cos_g = bundle.rays(rule.x[k], rule.y[k])
                    radiance = projected(a, project, cos_g.shape, state)
                else:
                    d, cos_g = grid.pupil_rays(rule.x[k], rule.y[k], rows, cols, right,
                                               down, forward)
                    radiance = state.scene.radiance(a, d, state)
                cos_g *= cos_g
                cos_g *= cos_g
                cos_g *= radiance
                cos_g *= rule.weights[k]
                acc += cos_g
            return acc

        def estimate(rule: pupil_rules.DiskRule, rows: NDArray[np.intp],
                     cols: NDArray[np.intp]) -> NDArray:
            # pixels are independent: large sets are cut into blocks whose temporaries
            # stay in a core's cache, computed by worker threads (numpy releases the GIL
            # in its loops), each pixel exactly as in one piece
            blocks = -(-rows.size // workers.BLOCK_PIXELS)
            pieces = np.array_split(np.arange(rows.size), blocks)
            return np.concatenate(workers.in_blocks([
                (part, rule, rows[i], cols[i]) for i in pieces]))

        # the reference's ladder and acceptance (a cheaper first check, Radon's rule
        # against a 16-point degree-7 rule, was measured and rejected: on a sharp lobe
        # both coarse rules can agree while 65 times the tolerance off, BENCHMARKS.md)
        rules = [pupil_rules.radon7()]
        rules += [pupil_rules.polar_gauss(n_s, n_phi) for n_s, n_phi in pupil_rules.LADDER]
        rows, cols = np.nonzero(near)
        rows += r0
        cols += c0
        prev = estimate(rules[0], rows, cols)
        for rule in rules[1:]:
            cur = estimate(rule, rows, cols)
            out[rows, cols] = cur
            left = np.abs(cur - prev) > self.optics.pupil_rtol * np.abs(cur) + atol
            if not left.any():
                break
            rows, cols, prev = rows[left], cols[left], cur[left]
        return out

    # -- the reference renderer (exhaustive) ----------------------------------------
    def _render_reference(self, state: WorldState, roi: Roi) -> NDArray[np.float64]:
        """What :meth:`_render` computes, the straightforward way: every chief ray of the
        ROI traced, the obliquity and the refined region computed anew for every view.
        Kept (``renderer="reference"``) to check the fast renderer against it."""
        p = self.sensor.params
        center, forward, right, down = self.camera_frame(state)
        pitch_mm = p.pixel_pitch_um * 1e-3
        f = self.optics.focal_length_mm
        cx, cy = (p.width - 1) / 2.0, (p.height - 1) / 2.0
        u = (np.arange(roi.x, roi.x + roi.width) - cx) * (pitch_mm / f)
        v = (np.arange(roi.y, roi.y + roi.height) - cy) * (pitch_mm / f)
        dirs = (forward[None, None, :] + u[None, :, None] * right[None, None, :]
                + v[:, None, None] * down[None, None, :])
        norm = np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2)
        dirs /= norm[..., None]
        cos_alpha = 1.0 / norm
        radiance = state.scene.radiance(center, dirs, state)
        if self._samples_pupil(state):
            return self._pupil_integral(state, center, forward, right, down, dirs, radiance)
        return radiance * cos_alpha**4

    def _pupil_integral(self, state: WorldState, center: NDArray, forward: NDArray,
                        right: NDArray, down: NDArray, dirs: NDArray, chief: NDArray
                        ) -> NDArray[np.float64]:
        """(1/A) ∫_pupil L(a → X) cos⁴γ da per pixel (module docstring, step 3).

        ``dirs`` (H, W, 3) are the chief rays, ``chief`` their radiance. Pixels are refined
        along Radon's rule, then :data:`hw_mocks.sim.pupil.LADDER` until two successive
        estimates agree within ``pupil_rtol`` × |value| + 10⁻⁹ × the frame's
        brightest radiance; a pixel that never does keeps the finest estimate (the
        convergence is checked in tests/hw_mocks/test_sim_camera.py).
        """
        rho = 0.5 * self.optics.aperture_diameter_mm
        focus = self._focus_mm(center)
        # the conjugate point of every pixel on the focus plane ⟂ forward at ``focus``
        target = center + dirs * (focus / (dirs @ forward))[..., None]

        def rays(rule: pupil_rules.DiskRule, k: int, points: NDArray
                 ) -> tuple[NDArray, NDArray, NDArray]:
            """Pupil point k of ``rule`` (3,), the unit directions (M, 3) from it to the
            conjugate points ``points`` (M, 3), and their cos γ to the axis."""
            a = center + rho * (rule.x[k] * right + rule.y[k] * down)
            d = points - a
            d /= np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
            return a, d, d @ forward

        flat_target = target.reshape(-1, 3)
        # the obliquity ∫cos⁴γ da/A of every pixel: smooth over the pupil, so one
        # degree-5 rule is exact to (ρ/F)⁶ ≈ 10⁻¹⁰
        rule = pupil_rules.radon7()
        obliquity = np.zeros(chief.size)
        for k in range(len(rule)):
            obliquity += rule.weights[k] * rays(rule, k, flat_target)[2] ** 4
        out = (chief.reshape(-1) * obliquity).reshape(chief.shape)
        span = float(chief.max() - chief.min())
        if span <= 0.0:
            return out  # a uniform field: the radiance does not change across the pupil
        todo = chief > chief.min() + 1e-7 * span
        # Rays through the pupil reach the scene up to a blur ρ·Δ/(F − Δ) off the chief
        # ray's point (Δ: the scene's depth extent about the focus point), so pixels that
        # far outside a lit region (a sharp edge, e.g. the sample's rim seen at grazing)
        # collect light too: grow the refined region by that blur in pixels.
        grow = self._blur_px(state, focus)
        # scipy.ndimage is imported where a frame is rendered, not with the module: every
        # emulated bench imports this module (each server start, each test process) and
        # the import costs about 1 s of CPU, which a bench that never renders a camera
        # frame saves
        from scipy import ndimage

        todo = ndimage.binary_dilation(todo, structure=_disk_structure(grow))
        atol = 1e-9 * float(np.abs(chief).max())

        def estimate(rule: pupil_rules.DiskRule, idx: NDArray[np.intp]) -> NDArray:
            points = flat_target[idx]
            acc = np.zeros(idx.size)
            for k in range(len(rule)):
                a, d, cos_g = rays(rule, k, points)
                cos2 = cos_g * cos_g
                acc += rule.weights[k] * state.scene.radiance(a, d, state) * (cos2 * cos2)
            return acc

        rules = [pupil_rules.radon7()]
        rules += [pupil_rules.polar_gauss(n_s, n_phi) for n_s, n_phi in pupil_rules.LADDER]
        idx = np.flatnonzero(todo)
        prev = estimate(rules[0], idx)
        flat_out = out.reshape(-1)
        for rule in rules[1:]:
            cur = estimate(rule, idx)
            flat_out[idx] = cur
            # the finer rule is far more accurate: |cur − prev| bounds the error of prev
            left = np.abs(cur - prev) > self.optics.pupil_rtol * np.abs(cur) + atol
            if not left.any():
                break
            idx, prev = idx[left], cur[left]
        return out

    def expected_dn(self, state: WorldState | None = None) -> NDArray[np.float64]:
        """Noise-free mean DN at the present settings (ground truth for tests)."""
        roi = self._roi
        return self.sensor.expected_dn(
            self.photon_rate(state, roi=roi), self._exposure_us, gain_db=self._gain_db,
            bits=self._format.bit_depth, roi=(roi.x, roi.y, roi.width, roi.height),
            binning=self._binning,
        )

    @property
    def system_gain_dn_per_e(self) -> float:
        """K at the present gain and pixel format (the simulator's truth)."""
        return self.sensor.params.system_gain(self._gain_db, self._format.bit_depth)

    def radiometric_response(self):
        """The :class:`analysis.radiometry.CameraResponse` of this camera, as a perfect
        calibration would give it (at the source's present wavelength)."""
        from analysis.radiometry import CameraResponse

        p = self.sensor.params
        return CameraResponse(
            system_gain_dn_per_e=self.system_gain_dn_per_e,
            quantum_efficiency=p.quantum_efficiency,
            wavelength_nm=self.world.source.wavelength_nm,
            pixel_pitch_um=p.pixel_pitch_um * self._binning,
            focal_length_mm=self.optics.focal_length_mm,
            aperture_diameter_mm=self.optics.aperture_diameter_mm,
        )

    def _capture(self) -> Frame:
        """Render and expose one frame of the world as it is now."""
        with self._lock:
            state = self.world.snapshot()
            roi, b, fmt = self._roi, self._binning, self._format
            exposure, gain = self._exposure_us, self._gain_db
            index = self._index
            self._index += 1
        spin = self.world.spin()
        rate = self.photon_rate(state, roi=roi)
        if state.source.coherence == "laser" and state.source.on:
            rate = self._speckled(state, roi, rate, spin, exposure)
        bits = fmt.bit_depth
        data = self.sensor.expose(
            rate, exposure, gain_db=gain, bits=bits,
            roi=(roi.x, roi.y, roi.width, roi.height), binning=b, frame_index=index,
        )
        return Frame(
            data=data, index=index, timestamp=time.time(), exposure_us=exposure, gain=gain,
            saturation_dn=self.sensor.saturation_dn(gain_db=gain, bits=bits, binning=b),
            bit_depth=bits, roi=roi, binning=b,
            metadata={
                "simulated": True,
                "world": self.world.name,
                "positions": dict(state.positions),
                "source_on": state.source.on,
                "system_gain_dn_per_e": self.sensor.params.system_gain(gain, bits),
            },
        )

    # ------------------------------------------------------------------ hooks
    def _do_identity(self) -> DeviceIdentity:
        p = self.sensor.params
        return DeviceIdentity(
            vendor="scatterlab", model="SimCam EMVA1288", serial=f"SIM{self.seed:06d}",
            firmware="1.0", extra={"sensor": f"{p.width}x{p.height}", "world": self.world.name},
        )

    def _do_sensor_shape(self) -> tuple[int, int]:
        p = self.sensor.params
        return p.height, p.width

    def _do_get_exposure_us(self) -> float:
        return self._exposure_us

    def _do_set_exposure_us(self, value: float) -> None:
        with self._lock:
            self._exposure_us = value

    def _do_get_gain(self) -> float:
        return self._gain_db

    def _do_set_gain(self, value: float) -> None:
        with self._lock:
            self._gain_db = value

    def _do_get_roi(self) -> Roi:
        return self._roi

    def _do_set_roi(self, roi: Roi) -> None:
        with self._lock:
            self._roi = roi

    def _do_get_binning(self) -> int:
        return self._binning

    def _do_set_binning(self, value: int) -> None:
        if value not in (1, 2, 4):
            from drivers.errors import UnsupportedFeature

            raise UnsupportedFeature(f"binning {value} is not supported (1, 2 or 4)",
                                     device=self.name, command="set binning")
        with self._lock:
            self._binning = value

    def _do_get_pixel_format(self) -> PixelFormat:
        return self._format

    def _do_set_pixel_format(self, fmt: PixelFormat) -> None:
        with self._lock:
            self._format = fmt

    def _do_invalidate(self) -> None:
        with self._lock:
            self._pending.clear()
            self._backlog.clear()

    def _do_trigger(self) -> None:
        frame = self._capture()
        with self._lock:
            self._pending.append(frame)

    def _do_acquire_one(self, timeout: float) -> Frame:
        with self._lock:
            if self._pending:
                return self._pending.popleft()
        if self.realtime:
            wait = self._exposure_us * 1e-6
            if wait > timeout:
                raise DeviceTimeout(f"exposure {wait:g} s exceeds the timeout {timeout:g} s",
                                    device=self.name, command="acquire")
            time.sleep(wait)
        if self.stale_buffers == 0:
            return self._capture()
        with self._lock:
            empty = not self._backlog
        if empty:  # the driver queue fills as soon as capture (re)starts
            for _ in range(self.stale_buffers):
                frame = self._capture()
                with self._lock:
                    self._backlog.append(frame)
        frame = self._capture()
        with self._lock:
            self._backlog.append(frame)
            return self._backlog.popleft()

    def _do_close_camera(self) -> None:
        with self._lock:
            self._pending.clear()
            self._backlog.clear()
            self._cache_rate = None
            self._speckle_rate = None


def _disk_structure(radius_px: int) -> NDArray[np.bool_]:
    """A disk of ``radius_px`` pixels for binary dilation."""
    k = np.arange(-radius_px, radius_px + 1)
    return (k[:, None] ** 2 + k[None, :] ** 2) <= radius_px * radius_px


def _disk_dilation(mask: NDArray[np.bool_], radius_px: int) -> NDArray[np.bool_]:
    """Every pixel within ``radius_px`` (Euclidean, whole pixels) of a True pixel of
    ``mask``: the binary dilation by :func:`_disk_structure` (nothing outside ``mask``
    counts), which is also the set a Euclidean distance transform puts at ≤ ``radius_px``.

    Built from rows: ``wide[k]`` dilates ``mask`` along x by ±k, and row offset dy takes
    ``wide[⌊√(r² − dy²)⌋]`` — about 4r + 3 whole-array ORs of booleans, where the distance
    transform of the main job's refined box took ~12 ms of the one engine thread a view
    (BENCHMARKS.md, main job, 2026-11-27). Exactly the same pixels: the offsets (dy, dx)
    taken are those with dy² + dx² ≤ r² (tests/hw_mocks/test_sim_camera_fast.py).
    """
    r = int(radius_px)
    h, w = mask.shape
    wide = [np.array(mask, dtype=bool)]
    for k in range(1, min(r, w - 1) + 1):
        grown = wide[-1].copy()
        grown[:, k:] |= mask[:, :-k]
        grown[:, :-k] |= mask[:, k:]
        wide.append(grown)
    out = wide[-1].copy()  # dy = 0: the full width ±r
    for dy in range(1, min(r, h - 1) + 1):
        row = wide[min(math.isqrt(r * r - dy * dy), len(wide) - 1)]
        out[dy:] |= row[:-dy]
        out[:-dy] |= row[dy:]
    return out


def _option(options: dict[str, Any], key: str, kind: type, default: Any, url: str) -> Any:
    """``options[key]`` converted to ``kind``; a bad value names the option and the URL."""
    if key not in options:
        return default
    try:
        return kind(options[key])
    except (TypeError, ValueError):
        raise ValueError(f"{url}: option {key}={options[key]!r} is not a valid "
                         f"{kind.__name__}") from None


def open_from_url(url: str, *, name: str | None = None) -> SimulatedCamera:
    """Open ``simcam://<name>?world=sim&seed=1[&width=..&height=..&format=MONO16...]``."""
    scheme, host, options = registry.parse_url(url)
    if scheme != "simcam":
        raise ValueError(f"expected a simcam:// URL, got {url!r}")
    opts: dict[str, Any] = dict(options)
    known = {"world", "seed", "width", "height", "focal_length_mm", "aperture_mm", "format",
             "stale", "realtime", "pixel_pitch_um", "pupil", "pupil_rtol",
             "focus_distance_mm", "renderer"}
    unknown = set(opts) - known
    if unknown:
        raise ValueError(f"unknown simcam options {sorted(unknown)}; known {sorted(known)}")
    defaults = SensorParams()
    sensor = replace(
        defaults,
        width=_option(opts, "width", int, defaults.width, url),
        height=_option(opts, "height", int, defaults.height, url),
        pixel_pitch_um=_option(opts, "pixel_pitch_um", float, defaults.pixel_pitch_um, url),
    )
    optics = OpticsParams(
        focal_length_mm=_option(opts, "focal_length_mm", float, 50.0, url),
        aperture_diameter_mm=_option(opts, "aperture_mm", float, 12.5, url),
        pupil=str(opts.get("pupil", "sampled")).lower(),
        pupil_rtol=_option(opts, "pupil_rtol", float, 1e-6, url),
        focus_distance_mm=_option(opts, "focus_distance_mm", float, None, url),
    )
    fmt_name = str(opts.get("format", "MONO12")).upper()
    try:
        fmt = PixelFormat[fmt_name]
    except KeyError:
        raise ValueError(f"{url}: unknown pixel format {fmt_name!r}; known "
                         f"{[f.name for f in PixelFormat]}") from None
    return SimulatedCamera(
        name or host,
        world=get_world(opts.get("world", "sim")),
        seed=_option(opts, "seed", int, 0, url),
        sensor=sensor,
        optics=optics,
        pixel_format=fmt,
        stale_buffers=_option(opts, "stale", int, 0, url),
        realtime=str(opts.get("realtime", "0")).lower() in ("1", "true", "yes"),
        renderer=str(opts.get("renderer", "fast")).lower(),
    )
