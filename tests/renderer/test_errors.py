"""The renderer's errors: one home (``renderer/errors.py``), each a SkynavError and a builtin."""

import pytest

from skynav.infra.errors import SkynavError
from skynav.renderer import errors, jit_backend


@pytest.mark.parametrize("cls, builtin", [
    (errors.BackendUnavailableError, RuntimeError),
    (errors.SensorInputError, ValueError),
    (errors.ProjectionCropError, ValueError),
])
def test_each_error_is_a_skynav_error_and_a_builtin(cls, builtin):
    assert issubclass(cls, SkynavError) and issubclass(cls, builtin)


def test_backend_error_raised_by_the_probe_is_the_one_in_errors():
    assert jit_backend.BackendUnavailableError is errors.BackendUnavailableError


def test_projection_crop_error_is_one_line_with_its_data():
    e = errors.ProjectionCropError("earth", (1, 2, 16, 8), "spans 90 deg or more from its central line of sight")
    assert "\n" not in str(e) and "'earth'" in str(e) and "(1, 2, 16, 8)" in str(e)
    assert e.body == "earth" and e.window == (1, 2, 16, 8)
