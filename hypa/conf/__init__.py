"""hypa's configuration tree, shipped inside the package: one YAML per command (``train.yaml``, ...)
and the groups they compose (``model/``, ``ann/``, ``dataset/``, ``vehicle/``, ``testbench/``,
``row/``, ``experiment/``, ``hydra/``). A user's own tree is added with ``--config-dir``."""

from pathlib import Path

CONF = Path(__file__).resolve().parent
"""The folder itself (Hydra's ``config_path`` for every command)."""
