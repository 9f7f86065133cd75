"""Spherical-harmonic signal processing for inverse rendering (physics.md §5, equations R, M).

Submodules: :mod:`convention` (the SH convention object), :mod:`legendre` (stable normalised
Legendre recurrences), :mod:`transform` (Gauss–Legendre SHT and scattered fits),
:mod:`filters` (BRDF filters A_l), :mod:`convolve` (convolution and Wiener deconvolution),
:mod:`identities` (Mahajan–Ramamoorthi–Curless identities and transfer), :mod:`consistency`
(calibrated image-consistency checker), :mod:`sphere_image` (camera image of a sphere →
directions and SH coefficients), :mod:`inverse` (K_d, K_s, Phong exponent under known
lighting).
"""
