"""The camera's pose from a printed ChArUco board lying on the table (OpenCV's ``aruco`` module).

The board defines the table frame: its centre is the origin (or lies at ``origin_xy`` in the table
frame), its printed top edge points away from the robot (+y), its printed right edge to the robot's
right (+x), z up out of the table. OpenCV's board coordinates have x along the columns, y down the
rows and z into the paper, so ``T_world_board`` = diag(1, -1, -1) about the board's centre.

The camera is static, so the corners found in several frames (hands may hide part of the board in
one frame, not in all) go into one ``solvePnP`` (iterative, refined): more corners, less noise.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

DICTIONARIES = ("DICT_4X4_50", "DICT_4X4_100", "DICT_5X5_50", "DICT_5X5_100", "DICT_6X6_50", "DICT_6X6_250")
PAPER_MM = {"A4": (297.0, 210.0), "A3": (420.0, 297.0), "letter": (279.4, 215.9)}


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares across x rows, the square and marker sides in metres, the dictionary."""

    squares_x: int = 7
    squares_y: int = 5
    square_m: float = 0.038
    marker_m: float = 0.028
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise ValueError(f"a board needs at least 3 x 3 squares, got {self.squares_x} x {self.squares_y}")
        if not 0 < self.marker_m < self.square_m:
            raise ValueError(f"the marker ({self.marker_m * 1000:g} mm) must be smaller than the square "
                             f"({self.square_m * 1000:g} mm)")
        if self.dictionary not in DICTIONARIES:
            raise ValueError(f"unknown dictionary {self.dictionary!r}; choose one of {', '.join(DICTIONARIES)}")

    @property
    def size_m(self) -> tuple[float, float]:
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def cv_board(self):
        import cv2

        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, d)

    def image(self, px_per_m: float, margin_px: int = 0) -> np.ndarray:
        """The board as a grayscale image at ``px_per_m`` (a white margin of ``margin_px`` around it)."""
        w, h = self.size_m
        size = (int(round(w * px_per_m)) + 2 * margin_px, int(round(h * px_per_m)) + 2 * margin_px)
        return self.cv_board().generateImage(size, marginSize=margin_px, borderBits=1)

    def to_json(self) -> dict:
        return asdict(self)


def T_world_board(spec: BoardSpec, origin_xy: Sequence[float] = (0.0, 0.0)) -> np.ndarray:
    """OpenCV board coordinates -> table frame for a board lying face up, top edge away from the robot,
    its centre at ``origin_xy``."""
    w, h = spec.size_m
    T = np.diag([1.0, -1.0, -1.0, 1.0])
    T[:3, 3] = [origin_xy[0] - w / 2, origin_xy[1] + h / 2, 0.0]
    return T


@dataclass
class BoardFit:
    """The board's pose seen by the camera and how well it fits."""

    T_camera_board: np.ndarray     # (4, 4)
    frames_used: list[int]
    corners: int                   # corner observations in the fit
    reprojection_px: float         # RMS


def find_corners(rgb: np.ndarray, spec: BoardSpec) -> tuple[np.ndarray, np.ndarray] | None:
    """(object points (n, 3) in board coordinates, image points (n, 2)) of the ChArUco corners found in
    one frame, or None when fewer than 6 are seen."""
    import cv2

    board = spec.cv_board()
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    params = cv2.aruco.CharucoParameters()
    det_params = cv2.aruco.DetectorParameters()
    det_params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.CharucoDetector(board, params, det_params)
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < 6:
        return None
    obj, img = board.matchImagePoints(corners, ids)
    if obj is None or len(obj) < 6:
        return None
    return obj.reshape(-1, 3).astype(np.float64), img.reshape(-1, 2).astype(np.float64)


def fit_board(frames: Sequence[tuple[int, np.ndarray]], K: np.ndarray, spec: BoardSpec,
              dist: np.ndarray | None = None) -> BoardFit | None:
    """One pose from the corners of every frame where the board is seen (the camera is static)."""
    import cv2

    obj, img, used = [], [], []
    for i, rgb in frames:
        got = find_corners(rgb, spec)
        if got is not None:
            obj.append(got[0])
            img.append(got[1])
            used.append(int(i))
    if not obj:
        return None
    P, q = np.concatenate(obj), np.concatenate(img)
    d = np.zeros(5) if dist is None else np.asarray(dist, float)
    ok, rvec, tvec = cv2.solvePnP(P, q, np.asarray(K, float), d, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(P, q, np.asarray(K, float), d, rvec, tvec)
    proj, _ = cv2.projectPoints(P, rvec, tvec, np.asarray(K, float), d)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - q) ** 2, axis=1))))
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.reshape(3)
    return BoardFit(T_camera_board=T, frames_used=used, corners=len(P), reprojection_px=rms)


def write_board_print(spec: BoardSpec, path: str | Path, paper: str = "A4", dpi: int = 300) -> Path:
    """The board to print at its true size: PNG (with its dpi) or PDF (one page of ``paper``)."""
    path = Path(path)
    w_mm, h_mm = PAPER_MM[paper]
    bw, bh = (x * 1000 for x in spec.size_m)
    if bw > w_mm - 10 or bh > h_mm - 10:
        raise ValueError(f"a {spec.squares_x} x {spec.squares_y} board of {spec.square_m * 1000:g} mm squares "
                         f"({bw:.0f} x {bh:.0f} mm) does not fit on {paper} ({w_mm:.0f} x {h_mm:.0f} mm, landscape)")
    px_per_m = dpi / 0.0254
    img = spec.image(px_per_m)
    caption = (f"demoforge ChArUco {spec.squares_x}x{spec.squares_y}, {spec.dictionary}, square {spec.square_m * 1000:g} mm, "
               f"marker {spec.marker_m * 1000:g} mm. Print at 100 % and check a square measures "
               f"{spec.square_m * 1000:g} mm. Lay it flat, this edge towards the robot.")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".png":
        from PIL import Image

        Image.fromarray(img).save(path, dpi=(dpi, dpi))
        return path
    if path.suffix.lower() != ".pdf":
        raise ValueError(f"{path}: the board print must be a .pdf or a .png")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(w_mm / 25.4, h_mm / 25.4))
    left, bottom = (w_mm - bw) / 2 / w_mm, (h_mm - bh) / 2 / h_mm
    ax = fig.add_axes((left, bottom, bw / w_mm, bh / h_mm))
    ax.imshow(img, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    ax.set_axis_off()
    fig.text(0.5, bottom / 2, caption, ha="center", va="center", fontsize=7)
    fig.text(0.5, 1 - bottom / 2, "top: away from the robot (+y)", ha="center", va="center", fontsize=8)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
