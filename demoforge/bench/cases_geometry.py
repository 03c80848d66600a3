"""Benchmark cases of the geometry stage (registered in demoforge/bench/registry.py)."""

from __future__ import annotations

import numpy as np

from demoforge.bench.timing import BenchCase
from demoforge.lib import geometry as g


def cases(quick: bool) -> list[BenchCase]:
    n = 20_000 if quick else 200_000

    def close(a, b):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-9)

    def quat_setup(k):
        q = g.random_quaternions(k, np.random.default_rng(1))

        def baseline():  # per-quaternion formula in Python
            out = np.empty((k, 3, 3))
            for i, (x, y, z, w) in enumerate(q):
                out[i] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
            return out

        return (lambda: g.quat_to_matrix(q)), baseline

    def rodrigues_setup(k):
        rng = np.random.default_rng(2)
        a, b = rng.normal(size=(k, 3)), rng.normal(size=(k, 3))

        def baseline():  # the thesis's formula, one pair at a time
            out = np.empty((k, 3, 3))
            for i in range(k):
                ah, bh = a[i] / np.linalg.norm(a[i]), b[i] / np.linalg.norm(b[i])
                v = np.cross(ah, bh)
                vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
                out[i] = np.eye(3) + vx + vx @ vx * (1 - ah @ bh) / (v @ v)
            return out

        return (lambda: g.rotation_between_vectors(a, b)), baseline

    def umeyama_setup(k):
        rng = np.random.default_rng(3)
        src = rng.normal(size=(k, 21, 3))
        R = g.random_rotations(k, rng)
        dst = 1.3 * np.einsum("kij,knj->kni", R, src) + rng.normal(size=(k, 1, 3))

        def baseline():  # one SVD per sample in a Python loop
            out = np.empty((k, 3, 3))
            for i in range(k):
                _, Ri, _ = g.umeyama(src[i], dst[i])
                out[i] = Ri
            return out

        return (lambda: g.umeyama(src, dst)[1]), baseline

    def reflect_setup(k):
        rng = np.random.default_rng(4)
        p8 = np.concatenate([rng.normal(size=(k, 2, 3)), g.random_quaternions(2 * k, rng).reshape(k, 2, 4),
                             np.ones((k, 2, 1))], axis=-1)

        def baseline():  # matrix route, one pose at a time
            out = np.empty_like(p8)
            M = np.diag([-1.0, 1.0, 1.0])
            for i in range(k):
                for a in range(2):
                    T, grip = g.pose8_to_transform(p8[i, a])
                    R = M @ T[:3, :3]
                    R[:, 1] *= -1
                    out[i, a] = g.transform_to_pose8(g.make_transform(R, M @ T[:3, 3]), grip)
            return out

        def fast():
            return g.reflect_pose8(p8)

        return fast, baseline

    def same_rotation_pose8(a, b):
        a, b = np.asarray(a), np.asarray(b)
        close(a[..., :3], b[..., :3])
        close(g.quat_to_matrix(a[..., 3:7]), g.quat_to_matrix(b[..., 3:7]))

    small = max(n // 20, 1000)
    return [
        BenchCase("geometry", "quat_to_matrix", n, "quats", "per-quaternion Python formula", quat_setup,
                  close, baseline_size=small),
        BenchCase("geometry", "rotation_between_vectors (Rodrigues)", n, "pairs",
                  "thesis formula per pair in a Python loop", rodrigues_setup, close, baseline_size=small),
        BenchCase("geometry", "umeyama 21-point similarity", n // 10, "samples",
                  "one SVD per sample in a Python loop", umeyama_setup, close, baseline_size=small // 10),
        BenchCase("geometry", "reflect_pose8 across YZ (2-arm poses)", n // 2, "steps",
                  "matrix route per pose in a Python loop", reflect_setup, same_rotation_pose8,
                  baseline_size=small // 2),
    ]
