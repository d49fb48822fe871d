"""jaxanm: a high-order implicit solver (Asymptotic Numerical Method) on JAX.

The residual of an implicit time step is written once in ``jax.numpy``; tangents come from
``jax.jacfwd``, homotopy series coefficients from ``jax.experimental.jet``, and each series
order is solved with one host LU factorisation of K*, reused while the series stays valid.

Every public function runs in float64 (inside ``jax.enable_x64``) without changing JAX's
global configuration; wrap your own jnp code in ``with jaxanm.float64():`` to match.
"""

from ._acceptance import evaluate_series, validity_range
from ._constant_step import ConstantStepSize
from ._factorization import Factorization, factorize
from ._hooks import Remap
from ._integrate import Solution, integrate
from ._run_checkpoint import stored_host_state
from ._saveat import SaveAt
from ._sensitivity_method import SensitivityMethod
from ._series import taylor_coefficients
from ._solver import ANM, ModifiedNewton, Newton, SolverState, StepSolver, make_solver, solver_kinds
from ._step_control import StepController
from ._x64 import float64
from .bordered import ContinuationFailure
from .branch import Branch, BranchPoints
from .continuation import continuation, newton_continuation
from .errors import InputError, NonFiniteError, SingularMatrixError, StepFailure
from .events import Event, StepEnd
from .jacobian import SparseJacobian, color_columns, detect_sparsity
from .sensitivity import ForwardSensitivity, Sensitivities, sensitivities, value_and_grad
from .stats import Stats

__all__ = [
    "ANM",
    "Branch",
    "BranchPoints",
    "ConstantStepSize",
    "ContinuationFailure",
    "Event",
    "Factorization",
    "ForwardSensitivity",
    "InputError",
    "ModifiedNewton",
    "Newton",
    "NonFiniteError",
    "Remap",
    "SaveAt",
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
    "StepSolver",
    "color_columns",
    "continuation",
    "detect_sparsity",
    "evaluate_series",
    "factorize",
    "float64",
    "integrate",
    "make_solver",
    "newton_continuation",
    "sensitivities",
    "solver_kinds",
    "stored_host_state",
    "taylor_coefficients",
    "validity_range",
    "value_and_grad",
]

__version__ = "0.2.0"
"""The package version (the one source: pyproject.toml reads it, see CHANGELOG.md)."""
