"""Image processors for the flight loop's tests (``bench nav --pipeline``, ``bench loop --pipeline``):
skynav's pipeline (tracking, as the flight's default) that faults on its third frame, in one way
each; and a factory that fails."""

import time
from dataclasses import replace

import numpy as np

from skynav.pipeline.plugins import skynav_tracking


class FaultOnThirdFrame:
    """skynav's pipeline, except that the third call raises, runs 30 s, returns a reflection or a string."""

    def __init__(self, camera, kind):
        self.inner, self.kind, self.calls = skynav_tracking(camera), kind, 0

    def process(self, observation, prediction):
        self.calls += 1
        result = self.inner.process(observation, prediction)
        if self.calls != 3:
            return result
        if self.kind == "raising":
            raise RuntimeError("the detector's driver crashed")
        if self.kind == "slow":
            time.sleep(30.0)     # past any --frame-timeout the tests give; the alarm cuts it short
        if self.kind == "reflection":
            return replace(result, R_cam_icrs=-np.eye(3))
        return "not a result"


def raising(camera):
    return FaultOnThirdFrame(camera, "raising")


def reflection(camera):
    return FaultOnThirdFrame(camera, "reflection")


def slow(camera):
    return FaultOnThirdFrame(camera, "slow")


def wrong_type(camera):
    return FaultOnThirdFrame(camera, "wrong_type")


def failing_factory(camera):
    raise RuntimeError("no licence for this tracker")
