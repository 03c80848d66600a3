"""HaMeR's crops and cameras: hand box -> square crop (flipped for left hands), crop camera -> camera frame.

Preprocessing follows hamer/datasets/vitdet_dataset.py (ViTDetDataset) and hamer/datasets/utils.py
(expand_to_aspect_ratio, generate_image_patch_cv2) of github.com/geopavlakos/hamer:

* box (x0, y0, x1, y1) -> centre, and ``rescale_factor`` (2.0 in demo.py) times its width/height,
  expanded to the backbone's 192:256 aspect ratio; the crop is the square of the larger side,
  resampled to 256 x 256 (pixel j of the patch samples the image at ``c + (j - 128) * size / 256``;
  for a left hand HaMeR flips the image, which samples at ``c - (j - 128) * size / 256``);
  RGB / 255, minus ImageNet mean, over ImageNet std; the ViT sees the middle 192 columns.
* The network's camera is weak perspective in the crop, (s, tx, ty): HaMeR renders it with a virtual
  focal length of 5000 px per 256 px crop (EXTRA.FOCAL_LENGTH / MODEL.IMAGE_SIZE), i.e. translation
  (tx, ty, 2 * 5000 / (256 s)), and demo.py moves it to the full image with ``cam_crop_to_full``
  (hamer/utils/renderer.py) using a focal length of 5000 / 256 * max(image width, height) and the
  image centre as principal point. :func:`cam_crop_to_camera` does the same with the real
  intrinsics K: the crop camera is a full-image camera with focal F = 5000 * size / 256 centred on
  the box, and matching its scale and offset with K's focal f and principal point gives
  ``Tz = 2 f / (size s)``, ``Tx = 2 (cx_box - cx) / (size s) * f / fx + tx`` (likewise y).
"""

from __future__ import annotations

import warnings

import numpy as np
import torch
import torch.nn.functional as F

__all__ = ["IMAGE_MEAN", "IMAGE_STD", "FOCAL_LENGTH", "IMAGE_SIZE", "BBOX_SHAPE", "boxes_to_crops",
           "crop_images", "cam_crop_to_full", "cam_crop_to_camera", "crop_points_to_image",
           "box_from_keypoints"]

IMAGE_MEAN = (0.485, 0.456, 0.406)
IMAGE_STD = (0.229, 0.224, 0.225)
FOCAL_LENGTH = 5000.0    # EXTRA.FOCAL_LENGTH: HaMeR's virtual focal length for a 256 px crop
IMAGE_SIZE = 256         # MODEL.IMAGE_SIZE
BBOX_SHAPE = (192, 256)  # MODEL.BBOX_SHAPE (width, height) set by load_hamer for the ViT


def boxes_to_crops(boxes_xyxy: np.ndarray, rescale_factor: float = 2.0,
                   bbox_shape: tuple[int, int] = BBOX_SHAPE) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (N, 4) px -> crop centres (N, 2) and square crop sizes (N,) px, as ViTDetDataset does."""
    b = np.asarray(boxes_xyxy, dtype=np.float64).reshape(-1, 4)
    center = (b[:, 0:2] + b[:, 2:4]) / 2.0
    wh = rescale_factor * (b[:, 2:4] - b[:, 0:2])
    w_t, h_t = bbox_shape
    # expand_to_aspect_ratio then .max(): the larger of the height and the width scaled to 192:256
    size = np.maximum(wh[:, 1], wh[:, 0] * h_t / w_t)
    return center, size


def box_from_keypoints(joints_px: np.ndarray, valid: np.ndarray | None = None, min_size: float = 8.0) -> np.ndarray:
    """Tight box (..., 4) x0, y0, x1, y1 of keypoints (..., 21, 2) (NaN rows ignored; all-NaN -> NaN box)."""
    p = np.asarray(joints_px, dtype=np.float64)
    if valid is not None:
        p = np.where(np.asarray(valid, bool)[..., None], p, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN hands give NaN boxes
        lo, hi = np.nanmin(p, axis=-2), np.nanmax(p, axis=-2)
    c, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, min_size / 2)
    return np.concatenate([c - half, c + half], axis=-1)


def crop_images(images: torch.Tensor, image_index: torch.Tensor, center: torch.Tensor, size: torch.Tensor,
                flip: torch.Tensor, out_size: int = IMAGE_SIZE) -> torch.Tensor:
    """Normalised square crops for the network, batched with grid_sample (CPU or GPU).

    Args:
        images: (B, H, W, 3) uint8 or float RGB (0-255).
        image_index: (N,) which image each crop comes from.
        center, size: (N, 2), (N,) crop centre and side in pixels (pixel centres at integers).
        flip: (N,) bool: mirror the crop horizontally (left hands).

    Returns:
        (N, 3, out_size, out_size) float32, ImageNet-normalised; outside the image = black, as
        HaMeR's BORDER_CONSTANT.
    """
    dev = images.device
    B, H, W, _ = images.shape
    n = int(image_index.shape[0])
    j = torch.arange(out_size, device=dev, dtype=torch.float32) - out_size / 2  # (j - 128)
    step = (size.to(dev).float() / out_size)[:, None]                          # px per patch px
    sign = torch.where(flip.to(dev).bool(), -1.0, 1.0)[:, None]
    center = center.to(dev).float()
    gx = (2 * (center[:, 0:1] + sign * j[None] * step) + 1) / W - 1          # align_corners=False
    gy = (2 * (center[:, 1:2] + j[None] * step) + 1) / H - 1
    grid = torch.stack([gx[:, None, :].expand(-1, out_size, -1), gy[:, :, None].expand(-1, -1, out_size)], -1)
    patch = torch.empty(n, 3, out_size, out_size, device=dev)
    image_index = image_index.to(dev).long()
    # one grid_sample per source image with its crops side by side: each image is converted to
    # float once, not once per crop (a 1080p frame is 25 MB as float)
    for b in torch.unique(image_index).tolist():
        sel = torch.nonzero(image_index == b)[:, 0]
        img = images[b].permute(2, 0, 1)[None].float()
        g = grid[sel].permute(1, 0, 2, 3).reshape(1, out_size, len(sel) * out_size, 2)
        out = F.grid_sample(img, g, mode="bilinear", padding_mode="zeros", align_corners=False)
        patch[sel] = out.reshape(3, out_size, len(sel), out_size).permute(2, 0, 1, 3)
    mean = torch.tensor(IMAGE_MEAN, device=dev).view(1, 3, 1, 1) * 255
    std = torch.tensor(IMAGE_STD, device=dev).view(1, 3, 1, 1) * 255
    return (patch - mean) / std


def cam_crop_to_full(cam: np.ndarray, center: np.ndarray, size: np.ndarray, img_size: np.ndarray,
                     focal_length: float) -> np.ndarray:
    """HaMeR's own conversion (hamer/utils/renderer.py cam_crop_to_full): principal point at the
    image centre (w/2, h/2), one focal length. Kept to check :func:`cam_crop_to_camera` against."""
    cam, center = np.asarray(cam, float), np.asarray(center, float)
    img_size, b = np.asarray(img_size, float), np.asarray(size, float)
    bs = b * cam[:, 0] + 1e-9
    tz = 2 * focal_length / bs
    tx = 2 * (center[:, 0] - img_size[:, 0] / 2.0) / bs + cam[:, 1]
    ty = 2 * (center[:, 1] - img_size[:, 1] / 2.0) / bs + cam[:, 2]
    return np.stack([tx, ty, tz], -1)


def cam_crop_to_camera(cam: np.ndarray, center: np.ndarray, size: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Crop camera (N, 3) = (s, tx, ty) -> translation (N, 3) of the MANO joints in the real camera frame.

    Uses K's focal lengths and principal point instead of HaMeR's 5000 px virtual focal length and
    the image centre; with fx = fy = 5000 / 256 * max(w, h) and (cx, cy) = (w / 2, h / 2) it equals
    :func:`cam_crop_to_full`. Non-positive scales give NaN (no valid depth).
    """
    cam, center, b = np.asarray(cam, float), np.asarray(center, float), np.asarray(size, float)
    K = np.asarray(K, float)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    f = 0.5 * (fx + fy)
    with np.errstate(divide="ignore", invalid="ignore"):
        bs = np.where(cam[:, 0] > 0, b * cam[:, 0], np.nan)
        tz = 2 * f / bs
        tx = (center[:, 0] - cx) * tz / fx + cam[:, 1]
        ty = (center[:, 1] - cy) * tz / fy + cam[:, 2]
    return np.stack([tx, ty, tz], -1)


def crop_points_to_image(joints: np.ndarray, cam: np.ndarray, center: np.ndarray, size: np.ndarray,
                         focal_length: float = FOCAL_LENGTH, image_size: int = IMAGE_SIZE) -> np.ndarray:
    """The network's own 2D keypoints: joints (N, J, 3) seen by the crop camera (virtual focal length,
    HaMeR's perspective_projection), mapped from the crop to full-image pixels (N, J, 2)."""
    joints, cam = np.asarray(joints, float), np.asarray(cam, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.stack([cam[:, 1], cam[:, 2], 2 * focal_length / (image_size * cam[:, 0])], -1)[:, None]
        p = joints + t
        uv = (focal_length / image_size) * p[..., :2] / p[..., 2:3]   # in crop sizes, centred
    return np.asarray(center, float)[:, None] + np.asarray(size, float)[:, None, None] * uv
