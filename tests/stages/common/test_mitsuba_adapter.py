"""The Mitsuba adapter's render gives a Ctrl-C back as the interruption it was."""

import numpy as np
import pytest

from stages.common.mitsuba_adapter import _interruptible


def _wrapped(error: BaseException):
    """What Dr.Jit's custom operation raises when ``error`` is raised inside it."""
    def render():
        try:
            raise error
        except BaseException as inner:
            raise RuntimeError("drjit.custom(<mitsuba.python.util._RenderOp>): error while performing a custom "
                               "differentiable operation. (see above).") from inner
    return render


def test_a_ctrl_c_inside_the_render_is_an_interruption_and_other_errors_stay_errors():
    with pytest.raises(KeyboardInterrupt):
        _interruptible(_wrapped(KeyboardInterrupt()))
    with pytest.raises(RuntimeError, match="custom differentiable operation"):
        _interruptible(_wrapped(ValueError("a real failure")))
    np.testing.assert_array_equal(_interruptible(lambda: [[1.0, 2.0]]), np.array([[1.0, 2.0]]))


def test_dr_jits_own_wrapping_of_a_ctrl_c_is_undone():
    """The wrapping as Dr.Jit does it (a custom operation whose evaluation is interrupted),
    not as the test above imitates it: if Dr.Jit chains the error otherwise, this fails."""
    from stages.common.mitsuba_adapter import load_mitsuba

    load_mitsuba()
    import drjit as dr
    import mitsuba as mi

    class Interrupted(dr.CustomOp):
        def eval(self, value):  # noqa: ANN001, ANN202 - Dr.Jit's signature
            raise KeyboardInterrupt

    with pytest.raises(RuntimeError) as wrapped:  # what reached the user as "a bug of speedplus"
        dr.custom(Interrupted, mi.Float(1.0))
    assert "custom" in str(wrapped.value)
    with pytest.raises(KeyboardInterrupt):
        _interruptible(lambda: dr.custom(Interrupted, mi.Float(1.0)))
