"""Spherical-harmonic signal processing for inverse rendering.

Reflection as a spherical convolution (Ramamoorthi & Hanrahan, SIGGRAPH 2001) and the
identities of Mahajan, Ramamoorthi & Curless (ECCV 2006; tags M4 … M25 in this package are
that paper's equation numbers).

Submodules: :mod:`convention` (the SH convention object), :mod:`legendre` (stable normalised
Legendre recurrences), :mod:`transform` (Gauss–Legendre SHT and scattered fits),
:mod:`ducc` (the transforms' default ducc0 backend and the backend setting),
:mod:`validation` (the input checks and ``SHInputError`` every public function uses),
:mod:`filters` (BRDF filters A_l), :mod:`convolve` (convolution and Wiener deconvolution),
:mod:`identities` (Mahajan–Ramamoorthi–Curless identities and transfer), :mod:`consistency`
(calibrated image-consistency checker), :mod:`sphere_image` (camera image of a sphere →
directions and SH coefficients), :mod:`inverse` (K_d, K_s, Phong exponent under known
lighting).
"""
