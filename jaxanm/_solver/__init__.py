"""The step solvers, one per module, against the base in :mod:`jaxanm._solver.base`.

Every module of this package is imported here, so that a solver class defined in a new module
registers its ``kind`` (:func:`~jaxanm._solver.base.make_solver`) without any other file
changing.
"""

import importlib
import pkgutil

from .anm import ANM
from .base import AttemptSolver, SolverState, StepReport, StepSolver, make_solver, solver_kinds
from .newton import ModifiedNewton, Newton

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
del _module

__all__ = ["ANM", "AttemptSolver", "ModifiedNewton", "Newton", "SolverState", "StepReport", "StepSolver", "make_solver",
           "solver_kinds"]
