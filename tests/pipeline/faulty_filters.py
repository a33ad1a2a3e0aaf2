"""Navigation filters with faults, for the fault tests (``--filter tests/pipeline/faulty_filters.py:NAME``).

Each wraps skynav's EKF and breaks from its third update on: an exception in every update, a NaN
state in run 1, a covariance with a negative diagonal in run 0.
"""

import numpy as np

from skynav.pipeline.flight import SkynavEKF


class _Broken(SkynavEKF):
    kind = ""

    def __init__(self, setup):
        super().__init__(setup)
        self.updates = 0

    def update(self, m):
        self.updates += 1
        if self.kind == "raise" and self.updates >= 3:
            raise FloatingPointError("the innovation covariance is singular")
        return super().update(m)

    def state(self):
        x, P = super().state()
        if self.updates >= 3 and self.kind == "nan":
            x = x.copy()
            x[1, 0] = np.nan
        if self.updates >= 3 and self.kind == "not_pd":
            P = P.copy()
            P[0, 0, 0] = -1.0
        return x, P


class Raising(_Broken):
    kind = "raise"


class NaNState(_Broken):
    kind = "nan"


class NotPositiveDefinite(_Broken):
    kind = "not_pd"


def raising(setup):
    return Raising(setup)


def nan_state(setup):
    return NaNState(setup)


def not_positive_definite(setup):
    return NotPositiveDefinite(setup)


def not_a_filter(setup):
    return object()


def failing_factory(setup):
    raise RuntimeError("no licence for this filter")
