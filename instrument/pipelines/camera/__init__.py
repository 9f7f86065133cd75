"""Camera characterization: a photon-transfer run → EMVA 1288 parameters, the calibration
file ``scatterlab fit`` reads, and a report figure (``scatterlab calibrate camera``)."""
