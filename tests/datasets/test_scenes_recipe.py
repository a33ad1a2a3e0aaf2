"""A ``scenes`` recipe renders each scene with its own ``camera`` and ``render`` keys.

Before: the keys were validated, then ignored (a scene's 64 x 64 camera came out at the recipe's
size and star limit). The reference here is the scene's own mapping read by the scene-file
parser (:func:`skynav.scenes.config.camera_from_mapping`), independent of the dataset code.
"""

from __future__ import annotations

import numpy as np
import pytest

import skynav.datasets as D
from skynav.scenes.config import camera_from_mapping

_OBSERVER = {"position_km": [1.2e8, -9.0e7, -3.9e7], "velocity_km_s": [18.0, 21.0, 9.0]}
_OWN_CAMERA = {"preset": "paper", "width": 64, "height": 48, "fov_deg": 12.0, "exposure_s": 0.1}


def _recipe() -> dict:
    return {
        "kind": "scenes",
        "seed": 5,
        "camera": {"preset": "paper", "width": 128, "height": 128, "fov_deg": 20.0},
        "catalog_limiting_v_mag": 7.0,
        "formats": ["png", "json"],
        "scenes": [
            {"epoch": "2027-03-15T00:00:00", "observer": _OBSERVER,
             "attitude": {"ra_deg": 83.6, "dec_deg": 22.0, "twist_deg": 30.0},
             "camera": _OWN_CAMERA, "visibility": {"limiting_v_mag": 3.0},
             "render": {"catalog_limiting_v_mag": 4.0, "cosmic_rays_per_frame": 20}},
            {"epoch": "2027-03-15T00:10:00", "observer": _OBSERVER,
             "attitude": {"ra_deg": 83.6, "dec_deg": 22.0, "twist_deg": 30.0}},
        ],
    }


def test_per_scene_camera_and_star_limit_are_used_and_recorded(tmp_path):
    D.generate(_recipe(), tmp_path / "ds", workers=1, progress=False)
    ds = D.open(tmp_path / "ds")
    own, default = ds[0], ds[1]
    ref = camera_from_mapping(_OWN_CAMERA)

    # the scene's camera: image size, intrinsics and exposure, in the pixels and in the truth
    assert own.dn.shape == (48, 64)
    cam = own.truth["camera"]
    assert (cam["width"], cam["height"]) == (64, 48)
    assert np.allclose(cam["K"], ref.K, rtol=1e-12, atol=0)
    assert cam["exposure_s"] == pytest.approx(0.1, rel=1e-12)
    # the scene's star limit: no catalog star fainter than V 4 (the recipe says 7)
    assert own.truth["catalog_limiting_v_mag"] == 4.0
    assert own.truth["stars"] and max(s["v_mag"] for s in own.truth["stars"]) <= 4.0
    assert own.truth["dataset"]["render"] == {"catalog_limiting_v_mag": 4.0, "cosmic_rays_per_frame": 20}
    # the scene's visibility rule and cosmic-ray rate (Poisson mean 20: P(no hit) = 2e-9)
    assert own.truth["visibility"]["limiting_v_mag"] == 3.0
    assert own.truth["render"]["cosmic_rays_per_frame"] == 20 and len(own.truth["cosmic_rays"]) > 0

    # the other scene keeps the recipe's camera and star limit
    assert default.dn.shape == (128, 128)
    assert default.truth["camera"]["width"] == 128 and default.truth["catalog_limiting_v_mag"] == 7.0
    assert max(s["v_mag"] for s in default.truth["stars"]) > 4.0
    assert "render" not in default.truth["dataset"]
    assert default.truth["visibility"]["limiting_v_mag"] == 7.0
    assert default.truth["render"]["cosmic_rays_per_frame"] == 1.0


def test_per_scene_seed_is_refused_in_one_line():
    r = _recipe()
    r["scenes"][1]["render"] = {"seed": 3}
    with pytest.raises(D.RecipeError) as err:
        D.validate_recipe(r)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("scenes[1].render.seed = 3 is not allowed")
