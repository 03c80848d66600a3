"""Synthetic RGB-D demonstrations with exact ground truth (MuJoCo offscreen rendering).

- :mod:`demoforge.lib.synth.render`: head camera (K, pose), :class:`~demoforge.lib.synth.render.SceneRenderer` (RGB +
  exact depth of a task scene with two capsule hands), depth sensor noise, per-joint visibility.
- :mod:`demoforge.lib.synth.take`: :func:`~demoforge.lib.synth.take.generate_take` writes a take in the layout of a real
  recording plus ``ground_truth/`` tables (schemas/synthetic.py).

Importing this package does not import MuJoCo; the submodules do (after ``import lib`` sets EGL).
"""

__all__ = ["generate_take", "write_take", "TakeSummary", "SceneRenderer"]


def __getattr__(name):
    if name in ("generate_take", "write_take", "TakeSummary"):
        from demoforge.lib.synth import take

        return getattr(take, name)
    if name == "SceneRenderer":
        from demoforge.lib.synth.render import SceneRenderer

        return SceneRenderer
    raise AttributeError(name)
