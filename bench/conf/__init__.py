"""The Hydra configs, shipped inside the package so a wheel install finds them (``pkg://bench.conf``)."""

from pathlib import Path

CONF_DIR = Path(__file__).resolve().parent
