"""Another program, in another process: it reads the frames itself and writes a results file.

    python docs/examples/ip_results_program.py DATASET RESULTS.jsonl
    skynav bench score ip DATASET RESULTS.jsonl -o REPORT

It does not import skynav: any language that reads a PNG and writes JSON can do the same. Per
frame ``frames/NNNNNN.png`` it finds the stars with tetra3rs (its own centroids, lost in space,
the camera's focal length from the frame's ``camera.K``) and writes one line of the results
schema (skynav/datasets/schemas/ip_results.schema.json): ``frame``, ``R_cam_icrs`` (or null),
``status`` and ``time_ms``.
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
import tetra3rs
from PIL import Image


def main(dataset, results):
    frames = sorted((Path(dataset) / "frames").glob("*.png"))
    camera = json.loads(frames[0].with_suffix(".json").read_text())["camera"]
    width, height, fx = camera["width"], camera["height"], camera["K"][0][0]
    fov_deg = float(np.degrees(2 * np.arctan(width / (2 * fx))))
    db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=1.05 * fov_deg, min_fov_deg=0.95 * fov_deg)
    model = tetra3rs.CameraModel(focal_length_px=fx, image_width=width, image_height=height)
    with open(results, "w") as out:
        for png in frames:
            t0 = time.perf_counter()
            image = np.asarray(Image.open(png))
            stars = tetra3rs.extract_centroids(image).centroids
            solution = db.solve_from_centroids(stars, camera_model=model) if len(stars) >= 4 else None
            R = np.asarray(solution.rotation_matrix_icrs_to_camera).tolist() if solution else None
            line = {"frame": int(png.stem), "R_cam_icrs": R, "status": "ok" if R else "unsolved",
                    "time_ms": (time.perf_counter() - t0) * 1e3}
            out.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main(*sys.argv[1:3])
