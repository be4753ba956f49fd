"""ShiftStdJoin: a shift and its standard errors from two topics, in either order."""

from subpix_ros.monitor.join import ShiftStdJoin


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def _join(**kw):
    out, clock = [], Clock()
    return ShiftStdJoin(lambda *a: out.append(a), clock=clock, **kw), out, clock


def test_errors_first_or_shift_first_each_emitted_once_with_errors():
    j, out, _ = _join()
    j.std(1, 0.01, 0.02)
    j.shift(1, 0.5, -0.25)
    j.shift(2, 0.1, 0.2)
    assert out == [(1, 0.5, -0.25, 0.01, 0.02)]
    j.std(2, 0.03, 0.04)
    assert out[-1] == (2, 0.1, 0.2, 0.03, 0.04) and len(out) == 2
    assert j.expire() == 0 and j.unmatched == 0


def test_a_shift_without_errors_goes_out_after_the_wait_and_is_counted():
    j, out, clock = _join(wait_s=0.5)
    j.shift(7, 1.0, 2.0)
    clock.t = 0.4
    assert j.expire() == 0 and out == []
    clock.t = 0.5
    assert j.expire() == 1 and out == [(7, 1.0, 2.0, None, None)] and j.unmatched == 1
    j.std(7, 0.1, 0.1)  # too late: not emitted a second time
    assert len(out) == 1


def test_overflow_emits_the_oldest_held_shift_instead_of_dropping_it():
    j, out, _ = _join(keep=2)
    for s in range(3):
        j.shift(s, float(s), 0.0)
    assert out == [(0, 0.0, 0.0, None, None)] and j.unmatched == 1
