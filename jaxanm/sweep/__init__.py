"""Sweeps: a grid of scene overrides x solver settings, run as independent tasks.

:mod:`~jaxanm.sweep.grid` reads grid files (a base scene, scene overrides and solver settings)
into validated tasks.
"""

from jaxanm.sweep.grid import Grid, GridError, Task, grid_from_dict, read_grid

__all__ = ["Grid", "GridError", "Task", "grid_from_dict", "read_grid"]
