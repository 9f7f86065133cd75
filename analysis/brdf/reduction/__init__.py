"""BRDF reduction: detector signals → BRDF values with an uncertainty budget.

Pure functions on arrays (no I/O), one module per job: :mod:`.detector` (signals, noise,
solid angles), :mod:`.receiver` (the instrument function: beam footprint and divergence,
receiver aperture, set-point spread), :mod:`.values` (absolute and relative BRDF,
signature), :mod:`.angular` (positioning uncertainty), :mod:`.reciprocity` (a check of the
data), :mod:`.uncertainty` (shared and correlated errors in fits), :mod:`.speckle` (a laser's
speckle in each value), :mod:`.forward` (the
forward model a fit compares the data with, its quadrature refined against the noise) and
:mod:`.candidates` (model selection among forward fits).
The chain, per measured point:

1. **Camera frames → collected power.** Light brackets and their dark frames are merged with
   :func:`analysis.hdr.merge_hdr` (dark subtracted per bracket, inverse-variance weighting
   with the EMVA 1288 noise model), divided by the flat field (:mod:`analysis.radiometry`)
   and summed over the region of interest. The summed signal rate S (DN/µs) of a camera
   whose pupil collects the light scattered by the whole footprint is the collected power
   ``P_s = S · 10⁶ · hν / (K η)`` (W): summing the camera equation
   ``Φ_pixel = L A_ap (p/f)² cos⁴α`` over the image of the footprint gives the power through
   the entrance pupil. The camera is then a detector whose aperture is its pupil.
2. **Absolute method** (Nicodemus et al. 1977, NBS Monograph 160, eq. for f_r = dL_r/dE_i;
   ASTM E2387 practice; Stover, *Optical Scattering*): for an under-filled sample
   ``f = P_s / (P_i · Ω · cos θr · G)``, with P_i the incident power (power meter in the
   direct beam), Ω the receiver solid angle (a meter aperture: the cone 2π(1 − cos a),
   tan a = (D/2)/R; a camera: A_pupil/R², the étendue of its calibration,
   :func:`camera_solid_angle_sr`) and G the **receiver factor** (:func:`receiver_factor`):
   what a constant BRDF would give through the real geometry — the beam's 1/cos θi
   footprint seen from the receiver (1/r² and obliquities across it) and the aperture's
   projected solid angle. A value is then the normalised average of f over what the
   receiver integrated, exact for a Lambertian sample; near a specular peak that average
   differs from f at the nominal angles (−7·10⁻⁴ on the sim bench's GGX α = 0.2 peak), which
   instrument-aware fitting accounts for (:func:`receiver_model`).
3. **Relative method** (ASTM E2387; Li & Torrance 2003): a reference standard measured at
   the same geometry, ``f = (S / S_ref) · f_ref(θi, θr)``, with f_ref from the standard's
   *measured* BRDF table (:class:`ReferenceStandard`), not ρ/π — real diffusers deviate by up
   to 20 % at large angles (PTB and IO-CSIC, EMRP project xDReflect). Source drift between
   the two runs is removed with monitor readings when given.
4. **Instrument signature** (ASTM E2387; Li & Torrance 2003): the BRDF-equivalent signal
   with no sample, reduced the same way, is subtracted point by point (:func:`subtract_signature`).

Output convention (flag ``cosine_corrected``): ``False`` gives the BRDF f (1/sr) of
Nicodemus; ``True`` gives Stover's *cosine-corrected BRDF* f·cos θr = P_s/(P_i Ω) (1/sr),
the quantity scatterometers often report (ASTM E1392/E2387 "CC-BRDF"). Some texts
call the f form "cosine-corrected" because cos θr is divided out; the flag names the
result, not the operation.

Uncertainty budget (sources as in ASTM E2387 and the EURAMET BRDF comparison, Basic et
al., Applied Optics 62(13), 2023), kept in separate columns of :class:`BRDFPoints`:

* ``u_stat``: signal noise — shot, read and dark noise of the light and dark frames
  (camera), or the reading noise of a power meter; independent between points. Under a
  laser (the profile's ``[source] coherence``) it includes the static sample's frozen
  speckle, σ_rel = 1/√M (:mod:`.speckle`), independent between geometries.
* ``u_angle``: positioning — |∂f/∂θi| σθi ⊕ |∂f/∂θr| σθr with the local slope of the
  measured BRDF (:func:`angular_uncertainty`); independent between points.
* ``u_ref``: the reference table's uncertainty (relative method).
* ``cov_corr``: errors shared between points with a known covariance — the camera's pixel
  response (PRNU, or a flat field's own noise) weighted by where each point's footprint
  is imaged (:func:`pixel_response_covariance`); propagated into fitted parameters by
  :func:`with_correlated_uncertainty`, not fitted as noise.
* ``u_scale_rel``: a *relative* uncertainty common to every point of the run — incident
  power, solid angle, camera responsivity Kη (absolute method) or the standard's
  calibration scale (relative method). Being fully correlated it must not be fed to a fit as
  per-point noise: :func:`with_scale_uncertainty` adds it to the fitted parameters instead.

Angles are in radians with the conventions of :mod:`analysis.brdf.geometry` (polar angles
from the normal, ωi towards the source, ωr towards the detector, specular at φr = φi + π).
"""

from analysis.brdf.reduction.angular import (
    angular_uncertainty,
)
from analysis.brdf.reduction.detector import (
    CameraSignal,
    DetectorNoise,
    camera_power_w,
    camera_signal,
    camera_solid_angle_sr,
    pixel_response_covariance,
    solid_angle_sr,
)
from analysis.brdf.reduction.forward import (
    ForwardFit,
    fit_forward,
    forward_model,
    forward_slopes,
)
from analysis.brdf.reduction.receiver import (
    LEVELS,
    NodeSet,
    QuadratureLevel,
    ReceiverGeometry,
    receiver_factor,
    receiver_model,
    receiver_nodes,
)
from analysis.brdf.reduction.reciprocity import (
    ReciprocityCheck,
    reciprocity_check,
)
from analysis.brdf.reduction.speckle import (
    speckle_cells,
    speckle_rel,
    spin_patterns,
)
from analysis.brdf.reduction.uncertainty import (
    scale_sensitivity,
    with_correlated_uncertainty,
    with_scale_uncertainty,
)
from analysis.brdf.reduction.values import (
    BRDFPoints,
    ReferenceStandard,
    absolute_brdf,
    relative_brdf,
    subtract_signature,
)

__all__ = [
    "LEVELS",
    "BRDFPoints",
    "CameraSignal",
    "DetectorNoise",
    "ForwardFit",
    "NodeSet",
    "QuadratureLevel",
    "ReceiverGeometry",
    "ReciprocityCheck",
    "ReferenceStandard",
    "absolute_brdf",
    "angular_uncertainty",
    "camera_power_w",
    "camera_signal",
    "camera_solid_angle_sr",
    "fit_forward",
    "forward_model",
    "forward_slopes",
    "pixel_response_covariance",
    "receiver_factor",
    "receiver_model",
    "receiver_nodes",
    "reciprocity_check",
    "relative_brdf",
    "scale_sensitivity",
    "solid_angle_sr",
    "speckle_cells",
    "speckle_rel",
    "spin_patterns",
    "subtract_signature",
    "with_correlated_uncertainty",
    "with_scale_uncertainty",
]
