"""demoforge installs as one package, `demoforge`: nothing named lib, tasks, flows or schemas at the top
level. Checked on a wheel built from this checkout and installed into a fresh venv outside it."""

import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path
from tests.support.paths import REPO_ROOT

ROOT = REPO_ROOT

PROBE = """
import importlib.resources, importlib.util, json, demoforge, demoforge.lib
print(json.dumps({
    "demoforge": demoforge.__file__,
    "lib": demoforge.lib.__file__,
    "top_level": {n: importlib.util.find_spec(n) is not None for n in ("tasks", "flows", "schemas")},
    "lib_geometry": importlib.util.find_spec("lib.geometry") is not None,
    "page": importlib.resources.files("demoforge.lib.annotate").joinpath("page.html").is_file(),
}))
"""


def test_wheel_installs_one_package_that_runs_outside_the_checkout(tmp_path, prefect_api_env):
    import json

    dist, venv, work, src = tmp_path / "dist", tmp_path / "venv", tmp_path / "elsewhere", tmp_path / "src"
    work.mkdir()
    # built from a copy of what the wheel is made of (setuptools writes build/ beside the sources)
    shutil.copytree(ROOT / "demoforge", src / "demoforge", ignore=shutil.ignore_patterns("__pycache__"))
    for part in ("setup.py", "pyproject.toml", "README.md"):
        shutil.copy2(ROOT / part, src / part)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(dist),
                    str(src)], check=True, capture_output=True, timeout=300)
    wheel, = dist.glob("demoforge-*.whl")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    # the project's dependencies (torch, prefect, mujoco, ...) from this venv, read-only, after the
    # fresh venv's own site-packages: installing them again would take minutes and gigabytes. Only a
    # path entry: this venv's .pth files (the checkout's editable import hook) are not processed.
    (site / "_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", str(wheel)],
                   check=True, capture_output=True, timeout=300)

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    # the session's Prefect API: the installed command's flow starts no temporary server of its own
    env.update(prefect_api_env, PREFECT_HOME=str(tmp_path / "prefect"), MUJOCO_GL="egl",
               DEMOFORGE_WAREHOUSE=str(tmp_path / "wh"))
    probe = subprocess.run([str(py), "-c", PROBE], cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert probe.returncode == 0, probe.stderr
    found = json.loads(probe.stdout)
    assert Path(found["demoforge"]).is_relative_to(site), found  # the wheel's copy, not the checkout
    assert Path(found["lib"]) == site / "demoforge" / "lib" / "__init__.py"
    assert found["top_level"] == {"tasks": False, "flows": False, "schemas": False}
    assert not found["lib_geometry"], found  # a bare `lib` may exist (llama-cpp-python's folder), never ours
    assert found["page"]  # package data travels with the wheel

    demoforge = venv / "bin" / "demoforge"
    help_ = subprocess.run([str(demoforge), "--help"], cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert help_.returncode == 0 and "synth" in help_.stdout and "evaluate" in help_.stdout, help_.stderr
    # one small flow, end to end: a 6-frame synthetic take rendered, written and registered
    synth = subprocess.run([str(demoforge), "synth", "--task", "trash_in_bin", "--max-frames", "6", "--no-video",
                            "--out", str(tmp_path / "takes")], cwd=work, env=env, capture_output=True, text=True,
                           timeout=600)
    assert synth.returncode == 0, synth.stdout + synth.stderr
    take, = (tmp_path / "takes").iterdir()
    assert len(list((take / "rgb").glob("*.png"))) == 6 and (take / "camera.json").is_file()
    rows = subprocess.run([str(demoforge), "sql", "SELECT count(*) AS n FROM takes", "--format", "csv"], cwd=work,
                          env=env, capture_output=True, text=True, timeout=300)
    assert rows.returncode == 0 and rows.stdout.split() == ['"n"', "1"], rows.stdout + rows.stderr
    # without $DEMOFORGE_WAREHOUSE an installed demoforge keeps its tables in ./warehouse, not in site-packages
    env.pop("DEMOFORGE_WAREHOUSE")
    cat = subprocess.run([str(demoforge), "catalog"], cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert cat.returncode == 0, cat.stdout + cat.stderr
    assert (work / "warehouse" / "catalog.duckdb").is_file() and not (site / "demoforge" / "warehouse").exists()


def test_checkout_packages_are_reached_only_through_demoforge():
    # in this (editable) environment too: the checkout's folders are demoforge's subpackages
    import demoforge.lib

    assert Path(demoforge.lib.__file__) == ROOT / "demoforge" / "lib" / "__init__.py"
    assert (ROOT / "lib").resolve() == ROOT / "demoforge" / "lib"  # the design card's folder, a link to it
    outside = subprocess.run([sys.executable, "-c", "import importlib.util as u; "
                              "print([u.find_spec(n) is not None for n in ('tasks', 'flows', 'schemas')])"],
                             cwd="/", capture_output=True, text=True, timeout=120,
                             env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert outside.stdout.strip() == "[False, False, False]", outside.stdout + outside.stderr
    assert importlib.util.find_spec("demoforge.cli") is not None
