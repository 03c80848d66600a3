"""Synthetic RGB-D demonstrations with exact ground truth (MuJoCo offscreen rendering).

- :mod:`lib.synth.render`: head camera (K, pose), :class:`~lib.synth.render.SceneRenderer` (RGB +
  exact depth of a task scene with two capsule hands), depth sensor noise, per-joint visibility.
- :mod:`lib.synth.take`: :func:`~lib.synth.take.generate_take` writes a take in the layout of a real
  recording plus ``ground_truth/`` tables (schemas/synthetic.py).

Importing this package does not import MuJoCo; the submodules do (after ``import lib`` sets EGL).
"""

__all__ = ["generate_take", "write_take", "TakeSummary", "SceneRenderer"]


def __getattr__(name):
    if name in ("generate_take", "write_take", "TakeSummary"):
        from lib.synth import take

        return getattr(take, name)
    if name == "SceneRenderer":
        from lib.synth.render import SceneRenderer

        return SceneRenderer
    raise AttributeError(name)
