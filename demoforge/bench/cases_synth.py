"""Benchmark cases of the synth stage (registered in demoforge/bench/registry.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demoforge.bench.timing import BenchCase
from demoforge.lib.perception.hand_model import hand_from_pinch
from demoforge.lib.scratch import folder_removed_at_exit
from demoforge.lib.task_library import get_task


def cases(quick: bool) -> list[BenchCase]:
    frames = 10 if quick else 40

    def setup(n: int):
        import mujoco

        # lazy: mujoco
        from demoforge.lib.synth.render import SceneRenderer, extra_worldbody_xml, hands_assets_xml
        from demoforge.lib.synth.take import hand_styles_for

        task = get_task("pouring")
        demo = task.scripted_demo(0)
        styles = hand_styles_for(0)
        xml = task.scene_xml(demo.placement, extra_worldbody=extra_worldbody_xml(styles),
                             extra_assets=hands_assets_xml(styles))
        idx = np.linspace(0, demo.n_frames - 1, n).astype(int)
        joints = np.stack([hand_from_pinch(demo.pinch_poses[idx, h], demo.aperture[idx, h],
                                           ("left", "right")[h], styles[h])[0] for h in range(2)], 1)
        ours = SceneRenderer(xml, task.object_names, styles)
        naive = SceneRenderer(xml, task.object_names, styles, multisamples=4)
        scn = naive._renderer.scene
        scn.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = True
        scn.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = True
        scn.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = True

        def run(renderer):
            def go():
                depth_sum = 0.0
                for k, i in enumerate(idx):
                    renderer.set_state(demo.object_poses[i], joints[k])
                    depth_sum += float(renderer.render().depth.sum())
                return depth_sum
            return go

        return run(ours), run(naive)

    def setup_write(n: int):
        from demoforge.lib.synth.take import generate_take  # lazy: mujoco

        root = folder_removed_at_exit("demoforge-bench-take-")
        generate_take("pouring", 0, False, root / "warm-up", max_frames=2)  # imports, EGL, codecs: untimed

        def run(queue: int):
            def go():
                out = root / f"q{queue}"
                generate_take("pouring", 0, False, out, max_frames=n, write_queue=queue)
                return out
            return go

        return run(4), run(0)

    def same_files(ours: Path, baseline: Path) -> None:
        import filecmp

        for sub in ("rgb", "depth"):
            names = sorted(p.name for p in (ours / sub).iterdir())
            match, mismatch, errors = filecmp.cmpfiles(ours / sub, baseline / sub, names, shallow=False)
            assert not mismatch and not errors, f"{sub}: {mismatch or errors} differ from the serial writer's"
        assert filecmp.cmp(ours / "rgb.mp4", baseline / "rgb.mp4", shallow=False), "rgb.mp4 differs"

    return [BenchCase("synth", "render RGB-D 640x480 (pouring scene)", frames, "frames",
                      "MuJoCo defaults: shadows, reflections, skybox, 4x multisampling", setup, repeats=1),
            BenchCase("synth", "write a take (render + noise + PNG/.npy/MP4, pouring)", frames, "frames",
                      "each frame written before the next renders (write_queue=0)", setup_write,
                      check=same_files, repeats=1)]
