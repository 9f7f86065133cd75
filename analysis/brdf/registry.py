"""Model registry: names usable on the command line (``--models lambert,lambert+ggx``).

A name is either a registered base model or a "+"-joined sum of them (e.g. ``lambert+ggx``,
``oren_nayar+beckmann``); see :func:`get_model` and :func:`available_models`.
"""

from __future__ import annotations

from collections.abc import Callable

from analysis.brdf.diffuse import hapke, lambertian, lommel_seeliger, oren_nayar
from analysis.brdf.fresnel_lobe import fresnel_microfacet
from analysis.brdf.lightfield import separable_specular
from analysis.brdf.model import BRDFModel, sum_models
from analysis.brdf.rough_surface import beckmann_kirchhoff, rayleigh_rice
from analysis.brdf.specular import blinn_phong, cook_torrance, phong, ward

_FACTORIES: dict[str, Callable[[], BRDFModel]] = {
    "lambert": lambertian,
    "oren_nayar": oren_nayar,
    "lommel_seeliger": lommel_seeliger,
    "hapke": hapke,
    "hapke_opposition": lambda: hapke(opposition=True),
    "phong": phong,
    "blinn_phong": blinn_phong,
    "ggx": lambda: cook_torrance(distribution="ggx", masking="smith"),
    "beckmann": lambda: cook_torrance(distribution="beckmann", masking="smith"),
    "ggx_vcavity": lambda: cook_torrance(distribution="ggx", masking="vcavity"),
    "beckmann_vcavity": lambda: cook_torrance(distribution="beckmann", masking="vcavity"),
    # the index as a fitted parameter (absolute BRDF data; spectral fits per wavelength)
    "ggx_fresnel": fresnel_microfacet,
    "ggx_conductor": lambda: fresnel_microfacet(absorbing=True),
    "ward": ward,
    "ward_aniso": lambda: ward(anisotropic=True),
    "beckmann_kirchhoff": beckmann_kirchhoff,
    "rayleigh_rice_gauss": lambda: rayleigh_rice(psd="gaussian"),
    "rayleigh_rice_abc": lambda: rayleigh_rice(psd="abc"),
    "lightfield_separable": separable_specular,
}

_BUILTIN = frozenset(_FACTORIES)

_ALIASES = {
    "lambertian": "lambert",
    "cook_torrance": "ggx",
    "torrance_sparrow": "beckmann_vcavity",
    "lafortune": "phong",
}


#: The library's model families, each by its representative registry names (the default
#: candidate set of a fit, :func:`default_candidates`).
FAMILIES: dict[str, tuple[str, ...]] = {
    "diffuse": ("lambert", "oren_nayar", "hapke"),
    "specular": ("ggx", "beckmann", "phong"),
    "physical_optics": ("beckmann_kirchhoff", "rayleigh_rice_gauss"),
}


def default_candidates() -> tuple[str, ...]:
    """Candidates for a sample whose model is not known: every diffuse, specular and
    physical-optics family member alone, then every sum of one diffuse and one specular or
    physical-optics model (3 + 3 + 2 + 3 × 5 = 23 names; practical fits usually combine
    a diffuse and a specular lobe: Montes & Ureña 2012, "An overview of BRDF models")."""
    lobes = FAMILIES["specular"] + FAMILIES["physical_optics"]
    sums = tuple(f"{d}+{s}" for d in FAMILIES["diffuse"] for s in lobes)
    return FAMILIES["diffuse"] + lobes + sums


def available_models() -> tuple[str, ...]:
    """Registered base-model names (sorted)."""
    return tuple(sorted(_FACTORIES))


def register_model(name: str, factory: Callable[[], BRDFModel]) -> None:
    """Add a base model (e.g. a configured :func:`cook_torrance` with a complex index)."""
    if "+" in name or "," in name or not name:
        raise ValueError("model names must be non-empty and contain no '+' or ','")
    if name in _BUILTIN or name in _ALIASES:
        raise ValueError(f"{name!r} is a built-in model name")
    _FACTORIES[name] = factory


def unregister_model(name: str) -> None:
    """Remove a model added with :func:`register_model` (built-in names are protected)."""
    if name in _BUILTIN:
        raise ValueError(f"{name!r} is a built-in model")
    _FACTORIES.pop(name, None)


#: Models whose value depends on the wavelength (factories taking ``wavelength_um``).
_SPECTRAL = {
    "rayleigh_rice_gauss": lambda lam: rayleigh_rice(psd="gaussian", wavelength_um=lam),
    "rayleigh_rice_abc": lambda lam: rayleigh_rice(psd="abc", wavelength_um=lam),
}


def get_model(name: str, *, wavelength_um: float | None = None) -> BRDFModel:
    """The model called ``name``; "a+b+…" builds the sum of the parts. ``wavelength_um``
    sets the wavelength of the models that depend on it (Rayleigh–Rice; default 0.6328).

    Raises
    ------
    KeyError
        Naming the unknown part and listing the known ones.
    """
    parts = [s.strip() for s in name.split("+")]
    models = []
    for part in parts:
        key = _ALIASES.get(part, part)
        if key not in _FACTORIES:
            raise KeyError(
                f"unknown BRDF model {part!r}; known: {', '.join(available_models())}"
            )
        if wavelength_um is not None and key in _SPECTRAL:
            models.append(_SPECTRAL[key](float(wavelength_um)))
            continue
        models.append(_FACTORIES[key]())
    return models[0] if len(models) == 1 else sum_models(*models)


def parse_model_list(spec: str) -> tuple[BRDFModel, ...]:
    """Models from a comma-separated list such as ``"lambert,lambert+ggx"``."""
    names = [s.strip() for s in spec.split(",") if s.strip()]
    if not names:
        raise ValueError("empty model list")
    return tuple(get_model(n) for n in names)
