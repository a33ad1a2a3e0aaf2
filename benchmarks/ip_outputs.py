"""Every output of the image processing on a dataset, to check that a speed change changes none.

Usage::

    python benchmarks/ip_outputs.py dump DATASET OUT.npz [--frames 200] [--mode improved|paper]
    python benchmarks/ip_outputs.py compare A.npz B.npz

``dump`` runs each frame lost in space and then in tracking (from the lost-in-space attitude),
with predicted states drawn at sigma 1e4, 1e6 and 1e7 km (seed 0), and stores per frame and mode:
the status and method, the attitude and its covariance, every centroid, the matched star ids and
each beacon's status, position, predicted position and predicted covariance. ``compare`` prints
the keys and shapes that differ (discrete changes) and, for the numbers, how many arrays are not
bit-identical, the worst difference relative to each array's largest value, by kind, and the
largest angle between two attitudes (arcsec).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402


def dump(dataset, out, n_frames, mode="improved"):
    from skynav.pipeline import OnboardCatalog, process_frame
    from skynav.pipeline.scoring import predicted_state, open_frames

    src = open_frames(dataset)
    cat = OnboardCatalog.load(camera=src.observation(0).camera)
    rec = {}
    for sig in (1e4, 1e6, 1e7):
        rng = np.random.default_rng(0)
        for k in range(min(n_frames, len(src))):
            obs, truth = src.observation(k), src.truth(k)
            ps = predicted_state(truth, sig, rng)
            prior = None
            for tag in ("lis", "trk"):
                if tag == "trk" and prior is None:
                    continue
                r = process_frame(obs, catalog=cat, predicted_state=ps, previous_attitude=prior, mode=mode)
                p = f"{sig:g}/{k}/{tag}/"
                rec[p + "status"] = np.array(r.status)
                rec[p + "method"] = np.array(r.star_id_method)
                rec[p + "R"] = np.zeros(0) if r.attitude.R_cam_icrs is None else r.attitude.R_cam_icrs
                rec[p + "P"] = np.zeros(0) if r.attitude.covariance_rad2 is None else r.attitude.covariance_rad2
                rec[p + "xy"] = np.asarray(r.centroids_xy_px)
                rec[p + "ids"] = np.asarray(r.matched_star_ids if r.matched_star_ids is not None else [])
                for b in r.beacons:
                    q = p + "b/" + b.name + "/"
                    rec[q + "status"] = np.array(b.status)
                    rec[q + "xy"] = np.zeros(0) if b.xy_px is None else np.asarray(b.xy_px)
                    rec[q + "pxy"] = np.asarray(b.predicted_xy_px)
                    rec[q + "pcov"] = np.asarray(b.predicted_cov_px2)
                if tag == "lis":
                    prior = r.attitude.R_cam_icrs
    np.savez(out, **rec)
    print(f"{len(rec)} arrays -> {out}")


def compare(a, b):
    A, B = np.load(a), np.load(b)
    ka, kb = set(A.files), set(B.files)
    discrete = sorted(ka ^ kb)
    n_numeric, worst, worst_att = 0, {}, 0.0
    for k in sorted(ka & kb):
        x, y = A[k], B[k]
        if k.endswith("/R") and x.shape == y.shape == (3, 3):  # the attitude difference, arcsec
            D = x @ y.T  # angle = atan2(|vee(D - D^T)| / 2, (tr D - 1) / 2): exact near 0, unlike arccos
            v = 0.5 * np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
            ang = np.arctan2(np.linalg.norm(v), (np.trace(D) - 1.0) / 2.0)
            worst_att = max(worst_att, float(np.degrees(ang) * 3600.0))
        if x.dtype.kind in "USbiu" or y.dtype.kind in "USbiu" or x.shape != y.shape:
            if x.shape != y.shape or not np.array_equal(x, y):
                discrete.append(k)
            continue
        if not np.array_equal(x, y):
            n_numeric += 1
            kind = k.rsplit("/", 1)[-1]
            scale = max(float(np.max(np.abs(y.astype(float)))), 1e-300)
            worst[kind] = max(worst.get(kind, 0.0), float(np.max(np.abs(x.astype(float) - y.astype(float)))) / scale)
    for k in discrete[:20]:
        print("differs:", k)
    print(f"{len(ka & kb)} common arrays; {len(discrete)} discrete differences (keys, shapes, statuses, ids); "
          f"{n_numeric} numeric arrays not bit-identical; worst relative difference by kind: {worst}; "
          f"largest attitude difference {worst_att:.2e} arcsec")
    return 1 if discrete else 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("dataset")
    d.add_argument("out")
    d.add_argument("--frames", type=int, default=200)
    d.add_argument("--mode", default="improved", choices=("improved", "paper"))
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args(argv)
    if args.cmd == "dump":
        dump(args.dataset, args.out, args.frames, args.mode)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    raise SystemExit(main())
