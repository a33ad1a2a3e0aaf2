"""The closed loop (``skynav bench loop``): navigation that points the camera itself.

Three parties, as on a spacecraft with a camera on a bench:

- the **simulator** (:class:`Simulator`, truth side): the trajectory and legs of a ``sequence``
  recipe, the pointing controller's error model (the recipe's ``pointing_error_deg`` and
  ``jitter_rate_deg_s``); it turns a commanded attitude at a frame time into the scene mapping the
  camera sees (true state, commanded attitude times the controller's error);
- the **flight software** (:class:`FlightSoftware`, ``skynav.pipeline`` only): its EKF state, the
  image processing, the on-board catalogue and ephemeris; at each frame time it commands the
  attitude that points the boresight at the target planet *as its own estimate predicts it*,
  receives the image, measures the planet and updates the filter. It sees the image, the
  calibrated camera, the frame's time and its own command; never the truth;
- the **render service** (another process, ``skynav serve``), reached only through
  :class:`skynav.service.Client`: the flight software's process loads no renderer, Mitsuba or
  Dr.Jit (tests check ``sys.modules``).

A filter that drifts points the camera away from its planet and loses it; an offline dataset,
pointed from the truth, cannot show that. :func:`run_loop` runs the loop; ``pointing="truth"``
points from the truth instead (what a dataset does) for the comparison of the biased case.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from skynav.datasets.errors import RecipeError
from skynav.datasets.observation import Observation
from skynav.datasets.plan import epoch_iso
from skynav.datasets.recipes import recipe_camera
from skynav.datasets.samplers import make_plan
from skynav.pipeline import NavFilter, OnboardCatalog, PredictedState, process_frame
from skynav.pipeline.filter_dynamics import FilterDynamics
from skynav.pipeline.measurement import CASES
from skynav.pipeline.pairs import candidates_from_state, optimal_pair
from skynav.pipeline.scoring_nav import UPDATE_ITERATIONS, CampaignResult, CentroidNoise, NavPlan, centroid_usable
from skynav.scenes import frames
from skynav.scenes.constants import C_KM_S, SECONDS_PER_DAY
from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris
from skynav.scenes.timescales import tdb_seconds

#: A target is "centred" when its true pixel is within this fraction of the half-width of the
#: field from the principal point (the 1024 px paper camera: 51 px).
CENTRED_FRACTION = 0.1


class Simulator:
    """The truth side of the loop: a ``sequence`` recipe's cruise and the pointing controller."""

    def __init__(self, recipe: dict, *, limit: int | None = None):
        if recipe.get("kind") != "sequence":
            raise RecipeError("kind", recipe.get("kind"), "sequence (a cruise with navigation legs) for bench loop")
        self.recipe = recipe
        self.plan = make_plan(recipe)
        self.frames = self.plan.n_frames if limit is None else min(self.plan.n_frames, int(limit))
        render = dict(recipe.get("render", {}))
        render.pop("resolved_threshold_px", None)
        self._render = {"catalog_limiting_v_mag": float(recipe.get("catalog_limiting_v_mag", 9.0)), **render}
        self._camera = dict(recipe.get("camera", {"preset": "paper"}))
        self._visibility = dict(recipe.get("visibility", {}))
        self.master_seed = int(recipe.get("seed", 0))

    # what the flight software may know: the camera schedule and the commanded pointing plan
    def schedule(self):
        """``[(frame time TDB s, leg, phase, target)]`` of the frames (the commanded observation plan)."""
        out = []
        for k in range(self.frames):
            leg, phase, target, _ = self.plan.frame_info[k]
            t = float(tdb_seconds(epoch_iso(float(self.plan.frame_tdb_s[k]))))   # the epoch the scene file holds
            out.append((t, int(leg), phase, target))
        return out

    def state(self, t: float):
        r, v = self.plan.trajectory.state(t)
        return np.asarray(r, dtype=float).reshape(3), np.asarray(v, dtype=float).reshape(3)

    def scene(self, k: int, t: float, R_commanded: np.ndarray, rng: np.random.Generator) -> dict:
        """The scene mapping of frame ``k``: the true state, the commanded attitude with the controller's error."""
        s = self.recipe["sequence"]
        err = rng.normal(0.0, math.radians(s["pointing_error_deg"]), 3)
        jitter = rng.normal(0.0, math.radians(s["jitter_rate_deg_s"]), 3)
        R = frames.rotation_vector_to_dcm(-err) @ np.asarray(R_commanded)   # as the dataset's sequence frames
        w_deg = np.asarray(s["angular_velocity_deg_s"], dtype=float) + np.degrees(jitter)
        r, v = self.state(t)
        seed = int(np.random.SeedSequence([self.master_seed, k]).generate_state(1)[0])
        return {"epoch": epoch_iso(t),
                "observer": {"position_km": [float(x) for x in r], "velocity_km_s": [float(x) for x in v]},
                "attitude": {"q_cam_icrs": [float(x) for x in frames.dcm_to_quat(R)],
                             "angular_velocity_deg_s": [float(x) for x in w_deg]},
                "camera": self._camera, "visibility": self._visibility, "render": {**self._render, "seed": seed}}


class FlightSoftware:
    """Navigation from ``skynav.pipeline``: EKF, image processing, pointing commands. No truth."""

    def __init__(self, camera, x0, P0, t0: float, t_end: float, *, sigma_px: float, case: int = 1, dynamics=None,
                 twist_rad: float = 0.0):
        self.camera, self.sigma_px, self.twist_rad = camera, float(sigma_px), float(twist_rad)
        self.eph = default_ephemeris()
        dyn = (dynamics or FilterDynamics()).bind(self.eph, t0 - SECONDS_PER_DAY, t_end + SECONDS_PER_DAY)
        self.kf = NavFilter(dyn, np.atleast_2d(x0), P0, t0, corrections=CASES[case], iterations=UPDATE_ITERATIONS)
        self.catalog = OnboardCatalog.load(camera=camera)
        self.previous_attitude = None

    def command(self, t: float, target: str) -> np.ndarray:
        """Propagate to ``t``; the attitude that puts ``target`` on the boresight as the estimate predicts it."""
        self.kf.propagate(t)
        r = self.kf.x[0, :3]
        p = self.eph.position(target, t)
        lt = np.linalg.norm(p - r) / C_KM_S        # first-order light-time: the planet where it was
        p = self.eph.position(target, t - lt)
        return frames.point_boresight(frames.normalize(p - r), self.twist_rad)

    def observe(self, k: int, t: float, dn: np.ndarray, target: str) -> dict:
        """Process the image of frame ``k`` and update the filter; what happened, for the report."""
        obs = Observation(index=k, dn=dn, epoch_tdb_s=t, exposure_s=self.camera.exposure_s, camera=self.camera)
        x, P = self.kf.x[0], self.kf.P[0]
        radius = BODY_RADII_KM.get(target, 0.0)
        ps = PredictedState(position_km=x[:3], velocity_km_s=x[3:6], position_cov_km2=P[:3, :3] + radius**2 * np.eye(3))
        fr = process_frame(obs, catalog=self.catalog, predicted_state=ps, previous_attitude=self.previous_attitude)
        self.previous_attitude = fr.attitude.R_cam_icrs if fr.status == "ok" else None
        out = {"status": fr.status, "xy": None, "residual_px": (math.nan, math.nan), "accepted": False}
        beacon = None
        if fr.status == "ok" and fr.attitude.R_cam_icrs is not None:
            beacon = next((b for b in fr.beacons if b.name == target and b.status == "found" and b.xy_px is not None), None)
        if beacon is None:
            return out
        use = centroid_usable(obs, fr, beacon, target, t=t, position_km=x[:3], ephemeris=self.eph)
        out["xy"] = tuple(float(c) for c in beacon.xy_px)
        if use is None:
            out["status"] = "blended"
            return out
        rp, vp = self.eph.position_velocity(target, t)
        u = self.kf.update(np.asarray(beacon.xy_px, dtype=float).reshape(1, 2), rp, vp, fr.attitude.R_cam_icrs,
                           self.camera, self.sigma_px, sun_position_km=self.eph.position("sun", t),
                           planet_radius_km=radius, photocentre=use)
        out["residual_px"] = tuple(float(c) for c in u.residual_px[0])
        out["accepted"] = bool(u.accepted[0])
        return out


@dataclass
class LoopRun:
    """One run of the loop: per-frame histories (F frames)."""

    error: np.ndarray              # (F, 6) estimate - truth after the frame, km, km/s
    cov: np.ndarray                # (F, 6, 6)
    residual_px: np.ndarray        # (F, 2)
    accepted: np.ndarray           # (F,)
    status: list                   # (F,) image processing status
    in_field: np.ndarray           # (F,) the target's true pixel is inside the frame
    offset_px: np.ndarray          # (F,) true target pixel to the principal point, px (inf: not in field)
    measured_error_px: np.ndarray  # (F, 2) centroid - true pixel of the target
    latency_s: np.ndarray          # (F,) request to frame in hand, wall s
    step_s: np.ndarray             # (F,) command to filter updated, wall s
    late: np.ndarray               # (F,) realtime: the step ended after its deadline
    ip_time_s: float = 0.0
    filter_time_s: float = 0.0
    pairs: list = field(default_factory=list)


def run_loop(sim: Simulator, client, *, x0, P0, sigma_px: float, case: int = 1, pointing: str = "estimate",
             realtime: float | None = None, seed: int = 0, dynamics=None, progress=None) -> LoopRun:
    """One closed-loop run over the simulator's frames, the frames asked of ``client``.

    ``pointing``: ``"estimate"`` (closed loop: the flight software's command) or ``"truth"`` (the
    command of a perfect estimate, as a dataset is pointed). ``realtime``: simulated seconds per
    wall second; frame k is asked no earlier than its time on that clock, and is late when its
    step ends after the next frame's time (the last frame: one cadence after its own).
    """
    sched = sim.schedule()
    F = len(sched)
    camera = recipe_camera(sim.recipe)
    twist = math.radians(sim.recipe["sequence"]["twist_deg"]) if "twist_deg" in sim.recipe["sequence"] else 0.0
    fsw = FlightSoftware(camera, x0, P0, sched[0][0], sched[-1][0], sigma_px=sigma_px, case=case, dynamics=dynamics,
                         twist_rad=twist)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x100B]))
    run = LoopRun(error=np.full((F, 6), np.nan), cov=np.full((F, 6, 6), np.nan), residual_px=np.full((F, 2), np.nan),
                  accepted=np.zeros(F, bool), status=[], in_field=np.zeros(F, bool), offset_px=np.full(F, np.inf),
                  measured_error_px=np.full((F, 2), np.nan), latency_s=np.zeros(F), step_s=np.zeros(F),
                  late=np.zeros(F, bool))
    cx, cy = (camera.width - 1) / 2.0, (camera.height - 1) / 2.0
    cadence = float(sim.recipe["sequence"]["cadence_s"])
    wall0 = time.perf_counter()
    for k, (t, leg, phase, target) in enumerate(sched):
        if realtime:
            due = wall0 + (t - sched[0][0]) / realtime
            pause = due - time.perf_counter()
            if pause > 0:
                time.sleep(pause)
        c0 = time.perf_counter()
        R_cmd = fsw.command(t, target)
        if k == 0 or leg != sched[k - 1][1]:
            mean = fsw.kf.x[0]
            choice = optimal_pair(candidates_from_state(t, mean[:3], mean[3:6], ephemeris=fsw.eph))
            pairs = sim.plan.windows
            plan_pair = tuple(w.target for w in pairs if w.leg == leg and w.phase.startswith("track"))
            run.pairs.append((leg, plan_pair, None if choice is None else (choice.first, choice.second)))
        if pointing == "truth":
            r_true, _ = sim.state(t)
            p = fsw.eph.position(target, t)
            R_cmd = frames.point_boresight(frames.normalize(p - r_true), twist)
        mapping = sim.scene(k, t, R_cmd, rng)
        c1 = time.perf_counter()
        frame = client.render(mapping, outputs=("png", "truth"))
        c2 = time.perf_counter()
        dn = frame.dn
        # ---- flight software: the image only
        got = fsw.observe(k, t, dn, target)
        c3 = time.perf_counter()
        # ---- scoring: the truth of the frame the service rendered
        truth = frame.truth
        body = next((b for b in truth["bodies"] if b["name"] == target), None)
        r_true = np.asarray(truth["observer"]["position_km"])
        v_true = np.asarray(truth["observer"]["velocity_km_s"])
        if body is not None and body["in_fov"]:
            run.in_field[k] = True
            run.offset_px[k] = float(math.hypot(body["xy"][0] - cx, body["xy"][1] - cy))
            if got["xy"] is not None:
                run.measured_error_px[k] = np.subtract(got["xy"], body["xy"])
        run.error[k] = np.concatenate([fsw.kf.x[0, :3] - r_true, fsw.kf.x[0, 3:6] - v_true])
        run.cov[k] = fsw.kf.P[0, :6, :6]
        run.residual_px[k] = got["residual_px"]
        run.accepted[k] = got["accepted"]
        run.status.append(got["status"])
        run.latency_s[k] = c2 - c1
        run.step_s[k] = c3 - c0
        run.ip_time_s += c3 - c2
        run.filter_time_s += c1 - c0
        if realtime:
            t_next = sched[k + 1][0] if k + 1 < F else t + cadence
            run.late[k] = time.perf_counter() > wall0 + (t_next - sched[0][0]) / realtime
        if progress is not None:
            progress(1)
    return run


def centred_px(camera) -> float:
    return CENTRED_FRACTION * 0.5 * min(camera.width, camera.height)


def bias_for_lost_planet(sim: Simulator, factor: float = 1.5) -> float:
    """An initial position error (km) that puts the first target ``factor`` half-fields off the boresight."""
    t, _, _, target = sim.schedule()[0]
    r, _ = sim.state(t)
    cam = recipe_camera(sim.recipe)
    d = float(np.linalg.norm(default_ephemeris().position(target, t) - r))
    return factor * d * math.tan(0.5 * min(cam.fov_x_rad, cam.fov_y_rad))


def perpendicular_bias(sim: Simulator, bias_km: float) -> np.ndarray:
    """A position offset of ``bias_km`` perpendicular to the first line of sight (it moves the planet in the image)."""
    t, _, _, target = sim.schedule()[0]
    r, _ = sim.state(t)
    u = default_ephemeris().position(target, t) - r
    u /= np.linalg.norm(u)
    a = np.cross(u, [0.0, 0.0, 1.0])
    return bias_km * a / np.linalg.norm(a)


def nav_plan(sim: Simulator, runs: list):
    """The :class:`~skynav.pipeline.scoring_nav.NavPlan` of the loop's cruise, for ``bench nav``'s report."""
    sched = sim.schedule()
    r = np.array([sim.state(t)[0] for t, *_ in sched])
    v = np.array([sim.state(t)[1] for t, *_ in sched])
    pairs = tuple(tuple(w.target for w in sim.plan.windows if w.leg == lg and w.phase.startswith("track"))
                  for lg in sorted({s[1] for s in sched}))
    return NavPlan(root="(closed loop)", frames=len(sched), t_tdb_s=np.array([s[0] for s in sched]),
                   leg=np.array([s[1] for s in sched]), phase=tuple(s[2] for s in sched),
                   target=tuple(s[3] for s in sched), position_km=r, velocity_km_s=v,
                   target_xy_px=np.full((len(sched), 2), np.nan), plan_pairs=pairs)


def campaign_result(runs: list, plan, *, sigma_px: float, case: int = 1):
    """``bench nav``'s :class:`~skynav.pipeline.scoring_nav.CampaignResult` of the loop's runs."""
    return CampaignResult(case=case, noise=CentroidNoise(sigma0_px=float(sigma_px)), t_tdb_s=plan.t_tdb_s,
                          error=np.stack([r.error for r in runs]), cov=np.stack([r.cov for r in runs]),
                          residual_px=np.stack([r.residual_px for r in runs]),
                          accepted=np.stack([r.accepted for r in runs]), ip_status=tuple(runs[0].status),
                          measured_error_px=runs[0].measured_error_px, ip_time_s=sum(r.ip_time_s for r in runs),
                          filter_time_s=sum(r.filter_time_s for r in runs), pairs=tuple(runs[0].pairs))


def loop_summary(runs: list, camera, *, realtime: float | None) -> dict:
    """Closed-loop numbers: target in the field and centred, latency, deadline misses."""
    inf = np.concatenate([r.in_field for r in runs])
    off = np.concatenate([r.offset_px for r in runs])
    lat = np.concatenate([r.latency_s for r in runs])
    step = np.concatenate([r.step_s for r in runs])
    late = np.concatenate([r.late for r in runs])
    lost = [int(np.argmax(~r.in_field)) if not r.in_field.all() else None for r in runs]
    return {"frames": int(inf.size), "target_in_field_fraction": float(inf.mean()),
            "target_centred_fraction": float(np.mean(off <= centred_px(camera))), "centred_within_px": centred_px(camera),
            "offset_px_median": float(np.median(off[np.isfinite(off)])) if np.isfinite(off).any() else None,
            "first_frame_lost": lost,
            "latency_s": {"median": float(np.median(lat)), "p90": float(np.percentile(lat, 90)),
                          "p99": float(np.percentile(lat, 99)), "max": float(lat.max())},
            "step_s": {"median": float(np.median(step)), "p99": float(np.percentile(step, 99)), "max": float(step.max())},
            "realtime_scale": realtime, "deadline_misses": int(late.sum()) if realtime else None}
