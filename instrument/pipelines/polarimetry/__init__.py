"""The Mueller-matrix pipeline of ``scatterlab fit`` for a polarimetric run (ADR 0104).

:mod:`~instrument.pipelines.polarimetry.readings` reads the run (the optical train, per
point the geometry, wavelength, step, mounts' read-back angles and the meter's reading
with its dark) and groups the points by geometry and wavelength;
:mod:`~instrument.pipelines.polarimetry.reduce` builds the instrument matrix from the
read-back angles and the nominal or calibrated optics and reduces each group to a
Mueller-matrix BRDF with its covariance, its Lu–Chipman decomposition and its
realizability test; :mod:`~instrument.pipelines.polarimetry.pipeline` adds the pBRDF fit,
the figures (:mod:`~instrument.pipelines.polarimetry.report`) and the results file
(:mod:`~instrument.pipelines.polarimetry.results`). The polarimeter's own calibration is
stored and looked up by :mod:`~instrument.pipelines.polarimetry.calibration`.
"""
