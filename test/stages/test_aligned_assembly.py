"""AlignedAssembler without ROS: frames, masks, references and links in any arrival order."""

import itertools

import numpy as np

from subpix_ros.data import load_crop
from subpix_ros.stages import Frame
from subpix_ros.stages.aligned_assembly import AlignedAssembler

T0 = 1_700_000_000_000_000_000


def _assembler(links=True):
    got, problems = [], []
    asm = AlignedAssembler(got.append, lambda: links, problems.append, problems.append)
    return asm, got, problems


def test_a_frame_goes_with_the_reference_its_link_names_in_every_arrival_order():
    img = load_crop("crop_rows")[:48, :64]
    mask = Frame(T0 + 9, np.full(img.shape, 255, np.uint8))
    events = {
        "ref0": lambda a: a.add_reference(Frame(T0, img)),
        "ref8": lambda a: a.add_reference(Frame(T0 + 8, img)),
        "frame": lambda a: a.add_frame(Frame(T0 + 9, img)),
        "mask": lambda a: a.add_mask(mask),
        "link": lambda a: a.add_link(T0 + 9, T0 + 8),
    }
    for order in itertools.permutations(events):
        asm, got, problems = _assembler()
        for name in order:
            events[name](asm)
        assert [(a.stamp_ns, a.reference.stamp_ns) for a in got] == [(T0 + 9, T0 + 8)], order
        valid = got[0].valid_mask()
        assert valid.dtype == bool and valid.shape == img.shape[:2] and valid.all()
        assert got[0].box == (0, img.shape[0], 0, img.shape[1]) and not problems


def test_without_link_publisher_the_latest_reference_not_later_than_the_frame():
    img = load_crop("crop_rows")[:48, :64]
    asm, got, problems = _assembler(links=False)
    asm.add_frame(Frame(T0 + 3, img))
    asm.add_mask(Frame(T0 + 3, np.full(img.shape, 255, np.uint8)))
    assert got == [] and "without a reference" in problems[-1]
    for r in (0, 8, 16):
        asm.add_reference(Frame(T0 + r, img))
    asm.add_frame(Frame(T0 + 9, img))
    asm.add_mask(Frame(T0 + 9, np.full(img.shape, 255, np.uint8)))
    assert [(a.stamp_ns, a.reference.stamp_ns) for a in got] == [(T0 + 9, T0 + 8)]


def test_a_lost_link_is_reported_once_a_later_link_arrives_and_bad_masks_are_refused():
    img = load_crop("crop_rows")[:48, :64]
    asm, got, problems = _assembler()
    asm.add_reference(Frame(T0, img))
    for k in (1, 2):
        asm.add_frame(Frame(T0 + k, img))
        asm.add_mask(Frame(T0 + k, np.full(img.shape, 255, np.uint8)))
    assert len(asm.unlinked) == 2
    asm.add_link(T0 + 2, T0)  # frame 1's link never came
    assert [a.stamp_ns for a in got] == [T0 + 2] and not asm.unlinked
    assert any("never came" in p for p in problems)
    asm.add_mask(Frame(T0 + 5, np.zeros(img.shape + (3,), np.uint8)))
    assert "not mono8" in problems[-1]


def test_a_delivery_that_resets_the_assembler_does_not_break_the_rest():
    """A node resets the assembler from its delivery (time jumped back: a looped replay).

    Two frames waiting for their reference are both delivered, though the first delivery
    clears the assembler (it raised KeyError out of add_reference and killed the node).
    """
    img = load_crop("crop_rows")[:48, :64]
    got = []
    asm = None

    def deliver(a):
        got.append(a.stamp_ns)
        asm.clear()  # what ReconstructionNode.reset does on a time jump, on this thread

    asm = AlignedAssembler(deliver, lambda: True, print, print)
    for s in (T0 + 1, T0 + 2):
        asm.add_link(s, T0)
        asm.add_frame(Frame(s, img))
        asm.add_mask(Frame(s, np.full(img.shape, 255, np.uint8)))
    asm.add_reference(Frame(T0, img))
    assert got == [T0 + 1, T0 + 2]
