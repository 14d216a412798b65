"""Maps the top-level folders into the ``quadmanip`` package (see pyproject.toml)."""

from setuptools import find_namespace_packages, setup

TOP_LEVEL = ("common", "services", "sim", "hardware", "configs")

packages = [
    "quadmanip",
    *find_namespace_packages(include=["quadmanip.*"], exclude=["*__pycache__*"]),
]
package_dir = {"quadmanip": "quadmanip"}
for folder in TOP_LEVEL:
    package_dir[f"quadmanip.{folder}"] = folder
    packages.append(f"quadmanip.{folder}")
    for sub in find_namespace_packages(where=folder, exclude=["*__pycache__*"]):
        packages.append(f"quadmanip.{folder}.{sub}")

setup(packages=packages, package_dir=package_dir)
