"""Packaging: one package, `demoforge`, with the design card's folders as its subpackages.

The code lives in ``demoforge/lib``, ``demoforge/tasks``, ``demoforge/flows`` and ``demoforge/schemas``
(the repository's top-level folders of those names are symbolic links to them), so nothing named
``lib``, ``tasks``, ``flows`` or ``schemas`` is installed at the top level. The metadata stays in
pyproject.toml; this file lists the packages and the data files that are not Python.
"""

from setuptools import find_packages, setup

setup(
    packages=find_packages(include=["demoforge", "demoforge.*"]),
    package_data={"demoforge.lib.annotate": ["page.html"]},
)
