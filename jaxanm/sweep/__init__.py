"""Sweeps: a grid of scene overrides x solver settings, run as independent tasks on Dask.

::

    from jaxanm.sweep import read_grid, run_sweep
    result = run_sweep(read_grid("benchmarks/grids/couette_demo.toml"), "results/sweep-couette_demo")
    result.table, result.plot, result.failed

The command line is ``jaxanm sweep GRID.toml``.  Modules: :mod:`~jaxanm.sweep.grid` (grid
files -> tasks), :mod:`~jaxanm.sweep.task` (one task on a worker), :mod:`~jaxanm.sweep.table`
(the results table and its errors), :mod:`~jaxanm.sweep.pareto` (the plot),
:mod:`~jaxanm.sweep.runner` (Dask, skipping finished tasks, the sweep directory).
"""

from jaxanm.sweep.grid import Grid, GridError, Task, grid_from_dict, read_grid
from jaxanm.sweep.runner import SweepResult, run_sweep

__all__ = ["Grid", "GridError", "SweepResult", "Task", "grid_from_dict", "read_grid", "run_sweep"]
