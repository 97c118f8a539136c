"""Every node's filter slots around a run of several drives (hilident.session.node_notch_step): bypassed while the
mechanism is measured, put back when the run ends before its upload, left with the new notches after it."""

from __future__ import annotations

from hilident.config.tables import Config
from hilident.filters.biquad import Biquad
from hilident.progress import Progress
from hilident.session.node_notch_step import NodeNotchStep
from support.filter_slots import FakeSlots

NOTCH = Biquad((0.99, -1.9, 0.98), (1.0, -1.9, 0.97))
PASS = Biquad.identity()


def _step():
    drives = [FakeSlots({}, node_id=1), FakeSlots({1: NOTCH}, node_id=2)]
    return NodeNotchStep(Config(), drives, Progress(enabled=False), []), drives


def test_an_enabled_slot_of_any_node_is_bypassed_while_measured_and_put_back_when_the_run_ends_early():
    step, (one, two) = _step()
    step.bypass()
    assert two.slots[1] == (NOTCH, False) and one.slots[0] == (PASS, False)
    assert [(f["node"], f["slot"], f["enabled"], f.get("bypassed", False)) for f in step.filters_found] == [
        (1, 0, False, False),
        (1, 1, False, False),
        (2, 0, False, False),
        (2, 1, True, True),
    ]
    step.restore()
    assert two.slots[1] == (NOTCH, True)
    assert step.filters_found[-1]["restored"] is True


def test_after_the_upload_nothing_is_put_back():
    step, (_, two) = _step()
    step.bypass()
    step.uploaded = True  # the drives hold the new notches from here
    step.restore()
    assert two.slots[1] == (NOTCH, False)
