"""The FSW recorder's checkpoint layout (``to_checkpoint`` / ``from_checkpoint``): explicit,
versioned, refused when it does not match.  That a resumed run is bit-identical to an
uninterrupted one is tested end to end in test_cli.py, test_fsw_rezone.py and test_fsw_start.py."""

from __future__ import annotations

import pytest

import jaxanm
from jaxanm.fsw.lagrangian import RunRecorder
from jaxanm.fsw.record import Recorder


def _bare(cls):
    """A recorder without its constructor's run (the layout methods need only its attributes)."""
    return object.__new__(cls)


def test_the_layout_names_each_stored_attribute_and_its_version():
    rec = _bare(RunRecorder)
    for i, name in enumerate(RunRecorder.CHECKPOINTED):
        setattr(rec, name, ("value", i))
    stored = rec.to_checkpoint()
    assert stored["version"] == Recorder.CHECKPOINT_VERSION
    assert set(stored) == {"version", *RunRecorder.CHECKPOINTED}
    assert set(Recorder.CHECKPOINTED) < set(RunRecorder.CHECKPOINTED)  # the moving cloud's state besides
    other = _bare(RunRecorder)
    other.from_checkpoint(stored)
    assert all(getattr(other, name) == ("value", i) for i, name in enumerate(RunRecorder.CHECKPOINTED))


def test_another_version_or_a_missing_entry_is_refused_with_the_fix():
    rec = _bare(RunRecorder)
    with pytest.raises(jaxanm.InputError, match=r"layout version 0, this jaxanm reads 1: start the run afresh"):
        rec.from_checkpoint({"version": 0})
    with pytest.raises(jaxanm.InputError, match=r"lacks points, t, .*start the run afresh"):
        rec.from_checkpoint({"version": Recorder.CHECKPOINT_VERSION})
