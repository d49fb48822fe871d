"""Hand-derived Taylor-series recursions (the paper's quadratic recast), in plain numpy.

This module is the *independent reference* for ``tests/test_jet_vs_hand.py``: it never
imports jax.  It follows section 3 of the source paper (eq. 12-16 and 22-25): every strong
nonlinearity is replaced by new variables bound by quadratic relations or by differential
forms,

    alpha = T^A            T d(alpha)       = A alpha dT                 (eq. 12, 4th line)
    gamma = epsbar^(n-1)   epsbar d(gamma)  = (n-1) gamma d(epsbar)      (eq. 12, 5th line)
    phi   = epsbar^2       epsbar^2         = (2/3) epsdot:epsdot        (eq. 12-13)
    mu    = (K/3) alpha gamma,   sigma = 2 mu epsdot,   q = 3 beta mu phi   (eq. 13)

and the unknowns are expanded as power series in the path parameter ``a`` (eq. 23).
Equating like powers of ``a`` turns each quadratic relation into a Cauchy product and each
differential form into a linear recursion for the new order, whose right-hand side depends
only on lower orders (the ``(.)^nl`` terms of eq. 20 and 25).

Series are numpy arrays ``S`` of shape ``(K + 1, *shape)``: ``S[k]`` is the coefficient of
``a^k`` (plain Taylor coefficients, not multiplied by ``k!``).  ``S[0]`` is the value at ``a = 0``
(in the paper the expansion is in increments, ``Delta X = X - X^k``, so that the order-0
term is the known state ``X^k``; here we carry the full variable, which is the same
recursion with the order-0 term kept explicitly).

Two model problems are provided:

* :func:`viscous_flow_series` -- 1D power-law viscous flow with temperature-dependent
  viscosity ``mu = (K/3) T^A epsbar^(n-1)`` and dissipation heating (the friction-stir-welding
  analogue of the paper's problem (11)), one implicit Euler step, flux form on faces.
* :func:`arrhenius_series` -- 2D reaction-diffusion of temperature and reactant with an
  Arrhenius source ``c exp(-E/T)`` and a conductivity ``k0 / (1 + b T)``, recast with
  ``w = T^2`` and ``w dr = E r dT`` for ``r = exp(-E/T)`` and ``(1 + b T) z = 1``.
"""

from __future__ import annotations

import numpy as np

# ---------------------------------------------------------------------------------------------
# Order-by-order building blocks
# ---------------------------------------------------------------------------------------------


def constant_series(value, order: int, shape=()) -> np.ndarray:
    """Series of a constant: ``value`` at order 0, zero above."""
    out = np.zeros((order + 1, *np.broadcast_shapes(np.shape(value), tuple(shape))))
    out[0] = value
    return out


def cauchy(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Series of the product ``x y``: ``(x y)_k = sum_{j=0}^{k} x_j y_{k-j}``.

    This is how every quadratic relation of eq. (13) turns into eq. (16)/(25): at order
    ``k`` the two terms ``x_0 y_k + x_k y_0`` are linear in the new order and the rest
    (``j = 1..k-1``) is the known right-hand side ``(.)^nl_k``.
    """
    x, y = np.broadcast_arrays(x, y)
    out = np.zeros_like(x, dtype=np.float64)
    for k in range(x.shape[0]):
        out[k] = sum(x[j] * y[k - j] for j in range(k + 1))
    return out


def sqrt_series(g: np.ndarray) -> np.ndarray:
    """Series of ``s = sqrt(g)`` from the quadratic relation ``s^2 = g`` (``g_0 > 0``).

    Order ``k`` of ``s s = g`` reads ``2 s_0 s_k + sum_{j=1}^{k-1} s_j s_{k-j} = g_k``:
    the paper's ``2 epsbar^k Delta epsbar = ... - Delta epsbar^2`` (eq. 16, 5th line), so

        s_k = (g_k - sum_{j=1}^{k-1} s_j s_{k-j}) / (2 s_0).
    """
    s = np.zeros_like(g, dtype=np.float64)
    s[0] = np.sqrt(g[0])
    for k in range(1, g.shape[0]):
        nl = sum(s[j] * s[k - j] for j in range(1, k))
        s[k] = (g[k] - nl) / (2.0 * s[0])
    return s


def power_series(x: np.ndarray, p: float) -> np.ndarray:
    """Series of ``y = x^p`` from the differential form ``x dy = p y dx`` (``x_0 > 0``).

    This is eq. (12)'s ``T d(alpha) = A alpha dT`` (``p = A``) and
    ``epsbar d(gamma) = (n-1) gamma d(epsbar)`` (``p = n - 1``).  With ``d/da`` of the series,
    ``x y' = p x' y`` at order ``a^(k-1)`` gives

        sum_{j=0}^{k} (k-j) x_j y_{k-j} = p sum_{j=1}^{k} j x_j y_{k-j},

    i.e. the linear equation for the new order (the paper's ``T^k d Delta alpha = A alpha^k
    d Delta T + alpha^nl``):

        k x_0 y_k = sum_{j=1}^{k} (p j - (k - j)) x_j y_{k-j}.
    """
    y = np.zeros_like(x, dtype=np.float64)
    y[0] = x[0] ** p
    for k in range(1, x.shape[0]):
        rhs = sum((p * j - (k - j)) * x[j] * y[k - j] for j in range(1, k + 1))
        y[k] = rhs / (k * x[0])
    return y


def reciprocal_series(w: np.ndarray) -> np.ndarray:
    """Series of ``z = 1 / w`` from the quadratic relation ``w z = 1`` (``w_0 != 0``).

    Order ``k >= 1`` of the Cauchy product: ``w_0 z_k + sum_{j=1}^{k} w_j z_{k-j} = 0``.
    """
    z = np.zeros_like(w, dtype=np.float64)
    z[0] = 1.0 / w[0]
    for k in range(1, w.shape[0]):
        z[k] = -sum(w[j] * z[k - j] for j in range(1, k + 1)) / w[0]
    return z


def arrhenius_factor_series(T: np.ndarray, energy: float) -> np.ndarray:
    """Series of ``r = exp(-E / T)`` by a quadratic recast, without any exp or division series.

    ``dr = r E / T^2 dT`` becomes, with the new quadratic variable ``w = T^2`` (a Cauchy
    product), the differential form ``w dr = E r dT`` -- the same pattern as eq. (12).  Order
    ``a^(k-1)`` of ``w r' = E T' r``:

        sum_{j=0}^{k} (k-j) w_j r_{k-j} = E sum_{j=1}^{k} j T_j r_{k-j},

    so ``k w_0 r_k = E sum_{j=1}^{k} j T_j r_{k-j} - sum_{j=1}^{k-1} (k-j) w_j r_{k-j}``.
    (``jet`` instead propagates the series through a division and then ``exp``.)
    """
    w = cauchy(T, T)
    r = np.zeros_like(T, dtype=np.float64)
    r[0] = np.exp(-energy / T[0])
    for k in range(1, T.shape[0]):
        rhs = energy * sum(j * T[j] * r[k - j] for j in range(1, k + 1))
        rhs = rhs - sum((k - j) * w[j] * r[k - j] for j in range(1, k))
        r[k] = rhs / (k * w[0])
    return r


# ---------------------------------------------------------------------------------------------
# Problem 1: 1D power-law viscous flow, mu(T, epsbar), dissipation heating
# ---------------------------------------------------------------------------------------------

VISCOUS_PARAMS = dict(
    rho=1.0,  # density
    cp=1.0,  # heat capacity
    dt=0.1,  # time step
    h=1.0 / 11.0,  # grid spacing (12 nodes on [0, 1])
    k_cond=0.02,  # conductivity
    K=3.0 * 450.0**3.3155,  # consistency, sized so that mu = O(1) at T = 450 K, epsbar = 1
    A=-3.3155,  # thermal-softening exponent (AA7075)
    n=0.1324,  # strain-rate sensitivity (AA7075)
    eps0=0.05,  # regularisation of epsbar at rest
    beta=1000.0,  # heating coefficient (nondimensional: the 0.9 of the paper times a scale)
    u_wall=0.05,  # tool velocity at x = 0 (Dirichlet)
    q_in=2.0,  # heat flux entering at x = 0
    h_conv=0.5,  # Robin coefficient at x = 1
    T_amb=300.0,  # ambient temperature
)
"""Parameters of problem 1: nondimensional apart from T in kelvin, so that ``T^A`` keeps
the paper's AA7075 exponent while the viscous, conductive and heating terms are O(0.1-10)."""


def viscous_flow_series(U: np.ndarray, T: np.ndarray, u_old, T_old, prm: dict) -> dict:
    """Taylor series of the implicit-Euler residual of problem 1, by the quadratic recast.

    Finite-volume form on ``N`` nodes, faces ``f = i + 1/2`` between nodes ``i`` and ``i+1``::

        d_f    = (u_{i+1} - u_i) / h                   velocity gradient on a face
        T_f    = (T_i + T_{i+1}) / 2
        epsbar = sqrt(d^2 + eps0^2)                     regularised equivalent strain rate
        mu_f   = (K/3) T_f^A epsbar_f^(n-1)
        sigma  = mu d,   q = beta mu d^2,   F = k (T_{i+1} - T_i) / h
        R_u[i] = rho h (u_i - u_old_i)/dt - (sigma_{i+1/2} - sigma_{i-1/2})
        R_T[i] = rho Cp h (T_i - T_old_i)/dt - (F_{i+1/2} - F_{i-1/2})
                 - h (q_{i-1/2} + q_{i+1/2}) / 2

    on interior nodes, with ``u_0 = u_wall``, ``u_{N-1} = 0``, an imposed flux
    ``-F_{1/2} = q_in`` at ``x = 0`` and Robin cooling ``F_{N-3/2} + h_conv (T - T_amb) = 0``
    at ``x = 1``.  ``U`` and ``T`` are series of shape ``(K + 1, N)``.

    Returns a dict with the residual series ``R_u``, ``R_T``, the series of the recast
    variables (``d, phi, g, epsbar, alpha, gamma, mu, sigma, q``) and the nonlinear parts of
    the two residuals, ``nl_u = -(sigma_{i+1/2} - sigma_{i-1/2})`` and
    ``nl_T = -h (q_{i-1/2} + q_{i+1/2}) / 2`` (interior nodes).
    """
    p = prm
    order = U.shape[0] - 1
    h = p["h"]

    # Linear kinematics (eq. 13, 4th line, in 1D): the face gradient is linear in U.
    d = (U[:, 1:] - U[:, :-1]) / h
    T_f = 0.5 * (T[:, 1:] + T[:, :-1])

    # phi = d^2 and g = epsbar^2 = phi + eps0^2 (eq. 12, 3rd line; eq. 13, 5th line).  Order k:
    # g_k = 2 d_0 d_k + sum_{j=1}^{k-1} d_j d_{k-j}   (eq. 16, last line).
    phi = cauchy(d, d)
    g = phi + constant_series(p["eps0"] ** 2, order, phi.shape[1:])
    # epsbar from epsbar^2 = g (eq. 16, 5th line).
    epsbar = sqrt_series(g)
    # alpha = T^A via T d(alpha) = A alpha dT (eq. 12, 4th line; eq. 16, 7th line).
    alpha = power_series(T_f, p["A"])
    # gamma = epsbar^(n-1) via epsbar d(gamma) = (n-1) gamma d(epsbar) (eq. 12, 5th line;
    # eq. 16, 8th line).
    gamma = power_series(epsbar, p["n"] - 1.0)
    # mu = (K/3) alpha gamma (eq. 13, 6th line; eq. 16, 6th line).
    mu = (p["K"] / 3.0) * cauchy(alpha, gamma)
    # Shear stress on faces, sigma = mu d (1D form of sigma = 2 mu epsdot; eq. 16, 3rd line).
    sigma = cauchy(mu, d)
    # Dissipation heating q = beta mu phi (eq. 13, 9th line, 1D shear: 3 epsbar^2 -> d^2).
    q = p["beta"] * cauchy(mu, phi)

    # Linear assembly, order by order (the constants enter at order 0 only).
    F = p["k_cond"] / h * (T[:, 1:] - T[:, :-1])
    nl_u = -(sigma[:, 1:] - sigma[:, :-1])
    nl_T = -0.5 * h * (q[:, :-1] + q[:, 1:])
    du = U - constant_series(u_old, order)
    dT = T - constant_series(T_old, order)
    R_u = np.zeros_like(U)
    R_u[:, 1:-1] = p["rho"] * h / p["dt"] * du[:, 1:-1] + nl_u
    R_u[:, 0] = U[:, 0] - constant_series(p["u_wall"], order)
    R_u[:, -1] = U[:, -1]
    R_T = np.zeros_like(T)
    R_T[:, 1:-1] = p["rho"] * p["cp"] * h / p["dt"] * dT[:, 1:-1] - (F[:, 1:] - F[:, :-1]) + nl_T
    R_T[:, 0] = -F[:, 0] - constant_series(p["q_in"], order)
    R_T[:, -1] = F[:, -1] + p["h_conv"] * (T[:, -1] - constant_series(p["T_amb"], order))
    return dict(
        R_u=R_u, R_T=R_T, d=d, phi=phi, g=g, epsbar=epsbar, alpha=alpha, gamma=gamma,
        mu=mu, sigma=sigma, q=q, nl_u=nl_u, nl_T=nl_T,
    )


# ---------------------------------------------------------------------------------------------
# Problem 2: 2D Arrhenius reaction-diffusion with a T-dependent conductivity
# ---------------------------------------------------------------------------------------------

ARRHENIUS_PARAMS = dict(
    h=0.25,  # grid spacing
    dt=0.0625,  # time step (h^2 / dt = 1)
    k0=6.0,  # conductivity k(T) = k0 / (1 + b T)
    b=0.01,  # thermal degradation of the conductivity, 1/K
    D=0.5,  # reactant diffusivity
    E=3000.0,  # activation temperature E/R, in kelvin
    Z=2.0e3,  # pre-exponential factor
    Q=20.0,  # temperature rise per unit of reactant consumed
)
"""Parameters of problem 2 (temperatures in kelvin, the rest nondimensional), chosen so
that storage, conduction and reaction are all O(1-10) in the residual."""


def _face_pairs(S: np.ndarray) -> tuple:
    """Values on both sides of every interior face of a 2D grid, for series ``S`` of shape
    ``(K + 1, nx, ny)``: ``(lo, hi)``, each of shape ``(K + 1, n_faces)``, x-faces first."""
    nk = S.shape[0]
    lo = np.concatenate([S[:, :-1, :].reshape(nk, -1), S[:, :, :-1].reshape(nk, -1)], axis=1)
    hi = np.concatenate([S[:, 1:, :].reshape(nk, -1), S[:, :, 1:].reshape(nk, -1)], axis=1)
    return lo, hi


def _net_outflow(flux: np.ndarray, shape: tuple) -> np.ndarray:
    """Sum over the faces of each cell of the face fluxes ``flux`` (positive from ``lo`` to
    ``hi``, as returned by :func:`_face_pairs`); zero flux through the boundary."""
    nx, ny = shape
    nk = flux.shape[0]
    fx = flux[:, : (nx - 1) * ny].reshape(nk, nx - 1, ny)
    fy = flux[:, (nx - 1) * ny :].reshape(nk, nx, ny - 1)
    out = np.zeros((nk, nx, ny))
    out[:, :-1, :] += fx
    out[:, 1:, :] -= fx
    out[:, :, :-1] += fy
    out[:, :, 1:] -= fy
    return out


def arrhenius_series(T: np.ndarray, C: np.ndarray, T_old, c_old, prm: dict) -> dict:
    """Taylor series of the implicit-Euler residual of problem 2, by a quadratic recast.

    Finite volumes on an ``nx x ny`` grid of square cells, zero flux through the boundary
    (on a square grid the face length and the node distance cancel in the conductances)::

        R_T = h^2 (T - T_old)/dt + sum_faces k(T_f) (T_i - T_j) - Q h^2 Z c exp(-E/T)
        R_c = h^2 (c - c_old)/dt + sum_faces D (c_i - c_j)     +   h^2 Z c exp(-E/T)
        k(T_f) = k0 / (1 + b T_f),  T_f = (T_i + T_j) / 2

    New variables: ``z = 1 / (1 + b T_f)`` with ``(1 + b T_f) z = 1``
    (:func:`reciprocal_series`), ``w = T^2`` and ``r = exp(-E/T)`` with ``w dr = E r dT``
    (:func:`arrhenius_factor_series`), then Cauchy products for ``k (T_i - T_j)`` and ``c r``.
    ``T`` and ``C`` are series of shape ``(K + 1, nx, ny)``.

    Returns a dict with ``R_T``, ``R_c``, the series ``z``, ``r``, ``rate`` (``h^2 Z c r``)
    and the nonlinear parts ``nl_T`` (conduction and heat release) and ``nl_c`` (``rate``).
    """
    p = prm
    order = T.shape[0] - 1
    shape = T.shape[1:]
    storage = p["h"] ** 2 / p["dt"]

    T_lo, T_hi = _face_pairs(T)
    T_f = 0.5 * (T_lo + T_hi)
    z = reciprocal_series(constant_series(1.0, order, T_f.shape[1:]) + p["b"] * T_f)
    conduction = _net_outflow(p["k0"] * cauchy(z, T_lo - T_hi), shape)
    C_lo, C_hi = _face_pairs(C)
    diffusion = _net_outflow(p["D"] * (C_lo - C_hi), shape)

    r = arrhenius_factor_series(T, p["E"])
    rate = p["h"] ** 2 * p["Z"] * cauchy(C, r)

    nl_T = conduction - p["Q"] * rate
    R_T = storage * (T - constant_series(T_old, order)) + nl_T
    R_c = storage * (C - constant_series(c_old, order)) + diffusion + rate
    return dict(R_T=R_T, R_c=R_c, z=z, r=r, rate=rate, nl_T=nl_T, nl_c=rate)
