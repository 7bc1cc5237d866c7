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
