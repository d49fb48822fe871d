"""The files and figures of an FSW run: :mod:`~jaxanm.fsw.io.output` (summary.json, fields.npz,
probes.csv, VTU/PVD, the figures' PNGs) and :mod:`~jaxanm.fsw.io.figures` (the paper's figures
from an :class:`~jaxanm.fsw.record.FSWResult`)."""
