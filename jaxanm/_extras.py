"""Optional dependencies ("extras"): imported on first use, with an error that names the extra.

The core (the ANM engine and the FSW model) needs only what ``pip install jaxanm`` installs.
Four features need more, each an extra of the package::

    sweep   dask, distributed    jaxanm sweep, jaxanm.sweep.run_sweep
    ida     scikit-sundae        jaxanm.ida.integrate_ida, sweep tasks of kind "ida"
    metis   pymetis              nested-dissection LU of matrices above 5000 unknowns
    vtu     meshio               VTU/PVD files of jaxanm run (skipped with a warning without it)

``pip install 'jaxanm[all]'`` installs all four.
"""

from __future__ import annotations

import importlib

from jaxanm.errors import InputError

EXTRAS = {"sweep": ("dask", "distributed"), "ida": ("scikit-sundae",), "metis": ("pymetis",),
          "vtu": ("meshio",)}
"""Extra name -> the distributions it installs."""


class MissingExtraError(InputError, ImportError):
    """An optional dependency is not installed; the message names the extra that installs it."""


def missing_extra_message(extra: str, purpose: str, detail: str = "") -> str:
    """``"<purpose> needs <packages> (not installed: <detail>): pip install 'jaxanm[<extra>]'"``."""
    packages = " and ".join(EXTRAS[extra])
    why = f"not installed: {detail}" if detail else "not installed"
    return f"{purpose} needs {packages} ({why}): pip install 'jaxanm[{extra}]'"


def require(module: str, extra: str, purpose: str):
    """Import and return ``module``; if it cannot be imported, raise :class:`MissingExtraError`
    naming ``extra`` (e.g. ``require("meshio", "vtu", "VTU output")``)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(missing_extra_message(extra, purpose, str(exc))) from exc
