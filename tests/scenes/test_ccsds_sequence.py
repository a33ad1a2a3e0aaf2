"""A sequence dataset writes its trajectory and attitudes as CCSDS OEM/AEM beside its CSV, and
they give back every frame's truth: the observer (1 m) and the attitude (1e-9 rad)."""

import numpy as np
import pytest

pytest.importorskip("ccsds_ndm")

from skynav.datasets import preset_recipe  # noqa: E402
from skynav.scenes import frames  # noqa: E402
from skynav.scenes.mission_ccsds import aem_attitude, oem_state, read_aem, read_oem  # noqa: E402


def test_sequence_dataset_writes_oem_and_aem_of_its_frames(tmp_path):
    import skynav.datasets as D

    rec = preset_recipe("sequence")
    rec["frames"] = 2
    rec["camera"] = {"preset": "paper", "width": 128, "height": 128, "fov_deg": 20.0}
    rec["catalog_limiting_v_mag"] = 6.0
    D.generate(rec, tmp_path / "seq", workers=1, progress=False)
    root = tmp_path / "seq"
    ds = D.open(root)
    assert set(ds.manifest["files"]) >= {"trajectory.csv", "trajectory.oem", "attitude.aem"}
    oem, aem = read_oem(root / "trajectory.oem"), read_aem(root / "attitude.aem")
    assert len(aem.t_tdb_s) == 2
    for fr in ds:
        t = fr.truth
        from skynav.scenes.timescales import tdb_seconds

        ts = float(tdb_seconds(t["epoch"]["tdb_iso"]))
        # the OEM holds the cruise hourly: cubic Hermite between two hourly states (truth: the
        # propagated trajectory, its dense output); 1 m at 20-30 km/s
        r, v = oem_state(oem, ts)
        assert np.max(np.abs(r - np.array(t["observer"]["position_km"]))) < 1e-3
        assert np.max(np.abs(v - np.array(t["observer"]["velocity_km_s"]))) < 1e-6
        q, w = aem_attitude(aem, ts)
        R = np.array(t["attitude"]["R_cam_icrs"])
        # the frame's attitude itself (pointing error and jitter drawn as the frame drew them)
        assert np.max(np.abs(frames.quat_to_dcm(q) - R)) < 1e-9
        np.testing.assert_allclose(w, t["attitude"]["angular_velocity_rad_s"], rtol=0, atol=1e-15)
    assert D.verify(root).ok
