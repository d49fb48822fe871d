"""The time schemes, one per module, against the base in :mod:`jaxanm._scheme.base`, and the
two forms of a residual (:mod:`jaxanm._scheme.residual_form`)."""

from .base import Interpolant, SchemeStep, StageSolve, TimeScheme, make_scheme, scheme_names
from .bdf2 import BDF2
from .esdirk import ESDIRK
from .euler import ImplicitEuler
from .residual_form import SemiDiscrete, stage_residual

__all__ = ["BDF2", "ESDIRK", "ImplicitEuler", "Interpolant", "SchemeStep", "SemiDiscrete", "StageSolve", "TimeScheme",
           "make_scheme", "scheme_names", "stage_residual"]
