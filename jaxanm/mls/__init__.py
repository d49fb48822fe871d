"""Moving-least-squares (MLS) shape functions as padded gather stencils.

This package holds the meshless spatial discretisation of jaxanm (paper section 3.2):

- :class:`Stencils`, a JAX pytree of ``(N, m)`` neighbour indices and MLS shape-function
  weights (value, first and second derivatives) at N evaluation points;
- :func:`build_stencils` (every point of the cloud is both an MLS node and a collocation
  point) and :func:`evaluate_at` (stencils at arbitrary targets, e.g. probes and sections),
  which share one code path; :func:`value_matrix`, the value operator as a sparse matrix;
- :func:`value`, :func:`grad`, :func:`hessian`, :func:`laplacian`: pure gathers and sums,
  safe inside ``jax.jit``, ``jax.jacfwd`` and ``jax.experimental.jet`` (trace those inside
  ``jax.enable_x64(True)``, as jaxanm's entry points do, or inputs are cast to float32);
- :class:`NeighbourList`, the neighbour candidates kept for a moving cloud.

The MLS approximation has the quadratic basis ``p = [1, x, y, x^2, xy, y^2]`` and the weight
of paper eq. 30, ``w(r) = exp(-(r/c)^(2q))`` for ``r <= 1``, 0 otherwise, ``r = |x - x_j| / h``.
Its shape functions and their first and second derivatives come in closed form from one QR
factorisation of ``sqrt(W) P`` per stencil (``jaxanm/mls/_shape.py``), computed for all
evaluation points by numpy on the host or, for stencils rebuilt at every step, in a few jitted
calls (``_kernel.py``; :func:`compile_values_ahead` starts the value-only kernel's
compilation in the background); stencils whose moment matrix is
too ill-conditioned are refused (``_condition.py``).  Neighbours come from
``scipy.spatial.cKDTree``, or for a moving cloud from the candidate lists of a
:class:`NeighbourList` (``_neighbours.py``), remade only when some point has moved far.

Accuracy (quadratic basis, tests/test_mls.py): quadratic fields are reproduced to round-off;
for smooth fields the errors decrease as dr^3 (value), dr^2 (first derivatives) and dr
(second derivatives) on irregular clouds; at the nodes of a regular grid symmetry raises the
value and second-derivative orders to 4 and 2.
"""

from ._gather import grad, hessian, laplacian, value
from ._kernel import compile_values_ahead
from ._neighbours import NeighbourList
from ._stencils import Stencils, build_stencils, evaluate_at, value_matrix

__all__ = [
    "NeighbourList",
    "Stencils",
    "build_stencils",
    "compile_values_ahead",
    "evaluate_at",
    "value_matrix",
    "value",
    "grad",
    "hessian",
    "laplacian",
]
