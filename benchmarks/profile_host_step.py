"""Profile of the host work of one Lagrangian ``fsw_paper`` step (issue 14, item 1).

The host work is :meth:`jaxanm.fsw.lagrangian.RunRecorder.after_step`: field values at the points,
probes, moving the points, the shear test, the stencil rebuild and the refit of the state.
This script

1. builds ``fsw_paper`` and runs ``--warm`` Newton steps with the run's own recorder as the
   ``after_step`` hook (a developed flow: the points move as in a run);
2. times each part of one host step separately on that state, and the whole hook, as medians
   of wall and process CPU time over ``--repeats`` calls (each on a copy of the recorder, so
   every call is the same step);
3. prints a table and writes ``benchmarks/results/profile_host_step.json`` (one entry per ``--label``, earlier
   labels kept) and ``benchmarks/results/profile_host_step.md`` (every label side by side).

    python benchmarks/profile_host_step.py --label before

Another checkout's code is profiled by putting it first on the path (the script's
compatibility checks let it time the code of before issue 14 too):

    PYTHONPATH=/path/to/old/checkout python benchmarks/profile_host_step.py --label old --commit abc1234
"""

from __future__ import annotations

import argparse
import copy
import datetime
import inspect
import json
import os
import pathlib
import time

import numpy as np

import jaxanm
from jaxanm import mls
from jaxanm.fsw import discretise, load_scene
from jaxanm.fsw.geometry import _apart

try:  # the hook's module since issue 17's split of fsw/
    from jaxanm.fsw import lagrangian as sim
    Hook = sim.RunRecorder
except ImportError:  # an older checkout: the hook was simulate._Recorder
    from jaxanm.fsw import simulate as sim
    Hook = sim._Recorder

try:  # the compiled kernel's module since jaxanm.mls became a package
    from jaxanm.mls._kernel import run_kernel
except ImportError:  # an older checkout: one module jaxanm/mls.py
    run_kernel = mls._run_kernel

RESULTS = pathlib.Path(__file__).resolve().parent / "results"
"""Where the committed benchmark outputs live."""


def warm_state(steps: int = 3, scene_name: str = "fsw_paper"):
    """Scene, model, recorder and the state after ``steps`` Newton steps of a Lagrangian run.

    Returns ``(scene, model, recorder, t, x, params)``: ``x`` is the last accepted state as the
    solver returned it, *before* its ``after_step`` (the recorder is one step behind: its points
    are those ``x`` was solved on), ``params`` the residual parameters on those points.
    """
    scene = load_scene(scene_name)
    _, stencils, model, params, x0 = discretise(scene)
    dt = scene.time.dt
    recorder = Hook(scene, model, stencils, x0, set())
    # keep the recorder and params as they were before the last hook call
    last = {}

    def hook(t_new, x_new, p):
        last.update(recorder=copy.deepcopy(recorder), t=float(t_new), x=np.asarray(x_new), params=p)
        return recorder.after_step(t_new, x_new, p)

    jaxanm.integrate(model.residual, x0, params, t0=0.0, t1=steps * dt, dt=dt,
                     solver=jaxanm.Newton(tol=1e-6), scale=model.scale(), jacobian="sparse",
                     sparsity=model.sparsity, after_step=hook)
    return scene, model, last["recorder"], last["t"], last["x"], last["params"]


def median_ms(fn, repeats: int, setup=None) -> tuple:
    """Median wall time and median process CPU time (all threads) of ``fn(setup())`` in ms over
    ``repeats`` calls (setup not timed).  On a machine shared with other processes the CPU time
    follows the load much less than the wall time, which counts the waits for a core."""
    wall, cpu = [], []
    for _ in range(repeats):
        arg = setup() if setup is not None else None
        t, c = time.perf_counter(), time.process_time()
        fn(arg)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))


def profile(recorder, t, x, params, repeats: int) -> dict:
    """Median ``(wall, CPU)`` ms per part of one host step, and of the whole ``after_step`` hook."""
    model, scene = recorder.model, recorder.scene
    g = scene.geometry
    kind, omega = model.cloud.kind, scene.tool.omega
    dt = t - recorder.t
    st = params["st"]
    values = model.values(x, st)
    full = model.full_values(values)
    moved = sim._move(recorder.points, kind, sim._velocity(full), omega, dt)
    new_st = sim.cloud_stencils(moved, model.cloud.n_tool, g, m_max=recorder.width)
    fresh = lambda: copy.deepcopy(recorder)  # noqa: E731 - every timed call sees the same step
    parts = {}
    parts["values (model.values)"] = median_ms(lambda _: model.values(x, st), repeats)
    parts["full values"] = median_ms(lambda _: model.full_values(values), repeats)
    parts["record probes"] = median_ms(lambda r: r._record(t, moved, full, False), repeats, fresh)
    parts["move"] = median_ms(lambda _: sim._move(recorder.points, kind, sim._velocity(full), omega, dt), repeats)
    # the code before issue 14 took no arguments here (a cKDTree per call): both are profiled
    takes_index = len(inspect.signature(recorder._sheared).parameters) > 0
    parts["shear test"] = median_ms(lambda r: r._sheared(np.asarray(st.index)) if takes_index else r._sheared(),
                                    repeats, fresh)
    if hasattr(recorder, "neighbours"):  # as the hook rebuilds: with the run's candidate lists
        parts["stencils (total)"] = median_ms(
            lambda r: sim.cloud_stencils(moved, model.cloud.n_tool, g, m_max=recorder.width, neighbours=r.neighbours),
            repeats, fresh)
    else:
        parts["stencils (total)"] = median_ms(
            lambda _: sim.cloud_stencils(moved, model.cloud.n_tool, g, m_max=recorder.width), repeats)
    # the stencil rebuild's two halves: neighbour search, MLS kernel (how mls._stencils calls them)
    apart = _apart(moved, model.cloud.n_tool, g)
    h = np.full(len(apart), g.h_factor * g.dr)
    m = recorder.width
    parts["  neighbour search (cKDTree)"] = median_ms(
        lambda _: sim.cKDTree(apart).query(apart, k=m, distance_upper_bound=float(np.nextafter(h.max(), np.inf))),
        repeats)
    if hasattr(recorder, "neighbours"):  # the run's candidate lists, as the hook uses them
        parts["  neighbour search (candidate lists)"] = median_ms(lambda r: r.neighbours.query(apart, h, m)[:2],
                                                                 repeats, fresh)
    index = np.asarray(new_st.index)
    mask = np.asarray(new_st.phi) != 0
    x_loc = (apart[:, 0][index] - apart[:, :1]) / h[:, None]
    y_loc = (apart[:, 1][index] - apart[:, 1:]) / h[:, None]
    # the kernel took (n, m, 2) local coordinates before issue 14's single-call kernel, x and y after
    kernel_args = ((x_loc, y_loc) if "y" in inspect.signature(run_kernel).parameters
                   else (np.stack([x_loc, y_loc], axis=-1),))
    # a moving cloud's rebuilds run the compiled kernel (``compiled``, where the checkout has the choice)
    compiled = {"compiled": True} if "compiled" in inspect.signature(run_kernel).parameters else {}
    parts["  MLS kernel (_run_kernel)"] = median_ms(
        lambda _: run_kernel(*kernel_args, mask, h, float(g.c), int(g.q), **compiled), repeats)
    parts["params"] = median_ms(lambda _: model.params(moved, new_st), repeats)
    parts["refit (fit_state, new splu)"] = median_ms(lambda _: model.fit_state(values, new_st), repeats)
    if hasattr(recorder, "refit"):  # preconditioned by the previous step's factorisation, as the hook does
        # (and from the state just solved, where fit_state takes a guess)
        guess = {"guess": x} if "guess" in inspect.signature(model.fit_state).parameters else {}
        parts["refit (fit_state, iterative)"] = median_ms(lambda r: model.fit_state(values, new_st, r.refit, **guess),
                                                          repeats, fresh)
    parts["  value matrix"] = median_ms(lambda _: mls.value_matrix(new_st), repeats)
    vm = mls.value_matrix(new_st)
    parts["  splu of the value matrix"] = median_ms(lambda _: jaxanm._factorization.sparse_lu(vm), repeats)
    parts["after_step (whole hook)"] = median_ms(lambda r: r.after_step(t, x, params), repeats, fresh)
    # after a rezoning, each step also evaluates the fields at the material points (markers)
    def markers(r, targets):
        if hasattr(r, "marker_neighbours"):
            return r._values_at(x, targets, r.marker_neighbours)
        return r._values_at(x, targets)

    def primed():  # markers' candidate lists made for these targets (a run remakes them every ~50 steps)
        r = fresh()
        markers(r, moved)
        return r

    parts["values at the markers (after a rezoning)"] = median_ms(lambda r: markers(r, moved), repeats, primed)
    parts["  the same with derivative stencils"] = median_ms(
        lambda _: model.values(x, sim.evaluate_stencils(recorder.points, model.cloud.n_tool, g, moved)), repeats)

    def rezoned():  # after a rezoning: material points (here where the nodes are) with primed lists
        first = fresh()
        first.markers = recorder.points.copy()
        first.after_step(t, x, params)
        r = fresh()
        r.markers, r.marker_neighbours = recorder.points.copy(), first.marker_neighbours
        return r

    parts["after_step after a rezoning (with markers)"] = median_ms(lambda r: r.after_step(t, x, params), repeats,
                                                                     rezoned)
    return parts


CHANGES = """\
## Second round (labels 'before blocked kernel' and 'blocked kernel, refit from x')

Measured on a 2-core AMD EPYC (AVX-512), about 2.5x faster per step than the machine of the
first four labels, shared with other runs (load about 4; single runs at load 5-6 scattered by
+-20 %): compare the last two labels with each other only, each the median of three runs
alternated with the other's.  The whole hook 8.5 -> 5.6 ms, the hook after a rezoning (with
the material points) 12.8 -> 7.6 ms, the stencil rebuild 6.0 -> 3.9 ms.  The issue's 5 ms
is not reached at this load (5.6 ms); the code of 871164a took 8.0 ms at load 2.8 against 8.5
here, so an idle machine may bring the hook to about 5 ms (not measured: none was idle).

- **MLS kernel** (`mls._run_kernel`): one jitted call over all points (up to 1024 per call,
  padded to a multiple of 128) instead of 7 calls of 128 -- a call's ~200 XLA fusions each
  have a start-up cost, paid once instead of 7 times (2.3 against 3.3 ms at load 6); inside
  the call a `lax.map` over blocks of 64 points keeps each fusion's arrays in cache (CPU time
  1.73 against 2.10 ms, value-only kernel 0.70 against 0.80); `Q = Q1 R2^-1` applied through
  the 6 x 6 `R2^-1` instead of formed (21 products of (n, m) arrays fewer); the rcond bound
  det / trace^6 from the kernel's own Cholesky factors instead of moment matrices out of the
  kernel and numpy LU determinants (eigenvalues of moments recomputed in numpy for the rows
  the bound does not decide); the all-finite flag as one sum of `a * 0` (six boolean
  reductions had been the kernel's most expensive fusion); the weights stay jax arrays,
  sliced to n on the device, instead of a round trip through numpy and a copy back.  Results
  change by round-off: 2e-16 (phi) to 2e-15 (second derivatives) of sum |w|; tests/test_mls.py
  (50-digit reference, 36 eps / sqrt(rcond) bounds) unchanged and passing.  Cost: compile
  time, 4.1 s for the derivative kernel and 3.4 s for the value-only one (3.2 and 1.7 s
  before), once per shape (multiples of 128 up to 1024) -- `jaxanm run` keeps them in its
  compile cache.
- **refit** (`model.Refit`): the iterations start from the state just solved (off by one
  step's change of the value matrix, and one solve less than `LU0^-1 values`), and refactorise
  after more than 7 iterations instead of 6: replayed on 60 steps with rezonings, 6.2 solves a
  step and a factorisation every 7.5 steps against 6.9 and every 4, each result within 3e-15
  of the direct solve (the same stopping test).  In 0.02 s of fsw_paper: 26 factorisations of
  the value matrix instead of 50.
- **values** (`Model.values`) and the refit's matrix: one CSR product straight from the
  stencil arrays, 0.08 against 0.17 ms.
- **markers** (after a rezoning): MLS values at the free material points only (792 of 881):
  the rigid ones take the nodes' values anyway.  Their candidate lists are no longer remade
  when a rigid edge marker, at r = R1 to round-off, flips between the tool's and the plate's
  side.  This profile now primes the markers' lists on the same targets (a run remakes them
  about every 50 steps); the first four labels' rows remade them in every timed call, for that
  flip, which overstated them.

Results unchanged: fsw_paper to 0.02 s, this round's code against 871164a, largest
differences: fields at the saved times u, v 1.8e-15 of max |V|, T 7.2e-14 of its rise; probes
(every step) T 1.4e-12 of its rise (8e-13 K), u, v 1.8e-13 of the probe's max |V|; sections
3e-13; with `--set geometry.rezone=0.999` (25 rezonings) u, v 1.8e-15, T 7.7e-14 of the rise,
probes T 2.5e-12 (1.0e-12 K).  Same steps, series orders, sub-steps and factorisations.

What is left (CPU time inside the hook, load 5): the MLS kernel about 2 ms (1.5 ms when timed
alone, caches warm: per block of 64 points ~75 reductions over the stencils, ~30 elementwise
passes and ~90 small fusions of the 6 x 6 algebra; traced before the blocks, the reductions
took 0.9 ms of a 1.8 ms call, 10-15 us each over (896, 32)), the refit
1.25 ms (6 SuperLU solves of 3 right-hand sides, 0.14-0.22 ms each, and 6 CSR products,
plus a factorisation every 7.5 steps, 2.5 ms), the neighbour search 0.7-0.8 ms (a cKDTree of
all points every step for the ~23 rows with a node at h to round-off), the rest about 1 ms
(local coordinates, checks, the index array to jax, values, shear test, motion).  Measured and
left: the basis columns stacked into (6, n, m) arrays for fewer, larger reductions (1.3x
slower for the Gram sums, 7x for the products with Q1), reductions as products with a ones
vector (no gain), the transposed (m, n) layout (slower in every run, up to 2.4x).

## Third round (labels 'before (9aefbae), idle' and 'after, idle', 2026-12-03)

Both labels are per-part medians of five runs of 20 repeats, alternated (before, after, ...)
on an idle 2-core AMD EPYC (load 0.8-1.8: the runs' own threads).  Consecutive runs of the
same code differed by up to 1.4x (whole hook, before: 5.5-8.0 ms; after: 5.1-7.9 ms), so only
the medians compare.  The whole hook: 5.99 -> 5.59 ms.

- **rcond screen** (`mls._condition_screen`): the kernel's lower bound of the moment
  matrices' rcond is now ``det ((k-1)/trace)^(k-1) / |A|_F`` (AM-GM on the k - 1 largest
  eigenvalues) instead of ``det / trace^k``, 3e3 to 8e3 times tighter for these
  equilibrated 6 x 6 matrices.  It clears the screen at all 881 points, where the old one sent 148 edge rows to
  numpy moments and eigenvalues: 0.73 ms, timed alone.  Which rows pass is unchanged, and so
  are the fields (bit-identical).
- Outside the hook, in the time loop: `integrate.on_device` keeps the device arrays of the
  leaves a hook's rebuilt params did not change (20 scalar constants, the point kinds):
  0.44 -> 0.15 ms a step.

Timed in place, after the same warm-up, without the profile's copy of the recorder before
each call (so with warm caches), medians of 30 calls at load 1: the hook takes 4.9 ms, of
which the stencil rebuild is 2.85 ms (MLS kernel about 1.7, candidate lists 0.6), the refit
1.45 ms (5-8 SuperLU solves of 3 right-hand sides, 0.14 ms each), values, motion, shear test
and params 0.35 ms.  So the issue's 5 ms is met with warm caches and not in this profile,
whose copy of the recorder before every call leaves the caches cold (5.6 ms).

**This profile underestimates the hook of a real run.** `benchmarks/hook_in_run.py` times
the hook and its parts at every step of fsw_paper from rest to 0.05 s (500 steps), where the
solver's series and triangular solves run between two hooks.  Medians in five runs at load
1-1.5, this session's code: 6.1-9.7 ms (the same code back to back: 6.07 and 9.68 ms, the
machine's speed); in one run of 6.07 ms: stencil rebuild 3.42 (MLS kernel 1.95, neighbour
query 0.88), refit 2.00 (mean 2.45 with its refactorisations), values 0.24, shear test 0.06.
Every part is 1.2-2.4x its time here: the caches hold the solver's data when the hook starts,
and the refit iterates more in a developing flow (6.4 iterations a step over the first 0.02 s
against 5 on this profile's state).  In a run, 9aefbae and this code took 7.16 / 7.01 and
6.33-7.15 ms alternately: the screen's 0.7 ms does not stand out of that spread.  So the
issue's 5 ms is not met in a run, by 1-2 ms.

Measured and left: the block size of the kernel's loop (interleaved in one process, 300
calls each: 16 points 2.16 ms, 32 1.91, 64 1.77, 128 2.26; the results are bit-identical
for every size), and an extrapolated start for the refit (the last step's correction added
to the guess: 6.41 against 6.39 iterations a step over 0.02 s, no gain).

## Fourth round (2026-12-03, second session): why a run's hook is slower, and what was tried

No code of the hook changed in this round; it measured why the hook costs 6-10 ms in a run
against 5-6 ms here, and tried five ways to hide or shorten its critical path.  Idle 2-core
AMD EPYC, load 0.6-1.8 (the runs' own threads).  Today's machine: this profile at HEAD gave
8.10, 7.47, 6.39 and 6.65 ms for the whole hook (four runs), and `hook_in_run.py` 6.88 ms
(stencil rebuild 3.83: neighbour query 0.94, MLS kernel 2.18; refit 2.17; values 0.27).

**Any 5 ms of other work makes the next short call slower, not only a full cache.**
`benchmarks/kernel_after_idle.py` times the hook's MLS kernels and the refit's seven SuperLU
solves back to back and after 5 ms asleep, 5 ms of a busy Python loop (no memory traffic) or
reading 64 MB.  Medians of 200 calls, three runs (ms):

| part | back to back | after 5 ms asleep | after 5 ms busy | after reading 64 MB |
| --- | ---: | ---: | ---: | ---: |
| MLS kernel (values and derivatives) | 1.42-1.50 | 2.00-2.90 | 2.08-3.11 | 2.69-3.58 |
| MLS kernel (values only) | 0.78-1.15 | 1.24-1.96 | 1.37-1.99 | 1.61-2.03 |
| 7 refit solves (3 right-hand sides) | 1.09-1.38 | 1.26-1.90 | 1.17-1.79 | 1.19-2.07 |

Pinned to one CPU (`taskset -c 0`) the kernel took 1.18-1.66 back to back and 1.57-3.47 ms
after the others: the same.  So the cost is not the caches alone (sleeping or spinning moves
no data) nor the XLA worker threads of the second core; it is the state any other work leaves
the core in, and the XLA kernels pay it most (1.4-2.4x, the solves 1.1-1.5x).  In a run every
part of the hook starts after a solver step, hence `hook_in_run.py`'s 1.2-2.4x; this profile,
which copies the recorder before each call, sits between the two.  The run is serial: it
uses about 1.1 cores (`time` of `jaxanm run fsw_paper --t-end 0.05`: 17.4 s user + 3.5 s
system in 19.2 s), and pinned to one CPU it took 17.5 and 14.4 s against 15.7 and 16.6 s on
two, alternated.

Tried and left (measured on this code, alternated, in one process where possible):

- **The refit beside the kernel's derivatives.**  The refit needs only phi.  A kernel split
  in two calls, phi first (with the QR factors as outputs) and the derivatives from them,
  lets the refit run while the second call computes.  The first call alone took 0.9-1.1 ms,
  the two in sequence 2.7-3.3 ms against 1.1-1.4 for the fused kernel (passing the 13 (n, m)
  intermediates costs more than it saves), and the second call beside the seven solves
  3.7-4.3 ms against 2.2-2.5 for the fused kernel followed by the solves.  For scale, the
  whole fused kernel dispatched and the solves run while it computes (impossible in the hook:
  the refit needs its phi) took 2.06 against 3.09 ms in sequence.
- **The material points' work on a worker thread.**  After a rezoning, a step's material
  points take their MLS values on the nodes the step was solved on, move and are recorded;
  nothing the solver needs depends on it (2.4-2.8 ms here).  On a one-thread pool, awaited
  by the next hook, a checkpoint and the result, the records were bit-identical to the inline
  run (fsw_paper with `geometry.rezone=0.999` to 0.05 s; a test comparing threaded and inline
  runs of a rezoned scene).  Timed by per-step medians over alternating blocks of 25 steps
  in one run (0.1 s, rezone 0.999, 40 blocks; threaded minus inline, median over the 20 block
  pairs):
  - submitted at the end of the hook, beside the next step: +1.9 ms (5 of 20 pairs faster)
    at Python's default GIL switch interval, -0.65 ms (11 of 20) at 0.2 ms.  The worker's
    numpy holds the GIL, and the main thread, back from each of the step's GIL-free solves
    and XLA calls, waits up to the switch interval to get it back;
  - submitted before the node stencils' rebuild, beside it and the refit: -3.10, -1.41 and
    -0.28 ms in three runs (15, 14 and 10 of 20 pairs faster).

  So at best about 1.4 ms a step after a rezoning, not resolved from the machine's spread in
  one run of three, for a thread that runs XLA beside the main thread's XLA calls (this
  kernel's batched LAPACK once deadlocked the XLA CPU runtime under load, see `mls`).  Not
  kept.  A single-threaded version of the same overlap (the markers' kernel dispatched before
  the nodes' neighbour query and awaited after the nodes' kernel) needs stencil builds that
  return before their kernel has run.
- **Two threads for the refit's solves** (1 and 2 right-hand sides; SuperLU releases the
  GIL): 0.179 against 0.180 ms in sequence, and 0.150 ms for one call with all 3.
- **XLA options**: the legacy runtime (`--xla_cpu_use_thunk_runtime=false`), the old fusion
  emitters, the concurrency-optimised scheduler off, synchronous dispatch
  (`jax_cpu_enable_async_dispatch=False`).  None was faster back to back or after idling,
  beyond the spread above.
- **The value matrix's SuperLU ordering** (3 right-hand sides, one solve): COLAMD 164,550
  non-zeros in L + U, 0.265 ms; MMD_AT_PLUS_A 93,210, 0.221 ms; MMD_ATA 120,862, 0.150 ms;
  NATURAL 221,550, 0.332 ms.  linalg's settings (`PERMC_SPEC` in symmetric mode) give
  0.147 ms, already the fastest.

Left, knowingly: in the neighbour query the tool centre's row (its third ring at h to
round-off) goes to a cKDTree of all points every step: building it takes 0.17 ms and
querying it 0.11 ms (line profile).  That is the price of keeping cKDTree's decisions for
nodes at h (second round).

So the issue's 5 ms holds back to back (4.9 ms, third round) and not in a run (6-7 ms).  What
is left is the cost of short calls after other work, which the alternation of solver step and
hook imposes.  A few longer host phases would avoid it, or an MLS kernel outside XLA (compiled
code with no executor to wake), which would add a dependency.

## What changed (issue 14, item 1), and what each part gained

- **values** (`Model.values`): numpy gathers of the stencils instead of a jnp dispatch per field.
- **shear test**: the nearest neighbour of each plate point is `index[:, 1]` of the stencils
  the step was solved on (nearest first), instead of a cKDTree of the plate points per step.
- **neighbour search** (`mls.NeighbourList`, skin h/4): candidates within h + skin kept from
  one rebuild to the next, remade when the points (and, for markers, the targets) have moved
  more than the skin allows (fsw_paper: every ~47 steps, by the tool edge's rigid turn); the
  m nearest are the sorted candidates.  Rows with a candidate at h to round-off (the polar
  cloud's tool ring at exactly 3 dr from the centre) are left to cKDTree, whose box pruning
  decides them its own way (measured: a node 11 ulps inside h excluded); without that the
  centre's stencil gained and lost a node of weight exp(-1/c^2) = 1.5e-5 and T at the tool
  centre moved by 1.3e-7 of its rise in 0.02 s.
- **MLS kernel**: chunks of 128 points instead of 512 (the call's working set stays in L2:
  9 vs 15 ms on one core), passed to the jitted kernel as numpy; the rcond check by the bound
  det / trace^6 (0.5 ms) and eigenvalues only where it does not decide (2.2 ms before).  The
  kernel itself (nested `jax.jacfwd` of the 6x6 solve in `mls._kernel`) was then what was left:
  ~9 ms on an idle core, more under load.
- **MLS kernel, closed form** (label 'closed-form MLS', issue 14 item 1 / issue 13 item 2): the
  derivatives of `A gamma = p` written out and solved through a CholeskyQR2 factorisation of
  the equilibrated `sqrt(W) P` (one per point, 6 right-hand sides) instead of autodiff of an
  elimination on `A`: about 2.5x faster than the jacfwd kernel measured back to back, and more
  accurate (at most 2.3 digits lost against a 50-digit reference where the normal equations
  lost 6.1, rcond down to 1e-6).  The support r <= 1 is decided in numpy, outside the jitted
  kernel (XLA contracted x*x + y*y into an FMA, which moved a node at h to round-off in or out
  of the polar cloud's stencils).  `jaxanm run fsw_paper --t-end 0.005` against the code of
  5caeaad: u, v within 3.1e-15, T 7.7e-13 of its rise, probes 7.4e-13 K; same step, series
  and factorisation counts.  The value-only stencils (markers) take phi from the same
  factorisation, so they keep the full stencils' values; that costs more than the old
  elimination on A (values at the markers 19.0 -> 21.7 ms here, the value-only kernel ~1.3x
  in interleaved runs).  The whole stencil rebuild (17.7 ms at load 3.4) is not yet within
  the 5 ms aimed at: the kernel's ~200 small XLA fusions per call dominate.
- **refit** (`model.Refit`): preconditioned Richardson iterations on the previous SuperLU of
  the value matrix, stopped when the estimated remaining error is below 1e-15 of max |x| per
  field (the direct solve's own error is cond eps, cond ~ 3); 5-7 iterations (contraction
  0.0044 with the previous step's factors), a new factorisation when more than 6 were needed
  (about every 4 steps).  The value matrix factorises faster with linalg's new ordering too.
- **after a rezoning** (two thirds of the full run's steps), the fields at the material points
  come from value-only MLS stencils (`evaluate_at(derivatives=False)`: phi alone, the same
  values, 10x cheaper) and candidate lists kept for the moving markers.

Results unchanged: `jaxanm run fsw_paper --t-end 0.02` against the code of af4c632, largest
relative differences (fields at the saved times, probes at every step, `/tmp`-style check as
in the commit messages): u, v 3e-15, T 9e-14 of its rise, probes 3e-12; with
`--set geometry.rezone=0.999` (25 rezonings, markers from step 13 on): T 1.1e-13, probes
1.9e-12.  For scale, one ulp of noise added to each refit of the old code gives 2.5e-13 and
1.5e-12.  Same factorisation counts, series orders and sub-steps.
"""


def _table(data: dict, labels: list, key: str) -> list:
    """Markdown rows of the ``key`` times ("parts_ms" or "parts_cpu_ms") of ``labels``."""
    names = list(dict.fromkeys(k for lab in labels[::-1] for k in data[lab][key]))  # the latest's order
    lines = ["| part | " + " | ".join(labels) + " |", "| --- | " + " | ".join("---:" for _ in labels) + " |"]
    for name in names:
        cells = [data[lab][key].get(name) for lab in labels]
        lines.append(f"| {name.replace('  ', '&nbsp;&nbsp;')} | "
                     + " | ".join("" if c is None else f"{c:.2f}" for c in cells) + " |")
    return lines


def write(label: str, parts: dict, cpu: dict, meta: dict) -> None:
    """Merge this label into benchmarks/results/profile_host_step.json and rewrite the markdown tables."""
    path = RESULTS / "profile_host_step.json"
    data = json.loads(path.read_text()) if path.is_file() else {}
    data[label] = {"parts_ms": parts, "parts_cpu_ms": cpu, **meta}
    path.write_text(json.dumps(data, indent=1) + "\n")
    labels = list(data)
    lines = ["# Host work of one Lagrangian fsw_paper step",
             "",
             "Made by `python benchmarks/profile_host_step.py --label LABEL` (issue 14, item 1): "
             "median ms per part over the repeats, one step of a developed flow (3 Newton steps "
             "from rest), each call on the same state; indented rows are parts of the row above, "
             "an empty cell a path that code did not have.  Load average (1 min) when measured is "
             "given per label; labels measured back to back compare, absolute times follow the load.",
             "",
             "Wall time:",
             ""] + _table(data, labels, "parts_ms")
    with_cpu = [lab for lab in labels if "parts_cpu_ms" in data[lab]]
    if with_cpu:
        lines += ["", "Process CPU time (all threads; on a shared machine it follows the load much less "
                  "than the wall time, which counts the waits for a core):", ""]
        lines += _table(data, with_cpu, "parts_cpu_ms")
    lines += ["", "| label | date | load average | repeats | commit |", "| --- | --- | --- | ---: | --- |"]
    for lab in labels:
        d = data[lab]
        lines.append(f"| {lab} | {d['date']} | {d['loadavg']} | {d['repeats']} | {d.get('commit', '')} |")
    notes = [data[lab].get("note") for lab in labels if data[lab].get("note")]
    if notes:
        lines += [""] + [f"- {lab}: {data[lab]['note']}" for lab in labels if data[lab].get("note")]
    (RESULTS / "profile_host_step.md").write_text("\n".join(lines) + "\n\n" + CHANGES)


def main() -> None:
    """Command line: ``--label``, ``--repeats``, ``--warm``, ``--note``, ``--no-write``, ``--commit``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", default="current")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--warm", type=int, default=3, help="Newton steps before the profiled one")
    ap.add_argument("--note", default="")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--commit", default="", help="commit of the code measured (default: this checkout's HEAD; "
                    "give it when PYTHONPATH points to another checkout)")
    args = ap.parse_args()
    with jaxanm.float64():
        _, _, recorder, t, x, params = warm_state(args.warm)
        for _ in range(3):  # compile and warm every code path once
            copy.deepcopy(recorder).after_step(t, x, params)
        load_before = os.getloadavg()
        timed = profile(recorder, t, x, params, args.repeats)
        load_after = os.getloadavg()
    parts = {name: wall for name, (wall, _) in timed.items()}
    cpu = {name: c for name, (_, c) in timed.items()}
    width = max(map(len, parts))
    print(f"{'':<{width}}  {'wall':>8}     {'CPU':>8}")
    for name in parts:
        print(f"{name:<{width}}  {parts[name]:8.3f} ms  {cpu[name]:8.3f} ms")
    load = f"{load_before[0]:.2f} -> {load_after[0]:.2f}"
    print(f"load average (1 min): {load}")
    if not args.no_write:
        head = os.popen("git -C " + str(RESULTS.parent.parent) + " rev-parse --short HEAD").read().strip()
        commit = args.commit or head
        write(
            args.label,
            parts,
            cpu,
            {
                "date": datetime.date.today().isoformat(),
                "loadavg": load,
                "repeats": args.repeats,
                "commit": commit,
                "note": args.note,
            },
        )


if __name__ == "__main__":
    main()
