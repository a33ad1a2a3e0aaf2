"""Scene samplers: what frame k of a dataset looks at, drawn from frame k's random stream.

Core module (imports the scene model only). Each recipe kind has a *plan* (deterministic,
computed once from the recipe: for a sequence, the trajectory and the leg timeline) and a
per-frame draw ``plan.frame_request(k, rng)`` that returns a :class:`FrameRequest` (epoch,
state, attitude, rate, metadata). The stream of frame k is
``np.random.default_rng(np.random.SeedSequence([master_seed, k]))`` (:func:`frame_seed`), used in
this documented order:

1. the sampler's draws (below, per kind), then
2. everything the renderer draws (``render(scene, rng=...)``: cosmic rays, then sensor noise).

Monte Carlo draws per attempt, in this order (Andreis et al. (2023a), Sec. V.A):
``epoch ~ U[start, end)`` (TDB s); ``position_ecl ~ N(0, diag(sigma)^2)`` AU (3 normals, x y z);
``ra ~ U[0, 2 pi)``; ``dec ~ N(0, (dec_3sigma/3)^2)``; ``twist ~ U[0, 2 pi)``; attempts repeat
until the keep-filters pass (the number of attempts is recorded as ``draws``).

Sequence draws per frame: pointing error ``N(0, sigma^2)`` about the camera x, y, z axes (3
normals), then the jitter rate ``N(0, sigma^2)`` about x, y, z (3 normals).

Free-form scenes draw nothing before the renderer.
"""

from __future__ import annotations

import math

import numpy as np

from skynav.scenes import frames
from skynav.scenes.config import scene_spec_from_mapping
from skynav.scenes.constants import AU_KM, GM_KM3_S2, OBLIQUITY_J2000_RAD
from skynav.scenes.ephemeris_jpl import default_ephemeris
from skynav.scenes.errors import ObserverInsideBodyError
from skynav.scenes.scene import resolve_spec
from skynav.scenes.sky import SCENE_BODIES, sky_bodies, sky_bodies_and_sun
from skynav.scenes.timescales import tdb_seconds

from .errors import SceneSamplingError
from .plan import FrameRequest, epoch_iso, frame_rng, frame_seed  # noqa: F401  (re-exported)
from .recipes import recipe_camera, recipe_visibility
from .sequence import SequencePlan

__all__ = [
    "OBLIQUITY_J2000_RAD",
    "R_ECL_ICRS",
    "FrameRequest",
    "frame_seed",
    "frame_rng",
    "MonteCarloPlan",
    "ScenesPlan",
    "keep_filters_pass",
    "make_plan",
    "epoch_iso",
]

# Ecliptic J2000 axes are ICRS turned about x by the obliquity (scenes.constants); the 23 mas ICRS
# frame bias is ignored (the sampler is statistical).
R_ECL_ICRS = frames.rot1(OBLIQUITY_J2000_RAD)  # passive: v_ecl = R_ECL_ICRS @ v_icrs


def keep_filters_pass(filters, sky, R_cam_icrs, camera, visibility) -> tuple[bool, dict]:
    """Evaluate keep-filters on the bodies of ``sky_bodies(...)`` for a pointing.

    ``visible_planet``: at least one body in the field of view that ``visibility.body_visible``
    accepts (the ``visible`` flag of :func:`skynav.scenes.scene.build_scene`, the same
    predicate); ``body_in_fov``: at least one body in the field whatever its brightness;
    ``sun_outside_exclusion``: the boresight's Sun angle exceeds the exclusion angle.

    Parameters
    ----------
    visibility : skynav.scenes.visibility.VisibilityCriteria

    Returns
    -------
    ok : bool
    facts : dict
        ``bodies_in_fov``, ``visible_bodies`` (lists of names), ``boresight_sun_angle_deg``.
    """
    bodies, sun_u = sky
    in_fov, visible = [], []
    R = np.asarray(R_cam_icrs)
    for b in bodies:
        p = camera.project((R @ b.directions.u_icrs)[None])[0]
        if bool(camera.in_image(p[None])[0]):
            in_fov.append(b.name)
            if visibility.body_visible(v_mag=b.v_mag, elongation_rad=b.elongation_rad):
                visible.append(b.name)
    boresight_sun_angle = float(np.arccos(np.clip(R[2] @ sun_u, -1.0, 1.0)))
    ok = True
    for f in filters:
        if f == "visible_planet":
            ok &= bool(visible)
        elif f == "body_in_fov":
            ok &= bool(in_fov)
        elif f == "sun_outside_exclusion":
            ok &= bool(visibility.outside_sun_exclusion(boresight_sun_angle))
    return bool(ok), {"bodies_in_fov": in_fov, "visible_bodies": visible,
                      "boresight_sun_angle_deg": math.degrees(boresight_sun_angle)}


class MonteCarloPlan:
    """Andreis et al. (2023a), Sec. V.A scene distribution (see the module docstring for the draw order).

    Position: Gaussian about the solar-system barycentre with ``sigma = (3, 3, 0.07) AU`` in
    ecliptic J2000 axes (the paper's N frame: "the spacecraft is supposed to lie close to the
    ecliptic plane"), rotated to ICRS. Attitude: ``ra ~ U[0, 2 pi)``, ``dec`` normal with
    3-sigma ``dec_3sigma`` (0.6 rad), ``twist ~ U[0, 2 pi)``, by default in the same ecliptic
    axes (``attitude_frame: ecliptic``: "planets are distributed close to the ecliptic plane"),
    or in ICRS. Velocity (the paper does not give one; it only matters for aberration):
    ``circular``: the circular heliocentric speed ``sqrt(GM_sun / r)`` at that distance, in the
    ecliptic plane, prograde (direction ``z_ecl x r``), plus the Sun's barycentric velocity;
    ``zero``: at rest with respect to the Sun. Positions closer than ``min_sun_distance_au`` to
    the Sun or inside a body are redrawn (counted in ``draws``).
    """

    kind = "montecarlo"

    def __init__(self, recipe: dict, camera, *, ephemeris=None):
        self.recipe = recipe
        self.camera = camera

        self.visibility = recipe_visibility(recipe)
        self.s = recipe["montecarlo"]
        self.n_frames = int(recipe["frames"])
        self.start_tdb_s = float(tdb_seconds(self.s["epoch_start_tdb"]))
        self.end_tdb_s = float(tdb_seconds(self.s["epoch_end_tdb"]))
        self._eph = ephemeris

    @property
    def ephemeris(self):
        if self._eph is None:
            self._eph = default_ephemeris()
        return self._eph

    def draw_pose(self, rng: np.random.Generator):
        """One attempt: (t_tdb_s, position_km (3,), R_cam_icrs (3, 3)) in the documented order."""
        s = self.s
        t0, t1 = self.start_tdb_s, self.end_tdb_s
        t = t0 + (t1 - t0) * rng.random() if t1 > t0 else t0
        p_ecl = rng.normal(0.0, 1.0, 3) * np.asarray(s["position_sigma_au"]) * AU_KM
        ra = rng.uniform(0.0, 2.0 * math.pi)
        dec = rng.normal(0.0, math.radians(s["dec_3sigma_deg"]) / 3.0)
        twist = rng.uniform(0.0, 2.0 * math.pi)
        # a normal dec may leave [-pi/2, pi/2] for huge sigmas: fold it back onto the sphere
        u = frames.radec_to_unit(ra, dec)
        ra_f, dec_f = frames.unit_to_radec(u)
        R_frame = frames.radec_twist_to_dcm(float(ra_f), float(dec_f), twist)
        if s["attitude_frame"] == "ecliptic":
            R = R_frame @ R_ECL_ICRS
        else:
            R = R_frame
        return t, R_ECL_ICRS.T @ p_ecl, R

    def velocity(self, t, r_km):
        """Barycentric velocity of the ``velocity`` model at a barycentric position."""
        sun_r, sun_v = self.ephemeris.position_velocity("sun", t)
        if self.s["velocity"] == "zero":
            return np.asarray(sun_v, dtype=float)
        rel = R_ECL_ICRS @ (r_km - sun_r)
        direction = frames.cross([0.0, 0.0, 1.0], rel)
        n = np.linalg.norm(direction)
        if n == 0.0:
            return np.asarray(sun_v, dtype=float)
        speed = math.sqrt(GM_KM3_S2["sun"] / np.linalg.norm(rel))
        return R_ECL_ICRS.T @ (speed * direction / n) + sun_v

    def _fov_candidates(self, t, r, R):
        """Bodies that may be in the field: those whose geometric direction is within the
        half-diagonal field of view + 1 deg of the boresight (aberration and light-time move a
        planet by < 0.01 deg, so no body the exact test finds in the image is left out).
        None when no keep-filter looks at bodies (every body is then computed)."""
        if not {"visible_planet", "body_in_fov"} & set(self.s["keep"]):
            return None

        limit = math.cos(min(math.pi, self.camera.half_diagonal_fov_rad + math.radians(1.0)))
        out = []
        for name in SCENE_BODIES:
            d = self.ephemeris.position(name, t) - r
            if R[2] @ d > limit * np.linalg.norm(d):
                out.append(name)
        return tuple(out)

    def _sky(self, t, r, v, R, candidates):
        """``(ok, facts, sky)`` of one drawn pose; ``ok`` False when it is rejected.

        The keep-filters only look at bodies in the image, so they are first evaluated on the
        candidates of :meth:`_fov_candidates` alone; the other bodies (needed for the ground
        truth) are computed only for a pose that passes. Each body's :class:`SkyBody` depends on
        (t, r, v, name) only, so the merged result equals ``sky_bodies`` on all bodies, and the
        decision equals evaluating the filters on all of them. A pose inside any body is rejected.
        ``candidates`` is None or non-empty (:meth:`frame_request` skips a pose with none).
        """
        s = self.s
        try:
            if candidates is None:
                sky = sky_bodies(t, r, v, ephemeris=self.ephemeris)
                ok, facts = keep_filters_pass(s["keep"], sky, R, self.camera, self.visibility)
                return ok, facts, sky
            # the Sun with the candidates, once for both parts
            part, sun = sky_bodies_and_sun(t, r, v, ephemeris=self.ephemeris, names=candidates)
            sun_u = np.asarray(sun.u_icrs, dtype=float)
            ok, facts = keep_filters_pass(s["keep"], (part, sun_u), R, self.camera, self.visibility)
            if not ok:
                return False, None, None
            rest, _ = sky_bodies_and_sun(t, r, v, ephemeris=self.ephemeris, sun=sun,
                                         names=tuple(n for n in SCENE_BODIES if n not in candidates))
        except ObserverInsideBodyError:
            return False, None, None
        by_name = {b.name: b for b in part + rest}
        return True, facts, (tuple(by_name[n] for n in SCENE_BODIES), sun_u)

    #: Poses drawn and pre-tested together (about 14 draws per kept frame with the default
    #: filters); the stream is rewound to just after the kept one, so the batch size changes
    #: nothing but speed.
    BATCH = 16

    def _near_sun(self, t, r) -> np.ndarray:
        """Which of the poses ``(t (n,), r (n, 3))`` are closer to the Sun than
        ``min_sun_distance_au``; the same decision as ``norm(r - sun(t)) < limit`` per pose: one
        vectorised ephemeris call, and the scalar formula again for a pose within 1e-9 of the
        limit (where a summation order could move the last bit)."""
        limit = self.s["min_sun_distance_au"] * AU_KM
        dist = np.sqrt(np.sum((r - self._positions(t, ("sun",))[:, 0]) ** 2, axis=1))
        near = dist < limit
        for i in np.flatnonzero(np.abs(dist - limit) <= 1e-9 * limit):
            near[i] = np.linalg.norm(r[i] - self.ephemeris.position("sun", t[i])) < limit
        return near

    def _fov_candidates_batch(self, t, r, boresights) -> list:
        """:meth:`_fov_candidates` of n poses (``boresights`` (n, 3): the rows ``R[2]``) in one
        ephemeris call per body. A body within 1e-9 (relative) of the cone's edge is kept: a
        candidate too many only costs its apparent direction, since the candidates decide which
        bodies are computed first, not the result (see :meth:`_sky`)."""
        if not {"visible_planet", "body_in_fov"} & set(self.s["keep"]):
            return [None] * len(t)

        limit = math.cos(min(math.pi, self.camera.half_diagonal_fov_rad + math.radians(1.0)))
        d = self._positions(t, SCENE_BODIES) - r[:, None, :]  # (n, bodies, 3)
        n = np.sqrt(np.sum(d * d, axis=2))
        inside = np.sum(boresights[:, None, :] * d, axis=2) > (limit - 1e-9) * n  # (n, bodies)
        return [tuple(name for name, yes in zip(SCENE_BODIES, row) if yes) for row in inside.tolist()]

    def _positions(self, t, bodies) -> np.ndarray:
        """Positions (n, len(bodies), 3) of bodies at the epochs ``t`` (n,): one vectorised
        call (``Ephemeris.positions_at``) where the ephemeris has it, else one per body."""
        eph = self.ephemeris
        if hasattr(eph, "positions_at"):
            return eph.positions_at(t, bodies)
        return np.stack([eph.position(b, t) for b in bodies], axis=1)

    def frame_request(self, k: int, rng: np.random.Generator) -> FrameRequest:
        """Frame k's scene: poses are drawn in the documented order until one passes the
        keep-filters. Draws are made and pre-tested (Sun distance, bodies near the field) in
        batches of :attr:`BATCH`; the first pose that passes, the number of draws, and the state
        the stream is left in (where the renderer starts) are those of drawing and testing one
        pose at a time."""
        s = self.s
        done, most = 0, s["max_draws_per_frame"]
        while done < most:
            poses, states = [], []
            for _ in range(min(self.BATCH, most - done)):
                poses.append(self.draw_pose(rng))
                states.append(rng.bit_generator.state)
            t = np.array([p[0] for p in poses])
            r = np.array([p[1] for p in poses])
            near = self._near_sun(t, r)
            cands = self._fov_candidates_batch(t, r, np.array([p[2][2] for p in poses]))
            for i, (ti, ri, R) in enumerate(poses):
                if near[i] or cands[i] == ():
                    continue
                v = self.velocity(ti, ri)
                ok, facts, sky = self._sky(ti, ri, v, R, cands[i])
                if ok:
                    rng.bit_generator.state = states[i]  # rewind: the poses after this one were not drawn
                    meta = {"kind": "montecarlo", "frame": int(k), "draws": done + i + 1,
                            "visible_bodies": facts["visible_bodies"], "bodies_in_fov": facts["bodies_in_fov"]}
                    return FrameRequest(epoch_tdb_s=ti, position_km=ri, velocity_km_s=v, R_cam_icrs=R, meta=meta, sky=sky)
            done += len(poses)
        raise SceneSamplingError(
            f"frame {k}: no scene passed the keep-filters {s['keep']} in {s['max_draws_per_frame']} draws;"
            " raise montecarlo.max_draws_per_frame or relax montecarlo.keep")

    def describe(self) -> dict:
        return {}


class ScenesPlan:
    """Free-form recipe: an explicit list of scenes (same keys as scene files), rendered in order.

    A scene's own ``camera`` (size, optics, sensor) and ``visibility`` replace the recipe's for
    that frame; its ``render.catalog_limiting_v_mag``, ``render.resolved_threshold_px``,
    ``render.cosmic_rays_per_frame`` and ``render.mitsuba_spp`` replace the recipe's (its
    ``render:`` mapping, or the defaults) for that frame. The frame's ground truth records the camera and star limit it was rendered
    with, and the scene's ``render`` mapping under ``dataset.render``. (``render.seed`` is refused
    by :func:`~skynav.datasets.recipe_checks.validate_recipe`: frame k's stream is fixed by the
    recipe's seed.)
    """

    kind = "scenes"

    def __init__(self, recipe: dict, camera, *, ephemeris=None):
        self.recipe = recipe
        self.camera = camera
        self.visibility = recipe_visibility(recipe)
        self.specs = [scene_spec_from_mapping({**sc, "camera": sc.get("camera", recipe["camera"]),
                                               "visibility": sc.get("visibility", recipe.get("visibility", {}))})
                      for sc in recipe["scenes"]]
        self.n_frames = len(self.specs)
        self._eph = ephemeris

    def frame_request(self, k: int, rng: np.random.Generator) -> FrameRequest:
        spec = self.specs[k]
        given = self.recipe["scenes"][k]
        render = dict(given.get("render") or {})
        a = spec.attitude
        t, r, v, R, sky = resolve_spec(spec, ephemeris=self._eph)
        meta = {"kind": "scenes", "frame": int(k)}
        if render:
            meta["render"] = render
        return FrameRequest(epoch_tdb_s=t, position_km=r, velocity_km_s=v, R_cam_icrs=R,
                            angular_velocity_rad_s=np.asarray(a.angular_velocity_rad_s, dtype=float), meta=meta, sky=sky,
                            camera=spec.camera if "camera" in given else None,
                            catalog_limiting_v_mag=spec.catalog_limiting_v_mag if "catalog_limiting_v_mag" in render else None,
                            resolved_threshold_px=spec.resolved_threshold_px if "resolved_threshold_px" in render else None,
                            visibility=spec.visibility if "visibility" in given else None,
                            cosmic_rays_per_frame=spec.cosmic_rays_per_frame if "cosmic_rays_per_frame" in render else None,
                            mitsuba_spp=spec.mitsuba_spp if "mitsuba_spp" in render else None)

    def describe(self) -> dict:
        return {}


def make_plan(recipe: dict, *, ephemeris=None):
    """The plan of a validated recipe (for a sequence: computes the trajectory and legs)."""
    camera = recipe_camera(recipe)
    if recipe["kind"] == "montecarlo":
        return MonteCarloPlan(recipe, camera, ephemeris=ephemeris)
    if recipe["kind"] == "scenes":
        return ScenesPlan(recipe, camera, ephemeris=ephemeris)

    return SequencePlan(recipe, camera, ephemeris=ephemeris)

