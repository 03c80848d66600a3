"""The thesis's Tables 1, 2 and Appendix B computed in Python from `keypoint_metrics` rows: the oracle the
tests check the report's SQL views (report_table1, report_table2, report_appendix_b) against."""

from __future__ import annotations

from typing import Sequence

from demoforge.lib.evaluation.keypoints import HAND_LABEL, SIDES, _avg, _take_order


def _by_hand(rows, side):
    return [r for r in rows if r.get("hand") == side]


def table1(rows: Sequence[dict], weighting: str = "frames") -> list[dict]:
    """Thesis Table 1: MPJPE / PA-MPJPE (m) per hand, raw and aligned, averaged over takes
    (``weighting``: "frames" = eq. (4) pooled over all evaluated frames, "takes" = plain mean)."""
    out = []
    for side in SIDES:
        rs = _by_hand(rows, side)
        for aligned in (False, True):
            sfx = "_aligned" if aligned else ""
            wk = "n_eval_aligned" if aligned else "n_eval"
            out.append({"method": HAND_LABEL[side] + (" (Aligned)" if aligned else ""), "hand": side,
                        "aligned": aligned, "mpjpe_m": _avg(rs, f"mpjpe{sfx}_m", weighting, wk),
                        "pa_mpjpe_m": _avg(rs, f"pa_mpjpe{sfx}_m", weighting, wk), "n_takes": len(rs)})
    return out


_2D_VARIANTS = {"projected": ("mpjpe_2d_px", "pck05", "pck15", "n_eval"),
                "aligned": ("mpjpe_2d_aligned_px", "pck05_aligned", "pck15_aligned", "n_eval_aligned"),
                "pred_px": ("mpjpe_2d_pred_px", "pck05_pred", "pck15_pred", "n_eval")}


def table2(rows: Sequence[dict], weighting: str = "frames", variant: str = "projected") -> list[dict]:
    """Thesis Table 2: 2D MPJPE (px), PCK@0.05, PCK@0.15 per hand. ``variant``: "projected" (the raw
    3D prediction projected with K, thesis 4.2.2), "aligned" (the aligned one), "pred_px" (the
    detector's own 2D)."""
    k_mp, k05, k15, wk = _2D_VARIANTS[variant]
    out = []
    for side in SIDES:
        rs = _by_hand(rows, side)
        out.append({"hand": HAND_LABEL[side], "mpjpe_2d_px": _avg(rs, k_mp, weighting, wk),
                    "pck05": _avg(rs, k05, weighting, wk), "pck15": _avg(rs, k15, weighting, wk),
                    "n_takes": len(rs), "variant": variant})
    return out


def appendix_b(rows: Sequence[dict]) -> list[dict]:
    """Thesis Appendix B: one row per take (Appendix B's take order first), with its column names:
    mpjpe_left, mpjpe_left_aligned, mpjpe_right, mpjpe_right_aligned, pa-mpjpe_{left,right}[_aligned],
    2D_mpjpe_r, 2D_mpjpe_l, pck05_r, pck15_r, pck05_l, pck15_l (+ object, size_group). The three
    sub-tables' columns are :data:`APPENDIX_B_SECTIONS`."""
    out = []
    nan = float("nan")
    for t in _take_order(rows):
        hs = {r["hand"]: r for r in rows if r.get("take", "") == t}
        L, R = hs.get("left", {}), hs.get("right", {})
        any_r = L or R
        out.append({
            "take": t, "object": any_r.get("object"), "size_group": any_r.get("size_group"),
            "mpjpe_left": L.get("mpjpe_m", nan), "mpjpe_left_aligned": L.get("mpjpe_aligned_m", nan),
            "mpjpe_right": R.get("mpjpe_m", nan), "mpjpe_right_aligned": R.get("mpjpe_aligned_m", nan),
            "pa-mpjpe_left": L.get("pa_mpjpe_m", nan), "pa-mpjpe_left_aligned": L.get("pa_mpjpe_aligned_m", nan),
            "pa-mpjpe_right": R.get("pa_mpjpe_m", nan), "pa-mpjpe_right_aligned": R.get("pa_mpjpe_aligned_m", nan),
            "2D_mpjpe_r": R.get("mpjpe_2d_px", nan), "2D_mpjpe_l": L.get("mpjpe_2d_px", nan),
            "pck05_r": R.get("pck05", nan), "pck15_r": R.get("pck15", nan),
            "pck05_l": L.get("pck05", nan), "pck15_l": L.get("pck15", nan),
        })
    return out
