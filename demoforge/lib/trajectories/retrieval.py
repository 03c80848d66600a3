"""Episode retrieval by object-keypoint similarity (thesis 3.4) and the evaluation's other selections.

MSE(K_q, K_db) = 1/N sum_i ||K_q,i - K_db,i||^2 over the N object keypoints (the thesis's metric).
Exact top-k: distances by the expansion ||q||^2 - 2 q.x + ||x||^2 (float64, one GEMV/GEMM over the
index), candidates by np.argpartition with a rounding margin, then the candidates' MSE recomputed
directly from differences and sorted by (MSE, id): the result equals a brute-force loop, ties
broken by the smaller id.

Metrics: "mse" (plain); "mse_mirrored": the MSE of the query against the mirror image of each stored
scene (reflect x -> -x and re-order keypoints with the task's mirror permutation, so that left/right
keypoint pairs keep their meaning; equivalently the mirrored query against the stored scene);
"min": min of the two (a scene matches a stored scene or its mirror image).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_EPS = 64 * np.finfo(np.float64).eps


@dataclass
class RetrievalResult:
    ids: np.ndarray  # (Q, k) episode ids, best first
    mse: np.ndarray  # (Q, k)
    mirrored: np.ndarray  # (Q, k) bool: matched the mirror image (metric "mse_mirrored" / "min")


class KeypointIndex:
    """Exact top-k index over (N, K, 3) episode keypoints with (N,) integer ids."""

    def __init__(self, keypoints: np.ndarray, ids: np.ndarray | None = None, mirror_perm: np.ndarray | None = None):
        kp = np.asarray(keypoints, dtype=np.float64)
        if kp.ndim != 3 or kp.shape[-1] != 3:
            raise ValueError(f"keypoints must be (N, K, 3), got {kp.shape}")
        self.n, self.k_points = kp.shape[:2]
        self.X = np.ascontiguousarray(kp.reshape(self.n, -1))
        self.ids = np.arange(self.n, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64)
        if self.ids.shape != (self.n,):
            raise ValueError("ids must be (N,)")
        # sorting rows by id makes "smallest position" = "smallest id" for the tie-break
        order = np.argsort(self.ids, kind="stable")
        if not np.all(order == np.arange(self.n)):
            self.X, self.ids = self.X[order], self.ids[order]
        self.sq = np.einsum("ij,ij->i", self.X, self.X)
        self.mirror_perm = None if mirror_perm is None else np.asarray(mirror_perm, int)

    def __len__(self) -> int:
        return self.n

    def _mirror_query(self, q: np.ndarray) -> np.ndarray:
        if self.mirror_perm is None:
            raise ValueError("metric needs mirror_perm")
        m = q.reshape(q.shape[0], self.k_points, 3)[:, self.mirror_perm] * np.array([-1.0, 1.0, 1.0])
        return m.reshape(q.shape[0], -1)

    def _dist(self, Q: np.ndarray) -> np.ndarray:
        """(Q, N) squared distances minus ||q||^2 (a per-query constant, equal for a query and its
        mirror image): ||x||^2 - 2 q.x by the expansion, only for ranking (exact values recomputed)."""
        D = Q @ self.X.T
        D *= -2.0
        D += self.sq[None, :]
        return D

    def query(self, q: np.ndarray, k: int = 3, metric: str = "mse", exclude_ids=None) -> RetrievalResult:
        """q (K, 3) or (Q, K, 3) -> RetrievalResult with (Q, k) arrays ((1, k) for a single query).
        exclude_ids: ids never returned (e.g. the query's own episode)."""
        q = np.asarray(q, dtype=np.float64)
        Q = q.reshape(-1, self.k_points * 3) if q.ndim == 3 else q.reshape(1, -1)
        if Q.shape[1] != self.X.shape[1]:
            raise ValueError(f"query has {Q.shape[1] // 3} keypoints, index has {self.k_points}")
        k = int(min(k, self.n))
        if metric == "mse":
            D, M = self._dist(Q), None
        elif metric == "mse_mirrored":
            D, M = self._dist(self._mirror_query(Q)), None
        elif metric == "min":
            Dp, Dm = self._dist(Q), self._dist(self._mirror_query(Q))
            M = Dm < Dp
            D = np.minimum(Dp, Dm)
        else:
            raise ValueError(f"unknown metric {metric!r}")
        if exclude_ids is not None:
            ex = np.isin(self.ids, np.asarray(exclude_ids))
            D[:, ex] = np.inf
        nq = Q.shape[0]
        out_ids = np.empty((nq, k), np.int64)
        out_mse = np.empty((nq, k))
        out_m = np.zeros((nq, k), bool)
        if k == 0:
            return RetrievalResult(out_ids, out_mse, out_m)
        scale = _EPS * (np.einsum("ij,ij->i", Q, Q)[:, None] + self.sq.max() + 1.0)
        part = np.argpartition(D, k - 1, axis=1)[:, :k] if k < self.n else np.tile(np.arange(self.n), (nq, 1))
        kth = np.take_along_axis(D, part, 1).max(1, keepdims=True)
        for r in range(nq):  # per query: candidates within the rounding margin, exact re-ranking
            cand = np.flatnonzero(D[r] <= kth[r] + 4 * scale[r, 0])
            if exclude_ids is not None:
                cand = cand[np.isfinite(D[r, cand])]
            diffp = self.X[cand] - Q[r]
            e = np.einsum("ij,ij->i", diffp, diffp) / self.k_points
            mir = np.zeros(len(cand), bool)
            if metric != "mse":
                Qm = self._mirror_query(Q[r:r + 1])[0]
                diffm = self.X[cand] - Qm
                em = np.einsum("ij,ij->i", diffm, diffm) / self.k_points
                if metric == "mse_mirrored":
                    e, mir = em, np.ones(len(cand), bool)
                else:
                    mir = em < e
                    e = np.minimum(e, em)
            o = np.lexsort((self.ids[cand], e))[:k]
            out_ids[r, :len(o)] = self.ids[cand[o]]
            out_mse[r, :len(o)] = e[o]
            out_m[r, :len(o)] = mir[o]
        return RetrievalResult(out_ids, out_mse, out_m)


def mse_brute_force(keypoints: np.ndarray, ids: np.ndarray, q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference: Python loop over episodes, MSE from differences, sorted by (MSE, id)."""
    rows = []
    for i in range(len(keypoints)):
        d = keypoints[i] - q
        rows.append((float(np.sum(d * d)) / len(q), int(ids[i])))
    rows.sort()
    top = rows[:k]
    return np.array([r[1] for r in top], np.int64), np.array([r[0] for r in top])


def select_random(ids, k: int, seed: int | None = None) -> np.ndarray:
    """k distinct ids uniformly at random (the evaluation's "random augmentation" prompt)."""
    ids = np.asarray(ids)
    rng = np.random.default_rng(seed)
    return rng.choice(ids, size=min(k, len(ids)), replace=False)


def select_original(ids, kinds) -> np.ndarray:
    """The single original demonstration (the evaluation's "no augmentation" baseline): the ids of
    kind "original" (one per take)."""
    ids, kinds = np.asarray(ids), np.asarray(kinds)
    out = ids[kinds == "original"]
    if len(out) == 0:
        raise ValueError("no episode of kind 'original'")
    return out


def select(strategy: str, index: KeypointIndex | None = None, query=None, ids=None, kinds=None, k: int = 3,
           seed: int | None = None, metric: str = "mse") -> np.ndarray:
    """One of the evaluation's three strategies: "retrieval" (top-k), "random" (k at random), "single"."""
    if strategy == "retrieval":
        return index.query(query, k, metric).ids[0]
    if strategy == "random":
        return select_random(ids, k, seed)
    if strategy == "single":
        return select_original(ids, kinds)[:1]
    raise ValueError(f"unknown strategy {strategy!r}")


__all__ = ["KeypointIndex", "RetrievalResult", "mse_brute_force", "select_random", "select_original", "select"]
