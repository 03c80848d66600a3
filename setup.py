"""Packaging: one package, `demoforge`, whose subpackages are the design card's top-level folders.

setuptools' ``package_dir`` maps ``demoforge.lib`` -> ``lib/`` (and tasks, flows, schemas), so the
folders stay where the design card puts them while nothing named ``lib``, ``tasks``, ``flows`` or
``schemas`` is installed at the top level. pyproject.toml cannot list the mapped subpackages by
pattern, hence this file; the metadata stays in pyproject.toml.
"""

from setuptools import find_packages, setup

MAPPED = ("lib", "tasks", "flows", "schemas")

packages = ["demoforge", *(f"demoforge.{p}" for p in find_packages("demoforge"))]
for top in MAPPED:
    packages += [f"demoforge.{top}", *(f"demoforge.{top}.{p}" for p in find_packages(top))]

setup(
    packages=packages,
    package_dir={"demoforge": "demoforge", **{f"demoforge.{top}": top for top in MAPPED}},
    package_data={"demoforge.lib.annotate": ["page.html"],
                  # the ViperX arms' MJCF and meshes (gym-aloha 0.1.5, Apache-2.0) with their licence
                  "demoforge.lib.sim.robots.aloha": ["assets/*"]},
)
