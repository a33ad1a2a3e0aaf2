"""An AEM (and OEM) written by skynav, read back by a second, independent reader: ``ccsds-ndm``
(Egemen Imre; Python classes generated from the CCSDS NDM/XML schemas with xsdata), where skynav
writes with ``ccsds-ndm-py`` (Rust bindings).

The two packages install the same import name, ``ccsds_ndm``, so they cannot share an
environment: the second reader lives in a folder of its own and runs in a subprocess. Make it with
``pip install --target DIR ccsds-ndm==3.1.1`` and point ``SKYNAV_SECOND_NDM_PATH`` at DIR; without
it these tests skip. Its XML reader is the one used: its KVN reader of AEM version 2 does not
know ``ATTITUDE_TYPE = QUATERNION/ANGVEL`` (version 2's name) and orders a plain ``QUATERNION``
scalar first (version 1's default), so skynav's version-2 KVN is not a fair test of it.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("ccsds_ndm")

from skynav.scenes import frames  # noqa: E402
from skynav.scenes.mission_ccsds import aem_xml, oem_xml, read_aem, read_oem  # noqa: E402
from skynav.scenes.timescales import tdb_seconds  # noqa: E402

SECOND = os.environ.get("SKYNAV_SECOND_NDM_PATH", "")
pytestmark = pytest.mark.skipif(not os.path.isfile(os.path.join(SECOND, "ccsds_ndm", "ndm_io.py")),
                                reason="the second CCSDS reader (ccsds-ndm) is not installed in SKYNAV_SECOND_NDM_PATH")

READ = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
from ccsds_ndm.ndm_io import NdmIo
msg = NdmIo().from_path(sys.argv[2])
out = []
for seg in msg.body.segment:
    md = seg.metadata
    if sys.argv[3] == "aem":
        for s in seg.data.attitude_state:
            x = s.quaternion_ang_vel
            out.append([x.epoch, x.quaternion.q1, x.quaternion.q2, x.quaternion.q3, x.quaternion.qc,
                        x.ang_vel.angvel_x.value, x.ang_vel.angvel_y.value, x.ang_vel.angvel_z.value,
                        str(md.ref_frame_a), str(md.time_system)])
    else:
        for s in seg.data.state_vector:
            out.append([s.epoch] + [getattr(s, k).value for k in ("x", "y", "z", "x_dot", "y_dot", "z_dot")]
                       + [str(md.ref_frame), str(md.time_system), str(md.center_name)])
print(json.dumps(out))
"""


def _second_reader(path, kind):
    done = subprocess.run([sys.executable, "-c", READ, SECOND, str(path), kind], capture_output=True, text=True,
                          env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"}, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout)


def test_an_aem_skynav_writes_is_read_by_the_second_reader_to_the_same_attitudes(tmp_path):
    rng = np.random.default_rng(3)
    t = float(tdb_seconds("2027-02-01T00:00:00")) + np.cumsum(rng.uniform(1.0, 100.0, 20))
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    w = rng.normal(0.0, 1e-3, (20, 3))
    (tmp_path / "a.xml").write_text(aem_xml(t, q, w))
    rows = _second_reader(tmp_path / "a.xml", "aem")
    assert len(rows) == 20 and {tuple(r[-2:]) for r in rows} == {("ICRF", "TDB")}
    # the same quaternion (Q1 Q2 Q3 QC: scalar last) and rate (deg/s): float64 written in full
    q2 = np.array([[r[4], r[1], r[2], r[3]] for r in rows])
    np.testing.assert_allclose(q2, q, rtol=0, atol=2e-16)
    np.testing.assert_allclose(np.radians([r[5:8] for r in rows]), w, rtol=1e-15, atol=0)
    # the epochs, TDB: to the microsecond the file writes
    np.testing.assert_allclose([tdb_seconds(r[0]) for r in rows], t, rtol=0, atol=1e-6)
    # and skynav's reader reads the same file to the same attitude matrices
    mine = read_aem(tmp_path / "a.xml")
    for qa, qb in zip(mine.q_cam_icrs, q2):
        np.testing.assert_allclose(frames.quat_to_dcm(qa), frames.quat_to_dcm(qb), rtol=0, atol=1e-15)


def test_an_oem_skynav_writes_is_read_by_the_second_reader_to_the_same_states(tmp_path):
    rng = np.random.default_rng(4)
    t = float(tdb_seconds("2027-02-01T00:00:00")) + np.arange(10) * 3600.0
    r, v = rng.normal(0.0, 1.5e8, (10, 3)), rng.normal(0.0, 30.0, (10, 3))
    (tmp_path / "o.xml").write_text(oem_xml(t, r, v))
    rows = _second_reader(tmp_path / "o.xml", "oem")
    assert {tuple(x[-3:]) for x in rows} == {("ICRF", "TDB", "SOLAR SYSTEM BARYCENTER")}
    np.testing.assert_allclose([x[1:4] for x in rows], r, rtol=1e-15, atol=0)
    np.testing.assert_allclose([x[4:7] for x in rows], v, rtol=1e-15, atol=0)
    np.testing.assert_allclose(read_oem(tmp_path / "o.xml").position_km, r, rtol=1e-15, atol=0)


def test_a_sequence_datasets_attitudes_are_read_by_the_second_reader(tmp_path):
    """The ``attitude_aem.xml`` a sequence dataset writes: the frames' own attitudes."""
    from skynav.datasets import preset_recipe, validate_recipe
    from skynav.datasets.samplers import frame_rng, make_plan

    recipe = preset_recipe("sequence")
    recipe["sequence"]["legs"] = 1
    recipe["frames"] = 5
    plan = make_plan(validate_recipe(recipe))
    (tmp_path / "attitude_aem.xml").write_bytes(plan.side_files()["attitude_aem.xml"])
    rows = _second_reader(tmp_path / "attitude_aem.xml", "aem")
    for k, row in enumerate(rows):
        req = plan.frame_request(k, frame_rng(int(plan.recipe["seed"]), k))
        R = frames.quat_to_dcm([row[4], row[1], row[2], row[3]])
        np.testing.assert_allclose(R, req.R_cam_icrs, rtol=0, atol=1e-15)
    assert len(rows) == 5
