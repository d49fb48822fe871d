"""jaxanm: a high-order implicit solver (Asymptotic Numerical Method) on JAX.

The residual of an implicit time step (or the semi-discrete ``F(u, u_dot, t, params) = 0`` that
a time scheme builds its stages from) is written once in ``jax.numpy``; tangents come from
``jax.jacfwd``, homotopy series coefficients from ``jax.experimental.jet``, and each series
order is solved with one host LU factorisation of K*, reused while the series stays valid.

Every public function runs in float64 (inside ``jax.enable_x64``) without changing JAX's
global configuration; wrap your own jnp code in ``with jaxanm.float64():`` to match.
"""

from typing import TYPE_CHECKING

from ._acceptance import evaluate_series, validity_range
from ._constant_step import ConstantStepSize
from ._factorization import Factorization
from ._hooks import Remap
from ._integrate import Solution, integrate
from ._problem import factorize
from ._run_checkpoint import stored_host_state
from ._saveat import SaveAt
from ._scheme import BDF2, ESDIRK, ImplicitEuler, SemiDiscrete, TimeScheme, make_scheme, scheme_names
from ._sensitivity_method import SensitivityMethod
from ._series import taylor_coefficients
from ._solver import ANM, ModifiedNewton, Newton, SolverState, StepReport, StepSolver, make_solver, solver_kinds
from ._step_control import StepController
from ._x64 import float64
from .bordered import ContinuationFailure
from .branch import Branch, BranchPoints
from .continuation import continuation, newton_continuation
from .critical import critical_load
from .errors import InputError, NonFiniteError, SingularMatrixError, StepFailure
from .events import Event, StepEnd
from .jacobian import SparseJacobian, color_columns, detect_sparsity
from .sensitivity import ForwardSensitivity, Sensitivities, sensitivities, value_and_grad
from .stats import Stats

__all__ = [
    "ANM",
    "BDF2",
    "Branch",
    "BranchPoints",
    "ConstantStepSize",
    "ContinuationFailure",
    "ESDIRK",
    "Event",
    "Factorization",
    "ForwardSensitivity",
    "ImplicitEuler",
    "InputError",
    "ModifiedNewton",
    "Newton",
    "NonFiniteError",
    "Remap",
    "SaveAt",
    "SemiDiscrete",
    "Sensitivities",
    "SensitivityMethod",
    "SingularMatrixError",
    "Solution",
    "SolverState",
    "SparseJacobian",
    "Stats",
    "StepController",
    "StepEnd",
    "StepFailure",
    "StepReport",
    "StepSolver",
    "TimeScheme",
    "color_columns",
    "continuation",
    "critical_load",
    "detect_sparsity",
    "evaluate_series",
    "factorize",
    "float64",
    "integrate",
    "make_scheme",
    "make_solver",
    "newton_continuation",
    "scheme_names",
    "sensitivities",
    "solver_kinds",
    "stored_host_state",
    "taylor_coefficients",
    "validity_range",
    "value_and_grad",
]

SUBMODULES = ("checkpoint", "compile_cache", "fsw", "ida", "mls", "sweep")
"""Documented submodules that ``import jaxanm`` does not load: each is imported on its first use
as an attribute (``jaxanm.fsw.run``, ``jaxanm.compile_cache.enable()``), so that importing the
solver stays as fast as it was and the FSW model, Dask or SUNDIALS load only when asked for."""

if TYPE_CHECKING:  # the type checker sees them as plain imports
    from . import checkpoint, compile_cache, fsw, ida, mls, sweep  # noqa: F401
else:
    def __getattr__(name: str):
        """Import a documented submodule on first access (PEP 562)."""
        if name in SUBMODULES:
            import importlib

            return importlib.import_module(f"{__name__}.{name}")
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

    def __dir__():
        """The package's names, the lazily imported submodules included."""
        return sorted({*globals(), *SUBMODULES})

__version__ = "0.2.0"
"""The package version (the one source: pyproject.toml reads it, see CHANGELOG.md)."""
