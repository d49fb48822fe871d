"""A user's own residual integrated with ANM, Newton and modified Newton, stats side by side.

The problem: 1D nonlinear reaction–diffusion with a power-law (p-Laplacian-type) diffusivity,

    u_t = ( |u_x|^(m-1) u_x )_x + (1 + u^2) u_xx ... written in flux form below,

on x in (0, 1) with u = 0 at both ends, a smoothly pulsating source and a cubic sink.  The
step residual is written once in jax.numpy; every solver uses it as it is.

    python examples/reaction_diffusion.py [--n 200] [--t-end 1.0] [--dt 1e-3]
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np

import jaxanm


def make_problem(n: int = 200, m: float = 1.5, eps: float = 1e-2):
    """Residual, initial state and parameters of the power-law reaction–diffusion problem.

    The diffusive flux is ``(D0 + |u_x|^(m-1)) u_x`` with ``|u_x|`` regularised as
    ``sqrt(u_x^2 + eps^2)`` so that jet never differentiates a power at 0.
    """
    h = 1.0 / (n + 1)
    x = np.linspace(h, 1.0 - h, n)

    def residual(u, u_old, t, dt, p):
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        grad = (up[1:] - up[:-1]) / h
        flux = (p["d0"] + (grad**2 + eps**2) ** ((m - 1) / 2)) * grad
        source = p["s"] * np.sin(np.pi * x) * (1.0 + 0.5 * jnp.sin(2 * jnp.pi * t))
        return (u - u_old) / dt - (flux[1:] - flux[:-1]) / h - source + p["k"] * u**3

    params = {"d0": 0.1, "s": 20.0, "k": 5.0}
    return residual, np.zeros(n), params


def compare(n: int = 200, t_end: float = 1.0, dt: float = 1e-3, tol: float = 1e-6) -> dict:
    """Run the three solvers on the same problem; return ``{name: Solution}``."""
    residual, x0, params = make_problem(n)
    solvers = {
        "ANM p=7": jaxanm.ANM(order=7, tol=tol),
        "Newton": jaxanm.Newton(tol=tol),
        "modified Newton": jaxanm.ModifiedNewton(tol=tol),
    }
    return {
        name: jaxanm.integrate(residual, x0, params, t0=0.0, t1=t_end, dt=dt, solver=solver, jacobian="sparse")
        for name, solver in solvers.items()
    }


def print_table(results: dict) -> None:
    """Print the solvers' statistics side by side, and their distance to the Newton result."""
    ref = results["Newton"].xs[-1]
    rows = [
        ("factorizations", lambda s: s.stats.factorizations),
        ("time steps", lambda s: s.stats.time_steps),
        ("series orders", lambda s: s.stats.series_orders),
        ("residual evaluations", lambda s: s.stats.residual_evaluations),
        ("Newton iterations", lambda s: s.stats.newton_iterations),
        ("continuation sub-steps", lambda s: s.stats.substeps),
        ("min a_max", lambda s: f"{min(s.stats.amax):.3g}" if s.stats.amax else "-"),
        ("wall time [s]", lambda s: f"{s.stats.wall_time_s:.2f}"),
        ("  jacobian", lambda s: f"{s.stats.wall_time['jacobian']:.2f}"),
        ("  factorize", lambda s: f"{s.stats.wall_time['factorize']:.2f}"),
        ("  series/residual", lambda s: f"{s.stats.wall_time['series']:.2f}"),
        ("  solve", lambda s: f"{s.stats.wall_time['solve']:.2f}"),
        ("  other", lambda s: f"{s.stats.wall_time['other']:.2f}"),
        ("max |u - u_Newton| / max|u|", lambda s: f"{np.abs(s.xs[-1] - ref).max() / np.abs(ref).max():.2e}"),
    ]
    names = list(results)
    print(f"{'':30s}" + "".join(f"{name:>18s}" for name in names))
    for label, get in rows:
        print(f"{label:30s}" + "".join(f"{str(get(results[name])):>18s}" for name in names))


def main(argv=None) -> None:
    """Command-line entry: run the comparison and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200, help="grid points")
    parser.add_argument("--t-end", type=float, default=1.0, help="final time")
    parser.add_argument("--dt", type=float, default=1e-3, help="time step")
    parser.add_argument("--tol", type=float, default=1e-6, help="ANM eta and Newton delta")
    args = parser.parse_args(argv)
    print_table(compare(args.n, args.t_end, args.dt, args.tol))


if __name__ == "__main__":
    main()
