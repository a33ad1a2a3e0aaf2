"""Navigation sequences: an Earth-Mars ballistic cruise and the navigation legs of Andreis et al. (2023b, 2024).

Driver-side core: builds a deterministic plan from a recipe (``kind: sequence``):

1. **Transfer.** A grid search over the departure window and the time of flight for the
   zero-revolution Lambert arc (:func:`skynav.datasets.lambert.solve_lambert`, Sun-centred,
   DE421 Earth and Mars centres) with the smallest ``v_inf(departure) + v_inf(arrival)``.
2. **Cruise.** The Lambert arc is followed on the two-body problem for ``start_offset_days``
   (leaving the Earth's sphere of influence), then the state is propagated with the
   high-fidelity model of :mod:`skynav.scenes.dynamics` (Sun + 9 bodies from DE421, SRP,
   1PN Sun; DOP853 at ``rtol``) over the whole timeline. The high-fidelity arc is a ballistic
   cruise initialised on the Lambert solution, not a targeted arrival at Mars.
3. **Legs** (Andreis et al. (2024), Sec. 4.2; Andreis et al. (2023b), Sec. IV, Fig. 5): track planet A for ``track_s``
   (1 h) at ``1 / cadence_s`` (0.01 Hz), slew for ``slew_s`` (30 min, no frames), track planet B
   for ``track_s``, propagate for ``propagate_s`` (10 days); ``legs`` times (10).
4. **Pair.** At the start of each leg, among the planets with ``V < pair_limiting_v_mag`` (7) and an
   elongation (angle from the Sun) larger than ``pair_elongation_min_deg`` (20 deg), the pair maximising the
   smallest eigenvalue of the line-of-sight information matrix
   ``J = sum_i (I - u_i u_i^T) / d_i^2`` (two directions u at distances d; a stand-in for the
   optimal-pair strategy of Franzese & Topputo that Andreis et al. (2023b, 2024) cite). A is the brighter.
   With one eligible planet, A = B.

Per frame (drawn from frame k's stream, see :mod:`skynav.datasets.samplers`): the boresight
points at the target's apparent direction with twist ``twist_deg``, turned by a pointing error
``N(0, pointing_error_deg^2)`` about each camera axis; the camera rate is
``angular_velocity_deg_s`` plus a jitter ``N(0, jitter_rate_deg_s^2)`` per axis (streaks).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from skynav.infra.count_cap import cap_count
from skynav.infra.errors import SkynavWarning
from skynav.scenes import frames
from skynav.scenes.constants import GM_KM3_S2, SECONDS_PER_DAY
from skynav.scenes.dynamics import ForceModel, SpacecraftSRP, propagate
from skynav.scenes.ephemeris_jpl import default_ephemeris
from skynav.scenes.errors import LambertError
from skynav.scenes.lambert import solve_lambert
from skynav.scenes.mission_ccsds import aem_kvn, aem_xml, ccsds_available, oem_kvn, oem_xml
from skynav.scenes.sky import sky_bodies
from skynav.scenes.timescales import tdb_seconds

from .errors import RecipeError, SceneSamplingError
from .plan import FrameRequest, epoch_iso, frame_rng
from .recipes import PLANETS, recipe_visibility
from .sequence_kernels import KernelCruise, describe_kernels, kernel_attitudes, rotation_vector

__all__ = ["Transfer", "LegWindow", "search_transfer", "leg_timeline", "choose_pair", "SequencePlan", "pointing_controller"]

DAY_S = SECONDS_PER_DAY


@dataclass(frozen=True, kw_only=True)
class Transfer:
    """The chosen Lambert transfer (heliocentric ICRS)."""

    departure_tdb_s: float
    tof_s: float
    v1_km_s: tuple          # heliocentric velocity at departure
    v_inf_departure_km_s: float
    v_inf_arrival_km_s: float


@dataclass(frozen=True, kw_only=True)
class LegWindow:
    """One window of the leg timeline."""

    leg: int
    phase: str              # track_A, slew, track_B, propagate
    target: str | None
    start_tdb_s: float
    end_tdb_s: float


def search_transfer(ephemeris, window_tdb_s, tof_range_s, step_s: float) -> Transfer:
    """Grid search of the Earth-Mars Lambert transfer with the smallest total v_inf.

    Parameters
    ----------
    ephemeris : object
        ``position_velocity(body, t_tdb_s)``.
    window_tdb_s : (float, float)
        Departure window, TDB s past J2000.
    tof_range_s : (float, float)
        Time-of-flight range, s.
    step_s : float
        Grid step for both, s.
    """
    deps = np.arange(window_tdb_s[0], window_tdb_s[1] + 0.5 * step_s, step_s)
    tofs = np.arange(tof_range_s[0], tof_range_s[1] + 0.5 * step_s, step_s)
    re, ve = ephemeris.position_velocity("earth", deps)
    rs, vs = ephemeris.position_velocity("sun", deps)
    arr = (deps[:, None] + tofs[None, :]).ravel()
    rm, vm = ephemeris.position_velocity("mars", arr)
    rs2, vs2 = ephemeris.position_velocity("sun", arr)
    best = None
    mu = GM_KM3_S2["sun"]
    for i, td in enumerate(deps):
        for j, tof in enumerate(tofs):
            n = i * len(tofs) + j
            try:
                sol = solve_lambert(re[i] - rs[i], rm[n] - rs2[n], float(tof), mu)
            except LambertError:
                continue
            vinf1 = float(np.linalg.norm(sol.v1_km_s - (ve[i] - vs[i])))
            vinf2 = float(np.linalg.norm(sol.v2_km_s - (vm[n] - vs2[n])))
            if best is None or vinf1 + vinf2 < best[0]:
                best = (vinf1 + vinf2, td, tof, sol.v1_km_s, vinf1, vinf2)
    if best is None:
        raise SceneSamplingError("no Lambert transfer found in the departure window")
    _, td, tof, v1, vinf1, vinf2 = best
    return Transfer(departure_tdb_s=float(td), tof_s=float(tof), v1_km_s=tuple(float(x) for x in v1),
                    v_inf_departure_km_s=vinf1, v_inf_arrival_km_s=vinf2)


def leg_timeline(t_start_tdb_s: float, *, legs: int, track_s: float, slew_s: float, propagate_s: float,
                 targets=None) -> list:
    """The windows of ``legs`` navigation legs from ``t_start_tdb_s`` (Andreis et al. (2023b, 2024) CONOPS).

    ``targets``: a list of ``(A, B)`` per leg (None for a timeline without targets).
    """
    out = []
    t = float(t_start_tdb_s)
    for i in range(legs):
        a, b = targets[i] if targets is not None else (None, None)
        for phase, dur, tgt in (("track_A", track_s, a), ("slew", slew_s, None), ("track_B", track_s, b),
                                ("propagate", propagate_s, None)):
            out.append(LegWindow(leg=i, phase=phase, target=tgt, start_tdb_s=t, end_tdb_s=t + dur))
            t += dur
    return out


def choose_pair(sky_list, *, limiting_v_mag: float, elongation_min_rad: float, planets=PLANETS):
    """(A, B) names of the best pair of ``sky_bodies`` entries (see the module docstring)."""
    elig = [b for b in sky_list if b.name in planets and np.isfinite(b.v_mag) and b.v_mag < limiting_v_mag
            and b.elongation_rad > elongation_min_rad]
    if not elig:
        return None
    if len(elig) == 1:
        return elig[0].name, elig[0].name
    best = None
    for i in range(len(elig)):
        for j in range(i + 1, len(elig)):
            J = np.zeros((3, 3))
            for b in (elig[i], elig[j]):
                u = np.asarray(b.directions.u_icrs)
                J += (np.eye(3) - np.outer(u, u)) / b.directions.distance_km**2
            score = float(np.linalg.eigvalsh(J)[0])
            if best is None or score > best[0]:
                best = (score, elig[i], elig[j])
    a, b = sorted(best[1:], key=lambda x: x.v_mag)
    return a.name, b.name


def pointing_controller(rng: np.random.Generator, sequence: dict, R_commanded: np.ndarray):
    """The pointing controller's error model of a ``sequence`` recipe, drawn from ``rng``.

    The pointing error ``err ~ N(0, pointing_error_deg^2)`` about each camera axis, then the rate
    jitter ``N(0, jitter_rate_deg_s^2)`` per axis, in this order (a frame's stream: the dataset and
    ``bench loop`` draw the same errors for the same frame); the camera turned by the small
    rotation vector ``err`` (camera axes) from the commanded attitude: ``R = exp(-[err x]) R_commanded``.

    Returns
    -------
    R : ndarray, shape (3, 3)
        The attitude the camera has (camera <- ICRS).
    err : ndarray, shape (3,), rad
    jitter : ndarray, shape (3,), rad/s
        Added to the recipe's ``angular_velocity_deg_s``.
    """
    err = rng.normal(0.0, math.radians(sequence["pointing_error_deg"]), 3)
    jitter = rng.normal(0.0, math.radians(sequence["jitter_rate_deg_s"]), 3)
    return frames.rotation_vector_to_dcm(-err) @ R_commanded, err, jitter


class SequencePlan:
    """Deterministic plan of a ``sequence`` recipe: transfer, trajectory, legs, frame epochs."""

    kind = "sequence"

    def __init__(self, recipe: dict, camera, *, ephemeris=None):
        self.recipe = recipe
        self.camera = camera

        self.visibility = recipe_visibility(recipe)
        s = self.s = recipe["sequence"]
        eph = self.ephemeris = ephemeris or default_ephemeris()
        leg_s = 2 * s["track_s"] + s["slew_s"] + s["propagate_s"]
        if "observer" in s:  # the mission's kernels (sequence_kernels.py)
            self.transfer = None
            self.trajectory = KernelCruise(s["observer"], s["legs"] * leg_s)
            t_start = self.trajectory.start_tdb_s
        else:
            t_start = self._ballistic_cruise(s, leg_s)
        t_end = t_start + s["legs"] * leg_s
        self.start_tdb_s, self.end_tdb_s = t_start, t_end

        # pairs at the start of each leg
        targets = []
        for i in range(s["legs"]):
            t = t_start + i * leg_s
            r, v = self.trajectory.state(t)
            pair = choose_pair(sky_bodies(t, r, v, ephemeris=eph)[0], limiting_v_mag=s["pair_limiting_v_mag"],
                               elongation_min_rad=math.radians(s["pair_elongation_min_deg"]))
            if pair is None:
                raise SceneSamplingError(f"leg {i}: no planet with V < {s['pair_limiting_v_mag']} outside "
                                         f"{s['pair_elongation_min_deg']} deg of the Sun")
            targets.append(pair)
        self.windows = leg_timeline(t_start, legs=s["legs"], track_s=s["track_s"], slew_s=s["slew_s"],
                                    propagate_s=s["propagate_s"], targets=targets)
        # frames: every cadence_s inside the tracking windows, [start, end)
        n_track = int(math.floor(s["track_s"] / s["cadence_s"] + 1e-9))
        rows = []
        for w in self.windows:
            if w.phase.startswith("track"):
                for j in range(n_track):
                    rows.append((w.start_tdb_s + j * s["cadence_s"], w.leg, w.phase, w.target, j))
        total = len(rows)
        n = recipe.get("frames") or total
        if n > total:
            raise RecipeError("frames", n, f"at most {total} (frames planned by the legs)")
        n = cap_count(n, "sequence frames")
        rows = rows[:n]
        self.n_frames = n
        self.n_planned = total
        self.frame_tdb_s = np.array([r[0] for r in rows])
        self.frame_info = [r[1:] for r in rows]
        self.frame_r, self.frame_v = self.trajectory.state(self.frame_tdb_s)
        self.frame_r = np.atleast_2d(self.frame_r)
        self.frame_v = np.atleast_2d(self.frame_v)
        self.frame_R = self.frame_w = None
        if "attitude" in s:  # read here, once: the workers get numbers
            self.frame_R, self.frame_w = kernel_attitudes(s["attitude"], self.frame_tdb_s)
        self.data_files = [{"key": f"sequence.{key}.spice.kernels", **r}
                           for key, d in describe_kernels(s).items() for r in d["spice"]["kernels"]]

    def _ballistic_cruise(self, s: dict, leg_s: float) -> float:
        """The built-in cruise (steps 1 and 2 of the module docstring): sets ``transfer`` and
        ``trajectory``; returns the legs' start, TDB s."""
        eph = self.ephemeris
        window = (float(tdb_seconds(s["departure_window_tdb"][0])), float(tdb_seconds(s["departure_window_tdb"][1])))
        self.transfer = search_transfer(eph, window, (s["tof_days"][0] * DAY_S, s["tof_days"][1] * DAY_S),
                                        s["grid_days"] * DAY_S)
        td = self.transfer.departure_tdb_s
        t_start = td + s["start_offset_days"] * DAY_S
        r0, v0 = self._two_body_start(td, t_start)
        model = ForceModel(srp=SpacecraftSRP(**s["spacecraft"]), relativity=s["relativity"])
        self.trajectory = propagate(eph, r0, v0, t_start, t_start + s["legs"] * leg_s, model=model, rtol=s["rtol"])
        return t_start

    def _two_body_start(self, td: float, t_start: float):
        """Barycentric state at ``t_start`` on the Sun-only Lambert arc from the Earth at ``td``."""
        eph = self.ephemeris
        re = eph.position("earth", td)
        rs = eph.position("sun", td)
        mu = GM_KM3_S2["sun"]

        def f(_t, y):
            r = y[:3]
            return np.concatenate([y[3:], -mu * r / np.linalg.norm(r) ** 3])

        y0 = np.concatenate([re - rs, np.asarray(self.transfer.v1_km_s)])
        sol = solve_ivp(f, (td, t_start), y0, method="DOP853", rtol=1e-13, atol=1e-9)
        rs1, vs1 = eph.position_velocity("sun", t_start)
        return sol.y[:3, -1] + rs1, sol.y[3:, -1] + vs1

    def __getstate__(self):
        d = dict(self.__dict__)
        d.pop("trajectory", None)  # workers use the per-frame states; keeps pickles small
        return d

    def frame_request(self, k: int, rng: np.random.Generator) -> FrameRequest:
        s = self.s
        t = float(self.frame_tdb_s[k])
        leg, phase, target, j = self.frame_info[k]
        r, v = self.frame_r[k], self.frame_v[k]
        sky = sky_bodies(t, r, v, ephemeris=self.ephemeris)
        body = next(b for b in sky[0] if b.name == target)
        R_nominal = frames.point_boresight(body.directions.u_icrs, math.radians(s["twist_deg"]))
        R, err, jitter = pointing_controller(rng, s, R_nominal)  # drawn in any case: frame k's stream
        w = np.radians(np.asarray(s["angular_velocity_deg_s"], dtype=float)) + jitter
        if self.frame_R is not None:  # the CK's attitude; its error from the nominal pointing
            R, w = self.frame_R[k].copy(), self.frame_w[k].copy()
            err = -rotation_vector(R @ R_nominal.T)  # R = exp(-[err x]) R_nominal (pointing_controller)
        meta = {"kind": "sequence", "frame": int(k), "leg": int(leg), "phase": phase, "target": target,
                "window_frame": int(j), "pointing_error_rad": [float(x) for x in err]}
        if self.data_files:
            meta["data_files"] = self.data_files
        return FrameRequest(epoch_tdb_s=t, position_km=np.array(r), velocity_km_s=np.array(v), R_cam_icrs=R,
                            angular_velocity_rad_s=w, meta=meta, sky=sky)

    # ------------------------------------------------------------------ dataset side files
    def describe(self) -> dict:
        """Plan summary for the manifest (the transfer, or the kernels read: names and SHA-256)."""
        tr = self.transfer
        head = describe_kernels(self.s)
        if tr is not None:
            head["transfer"] = {
                "departure_tdb": epoch_iso(tr.departure_tdb_s),
                "tof_days": tr.tof_s / DAY_S,
                "arrival_tdb": epoch_iso(tr.departure_tdb_s + tr.tof_s),
                "v_inf_departure_km_s": tr.v_inf_departure_km_s,
                "v_inf_arrival_km_s": tr.v_inf_arrival_km_s,
            }
        return {
            **head,
            "cruise_start_tdb": epoch_iso(self.start_tdb_s),
            "cruise_end_tdb": epoch_iso(self.end_tdb_s),
            "frames_planned": self.n_planned,
            "pairs": [[w.target for w in self.windows if w.leg == i and w.phase.startswith("track")]
                      for i in range(self.s["legs"])],
        }

    def trajectory_csv(self) -> str:
        """``trajectory.csv``: the cruise every ``trajectory_step_s``, barycentric ICRS, km and km/s."""
        step = self.s["trajectory_step_s"]
        t = np.arange(self.start_tdb_s, self.end_tdb_s + 0.5 * step, step)
        t = t[t <= self.end_tdb_s]
        r, v = self.trajectory.state(t)
        lines = ["epoch_tdb,t_tdb_s,x_km,y_km,z_km,vx_km_s,vy_km_s,vz_km_s"]
        for ti, ri, vi in zip(t.tolist(), np.atleast_2d(r).tolist(), np.atleast_2d(v).tolist()):
            lines.append(f"{epoch_iso(ti)},{ti!r},{ri[0]!r},{ri[1]!r},{ri[2]!r},{vi[0]!r},{vi[1]!r},{vi[2]!r}")
        return "\n".join(lines) + "\n"

    def legs_csv(self) -> str:
        """``legs.csv``: the leg timeline (one row per window)."""
        lines = ["leg,phase,target,start_tdb,end_tdb,start_tdb_s,end_tdb_s,duration_s"]
        for w in self.windows:
            t0, t1 = float(w.start_tdb_s), float(w.end_tdb_s)
            lines.append(f"{w.leg},{w.phase},{w.target or ''},{epoch_iso(t0)},{epoch_iso(t1)},{t0!r},{t1!r},{t1 - t0!r}")
        return "\n".join(lines) + "\n"

    def trajectory_oem(self, fmt: str = "kvn") -> str:
        """``trajectory.oem``: the states of ``trajectory.csv`` as a CCSDS OEM (``fmt`` kvn, or
        xml: ``trajectory_oem.xml``; ICRF, solar-system barycentre, TDB;
        :mod:`skynav.scenes.mission_ccsds`)."""
        step = self.s["trajectory_step_s"]
        t = np.arange(self.start_tdb_s, self.end_tdb_s + 0.5 * step, step)
        t = t[t <= self.end_tdb_s]
        r, v = self.trajectory.state(t)
        return (oem_xml if fmt == "xml" else oem_kvn)(t, np.atleast_2d(r), np.atleast_2d(v))

    def attitude_aem(self, fmt: str = "kvn") -> str:
        """``attitude.aem``: every frame's attitude (with its pointing error and jitter, as its
        truth) and angular velocity as a CCSDS AEM (``fmt`` kvn, or xml: ``attitude_aem.xml``;
        ICRF to the camera, TDB). The sampler's draws come first in frame k's stream
        (docs/conventions.md), so drawing them here gives the frames' own values."""
        if "_attitudes" not in self.__dict__:  # both formats write the same, drawn once
            seed = int(self.recipe["seed"])
            q, w = [], []
            for k in range(self.n_frames):
                req = self.frame_request(k, frame_rng(seed, k))
                q.append(frames.dcm_to_quat(req.R_cam_icrs))
                w.append(req.angular_velocity_rad_s)
            self._attitudes = (np.array(q), np.array(w))
        return (aem_xml if fmt == "xml" else aem_kvn)(self.frame_tdb_s, *self._attitudes)

    def side_files(self) -> dict:
        """Extra dataset files ``{name: bytes}``: trajectory and leg timeline (CSV), and the
        trajectory and attitudes as CCSDS OEM/AEM, KVN and XML, where the ``ccsds`` extra is
        installed."""
        files = {"trajectory.csv": self.trajectory_csv().encode("ascii"), "legs.csv": self.legs_csv().encode("ascii")}
        if ccsds_available():
            files["trajectory.oem"] = self.trajectory_oem().encode("ascii")
            files["attitude.aem"] = self.attitude_aem().encode("ascii")
            files["trajectory_oem.xml"] = self.trajectory_oem("xml").encode("utf-8")
            files["attitude_aem.xml"] = self.attitude_aem("xml").encode("utf-8")
        else:
            warnings.warn("sequence datasets write trajectory.oem and attitude.aem with the ccsds extra: "
                          "pip install 'skynav[ccsds]'", SkynavWarning, stacklevel=2)
        return files
