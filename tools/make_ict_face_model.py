"""Write drivers/data/ict_face_model.npz from a checkout of ICT-FaceKit (github.com/ICT-VGL/ICT-FaceKit, MIT).

usage: python tools/make_ict_face_model.py ICT-FaceKit/FaceXModel drivers/data/ict_face_model.npz [--modes 40]

Keeps what a time-of-flight camera sees of the ICT Face Model Light: the face, head and neck, mouth and eye
sockets and the eyeballs (the README's geometries #0-#4, #7, #8), its generic neutral mesh and its first --modes
identity shape modes (PCA, ordered by variance; identity = neutral + sum_k w_k mode_k with w_k ~ N(0, 1)).
Converts centimetres to metres, splits the quads into triangles and stores the modes as int16 multiples of
MODE_STEP_M.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

KEPT_VERTICES = np.r_[0:14062, 21451:24591]  # face, head and neck, mouth and eye sockets; eyeballs
NOSE_TIP = 4841  # the neutral mesh's front-most vertex (pronasale)
MODE_STEP_M = 1e-5
CM = 0.01


def read_obj(path: Path, *, faces: bool) -> tuple[np.ndarray, list[list[int]]]:
    """Vertices (N, 3) in the file's unit and, if asked, its polygons as 0-based vertex lists."""
    vertices, polygons = [], []
    with path.open() as fh:
        for line in fh:
            if line.startswith("v "):
                vertices.append([float(x) for x in line.split()[1:4]])
            elif faces and line.startswith("f "):
                polygons.append([int(token.split("/")[0]) - 1 for token in line.split()[1:]])
    return np.asarray(vertices), polygons


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model_dir", type=Path, help="ICT-FaceKit's FaceXModel directory")
    ap.add_argument("out", type=Path)
    ap.add_argument("--modes", type=int, default=40)
    args = ap.parse_args()
    neutral, polygons = read_obj(args.model_dir / "generic_neutral_mesh.obj", faces=True)
    index = np.full(len(neutral), -1)
    index[KEPT_VERTICES] = np.arange(len(KEPT_VERTICES))
    triangles = [(index[p[0]], index[p[k]], index[p[k + 1]])
                 for p in polygons if (index[p] >= 0).all() for k in range(1, len(p) - 1)]
    modes = np.stack([read_obj(args.model_dir / f"identity{k:03d}.obj", faces=False)[0] - neutral
                      for k in range(args.modes)])[:, KEPT_VERTICES] * CM
    steps = np.round(modes / MODE_STEP_M)
    if np.abs(steps).max() > np.iinfo(np.int16).max:
        raise SystemExit("a mode moves a vertex beyond the int16 range of MODE_STEP_M steps")
    np.savez_compressed(args.out, vertices=neutral[KEPT_VERTICES] * CM, faces=np.asarray(triangles, np.int32),
                        nose=np.int64(index[NOSE_TIP]), modes=steps.astype(np.int16), mode_step_m=MODE_STEP_M)
    print(f"{args.out}: {len(KEPT_VERTICES)} vertices, {len(triangles)} triangles, {args.modes} modes, "
          f"{args.out.stat().st_size} bytes")


if __name__ == "__main__":
    main()
