"""What jaxanm's own subpackages (``jaxanm.fsw``, ``jaxanm.sweep``) take from the core's
internal modules, in one place (as ``lineax.internal``).

**Not a stable API.**  These names serve the FSW model and the sweeps, which are built on the
core the way a user's model would be but reach a little further into it: the counted step
problem, the host LU of a sparse matrix, the float64 entry-point decorator, the checks of
scalar inputs, the optional-dependency guard.  They may change with the core; code outside
jaxanm should use the public names of :mod:`jaxanm` (or copy what it needs).

The rule this module holds (``tests/test_code_layout.py``): a module of ``jaxanm/fsw/`` or
``jaxanm/sweep/`` imports no private module of the core (``jaxanm._x``) but through here, and no
core module imports this one (the facade points one way: from the subpackages into the core).
"""

from ._checks import choice, flag, integer, positive, real
from ._extras import MissingExtraError, missing_extra_message, require
from ._factorization import Factorization, sparse_lu
from ._problem import Problem, count, factorize, relative_change
from ._solver import make_solver, solver_kinds
from ._x64 import entry_point

__all__ = [
    "Factorization",
    "MissingExtraError",
    "Problem",
    "choice",
    "count",
    "entry_point",
    "factorize",
    "flag",
    "integer",
    "make_solver",
    "missing_extra_message",
    "positive",
    "real",
    "relative_change",
    "require",
    "solver_kinds",
    "sparse_lu",
]
