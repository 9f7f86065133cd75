"""The error every analysis package raises for a bad argument.

:class:`InputError` names the offending argument (``argument``, as in the function's
signature) and says what is wrong with it; each package subclasses it
(:class:`analysis.sh.validation.SHInputError`,
:class:`analysis.polarimetry.validation.PolarimetryInputError`), so a caller can catch
one package's errors or any analysis input error.
"""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """An argument of an analysis function is non-finite, mis-shaped or out of domain.

    Attributes
    ----------
    argument : str
        The name of the offending argument, as in the function's signature.
    """

    def __init__(self, argument: str, problem: str) -> None:
        self.argument = argument
        super().__init__(f"{argument} {problem}")
