"""Branch points and branch switching with :func:`jaxanm.continuation`: the bifurcation diagram
of the Chafee-Infante problem, and the buckling of an elastica.

    python examples/bifurcations.py [--out DIR]

prints what it found and writes ``chafee_infante.png`` and ``elastica.png`` into DIR (the
guide's figures: ``--out docs/images``).

**Chafee-Infante.** ``u'' + lam (u - u^3) = 0`` on (0, 1), u(0) = u(1) = 0, by central
differences on N interior points (h = 1 / (N + 1)).  ``u = 0`` solves it for every lam; the
path follower finds where R_u is singular on it, the simple branch points at
``lam_k = (4 / h^2) sin^2(k pi h / 2)``, and each is switched onto: the mode-k branch, k - 1
interior zeros, both halves (``direction=+1`` and ``-1``).

**Elastica.** A cantilever as a chain of N rigid links (angles theta_i) with rotational
springs, under an axial end load: ``R_i = N^2 (2 theta_i - theta_(i-1) - theta_(i+1)) -
lam sin theta_i`` (theta_0 = 0, theta_(N+1) = theta_N), lam = P L^2 / EI.  It stays straight
until the first critical load (N^2 times the lowest eigenvalue of a tridiagonal matrix), then
bends; the continuous elastica bends with ``sqrt(lam) = K(sin^2(alpha / 2))`` at tip rotation
alpha (K: the complete elliptic integral of the first kind).
"""

from __future__ import annotations

import argparse
import functools
import pathlib

import jax.numpy as jnp
import numpy as np
import scipy.special

import jaxanm


@functools.lru_cache(maxsize=None)
def chafee_infante_residual(n: int):
    """``R(u, lam) = (u_(i+1) - 2 u_i + u_(i-1)) / h^2 + lam (u_i - u_i^3)`` on ``n`` interior points."""
    h = 1.0 / (n + 1)

    def residual(u, lam, params):
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        return (up[2:] - 2.0 * u + up[:-2]) / h**2 + lam * (u - u**3)

    return residual


def chafee_infante(n: int = 23, modes: int = 3, peak: float = 0.9, order: int = 8):
    """The trivial branch through the first ``modes`` branch points, and both halves of each
    mode's branch up to ``|u| = peak`` at its first maximum (x = 1 / (2k), a grid point when
    n + 1 is a multiple of 2k): ``(trivial, [(event, up, down), ...])``."""
    residual = chafee_infante_residual(n)
    h = 1.0 / (n + 1)
    lam_k = 4.0 / h**2 * np.sin(np.arange(1, modes + 2) * np.pi * h / 2) ** 2
    # the trivial branch's series is exact: its steps are max_step, below the gaps between branch points
    trivial = jaxanm.continuation(residual, np.zeros(n), 0.0, lam_end=0.5 * (lam_k[-2] + lam_k[-1]),
                                  max_step=0.5 * (lam_k[1] - lam_k[0]), max_steps=200, order=order)
    branches = []
    for k, event in enumerate(trivial.events_of("branch_point"), start=1):
        i = (n + 1) // (2 * k) - 1
        up = trivial.switch(event, stop_at=(i, peak))
        down = trivial.switch(event, direction=-1, stop_at=(i, -peak))
        branches.append((event, up, down))
    return trivial, branches


@functools.lru_cache(maxsize=None)
def elastica_residual(n: int):
    """The chain's equilibrium, ``n`` links (module docstring)."""

    def residual(theta, lam, params):
        padded = jnp.concatenate([jnp.zeros(1), theta, theta[-1:]])
        return n**2 * (2.0 * theta - padded[:-2] - padded[2:]) - lam * jnp.sin(theta)

    return residual


def elastica(n: int = 20, tip: float = 2.5, order: int = 8):
    """The straight chain past its first critical load, and its post-buckling branch from it to
    tip rotation ``tip`` (rad): ``(straight, bent)``."""
    first = 4 * n**2 * np.sin(np.pi / (2 * (2 * n + 1))) ** 2  # the lowest eigenvalue, in closed form
    straight = jaxanm.continuation(elastica_residual(n), np.zeros(n), 0.0, lam_end=1.5 * first, max_step=0.5 * first,
                                   order=order)
    bent = straight.switch(straight.events_of("branch_point")[0], stop_at=(n - 1, tip), max_steps=100)
    return straight, bent


def continuum_elastica(alpha):
    """The continuous elastica at tip rotation ``alpha``: ``(lam, x_tip, y_tip)`` (L = 1)."""
    m = np.sin(np.asarray(alpha) / 2) ** 2
    k, e = scipy.special.ellipk(m), scipy.special.ellipe(m)
    return k**2, 2 * e / k - 1, 2 * np.sqrt(m) / k


def print_table(trivial, branches, straight, bent) -> None:
    """What was found: the branch points, each mode's end, the elastica's."""
    n = trivial.u.shape[1]
    h = 1.0 / (n + 1)
    print("Chafee-Infante, N =", n)
    print(f"{'k':>2} {'branch point lam':>18} {'closed form':>18} {'peak lam':>12} {'zeros':>5} {'steps':>5}")
    for k, (event, up, _) in enumerate(branches, start=1):
        exact = 4 / h**2 * np.sin(k * np.pi * h / 2) ** 2
        zeros = int(np.count_nonzero(np.diff(np.sign(up.u[-1])) != 0))
        print(f"{k:>2} {event.lam:18.12f} {exact:18.12f} {up.lam[-1]:12.6f} {zeros:5d} {up.a.size:5d}")
    n = straight.u.shape[1]
    (event,) = straight.events_of("branch_point")
    lam, _, _ = continuum_elastica(bent.u[-1, -1])
    print(f"elastica, N = {n}: first critical load {event.lam:.12f} "
          f"(4 N^2 sin^2(pi / (2 (2N + 1))) = {4 * n**2 * np.sin(np.pi / (2 * (2 * n + 1))) ** 2:.12f}); "
          f"at tip rotation {bent.u[-1, -1]:g} lam = {bent.lam[-1]:.6f}, continuum {lam:.6f}")
    print(f"factorisations: trivial {trivial.stats.factorizations}, elastica {straight.stats.factorizations} + "
          f"{bent.stats.factorizations}")


def figures(trivial, branches, straight, bent, out: pathlib.Path) -> list:
    """The bifurcation diagram of Chafee-Infante and the elastica's, with its shapes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = trivial.u.shape[1]
    x = np.linspace(0.0, 1.0, n + 2)
    fig, (ax, shapes) = plt.subplots(1, 2, figsize=(11, 4.2))
    s = np.linspace(0.0, trivial.s[-1], 400)
    ax.plot(trivial.evaluate(s)[0], np.zeros_like(s), "k-", lw=1, label="u = 0")
    for k, (event, up, down) in enumerate(branches, start=1):
        i = (n + 1) // (2 * k) - 1
        for half, style in ((up, "-"), (down, "--")):
            lam, u = half.evaluate(np.linspace(0.0, half.s[-1], 300))
            ax.plot(lam, u[:, i], f"C{k - 1}{style}", label=f"mode {k}" if half is up else None)
        ax.plot(event.lam, 0.0, "ko", ms=5)
        shapes.plot(x, np.concatenate([[0.0], up.u[-1], [0.0]]), f"C{k - 1}-",
                    label=f"mode {k}, lam = {up.lam[-1]:.1f}")
    ax.set_xlabel("lam")
    ax.set_ylabel("u at x = 1/(2k)")
    ax.set_title("Chafee-Infante: branch points (dots) and the modes switched onto")
    ax.legend(fontsize=8)
    shapes.set_xlabel("x")
    shapes.set_ylabel("u")
    shapes.set_title("each mode at its last point")
    shapes.legend(fontsize=8)
    fig.tight_layout()
    paths = [out / "chafee_infante.png"]
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)

    fig, (ax, shapes) = plt.subplots(1, 2, figsize=(11, 4.2))
    alpha = np.linspace(0.0, bent.u[-1, -1], 200)
    ax.plot(continuum_elastica(alpha)[0], alpha, "k:", lw=2, label="continuous elastica, K(m)^2")
    lam, theta = bent.evaluate(np.linspace(0.0, bent.s[-1], 300))
    ax.plot(lam, theta[:, -1], "C0-", label=f"chain of {theta.shape[1]} links (switched branch)")
    ax.plot(straight.lam, np.zeros_like(straight.lam), "C0o", ms=3, label="straight chain")
    ax.plot(bent.lam[0], 0.0, "ko", ms=6, label="first critical load")
    ax.set_xlabel("lam = P L^2 / EI")
    ax.set_ylabel("tip rotation (rad)")
    ax.legend(fontsize=8)
    for tip in np.linspace(0.0, bent.u[-1, -1], 6)[1:]:
        found = bent.crossings(tip, bent.u.shape[1] - 1)  # where the tip rotation is ``tip``
        angles = found.u[0]
        xs = np.concatenate([[0.0], np.cumsum(np.cos(angles))]) / angles.size
        ys = np.concatenate([[0.0], np.cumsum(np.sin(angles))]) / angles.size
        shapes.plot(xs, ys, "o-", ms=2, label=f"tip {tip:.1f} rad, lam = {found.lam[0]:.2f}")
    shapes.set_aspect("equal")
    shapes.set_title("the bent chain, clamped at (0, 0)")
    shapes.legend(fontsize=8)
    fig.tight_layout()
    paths.append(out / "elastica.png")
    fig.savefig(paths[1], dpi=110)
    plt.close(fig)
    return paths


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=".", help="folder for the figures")
    args = parser.parse_args()
    trivial, branches = chafee_infante()
    straight, bent = elastica()
    print_table(trivial, branches, straight, bent)
    for path in figures(trivial, branches, straight, bent, pathlib.Path(args.out)):
        print("wrote", path)


if __name__ == "__main__":
    main()
