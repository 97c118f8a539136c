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


def test_a_node_uploaded_to_keeps_its_new_notches_and_one_not_yet_uploaded_gets_its_old_ones_back():
    one, two = FakeSlots({0: NOTCH}, node_id=1), FakeSlots({1: NOTCH}, node_id=2)  # both filter: both bypassed
    step = NodeNotchStep(Config(), [one, two], Progress(enabled=False), [])
    step.bypass()
    assert one.slots[0] == (NOTCH, False) and two.slots[1] == (NOTCH, False)
    step.nodes[0].uploaded = True  # node 1's slots hold the new notches (the upload stopped before node 2)
    assert step.uploaded
    step.restore()
    assert one.slots[0] == (NOTCH, False)  # not put back over node 1's new notch
    assert two.slots[1] == (NOTCH, True)
