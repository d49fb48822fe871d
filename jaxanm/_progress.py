"""The progress bar of a run: one tqdm bar over simulated time, for every front end.

Simulated time, not steps: under a step controller the number of steps is unknown until the
end, while ``t / t_end`` always gives the fraction done and the time left.
"""

from __future__ import annotations

import time


class ProgressBar:
    """A tqdm bar over simulated time from 0 to ``t_end`` (s), labelled ``label``, driven by
    ``bar(t, stats)`` after each accepted step (the ``callback`` of :func:`jaxanm.fsw.run`).

    Shows t / t_end, elapsed and remaining wall time, time steps per wall second and the
    factorisations done so far (from ``stats``, a :class:`jaxanm.Stats`).  ``disable=True``
    shows nothing (the calls stay valid).  A context manager: the bar closes once, when the
    ``with`` block ends, however it ends (a run that fails leaves its last state on the
    terminal before the error is printed).
    """

    def __init__(self, t_end: float, label: str, disable: bool = False):
        from tqdm import tqdm

        self.start = time.perf_counter()
        self.bar = tqdm(total=float(t_end), desc=label, unit="s", dynamic_ncols=True, disable=disable,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| t = {n:.4g}/{total:.4g} s "
                                   "[{elapsed}<{remaining}{postfix}]")

    def __call__(self, t, stats) -> None:
        """Advance the bar to simulated time ``t`` and show the statistics of ``stats``."""
        rate = stats.time_steps / max(time.perf_counter() - self.start, 1e-9)
        self.bar.set_postfix_str(f"{rate:.1f} steps/s, {stats.factorizations} factorizations", refresh=False)
        self.bar.update(float(t) - self.bar.n)

    def close(self) -> None:
        """Close the bar (its last state stays on the terminal); closing again does nothing."""
        self.bar.close()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
