"""Friction stir welding (paper section 4): scenes, the step residual of their effects, runs.

Along the data flow (docs/architecture.md):

- :mod:`~jaxanm.fsw.scene`: typed, validated scenes (Python, TOML, ``--set`` overrides);
- :mod:`~jaxanm.fsw.geometry`: point cloud and MLS stencils split at the tool edge;
- :mod:`~jaxanm.fsw.physics`: the strong-form MLS residual rows of the effects a scene lists and
  the constitutive laws;
- :mod:`~jaxanm.fsw.discretisation`: unknown layout, residual parameters, initial state,
  sparsity and refit (:class:`Model`, :func:`discretise`);
- :mod:`~jaxanm.fsw.record` and :mod:`~jaxanm.fsw.lagrangian`: what a run records at its steps
  (:class:`FSWResult`) and how its points move and are re-seeded;
- :mod:`~jaxanm.fsw.simulate`: :func:`run` a scene to an :class:`FSWResult`;
- :mod:`~jaxanm.fsw.io`: the files and figures of a result;
- :mod:`~jaxanm.fsw.calibration`: gradients w.r.t. K, A, n and least-squares calibration.
"""

from . import calibration
from .discretisation import Discretisation, Model, discretise, make_model
from .record import FSWResult
from .scene import EFFECTS, Scene, SceneError, load_scene, override_keys, shipped_scenes
from .simulate import run

__all__ = [
    "calibration",
    "Discretisation",
    "EFFECTS",
    "FSWResult",
    "Model",
    "discretise",
    "Scene",
    "SceneError",
    "load_scene",
    "make_model",
    "override_keys",
    "run",
    "shipped_scenes",
]
