"""AlignedAssembler under concurrent callers.

A reset (``clear``) from a node's worker thread while the executor delivers a reference must not
raise (it did: KeyError in add_reference).
"""

import sys
import threading

import numpy as np

from subpix_ros.stages.aligned_assembly import AlignedAssembler
from subpix_ros.stages.types import Frame


def test_clear_from_another_thread_while_references_deliver():
    delivered, problems, errors = [], [], []
    asm = AlignedAssembler(delivered.append, lambda: True, problems.append, problems.append)
    img, mask = np.zeros((4, 4), np.uint8), Frame(0, np.ones((4, 4), np.uint8))
    stop = threading.Event()

    def resets():
        while not stop.is_set():
            asm.clear()

    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    t = threading.Thread(target=resets)
    t.start()
    try:
        for k in range(3000):
            ref = 10_000 * (k + 1)
            for j in range(1, 9):  # frames that come before their reference
                stamp = ref + j
                asm.add_link(stamp, ref)
                asm.add_frame(Frame(stamp, img))
                asm.add_mask(Frame(stamp, mask.image))
            try:
                asm.add_reference(Frame(ref, img))
            except Exception as exc:  # noqa: BLE001 - the failure under test
                errors.append(repr(exc))
                break
    finally:
        stop.set()
        t.join()
        sys.setswitchinterval(old)
    assert not errors, errors
    assert delivered, "frames still delivered between resets"
