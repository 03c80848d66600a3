"""Synthetic RGB-D demonstrations with exact ground truth (MuJoCo offscreen rendering).

- :mod:`demoforge.lib.synth.render`: head camera (K, pose), :class:`~demoforge.lib.synth.render.SceneRenderer` (RGB +
  exact depth of a task scene with two capsule hands), depth sensor noise, per-joint visibility.
- :mod:`demoforge.lib.synth.take`: :func:`~demoforge.lib.synth.take.generate_take` writes a take in the layout of a real
  recording plus ``ground_truth/`` tables (schemas/synthetic.py).

Importing this package does not import MuJoCo; the submodules do (after ``import lib`` sets EGL).
"""

__all__ = ["generate_take", "write_take", "TakeSummary", "SceneRenderer", "MIRROR_CHOICES", "mirror_flags"]

#: Which variants of a synthetic take to write: "no" the original hands' roles, "yes" the mirrored
#: variant only, "both" the two.
MIRROR_CHOICES = ("both", "no", "yes")


def mirror_flags(mirror: str) -> list[bool]:
    """The `mirror` flags of the takes to write for a MIRROR_CHOICES value (a one-line ValueError otherwise)."""
    if mirror not in MIRROR_CHOICES:
        raise ValueError(f"mirror must be both, no or yes, got {mirror!r}")
    return {"no": [False], "yes": [True], "both": [False, True]}[mirror]


def __getattr__(name):
    if name in ("generate_take", "write_take", "TakeSummary"):
        from demoforge.lib.synth import take  # lazy: mujoco

        return getattr(take, name)
    if name == "SceneRenderer":
        from demoforge.lib.synth.render import SceneRenderer  # lazy: mujoco

        return SceneRenderer
    raise AttributeError(name)
