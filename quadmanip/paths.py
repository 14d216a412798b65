"""Locations of packaged data (configs, robot description), valid installed or editable."""

from pathlib import Path

import quadmanip.configs as _configs

CONFIG_DIR: Path = Path(_configs.__file__).resolve().parent
