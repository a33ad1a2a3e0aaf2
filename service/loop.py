"""The closed loop (``skynav bench loop``): navigation that points the camera itself.

Three parties, as on a spacecraft with a camera on a bench:

- the **simulator** (:class:`Simulator`, truth side): the trajectory and legs of a ``sequence``
  recipe, the pointing controller's error model (the recipe's ``pointing_error_deg`` and
  ``jitter_rate_deg_s``); it turns a commanded attitude at a frame time into the scene mapping the
  camera sees (true state, commanded attitude times the controller's error);
- the **flight software** (:class:`FlightSoftware`, ``skynav.pipeline`` only): its navigation filter, the
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
from dataclasses import dataclass, field, replace

import numpy as np

from skynav.datasets.errors import RecipeError
from skynav.datasets.observation import Observation
from skynav.datasets.plan import epoch_iso
from skynav.datasets.recipes import recipe_camera
from skynav.datasets.samplers import make_plan
from skynav.datasets.sequence import pointing_controller
from skynav.pipeline.filter_dynamics import FilterDynamics
from skynav.pipeline.flight import DEFAULT_FILTER, DEFAULT_PIPELINE, FlightComputer, make_filter
from skynav.pipeline.planet_centroid import CentroidNoise
from skynav.pipeline.plugins import load_image_processor
from skynav.pipeline.protocols import FilterSetup
from skynav.pipeline.scoring_nav import CampaignResult, NavPlan, calibrate_sigma_px
from skynav.scenes import frames
from skynav.scenes.apparent import aberrate
from skynav.scenes.constants import C_KM_S
from skynav.scenes.ephemeris_jpl import default_ephemeris
from skynav.scenes.timescales import tdb_seconds

#: A target is "centred" when its true pixel is within this fraction of the half-width of the
#: field from the principal point (the 1024 px paper camera: 51 px).
CENTRED_FRACTION = 0.1

#: Frames the noise calibration measures by default (``bench loop`` takes every N-th frame, N =
#: frames // this, at least 1): each costs a frame from the service and its image processing, one
#: rendering of the whole 720-frame preset would double the loop's time; 180 frames leave every
#: class of measurement of the preset its 9 frames and every track 9 (``MIN_CLASS_FRAMES``).
CALIBRATION_FRAMES = 180

#: The rendering of the cruise the measurement noise is calibrated on (its frames' random streams
#: are ``SeedSequence([seed, k, CALIBRATION_RENDERING])``): no run of the loop sees these images.
CALIBRATION_RENDERING = 0xCA1


def point_at(ephemeris, target: str, t: float, position_km, velocity_km_s, twist_rad: float = 0.0) -> np.ndarray:
    """The attitude that puts ``target`` on the boresight seen from ``position_km`` at ``t``: the
    planet where it was one (first-order) light-time earlier, as the on-board ephemeris gives it,
    aberrated by the observer's velocity ``velocity_km_s`` (up to 27 arcsec), i.e. its apparent
    direction, where a dataset points (``skynav.datasets.sequence``).

    Without the aberration the planet sits ~0.3 px (paper camera) from the principal point, on the
    same side for a whole track, and the centroid's pixel-phase error no longer averages out over
    the controller's random pointing errors: on the ``sequence`` preset the track-constant part of
    the Mars and Venus centroid errors measured 0.017-0.019 and 0.012-0.017 px (two calibration
    renderings), 0.000-0.004 px pointed at the apparent direction, which R then carries as
    ``n sigma_b^2`` per frame (docs/service.md, "Accuracy against bench nav")."""
    r = np.asarray(position_km, dtype=float)
    lt = np.linalg.norm(ephemeris.position(target, t) - r) / C_KM_S
    u = frames.normalize(ephemeris.position(target, t - lt) - r)
    return frames.point_boresight(aberrate(u, np.asarray(velocity_km_s, dtype=float)), twist_rad)


def observation(k: int, t: float, dn: np.ndarray, camera):
    """What the flight software has of frame ``k``: the image, its time, the calibrated camera."""
    return Observation(index=k, dn=dn, epoch_tdb_s=t, exposure_s=camera.exposure_s, camera=camera)


def centroid_noise(noise):
    """``noise`` as a :class:`~skynav.pipeline.planet_centroid.CentroidNoise` (a number: that sigma, px)."""
    return noise if isinstance(noise, CentroidNoise) else CentroidNoise(sigma0_px=float(noise))


class Simulator:
    """The truth side of the loop: a ``sequence`` recipe's cruise and the pointing controller."""

    def __init__(self, recipe: dict, *, limit: int | None = None):
        if recipe.get("kind") != "sequence":
            raise RecipeError("kind", recipe.get("kind"), "sequence (a cruise with navigation legs) for bench loop")
        self.recipe = recipe
        self.plan = make_plan(recipe)
        self.frames = self.plan.n_frames if limit is None else min(self.plan.n_frames, int(limit))
        render = dict(recipe.get("render", {}))   # as the dataset renders: the recipe's render keys
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

    def scene(self, k: int, t: float, R_commanded: np.ndarray, rendering: int = 0) -> dict:
        """The scene mapping of frame ``k``: the true state, the commanded attitude with the controller's error.

        Frame ``k`` of rendering 0 draws from the dataset's stream of that frame,
        ``default_rng(SeedSequence([seed, k]))`` (the recipe's ``seed``; docs/conventions.md), in the
        dataset's order: the controller's pointing error (3 axes), then its rate jitter
        (:func:`skynav.datasets.sequence.pointing_controller`, the dataset's own), so that ``bench loop`` and ``dataset generate`` of
        one recipe see the same controller errors, frame by frame, and differ only where the
        command points. Those errors set the planet's pixel phase, and the centroid's pixel-phase
        error (0.07 px for Mars's disc on the preset) is most of the frame's centroid error: two
        draws of them are two different cruises (docs/service.md, "Accuracy against bench nav").
        The render seed is ``SeedSequence([seed, k]).generate_state(1)[0]``. Rendering ``j > 0``
        (later runs, the noise calibration) draws both from ``SeedSequence([seed, k, j])``."""
        s = self.recipe["sequence"]
        key = [self.master_seed, k] + ([int(rendering)] if rendering else [])
        rng = np.random.default_rng(np.random.SeedSequence(key))
        R, _, jitter = pointing_controller(rng, s, np.asarray(R_commanded))   # as the dataset's sequence frames
        w_deg = np.asarray(s["angular_velocity_deg_s"], dtype=float) + np.degrees(jitter)
        r, v = self.state(t)
        seed = int(np.random.SeedSequence(key).generate_state(1)[0])
        return {"epoch": epoch_iso(t),
                "observer": {"position_km": [float(x) for x in r], "velocity_km_s": [float(x) for x in v]},
                "attitude": {"q_cam_icrs": [float(x) for x in frames.dcm_to_quat(R)],
                             "angular_velocity_deg_s": [float(x) for x in w_deg]},
                "camera": self._camera, "visibility": self._visibility, "render": {**self._render, "seed": seed}}


class FlightSoftware:
    """Navigation from ``skynav.pipeline``: the flight loop's step (:class:`~skynav.pipeline.flight.FlightComputer`),
    with anyone's navigation filter, and pointing commands. No truth."""

    def __init__(self, camera, x0, P0, t0: float, t_end: float, *, noise, case: int = 1, dynamics=None,
                 twist_rad: float = 0.0, track_frames: dict | None = None, filter_spec: str = DEFAULT_FILTER,
                 pipeline: str = DEFAULT_PIPELINE, frame_timeout_s: float | None = None):
        self.camera, self.twist_rad = camera, float(twist_rad)
        self.eph = default_ephemeris()
        setup = FilterSetup(ephemeris=self.eph, t_start_tdb_s=float(t0), t_end_tdb_s=float(t_end), case=case,
                            dynamics=dynamics or FilterDynamics())
        self.fc = FlightComputer(make_filter(filter_spec, setup), noise=centroid_noise(noise), ephemeris=self.eph,
                                 track_frames=track_frames, processor=load_image_processor(pipeline, camera),
                                 frame_timeout_s=frame_timeout_s)
        self.fc.start(t0, np.atleast_2d(x0), P0)
        self._last_command = np.eye(3)

    def estimate(self):
        """The filter's state and covariance of the run, ``(x (n,), P (n, n))`` (NaN after a fault)."""
        x, P, _ = self.fc.estimate()
        return x[0], P[0]

    def command(self, t: float, target: str) -> np.ndarray:
        """Propagate to ``t``; the attitude that puts ``target`` on the boresight as the estimate predicts it
        (a filter without a usable estimate holds the last command; before any, the ICRS axes)."""
        self.fc.propagate(t)
        x, _ = self.estimate()
        if np.all(np.isfinite(x[:6])):
            self._last_command = point_at(self.eph, target, t, x[:3], x[3:6], self.twist_rad)
        return self._last_command

    def observe(self, k: int, t: float, dn: np.ndarray, target: str, track: tuple = ()) -> dict:
        """Process the image of frame ``k`` and update the filter; what happened, for the report.

        ``track``: the frame's ``(leg, phase)`` in the observation plan (the measurement noise of a
        class with a track-constant part depends on the track's length, as in ``bench nav``)."""
        step = self.fc.step(observation(k, t, dn, self.camera), target, track=track)
        return {"status": step.status, "xy": None if step.xy_px is None else tuple(float(c) for c in step.xy_px),
                "residual_px": tuple(float(c) for c in step.residual_px[0]), "accepted": bool(step.accepted[0]),
                "fault": step.fault, "measured": step.measurement is not None}


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
    faults: list = field(default_factory=list)   # (F,) the filter's fault in that step ("" none)
    measured: list = field(default_factory=list)  # (F,) the filter was given the frame's centroid


def track_frames(schedule) -> dict:
    """Frames per ``(leg, phase)`` of a schedule (:meth:`Simulator.schedule`): the tracks' lengths."""
    out = {}
    for _, leg, phase, _ in schedule:
        out[(leg, phase)] = out.get((leg, phase), 0) + 1
    return out


def run_loop(sim: Simulator, client, *, x0, P0, noise, case: int = 1, pointing: str = "estimate",
             realtime: float | None = None, rendering: int = 0, dynamics=None,
             progress=None, filter_spec: str = DEFAULT_FILTER, pipeline: str = DEFAULT_PIPELINE,
             frame_timeout_s: float | None = None) -> LoopRun:
    """One closed-loop run over the simulator's frames, the frames asked of ``client``.

    ``filter_spec``: the navigation filter, ``MODULE:FACTORY`` (:mod:`skynav.pipeline.flight`);
    ``pipeline``: the image processor, ``MODULE:FACTORY`` (:mod:`skynav.pipeline.plugins`), and
    ``frame_timeout_s`` its time limit per frame (None: none).
    ``noise``: the filter's measurement noise, a :class:`~skynav.pipeline.planet_centroid.CentroidNoise`
    (:func:`calibrate_loop_noise`, as ``bench nav`` calibrates it) or a sigma in px.
    ``rendering``: which rendering of the cruise the run sees, its controller errors and image
    noise (:meth:`Simulator.scene`; rendering 0: the controller errors of the recipe's dataset).

    ``pointing``: ``"estimate"`` (closed loop: the flight software's command) or ``"truth"`` (the
    command of a perfect estimate, as a dataset is pointed). ``realtime``: simulated seconds per
    wall second; frame k is asked no earlier than its time on that clock, and is late when its
    step ends after the next frame's time (the last frame: one cadence after its own).
    """
    sched = sim.schedule()
    F = len(sched)
    camera = recipe_camera(sim.recipe)
    twist = math.radians(sim.recipe["sequence"]["twist_deg"]) if "twist_deg" in sim.recipe["sequence"] else 0.0
    fsw = FlightSoftware(camera, x0, P0, sched[0][0], sched[-1][0], noise=noise, case=case, dynamics=dynamics,
                         twist_rad=twist, track_frames=track_frames(sched), filter_spec=filter_spec,
                         pipeline=pipeline, frame_timeout_s=frame_timeout_s)
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
            plan_pair = tuple(w.target for w in sim.plan.windows if w.leg == leg and w.phase.startswith("track"))
            run.pairs.append((leg, plan_pair, fsw.fc.choose_pair(t)))
        if pointing == "truth":
            R_cmd = point_at(fsw.eph, target, t, *sim.state(t), twist)
        mapping = sim.scene(k, t, R_cmd, rendering)
        c1 = time.perf_counter()
        frame = client.render(mapping, outputs=("png", "truth"))
        c2 = time.perf_counter()
        dn = frame.dn
        # ---- flight software: the image only
        got = fsw.observe(k, t, dn, target, (leg, phase))
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
        x, P = fsw.estimate()
        run.error[k] = np.concatenate([x[:3] - r_true, x[3:6] - v_true])
        run.cov[k] = P[:6, :6]
        run.faults.append(got["fault"])
        run.measured.append(got["measured"])
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


def campaign_result(runs: list, plan, *, noise, case: int = 1, filter_name: str = DEFAULT_FILTER):
    """``bench nav``'s :class:`~skynav.pipeline.scoring_nav.CampaignResult` of the loop's runs."""
    return CampaignResult(case=case, noise=centroid_noise(noise), t_tdb_s=plan.t_tdb_s,
                          error=np.stack([r.error for r in runs]), cov=np.stack([r.cov for r in runs]),
                          residual_px=np.stack([r.residual_px for r in runs]),
                          accepted=np.stack([r.accepted for r in runs]), ip_status=tuple(runs[0].status),
                          measured_error_px=runs[0].measured_error_px, ip_time_s=sum(r.ip_time_s for r in runs),
                          filter_time_s=sum(r.filter_time_s for r in runs), pairs=tuple(runs[0].pairs),
                          faults=tuple(tuple(r.faults) for r in runs), filter_name=filter_name,
                          measured=np.array([r.measured for r in runs], dtype=bool))


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


def calibrate_loop_noise(sim: Simulator, client, *, stride: int = 1, renderings: int = 1, seed: int = 0,
                         phase_offset: bool = True, progress=None, pipeline: str = DEFAULT_PIPELINE,
                         frame_timeout_s: float | None = None):
    """The filter's measurement noise, measured as ``bench nav`` measures it (of the image processor
    ``pipeline``, ``MODULE:FACTORY``).

    ``bench nav`` calibrates R on a dataset (:func:`skynav.pipeline.scoring_nav.calibrate_sigma_px`);
    here the same function runs on a rendering of the cruise asked of ``client``: every
    ``stride``-th frame at the true state, pointed from the truth (as a dataset is) with the
    controller's error, the frames' noise from :data:`CALIBRATION_RENDERING` (images no run of the
    loop sees). ``renderings > 1`` pools that many renderings (``CALIBRATION_RENDERING + j``), as
    ``bench nav --calibrate-on`` pools datasets: the track-constant part of the error is then the
    ensemble's, not one rendering's draw of it. Ground-side work that needs the truth, done before
    the loop starts.
    ``progress(1)`` after each frame.
    """
    sched = sim.schedule()
    camera = recipe_camera(sim.recipe)
    s = sim.recipe["sequence"]
    twist = math.radians(s.get("twist_deg", 0.0))
    eph = default_ephemeris()
    centre = ((camera.width - 1) / 2.0, (camera.height - 1) / 2.0)
    # pointed at the target from the truth: its pixel is the principal point, to the controller's error
    plan = replace(nav_plan(sim, []), target_xy_px=np.tile(centre, (len(sched), 1)))

    def render(j, k):
        t, _, _, target = sched[k]
        R = point_at(eph, target, t, *sim.state(t), twist)
        frame = client.render(sim.scene(k, t, R, CALIBRATION_RENDERING + j), outputs=("png",))
        if progress is not None:
            progress(1)
        return observation(k, t, frame.dn, camera)

    plans = [plan] * int(renderings) if renderings > 1 else plan
    return calibrate_sigma_px(plans, stride=stride, seed=seed, phase_offset=phase_offset, observations=render,
                              pipeline=pipeline, frame_timeout_s=frame_timeout_s)
