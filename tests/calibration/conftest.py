import numpy as np
import pytest


@pytest.fixture(scope="session")
def small_facility():
    from skynav.scenes.facility import screen_small_preset

    return screen_small_preset()


@pytest.fixture(scope="session")
def small_patterns(tmp_path_factory, small_facility):
    from skynav.calibration.bench_files import write_patterns

    d = tmp_path_factory.mktemp("patterns")
    write_patterns(small_facility, d)
    return d


@pytest.fixture(scope="session")
def small_captures(tmp_path_factory, small_facility, small_patterns):
    """Captures of the 'realistic' virtual bench (4 frames averaged, to keep the suite fast)."""
    from skynav.calibration.bench_files import simulate

    d = tmp_path_factory.mktemp("captures")
    simulate(small_facility, small_patterns, d, scenario_name="realistic", frames=4)
    return d


def true_error_arcsec(facility, calibrated, truth, n=40):
    import dataclasses

    from skynav.scenes.constants import ARCSEC_RAD

    cam = facility.camera
    g = np.stack(np.meshgrid(np.linspace(8, cam.width - 9, n), np.linspace(8, cam.height - 9, n)), -1).reshape(-1, 2)
    xy = calibrated.projection.project(cam.line_of_sight(g))
    true = dataclasses.replace(facility.projection, model=truth.geometric).line_of_sight(xy)
    return np.linalg.norm(np.cross(true, calibrated.projection.line_of_sight(xy)), axis=-1) / ARCSEC_RAD
