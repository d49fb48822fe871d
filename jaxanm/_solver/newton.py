"""Newton step solvers on one shared iteration: :class:`Newton` (a Jacobian per iteration) and
:class:`ModifiedNewton` (the factorised Jacobian reused while the iteration contracts)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .._checks import real
from .._problem import relative_change
from ..errors import NonFiniteError, StepFailure
from .base import Attempt, AttemptSolver, check_count, check_tol


class _NewtonStep(Attempt):
    """One time step of a :class:`_NewtonIteration` (``opts``); ``fact`` is the factorised
    Jacobian it works with (the state's, rebuilt as the options say)."""

    opts: "_NewtonIteration"

    def run(self, step: int, x_old, t, dt, params, start=None) -> tuple[np.ndarray, None]:
        """Newton iterations from ``x_old`` (or ``start``) until ``|dx| / |x| <= tol``: the
        converged iterate (the residual there is not evaluated: None)."""
        P, st = self.problem, self.report
        x = np.array(x_old if start is None else start, dtype=np.float64)
        previous = None
        change = np.inf
        for _ in range(self.opts.max_iter):
            r = P.residual(x, x_old, t, dt, params)
            r_norm = float(np.max(np.abs(r)))
            if not np.isfinite(r_norm):
                raise NonFiniteError("Newton residual is not finite", step=step, t=t, residual_norm=r_norm)
            just_factored = self.fact is None or not self.opts.reuses_factorization
            if just_factored:
                self.drop_factorization()
                self.fact = P.factorize_in_step(step, x, x_old, t, dt, params, residual_norm=r_norm)
            dx = -P.solve(self.factorized(), r)
            size = P.norm(dx)
            slow = not just_factored and previous is not None and size > self.opts.max_rate * previous
            if slow or not np.isfinite(size):
                if just_factored:
                    raise NonFiniteError("Newton correction is not finite", step=step, t=t, residual_norm=r_norm)
                self.drop_factorization()  # slow or diverging with an old Jacobian: rebuild it here
                previous = None
                continue
            x = x + dx
            st.newton_iterations += 1
            previous = size
            change = relative_change(P, dx, x)
            if change <= self.opts.tol:
                return x, None
        raise StepFailure(f"{type(self.opts).__name__} did not converge in {self.opts.max_iter} iterations "
                          f"(last relative change {change:.3g} > tol {self.opts.tol:g})",
                          step=step, t=t, residual_norm=r_norm)


class _NewtonIteration(AttemptSolver):
    """The Newton iteration shared by :class:`Newton` and :class:`ModifiedNewton`: subclasses
    set ``tol``, ``max_iter``, ``reuses_factorization`` and, when reusing, ``max_rate``.  The new
    state holds the last factorised Jacobian (carried to the next step when
    ``reuses_factorization``)."""

    attempt = _NewtonStep
    tol: float
    max_iter: int
    max_rate: float  # ModifiedNewton's; read only when reuses_factorization


@dataclasses.dataclass(frozen=True)
class Newton(_NewtonIteration):
    """Newton–Raphson: a Jacobian and a factorisation at every iteration (kind ``"newton"``).

    Converged when the relative change of the (scaled) iterates ``|dx| / |x|`` is below ``tol``
    (the paper's delta), a float in (0, 1); at most ``max_iter`` (>= 1) iterations.
    """

    kind = "newton"
    tol: float = 1e-6
    max_iter: int = 30
    reuses_factorization = False  # nothing is reused across iterations or steps

    def __post_init__(self):
        check_tol("Newton", self.tol)
        check_count("Newton", "max_iter", self.max_iter, 1)


@dataclasses.dataclass(frozen=True)
class ModifiedNewton(_NewtonIteration):
    """Modified Newton: the factorised Jacobian is reused across iterations and time steps
    (kind ``"mnewton"``).

    It is rebuilt at the current iterate when the contraction ``|dx_k| / |dx_{k-1}|`` exceeds
    ``max_rate``, in (0, 1) (or the iteration diverges).  Same convergence test as
    :class:`Newton` (``tol`` in (0, 1), ``max_iter`` >= 1).
    """

    kind = "mnewton"
    tol: float = 1e-6
    max_iter: int = 50
    max_rate: float = 0.5
    reuses_factorization = True

    def __post_init__(self):
        check_tol("ModifiedNewton", self.tol)
        check_count("ModifiedNewton", "max_iter", self.max_iter, 1)
        real("ModifiedNewton.max_rate", self.max_rate, 0.0, 1.0, open_low=True, open_high=True,
             hint="e.g. max_rate=0.5")
