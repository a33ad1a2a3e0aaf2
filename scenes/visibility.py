"""When a body counts as visible: the mission's detection rule, apart from the camera.

The camera (:mod:`skynav.scenes.camera`) holds optics and sensor only. Whether a body is
*visible* (the ``visible`` flag of the ground truth, the ``visible_planet`` keep-filter of the
Monte Carlo sampler) depends on a detection threshold and a Sun-exclusion rule that a mission
chooses; they live here, in :class:`VisibilityCriteria`, which a :class:`~skynav.scenes.scene.Scene`
carries.

Vocabulary (one name per meaning):

- ``limiting_v_mag``: the faintest V magnitude the image processing detects (detection limit);
  the star catalogue cut is ``catalog_limiting_v_mag``, a different thing;
- ``elongation_rad``: a body's angle from the Sun seen from the spacecraft (Sun-spacecraft-body);
- ``boresight_sun_angle_rad``: the angle between the camera boresight and the Sun.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError


@dataclass(frozen=True, kw_only=True)
class VisibilityCriteria:
    """The detection rule of a mission: a magnitude limit and a Sun-exclusion angle.

    Parameters
    ----------
    limiting_v_mag : float
        Faintest V magnitude detected; Andreis et al. (2024): V < 7.
    sun_exclusion_rad : float
        Smallest angle from the Sun at which a body (its elongation) or the boresight is usable,
        rad; Andreis et al. (2024): 20 deg.

    Examples
    --------
    >>> import math
    >>> from skynav.scenes import VisibilityCriteria
    >>> rule = VisibilityCriteria()
    >>> bool(rule.body_visible(v_mag=-1.7, elongation_rad=math.radians(157.0)))
    True
    >>> bool(rule.body_visible(v_mag=8.0, elongation_rad=math.radians(157.0)))
    False
    """

    limiting_v_mag: float = 7.0
    sun_exclusion_rad: float = math.radians(20.0)

    def __post_init__(self):
        if isinstance(self.limiting_v_mag, bool) or not math.isfinite(self.limiting_v_mag):
            raise ConfigValueError("visibility.limiting_v_mag", self.limiting_v_mag, "a finite number")
        if not 0.0 <= self.sun_exclusion_rad < math.pi:
            raise ConfigValueError("visibility.sun_exclusion_deg", math.degrees(self.sun_exclusion_rad), "in [0, 180)")

    def outside_sun_exclusion(self, sun_angle_rad):
        """True where an angle from the Sun (a body's elongation or the boresight's Sun angle)
        exceeds the exclusion angle.

        Parameters
        ----------
        sun_angle_rad : float or ndarray, shape (N,)
            Angle from the Sun, rad.

        Returns
        -------
        bool or ndarray of bool, shape (N,)
            True outside the exclusion cone.
        """
        return np.asarray(sun_angle_rad) > self.sun_exclusion_rad

    def body_visible(self, *, v_mag, elongation_rad):
        """The visibility predicate: V finite and ``<= limiting_v_mag``, elongation outside the
        Sun exclusion. Whether the body is in the field of view is the caller's other test.

        Parameters
        ----------
        v_mag : float or ndarray, shape (N,)
            Apparent V magnitude (NaN or inf: never visible).
        elongation_rad : float or ndarray, shape (N,)
            Angle Sun-spacecraft-body, rad.

        Returns
        -------
        bool or ndarray of bool, shape (N,)
            True where the body counts as visible.
        """
        v = np.asarray(v_mag, dtype=float)
        return np.isfinite(v) & (v <= self.limiting_v_mag) & self.outside_sun_exclusion(elongation_rad)

    def to_dict(self) -> dict:
        """Plain dict for JSON/YAML (the ``visibility`` section of a scene file).

        Returns
        -------
        dict
            ``limiting_v_mag`` (mag) and ``sun_exclusion_deg`` (deg).
        """
        return {"limiting_v_mag": self.limiting_v_mag, "sun_exclusion_deg": math.degrees(self.sun_exclusion_rad)}

    @classmethod
    def from_dict(cls, d: dict) -> "VisibilityCriteria":
        """Inverse of :meth:`to_dict`; missing keys take the defaults.

        Parameters
        ----------
        d : dict
            ``limiting_v_mag`` (mag) and/or ``sun_exclusion_deg`` (deg).

        Returns
        -------
        VisibilityCriteria
            The rule, the angle in radians.

        Raises
        ------
        ConfigValueError
            An unknown key or a value that is not a finite number in range.
        """
        if not isinstance(d, dict):
            raise ConfigValueError("visibility", d, "a mapping with limiting_v_mag and sun_exclusion_deg")
        allowed = {"limiting_v_mag", "sun_exclusion_deg"}
        for k in d:
            if k not in allowed:
                raise ConfigValueError(f"visibility.{k}", d[k], "no such key; allowed keys: " + ", ".join(sorted(allowed)))
        kw = {}
        for k, v in d.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigValueError(f"visibility.{k}", v, "a finite number")
        if "limiting_v_mag" in d:
            kw["limiting_v_mag"] = float(d["limiting_v_mag"])
        if "sun_exclusion_deg" in d:
            kw["sun_exclusion_rad"] = math.radians(float(d["sun_exclusion_deg"]))
        return cls(**kw)
